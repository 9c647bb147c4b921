"""Every gimbal preset's zero direction and signs, on cases a person can check by eye.

docs/conventions.md ("Gimbal presets") states them; these tests hold the code to
that page. The aircraft flies level, heading north, so body X = north, body Y =
east (right wing), body Z = down, and the image centre's line of sight is read
in NED directly. Expected directions are written out by hand, not computed.
"""

import math

import numpy as np
import pytest

from geoloc.frames.chain import Pose
from geoloc.geodesy.local import R_ecef_ned
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS, gimbal_from_dict
from geoloc.sensors.lenses import PinholeLens

LENS = PinholeLens(fx=1000.0, fy=1000.0, cx=499.5, cy=399.5, width=1000, height=800)
LAT, LON = math.radians(40.0), math.radians(10.0)


def centre_ray_ned(preset, heading_deg=0.0, pitch_deg=0.0, roll_deg=0.0, **angles_deg):
    s = FrameSensor(LENS, PRESETS[preset])
    q17 = {k: angles_deg.pop(k) for k in ("gimbal_roll", "gimbal_pitch") if k in angles_deg}
    pose = Pose.from_deg(
        40.0,
        10.0,
        1000.0,
        heading_deg,
        pitch_deg,
        roll_deg,
        q17.get("gimbal_roll", 0.0),
        q17.get("gimbal_pitch", 0.0),
        angles_deg=angles_deg,
    )
    d = s.line_of_sight(400.5, 500.5, pose).direction_ecef  # the principal point
    return R_ecef_ned(LAT, LON).T @ d


N, E, D = np.eye(3)
# 1e-12: a handful of float64 rotations of unit vectors
TOL = 1e-12


@pytest.mark.parametrize("preset", ["azimuth-elevation", "azimuth-elevation-roll"])
def test_zero_angles_look_along_the_nose(preset):
    extra = {"sensor_roll": 0.0} if preset.endswith("roll") else {}
    np.testing.assert_allclose(centre_ray_ned(preset, azimuth=0.0, elevation=0.0, **extra), N, atol=TOL)


def test_azimuth_90_looks_along_the_right_wing():
    np.testing.assert_allclose(centre_ray_ned("azimuth-elevation", azimuth=90.0, elevation=0.0), E, atol=TOL)
    # clockwise seen from above: azimuth 45 is north-east, -90 (or 270) the left wing
    np.testing.assert_allclose(
        centre_ray_ned("azimuth-elevation", azimuth=45.0, elevation=0.0), (N + E) / math.sqrt(2), atol=TOL
    )
    np.testing.assert_allclose(centre_ray_ned("azimuth-elevation", azimuth=270.0, elevation=0.0), -E, atol=TOL)


def test_elevation_minus_90_looks_straight_down_and_positive_is_up():
    np.testing.assert_allclose(centre_ray_ned("azimuth-elevation", azimuth=0.0, elevation=-90.0), D, atol=TOL)
    np.testing.assert_allclose(
        centre_ray_ned("azimuth-elevation", azimuth=0.0, elevation=30.0),
        [math.cos(math.radians(30)), 0, -math.sin(math.radians(30))],
        atol=TOL,
    )
    # azimuth first, then elevation about the turned axis: az 90, el -30 is east and down
    np.testing.assert_allclose(
        centre_ray_ned("azimuth-elevation", azimuth=90.0, elevation=-30.0),
        [0, math.cos(math.radians(30)), math.sin(math.radians(30))],
        atol=TOL,
    )


def test_angles_follow_the_aircraft_attitude():
    # heading 90 (east): the nose looks east, azimuth 90 then looks south
    np.testing.assert_allclose(
        centre_ray_ned("azimuth-elevation", heading_deg=90.0, azimuth=90.0, elevation=0.0), -N, atol=TOL
    )


def test_sensor_roll_turns_the_image_not_the_line_of_sight():
    s = FrameSensor(LENS, PRESETS["azimuth-elevation-roll"])
    p0 = Pose.from_deg(40.0, 10.0, 1000.0, angles_deg={"azimuth": 0.0, "elevation": -90.0, "sensor_roll": 0.0})
    p1 = p0.with_angles(sensor_roll=math.radians(90.0))
    c0 = s.line_of_sight(400.5, 500.5, p0).direction_ecef
    c1 = s.line_of_sight(400.5, 500.5, p1).direction_ecef
    np.testing.assert_allclose(c0, c1, atol=TOL)
    # looking down with the image top to the north: the image's right (x) is east; a 90 deg
    # roll, clockwise looking out along the line of sight, turns image right to south
    R = R_ecef_ned(LAT, LON).T
    right0 = R @ s.graph.R_ecef("cam", p0)[:, 0]
    right1 = R @ s.graph.R_ecef("cam", p1)[:, 0]
    np.testing.assert_allclose(right0, E, atol=TOL)
    np.testing.assert_allclose(right1, -N, atol=TOL)


def test_q17_roll_pitch_signs():
    # [Q17]: positive gimbal roll looks left of track, so -45 looks right (east, heading north)
    d = centre_ray_ned("roll-pitch", gimbal_roll=-45.0, gimbal_pitch=0.0)
    np.testing.assert_allclose(d, [0, math.sqrt(0.5), math.sqrt(0.5)], atol=TOL)
    # zero angles: straight down; positive gimbal pitch looks forward (north)
    np.testing.assert_allclose(centre_ray_ned("roll-pitch", gimbal_roll=0.0, gimbal_pitch=0.0), D, atol=TOL)
    d = centre_ray_ned("roll-pitch", gimbal_roll=0.0, gimbal_pitch=10.0)
    assert d[0] > 0 and d[2] > 0


def test_earth_referenced_angles_ignore_the_aircraft_attitude():
    # DJI: gimbal yaw/pitch/roll in NED. Pitch -90 is straight down whatever the airframe does.
    a = dict(gimbal_yaw=0.0, gimbal_pitch=-90.0, gimbal_roll=0.0)
    np.testing.assert_allclose(centre_ray_ned("yaw-pitch-roll", **dict(a)), D, atol=TOL)
    np.testing.assert_allclose(
        centre_ray_ned("yaw-pitch-roll", heading_deg=123.0, pitch_deg=8.0, roll_deg=-15.0, **dict(a)), D, atol=TOL
    )
    # yaw 90, pitch 0: east, whatever the heading
    np.testing.assert_allclose(
        centre_ray_ned("yaw-pitch-roll", heading_deg=-60.0, gimbal_yaw=90.0, gimbal_pitch=0.0, gimbal_roll=0.0),
        E,
        atol=TOL,
    )


def test_custom_gimbal_from_a_file_table_and_its_errors():
    g = gimbal_from_dict(
        {"name": "pan-tilt", "joints": [{"angle": "pan", "axis": "z"}, {"angle": "tilt", "axis": "y"}]}
    )
    s = FrameSensor(LENS, g)
    assert s.angle_names == ("pan", "tilt")
    p = Pose.from_deg(40.0, 10.0, 1000.0, angles_deg={"pan": 90.0, "tilt": 0.0})
    d = R_ecef_ned(LAT, LON).T @ s.line_of_sight(400.5, 500.5, p).direction_ecef
    np.testing.assert_allclose(d, E, atol=TOL)
    with pytest.raises(ValueError, match="preset = 'pan-tilt'"):
        gimbal_from_dict({"preset": "pan-tilt"})
    with pytest.raises(ValueError, match=r"joints\[0\].*axis"):
        gimbal_from_dict({"joints": [{"angle": "pan"}]})
    with pytest.raises(ValueError, match="axis = 'w'"):
        gimbal_from_dict({"joints": [{"angle": "pan", "axis": "w"}]})
    with pytest.raises(ValueError, match="unknown key"):
        gimbal_from_dict({"joints": [{"angle": "pan", "axis": "z"}], "speed": 3})


def test_missing_angle_is_an_error_naming_it():
    s = FrameSensor(LENS, PRESETS["azimuth-elevation"])
    p = Pose.from_deg(40.0, 10.0, 1000.0, angles_deg={"azimuth": 10.0})
    with pytest.raises(ValueError, match="missing angle 'elevation'.*azimuth-elevation"):
        s.line_of_sight(1.0, 1.0, p)
