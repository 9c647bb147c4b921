"""``geoloc replay``: geolocate every flight-test record and compare with published and surveyed positions."""

from __future__ import annotations

from geoloc.cli.locate import load_camera, load_records_reporting
from geoloc.workflows.replay import replay_at_height, summary_table, write_replay_csv


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
    p.add_argument("--camera", default=None, help="camera TOML (default: bundled qiao2017.toml)")
    p.add_argument("--height-column", default=None,
                   help="column holding each target's ellipsoidal height [m], e.g. paper_height_m")
    p.add_argument("--target-h-m", type=float, default=None, help="one target height for every record [m]")
    p.add_argument("--surface", choices=["inflated", "geodetic"], default="inflated",
                   help="inflated ellipsoid of [Q17] eq. 11 (default) or the exact constant-height surface")
    p.add_argument("--out", default=None, help="output CSV (default: print the summary only)")
    p.add_argument("--group-by", default="table", help="column that groups records into flights (default: table)")
    p.set_defaults(func=run, _terrain_hook=None)
    from geoloc.cli.terrain_options import add_dem_options, replay_hook

    add_dem_options(p, replay_hook)


def run(args) -> int:
    records = load_records_reporting(args.records)
    camera = load_camera(args.camera)
    if args._terrain_hook is not None:
        result = args._terrain_hook(args, records, camera)
    else:
        if args.height_column is None and args.target_h_m is None:
            raise ValueError("give --height-column (e.g. paper_height_m) or --target-h-m")
        result = replay_at_height(records, camera, args.height_column, args.target_h_m, args.surface)
    print(summary_table(result, args.group_by))
    if args.out:
        write_replay_csv(args.out, result)
        print(f"wrote {len(records)} rows to {args.out}")
    return 0
