"""The optional calibration rotations of the camera file (boresight_deg, mount_deg).

Expected values are closed forms (flat-Earth tilt, composition of rotations about
one axis) and pyproj's geodesic, not the code under test.
"""

import dataclasses
import math

import numpy as np
import pytest
from pyproj import Geod

from geoloc.frames.chain import Pose
from geoloc.locate import ground_to_pixel, locate
from geoloc.sensors.camera import Camera

GEOD = Geod(ellps="WGS84")


def _cam(**kw):
    # principal point at the CCD centre so that the centre pixel is the optical axis
    return Camera(100000.0, 1000.5, 1000.5, 2000, 2000, **kw)


def test_toml_round_trip_and_degrees(tmp_path):
    cam = _cam(
        boresight=(math.radians(0.1), math.radians(-0.2), math.radians(0.3)), mount=(0.0, math.radians(0.22), 0.0)
    )
    p = tmp_path / "c.toml"
    cam.to_toml(p)
    text = p.read_text()
    assert "boresight_deg = [" in text and "mount_deg = [" in text
    back = Camera.from_toml(p)
    # repr of floats round-trips up to one rounding in deg<->rad (1e-15 relative)
    np.testing.assert_allclose(back.boresight, cam.boresight, rtol=1e-14, atol=0)
    np.testing.assert_allclose(back.mount, cam.mount, rtol=1e-14, atol=1e-300)
    assert Camera.from_toml(tmp_path.joinpath("c.toml")).R_base_body.shape == (3, 3)


def test_without_fields_the_file_is_unchanged(tmp_path):
    p = tmp_path / "c.toml"
    _cam().to_toml(p)
    assert "boresight" not in p.read_text() and "mount" not in p.read_text()
    assert _cam().R_cam_inner is None and _cam().R_base_body is None


@pytest.mark.parametrize("value", [[1.0, 2.0], ["a", 0, 0], [0, 0, True]])
def test_bad_file_value_names_the_key(tmp_path, value):
    with pytest.raises(ValueError, match="mount_deg"):
        Camera.from_dict(
            {
                "focal_length_px": 1e5,
                "principal_row": 1.0,
                "principal_col": 1.0,
                "rows": 2,
                "cols": 2,
                "mount_deg": value,
            }
        )


def test_bad_field_names_the_field():
    with pytest.raises(ValueError, match="boresight"):
        _cam(boresight=(0.0, float("nan"), 0.0))


def test_boresight_tilt_moves_nadir_point_north_by_H_tan_a():
    # Camera looking straight down (zero attitude and gimbal: Z_S = D), boresight
    # ry(a): v_inner = ry(a)^T [0, 0, 1] = [sin a, 0, cos a] in NED, i.e. tilted
    # north. Flat Earth: the ground point moves north by H tan a. Curvature over
    # 175 m changes this by ~H * d^2 / (2 R d) ~ 1e-4 m; tolerance 0.01 m.
    a, H = math.radians(1.0), 10000.0
    pose = Pose.from_deg(35.0, 80.0, H)
    g0 = locate(pose, _cam(), target_h=0.0)
    g1 = locate(pose, _cam(boresight=(0.0, a, 0.0)), target_h=0.0)
    az, _, d = GEOD.inv(float(g0.lon_deg), float(g0.lat_deg), float(g1.lon_deg), float(g1.lat_deg))
    assert d == pytest.approx(H * math.tan(a), abs=0.01)
    assert az == pytest.approx(0.0, abs=0.01)  # north; 0.01 deg ~ 3 cm across 175 m


def test_mount_about_x_adds_to_gimbal_roll():
    # rx(g) @ rx(b) = rx(g + b): a mounting roll b about body X is the same as
    # gimbal roll g + b. Same geometry, so agreement to float rounding (1e-6 m).
    b = math.radians(0.3)
    pose = Pose.from_deg(35.48, 80.97, 18000, 45, 3.5, 0.2, 50, -2.6)
    pose_b = Pose.from_deg(35.48, 80.97, 18000, 45, 3.5, 0.2, 50.3, -2.6)
    g1 = locate(pose, _cam(mount=(b, 0.0, 0.0)), 1200.0, 800.0, target_h=5000.0)
    g2 = locate(pose_b, _cam(), 1200.0, 800.0, target_h=5000.0)
    np.testing.assert_allclose(g1.ecef, g2.ecef, atol=1e-6)
    # and ground_to_pixel inverts it with the same rotation (1e-6 px: rounding)
    i, j, st = ground_to_pixel(pose, _cam(mount=(b, 0.0, 0.0)), g1.lat, g1.lon, g1.h)
    assert (i, j) == (pytest.approx(1200.0, abs=1e-6), pytest.approx(800.0, abs=1e-6))


# ----------------------------------------------------------------- a fitted sensor back as a camera file
def test_camera_from_sensor_inverts_to_sensor(tmp_path):
    # Camera -> FrameSensor -> Camera is the identity (the two conversions are each
    # other's inverse: cx = j0 - 1, cy = i0 - 1 in 0-based lens pixels); zero angles
    # stay absent from the file
    from geoloc.sensors.camera import as_sensor, camera_from_sensor

    for cam in (
        _cam(),
        _cam(mount=(0.001, -0.002, 0.003)),
        _cam(boresight=(0.0, 1e-4, 0.0), name="x"),
        Camera(1500.0, 300.25, 400.75, 600, 800, pixel_pitch_m=5e-6),
    ):
        back = camera_from_sensor(as_sensor(cam), pixel_pitch_m=cam.pixel_pitch_m)
        assert back == cam
    p = tmp_path / "c.toml"
    camera_from_sensor(as_sensor(_cam(mount=(0.0, 0.01, 0.0)))).to_toml(p)
    text = p.read_text()
    assert "mount_deg" in text and "boresight_deg" not in text


def test_camera_from_sensor_refuses_what_a_camera_file_cannot_say():
    from geoloc.assets import asset_path
    from geoloc.sensors.camera import as_sensor, camera_from_sensor
    from geoloc.sensors.gimbals import PRESETS
    from geoloc.sensors.sensor_file import load_sensor

    s = as_sensor(_cam())
    for change, field in (
        ({"fy": 100001.0}, "lens.fy"),
        ({"lever_arm_x_m": 0.5}, "lever_arm_m"),
        ({"skew": 0.1}, "lens.skew"),
    ):
        with pytest.raises(ValueError, match=field.replace(".", r"\.")):
            camera_from_sensor(s.with_params(**change))
    with pytest.raises(ValueError, match="gimbal = 'azimuth-elevation'"):
        camera_from_sensor(dataclasses.replace(s, gimbal=PRESETS["azimuth-elevation"]))
    with pytest.raises(ValueError, match="lens = 'BrownLens'"):  # a distorted lens
        camera_from_sensor(load_sensor(asset_path("sensors", "eo_turret.toml")))
