"""Atmospheric refraction (geoloc.corrections.atmosphere, geoloc.corrections.refraction) against outside numbers.

References, each written out here:
- [USSA76] U.S. Standard Atmosphere 1976, NOAA-S/T 76-1562, Table I (geometric altitude):
  temperature, pressure and density printed to 5-6 significant digits.
- [BD93] Birch & Downs, Metrologia 30 (1993) 155: n - 1 = 2.7180e-4 for dry air at 20 degC,
  101 325 Pa, 633 nm (the value NIST's "Refractive index of air calculator", Edlen option, prints).
- The classical photogrammetric refraction (flat Earth; e.g. the ASPRS Manual of
  Photogrammetry): the angle at the camera is tan(a) [mean(n) between ground and camera
  - n at the camera], written here with scipy.integrate.quad; and Bertram's fit of its
  coefficient K (ibid.), K = [2410 H/(H^2 - 6H + 250) - 2410 h/(h^2 - 6h + 250) (h/H)] 1e-6.
- Astronomical refraction: Smart, Textbook on Spherical Astronomy (6th ed. 1977), chapter on
  refraction: R = 58.16" tan z - 0.067" tan^3 z at 10 degC and 1013.25 hPa, scaled by P/T; Bennett,
  J. Navigation 35 (1982) 255: R = cot(h + 7.31/(h + 4.4)) arcmin at 10 degC and 1010 hPa.
- Orekit Rugged's tests: src/test/java/org/orekit/rugged/refraction/MultiLayerModelTest.java
  (testAlmostNadir, testDivingAngleChange, testNoOpRefraction, testReversedAtmosphere), whose
  satellite, line of sight and results are quoted as literals.
- An independent ray trace: the ray equation d/ds (n dx/ds) = grad n integrated in ECEF with
  scipy's solve_ivp, n a function of the geodetic height (so grad n = n'(h) times the
  ellipsoid's normal), stopped by an event at the target height.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from geoloc.corrections.atmosphere import STANDARD, StandardAtmosphere, air_refractivity
from geoloc.corrections.refraction import RUGGED_LAYERS, STANDARD_REFRACTION, Layers, Refraction
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef, up_normal_ecef
from geoloc.geodesy.local import R_ecef_ned
from geoloc.pipeline import Corrections, Pipeline
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight
from geoloc.surfaces.height import HeightSurface, ray_geodetic_height
from raytrace import exact_n, look, trace  # tests/raytrace.py: the independent ray trace

LAT, LON = np.deg2rad(35.0), np.deg2rad(80.0)
ARCMIN = np.pi / (180 * 60)


def locate(model, o, d, surface):
    """The location pipeline with refraction ``model`` only: (bent hit, straight hit, status).

    ``surface`` is a height h (the exact surface of geodetic height h) or a Surface."""
    if not hasattr(surface, "intersect"):
        surface = HeightSurface(surface, "geodetic")
    o, d = np.broadcast_arrays(np.asarray(o, float), np.asarray(d, float))
    los = LineOfSight(o, d, np.zeros(o.shape[:-1], np.uint8))
    hit = Pipeline(None, surface, Corrections(refraction=model)).intersect(los)
    return hit.ecef, surface.intersect(los).ecef, hit.status


# --- the atmosphere ----------------------------------------------------------------------------

#: [USSA76] Table I: geometric altitude [m], T [K], P [Pa], rho [kg/m^3] (each row also agrees to
#: 1e-5 with the ``ambiance`` package, ICAO 1993 = USSA76 below 80 km, run once by hand: not a
#: test dependency).
USSA76_TABLE = [
    (0.0, 288.150, 1.01325e5, 1.2250),
    (1000.0, 281.651, 8.9876e4, 1.1117),
    (5000.0, 255.676, 5.4048e4, 7.3643e-1),
    (10000.0, 223.252, 2.6500e4, 4.1351e-1),
    (20000.0, 216.650, 5.5293e3, 8.8910e-2),
    (30000.0, 226.509, 1.1970e3, 1.8410e-2),
    (40000.0, 250.350, 2.8714e2, 3.9957e-3),
    (50000.0, 270.650, 7.9779e1, 1.0269e-3),
    (60000.0, 247.021, 2.1958e1, 3.0968e-4),
    (70000.0, 219.585, 5.2209, 8.2829e-5),
    (80000.0, 198.639, 1.0525, 1.8458e-5),
]


@pytest.mark.parametrize("h, T, P, rho", USSA76_TABLE)
def test_standard_atmosphere_matches_the_published_table(h, T, P, rho):
    # the table prints 5 significant digits: half a unit of the last is 5e-5 relative at most;
    # temperatures to 1e-3 K
    assert STANDARD.temperature(h) == pytest.approx(T, abs=1e-3)
    assert STANDARD.pressure(h) == pytest.approx(P, rel=6e-5)
    assert STANDARD.density(h) == pytest.approx(rho, rel=6e-5)


def test_ground_override_keeps_the_barometric_law():
    # a hot, low-pressure day measured at 1200 m: the troposphere goes through the measurement
    # with -6.5 K/km' and P = P_g (T/T_g)^(g0 M0 / (R* 6.5e-3)) = P_g (T/T_g)^5.25588 [USSA76 eq. 33a]
    atm = StandardAtmosphere(ground_h_m=1200.0, ground_p_pa=86000.0, ground_t_k=303.0)
    assert atm.temperature(1200.0) == pytest.approx(303.0, abs=1e-9)
    assert atm.pressure(1200.0) == pytest.approx(86000.0, rel=1e-12)
    r0 = 6356766.0
    H = lambda h: r0 * h / (r0 + h)  # noqa: E731 - geopotential height [USSA76 eq. 18]
    for h in (0.0, 3000.0, 8000.0):
        T = 303.0 - 6.5e-3 * (H(h) - H(1200.0))
        assert atm.temperature(h) == pytest.approx(T, abs=1e-9)
        assert atm.pressure(h) == pytest.approx(86000.0 * (T / 303.0) ** 5.25588, rel=2e-6)
    # above the tropopause: the standard temperatures, the pressure continuous at 11 km'
    assert atm.temperature(25000.0) == pytest.approx(STANDARD.temperature(25000.0), abs=1e-9)
    below, above = atm.pressure(11019.0), atm.pressure(11019.2)
    assert above == pytest.approx(below, rel=1e-4)  # 0.2 m apart: 3e-5 by the scale height


def test_refractivity_of_air():
    # [BD93] / NIST calculator (Edlen option): 2.7180e-4 at 20 degC, 101 325 Pa, 633 nm, dry
    assert air_refractivity(101325.0, 293.15, 0.633) == pytest.approx(2.7180e-4, abs=2e-9)
    # the older optical form N = 77.6 (1 + 7.52e-3 / lambda^2) P[hPa] / T (1 % accuracy by its own account)
    for h in (0.0, 5000.0, 18000.0):
        T, P = STANDARD.temperature_pressure(h)
        simple = 77.6e-6 * (1 + 7.52e-3 / 0.55**2) * (P / 100.0) / T
        assert STANDARD.refractivity(h) == pytest.approx(simple, rel=0.01)
    # Rugged's built-in layer index at sea level, 1.000278
    assert 1.0 + STANDARD.refractivity(0.0) == pytest.approx(1.000278, abs=1e-6)


# --- near-vertical views: the photogrammetric refraction ------------------------------------------


@pytest.mark.parametrize("H_km, h_km", [(3.0, 0.0), (6.0, 0.0), (9.0, 0.0), (18.0, 0.0), (6.0, 2.0), (12.0, 1.5)])
def test_photogrammetric_refraction_near_vertical(H_km, h_km):
    H, h = H_km * 1000.0, h_km * 1000.0
    # flat Earth: the ray bends by d(alpha) = tan(alpha) [ (1/(H-h)) int_h^H n dz - n(H) ]
    mean_eps = quad(lambda z: STANDARD.refractivity(z), h, H, points=[11019.07], epsabs=1e-14, limit=200)[0] / (H - h)
    K = mean_eps - STANDARD.refractivity(H)
    for a in (5.0, 15.0, 30.0):
        o, d = look(LAT, LON, H, a, azimuth_deg=40.0)
        raw = ray_geodetic_height(o, d, h).ecef
        line = STANDARD_REFRACTION.correct(o, d, raw)
        g = line.hit_ecef - o
        delta = np.arccos(np.clip(g @ d / np.linalg.norm(g), -1.0, 1.0))
        # the flat formula leaves out the Earth's curvature, an error of the order of (H - h)/R
        # (1 + tan^2 a): 0.3 % at 18 km (measured: 0.11 %, 0.03 % at 9 km); 2e-4 for the rest
        tol = 2e-4 + (H - h) / 6.37e6 * (1.0 + np.tan(np.deg2rad(a)) ** 2)
        assert delta / np.tan(np.deg2rad(a)) == pytest.approx(K, rel=tol)
        if h_km == 0.0:
            # Bertram's K, a fit to the ARDC 1959 atmosphere: within 15 % of USSA76's (30.0 vs 34.4
            # microradians at 3 km, 93.1 vs 93.2 at 18 km)
            Kb = 2410 * H_km / (H_km**2 - 6 * H_km + 250) * 1e-6
            assert delta / np.tan(np.deg2rad(a)) == pytest.approx(Kb, rel=0.16)


# --- astronomical refraction: an observer looking up ------------------------------------------------


def astronomical_refraction(elevation_deg):
    o, d = look(LAT, LON, 0.0, 180.0 - (90.0 - elevation_deg))  # up, elevation above the horizon
    far = o + 3e6 * d
    line = STANDARD_REFRACTION.correct(o, d, far, at_h=ecef_to_geodetic(far)[2])
    assert line.status == Status.OK
    return np.arccos(np.clip(line.direction_ecef @ d, -1.0, 1.0))


@pytest.mark.parametrize("elevation_deg", [20.0, 30.0, 45.0, 70.0])
def test_astronomical_refraction_smart(elevation_deg):
    z = np.deg2rad(90.0 - elevation_deg)
    smart = (58.16 * np.tan(z) - 0.067 * np.tan(z) ** 3) * (101325.0 / 101325.0) * (283.15 / 288.15)
    # 0.5 %: Smart's constant is for yellow light (the dispersion from 0.55 to 0.59 um is 0.3 %)
    assert np.rad2deg(astronomical_refraction(elevation_deg)) * 3600 == pytest.approx(smart, rel=5e-3)


@pytest.mark.parametrize("elevation_deg", [0.0, 0.5, 2.0, 5.0, 10.0])
def test_astronomical_refraction_bennett_and_the_horizon(elevation_deg):
    e = elevation_deg
    bennett = 1.0 / np.tan(np.deg2rad(e + 7.31 / (e + 4.4))) * (101.325 / 101.0) * (283.0 / 288.15)
    got = astronomical_refraction(e) / ARCMIN
    # 3.5 %: Bennett fits Garfinkel's polytropic atmosphere; near the horizon the refraction
    # follows the lapse rate of the lowest kilometres, which differs from USSA76's
    assert got == pytest.approx(bennett, rel=0.035)
    if e == 0.0:
        assert 32.5 < got < 35.5  # "about 34 arcmin" (33.0' in USSA76 at 15 degC)


# --- the limb ---------------------------------------------------------------------------------------


def limb_ray(tangent_h):
    """From 700 km, a ray whose straight line grazes tangent_h (about) on the sphere of radius 6371 km."""
    o = geodetic_to_ecef(LAT, LON, 700e3)
    dep = np.arccos((6371e3 + tangent_h) / np.linalg.norm(o))
    return o, R_ecef_ned(LAT, LON) @ np.array([np.cos(dep), 0.0, np.sin(dep)])


def test_limb_refracted_tangent_against_the_ray_trace():
    for h in (3000.0, 8000.0, 15000.0, 30000.0):
        o, d = limb_ray(h)
        L = STANDARD_REFRACTION.limb(o, d)
        assert L.status == Status.OK
        ref = trace(o, d, None, exact_n, limb=True)
        h_ref = ecef_to_geodetic(ref)[2]
        # 1 m: the tangent height is flat along the ray, so the trace's event locates it well
        assert L.refracted_tangent_h_m == pytest.approx(h_ref, abs=1.0)
        assert np.linalg.norm(L.refracted_tangent_ecef - ref) < 300.0  # along the ray, where it is level
        assert L.refracted_tangent_h_m < L.tangent_h_m  # the bent ray passes lower


def test_limb_grazing_ray_bends_like_the_horizon_refraction():
    # a ray whose bent path grazes about sea level turns by the horizontal refraction by its tangent
    # point (half its whole bending), the ~34 arcmin an observer there sees at the horizon
    lo, hi = 0.0, 5000.0
    for _ in range(40):  # bisection on the straight tangent height for a refracted one of 50 m
        mid = 0.5 * (lo + hi)
        L = STANDARD_REFRACTION.limb(*limb_ray(mid))
        if L.status != Status.OK or L.refracted_tangent_h_m < 50.0:
            lo = mid
        else:
            hi = mid
    L = STANDARD_REFRACTION.limb(*limb_ray(hi))
    assert L.refracted_tangent_h_m == pytest.approx(50.0, abs=0.5)
    # the observer's horizontal refraction at 50 m (this model, tested above against Bennett)
    o, d = look(LAT, LON, 50.0, 90.0)
    far = o + 3e6 * d
    seen = STANDARD_REFRACTION.correct(o, d, far, at_h=ecef_to_geodetic(far)[2]).direction_ecef @ d
    assert L.bending_rad == pytest.approx(np.arccos(seen), rel=0.01)  # the two spheres differ slightly
    assert 30 * ARCMIN < L.bending_rad < 36 * ARCMIN
    assert L.tangent_h_m - L.refracted_tangent_h_m > 1000.0  # kilometres below the straight tangent


def test_limb_statuses():
    o = geodetic_to_ecef(LAT, LON, 700e3)
    L = STANDARD_REFRACTION.limb(o, -o)  # straight down: no tangent
    assert L.status == Status.HITS_EARTH and np.isnan(L.refracted_tangent_h_m)
    L = STANDARD_REFRACTION.limb(np.array([[np.nan, 0, 0]]), np.array([[0.0, 0, 1]]))
    assert L.status[0] == Status.INVALID_INPUT


# --- against an independent ray trace ----------------------------------------------------------------


@pytest.mark.parametrize(
    "h_p, off_nadir, h_g, tol_m",
    [
        (18000.0, 30.0, 0.0, 0.0005),
        (18000.0, 60.0, 0.0, 0.0005),
        (18000.0, 70.0, 1500.0, 0.0005),
        (18000.0, 80.0, 0.0, 0.003),
        (700e3, 20.0, 0.0, 0.0005),
        (700e3, 50.0, 300.0, 0.0005),
    ],
)
def test_against_an_independent_ray_trace(h_p, off_nadir, h_g, tol_m):
    # tolerances: measured 0.004, 0.04, 0.10, 1.39, 0.01, 0.05 mm (1.4 mm of 387 m at 80 deg); the
    # trace is converged to 0.05 mm (tests/raytrace.py), so 0.5 mm, and 3 mm at 80 deg (twice it)
    o, d = look(LAT, LON, h_p, off_nadir, azimuth_deg=53.0)
    hit, raw, st = locate(STANDARD_REFRACTION, o, d, h_g)
    assert st == Status.OK
    ref = trace(o, d, h_g, exact_n)
    assert np.linalg.norm(hit - ref) < tol_m
    assert np.linalg.norm(ref - raw) > 1.0  # the shift itself is metres


def test_shift_from_18_km_grows_with_the_angle_and_points_to_nadir(capsys):
    shifts = []
    for a in (30.0, 45.0, 60.0, 70.0):
        o, d = look(LAT, LON, 18000.0, a, azimuth_deg=120.0)
        hit, raw, st = locate(STANDARD_REFRACTION, o, d, 0.0)
        nadir = geodetic_to_ecef(LAT, LON, 0.0)
        shift = np.linalg.norm(hit - raw)
        # toward nadir: the corrected point is nearer the nadir point by (almost) the whole shift
        closer = np.linalg.norm(raw - nadir) - np.linalg.norm(hit - nadir)
        assert closer == pytest.approx(shift, rel=1e-3)
        # and it agrees with the independent trace (measured 0.004-0.13 mm; 0.5 mm as above)
        assert np.linalg.norm(hit - trace(o, d, 0.0, exact_n)) < 0.0005
        shifts.append(shift)
    with capsys.disabled():
        print("\nrefraction shift from 18 km at 30/45/60/70 deg off nadir: " + ", ".join(f"{s:.2f} m" for s in shifts))
    assert np.all(np.diff(shifts) > 0)
    # the figures of docs/refraction.md (1.29, 3.38, 11.83, 41.22 m), to 1 cm
    assert shifts == pytest.approx([1.29, 3.38, 11.83, 41.22], abs=0.01)


# --- Rugged's MultiLayerModel tests -------------------------------------------------------------------

#: MultiLayerModelTest: the satellite (ECEF, about 790 km over the Philippines) of every test.
RUGGED_SAT = np.array([-3787079.6453602533, 5856784.405679551, 1655869.0582939098])
#: Mayon volcano context (AbstractAlgorithmTest.setUpMayonVolcanoContext): a cone on a 16 m plain.
RUGGED_BASE_H = 16.0


def rugged_los(alpha):
    """MultiLayerModelTest.los(position, alpha): nadir turned by alpha about Hipparchus' nadir.orthogonal()."""
    lat, lon, _ = ecef_to_geodetic(RUGGED_SAT)
    nadir = -up_normal_ecef(lat, lon)
    x, y, z = nadir
    if abs(x) <= 0.6:
        k = np.array([0.0, z, -y]) / np.hypot(y, z)
    elif abs(y) <= 0.6:
        k = np.array([-z, 0.0, x]) / np.hypot(x, z)
    else:
        k = np.array([y, -x, 0.0]) / np.hypot(x, y)
    return nadir * np.cos(alpha) + np.cross(k, nadir) * np.sin(alpha)


def test_rugged_almost_nadir():
    # MultiLayerModelTest.testAlmostNadir: 0.0553796 m, to 1e-6 m. Its raw hit (13.40 N, 123.02 E)
    # is 73 km from the volcano's summit, on the 16 m plain of its DEM.
    los = np.array([0.5127552821932051, -0.8254313129088879, -0.2361041470463311])
    hit, raw, st = locate(Refraction(RUGGED_LAYERS), RUGGED_SAT, los, RUGGED_BASE_H)
    summit = geodetic_to_ecef(np.deg2rad(13.25667), np.deg2rad(123.685), 2463.0)
    assert np.linalg.norm(raw - summit) > 5000.0  # the cone's foot: 2447 m / sin(30 deg) = 4.9 km
    assert np.linalg.norm(hit - raw) == pytest.approx(0.0553796, abs=1e-6)


def test_rugged_diving_angle_change():
    # MultiLayerModelTest.testDivingAngleChange: 0 to 50 deg from nadir, Rugged's fit of its own
    # results, 1.17936 tan((2.94613 - 1.40162 a) a), held to its 0.12 m
    model = Refraction(RUGGED_LAYERS)
    for alpha in np.arange(0.0, np.deg2rad(50.0), 0.1):
        hit, raw, st = locate(model, RUGGED_SAT, rugged_los(alpha), RUGGED_BASE_H)
        ref = 1.17936 * np.tan((2.94613 - 1.40162 * alpha) * alpha)
        assert np.linalg.norm(hit - raw) == pytest.approx(ref, abs=0.12)


def test_rugged_no_op_and_reversed_atmosphere():
    los = rugged_los(np.deg2rad(50.0))
    # testNoOpRefraction: 16 layers of n = 1, correction below 1.7e-9 m in Rugged. The pipeline
    # takes the bent point at the surface's height from the kernel's polar angle (no second
    # intersection), rebuilt at 6.4e6 m from the centre, where one float64 step is 9.3e-10 m:
    # measured 2.3e-9 m, 2.5 steps; 5 steps allowed
    flat = Refraction(Layers(tuple((i * 1.0e4, 1.0) for i in range(16))))
    hit, raw, _ = locate(flat, RUGGED_SAT, los, RUGGED_BASE_H)
    assert np.linalg.norm(hit - raw) < 5 * 9.3e-10
    # testReversedAtmosphere: 1/n bends the other way; the three points are aligned
    base = Refraction(RUGGED_LAYERS)
    rev = Refraction(Layers(tuple((h, 1.0 / n) for h, n in RUGGED_LAYERS.layers)))
    corr, raw, _ = locate(base, RUGGED_SAT, los, RUGGED_BASE_H)
    back, _, _ = locate(rev, RUGGED_SAT, los, RUGGED_BASE_H)
    ang = lambda p: np.arccos(p @ RUGGED_SAT / np.linalg.norm(p) / np.linalg.norm(RUGGED_SAT))  # noqa: E731
    assert ang(corr) < ang(raw) < ang(back)
    d1, d2, d3 = (np.linalg.norm(corr - raw), np.linalg.norm(back - raw), np.linalg.norm(back - corr))
    assert d1 + d2 == pytest.approx(d3, rel=1e-6)  # Rugged: 1e-12 relative; here 1e-6 (to the mm)


# --- the pieces the pipeline calls -----------------------------------------------------------------------


def test_aim_inverts_the_correction():
    rng = np.random.default_rng(4)
    o, d0 = look(LAT, LON, 18000.0, 0.0)
    ds = np.array([look(LAT, LON, 18000.0, a, z)[1] for a, z in zip(rng.uniform(0, 75, 50), rng.uniform(0, 360, 50))])
    hit, raw, st = locate(STANDARD_REFRACTION, o, ds, 250.0)
    assert np.all(st == Status.OK)
    d_back, st2 = STANDARD_REFRACTION.aim(o, hit)
    assert np.all(st2 == Status.OK)
    # 2e-9 rad: the fixed point stops at 0.1 mm of miss, 1e-9 rad at 100 km
    assert np.max(np.linalg.norm(d_back - ds, axis=-1)) < 2e-9


def test_correct_vectorises_and_flags_bad_rays():
    o, d = look(LAT, LON, 18000.0, 45.0)
    raw = ray_geodetic_height(o, d, 0.0).ecef
    one = STANDARD_REFRACTION.correct(o, d, raw)
    many = STANDARD_REFRACTION.correct(np.broadcast_to(o, (2, 3, 3)), np.broadcast_to(d, (2, 3, 3)), raw)
    assert many.hit_ecef.shape == (2, 3, 3) and one.hit_ecef.shape == (3,)
    np.testing.assert_array_equal(many.hit_ecef[1, 2], one.hit_ecef)
    bad = STANDARD_REFRACTION.correct(
        np.array([[np.nan, 0, 0], o]), np.array([d, d]), np.array([raw, raw]), at_h=np.array([0.0, 30000.0])
    )
    assert bad.status[0] == Status.INVALID_INPUT and np.isnan(bad.hit_ecef[0]).all()
    # 30 km is above the camera, behind it along the line: not served
    assert bad.status[1] == Status.NO_CONVERGENCE
    # a straight-down look is not bent
    o2, down = look(LAT, LON, 18000.0, 0.0)
    nadir = STANDARD_REFRACTION.correct(o2, down, ray_geodetic_height(o2, down, 0.0).ecef)
    assert nadir.shift_m < 1e-6


def test_lat_lon_h_of_the_corrected_point():
    rng = np.random.default_rng(7)
    o = geodetic_to_ecef(LAT, LON, 18000.0)
    ds = np.array([look(LAT, LON, 18000.0, a, z)[1] for a, z in zip(rng.uniform(0, 80, 40), rng.uniform(0, 360, 40))])
    raw = ray_geodetic_height(o, ds, 400.0).ecef
    lat, lon, h = ecef_to_geodetic(raw)
    a = STANDARD_REFRACTION.correct(o, ds, raw)
    b = STANDARD_REFRACTION.correct(o, ds, raw, hit_llh=(lat, lon, h))
    np.testing.assert_allclose(a.hit_ecef, b.hit_ecef, rtol=0, atol=1e-8)  # the normal by two routes: rounding
    lat2, lon2, h2 = ecef_to_geodetic(b.hit_ecef)  # Vermeille's closed form, tested against pyproj
    # 1e-12 rad = 6 um; the height is the one asked for, to the sphere's departure over the shift
    np.testing.assert_allclose(b.lat, lat2, atol=1e-12)
    np.testing.assert_allclose(b.lon, lon2, atol=1e-12)
    np.testing.assert_allclose(b.h, h2, atol=1e-6)
    np.testing.assert_allclose(b.h, 400.0, atol=1e-6)


def _shift_by_quad(o, d, p, model):
    """The model's shift at the raw hit p, its angle integral done by scipy's quad in r, not by geoloc.

    The sphere osculating the ellipsoid at p along d's azimuth (Euler: 1/R = cos^2 a / M + sin^2 a / N,
    M and N of WGS-84 written here), Bouguer's invariant c = n(r_p) c0, and the polar angle the bent
    ray turns through from the camera's radius to p's, int c dr / (r sqrt(n^2 r^2 - c^2)), minus the
    straight line's (c0 for c, n = 1). n is the model's own table (linear between its nodes): each
    linear piece is integrated on its own (to 1e-17 rad each, 1e-14 over 900 pieces: 0.1 micrometre). The shift is the chord 2 r_g sin(dtheta / 2)."""
    a_wgs, f_wgs = 6378137.0, 1.0 / 298.257223563
    e2 = f_wgs * (2.0 - f_wgs)
    lat, lon, h = ecef_to_geodetic(p)
    up = up_normal_ecef(lat, lon)
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    w = 1.0 - e2 * np.sin(lat) ** 2
    N, M = a_wgs / np.sqrt(w), a_wgs * (1.0 - e2) / w**1.5
    az = np.arctan2(d @ east, d @ north)
    R = 1.0 / (np.cos(az) ** 2 / M + np.sin(az) ** 2 / N)
    centre = p - (R + h) * up
    u = d / np.linalg.norm(d)
    r_p, r_g = np.linalg.norm(o - centre), R + h
    c0 = np.linalg.norm(np.cross(o - centre, u))

    def n(r):
        return float(model.refractive_index(r - R))

    c = n(r_p) * c0

    def bent_minus_straight(r):
        return c / (r * np.sqrt(n(r) ** 2 * r**2 - c**2)) - c0 / (r * np.sqrt(r**2 - c0**2))

    h0, step, table = model.atmosphere.table()
    knots = R + h0 + step * np.arange(table.size)
    edges = np.r_[r_g, knots[(knots > r_g) & (knots < r_p)], r_p]
    dth = sum(quad(bent_minus_straight, a, b, epsabs=1e-17, epsrel=1e-10)[0] for a, b in zip(edges[:-1], edges[1:]))
    return 2.0 * r_g * abs(np.sin(0.5 * dth))


@pytest.mark.parametrize("off_nadir, tol_mm", [(80.0, 0.1), (84.0, 1.0), (85.0, 4.0)])
def test_the_shift_integral_against_scipy_quad_near_the_horizon(off_nadir, tol_mm):
    # the same integral as the kernel's Gauss-Legendre panels, by adaptive quadrature: from 18 km
    # (the horizon 85.7 deg off nadir) the shifts are 387 m, 2.9 km and 8.7 km. Measured: the
    # kernel's 4 nodes a panel within 0.01, 0.16 and 1.05 mm of quad (1.2e-7 of the shift; one quad
    # call over the whole range instead of a piece at a time moves quad's figure by 0.07 mm);
    # 3 nodes a panel are 0.02, 2.2 and 18 mm off, which the 1 and 4 mm tolerances refuse
    o, d = look(LAT, LON, 18000.0, off_nadir, azimuth_deg=53.0)
    raw = ray_geodetic_height(o, d, 0.0).ecef
    line = STANDARD_REFRACTION.correct(o, d, raw)
    assert line.status == Status.OK
    assert abs(float(line.shift_m) - _shift_by_quad(o, d, raw, STANDARD_REFRACTION)) < tol_mm * 1e-3


def test_looking_up_at_a_mountain():
    # a camera at 500 m looking 1 deg above the horizon at a slope 40 km away: the bent ray
    # (the sphere osculates at the camera, the lower end) against the ray trace
    o, d = look(LAT, LON, 500.0, 91.0, azimuth_deg=200.0)

    def intersect_up(o_, d_):  # the line's crossing of 1000 m on its way up
        lo, hi = 0.0, 2e5
        for _ in range(200):
            s = 0.5 * (lo + hi)
            if ecef_to_geodetic(o_ + s * d_ / np.linalg.norm(d_))[2] < 1000.0:
                lo = s
            else:
                hi = s
        return o_ + s * d_ / np.linalg.norm(d_), np.uint8(Status.OK)

    raw, _ = intersect_up(o, d)
    line = STANDARD_REFRACTION.correct(o, d, raw)
    assert line.status == Status.OK
    nfun = exact_n
    dd = d / np.linalg.norm(d)

    def rhs(s, y):
        lat, lon, h = ecef_to_geodetic(y[:3])
        return np.r_[y[3:] / nfun(h), (nfun(h + 0.5) - nfun(h - 0.5)) * up_normal_ecef(lat, lon)]

    def reach(s, y):
        return ecef_to_geodetic(y[:3])[2] - 1000.0

    reach.terminal, reach.direction = True, 1
    sol = solve_ivp(
        rhs,
        (0.0, 2e5),
        np.r_[o, nfun(500.0) * dd],
        method="DOP853",
        rtol=1e-12,
        atol=1e-7,
        events=reach,
        max_step=2000.0,
    )
    ref = sol.y_events[0][0][:3]
    shift = np.linalg.norm(ref - raw)
    assert shift > 5.0  # the ray climbs slower than the line: metres short of it
    # 1e-4 of the shift (401 m: at 1 deg the crossing of 1000 m slides along the ray); measured
    # 2.8 cm, 7e-5, as for the 80 deg look down
    assert np.linalg.norm(line.hit_ecef - ref) < 1e-4 * shift


def _trace_up_to(o, d, h_target):
    """The independent ray trace (the ray equation, as tests/raytrace.py) stopped where the ray climbs
    through geodetic height ``h_target``: (its point, its unit direction there)."""
    nfun = exact_n

    def rhs(s, y):
        lat, lon, h = ecef_to_geodetic(y[:3])
        return np.r_[y[3:] / nfun(h), (nfun(h + 0.5) - nfun(h - 0.5)) * up_normal_ecef(lat, lon)]

    def reach(s, y):
        return ecef_to_geodetic(y[:3])[2] - h_target

    reach.terminal, reach.direction = True, 1
    u = d / np.linalg.norm(d)
    y0 = np.r_[o, nfun(ecef_to_geodetic(o)[2]) * u]
    sol = solve_ivp(rhs, (0.0, 5e6), y0, method="DOP853", rtol=1e-12, atol=1e-7, events=reach, max_step=2000.0)
    y = sol.y_events[0][0]
    return y[:3], y[3:] / np.linalg.norm(y[3:])


@pytest.mark.parametrize("elevation_deg", [2.0, 3.0])
def test_a_long_look_up_leaves_the_air_in_the_traced_direction(elevation_deg):
    # from sea level 2 and 3 deg above the horizon to 100 km (930 and 850 km away, above nearly all
    # the air): the bent ray's direction there against the independent trace's. The stratification
    # is anchored at the lower end (the camera), where the air that bends the ray is: measured 0.23
    # and 0.05 microradians of bendings of 5.2 and 4.1 mrad; anchored at the far point instead (the
    # sphere of a point 900 km from the densest air) 9.3 and 5.8. 1 microradian is 2e-4 of the bending
    o, d = look(LAT, LON, 0.0, 90.0 + elevation_deg)
    u = d / np.linalg.norm(d)
    lo, hi = 0.0, 5e6  # the straight line's crossing of 100 km, by bisection
    for _ in range(200):
        s = 0.5 * (lo + hi)
        lo, hi = (s, hi) if ecef_to_geodetic(o + s * u)[2] < 100e3 else (lo, s)
    line = STANDARD_REFRACTION.correct(o, d, o + s * u, at_h=100e3)
    assert line.status == Status.OK
    _, traced = _trace_up_to(o, d, 100e3)
    assert np.arccos(np.clip(traced @ u, -1.0, 1.0)) > 4e-3  # the bending itself: milliradians
    assert np.arccos(np.clip(line.direction_ecef @ traced, -1.0, 1.0)) < 1e-6


def test_fixed_point_on_terrain():
    # a hilly terrain h(lat, lon); the surface callable meets a line with it by bisection; the
    # fixed point (the correction at the new hit's height) against the ray trace stopped on it
    def terrain(lat, lon):
        return 900.0 + 700.0 * np.sin((lat - LAT) * 3000.0) * np.cos((lon - LON) * 2500.0)

    class Terrain:  # a surface written here: the first crossing by a coarse scan, then bisection
        def intersect(self, los):
            o_ = np.atleast_2d(los.origin_ecef)
            d_ = np.atleast_2d(los.direction_ecef)
            d_ = d_ / np.linalg.norm(d_, axis=-1, keepdims=True)
            out = np.empty_like(o_)
            rng = np.empty(len(o_))
            for i in range(len(o_)):
                f = lambda s: ecef_to_geodetic(o_[i] + s * d_[i])[2] - terrain(*ecef_to_geodetic(o_[i] + s * d_[i])[:2])  # noqa: E731
                s = np.linspace(0.0, 2e5, 20001)
                vals = np.array([f(x) for x in s[::50]])
                k = np.argmax(vals < 0) * 50
                lo, hi = s[max(k - 50, 0)], s[k]
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if f(mid) > 0 else (lo, mid)
                out[i], rng[i] = o_[i] + hi * d_[i], hi
            lat, lon, h = ecef_to_geodetic(out)
            return GroundPoint(lat, lon, h, out, rng, np.zeros(len(o_), np.uint8), los)

    o, d = look(LAT, LON, 18000.0, 65.0, azimuth_deg=30.0)
    hit, raw, st = locate(STANDARD_REFRACTION, o[None], d[None], Terrain())
    assert st[0] == Status.OK

    def rhs(s, y):
        lat, lon, h = ecef_to_geodetic(y[:3])
        return np.r_[y[3:] / exact_n(h), (exact_n(h + 0.5) - exact_n(h - 0.5)) * up_normal_ecef(lat, lon)]

    def ground(s, y):
        lat, lon, h = ecef_to_geodetic(y[:3])
        return h - terrain(lat, lon)

    ground.terminal, ground.direction = True, -1
    sol = solve_ivp(
        rhs,
        (0.0, 2e5),
        np.r_[o, exact_n(18000.0) * d],
        method="DOP853",
        rtol=1e-12,
        atol=1e-7,
        events=ground,
        max_step=500.0,
    )
    ref = sol.y_events[0][0][:3]
    assert np.linalg.norm(ref - raw[0]) > 3.0
    # 1 cm on a slope (the terrain's 0.3 rad/km slopes turn a height error into a larger shift)
    assert np.linalg.norm(hit[0] - ref) < 0.01


def test_locate_passes_on_the_surface_status():
    o, d = look(LAT, LON, 18000.0, 45.0)
    sky = -d  # straight up
    hit, raw, st = locate(STANDARD_REFRACTION, np.stack([o, o]), np.stack([d, sky]), 0.0)
    assert st[0] == Status.OK and st[1] == Status.SKY
    assert np.isnan(hit[1]).all() and np.isfinite(hit[0]).all()


def test_the_profile_at_a_nan_height_stays_inside_its_table():
    """A NaN height (a ray of NaN) reads the table's first value, never an index int(NaN) far outside
    it (the limb kernel read there for an INVALID_INPUT ray: found with NUMBA_BOUNDSCHECK=1)."""
    from geoloc.corrections.refraction import _deps, _eps

    table, none = np.array([3e-4, 2e-4, 1e-4]), np.zeros(1)
    assert _eps(np.nan, 0, 0.0, 1000.0, table, none, none) == 3e-4
    assert _deps(np.nan, 0, 0.0, 1000.0, table) == 0.0
    # and inside the table, linear between the nodes: 1500 m is halfway from 2e-4 to 1e-4
    assert _eps(1500.0, 0, 0.0, 1000.0, table, none, none) == pytest.approx(1.5e-4, rel=1e-12)
    assert _deps(1500.0, 0, 0.0, 1000.0, table) == pytest.approx(-1e-7, rel=1e-12)


def test_the_corrected_range_is_the_distance_to_the_bent_point():
    """``range_m``: the distance from the origin to the bent point, computed here with numpy, for rays
    whose shift has every ECEF component (a batch off nadir in several azimuths)."""
    o = geodetic_to_ecef(np.deg2rad(35.5), np.deg2rad(81.0), 18000.0)
    R = R_ecef_ned(np.deg2rad(35.5), np.deg2rad(81.0))
    az = np.deg2rad([10.0, 130.0, 250.0])
    off = np.deg2rad(60.0)
    d_ned = np.stack([np.cos(az) * np.sin(off), np.sin(az) * np.sin(off), np.full(3, np.cos(off))], axis=-1)
    d = np.einsum("ij,nj->ni", R, d_ned)
    hit = HeightSurface(0.0, "geodetic").intersect(LineOfSight(np.broadcast_to(o, (3, 3)), d, np.zeros(3, np.uint8)))
    bent = STANDARD_REFRACTION.correct(np.broadcast_to(o, (3, 3)), d, np.asarray(hit.ecef))
    assert np.all(bent.status == Status.OK)
    want = np.sqrt(np.sum((np.asarray(bent.hit_ecef) - o) ** 2, axis=-1))
    assert np.allclose(bent.range_m, want, rtol=1e-12, atol=0)
    assert np.all(np.asarray(bent.shift_m) > 1.0)  # metres at 60 deg off nadir from 18 km
