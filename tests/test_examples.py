"""Every numbered core example (examples/0*.py) runs and prints what it promises."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE_EXAMPLES = sorted((ROOT / "examples").glob("0*.py"))


@pytest.mark.parametrize("path", CORE_EXAMPLES, ids=lambda p: p.name)
def test_core_example_runs(path):
    r = subprocess.run([sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip()


def test_there_are_core_examples():
    assert len(CORE_EXAMPLES) >= 5
