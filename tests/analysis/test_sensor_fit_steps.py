"""The named steps of the per-flight fit (geoloc.analysis.sensor_fit.fit_sensor_groups), each alone."""

from __future__ import annotations

import types

import numpy as np

from geoloc.analysis.sensor_fit import _leave_one_out, _rms, _rnd


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
