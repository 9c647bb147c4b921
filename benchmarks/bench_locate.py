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
(the goal: >= 3 for both), each followed by the same ratio in wall time. The
kernel runs on both cores and pymap3d on one, so the wall ratio is the larger on
an idle machine; on a loaded one the CPU ratio is the steadier figure.

``--hops`` prints where the kernel's CPU time goes: each hop's loop (a ``*_block`` function of
``geoloc/sensors/_fastlocate.py``) driven alone over the rays in blocks, as in the kernel, on
one thread, nanoseconds a ray (medians), beside the whole kernel's and ``locate()``'s; the
difference between the sum of the hops and the whole kernel is what no hop holds (the
kernel's memory traffic: inputs read once, outputs written to fresh pages).

``--ab REV`` times the kernel alone, this tree's against the ``_fastlocate.py`` of
git revision REV (loaded from ``git show``, compiled in the same process), on the
same rays, calls alternating, medians of wall and CPU time: an A/B that stays
meaningful when other processes load the machine (both sides see the same load). Three cases:
the two sensors' rays, and a frame (one pose, a grid of pixels: inputs of one value each).
"""

from __future__ import annotations

import argparse
import os
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
    # a frame: one pose (one value a field, one target height) for a grid of pixels
    cam = cases[0][1]
    rr, cc = np.meshgrid(np.linspace(1, cam.rows, 1000), np.linspace(1, cam.cols, max(n // 1000, 1)), indexing="ij")
    frame = Pose.from_deg(35.48, 80.97, 18000.0, 45.0, 3.5, 0.0, 50.0, -2.6)
    cases.append(("frame (one pose)", cam, frame, rr.ravel(), cc.ravel()))
    for name, sensor, pose, rows, cols in cases:
        s = as_sensor(sensor)
        out = {}
        for mod in (old, new):  # compile (or load) both first
            mod.locate_fast(pose if pose.shape == () else pose.take(slice(0, 1000)), s, rows[:1000], cols[:1000], 0.0)
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


def hops(n: int, repeat: int, rng) -> None:
    """Per-hop CPU time of the fused kernel, one thread, ns a ray (see the module docstring)."""
    import numba
    from numba import njit

    from geoloc.geodesy.ellipsoid import E2, A, B
    from geoloc.locate import as_sensor
    from geoloc.sensors import _fastlocate as F

    numba.set_num_threads(1)
    bl = F._BLOCK

    @njit
    def d_sincos(a, sc):
        for k0 in range(0, a.shape[0], bl):
            m = min(a.shape[0], k0 + bl) - k0
            F._sincos_block(a[k0 : k0 + m], sc[0, :m], sc[1, :m])

    @njit
    def d_valid(lat, lon, h, hd, p, r, row, col, th, ranges, b_m, sc):
        for k0 in range(0, lat.shape[0], bl):
            k1 = min(lat.shape[0], k0 + bl)
            F._valid_block(
                lat[k0:k1], lon[k0:k1], h[k0:k1], hd[k0:k1], p[k0:k1], r[k0:k1],
                row[k0:k1], col[k0:k1], th[k0:k1], ranges, b_m, sc[0, : k1 - k0],
            )  # fmt: skip

    @njit
    def d_unproject(code, lp, row, col, sc, good):
        for k0 in range(0, row.shape[0], bl):
            k1 = min(row.shape[0], k0 + bl)
            m = k1 - k0
            F._unproject_block(code, lp, row[k0:k1], col[k0:k1], sc[0, :m], sc[1, :m], sc[2, :m], good[:m])

    @njit
    def d_reset(n, sc):  # each rotation driver starts every block from the same unit vectors
        for k0 in range(0, n, bl):
            sc[0, :], sc[1, :], sc[2, :] = sc[13, :], sc[14, :], sc[15, :]

    @njit
    def d_mul_T(R, n, sc):
        for k0 in range(0, n, bl):
            sc[0, :], sc[1, :], sc[2, :] = sc[13, :], sc[14, :], sc[15, :]
            F._mul_T_block(R, sc[0], sc[1], sc[2])

    @njit
    def d_turn(n, sc):
        for k0 in range(0, n, bl):
            sc[0, :], sc[1, :], sc[2, :] = sc[13, :], sc[14, :], sc[15, :]
            F._turn_back_block(2, sc[16], sc[17], sc[0], sc[1], sc[2])

    @njit
    def d_b2n(n, sc, xyz):
        for k0 in range(0, n, bl):
            xyz[0, :], xyz[1, :], xyz[2, :] = sc[13, :], sc[14, :], sc[15, :]
            F._body_to_ned_block(sc, xyz[0], xyz[1], xyz[2])

    @njit
    def d_hit(sc, xyz, h, th, row, col, w, hh, lever, a_m, b_m, e2, o, d, s, ecef, st):
        for k0 in range(0, h.shape[0], bl):
            k1 = min(h.shape[0], k0 + bl)
            m = k1 - k0
            xyz[0, :], xyz[1, :], xyz[2, :] = sc[13, :], sc[14, :], sc[15, :]
            F._hit_block(
                sc[:, :m], xyz[0, :m], xyz[1, :m], xyz[2, :m], sc[12, :m], h[k0:k1], th[k0:k1], row[k0:k1],
                col[k0:k1], True, w, hh, lever, a_m, b_m, e2, o[k0:k1], d[k0:k1], s[k0:k1], ecef[k0:k1],
                st[k0:k1], xyz[3, :m], xyz[4, :m], xyz[5, :m],
            )  # fmt: skip

    @njit
    def d_geo(ecef, a_m, e2, st, lat, lon, h, good, xyz):
        for k0 in range(0, lat.shape[0], bl):
            k1 = min(lat.shape[0], k0 + bl)
            m = k1 - k0
            xyz[0, :m], xyz[1, :m], xyz[2, :m] = ecef[k0:k1, 0], ecef[k0:k1, 1], ecef[k0:k1, 2]
            F._geodetic_block(
                xyz[0, :m], xyz[1, :m], xyz[2, :m], a_m, e2, st[k0:k1], lat[k0:k1], lon[k0:k1], h[k0:k1], good[:m]
            )

    def med(fn):
        fn()  # compile
        cpu = []
        for _ in range(repeat):
            c = time.process_time()
            fn()
            cpu.append(time.process_time() - c)
        return float(np.median(cpu)) * 1e9 / n

    for name, (sensor, pose, rows, cols) in (("q17 pinhole", make_rays(n, rng)), ("turret", make_turret_rays(n, rng))):
        s = as_sensor(sensor)
        nj = len(s.angle_names)
        mount = not np.array_equal(s.R_base_body, np.eye(3))
        _, _, _, ecef, _, st, *_ = F.locate_fast(pose, s, rows, cols, 0.0)
        sc = np.zeros((18, bl))  # sines and cosines of attitude, lat, lon (rows 0-9), then scratch
        ang = rng.uniform(-0.2, 0.2, (5, bl))
        ang[3], ang[4] = pose.lat[:bl], pose.lon[:bl]
        sc[0:10:2], sc[1:10:2] = np.sin(ang), np.cos(ang)
        sc[12] = 1.0  # valid
        dn = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])  # a look down, 13 deg off nadir
        sc[13:16] = dn[:, None]
        sc[16], sc[17] = np.sin(ang[0]), np.cos(ang[0])
        xyz = np.empty((6, bl))
        good = np.empty(bl, dtype=np.bool_)
        th = np.zeros(n)
        ranges = np.array([pose.RANGES[k] for k in ("lat", "lon", "h", "heading", "pitch", "roll")], dtype=float)
        lp = F._lens_vector(s.lens)
        outs = [np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty(n, np.uint8)]
        geo = [np.empty(n) for _ in range(3)]
        lever = np.array(s.lever_arm_m, float)
        w, hh = float(s.lens.width), float(s.lens.height)
        cost = {
            f"sines and cosines (x {5 + nj})": (5 + nj) * med(lambda: d_sincos(pose.heading, sc)),
            "valid (pose, pixel ranges)": med(
                lambda: d_valid(
                    pose.lat,
                    pose.lon,
                    pose.h,
                    pose.heading,
                    pose.pitch,
                    pose.roll,
                    rows,
                    cols,
                    th,
                    ranges,
                    float(B),
                    sc,
                )
            ),  # fmt: skip
            f"lens inverse ({type(s.lens).__name__})": med(
                lambda: d_unproject(int(s.lens.code), lp, rows, cols, sc, good)
            ),
            f"rotations (x {1 + nj + mount} + attitude)": (1 + mount)
            * med(lambda: d_mul_T(np.ascontiguousarray(s.R_cam_last), n, sc))
            + nj * med(lambda: d_turn(n, sc))
            + med(lambda: d_b2n(n, sc, xyz))
            - (2 + nj + mount) * med(lambda: d_reset(n, sc)),
            "NED->ECEF, lever arm, ray x ellipsoid, status": med(
                lambda: d_hit(sc, xyz, pose.h, th, rows, cols, w, hh, lever, float(A), float(B), float(E2), *outs)
            ),
            "ECEF -> geodetic (Vermeille)": med(lambda: d_geo(ecef, float(A), float(E2), st, *geo, good, xyz)),
        }
        whole = med(lambda: F.locate_fast(pose, s, rows, cols, 0.0))
        full = med(lambda: locate(pose, sensor, rows, cols, target_h=0.0))
        print(f"[hops {name}] CPU ns a ray, one thread, medians of {repeat} over {n} rays:")
        for k, v in cost.items():
            print(f"[hops {name}]   {k:48s} {v:6.1f}")
        print(f"[hops {name}]   {'sum of the hops':48s} {sum(cost.values()):6.1f}")
        print(f"[hops {name}]   {'the whole kernel (locate_fast)':48s} {whole:6.1f}")
        print(f"[hops {name}]   {'locate() (Pipeline, GroundPoint)':48s} {full:6.1f}")
    print(f"load average {os.getloadavg()[0]:.2f}")


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
    ap.add_argument("--hops", action="store_true", help="only the per-hop CPU time of the kernel, one thread")
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    if args.ab:
        ab(args.ab, args.rays, args.repeat, rng)
        return
    if args.hops:
        hops(args.rays, args.repeat, rng)
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
