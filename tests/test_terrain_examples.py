"""The terrain examples (examples/2*.py) run and show what they promise."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("2[0-9]_*.py"))


def run(path):
    r = subprocess.run([sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path):
    out = run(path)
    assert out.strip()
    if path.name.startswith("20_"):
        assert "N =  -26.79 m" in out and "N =   17.16 m" in out  # published EGM96 values
    if path.name.startswith("24_"):
        lines = {ln.split()[0]: ln for ln in out.splitlines()}
        assert "hidden = True" in lines["bisect"] and "hidden = False" in lines["exact"]


def test_there_are_terrain_examples():
    assert len(EXAMPLES) >= 6
