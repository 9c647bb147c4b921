"""Tests written from the mutation run (``python benchmarks/mutation.py``, docs/testing.md).

Each test kills mutants of the core's geometry modules that the rest of the suite let
survive: contracts nobody had written down (defaults, range boundaries, batched shapes,
the non-converged branch of a solver, numerical stability). The expected values are
closed forms or definitions written out here, not the modules' outputs.
"""

import dataclasses
import math

import numpy as np
import pytest

from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose, T_ecef_ned, T_ned_ecef_q17_factors
from geoloc.geodesy.ellipsoid import ecef_to_geodetic_q17, up_normal_ecef, wrap_lon
from geoloc.status import Status
from geoloc.surfaces.height import ray_geodetic_height, ray_inflated_ellipsoid

A = 6378137.0
B = A * (1 - 1 / 298.257223563)


# ----------------------------------------------------------------- geodesy/ellipsoid.py
def test_q17_iteration_defaults_start_value_and_result_are_the_papers():
    xyz = np.array([[818401.683, 5149731.994, 3691808.776], [-2e6, 3e6, -5.2e6]])
    it = ecef_to_geodetic_q17(xyz)
    assert it.n_iter == 4 and it.h_history.shape == (5, 2)  # [Q17]: four iterations by default
    # eq. 12's start value h_0 = |r| - sqrt(a b), with a, b of WGS-84 written out
    np.testing.assert_allclose(it.h_history[0], np.linalg.norm(xyz, axis=-1) - math.sqrt(A * B), rtol=0, atol=1e-6)
    with pytest.raises(dataclasses.FrozenInstanceError):  # results are values, not state
        it.n_iter = 5


def test_up_normal_closed_form_on_a_batch():
    lat = np.deg2rad(np.array([[0.0, 30.0, -45.0], [60.0, 89.0, -10.0]]))
    lon = np.deg2rad(np.array([[0.0, 100.0, -170.0], [45.0, 10.0, 180.0]]))
    n = up_normal_ecef(lat, lon)
    assert n.shape == (2, 3, 3)  # the components on the last axis
    ref = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    np.testing.assert_allclose(n, ref, atol=1e-15)
    np.testing.assert_allclose(up_normal_ecef(0.0, 0.0), [1.0, 0.0, 0.0], atol=1e-15)


def test_wrap_lon_into_minus_pi_pi():
    x = np.array([0.0, math.pi, -math.pi, 1.5 * math.pi, -1.5 * math.pi, 7.0, -7.0, 4 * math.pi + 0.25])
    ref = np.array(
        [0.0, -math.pi, -math.pi, -0.5 * math.pi, 0.5 * math.pi, 7.0 - 2 * math.pi, -7.0 + 2 * math.pi, 0.25]
    )
    np.testing.assert_allclose(wrap_lon(x), ref, atol=1e-12)
    assert np.all((wrap_lon(x) >= -math.pi) & (wrap_lon(x) < math.pi))


# ----------------------------------------------------------------- frames/rotations.py
def test_transform_translation_and_apply_on_batches():
    rng = np.random.default_rng(0)
    R = np.stack([rot.rz(a) @ rot.rx(b) for a, b in rng.uniform(-3, 3, (4, 2))])
    t = np.array([1.0, -2.0, 3.0])
    T = rot.transform(R, t)  # batched rotations, one translation
    assert T.shape == (4, 4, 4)
    np.testing.assert_array_equal(T[:, :3, :3], R)
    np.testing.assert_array_equal(T[:, :3, 3], np.broadcast_to(t, (4, 3)))
    np.testing.assert_array_equal(T[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (4, 4)))
    ts = rng.normal(size=(5, 3))
    Tt = rot.translation(ts)  # batched translations
    assert Tt.shape == (5, 4, 4)
    np.testing.assert_array_equal(Tt[:, :3, :3], np.broadcast_to(np.eye(3), (5, 3, 3)))
    np.testing.assert_array_equal(Tt[:, :3, 3], ts)
    t2 = rng.normal(size=(2, 5, 3))  # two batch axes
    np.testing.assert_array_equal(rot.translation(t2)[..., :3, 3], t2)
    p = rng.normal(size=(4, 3))
    # apply: x_a = R x_b + t, written out
    np.testing.assert_allclose(rot.apply(T, p), np.einsum("nij,nj->ni", R, p) + t, atol=1e-14)
    np.testing.assert_allclose(rot.apply(rot.invert(T), rot.apply(T, p)), p, atol=1e-13)


# ----------------------------------------------------------------- frames/chain.py
def test_q17_factors_on_a_batch_equal_the_direct_form():
    lat = np.deg2rad(np.array([35.48, -60.0, 10.0]))
    lon = np.deg2rad(np.array([80.97, -120.0, 179.0]))
    h = np.array([18000.0, 500.0, -100.0])
    f = T_ned_ecef_q17_factors(lat, lon, h)
    assert all(m.shape == (3, 4, 4) for m in f)
    prod = f[0] @ f[1] @ f[2] @ f[3]
    np.testing.assert_allclose(prod, rot.invert(T_ecef_ned(lat, lon, h)), atol=1e-6)  # float64 at 6.4e6 m


def test_pose_defaults_are_zero():
    p = Pose(0.1, 0.2, 1000.0)
    for k in ("heading", "pitch", "roll", "gimbal_roll", "gimbal_pitch"):
        assert float(getattr(p, k)) == 0.0, k
    q = Pose.from_deg(35.0, 80.0, 1000.0)
    for k in ("heading", "pitch", "roll", "gimbal_roll", "gimbal_pitch"):
        assert float(getattr(q, k)) == 0.0, k
    assert Pose.from_deg(np.zeros(3), 80.0, 1000.0).shape == (3,)
    assert Pose.from_deg(35.0, 80.0, 1000.0, angles_deg={"azimuth": np.zeros((2, 1))}).shape == (2, 1)


@pytest.mark.parametrize(
    "field, value, valid",
    [
        # docs: lat in [-90, 90] deg, lon and heading in [-360, 360] deg, pitch in [-90, 90] deg,
        # h in [-12 km, 1e8 m], other joint angles in [-360, 360] deg; both ends included
        ("lat", -math.pi / 2, True),
        ("lat", -1.6, False),
        ("lat", math.pi / 2, True),
        ("lon", -2 * math.pi, True),
        ("lon", -7.0, False),
        ("lon", 7.0, False),
        ("h", -1.2e4, True),
        ("h", -11999.5, True),
        ("h", -12000.5, False),
        ("heading", -1.0, True),
        ("heading", 4.0, True),
        ("heading", 6.3, False),
        ("heading", -6.3, False),
        ("pitch", -math.pi / 2, True),
        ("pitch", -2.0, False),
        ("pitch", 2.0, False),
        ("azimuth", -6.0, True),
        ("azimuth", 6.0, True),
        ("azimuth", -6.3, False),
        ("azimuth", 6.3, False),
    ],
)
def test_pose_range_boundaries(field, value, valid):
    kw = dict(lat=0.5, lon=1.0, h=1000.0)
    angles = {}
    if field == "azimuth":
        angles = {"azimuth": np.float64(value)}
    else:
        kw[field] = value
    p = Pose(kw.pop("lat"), kw.pop("lon"), kw.pop("h"), **kw, angles=angles)
    assert bool(p.invalid_mask()) == (not valid)
    if valid:
        p.validate()
    else:
        with pytest.raises(ValueError, match=field):
            p.validate()


def test_pose_validate_names_the_first_bad_value():
    p = Pose(np.array([0.1, 2.0, 3.0]), 0.0, 0.0)
    with pytest.raises(ValueError, match=r"lat = 114\.592 deg"):  # 2 rad, the first of the two
        p.validate()


# ----------------------------------------------------------------- surfaces/height.py
def test_inflated_ellipsoid_degenerate_heights_and_origin_on_the_surface():
    d = np.array([-1.0, 0.0, 0.0])
    o = np.array([A + 100e3, 0.0, 0.0])
    # h <= -b leaves no ellipsoid: invalid input, also a little below -b
    for h in (-B, -B - 0.5):
        assert int(ray_inflated_ellipsoid(o, d, h).status) == Status.INVALID_INPUT
    assert int(ray_inflated_ellipsoid(o, d, -B + 1000.0).status) == Status.OK
    # an origin exactly on the inflated surface is not below it: the hit is the origin
    on = np.array([A + 250.0, 0.0, 0.0])
    hit = ray_inflated_ellipsoid(on, d, 250.0)
    assert int(hit.status) == Status.OK and float(hit.s) == 0.0


def test_geodetic_height_unconverged_branch():
    # one Newton step from the inflated answer (6 mm off at 5 km) is enough for 1 mm, but
    # with max_iter=1 the loop ends before it checks: the final check must see it converged.
    # With max_iter=0 and 1e-6 m the inflated answer itself is not converged. A batch of
    # one ray: with scalar inputs this branch raises TypeError (s is a numpy scalar there),
    # a known bug of surfaces/height.py's scalar path (not this test's to fix).
    o = np.array([[A * math.cos(0.6) + 18000.0, 0.0, B * math.sin(0.6)]])
    d = np.array([[-0.8, 0.3, -0.5]])
    d /= np.linalg.norm(d)
    one = ray_geodetic_height(o, d, 5000.0, tol_m=1e-3, max_iter=1)
    assert one.status[0] == Status.OK and np.isfinite(one.s[0])
    ref = ray_geodetic_height(o, d, 5000.0)
    assert one.s[0] == pytest.approx(ref.s[0], abs=1e-3)
    none = ray_geodetic_height(o, d, 5000.0, tol_m=1e-6, max_iter=0)
    assert none.status[0] == Status.NO_CONVERGENCE and np.isnan(none.s[0])


# ----------------------------------------------------------------- surfaces/terrain.py
def _ridge_lon_dem(n_cols=121):
    from geoloc.surfaces.dem import DEM

    lo = 78.0 + 0.0005 * np.arange(n_cols)
    z = np.tile(300.0 * np.clip(1 - np.abs(lo - 78.02) / 0.0025, 0, None), (21, 1))
    return DEM.from_array(z, 36.05, 78.0, 0.005, 0.0005)


def _rays(frame, origins, d):
    from geoloc.surfaces.base import LineOfSight

    o = frame.to_ecef(np.asarray(origins, float))
    dd = frame.R_ecef_enu @ (np.asarray(d, float) / np.linalg.norm(d))
    return o, dd, LineOfSight


def test_intersect_dem_broadcasts_origins_against_one_direction():
    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.terrain import intersect_dem

    dem = _ridge_lon_dem()
    o, d, LOS = _rays(
        EnuFrame.from_deg(36.0, 78.002, 0.0), [[0, 0, 400.0], [0, 50.0, 400.0], [0, -80.0, 420.0]], [1.0, 0.0, -0.12]
    )
    for method in ("exact", "steps", "bisect"):
        batch = intersect_dem(LOS(o, d, np.uint8(0)), dem, method)  # (3, 3) origins, (3,) direction, () status
        assert batch.h.shape == (3,)
        for k in range(3):
            one = intersect_dem(LOS(o[k], d, np.uint8(0)), dem, method)
            assert float(one.h) == pytest.approx(batch.h[k], abs=1e-9)


def test_steps_start_just_below_a_camera_lower_than_the_dem():
    # [Q17]'s H_0 is the DEM's highest node, or 1 mm below the camera when it flies lower
    from geoloc.frames.enu import EnuFrame
    from geoloc.geodesy.ellipsoid import ecef_to_geodetic
    from geoloc.surfaces.terrain import intersect_dem

    dem = _ridge_lon_dem()  # 300 m ridge at 78.02 E, floor 0 m
    o, d, LOS = _rays(EnuFrame.from_deg(36.0, 78.002, 0.0), [[0, 0, 120.0]], [0.3, 0.1, -1.0])
    hit = intersect_dem(LOS(o, d, np.zeros(1, np.uint8)), dem, "steps", eps_h=1.0, trace=True)
    h_cam = float(ecef_to_geodetic(o[0])[2])
    assert hit.status[0] == Status.OK
    assert hit.trace.ray(0)["H"][0] == pytest.approx(h_cam - 1e-3, abs=1e-6)


class _EquatorFake:
    """A DEM stand-in for _hidden: terrain 10 m above a ray along the equator (due east from
    0 E at 1 km), except where the ray's parameter s is in ``window`` (10 m below it)."""

    is_geographic = True

    def __init__(self, window, cell_deg):
        from types import SimpleNamespace

        self.window = window
        self.grid = SimpleNamespace(dlat_deg=cell_deg, dlon_deg=cell_deg, lat_north_deg=0.0, lat_south_deg=0.0)

    def height(self, lat, lon):
        s = (A + 1000.0) * np.tan(lon)
        h_ray = np.hypot(A + 1000.0, s) - A
        inside = (s > self.window[0]) & (s < self.window[1])
        return np.where(inside, h_ray - 10.0, h_ray + 10.0)


def test_hidden_samples_up_to_the_last_quarter_cell():
    # the bisection answer at s = 1000 m, the first crossing at 0: an emergence only in the
    # last 1.5 quarter cells before the answer must be seen (the sample one quarter cell
    # before it lies in it), and one that is not there must not
    from geoloc.surfaces import terrain

    cell_deg = 0.001
    q = np.deg2rad(cell_deg) * A / 4.0  # the solver's quarter cell [m]
    o = np.array([[A + 1000.0, 0.0, 0.0]])
    d = np.array([[0.0, 1.0, 0.0]])
    s_first, s_bis = np.array([0.0]), np.array([1000.0])
    ns = int(np.ceil(1000.0 / q))
    step = 1000.0 / ns
    seen = terrain._hidden(
        o, d, s_bis, s_first, _EquatorFake((1000.0 - 1.5 * step, 2000.0), cell_deg), np.array([True])
    )
    assert seen[0]
    none = terrain._hidden(o, d, s_bis, s_first, _EquatorFake((2000.0, 3000.0), cell_deg), np.array([True]))
    assert not none[0]


def test_walk_leaves_a_two_block_dem_on_every_side():
    """17 x 17 nodes: 16 x 16 cells, exactly two 8-cell blocks a side (the block count is a
    ceiling division of the cells, not of the nodes: one more would be an empty block the
    walk enters and reads beyond its tables). Horizontal rays 0.8-1.8 m over a terrain of
    100-101 m start inside the walk's top surface, cross every cell to the edge and leave:
    LEFT_DEM after walking, on all four sides and a diagonal. A ray that comes down hits.
    Run under NUMBA_BOUNDSCHECK=1 (with an empty NUMBA_CACHE_DIR) the table reads are checked
    too: that is how the extra-block mutant shows (docs/testing.md)."""
    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.base import LineOfSight
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import intersect_dem

    rng = np.random.default_rng(4)
    dem = DEM.from_array(100.0 + rng.random((17, 17)), 36.008, 78.0, 0.001, 0.001)
    fr = EnuFrame.from_deg(36.0, 78.008, 0.0)
    dirs = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.7, 0.7, 0.0]]
    o = fr.to_ecef(np.array([0.0, 0.0, 101.8]))
    d = np.stack([fr.R_ecef_enu @ (np.array(v) / np.linalg.norm(v)) for v in dirs])
    out = intersect_dem(LineOfSight(np.broadcast_to(o, d.shape), d, np.zeros(len(d), np.uint8)), dem, "exact")
    assert list(out.status) == [Status.LEFT_DEM] * len(dirs)
    assert np.all(out.dem_evaluations >= 2)  # walked across the blocks, not refused at the start
    down = fr.R_ecef_enu @ np.array([0.6, 0.2, -1.0]) / np.linalg.norm([0.6, 0.2, -1.0])
    hit = intersect_dem(LineOfSight(o, down, np.uint8(0)), dem, "exact")
    assert int(hit.status) == Status.OK
    assert abs(float(hit.h) - float(dem.height(hit.lat, hit.lon))) < 1e-3  # on the bilinear surface


def test_bisection_uses_the_serial_walk_and_the_defaults(monkeypatch):
    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces import terrain_numba as tn
    from geoloc.surfaces.terrain import intersect_dem

    def boom(*a, **k):
        raise AssertionError("the bisection's first-hit check must not start the threads")

    monkeypatch.setattr(tn, "walk_parallel", boom)
    dem = _ridge_lon_dem()
    o, d, LOS = _rays(EnuFrame.from_deg(36.0, 78.002, 0.0), [[0, 0, 400.0]], [1.0, 0.0, -0.12])
    los = LOS(o, d, np.zeros(1, np.uint8))
    bi = intersect_dem(los, dem, "bisect")
    assert bi.hidden.all()  # test_terrain.py's ridge case
    ex = intersect_dem(los, dem)
    assert ex.method == "exact" and ex.surface == "bilinear"
    assert ex.trace is None and bi.trace is None  # no trace unless asked
    assert ex.los is los and bi.los is los


def test_bisection_hidden_flag_on_a_projected_dem():
    # a non-geographic DEM: the first crossing comes from the sampled descent
    # (_first_sampled), and the ridge case must still be flagged
    import pyproj

    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import intersect_dem

    x0, y0, dx = 500000.0, 4100000.0, 20.0
    X = x0 + dx * np.arange(201)
    zrow = 300.0 * np.clip(1 - np.abs(X - (x0 + 1500.0)) / 120.0, 0, None)
    dem = DEM.from_array(np.tile(zrow, (41, 1)), y0, x0, dx, dx, crs="EPSG:32644")
    assert not dem.is_geographic
    lon0, lat0 = pyproj.Transformer.from_crs("EPSG:32644", "EPSG:4326", always_xy=True).transform(
        x0 + 200.0, y0 - 400.0
    )
    o, d, LOS = _rays(EnuFrame.from_deg(lat0, lon0, 0.0), [[0, 0, 400.0]], [1.0, 0.0, -0.12])
    los = LOS(o, d, np.zeros(1, np.uint8))
    st = intersect_dem(los, dem, "steps", eps_h=0.5)
    bi = intersect_dem(los, dem, "bisect", threshold=1.0)
    assert st.status[0] == Status.OK and st.h[0] > 150.0  # the ridge is the first crossing
    assert bi.status[0] == Status.OK and bi.h[0] < 2.0 and bi.hidden[0]
    # and a steeper ray that lands on the floor in front of the ridge is not flagged: the
    # answer is the first crossing (the sampled first crossing lies on the ray, ahead of
    # the camera, not behind it)
    o2, d2, _ = _rays(EnuFrame.from_deg(lat0, lon0, 0.0), [[0, 0, 400.0]], [1.0, 0.0, -0.35])
    near = intersect_dem(LOS(o2, d2, np.zeros(1, np.uint8)), dem, "bisect", threshold=1.0)
    assert near.status[0] == Status.OK and near.h[0] < 2.0 and not near.hidden[0]


# ----------------------------------------------------------------- analysis/sensor_fit.py (the calibrator)
@pytest.fixture(scope="module")
def flight():
    from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
    from geoloc.io.records import load_records
    from geoloc.locate import as_sensor
    from geoloc.sensors.camera import Camera

    return load_records(asset_path(*DEFAULT_RECORDS)), as_sensor(Camera.from_toml(asset_path(*DEFAULT_CAMERA)))


MOUNT = ["mount_x", "mount_y", "mount_z"]


def test_fit_refuses_too_few_records_with_the_count(flight):
    from geoloc.analysis.sensor_fit import fit_sensor_params
    from geoloc.surfaces.height import PerRecordHeightSurface

    rec, cam = flight
    with pytest.raises(ValueError, match=r"1 record\(s\) give 2 equations for 3 parameters; need at least 2 records"):
        fit_sensor_params(rec, cam, MOUNT, PerRecordHeightSurface(rec.column("paper_height_m")), idx=[0])


def test_report_rounding_outlier_rule_and_loo_components(flight):
    from geoloc.analysis.sensor_fit import fit_sensor_groups, fit_sensor_params
    from geoloc.surfaces.height import PerRecordHeightSurface

    rec, cam = flight
    t = PerRecordHeightSurface(rec.column("paper_height_m"))
    rep, _ = fit_sensor_groups(rec, cam, MOUNT, t, group_column="table", loo=True)
    # the default outlier rule is 3.5 robust sigma (docs/calibration.md), and it says so
    assert "3.5 robust sigma" in rep["outlier_rule"]
    # sigma 4.088081 m for T3 (docs/calibration.md: 4.09 m), to the 6 decimals it was reported with
    assert rep["groups"]["T3"]["sigma_m"] == pytest.approx(4.088081, abs=5e-7)
    # each record's leave-one-out east / north: the fit of the nine others, by hand (a separate loop)
    groups = np.array(rec.text("table"))
    idx = np.flatnonzero(groups == "T3")
    en = np.array([fit_sensor_params(rec, cam, MOUNT, t, idx=idx[idx != k]).sensor for k in idx], object)
    from geoloc.analysis.errors import error_vectors
    from geoloc.locate import line_of_sight
    from geoloc.surfaces.height import for_records

    vec = []
    for k, s in zip(idx, en):
        hit = for_records(t, [k]).intersect(
            line_of_sight(
                rec.pose().take([k]), s, rec.column("row")[[k]], rec.column("col")[[k]], outside="extrapolate"
            )
        )
        ev = error_vectors(rec.subset([k]), s, hit)
        vec.append([ev.east_m[0], ev.north_m[0]])
    vec = np.array(vec)
    got = np.array([[r["loo"]["east_m"], r["loo"]["north_m"]] for r in rep["groups"]["T3"]["records"]])
    np.testing.assert_allclose(got, vec, atol=6e-5)  # the report keeps 4 decimals
    assert np.abs(vec[:, 0] - vec[:, 1]).max() > 1.0  # and east is not north
    joint, _ = fit_sensor_groups(rec, cam, MOUNT, t, group_column="table", joint=True)
    assert joint["joint_fit"]["sigma_m"] == pytest.approx(4.148083, abs=5e-7)
    # one group ("all" records, no group column) with one joint rotation: the same fit
    alone, _ = fit_sensor_groups(rec, cam, MOUNT, t, group_column=None, joint=True)
    assert list(alone["groups"]) == ["all"] and alone["joint_fit"]["sigma_m"] == pytest.approx(4.148083, abs=5e-7)


# ----------------------------------------------------------------- analysis/montecarlo.py
def test_statistics_two_samples_first_vs_last_and_the_antimeridian_mean():
    from geoloc.analysis import montecarlo as mc

    # two samples are enough for a standard deviation (ddof = 1)
    s = mc.statistics(np.array([0.1, 0.1 + 1e-6]), np.array([0.2, 0.2]), np.array([0.0, 2.0]))
    assert s["n_ok"] == 2 and s["std_h_m"] == pytest.approx(math.sqrt(2.0), rel=1e-12)
    assert s["std_lat_deg"] == pytest.approx(math.degrees(1e-6) / math.sqrt(2.0), rel=1e-9)
    # the mean longitude does not depend on which sample is first or last
    lon = np.radians([10.0, 10.2, 10.4, 10.6])
    s = mc.statistics(np.full(4, 0.5), lon, np.zeros(4))
    assert s["mean_lon_deg"] == pytest.approx(10.3, abs=1e-12)
    # a mean just east of 180 deg reads as -179.99995, inside [-180, 180)
    lon = np.radians([179.9999, -179.9999, -179.9999, 179.9999, -179.9999, -179.9999])
    s = mc.statistics(np.full(6, 0.5), lon, np.zeros(6))
    assert s["mean_lon_deg"] == pytest.approx(-179.99996667, abs=1e-7)


def test_cep50_uses_the_radii_at_the_target_height():
    # +-delta along the parallel at 60 deg, 5 km up: every sample is delta (R_N + h) cos(phi)
    # from the mean, so the median distance is that exactly (R_N - h would be 0.16 % short)
    from geoloc.analysis import montecarlo as mc

    n, delta, lat0, h0 = 1000, 1e-5, math.radians(60.0), 5000.0
    pm = np.where(np.arange(n) % 2 == 0, delta, -delta)
    rn = A / math.sqrt(1 - (1 - (B / A) ** 2) * math.sin(lat0) ** 2)
    rm = A * (B / A) ** 2 / (1 - (1 - (B / A) ** 2) * math.sin(lat0) ** 2) ** 1.5
    e = mc.statistics(np.full(n, lat0), 0.3 + pm, np.full(n, h0))
    assert e["cep50_empirical_m"] == pytest.approx(delta * (rn + h0) * math.cos(lat0), rel=1e-9)
    nn = mc.statistics(lat0 + pm, np.full(n, 0.3), np.full(n, h0))
    assert nn["cep50_empirical_m"] == pytest.approx(delta * (rm + h0), rel=1e-9)


def test_first_order_ignores_sources_of_zero_spread():
    from dataclasses import replace

    from geoloc.analysis import montecarlo as mc
    from geoloc.analysis.errormodel import Distribution, ErrorModel
    from geoloc.assets import asset_path

    m = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
    one = replace(m, errors={"gimbal_roll_deg": Distribution("normal", 0.006)})
    both = replace(
        m, errors={"heading_deg": Distribution("normal", 0.0), "gimbal_roll_deg": Distribution("normal", 0.006)}
    )
    a, b = mc.first_order(one), mc.first_order(both)
    assert b.sources == ["gimbal_roll_deg"] and np.isfinite(b.cep_m)
    assert b.cep_m == pytest.approx(a.cep_m, rel=1e-12)


# ----------------------------------------------------------------- the sensor model (run 2)
def _turret():
    from geoloc.assets import asset_path
    from geoloc.sensors.sensor_file import load_sensor

    return load_sensor(asset_path("sensors", "eo_turret.toml"))


def _turret_states():
    return Pose.from_deg(
        np.array([36.6, -12.0]),
        np.array([-84.25, 170.0]),
        np.array([2500.0, 900.0]),
        np.array([45.0, -130.0]),
        np.array([2.0, -4.0]),
        np.array([1.0, 7.0]),
        angles_deg={"azimuth": np.array([90.0, 233.0]), "elevation": np.array([-30.0, -71.0])},
    )


def _R_ecef_ned_by_hand(lat, lon):
    # columns: north, east, down in ECEF (the definition, written out)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    n = np.stack([-sl * co, -sl * so, cl], -1)
    e = np.stack([-so, co, np.zeros_like(lon)], -1)
    d = np.stack([-cl * co, -cl * so, -sl], -1)
    return np.stack([n, e, d], -1)


def test_frame_graph_matrices_by_hand_for_a_batch_and_one_state():
    from scipy.spatial.transform import Rotation

    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    s = _turret()
    g = s.graph
    st = _turret_states()
    # NED -> ECEF and body -> NED (aerospace z-y-x: the active rotation of heading, pitch, roll)
    R_en = _R_ecef_ned_by_hand(st.lat, st.lon)
    R_nb = Rotation.from_euler("ZYX", np.stack([st.heading, st.pitch, st.roll], -1)).as_matrix()
    np.testing.assert_allclose(g.R_ecef("ned", st), R_en, atol=1e-15)
    np.testing.assert_allclose(g.R_ecef("body", st), R_en @ R_nb, atol=1e-15)
    # the origin of NED is the geodetic position; the gimbal base adds the lever arm in body axes
    o = geodetic_to_ecef(st.lat, st.lon, st.h)
    T = g.T_ecef("gimbal_base", st)
    assert T.shape == (2, 4, 4)
    np.testing.assert_allclose(T[:, :3, 3], o + np.einsum("nij,j->ni", R_en @ R_nb, s.lever_arm_m), atol=1e-8)
    # the whole chain's matrix applied to the optical axis is the vector path hop by hop
    z = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(g.R_ecef("cam", st) @ z, g.rotate_to_ecef(z, "cam", st), atol=1e-15)
    # one state: (4, 4), not a broadcast of batches
    one = Pose.from_deg(36.6, -84.25, 2500.0, 45.0, 2.0, 1.0, angles_deg={"azimuth": 90.0, "elevation": -30.0})
    T1 = g.T_ecef("cam", one)
    assert T1.shape == (4, 4)
    np.testing.assert_allclose(T1, g.T_ecef("cam", st)[0], atol=1e-8)


def test_hops_and_bound_frames_default_to_the_last_frame():
    s = _turret()
    st = Pose.from_deg(36.6, -84.25, 2500.0, 45.0, 2.0, 1.0, angles_deg={"azimuth": 90.0, "elevation": -30.0})
    g = s.graph
    assert g.frames[-1] == "cam"
    hops = g.hops(st)
    assert hops[0].dst == "ecef" and hops[-1].src == "cam"
    b = s.frames(st)
    assert b.leaf == "cam" and b.frames[-1] == "cam"
    from geoloc.frames.graph import BoundFrames

    assert BoundFrames(g, st, leaf="body").leaf == "body"
    assert BoundFrames(g, st, leaf="body").frames == ("ecef", "ned", "body")


def test_fixed_joints_take_stacks_of_rotations_and_refuse_reflections():
    from scipy.spatial.transform import Rotation

    from geoloc.frames.graph import Joint

    Rs = Rotation.from_euler("xyz", [[0.1, 0.2, 0.3], [-0.4, 0.5, 1.0]]).as_matrix()  # R_child_parent
    j = Joint("body", "base", "fixed", R=Rs)  # a stack (Monte Carlo's per-sample mounts)
    v = np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, 2.0]])
    np.testing.assert_allclose(j.rotate_to_parent(v, None), np.einsum("nji,nj->ni", Rs, v), atol=1e-15)
    np.testing.assert_allclose(j.rotate_to_child(j.rotate_to_parent(v, None), None), v, atol=1e-15)
    with pytest.raises(ValueError, match="must be a 3x3 rotation matrix"):
        Joint("body", "base", "fixed", R=np.diag([1.0, 1.0, -1.0]))  # a mirror, det -1
    with pytest.raises(ValueError, match="must be a 3x3 rotation matrix"):
        Joint("body", "base", "fixed", R=np.eye(3) * 1.01)


def test_gimbal_refuses_what_is_not_a_rotation_and_is_immutable():
    from scipy.spatial.transform import Rotation

    from geoloc.sensors.gimbals import PRESETS, Gimbal, GimbalJoint, gimbal_from_dict

    joint = (GimbalJoint("pan", "z", "pan"),)
    for bad in (np.eye(4), np.diag([1.0, -1.0, 1.0]), np.eye(3) + 1e-9):
        with pytest.raises(ValueError, match="R_opt_last must be a rotation matrix"):
            Gimbal("g", joint, bad)
    # proper rotations whose determinant rounds a little below 1 are rotations
    rng = np.random.default_rng(0)
    R = next(R for R in Rotation.random(200, random_state=1).as_matrix() if np.linalg.det(R) < 1.0)
    assert Gimbal("g", joint, R).R_opt_last.shape == (3, 3)
    del rng
    with pytest.raises(dataclasses.FrozenInstanceError):
        PRESETS["azimuth-elevation"].name = "x"
    with pytest.raises(dataclasses.FrozenInstanceError):  # its joints too: a preset is shared by every sensor
        PRESETS["azimuth-elevation"].joints[0].axis = "x"
    with pytest.raises(ValueError, match=r"joints = \{'angle': 'pan'\}: must be a non-empty list"):
        gimbal_from_dict({"joints": {"angle": "pan"}})
    with pytest.raises(ValueError, match=r"joints\[0\] = 'pan': must be"):
        gimbal_from_dict({"joints": ["pan"]})
    with pytest.raises(ValueError, match=r"joints\[0\] = \{'angle': 'pan', 'axis': 'z', 'speed': 1\}: must be"):
        gimbal_from_dict({"joints": [{"angle": "pan", "axis": "z", "speed": 1}]})


def test_frame_sensor_centre_params_and_field_checks():
    from geoloc.assets import asset_path
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.sensor_file import load_sensor

    s = _turret()
    assert s.center_pixel == ((s.rows + 1) / 2.0, (s.cols + 1) / 2.0) == (540.5, 960.5)  # 1080 x 1920
    # lens parameters other than the principal point pass through with_params unchanged
    assert s.with_params(fx=2000.0).params["fx"] == 2000.0
    assert s.with_params(k1=-0.1).params["k1"] == -0.1
    assert s.with_params(cx=700.0).params["cx"] == 700.0  # 1-based in, 1-based out
    drone = load_sensor(asset_path("sensors", "drone_camera.toml"))
    assert not {"mount_x", "mount_y", "mount_z"} & set(drone.params)  # earth-referenced: no mount
    assert {"boresight_x", "lever_arm_z_m"} <= set(drone.params)
    with pytest.raises(ValueError, match="mount"):
        dataclasses.replace(s, mount=(0.1, 0.2))
    with pytest.raises(ValueError, match=r"sensor field boresight = .*: angles must lie in \[-pi, pi\] rad"):
        dataclasses.replace(s, boresight=(0.0, 4.0, 0.0))
    assert isinstance(s, FrameSensor)


def test_azimuth_just_below_north_is_zero_not_360():
    from geoloc.geodesy.local import enu_to_aer_deg

    # a point a hair west of north: atan2 gives 2 pi - 1e-300, which is 360.0 in degrees
    az, el, r = enu_to_aer_deg(np.array([-1e-300, 1.0, 0.0]))
    assert 0.0 <= float(az) < 360.0 and float(az) == 0.0
