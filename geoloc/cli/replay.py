"""``geoloc replay``: geolocate every flight-test record and compare with published and surveyed positions."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from geoloc.assets import DEFAULT_RECORDS, asset_path, resolve_user_path
from geoloc.cli.locate import add_records_options, add_sensor_option, load_camera, records_from_args
from geoloc.workflows.replay import (
    outside_sensor_messages,
    replay_at_height,
    summary_table,
    write_replay_csv,
)


def register(sub) -> None:
    p = sub.add_parser(
        "replay",
        help="replay flight-test records: locate each one and measure the errors",
        description="Locate every record of a flight-test CSV (columns of [Q17] Tables 3-4) and write "
        "every input column plus lat_deg, lon_deg, h_m, error_to_paper_m, error_to_truth_m "
        "(horizontal geodesic distances in metres; empty where the input has no such column). "
        "Bad rows are reported with their line number; the good rows still run.",
    )
    p.add_argument("records", nargs="?", default=None,
                   help="records CSV (default: the bundled assets/records/qiao2017_flight_tests.csv)")
    add_sensor_option(p)
    add_records_options(p)
    p.add_argument("--height-column", default=None,
                   help="column holding each target's ellipsoidal height [m], e.g. paper_height_m")
    p.add_argument("--target-h-m", type=float, default=None, help="one target height for every record [m]")
    p.add_argument("--surface", choices=["inflated", "geodetic"], default="inflated",
                   help="inflated ellipsoid of [Q17] eq. 11 (default) or the exact constant-height surface")
    p.add_argument("--out", default=None,
                   help="output CSV of every row (never the input file: refused)")
    p.add_argument("--print-rows", action="store_true",
                   help=f"print one line per record even with --out or more than {ROWS_SHOWN} "
                   "records (default: the per-record lines only without --out and for at most "
                   f"{ROWS_SHOWN} records; the per-flight summary always)")
    p.add_argument("--group-by", default="table", help="column that groups records into flights (default: table)")
    p.add_argument("--export", default=None, metavar="FILE",
                   help="also write the results to GIS: FILE.gpkg, .geojson, .kml or .czml "
                   "(points, truth, error vectors, track; docs/gis.md)")
    p.set_defaults(func=run, _terrain_hook=None)
    from geoloc.cli.terrain_options import add_dem_options, replay_hook

    add_dem_options(p, replay_hook)


#: Without --out, records up to this many are printed one line each (more: the summary only).
ROWS_SHOWN = 50


def _same_file(a, b) -> bool:
    a, b = Path(a), Path(b)
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def run(args) -> int:
    records_path = (resolve_user_path(args.records) if args.records is not None
                    else asset_path(*DEFAULT_RECORDS))
    if args.out and _same_file(args.out, records_path):
        raise ValueError(f"--out {args.out} is the input records file: refusing to overwrite it; "
                         "write the replay to another file")
    camera = load_camera(str(resolve_user_path(args.camera)) if args.camera else None)
    records = records_from_args(args, str(records_path), camera)
    if args._terrain_hook is not None:
        args.dem = str(resolve_user_path(args.dem))
        result = args._terrain_hook(args, records, camera)
    else:
        if args.height_column is None and args.target_h_m is None:
            raise ValueError("give --height-column (e.g. paper_height_m) or --target-h-m")
        result = replay_at_height(records, camera, args.height_column, args.target_h_m, args.surface)
    for msg in outside_sensor_messages(records, camera):
        print(f"geoloc replay: warning: {msg}", file=sys.stderr)
    rows = args.print_rows or (not args.out and len(records) <= ROWS_SHOWN)
    print(summary_table(result, args.group_by, rows=rows))
    print(records.datum_summary())
    if not rows and not args.out:
        print(f"({len(records)} records: per-record lines not printed; --out FILE writes them, "
              "--print-rows prints them)")
    if args.out:
        write_replay_csv(args.out, result)
        print(f"wrote {len(records)} rows to {args.out}")
    if args.export:
        _export(args, result)
    return 0


def _export(args, result) -> None:
    """``--export FILE``: the rows of ``--out`` (or of a temporary CSV) through geoloc.io.gis."""
    import tempfile

    from geoloc.io.gis import export, read_results

    with tempfile.TemporaryDirectory() as tmp:
        csv_path = args.out or str(Path(tmp) / "replay.csv")
        if not args.out:
            write_replay_csv(csv_path, result)
        group = args.group_by if args.group_by in result.records.header else None
        print(export(read_results(csv_path), args.export, group_by=group))
