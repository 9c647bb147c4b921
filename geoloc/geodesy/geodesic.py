"""Distances on the WGS-84 ellipsoid (geodesics by Karney's algorithm, through pyproj)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import Geod

_GEOD = Geod(ellps="WGS84")


def horizontal_distance_m(
    lat1_deg: ArrayLike, lon1_deg: ArrayLike, lat2_deg: ArrayLike, lon2_deg: ArrayLike
) -> NDArray[np.float64]:
    """Geodesic distance on WGS-84 between two sets of points [m] (NaN in, NaN out)."""
    lat1, lon1, lat2, lon2 = np.broadcast_arrays(
        *(np.asarray(v, float) for v in (lat1_deg, lon1_deg, lat2_deg, lon2_deg))
    )
    out = np.full(lat1.shape, np.nan)
    ok = np.isfinite(lat1) & np.isfinite(lon1) & np.isfinite(lat2) & np.isfinite(lon2)
    if np.any(ok):
        out[ok] = _GEOD.inv(lon1[ok], lat1[ok], lon2[ok], lat2[ok])[2]
    return out


def forward_azimuth_deg(
    lat1_deg: ArrayLike, lon1_deg: ArrayLike, lat2_deg: ArrayLike, lon2_deg: ArrayLike
) -> np.ndarray:
    """Geodesic forward azimuth from point 1 to point 2 on WGS-84 [deg clockwise from true north,
    -180..180] (Karney's inverse problem; NaN in, or the same point twice, NaN out)."""
    lat1, lon1, lat2, lon2 = np.broadcast_arrays(
        *(np.asarray(v, float) for v in (lat1_deg, lon1_deg, lat2_deg, lon2_deg))
    )
    out = np.full(lat1.shape, np.nan)
    ok = np.isfinite(lat1) & np.isfinite(lon1) & np.isfinite(lat2) & np.isfinite(lon2)
    ok &= (lat1 != lat2) | (lon1 != lon2)
    if np.any(ok):
        out[ok] = _GEOD.inv(lon1[ok], lat1[ok], lon2[ok], lat2[ok])[0]
    return out
