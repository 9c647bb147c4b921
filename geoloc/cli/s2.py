"""``geoloc s2``: Sentinel-2 L1B direct-location grids, and the pixel of a ground point.

See docs/sentinel2.md. Degrees and metres at this edge.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from geoloc.cli import VERB_HELP
from geoloc.cli._options import (
    add_correction_options,
    add_dem_options,
    add_target_options,
    check_suffix,
    corrections_from_args,
    input_path,
    output_path,
)

#: The trimmed Sen2VM test product of a checkout (tests/data/sentinel2/README.md): the examples'
#: input, by absolute path, as the examples run from any folder (it is test data, not bundled)
_TDS1 = (Path(__file__).resolve().parents[2] / "tests" / "data" / "sentinel2" / "L1B").as_posix()
#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    f"geoloc s2 grid {_TDS1} --band B01 --detector 6 --step 100 --geoid --out grid.tif",
    f"geoloc s2 pixel {_TDS1} --band B02 --detector 6 --lat 33.4436 --lon -17.53 --geoid",
)


def _common(p) -> None:
    p.add_argument("product", type=input_path, help="the L1B product folder (holding DATASTRIP and GRANULE)")
    p.add_argument("--band", required=True, help="band: B01 .. B12, B8A")
    p.add_argument("--detector", required=True, help="detector: 1 .. 12")
    p.add_argument("--gipp", type=input_path, help="folder of the GIPP files (default PRODUCT/GIPP)")
    p.add_argument(
        "--iers",
        type=input_path,
        help="IERS Bulletin A file (AUX_UT1UTC; default PRODUCT/IERS/*UT1UTC*, else the datastrip's own IERS bulletin)",
    )
    p.add_argument("--no-refining", action="store_true", help="ignore the product's refining corrections")
    add_correction_options(p)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "s2",
        help=VERB_HELP["s2"],
        description="Sentinel-2 L1B's rigorous model (docs/sentinel2.md): GPS orbit, attitude quaternions, "
        "line dating, GIPP viewing directions and spacecraft model, Earth orientation from the product's "
        "IERS values. Light-time and aberration of light are on by default (as Orekit Rugged); Sen2VM's "
        "grids are made with both off (--no-light-time --no-aberration).",
    )
    actions = p.add_subparsers(dest="s2_action", metavar="ACTION")
    g = actions.add_parser(
        "grid",
        help="a direct-location grid GeoTIFF (longitude, latitude, height) at a step in pixels",
        description="Write Sen2VM's kind of direct-location grid for a band and detector: the ground "
        "point of every STEP-th pixel of every STEP-th line, over a granule or the whole datastrip, "
        "as a 3-band float64 GeoTIFF (lon_deg, lat_deg, h_m ellipsoidal), written to a temporary "
        "file then renamed.",
    )
    _common(g)
    g.add_argument(
        "--step",
        type=float,
        default=None,
        help="grid step [pixels of the band] (default: 600 / 300 / 100 for 10 / 20 / 60 m bands, Sen2VM's)",
    )
    g.add_argument("--granule", type=int, default=None, help="the detector's N-th granule only (1-based; default: all)")
    g.add_argument("--out", required=True, type=output_path, help="GeoTIFF to write")
    _height_options(g)
    g.set_defaults(func=run_grid)
    px = actions.add_parser(
        "pixel",
        help="the pixel (row, column) of a band and detector that sees a ground point",
        description="Inverse location: the 1-based row (line of the detector's datastrip) and column of "
        "a band and detector that see --lat/--lon at --target-h-m (ellipsoidal) or on the geoid, as JSON.",
    )
    _common(px)
    px.add_argument("--lat", type=float, required=True, help="latitude [deg]")
    px.add_argument("--lon", type=float, required=True, help="longitude [deg]")
    _height_options(px, dem=False)
    px.set_defaults(func=run_pixel)
    p.set_defaults(func=usage)


def _height_options(p, dem: bool = True) -> None:
    add_target_options(p, height_column=False)
    p.add_argument(
        "--geoid", action="store_true", help="the EGM96 geoid (the sea; Sen2VM's ground where its DEM has no tile)"
    )
    p.add_argument(
        "--geoid-grid",
        type=input_path,
        default=None,
        metavar="FILE",
        help="with --geoid: the geoid of this raster of geoid heights [m above WGS 84; north-up, geographic, "
        "nodes at pixel centres], e.g. Sen2VM's S2__OPER_DEM_GEOIDF (EGM2008) as a GeoTIFF; default the bundled EGM96",
    )
    if dem:
        add_dem_options(p, tolerances=False)


def usage(args: argparse.Namespace) -> int:
    print("geoloc s2: give an action: grid or pixel (geoloc s2 --help)")
    return 2


def _product_and_sensor(args):
    from geoloc.io.sentinel2 import read_product

    prod = read_product(args.product, gipp=args.gipp, iers=args.iers)
    sensor = prod.sensor(args.band, args.detector, refining=not args.no_refining)
    return prod, sensor


def _one_surface(args, dem_option: bool = True) -> list:
    if args.geoid_grid is not None and not args.geoid:
        raise ValueError(f"--geoid-grid = {str(args.geoid_grid)!r}: goes with --geoid (the surface it describes)")
    opts = [("--target-h-m", args.target_h_m is not None), ("--geoid", args.geoid)]
    if dem_option:
        opts.append(("--dem", args.dem))
    given = [n for n, on in opts if on]
    if len(given) != 1:
        names = ", ".join(n for n, _ in opts)
        raise ValueError(f"give exactly one of {names} (given: {', '.join(given) or 'none'})")
    if args.target_h_m is not None and not math.isfinite(args.target_h_m):
        raise ValueError(f"--target-h-m = {args.target_h_m!r}: must be a finite height in metres")
    return given


def _undulation(args):
    """The geoid N(lat, lon) of --geoid-grid, or None (the bundled EGM96)."""
    from geoloc.geodesy.geoid import grid_undulation

    return None if args.geoid_grid is None else grid_undulation(args.geoid_grid)


def _geoid_name(args) -> str:
    return "EGM96 (geoloc's bundled grid)" if args.geoid_grid is None else Path(args.geoid_grid).name


def run_grid(args: argparse.Namespace) -> int:
    from geoloc.cli._options import surface_from_args
    from geoloc.io.sentinel2 import band_info
    from geoloc.workflows.sentinel2 import DEFAULT_STEPS, direct_grid, grid_pixels, write_grid

    check_suffix("--out", args.out)
    given = _one_surface(args)
    band, _, size, _ = band_info(args.band)
    step = DEFAULT_STEPS[size] if args.step is None else args.step
    prod, sensor = _product_and_sensor(args)
    first, nrows = 1, None
    gid = "all"
    if args.granule is not None:
        g = prod.granule(args.detector, args.granule)
        first, nrows, gid = g.first_row(band), g.shape(band)[0], g.granule_id
    rows, cols = grid_pixels(sensor, step, first, nrows)
    surface = surface_from_args(args) if args.dem else None
    corr = corrections_from_args(args, sensor)
    lon, lat, h, status = direct_grid(
        sensor,
        rows,
        cols,
        surface=surface,
        height_m=args.target_h_m,
        geoid=args.geoid,
        corrections=corr,
        height_kind=args.height_kind,
        undulation=_undulation(args),
    )
    write_grid(
        args.out,
        lon,
        lat,
        h,
        rows,
        cols,
        {
            "band": band,
            "detector": f"{int(str(args.detector).lstrip('Dd')):02d}",
            "granule": gid,
            "surface": given[0],
            **({"geoid": _geoid_name(args)} if args.geoid else {}),
            "corrections": ",".join(corr.names) or "none",
            "refining": "off" if args.no_refining else "on",
            "eop": prod.eop_source,
        },
    )
    bad = int(np.sum(status != 0))
    print(
        f"{sensor.name}: {len(rows)} x {len(cols)} points (rows {rows[0]:g}..{rows[-1]:g}, step {step:g}), "
        f"corrections {', '.join(corr.names) or 'none'}; {bad} without a ground point; wrote {args.out}"
    )
    return 0


def run_pixel(args: argparse.Namespace) -> int:
    from geoloc.geodesy.geoid import egm96_undulation
    from geoloc.pipeline import Pipeline
    from geoloc.status import describe
    from geoloc.surfaces.height import HeightSurface

    if not (math.isfinite(args.lat) and -90 <= args.lat <= 90):
        raise ValueError(f"--lat = {args.lat!r}: must be in [-90, 90] degrees")
    if not math.isfinite(args.lon):
        raise ValueError(f"--lon = {args.lon!r}: must be a finite longitude in degrees")
    _one_surface(args, dem_option=False)
    _, sensor = _product_and_sensor(args)
    lat, lon = math.radians(args.lat), math.radians(args.lon)
    N = _undulation(args) or egm96_undulation
    h = float(N(lat, lon)) if args.geoid else args.target_h_m
    if not math.isfinite(h):
        raise ValueError(f"--geoid-grid = {str(args.geoid_grid)!r}: has no geoid height at {args.lat}, {args.lon} deg")
    corr = corrections_from_args(args, sensor)
    px = Pipeline(sensor, HeightSurface(h, args.height_kind), corr).ground_to_pixel(
        np.array([lat]), np.array([lon]), np.array([h])
    )
    st = int(px.status[0])
    out = {
        "band": args.band,
        "detector": args.detector,
        "lat_deg": args.lat,
        "lon_deg": args.lon,
        "h_m": h,
        "h_datum": "WGS 84 ellipsoid" + (f" (geoid height: {_geoid_name(args)})" if args.geoid else ""),
        "row": None if not np.isfinite(px.row[0]) else float(px.row[0]),
        "col": None if not np.isfinite(px.col[0]) else float(px.col[0]),
        "status": describe(st) if st else "ok",
        "corrections": list(corr.names),
    }
    print(json.dumps(out))
    return 0 if st == 0 else 1
