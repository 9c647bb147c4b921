"""Mutation testing of the core's modules with cosmic-ray: one command, a survivors list.

    python benchmarks/mutation.py                      # every target, sampled to ~30 min on 2 cores
    python benchmarks/mutation.py --targets ellipsoid,montecarlo --sample 0   # all their mutants
    python benchmarks/mutation.py --count              # how many mutants each target has
    python benchmarks/mutation.py --keep --scratch /tmp/mut   # keep the sessions, then, with new tests:
    python benchmarks/mutation.py --recheck /tmp/mut   # re-run only the survivors

What it does (nothing in the working tree is touched):

1. copies ``geoloc/``, ``tests/``, ``assets/`` and ``examples/`` into a scratch folder, one copy
   per parallel job (``--jobs``), each with its own numba cache;
2. for each target module, writes a cosmic-ray config there (module, the tests that hold
   it, a timeout from a baseline run) and initialises a session;
3. keeps the mutants worth running: binary operators replaced by their inverse only
   (+ <-> -, * <-> /, ** -> *), comparisons by their neighbours (< <=, > >=, < >, == !=,
   is / is not, in / not in), every number (+-1), unary operator, boolean, ``not``,
   break/continue, zero-iteration loop and exception mutant; not "remove decorator"
   (removing @njit or @dataclass(frozen) changes speed or mutability, not results); only
   inside the target's functions when it names some (the DEM solvers of terrain.py,
   the CEP of montecarlo.py); then a random sample of ``--sample`` per target (seeded),
   so that the run fits ``--budget-min``;
4. runs ``cosmic-ray exec`` (each mutant applied on disk in the scratch copy, the
   target's tests run with ``pytest -x``, the file restored) and prints, per target,
   the counts and every surviving mutant with its line and diff.

Survivors are either a test that is missing or an equivalent mutant; docs/testing.md
lists the last run's with a test that kills each or the reason it is equivalent. Not
run by CI: a full run takes hours, the sampled one about half an hour on 2 cores.
Needs ``pip install cosmic-ray`` (8.x) in the environment that runs the tests.
"""

from __future__ import annotations

import argparse
import random
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: docs/ too: tests read the pages (the Python block of docs/tour_cli.md runs in test_user_files.py)
COPY = ("geoloc", "viz", "tests", "assets", "examples", "docs")
#: The tests written from earlier runs' survivors run with every target.
KILLS = "tests/project/test_mutation_kills.py"


@dataclass
class Target:
    name: str
    module: str
    tests: tuple
    functions: tuple = ()  # empty: the whole module (module-level constants included)
    notes: str = ""
    #: run tests/project/test_mutation_kills.py too (the core's kill tests: nothing in it covers the last
    #: phase's modules, so their targets leave it out and run only their own tests)
    kills: bool = True


#: The tests of the live stream's demultiplexer and receiver (the targets ts_demux and live).
LIVE_TESTS = (
    "tests/io/test_live_gaps.py",
    "tests/workflows/test_live.py::test_synchronous_metadata_carriage_is_read",
    "tests/workflows/test_live.py::test_datagrams_and_chunks_decode_as_ffmpeg_reads_the_file",
    "tests/workflows/test_live.py::test_lost_swapped_and_repeated_datagrams_every_intact_packet_used",
    "tests/workflows/test_live.py::test_corrupt_cut_and_foreign_datagrams_are_counted_never_fatal",
    "tests/workflows/test_live.py::test_a_stream_that_stops_and_restarts",
    "tests/workflows/test_live.py::test_crc32_of_the_files_psi_sections_is_zero",
)

#: Tests left out of a target's run for their time alone (each is a minute or more on the shared
#: machine: a numba compile, a whole-flight replay, a Monte Carlo); the rest of the file runs.
_SLOW = {
    "uncertainty": (
        "tests/analysis/test_uncertainty.py::test_compiled_engine_equals_the_numpy_reference",
        "tests/analysis/test_uncertainty.py::test_predicted_ce90_le90_within_5_percent_of_monte_carlo",
        "tests/analysis/test_uncertainty.py::test_ce90_ends_are_the_normal_and_rayleigh_quantiles",
        "tests/analysis/test_uncertainty.py::test_ce90_matches_four_million_draws_and_not_the_circular_rule",
    ),
    "klv_fix": (
        "tests/workflows/test_klv_fix.py::test_fix_the_bundled_flight_on_the_dem",
        "tests/workflows/test_klv_fix.py::test_a_budget_writes_the_predicted_ce90_le90_into_tags_45_46",
    ),
    "pipeline": (
        "tests/pipeline/test_pipeline.py::test_refraction_as_a_source_of_the_error_budget",
        "tests/pipeline/test_pipeline.py::test_locate_refraction_from_18_km_grows_and_points_to_nadir",
        "tests/pipeline/test_pipeline.py::test_limb_cli_prints_the_refracted_tangent_height",
        "tests/pipeline/test_pipeline.py::test_whole_frame_grid_executor_agrees_with_the_pipeline_with_refraction",
        "tests/pipeline/test_pipeline.py::test_report_says_which_corrections_the_replay_applied",
    ),
    "refraction": ("tests/corrections/test_refraction.py::test_limb_refracted_tangent_against_the_ray_trace",),
}


def _skip(node_ids) -> tuple:
    return tuple(f"--deselect={n}" for n in node_ids)


UNCERTAINTY_TESTS = ("tests/analysis/test_uncertainty.py",) + _skip(_SLOW["uncertainty"])

TARGETS = [
    Target("ellipsoid", "geoloc/geodesy/ellipsoid.py", ("tests/geodesy/test_ellipsoid.py",)),
    Target("rotations", "geoloc/frames/rotations.py", ("tests/frames/test_frames.py", "tests/pipeline/test_locate.py")),
    Target("chain", "geoloc/frames/chain.py", ("tests/frames/test_frames.py", "tests/pipeline/test_locate.py")),
    Target("height", "geoloc/surfaces/height.py", ("tests/pipeline/test_locate.py", "tests/surfaces/test_terrain.py")),
    Target(
        "terrain",
        "geoloc/surfaces/terrain.py",
        (
            "tests/surfaces/test_terrain.py",
            "tests/surfaces/test_terrain_walk.py",
            "tests/surfaces/test_terrain_trimesh.py",
        ),
        (
            "_flat_los",
            "_ground",
            "_top_height",
            "_steps",
            "_bisect",
            "_hidden",
            "_exact_tables",
            "_exact",
            "intersect_dem",
            "_first_sampled",
        ),
        "the DEM solvers",
    ),
    Target(
        "montecarlo",
        "geoloc/analysis/montecarlo.py",
        ("tests/analysis/test_montecarlo.py",),
        ("statistics", "first_order"),
        "the statistics and CEP [Q17 eq. 18]",
    ),
    # the sensor model of the second phase
    Target("local", "geoloc/geodesy/local.py", ("tests/geodesy/test_local_frames.py", "tests/frames/test_frames.py")),
    Target("graph", "geoloc/frames/graph.py", ("tests/sensors/test_gimbals.py", "tests/sensors/test_sensors.py")),
    Target("gimbals", "geoloc/sensors/gimbals.py", ("tests/sensors/test_gimbals.py", "tests/sensors/test_sensors.py")),
    Target(
        "frame",
        "geoloc/sensors/frame.py",
        ("tests/sensors/test_gimbals.py", "tests/sensors/test_sensors.py", "tests/pipeline/test_locate.py"),
    ),
    # the one calibrator (analysis/calibrate.py, the first-phase camera's, is gone: one model of each thing)
    Target(
        "sensor_fit",
        "geoloc/analysis/sensor_fit.py",
        (
            "tests/analysis/test_sensor_fit.py",
            "tests/analysis/test_sensor_fit_groups.py",
            "tests/analysis/test_calibrate.py",
        ),
    ),
    # the last phase: the fastest test that covers each first (pytest -x stops there)
    Target("uncertainty", "geoloc/analysis/uncertainty.py", UNCERTAINTY_TESTS, kills=False),
    Target(
        "triangulate",
        "geoloc/analysis/triangulate.py",
        ("tests/analysis/test_triangulate_wls.py", "tests/analysis/test_triangulate.py"),
        kills=False,
    ),
    Target(
        "time_offset",
        "geoloc/analysis/time_offset.py",
        (
            "tests/analysis/test_time_offset.py",
            "tests/viz/test_video_example.py::test_fitting_the_time_offset_on_the_timing_fault_recovers_it",
        ),
        kills=False,
    ),
    # the live stream: its demultiplexer (geoloc.io.ts_demux, which geoloc.io.klv reads a .ts with too)
    # and its receiver (geoloc.io.live; not the sockets, the sender, the CLI), under the same tests
    Target(
        "ts_demux",
        "geoloc/io/ts_demux.py",
        LIVE_TESTS,
        (
            "crc32_mpeg2",
            "_crc32_table",
            "feed_datagram",
            "_datagram",
            "feed",
            "flush",
            "_feed",
            "_resync",
            "_packet",
            "expire",
            "_counters",
            "_gap",
            "_first",
            "_take",
            "_damage",
            "_finish",
            "_section",
            "_try_section",
            "_registration",
            "_timestamp",
            "_metadata_cells",
        ),
        "the MPEG-TS demultiplexer",
        kills=False,
    ),
    Target(
        "live",
        "geoloc/io/live.py",
        LIVE_TESTS,
        ("push", "tick", "push_bytes", "_units"),
        "the receiver (not the sockets, the sender, the CLI)",
        kills=False,
    ),
    Target("mgrs_grid", "geoloc/io/mgrs_grid.py", ("tests/io/test_mgrs_wrap.py", "tests/io/test_mgrs.py"), kills=False),
    Target("cot", "geoloc/io/cot.py", ("tests/io/test_cot_fields.py", "tests/io/test_cot.py"), kills=False),
    Target(
        "rpc_nitf",
        "geoloc/io/rpc_gdal.py",
        # read_rpc's sidecars (.RPB, _RPC.TXT) are read in test_rpc_sensor.py
        ("tests/io/test_rpc_nitf.py", "tests/sensors/test_rpc_sensor.py::test_read_rpc_from_geotiff_rpb_and_rpc_txt"),
        ("rpc00b_renormalized", "old_of", "write_rpc_nitf", "_is_sidecar", "read_rpc"),
        "the NITF RPC00B",
        kills=False,
    ),
    Target(
        "klv_fix",
        "geoloc/workflows/klv_fix.py",
        ("tests/workflows/test_klv_fix_parts.py", "tests/workflows/test_klv_fix.py") + _skip(_SLOW["klv_fix"]),
        kills=False,
    ),
    Target(
        "picture_model",
        "viz/geoloc_viz/picture_model.py",
        ("tests/viz/test_picture_opencv.py",),
        ("frame_sensor", "image_index", "locate_pixel", "image_marks"),
        "the picture's sensor and its pixels",
        kills=False,
    ),
    Target(
        "userfiles",
        "geoloc/userfiles.py",
        ("tests/cli/test_user_files.py", "tests/io/test_contract_io.py"),
        kills=False,
    ),
    # the modules new in the phase after it: the one location pipeline, the corrections (refraction,
    # light time and aberration), the height audit, the photo makers' tags, the camera database, DJI's SRT
    # the corrected pushbroom's round trip: the inverse's iteration from row to row (test_contract.py's
    # whole matrix of sensors, surfaces and corrections is minutes; this case is seconds)
    Target(
        "pipeline",
        "geoloc/pipeline.py",
        (
            "tests/pipeline/test_pipeline.py",
            "tests/pipeline/test_contract.py::test_a_corrected_pushbroom_round_trip_closes_to_a_millionth_of_a_pixel",
        )
        + _skip(_SLOW["pipeline"]),
        kills=False,
    ),
    Target(
        "refraction",
        "geoloc/corrections/refraction.py",
        ("tests/corrections/test_refraction.py",) + _skip(_SLOW["refraction"]),
        notes="the ray trace's kernels too (each mutant of a kernel recompiles it)",
        kills=False,
    ),
    Target("lighttime", "geoloc/corrections/lighttime.py", ("tests/corrections/test_lighttime.py",), kills=False),
    Target("height_audit", "geoloc/analysis/height_audit.py", ("tests/analysis/test_height_audit.py",), kills=False),
    Target("photo_makers", "geoloc/io/photo_makers.py", ("tests/io/test_photo_makers.py",), kills=False),
    Target(
        "camera_db",
        "geoloc/io/camera_db.py",
        ("tests/io/test_camera_db.py", "tests/io/test_photo_makers.py"),
        kills=False,
    ),
    # -k srt: test_dji_srt.py and the SRT cases of the readers' and writers' contracts
    Target(
        "dji_srt",
        "geoloc/io/dji_srt.py",
        ("tests/io/test_dji_srt.py", "tests/io/test_contract_io.py", "-k", "srt"),
        kills=False,
    ),
]

_KEEP_BINARY = {
    ("Add", "Sub"),
    ("Sub", "Add"),
    ("Mul", "Div"),
    ("Div", "Mul"),
    ("Pow", "Mul"),
    ("FloorDiv", "Div"),
    ("Mod", "Mul"),
}
_KEEP_COMPARE = {
    frozenset(p)
    for p in (
        ("Lt", "LtE"),
        ("Gt", "GtE"),
        ("Lt", "Gt"),
        ("LtE", "GtE"),
        ("Eq", "NotEq"),
        ("Is", "IsNot"),
        ("In", "NotIn"),
    )
}


def keep_operator(name: str) -> bool:
    op = name.split("/", 1)[-1]
    if op.startswith("RemoveDecorator"):
        return False
    m = re.match(r"ReplaceBinaryOperator_(\w+?)_(\w+)$", op)
    if m:
        return (m.group(1), m.group(2)) in _KEEP_BINARY
    m = re.match(r"ReplaceComparisonOperator_(\w+?)_(\w+)$", op)
    if m:
        return frozenset((m.group(1), m.group(2))) in _KEEP_COMPARE
    return True


def _run(cmd, cwd, env, timeout=None, check=True):
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    if check and r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed in {cwd}:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    return r


def _env(copy: Path):
    import os

    # NUMBA_BOUNDSCHECK: a mutant that makes the walk read beyond its tables raises IndexError
    # instead of reading garbage that may pass (the scratch copy's own cache holds only
    # bounds-checked code)
    # both packages of the copy (the core, and the viewer's geoloc_viz under viz/) before the installed ones
    return dict(
        os.environ,
        PYTHONPATH=os.pathsep.join((str(copy), str(copy / "viz"))),
        NUMBA_CACHE_DIR=str(copy / ".numba_cache_boundscheck"),
        NUMBA_BOUNDSCHECK="1",
        HOME=str(copy / ".home"),
        MPLBACKEND="Agg",
    )


def make_copy(dest: Path):
    dest.mkdir(parents=True)
    for name in COPY:
        shutil.copytree(ROOT / name, dest / name, ignore=shutil.ignore_patterns("__pycache__", ".hypothesis"))
    (dest / ".home").mkdir()


def test_command(t: Target) -> str:
    kills = f" {KILLS}" if t.kills else ""
    return f"{sys.executable} -m pytest -x -q -p no:cacheprovider {' '.join(t.tests)}{kills}"


def write_config(copy: Path, t: Target, timeout_s: float) -> Path:
    cfg = copy / f"cr-{t.name}.toml"
    cfg.write_text(
        "[cosmic-ray]\n"
        f'module-path = "{t.module}"\n'
        f"timeout = {timeout_s:.0f}\n"
        "excluded-modules = []\n"
        f'test-command = "{test_command(t)}"\n\n'
        "[cosmic-ray.distributor]\n"
        'name = "local"\n'
    )
    return cfg


def init_session(copy: Path, t: Target, sample: int, seed: int, timeout_s: float):
    """Initialise the target's session and skip what is not run; (generated, eligible, run)."""
    rng = random.Random(f"{seed}-{t.name}")
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import WorkerOutcome, WorkResult

    cfg = write_config(copy, t, timeout_s)
    db_path = copy / f"cr-{t.name}.sqlite"
    if db_path.exists():
        db_path.unlink()
    _run([sys.executable, "-m", "cosmic_ray.cli", "init", str(cfg), str(db_path)], copy, _env(copy))
    lines = (copy / t.module).read_text().splitlines()
    with use_db(str(db_path), WorkDB.Mode.open) as db:
        items = list(db.work_items)
        eligible, skip = [], []
        for it in items:
            m = it.mutations[0]
            line = lines[m.start_pos[0] - 1]
            ok = keep_operator(m.operator_name) and "pragma: no mutate" not in line
            if ok and t.functions:
                ok = m.definition_name in t.functions
            (eligible if ok else skip).append(it)
        run = eligible
        if sample and len(eligible) > sample:
            run = rng.sample(eligible, sample)
            chosen = {it.job_id for it in run}
            skip += [it for it in eligible if it.job_id not in chosen]
        if skip:
            db.set_multiple_results(
                [it.job_id for it in skip], WorkResult(worker_outcome=WorkerOutcome.SKIPPED, output="not run")
            )
    return cfg, db_path, len(items), len(eligible), len(run)


@dataclass
class Outcome:
    target: Target
    generated: int = 0
    eligible: int = 0
    sampled: int = 0
    killed: int = 0
    survived: list = field(default_factory=list)
    incompetent: int = 0
    not_run: int = 0
    seconds: float = 0.0


def collect(db_path: Path, t: Target, o: Outcome, copy: Path):
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome

    lines = (copy / t.module).read_text().splitlines()
    with use_db(str(db_path), WorkDB.Mode.open) as db:
        done = {it.job_id: (it, r) for it, r in db.completed_work_items}
        for it, r in done.values():
            if r.worker_outcome == WorkerOutcome.SKIPPED:
                continue
            if r.test_outcome == TestOutcome.KILLED:
                o.killed += 1
            elif r.test_outcome == TestOutcome.SURVIVED:
                m = it.mutations[0]
                o.survived.append(
                    dict(
                        line=m.start_pos[0],
                        col=m.start_pos[1],
                        operator=m.operator_name,
                        occurrence=m.occurrence,
                        function=m.definition_name,
                        source=lines[m.start_pos[0] - 1].strip(),
                        diff=r.diff or "",
                    )
                )
            else:
                o.incompetent += 1
        o.not_run = sum(1 for _ in db.pending_work_items)


def run_slot(copy: Path, targets, args, outcomes, deadline, lock):
    env = _env(copy)
    for k, t in enumerate(targets):
        o = Outcome(t)
        t0 = time.perf_counter()
        base = _run(test_command(t).split(), copy, env, check=False)
        if base.returncode != 0:  # reported, and the slot goes on with its next target
            with lock:
                print(f"[{t.name}] baseline fails: fix the tests first (not run)\n{base.stdout[-3000:]}", flush=True)
            continue
        t_base = time.perf_counter() - t0
        timeout_s = max(60.0, 4 * t_base + 30.0)
        cfg, db_path, o.generated, o.eligible, o.sampled = init_session(copy, t, args.sample, args.seed, timeout_s)
        pristine = (copy / t.module).read_bytes()
        # each target of the slot gets an equal share of what is left: a slow target early in
        # the list does not starve the ones after it
        left = (deadline - time.time()) / (len(targets) - k)
        if left > 0:
            p = subprocess.Popen(
                [sys.executable, "-m", "cosmic_ray.cli", "exec", str(cfg), str(db_path)],
                cwd=copy,
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            try:
                p.wait(timeout=left)
            except subprocess.TimeoutExpired:  # over budget: what ran is reported, the rest "not run"
                p.terminate()
                p.wait()
                (copy / t.module).write_bytes(pristine)  # the file cosmic-ray may have left mutated
        o.seconds = time.perf_counter() - t0
        collect(db_path, t, o, copy)
        with lock:
            outcomes.append(o)
            print(
                f"[{t.name}] {o.killed} killed, {len(o.survived)} survived, {o.incompetent} incompetent, "
                f"{o.not_run} not run ({o.sampled} of {o.eligible} eligible, {o.generated} generated) "
                f"in {o.seconds:.0f} s",
                flush=True,
            )


def recheck(args):
    """Re-run the survivors of a kept scratch folder (``--keep``/``--scratch``) against the
    current tests: the habit after writing the tests that kill them."""
    import sqlite3

    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome

    scratch = args.recheck
    outcomes, t0 = [], time.time()
    for db_path in sorted(scratch.glob("*/cr-*.sqlite")):
        copy = db_path.parent
        t = next(t for t in TARGETS if db_path.stem == f"cr-{t.name}")
        if args.targets and t.name not in args.targets.split(","):
            continue
        shutil.rmtree(copy / "tests")
        shutil.copytree(ROOT / "tests", copy / "tests", ignore=shutil.ignore_patterns("__pycache__", ".hypothesis"))
        base = _run(test_command(t).split(), copy, _env(copy), check=False)
        if base.returncode != 0:  # a failing test would "kill" every mutant
            raise RuntimeError(f"the current tests fail on {t.name}'s unmutated copy: {base.stdout[-3000:]}")
        with use_db(str(db_path), WorkDB.Mode.open) as db:
            ids = [it.job_id for it, r in db.completed_work_items if r.test_outcome == TestOutcome.SURVIVED]
        con = sqlite3.connect(str(db_path))
        con.executemany("DELETE FROM work_results WHERE job_id = ?", [(i,) for i in ids])
        con.commit()
        con.close()
        cfg = write_config(copy, t, 300.0)
        _run([sys.executable, "-m", "cosmic_ray.cli", "exec", str(cfg), str(db_path)], copy, _env(copy), check=False)
        o = Outcome(t, sampled=len(ids))
        collect(db_path, t, o, copy)
        o.killed = len(ids) - len(o.survived)  # of the survivors re-run
        o.incompetent = 0
        outcomes.append(o)
        print(f"[{t.name}] {len(ids)} survivors re-run: {o.killed} now killed, {len(o.survived)} survive", flush=True)
    print("\n" + report(outcomes, time.time() - t0, args))


def count(args):
    tmp = Path(tempfile.mkdtemp(prefix="geoloc-mutation-count-"))
    try:
        make_copy(tmp / "0")
        for t in select(args):
            _, _, gen, elig, run = init_session(tmp / "0", t, args.sample, args.seed, 60.0)
            print(f"{t.name:11s} {t.module:32s} generated {gen:5d}  eligible {elig:4d}  run {run:4d}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def select(args):
    names = [n for n in args.targets.split(",") if n] if args.targets else [t.name for t in TARGETS]
    unknown = set(names) - {t.name for t in TARGETS}
    if unknown:
        raise SystemExit(f"--targets: unknown {sorted(unknown)}; known: {[t.name for t in TARGETS]}")
    return [t for t in TARGETS if t.name in names]


def report(outcomes, elapsed, args) -> str:
    out = [
        f"# cosmic-ray survivors ({time.strftime('%Y-%m-%d %H:%M')}, {elapsed / 60:.0f} min, "
        f"--sample {args.sample} --seed {args.seed})",
        "",
    ]
    out.append("| target | generated | eligible | run | killed | survived | incompetent | not run |")
    out.append("|---|---|---|---|---|---|---|---|")
    order = {t.name: k for k, t in enumerate(TARGETS)}
    outcomes = sorted(outcomes, key=lambda o: order[o.target.name])
    for o in outcomes:
        out.append(
            f"| {o.target.name} | {o.generated} | {o.eligible} | {o.sampled} | {o.killed} | "
            f"{len(o.survived)} | {o.incompetent} | {o.not_run} |"
        )
    for o in outcomes:
        for s in sorted(o.survived, key=lambda s: (s["line"], s["col"])):
            op = s["operator"].split("/", 1)[-1]
            out.append("")
            out.append(f"- {o.target.module}:{s['line']} `{s['function']}` {op} #{s['occurrence']}: `{s['source']}`")
            diff = [
                ln for ln in s["diff"].splitlines() if ln.startswith(("+", "-")) and not ln.startswith(("+++", "---"))
            ]
            out.extend(f"      {ln}" for ln in diff)
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--targets", default="", help="comma-separated: " + ",".join(t.name for t in TARGETS))
    ap.add_argument("--sample", type=int, default=60, help="mutants run per target, at random (0: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2, help="parallel scratch copies")
    ap.add_argument("--budget-min", type=float, default=40.0, help="stop running new mutants after this")
    ap.add_argument("--scratch", type=Path, default=None, help="scratch folder (default: a new temp folder)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder (sessions, configs)")
    ap.add_argument("--out", type=Path, default=None, help="also write the report (markdown) here")
    ap.add_argument("--count", action="store_true", help="only count the mutants per target")
    ap.add_argument(
        "--recheck",
        type=Path,
        default=None,
        help="re-run the survivors kept in this scratch folder against the current tests",
    )
    args = ap.parse_args(argv)
    try:
        import cosmic_ray  # noqa: F401
    except ImportError:
        raise SystemExit("needs cosmic-ray: pip install cosmic-ray") from None
    if args.count:
        return count(args)
    if args.recheck:
        return recheck(args)
    targets = select(args)
    scratch = args.scratch or Path(tempfile.mkdtemp(prefix="geoloc-mutation-"))
    jobs = max(1, min(args.jobs, len(targets)))
    print(f"scratch {scratch}, {jobs} job(s), targets {[t.name for t in targets]}", flush=True)
    slots = [[] for _ in range(jobs)]
    for k, t in enumerate(targets):
        slots[k % jobs].append(t)
    t0 = time.time()
    deadline = t0 + 60.0 * args.budget_min
    outcomes, lock, threads, errors = [], threading.Lock(), [], []
    try:
        for j, ts in enumerate(slots):
            make_copy(scratch / str(j))

            def work(j=j, ts=ts):
                try:
                    run_slot(scratch / str(j), ts, args, outcomes, deadline, lock)
                except Exception as e:  # reported after the other slots finish
                    errors.append(e)

            th = threading.Thread(target=work)
            th.start()
            threads.append(th)
        for th in threads:
            th.join()
        if errors:
            raise errors[0]
        text = report(outcomes, time.time() - t0, args)
        print("\n" + text)
        if args.out:
            args.out.write_text(text + "\n")
    finally:
        if not args.keep and args.scratch is None:
            shutil.rmtree(scratch, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
