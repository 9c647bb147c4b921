"""The named steps of the fits (geoloc.analysis.sensor_fit: fit_sensor_groups's and
fit_sensor_params's), each alone.

Oracles: closed forms (a mean as the "fit", a 2 x 2 covariance), and pymap3d's geodetic2enu for a
record's (east, north) residual.
"""

from __future__ import annotations

import types

import numpy as np
import pymap3d
import pytest

from geoloc.analysis.sensor_fit import _correlation, _fit_problem, _leave_one_out, _loo_errors, _rms, _rms_m, _rnd
from geoloc.io.records import load_records
from geoloc.locate import locate
from geoloc.pipeline import NO_CORRECTIONS
from geoloc.surfaces.height import HeightSurface
from test_sensor_fit import make_records


def test_leave_one_out_fits_without_the_record_within_its_flight():
    # the "fit" is the mean of the training records' values, the "error" a record's value minus it:
    # leaving record k out of n in its flight gives (x_k - mean) * n / (n - 1), a closed form
    x = np.array([1.0, 2.0, 4.0, 10.0, 20.0, 40.0, 70.0])
    groups = np.array(["a", "a", "a", "b", "b", "b", "b"])
    use = np.array([True, True, True, True, True, True, False])  # the last is no training record

    def fit(train):
        return float(np.mean(x[train]))

    def measure(mean, idx):
        e = x[idx] - mean
        return types.SimpleNamespace(distance_m=np.abs(e), east_m=e, north_m=-e)

    d, en = _leave_one_out(fit, measure, groups, use, joint=False)
    expect = np.empty(7)
    for k in range(7):
        train = [j for j in range(7) if groups[j] == groups[k] and use[j] and j != k]
        expect[k] = x[k] - np.mean(x[train])
    np.testing.assert_allclose(en[:, 0], expect)
    np.testing.assert_allclose(en[:, 1], -expect)
    np.testing.assert_allclose(d, np.abs(expect))
    # the closed form for the flight whose records all train
    np.testing.assert_allclose(en[:3, 0], (x[:3] - x[:3].mean()) * 3 / 2)
    # joint: every usable record of every flight trains
    _, en_j = _leave_one_out(fit, measure, groups, use, joint=True)
    np.testing.assert_allclose(en_j[0, 0], x[0] - np.mean(x[1:6]))


def test_report_figures_are_rounded_and_none_where_not_finite():
    assert _rnd(1.234567) == 1.2346 and _rnd(float("nan")) is None and _rnd(np.inf) is None
    assert _rms([3.0, np.nan, -4.0]) == np.sqrt(12.5)
    assert np.isnan(_rms([np.nan]))


def test_fit_problem_refuses_what_cannot_be_fitted_naming_it(tmp_path):
    recs, nominal = make_records(tmp_path, n=5)
    surf = HeightSurface(300.0, "geodetic")

    def problem(names, idx=None, prefix="truth"):
        return _fit_problem(recs, nominal, names, surf, NO_CORRECTIONS, prefix, idx)

    with pytest.raises(ValueError, match="name at least one parameter"):
        problem([])
    # 2 records give 4 equations for 5 parameters
    with pytest.raises(ValueError, match=r"2 record\(s\) give 4 equations for 5 parameters; need at least 3"):
        problem(["mount_x", "mount_y", "mount_z", "fx", "fy"], idx=[0, 1])
    # record 3 without its surveyed latitude: refused when it is used, not when it is left out
    lines = (tmp_path / "rec.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[lines[0].split(",").index("truth_lat_deg")] = ""
    lines[3] = ",".join(cells)
    (tmp_path / "gap.csv").write_text("\n".join(lines) + "\n")
    gap = load_records(tmp_path / "gap.csv", angles=nominal.angle_names)
    with pytest.raises(ValueError, match=r"gap\.csv: every record to fit needs truth_lat_deg and _lon_deg"):
        _fit_problem(gap, nominal, ["mount_x"], surf, NO_CORRECTIONS, "truth", None)
    assert _fit_problem(gap, nominal, ["mount_x"], surf, NO_CORRECTIONS, "truth", [0, 1, 3, 4])[1].tolist() == [
        0,
        1,
        3,
        4,
    ]
    p, idx = problem(["mount_z", "fx"])
    assert idx.tolist() == [0, 1, 2, 3, 4]
    assert p.p0.tolist() == [nominal.params["mount_z"], nominal.params["fx"]]


def test_fit_problem_residuals_are_pymap3ds_east_north_of_the_ground_point_from_the_truth(tmp_path):
    recs, nominal = make_records(tmp_path, n=5)
    p, idx = _fit_problem(recs, nominal, ["mount_z"], HeightSurface(300.0, "geodetic"), NO_CORRECTIONS, "truth", None)
    r = p.errors(nominal, idx)  # the nominal sensor: the true one's targets are tens of metres off
    g = locate(recs.pose(), nominal, recs.column("row"), recs.column("col"), target_h=300.0, height_kind="geodetic")
    tlat, tlon = recs.column("truth_lat_deg"), recs.column("truth_lon_deg")
    e, n, _ = pymap3d.geodetic2enu(g.lat_deg, g.lon_deg, g.h, tlat, tlon, g.h)
    # 1 mm on tens of metres: the local level frame taken at the truth by two codes
    np.testing.assert_allclose(r, np.stack([e, n], -1), atol=1e-3)
    assert np.all(np.hypot(e, n) > 1.0)
    assert _rms_m(r) == pytest.approx(np.sqrt(np.mean(e**2 + n**2)), abs=1e-3)


def test_loo_errors_refit_without_each_record():
    # the "fit" is the mean of the training records' values, the error a record's value minus it:
    # leaving record k out gives x_k - mean(the others)
    x = np.array([1.0, 2.0, 4.0, 10.0])
    stub = types.SimpleNamespace(
        solve=lambda ii: types.SimpleNamespace(x=float(np.mean(x[ii]))),
        trial=lambda p: p,
        errors=lambda s, ii: np.stack([x[ii] - s, np.zeros(len(ii))], -1),
    )
    got = _loo_errors(stub, np.arange(4))
    np.testing.assert_allclose(got, [abs(x[k] - np.delete(x, k).mean()) for k in range(4)])


def test_correlation_of_a_covariance_closed_form():
    sd, corr = _correlation(np.array([[4.0, 1.2], [1.2, 9.0]]))
    np.testing.assert_allclose(sd, [2.0, 3.0])
    np.testing.assert_allclose(corr, [[1.0, 0.2], [0.2, 1.0]])
    sd, corr = _correlation(np.full((2, 2), np.nan))  # not determined
    assert np.isnan(sd).all() and np.isnan(corr).all()
    assert _rms_m(np.array([[3.0, 4.0], [0.0, 0.0]])) == pytest.approx(np.sqrt(12.5))
