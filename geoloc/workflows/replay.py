"""Flight-test replay: geolocate every record and measure it against published and surveyed positions.

[Q17 section 4]: the records of Tables 3-4, each a pixel, the POS pose and the
gimbal encoders, located here on the ellipsoid inflated to a target height (a
height column) — the terrain variant lives in :mod:`geoloc.surfaces.terrain`. Distances
are horizontal geodesic distances on WGS-84 (pyproj's Karney solver).
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.io.records import Records
from geoloc.io.mgrs_grid import mgrs_column
from geoloc.locate import line_of_sight
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.progress import Progress
from geoloc.sensors.frame import FrameSensor
from geoloc.status import Status, names
from geoloc.surfaces.base import GroundPoint, LineOfSight, terrain_of
from geoloc.surfaces.height import for_records
from geoloc.surfaces.terrain import TerrainHit, surface_for
from geoloc.userfiles import atomic_path

if TYPE_CHECKING:
    from geoloc.surfaces.dem import DEM
    from geoloc.sensors.base import Sensor
    from geoloc.sensors.budget import ErrorBudget
    from geoloc.surfaces.base import DemSource, MosaicSource, Surface

#: Columns the replay adds to every input row.
OUTPUT_COLUMNS = ["lat_deg", "lon_deg", "h_m", "error_to_paper_m", "error_to_truth_m"]


@dataclass
class ReplayResult:
    """Per-record results of a replay (arrays aligned with ``records.rows``)."""

    records: Records
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    h_m: np.ndarray
    status: np.ndarray
    error_to_paper_m: np.ndarray
    error_to_truth_m: np.ndarray
    extra: dict  # further output columns, name -> array (e.g. DEM evaluations)
    terrain: DEM | MosaicSource | None = None  # the DEM (or mosaic) located on, if any: for plausibility_warnings

    def columns(self) -> dict:
        cols = {
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "h_m": self.h_m,
            "error_to_paper_m": self.error_to_paper_m,
            "error_to_truth_m": self.error_to_truth_m,
        }
        cols.update(self.extra)
        return cols


def records_line_of_sight(records: Records, camera: FrameSensor) -> LineOfSight:
    """The line of sight of every good record (pixel row/col through the record's chain).

    Recorded pixels off the sensor are extended through the lens model (the
    replay flags them OUTSIDE_SENSOR and :func:`outside_sensor_messages` names
    them), so one off-sensor record neither vanishes nor passes unnoticed.
    """
    return line_of_sight(records.pose(), camera, records.column("row"), records.column("col"), outside="extrapolate")


def outside_sensor_mask(records: Records, camera: Sensor) -> NDArray[np.bool_]:
    """True for the records whose pixel lies off the sensor."""
    s = camera
    return ~s.in_image(records.column("row"), records.column("col"))


def outside_sensor_messages(records: Records, camera: Sensor, lat: np.ndarray | None = None) -> list[str]:
    """One message per record whose pixel is off the sensor: line, label, value and the sensor's size.

    ``lat`` (the replay's latitudes, optional) tells the records located by extending the lens
    model from those too far out for it (a distortion model has no ray there: NaN)."""
    s = camera
    row, col = records.column("row"), records.column("col")
    labels = records.labels()
    out = []
    for k in np.flatnonzero(outside_sensor_mask(records, camera)):
        what = []
        if not 0.5 <= row[k] <= s.rows + 0.5:
            what.append(f"row = {row[k]:g} (rows 1-{s.rows})")
        if not 0.5 <= col[k] <= s.cols + 0.5:
            what.append(f"col = {col[k]:g} (columns 1-{s.cols})")
        how = (
            "located by extending the lens model"
            if lat is None or np.isfinite(lat[k])
            else "too far out for the lens model to give a ray there: not located"
        )
        out.append(
            f"line {records.lines[k]} ({labels[k]}): {' and '.join(what)} is outside the sensor; "
            f"{how}, flagged outside_sensor"
        )
    return out


def result_from_ground(
    records: Records, ground: GroundPoint, extra: dict[str, np.ndarray] | None = None, camera: Sensor | None = None
) -> ReplayResult:
    """Wrap ground points with the distances to the published and surveyed positions.

    With ``camera``, records whose pixel is off its sensor get status
    OUTSIDE_SENSOR (their position is kept: see :func:`records_line_of_sight`).
    """
    lat, lon = ground.lat_deg, ground.lon_deg
    status = np.asarray(ground.status)
    extra = dict(extra or {})
    if camera is not None:
        # a pixel far off the sensor has no ray through a distortion model (NaN: INVALID_INPUT
        # from the line of sight); its reason is still that it is off the sensor, which says what to fix
        lens_nan = (status == Status.INVALID_INPUT) & ~np.broadcast_to(records.pose().invalid_mask(), status.shape)
        off = outside_sensor_mask(records, camera) & ((status == Status.OK) | lens_nan)
        status = np.where(off, np.uint8(Status.OUTSIDE_SENSOR), status).astype(np.uint8)
        if "status" in extra:
            extra["status"] = status

    def err(prefix):
        if records.has(f"{prefix}_lat_deg") and records.has(f"{prefix}_lon_deg"):
            return horizontal_distance_m(
                lat, lon, records.column(f"{prefix}_lat_deg"), records.column(f"{prefix}_lon_deg")
            )
        return np.full(len(records), np.nan)

    return ReplayResult(records, lat, lon, ground.h, status, err("paper"), err("truth"), extra)


#: Plausibility: a located point farther from its truth than this fraction of its slant range
#: (and than :data:`IMPLAUSIBLE_ERROR_M`) is warned about. A pointing error of 0.05 rad (2.9 deg)
#: is far beyond any gimbal's encoders and calibration; a height in feet read as metres (x 3.28)
#: or a datum mix-up gives errors of that order of the range (a feet column read as metres gave 41 km errors, all `ok`).
IMPLAUSIBLE_ERROR_FRACTION = 0.05
IMPLAUSIBLE_ERROR_M = 50.0
#: The camera counts as below the terrain under it when lower than the DEM by this much [m]
#: (a DEM's own error is a few metres to tens of metres: SRTM 16 m LE90).
BELOW_TERRAIN_M = 30.0


#: The records column that names each row's platform (:func:`geoloc.sensors.platform.is_drone`).
PLATFORM_COLUMN = "platform"


def drone_rows(records: Records, sensor: object = None) -> NDArray[np.bool_]:
    """True for the records whose platform is a drone: the row's ``platform`` column names one,
    or (where the row has no such cell) the sensor file's ``platform`` does
    (:func:`geoloc.sensors.platform.is_drone`; ``docs/records.md``, "Plausibility checks")."""
    from geoloc.sensors.platform import is_drone

    default = is_drone(getattr(sensor, "platform", ""))
    if PLATFORM_COLUMN not in records.header:
        return np.full(len(records), default)
    return np.array([is_drone(t) if t.strip() else default for t in records.text(PLATFORM_COLUMN)], dtype=bool)


def plausibility_warnings(
    records: Records, result: ReplayResult, terrain: DemSource | None = None, limit: int = 5, sensor: object = None
) -> list[str]:
    """Warnings for records whose numbers cannot be right, without changing them (a unit or datum
    mix-up still gives status ok).

    - the camera below the terrain under it (``terrain``: a DEM or DEM mosaic, whose
      ``sample(lat, lon)`` gives ellipsoidal heights), by more than :data:`BELOW_TERRAIN_M`;
    - a drone's camera (:func:`drone_rows`: ``sensor``'s platform, a ``platform`` column) more
      than :data:`~geoloc.sensors.platform.DRONE_MAX_HEIGHT_M` above the terrain under it (else
      above the located point's height: the target's), or above
      :data:`~geoloc.sensors.platform.DRONE_CEILING_M` anywhere;
    - a located point farther from its truth than :data:`IMPLAUSIBLE_ERROR_FRACTION` of the
      slant range (a height in feet read as metres, a datum or a sensor mixed up).

    Each names the line, the record and the values; at most ``limit`` lines per kind, then
    a count. Heights are ellipsoidal (WGS 84), as everywhere in the records.
    """
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    out = []
    labels = records.labels()
    c = records.column
    ac_lat, ac_lon, ac_h = c("ac_lat_deg"), c("ac_lon_deg"), c("ac_h_m")

    def add(kind, idx, text):
        for k in idx[:limit]:
            out.append(f"line {records.lines[k]} ({labels[k]}): {text(k)}")
        if len(idx) > limit:
            out.append(f"... and {len(idx) - limit} more record(s) {kind}")

    below = np.zeros(0, int)
    if terrain is not None:
        ht, _ = terrain.sample(np.deg2rad(ac_lat), np.deg2rad(ac_lon))
        with np.errstate(invalid="ignore"):
            below = np.flatnonzero(ac_h < ht - BELOW_TERRAIN_M)
        add(
            "with the camera below the terrain",
            below,
            lambda k: (
                f"the camera (ac_h_m = {ac_h[k]:.1f} m) is {ht[k] - ac_h[k]:.0f} m below the terrain under "
                f"it ({ht[k]:.1f} m, the DEM), heights ellipsoidal: a height in the wrong datum or unit "
                "(MSL read as ellipsoidal, feet as metres), or above the ground instead of the ellipsoid?"
            ),
        )
    ht_ok = None
    if terrain is not None:
        ht_ok = np.where(np.isfinite(ht), ht, np.nan)
    drone_high = _drone_height_warnings(records, result, ht_ok, sensor)
    add("too high for a drone", drone_high[0], drone_high[1])
    err = np.asarray(result.error_to_truth_m, float)
    if np.isfinite(err).any():
        p_cam = geodetic_to_ecef(np.deg2rad(ac_lat), np.deg2rad(ac_lon), ac_h)
        p_hit = geodetic_to_ecef(np.deg2rad(result.lat_deg), np.deg2rad(result.lon_deg), result.h_m)
        slant = np.linalg.norm(p_hit - p_cam, axis=-1)
        with np.errstate(invalid="ignore"):
            far = (err > IMPLAUSIBLE_ERROR_FRACTION * slant) & (err > IMPLAUSIBLE_ERROR_M)
        far[below] = False  # said already: the camera is below the terrain
        far = np.flatnonzero(far)
        add(
            "far from their truth",
            far,
            lambda k: (
                f"located {err[k]:.0f} m from its truth, {100 * err[k] / slant[k]:.0f} % of its slant range "
                f"({slant[k]:.0f} m): implausible for a pointing error; a height or angle in the wrong unit or "
                "datum, or the wrong sensor?"
            ),
        )
    return out


def _drone_height_warnings(records: Records, result: ReplayResult, ground, sensor):
    """(indices, text of index) of the drone records too high for a drone: above the terrain
    ``ground`` (None or NaN where unknown: the located point's height instead) by more than
    DRONE_MAX_HEIGHT_M, or above DRONE_CEILING_M."""
    from geoloc.sensors.platform import (
        DRONE_CEILING_M,
        DRONE_MAX_HEIGHT_M,
        drone_height_hint,
        drone_height_where,
        drone_too_high,
    )

    drone = drone_rows(records, sensor)
    if not drone.any():
        return np.zeros(0, int), None
    ac_h = records.column("ac_h_m")
    high, ref, what = drone_too_high(ac_h, result.h_m, ground)
    high &= drone
    src = records.altitude
    field = (
        "ac_h_m"
        if src.column in ("ac_h_m", "") or src.column not in records.header
        else f"{src.column} (read as ac_h_m, {src.unit}, {src.datum})"
    )

    def text(k):
        cell = records.rows[k].get(src.column if field != "ac_h_m" else "ac_h_m", "").strip() or f"{ac_h[k]:.1f}"
        known = np.isfinite(ref[k])
        where = drone_height_where(ac_h[k], ref[k], what[k])
        try:  # the hint in the file's own datum (an EGM96 column's value is H, ac_h_m is H + N)
            value = float(cell)
        except ValueError:
            value = ac_h[k]
        ref_file = ref[k] - (ac_h[k] - value) if known else None
        return (
            f"{field} = {cell}: a drone's camera {where}, while drones fly below "
            f"{DRONE_MAX_HEIGHT_M:.0f} m above the ground and {DRONE_CEILING_M:.0f} m above the sea: "
            + drone_height_hint(
                value,
                ref_file,
                src.unit,
                "a height column in feet needs unit = 'ft' in the column map (docs/columns.md)",
            )
            + "; the row is used as read"
        )

    return np.flatnonzero(high), text


#: Records located per call of the pipeline [records]: the unit of the replay's progress (docs/cli.md,
#: "Progress"). A ray's answer does not depend on its batch, so the chunk changes the pace, not a byte.
REPLAY_CHUNK = 20_000


def _take_rows(obj, sl: slice):
    """Rows ``sl`` of a batch dataclass (a :class:`LineOfSight`): every array with a leading record axis."""
    kw = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1:
            kw[f.name] = v[sl]
    return dataclasses.replace(obj, **kw)


def _concat_rows(parts: list):
    """The chunks' answers (:class:`GroundPoint` or a subclass) as one: arrays joined along the records;
    what every chunk has alike (the method, the corrections applied, None) taken from the first."""
    first = parts[0]
    if len(parts) == 1:
        return first
    kw = {}
    for f in dataclasses.fields(first):
        vals = [getattr(p, f.name) for p in parts]
        if isinstance(vals[0], np.ndarray) and vals[0].ndim >= 1:
            kw[f.name] = np.concatenate(vals)
        elif dataclasses.is_dataclass(vals[0]) and not isinstance(vals[0], type):
            kw[f.name] = _concat_rows(vals)
    return dataclasses.replace(first, **kw)


def replay_records(
    records: Records,
    sensor: FrameSensor,
    surface: Surface,
    corrections: Corrections = NO_CORRECTIONS,
    *,
    progress: bool | None = False,
    chunk: int | None = None,
) -> ReplayResult:
    """Locate every record on ``surface`` through the location pipeline: the replay itself.

    Parameters
    ----------
    records : Records
    sensor : FrameSensor
    surface : Surface
        Where the targets lie (:func:`geoloc.surfaces.terrain.surface_for`; on the
        command line :func:`geoloc.cli._options.surface_from_args`): a height, one
        height per record, a DEM or a mosaic.
    corrections : Corrections
        The line-of-sight corrections (:class:`geoloc.pipeline.Corrections`; none by default).

    Returns
    -------
    ReplayResult
        With the columns ``corrections`` (which were applied) and ``refraction_m`` (how far
        refraction moved each point); on a DEM also ``status``, ``dem_evaluations`` (and
        ``hidden`` for ``bisect``) and ``terrain`` (the DEM or mosaic, for
        :func:`plausibility_warnings`).
    progress : bool or None
        :class:`geoloc.progress.Progress` on stderr, one update per ``chunk`` records (None: the bar
        on a terminal, a line every 10 s elsewhere; False, the default of the API: nothing).
    chunk : int, optional
        Records per call of the pipeline (default :data:`REPLAY_CHUNK`).
    """
    chunk = REPLAY_CHUNK if chunk is None else chunk
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk = {chunk!r}: must be a whole number of records >= 1")
    los = records_line_of_sight(records, sensor)
    n = len(records)
    bar = Progress(n, f"replay {Path(str(records.path)).name}", progress)
    parts = []
    for i0 in range(0, max(n, 1), chunk):
        sl = slice(i0, min(i0 + chunk, n))
        part = los if (i0 == 0 and sl.stop == n) else _take_rows(los, sl)
        surf = surface if part is los else for_records(surface, np.arange(sl.start, sl.stop))
        parts.append(Pipeline(sensor, surf, corrections).intersect(part))
        bar.update(sl.stop - sl.start)
    bar.close()
    hit = _concat_rows(parts)
    terrain = terrain_of(surface)
    extra = {"corrections": np.full(len(records), corrections.label, dtype=object), "refraction_m": hit.refraction_m}
    if terrain is not None:  # besides corrections and refraction_m, which every row carries
        extra["status"] = hit.status
        if isinstance(hit, TerrainHit):  # a DEM met alone (a DEM-else-height surface gives plain points)
            extra["dem_evaluations"] = hit.dem_evaluations.astype(np.int64)
            if getattr(surface, "method", None) == "bisect":
                extra["hidden"] = hit.hidden.astype(np.int64)
    result = result_from_ground(records, hit, extra, camera=sensor)
    result.terrain = terrain
    return result


#: The replay CSV's predicted-uncertainty columns (written when the sensor file has an
#: ``[uncertainty]`` table: :func:`uncertainty_columns`).
UNCERTAINTY_COLUMNS = ["ce90_m", "le90_m", "ellipse_major_m", "ellipse_minor_m", "ellipse_azimuth_deg"]


def uncertainty_columns(
    records: Records, sensor: FrameSensor, surface: Surface, budget: ErrorBudget
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Each record's predicted uncertainty (:func:`geoloc.analysis.uncertainty.propagate`) as the
    replay CSV's columns: ``ce90_m le90_m ellipse_major_m ellipse_minor_m ellipse_azimuth_deg``.

    Only for a sensor whose file has an ``[uncertainty]`` table: without one there is no budget to
    propagate, and made-up defaults would print numbers that look measured. A ``time_s`` term needs
    the platform's velocity, which flight records do not carry: it is left out, and said so.

    Returns
    -------
    (dict, list of str)
        The columns (NaN where a record has no point) and the messages to show.
    """
    from geoloc.analysis.uncertainty import propagate
    from geoloc.sensors.budget import ErrorBudget

    messages = []
    if budget.sigma("time_s") > 0:
        messages.append(
            f"{budget.source}: [uncertainty] time_s = {budget.sigma('time_s'):g} s left out of the "
            "predicted uncertainty (the records carry no platform velocity)"
        )
        budget = ErrorBudget(
            {k: v for k, v in budget.sigmas.items() if k != "time_s"}, budget.dem_product, budget.source
        )
    pu = propagate(
        sensor,
        records.pose(),
        records.column("row"),
        records.column("col"),
        budget,
        surface=surface,
        outside="extrapolate",
    )
    ok = np.asarray(pu.status) == Status.OK
    cols = {k: np.where(ok, np.asarray(v, float), np.nan) for k, v in pu.columns().items()}
    return cols, messages


#: The summary notes refraction left off where it would move a point by more than this fraction
#: of the point's predicted CE90 (a tenth: below it the note would be noise).
REFRACTION_NOTE_FRACTION = 0.1


def refraction_note(
    records: Records, sensor: FrameSensor, surface: Surface, corrections: Corrections, result: ReplayResult
) -> str | None:
    """One line when refraction is off but would move points by more than a tenth of their CE90.

    Only with a predicted CE90 (``ce90_m``, from the sensor's ``[uncertainty]`` budget): the
    records are located again with the standard atmosphere and each shift is set against its
    own CE90. None when refraction is on, there is no CE90, or no point moves that far.
    """
    import dataclasses

    ce90 = result.extra.get("ce90_m")
    if corrections.refraction is not None or ce90 is None:
        return None
    from geoloc.corrections.refraction import STANDARD_REFRACTION

    bent = Pipeline(sensor, surface, dataclasses.replace(corrections, refraction=STANDARD_REFRACTION)).intersect(
        records_line_of_sight(records, sensor)
    )
    shift = np.asarray(bent.refraction_m, float)
    with np.errstate(invalid="ignore"):
        big = shift > REFRACTION_NOTE_FRACTION * np.asarray(ce90, float)
    if not big.any():
        return None
    k = int(np.nanargmax(np.where(big, shift, np.nan)))
    return (
        f"refraction is off, but the standard atmosphere would move {int(big.sum())} of {len(records)} "
        f"records by more than a tenth of their predicted CE90 (up to {shift[k]:.1f} m, line "
        f"{records.lines[k]}, CE90 {float(np.asarray(ce90)[k]):.1f} m): --refraction standard applies it"
    )


def replay_at_height(
    records: Records,
    camera: FrameSensor,
    height_column: str | None = None,
    target_h: float | None = None,
    height_kind: str = "inflated",
) -> ReplayResult:
    """:func:`replay_records` at a target height from a column, or one height for all.

    Parameters
    ----------
    records : Records
    camera : FrameSensor
        A sensor file's or a camera file's (:func:`geoloc.sensors.sensor_file.load_sensor`).
    height_column : str, optional
        Column with each target's ellipsoidal height [m] (e.g. ``paper_height_m``).
    target_h : float, optional
        One height for every record, if no column is given.
    height_kind : {"inflated", "geodetic"}
        [Q17 eq. 11] inflated ellipsoid or the exact constant-height surface.
    """
    if height_column is not None:
        h = records.column(height_column)
        bad = ~np.isfinite(h)
        if np.any(bad):
            rows = [int(n) for n in records.lines[bad]]
            raise ValueError(f"height column {height_column!r} is empty or not finite on line(s) {rows}")
    elif target_h is not None:
        h = np.full(len(records), float(target_h))
    else:
        raise ValueError("give a height column or a target height")
    return replay_records(records, camera, surface_for(h, kind=height_kind, per_record=True))


def _nanmean(v) -> float:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def _fmt(v, spec):
    return "" if not np.isfinite(v) else format(float(v), spec)


def write_replay_csv(path: str | os.PathLike[str], result: ReplayResult) -> None:
    """Write every input column of the good rows plus the replay's output columns (and ``mgrs``)."""
    records = result.records
    cols = result.columns()
    # every row's status, with or without a DEM: a row without a position says why
    cols.setdefault("status", result.status)
    # the MGRS reference of each computed point beside its latitude and longitude
    # (geoloc.io.mgrs_grid; '' where there is no point)
    mgrs = mgrs_column(result.lat_deg, result.lon_deg)
    new = [c for c in cols if c not in records.header]
    if "mgrs" not in records.header:
        new.insert(new.index("lon_deg") + 1 if "lon_deg" in new else len(new), "mgrs")
    header = list(records.header) + new
    status = names(result.status)
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for k, row in enumerate(records.rows):
            out = dict(row)
            out["mgrs"] = mgrs[k]
            for name, arr in cols.items():
                v = arr[k]
                if name in ("lat_deg", "lon_deg"):
                    out[name] = _fmt(v, ".8f")
                elif name == "status":
                    out[name] = status[k]
                elif isinstance(v, str):
                    out[name] = v
                elif isinstance(v, (int, np.integer)):
                    out[name] = str(int(v))
                else:
                    out[name] = _fmt(v, ".3f")
            w.writerow([out.get(c, "") for c in header])


def located(result: ReplayResult) -> np.ndarray:
    """True for the records that have a ground point (OK, or OUTSIDE_SENSOR: located by extending
    the lens model); False for the others (their status says why)."""
    return np.isfinite(np.asarray(result.lat_deg, float)) & np.isfinite(np.asarray(result.lon_deg, float))


def not_located_lines(result: ReplayResult) -> list:
    """The summary's word on the records that could not be located: how many, and why, per status
    (``[]`` when every record was located). docs/cli.md: such a replay exits with status 1."""
    from geoloc.status import describe

    lost = ~located(result)
    if not lost.any():
        return []
    st = np.asarray(result.status)[lost]
    why = "; ".join(
        f"{int(np.sum(st == c))} {Status(c).name.lower()} ({describe(c)})" for c in sorted(set(st.tolist()))
    )
    return [f"not located: {int(lost.sum())} of {len(lost)} records: {why}"]


def dem_coverage_warning(result: ReplayResult) -> str | None:
    """A warning when the DEM of a replay does not cover its records: how many aircraft positions
    lie outside it and how many lines of sight left it, with the DEM's bounds and the data's
    (west, south, east, north in degrees); None when it covers them (records outside the DEM used
    to exit 0 without a word)."""
    dem = result.terrain
    r = result.records
    if dem is None or not (r.has("ac_lat_deg") and r.has("ac_lon_deg")):
        return None
    lat, lon = r.column("ac_lat_deg"), r.column("ac_lon_deg")
    w, so, e, n = dem.extent_deg
    with np.errstate(invalid="ignore"):
        outside = ~((lat >= so) & (lat <= n) & (lon >= w) & (lon <= e))
    left = np.asarray(result.status) == Status.LEFT_DEM
    if not (outside.any() or left.any()):
        return None
    fin = np.isfinite(lat) & np.isfinite(lon)
    data = (
        f"W {np.min(lon[fin]):.4f} S {np.min(lat[fin]):.4f} E {np.max(lon[fin]):.4f} N {np.max(lat[fin]):.4f}"
        if fin.any()
        else "no finite position"
    )
    return (
        f"the DEM does not cover the data: {int(outside.sum())} of {len(r)} aircraft positions are outside it "
        f"and {int(left.sum())} lines of sight left it before meeting the terrain; DEM W {w:.4f} S {so:.4f} "
        f"E {e:.4f} N {n:.4f} deg, aircraft {data} deg"
    )


def summary_table(result: ReplayResult, group_column: str = "table", rows: bool = True) -> str:
    """A plain-text table: one line per record (if ``rows``), then per-group means and the RMS to the paper."""
    r = result.records
    labels = r.labels()
    pub = r.column("paper_error_m") if r.has("paper_error_m") else np.full(len(r), np.nan)
    lines = (
        [
            f"{'record':<10} {'lat_deg':>11} {'lon_deg':>11} {'h_m':>9} {'status':>8} "
            f"{'to_paper_m':>10} {'to_truth_m':>10} {'published_m':>11}"
        ]
        if rows
        else []
    )
    st = names(result.status)
    for k in range(len(r) if rows else 0):
        lines.append(
            f"{labels[k]:<10} {_fmt(result.lat_deg[k], '11.5f'):>11} {_fmt(result.lon_deg[k], '11.5f'):>11} "
            f"{_fmt(result.h_m[k], '9.1f'):>9} {st[k]:>8} {_fmt(result.error_to_paper_m[k], '10.2f'):>10} "
            f"{_fmt(result.error_to_truth_m[k], '10.2f'):>10} {_fmt(pub[k], '11.3f'):>11}"
        )
    groups = r.text(group_column) if group_column in r.header else ["all"] * len(r)
    if rows:
        lines.append("")
    for g in sorted(set(groups)):
        m = np.array([x == g for x in groups])
        text = f"group {g}: n={int(m.sum())}"
        if np.any(np.isfinite(result.error_to_truth_m[m])):
            text += f", mean error to truth {_fmt(_nanmean(result.error_to_truth_m[m]), '.2f')} m"
        if np.any(np.isfinite(pub[m])):
            text += f" (published {_fmt(_nanmean(pub[m]), '.2f')} m)"
        if np.any(np.isfinite(result.error_to_paper_m[m])):
            text += f", RMS to published position {_fmt(np.sqrt(_nanmean(result.error_to_paper_m[m] ** 2)), '.2f')} m"
        off = int(np.sum(m & (np.asarray(result.status) == Status.OUTSIDE_SENSOR)))
        if off:
            text += f"; {off} outside the sensor (located by extending the lens model)"
        lost = int(np.sum(m & ~located(result)))
        if lost:
            text += f"; {lost} not located"
        lines.append(text)
    lines += not_located_lines(result)
    if np.any(np.isfinite(result.error_to_paper_m)):
        lines.append(
            f"all: RMS distance to the published positions "
            f"{np.sqrt(_nanmean(result.error_to_paper_m**2)):.2f} m over "
            f"{int(np.isfinite(result.error_to_paper_m).sum())} records"
        )
    return "\n".join(lines)
