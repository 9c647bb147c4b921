"""Every benchmark in benchmarks/ runs, at a tiny size, and prints its figures and its peer's ratio.

benchmarks/bench_viz_flight.py raised a TypeError for weeks because nothing ran it. Here each
``bench_*.py`` runs as its own command (a subprocess, from a temporary folder, this tree on
PYTHONPATH) at the smallest arguments that still go through every part it measures; the test
checks the return code and that the lines carrying the figures and the ratio to the peer are
printed, with a number where the figure goes (the values at these sizes mean nothing: the
benchmarks' own runs measure). A ``bench_*.py`` that is not in ``CASES`` fails
``test_every_benchmark_is_listed``.

Wall time of this file, one process, 2-core machine at load 1.2-1.7: 254 s (the
heaviest then: bench_browser's two page loads in Chromium, bench_walk_ab's cold compile of REV's
walk, bench_viz_churn's 20-client warm-up; the last two are gone from the tiny runs since:
``--same-build`` 21.1 -> 2.1 s of CPU, a warm-up of N clients 16.6 -> 7.7 s, docs/testing.md).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "benchmarks"

#: A printed number: 12, 1,234, 0.110, 6.02e+04, -0.5.
N = r"-?\d[\d,]*(?:\.\d+)?(?:e[+-]?\d+)?"

#: file -> (arguments, patterns each must match a line of stdout, timeout [s]). The timeouts
#: stop a hang only: 5-10x the time each took on the loaded 2-core machine.
CASES = {
    "bench_browser.py": (
        # --window 1: each of the four census measures sleeps its window (4 s less than 2)
        ["--repeat", "1", "--steps", "1", "--groups", "--window", "1"],
        [
            rf"^default view to a settled canvas: median {N} s wall over 1 loads .*; ratio {N}$",
            rf"^timeline step to the canvas: median {N} s wall over 1 steps .*; ratio {N}$",
            rf"^  nothing hidden +{N} frames/s, +{N} draw calls and +{N} indices a frame, GPU process {N} s CPU a frame$",
            rf"^  and the rest of /enu +{N} frames/s, +{N} draw calls",
        ],
        600,
    ),
    "bench_viewer.py": (
        # --play-s 1: the playback sleeps its seconds (ten frames asked still counted)
        ["--repeat", "1", "--steps", "1", "--play-s", "1"],
        [
            rf"^first useful view .*: median {N} s wall over 1 loads \(goal 5 s\)",
            rf"^step to the next frame, to the first canvas change: median {N} ms wall over 1 steps",
            rf"^peer: viser's bare scene update .*: median {N} ms wall$",
            rf"^playback, 10 frames per second asked: {N} frames/s",
            rf"^ratio: step / bare update {N} \(Chromium CPU {N}\); playback reached / asked {N}$",
        ],
        900,
    ),
    "bench_frame.py": (
        ["--window", "1", "--rounds", "1", "--no-canvas"],
        [
            rf"^  everything shown +frame interval +{N} ms, main thread +{N} ms, +{N} frames/s; CPU per frame: GPU "
            rf"process +{N} ms",
            r"^  every node hidden +frame interval",
            rf"^ratio: a default frame / an empty canvas's frame {N}$",
        ],
        600,
    ),
    "bench_campaign.py": (
        # one worker: the same cluster path as the default two, 4 s less
        ["--records", "2000", "--partition", "1000", "--workers", "1"],
        [
            rf"^one process, 1 thread .* wall +{N} s +CPU +{N} s .* {N} records/s",
            rf"^cluster 1 proc x 1 thr .* wall +{N} s +CPU +{N} s .* {N} records/s",
            rf"^ratio: {N} \(speed-up",
        ],
        300,
    ),
    "bench_startup.py": (
        ["--repeat", "1"],
        [
            rf"^geoloc --help +wall {N} s  CPU {N} s$",
            rf"^one-pixel locate +wall {N} s  CPU {N} s$",
            rf"^ratio geoloc --help / peer {N}x; one-pixel locate / peer {N}x$",
        ],
        120,
    ),
    "bench_first_run.py": (
        ["--only", "locate"],  # one cold numba cache, one warm: 5 s
        [rf"^locate(?: +{N}){{7}}$"],
        300,
    ),
    "bench_images.py": (
        ["--repeat", "1", "--hour-s", "10", "--size", "320x180"],
        [
            rf"^hour: open \+ PTS index, one hour .*median wall {N} s",
            rf"^switch, random record .*median wall {N} ms, CPU {N} ms",
            rf"^  decode alone, .*ratio peer / ours {N}x \(wall\)$",
            rf"^ortho: 320 x 180 frame at {N} m cells .*median wall {N} s",
            rf"^ortho: peer GDAL warp .*ratio peer / ours {N}x \(wall\)$",
        ],
        300,
    ),
    "bench_klv.py": (
        ["--packets", "200", "--repeat", "1", "--klvdata-packets", "50", "--klvdata-repeat", "1"],
        [
            rf"^ours \(iter_packets, dict per packet\): .* {N} packets/s$",
            rf"^klvdata \(StreamParser \+ MetadataList\): .* {N} packets/s",
            rf"^ratio: {N}$",
        ],
        120,
    ),
    "bench_klv_replay.py": (
        ["--packets", "200", "--repeat", "1", "--klvdata-packets", "50", "--klvdata-repeat", "1"],
        [
            rf"^decode \+ replay \(frame-centre height\) +wall +{N} ms .* {N} packets/s",
            rf"^decode \+ replay \(DEM, exact\) +wall +{N} ms .* {N} packets/s",
            rf"^klvdata decode only .* {N} packets/s",
            rf"^ratio: {N}$",
        ],
        120,
    ),
    "bench_live.py": (
        ["--hours", "0.002", "--repeat", "1"],  # 216 packets; over loopback at 100x real time
        [
            rf"^ours \(LiveReceiver.push per datagram\): .* {N} packets/s",
            rf"^peer \(read_ts_klv: PyAV/FFmpeg demux\): .* {N} packets/s$",
            rf"^ratio: {N}$",
            rf"^over loopback, .*: {N} of 216 packets in {N} s",
        ],
        120,
    ),
    "bench_locate.py": (
        ["--rays", "1000", "--repeat", "1"],
        [
            rf"^\[q17 roll-pitch pinhole\] geoloc locate \(full chain\): .* {N} M rays/s$",
            rf"^\[turret: .*\] geoloc locate \(full chain\): .* {N} M rays/s$",
            rf"^ratio: {N}  \(wall {N}\)$",
            rf"^ratio turret: {N}  \(wall {N}\)$",
        ],
        120,
    ),
    "bench_montecarlo.py": (
        ["--quick"],
        [rf"^ellipsoid N = 200000: median {N} s", rf"^DEM N = 5000: median {N} s", rf"^ratio: {N}$"],
        300,
    ),
    "bench_montecarlo_memory.py": (
        ["--quick"],  # 1e4, 1e5, 1e6: the ratio needs two N >= 1e5
        [rf"^ +1000000 +streamed(?: +{N}){{6}}$", rf"ratio: {N}  \(flat = 1"],
        300,
    ),
    "bench_refraction.py": (
        ["--rays", "2000", "--repeat", "1"],
        [
            rf"^pipeline, --refraction none: .* {N} M rays/s cpu$",
            rf"^pipeline, --refraction standard: .* {N} M rays/s cpu$",
            rf"^ratio: {N}  \(wall {N}\)$",
        ],
        120,
    ),
    "bench_rpc.py": (
        ["--points", "200"],
        [
            rf"^rigorous ground_to_pixel \(Newton on line time\): median {N} ms$",
            rf"^RPC ground_to_pixel: +median {N} ms$",
            rf"^ratio: {N}$",
        ],
        120,
    ),
    "bench_sentinel2.py": (
        ["--step", "600", "--repeat", "1"],
        [
            rf"^Sen2VM's step 600: 5 x 5 points: median {N} s wall, CPU {N} s$",
            rf"^step 600: 5 x 5 = 25 points batched: median {N} s wall, CPU {N} s$",
            rf"^step 600: the same points one by one: median {N} s wall",
            rf"^ratio: {N} \(one by one / batched\)$",
        ],
        120,
    ),
    "bench_terrain.py": (
        # (c) too, on a 60 x 60 resampled DEM
        ["--rays", "200", "--repeat", "1", "--size", "60", "--big-rays", "500", "--big-repeat", "1"],
        [
            rf"^exact \(bilinear\): {N} cells or blocks visited per ray$",
            rf"^trimesh ray cast +{N} rays/s +{N} rays/s$",
            rf"^exact, triangles +{N} rays/s +{N} rays/s$",
            rf"^ratio: {N}$",
            rf"^big ratio \(CPU time, exact triangles over trimesh; goal >= 1.5\): {N}$",
        ],
        300,
    ),
    "bench_uncertainty.py": (
        ["--points", "200", "--repeat", "1", "--dem"],
        [rf"^\[ellipsoid\] propagate: .* {N} points/s wall", rf"^ratio: {N}$", rf"^ratio dem: {N}$"],
        300,
    ),
    "bench_panel.py": (
        ["--steps", "2"],
        [
            rf"^panel closed: timeline step median {N} ms wall, {N} ms CPU over 2 steps$",
            rf"^opening the panel: {N} s wall, {N} s CPU$",
            rf"^panel open: timeline step median {N} ms wall, {N} ms CPU over 2 steps$",
            rf"^ratio open / closed \(step wall\): {N}$",
        ],
        300,
    ),
    "bench_viz.py": (
        ["--nodes", "20", "--updates", "5"],  # 5 moves a case: each of the five slider values once
        [
            rf"^send 722-triangle DEM mesh, vertex colours \(add_mesh_trimesh\): median {N} s",
            rf"^slider -> updated scene, method exact : median {N} ms",
            rf"^ratio: {N}$",
        ],
        300,
    ),
    "bench_viz_churn.py": (
        ["4"],  # 4 clients after the fixed 20-client warm-up
        [
            rf"^  after the churn \+ gc +{N} MB  \(after / idle = {N};",
            rf"still alive after the churn {N} \(goal 0\)",
            rf"median wall: ours {N} ms, bare viser server {N} ms .*\(ratio {N}\)",
        ],
        300,
    ),
    "bench_viz_flight.py": (
        ["--frames", "20", "--repeat", "1"],
        [
            rf"^open \(model \+ scene build \+ serialise\): median wall {N} s",
            rf"^timeline step with load_record: median wall {N} ms",
            rf"ratio peer / batch {N}x \(wall\)$",
        ],
        300,
    ),
    "bench_steps_ab.py": (
        ["HEAD", "--pairs", "1", "--only", "maker,replay"],  # this tree against a copy of HEAD
        [
            rf"^maker +CPU old/new {N} \(quartiles {N}-{N}, fastest quarters {N}\); .*results equal: True$",
            rf"^replay +CPU old/new {N} \(quartiles {N}-{N}, fastest quarters {N}\); .*results equal: True$",
        ],
        600,
    ),
    "bench_walk_ab.py": (
        # this tree's walk against HEAD's; HEAD's source is this tree's (unless the walk is being
        # changed), so its rows call this tree's build: the scratch copy's compile was 21-55 s of
        # CPU; every row and comparison still runs
        ["HEAD", "--repeat", "1", "--same-build"],
        [
            rf"^this tree, climbing +{N} ns a ray +{N} of HEAD +identical to HEAD: (?:True|False)",
            rf"^this tree, flat +{N} ns a ray +{N} of HEAD, flat +identical to HEAD: (?:True|False)",
        ],
        600,
    ),
    "bench_whole_frame.py": (
        ["--repeat", "1", "--step", "32", "--embree-rays", "1000"],
        [
            rf"^locate_frame \(compiled grid \+ exact DEM, parallel\): wall {N} s, CPU {N} s, {N} M rays/s wall",
            rf"^peer, numpy line of sight \+ the same solver: .*ratio {N}x wall, {N}x CPU",
            rf"^peer, trimesh/embree on 1000 of the same rays .*ratio {N}x per CPU s",
        ],
        300,
    ),
}

#: Opens headless Chromium: on the xdist worker of tests/conftest.py's Chromium group (conftest
#: does not see a browser in a subprocess), and marked ``browser`` like the other browser tests.
#: Its smallest run (a warm-up load and one measured load) takes 46-54 s.
BROWSER = {"bench_browser.py", "bench_frame.py", "bench_viewer.py"}


def _params():
    for name in sorted(CASES):
        marks = [pytest.mark.xdist_group("chromium"), pytest.mark.browser] if name in BROWSER else []
        yield pytest.param(name, id=name.removesuffix(".py"), marks=marks)


def _run(args, tmp_path, timeout):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, *map(str, args)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.parametrize("name", _params())
def test_benchmark_runs_at_a_tiny_size(name, tmp_path):
    args, patterns, timeout = CASES[name]
    if name in ("bench_walk_ab.py", "bench_steps_ab.py") and not (ROOT / ".git").exists():
        pytest.skip(f"{name} reads REV with git: not a git checkout")
    r = _run([BENCH / name, *args], tmp_path, timeout)
    cmd = f"python benchmarks/{name} {' '.join(args)}"
    assert r.returncode == 0, f"{cmd} exited {r.returncode}; stderr:\n{r.stderr[-6000:]}"
    missing = [p for p in patterns if not re.search(p, r.stdout, re.MULTILINE)]
    assert not missing, (
        f"{cmd}: no line of its output matches {missing}\nstdout:\n{r.stdout[-6000:]}\nstderr:\n{r.stderr[-3000:]}"
    )


def test_every_benchmark_is_listed():
    found = {p.name for p in BENCH.glob("bench_*.py")}
    assert found - set(CASES) == set(), (
        f"benchmarks {sorted(found - set(CASES))} are not run by "
        "tests/project/test_benchmarks_run.py: add each to CASES with a tiny size"
    )
    assert set(CASES) - found == set(), f"CASES lists benchmarks that are gone: {sorted(set(CASES) - found)}"


def _mutation():
    spec = importlib.util.spec_from_file_location("bench_mutation", BENCH / "mutation.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.modules.pop(spec.name, None)
    return mod


def test_mutation_parses_and_its_targets_exist(tmp_path):
    # a real run needs cosmic-ray (not a test dependency) and takes half an hour: here its
    # command line parses and every module and test file its targets name is in the tree
    r = _run([BENCH / "mutation.py", "--help"], tmp_path, 60)
    assert r.returncode == 0 and "--targets" in r.stdout, r.stderr[-3000:]
    mut = _mutation()

    # a test may be named by its node id (file::function): the file exists and defines the function
    def paths(tests):  # the test files and node ids, not pytest's options (-k EXPR, --deselect=NODE)
        out, skip = [], False
        for a in tests:
            if skip or a == "-k":
                skip = a == "-k"
                continue
            out.append(a.split("=", 1)[1] if a.startswith("--deselect=") else a)
        return out

    missing = [
        (t.name, f)
        for t in mut.TARGETS
        for f in (t.module, *paths(t.tests))
        if not (ROOT / f.split("::")[0]).is_file()
        or (
            "::" in f
            and not re.search(
                rf"^def {re.escape(f.split('::')[1])}\(", (ROOT / f.split("::")[0]).read_text(), re.MULTILINE
            )
        )
    ]
    missing += [("kills", mut.KILLS)] if not (ROOT / mut.KILLS).is_file() else []
    assert not missing, f"benchmarks/mutation.py names files that are not in the tree: {missing}"
    for t in mut.TARGETS:  # the functions a target is restricted to are defined in its module
        src = (ROOT / t.module).read_text()
        gone = [f for f in t.functions if not re.search(rf"^\s*def {re.escape(f)}\(", src, re.MULTILINE)]
        assert not gone, f"mutation.py target {t.name}: {t.module} defines no {gone}"
    assert mut.keep_operator("core/ReplaceBinaryOperator_Add_Sub")
    assert not mut.keep_operator("core/ReplaceBinaryOperator_Add_Mul")
    assert not mut.keep_operator("core/RemoveDecorator")


# mutation.py's real run needs cosmic-ray, not a test dependency: its run is the benchmark's own
# (``python benchmarks/mutation.py``); the test above checks it parses and names what exists.
