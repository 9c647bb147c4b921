"""Results out to GIS: GeoPackage, GeoJSON, KML and CZML (``docs/gis.md``).

Reads a results CSV as ``geoloc replay --out`` writes it (:func:`read_results`)
and writes its computed points, the truth and published/reported positions, the
error vectors between them, the frame footprints and the platform track to the
usual GIS and globe formats (:func:`export`):

* GeoPackage (``.gpkg``) and GeoJSON (``.geojson``/``.json``) through
  ``pyogrio`` (GDAL), with WKB geometry encoded here with :mod:`struct`;
* KML (``.kml``) through ``simplekml``, altitudes as EGM96 orthometric heights
  (KML altitudes are above mean sea level);
* CZML (``.czml``) through ``czml3``'s pydantic models, heights above the WGS 84
  ellipsoid, with a clock so that Cesium plays the flight.

The writers' libraries are imported when a writer runs, so ``import geoloc.io.gis``
(and the rest of geoloc) works without them.

Heights: the table's heights are ellipsoidal (WGS 84) unless an ``h_datum``
column says ``EGM96``/orthometric for a row; every geometry written to
GPKG/GeoJSON/CZML is ellipsoidal (h = H + N), KML is orthometric (H = h - N),
with N from :func:`geoloc.geodesy.geoid.egm96_undulation`.
Conventions: ``docs/conventions.md`` (degrees at this edge, heights in metres).
"""

from __future__ import annotations

import contextlib
import csv
import html
import importlib
import math
import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from geoloc.geodesy.local import ellipse_ring_enu, enu_to_geodetic_deg
from geoloc.io.mgrs_grid import mgrs_column
from geoloc.status import Status
from geoloc.userfiles import atomic_path, note_input, write_bytes

#: Formats :func:`export` writes.
FORMATS = ("gpkg", "geojson", "kml", "czml")
_ALIASES = {"gpkg": "gpkg", "geopackage": "gpkg", "geojson": "geojson", "json": "geojson", "kml": "kml", "czml": "czml"}
#: Output extensions and the format each implies.
EXTENSIONS = {".gpkg": "gpkg", ".geojson": "geojson", ".json": "geojson", ".kml": "kml", ".czml": "czml"}
#: Layers, in the order they are written (every format writes all of them, empty or not).
LAYERS = ("points", "truth", "reported", "error_vectors", "footprints", "track", "ellipses")
#: Vertices of each predicted 90 % error ellipse's ring (the ``ellipses`` layer).
ELLIPSE_VERTICES = 72
#: Record id columns carried as text attributes when present.
ID_COLUMNS = ("table", "point", "record", "image", "packet")
#: Columns :func:`read_results` keeps as text even when every value looks like a number.
TEXT_COLUMNS = frozenset(ID_COLUMNS) | {"status", "method", "h_datum", "time_utc"}
#: The datum of every geometry height in GPKG, GeoJSON and CZML.
ELLIPSOID_DATUM = "ellipsoid (WGS 84)"
#: The datum of KML altitudes.
EGM96_DATUM = "EGM96 geoid (orthometric)"
#: Epoch of ``time_s`` (read as seconds after it) and of synthesized times.
DEFAULT_EPOCH = "1970-01-01T00:00:00Z"

#: Reference positions: (name, latitude column, longitude column, height columns in preference order).
_TRUTH = ("truth", "truth_lat_deg", "truth_lon_deg", ("truth_h_m", "truth_height_m"))
_REPORTED = (
    ("paper", "paper_lat_deg", "paper_lon_deg", ("paper_height_m", "paper_h_m")),
    ("reported", "reported_lat_deg", "reported_lon_deg", ("reported_h_m", "reported_height_m")),
)
_PLATFORMS = ("ac", "sensor")

_Z_TYPES = {"Point": 1, "LineString": 2, "Polygon": 3}


# --------------------------------------------------------------------------- reading


def read_results(path: str | os.PathLike[str]) -> dict:
    """Read a results CSV into a table: column name -> float array or list of strings.

    A column becomes a float64 array (NaN where empty) when every non-empty
    value parses as a number, except the id and text columns of
    :data:`TEXT_COLUMNS` (``table``, ``point``, ``status``, ``time_utc``, ...),
    which stay lists of strings ("" where empty). A UTF-8 byte-order mark is
    ignored; a file with no header line gives an empty table (``{}``).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist (the message names it).
    ValueError
        If the header repeats a name or a line has more fields than the header, or the
        file is not UTF-8 text (a binary file; the message names it).
    """
    note_input(path)
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"results file {str(path)!r} does not exist")
    if not p.is_file():
        raise FileNotFoundError(f"results path {str(path)!r} is not a file")
    try:
        return _read_results(path, p)
    except UnicodeDecodeError as e:
        raise ValueError(
            f"{path}: not a text CSV (UTF-8): byte 0x{e.object[e.start]:02x} cannot be decoded; is it a binary file?"
        ) from None


def _read_results(path, p):
    with p.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            return {}
        header = [h.strip() for h in header]
        seen = set()
        for h in header:
            if h in seen:
                raise ValueError(f"{path}: column {h!r} appears twice in the header")
            seen.add(h)
        cols = [[] for _ in header]
        for row in reader:
            if not row:  # a blank line
                continue
            if len(row) > len(header):
                raise ValueError(f"{path}: line {reader.line_num} has {len(row)} fields, the header has {len(header)}")
            row = row + [""] * (len(header) - len(row))
            for c, v in zip(cols, row):
                c.append(v.strip())
    return {name: _parse_column(name, vals) for name, vals in zip(header, cols)}


def _parse_column(name, vals):
    if name in TEXT_COLUMNS:
        return vals
    out = np.full(len(vals), np.nan)
    for k, v in enumerate(vals):
        if v == "":
            continue
        try:
            out[k] = float(v)
        except ValueError:
            return vals
    return out


# --------------------------------------------------------------------------- table access


def _nrows(table) -> int:
    lengths = {name: len(v) for name, v in table.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"the table's columns differ in length: {lengths}")
    return next(iter(lengths.values()), 0)


def _num(table, name, n):
    """Column as a float array (NaN where empty), or None if absent."""
    if name not in table:
        return None
    v = table[name]
    if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
        return v.astype(float)
    out = np.full(n, np.nan)
    for k, x in enumerate(v):
        if x is None:
            continue
        if isinstance(x, (int, float, np.number)) and not isinstance(x, bool):
            out[k] = float(x)
            continue
        s = str(x).strip()
        if s == "":
            continue
        try:
            out[k] = float(s)
        except ValueError:
            raise ValueError(f"column {name!r}: {s!r} on row {k} is not a number") from None
    return out


def _as_text(x):
    if x is None:
        return None
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            return None
        return str(int(x)) if float(x).is_integer() else repr(float(x))
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    s = str(x).strip()
    return s or None


def _text(table, name):
    """Column as a list of str (None where empty), or None if absent."""
    if name not in table:
        return None
    return [_as_text(x) for x in table[name]]


def _finite(x) -> bool:
    return x is not None and bool(np.isfinite(x))


def _opt(x):
    """A float, or None for NaN."""
    return float(x) if _finite(x) else None


def _status_text(values):

    out = []
    for s in values:
        if s is not None:
            try:
                s = Status(int(float(s))).name.lower()
            except ValueError:
                pass
        out.append(s)
    return out


def _is_error_column(name: str) -> bool:
    return name.startswith("error_") or name.endswith("_error_m")


# --------------------------------------------------------------------------- heights


def _datum_kind(text, k):
    if text is None:
        return "ellipsoid"
    t = text.lower()
    if any(s in t for s in ("egm96", "orthometric", "geoid", "msl", "sea level", "5773")):
        return "egm96"
    if any(s in t for s in ("ellipsoid", "wgs 84", "wgs84", "wgs-84", "4979")):
        return "ellipsoid"
    raise ValueError(f"h_datum {text!r} on row {k} is not understood: use {ELLIPSOID_DATUM!r} or {EGM96_DATUM!r}")


def _undulation(lat_deg, lon_deg):
    """EGM96 N [m] at points in degrees (NaN where not finite)."""
    from geoloc.geodesy.geoid import egm96_undulation

    lat = np.asarray(lat_deg, float)
    lon = np.asarray(lon_deg, float)
    return egm96_undulation(np.deg2rad(lat), np.deg2rad(lon))


def _ellipsoidal(h, lat, lon, egm96_rows):
    """Heights made ellipsoidal: h + N on the rows whose h_datum is EGM96."""
    if h is None:
        return None
    h = h.copy()
    sel = egm96_rows & np.isfinite(h) & np.isfinite(lat) & np.isfinite(lon)
    if np.any(sel):
        h[sel] = h[sel] + _undulation(lat[sel], lon[sel])
    return h


# --------------------------------------------------------------------------- times


def _parse_time(text, k=None):
    try:
        t = datetime.fromisoformat(text.strip().replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        where = f" on row {k}" if k is not None else ""
        raise ValueError(f"time {text!r}{where} is not an ISO 8601 date and time") from None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def _iso(base: datetime, seconds: float) -> str:
    t = base + timedelta(seconds=float(seconds))
    return t.strftime("%Y-%m-%dT%H:%M:%SZ" if t.microsecond == 0 else "%Y-%m-%dT%H:%M:%S.%fZ")


# --------------------------------------------------------------------------- model


@dataclass
class _Feature:
    coords: list | None  # [(lon_deg, lat_deg, h_ellipsoidal_m or NaN), ...]; a polygon ring is closed
    attrs: dict
    label: str
    row: int | None = None  # data row (0-based) the feature comes from
    time: float | None = None  # seconds after the time base
    samples: list | None = None  # track: every sample, also when fewer than two
    times: list | None = None  # track: sample times [s after the base]


@dataclass
class _Layer:
    name: str
    geometry: str  # "Point", "LineString" or "Polygon"
    fields: list  # [(name, "text" | "real" | "int")]
    features: list = field(default_factory=list)
    description: str = ""

    def has_z(self) -> bool:
        """3D when every feature with a geometry has a finite height at every vertex."""
        return all(all(np.isfinite(c[2]) for c in f.coords) for f in self.features if f.coords)

    def without_geometry(self) -> int:
        return sum(1 for f in self.features if not f.coords)


@dataclass
class _Context:
    n: int
    base: datetime
    seconds: np.ndarray
    time_source: str  # "time_utc", "time_s" or "row_order" (no time column: one second per row)
    labels: list
    status: list | None
    rows_without_position: list
    source: str = ""

    @property
    def real_time(self) -> bool:
        return self.time_source != "row_order"

    def iso(self, seconds) -> str:
        return _iso(self.base, seconds)

    def missing_text(self, rows) -> list:
        out = []
        for k in rows:
            st = self.status[k] if self.status is not None and self.status[k] else "unknown"
            out.append(f"row {k} ({self.labels[k]}): status {st}")
        return out


@dataclass
class ExportSummary:
    """What :func:`export` wrote: files, features per layer, rows without a position."""

    format: str
    paths: list
    rows: int
    features: dict  # layer -> number of features
    without_geometry: dict  # layer -> features written with an empty geometry
    rows_without_position: list  # data rows (0-based) without a computed lat/lon
    missing: list  # one line per such row: "row 3 (T3/4): status sky"
    time_source: str
    notes: list = field(default_factory=list)

    def __str__(self) -> str:
        lines = [f"wrote {self.format} ({self.rows} rows) to {', '.join(str(p) for p in self.paths)}"]
        for name in LAYERS:
            lines.append(
                f"  {name:<14} {self.features.get(name, 0):5d} features, "
                f"{self.without_geometry.get(name, 0)} with an empty geometry"
            )
        lines.append(f"  rows without a computed position: {len(self.rows_without_position)}")
        lines += [f"    {m}" for m in self.missing]
        lines += [f"  note: {s}" for s in self.notes]
        return "\n".join(lines)


# --------------------------------------------------------------------------- layers from the table


def _row_labels(table, n) -> tuple[list, list]:
    """The id columns present, and each row's label: its ids joined by '/', else ``row k``."""
    ids = [c for c in ID_COLUMNS if c in table]
    id_text = {c: _text(table, c) for c in ids}
    labels = []
    for k in range(n):
        parts = [id_text[c][k] for c in ids if id_text[c][k]]
        labels.append("/".join(parts) if parts else f"row {k}")
    return ids, labels


def _row_fields(table, n, ids, group_by) -> tuple[list, dict, list | None, np.ndarray]:
    """The attributes every row-based feature carries: ``(fields, values, status, egm96)`` with
    fields ``[(name, kind)]``, values name -> one value per row, the status text per row (None
    without a status column), and where a row's heights are EGM96 (made ellipsoidal by the
    positions)."""
    fields = [("row_index", "int")]
    values: dict[str, list] = {"row_index": list(range(n))}  # name -> one value per row (int, float, str, None)
    for c in ids + ([group_by] if group_by and group_by not in ids else []):
        fields.append((c, "text"))
        values[c] = _text(table, c)
    if "time_utc" in table:
        fields.append(("time_utc", "text"))
        values["time_utc"] = _text(table, "time_utc")
    if "time_s" in table:
        fields.append(("time_s", "real"))
        values["time_s"] = [_opt(v) for v in _num(table, "time_s", n)]
    status = None
    if "status" in table:
        status = _status_text(_text(table, "status"))
        fields.append(("status", "text"))
        values["status"] = status
    if "method" in table:
        fields.append(("method", "text"))
        values["method"] = _text(table, "method")
    if "dem_evaluations" in table:
        v = _num(table, "dem_evaluations", n)
        fin = v[np.isfinite(v)]
        integral = bool(np.all(fin == np.round(fin)))
        fields.append(("dem_evaluations", "int" if integral else "real"))
        values["dem_evaluations"] = [(int(x) if integral else float(x)) if np.isfinite(x) else None for x in v]
    for c in table:
        if _is_error_column(c):
            fields.append((c, "real"))
            values[c] = [_opt(x) for x in _num(table, c, n)]
    fields.append(("h_datum", "text"))
    values["h_datum"] = [ELLIPSOID_DATUM] * n
    datum_text = _text(table, "h_datum")
    if datum_text is not None:
        fields.append(("h_datum_input", "text"))
        values["h_datum_input"] = datum_text
    egm96 = np.array([_datum_kind(datum_text[k] if datum_text else None, k) == "egm96" for k in range(n)], dtype=bool)
    return fields, values, status, egm96


def _time_base(table, n, epoch) -> tuple[datetime, np.ndarray, str]:
    """The time base and each row's seconds after it: from ``time_utc`` (the base its earliest
    stamp), else ``time_s`` after ``epoch``, else one second per row after ``epoch``."""
    if "time_utc" in table:
        txt = _text(table, "time_utc")
        stamps = [None if t is None else _parse_time(t, k) for k, t in enumerate(txt)]
        known = [t for t in stamps if t is not None]
        base = min(known) if known else _parse_time(epoch)
        seconds = np.array([np.nan if t is None else (t - base).total_seconds() for t in stamps])
        return base, seconds, "time_utc"
    if "time_s" in table:
        return _parse_time(epoch), _num(table, "time_s", n), "time_s"
    return _parse_time(epoch), np.arange(n, dtype=float), "row_order"


def _has_position(p, k) -> bool:
    """Row k of the position ``p`` (from :meth:`_Rows.position`) has a finite lat and lon."""
    return p is not None and np.isfinite(p[0][k]) and np.isfinite(p[1][k])


@dataclass
class _Rows:
    """The table's rows as the layers read them: labels, the attributes each row-based feature
    carries, and each row's time."""

    table: dict
    n: int
    labels: list
    fields: list  # [(name, kind)] every row-based feature carries
    values: dict  # name -> one value per row
    egm96: np.ndarray  # rows whose heights are EGM96 (made ellipsoidal by position)
    seconds: np.ndarray  # after the time base, NaN where unknown

    def attrs(self, k, **extra) -> dict:
        a = {name: self.values[name][k] for name, _ in self.fields}
        a.update(extra)
        return a

    def t_of(self, k) -> float | None:
        return float(self.seconds[k]) if np.isfinite(self.seconds[k]) else None

    def position(self, lat_col, lon_col, h_cols):
        """``(lat, lon, h, h_column)`` of the columns named, the height made ellipsoidal (NaN where
        the table has none of ``h_cols``); None without the lat or lon column."""
        lat, lon = _num(self.table, lat_col, self.n), _num(self.table, lon_col, self.n)
        if lat is None or lon is None:
            return None
        h = next((_num(self.table, c, self.n) for c in h_cols if c in self.table), None)
        h = np.full(self.n, np.nan) if h is None else _ellipsoidal(h, lat, lon, self.egm96)
        hcol = next((c for c in h_cols if c in self.table), None)
        return lat, lon, h, hcol

    def mgrs_of(self, p) -> list:
        """Each row's MGRS reference of position ``p`` (1 m; None where it has no position)."""
        return [t or None for t in mgrs_column(p[0], p[1])] if p is not None else [None] * self.n


def _point_fields(rows: _Rows) -> list:
    # every point carries its MGRS reference (1 m, geoloc.io.mgrs_grid; None where it has no position)
    return rows.fields + [("h_m", "real"), ("mgrs", "text")]


def _points_layer(rows: _Rows, comp) -> tuple[_Layer, list]:
    """The computed ground points, one feature per row (an empty geometry where the row has no
    position), and the rows without one."""
    comp_mgrs = rows.mgrs_of(comp)
    lay = _Layer("points", "Point", _point_fields(rows))
    missing = []
    for k in range(rows.n):
        if _has_position(comp, k):
            coords = [(float(comp[1][k]), float(comp[0][k]), float(comp[2][k]))]
        else:
            coords = None
            missing.append(k)
        attrs = rows.attrs(k, h_m=_opt(comp[2][k]) if comp else None, mgrs=comp_mgrs[k])
        lay.features.append(_Feature(coords, attrs, rows.labels[k], k, rows.t_of(k)))
    lay.description = "computed ground points (lat_deg, lon_deg, h_m)"
    return lay, missing


def _truth_layer(rows: _Rows, truth) -> _Layer:
    """The surveyed positions, one feature per row; empty without truth columns."""
    lay = _Layer("truth", "Point", _point_fields(rows))
    if truth is not None:
        truth_mgrs = rows.mgrs_of(truth)
        for k in range(rows.n):
            coords = [(float(truth[1][k]), float(truth[0][k]), float(truth[2][k]))] if _has_position(truth, k) else None
            attrs = rows.attrs(k, h_m=_opt(truth[2][k]), mgrs=truth_mgrs[k])
            lay.features.append(_Feature(coords, attrs, f"truth {rows.labels[k]}", k, rows.t_of(k)))
    lay.description = "surveyed (truth) positions (truth_lat_deg, truth_lon_deg, truth_h_m)"
    return lay


def _reported_layer(rows: _Rows, reported) -> _Layer:
    """The published and reported positions (``[(source, position)]``), one feature per row
    and source."""
    lay = _Layer("reported", "Point", rows.fields + [("source", "text"), ("h_m", "real"), ("mgrs", "text")])
    for name, p in reported:
        p_mgrs = rows.mgrs_of(p)
        for k in range(rows.n):
            coords = [(float(p[1][k]), float(p[0][k]), float(p[2][k]))] if _has_position(p, k) else None
            attrs = rows.attrs(k, source=name, h_m=_opt(p[2][k]), mgrs=p_mgrs[k])
            lay.features.append(_Feature(coords, attrs, f"{name} {rows.labels[k]}", k, rows.t_of(k)))
    lay.description = (
        "published (paper_*) and reported (reported_*, e.g. MISB KLV) positions; attribute source says which"
    )
    return lay


def _error_vector_layer(rows: _Rows, comp, targets) -> _Layer:
    """A line from each computed point to each target (``[(name, position)]``: truth, paper,
    reported); the far end at the target's height, or the computed height where it has none."""
    lay = _Layer(
        "error_vectors", "LineString", rows.fields + [("target", "text"), ("error_m", "real"), ("end_h_from", "text")]
    )
    for name, p in targets:
        err = _num(rows.table, f"error_to_{name}_m", rows.n)
        if err is None and name == "reported":  # a MISB KLV replay names it after the frame centre
            err = _num(rows.table, "frame_center_error_m", rows.n)
        for k in range(rows.n):
            coords, end_from = None, None
            if _has_position(comp, k) and _has_position(p, k):
                h_end = p[2][k] if np.isfinite(p[2][k]) else comp[2][k]
                end_from = p[3] if np.isfinite(p[2][k]) else "h_m (target height unknown)"
                coords = [
                    (float(comp[1][k]), float(comp[0][k]), float(comp[2][k])),
                    (float(p[1][k]), float(p[0][k]), float(h_end)),
                ]
            attrs = rows.attrs(k, target=name, error_m=_opt(err[k]) if err is not None else None, end_h_from=end_from)
            lay.features.append(_Feature(coords, attrs, f"{rows.labels[k]} to {name}", k, rows.t_of(k)))
    lay.description = (
        "from the computed point to the truth / published / reported position; the far "
        "end takes the target's height, or the computed height when the target has none"
    )
    return lay


def _footprint_layer(rows: _Rows) -> _Layer:
    """Each row's image footprint (corner1..corner4) as a closed ring, counterclockwise (RFC 7946,
    3.1.6); ``ring_corners`` says the corner order. Empty without the four corners' columns."""
    lay = _Layer("footprints", "Polygon", rows.fields + [("ring_corners", "text")])
    corner_cols = [(f"corner{i}_lat_deg", f"corner{i}_lon_deg") for i in range(1, 5)]
    if all(a in rows.table and b in rows.table for a, b in corner_cols):
        corners = [rows.position(a, b, (f"corner{i + 1}_h_m",)) for i, (a, b) in enumerate(corner_cols)]
        for k in range(rows.n):
            coords, ring = None, None
            if all(_has_position(c, k) for c in corners):
                pts = [(float(c[1][k]), float(c[0][k]), float(c[2][k])) for c in corners]
                order = [0, 1, 2, 3] if _signed_area(pts) >= 0 else [0, 3, 2, 1]
                order = order + [0]
                coords = [pts[i] for i in order]
                ring = ",".join(str(i + 1) for i in order)
            lay.features.append(
                _Feature(coords, rows.attrs(k, ring_corners=ring), f"footprint {rows.labels[k]}", k, rows.t_of(k))
            )
    lay.description = (
        "image footprints (corner1..corner4), closed ring, counterclockwise; ring_corners gives the corner order"
    )
    return lay


def _track_layer(rows: _Rows, group_by, time_source) -> _Layer:
    """The platform's track (``ac_*`` else ``sensor_*`` columns), one line per group (flight),
    ordered by time, one sample per time (the first row at it); rows without a time are left out."""
    table, n, seconds = rows.table, rows.n, rows.seconds
    gname = group_by or "group"
    tfields = [
        (gname, "text"),
        ("n_samples", "int"),
        ("first_row", "int"),
        ("last_row", "int"),
        ("time_source", "text"),
    ]
    if time_source == "time_utc":
        tfields += [("start_time_utc", "text"), ("end_time_utc", "text")]
    if "time_s" in table:
        tfields += [("start_time_s", "real"), ("end_time_s", "real")]
    tfields += [("h_datum", "text")]
    lay = _Layer("track", "LineString", tfields)
    lay.description = "platform track (ac_* or sensor_* columns), one line per flight, ordered by time"
    plat = next(
        (
            rows.position(f"{p}_lat_deg", f"{p}_lon_deg", (f"{p}_h_m",))
            for p in _PLATFORMS
            if f"{p}_lat_deg" in table and f"{p}_lon_deg" in table
        ),
        None,
    )
    if plat is None or not n:
        return lay
    groups = _text(table, group_by) if group_by else ["all"] * n
    groups = [g or "" for g in groups]
    time_s = _num(table, "time_s", n)
    utc = _text(table, "time_utc")
    for g in dict.fromkeys(groups):
        ks = [k for k in range(n) if groups[k] == g and _has_position(plat, k) and np.isfinite(seconds[k])]
        ks.sort(key=lambda k: seconds[k])
        keep: list[int] = []
        for k in ks:  # one sample per time: the first row at each time
            if not keep or seconds[k] > seconds[keep[-1]]:
                keep.append(k)
        samples = [(float(plat[1][k]), float(plat[0][k]), float(plat[2][k])) for k in keep]
        a = {
            gname: g,
            "n_samples": len(keep),
            "first_row": keep[0] if keep else None,
            "last_row": keep[-1] if keep else None,
            "time_source": time_source,
            "h_datum": ELLIPSOID_DATUM,
        }
        if time_source == "time_utc":
            a["start_time_utc"] = utc[keep[0]] if keep else None
            a["end_time_utc"] = utc[keep[-1]] if keep else None
        if time_s is not None:
            a["start_time_s"] = _opt(time_s[keep[0]]) if keep else None
            a["end_time_s"] = _opt(time_s[keep[-1]]) if keep else None
        lay.features.append(
            _Feature(
                samples if len(samples) >= 2 else None,
                a,
                f"track {g}".strip(),
                None,
                float(seconds[keep[0]]) if keep else None,
                samples,
                [float(seconds[k]) for k in keep],
            )
        )
    return lay


def build_layers(
    table: dict, group_by: str | None = None, epoch: str = DEFAULT_EPOCH
) -> tuple[dict[str, _Layer], _Context]:
    """The six layers of a table, with heights made ellipsoidal (the writers' common input).

    Returns ``(layers, context)``: a dict layer name -> layer, and the time base,
    labels and rows without a position. See :func:`export` for the arguments.
    """
    n = _nrows(table)
    if group_by is not None and group_by not in table:
        raise ValueError(f"group-by column {group_by!r} is not in the results (columns: {', '.join(table) or 'none'})")
    if group_by is None and "table" in table:
        group_by = "table"
    ids, labels = _row_labels(table, n)
    fields, values, status, egm96 = _row_fields(table, n, ids, group_by)
    base, seconds, time_source = _time_base(table, n, epoch)
    rows = _Rows(table, n, labels, fields, values, egm96, seconds)

    comp = rows.position("lat_deg", "lon_deg", ("h_m",))
    truth = rows.position(*_TRUTH[1:])
    reported = [(name, rows.position(lat, lon, hs)) for name, lat, lon, hs in _REPORTED]
    reported = [(name, p) for name, p in reported if p is not None]
    layers = {}
    layers["points"], missing = _points_layer(rows, comp)
    layers["truth"] = _truth_layer(rows, truth)
    layers["reported"] = _reported_layer(rows, reported)
    targets = ([("truth", truth)] if truth is not None else []) + reported
    layers["error_vectors"] = _error_vector_layer(rows, comp, targets)
    layers["footprints"] = _footprint_layer(rows)
    layers["track"] = _track_layer(rows, group_by, time_source)
    layers["ellipses"] = _ellipse_layer(table, n, comp, _has_position, fields, rows.attrs, labels, rows.t_of)
    ctx = _Context(n, base, seconds, time_source, labels, status, missing)
    return layers, ctx


def _ellipse_layer(table, n, comp, ok, fields, row_attrs, labels, t_of):
    """Each computed point's predicted 90 % horizontal error ellipse as a polygon (the replay's
    ``ellipse_major_m ellipse_minor_m ellipse_azimuth_deg`` columns, 1 sigma, scaled by 2.1460:
    geoloc.analysis.uncertainty), its vertices at the point's height, counterclockwise."""

    ell = [_num(table, c, n) for c in ("ellipse_major_m", "ellipse_minor_m", "ellipse_azimuth_deg")]
    ce, le = _num(table, "ce90_m", n), _num(table, "le90_m", n)
    lay = _Layer(
        "ellipses",
        "Polygon",
        fields
        + [
            ("ce90_m", "real"),
            ("le90_m", "real"),
            ("semi_major_90_m", "real"),
            ("semi_minor_90_m", "real"),
            ("azimuth_deg", "real"),
        ],
    )
    lay.description = (
        "predicted 90 % horizontal error ellipse of each computed point (the ellipse_* columns "
        "x 2.1460, chi-square 2 dof), at the point's height; counterclockwise"
    )
    if any(c is None for c in ell):
        return lay
    r90 = math.sqrt(-2.0 * math.log(0.1))
    for k in range(n):
        a, b, az = (float(c[k]) for c in ell)
        coords = None
        if ok(comp, k) and all(np.isfinite((a, b, az))):
            # counterclockwise (RFC 7946): geoloc.geodesy.local.ellipse_ring_enu
            h0 = float(comp[2][k])
            la, lo, _ = enu_to_geodetic_deg(
                ellipse_ring_enu(r90 * a, r90 * b, az, ELLIPSE_VERTICES),
                float(comp[0][k]),
                float(comp[1][k]),
                h0 if np.isfinite(h0) else 0.0,
            )
            pts = [(float(x), float(y), h0) for x, y in zip(lo, la)]
            coords = pts + [pts[0]]
        lay.features.append(
            _Feature(
                coords,
                row_attrs(
                    k,
                    ce90_m=_opt(ce[k]) if ce is not None else None,
                    le90_m=_opt(le[k]) if le is not None else None,
                    semi_major_90_m=_opt(r90 * a),
                    semi_minor_90_m=_opt(r90 * b),
                    azimuth_deg=_opt(az),
                ),
                f"ellipse {labels[k]}",
                k,
                t_of(k),
            )
        )
    return lay


def _signed_area(pts) -> float:
    """Shoelace area in degrees^2 of a ring of (lon, lat, h): > 0 counterclockwise."""
    lon0 = pts[0][0]
    xy = [(((p[0] - lon0 + 180.0) % 360.0) - 180.0, p[1]) for p in pts]
    return 0.5 * sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in zip(xy, xy[1:] + xy[:1]))


# --------------------------------------------------------------------------- export


def resolve_format(format: str | None, out_path: str | os.PathLike[str]) -> str:
    """The format name from ``format`` (any case, aliases) or the output's extension."""
    allowed = ", ".join(FORMATS)
    if format is not None:
        f = _ALIASES.get(str(format).strip().lower())
        if f is None:
            raise ValueError(f"unknown format {format!r}: choose one of {allowed}")
        return f
    ext = Path(out_path).suffix.lower()
    if ext not in EXTENSIONS:
        raise ValueError(
            f"cannot tell the format from the extension {ext or '(none)'!r} of {str(out_path)!r}: "
            f"give a format (one of {allowed}) or use one of {', '.join(EXTENSIONS)}"
        )
    return EXTENSIONS[ext]


def geojson_paths(out_path: str | os.PathLike[str]) -> dict:
    """GeoJSON file of each layer: ``OUT.geojson`` for the points, ``OUT_<layer>.geojson`` for the others."""
    p = Path(out_path)
    if not p.suffix:
        p = p.with_name(p.name + ".geojson")
    return {name: p if name == "points" else p.with_name(f"{p.stem}_{name}{p.suffix}") for name in LAYERS}


def export(
    table: dict | str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    format: str | None = None,
    *,
    group_by: str | None = None,
    epoch: str = DEFAULT_EPOCH,
    require_rows: bool = False,
) -> ExportSummary:
    """Write a results table to GeoPackage, GeoJSON, KML or CZML.

    Parameters
    ----------
    table : dict or path
        Column name -> array or list (as :func:`read_results` returns), or the
        path of a results CSV.
    out_path : path
        Output file. GeoJSON writes one file per layer (``OUT.geojson`` and
        ``OUT_<layer>.geojson``, see :func:`geojson_paths`).
    format : {"gpkg", "geojson", "kml", "czml"}, optional
        Default: from the extension (.gpkg, .geojson/.json, .kml, .czml).
    group_by : str, optional
        Column that groups rows into flights for the track (default ``table``
        when present, else one flight).
    epoch : str
        ISO 8601 time that ``time_s`` counts from, and the start of synthesized
        times (one second per row) when the table has no time column.
    require_rows : bool
        Refuse an empty table (a 0-byte file, a header without rows) instead of
        writing valid empty layers (``geoloc export`` sets it: docs/cli.md).

    Returns
    -------
    ExportSummary
        Paths, features per layer, features with an empty geometry, rows without
        a computed position.

    Raises
    ------
    ValueError
        An empty table with ``require_rows``, unknown format (names it and the allowed
        ones), unknown group-by column,
        unparseable h_datum or time, a table without computed positions (``lat_deg``,
        ``lon_deg``: a records CSV that was never replayed).
    FileNotFoundError
        Missing input file or output folder.
    """
    fmt = resolve_format(format, out_path)
    source = "the results table"
    if isinstance(table, (str, os.PathLike)):
        source = str(table)
        table = read_results(table)
    if require_rows and not table:  # a 0-byte file: an empty GeoPackage said nothing
        raise ValueError(f"{source}: empty (no header line, no rows): nothing to export")
    if require_rows and not len(next(iter(table.values()))):
        raise ValueError(f"{source}: a header and no rows: nothing to export")
    if table and not ("lat_deg" in table and "lon_deg" in table):
        # a records CSV never replayed: six layers of empty geometries said nothing
        hint = (
            " (it has the records' columns: replay it first, `geoloc replay FILE --out results.csv`, "
            "then export results.csv)"
            if "ac_lat_deg" in table
            else ""
        )
        raise ValueError(
            f"{source}: no computed positions (columns lat_deg and lon_deg): not the results of a replay{hint}"
        )
    out = Path(out_path)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"{out}: output folder {str(out.parent)!r} does not exist")
    layers, ctx = build_layers(table, group_by=group_by, epoch=epoch)
    notes = []
    if ctx.time_source == "row_order" and fmt == "czml":
        notes.append(f"no time column (time_s / time_utc): one second per row synthesized from {epoch}")
    elif ctx.time_source == "row_order" and fmt == "kml":
        notes.append("no time column (time_s / time_utc): the KML features carry no time stamps")
    if fmt == "gpkg":
        paths = _write_ogr(layers, {name: out for name in LAYERS}, "GPKG")
    elif fmt == "geojson":
        paths = _write_ogr(layers, geojson_paths(out), "GeoJSON")
    elif fmt == "kml":
        paths = [_write_kml(layers, ctx, out)]
    else:
        paths = [_write_czml(layers, ctx, out, epoch)]
    return ExportSummary(
        fmt,
        [str(p) for p in paths],
        ctx.n,
        {k: len(v.features) for k, v in layers.items()},
        {k: v.without_geometry() for k, v in layers.items()},
        list(ctx.rows_without_position),
        ctx.missing_text(ctx.rows_without_position),
        ctx.time_source,
        notes,
    )


def _require(module: str, pip_name: str):
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"this export needs {pip_name}: pip install {pip_name}") from None


# --------------------------------------------------------------------------- GeoPackage / GeoJSON


def wkb(geometry: str, coords: Sequence[Sequence[float]], z: bool) -> bytes:
    """ISO WKB (little-endian) of a Point, LineString or single-ring Polygon."""
    code = _Z_TYPES[geometry] + (1000 if z else 0)
    fmt = "<ddd" if z else "<dd"
    body = b"".join(struct.pack(fmt, *(c[:3] if z else c[:2])) for c in coords)
    head = struct.pack("<BI", 1, code)
    if geometry == "Point":
        return head + body
    if geometry == "LineString":
        return head + struct.pack("<I", len(coords)) + body
    return head + struct.pack("<II", 1, len(coords)) + body


def _ogr_columns(layer):
    names, data, masks = [], [], []
    for name, typ in layer.fields:
        vals = [f.attrs.get(name) for f in layer.features]
        if typ == "text":
            arr = np.empty(len(vals), dtype=object)
            arr[:] = [None if v is None else str(v) for v in vals]
            mask = None
        elif typ == "real":
            arr = np.array([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
            mask = None  # NaN is written as null
        else:
            arr = np.array([0 if v is None else int(v) for v in vals], dtype=np.int64)
            mask = np.array([v is None for v in vals], dtype=bool)
        names.append(name)
        data.append(arr)
        masks.append(mask)
    return names, data, masks


def _write_ogr(layers, paths, driver):
    raw = _require("pyogrio.raw", "pyogrio")
    written = []
    with contextlib.ExitStack() as stack:  # every file renamed into place once all its layers are in
        tmp = {p: stack.enter_context(atomic_path(p)) for p in dict.fromkeys(paths.values())}
        for name in LAYERS:
            _write_ogr_layer(raw, layers[name], name, str(tmp[paths[name]]), driver)
            written.append(paths[name])
    return list(dict.fromkeys(written))


def _write_ogr_layer(raw, layer, name, path, driver) -> None:
    """One layer into an OGR file (a GeoPackage takes several; GeoJSON one a file)."""
    z = layer.has_z()
    geoms = np.empty(len(layer.features), dtype=object)
    geoms[:] = [wkb(layer.geometry, f.coords, z) if f.coords else None for f in layer.features]
    names, data, masks = _ogr_columns(layer)
    desc = f"{layer.description}. Heights: metres above the WGS 84 ellipsoid (h_datum = {ELLIPSOID_DATUM!r})."
    opts = {"DESCRIPTION": desc}
    if driver == "GeoJSON":
        opts.update({"RFC7946": "YES", "COORDINATE_PRECISION": "12"})
    raw.write(
        path,
        geoms,
        data,
        names,
        field_mask=masks,
        layer=name,
        driver=driver,
        geometry_type=layer.geometry + (" Z" if z else ""),
        crs="EPSG:4979" if z else "EPSG:4326",
        layer_options=opts,
    )


# --------------------------------------------------------------------------- KML

_KML_COLORS = {  # aabbggrr
    "points": "ff0000ff",
    "truth": "ff00ff00",
    "reported": "ffff8800",
    "error_vectors": "ff00ffff",
    "footprints": "ff00ffff",
    "track": "ffffffff",
    "ellipses": "ffff00ff",
}


def _describe_heights_kml() -> str:
    return (
        "KML altitudes are above mean sea level: absolute altitudes here are EGM96 orthometric "
        "heights H = h - N (h ellipsoidal WGS 84, N from the bundled EGM96 grid, geoloc.geodesy.geoid); "
        "positions without a height are clampToGround. The attribute h_m keeps the ellipsoidal height."
    )


def _document_description(ctx, layers, extra) -> str:
    lines = [f"geoloc results: {ctx.n} rows."]
    lines += extra
    missing = ctx.missing_text(ctx.rows_without_position)
    if missing:
        lines.append(f"Rows without a computed position ({len(missing)}): " + "; ".join(missing) + ".")
    else:
        lines.append("Every row has a computed position.")
    for name in LAYERS:
        lay = layers[name]
        lines.append(f"{name}: {len(lay.features)} features, {lay.without_geometry()} without a position.")
    return "\n".join(lines)


def _write_kml(layers, ctx, out):
    simplekml = _require("simplekml", "simplekml")
    kml = simplekml.Kml(name=out.stem)
    extra = [_describe_heights_kml()]
    if not ctx.real_time:
        extra.append("No time column: the features carry no time stamps.")
    kml.document.description = _document_description(ctx, layers, extra)
    for name in LAYERS:
        layer = layers[name]
        folder = kml.newfolder(name=name)
        style = simplekml.Style()
        color = _KML_COLORS[name]
        style.iconstyle.color = color
        style.linestyle.color = color
        style.linestyle.width = 3 if name == "track" else 2
        style.polystyle.color = "4000ffff"
        missing = []
        for f in layer.features:
            pts = f.coords
            if not pts:
                missing.append(
                    ctx.missing_text([f.row])[0]
                    if name == "points"
                    else f.label
                    if f.row is None
                    else f"row {f.row} ({ctx.labels[f.row]})"
                )
                continue
            lon = np.array([c[0] for c in pts])
            lat = np.array([c[1] for c in pts])
            h = np.array([c[2] for c in pts])
            und = _undulation(lat, lon)
            absolute = bool(np.all(np.isfinite(h)) and np.all(np.isfinite(und)))
            if absolute:
                coords = [(float(x), float(y), float(z)) for x, y, z in zip(lon, lat, h - und)]
                mode = simplekml.AltitudeMode.absolute
            else:
                coords = [(float(x), float(y)) for x, y in zip(lon, lat)]
                mode = simplekml.AltitudeMode.clamptoground
            if layer.geometry == "Point":
                g = folder.newpoint(name=f.label, coords=coords)
            elif layer.geometry == "LineString":
                g = folder.newlinestring(name=f.label, coords=coords)
            else:
                g = folder.newpolygon(name=f.label, outerboundaryis=coords)
            g.altitudemode = mode
            if not absolute and layer.geometry != "Point":
                g.tessellate = 1
            g.style = style
            for k, v in f.attrs.items():
                if v is not None:
                    g.extendeddata.newdata(k, html.escape(str(v), quote=False))
            g.extendeddata.newdata(
                "altitude", "EGM96 orthometric H = h - N (absolute)" if absolute else "clampToGround (no height)"
            )
            if layer.geometry == "Point" and absolute:
                g.extendeddata.newdata("egm96_undulation_m", repr(float(und[0])))
            if ctx.real_time:
                if f.times:
                    g.timespan.begin = ctx.iso(f.times[0])
                    g.timespan.end = ctx.iso(f.times[-1])
                elif f.time is not None:
                    g.timestamp.when = ctx.iso(f.time)
        desc = f"{layer.description}. {len(layer.features)} features"
        if missing:
            desc += f"; without a position ({len(missing)}): " + "; ".join(missing)
        folder.description = desc + "."
    write_bytes(out, _kml_schema_order(kml.kml(format=False)))
    return out


_KML_NS = "http://www.opengis.net/kml/2.2"
_GX_NS = "http://www.google.com/kml/ext/2.2"
#: Feature elements the KML 2.2 schema puts before a StyleSelector (Style, StyleMap).
_BEFORE_STYLE = {
    "name",
    "visibility",
    "open",
    "author",
    "link",
    "address",
    "AddressDetails",
    "phoneNumber",
    "Snippet",
    "snippet",
    "description",
    "LookAt",
    "Camera",
    "TimeStamp",
    "TimeSpan",
    "styleUrl",
}


def _kml_schema_order(text: str) -> bytes:
    """Two fixes to simplekml's output for the KML 2.2 schema: a container's Style goes after its
    name/description (simplekml writes it first), and ids start with a letter."""
    import xml.etree.ElementTree as ET

    ET.register_namespace("", _KML_NS)
    ET.register_namespace("gx", _GX_NS)
    root = ET.fromstring(text.encode("utf-8"))
    style_tags = {f"{{{_KML_NS}}}Style", f"{{{_KML_NS}}}StyleMap"}
    # simplekml's ids are bare numbers from a counter of the whole process (a second KML written by
    # the same process had other ids: `export --out -` against `--out FILE`); the schema's
    # xsd:ID must start with a letter: k1, k2, ... in the order of the document
    ids: dict[str | None, str] = {}
    for el in root.iter():
        if "id" in el.attrib:
            ids.setdefault(el.get("id"), f"k{len(ids) + 1}")
    for el in root.iter():
        if "id" in el.attrib:
            el.set("id", ids[el.get("id")])
        if el.tag == f"{{{_KML_NS}}}styleUrl" and el.text and el.text.startswith("#"):
            el.text = "#" + ids.get(el.text[1:], f"k{el.text[1:]}")
        if el.tag not in (f"{{{_KML_NS}}}Document", f"{{{_KML_NS}}}Folder"):
            continue
        styles = [c for c in el if c.tag in style_tags]
        for s in styles:
            el.remove(s)
        head = 0
        for i, c in enumerate(el):
            if c.tag.rsplit("}", 1)[-1] in _BEFORE_STYLE:
                head = i + 1
        for j, s in enumerate(styles):
            el.insert(head + j, s)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


# --------------------------------------------------------------------------- CZML

_CZML_COLORS = {
    "points": [255, 0, 0, 255],
    "truth": [0, 255, 0, 255],
    "reported": [0, 136, 255, 255],
    "error_vectors": [255, 255, 0, 255],
    "footprints": [255, 255, 0, 70],
    "track": [255, 255, 255, 255],
    "ellipses": [255, 0, 255, 90],
}


def _html_table(attrs) -> str:
    rows = "".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>"
        for k, v in attrs.items()
        if v is not None
    )
    return f"<table>{rows}</table>"


def _write_czml(layers, ctx, out, epoch):
    """The layers as one CZML document (czml3): the document packet with its clock, then a packet
    per feature: the platform's track as a moving point with its path, the others as points,
    polylines or polygons, each shown from its time on."""
    C = _require("czml3", "czml3")
    times = [t for t in ctx.seconds if np.isfinite(t)]
    start = float(min(times)) if times else 0.0
    stop = (float(max(times)) if times else 0.0) + 1.0  # one second past the last record, so it shows
    packets = [_czml_document(C, layers, ctx, out, epoch, start, stop)]
    stop_iso = ctx.iso(stop)
    for name in LAYERS:
        layer = layers[name]
        for f in layer.features:
            common = {
                "name": f.label,
                "description": _html_table(f.attrs),
                "properties": {k: v for k, v in f.attrs.items() if v is not None},
            }
            if name == "track":
                packet = _czml_track(C, f, layer, ctx, stop_iso, common) if f.samples else None
            else:
                packet = _czml_feature(C, f, name, layer, ctx, stop_iso, common) if f.coords else None
            if packet is not None:
                packets.append(packet)
    with atomic_path(out) as tmp:
        C.Document(packets=packets).save(str(tmp))
    return out


def _czml_document(C, layers, ctx, out, epoch, start: float, stop: float):
    """The CZML document packet: its description (the heights and where the times come from)
    and a clock over the records' span, one minute of play at the least multiplier."""
    from czml3.enums import ClockRanges, ClockSteps

    extra = [
        (
            "Heights are metres above the WGS 84 ellipsoid (CZML cartographicDegrees); "
            "positions without a height are clamped to the ground."
        )
    ]
    if ctx.time_source == "row_order":
        extra.append(
            f"The results have no time column (time_s / time_utc): times are synthesized, "
            f"one second per row from {epoch}."
        )
    elif ctx.time_source == "time_s":
        extra.append(f"Times are time_s seconds after {epoch}.")
    else:
        extra.append("Times are the time_utc column.")
    clock = C.Clock(
        interval=C.TimeInterval(start=ctx.iso(start), end=ctx.iso(stop)),
        currentTime=ctx.iso(start),
        multiplier=max(1.0, (stop - start) / 60.0),
        range=ClockRanges.CLAMPED,
        step=ClockSteps.SYSTEM_CLOCK_MULTIPLIER,
    )
    return C.Packet(
        id="document",
        name=out.stem,
        version=C.CZML_VERSION,
        description=_document_description(ctx, layers, extra),
        clock=clock,
    )


def _czml_color(C, name: str):
    """A layer's CZML colour."""
    return C.Color(rgba=_CZML_COLORS[name])


def _czml_clamp(has_h: bool):
    """The height reference of a position: None with heights, else clamped to the ground."""
    from czml3.enums import HeightReferences
    from czml3.properties import HeightReference

    return None if has_h else HeightReference(heightReference=HeightReferences.CLAMP_TO_GROUND)


def _czml_track(C, f, layer, ctx, stop_iso: str, common: dict):
    """The platform's packet: a point moving along its samples (linear interpolation, time from
    its first sample) drawn with its path, or one fixed point from its time to the end."""
    from czml3.enums import InterpolationAlgorithms

    s = f.samples
    has_h = all(np.isfinite(c[2]) for c in s)
    if len(s) >= 2:
        t0 = f.times[0]
        vals = []
        for t, c in zip(f.times, s):
            vals += [t - t0, c[0], c[1], c[2] if has_h else 0.0]
        pos = C.Position(
            epoch=ctx.iso(t0),
            cartographicDegrees=vals,
            interpolationAlgorithm=InterpolationAlgorithms.LINEAR,
            interpolationDegree=1,
        )
        avail = C.TimeInterval(start=ctx.iso(t0), end=ctx.iso(f.times[-1]))
    else:
        c = s[0]
        pos = C.Position(cartographicDegrees=[c[0], c[1], c[2] if has_h else 0.0])
        avail = C.TimeInterval(start=ctx.iso(f.times[0]), end=stop_iso)
    return C.Packet(
        id=f"platform/{f.attrs.get(layer.fields[0][0])}",
        availability=avail,
        position=pos,
        point=C.Point(pixelSize=10, color=_czml_color(C, "track"), heightReference=_czml_clamp(has_h)),
        path=C.Path(
            width=2,
            leadTime=0,
            resolution=1,
            material=C.PolylineMaterial(solidColor=C.SolidColorMaterial(color=_czml_color(C, "track"))),
        ),
        **common,
    )


def _czml_feature(C, f, name: str, layer, ctx, stop_iso: str, common: dict):
    """A point, polyline or polygon feature's packet (a polygon's ring without its closing
    point), shown from its time on; without heights clamped to the ground."""
    avail = C.TimeInterval(start=ctx.iso(f.time), end=stop_iso) if f.time is not None else None
    pid = f"{name}/{f.attrs.get('source') or f.attrs.get('target') or ''}/{f.row}".replace("//", "/")
    has_h = all(np.isfinite(c[2]) for c in f.coords)
    flat = []
    for c in f.coords[:-1] if layer.geometry == "Polygon" else f.coords:
        flat += [c[0], c[1], c[2] if has_h else 0.0]
    color = _czml_color(C, name)
    if layer.geometry == "Point":
        point = C.Point(pixelSize=8, color=color, heightReference=_czml_clamp(has_h))
        return C.Packet(
            id=pid, availability=avail, position=C.Position(cartographicDegrees=flat), point=point, **common
        )
    if layer.geometry == "LineString":
        polyline = C.Polyline(
            positions=C.PositionList(cartographicDegrees=flat),
            width=2,
            material=C.PolylineMaterial(solidColor=C.SolidColorMaterial(color=color)),
            clampToGround=None if has_h else True,
        )
        return C.Packet(id=pid, availability=avail, polyline=polyline, **common)
    polygon = C.Polygon(
        positions=C.PositionList(cartographicDegrees=flat),
        material=C.Material(solidColor=C.SolidColorMaterial(color=color)),
        outline=True,
        outlineColor=C.Color(rgba=[255, 255, 0, 255]),
        perPositionHeight=True if has_h else None,
        heightReference=_czml_clamp(has_h),
    )
    return C.Packet(id=pid, availability=avail, polygon=polygon, **common)
