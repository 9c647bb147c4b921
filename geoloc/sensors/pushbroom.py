"""Satellite pushbroom (line-scanner) rigorous sensor model [L12 eq. 1-2].

Conventions: ``docs/conventions.md`` (passive rotations, ``R_dst_src``,
radians and metres inside, 1-based pixels). User guide: ``docs/rpc.md``.

The model of [L12 eq. 1], written in this project's frames::

    P_ecef = C(t) + m * R_ecef_orb(t) R_orb_body(t) R_body_cam u(j)
    C(t)   = G(t) + R_ecef_body(t) lever_arm_body
    u(j)   = [tan psi_Y(j), tan psi_X(j), -1]                        [L12 eq. 1]

* ``t`` is the time of image line (row) ``i``: ``t = t0 + (i - 1) * line_period``.
  Every line has its own position and attitude, interpolated from samples
  ([L12]: orbit at 1 Hz, attitude at 4 Hz).
* ``G(t)`` is the orbit (GPS phase centre) in ECEF: cubic Hermite interpolation
  of position samples with their velocities.
* ``R_ecef_orb`` is the orbital frame of [L18 eq. 7-10] built from the ECEF
  position and velocity: b3 = -G/|G| (geocentric down), b2 = (b3 x V)/|b3 x V|
  (right of track), b1 = b2 x b3 (forward). Because V is the Earth-fixed
  velocity, this frame already contains the Earth-rotation yaw ("yaw steering").
* ``R_orb_body`` is the attitude *relative to the orbital frame*, so no
  J2000 / Earth-orientation model is needed: body = Rx(roll) Ry(pitch) Rz(yaw)
  orbital (passive z-y-x, the same order as [Q17 eq. 6]); the three angles are
  interpolated with cubic splines through the samples.
  [L12 eq. 1] composes R_J2000^WGS84 R_star^J2000 (R_star^body)^T instead, from
  star-tracker quaternions in J2000; this model deliberately starts after that
  product (see docs/rpc.md).
* ``R_body_cam`` is the camera mounting times the exterior calibration rotation
  R of [L12 eq. 2] (which absorbs the mounting and timing biases):
  ``R_cam_body = Rx(pi) Rzyx(cal) Rzyx(mount)``. The Rx(pi) turns a body-like
  frame (Z down) into the camera frame of [L12] (X along track, Y to the left,
  Z up, so the line of sight is along -Z, as in u(j) above).
* ``(psi_X, psi_Y)`` are the per-detector look angles (the interior
  calibration parameters of [L12 eq. 2]), tabulated for detectors 1..N and
  linearly interpolated between detectors. Detector j is image column j.

Ground -> image (:meth:`PushbroomSensor.ground_to_pixel`) iterates on the
line time: Newton steps on the along-track angle residual
``u_x / -u_z - tan psi_Y(j)`` until the time step is below 1e-6 line.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from geoloc.frames import rotations as rot
from geoloc.geodesy.ellipsoid import A, geodetic_to_ecef
from geoloc.sensors.base import PixelHit, check_outside, check_param_names, flag_outside
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.tomlio import read_toml

#: Earth rotation rate [rad/s] (WGS-84 / IERS nominal value), used only to
#: synthesise the orbit of a scenario (:func:`circular_orbit`).
OMEGA_EARTH = 7.2921150e-5
#: Earth gravitational constant GM [m^3/s^2] (WGS-84), for :func:`circular_orbit`.
GM_EARTH = 3.986004418e14


def _bad(field_name, value, why):
    raise ValueError(f"{field_name} = {value!r}: {why}")


def R_ecef_orbital(position: ArrayLike, velocity: ArrayLike) -> np.ndarray:
    """Orbital frame -> ECEF from position and velocity [L18 eq. 7-10].

    b3 = -P/|P| (towards the Earth's centre), b2 = (b3 x V)/|b3 x V| (right of
    the velocity), b1 = b2 x b3 (along the velocity); the matrix has columns
    b1, b2, b3 (so it maps orbital coordinates to ECEF).

    Parameters
    ----------
    position, velocity : array_like (..., 3)
        ECEF position [m] and Earth-fixed velocity [m/s].

    Returns
    -------
    ndarray (..., 3, 3)
    """
    p = np.asarray(position, float)
    v = np.asarray(velocity, float)
    b3 = -p / np.linalg.norm(p, axis=-1, keepdims=True)
    b2 = np.cross(b3, v)
    b2 = b2 / np.linalg.norm(b2, axis=-1, keepdims=True)
    b1 = np.cross(b2, b3)
    return np.stack([b1, b2, b3], axis=-1)


def R_zyx(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> np.ndarray:
    """Passive z-y-x rotation Rx(roll) Ry(pitch) Rz(yaw), the order of [Q17 eq. 6]."""
    return rot.rx(roll) @ rot.ry(pitch) @ rot.rz(yaw)


# ---------------------------------------------------------------------- orbit
@dataclass(frozen=True)
class Orbit:
    """Orbit samples (GPS phase centre) in ECEF, interpolated by cubic Hermite.

    Attributes
    ----------
    t : ndarray (K,)
        Sample times [s], strictly increasing (any epoch).
    position : ndarray (K, 3)
        ECEF position [m].
    velocity : ndarray (K, 3)
        ECEF (Earth-fixed) velocity [m/s].
    """

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    _spline: Any = field(init=False, repr=False, compare=False)  # scipy ships no types

    def __post_init__(self):
        t = np.asarray(self.t, float)
        p = np.asarray(self.position, float)
        v = np.asarray(self.velocity, float)
        if t.ndim != 1 or t.size < 2:
            _bad("orbit.t", t.shape, "needs a 1-D array of at least 2 sample times")
        if not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
            _bad("orbit.t", t[:5].tolist(), "sample times must be finite and strictly increasing")
        for name, arr in (("orbit.position", p), ("orbit.velocity", v)):
            if arr.shape != (t.size, 3) or not np.all(np.isfinite(arr)):
                _bad(name, arr.shape, f"must be a finite ({t.size}, 3) array")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "velocity", v)
        object.__setattr__(self, "_spline", CubicHermiteSpline(t, p, v, axis=0))

    @property
    def span(self) -> tuple[float, float]:
        return float(self.t[0]), float(self.t[-1])

    def state(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated position and velocity at times ``t`` [L12 section 4.1].

        Cubic Hermite through the position samples with the sampled velocities
        as derivatives (for a 1 Hz LEO orbit the interpolation error is far
        below a millimetre: the fourth derivative is ~ GM/r^2 * n^2 ~ 1e-5 m/s^4,
        error <= h^4/384 * that). Times outside the sample span give NaN.

        Returns
        -------
        position, velocity : ndarray (..., 3)
        """
        t = np.asarray(t, float)
        lo, hi = self.span
        inside = (t >= lo) & (t <= hi)
        tc = np.where(inside, t, lo)
        p = self._spline(tc)
        v = self._spline(tc, 1)
        p = np.where(inside[..., None], p, np.nan)
        v = np.where(inside[..., None], v, np.nan)
        return p, v


def circular_orbit(
    altitude_m: float,
    inclination: float,
    centre_lat: float,
    centre_lon: float,
    times: ArrayLike,
    *,
    descending: bool = True,
) -> Orbit:
    """Synthetic circular Keplerian orbit passing over a ground point at t = 0.

    Used to build the bundled ZY-3-like scenario. The inertial frame is taken
    equal to ECEF at t = 0 and the Earth turns about Z at :data:`OMEGA_EARTH`
    (no precession, nutation or polar motion: enough for a synthetic scene,
    and the sensor model itself only sees the ECEF samples). At t = 0 the
    satellite is on the geocentric vertical of (centre_lat, centre_lon), so the
    geocentric nadir (the orbital frame's b3) meets the ground there.

    Parameters
    ----------
    altitude_m : float
        Orbit radius minus the WGS-84 semi-major axis a [m].
    inclination : float
        Orbit inclination [rad].
    centre_lat, centre_lon : float
        Geodetic latitude and longitude of the scene centre [rad].
    times : array_like (K,)
        Sample times [s] relative to the pass over the centre.
    descending : bool
        Descending (north to south) pass, as ZY-3's daytime passes (10:30 descending node).

    Returns
    -------
    Orbit
    """
    r = A + float(altitude_m)
    c = geodetic_to_ecef(centre_lat, centre_lon, 0.0)
    lat_c = math.atan2(c[2], math.hypot(c[0], c[1]))  # geocentric latitude of the centre
    s = math.sin(lat_c) / math.sin(inclination)
    if abs(s) > 1:
        _bad("centre_lat_deg", math.degrees(centre_lat), "not reachable with this inclination")
    u0 = math.pi - math.asin(s) if descending else math.asin(s)
    node = centre_lon - math.atan2(math.cos(inclination) * math.sin(u0), math.cos(u0))
    n = math.sqrt(GM_EARTH / r**3)  # mean motion
    t = np.asarray(times, float)
    u = u0 + n * t
    # inertial position and velocity: R3(-node) R1(-i) [r cos u, r sin u, 0]
    ci, si, cn, sn = math.cos(inclination), math.sin(inclination), math.cos(node), math.sin(node)
    xo, yo = r * np.cos(u), r * np.sin(u)
    vxo, vyo = -r * n * np.sin(u), r * n * np.cos(u)

    def to_inertial(x, y):
        return np.stack([cn * x - sn * ci * y, sn * x + cn * ci * y, si * y], axis=-1)

    p_i = to_inertial(xo, yo)
    v_i = to_inertial(vxo, vyo)
    # ECEF = Rz(theta) inertial, theta = omega t (passive rotation about Z)
    R = rot.rz(OMEGA_EARTH * t)
    p_e = rot.rotate(R, p_i)
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    v_e = rot.rotate(R, v_i - np.cross(w, p_i))
    return Orbit(t, p_e, v_e)


# ------------------------------------------------------------------- attitude
@dataclass(frozen=True)
class Attitude:
    """Attitude samples of the body relative to the orbital frame.

    body = Rx(roll) Ry(pitch) Rz(yaw) orbital (passive, [Q17 eq. 6] order);
    each angle is interpolated by a cubic spline through the samples ([L12]:
    4 Hz). Times outside the sample span give NaN.

    Attributes
    ----------
    t : ndarray (K,)
        Sample times [s], strictly increasing.
    roll, pitch, yaw : ndarray (K,)
        Angles [rad].
    """

    t: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    _splines: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        t = np.asarray(self.t, float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
            _bad("attitude.t", t.shape, "needs >= 2 finite, strictly increasing sample times")
        sp = []
        for name in ("roll", "pitch", "yaw"):
            a = np.asarray(getattr(self, name), float)
            if a.shape != t.shape or not np.all(np.isfinite(a)):
                _bad(f"attitude.{name}", a.shape, f"must be a finite array of shape {t.shape}")
            object.__setattr__(self, name, a)
            sp.append(CubicSpline(t, a))
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "_splines", tuple(sp))

    def angles(self, t: ArrayLike) -> tuple[np.ndarray, ...]:
        """Interpolated (roll, pitch, yaw) [rad] at times ``t``; NaN outside the span."""
        t = np.asarray(t, float)
        inside = (t >= self.t[0]) & (t <= self.t[-1])
        tc = np.where(inside, t, self.t[0])
        return tuple(np.where(inside, s(tc), np.nan) for s in self._splines)

    def R_orb_body(self, t: ArrayLike) -> np.ndarray:
        """Body -> orbital rotation at times ``t``, shape (..., 3, 3)."""
        r, p, y = self.angles(t)
        return np.swapaxes(R_zyx(r, p, y), -1, -2)


# ---------------------------------------------------------------- look angles
@dataclass(frozen=True)
class LookAngles:
    """Per-detector look angles (psi_X, psi_Y) of a linear CCD [L12 eq. 1-2].

    Stored as tan psi_X and tan psi_Y for detectors 1..N (detector j images
    column j), linearly interpolated between detectors (and extrapolated
    linearly beyond the ends). In the camera frame of [L12] the line of sight
    of detector j is u = [tan psi_Y(j), tan psi_X(j), -1].

    Attributes
    ----------
    tan_psi_x : ndarray (N,)
        Across-track component; must be strictly monotonic in j.
    tan_psi_y : ndarray (N,)
        Along-track component.
    """

    tan_psi_x: np.ndarray
    tan_psi_y: np.ndarray

    def __post_init__(self):
        x = np.asarray(self.tan_psi_x, float)
        y = np.asarray(self.tan_psi_y, float)
        if x.ndim != 1 or x.size < 2 or y.shape != x.shape:
            _bad("look angles", (x.shape, y.shape), "tan_psi_x and tan_psi_y need the same 1-D shape, N >= 2")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            _bad("look angles", "non-finite", "tables must be finite")
        d = np.diff(x)
        if not (np.all(d > 0) or np.all(d < 0)):
            _bad("tan_psi_x", x[:3].tolist(), "must be strictly monotonic across the detectors")
        object.__setattr__(self, "tan_psi_x", x)
        object.__setattr__(self, "tan_psi_y", y)

    @classmethod
    def from_polynomial(
        cls, n: int, coeffs_x: Sequence[float], coeffs_y: Sequence[float], centre: float | None = None
    ) -> LookAngles:
        """Look angles as cubic (or any degree) polynomials of the detector offset.

        tan psi_X(j) = sum_k cx[k] s^k, tan psi_Y(j) = sum_k cy[k] s^k with
        s = j - centre (centre default (N+1)/2), the usual on-orbit calibration
        model of the ZY-3 interior parameters (cubic in the detector number).
        """
        if not (isinstance(n, int) and n >= 2):
            _bad("detectors", n, "must be an integer >= 2")
        c = (n + 1) / 2.0 if centre is None else float(centre)
        s = np.arange(1, n + 1, dtype=float) - c
        return cls(
            np.polynomial.polynomial.polyval(s, np.asarray(coeffs_x, float)),
            np.polynomial.polynomial.polyval(s, np.asarray(coeffs_y, float)),
        )

    @property
    def n(self) -> int:
        return int(self.tan_psi_x.size)

    def _interp(self, table, col):
        col = np.asarray(col, float)
        j = np.arange(1, self.n + 1, dtype=float)
        out = np.interp(col, j, table)
        lo = col < 1
        hi = col > self.n
        out = np.where(lo, table[0] + (col - 1) * (table[1] - table[0]), out)
        out = np.where(hi, table[-1] + (col - self.n) * (table[-1] - table[-2]), out)
        return out

    def tan_x(self, col: ArrayLike) -> np.ndarray:
        """tan psi_X at (fractional) detector positions ``col``."""
        return self._interp(self.tan_psi_x, col)

    def tan_y(self, col: ArrayLike) -> np.ndarray:
        """tan psi_Y at (fractional) detector positions ``col``."""
        return self._interp(self.tan_psi_y, col)

    def col_of_tan_x(self, tx: ArrayLike) -> np.ndarray:
        """Inverse of :meth:`tan_x`: the fractional detector whose tan psi_X is ``tx``."""
        tx = np.asarray(tx, float)
        x = self.tan_psi_x
        j = np.arange(1, self.n + 1, dtype=float)
        if x[0] > x[-1]:
            x, j = x[::-1], j[::-1]
        out = np.interp(tx, x, j)
        out = np.where(tx < x[0], j[0] + (tx - x[0]) * (j[1] - j[0]) / (x[1] - x[0]), out)
        out = np.where(tx > x[-1], j[-1] + (tx - x[-1]) * (j[-1] - j[-2]) / (x[-1] - x[-2]), out)
        return out

    def direction(self, col: ArrayLike) -> np.ndarray:
        """Camera-frame line of sight u = [tan psi_Y, tan psi_X, -1], [L12 eq. 1], shape (..., 3)."""
        tx = self.tan_x(col)
        ty = self.tan_y(col)
        return np.stack([ty, tx, -np.ones_like(tx)], axis=-1)


# --------------------------------------------------------------------- sensor
class LineDating:
    """Line dating and the image's extent of a pushbroom (``t0_s``, ``line_period_s``, ``rows``,
    ``cols``), shared by :class:`PushbroomSensor` and the inertial one."""

    t0_s: float
    line_period_s: float
    rows: int

    @property
    def cols(self) -> int:
        raise NotImplementedError

    def line_time(self, row: npt.ArrayLike) -> np.ndarray:
        """Imaging time of (fractional, 1-based) line ``row``: t0 + (row - 1) * line_period."""
        return self.t0_s + (np.asarray(row, float) - 1.0) * self.line_period_s

    def row_of_time(self, t: npt.ArrayLike) -> np.ndarray:
        """Inverse of :meth:`line_time`."""
        return 1.0 + (np.asarray(t, float) - self.t0_s) / self.line_period_s

    def in_image(self, row: npt.ArrayLike, col: npt.ArrayLike) -> np.ndarray:
        row, col = np.asarray(row, float), np.asarray(col, float)
        return (row >= 0.5) & (row <= self.rows + 0.5) & (col >= 0.5) & (col <= self.cols + 0.5)


@dataclass(frozen=True)
class PushbroomSensor(LineDating):
    """Rigorous line-scanner model [L12 eq. 1-2] (see the module docstring).

    A spaceborne sensor (:attr:`spaceborne`): light-time and aberration of light are on by
    default in its location pipeline (:class:`geoloc.pipeline.Corrections`).

    Attributes
    ----------
    orbit : Orbit
    attitude : Attitude
        Body relative to the orbital frame.
    look : LookAngles
        Interior orientation, one entry per detector (image column).
    rows : int
        Number of image lines.
    line_period_s : float
        Time between lines [s].
    t0_s : float
        Time of line 1 (row 1) [s], on the clock of the orbit / attitude samples.
    R_cam_body : ndarray (3, 3)
        Body -> camera (mounting and exterior calibration, [L12 eq. 2] R).
    lever_arm_body : ndarray (3,)
        GPS phase centre -> camera perspective centre, body frame [m]
        (the sum of the two offsets of [L12 eq. 1], with its signs folded in).
    name : str
    """

    orbit: Orbit
    attitude: Attitude
    look: LookAngles
    rows: int
    line_period_s: float
    t0_s: float = 0.0
    R_cam_body: np.ndarray = field(default_factory=lambda: rot.rx(np.pi))
    lever_arm_body: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = ""

    #: Light-time and aberration of light are on by default (geoloc.pipeline.Corrections.for_sensor).
    spaceborne: ClassVar[bool] = True

    def __post_init__(self):
        if not (isinstance(self.rows, int) and self.rows > 0):
            _bad("rows", self.rows, "must be a positive integer")
        lp = self.line_period_s
        if not (isinstance(lp, (int, float)) and math.isfinite(lp) and lp > 0):
            _bad("line_period_s", lp, "must be a finite number > 0 (seconds)")
        if not math.isfinite(self.t0_s):
            _bad("t0_s", self.t0_s, "must be finite")
        R = np.asarray(self.R_cam_body, float)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9):
            _bad("R_cam_body", R.shape, "must be a 3x3 rotation matrix")
        la = np.asarray(self.lever_arm_body, float)
        if la.shape != (3,) or not np.all(np.isfinite(la)):
            _bad("lever_arm_body_m", la, "must be 3 finite numbers (metres)")
        object.__setattr__(self, "R_cam_body", R)
        object.__setattr__(self, "lever_arm_body", la)
        t_first, t_last = self.line_time(1), self.line_time(self.rows)
        for name, span in (("orbit", self.orbit.span), ("attitude", (self.attitude.t[0], self.attitude.t[-1]))):
            if t_first < span[0] or t_last > span[1]:
                _bad(f"{name} samples", span, f"must cover the imaging time [{t_first:.3f}, {t_last:.3f}] s")

    # ------------------------------------------------------------ basics
    @property
    def cols(self) -> int:
        """Number of detectors (image columns)."""
        return self.look.n

    def exterior(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Perspective centre and camera -> ECEF rotation at times ``t`` [L12 eq. 1].

        Returns
        -------
        centre_ecef : ndarray (..., 3)
            C(t) = G(t) + R_ecef_body(t) lever_arm_body.
        R_ecef_cam : ndarray (..., 3, 3)
            R_ecef_orb(t) R_orb_body(t) R_body_cam.
        """
        p, v = self.orbit.state(t)
        R_ecef_body = R_ecef_orbital(p, v) @ self.attitude.R_orb_body(t)
        centre = p + rot.rotate(R_ecef_body, self.lever_arm_body)
        return centre, R_ecef_body @ self.R_cam_body.T

    # ------------------------------------------------------- image -> ground
    # ------------------------------------------------------- the Sensor interface
    #: Named parameters (SI): the lever arm and the line timing.
    PARAMS = ("lever_arm_x_m", "lever_arm_y_m", "lever_arm_z_m", "t0_s", "line_period_s")

    @property
    def params(self) -> dict:
        """Named parameters: lever arm [m] (body axes) and line timing [s] (``docs/architecture.md``)."""
        la = self.lever_arm_body
        return dict(zip(self.PARAMS, (float(la[0]), float(la[1]), float(la[2]), self.t0_s, self.line_period_s)))

    def with_params(self, **changes: float) -> "PushbroomSensor":
        import dataclasses

        check_param_names(changes, self.params, "pushbroom sensor")
        p = {**self.params, **{k: float(v) for k, v in changes.items()}}
        return dataclasses.replace(
            self,
            lever_arm_body=np.array([p["lever_arm_x_m"], p["lever_arm_y_m"], p["lever_arm_z_m"]]),
            t0_s=p["t0_s"],
            line_period_s=p["line_period_s"],
        )

    def frames(self, state: Any = None) -> None:
        """A pushbroom's frames change line by line; the viewers draw it from its lines of sight (None)."""
        return None

    def line_of_sight(self, row: ArrayLike, col: ArrayLike, state: Any = None, *, outside: str = "flag") -> LineOfSight:
        """Pixel (row i = line, column j = detector), 1-based -> line of sight in ECEF [L12 eq. 1].

        ``state`` is unused (time and attitude come from the row).

        Returns
        -------
        LineOfSight
            Unit directions; status INVALID_INPUT for NaN pixels or lines
            outside the orbit / attitude sample span, OUTSIDE_SENSOR for a pixel
            off the image (unless ``outside="extrapolate"``).
        """
        check_outside(outside)
        row, col = np.broadcast_arrays(np.asarray(row, float), np.asarray(col, float))
        t = self.line_time(row)
        centre, R = self.exterior(t)
        d = rot.rotate(R, self.look.direction(col))
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        bad = ~(np.all(np.isfinite(d), axis=-1) & np.all(np.isfinite(centre), axis=-1))
        status = np.where(bad, Status.INVALID_INPUT, Status.OK).astype(np.uint8)
        if outside == "flag":
            status = flag_outside(status, row, col, self.rows, self.cols)
        # the orbit's velocity (the antenna's; the lever arm's rotation adds < 1 mm/s), for aberration
        return LineOfSight(centre, d, status, velocity_ecef=self.orbit.state(t)[1])

    # ------------------------------------------------------- ground -> image
    def ground_to_pixel(
        self,
        lat: ArrayLike,
        lon: ArrayLike,
        h: ArrayLike,
        state: Any = None,
        *,
        tol_lines: float = 1e-6,
        max_iter: int = 30,
    ) -> PixelHit:
        """Ground point -> (row, col) by iteration over the line time [L12 section 4.1].

        At a trial time t the point is expressed in the camera frame,
        u = R_cam_ecef(t) (P - C(t)); its across-track tangent u_y / -u_z gives
        the detector j (inverse look-angle table) and the along-track residual
        e(t) = u_x / -u_z - tan psi_Y(j) is driven to zero by Newton steps
        (the derivative by a one-line finite difference). Starts at the middle
        line; converges in 3-4 steps for points in or near the image.

        Parameters
        ----------
        lat, lon : array_like
            Geodetic latitude, longitude [rad].
        h : array_like
            Ellipsoidal height [m].
        tol_lines : float
            Stop when the time step is below this fraction of a line.
        max_iter : int
            Iteration limit.

        Returns
        -------
        PixelHit
            ``row, col`` 1-based; ``status`` OK; OUTSIDE_SENSOR (the pixel is
            given but lies off the image); BEHIND_CAMERA (point above the
            camera's horizon plane); INVALID_INPUT (NaN input or the solution
            leaves the sample span); NO_CONVERGENCE.
        """
        P = geodetic_to_ecef(lat, lon, h)
        shape = P.shape[:-1]
        t = np.full(shape, float(self.line_time((self.rows + 1) / 2.0)))
        dt = self.line_period_s
        status = np.full(shape, Status.OK, dtype=np.uint8)
        status[~np.all(np.isfinite(P), axis=-1)] = Status.INVALID_INPUT
        lo, hi = max(self.orbit.span[0], self.attitude.t[0]), min(self.orbit.span[1], self.attitude.t[-1]) - dt

        def residual(tt):
            c, R = self.exterior(tt)
            u = rot.rotate(np.swapaxes(R, -1, -2), P - c)
            with np.errstate(invalid="ignore", divide="ignore"):
                x = u[..., 0] / -u[..., 2]
                y = u[..., 1] / -u[..., 2]
            col = self.look.col_of_tan_x(y)
            return x - self.look.tan_y(col), col, u[..., 2]

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
            behind = active & ~(uz < 0)
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
            edge = ok & ((t <= lo) | (t >= hi))
            status[edge] = Status.INVALID_INPUT
            ok = status == Status.OK
        row = np.where(ok, self.row_of_time(t), np.nan)
        col = np.where(ok, col, np.nan)
        return PixelHit(row, col, flag_outside(status, row, col, self.rows, self.cols))

    # ---------------------------------------------------------- scenarios
    @classmethod
    def from_dict(cls, data: dict, source: str = "scenario") -> "PushbroomSensor":
        """Build a synthetic pushbroom sensor from a scenario dictionary (see docs/rpc.md)."""
        return _sensor_from_dict(data, source)

    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> "PushbroomSensor":
        path = Path(path)
        data = read_toml(path, "scenario file")
        return cls.from_dict(data, source=str(path))


def _get(d: dict, key: str, source: str, kind=float, default=None, check=None, why=""):
    if key not in d:
        if default is None:
            raise ValueError(f"{source}: missing key {key!r}")
        return default
    v = d[key]
    try:
        if kind is float:
            if isinstance(v, bool):
                raise TypeError
            v = float(v)
        elif kind is int:
            if isinstance(v, bool) or not isinstance(v, int):
                raise TypeError
        elif kind is list:
            v = [float(x) for x in v]
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {key} = {d[key]!r} is not a valid {kind.__name__}") from None
    if kind is float and not math.isfinite(v):
        raise ValueError(f"{source}: {key} = {v!r} must be finite")
    if check is not None and not check(v):
        raise ValueError(f"{source}: {key} = {v!r}: {why}")
    return v


def _sensor_from_dict(data: dict, source: str) -> PushbroomSensor:
    """Scenario tables [orbit], [attitude], [camera] -> PushbroomSensor (units at the edge: deg, m, s)."""
    for sec in ("orbit", "attitude", "camera"):
        if sec not in data or not isinstance(data[sec], dict):
            raise ValueError(f"{source}: missing table [{sec}]")
    o, a, c = data["orbit"], data["attitude"], data["camera"]
    so, sa, sc = f"{source} [orbit]", f"{source} [attitude]", f"{source} [camera]"
    known = {
        "orbit": {
            "altitude_m",
            "inclination_deg",
            "centre_lat_deg",
            "centre_lon_deg",
            "descending",
            "sample_interval_s",
            "margin_s",
        },
        "attitude": {
            "sample_interval_s",
            "roll_deg",
            "pitch_deg",
            "yaw_deg",
            "roll_rate_deg_s",
            "pitch_rate_deg_s",
            "yaw_rate_deg_s",
            "jitter_amplitude_deg",
            "jitter_period_s",
        },
        "camera": {
            "focal_length_m",
            "pixel_pitch_m",
            "detectors",
            "lines",
            "line_period_s",
            "tan_psi_x_poly",
            "tan_psi_y_poly",
            "mount_roll_deg",
            "mount_pitch_deg",
            "mount_yaw_deg",
            "cal_roll_deg",
            "cal_pitch_deg",
            "cal_yaw_deg",
            "lever_arm_body_m",
        },
    }
    for sec, d in (("orbit", o), ("attitude", a), ("camera", c)):
        unknown = sorted(set(d) - known[sec])
        if unknown:
            raise ValueError(f"{source} [{sec}]: unknown key(s) {unknown}; allowed: {sorted(known[sec])}")
    pos = lambda v: v > 0  # noqa: E731
    f = _get(c, "focal_length_m", sc, check=pos, why="must be > 0")
    pitch = _get(c, "pixel_pitch_m", sc, check=pos, why="must be > 0")
    n = _get(c, "detectors", sc, int, check=lambda v: v >= 2, why="must be >= 2")
    lines = _get(c, "lines", sc, int, check=lambda v: v >= 2, why="must be >= 2")
    period = _get(c, "line_period_s", sc, check=pos, why="must be > 0")
    # ideal CCD: tan psi_X = -(pitch/f) s (column j grows to the right of track), plus optional terms
    cx = _get(c, "tan_psi_x_poly", sc, list, default=[0.0, -pitch / f])
    cy = _get(c, "tan_psi_y_poly", sc, list, default=[0.0])
    look = LookAngles.from_polynomial(n, cx, cy)
    deg = math.radians
    R_mount = R_zyx(
        deg(_get(c, "mount_roll_deg", sc, default=0.0)),
        deg(_get(c, "mount_pitch_deg", sc, default=0.0)),
        deg(_get(c, "mount_yaw_deg", sc, default=0.0)),
    )
    R_cal = R_zyx(
        deg(_get(c, "cal_roll_deg", sc, default=0.0)),
        deg(_get(c, "cal_pitch_deg", sc, default=0.0)),
        deg(_get(c, "cal_yaw_deg", sc, default=0.0)),
    )
    lever = _get(c, "lever_arm_body_m", sc, list, default=[0.0, 0.0, 0.0])
    if len(lever) != 3:
        raise ValueError(f"{sc}: lever_arm_body_m = {lever!r} must have 3 numbers")

    alt = _get(o, "altitude_m", so, check=lambda v: 1e5 <= v <= 4e7, why="must be 100 km .. 40 000 km")
    inc = _get(o, "inclination_deg", so, check=lambda v: 0 < v < 180, why="must be in (0, 180) deg")
    lat0 = _get(o, "centre_lat_deg", so, check=lambda v: -90 < v < 90, why="must be in (-90, 90) deg")
    lon0 = _get(o, "centre_lon_deg", so, check=lambda v: -180 <= v <= 360, why="must be in [-180, 360] deg")
    desc = o.get("descending", True)
    if not isinstance(desc, bool):
        raise ValueError(f"{so}: descending = {desc!r} must be true or false")
    dto = _get(o, "sample_interval_s", so, default=1.0, check=pos, why="must be > 0")
    margin = _get(o, "margin_s", so, default=5.0, check=lambda v: v >= 0, why="must be >= 0")
    half = (lines - 1) * period / 2.0
    t0 = -half  # line 1 at -half, the centre line at t = 0 (over the scene centre)
    k = int(math.ceil((half + margin) / dto))
    orbit = circular_orbit(alt, deg(inc), deg(lat0), deg(lon0), np.arange(-k, k + 1) * dto, descending=desc)

    dta = _get(a, "sample_interval_s", sa, default=0.25, check=pos, why="must be > 0")
    ka = int(math.ceil((half + margin) / dta))
    ta = np.arange(-ka, ka + 1) * dta
    amp = deg(_get(a, "jitter_amplitude_deg", sa, default=0.0))
    per = _get(a, "jitter_period_s", sa, default=10.0, check=pos, why="must be > 0")
    angles = []
    for name in ("roll", "pitch", "yaw"):
        v0 = deg(_get(a, f"{name}_deg", sa, default=0.0))
        rate = deg(_get(a, f"{name}_rate_deg_s", sa, default=0.0))
        angles.append(v0 + rate * ta)
    # a slow sinusoidal jitter on roll and pitch (phase-shifted), sampled at the attitude rate
    angles[0] = angles[0] + amp * np.sin(2 * np.pi * ta / per)
    angles[1] = angles[1] + amp * np.cos(2 * np.pi * ta / per)
    att = Attitude(ta, *angles)
    return PushbroomSensor(
        orbit,
        att,
        look,
        lines,
        period,
        t0,
        R_cam_body=rot.rx(np.pi) @ R_cal @ R_mount,
        lever_arm_body=np.asarray(lever),
        name=str(data.get("name", "")),
    )


__all__ = [
    "Attitude",
    "LookAngles",
    "Orbit",
    "PushbroomSensor",
    "R_ecef_orbital",
    "R_zyx",
    "circular_orbit",
    "GM_EARTH",
    "OMEGA_EARTH",
]
