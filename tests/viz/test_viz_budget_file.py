"""The viewer reads the error budget from the scenario's sensor file.

A sensor file's ``[uncertainty]`` table (``geoloc view --sensor FILE``) is the budget of the
viewer's predicted ellipse and of a target triangulated from picks in several frames; what the
viewer cannot carry is left out and said so (``time_s`` where a record has no velocity, a records
CSV; a KLV flight's records have theirs; a lens
key of a lens the frame does not have: a KLV frame's lens comes from its fields of view).

The oracles are closed forms, not the code's output:

* a budget of platform position only, sigma s north and east, over a level surface: the hit moves
  with the platform, so the 1-sigma ellipse is the circle of radius s and CE90 is the Rayleigh
  quantile s sqrt(chi2(2, 0.9)) (scipy);
* a budget of the time tag only over a level surface, on the example KLV flight: the platform
  moves by its velocity times the error, so the ellipse is a segment along the track of 1-sigma
  length |v| sigma_t, v the packets' positions differenced over their time stamps with pyproj's
  geodesic;
* a budget of platform position only, sigma s in north, east and up, independent per frame: each
  ray is translated by an isotropic error, its miss across it has covariance s^2 I, and the
  weighted least-squares point has covariance s^2 (sum_i P_i)^-1, P_i = I - d_i d_i^T the
  projector across ray i, with d_i from pyproj's ECEF of the aircraft and of the target and
  pymap3d's ENU at the target.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2
from test_viz_browser import served

from geoloc.assets import asset_path
from geoloc.io.images import ArrayImages
from geoloc.status import Status

FRAMES = (0, 20, 40)


def _with_budget(tmp_path, src, table: str):
    p = tmp_path / "sensor_with_budget.toml"
    p.write_text(open(src).read() + "\n[uncertainty]\n" + table)
    return p


def _layer(app, name):
    return next(lay for lay in app.layers if type(lay).__name__ == name)


def test_the_ellipse_is_the_sensor_files_budget(tmp_path):
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scene_geoloc import WORLD_SCALE
    from geoloc_viz.scenario import load_view_scenario

    s = 4.0
    path = _with_budget(
        tmp_path, asset_path("cameras", "qiao2017.toml"), f"north_m = {s}\neast_m = {s}\ntime_s = 0.01\n"
    )
    scn = load_view_scenario(camera_path=path, use_dem=False)  # the ellipsoid at the record's height
    assert scn.budget is not None and scn.budget.sigma("north_m") == s
    with served() as server:
        app = GeolocApp(server, scn)
        lay = _layer(app, "UncertaintyLayer")
        pu = lay.pu
        assert pu is not None and pu.status == Status.OK
        # The hit moves with the platform, except for the local frame turning with it (the attitude
        # is to the local NED: 1 / R per metre, times the slant range, 8 km here: 1.3e-3) and the
        # level surface's normal at the hit against the aircraft's (the same angle): 5e-3 covers both
        assert float(pu.ellipse_major_m) == pytest.approx(s, rel=5e-3)
        assert float(pu.ellipse_minor_m) == pytest.approx(s, rel=5e-3)
        r90 = math.sqrt(chi2.ppf(0.9, 2))
        assert float(pu.ce90_m) == pytest.approx(r90 * s, rel=5e-3)
        # the drawn ellipse is that circle, at its own drawing factor (true size by default)
        d = app.view.disp
        assert lay.scale == 1.0
        seg = np.asarray(server.scene.get_handle_by_name("/enu/uncertainty/ellipse").points, float)
        pts = seg[:, 0, :] / (WORLD_SCALE * np.array([1.0, 1.0, d.vertical_exaggeration]))
        hit = np.asarray(app.geometry.hit_enu, float)
        r = np.hypot(pts[:, 0] - hit[0], pts[:, 1] - hit[1])
        # float32 scene coordinates in km: 1e-3 of a few tens of metres
        np.testing.assert_allclose(r, r90 * s * lay.scale, rtol=1e-2)
        text = lay.md.content
        assert "illustrative" not in text and path.name in text
        assert "time_s = 0.01 s left out" in text
        assert f"CE90 {r90 * s:.1f} m" in text


@pytest.fixture(scope="module")
def orbit_with_budget(tmp_path_factory):
    """The bundled example flight on the EO turret's sensor file, with a position-only budget."""
    from test_viz_picture import render_frame

    from geoloc_viz.flight_model import default_flight_scenario

    path = _with_budget(
        tmp_path_factory.mktemp("budget"),
        asset_path("sensors", "eo_turret.toml"),
        "north_m = 3.0\neast_m = 3.0\nup_m = 3.0\nk1 = 0.001\n",
    )
    scn = default_flight_scenario(camera_path=path)
    scn.images = ArrayImages([render_frame(scn, i) for i in FRAMES])
    idx = np.full(len(scn.records), -1)
    idx[list(FRAMES)] = np.arange(len(FRAMES))
    scn.image_index = idx
    return scn, path


def test_the_triangulated_target_takes_the_sensor_files_budget(orbit_with_budget):
    import pymap3d
    import pyproj
    from test_viz_picture import make_app
    from test_viz_triangulate import _pixel_of, _target

    scn, path = orbit_with_budget
    s = 3.0
    server, app, layer = make_app(scn)
    try:
        g = _target(app, layer)
        for k in FRAMES:
            app.load_record(k, move_camera=False)
            layer.pick_pixel(*_pixel_of(app, layer, g))
        t = layer.target_rays
        assert t is not None and t.tri.status == Status.OK and t.tri.cov_enu is not None
        to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
        P = np.zeros((3, 3))
        dirs = []
        for k in FRAMES:
            inp = scn.records[k][1]
            a = to_ecef.transform(inp.lon_deg, inp.lat_deg, inp.h_m)
            v = np.array(pymap3d.ecef2enu(*a, g[0], g[1], g[2]))  # the target to the aircraft, ENU at G
            v /= np.linalg.norm(v)
            dirs.append(v)
            P += np.eye(3) - np.outer(v, v)
        expected = s * s * np.linalg.inv(P)
        # the rays start at the optical centre, a lever arm of 1.7 m from the aircraft's reference
        # over ranges of kilometres (6e-4 rad), and the local frame turns with the platform's move
        # (range / R, 5e-4): 2 % of the largest term covers both, the matrix's shape and size
        np.testing.assert_allclose(t.tri.cov_enu, expected, atol=2e-2 * np.abs(expected).max())
        text = layer.md_target.content
        assert "illustrative" not in text and path.name in text
        assert "k1 = 0.001 left out" in text
        # and a time tag error, per frame: each ray moves by its platform's velocity times it, so
        # frame i's error is s^2 I + sigma_t^2 v_i v_i^T and the weighted least squares point's
        # covariance is (sum_i B_i (B_i^T Sigma_i B_i)^-1 B_i^T)^-1, B_i across ray i
        from geoloc.sensors.budget import ErrorBudget

        sig_t = 0.2
        app.scn.budget = ErrorBudget({**app.scn.budget.sigmas, "time_s": sig_t}, None, str(path))
        layer._add_to_target()
        t = layer.target_rays
        A = np.zeros((3, 3))
        for k, d in zip(FRAMES, dirs):
            v = _velocity_enu(int(scn.records[k][0].label.split()[-1]))
            Sig = s * s * np.eye(3) + sig_t**2 * np.outer(v, v)
            ref = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            b1 = np.cross(d, ref)
            b1 /= np.linalg.norm(b1)
            B = np.stack([b1, np.cross(d, b1)], -1)
            A += B @ np.linalg.inv(B.T @ Sig @ B) @ B.T
        expected = np.linalg.inv(A)
        np.testing.assert_allclose(t.tri.cov_enu, expected, atol=2e-2 * np.abs(expected).max())
        assert "moves the platform by the packets' velocity" in layer.md_target.content
    finally:
        server.stop()


def test_without_a_table_the_viewer_says_its_budget_is_illustrative(tmp_path):
    from geoloc_viz.scenario import load_view_scenario
    from geoloc_viz.uncertainty_layer import scenario_budget

    scn = load_view_scenario(use_dem=False)  # the bundled [Q17] camera file has no [uncertainty]
    assert scn.budget is None
    b, note, illustrative = scenario_budget(scn)
    assert illustrative and note == "illustrative budget" and b.sigma("heading_deg") > 0


def _velocity_enu(packet):
    """The platform's velocity at ``packet`` of the example flight, east-north-up [m/s]: its
    neighbours' positions (decoded from the file) over their time stamps, the motion by pyproj's
    geodesic (one-sided at the ends, as a central difference cannot be)."""
    import pyproj

    from geoloc_viz.flight_model import default_flight_path
    from geoloc.workflows.klv_replay import read_klv

    r = read_klv(default_flight_path())
    c = r.columns
    j = list(np.asarray(r.packet, int)).index(packet)
    a, b = max(j - 1, 0), min(j + 1, len(r.packet) - 1)
    lat, lon, h = (
        np.asarray(c[k], float) for k in ("sensor_latitude_deg", "sensor_longitude_deg", "sensor_ellipsoid_height_m")
    )
    t = np.asarray(c["precision_time_stamp_us"], float) * 1e-6
    az, _, dist = pyproj.Geod(ellps="WGS84").inv(lon[a], lat[a], lon[b], lat[b])
    dt = t[b] - t[a]
    sp = dist * (1 + h[j] / 6371e3) / dt  # the chord at the platform's height
    return np.array([sp * math.sin(math.radians(az)), sp * math.cos(math.radians(az)), (h[b] - h[a]) / dt])


def test_a_time_error_on_a_klv_flight_moves_the_point_along_the_track(tmp_path):
    import pyproj

    from geoloc_viz.app import GeolocApp
    from geoloc_viz.flight_model import default_flight_path, default_flight_scenario
    from geoloc.workflows.klv_replay import read_klv

    sig_t = 0.1
    path = _with_budget(tmp_path, asset_path("sensors", "eo_turret.toml"), f"time_s = {sig_t}\n")
    scn = default_flight_scenario(camera_path=path, use_dem=False)  # level: each packet's reported height
    k = 10
    packet = int(scn.records[k][0].label.split()[-1])
    r = read_klv(default_flight_path())
    c = r.columns
    assert np.all(np.isnan(np.asarray(c["sensor_north_velocity_m_s"], float)))  # no tags 79 / 80 here
    j = list(np.asarray(r.packet, int)).index(packet)
    # the neighbours' positions over their time stamps (the packets' own, decoded; the motion: pyproj)
    lat, lon = (np.asarray(c[f"sensor_{a}itude_deg"], float) for a in ("lat", "long"))
    t = np.asarray(c["precision_time_stamp_us"], float) * 1e-6
    az, _, dist = pyproj.Geod(ellps="WGS84").inv(lon[j - 1], lat[j - 1], lon[j + 1], lat[j + 1])
    h = scn.records[k][1].h_m
    speed = dist * (1 + h / 6371e3) / (t[j + 1] - t[j - 1])  # the chord at the platform's height
    with served() as server:
        app = GeolocApp(server, scn)
        app.load_record(k, move_camera=False)
        pu = _layer(app, "UncertaintyLayer").pu
        assert pu is not None and pu.status == Status.OK
        # the hit moves with the platform over a level surface: a segment of 1-sigma length
        # speed x sigma_t along the track. The platform's climb (under 0.5 m/s against 54 m/s) moves
        # the hit along the ray by climb x tan(off nadir): 2 % covers it and the local frame's turn
        print(
            f"1-sigma segment {float(pu.ellipse_major_m):.3f} m (speed x sigma_t {speed * sig_t:.3f} m), minor "
            f"{float(pu.ellipse_minor_m):.4f} m, azimuth {float(pu.ellipse_azimuth_deg):.2f} deg (track {az:.2f})"
        )
        # (measured: 5.442 m against 5.445 m, the azimuth 0.4 deg off the chord's)
        assert float(pu.ellipse_major_m) == pytest.approx(speed * sig_t, rel=1e-2)
        assert float(pu.ellipse_minor_m) < 0.01 * float(pu.ellipse_major_m)
        assert (float(pu.ellipse_azimuth_deg) - az + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1.0)
        text = _layer(app, "UncertaintyLayer").md.content
        assert "moves the platform by the packets' velocity" in text and "left out" not in text
