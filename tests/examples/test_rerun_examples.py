"""The rerun examples this helper added, run as scripts with their printed figures checked.

(``tests/examples/test_examples.py::test_every_example_is_checked_somewhere`` looks for each example's file
name in the ``test_*examples*.py`` modules: ``82_rerun_flight_test_debugger.py`` is run here;
``72_accuracy_report.py`` is run by ``tests/cli/test_report.py::test_example_72_prints_the_report``.)
"""

from __future__ import annotations

import re

import pytest
from test_examples import (
    run,  # the examples' runner: a script from the repository root, exit 0, output
)


def test_example_82_prints_per_flight_figures(tmp_path):
    out = run("82_rerun_flight_test_debugger.py", tmp_path / "x.rrd", env={"HOME": str(tmp_path)})
    got = re.findall(
        r"flight (T\d): origin ([0-9.]+) N ([0-9.]+) E .* along ([-+0-9.]+) m, across ([-+0-9.]+) m; "
        r"before ([0-9.]+) m, after calibration ([0-9.]+) m",
        out,
    )
    assert [g[0] for g in got] == ["T3", "T4"]
    # origins 200 km apart, the first published points rounded (see test_rerun_log); docs/calibration.md:
    # ~50 m before, 5.0 / 5.1 m after; the error is along track
    assert got[0][1:3] == ("36.338", "78.858") and got[1][1:3] == ("35.574", "80.873")
    for g, want_after in zip(got, (5.0, 5.1)):
        assert float(g[3]) < -45 and abs(float(g[4])) < 2
        assert 49 < float(g[5]) < 52 and float(g[6]) == pytest.approx(want_after, abs=0.1)
    assert (tmp_path / "x.rrd").stat().st_size > 10_000


def test_example_83_prints_the_sensor_fit_on_the_dem(tmp_path):
    out = run("83_rerun_sensor_calibration_on_dem.py", tmp_path / "t.rrd", env={"HOME": str(tmp_path)})
    before, after = map(float, re.search(r"before ([0-9.]+) m, after ([0-9.]+) m", out).groups())
    # docs/sensors.md: 22.87 m mean error before on this DEM; the fit lowers the mean (in-sample)
    assert before == pytest.approx(22.87, abs=0.005) and after < before
    fit = {k: (float(v), float(sd)) for k, v, sd in re.findall(r"(mount_[xyz]) ([-+0-9.]+) \+- ([0-9.]+) deg", out)}
    # the records were made with the sensor file's own mount (assets/sensors/eo_turret.toml: 0.10, -0.05,
    # 0.20 deg) and angle noise: the fit must agree with it within 3 of its standard deviations
    for k, want in (("mount_x", 0.10), ("mount_y", -0.05), ("mount_z", 0.20)):
        v, sd = fit[k]
        assert abs(v - want) < 3 * sd, (k, v, sd)
    assert (tmp_path / "t.rrd").stat().st_size > 10_000
