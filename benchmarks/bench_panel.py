"""The large panel's cost on the server (geoloc_viz.panel_layer): a timeline step with the panel
open against the same step with it closed (the peer), and the time to open it.

``GeolocApp`` with the default layers on the bundled example flight (its video, its DEM), no
browser: a step is ``FlightLayer.go`` (the record loaded, its scene redrawn, every layer's update:
with the panel open, its picture at full resolution, the map's overlay and the plots' cursor).
Prints medians over ``--steps`` consecutive frames, wall and CPU, the load average, and the ratio
open / closed last.

Run: ``python benchmarks/bench_panel.py [--steps 30]``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _steps(fl, frames):
    wall, cpu = [], []
    for i in frames:
        t0, c0 = time.perf_counter(), time.process_time()
        fl.go(int(i))
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)), float(np.median(cpu))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=30, help="timeline steps per case (default 30)")
    args = ap.parse_args(argv)
    from geoloc_viz import panel_layer
    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    server = make_server(port=0)
    try:
        app = GeolocApp(server, default_flight_scenario())
        fl = app.layers[0]
        pl = next(o for o in app.layers if isinstance(o, panel_layer.PanelLayer))
        n = max(int(args.steps), 1)
        print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        w0, c0 = _steps(fl, range(10, 10 + n))
        print(f"panel closed: timeline step median {w0 * 1e3:.1f} ms wall, {c0 * 1e3:.1f} ms CPU over {n} steps")
        t, c = time.perf_counter(), time.process_time()
        pl.open_panel()
        print(f"opening the panel: {time.perf_counter() - t:.3f} s wall, {time.process_time() - c:.3f} s CPU")
        w1, c1 = _steps(fl, range(100, 100 + n))
        print(f"panel open: timeline step median {w1 * 1e3:.1f} ms wall, {c1 * 1e3:.1f} ms CPU over {n} steps")
        sizes = {k: len(getattr(pl, f"html_{k}").content) for k in ("picture", "map", "plots")}
        print("sent per step: " + ", ".join(f"{k} {v / 1e3:.1f} kB" for k, v in sizes.items()))
        print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        print(f"ratio open / closed (step wall): {w1 / w0:.3f}")
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
