"""``geoloc pixel``: which pixel sees a ground point (the inverse of ``geoloc locate``).

The ground point is given as latitude and longitude or as an MGRS / USNG reference
(:func:`geoloc.io.mgrs_grid.parse_mgrs`: the centre of the reference's square), at a
height given or read from the DEM. The sensor and its pose are those of ``geoloc locate``.
The answer is the sensor's ``ground_to_pixel`` (docs/architecture.md, "The Sensor
interface") and a verdict: in the frame, outside the frame, behind the camera, or, with a
DEM, hidden behind terrain (:func:`geoloc.locate.point_view`, the viewer's rule: the line of
sight through that pixel meets the terrain more than 1 m before the point).
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from geoloc.cli._options import (
    add_correction_options,
    add_dem_options,
    add_gimbal_options,
    add_pose_options,
    pipeline_from_args,
    sensor_from_args,
    surface_from_args,
)
from geoloc.cli.locate import pose_from_args
from geoloc.io.columns import ELLIPSOID_DATUM
from geoloc.io.mgrs_grid import mgrs_text, parse_mgrs
from geoloc.locate import point_view
from geoloc.status import Status, describe
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    "geoloc pixel --sensor assets/sensors/eo_turret.toml --lat-deg 36.6 --lon-deg -84.25 --h-m 2500 "
    "--heading-deg 45 --pitch-deg 2 --roll-deg 1 --angle azimuth=90 --angle elevation=-30 "
    "--mgrs 16SGF4865251608 --dem assets/dem/srtm_jacksboro.tif"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "pixel",
        help=VERB_HELP["pixel"],
        description="The inverse of `geoloc locate`: the pixel (1-based row, column) in which the "
        "sensor sees a ground point, given as --point-lat-deg/--point-lon-deg or --mgrs, at "
        "--point-h-m or at the DEM's height there; with a DEM, whether terrain hides it.",
    )
    add_pose_options(p.add_argument_group("aircraft (POS)"), required=True)
    add_gimbal_options(p.add_argument_group("gimbal and sensor"))
    g = p.add_argument_group("the ground point")
    g.add_argument(
        "--mgrs",
        default=None,
        metavar="REF",
        help="MGRS or USNG reference, e.g. 16SGF4866651490 (the centre of its square)",
    )
    g.add_argument("--point-lat-deg", type=float, default=None, help="latitude [deg]")
    g.add_argument("--point-lon-deg", type=float, default=None, help="longitude [deg, east +]")
    g.add_argument(
        "--point-h-m",
        type=float,
        default=None,
        help="height [m above the WGS 84 ellipsoid]; default with --dem: the DEM's height there",
    )
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    add_dem_options(p)
    add_correction_options(p)
    p.set_defaults(func=run)


def point_from_args(args: argparse.Namespace) -> tuple[float, float, str]:
    """(lat_deg, lon_deg, how it was given); errors name the option and the value."""
    has_ll = args.point_lat_deg is not None or args.point_lon_deg is not None
    if args.mgrs is not None and has_ll:
        raise ValueError("give the ground point once: --mgrs or --point-lat-deg/--point-lon-deg, not both")
    if args.mgrs is not None:
        lat, lon = parse_mgrs(args.mgrs)
        return lat, lon, f"MGRS {args.mgrs}"
    if args.point_lat_deg is None or args.point_lon_deg is None:
        raise ValueError("the ground point: give --mgrs REF, or both --point-lat-deg and --point-lon-deg")
    for name in ("point_lat_deg", "point_lon_deg"):
        v = getattr(args, name)
        if not math.isfinite(v):
            raise ValueError(f"--{name.replace('_', '-')} {v}: not a finite number")
    if abs(args.point_lat_deg) > 90.0:
        raise ValueError(f"--point-lat-deg {args.point_lat_deg}: latitude must be in [-90, 90] deg")
    return args.point_lat_deg, args.point_lon_deg, "latitude/longitude"


def run(args: argparse.Namespace) -> int:
    sensor = sensor_from_args(args)
    pose = pose_from_args(args, sensor)
    lat_deg, lon_deg, given = point_from_args(args)
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    surface = None
    if args.dem is not None:
        # the same surface `locate --dem` meets (mosaics, method, tolerances, datum)
        surface = surface_from_args(args)
    if args.point_h_m is not None:
        if not math.isfinite(args.point_h_m):
            raise ValueError(f"--point-h-m {args.point_h_m}: not a finite number")
        h, h_from = float(args.point_h_m), "--point-h-m"
    elif surface is not None:
        from geoloc.surfaces.base import terrain_of

        terrain = terrain_of(surface)
        assert terrain is not None  # --dem given: the surface reads that DEM
        h = float(np.asarray(terrain.height(np.asarray([lat]), np.asarray([lon])))[0])
        if not math.isfinite(h):
            raise ValueError(f"the DEM has no height at {lat_deg:.7f}, {lon_deg:.7f}: give --point-h-m")
        h_from = "the DEM"
    else:
        raise ValueError("the ground point's height: give --point-h-m H (ellipsoidal) or --dem FILE")
    pipe = pipeline_from_args(args, sensor, surface)
    if surface is not None:
        v = point_view(pipe, pose, lat, lon, h)
        st, row, col, occluder = v.pixel_status, v.row, v.col, v.occluder_range_m
        visible = v.visible if st == Status.OK else None
    else:
        px = pipe.ground_to_pixel(np.asarray(lat), np.asarray(lon), np.asarray(h), pose)
        st, row, col = int(np.asarray(px.status)), float(np.asarray(px.row)), float(np.asarray(px.col))
        visible, occluder = None, float("nan")
    if st == Status.BEHIND_CAMERA:
        verdict = "behind the camera"
    elif st == Status.OUTSIDE_SENSOR:
        verdict = "outside the frame"
    elif st != Status.OK:
        verdict = describe(st, sensor.rows, sensor.cols)
    elif visible is False:
        verdict = "hidden behind terrain from this camera"
    else:
        verdict = "in the frame" + ("" if visible else " (no DEM: not checked for terrain in the way)")
    out = {
        "row": row,
        "col": col,
        "status": Status(st).name.lower(),
        "verdict": verdict,
        "lat_deg": lat_deg,
        "lon_deg": lon_deg,
        "h_m": h,
        "h_datum": ELLIPSOID_DATUM,
        "h_from": h_from,
        "given": given,
        "visible": visible,
        "corrections": pipe.corrections.label,
    }
    if visible is not None and math.isfinite(occluder):
        out["occluder_range_m"] = occluder
    if args.json:
        print(json.dumps(out))
    else:
        print(f"pixel row {row:.3f}, column {col:.3f}: {verdict}")
        print(
            f"ground point {lat_deg:.7f} N, {lon_deg:.7f} E, h {h:.2f} m ({ELLIPSOID_DATUM}, from {h_from}); "
            f"{mgrs_text(lat_deg, lon_deg)}"
        )
        if visible is False:
            print(
                f"the line of sight through that pixel meets the terrain {occluder:.0f} m from the camera, "
                f"before the point"
            )
    return 0 if st == Status.OK and visible is not False else 1
