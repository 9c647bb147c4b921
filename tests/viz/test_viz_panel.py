"""The large panel (``geoloc_viz.panel_layer``): the picture at full resolution, the map, the plots.

* no browser: the map's pixel of every reported and surveyed point (latitude, longitude from the
  records) equals the pixel of pymap3d's East-North of it about the map's origin; the map's
  hillshade equals the core renderer's on a DEM-aligned ramp; a closed panel costs a step nothing;
  plots whose first drawing failed are drawn at the next frame, not left missing.
* headless Chromium, as a person does it: open the panel with its button; click a pixel of the
  large picture and read the sidebar's latitude and longitude: ``geoloc locate``'s for that pixel;
  the map tab's current footprint and pick sit where pymap3d puts the scene's own points (and are
  drawn there in the current frame's magenta); the plots' cursor is found in the screenshot at the
  current frame's time, for three frames along the timeline.
"""

from __future__ import annotations

import copy
import html
import io
import re
import time

import numpy as np
import pytest
from test_viz_picture import COLS, ROWS, locate_cli, read_pick_latlon, render_frame

from geoloc.io.images import ArrayImages


@pytest.fixture(scope="module")
def flight():
    """The bundled example flight with rendered images for its first two records."""
    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    n = 2
    scn.images = ArrayImages([render_frame(scn, i) for i in range(n)])
    scn.image_index = np.r_[np.arange(n), np.full(len(scn.records) - n, -1)]
    return scn


def make_app(scn):
    from geoloc_viz import flight_layer, image_layer, panel_layer
    from geoloc_viz.app import GeolocApp, make_server

    server = make_server(port=0)
    app = GeolocApp(server, copy.copy(scn), layers=(flight_layer.attach, image_layer.attach, panel_layer.attach))
    return server, app, app.layers[0], app.layers[1], app.layers[2]


def _enu_px(lat_deg, lon_deg, h_m, origin, e0, n0, mpp):
    """Map pixel (x, y) of a geodetic point by pymap3d: East-North about the map's origin."""
    import pymap3d

    e, n, _u = pymap3d.geodetic2enu(lat_deg, lon_deg, h_m, *origin)
    return np.stack([(np.asarray(e) - e0) / mpp, (n0 - np.asarray(n)) / mpp], -1)


def test_map_places_reported_and_surveyed_points_where_pymap3d_does(flight):
    from geoloc_viz import panel_layer
    from geoloc_viz.flight_layer import model_for

    m = model_for(flight)
    view = panel_layer.build_map(m, flight.dem)
    o = m.enu.to_geodetic(np.zeros(3))
    origin = (np.degrees(o[0]), np.degrees(o[1]), float(o[2]))
    ok = np.isfinite(m.reported_lat_deg)
    ref = _enu_px(
        m.reported_lat_deg[ok], m.reported_lon_deg[ok], m.reported_h_m[ok], origin, view.e0, view.n0, view.m_per_px
    )
    # pymap3d and the core's ENU agree to micrometres: 1e-4 px is 1 mm at 11 m per pixel
    np.testing.assert_allclose(view.to_px(m.reported_enu[ok]), ref, atol=1e-4)
    # everything drawn lies inside the image
    assert np.all((ref >= 0) & (ref <= [view.width, view.height]))
    assert view.background.shape == (view.height, view.width, 3) and view.background.std() > 10
    # "map shows: the footprints": a finer map (the orbit is 3-4 times the ground seen) framing
    # every footprint corner, the track running off it
    ground = panel_layer.build_map(m, flight.dem, extent="the footprints")
    assert ground.m_per_px < 0.5 * view.m_per_px
    ok = np.all(np.isfinite(m.corners_enu), axis=2)
    px = ground.to_px(m.corners_enu[ok])
    assert np.all((px >= 0) & (px <= [ground.width, ground.height]))
    tr = ground.to_px(m.track_enu)
    assert np.any((tr < 0) | (tr > [ground.width, ground.height]))
    with pytest.raises(ValueError, match="map extent 'the moon'"):
        panel_layer.map_extent(m, "the moon")


def test_map_hillshade_equals_the_renderers_on_a_plane():
    """A plane tilted up to the east (slope s): the Lambert shading is cos of the angle between
    its normal (-s, 0, 1)/|.| and the sun, by hand; the map's grid shading gives it everywhere."""
    from geoloc_viz import panel_layer

    s, mpp = 0.3, 10.0
    H = np.tile(np.arange(40) * mpp * s, (30, 1))
    az, el = np.radians(panel_layer.SUN_AZ_EL_DEG)
    sun = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    nrm = np.array([-s, 0.0, 1.0]) / np.hypot(s, 1.0)
    np.testing.assert_allclose(panel_layer.hillshade_grid(H, mpp), max(nrm @ sun, 0.0), atol=1e-12)


def test_a_closed_panel_draws_nothing_and_an_open_one_follows_the_timeline(flight):
    server, app, fl, _im, pl = make_app(flight)
    try:
        assert not pl.is_open
        fl.go(5)
        assert pl.view is None and pl.plot_view is None  # nothing built while closed
        pl.open_panel()
        assert 'data-frame="5"' in pl.html_map.content and 'data-frame="5"' in pl.html_plots.content
        fl.go(7)
        assert 'data-frame="7"' in pl.html_map.content and 'data-frame="7"' in pl.html_plots.content
        # the map's caption and the plots' title name the frame as the timeline does (no "packet 7" alone)
        from geoloc_viz.model import frame_name

        assert html.escape(frame_name(app.scn, 7, of=False)) + ": map East-North" in pl.html_map.content
        assert pl.md_plots.content.startswith(f"**{frame_name(app.scn, 7)}**")
        # frame 0 has its picture; 7 has none and says so
        assert "no picture" in pl.html_picture.content
        fl.go(0)
        assert 'id="geoloc-picture-large"' in pl.html_picture.content
        assert f'data-rows="{ROWS}" data-cols="{COLS}"' in pl.html_picture.content
        # its caption names the frame as the timeline does (the picture's own count is not a second numbering)
        from geoloc_viz.model import frame_name

        assert frame_name(app.scn, 0) + ":" in pl.html_picture.content and "image 1 of" not in pl.html_picture.content
        pl.close_panel()
        assert not pl.is_open and pl.bt_open.label.startswith("open")
    finally:
        server.stop()


def test_plots_are_drawn_after_a_failed_first_drawing_within_the_redraw_interval(flight, monkeypatch):
    # a first drawing that failed records its time; a live window that grew within REBUILD_S must
    # still get plots (none exist yet), not fail on the missing ones until the interval is over
    from geoloc_viz import panel_layer

    server, app, fl, _im, pl = make_app(flight)
    try:
        real = panel_layer.build_plots

        def planted(S):
            raise RuntimeError("planted: the plots' first drawing fails")

        monkeypatch.setattr(panel_layer, "build_plots", planted)
        with pytest.raises(RuntimeError, match="planted"):
            pl.open_panel()
        assert pl.plot_view is None
        monkeypatch.setattr(panel_layer, "build_plots", real)
        # the window grew since that attempt (its time is fresh, its number of frames another)
        pl._built["plots"] = (time.monotonic(), len(fl.model) - 1)
        pl.update_plots()
        assert pl.plot_view is not None and 'data-frame="' in pl.html_plots.content
    finally:
        server.stop()


# ------------------------------------------------------------------ headless Chromium


def _magenta_columns(png: bytes) -> np.ndarray:
    import PIL.Image

    a = np.asarray(PIL.Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    mask = (a[..., 0] > 200) & (a[..., 1] < 90) & (a[..., 2] > 200)
    return mask, a


@pytest.mark.browser
def test_large_picture_map_and_plots_in_chromium(flight, tmp_path):
    import pymap3d
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for

    from geoloc_viz.scene_geoloc import WORLD_SCALE

    ARTIFACTS.mkdir(exist_ok=True)
    server, app, fl, im, pl = make_app(flight)
    try:
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1400, 860)
            page.get_by_role("button", name="open the large panel").click(timeout=60000)
            img = page.locator("#geoloc-picture-large")
            img.wait_for(timeout=60000)

            # a pixel of the large picture: at 520 screen px for 240 image px, a pixel is 2 px wide
            r, c = 40.0, 170.0
            box = img.bounding_box(timeout=60000)
            M, N = (float(img.get_attribute(k)) for k in ("data-rows", "data-cols"))
            page.mouse.click(box["x"] + (c - 0.5) / N * box["width"], box["y"] + (r - 0.5) / M * box["height"])
            wait_for(lambda: im.pick is not None, 60, "the click to reach the server")
            assert (im.pick.row, im.pick.col) == (r, c)
            lat, lon = read_pick_latlon(page)
            ref = locate_cli(flight, im.sensor, app.inputs, r, c, tmp_path)
            # the panel prints 8 decimals: 5e-9 of rounding, under the 1e-7 deg asked
            assert lat == pytest.approx(ref["lat_deg"], abs=1e-7)
            assert lon == pytest.approx(ref["lon_deg"], abs=1e-7)
            time.sleep(1.0)
            page.screenshot(path=str(ARTIFACTS / "viz_panel_picture.png"))

            # the map: the scene's current outline (the flight node's own ENU, km) and the pick
            page.get_by_role("tab", name="Map").click()
            mp = page.locator("#geoloc-map")
            mp.wait_for(timeout=60000)
            a = {k: float(mp.get_attribute(f"data-{k}")) for k in ("e0", "n0", "m-per-px", "width", "height")}
            origin = tuple(float(mp.get_attribute(f"data-origin-{k}")) for k in ("lat-deg", "lon-deg", "h-m"))
            seg = np.asarray(server.scene.get_handle_by_name("/flight/current").points, float) / WORLD_SCALE
            o = fl.model.enu.to_geodetic(np.zeros(3))
            la, lo, h = pymap3d.enu2geodetic(
                seg[:, 0, 0], seg[:, 0, 1], seg[:, 0, 2], np.degrees(o[0]), np.degrees(o[1]), float(o[2])
            )
            want = _enu_px(la, lo, h, origin, a["e0"], a["n0"], a["m-per-px"])
            pts = page.locator("#geoloc-map-current").get_attribute("points")
            got = np.array([[float(v) for v in p.split(",")] for p in pts.split()])
            # float32 scene points (km): 1e-4 km = 0.1 m, 0.01 px at 11 m per pixel; the page prints 0.01 px
            np.testing.assert_allclose(got, want, atol=0.02)
            pick = page.locator("#geoloc-map-pick")
            want_pick = _enu_px(ref["lat_deg"], ref["lon_deg"], ref["h_m"], origin, a["e0"], a["n0"], a["m-per-px"])
            got_pick = [float(pick.get_attribute("data-x")), float(pick.get_attribute("data-y"))]
            np.testing.assert_allclose(got_pick, want_pick, atol=0.02)
            # and a person sees them there: magenta at the outline's edge midpoints in the screenshot
            time.sleep(1.0)
            shot = mp.screenshot()
            mask, _rgb = _magenta_columns(shot)
            sx = mask.shape[1] / a["width"]
            mids = 0.5 * (want + np.roll(want, -1, axis=0)) * sx
            hits = [mask[int(y) - 2 : int(y) + 3, int(x) - 2 : int(x) + 3].any() for x, y in mids[::2]]
            assert np.mean(hits) > 0.8, hits
            page.screenshot(path=str(ARTIFACTS / "viz_panel_map.png"))

            # the plots: the cursor at the current frame's time, frame after frame
            page.get_by_role("tab", name="Plots").click()
            pp = page.locator("#geoloc-plots")
            pp.wait_for(timeout=60000)
            xs, ts = [], []
            for idx in (20, 150, 280):
                fl.go(idx)  # what the timeline slider's callback does
                wait_for(lambda: pp.get_attribute("data-frame") == str(idx), 60, f"the plots at frame {idx}")
                time.sleep(0.5)
                mask, _rgb = _magenta_columns(pp.screenshot())
                cols = np.flatnonzero(mask.sum(axis=0) > 0.5 * mask.shape[0] * 0.5)
                assert len(cols), f"no cursor line at frame {idx}"
                W = float(pp.get_attribute("data-width"))
                x = cols.mean() * W / mask.shape[1]  # screen -> image pixels
                t = float(pp.get_attribute("data-t"))
                x_page = float(pp.get_attribute("data-x0-px")) + (t - float(pp.get_attribute("data-t0"))) * float(
                    pp.get_attribute("data-px-per-t")
                )
                assert x == pytest.approx(x_page, abs=2.0)  # a 2 px line, rounded to screen pixels
                xs.append(x)
                ts.append(t)
            # the cursor's column is affine in the frame's time (the axis is linear): 2 px
            k = (xs[2] - xs[0]) / (ts[2] - ts[0])
            assert xs[1] == pytest.approx(xs[0] + k * (ts[1] - ts[0]), abs=2.0)
            assert k > 0
            # a person points at the plots: the readout names the frame under the pointer and its values
            from geoloc_viz.model import frame_name

            j = 150
            tj = ts[1]  # frame 150's time, as the page gave it above
            box = pp.bounding_box(timeout=60000)
            W = float(pp.get_attribute("data-width"))
            # the page's own time-to-pixel transform (a frame is 1.5 image px wide: the cursor's 2 px is too coarse)
            xj = float(pp.get_attribute("data-x0-px")) + (tj - float(pp.get_attribute("data-t0"))) * float(
                pp.get_attribute("data-px-per-t")
            )
            page.mouse.move(box["x"] + xj / W * box["width"], box["y"] + 0.3 * box["height"])
            ro = pp.locator(".geoloc-plots-readout")
            ro.wait_for(state="visible", timeout=30000)
            text = ro.inner_text()
            assert text.splitlines()[0] == frame_name(app.scn, j, of=False), text
            m = re.search(r"error to \w+ \(horizontal\): ([-0-9.]+) m", text)
            # the page holds the series to 0.1 m: the model's residual rounded, within that rounding
            assert m and float(m[1]) == pytest.approx(float(fl.model.residual_m[j]), abs=0.05 + 1e-9), text
            h = re.search(r"aircraft: ([-0-9.]+) m", text)
            assert h and float(h[1]) == pytest.approx(app.scn.records[j][1].h_m, abs=0.05 + 1e-9), text
            page.screenshot(path=str(ARTIFACTS / "viz_panel_plots.png"))
    finally:
        server.stop()


def test_a_flight_view_folds_the_teaching_panel_and_hides_its_row(flight):
    """The teaching row sits on the aircraft: in a flight view it starts hidden (the panel folded);
    'frame the aircraft' shows it. Without a flight (a lesson) it shows from the start."""
    from geoloc_viz import flight_layer, teaching_panel
    from geoloc_viz.app import GeolocApp, make_server

    server = make_server(port=0)
    try:
        app = GeolocApp(server, copy.copy(flight), layers=(flight_layer.attach, teaching_panel.attach))
        tp = app.layers[1]
        root = lambda: server.scene.get_handle_by_name(teaching_panel.ROOT)  # noqa: E731
        assert tp.flight_view and not tp.cb_show.value and not root().visible
        # hidden, the row stays where it was while the timeline moves the aircraft (a step sends no
        # scene message for it); shown, it is on the aircraft (the scene's own node, placed by the app)
        fl, was = app.layers[0], np.array(root().position, float)
        for _ in range(2):
            fl.go(int(fl.sl_frame.value) + 1)
        aircraft = np.array(server.scene.get_handle_by_name("/enu/aircraft").position, float)
        assert np.linalg.norm(aircraft - was) > 1e-3  # the aircraft moved (km): the check below can fail
        np.testing.assert_array_equal(root().position, was)
        tp.frame_aircraft()
        assert tp.cb_show.value and root().visible
        # float32 positions on the wire are not involved: both are the server's float64 values (1e-9 km)
        np.testing.assert_allclose(root().position, aircraft, atol=1e-9)
        lesson = GeolocApp(server, copy.copy(flight), layers=(teaching_panel.attach,)).layers[0]
        assert not lesson.flight_view and lesson.cb_show.value
    finally:
        server.stop()
