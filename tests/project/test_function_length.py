"""No function of ``geoloc/`` or ``viz/geoloc_viz/`` is longer than ``tools/function_lengths.py``'s
``LIMIT`` lines, but those listed in ``tests/project/long_functions.txt``, and none of those grows.

The list holds each long function as it was when it was last measured: ``LINES path:qualname``.
It only shrinks: a listed function longer than its lines fails (split it, or the change that
lengthens it does); a listed function now within the limit, or gone, fails too, so that it
leaves the list and stays short. The length is ``tools/function_lengths.py``'s: ``def`` to the
body's last line, the docstring included, the decorators not.
"""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

from function_lengths import LIMIT, function_lengths, module_lengths  # noqa: E402

LONG_LIST = Path(__file__).with_name("long_functions.txt")


def _listed() -> dict[str, int]:
    out = {}
    for line in LONG_LIST.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            n, name = line.split()
            assert name not in out, f"{name} listed twice in {LONG_LIST.name}"
            out[name] = int(n)
    return out


@pytest.fixture(scope="module")
def lengths():
    # one parse of the trees for both checks (about 2 s of CPU)
    return function_lengths()


def test_no_function_is_longer_than_the_limit_or_its_listed_length(lengths):
    listed = _listed()
    unlisted = [f"{n} {k}" for k, n in lengths.items() if n > LIMIT and k not in listed]
    grown = [f"{k}: {lengths[k]} lines, listed at {n}" for k, n in listed.items() if lengths.get(k, 0) > n]
    assert not unlisted, f"longer than {LIMIT} lines: split into named steps (docs/conventions.md):\n" + "\n".join(
        unlisted
    )
    assert not grown, f"grown past its length in {LONG_LIST.name}:\n" + "\n".join(grown)


def test_the_list_only_shrinks(lengths):
    listed = _listed()
    short = [f"{k}: {lengths.get(k, 'gone')}" for k in listed if lengths.get(k, 0) <= LIMIT]
    shorter = [f"{lengths[k]} {k}" for k, n in listed.items() if LIMIT < lengths.get(k, 0) < n]
    assert not short, f"within {LIMIT} lines or gone now: take them out of {LONG_LIST.name}:\n" + "\n".join(short)
    assert not shorter, f"shorter now: write these lengths in {LONG_LIST.name}:\n" + "\n".join(shorter)


def test_lengths_are_counted_from_def_to_the_bodys_last_line(tmp_path):
    # a closed form: 1 def line, a 3-line docstring, 2 body lines; the decorator is not counted;
    # a nested function counts alone and inside its holder; a method is named by its class
    src = (
        "@decorator\n"
        "def f(x):\n"
        '    """One\n\n    three."""\n'
        "    def g():\n"
        "        return 1\n"
        "class C:\n"
        "    def m(self):\n"
        "        pass\n"
        "if True:\n"
        "    def h():\n"
        "        pass\n"
        "else:\n"
        "    def h():\n"
        "        a = 1\n"
        "        return a\n"
    )
    assert module_lengths(src) == {"f": 6, "f.g": 2, "C.m": 2, "h": 3}
    # over a tree: each function named by its file and qualname
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "sub" / "m.py").write_text(src)
    assert function_lengths(tmp_path, ("pkg",))["pkg/sub/m.py:C.m"] == 2
