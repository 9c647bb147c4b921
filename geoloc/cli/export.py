"""``geoloc export``: a results CSV out to GIS (GeoPackage, GeoJSON, KML, CZML); see ``docs/gis.md``."""

from __future__ import annotations

from geoloc.cli._options import input_path, output_path
from geoloc.io.gis import DEFAULT_EPOCH, EXTENSIONS, FORMATS, export, read_results


def register(sub) -> None:
    p = sub.add_parser(
        "export",
        help="write replay results to GeoPackage, GeoJSON, KML or CZML",
        description="Write a results CSV (as `geoloc replay --out` writes it) to GIS layers: computed "
        "points, truth and reported points, error vectors, frame footprints and the platform track. "
        "GPKG/GeoJSON/CZML heights are above the WGS 84 ellipsoid; KML altitudes are EGM96 orthometric "
        "(KML altitudes are above sea level). GeoJSON writes one file per layer: OUT.geojson (points) "
        "and OUT_<layer>.geojson. Rows without a position are kept (empty geometry) and listed.",
    )
    p.add_argument("results", type=input_path, help="results CSV (e.g. from geoloc replay --out)")
    p.add_argument("--out", required=True, type=output_path, help="output file (.gpkg, .geojson/.json, .kml, .czml)")
    p.add_argument("--format", default=None,
                   help=f"one of {', '.join(FORMATS)} (default: from the extension of --out: "
                   f"{', '.join(EXTENSIONS)})")
    p.add_argument("--group-by", default=None,
                   help="column that groups rows into flights for the track (default: table when present)")
    p.add_argument("--epoch", default=DEFAULT_EPOCH,
                   help=f"ISO 8601 time that time_s counts from, and the start of the times synthesized "
                   f"(one second per row) when there is no time column (default {DEFAULT_EPOCH})")
    p.set_defaults(func=run)


def run(args) -> int:
    table = read_results(args.results)
    summary = export(table, args.out, args.format, group_by=args.group_by, epoch=args.epoch)
    print(summary)
    return 0
