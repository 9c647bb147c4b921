"""The rules of docs/cli.md, run on every verb's own example.

Each verb module declares ``EXAMPLE``: a quick command that writes its files (a tuple when
earlier commands make its inputs, or when the verb has actions: ``klv dump``, ``fix``,
``send``). The table is built from those examples and the verbs' option declarations
(the argparse types of ``geoloc.cli._options``, as tests/cli/test_user_files.py does): every
output of every example is written through a symlink to a file with other permission bits,
into a FIFO, into ``/dev/full``, onto a full filesystem, is hit by Ctrl-C and by ENOSPC at
its rename, and every text output goes to standard output and into a closed pipe. A new
verb is in the table the day it lands: ``test_every_verb_has_an_example`` fails until it
declares one. A rule on one output runs the example with that output alone (:func:`_alone`:
``calibrate``'s ``--out`` case draws no ``--plot``); each other output has its own case.

The refusals that need no run (an input as an output, a read-only file, a folder, a
missing folder, ``-`` for a binary file) are tests/cli/test_user_files.py's, over the same
declarations; the catalogue of bad inputs is tests/cli/test_bad_inputs.py.
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import io
import itertools
import os
import re
import shlex
import signal
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from geoloc import userfiles
from geoloc.cli import _verb_modules, build_parser, main
from geoloc.cli._options import ROLES, declared_files, text_output_path


def _leaves(parser, prefix=()):
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for name, p in subs[0].choices.items():
        yield from _leaves(p, prefix + (name,))


PARSER = build_parser()
LEAVES = {prefix: p for prefix, p in _leaves(PARSER) if prefix}


def _examples() -> dict:
    """Leaf (``("klv", "dump")``) -> (setup argvs, its own argv), from each verb module's EXAMPLE."""
    out = {}
    for name, module in _verb_modules():
        ex = getattr(importlib.import_module(module), "EXAMPLE", None)
        if ex is None:
            continue
        setup = []
        for cmd in (ex,) if isinstance(ex, str) else ex:
            argv = shlex.split(cmd)
            assert argv[0] == "geoloc", cmd
            argv = argv[1:]
            leaf = tuple(argv[:2]) if tuple(argv[:2]) in LEAVES else (argv[0],)
            if argv[0] != name:
                setup.append(argv)
            else:
                out[leaf] = (list(setup), argv)
    return out


EXAMPLES = _examples()


def _outputs(argv) -> list:
    """(option, path, role, type) of the outputs a command line writes."""
    return declared_files(PARSER, PARSER.parse_args(argv), types=True)[1]


def _cases(text_only=False, first_only=False):
    out = []
    for leaf, (_setup, argv) in sorted(EXAMPLES.items()):
        outs = _outputs(argv)
        for k, (opt, path, role, kind) in enumerate(outs):
            if (text_only and kind is not text_output_path) or (first_only and k):
                continue
            out.append(pytest.param(leaf, opt, id=f"{' '.join(leaf)}:{opt}"))
    return out


def _with(argv, opt, value) -> list:
    """``argv`` with output option ``opt`` (or the positional of that metavar) set to ``value``."""
    argv = list(argv)
    if opt in argv:
        argv[argv.index(opt) + 1] = str(value)
        return argv
    old = next(path for o, path, _r, _t in _outputs(argv) if o == opt)
    argv[argv.index(old)] = str(value)
    return argv


def _alone(leaf, argv, opt) -> list:
    """``argv`` without its outputs other than ``opt`` that the verb does not require: a rule on one
    output does not wait for the others (calibrate's figure is three quarters of its run)."""
    argv = list(argv)
    for o, _p, _r, _t in _outputs(argv):
        required = any(a.required for a in LEAVES[leaf]._actions if o in a.option_strings)
        if o != opt and o.startswith("-") and not required:
            i = argv.index(o)
            del argv[i : i + 2]
    return argv


class Run:
    def __init__(self, rc, out, err):
        self.rc, self.out, self.err = rc, out, err

    def lines(self):
        return [ln for ln in self.err.splitlines() if ln.strip()]


def _run(argv, capsysbinary) -> Run:
    capsysbinary.readouterr()
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse's usage errors
        rc = e.code
    out, err = capsysbinary.readouterr()
    return Run(rc, out, err.decode("utf-8", "replace"))


def _setup(leaf, tmp_path, monkeypatch, capsysbinary):
    monkeypatch.chdir(tmp_path)
    setup, argv = EXAMPLES[leaf]
    for s in setup:
        r = _run(s, capsysbinary)
        assert r.rc in (0, 1), (s, r.err)
    return argv


_REFERENCE: dict = {}


def _reference(leaf, opt, tmp_path_factory, dash: bool = False) -> dict:
    """The example with output ``opt`` alone (:func:`_alone`) run plainly once: its exit status and
    that output's bytes (a folder: its file names).

    ``dash``: the output written as ``./-.SUFFIX``, a file whose name is standard output's
    (a KML names its document after its file: ``-``)."""
    key = (leaf, opt, dash)
    if key not in _REFERENCE:
        d = tmp_path_factory.mktemp("reference")
        old = os.getcwd()
        os.chdir(d)
        try:
            setup, argv = EXAMPLES[leaf]
            for s in setup:
                assert main(s) in (0, 1), s
            argv = _alone(leaf, argv, opt)
            if dash:
                argv = _with(argv, opt, "./-" + Path(_with_path(argv, opt)).suffix)
            rc = main(argv)
        finally:
            os.chdir(old)
        path, role = next((p, r) for o, p, r, _t in _outputs(argv) if o == opt)
        got = d / path
        _REFERENCE[key] = {"rc": rc, "file": sorted(os.listdir(got)) if role == "output_dir" else got.read_bytes()}
    return _REFERENCE[key]


#: Outputs whose bytes differ from one run to the next, and why: compared by their magic number only.
NOT_REPRODUCIBLE = {
    ".rrd": "rerun stamps its chunks with the time of logging and random ids",
    ".gpkg": "GDAL writes the time of writing in gpkg_contents.last_change",
}


def _same_output(path, got: bytes, ref: bytes) -> bool:
    if Path(str(path)).suffix in NOT_REPRODUCIBLE:
        return len(got) > 0 and got[:4] == ref[:4]
    return got == ref


def _temp_files(folder: Path) -> list:
    """Files atomic_path leaves when it fails to clean up (``.NAME.geoloc-XXXX``)."""
    return [p.name for p in Path(folder).iterdir() if ".geoloc-" in p.name]


def _role(leaf, opt):
    _s, argv = EXAMPLES[leaf]
    return next(r for o, _p, r, _t in _outputs(argv) if o == opt)


# --------------------------------------------------------------------------- the table covers every verb


def test_every_verb_has_an_example():
    # every leaf of the command line (the viewer's verbs too) declares an EXAMPLE that parses
    assert set(EXAMPLES) == set(LEAVES), sorted(set(LEAVES) - set(EXAMPLES))
    from geoloc.cli import VERB_HELP

    assert {leaf[0] for leaf in EXAMPLES} == set(VERB_HELP)
    for leaf, (setup, argv) in EXAMPLES.items():
        for a in setup + [argv]:
            PARSER.parse_args(a)  # an example that does not parse exits here


def test_every_output_option_of_the_examples_is_in_the_table():
    # the options an example leaves out are still covered by tests/cli/test_user_files.py's refusals;
    # here, each verb that writes a file writes at least one in its example
    writers = {
        leaf for leaf, p in LEAVES.items() if any(ROLES.get(a.type) in ("output", "output_dir") for a in p._actions)
    }
    with_outputs = {leaf for leaf, (_s, argv) in EXAMPLES.items() if _outputs(argv)}
    # klv send writes nothing; view's --journal and live --record are live-only (docs/live.md)
    assert writers - with_outputs <= {("klv", "send")}, writers - with_outputs
    assert len(with_outputs) >= 12


@pytest.mark.parametrize("leaf", sorted(EXAMPLES), ids=" ".join)
def test_the_example_runs_and_exits_0_or_1(leaf, tmp_path, monkeypatch, capsysbinary):
    # exit codes (docs/cli.md): 0 all done, 1 some records not located (klv dump of the example flight:
    # its one planted bad checksum); every output is there, no temporary file is left
    argv = _setup(leaf, tmp_path, monkeypatch, capsysbinary)
    r = _run(argv, capsysbinary)
    assert r.rc in (0, 1) and "Traceback" not in r.err, r.err
    for opt, path, role, _t in _outputs(argv):
        assert (tmp_path / path).is_dir() if role == "output_dir" else (tmp_path / path).stat().st_size > 0
    assert _temp_files(tmp_path) == []


@pytest.mark.parametrize("leaf", sorted(EXAMPLES), ids=" ".join)
def test_bad_usage_is_exit_2(leaf, capsysbinary):
    # the example with an option the verb does not have: argparse's usage line, exit 2, nothing run
    r = _run(EXAMPLES[leaf][1] + ["--no-such-option"], capsysbinary)
    assert r.rc == 2 and "unrecognized arguments: --no-such-option" in r.lines()[-1], r.err


# --------------------------------------------------------------------------- arguments before any work


@pytest.mark.parametrize("leaf,opt", _cases())
def test_a_refused_output_stops_the_verb_before_it_starts(leaf, opt, tmp_path, monkeypatch, capsysbinary):
    # the outputs are checked before the verb runs: command_files (the verb's whole run is inside it)
    # is never entered when an output is a folder
    argv = _setup(leaf, tmp_path, monkeypatch, capsysbinary)
    folder = tmp_path / "a_folder"
    folder.mkdir()
    wrong = tmp_path / "a_file" if _role(leaf, opt) == "output_dir" else folder
    (tmp_path / "a_file").write_text("x")

    def started(inputs=()):
        raise AssertionError(f"{' '.join(leaf)} started before refusing {opt} {wrong}")

    monkeypatch.setattr(userfiles, "command_files", started)
    r = _run(_with(argv, opt, wrong), capsysbinary)
    assert r.rc == 2 and len(r.lines()) == 1 and "error:" in r.err, r.err


# --------------------------------------------------------------------------- --out -: standard output


@pytest.mark.parametrize("leaf,opt", _cases(text_only=True))
def test_out_dash_writes_standard_output_the_files_bytes(
    leaf, opt, tmp_path, tmp_path_factory, monkeypatch, capsysbinary
):
    ref = _reference(leaf, opt, tmp_path_factory, dash=True)
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    before = set(os.listdir(tmp_path))
    r = _run(_with(argv, opt, "-"), capsysbinary)
    assert r.rc == ref["rc"], r.err
    assert r.out == ref["file"]  # the data alone: the messages went to stderr
    assert not (tmp_path / "-").exists()
    assert set(os.listdir(tmp_path)) - before <= {p for o, p, _r, _t in _outputs(argv) if o != opt}


class _ClosedPipe:
    """A standard output whose reader has gone: every write is EPIPE (no file descriptor: main takes
    the BrokenPipeError as the closed pipe, as tests/cli/test_user_files.py does)."""

    def write(self, data):
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    def flush(self):
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    @property
    def buffer(self):
        return self

    def isatty(self):
        return False


@pytest.mark.parametrize("leaf,opt", _cases(text_only=True))
def test_out_dash_into_a_closed_pipe_ends_quietly_with_141(leaf, opt, tmp_path, monkeypatch, capsysbinary):
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    capsysbinary.readouterr()
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    rc = main(_with(argv, opt, "-"))
    monkeypatch.undo()
    assert rc == 141
    assert "Traceback" not in capsysbinary.readouterr().err.decode()


# --------------------------------------------------------------------------- what is there is written through


@pytest.mark.parametrize("leaf,opt", _cases())
def test_a_symlink_stays_and_its_target_keeps_its_mode(
    leaf, opt, tmp_path, tmp_path_factory, monkeypatch, capsysbinary
):
    ref = _reference(leaf, opt, tmp_path_factory)
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    real = tmp_path / "real"
    real.mkdir()
    is_dir = _role(leaf, opt) == "output_dir"
    suffix = Path(_with_path(argv, opt)).suffix  # a writer may choose its format by it (matplotlib)
    target = real / ("target_dir" if is_dir else "target" + suffix)
    if is_dir:
        target.mkdir()
    else:
        target.write_bytes(b"the old output\n")
        target.chmod(0o640)
    link = tmp_path / "links" / Path(_with_path(argv, opt)).name  # the example's name (a KML names itself by it)
    link.parent.mkdir()
    link.symlink_to(target)
    r = _run(_with(argv, opt, link), capsysbinary)
    assert r.rc == ref["rc"], r.err
    assert link.is_symlink() and os.readlink(link) == str(target)
    if is_dir:
        assert sorted(os.listdir(target)) == ref["file"]
    else:
        assert _same_output(link, target.read_bytes(), ref["file"])
        assert stat.S_IMODE(target.stat().st_mode) == 0o640
        assert sorted(os.listdir(real)) == [target.name]
    assert _temp_files(tmp_path) == []


def _file_cases(**kw):
    return [c for c in _cases(**kw) if _role(c.values[0], c.values[1]) == "output"]


@pytest.mark.parametrize("leaf,opt", _file_cases())
def test_a_fifo_is_written_through(leaf, opt, tmp_path, tmp_path_factory, monkeypatch, capsysbinary):
    ref = _reference(leaf, opt, tmp_path_factory)
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    fifo = tmp_path / "fifos" / Path(_with_path(argv, opt)).name  # the example's name (a KML names itself by it)
    fifo.parent.mkdir()
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    r = _run(_with(argv, opt, fifo), capsysbinary)
    if not got:  # the verb failed before opening it: let the reader go
        with contextlib.suppress(OSError):
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
    reader.join(timeout=60)
    assert r.rc == ref["rc"], r.err
    assert fifo.is_fifo() and len(got) == 1 and _same_output(fifo, got[0], ref["file"])
    assert _temp_files(tmp_path) == []


def _with_path(argv, opt):
    return next(p for o, p, _r, _t in _outputs(argv) if o == opt)


@pytest.mark.parametrize("leaf,opt", _file_cases())
def test_dev_full_is_written_through_and_is_one_line(leaf, opt, tmp_path, monkeypatch, capsysbinary):
    # through a link, so that a verb that replaced its output would replace the link, not the device
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    link = tmp_path / ("full" + Path(_with_path(argv, opt)).suffix)
    link.symlink_to("/dev/full")
    r = _run(_with(argv, opt, link), capsysbinary)
    assert r.rc == 2, r.err
    assert r.lines()[-1].endswith(f"error: {link}: No space left on device"), r.err
    assert link.is_symlink() and Path("/dev/full").is_char_device()


# --------------------------------------------------------------------------- Ctrl-C and faults at the rename


def _replace_raising(monkeypatch, target: Path, exc):
    """os.replace raises ``exc`` when it would put a file at or in ``target`` (the last step of atomic_path)."""
    real = os.replace
    hits = []

    def replace(src, dst, *a, **k):
        d = Path(os.fspath(dst))
        if d == target or target in d.parents:
            hits.append(d)
            raise exc
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", replace)
    return hits


def _old_output(tmp_path, leaf, opt):
    """An earlier output of the same name: a file with known bytes, or a folder holding one."""
    p = tmp_path / ("old_output" + Path(_with_path(EXAMPLES[leaf][1], opt)).suffix)
    if _role(leaf, opt) == "output_dir":
        p.mkdir()
        (p / "earlier.txt").write_bytes(b"an earlier report\n")
        return p, lambda: sorted(os.listdir(p)) == ["earlier.txt"] or (p / "earlier.txt").read_bytes()
    p.write_bytes(b"the old output\n")
    return p, lambda: p.read_bytes() == b"the old output\n"


@pytest.mark.parametrize("leaf,opt", _cases())
def test_ctrl_c_while_writing_is_one_line_130_and_the_old_output_stays(leaf, opt, tmp_path, monkeypatch, capsysbinary):
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    old, intact = _old_output(tmp_path, leaf, opt)
    hits = _replace_raising(monkeypatch, old, KeyboardInterrupt())
    r = _run(_with(argv, opt, old), capsysbinary)
    prog = "geoloc " + " ".join(leaf)
    assert hits and r.rc == 130 and r.lines()[-1:] == [f"{prog}: interrupted (Ctrl-C)"], r.err
    assert "Traceback" not in r.err and intact()
    assert _temp_files(tmp_path) == [] and (not old.is_dir() or _temp_files(old) == [])


@pytest.mark.parametrize("leaf,opt", _cases())
def test_no_space_at_the_rename_keeps_the_old_output(leaf, opt, tmp_path, monkeypatch, capsysbinary):
    # a patched os.replace raising ENOSPC: the fault every platform can inject (the real full disk: below)
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    old, intact = _old_output(tmp_path, leaf, opt)
    hits = _replace_raising(monkeypatch, old, OSError(errno.ENOSPC, "No space left on device", str(old)))
    r = _run(_with(argv, opt, old), capsysbinary)
    assert hits and r.rc == 2 and "No space left on device" in r.lines()[-1], r.err
    assert len([ln for ln in r.lines() if "error:" in ln]) == 1 and "Traceback" not in r.err
    assert intact() and _temp_files(tmp_path) == [] and (not old.is_dir() or _temp_files(old) == [])


# --------------------------------------------------------------------------- a real full disk, a folder made read-only


@pytest.fixture
def small_fs(tmp_path):
    """A mount point of a 1 MB tmpfs (root only: skipped where mounting is not allowed); unmounted after."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if p.returncode:
        pytest.skip(f"cannot mount a small filesystem here: {p.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _fill(mnt: Path, leave: int) -> None:
    """Fill the filesystem but ``leave`` bytes (rounded down to its blocks)."""
    st = os.statvfs(mnt)
    free = st.f_bavail * st.f_frsize
    with open(mnt / "filler", "wb") as fh:
        with contextlib.suppress(OSError):
            fh.write(b"\0" * max(0, free - leave))


@pytest.mark.parametrize("leaf,opt", _cases())
def test_a_disk_full_while_writing_keeps_the_old_output(
    leaf, opt, small_fs, tmp_path, tmp_path_factory, monkeypatch, capsysbinary
):
    ref = _reference(leaf, opt, tmp_path_factory)
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    old, intact = _old_output(small_fs, leaf, opt)
    size = len(ref["file"]) if isinstance(ref["file"], bytes) else 4096
    _fill(small_fs, size // 2)  # the write runs out of space half way (or at its first block)
    before = sorted(os.listdir(small_fs))
    r = _run(_with(argv, opt, old), capsysbinary)
    assert r.rc == 2 and len([ln for ln in r.lines() if "error:" in ln]) == 1, r.err
    assert "No space left on device" in r.lines()[-1] and "Traceback" not in r.err, r.err
    assert intact() and sorted(os.listdir(small_fs)) == before
    assert not old.is_dir() or _temp_files(old) == []


@pytest.mark.parametrize("leaf,opt", _cases(first_only=True))
def test_a_folder_made_read_only_mid_run_is_one_line(leaf, opt, small_fs, tmp_path, monkeypatch, capsysbinary):
    # after the outputs were checked, the folder turns read-only (remounted: as root, permission bits do
    # not stop a write); the verb ends with one line, the old output whole, nothing left behind
    import geoloc.cli._options as options

    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    old, intact = _old_output(small_fs, leaf, opt)
    real = options.check_outputs

    def then_read_only(parser, args):
        inputs = real(parser, args)
        subprocess.run(["mount", "-o", "remount,ro", str(small_fs)], check=True)
        return inputs

    monkeypatch.setattr(options, "check_outputs", then_read_only)
    r = _run(_with(argv, opt, old), capsysbinary)
    assert r.rc == 2 and "Read-only file system" in r.lines()[-1] and "Traceback" not in r.err, r.err
    assert intact() and sorted(os.listdir(small_fs)) == [old.name]


# --------------------------------------------------------------------------- progress of long work

#: The verbs without ``--progress`` (geoloc.cli._options.add_progress_options), and why their work is
#: short or shows itself. A new verb is either run by the test below or named here with its reason.
QUICK = {
    ("locate",): "one line of sight",
    ("pixel",): "one pixel",
    ("limb",): "a few tangent points",
    ("calibrate",): "a least-squares fit of a flight's records, seconds",
    ("export",): "a format conversion of a results file, one pass",
    ("report",): "a report of a results file, one pass",
    ("reproduce",): "the papers' tables at their fixed sizes (its Monte Carlo takes progress= in the API)",
    ("warm",): "compiles the kernels once, a few seconds; says so before it starts",
    ("klv", "dump"): "streams its packets out as it reads them",
    ("klv", "fix"): "one pass over a file, streamed",
    ("klv", "send"): "sends in real time; the live verbs show their own state",
    ("view",): "a viewer: its progress is on screen",
    ("log",): "one recording of a results file",
    ("s2", "grid"): "a granule's grid is one batched call: 0.04 s at a 150-pixel step (benchmarks/bench_sentinel2.py)",
    ("s2", "pixel"): "one ground point",
}
#: The verbs whose work grows with the input: they must show progress.
LONG = {("montecarlo",), ("replay",), ("ortho",), ("rpc",)}


def _with_progress():
    return sorted(leaf for leaf, p in LEAVES.items() if any("--progress" in a.option_strings for a in p._actions))


def test_every_long_verb_shows_progress_and_every_other_says_why_not():
    shown = set(_with_progress())
    assert LONG <= shown, LONG - shown
    assert set(LEAVES) - shown == set(QUICK), (set(LEAVES) - shown) ^ set(QUICK)


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _asset(*parts) -> str:
    from geoloc.assets import asset_path

    return str(asset_path(*parts))


def _srt(tmp_path) -> str:
    # two blocks in DJI's bracketed layout (tests/io/test_dji_srt.py has both layouts)
    p = tmp_path / "DJI_0001.SRT"
    p.write_text(
        "".join(
            f"{k}\n00:00:0{k - 1},000 --> 00:00:0{k},000\n[latitude: 36.52{k}] [longitude: -84.21] "
            f"[rel_alt: 100.0 abs_alt: 412.6] [FrameCnt: {k}]\n\n"
            for k in (1, 2)
        )
    )
    return str(p)


#: Each kind of input ``replay`` reads (geoloc.cli.replay.INPUT_KINDS) as a quick command that shows
#: its progress (its example, ``EXAMPLE``, is the records CSV's), or the reason it needs none.
REPLAY_KINDS = {
    "records": None,  # the verb's own example
    "klv": lambda tmp: ["replay", _asset("klv", "example_flight.klv"), "--out", "k.csv"],
    "photos": lambda tmp: [
        "replay",
        _asset("photos", "DJI_0001.JPG"),
        "--targets",
        _asset("photos", "targets.csv"),
        "--out",
        "p.csv",
    ],
    "srt": lambda tmp: ["replay", _srt(tmp), "--out", "s.csv"],
    "campaign": lambda tmp: [
        "replay",
        _asset("klv", "example_flight.klv"),
        "--parquet-out",
        "parts",
        "--scheduler",
        "none",
    ],
    "live": "a live stream has no end to count towards: each packet's row is printed as it arrives (docs/live.md)",
}


def test_every_input_kind_of_replay_shows_progress_or_says_why_not():
    from geoloc.cli.replay import INPUT_KINDS

    assert set(REPLAY_KINDS) == set(INPUT_KINDS), set(REPLAY_KINDS) ^ set(INPUT_KINDS)


def _progress_cases():
    cases = [pytest.param(leaf, None, id=" ".join(leaf)) for leaf in _with_progress()]
    return cases + [
        pytest.param(("replay",), kind, id=f"replay {kind}") for kind, how in REPLAY_KINDS.items() if callable(how)
    ]


@pytest.mark.parametrize("leaf,kind", _progress_cases())
def test_long_work_is_a_bar_on_a_terminal_and_a_line_in_a_log(leaf, kind, tmp_path, monkeypatch, capsysbinary):
    # the example (or a replay of another kind of input) with a clock that jumps 11 s at each reading,
    # so that every update of the work is due (the 10 s between two lines of a log:
    # tests/cli/test_bad_inputs.py); stderr a log (not a terminal): plain lines; a terminal: the
    # \r-updated bar; --no-progress on a terminal: nothing
    import geoloc.progress as progress

    argv = _setup(leaf, tmp_path, monkeypatch, capsysbinary)
    if kind is not None:
        argv = REPLAY_KINDS[kind](tmp_path)
    clock = itertools.count(0, 11)
    monkeypatch.setattr(progress, "_now", lambda: float(next(clock)))
    line = re.compile(rf"{leaf[0]} .+: (\d+)/(\d+) \(\d+\.\d%\), \S+ elapsed, \S+ left")
    r = _run(argv, capsysbinary)
    lines = [m for m in map(line.fullmatch, r.err.splitlines()) if m]
    assert r.rc in (0, 1) and lines and "\r" not in r.err, r.err
    assert lines[-1].group(1) == lines[-1].group(2)  # the last update counts the whole of the work
    assert b"elapsed" not in r.out  # standard output carries the data alone

    def on_a_terminal(extra):
        term = _Terminal()
        with monkeypatch.context() as m:
            m.setattr(sys, "stderr", term)
            rc = main(argv + extra)
        capsysbinary.readouterr()
        return rc, term.getvalue()

    if kind == "campaign":  # a second run into the same folder is refused: a new one
        argv = _with_value(argv, "--parquet-out", "parts2")
    rc, err = on_a_terminal([])
    if kind == "campaign":
        argv = _with_value(argv, "--parquet-out", "parts3")
    bars = re.findall(rf"\r{leaf[0]} .+? \[[# ]{{30}}\] +\d+\.\d% (\d+)/(\d+) ", err)
    assert rc in (0, 1) and bars and bars[-1][0] == bars[-1][1], err
    rc, err = on_a_terminal(["--no-progress"])
    assert rc in (0, 1) and "elapsed" not in err and "\r" not in err, err


def _with_value(argv, opt, value) -> list:
    argv = list(argv)
    argv[argv.index(opt) + 1] = value
    return argv


def _folder_turns_read_only(monkeypatch, folder: Path, err: int, hits: list) -> None:
    """From now on, what the kernel refuses in a folder made read-only refuses in ``folder``: creating,
    opening for writing, renaming, changing the mode of or removing a file there fails with ``err``
    (EROFS: the filesystem remounted read-only; EACCES: the folder lost its write bit, for a user who
    is not root). The system calls Python makes (``os.open``, under ``tempfile.mkstemp`` and
    ``os.fdopen``; ``open``; ``os.replace`` ...) are patched, so no root is needed; the real read-only
    filesystem is the next test's. ``hits`` gets the paths refused (the fault was met, not missed)."""
    import builtins

    folder = folder.resolve()

    def inside(p) -> bool:
        if isinstance(p, int):
            return False
        q = Path(os.fsdecode(p)).absolute()
        return q.parent == folder or folder in q.parents

    def refuse(p):
        hits.append(os.fsdecode(p))
        raise OSError(err, os.strerror(err), os.fsdecode(p))

    real_os_open = os.open

    def os_open(p, flags, *a, **k):
        if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC) and inside(p):
            refuse(p)
        return real_os_open(p, flags, *a, **k)

    monkeypatch.setattr(os, "open", os_open)
    for name in ("mkdir", "replace", "rename", "chmod", "unlink", "rmdir", "truncate"):

        def refused(p, *a, _real=getattr(os, name), **k):
            if inside(p) or any(inside(x) for x in a[:1] if isinstance(x, (str, bytes, os.PathLike))):
                refuse(p)
            return _real(p, *a, **k)

        monkeypatch.setattr(os, name, refused)
    real_open = builtins.open

    def open_(file, mode="r", *a, **k):
        if any(c in mode for c in "wax+") and inside(file):
            refuse(file)
        return real_open(file, mode, *a, **k)

    monkeypatch.setattr(builtins, "open", open_)
    monkeypatch.setattr(io, "open", open_)


def _read_only_cases():
    # EROFS on every verb's first output; EACCES (the same path through atomic_path, another reason in
    # the line) on one verb's, to keep the suite's time
    out = [pytest.param(*c.values, errno.EROFS, id=f"{c.id}:read-only-fs") for c in _cases(first_only=True)]
    return out + [pytest.param(("replay",), "--out", errno.EACCES, id="replay:--out:no-write-bit")]


@pytest.mark.parametrize("leaf,opt,err", _read_only_cases())
def test_a_folder_made_read_only_after_the_checks_keeps_the_old_output(
    leaf, opt, err, tmp_path, monkeypatch, capsysbinary
):
    # the folder is writable when the outputs are checked (check_outputs passes), then refuses every
    # write: the verb ends with one line naming the output (not the hidden temporary file) and the
    # reason, exit 2; the old output is whole and nothing is left beside it. No root needed: the
    # system calls are patched (_folder_turns_read_only); as root a permission bit would not stop a write
    import geoloc.cli._options as options

    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    folder = tmp_path / "outputs"
    folder.mkdir()
    old, intact = _old_output(folder, leaf, opt)
    real = options.check_outputs
    hits = []

    def then_read_only(parser, args):
        inputs = real(parser, args)
        _folder_turns_read_only(patches, folder, err, hits)
        return inputs

    with pytest.MonkeyPatch.context() as patches:
        monkeypatch.setattr(options, "check_outputs", then_read_only)
        r = _run(_with(argv, opt, old), capsysbinary)
    reason = os.strerror(err)
    assert hits, f"{' '.join(leaf)} wrote {opt} without a system call the test can refuse"
    assert r.rc == 2 and "Traceback" not in r.err, r.err
    last = r.lines()[-1]  # "...error: [--out] OLD: [cannot write in folder F: ]REASON"
    assert "error: " in last and str(old) in last and last.endswith(f": {reason}") and ".geoloc-" not in last, r.err
    assert len([ln for ln in r.lines() if "error:" in ln]) == 1, r.err
    assert intact() and sorted(os.listdir(folder)) == [old.name]
    assert not old.is_dir() or _temp_files(old) == []


@pytest.mark.parametrize(
    "leaf,opt",
    # atomic_path's three kinds of output: a text file, a GDAL raster (read back before its rename),
    # a folder of files
    [(("replay",), "--out"), (("ortho",), "--out"), (("report",), "--out-dir")],
    ids=lambda v: " ".join(v) if isinstance(v, tuple) else v,
)
def test_a_folder_made_read_only_at_the_rename_names_the_temp_file_it_cannot_remove(
    leaf, opt, tmp_path, monkeypatch, capsysbinary
):
    # the fault at the one point where the temporary file is whole and cannot be taken back: the writer
    # has finished, then the folder turns read-only, so the rename and the removal of the temporary file
    # are both refused. The command ends with one error line naming the output (not the temporary file,
    # which the removal's own error once named), one warning line naming the file left behind so the
    # user can delete it, exit 2, the old output whole
    argv = _alone(leaf, _setup(leaf, tmp_path, monkeypatch, capsysbinary), opt)
    folder = tmp_path / "outputs"
    folder.mkdir()
    old, intact = _old_output(folder, leaf, opt)
    hits: list = []
    renames: list = []
    real_replace = os.replace

    with pytest.MonkeyPatch.context() as patches:

        def replace(src, dst, *a, **k):
            d = Path(os.fspath(dst))
            if d == old or old in d.parents:
                renames.append(d)
                _folder_turns_read_only(patches, folder, errno.EROFS, hits)
                return os.replace(src, dst, *a, **k)  # now the refusing one
            return real_replace(src, dst, *a, **k)

        patches.setattr(os, "replace", replace)
        r = _run(_with(argv, opt, old), capsysbinary)
    left = _temp_files(folder) + (_temp_files(old) if old.is_dir() else [])
    assert renames and r.rc == 2 and "Traceback" not in r.err, r.err
    last = r.lines()[-1]
    assert "error: " in last and str(old) in last and last.endswith(": Read-only file system"), r.err
    assert ".geoloc-" not in last and len([ln for ln in r.lines() if "error:" in ln]) == 1, r.err
    assert len(left) == 1 and intact(), (left, r.err)
    warned = [ln for ln in r.lines() if "warning:" in ln and left[0] in ln]
    assert len(warned) == 1 and "could not be removed (Read-only file system); delete it by hand" in warned[0], r.err


# --------------------------------------------------------------------------- bounded iterations


def _dem_cases():
    return [
        pytest.param(leaf, id=" ".join(leaf))
        for leaf, (_s, argv) in sorted(EXAMPLES.items())
        if any("--eps-h" in a.option_strings for a in LEAVES[leaf]._actions)
        and "--dem" in argv
        or leaf in {("replay",), ("ortho",), ("calibrate",)}
    ]


@pytest.mark.parametrize("leaf", _dem_cases())
def test_a_tolerance_no_solver_reaches_still_ends(leaf, tmp_path, monkeypatch, capsysbinary):
    # --method steps --eps-h 1e-9: unbounded, the descending steps would take (relief / 1e-9) steps,
    # hours; bounded (docs/cli.md, "Bounded iterations"), the verb ends with statuses. The alarm only
    # turns a hang into a failure (it is no speed test: the run takes seconds)
    import geoloc.surfaces.terrain as terrain

    # the bound, whatever its value, turns into a status: a tenth of it here, where the real one
    # (20 000 steps, its value checked by tests/cli/test_bad_inputs.py) took 14 s of CPU for pixel's
    # one ray and 12 s for ortho's frame, 40 s each under CI's load. A verb that set its own larger
    # bound (max_iter) or none would still run for hours and meet the alarm
    bound = terrain.STEPS_MAX // 10
    monkeypatch.setattr(terrain, "STEPS_MAX", bound)
    real_steps, walked = terrain._steps, []

    def steps(*a, **k):
        out, evals = real_steps(*a, **k)
        walked.append(int(evals.max(initial=0)))
        return out, evals

    monkeypatch.setattr(terrain, "_steps", steps)
    argv = _setup(leaf, tmp_path, monkeypatch, capsysbinary)

    def hang(*_):
        raise TimeoutError(f"{' '.join(leaf)} --method steps --eps-h 1e-9 did not end in 300 s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(300)
    try:
        r = _run(argv + ["--method", "steps", "--eps-h", "1e-9"], capsysbinary)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    assert r.rc in (0, 1) and "Traceback" not in r.err, r.err
    # the examples on a DEM (pixel's --dem, ortho's record) stepped down to the bound; replay and
    # calibrate locate on the records' heights, where --method steps takes no step
    assert (max(walked) if walked else None) == (bound if leaf in {("pixel",), ("ortho",)} else None), walked


def test_two_kml_exports_in_one_process_are_the_same_bytes(tmp_path, monkeypatch, capsysbinary):
    # found by the `--out -` rule: simplekml numbers ids with a counter of the whole process, so the
    # second KML a process wrote had other ids (k32 for k1) than the first
    monkeypatch.chdir(tmp_path)
    assert main(["replay", "--height-column", "paper_height_m", "--out", "r.csv"]) == 0
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        assert main(["export", "r.csv", "--out", f"{name}/x.kml"]) == 0
    a, b = (tmp_path / "a" / "x.kml").read_bytes(), (tmp_path / "b" / "x.kml").read_bytes()
    assert a == b and b'id="k1"' in a
