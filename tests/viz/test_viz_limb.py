"""The limb scene and the ``geoloc view`` command line, in process (no browser)."""

import numpy as np
import pyproj
import pytest

from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.geodesy.ellipsoid import A, F
from geoloc_viz.app import make_server
from geoloc_viz.scene_geoloc import WORLD_SCALE
from geoloc_viz.scene_limb import LimbApp, load_limb


@pytest.fixture(scope="module")
def limb():
    server = make_server(port=0)
    app = LimbApp(server, load_limb())
    yield app
    server.stop()


def ecef_of(app, name):
    """A node's position back in ECEF metres (scene: ENU in km)."""
    p = np.asarray(app.server.scene.get_handle_by_name(name).position, float) / WORLD_SCALE
    return app.enu.to_ecef(p)


def test_limb_nodes_where_the_geometry_says(limb):
    names = set(limb.server.scene._handle_from_node_name)
    for n in (
        "earth",
        "virtual",
        "spacecraft",
        "velocity",
        "los",
        "tangent",
        "tangent/label",
        "exact",
        "exact/label",
        "earth_section",
        "virtual_section",
        "nr/iterate_0",
    ):
        assert f"/limb/{n}" in names, n
    # Spacecraft on the bundled circular orbit: |P| = a + 390 km (scenario file); 1e-3 m
    # covers float64 km positions on the wire.
    assert np.linalg.norm(ecef_of(limb, "/limb/spacecraft")) == pytest.approx(A + 390e3, abs=1e-3)
    # The [L18] tangent point lies on the virtual ellipsoid of eq. 13 (a' = a + Delta a,
    # same flattening) and the line of sight is tangent there: the direction is
    # perpendicular to the ellipsoid normal (x/a'^2, y/a'^2, z/b'^2).
    t = ecef_of(limb, "/limb/tangent")
    da = float(limb.tan.delta_a)
    a2, b2 = (A + da) ** 2, ((1 - F) * (A + da)) ** 2
    assert (t[0] ** 2 + t[1] ** 2) / a2 + t[2] ** 2 / b2 == pytest.approx(1.0, abs=1e-9)  # ~6 mm
    n = np.array([t[0] / a2, t[1] / a2, t[2] / b2])
    d = np.asarray(limb.chain.direction_ecef)
    assert abs(n @ d) / np.linalg.norm(n) < 1e-6  # tangency to 1 micro-radian
    # The exact tangent's geodetic height by PROJ matches the height shown in its label (the
    # marker is drawn k_off times farther from the tangent point along the line: undo that).
    e = t + (ecef_of(limb, "/limb/exact") - t) / limb.offset_exaggeration
    lon, lat, h = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*e)
    label = limb.server.scene.get_handle_by_name("/limb/exact/label").text
    assert f"{h / 1e3:.3f} km" in label
    assert 10e3 < h < 60e3  # the instrument's 10-60 km range ([L18]; scenario aimed there)


def test_alpha_slider_raises_the_tangent(limb):
    h0 = float(limb.tan.exact_h)
    limb.sl_alpha.value = 1.0  # alpha positive is upwards (geoloc.workflows.limb_scenario.alphas)
    try:
        h1 = float(limb.tan.exact_h)
        # ~2 200 km to the tangent: 1 deg up raises it by ~2200 km * 0.0175 = 38 km, minus curvature.
        assert 20e3 < h1 - h0 < 50e3
        assert f"{h1 / 1e3:.3f}" in limb.md.content
    finally:
        limb.sl_alpha.value = 0.0


TO_GEO = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
TO_ECEF = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def points_ecef(app, name):
    pts = np.asarray(app.server.scene.get_handle_by_name(name).points, float).reshape(-1, 3)
    return app.enu.to_ecef(pts / WORLD_SCALE)


def line_distance(p, o, d):
    """Distance of points p (n, 3) from the line o + s d."""
    d = d / np.linalg.norm(d)
    r = p - o
    return np.linalg.norm(r - (r @ d)[:, None] * d, axis=1)


def true_virtual_height(lat_deg, lon_deg, da):
    """Height above WGS-84 (PROJ) of the eq. 13 virtual ellipsoid along the normal at (lat, lon):
    the root of its implicit equation, by scipy's brentq (independent of the scene's closed form)."""
    from scipy.optimize import brentq

    a2, b2 = (A + da) ** 2, ((1 - F) * (A + da)) ** 2

    def g(h):
        x, y, z = TO_ECEF.transform(lon_deg, lat_deg, h)
        return (x * x + y * y) / a2 + z * z / b2 - 1.0

    return brentq(g, 0.0, 2.0 * da, xtol=1e-7, rtol=1e-15)


@pytest.mark.parametrize("k", [1.0, 1000.0, 5000.0])
def test_drawn_virtual_ellipsoid_stays_tangent_to_the_drawn_line(limb, k):
    limb.sl_exag.value = k
    try:
        los = points_ecef(limb, "/limb/los")
        o, d = los[0], los[-1] - los[0]
        seg = points_ecef(limb, "/limb/virtual_section").reshape(-1, 2, 3)
        sec = np.concatenate([seg[:, 0], seg[-1:, 1]])  # the polyline's vertices, once each
        dist = line_distance(sec, o, d)
        i = int(np.argmin(dist))
        # The drawn line touches the drawn surface: 0.5 m covers float32 km vertices (0.12 m at
        # 2000 km from the origin, at the line's ends) and the 0.5 km sampling near the tangent
        # (sag (250 m)^2 / (2 x 6400 km) = 5 mm). The old drawing (a' = a + k Delta a) missed by
        # (k - 1) x 33.8 km.
        assert dist[i] < 0.5, dist[i]
        t = ecef_of(limb, "/limb/tangent")
        assert np.linalg.norm(sec[i] - t) < 1000.0  # ... at the drawn tangent point (0.5 km sampling)
        # ... tangentially: the section's chord across the touching vertex is parallel to the line
        # (to 2e-4 rad: a 1 km chord of a 6400 km radius curve, off-centre by <= 250 m: 4e-5 rad)
        chord = sec[i + 1] - sec[i - 1]
        cosang = abs(chord @ d) / np.linalg.norm(chord) / np.linalg.norm(d)
        assert np.arccos(min(cosang, 1.0)) < 2e-4
        # and the drawing is exaggerated where it should be: at the section's far end the drawn
        # height is H_V + (k - 1) (H_V - h_T - slope term) of the true virtual ellipsoid (PROJ + brentq)
        da = float(limb.tan.delta_a)
        lon_t, lat_t, _ = TO_GEO.transform(*limb.tan.tangent_ecef)
        step = 1e-3  # deg: central differences of a smooth height (error ~ step^2 x third derivative: sub-mm)
        h_t = true_virtual_height(lat_t, lon_t, da)
        g_lat = (true_virtual_height(lat_t + step, lon_t, da) - true_virtual_height(lat_t - step, lon_t, da)) / (
            2 * step
        )
        g_lon = (true_virtual_height(lat_t, lon_t + step, da) - true_virtual_height(lat_t, lon_t - step, da)) / (
            2 * step
        )
        lon_e, lat_e, h_drawn = TO_GEO.transform(*sec[-1])
        h_v = true_virtual_height(lat_e, lon_e, da)
        expect = h_v + (k - 1) * (h_v - h_t - g_lat * (lat_e - lat_t) - g_lon * (lon_e - lon_t))
        # 1 m: float32 km vertex 2000 km out (0.12 m), plus brentq's 1e-7 m and the slope
        # term's finite differences, both times (k - 1)
        assert h_drawn == pytest.approx(expect, abs=1.0 + 2e-4 * k)
        if k > 1:
            assert abs(h_drawn - h_v) > 1000.0  # the exaggeration shows (km, not m)
    finally:
        limb.sl_exag.value = 1000.0


def test_markers_smaller_than_half_their_separation(limb):
    from scipy.optimize import minimize_scalar

    sc = limb.server.scene
    t, x = ecef_of(limb, "/limb/tangent"), ecef_of(limb, "/limb/exact")
    sep_km = np.linalg.norm(x - t) * WORLD_SCALE
    for n in ("/limb/tangent", "/limb/exact"):
        assert sc.get_handle_by_name(n).radius < 0.5 * sep_km
    # the exact minimum is drawn on the line, k_off times its true offset from the tangent point;
    # the true minimum of the geodetic height along the line by PROJ + scipy (independent)
    o, d = np.asarray(limb.chain.origin_ecef), np.asarray(limb.chain.direction_ecef)
    los = points_ecef(limb, "/limb/los")
    assert line_distance(x[None], los[0], los[-1] - los[0])[0] < 1.0  # float32 km on the wire
    s_t = float((t - o) @ d)
    res = minimize_scalar(lambda s: TO_GEO.transform(*(o + s * d))[2], bracket=(s_t - 5e3, s_t, s_t + 5e3), tol=1e-12)
    true_off = res.x - s_t
    k_off = limb.offset_exaggeration
    # a flat minimum (h ~ (s - s_X)^2 / 2R): 1e-7 m of height precision is ~1.6 m along the line
    assert float((x - t) @ d) == pytest.approx(k_off * true_off, abs=k_off * 2.0)
    assert 20.0 < abs(true_off) < 200.0  # tens of metres (35-135 m over the limb's frames)
    assert sep_km > 5.0  # drawn apart by kilometres at the default exaggeration


def test_line_that_hits_the_earth_stops_there(limb):
    limb.sl_alpha.value = -1.5  # below the limb: this line meets the Earth
    try:
        assert int(limb.tan.status) == 7  # HITS_EARTH
        los = points_ecef(limb, "/limb/los")
        # the end lies on WGS-84 (PROJ height 0; 1 m covers float32 km vertices ~2000 km out)
        assert abs(TO_GEO.transform(*los[-1])[2]) < 1.0
        # ... and is the first crossing: above ground before it, below just after it
        dirn = (los[-1] - los[0]) / np.linalg.norm(los[-1] - los[0])
        for f in (0.25, 0.5, 0.75, 0.99):
            assert TO_GEO.transform(*(los[0] + f * (los[-1] - los[0])))[2] > 0.0
        assert TO_GEO.transform(*(los[-1] + 5e3 * dirn))[2] < 0.0
        sc = limb.server.scene
        assert sc.get_handle_by_name("/limb/earth_hit") is not None
        assert sc.get_handle_by_name("/limb/tangent") is None
    finally:
        limb.sl_alpha.value = 0.0
    assert limb.server.scene.get_handle_by_name("/limb/earth_hit") is None


def test_view_command_exports_both_scenes(tmp_path, capsys):
    out = tmp_path / "flight.html"
    assert main(["view", "--scenario", "flight-test", "--record", "T4-2", "--export", str(out)]) == 0
    html = out.read_text()
    assert html.lstrip().lower().startswith("<!doctype html") and len(html) > 100_000
    out2 = tmp_path / "limb.viser"
    assert main(["view", "--scenario", "limb", "--export", str(out2)]) == 0
    assert out2.stat().st_size > 10_000  # the Earth and virtual-ellipsoid meshes
    assert "wrote" in capsys.readouterr().out


def test_view_command_rejects_bad_arguments(capsys):
    assert main(["view", "--scenario", "flight-test", "--record", "T9-9", "--export", "/dev/null"]) == 2
    err = capsys.readouterr().err
    assert "record = 'T9-9'" in err and "T3-1" in err
    assert main(["view", "--port", "70000", "--no-browser"]) == 2
    assert "port = 70000" in capsys.readouterr().err
    # A DEM that does not cover the target (the SRTM tile is in Tennessee, T3-1 in Asia).
    assert (
        main(
            [
                "view",
                "--scenario",
                "flight-test",
                "--dem",
                str(asset_path("dem", "srtm_jacksboro.tif")),
                "--export",
                "/dev/null",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "does not cover the target" in err and "srtm_jacksboro.tif" in err


def test_exports_read_back_node_by_node(limb, tmp_path):
    # the limb scene's .viser and HTML exports decoded message by message: every marker
    # at the live scene's position (float64 kept; the live positions are held to the core's
    # geometry by test_limb_nodes_where_the_geometry_says), the meshes and the line of sight present
    import base64
    import re

    from test_viz_scene import _decode_recording

    p = limb.export(tmp_path / "limb.viser")
    h = limb.export(tmp_path / "limb.html")
    b64 = re.search(r'window\.__VISER_EMBED_DATA__="([^"]*)"', h.read_text()).group(1)
    assert 'id="geoloc-summary"' in h.read_text() and "Newton-Raphson" in h.read_text()
    for rec in (_decode_recording(p.read_bytes()), _decode_recording(base64.b64decode(b64))):
        last, kinds = {}, {}
        for _, m in rec["messages"]:
            kinds.setdefault(m.get("type"), set()).add(m.get("name"))
            if m.get("type") == "SetPositionMessage":
                last[m["name"]] = np.asarray(m["position"], float)
        for name in ("/limb/spacecraft", "/limb/tangent", "/limb/exact"):
            live = np.asarray(limb.server.scene.get_handle_by_name(name).position, float)
            np.testing.assert_array_equal(last[name], live, err_msg=name)
        assert {"/limb/earth", "/limb/virtual"} <= kinds.get("MeshMessage", set())
        assert {"/limb/spacecraft", "/limb/tangent", "/limb/exact"} <= kinds.get("IcosphereMessage", set())
        assert kinds.get("LineSegmentsMessage")
