"""The benchmark guard (benchmarks/guard.py) catches a slowed kernel and passes the code against itself.

Speed is never asserted here: these tests check the guard's logic. A slowdown is injected large
(2x: the kernel's work done twice), far beyond the 10 % the guard fails at, so a noisy 2-core
machine cannot hide it (the per-pair ratio of a 2x loss is 0.5; the load moves an A-vs-A
median by a few per cent, as the guard's own quartiles show). The A-vs-A checks are the guard's
real threshold with its confirmation rounds (a dip must repeat, pooled, to fail).

The command runs ``--fast`` on two kernels (the compiled refraction correction, the numpy
locate path): this tree against a copy of itself (A vs A, exit 0), and a copy with
``Refraction.correct`` slowed against this tree (exit 1). Wall time on the 2-core machine: about
35 s the first time (numba compiles the copies' refraction kernel, kept in the guard's cache for
the next run), about 12 s after.
"""

from __future__ import annotations

import weakref

import csv
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
GUARD = ROOT / "benchmarks" / "guard.py"
N = r"-?\d+(?:\.\d+)?"


def _guard():
    spec = importlib.util.spec_from_file_location("bench_guard", GUARD)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _work():
    # about 20-40 ms of CPU on the 2-core machine: a pure-Python loop, no allocation to vary. Not
    # shorter: the process's CPU time counts its other threads too (the test worker's own), and
    # against 2-4 ms their bursts put a kernel at 0.85 of itself in a CI run at load 6
    s = 0
    for i in range(400_000):
        s += i * i
    return s


def _work_twice():
    _work()
    return _work()


def test_judge_fails_a_doubled_kernel():
    g = _guard()
    cpu, wall, res, ok = g.judge(_work, _work_twice, pairs=9, threshold=0.10, confirm=1)
    assert not ok
    assert g.ratios(cpu)[0] < 0.8, g.ratios(cpu)  # 2x: about 0.5
    assert res == [_work(), _work()]


def test_judge_passes_a_kernel_against_itself():
    g = _guard()
    cpu, wall, res, ok = g.judge(_work, _work, pairs=9, threshold=0.10, confirm=2)
    assert ok, g.ratios(cpu)
    assert cpu.shape[1] == 2 and (cpu > 0).all()


def test_a_stretch_of_load_on_one_side_passes_a_uniform_loss_fails():
    g = _guard()
    rng = np.random.default_rng(0)
    old = 0.030 * (1 + 0.02 * rng.random(21))
    # A vs A at load 3-10 (seen): a third of the new side's calls 17 % slower, one stretch
    new = 0.030 * (1 + 0.02 * rng.random(21))
    new[5:12] *= 1.17
    cpu = np.stack([old, new], -1)
    assert g.passes(cpu, 0.10)
    # the median alone would have failed it had half the calls been hit; the fastest quarters pass it
    new2 = new.copy()
    new2[:11] *= 1.17
    assert g.ratios(np.stack([old, new2], -1))[0] < 0.9 and g.passes(np.stack([old, new2], -1), 0.10)
    # a real loss: every call 12 % slower, and 2x
    for f in (1.12, 2.0):
        assert not g.passes(np.stack([old, old * f * (1 + 0.02 * rng.random(21))], -1), 0.10)
    assert g.passes(np.stack([old, old * 1.05], -1), 0.10)


def test_measure_alternates_the_order():
    g = _guard()
    calls = []
    g.measure(lambda: calls.append("old"), lambda: calls.append("new"), pairs=4, warm=0)
    # the timed ABBA calls, then one untimed call of each for the outputs
    assert calls == ["old", "new", "new", "old", "old", "new", "new", "old", "old", "new"]


def test_measure_drops_each_timed_result_before_the_next_call():
    """A result kept alive across the other side's call made identical code read 0.85 (its memory
    held, the next call paid fresh pages): no timed call may start while an earlier one's result lives."""
    g = _guard()
    refs, alive = [], []

    class Result:
        pass

    def call():
        alive.append(sum(r() is not None for r in refs))
        out = Result()
        refs.append(weakref.ref(out))
        return out

    g.measure(call, call, pairs=6, warm=1)
    assert alive[: 2 + 12] == [0] * 14  # the warm pair and the 12 timed calls


def test_default_against(monkeypatch):
    g = _guard()
    monkeypatch.setattr(g, "_git", lambda *a: " M geoloc/locate.py")
    assert g.default_against()[0] == "HEAD"
    monkeypatch.setattr(g, "_git", lambda *a: "")
    assert g.default_against()[0] == "HEAD~1"


def _run(args, tmp_path, timeout=600):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), MPLBACKEND="Agg")
    t = time.perf_counter()
    r = subprocess.run(
        [sys.executable, str(GUARD), *map(str, args)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return r, time.perf_counter() - t


#: The kernels the command runs here: one compiled (refraction), one numpy path (locate_numpy).
FAST = ["--fast", "--only", "refraction,locate_numpy"]


def test_guard_passes_this_tree_against_itself(tmp_path):
    hist = tmp_path / "history.csv"
    # --confirm 2: a load spike must dip the pooled median of 27 pairs below 0.9 to fail A vs A
    r, _ = _run([*FAST, "--against", ROOT, "--confirm", "2", "--history", hist], tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
    lines = r.stdout.strip().splitlines()
    assert re.match(rf"^ratio: {N}  \(worst of 2 kernels: \w+; pass\)$", lines[-1]), lines[-1]
    for k in ("refraction", "locate_numpy"):
        line = next(x for x in lines if x.startswith(k))
        # figures of both sides, CPU beside wall, the load, identical outputs, the ratio last
        assert re.search(rf"old +{N}(?:e[+-]\d+)? /CPU s .* load {N}-{N} \| outputs identical \|", line), line
        assert re.search(rf"ratio CPU {N} \({N}-{N}\) wall {N} \({N}-{N}\) ok$", line), line
    with hist.open() as f:
        rows = list(csv.DictReader(f))
    assert sorted((r_["kernel"], r_["clock"]) for r_ in rows) == [
        ("locate_numpy", "cpu"),
        ("locate_numpy", "wall"),
        ("refraction", "cpu"),
        ("refraction", "wall"),
    ]
    assert all(r_["mode"] == "fast" and r_["verdict"] == "ok" and float(r_["load"]) >= 0 for r_ in rows)


def test_guard_fails_on_a_slowed_kernel(tmp_path):
    # a copy of this tree whose Refraction.correct (the wrapper of the compiled kernel) does its work twice
    tree = tmp_path / "slowed"
    shutil.copytree(ROOT / "geoloc", tree / "geoloc", ignore=shutil.ignore_patterns("__pycache__"))
    with (tree / "geoloc" / "corrections" / "refraction.py").open("a") as f:
        f.write(
            "\n\n_guard_correct = Refraction.correct\n\n\n"
            "def _twice(self, *a, **k):\n    _guard_correct(self, *a, **k)\n    return _guard_correct(self, *a, **k)\n\n\n"
            "Refraction.correct = _twice\n"
        )
    r, _ = _run([*FAST, "--against", ROOT, "--tree", tree, "--no-history"], tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr[-3000:]
    lines = r.stdout.strip().splitlines()
    line = next(x for x in lines if x.startswith("refraction"))
    ratio = float(re.search(rf"ratio CPU ({N})", line).group(1))
    assert ratio < 0.8 and line.endswith("FAIL"), line  # 2x: about 0.5
    assert "outputs identical" in line  # the same numbers, twice the work
    assert next(x for x in lines if x.startswith("locate_numpy")).endswith(" ok")
    assert re.match(
        rf"^ratio: {N}  \(worst of 2 kernels: refraction; FAIL: refraction lost more than 10%\)$", lines[-1]
    ), lines[-1]


def test_plot_draws_the_history(tmp_path):
    g = _guard()
    hist = tmp_path / "h.csv"
    rows = [
        {
            "date": f"2026-12-0{i}T00:00:00Z",
            "commit": "c",
            "against": "a",
            "kernel": k,
            "figure": str(f * i),
            "unit": "rays/s",
            "clock": c,
            "ratio": str(1.0 - 0.05 * i),
            "q1": "0.9",
            "q3": "1.1",
            "load": "1.0",
            "pairs": 21,
            "threads": 1,
            "mode": "full",
            "verdict": "ok",
        }
        for i in (1, 2, 3)
        for k, f in (("locate", 4e6), ("dem_walk", 1e6))
        for c in ("cpu", "wall")
    ]
    g.append_history(hist, rows)
    out = g.plot(hist, tmp_path / "h.png")
    assert out.stat().st_size > 1000
    svg = g._svg({"locate": [(0, 4e6, 1.0), (1, 8e6, 0.9)]}, ["d1", "d2"])
    assert svg.startswith("<svg") and svg.count("<polyline") == 1 and svg.rstrip().endswith("</svg>")


def test_a_copy_whose_assets_link_dangles_is_pointed_back(tmp_path):
    # the guard's cache outlives checkouts (CI's clone, a removed worktree): a copy made from a
    # checkout since deleted had assets -> a missing folder, and every kernel of the old side was
    # skipped for want of the geoid grid
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import _revision
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    (tmp_path / "assets").symlink_to(tmp_path / "gone" / "assets")
    assert not (tmp_path / "assets").exists()
    _revision._link_assets(tmp_path)
    assert (tmp_path / "assets" / "geoid" / "egm96_flight_area.tif").is_file()
    assert os.readlink(tmp_path / "assets") == str(ROOT / "assets")
