"""Fused numba kernel for :func:`geoloc.locate.locate` on the inflated ellipsoid, for any frame sensor.

The same mathematics as the numpy reference path (lens -> frame graph -> line
of sight -> [Q17 eq. 10-11] -> Vermeille), written per ray so that a million
rays cost one pass over memory instead of ~100 temporary arrays. The chain is
passed as data, not code: the lens as a model code and its parameter vector
(:meth:`geoloc.sensors.lenses.Lens.as_array`), the gimbal joints as axis codes
with one column of angles each, the boresight/optical turn and the mount as
3x3 matrices, the lever arm as a vector, and a flag for earth-referenced
gimbals. So every preset, lens, mount, boresight and lever arm runs compiled
(no silent fallback). ``tests/test_fastlocate.py`` holds it equal to the
reference path, ray for ray.

The ellipsoid constants are arguments too, so a cached compile never keeps a
stale constant.

What makes it fast (``benchmarks/bench_locate.py``; each step checked against the
numpy reference path by ``tests/test_fastlocate.py``):

- the lens is passed as :meth:`geoloc.sensors.lenses.Lens.kernel_array`: for a
  Brown lens its undistortion map, so the inverse is a bilinear guess and two
  Newton steps (:func:`geoloc.sensors.lenses.unproject_map_nb`) instead of a
  full iteration from the distorted point (5-8 steps);
- every angle's sine and cosine come from one range reduction and two short
  polynomials (:func:`sincos`, fdlibm's kernels; within 1.2e-16 of libm's
  values for the angles a pose may hold), and the attitude's six are computed
  once per ray and shared by the line of sight and the lever arm;
- ECEF -> geodetic is Vermeille's closed form with ``sqrt`` for ``hypot`` (no
  overflow is possible at Earth's scale) and one ``atan`` for the latitude's
  ``atan2`` (its second argument d + sqrt(d^2 + z^2) is > 0 off the Earth's
  centre) (:func:`geodetic_fast`).

Why numba: the numpy path is bound by temporaries; see ``benchmarks/bench_locate.py``.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import prange

from geoloc import status as _status_module
from geoloc.geodesy import _nbgeo
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, geodetic  # noqa: F401 (geodetic: public helper)
from geoloc.geodesy.ellipsoid import E2, A, B
from geoloc.sensors import lenses as _lenses_module
from geoloc.sensors.lenses import unproject_map_nb, unproject_nb  # noqa: F401 (unproject_nb: public helper)
from geoloc.status import Status

#: The kernel's cache key: the constants and the sources of every module whose compiled code it
#: calls (numba keys a cache on the kernel's own source only, so a changed callee would go stale).
KEY = dependency_key(_nbgeo, _status_module, _lenses_module, sys.modules[__name__])

_OK = int(Status.OK)
_SKY = int(Status.SKY)
_BELOW = int(Status.ORIGIN_BELOW)
_INVALID = int(Status.INVALID_INPUT)
_OUTSIDE = int(Status.OUTSIDE_SENSOR)

_AXIS = {"x": 0, "y": 1, "z": 2}


@cached_njit(KEY, inline="always")
def _in(v, lo, hi):
    return math.isfinite(v) and lo <= v <= hi


@cached_njit(KEY, inline="always")
def _turn_back_cs(axis, c, s, x, y, z):
    """:func:`_turn_back` with the angle's cosine and sine given."""
    if axis == 0:
        return x, c * y - s * z, s * y + c * z
    if axis == 1:
        return c * x + s * z, y, -s * x + c * z
    return c * x - s * y, s * x + c * y, z


@cached_njit(KEY, inline="always")
def _turn_back(axis, a, x, y, z):
    """The transpose of the passive elementary rotation about ``axis`` by ``a``, applied to (x, y, z)."""
    return _turn_back_cs(axis, math.cos(a), math.sin(a), x, y, z)


@cached_njit(KEY, inline="always")
def _mul_T(R, x, y, z):
    """R^T (x, y, z) for a 3x3 R."""
    return (R[0, 0] * x + R[1, 0] * y + R[2, 0] * z,
            R[0, 1] * x + R[1, 1] * y + R[2, 1] * z,
            R[0, 2] * x + R[1, 2] * y + R[2, 2] * z)


@cached_njit(KEY, inline="always")
def _body_to_ned(heading, pitch, roll, x, y, z):
    """(rx(roll) ry(pitch) rz(heading))^T (x, y, z) [Q17 eq. 6, transposed]."""
    x, y, z = _turn_back(0, roll, x, y, z)
    x, y, z = _turn_back(1, pitch, x, y, z)
    return _turn_back(2, heading, x, y, z)


# fdlibm's (and musl's) __sin / __cos kernels on [-pi/4, pi/4] (Sun Microsystems, 1993;
# errors below 1 ulp there) and its medium-size Cody-Waite reduction by pi/2 in two parts.
_INV_PIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e+00  # first 33 bits of pi/2: fn * _PIO2_1 is exact for |fn| < 2^20
_PIO2_1T = 6.07710050650619224932e-11  # pi/2 - _PIO2_1
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
_SINCOS_MAX = 64.0  # beyond (never for a valid pose: its angles are within 2 pi), libm's sin and cos


@cached_njit(KEY, inline="always", error_model="numpy")
def sincos(a):
    """(sin a, cos a) with one range reduction; absolute error < 2e-16 for |a| <= 64 (libm beyond, and NaN).

    ``tests/test_fastlocate.py`` holds it to numpy's sin and cos.
    """
    if not abs(a) <= _SINCOS_MAX:
        return math.sin(a), math.cos(a)
    fn = math.floor(a * _INV_PIO2 + 0.5)
    r = (a - fn * _PIO2_1) - fn * _PIO2_1T
    z = r * r
    w = z * z
    s = r + z * r * (_S1 + z * (_S2 + z * (_S3 + z * _S4) + z * w * (_S5 + z * _S6)))
    cr = z * (_C1 + z * (_C2 + z * _C3)) + w * w * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    ww = 1.0 - hz
    c = ww + (((1.0 - ww) - hz) + z * cr)
    q = int(fn) & 3  # the quadrant (branches measured faster than selects here, random angles too)
    if q == 0:
        return s, c
    if q == 1:
        return c, -s
    if q == 2:
        return -s, -c
    return -c, s


@cached_njit(KEY, inline="always")
def _body_to_ned_cs(ch, sh, cp, sp, cr, sr, x, y, z):
    """:func:`_body_to_ned` with the cosines and sines of heading, pitch and roll given."""
    y, z = cr * y - sr * z, sr * y + cr * z
    x, z = cp * x + sp * z, -sp * x + cp * z
    return ch * x - sh * y, sh * x + ch * y, z


@cached_njit(KEY, inline="always", error_model="numpy")
def geodetic_fast(x, y, z, a_m, e2):
    """ECEF -> (lat, lon, h): Vermeille's closed form as :func:`geoloc.geodesy.ellipsoid.vermeille`.

    The same formulas with ``sqrt(d^2 + z^2)`` for ``hypot`` and ``2 atan(z / (d + dz))`` for
    ``2 atan2(z, d + dz)`` (d + dz > 0 off the Earth's centre): the same values to a few ulps,
    held to ``ecef_to_geodetic`` by ``tests/test_fastlocate.py``.
    """
    e4 = e2 * e2
    rho2 = x * x + y * y
    rho = math.sqrt(rho2)
    p = rho2 / (a_m * a_m)
    q = (1.0 - e2) * z * z / (a_m * a_m)
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r * r * r)
    t = np.cbrt(1.0 + s + math.sqrt(s * (2.0 + s)))
    u = r * (1.0 + t + 1.0 / t)
    v = math.sqrt(u * u + e4 * q)
    w = e2 * (u + v - q) / (2.0 * v)
    k = math.sqrt(u + v + w * w) - w
    d = k * rho / (k + e2)
    dz = math.sqrt(d * d + z * z)
    lat = 2.0 * math.atan(z / (d + dz))
    h = (k + e2 - 1.0) / k * dz
    lon = math.atan2(y, x)
    return lat, lon, h


@cached_njit(KEY, parallel=True, error_model="numpy")
def locate_kernel(lat, lon, h, heading, pitch, roll, angles, row, col, target_h,
                  lens_code, lens_p, width, height, flag_off, axes, R_cam_last, has_mount, R_base_body, lever, earth_ref,
                  ranges, angle_lo, angle_hi, a_m, b_m, e2,
                  out_lat, out_lon, out_h, out_ecef, out_s, out_o, out_d, out_status):
    n = lat.shape[0]
    nj = axes.shape[0]
    has_lever = lever[0] != 0.0 or lever[1] != 0.0 or lever[2] != 0.0
    for k in prange(n):
        ok = (_in(lat[k], ranges[0, 0], ranges[0, 1]) and _in(lon[k], ranges[1, 0], ranges[1, 1])
              and _in(h[k], ranges[2, 0], ranges[2, 1])
              and _in(heading[k], ranges[3, 0], ranges[3, 1])
              and _in(pitch[k], ranges[4, 0], ranges[4, 1]) and _in(roll[k], ranges[5, 0], ranges[5, 1])
              and math.isfinite(row[k]) and math.isfinite(col[k]))
        for j in range(nj):
            if not _in(angles[k, j], angle_lo[j], angle_hi[j]):
                ok = False
        inside = (not flag_off) or ((0.5 <= row[k] <= height + 0.5) and (0.5 <= col[k] <= width + 0.5))
        # pixel (1-based) -> optical frame (OpenCV's 0-based u, v); lens_p may carry the
        # undistortion map (Lens.kernel_array), else this is unproject_nb
        x, y, z = unproject_map_nb(lens_code, lens_p, col[k] - 1.0, row[k] - 1.0)
        # optical -> last joint frame -> ... -> gimbal base (or NED)
        x, y, z = _mul_T(R_cam_last, x, y, z)
        for j in range(nj - 1, -1, -1):
            sj, cj = sincos(angles[k, j])
            x, y, z = _turn_back_cs(axes[j], cj, sj, x, y, z)
        # the attitude's sines and cosines, once for the line of sight and the lever arm
        sh, ch = sincos(heading[k])
        sa, ca = sincos(pitch[k])
        sr, cr = sincos(roll[k])
        if not earth_ref:
            if has_mount:
                x, y, z = _mul_T(R_base_body, x, y, z)
            x, y, z = _body_to_ned_cs(ch, sh, ca, sa, cr, sr, x, y, z)
        # NED -> ECEF: columns N, E, D [Q17 eq. 5]
        sp, cp = sincos(lat[k])
        sl, cl = sincos(lon[k])
        dx = -sp * cl * x - sl * y - cp * cl * z
        dy = -sp * sl * x + cl * y - cp * sl * z
        dz = cp * x - sp * z
        rn = a_m / math.sqrt(1.0 - e2 * sp * sp)
        ox = (rn + h[k]) * cp * cl
        oy = (rn + h[k]) * cp * sl
        oz = (rn * (1.0 - e2) + h[k]) * sp
        if has_lever:
            lx, ly, lz = _body_to_ned_cs(ch, sh, ca, sa, cr, sr, lever[0], lever[1], lever[2])
            ox += -sp * cl * lx - sl * ly - cp * cl * lz
            oy += -sp * sl * lx + cl * ly - cp * sl * lz
            oz += cp * lx - sp * lz
        out_o[k, 0], out_o[k, 1], out_o[k, 2] = ox, oy, oz
        out_d[k, 0], out_d[k, 1], out_d[k, 2] = dx, dy, dz
        # ray x inflated ellipsoid [Q17 eq. 10-11]
        ht = target_h[k]
        aa = a_m + ht
        bb = b_m + ht
        if not (math.isfinite(ht) and bb > 0.0 and math.isfinite(dx)):
            ok = False
        status = _OK
        sol = math.nan
        if not ok:
            status = _INVALID
        elif not inside:
            status = _OUTSIDE
        else:
            opx, opy, opz = ox / aa, oy / aa, oz / bb
            dpx, dpy, dpz = dx / aa, dy / aa, dz / bb
            qa = dpx * dpx + dpy * dpy + dpz * dpz
            qb = 2.0 * (opx * dpx + opy * dpy + opz * dpz)
            qc = opx * opx + opy * opy + opz * opz - 1.0
            disc = qb * qb - 4.0 * qa * qc
            if qc < 0.0:
                status = _BELOW
            elif disc < 0.0 or qb >= 0.0:
                status = _SKY
            else:
                q = -0.5 * (qb - math.sqrt(disc))
                sol = min(q / qa, qc / q)
        out_status[k] = status
        if status != _OK:
            sol = math.nan
        out_s[k] = sol
        px, py, pz = ox + sol * dx, oy + sol * dy, oz + sol * dz
        out_ecef[k, 0], out_ecef[k, 1], out_ecef[k, 2] = px, py, pz
        if status != _OK:
            out_lat[k] = math.nan
            out_lon[k] = math.nan
            out_h[k] = math.nan
            continue
        # ECEF -> geodetic, Vermeille's closed form (as geoloc.geodesy.ellipsoid.ecef_to_geodetic)
        out_lat[k], out_lon[k], out_h[k] = geodetic_fast(px, py, pz, a_m, e2)


def _col(a, shape):
    """A C-contiguous, writable float64 copy-or-view of ``a`` broadcast to ``shape``, flattened.

    Always the same array type, so numba compiles the kernel once (a readonly
    broadcast view would be a second signature).
    """
    a = np.asarray(a, float)
    if a.shape == shape and a.flags.c_contiguous and a.flags.writeable:
        return a.reshape(-1)  # already the kernel's array type: no copy
    return np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1)  # broadcast views are read-only: copy


def _lens_vector(lens) -> np.ndarray:
    """The kernel's lens vector: :meth:`Lens.kernel_array` (with a Brown lens's undistortion map), writable.

    A writable copy so that the kernel keeps one signature (the cached array is read-only).
    """
    return np.array(lens.kernel_array(), float)


def locate_fast(pose, sensor, row, col, target_h, outside="flag"):
    """Run :func:`locate_kernel` for a :class:`geoloc.sensors.frame.FrameSensor`; arrays shaped like the batch.

    Returns
    -------
    lat, lon, h, ecef, slant_range, status, origin_ecef, direction_ecef
    """
    names = sensor.angle_names
    angles = [pose.angle(a) for a in names]
    fields = [pose.lat, pose.lon, pose.h, pose.heading, pose.pitch, pose.roll, row, col, target_h, *angles]
    shape = np.broadcast_shapes(*(np.shape(v) for v in fields))
    flat = [_col(v, shape) for v in fields[:9]]
    n = flat[0].size
    ang = np.empty((n, len(names)))
    for j, a in enumerate(angles):
        ang[:, j] = np.broadcast_to(np.asarray(a, float), shape).reshape(-1)
    has_mount = not np.array_equal(sensor.R_base_body, np.eye(3))
    ranges = np.array([pose.RANGES[k] for k in ("lat", "lon", "h", "heading", "pitch", "roll")], dtype=float)
    lo = np.array([pose.RANGES.get(a, pose.ANGLE_RANGE)[0] for a in names], dtype=float)
    hi = np.array([pose.RANGES.get(a, pose.ANGLE_RANGE)[1] for a in names], dtype=float)
    axes = np.array([_AXIS[j.axis] for j in sensor.gimbal.joints], dtype=np.int64)
    out_lat, out_lon, out_h, out_s = (np.empty(n) for _ in range(4))
    out_ecef, out_o, out_d = (np.empty((n, 3)) for _ in range(3))
    out_status = np.empty(n, dtype=np.uint8)
    lens = sensor.lens
    locate_kernel(*flat[:6], ang, *flat[6:], int(lens.code), _lens_vector(lens),
                  float(lens.width), float(lens.height), outside == "flag", axes,
                  np.ascontiguousarray(sensor.R_cam_last), has_mount, np.ascontiguousarray(sensor.R_base_body),
                  np.array(sensor.lever_arm_m, float), bool(sensor.gimbal.earth_referenced),
                  ranges, lo, hi, float(A), float(B), float(E2),
                  out_lat, out_lon, out_h, out_ecef, out_s, out_o, out_d, out_status)
    return (out_lat.reshape(shape), out_lon.reshape(shape), out_h.reshape(shape),
            out_ecef.reshape(shape + (3,)), out_s.reshape(shape), out_status.reshape(shape),
            out_o.reshape(shape + (3,)), out_d.reshape(shape + (3,)))
