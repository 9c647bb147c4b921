"""The exact DEM walk alone, this tree's against git revision REV's, on the same rays and tables.

    python benchmarks/bench_walk_ab.py REV [--size N] [--repeat K] [--dem-model bilinear]

``--size 0`` (default) is the bundled SRTM crop with 10 000 oblique rays; ``--size N``
the crop resampled to N x N nodes plus 3 m roughness (as ``bench_terrain.py --size``) with
100 000 rays, frame angle 45-82 deg. REV's ``geoloc/surfaces/terrain_numba.py`` is loaded
from ``git show`` as a scratch module and compiled in this process (a cold compile: tens of
seconds); both walks get this tree's tables (REV's walk without ``hinv``/``hlev`` if it
predates the hierarchy, and block tables of 8 cells if it predates the block side of
``terrain.block_cells``). The rays are walked in the order given, not in ``ray_order``'s
(which REV may not take): on a large DEM that is slower than ``intersect_dem`` (0.82x on
3601 x 3601), and a change that helps sorted rays may not show here. Four rows, calls in
turn (the machine's load swings), medians of CPU time per ray, one thread: REV's walk (with
the levels from ``terrain.CLIMB_FROM`` where it has them); REV's with none; this tree's with
the levels (the climbing kernel), against REV's; this tree's with none (the ``"flat"`` walk of
``terrain_numba.KERNELS``, ``"flat_block"`` for blocks other than 8 cells), against REV's with none.
Each row says whether its statuses and hits equal REV's bit for bit, and if not, whether the
statuses do and how far apart the hits are. ``--dem-model``: the cell model walked,
``triangles`` (default, as ``bench_terrain.py``) or ``bilinear`` (what ``locate`` and
``replay`` use by default). Measures what the walk costs; ``bench_terrain.py`` compares it
with embree.

``--placement ORDER`` (e.g. ``AMB``, ``MAB``) measures instead how the process's load order moves
the same walk's speed (docs/terrain.md, seventh round): the flat walk of this tree's
``terrain_numba.KERNELS`` (A), the same source compiled afresh inside ``terrain_numba`` with its
helpers (B, ``numba.njit``, no cache), and REV's whole ``terrain_numba.py`` loaded as a scratch
module (M, with helpers of its own, as the rows above load REV; pass ``HEAD`` for the same code),
loaded in ORDER, then called in rotated turn, CPU medians, outputs compared bit for bit with A's.

``--same-build``: when REV's ``terrain_numba.py`` is this tree's byte for byte, REV's rows call
this tree's compiled walk instead of compiling the scratch copy (two cold compiles: about 50 s
of CPU). Every row, table and comparison still runs and is measured, but both sides are then
one machine code, so the ratios show only the calls' noise, not the placement a second copy
gets; a line says so. For the tiny run of ``tests/project/test_benchmarks_run.py``; a REV
that differs is compiled as without the flag.
"""

from __future__ import annotations

import argparse
import inspect
import time
from pathlib import Path

import numpy as np
from _revision import module_at  # benchmarks/ is on sys.path when run as a script
from bench_terrain import SRTM

from geoloc.surfaces import terrain
from geoloc.surfaces import terrain_numba as tn
from geoloc.surfaces.dem import DEM, upsampled_dem
from geoloc.surfaces.terrain import _MARGIN_M, random_oblique_rays


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev")
    ap.add_argument("--size", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=11)
    ap.add_argument("--dem-model", choices=("triangles", "bilinear"), default="triangles")
    ap.add_argument("--placement", default="", help="load order of A, B, M (see the module docstring)")
    ap.add_argument(
        "--same-build", action="store_true", help="REV identical to this tree: call this tree's walk for both"
    )
    a = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    if a.placement:
        placement(a)
        return
    old = module_at(a.rev, "geoloc/surfaces/terrain_numba.py")
    if a.same_build and Path(old.__file__).read_bytes() == Path(tn.__file__).read_bytes():
        print(f"--same-build: {a.rev}'s terrain_numba.py is this tree's; its rows call this tree's compiled walk")
        old = tn
    dem = DEM.open(SRTM) if a.size == 0 else upsampled_dem(DEM.open(SRTM), a.size, np.random.default_rng(0))
    los = random_oblique_rays(
        dem, 10_000 if a.size == 0 else 100_000, np.random.default_rng(1), frame_angle_deg=(45.0, 82.0)
    )
    o = np.ascontiguousarray(los.origin_ecef.reshape(-1, 3))
    d = np.ascontiguousarray(los.direction_ecef.reshape(-1, 3))
    t = terrain._exact_tables(dem)
    n = len(o)
    head = (o, d, t["h_max"] + _MARGIN_M, t["h_floor"], t["hgt"], t["lon_col"], t["cinv"], t["binv"])
    old_block = hasattr(old, "WalkGrid") or "block" in inspect.signature(old.walk).parameters
    old_hinv, old_hlev = t["hinv"], t["hlev"]
    if not old_block and t["block"] != 8:
        # REV's walk has blocks of 8 cells built in: its block tables are made for that side
        b8, old_hinv, old_hlev = terrain._block_tables(dem.cell_max(), 8, t["h_floor"])
        head_old8 = head[:7] + (b8,)
    else:
        head_old8 = head
    if {k: v for k, v, _ in getattr(old, "_IN", ())}.get("binv", np.float64) != np.float32:
        # REV's walk reads absolute (1/(a+H)^2, 1/(b+H)^2): binv in float64, cinv float32 rounded
        # toward zero (a larger ellipsoid), decoded from this tree's offsets (terrain._offsets32)
        ref = terrain._floor_inv(t["h_floor"])
        c64 = ref + t["cinv"].astype(float)
        c32 = c64.astype(np.float32)
        up = c32.astype(float) > c64
        c32[up] = np.nextafter(c32[up], np.float32(0))
        old_head = head_old8[:6] + (c32, ref + head_old8[7].astype(float))
    else:
        old_head = head_old8
    tail = (
        t["row_geo"],
        t["lat_n"],
        t["lon_w"],
        t["dlat"],
        t["dlon"],
        t["tan_row"],
        t["c_row"],
        t["sin_col"],
        t["cos_col"],
        a.dem_model == "triangles",
    )
    old_has_levels = hasattr(old, "WalkGrid") or "hinv" in inspect.signature(old.walk).parameters

    def outs():
        return (
            np.empty(n),
            np.empty((n, 3)),
            np.empty((n, 4)),
            np.zeros(n, np.uint8),
            np.empty(n, np.int64),
            np.full((n, 0), np.nan),
            np.full((n, 0, 2), -1, np.int64),
        )

    def run(walk, hlev, levels_arg=True, head=head, hinv=t["hinv"], **kw):
        r = outs()
        walk(*head, *((hinv, hlev) if levels_arg else ()), *tail, *r, **kw)
        return r

    grid = terrain.walk_grid(t, climb=False)

    def run_record(mod, hlev):
        """A walk that takes its tables as one record (this tree's; REV's from the record on)."""
        out = mod.walk_outputs(np.zeros(n, np.uint8))
        mod.walk(o, d, mod.WalkGrid(*grid._replace(hlev=hlev)), out, a.dem_model == "triangles")
        return out

    blk = {"block": t["block"]}
    rows = {
        f"{a.rev}": lambda: (
            run_record(old, t["hlev"][terrain.CLIMB_FROM - 1 :])
            if hasattr(old, "WalkGrid")
            else run(
                old.walk,
                old_hlev[terrain.CLIMB_FROM - 1 :],
                old_has_levels,
                old_head,
                old_hinv,
                **(blk if old_block else {}),
            )
        ),
        f"{a.rev}, flat": lambda: (
            run_record(old, t["hlev"][:0])
            if hasattr(old, "WalkGrid")
            else run(old.walk, old_hlev[:0], old_has_levels, old_head, old_hinv, **(blk if old_block else {}))
        ),
        "this tree, climbing": lambda: run_record(tn, t["hlev"][terrain.CLIMB_FROM - 1 :]),
        "this tree, flat": lambda: run_record(tn, t["hlev"][:0]),
    }
    for f in rows.values():  # compile (or load) first
        f()
    times = {k: [] for k in rows}
    res = {}
    for _ in range(a.repeat):
        for k, f in rows.items():
            c = time.process_time()
            res[k] = f()
            times[k].append(time.process_time() - c)
    ref = res[a.rev]
    # each row against its peer: this tree's flat walk against REV's flat walk, the rest against REV's
    peer = {"this tree, flat": f"{a.rev}, flat"}
    print(
        f"{'DEM: crop' if a.size == 0 else f'DEM: {a.size} x {a.size}'}, {a.dem_model}, {n} rays, "
        f"{a.repeat} calls each in turn, one thread, median CPU time"
    )
    for k in rows:
        same = np.array_equal(res[k][3], ref[3]) and np.array_equal(res[k][1], ref[1], equal_nan=True)
        p = peer.get(k, a.rev)
        diff = ""
        if not same:  # how far from REV's: the statuses, and the largest hit apart (ECEF, m)
            both = (res[k][3] == ref[3]) & np.isfinite(res[k][1][:, 0]) & np.isfinite(ref[1][:, 0])
            dp = np.abs(res[k][1][both] - ref[1][both]).max() if both.any() else 0.0
            diff = f" (statuses equal: {np.array_equal(res[k][3], ref[3])}, hits within {dp:.1e} m)"
        print(
            f"{k:22s} {np.median(times[k]) * 1e9 / n:8.1f} ns a ray   "
            f"{np.median(times[k]) / np.median(times[p]):5.3f} of {p:12s}   identical to {a.rev}: {same}{diff}"
        )


def placement(a) -> None:
    """The same flat walk loaded three ways, in the order ``a.placement`` (module docstring)."""
    import os
    import statistics

    import numba

    dem = DEM.open(SRTM) if a.size == 0 else upsampled_dem(DEM.open(SRTM), a.size, np.random.default_rng(0))
    los = random_oblique_rays(
        dem, 10_000 if a.size == 0 else 100_000, np.random.default_rng(1), frame_angle_deg=(45.0, 82.0)
    )
    o = np.ascontiguousarray(los.origin_ecef.reshape(-1, 3))
    d = np.ascontiguousarray(los.direction_ecef.reshape(-1, 3))
    grid = terrain.walk_grid(terrain._exact_tables(dem), climb=False)
    tri = a.dem_model == "triangles"
    n = len(o)
    mods, kernels = {}, {}
    for c in a.placement:
        if c == "A":
            mods[c], kernels[c] = tn, tn._kernel_for(grid.hlev, grid.blk, tri)
        elif c == "B":
            fresh = tn._variant(tn._walk, "_walk_fresh", False, tn.BLOCK if grid.blk == tn.BLOCK else 0, tri)
            mods[c], kernels[c] = tn, numba.njit(error_model="numpy", fastmath={"contract"}, nogil=True)(fresh)
        elif c == "M":
            m = module_at(a.rev, "geoloc/surfaces/terrain_numba.py")
            mods[c], kernels[c] = m, m._kernel_for(grid.hlev, grid.blk, tri)
        else:
            raise SystemExit(f"--placement: letters A, B, M only, got {c!r}")

    def run(c):
        m = mods[c]
        out = m.walk_outputs(np.zeros(n, np.uint8))
        _, (rays, g, out), _ = m._prepare(o, d, m.WalkGrid(*grid), out, tri)
        kernels[c](rays, g, out)
        return out

    for c in mods:  # compile or load, in the order given
        run(c)
    names = list(mods)
    times = {c: [] for c in names}
    res = {}
    for r in range(a.repeat):
        for c in names[r % len(names) :] + names[: r % len(names)]:
            t0 = time.process_time()
            res[c] = run(c)
            times[c].append(time.process_time() - t0)
    base = names[0]
    print(
        f"placement: load order {a.placement}, {'crop' if a.size == 0 else a.size}, {a.dem_model}, flat, {n} rays, "
        f"{a.repeat} calls each in rotated turn, one thread, load {os.getloadavg()[0]:.1f}"
    )
    for c in names:
        same = all(
            np.array_equal(getattr(res[c], f), getattr(res[base], f), equal_nan=True)
            for f in ("status", "ncell", "p_out", "geo_out", "s_out")
        )
        med = statistics.median(times[c])
        print(
            f"{c}: {med * 1e9 / n:7.1f} ns a ray   {med / statistics.median(times[base]):.3f} of {base}   "
            f"identical to {base}: {same}"
        )


if __name__ == "__main__":
    main()
