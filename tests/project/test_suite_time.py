"""tools/suite_time.py: the suite's per-phase time log (tests/conftest.py, GEOLOC_TEST_TIMELOG) and its summary."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("suite_time_under_test", ROOT / "tools" / "suite_time.py")
st = sys.modules["suite_time_under_test"] = importlib.util.module_from_spec(_spec)  # dataclasses look it up
_spec.loader.exec_module(st)

# end time s, load, worker, phase, duration s, outcome, test id: two workers, one group
LOG = """\
#a comment line is skipped
2.0\t1.5\tgw0\tsetup\t1.0\tpassed\ttests/viz/test_a.py::test_x@chromium
12.0\t1.5\tgw0\tcall\t10.0\tpassed\ttests/viz/test_a.py::test_x@chromium
12.5\t1.5\tgw0\tteardown\t0.5\tpassed\ttests/viz/test_a.py::test_x@chromium
5.0\t3.0\tgw1\tcall\t4.0\tpassed\ttests/io/test_b.py::test_y[a@b]
20.0\t2.0\tgw0\tcall\t7.0\tfailed\ttests/io/test_b.py::test_z
"""


def test_summary_sums_and_spans_per_worker_and_group(tmp_path):
    (tmp_path / "log").write_text(LOG)
    phases = st.read_log(tmp_path / "log")
    assert [p.group for p in phases] == ["chromium"] * 3 + ["other"] * 2  # the "@" in a parameter is not a group
    lines = st.summarise(phases, top=2)
    # by hand from LOG: gw0 1 + 10 + 0.5 + 7 = 18.5 s of phases, from 2 - 1 = 1 s to 20 s
    assert lines[0] == "5 phases, 1 not passed; last at 20 s; load min 1.5, median 1.5, max 3.0"
    assert "worker gw0: 2 tests, phases 18 s, from 1 to 20 s" in lines  # 18.5 printed to 0 decimals
    assert "worker gw1: 1 tests, phases 4 s, from 1 to 5 s" in lines
    assert "group chromium: 1 tests, phases 12 s, from 1 to 12 s, on gw0" in lines  # 11.5 s
    assert "group other: 2 tests, phases 11 s, from 1 to 20 s, on gw0, gw1" in lines
    # gw0's first test outside the group started at 20 - 7 = 13 s, gw1's at 5 - 4 = 1 s
    assert "first test outside a group: gw0 at 13 s, gw1 at 1 s" in lines
    assert lines[-2].split()[:2] == ["10.0", "s"] and lines[-1].split()[:2] == ["7.0", "s"]


def test_a_malformed_line_is_named(tmp_path):
    (tmp_path / "log").write_text(LOG + "3.0\tgw0\tcall\n")
    with pytest.raises(ValueError, match="line 7 is not a phase"):
        st.read_log(tmp_path / "log")


@pytest.mark.xdist_group("timelog_probe")
def test_probe_in_a_group():
    """Run by the next test in a pytest subprocess: a grouped test of the time log."""


def test_probe_outside_a_group():
    """Run by the next test in a pytest subprocess: the log's variable is gone from the tests'
    environment, so a pytest a test starts does not write into the run's log."""
    assert "GEOLOC_TEST_TIMELOG" not in os.environ


def test_conftest_logs_each_phase_from_the_workers(tmp_path):
    # the suite's own conftest under pytest-xdist, two workers, on the two probes above
    log = tmp_path / "time.log"
    env = dict(os.environ, GEOLOC_TEST_TIMELOG=str(log))
    here = Path(__file__).relative_to(ROOT).as_posix()
    ids = [f"{here}::test_probe_in_a_group", f"{here}::test_probe_outside_a_group"]
    args = ["-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadgroup", *ids]
    r = subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    phases = st.read_log(log)
    got = sorted((p.nodeid, p.when) for p in phases)
    want = sorted(
        (i + ("@timelog_probe" if "in_a_group" in i else ""), w) for i in ids for w in ("setup", "call", "teardown")
    )
    assert got == want
    assert {p.worker for p in phases} <= {"gw0", "gw1"} and all(p.duration_s >= 0 for p in phases)
    assert {p.group for p in phases} == {"timelog_probe", "other"}
