"""Rays per second of the location pipeline with refraction on, against the same pipeline with it off.

Every ray has its own aircraft position (30-40 N, 75-85 E, 5-20 km) and its own
direction (0-75 deg off nadir, any azimuth), as in a Monte Carlo run or a long replay.
Both go through ``geoloc.pipeline.Pipeline.intersect`` on the inflated surface at h = 0
([Q17 eq. 11], then Vermeille), as every verb does. "Without": ``--refraction none``.
"With": ``--refraction standard``: the same raw hit, then ``Refraction.correct`` from it,
whose bent point at the raw hit's height is the corrected ground point on a
constant-height surface (with its latitude, longitude and height), and the bookkeeping
of the shift. Both are timed on the same rays, alternately, medians of ``--repeat`` calls.

Run: ``python benchmarks/bench_refraction.py [--rays N] [--repeat K] [--threads T]``.
Prints wall and CPU time of each, the machine's load, and last ``ratio: X  (wall Y)``:
rays per CPU second with refraction over rays per CPU second without (the goal: >= 0.5,
locating with refraction at least half as fast as without), the same in wall time in
brackets. The correction's kernel runs on every core (numba ``prange``); the straight
path is numpy on one, so on an idle machine the wall ratio is the larger.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _timing import timed  # benchmarks/_timing.py (the script's folder is on sys.path)

from geoloc.corrections.refraction import STANDARD_REFRACTION
from geoloc.pipeline import Corrections, Pipeline
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_ned
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.height import HeightSurface


def make_rays(n: int, rng: np.random.Generator) -> LineOfSight:
    lat = np.deg2rad(rng.uniform(30, 40, n))
    lon = np.deg2rad(rng.uniform(75, 85, n))
    o = geodetic_to_ecef(lat, lon, rng.uniform(5000, 20000, n))
    a = np.deg2rad(rng.uniform(0, 75, n))
    z = np.deg2rad(rng.uniform(0, 360, n))
    d_ned = np.stack([np.sin(a) * np.cos(z), np.sin(a) * np.sin(z), np.cos(a)], axis=-1)
    d = np.einsum("...ij,...j->...i", R_ecef_ned(lat, lon), d_ned)
    return LineOfSight(o, d, np.zeros(n, np.uint8))


SURFACE = HeightSurface(0.0)
OFF = Pipeline(None, SURFACE, Corrections())
ON = Pipeline(None, SURFACE, Corrections(refraction=STANDARD_REFRACTION))


def straight(los):
    return OFF.intersect(los)


def refracted(los):
    return ON.intersect(los)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument(
        "--threads", type=int, default=None, help="numba threads for the correction (default: one per core)"
    )
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    los = make_rays(args.rays, rng)
    refracted(LineOfSight(los.origin_ecef[:100], los.direction_ecef[:100], los.status[:100]))  # compile first
    load0 = os.getloadavg()
    runs = {"straight": [], "refracted": []}
    for _ in range(args.repeat):  # alternate, so that both see the same load
        for name, fn in (("straight", straight), ("refracted", refracted)):
            w, c, out = timed(lambda fn=fn: fn(los), 1)
            runs[name].append((w, c))
    load1 = os.getloadavg()
    (ws, cs), (wr, cr) = (np.median(np.array(runs[k]), axis=0) for k in ("straight", "refracted"))
    t0 = time.perf_counter()
    g = refracted(los)
    tc = time.perf_counter() - t0
    ok = g.status == Status.OK
    shift = g.refraction_m[ok]
    n = args.rays
    print(
        f"rays: {n}, repeats: {args.repeat} (medians, alternating), load average {load0[0]:.2f} before, "
        f"{load1[0]:.2f} after"
    )
    print(f"rays corrected: {int(ok.sum())}; shift median {np.median(shift):.2f} m, max {np.max(shift):.1f} m")
    print(
        f"pipeline, --refraction none:     wall {ws:.4f} s  cpu {cs:.4f} s  "
        f"{n / ws / 1e6:.3f} M rays/s wall  {n / cs / 1e6:.3f} M rays/s cpu"
    )
    print(
        f"pipeline, --refraction standard: wall {wr:.4f} s  cpu {cr:.4f} s  "
        f"{n / wr / 1e6:.3f} M rays/s wall  {n / cr / 1e6:.3f} M rays/s cpu"
    )
    print(f"refraction alone (difference):   wall {wr - ws:.4f} s  cpu {cr - cs:.4f} s; one more call {tc:.4f} s wall")
    print("ratio is rays per CPU second with refraction over without (goal >= 0.5); wall in brackets")
    print(f"ratio: {cs / cr:.2f}  (wall {ws / wr:.2f})")


if __name__ == "__main__":
    main()
