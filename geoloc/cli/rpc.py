"""``geoloc rpc``: fit the RPC of a scenario's sensor, write it into a GeoTIFF, cross-check with GDAL.

See docs/rpc.md. Degrees and metres at this edge.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

from geoloc.cli._options import (
    add_progress_options,
    add_correction_options,
    check_suffix,
    corrections_from_args,
    input_path,
    output_path,
    text_output_path,
)
from geoloc.userfiles import write_text
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc rpc assets/scenarios/zy3_nadir.toml --out zy3.tif --report rpc.json --no-gdal"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "rpc",
        help=VERB_HELP["rpc"],
        description=(
            "Fit the 78 RPC00B coefficients to the scenario's rigorous sensor model (pushbroom [L12] "
            "or the [Q17] frame camera) over a 3-D grid of ground points, report residuals on "
            "independent check points, write the RPC as GDAL metadata into a GeoTIFF, and compare "
            "GDAL's RPC transformer with RPC_DEM against the project's exact DEM intersection."
        ),
    )
    p.add_argument("scenario", type=input_path, help="scenario TOML (e.g. assets/scenarios/zy3_nadir.toml)")
    p.add_argument("--out", required=True, type=output_path, help="GeoTIFF to write (RPC tag, sparse pixels)")
    p.add_argument(
        "--report",
        type=text_output_path,
        help="JSON report to write (fit_rms_px, check_rms_px, check_max_px, gdal_vs_exact_max_px, ...)",
    )
    p.add_argument("--no-gdal", action="store_true", help="skip the GDAL RPC_DEM cross-check")
    p.add_argument(
        "--gdal-threshold-px",
        type=float,
        default=1e-6,
        help="GDAL RPC_PIXEL_ERROR_THRESHOLD for the cross-check [px] (GDAL's default is 0.1)",
    )
    add_correction_options(p)
    p.add_argument(
        "--ellipsoidal-dem", type=output_path, help="keep the ellipsoidal-height DEM copy given to GDAL at this path"
    )
    add_progress_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from geoloc.workflows.rpc_scenario import rpc_report
    from geoloc.workflows.scenario import load_scenario

    thr = args.gdal_threshold_px
    if not (math.isfinite(thr) and thr > 0):
        raise ValueError(f"--gdal-threshold-px = {thr!r} must be a number > 0 (pixels)")
    check_suffix("--out", args.out)  # the GeoTIFF's name, before the fit: a bad name fails in a second
    check_suffix("--ellipsoidal-dem", args.ellipsoidal_dem)
    out = Path(args.out)
    sc = load_scenario(args.scenario, expect=("pushbroom", "frame"))  # not a montecarlo, limb ... file
    # the scenario's [corrections] with --refraction / --light-time / --no-aberration on top
    sc = dataclasses.replace(sc, corrections=corrections_from_args(args, sc.sensor, base=sc.corrections))
    dem = None
    if not args.no_gdal and sc.dem_path is not None:  # the scenario's DEM, opened here at the edge
        dem = SurfaceSpec(dem=str(sc.dem_path), dem_datum=sc.dem_datum).raster(f"{sc.name}: dem")
    rep = rpc_report(
        sc,
        out,
        dem,
        gdal=not args.no_gdal,
        pixel_error_threshold=thr,
        dem_copy=args.ellipsoidal_dem,
        progress=args.progress,
    )
    print(f"{sc.name}: {rep['rows']} x {rep['cols']} px, {rep['n_fit']} fit / {rep['n_check']} check points")
    print(f"  rigorous model's line-of-sight corrections (the RPC holds them): {rep['corrections']}")
    print(f"  fit   RMS {rep['fit_rms_px']:.2e} px")
    print(f"  check RMS {rep['check_rms_px']:.2e} px, max {rep['check_max_px']:.2e} px")
    if rep.get("gdal_vs_exact_max_px") is not None:
        print(
            f"  GDAL RPC_DEM vs exact DEM intersection: max {rep['gdal_vs_exact_max_px']:.2e} px "
            f"({rep['gdal_vs_exact_max_m']:.1e} m) over {rep['gdal_points']} pixels "
            f"(threshold {thr:g} px; GDAL default 0.1 px gives max {rep['gdal_default_threshold_max_px']:.3f} px)"
        )
        print(
            f"  same with the orthometric DEM as GDAL reads it by default: max "
            f"{rep['gdal_orthometric_dem_max_px']:.3g} px ({rep['gdal_orthometric_dem_max_m']:.2f} m)"
        )
    else:
        print(f"  GDAL cross-check: {rep.get('gdal_note')}")
    print(f"  wrote {out}")
    if args.report:
        write_text(args.report, json.dumps(rep, indent=2) + "\n", "--report")
        print(f"  wrote {args.report}")
    return 0
