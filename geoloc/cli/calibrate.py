"""``geoloc calibrate``: error vectors, outliers and boresight / mounting calibration of flight-test records.

One calibrator for every sensor, :mod:`geoloc.analysis.sensor_fit`: a first-phase camera
file is fitted as its sensor (``--model`` / ``--fit-focal`` / ``--fit-principal-point``
choose the parameters, ``--fit NAMES`` names them) and written back with
``--write-camera``. See ``docs/calibration.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from geoloc.analysis.sensor_fit import error_vector_panels, fit_sensor_groups, resect_sensor
from geoloc.assets import asset_path
from geoloc.cli import VERB_HELP
from geoloc.cli._options import (
    add_correction_options,
    add_dem_options,
    add_sensor_option,
    add_target_options,
    corrections_from_args,
    input_path,
    output_path,
    sensor_from_args,
    surface_from_args,
    text_output_path,
)
from geoloc.cli.locate import load_records_reporting
from geoloc.sensors.camera import camera_from_sensor
from geoloc.sensors.sensor_file import sensor_to_toml
from geoloc.userfiles import write_text

#: ``--model``: the rotation each names (``Camera`` file keys ``mount_deg`` / ``boresight_deg``).
MODELS = {"mount": ("mount_x", "mount_y", "mount_z"), "camera": ("boresight_x", "boresight_y", "boresight_z")}

#: ``--resect`` without ``--fit``: the camera's focal length and principal point (row, column).
RESECT_NAMES = ("f", "cy", "cx")


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc calibrate --height-column paper_height_m --out calibration.json --plot errors.png"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help=VERB_HELP["calibrate"],
        description="Measure every record's error against its surveyed truth (north/east, along/cross "
        "track, image pixels), flag outliers per flight, fit a small mounting rotation (three angles, "
        "optionally focal length and principal point) by least squares, and report errors before, "
        "after and in leave-one-out cross-validation, as JSON. See docs/calibration.md.",
    )
    p.add_argument(
        "records",
        nargs="?",
        default=None,
        type=input_path,
        help="records CSV with truth_lat_deg/truth_lon_deg (default: the bundled "
        "assets/records/qiao2017_flight_tests.csv)",
    )
    add_sensor_option(p)
    p.add_argument(
        "--fit",
        default=None,
        metavar="NAMES",
        help="a sensor file's named parameters to fit, comma-separated (e.g. "
        "mount_x,mount_y,mount_z,fx,cx,cy,k1,lever_arm_x_m): the fit for any --sensor "
        "(flights from --group-by, outliers, --joint, --loo and --resect apply to it too)",
    )
    p.add_argument(
        "--write-sensor",
        default=None,
        metavar="FILE",
        type=output_path,
        help="save the fitted sensor file (TOML); with several flights fitted separately, one "
        "file per flight named STEM_<flight>.toml",
    )
    add_target_options(p)
    add_dem_options(p)
    add_correction_options(p)
    p.add_argument(
        "--group-by",
        default="table",
        help="column grouping records into flights (default: table; 'none' for one group)",
    )
    p.add_argument(
        "--model",
        choices=sorted(MODELS),
        default=None,
        help="without --fit: where the fitted rotation sits: 'mount' = gimbal base in the aircraft "
        "body (R_base_body, mount_x,mount_y,mount_z; default), 'camera' = camera in the inner "
        "gimbal (R_cam_inner, boresight_x,boresight_y,boresight_z)",
    )
    p.add_argument(
        "--joint", action="store_true", help="fit one rotation to all flights together (default: one fit per flight)"
    )
    p.add_argument(
        "--fit-focal",
        action="store_true",
        help="without --fit: also fit the focal length (f: the lens's fx and fy together)",
    )
    p.add_argument(
        "--fit-principal-point",
        action="store_true",
        help="without --fit: also fit the principal point (cy, cx: row and column, 1-based)",
    )
    p.add_argument("--loo", action="store_true", help="leave-one-out cross-validation per flight")
    p.add_argument(
        "--exclude-outliers",
        action="store_true",
        help="leave records flagged as outliers (on the residuals of a first fit with every record) out of the fit",
    )
    p.add_argument(
        "--truth-prefix",
        default="truth",
        help="columns {prefix}_lat_deg/{prefix}_lon_deg hold the surveyed truth (default truth)",
    )
    p.add_argument(
        "--resect",
        action="store_true",
        help="also fit focal length and principal point (f, cy, cx; with --fit its names) to "
        "the published computed positions (paper_lat_deg/paper_lon_deg) with unknown target "
        "heights: how the bundled camera was derived",
    )
    p.add_argument("--out", default=None, type=text_output_path, help="write the JSON report here")
    p.add_argument(
        "--write-camera",
        default=None,
        type=output_path,
        help="save the calibrated sensor as a first-phase camera file (TOML; a pinhole with "
        "fx = fy on the roll-pitch gimbal, else use --write-sensor); with several flights "
        "fitted separately, one file per flight named STEM_<flight>.toml",
    )
    p.add_argument(
        "--plot", default=None, type=output_path, help="matplotlib figure of the error vectors per flight (PNG)"
    )
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
    return "-" if v is None or not np.isfinite(v) else format(v, spec)


def _surface(args, records, example: str = "paper_height_m"):
    """The surface the targets lie on, for the sensor fit (:func:`geoloc.cli._options.surface_from_args`)."""
    label = (
        f"dem:{args.dem}"
        if args.dem is not None
        else f"column:{args.height_column}"
        if args.height_column is not None
        else f"height:{args.target_h_m}"
    )
    return surface_from_args(args, records, example=example), label


def fit_names(args: argparse.Namespace) -> list:
    """The parameters to fit: ``--fit NAMES``, else those of ``--model`` / ``--fit-focal`` / ``--fit-principal-point``."""
    if args.fit is not None:
        chosen = [
            o
            for o, v in (
                ("--model", args.model is not None),
                ("--fit-focal", args.fit_focal),
                ("--fit-principal-point", args.fit_principal_point),
            )
            if v
        ]
        if chosen:
            raise ValueError(
                f"{', '.join(chosen)} choose the parameters without --fit; with --fit {args.fit} "
                "name them all (e.g. mount_x,mount_y,mount_z,f,cy,cx)"
            )
        names = [n.strip() for n in args.fit.split(",") if n.strip()]
        if not names:
            raise ValueError(f"--fit {args.fit!r}: name at least one parameter (e.g. mount_x,mount_y,mount_z)")
        return names
    names = list(MODELS[args.model or "mount"])
    if args.fit_focal:
        names.append("f")
    if args.fit_principal_point:
        names += ["cy", "cx"]
    return names


def _write_fitted(option: str, out, sensors: dict, joint: bool, write) -> None:
    """One file, or with several flights fitted separately one ``STEM_<flight>`` file each."""
    out = Path(out)
    todo = (
        [(g, out) for g in sensors]
        if joint or len(sensors) == 1
        else [(g, out.with_name(f"{out.stem}_{g}{out.suffix or '.toml'}")) for g in sensors]
    )
    for g, path in todo:
        write(sensors[g], path)
        print(f"wrote the fitted {option} ({g}) to {path}")


def run(args: argparse.Namespace) -> int:
    """Fit the parameters of :func:`fit_names` per flight (:func:`geoloc.analysis.sensor_fit.fit_sensor_groups`).

    Flights come from ``--group-by`` (default the ``table`` column when the records
    have one, else one group); outliers are flagged on the residuals of a first fit
    and left out with ``--exclude-outliers``; ``--joint`` fits one set for all
    flights; ``--resect`` fits the focal length and principal point (or the ``--fit``
    names) to the published positions with unknown target heights
    (:func:`geoloc.analysis.sensor_fit.resect_sensor`).
    """
    from geoloc.workflows.replay import outside_sensor_messages

    if args.exaggeration <= 0 or not np.isfinite(args.exaggeration):
        raise ValueError(f"--exaggeration = {args.exaggeration}: must be a finite number > 0")
    names = fit_names(args)
    sensor = sensor_from_args(args)
    records = load_records_reporting(args.records, sensor)
    for msg in outside_sensor_messages(records, sensor):
        print(f"geoloc calibrate: warning: {msg}", file=sys.stderr)
    surface, label = _surface(args, records, example="truth_h_m" if args.fit is not None else "paper_height_m")
    group = args.group_by
    if group.lower() == "none" or (group == "table" and "table" not in records.header):
        group = None
    corrections = corrections_from_args(args, sensor)
    rep, sensors = fit_sensor_groups(
        records,
        sensor,
        names,
        surface,
        corrections=corrections,
        group_column=group,
        joint=args.joint,
        exclude_outliers=args.exclude_outliers,
        loo=args.loo,
        truth_prefix=args.truth_prefix,
    )
    report = {
        "records": str(records.path),
        "sensor": str(args.camera or asset_path("cameras", "qiao2017.toml")),
        "target": label,
        "corrections": corrections.label,
        **rep,
    }
    for g, e in rep["groups"].items():
        line = (
            f"flight {g}: n={e['n']} (fit {e['n_used_in_fit']}), mean error to truth: "
            f"before {_fmt(e['mean_error_before_m'])} m, after {_fmt(e['mean_error_after_m'])} m"
        )
        if args.loo:
            line += f", leave-one-out {_fmt(e['mean_error_loo_m'])} m"
        rms = f"before {_fmt(e['rms_before_m'])}, after {_fmt(e['rms_after_m'])}"
        print(line + f" (RMS {rms}" + (f", leave-one-out {_fmt(e['rms_loo_m'])}" if args.loo else "") + " m)")
        flagged = [r["label"] for r in e["records"] if r["outlier"]]
        if flagged:
            print(
                f"  outliers before the fit: {flagged}"
                + (" (left out)" if args.exclude_outliers else " (kept; --exclude-outliers leaves them out)")
            )
        if not args.joint:
            _print_parameters(e["parameters"], e["degenerate_pairs"])
    if args.joint:
        print(f"joint fit ({rep['joint_fit']['n']} records):")
        _print_parameters(rep["joint_fit"]["parameters"], rep["joint_fit"]["degenerate_pairs"])
    if args.resect:
        rnames = names if args.fit is not None else list(RESECT_NAMES)
        r = resect_sensor(records, sensor, rnames, corrections=corrections)
        report["resection"] = r.report()
        print(
            f"resection of {', '.join(rnames)} to the published positions (unknown target heights): "
            f"RMS misfit {r.rms_m:.2f} m" + ("" if r.success else " (did not converge)")
        )
        _print_parameters(report["resection"]["parameters"], report["resection"]["degenerate_pairs"])
    report = _json_safe(report)
    if args.out:
        write_text(args.out, json.dumps(report, indent=2, allow_nan=False) + "\n", "--out")
        print(f"wrote {args.out}")
    if args.write_sensor:
        # the fitted sensor carries the corrections it was fitted with (else, located without
        # them, its parameters would be biased by the very shift they absorbed)
        table = corrections.to_table()
        _write_fitted(
            "sensor", args.write_sensor, sensors, args.joint, lambda s, path: sensor_to_toml(s, path, corrections=table)
        )
    if args.write_camera:
        # the fitted sensor carries the input camera file's pixel pitch, if it gave one
        _write_fitted(
            "camera", args.write_camera, sensors, args.joint, lambda s, path: camera_from_sensor(s).to_toml(path)
        )
    if args.plot:
        from geoloc.analysis.errors import plot_error_vectors

        plot_error_vectors(
            args.plot,
            error_vector_panels(report, records, args.exaggeration),
            title=f"error vectors (computed - truth), {', '.join(names)}"
            + (", joint fit" if args.joint else ", one fit per flight"),
        )
        print(f"wrote {args.plot}")
    return 0


def _print_parameters(params: dict, degenerate=()) -> None:
    print(f"  {'parameter':<16} {'start':>14} {'fitted':>14} {'sd':>12}")
    for n, e in params.items():
        print(f"  {n:<16} {e['start']:>14.6f} {e['value']:>14.6f} {_fmt(e['sd'], '.6f'):>12} {e['unit']}")
    if degenerate:
        print(
            f"  not separable with these records (|correlation| > 0.99): {', '.join('/'.join(p) for p in degenerate)}"
        )
