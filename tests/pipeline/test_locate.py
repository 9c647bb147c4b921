"""Pixel -> ground at a target height [Q17 section 2.2]: Table 1, inverses, batch edge cases."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Transformer

from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import A, B, geodetic_to_ecef
from geoloc.locate import ground_to_pixel, locate
from geoloc.sensors.camera import Camera
from geoloc.status import Status
from geoloc.surfaces.height import ray_geodetic_height, ray_inflated_ellipsoid

TO_GEOD = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
CAM = Camera(166841.0, (2323 + 1) / 2, (2292 + 1) / 2, 2323, 2292)
TABLE1 = Pose.from_deg(35.48, 80.97, 18000.0, 45.0, 3.5, 0.0, 50.0, -2.6)


def test_table1_nominal_point():
    # docs/method.md section 8: [Q17] reports 35.57709 N, 80.84918 E at h_T = 5083.5 m,
    # published to 1e-5 deg, so agreement is checked to half of that.
    g = locate(TABLE1, CAM, target_h=5083.5)
    assert g.status == Status.OK
    assert float(g.lat_deg) == pytest.approx(35.57709, abs=0.5e-5)
    assert float(g.lon_deg) == pytest.approx(80.84918, abs=0.5e-5)


def test_inflated_versus_exact_constant_height():
    g1 = locate(TABLE1, CAM, target_h=5083.5)
    g2 = locate(TABLE1, CAM, target_h=5083.5, height_kind="geodetic")
    # exact surface: pyproj's geodetic height of the hit is h_T (PROJ's inverse is
    # good to 1e-6 m at this height, see test_ellipsoid)
    assert TO_GEOD.transform(*g2.ecef)[2] == pytest.approx(5083.5, abs=1e-5)
    # the paper's inflated ellipsoid is a few millimetres off h_T at 5 km
    dh = float(g1.h) - 5083.5
    assert 1e-3 < abs(dh) < 2e-2
    # and the horizontal shift that causes is centimetric (slant ~ 3.5 x height)
    assert 1e-3 < np.linalg.norm(g1.ecef - g2.ecef) < 0.1


def test_inflated_ellipsoid_closed_forms():
    # nadir ray from above the equator: hits at x = a + h exactly
    o = np.array([A + 20000.0, 0, 0])
    hit = ray_inflated_ellipsoid(o, [-1.0, 0, 0], 500.0)
    assert hit.ecef[0] == pytest.approx(A + 500.0, abs=1e-8)
    assert hit.s == pytest.approx(19500.0, abs=1e-8)
    # from above the pole: z = b + h
    hit = ray_inflated_ellipsoid([0, 0, B + 9000.0], [0, 0, -1.0], 1000.0)
    assert hit.ecef[2] == pytest.approx(B + 1000.0, abs=1e-8)


def test_batch_rays_to_the_sky_give_nan_and_a_reason():
    rows = np.array([1162.0, 1162.0, 1162.0])
    pose = Pose.from_deg(35.48, 80.97, 18000.0, 45.0, 3.5, 0.0, [50.0, 95.0, 179.0], -2.6)
    g = locate(pose, CAM, rows, 1146.5, target_h=0.0)
    assert list(g.status) == [Status.OK, Status.SKY, Status.SKY]
    assert np.isfinite(g.lat[0]) and np.all(np.isnan(g.lat[1:])) and np.all(np.isnan(g.ecef[1:]))


def test_batch_invalid_inputs_and_origin_below():
    pose = Pose.from_deg(
        [35.48, np.nan, 35.48, 35.48],
        80.97,
        [18000.0, 18000.0, 18000.0, 100.0],
        45,
        [3.5, 3.5, 120.0, 3.5],
        0,
        50,
        -2.6,
    )
    g = locate(pose, CAM, target_h=5000.0)
    assert list(g.status) == [Status.OK, Status.INVALID_INPUT, Status.INVALID_INPUT, Status.ORIGIN_BELOW]
    assert np.all(np.isnan(g.h[1:]))


def test_grazing_ray_just_below_and_above_the_horizon():
    # From 18 km the horizon is at depression acos(R/(R+h)) ~ 4.3 deg: a ray
    # 0.01 deg below it hits, 0.01 deg above it misses, both without exceptions.
    h = 18000.0
    R = A  # at the equator, looking north-south the radius is a mix; look east (R_N = a)
    dip = np.rad2deg(np.arccos(R / (R + h)))
    o = geodetic_to_ecef(0.0, 0.0, h)
    dirs = []
    for d in (dip + 0.01, dip - 0.01):
        e = np.deg2rad(d)
        dirs.append([-np.sin(e), np.cos(e), 0.0])  # east, dipping by e
    hit = ray_inflated_ellipsoid(o, np.array(dirs), 0.0)
    assert list(hit.status) == [Status.OK, Status.SKY]
    assert hit.s[0] > 400e3  # a grazing hit is far away
    geo = ray_geodetic_height(o, np.array(dirs), 0.0)
    assert list(geo.status) == [Status.OK, Status.SKY]


@settings(max_examples=100, deadline=None)
@given(st.floats(1.0, 2323.0), st.floats(1.0, 2292.0))
def test_pixel_los_round_trip(row, col):
    d = CAM.pixel_to_los(row, col)
    assert np.linalg.norm(d) == pytest.approx(1.0)
    i, j, status = CAM.los_to_pixel(d * 7.3)
    assert status == Status.OK
    assert i == pytest.approx(row, abs=1e-6) and j == pytest.approx(col, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.floats(1.0, 2323.0), st.floats(1.0, 2292.0), st.floats(0.0, 6000.0))
def test_ground_to_pixel_inverts_locate(row, col, h):
    g = locate(TABLE1, CAM, row, col, target_h=h)
    i, j, status = ground_to_pixel(TABLE1, CAM, g.lat, g.lon, g.h)
    # 1e-6 px = 0.4 um on the ground at 70 km: float64 rounding of 6e6-m ECEF coordinates
    assert status == Status.OK
    assert i == pytest.approx(row, abs=1e-4) and j == pytest.approx(col, abs=1e-4)


def test_pixel_axes_follow_q17_eq8():
    # [Q17 eq. 8]: d_S = [a(i - (M+1)/2), a((N+1)/2 - j), f]: a larger row looks
    # along +X_S, a larger column along -Y_S.
    d = CAM.pixel_to_los([CAM.principal_row + 100, CAM.principal_row], [CAM.principal_col, CAM.principal_col + 100])
    assert d[0, 0] > 0 and abs(d[0, 1]) < 1e-15
    assert d[1, 1] < 0 and abs(d[1, 0]) < 1e-15


def test_point_behind_camera_has_no_pixel():
    pose = Pose.from_deg(35.48, 80.97, 18000.0)  # looking straight down
    i, j, status = ground_to_pixel(pose, CAM, np.deg2rad(35.48), np.deg2rad(80.97), 30000.0)
    assert status == Status.BEHIND_CAMERA and np.isnan(i) and np.isnan(j)


def test_camera_validation_names_field(tmp_path):
    with pytest.raises(ValueError, match="focal_length_px"):
        Camera(-1.0, 10, 10, 20, 20)
    with pytest.raises(ValueError, match="rows"):
        Camera(100.0, 10, 10, 0, 20)
    p = tmp_path / "c.toml"
    p.write_text("focal_length_px = 100.0\nprincipal_row = 5\nprincipal_col = 5\nrows = 10\ncolumns = 10\n")
    with pytest.raises(ValueError, match="columns"):
        Camera.from_toml(p)


def test_camera_toml_round_trip(tmp_path):
    cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292, pixel_pitch_m=7e-6, name="test")
    cam.to_toml(tmp_path / "c.toml")
    assert Camera.from_toml(tmp_path / "c.toml") == cam
    assert cam.sensor_size_m == pytest.approx((2323 * 7e-6, 2292 * 7e-6))


def test_geodetic_height_surface_reports_no_convergence_for_one_ray():
    # one ray (0-d arrays) that the iteration is not allowed to finish: NaN and a status, no TypeError
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc.status import Status
    from geoloc.surfaces.height import ray_geodetic_height

    o = geodetic_to_ecef(0.6, 1.4, 18000.0)
    hit = ray_geodetic_height(o, -o / np.linalg.norm(o), 100.0, max_iter=0)
    assert int(hit.status) == Status.NO_CONVERGENCE and np.isnan(hit.s)
