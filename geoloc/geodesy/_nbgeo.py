"""Scalar ECEF -> geodetic for numba kernels (terrain walk, fused locate).

Vermeille's closed form (J. Geodesy 76:451-454, 2002; 78:94-95, 2004): numba
compiles the very function behind :func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`
(:func:`geoloc.geodesy.ellipsoid.vermeille`) for scalars, so that compiled kernels can
call it per point. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

from numba import njit

from geoloc.geodesy.ellipsoid import vermeille

_vermeille = njit(cache=True, error_model="numpy", inline="always")(vermeille)


@njit(cache=True, error_model="numpy")
def geodetic(x, y, z):
    """Scalar ECEF -> (lat, lon, h), as geoloc.geodesy.ellipsoid.ecef_to_geodetic."""
    lat, lon, h, _, _, _ = _vermeille(x, y, z)
    return lat, lon, h


@njit(cache=True, error_model="numpy")
def geodetic_up(x, y, z):
    """As :func:`geodetic`, plus the outward normal (cos phi cos lam, cos phi sin lam, sin phi).

    phi = atan2(z, d) in Vermeille's notation, so the normal needs no trigonometry.
    """
    lat, lon, h, d, dz, rho = _vermeille(x, y, z)
    cphi = d / dz
    return lat, lon, h, cphi * x / rho, cphi * y / rho, z / dz
