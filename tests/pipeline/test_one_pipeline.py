"""No locating code path outside the location pipeline, so that every correction applies everywhere: the grep, done with the AST.

Every call that meets a surface with a line of sight, in the core and the viewer, is one of
- a call in ``geoloc/surfaces/`` (the surfaces themselves) or ``geoloc/pipeline.py``;
- ``X.intersect(...)`` where X is a :class:`geoloc.pipeline.Pipeline` (``Pipeline(...)`` itself,
  or a name bound to one in the same module);
- the fused kernel ``locate_fast`` only in the pipeline (its executor) and its own module;
- one of :data:`EXCEPTIONS`, each with the reason it is not a location.

So a correction added to the pipeline reaches every path, and a new path that meets a
surface directly fails here, named by file, line and function.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCANNED = [ROOT / "geoloc", ROOT / "viz" / "geoloc_viz"]
#: Where surfaces are met by design: the surfaces themselves and the pipeline.
HOME = [ROOT / "geoloc" / "surfaces", ROOT / "geoloc" / "pipeline.py"]
#: Functions that meet a surface and are no location, each with why.
EXCEPTIONS = {
    (
        "viz/geoloc_viz/picture_model.py",
        "ground_pick",
        "intersect",
    ): "the browser's ray from the viewer's camera (a click in the 3D scene), not a sensor's line of sight",
    (
        "viz/geoloc_viz/terrain_link.py",
        "terrain_geometry",
        "intersect_los_height",
    ): "the teaching drawing: where the straight line crosses the heights the DEM iteration tries",
    (
        "geoloc/sensors/limb.py",
        "limb_tangent",
        "ray_inflated_ellipsoid",
    ): "the limb tangent solver's test that a limb ray meets the Earth (HITS_EARTH), no location",
}
#: Calls that meet a surface, by name.
SURFACE_FUNCTIONS = {
    "intersect_los_height",
    "intersect_dem",
    "ray_at_height",
    "ray_inflated_ellipsoid",
    "ray_geodetic_height",
    "locate_fast",
}
#: The fused kernel's own module may call it.
KERNEL_HOME = ROOT / "geoloc" / "sensors" / "_fastlocate.py"


def _files():
    for base in SCANNED:
        for p in sorted(base.rglob("*.py")):
            if any(p == h or h in p.parents for h in HOME):
                continue
            yield p


def _pipeline_names(tree) -> set:
    """Names bound to a Pipeline in the module: ``x = Pipeline(...)`` (or ``dataclasses.replace(pipe, ...)``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            f = node.value.func
            callee = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            if callee == "Pipeline":
                names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def _is_pipeline(expr, names) -> bool:
    if isinstance(expr, ast.Call):
        f = expr.func
        return (isinstance(f, ast.Name) and f.id == "Pipeline") or (
            isinstance(f, ast.Attribute) and f.attr == "replace" and expr.args and _is_pipeline(expr.args[0], names)
        )
    return isinstance(expr, ast.Name) and expr.id in names


def _enclosing(tree):
    """node -> name of the innermost enclosing function."""
    owner = {}

    def visit(node, fn):
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else fn
            owner[child] = name
            visit(child, name)

    visit(tree, "<module>")
    return owner


def _findings():
    out = []
    for p in _files():
        rel = p.relative_to(ROOT).as_posix()
        tree = ast.parse(p.read_text(), filename=rel)
        names = _pipeline_names(tree)
        owner = _enclosing(tree)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            what = None
            if isinstance(f, ast.Attribute) and f.attr == "intersect" and not _is_pipeline(f.value, names):
                what = "intersect"
            callee = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            if callee in SURFACE_FUNCTIONS and not (callee == "locate_fast" and p == KERNEL_HOME):
                what = callee
            if what is None:
                continue
            fn = owner.get(node, "<module>")
            if (rel, fn, what) in EXCEPTIONS:
                continue
            out.append(f"{rel}:{node.lineno} in {fn}(): {what} outside the pipeline")
    return out


def test_no_locating_path_outside_the_pipeline():
    found = _findings()
    assert not found, "meet the surface through geoloc.pipeline.Pipeline:\n" + "\n".join(found)


def test_the_exceptions_are_still_there():
    """An exception whose call is gone is removed from the list (it cannot go stale)."""
    seen = set()
    for p in _files():
        rel = p.relative_to(ROOT).as_posix()
        tree = ast.parse(p.read_text())
        owner = _enclosing(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                callee = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
                seen.add((rel, owner.get(node, "<module>"), callee))
    assert set(EXCEPTIONS) <= seen, sorted(set(EXCEPTIONS) - seen)


def test_the_check_catches_a_direct_call(tmp_path, monkeypatch):
    """The check itself: a module meeting a surface directly is found, one through a pipeline is not."""
    bad = tmp_path / "geoloc"
    bad.mkdir()
    (bad / "m.py").write_text(
        "def f(surface, los, pipe_src):\n"
        "    a = surface.intersect(los)\n"
        "    pipe = Pipeline(None, surface)\n"
        "    b = pipe.intersect(los)\n"
        "    c = Pipeline(None, surface).intersect(los)\n"
        "    d = intersect_dem(los, None, 'exact')\n"
    )
    monkeypatch.setattr(__import__(__name__), "SCANNED", [bad])
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    found = _findings()
    assert [x.split(" in ")[0] for x in found] == ["geoloc/m.py:2", "geoloc/m.py:6"], found
