"""The user's files: no verb writes over one of its inputs, outputs are atomic, unwritable paths are one line.

The table of cases is built from the verbs' own option declarations
(``geoloc.cli._options``: every file option is typed ``input_path``, ``output_path``
or ``output_dir``), so a new verb or a new file option is covered without editing
this file: every output of every verb is given every input of that verb, through
the same path, a symlink, a hard link and a relative path; and every output is
given a folder that cannot be written. Each must be refused with exit status 2 and
one line on stderr, and the input's bytes must be unchanged.
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

import pytest

from geoloc import userfiles
from geoloc.assets import asset_path
from geoloc.cli import build_parser, main
from geoloc.cli._options import ROLES, declared_files


def _leaf_parsers(parser, prefix=()):
    """(argv prefix, parser) for every verb and sub-verb that runs (``klv dump``)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for name, p in subs[0].choices.items():
        yield from _leaf_parsers(p, prefix + (name,))


def _role(action):
    return ROLES.get(action.type)


def _filler(action) -> str:
    """A value argparse accepts for a required option that names no file."""
    if action.choices:
        return str(next(iter(action.choices)))
    return "1"


def _verbs():
    out = []
    for prefix, p in _leaf_parsers(build_parser()):
        if not prefix:
            continue
        files = [a for a in p._actions if _role(a)]
        if any(_role(a) != "input" for a in files):
            out.append((prefix, p))
    return out


VERBS = _verbs()


class Line:
    """An argv being built: positionals first (after the verb), then options."""

    def __init__(self, prefix, parser, tmp):
        self.prefix, self.parser, self.tmp = list(prefix), parser, Path(tmp)
        self.pos: dict = {}
        self.opts: dict = {}
        for a in parser._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            needed = (not a.option_strings and a.nargs not in ("?", "*")) or getattr(a, "required", False)
            if not needed:
                continue
            role = _role(a)
            if role == "input":
                v = str(self._dummy(a.dest))
            elif role == "output":
                v = str(self.tmp / f"other_{a.dest}.out")
            elif role == "output_dir":
                v = str(self.tmp / f"other_{a.dest}_dir")
            else:
                v = _filler(a)
            self.set(a, v)

    def _dummy(self, name) -> Path:
        p = self.tmp / f"input_{name}.dat"
        if not p.exists():
            p.write_bytes(b"an input of the command " + name.encode() + b"\n")
        return p

    def set(self, action, value) -> None:
        if action.option_strings:
            self.opts[action.option_strings[0]] = str(value)
        else:
            self.pos[action.dest] = str(value)

    def argv(self) -> list:
        out = list(self.prefix)
        for a in self.parser._actions:  # positionals in their declared order
            if not a.option_strings and a.dest in self.pos:
                out.append(self.pos[a.dest])
        for k, v in self.opts.items():
            out += [k, v]
        return out


def _cases():
    cases = []
    for prefix, p in VERBS:
        ins = [a for a in p._actions if _role(a) == "input"]
        outs = [a for a in p._actions if _role(a) in ("output", "output_dir")]
        for o in outs:
            for i in ins:
                cases.append(pytest.param(prefix, o.dest, i.dest, id=f"{' '.join(prefix)}:{o.dest}<-{i.dest}"))
    return cases


def _action(parser, dest):
    return next(a for a in parser._actions if a.dest == dest)


def _parser(prefix):
    return dict((tuple(k), v) for k, v in VERBS)[tuple(prefix)]


def _run(argv, capsys):
    rc = main(argv)
    err = capsys.readouterr().err
    return rc, err


def _assert_one_line_error(rc, err, *needles):
    assert rc == 2, (rc, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "error:" in lines[0], err
    for n in needles:
        assert n in lines[0], (n, err)


def test_every_verb_that_writes_is_in_the_table():
    # the verbs that write files today; a verb that writes must declare its outputs with the types
    names = {" ".join(p) for p, _ in VERBS}
    assert names >= {
        "calibrate",
        "export",
        "klv dump",
        "limb",
        "log",
        "montecarlo",
        "ortho",
        "replay",
        "report",
        "reproduce",
        "rpc",
        "view",
    }, names
    # and no file option escapes the table: an untyped option whose help names a file or a folder
    # is a file option declared as a plain string (the ones listed name something else)
    not_files = {
        "--format",
        "--group-by",
        "--record",
        "--scenario",
        "--reference",
        "--ref-h-column",
        "--height-column",
        "--truth-prefix",
        "--fit",
        "--epoch",
        "--angle",
        "--columns",
    }
    words = ("file", "csv", "toml", "folder", ".tif", "geotiff", ".rrd", ".json")
    for prefix, p in _leaf_parsers(build_parser()):
        for a in p._actions:
            name = a.option_strings[0] if a.option_strings else a.dest
            if a.type is not None or a.nargs == 0 or name in not_files or isinstance(a, argparse._HelpAction):
                continue
            if any(w in (a.help or "").lower() for w in words) and not a.choices:
                pytest.fail(f"{' '.join(prefix)} {name}: names a file ({a.help!r}) without a path type")


@pytest.mark.parametrize("prefix,out_dest,in_dest", _cases())
def test_an_input_given_as_an_output_is_refused(prefix, out_dest, in_dest, tmp_path, capsys):
    p = _parser(prefix)
    line = Line(prefix, p, tmp_path)
    src = tmp_path / "the_input.csv"
    src.write_bytes(b"lat_deg,lon_deg\n1,2\n")
    before = src.read_bytes()
    o, i = _action(p, out_dest), _action(p, in_dest)
    if _role(o) == "output_dir":
        src = tmp_path / "the_input_folder"
        src.mkdir()
        (src / "tile.tif").write_bytes(b"tile")
        before = (src / "tile.tif").read_bytes()
    line.set(i, src)
    line.set(o, src)
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, "is an input of this command")
    if src.is_dir():
        assert (src / "tile.tif").read_bytes() == before and sorted(os.listdir(src)) == ["tile.tif"]
    else:
        assert src.read_bytes() == before


def _with_file_pair():
    return [
        prefix
        for prefix, p in VERBS
        if any(_role(a) == "input" for a in p._actions) and any(_role(a) == "output" for a in p._actions)
    ]


@pytest.mark.parametrize("how", ["symlink", "hardlink", "relative", "dotted"])
@pytest.mark.parametrize("prefix", _with_file_pair(), ids=" ".join)
def test_the_same_file_by_another_name_is_refused(prefix, how, tmp_path, capsys, monkeypatch):
    p = _parser(prefix)
    ins = [a for a in p._actions if _role(a) == "input"]
    outs = [a for a in p._actions if _role(a) == "output"]
    line = Line(prefix, p, tmp_path)
    src = tmp_path / "data" / "the_input.csv"
    src.parent.mkdir()
    src.write_bytes(b"x,y\n1,2\n")
    monkeypatch.chdir(tmp_path)
    other = {
        "symlink": tmp_path / "link.csv",
        "hardlink": tmp_path / "hard.csv",
        "relative": Path("data/the_input.csv"),
        "dotted": tmp_path / "data" / ".." / "data" / "the_input.csv",
    }[how]
    if how == "symlink":
        other.symlink_to(src)
    elif how == "hardlink":
        os.link(src, other)
    line.set(ins[0], src)
    line.set(outs[0], other)
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, "is an input of this command")
    assert src.read_bytes() == b"x,y\n1,2\n"


def _unwritable_cases():
    out = []
    for prefix, p in VERBS:
        for a in p._actions:
            if _role(a) in ("output", "output_dir"):
                for where in ("read-only", "missing folder", "parent is a file", "wrong kind"):
                    out.append(pytest.param(prefix, a.dest, where, id=f"{' '.join(prefix)}:{a.dest}:{where}"))
    return out


@pytest.mark.parametrize("prefix,out_dest,where", _unwritable_cases())
def test_an_unwritable_output_is_one_line(prefix, out_dest, where, tmp_path, capsys):
    p = _parser(prefix)
    o = _action(p, out_dest)
    line = Line(prefix, p, tmp_path)
    is_dir = _role(o) == "output_dir"
    if where == "read-only":
        if os.geteuid() == 0:  # root writes through permission bits: sysfs refuses even root
            target, needle = Path("/sys") / ("geoloc_out_dir" if is_dir else "geoloc_out.csv"), "cannot write"
        else:
            ro = tmp_path / "ro"
            ro.mkdir()
            ro.chmod(0o555)
            target, needle = ro / ("out_dir" if is_dir else "out.csv"), "cannot write"
    elif where == "missing folder":
        target, needle = tmp_path / "no" / "such" / "out.csv", "does not exist"
        if is_dir:  # a folder output is made with its parents: refuse only where nothing can be made
            target, needle = Path("/sys/no/such/dir"), "cannot write"
    elif where == "parent is a file":
        f = tmp_path / "a_file"
        f.write_text("x")
        target, needle = f / "out.csv", "is a file"
    else:  # a folder given as a file output, a file given as a folder output
        if is_dir:
            target = tmp_path / "a_file"
            target.write_text("x")
            needle = "is a file, not a folder"
        else:
            target, needle = tmp_path, "is a folder"
    line.set(o, target)
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, needle)


# --------------------------------------------------------------------------- inputs the verb finds itself


def test_a_file_a_scenario_names_is_an_input_too(tmp_path, capsys):
    # montecarlo --out onto the DEM that the scenario names (not a command-line option): the run
    # notes the DEM when it opens it, and the writer refuses it; the DEM is unchanged
    dem = tmp_path / "dem.tif"
    shutil.copy(asset_path("dem", "etopo5_flight_area.tif"), dem)
    scen = tmp_path / "scen.toml"
    text = asset_path("scenarios", "qiao2017_table1_dem.toml").read_text()
    import re

    text = re.sub(r'(?m)^path\s*=\s*".*"', f'path = "{dem}"', text)
    assert str(dem) in text
    scen.write_text(text)
    before = dem.read_bytes()
    rc, err = _run(["montecarlo", str(scen), "--samples", "50", "--out", str(dem)], capsys)
    _assert_one_line_error(rc, err, "is an input of this command")
    assert dem.read_bytes() == before


def test_a_tile_of_a_mosaic_is_an_input(tmp_path, capsys):
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    shutil.copy(asset_path("dem", "srtm_jacksboro.tif"), tiles / "a.tif")
    before = (tiles / "a.tif").read_bytes()
    rc, err = _run(
        ["replay", str(asset_path("klv", "example_flight.klv")), "--dem", str(tiles), "--out", str(tiles / "a.tif")],
        capsys,
    )
    assert rc == 2 and "is an input of this command" in err, err
    assert (tiles / "a.tif").read_bytes() == before


def test_the_bundled_data_is_never_written(capsys):
    # the default records are no command-line input, but they are bundled data
    records = asset_path("records", "qiao2017_flight_tests.csv")
    before = records.read_bytes()
    rc, err = _run(["replay", "--height-column", "paper_height_m", "--out", str(records)], capsys)
    assert rc == 2 and ("bundled data" in err or "is an input" in err), err
    assert records.read_bytes() == before


def test_two_outputs_on_one_path_are_refused(tmp_path, capsys):
    out = tmp_path / "same.tif"
    rc, err = _run(
        ["ortho", "--photo", "assets/photos/DJI_0001.JPG", "--out", str(out), "--ortho-out", str(out), "--gsd-m", "1"],
        capsys,
    )
    _assert_one_line_error(rc, err, "are the same file")
    assert not out.exists()


# --------------------------------------------------------------------------- atomic writes


def test_an_interrupted_write_leaves_the_old_file_whole(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("the old results\n")
    with pytest.raises(KeyboardInterrupt):
        with userfiles.atomic_path(out) as tmp:
            tmp.write_text("half of the new")
            raise KeyboardInterrupt
    assert out.read_text() == "the old results\n"
    assert sorted(os.listdir(tmp_path)) == ["out.csv"]  # no temporary file left behind


def test_klv_dump_interrupted_keeps_the_old_output(tmp_path, capsys, monkeypatch):
    import geoloc.cli.klv as verb

    out = tmp_path / "dump.jsonl"
    out.write_text("old\n")

    def half(name, results, fh):
        fh.write('{"packet": 0}\n')
        raise KeyboardInterrupt

    monkeypatch.setattr(verb, "_dump", half)
    assert main(["klv", "dump", "assets/klv/example_flight.klv", "--out", str(out)]) == 130  # docs/cli.md
    assert capsys.readouterr().err.strip() == "geoloc klv dump: interrupted (Ctrl-C)"
    assert out.read_text() == "old\n" and sorted(os.listdir(tmp_path)) == ["dump.jsonl"]


def test_a_written_output_replaces_the_old_one_with_the_same_suffix(tmp_path):
    out = tmp_path / "layer.gpkg"
    out.write_text("old")
    seen = []
    with userfiles.atomic_path(out) as tmp:
        seen.append(tmp)
        assert tmp.parent == tmp_path and tmp.suffix == ".gpkg" and not tmp.exists()
        tmp.write_text("new")
    assert out.read_text() == "new" and not seen[0].exists()


def test_outside_a_command_nothing_is_noted():
    # the Python API may read a file and write it back: only a command notes its inputs
    userfiles.note_input("/etc/hostname")
    assert userfiles.noted_inputs() == []
    with userfiles.command_files(["a.csv"]) as noted:
        userfiles.note_input("b.csv")
        assert [str(p) for p in noted] == ["a.csv", "b.csv"]
    assert userfiles.noted_inputs() == []


def test_declared_files_reads_the_types(tmp_path):
    parser = build_parser()
    args = parser.parse_args(["replay", "a.csv", "b.csv", "--out", "o.csv", "--dem", "d.tif", "--dem", "e.tif"])
    ins, outs = declared_files(parser, args)
    assert sorted(ins) == ["a.csv", "b.csv", "d.tif", "e.tif"]
    assert ("--out", "o.csv", "output") in outs


def test_klv_dump_finds_the_bundled_file_from_any_folder(tmp_path, capsys, monkeypatch):
    # docs/tour_sensors.md's command names assets/klv/...: from another folder it is the bundled file
    monkeypatch.chdir(tmp_path)
    # exit 1: the example flight's one planted bad checksum is a packet that could not be used
    assert main(["klv", "dump", "assets/klv/example_flight.klv", "--out", "d.jsonl"]) == 1
    assert (tmp_path / "d.jsonl").read_text().count("\n") > 250


def test_klv_dump_of_a_folder_is_one_line(tmp_path, capsys):
    rc, err = _run(["klv", "dump", str(tmp_path)], capsys)
    _assert_one_line_error(rc, err, "is a folder")


# --------------------------------------------------------------------------- validate before acting


def test_view_reports_a_bad_input_before_it_serves(tmp_path, capsys, monkeypatch):
    import geoloc_viz.app as app

    def no_server(*a, **k):
        raise AssertionError("geoloc view started a server before checking its inputs")

    monkeypatch.setattr(app, "make_server", no_server)
    bad = tmp_path / "bad.csv"
    bad.write_text("not,a,records,file\n1,2,3,4\n")
    rc, err = _run(["view", "--scenario", "flight-test", "--records", str(bad), "--no-browser"], capsys)
    assert rc == 2 and "error:" in err and str(bad) in err, err


def test_ortho_refuses_ortho_out_without_a_dem_before_writing(tmp_path, capsys):
    out, ortho = tmp_path / "frame.tif", tmp_path / "ortho.tif"
    rc, err = _run(
        [
            "ortho",
            "--photo",
            "assets/photos/DJI_0001.JPG",
            "--target-h-m",
            "100",
            "--out",
            str(out),
            "--ortho-out",
            str(ortho),
            "--gsd-m",
            "1",
        ],
        capsys,
    )
    assert rc == 2 and "needs a DEM" in err, err
    assert not out.exists() and not ortho.exists()


# --------------------------------------------------------------------------- the docs from any folder


def test_the_docs_python_block_runs_from_an_empty_folder(tmp_path):
    import re
    import subprocess
    import sys

    # the README's Python example, now on docs/tour_cli.md (the README is one screen)
    page = (Path(__file__).resolve().parents[2] / "docs" / "tour_cli.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", page, re.S)
    assert blocks
    for code in blocks:
        lines = code.rstrip().splitlines()
        # the block ends with the expression a reader looks at: print it
        code = "\n".join(lines[:-1] + [f"print(repr(({lines[-1]})))"])
        r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    # the page's first block is [Q17]'s T3 point 1; the paper prints 35.57709 N, 80.84918 E
    assert "35.5770" in r.stdout and "80.849" in r.stdout, r.stdout


# --------------------------------------------------------------------------- the --out rules (docs/cli.md)


def _text_type():
    import geoloc.cli._options as o

    return getattr(o, "text_output_path", None)  # (None where a verb has none: the test then fails, not errors)


def _file_outputs(binary_only=False):
    text_output_path = _text_type()
    out = []
    for prefix, p in VERBS:
        for a in p._actions:
            if _role(a) == "output" and not (binary_only and a.type is text_output_path):
                out.append(pytest.param(prefix, a.dest, id=f"{' '.join(prefix)}:{a.dest}"))
    return out


@pytest.mark.parametrize("prefix,out_dest", _file_outputs())
def test_a_folder_path_with_a_trailing_slash_is_refused(prefix, out_dest, tmp_path, capsys):
    # before: `--out results/` wrote a file named `results`
    p = _parser(prefix)
    line = Line(prefix, p, tmp_path)
    line.set(_action(p, out_dest), f"{tmp_path}/results/")
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, "ends with '/'")
    assert not (tmp_path / "results").exists()


@pytest.mark.parametrize("prefix,out_dest", _file_outputs())
def test_a_read_only_output_is_refused_even_for_root(prefix, out_dest, tmp_path, capsys):
    # before: root replaced a file without a write bit (the rename needs only the folder's)
    p = _parser(prefix)
    line = Line(prefix, p, tmp_path)
    ro = tmp_path / "kept.out"
    ro.write_text("read-only results\n")
    ro.chmod(0o444)
    line.set(_action(p, out_dest), ro)
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, "is read-only")
    assert ro.read_text() == "read-only results\n" and (ro.stat().st_mode & 0o777) == 0o444


@pytest.mark.parametrize("prefix,out_dest", _file_outputs(binary_only=True))
def test_standard_output_is_refused_for_a_binary_output(prefix, out_dest, tmp_path, capsys):
    # `--out -`: one clear line where the file is binary (the text ones: tests/cli/test_bad_inputs.py)
    p = _parser(prefix)
    a = _action(p, out_dest)
    line = Line(prefix, p, tmp_path)
    line.set(a, "-")
    rc, err = _run(line.argv(), capsys)
    _assert_one_line_error(rc, err, "standard output is for text outputs")


def test_the_text_outputs_are_those_of_text_formats():
    # the options where `-` is standard output: CSV, JSON, JSON lines, TOML, and export's KML/CZML/CoT
    text_output_path = _text_type()
    text = {
        f"{' '.join(prefix)} {a.option_strings[0] if a.option_strings else a.metavar}"
        for prefix, p in VERBS
        for a in p._actions
        if a.type is text_output_path
    }
    assert text == {
        "replay --out",
        "montecarlo --out",
        "limb --out",
        "klv dump --out",
        "calibrate --out",
        "reproduce --json",
        "rpc --report",
        "export --out",
        "export OUT",
    }


def test_a_symlink_output_is_written_through_and_kept(tmp_path):
    target = tmp_path / "real" / "results.csv"
    target.parent.mkdir()
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    userfiles.write_text(link, "new\n")
    assert link.is_symlink() and os.readlink(link) == str(target)  # the link kept
    assert target.read_text() == "new\n"
    assert sorted(os.listdir(target.parent)) == ["results.csv"] and sorted(os.listdir(tmp_path)) == ["link.csv", "real"]


def test_a_dangling_symlink_output_creates_its_target(tmp_path):
    target = tmp_path / "results.csv"
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    userfiles.write_text(link, "new\n")
    assert link.is_symlink() and target.read_text() == "new\n"


def test_a_fifo_output_is_written_through(tmp_path):
    import threading

    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    userfiles.write_text(fifo, "a,b\n1,2\n")
    reader.join(timeout=60)
    assert got == [b"a,b\n1,2\n"]
    assert fifo.is_fifo() and sorted(os.listdir(tmp_path)) == ["pipe.csv"]


def test_an_existing_output_keeps_its_permission_bits(tmp_path):
    out = tmp_path / "shared.csv"
    out.write_text("old\n")
    out.chmod(0o640)
    userfiles.write_text(out, "new\n")
    assert out.read_text() == "new\n" and (out.stat().st_mode & 0o777) == 0o640


def test_dev_null_and_dev_full_through_a_link_are_written_through(tmp_path, capsys):
    # run as root, `--out /dev/null` was replaced by a regular file (the temp-file-and-rename rule
    # applied to a device); a link to it here, so that the unfixed code replaces the link, not the device
    for dev, rc_want in (("/dev/null", 0), ("/dev/full", 2)):
        link = tmp_path / f"to_{Path(dev).name}.csv"
        link.symlink_to(dev)
        rc = main(["replay", "--height-column", "paper_height_m", "--out", str(link)])
        err = capsys.readouterr().err
        assert rc == rc_want, err
        assert link.is_symlink() and Path(dev).is_char_device(), dev
        if rc_want:
            assert err.splitlines()[-1] == f"geoloc replay: error: {link}: No space left on device"
    assert sorted(os.listdir(tmp_path)) == ["to_full.csv", "to_null.csv"]


def _leaf_argvs(tmp_path):
    for prefix, p in _leaf_parsers(build_parser()):
        if prefix:
            yield " ".join(("geoloc",) + prefix), Line(prefix, p, tmp_path).argv()


def test_ctrl_c_in_every_verb_is_one_line_and_130(tmp_path, capsys, monkeypatch):
    # before: Ctrl-C printed a KeyboardInterrupt traceback; main now ends every verb the same way
    import contextlib

    @contextlib.contextmanager
    def ctrl_c(inputs=()):
        raise KeyboardInterrupt
        yield  # pragma: no cover

    monkeypatch.setattr(userfiles, "command_files", ctrl_c)
    argvs = list(_leaf_argvs(tmp_path))
    assert len(argvs) >= 17  # every verb and klv's three actions
    for prog, argv in argvs:
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 130 and err.strip().splitlines() == [f"{prog}: interrupted (Ctrl-C)"], (argv, err)


def test_a_live_journal_to_standard_output_is_one_line(tmp_path):
    with pytest.raises(userfiles.OutputRefused, match="a live journal grows as a file"):
        with userfiles.growing_path("-", "--out"):
            pass


def test_a_closed_pipe_in_every_verb_ends_quietly_with_141(tmp_path, capsys, monkeypatch):
    # before: `geoloc klv dump FILE | head -1` died of BrokenPipeError; main ends every verb the same way
    # (here stdout is pytest's capture, with no file descriptor: taken as the closed pipe; the real pipe:
    # tests/cli/test_bad_inputs.py)
    import contextlib

    @contextlib.contextmanager
    def closed_pipe(inputs=()):
        raise BrokenPipeError(32, "Broken pipe")
        yield  # pragma: no cover

    monkeypatch.setattr(userfiles, "command_files", closed_pipe)
    for prog, argv in _leaf_argvs(tmp_path):
        rc = main(argv)
        assert rc == 141 and capsys.readouterr().err == "", prog


def test_a_library_writer_into_a_fifo_does_not_replace_it(tmp_path, capsys):
    # GDAL's GeoPackage driver, given the path of an existing file, deletes it and makes a new one:
    # given a device or FIFO itself it replaced it (as root, /dev/null). The bytes are now copied in.
    import threading

    results = tmp_path / "r.csv"
    assert main(["replay", "--height-column", "paper_height_m", "--out", str(results)]) == 0
    fifo = tmp_path / "layers.gpkg"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    import subprocess
    import sys

    # in a child with a time limit: given the FIFO itself, SQLite waited on it forever
    p = subprocess.run(
        [sys.executable, "-m", "geoloc", "export", str(results), "--out", str(fifo)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    reader.join(timeout=120)
    assert fifo.is_fifo() and got and got[0].startswith(b"SQLite format 3\x00")  # a GeoPackage is SQLite
    assert sorted(x.name for x in tmp_path.iterdir()) == ["layers.gpkg", "r.csv"]


def test_a_live_journal_grows_beside_its_path_and_never_over_an_older_one(tmp_path):
    """``STEM.partial.SUFFIX``, or ``STEM.partial-2.SUFFIX`` when an earlier session's is there (the
    names docs/cli.md gives), renamed onto the path at the end; the older journal is kept."""
    from geoloc.userfiles import growing_path

    out = tmp_path / "live.csv"
    with growing_path(out) as part:
        assert part == tmp_path / "live.partial.csv"
        part.write_text("a\n1\n")
    assert out.read_text() == "a\n1\n" and not part.exists()
    (tmp_path / "live.partial.csv").write_text("an earlier session\n")
    with growing_path(out) as part:
        assert part == tmp_path / "live.partial-2.csv"
        part.write_text("a\n2\n")
    assert out.read_text() == "a\n2\n"
    assert (tmp_path / "live.partial.csv").read_text() == "an earlier session\n"


def test_a_vague_library_error_on_a_full_disk_is_named_as_the_disk_full(tmp_path, monkeypatch):
    """An OSError that says nothing (errno None or EIO) in a folder whose filesystem is full becomes
    ENOSPC naming the output; the same error elsewhere stays what it was (the filesystem's state
    is stood in for by monkeypatching ``_fault_of``: no test fills a disk)."""
    import errno

    from geoloc import userfiles

    out = tmp_path / "out.gpkg"
    monkeypatch.setattr(userfiles, "_fault_of", lambda folder: errno.ENOSPC if folder == tmp_path else None)
    with pytest.raises(OSError) as e, userfiles.atomic_path(out):
        raise OSError("Failed to commit transaction")
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(out)
    monkeypatch.setattr(userfiles, "_fault_of", lambda folder: None)
    with pytest.raises(OSError) as e, userfiles.atomic_path(out):
        raise OSError("Failed to commit transaction")
    assert e.value.errno is None and str(e.value) == "Failed to commit transaction"
