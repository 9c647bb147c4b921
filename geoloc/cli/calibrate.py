"""``geoloc calibrate``: error vectors, outliers and boresight / mounting calibration of flight-test records.

See ``docs/calibration.md`` and :mod:`geoloc.analysis.calibrate`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from geoloc.analysis.calibrate import (
    MODELS,
    calibrate_groups,
    resect_camera,
)
from geoloc.assets import asset_path
from geoloc.cli._options import (
    add_dem_options,
    add_sensor_option,
    add_target_options,
    input_path,
    sensor_from_args,
    surface_from_args,
    output_path,
)
from geoloc.cli.locate import load_records_reporting
from geoloc.userfiles import write_text


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate",
        help="flight-test debugger: error vectors, outliers, mounting/boresight fit, resection",
        description="Measure every record's error against its surveyed truth (north/east, along/cross "
        "track, image pixels), flag outliers per flight, fit a small mounting rotation (three angles, "
        "optionally focal length and principal point) by least squares, and report errors before, "
        "after and in leave-one-out cross-validation, as JSON. See docs/calibration.md.",
    )
    p.add_argument("records", nargs="?", default=None, type=input_path,
                   help="records CSV with truth_lat_deg/truth_lon_deg (default: the bundled "
                        "assets/records/qiao2017_flight_tests.csv)")
    add_sensor_option(p)
    p.add_argument("--fit", default=None, metavar="NAMES",
                   help="a sensor file's named parameters to fit, comma-separated (e.g. "
                        "mount_x,mount_y,mount_z,fx,cx,cy,k1,lever_arm_x_m): the fit for any --sensor "
                        "(flights from --group-by, outliers, --joint, --loo and --resect apply to it too)")
    p.add_argument("--write-sensor", default=None, metavar="FILE", type=output_path,
                   help="with --fit: save the fitted sensor file (TOML)")
    add_target_options(p)
    add_dem_options(p)
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
    p.add_argument("--out", default=None, type=output_path, help="write the JSON report here")
    p.add_argument("--write-camera", default=None, type=output_path,
                   help="save the calibrated camera (TOML); with several flights fitted separately, one "
                        "file per flight named STEM_<flight>.toml")
    p.add_argument("--plot", default=None, type=output_path, help="matplotlib figure of the error vectors per flight (PNG)")
    p.add_argument("--exaggeration", type=float, default=1.0, help="arrow scale of --plot (default 1)")
    p.set_defaults(func=run)


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


def _surface(args, records, example: str = "paper_height_m"):
    """The surface the targets lie on, for the sensor fit (:func:`geoloc.cli._options.surface_from_args`)."""
    label = (f"dem:{args.dem}" if args.dem is not None else f"column:{args.height_column}"
             if args.height_column is not None else f"height:{args.target_h_m}")
    return surface_from_args(args, records, example=example), label


def run_sensor_fit(args, camera) -> int:
    """``--fit NAMES``: least squares on any of the sensor's named parameters, per flight.

    Flights come from ``--group-by`` (default the ``table`` column when the records
    have one, else one group); outliers are flagged on the residuals of a first fit
    and left out with ``--exclude-outliers``; ``--joint`` fits one set for all
    flights; ``--resect`` fits the same names to the published positions with
    unknown target heights (:mod:`geoloc.analysis.sensor_fit`).
    """
    from geoloc.analysis.sensor_fit import fit_sensor_groups, resect_sensor
    from geoloc.locate import as_sensor
    from geoloc.sensors.sensor_file import sensor_to_toml
    from geoloc.workflows.replay import outside_sensor_messages

    sensor = as_sensor(camera)
    records = load_records_reporting(args.records, sensor)
    for msg in outside_sensor_messages(records, sensor):
        print(f"geoloc calibrate: warning: {msg}", file=sys.stderr)
    names = [n.strip() for n in args.fit.split(",") if n.strip()]
    surface, label = _surface(args, records, example="truth_h_m")
    group = args.group_by
    if group.lower() == "none" or (group == "table" and "table" not in records.header):
        group = None
    rep, sensors = fit_sensor_groups(records, sensor, names, surface, group_column=group, joint=args.joint,
                                     exclude_outliers=args.exclude_outliers, loo=args.loo,
                                     truth_prefix=args.truth_prefix)
    report = {"records": str(records.path), "sensor": str(args.camera), "target": label, **rep}
    for g, e in rep["groups"].items():
        line = (f"flight {g}: n={e['n']} (fit {e['n_used_in_fit']}), RMS horizontal error to truth: "
                f"before {_fmt(e['rms_before_m'])} m, after {_fmt(e['rms_after_m'])} m")
        if args.loo:
            line += f", leave-one-out {_fmt(e['rms_loo_m'])} m"
        print(line)
        flagged = [r["label"] for r in e["records"] if r["outlier"]]
        if flagged:
            print(f"  outliers before the fit: {flagged}"
                  + (" (left out)" if args.exclude_outliers else " (kept; --exclude-outliers leaves them out)"))
        if not args.joint:
            _print_parameters(e["parameters"])
    if args.joint:
        print(f"joint fit ({rep['joint_fit']['n']} records):")
        _print_parameters(rep["joint_fit"]["parameters"])
    if args.resect:
        r = resect_sensor(records, sensor, names)
        report["resection"] = r.report()
        print(f"resection of {', '.join(names)} to the published positions (unknown target heights): "
              f"RMS misfit {r.rms_m:.2f} m" + ("" if r.success else " (did not converge)"))
        _print_parameters(report["resection"]["parameters"])
    report = _json_safe(report)
    if args.out:
        write_text(args.out, json.dumps(report, indent=2, allow_nan=False) + "\n", "--out")
        print(f"wrote {args.out}")
    if args.write_sensor:
        out = Path(args.write_sensor)
        todo = ([(g, out) for g in sensors] if len(sensors) == 1 else
                [(g, out.with_name(f"{out.stem}_{g}{out.suffix or '.toml'}")) for g in sensors])
        for g, path in todo:
            sensor_to_toml(sensors[g], path)
            print(f"wrote the fitted sensor ({g}) to {path}")
    return 0


def _print_parameters(params: dict) -> None:
    print(f"  {'parameter':<16} {'start':>14} {'fitted':>14} {'sd':>12}")
    for n, e in params.items():
        print(f"  {n:<16} {e['start']:>14.6f} {e['value']:>14.6f} {e['sd']:>12.6f} {e['unit']}")


def run(args) -> int:
    if args.exaggeration <= 0 or not np.isfinite(args.exaggeration):
        raise ValueError(f"--exaggeration = {args.exaggeration}: must be a finite number > 0")
    camera = sensor_from_args(args)
    if args.fit is not None:
        return run_sensor_fit(args, camera)
    if args.write_sensor:
        raise ValueError("--write-sensor goes with --fit NAMES")
    from geoloc.sensors.camera import Camera

    if not isinstance(camera, Camera):
        raise ValueError(f"--sensor {args.camera}: a sensor file is calibrated with --fit NAMES "
                         "(e.g. --fit mount_x,mount_y,mount_z); the flight-grouped fit is the first-phase camera's")
    records = load_records_reporting(args.records)
    surface, label = _surface(args, records)
    group = None if args.group_by.lower() == "none" else args.group_by
    report, cameras = calibrate_groups(
        records, camera, surface, group, model=args.model, fit_focal=args.fit_focal,
        fit_pp=args.fit_principal_point, loo=args.loo, joint=args.joint,
        exclude_outliers=args.exclude_outliers, truth_prefix=args.truth_prefix)
    report = {"records": str(records.path), "camera": str(args.camera or asset_path("cameras", "qiao2017.toml")),
              "target": label, **report}
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
        write_text(args.out, json.dumps(report, indent=2, allow_nan=False) + "\n", "--out")
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
