"""``geoloc klv``: MISB ST 0601 (UAS Datalink Local Set) KLV metadata.

``geoloc klv dump FILE [--out F]`` prints every decoded packet as one JSON object
a line (its byte offset, or pts for a container, then the decoded fields in tag
order; reserved error / out-of-range values as null with their ``flags``). Bad
packets go to stderr with their offset and reason; the good ones are still
printed. Exit code 0 if at least one good packet was decoded, else 1. Raw files
(``.klv``, ``.bin``, anything else) are read in chunks; ``.ts``, ``.m2ts``,
``.mpg``, ``.mp4``, ``.mov``, ``.mkv`` through PyAV. See docs/klv.md.
"""

from __future__ import annotations

import contextlib
import json
import sys
from pathlib import Path

from geoloc.cli._options import input_path, output_path


def register(sub) -> None:
    p = sub.add_parser(
        "klv",
        help="MISB ST 0601 KLV metadata: dump the decoded packets of a .klv/.bin or .ts file",
        description="MISB ST 0601 (UAS Datalink Local Set) KLV metadata (docs/klv.md).",
    )
    actions = p.add_subparsers(dest="klv_action", metavar="ACTION")
    d = actions.add_parser(
        "dump",
        help="print every packet as a JSON line",
        description="Print every decoded UAS LS packet of FILE as one JSON object a line: its byte "
        "offset (containers: the demuxer's packet position, pts and time_s), the decoded fields "
        "in tag order with their units in their names (platform_heading_deg, "
        "sensor_true_altitude_m [MSL], sensor_ellipsoid_height_m [HAE], ...; reserved error / "
        "out-of-range values as null, named in 'flags'), raw unknown items as hex and the "
        "checksum. Bad packets (checksum mismatch, truncated, wrong lengths, bytes that are no "
        "packet) are reported on stderr with their byte offset and reason; the good packets "
        "around them are still printed. Exit code 0 if at least one packet was good, else 1.",
    )
    d.add_argument("file", metavar="FILE", type=input_path,
                   help="raw KLV (.klv, .bin: concatenated packets) or a container (.ts, .m2ts, .mpg, .mp4)")
    d.add_argument("--out", default=None, type=output_path, help="write the JSON lines to this file instead of stdout")
    d.add_argument("--no-checksum", action="store_true",
                   help="do not verify the checksums (tag 1), nor require them")
    d.set_defaults(func=run)

    def usage(args) -> int:
        p.print_help(sys.stderr)
        return 2

    p.set_defaults(func=usage)


def run(args) -> int:
    from geoloc.io.klv import read_packets

    from geoloc.userfiles import atomic_path

    if Path(args.file).is_dir():
        raise ValueError(f"{args.file} is a folder: give a .klv, .bin or .ts file")
    results = read_packets(args.file, verify_checksum=not args.no_checksum)
    with contextlib.ExitStack() as stack:
        out = sys.stdout
        if args.out:
            tmp = stack.enter_context(atomic_path(args.out, "--out"))
            out = stack.enter_context(tmp.open("w", encoding="utf-8"))
        good, bad = _dump(args.file, results, out)
    if args.out:
        print(f"wrote {good} packets to {args.out}" + (f" ({bad} bad, see above)" if bad else ""),
              file=sys.stderr)
    if good == 0:
        print(f"geoloc klv: {args.file}: no good UAS LS packet", file=sys.stderr)
        return 1
    return 0


def _dump(name, results, out) -> tuple[int, int]:
    """Write each good packet as a JSON line to ``out``, report each bad one; returns (good, bad)."""
    from geoloc.io.klv import KlvError

    good = bad = 0
    for r in results:
        if isinstance(r, KlvError):
            bad += 1
            print(f"geoloc klv: {name}: {r}", file=sys.stderr)
            continue
        good += 1
        out.write(json.dumps(r.to_json(), ensure_ascii=False, allow_nan=False))
        out.write("\n")
    return good, bad
