"""Per-flight sensor fits, outlier flags and resection for sensor files (geoloc.analysis.sensor_fit).

Synthetic flights with a known truth, as in tests/analysis/test_sensor_fit.py: targets are
placed with a *true* sensor that the nominal file does not know, so a fit that
works recovers the planted values exactly (noise-free) and a fit that mixes the
flights, keeps an outlier or ignores a height cannot.
"""

import csv
import math

import numpy as np
import pytest

from geoloc.analysis.sensor_fit import fit_sensor_groups, resect_sensor
from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.frames.chain import Pose
from geoloc.io.records import load_records
from geoloc.locate import locate
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.height import HeightSurface, PerRecordHeightSurface

MOUNTS = {"A": (0.4, -0.25, 0.6), "B": (-0.3, 0.2, -0.5)}  # deg, per flight
NAMES = ["mount_x", "mount_y", "mount_z"]


def _write(path, rows, header):
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def make_flights(tmp_path, n=12, outlier_m=60.0, heights=None, true_params=None, rng_seed=3):
    """Two flights A and B with their own true mounts; record B-1's survey is ``outlier_m`` off (north)."""
    nominal = load_sensor(asset_path("sensors", "eo_turret.toml"))
    rng = np.random.default_rng(rng_seed)
    rows = []
    for table, mount in MOUNTS.items():
        params = true_params or {k: math.radians(v) for k, v in zip(NAMES, mount)}
        true = nominal.with_params(**params)
        az, el = rng.uniform(0, 360, n), rng.uniform(-80, -30, n)
        pose = Pose.from_deg(
            36.6 + rng.uniform(-0.05, 0.05, n),
            -84.25 + rng.uniform(-0.05, 0.05, n),
            rng.uniform(1500, 3500, n),
            rng.uniform(-180, 180, n),
            rng.uniform(-3, 3, n),
            rng.uniform(-5, 5, n),
            angles_deg={"azimuth": az, "elevation": el},
        )
        row, col = rng.uniform(50, 1030, n), rng.uniform(50, 1870, n)
        h = np.full(n, 300.0) if heights is None else heights(rng, n)
        g = locate(pose, true, row, col, target_h=h, height_kind="inflated" if heights else "geodetic")
        tlat = g.lat_deg.copy()
        if table == "B":
            tlat[0] += outlier_m / 111_000.0
        for k in range(n):
            rows.append(
                [table, k + 1]
                + [
                    repr(float(v))
                    for v in (
                        row[k],
                        col[k],
                        np.rad2deg(pose.lat[k]),
                        np.rad2deg(pose.lon[k]),
                        pose.h[k],
                        np.rad2deg(pose.heading[k]),
                        np.rad2deg(pose.pitch[k]),
                        np.rad2deg(pose.roll[k]),
                        az[k],
                        el[k],
                        tlat[k],
                        g.lon_deg[k],
                        h[k],
                        g.lat_deg[k],
                        g.lon_deg[k],
                    )
                ]
            )
    f = tmp_path / "flights.csv"
    _write(
        f,
        rows,
        [
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
            "azimuth_deg",
            "elevation_deg",
            "truth_lat_deg",
            "truth_lon_deg",
            "truth_h_m",
            "paper_lat_deg",
            "paper_lon_deg",
        ],
    )
    return f, load_records(f, angles=nominal.angle_names), nominal


def _values_deg(entry):
    return [entry["parameters"][k]["value"] for k in NAMES]


def test_one_fit_per_flight_recovers_each_flights_mount(tmp_path):
    _, recs, nominal = make_flights(tmp_path)
    rep, sensors = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"), exclude_outliers=True)
    # flight A is clean: its own mount to the solver's tolerance (1e-7 deg is 5 mm at 3 km)
    np.testing.assert_allclose(_values_deg(rep["groups"]["A"]), MOUNTS["A"], atol=1e-7)
    # flight B's planted 60 m survey error is flagged before the fit and left out of it,
    # so B's mount is exact too; the flag sits on B-1 and nowhere else
    b = rep["groups"]["B"]
    assert [r["label"] for r in b["records"] if r["outlier"]] == [b["records"][0]["label"]]
    assert not any(r["outlier"] for r in rep["groups"]["A"]["records"])
    assert b["n_used_in_fit"] == 11
    np.testing.assert_allclose(_values_deg(b), MOUNTS["B"], atol=1e-7)
    # after: B-1 keeps its 60 m (measured against the fit it took no part in), the rest ~0
    assert b["records"][0]["after"]["distance_m"] == pytest.approx(60.0, abs=0.3)
    assert max(r["after"]["distance_m"] for r in b["records"][1:]) < 1e-3
    assert set(sensors) == {"A", "B"}


def test_keeping_the_outlier_biases_that_flight_only(tmp_path):
    _, recs, nominal = make_flights(tmp_path)
    rep, _ = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"))
    np.testing.assert_allclose(_values_deg(rep["groups"]["A"]), MOUNTS["A"], atol=1e-7)
    # with the 60 m record in its fit, flight B's mount leans towards it (by > 1e-3 deg)
    assert np.max(np.abs(np.subtract(_values_deg(rep["groups"]["B"]), MOUNTS["B"]))) > 1e-3


def test_joint_fit_cannot_serve_two_different_mounts(tmp_path):
    _, recs, nominal = make_flights(tmp_path, outlier_m=0.0)
    rep, sensors = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"), joint=True)
    assert set(sensors) == {"joint"}
    v = [rep["joint_fit"]["parameters"][k]["value"] for k in NAMES]
    # one rotation for two flights 0.6-1.1 deg apart: between them, and leaving metres of error in both
    for k in range(3):
        assert min(MOUNTS["A"][k], MOUNTS["B"][k]) - 1e-6 < v[k] < max(MOUNTS["A"][k], MOUNTS["B"][k]) + 1e-6
    assert rep["groups"]["A"]["rms_after_m"] > 5.0 and rep["groups"]["B"]["rms_after_m"] > 5.0


def test_leave_one_out_per_flight(tmp_path):
    _, recs, nominal = make_flights(tmp_path, n=8)
    rep, _ = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"), loo=True)
    b = rep["groups"]["B"]["records"]
    # B-1 left out: the seven clean records give B's true mount, so its LOO error is the planted 60 m
    assert b[0]["loo_distance_m"] == pytest.approx(60.0, abs=0.3)
    # in-sample it is smaller (the fit leans towards it): a LOO that used it would not see 60 m
    assert b[0]["after"]["distance_m"] < 58.0  # 56.6 m here, 3.4 m from the LOO figure
    # the clean flight's LOO errors are zero to the solver's tolerance
    assert max(r["loo_distance_m"] for r in rep["groups"]["A"]["records"]) < 1e-3


def test_too_few_records_for_the_parameters_names_them(tmp_path):
    _, recs, nominal = make_flights(tmp_path, n=1)
    with pytest.raises(ValueError, match=r"group 'A': 1 usable record\(s\) cannot determine 3 parameters"):
        fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"))


def test_resection_recovers_intrinsics_and_heights(tmp_path):
    nominal = load_sensor(asset_path("sensors", "eo_turret.toml"))
    p = nominal.params
    true = {"fx": p["fx"] * 1.03, "cx": p["cx"] + 12.0, "cy": p["cy"] - 8.0}

    def heights(rng, n):
        return rng.uniform(150.0, 900.0, n)

    _, recs, _ = make_flights(tmp_path, n=10, outlier_m=0.0, heights=heights, true_params=true)
    res = resect_sensor(recs, nominal, ["fx", "cx", "cy"])
    assert res.success
    # noise-free: the planted intrinsics (1e-6 px) and every target's height (1e-5 m)
    np.testing.assert_allclose(res.fit.values, [true["fx"], true["cx"], true["cy"]], atol=1e-6)
    np.testing.assert_allclose(res.heights_m, recs.column("truth_h_m"), atol=1e-5)
    assert res.rms_m < 1e-6


def test_calibrate_cli_groups_and_resects_a_sensor_file(tmp_path, capsys):
    f, _, _ = make_flights(tmp_path)
    out = tmp_path / "rep.json"
    sensor = str(asset_path("sensors", "eo_turret.toml"))
    assert (
        main(
            [
                "calibrate",
                str(f),
                "--sensor",
                sensor,
                "--fit",
                ",".join(NAMES),
                "--target-h-m",
                "300",
                "--height-kind",
                "geodetic",
                "--exclude-outliers",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "outliers before the fit: ['B-1'] (left out)" in text
    import json

    rep = json.loads(out.read_text())
    np.testing.assert_allclose(_values_deg(rep["groups"]["B"]), MOUNTS["B"], atol=1e-7)
    # --resect on a sensor file: the same names fitted to the published positions, heights unknown
    assert (
        main(
            [
                "calibrate",
                str(f),
                "--sensor",
                sensor,
                "--fit",
                ",".join(NAMES),
                "--target-h-m",
                "300",
                "--group-by",
                "none",
                "--resect",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "resection of mount_x, mount_y, mount_z to the published positions" in text
    assert len(json.loads(out.read_text())["resection"]["heights_m"]) == 24


def test_report_units_boundaries_and_an_exact_fit(tmp_path):
    # (mutation run 2) the report converts start, value and sd to degrees; a fit with as many
    # residuals as parameters has no degrees of freedom: NaN uncertainties, not a ZeroDivisionError
    from geoloc.analysis.sensor_fit import fit_sensor_params

    _, recs, nominal = make_flights(tmp_path, n=3, outlier_m=0.0)
    one = recs.subset([0])
    fit = fit_sensor_params(one, nominal, ["mount_y", "mount_z"], HeightSurface(300.0, "geodetic"))
    assert fit.dof == 0 and np.all(np.isnan(fit.sd))
    p = fit.report()["parameters"]["mount_y"]
    assert p["start"] == pytest.approx(math.degrees(nominal.params["mount_y"]), abs=1e-12)  # -0.05 deg
    assert p["unit"] == "deg"
    # resection: p + 1 records are enough, p are not (2n equations for n heights + p parameters)
    with pytest.raises(ValueError, match=r"resection of 3 parameters needs at least 4 records, got 3"):
        resect_sensor(recs.subset([0, 1, 2]), nominal, ["fx", "cx", "cy"])
    res = resect_sensor(recs.subset([0, 1, 2, 3]), nominal, ["fx", "cx", "cy"])
    assert res.report()["heights_m"] == [round(float(h), 2) for h in res.heights_m]


def test_per_record_heights_rule_and_rounding(tmp_path):
    # (mutation run 2, recheck) a callable surface gives each record its own height (the CLI's
    # --height-column); the report names the 3.5-sigma rule and rounds distances to 0.1 mm
    from geoloc.analysis.sensor_fit import fit_sensor_params

    _, recs, nominal = make_flights(tmp_path, n=6, outlier_m=0.0)
    h = recs.column("truth_h_m")
    fit = fit_sensor_params(
        recs, nominal, NAMES, PerRecordHeightSurface(h, "geodetic"), idx=np.arange(6)
    )  # flight A: its true mount
    np.testing.assert_allclose(np.degrees(fit.values), MOUNTS["A"], atol=1e-7)
    rep, _ = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"))
    assert "> 3.5 robust sigma" in rep["outlier_rule"]
    d = rep["groups"]["A"]["rms_before_m"]
    assert d == round(d, 4) and d != round(d, 3)  # 4 decimals (seeded: this value's fourth decimal is not 0)


def test_leave_one_out_vectors_and_mean_per_flight(tmp_path):
    # the record's leave-one-out (east, north) is its vector against the fit of the others:
    # B-1's survey is planted 60 m north of its true point, so computed - truth is ~60 m
    # south (to the solver's tolerance and the 111 km/deg planting: 0.3 m); the mean is the
    # mean of the per-record distances
    _, recs, nominal = make_flights(tmp_path, n=8)
    rep, _ = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"), loo=True)
    b = rep["groups"]["B"]
    loo = b["records"][0]["loo"]
    assert loo["north_m"] == pytest.approx(-60.0, abs=0.3) and abs(loo["east_m"]) < 0.3
    assert loo["distance_m"] == b["records"][0]["loo_distance_m"]
    assert b["mean_error_loo_m"] == pytest.approx(np.mean([r["loo_distance_m"] for r in b["records"]]), abs=1e-4)
    rep, _ = fit_sensor_groups(recs, nominal, NAMES, HeightSurface(300.0, "geodetic"))
    assert rep["groups"]["B"]["mean_error_loo_m"] is None and "loo" not in rep["groups"]["B"]["records"][0]


def test_tied_focal_length_and_degenerate_pairs(tmp_path):
    # "f" fits fx and fy as one focal length (a camera file's): planted on both, it is
    # recovered (noise-free, 1e-6 px) and the fitted sensor keeps fx == fy; a sensor whose
    # fx and fy differ has no "f" (the error lists what it has)
    from geoloc.analysis.sensor_fit import fit_params, fit_sensor_params

    nominal = load_sensor(asset_path("sensors", "eo_turret.toml"))
    nominal = nominal.with_params(fy=nominal.params["fx"])
    f_true = nominal.params["fx"] * 1.02
    _, recs, _ = make_flights(tmp_path, n=10, outlier_m=0.0, true_params={"fx": f_true, "fy": f_true})
    fit = fit_sensor_params(recs, nominal, ["f"], HeightSurface(300.0, "geodetic"))
    assert fit.values[0] == pytest.approx(f_true, abs=1e-6)
    assert fit.sensor.params["fx"] == fit.sensor.params["fy"] == fit.values[0]
    assert fit.report()["parameters"]["f"]["unit"] == "px"
    assert "f" not in fit_params(nominal.with_params(fy=1.0))
    with pytest.raises(ValueError, match=r"cannot fit \['f'\]"):
        fit_sensor_params(recs, nominal.with_params(fy=1.0), ["f"], HeightSurface(300.0, "geodetic"))
    # a parameter fitted twice over (fx and the f that contains it) cannot be separated: the
    # report lists the pair as degenerate (|correlation| > 0.99 or not determined)
    fit = fit_sensor_params(recs, nominal, ["fx", "f"], HeightSurface(300.0, "geodetic"))
    assert fit.report()["degenerate_pairs"] == [["fx", "f"]]
    # and a well-posed fit has none
    fit = fit_sensor_params(recs, nominal, ["mount_x", "f"], HeightSurface(300.0, "geodetic"))
    assert fit.report()["degenerate_pairs"] == []
