"""``geoloc replay``: geolocate every flight-test record and compare with published and surveyed positions."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from geoloc.cli._options import (
    add_progress_options,
    add_correction_options,
    add_records_options,
    add_sensor_option,
    add_target_options,
    corrections_from_args,
    input_path,
    output_dir,
    output_path,
    sensor_from_args,
    text_output_path,
    surface_from_args,
    surface_spec_from_args,
    warn_datums,
)
from geoloc.assets import DEFAULT_RECORDS, asset_path
from geoloc.cli.locate import records_from_args
from geoloc.status import Status
from geoloc.workflows.replay import (
    dem_coverage_warning,
    located,
    outside_sensor_messages,
    plausibility_warnings,
    refraction_note,
    replay_records,
    summary_table,
    uncertainty_columns,
    write_replay_csv,
)
from geoloc.workflows.triangulation import TARGET_ID_COLUMN, summary_lines, triangulate_records
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc replay --height-column paper_height_m --out results.csv --export results.gpkg"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help=VERB_HELP["replay"],
        description="Locate every record of a flight-test CSV (columns of [Q17] Tables 3-4) and write "
        "every input column plus lat_deg, lon_deg, h_m, error_to_paper_m, error_to_truth_m "
        "(horizontal geodesic distances in metres; empty where the input has no such column). "
        "Bad rows are reported with their line number; the good rows still run. "
        "MISB ST 0601 KLV inputs (.klv, .bin, .ts, .mpg, .mp4): every packet's frame centre and corners "
        "recomputed from its own pose and compared with the packet's, outliers flagged (docs/klv.md). "
        "Drone photos with --targets: docs/photos.md.",
    )
    p.add_argument(
        "records",
        nargs="*",
        default=None,
        metavar="INPUT",
        type=input_path,
        help="records CSV (default: the bundled assets/records/qiao2017_flight_tests.csv); "
        "or MISB ST 0601 KLV: raw .klv/.bin or video .ts/.mpg/.mp4 (one or more files: each "
        "packet's frame centre and corners recomputed and compared, docs/klv.md); or drone "
        "photos .jpg/.jpeg/.tif/.tiff/.dng with --targets; or DJI flight-log subtitles .srt (docs/photos.md)",
    )
    add_sensor_option(p)
    add_records_options(p)
    add_target_options(p)
    p.add_argument(
        "--out", default=None, type=text_output_path, help="output CSV of every row (never the input file: refused)"
    )
    p.add_argument(
        "--print-rows",
        action="store_true",
        help=f"print one line per record even with --out or more than {ROWS_SHOWN} "
        "records (default: the per-record lines only without --out and for at most "
        f"{ROWS_SHOWN} records; the per-flight summary always)",
    )
    p.add_argument(
        "--group-by",
        default=None,
        help="records CSV: the column that groups records into flights (default: table, when there "
        "is one; a column that is not there is an error naming the columns there are)",
    )
    p.add_argument(
        "--export",
        default=None,
        metavar="FILE",
        type=output_path,
        help="also write the results to GIS: FILE.gpkg, .geojson, .kml or .czml "
        "(points, truth, error vectors, track; docs/gis.md)",
    )
    p.add_argument(
        "--audit",
        action="store_true",
        help="with --dem: audit the flight's heights and conventions from the data (MSL read as "
        "ellipsoidal and the reverse, the geoid's sign, relative heights, flat-earth frame centres, "
        "a time offset, a boresight bias; KLV, also without --dem: frame centres that leave the "
        "heading out): one line per finding, docs/height_audit.md",
    )
    p.add_argument(
        "--targets",
        default=None,
        metavar="T.csv",
        type=input_path,
        help="drone photos: the targets to locate (columns image,row,col; optional truth columns)",
    )
    from geoloc.cli._options import add_live_options

    add_live_options(p)
    c = p.add_argument_group("campaigns (many inputs on dask.distributed, docs/scale.md)")
    c.add_argument(
        "--parquet-out",
        default=None,
        metavar="DIR",
        type=output_dir,
        help="campaign: replay every input (files, or folders of KLV/TS files, photos, or a "
        "partitioned Parquet / CSVs of records) unit by unit and write the rows to DIR/part-*.parquet",
    )
    c.add_argument(
        "--scheduler",
        default="local",
        metavar="ADDR",
        help="campaign: 'local' (a local dask cluster on 127.0.0.1, the default), 'none' (serial, "
        "this process), or a dask scheduler address such as tcp://10.0.0.5:8786",
    )
    c.add_argument("--workers", type=int, default=2, help="campaign: workers of the local cluster (default 2)")
    add_progress_options(p)
    p.set_defaults(func=run)
    from geoloc.cli._options import add_dem_options

    add_dem_options(p)
    add_correction_options(p)


#: The kinds of input replay reads (``_input_kind``, a campaign, a live stream): each shows the
#: progress of its work, or tests/cli/test_cli_rules.py names why it needs none.
INPUT_KINDS = ("records", "klv", "photos", "srt", "campaign", "live")

#: Without --out, records up to this many are printed one line each (more: the summary only).
ROWS_SHOWN = 50


def run(args: argparse.Namespace) -> int:
    from geoloc.cli._options import check_gis_output, is_stream

    check_gis_output("--export", args.export)  # before any record is located: fail in a second
    inputs = list(args.records or [])
    # --audit without --dem: said before any record is located (KLV has a check that needs no terrain)
    try:
        klv_only = bool(inputs) and not any(is_stream(x) for x in inputs) and _input_kind(inputs) == "klv"
    except ValueError:  # a mix of kinds: said where the inputs are read
        klv_only = False
    if not klv_only:
        _audit_wanted(args)
    if any(is_stream(x) for x in inputs):
        return _run_live(args, inputs)
    if getattr(args, "record_ts", None):
        raise ValueError("--record is for a live input (udp://HOST:PORT)")
    if args.parquet_out or any(Path(x).is_dir() or Path(x).suffix.lower() in (".parquet", ".pq") for x in inputs):
        return _run_campaign(args, inputs)
    kind = _input_kind(inputs)
    if kind == "klv":
        return _run_klv(args, inputs)
    if kind == "photos":
        return _run_photos(args, inputs)
    if kind == "srt":
        return _run_srt(args, inputs)
    if len(inputs) > 1:
        raise ValueError(
            f"{len(inputs)} records files given ({', '.join(inputs)}): give one records CSV "
            "(several inputs are for KLV files or photos)"
        )
    args.records = inputs[0] if inputs else None
    records_path = args.records if args.records is not None else asset_path(*DEFAULT_RECORDS)
    camera = sensor_from_args(args)
    records = records_from_args(args, str(records_path), camera)
    if args.group_by is not None and args.group_by not in records.header:  # before: silently one group
        raise ValueError(
            f"--group-by {args.group_by!r}: no such column in {records.path}; its columns: {', '.join(records.header)}"
        )
    group_by = args.group_by or "table"
    surface = surface_from_args(args, records)
    if args.dem is not None:
        warn_datums("replay", args.dem_datum, records.altitude)
    corrections = corrections_from_args(args, camera)
    result = replay_records(records, camera, surface, corrections, progress=args.progress)
    budget = _budget(args)
    if budget is not None:
        cols, notes = uncertainty_columns(records, camera, surface, budget)
        result.extra.update(cols)
        for msg in notes:
            print(f"geoloc replay: note: {msg}", file=sys.stderr)
        note = refraction_note(records, camera, surface, corrections, result)
        if note:
            print(f"geoloc replay: note: {note}", file=sys.stderr)
    for msg in outside_sensor_messages(records, camera, result.lat_deg):
        print(f"geoloc replay: warning: {msg}", file=sys.stderr)
    if TARGET_ID_COLUMN in records.header:  # targets seen in several rows: their rays' intersection
        for line in summary_lines(
            triangulate_records(
                records, camera, budget, result.h_m, result.status == Status.OK, corrections=corrections
            )
        ):
            print(line)
    for msg in plausibility_warnings(records, result, result.terrain, sensor=camera):
        print(f"geoloc replay: warning: {msg}", file=sys.stderr)
    coverage = dem_coverage_warning(result)
    if coverage:
        print(f"geoloc replay: warning: {coverage}", file=sys.stderr)
    rows = args.print_rows or (not args.out and len(records) <= ROWS_SHOWN)
    print(summary_table(result, group_by, rows=rows))
    print(records.datum_summary())
    if _audit_wanted(args):
        from geoloc.analysis.height_audit import audit_records

        print("\n".join(audit_records(records, camera, surface, group_column=group_by).lines()))
    if not rows and not args.out:
        print(
            f"({len(records)} records: per-record lines not printed; --out FILE writes them, --print-rows prints them)"
        )
    if args.out:
        write_replay_csv(args.out, result)
        print(f"wrote {len(records)} rows to {args.out}")
    if args.export:
        _export(
            args, lambda path: write_replay_csv(path, result), group_by if group_by in result.records.header else None
        )
    return 0 if located(result).all() else 1  # docs/cli.md: 1 = some records could not be located


def _audit_wanted(args) -> bool:
    """``--audit``: True with a DEM; without one a clear error (the audit compares with the terrain)."""
    if not getattr(args, "audit", False):
        return False
    if not getattr(args, "dem", None):
        raise ValueError("--audit compares heights with the terrain: give a DEM with --dem")
    return True


def _budget(args):
    """The ``--sensor`` file's error budget (its ``[uncertainty]`` table), or None."""
    from geoloc.sensors.sensor_file import load_sensor_budget

    path = getattr(args, "camera", None)
    return load_sensor_budget(path) if path else None


def _export(args, write_csv, group_by) -> None:
    """``--export FILE``: the rows of ``--out`` (or, without a file there, of a temporary CSV that
    ``write_csv(path)`` writes) through geoloc.io.gis; records, KLV and photos alike."""
    import tempfile

    from geoloc.io.gis import export, read_results

    with tempfile.TemporaryDirectory() as tmp:
        # --out -: stdout, not re-readable; nor is a FIFO or a device (`--out FIFO --export X` once
        # read its own FIFO back: "is not a file")
        on_disk = args.out if args.out not in (None, "-") and Path(args.out).is_file() else None
        csv_path = on_disk or str(Path(tmp) / "replay.csv")
        if not on_disk:
            write_csv(csv_path)
        print(export(read_results(csv_path), args.export, group_by=group_by))


# --------------------------------------------------------------------------- KLV and photo inputs

#: Drone photo suffixes (``geoloc.workflows.photo_replay``).
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".dng")


def _input_kind(inputs) -> str:
    """ "klv", "photos", "srt" or "records" for the positional inputs (suffixes; a mix is an error)."""
    from geoloc.workflows.klv_replay import is_klv_path

    kinds = [
        "klv"
        if is_klv_path(x)
        else "photos"
        if Path(x).suffix.lower() in PHOTO_SUFFIXES
        else "srt"
        if Path(x).suffix.lower() == ".srt"
        else "records"
        for x in inputs
    ]
    if len(set(kinds)) > 1:
        raise ValueError(
            "inputs of different kinds: "
            + ", ".join(f"{x} ({k})" for x, k in zip(inputs, kinds))
            + "; replay one kind at a time"
        )
    return kinds[0] if kinds else "records"


def _reject_records_options(args, what: str) -> None:
    for opt, why in (
        ("height_column", "records CSVs"),
        ("target_h_m", "records CSVs"),
        ("columns", "records CSVs"),
        ("group_by", "records CSVs"),
    ):
        if getattr(args, opt, None) is not None:
            raise ValueError(f"--{opt.replace('_', '-')} is for {why}, not for {what}")


def _run_klv(args, inputs) -> int:
    """``geoloc replay FILE.klv|FILE.ts ...``: :func:`geoloc.workflows.klv_replay.replay_klv` per file."""
    from geoloc.workflows.klv_replay import replay_klv, write_klv_csv

    _reject_records_options(
        args,
        "KLV: each packet is intersected at its own frame-centre height "
        "(tag 78 HAE, else tag 25 MSL + EGM96 N), or with --dem",
    )
    if getattr(args, "altitude_datum", None) is not None:
        print(
            "geoloc replay: note: --altitude-datum is not used for KLV: MISB ST 0601 gives each height's "
            "datum (tags 75, 78: ellipsoid; tags 15, 25: MSL, made ellipsoidal with EGM96)",
            file=sys.stderr,
        )
    paths = [Path(x) for x in inputs]
    sensor = sensor_from_args(args, default=False)
    surface = surface_from_args(args) if args.dem else None  # else: each packet's own frame-centre height
    corrections = corrections_from_args(args, sensor)  # KLV comes from aircraft: refraction, light-time
    # one step per file, counted in bytes (a file is read and located whole: its outliers are
    # judged against all its packets); the messages after the bar, not through it
    bar = _files_progress(paths, "KLV", args.progress)
    replays = []
    for path in paths:
        replays.append(replay_klv(path, surface=surface, sensor=sensor, budget=_budget(args), corrections=corrections))
        bar.update(_size(path))
    bar.close()
    for path, r in zip(paths, replays):
        for e in r.errors:
            print(f"geoloc replay: {path}: {e}", file=sys.stderr)
        print(r.summary)
        if getattr(args, "audit", False):  # without --dem: the bearing check alone, said in its heading
            from geoloc.analysis.height_audit import audit_klv_columns

            print("\n".join(audit_klv_columns(r.columns, r.sensor, surface, source=path.name).lines()))
        show = args.print_rows or (not args.out and len(r) <= ROWS_SHOWN)
        if show and len(r):
            print(_klv_rows_text(r))
    n = sum(len(r) for r in replays)
    if args.out and n:
        write_klv_csv(args.out, replays)
        print(
            f"wrote {n} rows to {args.out} (heights ellipsoidal, WGS 84: column h_datum; "
            "*_msl_m columns mean sea level)"
        )
    if args.export and n:
        _export(args, lambda path: write_klv_csv(path, replays), "file" if len(paths) > 1 else None)
    if n == 0:
        print("geoloc replay: no good UAS LS packet", file=sys.stderr)
        return 1
    return 0


def _size(path: Path) -> int:
    """A file's size [bytes]: the progress of a replay of whole files (0 for a stream or a device)."""
    try:
        return path.stat().st_size if path.is_file() else 0
    except OSError:
        return 0


def _files_progress(paths, kind: str, enabled):
    """:class:`geoloc.progress.Progress` over the bytes of ``paths``, one update per file replayed."""
    from geoloc.progress import Progress

    label = f"replay {paths[0].name}" if len(paths) == 1 else f"replay {len(paths)} {kind} files"
    return Progress(sum(_size(p) for p in paths), f"{label} (bytes)", enabled)


def _run_live(args, inputs) -> int:
    """``geoloc replay udp://HOST:PORT``: every packet located as it arrives, rows journalled (docs/live.md)."""
    import contextlib

    from geoloc.cli._options import live_limits
    from geoloc.io.live import LiveReceiver, receive
    from geoloc.userfiles import growing_path
    from geoloc.workflows.live_replay import HEADER, LiveReplay

    if len(inputs) != 1:
        raise ValueError(f"{len(inputs)} inputs given ({', '.join(inputs)}): a live replay takes one udp:// stream")
    for opt in ("parquet_out", "export", "targets"):
        if getattr(args, opt, None):
            raise ValueError(f"--{opt.replace('_', '-')} is not for a live stream; --out journals its rows")
    _reject_records_options(args, "a live KLV stream (each packet at its own frame-centre height, or --dem)")
    url = inputs[0]
    limits = live_limits(args, url)
    from geoloc.cli.klv import _bind

    sock = _bind(url)  # bound before anything else: what is sent meanwhile waits in the kernel
    sensor = sensor_from_args(args, default=False)
    surface = surface_from_args(args) if args.dem else None  # else: each packet's own frame-centre height
    rx = LiveReceiver()
    with contextlib.ExitStack() as stack:
        journal = record = None
        if args.out:
            part = stack.enter_context(growing_path(args.out, "--out"))
            journal = stack.enter_context(part.open("w", newline=""))
            print(f"geoloc replay: journalling rows to {part} (renamed {args.out} at the end)", file=sys.stderr)
        if args.record_ts:
            rec = stack.enter_context(growing_path(args.record_ts, "--record"))
            fh = stack.enter_context(rec.open("wb"))
            print(
                f"geoloc replay: recording the stream to {rec} (renamed {args.record_ts} at the end)", file=sys.stderr
            )

            def record(b, fh=fh):
                fh.write(b)

        live = LiveReplay(url, surface=surface, sensor=sensor, journal=journal, receiver=rx)
        print(
            f"geoloc replay: listening on {url}" + ("" if any(limits.values()) else " (Ctrl-C to stop)"),
            file=sys.stderr,
            flush=True,
        )
        print(HEADER, flush=True)

        def batch(results):
            r = live.add(results)
            for e in results:
                if not hasattr(e, "fields"):
                    print(f"geoloc replay: {url}: {e}", file=sys.stderr)
            if r is not None:
                print(live.row_text(r), flush=True)
            if args.record_ts:
                fh.flush()

        for _ in receive(url, receiver=rx, record=record, on_batch=batch, sock=sock, **limits):
            pass
        r = live.flush()  # the packets still waiting for their video frame
        if r is not None:
            print(live.row_text(r), flush=True)
    print(live.summary())
    print(f"  stream: {rx.stats.line()}")
    if args.out:
        print(f"wrote {live.rows_total} rows to {args.out} (heights ellipsoidal, WGS 84: column h_datum)")
    if args.record_ts:
        print(f"recorded {rx.stats.bytes} bytes to {args.record_ts} (geoloc replay {args.record_ts} replays it)")
    if live.rows_total == 0:
        print("geoloc replay: no good UAS LS packet received", file=sys.stderr)
        return 1
    return 0


def _klv_rows_text(r) -> str:
    """One line per packet: time, recomputed centre, status, error to the reported centre, outlier."""
    c = r.columns
    from geoloc.status import names

    st = names(c["status"])
    lines = [
        f"{'packet':>6} {'time_utc':<27} {'lat_deg':>11} {'lon_deg':>12} {'h_m (HAE)':>9} {'status':>13} "
        f"{'centre_err_m':>12} {'corner_err_m':>12} outlier"
    ]

    def f(v, spec):
        return format(float(v), spec) if v == v else ""

    for k in range(len(r)):
        lines.append(
            f"{c['packet'][k]:>6} {c['time_utc'][k]:<27} {f(c['lat_deg'][k], '11.6f'):>11} "
            f"{f(c['lon_deg'][k], '12.6f'):>12} {f(c['h_m'][k], '9.1f'):>9} {st[k]:>13} "
            f"{f(c['frame_center_error_m'][k], '12.3f'):>12} {f(c['corner_error_m'][k], '12.3f'):>12} "
            f"{'yes' if c['outlier'][k] else ''}"
        )
    return "\n".join(lines)


def _run_photos(args, inputs) -> int:
    """``geoloc replay PHOTOS... --targets T.csv``: :func:`geoloc.workflows.photo_replay.replay_photos`."""
    from geoloc.workflows.photo_replay import replay_photos, summarize, write_rows

    _reject_records_options(args, "drone photos")
    if not args.targets:
        raise ValueError("drone photos need --targets T.csv (columns image,row,col; optional truth columns)")
    photos = list(inputs)
    sensor = sensor_from_args(args, default=False)
    surface = surface_from_args(args) if args.dem else None  # else: each target at its truth_h_m
    extra = {"altitude_datum": args.altitude_datum} if getattr(args, "altitude_datum", None) else {}
    targets: list = []  # a target_id column: each target seen in several photos, triangulated
    rows, messages = replay_photos(
        photos,
        args.targets,
        sensor=sensor,
        surface=surface,
        targets_out=targets,
        corrections=corrections_from_args(args, sensor),
        progress=args.progress,
        **extra,
    )
    for m in messages:
        print(f"geoloc replay: {m}", file=sys.stderr)
    print(summarize(rows, messages))
    for line in summary_lines(targets):
        print(line)
    if args.out:
        write_rows(args.out, rows)
        print(f"wrote {len(rows)} rows to {args.out}")
    if args.export and rows:
        _export(args, lambda path: write_rows(path, rows), None)
    return 0 if rows else 1


def _run_srt(args, inputs) -> int:
    """``geoloc replay FLIGHT.SRT ...``: DJI flight-log subtitles read as a flight
    (:func:`geoloc.io.dji_srt.read_srt`); bad blocks reported by line; ``--out`` writes the records."""
    from geoloc.io.dji_srt import SrtFlight, read_srt, write_srt_records

    _reject_records_options(args, "DJI SRT flight logs")
    flights = []
    bar = _files_progress([Path(x) for x in inputs], "SRT", args.progress)
    for path in inputs:
        flights.append(read_srt(path))
        bar.update(_size(Path(path)))
    bar.close()
    for path, f in zip(inputs, flights):
        for line, msg in f.errors:
            print(f"geoloc replay: {path} line {line}: {msg}: skipped", file=sys.stderr)
        for line, msg in f.warnings:
            print(f"geoloc replay: {path} line {line}: {msg}: kept in file order", file=sys.stderr)
        print(f.summary())
    if args.out:
        merged = SrtFlight(",".join(inputs), [r for f in flights for r in f.records], [])
        n = write_srt_records(args.out, merged)
        print(
            f"wrote {n} rows to {args.out} (ac_h_m ellipsoidal, WGS 84, from abs_alt taken as EGM96; "
            "rel_alt above the take-off point)"
        )
    return 0


# --------------------------------------------------------------------------- campaigns


def _run_campaign(args, inputs) -> int:
    """``geoloc replay INPUTS... --parquet-out DIR``: :func:`geoloc.workflows.campaign.run_campaign`."""
    from geoloc.workflows.campaign import CampaignConfig, run_campaign

    if not args.parquet_out:
        raise ValueError(
            f"inputs {', '.join(inputs)}: a folder or a Parquet dataset is a campaign: give "
            "--parquet-out DIR (and --scheduler, --workers; docs/scale.md)"
        )
    if not inputs:
        raise ValueError("--parquet-out: give the campaign's inputs (files or folders)")
    for opt in ("out", "export"):
        if getattr(args, opt, None):
            raise ValueError(f"--{opt} is for one replay; a campaign writes Parquet parts (--parquet-out)")
    paths = list(inputs)
    out = args.parquet_out
    from geoloc.sensors.sensor_file import load_sensor

    cfg = CampaignConfig(
        sensor=args.camera,
        surface=surface_spec_from_args(args),
        altitude_datum=getattr(args, "altitude_datum", None) or "ellipsoid",
        targets=args.targets,
        corrections=corrections_from_args(args, load_sensor(args.camera) if args.camera else None),
    )
    if args.workers < 1:
        raise ValueError(f"--workers {args.workers}: must be at least 1")

    def report(u):
        for m in u.messages:
            print(f"geoloc replay: {m}", file=sys.stderr)

    res = run_campaign(
        paths, out, cfg, scheduler=args.scheduler, workers=args.workers, on_unit=report, progress=args.progress
    )
    for m in res.notes:
        print(f"geoloc replay: note: {m}", file=sys.stderr)
    print(res.summary())
    for u in res.failed:
        print(f"geoloc replay: failed unit: {u.source}", file=sys.stderr)
    return 0 if res.rows else 1
