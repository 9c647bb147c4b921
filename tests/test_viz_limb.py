"""The limb scene and the ``geoloc view`` command line, in process (no browser)."""


import numpy as np
import pyproj
import pytest

from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.geodesy.ellipsoid import A, F
from geoloc.viz.app import make_server
from geoloc.viz.scene_geoloc import WORLD_SCALE
from geoloc.viz.scene_limb import LimbApp, load_limb


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
    for n in ("earth", "virtual", "spacecraft", "velocity", "los", "tangent", "tangent/label", "exact",
              "exact/label", "earth_section", "virtual_section", "nr/iterate_0"):
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
    # The exact tangent's geodetic height by PROJ matches the height shown in its label.
    e = ecef_of(limb, "/limb/exact")
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


def test_exaggeration_grows_the_virtual_section(limb):
    def mean_radius(name):
        pts = np.asarray(limb.server.scene.get_handle_by_name(name).points, float).reshape(-1, 3)
        return np.linalg.norm(limb.enu.to_ecef(pts / WORLD_SCALE), axis=-1)

    r_earth = mean_radius("/limb/earth_section")
    da = float(limb.tan.delta_a)
    for k in (1.0, 5.0):
        limb.sl_exag.value = k
        # Homothety of eq. 13: every point scaled by (a + k Delta a) / a; float32 km vertices
        # at 6.4e3 km carry ~0.5 m, hence 1e-6 relative.
        np.testing.assert_allclose(mean_radius("/limb/virtual_section") / r_earth, (A + k * da) / A, rtol=1e-6)
    limb.sl_exag.value = 1.0


def test_view_command_exports_both_scenes(tmp_path, capsys):
    out = tmp_path / "flight.html"
    assert main(["view", "--record", "T4-2", "--export", str(out)]) == 0
    html = out.read_text()
    assert html.lstrip().lower().startswith("<!doctype html") and len(html) > 100_000
    out2 = tmp_path / "limb.viser"
    assert main(["view", "--scenario", "limb", "--export", str(out2)]) == 0
    assert out2.stat().st_size > 10_000  # the Earth and virtual-ellipsoid meshes
    assert "wrote" in capsys.readouterr().out


def test_view_command_rejects_bad_arguments(capsys):
    assert main(["view", "--record", "T9-9", "--export", "/dev/null"]) == 2
    err = capsys.readouterr().err
    assert "record = 'T9-9'" in err and "T3-1" in err
    assert main(["view", "--port", "70000", "--no-browser"]) == 2
    assert "port = 70000" in capsys.readouterr().err
    # A DEM that does not cover the target (the SRTM tile is in Tennessee, T3-1 in Asia).
    assert main(["view", "--dem", str(asset_path("dem", "srtm_jacksboro.tif")), "--export", "/dev/null"]) == 2
    err = capsys.readouterr().err
    assert "does not cover the target" in err and "srtm_jacksboro.tif" in err
