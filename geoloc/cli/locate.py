"""``geoloc locate``: geolocate one pixel from the aircraft pose, gimbal angles and a sensor.

Also what the other verbs read from the shared options (declared in
:mod:`geoloc.cli._options`): the sensor (:func:`geoloc.cli._options.sensor_from_args`), the pose
(:func:`pose_from_args`) and the records with their column map and datums
(:func:`records_from_args`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.assets import DEFAULT_RECORDS, asset_path
from geoloc.cli import VERB_HELP
from geoloc.cli._options import (
    add_correction_options,
    add_dem_options,
    add_gimbal_options,
    add_pose_options,
    add_target_options,
    pipeline_from_args,
    sensor_from_args,
    surface_from_args,
    warn_datums,
)
from geoloc.frames.chain import Pose
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.columns import (
    DATUM_TEXT,
    ELLIPSOID_DATUM,
    ColumnMap,
    HeightSource,
    load_column_map,
)
from geoloc.io.records import Records, load_records
from geoloc.sensors.base import check_angle_names
from geoloc.sensors.sensor_file import load_sensor_columns
from geoloc.status import Status, describe
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.height import HeightSurface

#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    "geoloc locate --lat-deg 35.48 --lon-deg 80.97 --h-m 18000 --heading-deg 45 --pitch-deg 3.5 "
    "--gimbal-roll-deg 50 --gimbal-pitch-deg -2.6 --target-h-m 5083.5 --json"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "locate",
        help=VERB_HELP["locate"],
        description="Geolocate one pixel: aircraft position and attitude, gimbal encoder angles, "
        "a camera file and a target height give the target's latitude, longitude and height "
        "([Q17] eq. 4-13). Angles in degrees, heights ellipsoidal in metres.",
    )
    add_pose_options(p.add_argument_group("aircraft (POS)"), required=True)
    g = p.add_argument_group("gimbal and sensor")
    add_gimbal_options(g)
    g.add_argument(
        "--row", type=float, default=None, help="pixel row, 1-based pixel centres (default: the image centre)"
    )
    g.add_argument(
        "--col", type=float, default=None, help="pixel column, 1-based pixel centres (default: the image centre)"
    )
    add_target_options(p, height_column=False)
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(func=run)
    add_dem_options(p)
    add_correction_options(p)


def parse_angles(items: Iterable[str]) -> dict:
    """``["azimuth=90", ...]`` -> ``{"azimuth": 90.0}``; errors name the item."""
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name.isidentifier():
            raise ValueError(f"--angle {item!r}: must be NAME=DEGREES, e.g. --angle azimuth=90")
        try:
            v = float(value)
        except ValueError:
            raise ValueError(f"--angle {item!r}: {value!r} is not a number of degrees") from None
        if not math.isfinite(v):
            raise ValueError(f"--angle {item!r}: {value!r} is not a finite number of degrees")
        if name in out:
            raise ValueError(f"--angle {name} is given twice")
        out[name] = v
    return out


def _is_bundled_records(path) -> bool:

    try:
        return Path(path).resolve() == asset_path(*DEFAULT_RECORDS).resolve()
    except OSError:
        return False


def load_records_reporting(
    path: str | os.PathLike[str] | None, sensor: Any = None, columns: Any = None, altitude_datum: str | None = None
) -> Records:
    """Records from ``path`` (default: the bundled flight test); each rejected row is
    reported on stderr with its line, and no good row at all is an error. With
    ``sensor``, its gimbal's angles are the required ``<angle>_deg`` columns.

    ``columns`` is a column map (a :class:`~geoloc.io.columns.ColumnMap`, a
    ``[columns]`` dict or a map file); ``altitude_datum`` the ``--altitude-datum``
    (None: not stated; ellipsoidal, except that the bundled flight test's heights
    are ellipsoidal by docs/records.md, which counts as stated). A column map's
    datum for ``ac_h_m`` that differs from ``altitude_datum`` wins, with a note."""
    angles = sensor.angle_names if sensor is not None else ("gimbal_roll", "gimbal_pitch")
    path = path if path else asset_path(*DEFAULT_RECORDS)
    source = "--altitude-datum"
    if altitude_datum is None and columns is None and _is_bundled_records(path):
        altitude_datum, source = "ellipsoid", "docs/records.md"
    records = load_records(path, angles=angles, columns=columns, altitude_datum=altitude_datum, altitude_source=source)
    alt = records.altitude
    if altitude_datum is not None and alt.datum != altitude_datum:
        print(
            f"{records.path}: note: --altitude-datum {altitude_datum} not used for ac_h_m: the "
            f"{alt.stated} gives datum {alt.datum!r} for column {alt.column!r}",
            file=sys.stderr,
        )
    for err in records.errors:
        print(f"{records.path}: skipped {err}", file=sys.stderr)
    for msg in records.warnings:
        print(f"warning: {msg}", file=sys.stderr)
    if len(records) == 0:
        raise ValueError(f"{records.path}: no valid record")
    return records


def column_map_from_args(args: argparse.Namespace) -> ColumnMap | None:
    """The column map of ``--columns FILE``, else of the ``--sensor`` file's ``[columns]`` table, else None."""
    path = getattr(args, "columns", None)
    if path:
        return load_column_map(path)
    sensor_path = getattr(args, "camera", None)
    if sensor_path:
        table = load_sensor_columns(sensor_path)
        if table is not None:
            return ColumnMap.from_table(table, source=str(sensor_path))
    return None


def records_from_args(args: argparse.Namespace, path: str | os.PathLike[str] | None, sensor: Any) -> Records:
    """:func:`load_records_reporting` with the verb's ``--columns`` (or the sensor file's
    ``[columns]``) and ``--altitude-datum`` (options of :func:`add_records_options`)."""
    return load_records_reporting(
        path, sensor, columns=column_map_from_args(args), altitude_datum=getattr(args, "altitude_datum", None)
    )


def altitude_from_args(args: argparse.Namespace) -> HeightSource:
    """How ``--h-m`` is read: its datum and whether ``--altitude-datum`` stated it."""
    return HeightSource.of_option(getattr(args, "altitude_datum", None), "--h-m")


def ellipsoidal_h_from_args(args: argparse.Namespace) -> float:
    """``--h-m`` as an ellipsoidal height: + N (bundled EGM96) for ``--altitude-datum egm96``."""
    if altitude_from_args(args).datum != "egm96":
        return args.h_m

    for name in ("lat_deg", "lon_deg", "h_m"):
        v = getattr(args, name)
        if not math.isfinite(v):
            raise ValueError(f"--{name.replace('_', '-')} {v}: not a finite number")
    if abs(args.lat_deg) > 90.0:
        raise ValueError(f"--lat-deg {args.lat_deg}: latitude must be in [-90, 90] deg")
    n = float(egm96_undulation(math.radians(args.lat_deg), math.radians(args.lon_deg)))
    return args.h_m + n


def pose_from_args(args: argparse.Namespace, sensor: Any) -> Pose:
    """The pose of the command line, with every joint angle the sensor's gimbal needs."""

    angles = parse_angles(getattr(args, "angle", []))
    given = {name: f"--angle {name}={v:g}" for name, v in angles.items()}
    for name in ("gimbal_roll", "gimbal_pitch"):
        v = getattr(args, f"{name}_deg", None)
        if v is not None:
            if name in angles:
                raise ValueError(f"--{name.replace('_', '-')}-deg and --angle {name}= both given")
            angles[name] = v
            given[name] = f"--{name.replace('_', '-')}-deg {v:g}"
    s = sensor
    # unchecked, --gimbal-roll-deg was ignored on a gimbal without it, and a misspelt
    # --angle tilt=-30 was reported as the missing elevation
    check_angle_names(given, s.angle_names, s.gimbal.name, defaults=("gimbal_roll", "gimbal_pitch"))
    q = {k: angles.pop(k, 0.0) for k in ("gimbal_roll", "gimbal_pitch")}
    return Pose.from_deg(
        args.lat_deg,
        args.lon_deg,
        ellipsoidal_h_from_args(args),
        args.heading_deg,
        args.pitch_deg,
        args.roll_deg,
        q["gimbal_roll"],
        q["gimbal_pitch"],
        angles_deg=angles,
    ).validate()


def run(args: argparse.Namespace) -> int:
    camera = sensor_from_args(args)
    pose = pose_from_args(args, camera)
    for name in ("row", "col"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise ValueError(f"{name} = {v} is not a finite pixel coordinate")
    sensor = camera  # sensor_from_args: a FrameSensor (a camera file's too)
    row = sensor.center_pixel[0] if args.row is None else args.row
    col = sensor.center_pixel[1] if args.col is None else args.col
    extra = {}
    if args.dem is not None:
        warn_datums("locate", args.dem_datum, HeightSource.of_option(getattr(args, "altitude_datum", None)))
    surface = surface_from_args(args)
    pipe = pipeline_from_args(args, sensor, surface)
    ground = pipe.locate(row, col, pose)
    if args.dem is not None:
        extra = {"method": args.method, "dem_evaluations": int(ground.dem_evaluations)}
        if args.method == "bisect":
            extra["hidden"] = bool(ground.hidden)
    else:
        kind = "geodetic" if args.height_kind == "inflated" else "inflated"
        other = dataclasses.replace(pipe, surface=HeightSurface(args.target_h_m, kind)).locate(row, col, pose)
        if int(other.status) == Status.OK:
            # the paper's inflated ellipsoid vs the exact constant-height surface
            extra["surface_difference_m"] = float(np.linalg.norm(ground.ecef - other.ecef))
    status = int(ground.status)
    if status != Status.OK:
        msg = f"no ground point for pixel ({row:g}, {col:g}): {describe(status, sensor.rows, sensor.cols)}"
        if args.json:
            print(json.dumps({"status": Status(status).name.lower(), "error": msg}))
        else:
            print(f"geoloc locate: {msg}", file=sys.stderr)
        return 1
    alt = altitude_from_args(args)
    out = {
        "lat_deg": float(ground.lat_deg),
        "lon_deg": float(ground.lon_deg),
        "h_m": float(ground.h),
        "slant_range_m": float(ground.slant_range),
        "row": float(row),
        "col": float(col),
        "status": "ok",
        "h_datum": ELLIPSOID_DATUM,
        "ac_h_m": float(pose.h) if np.ndim(pose.h) == 0 else float(np.ravel(pose.h)[0]),
        "ac_h_datum_input": alt.describe(),
        "corrections": pipe.corrections.label,
        "refraction_m": float(ground.refraction_m),
    }
    out.update(_grid_reference(out["lat_deg"], out["lon_deg"]))
    out.update(extra)
    for msg in _drone_height_warning(camera, pose, float(ground.h), surface, alt):
        print(f"geoloc locate: warning: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"lat {out['lat_deg']:.7f} deg  lon {out['lon_deg']:.7f} deg  h {out['h_m']:.2f} m"
            f"  (slant range {out['slant_range_m']:.1f} m)"
        )
        print(f"MGRS {out['mgrs']}  (USNG {out['usng']})")
        if "surface_difference_m" in out:
            print(
                f"inflated ellipsoid [Q17 eq. 11] vs exact constant-height surface: "
                f"{out['surface_difference_m'] * 1000:.1f} mm apart"
            )
        print(_locate_datum_line(alt, args.h_m, out["ac_h_m"]))
        print(_corrections_line(pipe.corrections, out["refraction_m"]))
    return 0


def _corrections_line(corrections, refraction_m: float) -> str:
    """The text output's line on the line-of-sight corrections (docs/refraction.md)."""
    if corrections.refraction is None:
        head = (
            "corrections: none (a straight line of sight, as the papers)"
            if not corrections
            else f"corrections: {corrections.label}"
        )
        return head + "; --refraction standard bends it through the standard atmosphere"
    return (
        f"corrections: {corrections.label}; refraction moved the point {refraction_m:.2f} m "
        "(U.S. Standard Atmosphere 1976)"
    )


def _drone_height_warning(camera, pose, target_h: float, surface, alt) -> list:
    """A drone sensor (its file's ``platform``) more than DRONE_MAX_HEIGHT_M above the terrain
    under it (with a DEM) or the target, or above DRONE_CEILING_M: one warning (docs/records.md,
    "Plausibility checks"); the point is still given as computed."""
    from geoloc.sensors.platform import (
        DRONE_CEILING_M,
        DRONE_MAX_HEIGHT_M,
        drone_height_hint,
        drone_height_where,
        drone_too_high,
        is_drone,
    )

    if not is_drone(getattr(camera, "platform", "")):
        return []
    h = float(np.ravel(pose.h)[0])
    terrain = terrain_of(surface)
    ground = None if terrain is None else terrain.sample(np.ravel(pose.lat)[:1], np.ravel(pose.lon)[:1])[0][0]
    high, ref, what = drone_too_high(h, target_h, ground)
    if not high:
        return []
    ref_m, ref_what = float(ref), str(what)
    return [
        f"{alt.column} = {h:.1f} m: a drone's camera (the sensor file's platform {camera.platform!r}) "
        f"{drone_height_where(h, ref_m, ref_what)}, while drones fly below "
        f"{DRONE_MAX_HEIGHT_M:.0f} m above the ground and {DRONE_CEILING_M:.0f} m above the sea: "
        f"{drone_height_hint(h, ref_m)}; the point is computed as given"
    ]


def _grid_reference(lat_deg: float, lon_deg: float) -> dict:
    """``mgrs`` (1 m) and ``usng`` of the ground point (geoloc.io.mgrs_grid)."""
    from geoloc.io.mgrs_grid import format_usng, latlon_to_mgrs

    text = str(latlon_to_mgrs(lat_deg, lon_deg).text[()])
    return {"mgrs": text, "usng": format_usng(text)}


def _locate_datum_line(alt: HeightSource, given: float, used: float) -> str:
    if alt.datum == "egm96":
        return (
            f"heights: aircraft --h-m {given:.2f} m read as {DATUM_TEXT['egm96']} (--altitude-datum), "
            f"used as {used:.2f} m ellipsoidal (N = {used - given:+.2f} m, bundled EGM96); "
            f"h is {ELLIPSOID_DATUM}"
        )
    how = "--altitude-datum" if alt.stated else "the default: not stated; --altitude-datum egm96 if it is MSL"
    return f"heights: aircraft --h-m read as {ELLIPSOID_DATUM} ({how}); h is {ELLIPSOID_DATUM}"
