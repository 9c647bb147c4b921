"""Replay of drone photos: locate the targets picked in DJI photos and compare them with the truth.

``geoloc replay PHOTOS... --targets T.csv [--dem DEM]`` (``docs/photos.md``). Each
photo gives its own sensor and state (:mod:`geoloc.io.photos`: the lens from its
calibration tags on the earth-referenced ``yaw-pitch-roll`` gimbal, the pose from
its GPS position, altitude and angles); each target, a pixel of a photo, is
located on the DEM (:class:`geoloc.surfaces.terrain.DemSurface`) or, without one,
at its own surveyed height (``truth_h_m``) on the exact surface of that geodetic
height. Errors to truth are horizontal geodesic distances on WGS-84.

Nothing stops the run but a targets file that cannot be read or a run that cannot
give any target a height: a photo without the needed tags is reported by name in
the messages and its targets skipped; a target naming an image that was not given,
or with a value that is not a number, is reported with its line and skipped.

Conventions: ``docs/conventions.md`` (1-based pixel centres, ellipsoidal heights).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.gis import EGM96_DATUM, ELLIPSOID_DATUM
from geoloc.io.mgrs_grid import mgrs_column
from geoloc.io.photos import (
    ALTITUDE_DATUMS,
    PhotoTagError,
    camera_height,
    photo_columns,
    photo_sensor,
    pose_from_photo,
    read_photo,
)
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.platform import DRONE_MAX_HEIGHT_M, drone_height_hint
from geoloc.status import Status, names
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.height import HeightSurface
from geoloc.userfiles import atomic_path
from geoloc.workflows.triangulation import TARGET_ID_COLUMN, triangulate_ids

if TYPE_CHECKING:
    from geoloc.sensors.frame import FrameSensor
    from geoloc.surfaces.base import Surface
    from geoloc.workflows.triangulation import TargetResult

__all__ = ["OUTPUT_COLUMNS", "read_targets", "replay_photos", "summarize", "write_rows"]

#: Columns of every output row, in this order (input columns the targets file adds follow).
OUTPUT_COLUMNS = [
    "image",
    "row",
    "col",
    "lat_deg",
    "lon_deg",
    "mgrs",
    "h_m",
    "h_datum",
    "status",
    "surface",
    "slant_range_m",
    "truth_lat_deg",
    "truth_lon_deg",
    "truth_h_m",
    "error_to_truth_m",
    "vertical_error_m",
    "corrections",
    "refraction_m",
    "sensor_lat_deg",
    "sensor_lon_deg",
    "sensor_h_m",
    "absolute_altitude_m",
    "altitude_datum",
    "geoid_undulation_m",
    "relative_altitude_m",
    "heading_deg",
    "pitch_deg",
    "roll_deg",
    "gimbal_yaw_deg",
    "gimbal_pitch_deg",
    "gimbal_roll_deg",
    "lens",
    "lens_fx_sigma_px",
    "rtk_flag",
    "make",
    "model",
    "maker",
]
#: Required columns of the targets file.
TARGET_COLUMNS = ("image", "row", "col")
#: Optional truth columns (heights ellipsoidal unless ``truth_h_datum="egm96"``).
TRUTH_COLUMNS = ("truth_lat_deg", "truth_lon_deg", "truth_h_m")
#: The camera's height above the DEM and RelativeAltitude (above take-off) disagreeing by more
#: than this [m] gives a message: a datum mix-up (|N| is tens of metres) or a barometric altitude.
ALTITUDE_CHECK_M = 30.0
# A drone photo's camera more than geoloc.sensors.platform.DRONE_MAX_HEIGHT_M above the DEM under
# it (or a RelativeAltitude above it) is warned about as implausible: the records and
# KLV checks use the same number.
#: The datum names written in ``altitude_datum`` for each ``altitude_datum`` argument.
_DATUM_TEXT = {"egm96": EGM96_DATUM, "ellipsoid": ELLIPSOID_DATUM}


def read_targets(
    path: str | os.PathLike[str],
) -> tuple[list[dict[str, Any]], list[str], list[str]]:
    """Read a targets CSV: ``(targets, header, messages)``.

    Each target is a dict with ``line`` (the file's line number), ``image``,
    ``row``, ``col`` (floats, 1-based pixel centres), the truth columns present
    (float or None) and every other column as text. A UTF-8 byte-order mark is
    ignored. A line whose row/col/truth value is not a number is reported in
    ``messages`` and left out.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        No header, a required column missing, a name repeated, or a half truth
        position (only one of truth_lat_deg, truth_lon_deg).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"targets file not found: {path}")
    with p.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ValueError(f"targets file {path} is empty: it needs a header with {list(TARGET_COLUMNS)}")
        header = [h.strip() for h in header]
        dup = sorted({h for h in header if header.count(h) > 1})
        if dup:
            raise ValueError(f"targets file {path}: column(s) {dup} appear more than once in the header")
        missing = [c for c in TARGET_COLUMNS if c not in header]
        if missing:
            raise ValueError(
                f"targets file {path}: column(s) {missing} missing (header: {header}); "
                f"a targets file has columns {list(TARGET_COLUMNS)} (1-based pixel centres) "
                f"and optionally {list(TRUTH_COLUMNS)}"
            )
        if ("truth_lat_deg" in header) != ("truth_lon_deg" in header):
            raise ValueError(f"targets file {path}: give both truth_lat_deg and truth_lon_deg, or neither")
        targets, messages = [], []
        for values in reader:
            line = reader.line_num
            if not any(v.strip() for v in values):
                continue
            if len(values) > len(header):
                messages.append(
                    f"targets file {p.name} line {line}: {len(values)} fields, the header has {len(header)}: skipped"
                )
                continue
            rec = dict(zip(header, [v.strip() for v in values] + [""] * (len(header) - len(values))))
            t: dict[str, Any] = {"line": line}  # a target: its line, numbers, texts (None: not given)
            bad: list[str] = []
            for k, v in rec.items():
                if k in ("row", "col") or k in TRUTH_COLUMNS:
                    if v == "" and k in TRUTH_COLUMNS:
                        t[k] = None
                        continue
                    try:
                        t[k] = float(v)
                    except ValueError:
                        t[k] = math.nan
                    if not math.isfinite(t[k]):
                        bad.append(f"{k} = {v!r} is not a finite number")
                else:
                    t[k] = v
            if not rec["image"]:
                bad.append("image is empty")
            if bad:
                messages.append(f"targets file {p.name} line {line}: {'; '.join(bad)}: skipped")
                continue
            targets.append(t)
    return targets, header, messages


def _photo_index(metas: dict) -> dict:
    """Image names a target may use -> photo key: the file name, and the name without its extension."""
    index: dict[str, str] = {}
    for key in metas:
        index.setdefault(key, key)
        index.setdefault(key.lower(), key)
        stem = Path(key).stem
        index.setdefault(stem, key)
        index.setdefault(stem.lower(), key)
    return index


def _resolve(image: str, index: dict):
    name = Path(image.replace("\\", "/")).name
    for k in (name, name.lower(), Path(name).stem, Path(name).stem.lower()):
        if k in index:
            return index[k]
    return None


def replay_photos(
    photo_paths: Iterable[str | os.PathLike[str]],
    targets_csv: str | os.PathLike[str],
    sensor: FrameSensor | None = None,
    surface: Surface | None = None,
    *,
    altitude_datum: str = "egm96",
    truth_h_datum: str = "ellipsoid",
    targets_out: list[TargetResult] | None = None,
    corrections: Corrections = NO_CORRECTIONS,
    progress: bool | None = False,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Locate every target of ``targets_csv`` in its photo and compare it with its truth.

    Parameters
    ----------
    photo_paths : iterable of path-like
        JPEG or TIFF files with DJI's XMP and EXIF (:func:`geoloc.io.photos.read_photo`).
    targets_csv : path-like
        Columns ``image,row,col`` (the photo's file name, with or without its
        extension; 1-based pixel centres) and optionally
        ``truth_lat_deg,truth_lon_deg[,truth_h_m]``; other columns are copied.
    sensor : FrameSensor, optional
        Replaces every photo's own lens (a calibrated sensor file on the
        ``yaw-pitch-roll`` gimbal), scaled to a resized raster.
    surface : Surface, optional
        Locate on this surface (a DEM's :class:`geoloc.surfaces.terrain.DemSurface` or a
        mosaic: :func:`geoloc.surfaces.terrain.surface_for`). Without one each target
        is located at its own ``truth_h_m`` (the surface of that geodetic height).
    altitude_datum : {"egm96", "ellipsoid"}
        Datum of the photos' AbsoluteAltitude (default EGM96 orthometric: DJI's
        non-RTK aircraft; ``docs/photos.md``).
    truth_h_datum : {"ellipsoid", "egm96"}
        Datum of ``truth_h_m`` (default ellipsoidal, as every height in geoloc).
    targets_out : list, optional
        With a ``target_id`` column in the targets file: each target named in two rows or more
        (seen in several photos) is triangulated from its photos' rays, without any DEM, and its
        :class:`geoloc.workflows.triangulation.TargetResult` appended here (with a DEM, its
        ``surface``: each photo's DEM hit against the intersection;
        :func:`geoloc.workflows.triangulation.triangulate_ids`).
    corrections : Corrections
        The location pipeline's line-of-sight corrections (:class:`geoloc.pipeline.Corrections`;
        none by default); each row says which (``corrections``) and ``refraction_m``.
    progress : bool or None
        :class:`geoloc.progress.Progress` on stderr, counting each photo read and each target
        located (None: the bar on a terminal, a line every 10 s in a log; False, the default: nothing).

    Returns
    -------
    rows : list of dict
        One per located target, columns :data:`OUTPUT_COLUMNS` then the targets
        file's other columns; heights ellipsoidal (``h_datum``), the camera
        height's source datum in ``altitude_datum``.
    messages : list of str
        Photos skipped (by name, with the missing tags), targets skipped (by
        line), notes on each photo (resized, RTK datum, altitude check), pixels
        off the sensor.

    Raises
    ------
    ValueError
        A bad argument; a targets file that cannot be read; no DEM and no
        ``truth_h_m`` column to give targets a height.
    """
    if altitude_datum not in ALTITUDE_DATUMS:
        raise ValueError(f"altitude_datum = {altitude_datum!r}: must be one of {ALTITUDE_DATUMS}")
    if truth_h_datum not in ALTITUDE_DATUMS:
        raise ValueError(f"truth_h_datum = {truth_h_datum!r}: must be one of {ALTITUDE_DATUMS}")
    surface_dem = terrain_of(surface) if surface is not None else None  # the DEM the surface reads
    targets, header, messages = read_targets(targets_csv)
    if surface is None and "truth_h_m" not in header:
        raise ValueError(
            f"no DEM and the targets file {targets_csv} has no truth_h_m column: give a DEM "
            "(--dem) or each target's height (truth_h_m, ellipsoidal unless its datum is "
            "given) so that the targets can be located"
        )

    # ---- the photos
    photo_paths = list(photo_paths)
    from geoloc.progress import Progress

    # the work: each photo read (its tags, its sensor) and each target located
    bar = Progress(len(photo_paths) + len(targets), f"replay {len(photo_paths)} photo(s)", progress)
    photos, bad_photos = _read_photos(photo_paths, sensor, altitude_datum, surface_dem, messages, bar.update)

    # ---- the targets, photo by photo
    by_photo, order = _targets_by_photo(targets, photos, bad_photos, surface is not None, messages)

    extra = [c for c in header if c not in TARGET_COLUMNS and c not in TRUTH_COLUMNS]
    out = {}
    for key, ks in by_photo.items():
        bar.update(len(ks))
        out.update(
            _locate_photo(
                photos[key],
                [targets[k] for k in ks],
                ks,
                surface,
                altitude_datum,
                truth_h_datum,
                extra,
                messages,
                corrections,
            )
        )
    if len(order) < len(targets):
        bar.update(len(targets) - len(order))  # the targets skipped: done with
    bar.close()
    if targets_out is not None and TARGET_ID_COLUMN in header:
        targets_out.extend(_triangulate_targets(photos, targets, by_photo, out, surface is not None))
    return [out[k] for k in order], messages


def _read_photos(
    photo_paths: list,
    sensor: FrameSensor | None,
    altitude_datum: str,
    surface_dem: Any,
    messages: list[str],
    step: Callable[[int], Any] = lambda k: None,
) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """Each photo's tags, sensor, pose and camera height, by file name; the photos that cannot be
    used, by file name, with why (said in ``messages``, as are each photo's notes).

    A second photo of the same file name is ignored (targets name their photo by file name).
    ``step(1)`` is called once per photo (the progress bar)."""
    photos: dict[str, dict[str, Any]] = {}
    bad_photos: dict[str, str] = {}
    for path in photo_paths:
        step(1)
        name = Path(path).name
        if name in photos or name in bad_photos:
            messages.append(
                f"{name}: a second photo with this file name ({path}) is ignored: targets name their photo by file name"
            )
            continue
        try:
            meta = read_photo(path)
            s, lens = photo_sensor(meta, sensor)
            pose = pose_from_photo(meta, altitude_datum)
            h_cam, n = camera_height(meta, altitude_datum)
        except PhotoTagError as e:
            messages.append(f"{e}; its targets are skipped")
            bad_photos[name] = str(e)
            continue
        except (ValueError, OSError) as e:
            messages.append(f"{name}: skipped: {e}")
            bad_photos[name] = str(e)
            continue
        messages.extend(f"{meta.name}: {note}" for note in meta.notes)
        messages.extend(_datum_messages(meta, altitude_datum, h_cam, n, surface_dem))
        photos[name] = {"meta": meta, "sensor": s, "lens": lens, "pose": pose, "h_cam": h_cam, "n": n}
    return photos, bad_photos


def _targets_by_photo(
    targets: list[dict[str, Any]],
    photos: dict[str, Any],
    bad_photos: dict[str, Any],
    on_surface: bool,
    messages: list[str],
) -> tuple[dict[str, list[int]], list[int]]:
    """The targets (indices into ``targets``) each photo locates, and every located target in the
    file's order.

    A target whose photo is not among ``photos`` is skipped: one line per unusable photo with its
    count, one line per target naming a photo not given at all. Without a surface
    (``on_surface`` False) a target needs its own ``truth_h_m``."""
    index = _photo_index(photos)
    bad_index = _photo_index(bad_photos)
    by_photo: dict[str, list[int]] = {}
    order: list[int] = []
    skipped_bad: dict[str, int] = {}
    for k, t in enumerate(targets):
        key = _resolve(t["image"], index)
        if key is None:
            bad = _resolve(t["image"], bad_index)
            if bad is not None:
                skipped_bad[bad] = skipped_bad.get(bad, 0) + 1
            else:
                given = ", ".join(sorted(photos) + sorted(bad_photos)) or "none"
                messages.append(
                    f"targets file line {t['line']}: image {t['image']!r} is not among the "
                    f"photos given ({given}): skipped"
                )
            continue
        if not on_surface and t.get("truth_h_m") is None:
            messages.append(
                f"targets file line {t['line']} ({t['image']}): no DEM and no truth_h_m: "
                "no height to locate the target at; skipped"
            )
            continue
        by_photo.setdefault(key, []).append(k)
        order.append(k)
    for name, count in skipped_bad.items():
        messages.append(f"{name}: {count} target(s) skipped (the photo could not be used)")
    return by_photo, order


def _triangulate_targets(photos, targets, by_photo, located, on_surface: bool) -> list:
    """The targets named in several rows (``target_id``): each row's ray from its own photo."""
    ks, O, D, ok = [], [], [], []
    for key, kk in by_photo.items():
        ph = photos[key]
        los = ph["sensor"].line_of_sight(
            np.array([targets[k]["row"] for k in kk]), np.array([targets[k]["col"] for k in kk]), ph["pose"]
        )
        ks.extend(kk)
        O.append(np.asarray(los.origin_ecef, float).reshape(-1, 3))
        D.append(np.asarray(los.direction_ecef, float).reshape(-1, 3))
        ok.append(np.asarray(los.status).reshape(-1) == Status.OK)
    if not ks:
        return []
    h = [located[k]["h_m"] if located[k]["h_m"] is not None else math.nan for k in ks]
    return triangulate_ids(
        [targets[k].get(TARGET_ID_COLUMN, "") for k in ks],
        np.concatenate(O),
        np.concatenate(D),
        np.concatenate(ok),
        [targets[k]["line"] for k in ks],
        np.array(h, float) if on_surface else None,
        [located[k]["status"] == "ok" for k in ks],
    )


def _datum_messages(meta, altitude_datum, h_cam, n, dem) -> list:
    out = []
    if altitude_datum == "egm96" and (meta.rtk_corrected or (meta.altitude_type or "").lower() == "rtkalt"):
        why = f"RtkFlag = {meta.rtk_flag}" if meta.rtk_corrected else f"AltitudeType = {meta.altitude_type}"
        out.append(
            f"{meta.name}: {why} (an RTK-corrected position): DJI's RTK aircraft write "
            f"AbsoluteAltitude as a WGS-84 ellipsoidal height; it is taken here as EGM96 "
            f"(altitude_datum='egm96'), which adds N = {n:+.2f} m. If this aircraft writes "
            "ellipsoidal heights, use altitude_datum='ellipsoid' (--altitude-datum ellipsoid)"
        )
    above_dem = None
    if dem is not None:
        ground, st = dem.sample(np.array(math.radians(meta.lat_deg)), np.array(math.radians(meta.lon_deg)))
        if int(st) == Status.OK and np.isfinite(ground):
            above_dem = h_cam - float(ground)
    rel = meta.relative_altitude_m
    if (above_dem is not None and above_dem > DRONE_MAX_HEIGHT_M) or (rel is not None and rel > DRONE_MAX_HEIGHT_M):
        said = (
            [
                f"the camera is {above_dem / 1000:.1f} km above the DEM under it (its altitude "
                f"{meta.altitude_m:.1f} m taken as {_DATUM_TEXT[altitude_datum]})"
            ]
            if above_dem is not None and above_dem > DRONE_MAX_HEIGHT_M
            else []
        )
        if rel is not None:
            said.append(f"RelativeAltitude (above the take-off point) is {rel:.1f} m")
        if above_dem is not None and above_dem > DRONE_MAX_HEIGHT_M:
            # the hint in the photo's own datum: the DEM height less the N added to the altitude
            ground_file = meta.altitude_m - above_dem
            field, hint = (
                f"{meta.altitude_source or 'altitude'} = {meta.altitude_m:g}",
                drone_height_hint(meta.altitude_m, ground_file),
            )
        else:
            field, hint = f"RelativeAltitude = {rel:g}", drone_height_hint(rel, 0.0)
        out.append(
            f"{meta.name}: warning: implausible for a drone: {'; '.join(said)}, while drones fly below "
            f"{DRONE_MAX_HEIGHT_M:.0f} m (DJI's firmware caps them at 500 m above take-off): "
            f"{field}: {hint}; the numbers are used as read"
        )
    if dem is not None and meta.relative_altitude_m is not None:
        ground, st = dem.sample(np.array(math.radians(meta.lat_deg)), np.array(math.radians(meta.lon_deg)))
        if int(st) == Status.OK and np.isfinite(ground):
            above = h_cam - float(ground)
            if abs(above - meta.relative_altitude_m) > ALTITUDE_CHECK_M:
                out.append(
                    f"{meta.name}: altitude check: the camera is {above:.1f} m above the DEM under it, "
                    f"but RelativeAltitude (above the take-off point) is {meta.relative_altitude_m:.1f} m. "
                    f"Check the altitude datum (AbsoluteAltitude taken as {_DATUM_TEXT[altitude_datum]}; "
                    f"EGM96 N here is {n:+.2f} m), the DEM's datum, and whether AbsoluteAltitude is "
                    "barometric (DJI's consumer aircraft); a take-off point at another ground height "
                    "explains part of a difference"
                )
    return out


def _locate_photo(
    ph, targets, ks, on, altitude_datum, truth_h_datum, extra, messages, corrections: Corrections = NO_CORRECTIONS
) -> dict:
    meta, s, pose = ph["meta"], ph["sensor"], ph["pose"]
    row = np.array([t["row"] for t in targets])
    col = np.array([t["col"] for t in targets])
    truth = {c: np.array([np.nan if t.get(c) is None else t[c] for t in targets]) for c in TRUTH_COLUMNS}
    if truth_h_datum == "egm96":
        lat_t = np.where(np.isfinite(truth["truth_lat_deg"]), truth["truth_lat_deg"], meta.lat_deg)
        lon_t = np.where(np.isfinite(truth["truth_lon_deg"]), truth["truth_lon_deg"], meta.lon_deg)
        truth["truth_h_m"] = truth["truth_h_m"] + egm96_undulation(np.deg2rad(lat_t), np.deg2rad(lon_t))
    los = s.line_of_sight(row, col, pose)
    dem = terrain_of(on) if on is not None else None
    given = on is not None  # a surface given (else each target at its own truth height)
    if given:
        surface = (
            f"dem ({on.method})" + (f": {Path(dem_path).name}" if (dem_path := getattr(dem, "path", None)) else "")
            if dem is not None
            else repr(on)
        )
    else:
        on = HeightSurface(truth["truth_h_m"], "geodetic")
        surface = "truth_h_m (geodetic height)"
    hit = Pipeline(s, on, corrections).intersect(los)
    refraction_m = hit.refraction_m
    assert refraction_m is not None  # the pipeline says how far refraction moved each point (0: off)
    lat, lon = np.rad2deg(hit.lat), np.rad2deg(hit.lon)
    err = horizontal_distance_m(lat, lon, truth["truth_lat_deg"], truth["truth_lon_deg"])
    vert = hit.h - truth["truth_h_m"] if given else np.full(len(ks), np.nan)
    st = names(hit.status)
    for t, code in zip(targets, hit.status):
        if code == Status.OUTSIDE_SENSOR:
            messages.append(
                f"targets file line {t['line']} ({meta.name}): pixel row {t['row']:g}, col "
                f"{t['col']:g} is outside the {s.rows} x {s.cols} image (rows 0.5..{s.rows + 0.5:g}, "
                f"columns 0.5..{s.cols + 0.5:g}): not located"
            )
    common = {
        "h_datum": ELLIPSOID_DATUM,
        "surface": surface,
        "sensor_lat_deg": meta.lat_deg,
        "sensor_lon_deg": meta.lon_deg,
        "sensor_h_m": ph["h_cam"],
        "altitude_datum": _DATUM_TEXT[altitude_datum],
        "geoid_undulation_m": ph["n"],
        "lens": ph["lens"],
        **photo_columns(meta),
    }
    out = {}
    mgrs = mgrs_column(lat, lon)  # '' where not located (geoloc.io.mgrs_grid)
    for j, (k, t) in enumerate(zip(ks, targets)):
        r: dict[str, Any] = {c: None for c in OUTPUT_COLUMNS}
        r.update(common)
        r.update(
            image=t["image"],
            row=t["row"],
            col=t["col"],
            lat_deg=_f(lat[j]),
            lon_deg=_f(lon[j]),
            mgrs=mgrs[j],
            h_m=_f(hit.h[j]),
            status=str(st[j]),
            slant_range_m=_f(hit.slant_range[j]),
            truth_lat_deg=_f(truth["truth_lat_deg"][j]),
            truth_lon_deg=_f(truth["truth_lon_deg"][j]),
            truth_h_m=_f(truth["truth_h_m"][j]),
            error_to_truth_m=_f(err[j]),
            vertical_error_m=_f(vert[j]),
            corrections=corrections.label,
            refraction_m=_f(refraction_m[j]),
        )
        for c in extra:
            r[c if c not in r else f"input_{c}"] = t.get(c, "")
        out[k] = r
    return out


def _f(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    return str(v)


def write_rows(path: str | os.PathLike[str], rows: Iterable[Mapping[str, Any]]) -> None:
    """Write the rows of :func:`replay_photos` to a CSV (empty cells for None/NaN; full float precision).

    The columns are :data:`OUTPUT_COLUMNS` then any others in the order they
    first appear; :func:`geoloc.io.gis.read_results` and ``geoloc export`` read it.
    """
    cols = [c for c in OUTPUT_COLUMNS]
    for r in rows:
        cols.extend(c for c in r if c not in cols)
    with atomic_path(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in cols])


def summarize(rows: Sequence[Mapping[str, Any]], messages: Sequence[str] = ()) -> str:
    """A few lines per photo: targets located, mean and largest error to truth, and the datums used."""
    lines = []
    images = dict.fromkeys(r["image"] for r in rows)
    for image in images:
        rs = [r for r in rows if r["image"] == image]
        ok = [r for r in rs if r["status"] == "ok"]
        errs = [r["error_to_truth_m"] for r in ok if r["error_to_truth_m"] is not None]
        line = f"{image}: {len(ok)}/{len(rs)} targets located"
        if errs:
            line += f", error to truth mean {np.mean(errs):.2f} m, max {np.max(errs):.2f} m"
        lines.append(line)
    if rows:
        r = rows[0]
        lines.append(f"heights: {r['h_datum']}; camera AbsoluteAltitude taken as {r['altitude_datum']}")
    if messages:
        lines.append(f"{len(messages)} message(s)")
    return "\n".join(lines)
