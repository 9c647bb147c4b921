"""Flight-test records: load and validate a CSV with the columns of [Q17] Tables 3-4.

Columns (degrees and metres at this edge; see ``../shared/data/README.md``):
``row, col, ac_lat_deg, ac_lon_deg, ac_h_m, heading_deg, pitch_deg, roll_deg,
gimbal_roll_deg, gimbal_pitch_deg`` are required; ``table, point,
paper_lat_deg, paper_lon_deg, paper_height_m, truth_lat_deg, truth_lon_deg,
paper_error_m`` and any other column are optional and carried through.

Every field is validated (finite, in range). A bad row is reported with its
line number, column and value, and left out; the good rows still run.
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from geoloc.frames.chain import Pose

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
        The file's columns, in order.
    rows : list of dict
        The good rows as text, exactly as read (for writing them back).
    lines : ndarray of int
        1-based line number of each good row.
    errors : list of RowError
        One entry per rejected row.
    """

    path: str
    header: list
    rows: list
    lines: np.ndarray
    errors: list = field(default_factory=list)

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
        """The aircraft poses of all good rows as one batched :class:`Pose`."""
        c = self.column
        return Pose.from_deg(c("ac_lat_deg"), c("ac_lon_deg"), c("ac_h_m"), c("heading_deg"),
                             c("pitch_deg"), c("roll_deg"), c("gimbal_roll_deg"),
                             c("gimbal_pitch_deg"))

    def labels(self) -> list:
        """Short row labels: ``table-point`` when those columns exist, else the line number."""
        if "table" in self.header and "point" in self.header:
            return [f"{r['table']}-{r['point']}" for r in self.rows]
        return [f"line {n}" for n in self.lines]


def _to_float(text: str) -> float:
    text = text.strip()
    return float(text) if text else math.nan


def load_records(path, required=REQUIRED, optional=OPTIONAL) -> Records:
    """Read and validate a records CSV.

    Parameters
    ----------
    path : path-like
    required, optional : dict
        Column name -> (min, max) valid range. Required columns must exist in
        the header and hold a finite number in range in every good row;
        optional ones, if present, may be empty.

    Returns
    -------
    Records
        The good rows and the list of :class:`RowError` for the rejected ones.

    Raises
    ------
    FileNotFoundError, ValueError
        If the file is missing, empty, or lacks a required column (the error
        names the columns).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"records file not found: {path}")
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{path}: empty file, expected a header line") from None
        missing = [c for c in required if c not in header]
        if missing:
            raise ValueError(f"{path}: missing required column(s) {missing}; header is {header}")
        rows, lines, errors = [], [], []
        for cells in reader:
            line = reader.line_num
            if not cells or all(not c.strip() for c in cells):
                continue
            if len(cells) != len(header):
                errors.append(RowError(line, "*", ",".join(cells),
                                       f"has {len(cells)} fields, header has {len(header)}"))
                continue
            row = dict(zip(header, (c.strip() for c in cells)))
            err = _check_row(row, line, required, optional)
            if err is not None:
                errors.append(err)
                continue
            rows.append(row)
            lines.append(line)
    return Records(str(path), header, rows, np.array(lines, dtype=int), errors)


def _check_row(row, line, required, optional):
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
