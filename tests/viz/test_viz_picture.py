"""The picture layer: each frame's image in its frustum and in a panel,
pixel picks located as ``geoloc locate`` locates them, terrain picks marked at their pixel.

The images here (:class:`geoloc.io.images.ArrayImages`) are frames of the bundled example
flight rendered in the test by casting every pixel's ray through the core onto the SRTM crop
(height colours and a 200 m checker), small (135 x 240 px) so the test stays quick on 2 cores.

* no browser: the layer's pixel pick equals ``geoloc locate`` (a subprocess of the CLI, with the
  frame's own sensor written to a sensor file) to 1e-9 deg; a browser-like ray at a pixel's
  ground point marks that pixel; a ridge hides a point (``hidden behind terrain``), a point far
  from the footprint is "outside the frame"; the frustum image's plane maps a ray to its pixel;
* headless Chromium (``-m browser``): click pixel (r, c) in the zoomed panel as a person does
  and read the panel's latitude and longitude: ``geoloc locate``'s for (r, c) to 1e-7 deg; click
  the terrain at a pixel's ground point on the canvas: the pixel marked is that pixel to 0.5 px.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time

import numpy as np
import pytest
from test_viz_browser import served

from geoloc.io.images import ArrayImages
from geoloc.status import Status

ROWS, COLS = 135, 240


def render_frame(scn, idx, rows=ROWS, cols=COLS):
    """Frame ``idx`` seen through its own sensor: each pixel's exact DEM hit, coloured (test only)."""
    import matplotlib

    from geoloc.surfaces.terrain import DemSurface
    from geoloc_viz import picture_model as pm

    sensor = pm.frame_sensor(scn, idx, rows, cols)
    R, C = np.mgrid[1 : rows + 1, 1 : cols + 1].astype(float)
    hit = DemSurface(scn.dem, "exact").intersect(sensor.line_of_sight(R, C, scn.records[idx][1].pose()))
    h = np.nan_to_num(np.asarray(hit.h, float), nan=0.0)
    t = (h - np.nanmin(h)) / max(np.ptp(h), 1.0)
    rgb = matplotlib.colormaps["gist_earth"](0.25 + 0.6 * t)[..., :3]
    # a 200 m checker on the ground (lat, lon): texture to see the ground move
    check = (np.floor(np.degrees(hit.lat) * 111e3 / 200) + np.floor(np.degrees(hit.lon) * 89e3 / 200)) % 2
    rgb = rgb * np.where(check[..., None] > 0, 1.0, 0.8)
    rgb[np.asarray(hit.status) != Status.OK] = (0.45, 0.6, 0.85)
    return (rgb * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def flight():
    """The bundled example flight with images for its first three records."""
    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    n = 3
    scn.images = ArrayImages([render_frame(scn, i) for i in range(n)])
    scn.image_index = np.r_[np.arange(n), np.full(len(scn.records) - n, -1)]
    return scn


def locate_cli(scn, sensor, inputs, row, col, tmp_path):
    """``geoloc locate`` for (row, col): the frame's sensor written to a file, the record's pose."""
    from geoloc.sensors.sensor_file import sensor_to_toml

    path = tmp_path / "frame_sensor.toml"
    sensor_to_toml(sensor, path)
    args = [
        sys.executable,
        "-m",
        "geoloc",
        "locate",
        "--sensor",
        str(path),
        "--lat-deg",
        repr(inputs.lat_deg),
        "--lon-deg",
        repr(inputs.lon_deg),
        "--h-m",
        repr(inputs.h_m),
        "--heading-deg",
        repr(inputs.heading_deg),
        "--pitch-deg",
        repr(inputs.pitch_deg),
        "--roll-deg",
        repr(inputs.roll_deg),
        "--row",
        repr(float(row)),
        "--col",
        repr(float(col)),
        "--dem",
        scn._dem_path,
        "--method",
        inputs.method,
        "--threshold",
        repr(inputs.threshold),
        "--eps-h",
        repr(inputs.eps_h),
        "--json",
    ]
    for k, v in inputs.angles_deg.items():
        args += ["--angle", f"{k}={v!r}"]
    out = subprocess.run(args, capture_output=True, text=True, check=False, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def make_app(scn, **kw):
    from geoloc_viz import image_layer
    from geoloc_viz.app import GeolocApp, make_server

    import copy

    server = make_server(port=0)
    # a copy: an app moves its scenario to the records it loads, and the module's scenario is shared
    app = GeolocApp(server, copy.copy(scn), layers=(image_layer.attach,), **kw)
    return server, app, app.layers[0]


def test_scenario_without_images_gets_no_layer():
    from geoloc_viz import image_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario(), layers=(image_layer.attach,))
        assert app.layers == [None]
        assert server.scene.get_handle_by_name("/enu/picture/frame") is None


def test_pixel_pick_equals_geoloc_locate(flight, tmp_path):
    server, app, layer = make_app(flight)
    try:
        assert layer.image.shape == (ROWS, COLS, 3) and layer.sensor.rows == ROWS
        r, c = 40.0, 171.0
        p = layer.pick_pixel(r, c)
        ref = locate_cli(flight, layer.sensor, app.inputs, r, c, tmp_path)
        # the same sensor, pose, DEM and method through the CLI: equal to round-off of the
        # printed float (repr: 17 digits) and of the TOML lens (repr too): 1e-9 deg ~ 0.1 mm
        assert p.ok and ref["status"] == "ok"
        assert p.lat_deg() == pytest.approx(ref["lat_deg"], abs=1e-9)
        assert p.lon_deg() == pytest.approx(ref["lon_deg"], abs=1e-9)
        assert float(p.hit.h) == pytest.approx(ref["h_m"], abs=1e-4)
        text = layer.md_pick.content
        assert f"{ref['lat_deg']:.7f}" in text and "ellipsoidal, WGS 84" in text and "DEM evaluations" in text
        assert f"MGRS {ref['mgrs']} (USNG {ref['usng']})" in text  # beside lat/lon, as locate --json
        # the scene: the ray from the optical centre to the hit, and a marker at the hit
        hit = np.array(server.scene.get_handle_by_name("/enu/picture/hit").position)
        want = app.view.disp.z(app.scn.enu.from_ecef(p.hit.ecef))
        np.testing.assert_allclose(hit, want, atol=1e-6)  # km: the node is placed there
        assert layer.tx_pixel.value == "40, 171"
    finally:
        server.stop()


def test_terrain_pick_marks_the_pixel_of_the_ground_point(flight, tmp_path):
    server, app, layer = make_app(flight)
    try:
        r, c = 90.0, 60.0
        ref = locate_cli(flight, layer.sensor, app.inputs, r, c, tmp_path)
        from geoloc.geodesy.ellipsoid import geodetic_to_ecef

        G = geodetic_to_ecef(np.radians(ref["lat_deg"]), np.radians(ref["lon_deg"]), ref["h_m"])
        d = app.view.disp
        g_scene = d.z(app.scn.enu.from_ecef(G))
        # a browser's click ray: from a viewpoint 2 km up and 1 km aside, through the ground point
        eye = g_scene + np.array([1.0, -0.5, 2.0])
        gp = layer.pick_ground(eye, g_scene - eye)
        assert gp.ok and gp.in_frame and gp.visible
        # the locate CLI's point back to its pixel: round trip to the solver's tolerance
        # (bisect, 1 m threshold, over ~5 km slant range at 240 px across 7 deg: < 0.05 px)
        assert gp.row == pytest.approx(r, abs=0.5) and gp.col == pytest.approx(c, abs=0.5)
        assert "in the frame" in layer.md_ground.content
        import mgrs  # the pick's MGRS beside its lat/lon, as NGA's GEOTRANS (the mgrs package) gives it

        ref_mgrs = mgrs.MGRS().toMGRS(float(np.degrees(gp.hit.lat)), float(np.degrees(gp.hit.lon)), MGRSPrecision=5)
        assert f"MGRS {ref_mgrs} (USNG " in layer.md_ground.content
        assert server.scene.get_handle_by_name("/enu/picture/ground").visible
        # far from the footprint: outside the frame
        far = g_scene + np.array([15.0, 15.0, 0.0])
        gp2 = layer.pick_ground(far + np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -1.0]))
        assert gp2.ok and not gp2.in_frame and "outside the frame" in layer.md_ground.content
    finally:
        server.stop()


def test_frustum_image_plane_maps_rays_to_their_pixels(flight):
    server, app, layer = make_app(flight)
    try:
        pos, R, w, h = layer.plane
        # a ray through the image plane at fractions (u, v) of its width and height: pixel
        # (0.5 + v M, 0.5 + u N) rounded to its centre; from a point off the axis
        for u, v in ((0.113, 0.207), (0.502, 0.497), (0.93, 0.771)):
            x = pos + R @ np.array([(u - 0.5) * w, (v - 0.5) * h, 0.0])
            eye = x + R @ np.array([0.3, -0.2, -1.0])
            rc = layer.pixel_on_frame(eye, x - eye)
            assert rc == (np.floor(0.5 + v * ROWS + 0.5), np.floor(0.5 + u * COLS + 0.5))
        assert layer.pixel_on_frame(pos + R @ np.array([2 * w, 0, -1.0]), R[:, 2]) is None
        # the plane is in the camera's optical frame at the chosen fraction of the range
        assert server.scene.get_handle_by_name("/enu/picture/frame").visible
    finally:
        server.stop()


def test_a_ridge_hides_a_point_and_the_verdict_says_so():
    # a flat plain at 100 m with a 600 m ridge 4 km north of the camera; the camera, 400 m above
    # the plain, looks north 3 deg down: a point 1.5 km behind the ridge is in the frame, hidden
    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.dem import DEM
    from geoloc_viz import picture_model as pm
    from geoloc_viz.model import Inputs, RecordInfo, Scenario
    from geoloc.workflows.klv_replay import klv_sensor

    lat0, lon0 = 36.5, -84.2
    n = 401
    step = 0.0005  # deg, ~55 m
    H = np.full((n, n), 100.0)
    lats = lat0 + 0.1 - step * np.arange(n)
    ridge = np.abs(lats - (lat0 + 0.036)) < 0.002  # ~4 km north, ~440 m wide
    H[ridge, :] = 600.0
    dem = DEM.from_array(H, lat0 + 0.1, lon0 - 0.1, step, step, datum="ellipsoid")
    sensor = klv_sensor(np.radians(20.0), np.radians(11.25))
    inp = Inputs(
        lat0,
        lon0,
        500.0,
        0.0,
        0.0,
        0.0,
        row=540.5,
        col=960.5,
        method="exact",
        target_h=100.0,
        angles_deg={"azimuth": 0.0, "elevation": -3.0, "sensor_roll": 0.0},
    )
    scn = Scenario("ridge", sensor, inp, EnuFrame.from_deg(lat0, lon0, 100.0), [(RecordInfo("r"), inp)], 0, dem=dem)
    # a browser ray from straight above a point 1.5 km behind the ridge, falling onto it
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    top = geodetic_to_ecef(np.radians(lat0 + 0.036 + 0.0135), np.radians(lon0), 5000.0)
    down = geodetic_to_ecef(np.radians(lat0 + 0.036 + 0.0135), np.radians(lon0), 0.0) - top
    gp = pm.ground_pick(scn, inp, sensor, top, down)
    assert gp.ok and float(gp.hit.h) == pytest.approx(100.0, abs=1e-6)
    assert gp.in_frame, (gp.row, gp.col, gp.pixel_status)
    assert not gp.visible and gp.verdict() == "hidden behind terrain from this camera"
    # the camera's ray meets the ridge ~4 km out, before the point ~5.5 km out
    assert 3.5e3 < gp.occluder_range_m < 4.5e3 < gp.range_m
    # in front of the ridge (3.3 km out, 6.9 deg down, inside the 5.6 deg half field): visible
    top2 = geodetic_to_ecef(np.radians(lat0 + 0.030), np.radians(lon0), 5000.0)
    down2 = geodetic_to_ecef(np.radians(lat0 + 0.030), np.radians(lon0), 0.0) - top2
    gp2 = pm.ground_pick(scn, inp, sensor, top2, down2)
    assert gp2.ok and gp2.in_frame and gp2.visible


def test_marks_reproject_the_reported_centre_and_the_horizon_bounds_the_terrain(flight):
    from geoloc_viz import picture_model as pm

    server, app, layer = make_app(flight)
    try:
        m = layer.marks
        r0, c0 = layer.sensor.center_pixel
        # the recomputed centre is the image centre's own hit: back at the centre pixel
        assert m["recomputed"][0] == pytest.approx(r0, abs=0.05) and m["recomputed"][1] == pytest.approx(c0, abs=0.05)
        # packet 0 has no fault: the reported frame centre (KLV tags 23-25) reprojects near the centre
        assert "reported" in m and abs(m["reported"][0] - r0) < 3 and abs(m["reported"][1] - c0) < 3
        # the flight looks down 36 deg: no horizon in the frame; looking level it appears
        assert len(layer.horizon) == 0
        level = app.inputs.replace(angles_deg={**app.inputs.angles_deg, "elevation": -1.0})
        hz = pm.terrain_horizon(app.scn, level, layer.sensor)
        assert len(hz) > 5
        # independent check of each horizon point: a pixel 2 rows above misses the terrain,
        # 2 rows below meets it (rays cast again through the exact solver)
        from geoloc.surfaces.terrain import DemSurface

        pose = level.pose()
        surf = DemSurface(app.scn.dem, "exact")
        above = surf.intersect(layer.sensor.line_of_sight(hz[:, 0] - 2, hz[:, 1], pose, outside="extrapolate"))
        below = surf.intersect(layer.sensor.line_of_sight(hz[:, 0] + 2, hz[:, 1], pose, outside="extrapolate"))
        assert np.all(np.asarray(above.status) != Status.OK) and np.all(np.asarray(below.status) == Status.OK)
    finally:
        server.stop()


def test_the_horizon_is_where_the_rays_reach_a_flat_dems_far_edge(flight):
    """terrain_horizon against an oracle outside the DEM walk: over a flat DEM (h0 on the
    ellipsoid, every node) whose far edge is in view, a ray meets the terrain iff it meets the
    ellipsoid raised by h0 (closed-form quadratic) at a latitude and longitude inside the DEM
    (pymap3d's ecef2geodetic). Each horizon point's ray half a pixel above lands outside, half a
    pixel below inside (the bisection's 13 halvings of the frame: 0.02 px at 135 rows)."""
    import copy

    import pymap3d

    from geoloc.surfaces.dem import DEM
    from geoloc_viz import picture_model as pm

    server, app, layer = make_app(flight)
    try:
        level = app.inputs.replace(angles_deg={**app.inputs.angles_deg, "elevation": -2.0})
        pose = level.pose()
        lat0, lon0 = np.degrees(pose.lat), np.degrees(pose.lon)
        h0 = 300.0
        # the frame's rays, 2 deg down on the turret, leave the aircraft 5-12 deg down to the NNE
        # from 2.9 km: they meet a 300 m ground 12-29 km away. The DEM's north edge 20 km ahead
        # (0.18 deg) crosses the frame; 0.6 deg (67 km) the other ways, out of view
        d = 0.005
        north, south, west, east = lat0 + 0.18, lat0 - 0.6, lon0 - 0.6, lon0 + 0.6
        dem = DEM.from_array(
            np.full((round((north - south) / d) + 1, round((east - west) / d) + 1), h0), north, west, d, d
        )
        south, east = north - d * (dem.shape[0] - 1), west + d * (dem.shape[1] - 1)
        scn = copy.copy(app.scn)
        scn.dem = dem
        hz = pm.terrain_horizon(scn, level, layer.sensor)
        assert len(hz) >= 20  # most of the 32 columns

        a, b = 6378137.0 + h0, 6356752.314245179 + h0  # WGS 84 raised by h0 (a shell at h0 along
        # the normal differs from this by < 1 mm at 300 m: e^2 h0 terms)

        def inside(r, c):
            los = layer.sensor.line_of_sight(r, c, pose, outside="extrapolate")
            o = np.broadcast_to(los.origin_ecef, los.direction_ecef.shape).reshape(-1, 3)
            u = los.direction_ecef.reshape(-1, 3)
            u = u / np.linalg.norm(u, axis=1, keepdims=True)
            w = np.array([1 / a**2, 1 / a**2, 1 / b**2])
            A, B, C = np.sum(u * u * w, 1), 2 * np.sum(o * u * w, 1), np.sum(o * o * w, 1) - 1
            disc = B * B - 4 * A * C
            t = (-B - np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * A)
            p = o + t[:, None] * u
            la, lo, _ = pymap3d.ecef2geodetic(p[:, 0], p[:, 1], p[:, 2])
            return (disc >= 0) & (t > 0) & (la <= north) & (la >= south) & (lo >= west) & (lo <= east)

        assert not inside(hz[:, 0] - 0.5, hz[:, 1]).any()
        assert inside(hz[:, 0] + 0.5, hz[:, 1]).all()
    finally:
        server.stop()


def test_the_timeline_shows_each_frames_own_image(flight):
    server, app, layer = make_app(flight)
    try:
        assert layer.k == 0
        np.testing.assert_array_equal(layer.image, flight.images.image(0))
        app.load_record(2, move_camera=False)
        assert layer.k == 2
        np.testing.assert_array_equal(layer.image, flight.images.image(2))
        app.load_record(5, move_camera=False)
        assert layer.k == -1 and "no image" in layer.html.content
    finally:
        server.stop()


# ------------------------------------------------------------------ headless Chromium


def _panel_pixel_xy(page, r, c):
    """Screen position of pixel (r, c)'s centre in the panel's image (its crop read from the page)."""
    img = page.locator("#geoloc-picture")
    box = img.bounding_box(timeout=120000)  # 2 shared cores under load: a panel redraw can take long
    r1, c1, h, w = (float(img.get_attribute(k)) for k in ("data-r1", "data-c1", "data-h", "data-w"))
    return (box["x"] + (c - (c1 - 0.5)) / w * box["width"], box["y"] + (r - (r1 - 0.5)) / h * box["height"])


def click_picture_and_read_latlon(page, layer, r, c):
    """A person's click on pixel (r, c) of the panel's picture, zoomed 4x first (an image pixel then
    spans several screen pixels, so the click lands inside it): checks the server got that pixel,
    then returns the latitude and longitude [deg] the page prints for it."""
    from test_viz_browser import wait_for

    img = page.locator("#geoloc-picture")
    layer.sl_zoom.value = 2
    wait_for(lambda: img.get_attribute("data-w") == "160", 60, "the 4x crop")
    img.scroll_into_view_if_needed(timeout=60000)  # the GUI panel scrolls; a click must land on the picture
    page.mouse.click(*_panel_pixel_xy(page, r, c))
    wait_for(lambda: layer.pick is not None, 60, "the click to reach the server")
    assert (layer.pick.row, layer.pick.col) == (r, c)
    return read_pick_latlon(page)


def read_pick_latlon(page, timeout=60):
    """The latitude and longitude [deg] the page prints for the pick, once both numbers are shown.

    The page text is read whole and searched for "latitude <number>": other text names
    latitude without a number after it (the share folder's "latitude, longitude, height"
    heading), and it may be drawn before the pick's own line, so the first element that
    says "latitude" is not a reliable place to read."""
    from test_viz_browser import wait_for

    found = {}

    def shown():
        text = page.evaluate("() => document.body.innerText")
        la, lo = re.search(r"latitude\s*([-0-9.]+)", text), re.search(r"longitude\s*([-0-9.]+)", text)
        if la and lo:
            found["v"] = (float(la[1]), float(lo[1]))
        return bool(found)

    wait_for(shown, timeout, "the pick's latitude and longitude in the page")
    return found["v"]


@pytest.mark.browser
def test_click_a_pixel_in_the_panel_and_the_terrain_in_chromium(flight, tmp_path):
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for

    ARTIFACTS.mkdir(exist_ok=True)
    server, app, layer = make_app(flight)
    try:
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1280, 860)
            page.wait_for_selector("#geoloc-picture", timeout=60000)
            # zoom 4x: an image pixel is ~9 screen px wide, so a click lands inside it
            layer.sl_zoom.value = 2
            wait_for(
                lambda: page.locator("#geoloc-picture").get_attribute("data-w") == str(COLS // 4),
                60,
                "the panel to show the 4x crop",
            )
            r, c = 70.0, 118.0
            x, y = _panel_pixel_xy(page, r, c)
            page.mouse.click(x, y)
            wait_for(lambda: layer.pick is not None, 60, "the click to reach the server")
            assert (layer.pick.row, layer.pick.col) == (r, c)
            lat, lon = read_pick_latlon(page)
            ref = locate_cli(flight, layer.sensor, app.inputs, r, c, tmp_path)
            # the panel prints 8 decimals: 5e-9 of rounding, under the 1e-7 deg asked
            assert lat == pytest.approx(ref["lat_deg"], abs=1e-7)
            assert lon == pytest.approx(ref["lon_deg"], abs=1e-7)
            time.sleep(1.0)
            page.screenshot(path=str(ARTIFACTS / "viz_picture_pixel_pick.png"))

            # the terrain: aim the browser's camera at the ground point of pixel (r2, c2), close
            # (600 m) so a screen pixel spans well under an image pixel's ground sample, and
            # click the canvas where that point is drawn
            r2, c2 = 30.0, 200.0
            ref2 = locate_cli(flight, layer.sensor, app.inputs, r2, c2, tmp_path)
            from geoloc.geodesy.ellipsoid import geodetic_to_ecef

            G = app.view.disp.z(
                app.scn.enu.from_ecef(
                    geodetic_to_ecef(np.radians(ref2["lat_deg"]), np.radians(ref2["lon_deg"]), ref2["h_m"])
                )
            )
            client = next(iter(server.get_clients().values()))
            eye = G + np.array([0.25, -0.35, 0.45])
            app.move_camera((eye, G))
            wait_for(
                lambda: (
                    np.linalg.norm(np.array(client.camera.position) - eye) < 1e-3
                    and np.linalg.norm(np.array(client.camera.look_at) - G) < 1e-3
                ),
                30,
                "the browser's camera at the ground point",
            )
            time.sleep(1.5)
            canvas = page.locator("canvas").first.bounding_box()
            # looking at G: G is drawn at the canvas's centre
            page.mouse.click(canvas["x"] + canvas["width"] / 2, canvas["y"] + canvas["height"] / 2)
            wait_for(lambda: layer.ground is not None, 60, "the terrain click to reach the server")
            gp = layer.ground
            assert gp.ok and gp.in_frame
            # the marked pixel is the pixel whose ground point we clicked, to half a pixel
            assert gp.row == pytest.approx(r2, abs=0.5) and gp.col == pytest.approx(c2, abs=0.5)
            page.wait_for_selector("text=terrain pick", timeout=60000)
            time.sleep(1.0)
            page.screenshot(path=str(ARTIFACTS / "viz_picture_terrain_pick.png"))
    finally:
        server.stop()
