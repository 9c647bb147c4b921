"""``geoloc view``: the interactive 3D scene in the browser (viser).

With no arguments it opens the bundled default: the first [Q17] flight-test
record over the bundled terrain, showing the aircraft, the gimbal frames, the
line of sight, the iterations of the terrain method and the hit. The viewer
lives in the ``viz`` package (the core never imports viser). User guide:
``docs/viz.md``.
"""

from __future__ import annotations

import sys
import time
import webbrowser


def register(sub) -> None:
    p = sub.add_parser(
        "view",
        help="open the interactive 3D scene in the browser (default: a bundled flight-test record)",
        description="Start a local viser server with the 3D scene of a geolocation: aircraft, "
        "NED/body/gimbal/camera frames, frustum, line of sight, DEM mesh, the iterations of the "
        "terrain method, and the published and surveyed positions of a flight-test record. "
        "With --scenario limb: the TianGong-2 limb-viewing scene. Binds to 127.0.0.1 unless "
        "--host says otherwise.",
    )
    p.add_argument("--scenario", default="flight-test",
                   help="'flight-test' (default: the bundled [Q17] records), 'limb' (bundled "
                   "TianGong-2 limb scenario) or a path to a limb scenario TOML")
    p.add_argument("--records", default=None,
                   help="records CSV for the flight-test scene (default: the bundled "
                   "assets/records/qiao2017_flight_tests.csv)")
    p.add_argument("--record", default=None,
                   help="record to open: label such as T4-3, or 0-based index (default: the first)")
    p.add_argument("--camera", default=None, help="camera TOML (default: assets/cameras/qiao2017.toml)")
    p.add_argument("--dem", default=None,
                   help="DEM GeoTIFF (default: a bundled DEM covering the target, if any)")
    p.add_argument("--no-dem", action="store_true",
                   help="no terrain: intersect at each record's paper_height_m")
    p.add_argument("--method", choices=("steps", "bisect", "exact"), default=None,
                   help="terrain method shown first (default bisect)")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to bind (default 127.0.0.1, this machine only; "
                   "0.0.0.0 exposes the viewer to the network)")
    p.add_argument("--port", type=int, default=8080,
                   help="port (default 8080; viser moves to the next free one if taken; 0 = any free)")
    p.add_argument("--export", default=None, metavar="FILE",
                   help="write a static recording and exit: FILE.html (self-contained, opens "
                   "in a browser without a server) or FILE.viser (viser's playback format)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    p.set_defaults(func=run)


def build(args, server):
    """Build the app named by ``args`` on ``server``; returns the app object."""
    scen = args.scenario
    if scen in ("flight-test", "qiao2017", "default"):
        from geoloc.viz.app import GeolocApp
        from geoloc.viz.scenario import load_scenario

        scn = load_scenario(args.records, args.record, args.camera, args.dem,
                            use_dem=not args.no_dem)
        if args.method:
            scn.inputs = scn.inputs.replace(method=args.method)
        return GeolocApp(server, scn)
    from geoloc.viz.scene_limb import LimbApp, load_limb

    return LimbApp(server, load_limb(None if scen == "limb" else scen))


def run(args) -> int:
    from geoloc.viz.app import make_server

    if args.port < 0 or args.port > 65535:
        raise ValueError(f"port = {args.port}: must be in 0..65535")
    # An export needs no listener anyone could reach: a free local port.
    server = make_server("127.0.0.1", 0) if args.export else make_server(args.host, args.port)
    try:
        app = build(args, server)
        if args.export:
            path = app.export(args.export)
            print(f"wrote {path}")
            return 0
        url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{server.get_port()}"
        print(f"geoloc view: {url}  (Ctrl+C to stop)", flush=True)
        if args.host not in ("127.0.0.1", "localhost", "::1"):
            print(f"warning: listening on {args.host}: anyone who can reach this machine can "
                  "open the viewer", file=sys.stderr)
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
