"""Scalar ECEF -> geodetic for numba kernels (terrain walk, fused locate).

Vermeille's closed form (J. Geodesy 76:451-454, 2002; 78:94-95, 2004), the same
formula as :func:`geoloc.ellipsoid.ecef_to_geodetic`, written per point so
that compiled kernels can call it. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math

from numba import njit

from .ellipsoid import A, E2


@njit(cache=True, error_model="numpy", inline="always")
def _vermeille(x, y, z):
    """Returns lat, lon, h and Vermeille's d, sqrt(d^2 + z^2) and rho = sqrt(x^2 + y^2)."""
    e4 = E2 * E2
    rho2 = x * x + y * y
    rho = math.sqrt(rho2)
    p = rho2 / (A * A)
    q = (1.0 - E2) * z * z / (A * A)
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r * r * r)
    t = math.pow(1.0 + s + math.sqrt(s * (2.0 + s)), 1.0 / 3.0)
    u = r * (1.0 + t + 1.0 / t)
    v = math.sqrt(u * u + e4 * q)
    w = E2 * (u + v - q) / (2.0 * v)
    k = math.sqrt(u + v + w * w) - w
    d = k * rho / (k + E2)
    dz = math.hypot(d, z)
    lat = 2.0 * math.atan2(z, d + dz)
    h = (k + E2 - 1.0) / k * dz
    lon = math.atan2(y, x)
    return lat, lon, h, d, dz, rho


@njit(cache=True, error_model="numpy")
def geodetic(x, y, z):
    """Scalar ECEF -> (lat, lon, h), as geoloc.ellipsoid.ecef_to_geodetic."""
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
