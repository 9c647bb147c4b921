"""A Sentinel-2 granule's 10 m-band direct-location grid, batched, against the same points one by one.

The trimmed Sen2VM test product (tests/data/sentinel2): band B02 of detector 06, its first
granule (2304 lines x 2552 pixels), Sen2VM's step (600 pixels: 5 x 5 points) and a fine step
(``--step``, default 150: 16 x 18 points), on the geoid, with light-time and aberration
(geoloc's and Rugged's defaults). The peer is the same grid computed pixel by pixel (one
pipeline call per point), in the same run; the ratio is pixel-by-pixel / batched.

Run: python benchmarks/bench_sentinel2.py [--step 150] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import timed  # noqa: E402

from geoloc.io.sentinel2 import read_product  # noqa: E402
from geoloc.pipeline import Corrections  # noqa: E402
from geoloc.workflows.sentinel2 import direct_grid, grid_pixels  # noqa: E402

PRODUCT = Path(__file__).resolve().parents[1] / "tests" / "data" / "sentinel2" / "L1B"


def main(step: float, repeat: int) -> None:
    product = read_product(PRODUCT)
    g = product.granule(6, 1)
    sensor = product.sensor("B02", 6)
    corr = Corrections.for_sensor(sensor)
    rows, cols = grid_pixels(sensor, step, g.first_row("B02"), g.shape("B02")[0])
    n = rows.size * cols.size

    def batched():
        return direct_grid(sensor, rows, cols, geoid=True, corrections=corr)

    def one_by_one():
        out = np.empty((3, rows.size, cols.size))
        for i, r in enumerate(rows):
            for j, c in enumerate(cols):
                lon, lat, h, _ = direct_grid(sensor, rows[i : i + 1], cols[j : j + 1], geoid=True, corrections=corr)
                out[:, i, j] = lon[0, 0], lat[0, 0], h[0, 0]
        return out

    sen2vm_rows, sen2vm_cols = grid_pixels(sensor, 600, g.first_row("B02"), g.shape("B02")[0])
    w6, c6, _ = timed(lambda: direct_grid(sensor, sen2vm_rows, sen2vm_cols, geoid=True, corrections=corr), repeat)
    wb, cb, a = timed(batched, repeat)
    wp, cp, b = timed(one_by_one, max(1, repeat // 3))
    diff = float(np.nanmax(np.abs(np.asarray(a[:3]) - b)))
    print(f"load average {os.getloadavg()[0]:.2f}; {sensor.name}, granule 1 ({g.shape('B02')[0]} x {sensor.cols} px)")
    print(f"Sen2VM's step 600: {sen2vm_rows.size} x {sen2vm_cols.size} points: median {w6:.3f} s wall, CPU {c6:.3f} s")
    print(f"step {step:g}: {rows.size} x {cols.size} = {n} points batched: median {wb:.3f} s wall, CPU {cb:.3f} s")
    print(
        f"step {step:g}: the same points one by one: median {wp:.3f} s wall, CPU {cp:.3f} s (max difference {diff:.1e})"
    )
    print(f"ratio: {wp / wb:.1f} (one by one / batched)")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=150.0, help="grid step [pixels] of the timed grids (default 150)")
    ap.add_argument("--repeat", type=int, default=3, help="timed calls of the batched grid (default 3)")
    args = ap.parse_args()
    main(args.step, args.repeat)
