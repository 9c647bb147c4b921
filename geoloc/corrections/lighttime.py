"""Light-time and aberration of light: the two corrections of a spaceborne line of sight for motion.

Both are what Orekit Rugged applies in its direct location (``Rugged.directLocation``,
``setLightTimeCorrection`` and ``setAberrationOfLightCorrection``, both on by default
there); the formulas here are the textbook ones, written out below.

Light-time
----------
The light the sensor records at time t left the ground at t - dt, dt = rho / c (rho the
slant range). Meanwhile the Earth turned by omega_E dt about its axis. The straight
line of sight, met with the Earth frozen at t, gives the point where the ground *was*
when the light left it; the ground point's Earth-fixed coordinates are that point turned
eastwards by omega_E rho / c (for a surface of revolution about the axis, such as a
constant height above the ellipsoid, that is the whole correction; for a DEM, meet the
turned line with it: :func:`light_time_line`). At 800 km, 2.7 ms: 1.24 m cos(latitude).

Aberration
----------
A sensor moving at v (relative to an inertial frame) sees the light arrive from a
direction tilted towards its velocity by about |v| sin(angle) / c: 25 microradians at
7.5 km/s, 20 m on the ground from 800 km. The line of sight the sensor reports (its
*apparent* direction u') is turned back into the direction the light came from in the
inertial frame (u): classically as Rugged does, c u + v = k u' with |u| = 1 (Galilean
addition of velocities), or exactly, by the Lorentz transformation of the photon's
direction (special relativity; e.g. Jackson, Classical Electrodynamics, chapter 11,
or any text's "relativistic aberration"):

    u = (u'_perp + gamma (u'_par - beta) v_hat) / (gamma (1 - beta u'_par)),   beta = |v| / c,

u'_par = u' . v_hat. The two differ by (beta^2) ~ 1e-9 rad, 1 mm at 800 km.
The velocity must be inertial, expressed in the axes the direction is in (ECEF axes at
the instant: :func:`inertial_velocity` adds the Earth's rotation, omega x r, to an
Earth-fixed velocity).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: Speed of light in vacuum [m/s] (SI, exact).
C_LIGHT = 299792458.0
#: The Earth's rotation rate [rad/s] (WGS-84, NIMA TR8350.2 table 3.1; IERS's nominal value).
OMEGA_EARTH = 7.292115e-5


def _vec(a: npt.ArrayLike) -> np.ndarray:
    return np.asarray(a, float)


def inertial_velocity(position_ecef: npt.ArrayLike, velocity_ecef: npt.ArrayLike) -> np.ndarray:
    """Velocity relative to the inertial frame aligned with ECEF now: v_ecef + omega_E z x r [m/s].

    Parameters
    ----------
    position_ecef, velocity_ecef : array_like (..., 3)
        Position [m] and Earth-fixed velocity [m/s].
    """
    r = _vec(position_ecef)
    v = _vec(velocity_ecef)
    w = np.stack(np.broadcast_arrays(-OMEGA_EARTH * r[..., 1], OMEGA_EARTH * r[..., 0], 0.0 * r[..., 2]), axis=-1)
    return v + w


def aberration(direction: npt.ArrayLike, velocity_inertial: npt.ArrayLike, relativistic: bool = False) -> np.ndarray:
    """The direction the light came from, given the apparent line of sight of a moving sensor.

    Parameters
    ----------
    direction : array_like (..., 3)
        The apparent line of sight (from the sensor to the scene), need not be unit.
    velocity_inertial : array_like (..., 3)
        The sensor's velocity relative to an inertial frame, in the same axes [m/s].
    relativistic : bool
        The Lorentz form (exact) instead of the classical one (Rugged's); they differ by
        (v/c)^2, below 1e-9 rad for a satellite.

    Returns
    -------
    ndarray (..., 3)
        Unit direction of the light path, from the sensor towards the scene (NaN where
        the input is not finite or the direction is zero).
    """
    u = _vec(direction)
    v = _vec(velocity_inertial)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        if not relativistic:
            # c l + v = k u, |l| = 1: k^2 - 2 k (u.v) + |v|^2 - c^2 = 0, the positive root
            uv = np.sum(u * v, axis=-1, keepdims=True)
            vv = np.sum(v * v, axis=-1, keepdims=True)
            k = uv + np.sqrt(uv * uv - (vv - C_LIGHT**2))
            return (k * u - v) / C_LIGHT
        return _lorentz(u, v, -1.0)


def _lorentz(u, v, sign: float):
    """The relativistic aberration of unit directions u by the velocity v, with beta = sign |v| / c:
    u' = (u_perp + gamma (u_par + beta) v_hat) / (gamma (1 + beta u_par)), normalised
    (:func:`aberration` with sign -1, its inverse :func:`apparent_direction` with +1)."""
    speed = np.linalg.norm(v, axis=-1, keepdims=True)
    beta = sign * speed / C_LIGHT
    vhat = np.where(speed > 0, v / np.where(speed > 0, speed, 1.0), 0.0)
    gamma = 1.0 / np.sqrt(1.0 - beta * beta)
    upar = np.sum(u * vhat, axis=-1, keepdims=True)
    uperp = u - upar * vhat
    out = (uperp + gamma * (upar + beta) * vhat) / (gamma * (1.0 + beta * upar))
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def apparent_direction(
    direction: npt.ArrayLike, velocity_inertial: npt.ArrayLike, relativistic: bool = False
) -> np.ndarray:
    """The inverse of :func:`aberration`: the line of sight a moving sensor sees for a light path.

    Classical: u' = (c u + v) / |c u + v|; relativistic: the Lorentz form with +beta.
    """
    u = _vec(direction)
    v = _vec(velocity_inertial)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        if not relativistic:
            out = C_LIGHT * u + v
            return out / np.linalg.norm(out, axis=-1, keepdims=True)
        return _lorentz(u, v, 1.0)


def _rot_z(angle, x):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * x[..., 0] - s * x[..., 1], s * x[..., 0] + c * x[..., 1], x[..., 2]], axis=-1)


def light_time_angle(origin_ecef: npt.ArrayLike, hit_ecef: npt.ArrayLike) -> np.ndarray:
    """omega_E rho / c: how far the Earth turns while the light crosses the slant range rho [rad]."""
    rho = np.linalg.norm(_vec(hit_ecef) - _vec(origin_ecef), axis=-1)
    return OMEGA_EARTH * rho / C_LIGHT


def light_time_point(origin_ecef: npt.ArrayLike, hit_ecef: npt.ArrayLike) -> np.ndarray:
    """The ground point's Earth-fixed position: the raw hit turned east by omega_E rho / c.

    Exact for a surface of revolution about the Earth's axis (a constant height above
    the ellipsoid), where meeting the turned line equals turning the hit.
    """
    hit = _vec(hit_ecef)
    return _rot_z(light_time_angle(origin_ecef, hit_ecef), hit)


def light_time_line(
    origin_ecef: npt.ArrayLike, direction_ecef: npt.ArrayLike, hit_ecef: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """The line of sight turned east by omega_E rho / c, rho the range to the raw hit: meet it with a DEM.

    Rugged's correction, as a line: points of the light path at the raw hit's range are
    exactly where the Earth-fixed ground was when the light left it; a range off by
    dr turns them by omega_E dr / c too little or too much (1e-12 rad for 3 km).

    Returns
    -------
    (origin (..., 3), direction (..., 3))
    """
    ang = light_time_angle(origin_ecef, hit_ecef)
    return _rot_z(ang, _vec(origin_ecef)), _rot_z(ang, _vec(direction_ecef))


def light_time_source(origin_ecef: npt.ArrayLike, ground_ecef: npt.ArrayLike, iterations: int = 3) -> np.ndarray:
    """Where an Earth-fixed ground point was when the light now reaching ``origin`` left it: aim there.

    The inverse of :func:`light_time_point` (for ground to pixel): the point turned west by
    omega_E rho / c, rho its range from the sensor, found by a fixed point on rho (each
    step gains the factor omega_E rho / c ~ 2e-7; three are exact to rounding).
    """
    o = _vec(origin_ecef)
    g = _vec(ground_ecef)
    x = g
    for _ in range(iterations):
        x = _rot_z(-light_time_angle(o, x), g)
    return x
