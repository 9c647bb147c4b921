"""Pixels -> lat/lon/h per second for 1 M rays, against pymap3d.lookAtSpheroid in the same run.

Every ray has its own aircraft pose (position, attitude, gimbal angles) and
pixel, as in a Monte Carlo run or a replay of a long flight. geoloc does the
whole chain (pixel -> camera -> gimbals -> body -> NED -> ECEF, ray x ellipsoid,
ECEF -> geodetic). pymap3d is given the easier job: the azimuth and tilt of
the same rays, precomputed outside the timing, and it intersects them with the
ellipsoid (h = 0). The hits of both are compared.

Two sensors: the [Q17] roll-pitch pinhole, and an azimuth-elevation turret with
Brown distortion, a mount, a boresight and a lever arm (the compiled path runs
any sensor; nothing falls back to numpy).

Run: ``python benchmarks/bench_locate.py [--rays N] [--repeat K]``. Prints
medians of wall and CPU time; the last lines are ``ratio: X`` (the [Q17]
camera) and ``ratio turret: X`` = geoloc rays per CPU second over pymap3d's
(the goal: >= 2.5 for both), each followed by the same ratio in wall time. The
kernel runs on both cores and pymap3d on one, so the wall ratio is the larger on
an idle machine; on a loaded one the CPU ratio is the steadier figure.

``--ab REV`` times the kernel alone, this tree's against the ``_fastlocate.py`` of
git revision REV (loaded from ``git show``, compiled in the same process), on the
same rays, calls alternating, medians of wall and CPU time: an A/B that stays
meaningful when other processes load the machine (both sides see the same load).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _revision import (
    module_at,  # benchmarks/_revision.py (the script's folder is on sys.path)
)
from _timing import timed  # benchmarks/_timing.py
from pymap3d.los import lookAtSpheroid

from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.geodesy.local import R_ecef_ned
from geoloc.locate import line_of_sight, locate
from geoloc.sensors.camera import Camera
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens
from geoloc.surfaces.height import intersect_los_height

#: The turret: a Brown-distorted lens on an azimuth-elevation gimbal with a mount, a boresight and a lever arm.
TURRET = FrameSensor(
    BrownLens(
        fx=2200.0,
        fy=2195.0,
        cx=959.5,
        cy=539.5,
        width=1920,
        height=1080,
        k1=-0.21,
        k2=0.07,
        p1=4e-4,
        p2=-2e-4,
        k3=-0.01,
    ),
    PRESETS["azimuth-elevation"],
    mount=(2e-3, -1e-3, 4e-3),
    boresight=(1e-3, 2e-3, -3e-3),
    lever_arm_m=(1.5, 0.2, 0.7),
    name="turret",
)


def make_rays(n: int, rng: np.random.Generator):
    cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)
    pose = Pose.from_deg(
        rng.uniform(30, 40, n),
        rng.uniform(75, 85, n),
        rng.uniform(5000, 20000, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-5, 5, n),
        rng.uniform(-5, 5, n),
        rng.uniform(-60, 60, n),
        rng.uniform(-10, 10, n),
    )
    rows = rng.uniform(1, cam.rows, n)
    cols = rng.uniform(1, cam.cols, n)
    return cam, pose, rows, cols


def make_turret_rays(n: int, rng: np.random.Generator):
    pose = Pose.from_deg(
        rng.uniform(30, 40, n),
        rng.uniform(75, 85, n),
        rng.uniform(500, 6000, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-5, 5, n),
        rng.uniform(-5, 5, n),
        angles_deg={"azimuth": rng.uniform(0, 360, n), "elevation": rng.uniform(-85, -25, n)},
    )
    return TURRET, pose, rng.uniform(1, TURRET.rows, n), rng.uniform(1, TURRET.cols, n)


def peer_inputs(pose: Pose, camera, rows, cols):
    """Azimuth and tilt (from nadir) of the same lines of sight, in degrees, for pymap3d."""
    los = line_of_sight(pose, camera, rows, cols)
    # pymap3d starts at the optical centre (the navigation reference plus the lever arm) and
    # reads azimuth and tilt in the NED frame there
    lat, lon, h = ecef_to_geodetic(los.origin_ecef)
    d_ned = rot.rotate(np.swapaxes(R_ecef_ned(lat, lon), -1, -2), los.direction_ecef)
    az = np.rad2deg(np.arctan2(d_ned[..., 1], d_ned[..., 0]))
    tilt = np.rad2deg(np.arccos(np.clip(d_ned[..., 2], -1, 1)))
    return np.rad2deg(lat), np.rad2deg(lon), h, az, tilt


def compare(name, n, repeat, sensor, pose, rows, cols):
    """Time geoloc and pymap3d on the same rays; print both and return the wall-time ratio."""
    lat0, lon0, h0, az, tilt = peer_inputs(pose, sensor, rows, cols)
    locate(pose.take(slice(0, 10_000)), sensor, rows[:10_000], cols[:10_000], target_h=0.0)  # compile first
    t_ours, c_ours, g = timed(lambda: locate(pose, sensor, rows, cols, target_h=0.0), repeat)
    t_peer, c_peer, (plat, plon, prange) = timed(lambda: lookAtSpheroid(lat0, lon0, h0, az, tilt), repeat)
    ok = np.isfinite(g.lat) & np.isfinite(plat)
    dlat_m = np.abs(g.lat_deg[ok] - plat[ok]) * 111_000.0
    drange = np.abs(g.slant_range[ok] - prange[ok])
    print(
        f"[{name}] hits: geoloc {int(np.isfinite(g.lat).sum())}, pymap3d {int(np.isfinite(plat).sum())}, "
        f"both {int(ok.sum())}; max |dlat| {dlat_m.max():.2e} m, max |d range| {drange.max():.2e} m"
    )
    print(
        f"[{name}] geoloc locate (full chain):  wall {t_ours:.3f} s  cpu {c_ours:.3f} s  "
        f"{n / t_ours / 1e6:.2f} M rays/s"
    )
    print(
        f"[{name}] pymap3d lookAtSpheroid:      wall {t_peer:.3f} s  cpu {c_peer:.3f} s  "
        f"{n / t_peer / 1e6:.2f} M rays/s"
    )
    return c_peer / c_ours, t_peer / t_ours


def _old_fastlocate(rev: str):
    """The ``geoloc/sensors/_fastlocate.py`` of git revision ``rev``, imported as a scratch module."""
    return module_at(rev, "geoloc/sensors/_fastlocate.py")


def ab(rev: str, n: int, repeat: int, rng) -> None:
    """Kernel alone, old (``rev``) vs new (this tree), alternating calls, same rays; medians."""
    from geoloc.locate import as_sensor
    from geoloc.sensors import _fastlocate as new

    old = _old_fastlocate(rev)
    cases = [("q17 roll-pitch pinhole", *make_rays(n, rng)), ("turret", *make_turret_rays(n, rng))]
    for name, sensor, pose, rows, cols in cases:
        s = as_sensor(sensor)
        out = {}
        for mod in (old, new):  # compile (or load) both first
            mod.locate_fast(pose.take(slice(0, 1000)), s, rows[:1000], cols[:1000], 0.0)
        for _ in range(repeat):
            for label, mod in (("old", old), ("new", new)):
                c, w = time.process_time(), time.perf_counter()
                res = mod.locate_fast(pose, s, rows, cols, 0.0)
                out.setdefault(label, []).append((time.perf_counter() - w, time.process_time() - c))
                out[label + "_res"] = res
        (wo, co), (wn, cn) = (np.median(np.array(out[k]), axis=0) for k in ("old", "new"))
        lo, ln = out["old_res"][0], out["new_res"][0]
        ok = np.isfinite(lo) & np.isfinite(ln)
        print(
            f"[A/B {name}] kernel {rev}: wall {wo:.3f} s cpu {co:.3f} s | this tree: wall {wn:.3f} s "
            f"cpu {cn:.3f} s | speed-up cpu {co / cn:.2f}x wall {wo / wn:.2f}x | "
            f"max |d lat| {np.max(np.abs(lo[ok] - ln[ok])):.1e} rad"
        )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument(
        "--ab", metavar="REV", default=None, help="only the A/B of the kernel: this tree's against git revision REV's"
    )
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="numba threads for the kernel (default: numba's, one per core); 1 measures the "
        "kernel's own CPU cost without waits at the parallel loop's barrier",
    )
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    if args.ab:
        ab(args.ab, args.rays, args.repeat, rng)
        return
    cam, pose, rows, cols = make_rays(args.rays, rng)
    print(f"rays: {args.rays}, repeats: {args.repeat} (medians; the kernel uses both cores, so CPU > wall)")
    ratio = compare("q17 roll-pitch pinhole", args.rays, args.repeat, cam, pose, rows, cols)
    # the numpy reference path (lens and frame graph in numpy), for scale
    t_los, _, los = timed(lambda: line_of_sight(pose, cam, rows, cols, engine="numpy"), args.repeat)
    t_hit, _, _ = timed(lambda: intersect_los_height(los, 0.0), args.repeat)
    print(
        f"[q17 roll-pitch pinhole] numpy reference path: {t_los + t_hit:.3f} s  "
        f"{args.rays / (t_los + t_hit) / 1e6:.2f} M rays/s  "
        f"(line_of_sight {t_los:.3f} s + intersect/geodetic {t_hit:.3f} s)"
    )
    ratio_t = compare(
        "turret: az-el, Brown, mount, boresight, lever arm", args.rays, args.repeat, *make_turret_rays(args.rays, rng)
    )
    print("ratios are rays per CPU second (geoloc / pymap3d); wall in brackets")
    print(f"ratio: {ratio[0]:.2f}  (wall {ratio[1]:.2f})")
    print(f"ratio turret: {ratio_t[0]:.2f}  (wall {ratio_t[1]:.2f})")


if __name__ == "__main__":
    main()
