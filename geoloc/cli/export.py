"""``geoloc export``: a results CSV out to GIS (GeoPackage, GeoJSON, KML, CZML) or to TAK as
Cursor-on-Target (a ``.cot`` file, or UDP datagrams with ``--cot udp://HOST:PORT``); see ``docs/gis.md``."""

from __future__ import annotations

import argparse
from pathlib import Path

from geoloc.cli._options import input_path, text_output_path
from geoloc.io.cot import DEFAULT_HOW, DEFAULT_STALE_S, DEFAULT_TYPE, TAK_SA_MULTICAST
from geoloc.io.gis import DEFAULT_EPOCH, EXTENSIONS, FORMATS, export, read_results
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    "geoloc replay --height-column paper_height_m --out results.csv",
    "geoloc export results.csv --out results.kml --format kml",
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help=VERB_HELP["export"],
        description="Write a results CSV (as `geoloc replay --out` writes it) to GIS layers: computed "
        "points, truth and reported points, error vectors, frame footprints and the platform track. "
        "GPKG/GeoJSON/CZML heights are above the WGS 84 ellipsoid; KML altitudes are EGM96 orthometric "
        "(KML altitudes are above sea level). GeoJSON writes one file per layer: OUT.geojson (points) "
        "and OUT_<layer>.geojson. Rows without a position are kept (empty geometry) and listed. "
        "--format cot (or OUT.cot) writes one Cursor-on-Target event a line per located point; "
        f"--cot udp://HOST:PORT sends them as UDP datagrams (TAK's SA multicast is {TAK_SA_MULTICAST}).",
    )
    p.add_argument("results", type=input_path, help="results CSV (e.g. from geoloc replay --out)")
    p.add_argument(
        "output",
        nargs="?",
        default=None,
        metavar="OUT",
        type=text_output_path,
        help="output file (.gpkg, .geojson/.json, .kml, .czml, .cot), as --out",
    )
    p.add_argument(
        "--out",
        default=None,
        type=text_output_path,
        help="output file (.gpkg, .geojson/.json, .kml, .czml, .cot; '-': standard output, for "
        "KML, CZML and CoT); required unless --cot",
    )
    p.add_argument(
        "--format",
        default=None,
        help=f"one of {', '.join(FORMATS + ('cot',))} (default: from the extension of --out: "
        f"{', '.join(list(EXTENSIONS) + ['.cot'])})",
    )
    p.add_argument(
        "--group-by",
        default=None,
        help="column that groups rows into flights for the track (default: table when present)",
    )
    p.add_argument(
        "--epoch",
        default=DEFAULT_EPOCH,
        help=f"ISO 8601 time that time_s counts from, and the start of the times synthesized "
        f"(one second per row) when there is no time column (default {DEFAULT_EPOCH})",
    )
    g = p.add_argument_group("Cursor-on-Target (TAK)")
    g.add_argument(
        "--cot",
        default=None,
        metavar="udp://HOST:PORT",
        help=f"send the CoT events as UDP datagrams (TAK's SA multicast: {TAK_SA_MULTICAST})",
    )
    g.add_argument(
        "--cot-type",
        default=DEFAULT_TYPE,
        help=f"CoT event type (default {DEFAULT_TYPE}: unknown ground; b-m-p-s-p-i: a spot map point)",
    )
    g.add_argument("--cot-how", default=DEFAULT_HOW, help=f"CoT how (default {DEFAULT_HOW}: machine, from imagery)")
    g.add_argument(
        "--cot-stale-s",
        type=float,
        default=DEFAULT_STALE_S,
        help=f"seconds the events stay valid (default {DEFAULT_STALE_S:g})",
    )
    p.set_defaults(func=run)


#: Formats written as one text file, so that ``--out -`` (standard output) can take them.
STDOUT_FORMATS = ("kml", "czml", "cot")


def run(args: argparse.Namespace) -> int:
    if args.output is not None and args.out is not None and args.output != args.out:
        raise ValueError(f"two outputs given ({args.output} and --out {args.out}): give one")
    args.out = args.out if args.out is not None else args.output
    if args.out == "-":
        fmt = (args.format or "").strip().lower()
        if not fmt:
            raise ValueError(
                "--out -: standard output has no extension to tell the format by: give --format "
                f"({', '.join(STDOUT_FORMATS)})"
            )
        if fmt not in STDOUT_FORMATS:
            why = "writes one file per layer" if fmt in ("geojson", "json") else "is a binary file"
            raise ValueError(
                f"--out - --format {args.format}: {args.format} {why}; standard output takes "
                f"{', '.join(STDOUT_FORMATS)}: give a file name"
            )
    is_cot = (args.format or "").strip().lower() == "cot" or (
        args.format is None and args.out is not None and Path(args.out).suffix.lower() == ".cot"
    )
    if args.out is None and args.cot is None:
        raise ValueError("give --out FILE, or --cot udp://HOST:PORT to send Cursor-on-Target events")
    if not is_cot and args.cot is None:
        # the path, not a table read here: export's errors then name the file
        print(export(args.results, args.out, args.format, group_by=args.group_by, epoch=args.epoch, require_rows=True))
        return 0
    from geoloc.io.cot import cot_events, parse_udp_url, send_udp, write_cot

    if args.cot is not None:
        parse_udp_url(args.cot)  # a bad URL is one clear line before any work
    if args.out is not None and not is_cot:
        raise ValueError(f"--cot sends Cursor-on-Target; --out {args.out} would need --format cot (or a .cot name)")
    table = read_results(args.results)
    if not table or not len(next(iter(table.values()))):
        raise ValueError(
            f"{args.results}: {'a header and no rows' if table else 'empty (no header line, no rows)'}"
            ": nothing to export"
        )
    ev = cot_events(
        table,
        source=Path(args.results).stem,
        cot_type=args.cot_type,
        how=args.cot_how,
        stale_s=args.cot_stale_s,
        epoch=args.epoch,
    )
    for _, why in ev.skipped:
        print(f"geoloc export: no CoT event for {why}")
    if args.out is not None:
        out = Path(args.out)
        write_cot(ev, out)
        print(f"wrote {len(ev.events)} Cursor-on-Target events to {out} ({len(ev.skipped)} rows without a position)")
    if args.cot is not None:
        n = send_udp(ev, args.cot)
        print(f"sent {n} Cursor-on-Target events to {args.cot}")
    return 0
