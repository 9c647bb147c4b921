"""Predicted uncertainty of every located point: first-order propagation of a sensor's error budget.

For a batch of rays (pixels, poses) and a surface, :func:`propagate` gives each located point
its 3x3 covariance in the local east-north-up frame at the hit, the horizontal error ellipse
(1-sigma semi-axes and the major axis's azimuth), CE90 computed exactly for that ellipse
(:func:`ce90`, not the circular approximation) and LE90 = 1.6449 sigma_up. The budget is the
sensor file's ``[uncertainty]`` table (:class:`geoloc.sensors.budget.ErrorBudget`); the
method and its check against Monte Carlo: ``docs/uncertainty.md``.

The Jacobian, per ray, is analytic through the chain and the surface:

* every angle of the chain (attitude, each gimbal joint, mount, boresight) turns the line of
  sight about its joint's axis: with that axis ``a`` in ECEF, ``dD = a x D`` per radian
  (and ``dO = a x L`` for the attitude, which turns the lever arm ``L`` too);
* a platform displacement moves the origin along the local north, east or up and turns the
  local NED frame (by ``-e / (R_M + h)`` per metre north, ``z / ((R_N + h) cos lat)`` east);
* the lever arm moves the origin along the body axes; a lens parameter moves the optical
  direction (central differences of the lens's ``unproject``, turned to ECEF);
* a time-tag error is the platform displacement ``v dt`` (the velocity is the caller's);
* the surface: the hit ``P = O + t D`` stays on the surface, linearised at the hit with its
  normal ``m = u - g_e e - g_n n`` (``g`` the DEM's local slope there, zero on a constant
  height); a change ``dO, dD`` and a vertical surface error ``dz`` move the hit by
  ``dP = dO + t dD + D (dz - m.(dO + t dD)) / (m.D)``.

The batch runs compiled (:mod:`geoloc.analysis._fastuncert`, ``engine="auto"``): a numba kernel
for the chain's Jacobian per ray and one for the surface step, the covariance, the ellipse and
CE90 (on a geographic DEM one that also fits the footprint's plane, the terrain's departure from
it and the grazing test; a projected DEM or a mosaic takes the numpy surface step); the numpy
path here is the reference they are held to.
``benchmarks/bench_uncertainty.py`` times it against ``locate``.

``tests/analysis/test_uncertainty.py`` holds the analytic Jacobian to central differences of the whole
``locate`` chain, and the predicted CE90 / LE90 to Monte Carlo (:func:`monte_carlo`) over
nadir to 80 degrees off nadir, the ellipsoid and a DEM, and every gimbal preset.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from collections.abc import Iterable
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import E2, A, geodetic_to_ecef, meridian_radius, prime_vertical_radius
from geoloc.geodesy.local import R_ecef_enu, R_ecef_ned, ecef_to_enu
from geoloc.locate import as_sensor
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.base import COMPILED_MIN_RAYS
from geoloc.sensors.budget import LE90_PER_SIGMA, LENS_KEYS, ErrorBudget
from geoloc.sensors.frame import small_rotation
from geoloc.sensors.lenses import PARAM_LAYOUT
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight, terrain_of
from geoloc.surfaces.height import HeightSurface

if TYPE_CHECKING:  # the error model's module loads only for budget_from_error_model
    from geoloc.analysis.errormodel import ErrorModel

DEG = math.pi / 180.0
#: sqrt of the chi-square (2 dof) 0.9 quantile: the 90 % ellipse is the 1-sigma ellipse times this.
ELLIPSE90_PER_SIGMA = math.sqrt(-2.0 * math.log(0.1))
_AXES = {"x": 0, "y": 1, "z": 2}


# --------------------------------------------------------------------- CE90, exactly
def _prob_inside(R, q, nodes=128):
    """P(sqrt(X1^2 + q^2 X2^2) <= R), X1, X2 standard normal (vectorised over R, q).

    With x = R sin(phi): P = 2 int_0^{pi/2} pdf(R sin phi) [2 Phi(R cos phi / q) - 1] R cos phi dphi,
    a smooth integrand for every q in [0, 1] (Gauss-Legendre).
    """
    from scipy.special import ndtr

    w, s, c = _quadrature(nodes)
    R = np.asarray(R, float)[..., None]
    q = np.asarray(q, float)[..., None]
    with np.errstate(divide="ignore"):
        inner = np.where(q > 0, 2.0 * ndtr(R * c / np.where(q > 0, q, 1.0)) - 1.0, 1.0)
    pdf = np.exp(-0.5 * (R * s) ** 2) / math.sqrt(2.0 * math.pi)
    return 2.0 * np.sum(w * pdf * inner * R * c, axis=-1)


@lru_cache(maxsize=4)
def _quadrature(nodes: int):
    """Weights and sin, cos of the Gauss-Legendre nodes on [0, pi/2] (numpy's ``leggauss`` solves
    an eigenproblem: 27 ms a call, a quarter of a 2001-node ``_prob_inside``)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    phi = (x + 1.0) * (math.pi / 4.0)
    out = (w * (math.pi / 4.0), np.sin(phi), np.cos(phi))
    for a in out:
        a.flags.writeable = False
    return out


@lru_cache(maxsize=8)
def _ce_table(p: float, n: int = 2001):
    """(q, R_p(q)): the p-quantile of the radial error of an ellipse of semi-axes 1 and q.

    Each R solves ``_prob_inside(R, q) = p`` by false position with the Anderson-Bjorck
    weighting (superlinear), from the bracket of the two closed forms, until the bracket is
    within 4e-16 of R (float64's spacing) or the residual is 0: 9-12 evaluations where a
    bisection took 48, the same roots within 5e-15 of R (the table's interpolation error is 1e-7).
    """
    from scipy.special import ndtri

    q = np.linspace(0.0, 1.0, n)
    lo = np.full(n, ndtri(0.5 + p / 2.0)) * (1 - 1e-9)  # q = 0: a normal error along one line
    hi = np.full(n, math.sqrt(-2.0 * math.log1p(-p))) * (1 + 1e-9)  # q = 1: Rayleigh
    f_lo, f_hi = _prob_inside(lo, q) - p, _prob_inside(hi, q) - p  # < 0 and > 0
    x = 0.5 * (lo + hi)
    kept = np.zeros(n)  # the end the last step kept: +1 lo, -1 hi
    todo = np.arange(n)
    for _ in range(64):  # bounded; 12 or fewer steps are taken
        a, b, fa, fb = lo[todo], hi[todo], f_lo[todo], f_hi[todo]
        xt = np.clip((a * fb - b * fa) / (fb - fa), a, b)
        ft = _prob_inside(xt, q[todo]) - p
        x[todo] = xt
        up = ft > 0  # the root is below xt: xt becomes hi
        # the end kept a second time in a row is weighted by m = 1 - f(x)/f(replaced end)
        with np.errstate(divide="ignore", invalid="ignore"):
            m = np.where(up, 1.0 - ft / fb, 1.0 - ft / fa)
        m = np.where(m > 0, m, 0.5)
        again = np.where(up, kept[todo] == 1, kept[todo] == -1)
        lo[todo], f_lo[todo] = np.where(up, a, xt), np.where(up, np.where(again, fa * m, fa), ft)
        hi[todo], f_hi[todo] = np.where(up, xt, b), np.where(up, ft, np.where(again, fb * m, fb))
        kept[todo] = np.where(up, 1, -1)
        todo = todo[(ft != 0) & (hi[todo] - lo[todo] > 4e-16 * hi[todo])]
        if not todo.size:
            break
    return q, x


def ce90(major: ArrayLike, minor: ArrayLike, p: float = 0.9) -> np.ndarray:
    """The exact p-quantile of the horizontal radial error of a 2D normal error (default CE90).

    Parameters
    ----------
    major, minor : array_like
        1-sigma semi-axes of the error ellipse [m] (any order), broadcasting.
    p : float
        Probability (0.9: CE90; 0.5: CEP).

    Returns
    -------
    ndarray
        R with P(|e| <= R) = p for e ~ N(0, diag(major^2, minor^2)). Not the circular
        approximation: R / major goes from 1.6449 (minor = 0, a normal error along one line) to
        2.1460 (a circle, sqrt(-2 ln 0.1)). Computed by quadrature and false position on a table of
        the axis ratio (2001 nodes), linearly interpolated (error < 1e-7 of R; the tests hold it
        to a direct solution and to 4 million normal draws).
    """
    a, b = np.broadcast_arrays(np.asarray(major, float), np.asarray(minor, float))
    big, small = np.maximum(a, b), np.minimum(a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(big > 0, small / big, 0.0)
    qt, rt = _ce_table(float(p))
    return big * np.interp(q, qt, rt)


def ellipse(cov_en: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1-sigma error ellipse of (..., 2, 2) east-north covariances.

    Returns
    -------
    major, minor : ndarray
        Semi-axes [m] (sqrt of the eigenvalues).
    azimuth_deg : ndarray
        Azimuth of the major axis, clockwise from north, in [0, 180).
    """
    cov_en = np.asarray(cov_en, float)
    a, b, c = cov_en[..., 0, 0], cov_en[..., 0, 1], cov_en[..., 1, 1]
    mean, dif = 0.5 * (a + c), np.hypot(0.5 * (a - c), b)
    major = np.sqrt(np.maximum(mean + dif, 0.0))
    minor = np.sqrt(np.maximum(mean - dif, 0.0))
    theta = 0.5 * np.arctan2(2.0 * b, a - c)  # from east, counter-clockwise
    az = np.mod(90.0 - np.degrees(theta), 180.0)
    return major, minor, az


# --------------------------------------------------------------------- the result
@dataclass
class PointUncertainty:
    """Predicted uncertainty of a batch of located points (every array over the batch's shape).

    Attributes
    ----------
    lat, lon, h : ndarray
        The located points [rad, rad, m ellipsoidal]; NaN where the status is not OK.
    status : ndarray of uint8
    cov_enu : ndarray (..., 3, 3)
        Covariance of the point's error in east, north, up at the hit [m^2].
    jacobian_enu : ndarray (..., 3, k) or None
        d(east, north, up) / d(source), per the source's 1 sigma [m]: cov = J J^T; None where
        :func:`propagate` was asked for none (``jacobian=False``).
    sources : tuple of str
        The budget keys of the Jacobian's columns.
    ellipse_major_m, ellipse_minor_m : ndarray
        1-sigma semi-axes of the horizontal error ellipse (the 90 % ellipse is 2.1460 times it).
    ellipse_azimuth_deg : ndarray
        Azimuth of the major axis, clockwise from north, [0, 180).
    ce90_m, le90_m : ndarray
        Exact CE90 of the ellipse (:func:`ce90`); LE90 = 1.6449 sigma_up.
    terrain_rms_m : ndarray or None
        On a DEM: the terrain's RMS departure [m] from the plane fitted over the point's
        footprint (:func:`surface_normal`). Where it is a sizeable part of ``sigma_up`` the
        terrain is not a plane where the errors put the point, and the first order is only a
        guide (:attr:`linear`); zero on a constant height.
    """

    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    status: np.ndarray
    cov_enu: np.ndarray
    jacobian_enu: np.ndarray | None
    sources: tuple
    ellipse_major_m: np.ndarray
    ellipse_minor_m: np.ndarray
    ellipse_azimuth_deg: np.ndarray
    ce90_m: np.ndarray
    le90_m: np.ndarray
    terrain_rms_m: np.ndarray | None = None
    surface_sigma_m: float = 0.0
    #: On a DEM: True where the ray passes within 2 sigma of the terrain away from its hit (a ridge
    #: the errors may make it hit or clear: the point would jump; ``_grazing``).
    grazing: np.ndarray | None = None

    #: The first order is flagged as only a guide on a DEM where the terrain departs from its
    #: footprint's plane by more than this fraction of the DEM's vertical sigma (RMS).
    NONLINEAR_TERRAIN = 0.1

    @property
    def linear(self) -> np.ndarray:
        """True where the first order holds: a constant height, or a DEM that is a plane over the
        footprint to within ``NONLINEAR_TERRAIN`` of its vertical sigma (the grid of
        ``tests/analysis/test_uncertainty.py``: every point under it within 5 % of Monte Carlo; the
        two over it, 0.16 of sigma, 7 % off: hills the errors carry the point onto)."""
        if self.terrain_rms_m is None:
            return np.ones(np.shape(self.ce90_m), bool)
        ref = self.surface_sigma_m if self.surface_sigma_m > 0 else np.sqrt(self.cov_enu[..., 2, 2])
        rough = self.terrain_rms_m > self.NONLINEAR_TERRAIN * ref
        return ~rough & ~(self.grazing if self.grazing is not None else False)

    @property
    def sigma_up_m(self) -> np.ndarray:
        return np.sqrt(self.cov_enu[..., 2, 2])

    def columns(self) -> dict:
        """The replay CSV's columns: ``ce90_m le90_m ellipse_major_m ellipse_minor_m ellipse_azimuth_deg``."""
        return {
            "ce90_m": self.ce90_m,
            "le90_m": self.le90_m,
            "ellipse_major_m": self.ellipse_major_m,
            "ellipse_minor_m": self.ellipse_minor_m,
            "ellipse_azimuth_deg": self.ellipse_azimuth_deg,
        }


def summarise(
    cov_enu: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    h: np.ndarray,
    status: ArrayLike,
    jac: np.ndarray | None,
    sources: Iterable[str],
) -> PointUncertainty:
    """A :class:`PointUncertainty` from covariances (NaN where the status is not OK)."""
    bad = np.asarray(status) != Status.OK
    cov = np.where(bad[..., None, None], np.nan, cov_enu)
    major, minor, az = ellipse(cov[..., :2, :2])
    return PointUncertainty(
        lat,
        lon,
        h,
        np.asarray(status, np.uint8),
        cov,
        jac,
        tuple(sources),
        major,
        minor,
        az,
        ce90(major, minor),
        LE90_PER_SIGMA * np.sqrt(cov[..., 2, 2]),
    )


# --------------------------------------------------------------------- the Jacobian
def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frames(s, pose, shape):
    """R_ecef_<frame> (n, 3, 3) for every frame on the path to the camera, and the body."""
    n = int(np.prod(shape))
    out = {}
    R = np.eye(3)
    for j in s.graph.path("cam"):
        R = R @ np.swapaxes(j.R_child_parent(pose), -1, -2)
        out[j.child] = np.broadcast_to(R, shape + (3, 3)).reshape(n, 3, 3)
    if "body" not in out:
        out["body"] = np.broadcast_to(s.graph.R_ecef("body", pose), shape + (3, 3)).reshape(n, 3, 3)
    return out


def _flat(v, shape):
    return np.broadcast_to(np.asarray(v, float), shape).reshape(-1)


def _xyz_axes(angles):
    """Axes (in the parent frame) of the three angles of ``rx(x) ry(y) rz(z)``, child = R parent.

    ``v_parent = rz(z)^T ry(y)^T rx(x)^T v_child``: z turns about the parent's z, y about
    ``rz(z)^T e_y``, x about ``rz(z)^T ry(y)^T e_x``.
    """
    x, y, z = angles
    Rz, Ry = rot.rz(z), rot.ry(y)
    return {"x": Rz.T @ Ry.T @ np.array([1.0, 0, 0]), "y": Rz.T @ np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}


def chain_derivatives(
    sensor: Any,
    pose: Pose,
    row: ArrayLike | None,
    col: ArrayLike | None,
    budget: ErrorBudget,
    velocity_ned_m_s: ArrayLike | None = None,
) -> tuple[list[str], np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray], tuple[int, ...]]:
    """d(origin), d(direction) of each ray per 1 sigma of each budget source (ECEF, flat batch).

    Returns
    -------
    sources : list of str
    dO, dD : ndarray (n, 3, k)
        Origin [m] and unit-direction change per the source's 1 sigma.
    (O, D) : ndarray (n, 3)
        The rays' origins and unit directions from the chain (the reference for ``dD``).
    shape : tuple
        The batch's shape.
    """
    s = sensor  # a Sensor (propagate, monte_carlo and triangulate take a Python Camera too)
    r0, c0 = s.center_pixel
    row = r0 if row is None else row
    col = c0 if col is None else col
    shape = np.broadcast_shapes(pose.shape, np.shape(row), np.shape(col))
    n = int(np.prod(shape))
    Rs = _frames(s, pose, shape)
    u = _flat(col, shape) - 1.0
    v = _flat(row, shape) - 1.0
    d_cam = _unit(s.lens.unproject(u, v))
    R_cam = Rs["cam"]
    D = np.einsum("nij,nj->ni", R_cam, d_cam)
    lat, lon, h = (_flat(getattr(pose, k), shape) for k in ("lat", "lon", "h"))
    lever = np.einsum("nij,j->ni", Rs["body"], np.array(s.lever_arm_m))

    O = geodetic_to_ecef(lat, lon, h) + lever
    cols, names = [], []

    def add(name, dO, dD, sigma):
        names.append(name)
        cols.append((np.broadcast_to(dO, (n, 3)) * sigma, np.broadcast_to(dD, (n, 3)) * sigma))

    zero = np.zeros((n, 3))
    attitude_turns_los = "body" in [j.child for j in s.graph.path("cam")]  # not an earth-referenced gimbal
    # platform position: the origin moves, the local frame turns
    Rn = R_ecef_ned(lat, lon)
    e_n, e_e, e_u = Rn[..., 0], Rn[..., 1], -Rn[..., 2]
    w_n = -e_e / (meridian_radius(lat) + h)[:, None]
    w_e = np.array([0.0, 0.0, 1.0]) / ((prime_vertical_radius(lat) + h) * np.cos(lat))[:, None]
    pos = {
        "north_m": (e_n + np.cross(w_n, lever), np.cross(w_n, D)),
        "east_m": (e_e + np.cross(w_e, lever), np.cross(w_e, D)),
        "up_m": (e_u, zero),
    }
    for k, (dO, dD) in pos.items():
        if budget.sigma(k) > 0:
            add(k, dO, dD, budget.sigma(k))
    dt = budget.sigma("time_s")
    if dt > 0:
        if velocity_ned_m_s is None:
            raise ValueError(
                f"{budget.source}: [uncertainty] time_s = {dt:g} needs the platform's velocity "
                "(velocity_ned_m_s, north-east-down metres per second)"
            )
        vel = np.broadcast_to(np.asarray(velocity_ned_m_s, float), shape + (3,)).reshape(n, 3)
        dO = sum(vel[:, [i]] * pos[k][0] for i, k in ((0, "north_m"), (1, "east_m"))) - vel[:, [2]] * e_u
        dD = sum(vel[:, [i]] * pos[k][1] for i, k in ((0, "north_m"), (1, "east_m")))
        add("time_s", dO, dD, dt)
    # attitude: z-y-x from NED; the lever arm turns with the body
    heading = _flat(pose.heading, shape)
    axes = {
        "heading_deg": Rn[..., 2],
        "pitch_deg": np.einsum("nij,nj->ni", Rn, np.stack([-np.sin(heading), np.cos(heading), 0 * heading], -1)),
        "roll_deg": Rs["body"][..., 0],
    }
    for k, a in axes.items():
        if budget.sigma(k) > 0:
            add(k, np.cross(a, lever), np.cross(a, D) if attitude_turns_los else zero, budget.sigma(k) * DEG)
    # gimbal joints: each turns about its axis (the same in its parent and its own frame)
    last = None
    for j in s.graph.path("cam"):
        if j.kind == "revolute":
            last = j.child
            k = f"{j.angle}_deg"
            if budget.sigma(k) > 0:
                a = Rs[j.child][..., _AXES[j.axis]]
                add(k, zero, np.cross(a, D), budget.sigma(k) * DEG)
    # mount (in the body), boresight (in the last joint frame)
    for which, frame, angles in (("mount", "body", s.mount), ("boresight", last, s.boresight)):
        ax = _xyz_axes(angles)
        for c in "xyz":
            k = f"{which}_{c}_deg"
            if budget.sigma(k) > 0:
                a = np.einsum("nij,j->ni", Rs[frame], ax[c])
                add(k, zero, np.cross(a, D), budget.sigma(k) * DEG)
    for i, c in enumerate("xyz"):
        k = f"lever_arm_{c}_m"
        if budget.sigma(k) > 0:
            add(k, Rs["body"][..., i], zero, budget.sigma(k))
    # lens: central differences of unproject over one sigma, turned to ECEF
    for k, p in LENS_KEYS.items():
        sig = budget.sigma(k)
        if sig > 0:
            base = s.lens.params[p]
            dp = _unit(s.lens.with_params(**{p: base + sig}).unproject(u, v))
            dm = _unit(s.lens.with_params(**{p: base - sig}).unproject(u, v))
            add(k, zero, np.einsum("nij,nj->ni", R_cam, (dp - dm) / 2.0), 1.0)
    if cols:
        dO = np.stack([c[0] for c in cols], -1)
        dD = np.stack([c[1] for c in cols], -1)
    else:
        dO = dD = np.zeros((n, 3, 0))
    return names, dO, dD, (O, D), shape


def _dem_height(dem, lat, lon, h, de, dn):
    """The DEM at offsets (east, north) [m] from (lat, lon) (broadcasting)."""
    dlat = dn / (meridian_radius(lat) + h)
    dlon = de / ((prime_vertical_radius(lat) + h) * np.cos(lat))
    return dem.height(lat + dlat, lon + dlon)


#: Gauss-Hermite nodes and weights (probabilists', 5 per axis) of the footprint's slope fit.
_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(5)


def surface_normal(
    surface: Any,
    lat: np.ndarray,
    lon: np.ndarray,
    h: np.ndarray,
    cov_en: ArrayLike | None = None,
    residual: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The surface's linearised normal ``m = u - g_e e - g_n n`` (ECEF, flat) at hits.

    ``g`` is the DEM's slope (dh/d east, dh/d north); zero on a constant-height surface.
    Without ``cov_en`` it is the slope of the DEM's bilinear surface at the hit (central
    differences over +-1 m). With ``cov_en`` (..., 2, 2), the hit's predicted horizontal
    covariance, it is the slope of the plane fitted to the DEM over that footprint, weighted
    by the normal distribution (5 x 5 Gauss-Hermite nodes): the statistical linearisation,
    the plane that best stands for the terrain where the errors put the point (``g = C^-1
    E[delta h(delta)]`` for delta ~ N(0, C), by Stein's lemma).
    """
    Re = R_ecef_enu(lat, lon)
    e, nn, u = Re[..., 0], Re[..., 1], Re[..., 2]
    dem = terrain_of(surface)
    if dem is None:
        return (u, np.zeros(len(u))) if residual else u
    if cov_en is None:
        g_n = (_dem_height(dem, lat, lon, h, 0.0, 1.0) - _dem_height(dem, lat, lon, h, 0.0, -1.0)) / 2.0
        g_e = (_dem_height(dem, lat, lon, h, 1.0, 0.0) - _dem_height(dem, lat, lon, h, -1.0, 0.0)) / 2.0
    else:
        C = np.asarray(cov_en, float) + np.eye(2) * 1e-6  # a point footprint stays positive definite
        L = np.linalg.cholesky(C)  # (n, 2, 2)
        z1, z2 = np.meshgrid(_GH_X, _GH_X, indexing="ij")
        w = np.outer(_GH_W, _GH_W).ravel() / (2.0 * math.pi)
        z = np.stack([z1.ravel(), z2.ravel()], -1)  # (25, 2)
        delta = np.einsum("nij,kj->nki", L, z)  # (n, 25, 2) east, north [m]
        H = _dem_height(dem, lat[:, None], lon[:, None], h[:, None], delta[..., 0], delta[..., 1])
        ok = np.isfinite(H)
        H0 = np.nansum(np.where(ok, H, 0.0) * w, -1) / np.maximum(np.sum(ok * w, -1), 1e-300)
        Eh = np.einsum("nk,ki->ni", np.where(ok, H - H0[:, None], 0.0) * w, z)  # E[z (h - h0)]
        g = np.einsum("nji,nj->ni", np.linalg.inv(L), Eh)  # C^-1 E[delta h] = L^-T E[z h]
        g_e, g_n = g[:, 0], g[:, 1]
        if residual:  # the terrain's RMS departure from the plane over the footprint
            plane = H0[:, None] + np.einsum("nki,ni->nk", delta, g)
            rms = np.sqrt(np.sum(np.where(ok, (H - plane) ** 2, 0.0) * w, -1) / np.maximum(np.sum(ok * w, -1), 1e-300))
    g_n, g_e = np.nan_to_num(g_n), np.nan_to_num(g_e)  # at the DEM's edge: level
    m = u - g_e[:, None] * e - g_n[:, None] * nn
    if residual:
        return m, (rms if cov_en is not None else np.zeros(len(m)))
    return m


#: Ranges (fractions of the hit's) where :func:`_grazing` looks for terrain close to the ray.
_GRAZE_R = np.linspace(0.5, 1.5, 65)


def _grazing(dem, lat, lon, h, D_enu, t, sig_t, free_up, sigma_dem):
    """True where the ray passes within 2 sigma of the terrain away from its hit (a ridge it may hit
    or clear when the errors move it: the hit would jump, which no first order describes).

    Along the ray from half to one and a half times the hit's range, outside 3 sigma of the hit's
    own range, the ray's clearance over the DEM (ENU at the hit, the Earth's curvature taken into
    account) is compared with the clearance's sigma there: the ray's vertical sigma (the chain's
    sources) and the DEM's own vertical error, which lifts the ridge too.
    """
    k = _GRAZE_R[None, :] * t[:, None]  # (n, 65) ranges
    dr = k - t[:, None]
    e, nn, up = (dr * D_enu[:, [i]] for i in range(3))
    R = meridian_radius(lat)[:, None] + h[:, None]
    ray_h = h[:, None] + up + (e * e + nn * nn) / (2.0 * R)  # the ray's height above the ellipsoid (approx.)
    ground = _dem_height(dem, lat[:, None], lon[:, None], h[:, None], e, nn)
    # the ray's vertical sigma at range r: |u.(dO + r dD)| per source, linear in r between O and the hit
    sig_v = np.sqrt(np.sum(free_up**2, -1)[:, None] * (k / t[:, None]) ** 2 + sigma_dem**2)
    near = np.abs(dr) <= 3.0 * sig_t[:, None]
    close = np.isfinite(ground) & ~near & (np.abs(ray_h - ground) < 2.0 * sig_v)
    return np.any(close, -1)


def surface_sigma_m(surface: Any, budget: ErrorBudget) -> float:
    """The budget's vertical sigma for this surface: ``dem_m`` (or its default) on a DEM, else ``height_m``."""
    dem = terrain_of(surface)
    if dem is not None:
        return budget.dem_sigma_m(dem)
    return budget.sigma("height_m")


def propagate(
    sensor: Any,
    pose: Pose,
    row: ArrayLike | None = None,
    col: ArrayLike | None = None,
    budget: ErrorBudget | None = None,
    *,
    surface: Any = None,
    target_h: ArrayLike | None = None,
    dem: Any = None,
    velocity_ned_m_s: ArrayLike | None = None,
    outside: str = "flag",
    dem_method: str = "exact",
    dem_slope: str = "footprint",
    footprint_iterations: int = 3,
    engine: str = "auto",
    corrections: Corrections = NO_CORRECTIONS,
    jacobian: bool = False,
) -> PointUncertainty:
    """Locate a batch of pixels and predict each point's uncertainty (first order).

    Parameters
    ----------
    sensor : FrameSensor or Camera
    pose : Pose
        Platform states (any batch shape, broadcasting with ``row``, ``col``).
    row, col : array_like, optional
        1-based pixels; default the image centre.
    budget : ErrorBudget
        1-sigma errors (the sensor file's ``[uncertainty]``).
    surface : Surface, optional
        A :class:`HeightSurface` or a :class:`DemSurface`; else built by
        :func:`geoloc.surfaces.terrain.surface_for` from ``target_h`` / ``dem``.
    velocity_ned_m_s : array_like (..., 3), optional
        Platform velocity (north, east, down), needed when the budget has ``time_s``.
    outside : {"flag", "extrapolate"}
        As :meth:`FrameSensor.line_of_sight`.
    dem_slope : {"footprint", "point"}
        On a DEM: the slope of the plane fitted to the terrain over the point's predicted
        footprint (default; :func:`surface_normal`, iterated ``footprint_iterations`` times
        from the slope at the hit), or the slope at the hit itself (the strict first order,
        which holds only where the terrain is a plane over the footprint).
    engine : {"auto", "numba", "numpy"}
        ``"numba"``: the compiled kernels of :mod:`geoloc.analysis._fastuncert` (the chain's
        Jacobian per ray, the surface step, the ellipse and CE90; ``"auto"`` takes them for
        batches of 10 000 rays or more, as ``locate``, when they serve the sensor: one lens, no
        per-sample perturbation; below that the first call's compile and numba's call overhead
        outweigh them); ``"numpy"``: the reference path (:func:`chain_derivatives`), which the
        tests hold the kernels to.
    corrections : Corrections
        The location pipeline's line-of-sight corrections (:class:`geoloc.pipeline.Corrections`):
        the points are the corrected ones; the derivatives are the straight line's (refraction
        changes a ray's direction by 1e-4 of itself at most, so its Jacobian by as little).
    jacobian : bool
        Also return each point's Jacobian (:attr:`PointUncertainty.jacobian_enu`, 24 (k + 1) bytes a
        point: 53 MB for 100 000 points of 21 sources, written on fresh pages each call). Default
        False: ``jacobian_enu`` is None, the compiled kernels keep each ray's columns in a scratch
        row, and the covariance, ellipse, CE90 and LE90 are the same to the bit (the replay's
        columns, the viewer's ellipses need no more). Ask for it to see which source dominates.

    Returns
    -------
    PointUncertainty
        NaN and the status where a ray has no ground point.
    """
    budget = _checked(budget, dem_slope, engine)
    s = as_sensor(sensor)
    if surface is None:
        from geoloc.surfaces.terrain import surface_for

        surface = surface_for(target_h, dem, method=dem_method)
    row, col = (s.center_pixel[0] if row is None else row), (s.center_pixel[1] if col is None else col)
    job = _Job(s, pose, row, col, surface, budget, corrections, outside, velocity_ned_m_s)
    fast = _fast(job, engine)
    sz = surface_sigma_m(surface, budget)
    out = _compiled_rays(job, sz, dem_slope, footprint_iterations, jacobian) if fast else _numpy_rays(job)
    if isinstance(out, _Rays):  # not the fused kernels' whole result: carry the columns onto the surface
        out = _through_surface(out, surface, sz, dem_slope, footprint_iterations, jacobian)
    return _with_refraction(out, job)


@dataclass
class _Job:
    """What :func:`propagate` locates: the sensor, the poses, the pixels (defaulted), the surface,
    the budget, the location pipeline's corrections, the ``outside`` rule and the velocity."""

    s: Any
    pose: Pose
    row: Any
    col: Any
    surface: Any
    budget: ErrorBudget
    corrections: Corrections
    outside: str
    velocity_ned_m_s: Any


def _checked(budget: ErrorBudget | None, dem_slope: str, engine: str) -> ErrorBudget:
    """The budget, once :func:`propagate`'s options are checked: a bad one refused by name and value."""
    if budget is None:
        raise ValueError("propagate needs an error budget (the sensor file's [uncertainty] table)")
    if dem_slope not in ("footprint", "point"):
        raise ValueError(f"dem_slope = {dem_slope!r}: must be 'footprint' or 'point'")
    if engine not in ("auto", "numba", "numpy"):
        raise ValueError(f"engine = {engine!r}: must be 'auto', 'numba' or 'numpy'")
    return budget


def _fast(job: _Job, engine: str) -> bool:
    """Whether :func:`propagate` takes the compiled kernels: ``engine="numba"``, or ``"auto"`` with a
    compiled sensor and a batch of :data:`COMPILED_MIN_RAYS` rays or more (as ``locate``)."""
    s = job.s
    if engine == "auto" and s.compiled:
        n_rays = int(np.prod(np.broadcast_shapes(job.pose.shape, np.shape(job.row), np.shape(job.col))))
        fast = n_rays >= COMPILED_MIN_RAYS
    else:
        fast = engine == "numba"
    if fast and not s.compiled:
        raise ValueError("engine='numba' needs a sensor with one lens and no per-sample perturbation")
    return fast


@dataclass
class _Rays:
    """Located rays, flat, with the chain's columns: what the surface step of :func:`propagate` needs.

    ``free`` (n, 3, k): each source's 1-sigma shift of the point carried along the old range (ECEF);
    ``D`` (n, 3) the unit directions, ``t`` (n,) the ranges; ``shape`` the batch's shape.
    """

    names: list
    free: np.ndarray
    D: np.ndarray
    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    status: np.ndarray
    shape: tuple


def _flat_hits(hit, shape: tuple):
    """The hits' status, latitude, longitude, height (contiguous) and ECEF points, flat over ``shape``."""
    status = np.broadcast_to(hit.status, shape).reshape(-1)
    lat, lon, h = (
        np.ascontiguousarray(np.broadcast_to(getattr(hit, k), shape).reshape(-1)) for k in ("lat", "lon", "h")
    )
    P = np.broadcast_to(hit.ecef, shape + (3,)).reshape(-1, 3)
    return status, lat, lon, h, P


def _compiled_rays(job: _Job, sz: float, dem_slope: str, footprint_iterations: int, jacobian: bool):
    """The compiled path: the points located by the pipeline's compiled executors, then on a
    height surface or a compiled DEM one fused pass per ray (the chain's columns never leave the
    ray's scratch row: the whole :class:`PointUncertainty`), else the chain's columns
    (:func:`_chain_fast`) as :class:`_Rays`."""
    s, pose, budget, v = job.s, job.pose, job.budget, job.velocity_ned_m_s
    hit, shape, O, D = _locate_for(s, pose, job.row, job.col, job.surface, job.outside, job.corrections)
    status, lat, lon, h, P = _flat_hits(hit, shape)
    dem = terrain_of(job.surface)
    if dem is None:
        return _height_fused(s, pose, budget, v, shape, O, D, P, lat, lon, h, status, sz, jacobian)
    if _compiled_dem(dem):
        footprint = dem_slope == "footprint"
        it = footprint_iterations if footprint else 0
        return _dem_fused(s, pose, budget, v, shape, O, D, P, dem, lat, lon, h, status, sz, it, footprint, jacobian)
    t = np.sqrt(np.sum((P - O) ** 2, axis=-1))
    names, free = _chain_fast(s, pose, budget, v, shape, O, D, t)
    return _Rays(names, free, D, t, lat, lon, h, status, shape)


def _numpy_rays(job: _Job) -> _Rays:
    """The reference path: the pipeline's hits and :func:`chain_derivatives`'s columns."""
    s, pose, row, col = job.s, job.pose, job.row, job.col
    hit = Pipeline(s, job.surface, job.corrections).intersect(s.line_of_sight(row, col, pose, outside=job.outside))
    names, dO, dD, (O, D), shape = chain_derivatives(s, pose, row, col, job.budget, job.velocity_ned_m_s)
    status, lat, lon, h, P = _flat_hits(hit, shape)
    t = np.linalg.norm(P - O, axis=-1)
    free = dO + t[:, None, None] * dD  # the point carried along the old range
    return _Rays(names, free, D, t, lat, lon, h, status, shape)


def _through_surface(
    rays: _Rays, surface, sz: float, dem_slope: str, footprint_iterations: int, jacobian: bool
) -> PointUncertainty:
    """The rays' columns carried onto the surface: the ENU Jacobian and covariance
    (:func:`_surface_jacobian`), the terrain's roughness over the footprint and the grazing flags
    on a DEM, summarised per point (:func:`summarise`)."""
    dem = terrain_of(surface)
    on_dem = dem is not None
    names = rays.names + (["dem_m" if on_dem else "height_m"] if sz > 0 else [])
    lat, lon, h = rays.lat, rays.lon, rays.h
    Re = R_ecef_enu(lat, lon)
    footprint = dem_slope == "footprint"
    iterations = footprint_iterations if on_dem and footprint else 0
    m, inv, J, cov, cov_en = _surface_jacobian(surface, rays, Re, sz, iterations, footprint)
    terrain_rms = surface_normal(surface, lat, lon, h, cov_en, residual=True)[1] if on_dem else np.zeros(len(lat))
    grazing = _grazing_of(dem, rays, Re, m, inv, sz) if on_dem else np.zeros(len(lat), bool)
    shape = rays.shape
    r = lambda a, tail=(): a.reshape(shape + tail)  # noqa: E731
    out = summarise(
        r(cov, (3, 3)), r(lat), r(lon), r(h), r(rays.status), r(J, (3, J.shape[-1])) if jacobian else None, names
    )
    out.terrain_rms_m = r(np.where(out.status.reshape(-1) == Status.OK, terrain_rms, np.nan))
    out.surface_sigma_m = float(sz)
    out.grazing = r(grazing & (out.status.reshape(-1) == Status.OK))
    return out


def _surface_jacobian(surface, rays: _Rays, Re, sz: float, iterations: int, footprint: bool):
    """Each point's ENU Jacobian per 1 sigma on the surface: the free point slid along its ray back
    onto the tangent plane of normal ``m`` (plus the surface's own vertical error ``sz``). With
    ``footprint`` the plane is fitted over the predicted footprint, refitted ``iterations`` times
    from the slope at the hit. Returns ``m``, ``inv`` (1 / m.D, NaN where the ray does not enter
    the surface), ``J``, its covariance and that covariance's horizontal block (finite)."""
    free, D = rays.free, rays.D
    cov_en = None
    for _ in range(1 + iterations):
        m = surface_normal(surface, rays.lat, rays.lon, rays.h, cov_en if footprint else None)
        mD = np.einsum("ni,ni->n", m, D)
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(mD < -1e-12, 1.0 / mD, np.nan)  # the ray must enter the surface
        dP = free - D[:, :, None] * (np.einsum("ni,nik->nk", m, free) * inv[:, None])[:, None, :]
        if sz > 0:
            dP = np.concatenate([dP, (D * (sz * inv)[:, None])[:, :, None]], -1)
        J = np.einsum("nji,njk->nik", Re, dP)  # ENU at the hit, per 1 sigma
        cov = J @ np.swapaxes(J, -1, -2)
        cov_en = np.where(np.isfinite(cov[:, :2, :2]), cov[:, :2, :2], 0.0)
    return m, inv, J, cov, cov_en


def _grazing_of(dem, rays: _Rays, Re, m, inv, sz: float) -> np.ndarray:
    """:func:`_grazing`'s flags for the rays: the range's 1-sigma spread along each ray from the
    chain's columns and the DEM's vertical error, the ray and the free point's up shift in ENU."""
    free = rays.free
    dt = -np.einsum("ni,nik->nk", m, free) * inv[:, None]
    sig_t = np.sqrt(np.sum(dt * dt, -1) + (sz * inv) ** 2)
    D_enu = np.einsum("nji,nj->ni", Re, rays.D)
    free_up = np.einsum("nj,njk->nk", Re[..., 2], free)
    return _grazing(dem, rays.lat, rays.lon, rays.h, D_enu, rays.t, sig_t, free_up, sz)


def _with_refraction(out: PointUncertainty, job: _Job) -> PointUncertainty:
    """The budget's ``refraction`` source (a fraction of the standard atmosphere's shift, 1 sigma)
    added to the points' covariance: the shift's vector (ENU at each point) times that fraction,
    one more column of the Jacobian. The shift is the pipeline's own (the point located with and
    without refraction, every other correction as given), so it holds on a DEM too: ``out``'s
    point is one of the two, the other is located here."""
    sig = job.budget.sigma("refraction")
    if not sig > 0:
        return out
    from geoloc.corrections.refraction import STANDARD_REFRACTION

    on = job.corrections.refraction is not None
    other = Pipeline(
        job.s, job.surface, dataclasses.replace(job.corrections, refraction=None if on else STANDARD_REFRACTION)
    ).locate(job.row, job.col, job.pose, outside=job.outside)
    here = geodetic_to_ecef(out.lat, out.lon, out.h)
    v = (here - np.asarray(other.ecef, float)) * (1.0 if on else -1.0)  # bent minus straight
    shape = np.shape(out.status)
    v = np.broadcast_to(v, shape + (3,))
    j = sig * np.einsum("...ji,...j->...i", R_ecef_enu(out.lat, out.lon), v)
    j = np.where(np.isfinite(j), j, 0.0)
    cov = out.cov_enu + j[..., :, None] * j[..., None, :]
    jac = (
        None
        if out.jacobian_enu is None
        else np.concatenate(
            [np.broadcast_to(out.jacobian_enu, shape + np.shape(out.jacobian_enu)[-2:]), j[..., :, None]], axis=-1
        )
    )
    new = summarise(cov, out.lat, out.lon, out.h, out.status, jac, out.sources + ("refraction",))
    new.terrain_rms_m, new.surface_sigma_m, new.grazing = out.terrain_rms_m, out.surface_sigma_m, out.grazing
    return new


# --------------------------------------------------------------------- the compiled engine
def _locate_for(s, pose, row, col, surface, outside, corrections: Corrections = NO_CORRECTIONS):
    """The hits and the rays (flat origins and directions) for the compiled engine: the location
    pipeline's compiled executors (on the inflated constant height the fused locate kernel gives
    both in one pass; elsewhere the compiled line of sight and the surface's own solver)."""
    hit = Pipeline(s, surface, corrections).locate(row, col, pose, outside=outside, engine="numba")
    o, d = np.asarray(hit.los.origin_ecef, float), np.asarray(hit.los.direction_ecef, float)
    shape = np.broadcast_shapes(np.shape(o)[:-1], np.shape(d)[:-1], np.shape(hit.status))
    o, d = np.broadcast_to(o, shape + (3,)), np.broadcast_to(d, shape + (3,))
    return hit, shape, o.reshape(-1, 3), d.reshape(-1, 3)


def _source_codes(s, budget: ErrorBudget):
    """The budget's sources in :func:`chain_derivatives`'s order: names, kernel codes, SI sigmas."""
    from geoloc.analysis import _fastuncert as F

    names, codes, sig = [], [], []

    def add(k, code, scale=1.0):
        if budget.sigma(k) > 0:
            names.append(k)
            codes.append(code)
            sig.append(budget.sigma(k) * scale)

    add("north_m", F.SRC_NORTH)
    add("east_m", F.SRC_EAST)
    add("up_m", F.SRC_UP)
    add("time_s", F.SRC_TIME)
    add("heading_deg", F.SRC_HEADING, DEG)
    add("pitch_deg", F.SRC_PITCH, DEG)
    add("roll_deg", F.SRC_ROLL, DEG)
    for j, joint in enumerate(s.gimbal.joints):
        add(f"{joint.angle}_deg", F.SRC_JOINT + j, DEG)
    for c, axis in enumerate("xyz"):
        add(f"mount_{axis}_deg", F.SRC_MOUNT + c, DEG)
    for c, axis in enumerate("xyz"):
        add(f"boresight_{axis}_deg", F.SRC_BORE + c, DEG)
    for c, axis in enumerate("xyz"):
        add(f"lever_arm_{axis}_m", F.SRC_LEVER + c)
    for k, p in LENS_KEYS.items():
        add(k, F.SRC_LENS + PARAM_LAYOUT.index(p))
    return names, np.array(codes, np.int64), np.array(sig, float)


def _chain_inputs(s, pose, budget, velocity_ned_m_s, shape):
    """The budget's source names and :func:`_fastuncert.chain_kernel`'s arguments: those before the
    rays (the platform and joint angles, flat) and those after them (velocity .. ellipsoid)."""
    from geoloc.sensors._fastlocate import _AXIS

    names, codes, sig = _source_codes(s, budget)
    n = int(np.prod(shape))
    if "time_s" in names and velocity_ned_m_s is None:
        raise ValueError(
            f"{budget.source}: [uncertainty] time_s = {budget.sigma('time_s'):g} needs the platform's "
            "velocity (velocity_ned_m_s, north-east-down metres per second)"
        )
    col = lambda v: np.ascontiguousarray(np.broadcast_to(np.asarray(v, float), shape).reshape(-1))  # noqa: E731
    joints = s.gimbal.joints
    ang = np.empty((n, len(joints)))
    for j, joint in enumerate(joints):
        ang[:, j] = np.broadcast_to(np.asarray(pose.angle(joint.angle), float), shape).reshape(-1)
    vel = (
        np.zeros((1, 3))
        if velocity_ned_m_s is None
        else np.ascontiguousarray(np.broadcast_to(np.asarray(velocity_ned_m_s, float), shape + (3,)).reshape(n, 3))
    )
    mx, bx = _xyz_axes(s.mount), _xyz_axes(s.boresight)
    before = tuple(col(getattr(pose, k)) for k in ("lat", "lon", "h", "heading", "pitch", "roll")) + (ang,)
    after = (
        vel,
        np.array([_AXIS[j.axis] for j in joints], np.int64),
        np.ascontiguousarray(s.R_cam_last),
        np.ascontiguousarray(s.R_base_body),
        np.array(s.lever_arm_m, float),
        bool(s.gimbal.earth_referenced),
        np.array([mx[c] for c in "xyz"]),
        np.array([bx[c] for c in "xyz"]),
        int(s.lens.code),
        np.array(s.lens.as_array(), float),
        codes,
        sig,
        float(A),
        float(E2),
    )
    return names, before, after


def _chain_fast(s, pose, budget, velocity_ned_m_s, shape, O, D, t):
    """:func:`chain_derivatives`'s ``dO + t dD`` (n, 3, k) through :func:`_fastuncert.chain_kernel`."""
    from geoloc.analysis import _fastuncert as F

    names, before, after = _chain_inputs(s, pose, budget, velocity_ned_m_s, shape)
    free = np.empty((int(np.prod(shape)), 3, len(names)))
    F.chain_kernel(*before, np.ascontiguousarray(O), np.ascontiguousarray(D), np.ascontiguousarray(t), *after, free)
    return names, free


def _outputs(n, kk, jacobian: bool = True):
    """The compiled surface step's output arrays: J (n, 3, kk), cov (n, 3, 3) and six (n,) rows;
    without ``jacobian`` J has no rows (the kernels then keep each ray's in a scratch row)."""
    return (np.empty((n if jacobian else 0, 3, kk)), np.empty((n, 3, 3))) + tuple(np.empty(n) for _ in range(6))


def _wrap(lat, lon, h, status, J, cov, names, major, minor, az, ce, le, shape) -> PointUncertainty:
    """A :class:`PointUncertainty` of the compiled engine's flat outputs in the batch's shape."""
    r = lambda a, tail=(): a.reshape(shape + tail)  # noqa: E731
    return PointUncertainty(
        r(lat),
        r(lon),
        r(h),
        r(np.asarray(status, np.uint8)),
        r(cov, (3, 3)),
        r(J, (3, J.shape[-1])) if len(J) == len(cov) else None,
        tuple(names),
        r(major),
        r(minor),
        r(az),
        r(ce),
        r(le),
    )


def _height_fused(s, pose, budget, velocity_ned_m_s, shape, O, D, P, lat, lon, h, status, sz, jacobian=True):
    """The chain and the surface step on a constant height in one pass
    (:func:`_fastuncert.chain_surface_kernel`): what :func:`_chain_fast` then the numpy surface step give on a constant height."""
    from geoloc.analysis import _fastuncert as F

    names, before, after = _chain_inputs(s, pose, budget, velocity_ned_m_s, shape)
    n = int(np.prod(shape))
    if sz > 0:
        names = names + ["height_m"]
    J, cov, major, minor, az, ce, le, _ = _outputs(n, len(names), jacobian)
    qt, rt = _ce_table(0.9)
    st = np.ascontiguousarray(status, dtype=np.uint8)
    C = np.ascontiguousarray
    F.chain_surface_kernel(
        *before,
        C(O),
        C(D),
        C(P),
        *after,
        lat,
        lon,
        st,
        float(sz),
        float(len(qt) - 1),
        rt,
        LE90_PER_SIGMA,
        J,
        cov,
        major,
        minor,
        az,
        ce,
        le,
    )
    out = _wrap(lat, lon, h, st, J, cov, names, major, minor, az, ce, le, shape)
    out.terrain_rms_m = np.where(out.status == Status.OK, 0.0, np.nan)  # a constant height is a plane
    out.surface_sigma_m = float(sz)
    out.grazing = np.zeros(shape, bool)
    return out


def _dem_fused(
    s,
    pose,
    budget,
    velocity_ned_m_s,
    shape,
    O,
    D,
    P,
    dem,
    lat,
    lon,
    h,
    status,
    sz,
    iterations,
    footprint,
    jacobian=True,
):
    """The chain and the surface step on a geographic DEM in one pass
    (:func:`_fastuncert.chain_dem_kernel`): what :func:`_chain_fast` then the numpy surface step give on a DEM."""
    from geoloc.analysis import _fastuncert as F

    names, before, after = _chain_inputs(s, pose, budget, velocity_ned_m_s, shape)
    n = int(np.prod(shape))
    if sz > 0:
        names = names + ["dem_m"]
    J, cov, major, minor, az, ce, le, rms = _outputs(n, len(names), jacobian)
    grazing = np.empty(n, np.bool_)
    qt, rt = _ce_table(0.9)
    st = np.ascontiguousarray(status, dtype=np.uint8)
    g = dem.grid
    C = np.ascontiguousarray
    Z = C(g.values, dtype=float)
    # the grazing test's tile bounds: one pass over the grid, made only where it costs a small
    # part of the rays' own work (a large DEM and a few rays read every sample instead)
    tiles = F.dem_tiles(Z) if Z.size <= 8 * n else np.empty((2, 0, 0))
    F.chain_dem_kernel(
        *before,
        C(O),
        C(D),
        C(P),
        *after,
        lat,
        lon,
        h,
        st,
        float(sz),
        int(iterations),
        bool(footprint),
        Z,
        tiles,
        float(g.lat_north_deg),
        float(g.lon_west_deg),
        float(g.dlat_deg),
        float(g.dlon_deg),
        float(g.margin),
        _GH_X,
        _GH_W,
        _GRAZE_R,
        float(len(qt) - 1),
        rt,
        LE90_PER_SIGMA,
        J,
        cov,
        major,
        minor,
        az,
        ce,
        le,
        rms,
        grazing,
    )
    out = _wrap(lat, lon, h, st, J, cov, names, major, minor, az, ce, le, shape)
    out.terrain_rms_m = rms.reshape(shape)
    out.surface_sigma_m = float(sz)
    out.grazing = grazing.reshape(shape)
    return out


def _compiled_dem(dem) -> bool:
    """True where :func:`_fastuncert.chain_dem_kernel` reads the DEM itself: one geographic grid."""
    from geoloc.surfaces.dem import DEM

    return isinstance(dem, DEM) and dem.is_geographic


# --------------------------------------------------------------------- Monte Carlo of a budget
def draw(budget: ErrorBudget, n: int, rng: np.random.Generator) -> dict:
    """``n`` normal draws of every nonzero source (edge units), in a fixed order (reproducible)."""
    keys = [k for k in sorted(budget.sigmas) if budget.sigma(k) > 0]
    out = {k: rng.standard_normal(n) * budget.sigma(k) for k in keys}
    if "dem_m" not in out and budget.dem_product is not None:
        out["dem_m"] = rng.standard_normal(n) * budget.dem_sigma_m()
    return out


def monte_carlo(
    sensor: Any,
    pose: Pose,
    row: float,
    col: float,
    budget: ErrorBudget,
    surface: Any,
    n: int,
    rng: np.random.Generator,
    velocity_ned_m_s: ArrayLike | None = None,
    draws: dict | None = None,
    corrections: Corrections = NO_CORRECTIONS,
) -> tuple[np.ndarray, np.ndarray]:
    """Monte Carlo of one ray's located point under the budget: the errors (east, north, up) [m].

    Every source is drawn per sample and applied exactly (not linearised): the pose's
    position (metres to degrees at the nominal point), attitude and joint angles; the mount
    and boresight as the rotations of the drawn angles (``FrameSensor``'s per-sample
    ``R_base_extra`` / ``R_bore_extra``), the lever arm; the lens's parameters per sample
    (:func:`geoloc.analysis.montecarlo.perturbed_lens`); the time tag as ``v dt``; a constant
    height's error as the sample's height; a DEM's as the DEM shifted by ``dz`` along the
    hit's vertical (the ray's origin moved by ``-dz u``, the hit moved back).

    Returns
    -------
    enu : ndarray (n, 3)
        Each sample's point minus the error-free point, in ENU at the error-free point [m].
    status : ndarray (n,) of uint8
    """
    from geoloc.analysis.montecarlo import perturbed_lens

    s = as_sensor(sensor)
    x = draws if draws is not None else draw(budget, n, rng)
    g = lambda k: x.get(k, 0.0)  # noqa: E731
    p0 = pose
    lat0, lon0, h0 = (float(np.asarray(getattr(p0, k))) for k in ("lat", "lon", "h"))
    dn, de, du = g("north_m"), g("east_m"), g("up_m")
    if "time_s" in x:
        if velocity_ned_m_s is None:
            raise ValueError("time_s needs velocity_ned_m_s")
        vn, ve, vd = np.asarray(velocity_ned_m_s, float)
        dn, de, du = dn + vn * x["time_s"], de + ve * x["time_s"], du - vd * x["time_s"]
    kw = dict(
        lat=lat0 + dn / (meridian_radius(lat0) + h0),
        lon=lon0 + de / ((prime_vertical_radius(lat0) + h0) * math.cos(lat0)),
        h=h0 + du,
    )
    for f in ("heading", "pitch", "roll"):
        kw[f] = float(np.asarray(getattr(p0, f))) + g(f"{f}_deg") * DEG
    angles = {a: float(np.asarray(p0.angle(a))) + g(f"{a}_deg") * DEG for a in s.angle_names}
    kw = {k: np.broadcast_to(v, (n,)).astype(float) for k, v in kw.items()}
    pose_s = Pose(**kw).with_angles(**{a: np.broadcast_to(v, (n,)).astype(float) for a, v in angles.items()})
    extra = {}
    mnt = [g(f"mount_{c}_deg") * DEG for c in "xyz"]
    if any(np.any(v) for v in mnt):
        m0 = small_rotation(s.mount)
        extra["R_base_extra"] = m0.T @ small_rotation(tuple(b + np.broadcast_to(d, (n,)) for b, d in zip(s.mount, mnt)))
    bst = [g(f"boresight_{c}_deg") * DEG for c in "xyz"]
    if any(np.any(v) for v in bst):
        b0 = small_rotation(s.boresight)
        extra["R_bore_extra"] = (
            small_rotation(tuple(b + np.broadcast_to(d, (n,)) for b, d in zip(s.boresight, bst))) @ b0.T
        )
    lev = [g(f"lever_arm_{c}_m") for c in "xyz"]
    if any(np.any(v) for v in lev):
        extra["lever_extra_m"] = np.stack([np.broadcast_to(v, (n,)) for v in lev], -1)
    lens = perturbed_lens(s.lens, {k: v for k, v in x.items() if k in LENS_KEYS})
    sp = dataclasses.replace(s, lens=lens, **extra)
    rr, cc = np.broadcast_to(float(row), (n,)), np.broadcast_to(float(col), (n,))
    los = sp.line_of_sight(rr, cc, pose_s, outside="extrapolate", engine="numpy")
    nominal = Pipeline(s, surface, corrections).intersect(
        s.line_of_sight(float(row), float(col), p0, outside="extrapolate", engine="numpy")
    )
    la, lo, hh = (float(np.asarray(getattr(nominal, k)).reshape(())) for k in ("lat", "lon", "h"))
    if terrain_of(surface) is None:
        hz = surface.h + g("height_m")
        hit = Pipeline(sp, HeightSurface(np.broadcast_to(hz, (n,)), surface.kind), corrections).intersect(los)
        P = hit.ecef
    else:
        dz = np.broadcast_to(g("dem_m"), (n,))
        up = R_ecef_enu(la, lo)[..., 2]
        shifted = LineOfSight(los.origin_ecef - dz[:, None] * up, los.direction_ecef, los.status)
        hit = Pipeline(sp, surface, corrections).intersect(shifted)
        P = hit.ecef + dz[:, None] * up
    enu = ecef_to_enu(P, la, lo, hh)
    return np.where((hit.status == Status.OK)[:, None], enu, np.nan), np.asarray(hit.status, np.uint8)


def empirical_ce90_le90(enu: ArrayLike, status: ArrayLike | None = None) -> tuple[float, float]:
    """CE90 and LE90 of a sample of errors (ENU, metres): the 0.9 quantiles of the horizontal
    distance and of |up| (numpy's linear percentile, as :mod:`geoloc.analysis.accuracy`)."""
    enu = np.asarray(enu, float)
    ok = np.all(np.isfinite(enu), axis=-1) if status is None else (np.asarray(status) == Status.OK)
    e = enu[ok]
    return float(np.percentile(np.hypot(e[:, 0], e[:, 1]), 90)), float(np.percentile(np.abs(e[:, 2]), 90))


# --------------------------------------------------------------------- [Q17]'s error model as a budget
def budget_from_error_model(model: ErrorModel) -> ErrorBudget:
    """The budget of a Monte Carlo error model (:class:`geoloc.analysis.errormodel.ErrorModel`).

    Standard deviations carry over (a uniform error's is max / sqrt(3)); biases are left out.
    Latitude and longitude errors become metres north and east at the nominal point; the
    image-centre error (micrometres on the CCD, x along rows) becomes the principal point's
    ``cy_px`` / ``cx_px``; the shock-absorber vibration (yaw, pitch, roll) is the mount's z, y, x
    (exact for a camera without a mount, which [Q17]'s has not); the collimation error is the
    boresight's x (a turn about the camera frame's X); the gimbal non-orthogonality (a turn
    about the outer gimbal's Z, written in the inner frame: ``(-sin p, 0, cos p)`` for inner angle p)
    is split onto the boresight's z and x, their correlation left out (at p = -2.6 deg it is
    sin^2 p = 0.2 % of that term's variance); the target height's error is ``height_m``.
    """
    from geoloc.analysis.errormodel import LENS_SOURCES

    std = {k: d.std for k, d in model.errors.items()}
    nom = model.nominal
    lat = math.radians(nom["lat_deg"])
    out: dict = {}

    def acc(k, s):
        out[k] = math.hypot(out.get(k, 0.0), s)

    for k, s in std.items():
        if k == "lat_deg":
            acc("north_m", s * DEG * (meridian_radius(lat) + nom["h_m"]))
        elif k == "lon_deg":
            acc("east_m", s * DEG * (prime_vertical_radius(lat) + nom["h_m"]) * math.cos(lat))
        elif k == "h_m":
            acc("up_m", s)
        elif k in ("heading_deg", "pitch_deg", "roll_deg", "gimbal_roll_deg", "gimbal_pitch_deg"):
            acc(k, s)
        elif k == "image_centre_x_um":
            acc("cy_px", s * 1e-6 / model.camera.pixel_pitch_m)
        elif k == "image_centre_y_um":
            acc("cx_px", s * 1e-6 / model.camera.pixel_pitch_m)
        elif k.startswith("vibration_"):
            acc({"yaw": "mount_z_deg", "pitch": "mount_y_deg", "roll": "mount_x_deg"}[k.split("_")[1]], s)
        elif k == "collimation_deg":
            acc("boresight_x_deg", s)
        elif k == "gimbal_nonorthogonality_deg":
            p = math.radians(nom["gimbal_pitch_deg"])
            acc("boresight_z_deg", s * abs(math.cos(p)))
            acc("boresight_x_deg", s * abs(math.sin(p)))
        elif k == "target_h_m":
            acc("height_m", s)
        elif k in LENS_SOURCES and k != "focal_length_px":
            acc(k, s)
        elif k.startswith(("mount_", "boresight_", "lever_arm_")):
            acc(k, s)
        else:
            raise ValueError(
                f"{model.source} [errors] {k}: no budget key for it (focal_length_px draws fx and fy "
                "together: give fx_px and fy_px)"
            )
    return ErrorBudget(out, None, model.source)


# --------------------------------------------------------------------- the budget judged by the data
#: The Mahalanobis radius of the 90 % (99 %) ellipse: sqrt of the chi-square (2 dof) quantile.
ELLIPSE99_PER_SIGMA = math.sqrt(-2.0 * math.log(0.01))


def normalised_errors(
    east_m: ArrayLike, north_m: ArrayLike, major_m: ArrayLike, minor_m: ArrayLike, azimuth_deg: ArrayLike
) -> np.ndarray:
    """Each horizontal error's Mahalanobis distance in its own predicted ellipse (1-sigma units).

    With the error's components along the major axis (azimuth clockwise from north) and the minor,
    ``d^2 = (a / major)^2 + (b / minor)^2``: chi-square with 2 degrees of freedom when the budget
    is right, so ``d <= 2.1460`` (:data:`ELLIPSE90_PER_SIGMA`) for 90 % of the points.
    """
    az = np.radians(np.asarray(azimuth_deg, float))
    e, n = np.asarray(east_m, float), np.asarray(north_m, float)
    along = e * np.sin(az) + n * np.cos(az)
    across = e * np.cos(az) - n * np.sin(az)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(
            (along / np.asarray(major_m, float)) ** 2
            + (across / np.maximum(minor_m, 1e-9 * np.asarray(major_m, float))) ** 2
        )


def outside_ellipse(
    east_m: ArrayLike,
    north_m: ArrayLike,
    major_m: ArrayLike,
    minor_m: ArrayLike,
    azimuth_deg: ArrayLike,
    p: float = 0.99,
) -> np.ndarray:
    """True where the horizontal error lies outside its own predicted ``p`` ellipse (default 99 %)."""
    return normalised_errors(east_m, north_m, major_m, minor_m, azimuth_deg) > math.sqrt(-2.0 * math.log1p(-p))


def budget_check(
    east_m: ArrayLike,
    north_m: ArrayLike,
    major_m: ArrayLike,
    minor_m: ArrayLike,
    azimuth_deg: ArrayLike,
    up_m: ArrayLike | None = None,
    le90_m: ArrayLike | None = None,
    confidence: float = 0.99,
) -> dict:
    """Judge a budget by its data: the share of truths inside their own predicted 90 % ellipse.

    Parameters
    ----------
    east_m, north_m : array_like
        Each point's horizontal error (computed minus truth) [m].
    major_m, minor_m, azimuth_deg : array_like
        Its predicted 1-sigma ellipse (:class:`PointUncertainty`, the replay CSV's columns).
    up_m, le90_m : array_like, optional
        Vertical error and predicted LE90 [m]: the same check on the vertical.
    confidence : float
        The binomial interval around 90 % that counts as "holds" (default 99 %: a right budget
        is called wrong once in a hundred flights).

    Returns
    -------
    dict
        ``n``, ``inside_90`` (share), ``interval`` (the binomial ``confidence`` interval of the
        share for n points if the budget is right), ``normalised`` (per point: d / 2.1460, the
        error over its 90 % ellipse's radius in its direction; 1 = on the ellipse), ``factor``
        (the scale that would put 90 % inside: the 90th percentile of d over 2.1460; > 1: the
        errors are larger than predicted), ``verdict`` (``holds``, ``optimistic`` or
        ``pessimistic``) and ``text``; with the vertical, ``vertical`` with the same keys for |up|
        over LE90.
    """
    from scipy.stats import binom

    d = normalised_errors(east_m, north_m, major_m, minor_m, azimuth_deg) / ELLIPSE90_PER_SIGMA
    out = _judge(d, confidence, "horizontal errors inside their predicted 90 % ellipse", binom)
    if up_m is not None and le90_m is not None:
        v = np.abs(np.asarray(up_m, float)) / np.asarray(le90_m, float)
        out["vertical"] = _judge(v, confidence, "vertical errors inside their predicted LE90", binom)
    return out


def _judge(r, confidence, what, binom) -> dict:
    r = np.asarray(r, float)
    ok = np.isfinite(r)
    n = int(ok.sum())
    if n == 0:
        return {
            "n": 0,
            "inside_90": math.nan,
            "interval": [math.nan, math.nan],
            "normalised": r,
            "factor": math.nan,
            "verdict": "no data",
            "text": f"budget check: no {what.split(' inside')[0]} with a predicted uncertainty",
        }
    share = float(np.mean(r[ok] <= 1.0))
    lo, hi = (float(x) / n for x in binom.interval(confidence, n, 0.9))
    factor = float(np.percentile(r[ok], 90))
    if share < lo:
        verdict, how = "optimistic", f"too optimistic: the errors are {factor:.2f}x the predicted"
    elif share > hi:
        verdict, how = (
            "pessimistic",
            f"too pessimistic: the errors are {factor:.2f}x the predicted ({1 / factor:.2f}x smaller)",
        )
    else:
        verdict, how = "holds", f"holds (errors {factor:.2f}x the predicted)"
    text = (
        f"budget {how}: {share:.1%} of {n} {what} (a right budget: {lo:.1%}-{hi:.1%}, "
        f"{confidence:.0%} binomial interval)"
    )
    return {
        "n": n,
        "inside_90": share,
        "interval": [lo, hi],
        "normalised": r,
        "factor": factor,
        "verdict": verdict,
        "text": text,
    }
