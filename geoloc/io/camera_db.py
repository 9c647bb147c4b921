"""The bundled camera database: the sensor and nominal lens of drone cameras whose photos carry no calibration.

``assets/cameras/drone_cameras.csv`` (its header names every value's source and the licence) gives,
per camera, the full image size that covers the sensor, the sensor's size and the nominal focal
length (or none: the photo's EXIF FocalLength is then used), with the focal length's 1-sigma:
a relative part (a nominal against a calibrated focal length, about 1 %) and the rounding of the
published value (its step / sqrt(12)), in quadrature. :func:`geoloc.io.photos.lens_from_photo`
uses it when a photo has no calibration tags (``docs/photos.md``, "Cameras without calibration").
"""

from __future__ import annotations

import csv
import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from geoloc.assets import asset_path

__all__ = ["CAMERA_DB", "CameraEntry", "DbLens", "db_lens", "find_camera", "load_camera_db"]

#: The bundled database, inside the assets folder.
CAMERA_DB = ("cameras", "drone_cameras.csv")
#: Relative tolerance on the image's aspect ratio against the database's (a crop mode differs more).
ASPECT_TOLERANCE = 0.01


@dataclass(frozen=True)
class CameraEntry:
    """One camera of the database (millimetres and pixels, as the file gives them)."""

    make: str
    model: str
    width_px: int
    height_px: int
    sensor_width_mm: float
    sensor_height_mm: float
    focal_mm: float | None
    focal_step_mm: float
    focal_rel_sigma: float
    source: str
    line: int = 0

    @property
    def label(self) -> str:
        return f"{self.make} {self.model}"


@dataclass(frozen=True)
class DbLens:
    """A pinhole from the database, in pixels of an image ``width`` x ``height`` (corner origin)."""

    fx: float
    fy: float
    sigma_fx: float
    sigma_fy: float
    focal_mm: float
    focal_sigma_mm: float
    focal_from: str
    entry: CameraEntry

    def describe(self) -> str:
        return (
            f"camera database: {self.entry.label}, focal {self.focal_mm:g} mm ({self.focal_from}) "
            f"+- {self.focal_sigma_mm:.3g} mm (1 sigma), sensor {self.entry.sensor_width_mm:g} x "
            f"{self.entry.sensor_height_mm:g} mm; fx 1-sigma {self.sigma_fx:.3g} px"
        )


def _float(text, name, path, line, required=True):
    text = (text or "").strip()
    if not text and not required:
        return None
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{path} line {line}: {name} = {text!r} is not a number") from None
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{path} line {line}: {name} = {text!r} must be a finite number >= 0")
    return v


@functools.lru_cache(maxsize=4)
def load_camera_db(path: str | os.PathLike[str] | None = None) -> tuple[CameraEntry, ...]:
    """The cameras of ``path`` (default: the bundled database); ValueError names a bad line and field."""
    p = Path(path) if path is not None else asset_path(*CAMERA_DB)
    lines = p.read_text(encoding="utf-8").splitlines()
    body = [(k + 1, s) for k, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")]
    if not body:
        raise ValueError(f"{p}: no header line")
    rows = list(csv.reader([s for _, s in body]))
    header = [h.strip() for h in rows[0]]
    need = [
        "make",
        "model",
        "width_px",
        "height_px",
        "sensor_width_mm",
        "sensor_height_mm",
        "focal_mm",
        "focal_step_mm",
        "focal_rel_sigma",
        "source",
    ]
    missing = [c for c in need if c not in header]
    if missing:
        raise ValueError(f"{p}: column(s) {missing} missing from the header {header}")
    out = []
    for (line, _), cells in zip(body[1:], rows[1:]):
        r = dict(zip(header, (c.strip() for c in cells)))
        width, height = _float(r["width_px"], "width_px", p, line), _float(r["height_px"], "height_px", p, line)
        sw, sh = (
            _float(r["sensor_width_mm"], "sensor_width_mm", p, line),
            _float(r["sensor_height_mm"], "sensor_height_mm", p, line),
        )
        if not (width and height and sw and sh):
            raise ValueError(f"{p} line {line}: sizes must be > 0")
        out.append(
            CameraEntry(
                r["make"],
                r["model"],
                int(width),
                int(height),
                sw,
                sh,
                _float(r["focal_mm"], "focal_mm", p, line, False),
                _float(r["focal_step_mm"], "focal_step_mm", p, line, False) or 0.0,
                _float(r["focal_rel_sigma"], "focal_rel_sigma", p, line),
                r["source"],
                line,
            )
        )
    return tuple(out)


def find_camera(
    make: str | None, model: str | None, width: float, height: float, db: Sequence[CameraEntry] | None = None
) -> CameraEntry | None:
    """The database's camera for EXIF ``make`` and ``model`` (its start) whose image has the
    aspect ratio of ``width`` x ``height`` (a resized photo matches; a crop mode does not)."""
    if not make or not model:
        return None
    db = load_camera_db() if db is None else db
    mk, md = make.strip().lower(), model.strip().lower()
    for e in db:
        if e.make.lower() != mk or not md.startswith(e.model.lower()):
            continue
        if abs((width / height) / (e.width_px / e.height_px) - 1.0) <= ASPECT_TOLERANCE:
            return e
    return None


def db_lens(entry: CameraEntry, width: int, height: int, exif_focal_mm: float | None) -> DbLens | None:
    """A pinhole for an image ``width`` x ``height`` covering the entry's sensor; None without a focal length.

    fx = f / sensor_width x width, fy = f / sensor_height x height; the focal length is the
    entry's, else the photo's EXIF FocalLength. sigma_f = f sqrt(rel^2 + (step / sqrt(12) / f)^2).
    """
    if entry.focal_mm is not None:
        f, step, came = entry.focal_mm, entry.focal_step_mm, "camera database"
    elif exif_focal_mm is not None and exif_focal_mm > 0:
        # EXIF FocalLength is a rational the camera writes; its rounding is not known: one step
        # of its last written digit is not recoverable from a float, so only the relative part counts
        f, step, came = float(exif_focal_mm), 0.0, "EXIF FocalLength"
    else:
        return None
    sigma_f = f * math.hypot(entry.focal_rel_sigma, step / math.sqrt(12.0) / f)
    fx, fy = f / entry.sensor_width_mm * width, f / entry.sensor_height_mm * height
    return DbLens(fx, fy, fx * sigma_f / f, fy * sigma_f / f, f, sigma_f, came, entry)
