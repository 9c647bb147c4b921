"""The limb examples (examples/4x_*.py) run and print the figures docs/limb.md quotes."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# (example, strings its output must contain). The figures are those of docs/limb.md, which
# the tests in test_limb.py establish against constructed lines; here we check the examples
# still print them (rounded as printed).
CASES = [
    ("40_limb_tangent_one_line.py", ["difference L18-exact       -1.4083 mm", "exact tangent height    40000.0000 m"]),
    ("41_limb_l18_chain.py", ["eq. 11 V_ECEF", "eq. 7-10"]),
    ("42_limb_newton_raphson.py", ["status: ok", "with max_iter=2: status iteration did not converge"]),
    (
        "43_limb_virtual_ellipsoid_error.py",
        ["   100 |      336.31          8.720", "    60 |      201.78          3.159"],
    ),
    ("44_limb_scenario.py", ["   47     1.175          0     75.86     85.85              6.415"]),
]


@pytest.mark.parametrize("name, expected", CASES, ids=[c[0] for c in CASES])
def test_limb_example(name, expected):
    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / name)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    for s in expected:
        assert s in r.stdout, (s, r.stdout[-2000:])
