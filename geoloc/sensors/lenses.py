"""Lens models (pinhole, Brown-Conrady, fisheye) in OpenCV's conventions.

Conventions (``docs/lenses.md``, ``docs/conventions.md``):

- Pixels (u, v) as OpenCV has them: (0, 0) is the **centre** of the top-left
  pixel, u runs along the columns (to the right), v along the rows (down). The
  sensor covers -0.5 <= u <= width - 0.5, -0.5 <= v <= height - 0.5.
- Camera (optical) frame: x right, y down, z forward (the line of sight).
- The project's own pixel convention (1-based, ``docs/conventions.md``) appears
  only in the sensor file (:func:`lens_from_dict` / :func:`lens_to_dict`).

Models, with (x, y) = (X/Z, Y/Z) the normalised coordinates of a direction
(X, Y, Z) and the intrinsic matrix K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]
mapping a distorted normalised point (xd, yd) to the pixel
u = fx xd + skew yd + cx, v = fy yd + cy:

- :class:`PinholeLens`: xd = x, yd = y.
- :class:`BrownLens`: OpenCV's rational Brown-Conrady model, exactly as
  ``cv2.projectPoints`` evaluates it (OpenCV documentation, *Camera
  Calibration and 3D Reconstruction* (calib3d), "Detailed description")::

      r2 = x^2 + y^2
      R  = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
      xd = x R + 2 p1 x y + p2 (r2 + 2 x^2)
      yd = y R + p1 (r2 + 2 y^2) + 2 p2 x y

- :class:`FisheyeLens`: OpenCV's fisheye (equidistant, Kannala-Brandt) model of
  ``cv2.fisheye`` (OpenCV documentation, *Fisheye camera model*)::

      r = sqrt(x^2 + y^2),  theta = atan(r)
      theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
      xd = (theta_d / r) x,  yd = (theta_d / r) y

  ``cv2.fisheye`` takes a *relative* skew ``alpha`` (u = fx (xd + alpha yd) + cx);
  here ``skew`` is the absolute K[0, 1], so alpha = skew / fx.

OpenCV's calib3d functions (``projectPoints``, ``undistortPoints``) read fx, fy,
cx, cy from the camera matrix and ignore K[0, 1]; with ``skew = 0`` (what
``cv2.calibrateCamera`` always returns) :class:`BrownLens` is OpenCV's model
exactly, with ``skew != 0`` it applies the full K.

Inversion (:meth:`Lens.unproject`): Newton's method on the 2x2 Jacobian of the
Brown distortion, on theta for the fisheye, started at the distorted point and
stopped when the step is below 1e-14 in normalised coordinates. (OpenCV's
``undistortPoints`` uses a fixed-point iteration, which stalls or diverges in
the corners of strongly distorted lenses.) A point whose iteration does not
converge, or converges where the model folds over (Brown: det J <= 0 or a
radial factor R <= 0, which maps the point to the opposite side of the axis;
fisheye: d theta_d / d theta <= 0), or (fisheye) lies at theta >= 90 deg, gives
NaN. These tests are local: a pixel beyond the image of the model's first
monotone branch (outside any sensor the lens was calibrated on) can still
converge to a spurious root where the polynomial rises again.

Compiled kernels: :func:`project_nb` and :func:`unproject_nb` evaluate the same
maths per element inside numba code, with a lens given as its ``code`` and its
parameter vector :meth:`Lens.as_array` (layout :data:`PARAM_LAYOUT`).
The formulas live once, in the ``_*`` functions below that take arrays or
scalars; numba compiles them for scalars.

Undistortion map (the fast path's Brown inverse): :meth:`Lens.kernel_array` is
:meth:`Lens.as_array` followed by a coarse map of the inverse over the sensor (as
OpenCV's ``initUndistortRectifyMap``, but of normalised points; at most
:data:`MAP_NODES` nodes a side, built once per lens by the full Newton inverse and
cached on the lens). :func:`unproject_map_nb` interpolates the map bilinearly and
refines the guess by two Newton steps; Newton converges quadratically, so from the
map's ~1e-5 the second step leaves rounding only, the same root as the full
iteration's to ~1e-16 (``tests/sensors/test_lenses.py`` holds it to :func:`unproject_nb`
over the whole sensor). A pixel off the map, a guess the map does not have (a
node where the inverse fails) or a second step above :data:`MAP_ACCEPT` falls back
to the full iteration, so the result never depends on the map's accuracy.

Per-sample parameters (Monte Carlo): every numeric field may be an array
(``lens.with_params(cx=cx + draws)``); the numpy methods broadcast it over the
batch, element by element. A sample whose parameters are not valid (fx or fy
<= 0, a non-finite value) gives NaN directions (``unproject``) or
``INVALID_INPUT`` (``project``) instead of an exception, as any batch function.
Such a lens has no kernel vector (:meth:`Lens.as_array` refuses it): the fast
path is for one lens.

Status: ``project`` returns a :class:`geoloc.status.Status` per direction:
``OK``, ``BEHIND_CAMERA`` (z <= 0) or ``INVALID_INPUT`` (non-finite input).
Like OpenCV, ``project`` does not flag directions far outside the field of view
which the polynomial folds back into the image; :meth:`Lens.in_image` and the
caller's field-of-view test decide.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

import sys

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..geodesy._nbgeo import cached_njit, dependency_key
from ..status import Status

__all__ = [
    "BROWN",
    "FISHEYE",
    "PARAM_LAYOUT",
    "PINHOLE",
    "BrownLens",
    "FisheyeLens",
    "Lens",
    "PinholeLens",
    "lens_from_dict",
    "lens_from_fov",
    "lens_from_opencv",
    "lens_to_dict",
    "project_nb",
    "unproject_map_lanes",
    "unproject_map_nb",
    "unproject_nb",
]

PINHOLE, BROWN, FISHEYE = 0, 1, 2  #: values of ``Lens.code``

#: Layout of :meth:`Lens.as_array`: fx, fy, cx, cy, skew and the distortion
#: coefficients; a fisheye lens puts its k1..k4 in the k1, k2, k3, k4 slots
#: (indices 5, 6, 9, 10); unused slots are 0.
PARAM_LAYOUT = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
_SLOT = {name: i for i, name in enumerate(PARAM_LAYOUT)}
_N_SLOTS = len(PARAM_LAYOUT)

_MAX_ITER = 50  # Newton iterations at most (5-8 are typical inside a sensor)
_STEP_TOL = 1e-14  # stop when the Newton step (normalised coordinates / radians) is below this
_ACCEPT_TOL = 1e-12  # converged if the last step is below this (Newton is quadratic: what is left is rounding)
_TINY = 1e-300  # guards 0/0 at the optical axis (the ratio it guards is multiplied by 0 there)
_HALF_PI = 0.5 * math.pi

#: Most nodes a side of the undistortion map of :meth:`Lens.kernel_array` (64 x 64 x 2 floats:
#: 64 kB, in cache however the pixels are scattered).
MAP_NODES = 64
#: Largest second Newton step (normalised) that :func:`unproject_map_nb` accepts. Newton's error
#: after a step is about M e^2 with e the error before it and M = |f''| / 2|f'| (of order 1 inside a
#: sensor): a second step below 1e-9 means the point after it is within ~1e-18 of the root, i.e.
#: rounding. Larger (a poor guess): the full iteration decides.
MAP_ACCEPT = 1e-9
_HEADER = 5  # u0, v0, 1 / step, nodes along u, nodes along v (after the PARAM_LAYOUT slots)


# ---------------------------------------------------------------------------
# The maths, once: numpy ufuncs only, so each body runs on arrays (numpy path)
# and numba compiles it for scalars (kernels). p is the as_array() vector.


def _to_pixel(p, xd, yd):
    """Distorted normalised point -> pixel: (u, v) = K (xd, yd, 1)."""
    return p[0] * xd + p[4] * yd + p[2], p[1] * yd + p[3]


def _from_pixel(p, u, v):
    """Pixel -> distorted normalised point: K^-1 (u, v, 1)."""
    yd = (v - p[3]) / p[1]
    return (u - p[2] - p[4] * yd) / p[0], yd


def _brown_distort(p, x, y):
    """Brown-Conrady distortion of (x, y): (xd, yd), the radial factor R(r2) and dR/dr2."""
    k1, k2, p1, p2, k3, k4, k5, k6 = p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12]
    r2 = x * x + y * y
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / den
    d_radial = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) - radial * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / den
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    return xd, yd, radial, d_radial


def _brown_newton_step(p, x, y, xd, yd, radial, d_radial, xt, yt):
    """Newton step for distort(x, y) = (xt, yt), given distort(x, y) = (xd, yd) and R, dR/dr2 at (x, y).

    Returns the step (dx, dy) to subtract and det J of the distortion at (x, y).
    """
    p1, p2 = p[7], p[8]
    g = 2.0 * d_radial
    j11 = radial + g * x * x + 2.0 * p1 * y + 6.0 * p2 * x
    j12 = g * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    j22 = radial + g * y * y + 6.0 * p1 * y + 2.0 * p2 * x
    det = j11 * j22 - j12 * j12  # J is symmetric: j21 = j12
    ex, ey = xd - xt, yd - yt
    return (j22 * ex - j12 * ey) / det, (j11 * ey - j12 * ex) / det, det


def _fisheye_theta_d(p, theta):
    """Fisheye theta_d(theta) = theta (1 + k1 theta^2 + ... + k4 theta^8) and d theta_d / d theta."""
    k1, k2, k3, k4 = p[5], p[6], p[9], p[10]
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    slope = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return theta_d, slope


def _fisheye_scale(theta_d, r):
    """theta_d / r, the factor from the normalised point of radius r to the distorted one."""
    return theta_d / np.maximum(r, _TINY)  # r = 0: theta_d = 0 and the point is (0, 0)


def _fisheye_direction(theta, theta_d, xd, yd):
    """Unit direction at angle theta from the axis through the distorted point (xd, yd) of radius theta_d."""
    s = np.sin(theta) / np.maximum(theta_d, _TINY)  # theta_d = 0: xd = yd = 0
    return s * xd, s * yd, np.cos(theta)


def _unit(x, y):
    """Unit vector along (x, y, 1)."""
    n = np.sqrt(x * x + y * y + 1.0)
    return x / n, y / n, 1.0 / n


#: The lens kernels' cache key (this file's source: geoloc.geodesy._nbgeo.cached_njit), so that
#: they are cached with the others in the user's cache folder, not in a __pycache__ a reinstall deletes.
_KEY = dependency_key(sys.modules[__name__])
_jit = cached_njit(_KEY, inline="always", error_model="numpy")
_to_pixel_nb = _jit(_to_pixel)
_from_pixel_nb = _jit(_from_pixel)
_brown_distort_nb = _jit(_brown_distort)
_brown_newton_step_nb = _jit(_brown_newton_step)
_fisheye_theta_d_nb = _jit(_fisheye_theta_d)
_fisheye_scale_nb = _jit(_fisheye_scale)
_fisheye_direction_nb = _jit(_fisheye_direction)
_unit_nb = _jit(_unit)


@cached_njit(_KEY, error_model="numpy")
def project_nb(code: int, p: NDArray[np.float64], x: float, y: float, z: float) -> tuple[float, float, bool]:
    """Direction (x, y, z) in the optical frame -> pixel (u, v, ok), per element, for numba kernels.

    Parameters
    ----------
    code : int
        ``Lens.code`` (PINHOLE, BROWN, FISHEYE).
    p : ndarray of float64, shape (13,)
        ``Lens.as_array()``.
    x, y, z : float
        Direction, any length.

    Returns
    -------
    u, v : float
        Pixel (OpenCV convention); NaN if not ok.
    ok : bool
        False where z <= 0 (behind the camera) or the input is not finite.
    """
    if not (z > 0.0 and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return np.nan, np.nan, False
    a = x / z
    b = y / z
    if code == BROWN:
        a, b, _, _ = _brown_distort_nb(p, a, b)
    elif code == FISHEYE:
        r = math.hypot(a, b)
        theta_d, _ = _fisheye_theta_d_nb(p, math.atan(r))
        s = _fisheye_scale_nb(theta_d, r)
        a, b = s * a, s * b
    u, v = _to_pixel_nb(p, a, b)
    return u, v, True


@cached_njit(_KEY, error_model="numpy")
def unproject_nb(code: int, p: NDArray[np.float64], u: float, v: float) -> tuple[float, float, float]:
    """Pixel (u, v) -> unit direction (x, y, z) in the optical frame, per element, for numba kernels.

    Same parameters as :func:`project_nb`; NaN where the inversion fails
    (see :meth:`Lens.unproject`).
    """
    xt, yt = _from_pixel_nb(p, u, v)
    if code == BROWN:
        x, y = xt, yt
        step, det, radial = np.inf, 0.0, 0.0
        for _ in range(_MAX_ITER):
            xd, yd, radial, d_radial = _brown_distort_nb(p, x, y)
            dx, dy, det = _brown_newton_step_nb(p, x, y, xd, yd, radial, d_radial, xt, yt)
            x -= dx
            y -= dy
            step = math.hypot(dx, dy)
            if not step > _STEP_TOL:
                break
        if not (step <= _ACCEPT_TOL and det > 0.0 and radial > 0.0):
            return np.nan, np.nan, np.nan
        return _unit_nb(x, y)
    if code == FISHEYE:
        theta_d = math.hypot(xt, yt)
        theta, step, slope = theta_d, np.inf, 0.0
        for _ in range(_MAX_ITER):
            f, slope = _fisheye_theta_d_nb(p, theta)
            dtheta = (f - theta_d) / slope
            theta -= dtheta
            step = abs(dtheta)
            if not step > _STEP_TOL:
                break
        if not (step <= _ACCEPT_TOL and slope > 0.0 and 0.0 <= theta < _HALF_PI):
            return np.nan, np.nan, np.nan
        return _fisheye_direction_nb(theta, theta_d, xt, yt)
    return _unit_nb(xt, yt)


@cached_njit(_KEY, inline="always", error_model="numpy")
def _unproject_map_guess(p, u, v):
    """The bilinear guess of :func:`unproject_map_lanes` from the undistortion map: (x0, y0, inmap).

    ``inmap`` is False where the map does not cover the pixel (NaN included); such a pixel
    reads node (0, 0), so that every lane's memory access stays inside the map.
    """
    n0 = _N_SLOTS
    nu, nv = int(p[n0 + 3]), int(p[n0 + 4])
    gu = (u - p[n0]) * p[n0 + 2]
    gv = (v - p[n0 + 1]) * p[n0 + 2]
    inmap = (gu >= 0.0) & (gu < nu - 1) & (gv >= 0.0) & (gv < nv - 1)  # False for NaN
    gu = gu if inmap else 0.0
    gv = gv if inmap else 0.0
    i, j = int(gv), int(gu)
    fu, fv = gu - j, gv - i
    k = n0 + _HEADER + 2 * (i * nu + j)
    k2 = k + 2 * nu
    x = (1.0 - fv) * ((1.0 - fu) * p[k] + fu * p[k + 2]) + fv * ((1.0 - fu) * p[k2] + fu * p[k2 + 2])
    y = (1.0 - fv) * ((1.0 - fu) * p[k + 1] + fu * p[k + 3]) + fv * ((1.0 - fu) * p[k2 + 1] + fu * p[k2 + 3])
    return x, y, inmap


@cached_njit(_KEY, inline="always", error_model="numpy")
def _unproject_map_refine(p, u, v, x, y, inmap):
    """Two Newton steps of :func:`unproject_map_lanes` from the guess (x, y): (x, y, z, ok).

    ``p`` holds the :data:`PARAM_LAYOUT` slots (an array, or a tuple of them: a kernel passes
    a tuple, whose values stay in registers, so that its loop over pixels has no memory access
    but the pixel's and compiles to SIMD code).
    """
    xt, yt = _from_pixel_nb(p, u, v)
    xd, yd, radial, d_radial = _brown_distort_nb(p, x, y)
    dx, dy, det = _brown_newton_step_nb(p, x, y, xd, yd, radial, d_radial, xt, yt)
    x -= dx
    y -= dy
    xd, yd, radial, d_radial = _brown_distort_nb(p, x, y)
    dx, dy, det = _brown_newton_step_nb(p, x, y, xd, yd, radial, d_radial, xt, yt)
    x -= dx
    y -= dy
    ok = inmap & (abs(dx) + abs(dy) <= MAP_ACCEPT) & (det > 0.0) & (radial > 0.0)
    ux, uy, uz = _unit_nb(x, y)
    return ux, uy, uz, ok


@cached_njit(_KEY, inline="always", error_model="numpy")
def _slots(p):
    """The :data:`PARAM_LAYOUT` slots of ``p`` (all 13 of them) as a tuple (for :func:`_unproject_map_refine`)."""
    return (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12])


@cached_njit(_KEY, inline="always", error_model="numpy")
def unproject_map_lanes(p: NDArray[np.float64], u: float, v: float) -> tuple[float, float, float, bool]:
    """A Brown lens's inverse through its undistortion map, without branches: (x, y, z, ok).

    ``p`` is :meth:`Lens.kernel_array` of a Brown lens. The bilinear guess from the map
    (:func:`_unproject_map_guess`), two Newton steps and the fold tests of the full iteration
    (det J > 0, R > 0; :func:`_unproject_map_refine`); ``ok`` is False where the map does not
    cover the pixel, a node is NaN, or the second step is above :data:`MAP_ACCEPT` (then the
    caller takes :func:`unproject_nb`). Selects instead of branches.
    """
    x, y, inmap = _unproject_map_guess(p, u, v)
    return _unproject_map_refine(p, u, v, x, y, inmap)


@cached_njit(_KEY, error_model="numpy")
def unproject_map_nb(code: int, p: NDArray[np.float64], u: float, v: float) -> tuple[float, float, float]:
    """:func:`unproject_nb` with the undistortion map of :meth:`Lens.kernel_array`, per element.

    ``p`` is :meth:`Lens.kernel_array` (or a plain :meth:`Lens.as_array`, then this is
    :func:`unproject_nb`). For a Brown lens inside the map: :func:`unproject_map_lanes`;
    elsewhere, or where that refuses the pixel, the full iteration.
    """
    if code == BROWN and p.shape[0] > _N_SLOTS:
        x, y, z, ok = unproject_map_lanes(p, u, v)
        if ok:
            return x, y, z
    return unproject_nb(code, p, u, v)


# ---------------------------------------------------------------------------
# Validation helpers


def _bad(field, value, why):
    return ValueError(f"lens field {field} = {value!r}: {why}")


def _real(field, value, positive=False):
    """A finite float (> 0 if positive), else ValueError naming the field and the value."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    value = float(value) if ok else value
    if not (ok and math.isfinite(value) and (value > 0 or not positive)):
        raise _bad(field, value, "must be a finite number > 0" if positive else "must be a finite number")
    return value


def _real_array(field, value):
    """A per-sample parameter: a float64 array of real numbers (its elements' validity is per sample)."""
    a = np.asarray(value)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise _bad(field, value, "must be a number or an array of numbers")
    return a.astype(float)


def _is_batch(value) -> bool:
    return isinstance(value, (np.ndarray, list, tuple)) and np.ndim(value) > 0


def _count(field, value):
    if not (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value > 0):
        raise _bad(field, value, "must be a positive integer")
    return int(value)


# ---------------------------------------------------------------------------
# Lens classes


@dataclass(frozen=True)
class Lens:
    """Common base of the lens models: intrinsics and the API shared by all models.

    Not instantiated itself; use :class:`PinholeLens`, :class:`BrownLens` or
    :class:`FisheyeLens`.

    Attributes
    ----------
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in OpenCV pixels ((0, 0) the centre of the top-left pixel).
    width, height : int
        Sensor size in pixels (columns, rows).
    skew : float
        K[0, 1] in pixels (absolute).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    skew: float = 0.0

    model: ClassVar[str] = ""  #: "pinhole", "brown" or "fisheye"
    code: ClassVar[int] = -1  #: PINHOLE, BROWN or FISHEYE (the kernels' switch)
    coefficients: ClassVar[tuple[str, ...]] = ()  #: distortion coefficient names, OpenCV order

    def __post_init__(self):
        if type(self) is Lens:
            raise TypeError("Lens is the common base; use PinholeLens, BrownLens or FisheyeLens")
        for name in ("fx", "fy", "cx", "cy", "skew", *self.coefficients):
            value = getattr(self, name)
            if _is_batch(value):  # per-sample parameters (Monte Carlo): validity is per element
                object.__setattr__(self, name, _real_array(name, value))
            else:
                object.__setattr__(self, name, _real(name, value, positive=name in ("fx", "fy")))
        for name in ("width", "height"):
            object.__setattr__(self, name, _count(name, getattr(self, name)))

    # ------------------------------------------------------------ parameters
    @property
    def params(self) -> dict[str, float]:
        """Named parameters: fx, fy, cx, cy, skew and the distortion coefficients."""
        return {name: getattr(self, name) for name in ("fx", "fy", "cx", "cy", "skew", *self.coefficients)}

    @property
    def batched(self) -> bool:
        """True when some parameter is a per-sample array (see the module docstring)."""
        return any(isinstance(v, np.ndarray) for v in self.params.values())

    def with_params(self, **changes: Any) -> Lens:
        """A copy with some of :attr:`params` changed (an unknown name raises ValueError).

        A value may be an array (per-sample parameters, broadcasting over the batch of
        :meth:`unproject` / :meth:`project`): how Monte Carlo perturbs the lens.
        """
        unknown = sorted(set(changes) - set(self.params))
        if unknown:
            raise ValueError(f"{self.model} lens has no parameter(s) {unknown}; its parameters: {list(self.params)}")
        return dataclasses.replace(self, **changes)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients in OpenCV's order (empty for the pinhole)."""
        return np.array([getattr(self, name) for name in self.coefficients], dtype=float)

    def as_array(self) -> np.ndarray:
        """Parameter vector for :func:`project_nb` / :func:`unproject_nb` (layout :data:`PARAM_LAYOUT`).

        Raises ValueError for a lens with per-sample parameters (the kernels take one lens).
        """
        if self.batched:
            raise ValueError(
                f"{self.model} lens with per-sample parameter arrays has no kernel vector; "
                "use the numpy path (unproject / project)"
            )
        p = np.zeros(len(PARAM_LAYOUT))
        for name, value in self.params.items():
            p[_SLOT[name]] = value
        return p

    def kernel_array(self) -> np.ndarray:
        """:meth:`as_array`, then (Brown) the undistortion map of :func:`unproject_map_nb`; cached.

        Layout after the :data:`PARAM_LAYOUT` slots: u0, v0 (the map's first node, OpenCV
        pixels), 1 / step (px), nodes along u, nodes along v, then the nodes' undistorted
        normalised (x, y), row by row (NaN where the full inverse fails). The nodes run from
        one step before the sensor's edge (u = -0.5) to one step past the far edge, at most
        :data:`MAP_NODES` a side.
        """
        cached = self.__dict__.get("_kernel_array")
        if cached is None:
            cached = self.as_array()
            if self.code == BROWN:
                cached = np.concatenate([cached, self._undistort_map()])
            cached.flags.writeable = False
            self.__dict__["_kernel_array"] = cached  # frozen dataclass: cache beside the fields
        return cached

    def _undistort_map(self) -> np.ndarray:
        step = max(self.width, self.height) / (MAP_NODES - 3)
        nu = min(MAP_NODES, math.ceil((self.width + 2 * step) / step) + 1)
        nv = min(MAP_NODES, math.ceil((self.height + 2 * step) / step) + 1)
        u0, v0 = -0.5 - step, -0.5 - step
        u, v = np.meshgrid(u0 + step * np.arange(nu), v0 + step * np.arange(nv))
        d = self.unproject(u, v)
        with np.errstate(all="ignore"):
            xy = d[..., :2] / d[..., 2:]
        return np.concatenate([[u0, v0, 1.0 / step, nu, nv], xy.reshape(-1)])

    def _p(self):
        """The :data:`PARAM_LAYOUT` slots for the numpy formulas: floats, or per-sample arrays."""
        if not self.batched:
            return self.as_array()
        p = [0.0] * len(PARAM_LAYOUT)
        for name, value in self.params.items():
            p[_SLOT[name]] = value
        return tuple(p)

    def _invalid(self):
        """Per-sample: True where the parameters are not a valid lens (False for a scalar lens)."""
        if not self.batched:
            return False
        bad = ~(np.asarray(self.fx) > 0) | ~(np.asarray(self.fy) > 0)
        for value in self.params.values():
            bad = bad | ~np.isfinite(value)
        return bad

    # -------------------------------------------------------------- geometry
    def project(self, dirs: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions in the optical frame -> pixels.

        Parameters
        ----------
        dirs : array_like (..., 3)
            Directions (x right, y down, z forward), any length.

        Returns
        -------
        u, v : ndarray (...)
            Pixel coordinates (OpenCV convention); NaN unless the status is OK.
        status : ndarray of uint8 (...)
            ``Status.OK``, ``Status.BEHIND_CAMERA`` (z <= 0) or
            ``Status.INVALID_INPUT`` (a non-finite component).
        """
        d = np.asarray(dirs, dtype=float)
        finite = np.isfinite(d).all(axis=-1) & ~self._invalid()
        front = finite & (d[..., 2] > 0)
        p = self._p()
        with np.errstate(all="ignore"):
            z = np.where(front, d[..., 2], np.nan)
            xd, yd = self._distort(p, d[..., 0] / z, d[..., 1] / z)
            u, v = _to_pixel(p, xd, yd)
        u, v = np.where(front, u, np.nan), np.where(front, v, np.nan)
        status = np.where(front, Status.OK, np.where(finite, Status.BEHIND_CAMERA, Status.INVALID_INPUT))
        return u, v, status.astype(np.uint8)

    def unproject(self, u: ArrayLike, v: ArrayLike) -> np.ndarray:
        """Pixels -> unit directions in the optical frame.

        Parameters
        ----------
        u, v : array_like
            Pixel coordinates (OpenCV convention), broadcasting.

        Returns
        -------
        ndarray (..., 3)
            Unit directions; NaN where the inversion of the distortion does
            not converge to a valid point (see the module docstring).
        """
        bad = self._invalid()
        u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float), bad)[:2]
        p = self._p()
        with np.errstate(all="ignore"):
            x, y, z = self._undistort(p, *_from_pixel(p, u, v))
        d = np.stack(np.broadcast_arrays(x, y, z), axis=-1)
        return np.where(np.asarray(bad)[..., None], np.nan, d) if self.batched else d

    def in_image(self, u: ArrayLike, v: ArrayLike) -> np.ndarray:
        """True where (u, v) lies on the sensor: -0.5 <= u <= width - 0.5, -0.5 <= v <= height - 0.5."""
        u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
        return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)

    # ---------------------------------------------------- per-model hooks
    def _distort(self, p, x, y):
        """Normalised (x, y) -> distorted normalised (arrays)."""
        return x, y

    def _undistort(self, p, xt, yt):
        """Distorted normalised (arrays) -> unit direction components (NaN where it fails)."""
        return _unit(xt, yt)


@dataclass(frozen=True)
class PinholeLens(Lens):
    """Distortion-free pinhole: u = fx x + skew y + cx, v = fy y + cy, (x, y) = (X/Z, Y/Z)."""

    model: ClassVar[str] = "pinhole"
    code: ClassVar[int] = PINHOLE


@dataclass(frozen=True)
class BrownLens(Lens):
    """OpenCV's rational Brown-Conrady lens (cv2.projectPoints, distortion (k1, k2, p1, p2, k3, k4, k5, k6)).

    Attributes
    ----------
    k1, k2, k3 : float
        Radial numerator coefficients.
    k4, k5, k6 : float
        Radial denominator coefficients (OpenCV's CALIB_RATIONAL_MODEL).
    p1, p2 : float
        Tangential (decentring) coefficients.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0

    model: ClassVar[str] = "brown"
    code: ClassVar[int] = BROWN
    coefficients: ClassVar[tuple[str, ...]] = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")

    def _distort(self, p, x, y):
        xd, yd, _, _ = _brown_distort(p, x, y)
        return xd, yd

    def _undistort(self, p, xt, yt):
        # Newton on the 2x2 Jacobian, all points at once; stops when every point's step is tiny
        # (NaN steps of failed points do not hold the loop: NaN > tol is False).
        x, y = xt.copy(), yt.copy()
        step = det = radial = np.full(xt.shape, np.nan)
        for _ in range(_MAX_ITER):
            xd, yd, radial, d_radial = _brown_distort(p, x, y)
            dx, dy, det = _brown_newton_step(p, x, y, xd, yd, radial, d_radial, xt, yt)
            x, y = x - dx, y - dy
            step = np.hypot(dx, dy)
            if not np.any(step > _STEP_TOL):
                break
        ok = (step <= _ACCEPT_TOL) & (det > 0) & (radial > 0)
        return tuple(np.where(ok, c, np.nan) for c in _unit(x, y))


@dataclass(frozen=True)
class FisheyeLens(Lens):
    """OpenCV's fisheye lens (cv2.fisheye; equidistant with theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)).

    ``skew`` is the absolute K[0, 1]; cv2.fisheye's ``alpha`` is skew / fx.
    Directions at theta >= 90 deg (z <= 0) are outside this implementation's
    domain (project: BEHIND_CAMERA; unproject: NaN).
    """

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0

    model: ClassVar[str] = "fisheye"
    code: ClassVar[int] = FISHEYE
    coefficients: ClassVar[tuple[str, ...]] = ("k1", "k2", "k3", "k4")

    def _distort(self, p, x, y):
        r = np.hypot(x, y)
        theta_d, _ = _fisheye_theta_d(p, np.arctan(r))
        s = _fisheye_scale(theta_d, r)
        return s * x, s * y

    def _undistort(self, p, xt, yt):
        theta_d = np.hypot(xt, yt)
        theta = theta_d.copy()
        step = slope = np.full(xt.shape, np.nan)
        for _ in range(_MAX_ITER):
            f, slope = _fisheye_theta_d(p, theta)
            dtheta = (f - theta_d) / slope
            theta = theta - dtheta
            step = np.abs(dtheta)
            if not np.any(step > _STEP_TOL):
                break
        ok = (step <= _ACCEPT_TOL) & (slope > 0) & (theta >= 0) & (theta < _HALF_PI)
        return tuple(np.where(ok, c, np.nan) for c in _fisheye_direction(theta, theta_d, xt, yt))


_MODELS = {cls.model: cls for cls in (PinholeLens, BrownLens, FisheyeLens)}


# ---------------------------------------------------------------------------
# Constructors


def lens_from_fov(
    hfov: float, vfov: float, width: int, height: int, cx: float | None = None, cy: float | None = None
) -> PinholeLens:
    """Pinhole lens from its fields of view.

    Parameters
    ----------
    hfov, vfov : float
        Full horizontal / vertical field of view [rad], in (0, pi), measured
        between the outer edges of the sensor (u = -0.5 and u = width - 0.5).
    width, height : int
        Sensor size in pixels.
    cx, cy : float, optional
        Principal point (OpenCV pixels); default the image centre
        ((width - 1) / 2, (height - 1) / 2).

    Returns
    -------
    PinholeLens
        fx = (width / 2) / tan(hfov / 2), fy = (height / 2) / tan(vfov / 2).
    """
    for name, value in (("hfov", hfov), ("vfov", vfov)):
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not (ok and 0.0 < value < math.pi):
            raise _bad(name, value, "must be a field of view in (0, pi) radians")
    width, height = _count("width", width), _count("height", height)
    return PinholeLens(
        fx=(width / 2.0) / math.tan(hfov / 2.0),
        fy=(height / 2.0) / math.tan(vfov / 2.0),
        cx=(width - 1) / 2.0 if cx is None else cx,
        cy=(height - 1) / 2.0 if cy is None else cy,
        width=width,
        height=height,
    )


def lens_from_opencv(
    camera_matrix: ArrayLike, dist_coeffs: ArrayLike | None, image_size: tuple[int, int], model: str = "brown"
) -> Lens:
    """Lens from OpenCV's calibration results.

    Parameters
    ----------
    camera_matrix : array_like (3, 3)
        K as ``cv2.calibrateCamera`` / ``cv2.fisheye.calibrate`` return it
        (K[0, 1] the absolute skew; last row [0, 0, 1]).
    dist_coeffs : array_like or None
        ``model="brown"``: 4, 5 or 8 values (k1, k2, p1, p2[, k3[, k4, k5, k6]]),
        or none (all zero). ``model="fisheye"``: exactly 4 (k1..k4). 12 or 14
        values (thin prism, tilted sensor) are not supported.
    image_size : (int, int)
        (width, height), as OpenCV gives it.
    model : {"brown", "fisheye"}

    Returns
    -------
    BrownLens or FisheyeLens
    """
    K = np.asarray(camera_matrix, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or np.any(K[[1, 2, 2], [0, 0, 1]] != 0) or K[2, 2] != 1:
        raise ValueError(f"camera matrix {K.tolist()}: must be 3x3 [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]")
    d = np.zeros(0) if dist_coeffs is None else np.asarray(dist_coeffs, dtype=float).ravel()
    try:
        width, height = image_size
    except (TypeError, ValueError):
        raise ValueError(f"image size {image_size!r}: must be (width, height)") from None
    cls: type[BrownLens] | type[FisheyeLens]
    if model == "brown":
        if len(d) not in (0, 4, 5, 8):
            raise ValueError(
                f"distortion coefficients {d.tolist()}: {len(d)} values are not supported "
                "(brown takes 4, 5 or 8: k1, k2, p1, p2[, k3[, k4, k5, k6]]; "
                "thin prism (12) and tilt (14) models are not supported)"
            )
        cls, d = BrownLens, np.concatenate([d, np.zeros(8 - len(d))])
    elif model == "fisheye":
        if len(d) != 4:
            raise ValueError(f"distortion coefficients {d.tolist()}: the fisheye model takes exactly 4 (k1..k4)")
        cls = FisheyeLens
    else:
        raise ValueError(f"lens model {model!r}: must be 'brown' or 'fisheye'")
    coeffs = {name: float(c) for name, c in zip(cls.coefficients, d)}
    return cls(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], skew=K[0, 1], width=width, height=height, **coeffs)


# ---------------------------------------------------------------------------
# The [lens] table of a sensor file (project pixel convention: 1-based)

_FILE_KEYS = {
    "pinhole": ("fx", "fy", "cx", "cy", "width", "height", "skew"),
    "brown": ("fx", "fy", "cx", "cy", "width", "height", "skew", *BrownLens.coefficients),
    "fisheye": ("fx", "fy", "cx", "cy", "width", "height", "skew", *FisheyeLens.coefficients),
    "fov": ("hfov_deg", "vfov_deg", "width", "height", "cx", "cy"),
}
_REQUIRED = {"pinhole": 6, "brown": 6, "fisheye": 6, "fov": 4}  # the first n keys of _FILE_KEYS


def lens_from_dict(data: dict, source: str = "lens") -> Lens:
    """Lens from the ``[lens]`` table of a sensor file.

    Keys: ``model`` ("pinhole", "brown", "fisheye" or "fov") and

    - pinhole / brown / fisheye: ``fx, fy, cx, cy, width, height`` (required),
      ``skew`` and the model's coefficients (brown: k1..k6, p1, p2; fisheye:
      k1..k4) (optional, default 0);
    - fov: ``hfov_deg, vfov_deg, width, height`` (required), ``cx, cy``
      (optional, default the image centre).

    ``cx`` (a column) and ``cy`` (a row) are in the project's 1-based pixel
    convention (the centre of the top-left pixel is (1, 1),
    ``docs/conventions.md``): the lens gets cx - 1, cy - 1.

    Raises
    ------
    ValueError
        Unknown, missing or wrongly typed keys, keys the model does not take,
        invalid values; the message names the key, the value and ``source``.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{source}: lens table {data!r}: must be a table of keys")  # noqa: TRY004 (file error)
    model = data.get("model")
    if model not in _FILE_KEYS:
        what = "missing" if "model" not in data else f"= {model!r}"
        raise ValueError(f"{source}: lens key model {what}: must be one of {list(_FILE_KEYS)}")
    keys = _FILE_KEYS[model]
    for key, value in data.items():
        if key != "model" and key not in keys:
            raise ValueError(
                f"{source}: lens key {key} = {value!r}: not a key of a {model} lens (allowed: {list(keys)})"
            )
        integral = key in ("width", "height")
        if key != "model" and (isinstance(value, bool) or not isinstance(value, int if integral else (int, float))):
            raise ValueError(
                f"{source}: lens key {key} = {value!r}: must be {'an integer' if integral else 'a number'}"
            )
    missing = [k for k in keys[: _REQUIRED[model]] if k not in data]
    if missing:
        raise ValueError(
            f"{source}: lens key(s) {missing} missing (a {model} lens needs {list(keys[: _REQUIRED[model]])})"
        )
    for k in ("hfov_deg", "vfov_deg"):
        if k in data and not 0 < data[k] < 180:
            raise ValueError(f"{source}: lens key {k} = {data[k]!r}: must be a field of view in (0, 180) degrees")
    values = {k: v for k, v in data.items() if k != "model"}
    for k in ("cx", "cy"):
        if k in values:
            values[k] = values[k] - 1.0
    try:
        if model == "fov":
            return lens_from_fov(math.radians(values.pop("hfov_deg")), math.radians(values.pop("vfov_deg")), **values)
        return _MODELS[model](**values)
    except ValueError as e:
        raise ValueError(f"{source}: {e}") from None


def lens_to_dict(lens: Lens) -> dict:
    """The ``[lens]`` table of :func:`lens_from_dict` for ``lens`` (cx, cy 1-based)."""
    out: dict[str, Any] = {"model": lens.model, **lens.params, "width": lens.width, "height": lens.height}
    out["cx"] += 1.0
    out["cy"] += 1.0
    return out
