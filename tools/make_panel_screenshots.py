"""The large panel's screenshots for docs/viz.md, from the real page: ``geoloc view``'s per-tab
viewer on the bundled example flight in headless Debian Chromium (software WebGL), 1400 x 860.

A person's steps: open the large panel with its button, move the timeline to packet 90 (typed
into the frame index box), click painted cross (273, 310) in the large picture, then look at each
tab (on the plots, the pointer over them shows the readout of the frame under it). Writes ``panel_picture.png``, ``panel_map.png`` and ``panel_plots.png`` (each to a temporary
file renamed into place).

Run: ``python tools/make_panel_screenshots.py [--out docs/img]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz")]  # the browser helpers of tests/viz


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="folder of the PNGs (docs/img)")
    ap.add_argument("--packet", default="packet 90", help="the frame to show (its label)")
    ap.add_argument("--pixel", default="273,310", help="row,col of the pixel to click (1-based)")
    args = ap.parse_args(argv)
    from make_viewer_screenshots import shot  # one way to write a screenshot: temp file, renamed
    from test_viz_browser import chromium, wait_for

    from geoloc_viz.app import GeolocViewer, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    args.out.mkdir(parents=True, exist_ok=True)
    server = make_server(port=0)
    viewer = GeolocViewer(server, default_flight_scenario())
    r, c = (float(v) for v in args.pixel.split(","))

    try:
        with tempfile.TemporaryDirectory() as home, chromium(Path(home)) as browser:
            page = browser.new_page(viewport={"width": 1400, "height": 860})
            page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=60000)
            page.get_by_role("button", name="open the large panel").click(timeout=180000)
            page.locator("#geoloc-picture-large").wait_for(timeout=120000)
            labels = [info.label for info, _ in default_flight_scenario().records]
            idx = labels.index(args.packet)
            # the number box beside the timeline slider (arrow keys on the slider move the 3D camera too)
            row = page.locator("label", has_text="frame index").first.locator("xpath=ancestor::*[.//input][1]")
            box = row.locator("input:not([type=hidden])").last
            box.fill(str(idx))
            box.press("Enter")
            wait_for(
                lambda: f"frame {idx} of 0 .. " in page.locator("body").inner_text(),
                120,
                f"frame index {idx} on the page",
            )
            # two screen pixels per image pixel, so the click lands on the pixel asked (the panel is
            # narrower than the 640-pixel frame, and a click's position is a whole screen pixel):
            # the "picture size" box, set as a person chooses it, then the picture scrolled to the pixel
            for cid in list(server.get_clients()):
                s = viewer.session_of(cid)
                assert s is not None  # a client of the page: its session exists
                next(o for o in s.layers if type(o).__name__ == "PanelLayer").dd_size.value = "2:1"
            img = page.locator("#geoloc-picture-large")
            wait_for(lambda: "shown 2:1" in page.locator("body").inner_text(), 60, "the picture at 2:1")
            img.evaluate(
                f"e => {{ e.parentElement.scrollLeft = {2 * c - 200}; e.parentElement.scrollTop = {2 * r - 250}; }}"
            )
            time.sleep(2.0)
            b = img.bounding_box(timeout=60000)
            M, N = (float(img.get_attribute(k)) for k in ("data-rows", "data-cols"))
            page.mouse.click(b["x"] + (c - 0.5) / N * b["width"], b["y"] + (r - 0.5) / M * b["height"])
            page.wait_for_selector("text=latitude", timeout=120000)
            for cid in list(server.get_clients()):  # the whole frame again, for the picture
                s = viewer.session_of(cid)
                assert s is not None  # a client of the page: its session exists
                next(o for o in s.layers if type(o).__name__ == "PanelLayer").dd_size.value = "fit the panel"
            time.sleep(6.0)
            shot(page, args.out / "panel_picture.png")
            page.get_by_role("tab", name="Map").click()
            time.sleep(3.0)
            shot(page, args.out / "panel_map.png")
            page.get_by_role("tab", name="Plots").click()
            pp = page.locator("#geoloc-plots")
            pp.wait_for(timeout=120000)
            time.sleep(3.0)
            # the pointer on the plots, a little left of the cursor: the readout of the frame under it
            b = pp.bounding_box(timeout=60000)
            page.mouse.move(b["x"] + 0.22 * b["width"], b["y"] + 0.12 * b["height"])
            page.locator(".geoloc-plots-readout").wait_for(state="visible", timeout=60000)
            time.sleep(1.0)
            shot(page, args.out / "panel_plots.png")
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
