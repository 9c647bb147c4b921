"""Screenshots of the picture in the scene for the README and docs/picture.md, from the real page.

``python tools/make_picture_screenshots.py [--out docs/img]`` opens ``geoloc view``'s app on the
bundled example flight (its rendered H.264 video beside the KLV) with the picture layer, loads
headless Debian Chromium through playwright (``/usr/bin/chromium``, its HOME in a temporary
folder), and writes

* ``picture_frustum.png``: packet 90's frame textured in its frustum over the terrain;
* ``picture_pixel_pick.png``: a painted cross clicked in the 2D panel (a real mouse click on the
  panel's image), its ray to the terrain, the marker and the panel's numbers;
* ``picture_drape.png``: the frame orthorectified and draped on the terrain (the panel's toggle);
* ``picture_heading_bias.png``: packet 105 (heading 2.5 deg off): the crosses part from the white
  marks of the targets' reprojection, and the panel says so.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz")]  # the browser helpers of tests/viz


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "img"))
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    from test_viz_browser import chromium, open_viewer, wait_for
    from test_viz_picture import _panel_pixel_xy

    from geoloc_viz import image_layer
    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.flight_model import default_flight_scenario
    from geoloc.workflows.render import find_marks

    scn = default_flight_scenario()
    labels = [str(i.label) for i, _ in scn.records]
    server = make_server(port=0)
    try:
        app = GeolocApp(server, scn, layers=(image_layer.attach,))
        layer = app.layers[0]
        app.load_record(labels.index("packet 90"), move_camera=False)
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            page = open_viewer(browser, server, 1280, 800)
            page.wait_for_selector("#geoloc-picture", timeout=60000)
            client = next(iter(server.get_clients().values()))

            def panel_shows_the_picture():
                """Scroll the panel so the picture is at its top, its numbers below it (under the legend
                they are out of an 800-pixel window's view)."""
                page.locator("#geoloc-picture").evaluate("e => e.scrollIntoView({block: 'start'})")

            def look(eye, aim, name, settle=3.0):
                app.move_camera((eye, aim))
                wait_for(lambda: np.linalg.norm(np.array(client.camera.position) - eye) < 1e-3, 30, "camera")
                time.sleep(settle)
                page.screenshot(path=str(out / name), timeout=180000)
                print(f"wrote {out / name}")

            # the "software WebGL" notice (SwiftShader) would cover the scene's corner
            page.add_style_tag(content="[class*='Notification-root']{display:none !important}")
            # the aircraft and its frames drawn x15 (not x200): the frustum in view; viser's value setter
            # is not next to its getter: mypy sees the property read-only
            app.sl_ac.value = 15.0  # type: ignore[misc]
            d = app.view.disp

            def frame_geometry():
                g = app.geometry
                return d.z(g.aircraft_enu), d.z(g.hit_enu), app.view.camera_pose("overview")

            def behind(A, P):
                """A point of view from the aircraft's side of the picture, a little off the line of sight."""
                v = P - A
                side = np.cross(v, [0.0, 0.0, 1.0])
                side /= np.linalg.norm(side)
                return A + 0.35 * v + side * 0.22 * np.linalg.norm(v) + np.array([0, 0, 0.08]) * np.linalg.norm(v)

            layer.sl_dist.value = 0.45
            time.sleep(1.0)
            A, H, (E0, _) = frame_geometry()
            P = layer.plane[0]
            look(behind(A, P), P, "picture_frustum.png")

            # click the first painted cross found in the frame, in the panel, zoomed 4x
            r, c = find_marks(layer.image)[0][0]
            r, c = float(round(r)), float(round(c))
            layer.sl_zoom.value = 2
            wait_for(
                lambda: page.locator("#geoloc-picture").get_attribute("data-w") == str(layer.image.shape[1] // 4),
                60,
                "the 4x crop",
            )
            layer.pick_pixel(r, c)  # centre the zoomed crop on it, then click it as a person does
            time.sleep(1.0)
            wait_for(
                lambda: (
                    page.locator("#geoloc-picture").bounding_box() is not None
                    and page.locator("#geoloc-picture").get_attribute("data-r1") is not None
                ),
                60,
                "the panel",
            )
            x, y = _panel_pixel_xy(page, r, c)
            page.mouse.click(x, y)
            wait_for(lambda: layer.pick is not None and (layer.pick.row, layer.pick.col) == (r, c), 60, "the pick")
            page.wait_for_selector("text=latitude", timeout=60000)
            layer.sl_dist.value = 0.25
            time.sleep(1.0)
            panel_shows_the_picture()
            look(E0 + 0.15 * (A - E0), 0.55 * H + 0.45 * A, "picture_pixel_pick.png")

            layer.cb_drape.value = True
            wait_for(lambda: f"{image_layer.ROOT}/drape" in layer.handles, 120, "the drape")
            layer.cb_frustum.value = False
            # from above, on the aircraft's side: the draped footprint around the hit markers
            hz = (A - H) * np.array([1.0, 1.0, 0.0])
            hz /= np.linalg.norm(hz)
            L = float(np.linalg.norm(A - H))
            look(H + hz * 0.12 * L + np.array([0.0, 0.0, 0.3 * L]), H - hz * 0.02 * L, "picture_drape.png", 5.0)
            layer.cb_drape.value = False
            layer.cb_frustum.value = True

            app.load_record(labels.index("packet 105"), move_camera=False)
            layer.pick = None
            layer.sl_zoom.value = 0
            layer.sl_dist.value = 0.45
            time.sleep(2.0)
            page.wait_for_selector("text=disagree", timeout=60000)
            panel_shows_the_picture()
            A, H, (E0, _) = frame_geometry()
            P = layer.plane[0]
            look(behind(A, P), P, "picture_heading_bias.png")
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
