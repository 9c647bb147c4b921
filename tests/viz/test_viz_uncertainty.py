"""The predicted 90 % error ellipse in the viewer (geoloc_viz.uncertainty_layer), and in headless Chromium.

The drawn ellipse is held to its definition, measured in the scene: the vertices' horizontal
distances from the hit span the 90 % semi-axes (the 1-sigma axes x sqrt(chi2(2, 0.9)), scipy)
times the display's exaggeration; the panel quotes the propagation's CE90 and the distance to
the surveyed truth the scene draws. It is drawn at true size by default (its semi-axes
are the reported ones), in its own colour (not the flight's magenta), and enlarged only by its own
control, whose factor the label on the drawing gives ("x10"). In Chromium, a person opens the
folder, types 10 into "ellipse drawn x" (the label on the drawing then reads x10 and the drawn
semi-axes are ten times the reported ones) and unticks the checkbox: the ellipse leaves the scene.
The render is kept as docs/img/viewer_uncertainty_ellipse.png.
"""

import math
import re
import time

import numpy as np
import pytest
from scipy.stats import chi2

from test_viz_browser import ARTIFACTS, chromium, look_at_wxyz, n_colours, open_viewer, served, wait_for

pytestmark = [pytest.mark.browser]


def _layer(app):
    return next(lay for lay in app.layers if type(lay).__name__ == "UncertaintyLayer")


def drawn_semi_axes(server, app):
    """The drawn ellipse's (major, minor) semi-axes [m], measured on its scene node about the hit."""
    from geoloc_viz.scene_geoloc import WORLD_SCALE

    d = app.view.disp
    seg = np.asarray(server.scene.get_handle_by_name("/enu/uncertainty/ellipse").points, float)
    pts = seg[:, 0, :] / (WORLD_SCALE * np.array([1.0, 1.0, d.vertical_exaggeration]))  # back to ENU metres
    hit = np.asarray(app.geometry.hit_enu, float)
    r = np.hypot(pts[:, 0] - hit[0], pts[:, 1] - hit[1])
    return r.max(), r.min()


def reported_semi_axes(text):
    """The panel's "90 % ellipse A x B m", as a person reads it."""
    m = re.search(r"90 % ellipse (\d+\.\d) x (\d+\.\d) m", text)
    return float(m.group(1)), float(m.group(2))


def test_the_ellipse_in_the_scene_is_the_predicted_90_percent_ellipse():
    from geoloc_viz import flight_layer, uncertainty_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        lay = _layer(app)
        pu = lay.pu
        r90 = math.sqrt(chi2.ppf(0.9, 2))
        assert lay.scale == 1.0 and app.view.disp.error_exaggeration == 1.0  # both true size by default
        app.sl_err.value = 10.0  # the error vector's factor: the ellipse keeps its own
        for k in (1.0, 10.0):
            lay.sl_scale.value = k
            lay.update()
            a, b = drawn_semi_axes(server, app)
            # 96 vertices: the extremes are sampled within cos(pi / 96) of the axes (5e-4); float32 in km
            assert a == pytest.approx(r90 * float(pu.ellipse_major_m) * k, rel=1e-3)
            assert b == pytest.approx(r90 * float(pu.ellipse_minor_m) * k, rel=1e-3)
            # the panel's semi-axes (0.1 m) times the label's factor are the drawn ones
            A, B = reported_semi_axes(lay.md.content)
            assert a == pytest.approx(k * A, abs=k * 0.05 + 1e-3 * a) and b == pytest.approx(
                k * B, abs=k * 0.05 + 1e-3 * b
            )
            label = server.scene.get_handle_by_name("/enu/uncertainty/label")
            assert label.visible and (("x10 " in label.text) if k == 10.0 else ("true size" in label.text))
            assert f"CE90 {float(pu.ce90_m):.1f} m" in label.text
        # one colour per meaning: not the flight layer's magenta current footprint
        assert tuple(uncertainty_layer.COLOR) != tuple(flight_layer.COLORS["current"])
        assert tuple(uncertainty_layer.COLOR) not in {tuple(c) for c in flight_layer.COLORS.values()}
        text = lay.md.content
        assert f"CE90 {float(pu.ce90_m):.1f} m" in text
        err = float(np.hypot(*(app.geometry.hit_enu - app.geometry.surveyed_enu)[:2]))
        assert f"{err:.1f} m" in text and "illustrative budget" in text


def test_a_person_hides_the_ellipse_in_chromium(tmp_path):
    import PIL.Image

    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 800, 520)
            page.wait_for_selector("canvas", timeout=90000)
            client = next(iter(server.get_clients().values()))
            hit = np.array(server.scene.get_handle_by_name("/enu/hit/result").position)
            # km: 0.35 km off, looking down at the hit (the true-size ellipse is tens of metres across)
            pos = hit + np.array([0.07, -0.2, 0.28])
            img = None
            for _ in range(40):
                img = client.get_render(
                    640,
                    960,
                    position=tuple(pos),
                    wxyz=look_at_wxyz(pos, hit),
                    fov=0.9,
                    transport_format="png",
                    timeout=60,
                )
                if n_colours(img) > 20:
                    break
            PIL.Image.fromarray(img[..., :3]).save(ARTIFACTS / "viewer_uncertainty_ellipse.png")
            # at true size (45 x 35 m semi-axes for T3-1) the ellipse lies under the flight layer's
            # markers at the hit (10 % of the 487 m error: 49 m radius): the label on it says what it is
            # (viser draws labels on the canvas, not as page text: the label node the browser draws)
            lab = server.scene.get_handle_by_name("/enu/uncertainty/label")
            assert lab.visible and lab.text.startswith("90 % ellipse, true size (CE90")
            page.get_by_text("Predicted uncertainty").click()
            # a person enlarges it: types 10 into the slider's number box
            num = page.locator(
                "xpath=//label[normalize-space()='ellipse drawn x']/ancestor::div"
                "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
            )
            num.fill("10", timeout=60000)
            num.press("Enter")
            wait_for(lambda: _layer(app).scale == 10.0, 30, "the factor to reach the server")
            wait_for(
                lambda: server.scene.get_handle_by_name("/enu/uncertainty/label").text.startswith(
                    "90 % ellipse, x10 (CE90"
                ),
                60,
                "the label x10 on the drawing",
            )
            a, b = drawn_semi_axes(server, app)
            A, B = reported_semi_axes(page.get_by_text(re.compile(r"90 % ellipse \d")).first.inner_text())
            # the page's semi-axes (0.1 m) times the label's factor are the drawn ones
            assert a == pytest.approx(10 * A, abs=0.5 + 1e-3 * a) and b == pytest.approx(10 * B, abs=0.5 + 1e-3 * b)
            pos = hit + np.array([0.6, -2.0, 2.4])  # km: 3 km off, looking down at the hit
            for _ in range(40):
                img = client.get_render(
                    640,
                    960,
                    position=tuple(pos),
                    wxyz=look_at_wxyz(pos, hit),
                    fov=0.9,
                    transport_format="png",
                    timeout=60,
                )
                if n_colours(img) > 20:
                    break
            PIL.Image.fromarray(img[..., :3]).save(ARTIFACTS / "viewer_uncertainty_ellipse_x10.png")
            rgb = img[..., :3].astype(int)
            # COLOR (0, 200, 170) as the unlit line renders here: about (85, 205, 185); nothing else in
            # the scene is within these bounds (the line of sight's light blue is (140, 220, 220))
            teal = (abs(rgb[..., 0] - 85) < 25) & (abs(rgb[..., 1] - 205) < 20) & (abs(rgb[..., 2] - 185) < 20)
            assert teal.sum() > 200, teal.sum()  # the ellipse's line (teal, x10) is in the picture
            page.screenshot(path=str(ARTIFACTS / "viewer_uncertainty_ellipse_x10_page.png"))
            box = page.get_by_label("90 % error ellipse at the hit")
            box.click()
            wait_for(lambda: not _layer(app).cb_show.value, 30, "the checkbox to reach the server")
            # (hidden, not removed: a step updates the node in place)
            wait_for(
                lambda: _layer(app).handle is None or not _layer(app).handle.visible,
                30,
                "the ellipse to leave the scene",
            )
            assert re.search(r"CE90 \d+\.\d m", _layer(app).md.content)


def test_flight_debugger_flags_frames_outside_their_own_99_percent_ellipse():
    """The bundled flight's planted faults (a 2.5 deg heading burst, MSL in the ellipsoid tag, a
    stale pose) put their frames tens of metres off the reported centres; with a budget of metres and hundredths of
    a degree those frames are outside their own 99 % ellipse, the frames that agree to millimetres
    are not."""
    from geoloc.sensors.budget import ErrorBudget
    from geoloc_viz import flight_model

    scn = flight_model.default_flight_scenario()
    names = scn.camera.angle_names  # the Scenario holds a FrameSensor
    b = {"north_m": 2.0, "east_m": 2.0, "up_m": 3.0, "heading_deg": 0.05, "pitch_deg": 0.03, "roll_deg": 0.03}
    b.update({f"{a}_deg": 0.03 for a in names})
    scn.budget = ErrorBudget(b, "srtm")
    m = flight_model.build(scn, diagnose_faults=False)
    out = m.outside_ellipse99
    assert out is not None and out.shape == m.residual_m.shape
    big = np.isfinite(m.residual_m) & (m.residual_m > 50.0)
    small = np.isfinite(m.residual_m) & (m.residual_m < 1.0)
    assert big.sum() >= 5 and small.sum() > 200
    assert np.all(out[big]) and not np.any(out[small])
    assert "outside their own predicted 99 % ellipse" in m.summary_markdown()
    assert "outside 99 %" in m.outlier_markdown()


def _pink_along(img, p0, p1, half_width_px=6.0):
    """Pixels of the error vector's pink (255, 90, 200) within ``half_width_px`` of the line p0 -> p1
    (image x, y): their positions along it [px from p0], sorted."""
    rgb = img[..., :3].astype(int)
    # (a thin line blends with what is behind it at its edges: pink is red and blue well above green)
    pink = (rgb[..., 0] > 180) & (rgb[..., 2] > 140) & (rgb[..., 1] < np.minimum(rgb[..., 0], rgb[..., 2]) - 25)
    ys, xs = np.nonzero(pink)
    q = np.stack([xs, ys], axis=1) + 0.5 - p0
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    t = q @ u
    across = np.abs(q @ np.array([-u[1], u[0]]))
    return np.sort(t[across < half_width_px])


def test_the_error_vector_is_drawn_at_true_length_in_chromium(tmp_path):
    """Read from the page: the pink vector's pixels, on a render looking down at the hit, span the
    hit to the surveyed point (their pixels by the pinhole model of the render's camera), no
    further; a person types 10 into "error vector drawn x" and the pink runs ten times as far."""
    import PIL.Image
    import viser.transforms as vtf

    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    H = W = 640
    fov = 0.9  # rad, vertical (viser's get_render)
    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 900, 600)
            page.wait_for_selector("canvas", timeout=90000)
            client = next(iter(server.get_clients().values()))
            # the flight layer draws the current frame's error in the same pink: hide it, to measure this node
            server.scene.get_handle_by_name("/flight").visible = False
            app.cb_terrain.value = False  # the vector lies on the terrain (both its ends do): measure it alone
            server.scene.get_handle_by_name("/enu/origin").visible = False  # its axes cross the surveyed end
            g, d = app.geometry, app.view.disp
            a, b = d.z(g.hit_enu), d.z(g.surveyed_enu)  # km, the scene's units
            pos = a + np.array([0.0, -0.05, 1.5])  # 1.5 km above the hit, a little south (up stays defined)
            q = look_at_wxyz(pos, a)
            R = vtf.SO3(np.asarray(q)).as_matrix()  # camera -> scene (OpenCV axes: x right, y down, z forward)
            f_px = 0.5 * H / np.tan(0.5 * fov)

            def px(p):
                c = R.T @ (np.asarray(p, float) - pos)
                return np.array([W / 2 + f_px * c[0] / c[2], H / 2 + f_px * c[1] / c[2]])

            p0, p1 = px(a), px(b)
            L = float(np.linalg.norm(p1 - p0))
            img = None
            for _ in range(40):
                img = client.get_render(H, W, position=tuple(pos), wxyz=q, fov=fov, transport_format="png", timeout=60)
                # drawn, and the terrain's hiding applied (the background then fills most of the picture)
                if n_colours(img[..., :3]) > 20 and (img[..., :3].max(axis=-1) < 30).mean() > 0.5:
                    break
                time.sleep(0.5)
            PIL.Image.fromarray(img[..., :3]).save(ARTIFACTS / "viewer_error_vector_true_length.png")
            t = _pink_along(img, p0, p1)
            assert len(t) > 50, len(t)
            # the markers (spheres, seen from above) hide the vector's ends: radius r at the hit, 0.6 r at
            # the surveyed point, r the session's marker radius (display only, metres -> pixels here)
            m_per_px = 1e3 * float(np.linalg.norm(pos - a)) / f_px
            hidden_px = 1.6 * d.marker_radius_m / m_per_px
            # 3 px: the line's width and antialiasing at its end caps
            assert t[0] > -3.0 and t[-1] < L + 3.0, (t[0], t[-1], L)
            assert t[-1] - t[0] > L - hidden_px - 6.0, (t[0], t[-1], L, hidden_px)
            # a person draws it ten times longer: the Display folder, "error vector drawn x" = 10
            page.get_by_text("Display", exact=True).click()
            num = page.locator(
                "xpath=//label[normalize-space()='error vector drawn x']/ancestor::div"
                "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
            )
            num.fill("10", timeout=60000)
            num.press("Enter")
            wait_for(lambda: app.view.disp.error_exaggeration == 10.0, 30, "the factor to reach the server")
            wait_for(
                lambda: "drawn x10" in server.scene.get_handle_by_name("/enu/record/error/label").text,
                60,
                "the label x10 on the drawing",
            )
            for _ in range(40):
                img = client.get_render(H, W, position=tuple(pos), wxyz=q, fov=fov, transport_format="png", timeout=60)
                t = _pink_along(img, p0, p1)
                if len(t) and t[-1] > 2.0 * L:
                    break
            PIL.Image.fromarray(img[..., :3]).save(ARTIFACTS / "viewer_error_vector_x10.png")
            # ten times L runs off the 640 px picture: the pink reaches past twice the true length, or to
            # where the line leaves the picture (5 px: the line's end cap and antialiasing)
            u = (p1 - p0) / L
            t_exit = min(((W if u[0] > 0 else 0.0) - p0[0]) / u[0], ((H if u[1] > 0 else 0.0) - p0[1]) / u[1])
            assert t[-1] > min(2.0 * L, t_exit - 5.0), (t[-1], L, t_exit)
