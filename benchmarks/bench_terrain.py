"""Terrain solvers: DEM evaluations per ray, and exact solver vs trimesh ray casting.

    python benchmarks/bench_terrain.py [--rays 10000] [--repeat 5]

(a) On 10 000 oblique rays (frame angle 45-82 deg) over the SRTM Jacksboro crop:
    DEM evaluations per ray of the descending steps [Q17] (step eps_h) and the
    bisection [L23] (threshold), both at 1/10, 1/2 and 1 DEM cell (the cell's mean
    horizontal size in metres, as a height), and cells visited by the exact solver.
    [L23] claims 45.5 % fewer iterations for bisection than for steps.
(b) Rays per second: the exact solver in triangle mode vs trimesh's ray cast
    (embree backend when embreex is installed) on the same rays and mesh, in the
    same run, after warm-up (numba compiled, BVH built; build times printed apart),
    the two called in turn (the machine's load swings within a minute).
    trimesh's embree cast runs on one thread (its wall and CPU times agree); the
    ``parallel`` exact row uses numba's threads (compare its wall column).
    The hits must be identical (to the float64 rounding of the walk's fused multiply-adds,
    ~1e-7 m; embree's float32 edge test can differ on a ray that passes within a few
    millimetres of an edge, which the bench counts, and each such ray is judged by
    ``geoloc.surfaces.referee``: pyproj's vertices, extended precision). Wall time and
    process CPU time are both printed; the last line ``ratio: X`` is exact rays per CPU
    second over trimesh's.
(c) ``--size N`` (``--big``: N = 3601, one 1-arc-second SRTM tile; 1801 for a quicker
    check): the same comparison on an N x N DEM made by resampling the crop bilinearly
    over the same area plus seeded Gaussian roughness (3 m), ``--big-rays`` (100 000)
    oblique rays: rays per CPU second of both, hits compared (with trimesh, and bit for
    bit with the walk without its levels above the blocks), setup times (exact: tables;
    trimesh: mesh + BVH) and memory (peak RSS over the process's RSS before the build,
    from ru_maxrss; the exact tables are built first, so each peak is its own; numpy's
    share of the exact one by tracemalloc too). Embree's 3601 mesh takes 70 s and 7.7 GB.

    python benchmarks/bench_terrain.py --big            # (a), (b) and (c) at 3601
    python benchmarks/bench_terrain.py --size 1801 --skip-small
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import time
import tracemalloc

import numpy as np

from geoloc.assets import asset_path
from geoloc.geodesy.ellipsoid import A
from geoloc.status import Status
from geoloc.surfaces import terrain
from geoloc.surfaces.dem import DEM, upsampled_dem
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

SRTM = asset_path("dem", "srtm_jacksboro.tif")  # $GEOLOC_ASSETS, the package data or assets/


def median_time(fn, repeat):
    """Median wall time and median process CPU time [s] of ``repeat`` calls.

    On a shared machine the wall time swings with other processes' load; the
    CPU time (all threads of this process) is the steadier measure of work.
    """
    ts, cs = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    return statistics.median(ts), statistics.median(cs)


def median_times_alternating(fns, repeat):
    """:func:`median_time` of each of ``fns``, called in turn within each repetition.

    The load from other processes swings by tens of per cent within a minute on
    this machine; alternating the calls gives the exact solver and trimesh the
    same conditions, so that their ratio does not depend on when each ran.
    """
    ts = [[] for _ in fns]
    cs = [[] for _ in fns]
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t, c = time.perf_counter(), time.process_time()
            fn()
            ts[k].append(time.perf_counter() - t)
            cs[k].append(time.process_time() - c)
    return [(statistics.median(a), statistics.median(b)) for a, b in zip(ts, cs)]


def _rss():
    """The process's resident set size now [bytes] (/proc/self/statm)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _peak_rss():
    """The process's peak resident set size so far [bytes] (ru_maxrss is in kB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def referee_report(dem, los, hit, mesh, loc, idx, tri):
    """The rays where the exact walk and trimesh/embree land more than 1 mm apart, each judged
    by :mod:`geoloc.surfaces.referee` (pyproj vertices, Moller-Trumbore in extended precision,
    every triangle around both hits): one line saying whose hit it finds, and for embree's
    triangle how far the ray passes outside it, or that it lies beyond the walk's hit."""
    from geoloc.surfaces.referee import judge, referee_triangle

    fr = mesh.metadata["enu_frame"]
    diff = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
    bad = np.nonzero(diff > 1e-3)[0]
    o, d, ecef = los.origin_ecef.reshape(-1, 3), los.direction_ecef.reshape(-1, 3), hit.ecef.reshape(-1, 3)
    nc = dem.shape[1]
    verdicts = {"a": 0, "b": 0, "both": 0, "neither": 0}
    outside_mm, beyond = [], 0
    for k in bad:
        r = idx[k]
        v, ref = judge(dem, o[r], d[r], ecef[r], fr.to_ecef(loc[k]))
        verdicts[v] += 1
        theirs = referee_triangle(dem, o[r], d[r], [divmod(int(q), nc) for q in mesh.faces[tri[k]]])
        if theirs.inside_m < 0:
            outside_mm.append(-theirs.inside_m * 1e3)
        elif np.isfinite(ref.range_m) and theirs.range_m > ref.range_m:
            beyond += 1
    line = (
        f"rays more than 1 mm apart: {len(bad)} of {len(idx)} hits (max {diff.max():.2e} m); the referee "
        f"(pyproj vertices, extended precision) finds the exact walk's hit on {verdicts['a']}, "
        f"embree's on {verdicts['b']}, neither on {verdicts['neither']}"
    )
    if len(bad):
        line += (
            f"; embree's triangle: missed by the ray on {len(outside_mm)}"
            + (f" (by {min(outside_mm):.2f}-{max(outside_mm):.2f} mm)" if outside_mm else "")
            + f", beyond the walk's hit (embree missed that one) on {beyond}"
        )
    return line


def big_case(n, rays, repeat, seed):
    """(c): the exact walk against trimesh/embree on an n x n upsampled DEM."""
    src = DEM.open(SRTM)
    dem = upsampled_dem(src, n, np.random.default_rng(seed))
    los = random_oblique_rays(dem, rays, np.random.default_rng(seed + 1), frame_angle_deg=(45.0, 82.0))
    g = dem.grid
    print(
        f"\n(c) {n} x {n} nodes ({(n - 1) ** 2 * 2 / 1e6:.0f} M triangles), the crop resampled plus 3 m "
        f"roughness (seed {seed}), cell {g.dlat_deg * 3600:.2f} x {g.dlon_deg * 3600:.2f} arc seconds; "
        f"{rays} rays, frame angle 45-82 deg"
    )
    # exact first: its peak is then its own (ru_maxrss only grows)
    rss0 = _rss()
    tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    terrain._exact_tables(dem)
    t_tab, c_tab = time.perf_counter() - t0, time.process_time() - c0
    intersect_dem(los, dem, "exact", dem_model="triangles")  # compiled code from the cache, one walk
    t_first = time.perf_counter() - t0
    _, tm_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    mem_ex = _peak_rss() - rss0
    # trimesh / embree
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    rss1 = _rss()
    t0, c0 = time.perf_counter(), time.process_time()
    mesh = dem.to_trimesh()
    fr = mesh.metadata["enu_frame"]
    caster = RayMeshIntersector(mesh)
    O = fr.from_ecef(los.origin_ecef)
    D = fr.vector_from_ecef(los.direction_ecef)
    caster.intersects_location(O[:10], D[:10], multiple_hits=False)  # builds the BVH
    t_build, c_build = time.perf_counter() - t0, time.process_time() - c0
    mem_tm = _peak_rss() - rss1

    def run_tm():
        return caster.intersects_location(O, D, multiple_hits=False)

    def run_ex():
        return intersect_dem(los, dem, "exact", dem_model="triangles")

    (t_tm, t_ex) = median_times_alternating((run_tm, run_ex), repeat)
    loc, idx, tri = run_tm()
    hit = run_ex()
    climb = terrain.CLIMB_FROM
    try:
        terrain.CLIMB_FROM = 10**6  # no level above the blocks: the two-level walk
        two = intersect_dem(los, dem, "exact", dem_model="triangles")
    finally:
        terrain.CLIMB_FROM = climb
    okx = hit.status == Status.OK
    hit_tm = np.zeros(len(okx), bool)
    hit_tm[idx] = True
    diff = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
    n_two = int(
        np.sum(
            (two.status != hit.status)
            | np.any(~((two.ecef == hit.ecef) | (np.isnan(two.ecef) & np.isnan(hit.ecef))), -1)
        )
    )
    print(
        f"setup: exact tables {t_tab:.2f} s wall ({c_tab:.2f} s CPU), first call with them {t_first:.2f} s; "
        f"trimesh mesh + BVH {t_build:.2f} s wall ({c_build:.2f} s CPU); exact / trimesh "
        f"{t_tab / t_build:.3f} (goal <= 0.1)"
    )
    print(
        f"memory (peak RSS over RSS before the build): exact {mem_ex / 1e6:,.0f} MB (numpy, tracemalloc: "
        f"{tm_peak / 1e6:,.0f} MB), trimesh/embree {mem_tm / 1e6:,.0f} MB; exact / trimesh "
        f"{mem_ex / max(mem_tm, 1):.3f} (goal <= 0.25)"
    )
    print(f"{'':28s} {'wall':>14s} {'per CPU second':>16s}")
    for name, (tw, tc) in (("trimesh ray cast", t_tm), ("exact, triangles", t_ex)):
        print(f"{name:28s} {rays / tw:9,.0f} rays/s {rays / tc:10,.0f} rays/s")
    print(
        f"cells or nodes visited per ray: {hit.dem_evaluations.mean():.2f} "
        f"(without the levels above the blocks {two.dem_evaluations.mean():.2f})"
    )
    print(
        f"same rays hit as trimesh: {np.array_equal(okx, hit_tm)} ({int((okx != hit_tm).sum())} differ); "
        f"max |exact - trimesh| = {diff.max():.2e} m"
    )
    print(f"rays whose status or hit differs from the two-level walk's (bit for bit): {n_two}")
    print(referee_report(dem, los, hit, mesh, loc, idx, tri))
    print(f"big ratio (CPU time, exact triangles over trimesh; goal >= 1.5): {t_tm[1] / t_ex[1]:.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=0, help="also run (c) on an N x N upsampled DEM")
    ap.add_argument("--big", action="store_true", help="--size 3601 (one SRTM 1-arc-second tile)")
    ap.add_argument("--big-rays", type=int, default=100_000)
    ap.add_argument("--big-repeat", type=int, default=3)
    ap.add_argument("--skip-small", action="store_true", help="only (c)")
    a = ap.parse_args(argv)
    size = 3601 if a.big else a.size
    if not a.skip_small:
        small_case(a)
    if size:
        big_case(size, a.big_rays, a.big_repeat, a.seed)


def small_case(a):
    dem = DEM.open(SRTM)
    los = random_oblique_rays(dem, a.rays, np.random.default_rng(a.seed), frame_angle_deg=(45.0, 82.0))
    g = dem.grid
    lat_mid = np.deg2rad(0.5 * (g.lat_north_deg + g.lat_south_deg))
    cell_m = 0.5 * np.deg2rad(g.dlat_deg) * A + 0.5 * np.deg2rad(g.dlon_deg) * A * np.cos(lat_mid)
    print(
        f"DEM {SRTM.name}: {dem.shape[0]} x {dem.shape[1]} nodes, cell ~ {cell_m:.1f} m, "
        f"heights {dem.min_height():.0f}..{dem.max_height():.0f} m (ellipsoidal); {a.rays} rays, "
        "frame angle 45-82 deg, camera 1500 m above the aimed point"
    )

    # ---------------------------------------------------------------- (a) evaluations per ray
    ex = intersect_dem(los, dem, "exact")
    ok = ex.status == Status.OK
    print(f"\n(a) DEM evaluations per ray (mean over the {ok.sum()} rays that hit)")
    print(f"exact (bilinear): {ex.dem_evaluations[ok].mean():.2f} cells or blocks visited per ray")
    for frac in (0.1, 0.5, 1.0):
        thr = frac * cell_m
        st = intersect_dem(los, dem, "steps", eps_h=thr)
        bi = intersect_dem(los, dem, "bisect", threshold=thr)
        both = ok & (st.status == Status.OK) & (bi.status == Status.OK)
        ns, nb = st.dem_evaluations[both].mean(), bi.dem_evaluations[both].mean()
        print(
            f"{frac:>4} cell ({thr:6.1f} m): steps {ns:7.2f}  bisect {nb:6.2f}  "
            f"-> bisection {100 * (1 - nb / ns):5.1f} % fewer; "
            f"bisection hidden (not the first crossing) on {bi.hidden[both].mean() * 100:.1f} % of rays; "
            f"median |h - exact|: steps {np.median(np.abs(st.h - ex.h)[both]):.2f} m, "
            f"bisect {np.median(np.abs(bi.h - ex.h)[both]):.2f} m"
        )

    # ---------------------------------------------------------------- (b) rays per second

    t0 = time.perf_counter()
    mesh = dem.to_trimesh()
    fr = mesh.metadata["enu_frame"]
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        backend = "embree (embreex)"
    except ImportError:  # pragma: no cover
        from trimesh.ray.ray_triangle import RayMeshIntersector

        backend = "pure python (slow; install embreex)"
    caster = RayMeshIntersector(mesh)
    O = fr.from_ecef(los.origin_ecef)
    D = fr.vector_from_ecef(los.direction_ecef)
    caster.intersects_location(O[:10], D[:10], multiple_hits=False)  # builds the BVH
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    intersect_dem(los, dem, "exact", dem_model="triangles")  # numba warm-up (cache) + tables
    t_warm = time.perf_counter() - t0

    def run_tm():
        return caster.intersects_location(O, D, multiple_hits=False)

    def run_ex():
        return intersect_dem(los, dem, "exact", dem_model="triangles")

    t_tm, t_ex = median_times_alternating((run_tm, run_ex), a.repeat)
    t_bl = median_time(lambda: intersect_dem(los, dem, "exact"), a.repeat)
    t_par = median_time(lambda: intersect_dem(los, dem, "exact", dem_model="triangles", parallel=True), a.repeat)
    loc, idx, tri = run_tm()
    hit = run_ex()
    hit_par = intersect_dem(los, dem, "exact", dem_model="triangles", parallel=True)
    try:
        import numba

        layer = f"numba threads: {numba.get_num_threads()}, layer {numba.threading_layer()}"
    except ValueError:  # the parallel kernel never started its threads
        layer = "numba threads never started"
    okx = hit.status == Status.OK
    hit_tm = np.zeros(len(okx), bool)
    hit_tm[idx] = True
    diff = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
    print(f"\n(b) rays per second on {a.rays} rays (median of {a.repeat}); trimesh backend: {backend}")
    print(f"setup: trimesh mesh + BVH {t_build:.2f} s; exact first call (tables, compiled code) {t_warm:.2f} s")
    print(f"{'':28s} {'wall':>14s} {'per CPU second':>16s}")
    for name, (tw, tc) in (
        ("trimesh ray cast", t_tm),
        ("exact, triangles", t_ex),
        ("exact, triangles, parallel", t_par),
        ("exact, bilinear", t_bl),
    ):
        print(f"{name:28s} {a.rays / tw:9,.0f} rays/s {a.rays / tc:10,.0f} rays/s")
    print(
        f"same rays hit: {np.array_equal(okx, hit_tm)}; max |exact - trimesh| = {diff.max():.2e} m "
        "(embree tests in float32: a ray that passes within millimetres of an edge can land elsewhere)"
    )
    same_par = np.array_equal(hit_par.status, hit.status) and np.array_equal(hit_par.ecef[okx], hit.ecef[okx])
    if backend.startswith("embree"):
        print(referee_report(dem, los, hit, mesh, loc, idx, tri))
    print(f"parallel identical to serial: {same_par} ({layer})")
    print(f"wall-time ratio: {t_tm[0] / t_ex[0]:.2f}")
    print("ratio (CPU time, serial exact triangles over trimesh; steadier on a shared machine):")
    print(f"ratio: {t_tm[1] / t_ex[1]:.2f}")


if __name__ == "__main__":
    main()
