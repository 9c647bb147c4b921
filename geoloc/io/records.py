"""Flight-test records: load and validate a CSV with the columns of [Q17] Tables 3-4.

Columns (degrees and metres at this edge; see ``docs/records.md``):
``row, col, ac_lat_deg, ac_lon_deg, ac_h_m, heading_deg, pitch_deg, roll_deg,
gimbal_roll_deg, gimbal_pitch_deg`` are required; ``table, point,
paper_lat_deg, paper_lon_deg, paper_height_m, truth_lat_deg, truth_lon_deg,
paper_error_m`` and any other column are optional and carried through.

Every field is validated (finite, in range). A bad row is reported with its
line number, column and value, and left out; the good rows still run.

Any other CSV loads through a column map (``columns=``, :mod:`geoloc.io.columns`,
``docs/columns.md``): its own names and units (deg/rad, m/ft, ellipsoidal or
EGM96/MSL heights, zero- or one-based pixels) become the canonical columns
before validation; its own columns are carried through. Every height the
records hold is ellipsoidal (WGS 84); the rows say so in an ``h_datum`` column,
and how the aircraft heights were read in ``ac_h_datum_input``.
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames.chain import Pose
from geoloc.io.columns import ColumnMap, HeightSource, as_column_map, plan_columns
from geoloc.userfiles import note_input

#: Required numeric columns and their valid ranges (inclusive).
REQUIRED = {
    "row": (-1e7, 1e7),
    "col": (-1e7, 1e7),
    "ac_lat_deg": (-90.0, 90.0),
    "ac_lon_deg": (-180.0, 360.0),
    "ac_h_m": (-1.2e4, 1.0e8),
    "heading_deg": (-360.0, 360.0),
    "pitch_deg": (-90.0, 90.0),
    "roll_deg": (-180.0, 180.0),
    "gimbal_roll_deg": (-180.0, 180.0),
    "gimbal_pitch_deg": (-180.0, 180.0),
}

#: The [Q17] gimbal's angles (the default sensor's); another sensor's joints name their own
#: columns ``<angle>_deg`` (``azimuth_deg``, ``elevation_deg``, ...).
Q17_ANGLES = ("gimbal_roll", "gimbal_pitch")

#: Range of a joint-angle column [deg].
ANGLE_RANGE_DEG = (-360.0, 360.0)


def required_columns(angles: Sequence[str] = Q17_ANGLES) -> dict:
    """The required columns for a sensor whose gimbal has joint ``angles``."""
    base = {k: v for k, v in REQUIRED.items() if not (k.startswith("gimbal_") and k.endswith("_deg"))}
    for a in angles:
        base[f"{a}_deg"] = REQUIRED.get(f"{a}_deg", ANGLE_RANGE_DEG)
    return base


#: Optional numeric columns (may be empty) and their ranges.
OPTIONAL = {
    "paper_lat_deg": (-90.0, 90.0),
    "paper_lon_deg": (-180.0, 360.0),
    "paper_height_m": (-1.2e4, 1.0e5),
    "truth_lat_deg": (-90.0, 90.0),
    "truth_lon_deg": (-180.0, 360.0),
    "truth_h_m": (-1.2e4, 1.0e5),
    "paper_error_m": (0.0, 1.0e7),
}


@dataclass(frozen=True)
class RowError:
    """A rejected row: its 1-based line number in the file, the column and value, and why."""

    line: int
    column: str
    value: str
    message: str

    def __str__(self) -> str:
        return f"line {self.line}: {self.column} = {self.value!r}: {self.message}"


@dataclass
class Records:
    """The good rows of a records file.

    Attributes
    ----------
    path : str
    header : list of str
        The rows' columns, in order: the file's (a column whose canonical name a
        column map redefines is kept as ``<name>_input``), the canonical columns
        a column map computes, then ``h_datum`` and ``ac_h_datum_input``.
    rows : list of dict
        The good rows as text (the file's cells exactly as read, for writing them
        back; computed canonical values as ``repr`` of the float).
    lines : ndarray of int
        1-based line number of each good row.
    errors : list of RowError
        One entry per rejected row.
    angles : tuple of str
        The sensor gimbal's joint angles.
    source_header : list of str
        The file's own header (``header`` if not given).
    heights : dict
        Height column -> :class:`~geoloc.io.columns.HeightSource`: how it was read
        (column, unit, datum, who stated the datum). ``altitude`` is the aircraft's.
    column_map : ColumnMap or None
    """

    path: str
    header: list
    rows: list
    lines: np.ndarray
    errors: list = field(default_factory=list)
    angles: tuple = Q17_ANGLES
    source_header: list | None = None
    heights: dict = field(default_factory=dict)
    column_map: ColumnMap | None = None
    #: Plausibility warnings of the loading (a mapped column named in feet without its unit, ...).
    warnings: list = field(default_factory=list)

    def __post_init__(self):
        if self.source_header is None:
            self.source_header = list(self.header)

    @property
    def altitude(self) -> HeightSource:
        """How the aircraft heights (``ac_h_m``) were read (default: ellipsoidal, not stated)."""
        return self.heights.get("ac_h_m", HeightSource())

    def datum_summary(self) -> str:
        """One line for a verb's summary: the aircraft heights' datum and what was done with it."""
        return self.altitude.sentence()

    def subset(self, idx: ArrayLike) -> Records:
        """The records of the rows ``idx`` (same header, angles, datums; no errors)."""
        idx = np.asarray(idx, dtype=int)
        return Records(
            self.path,
            self.header,
            [self.rows[k] for k in idx],
            self.lines[idx],
            [],
            self.angles,
            self.source_header,
            dict(self.heights),
            self.column_map,
            list(self.warnings),
        )

    def __len__(self) -> int:
        return len(self.rows)

    def column(self, name: str) -> np.ndarray:
        """A numeric column as float array (NaN where empty); ValueError if absent."""
        if name not in self.header:
            raise ValueError(f"{self.path}: no column {name!r}; columns are {self.header}")
        return np.array([_to_float(r[name]) for r in self.rows], dtype=float)

    def text(self, name: str, default: str = "") -> list:
        """A column as text (``default`` if absent)."""
        return [r.get(name, default) for r in self.rows]

    def has(self, name: str) -> bool:
        """True if the column exists and at least one good row has a value in it."""
        return name in self.header and any(r[name].strip() for r in self.rows)

    def pose(self) -> Pose:
        """The aircraft poses of all good rows as one batched :class:`Pose` (with the joint angles)."""
        c = self.column
        q17 = {a: c(f"{a}_deg") for a in Q17_ANGLES if f"{a}_deg" in self.header}
        other = {a: c(f"{a}_deg") for a in self.angles if a not in Q17_ANGLES}
        return Pose.from_deg(
            c("ac_lat_deg"),
            c("ac_lon_deg"),
            c("ac_h_m"),
            c("heading_deg"),
            c("pitch_deg"),
            c("roll_deg"),
            q17.get("gimbal_roll", 0.0),
            q17.get("gimbal_pitch", 0.0),
            angles_deg=other,
        )

    def labels(self) -> list:
        """Short row labels: ``table-point`` when those columns exist, else the line number."""
        if "table" in self.header and "point" in self.header:
            return [f"{r['table']}-{r['point']}" for r in self.rows]
        return [f"line {n}" for n in self.lines]


def _to_float(text: str) -> float:
    text = text.strip()
    return float(text) if text else math.nan


def load_records(
    path: str | os.PathLike[str],
    required: Mapping[str, tuple[float, float]] | None = None,
    optional: Mapping[str, tuple[float, float]] = OPTIONAL,
    angles: Sequence[str] = Q17_ANGLES,
    columns: Any = None,
    altitude_datum: str | None = None,
    altitude_source: str = "--altitude-datum",
) -> Records:
    """Read and validate a records CSV (UTF-8, with or without a byte-order mark).

    Parameters
    ----------
    path : path-like
    required, optional : dict
        Column name -> (min, max) valid range. Required columns must exist in
        the header and hold a finite number in range in every good row;
        optional ones, if present, may be empty. ``required`` defaults to
        :func:`required_columns` of ``angles``.
    angles : sequence of str
        The sensor gimbal's joint angles (``FrameSensor.angle_names``): each
        needs a column ``<angle>_deg``.
    columns : ColumnMap, dict or path, optional
        A column map (``docs/columns.md``): the file's names and units onto the
        canonical columns, applied to each row before validation. A dict is a
        ``[columns]`` table, a path a column-map file.
    altitude_datum : {"ellipsoid", "egm96"}, optional
        Vertical datum of the aircraft heights where the column map gives none
        (None: ellipsoidal, the default, recorded as not stated). ``egm96`` (MSL)
        heights are made ellipsoidal with the bundled EGM96 grid, h = H + N.
    altitude_source : str
        Who stated ``altitude_datum`` (messages, the ``ac_h_datum_input`` column).

    Returns
    -------
    Records
        The good rows and the list of :class:`RowError` for the rejected ones.
        A row rejected for a mapped column names the file's column and value.

    Raises
    ------
    FileNotFoundError, ValueError
        If the file is missing, empty, or lacks a required column (the error
        names the columns), or the column map does not fit the file or the
        sensor (the error names the key and the value).
    """
    note_input(path)
    path = Path(path)
    angles = tuple(angles)
    required = required_columns(angles) if required is None else required
    column_map = as_column_map(columns)
    if not path.exists():
        raise FileNotFoundError(f"records file not found: {path}")
    # utf-8-sig: a spreadsheet's byte-order mark must not become part of the first column's name
    with path.open(newline="", encoding="utf-8-sig") as fh:
        try:
            return _read_records(path, fh, angles, required, optional, column_map, altitude_datum, altitude_source)
        except UnicodeDecodeError as e:
            raise ValueError(
                f"{path}: not a text CSV (UTF-8): byte 0x{e.object[e.start]:02x} cannot be "
                "decoded; is it a binary file?"
            ) from None


#: Labels a "no such record" message shows at most (listing all 299 of a flight buried the message).
LABELS_SHOWN = 5


def describe_labels(value: str, labels: Sequence[str], shown: int = LABELS_SHOWN) -> str:
    """A short account of ``labels`` for a message refusing ``value``: how many there are, the
    first and last, and the few nearest ``value`` (by :func:`difflib.get_close_matches`, and for
    labels ending in a number, those whose number is nearest), never the whole list.

    ``describe_labels('packet 9999', ['packet 0', ..., 'packet 298'])`` ->
    ``"299 records, 'packet 0' .. 'packet 298'; nearest: 'packet 298', 'packet 297', ..."``."""
    import difflib
    import re

    labels = [str(x) for x in labels]
    if not labels:
        return "the file has no records"
    text = f"{len(labels)} record{'s' if len(labels) != 1 else ''}"
    if len(labels) <= shown:
        return text + ": " + ", ".join(repr(x) for x in labels)
    text += f", {labels[0]!r} .. {labels[-1]!r}"
    value = str(value)
    near = []
    m = re.fullmatch(r"(.*?)(\d+)", value.strip())
    if m:  # same prefix, nearest number
        prefix, number = m.group(1), int(m.group(2))
        numbered = [
            (abs(int(mm.group(2)) - number), i)
            for i, lab in enumerate(labels)
            if (mm := re.fullmatch(r"(.*?)(\d+)", lab)) and mm.group(1) == prefix
        ]
        near = [labels[i] for _, i in sorted(numbered)[:shown]]
    for x in difflib.get_close_matches(value, labels, n=shown, cutoff=0.5):
        if x not in near and len(near) < shown:
            near.append(x)
    return text + ("; nearest: " + ", ".join(repr(x) for x in near) if near else "")


def check_header(path: str | os.PathLike[str], header: Sequence[str]) -> None:
    """Refuse a CSV header with two columns of one name (ValueError naming the column, its
    positions and the file): a reader of rows as dicts keeps the last one without a word
    (two ``row`` columns once took the second, 0.36 m -> 72.83 m RMS to the paper)."""
    seen: dict[str, list[int]] = {}
    for k, name in enumerate(header):
        seen.setdefault(name, []).append(k + 1)
    dup = {n: pos for n, pos in seen.items() if len(pos) > 1 and n}  # (blank: trailing empty cells)
    if dup:
        what = "; ".join(f"{n!r} in columns {', '.join(map(str, pos))}" for n, pos in dup.items())
        raise ValueError(f"{path}: duplicate column name(s): {what}; rename or remove the extra column(s)")


def _separator_hint(header) -> str:
    """A hint when the header looks split by another separator than the comma."""
    for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars")):
        if any(sep in h for h in header):
            return (
                f"; the header holds {name} ({header[0][:60]!r}): records CSVs are comma-separated "
                "(save the sheet as CSV with commas)"
            )
    return ""


def _read_records(path, fh, angles, required, optional, column_map, altitude_datum, altitude_source):
    """The body of :func:`load_records` on the open file ``fh``."""
    reader = csv.reader(fh)
    try:
        source_header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ValueError(f"{path}: empty file, expected a header line") from None
    check_header(path, source_header)
    try:
        plan = plan_columns(
            str(path), source_header, angles, column_map, altitude_datum, altitude_source, required=required
        )
    except ValueError as e:
        hint = _separator_hint(source_header)
        if hint:
            raise ValueError(f"{e}{hint}") from None
        raise
    rows, lines, raws, errors = [], [], [], []
    for cells in reader:
        line = reader.line_num
        if not cells or all(not c.strip() for c in cells):
            continue
        if len(cells) != len(source_header):
            errors.append(
                RowError(line, "*", ",".join(cells), f"has {len(cells)} fields, header has {len(source_header)}")
            )
            continue
        raw = dict(zip(source_header, (c.strip() for c in cells)))
        row, err = plan.apply(raw, line, len(rows))
        if err is not None:
            errors.append(RowError(line, *err))
            continue
        rows.append(row)
        lines.append(line)
        raws.append(raw)
    bad = plan.apply_datums(rows)
    good_rows, good_lines = [], []
    for k, (row, line, raw) in enumerate(zip(rows, lines, raws)):
        err = RowError(line, *bad[k]) if k in bad else _check_row(row, line, required, optional, plan, raw)
        if err is not None:
            errors.append(err)
            continue
        good_rows.append(row)
        good_lines.append(line)
    errors.sort(key=lambda e: e.line)
    return Records(
        str(path),
        plan.header,
        good_rows,
        np.array(good_lines, dtype=int),
        errors,
        angles,
        source_header,
        dict(plan.heights),
        column_map,
        list(plan.warnings),
    )


def _check_row(row, line, required, optional, plan=None, raw=None):
    err = _check_canonical(row, line, required, optional)
    if err is None or plan is None:
        return err
    src = plan.source_of(err.column)
    if src is None:
        return err
    # the value was computed from the file's column: name that column and its text
    return RowError(line, src, raw.get(src, ""), f"{err.message} (as {err.column} = {err.value})")


def _check_canonical(row, line, required, optional):
    for name, (lo, hi) in list(required.items()) + list(optional.items()):
        if name not in row:
            continue
        text = row[name]
        if not text and name in optional:
            continue
        try:
            v = float(text)
        except ValueError:
            return RowError(line, name, text, "not a number")
        if not math.isfinite(v):
            return RowError(line, name, text, "not finite")
        if not lo <= v <= hi:
            return RowError(line, name, text, f"out of range [{lo:g}, {hi:g}]")
    return None
