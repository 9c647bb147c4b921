"""Boresight / mounting calibration, resection and error decomposition.

The calibrator is :mod:`geoloc.analysis.sensor_fit`, run on the camera file's sensor
(``as_sensor``), as ``geoloc calibrate`` runs it.

Outside references: the published errors of [Q17] Tables 3-4 (``paper_error_m``),
the camera derivation of ``docs/records.md`` (f = 166 841.0 px,
i0 = 1162.12, j0 = 1146.42, RMS misfit 0.25 m), planted rotations in synthetic
records, closed-form nadir geometry and pyproj's geodesic.
"""

import csv
import json
import math

import numpy as np
import pytest
from pyproj import Geod

from geoloc.surfaces.height import PerRecordHeightSurface
from geoloc.analysis.sensor_fit import fit_sensor_groups, fit_sensor_params, resect_sensor
from geoloc.analysis.errors import error_vectors, outlier_flags
from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.cli import main
from geoloc.frames.chain import Pose
from geoloc.frames.enu import EnuFrame
from geoloc.io.records import load_records
from geoloc.locate import as_sensor, locate
from geoloc.sensors.camera import Camera

GEOD = Geod(ellps="WGS84")
COLUMNS = [
    "table",
    "point",
    "row",
    "col",
    "ac_lat_deg",
    "ac_lon_deg",
    "ac_h_m",
    "heading_deg",
    "pitch_deg",
    "roll_deg",
    "gimbal_roll_deg",
    "gimbal_pitch_deg",
    "paper_height_m",
    "truth_lat_deg",
    "truth_lon_deg",
]


#: The rotation of each model (``geoloc calibrate --model``): gimbal base in the body, camera in the gimbal.
MODELS = {"mount": ["mount_x", "mount_y", "mount_z"], "camera": ["boresight_x", "boresight_y", "boresight_z"]}
MOUNT = MODELS["mount"]


def mount_groups(rec, cam, surface, group, **kw):
    """The per-flight mounting fit as ``geoloc calibrate`` runs it on a camera file."""
    return fit_sensor_groups(rec, as_sensor(cam), MOUNT, surface, group_column=group, **kw)


def fit_rotation(rec, cam, surface, idx=None, model="mount", names=()):
    return fit_sensor_params(rec, as_sensor(cam), MODELS[model] + list(names), surface, idx=idx)


def value_sd(params, name):
    return params[name]["value"], params[name]["sd"]


@pytest.fixture(scope="module")
def bundled():
    return load_records(asset_path(*DEFAULT_RECORDS)), Camera.from_toml(asset_path(*DEFAULT_CAMERA))


@pytest.fixture(scope="module")
def per_flight(bundled):
    rec, cam = bundled
    return mount_groups(rec, cam, PerRecordHeightSurface(rec.column("paper_height_m")), "table", loo=True)


# ----------------------------------------------------------------- the bundled flight test
def test_before_matches_published_errors(bundled, per_flight):
    # [Q17] Tables 3-4 publish each point's error; the published computed positions
    # are rounded to 1e-5 deg (~1 m), so the flight means agree to within 1 m.
    rec, _ = bundled
    pub = rec.column("paper_error_m")
    groups = np.array(rec.text("table"))
    for g, e in per_flight[0]["groups"].items():
        assert e["mean_error_before_m"] == pytest.approx(pub[groups == g].mean(), abs=1.0)


def test_readme_calibration_table(per_flight):
    # docs/tour_papers.md / docs/calibration.md, one rotation per flight: before 50.0 / 50.5 m, after
    # 5.0 / 5.1 m, leave-one-out 5.9 / 5.9 m; the report example quotes T3's 50.015,
    # 4.976, 5.927 m and sigma 4.09 m. Held to the printed digits (half a unit of the last).
    g = per_flight[0]["groups"]
    for name, before, after, loo in (("T3", 50.015, 4.976, 5.927), ("T4", 50.521, 5.056, 5.867)):
        e = g[name]
        assert e["mean_error_before_m"] == pytest.approx(before, abs=5e-4)
        assert e["mean_error_after_m"] == pytest.approx(after, abs=5e-4)
        assert e["mean_error_loo_m"] == pytest.approx(loo, abs=5e-4)
    assert g["T3"]["sigma_m"] == pytest.approx(4.09, abs=5e-3)
    # docs/tour_papers.md: fitted per flight, "the pitch comes out at +0.29 +- 0.10 deg (T3) and
    # +0.35 +- 0.10 deg (T4)", pitch and yaw "correlation above 0.99"
    for name, y in (("T3", 0.29), ("T4", 0.35)):
        v, sd = value_sd(g[name]["parameters"], "mount_y")
        assert v == pytest.approx(y, abs=5e-3)
        assert sd == pytest.approx(0.10, abs=5e-3)
        assert abs(g[name]["correlation"][1][2]) > 0.99


def test_leave_one_out_never_sees_the_left_out_record(bundled, per_flight):
    """Leave-one-out by hand, independently of the report's loop: for each T3 record k, fit
    the nine others with ``fit_sensor_params``, locate k through the ordinary ``locate`` path
    with that camera and measure pyproj's geodesic to k's truth. The report's figures must
    be these (1 mm: the report rounds to 1e-3 m), and they must differ from what a fit that
    keeps k would give (the in-sample error, T3: 4.98 m against 5.93 m), so a
    leave-one-out that used the left-out record fails here."""
    rec, cam = bundled
    t = PerRecordHeightSurface(rec.column("paper_height_m"))
    groups = np.array(rec.text("table"))
    idx = np.flatnonzero(groups == "T3")
    loo, insample = [], []
    kept = fit_rotation(rec, cam, t, idx=idx)
    for k in idx:
        fit = fit_rotation(rec, cam, t, idx=idx[idx != k])
        for c, out in ((fit.sensor, loo), (kept.sensor, insample)):
            g = locate(rec.pose(), c, rec.column("row"), rec.column("col"), rec.column("paper_height_m"))
            out.append(
                GEOD.inv(
                    float(g.lon_deg[k]),
                    float(g.lat_deg[k]),
                    rec.column("truth_lon_deg")[k],
                    rec.column("truth_lat_deg")[k],
                )[2]
            )
    e = per_flight[0]["groups"]["T3"]
    by_label = {r["label"]: r for r in e["records"]}
    labels = rec.labels()
    for j, k in enumerate(idx):
        assert by_label[labels[k]]["loo"]["distance_m"] == pytest.approx(loo[j], abs=1e-3)
    assert e["mean_error_loo_m"] == pytest.approx(np.mean(loo), abs=1e-3)
    assert np.mean(loo) == pytest.approx(5.927, abs=5e-4)
    assert np.mean(insample) == pytest.approx(e["mean_error_after_m"], abs=1e-3)
    assert np.mean(loo) - np.mean(insample) > 0.9
    # fit_sensor_params' own leave-one-out (a third loop): the norm of the (east, north) vector
    # at the target height, longer than the geodesic on the ellipsoid by (R + h) / R (h ~ 5 km:
    # 8e-4, 5 mm at 6 m): 1e-3 relative
    d = fit_sensor_params(rec, as_sensor(cam), MOUNT, t, idx=idx, loo=True).loo_errors_m
    np.testing.assert_allclose(d, loo, rtol=1e-3)


def test_must_show_loo_per_flight_at_most_7_m(per_flight):
    # the target: leave-one-out mean error <= 7 m per flight, from about 50 m
    report = per_flight[0]
    assert set(report["groups"]) == {"T3", "T4"}
    for g, e in report["groups"].items():
        assert e["n"] == 10
        assert e["mean_error_before_m"] > 45.0
        assert e["mean_error_loo_m"] <= 7.0
        # in-sample error cannot exceed the honest out-of-sample one
        assert e["mean_error_after_m"] <= e["mean_error_loo_m"]
        assert e["before"]["outliers"] == []


def test_errors_are_along_track_and_match_image_rows(per_flight):
    # Both flights: computed points fall ~50 m short along track, < 2 m across it.
    # A pure along-track ground shift at slant range R maps to ~f * shift / R
    # image rows (row axis ~ forward here): f = 166841 px, R ~ 17-19 km -> 440-490 px.
    for e in per_flight[0]["groups"].values():
        b = e["before"]
        assert b["bias_along_m"] == pytest.approx(-50.0, abs=2.0)
        assert abs(b["bias_cross_m"]) < 2.0
        assert 380 < -b["bias_row_px"] < 520


def test_joint_mount_fit_separates_the_angles(bundled, per_flight):
    # One flight (gimbal roll within 5 deg): the mount angles are nearly degenerate
    # (|corr| > 0.99). Both flights (roll -45 and +50 deg): one rotation, angles
    # determined to < 0.01 deg with |corr| < 0.3, and every flight still <= 7 m.
    rec, cam = bundled
    for e in per_flight[0]["groups"].values():
        assert abs(e["correlation"][1][2]) > 0.99
    report, cams = mount_groups(
        rec, cam, PerRecordHeightSurface(rec.column("paper_height_m")), "table", loo=True, joint=True
    )
    j = report["joint_fit"]
    angles = [j["parameters"][k]["value"] for k in MOUNT]
    sds = [j["parameters"][k]["sd"] for k in MOUNT]
    assert max(sds) < 0.01
    # docs/tour_papers.md: "one pitch of the gimbal base, +0.220 +- 0.004 deg"; docs/calibration.md:
    # x = -0.001 +- 0.002, z = 0.000 +- 0.004 deg. The angles to the printed digits; the
    # sd of y one digit further (0.00410), since s^2 / m instead of s^2 / (m - p) gives
    # 0.00394, which prints as 0.004 too (test_covariance_uses_m_minus_p_degrees_of_freedom).
    assert angles[1] == pytest.approx(0.220, abs=5e-4)
    assert angles[0] == pytest.approx(-0.001, abs=5e-4)
    assert angles[2] == pytest.approx(0.000, abs=5e-4)
    assert sds[1] == pytest.approx(0.00410, abs=5e-6)
    assert sds[0] == pytest.approx(0.002, abs=5e-4)
    assert sds[2] == pytest.approx(0.004, abs=5e-4)
    # docs/tour_papers.md: leave-one-out with --joint 5.4 / 5.7 m; docs: after 5.1 / 5.3 m
    for name, after, loo in (("T3", 5.1, 5.4), ("T4", 5.3, 5.7)):
        assert report["groups"][name]["mean_error_after_m"] == pytest.approx(after, abs=0.05)
        assert report["groups"][name]["mean_error_loo_m"] == pytest.approx(loo, abs=0.05)
    corr = np.array(j["correlation"], float)
    assert np.all(np.abs(corr[np.triu_indices(3, 1)]) < 0.3)
    assert all(e["mean_error_loo_m"] <= 7.0 for e in report["groups"].values())
    # the saved camera reproduces the after-errors through the ordinary locate path
    ground = locate(
        rec.pose(),
        cams["joint"],
        rec.column("row"),
        rec.column("col"),
        rec.column("paper_height_m"),
        outside="extrapolate",
    )  # T4-3: col 2308 > 2292
    d = GEOD.inv(ground.lon_deg, ground.lat_deg, rec.column("truth_lon_deg"), rec.column("truth_lat_deg"))[2]
    groups = np.array(rec.text("table"))
    for g, e in report["groups"].items():
        assert d[groups == g].mean() == pytest.approx(e["mean_error_after_m"], abs=1e-3)


def test_resection_reproduces_the_bundled_camera(bundled):
    # docs/records.md: f = 166841.0 px, i0 = 1162.12, j0 = 1146.42, RMS 0.25 m.
    # Same least-squares optimum from a start 10 % off in f and 50 px off in the
    # principal point; tolerances are docs/tour_papers.md's printed rounding plus solver
    # termination (1 px in f is 0.5 % of its 208-px standard deviation).
    rec, cam = bundled
    start = Camera(150000.0, 1112.0, 1196.0, cam.rows, cam.cols)
    r = resect_sensor(rec, as_sensor(start), ["f", "cy", "cx"])  # focal length, principal row i0, column j0
    assert r.success
    f, i0, j0 = r.fit.values
    assert f == pytest.approx(166841.0, abs=1.0)
    assert i0 == pytest.approx(1162.12, abs=0.02)
    assert j0 == pytest.approx(1146.42, abs=0.05)
    assert r.rms_m == pytest.approx(0.25, abs=0.01)
    # paper_height_m is the height where that camera's ray meets the published point:
    # the fitted heights agree to 0.1 m (0.25 m misfit over a ~1:1 slant).
    np.testing.assert_allclose(r.heights_m, rec.column("paper_height_m"), atol=0.1)


# ----------------------------------------------------------------- synthetic records
def _synthetic(tmp_path, rng, planted_cam, noise_m, n=20, name="syn.csv"):
    """Records at both flights' geometries, truth from the planted camera plus noise."""
    rows = []
    for k in range(n):
        left = k % 2 == 0
        lat, lon = (35.49, 80.99) if left else (36.41, 78.74)
        heading = 45.0 if left else 30.0
        g_roll = rng.uniform(47, 53) if left else rng.uniform(-48, -42)
        pose = Pose.from_deg(
            lat + rng.uniform(-0.01, 0.01),
            lon + rng.uniform(-0.01, 0.01),
            17987.0 + rng.normal(0, 0.3),
            heading + rng.normal(0, 0.1),
            3.5 + rng.normal(0, 0.1),
            rng.normal(0, 0.03),
            g_roll,
            -2.5 + rng.normal(0, 0.1),
        )
        i, j = rng.uniform(1, 2323), rng.uniform(1, 2292)
        h = rng.uniform(4600, 5400)
        g = locate(pose, planted_cam, i, j, h)
        frame = EnuFrame(float(g.lat), float(g.lon), h)
        tl, tn, _ = frame.to_geodetic(np.array([rng.normal(0, noise_m), rng.normal(0, noise_m), 0.0]))
        rows.append(
            [
                "T4" if left else "T3",
                k,
                f"{i:.6f}",
                f"{j:.6f}",
                *(f"{math.degrees(float(v)):.10f}" for v in (pose.lat, pose.lon)),
                f"{float(pose.h):.4f}",
                *(
                    f"{math.degrees(float(v)):.8f}"
                    for v in (pose.heading, pose.pitch, pose.roll, pose.gimbal_roll, pose.gimbal_pitch)
                ),
                f"{h:.4f}",
                f"{math.degrees(float(tl)):.10f}",
                f"{math.degrees(float(tn)):.10f}",
            ]
        )
    path = tmp_path / name
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        w.writerows(rows)
    return load_records(path)


@pytest.mark.parametrize("model", ["mount", "camera"])
def test_synthetic_fit_recovers_planted_rotation(tmp_path, model):
    # Planted: 0.05, 0.22, -0.10 deg; noise 3 m per component. Each angle must
    # lie within 3 reported standard deviations (a Gaussian passes with 99.7 %;
    # the seed is fixed) and the noise level must be recovered (s within 30 %
    # of 3 m: 40 residuals, 37 dof, relative sd of s ~ 12 %).
    rng = np.random.default_rng(8)
    base = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    planted = np.deg2rad([0.05, 0.22, -0.10])
    field = "mount" if model == "mount" else "boresight"
    rec = _synthetic(tmp_path, rng, Camera(**{**base.__dict__, field: tuple(planted)}), 3.0)
    fit = fit_rotation(rec, base, PerRecordHeightSurface(rec.column("paper_height_m")), model=model)
    assert fit.success
    z = (fit.values - planted) / fit.sd
    assert np.all(np.abs(z) < 3.0), (np.rad2deg(fit.values), np.rad2deg(fit.sd))
    assert fit.sigma_m == pytest.approx(3.0, rel=0.3)
    # and the camera's tilt angles are far better determined than its twist about
    # the line of sight (lever: pixel offset / f ~ 0.006 rad)
    if model == "camera":
        assert fit.sd[2] > 20 * max(fit.sd[:2])


def test_covariance_uses_m_minus_p_degrees_of_freedom(bundled):
    # cov = s^2 (J^T J)^-1 with s^2 = |r|^2 / (m - p) (module docstring): the reported sigma
    # is that s, from the fit's own residuals (m = 2 n components, p = 3 angles); with
    # s^2 / m it would be sqrt(37 / 40) = 3.8 % smaller
    rec, cam = bundled
    fit = fit_rotation(rec, cam, PerRecordHeightSurface(rec.column("paper_height_m")))
    r = fit.residual_m.ravel()
    assert r.size == 40 and len(fit.names) == 3
    assert fit.sigma_m == pytest.approx(math.sqrt(r @ r / (40 - 3)), rel=1e-12)
    # and the angles' sd is s sqrt(diag (J^T J)^-1), J by central differences here: the
    # residuals' Jacobian with respect to the three mount angles at the solution
    from geoloc.analysis.sensor_fit import _enu_residuals, _ground

    surf = PerRecordHeightSurface(rec.column("paper_height_m"))
    sensor = as_sensor(cam)
    tlat, tlon = np.deg2rad(rec.column("truth_lat_deg")), np.deg2rad(rec.column("truth_lon_deg"))

    def res(p):
        s = sensor.with_params(**dict(zip(MOUNT, p)))
        return _enu_residuals(_ground(s, rec.pose(), rec.column("row"), rec.column("col"), surf), tlat, tlon).ravel()

    h = 1e-7
    J = np.stack([(res(fit.values + h * e) - res(fit.values - h * e)) / (2 * h) for e in np.eye(3)], -1)
    sd = fit.sigma_m * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    np.testing.assert_allclose(fit.sd, sd, rtol=1e-3)  # finite differences: 1e-3


def test_synthetic_uncertainty_has_nominal_coverage(tmp_path):
    # 25 independent synthetic flights: the fraction of angle estimates within one
    # reported sd must be near 68.3 %. Binomial over 75 estimates (correlated
    # within a fit, so count per fit: n = 25), 3 sd of a proportion is 0.28.
    rng = np.random.default_rng(2026)
    base = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    planted = np.deg2rad([-0.03, 0.2, 0.08])
    hits = []
    for t in range(25):
        rec = _synthetic(
            tmp_path, rng, Camera(**{**base.__dict__, "mount": tuple(planted)}), 2.0, n=12, name=f"s{t}.csv"
        )
        fit = fit_rotation(rec, base, PerRecordHeightSurface(rec.column("paper_height_m")))
        hits.extend(np.abs(fit.values - planted) < fit.sd)
    assert abs(np.mean(hits) - 0.683) < 0.28


def test_noise_free_fit_is_exact(tmp_path):
    # Without noise the planted rotation is the exact solution: recovered to
    # 1e-7 deg (solver tolerance; 1e-7 deg moves an 18-km ray by 3e-5 m).
    rng = np.random.default_rng(1)
    base = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    planted = np.deg2rad([0.1, -0.2, 0.3])
    rec = _synthetic(tmp_path, rng, Camera(**{**base.__dict__, "mount": tuple(planted)}), 0.0, n=10)
    fit = fit_rotation(rec, base, PerRecordHeightSurface(rec.column("paper_height_m")))
    np.testing.assert_allclose(np.rad2deg(fit.values), np.rad2deg(planted), atol=1e-7)
    d = fit_sensor_params(
        rec, as_sensor(base), MOUNT, PerRecordHeightSurface(rec.column("paper_height_m")), loo=True
    ).loo_errors_m
    # truth coordinates are written with 1e-10 deg (1e-5 m): LOO errors at that level
    assert np.all(d < 1e-3)


# ----------------------------------------------------------------- decomposition and outliers
def _nadir_records(tmp_path, heading_deg):
    # Camera straight down (zero attitude and gimbal) at the principal point, 10 km
    # above the target height; truth placed 10 m NORTH of the computed point with
    # pyproj's direct geodesic.
    cam = Camera(100000.0, 1000.5, 1000.5, 2000, 2000)
    g = locate(Pose.from_deg(35.0, 80.0, 15000.0, heading_deg), cam, 1000.5, 1000.5, 5000.0)
    tlon, tlat, _ = GEOD.fwd(float(g.lon_deg), float(g.lat_deg), 0.0, 10.0)
    path = tmp_path / f"nadir{heading_deg}.csv"
    path.write_text(
        ",".join(COLUMNS) + "\n" + f"A,1,1000.5,1000.5,35.0,80.0,15000.0,{heading_deg},0,0,0,0,5000.0,"
        f"{tlat:.12f},{tlon:.12f}\n"
    )
    rec = load_records(path)
    return rec, cam, locate(rec.pose(), cam, rec.column("row"), rec.column("col"), 5000.0)


@pytest.mark.parametrize("heading, along, cross", [(0.0, -1.0, 0.0), (90.0, 0.0, 1.0), (180.0, 1.0, 0.0)])
def test_decomposition_closed_form(tmp_path, heading, along, cross):
    # Truth 10 m NORTH of the computed point on the ellipsoid (pyproj); at the target
    # height h = 5000 m the same latitude step spans d = 10 (M + h) / M metres
    # (M: meridian radius [Q17 eq. 16]), so computed - truth = d SOUTH. Heading
    # north: d behind; heading east: d to the right of track (+cross); heading
    # south: d ahead. distance_m is the geodesic on the ellipsoid: 10 m.
    # Pixel: the truth, d north at H = 10 km below the camera, is seen at row
    # i0 + f d / H when the nose (X_S, the row axis) points north, so the
    # measured-minus-truth error is -f d / H ~ -100 px along the nose direction;
    # in (X nose, Y right) north is (cos psi, -sin psi), and Y_S = -columns.
    # Tolerances: 1 mm (tangent plane vs ellipsoid over 10 m: ~1e-8 m) and 0.01 px
    # (Earth curvature over 10 m at 10 km: 1e-7 rad -> 0.01 px).
    rec, cam, ground = _nadir_records(tmp_path, heading)
    a, e2, phi = 6378137.0, 0.0066943799901413165, math.radians(35.0)
    M = a * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    d = 10.0 * (M + 5000.0) / M
    ev = error_vectors(rec, cam, ground)
    assert ev.east_m[0] == pytest.approx(0.0, abs=1e-3)
    assert ev.north_m[0] == pytest.approx(-d, abs=1e-3)
    assert ev.along_m[0] == pytest.approx(along * d, abs=1e-3)
    assert ev.cross_m[0] == pytest.approx(cross * d, abs=1e-3)
    assert ev.distance_m[0] == pytest.approx(10.0, abs=1e-3)
    h = math.radians(heading)
    assert ev.row_px[0] == pytest.approx(-100000.0 * d / 10000.0 * math.cos(h), abs=0.01)
    assert ev.col_px[0] == pytest.approx(-100000.0 * d / 10000.0 * math.sin(h), abs=0.01)


def test_outlier_rule():
    # Rayleigh median: for sigma = 1 the median distance is sqrt(2 ln 2) = 1.177,
    # so the rule's scale is exact on these constructed distances.
    rng = np.random.default_rng(3)
    e, n = rng.normal(0, 2.0, 200), rng.normal(0, 2.0, 200)
    e[7] += 40.0
    flags, d, sigma = outlier_flags(e, n)
    assert sigma == pytest.approx(2.0, rel=0.15)  # 200 samples: median sd ~ 7 %
    assert flags[7] and flags.sum() <= 3  # P(false flag) = 0.2 % each
    # all-identical errors: the 0.5 m floor keeps centimetre differences unflagged
    flags, _, sigma = outlier_flags(np.array([1.0, 1.01, 0.99, 1.02]), np.zeros(4))
    assert sigma == 0.5 and not flags.any()


def test_blunder_is_flagged_and_can_be_excluded(tmp_path, bundled):
    rec, cam = bundled
    lines = asset_path(*DEFAULT_RECORDS).read_text().splitlines()
    cells = lines[3].split(",")  # T3 point 3
    header = lines[0].split(",")
    k = header.index("truth_lat_deg")
    cells[k] = f"{float(cells[k]) + 0.0003:.5f}"  # +33 m north
    lines[3] = ",".join(cells)
    path = tmp_path / "blunder.csv"
    path.write_text("\n".join(lines) + "\n")
    bad = load_records(path)
    t = PerRecordHeightSurface(bad.column("paper_height_m"))
    report, _ = mount_groups(bad, cam, t, "table")
    assert report["groups"]["T3"]["before"]["outliers"] == [2]
    assert report["groups"]["T4"]["before"]["outliers"] == []
    assert report["groups"]["T3"]["records"][2]["outlier_before"]
    clean, _ = mount_groups(bad, cam, t, "table", exclude_outliers=True)
    assert clean["groups"]["T3"]["n_used_in_fit"] == 9
    # without the blunder the other nine fit better
    assert clean["groups"]["T3"]["sigma_m"] < report["groups"]["T3"]["sigma_m"]


# ----------------------------------------------------------------- command line
def test_cli_report_and_camera(tmp_path, capsys):
    out, camfile = tmp_path / "report.json", tmp_path / "cal.toml"
    code = main(
        [
            "calibrate",
            str(asset_path(*DEFAULT_RECORDS)),
            "--camera",
            str(asset_path(*DEFAULT_CAMERA)),
            "--height-column",
            "paper_height_m",
            "--group-by",
            "table",
            "--joint",
            "--out",
            str(out),
            "--write-camera",
            str(camfile),
        ]
    )
    assert code == 0
    rep = json.loads(out.read_text())
    for g in ("T3", "T4"):
        e = rep["groups"][g]
        for key in ("n", "mean_error_before_m", "mean_error_after_m", "mean_error_loo_m", "parameters"):
            assert key in e
        assert e["mean_error_loo_m"] is None  # --loo not given
        assert len(e["records"]) == 10 and "along_m" in e["records"][0]["before"]
    assert list(rep["joint_fit"]["parameters"]) == ["mount_x", "mount_y", "mount_z"]  # --model mount
    cam = Camera.from_toml(camfile)
    assert cam.mount is not None and cam.boresight is None
    np.testing.assert_allclose(
        np.rad2deg(cam.mount), [p["value"] for p in rep["joint_fit"]["parameters"].values()], rtol=1e-12
    )
    # the calibrated camera through the ordinary replay verb: ~5 m instead of ~50 m
    assert main(["replay", "--camera", str(camfile), "--height-column", "paper_height_m"]) == 0
    text = capsys.readouterr().out
    assert "group T3: n=10, mean error to truth 5.0" in text or "group T3: n=10, mean error to truth 5.1" in text


def test_cli_errors_name_the_problem(tmp_path, capsys):
    assert main(["calibrate"]) == 2
    assert "--height-column" in capsys.readouterr().err
    assert main(["calibrate", "--height-column", "nope"]) == 2
    assert "'nope'" in capsys.readouterr().err
    assert main(["calibrate", "--height-column", "paper_height_m", "--group-by", "zzz"]) == 2
    assert "'zzz'" in capsys.readouterr().err


def test_intrinsics_with_mount_from_both_sides(tmp_path):
    # Noise-free records from both flights' geometries, planted mount + 2 % focal
    # length + principal-point shift (+30, -20 px). Expected values are the planted
    # ones; tolerances: solver termination (f to 0.1 px = 6e-7 relative, i0 to
    # 0.01 px). The principal column and the mount's x angle are both rotations
    # about (nearly) the body X axis (gimbal pitch ~ -2.5 deg), so they are
    # degenerate: the fit must say so (|corr| > 0.99) rather than hide it.
    rng = np.random.default_rng(5)
    base = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    planted = np.deg2rad([0.05, 0.2, -0.1])
    true = Camera(
        **{
            **base.__dict__,
            "mount": tuple(planted),
            "focal_length_px": base.focal_length_px * 1.02,
            "principal_row": base.principal_row + 30.0,
            "principal_col": base.principal_col - 20.0,
        }
    )
    rec = _synthetic(tmp_path, rng, true, 0.0, n=20)
    # f: the focal length (fx and fy together); cy, cx: the principal row and column (1-based)
    fit = fit_rotation(rec, base, PerRecordHeightSurface(rec.column("paper_height_m")), names=["f", "cy", "cx"])
    par = fit.report()["parameters"]
    assert par["f"]["value"] == pytest.approx(true.focal_length_px, abs=0.1)
    assert par["cy"]["value"] == pytest.approx(true.principal_row, abs=0.01)
    np.testing.assert_allclose([par["mount_y"]["value"], par["mount_z"]["value"]], np.rad2deg(planted[1:]), atol=1e-5)
    names = fit.names
    assert abs(fit.correlation[names.index("mount_x"), names.index("cx")]) > 0.99
    # and within its (large) uncertainty the degenerate pair is still right
    assert abs(par["cx"]["value"] - true.principal_col) < 3 * par["cx"]["sd"] + 0.01


def test_cli_flags_degenerate_parameters(tmp_path, capsys):
    # One flight cannot separate the principal point from the mount angles (module
    # docstring): the report must say so, and stay valid JSON (no NaN).
    out = tmp_path / "r.json"
    assert (
        main(
            [
                "calibrate",
                "--height-column",
                "paper_height_m",
                "--fit-focal",
                "--fit-principal-point",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "not separable" in capsys.readouterr().out
    rep = json.loads(out.read_text())
    for e in rep["groups"].values():
        # the camera file's principal column is the sensor's cx (1-based), its focal length f
        assert ["mount_x", "cx"] in e["degenerate_pairs"]
        assert list(e["parameters"]) == ["mount_x", "mount_y", "mount_z", "f", "cy", "cx"]
        assert e["parameters"]["f"]["unit"] == "px" and e["parameters"]["cy"]["unit"] == "px"
