"""``geoloc ortho``: every pixel of one frame onto the terrain, as a GeoTIFF; a photo's orthophoto.

The pose comes from the command line (the options of ``geoloc locate``), from one
record of a records CSV (``--record LABEL --records CSV``) or from a DJI photo
(``--photo JPG``: its sensor and pose, ``docs/photos.md``). The surface is a DEM
(``--dem``; default a bundled DEM that covers the aircraft) or a constant height
(``--target-h-m``). Writes ``--out FILE.tif`` (bands lat_deg, lon_deg, h_m, status on
the image grid: :func:`geoloc.workflows.ortho.write_frame_geotiff`) and, for a photo,
``--ortho-out FILE.tif --gsd-m M`` (:func:`geoloc.workflows.ortho.orthorectify`).
Docs: ``docs/ortho.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from geoloc.assets import asset_path
from geoloc.cli import VERB_HELP
from geoloc.cli._options import (
    add_columns_option,
    add_correction_options,
    add_dem_options,
    add_gimbal_options,
    add_pose_options,
    add_progress_options,
    add_target_options,
    check_crs,
    check_suffix,
    corrections_from_args,
    input_path,
    output_path,
    sensor_from_args,
    surface_from_args,
)
from geoloc.cli.locate import pose_from_args, records_from_args
from geoloc.extras import require
from geoloc.io.columns import ELLIPSOID_DATUM
from geoloc.surfaces.base import terrain_of

POSE_FIELDS = ("lat_deg", "lon_deg", "h_m")


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc ortho --record T3-1 --step 256 --out frame.tif"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ortho",
        help=VERB_HELP["ortho"],
        description="Locate every pixel (or every --step-th) of one frame on the terrain in one call and "
        "write the per-pixel latitude, longitude and ellipsoidal height (WGS 84) as a GeoTIFF on the "
        "image grid, with a status band; for a drone photo also an orthorectified image (--ortho-out). "
        "The pose: the aircraft options below (as geoloc locate), or --record LABEL [--records CSV], "
        "or --photo JPG. Angles in degrees, heights in metres.",
    )
    g = p.add_argument_group("pose (as geoloc locate), or --record, or --photo")
    add_pose_options(g, required=False, datum_what="--h-m, the records' ac_h_m or the photo's altitude")
    add_gimbal_options(g)
    g.add_argument(
        "--record",
        default=None,
        metavar="LABEL",
        help="take the pose from this record of --records (its label: table-point, e.g. T3-1, or 'line N')",
    )
    g.add_argument(
        "--records",
        default=None,
        metavar="CSV",
        type=input_path,
        help="records CSV for --record (default: the bundled assets/records/qiao2017_flight_tests.csv)",
    )
    add_columns_option(g)
    g.add_argument(
        "--photo",
        default=None,
        metavar="JPG",
        type=input_path,
        help="a DJI photo: its own sensor (or --sensor's lens) and pose; enables --ortho-out",
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "--out",
        required=True,
        metavar="FILE.tif",
        type=output_path,
        help="GeoTIFF on the image grid: bands lat_deg, lon_deg, h_m (ellipsoidal), status",
    )
    o.add_argument("--step", type=int, default=1, help="every Nth pixel in both directions (default 1: all)")
    o.add_argument(
        "--chunk",
        type=int,
        default=None,
        help="rays per call of the DEM solver (default 262144; memory is bounded by it)",
    )
    o.add_argument(
        "--ortho-out",
        default=None,
        metavar="FILE.tif",
        type=output_path,
        help="with --photo: the orthorectified photo (RGB + alpha), north-up",
    )
    o.add_argument("--gsd-m", type=float, default=None, help="cell size of --ortho-out [m] (required with it)")
    o.add_argument(
        "--ortho-crs",
        default="geographic",
        help="grid of --ortho-out: geographic (EPSG:4326, default), utm (the zone of the "
        "footprint) or a CRS such as EPSG:32617",
    )
    o.add_argument(
        "--serial",
        action="store_true",
        help="run the DEM solver on one core (default: all cores, numba threads); the same hits",
    )
    o.add_argument("--json", action="store_true", help="print a JSON summary")
    add_target_options(p, height_column=False)
    add_progress_options(p)
    p.set_defaults(func=run)
    add_dem_options(p)
    add_correction_options(p)


def _bundled_dem(lat_deg: float, lon_deg: float):
    """The finest bundled DEM (assets/dem/*.tif) whose bounds contain (lat, lon), or None."""
    import rasterio

    best = None
    for path in sorted(Path(asset_path("dem")).glob("*.tif")):
        with rasterio.open(path) as src:
            b = src.bounds
            if (
                src.crs is not None
                and src.crs.is_geographic
                and b.left <= lon_deg <= b.right
                and b.bottom <= lat_deg <= b.top
            ):
                if best is None or abs(src.res[0]) < best[0]:
                    best = (abs(src.res[0]), path)
    return None if best is None else best[1]


def _pose(args):
    """(sensor, pose, photo meta or None, where the pose came from)."""
    given = [
        name
        for name, on in (
            ("--photo", args.photo),
            ("--record", args.record),
            ("--lat-deg/--lon-deg/--h-m", any(getattr(args, k) is not None for k in POSE_FIELDS)),
        )
        if on
    ]
    if len(given) > 1:
        raise ValueError(f"the pose is given twice ({' and '.join(given)}): use one of them")
    if args.photo:
        from geoloc.io.photos import photo_sensor, pose_from_photo, read_photo

        path = args.photo
        meta = read_photo(path)
        user = sensor_from_args(args) if args.camera else None
        sensor, lens = photo_sensor(meta, user)
        pose = pose_from_photo(meta, args.altitude_datum or "egm96")
        return sensor, pose, meta, f"photo {meta.name} (lens: {lens})"
    camera = sensor = sensor_from_args(args)  # a FrameSensor (a camera file's too)
    if args.record:
        records = records_from_args(args, args.records, camera)
        labels = records.labels()
        if args.record not in labels:
            from geoloc.io.records import describe_labels

            raise ValueError(
                f"--record {args.record!r}: no such record in {records.path} ({describe_labels(args.record, labels)})"
            )
        k = labels.index(args.record)
        pose = records.subset([k]).pose().validate()
        return sensor, pose, None, f"record {args.record} of {records.path} ({records.altitude.describe()})"
    missing = [f"--{k.replace('_', '-')}" for k in POSE_FIELDS if getattr(args, k) is None]
    if missing:
        raise ValueError(f"no pose: give {', '.join(missing)} (or --record LABEL, or --photo JPG)")
    return sensor, pose_from_args(args, camera), None, "command line"


def _surface(args, pose):
    """The surface of the shared options (:func:`geoloc.cli._options.surface_from_args`); without
    ``--dem`` and ``--target-h-m``, the finest bundled DEM that covers the aircraft."""

    if args.target_h_m is not None:
        if args.dem:
            raise ValueError("--dem and --target-h-m both given: the surface is one or the other")
        if not math.isfinite(args.target_h_m):
            raise ValueError(f"--target-h-m {args.target_h_m}: not a finite height")
        return surface_from_args(args), f"constant height {args.target_h_m:g} m ({args.height_kind})"
    if not args.dem:
        lat, lon = (float(np.rad2deg(np.ravel(v)[0])) for v in (pose.lat, pose.lon))
        args.dem = _bundled_dem(lat, lon)
        if args.dem is None:
            raise ValueError(
                f"no --dem and no bundled DEM covers the aircraft at {lat:.5f}, {lon:.5f} deg: "
                "give --dem FILE or --target-h-m"
            )
        args.dem = str(args.dem)
    shown = ", ".join(Path(p).name for p in args.dem) if isinstance(args.dem, list) else Path(args.dem).name
    return surface_from_args(args), f"DEM {shown} ({args.method}, {args.dem_model}; its heights {args.dem_datum})"


def run(args: argparse.Namespace) -> int:
    from geoloc.workflows.ortho import (
        DEFAULT_CHUNK,
        orthorectify,
        read_photo_pixels,
        write_frame_geotiff,
    )

    if isinstance(args.step, bool) or args.step < 1:
        raise ValueError(f"--step {args.step}: must be a whole number of pixels >= 1")
    chunk = DEFAULT_CHUNK if args.chunk is None else args.chunk
    if chunk < 1:
        raise ValueError(f"--chunk {chunk}: must be a whole number of rays >= 1")
    if args.ortho_out and not args.photo:
        raise ValueError("--ortho-out needs --photo (the image to orthorectify)")
    if args.ortho_out and args.gsd_m is None:
        raise ValueError("--ortho-out needs --gsd-m (the orthophoto's cell size in metres)")
    if args.gsd_m is not None and not (math.isfinite(args.gsd_m) and args.gsd_m > 0):
        raise ValueError(f"--gsd-m {args.gsd_m}: must be a positive number of metres")
    out = Path(args.out)
    check_suffix("--out", args.out)
    if args.ortho_out:  # before any pixel is located (a bad CRS used to fail after all of them)
        check_crs("--ortho-crs", args.ortho_crs)
        check_suffix("--ortho-out", args.ortho_out)
    sensor, pose, meta, pose_from = _pose(args)
    surface, surface_text = _surface(args, pose)
    if args.ortho_out:  # checked before the first output is written
        if terrain_of(surface) is None:
            raise ValueError("--ortho-out needs a DEM (--dem or a bundled one), not --target-h-m")
    image = None
    if args.ortho_out:  # the photo's pixels read (and OpenCV found) before the first output is written
        require("cv2", "--ortho-out (a photo's pixels)")
        image = read_photo_pixels(Path(meta.path))
        if image.shape[1:] != (sensor.rows, sensor.cols):
            raise ValueError(
                f"--photo {meta.path}: its pixels are {image.shape[2]} x {image.shape[1]}, "
                f"the sensor's {sensor.cols} x {sensor.rows}"
            )
    corrections = corrections_from_args(args, sensor)
    tags = {
        "pose": pose_from,
        "surface": surface_text,
        "sensor": getattr(sensor, "name", "") or "frame sensor",
        "corrections": corrections.label,
    }
    t0 = time.perf_counter()
    info = write_frame_geotiff(
        out,
        sensor,
        pose,
        surface,
        step=args.step,
        chunk=chunk,
        tags=tags,
        parallel=not args.serial,
        corrections=corrections,
        progress=args.progress,
    )
    info["seconds"] = time.perf_counter() - t0
    info.update(pose=pose_from, surface=surface_text, h_datum=ELLIPSOID_DATUM, corrections=corrections.label)
    if args.ortho_out:
        terrain = terrain_of(surface)
        assert image is not None and terrain is not None  # both checked above, before any output
        info["ortho"] = orthorectify(
            image,
            sensor,
            pose,
            terrain,
            args.ortho_out,
            gsd_m=args.gsd_m,
            crs=args.ortho_crs,
            chunk=chunk,
            tags={"photo": meta.name},
            parallel=not args.serial,
            corrections=corrections,
            progress=args.progress,
        )
    if args.json:
        print(json.dumps(info))
    else:
        n = info["shape"][0] * info["shape"][1]
        counts = ", ".join(f"{k} {v}" for k, v in info["counts"].items())
        print(
            f"{out}: {info['shape'][0]} x {info['shape'][1]} pixels (step {args.step}), {n} rays in "
            f"{info['seconds']:.2f} s; {counts}"
        )
        print(f"pose: {pose_from}; surface: {surface_text}; h is {ELLIPSOID_DATUM}")
        if "ortho" in info:
            o = info["ortho"]
            print(
                f"{o['path']}: orthophoto {o['width']} x {o['height']} cells of {o['gsd_m']:g} m ({o['crs']}), "
                f"{o['cells_seen']} seen, {o['cells_hidden']} hidden behind terrain"
            )
    bad = info["counts"].get("ok", 0) == 0
    if bad:
        print("geoloc ortho: warning: no pixel has a ground point", file=sys.stderr)
    return 1 if bad else 0
