"""Pushbroom rigorous model [L12 eq. 1-2]: closed-form cases, the paper's numbers, inverse, errors."""

import copy
import math
import tomllib

import numpy as np
import pytest
from pyproj import Transformer

from geoloc.assets import asset_path
from geoloc.geodesy.ellipsoid import A, B
from geoloc.sensors.pushbroom import GM_EARTH, OMEGA_EARTH, LookAngles, PushbroomSensor
from geoloc.status import Status
from geoloc.pipeline import at_height

SCEN = tomllib.loads(asset_path("scenarios", "zy3_nadir.toml").read_text())
IFOV = 7.0e-6 / 1.7  # [L12] Table 2: 7 um pixels behind a 1700 mm lens


def ideal(**camera):
    """The bundled scenario with zero attitude, calibration and lever arm, ideal linear CCD."""
    d = copy.deepcopy(SCEN)
    d["attitude"] = {"sample_interval_s": 0.25}
    cam = d["camera"]
    for k in ("cal_roll_deg", "cal_pitch_deg", "cal_yaw_deg", "lever_arm_body_m"):
        cam.pop(k)
    cam["tan_psi_x_poly"] = [0.0, -IFOV]
    cam["tan_psi_y_poly"] = [0.0]
    cam.update(camera)
    return d


@pytest.fixture(scope="module")
def zy3():
    return PushbroomSensor.from_dict(SCEN)


def test_orbit_matches_the_scenario_elements():
    """Radius a + 505 984 m, inertial speed sqrt(GM/r), inclination 97.421 deg ([L12] Table 1), descending."""
    s = PushbroomSensor.from_dict(SCEN)
    o = s.orbit
    r = np.linalg.norm(o.position, axis=-1)
    assert np.allclose(r, A + 505984.0, atol=1e-6)  # metres; float64 rounding at 7e6 m is 1e-9
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    v_inertial = o.velocity + np.cross(w, o.position)  # the frames coincide in orientation at each instant
    assert np.allclose(np.linalg.norm(v_inertial, axis=-1), math.sqrt(GM_EARTH / r[0]), rtol=1e-12)
    h = np.cross(o.position, v_inertial)
    # angular momentum is inertial; at t = 0 the inertial frame coincides with ECEF
    i0 = np.argmin(np.abs(o.t))
    assert math.degrees(math.acos(h[i0, 2] / np.linalg.norm(h[i0]))) == pytest.approx(97.421, abs=1e-9)
    assert np.all(np.diff(o.position[:, 2]) < 0)  # descending: z falls with time


def test_centre_pixel_of_ideal_sensor_is_the_geocentric_nadir_point():
    """Zero attitude: the centre detector at the centre line looks along -P/|P| ([L18 eq. 7-10] b3).

    At h = 0 that ray meets the ellipsoid at r_e(phi_c) P/|P|, with the ellipse radius at
    geocentric latitude phi_c, r_e = a b / sqrt(b^2 cos^2 + a^2 sin^2): numpy only; and the
    scenario puts the satellite over its centre, so pyproj must return the scenario centre.
    """
    s = PushbroomSensor.from_dict(ideal())
    row, col = (s.rows + 1) / 2, (s.cols + 1) / 2
    g = at_height(s, row, col, 0.0)
    p, _ = s.orbit.state(0.0)
    phic = math.atan2(p[2], math.hypot(p[0], p[1]))
    re = A * B / math.sqrt((B * math.cos(phic)) ** 2 + (A * math.sin(phic)) ** 2)
    assert np.allclose(g.ecef, re * p / np.linalg.norm(p), atol=1e-6)  # 1 um: Newton tolerance in h
    lon, lat, h = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*g.ecef)
    assert lat == pytest.approx(SCEN["orbit"]["centre_lat_deg"], abs=1e-10)  # ~1e-5 m
    assert lon == pytest.approx(SCEN["orbit"]["centre_lon_deg"], abs=1e-10)
    assert h == pytest.approx(0.0, abs=1e-5)


def test_roll_sign_and_size_closed_form():
    """Roll +1 deg (right wing down, [Q17 eq. 6] order) makes a nadir camera look left.

    The nadir point then lies 1 deg to the right of the boresight: in the ideal
    CCD tan psi_X = -IFOV (j - j0), so it is imaged at column j0 + tan(1 deg) / IFOV
    on the centre line, exactly.
    """
    d = ideal()
    d["attitude"]["roll_deg"] = 1.0
    s = PushbroomSensor.from_dict(d)
    g0 = at_height(PushbroomSensor.from_dict(ideal()), (s.rows + 1) / 2, (s.cols + 1) / 2, 0.0)
    row, col, st = s.ground_to_pixel(g0.lat, g0.lon, g0.h)
    assert st == Status.OK
    assert col == pytest.approx((s.cols + 1) / 2 + math.tan(math.radians(1.0)) / IFOV, abs=1e-5)
    assert row == pytest.approx((s.rows + 1) / 2, abs=1e-5)  # 1e-5 px: the inverse stops at 1e-6 line


def test_along_track_look_angle_shifts_the_line():
    """tan psi_Y = one IFOV: the CCD looks one pixel forward, so ground points are seen ~1 line earlier.

    The along-track and across-track ground samples differ by < 1 % (scenario line
    period), so the shift is -1 line within 1 %.
    """
    s0 = PushbroomSensor.from_dict(ideal())
    s1 = PushbroomSensor.from_dict(ideal(tan_psi_y_poly=[IFOV]))
    r = np.array([100.0, 12288.5, 24000.0])
    c = np.array([5.0, 12288.5, 24500.0])
    g = at_height(s0, r, c, 500.0)
    r1, c1, st = s1.ground_to_pixel(g.lat, g.lon, g.h)
    assert np.all(st == Status.OK)
    assert np.allclose(r1 - r, -1.0, atol=0.01)
    assert np.allclose(c1 - c, 0.0, atol=0.01)


def test_ground_sample_distance_swath_and_field_of_view_match_l12(zy3):
    """[L12] Table 2: 2.1 m, 52 km swath, 6 deg field of view for the nadir camera.

    At the centre the across-track sample must also equal H * IFOV exactly to first
    order (H: camera-to-ground distance along the ray; the ellipsoid normal is 0.19 deg
    off the geocentric ray: relative effect 6e-6, plus the attitude < 0.03 deg).
    """
    r0, c0 = (zy3.rows + 1) / 2, (zy3.cols + 1) / 2
    g = at_height(zy3, [r0, r0 + 1, r0, r0, r0], [c0, c0, c0 + 1, 1, zy3.cols], 300.0)
    e = g.ecef
    across = np.linalg.norm(e[2] - e[0])
    along = np.linalg.norm(e[1] - e[0])
    assert across == pytest.approx(g.slant_range[0] * IFOV, rel=2e-5)
    assert across == pytest.approx(2.1, abs=0.05)  # [L12]: "2.1 m" (2.08 m at 505 km over a; 2.11 m here)
    assert along == pytest.approx(across, rel=0.01)  # square pixels by the scenario's line period
    swath = np.linalg.norm(e[4] - e[3])
    assert swath / 1000 == pytest.approx(52.0, abs=1.0)  # [L12] Table 2: 52 km
    fov = math.degrees(2 * math.atan(zy3.cols / 2 * IFOV))
    assert fov == pytest.approx(6.0, abs=0.25)  # [L12] Table 2: 6 deg (5.80 deg from 24576 x 7 um / 1.7 m)


def test_ground_to_pixel_inverts_locate(zy3):
    rng = np.random.default_rng(7)
    r = rng.uniform(0.5, zy3.rows + 0.5, 200)
    c = rng.uniform(0.5, zy3.cols + 0.5, 200)
    h = rng.uniform(-100, 2000, 200)
    g = at_height(zy3, r, c, h)
    assert np.all(g.status == Status.OK)
    rr, cc, st = zy3.ground_to_pixel(g.lat, g.lon, g.h)
    assert np.all(st == Status.OK)
    # 1e-6 px: the iteration stops at 1e-6 line; ray x surface is solved to 1 um
    assert np.max(np.abs(rr - r)) < 1e-5 and np.max(np.abs(cc - c)) < 1e-5


def test_look_angle_table_interpolates_and_inverts():
    la = LookAngles.from_polynomial(101, [0.01, -1e-4, 2e-8], [1e-5, 0.0, 1e-9])
    j = np.array([1.0, 17.25, 50.5, 101.0, -3.0, 104.0])
    s = j - 51
    want_x = 0.01 - 1e-4 * s + 2e-8 * s**2
    # linear between detectors: error <= f''/8 = 2 * 2e-8 / 8 = 5e-9
    assert np.allclose(la.tan_x(j[:4]), want_x[:4], atol=5e-9)
    # beyond the ends: the end segments continued linearly
    assert la.tan_x(-3.0) == pytest.approx(la.tan_psi_x[0] - 4 * (la.tan_psi_x[1] - la.tan_psi_x[0]), abs=1e-15)
    assert la.tan_x(104.0) == pytest.approx(la.tan_psi_x[-1] + 3 * (la.tan_psi_x[-1] - la.tan_psi_x[-2]), abs=1e-15)
    assert np.allclose(la.col_of_tan_x(la.tan_x(j)), j, atol=1e-9)
    u = la.direction(j)
    assert u.shape == (6, 3) and np.all(u[:, 2] == -1)


def test_bad_inputs_give_clear_errors_and_status():
    d = copy.deepcopy(SCEN)
    d["camera"]["focal_length_m"] = -1.7
    with pytest.raises(ValueError, match="focal_length_m"):
        PushbroomSensor.from_dict(d)
    d = copy.deepcopy(SCEN)
    d["orbit"]["inclination_pct"] = 3
    with pytest.raises(ValueError, match="inclination_pct"):
        PushbroomSensor.from_dict(d)
    d = copy.deepcopy(SCEN)
    d["camera"]["detectors"] = 2.5
    with pytest.raises(ValueError, match="detectors"):
        PushbroomSensor.from_dict(d)
    with pytest.raises(ValueError, match="tan_psi_x"):
        LookAngles(np.array([0.0, 1.0, 0.5]), np.zeros(3))
    s = PushbroomSensor.from_dict(SCEN)
    row, col, st = s.ground_to_pixel(
        np.array([np.nan, math.radians(60.0)]), np.array([0.0, math.radians(-84.2)]), np.array([0.0, 0.0])
    )
    assert st[0] == Status.INVALID_INPUT and np.isnan(row[0])
    # 60 N is ~2600 km along track, far outside the orbit samples of this scene
    assert st[1] != Status.OK and np.isnan(col[1])
    los = s.line_of_sight(np.array([1.0, 1e7]), np.array([1.0, 1.0]))
    assert los.status.tolist() == [Status.OK, Status.INVALID_INPUT]
