"""``geoloc reproduce``: the project's numbers beside [Q17]'s published ones."""

import json

import numpy as np
import pytest

from geoloc.cli import main
from geoloc.cli._options import surface_from_scenario
from geoloc.workflows import reproduce as rp


@pytest.fixture(scope="module")
def q17():
    return rp.qiao2017_report(samples=5000, seed=0, sweep_samples=300)  # no surface: no DEM parts


def test_nominal_point_is_the_papers(q17):
    n = q17.numbers
    # [Q17] section 3.2 prints 35.57709 N, 80.84918 E: half a unit of the 5th decimal
    assert abs(n["nominal_lat_deg"] - 35.57709) <= 0.5e-5
    assert abs(n["nominal_lon_deg"] - 80.84918) <= 0.5e-5


def test_monte_carlo_std_within_5_percent(q17):
    n = q17.numbers
    for key, paper in (("mc_std_lat_deg", 0.00048), ("mc_std_lon_deg", 0.00060), ("mc_std_h_m", 62.3)):
        assert abs(n[key] / paper - 1) < 0.05, key  # 5 %: 1 % sampling, 1 % the paper's rounding, and margin


def test_flight_test_positions_and_errors(q17):
    n = q17.numbers
    # published coordinates are rounded to 1e-5 deg (1.1 m N, 0.9 m E): a uniform
    # rounding error has an RMS of ~0.4 m, so 1 m bounds the replay's misfit
    assert n["flight_rms_to_paper_m"] < 1.0
    # [Q17] section 4 mean errors per flight against the surveyed truth: 50.246 m
    # (Table 3) and 50.485 m (Table 4); 1 m for the same rounding
    assert n["flight_T3_mean_error_m"] == pytest.approx(50.246, abs=1.0)
    assert n["flight_T4_mean_error_m"] == pytest.approx(50.485, abs=1.0)


@pytest.fixture(scope="module")
def q17_dem():
    # the defaults of `geoloc reproduce qiao2017`: the DEM scenario's surface, opened by the caller
    return rp.qiao2017_report(surface=surface_from_scenario(rp.load_q17_dem_model()))


def test_reproduce_table_of_the_docs(q17_dem):
    """docs/montecarlo.md's side-by-side table and docs/tour_papers.md's Table 1-2 row and Fig. 10b
    sentence, at their printed digits, each beside its outside reference: [Q17]'s values
    (5 %), the first-order propagation (a different method: within 3 %, three sampling
    standard errors of a std at N = 5000), the paper's Fig. 10b bounds."""
    from geoloc.analysis import montecarlo as mc
    from geoloc.analysis.errormodel import ErrorModel
    from geoloc.assets import asset_path

    n = q17_dem.numbers
    # geoloc row: 0.000483 deg, 0.000596 deg, 62.1 m; CEP eq. 18 76 m, CEP50 52 m
    assert (round(n["mc_std_lat_deg"], 6), round(n["mc_std_lon_deg"], 6), round(n["mc_std_h_m"], 1)) == (
        0.000483,
        0.000596,
        62.1,
    )
    assert (round(n["mc_cep_m"]), round(n["mc_cep50_empirical_m"])) == (76, 52)
    fo = mc.first_order(ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml")))
    # docs/tour_papers.md's first-order row: 0.000487 deg, 0.000602 deg, 62.47 m
    assert (round(fo.std_lat_deg, 6), round(fo.std_lon_deg, 6), round(fo.std_h_m, 2)) == (0.000487, 0.000602, 62.47)
    for k, ref in (("mc_std_lat_deg", fo.std_lat_deg), ("mc_std_lon_deg", fo.std_lon_deg), ("mc_std_h_m", fo.std_h_m)):
        assert n[k] == pytest.approx(ref, rel=0.03)
    # the DEM row: 0.00012 deg, 0.00014 deg, 0.64 m (ETOPO5; [Q17]: 0.00015, 0.00013, 3.58 m on ASTER)
    assert (round(n["mcdem_std_lat_deg"], 5), round(n["mcdem_std_lon_deg"], 5), round(n["mcdem_std_h_m"], 2)) == (
        0.00012,
        0.00014,
        0.64,
    )
    # Fig. 10b on the bundled DEM: "36 m at 70 deg and 106 m at 80 deg" against the paper's
    # "< 50 m" and "< 180 m"; angles 10, 30, 50, 63, 70, 80, 82
    c = n["fig10b_cep_m"]
    assert round(c[4]) == 36 and round(c[5]) == 106 and c[4] < 50 and c[5] < 180
    # the flight rows: 50.02 / 50.52 m ([Q17]: 50.246 / 50.485), 0.36 m RMS (T3 0.40, T4 0.32)
    assert (round(n["flight_T3_mean_error_m"], 2), round(n["flight_T4_mean_error_m"], 2)) == (50.02, 50.52)
    assert (
        round(n["flight_rms_to_paper_m"], 2),
        round(n["flight_T3_rms_to_paper_m"], 2),
        round(n["flight_T4_rms_to_paper_m"], 2),
    ) == (0.36, 0.40, 0.32)


def test_fig10_trend(q17):
    # [Q17] Fig. 10a: CEP grows with the frame angle and with the terrain sigma
    assert q17.numbers["fig10a_increasing_with_angle"]
    assert q17.numbers["fig10a_increasing_with_sigma"]


def test_cli_prints_paper_and_project_side_by_side(tmp_path, capsys):
    out = tmp_path / "q17.json"
    assert (
        main(["reproduce", "qiao2017", "--no-dem", "--samples", "1000", "--sweep-samples", "200", "--json", str(out)])
        == 0
    )
    text = capsys.readouterr().out
    assert "paper   35.57709 N  80.84918 E" in text and "geoloc  35.57709 N  80.84918 E" in text
    assert json.loads(out.read_text())["nominal_lat_deg"] == pytest.approx(35.57709, abs=0.5e-5)


def test_cli_li2023(capsys):
    # The table's saving is our measurement, 1 - bisect / steps evaluations of its own
    # columns; [L23]'s 45.5 % is only quoted as the paper's figure, never our result.
    assert main(["reproduce", "li2023", "--rays", "4", "--tolerances-m", "10"]) == 0
    text = capsys.readouterr().out
    assert "45.5 %" in text and "saving" in text  # the paper's claim, quoted beside ours
    row = next(ln.split() for ln in text.splitlines() if ln.split()[:1] == ["10"])
    steps, bisect, saving = float(row[1]), float(row[2]), float(row[3])
    assert saving == pytest.approx(100 * (1 - bisect / steps), abs=0.1)
    assert saving != pytest.approx(45.5, abs=1.0)


@pytest.fixture(scope="module")
def l23():
    return rp.li2023_report(surface_from_scenario(rp.load_q17_dem_model()), seed=0, n_rays=100)


def test_li2023_counts_match_the_readme(l23):
    # docs/tour_papers.md / docs/montecarlo.md: "bisection takes 7, 9 and 10 reads against 120, 590 and
    # 1180 for descending steps at tolerances of 10, 2 and 1 m" (the means 7.0 / 9.2 / 10.3
    # and 119.5 / 591.6 / 1181.8 at the printed digits), "no bisection answer was hidden".
    for tol, steps, bisect in ((10, 120, 7), (2, 590, 9), (1, 1180, 10)):
        n = l23.numbers[f"tol_{tol:g}"]
        assert abs(n["steps_mean_evals"] - steps) < 5  # printed to 2-3 significant digits
        assert round(n["bisect_mean_evals"]) == bisect
        assert n["hidden"] == 0 and n["n_ok"] == 120
        assert n["saving_pct"] == pytest.approx(100 * (1 - n["bisect_mean_evals"] / n["steps_mean_evals"]), rel=1e-9)


def test_li2023_counts_follow_the_closed_forms():
    """What the counts should be, from the methods' definitions and the exact first hit,
    per ray (the 20 flight-test records on the ETOPO5 crop): the steps read
    (H_max - h)/t + 1 heights ([Q17]: H_n = H_max - n t until H_n is below the terrain;
    one more or less where the terrain under the ray changes within a step); the
    bisection at most ceil(log2((H_max - H_min) / t)) + 1 ([L23]: the bracket halves until
    it is within t of the terrain)."""
    from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
    from geoloc.io.records import load_records
    from geoloc.sensors.camera import Camera
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import intersect_dem
    from geoloc.workflows.replay import records_line_of_sight

    dem = DEM.open(asset_path("dem", "etopo5_flight_area.tif"))
    los = records_line_of_sight(
        load_records(asset_path(*DEFAULT_RECORDS)), Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    )
    ex = intersect_dem(los, dem, "exact")
    assert (ex.status == 0).all()
    h_max, h_min = dem.max_height(), dem.min_height()
    assert (round(h_min), round(h_max)) == (1163, 6683)  # the report's "heights 1163-6683 m"
    for t in (10.0, 2.0, 1.0):
        st = intersect_dem(los, dem, "steps", eps_h=t)
        bi = intersect_dem(los, dem, "bisect", threshold=t)
        expect = np.floor((h_max - ex.h) / t) + 1
        assert np.all(np.abs(st.dem_evaluations - expect) <= 1), (t, st.dem_evaluations - expect)
        assert np.all(bi.dem_evaluations <= np.ceil(np.log2((h_max - h_min) / t)) + 1)
        assert np.all(np.abs(bi.h - ex.h) < 60)  # no hidden crossing: the same hill


def test_cli_rejects_bad_counts(capsys):
    assert main(["reproduce", "qiao2017", "--samples", "0"]) == 2
    assert "--samples = 0" in capsys.readouterr().err
    assert main(["reproduce", "li2023", "--tolerances-m", "1,-2"]) == 2
    assert "--tolerances-m = '1,-2'" in capsys.readouterr().err
