"""The sensor file (TOML): ``[lens]``, ``[gimbal]``, ``[mount]``, ``[lever_arm]``, ``[boresight]``
(and optionally ``[columns]``, the column map of its records: ``docs/columns.md``, and
``[uncertainty]``, its error budget: :mod:`geoloc.sensors.budget`).

Format: ``docs/sensor_format.md``. The smallest file that works::

    [lens]
    model = "pinhole"
    fx = 1500.0
    fy = 1500.0
    cx = 640.0        # 1-based column of the principal point
    cy = 480.0        # 1-based row
    width = 1280
    height = 960

    [gimbal]
    preset = "azimuth-elevation"

The first-phase camera file (``focal_length_px``, ``principal_row``, ...) loads as
a :class:`FrameSensor` too, a pinhole on the [Q17] ``roll-pitch`` gimbal (the
:class:`~geoloc.sensors.camera.Camera` class is that file's reader and writer). Unknown keys, bad
values and missing keys are errors naming the key, the value and the file.
"""

from __future__ import annotations

import os
import math
from pathlib import Path

from geoloc.sensors.budget import ErrorBudget, budget_from_dict, budget_to_dict
from geoloc.sensors.camera import Camera
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import DEFAULT, PRESETS, gimbal_from_dict, gimbal_to_dict
from geoloc.sensors.lenses import lens_from_dict, lens_to_dict
from geoloc.tomlio import read_toml
from geoloc.userfiles import write_text
from geoloc.corrections import check_table

#: Top-level tables and keys of a sensor file.
TABLES = ("lens", "gimbal", "mount", "boresight", "lever_arm")
KEYS = ("name", "platform")
#: The optional table of a sensor (or first-phase camera) file that is not the sensor's: the
#: column map of the records its flights come in (``docs/columns.md``; read by
#: :func:`load_sensor_columns`, checked by ``geoloc.io.columns``, ignored by the sensor itself).
COLUMNS_TABLE = "columns"
#: The optional error budget of a sensor (or first-phase camera) file: 1-sigma errors, checked
#: against the sensor on load (:func:`geoloc.sensors.budget.budget_from_dict`), read by
#: :func:`load_sensor_budget`.
UNCERTAINTY_TABLE = "uncertainty"
#: The optional line-of-sight corrections of a sensor file (``refraction``, ``light_time``,
#: ``aberration``: docs/refraction.md), checked on load and read by :func:`load_sensor_corrections`;
#: the location pipeline applies them (the command line's options on top).
CORRECTIONS_TABLE = "corrections"


def _triple(table: dict, what: str, source: str, suffix: str, bound: float, unit: str) -> tuple:
    """``x<suffix>``, ``y<suffix>``, ``z<suffix>`` of a table (each optional, default 0), checked."""
    keys = tuple(f"{a}{suffix}" for a in "xyz")
    if not isinstance(table, dict):
        raise ValueError(f"{source}: [{what}] must be a table of {', '.join(keys)}, got {table!r}")
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise ValueError(f"{source}: [{what}] unknown key(s) {unknown}; allowed: {', '.join(keys)}")
    out = []
    for k in keys:
        v = table.get(k, 0.0)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= bound):
            raise ValueError(f"{source}: [{what}] {k} = {v!r}: must be a number of {unit}, |v| <= {bound:g}")
        out.append(float(v))
    return tuple(out)


def _angles(table: dict, what: str, source: str) -> tuple:
    """``x_deg``, ``y_deg``, ``z_deg`` -> radians (mount, boresight)."""
    return tuple(math.radians(v) for v in _triple(table, what, source, "_deg", 180.0, "degrees"))


def _lever(table: dict, source: str) -> tuple:
    """``x_m``, ``y_m``, ``z_m`` in body axes (forward, right, down) -> metres."""
    return _triple(table, "lever_arm", source, "_m", 1e3, "metres")


def sensor_from_dict(data: dict, source: str = "sensor") -> FrameSensor:
    """A :class:`FrameSensor` from the tables of a sensor file (or a first-phase camera file).

    A ``[columns]`` table (the records' column map) is not the sensor's and is left out here;
    an ``[uncertainty]`` table is checked against the sensor (unknown keys and bad values are
    errors naming them) and left out (:func:`budget_from_sensor_dict` reads it)."""
    data = _without_columns(data, source)
    if CORRECTIONS_TABLE in data:
        check_table(data[CORRECTIONS_TABLE], f"{source} [{CORRECTIONS_TABLE}]")
        data = {k: v for k, v in data.items() if k != CORRECTIONS_TABLE}
    if UNCERTAINTY_TABLE in data:
        rest = {k: v for k, v in data.items() if k != UNCERTAINTY_TABLE}
        sensor = sensor_from_dict(rest, source)
        budget_from_dict(data[UNCERTAINTY_TABLE], sensor, source)
        return sensor
    if "lens" not in data:
        _refuse_sensor_without_lens(data, source)
        return Camera.from_dict(data, source=source).to_sensor()
    unknown = sorted(set(data) - set(TABLES) - set(KEYS))
    if unknown:
        raise ValueError(
            f"{source}: unknown key(s) or table(s) {unknown}; allowed: {['[' + t + ']' for t in TABLES] + list(KEYS)}"
        )
    name = data.get("name", "")
    if not isinstance(name, str):
        raise ValueError(f"{source}: name = {name!r}: must be a string")
    platform = data.get("platform", "")
    if not isinstance(platform, str):
        raise ValueError(
            f'{source}: platform = {platform!r}: must be a string (e.g. "drone", '
            '"DJI Matrice 300 RTK", "King Air 350"; docs/sensor_format.md)'
        )
    lens = lens_from_dict(data["lens"], source=f"{source} [lens]")
    gimbal = gimbal_from_dict(data["gimbal"], source) if "gimbal" in data else PRESETS[DEFAULT]
    return FrameSensor(
        lens,
        gimbal,
        mount=_angles(data.get("mount", {}), "mount", source),
        boresight=_angles(data.get("boresight", {}), "boresight", source),
        lever_arm_m=_lever(data.get("lever_arm", {}), source),
        name=name,
        platform=platform,
    )


def load_sensor(path: str | os.PathLike[str]) -> FrameSensor:
    """Read a sensor file, or a first-phase camera file, by path: a :class:`FrameSensor` either way.

    A camera file (``focal_length_px``, ``principal_row``, ...; :class:`geoloc.sensors.camera.Camera`
    is its reader and writer) is a pinhole on the [Q17] ``roll-pitch`` gimbal, with the file's
    ``pixel_pitch_m``. Its ``[columns]`` and ``[uncertainty]`` tables are checked and left out
    (:func:`load_sensor_columns`, :func:`load_sensor_budget`)."""
    path = Path(path)
    return _naming_source(str(path), lambda: sensor_from_dict(read_toml(path, "sensor file"), source=str(path)))


def _naming_source(source: str, build):
    """``build()``, with a ValueError that does not name ``source`` (a first-phase camera's own check:
    "camera field focal_length_px = nan: ...", found by fuzzing) prefixed with it."""
    try:
        return build()
    except ValueError as e:
        if source in str(e):
            raise
        raise ValueError(f"{source}: {e}") from None


def budget_from_sensor_dict(data: dict, source: str = "sensor") -> ErrorBudget | None:
    """The checked ``[uncertainty]`` table of a sensor file's tables; None if it has none."""
    if UNCERTAINTY_TABLE not in data:
        return None
    rest = {k: v for k, v in _without_columns(data, source).items() if k != UNCERTAINTY_TABLE}
    return budget_from_dict(data[UNCERTAINTY_TABLE], sensor_from_dict(rest, source), source)


def load_sensor_budget(path: str | os.PathLike[str]) -> ErrorBudget | None:
    """The error budget (``[uncertainty]``) of a sensor (or first-phase camera) file; None if it has none."""
    path = Path(path)
    return budget_from_sensor_dict(read_toml(path, "sensor file"), source=str(path))


def _refuse_sensor_without_lens(data: dict, source: str) -> None:
    """A file with a sensor file's tables but no ``[lens]`` is a sensor file missing its lens,
    not a first-phase camera file with unknown keys: say so."""
    tables = [t for t in TABLES if t in data]
    if tables:
        raise ValueError(
            f"{source}: missing table [lens] (the file has "
            f"{', '.join('[' + t + ']' for t in tables)}, so it is a sensor file, and a "
            f"sensor file needs a [lens] table: model, fx, fy, cx, cy, width, height; "
            f"docs/sensor_format.md)"
        )


def _without_columns(data: dict, source: str) -> dict:
    if COLUMNS_TABLE not in data:
        return data
    if not isinstance(data[COLUMNS_TABLE], dict):
        raise ValueError(
            f"{source}: [{COLUMNS_TABLE}] must be a table (canonical name = column), got {data[COLUMNS_TABLE]!r}"
        )
    return {k: v for k, v in data.items() if k != COLUMNS_TABLE}


def load_sensor_columns(path: str | os.PathLike[str]) -> dict | None:
    """The ``[columns]`` table of a sensor (or first-phase camera) file, as read; None if it has none.

    The table is the column map of the records CSV flown with this sensor
    (``docs/columns.md``); ``geoloc.io.columns.ColumnMap.from_table`` checks it.
    """
    path = Path(path)
    data = read_toml(path, "sensor file")
    if COLUMNS_TABLE not in data:
        return None
    _without_columns(data, str(path))  # checks that it is a table
    return data[COLUMNS_TABLE]


def load_sensor_corrections(path: str | os.PathLike[str]) -> dict | None:
    """The checked ``[corrections]`` table of a sensor (or first-phase camera) file; None if it has none."""
    path = Path(path)
    data = read_toml(path, "sensor file")
    if CORRECTIONS_TABLE not in data:
        return None
    return check_table(data[CORRECTIONS_TABLE], f"{path} [{CORRECTIONS_TABLE}]")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    return repr(v)


def sensor_to_toml(
    sensor: FrameSensor,
    path: str | os.PathLike[str],
    budget: ErrorBudget | None = None,
    corrections: dict | None = None,
) -> None:
    """Write a sensor file that :func:`load_sensor` reads back to the same sensor (and
    :func:`load_sensor_budget` to ``budget``, :func:`load_sensor_corrections` to the
    ``[corrections]`` table ``corrections``, when given)."""
    lines = []
    if sensor.name:
        lines.append(f"name = {_toml_value(sensor.name)}")
    if getattr(sensor, "platform", ""):
        lines.append(f"platform = {_toml_value(sensor.platform)}")
    if lines:
        lines[-1] += "\n"
    tables = {
        "lens": lens_to_dict(sensor.lens),
        "gimbal": gimbal_to_dict(sensor.gimbal),
        "mount": {f"{a}_deg": math.degrees(v) for a, v in zip("xyz", sensor.mount)},
        "boresight": {f"{a}_deg": math.degrees(v) for a, v in zip("xyz", sensor.boresight)},
        "lever_arm": {f"{a}_m": v for a, v in zip("xyz", sensor.lever_arm_m)},
    }
    if budget is not None:
        tables[UNCERTAINTY_TABLE] = budget_to_dict(budget)
    if corrections is not None:
        tables[CORRECTIONS_TABLE] = check_table(corrections, f"{path} [{CORRECTIONS_TABLE}]")
    for t, d in tables.items():
        lines.append(f"[{t}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in d.items())
        lines.append("")
    write_text(path, "\n".join(lines))
