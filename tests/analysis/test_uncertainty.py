"""First-order uncertainty of located points (geoloc.analysis.uncertainty) against outside numbers.

* CE90 of an ellipse: scipy's normal and chi-square quantiles at the two ends, an independent
  formula (the polar integral, solved with scipy's brentq) between them, and 4 million draws.
* The analytic Jacobian: central differences of the exact chain (every source perturbed by
  +-1e-3 sigma and located again), for every gimbal preset, on the ellipsoid and a DEM.
* The covariance, CE90 and LE90: Monte Carlo of the same budget over a grid of geometries
  (nadir to 80 degrees off nadir, ellipsoid and SRTM DEM, every gimbal preset).
* [Q17] Table 1's published standard deviations.
"""

import dataclasses
import math

import numpy as np
import pytest
import pyproj
from scipy import integrate, optimize
from scipy import stats as sps

from geoloc.analysis import montecarlo as mc
from geoloc.analysis import uncertainty as U
from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import meridian_radius, prime_vertical_radius
from geoloc.sensors.budget import ErrorBudget
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens, FisheyeLens, PinholeLens
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import HeightSurface
from geoloc.surfaces.terrain import DemSurface

TURRET = FrameSensor(
    BrownLens(
        fx=2200.0,
        fy=2195.0,
        cx=959.5,
        cy=539.5,
        width=1920,
        height=1080,
        k1=-0.21,
        k2=0.07,
        p1=4e-4,
        p2=-2e-4,
        k3=-0.01,
    ),
    PRESETS["azimuth-elevation"],
    mount=(2e-3, -1e-3, 4e-3),
    boresight=(1e-3, 2e-3, -3e-3),
    lever_arm_m=(1.5, 0.2, 0.7),
)
COMMON = {
    "north_m": 2.0,
    "east_m": 2.0,
    "up_m": 3.0,
    "heading_deg": 0.03,
    "pitch_deg": 0.02,
    "roll_deg": 0.02,
    "boresight_x_deg": 0.01,
    "boresight_y_deg": 0.01,
    "boresight_z_deg": 0.01,
    "lever_arm_x_m": 0.05,
    "lever_arm_z_m": 0.05,
    "fx_px": 2.0,
    "fy_px": 1.0,
    "cx_px": 0.5,
    "cy_px": 0.5,
    "k1": 0.001,
    "height_m": 10.0,
    "dem_m": 16.0 / 1.6448536269514722,
}
ROW, COL = 540.0, 1000.0  # a pixel off the centre: the lens's terms move it


@pytest.fixture(scope="module")
def srtm():
    return DEM.open(asset_path("dem", "srtm_jacksboro.tif"))


def sensor_for(preset):
    g = PRESETS[preset]
    return dataclasses.replace(TURRET, gimbal=g, mount=(0.0, 0.0, 0.0) if g.earth_referenced else TURRET.mount)


def budget_for(s, **extra):
    b = dict(COMMON)
    b.update({f"{a}_deg": 0.01 for a in s.angle_names})
    if not s.gimbal.earth_referenced:
        b.update(mount_x_deg=0.01, mount_y_deg=0.005, mount_z_deg=0.01)
    b.update(extra)
    return ErrorBudget(b)


def pose_for(preset, off_nadir_deg):
    """The platform over the SRTM crop's south (36.47 N), 3 km up, looking north ``off_nadir_deg`` off nadir."""
    t = off_nadir_deg
    if preset == "roll-pitch":  # gimbal roll + looks left of track: heading east, left = north
        hd, ang = 90.0, {"gimbal_roll": t, "gimbal_pitch": 0.0}
    elif preset.startswith("azimuth"):
        hd, ang = 0.0, {"azimuth": 0.0, "elevation": -(90.0 - t)}
        if preset.endswith("roll"):
            ang["sensor_roll"] = 5.0
    else:  # earth-referenced: the yaw from north, whatever the airframe's heading
        hd, ang = 20.0, {"gimbal_yaw": 0.0, "gimbal_pitch": -(90.0 - t), "gimbal_roll": 0.0}
    return Pose.from_deg(36.47, -84.246, 3000.0, hd, 1.0, 0.5, angles_deg=ang)


# ------------------------------------------------------------------ CE90 of an ellipse
def _ce_polar(q, p):
    """P(r <= R) = 1/(2 pi) int_0^2pi 1 - exp(-R^2 / (2 s(t)^2)) dt, s^2 = cos^2 + q^2 sin^2: another route."""

    def prob(R):
        f = lambda t: 1.0 - math.exp(-R * R / (2.0 * (math.cos(t) ** 2 + (q * math.sin(t)) ** 2)))  # noqa: E731
        return integrate.quad(f, 0.0, math.pi / 2.0, epsabs=1e-13, limit=200)[0] * 2.0 / math.pi - p

    return optimize.brentq(prob, 1e-3, 5.0, xtol=1e-13)


def test_ce90_ends_are_the_normal_and_rayleigh_quantiles():
    assert float(U.ce90(3.0, 0.0)) == pytest.approx(3.0 * sps.norm.ppf(0.95), rel=1e-9)
    assert float(U.ce90(3.0, 3.0)) == pytest.approx(3.0 * math.sqrt(sps.chi2.ppf(0.9, 2)), rel=1e-9)
    assert float(U.ce90(2.0, 2.0, p=0.5)) == pytest.approx(2.0 * math.sqrt(sps.chi2.ppf(0.5, 2)), rel=1e-9)


@pytest.mark.parametrize("q", [0.01, 0.1, 0.3, 0.5, 0.77, 0.95])
def test_ce90_between_the_ends_matches_the_polar_integral(q):
    # linear interpolation on 2001 ratios: h^2/8 |f''| < 1e-7; quadrature and bisection 1e-12
    assert float(U.ce90(1.0, q)) == pytest.approx(_ce_polar(q, 0.9), rel=2e-7)
    assert float(U.ce90(q * 5.0, 5.0, p=0.5)) == pytest.approx(5.0 * _ce_polar(q, 0.5), rel=2e-7)


def test_ce90_matches_four_million_draws_and_not_the_circular_rule():
    rng = np.random.default_rng(5)
    a, b = 10.0, 3.0
    x = rng.standard_normal((4_000_000, 2)) * [a, b]
    r90 = np.percentile(np.hypot(x[:, 0], x[:, 1]), 90)
    # the 0.9 quantile's standard error: sqrt(0.09 / N) / pdf(R) = 0.05 % of R here: 0.3 % is 6 of them
    assert float(U.ce90(a, b)) == pytest.approx(r90, rel=3e-3)
    # the circular approximation (2.146 sqrt((a^2 + b^2) / 2)) is 6 % off for this ellipse
    assert abs(2.1460 * math.sqrt((a * a + b * b) / 2) / r90 - 1) > 0.05


def test_ellipse_axes_and_azimuth_of_a_turned_covariance():
    az = math.radians(30.0)  # major axis 10 m towards azimuth 30 deg (east = sin az, north = cos az)
    u = np.array([math.sin(az), math.cos(az)])
    w = np.array([math.cos(az), -math.sin(az)])
    C = 100.0 * np.outer(u, u) + 4.0 * np.outer(w, w)
    major, minor, azd = U.ellipse(C)
    assert (float(major), float(minor), float(azd)) == pytest.approx((10.0, 2.0, 30.0), rel=1e-12)
    assert float(U.ellipse(np.diag([1.0, 4.0]))[2]) == pytest.approx(0.0, abs=1e-12)  # north-south major axis


# ------------------------------------------------------------------ the Jacobian
@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("off_nadir", [0.0, 55.0])
def test_jacobian_matches_central_differences_of_the_exact_chain(preset, off_nadir, srtm):
    s = sensor_for(preset)
    b = budget_for(s, time_s=0.01)
    pose = pose_for(preset, off_nadir)
    vel = np.array([40.0, -20.0, 1.5])
    for surf in (HeightSurface(500.0), DemSurface(srtm)):
        pu = U.propagate(s, pose, ROW, COL, b, surface=surf, velocity_ned_m_s=vel, dem_slope="point", jacobian=True)
        assert pu.status == Status.OK
        eps = 1e-3  # of each sigma: the chain's curvature over it is < 1e-6 of the column
        for k, key in enumerate(pu.sources):
            sig = U.surface_sigma_m(surf, b) if key in ("dem_m", "height_m") else b.sigma(key)
            enu, st = U.monte_carlo(
                s,
                pose,
                ROW,
                COL,
                b,
                surf,
                2,
                None,
                velocity_ned_m_s=vel,
                draws={key: np.array([eps * sig, -eps * sig])},
            )
            assert np.all(st == Status.OK), key
            fd = (enu[0] - enu[1]) / (2 * eps)
            col = pu.jacobian_enu[:, k]
            # 1e-4 of the column (the difference's rounding: 1e-9 m of ECEF over 1e-3 sigma) + 1 um
            assert np.allclose(col, fd, rtol=0, atol=1e-4 * np.linalg.norm(fd) + 1e-6), (surf, key, col, fd)


LENSES = {
    "pinhole": PinholeLens(fx=2200.0, fy=2195.0, cx=959.5, cy=539.5, width=1920, height=1080, skew=0.8),
    "brown": TURRET.lens,
    "brown-rational": BrownLens(
        fx=2200.0,
        fy=2195.0,
        cx=959.5,
        cy=539.5,
        width=1920,
        height=1080,
        k1=-0.2,
        k2=0.05,
        k3=0.01,
        k4=0.02,
        k5=-0.01,
        k6=0.003,
        p1=2e-4,
        p2=1e-4,
    ),
    "fisheye": FisheyeLens(
        fx=900.0, fy=900.0, cx=959.5, cy=539.5, width=1920, height=1080, k1=0.05, k2=-0.01, k3=0.002, k4=-1e-4
    ),
}


@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("lens", list(LENSES))
def test_compiled_engine_equals_the_numpy_reference(preset, lens, srtm):
    """The numba kernels against the reference path (whose Jacobian the central differences above
    and the Monte Carlo below judge), on a batch of varied rays, an off-sensor pixel and a ray to
    the sky among them."""
    s = dataclasses.replace(sensor_for(preset), lens=LENSES[lens])
    extra = {"skew_px": 0.3} if lens == "pinhole" else {"k1": 0.001, "k2": 5e-4} if lens != "pinhole" else {}
    b = budget_for(s, time_s=0.01, **extra)
    if lens == "pinhole":
        b = ErrorBudget({k: v for k, v in b.sigmas.items() if k != "k1"})
    rng = np.random.default_rng(5)
    n = 64
    base = pose_for(preset, 30.0)
    ang = {a: np.degrees(np.asarray(base.angle(a))) + rng.uniform(-25, 25, n) for a in s.angle_names}
    pose = Pose.from_deg(
        36.47 + rng.uniform(0, 0.1, n),
        -84.246 + rng.uniform(0, 0.1, n),
        rng.uniform(2000, 4000, n),
        np.degrees(float(base.heading)) + rng.uniform(-30, 30, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-3, 3, n),
        angles_deg=ang,
    )
    row, col = rng.uniform(1, 1080, n), rng.uniform(1, 1920, n)
    row[3] = 5000.0  # off the sensor: OUTSIDE_SENSOR in both
    vel = np.stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(-3, 3, n)], -1)
    for surf in (HeightSurface(500.0), DemSurface(srtm)):
        kw = dict(surface=surf, velocity_ned_m_s=vel, jacobian=True)
        a = U.propagate(s, pose, row, col, b, engine="numba", **kw)
        r = U.propagate(s, pose, row, col, b, engine="numpy", **kw)
        assert a.sources == r.sources
        np.testing.assert_array_equal(a.status, r.status)
        assert a.status[3] == Status.OUTSIDE_SENSOR
        ok = r.status == Status.OK
        assert ok.sum() > n // 2
        ref = r.jacobian_enu[ok]
        scale = np.linalg.norm(ref, axis=1, keepdims=True)  # each column's length, per ray
        # the angles, position, lever arm and surface: the same formulas (rounding, 1e-10 of the
        # column); the lens: the kernel differentiates the projection (linear in k1..k4, so exact)
        # where the reference takes the +-1 sigma secant of the inverse, which is off the true
        # derivative by a second-order term: 1.3e-5 of the column for the fisheye's k1 at a corner
        # (measured against +-1e-3 sigma secants), so 5e-5
        assert np.all(np.abs(a.jacobian_enu[ok] - ref) <= 5e-5 * scale + 1e-9), (surf, lens)
        for f in ("ce90_m", "le90_m", "ellipse_major_m", "ellipse_minor_m"):
            np.testing.assert_allclose(getattr(a, f)[ok], getattr(r, f)[ok], rtol=1e-5, err_msg=f)
            assert np.all(np.isnan(getattr(a, f)[~ok])), f
        # the azimuth of a near-circle is ill conditioned: a relative change e of the covariance turns
        # the axes by up to e a^2 / (a^2 - b^2) rad; e = 5e-5 as the columns above
        el = ok & (r.ellipse_minor_m < 0.999 * r.ellipse_major_m)
        a2, b2 = r.ellipse_major_m[el] ** 2, r.ellipse_minor_m[el] ** 2
        daz = np.abs((a.ellipse_azimuth_deg[el] - r.ellipse_azimuth_deg[el] + 90) % 180 - 90)
        assert np.all(daz <= np.degrees(5e-5 * a2 / (a2 - b2)))
        if isinstance(surf, DemSurface):
            # the DEM kernel's footprint plane, terrain RMS and grazing test: the reference's formulas;
            # the footprint is the covariance's, so the lens columns' 5e-5 (above) carries over to the
            # RMS (measured: 1.4e-5 for the fisheye, 1e-7 elsewhere), plus 1e-6 m of rounding
            np.testing.assert_allclose(a.terrain_rms_m[ok], r.terrain_rms_m[ok], rtol=5e-5, atol=1e-6)
            assert np.all(np.isnan(a.terrain_rms_m[~ok]))
            np.testing.assert_array_equal(a.grazing, r.grazing)
            np.testing.assert_array_equal(a.linear, r.linear)
            p = U.propagate(s, pose, row, col, b, surface=surf, velocity_ned_m_s=vel, engine="numba", dem_slope="point")
            q = U.propagate(s, pose, row, col, b, surface=surf, velocity_ned_m_s=vel, engine="numpy", dem_slope="point")
            np.testing.assert_allclose(p.ce90_m[ok], q.ce90_m[ok], rtol=1e-5)
            np.testing.assert_allclose(p.le90_m[ok], q.le90_m[ok], rtol=1e-5)


def test_time_error_is_the_platform_moving_by_its_velocity():
    s = sensor_for("roll-pitch")
    pose = pose_for("roll-pitch", 30.0)
    a = U.propagate(
        s,
        pose,
        ROW,
        COL,
        ErrorBudget({"time_s": 0.1}),
        surface=HeightSurface(500.0),
        velocity_ned_m_s=[60.0, 80.0, 0.0],
        jacobian=True,
    )
    b = U.propagate(
        s, pose, ROW, COL, ErrorBudget({"north_m": 6.0, "east_m": 8.0}), surface=HeightSurface(500.0), jacobian=True
    )
    # one velocity, one draw: dt moves the platform (6, 8) m together -> J_time = J_north + J_east
    assert np.allclose(a.jacobian_enu[:, 0], b.jacobian_enu.sum(-1), atol=1e-9)
    with pytest.raises(ValueError, match="time_s = 0.1 needs the platform's velocity"):
        U.propagate(s, pose, ROW, COL, ErrorBudget({"time_s": 0.1}, source="x.toml"), surface=HeightSurface(500.0))


def test_a_ray_without_a_ground_point_gets_nan_and_its_status():
    s = sensor_for("azimuth-elevation")
    pose = Pose.from_deg(
        [36.5, 36.5], -84.2, 3000.0, 0.0, 0.0, 0.0, angles_deg={"azimuth": 0.0, "elevation": [-30.0, 10.0]}
    )
    pu = U.propagate(s, pose, ROW, COL, budget_for(s), surface=HeightSurface(0.0))
    assert pu.status.tolist() == [Status.OK, Status.SKY]
    assert np.isfinite(pu.ce90_m[0]) and np.isnan(pu.ce90_m[1]) and np.isnan(pu.le90_m[1])


@pytest.mark.parametrize("engine", ["numba", "numpy"])
def test_without_the_jacobian_every_other_output_is_the_same(engine, srtm):
    # the default (jacobian=False) keeps no (n, 3, k) array: the kernels use a scratch row per ray; the
    # covariance, ellipse, CE90, LE90, terrain RMS and grazing flags must not move by a bit, and a
    # ray without a ground point (the sky, index 1) keeps its NaN and status
    s = sensor_for("azimuth-elevation")
    rng = np.random.default_rng(9)
    n = 24
    elev = rng.uniform(-80.0, -30.0, n)
    elev[1] = 10.0
    pose = Pose.from_deg(
        36.47 + rng.uniform(0, 0.1, n),
        -84.246 + rng.uniform(0, 0.1, n),
        3000.0,
        rng.uniform(0, 360, n),
        0.0,
        0.0,
        angles_deg={"azimuth": rng.uniform(0, 360, n), "elevation": elev},
    )
    b = budget_for(s, refraction=0.05)
    for surf in (HeightSurface(500.0), DemSurface(srtm)):
        kw = dict(surface=surf, engine=engine)
        full = U.propagate(s, pose, ROW, COL, b, jacobian=True, **kw)
        lean = U.propagate(s, pose, ROW, COL, b, **kw)  # the default: no Jacobian
        assert lean.jacobian_enu is None and full.jacobian_enu.shape == (n, 3, len(full.sources))
        assert lean.sources == full.sources and full.status[1] == Status.SKY
        np.testing.assert_array_equal(lean.status, full.status)
        for f in ("cov_enu", "ce90_m", "le90_m", "ellipse_major_m", "ellipse_minor_m", "ellipse_azimuth_deg"):
            np.testing.assert_array_equal(getattr(lean, f), getattr(full, f), err_msg=f)
        np.testing.assert_array_equal(lean.terrain_rms_m, full.terrain_rms_m)
        np.testing.assert_array_equal(lean.grazing, full.grazing)


def test_a_dem_without_a_vertical_error_is_refused_naming_the_keys():
    etopo = DEM.open(asset_path("dem", "etopo5_flight_area.tif"))
    s = sensor_for("roll-pitch")
    with pytest.raises(ValueError, match="dem_m.*dem_product"):
        U.propagate(
            s,
            Pose.from_deg(35.5, 80.9, 9000.0, 0, 0, 0, 20.0, 0.0),
            None,
            None,
            ErrorBudget({"heading_deg": 0.1}),
            surface=DemSurface(etopo),
        )


# ------------------------------------------------------------------ against Monte Carlo
#: Samples per geometry. The 0.9 quantile's standard error is sqrt(0.09 / N) / (pdf(R) R) of R:
#: 0.88 / sqrt(N) for a normal error along one line (the worst case, LE90 and a thin ellipse),
#: 0.65 / sqrt(N) for a circle: 0.62 % at N = 20 000, so 5 % is 8 standard errors.
N_MC = 20_000


@pytest.mark.parametrize("preset", list(PRESETS))
def test_predicted_ce90_le90_within_5_percent_of_monte_carlo(preset, srtm):
    s = sensor_for(preset)
    b = budget_for(s)
    flagged = []
    for i, off_nadir in enumerate((0.0, 20.0, 40.0, 60.0, 70.0, 80.0)):
        pose = pose_for(preset, off_nadir)
        for surf in (HeightSurface(500.0), DemSurface(srtm)):
            pu = U.propagate(s, pose, ROW, COL, b, surface=surf)
            enu, st = U.monte_carlo(s, pose, ROW, COL, b, surf, N_MC, np.random.default_rng(100 + i))
            assert np.mean(st == Status.OK) == 1.0
            ce, le = U.empirical_ce90_le90(enu, st)
            err = (float(pu.ce90_m) / ce - 1, float(pu.le90_m) / le - 1)
            if bool(pu.linear):
                assert max(map(abs, err)) < 0.05, (preset, off_nadir, surf, err)
                continue
            # the first order is flagged as a guide only: on a DEM, never on the ellipsoid
            assert isinstance(surf, DemSurface)
            flagged.append((off_nadir, bool(pu.grazing), err))
            if not pu.grazing:  # hills inside the footprint: still a guide (measured 7 % at most)
                assert max(map(abs, err)) < 0.10, (preset, off_nadir, err)
            # grazing a ridge: Monte Carlo's cloud has two parts (the ridge, the slope behind):
            # no normal error describes it; the flag is the answer
    print(preset, "flagged (off nadir, grazing, CE90 and LE90 errors):", flagged)
    assert len(flagged) <= 3, flagged  # of 6 DEM geometries: most of the grid is within 5 %


def test_the_strict_point_slope_is_worse_on_rough_terrain_than_the_footprint_plane(srtm):
    # yaw-pitch-roll at 60 deg: the footprint's plane is the better linearisation (Monte Carlo decides)
    s = sensor_for("azimuth-elevation-roll")
    b = budget_for(s)
    pose = pose_for("azimuth-elevation-roll", 60.0)
    surf = DemSurface(srtm)
    enu, st = U.monte_carlo(s, pose, ROW, COL, b, surf, N_MC, np.random.default_rng(7))
    ce, _ = U.empirical_ce90_le90(enu, st)
    foot = float(U.propagate(s, pose, ROW, COL, b, surface=surf).ce90_m)
    point = float(U.propagate(s, pose, ROW, COL, b, surface=surf, dem_slope="point").ce90_m)
    assert abs(foot / ce - 1) < abs(point / ce - 1)


# ------------------------------------------------------------------ [Q17] Table 1
def test_q17_table1_standard_deviations_from_the_propagation():
    model = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
    b = U.budget_from_error_model(model)
    pu = U.propagate(
        model.camera,
        model.nominal_pose(),
        model.row,
        model.col,
        b,
        surface=HeightSurface(model.target_h_m, model.height_kind),
        outside="extrapolate",
    )
    lat, h = float(pu.lat), float(pu.h)
    se, sn, su = np.sqrt(np.diag(pu.cov_enu))
    s_lat = math.degrees(sn / (meridian_radius(lat) + h))
    s_lon = math.degrees(se / ((prime_vertical_radius(lat) + h) * math.cos(lat)))
    # [Q17] Table 1 prints 0.00048 deg, 0.00060 deg, 62.3 m from N = 5000 samples: 2 digits (+-1 %)
    # and the paper's own sampling error, 1/sqrt(2N) = 1 %: 3 % is the two plus one more sampling error
    for got, paper in ((s_lat, 0.00048), (s_lon, 0.00060), (su, 62.3)):
        assert got == pytest.approx(paper, rel=0.03)
    # and the [Q17] chain's own central differences through the error model (another route: the
    # error model's sources perturbed in the paper's frames): the budget's mapping is exact to 1e-4
    fo = mc.first_order(model)
    assert (s_lat, s_lon, su) == pytest.approx((fo.std_lat_deg, fo.std_lon_deg, fo.std_h_m), rel=1e-4)


# ------------------------------------------------------------------ on a DEM mosaic
def _plane_tiles(folder, slope):
    """A terrain rising east at ``slope`` (metres per metre) as two GeoTIFF tiles split at 84.2 W, and
    the same nodes as one raster. Heights linear in longitude: the bilinear DEM is that plane exactly."""
    import rasterio

    folder.mkdir()
    d, lat0, lon0 = 2e-4, 36.48, -84.2  # node spacing [deg], seam at lon0
    _, _, m_per_deg = pyproj.Geod(ellps="WGS84").inv(lon0, lat0, lon0 + 1e-3, lat0)
    k = slope * m_per_deg / 1e-3  # metres per degree of longitude
    lon = lon0 + d * np.arange(-50, 51)  # 101 nodes, 1 km east-west
    lat = lat0 + 0.005 - d * np.arange(51)  # 51 nodes, north to south
    H = np.broadcast_to(300.0 + k * (lon - lon0), (len(lat), len(lon))).astype("float64")
    prof = dict(driver="GTiff", count=1, dtype="float64", crs="EPSG:4326")

    def write(p, c0, c1):
        tr = rasterio.Affine.translation(lon[c0] - d / 2, lat[0] + d / 2) @ rasterio.Affine.scale(d, -d)
        with rasterio.open(p, "w", height=len(lat), width=c1 - c0, transform=tr, **prof) as dst:
            dst.write(H[:, c0:c1], 1)
        return p

    tiles = [write(folder / "west.tif", 0, 50), write(folder / "east.tif", 50, 101)]
    return tiles, write(folder.parent / "merged.tif", 0, 101), (lambda lon_deg: 300.0 + k * (lon_deg - lon0))


def test_on_a_mosaic_the_dem_error_moves_the_point_by_the_mosaic_slope(tmp_path):
    # the DEM's vertical error dz moves the hit along the ray D by dz / (m . D), m = (-g_e, -g_n, 1)
    # the terrain's normal in ENU (the first order at a plane): a closed form, with the plane's slope
    # g_e from pymap3d (rise over east run between two of its points) and D in ENU from pymap3d
    import pymap3d

    from geoloc.surfaces.mosaic import DemMosaic

    slope = 0.3
    tiles, merged, H = _plane_tiles(tmp_path / "tiles", slope)
    s = sensor_for("azimuth-elevation")
    # 1300 m up, 838 m west of the seam, looking east 40 deg off nadir: the hit is near the seam
    pose = Pose.from_deg(36.478, -84.2094, 1300.0, 90.0, 0.0, 0.0, angles_deg={"azimuth": 0.0, "elevation": -50.0})
    b = ErrorBudget({"dem_m": 10.0, "heading_deg": 0.02})
    mosaic = DemMosaic.open([str(p) for p in tiles], datum="ellipsoid", block=32)
    on_mosaic = U.propagate(s, pose, None, None, b, surface=mosaic, dem_slope="point", jacobian=True)
    on_raster = U.propagate(
        s, pose, None, None, b, surface=DemSurface(DEM.open(merged, datum="ellipsoid")), dem_slope="point"
    )
    assert on_mosaic.status == Status.OK and on_mosaic.sources[-1] == "dem_m"

    lat, lon = math.degrees(float(on_mosaic.lat)), math.degrees(float(on_mosaic.lon))
    e, _, u = pymap3d.geodetic2enu(lat, lon + 1e-5, H(lon + 1e-5), lat, lon, H(lon))
    g_e = u / e
    los = s.line_of_sight(*s.center_pixel, pose)
    D = np.array(pymap3d.ecef2enuv(*np.asarray(los.direction_ecef).reshape(3), lat, lon))
    m = np.array([-g_e, 0.0, 1.0])
    expected = 10.0 * D / (m @ D)
    level = 10.0 * D / D[2]  # what a surface without its terrain gives
    got = np.asarray(on_mosaic.jacobian_enu)[..., -1].reshape(3)
    # 1e-4 of 10 m: the hit (solved to under 1 mm on a 1.3 km range) and the flat ENU at the hit
    # (metres over the Earth's radius, 1e-6) move it by far less; the level answer is 25 % off
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4 * 10.0)
    assert np.max(np.abs(level - expected)) > 1.0
    # the default footprint plane is the same plane: the same column
    foot = U.propagate(s, pose, None, None, b, surface=mosaic, jacobian=True)
    np.testing.assert_allclose(np.asarray(foot.jacobian_enu)[..., -1].reshape(3), expected, rtol=1e-4, atol=1e-3)
    # and the mosaic's answer is the one raster's, the same nodes (float rounding of the windows)
    np.testing.assert_allclose(on_mosaic.cov_enu, on_raster.cov_enu, rtol=1e-9, atol=1e-9)


def test_the_linear_flag_compares_the_terrain_with_the_dems_own_sigma_when_given():
    """``linear``: the terrain's RMS against 0.1 of the DEM's vertical sigma when it is given (even
    below 1 m), else of the point's own vertical sigma; the numbers worked here by hand."""
    from geoloc.analysis.uncertainty import PointUncertainty

    cov = np.diag([4.0, 4.0, 0.01])[None]  # the point's vertical sigma 0.1 m

    def pu(terrain_rms, surface_sigma):
        z = np.zeros(1)
        return PointUncertainty(
            z, z, z, np.zeros(1, np.uint8), cov, np.zeros((1, 3, 1)), ("x",), z, z, z, z, z,
            terrain_rms_m=np.array([terrain_rms]), surface_sigma_m=surface_sigma,
        )  # fmt: skip

    # a DEM sigma of 0.5 m: the threshold is 0.05 m, so 0.04 m of relief is a plane, 0.06 m is not
    assert pu(0.04, 0.5).linear.tolist() == [True]
    assert pu(0.06, 0.5).linear.tolist() == [False]
    # no DEM sigma: the point's own 0.1 m, threshold 0.01 m
    assert pu(0.009, 0.0).linear.tolist() == [True]
    assert pu(0.04, 0.0).linear.tolist() == [False]
    # no terrain (a constant height): linear
    import dataclasses

    assert dataclasses.replace(pu(0.5, 0.0), terrain_rms_m=None).linear.tolist() == [True]


def test_normalised_errors_in_their_own_ellipse_by_hand():
    """d^2 = (along / major)^2 + (across / minor)^2, azimuth clockwise from north; a zero minor axis
    is floored at 1e-9 of the major (an error across a degenerate ellipse is far outside it)."""
    from geoloc.analysis.uncertainty import normalised_errors, outside_ellipse

    # major axis north (azimuth 0): 3 m north and 1 m east in a 10 x 1 m ellipse: d^2 = 0.09 + 1
    assert normalised_errors(1.0, 3.0, 10.0, 1.0, 0.0) == pytest.approx(math.sqrt(1.09), rel=1e-14)
    # major axis east (azimuth 90): the same error is 1 m along, 3 m across
    assert normalised_errors(1.0, 3.0, 10.0, 1.0, 90.0) == pytest.approx(math.sqrt(0.01 + 9.0), rel=1e-14)
    # a zero minor axis: 1 m across is 1 / (1e-9 x 10) = 1e8 sigma
    assert normalised_errors(1.0, 0.0, 10.0, 0.0, 0.0) == pytest.approx(1e8, rel=1e-12)
    # the 99 % ellipse's radius sqrt(-2 ln 0.01) = 3.0349 sigma, both sides of it
    r99 = math.sqrt(-2.0 * math.log(0.01))
    assert (
        outside_ellipse(0.0, 1.001 * r99, 1.0, 1.0, 0.0).item()
        and not outside_ellipse(0.0, 0.999 * r99, 1.0, 1.0, 0.0).item()
    )
