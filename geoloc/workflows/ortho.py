"""Whole frames: every pixel of a frame through the sensor onto a surface, and the orthophoto.

* :func:`locate_frame` takes one pose and gives the ground point of every pixel (or
  of every ``step``-th pixel in both directions) as a :class:`FrameGrid`: latitude,
  longitude and ellipsoidal height (WGS 84) per pixel, float64, NaN and a
  :class:`geoloc.status.Status` where a pixel has no ground point. It runs the
  sensor's line of sight (compiled for a frame camera by
  :mod:`geoloc.sensors._fastgrid`, else ``sensor.line_of_sight``) and the surface
  (a DEM: :func:`geoloc.surfaces.terrain.intersect_dem`, ``"exact"``, in parallel)
  chunk by chunk, so memory is the chunk's plus the answer's.
* :func:`write_frame_geotiff` streams the same chunks into a GeoTIFF on the image
  grid (bands ``lat_deg``, ``lon_deg``, ``h_m``, ``status``), so writing never holds
  more than a chunk.
* :func:`orthorectify` resamples a photo onto a geographic (or UTM) grid of a given
  ground sample distance: an inverse map. Each output cell's ground point (its
  centre at the DEM's height) goes through ``sensor.ground_to_pixel``; the cell is
  kept only if the line of sight of that pixel meets the terrain *there* (not at a
  nearer ridge: a hidden cell gets no colour instead of a ghost), and the photo is
  sampled there bilinearly with OpenCV's ``remap``. ``docs/ortho.md`` says why this
  and not GDAL's geolocation-array warp.

Conventions: ``docs/conventions.md`` (1-based pixel centres, radians inside, heights
ellipsoidal unless a datum says otherwise).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.extras import require
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.io.columns import ELLIPSOID_DATUM
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.progress import Progress
from geoloc.sensors.base import PixelHit, flag_outside
from geoloc.sensors.camera import sensor_of
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.userfiles import atomic_path

if TYPE_CHECKING:  # affine comes with rasterio, an optional dependency
    from affine import Affine

    from geoloc.frames.chain import Pose
    from geoloc.sensors.base import Sensor
    from geoloc.sensors.camera import SensorLike
    from geoloc.surfaces.base import MosaicSource, Surface
    from geoloc.surfaces.dem import DEM

#: Default chunk [rays]: whole image rows of about this many pixels per call of the surface.
#: 2^18 rays hold ~45 MB of temporaries in the exact DEM solver (about 170 bytes a ray).
DEFAULT_CHUNK = 1 << 18

#: Band names of the image-grid GeoTIFF, in order.
BANDS = ("lat_deg", "lon_deg", "h_m", "status")


@dataclass(frozen=True)
class FrameGrid:
    """Ground points of a frame's pixel grid (:func:`locate_frame`).

    Attributes
    ----------
    lat, lon : ndarray (n_rows, n_cols), float64
        Geodetic latitude and longitude [rad], WGS 84; NaN where no hit.
    h : ndarray (n_rows, n_cols), float64
        Height [m] in :attr:`h_datum` (ellipsoidal, WGS 84); NaN where no hit.
    status : ndarray (n_rows, n_cols), uint8
        :class:`geoloc.status.Status` per pixel.
    rows, cols : ndarray (n_rows,), (n_cols,)
        The 1-based pixel centres sampled (``1, 1 + step, ...``).
    step : int
    h_datum : str
    """

    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    status: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    step: int = 1
    h_datum: str = ELLIPSOID_DATUM

    @property
    def lat_deg(self) -> np.ndarray:
        return np.rad2deg(self.lat)

    @property
    def lon_deg(self) -> np.ndarray:
        return np.rad2deg(self.lon)

    @property
    def shape(self) -> tuple:
        return self.lat.shape

    def counts(self) -> dict:
        """Pixels per status name (only the statuses that occur)."""
        c = np.bincount(self.status.reshape(-1), minlength=len(Status))
        return {Status(k).name.lower(): int(v) for k, v in enumerate(c) if v}


# --------------------------------------------------------------------------- checks
def _check_step(step) -> int:
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
        raise ValueError(f"step = {step!r}: must be a whole number of pixels >= 1")
    return int(step)


def _check_chunk(chunk) -> int:
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk = {chunk!r}: must be a whole number of rays >= 1")
    return int(chunk)


def frame_pixels(sensor: SensorLike, step: int = 1) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The 1-based pixel centres ``1, 1 + step, ...`` along the rows and the columns of ``sensor``."""
    step = _check_step(step)
    return (
        np.arange(1, int(sensor.rows) + 1, step, dtype=float),
        np.arange(1, int(sensor.cols) + 1, step, dtype=float),
    )


def _as_sensor(sensor: SensorLike) -> Sensor:

    return sensor_of(sensor)


def _as_surface(surface):
    """A DEM becomes the exact parallel solver; a surface stays itself."""
    from geoloc.surfaces.dem import DEM

    if isinstance(surface, DEM):
        from geoloc.surfaces.terrain import DemSurface

        return DemSurface(surface, "exact")
    if not hasattr(surface, "intersect"):
        raise ValueError(f"surface = {surface!r}: must be a DEM or a surface (DemSurface, HeightSurface)")
    return surface


def _on_cores(surface, parallel: bool = True):
    """The surface with its DEM solver on all cores (a frame is millions of rays), unless told otherwise."""
    from geoloc.surfaces.terrain import DemSurface

    if isinstance(surface, DemSurface):
        return DemSurface(
            surface.dem, surface.method, surface.dem_model, **{**surface.options, "parallel": bool(parallel)}
        )
    return surface


def frame_line_of_sight(sensor: Sensor, pose: Pose, rows: ArrayLike, cols: ArrayLike) -> LineOfSight:
    """Lines of sight of the grid ``rows x cols`` (1-based, 1-D each): compiled for a frame camera
    (:func:`geoloc.sensors._fastgrid.grid_line_of_sight`), else ``sensor.line_of_sight``."""
    from geoloc.sensors import _fastgrid

    if _fastgrid.supports(sensor):
        return _fastgrid.grid_line_of_sight(sensor, pose, rows, cols)
    R, C = np.meshgrid(np.asarray(rows, float), np.asarray(cols, float), indexing="ij")
    return sensor.line_of_sight(R, C, pose)


def iter_frame(
    sensor: SensorLike,
    pose: Pose,
    surface: DEM | Surface,
    *,
    step: int = 1,
    chunk: int = DEFAULT_CHUNK,
    parallel: bool = True,
    corrections: Corrections = NO_CORRECTIONS,
) -> Iterator[tuple[int, int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]]:
    """Yield ``(i0, i1, lat, lon, h, status)`` for blocks of whole grid rows ``i0:i1`` (see :func:`locate_frame`)."""
    sensor = _as_sensor(sensor)
    pipe = Pipeline(sensor, _on_cores(_as_surface(surface), parallel), corrections)
    chunk = _check_chunk(chunk)
    rows, cols = frame_pixels(sensor, step)
    per = max(1, chunk // cols.size)
    for i0 in range(0, rows.size, per):
        i1 = min(rows.size, i0 + per)
        los = frame_line_of_sight(sensor, pose, rows[i0:i1], cols)  # the compiled grid executor
        hit = pipe.intersect(los)
        yield (
            i0,
            i1,
            np.asarray(hit.lat, float),
            np.asarray(hit.lon, float),
            np.asarray(hit.h, float),
            np.asarray(hit.status, np.uint8),
        )


def locate_frame(
    sensor: SensorLike,
    pose: Pose,
    surface: DEM | Surface,
    *,
    step: int = 1,
    chunk: int = DEFAULT_CHUNK,
    parallel: bool = True,
    corrections: Corrections = NO_CORRECTIONS,
) -> FrameGrid:
    """Every pixel of one frame onto a surface, in one call.

    Parameters
    ----------
    sensor : FrameSensor, Camera or any Sensor
        A frame camera runs the compiled grid line of sight; other sensors their own
        ``line_of_sight``.
    pose : Pose
        One state (batch size 1 for the compiled path).
    surface : DEM, DemSurface or HeightSurface
        A :class:`geoloc.surfaces.dem.DEM` is intersected with the exact solver
        (``intersect_dem(los, dem, "exact", parallel=True)``); a ``DemSurface`` with
        its own method and model, in parallel.
    step : int
        Every ``step``-th pixel in both directions, from pixel (1, 1).
    chunk : int
        Rays per call of the surface (rounded to whole image rows, at least one row):
        the temporaries are bounded by the chunk, whatever the frame's size.
    parallel : bool
        The DEM solver on all cores (numba threads, the default) or on one (``False``:
        the same hits; for a caller that spreads frames over processes itself).
    corrections : Corrections
        The location pipeline's line-of-sight corrections (:class:`geoloc.pipeline.Corrections`).

    Returns
    -------
    FrameGrid
        Heights ellipsoidal (WGS 84); NaN + Status where a pixel has no ground point
        (SKY, LEFT_DEM, NODATA, INVALID_INPUT for a bad pose, ...).

    Raises
    ------
    ValueError
        ``step`` or ``chunk`` not a whole number >= 1 (the message names it); a
        surface that is neither a DEM nor a surface; a pose with more than one state
        (compiled path).
    """
    sensor = _as_sensor(sensor)
    rows, cols = frame_pixels(sensor, step)
    shape = (rows.size, cols.size)
    lat, lon, h = (np.empty(shape) for _ in range(3))
    st = np.empty(shape, dtype=np.uint8)
    for i0, i1, a, b, c, s in iter_frame(
        sensor, pose, surface, step=step, chunk=chunk, parallel=parallel, corrections=corrections
    ):
        lat[i0:i1], lon[i0:i1], h[i0:i1], st[i0:i1] = a, b, c, s
    return FrameGrid(lat, lon, h, st, rows, cols, int(step))


# --------------------------------------------------------------------------- GeoTIFF on the image grid
def _status_legend() -> str:
    return ", ".join(f"{int(s)}={s.name.lower()}" for s in Status)


#: The bands' descriptions, in BANDS' order.
BAND_DESCRIPTIONS = (
    "lat_deg: geodetic latitude, WGS 84 [deg]",
    "lon_deg: longitude, WGS 84, east + [deg]",
    f"h_m: height [m], {ELLIPSOID_DATUM}",
    "status: geoloc.status.Status code (0 = ok)",
)


def _geotiff_profile(width: int, height: int) -> dict:
    """rasterio's creation options for a frame's file: four float64 bands, NaN as nodata, tiled
    256 x 256, deflate with the floating-point predictor, BigTIFF if it may need it."""
    return dict(
        driver="GTiff",
        width=width,
        height=height,
        count=len(BANDS),
        dtype="float64",
        nodata=float("nan"),
        tiled=True,
        blockxsize=256,
        blockysize=256,
        compress="deflate",
        predictor=3,
        BIGTIFF="IF_SAFER",
    )


def _geotiff_tags(sensor, step: int, tags: dict | None) -> dict:
    """The file's metadata: datums, the pixel convention, the step, the sensor's size, the status
    codes, then the caller's ``tags`` (as text; a caller's tag of the same name wins)."""
    out = {
        "h_datum": ELLIPSOID_DATUM,
        "lat_lon_datum": "WGS 84 (geodetic)",
        "pixel_convention": "1-based pixel centres (docs/conventions.md)",
        "row_first": "1",
        "col_first": "1",
        "step": str(int(step)),
        "sensor_rows": str(sensor.rows),
        "sensor_cols": str(sensor.cols),
        "status_codes": _status_legend(),
        "software": "geoloc ortho (geoloc.workflows.ortho.write_frame_geotiff)",
    }
    out.update({k: str(v) for k, v in (tags or {}).items()})
    return out


def _label_bands(dst) -> None:
    """Each band of the open dataset ``dst`` described, and tagged with its name, unit and datum."""
    for b, (name, desc) in enumerate(zip(BANDS, BAND_DESCRIPTIONS), start=1):
        dst.set_band_description(b, desc)
        unit = {"lat_deg": "deg", "lon_deg": "deg", "h_m": "m"}.get(name, "")
        dst.update_tags(b, name=name, unit=unit, **({"datum": ELLIPSOID_DATUM} if name == "h_m" else {}))


def _write_chunks(dst, chunks, width: int, bar: Progress) -> np.ndarray:
    """Write :func:`iter_frame`'s chunks of whole rows (radians to degrees, the status as a
    number) into ``dst``; the count of pixels per status."""
    import rasterio.windows

    counts = np.zeros(len(Status), dtype=np.int64)
    for i0, i1, lat, lon, h, st in chunks:
        win = rasterio.windows.Window(0, i0, width, i1 - i0)
        dst.write(np.rad2deg(lat), 1, window=win)
        dst.write(np.rad2deg(lon), 2, window=win)
        dst.write(h, 3, window=win)
        dst.write(st.astype(np.float64), 4, window=win)
        counts += np.bincount(st.reshape(-1), minlength=len(Status))
        bar.update((i1 - i0) * width)
    return counts


def write_frame_geotiff(
    path: str | os.PathLike[str],
    sensor: SensorLike,
    pose: Pose,
    surface: DEM | Surface,
    *,
    step: int = 1,
    chunk: int = DEFAULT_CHUNK,
    tags: dict | None = None,
    parallel: bool = True,
    corrections: Corrections = NO_CORRECTIONS,
    progress: bool | None = False,
) -> dict:
    """Locate a whole frame and write it as a 4-band float64 GeoTIFF on the image grid, chunk by chunk.

    Bands: ``lat_deg``, ``lon_deg`` (WGS 84, degrees), ``h_m`` (ellipsoidal height
    above WGS 84, metres), ``status`` (the :class:`geoloc.status.Status` code as a
    number). NaN is the nodata value of the three coordinates (the status band is
    never NaN). Output pixel (i, j) (0-based) is the sensor's pixel
    ``(1 + i * step, 1 + j * step)`` (1-based centres), as the tags say; the file is
    on the image grid, so it has no CRS or geotransform. ``progress``: :class:`geoloc.progress.Progress`
    on stderr, one update per chunk of pixels (None: the bar on a terminal, a line every 10 s elsewhere).

    Returns
    -------
    dict
        ``shape``, ``step``, ``counts`` (pixels per status), ``path``.
    """

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    sensor = _as_sensor(sensor)
    rows, cols = frame_pixels(sensor, step)
    path = Path(path)
    bar = Progress(rows.size * cols.size, f"ortho {path.name}", progress)
    with atomic_path(path) as tmp:
        with warnings.catch_warnings(), rasterio.Env():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)  # the image grid has no CRS by design
            dst = rasterio.open(tmp, "w", **_geotiff_profile(cols.size, rows.size))
        with dst:
            dst.update_tags(**_geotiff_tags(sensor, step, tags))
            _label_bands(dst)
            chunks = iter_frame(
                sensor, pose, surface, step=step, chunk=chunk, parallel=parallel, corrections=corrections
            )
            counts = _write_chunks(dst, chunks, cols.size, bar)
    bar.close()
    return {
        "path": str(path),
        "shape": [int(rows.size), int(cols.size)],
        "step": int(step),
        "counts": {Status(k).name.lower(): int(v) for k, v in enumerate(counts) if v},
    }


def read_frame_geotiff(path: str | os.PathLike[str]) -> FrameGrid:
    """A :func:`write_frame_geotiff` file back as a :class:`FrameGrid` (for tests and users)."""

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # the image grid has no CRS by design
        with rasterio.open(path) as src:
            lat, lon, h, st = src.read()
            tags = src.tags()
    step = int(tags.get("step", 1))
    rows = 1.0 + step * np.arange(lat.shape[0], dtype=float)
    cols = 1.0 + step * np.arange(lat.shape[1], dtype=float)
    return FrameGrid(
        np.deg2rad(lat), np.deg2rad(lon), h, st.astype(np.uint8), rows, cols, step, tags.get("h_datum", ELLIPSOID_DATUM)
    )


# --------------------------------------------------------------------------- orthophoto
def _utm_crs(lat_deg: float, lon_deg: float) -> str:
    zone = int(math.floor((lon_deg + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{(32600 if lat_deg >= 0 else 32700) + zone}"


@dataclass(frozen=True)
class OrthoGrid:
    """The output grid of :func:`orthorectify`: a north-up raster in ``crs``."""

    crs: str
    transform: Affine  # cell corner (0, 0) -> (x, y)
    width: int
    height: int
    gsd_m: float


def ortho_grid(frame: FrameGrid, gsd_m: float, crs: str = "geographic") -> OrthoGrid:
    """The north-up grid of cell size ``gsd_m`` that covers the frame's ground points.

    ``crs``: ``"geographic"`` (EPSG:4326, the cell ``gsd_m`` north-south and east-west
    at the footprint's centre) or ``"utm"`` (the zone of the footprint's centre,
    WGS 84), or any CRS string pyproj reads (its unit taken as metres).
    """
    from affine import Affine

    if not (isinstance(gsd_m, (int, float)) and math.isfinite(gsd_m) and gsd_m > 0):
        raise ValueError(f"gsd_m = {gsd_m!r}: must be a positive number of metres")
    ok = frame.status == Status.OK
    if not ok.any():
        raise ValueError("the frame has no ground point (every pixel's status is not ok): nothing to orthorectify")
    lat, lon = frame.lat_deg[ok], frame.lon_deg[ok]
    lat0, lon0 = 0.5 * (lat.min() + lat.max()), 0.5 * (lon.min() + lon.max())
    if crs == "geographic":
        from geoloc.geodesy.ellipsoid import E2, A

        s = math.sin(math.radians(lat0))
        w = math.sqrt(1.0 - E2 * s * s)
        m_per_deg_lat = math.radians(1.0) * A * (1.0 - E2) / w**3  # meridian radius of curvature
        m_per_deg_lon = math.radians(1.0) * A / w * math.cos(math.radians(lat0))
        dy, dx = gsd_m / m_per_deg_lat, gsd_m / m_per_deg_lon
        x0, x1, y0, y1 = lon.min(), lon.max(), lat.min(), lat.max()
        crs_out = "EPSG:4326"
    else:
        import pyproj

        crs_out = _utm_crs(lat0, lon0) if crs == "utm" else pyproj.CRS.from_user_input(crs).to_string()
        tr = pyproj.Transformer.from_crs("EPSG:4326", crs_out, always_xy=True)
        x, y = tr.transform(lon, lat)
        dx = dy = float(gsd_m)
        x0, x1, y0, y1 = float(np.min(x)), float(np.max(x)), float(np.min(y)), float(np.max(y))
    width = int(math.ceil((x1 - x0) / dx)) + 1
    height = int(math.ceil((y1 - y0) / dy)) + 1
    if width * height > 400_000_000:
        raise ValueError(f"gsd_m = {gsd_m!r}: the orthophoto would be {width} x {height} cells; use a larger GSD")
    return OrthoGrid(crs_out, Affine(dx, 0.0, x0 - 0.5 * dx, 0.0, -dy, y1 + 0.5 * dy), width, height, float(gsd_m))


def _cell_geodetic(grid: OrthoGrid, i0: int, i1: int):
    """Geodetic lat, lon [rad] of the centres of output rows i0:i1."""
    jj, ii = np.meshgrid(np.arange(grid.width) + 0.5, np.arange(i0, i1) + 0.5)
    t = grid.transform
    x, y = t.a * jj + t.b * ii + t.c, t.d * jj + t.e * ii + t.f
    if grid.crs == "EPSG:4326":
        return np.deg2rad(y), np.deg2rad(x)
    import pyproj

    tr = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True)
    lon, lat = tr.transform(x, y)
    return np.deg2rad(lat), np.deg2rad(lon)


def _sample_cells(dem, grid: OrthoGrid, lat, lon):
    """``dem.sample(lat, lon)`` at a block of output cells; for a geographic grid on a geographic DEM
    (rows of one latitude, columns of one longitude) the bilinear weights and nodes are found once
    per row and per column and the same arithmetic is broadcast: the same heights, bit for bit."""
    g = getattr(dem, "grid", None)
    if grid.crs != "EPSG:4326" or not getattr(dem, "is_geographic", False) or g is None or lat.ndim != 2:
        return dem.sample(lat, lon)
    y, x = dem._xy(lat[:, :1], lon[:1, :])  # (n, 1) latitudes, (1, m) longitudes [deg]
    r, c = g.grid_coords(y, x)
    nr, nc = g.values.shape
    t = 1e-9 + g.margin
    ok_r, ok_c = (r >= -t) & (r <= nr - 1 + t), (c >= -t) & (c <= nc - 1 + t)
    with np.errstate(invalid="ignore"):
        rc, cc = np.clip(r, 0.0, nr - 1.0), np.clip(c, 0.0, nc - 1.0)
        i = np.clip(np.floor(np.nan_to_num(rc)), 0, nr - 2).astype(np.intp)
        j = np.clip(np.floor(np.nan_to_num(cc)), 0, nc - 2).astype(np.intp)
        v, u = rc - i, cc - j
    z = g.values
    out = np.zeros(np.broadcast_shapes(u.shape, v.shape))
    for w, zz in (
        ((1 - u) * (1 - v), z[i, j]),
        (u * (1 - v), z[i, j + 1]),
        ((1 - u) * v, z[i + 1, j]),
        (u * v, z[i + 1, j + 1]),
    ):
        with np.errstate(invalid="ignore"):
            out = out + np.where(w != 0, w * zz, 0.0)
    inside = ok_r & ok_c & np.isfinite(r) & np.isfinite(c)
    status = np.full(out.shape, Status.OK, dtype=np.uint8)
    status[~np.broadcast_to(np.isfinite(r) & np.isfinite(c), out.shape)] = Status.INVALID_INPUT
    status[np.broadcast_to(np.isfinite(r) & np.isfinite(c) & ~inside, out.shape)] = Status.LEFT_DEM
    status[inside & ~np.isfinite(out)] = Status.NODATA
    return np.where(status == Status.OK, out, np.nan), status


def _project_cells(sensor, pose, lat, lon, h, p_ecef, corrections: Corrections = NO_CORRECTIONS):
    """``sensor.ground_to_pixel(lat, lon, h, pose)`` for a block of cells whose ECEF points
    ``p_ecef`` are known. For a :class:`~geoloc.sensors.frame.FrameSensor` at one pose the chain
    ECEF -> optical frame is one 3x3 matrix (the frame graph's ``T_ecef_cam``), applied once
    instead of hop by hop, then the lens's ``project``: the same pixels to rounding (1e-16 of a
    unit vector, 1e-12 px), a third of the time."""
    from geoloc.sensors.frame import FrameSensor

    if (
        corrections
        or not isinstance(sensor, FrameSensor)
        or np.ndim(pose.lat) != 0
        or sensor.lever_extra_m is not None
        or bool(np.any(pose.invalid_mask()))
    ):
        return Pipeline(sensor, None, corrections).ground_to_pixel(lat, lon, h, pose)
    R_ecef_cam = np.asarray(sensor.frames(pose).T_ecef("cam"), float)[:3, :3]
    o = np.asarray(sensor.optical_centre_ecef(pose), float).reshape(3)
    d_cam = (p_ecef - o) @ R_ecef_cam  # R_cam_ecef @ d for each point
    u, v, status = sensor.lens.project(d_cam)
    row, col = v + 1.0, u + 1.0
    bad = ~np.all(np.isfinite(p_ecef), axis=-1)
    status = np.where(np.broadcast_to(bad, np.shape(status)), np.uint8(Status.INVALID_INPUT), status)
    return PixelHit(row, col, flag_outside(status, row, col, sensor.rows, sensor.cols))


def orthorectify(
    image: np.ndarray,
    sensor: SensorLike,
    pose: Pose,
    dem: DEM | MosaicSource,
    out_path: str | os.PathLike[str],
    *,
    gsd_m: float,
    crs: str = "geographic",
    frame: FrameGrid | None = None,
    chunk: int = DEFAULT_CHUNK,
    visible_tol_m: float | None = None,
    tags: dict | None = None,
    parallel: bool = True,
    corrections: Corrections = NO_CORRECTIONS,
    progress: bool | None = False,
) -> dict:
    """Resample ``image`` onto a north-up grid (inverse map, occlusion-aware) and write a GeoTIFF.

    Parameters
    ----------
    image : ndarray (bands, rows, cols) or (rows, cols)
        The photo, the sensor's size (uint8 or float).
    sensor, pose : the photo's sensor and state.
    dem : DEM
        The terrain; output cells are its bilinear height at their centres (ellipsoidal).
    out_path : path-like
        GeoTIFF: the image's bands then an alpha band (255 where the cell saw the photo).
    gsd_m : float
        Output cell size [m] (:func:`ortho_grid`).
    crs : str
        ``"geographic"`` (EPSG:4326), ``"utm"`` or a CRS string.
    frame : FrameGrid, optional
        The frame's ground points (to size the grid); computed with ``step`` 1 if not given.
    visible_tol_m : float, optional
        A cell is seen when its pixel's line of sight meets the terrain within this
        distance of the cell's ground point; default a quarter of ``gsd_m`` (a nearer
        ridge hides a cell by far more; the round trip ground -> pixel -> ground is
        exact to micrometres, so the tolerance only separates "this cell" from "another").
    progress : bool or None
        :class:`geoloc.progress.Progress` on stderr, one update per chunk of cells (None: the bar
        on a terminal, a line every 10 s elsewhere; False: nothing).

    Returns
    -------
    dict
        ``path``, ``crs``, ``width``, ``height``, ``gsd_m``, ``transform`` (GDAL order),
        ``cells_seen``, ``cells_hidden`` (in the photo but behind terrain).
    """
    cv2 = require("cv2", "an orthophoto from a photo's pixels")
    import rasterio

    from geoloc.surfaces.terrain import surface_for

    sensor = _as_sensor(sensor)
    # a cell is seen when its pixel's line of sight, through the pipeline, first meets the DEM there
    # (a mosaic solves region by region: surface_for makes either the exact solver)
    visibility = Pipeline(sensor, surface_for(dem=dem, method="exact", parallel=bool(parallel)), corrections)
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[None]
    if img.ndim != 3 or img.shape[1:] != (sensor.rows, sensor.cols):
        raise ValueError(
            f"image shape {np.shape(image)}: must be (bands, {sensor.rows}, {sensor.cols}) "
            f"(the sensor's rows and columns)"
        )
    chunk = _check_chunk(chunk)
    if frame is None:
        frame = locate_frame(
            sensor, pose, dem, step=max(1, min(sensor.rows, sensor.cols) // 400), chunk=chunk, parallel=parallel
        )
    grid = ortho_grid(frame, gsd_m, crs)
    tol = 0.25 * grid.gsd_m if visible_tol_m is None else float(visible_tol_m)
    bands = img.shape[0]
    src = [np.ascontiguousarray(b.astype(np.float32)) for b in img]
    dtype = img.dtype if img.dtype in (np.uint8, np.uint16, np.float32) else np.float32
    profile = _ortho_profile(grid, bands, dtype)
    per = max(1, chunk // grid.width)
    seen_total = hidden_total = 0
    alpha_max = 255 if dtype == np.uint8 else (65535 if dtype == np.uint16 else 1.0)
    all_tags = {
        "method": "inverse map: cell centre at the DEM height -> sensor.ground_to_pixel -> "
        "visibility (the pixel's line of sight meets the terrain there) -> cv2.remap bilinear",
        "gsd_m": repr(grid.gsd_m),
        "visible_tol_m": repr(tol),
        "dem_height_datum": ELLIPSOID_DATUM,
        "software": "geoloc ortho (geoloc.workflows.ortho.orthorectify)",
    }
    all_tags.update({k: str(v) for k, v in (tags or {}).items()})
    bar = Progress(grid.height * grid.width, f"ortho {Path(out_path).name}", progress)
    with atomic_path(out_path) as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.update_tags(**all_tags)
        for i0 in range(0, grid.height, per):
            i1 = min(grid.height, i0 + per)
            lat, lon = _cell_geodetic(grid, i0, i1)
            h, st = _sample_cells(dem, grid, lat, lon)
            p_all = geodetic_to_ecef(lat, lon, h)
            px = _project_cells(sensor, pose, lat, lon, h, p_all, corrections)
            inside = (st == Status.OK) & (px.status == Status.OK)
            r, c = np.where(inside, px.row, np.nan), np.where(inside, px.col, np.nan)
            seen, hidden = _seen_cells(sensor, pose, visibility, p_all, inside, r, c, tol, corrections)
            hidden_total += hidden
            seen_total += int(seen.sum())
            # OpenCV's 0-based pixel centres (u, v) = (col - 1, row - 1); unseen cells sample nothing
            mx = np.where(seen, c - 1.0, -1e6).astype(np.float32)
            my = np.where(seen, r - 1.0, -1e6).astype(np.float32)
            win = rasterio.windows.Window(0, i0, grid.width, i1 - i0)
            for b in range(bands):
                v = cv2.remap(src[b], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                dst.write(np.where(seen, v, 0).astype(dtype), b + 1, window=win)
            dst.write(np.where(seen, alpha_max, 0).astype(dtype), bands + 1, window=win)
            bar.update((i1 - i0) * grid.width)
        bar.close()
        from rasterio.enums import ColorInterp

        rgb = bands == 3 and dtype == np.uint8
        interp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue] if rgb else [ColorInterp.gray] * bands
        dst.colorinterp = [*interp, ColorInterp.alpha]
    return {
        "path": str(out_path),
        "crs": grid.crs,
        "width": grid.width,
        "height": grid.height,
        "gsd_m": grid.gsd_m,
        "transform": list(grid.transform.to_gdal()),
        "cells_seen": seen_total,
        "cells_hidden": hidden_total,
    }


def _ortho_profile(grid: OrthoGrid, bands: int, dtype: Any) -> dict[str, Any]:
    """The orthophoto's rasterio profile: ``bands`` of ``dtype`` and an alpha band, tiled 256 x 256,
    deflate; photometric RGB for three bands of uint8."""
    return dict(
        driver="GTiff",
        width=grid.width,
        height=grid.height,
        count=bands + 1,
        dtype=str(np.dtype(dtype)),
        crs=grid.crs,
        transform=grid.transform,
        tiled=True,
        blockxsize=256,
        blockysize=256,
        compress="deflate",
        photometric="RGB" if bands == 3 and dtype == np.uint8 else "MINISBLACK",
    )


def _seen_cells(
    sensor: Sensor,
    pose: Pose,
    visibility: Pipeline,
    p_all: np.ndarray,
    inside: np.ndarray,
    r: np.ndarray,
    c: np.ndarray,
    tol: float,
    corrections: Corrections,
) -> tuple[np.ndarray, int]:
    """Which cells the photo sees, and how many in it are hidden behind terrain.

    A cell ``inside`` the photo (its point ``p_all`` [ECEF, m] projects to pixel ``(r, c)``) is
    seen when its pixel's line of sight first meets the terrain (``visibility``) within ``tol``
    [m] of the cell's point; the others inside are hidden."""
    seen = np.zeros(inside.shape, dtype=bool)
    idx = np.flatnonzero(inside)
    if not idx.size:
        return seen, 0
    # the cell's pixel's line of sight is the ray from the optical centre through the
    # cell's ground point (ground_to_pixel projects that point): built from the two
    # points, it needs no unprojection through the lens
    p = p_all.reshape(-1, 3)[idx]
    if hasattr(sensor, "optical_centre_ecef") and not corrections:
        o = np.broadcast_to(np.asarray(sensor.optical_centre_ecef(pose), float).reshape(-1, 3)[0], p.shape)
        dvec = p - o
        los = LineOfSight(
            np.ascontiguousarray(o),
            dvec / np.linalg.norm(dvec, axis=-1, keepdims=True),
            np.zeros(len(idx), np.uint8),
        )
    else:
        los = sensor.line_of_sight(r.reshape(-1)[idx], c.reshape(-1)[idx], pose)
    hit = visibility.intersect(los)
    ok = (hit.status == Status.OK) & (np.linalg.norm(hit.ecef - p, axis=-1) <= tol)
    seen.reshape(-1)[idx[ok]] = True
    return seen, int(idx.size - ok.sum())


def read_photo_pixels(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """A photo's pixels as (bands, rows, cols) uint8 (OpenCV reads the JPEG; BGR turned to RGB)."""
    cv2 = require("cv2", "an orthophoto from a photo's pixels")

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if a is None:
        raise ValueError(f"photo {path}: OpenCV cannot read its pixels")
    if a.ndim == 2:
        return a[None]
    if a.shape[2] == 4:
        a = a[:, :, :3]
    return np.ascontiguousarray(a[:, :, ::-1].transpose(2, 0, 1))
