"""[L18] chain (eq. 1-11) and the bundled limb scenario.

Expected values: the matrices as printed in [L18] (typed in here), closed-form
equatorial geometry, Kepler's laws and finite differences.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.sensors.limb import limb_tangent, line_of_sight_l18
from geoloc.status import Status
from geoloc.workflows.limb_scenario import scenario_from_dict
from geoloc.workflows.scenario import load_scenario

A = 6378137.0
GM = 3.986004418e14
OMEGA_E = 7.292115e-5
SCENARIO = Path(__file__).resolve().parents[2] / "assets" / "scenarios" / "tiangong2_limb.toml"


def paper_Tz(p):  # [L18] eq. 3
    c, s = math.cos(p), math.sin(p)
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])


def paper_Tx(p):  # [L18] eq. 4 (and eq. 2, same form)
    c, s = math.cos(p), math.sin(p)
    return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])


def paper_Ty(p):  # [L18] eq. 5, as printed
    c, s = math.cos(p), math.sin(p)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_chain_matrices_are_the_printed_ones():
    rng = np.random.default_rng(5)
    for _ in range(5):
        yaw, roll, pitch, th, al = rng.uniform(-1.5, 1.5, 5)
        p = rng.normal(size=3) * 7e6
        v = rng.normal(size=3) * 7e3
        c = line_of_sight_l18(p, v, yaw, roll, pitch, th, al)
        np.testing.assert_allclose(c.T_z, paper_Tz(yaw), atol=1e-15)
        np.testing.assert_allclose(c.T_x, paper_Tx(roll), atol=1e-15)
        np.testing.assert_allclose(c.T_y, paper_Ty(pitch), atol=1e-15)
        np.testing.assert_allclose(c.R_body_scs, paper_Tx(th), atol=1e-15)
        np.testing.assert_allclose(c.R_orb_body, paper_Ty(pitch) @ paper_Tx(roll) @ paper_Tz(yaw), atol=1e-15)
        b3 = -p / np.linalg.norm(p)  # eq. 7-10
        b2 = np.cross(b3, v) / np.linalg.norm(np.cross(b3, v))
        b1 = np.cross(b2, b3)
        np.testing.assert_allclose(c.R_ecef_orb, np.column_stack([b1, b2, b3]), atol=1e-15)
        view = np.array([0.0, math.sin(al), math.cos(al)])  # eq. 1
        d = np.column_stack([b1, b2, b3]) @ paper_Ty(pitch) @ paper_Tx(roll) @ paper_Tz(yaw) @ paper_Tx(th) @ view
        np.testing.assert_allclose(c.direction_ecef, d, atol=1e-14)  # eq. 11
        np.testing.assert_allclose(c.R_ecef_scs @ c.R_ecef_scs.T, np.eye(3), atol=1e-14)
        assert c.status == Status.OK


def test_equatorial_orbit_closed_form_tangent():
    """Equatorial circular orbit, slit forward in the equatorial plane: the ellipsoid's section is
    the circle of radius a, so the tangent height is r sin(theta + alpha) - a exactly."""
    r = A + 390e3
    v = math.sqrt(GM / r)
    theta = math.radians(71.0)
    alpha = np.radians([-1.0, -0.3, 0.0, 0.5, 1.2])
    c = line_of_sight_l18([r, 0, 0], [0, v, 0], math.radians(90.0), 0.0, 0.0, theta, alpha)
    # yaw 90 deg: body Y along track (b1 = +y here), so the view is forward and down.
    np.testing.assert_allclose(
        c.direction_ecef, np.stack([-np.cos(theta + alpha), np.sin(theta + alpha), 0 * alpha], -1), atol=1e-15
    )
    t = limb_tangent(c.origin_ecef, c.direction_ecef)
    h = r * np.sin(theta + alpha) - A
    ok = h > 0
    assert np.array_equal(t.status == Status.OK, ok) and np.all(t.status[~ok] == Status.HITS_EARTH)
    # 1e-6 m: both methods are exact here; float rounding of 6.8e6 m coordinates is ~1e-9 m.
    np.testing.assert_allclose(t.exact_h[ok], h[ok], atol=1e-6)
    np.testing.assert_allclose(t.tangent_h[ok], h[ok], atol=1e-6)
    np.testing.assert_allclose(t.delta_a[ok], h[ok], atol=1e-6)
    # Tangent point: ahead along track, at range r cos(theta + alpha).
    np.testing.assert_allclose(t.exact_s[ok], r * np.cos(theta + alpha[ok]), atol=1e-3)


def test_attitude_signs_follow_the_printed_matrices():
    r = A + 390e3
    p, v = [r, 0, 0], [0, 7600.0, 0]  # b1 = +y (forward), b2 = -z, b3 = -x (nadir)
    a = math.radians(10)
    # Pitch alone tilts the nadir view towards +X_orb (forward): printed eq. 5, third column (s, 0, c).
    d = line_of_sight_l18(p, v, 0.0, 0.0, a, 0.0, 0.0).direction_ecef
    np.testing.assert_allclose(d, [-math.cos(a), math.sin(a), 0.0], atol=1e-15)
    # Roll alone tilts it towards +Y_orb = -orbit normal = -z here (eq. 4, third column (0, s, c)).
    d = line_of_sight_l18(p, v, 0.0, a, 0.0, 0.0, 0.0).direction_ecef
    np.testing.assert_allclose(d, [-math.cos(a), 0.0, -math.sin(a)], atol=1e-15)
    # Mounting and view angle add up (both about the sensor/body X axis, eq. 1-2).
    d1 = line_of_sight_l18(p, v, 0.3, 0.02, -0.01, 1.2, 0.03).direction_ecef
    d2 = line_of_sight_l18(p, v, 0.3, 0.02, -0.01, 1.23, 0.0).direction_ecef
    np.testing.assert_allclose(d1, d2, atol=1e-15)


def test_chain_invalid_and_broadcast():
    p = np.array([A + 4e5, 0, 0])
    c = line_of_sight_l18(
        np.stack([p, p, [np.nan, 0, 0]]), np.stack([p, [0, 7e3, 0], [0, 7e3, 0]]), 0.0, 0.0, 0.0, 1.2, 0.0
    )
    assert list(c.status) == [Status.INVALID_INPUT, Status.OK, Status.INVALID_INPUT]
    assert np.isnan(c.direction_ecef[0]).all()
    c = line_of_sight_l18(np.tile(p, (4, 1, 1)), [0, 7e3, 0], 0.0, 0.0, 0.0, 1.2, np.linspace(-0.02, 0.02, 7))
    assert c.direction_ecef.shape == (4, 7, 3) and c.R_ecef_scs.shape == (4, 7, 3, 3)
    c = line_of_sight_l18(p, [0, 7e3, 0], 0.0, np.nan, 0.0, 1.2, 0.0)
    assert c.status == Status.INVALID_INPUT


def test_bundled_orbit_is_keplerian():
    sc = load_scenario(SCENARIO)
    t = np.linspace(0, 2 * math.pi / sc.mean_motion, 2001)  # one full orbit
    p, v = sc.state_ecef(t)
    r = A + 390e3
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), r, rtol=1e-14)
    # Inertial speed sqrt(GM / r) (vis-viva, circular): add back Earth rotation omega x r.
    v_in = v + np.cross([0, 0, OMEGA_E], p)
    np.testing.assert_allclose(np.linalg.norm(v_in, axis=-1), math.sqrt(GM / r), rtol=1e-12)
    # Highest geocentric latitude = inclination 42.8 deg (sampling 2001 points/orbit: < 0.01 deg short).
    assert np.degrees(np.arcsin(p[:, 2] / r)).max() == pytest.approx(42.8, abs=0.01)
    # ECEF velocity is the time derivative of ECEF position (central differences, dt = 0.01 s:
    # truncation ~ r n^3 dt^2 / 6 ~ 1e-6 m/s, rounding ~ 1e-9 m / 0.01 s; 1e-4 m/s tolerance).
    dt = 0.01
    pp, _ = sc.state_ecef(t[:50] + dt)
    pm, _ = sc.state_ecef(t[:50] - dt)
    np.testing.assert_allclose((pp - pm) / (2 * dt), v[:50], atol=1e-4)


def test_bundled_slit_covers_10_to_60_km_in_every_frame():
    sc = load_scenario(SCENARIO)
    assert (sc.n_frames, sc.n_pixels) == (1137, 48)  # [L18] section 4: 1 137 frames
    assert math.degrees(sc.fov) == pytest.approx(2.4)
    chain, r = sc.solve()
    h = np.where(r.status == Status.OK, r.exact_h, np.nan)
    assert np.all(np.nanmin(h, axis=1) <= 10e3) and np.all(np.nanmax(h, axis=1) >= 60e3)
    # Heights rise with alpha (upwards along the slit); only bottom pixels hit the Earth.
    hits = r.status == Status.HITS_EARTH
    assert np.all(np.isin(r.status, [Status.OK, Status.HITS_EARTH]))
    assert np.all(np.diff(hits.astype(int), axis=1) <= 0)
    dh = np.diff(h, axis=1)
    assert np.all(dh[np.isfinite(dh)] > 0)
    # The forward slit: the tangent point is ahead of the platform along its velocity.
    p, v = sc.state_ecef()
    ahead = np.einsum("fpi,fi->fp", r.exact_ecef - p[:, None, :], v)
    assert np.all(ahead[~hits] > 0)
    # [L18] vs exact on the whole scenario: within the documented bound (< 1 cm below 100 km).
    assert np.nanmax(np.abs(r.h_difference)) < 0.01


def _base():
    return {
        "name": "t",
        "orbit": {"altitude_m": 390e3, "inclination_deg": 42.8},
        "frames": {"n": 3, "interval_s": 2.0},
        "sensor": {"theta_mount_deg": 71.3, "fov_deg": 2.4, "n_pixels": 8},
    }


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["orbit"].pop("altitude_m"), "missing orbit.altitude_m"),
        (lambda d: d["orbit"].update(altitude_m=-5.0), "orbit.altitude_m = -5.0"),
        (lambda d: d["orbit"].update(inclination_deg="high"), "orbit.inclination_deg = 'high'"),
        (lambda d: d["sensor"].update(fov_deg=200.0), "sensor.fov_deg = 200.0"),
        (lambda d: d["orbit"].update(inclination_deg=float("nan")), "orbit.inclination_deg = nan"),
        (lambda d: d["sensor"].update(n_pixels=0), "n_pixels = 0"),
        (lambda d: d["frames"].update(n=2.5), "frames.n = 2.5"),
        (lambda d: d["sensor"].update(focal=1.0), "unknown key sensor.focal"),
        (lambda d: d.update(extra={}), "unknown section or key 'extra'"),
    ],
)
def test_scenario_errors_name_field_and_value(mutate, message):
    d = _base()
    scenario_from_dict(d)  # the base is valid
    mutate(d)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")):
        scenario_from_dict(d, source="x.toml")


def test_scenario_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_scenario(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[orbit\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_scenario(bad)


def test_the_l18_chain_hands_surfaces_the_common_line_of_sight():
    # the limb instrument's line of sight is the LineOfSight every surface takes: a ray
    # built tangent-ish from 390 km, looking 20 deg below the local horizontal, meets the
    # ellipsoid (the HeightSurface answer lies on the chain's own line)
    from geoloc.surfaces.base import LineOfSight
    from geoloc.surfaces.height import HeightSurface

    p = geodetic_to_ecef(0.3, 1.1, 390e3)
    up = p / np.linalg.norm(p)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    v = 7.6e3 * east
    c = line_of_sight_l18(p, v, 0.0, 0.0, 0.0, np.deg2rad(-70.0), 0.0)
    los = c.los
    assert isinstance(los, LineOfSight) and int(los.status) == 0
    hit = HeightSurface(0.0, "geodetic").intersect(los)
    on_line = np.cross(hit.ecef - c.origin_ecef, c.direction_ecef)
    # 1e-6 m off the line at 1e6 m range: float64 rounding
    assert int(hit.status) == 0 and np.linalg.norm(on_line) < 1e-6
