"""Every `geoloc` command of the README and of the tour pages runs as written from an empty folder.

The pages' bash blocks are read here, not copied: each block's commands run in order in
one new empty folder (a later command may read what an earlier one wrote, as a reader's
would), through the installed `geoloc` entry point, exactly as printed. The pages are
``PAGES``: the README and the pages its sections moved to (docs/install.md, docs/tour_*.md,
docs/benchmarks.md), and the guides whose commands all run here (calibration.md, gis.md,
sensors.md). Any other docs page with `geoloc` commands in a bash block must be named
in ``PAGES_NOT_RUN`` with the reason, so a new page cannot slip out of this test unseen. A
command is left out only for a reason listed in ``NOT_RUN`` (a template naming the reader's own
files, a run of about an hour, a send to the LAN); the test fails when a listed command is no
longer on the pages, so the list cannot go stale. `geoloc view` is run until it says where it
serves, then stopped. The output a block prints under a command (its `#   ` lines; "..."
elides part of one) must appear in what the command printed or in a text file it wrote:
the figures the pages quote are the ones a reader gets.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
# the README and the pages its sections moved to (the README is one screen, the rest a site),
# then the guides whose commands run here too
PAGES = [
    ROOT / "README.md",
    DOCS / "install.md",
    *sorted(DOCS.glob("tour_*.md")),
    DOCS / "benchmarks.md",
    DOCS / "calibration.md",
    DOCS / "gis.md",
    DOCS / "sensors.md",
]
# docs pages whose bash blocks are not run here yet -> why
PAGES_NOT_RUN = {
    "live.md": "its commands are two terminals run at once (sender and receiver); test_live.py runs them together",
    "height_audit.md": "flight.csv is the reader's own faulty flight; test_height_audit.py plants each fault and runs these",
    "photos.md": "a template: DJI_0002.JPG and targets.csv are the reader's own (test_photos.py)",
    "scale.md": "templates: the reader's own tiles, flights and scheduler (test_mosaic.py, test_campaign.py)",
}

# command (as on the pages, continuations joined) -> why it is not run here
NOT_RUN = {
    "geoloc replay my_log.csv --columns map.toml --sensor my_sensor.toml --target-h-m 300": "a template: the reader's own log, map and sensor (the column maps are tested in test_columns.py)",
    "geoloc locate ... --dem assets/dem/srtm_jacksboro.tif --method bisect --threshold 8": "a template: '...' stands for the pose options of the commands above",
    "geoloc locate --dem tiles/ ...": "a template: the reader's own folder of tiles (test_mosaic.py)",
    "geoloc replay flights/ --parquet-out out/": "a template: the reader's own folder (test_campaign.py)",
    "geoloc montecarlo assets/scenarios/qiao2017_table1.toml --samples 1e9 --progress": "about an hour by design (the constant-memory claim is test_montecarlo_streaming.py's)",
    "geoloc export frames.csv --cot udp://239.2.3.1:6969": "sends to TAK's LAN multicast group; the same sender to loopback is test_cot.py's",
}

#: Commands run at another pace than the page's, and why: (what the page says, what is run). Only the
#: pace of a sender with no receiver changes (its datagrams go to nobody, what it prints is the same);
#: the real-time pacing itself is tests/workflows/test_live.py's (test_real_time_over_loopback).
PACED = {
    "geoloc klv send assets/klv/example_flight.ts udp://127.0.0.1:5600 --speed 10": (
        "--speed 10",
        "--speed 1000",
        "the viewer's companion, run after the viewer stopped: 36 s of sleeping between datagrams no one reads",
    ),
}


def bash_blocks(text: str) -> list[list[tuple[str, list[str]]]]:
    """A page's bash blocks: each a list of (command, the `#   ` output lines under it)."""
    blocks, cur, in_block = [], None, False
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            if not in_block and line.strip() == "```bash":
                in_block, cur = True, []
            elif in_block:
                blocks.append(cur)
                in_block = False
            i += 1
            continue
        if in_block:
            if line.startswith("geoloc "):
                cmd = line
                while cmd.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    cmd = cmd.rstrip()[:-1].rstrip() + " " + lines[i].strip()
                cur.append((strip_comment(cmd), []))
            elif line.startswith("#   ") and cur:
                cur[-1][1].append(line[4:].strip())
        i += 1
    return [b for b in blocks if b]


def strip_comment(cmd: str) -> str:
    """The command without its trailing `# ...` remark (a `#` inside quotes is kept)."""
    quote = None
    for j, ch in enumerate(cmd):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (j == 0 or cmd[j - 1].isspace()):
            return cmd[:j].strip()
    return cmd.strip()


BLOCKS = [(page, b) for page in PAGES for b in bash_blocks(page.read_text(encoding="utf-8"))]
ALL_COMMANDS = [c for _, b in BLOCKS for c, _ in b]


def test_not_run_list_is_current():
    assert ALL_COMMANDS, "no geoloc command found in the pages' bash blocks"
    stale = sorted(set(NOT_RUN) - set(ALL_COMMANDS))
    assert not stale, f"NOT_RUN names commands the pages no longer have: {stale}"
    stale = sorted(set(PACED) - set(ALL_COMMANDS))
    assert not stale, f"PACED names commands the pages no longer have: {stale}"
    for cmd, (page_pace, run_pace, _why) in PACED.items():
        assert cmd.endswith(page_pace) and run_pace.split()[0] == page_pace.split()[0], cmd


def test_every_page_with_commands_is_run_or_says_why():
    run = {p.name for p in PAGES if p.parent == DOCS}
    with_commands = {p.name for p in DOCS.rglob("*.md") if bash_blocks(p.read_text(encoding="utf-8"))}
    missing = sorted(with_commands - run - set(PAGES_NOT_RUN))
    assert not missing, f"docs pages with geoloc commands in bash blocks, neither run nor in PAGES_NOT_RUN: {missing}"
    stale = sorted(set(PAGES_NOT_RUN) - with_commands)
    assert not stale, f"PAGES_NOT_RUN names pages without geoloc commands: {stale}"
    assert not run & set(PAGES_NOT_RUN), "a page is both run and listed as not run"


def _env():
    env = dict(os.environ)
    bindir = str(Path(sys.executable).parent)
    env["PATH"] = bindir + os.pathsep + env.get("PATH", "")
    # a checkout run with PYTHONPATH (a worktree) keeps it; nothing else is set for the reader
    return env


def _geoloc_exe():
    exe = shutil.which("geoloc", path=str(Path(sys.executable).parent))
    assert exe, f"the geoloc entry point is not installed beside {sys.executable}"
    return exe


def _run_view(cmd: str, cwd: Path, env) -> str:
    """Start `geoloc view ...` on a free port and return its output once it serves."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    args = shlex.split(cmd) + ["--port", str(port)]
    p = subprocess.Popen(
        args, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )
    out = []
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            line = p.stdout.readline()
            if not line:
                break
            out.append(line)
            if f"127.0.0.1:{port}" in line:
                return "".join(out)
        raise AssertionError(f"{cmd!r} did not say where it serves:\n{''.join(out)[-2000:]}")
    finally:
        try:
            os.killpg(p.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        p.wait(timeout=30)


def _files(folder: Path) -> dict:
    return {f: f.stat().st_mtime_ns for f in folder.rglob("*") if f.is_file()}


def _text(path: Path, limit: int = 1 << 16) -> str:
    """The first ``limit`` bytes of a text file, else nothing."""
    try:
        return "\n" + path.read_bytes()[:limit].decode("utf-8")
    except (UnicodeDecodeError, OSError):
        return ""


def _block_ids():
    ids, seen = [], {}
    for page, _ in BLOCKS:
        seen[page.name] = seen.get(page.name, 0) + 1
        ids.append(f"{page.stem}-block{seen[page.name]}")
    return ids


@pytest.mark.parametrize("block", range(len(BLOCKS)), ids=_block_ids())
def test_docs_block_runs_from_an_empty_folder(block, tmp_path):
    _geoloc_exe()
    env = _env()
    page, commands = BLOCKS[block]
    for cmd, printed in commands:
        if cmd in NOT_RUN:
            continue
        before = _files(tmp_path)
        if cmd in PACED:
            page_pace, run_pace, _why = PACED[cmd]
            cmd = cmd[: -len(page_pace)] + run_pace
        if cmd.startswith("geoloc view "):
            out = _run_view(cmd, tmp_path, env)
        else:
            r = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
            out = r.stdout + r.stderr
            assert "Traceback" not in out, f"{cmd!r}:\n{out[-3000:]}"
            if "|" not in cmd:  # `... | head -1` ends its writer by SIGPIPE, by design
                assert r.returncode == 0, f"{cmd!r} exited {r.returncode}:\n{out[-3000:]}"
            else:
                assert r.stdout.strip(), f"{cmd!r} printed nothing:\n{out[-3000:]}"
        # what the page shows under a command is what it printed or the head of a text file
        # it wrote (the CSV lines under `replay --out`)
        written = [f for f, m in _files(tmp_path).items() if before.get(f) != m]
        norm = re.sub(r"\s+", " ", out + "".join(_text(f) for f in sorted(written)))
        for want in printed:
            # "..." elides part of a line: the pieces around it must appear, in order
            pos = 0
            for piece in (p.strip() for p in re.sub(r"\s+", " ", want).split("...")):
                k = norm.find(piece, pos) if piece else pos
                assert k >= 0, f"{cmd!r} no longer prints {piece!r} ({page.name}: {want!r}):\n{out[-3000:]}"
                pos = k + len(piece)
