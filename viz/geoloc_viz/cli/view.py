"""``geoloc view``: the interactive 3D scene in the browser (viser).

With no arguments it opens the bundled example flight (MISB ST 0601 KLV over the
SRTM crop, with planted faults) in the flight debugger: the track, footprints,
outliers first, the accuracy panel, and the current frame's aircraft, gimbal
frames, line of sight, terrain iterations and hit. ``--scenario flight-test``
opens the [Q17] flight-test records. The viewer
lives in the ``viz`` package (the core never imports viser). User guide:
``docs/viz.md``.
"""

from __future__ import annotations

import sys
import time
import webbrowser

from geoloc.cli._options import add_dem_options, add_sensor_option, input_path, one_dem_raster, output_path
from geoloc.cli import VERB_HELP


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
#: The [Q17] flight-test scene (a record over its DEM): the same GeolocApp export as the default
#: example flight, whose 5364 footprint rays make its first scene about 3 times the CPU.
EXAMPLE = "geoloc view --no-browser --scenario flight-test --export scene.html"


def register(sub) -> None:
    p = sub.add_parser(
        "view",
        help=VERB_HELP["view"],
        description="Start a local viser server with the 3D scene of a geolocation: aircraft, "
        "NED/body/gimbal/camera frames, frustum, line of sight, DEM mesh, the iterations of the "
        "terrain method, and the published and surveyed positions of a flight-test record. "
        "With --scenario limb: the TianGong-2 limb-viewing scene; with a Sentinel-2 L1B product "
        "folder: its orbit, attitude frames, lines of sight and footprints. Binds to 127.0.0.1 unless "
        "--host says otherwise.",
    )
    p.add_argument(
        "--scenario",
        default="flight",
        type=input_path,
        help="'flight' (default: the bundled MISB ST 0601 example flight over the SRTM crop, "
        "with its planted faults, in the flight debugger), 'flight-test' (the bundled [Q17] "
        "records), 'limb' (bundled TianGong-2 limb scenario), a path to a limb scenario TOML, or a "
        "Sentinel-2 L1B product folder (holding DATASTRIP and GRANULE: its orbit, attitude, lines of "
        "sight and footprints, docs/sentinel2.md)",
    )
    p.add_argument("--s2-band", default="B02", help="with a Sentinel-2 product: the band shown (default B02)")
    p.add_argument(
        "--records",
        default=None,
        type=input_path,
        help="records CSV (or a MISB ST 0601 .klv/.ts file) for the flight scene (default: "
        "the bundled example flight; with --scenario flight-test the bundled "
        "assets/records/qiao2017_flight_tests.csv)",
    )
    p.add_argument(
        "--record", default=None, help="record to open: label such as T4-3, or 0-based index (default: the first)"
    )
    add_sensor_option(p)
    from geoloc.cli._options import add_correction_options

    add_correction_options(p)
    add_dem_options(
        p,
        mosaic=False,
        tolerances=False,
        method_default=None,
        dem_help="DEM GeoTIFF (default: a bundled DEM covering the target, if any)",
        method_help="terrain method shown first: steps, bisect or exact (default bisect)",
    )
    p.add_argument("--no-dem", action="store_true", help="no terrain: intersect at each record's paper_height_m")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="interface to bind (default 127.0.0.1, this machine only; 0.0.0.0 exposes the viewer to the network)",
    )
    p.add_argument(
        "--port",
        type=int,
        default=None,
        help="port (default 8080; viser moves to the next free one if taken; 0 = any free). "
        "With --export the scene is built on a private server on 127.0.0.1 at this "
        "port (default: any free one) that is stopped before the command returns",
    )
    p.add_argument(
        "--pixel",
        action="append",
        default=None,
        metavar="ROW,COL",
        help="with --export: locate this pixel of the record's picture before exporting, as a "
        "click in the picture panel does (1-based pixel centres; repeat for several): its ray and "
        "hit are in the scene, the picture with its marks and each pixel's latitude, longitude, "
        "height and datum in the page",
    )
    p.add_argument(
        "--export",
        default=None,
        metavar="FILE",
        type=output_path,
        help="write a static recording and exit, printing only its name: FILE.html "
        "(self-contained, opens in a browser without a server, with a text panel naming "
        "the record, the hit and its error) or FILE.viser (viser's playback format)",
    )
    p.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    p.add_argument(
        "--presenter",
        action="store_true",
        help="presenter mode: the first browser tab drives, the others follow read-only "
        "(scene, camera, disabled controls) until one presses 'take control'. Default: "
        "every tab has its own state",
    )
    p.add_argument(
        "--max-clients",
        type=int,
        default=16,
        metavar="N",
        help="browser tabs served at once (default 16); a tab beyond is told the limit",
    )
    lv = p.add_argument_group("live (docs/live.md)")
    lv.add_argument(
        "--live",
        default=None,
        metavar="udp://HOST:PORT",
        type=input_path,
        help="follow a live MPEG-TS / MISB ST 0601 stream: the timeline grows as packets arrive, "
        "the view follows the latest frame until you scrub back ('live' returns), loss counts in "
        "a panel",
    )
    lv.add_argument(
        "--journal",
        default=None,
        metavar="FILE.csv",
        type=output_path,
        help="live: journal every located packet's row to this CSV as it arrives (the columns of geoloc replay --out)",
    )
    from geoloc.cli._options import add_live_options

    add_live_options(p, record_flag="--record-ts")
    p.set_defaults(func=run)


def build(args, server, serve: bool = False):
    """Build the app named by ``args`` on ``server``; returns the app object.

    ``serve``: the flight-test scene as a :class:`geoloc_viz.app.GeolocViewer` (a state per
    tab, or ``--presenter``); otherwise a session on the server itself (the export's).
    """
    return app_factory(args, serve)(server)


def app_factory(args, serve: bool = False):
    """Load and check everything the scene needs (files, record, DEM); returns ``server -> app``.

    ``geoloc view`` calls it before it starts a server, so a bad input is reported
    and nothing is served.
    """
    scen = args.scenario
    dem = one_dem_raster(args, "view")
    if scen in ("flight", "flight-test", "qiao2017", "default"):
        from geoloc_viz.app import GeolocApp, GeolocViewer
        from geoloc_viz.flight_model import default_flight_scenario
        from geoloc_viz.scenario import KLV_SUFFIXES, load_view_scenario

        klv = args.records is not None and args.records.lower().endswith(KLV_SUFFIXES)
        if scen in ("flight", "default") and args.records is None or klv:
            # the bundled MISB ST 0601 example flight (or the user's KLV), with each frame's fields of view
            scn = default_flight_scenario(
                args.record, args.records, args.camera, dem, use_dem=not args.no_dem, dem_datum=args.dem_datum
            )
        else:
            scn = load_view_scenario(
                args.records, args.record, args.camera, dem, use_dem=not args.no_dem, dem_datum=args.dem_datum
            )
        if args.method:
            scn.inputs = scn.inputs.replace(method=args.method)
        with_corrections = _corrections_setter(args)
        with_corrections(scn)
        if serve:
            scenarios = None
            if args.records is None and args.dem is None and args.camera is None:
                # the two bundled scenarios, one click apart (the chosen one first)
                flight = (
                    "example flight (MISB ST 0601 KLV)",
                    lambda: with_corrections(default_flight_scenario(use_dem=not args.no_dem)),
                )
                q17 = ("[Q17] flight test", lambda: with_corrections(load_view_scenario(use_dem=not args.no_dem)))
                scenarios = dict([q17, flight] if scen in ("flight-test", "qiao2017") else [flight, q17])
            return lambda server: GeolocViewer(
                server,
                scn,
                presenter=getattr(args, "presenter", False),
                max_clients=getattr(args, "max_clients", 16),
                scenarios=scenarios,
            )
        return lambda server: GeolocApp(server, scn)
    from geoloc_viz.scene_sentinel2 import is_product

    if is_product(scen):
        from geoloc_viz.scene_sentinel2 import Sentinel2App, Sentinel2Viewer, load

        product = load(scen)
        band = getattr(args, "s2_band", "B02")
        return (
            (lambda server: Sentinel2Viewer(server, product, band))
            if serve
            else (lambda server: Sentinel2App(server, product, band))
        )
    from geoloc_viz.scene_limb import LimbApp, LimbViewer, load_limb

    limb = load_limb(None if scen == "limb" else scen)
    refr = getattr(args, "refraction", None) == "standard"  # the refracted tangent point beside the straight one
    # serving: a state per tab, as the flight scene; the export: one scene on the server
    return (lambda server: LimbViewer(server, limb, refr)) if serve else (lambda server: LimbApp(server, limb, refr))


def _corrections_setter(args):
    """``scn -> scn`` with ``Scenario.corrections`` set from ``--refraction`` / ``--light-time`` over the
    ``--sensor`` file's ``[corrections]`` table and the sensor's defaults (the core's option helper)."""
    from geoloc.cli._options import corrections_from_args

    def apply(scn):
        scn.corrections = corrections_from_args(args, scn.camera)
        return scn

    return apply


def run(args) -> int:
    if args.port is not None and not 0 <= args.port <= 65535:
        raise ValueError(f"port = {args.port}: must be in 0..65535")
    if args.max_clients < 1:
        raise ValueError(f"max-clients = {args.max_clients}: must be >= 1")
    if args.live:
        return _run_live(args)
    for opt in ("journal", "record_ts", "duration", "packets", "idle"):
        if getattr(args, opt, None) is not None:
            raise ValueError(f"--{opt.replace('_', '-')} is for --live udp://HOST:PORT")
    if args.pixel and not args.export:
        raise ValueError("--pixel is used with --export (in the browser, click the picture panel)")
    if args.export:
        return _export(args)
    from geoloc_viz.app import make_server

    make_app = app_factory(args, serve=True)  # inputs read and checked before anything is served
    server = make_server(args.host, 8080 if args.port is None else args.port)
    try:
        make_app(server)
        url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{server.get_port()}"
        mode = (
            "presenter mode: the first tab drives, the others follow"
            if args.presenter
            else "each browser tab has its own state"
        )
        print(f"geoloc view: {url}  ({mode}; at most {args.max_clients} tabs; Ctrl+C to stop)", flush=True)
        if args.host not in ("127.0.0.1", "localhost", "::1"):
            print(
                f"warning: listening on {args.host}: anyone who can reach this machine can open the viewer",
                file=sys.stderr,
            )
        if not args.no_browser:
            webbrowser.open(url)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        try:
            server.stop()
        except KeyboardInterrupt:  # a second Ctrl+C while stopping
            pass


def _export(args) -> int:
    """Build the scene on a private local server, write the file, stop; print only the file's name.

    viser prints a banner when a server starts and a line when it stops; neither
    means anything to someone exporting a file, so both are swallowed (viser's
    own output only: errors still reach stderr).
    """
    import contextlib
    import io

    from geoloc_viz.app import make_server

    if args.host not in ("127.0.0.1", "localhost"):
        print(
            f"geoloc view: note: --host {args.host} is not used by --export (no one connects "
            "to an export's private server)",
            file=sys.stderr,
        )
    sink = io.StringIO()
    with contextlib.redirect_stdout(sink):
        server = make_server("127.0.0.1", 0 if args.port is None else args.port)
        try:
            app = build(args, server)
            _pick_pixels(app, args.pixel or ())
            path = app.export(args.export)
        finally:
            server.stop()
            time.sleep(0.05)  # viser's server thread prints its "stopped" line on its way out
    print(f"wrote {path}")
    return 0


def _run_live(args) -> int:
    """``geoloc view --live udp://HOST:PORT``: :class:`geoloc_viz.live_view.LiveViewer` (docs/live.md)."""
    import contextlib

    from geoloc.cli._options import is_stream, live_limits
    from geoloc.userfiles import growing_path

    if not is_stream(args.live):
        raise ValueError(f"--live {args.live}: give a stream, udp://HOST:PORT (a file opens with --records)")
    if args.export:
        raise ValueError("--export writes a static scene; --live follows a stream: give one of them")
    limits = live_limits(args, args.live)
    from geoloc.cli.klv import _bind

    sock = _bind(args.live)  # before the viewer's imports: what is sent meanwhile waits in the kernel
    from geoloc.cli._options import sensor_from_args

    sensor = sensor_from_args(args, default=False)
    surface = None  # each packet at its own frame-centre height
    if args.dem:
        from geoloc.surfaces.spec import SurfaceSpec

        surface = SurfaceSpec(
            dem=one_dem_raster(args, "view"), dem_datum=args.dem_datum, method=args.method or "exact"
        ).build()
    from geoloc_viz.app import make_server
    from geoloc_viz.live_view import LiveFeed, LiveViewer

    with contextlib.ExitStack() as stack:
        journal = record = None
        if args.journal:
            part = stack.enter_context(growing_path(args.journal, "--journal"))
            journal = stack.enter_context(part.open("w", newline=""))
        if args.record_ts:
            rec = stack.enter_context(growing_path(args.record_ts, "--record-ts"))
            fh = stack.enter_context(rec.open("wb"))
            record = fh.write
        feed = LiveFeed(
            args.live, sensor=sensor, surface=surface, limits=limits, journal=journal, record=record, sock=sock
        )
        server = make_server(args.host, 8080 if args.port is None else args.port)
        viewer = None
        try:
            viewer = LiveViewer(
                server,
                feed,
                max_clients=args.max_clients,
                dem_path=one_dem_raster(args, "view"),
                dem_datum=args.dem_datum,
            )
            feed.start()
            url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{server.get_port()}"
            print(f"geoloc view: {url}  (live: {args.live}; Ctrl+C to stop)", flush=True)
            if args.host not in ("127.0.0.1", "localhost", "::1"):
                print(
                    f"warning: listening on {args.host}: anyone who can reach this machine can open the viewer",
                    file=sys.stderr,
                )
            if not args.no_browser:
                webbrowser.open(url)
            while not feed.done:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        finally:
            if viewer is not None:
                viewer.stop()
            else:
                feed.stop()
            try:
                server.stop()
            except KeyboardInterrupt:
                pass
    print(feed.replay.summary())
    print(f"  stream: {feed.rx.stats.line()}")
    return 0


def _pick_pixels(app, values) -> None:
    """``--pixel ROW,COL`` for an export: each located through the picture layer (a click's path)."""
    if not values:
        return
    from geoloc_viz.image_layer import parse_pixel

    layer = next((obj for obj in getattr(app, "layers", ()) if hasattr(obj, "pick_pixel")), None)
    if layer is None or layer.sensor is None:
        raise ValueError(f"--pixel {values[0]}: the record has no picture (a video or photo beside its metadata)")
    for v in values:
        rc = parse_pixel(str(v))
        if rc is None:
            raise ValueError(f"--pixel {v!r}: expected ROW,COL (1-based pixel centres, e.g. 180.5,320)")
        layer.pick_pixel(*rc)
