"""The accuracy report (geoloc.analysis.accuracy, `geoloc report`) against outside oracles.

Oracles: pymap3d (``geodetic2ned``, ``geodetic2aer``) for the error components and the
sight geometry, pyproj's geodesic (``Geod.fwd``) for along / across track, ``np.percentile``
/ ``np.mean`` / ``np.polyfit`` written here for the statistics, and the replay CSV's own
``error_to_truth_m`` column (pyproj's geodesic distance, computed by the replay, not the report).
The [Q17] flight-test replay is made by `geoloc replay` in a temporary folder.
"""

from __future__ import annotations

import base64
import csv
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from pyproj import Geod

from geoloc.analysis.accuracy import (
    accuracy_report,
    datum_warning,
    error_components,
    outlier_rule,
    robust_outliers,
    sight_geometry,
)
from geoloc.cli import main

ROOT = Path(__file__).resolve().parents[2]
RECORDS = ROOT / "assets" / "records" / "qiao2017_flight_tests.csv"
GEOD = Geod(ellps="WGS84")


@pytest.fixture(scope="module")
def replay_csv(tmp_path_factory):
    out = tmp_path_factory.mktemp("rep") / "q17_replay.csv"
    assert main(["replay", str(RECORDS), "--height-column", "paper_height_m", "--out", str(out)]) == 0
    return out


def _read(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return rows, (lambda k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows]))


def _direct(rows, col):
    """Errors computed here, independently of geoloc: pymap3d about the truth (at the computed height for
    the horizontal, at paper_height_m for the vertical)."""
    lat, lon, h = col("lat_deg"), col("lon_deg"), col("h_m")
    tl, to, th = col("truth_lat_deg"), col("truth_lon_deg"), col("paper_height_m")
    n, e, _ = pymap3d.geodetic2ned(lat, lon, h, tl, to, h)
    _, _, d = pymap3d.geodetic2ned(lat, lon, h, tl, to, th)
    return np.hypot(n, e), -d, n, e


# --------------------------------------------------------------------------- components


def test_components_equal_pymap3d_geodetic2ned():
    rng = np.random.default_rng(5)
    lat0, lon0, h0 = rng.uniform(-80, 80, 200), rng.uniform(-180, 180, 200), rng.uniform(-100, 5000, 200)
    lat = lat0 + rng.normal(0, 1e-3, 200)
    lon = lon0 + rng.normal(0, 1e-3, 200)
    h = h0 + rng.normal(0, 30, 200)
    c = error_components(lat, lon, h, lat0, lon0, h0)
    n, e, d = pymap3d.geodetic2ned(lat, lon, h, lat0, lon0, h0)
    # pymap3d and geoloc both go through ECEF in float64: agreement at 1e-6 m for 100 m vectors
    # (ECEF magnitudes 6.4e6 m carry ~1e-9 m rounding; 1e-6 leaves margin for the different formulas)
    np.testing.assert_allclose(c["north_m"], n, atol=1e-6)
    np.testing.assert_allclose(c["east_m"], e, atol=1e-6)
    np.testing.assert_allclose(c["up_m"], -d, atol=1e-6)
    np.testing.assert_allclose(c["vertical_m"], -d, atol=1e-6)
    np.testing.assert_allclose(c["horizontal_m"], np.hypot(n, e), atol=1e-6)
    np.testing.assert_allclose(c["slant_m"], np.sqrt(n * n + e * e + d * d), atol=1e-6)


def test_along_across_from_pyproj_displacements():
    # a point 40 m from the reference along azimuth psi (pyproj's geodesic) is +40 m along a track of
    # heading psi; at psi + 90 deg it is +40 m across (right of track). The geodesic and the tangent-plane
    # vector differ by O(d^3 / R^2) at 40 m (and the 0.1 mm height drop is not in the horizontal):
    # 1e-3 m bounds both. At height 0: Geod measures on the ellipsoid itself (at height h the same
    # angle spans (R + h) / R times more, 3 cm at 4.8 km).
    lat0, lon0, h0 = 36.3, 78.8, 0.0
    for psi in (0.0, 30.0, 135.0, 250.0):
        lo1, la1, _ = GEOD.fwd(lon0, lat0, psi, 40.0)
        lo2, la2, _ = GEOD.fwd(lon0, lat0, psi + 90.0, 40.0)
        c = error_components([la1, la2], [lo1, lo2], h0, lat0, lon0, np.nan, track_heading_rad=math.radians(psi))
        assert c["along_m"][0] == pytest.approx(40.0, abs=1e-3)
        assert c["across_m"][0] == pytest.approx(0.0, abs=1e-3)
        assert c["along_m"][1] == pytest.approx(0.0, abs=1e-3)
        assert c["across_m"][1] == pytest.approx(40.0, abs=1e-3)
        assert np.isnan(c["up_m"]).all()  # no reference height: no vertical


def test_nan_rows_stay_nan():
    c = error_components(
        [36.0, np.nan, 36.0],
        [78.0, 78.0, 78.0],
        [100.0, 100.0, np.nan],
        [36.0001, 36.0, 36.0],
        [78.0, 78.0, 78.0],
        [90.0, 90.0, 90.0],
        track_heading_rad=0.3,
    )
    for k, v in c.items():
        assert np.isfinite(v[0]), k
        assert np.isnan(v[1]) and np.isnan(v[2]), k


def test_sight_geometry_equals_pymap3d_aer(replay_csv):
    rows, col = _read(replay_csv)
    g = sight_geometry(col("ac_lat_deg"), col("ac_lon_deg"), col("ac_h_m"), col("lat_deg"), col("lon_deg"), col("h_m"))
    _az, el, srange = pymap3d.geodetic2aer(
        col("lat_deg"), col("lon_deg"), col("h_m"), col("ac_lat_deg"), col("ac_lon_deg"), col("ac_h_m")
    )
    # 20 km ranges through ECEF in float64 on both sides: 1e-6 m, 1e-9 rad
    np.testing.assert_allclose(g["slant_range_m"], srange, atol=1e-6)
    np.testing.assert_allclose(g["off_nadir_rad"], np.deg2rad(90.0 + el), atol=1e-9)  # el < 0 looking down


# --------------------------------------------------------------------------- outliers


def test_robust_outliers_is_the_klv_rule():
    from geoloc.workflows.klv_replay import outlier_mask

    rng = np.random.default_rng(1)
    e = rng.normal(10.0, 2.0, 500)
    e[[7, 300]] = [60.0, -40.0]
    e[11] = np.nan
    m = robust_outliers(e)
    # the rule by hand: |e - median| > max(3.5 * 1.4826 * MAD, 1 m)
    ok = np.isfinite(e)
    med = np.median(e[ok])
    thr = max(3.5 * 1.4826 * np.median(np.abs(e[ok] - med)), 1.0)
    expect = ok & (np.abs(np.nan_to_num(e, nan=med) - med) > thr)
    assert np.array_equal(m, expect)
    assert m[7] and m[300] and not m[11]
    km, kmed, _, kthr = outlier_mask(e)
    assert np.array_equal(km, m) and kmed == med and kthr == pytest.approx(thr, rel=1e-15)
    assert outlier_rule(e)[3] == kthr


# --------------------------------------------------------------------------- the report's numbers


def test_report_numbers_equal_a_direct_computation(replay_csv):
    from geoloc.cli.report import report_from_csv

    rows, col = _read(replay_csv)
    rep, messages = report_from_csv(replay_csv, ref_h_column="paper_height_m")
    assert messages == []
    hor, up, n, e = _direct(rows, col)
    table = np.array([r["table"] for r in rows])
    for g, s in list(rep.groups.items()) + [("all", rep.overall)]:
        m = np.ones(len(rows), bool) if g == "all" else table == g
        assert s["n"] == m.sum() == 10 * (2 if g == "all" else 1)
        # the same float64 numbers through pymap3d here and geoloc there: 1e-6 m
        assert s["cep_m"] == pytest.approx(np.percentile(hor[m], 50), abs=1e-6)
        assert s["ce90_m"] == pytest.approx(np.percentile(hor[m], 90), abs=1e-6)
        assert s["le90_m"] == pytest.approx(np.percentile(np.abs(up[m]), 90), abs=1e-6)
        assert s["mae_horizontal_m"] == pytest.approx(hor[m].mean(), abs=1e-6)
        assert s["mae_vertical_m"] == pytest.approx(np.abs(up[m]).mean(), abs=1e-6)
        assert s["bias_north_m"] == pytest.approx(n[m].mean(), abs=1e-6)
        assert s["bias_east_m"] == pytest.approx(e[m].mean(), abs=1e-6)
        assert s["bias_up_m"] == pytest.approx(up[m].mean(), abs=1e-6)
        # [Q17] eq. 18 on the north/east spreads is the radial RMS about the mean error
        assert s["radial_rms_eq18_m"] == pytest.approx(math.hypot(np.std(n[m], ddof=1), np.std(e[m], ddof=1)), rel=1e-9)
        # against the replay's own error column (pyproj's geodesic on the ellipsoid): the report's
        # error is at the target's height (~4.9 km), longer by h / R = 7.7e-4; 1e-3 relative covers it
        d = col("error_to_truth_m")[m]
        assert s["cep_m"] == pytest.approx(np.percentile(d, 50), rel=1e-3)
        assert s["ce90_m"] == pytest.approx(np.percentile(d, 90), rel=1e-3)
        assert s["mae_horizontal_m"] == pytest.approx(d.mean(), rel=1e-3)
    # the published figures: mean error to truth about 50 m in both flights ([Q17] Tables 3-4)
    assert 45 < rep.groups["T3"]["mae_horizontal_m"] < 55 and 45 < rep.groups["T4"]["mae_horizontal_m"] < 55
    assert rep.overall["datum_warning"] is None
    assert all(s["datum_warning"] is None for s in rep.groups.values())


def test_slant_range_model_equals_polyfit(replay_csv):
    from geoloc.cli.report import report_from_csv

    rows, col = _read(replay_csv)
    rep, _ = report_from_csv(replay_csv, ref_h_column="paper_height_m")
    hor, *_ = _direct(rows, col)
    _, _, srange = pymap3d.geodetic2aer(
        col("lat_deg"), col("lon_deg"), col("h_m"), col("ac_lat_deg"), col("ac_lon_deg"), col("ac_h_m")
    )
    table = np.array([r["table"] for r in rows])
    for g, s in list(rep.groups.items()) + [("all", rep.overall)]:
        m = np.ones(len(rows), bool) if g == "all" else table == g
        slope, icpt = np.polyfit(srange[m], hor[m], 1)
        mdl = s["slant_range_model"]
        assert mdl["error"] == "horizontal_m" and mdl["n"] == m.sum()
        # lstsq vs polyfit on 20 km ranges: both solve the same normal problem; conditioning ~1e8
        # leaves ~1e-8 relative, so 1e-6 m/m and 1e-4 m are loose but far below the figures (m, mm/m)
        assert mdl["m_per_m"] == pytest.approx(slope, abs=1e-6)
        assert mdl["intercept_m"] == pytest.approx(icpt, abs=1e-2)
        # binned medians: each bin's median equals np.median of the errors whose range falls in it
        for b in s["by_slant_range_m"]:
            inb = m & (srange >= b["lo"] - 1e-6) & (srange <= b["hi"] + 1e-6)
            assert b["n"] in (inb.sum(), inb.sum() - 1)  # a shared edge belongs to one bin only
    assert sum(b["n"] for b in rep.overall["by_slant_range_m"]) == 20


def _shifted_csv(src, dst, dh):
    with open(src, newline="") as fh:
        rows = list(csv.DictReader(fh))
        header = list(rows[0].keys())
    for r in rows:
        r["h_m"] = f"{float(r['h_m']) + dh:.3f}"
    with open(dst, "w", newline="") as fh:
        w = csv.DictWriter(fh, header)
        w.writeheader()
        w.writerows(rows)
    return dst


def test_datum_warning_fires_on_a_planted_30_m_shift(replay_csv, tmp_path):
    from geoloc.cli.report import report_from_csv

    rep, _ = report_from_csv(_shifted_csv(replay_csv, tmp_path / "s.csv", 30.0), ref_h_column="paper_height_m")
    assert rep.overall["bias_up_m"] == pytest.approx(30.0, abs=0.1)  # the 30 m planted, minus the ~1 cm clean bias
    assert "likely datum mismatch" in rep.overall["datum_warning"]
    assert all("likely datum mismatch" in s["datum_warning"] for s in rep.groups.values())
    assert len(rep.warnings) == 3
    # the rule's two halves: a 6 m mean with a 20 m spread is not "shared" (SE 4.5 m > 6/3) ...
    rng = np.random.default_rng(3)
    u = rng.normal(0, 1, 20)
    u = 6.0 + 20.0 * (u - u.mean()) / u.std(ddof=1)
    assert datum_warning(u)[0] is None
    # ... and a 4 m shared bias is below the 5 m floor
    assert datum_warning(np.full(20, 4.0) + rng.normal(0, 0.1, 20))[0] is None
    assert datum_warning(np.full(20, 6.0) + rng.normal(0, 0.1, 20))[0] is not None


def test_cli_writes_png_html_and_json(replay_csv, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["report", str(replay_csv), "--ref-h-column", "paper_height_m", "--out-dir", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| T3 | 10 |" in text and "| all | 20 |" in text
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) == 5  # north/east scatter, CDF, slant range, off-nadir, pixel radius
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (out / "report.html").read_text()
    blobs = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert sorted(base64.b64decode(b) for b in blobs) == sorted(p.read_bytes() for p in pngs)
    assert "<script" not in page and "http" not in page.split("<pre>")[0]  # self-contained, no fetches
    d = json.loads((out / "report.json").read_text())
    rows, col = _read(replay_csv)
    hor, *_ = _direct(rows, col)
    cep = np.percentile(hor, 50)
    assert f"{cep:.2f}" in page and f"{np.percentile(hor, 90):.2f}" in page
    assert d["overall"]["cep_m"] == pytest.approx(cep, abs=1e-6)
    assert len(d["targets"]["horizontal_m"]) == 20

    assert main(["report", str(replay_csv), "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    assert j["overall"]["le90_m"] is None  # no reference height given: no vertical, said so
    assert "no reference height" in j["meta"]["reference"]
    assert j["overall"]["cep_m"] == pytest.approx(cep, abs=1e-6)
    assert set(j["groups"]) == {"T3", "T4"}


def test_cli_reports_bad_rows_and_keeps_the_good(replay_csv, tmp_path, capsys):
    lines = replay_csv.read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("lat_deg")
    bad = lines[3].split(",")
    bad[k] = "north"
    lines[3] = ",".join(bad)
    lines.insert(6, "T3,too,few")
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    assert main(["report", str(p), "--json"]) == 0
    cap = capsys.readouterr()
    assert "line 4: column lat_deg = 'north' is not a number" in cap.err
    assert "line 7: 3 fields" in cap.err
    assert json.loads(cap.out)["overall"]["n"] == 19
    assert main(["report", str(tmp_path / "missing.csv")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_report_api_groups_and_tracks():
    # two flights, synthetic errors planted with pyproj: flight A +10 m along a 90 deg track,
    # flight B +5 m to the right of a 0 deg track; heights shifted by -2 m
    lat0 = np.array([36.0, 36.001, 36.002, 35.0, 35.001, 35.002])
    lon0 = np.array([78.0, 78.0, 78.0, 81.0, 81.0, 81.0])
    psi = np.array([90.0, 90.0, 90.0, 0.0, 0.0, 0.0])
    lon1, lat1, _ = GEOD.fwd(lon0, lat0, np.where(psi == 90.0, 90.0, 90.0), np.where(psi == 90.0, 10.0, 5.0))
    rep = accuracy_report(
        lat1, lon1, 98.0, lat0, lon0, 100.0, track_heading_rad=np.deg2rad(psi), group=["A"] * 3 + ["B"] * 3
    )
    # tangent plane vs geodesic at 10 m: ~1e-5 m; the 2 m drop moves the horizontal by 2 * 10/R: negligible
    assert rep.groups["A"]["bias_along_m"] == pytest.approx(10.0, abs=1e-3)
    assert rep.groups["A"]["bias_across_m"] == pytest.approx(0.0, abs=1e-3)
    assert rep.groups["B"]["bias_across_m"] == pytest.approx(5.0, abs=1e-3)
    assert rep.groups["B"]["bias_along_m"] == pytest.approx(0.0, abs=1e-3)
    # the sphere's curvature lowers a point 10 m away by d^2 / 2R = 8e-6 m: up is -2 m to 1e-4
    assert rep.overall["bias_up_m"] == pytest.approx(-2.0, abs=1e-4)
    assert rep.overall["le90_m"] == pytest.approx(2.0, abs=1e-4)
    md = rep.markdown()
    assert "| A | 3 |" in md and "| all | 6 |" in md and "Hyndman-Fan" in md


def test_example_72_prints_the_report(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "72_accuracy_report.py"), str(tmp_path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    m = re.search(r"CEP ([0-9.]+) m, CE90 ([0-9.]+) m .* direct ([0-9.]+) m, ([0-9.]+) m", r.stdout)
    assert m, r.stdout
    # the example's report and its own direct np.percentile of pymap3d errors agree to the printed 0.01 m
    assert float(m.group(1)) == pytest.approx(float(m.group(3)), abs=0.006)
    assert float(m.group(2)) == pytest.approx(float(m.group(4)), abs=0.006)
    # [Q17] Tables 3-4: the flight-test errors to truth are about 50 m
    assert 45 < float(m.group(1)) < 55
    assert "likely datum mismatch" in r.stdout  # the planted +30 m shift
    assert (tmp_path / "report.html").exists()


def test_readme_accuracy_table(replay_csv, capsys):
    # docs/tour_accuracy.md "Accuracy report": the table's digits (regression pins; the definitions are held to a
    # direct computation in test_report_numbers_equal_a_direct_computation)
    assert main(["report", str(replay_csv), "--ref-h-column", "paper_height_m", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    table = {
        "T3": (10, 50.71, 51.87, 50.05, -49.83, -0.59),
        "T4": (10, 49.79, 54.99, 50.56, -50.27, -0.60),
        "all": (20, 50.25, 54.99, 50.31, -50.05, -0.59),
    }
    for g, (n, cep, ce90, mae, along, across) in table.items():
        e = d["overall"] if g == "all" else d["groups"][g]
        got = (e["n"], e["cep_m"], e["ce90_m"], e["mae_horizontal_m"], e["bias_along_m"], e["bias_across_m"])
        assert got[0] == n
        np.testing.assert_allclose(got[1:], (cep, ce90, mae, along, across), atol=0.005)  # printed to 1 cm
