"""The whole tree passes ruff's lint with the rules of ``pyproject.toml`` ([tool.ruff]), and is
laid out as ``ruff format`` lays it out.

The rules are pyflakes (unused imports and variables, undefined names, redefinitions) and
pycodestyle's errors; each ignore in the configuration says why. A finding fails the suite
with ruff's own report, file and line; ``.venv/bin/ruff check --fix`` mends most of them, and
``.venv/bin/ruff format`` mends every layout finding.
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TREE = ("geoloc", "viz", "tests", "examples", "benchmarks", "tools")


def test_ruff_finds_nothing():
    r = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", *TREE],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_would_find_a_planted_fault(tmp_path):
    # the check can fail: an unused import and an undefined name, under the project's configuration
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f():\n    return undefined_name\n")
    r = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"), str(bad)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1 and "F401" in r.stdout and "F821" in r.stdout, r.stdout + r.stderr


def test_ruff_format_would_change_nothing():
    r = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "--no-cache", *TREE],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, "run `.venv/bin/ruff format` to lay these out:\n" + r.stdout + r.stderr


def test_ruff_format_would_find_a_planted_layout(tmp_path):
    # the check can fail: single quotes and a cramped call, under the project's configuration
    bad = tmp_path / "bad.py"
    bad.write_text("x = f( 'a',1 )\n")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "ruff",
            "format",
            "--check",
            "--no-cache",
            "--config",
            str(ROOT / "pyproject.toml"),
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1 and "bad.py" in r.stdout, r.stdout + r.stderr
