"""The budget judged by the data (geoloc.analysis.uncertainty.budget_check, geoloc report).

A simulated flight: for every record the truth is the point the chain gives with errors drawn
from a known budget (each source drawn and applied exactly by ``monte_carlo``, not through the
first order), and the record holds the error-free values. The predicted ellipses of that budget
must hold 88-92 % of the truths (a binomial 90 % with n = 1500 has a sigma of 0.77 %: the band is
+-2.6 sigma), the check must say the budget holds, and with the budget halved it must say
optimistic by about 2x. The reference for the chi-square radius is scipy's quantile.
"""

import csv
import math

import numpy as np
import pytest
from scipy import stats as sps

from geoloc.analysis import uncertainty as U
from geoloc.frames.chain import Pose
from geoloc.geodesy.local import enu_to_geodetic
from geoloc.sensors.budget import ErrorBudget
from geoloc.status import Status
from geoloc.surfaces.height import HeightSurface
from test_uncertainty import TURRET

BUDGET = ErrorBudget(
    {
        "north_m": 3.0,
        "east_m": 3.0,
        "up_m": 4.0,
        "heading_deg": 0.1,
        "pitch_deg": 0.05,
        "roll_deg": 0.05,
        "azimuth_deg": 0.05,
        "elevation_deg": 0.05,
        "mount_z_deg": 0.02,
        "boresight_x_deg": 0.02,
        "fx_px": 3.0,
        "cx_px": 1.0,
        "height_m": 8.0,
    }
)
N = 1500


@pytest.fixture(scope="module")
def flight():
    rng = np.random.default_rng(29)
    t = np.linspace(0, 2 * math.pi, N, endpoint=False)
    lat = 36.5 + 0.03 * np.sin(t)
    lon = -84.25 + 0.04 * np.cos(t)
    hd = np.mod(np.degrees(t) + 90.0, 360.0)
    el = rng.uniform(-85, -35, N)
    az = rng.uniform(0, 360, N)
    row, col = rng.uniform(1, 1080, N), rng.uniform(1, 1920, N)
    surf = HeightSurface(500.0)
    err = np.full((N, 3), np.nan)
    for i in range(N):
        pose = Pose.from_deg(
            lat[i], lon[i], 3000.0, hd[i], 1.0, -0.5, angles_deg={"azimuth": az[i], "elevation": el[i]}
        )
        enu, st = U.monte_carlo(TURRET, pose, row[i], col[i], BUDGET, surf, 1, rng)
        if st[0] == Status.OK:
            err[i] = -enu[0]  # computed (error-free record) minus truth (the drawn chain)
    poses = Pose.from_deg(
        lat, lon, np.full(N, 3000.0), hd, np.full(N, 1.0), np.full(N, -0.5), angles_deg={"azimuth": az, "elevation": el}
    )
    pu = U.propagate(TURRET, poses, row, col, BUDGET, surface=surf)
    ok = np.isfinite(err[:, 0]) & (pu.status == Status.OK)
    assert ok.mean() > 0.99
    return err[ok], pu, ok


def _check(err, pu, ok, scale=1.0):
    return U.budget_check(
        err[:, 0],
        err[:, 1],
        pu.ellipse_major_m[ok] * scale,
        pu.ellipse_minor_m[ok] * scale,
        pu.ellipse_azimuth_deg[ok],
        err[:, 2],
        pu.le90_m[ok] * scale,
    )


def test_ellipse_radius_is_the_chi_square_quantile():
    assert U.ELLIPSE90_PER_SIGMA == pytest.approx(math.sqrt(sps.chi2.ppf(0.9, 2)), rel=1e-12)
    assert U.ELLIPSE99_PER_SIGMA == pytest.approx(math.sqrt(sps.chi2.ppf(0.99, 2)), rel=1e-12)


def test_a_right_budget_holds_88_to_92_percent_of_the_truths(flight):
    err, pu, ok = flight
    c = _check(err, pu, ok)
    assert 0.88 <= c["inside_90"] <= 0.92, c["text"]
    assert c["verdict"] == "holds", c["text"]
    assert "holds" in c["text"]
    assert 0.88 <= c["vertical"]["inside_90"] <= 0.92, c["vertical"]["text"]
    assert c["vertical"]["verdict"] == "holds"
    # the 99 % ellipse: about 1 % outside (binomial sigma 0.26 % at n = 1500: 3 sigma is 0.8 %)
    out = U.outside_ellipse(
        err[:, 0], err[:, 1], pu.ellipse_major_m[ok], pu.ellipse_minor_m[ok], pu.ellipse_azimuth_deg[ok]
    )
    assert 0.002 <= out.mean() <= 0.018


def test_a_halved_budget_is_optimistic_by_about_2x(flight):
    err, pu, ok = flight
    c = _check(err, pu, ok, scale=0.5)  # the first order is linear: half every sigma, half the ellipse
    assert c["verdict"] == "optimistic", c["text"]
    assert c["factor"] == pytest.approx(2.0, rel=0.1), c["text"]  # the 90th percentile of n = 1500: ~3 %
    assert "optimistic" in c["text"] and "2.0" in f"{c['factor']:.1f}"
    d = _check(err, pu, ok, scale=2.0)
    assert d["verdict"] == "pessimistic" and d["factor"] == pytest.approx(0.5, rel=0.1)


def test_the_halved_budget_propagates_to_the_halved_ellipse():
    """What makes scaling the ellipse the same as halving the budget: the first order is linear."""
    pose = Pose.from_deg(36.5, -84.25, 3000.0, 30.0, 1.0, -0.5, angles_deg={"azimuth": 40.0, "elevation": -50.0})
    a = U.propagate(TURRET, pose, 300.0, 700.0, BUDGET, surface=HeightSurface(500.0))
    b = U.propagate(TURRET, pose, 300.0, 700.0, BUDGET.scaled(0.5), surface=HeightSurface(500.0))
    # the lens columns are +-1 sigma secants: second order in sigma, < 1e-6 of the axes here
    assert float(b.ellipse_major_m) == pytest.approx(0.5 * float(a.ellipse_major_m), rel=1e-6)
    assert float(b.le90_m) == pytest.approx(0.5 * float(a.le90_m), rel=1e-6)


def test_report_says_whether_the_budget_holds(flight, tmp_path):
    """Through the replay CSV's columns and ``geoloc report``'s reader."""
    from geoloc.cli.report import report_from_csv

    err, pu, ok = flight
    lat, lon, h = (np.degrees(pu.lat[ok]), np.degrees(pu.lon[ok]), pu.h[ok])
    tl, tn, th = enu_to_geodetic(-err, pu.lat[ok], pu.lon[ok], pu.h[ok])
    for scale, verdict in ((1.0, "holds"), (0.5, "optimistic")):
        p = tmp_path / f"r{scale}.csv"
        with p.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(
                [
                    "lat_deg",
                    "lon_deg",
                    "h_m",
                    "truth_lat_deg",
                    "truth_lon_deg",
                    "truth_h_m",
                    "status",
                    "ce90_m",
                    "le90_m",
                    "ellipse_major_m",
                    "ellipse_minor_m",
                    "ellipse_azimuth_deg",
                ]
            )
            for k in range(len(lat)):
                w.writerow(
                    [
                        f"{lat[k]:.10f}",
                        f"{lon[k]:.10f}",
                        f"{h[k]:.4f}",
                        f"{np.degrees(tl[k]):.10f}",
                        f"{np.degrees(tn[k]):.10f}",
                        f"{th[k]:.4f}",
                        "ok",
                        f"{pu.ce90_m[ok][k] * scale:.4f}",
                        f"{pu.le90_m[ok][k] * scale:.4f}",
                        f"{pu.ellipse_major_m[ok][k] * scale:.4f}",
                        f"{pu.ellipse_minor_m[ok][k] * scale:.4f}",
                        f"{pu.ellipse_azimuth_deg[ok][k]:.4f}",
                    ]
                )
        rep, _ = report_from_csv(p)
        b = rep.overall["budget"]
        assert b["verdict"] == verdict, b["text"]
        assert 0.88 <= b["inside_90"] <= 0.92 if verdict == "holds" else b["factor"] == pytest.approx(2.0, rel=0.1)
        assert b["text"] in rep.markdown()
        assert len(rep.components["normalised_error"]) == len(lat)


def test_replay_writes_the_predicted_columns_only_with_a_budget(tmp_path):
    """``geoloc replay --sensor FILE``: the columns when the file has ``[uncertainty]``, none without;
    the values are ``propagate``'s for the record (the API the tests above judge)."""
    from geoloc.assets import asset_path
    from geoloc.cli import main
    from geoloc.io.records import load_records
    from geoloc.sensors.sensor_file import load_sensor
    from geoloc.workflows.replay import UNCERTAINTY_COLUMNS

    cam = asset_path("cameras", "qiao2017.toml")
    with_budget = tmp_path / "q.toml"
    with_budget.write_text(
        cam.read_text() + "\n[uncertainty]\nnorth_m = 2.0\nheading_deg = 0.02\n"
        "gimbal_pitch_deg = 0.005\nheight_m = 5.0\n"
    )
    for sensor, expect in ((cam, False), (with_budget, True)):
        out = tmp_path / f"{sensor.stem}.csv"
        assert main(["replay", "--sensor", str(sensor), "--height-column", "paper_height_m", "--out", str(out)]) == 0
        with out.open() as fh:
            rows = list(csv.DictReader(fh))
        assert all(c in rows[0] for c in UNCERTAINTY_COLUMNS) == expect
    recs = load_records(asset_path("records", "qiao2017_flight_tests.csv"))
    pose = recs.pose()
    k = 0
    p1 = Pose(pose.lat[k], pose.lon[k], pose.h[k], pose.heading[k], pose.pitch[k], pose.roll[k]).with_angles(
        **{a: pose.angle(a)[k] for a in ("gimbal_roll", "gimbal_pitch")}
    )
    pu = U.propagate(
        load_sensor(cam),
        p1,
        recs.column("row")[k],
        recs.column("col")[k],
        ErrorBudget({"north_m": 2.0, "heading_deg": 0.02, "gimbal_pitch_deg": 0.005, "height_m": 5.0}),
        surface=HeightSurface(recs.column("paper_height_m")[k]),
    )
    assert float(rows[0]["ce90_m"]) == pytest.approx(float(pu.ce90_m), abs=1e-3)  # written with 3 decimals
    assert float(rows[0]["ellipse_azimuth_deg"]) == pytest.approx(float(pu.ellipse_azimuth_deg), abs=1e-3)


def test_klv_replay_predicts_beside_the_packets_own_tags_45_46(tmp_path):
    """Nadir packets, a budget of platform position only and a height error: the closed forms are a
    circular error of sigma (CE90 = sqrt(-2 ln 0.1) sigma, scipy's chi-square) and LE90 = 1.6449
    sigma_h; the packet's own estimates (tags 45, 46) come back beside them, as klvdata reads them."""
    import klvdata
    from test_klv_replay import pose_fields, with_oracle

    from geoloc.io.klv import encode_packet
    from geoloc.workflows.klv_replay import replay_klv

    pk = []
    for i in range(3):
        f = with_oracle(pose_fields(36.5 + 0.001 * i, -84.25, 3000.0, 30.0, 0.0, -90.0, i=i))[0]
        f.update(target_error_ce90_m=25.0, target_error_le90_m=12.0)
        pk.append(encode_packet(f))
    path = tmp_path / "n.klv"
    path.write_bytes(b"".join(pk))
    independent = [p.MetadataList() for p in klvdata.StreamParser(path.read_bytes())]
    assert float(independent[0][45][3]) == pytest.approx(25.0, abs=0.1)  # klvdata's own decoding of tag 45
    r = replay_klv(path, budget=ErrorBudget({"north_m": 4.0, "east_m": 4.0, "height_m": 6.0}))
    c = r.columns
    np.testing.assert_allclose(c["reported_ce90_m"], 25.0, atol=0.1)  # tag 45's step: 4095 / 65535 m
    np.testing.assert_allclose(c["reported_le90_m"], 12.0, atol=0.1)
    # the platform's shift moves the hit by the same amount (the local frame's turn over 3 km: 5e-4)
    np.testing.assert_allclose(c["ce90_m"], math.sqrt(sps.chi2.ppf(0.9, 2)) * 4.0, rtol=2e-3)
    np.testing.assert_allclose(c["le90_m"], sps.norm.ppf(0.95) * 6.0, rtol=1e-6)
