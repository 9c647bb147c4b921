"""Targets seen from many frames: the least-squares intersection of their rays, without a DEM.

A target seen in several frames has one line of sight per frame. The point closest to all of
them (each ray's miss measured perpendicular to it) needs no surface, so it exposes what the
surface gets wrong: compared with each frame's hit on the DEM, a consistent height difference is
what a DEM or datum error looks like.

The intersection (the classic midpoint / least-squares form, e.g. Hartley and Zisserman,
*Multiple View Geometry*, 2nd ed., section 12.2's linear triangulation in its metric version)::

    X = (sum_i W_i)^-1 sum_i W_i O_i,     W_i = B_i C_i^-1 B_i^T

with ``B_i`` two unit vectors perpendicular to ray ``i`` and ``C_i`` the 2x2 covariance of the
ray's miss at the target (its budget, :func:`geoloc.analysis.uncertainty.chain_derivatives`
carried to the range: ``dO + t dD``, projected on the plane across the ray); without a budget
``C_i = I`` (the plain perpendicular least squares). Each ray's residual is its perpendicular
distance from ``X``.

Covariance, first order: a source moving ray ``i`` by ``f_i`` at the target moves ``X`` by
``(sum W)^-1 sum_i W_i f_i``. A source independent from frame to frame (position, attitude,
joints, time: noise) gives one column per frame; a source shared by every frame (the sensor's
own mount, boresight, lever arm and lens: biases, ``SHARED``) one column summed over the frames,
so that averaging many frames does not shrink it. ``tests/analysis/test_triangulate.py`` holds the
predicted CE90 / LE90 to Monte Carlo of the whole chain for a target seen from 3 to 30 frames of
an orbit.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from geoloc.analysis.uncertainty import ce90, chain_derivatives, ellipse
from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.frames.chain import Pose
from geoloc.geodesy.local import R_ecef_enu
from geoloc.sensors.budget import LE90_PER_SIGMA, LENS_KEYS, SENSOR_KEYS, ErrorBudget
from geoloc.status import Status
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline

#: Budget keys shared by every frame of one sensor (biases): the mount, boresight, lever arm and lens.
SHARED = frozenset(SENSOR_KEYS) | frozenset(LENS_KEYS)

#: A mean DEM-minus-triangulated height beyond this many standard errors, and beyond
#: :data:`DEM_OFFSET_MIN_M`, is reported as a likely DEM or datum error.
DEM_OFFSET_SE = 3.0
DEM_OFFSET_MIN_M = 5.0


@dataclass
class Triangulation:
    """One target located from the intersection of its rays.

    Attributes
    ----------
    ecef : ndarray (3,)
    lat, lon, h : float
        The point [rad, rad, m ellipsoidal WGS 84].
    n_rays : int
    residual_m : ndarray (n,)
        Each ray's perpendicular distance from the point [m] (NaN for a ray left out).
    cov_enu : ndarray (3, 3) or None
        First-order covariance of the point in ENU at it [m^2] (with a budget).
    ellipse_major_m, ellipse_minor_m, ellipse_azimuth_deg, ce90_m, le90_m : float
        Its 1-sigma horizontal ellipse, exact CE90 and LE90 (NaN without a budget).
    status : int
        OK, or INVALID_INPUT for fewer than two usable rays or rays that are all parallel.
    """

    ecef: np.ndarray
    lat: float
    lon: float
    h: float
    n_rays: int
    residual_m: np.ndarray
    cov_enu: np.ndarray | None = None
    ellipse_major_m: float = math.nan
    ellipse_minor_m: float = math.nan
    ellipse_azimuth_deg: float = math.nan
    ce90_m: float = math.nan
    le90_m: float = math.nan
    status: int = int(Status.OK)

    @property
    def lat_deg(self) -> float:
        return math.degrees(self.lat)

    @property
    def lon_deg(self) -> float:
        return math.degrees(self.lon)


def _across(D):
    """Two unit vectors (n, 3, 2) perpendicular to each unit direction D (n, 3)."""
    ref = np.where(np.abs(D[:, [2]]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    b1 = np.cross(D, ref)
    b1 /= np.linalg.norm(b1, axis=-1, keepdims=True)
    b2 = np.cross(D, b1)
    return np.stack([b1, b2], -1)


def intersect_rays(
    origins: ArrayLike, directions: ArrayLike, cov_across: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The weighted least-squares intersection of rays (ECEF): ``(X, residuals, W, B)``.

    Parameters
    ----------
    origins, directions : array_like (n, 3)
        Ray origins [m] and directions (any length).
    cov_across : array_like (n, 2, 2), optional
        Covariance of each ray's miss in the plane across it (the basis ``B`` this function
        returns); default the identity (every ray weighted alike).

    Returns
    -------
    X : ndarray (3,)
    residuals : ndarray (n,)
        Perpendicular distance of ``X`` from each ray [m].
    W : ndarray (n, 3, 3)
        Each ray's weight ``B C^-1 B^T``.
    B : ndarray (n, 3, 2)
    """
    O = np.asarray(origins, float)
    D = np.asarray(directions, float)
    D = D / np.linalg.norm(D, axis=-1, keepdims=True)
    B = _across(D)
    C = np.broadcast_to(np.eye(2), (len(O), 2, 2)) if cov_across is None else np.asarray(cov_across, float)
    W = B @ np.linalg.inv(C) @ np.swapaxes(B, -1, -2)
    A = W.sum(0)
    X = np.linalg.solve(A, np.einsum("nij,nj->i", W, O))
    r = X - O
    miss = r - np.einsum("ni,ni->n", r, D)[:, None] * D
    return X, np.linalg.norm(miss, axis=-1), W, B


def triangulate(
    sensor: Any,
    pose: Pose,
    row: ArrayLike,
    col: ArrayLike,
    budget: ErrorBudget | None = None,
    *,
    shared: Iterable[str] = SHARED,
    velocity_ned_m_s: ArrayLike | None = None,
    min_angle_deg: float = 1.0,
    corrections: Corrections = NO_CORRECTIONS,
) -> Triangulation:
    """Locate one target from its pixels in several frames (``pose``, ``row``, ``col`` of shape (n,)).

    Parameters
    ----------
    sensor : FrameSensor or Camera
    pose : Pose
        The platform state of each frame.
    row, col : array_like (n,)
        The target's 1-based pixel in each frame.
    budget : ErrorBudget, optional
        Weights the rays and gives the covariance (its surface keys are ignored: no surface).
    shared : set of str
        The budget keys shared by every frame (default :data:`SHARED`: the sensor's own).
    min_angle_deg : float
        Rays must span at least this angle (the largest angle between two of them), else the
        point is only known along the rays: INVALID_INPUT.
    corrections : Corrections
        The location pipeline's line-of-sight corrections: the rays are met as they arrive near
        the target (:meth:`geoloc.pipeline.Pipeline.lines_near`: the bent rays' tangents at its
        height), the point found again from them until it moves less than 1 mm (three times at
        most; each step gains the ratio of the point's move to the shift). The covariance keeps
        the straight rays' derivatives (refraction changes them by 1e-4 of themselves).
    """
    from geoloc.locate import as_sensor

    s = as_sensor(sensor)
    los = s.line_of_sight(row, col, pose, outside="extrapolate", engine="numpy")
    O = np.asarray(los.origin_ecef, float).reshape(-1, 3)
    D = np.asarray(los.direction_ecef, float).reshape(-1, 3)
    ok = np.asarray(los.status).reshape(-1) == Status.OK
    names, dO, dD = None, None, None
    if budget is not None:
        names, dO, dD, _, _ = chain_derivatives(s, pose, row, col, budget, velocity_ned_m_s)
    tri = triangulate_rays(O, D, ok, names, dO, dD, shared=shared, min_angle_deg=min_angle_deg)
    if corrections:
        pipe = Pipeline(s, None, corrections)
        for _ in range(3):
            if tri.status != Status.OK:
                break
            lines = pipe.lines_near(los, np.broadcast_to(tri.ecef, np.shape(los.origin_ecef)))
            Oc = np.asarray(lines.origin_ecef, float).reshape(-1, 3)
            Dc = np.asarray(lines.direction_ecef, float).reshape(-1, 3)
            okc = ok & (np.asarray(lines.status).reshape(-1) == Status.OK)
            new = triangulate_rays(Oc, Dc, okc, names, dO, dD, shared=shared, min_angle_deg=min_angle_deg)
            moved = float(np.linalg.norm(np.asarray(new.ecef) - np.asarray(tri.ecef)))
            tri = new
            if not moved > 1e-3:
                break
    return tri


def triangulate_rays(
    O: ArrayLike,
    D: ArrayLike,
    ok: ArrayLike | None = None,
    names: Sequence[str] | None = None,
    dO: ArrayLike | None = None,
    dD: ArrayLike | None = None,
    *,
    shared: Iterable[str] = SHARED,
    min_angle_deg: float = 1.0,
) -> Triangulation:
    """:func:`triangulate` from the rays themselves: origins ``O`` and unit directions ``D`` (n, 3)
    in ECEF, and with a budget each ray's derivatives ``dO``, ``dD`` (n, 3, k) per 1 sigma of the
    sources ``names`` (:func:`geoloc.analysis.uncertainty.chain_derivatives`, one frame's sensor
    per ray if need be: the viewer's frames each have their own zoom)."""
    O = np.asarray(O, float).reshape(-1, 3)
    D = np.asarray(D, float).reshape(-1, 3)
    use = (np.ones(len(O), bool) if ok is None else np.asarray(ok, bool).reshape(-1)) & np.all(np.isfinite(D), -1)
    n = len(O)
    nan3 = np.full(3, np.nan)
    if use.sum() < 2 or _spread_deg(D[use]) < min_angle_deg:
        return Triangulation(
            nan3, math.nan, math.nan, math.nan, int(use.sum()), np.full(n, np.nan), status=int(Status.INVALID_INPUT)
        )
    X, _, _, _ = intersect_rays(O[use], D[use])
    out_res = np.full(n, np.nan)
    if names is None:
        X, res, _, _ = intersect_rays(O[use], D[use])
        out_res[use] = res
        lat, lon, h = (float(v) for v in ecef_to_geodetic(X))
        return Triangulation(X, lat, lon, h, int(use.sum()), out_res)
    if dO is None or dD is None:
        raise ValueError(
            f"triangulate_rays: names = {list(names)!r} given without their derivatives dO and dD (n, 3, k)"
        )
    t = np.einsum("ni,ni->n", X - O, D)  # range to the target along each ray
    free = (np.asarray(dO, float) + t[:, None, None] * np.asarray(dD, float))[
        use
    ]  # (m, 3, k): each ray's move at the target
    Dk = D[use]
    B = _across(Dk)
    fa = np.einsum("nji,njk->nik", B, free)  # across-ray components (m, 2, k)
    C = fa @ np.swapaxes(fa, -1, -2) + np.eye(2) * 1e-12  # each ray's miss covariance across it
    X, res, W, _ = intersect_rays(O[use], Dk, C)
    out_res[use] = res
    Ainv = np.linalg.inv(W.sum(0))
    moves = np.einsum("ij,njk,nkl->nil", Ainv, W, free)  # (m, 3, k): X's move per ray per source
    cols = []
    for k, key in enumerate(names):
        if key in shared:
            cols.append(moves[:, :, k].sum(0)[:, None])  # a bias: the same in every frame
        else:
            cols.append(moves[:, :, k].T)  # noise: independent per frame
    J = np.concatenate(cols, -1) if cols else np.zeros((3, 0))
    lat, lon, h = (float(v) for v in ecef_to_geodetic(X))
    Re = R_ecef_enu(lat, lon)
    Je = Re.T @ J
    cov = Je @ Je.T
    major, minor, az = (float(v) for v in ellipse(cov[:2, :2]))
    return Triangulation(
        X,
        lat,
        lon,
        h,
        int(use.sum()),
        out_res,
        cov,
        major,
        minor,
        az,
        float(ce90(major, minor)),
        float(LE90_PER_SIGMA * math.sqrt(cov[2, 2])),
    )


def _spread_deg(D) -> float:
    """The largest angle between two of the unit directions D (m, 3) [deg]."""
    c = np.clip(D @ D.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(c.min())))


def compare_with_surface(tri: Triangulation, surface_h_m: ArrayLike, surface_ok: ArrayLike | None = None) -> dict:
    """Each frame's surface hit height against the triangulated height: a DEM or datum check.

    Parameters
    ----------
    tri : Triangulation
    surface_h_m : array_like (n,)
        The target's height where each frame's ray meets the DEM (ellipsoidal) [m].

    Returns
    -------
    dict
        ``differences_m`` (surface minus triangulated, per frame), ``mean_m``, ``se_m`` (its
        standard error: the frames' scatter over sqrt(n) and the triangulation's own sigma up),
        ``warning`` (a text when ``|mean| > 3 SE`` and ``> 5 m``: "likely DEM or datum error",
        else "").
    """
    d = np.asarray(surface_h_m, float) - tri.h
    good = np.isfinite(d) if surface_ok is None else (np.isfinite(d) & np.asarray(surface_ok, bool))
    v = d[good]
    if v.size == 0:
        return {"differences_m": d, "mean_m": math.nan, "se_m": math.nan, "warning": ""}
    sig_up = math.sqrt(tri.cov_enu[2, 2]) if tri.cov_enu is not None else 0.0
    scatter = float(np.std(v, ddof=1) / math.sqrt(v.size)) if v.size > 1 else 0.0
    se = math.hypot(scatter, sig_up)
    mean = float(v.mean())
    warn = ""
    if abs(mean) > DEM_OFFSET_SE * se and abs(mean) > DEM_OFFSET_MIN_M:
        warn = (
            f"the surface is {mean:+.1f} m from the rays' intersection on average over {v.size} frames "
            f"(standard error {se:.1f} m): likely DEM or datum error (ellipsoid vs MSL? a DEM offset?)"
        )
    return {"differences_m": d, "mean_m": mean, "se_m": se, "warning": warn}
