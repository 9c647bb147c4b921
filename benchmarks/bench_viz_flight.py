"""Speed of the flight debugger: a 10 000-frame flight opens in <= 3 s, a timeline step <= 100 ms.

One command: ``python benchmarks/bench_viz_flight.py [--frames 10000] [--repeat 3]``.

The flight is synthetic and seeded, from the bundled KLV example's sensor geometry: the example's
298 frames (pose, turret angles, fields of view, over the SRTM crop) tiled to ``--frames`` with
small seeded pose perturbations (0.2 deg of heading, 5 m of position). Measured, medians of wall
and CPU time:

* **open**: :func:`geoloc_viz.flight_model.build` (all footprints, centres and residuals in one
  batch) plus the layer's scene build (:class:`geoloc_viz.flight_layer.FlightLayer`) on a viser
  server with a simulated client (the scene messages are serialised as for a browser);
* **step**: one timeline step, the layer's highlight update alone, and the whole step with the
  session's ``load_record`` (the current frame's chain, line of sight and DEM iterations);
* **peer**: the same footprints computed frame by frame (one ``line_of_sight`` + ``intersect``
  per frame, on a sample of frames, scaled to the flight), the loop the batch replaces.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import timed

from geoloc_viz import flight_layer, flight_model


def synthetic_flight(n: int, seed: int = 20261201):
    """The KLV example's scenario with its records tiled to ``n`` frames, seeded perturbations."""
    scn = flight_model.default_flight_scenario()
    rng = np.random.default_rng(seed)
    base, fov = scn.records, scn.frame_fov_deg
    recs, fovs = [], []
    for k in range(n):
        info, inp = base[k % len(base)]
        info = copy.copy(info)
        info.label = f"frame {k}"
        recs.append(
            (
                info,
                inp.replace(
                    heading_deg=inp.heading_deg + rng.normal(0, 0.2),
                    lat_deg=inp.lat_deg + rng.normal(0, 5e-5),
                    lon_deg=inp.lon_deg + rng.normal(0, 5e-5),
                ),
            )
        )
        fovs.append(fov[k % len(base)])
    scn.records = recs
    scn.frame_fov_deg = np.array(fovs)
    return scn


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    from geoloc_viz.app import GeolocApp, make_server

    scn = synthetic_flight(a.frames)
    server = make_server(port=0)
    try:
        app = GeolocApp(server, scn, layers=())  # the session alone; the layer is timed below
        flight_model.build(scn, diagnose_faults=False)  # warm the compiled DEM walk

        layers = []

        def open_flight():
            flight_layer._CACHE.clear()
            if layers:
                layers.pop().close()  # the previous repeat's layer: its session callbacks go quiet
            m = flight_model.build(scn)
            layer = flight_layer.FlightLayer(app, m)
            # a simulated client: serialise the scene as a browser would receive it
            server.get_scene_serializer().serialize()
            layers.append(layer)
            return layer

        w_open, c_open, layer = timed(open_flight, a.repeat)
        m = layer.model
        idx = iter(np.random.default_rng(1).integers(0, len(m), 1000))
        w_hl, c_hl, _ = timed(lambda: layer.highlight(int(next(idx))), 20)
        w_step, c_step, _ = timed(lambda: layer.go(int(next(idx))), 10)

        # peer: frame by frame, on a sample of frames, scaled to the flight
        sensor = scn.camera  # the Scenario's FrameSensor
        pose, _, _, target_h = flight_model.records_pose(scn.records)
        surface = flight_model._surface(scn, target_h, "exact")
        rr, cc = flight_model.outline_pixels(sensor, flight_model.EDGE_SAMPLES, scn.frame_fov_deg)
        sample = np.arange(0, len(m), max(len(m) // 100, 1))

        def per_frame():
            for k in sample:
                p = pose.take(np.array([k]))
                los = sensor.line_of_sight(rr[:, k : k + 1], cc[:, k : k + 1], p, outside="extrapolate")
                flight_model._hit(surface, los)

        w_peer, c_peer, _ = timed(per_frame, 1)
        scale = len(m) / len(sample)
        w_model, c_model, _ = timed(lambda: flight_model.build(scn, diagnose_faults=False), 1)
    finally:
        server.stop()
    P = m.footprint_enu.shape[1]
    print(
        f"flight: {len(m)} frames, {P} outline points each ({len(m) * (P + 2)} lines of sight), "
        f"{int(m.outlier.sum())} outliers; 2-core machine shared with other jobs (loaded)"
    )
    print(f"open (model + scene build + serialise): median wall {w_open:.3f} s, CPU {c_open:.3f} s (target <= 3 s)")
    print(f"timeline step, highlight only: median wall {w_hl * 1e3:.2f} ms, CPU {c_hl * 1e3:.2f} ms")
    print(
        f"timeline step with load_record: median wall {w_step * 1e3:.1f} ms, CPU {c_step * 1e3:.1f} ms "
        f"(target <= 100 ms)"
    )
    print(
        f"footprints batched (model, no diagnosis): wall {w_model:.3f} s, CPU {c_model:.3f} s; "
        f"frame by frame (peer, {len(sample)} frames scaled x{scale:.0f}): wall {w_peer * scale:.3f} s, "
        f"CPU {c_peer * scale:.3f} s; ratio peer / batch {w_peer * scale / w_model:.1f}x (wall)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
