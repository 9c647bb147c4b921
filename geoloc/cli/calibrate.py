"""``geoloc calibrate``: error vectors, outliers and boresight / mounting calibration of flight-test records.

See ``docs/calibration.md`` and :mod:`geoloc.analysis.calibrate`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from geoloc.analysis.calibrate import (
    MODELS,
    DemTarget,
    HeightTarget,
    calibrate_groups,
    resect_camera,
)
from geoloc.assets import asset_path
from geoloc.cli.locate import load_camera, load_records_reporting


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate",
        help="flight-test debugger: error vectors, outliers, mounting/boresight fit, resection",
        description="Measure every record's error against its surveyed truth (north/east, along/cross "
        "track, image pixels), flag outliers per flight, fit a small mounting rotation (three angles, "
        "optionally focal length and principal point) by least squares, and report errors before, "
        "after and in leave-one-out cross-validation, as JSON. See docs/calibration.md.",
    )
    p.add_argument("records", nargs="?", default=None,
                   help="records CSV with truth_lat_deg/truth_lon_deg (default: the bundled "
                        "assets/records/qiao2017_flight_tests.csv)")
    p.add_argument("--camera", default=None, help="camera TOML (default: bundled qiao2017.toml)")
    t = p.add_mutually_exclusive_group()
    t.add_argument("--height-column", default=None,
                   help="column holding each target's ellipsoidal height [m], e.g. paper_height_m")
    t.add_argument("--target-h-m", type=float, default=None, help="one target height for every record [m]")
    t.add_argument("--dem", default=None,
                   help="DEM raster: targets where the line of sight meets the terrain (geoloc.surfaces.terrain)")
    p.add_argument("--dem-datum", choices=["egm96", "ellipsoid"], default="egm96",
                   help="vertical datum of the DEM's heights (default egm96: orthometric)")
    p.add_argument("--surface", choices=["inflated", "geodetic"], default="inflated",
                   help="with a height: [Q17] eq. 11 inflated ellipsoid (default) or exact constant height")
    p.add_argument("--group-by", default="table",
                   help="column grouping records into flights (default: table; 'none' for one group)")
    p.add_argument("--model", choices=sorted(MODELS), default="mount",
                   help="where the fitted rotation sits: 'mount' = gimbal base in the aircraft body "
                        "(R_base_body, default), 'camera' = camera in the inner gimbal (R_cam_inner)")
    p.add_argument("--joint", action="store_true",
                   help="fit one rotation to all flights together (default: one fit per flight)")
    p.add_argument("--fit-focal", action="store_true", help="also fit the focal length")
    p.add_argument("--fit-principal-point", action="store_true", help="also fit the principal point")
    p.add_argument("--loo", action="store_true", help="leave-one-out cross-validation per flight")
    p.add_argument("--exclude-outliers", action="store_true",
                   help="leave records flagged as outliers (before calibration) out of the fit")
    p.add_argument("--truth-prefix", default="truth",
                   help="columns {prefix}_lat_deg/{prefix}_lon_deg hold the surveyed truth (default truth)")
    p.add_argument("--resect", action="store_true",
                   help="also fit focal length and principal point to the published computed positions "
                        "(paper_lat_deg/paper_lon_deg) with unknown target heights: how the bundled "
                        "camera was derived")
    p.add_argument("--out", default=None, help="write the JSON report here")
    p.add_argument("--write-camera", default=None,
                   help="save the calibrated camera (TOML); with several flights fitted separately, one "
                        "file per flight named STEM_<flight>.toml")
    p.add_argument("--plot", default=None, help="matplotlib figure of the error vectors per flight (PNG)")
    p.add_argument("--exaggeration", type=float, default=1.0, help="arrow scale of --plot (default 1)")
    p.set_defaults(func=run)


def _target(args, records):
    if args.dem is not None:
        try:
            from geoloc.surfaces.dem import DEM
            from geoloc.surfaces.terrain import intersect_dem  # noqa: F401  (fails clearly if not available)
        except ImportError as e:
            raise ValueError(f"--dem {args.dem}: terrain intersection is not available ({e})") from None
        return DemTarget(DEM.open(args.dem, datum=args.dem_datum), label=f"dem:{args.dem}")
    if args.height_column is not None:
        h = records.column(args.height_column)
        bad = ~np.isfinite(h)
        if np.any(bad):
            raise ValueError(f"height column {args.height_column!r} is empty or not finite on line(s) "
                             f"{[int(n) for n in records.lines[bad]]}")
        return HeightTarget(h, args.surface, label=f"column:{args.height_column}")
    if args.target_h_m is not None:
        return HeightTarget(np.full(len(records), args.target_h_m), args.surface,
                            label=f"height:{args.target_h_m}")
    raise ValueError("give --height-column (e.g. paper_height_m), --target-h-m or --dem")


def _json_safe(v):
    """NaN / inf -> None (JSON has no NaN), recursively; numpy scalars -> Python."""
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _fmt(v, spec=".2f"):
    return "-" if v is None else format(v, spec)


def run(args) -> int:
    records = load_records_reporting(args.records)
    if args.exaggeration <= 0 or not np.isfinite(args.exaggeration):
        raise ValueError(f"--exaggeration = {args.exaggeration}: must be a finite number > 0")
    camera = load_camera(args.camera)
    target = _target(args, records)
    group = None if args.group_by.lower() == "none" else args.group_by
    report, cameras = calibrate_groups(
        records, camera, target, group, model=args.model, fit_focal=args.fit_focal,
        fit_pp=args.fit_principal_point, loo=args.loo, joint=args.joint,
        exclude_outliers=args.exclude_outliers, truth_prefix=args.truth_prefix)
    report = {"records": str(records.path), "camera": str(args.camera or asset_path("cameras", "qiao2017.toml")),
              "target": target.label, **report}
    if args.resect:
        report["resection"] = resect_camera(records, camera).report()

    print(f"{'flight':<8} {'n':>3} {'before_m':>9} {'after_m':>8} {'loo_m':>7}   angles_deg (x, y, z) +- sd")
    for g, e in report["groups"].items():
        ang = ", ".join(f"{a:+.4f}+-{_fmt(s, '.4f')}" for a, s in zip(e["angles_deg"], e["angles_sd_deg"]))
        print(f"{g:<8} {e['n']:>3} {_fmt(e['mean_error_before_m']):>9} {_fmt(e['mean_error_after_m']):>8} "
              f"{_fmt(e['mean_error_loo_m']):>7}   {ang}")
        if e["degenerate_pairs"]:
            print(f"         not separable with these records (|correlation| > 0.99): "
                  f"{', '.join('/'.join(p) for p in e['degenerate_pairs'])}")
        if e["before"]["outliers"]:
            print(f"         outliers before calibration: "
                  f"{[e['records'][k]['label'] for k in e['before']['outliers']]}")
    if "resection" in report:
        r = report["resection"]
        print(f"resection: f = {r['focal_length_px']:.1f} +- {r['focal_length_sd_px']:.1f} px, "
              f"i0 = {r['principal_row']:.2f} +- {r['principal_row_sd']:.2f}, "
              f"j0 = {r['principal_col']:.2f} +- {r['principal_col_sd']:.2f}, "
              f"RMS misfit {r['rms_misfit_m']:.2f} m")

    report = _json_safe(report)
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
        print(f"wrote {args.out}")
    if args.write_camera:
        out = Path(args.write_camera)
        todo = ([("joint", out)] if args.joint else
                [(g, out) for g in cameras] if len(cameras) == 1 else
                [(g, out.with_name(f"{out.stem}_{g}{out.suffix or '.toml'}")) for g in cameras])
        for g, path in todo:
            cameras[g].to_toml(path)
            print(f"wrote calibrated camera ({g}) to {path}")
    if args.plot:
        from geoloc.analysis.calibrate import error_vector_panels
        from geoloc.analysis.errors import plot_error_vectors

        plot_error_vectors(args.plot, error_vector_panels(report, records, args.exaggeration),
                           title=f"error vectors (computed - truth), model {args.model}"
                                 + (", joint fit" if args.joint else ", one fit per flight"))
        print(f"wrote {args.plot}")
    return 0
