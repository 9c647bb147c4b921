"""Sentinel-2 L1B location grids and pixels of ground points (``geoloc s2``, ``docs/sentinel2.md``).

A direct-location grid is Sen2VM's (ESA's viewing model, whose layout is followed, not its
code): for a band and detector, the ground point of every ``step``-th pixel of every
``step``-th line, from the first pixel of the first line, over a granule (or the detector's
whole datastrip), one grid row past its last line; three bands: longitude, latitude (degrees,
WGS 84) and the ellipsoidal height [m]. The surface is a constant ellipsoidal height, the
EGM96 geoid, or a DEM.
"""

from __future__ import annotations

from typing import Callable

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.geoid import egm96_undulation
from geoloc.pipeline import Corrections, Pipeline
from geoloc.status import Status
from geoloc.sensors.base import Sensor
from geoloc.surfaces.base import GroundPoint, Surface
from geoloc.surfaces.height import HeightSurface

#: Sen2VM's usual steps [pixels of the band] (its test configuration: 6 km)
DEFAULT_STEPS = {10: 600, 20: 300, 60: 100}
#: Geoid surface: the fixed point h = N(lat, lon) at the hit settles below 1 mm in this many steps
#: (N's slope is below 1e-4, so each step gains that factor at a nadir view, 0.02 at 10 deg)
GEOID_ITERATIONS = 4


def grid_pixels(
    sensor: Sensor, step: float, first_row: int = 1, rows: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Sen2VM's grid over rows ``first_row .. first_row + rows - 1`` of ``sensor``.

    Grid row i is image row 1 + step * (r0 + i), r0 the grid row holding ``first_row`` (the
    nearest: Sen2VM's ``floor((first - 1 + step / 2) / step)``), up to the grid row holding
    the last row; columns 1 + step * j up to the last column and half a step (Sen2VM's overlap
    of one point). Returns (rows (M,), cols (N,)) of 1-based pixel centres.
    """
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"step = {step!r}: must be a number of pixels > 0")
    rows = sensor.rows - first_row + 1 if rows is None else rows
    start = first_row - 1
    r0 = int(np.floor((start + step / 2) / step))
    r1 = int(np.floor((start + rows + step / 2) / step))
    nc = int(np.floor((sensor.cols + step / 2 - 0.5) / step)) + 1
    return 1.0 + step * np.arange(r0, r1 + 1), 1.0 + step * np.arange(nc)


def locate_on_geoid(
    pipe_for: Callable[[np.ndarray], Pipeline],
    row: ArrayLike,
    col: ArrayLike,
    undulation: Callable[..., np.ndarray] | None = None,
) -> GroundPoint:
    """Pixels onto the geoid: heights h = N(lat, lon) at the hit, a fixed point.

    ``pipe_for(h)`` gives the pipeline on the surface of geodetic height h (broadcast to the
    pixels). ``undulation(lat, lon)`` [rad -> m] is the geoid (default: the bundled EGM96,
    :func:`~geoloc.geodesy.geoid.egm96_undulation`; a file's, e.g. Sen2VM's EGM2008:
    :func:`~geoloc.geodesy.geoid.grid_undulation`); a point where it is NaN (off the geoid's
    grid) keeps a NaN height and its status says so. Returns the last GroundPoint.
    """
    N = egm96_undulation if undulation is None else undulation
    h = np.zeros(np.broadcast_shapes(np.shape(row), np.shape(col)))
    hit = pipe_for(h).locate(row, col, outside="extrapolate")
    for _ in range(GEOID_ITERATIONS):
        ok = hit.status == Status.OK
        n = N(np.where(ok, hit.lat, 0.0), np.where(ok, hit.lon, 0.0))
        h = np.where(ok, n, h)
        hit = pipe_for(h).locate(row, col, outside="extrapolate")
    return hit


def direct_grid(
    sensor: Sensor,
    rows: np.ndarray,
    cols: np.ndarray,
    *,
    surface: Surface | None = None,
    height_m: float | None = None,
    geoid: bool = False,
    corrections: Corrections,
    height_kind: str = "geodetic",
    undulation: Callable[..., np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ground points of the grid's pixels: (lon_deg, lat_deg, h_m, status), each (M, N).

    Exactly one of ``surface`` (a DEM surface), ``height_m`` (ellipsoidal; the surface of
    ``height_kind``, :class:`~geoloc.surfaces.height.HeightSurface`) or ``geoid`` (the bundled
    EGM96, or ``undulation``'s geoid: :func:`locate_on_geoid`).
    """
    if sum(x is not None and x is not False for x in (surface, height_m, geoid or None)) != 1:
        raise ValueError("give one of a DEM, a height (--h-m) or --geoid")
    R, C = np.meshgrid(rows, cols, indexing="ij")
    if geoid:
        hit = locate_on_geoid(lambda h: Pipeline(sensor, HeightSurface(h, "geodetic"), corrections), R, C, undulation)
    else:
        surf = surface if surface is not None else HeightSurface(float(height_m), height_kind)  # type: ignore[arg-type]
        hit = Pipeline(sensor, surf, corrections).locate(R, C, outside="extrapolate")
    return np.degrees(hit.lon), np.degrees(hit.lat), np.asarray(hit.h, float), np.asarray(hit.status)


def write_grid(
    path: str | Path,
    lon_deg: np.ndarray,
    lat_deg: np.ndarray,
    h_m: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    tags: dict,
) -> None:
    """The grid as a GeoTIFF (float64 bands lon, lat, h), written to a temporary file then renamed.

    Like Sen2VM's: no georeferencing (the grid is in the image's geometry); the tags say where it
    is: ``ROW_OFFSET``, ``COL_OFFSET`` (geoloc's 1-based pixel of grid point (0, 0)),
    ``ROW_STEP``, ``COL_STEP``, ``SRS`` (EPSG:4326), the height datum, and the caller's tags.
    """
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from geoloc.userfiles import atomic_path

    h, w = lon_deg.shape
    profile = dict(driver="GTiff", width=w, height=h, count=3, dtype="float64", nodata=np.nan)
    all_tags = {
        "ROW_OFFSET": f"{rows[0]:.6f}",
        "COL_OFFSET": f"{cols[0]:.6f}",
        "ROW_STEP": f"{(rows[1] - rows[0]) if len(rows) > 1 else 0:.6f}",
        "COL_STEP": f"{(cols[1] - cols[0]) if len(cols) > 1 else 0:.6f}",
        "PIXEL_CONVENTION": "1-based pixel centres (geoloc); Sen2VM's = geoloc's - 0.5",
        "SRS": "EPSG:4326",
        "software": "geoloc s2 grid (geoloc.workflows.sentinel2)",
        **{k: str(v) for k, v in tags.items()},
    }
    with atomic_path(path, "--out") as tmp:
        with warnings.catch_warnings(), rasterio.Env():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            dst = rasterio.open(tmp, "w", **profile)
        with dst:
            dst.update_tags(**all_tags)
            for b, (name, unit, a) in enumerate(
                (("lon_deg", "deg", lon_deg), ("lat_deg", "deg", lat_deg), ("h_m", "m", h_m)), start=1
            ):
                dst.write(np.asarray(a, float), b)
                dst.set_band_description(b, name)
                extra = {"datum": "WGS 84 ellipsoid"} if name == "h_m" else {}
                dst.update_tags(b, name=name, unit=unit, **extra)


__all__ = ["DEFAULT_STEPS", "direct_grid", "grid_pixels", "locate_on_geoid", "write_grid"]
