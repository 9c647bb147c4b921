"""Whole frame: every pixel of the 2323 x 2292 [Q17] sensor (5.3 M rays) onto the DEM in one call.

    .venv/bin/python benchmarks/bench_whole_frame.py [--repeat 3] [--embree-rays 262144] [--step K]

The [Q17] camera (assets/cameras/qiao2017.toml) at record T3-1 of
assets/records/qiao2017_flight_tests.csv over the bundled DEM that covers it
(assets/dem/etopo5_flight_area.tif). Prints medians of wall and CPU time, rays/s,
the peak of traced (numpy) memory of one call and its chunk, and two peers measured
in the same run (``--step K``: every K-th pixel in both directions, for a quick check; the
figures are the whole frame's at the default, K = 1):

* the numpy path: ``sensor.line_of_sight`` on the whole pixel grid, then the same
  exact DEM solver (``intersect_dem(..., "exact", parallel=True)``), in the same chunks;
* trimesh/embree casting a subsample of the same rays on the DEM's mesh, against
  ``locate_frame``'s solver in triangle mode on the same rays (rays per CPU second).

Run it on an idle machine for the 5 s figure: wall time on a shared, loaded machine
measures the other processes too (the CPU time does not).
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import timed

from geoloc.io.records import load_records
from geoloc.sensors.sensor_file import load_sensor
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import DemSurface, intersect_dem
from geoloc.workflows.ortho import DEFAULT_CHUNK, frame_pixels, locate_frame

ROOT = Path(__file__).resolve().parents[1]


def numpy_frame(sensor, pose, dem, chunk=DEFAULT_CHUNK, step=1):
    """The peer: numpy line of sight per block of rows, the same DEM solver."""
    rows, cols = frame_pixels(sensor, step)
    per = max(1, chunk // cols.size)
    out = np.empty((rows.size, cols.size))
    for i0 in range(0, rows.size, per):
        R, C = np.meshgrid(rows[i0 : i0 + per], cols, indexing="ij")
        out[i0 : i0 + per] = intersect_dem(sensor.line_of_sight(R, C, pose), dem, "exact", parallel=True).h
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--embree-rays", type=int, default=262144)
    ap.add_argument("--step", type=int, default=1, help="every K-th pixel (default 1: the whole frame)")
    args = ap.parse_args(argv)
    sensor = load_sensor(ROOT / "assets" / "cameras" / "qiao2017.toml")
    pose = load_records(ROOT / "assets" / "records" / "qiao2017_flight_tests.csv").subset([0]).pose()
    dem = DEM.open(ROOT / "assets" / "dem" / "etopo5_flight_area.tif")
    rows, cols = frame_pixels(sensor, args.step)
    n = rows.size * cols.size
    every = "" if args.step == 1 else f", pixel step {args.step}: {rows.size} x {cols.size}"
    print(f"[Q17] sensor {sensor.rows} x {sensor.cols}{every} = {n} rays, record T3-1, DEM {Path(dem.path).name}")
    c0, w0 = time.process_time(), time.perf_counter()
    locate_frame(sensor, pose, dem, step=64)  # compile (or load the numba cache) outside the timing
    print(
        f"first call (compile or cache load): {time.perf_counter() - w0:.1f} s wall, "
        f"{time.process_time() - c0:.1f} s CPU"
    )

    wall, cpu, grid = timed(lambda: locate_frame(sensor, pose, dem, step=args.step), args.repeat)
    counts = grid.counts()
    print(
        f"locate_frame (compiled grid + exact DEM, parallel): wall {wall:.2f} s, CPU {cpu:.2f} s, "
        f"{n / wall / 1e6:.2f} M rays/s wall, {n / cpu / 1e6:.2f} M rays/s per CPU s; {counts}"
    )
    tracemalloc.start()
    locate_frame(sensor, pose, dem, step=args.step)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    answer = sum(a.nbytes for a in (grid.lat, grid.lon, grid.h, grid.status))
    print(
        f"peak traced memory {peak / 1e6:.0f} MB: the answer {answer / 1e6:.0f} MB + "
        f"{(peak - answer) / 1e6:.0f} MB of temporaries for chunks of {DEFAULT_CHUNK} rays "
        f"({min(DEFAULT_CHUNK // cols.size, rows.size)} image rows)"
    )

    w_np, c_np, h_np = timed(lambda: numpy_frame(sensor, pose, dem, step=args.step), args.repeat)
    same = np.array_equal(np.isnan(h_np), np.isnan(grid.h))
    dh = float(np.nanmax(np.abs(h_np - grid.h)))
    print(
        f"peer, numpy line of sight + the same solver: wall {w_np:.2f} s, CPU {c_np:.2f} s; "
        f"ratio {w_np / wall:.2f}x wall, {c_np / cpu:.2f}x CPU; same NaNs {same}, max |dh| {dh:.1e} m"
    )

    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError:  # pragma: no cover
        print("trimesh/embree peer skipped: pip install embreex")
        return 0
    from geoloc.workflows.ortho import frame_line_of_sight

    rng = np.random.default_rng(5)
    k = min(args.embree_rays, n)
    los_all = frame_line_of_sight(sensor, pose, rows, cols)
    pick = rng.choice(n, k, replace=False)
    o = np.ascontiguousarray(np.broadcast_to(los_all.origin_ecef, (rows.size, cols.size, 3)).reshape(-1, 3)[pick])
    d = los_all.direction_ecef.reshape(-1, 3)[pick]
    from geoloc.surfaces.base import LineOfSight

    los = LineOfSight(o, d, np.zeros(k, np.uint8))
    mesh = dem.to_trimesh()
    fr = mesh.metadata["enu_frame"]
    tri = DemSurface(dem, "exact", "triangles", parallel=True)
    w_t, c_t, hit = timed(lambda: tri.intersect(los), args.repeat)
    oe, de = fr.from_ecef(o), fr.vector_from_ecef(d)
    inter = RayMeshIntersector(mesh)
    inter.intersects_location(oe[:10], de[:10], multiple_hits=False)  # build the BVH outside the timing
    w_e, c_e, (loc, idx, _) = timed(lambda: inter.intersects_location(oe, de, multiple_hits=False), args.repeat)
    err = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1).max() if len(idx) else float("nan")
    ok = int((hit.status == Status.OK).sum())
    print(
        f"peer, trimesh/embree on {k} of the same rays (DEM mesh): wall {w_e:.3f} s, CPU {c_e:.3f} s "
        f"({k / c_e / 1e6:.2f} M rays per CPU s); ours in triangle mode: wall {w_t:.3f} s, CPU {c_t:.3f} s "
        f"({k / c_t / 1e6:.2f} M rays per CPU s); ratio {c_e / c_t:.2f}x per CPU s; hits {ok} vs {len(idx)}, "
        f"max distance {err:.1e} m"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
