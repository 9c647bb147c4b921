"""Survey of the imports inside functions in ``geoloc/`` and ``viz/geoloc_viz/`` (the rule in
docs/architecture.md, "Imports at the top").

Each in-function import is put in one class:

- ``optional``: its module is not a required dependency (an extra, the viewer's stack seen from
  the core): it stays in the function that needs it (``geoloc.extras.require``);
- ``loaded``: importing the module it sits in already loads its target (measured in a new
  interpreter): at the top it costs nothing, so it belongs there;
- ``cost``: importing the module does not load its target; the time importing the target adds
  is measured (a new interpreter: import the module, then time the target's import).

    python tools/import_survey.py [--json OUT]

One new interpreter per module (about a minute on an idle machine). Prints the counts per class.
"""

from __future__ import annotations

import ast
import collections
import importlib.util
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the import names of pyproject.toml's required dependencies (and what they bring: llvmlite, affine)
REQUIRED = {
    "numpy",
    "pyproj",
    "rasterio",
    "scipy",
    "numba",
    "matplotlib",
    "yaml",
    "pyogrio",
    "simplekml",
    "czml3",
    "defusedxml",
    "PIL",
    "mgrs",
    "llvmlite",
    "affine",
}
STDLIB = set(sys.stdlib_module_names)

PROBE = r"""
import importlib, json, sys, time
module, targets = sys.argv[1], json.loads(sys.argv[2])
importlib.import_module(module)
out = {}
there = {t for t in targets if t in sys.modules}  # before any target is imported here
for t in targets:
    if t in there:
        out[t] = 0.0
        continue
    t0 = time.perf_counter()
    try:
        importlib.import_module(t)
        out[t] = time.perf_counter() - t0
    except Exception:
        out[t] = None
print(json.dumps(out))
"""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    parts = parts[1:] if parts[0] == "viz" else parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def _target(node: ast.Import | ast.ImportFrom, module: str, package: bool) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if not node.level:
        base = node.module or ""
        subs = [
            f"{base}.{a.name}" for a in node.names if importlib.util.find_spec(base) and _is_module(f"{base}.{a.name}")
        ]
        return subs or [base]
    parts = module.split(".") if package else module.split(".")[:-1]
    parts = parts[: len(parts) - (node.level - 1)]
    return [".".join(parts + ([node.module] if node.module else []))]


def in_function_imports(path: Path) -> list[tuple[str, str, int, str]]:
    """(module, function, line, imported module) of each import inside a function of ``path``."""
    module, package = module_name(path), path.name == "__init__.py"
    out = []

    def visit(node, fn):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                visit(child, child.name)
            elif isinstance(child, (ast.Import, ast.ImportFrom)) and fn:
                out.extend((module, fn, child.lineno, t) for t in _target(child, module, package))
            else:
                visit(child, fn)

    visit(ast.parse(path.read_text()), None)
    return out


def survey() -> list[dict]:
    files = sorted((ROOT / "geoloc").rglob("*.py")) + sorted((ROOT / "viz" / "geoloc_viz").rglob("*.py"))
    by_module = collections.defaultdict(list)
    for path in files:
        for row in in_function_imports(path):
            by_module[row[0]].append(row)
    rows = []
    for module, found in sorted(by_module.items()):
        top = {t: t.split(".")[0] for *_, t in found}
        probe = sorted(t for t, p in top.items() if p in STDLIB or p in REQUIRED or p in ("geoloc", "geoloc_viz"))
        r = subprocess.run([sys.executable, "-c", PROBE, module, json.dumps(probe)], capture_output=True, text=True)
        measured = json.loads(r.stdout.splitlines()[-1]) if r.returncode == 0 and r.stdout.strip() else {}
        for _, fn, line, t in found:
            optional = top[t] not in STDLIB and top[t] not in REQUIRED and top[t] not in ("geoloc", "geoloc_viz")
            optional |= module.startswith("geoloc") and top[t] == "geoloc_viz"
            seconds = None if optional else measured.get(t)
            cls = "optional" if optional else "loaded" if seconds == 0.0 else "cost"
            rows.append(dict(module=module, function=fn, line=line, target=t, cls=cls, seconds=seconds))
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    rows = survey()
    counts = collections.Counter(r["cls"] for r in rows)
    modules = len({r["module"] for r in rows})
    print(
        f"in-function imports: {len(rows)} in {modules} modules; "
        + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    )
    cost = [r["seconds"] for r in rows if r["cls"] == "cost" and r["seconds"] is not None]
    if cost:
        print(
            f"cost: median {1e3 * statistics.median(cost):.0f} ms added to its module's import ({len(cost)} measured)"
        )
    if "--json" in argv:
        Path(argv[argv.index("--json") + 1]).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
