"""Render what a frame sensor sees over a DEM: synthetic pictures for synthetic data.

Every pixel's line of sight meets the terrain exactly (the whole-frame machinery of
:func:`geoloc.workflows.ortho.iter_frame`: the compiled grid of lines of sight and
the exact DEM walk), and the pixel takes the colour of a :class:`GroundTexture` at
its ground point; a ray that misses the terrain takes the sky's colour (``SKY``) or,
when it leaves the DEM's extent or meets no data, a haze colour. So a rendered
frame is the picture the sensor model itself predicts: a target painted on the
ground appears at the pixel that :func:`geoloc.locate` gives back the target for,
and a frame rendered from the true pose shows where a faulted pose's marks go wrong.

The texture (:func:`ground_texture`) is computed at run time from the DEM, in a
few milliseconds for the bundled crop, and is deterministic:

* a hypsometric tint (green low, brown high) shaded by Lambert's law under a sun
  at azimuth 315 deg, elevation 45 deg (the cartographers' hillshade
  convention), from the DEM's own node heights and the node spacing in metres;
* an optional faint graticule, dark lines every ``graticule_deg`` of latitude and
  longitude, so motion, scale and a rotation are visible at any zoom;
* :class:`Cross` marks, painted analytically at their surveyed positions (a cross
  of two bars ``arm_m`` long each side of the centre and ``width_m`` wide, in the
  local east/north plane): sharp at any zoom, with no texture raster to outgrow.

Pixels: the image is ``(rows, cols, 3)`` uint8 RGB, array row 0 is pixel row 1
(docs/conventions.md, "Pixels"), as :mod:`geoloc.io.images` serves it.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.status import Status
from geoloc.extras import require

if TYPE_CHECKING:
    from geoloc.frames.chain import Pose
    from geoloc.sensors.camera import SensorLike
    from geoloc.surfaces.base import Surface
    from geoloc.surfaces.dem import DEM

__all__ = [
    "Cross",
    "GroundTexture",
    "ground_texture",
    "hillshade",
    "find_marks",
    "RenderedFrame",
    "read_crosses",
    "render_frame",
    "SKY_RGB",
    "HAZE_RGB",
    "CROSS_RGB",
]

#: Colour of rays that miss the terrain upward (Status.SKY).
SKY_RGB = (150, 190, 235)
#: Colour of rays that leave the DEM or meet no data (no ground point, not sky).
HAZE_RGB = (200, 200, 205)
#: Default colour of a painted cross: pure red, which no tint of the hillshade reaches.
CROSS_RGB = (255, 0, 0)


@dataclass(frozen=True)
class Cross:
    """A target painted on the ground as a cross centred on its surveyed position.

    Attributes
    ----------
    lat_deg, lon_deg : float
        The centre [deg, WGS 84].
    arm_m : float
        Half-length of each bar [m] (the cross spans 2 * arm_m).
    width_m : float
        Width of each bar [m].
    name : str
    rgb : tuple of int
    """

    lat_deg: float
    lon_deg: float
    arm_m: float = 12.0
    width_m: float = 2.5
    name: str = ""
    rgb: tuple = CROSS_RGB

    def __post_init__(self):
        for k in ("lat_deg", "lon_deg", "arm_m", "width_m"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"Cross {self.name!r}: {k} = {v!r} must be a finite number")
        if not (self.arm_m > 0 and 0 < self.width_m <= 2 * self.arm_m):
            raise ValueError(
                f"Cross {self.name!r}: arm_m = {self.arm_m!r}, width_m = {self.width_m!r}: need "
                f"arm_m > 0 and 0 < width_m <= 2 arm_m"
            )


def read_crosses(path: str | os.PathLike[str], *, arm_m: float = 12.0, width_m: float = 2.5) -> list[Cross]:
    """Crosses from a CSV with columns ``name, lat_deg, lon_deg`` (optional ``arm_m``, ``width_m``)."""
    out = []
    with open(path, newline="", encoding="utf-8-sig") as f:
        for line, row in enumerate(csv.DictReader(f), start=2):
            try:
                out.append(
                    Cross(
                        float(row["lat_deg"]),
                        float(row["lon_deg"]),
                        float(row.get("arm_m") or arm_m),
                        float(row.get("width_m") or width_m),
                        row.get("name", "") or "",
                    )
                )
            except (KeyError, ValueError) as e:
                raise ValueError(f"{path}, line {line}: {e}") from None
    return out


def _radii(lat_rad):
    from geoloc.geodesy.ellipsoid import E2, A

    s = np.sin(lat_rad)
    w = np.sqrt(1.0 - E2 * s * s)
    return A * (1.0 - E2) / w**3, A / w  # meridian M, prime vertical N


@dataclass(frozen=True)
class GroundTexture:
    """Colours of the ground: a shaded-relief raster on the DEM's nodes, a graticule, crosses.

    Build with :func:`ground_texture`; :meth:`colour` gives the RGB of ground points.
    """

    rgb: np.ndarray  # (nr, nc, 3) float32 0..255 on the DEM's nodes (row 0 north)
    lat_north_deg: float
    lon_west_deg: float
    dlat_deg: float
    dlon_deg: float
    crosses: tuple = ()
    graticule_deg: float = 0.0
    graticule_width_m: float = 1.5
    sky_rgb: tuple = SKY_RGB
    haze_rgb: tuple = HAZE_RGB
    _cross_arrays: dict = field(default_factory=dict, compare=False, repr=False)

    def colour(self, lat: ArrayLike, lon: ArrayLike) -> np.ndarray:
        """RGB (uint8, shape ``lat.shape + (3,)``) of ground points ``lat, lon`` [rad]; NaN -> haze."""
        lat = np.asarray(lat, float)
        lon = np.asarray(lon, float)
        lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
        nr, nc = self.rgb.shape[:2]
        ok = np.isfinite(lat_deg) & np.isfinite(lon_deg)
        y = np.clip(np.where(ok, (self.lat_north_deg - lat_deg) / self.dlat_deg, 0.0), 0, nr - 1)
        x = np.clip(np.where(ok, (lon_deg - self.lon_west_deg) / self.dlon_deg, 0.0), 0, nc - 1)
        y0 = np.minimum(np.floor(y).astype(np.int64), nr - 2)
        x0 = np.minimum(np.floor(x).astype(np.int64), nc - 2)
        fy, fx = (y - y0)[..., None], (x - x0)[..., None]
        t = self.rgb
        c = (t[y0, x0] * (1 - fx) + t[y0, x0 + 1] * fx) * (1 - fy) + (
            t[y0 + 1, x0] * (1 - fx) + t[y0 + 1, x0 + 1] * fx
        ) * fy
        M, N = _radii(np.where(ok, lat, 0.0))
        if self.graticule_deg > 0:
            g = math.radians(self.graticule_deg)
            dn = np.abs((lat / g + 0.5) % 1.0 - 0.5) * g * M
            de = np.abs((lon / g + 0.5) % 1.0 - 0.5) * g * N * np.cos(lat)
            on = (np.minimum(dn, de) < 0.5 * self.graticule_width_m)[..., None]
            c = np.where(on, c * 0.55, c)
        for cr in self.crosses:
            la, lo = math.radians(cr.lat_deg), math.radians(cr.lon_deg)
            n = (lat - la) * M
            e = (lon - lo) * N * np.cos(lat)
            half = 0.5 * cr.width_m
            inside = ((np.abs(n) <= half) & (np.abs(e) <= cr.arm_m)) | ((np.abs(e) <= half) & (np.abs(n) <= cr.arm_m))
            c = np.where(inside[..., None], np.asarray(cr.rgb, np.float32), c)
        out = np.clip(np.rint(c), 0, 255).astype(np.uint8)
        out[~ok] = self.haze_rgb
        return out


def _tint(z, lo, hi) -> np.ndarray:
    """Hypsometric tint: green (low) through olive to brown and pale (high), (..., 3) in 0..1."""
    stops = np.array(
        [
            [0.00, 0.27, 0.45, 0.20],
            [0.35, 0.50, 0.60, 0.28],
            [0.65, 0.66, 0.58, 0.36],
            [0.85, 0.60, 0.45, 0.30],
            [1.00, 0.85, 0.82, 0.78],
        ]
    )
    u = np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)
    return np.stack([np.interp(u, stops[:, 0], stops[:, k]) for k in (1, 2, 3)], -1)


def _node_spacing_m(dem):
    g = dem.grid
    lat_c = math.radians(g.lat_north_deg - 0.5 * g.dlat_deg * (dem.shape[0] - 1))
    M, N = _radii(lat_c)
    return math.radians(g.dlat_deg) * M, math.radians(g.dlon_deg) * N * math.cos(lat_c)


def hillshade(dem: DEM, sun_azimuth_deg: float = 315.0, sun_elevation_deg: float = 45.0) -> NDArray[np.float64]:
    """Lambert shading of a geographic DEM's nodes: cos of the angle between the surface
    normal and the sun, clipped at 0, shape ``dem.shape`` (row 0 north).

    The normal from central differences (``numpy.gradient``) of the node heights over
    the node spacing in metres (meridian and prime-vertical radii at the crop's
    centre latitude); the sun at ``sun_azimuth_deg`` clockwise from north and
    ``sun_elevation_deg`` above the horizon. No-data nodes take the median height.
    """
    if not dem.is_geographic:
        raise ValueError(f"dem {dem!r}: hillshade needs a geographic DEM (DEM.to_geographic())")
    z = np.asarray(dem.grid.values, float)
    dy, dx = _node_spacing_m(dem)
    zf = np.where(np.isfinite(z), z, np.nanmedian(z))
    dz_drow, dz_dcol = np.gradient(zf, dy, dx)
    dz_dn, dz_de = -dz_drow, dz_dcol  # rows run south
    nrm = np.stack([-dz_de, -dz_dn, np.ones_like(zf)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    az, el = math.radians(sun_azimuth_deg), math.radians(sun_elevation_deg)
    light = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    return np.clip(nrm @ light, 0, 1)


def ground_texture(
    dem: DEM,
    crosses: Iterable[Cross] = (),
    *,
    sun_azimuth_deg: float = 315.0,
    sun_elevation_deg: float = 45.0,
    graticule_deg: float = 0.001,
    graticule_width_m: float = 1.5,
) -> GroundTexture:
    """The shaded relief of a geographic DEM, with a graticule and crosses.

    Parameters
    ----------
    dem : geoloc.surfaces.dem.DEM
        Geographic (EPSG:4326) DEM; its node heights are shaded (:func:`hillshade`;
        ellipsoidal or orthometric makes no visible difference: N is smooth) and
        tinted by height (1st to 99th percentile).
    crosses : iterable of Cross
    sun_azimuth_deg, sun_elevation_deg : float
        The light (clockwise from north; above the horizon).
    graticule_deg : float
        Spacing of the dark graticule lines [deg]; 0 for none.
    graticule_width_m : float
        Their width on the ground [m].
    """
    shade = hillshade(dem, sun_azimuth_deg, sun_elevation_deg)
    g = dem.grid
    z = np.asarray(g.values, float)
    zf = np.where(np.isfinite(z), z, np.nanmedian(z))
    lo, hi = np.percentile(zf, [1, 99])
    el = math.radians(sun_elevation_deg)
    # flat ground (shade = sin el) gets the tint at full strength, slopes away from the sun down to 35 %
    rgb = _tint(zf, lo, hi) * np.clip(0.35 + 0.65 * shade / max(math.sin(el), 1e-6), 0, 1.3)[..., None]
    rgb = np.clip(rgb * 255.0, 0, 255).astype(np.float32)
    rgb[~np.isfinite(z)] = HAZE_RGB
    crosses = tuple(crosses)
    for c in crosses:
        if not isinstance(c, Cross):
            raise ValueError(f"crosses: {c!r} is not a Cross")
    return GroundTexture(
        rgb,
        float(g.lat_north_deg),
        float(g.lon_west_deg),
        float(g.dlat_deg),
        float(g.dlon_deg),
        crosses,
        float(graticule_deg),
        float(graticule_width_m),
    )


@dataclass(frozen=True)
class RenderedFrame:
    """A rendered frame and the ground points it was coloured from.

    Attributes
    ----------
    image : ndarray (rows, cols, 3) uint8
        RGB, array row 0 = pixel row 1.
    grid : geoloc.workflows.ortho.FrameGrid
        Every pixel's ground point and status (``step`` 1).
    """

    image: np.ndarray
    grid: object


def render_frame(
    sensor: SensorLike,
    pose: Pose,
    surface: DEM | Surface,
    texture: GroundTexture,
    *,
    parallel: bool = True,
    chunk: int | None = None,
) -> RenderedFrame:
    """Render one frame: every pixel's exact terrain hit, coloured from ``texture``.

    Parameters
    ----------
    sensor : FrameSensor or any Sensor
        Its ``rows x cols`` is the image size.
    pose : Pose
        One state.
    surface : DEM or DemSurface
        The terrain (a DEM runs the exact solver).
    texture : GroundTexture
    parallel : bool
        The DEM solver on all cores (default) or one.
    chunk : int, optional
        Rays per call of the surface (default :data:`geoloc.workflows.ortho.DEFAULT_CHUNK`).

    Returns
    -------
    RenderedFrame
        ``image`` and ``grid``; SKY pixels are ``texture.sky_rgb``, other misses ``texture.haze_rgb``.
    """
    from geoloc.workflows.ortho import DEFAULT_CHUNK, locate_frame

    grid = locate_frame(sensor, pose, surface, chunk=chunk or DEFAULT_CHUNK, parallel=parallel)
    ok = grid.status == Status.OK
    img = texture.colour(np.where(ok, grid.lat, np.nan), np.where(ok, grid.lon, np.nan))
    img[grid.status == Status.SKY] = texture.sky_rgb
    return RenderedFrame(img, grid)


def find_marks(
    image: ArrayLike, *, min_excess: int = 60, min_pixels: int = 6
) -> tuple[NDArray[np.float64], NDArray[np.int_]]:
    """Centres of the red marks (the painted crosses) in an image, 1-based ``(row, col)``.

    Redness is ``R - max(G, B)``: 255 on a painted cross, below 60 on every tint of
    the hillshade, the graticule and the sky. Blobs of redness above ``min_excess``
    (8-connected, at least ``min_pixels`` pixels) are the marks; each one's centre is
    its redness-weighted centroid (the weights are the redness minus ``min_excess``),
    which keeps a mark smeared by video compression (chroma at half resolution,
    symmetric blur) centred where it was. Returns an ``(n, 2)`` array (row, col),
    largest blob first, and the blobs' pixel counts.
    """
    cv2 = require("cv2", "finding the marks painted in a frame")

    a = np.ascontiguousarray(np.asarray(image)[..., :3], dtype=np.uint8)
    r, g, b = cv2.split(a)
    red = cv2.subtract(r, cv2.max(g, b))  # uint8, saturating: the redness where positive, else 0
    mask = (red > min_excess).view(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_pixels]
    keep.sort(key=lambda k: -stats[k, cv2.CC_STAT_AREA])
    # the weighted centroids over the marked pixels only (a frame holds few), one bincount per sum
    idx = np.flatnonzero(mask)
    rr, cc = np.divmod(idx, mask.shape[1])
    lk = lab.reshape(-1)[idx]
    w = (red.reshape(-1)[idx] - min_excess).astype(float)
    sw = np.bincount(lk, weights=w, minlength=n)
    sr = np.bincount(lk, weights=w * rr, minlength=n)
    sc = np.bincount(lk, weights=w * cc, minlength=n)
    out = [[sr[k] / sw[k] + 1.0, sc[k] / sw[k] + 1.0] for k in keep]
    return np.array(out).reshape(-1, 2), np.array([stats[k, cv2.CC_STAT_AREA] for k in keep], int)
