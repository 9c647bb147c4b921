"""Local level frames at a point of the ellipsoid: NED and ENU axes.

Conventions: ``docs/conventions.md`` (frames ``ned`` and ``enu``). Radians;
arrays broadcast over leading axes.

Points in those frames, about a geodetic origin (lat0, lon0, h0), with the
names pymap3d users look for spelled ``src_to_dst``: ``ecef_to_enu``,
``enu_to_ecef``, ``geodetic_to_enu``, ``enu_to_geodetic``, the same four for
NED, and AER (azimuth clockwise from north in [0, 2 pi), elevation up from the
local horizontal plane, slant range in metres): ``enu_to_aer``, ``aer_to_enu``,
``geodetic_to_aer``, ``aer_to_geodetic``, ``ecef_to_aer``, ``aer_to_ecef``.
Degree front ends carry ``_deg`` (``geodetic_to_aer_deg``, ...). Checked
against pymap3d in ``tests/geodesy/test_local_frames.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef


def R_ecef_ned(lat: ArrayLike, lon: ArrayLike) -> np.ndarray:
    """Rotation NED -> ECEF at (phi, lambda): columns N, E, D in ECEF [Q17 eq. 5].

    N = (-sin phi cos lambda, -sin phi sin lambda, cos phi),
    E = (-sin lambda, cos lambda, 0),
    D = (-cos phi cos lambda, -cos phi sin lambda, -sin phi).
    """
    lat, lon = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float))
    sp, cp, sl, cl = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    n = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    e = np.stack([-sl, cl, z], axis=-1)
    d = np.stack([-cp * cl, -cp * sl, -sp], axis=-1)
    return np.stack([n, e, d], axis=-1)


#: Permutation taking NED coordinates to ENU coordinates: v_enu = P @ v_ned.
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def R_ecef_enu(lat: ArrayLike, lon: ArrayLike) -> np.ndarray:
    """Rotation ENU -> ECEF at (phi, lambda): columns E, N, U in ECEF.

    E = (-sin lambda, cos lambda, 0), N = (-sin phi cos lambda, -sin phi sin lambda, cos phi),
    U = (cos phi cos lambda, cos phi sin lambda, sin phi) (the NED axes of [Q17 eq. 5]
    reordered, U = -D).
    """
    return R_ecef_ned(lat, lon) @ R_ENU_NED.T


# ---------------------------------------------------------------------------
# Points in local frames: ENU, NED and AER (the functions pymap3d users expect)
# ---------------------------------------------------------------------------
#
# Every function below takes the local origin as geodetic (lat0, lon0, h0)
# [rad, rad, m] on WGS-84 and works in radians and metres; the ``_deg`` wrappers
# at the end take and give degrees where a pymap3d user passes them. Points are
# (..., 3) arrays; origins and points broadcast against each other over the
# leading axes, so one origin serves a batch of points and a batch of origins
# serves one point (or a batch of the same shape). A NaN in any coordinate of
# a point or of its origin gives NaN in every output of that point.

_TAU = 2.0 * np.pi


def _rotate_into(R_ecef_x, v_ecef):
    """Components in frame x of ECEF vectors: R_x_ecef @ v = R_ecef_x^T @ v, broadcast.

    An explicit product and sum over the last axis, so a NaN component reaches
    every output (NaN * 0 is NaN) whatever the leading shapes.
    """
    return np.einsum("...ji,...j->...i", R_ecef_x, v_ecef)


def _rotate_out_of(R_ecef_x, v_x):
    """ECEF components of vectors given in frame x: R_ecef_x @ v, broadcast."""
    return np.einsum("...ij,...j->...i", R_ecef_x, v_x)


def _nan_rows(v):
    """A point with a NaN in any coordinate becomes NaN in all three.

    Needed where a zero in the rotation would keep a coordinate finite: with
    lon0 NaN the E axis still has an exact 0 as its ECEF z component, so the
    ECEF z of an ENU point would come out finite.
    """
    return np.where(np.isnan(v).any(axis=-1, keepdims=True), np.nan, v)


def _nan_where(bad, *arrays):
    """Set every array to NaN where ``bad`` (a point with any NaN input is all NaN)."""
    return tuple(np.where(bad, np.nan, a) for a in arrays)


def ecef_to_enu(p_ecef: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike) -> np.ndarray:
    """ECEF points to ENU coordinates about a geodetic origin.

    p_enu = R_enu_ecef @ (p_ecef - o_ecef), with o_ecef the ECEF position of
    (lat0, lon0, h0) and R_ecef_enu of :func:`R_ecef_enu` (E east, N north,
    U along the outward ellipsoid normal at the origin; ``docs/conventions.md``).
    pymap3d: ``ecef2enu``.

    Parameters
    ----------
    p_ecef : array_like, shape (..., 3)
        ECEF points [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the ENU origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        ENU coordinates (east, north, up) [m]; leading axes broadcast between
        the points and the origin.
    """
    d = np.asarray(p_ecef, float) - geodetic_to_ecef(lat0, lon0, h0)
    return _nan_rows(_rotate_into(R_ecef_enu(lat0, lon0), d))


def enu_to_ecef(p_enu: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike) -> np.ndarray:
    """ENU coordinates about a geodetic origin to ECEF points.

    p_ecef = o_ecef + R_ecef_enu @ p_enu (the inverse of :func:`ecef_to_enu`).
    pymap3d: ``enu2ecef``.

    Parameters
    ----------
    p_enu : array_like, shape (..., 3)
        ENU coordinates (east, north, up) [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the ENU origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        ECEF points [m].
    """
    v = _rotate_out_of(R_ecef_enu(lat0, lon0), np.asarray(p_enu, float))
    return _nan_rows(geodetic_to_ecef(lat0, lon0, h0) + v)


def geodetic_to_enu(
    lat: ArrayLike, lon: ArrayLike, h: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """Geodetic points to ENU coordinates about a geodetic origin.

    Both go to ECEF by [Q17 eq. 4] (:func:`geoloc.geodesy.ellipsoid.geodetic_to_ecef`),
    then :func:`ecef_to_enu`. pymap3d: ``geodetic2enu``.

    Parameters
    ----------
    lat, lon : array_like
        Geodetic latitude and longitude of the points [rad].
    h : array_like
        Ellipsoidal height of the points [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the ENU origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        ENU coordinates (east, north, up) [m].
    """
    return ecef_to_enu(geodetic_to_ecef(lat, lon, h), lat0, lon0, h0)


def enu_to_geodetic(
    p_enu: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ENU coordinates about a geodetic origin to geodetic points.

    :func:`enu_to_ecef`, then Vermeille's closed form
    (:func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`; NaN for a point within
    ~43 km of the Earth's centre). pymap3d: ``enu2geodetic``.

    Parameters
    ----------
    p_enu : array_like, shape (..., 3)
        ENU coordinates (east, north, up) [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the ENU origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    lat, lon, h : ndarray
        Geodetic latitude and longitude [rad] (longitude in (-pi, pi]) and
        ellipsoidal height [m] of the points.
    """
    return ecef_to_geodetic(enu_to_ecef(p_enu, lat0, lon0, h0))


def ecef_to_ned(p_ecef: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike) -> np.ndarray:
    """ECEF points to NED coordinates about a geodetic origin.

    p_ned = R_ned_ecef @ (p_ecef - o_ecef), with R_ecef_ned of :func:`R_ecef_ned`
    [Q17 eq. 5] (N north, E east, D along the inward ellipsoid normal at the
    origin). pymap3d: ``ecef2ned``.

    Parameters
    ----------
    p_ecef : array_like, shape (..., 3)
        ECEF points [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the NED origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        NED coordinates (north, east, down) [m].
    """
    d = np.asarray(p_ecef, float) - geodetic_to_ecef(lat0, lon0, h0)
    return _nan_rows(_rotate_into(R_ecef_ned(lat0, lon0), d))


def ned_to_ecef(p_ned: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike) -> np.ndarray:
    """NED coordinates about a geodetic origin to ECEF points.

    p_ecef = o_ecef + R_ecef_ned @ p_ned (the inverse of :func:`ecef_to_ned`).
    pymap3d: ``ned2ecef``.

    Parameters
    ----------
    p_ned : array_like, shape (..., 3)
        NED coordinates (north, east, down) [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the NED origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        ECEF points [m].
    """
    v = _rotate_out_of(R_ecef_ned(lat0, lon0), np.asarray(p_ned, float))
    return _nan_rows(geodetic_to_ecef(lat0, lon0, h0) + v)


def geodetic_to_ned(
    lat: ArrayLike, lon: ArrayLike, h: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """Geodetic points to NED coordinates about a geodetic origin.

    pymap3d: ``geodetic2ned``.

    Parameters
    ----------
    lat, lon : array_like
        Geodetic latitude and longitude of the points [rad].
    h : array_like
        Ellipsoidal height of the points [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the NED origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    ndarray, shape (..., 3)
        NED coordinates (north, east, down) [m].
    """
    return ecef_to_ned(geodetic_to_ecef(lat, lon, h), lat0, lon0, h0)


def ned_to_geodetic(
    p_ned: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NED coordinates about a geodetic origin to geodetic points.

    pymap3d: ``ned2geodetic``.

    Parameters
    ----------
    p_ned : array_like, shape (..., 3)
        NED coordinates (north, east, down) [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the NED origin [rad].
    h0 : array_like
        Ellipsoidal height of the origin [m].

    Returns
    -------
    lat, lon, h : ndarray
        Geodetic latitude and longitude [rad] (longitude in (-pi, pi]) and
        ellipsoidal height [m] of the points.
    """
    return ecef_to_geodetic(ned_to_ecef(p_ned, lat0, lon0, h0))


def enu_to_aer(p_enu: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ENU coordinates to azimuth, elevation and slant range.

    az = atan2(e, n) wrapped into [0, 2 pi) (clockwise from north: east is
    pi/2), el = atan2(u, sqrt(e^2 + n^2)) in [-pi/2, pi/2] (up from the local
    horizontal plane, the plane normal to the ellipsoid normal at the origin),
    srange = |p_enu|. Straight up or down the azimuth is undefined and comes
    out 0 (exactly so when e = n = 0); the zero vector gives (0, 0, 0).
    Unlike pymap3d's ``enu2aer`` nothing is rounded: pymap3d sets components
    below 1 mm to zero before taking the angles.

    Parameters
    ----------
    p_enu : array_like, shape (..., 3)
        ENU coordinates (east, north, up) [m].

    Returns
    -------
    az, el : ndarray, shape (...)
        Azimuth in [0, 2 pi) and elevation in [-pi/2, pi/2], in rad.
    srange : ndarray, shape (...)
        Slant range [m].
    """
    p = np.asarray(p_enu, float)
    e, n, u = p[..., 0], p[..., 1], p[..., 2]
    r = np.hypot(e, n)
    az = np.mod(np.arctan2(e, n), _TAU)
    az = np.where(az >= _TAU, 0.0, az)  # -tiny mod 2 pi rounds to 2 pi itself
    el = np.arctan2(u, r)
    srange = np.hypot(r, u)
    return _nan_where(np.isnan(p).any(axis=-1), az, el, srange)


def aer_to_enu(az: ArrayLike, el: ArrayLike, srange: ArrayLike) -> np.ndarray:
    """Azimuth, elevation and slant range to ENU coordinates.

    e = s cos(el) sin(az), n = s cos(el) cos(az), u = s sin(el), with the
    angles as in :func:`enu_to_aer` (any real az and el are accepted; el
    outside [-pi/2, pi/2] is taken literally). A negative slant range is
    invalid and gives NaN (pymap3d's ``aer2enu`` raises ``ValueError``; a
    batch here never raises, ``docs/conventions.md``).

    Parameters
    ----------
    az, el : array_like
        Azimuth clockwise from north and elevation above the local horizontal
        plane [rad].
    srange : array_like
        Slant range [m], >= 0.

    Returns
    -------
    ndarray, shape (..., 3)
        ENU coordinates (east, north, up) [m]; the leading shape is the
        broadcast of az, el and srange.
    """
    az, el, srange = np.broadcast_arrays(np.asarray(az, float), np.asarray(el, float), np.asarray(srange, float))
    bad = np.isnan(az) | np.isnan(el) | np.isnan(srange) | (srange < 0.0)
    r = srange * np.cos(el)
    e, n, u = _nan_where(bad, r * np.sin(az), r * np.cos(az), srange * np.sin(el))
    return np.stack([e, n, u], axis=-1)


def geodetic_to_aer(
    lat: ArrayLike, lon: ArrayLike, h: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth, elevation and slant range of geodetic points seen from a geodetic origin.

    :func:`geodetic_to_enu`, then :func:`enu_to_aer`. pymap3d: ``geodetic2aer``.

    Parameters
    ----------
    lat, lon : array_like
        Geodetic latitude and longitude of the targets [rad].
    h : array_like
        Ellipsoidal height of the targets [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the observer [rad].
    h0 : array_like
        Ellipsoidal height of the observer [m].

    Returns
    -------
    az, el : ndarray
        Azimuth in [0, 2 pi) clockwise from north and elevation above the
        observer's local horizontal plane [rad].
    srange : ndarray
        Slant range [m].
    """
    return enu_to_aer(geodetic_to_enu(lat, lon, h, lat0, lon0, h0))


def aer_to_geodetic(
    az: ArrayLike, el: ArrayLike, srange: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic point at an azimuth, elevation and slant range from a geodetic origin.

    :func:`aer_to_enu`, then :func:`enu_to_geodetic`. pymap3d: ``aer2geodetic``.

    Parameters
    ----------
    az, el : array_like
        Azimuth clockwise from north and elevation above the observer's local
        horizontal plane [rad].
    srange : array_like
        Slant range [m], >= 0 (negative gives NaN).
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the observer [rad].
    h0 : array_like
        Ellipsoidal height of the observer [m].

    Returns
    -------
    lat, lon, h : ndarray
        Geodetic latitude and longitude [rad] (longitude in (-pi, pi]) and
        ellipsoidal height [m] of the targets.
    """
    return enu_to_geodetic(aer_to_enu(az, el, srange), lat0, lon0, h0)


def ecef_to_aer(
    p_ecef: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth, elevation and slant range of ECEF points seen from a geodetic origin.

    :func:`ecef_to_enu`, then :func:`enu_to_aer`. pymap3d: ``ecef2aer``.

    Parameters
    ----------
    p_ecef : array_like, shape (..., 3)
        ECEF points [m].
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the observer [rad].
    h0 : array_like
        Ellipsoidal height of the observer [m].

    Returns
    -------
    az, el : ndarray
        Azimuth in [0, 2 pi) clockwise from north and elevation above the
        observer's local horizontal plane [rad].
    srange : ndarray
        Slant range [m].
    """
    return enu_to_aer(ecef_to_enu(p_ecef, lat0, lon0, h0))


def aer_to_ecef(
    az: ArrayLike, el: ArrayLike, srange: ArrayLike, lat0: ArrayLike, lon0: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """ECEF point at an azimuth, elevation and slant range from a geodetic origin.

    :func:`aer_to_enu`, then :func:`enu_to_ecef`. pymap3d: ``aer2ecef``.

    Parameters
    ----------
    az, el : array_like
        Azimuth clockwise from north and elevation above the observer's local
        horizontal plane [rad].
    srange : array_like
        Slant range [m], >= 0 (negative gives NaN).
    lat0, lon0 : array_like
        Geodetic latitude and longitude of the observer [rad].
    h0 : array_like
        Ellipsoidal height of the observer [m].

    Returns
    -------
    ndarray, shape (..., 3)
        ECEF points [m].
    """
    return enu_to_ecef(aer_to_enu(az, el, srange), lat0, lon0, h0)


# --- degree front ends (pymap3d's default units): angles in degrees, lengths in metres


def geodetic_to_enu_deg(
    lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """:func:`geodetic_to_enu` with latitudes and longitudes in degrees; ENU [m] (..., 3)."""
    return geodetic_to_enu(np.deg2rad(lat_deg), np.deg2rad(lon_deg), h, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0)


def enu_to_geodetic_deg(
    p_enu: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`enu_to_geodetic` with the origin and the result (lat_deg, lon_deg, h) in degrees."""
    lat, lon, h = enu_to_geodetic(p_enu, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0)
    return np.rad2deg(lat), np.rad2deg(lon), h


def geodetic_to_ned_deg(
    lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """:func:`geodetic_to_ned` with latitudes and longitudes in degrees; NED [m] (..., 3)."""
    return geodetic_to_ned(np.deg2rad(lat_deg), np.deg2rad(lon_deg), h, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0)


def ned_to_geodetic_deg(
    p_ned: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ned_to_geodetic` with the origin and the result (lat_deg, lon_deg, h) in degrees."""
    lat, lon, h = ned_to_geodetic(p_ned, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0)
    return np.rad2deg(lat), np.rad2deg(lon), h


def enu_to_aer_deg(p_enu: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`enu_to_aer` giving (az_deg in [0, 360), el_deg, srange [m])."""
    az, el, srange = enu_to_aer(p_enu)
    az_deg = np.rad2deg(az)
    return np.where(az_deg >= 360.0, 0.0, az_deg), np.rad2deg(el), srange


def aer_to_enu_deg(az_deg: ArrayLike, el_deg: ArrayLike, srange: ArrayLike) -> np.ndarray:
    """:func:`aer_to_enu` with azimuth and elevation in degrees; ENU [m] (..., 3)."""
    return aer_to_enu(np.deg2rad(az_deg), np.deg2rad(el_deg), srange)


def geodetic_to_aer_deg(
    lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`geodetic_to_aer` in degrees: (az_deg in [0, 360), el_deg, srange [m])."""
    return enu_to_aer_deg(geodetic_to_enu_deg(lat_deg, lon_deg, h, lat0_deg, lon0_deg, h0))


def aer_to_geodetic_deg(
    az_deg: ArrayLike, el_deg: ArrayLike, srange: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`aer_to_geodetic` in degrees: (lat_deg, lon_deg, h [m])."""
    return enu_to_geodetic_deg(aer_to_enu_deg(az_deg, el_deg, srange), lat0_deg, lon0_deg, h0)


def ecef_to_aer_deg(
    p_ecef: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ecef_to_aer` with the origin in degrees: (az_deg in [0, 360), el_deg, srange [m])."""
    return enu_to_aer_deg(ecef_to_enu(p_ecef, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0))


def aer_to_ecef_deg(
    az_deg: ArrayLike, el_deg: ArrayLike, srange: ArrayLike, lat0_deg: ArrayLike, lon0_deg: ArrayLike, h0: ArrayLike
) -> np.ndarray:
    """:func:`aer_to_ecef` with azimuth, elevation and the origin in degrees; ECEF [m] (..., 3)."""
    return aer_to_ecef(np.deg2rad(az_deg), np.deg2rad(el_deg), srange, np.deg2rad(lat0_deg), np.deg2rad(lon0_deg), h0)


def ellipse_ring_enu(semi_major: float, semi_minor: float, azimuth_deg: float, n: int) -> np.ndarray:
    """``n`` vertices (n, 3) of a horizontal ellipse in a local ENU frame [m], about its origin.

    The major axis points along ``azimuth_deg`` (clockwise from north), the minor axis 90 degrees
    clockwise of it; the ring starts at the major axis's end and runs towards minus the minor
    axis: counterclockwise seen from above (RFC 7946's outer-ring order). Up is 0.
    """
    th = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    A, B = semi_major * np.cos(th), -semi_minor * np.sin(th)
    sa, ca = math.sin(math.radians(azimuth_deg)), math.cos(math.radians(azimuth_deg))
    return np.stack([A * sa + B * ca, A * ca - B * sa, np.zeros(n)], -1)
