"""ENU, NED and AER points (geoloc.geodesy.local) against pymap3d, an outside oracle.

pymap3d is called with ``deg=False`` so that both sides get the same radians,
except in the tests of the ``_deg`` front ends, which use pymap3d's default
degrees. Observers are drawn over the whole globe (poles and antimeridian
included), at heights from -10 km to 100 km, targets up to 1000 km away in any
direction (so from ~1000 km below the ellipsoid to ~1100 km above it).

The poles need no exclusion: pymap3d 3.2 is not singular there (its
ecef2geodetic special-cases points on the axis, and its ENU axes at a pole are
set by lon0 exactly as ours are; measured: same agreement at lat0 = +-90 deg,
90 - 1e-6 deg and elsewhere), so the strategies include +-pi/2 and explicit
examples pin them. Two things of pymap3d's own are allowed for instead, each
where it is used: ``enu2aer`` snaps ENU components below 1 mm to zero, and its
ecef2geodetic (You 2000, one correction step) loses latitude accuracy away
from the ellipsoid (measured: 3e-9 m within 20 km, 1.5e-6 m at |h| = 100 km,
1.3 cm at 1100 km up, 2.3 cm at 1000 km down; ours stays at 3e-9 m).
"""

import math

import numpy as np
import pymap3d as pm
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from geoloc.geodesy import local as L
from geoloc.geodesy.ellipsoid import (
    B,
    ecef_to_geodetic,
    geodetic_to_ecef,
    meridian_radius,
)

# Positions: 3e-8 m. Both sides form ECEF by the same closed form [Q17 eq. 4]
# (pymap3d writes R_N as a^2 / hypot(a cos phi, b sin phi) and rounds b to
# 6356752.31424518 m, one ulp off), subtract the origin and rotate, so they
# differ by rounding of ECEF coordinates of up to ~7.4e6 m, whose ulp is
# 2^-30 m = 9.3e-10 m. Measured worst over 10^6 random cases: 5.1e-9 m
# (5.5 ulp); 3e-8 m is 32 ulp, far below anything physical (GRS80's b would
# move points by 1e-4 m).
TOL_M = 3e-8
# Angles are compared as the distance they move the target: d(az) * horizontal
# range, d(el) * slant range (the same 3e-8 m).

lat_rad = st.floats(-math.pi / 2, math.pi / 2, allow_nan=False)
lon_rad = st.floats(-math.pi, math.pi, allow_nan=False)
h0_m = st.floats(-10_000.0, 100_000.0, allow_nan=False)
az_rad = st.floats(0.0, 2 * math.pi, allow_nan=False, exclude_max=True)
el_rad = st.floats(-math.pi / 2, math.pi / 2, allow_nan=False)
srange_m = st.floats(0.0, 1.0e6, allow_nan=False)

POLE = math.pi / 2
NEAR_POLE = math.radians(90.0 - 1e-6)


def _ang(a, b):
    """Signed difference of two angles wrapped into [-pi, pi)."""
    return (np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi


def _target(az, el, s, lat0, lon0, h0):
    """A target at (az, el, s) from the origin: ENU, ECEF and geodetic (ours)."""
    enu = L.aer_to_enu(az, el, s)
    xyz = L.enu_to_ecef(enu, lat0, lon0, h0)
    return enu, xyz, ecef_to_geodetic(xyz)


def _dist(p, q):
    return float(np.linalg.norm(np.asarray(p, float) - np.asarray(q, float)))


def _geodetic_gap_m(a, b):
    """Distance [m] between the points two (lat, lon, h) triples name (poles and lon wrap safe)."""
    return _dist(geodetic_to_ecef(*a), geodetic_to_ecef(*b))


def _aer_gaps_m(ours, ref):
    """(d_az * horizontal range, d_el * slant range, d_range) in metres."""
    az, el, s = (float(v) for v in ours)
    raz, rel, rs = (float(v) for v in ref)
    return (abs(float(_ang(az, raz))) * s * math.cos(el), abs(el - rel) * s, abs(s - rs))


origins = [lat_rad, lon_rad, h0_m]
aers = [az_rad, el_rad, srange_m]


# --- 1. against pymap3d: ENU and NED (metres out) -------------------------------------


@settings(max_examples=400, deadline=None)
@given(*aers, *origins)
@example(0.3, -0.2, 1.0e6, POLE, 0.7, 5000.0)
@example(2.0, 0.1, 1.0e6, -POLE, -3.0, 5000.0)
@example(4.0, -1.0, 9.0e5, NEAR_POLE, math.pi, 100_000.0)
@example(1.0, 0.0, 1.0e6, 0.3, math.pi, -10_000.0)
def test_enu_and_ned_match_pymap3d(az, el, s, lat0, lon0, h0):
    _, xyz, (lat, lon, h) = _target(az, el, s, lat0, lon0, h0)
    x, y, z = (float(c) for c in xyz)

    enu = L.ecef_to_enu(xyz, lat0, lon0, h0)
    assert _dist(enu, pm.ecef2enu(x, y, z, lat0, lon0, h0, deg=False)) <= TOL_M
    assert _dist(L.enu_to_ecef(enu, lat0, lon0, h0), pm.enu2ecef(*enu, lat0, lon0, h0, deg=False)) <= TOL_M
    assert (
        _dist(L.geodetic_to_enu(lat, lon, h, lat0, lon0, h0), pm.geodetic2enu(lat, lon, h, lat0, lon0, h0, deg=False))
        <= TOL_M
    )

    ned = L.ecef_to_ned(xyz, lat0, lon0, h0)
    assert _dist(ned, pm.ecef2ned(x, y, z, lat0, lon0, h0, deg=False)) <= TOL_M
    assert _dist(L.ned_to_ecef(ned, lat0, lon0, h0), pm.ned2ecef(*ned, lat0, lon0, h0, deg=False)) <= TOL_M
    assert (
        _dist(L.geodetic_to_ned(lat, lon, h, lat0, lon0, h0), pm.geodetic2ned(lat, lon, h, lat0, lon0, h0, deg=False))
        <= TOL_M
    )


# --- 2. against pymap3d: AER ----------------------------------------------------------


@settings(max_examples=400, deadline=None)
@given(*aers, *origins)
@example(0.3, -0.2, 1.0e6, POLE, 0.7, 5000.0)
@example(5.0, 0.4, 7.0e5, -NEAR_POLE, 1.0, 0.0)
@example(3.0, -0.05, 1.0e6, 0.5, -math.pi, 18_000.0)
def test_aer_matches_pymap3d(az, el, s, lat0, lon0, h0):
    enu, xyz, (lat, lon, h) = _target(az, el, s, lat0, lon0, h0)
    # pymap3d's enu2aer sets ENU components below 1 mm to zero before taking
    # the angles (test_pymap3d_snaps_millimetres_we_do_not); compare where it does not
    assume(np.all(np.abs(enu) >= 2e-3))
    x, y, z = (float(c) for c in xyz)

    assert _dist(L.aer_to_enu(az, el, s), pm.aer2enu(az, el, s, deg=False)) <= TOL_M
    assert _dist(L.aer_to_ecef(az, el, s, lat0, lon0, h0), pm.aer2ecef(az, el, s, lat0, lon0, h0, deg=False)) <= TOL_M

    cases = {
        "enu_to_aer": (L.enu_to_aer(enu), pm.enu2aer(*(float(c) for c in enu), deg=False)),
        "ecef_to_aer": (L.ecef_to_aer(xyz, lat0, lon0, h0), pm.ecef2aer(x, y, z, lat0, lon0, h0, deg=False)),
        "geodetic_to_aer": (
            L.geodetic_to_aer(lat, lon, h, lat0, lon0, h0),
            pm.geodetic2aer(lat, lon, h, lat0, lon0, h0, deg=False),
        ),
    }
    for name, (ours, ref) in cases.items():
        assert max(_aer_gaps_m(ours, ref)) <= TOL_M, (name, _aer_gaps_m(ours, ref))
        assert 0.0 <= ours[0] < 2 * math.pi


# --- 3. against pymap3d: geodetic out -------------------------------------------------


@settings(max_examples=400, deadline=None)
@given(*aers, *origins)
@example(0.3, -0.2, 1.0e6, POLE, 0.7, 5000.0)
@example(1.0, math.pi / 2, 1.0e6, -POLE, 0.0, 100_000.0)  # straight up over the south pole
@example(0.0, -math.pi / 2, 1.0e6, 1.05, 2.0, -10_000.0)  # 1000 km down at 60 deg N
@example(2.5, 0.0, 1.0e6, 0.1, -math.pi, 0.0)
def test_geodetic_outputs_match_pymap3d(az, el, s, lat0, lon0, h0):
    enu = L.aer_to_enu(az, el, s)
    ned = enu[[1, 0, 2]] * [1.0, 1.0, -1.0]
    cases = {
        "enu_to_geodetic": (L.enu_to_geodetic(enu, lat0, lon0, h0), pm.enu2geodetic(*enu, lat0, lon0, h0, deg=False)),
        "ned_to_geodetic": (L.ned_to_geodetic(ned, lat0, lon0, h0), pm.ned2geodetic(*ned, lat0, lon0, h0, deg=False)),
        "aer_to_geodetic": (
            L.aer_to_geodetic(az, el, s, lat0, lon0, h0),
            pm.aer2geodetic(az, el, s, lat0, lon0, h0, deg=False),
        ),
    }
    target_pm = np.array(pm.aer2ecef(az, el, s, lat0, lon0, h0, deg=False))
    for name, (ours, ref) in cases.items():
        # ours lands on the target under pymap3d's own forward geodetic2ecef (exact
        # to rounding), at any height
        assert _dist(pm.geodetic2ecef(*ours, deg=False), target_pm) <= TOL_M, name
        # and agrees with pymap3d's inverse up to that inverse's own error, measured
        # here the same way (its latitude drifts with |h|: module docstring)
        own_err = _dist(pm.geodetic2ecef(*ref, deg=False), target_pm)
        assert _geodetic_gap_m(ours, ref) <= TOL_M + own_err, (name, own_err)
        # within 100 km of the ellipsoid that own error is negligible (<= 1.5e-6 m)
        if abs(ours[2]) <= 100_000.0:
            assert _geodetic_gap_m(ours, ref) <= 1e-5, name


# --- 4. the degree front ends, against pymap3d's degrees -------------------------------


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, 360.0, exclude_max=True),
    st.floats(-90.0, 90.0),
    srange_m,
    st.floats(-90.0, 90.0),
    st.floats(-180.0, 180.0),
    h0_m,
)
@example(45.0, -30.0, 20_000.0, 35.48, 80.97, 18_000.0)
def test_deg_front_ends_match_pymap3d_degrees(az_deg, el_deg, s, lat0_deg, lon0_deg, h0):
    enu = L.aer_to_enu_deg(az_deg, el_deg, s)
    assume(np.all(np.abs(enu) >= 2e-3))  # pymap3d's 1 mm snap, as above
    assert _dist(enu, pm.aer2enu(az_deg, el_deg, s)) <= TOL_M
    xyz = L.aer_to_ecef_deg(az_deg, el_deg, s, lat0_deg, lon0_deg, h0)
    assert _dist(xyz, pm.aer2ecef(az_deg, el_deg, s, lat0_deg, lon0_deg, h0)) <= TOL_M

    lat_deg, lon_deg, h = L.aer_to_geodetic_deg(az_deg, el_deg, s, lat0_deg, lon0_deg, h0)
    ref = pm.aer2geodetic(az_deg, el_deg, s, lat0_deg, lon0_deg, h0)
    own_err = _dist(pm.geodetic2ecef(*ref), xyz)
    gap = _dist(
        geodetic_to_ecef(np.deg2rad(lat_deg), np.deg2rad(lon_deg), h),
        geodetic_to_ecef(np.deg2rad(ref[0]), np.deg2rad(ref[1]), ref[2]),
    )
    assert gap <= TOL_M + own_err + 1e-8  # + degree <-> radian rounding on both sides

    for ours, ref in [
        (L.enu_to_geodetic_deg(enu, lat0_deg, lon0_deg, h0), pm.enu2geodetic(*enu, lat0_deg, lon0_deg, h0)),
        (
            L.ned_to_geodetic_deg(enu[[1, 0, 2]] * [1, 1, -1], lat0_deg, lon0_deg, h0),
            pm.ned2geodetic(enu[1], enu[0], -enu[2], lat0_deg, lon0_deg, h0),
        ),
    ]:
        gap = _dist(
            geodetic_to_ecef(np.deg2rad(ours[0]), np.deg2rad(ours[1]), ours[2]),
            geodetic_to_ecef(np.deg2rad(ref[0]), np.deg2rad(ref[1]), ref[2]),
        )
        assert gap <= TOL_M + own_err + 1e-8

    assert (
        _dist(
            L.geodetic_to_enu_deg(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
            pm.geodetic2enu(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
        )
        <= TOL_M
    )
    assert (
        _dist(
            L.geodetic_to_ned_deg(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
            pm.geodetic2ned(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
        )
        <= TOL_M
    )

    def to_rad(aer):
        return math.radians(aer[0]), math.radians(aer[1]), aer[2]

    for ours, ref in [
        (L.enu_to_aer_deg(enu), pm.enu2aer(*(float(c) for c in enu))),
        (L.ecef_to_aer_deg(xyz, lat0_deg, lon0_deg, h0), pm.ecef2aer(*(float(c) for c in xyz), lat0_deg, lon0_deg, h0)),
        (
            L.geodetic_to_aer_deg(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
            pm.geodetic2aer(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0),
        ),
    ]:
        assert 0.0 <= ours[0] < 360.0
        # the last one goes through our geodetic (lat, lon, h) of the target: its
        # degree rounding (1e-14 deg ~ 1e-9 m) is inside TOL_M
        assert max(_aer_gaps_m(to_rad(ours), to_rad(ref))) <= TOL_M


# --- 5. closed forms a person can check -----------------------------------------------

LAT0, LON0, H0 = math.radians(35.48), math.radians(80.97), 18_000.0


@pytest.mark.parametrize(
    "enu, az_deg", [((0, 1000, 0), 0.0), ((1000, 0, 0), 90.0), ((0, -1000, 0), 180.0), ((-1000, 0, 0), 270.0)]
)
def test_compass_points_on_the_tangent_plane(enu, az_deg):
    # on the tangent plane (u = 0) at 1000 m: azimuth the compass point, elevation 0, range 1000
    az, el, s = L.enu_to_aer(np.array(enu, float))
    assert az == pytest.approx(math.radians(az_deg), abs=1e-15) and el == 0.0 and s == 1000.0
    np.testing.assert_allclose(L.aer_to_enu(az, el, s), enu, atol=1e-12)


def test_a_point_1000_m_north_on_the_tangent_plane_seen_from_ecef():
    # The tangent-plane point o + 1000 m * N (N the NED north axis in ECEF) has az 0, el 0,
    # range 1000 from the origin, wherever the origin is (here the [Q17] aircraft).
    north_ecef = L.R_ecef_ned(LAT0, LON0)[:, 0]
    p = geodetic_to_ecef(LAT0, LON0, H0) + 1000.0 * north_ecef
    az, el, s = L.ecef_to_aer(p, LAT0, LON0, H0)
    # 1e-12 m of ENU rounding on 1000 m: angles to 1e-15 rad, az near 0 from either side
    assert abs(_ang(az, 0.0)) < 1e-12 and abs(el) < 1e-12 and s == pytest.approx(1000.0, abs=1e-8)
    np.testing.assert_allclose(L.ecef_to_ned(p, LAT0, LON0, H0), [1000, 0, 0], atol=1e-8)
    np.testing.assert_allclose(L.ecef_to_enu(p, LAT0, LON0, H0), [0, 1000, 0], atol=1e-8)


def test_the_tangent_plane_rises_above_the_ellipsoid_by_the_sagitta():
    # 1000 m north along the tangent plane from a point on the ellipsoid is
    # s^2 / (2 R_M) = 7.87 cm above it; the next terms (R_M changing along the arc,
    # ~e^2 s / R ~ 1e-6 relative) and h's rounding (3e-9 m) are inside rtol 1e-5.
    lat, lon, h = L.aer_to_geodetic(0.0, 0.0, 1000.0, LAT0, LON0, 0.0)
    assert h == pytest.approx(1000.0**2 / (2 * meridian_radius(LAT0)), rel=1e-5)
    assert lat > LAT0 and lon == pytest.approx(LON0, abs=1e-15)
    # and so, from the ground, that point of the ellipsoid is seen slightly below the horizon
    az, el, _ = L.geodetic_to_aer(lat, lon, 0.0, LAT0, LON0, 0.0)
    assert el == pytest.approx(-h / 1000.0, rel=1e-3) and abs(_ang(az, 0.0)) < 1e-12


@pytest.mark.parametrize("lat0, lon0", [(LAT0, LON0), (0.0, 0.0), (POLE, 1.0), (-POLE, -2.0)])
def test_straight_up_and_down(lat0, lon0):
    # a point 1000 m up the ellipsoid normal: el = 90 deg, range 1000, NED (0, 0, -1000)
    _, el, s = L.geodetic_to_aer(lat0, lon0, H0 + 1000.0, lat0, lon0, H0)
    # the ECEF difference of two points 1000 m apart has ~1e-9 m of rounding across the
    # normal: el within 1e-12 rad of 90 deg (the azimuth is then meaningless)
    assert el == pytest.approx(math.pi / 2, abs=1e-11) and s == pytest.approx(1000.0, abs=1e-8)
    np.testing.assert_allclose(L.geodetic_to_ned(lat0, lon0, H0 + 1000.0, lat0, lon0, H0), [0, 0, -1000], atol=1e-8)
    down = L.aer_to_geodetic(1.234, -math.pi / 2, 1000.0, lat0, lon0, H0)
    assert _geodetic_gap_m(down, (lat0, lon0, H0 - 1000.0)) <= 1e-8
    assert L.enu_to_aer(np.array([0.0, 0.0, 5.0])) == (0.0, math.pi / 2, 5.0)
    assert L.enu_to_aer(np.array([0.0, 0.0, -5.0])) == (0.0, -math.pi / 2, 5.0)


def test_axes_at_the_equator_and_the_pole():
    # At (0 N, 0 E, h = 0): E = +Y, N = +Z, U = +X of ECEF (NED: N = +Z, E = +Y, D = -X)
    a = geodetic_to_ecef(0.0, 0.0, 0.0)[0]
    p = [a + 100.0, 50.0, 20.0]
    np.testing.assert_allclose(L.ecef_to_enu(p, 0.0, 0.0, 0.0), [50, 20, 100], atol=1e-9)
    np.testing.assert_allclose(L.ecef_to_ned(p, 0.0, 0.0, 0.0), [20, 50, -100], atol=1e-9)
    # At the north pole with lon0 = 0: E = +Y, N = -X (towards 180 deg), U = +Z
    p = [10.0, 20.0, B + 30.0]
    np.testing.assert_allclose(L.ecef_to_enu(p, POLE, 0.0, 0.0), [20, -10, 30], atol=1e-9)
    az, _, s = L.ecef_to_aer(p, POLE, 0.0, 0.0)
    # float pi/2 has cos = 6e-17, tilting the axes by that: 6e-17 * |z| = 4e-10 m of ENU,
    # 2e-11 rad of azimuth at 22 m
    assert az == pytest.approx(math.atan2(20, -10), abs=1e-10)
    assert s == pytest.approx(math.sqrt(100 + 400 + 900), abs=1e-9)


def test_azimuth_stays_in_zero_two_pi():
    # atan2 of a tiny negative east component is -1e-300; mod 2 pi would round it to
    # 2 pi itself, which the half-open interval excludes: it must come back as 0
    tiny_west = np.array([[-1e-300, 1.0, 0.0], [-0.0, 1.0, 0.0], [-1e-17, 1.0, 0.0], [0.0, 0.0, 0.0]])
    az, _, _ = L.enu_to_aer(tiny_west)
    assert np.all((az >= 0) & (az < 2 * np.pi)), az
    az_deg, _, _ = L.enu_to_aer_deg(tiny_west)
    assert np.all((az_deg >= 0) & (az_deg < 360)), az_deg
    az, _, _ = L.enu_to_aer(np.array([-1e-9, 1.0, 0.0]))
    assert 2 * np.pi - 2e-9 < az < 2 * np.pi  # just west of north is still just below 2 pi


def test_pymap3d_snaps_millimetres_we_do_not():
    # pymap3d's enu2aer zeroes components below 1 mm; 0.5 mm east at 1000 m north is
    # 5e-7 rad of azimuth for us, 0 for pymap3d: the one deliberate difference
    az, _, _ = L.enu_to_aer(np.array([5e-4, 1000.0, 0.0]))
    assert az == pytest.approx(5e-7, rel=1e-9)
    assert pm.enu2aer(5e-4, 1000.0, 0.0, deg=False)[0] == 0.0


def test_negative_slant_range_is_nan_not_an_exception():
    # pymap3d raises ValueError; a batch here gives NaN for that element only
    with pytest.raises(ValueError):
        pm.aer2enu(0.0, 0.0, -1.0, deg=False)
    out = L.aer_to_enu(0.0, 0.0, np.array([-1.0, 1.0]))
    assert np.all(np.isnan(out[0])) and np.allclose(out[1], [0, 1, 0])
    lat, lon, h = L.aer_to_geodetic(0.0, 0.0, np.array([-1.0, 1.0]), LAT0, LON0, H0)
    assert np.isnan([lat[0], lon[0], h[0]]).all() and np.isfinite([lat[1], lon[1], h[1]]).all()


# --- 6. round trips -------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(*aers, *origins)
@example(1.0, 0.2, 1.0e6, POLE, 0.0, 0.0)
@example(1.0, -0.2, 1.0e6, -NEAR_POLE, math.pi, 100_000.0)
def test_round_trips(az, el, s, lat0, lon0, h0):
    enu, xyz, (lat, lon, h) = _target(az, el, s, lat0, lon0, h0)
    assert _dist(L.enu_to_ecef(L.ecef_to_enu(xyz, lat0, lon0, h0), lat0, lon0, h0), xyz) <= TOL_M
    assert _dist(L.ned_to_ecef(L.ecef_to_ned(xyz, lat0, lon0, h0), lat0, lon0, h0), xyz) <= TOL_M
    assert _dist(L.aer_to_enu(*L.enu_to_aer(enu)), enu) <= TOL_M
    assert _dist(L.aer_to_ecef(*L.ecef_to_aer(xyz, lat0, lon0, h0), lat0, lon0, h0), xyz) <= TOL_M
    # geodetic round trips through our Vermeille inverse (exact to ~3e-9 m)
    back = L.enu_to_geodetic(L.geodetic_to_enu(lat, lon, h, lat0, lon0, h0), lat0, lon0, h0)
    assert _geodetic_gap_m(back, (lat, lon, h)) <= TOL_M
    back = L.ned_to_geodetic(L.geodetic_to_ned(lat, lon, h, lat0, lon0, h0), lat0, lon0, h0)
    assert _geodetic_gap_m(back, (lat, lon, h)) <= TOL_M
    back = L.aer_to_geodetic(*L.geodetic_to_aer(lat, lon, h, lat0, lon0, h0), lat0, lon0, h0)
    assert _geodetic_gap_m(back, (lat, lon, h)) <= TOL_M
    # NED is ENU with the axes reordered, exactly
    ned = L.ecef_to_ned(xyz, lat0, lon0, h0)
    np.testing.assert_array_equal(ned, L.R_ENU_NED.T @ L.ecef_to_enu(xyz, lat0, lon0, h0))


# --- 7. NaN in -> NaN out, per element ------------------------------------------------

O = (0.6, 1.4, 500.0)  # origin (rad, rad, m)
O_DEG = (34.4, 80.2, 500.0)
P_ECEF = geodetic_to_ecef(0.6001, 1.4001, 800.0)
P_LOC = (300.0, -200.0, 50.0)
GEO = (0.6001, 1.4001, 800.0)
GEO_DEG = (34.41, 80.21, 800.0)
AER = (1.0, 0.2, 5000.0)
AER_DEG = (57.0, 11.0, 5000.0)

#: function -> its arguments ("p" is a (3,) point, a number a scalar)
CALLS = {
    "ecef_to_enu": (P_ECEF, *O),
    "enu_to_ecef": (P_LOC, *O),
    "geodetic_to_enu": (*GEO, *O),
    "enu_to_geodetic": (P_LOC, *O),
    "ecef_to_ned": (P_ECEF, *O),
    "ned_to_ecef": (P_LOC, *O),
    "geodetic_to_ned": (*GEO, *O),
    "ned_to_geodetic": (P_LOC, *O),
    "enu_to_aer": (P_LOC,),
    "aer_to_enu": AER,
    "geodetic_to_aer": (*GEO, *O),
    "aer_to_geodetic": (*AER, *O),
    "ecef_to_aer": (P_ECEF, *O),
    "aer_to_ecef": (*AER, *O),
    "geodetic_to_enu_deg": (*GEO_DEG, *O_DEG),
    "enu_to_geodetic_deg": (P_LOC, *O_DEG),
    "geodetic_to_ned_deg": (*GEO_DEG, *O_DEG),
    "ned_to_geodetic_deg": (P_LOC, *O_DEG),
    "enu_to_aer_deg": (P_LOC,),
    "aer_to_enu_deg": AER_DEG,
    "geodetic_to_aer_deg": (*GEO_DEG, *O_DEG),
    "aer_to_geodetic_deg": (*AER_DEG, *O_DEG),
    "ecef_to_aer_deg": (P_ECEF, *O_DEG),
    "aer_to_ecef_deg": (*AER_DEG, *O_DEG),
}


def _outputs(out):
    """A function's outputs as a list of arrays whose first axis is the batch."""
    return [np.asarray(o) for o in out] if isinstance(out, tuple) else [np.asarray(out)]


def _batch(args, n=3):
    """Each argument repeated n times along a new first axis."""
    return [np.repeat(np.asarray(a, float)[None], n, axis=0) for a in args]


@pytest.mark.parametrize("name", sorted(CALLS))
def test_nan_in_any_input_gives_nan_in_every_output_of_that_element(name):
    fn = getattr(L, name)
    for i, a in enumerate(CALLS[name]):
        for k in range(np.size(a)):  # every component of a point, or the scalar
            args = _batch(CALLS[name])
            args[i].reshape(3, -1)[1, k] = np.nan
            for o in _outputs(fn(*args)):
                assert np.all(np.isnan(o[1])), (name, i, k, o)
                assert np.all(np.isfinite(o[[0, 2]])), (name, i, k, o)


# --- 8. broadcasting ------------------------------------------------------------------


def test_a_batch_of_points_against_one_origin_matches_pymap3d():
    rng = np.random.default_rng(13)
    lat0, lon0, h0 = math.radians(35.48), math.radians(80.97), 18_000.0
    az, el, s = rng.uniform(0, 2 * np.pi, 500), rng.uniform(-1.5, 1.5, 500), rng.uniform(0, 1e6, 500)
    xyz = L.aer_to_ecef(az, el, s, lat0, lon0, h0)
    assert xyz.shape == (500, 3)
    ref = np.stack(pm.ecef2enu(*xyz.T, lat0, lon0, h0, deg=False), -1)
    assert np.abs(L.ecef_to_enu(xyz, lat0, lon0, h0) - ref).max() <= TOL_M
    ref = np.stack(pm.ecef2ned(*xyz.T, lat0, lon0, h0, deg=False), -1)
    assert np.abs(L.ecef_to_ned(xyz, lat0, lon0, h0) - ref).max() <= TOL_M
    ref = np.stack(pm.aer2ecef(az, el, s, lat0, lon0, h0, deg=False), -1)
    assert np.abs(xyz - ref).max() <= TOL_M
    a2, e2, s2 = L.ecef_to_aer(xyz, lat0, lon0, h0)
    assert a2.shape == e2.shape == s2.shape == (500,)
    assert np.abs(_ang(a2, az) * s * np.cos(el)).max() <= TOL_M and np.abs(s2 - s).max() <= TOL_M


def test_a_batch_of_origins_against_one_point_matches_pymap3d():
    rng = np.random.default_rng(14)
    lat0, lon0 = rng.uniform(-np.pi / 2, np.pi / 2, 400), rng.uniform(-np.pi, np.pi, 400)
    h0 = rng.uniform(-1e4, 1e5, 400)
    lat, lon, h = 0.62, 1.41, 4500.0
    enu = L.geodetic_to_enu(lat, lon, h, lat0, lon0, h0)
    assert enu.shape == (400, 3)
    ref = np.stack(pm.geodetic2enu(lat, lon, h, lat0, lon0, h0, deg=False), -1)
    assert np.abs(enu - ref).max() <= TOL_M
    ned = L.geodetic_to_ned(lat, lon, h, lat0, lon0, h0)
    ref = np.stack(pm.geodetic2ned(lat, lon, h, lat0, lon0, h0, deg=False), -1)
    assert np.abs(ned - ref).max() <= TOL_M
    # the origins are anywhere on the globe, so ranges reach 1.3e7 m (ulp 1.9e-9 m): 10 TOL_M
    az, el, s = L.geodetic_to_aer(lat, lon, h, lat0, lon0, h0)
    raz, rel, rs = pm.geodetic2aer(lat, lon, h, lat0, lon0, h0, deg=False)
    ok = np.all(np.abs(enu) >= 2e-3, axis=-1)  # pymap3d's 1 mm snap
    assert np.abs(s - rs).max() <= TOL_M * 10
    assert np.abs((el - rel) * s).max() <= TOL_M * 10
    assert np.abs(_ang(az, raz) * s * np.cos(el))[ok].max() <= TOL_M * 10
    # one point, back from every origin: all land on it
    back = L.enu_to_geodetic(enu, lat0, lon0, h0)
    gaps = np.linalg.norm(geodetic_to_ecef(*back) - geodetic_to_ecef(lat, lon, h), axis=-1)
    assert gaps.shape == (400,) and gaps.max() <= TOL_M * 10


def _kinds(name):
    """Each argument's role: "p" a (3,) point, "t" a target scalar (lat, lon, h or az, el, s), "o" origin."""
    n = len(CALLS[name])
    head = "ttt" if name.startswith(("geodetic_to", "aer_to")) else "p"
    return head + "o" * (n - len(head))


@pytest.mark.parametrize("name", sorted(CALLS))
def test_points_and_origins_broadcast_like_a_loop(name):
    # points (and target scalars) on rows, shape (4, 1), origins on columns, shape (3,):
    # every output is (4, 3[, 3]) and each element equals the call on that one point
    # and that one origin (the same arithmetic, so to rounding of the broadcast)
    fn, rng = getattr(L, name), np.random.default_rng(15)
    args = []
    for kind, a in zip(_kinds(name), CALLS[name]):
        a = np.asarray(a, float)
        if kind == "p":
            args.append(a + rng.normal(0.0, 100.0, (4, 1, 3)))
        else:
            args.append(a * (1 + rng.uniform(-1e-3, 1e-3, (4, 1) if kind == "t" else (3,))))
    outs = _outputs(fn(*args))
    for o in outs:  # enu_to_aer and aer_to_enu have no origin: their rows stay (4, 1)
        assert o.shape[:2] == ((4, 3) if "o" in _kinds(name) else (4, 1)), (name, o.shape)
    for r in range(4):
        for c in range(3):
            if c >= outs[0].shape[1]:
                continue
            one = [a[c] if kind == "o" else a[r, 0] for kind, a in zip(_kinds(name), args)]
            for o, o1 in zip(outs, _outputs(fn(*one))):
                np.testing.assert_allclose(o[r, c], o1, rtol=0, atol=1e-9)
