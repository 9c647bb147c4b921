"""Light-time and aberration of light (geoloc.corrections.lighttime) against closed forms and Rugged's figures.

- Aberration: the classical angle is atan(v/c) for a velocity across the line of sight (the
  Galilean sum c u + v); the relativistic one obeys cos(t') = (cos(t) + b) / (1 + b cos(t))
  between the directions to the source and the velocity (the relativistic aberration of any
  text on special relativity), so sin(t') = b across it.
- Light-time: the ground turns by omega_E rho / c while the light crosses rho; the hit moves
  east by that angle times its distance from the axis, (N + h) cos(lat).
- Rugged (src/test/java/org/orekit/rugged/api/RuggedTest.java, testLightTimeCorrection): 1.23-1.27 m
  between the hits with and without light-time, a line of 400 pixels +-10 deg about nadir from a
  spacecraft at |r| = 7176419.526 m; testAberrationOfLightCorrection: 20.0-20.5 m. Neither test
  states the latitude of its line; the band of the first holds only within 8 deg of the equator,
  that of the second between 35 and 45 deg (a circular velocity due north), where each is checked.
"""

from __future__ import annotations

import numpy as np
import pytest

from geoloc.corrections.lighttime import (
    C_LIGHT,
    OMEGA_EARTH,
    aberration,
    apparent_direction,
    inertial_velocity,
    light_time_line,
    light_time_point,
)
from geoloc.geodesy.ellipsoid import A, E2, ecef_to_geodetic, geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_ned
from geoloc.surfaces.height import ray_geodetic_height

C = 299792458.0  # m/s, exact
OMEGA = 7.292115e-5  # rad/s, WGS-84


def test_constants():
    assert C_LIGHT == C and OMEGA_EARTH == OMEGA


@pytest.mark.parametrize("relativistic", [False, True])
def test_aberration_across_the_line_of_sight(relativistic):
    v = np.array([7500.0, 0.0, 0.0])
    seen = np.array([0.0, 0.0, -1.0])  # nadir, velocity across it
    true = aberration(seen, v, relativistic=relativistic)
    ang = np.arctan2(np.linalg.norm(np.cross(true, seen)), true @ seen)
    b = 7500.0 / C
    expected = np.arcsin(b) if relativistic else np.arctan(b)  # 25.0 microradians
    assert ang == pytest.approx(expected, rel=1e-9)
    assert ang == pytest.approx(25.0e-6, rel=1e-3)
    # the sensor sees the scene displaced towards its velocity: the light came from behind
    assert true[0] < 0.0
    assert np.linalg.norm(true) == pytest.approx(1.0, abs=1e-15)


def test_relativistic_aberration_formula_at_all_angles():
    b = 3e-3  # a large beta, so that the relativistic terms show
    v = np.array([b * C, 0.0, 0.0])
    for t in np.deg2rad([1.0, 30.0, 60.0, 90.0, 120.0, 179.0]):
        true = np.array([np.cos(t), np.sin(t), 0.0])  # towards the source, angle t to the velocity
        seen = apparent_direction(true, v, relativistic=True)
        cos_seen = (np.cos(t) + b) / (1.0 + b * np.cos(t))
        assert seen[0] == pytest.approx(cos_seen, abs=1e-15)
        np.testing.assert_allclose(aberration(seen, v, relativistic=True), true, atol=1e-15)
        # classical and relativistic agree to b^2
        cl = aberration(seen, v)
        assert np.linalg.norm(cl - true) < 2 * b * b


def test_aberration_on_the_ground_from_700_km():
    lat, lon = np.deg2rad(40.0), np.deg2rad(10.0)
    o = geodetic_to_ecef(lat, lon, 700e3)
    R = R_ecef_ned(lat, lon)
    v_in = R @ np.array([7500.0, 0.0, 0.0])  # northward, inertial
    seen = R @ np.array([0.0, 0.0, 1.0])
    p_seen = ray_geodetic_height(o, seen, 0.0).ecef
    p_true = ray_geodetic_height(o, aberration(seen, v_in), 0.0).ecef
    shift = np.linalg.norm(p_true - p_seen)
    # closed form: range x atan(v/c), 700 km x 25.0 urad = 17.51 m (the ground is level at nadir;
    # the Earth's curvature changes it by 700/6371 x 25 urad^2: nothing)
    assert shift == pytest.approx(700e3 * np.arctan(7500.0 / C), rel=1e-4)
    assert 17.0 < shift < 20.0
    # towards the south: behind the motion
    assert (R.T @ (p_true - p_seen))[0] < 0.0


def test_inertial_velocity_adds_the_earth_rotation():
    r = geodetic_to_ecef(0.0, np.deg2rad(30.0), 0.0)
    v = inertial_velocity(r, np.zeros(3))
    # a point on the equator moves east at omega a = 465.10 m/s
    assert np.linalg.norm(v) == pytest.approx(OMEGA * A, rel=1e-12)
    assert v @ np.array([-np.sin(np.deg2rad(30.0)), np.cos(np.deg2rad(30.0)), 0.0]) == pytest.approx(OMEGA * A)
    assert inertial_velocity(np.zeros((4, 3)), np.ones((4, 3))).shape == (4, 3)


@pytest.mark.parametrize("lat_deg", [0.0, 35.0, 60.0])
def test_light_time_turns_the_ground_east(lat_deg):
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(80.0)
    o = geodetic_to_ecef(lat, lon, 700e3)
    d = R_ecef_ned(lat, lon) @ np.array([0.0, 0.0, 1.0])
    raw = ray_geodetic_height(o, d, 0.0).ecef
    rho = np.linalg.norm(raw - o)
    moved = light_time_point(o, raw)
    # omega_E x rho / c x (N + h) cos(lat): 1.09 m at the equator from 700 km (2.33 ms)
    N = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
    expected = OMEGA * rho / C * N * np.cos(lat)
    assert np.linalg.norm(moved - raw) == pytest.approx(expected, rel=1e-9)
    assert rho / C == pytest.approx(2.33e-3, rel=0.01)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    assert (moved - raw) @ east == pytest.approx(expected, rel=1e-6)
    # on a surface of revolution, meeting the turned line is turning the hit
    o2, d2 = light_time_line(o, d, raw)
    hit2 = ray_geodetic_height(o2, d2, 0.0).ecef
    assert np.linalg.norm(hit2 - moved) < 1e-6
    assert ecef_to_geodetic(moved)[2] == pytest.approx(0.0, abs=1e-6)


def test_rugged_light_time_band_near_the_equator():
    # RuggedTest.testLightTimeCorrection: 1.23 < shift < 1.27 m across the line (+-10 deg about nadir),
    # spacecraft at |r| = 7176419.526 m (its getScToInertial translation)
    for lat_deg in (0.0, 5.0):
        lat, lon = np.deg2rad(lat_deg), 0.3
        up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        o = 7176419.526 * up
        R = R_ecef_ned(lat, lon)
        for across in np.deg2rad([-10.0, 0.0, 10.0]):
            d = R @ np.array([0.0, np.sin(across), np.cos(across)])
            raw = ray_geodetic_height(o, d, 0.0).ecef
            shift = np.linalg.norm(light_time_point(o, raw) - raw)
            assert 1.23 < shift < 1.27


@pytest.mark.parametrize("lat_deg", [35.0, 40.0, 45.0])
def test_rugged_aberration_band_at_mid_latitudes(lat_deg):
    # RuggedTest.testAberrationOfLightCorrection: 20.0 < shift < 20.5 m across the line (+-10 deg
    # about nadir), the same spacecraft (|r| = 7176419.526 m, a near-circular orbit of EIGEN-5C's
    # mu, inclination 98.6 deg: moving about north). Here the velocity is the circular one, due
    # north; the band then holds between 35 and 45 deg of latitude (at the equator the nadir pixel
    # gives 19.85 m, at 55 deg the edges 20.56 m), and the test states it there, as the light-time
    # band is stated near the equator: neither Rugged test gives its line's latitude, and its
    # yaw-steered attitude and real orbit move both figures by a few per cent, so one latitude for
    # both is not expected of this simplified geometry. What it pins: the size of the shift to 1 %.
    mu = 3.986004415e14  # m^3/s^2, EIGEN-5C (Orekit's Constants.EIGEN5C_EARTH_MU)
    r = 7176419.526
    lat, lon = np.deg2rad(lat_deg), 0.3
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    o = r * up
    R = R_ecef_ned(lat, lon)
    v_in = R @ np.array([np.sqrt(mu / r), 0.0, 0.0])
    for across in np.deg2rad([-10.0, -5.0, 0.0, 5.0, 10.0]):
        d = R @ np.array([0.0, np.sin(across), np.cos(across)])
        seen = ray_geodetic_height(o, d, 0.0).ecef
        true = ray_geodetic_height(o, aberration(d, v_in), 0.0).ecef
        assert 20.0 < np.linalg.norm(true - seen) < 20.5


def test_vectorised_and_nan():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(5, 7, 3))
    v = rng.normal(size=(7, 3)) * 7000.0
    for rel in (False, True):
        out = aberration(d, v, relativistic=rel)
        assert out.shape == (5, 7, 3)
        np.testing.assert_allclose(
            apparent_direction(out, v, relativistic=rel), d / np.linalg.norm(d, axis=-1, keepdims=True), atol=2e-15
        )
    assert np.isnan(aberration(np.array([np.nan, 0, 1.0]), np.zeros(3))).all()
    assert np.isnan(aberration(np.zeros(3), np.zeros(3))).all()
    pts = light_time_point(np.zeros((3, 3)), rng.normal(size=(3, 3)) * 1e6)
    assert pts.shape == (3, 3)


def test_light_time_source_inverts_the_point():
    from geoloc.corrections.lighttime import light_time_source

    rng = np.random.default_rng(3)
    lat, lon = rng.uniform(-1.2, 1.2, 20), rng.uniform(-3, 3, 20)
    o = geodetic_to_ecef(lat, lon, 700e3)
    g = geodetic_to_ecef(lat + rng.uniform(-0.05, 0.05, 20), lon + rng.uniform(-0.05, 0.05, 20), 100.0)
    src = light_time_source(o, g)
    # turning the source east by omega rho / c, rho its own range, gives the ground point back
    np.testing.assert_allclose(light_time_point(o, src), g, rtol=0, atol=1e-8)
    assert np.all(np.linalg.norm(src - g, axis=-1) > 0.1)  # metres apart before the correction
