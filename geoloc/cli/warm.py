"""``geoloc warm``: compile the kernels the verbs use, once, ahead of their first call.

numba compiles geoloc's terrain walk and camera chain the first time they run on a machine
(5-30 s of CPU on 2 cores, under 500 MB, measured) and caches them in the user's cache folder
(:func:`geoloc.geodesy._nbgeo.cache_dir`), where a reinstall keeps them. A small call walks the
terrain uncompiled (``terrain_numba.PY_WALK_MAX_RAYS``: a one-ray ``locate``, a short ``replay``),
and so does the viewer's first scene (``terrain_numba.uncompiled_budget``), so only a larger
batch (a long replay, a whole frame, a campaign) needs the compiled walk: the last step compiles
it. ``tools/run.sh`` runs this verb
after installing. Each step runs the verb itself on the bundled data, its output swallowed, and
prints what it compiled and how long it took. A warm cache makes every step a few seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time

import numpy as np

from geoloc.cli import VERB_HELP, main
from geoloc.pipeline import Corrections, Pipeline
from geoloc.surfaces.height import HeightSurface


def _large_batch() -> int:
    """The compiled walk a large batch takes: 20 000 oblique rays over the bundled SRTM crop, the
    cell model ``locate`` and ``replay`` use (bilinear), serial and threaded (one kernel)."""

    from geoloc.assets import asset_path
    from geoloc.surfaces.spec import SurfaceSpec
    from geoloc.surfaces.terrain import DemSurface, random_oblique_rays

    dem = SurfaceSpec(dem=str(asset_path("dem", "srtm_jacksboro.tif"))).raster()
    assert dem is not None  # a bundled raster file
    g = Pipeline(None, DemSurface(dem, "exact")).intersect(random_oblique_rays(dem, 20000, np.random.default_rng(0)))
    return 0 if np.any(np.asarray(g.status) == 0) else 1


def _refraction() -> int:
    """The refraction kernels (``--refraction standard``): a ground ray through the pipeline, on a
    height and on the DEM, and a limb ray (``geoloc limb --refraction standard``)."""

    from geoloc.assets import asset_path
    from geoloc.corrections.refraction import STANDARD_REFRACTION
    from geoloc.surfaces.spec import SurfaceSpec
    from geoloc.surfaces.terrain import DemSurface, random_oblique_rays

    dem = SurfaceSpec(dem=str(asset_path("dem", "srtm_jacksboro.tif"))).raster()
    assert dem is not None  # a bundled raster file
    los = random_oblique_rays(dem, 100, np.random.default_rng(0))
    c = Corrections(refraction=STANDARD_REFRACTION)
    ok = [
        np.any(np.asarray(Pipeline(None, surf, c).intersect(los).status) == 0)
        for surf in (HeightSurface(300.0), DemSurface(dem, "exact"))
    ]
    limb = STANDARD_REFRACTION.limb(np.array([6378137.0 + 10e3, -2.3e6, 0.0]), np.array([0.0, 1.0, 0.0]))
    return 0 if all(ok) and np.all(np.isfinite(limb.refracted_tangent_h_m)) else 1


#: The steps: (what it runs, the verb's arguments or a function); paths under the bundled assets.
STEPS = (
    (
        "a one-ray locate (its walk uncompiled): geoloc locate --sensor eo_turret.toml --dem srtm_jacksboro.tif",
        [
            "locate",
            "--sensor",
            "assets/sensors/eo_turret.toml",
            "--lat-deg",
            "36.6",
            "--lon-deg",
            "-84.25",
            "--h-m",
            "2500",
            "--heading-deg",
            "45",
            "--angle",
            "azimuth=90",
            "--angle",
            "elevation=-30",
            "--dem",
            "assets/dem/srtm_jacksboro.tif",
            "--json",
        ],
    ),
    (
        "a records replay: geoloc replay drone_targets.csv --sensor drone_camera.toml --dem srtm_jacksboro.tif",
        [
            "replay",
            "assets/records/drone_targets.csv",
            "--sensor",
            "assets/sensors/drone_camera.toml",
            "--dem",
            "assets/dem/srtm_jacksboro.tif",
        ],
    ),
    ("a KLV replay: geoloc replay example_flight.klv", ["replay", "assets/klv/example_flight.klv"]),
    (
        "the viewer's first scene (its walk uncompiled): geoloc view --export (the scene geoloc view serves)",
        ["view", "--export", "{tmp}/scene.html"],
    ),
    ("the terrain walk of a large batch: 20 000 rays over srtm_jacksboro.tif", _large_batch),
    ("the refraction kernels: --refraction standard on a height, on the DEM, and a limb ray", _refraction),
)


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc warm --skip-view"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "warm",
        help=VERB_HELP["warm"],
        description="Run geoloc locate, replay and view once on the bundled data, output swallowed, so that "
        "numba compiles their kernels now (5-30 s of CPU on a 2-core machine, the first time only) "
        "and caches them in the user's cache folder (NUMBA_CACHE_DIR if set, else ~/.cache/geoloc/numba), "
        "where a reinstall keeps them. Prints each step and its time. tools/run.sh runs it.",
    )
    p.add_argument("--skip-view", action="store_true", help="leave out the viewer's scene (no viser server)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from geoloc.geodesy import _nbgeo

    print(f"geoloc warm: compiling what locate, replay and view need, once; cache: {_nbgeo.cache_dir()}", flush=True)
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="geoloc-warm-") as tmp:
        for what, argv in STEPS:
            if args.skip_view and not callable(argv) and argv[0] == "view":
                continue
            print(f"  {what} ...", end="", flush=True)
            n0 = len(_nbgeo.COMPILED)
            w0, c0 = time.perf_counter(), time.process_time()
            out, err = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                rc = argv() if callable(argv) else main([a.replace("{tmp}", tmp) for a in argv])
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            new = _nbgeo.COMPILED[n0:]
            said = f"compiled {len(new)} kernel(s)" if new else "nothing to compile (cached, or not needed)"
            print(f" {said}, {wall:.1f} s ({cpu:.1f} s CPU)", flush=True)
            if rc != 0:
                tail = err.getvalue().strip().splitlines()[-1:] or ["(no message)"]
                print(f"geoloc warm: step failed (exit {rc}): {tail[0]}", file=sys.stderr)
                return rc
    print(f"geoloc warm: done in {time.perf_counter() - t_all:.1f} s; the next runs start from the cache", flush=True)
    return 0
