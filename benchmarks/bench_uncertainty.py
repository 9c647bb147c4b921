"""Predicted uncertainty per second (geoloc.analysis.uncertainty.propagate) against `locate` in the same run.

Every point has its own pose and pixel (an azimuth-elevation turret with a Brown lens, a mount,
a boresight and a lever arm, as bench_locate's), and a full budget: position, attitude, both
joints, mount, boresight, lever arm, four lens parameters, time (with a velocity) and the
surface's vertical error: 21 sources. ``propagate`` locates the points itself (the fused locate
kernel on the ellipsoid; the compiled line of sight and the DEM solver on a DEM), then builds the
analytic Jacobian, the covariance, the ellipse and the exact CE90 in numba kernels
(``geoloc.analysis._fastuncert``). ``locate`` is the compiled pixel -> ground path on the same rays.

Run: ``python benchmarks/bench_uncertainty.py [--points N] [--repeat K] [--dem] [--threads T] [--jacobian]``. Prints
medians of wall and CPU time, points per second of each, and ``ratio: X`` = propagation points
per CPU second over locate's rays per CPU second (the goal: >= 0.25, on the DEM too), then the same in wall time.
``--dem`` also times both on the bundled SRTM crop (exact DEM solver). ``--breakdown`` first times
the parts of a point on the ellipsoid (its location, the chain kernel's frames alone, the angle,
position and lever-arm sources, the lens sources, all of them, and the fused chain-and-surface
kernel), each alone with its outputs allocated once, so that where the time goes is measured.
``propagate`` is timed as the replay calls it, without the per-point Jacobian (its default);
``--jacobian`` also times it with ``jacobian=True``.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from _timing import timed  # benchmarks/_timing.py

from geoloc.analysis.uncertainty import propagate
from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.locate import locate
from geoloc.sensors.budget import ErrorBudget
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import HeightSurface
from geoloc.surfaces.terrain import DemSurface

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
#: The turret's 1-sigma budget (the guard builds its uncertainty kernel from the same table).
BUDGET_TABLE = {
    "north_m": 2.0,
    "east_m": 2.0,
    "up_m": 3.0,
    "heading_deg": 0.03,
    "pitch_deg": 0.02,
    "roll_deg": 0.02,
    "azimuth_deg": 0.01,
    "elevation_deg": 0.01,
    "mount_x_deg": 0.01,
    "mount_y_deg": 0.01,
    "mount_z_deg": 0.01,
    "boresight_x_deg": 0.01,
    "boresight_y_deg": 0.01,
    "boresight_z_deg": 0.01,
    "lever_arm_x_m": 0.05,
    "fx_px": 2.0,
    "cx_px": 0.5,
    "cy_px": 0.5,
    "k1": 0.001,
    "time_s": 0.005,
    "height_m": 10.0,
    "dem_m": 9.73,
}
BUDGET = ErrorBudget(BUDGET_TABLE)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--dem", action="store_true", help="also on the SRTM crop")
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="numba threads (default: numba's, one per core); 1 measures the kernels' own CPU cost "
        "without the waits of a parallel loop's threads on a loaded machine",
    )
    ap.add_argument("--breakdown", action="store_true", help="time the parts of a point on the ellipsoid first")
    ap.add_argument(
        "--jacobian",
        action="store_true",
        help="also time propagate(..., jacobian=True), which returns each point's (3, k) Jacobian (53 MB "
        "at 100 000 points), beside the default without it",
    )
    a = ap.parse_args()
    if a.threads:
        import numba

        numba.set_num_threads(a.threads)
    n = a.points
    rng = np.random.default_rng(0)
    pose = Pose.from_deg(
        rng.uniform(36.5, 36.68, n),
        rng.uniform(-84.35, -84.15, n),
        rng.uniform(2500, 4000, n),
        rng.uniform(0, 360, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-5, 5, n),
        angles_deg={"azimuth": rng.uniform(0, 360, n), "elevation": rng.uniform(-90, -30, n)},
    )
    row, col = rng.uniform(1, 1080, n), rng.uniform(1, 1920, n)
    vel = np.stack([rng.uniform(-60, 60, n), rng.uniform(-60, 60, n), np.zeros(n)], -1)
    cases = [("ellipsoid", HeightSurface(500.0))]
    if a.dem:
        cases.append(("srtm dem", DemSurface(DEM.open(asset_path("dem", "srtm_jacksboro.tif")))))
    print(
        f"{n} points, {len(BUDGET.sigmas) - 1} sources, {a.repeat} repeats (medians); 2 cores shared, "
        "a loaded machine: the CPU ratio is the steadier figure; load average %.2f" % os.getloadavg()[0]
    )
    if a.breakdown:
        breakdown(pose, row, col, vel, a.repeat)
    for name, surf in cases:
        if name == "ellipsoid":

            def loc():
                return locate(pose, TURRET, row, col, 500.0)
        else:

            def loc():
                return surf.intersect(TURRET.line_of_sight(row, col, pose))

        def prop():
            return propagate(TURRET, pose, row, col, BUDGET, surface=surf, velocity_ned_m_s=vel)

        loc(), prop()  # compile and warm
        wl, cl, _ = timed(loc, a.repeat)
        wp, cp, pu = timed(prop, a.repeat)
        ok = float(np.mean(pu.status == 0))
        print(
            f"[{name}] locate:    {wl * 1e3:8.1f} ms wall {cl * 1e3:8.1f} ms CPU  {n / wl:10.3g} rays/s wall  "
            f"{n / cl:10.3g} rays/CPU s"
        )
        print(
            f"[{name}] propagate: {wp * 1e3:8.1f} ms wall {cp * 1e3:8.1f} ms CPU  {n / wp:10.3g} points/s wall  "
            f"{n / cp:10.3g} points/CPU s  ({ok:.1%} located; median CE90 {np.nanmedian(pu.ce90_m):.1f} m)"
        )
        if a.jacobian:

            def prop_j():
                return propagate(TURRET, pose, row, col, BUDGET, surface=surf, velocity_ned_m_s=vel, jacobian=True)

            prop_j()
            wj, cj, _ = timed(prop_j, a.repeat)
            print(
                f"[{name}] propagate, jacobian=True: {wj * 1e3:8.1f} ms wall {cj * 1e3:8.1f} ms CPU  "
                f"{n / cj:10.3g} points/CPU s  (ratio {cl / cj:.3f})"
            )
        print(f"[{name}] load average {os.getloadavg()[0]:.2f}")
        tag = "" if name == "ellipsoid" else " dem"
        print(f"ratio{tag}: {cl / cp:.3f}")
        print(f"ratio{tag} wall: {wl / wp:.3f}")


def breakdown(pose, row, col, vel, repeat: int) -> None:
    """CPU time of each part of ``propagate`` on the ellipsoid, each alone (outputs allocated once)."""
    from geoloc.analysis import _fastuncert as F
    from geoloc.analysis import uncertainty as U

    s, surf = U.as_sensor(TURRET), HeightSurface(500.0)
    hit, shape, O, D = U._locate_for(s, pose, row, col, surf, "flag")
    n = int(np.prod(shape))
    P = np.ascontiguousarray(np.broadcast_to(hit.ecef, shape + (3,)).reshape(-1, 3))
    t = np.sqrt(np.sum((P - O) ** 2, axis=-1))
    flat = [np.ascontiguousarray(np.broadcast_to(getattr(hit, k), shape).reshape(-1)) for k in ("lat", "lon", "h")]
    status = np.broadcast_to(hit.status, shape).reshape(-1)
    names, before, after = U._chain_inputs(s, pose, BUDGET, vel, shape)
    codes, sig = after[-4], after[-3]
    lens = codes >= F.SRC_LENS

    def chain(sel):
        free = np.empty((n, 3, int(np.sum(sel))))
        aft = after[:-4] + (np.ascontiguousarray(codes[sel]), np.ascontiguousarray(sig[sel])) + after[-2:]
        return lambda: F.chain_kernel(*before, O, D, t, *aft, free)

    sz = float(BUDGET.sigma("height_m"))
    parts = [
        ("the points (the pipeline's fused locate)", lambda: U._locate_for(s, pose, row, col, surf, "flag")),
        ("chain kernel: the frames alone", chain(np.zeros(len(codes), bool))),
        (f"chain kernel: {int(np.sum(~lens))} angle, position, lever-arm sources", chain(~lens)),
        (f"chain kernel: {int(np.sum(lens))} lens sources", chain(lens)),
        (f"chain kernel: all {len(codes)} sources", chain(np.ones(len(codes), bool))),
        (
            "fused chain + surface step + ellipse (outputs new, J kept)",
            lambda: U._height_fused(s, pose, BUDGET, vel, shape, O, D, P, *flat, status, sz),
        ),
    ]
    for what, fn in parts:
        fn()
        w, c, _ = timed(fn, repeat)
        print(f"[breakdown] {what:55s} {c * 1e3:8.1f} ms CPU {w * 1e3:8.1f} ms wall  load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
