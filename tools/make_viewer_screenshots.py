"""The README's two viewer screenshots (issue 34), from the real page: ``geoloc view``'s per-tab
viewer on the bundled example flight in headless Debian Chromium (software WebGL), 1100 x 700.

* ``docs/img/viewer_first_view.png``: the first view (the whole flight framed, its flagged runs
  labelled), once the canvas has settled;
* ``docs/img/viewer_outlier_error.png``: after "go to" packet 100 (set as the GUI would), its
  error vector framed and labelled.

Run: ``python tools/make_viewer_screenshots.py [--out docs/img]``. Each PNG is written to a
temporary file and renamed into place. The canvas is watched from inside the page as
``benchmarks/bench_browser.py`` watches it (2 s without a change).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz")]  # the browser helpers of tests/viz
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="folder of the PNGs (docs/img)")
    ap.add_argument("--packet", type=int, default=100, help="the outlier to go to (default 100)")
    args = ap.parse_args(argv)
    from bench_browser import PROBE, _settled
    from test_viz_browser import chromium

    from geoloc_viz.app import GeolocViewer, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    args.out.mkdir(parents=True, exist_ok=True)
    server = make_server(port=0)
    viewer = GeolocViewer(server, default_flight_scenario())
    built = []
    orig = viewer._build_tab
    viewer._build_tab = lambda client, name: (orig(client, name), built.append(client.client_id))

    def shot(page, name):
        path = args.out / name
        fd, tmp = tempfile.mkstemp(suffix=".png", dir=args.out)
        os.close(fd)
        try:
            page.screenshot(path=tmp, timeout=120000)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        print(f"wrote {path}")

    try:
        with tempfile.TemporaryDirectory() as home, chromium(Path(home)) as browser:
            page = browser.new_page(viewport={"width": 1100, "height": 700})
            page.add_init_script(PROBE)
            t0 = time.time()
            page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
            _, seen = _settled(page, t0, ready=lambda: len(built) == 1)
            shot(page, "viewer_first_view.png")
            fl = viewer.session_of(built[0]).layers[0]
            opt = next(o for o, i in zip(fl.opts, fl.top_idx) if fl.model.labels[i] == f"packet {args.packet}")
            t1 = time.time()
            fl.dd_goto.value = opt  # as the GUI would
            _settled(page, t1, after=seen)
            shot(page, "viewer_outlier_error.png")
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
