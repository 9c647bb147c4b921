"""EGM96 geoid undulation from the grids bundled in ``assets/geoid/``.

DEM heights (SRTM, ASTER GDEM, ETOPO) are orthometric, above the EGM96 geoid;
the frame chain needs ellipsoidal heights: h = H + N (``docs/method.md`` section 4).
N is read from the NGA EGM96 15' grid (Debian ``proj-data``,
``egm96_15.gtx``), cropped by ``tools/build_assets.py``:

* ``egm96_flight_area.tif``: 15' nodes over 34-38 N, 76-83 E ([Q17] flight test);
* ``egm96_jacksboro.tif``: 15' nodes over 35.5-37.5 N, 85.5-83 W (SRTM sample tile);
* ``egm96_global_30min.tif``: every second node (30'), the whole globe.

A point uses the finest grid that contains it, with bilinear interpolation
between nodes (as PROJ does for .gtx grids). Inside the crops the answer equals
PROJ with the full grid (< 1 mm). Elsewhere the 30' copy is an approximation of
the 15' grid: at the 778 320 nodes of the 15' grid that the 30' copy drops (three
in four), RMS 0.15 m, 99 % within 0.61 m, 0.3 % beyond 1 m and at most 3.93 m (at
10.75 N, 73.75 W, where the geoid is steep); measured by ``tests/geodesy/test_geoid.py``
when Debian's ``proj-data`` is installed (``tools/test.sh`` installs it). Use the crops' areas, or a full grid (``folder=``), where metres matter.

The grids are found through :mod:`geoloc.assets` (``$GEOLOC_ASSETS``, the
installed package data, or the checkout's ``assets/``).

Unlike pyproj without its grid (which silently returns N = 0 with a warning),
a missing grid here is an error.

Conventions: ``docs/conventions.md`` (radians inside, metres).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from geoloc.assets import ASSETS

#: Folder of the bundled geoid grids.
GEOID_DIR = ASSETS / "geoid"
#: Grids in order of preference (finest first).
GEOID_FILES = ("egm96_flight_area.tif", "egm96_jacksboro.tif", "egm96_global_30min.tif")


@dataclass(frozen=True)
class NodeGrid:
    """A geographic grid of node values (row 0 north) with bilinear interpolation.

    Attributes
    ----------
    values : ndarray (nrows, ncols) of float64
        Node values, NaN where there is no data.
    lat_north_deg, lon_west_deg : float
        Latitude of row 0 and longitude of column 0 (node positions) [deg].
    dlat_deg, dlon_deg : float
        Node spacing [deg] (positive; rows go south).
    path : str or None
        File it came from.
    margin : float
        How far beyond the outer nodes the grid is defined, in cells (0: the node
        hull). A raster whose nodes are its pixel centres covers half a cell more
        on each side, as GDAL samples it: ``margin=0.5`` continues the edge
        nodes' values there (bilinear with the position clamped to the hull).
    """

    values: np.ndarray
    lat_north_deg: float
    lon_west_deg: float
    dlat_deg: float
    dlon_deg: float
    path: str | None = None
    margin: float = 0.0

    @classmethod
    def from_geotiff(cls, path: str | os.PathLike[str]) -> "NodeGrid":
        """Read band 1 of a north-up geographic GeoTIFF; pixel centres are the nodes."""
        import rasterio

        with rasterio.open(path) as src:
            t = src.transform
            if t.b != 0 or t.d != 0 or t.e >= 0:
                raise ValueError(f"{path}: transform {tuple(t)[:6]} is not north-up")
            v = src.read(1, masked=True).astype(float).filled(np.nan)
        return cls(v, t.f + t.e / 2, t.c + t.a / 2, -t.e, t.a, str(path))

    @property
    def lat_south_deg(self) -> float:
        return self.lat_north_deg - self.dlat_deg * (self.values.shape[0] - 1)

    @property
    def lon_east_deg(self) -> float:
        return self.lon_west_deg + self.dlon_deg * (self.values.shape[1] - 1)

    def grid_coords(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of points, 0 at the first node."""
        return (
            (self.lat_north_deg - np.asarray(lat_deg, float)) / self.dlat_deg,
            (np.asarray(lon_deg, float) - self.lon_west_deg) / self.dlon_deg,
        )

    def contains(self, lat_deg: ArrayLike, lon_deg: ArrayLike, tol: float = 1e-9) -> np.ndarray:
        """True where a point is on the grid: the node hull grown by ``margin`` cells."""
        r, c = self.grid_coords(lat_deg, lon_deg)
        nr, nc = self.values.shape
        t = tol + self.margin
        return (r >= -t) & (r <= nr - 1 + t) & (c >= -t) & (c <= nc - 1 + t)

    def interp(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> np.ndarray:
        """Bilinear interpolation between the four surrounding nodes; NaN outside.

        Inside the ``margin`` band beyond the outer nodes the position is clamped
        to the node hull: the edge values continue.
        """
        r, c = self.grid_coords(lat_deg, lon_deg)
        nr, nc = self.values.shape
        inside = self.contains(lat_deg, lon_deg)
        with np.errstate(invalid="ignore"):
            r = np.clip(r, 0.0, nr - 1.0)
            c = np.clip(c, 0.0, nc - 1.0)
            i = np.clip(np.floor(np.nan_to_num(r)), 0, nr - 2).astype(np.intp)
            j = np.clip(np.floor(np.nan_to_num(c)), 0, nc - 2).astype(np.intp)
            v = r - i
            u = c - j
        z = self.values
        out = np.zeros(np.shape(u))
        # a missing node spoils the point only if its weight is not zero
        for w, zz in (
            ((1 - u) * (1 - v), z[i, j]),
            (u * (1 - v), z[i, j + 1]),
            ((1 - u) * v, z[i + 1, j]),
            (u * v, z[i + 1, j + 1]),
        ):
            with np.errstate(invalid="ignore"):
                out = out + np.where(w != 0, w * zz, 0.0)
        return np.where(inside, out, np.nan)


@lru_cache(maxsize=None)
def _grids(folder: str) -> tuple:
    grids = []
    for name in GEOID_FILES:
        p = Path(folder) / name
        if not p.is_file():
            raise FileNotFoundError(
                f"EGM96 geoid grid {p} is missing (refusing to use an undulation of 0 as pyproj "
                f"does without its grid): the bundled data folder {folder} is incomplete; "
                "reinstall geoloc, or set GEOLOC_ASSETS to a folder laid out like the "
                "repository's assets/ (in a source checkout, tools/build_assets.py rebuilds "
                "the grids)"
            )
        grids.append(NodeGrid.from_geotiff(p))
    return tuple(grids)


def grid_undulation(path: str | Path) -> Callable[..., np.ndarray]:
    """The geoid of a raster of geoid heights (any geoid model: EGM2008, a national one), as a
    function ``N(lat, lon)`` [m] of geodetic latitude and longitude [rad], like
    :func:`egm96_undulation`.

    The raster (any GDAL format rasterio reads, e.g. GeoTIFF) is north-up and geographic on
    WGS 84, its pixel centres the nodes, its values N in metres above the WGS 84 ellipsoid
    (Sentinel-2's ``S2__OPER_DEM_GEOIDF`` file, EGM2008 at 15', in a GeoTIFF). Bilinear between
    nodes, as PROJ does for .gtx grids; NaN outside the node hull (no edge continued: a geoid
    that is not there is not guessed).

    Raises
    ------
    ValueError
        If the raster is not north-up (:meth:`NodeGrid.from_geotiff`).
    """
    grid = NodeGrid.from_geotiff(path)

    def undulation(lat, lon) -> np.ndarray:
        lat_deg = np.rad2deg(np.asarray(lat, float))
        lon_deg = (np.rad2deg(np.asarray(lon, float)) + 180.0) % 360.0 - 180.0
        return np.asarray(grid.interp(lat_deg, lon_deg), float)

    return undulation


def egm96_undulation(lat: ArrayLike, lon: ArrayLike, *, folder: str | os.PathLike[str] | None = None) -> np.ndarray:
    """EGM96 geoid undulation N [m] at geodetic (lat, lon) [rad].

    h = H + N converts an orthometric height H to the ellipsoidal height h
    (``docs/method.md`` section 4). Bilinear between the 15' nodes (30' outside the
    bundled crops).

    Parameters
    ----------
    lat, lon : array_like
        Geodetic latitude and longitude [rad], broadcasting.
    folder : path, optional
        Folder with the grids (default :data:`GEOID_DIR`, the bundled ``geoid/``).

    Returns
    -------
    ndarray
        N [m]; NaN for non-finite input or |lat| > 90 deg.

    Raises
    ------
    FileNotFoundError
        If a bundled grid file is missing.

    Examples
    --------
    >>> import numpy as np
    >>> round(float(egm96_undulation(0.0, 0.0)), 2)
    17.16
    """
    grids = _grids(str(folder or GEOID_DIR))
    lat_deg, lon_deg = np.broadcast_arrays(np.rad2deg(np.asarray(lat, float)), np.rad2deg(np.asarray(lon, float)))
    lon_deg = (lon_deg + 180.0) % 360.0 - 180.0  # [-180, 180); the global grid closes at +180
    out = np.full(lat_deg.shape, np.nan)
    todo = np.isfinite(lat_deg) & np.isfinite(lon_deg) & (np.abs(lat_deg) <= 90.0)
    for g in grids:
        if not np.any(todo):
            break
        sel = todo & g.contains(lat_deg, lon_deg)
        if np.any(sel):
            out[sel] = g.interp(lat_deg[sel], lon_deg[sel])
            todo &= ~sel
    return out
