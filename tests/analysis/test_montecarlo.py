"""Monte Carlo error analysis [Q17 section 3] against the paper and closed-form propagation.

Expected numbers come from outside the code: [Q17]'s published values, the
geometry of the nominal line of sight measured with pyproj, normal-distribution
quantiles, and exact relations between rotations about the same axis.
"""

import json
import math
from dataclasses import replace

import numpy as np
import pyproj
import pytest
from scipy import stats as sps

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import Distribution, ErrorModel
from geoloc.assets import asset_path
from geoloc.sensors.camera import camera_from_sensor
from geoloc.cli import main

SCEN = asset_path("scenarios", "qiao2017_table1.toml")
DEG = math.pi / 180.0


@pytest.fixture(scope="module")
def model():
    return ErrorModel.from_toml(SCEN)


def only(model, **dists):
    """The model with only the given error sources."""
    return replace(model, errors=dict(dists))


# ------------------------------------------------------------------ the paper
def test_table1_nominal_point_matches_q17(model):
    lat, lon, h, st = mc.nominal_point(model)
    assert st == 0
    # [Q17] prints 35.57709 N, 80.84918 E (5 decimals): half a unit of the last digit.
    assert abs(math.degrees(lat) - 35.57709) <= 0.5e-5
    assert abs(math.degrees(lon) - 80.84918) <= 0.5e-5
    # the inflated ellipsoid (eq. 11) differs from the constant-height surface by mm at 5 km
    assert abs(h - 5083.5) < 0.02


def test_table12_standard_deviations_within_5_percent_of_q17(model):
    r = mc.run(model, 5000, np.random.default_rng(0))
    s = r.stats
    assert s["n_ok"] == 5000
    # Held to 5 % of [Q17]'s figures. Sampling error of a standard deviation with N = 5000 is
    # 1/sqrt(2N) = 1 %, and [Q17] rounds to 2 digits (0.00048: +-1 %).
    for key, paper in (("std_lat_deg", 0.00048), ("std_lon_deg", 0.00060), ("std_h_m", 62.3)):
        assert abs(s[key] / paper - 1) < 0.05, (key, s[key], paper)


# ------------------------------------------------------------ closed-form checks
def _nominal_geometry(model):
    """Aircraft and nominal target from pyproj: slant direction, tan(incidence), ground distance."""
    lat, lon, h, _ = mc.nominal_point(model)
    la_t, lo_t = math.degrees(lat), math.degrees(lon)
    n = model.nominal
    ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    a = np.array(ecef.transform(n["lon_deg"], n["lat_deg"], n["h_m"]))
    t = np.array(ecef.transform(lo_t, la_t, h))
    d = (t - a) / np.linalg.norm(t - a)
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    cos_i = -d @ up
    tan_i = math.sqrt(1 - cos_i**2) / cos_i
    dist = pyproj.Geod(ellps="WGS84").inv(n["lon_deg"], n["lat_deg"], lo_t, la_t)[2]
    return tan_i, dist, h


def test_height_error_only_gives_sigma_times_tan_incidence(model):
    # A target-height error moves the point along the line of sight: the horizontal
    # displacement is dh tan(i), i the incidence angle measured with pyproj.
    tan_i, _, _ = _nominal_geometry(model)
    m = only(model, target_h_m=Distribution("normal", 62.47))
    s = mc.run(m, 20000, np.random.default_rng(1)).stats
    # 3 %: sampling error of a std with N = 20000 is 0.5 % (6 sigma), the ellipsoid's
    # curvature over +-200 m of displacement is < 1e-4.
    assert s["cep_m"] == pytest.approx(62.47 * tan_i, rel=0.03)
    # One-dimensional normal error: the 50 % radius is the 0.75 quantile of N(0,1)
    # times sigma, and eq. 18 is sigma itself (scipy's quantile, not ours).
    assert s["cep50_empirical_m"] / s["cep_m"] == pytest.approx(sps.norm.ppf(0.75), rel=0.03)


def test_heading_error_only_turns_the_point_about_the_aircraft(model):
    # A heading error turns the line of sight about the aircraft's vertical, so the
    # target moves on a circle of radius = its ground distance (pyproj geodesic).
    _, dist, h_t = _nominal_geometry(model)
    sig = 0.02 * DEG
    m = only(model, heading_deg=Distribution("normal", 0.02))
    s = mc.run(m, 20000, np.random.default_rng(2)).stats
    # 3 %: 0.5 % sampling; the geodesic is at h = 0 while the target is at 5 km
    # (+0.08 %); the ellipsoid normal at the aircraft misses the Earth's centre (~e^2).
    assert s["cep_m"] == pytest.approx(dist * (1 + h_t / 6.37e6) * sig, rel=0.03)


# ------------------------------------------------------- first-order propagation
def test_monte_carlo_matches_first_order_propagation_for_small_errors(model):
    # Shrink every error 100x: the chain is linear to 1e-4 there, so the sample
    # standard deviations must agree with J Sigma J^T within sampling error.
    small = replace(model, errors={k: Distribution(d.dist, d.scale / 100) for k, d in model.errors.items()})
    fo = mc.first_order(small)
    r = mc.run(small, 40000, np.random.default_rng(3))
    s = r.stats
    # 2 %: sampling error of a std with N = 40000 is 0.35 % (5.7 sigma).
    assert s["std_lat_deg"] == pytest.approx(fo.std_lat_deg, rel=0.02)
    assert s["std_lon_deg"] == pytest.approx(fo.std_lon_deg, rel=0.02)
    assert s["std_h_m"] == pytest.approx(fo.std_h_m, rel=0.02)
    assert s["cep_m"] == pytest.approx(fo.cep_m, rel=0.02)
    # the lat-lon correlation too (errors along the line-of-sight azimuth): the
    # standard error of a correlation coefficient is (1 - r^2)/sqrt(N) < 0.005
    ok = r.status == 0
    r_mc = np.corrcoef(r.lat[ok], r.lon[ok])[0, 1]
    r_fo = fo.cov[0, 1] / math.sqrt(fo.cov[0, 0] * fo.cov[1, 1])
    assert r_mc == pytest.approx(r_fo, abs=0.02)


def test_first_order_reproduces_q17_magnitudes(model):
    # The Table 1-2 errors are small enough that the linear propagation alone
    # gives [Q17]'s numbers (5 %, as for the Monte Carlo).
    fo = mc.first_order(model)
    assert fo.std_lat_deg == pytest.approx(0.00048, rel=0.05)
    assert fo.std_lon_deg == pytest.approx(0.00060, rel=0.05)
    assert fo.std_h_m == pytest.approx(62.3, rel=0.05)


def test_uniform_vibration_roll_equals_gimbal_roll_of_same_std(model):
    # Vibration roll turns the gimbal base about body X, exactly the outer gimbal
    # axis: U(-m, m) must act like a gimbal-roll error of std m / sqrt(3).
    m = 0.01
    a = mc.first_order(only(model, vibration_roll_deg=Distribution("uniform", m)))
    b = mc.first_order(only(model, gimbal_roll_deg=Distribution("normal", m / math.sqrt(3))))
    # same axis, same std: equal to the finite-difference noise (1e-6 relative)
    assert a.cep_m == pytest.approx(b.cep_m, rel=1e-5)
    s = mc.run(only(model, vibration_roll_deg=Distribution("uniform", m)), 20000, np.random.default_rng(4)).stats
    assert s["cep_m"] == pytest.approx(a.cep_m, rel=0.03)  # 0.5 % sampling error


@pytest.mark.parametrize("gp_deg", [-2.6, -30.0])
def test_table2_rotations_act_about_their_axes(model, gp_deg):
    m0 = model.with_nominal(gimbal_pitch_deg=gp_deg)
    sig = 0.001
    roll = mc.first_order(only(m0, gimbal_roll_deg=Distribution("normal", sig)))
    pitch = mc.first_order(only(m0, gimbal_pitch_deg=Distribution("normal", sig)))
    coll = mc.first_order(only(m0, collimation_deg=Distribution("normal", sig)))
    nonorth = mc.first_order(only(m0, gimbal_nonorthogonality_deg=Distribution("normal", sig)))
    # collimation (about camera X) vs gimbal roll (about outer X, which is camera X
    # turned by the pitch): the line of sight moves the same way by sigma vs sigma cos(gp)
    gp = math.radians(gp_deg)
    assert coll.cep_m * math.cos(gp) == pytest.approx(roll.cep_m, rel=1e-3)
    # an inner axis tilted by delta towards the outer axis moves the line of sight by
    # delta |sin(gp)| across the pitch plane, the same direction as a roll error,
    # which moves it by sigma cos(gp): the ratio is |tan(gp)|
    assert nonorth.cep_m == pytest.approx(roll.cep_m * abs(math.tan(gp)), rel=1e-3)
    # image-centre error: 0.6 um / 7 um pitch along rows = a pitch-like rotation of
    # 0.6e-6 / f_m rad
    img = mc.first_order(only(m0, image_centre_x_um=Distribution("normal", 0.6)))
    f_m = model.camera.lens.fx * model.camera.pixel_pitch_m
    pitch_img = mc.first_order(only(m0, gimbal_pitch_deg=Distribution("normal", math.degrees(0.6e-6 / f_m))))
    assert img.cep_m == pytest.approx(pitch_img.cep_m, rel=1e-3)
    assert pitch.cep_m > 0


# ------------------------------------------------------------------ statistics
def test_statistics_circular_normal_cep50_and_eq18():
    # Synthetic circular normal cloud of sigma 10 m per axis at 35 deg N.
    rng = np.random.default_rng(5)
    n = 200000
    lat0 = math.radians(35.0)
    rm = 6378137.0 * (1 - 0.00669437999014) / (1 - 0.00669437999014 * math.sin(lat0) ** 2) ** 1.5
    rn = 6378137.0 / math.sqrt(1 - 0.00669437999014 * math.sin(lat0) ** 2)
    lat = lat0 + rng.normal(0, 10.0, n) / rm
    lon = 1.0 + rng.normal(0, 10.0, n) / (rn * math.cos(lat0))
    s = mc.statistics(lat, lon, np.zeros(n))
    # eq. 18 = sqrt(2) sigma; the 50 % radius of a Rayleigh law is sigma sqrt(2 ln 2).
    # 1 %: sampling error ~0.2 % at N = 2e5.
    assert s["cep_m"] == pytest.approx(10 * math.sqrt(2), rel=0.01)
    assert s["cep50_empirical_m"] == pytest.approx(10 * math.sqrt(2 * math.log(2)), rel=0.01)


# WGS-84 written out (not the module's constants): a = 6378137 m, 1/f = 298.257223563
_A = 6378137.0
_E2 = (2.0 - 1.0 / 298.257223563) / 298.257223563


def _rn_rm(lat):
    w2 = 1.0 - _E2 * math.sin(lat) ** 2
    return _A / math.sqrt(w2), _A * (1.0 - _E2) / w2**1.5


def test_eq18_radii_are_not_interchangeable():
    # [Q17] eq. 18 weighs the latitude spread with R_M and the longitude spread with
    # R_N cos(phi). Clouds spread along one axis make the two radii tell: at the equator
    # R_N / R_M = 1 / (1 - e^2) = 1.0067, so swapping them moves CEP by 0.67 %; here it
    # must equal the closed form to rounding (1e-9: the longitude offsets are taken modulo
    # 2 pi, 7e-12 relative). The cloud is +-delta exactly, so its
    # sample std is delta sqrt(n / (n - 1)) with no sampling error.
    n, delta = 1000, 1e-5
    pm = np.where(np.arange(n) % 2 == 0, delta, -delta)
    k = math.sqrt(n / (n - 1))
    rn0, rm0 = _rn_rm(0.0)
    assert rn0 / rm0 - 1 > 6e-3
    north = mc.statistics(pm, np.full(n, 0.3), np.zeros(n))  # along the meridian at the equator
    assert north["cep_m"] == pytest.approx(delta * k * rm0, rel=1e-9)
    east = mc.statistics(np.zeros(n), 0.3 + pm, np.zeros(n))  # along the equator
    assert east["cep_m"] == pytest.approx(delta * k * rn0, rel=1e-9)
    # at 60 deg and 5 km up: R_N cos(phi) and the target height in both terms
    lat0, h0 = math.radians(60.0), 5000.0
    rn, rm = _rn_rm(lat0)
    e = mc.statistics(np.full(n, lat0), 0.3 + pm, np.full(n, h0))
    assert e["cep_m"] == pytest.approx(delta * k * (rn + h0) * math.cos(lat0), rel=1e-9)
    nn = mc.statistics(lat0 + pm, np.full(n, 0.3), np.full(n, h0))
    assert nn["cep_m"] == pytest.approx(delta * k * (rm + h0), rel=1e-9)


@pytest.mark.parametrize(
    "lat0_deg, sigma_north_m, sigma_east_m",
    [
        (60.0, 40.0, 3.0),  # long along the meridian
        (60.0, 3.0, 40.0),  # long along the parallel
        (-10.0, 25.0, 5.0),
    ],
)
def test_cep50_empirical_on_elongated_clouds_equals_enu_reference(lat0_deg, sigma_north_m, sigma_east_m):
    # The empirical CEP50 is the median horizontal distance to the mean point. Reference:
    # each sample's east and north in the tangent plane at the mean point, from pymap3d's
    # geodetic2enu (not the module's radii). The cloud is 13x (8x) longer one way, so the
    # median distance is mostly one component: R_N and R_M swapped (or the height left out)
    # move it by (R_N - R_M) / R = 1.7e-3 at 60 deg, 6.5e-3 at 10 deg (asserted below).
    # Tolerance 2e-6: tangent plane vs the module's curvilinear offsets differ at second
    # order, (offset / R) tan(lat) ~ 1e-5 on the short component, whose share of the
    # distance is (sigma_short / sigma_long)^2; measured 4e-8 to 2.3e-7 on these clouds.
    pymap3d = pytest.importorskip("pymap3d")
    rng = np.random.default_rng(35)
    n, h0 = 20001, 5000.0
    lat0 = math.radians(lat0_deg)
    lat = lat0 + rng.normal(0.0, sigma_north_m / 6.38e6, n)
    lon = 0.3 + rng.normal(0.0, sigma_east_m / (6.39e6 * math.cos(lat0)), n)
    h = h0 + rng.normal(0.0, 1.0, n)  # 1 m of height spread: 1.6e-7 of the radii at most
    s = mc.statistics(lat, lon, h)
    e, nn, _ = pymap3d.geodetic2enu(lat, lon, h, lat.mean(), lon.mean(), h.mean(), deg=False)
    ref = float(np.median(np.hypot(e, nn)))
    assert s["cep50_empirical_m"] == pytest.approx(ref, rel=2e-6)
    # the radii swapped: what the test must tell apart
    rn, rm = _rn_rm(lat.mean())
    de = (lon - lon.mean()) * (rm + h0) * math.cos(lat.mean())
    dn = (lat - lat.mean()) * (rn + h0)
    assert abs(float(np.median(np.hypot(de, dn))) / ref - 1) > 1e-3


def test_first_order_eq18_weights_east_and_north_with_their_radii(model):
    # Flying north with the gimbal rolled to the side, a target-height error moves the
    # point east-west only: first_order's CEP must be eq. 18 of its own covariance with
    # R_N for longitude and R_M for latitude (1e-9); R_N / R_M = 1.0044 at 35.6 deg, and
    # the cloud is 100x longer east than north, so swapping them moves CEP by 0.44 %.
    m = only(
        model.with_nominal(heading_deg=0.0, pitch_deg=0.0, roll_deg=0.0, gimbal_pitch_deg=0.0),
        target_h_m=Distribution("normal", 62.47),
    )
    fo = mc.first_order(m)
    lat0, _, h0, st = mc.nominal_point(m)
    assert st == 0
    rn, rm = _rn_rm(lat0)
    s_lat, s_lon = math.sqrt(fo.cov[0, 0]), math.sqrt(fo.cov[1, 1])
    east, north = s_lon * (rn + h0) * math.cos(lat0), s_lat * (rm + h0)
    assert east > 100 * north
    assert fo.cep_m == pytest.approx(math.hypot(east, north), rel=1e-9)
    swapped = math.hypot(s_lon * (rm + h0) * math.cos(lat0), s_lat * (rn + h0))
    assert abs(swapped / fo.cep_m - 1) > 4e-3


def test_statistics_ignores_failed_samples_and_wraps_longitude():
    lat = np.radians([10.0, 10.0, 10.0, np.nan])
    lon = np.radians([179.9999, -179.9999, 179.9999, 0.0])
    s = mc.statistics(lat, lon, np.zeros(4), np.array([0, 0, 0, 1], np.uint8))
    assert s["n_ok"] == 3 and s["n_failed"] == 1
    # mean of +179.9999, -179.9999, +179.9999 across the antimeridian: 179.99997 (not ~60)
    assert abs(abs(s["mean_lon_deg"]) - 179.99997) < 1e-4


def test_sky_samples_are_counted_not_raised(model):
    m = model.with_nominal(gimbal_roll_deg=89.9).with_error("gimbal_roll_deg", Distribution("normal", 5.0))
    r = mc.run(m, 2000, np.random.default_rng(6))
    assert r.stats["n_failed"] > 0 and r.stats["n_ok"] > 0
    assert np.all(np.isnan(r.lat[r.status != 0]))


def test_seed_reproducible(model):
    a = mc.run(model, 1000, np.random.default_rng(9)).stats
    b = mc.run(model, 1000, np.random.default_rng(9)).stats
    assert a == b


# ------------------------------------------------------------------ error model file
@pytest.mark.parametrize(
    "patch, needle",
    [
        ({"errors": {"heading_deg": {"dist": "gauss", "sigma": 1}}}, "heading_deg dist = 'gauss'"),
        ({"errors": {"heading_deg": {"dist": "normal", "sigma": -1}}}, "heading_deg sigma = -1"),
        ({"errors": {"heading_deg": {"dist": "uniform", "sigma": 1}}}, "heading_deg"),
        ({"errors": {"wind_deg": {"dist": "normal", "sigma": 1}}}, "wind_deg"),
        ({"nominal": {"lat_deg": 95.0, "lon_deg": 0.0, "h_m": 1.0}}, "lat = 95"),
        ({"target": {"h_m": "high"}}, "h_m = 'high'"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_scenario_names_field(patch, needle):
    import tomllib

    data = tomllib.loads(SCEN.read_text())
    data.update(patch)
    with pytest.raises(ValueError, match=None) as e:
        ErrorModel.from_dict(data, "scenario")
    assert needle in str(e.value)


def test_image_centre_error_needs_pixel_pitch():
    import tomllib

    data = tomllib.loads(SCEN.read_text())
    del data["camera"]["pixel_pitch_m"]
    with pytest.raises(ValueError, match="pixel_pitch_m"):
        ErrorModel.from_dict(data, "scenario")


# ------------------------------------------------------------------ command line
def test_cli_stats_json_keys_and_values(tmp_path, capsys):
    out = tmp_path / "stats.json"
    assert main(["montecarlo", str(SCEN), "--samples", "5000", "--seed", "0", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert set(d) == {
        "mean_lat_deg",
        "mean_lon_deg",
        "mean_h_m",
        "std_lat_deg",
        "std_lon_deg",
        "std_h_m",
        "cep_m",
        "cep50_empirical_m",
    }
    assert abs(d["std_lat_deg"] / 0.00048 - 1) < 0.05  # as in the test above
    assert abs(d["mean_lat_deg"] - 35.57709) < 3 * 0.00048 / math.sqrt(5000) + 0.5e-5


def test_cli_sweep_writes_csv_and_png(tmp_path, capsys):
    assert (
        main(
            [
                "montecarlo",
                str(SCEN),
                "--sweep",
                "terrain",
                "--samples",
                "400",
                "--angles-deg",
                "10:70:60",
                "--terrain-sigmas-m",
                "10,100",
                "--out-dir",
                str(tmp_path),
            ]
        )
        == 0
    )
    rows = (tmp_path / "fig10a_terrain_sigma.csv").read_text().splitlines()
    assert rows[0] == "gimbal_roll_deg,curve,cep_m,cep50_empirical_m,n_ok"
    assert len(rows) == 1 + 2 * 2
    cep = {(r.split(",")[0], r.split(",")[1]): float(r.split(",")[2]) for r in rows[1:]}
    # [Q17] Fig. 10a: CEP grows with the angle and with the terrain sigma
    assert cep[("70", "sigma_h=100m")] > cep[("10", "sigma_h=100m")] > cep[("10", "sigma_h=10m")]
    png = (tmp_path / "fig10a_terrain_sigma.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10000


def test_cli_bad_samples_is_an_error(capsys):
    assert main(["montecarlo", str(SCEN), "--samples", "1"]) == 2
    assert "--samples = 1" in capsys.readouterr().err


def test_hop_by_hop_engine_equals_frame_chain(model):
    # The fast path rotates the vector hop by hop; the reference builds the batched
    # FrameChain. Include every error source and a camera with its own boresight
    # and mount rotations, at large errors so every factor matters.
    cam = replace(model.camera, boresight=(0.01, -0.02, 0.03), mount=(-0.005, 0.004, 0.02))
    big = replace(
        model,
        camera=cam,
        errors={k: Distribution(d.dist, d.scale * (1 if k == "target_h_m" else 1000)) for k, d in model.errors.items()},
    )
    errs = big.sample(3000, np.random.default_rng(8))
    a = chain_reference(big, errs)
    b = mc.evaluate(big, errs)
    np.testing.assert_array_equal(a[3], b[3])
    ok = a[3] == 0
    assert ok.sum() > 2500
    # 1e-12 rad (6 um) and 1e-5 m: two orders of float64 products of unit
    # rotations (ulp 1e-16) on ranges of ~1e5 m
    np.testing.assert_allclose(a[0][ok], b[0][ok], atol=1e-12, rtol=0)
    np.testing.assert_allclose(a[1][ok], b[1][ok], atol=1e-12, rtol=0)
    np.testing.assert_allclose(a[2][ok], b[2][ok], atol=1e-5, rtol=0)


def chain_reference(model, errs):
    """The [Q17] reference: the batched FrameChain of the perturbed rotations, at the target height."""
    from geoloc.surfaces.height import HeightSurface

    pose, chain, row, col = mc.perturbed_geometry(model, errs)
    los = camera_from_sensor(model.camera).chain_line_of_sight(pose, row, col, chain=chain)  # the file's form
    g = HeightSurface(model.target_h_m + errs.get("target_h_m", 0.0), model.height_kind).intersect(los)
    return g.lat, g.lon, g.h, np.asarray(g.status, np.uint8)


def test_cli_no_located_sample_is_an_error_not_nan_json(tmp_path, capsys):
    # outer gimbal at 95 deg with 18 km altitude: every line of sight points above
    # the horizon (the horizon dip from 18 km is 4.3 deg)
    text = SCEN.read_text().replace("gimbal_roll_deg = 50.0", "gimbal_roll_deg = 95.0")
    scen = tmp_path / "sky.toml"
    scen.write_text(text)
    out = tmp_path / "stats.json"
    assert main(["montecarlo", str(scen), "--samples", "50", "--out", str(out)]) == 1
    assert "sky: 50" in capsys.readouterr().err
    assert not out.exists()


def test_the_height_kind_key_and_its_older_name():
    # [target] height_kind names the constant-height surface's kind; "surface" (its name before
    # "surface" came to mean only what a line of sight meets) still reads the same, both is an error
    import tomllib

    data = tomllib.loads(SCEN.read_text())
    assert data["target"]["height_kind"] == "inflated"
    tgt = {k: v for k, v in data["target"].items() if k != "height_kind"}
    for key in ("height_kind", "surface"):
        m = ErrorModel.from_dict({**data, "target": {**tgt, key: "geodetic"}}, "scenario")
        assert m.height_kind == "geodetic"
    with pytest.raises(ValueError, match="not both height_kind and surface"):
        ErrorModel.from_dict({**data, "target": {**tgt, "height_kind": "geodetic", "surface": "geodetic"}}, "s")
    with pytest.raises(ValueError, match="surface = 'flat'"):
        ErrorModel.from_dict({**data, "target": {**tgt, "surface": "flat"}}, "scenario")
