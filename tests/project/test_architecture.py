"""docs/architecture.md is the map, and this test holds the territory to it.

The page's package table (``## Two packages``) and layer table (``## Layers and import
direction``) are read from the page itself, not copied here, so the map and the check cannot
drift apart. Then every module of both packages is read from the source, and every import
(function-local ones too, since a deferred import is still a dependency) is checked:

- every package and module the page names exists, and every module on disk is in a layer;
- a module imports its own layer and the ones below, never above (``geoloc_viz`` reads the
  core, never the reverse), and there is no import cycle between modules;
- the core imports no viser, rerun or ``geoloc_viz`` at run time, and the optional libraries
  of its extras only inside functions (``geoloc.extras.require``), never at a module's top.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "architecture.md"
#: Import roots of the two packages, and the folder each lives in.
ROOTS = {"geoloc": ROOT / "geoloc", "geoloc_viz": ROOT / "viz" / "geoloc_viz"}
#: The libraries of the core's extras and of the viewer (pyproject.toml, viz/pyproject.toml).
OPTIONAL = {"av", "cv2", "trimesh", "dask", "distributed", "pyarrow", "astropy", "erfa"}
VIEWER_LIBS = {"viser", "rerun"}

#: Import cycles allowed inside geoloc_viz: none.
KNOWN_VIZ_CYCLES: list = []


def _section(text: str, heading: str) -> str:
    m = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, f"docs/architecture.md has no section '## {heading}'"
    return m.group(1)


def _table_rows(section: str) -> list[list[str]]:
    rows = [
        [c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines() if line.startswith("|")
    ]
    return [r for r in rows[2:]]  # past the header and its rule


def doc_packages(text: str) -> dict:
    """Import name -> directory, from the page's package table."""
    out = {}
    for row in _table_rows(_section(text, "Two packages")):
        name, folder = re.findall(r"`([^`]+)`", row[0])[0], re.findall(r"`([^`]+)`", row[1])[0]
        out[name] = ROOT / folder
    return out


def doc_layers(text: str) -> dict:
    """Module or package prefix -> layer, from the page's layer table."""
    out = {}
    for row in _table_rows(_section(text, "Layers and import direction")):
        layer = int(row[0])
        for name in re.findall(r"`([^`]+)`", row[1]):
            out[name] = layer
    return out


TEXT = DOC.read_text()
PACKAGES = doc_packages(TEXT)
LAYERS = doc_layers(TEXT)


def module_name(path: Path, root: str) -> str:
    rel = path.relative_to(ROOTS[root].parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _exists(mod: str) -> bool:
    top, *rest = mod.split(".")
    base = ROOTS.get(top)
    if base is None:
        return False
    p = base.joinpath(*rest)
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


def layer_of(mod: str, layers: dict = LAYERS) -> int:
    best = None
    for prefix, layer in layers.items():
        if mod == prefix or mod.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    if best is None and mod == "geoloc":
        return 0  # the package root re-exports; checked on its own below
    assert best is not None, f"{mod} is in no layer of docs/architecture.md"
    return best[1]


def _tree(path: Path):
    return ast.parse(path.read_text(), filename=str(path))


def imports_of(path: Path, mod: str, tree=None) -> set:
    """Modules of the two packages imported anywhere in the file (names resolved to modules)."""
    tree = tree or _tree(path)
    is_pkg = path.name == "__init__.py"
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] in ROOTS)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] not in ROOTS:
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if _exists(sub) else target)
    return out


def sources() -> dict:
    """Module name -> path, for every module of both packages."""
    return {module_name(p, root): p for root, base in ROOTS.items() for p in sorted(base.rglob("*.py"))}


def graph() -> dict:
    return {mod: {m for m in imports_of(p, mod) if m != mod} for mod, p in sources().items()}


def upward_imports(g: dict, layers: dict) -> list:
    bad = []
    for mod, deps in g.items():
        if mod == "geoloc":
            continue
        for dep in deps:
            if layer_of(dep, layers) > layer_of(mod, layers):
                bad.append(f"{mod} (layer {layer_of(mod, layers)}) imports {dep} (layer {layer_of(dep, layers)})")
    return sorted(bad)


def test_the_page_names_both_packages_and_they_exist():
    assert set(PACKAGES) == set(ROOTS), PACKAGES
    for name, folder in PACKAGES.items():
        assert (folder / "__init__.py").exists(), f"{name}: no package at {folder}"
        assert folder == ROOTS[name]
    assert (ROOT / "viz" / "pyproject.toml").exists()  # the viewer installs on its own


def test_every_layer_the_page_names_exists_and_every_module_has_one():
    assert len(set(LAYERS.values())) >= 10, LAYERS  # the table really was read
    missing = [m for m in LAYERS if not _exists(m)]
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"
    mods = sources()
    assert len(mods) >= 60, "the walk found too few modules"
    for mod in mods:
        layer_of(mod)  # raises for a module in no layer


def test_every_module_imports_only_downwards():
    bad = upward_imports(graph(), LAYERS)
    assert not bad, "\n".join(bad)


def test_an_upward_import_is_caught():
    # the check must be able to fail: a core module reading the viewer, and a layer the page lost
    g = {"geoloc.surfaces.dem": {"geoloc_viz.app"}, "geoloc_viz.app": {"geoloc.surfaces.dem"}}
    assert upward_imports(g, LAYERS) == ["geoloc.surfaces.dem (layer 3) imports geoloc_viz.app (layer 9)"]
    with pytest.raises(AssertionError, match="in no layer"):
        layer_of("geoloc.sensors.frame", {k: v for k, v in LAYERS.items() if k != "geoloc.sensors"})


def test_the_package_root_reexports_only_the_core():
    deps = graph()["geoloc"]
    assert deps and all(d.startswith("geoloc.") and layer_of(d) <= 7 for d in deps), deps


def _cycles(g: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    sys.setrecursionlimit(10_000)
    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    g = graph()
    # a package __init__ that re-exports its modules is not a cycle with them
    g = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in g.items()}
    cycles = _cycles(g)
    core = [c for c in cycles if not all(m.startswith("geoloc_viz") for m in c)]
    assert not core, f"import cycles in the core: {core}"
    viz = sorted(sorted(c) for c in cycles if c not in core)
    assert viz == sorted(sorted(c) for c in KNOWN_VIZ_CYCLES), (
        f"viz cycles changed: {viz}; update KNOWN_VIZ_CYCLES (it may only shrink)"
    )


def test_cycle_finder_finds_a_planted_cycle():
    # the check above must be able to fail
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def _top_level_imports(tree) -> set:
    """Top-level names imported at a module's top (not inside a function or class)."""
    out = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def _all_imports(tree) -> set:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def test_the_core_imports_optional_libraries_only_inside_functions():
    bad, viewer = [], []
    for mod, path in sources().items():
        if not mod.startswith("geoloc.") and mod != "geoloc":
            continue
        tree = _tree(path)
        bad += [f"{mod}: {lib}" for lib in sorted(_top_level_imports(tree) & OPTIONAL)]
        viewer += [f"{mod}: {lib}" for lib in sorted(_all_imports(tree) & VIEWER_LIBS)]
    assert not bad, f"the core imports an extra's library at a module's top: {bad}"
    assert not viewer, f"the core imports the viewer's libraries: {viewer}"


def test_core_modules_import_no_viser_rerun_or_viz():
    core = sorted(m for m in sources() if m.startswith("geoloc.") and not m.endswith("__main__"))
    code = (
        "import importlib, sys\n"
        f"for m in {core!r}: importlib.import_module(m)\n"
        "bad = sorted(k for k in sys.modules if k.split('.')[0] in ('viser', 'rerun', 'geoloc_viz'))\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"core pulled in: {r.stdout.strip()[:500]}"
    assert len(core) >= 30  # the walk really found the core modules


def doc_test_folders(text: str) -> dict:
    """The ``## Tests laid out like the code`` table: folder -> what it tests."""
    rows = _table_rows(_section(text, "Tests laid out like the code"))
    return {r[0].strip("`"): r[1] for r in rows}


def layout_faults(tests_dir: Path, folders: dict, pythonpath: list) -> list:
    """What breaks the tests' layout: a test file at the top, a folder the page does not name,
    a named folder missing, or one off ``pythonpath``."""
    faults = [f"{p.name}: a test at tests/ itself" for p in sorted(tests_dir.glob("test_*.py"))]
    have = {p.parent.name for p in tests_dir.glob("*/test_*.py")}
    faults += [f"tests/{d}/: not in the page's table" for d in sorted(have - set(folders))]
    faults += [f"tests/{d}/: named by the page, holds no test" for d in sorted(set(folders) - have)]
    faults += [f"tests/{d}/: not on pythonpath" for d in sorted(have) if f"tests/{d}" not in pythonpath]
    names = [p.name for p in tests_dir.glob("*/test_*.py")]
    faults += [f"{n}: the same module name in two folders" for n in sorted({n for n in names if names.count(n) > 1})]
    return faults


def _pythonpath() -> list:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["pythonpath"]


def test_tests_are_laid_out_as_the_page_says():
    folders = doc_test_folders(DOC.read_text(encoding="utf-8"))
    assert {"geodesy", "sensors", "surfaces", "viz", "project"} <= set(folders), folders
    assert layout_faults(ROOT / "tests", folders, _pythonpath()) == []


def test_a_misplaced_test_is_caught(tmp_path):
    (tmp_path / "sensors").mkdir()
    (tmp_path / "sensors" / "test_a.py").write_text("")
    (tmp_path / "stray").mkdir()
    (tmp_path / "stray" / "test_a.py").write_text("")
    (tmp_path / "test_top.py").write_text("")
    faults = layout_faults(tmp_path, {"sensors": "", "viz": ""}, ["tests/sensors"])
    assert faults == [
        "test_top.py: a test at tests/ itself",
        "tests/stray/: not in the page's table",
        "tests/viz/: named by the page, holds no test",
        "tests/stray/: not on pythonpath",
        "test_a.py: the same module name in two folders",
    ], faults
