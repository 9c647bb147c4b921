"""``geoloc locate``: geolocate one pixel from the aircraft pose, gimbal angles and a camera."""

from __future__ import annotations

import json
import math
import sys

import numpy as np

from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.frames.chain import Pose
from geoloc.io.records import Records, load_records
from geoloc.locate import line_of_sight
from geoloc.sensors.camera import Camera
from geoloc.status import Status, describe
from geoloc.surfaces.height import intersect_los_height


def register(sub) -> None:
    p = sub.add_parser(
        "locate",
        help="geolocate one pixel (aircraft pose + gimbal angles + camera + target height)",
        description="Geolocate one pixel: aircraft position and attitude, gimbal encoder angles, "
        "a camera file and a target height give the target's latitude, longitude and height "
        "([Q17] eq. 4-13). Angles in degrees, heights ellipsoidal in metres.",
    )
    g = p.add_argument_group("aircraft (POS)")
    g.add_argument("--lat-deg", type=float, required=True, help="aircraft geodetic latitude [deg]")
    g.add_argument("--lon-deg", type=float, required=True, help="aircraft longitude [deg, east +]")
    g.add_argument("--h-m", type=float, required=True, help="aircraft ellipsoidal height [m]")
    g.add_argument("--heading-deg", type=float, default=0.0, help="heading psi [deg] (default 0)")
    g.add_argument("--pitch-deg", type=float, default=0.0, help="pitch theta, nose up + [deg]")
    g.add_argument("--roll-deg", type=float, default=0.0, help="roll phi, right wing down + [deg]")
    g = p.add_argument_group("gimbal and camera")
    g.add_argument("--gimbal-roll-deg", type=float, default=0.0,
                   help="outer gimbal (roll) angle [deg]; negative looks right of track")
    g.add_argument("--gimbal-pitch-deg", type=float, default=0.0, help="inner gimbal (pitch) angle [deg]")
    g.add_argument("--camera", default=None,
                   help="camera TOML file (default: the bundled assets/cameras/qiao2017.toml)")
    g.add_argument("--row", type=float, default=None, help="pixel row i, 1-based (default: CCD centre)")
    g.add_argument("--col", type=float, default=None, help="pixel column j, 1-based (default: CCD centre)")
    g = p.add_argument_group("target")
    g.add_argument("--target-h-m", type=float, default=None,
                   help="target ellipsoidal height [m] (required unless a DEM is given)")
    g.add_argument("--surface", choices=["inflated", "geodetic"], default="inflated",
                   help="inflated ellipsoid of [Q17] eq. 11 (default) or the exact constant-height surface")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(func=run, _terrain_hook=None)
    from geoloc.cli.terrain_options import add_dem_options, locate_hook

    add_dem_options(p, locate_hook)


def load_camera(path) -> Camera:
    return Camera.from_toml(path if path else asset_path(*DEFAULT_CAMERA))


def load_records_reporting(path) -> Records:
    """Records from ``path`` (default: the bundled flight test); each rejected row is
    reported on stderr with its line, and no good row at all is an error."""
    records = load_records(path if path else asset_path(*DEFAULT_RECORDS))
    for err in records.errors:
        print(f"{records.path}: skipped {err}", file=sys.stderr)
    if len(records) == 0:
        raise ValueError(f"{records.path}: no valid record")
    return records


def pose_from_args(args) -> Pose:
    return Pose.from_deg(args.lat_deg, args.lon_deg, args.h_m, args.heading_deg, args.pitch_deg,
                         args.roll_deg, args.gimbal_roll_deg, args.gimbal_pitch_deg).validate()


def run(args) -> int:
    camera = load_camera(args.camera)
    pose = pose_from_args(args)
    for name in ("row", "col"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise ValueError(f"{name} = {v} is not a finite pixel coordinate")
    row = camera.center_pixel[0] if args.row is None else args.row
    col = camera.center_pixel[1] if args.col is None else args.col
    los = line_of_sight(pose, camera, row, col)
    extra = {}
    if args._terrain_hook is not None:
        ground, extra = args._terrain_hook(args, los)
    else:
        if args.target_h_m is None:
            raise ValueError("--target-h-m is required (the target's ellipsoidal height in metres)")
        ground = intersect_los_height(los, args.target_h_m, args.surface)
        other = intersect_los_height(los, args.target_h_m,
                                     "geodetic" if args.surface == "inflated" else "inflated")
        if int(other.status) == Status.OK:
            # the paper's inflated ellipsoid vs the exact constant-height surface
            extra["surface_difference_m"] = float(np.linalg.norm(ground.ecef - other.ecef))
    status = int(ground.status)
    if status != Status.OK:
        msg = f"no ground point for pixel ({row:g}, {col:g}): {describe(status)}"
        if args.json:
            print(json.dumps({"status": Status(status).name.lower(), "error": msg}))
        else:
            print(f"geoloc locate: {msg}")
        return 1
    out = {
        "lat_deg": float(ground.lat_deg),
        "lon_deg": float(ground.lon_deg),
        "h_m": float(ground.h),
        "slant_range_m": float(ground.slant_range),
        "row": float(row),
        "col": float(col),
        "status": "ok",
    }
    out.update(extra)
    if args.json:
        print(json.dumps(out))
    else:
        print(f"lat {out['lat_deg']:.7f} deg  lon {out['lon_deg']:.7f} deg  h {out['h_m']:.2f} m"
              f"  (slant range {out['slant_range_m']:.1f} m)")
        if "surface_difference_m" in out:
            print(f"inflated ellipsoid [Q17 eq. 11] vs exact constant-height surface: "
                  f"{out['surface_difference_m'] * 1000:.1f} mm apart")
    return 0
