"""The README's viewer screenshots, from the real page: ``geoloc view``'s per-tab viewer on the
bundled example flight in headless Debian Chromium (software WebGL), 1100 x 700.

* ``docs/img/viewer_first_view.png``: the first view (the whole flight framed, its flagged runs
  labelled), once the canvas has settled;
* ``docs/img/viewer_outlier_error.png``: after "go to" packet 100 (set as the GUI would), its
  error vector framed and labelled;
* ``docs/img/viewer_legend.png``: then the Legend folder opened with a click and scrolled to the
  panel's top, as a person reads it (its colour words are the viewer's one colour table's);
* ``docs/img/viewer_limb.png``: ``geoloc view --scenario limb`` (its own viewer, 1100 x 700) with the
  line of sight meeting the Earth (frame 0, view angle alpha -1.5 deg, set as its sliders do): the
  Earth in view below the line, not filling it.

Run: ``python tools/make_viewer_screenshots.py [--out docs/img] [--only flight|limb]``. Each PNG is written to a
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz")]  # the browser helpers of tests/viz
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="folder of the PNGs (docs/img)")
    ap.add_argument("--packet", type=int, default=100, help="the outlier to go to (default 100)")
    ap.add_argument("--only", choices=("flight", "limb"), help="take only the flight's two or the limb's one")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.only != "limb":
        flight_shots(args)
    if args.only != "flight":
        limb_shot(args)
    return 0


def shot(page, path: Path) -> None:
    """A screenshot of the page written to a temporary file and renamed into place."""
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        from test_viz_browser import close_software_webgl_notice

        close_software_webgl_notice(page)
        page.screenshot(path=tmp, timeout=120000)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    print(f"wrote {path}")


def _canvas(page) -> np.ndarray:
    """The page's 3D canvas as RGB floats."""
    import io

    import PIL.Image

    png = page.locator("canvas").first.screenshot(timeout=120000)
    return np.asarray(PIL.Image.open(io.BytesIO(png)).convert("RGB"), float)


def limb_shot(args) -> None:
    """``viewer_limb.png``: the limb scene with the line of sight meeting the Earth (module docstring)."""
    from bench_browser import PROBE, _settled
    from test_viz_browser import chromium

    from geoloc_viz.app import make_server
    from geoloc_viz.scene_limb import LimbViewer, load_limb

    server = make_server(port=0)
    viewer = LimbViewer(server, load_limb())
    try:
        with tempfile.TemporaryDirectory() as home, chromium(Path(home)) as browser:
            page = browser.new_page(viewport={"width": 1100, "height": 700})
            page.add_init_script(PROBE)
            t0 = time.time()
            page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
            _settled(page, t0, ready=lambda: len(viewer.apps) == 1)
            app = next(iter(viewer.apps.values()))
            before = _canvas(page)
            # viser's value setter is not next to its getter: mypy sees the property read-only
            app.sl_frame.value = 0  # type: ignore[misc]
            app.sl_alpha.value = -1.5  # type: ignore[misc]  # the line of sight meets the Earth (HITS_EARTH)
            # the camera moves with the view angle: wait for a canvas that differs from before and holds
            # still over two shots 2 s apart (the probe's change count settles on its own too early here)
            t1, prev = time.monotonic(), None
            while time.monotonic() - t1 < 240:
                img = _canvas(page)
                if prev is not None and np.abs(img - prev).mean() < 0.5 and np.abs(img - before).mean() > 1.0:
                    break
                prev = img
                time.sleep(2.0)
            else:
                raise RuntimeError("the limb scene's canvas did not settle within 240 s")
            shot(page, args.out / "viewer_limb.png")
    finally:
        server.stop()


def flight_shots(args) -> None:
    """``viewer_first_view.png``, ``viewer_outlier_error.png`` and ``viewer_legend.png`` (module docstring)."""
    from bench_browser import PROBE, _settled
    from test_viz_browser import chromium

    from geoloc_viz.app import GeolocViewer, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    server = make_server(port=0)
    viewer = GeolocViewer(server, default_flight_scenario())
    built = []
    orig = viewer._build_tab

    def build_tab(client, name) -> None:  # the viewer's own, then the client noted as built
        orig(client, name)
        built.append(client.client_id)

    viewer._build_tab = build_tab  # type: ignore[method-assign]

    try:
        with tempfile.TemporaryDirectory() as home, chromium(Path(home)) as browser:
            page = browser.new_page(viewport={"width": 1100, "height": 700})
            page.add_init_script(PROBE)
            t0 = time.time()
            page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
            _, seen = _settled(page, t0, ready=lambda: len(built) == 1)
            shot(page, args.out / "viewer_first_view.png")
            session = viewer.session_of(built[0])
            assert session is not None  # the client built its tab above
            fl = session.layers[0]
            opt = next(o for o, i in zip(fl.opts, fl.top_idx) if fl.model.labels[i] == f"packet {args.packet}")
            t1 = time.time()
            fl.dd_goto.value = opt  # as the GUI would
            _settled(page, t1, after=seen)
            shot(page, args.out / "viewer_outlier_error.png")
            page.get_by_text("Legend", exact=True).first.click(timeout=120000)
            items = page.locator("li", has_text="the ellipsoid hit at H_max").first.locator("xpath=..")
            items.wait_for(timeout=120000)
            items.evaluate("e => e.scrollIntoView({block: 'start'})")
            shot(page, args.out / "viewer_legend.png")
    finally:
        server.stop()


if __name__ == "__main__":
    raise SystemExit(main())
