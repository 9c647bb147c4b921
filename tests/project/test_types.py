"""The type checker (mypy, configured in ``pyproject.toml`` [tool.mypy]) finds nothing in
``geoloc/``, ``viz/geoloc_viz/`` and ``tools/``, and every public function of the core says its types.

mypy checks the annotated functions' bodies and every call into them. The modules whose findings
were not yet mended when the check came in are listed in [tool.mypy]'s ``ignore_errors`` override;
the list only shrinks: a listed module in which mypy finds nothing fails here, so that it leaves
the list and stays clean. The list is empty now and the override gone: mypy finds nothing in either
package. One mypy run serves both checks: it is run with any such override taken out, and its
findings are sorted into the listed modules and the others.

Public functions of the core (a name without a leading underscore, in a module and class whose
names have none) annotate every parameter and the return (``__init__`` its parameters). Those
that did not yet when this check came in are listed in ``tests/project/untyped_public_functions.txt``;
that list only shrinks too.

The full run keeps mypy's cache in the user's cache folder (``$XDG_CACHE_HOME/geoloc/mypy``,
``~/.cache/geoloc/mypy``), beside geoloc's compiled kernels, so a second run, from this checkout or
a fresh clone elsewhere, re-checks only what changed: 65 s of CPU without a cache (mypy 2.4.1, 160
files with the libraries' stubs, load 9-13), 0.7 s on an unchanged tree and 1.1 s from a fresh
clone in another folder. mypy keys each module's entry on its source's hash when the path or mtime
differs (a clone, a checkout), on its options and mypy's version, and re-checks the modules that
depend on a changed one; a fault planted in a clone with the cache warm gave the same findings as
a run without a cache (10.6 s of CPU). One run at a time uses the folder (a lock file: another
suite's run on the same machine fills it meanwhile). The planted-fault run keeps a cache of its own
in a temporary folder (``--no-incremental``).
"""

import ast
import fcntl
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
UNTYPED_LIST = Path(__file__).with_name("untyped_public_functions.txt")
FINDING = re.compile(r"^(?P<path>[^:\s]+\.py):(?P<line>\d+): error: (?P<text>.*)$", re.M)


def _config():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]


def _not_yet_mended(config) -> list[str]:
    lists = [o["module"] for o in config.get("overrides", []) if o.get("ignore_errors")]
    assert len(lists) <= 1, "at most one ignore_errors override in [tool.mypy], the modules not yet mended"
    return lists[0] if lists else []


def _module_of(path: str) -> str:
    parts = Path(path).with_suffix("").parts
    parts = parts[1:] if parts[0] == "viz" else parts
    parts = parts[:-1] if parts[-1] == "__init__" else parts
    return ".".join(parts)


def mypy_cache_dir() -> Path:
    """The user's folder for mypy's cache of this project (``$XDG_CACHE_HOME/geoloc/mypy``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "geoloc" / "mypy"


def _mypy(config_text: str, tmp_path, *paths, cache: Path | None = None) -> subprocess.CompletedProcess:
    """mypy under ``config_text``; with ``cache``, incremental in that folder (one run at a time
    holds it), else without a cache."""
    cfg = tmp_path / "mypy.toml"
    cfg.write_text(config_text)
    if cache is None:
        where = ["--no-incremental", "--cache-dir", str(tmp_path / "cache")]
    else:
        where = ["--cache-dir", str(cache)]
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(cfg), *where, *paths]
    # a full check without a cache is about 65 s of CPU; at a load of 20 on two cores two runs
    # took over 600 s
    if cache is None:
        return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1200)
    cache.mkdir(parents=True, exist_ok=True)
    with open(cache / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1200)


def _without_the_list(text: str) -> str:
    """pyproject.toml's text with the ignore_errors override taken out (the rest kept as written)."""
    if "ignore_errors = true" not in text:  # every module mended: no list
        return text
    start = text.index("ignore_errors = true")
    head = text.rindex("[[tool.mypy.overrides]]", 0, start)
    return text[:head] + text[start + len("ignore_errors = true") :]


def test_mypy_finds_nothing_outside_the_list_and_something_in_each_listed_module(tmp_path):
    text = (ROOT / "pyproject.toml").read_text()
    listed = _not_yet_mended(_config())
    r = _mypy(_without_the_list(text), tmp_path, cache=mypy_cache_dir())
    assert r.returncode in (0, 1), r.stdout + r.stderr  # 2: mypy itself failed (configuration, crash)
    found = FINDING.findall(r.stdout)
    outside = [f"{p}:{n}: {t}" for p, n, t in found if _module_of(p) not in listed]
    assert not outside, "mypy's findings (pyproject.toml [tool.mypy]):\n" + "\n".join(outside)
    dirty = {_module_of(p) for p, _, _ in found}
    clean = sorted(set(listed) - dirty)
    assert not clean, f"mypy finds nothing in these now: take them out of [tool.mypy]'s ignore_errors list: {clean}"


def test_mypy_would_find_a_planted_fault(tmp_path):
    # the check can fail: a return of the wrong type and an attribute that does not exist, under
    # the project's configuration
    bad = tmp_path / "bad.py"
    bad.write_text("def f(x: int) -> str:\n    return x\n\n\ndef g(s: str) -> int:\n    return s.nope\n")
    r = _mypy((ROOT / "pyproject.toml").read_text(), tmp_path, str(bad))
    assert r.returncode == 1 and "[return-value]" in r.stdout and "[attr-defined]" in r.stdout, r.stdout + r.stderr


def _untyped_public(tree: ast.Module, module: str) -> list[str]:
    out = []

    def walk(body, prefix):
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if node.name.startswith("_") and node.name != "__init__":
                    continue
                a = node.args
                params = a.posonlyargs + a.args + a.kwonlyargs + [p for p in (a.vararg, a.kwarg) if p]
                params = [p for p in params if p.arg not in ("self", "cls")]
                untyped = any(p.annotation is None for p in params)
                if untyped or (node.returns is None and node.name != "__init__"):
                    out.append(f"{module}:{prefix}{node.name}")
            elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                walk(node.body, f"{prefix}{node.name}.")

    walk(tree.body, "")
    return out


def untyped_public_functions(root: Path = ROOT) -> list[str]:
    """``module:qualname`` of each public function of the core that leaves a parameter or its
    return without an annotation."""
    out = []
    for path in sorted((root / "geoloc").rglob("*.py")):
        rel = path.relative_to(root).with_suffix("").parts
        if any(p.startswith("_") and p != "__init__" for p in rel):
            continue
        out += _untyped_public(ast.parse(path.read_text()), _module_of(str(path.relative_to(root))))
    return out


def _listed() -> list[str]:
    lines = UNTYPED_LIST.read_text().splitlines()
    return [s for s in (line.strip() for line in lines) if s and not s.startswith("#")]


def test_public_functions_of_the_core_are_annotated():
    found = set(untyped_public_functions())
    listed = set(_listed())
    new = sorted(found - listed)
    assert not new, "annotate the parameters and return of these public functions:\n" + "\n".join(new)
    done = sorted(listed - found)
    assert not done, f"annotated or gone now: take them out of {UNTYPED_LIST.name}:\n" + "\n".join(done)


@pytest.mark.parametrize(
    "source, untyped",
    [
        ("def f(x: int) -> int:\n    return x\n", []),
        ("def f(x) -> int:\n    return x\n", ["m:f"]),
        ("def f(x: int):\n    return x\n", ["m:f"]),
        ("def _f(x):\n    return x\n", []),
        ("class C:\n    def __init__(self, x: int):\n        pass\n    def g(self, *a):\n        pass\n", ["m:C.g"]),
        ("class _C:\n    def g(self, x):\n        pass\n", []),
    ],
)
def test_the_annotation_walk_sees_a_missing_annotation(source, untyped):
    # the walk can fail: a parameter or return left bare is found, a private name is not
    assert _untyped_public(ast.parse(source), "m") == untyped
