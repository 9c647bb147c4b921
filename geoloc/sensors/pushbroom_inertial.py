"""A pushbroom whose attitude is measured against the stars: a real satellite's line scanner.

Conventions: ``docs/conventions.md``; the Sentinel-2 instance: ``docs/sentinel2.md``.

The model, as Orekit Rugged's ``LineSensor`` on a spacecraft whose attitude is given in an
inertial frame (Sen2VM's Sentinel-2 set-up)::

    P_ecef = C(t) + m * R_ecef_in(t) R_in_body(t) R_body_det(t) u(j)
    u(j)   = [tan psi_y(j), -tan psi_x(j), 1] / norm         (detector frame, Z towards the Earth)
    t      = t0 + (i - 1) * line_period                          (row i's centre)

* ``C(t)``: the orbit (GPS antenna; Sentinel-2 gives no lever arm), Earth-fixed samples
  interpolated by cubic Hermite (:class:`geoloc.sensors.pushbroom.Orbit`).
* ``R_in_body(t)``: the attitude quaternions (inertial -> body, scalar first), interpolated by
  spherical linear interpolation between samples (Rugged's default with two neighbours).
* ``R_ecef_in(t)``: the Earth's orientation, precession-nutation, Earth rotation and polar
  motion (:class:`geoloc.frames.earth.EarthRotationTable`, astropy/ERFA from IERS values).
* ``R_body_det(t)``: the instrument's mounting (fixed small rotations: body <- MSI <- focal
  plane <- detector), each of the first two followed by its refining rotation, polynomials in
  time (:class:`geoloc.io.sentinel2.Refining`: ``MSI_State``, ``Focal_Plane_State``), and
  their homotheties on the detector frame's Z (the focal length's relative change).
* ``u(j)``: the viewing direction of detector pixel j (column j), from its tabulated
  tan psi_x (across track) and tan psi_y (along track), interpolated linearly between pixels.

Ground -> image iterates on the line time (as :class:`geoloc.sensors.pushbroom.PushbroomSensor`):
the point in the detector frame gives the column from tan psi_x and an along-track residual
driven to zero by Newton steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from geoloc.frames import rotations as rot
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.sensors.base import PixelHit, check_outside, check_param_names, flag_outside
from geoloc.sensors.pushbroom import LineDating, LookAngles, Orbit
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight

if TYPE_CHECKING:
    from geoloc.frames.earth import EarthRotationTable


def _bad(field_name, value, why):
    raise ValueError(f"{field_name} = {value!r}: {why}")


def R_small(angles: Sequence[float] | np.ndarray, axes: tuple[str, ...] = ("X", "Y", "Z")) -> np.ndarray:
    """The passive rotation ``R_a3 @ R_a2 @ R_a1`` of three angles about the named axes (R1 first)."""
    elementary = {"X": rot.rx, "Y": rot.ry, "Z": rot.rz}
    R = np.eye(3)
    for a, ax in zip(angles, axes):
        R = elementary[ax](a) @ R
    return R


@dataclass(frozen=True)
class InertialPushbroomSensor(LineDating):
    """A line scanner with inertial attitude (see the module docstring).

    Attributes
    ----------
    orbit : Orbit
        Earth-fixed orbit samples; times in seconds from the sensor's epoch.
    attitude_t : ndarray (M,)
        Attitude sample times [s from the epoch].
    q_in_body : ndarray (M, 4)
        Quaternions (scalar first) of the rotation inertial -> body: ``v_body = R(q)^T v_in``
        with R(q) the usual (active) rotation matrix of q (Orekit's ``Rotation.applyTo``).
    earth : EarthRotationTable
        ``R_ecef_in(t)``.
    look : LookAngles
        tan psi_x, tan psi_y per detector pixel (column 1..N).
    rows : int
    line_period_s : float
    t0_s : float
        Time of row 1's centre [s from the epoch].
    R_body_msi : ndarray (3, 3)
        The instrument's mounting, MSI frame -> body (piloting) frame.
    R_msi_fp, R_fp_det : ndarray (3, 3)
        Focal plane -> MSI frame, detector -> focal plane (identity by default).
    refining_t0_s : float
        Time origin of the refining polynomials [s from the epoch].
    refining_rotation : tuple of 3 tuples
        Coefficients (lowest degree first, seconds) of the refining angles about X, Y, Z [rad],
        applied after the MSI mounting (Sentinel-2's ``MSI_State``).
    refining_homothety : tuple
        Coefficients of the relative scale of the detector frame's Z.
    focal_rotation, focal_homothety : tuple
        The same two terms of the focal plane (``Focal_Plane_State``): the rotation applied after
        ``R_msi_fp``, the scale multiplying ``refining_homothety``'s.
    name : str
    """

    orbit: Orbit
    attitude_t: np.ndarray
    q_in_body: np.ndarray
    earth: EarthRotationTable
    look: LookAngles
    rows: int
    line_period_s: float
    t0_s: float
    R_body_msi: np.ndarray = field(default_factory=lambda: np.eye(3))
    refining_t0_s: float = 0.0
    refining_rotation: tuple = ((0.0,), (0.0,), (0.0,))
    refining_homothety: tuple = (0.0,)
    R_msi_fp: np.ndarray = field(default_factory=lambda: np.eye(3))
    R_fp_det: np.ndarray = field(default_factory=lambda: np.eye(3))
    focal_rotation: tuple = ((0.0,), (0.0,), (0.0,))
    focal_homothety: tuple = (0.0,)
    name: str = ""
    epoch: object = None  # the datetime64 of t = 0 (for messages and the inverse's dates)

    #: light-time and aberration of light are on by default (Rugged's directLocation)
    spaceborne: ClassVar[bool] = True
    #: named parameters (SI): the line timing
    PARAMS: ClassVar[tuple] = ("t0_s", "line_period_s")

    def __post_init__(self):
        t = np.asarray(self.attitude_t, float)
        q = np.asarray(self.q_in_body, float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.diff(t) > 0):
            _bad("attitude_t", t[:4].tolist(), "needs >= 2 strictly increasing times")
        if q.shape != (t.size, 4) or not np.all(np.isfinite(q)):
            _bad("q_in_body", q.shape, f"must be a finite ({t.size}, 4) array")
        if not (isinstance(self.rows, (int, np.integer)) and self.rows >= 1):
            _bad("rows", self.rows, "must be an integer >= 1")
        if not (np.isfinite(self.line_period_s) and self.line_period_s > 0):
            _bad("line_period_s", self.line_period_s, "must be > 0")
        object.__setattr__(self, "attitude_t", t)
        object.__setattr__(self, "q_in_body", q)
        # scipy's quaternions are scalar last; R(q) as scipy builds it is the active matrix
        object.__setattr__(self, "_slerp", Slerp(t, Rotation.from_quat(q[:, [1, 2, 3, 0]])))
        t1, t2 = self.line_time(1), self.line_time(self.rows)
        for name, span in (("orbit", self.orbit.span), ("attitude", (t[0], t[-1]))):
            if t1 < span[0] or t2 > span[1]:
                _bad(f"{name} samples", span, f"must cover the imaging time [{t1:.3f}, {t2:.3f}] s")

    # ------------------------------------------------------------ basics
    @property
    def cols(self) -> int:
        return self.look.n

    @property
    def params(self) -> dict:
        return {"t0_s": float(self.t0_s), "line_period_s": float(self.line_period_s)}

    def with_params(self, **changes: float) -> "InertialPushbroomSensor":
        import dataclasses

        check_param_names(changes, self.params, "inertial pushbroom sensor")
        values: dict[str, Any] = {k: float(v) for k, v in changes.items()}
        return dataclasses.replace(self, **values)

    def frames(self, state: object = None) -> None:
        """The frames change line by line; the viewers draw it from its lines of sight (None)."""
        return None

    # ------------------------------------------------------------ geometry at a time
    def _R_in_body(self, t):
        t = np.clip(np.asarray(t, float), self.attitude_t[0], self.attitude_t[-1])
        # v_in = R(q) v_body: the active matrix of q maps body coordinates to inertial ones
        return self._slerp(np.ravel(t)).as_matrix().reshape(np.shape(t) + (3, 3))

    def _refining_R(self, t: np.ndarray, coefficients: tuple) -> np.ndarray:
        """The refining rotation of angles about X, Y, Z (polynomials in seconds from the
        refining origin) at times ``t``: ``Rz Ry Rx`` (..., 3, 3)."""
        dt = np.asarray(t, float) - self.refining_t0_s
        ang = [np.polynomial.polynomial.polyval(dt, c) for c in coefficients]
        return rot.rz(ang[2]) @ rot.ry(ang[1]) @ rot.rx(ang[0])

    def R_body_det(self, t: np.ndarray) -> np.ndarray:
        """Detector frame -> body frame at times ``t``: MSI mounting, its refining rotation, the
        focal plane's mounting, its refining rotation, the detector's mounting."""
        R = self.R_body_msi @ self._refining_R(t, self.refining_rotation) @ self.R_msi_fp
        return R @ self._refining_R(t, self.focal_rotation) @ self.R_fp_det

    def exterior(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centre_ecef, velocity_ecef, R_ecef_det) at times ``t``."""
        t = np.asarray(t, float)
        p, v = self.orbit.state(t)
        R = self.earth.R_ecef_in(t) @ self._R_in_body(t) @ self.R_body_det(t)
        return p, v, R

    def _scale_z(self, t: ArrayLike) -> np.ndarray:
        dt = np.asarray(t, float) - self.refining_t0_s
        msi = np.polynomial.polynomial.polyval(dt, self.refining_homothety)
        return (1.0 + msi) * (1.0 + np.polynomial.polynomial.polyval(dt, self.focal_homothety))

    def detector_direction(self, col: ArrayLike, t: ArrayLike) -> np.ndarray:
        """u(j) in the detector frame (not normalised), with the refining homothety on Z."""
        tx = self.look.tan_x(col)
        ty = self.look.tan_y(col)
        return np.stack([ty, -tx, np.broadcast_to(self._scale_z(t), np.shape(tx))], axis=-1)

    # ------------------------------------------------------------ the Sensor interface
    def line_of_sight(
        self, row: ArrayLike, col: ArrayLike, state: object = None, *, outside: str = "flag"
    ) -> LineOfSight:
        """Pixels (1-based row = line, col = detector pixel) -> lines of sight in ECEF.

        Geometry is computed once per distinct row (one time per image line).
        """
        check_outside(outside)
        row, col = np.broadcast_arrays(np.asarray(row, float), np.asarray(col, float))
        shape = row.shape
        r = row.ravel()
        c = col.ravel()
        finite = np.isfinite(r) & np.isfinite(c)
        rr = np.where(finite, r, 1.0)
        urow, inv = np.unique(rr, return_inverse=True)
        t = self.line_time(urow)
        p, v, R = self.exterior(t)
        u = self.detector_direction(c, self.line_time(rr))
        d = np.einsum("nij,nj->ni", R[inv], u)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        o = p[inv]
        vel = v[inv]
        t_all = self.line_time(rr)
        span_ok = (t_all >= max(self.orbit.span[0], self.attitude_t[0])) & (
            t_all <= min(self.orbit.span[1], self.attitude_t[-1])
        )
        bad = ~finite | ~span_ok
        d[bad] = np.nan
        status = np.where(bad, Status.INVALID_INPUT, Status.OK).astype(np.uint8)
        if outside == "flag":
            status = flag_outside(status, r, c, self.rows, self.cols)
        return LineOfSight(
            o.reshape(shape + (3,)),
            d.reshape(shape + (3,)),
            status.reshape(shape),
            velocity_ecef=vel.reshape(shape + (3,)),
        )

    def ground_to_pixel(
        self,
        lat: ArrayLike,
        lon: ArrayLike,
        h: ArrayLike,
        state: object = None,
        *,
        tol_lines: float = 1e-7,
        max_iter: int = 30,
    ) -> PixelHit:
        """Ground points (rad, rad, m ellipsoidal) -> (row, col), by Newton steps on the line time.

        At a trial time the point in the detector frame, u = R_det_ecef (P - C), gives the
        column from its across-track tangent (-u_y / u_z = tan psi_x) and the along-track
        residual u_x / u_z - tan psi_y(col), driven to zero (derivative by a finite difference
        of one line).
        """
        P = geodetic_to_ecef(lat, lon, h)
        shape = P.shape[:-1]
        status = np.full(shape, Status.OK, dtype=np.uint8)
        status[~np.all(np.isfinite(P), axis=-1)] = Status.INVALID_INPUT
        t = np.full(shape, float(self.line_time((self.rows + 1) / 2.0)))
        dt = self.line_period_s
        lo = max(self.orbit.span[0], self.attitude_t[0])
        hi = min(self.orbit.span[1], self.attitude_t[-1]) - dt

        def residual(tt):
            p, _, R = self.exterior(tt)
            u = np.einsum("...ji,...j->...i", R, P - p)  # R^T (P - C)
            with np.errstate(invalid="ignore", divide="ignore"):
                uz = u[..., 2] / self._scale_z(tt)
                x = u[..., 0] / uz
                y = -u[..., 1] / uz
            col = self.look.col_of_tan_x(y)
            return x - self.look.tan_y(col), col, uz

        active = status == Status.OK
        col = np.full(shape, np.nan)
        for _ in range(max_iter):
            if not np.any(active):
                break
            e0, col_k, uz = residual(t)
            e1, _, _ = residual(t + dt)
            with np.errstate(invalid="ignore", divide="ignore"):
                step = -e0 / ((e1 - e0) / dt)
            step = np.where(active, step, 0.0)
            col = np.where(active, col_k, col)
            behind = active & ~(uz > 0)
            status[behind] = Status.BEHIND_CAMERA
            bad = active & ~np.isfinite(step)
            status[bad & ~behind] = Status.INVALID_INPUT
            active = active & ~behind & ~bad
            t = np.where(active, np.clip(t + step, lo, hi), t)
            active = active & ~(np.abs(step) <= tol_lines * dt)
        if np.any(active):
            status[active] = Status.NO_CONVERGENCE
        ok = status == Status.OK
        if np.any(ok):
            _, col_f, _ = residual(t)
            col = np.where(ok, col_f, col)
            status[ok & ((t <= lo) | (t >= hi))] = Status.INVALID_INPUT
            ok = status == Status.OK
        row = np.where(ok, self.row_of_time(t), np.nan)
        col = np.where(ok, col, np.nan)
        return PixelHit(row, col, flag_outside(status, row, col, self.rows, self.cols))


__all__ = ["InertialPushbroomSensor", "R_small"]
