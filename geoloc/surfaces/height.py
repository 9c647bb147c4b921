"""Line of sight x ellipsoid at a target height [Q17 section 2.2, eq. 10-11].

Conventions: ``docs/conventions.md``. Origins and directions are ECEF arrays
``(..., 3)``; directions need not be unit vectors (the parameter ``s`` returned
is in units of ``|d|``; with unit directions it is the slant range in metres).

Two surfaces of "height h_T":

* ``"inflated"``: the paper's ellipsoid with semi-axes (a + h_T, b + h_T)
  [Q17 eq. 11]. Closed form (one quadratic), but it is not exactly the surface
  of constant geodetic height: its geodetic height is low by about
  1.4e-6 h_T sin^2(2 phi) (measured on nadir rays: 1.4 mm at h_T = 1 km,
  7.2 mm at 5 km, 28 mm at 20 km, 14 cm at 100 km, 65 cm at 500 km, all at
  45 deg latitude, and zero at the equator and the poles).
* ``"geodetic"``: the exact surface of constant geodetic height h_T, by
  Newton iteration on s starting from the inflated answer
  (g(s) = h(O + s d) - h_T, g'(s) = n_up . d).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import A, B, ecef_to_geodetic, up_normal_ecef
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight, Surface


@dataclass(frozen=True)
class EllipsoidHit:
    """Result of a batch line-of-sight x ellipsoid intersection.

    Attributes
    ----------
    s : ndarray (...)
        Ray parameter of the hit (metres along a unit direction); NaN if none.
    ecef : ndarray (..., 3)
        Hit point, NaN if none.
    status : ndarray (...) of uint8
        :class:`geoloc.status.Status` codes.
    iterations : ndarray (...) of int
        Newton iterations used (0 for the inflated surface).
    """

    s: np.ndarray
    ecef: np.ndarray
    status: np.ndarray
    iterations: np.ndarray


def ray_inflated_ellipsoid(origin: ArrayLike, direction: ArrayLike, h: ArrayLike) -> EllipsoidHit:
    """Nearest forward intersection with the ellipsoid (a+h, a+h, b+h) [Q17 eq. 10-11].

    Substituting P = O + s d in (x^2 + y^2)/(a+h)^2 + z^2/(b+h)^2 = 1 gives
    qa s^2 + qb s + qc = 0 with primed (axis-scaled) vectors:
    qa = |d'|^2, qb = 2 O'.d', qc = |O'|^2 - 1. The smaller positive root is the
    visible intersection; it is computed in the cancellation-free form.

    Parameters
    ----------
    origin, direction : array_like (..., 3)
        Ray origin (camera centre) and direction, ECEF [m].
    h : array_like (...)
        Target height above the ellipsoid [m].

    Returns
    -------
    EllipsoidHit
        status SKY where the ray misses or points away, ORIGIN_BELOW where the
        origin is inside the inflated ellipsoid, INVALID_INPUT for NaN input
        or h <= -b.
    """
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    h = np.asarray(h, float)
    shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1], h.shape)
    o = np.broadcast_to(o, shape + (3,))
    d = np.broadcast_to(d, shape + (3,))
    h = np.broadcast_to(h, shape)
    scale = np.stack(np.broadcast_arrays(A + h, A + h, B + h), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        op = o / scale
        dp = d / scale
        qa = np.sum(dp * dp, axis=-1)
        qb = 2.0 * np.sum(op * dp, axis=-1)
        qc = np.sum(op * op, axis=-1) - 1.0
        disc = qb * qb - 4.0 * qa * qc
        q = -0.5 * (qb - np.sqrt(disc))  # qb < 0 on the useful branch, so no cancellation
        s = np.minimum(q / qa, qc / q)
    status = np.full(shape, Status.OK, dtype=np.uint8)
    finite = np.all(np.isfinite(o), axis=-1) & np.all(np.isfinite(d), axis=-1) & np.isfinite(h) & (B + h > 0) & (qa > 0)
    status[~finite] = Status.INVALID_INPUT
    inside = finite & (qc < 0)
    status[inside] = Status.ORIGIN_BELOW
    miss = finite & ~inside & ((disc < 0) | (qb >= 0))
    status[miss] = Status.SKY
    ok = status == Status.OK
    s = np.where(ok, s, np.nan)
    p = o + s[..., None] * d
    return EllipsoidHit(s, p, status, np.zeros(shape, dtype=np.int32))


def ray_geodetic_height(
    origin: ArrayLike, direction: ArrayLike, h: ArrayLike, tol_m: float = 1e-6, max_iter: int = 20
) -> EllipsoidHit:
    """Nearest forward intersection with the surface of constant geodetic height h.

    Newton iteration on the ray parameter, started at the inflated-ellipsoid
    answer of :func:`ray_inflated_ellipsoid`: s <- s - (h(P) - h_T) / (n_up . d).
    Near-grazing rays (n_up . d -> 0) converge slowly; a ray that has not met
    ``tol_m`` after ``max_iter`` steps is returned with status NO_CONVERGENCE.

    Parameters
    ----------
    origin, direction : array_like (..., 3)
        Ray origin and direction, ECEF [m].
    h : array_like (...)
        Target geodetic height [m].
    tol_m : float
        Stop when the height residual is below this many metres.
    max_iter : int
        Iteration limit.

    Returns
    -------
    EllipsoidHit
    """
    first = ray_inflated_ellipsoid(origin, direction, h)
    o = np.broadcast_to(np.asarray(origin, float), first.ecef.shape)
    d = np.broadcast_to(np.asarray(direction, float), first.ecef.shape)
    hT = np.broadcast_to(np.asarray(h, float), first.s.shape)
    s = first.s.copy()
    status = first.status.copy()
    iters = np.zeros(s.shape, dtype=np.int32)
    active = status == Status.OK
    for _ in range(max_iter):
        if not np.any(active):
            break
        p = o + s[..., None] * d
        lat, lon, hp = ecef_to_geodetic(p)
        resid = hp - hT
        converged = active & (np.abs(resid) <= tol_m)
        active = active & ~converged
        slope = np.sum(up_normal_ecef(lat, lon) * d, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.where(active, resid / slope, 0.0)
        s = s - step
        iters = iters + active
    if np.any(active):
        p = o + s[..., None] * d
        resid = ecef_to_geodetic(p)[2] - hT
        still = active & ~(np.abs(resid) <= tol_m)
        # np.where, not item assignment: for one ray these are 0-d arrays or numpy scalars
        status = np.where(still, np.uint8(Status.NO_CONVERGENCE), status).astype(np.uint8)
        s = np.where(still, np.nan, s)
    ok = status == Status.OK
    s = np.where(ok, s, np.nan)
    return EllipsoidHit(s, o + s[..., None] * d, status, iters)


def ray_at_height(origin: ArrayLike, direction: ArrayLike, h: ArrayLike, height_kind: str = "inflated") -> EllipsoidHit:
    """Dispatch to the inflated [Q17 eq. 11] or exact geodetic-height surface."""
    if height_kind == "inflated":
        return ray_inflated_ellipsoid(origin, direction, h)
    if height_kind == "geodetic":
        return ray_geodetic_height(origin, direction, h)
    raise ValueError(f"height_kind must be 'inflated' or 'geodetic', got {height_kind!r}")


def intersect_los_height(los: LineOfSight, target_h: ArrayLike, height_kind: str = "inflated") -> GroundPoint:
    """Intersect lines of sight with the surface of height ``target_h`` [Q17 eq. 10-13].

    Parameters
    ----------
    los : LineOfSight
    target_h : array_like
        Target ellipsoidal height h_T [m], broadcasting.
    height_kind : {"inflated", "geodetic"}
        The paper's inflated ellipsoid (eq. 11) or the exact constant-height surface.

    Returns
    -------
    GroundPoint
    """
    hit = ray_at_height(los.origin_ecef, los.direction_ecef, target_h, height_kind)
    status = np.where(los.status != Status.OK, los.status, hit.status).astype(np.uint8)
    ok = status == Status.OK
    ecef = np.where(ok[..., None], hit.ecef, np.nan)
    lat, lon, h = ecef_to_geodetic(ecef)
    return GroundPoint(lat, lon, h, ecef, np.where(ok, hit.s, np.nan), status, los)


#: Kinds of constant-height surface.
HEIGHT_KINDS = ("inflated", "geodetic")


class HeightSurface:
    """A surface of constant ellipsoidal height: the [Q17] inflated ellipsoid or the exact one.

    Parameters
    ----------
    h : array_like
        Target ellipsoidal height [m], broadcasting against the lines of sight.
    kind : {"inflated", "geodetic"}
        ``"inflated"``: the ellipsoid with both semi-axes grown by h [Q17 eq. 11];
        ``"geodetic"``: the exact surface of geodetic height h.
    """

    #: A point at the raw hit's height lies on it (the pipeline's refraction and light-time need
    #: no second intersection: :class:`geoloc.pipeline.Pipeline`).
    constant_height = True

    def __init__(self, h: ArrayLike, kind: str = "inflated"):
        if kind not in HEIGHT_KINDS:
            raise ValueError(f"height surface kind = {kind!r}: must be one of {HEIGHT_KINDS}")
        self.h: ArrayLike = h  # as given: one height, or one per ray (per record: an array, below)
        self.kind = kind

    def intersect(self, los: LineOfSight) -> GroundPoint:
        """The first crossing of each line of sight with the surface [Q17 eq. 10-13]."""
        return intersect_los_height(los, self.h, self.kind)

    def __repr__(self) -> str:
        return f"HeightSurface(h={self.h!r}, kind={self.kind!r})"


class PerRecordHeightSurface(HeightSurface):
    """One target height per record (a records file's height column, e.g. ``paper_height_m``).

    A :class:`HeightSurface` whose ``h`` is one ellipsoidal height per record, in
    record order, so that the lines of sight of the records (shape ``(n,)``) meet
    each its own height; :meth:`take` is the surface of a subset of the records
    (leave-one-out, one flight), in the subset's order.

    Parameters
    ----------
    h : array_like (n,)
        Target ellipsoidal height of each record [m].
    kind : {"inflated", "geodetic"}
        As :class:`HeightSurface`.
    """

    h: np.ndarray  # one height per record (1-D), checked here

    def __init__(self, h: ArrayLike, kind: str = "inflated"):
        h = np.asarray(h, float)
        if h.ndim != 1:
            raise ValueError(f"per-record heights must be one height per record (1-D), got shape {h.shape}")
        super().__init__(h, kind)

    def take(self, idx: Any) -> "PerRecordHeightSurface":
        """The surface of the records ``idx`` (indices into this one's records)."""
        idx = np.asarray(idx)
        return PerRecordHeightSurface(self.h[idx if idx.size else idx.astype(int)], self.kind)

    def __repr__(self) -> str:
        return f"PerRecordHeightSurface({len(self.h)} heights, kind={self.kind!r})"


def for_records(surface: Surface, idx: Any) -> Surface:
    """The surface of the records ``idx``: a per-record surface's :meth:`~PerRecordHeightSurface.take`,
    any other surface itself (it is the same for every record)."""
    return surface.take(idx) if isinstance(surface, PerRecordHeightSurface) else surface
