"""The longest functions of ``geoloc/`` and ``viz/geoloc_viz/``, by lines.

A function's length is its lines from ``def`` to the last line of its body: the docstring, the
comments and blank lines inside it count, the decorators do not (``end_lineno - lineno + 1`` of
Python's ``ast``). A nested function counts in its own right and inside the one that holds it.
Its name is ``path:qualname`` (``geoloc/workflows/klv_replay.py:_replay``, a method
``...:KlvRead.take``, a nested one ``...:outer.inner``); where a module defines one name twice
(an ``if`` with two ``def``), the longer one is kept.

    python tools/function_lengths.py [--top N] [--over LINES]

``tests/project/test_function_length.py`` holds every function to :data:`LIMIT` lines, but the
ones listed in ``tests/project/long_functions.txt`` with the length each may not grow past.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The trees measured (the project's code; tests, tools and examples are not held to it).
TREES = ("geoloc", "viz/geoloc_viz")
#: A function longer than this is listed in tests/project/long_functions.txt or fails there.
LIMIT = 80


def _walk(node: ast.AST, prefix: str, out: dict[str, int]) -> None:
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}{child.name}"
            if not isinstance(child, ast.ClassDef):
                n = (child.end_lineno or child.lineno) - child.lineno + 1
                out[name] = max(out.get(name, 0), n)
            _walk(child, f"{name}.", out)
        else:  # a def inside an if / try / with keeps the enclosing name
            _walk(child, prefix, out)


def module_lengths(source: str) -> dict[str, int]:
    """``{qualname: lines}`` of every function in one module's source."""
    out: dict[str, int] = {}
    _walk(ast.parse(source), "", out)
    return out


def function_lengths(root: Path = ROOT, trees: tuple[str, ...] = TREES) -> dict[str, int]:
    """``{"path:qualname": lines}`` of every function under ``trees`` (paths relative to ``root``)."""
    out: dict[str, int] = {}
    for tree in trees:
        for path in sorted((root / tree).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            for name, n in module_lengths(path.read_text(encoding="utf-8")).items():
                out[f"{rel}:{name}"] = n
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--top", type=int, default=30, help="how many of the longest to print (default 30)")
    ap.add_argument("--over", type=int, default=None, help="print every function longer than this instead")
    a = ap.parse_args(argv)
    lengths = sorted(function_lengths().items(), key=lambda kv: (-kv[1], kv[0]))
    shown = [kv for kv in lengths if kv[1] > a.over] if a.over is not None else lengths[: a.top]
    for name, n in shown:
        print(f"{n:5d}  {name}")
    over = sum(n > LIMIT for _, n in lengths)
    print(f"{len(lengths)} functions, {over} over {LIMIT} lines, the longest {lengths[0][1] if lengths else 0}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
