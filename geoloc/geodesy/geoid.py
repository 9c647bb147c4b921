"""EGM96 geoid undulation from the grids bundled in ``assets/geoid/``.

DEM heights (SRTM, ASTER GDEM, ETOPO) are orthometric, above the EGM96 geoid;
the frame chain needs ellipsoidal heights: h = H + N (GEOMETRY.md section 4).
N is read from the NGA EGM96 15' grid (Debian ``proj-data``,
``egm96_15.gtx``), cropped by ``tools/build_assets.py``:

* ``egm96_flight_area.tif``: 15' nodes over 34-38 N, 76-83 E ([Q17] flight test);
* ``egm96_jacksboro.tif``: 15' nodes over 35.5-37.5 N, 85.5-83 W (SRTM sample tile);
* ``egm96_global_30min.tif``: every second node (30'), the whole globe.

A point uses the finest grid that contains it, with bilinear interpolation
between nodes (as PROJ does for .gtx grids). Inside the crops the answer equals
PROJ with the full grid; elsewhere the 30' copy differs from the 15' grid by up
to about a metre (larger near steep geoid features; measured in
``tests/test_geoid.py``).

Unlike pyproj without its grid (which silently returns N = 0 with a warning),
a missing grid here is an error.

Conventions: ``docs/conventions.md`` (radians inside, metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

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
    """

    values: np.ndarray
    lat_north_deg: float
    lon_west_deg: float
    dlat_deg: float
    dlon_deg: float
    path: str | None = None

    @classmethod
    def from_geotiff(cls, path) -> "NodeGrid":
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

    def grid_coords(self, lat_deg, lon_deg):
        """Fractional (row, col) of points, 0 at the first node."""
        return ((self.lat_north_deg - np.asarray(lat_deg, float)) / self.dlat_deg,
                (np.asarray(lon_deg, float) - self.lon_west_deg) / self.dlon_deg)

    def contains(self, lat_deg, lon_deg, tol=1e-9):
        r, c = self.grid_coords(lat_deg, lon_deg)
        nr, nc = self.values.shape
        return (r >= -tol) & (r <= nr - 1 + tol) & (c >= -tol) & (c <= nc - 1 + tol)

    def interp(self, lat_deg, lon_deg):
        """Bilinear interpolation between the four surrounding nodes; NaN outside."""
        r, c = self.grid_coords(lat_deg, lon_deg)
        nr, nc = self.values.shape
        inside = self.contains(lat_deg, lon_deg)
        with np.errstate(invalid="ignore"):
            i = np.clip(np.floor(np.nan_to_num(r)), 0, nr - 2).astype(np.intp)
            j = np.clip(np.floor(np.nan_to_num(c)), 0, nc - 2).astype(np.intp)
            v = r - i
            u = c - j
        z = self.values
        out = np.zeros(np.shape(u))
        # a missing node spoils the point only if its weight is not zero
        for w, zz in (((1 - u) * (1 - v), z[i, j]), (u * (1 - v), z[i, j + 1]),
                      ((1 - u) * v, z[i + 1, j]), (u * v, z[i + 1, j + 1])):
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
                f"EGM96 geoid grid {p} is missing: rebuild it with tools/build_assets.py "
                "(refusing to use an undulation of 0 as pyproj does without its grid)")
        grids.append(NodeGrid.from_geotiff(p))
    return tuple(grids)


def egm96_undulation(lat, lon, *, folder=None):
    """EGM96 geoid undulation N [m] at geodetic (lat, lon) [rad].

    h = H + N converts an orthometric height H to the ellipsoidal height h
    (GEOMETRY.md section 4). Bilinear between the 15' nodes (30' outside the
    bundled crops).

    Parameters
    ----------
    lat, lon : array_like
        Geodetic latitude and longitude [rad], broadcasting.
    folder : path, optional
        Folder with the grids (default ``assets/geoid``).

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
    lat_deg, lon_deg = np.broadcast_arrays(np.rad2deg(np.asarray(lat, float)),
                                           np.rad2deg(np.asarray(lon, float)))
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
