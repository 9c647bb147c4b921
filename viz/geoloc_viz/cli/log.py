"""``geoloc log``: write a rerun recording (.rrd) of a simulated flight or of flight-test records.

The core computes (``geoloc.workflows.flight``, ``geoloc.workflows.replay``, ``geoloc.surfaces.terrain``);
``geoloc_viz.rerun_log`` writes. rerun is imported only when the verb runs, so the
core stays free of it.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import numpy as np

from geoloc.cli._options import (
    add_dem_options,
    add_sensor_option,
    add_target_options,
    input_path,
    one_dem_raster,
    output_path,
    sensor_from_args,
)
from geoloc.assets import ASSETS
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc log assets/records/qiao2017_flight_tests.csv --height-column paper_height_m --out run.rrd"


def register(sub) -> None:
    p = sub.add_parser(
        "log",
        help=VERB_HELP["log"],
        description="Log a simulated flight (scenario TOML, e.g. assets/scenarios/flight_scan.toml, "
        "or just its name 'flight_scan') or a flight-test records CSV (one time step per record) "
        "to a rerun recording: aircraft pose and frame chain, line of sight and hits in the local "
        "ENU frame of the 3D viewer (one entity tree and origin per flight of a records file), time "
        "series (heading; pitch and roll; gimbal angles, slant range, target height, errors and their "
        "north/east/along/across components, outlier flags, errors before/after the per-flight mounting "
        "calibration, DEM evaluations, H_n - h_n of the height iteration), record labels and outlier notes "
        "in a log, an offline 2D target/truth plot, map points and a default layout whose 3D view follows "
        "the current hit. Open it with `rerun run.rrd` (or the web viewer: --serve). See docs/rerun.md.",
    )
    p.add_argument(
        "input",
        metavar="SCENARIO_OR_RECORDS",
        type=input_path,
        help="scenario .toml (or the name of a bundled one) or records .csv; or MISB ST 0601 KLV "
        "(.klv, .ts), or a live stream udp://HOST:PORT (logged as it arrives, until --duration, --packets, "
        "--idle or Ctrl-C; docs/live.md)",
    )
    p.add_argument(
        "--out", default=None, type=output_path, help="output .rrd file (required unless --serve or --spawn)"
    )
    add_sensor_option(p)
    from geoloc.cli._options import add_correction_options

    add_correction_options(p)
    add_target_options(p)
    add_dem_options(
        p,
        mosaic=False,
        dem_help="DEM raster (GeoTIFF, ...): intersect the line of sight with "
        "the terrain instead of a target height, e.g. assets/dem/etopo5_flight_area.tif; default for a MISB "
        "KLV file, and for records without any target height (no --target-h-m, --height-column or "
        "paper_height_m): a bundled DEM covering the flight, as geoloc view draws it (--no-dem: none)",
    )
    p.add_argument(
        "--no-dem",
        action="store_true",
        help="no DEM, even where a bundled one covers the flight (a KLV packet is then located at "
        "its own frame-centre height; records need --target-h-m, --height-column or paper_height_m)",
    )
    g = p.add_argument_group(
        "records (a records CSV's target height: --dem, --target-h-m or --height-column, "
        "first given wins; default paper_height_m)"
    )
    g.add_argument(
        "--group-by",
        default="table",
        help="records: column naming each record's flight (default table; 'none' for one flight); "
        "each flight gets its own scene origin and entity tree",
    )
    g.add_argument(
        "--no-calibration",
        action="store_true",
        help="records: do not fit and log the per-flight mounting calibration (before/after series)",
    )
    g.add_argument(
        "--fit",
        default=None,
        metavar="NAMES",
        help="records: comma-separated sensor parameters to fit per flight for the before/after "
        "series (geoloc.analysis.sensor_fit, e.g. mount_x,mount_y,mount_z,boresight_z); default "
        "mount_x,mount_y,mount_z (the mounting calibration of geoloc calibrate)",
    )
    g = p.add_argument_group("viewer")
    g.add_argument(
        "--display-scale", type=float, default=200.0, help="scale of the aircraft mesh in the 3D view (default 200)"
    )
    g.add_argument(
        "--serve",
        action="store_true",
        help="also serve the recording to the web viewer (bundled in the rerun wheel, "
        "works offline) and wait for Ctrl-C",
    )
    g.add_argument(
        "--host",
        default="127.0.0.1",
        help="address the web viewer and the gRPC server of --serve listen on (default "
        "127.0.0.1: this machine only; 0.0.0.0 exposes them to the network)",
    )
    g.add_argument("--web-port", type=int, default=9090, help="web viewer port (default 9090)")
    g.add_argument("--grpc-port", type=int, default=9876, help="gRPC server port (default 9876)")
    g.add_argument(
        "--spawn",
        action="store_true",
        help="also open the native rerun viewer on the recording (on --out once written, else "
        "streamed to it), bound to --host like every port here; it needs a display: without one "
        "(DISPLAY / WAYLAND_DISPLAY unset) the verb refuses before computing, exit status 2",
    )
    from geoloc.cli._options import add_live_options

    add_live_options(p)
    p.set_defaults(func=run)


def resolve_input(text: str) -> Path:
    """A path, or the name of a bundled scenario in assets/scenarios/."""
    path = Path(text)
    if path.exists():
        return path
    bundled = Path(ASSETS) / "scenarios" / f"{text}.toml"
    if not path.suffix and bundled.exists():
        return bundled
    raise FileNotFoundError(f"input not found: {text} (neither a file nor a bundled scenario name)")


def _fit_names(text):
    """``--fit NAMES`` as a list (None when not given); an empty list is an error naming the option."""
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ValueError(f"--fit = {text!r}: name at least one sensor parameter (e.g. mount_x,mount_y,mount_z)")
    return names


#: A live recording logs what arrived at most this often [s] (a batch of packets each time).
LIVE_FLUSH_S = 1.0


def _log_live(args, camera, dem) -> int:
    """``geoloc log udp://HOST:PORT``: the recording written as the packets arrive
    (:class:`geoloc_viz.rerun_log.LiveRecording`, flushed every :data:`LIVE_FLUSH_S`), the ``.rrd``
    growing as ``OUT.partial.rrd`` until the session ends (then renamed onto ``--out``), so a
    session killed mid-flight leaves every batch logged; the raw stream journalled with ``--record``."""
    import contextlib

    from geoloc.cli._options import live_limits
    from geoloc.cli.klv import _bind
    from geoloc.io.live import LiveReceiver, receive
    from geoloc.userfiles import growing_path
    from geoloc_viz.rerun_log import LiveRecording, exposure_note, serve_web

    limits = live_limits(args, args.input)
    if not any(limits.values()):
        print("geoloc log: logging until Ctrl-C (--duration, --packets or --idle stop it)", file=sys.stderr, flush=True)
    sock = _bind(args.input)
    rx = LiveReceiver()
    with contextlib.ExitStack() as stack:
        out = stack.enter_context(growing_path(args.out, "--out")) if args.out else None
        record = None
        if args.record_ts:
            rec_ts = stack.enter_context(growing_path(args.record_ts, "--record"))
            record = stack.enter_context(rec_ts.open("wb")).write
        live = LiveRecording(
            out,
            args.input,
            camera,
            dem_path=dem,
            dem_datum=args.dem_datum,
            method=args.method,
            eps_h_m=args.eps_h,
            threshold_m=args.threshold,
            display_scale=args.display_scale,
            serve=args.serve,
            grpc_port=args.grpc_port,
            grpc_host=args.host,
            spawn=args.spawn,
        )
        viewer = None
        if args.serve:
            note = exposure_note(args.host, (args.web_port, args.grpc_port))
            if note:
                print(note, file=sys.stderr, flush=True)
        pending: list = []
        last = [time.monotonic()]

        def flush():
            if pending:
                live.add(pending)
                pending.clear()
            last[0] = time.monotonic()

        def on_batch(res):
            pending.extend(res)
            if time.monotonic() - last[0] >= LIVE_FLUSH_S:
                flush()

        def _stop(signum, frame):
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, _stop)  # a killed session still ends its .rrd on what was logged
        print(
            f"geoloc log: listening on {args.input}" + (f", logging to {out}" if out else ""),
            file=sys.stderr,
            flush=True,
        )
        try:
            for _ in receive(args.input, receiver=rx, record=record, sock=sock, on_batch=on_batch, **limits):
                if args.serve and viewer is None and live.rec is not None:
                    url, viewer = serve_web(args.grpc_port, args.web_port, host=args.host)
                    print(f"web viewer: {url}", flush=True)
        except KeyboardInterrupt:
            pass
        finally:
            flush()
            live.close()
            if viewer is not None:
                viewer.terminate()
                viewer.wait(timeout=10)
    print(f"geoloc log: {rx.stats.line()}", file=sys.stderr)
    for err in live.errors:
        print(f"{args.input}: skipped bad packet at byte {err.offset}: {err.reason}", file=sys.stderr)
    if args.out:
        print(
            f"wrote {args.out}: {live.steps_total} steps ({live.located_total} located) on timeline(s) "
            f"{', '.join(live.timelines)}, logged as they arrived"
        )
    return 0


def _corrections(args, camera):
    """The recording's line-of-sight corrections (``--refraction``, ``--light-time``, ``--no-aberration``
    over the ``--sensor`` file's ``[corrections]`` table, over the sensor's defaults; none for
    the frame cameras this verb logs, unless asked)."""
    from geoloc.cli._options import corrections_from_args

    return corrections_from_args(args, camera)


def run(args) -> int:
    if args.out is None and not (args.serve or args.spawn):
        raise ValueError("--out is required unless --serve or --spawn is given")
    if not args.display_scale > 0:
        raise ValueError(f"--display-scale = {args.display_scale}: must be > 0")
    if args.no_dem and args.dem is not None:
        raise ValueError("--no-dem and --dem: give one of them")
    if args.spawn:
        from geoloc_viz.rerun_log import require_display

        require_display()  # before anything is computed (a headless machine cannot open the window)
    from geoloc.cli._options import is_stream

    live = is_stream(args.input)
    if not live and getattr(args, "record_ts", None):
        raise ValueError("--record is for a live input (udp://HOST:PORT)")
    if live:
        return _log_live(args, sensor_from_args(args, default=False), one_dem_raster(args, "log"))
    path = resolve_input(args.input)
    from geoloc_viz.rerun_log import exposure_note, serve_web, write  # rerun is imported here only
    from geoloc_viz.rerun_model import (
        steps_from_flight,
        steps_from_records,
    )

    camera = sensor_from_args(args, default=False)
    dem = one_dem_raster(args, "log")  # the recording draws the DEM it samples
    corrections = _corrections(args, camera)
    if path.suffix.lower() == ".toml":
        from geoloc.workflows.flight import FlightScenario

        steps = steps_from_flight(FlightScenario.from_toml(path), camera, corrections=corrections)
    elif path.suffix.lower() == ".csv":
        if dem is None and not args.no_dem and args.target_h_m is None and args.height_column is None:
            from geoloc_viz.rerun_model import records_default_dem

            dem = records_default_dem(path, camera)  # no height in the file: the DEM `geoloc view` draws
            if dem is not None:
                print(
                    f"geoloc log: DEM {dem} (bundled, covers the targets; the records give no target height)",
                    file=sys.stderr,
                )
        steps, errors = steps_from_records(
            path,
            camera,
            height_column=args.height_column,
            target_h_m=args.target_h_m,
            height_kind=args.height_kind,
            dem_path=dem,
            dem_datum=args.dem_datum,
            method=args.method,
            eps_h_m=args.eps_h,
            threshold_m=args.threshold,
            group_column=None if args.group_by == "none" else args.group_by,
            calibrate=not args.no_calibration,
            fit_names=_fit_names(args.fit),
            corrections=corrections,
        )
        for err in errors:
            print(f"{path}: skipped {err}", file=sys.stderr)
    elif path.suffix.lower() in (".klv", ".bin", ".ts", ".mpg", ".mpeg", ".mp4", ".m2ts"):
        from geoloc_viz.rerun_model import klv_default_dem, steps_from_klv

        if dem is None and not args.no_dem:
            dem = klv_default_dem(path)  # the DEM `geoloc view` draws for this flight
            if dem is not None:
                print(f"geoloc log: DEM {dem} (bundled, covers the flight; --no-dem for none)", file=sys.stderr)
        steps, errors = steps_from_klv(
            path,
            camera,
            dem_path=dem,
            dem_datum=args.dem_datum,
            method=args.method,
            eps_h_m=args.eps_h,
            threshold_m=args.threshold,
            corrections=corrections,
        )
        for err in errors:
            print(f"{path}: skipped bad packet at byte {err.offset}: {err.reason}", file=sys.stderr)
    else:
        raise ValueError(f"input {path}: expected a scenario .toml, a records .csv or a MISB KLV file (.klv, .ts)")
    rec = write(
        steps,
        args.out,
        display_scale=args.display_scale,
        serve=args.serve,
        grpc_port=args.grpc_port,
        grpc_host=args.host,
        spawn=args.spawn,
    )
    ok = int((steps.ground.status == 0).sum())
    if args.out:
        print(
            f"wrote {args.out}: {len(steps)} steps ({ok} located) on timeline(s) "
            f"{', '.join(steps.timelines)}"
            + (f"; flights {', '.join(steps.groups)}, one scene origin each" if steps.multi else "")
        )
        if steps.outlier is not None and steps.outlier.any():
            bad = [steps.labels[k] for k in np.flatnonzero(steps.outlier)]
            print(
                f"outliers (median / MAD of the horizontal error to {steps.reference}, per flight): "
                f"{len(bad)}: {', '.join(bad[:20])}{' ...' if len(bad) > 20 else ''}"
            )
        if steps.calibration is not None:
            print(steps.calibration["note"])
    viewer = None
    if args.serve:
        note = exposure_note(args.host, (args.web_port, args.grpc_port))
        if note:
            print(note, file=sys.stderr, flush=True)
        url, viewer = serve_web(args.grpc_port, args.web_port, host=args.host)
        print(f"web viewer: {url}  (Ctrl-C to stop)", flush=True)
    if args.spawn and not args.serve:
        print("rerun viewer started" + (f" on {args.out}" if args.out else " (streamed)"), flush=True)
    if args.serve:
        # Stop cleanly on Ctrl-C and on SIGTERM, even when started in the background
        # (a non-interactive shell starts background jobs with SIGINT ignored).
        def _stop(signum, frame):
            raise KeyboardInterrupt

        signal.signal(signal.SIGINT, _stop)
        signal.signal(signal.SIGTERM, _stop)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            if viewer is not None:
                viewer.terminate()
                viewer.wait(timeout=10)
            rec.disconnect()
    return 0
