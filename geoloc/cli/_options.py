"""Options shared by the verbs: the path types every file option is declared with, and the DEM options.

**Files.** Every option that names a file is declared with one of three argparse
types, so that what a verb reads and writes is known from its declaration alone:
:func:`input_path` (a file or folder it reads; ``assets/...`` names the bundled file
where there is no such file here), :func:`output_path` (a file it writes) and
:func:`output_dir` (a folder it writes files into). :func:`geoloc.cli.main` reads
them (:func:`declared_files`) and checks every output against every input before
the verb runs (docs/architecture.md, "The user's files").

**DEM.** ``add_dem_options(parser)`` adds ``--dem FILE --method --dem-datum --eps-h
--threshold --dem-model --dem-cache-mb``; ``--dem`` is one raster, or a folder of
tiles, a ``.vrt`` or a repeated ``--dem``: a :class:`geoloc.surfaces.mosaic.DemMosaic`
(:func:`open_surface`). Giving ``--dem`` installs the verb's terrain hook
(``args._terrain_hook``), so the verb's own code path is untouched without it.
The hooks warn when the DEM's datum and the aircraft heights' datum look mixed
(:func:`warn_datums`).
Degrees and metres at this edge (docs/conventions.md).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from geoloc.surfaces.terrain import METHODS, SURFACES, surface_for


# --------------------------------------------------------------------------- file options


def input_path(text: str) -> str:
    """argparse type of an option naming a file or folder the verb reads.

    ``assets/...`` names the bundled file when there is no such file here
    (:func:`geoloc.assets.resolve_user_path`), so the README's commands run anywhere.
    """
    from geoloc.assets import resolve_user_path

    return str(resolve_user_path(text))


def output_path(text: str) -> str:
    """argparse type of an option naming a file the verb writes (checked before the verb runs)."""
    return str(text)


def output_dir(text: str) -> str:
    """argparse type of an option naming a folder the verb writes files into."""
    return str(text)


#: The role of each path type, as :func:`declared_files` reports it.
ROLES = {input_path: "input", output_path: "output", output_dir: "output_dir"}


def chosen_parsers(parser, args) -> list:
    """The parser and the sub-parsers ``args`` went through (``geoloc klv dump``: three)."""
    out = [parser]
    while True:
        subs = [a for a in out[-1]._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subs[0].dest, None) if subs else None
        if not subs or name not in subs[0].choices:
            return out
        out.append(subs[0].choices[name])


def declared_files(parser, args) -> tuple[list, list]:
    """The inputs and outputs of a parsed command line, from its options' types.

    Returns ``(inputs, outputs)``: ``inputs`` a list of paths, ``outputs`` a list of
    ``(option, path, role)`` with ``role`` ``"output"`` or ``"output_dir"``.
    """
    inputs, outputs = [], []
    for p in chosen_parsers(parser, args):
        for a in p._actions:
            role = ROLES.get(a.type)
            v = getattr(args, a.dest, None) if role else None
            if v is None:
                continue
            name = a.option_strings[0] if a.option_strings else a.metavar or a.dest
            for x in (v if isinstance(v, list) else [v]):
                if role == "input":
                    inputs.append(x)
                else:
                    outputs.append((name, x, role))
    return inputs, outputs


def check_outputs(parser, args) -> list:
    """Refuse, before the verb runs, an output that is an input or cannot be written; returns the inputs."""
    from geoloc.userfiles import check_output, check_output_dir

    inputs, outputs = declared_files(parser, args)
    seen = {}
    for name, path, role in outputs:
        (check_output if role == "output" else check_output_dir)(path, name, inputs=inputs)
        for other, q in seen.items():
            if _same_path(path, q):
                raise ValueError(f"{name} {path} and {other} {q} are the same file: give two paths")
        seen[name] = path
    return inputs


def _same_path(a, b) -> bool:
    import os
    from pathlib import Path

    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


# --------------------------------------------------------------------------- DEM options


def dem_sources(args):
    """``--dem`` as given: one path (str) or, for a repeated ``--dem``, a list of paths."""
    return list(args.dem) if isinstance(args.dem, list) else args.dem


def _mosaic_options(args) -> dict:
    mb = getattr(args, "dem_cache_mb", 64.0)
    if not (np.isfinite(mb) and mb > 0):
        raise ValueError(f"--dem-cache-mb must be a positive number of MiB, got {mb!r}")
    return {"cache_bytes": max(int(mb * 2**20), 2**16)}


def open_dem_arg(args):
    """``--dem``: a :class:`~geoloc.surfaces.dem.DEM` for one raster file, a
    :class:`~geoloc.surfaces.mosaic.DemMosaic` for a folder, a ``.vrt`` or several files."""
    from geoloc.surfaces.mosaic import open_dem_or_mosaic

    return open_dem_or_mosaic(dem_sources(args), args.dem_datum, **_mosaic_options(args))


def open_surface(args):
    """The surface of the DEM options: ``DemSurface`` of one raster, or the mosaic itself."""
    from geoloc.surfaces.mosaic import DemMosaic, open_dem_or_mosaic

    src = dem_sources(args)
    opts = {"eps_h": args.eps_h, "threshold": args.threshold}
    dem = open_dem_or_mosaic(src, args.dem_datum, method=args.method, dem_model=args.dem_surface,
                             **_mosaic_options(args), **opts)
    if isinstance(dem, DemMosaic):
        return dem  # a Surface itself: solves region by region within its memory bound
    return surface_for(dem=dem, method=args.method, dem_model=args.dem_surface, **opts)


def _solve(args, los):
    return open_surface(args).intersect(los)


def warn_datums(verb: str, dem_datum: str, height) -> list:
    """Print (on stderr) and return the warnings of a DEM of ``dem_datum`` meeting aircraft heights
    read as ``height`` (a :class:`geoloc.io.columns.HeightSource`): see
    :func:`geoloc.io.columns.datum_warnings`."""
    from geoloc.io.columns import datum_warnings

    msgs = datum_warnings(dem_datum, height)
    for m in msgs:
        print(f"geoloc {verb}: warning: {m}", file=sys.stderr)
    return msgs


def locate_hook(args, los):
    """``geoloc locate --dem``: returns (ground point, extra output fields)."""
    from geoloc.io.columns import HeightSource

    warn_datums("locate", args.dem_datum, HeightSource.of_option(getattr(args, "altitude_datum", None)))
    hit = _solve(args, los)
    extra = {"method": args.method, "dem_evaluations": int(hit.dem_evaluations)}
    if args.method == "bisect":
        extra["hidden"] = bool(hit.hidden)
    return hit, extra


def replay_hook(args, records, camera):
    """``geoloc replay --dem``: locate every record on the DEM; adds status and dem_evaluations."""
    from geoloc.workflows.replay import records_line_of_sight, result_from_ground

    warn_datums("replay", args.dem_datum, records.altitude)
    hit = _solve(args, records_line_of_sight(records, camera))
    extra = {"status": hit.status, "dem_evaluations": hit.dem_evaluations.astype(np.int64)}
    if args.method == "bisect":
        extra["hidden"] = hit.hidden.astype(np.int64)
    return result_from_ground(records, hit, extra, camera=camera)


class _DemAction(argparse.Action):
    def __init__(self, *a, hook=None, **k):
        self.hook = hook
        super().__init__(*a, **k)

    def __call__(self, parser, namespace, values, option_string=None):
        prev = getattr(namespace, self.dest, None) if getattr(namespace, "_terrain_hook", None) else None
        if prev is None:
            setattr(namespace, self.dest, values)  # one --dem: a path, as always
        else:  # --dem repeated: the files of one mosaic
            setattr(namespace, self.dest, (prev if isinstance(prev, list) else [prev]) + [values])
        setattr(namespace, "_terrain_hook", self.hook)


def add_dem_options(parser, hook) -> None:
    """Add the DEM options to a verb's parser; ``hook`` runs the verb on the DEM."""
    g = parser.add_argument_group("terrain (DEM)")
    g.add_argument("--dem", metavar="FILE", default=None, action=_DemAction, hook=hook, type=input_path,
                   help="DEM raster (GeoTIFF, ...): intersect the line of sight with the terrain instead "
                   "of a target height, e.g. assets/dem/etopo5_flight_area.tif; a folder of tiles, a GDAL "
                   ".vrt, or --dem given several times is one mosaic, read in windows on demand "
                   "(docs/scale.md)")
    g.add_argument("--dem-cache-mb", type=float, default=64.0,
                   help="DEM mosaic: bound of its tile cache and of one region it assembles [MiB] "
                   "(default 64)")
    g.add_argument("--method", choices=METHODS, default="exact",
                   help="steps: descending steps of [Q17]; bisect: halving of [L23]; "
                   "exact: first visible hit, no threshold (default)")
    g.add_argument("--dem-datum", choices=["egm96", "ellipsoid"], default="egm96",
                   help="vertical datum of the DEM heights (default egm96: real DEMs are orthometric; "
                   "N from the bundled EGM96 grid)")
    g.add_argument("--eps-h", type=float, default=1.0, help="step of --method steps [m] (default 1)")
    g.add_argument("--threshold", type=float, default=1.0,
                   help="bisection stops when |H - h_DEM| < threshold [m] (default 1)")
    g.add_argument("--dem-model", "--dem-surface", dest="dem_surface", choices=SURFACES, default="bilinear",
                   help="how the exact method reads between DEM nodes: bilinear cells (default) or two "
                   "triangles per cell (--dem-surface is the same option's first-phase name)")
