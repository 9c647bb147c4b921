"""Ground -> image: the rigorous pushbroom model (iteration over line time) against its RPC.

[L12] section 4.1: back-projecting ground points with the rigorous line-scanner model
needs an iteration and is slow; the RPC replaces it. This measures both on the same
100 000 ground points of the bundled ZY-3-like scene and prints medians and the ratio
(rigorous / bare RPC); it also times the RPC behind the Sensor interface
(``RPCSensor``: domain check and statuses, and its lines of sight).

Run: python benchmarks/bench_rpc.py [--points N]
"""

import argparse
import time

import numpy as np

from geoloc.analysis.rpc_fit import fit_rpc
from geoloc.assets import asset_path
from geoloc.sensors.rpc import RPCSensor
from geoloc.workflows.scenario import load_scenario
from geoloc.pipeline import at_height


def median_time(fn, repeat=5):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def main(n=100_000):
    sc = load_scenario(asset_path("scenarios", "zy3_nadir.toml"))
    s = sc.sensor
    model = fit_rpc(s, sc.height_min, sc.height_max, sc.grid, sc.check_grid).model
    rng = np.random.default_rng(0)
    r0, c0 = rng.uniform(1, s.rows, n), rng.uniform(1, s.cols, n)
    g = at_height(s, r0, c0, rng.uniform(0, 1200, n))
    lat, lon, h = g.lat, g.lon, g.h
    t_rig = median_time(lambda: s.ground_to_pixel(lat, lon, h))
    t_rpc = median_time(lambda: model.ground_to_pixel(lat, lon, h))
    sensor = RPCSensor(model, s.rows, s.cols)  # the same RPC behind the Sensor interface
    t_sen = median_time(lambda: sensor.ground_to_pixel(lat, lon, h))
    t_los = median_time(lambda: sensor.line_of_sight(r0, c0), repeat=3)
    r1, c1, _ = s.ground_to_pixel(lat, lon, h)
    r2, c2 = model.ground_to_pixel(lat, lon, h)
    print(f"points: {n}")
    print(f"rigorous ground_to_pixel (Newton on line time): median {t_rig * 1e3:.1f} ms")
    print(f"RPC ground_to_pixel:                            median {t_rpc * 1e3:.1f} ms")
    print(f"RPCSensor.ground_to_pixel (domain check, status): median {t_sen * 1e3:.1f} ms")
    print(f"RPCSensor.line_of_sight (inverse at 2 heights):   median {t_los * 1e3:.1f} ms")
    print(f"max difference: {np.max(np.hypot(r1 - r2, c1 - c2)):.2e} px")
    print(f"ratio: {t_rig / t_rpc:.1f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100_000, help="ground points (default 100 000)")
    main(ap.parse_args().points)
