"""``geoloc klv``: MISB ST 0601 (UAS Datalink Local Set) KLV metadata.

``geoloc klv dump FILE [--out F]`` prints every decoded packet as one JSON object
a line (its byte offset, or pts for a container, then the decoded fields in tag
order; reserved error / out-of-range values as null with their ``flags``). Bad
packets go to stderr with their offset and reason; the good ones are still
printed. A quirk of the writer that leaves the values unambiguous (an item at
another length than the standard's, an EG 0104 universal set, ...) keeps the
packet and is reported once per kind at the end, with a count and the first
packet's offset. Exit code (docs/cli.md): 0 every packet decoded, 1 some could
not be (each named on stderr), 2 none could (or bad usage). Raw files
(``.klv``, ``.bin``, anything else) are read in chunks; ``.ts``, ``.m2ts``,
``.mpg``, ``.mp4``, ``.mov``, ``.mkv`` through PyAV.

``geoloc klv fix IN --out OUT [--dem DEM] [--sensor FILE]`` writes a copy of IN
whose frame-centre and corner items are geoloc's replay of each packet
(:func:`geoloc.workflows.klv_fix.fix_klv`). See docs/klv.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from geoloc.cli._options import input_path, output_path, text_output_path
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    "geoloc klv dump assets/klv/example_flight.klv --out packets.jsonl",
    "geoloc klv fix assets/klv/example_flight.klv --out fixed.klv",
    "geoloc klv send assets/klv/example_flight.ts udp://127.0.0.1:9 --fast",
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "klv",
        help=VERB_HELP["klv"],
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
        "around them are still printed. A writer's quirk that leaves the values unambiguous (an item "
        "at another length than the standard's, an EG 0104 universal set, a nested set that cannot be "
        "read) keeps the packet and is reported once per kind, with a count and the first offset. "
        "Exit code: 0 every packet decoded, 1 some could not be, 2 none could.",
    )
    d.add_argument(
        "file",
        metavar="FILE",
        type=input_path,
        help="raw KLV (.klv, .bin: concatenated packets), a container (.ts, .m2ts, .mpg, .mp4), or a "
        "live MPEG-TS stream udp://HOST:PORT (docs/live.md)",
    )
    d.add_argument(
        "--out", default=None, type=text_output_path, help="write the JSON lines to this file instead of stdout"
    )
    d.add_argument("--no-checksum", action="store_true", help="do not verify the checksums (tag 1), nor require them")
    from geoloc.cli._options import add_live_options

    add_live_options(d)
    d.set_defaults(func=run)

    f = actions.add_parser(
        "fix",
        help="write a copy whose frame-centre and corner tags are recomputed (checksums too)",
        description="Write a copy of IN (raw KLV or an MPEG-TS) whose frame-centre tags (23-25, 78) and "
        "corner tags (82-89 full, or 26-33 offsets) hold geoloc's replay of each packet (on --dem, with "
        "the --sensor file's calibration; with its [uncertainty] budget, tags 45 / 46 get the predicted CE90 / "
        "LE90), checksums recomputed. Every other byte of every packet, the "
        "bad packets, and (containers) every other stream are copied as they are: a remux, no "
        "re-encode. Packets that cannot be located are copied unchanged and listed (docs/klv.md).",
    )
    f.add_argument("file", metavar="IN", type=input_path, help="raw KLV (.klv, .bin) or a container (.ts, .m2ts, .mpg)")
    f.add_argument("--out", required=True, type=output_path, help="the copy to write (the same kind of file; never IN)")
    from geoloc.cli._options import add_correction_options, add_dem_options, add_sensor_option

    add_sensor_option(
        f,
        help="sensor file (image size, mount, boresight, lever arm: e.g. a calibration "
        "written by geoloc calibrate --fit ... --write-sensor)",
    )
    f.add_argument("--no-checksum", action="store_true", help="do not verify the input's checksums")
    add_dem_options(f)
    add_correction_options(f)
    f.set_defaults(func=run_fix)

    sd = actions.add_parser(
        "send",
        help="stream an MPEG-TS (or a raw .klv) to udp://HOST:PORT, paced by its time stamps (a sender for live tests)",
        description="Stream FILE (an MPEG-TS: video and MISB ST 0601 KLV; a raw .klv is first wrapped in an "
        "MPEG-TS, its decodable packets in a KLVA data stream timed by their tag 2) to udp://HOST:PORT as UDP "
        "datagrams of 7 TS packets, each leaving at the time stamp of the PES it carries (--speed 1: real "
        "time), as an aircraft's data link would; for trying geoloc view --live, replay and klv dump on "
        "udp:// (docs/live.md). A multicast group is sent to with TTL 1 (this network segment only).",
    )
    sd.add_argument(
        "file",
        metavar="FILE.ts",
        type=input_path,
        help="the transport stream, e.g. assets/klv/example_flight.ts, or a raw KLV file (.klv, .bin)",
    )
    sd.add_argument("url", metavar="udp://HOST:PORT", help="where to send (udp://127.0.0.1:5600: this machine)")
    sd.add_argument("--speed", type=float, default=1.0, help="pace: 1 = real time (default), 10 = ten times faster")
    sd.add_argument("--fast", action="store_true", help="as fast as possible (no pacing)")
    sd.add_argument("--loop", type=int, default=1, metavar="N", help="send the file N times (default 1)")
    sd.add_argument(
        "--wait",
        type=float,
        default=0.0,
        metavar="S",
        help="first wait up to S seconds for a program on this machine to listen on the port "
        "(loopback or a local address), e.g. a geoloc replay udp:// started on the same line",
    )
    sd.set_defaults(func=run_send)

    def usage(args) -> int:
        p.print_help(sys.stderr)
        return 2

    p.set_defaults(func=usage)


def run(args: argparse.Namespace) -> int:
    from geoloc.io.klv import read_packets

    from geoloc.cli._options import is_stream
    from geoloc.userfiles import atomic_path

    if is_stream(args.file):
        return _run_live(args)
    if getattr(args, "record_ts", None):
        raise ValueError(f"--record is for a live input (udp://HOST:PORT); {args.file} is a file already")
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
        print(f"wrote {good} packets to {args.out}" + (f" ({bad} bad, see above)" if bad else ""), file=sys.stderr)
    return _status(args.file, good, bad)


def _status(name, good: int, bad: int) -> int:
    """The exit code of a dump: 0 every packet decoded, 1 some not, 2 none (docs/cli.md)."""
    if good == 0:
        what = (
            f"{bad} packet{'s' if bad != 1 else ''} found, none could be decoded (see above)"
            if bad
            else "no UAS LS (MISB ST 0601) or EG 0104 packet in it"
        )
        print(f"geoloc klv: {name}: {what}", file=sys.stderr)
        return 2
    if bad:
        print(f"geoloc klv: {name}: {good} packets decoded, {bad} could not be (see above)", file=sys.stderr)
        return 1
    return 0


def _run_live(args) -> int:
    """``geoloc klv dump udp://HOST:PORT``: each packet printed as it arrives (docs/live.md)."""
    from geoloc.cli._options import live_limits
    from geoloc.io.live import LiveReceiver, receive
    from geoloc.userfiles import atomic_path, growing_path

    limits = live_limits(args, args.file)
    sock = _bind(args.file)
    rx = LiveReceiver(verify_checksum=not args.no_checksum)
    print(
        f"geoloc klv: listening on {args.file}" + (" (Ctrl-C to stop)" if not any(limits.values()) else ""),
        file=sys.stderr,
        flush=True,
    )
    with contextlib.ExitStack() as stack:
        out = sys.stdout
        if args.out:
            tmp = stack.enter_context(atomic_path(args.out, "--out"))
            out = stack.enter_context(tmp.open("w", encoding="utf-8"))
        record = None
        if args.record_ts:
            rec = stack.enter_context(growing_path(args.record_ts, "--record"))
            fh = stack.enter_context(rec.open("wb"))
            record = fh.write
        results = receive(args.file, receiver=rx, record=record, sock=sock, **limits)
        good, bad = _dump(args.file, results, out, flush=True)
    print(f"geoloc klv: {rx.stats.line()}", file=sys.stderr)
    if args.out:
        print(f"wrote {good} packets to {args.out}", file=sys.stderr)
    if args.record_ts:
        print(f"recorded {rx.stats.bytes} bytes to {args.record_ts}", file=sys.stderr)
    return 0 if good else 1  # a live stream's losses are the network's: counted above


def _bind(url):
    """The socket of ``url``, bound at once (the exposure of a non-loopback bind printed first)."""
    from geoloc.io.live import exposure_note, open_socket, parse_udp_url

    u = parse_udp_url(url)
    note = exposure_note(u)
    if note:
        print(note, file=sys.stderr, flush=True)
    return open_socket(u)


#: Runs of bytes between packets that are no packet, named one by one before they are only counted.
STRAY_SHOWN = 3


def _dump(name, results, out, flush: bool = False) -> tuple[int, int]:
    """Write each good packet as a JSON line to ``out``, report each bad one; returns (good, bad).

    Bytes that are no packet are reported but not counted as bad packets. The quirks of the
    good packets are reported at the end, once per kind (:class:`geoloc.io.klv.QuirkTally`)."""
    from geoloc.io.klv import KlvError, QuirkTally

    good = bad = stray = 0
    quirks = QuirkTally()
    try:
        for r in results:
            if isinstance(r, KlvError):
                if r.reason.endswith("are not a UAS LS packet"):
                    # filler between packets (no packet lost): the first few named, the rest counted
                    stray += 1
                    if stray > STRAY_SHOWN:
                        continue
                else:
                    bad += 1
                print(f"geoloc klv: {name}: {r}", file=sys.stderr)
                continue
            good += 1
            quirks.add(r)
            if r.time_back:  # kept and written, in file order; the user is told where the clock went back
                print(f"geoloc klv: {name}: {r.time_back}", file=sys.stderr)
            out.write(json.dumps(r.to_json(), ensure_ascii=False, allow_nan=False))
            out.write("\n")
            if flush:
                out.flush()
    finally:
        if stray > STRAY_SHOWN:
            print(
                f"geoloc klv: {name}: and {stray - STRAY_SHOWN} more runs of bytes that are no UAS LS packet "
                "between packets (no packet lost)",
                file=sys.stderr,
            )
        for line in quirks.lines():
            print(f"geoloc klv: {name}: quirk: {line}", file=sys.stderr)
    return good, bad


def run_send(args: argparse.Namespace) -> int:
    from geoloc.io.live import parse_udp_url, send

    url = parse_udp_url(args.url)
    if not args.fast and not args.speed > 0:
        raise ValueError(f"--speed {args.speed}: must be > 0 (or --fast)")
    if args.loop < 1:
        raise ValueError(f"--loop {args.loop}: must be at least 1")
    if not Path(args.file).is_file():
        raise FileNotFoundError(f"{args.file}: no such file")
    from geoloc.userfiles import note_input

    note_input(args.file)
    if args.wait > 0:
        import time

        from geoloc.io.live import wait_for_listener

        if not wait_for_listener(url, args.wait):
            print(f"geoloc klv send: nothing listens on {url} after {args.wait:g} s: sending anyway", file=sys.stderr)
        time.sleep(0.2)  # the listener binds, then starts up: give it a moment
    from geoloc.io.klv import is_container_file

    source, note = args.file, ""
    if not is_container_file(args.file):
        # raw KLV: a receiver demultiplexes a transport stream, so wrap the packets in one
        from geoloc.io.live import klv_as_ts

        source, n, bad = klv_as_ts(args.file)
        note = (
            f" ({n} KLV packets in an MPEG-TS, stream type 0x06 KLVA"
            + (f"; {bad} bad packets left out" if bad else "")
            + ")"
        )
    total = 0
    for _ in range(args.loop):
        r = send(source, url, speed=None if args.fast else args.speed)
        total += r["sent"]
    print(f"sent {total} datagrams of {args.file} to {url}{note}")
    return 0


def run_fix(args: argparse.Namespace) -> int:
    from geoloc.cli._options import corrections_from_args, sensor_from_args, surface_from_args
    from geoloc.workflows.klv_fix import fix_klv

    sensor = sensor_from_args(args, default=False)
    surface = surface_from_args(args) if args.dem else None  # else: each packet's own frame-centre height
    path = getattr(args, "camera", None)
    from geoloc.sensors.sensor_file import load_sensor_budget

    budget = load_sensor_budget(path) if path else None  # its [uncertainty]: tags 45 / 46
    fix = fix_klv(
        args.file,
        args.out,
        surface=surface,
        sensor=sensor,
        budget=budget,
        verify_checksum=not args.no_checksum,
        corrections=corrections_from_args(args, sensor),
    )
    print(fix)
    return 0 if fix.packets else 1
