"""Import direction and cycles, as docs/architecture.md lays them down.

Every import in geoloc/ is read from the source (function-local ones too, since
a deferred import is still a dependency) and checked against the layers: a
module may import its own layer and the ones below, never above. The core
(layers 0-7) must not pull in viser, rerun or geoloc.viz at run time either.
"""

import ast
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "geoloc"

#: Module or package prefix -> layer (docs/architecture.md, "Layers and import direction").
LAYERS = {
    "geoloc": 0,  # the package's own __init__ re-exports; checked separately below
    "geoloc.status": 0, "geoloc.tomlio": 0, "geoloc.assets": 0, "geoloc.userfiles": 0, "geoloc.__main__": 8,
    "geoloc.geodesy": 1,
    "geoloc.frames": 2,
    "geoloc.surfaces": 3,
    "geoloc.sensors": 4,
    "geoloc.locate": 5, "geoloc.io": 5,
    "geoloc.analysis": 6,
    "geoloc.workflows": 7,
    "geoloc.cli": 8,
    "geoloc.viz": 9,
}

#: Import cycles allowed inside geoloc.viz: none (the two that predated the layout,
#: model/scenario/terrain_link and rerun_log/rerun_model/rerun_terrain, are untangled).
KNOWN_VIZ_CYCLES: list = []


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def layer_of(mod: str) -> int:
    best = None
    for prefix, layer in LAYERS.items():
        if mod == prefix or mod.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    assert best is not None, f"{mod} is in no layer of docs/architecture.md"
    return best[1]


def imports_of(path: Path, mod: str) -> set:
    """geoloc modules imported anywhere in the file (names resolved to modules where they are)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "geoloc")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "geoloc":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if (PKG.parent / Path(*sub.split("."))).with_suffix(".py").exists()
                        or (PKG.parent / Path(*sub.split(".")) / "__init__.py").exists() else target)
    return out


def graph() -> dict:
    g = {}
    for path in sorted(PKG.rglob("*.py")):
        mod = module_name(path)
        g[mod] = {m for m in imports_of(path, mod) if m != mod}
    return g


def test_every_module_has_a_layer_and_imports_only_downwards():
    g = graph()
    assert len(g) >= 40, "the walk found too few modules"
    bad = []
    for mod, deps in g.items():
        if mod == "geoloc":
            continue
        for dep in deps:
            if layer_of(dep) > layer_of(mod) and not (mod.startswith("geoloc.cli.") and dep.startswith("geoloc.viz")):
                bad.append(f"{mod} (layer {layer_of(mod)}) imports {dep} (layer {layer_of(dep)})")
            if mod.startswith("geoloc.viz") and dep.startswith("geoloc.cli"):
                bad.append(f"{mod} imports the command line {dep}")
    assert not bad, "\n".join(sorted(bad))


def test_the_package_root_reexports_only_the_core():
    deps = graph()["geoloc"]
    assert deps and all(layer_of(d) <= 7 for d in deps), deps


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
    core = [c for c in cycles if not all(m.startswith("geoloc.viz") for m in c)]
    assert not core, f"import cycles in the core: {core}"
    viz = sorted(sorted(c) for c in cycles if c not in core)
    assert viz == sorted(sorted(c) for c in KNOWN_VIZ_CYCLES), (
        f"viz cycles changed: {viz}; update KNOWN_VIZ_CYCLES (it may only shrink)")


def test_cycle_finder_finds_a_planted_cycle():
    # the check above must be able to fail
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def test_core_modules_import_no_viser_rerun_or_viz():
    core = sorted(m for m in graph() if layer_of(m) <= 7)
    code = (
        "import importlib, sys\n"
        f"for m in {core!r}: importlib.import_module(m)\n"
        "bad = sorted(k for k in sys.modules if k.split('.')[0] in ('viser', 'rerun')"
        " or k.startswith('geoloc.viz'))\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"core pulled in: {r.stdout.strip()[:500]}"
    assert len(core) >= 30  # the walk really found the core modules
