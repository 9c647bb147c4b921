"""One model of each thing, so that a fix lands once, read from the source like tests/project/test_architecture.py.

- A workflow or an analysis module does not open a DEM itself: it takes the
  :class:`geoloc.surfaces.base.Surface` its caller built (on the command line,
  ``geoloc.cli._options.surface_from_args``; in Python, ``surfaces.terrain.surface_for``).
- A first-phase ``Camera`` is a file format: a camera file loads as a ``FrameSensor``
  (``sensors.sensor_file.load_sensor``), and no module outside the file-format code
  asks ``isinstance(x, Camera)`` or imports ``Camera``.
- A mosaic is recognised by ``geoloc.surfaces.base.is_mosaic`` alone, not by its attributes.

Each rule walks every module's syntax tree, so a new module is covered without
editing this file; the KNOWN_* tables name what is still left to move and may only
shrink (each entry says why it is still there).
"""

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "geoloc"
VIZ = Path(__file__).resolve().parents[2] / "viz" / "geoloc_viz"  # the viewer package, read the same way

#: Calls that open a DEM file: ``DEM.open(...)``, ``DemMosaic.open(...)``, ``open_dem_or_mosaic(...)``,
#: and any ``open_dem(...)`` / ``x.open_dem(...)`` (a module's own wrapper of them).
DEM_OPENERS = {("DEM", "open"), ("DemMosaic", "open"), (None, "open_dem_or_mosaic"), (None, "open_dem")}

#: Modules read for DEM openers: every module of both packages but ``geoloc.surfaces``, where the
#: openers live (``SurfaceSpec.build`` / ``.raster()`` is the one way from a DEM's name to a DEM).
DEM_OPENER_SCOPE = (
    "geoloc.status",
    "geoloc.tomlio",
    "geoloc.assets",
    "geoloc.userfiles",
    "geoloc.extras",
    "geoloc.geodesy",
    "geoloc.frames",
    "geoloc.sensors",
    "geoloc.locate",
    "geoloc.io",
    "geoloc.analysis",
    "geoloc.workflows",
    "geoloc.cli",
    "geoloc_viz",
)

#: Modules in DEM_OPENER_SCOPE that still open a DEM, and why (may only shrink): none left. The
#: verbs (``geoloc rpc``, ``warm``, ``view``), the viewer's scene (``terrain_link``) and the rerun
#: recordings, which draw one raster, open it through the one way, ``SurfaceSpec(dem=...).raster()``
#: (a mosaic refused by name).
KNOWN_DEM_OPENERS: set = set()

#: Modules that are the first-phase camera file format (they may know the Camera type).
CAMERA_FORMAT = {"geoloc.sensors.camera", "geoloc.sensors.sensor_file"}

#: Modules still branching on ``isinstance(x, Camera)`` outside the file format (may only shrink).
KNOWN_CAMERA_CHECKS: set = set()

#: The package itself re-exports the camera file format's class for Python users (``from geoloc import
#: Camera``; ``geoloc.locate``'s example builds one), which every function takes as its sensor (``as_sensor``).
CAMERA_REEXPORT = {"geoloc"}

#: Modules outside the file format that still import ``Camera`` (may only shrink; a camera or sensor
#: file, or a Monte Carlo scenario's [camera] table, loads as a FrameSensor: ``sensor_file.load_sensor``,
#: ``sensor_from_dict``): none left.
KNOWN_CAMERA_IMPORTS: set = set()


def module_name(path: Path, base: Path = PKG) -> str:
    parts = list(path.relative_to(base.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(*packages):
    for base in (PKG, VIZ):
        yield from _modules(base, packages)


def _modules(base, packages):
    for path in sorted(base.rglob("*.py")):
        mod = module_name(path, base)
        if not packages or any(mod == p or mod.startswith(p + ".") for p in packages):
            yield mod, ast.parse(path.read_text(), filename=str(path))


def dem_opens(tree) -> list:
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Attribute):  # x.open(...): x a name, or a module's attribute (_dem.DEM.open)
            owner = (
                f.value.id
                if isinstance(f.value, ast.Name)
                else (f.value.attr if isinstance(f.value, ast.Attribute) else None)
            )
            key = (owner, f.attr)
        else:
            key = (None, f.id) if isinstance(f, ast.Name) else None
        if key in DEM_OPENERS or (key is not None and (None, key[1]) in DEM_OPENERS):
            out.append(node.lineno)
    return out


def camera_checks(tree) -> list:
    out = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("isinstance", "issubclass")
        ):
            if len(node.args) == 2 and "Camera" in {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)}:
                out.append(node.lineno)
    return out


def mosaic_attribute_checks(tree) -> list:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "getattr"):
            if (
                len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and node.args[1].value in ("with_solver", "cache")
            ):
                out.append(node.lineno)
    return out


#: Modules that still ask a surface for its ``.dem`` attribute (a mosaic has none): none left; a
#: surface's terrain is :func:`geoloc.surfaces.base.terrain_of`.
KNOWN_SURFACE_DEM_ASKS: set = set()


def surface_dem_asks(tree) -> list:
    """Lines that ask ``hasattr(x, "dem")``, or ``getattr(surface..., "dem")`` of a surface."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "getattr"):
            if len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and node.args[1].value == "dem":
                obj = node.args[0]
                if node.func.id == "hasattr" or (isinstance(obj, ast.Name) and "surface" in obj.id):
                    out.append(node.lineno)
    return out


def test_a_surface_is_asked_for_its_terrain_with_terrain_of():
    found = {
        mod: lines for mod, tree in modules() if mod != "geoloc.surfaces.base" and (lines := surface_dem_asks(tree))
    }
    new = {m: v for m, v in found.items() if m not in KNOWN_SURFACE_DEM_ASKS}
    assert not new, f"ask geoloc.surfaces.base.terrain_of(surface), not its .dem (a mosaic has none): {new}"
    gone = KNOWN_SURFACE_DEM_ASKS - set(found)
    assert not gone, f"mended: remove them from KNOWN_SURFACE_DEM_ASKS: {sorted(gone)}"


def test_no_workflow_or_analysis_opens_a_dem_itself():
    found = {mod: lines for mod, tree in modules(*DEM_OPENER_SCOPE) if (lines := dem_opens(tree))}
    new = {m: v for m, v in found.items() if m not in KNOWN_DEM_OPENERS}
    assert not new, f"these open a DEM themselves (take a Surface from the caller instead): {new}"
    gone = KNOWN_DEM_OPENERS - set(found)
    assert not gone, f"no longer open a DEM: remove them from KNOWN_DEM_OPENERS: {sorted(gone)}"


def test_no_camera_type_check_outside_the_file_format():
    found = {mod: lines for mod, tree in modules() if mod not in CAMERA_FORMAT and (lines := camera_checks(tree))}
    new = {m: v for m, v in found.items() if m not in KNOWN_CAMERA_CHECKS}
    assert not new, f"isinstance(..., Camera) outside the camera file format: {new}"
    gone = KNOWN_CAMERA_CHECKS - set(found)
    assert not gone, f"no longer check for a Camera: remove them from KNOWN_CAMERA_CHECKS: {sorted(gone)}"


def camera_imports(tree, mod: str) -> list:
    """Lines importing ``Camera`` (``from geoloc.sensors.camera import Camera``, ``from geoloc import Camera``)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in ("geoloc", "geoloc.sensors.camera", "geoloc.sensors"):
            if any(a.name == "Camera" for a in node.names):
                out.append(node.lineno)
    return out


def test_a_camera_file_loads_as_a_sensor_and_camera_is_imported_by_the_file_format_only(tmp_path):
    found = {
        mod: lines
        for mod, tree in modules()
        if mod not in CAMERA_FORMAT | CAMERA_REEXPORT and (lines := camera_imports(tree, mod))
    }
    new = {m: v for m, v in found.items() if m not in KNOWN_CAMERA_IMPORTS}
    assert not new, f"these import Camera outside the camera file format (load_sensor gives a FrameSensor): {new}"
    gone = KNOWN_CAMERA_IMPORTS - set(found)
    assert not gone, f"no longer import Camera: remove them from KNOWN_CAMERA_IMPORTS: {sorted(gone)}"
    from geoloc.assets import asset_path
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.sensor_file import load_sensor

    from geoloc.sensors.camera import Camera

    path = asset_path("cameras", "qiao2017.toml")
    cam = load_sensor(path)
    assert type(cam) is FrameSensor and cam == Camera.from_toml(path).to_sensor() and cam.lens.fx == 166841.0
    # the file's pixel pitch rides along (Monte Carlo's micrometre sources, calibrate --write-camera)
    with_pitch = tmp_path / "pitch.toml"
    with_pitch.write_text(path.read_text() + "\npixel_pitch_m = 7.0e-6\n")
    assert cam.pixel_pitch_m is None and load_sensor(with_pitch).pixel_pitch_m == 7.0e-6


#: The Python entrances where a first-phase ``Camera`` built in Python becomes its sensor
#: (``as_sensor``, or ``sensor_of`` for any sensor kind); everything behind them holds a Sensor.
#: Each is a function a user calls or an object a user builds (docs, examples):
CAMERA_ENTRANCES = {
    "geoloc.locate": "locate, line_of_sight, ground_to_pixel: the package's own API (geoloc.locate)",
    "geoloc.analysis.uncertainty": "propagate and monte_carlo (docs/uncertainty.md, examples/34)",
    "geoloc.analysis.triangulate": "triangulate (examples/35)",
    "geoloc.analysis.errormodel": "ErrorModel and its with_camera (examples/31-33)",
    "geoloc.workflows.ortho": "locate_frame, write_frame_geotiff, orthorectify "
    "(docs/tour_terrain.md, docs/ortho.md, examples/26)",
    "geoloc_viz.model": "the viewer's Scenario, converted once in __post_init__",
    "geoloc_viz.rerun_model": "steps_from_flight and steps_from_records (docs/rerun.md, examples/80-83)",
}


def sensor_conversions(tree) -> list:
    """Lines calling ``as_sensor(...)`` or ``sensor_of(...)`` (by name or as an attribute)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            if name in ("as_sensor", "sensor_of"):
                out.append(node.lineno)
    return out


def test_a_camera_becomes_a_sensor_only_at_the_python_entrances():
    found = {mod: lines for mod, tree in modules() if (lines := sensor_conversions(tree))}
    new = {m: v for m, v in found.items() if m not in CAMERA_ENTRANCES}
    assert not new, (
        "as_sensor/sensor_of behind the Python entrances (what reaches here is a Sensor "
        f"already; convert where the object is built): {new}"
    )
    gone = set(CAMERA_ENTRANCES) - set(found)
    assert not gone, f"no conversion left: remove them from CAMERA_ENTRANCES: {sorted(gone)}"


def test_a_mosaic_is_recognised_by_is_mosaic_only():
    found = {mod: lines for mod, tree in modules() if (lines := mosaic_attribute_checks(tree))}
    assert not found, f"recognise a mosaic with geoloc.surfaces.base.is_mosaic: {found}"


def test_the_checks_find_planted_cases():
    # each rule above must be able to fail
    tree = ast.parse(
        "from geoloc.surfaces.dem import DEM\n"
        "def f(p):\n"
        "    d = DEM.open(p)\n"
        "    m = open_dem_or_mosaic(p); mc.open_dem(p)\n"
        "    if isinstance(d, (Camera, int)): pass\n"
        "    from geoloc.sensors.camera import Camera\n"
        "    return hasattr(m, 'with_solver') or hasattr(m, 'dem') or getattr(surface, 'dem', None)\n"
        "s = as_sensor(c); t = camera.sensor_of(c)\n"
        "e = _dem.DEM.open(p)\n"
    )
    assert sorted(dem_opens(tree)) == [3, 4, 4, 9]
    assert camera_checks(tree) == [5]
    assert camera_imports(tree, "geoloc.x") == [6]
    assert mosaic_attribute_checks(tree) == [7]
    assert surface_dem_asks(tree) == [7, 7]
    assert sensor_conversions(tree) == [8, 8]


def test_the_rerun_recordings_raster_comes_from_the_one_way(tmp_path):
    """``SurfaceSpec.raster`` (the rerun recordings' DEM) is the raster ``build`` reads, and refuses a mosaic."""
    import pytest
    import rasterio

    from geoloc.assets import asset_path
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.spec import SurfaceSpec

    path = asset_path("dem", "srtm_jacksboro.tif")
    d = SurfaceSpec(dem=str(path), dem_datum="egm96").raster()
    with rasterio.open(path) as ds:  # GDAL's own reading of the file: the node grid
        assert isinstance(d, DEM) and d.shape == (ds.height, ds.width)
    assert SurfaceSpec().raster() is None
    for mosaic in (str(tmp_path), (str(path), str(path))):
        with pytest.raises(ValueError, match="is a mosaic"):
            SurfaceSpec(dem=mosaic).raster("--dem")
