"""One target picked in several frames of the viewer: its rays meet in the scene.

The frames are the bundled example flight's records 1, 21 and 41 (an orbit: 50 degrees of heading
between the first and the last), rendered as in ``tests/viz/test_viz_picture.py``. The target is the
ground point G of record 21's image centre on the SRTM crop; in each frame the pixel that sees G is
picked (``ground_to_pixel``), so every ray passes through G and their intersection is G itself:
checked against pyproj's geodetic -> ECEF of G (not the code under test), to a millimetre, with
residuals of a millimetre and a DEM-minus-triangulated height of zero (G is on the DEM).

In headless Chromium (``-m browser``) a person clicks the target's pixel (rounded to a whole
pixel) in the panel of each of the three frames, reads the triangulated position in the panel and
takes a screenshot; the clicked pixels are within half a pixel of G's, so the point is within the
rays' spread there (``bound_m``).
"""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

from geoloc_viz.scene_geoloc import WORLD_SCALE

from geoloc.io.images import ArrayImages
from geoloc.status import Status

FRAMES = (0, 20, 40)


@pytest.fixture(scope="module")
def orbit():
    from test_viz_picture import render_frame

    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    scn.images = ArrayImages([render_frame(scn, i) for i in FRAMES])
    idx = np.full(len(scn.records), -1)
    idx[list(FRAMES)] = np.arange(len(FRAMES))
    scn.image_index = idx
    return scn


def _target(app, layer):
    """G: record 21's image centre on the DEM (lat, lon [deg], h [m] ellipsoidal)."""
    from geoloc_viz import picture_model as pm

    app.load_record(FRAMES[1], move_camera=False)
    c = pm.locate_pixel(app.scn, app.inputs, layer.sensor, *layer.sensor.center_pixel)
    assert c.ok
    return c.lat_deg(), c.lon_deg(), float(c.hit.h)


def _pixel_of(app, layer, g):
    px = layer.sensor.ground_to_pixel(math.radians(g[0]), math.radians(g[1]), g[2], app.inputs.pose())
    assert int(np.asarray(px.status)) == Status.OK
    return float(np.asarray(px.row)), float(np.asarray(px.col))


def _ecef_pyproj(lat_deg, lon_deg, h):
    import pyproj

    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(t.transform(lon_deg, lat_deg, h))


def test_picks_in_three_frames_meet_at_the_ground_point(orbit):
    from test_viz_picture import make_app

    server, app, layer = make_app(orbit)
    try:
        g = _target(app, layer)
        for n, k in enumerate(FRAMES):
            app.load_record(k, move_camera=False)
            r, c = _pixel_of(app, layer, g)
            layer.pick_pixel(r, c)
            if n == 0:
                assert layer.target_rays is None and "1 frame picked" in layer.md_target.content
        t = layer.target_rays
        assert t is not None and t.frames == list(FRAMES) and t.tri.status == Status.OK
        G = _ecef_pyproj(*g)
        # every ray passes through G (to ground_to_pixel's inversion, ~1e-9 px): their intersection is G
        assert np.linalg.norm(np.asarray(t.tri.ecef) - G) < 1e-3
        assert np.nanmax(t.tri.residual_m) < 1e-3
        # G is on the DEM and seen by every frame: each frame's DEM hit is G, DEM minus triangulated 0
        assert abs(t.surface["mean_m"]) < 1e-2 and not t.surface["warning"]
        # a budget (the illustrative one: the bundled sensor has none) gives the covariance and ellipse
        assert t.tri.cov_enu is not None and 0 < t.tri.ce90_m < 100
        text = layer.md_target.content
        assert "3 frames" in text and f"{t.tri.lat_deg:.8f}" in text and "ray residual" in text
        assert "DEM minus triangulated" in text and "covariance ENU" in text
        for name in ("rays", "residuals", "point", "ellipse"):
            assert server.scene.get_handle_by_name(f"/enu/picture/target/{name}") is not None, name
        # true size by default, and the drawing says so; the Display factor enlarges the residuals and
        # the ellipse about the point, and the label on the drawing then gives the factor
        label = server.scene.get_handle_by_name("/enu/picture/target/label")
        assert label.text.endswith("90 % ellipse at true size"), label.text

        def ellipse_radius_m():
            seg = np.asarray(server.scene.get_handle_by_name("/enu/picture/target/ellipse").points, float)
            X = server.scene.get_handle_by_name("/enu/picture/target/point").position
            return float(np.max(np.hypot(seg[:, 0, 0] - X[0], seg[:, 0, 1] - X[1]))) / WORLD_SCALE

        r1 = ellipse_radius_m()
        app.sl_err.value = 10.0
        layer.draw_target()
        assert server.scene.get_handle_by_name("/enu/picture/target/label").text.endswith("drawn x10")
        # float32 km positions near the origin: well under 1 mm of a metres-wide ellipse
        assert ellipse_radius_m() == pytest.approx(10.0 * r1, rel=1e-4)
        app.sl_err.value = 1.0
        layer.clear_target()
        assert layer.target_rays is None and layer.md_target.content == ""
    finally:
        server.stop()


@pytest.mark.browser
def test_click_the_target_in_three_frames_in_chromium(orbit, tmp_path):
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for
    from test_viz_picture import _panel_pixel_xy, make_app

    ARTIFACTS.mkdir(exist_ok=True)
    server, app, layer = make_app(orbit)
    try:
        g = _target(app, layer)
        G = _ecef_pyproj(*g)
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1280, 900)
            page.wait_for_selector("#geoloc-picture", timeout=60000)
            layer.sl_zoom.value = 2  # 4x: an image pixel is ~9 screen px, a click lands inside it
            clicked = []
            for k in FRAMES:
                app.load_record(k, move_camera=False)
                wait_for(lambda: layer.index == k and layer.image is not None, 60, f"record {k + 1}'s image")
                r, c = (float(round(v)) for v in _pixel_of(app, layer, g))
                wait_for(
                    lambda: page.locator("#geoloc-picture").get_attribute("data-w") == str(240 // 4),
                    60,
                    "the panel to show the 4x crop",
                )
                time.sleep(1.0)
                x, y = _panel_pixel_xy(page, r, c)
                page.mouse.click(x, y)
                wait_for(
                    lambda: layer.pick is not None and (layer.pick.row, layer.pick.col) == (r, c) and k in layer.target,
                    60,
                    "the click to reach the server",
                )
                clicked.append((r, c))
            page.wait_for_selector("text=triangulated latitude", timeout=60000)
            t = layer.target_rays
            # the panel shows a triangulation from the second click on: wait for the third's (the
            # page can still hold the two-frame one when the server has the three-frame one)
            panel = page.locator("text=triangulated latitude").first
            wait_for(lambda: f"{t.tri.lat_deg:.8f}" in panel.inner_text(), 60, "the panel to show three frames'")
            text = panel.inner_text()
            lat = float(re.search(r"latitude\s*([-0-9.]+)", text).group(1))
            lon = float(re.search(r"longitude\s*([-0-9.]+)", text).group(1))
            assert lat == pytest.approx(t.tri.lat_deg, abs=1e-8) and lon == pytest.approx(t.tri.lon_deg, abs=1e-8)
            # the clicked pixels are within half a pixel of G's: each ray misses G by at most its
            # ground sample there (range x pixel angle x 0.71); the intersection is within a few of them
            rng = [float(p.hit.slant_range) for p in t.picks]
            ifov = max(1.0 / float(s.lens.fx) for s, _, _ in layer.target.values())
            bound_m = 4.0 * 0.71 * max(rng) * ifov / math.sin(math.radians(10.0))
            err = float(np.linalg.norm(np.asarray(t.tri.ecef) - G))
            print(
                f"clicked {clicked}; triangulated {err:.2f} m from G (bound {bound_m:.1f} m); residuals "
                f"{np.round(t.tri.residual_m, 2)} m; CE90 {t.tri.ce90_m:.1f} m"
            )
            assert err < bound_m
            # look at the rays from the side, half way up to the cameras, and show the panel's text
            z = lambda p: np.asarray(app.view.disp.z(app.scn.enu.from_ecef(p)), float)  # noqa: E731
            Gs, m = z(G), np.mean([z(o) for o in t.origins], 0) - z(G)
            side = np.cross(m, [0.0, 0.0, 1.0])
            side /= np.linalg.norm(side)
            app.move_camera((Gs + 0.45 * m + 0.9 * np.linalg.norm(m) * side, Gs + 0.3 * m))
            page.locator("text=triangulated latitude").first.evaluate("e => e.scrollIntoView({block: 'center'})")
            time.sleep(3.0)
            page.screenshot(path=str(ARTIFACTS / "viz_target_rays.png"))
    finally:
        server.stop()
