"""Column maps: any CSV's column names and units onto the records' canonical columns.

A column map (``docs/columns.md``) says which of the user's columns hold the
pose (``ac_lat_deg, ac_lon_deg, ac_h_m, heading_deg, pitch_deg, roll_deg``),
the sensor gimbal's joint angles (``<angle>_deg``), the pixel (``row, col``),
the truth and published positions, and in which units and vertical datum::

    [columns]
    ac_lat_deg = "Latitude"
    ac_h_m = {column = "Alt_ft", unit = "ft", datum = "egm96"}
    heading_deg = {column = "Yaw", unit = "rad"}
    col = {column = "PixelX", pixel = "zero-based"}

It comes from ``--columns map.toml`` or from the ``[columns]`` table of the
sensor file. :func:`geoloc.io.records.load_records` applies it row by row
before validation (:class:`ColumnPlan`), so a bad row is still reported with
its line number and the good ones run; the user's columns are carried through.

Units: angles ``deg`` | ``rad``; lengths ``m`` | ``ft`` (international foot,
0.3048 m). Heights have a vertical datum, ``ellipsoid`` (WGS 84) or ``egm96``
(MSL: orthometric above the EGM96 geoid, made ellipsoidal with the bundled
grid, h = H + N, :func:`geoloc.geodesy.geoid.egm96_undulation`). Pixels are
``one-based`` centres (the project's, the default) or ``zero-based`` centres
(OpenCV's: + 1 on the way in). Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.tomlio import read_toml

#: Angle units and their size in degrees (rad: converted with ``math.degrees``).
ANGLE_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi}
#: Length units and their size in metres (ft: the international foot).
LENGTH_UNITS = {"m": 1.0, "ft": 0.3048}
#: Vertical datums of a height column.
DATUMS = ("ellipsoid", "egm96")
#: Pixel conventions of a row/col column.
PIXELS = ("one-based", "zero-based")

#: The datum of every height the records hold after loading (and of every output height);
#: the same text as :data:`geoloc.io.gis.ELLIPSOID_DATUM`, which reads it back.
ELLIPSOID_DATUM = "ellipsoid (WGS 84)"
#: How each datum is named in messages and outputs.
DATUM_TEXT = {"ellipsoid": "ellipsoid (WGS 84)", "egm96": "egm96 (MSL, orthometric)"}

#: Canonical columns by group (the angles of the sensor's gimbal come on top).
TEXT_COLUMNS = ("table", "point")
PIXEL_COLUMNS = ("row", "col")
POSE_COLUMNS = ("ac_lat_deg", "ac_lon_deg", "ac_h_m", "heading_deg", "pitch_deg", "roll_deg")
TRUTH_COLUMNS = ("truth_lat_deg", "truth_lon_deg", "truth_h_m")
PAPER_COLUMNS = ("paper_lat_deg", "paper_lon_deg", "paper_height_m", "paper_error_m")
#: Height columns and the (latitude, longitude) columns of the point each is the height of
#: (where N is taken for an ``egm96`` height).
HEIGHT_COLUMNS = {
    "ac_h_m": ("ac_lat_deg", "ac_lon_deg"),
    "truth_h_m": ("truth_lat_deg", "truth_lon_deg"),
    "paper_height_m": ("paper_lat_deg", "paper_lon_deg"),
}
#: The output columns that state the heights' datums.
H_DATUM_COLUMN = "h_datum"
AC_H_DATUM_COLUMN = "ac_h_datum_input"
#: Suffix of a file column renamed because the map redefines its (canonical) name.
INPUT_SUFFIX = "_input"
#: Who stated the aircraft heights' datum when only the file's own ``h_datum`` column did.
FILE_STATED = "the file's h_datum column"

_FIXED = TEXT_COLUMNS + PIXEL_COLUMNS + POSE_COLUMNS + TRUTH_COLUMNS + PAPER_COLUMNS
_KEYS = {
    "text": {"column"},
    "pixel": {"column", "pixel"},
    "angle": {"column", "unit"},
    "length": {"column", "unit"},
    "height": {"column", "unit", "datum"},
}


def column_kind(name: str) -> str | None:
    """``text``, ``pixel``, ``angle``, ``length`` or ``height`` for a canonical-looking name, else None."""
    if name in HEIGHT_COLUMNS:
        return "height"
    if name in PIXEL_COLUMNS:
        return "pixel"
    if name in TEXT_COLUMNS:
        return "text"
    if name.endswith("_deg"):
        return "angle"
    if name in PAPER_COLUMNS and name.endswith("_m"):
        return "length"
    return None


def canonical_names(angles: Sequence[str] = ()) -> tuple:
    """Every canonical column a map may name, for a gimbal with joint ``angles``."""
    out = list(TEXT_COLUMNS + PIXEL_COLUMNS + POSE_COLUMNS)
    out += [f"{a}_deg" for a in angles if f"{a}_deg" not in out]
    return tuple(out) + TRUTH_COLUMNS + PAPER_COLUMNS


def _datum_of_text(text: str) -> str | None:
    """The datum an ``h_datum`` cell names (the vocabulary of :mod:`geoloc.io.gis`), None if unknown."""
    t = text.lower()
    if any(s in t for s in ("egm96", "orthometric", "geoid", "msl", "sea level", "5773")):
        return "egm96"
    if any(s in t for s in ("ellipsoid", "wgs 84", "wgs84", "wgs-84", "4979")):
        return "ellipsoid"
    return None


@dataclass(frozen=True)
class ColumnSpec:
    """One entry of a column map: canonical ``name`` <- the file's ``column``.

    ``unit``, ``datum`` and ``pixel`` are None where the map does not say
    (then: deg or m, ``ellipsoid`` unless ``--altitude-datum`` says otherwise, ``one-based``).
    """

    name: str
    column: str
    unit: str | None = None
    datum: str | None = None
    pixel: str | None = None

    @property
    def kind(self) -> str | None:
        return column_kind(self.name)

    def converts(self) -> bool:
        """True if the value changes on the way in (unit or pixel convention; the datum apart)."""
        return self.unit in ("rad", "ft") or self.pixel == "zero-based"

    def convert(self, v: float) -> float:
        """A value in the file's unit/convention -> canonical (deg, m, 1-based), before any datum."""
        if self.unit == "rad":
            return math.degrees(v)
        if self.unit == "ft":
            return v * LENGTH_UNITS["ft"]
        if self.pixel == "zero-based":
            return v + 1.0
        return v

    def describe(self) -> str:
        bits = [f"column {self.column!r}"]
        bits += [x for x in (self.unit, self.datum, self.pixel) if x]
        return ", ".join(bits)


@dataclass(frozen=True)
class ColumnMap:
    """A validated column map: canonical name -> :class:`ColumnSpec`, in the file's order."""

    specs: dict
    source: str = "column map"

    def __contains__(self, name) -> bool:
        return name in self.specs

    def __getitem__(self, name) -> ColumnSpec:
        return self.specs[name]

    def __len__(self) -> int:
        return len(self.specs)

    @classmethod
    def from_table(cls, table: Mapping[str, Any], source: str = "column map") -> ColumnMap:
        """From the ``[columns]`` table (a dict); errors name the key and the value."""
        where = f"{source} [columns]"
        if not isinstance(table, dict):
            raise ValueError(f"{where}: must be a table of canonical name = column, got {table!r}")
        specs = {}
        for name, entry in table.items():
            kind = column_kind(name)
            if kind is None:
                raise ValueError(
                    f"{where}: unknown canonical column {name!r} (= {entry!r}); the names are "
                    f"{list(_FIXED)} and <angle>_deg for each joint angle of the sensor's gimbal"
                )
            if isinstance(entry, str):
                entry = {"column": entry}
            if not isinstance(entry, dict):
                raise ValueError(
                    f"{where}: {name} = {entry!r}: must be a column name (a string) or a "
                    "table {column = ..., unit = ...}"
                )
            unknown = sorted(set(entry) - _KEYS[kind])
            if unknown:
                raise ValueError(
                    f"{where}: {name} = {entry!r}: key(s) {unknown} not allowed for "
                    f"{name} (a column of kind {kind}); allowed: {sorted(_KEYS[kind])}"
                )
            col = entry.get("column")
            if not isinstance(col, str) or not col.strip():
                raise ValueError(f"{where}: {name}: column = {col!r}: must be the name of a column of the file")
            unit, datum, pixel = entry.get("unit"), entry.get("datum"), entry.get("pixel")
            if unit is not None:
                units = ANGLE_UNITS if kind == "angle" else LENGTH_UNITS
                if unit not in units:
                    raise ValueError(
                        f"{where}: {name}: unit = {unit!r} is not {'an angle' if kind == 'angle' else 'a length'} "
                        f"unit; use one of {list(units)}"
                        + (" (ft: the international foot, 0.3048 m)" if kind != "angle" else "")
                    )
            if datum is not None and datum not in DATUMS:
                raise ValueError(
                    f"{where}: {name}: datum = {datum!r} is not a vertical datum; use "
                    f"'ellipsoid' (WGS 84) or 'egm96' (MSL, orthometric: the usual 'altitude')"
                )
            if pixel is not None and pixel not in PIXELS:
                raise ValueError(
                    f"{where}: {name}: pixel = {pixel!r} is not a pixel convention; use "
                    "'one-based' (the project's, pixel (1, 1) the top-left centre) or "
                    "'zero-based' (OpenCV's, (0, 0) the top-left centre)"
                )
            specs[name] = ColumnSpec(name, col.strip(), unit, datum, pixel)
        return cls(specs, source)

    def check_names(self, angles: Sequence[str]) -> None:
        """Every name canonical for a gimbal with joint ``angles``; errors name the key."""
        known = set(canonical_names(angles))
        for name, spec in self.specs.items():
            if name not in known:
                raise ValueError(
                    f"{self.source} [columns]: {name} = {spec.column!r}: the sensor's gimbal has no joint "
                    f"angle {name[:-4]!r}; its angles are {list(angles)} (columns "
                    f"{[f'{a}_deg' for a in angles]})"
                )


def load_column_map(path: str | os.PathLike[str]) -> ColumnMap:
    """Read a column-map TOML file: one ``[columns]`` table (``docs/columns.md``)."""
    path = Path(path)
    data = read_toml(path, "column map")
    unknown = sorted(set(data) - {"columns"})
    if unknown or "columns" not in data:
        raise ValueError(
            f"column map {path}: expected one [columns] table"
            + (f", got unknown key(s) or table(s) {unknown}" if unknown else ", found none")
        )
    return ColumnMap.from_table(data["columns"], source=str(path))


def as_column_map(
    columns: ColumnMap | Mapping[str, Any] | str | os.PathLike[str] | None, source: str = "column map"
) -> ColumnMap | None:
    """None, a :class:`ColumnMap`, a ``[columns]`` dict or a path to a column-map file -> ColumnMap or None."""
    if columns is None or isinstance(columns, ColumnMap):
        return columns
    if isinstance(columns, Mapping):
        return ColumnMap.from_table(columns, source)
    return load_column_map(columns)


@dataclass(frozen=True)
class HeightSource:
    """How a height column was read: the file's column, its unit and datum, and who said so.

    ``stated`` is empty when nobody did (the default: ellipsoidal), else e.g.
    ``"column map"``, ``"--altitude-datum"``, ``"h_datum column"``.
    """

    name: str = "ac_h_m"
    column: str = "ac_h_m"
    datum: str = "ellipsoid"
    unit: str = "m"
    stated: str = ""

    @classmethod
    def of_option(cls, datum: str | None, column: str = "--h-m", option: str = "--altitude-datum") -> HeightSource:
        """An aircraft height given on the command line: ``datum`` as ``option`` gave it (None: not given)."""
        if datum is not None and datum not in DATUMS:
            raise ValueError(f"{option} {datum!r}: use 'ellipsoid' or 'egm96' (MSL)")
        return cls("ac_h_m", column, datum or "ellipsoid", "m", option if datum else "")

    def describe(self) -> str:
        """Short form for an output cell: ``"egm96 (column map: Alt_ft, ft)"``."""
        how = self.stated or "default, not stated"
        if (self.column != self.name and not self.column.startswith("--")) or self.unit != "m":
            how += f": {self.column}" + (f", {self.unit}" if self.unit != "m" else "")
        return f"{self.datum} ({how})"

    def sentence(self) -> str:
        """The summary line: what the heights were taken as and what was done."""
        what = f"aircraft heights ({self.name}"
        what += f" from column {self.column!r}" if self.column != self.name else ""
        what += f", {self.unit}" if self.unit != "m" else ""
        what += f") read as {DATUM_TEXT[self.datum]}"
        what += (
            f" ({self.stated})" if self.stated else " (the default: not stated; --altitude-datum egm96 if they are MSL)"
        )
        if self.datum == "egm96":
            what += ", made ellipsoidal with the bundled EGM96 grid (h = H + N)"
        return f"heights: {what}; every output height is ellipsoidal, WGS 84 (h_datum column)"


def datum_warnings(
    dem_datum: str, height: HeightSource, altitude_option: str = "--altitude-datum", dem_option: str = "--dem-datum"
) -> list:
    """Warnings for a DEM of ``dem_datum`` meeting aircraft heights read as ``height``.

    * an orthometric (egm96) DEM with aircraft heights of unstated datum (taken
      as ellipsoidal by default): MSL heights would be N (tens of metres) off;
    * aircraft heights given as MSL (egm96) with a DEM taken as ellipsoidal: most
      DEMs are orthometric.
    """
    out = []
    if dem_datum == "egm96" and height.datum == "ellipsoid" and not height.stated:
        out.append(
            f"the DEM is orthometric (egm96) and the aircraft heights are taken as ellipsoidal "
            f"(default): if they are MSL, pass {altitude_option} egm96 (if they are ellipsoidal, "
            f"{altitude_option} ellipsoid says so)"
        )
    if dem_datum == "ellipsoid" and height.datum == "egm96":
        out.append(
            f"the aircraft heights are MSL (egm96, {height.stated or 'stated'}; made ellipsoidal with "
            f"EGM96) and the DEM is taken as ellipsoidal ({dem_option} ellipsoid): check the DEM's "
            f"vertical datum: most DEMs (SRTM, ASTER GDEM, Copernicus, ETOPO) are orthometric, "
            f"for which pass {dem_option} egm96"
        )
    return out


@dataclass
class ColumnPlan:
    """A column map bound to one file: what each output row holds and how to make it.

    Built by :func:`plan_columns`; :meth:`apply` turns a row of the file into the
    canonical row (units, pixel convention) and :meth:`apply_datums` adds N to
    the ``egm96`` heights of all rows at once.

    Attributes
    ----------
    header : list of str
        The output columns: the file's (a column whose canonical name the map
        redefines renamed ``<name>_input``), the mapped canonical ones, then
        ``h_datum`` and ``ac_h_datum_input``.
    specs : dict
        Canonical name -> :class:`ColumnSpec` of every column to compute.
    renamed : dict
        File column -> its name in the output.
    heights : dict
        Height column -> :class:`HeightSource`.
    """

    path: str
    source_header: list
    header: list
    specs: dict
    renamed: dict
    heights: dict
    file_h_datum: bool = False
    warnings: list = field(default_factory=list)  #: :func:`unit_warnings` of the map
    _pending: dict = field(default_factory=dict)

    @property
    def altitude(self) -> HeightSource:
        return self.heights["ac_h_m"]

    def source_of(self, name: str) -> str | None:
        """The file column a canonical column comes from, if it is computed."""
        spec = self.specs.get(name)
        return spec.column if spec is not None else None

    def apply(self, raw: dict, line: int, index: int) -> tuple[dict | None, tuple[str, str, str] | None]:
        """Row of the file (column -> text) -> (output row, None) or (None, error).

        ``index`` is the row's place among the rows kept so far (for
        :meth:`apply_datums`). The error is ``(column, value, message)`` naming
        the file's column.
        """
        row = {self.renamed.get(k, k): v for k, v in raw.items()}
        pending = []
        for name, spec in self.specs.items():
            text = raw[spec.column]
            datum = self.heights[name].datum if name in self.heights else None
            if not spec.converts() and datum != "egm96":
                row[name] = text
                continue
            if not text:
                row[name] = ""
                continue
            try:
                v = float(text)
            except ValueError:
                return None, (spec.column, text, f"not a number (mapped to {name})")
            v = spec.convert(v)
            if datum == "egm96":
                pending.append((name, v))
                row[name] = ""  # filled by apply_datums
            else:
                row[name] = repr(v)
        if self.file_h_datum:
            err = self._check_file_datum(raw)
            if err is not None:
                return None, err
        for name, v in pending:  # only for a row that is kept: index is its place among them
            self._pending.setdefault(name, []).append((index, v))
        row[H_DATUM_COLUMN] = ELLIPSOID_DATUM
        row[AC_H_DATUM_COLUMN] = self.altitude.describe()
        return row, None

    def _check_file_datum(self, raw):
        """The file's own ``h_datum`` cell must agree with the datum each height is read in."""
        text = raw.get(H_DATUM_COLUMN, "")
        kind = _datum_of_text(text)
        if kind is None:
            return (
                H_DATUM_COLUMN,
                text,
                (f"is not a vertical datum: use {DATUM_TEXT['ellipsoid']!r} or {DATUM_TEXT['egm96']!r}"),
            )
        for name, src in self.heights.items():
            if src.datum != kind and raw.get(src.column, "").strip():
                who = src.stated if src.stated not in ("", FILE_STATED) else "the default"
                fix = (
                    f"--altitude-datum {kind}" if name == "ac_h_m" else f"datum = {kind!r} for {name} in the column map"
                )
                return (
                    H_DATUM_COLUMN,
                    text,
                    f"says {kind} but {name} is read as {src.datum} ({who}): pass {fix}, or correct the file",
                )
        return None

    def apply_datums(self, rows: list) -> dict:
        """Add N to the pending ``egm96`` heights of ``rows`` (the outputs of :meth:`apply`, indexed
        as given to it); returns index -> (column, value, message) for the rows that cannot be converted."""
        from geoloc.geodesy.geoid import egm96_undulation

        errors = {}
        for name, items in self._pending.items():
            lat_name, lon_name = HEIGHT_COLUMNS[name]
            idx = np.array([k for k, _ in items], dtype=int)
            H = np.array([v for _, v in items], dtype=float)
            lat = np.array([_float(rows[k].get(lat_name, "")) for k in idx])
            lon = np.array([_float(rows[k].get(lon_name, "")) for k in idx])
            ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0)
            n = np.full(idx.size, np.nan)
            if np.any(ok):
                n[ok] = egm96_undulation(np.deg2rad(lat[ok]), np.deg2rad(lon[ok]))
            spec = self.specs[name]
            for j, k in enumerate(idx):
                if math.isfinite(n[j]):
                    rows[k][name] = repr(float(H[j] + n[j]))
                elif name != "ac_h_m" or ok[j]:
                    # (a bad aircraft position is reported on its own column by the validation)
                    errors[int(k)] = (
                        spec.column,
                        _text_of(rows[k], self, name),
                        (
                            f"egm96 height {name} needs a valid {lat_name}/{lon_name} in the row "
                            "to add the geoid undulation N"
                        ),
                    )
        self._pending = {}
        return errors


def _float(text) -> float:
    try:
        return float(str(text).strip())
    except ValueError:
        return math.nan


def _text_of(row, plan, name):
    spec = plan.specs[name]
    return row.get(plan.renamed.get(spec.column, spec.column), "")


#: A file column's name that states a unit: feet, radians (a word or a ``_ft`` / ``(ft)`` part).
_NAME_UNITS = {"ft": ("ft", "feet", "foot"), "rad": ("rad", "radian", "radians")}


def _name_unit(column: str) -> str | None:
    """The unit a column's name states (``"ft"``, ``"rad"``), else None: ``Alt_ft``, ``alt (ft)``,
    ``AltitudeFeet``, ``yaw_rad``."""
    import re

    parts = [p.lower() for p in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", column)]
    for unit, words in _NAME_UNITS.items():
        if any(p in words for p in parts):
            return unit
    return None


def unit_warnings(column_map: ColumnMap | None) -> list:
    """Warnings for mapped columns whose name states a unit the map does not give (once
    ``ac_h_m = "Alt_ft"`` read feet as metres, 41 km errors marked ok). A unit the map states
    (even ``m``) is taken as meant."""
    out: list[str] = []
    if column_map is None:
        return out
    for name, spec in column_map.specs.items():
        said = _name_unit(spec.column)
        kind = spec.kind
        if spec.unit is not None or said is None:
            continue
        if (said == "ft" and kind in ("length", "height")) or (said == "rad" and kind == "angle"):
            canon = "metres" if said == "ft" else "degrees"
            out.append(
                f"{column_map.source} [columns]: {name} = {spec.column!r}: the column's name says "
                f"{'feet' if said == 'ft' else 'radians'} but the map gives no unit, so it is read in "
                f"{canon}; write {name} = {{column = {spec.column!r}, unit = {said!r}}} if it is"
            )
    return out


def plan_columns(
    path: str | os.PathLike[str],
    header: list,
    angles: Sequence[str] = (),
    column_map: ColumnMap | None = None,
    altitude_datum: str | None = None,
    altitude_source: str = "--altitude-datum",
    required: Iterable[str] = (),
) -> ColumnPlan:
    """Bind a column map (and the aircraft heights' datum) to a file's ``header``.

    Parameters
    ----------
    path : str
        The file (for messages).
    header : list of str
        The file's columns.
    angles : sequence of str
        The sensor gimbal's joint angles (their columns ``<angle>_deg`` are canonical).
    column_map : ColumnMap, optional
    altitude_datum : {"ellipsoid", "egm96"}, optional
        Datum of the aircraft heights where the map gives none (``--altitude-datum``);
        None: ellipsoidal, not stated.
    altitude_source : str
        Who stated ``altitude_datum`` (for messages and the ``ac_h_datum_input`` column).
    required : iterable of str
        Required canonical columns: each must be in the header or mapped.

    Raises
    ------
    ValueError
        A canonical name the sensor does not have, a mapped column absent from
        the file (the message lists the header), a required column neither in
        the file nor mapped, an unknown ``altitude_datum``, an ``egm96`` height
        without the columns of its point's position.
    """
    angles = tuple(angles)
    column_map = column_map if column_map is not None else ColumnMap({})
    column_map.check_names(angles)
    if altitude_datum is not None and altitude_datum not in DATUMS:
        raise ValueError(f"{altitude_source} {altitude_datum!r}: use 'ellipsoid' or 'egm96' (MSL)")
    for name, spec in column_map.specs.items():
        if spec.column not in header:
            raise ValueError(
                f"{column_map.source} [columns]: {name} = {spec.column!r}: no column "
                f"{spec.column!r} in {path}; its header is {header}"
            )
    specs = dict(column_map.specs)
    # a height whose datum is egm96 by --altitude-datum but which the map does not name
    heights = {}
    for name in HEIGHT_COLUMNS:
        spec = specs.get(name)
        if spec is not None and spec.datum is not None:
            heights[name] = HeightSource(
                name, spec.column, spec.datum, spec.unit or "m", f"column map {column_map.source}"
            )
        elif name == "ac_h_m" and altitude_datum is not None:
            col = spec.column if spec is not None else name
            heights[name] = HeightSource(
                name, col, altitude_datum, (spec.unit if spec else None) or "m", altitude_source
            )
            if altitude_datum == "egm96" and spec is None:
                specs[name] = ColumnSpec(name, name, None, "egm96", None)
        elif spec is not None or name in header or name == "ac_h_m":
            col = spec.column if spec is not None else name
            heights[name] = HeightSource(name, col, "ellipsoid", (spec.unit if spec else None) or "m", "")
    file_h_datum = H_DATUM_COLUMN in header
    if file_h_datum and not heights["ac_h_m"].stated:
        heights["ac_h_m"] = replace(heights["ac_h_m"], stated=FILE_STATED)
    # renames: a file column that a computed canonical column replaces
    renamed = {}
    for name, spec in specs.items():
        if name in header:
            new = name + INPUT_SUFFIX
            if new in header:
                raise ValueError(
                    f"{column_map.source} [columns]: {name} = {spec.column!r} replaces the "
                    f"file's column {name!r}, which would be kept as {new!r}, but {path} already "
                    f"has a column {new!r}"
                )
            renamed[name] = new
    out = [renamed.get(h, h) for h in header]
    out += [n for n in specs if n not in out]
    out += [c for c in (H_DATUM_COLUMN, AC_H_DATUM_COLUMN) if c not in out]
    for name, src in heights.items():
        if src.datum == "egm96":
            lat, lon = HEIGHT_COLUMNS[name]
            missing = [c for c in (lat, lon) if c not in out]
            if missing:
                raise ValueError(
                    f"{name} (column {src.column!r}) is egm96 (MSL): converting it needs the "
                    f"position of its point, and there is no {missing} column in {path} "
                    "(map it, or give the height as ellipsoidal)"
                )
    missing = [c for c in required if c not in out]
    if missing:
        hint = " (a column map, --columns FILE or [columns] in the sensor file, maps your own names: docs/columns.md)"
        raise ValueError(f"{path}: missing required column(s) {missing}; header is {header}{hint}")
    return ColumnPlan(
        str(path), list(header), out, specs, renamed, heights, file_h_datum, warnings=unit_warnings(column_map)
    )
