"""Limb viewing: tangent height of a line of sight that misses the Earth [L18].

Conventions (frames, units, names, status codes): ``docs/conventions.md``;
method: docs/method.md section 6 and ``docs/limb.md``. Radians and metres inside,
arrays ``(..., 3)`` broadcasting over leading axes (a slit of pixels times many
frames is one call).

Three pieces:

* :func:`line_of_sight_l18`: the [L18] chain (eq. 1-11) from the sensor view
  angle alpha, the mounting angle theta, the platform attitude (yaw, roll,
  pitch) and the ECEF position and velocity to the ECEF line of sight, with
  every intermediate matrix kept (:class:`L18Chain`) for the teaching view.
* The virtual ellipsoid of [L18] (eq. 12-26): the WGS-84 ellipsoid grown with
  the same flattening by Delta a until it touches the line (eq. 17, solved by
  Newton-Raphson, every iterate recorded), its tangent point, the latitude and
  longitude of eq. 18-19 and the limb height of eq. 21-26.
* The exact tangent, beyond the paper: the minimum geodetic height along the
  line. Outside the Earth the geodetic height is the Euclidean distance to the
  (convex) ellipsoid, hence a convex function of the line parameter s; its
  derivative g(s) = n_up(P(s)) . d is monotone, and the minimum is the unique
  root of g, found by a bracketed Newton iteration that falls back to
  bisection (it cannot diverge and cannot pick a wrong local minimum).

Entry point for batches: :func:`limb_tangent`; scenario files:
:func:`geoloc.workflows.scenario.load_scenario` (``assets/scenarios/tiangong2_limb.toml``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames.rotations import rotate, rx, ry, rz
from geoloc.geodesy.ellipsoid import (
    E2,
    A,
    B,
    F,
    ecef_to_geodetic,
    meridian_radius,
    prime_vertical_radius,
    up_normal_ecef,
)
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.height import ray_inflated_ellipsoid

__all__ = [
    "L18Chain",
    "LimbTangent",
    "line_of_sight_l18",
    "orbital_frame_l18",
    "limb_tangent",
    "virtual_ellipsoid_tangent",
    "l18_geodetic",
    "exact_tangent",
]


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _mm(a, b):
    return np.einsum("...ij,...jk->...ik", a, b)


# --------------------------------------------------------------------------- #
# [L18] eq. 1-11: sensor view vector -> ECEF line of sight
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class L18Chain:
    """The [L18] chain from the sensor view angle to the ECEF line of sight.

    The paper's ``T_A/B`` ("from A to B") is the project's ``R_B_A``
    (``docs/conventions.md``). All matrices are stored exactly as printed in
    [L18]; in the project's passive notation ``T_z = rz(yaw)``,
    ``T_x = rx(roll)`` and ``T_y = ry(-pitch)`` (the printed eq. 5 has the
    sines swapped with respect to eq. 3-4; see ``docs/limb.md``).

    Attributes
    ----------
    view_scs : ndarray (..., 3)
        View vector in the sensor frame, [0, sin alpha, cos alpha] (eq. 1).
    R_body_scs : ndarray (..., 3, 3)
        Sensor -> body, rotation about X by theta (eq. 2, ``T_SCS/BODY``).
    T_z, T_x, T_y : ndarray (..., 3, 3)
        Yaw, roll and pitch factors (eq. 3, 4, 5).
    R_orb_body : ndarray (..., 3, 3)
        Body -> orbital, ``T_y T_x T_z`` (eq. 6, ``T_BODY/ORB``).
    R_ecef_orb : ndarray (..., 3, 3)
        Orbital -> ECEF, columns b1, b2, b3 (eq. 7-10, ``T_ORB/ECEF``).
    R_ecef_scs : ndarray (..., 3, 3)
        The whole product of eq. 11.
    origin_ecef : ndarray (..., 3)
        Sensor position P [m] (the line's origin X_ECEF of eq. 12).
    direction_ecef : ndarray (..., 3)
        Unit line of sight V_ECEF (eq. 11).
    status : ndarray (...) of uint8
        OK, or INVALID_INPUT (non-finite input, P = 0, or V parallel to P).
    """

    view_scs: np.ndarray
    R_body_scs: np.ndarray
    T_z: np.ndarray
    T_x: np.ndarray
    T_y: np.ndarray
    R_orb_body: np.ndarray
    R_ecef_orb: np.ndarray
    R_ecef_scs: np.ndarray
    origin_ecef: np.ndarray
    direction_ecef: np.ndarray
    status: np.ndarray

    @property
    def los(self) -> LineOfSight:
        """The chain's line of sight as the one type every sensor hands to surfaces."""
        return LineOfSight(self.origin_ecef, self.direction_ecef, self.status)


def orbital_frame_l18(position_ecef: ArrayLike, velocity_ecef: ArrayLike) -> np.ndarray:
    """Orbital -> ECEF rotation from position and velocity [L18 eq. 7-10].

    b3 = -P/|P| (towards the Earth's centre), b2 = (b3 x V)/|b3 x V|,
    b1 = b2 x b3, R_ecef_orb = [b1 b2 b3] (columns). For a circular orbit b1 is
    the along-track direction, b2 the negative orbit normal, b3 the nadir.

    Parameters
    ----------
    position_ecef, velocity_ecef : array_like (..., 3)
        Platform position P [m] and velocity V [m/s] in ECEF.

    Returns
    -------
    R_ecef_orb : ndarray (..., 3, 3)
        NaN where P = 0 or V is parallel to P.
    """
    p = np.asarray(position_ecef, float)
    v = np.asarray(velocity_ecef, float)
    p, v = np.broadcast_arrays(p, v)
    with np.errstate(invalid="ignore", divide="ignore"):
        b3 = -p / np.linalg.norm(p, axis=-1, keepdims=True)
        c = np.cross(b3, v)
        nc = np.linalg.norm(c, axis=-1, keepdims=True)
        # V (anti)parallel to P (or zero) leaves b2 undefined: NaN, flagged by the caller.
        nc = np.where(nc > 1e-12 * np.linalg.norm(v, axis=-1, keepdims=True), nc, np.nan)
        b2 = c / nc
        b1 = np.cross(b2, b3)
    return np.stack([b1, b2, b3], axis=-1)


def line_of_sight_l18(
    position_ecef: ArrayLike,
    velocity_ecef: ArrayLike,
    yaw: ArrayLike,
    roll: ArrayLike,
    pitch: ArrayLike,
    theta_mount: ArrayLike,
    alpha: ArrayLike,
) -> L18Chain:
    """ECEF line of sight of the limb sensor, the [L18] chain (eq. 1-11).

    V_ECEF = T_ORB/ECEF T_BODY/ORB T_SCS/BODY View, i.e. in the project's names
    ``direction_ecef = R_ecef_orb @ R_orb_body @ R_body_scs @ view_scs``, with
    View = [0, sin alpha, cos alpha] (eq. 1), ``R_body_scs = rx(theta)`` (eq. 2),
    ``R_orb_body = T_y T_x T_z`` (eq. 3-6, printed matrices) and
    ``R_ecef_orb = [b1 b2 b3]`` (eq. 7-10).

    At zero attitude the body frame is the orbital frame (X along track,
    Y the negative orbit normal, Z nadir), so the sensor's YZ plane - where
    both alpha and theta act - is the cross-track plane. A forward-looking
    limb slit therefore needs yaw = 90 deg (body Y along track), as in the
    bundled scenario; ``docs/limb.md`` discusses this reading of the paper.

    Parameters
    ----------
    position_ecef, velocity_ecef : array_like (..., 3)
        Platform position [m] and velocity [m/s], ECEF.
    yaw, roll, pitch : array_like (...)
        Platform attitude psi, phi, theta [rad] (eq. 3-5).
    theta_mount : array_like (...)
        Sensor mounting angle about body X [rad] (eq. 2).
    alpha : array_like (...)
        View angle in the sensor YZ plane from Z_SCS, positive towards +Y [rad] (eq. 1).

    Returns
    -------
    L18Chain
        All arrays broadcast over the leading axes of every input, e.g.
        position ``(F, 1, 3)`` and alpha ``(P,)`` give ``(F, P)`` lines.
    """
    p = np.asarray(position_ecef, float)
    v = np.asarray(velocity_ecef, float)
    angles = [np.asarray(x, float) for x in (yaw, roll, pitch, theta_mount, alpha)]
    shape = np.broadcast_shapes(p.shape[:-1], v.shape[:-1], *(x.shape for x in angles))
    p = np.broadcast_to(p, shape + (3,))
    v = np.broadcast_to(v, shape + (3,))
    yaw, roll, pitch, theta_mount, alpha = (np.broadcast_to(x, shape) for x in angles)

    view = np.stack([np.zeros(shape), np.sin(alpha), np.cos(alpha)], axis=-1)  # eq. 1
    R_body_scs = rx(theta_mount)  # eq. 2: [[1,0,0],[0,c,s],[0,-s,c]]
    T_z = rz(yaw)  # eq. 3: [[c,s,0],[-s,c,0],[0,0,1]]
    T_x = rx(roll)  # eq. 4: [[1,0,0],[0,c,s],[0,-s,c]]
    T_y = ry(-pitch)  # eq. 5 as printed: [[c,0,s],[0,1,0],[-s,0,c]]
    R_orb_body = _mm(T_y, _mm(T_x, T_z))  # eq. 6
    R_ecef_orb = orbital_frame_l18(p, v)  # eq. 7-10
    R_ecef_scs = _mm(R_ecef_orb, _mm(R_orb_body, R_body_scs))
    d = rotate(R_ecef_scs, view)  # eq. 11

    finite = (
        np.all(np.isfinite(p), axis=-1)
        & np.all(np.isfinite(v), axis=-1)
        & np.all(np.isfinite(np.stack(np.broadcast_arrays(yaw, roll, pitch, theta_mount, alpha), -1)), axis=-1)
        & np.all(np.isfinite(d), axis=-1)
    )
    status = np.where(finite, Status.OK, Status.INVALID_INPUT).astype(np.uint8)
    d = np.where(finite[..., None], d, np.nan)
    return L18Chain(view, R_body_scs, T_z, T_x, T_y, R_orb_body, R_ecef_orb, R_ecef_scs, p.copy(), d, status)


# --------------------------------------------------------------------------- #
# [L18] eq. 12-17: virtual ellipsoid of equal flattening, Newton-Raphson on Delta a
# --------------------------------------------------------------------------- #

#: Ratio b/a = 1 - f of every virtual ellipsoid (eq. 13: equal flattening).
_K = 1.0 - F


def _eq17(delta_a, xt, ut):
    """Eq. 17 divided by |v'|^2 and the derivative of eq. 17 itself, for Newton.

    With a' = a + Delta a, b' = (1 - f) a', v' = (v1/a', v2/a', v3/b') (eq. 14),
    P' = (x1/a', x2/a', x3/b') (eq. 15), eq. 17 (divided by 4) reads
    D(a') = (v'.P')^2 - |v'|^2 (|P'|^2 - 1). Writing u = (v1, v2, v3/(1-f)),
    X = (x1, x2, x3/(1-f)) and C = |u|^2 |X|^2 - (u.X)^2, D = |u|^2/a'^2 - C/a'^4
    and dD/da' = 4 C/a'^5 - 2 |u|^2/a'^3.
    """
    ap = A + delta_a
    vp = ut / ap[..., None]
    pp = xt / ap[..., None]
    vv = _dot(vp, vp)
    disc = _dot(vp, pp) ** 2 - vv * (_dot(pp, pp) - 1.0)  # eq. 17 / 4
    uu = _dot(ut, ut)
    C = uu * _dot(xt, xt) - _dot(ut, xt) ** 2
    ddisc = 4.0 * C / ap**5 - 2.0 * uu / ap**3
    return disc, ddisc, disc / vv


@dataclass(frozen=True)
class VirtualEllipsoid:
    """Newton-Raphson solution of [L18] eq. 17 and the tangent point (eq. 12, 16).

    Attributes
    ----------
    delta_a : ndarray (...)
        Growth Delta a of the semi-major axis [m].
    s : ndarray (...)
        Line parameter of the tangent point, metres along the unit direction.
    ecef : ndarray (..., 3)
        Tangent point X + s V (eq. 12).
    iterations : ndarray (...) of int
        Newton steps taken.
    delta_a_history, residual_history : ndarray (max_iter + 1, ...)
        Delta a and the normalised eq. 17 residual (eq. 17 / |v'|^2,
        dimensionless, 0 at tangency) at the start and after each step; NaN
        after convergence.
    status : ndarray (...) of uint8
        OK or NO_CONVERGENCE (or INVALID_INPUT for non-finite input).
    """

    delta_a: np.ndarray
    s: np.ndarray
    ecef: np.ndarray
    iterations: np.ndarray
    delta_a_history: np.ndarray
    residual_history: np.ndarray
    status: np.ndarray


def virtual_ellipsoid_tangent(
    origin_ecef: ArrayLike,
    direction_ecef: ArrayLike,
    *,
    delta_a0: ArrayLike = 0.0,
    tol_m: float = 1e-6,
    max_iter: int = 20,
) -> VirtualEllipsoid:
    """Solve the tangency condition [L18 eq. 17] for Delta a by Newton-Raphson.

    The virtual ellipsoid (x^2 + y^2)/(a + Da)^2 + z^2/((1 - f)(a + Da))^2 = 1
    (eq. 13, equal flattening) meets the line X + s V where
    s^2 |v'|^2 + 2 s (v'.P') + |P'|^2 - 1 = 0 (eq. 16); it touches it when the
    discriminant vanishes (eq. 17). Newton steps Da <- Da - D(Da)/D'(Da) start
    at ``delta_a0`` (the paper gives no start value; 0, the WGS-84 ellipsoid,
    converges quadratically for any line passing above the ground) and stop
    when a step is below ``tol_m``. Then s = -(v'.P')/|v'|^2 (the double root of
    eq. 16) and the tangent point is X + s V (eq. 12).

    Parameters
    ----------
    origin_ecef, direction_ecef : array_like (..., 3)
        Line origin X [m] and direction V (any length), ECEF.
    delta_a0 : float or array_like
        Start value of Delta a [m].
    tol_m : float
        Convergence threshold on the Newton step [m].
    max_iter : int
        Step limit; a line not converged by then gets NO_CONVERGENCE.

    Returns
    -------
    VirtualEllipsoid
    """
    if not (max_iter >= 0):
        raise ValueError(f"max_iter must be >= 0, got {max_iter!r}")
    if not (tol_m > 0):
        raise ValueError(f"tol_m must be > 0, got {tol_m!r}")
    x = np.asarray(origin_ecef, float)
    v = np.asarray(direction_ecef, float)
    shape = np.broadcast_shapes(x.shape[:-1], v.shape[:-1], np.shape(delta_a0))
    x = np.broadcast_to(x, shape + (3,))
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.broadcast_to(v, shape + (3,)) / np.linalg.norm(np.broadcast_to(v, shape + (3,)), axis=-1, keepdims=True)
    scale = np.array([1.0, 1.0, 1.0 / _K])
    xt, ut = x * scale, v * scale
    finite = np.all(np.isfinite(xt), axis=-1) & np.all(np.isfinite(ut), axis=-1)
    da = np.where(finite, np.broadcast_to(np.asarray(delta_a0, float), shape), np.nan)
    hist_da = np.full((max_iter + 1,) + shape, np.nan)
    hist_r = np.full((max_iter + 1,) + shape, np.nan)
    iters = np.zeros(shape, dtype=np.int32)
    converged = np.zeros(shape, bool)
    active = finite.copy()
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        _, _, r0 = _eq17(da, xt, ut)
        hist_da[0] = np.where(active, da, np.nan)
        hist_r[0] = np.where(active, r0, np.nan)
        for k in range(1, max_iter + 1):
            if not active.any():
                break
            disc, ddisc, _ = _eq17(da, xt, ut)
            step = disc / ddisc
            bad = active & ~np.isfinite(step)
            active &= ~bad
            da = np.where(active, da - step, da)
            iters += active
            _, _, r = _eq17(da, xt, ut)
            hist_da[k] = np.where(active, da, np.nan)
            hist_r[k] = np.where(active, r, np.nan)
            done = active & (np.abs(step) <= tol_m) & (A + da > 0)
            converged |= done
            active &= ~done
        status = np.full(shape, Status.NO_CONVERGENCE, dtype=np.uint8)
        status[converged] = Status.OK
        status[~finite] = Status.INVALID_INPUT
        da = np.where(converged, da, np.nan)
        ap = A + da
        vp, pp = ut / ap[..., None], xt / ap[..., None]
        s = -_dot(vp, pp) / _dot(vp, vp)  # double root of eq. 16
    return VirtualEllipsoid(da, s, x + s[..., None] * v, iters, hist_da, hist_r, status)


# --------------------------------------------------------------------------- #
# [L18] eq. 18-26: latitude, longitude and limb height of the tangent point
# --------------------------------------------------------------------------- #


def l18_geodetic(p_ecef: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude and limb height of a tangent point as in [L18 eq. 18-26].

    lon = atan2(y, x) (eq. 18, quadrant-aware);
    lat_d = atan( z / ((1 - e^2) sqrt(x^2 + y^2)) ) (eq. 19);
    geocentric latitude of the foot point P', tan(lat) = (1 - e^2) tan(lat_d) (eq. 20);
    P' = (x_a, y_a, z_a) on the WGS-84 ellipsoid at that geocentric latitude and
    at longitude lon (eq. 21-23); the height h solves
    P = P' + h (cos lat_d cos lon, cos lat_d sin lon, sin lat_d) (eq. 24-26) -
    three equations for one unknown, solved in the least-squares sense,
    h = (P - P') . n(lat_d); the residual is returned as ``misfit``.

    Eq. 19 is the geodetic latitude of a point *on* the ellipsoid; for a point
    at height h it is biased by about e^2 (h / R_N) sin(lat) cos(lat) (see
    ``docs/limb.md`` for the measured effect).

    Parameters
    ----------
    p_ecef : array_like (..., 3)
        Tangent point [m].

    Returns
    -------
    lat_d, lon, h : ndarray
        Latitude and longitude [rad], limb height [m].
    foot_ecef : ndarray (..., 3)
        Foot point P' (eq. 21-23).
    misfit : ndarray
        |P - P' - h n| [m]: how far eq. 24-26 are from being consistent.
    """
    p = np.asarray(p_ecef, float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rho = np.hypot(x, y)
    lon = np.arctan2(y, x)  # eq. 18
    lat_d = np.arctan2(z, (1.0 - E2) * rho)  # eq. 19
    lat_c = np.arctan2((1.0 - E2) * np.sin(lat_d), np.cos(lat_d))  # eq. 20
    # eq. 21-22: the point of the ellipsoid at geocentric latitude lat_c
    r = A * B / np.hypot(B * np.cos(lat_c), A * np.sin(lat_c))
    rho_a, z_a = r * np.cos(lat_c), r * np.sin(lat_c)
    foot = np.stack([rho_a * np.cos(lon), rho_a * np.sin(lon), z_a], axis=-1)  # eq. 23
    n = up_normal_ecef(lat_d, lon)
    h = _dot(p - foot, n)  # eq. 24-26, least squares
    misfit = np.linalg.norm(p - foot - h[..., None] * n, axis=-1)
    return lat_d, lon, h, foot, misfit


# --------------------------------------------------------------------------- #
# Exact tangent: minimum geodetic height along the line (beyond the paper)
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class ExactTangent:
    """Minimum geodetic height along a line of sight.

    Attributes
    ----------
    s : ndarray (...)
        Line parameter of the minimum, metres along the unit direction.
    ecef : ndarray (..., 3)
        The point of minimum geodetic height.
    lat, lon, h : ndarray (...)
        Its geodetic coordinates [rad, rad, m] (``geoloc.geodesy.ellipsoid.ecef_to_geodetic``).
    iterations : ndarray (...) of int
        Bracketed Newton / bisection steps (bracket search not counted).
    status : ndarray (...) of uint8
    """

    s: np.ndarray
    ecef: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    iterations: np.ndarray
    status: np.ndarray


def _slope(o, d, s):
    """g(s) = n_up . d and its exact derivative along the line (unit d).

    Outside the ellipsoid the geodetic height is the distance to it, so its
    gradient is the outward normal at the foot point: dh/ds = n_up . d = g.
    The surfaces of constant height h have principal radii R_M + h (north)
    and R_N + h (east) along the same normal, so
    dg/ds = (d.N)^2/(R_M + h) + (d.E)^2/(R_N + h) >= 0.
    """
    p = o + s[..., None] * d
    lat, lon, h = ecef_to_geodetic(p)
    n = up_normal_ecef(lat, lon)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    north = np.stack([-sl * co, -sl * so, cl], axis=-1)
    east = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    g = _dot(n, d)
    dg = _dot(d, north) ** 2 / (meridian_radius(lat) + h) + _dot(d, east) ** 2 / (prime_vertical_radius(lat) + h)
    return g, dg


def exact_tangent(
    origin_ecef: ArrayLike,
    direction_ecef: ArrayLike,
    active: ArrayLike | None = None,
    *,
    tol_m: float = 1e-4,
    max_iter: int = 100,
) -> ExactTangent:
    """Minimum geodetic height along the ray X + s V, s >= 0, for rays that miss the Earth.

    Why it is robust: outside the (convex) ellipsoid the geodetic height of a
    point is its Euclidean distance to the ellipsoid, and the distance to a
    convex set is a convex function; along a line that does not meet the
    ellipsoid h(s) is therefore convex, with a single minimum where its slope
    g(s) = n_up . V changes sign (g is non-decreasing). The search keeps a
    bracket [lo, hi] with g(lo) < 0 < g(hi) (lo = 0, hi doubled until g > 0),
    takes Newton steps s - g/g' with the exact curvature g' of the constant-
    height surface, and bisects whenever a step would leave the bracket. It
    stops when the step or the bracket is below ``tol_m``. A position error
    ds along the line changes the height only by ds^2 / (2 (R + h)), so
    ``tol_m = 1e-4`` gives heights exact to floating-point rounding.

    Parameters
    ----------
    origin_ecef, direction_ecef : array_like (..., 3)
        Ray origin [m] and direction (normalised here), ECEF.
    active : array_like of bool (...), optional
        Rays to solve; the caller guarantees they miss the Earth and descend at
        s = 0 (g(0) < 0). Others get NaN and status INVALID_INPUT. By default
        the rays whose g(0) < 0 (no check that they miss the Earth).
    tol_m : float
        Stop tolerance on s [m].
    max_iter : int
        Newton/bisection step limit (bisection alone needs about 40 steps).

    Returns
    -------
    ExactTangent
    """
    o = np.asarray(origin_ecef, float)
    d = np.asarray(direction_ecef, float)
    shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1])
    o = np.broadcast_to(o, shape + (3,))
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.broadcast_to(d, shape + (3,))
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        g0, _ = _slope(o, d, np.zeros(shape))
        live = np.broadcast_to(np.asarray(g0 < 0 if active is None else active, bool), shape) & (g0 < 0)
        lo = np.zeros(shape)
        # Spherical estimate of the closest approach, then double until g(hi) > 0.
        hi = np.where(live, np.maximum(-2.0 * _dot(o, d), 1e3), np.nan)
        grow = live.copy()
        for _ in range(64):
            if not grow.any():
                break
            ghi, _ = _slope(o, d, hi)
            still = grow & ~(ghi > 0)
            lo = np.where(still, hi, lo)
            hi = np.where(still, 2.0 * hi + 1e3, hi)
            grow = still
        live = live & ~grow
        s = np.where(live, np.clip(-_dot(o, d), lo, hi), np.nan)
        iters = np.zeros(shape, dtype=np.int32)
        converged = np.zeros(shape, bool)
        run = live.copy()
        for _ in range(max_iter):
            if not run.any():
                break
            g, dg = _slope(o, d, s)
            lo = np.where(run & (g < 0), s, lo)
            hi = np.where(run & (g > 0), s, hi)
            newton = s - g / dg
            inside = (newton >= lo) & (newton <= hi)
            s_new = np.where(inside, newton, 0.5 * (lo + hi))
            s_new = np.where(g == 0, s, s_new)
            done = run & ((np.abs(s_new - s) <= tol_m) | (hi - lo <= tol_m))
            s = np.where(run, s_new, s)
            iters += run
            converged |= done
            run &= ~done
        status = np.full(shape, Status.INVALID_INPUT, dtype=np.uint8)
        status[live] = Status.NO_CONVERGENCE
        status[converged] = Status.OK
        s = np.where(converged, s, np.nan)
        p = o + s[..., None] * d
        lat, lon, h = ecef_to_geodetic(p)
    return ExactTangent(s, p, lat, lon, h, iters, status)


# --------------------------------------------------------------------------- #
# Both together, for batches of lines of sight
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class LimbTangent:
    """Tangent of a batch of lines of sight: [L18] virtual ellipsoid and exact minimum.

    Every array has the broadcast leading shape ``(...)`` of the inputs
    (points ``(..., 3)``, histories ``(max_iter + 1, ...)``). Numeric outputs
    are NaN where their method did not give an answer.

    Attributes
    ----------
    status : ndarray (...) of uint8
        :class:`geoloc.status.Status`: OK; INVALID_INPUT (non-finite input or
        zero direction); ORIGIN_BELOW (origin at or below the ellipsoid);
        HITS_EARTH (the ray meets the WGS-84 ellipsoid ahead: no tangent);
        BEHIND_CAMERA (the ray rises from its origin: the closest approach is
        behind the sensor); NO_CONVERGENCE (Newton-Raphson on eq. 17, or the
        exact search, did not converge: see ``nr_status``/``exact_status``).
    nr_status, exact_status : ndarray (...) of uint8
        Status of each method alone.
    delta_a : ndarray (...)
        Delta a of the virtual ellipsoid [m] (eq. 17).
    s : ndarray (...)
        Line parameter of the virtual-ellipsoid tangent point [m along the unit direction].
    tangent_ecef : ndarray (..., 3)
        Virtual-ellipsoid tangent point (eq. 12).
    tangent_lat, tangent_lon : ndarray (...)
        Its latitude and longitude by eq. 18-19 [rad].
    tangent_h : ndarray (...)
        Its limb height by eq. 21-26 [m] (the paper's answer).
    foot_ecef : ndarray (..., 3)
        Foot point P' on the ellipsoid (eq. 21-23).
    tangent_h_geodetic, tangent_lat_geodetic : ndarray (...)
        Exact geodetic height [m] and latitude [rad] of the same tangent point.
    nr_iterations : ndarray (...) of int
    nr_delta_a_history, nr_residual_history : ndarray (max_iter + 1, ...)
        Newton-Raphson iterates of Delta a [m] and normalised eq. 17 residual.
    exact_s, exact_ecef, exact_lat, exact_lon, exact_h : ndarray
        Exact tangent: parameter [m], point, geodetic latitude/longitude [rad]
        and minimum geodetic height [m] along the line.
    exact_iterations : ndarray (...) of int
    earth_hit_ecef : ndarray (..., 3)
        First intersection with the WGS-84 ellipsoid where status is HITS_EARTH.
    origin_ecef, direction_ecef : ndarray (..., 3)
        The inputs, direction normalised.
    """

    status: np.ndarray
    nr_status: np.ndarray
    exact_status: np.ndarray
    delta_a: np.ndarray
    s: np.ndarray
    tangent_ecef: np.ndarray
    tangent_lat: np.ndarray
    tangent_lon: np.ndarray
    tangent_h: np.ndarray
    foot_ecef: np.ndarray
    tangent_h_geodetic: np.ndarray
    tangent_lat_geodetic: np.ndarray
    nr_iterations: np.ndarray
    nr_delta_a_history: np.ndarray
    nr_residual_history: np.ndarray
    exact_s: np.ndarray
    exact_ecef: np.ndarray
    exact_lat: np.ndarray
    exact_lon: np.ndarray
    exact_h: np.ndarray
    exact_iterations: np.ndarray
    earth_hit_ecef: np.ndarray
    origin_ecef: np.ndarray
    direction_ecef: np.ndarray

    @property
    def h_difference(self) -> np.ndarray:
        """Virtual-ellipsoid limb height minus exact tangent height [m]."""
        return self.tangent_h - self.exact_h

    @property
    def tangent_lat_deg(self) -> np.ndarray:
        return np.degrees(self.tangent_lat)

    @property
    def tangent_lon_deg(self) -> np.ndarray:
        return np.degrees(self.tangent_lon)

    @property
    def exact_lat_deg(self) -> np.ndarray:
        return np.degrees(self.exact_lat)

    @property
    def exact_lon_deg(self) -> np.ndarray:
        return np.degrees(self.exact_lon)

    @property
    def shape(self) -> tuple:
        return self.status.shape


def limb_tangent(
    origin_ecef: ArrayLike,
    direction_ecef: ArrayLike,
    *,
    delta_a0: ArrayLike = 0.0,
    tol_m: float = 1e-6,
    max_iter: int = 20,
    exact_tol_m: float = 1e-4,
    exact_max_iter: int = 100,
) -> LimbTangent:
    """Tangent point and limb height of lines of sight, [L18] and exact, in one batch.

    For each line X + s V (s >= 0): first the geometry is classified with the
    closed-form ray x WGS-84 ellipsoid intersection
    (:func:`geoloc.surfaces.height.ray_inflated_ellipsoid` at h = 0): a ray that
    meets the Earth is HITS_EARTH (its ground point in ``earth_hit_ecef``), not
    a tangent. For the others: the [L18] virtual ellipsoid
    (:func:`virtual_ellipsoid_tangent`, eq. 12-17) and its latitude, longitude
    and height (:func:`l18_geodetic`, eq. 18-26), and independently the
    minimum geodetic height along the line (:func:`exact_tangent`).

    Parameters
    ----------
    origin_ecef, direction_ecef : array_like (..., 3)
        Sensor position [m] and line of sight (any length), ECEF; broadcast.
    delta_a0, tol_m, max_iter
        Newton-Raphson start value [m], step tolerance [m] and step limit for eq. 17.
    exact_tol_m, exact_max_iter
        Tolerance [m along the line] and step limit of the exact search.

    Returns
    -------
    LimbTangent
    """
    o = np.asarray(origin_ecef, float)
    d = np.asarray(direction_ecef, float)
    shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1])
    o = np.broadcast_to(o, shape + (3,))
    d = np.broadcast_to(d, shape + (3,))
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.linalg.norm(d, axis=-1, keepdims=True)
        d = d / norm
    finite = np.all(np.isfinite(o), axis=-1) & np.all(np.isfinite(d), axis=-1) & (norm[..., 0] > 0)
    o_safe = np.where(finite[..., None], o, A * 2.0)  # keep NaN out of the solvers' arithmetic
    d_safe = np.where(finite[..., None], d, np.array([0.0, 0.0, 1.0]))

    status = np.where(finite, Status.OK, Status.INVALID_INPUT).astype(np.uint8)
    hit = ray_inflated_ellipsoid(o_safe, d_safe, 0.0)
    below = finite & (hit.status == Status.ORIGIN_BELOW)
    hits = finite & (hit.status == Status.OK)
    status[below] = Status.ORIGIN_BELOW
    status[hits] = Status.HITS_EARTH
    earth_hit = np.where(hits[..., None], hit.ecef, np.nan)

    with np.errstate(invalid="ignore", divide="ignore"):
        lat0, lon0, _ = ecef_to_geodetic(o_safe)
        g0 = _dot(up_normal_ecef(lat0, lon0), d_safe)
    behind = (status == Status.OK) & ~(g0 < 0)
    status[behind] = Status.BEHIND_CAMERA
    solve = status == Status.OK

    ve = virtual_ellipsoid_tangent(o_safe, d_safe, delta_a0=delta_a0, tol_m=tol_m, max_iter=max_iter)
    ex = exact_tangent(o_safe, d_safe, solve, tol_m=exact_tol_m, max_iter=exact_max_iter)

    nr_status = np.where(solve, ve.status, status).astype(np.uint8)
    exact_status = np.where(solve, ex.status, status).astype(np.uint8)
    status[solve & (nr_status != Status.OK)] = Status.NO_CONVERGENCE
    status[solve & (exact_status != Status.OK)] = Status.NO_CONVERGENCE

    nr_ok = nr_status == Status.OK
    ex_ok = exact_status == Status.OK

    def keep(x, mask):
        m = mask if x.ndim == mask.ndim else mask[..., None]
        return np.where(m, x, np.nan)

    with np.errstate(invalid="ignore", divide="ignore"):
        lat_d, lon, h, foot, _ = l18_geodetic(ve.ecef)
        glat, _, gh = ecef_to_geodetic(ve.ecef)
    hist_mask = np.broadcast_to(solve, ve.delta_a_history.shape)
    return LimbTangent(
        status=status,
        nr_status=nr_status,
        exact_status=exact_status,
        delta_a=keep(ve.delta_a, nr_ok),
        s=keep(ve.s, nr_ok),
        tangent_ecef=keep(ve.ecef, nr_ok),
        tangent_lat=keep(lat_d, nr_ok),
        tangent_lon=keep(lon, nr_ok),
        tangent_h=keep(h, nr_ok),
        foot_ecef=keep(foot, nr_ok),
        tangent_h_geodetic=keep(gh, nr_ok),
        tangent_lat_geodetic=keep(glat, nr_ok),
        nr_iterations=np.where(solve, ve.iterations, 0).astype(np.int32),
        nr_delta_a_history=np.where(hist_mask, ve.delta_a_history, np.nan),
        nr_residual_history=np.where(hist_mask, ve.residual_history, np.nan),
        exact_s=keep(ex.s, ex_ok),
        exact_ecef=keep(ex.ecef, ex_ok),
        exact_lat=keep(ex.lat, ex_ok),
        exact_lon=keep(ex.lon, ex_ok),
        exact_h=keep(ex.h, ex_ok),
        exact_iterations=np.where(solve, ex.iterations, 0).astype(np.int32),
        earth_hit_ecef=earth_hit,
        origin_ecef=np.where(finite[..., None], o, np.nan),
        direction_ecef=np.where(finite[..., None], d, np.nan),
    )
