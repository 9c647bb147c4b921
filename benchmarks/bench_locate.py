"""Pixels -> lat/lon/h per second for 1 M rays, against pymap3d.lookAtSpheroid in the same run.

Every ray has its own aircraft pose (position, attitude, gimbal angles) and
pixel, as in a Monte Carlo run or a replay of a long flight. geoloc does the
whole chain (pixel -> camera -> gimbals -> body -> NED -> ECEF, ray x ellipsoid,
ECEF -> geodetic). pymap3d is given the easier job: the azimuth and tilt of
the same rays, precomputed outside the timing, and it intersects them with the
ellipsoid (h = 0). The hits of both are compared.

Run: ``python benchmarks/bench_locate.py [--rays N] [--repeat K]``. Prints
medians; the last line is ``ratio: X`` = geoloc rays/s over pymap3d rays/s.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from pymap3d.los import lookAtSpheroid

from geoloc.frames import rotations as rot
from geoloc.frames.chain import FrameChain, Pose
from geoloc.locate import line_of_sight, locate
from geoloc.sensors.camera import Camera
from geoloc.surfaces.height import intersect_los_height


def make_rays(n: int, rng: np.random.Generator):
    cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)
    pose = Pose.from_deg(
        rng.uniform(30, 40, n), rng.uniform(75, 85, n), rng.uniform(5000, 20000, n),
        rng.uniform(-180, 180, n), rng.uniform(-5, 5, n), rng.uniform(-5, 5, n),
        rng.uniform(-60, 60, n), rng.uniform(-10, 10, n),
    )
    rows = rng.uniform(1, cam.rows, n)
    cols = rng.uniform(1, cam.cols, n)
    return cam, pose, rows, cols


def peer_inputs(pose: Pose, camera: Camera, rows, cols):
    """Azimuth and tilt (from nadir) of the same lines of sight, in degrees, for pymap3d."""
    los = line_of_sight(pose, camera, rows, cols)
    chain = FrameChain(pose)
    d_ned = rot.rotate(np.swapaxes(chain.R_ecef_ned, -1, -2), los.direction_ecef)
    az = np.rad2deg(np.arctan2(d_ned[..., 1], d_ned[..., 0]))
    tilt = np.rad2deg(np.arccos(np.clip(d_ned[..., 2], -1, 1)))
    return np.rad2deg(pose.lat), np.rad2deg(pose.lon), pose.h, az, tilt


def median_time(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    cam, pose, rows, cols = make_rays(args.rays, rng)
    lat0, lon0, h0, az, tilt = peer_inputs(pose, cam, rows, cols)

    t_ours, g = median_time(lambda: locate(pose, cam, rows, cols, target_h=0.0), args.repeat)
    # the numpy reference path (FrameChain matrices), for scale
    t_los, los = median_time(lambda: line_of_sight(pose, cam, rows, cols), args.repeat)
    t_hit, _ = median_time(lambda: intersect_los_height(los, 0.0), args.repeat)
    t_peer, (plat, plon, prange) = median_time(
        lambda: lookAtSpheroid(lat0, lon0, h0, az, tilt), args.repeat)

    ok = np.isfinite(g.lat) & np.isfinite(plat)
    dlat_m = np.abs(g.lat_deg[ok] - plat[ok]) * 111_000.0
    drange = np.abs(g.slant_range[ok] - prange[ok])
    print(f"rays: {args.rays}, repeats: {args.repeat} (medians)")
    print(f"hits: geoloc {int(np.isfinite(g.lat).sum())}, pymap3d {int(np.isfinite(plat).sum())}, "
          f"both {int(ok.sum())}; max |dlat| {dlat_m.max():.2e} m, max |d range| {drange.max():.2e} m")
    print(f"geoloc locate (pixel -> lat/lon/h, full chain): {t_ours:.3f} s  "
          f"{args.rays / t_ours / 1e6:.2f} M rays/s")
    print(f"geoloc numpy reference path (FrameChain):       {t_los + t_hit:.3f} s  "
          f"{args.rays / (t_los + t_hit) / 1e6:.2f} M rays/s  "
          f"(line_of_sight {t_los:.3f} s + intersect/geodetic {t_hit:.3f} s)")
    print(f"pymap3d lookAtSpheroid (az/tilt given):         {t_peer:.3f} s  "
          f"{args.rays / t_peer / 1e6:.2f} M rays/s")
    print(f"ratio: {t_peer / t_ours:.2f}")


if __name__ == "__main__":
    main()
