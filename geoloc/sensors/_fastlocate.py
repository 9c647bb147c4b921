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

Why numba: the numpy path is bound by temporaries; see ``benchmarks/bench_locate.py``.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import prange

from geoloc import status as _status_module
from geoloc.geodesy import _nbgeo
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, geodetic
from geoloc.geodesy.ellipsoid import E2, A, B
from geoloc.sensors import lenses as _lenses_module
from geoloc.sensors.lenses import unproject_nb
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
def _turn_back(axis, a, x, y, z):
    """The transpose of the passive elementary rotation about ``axis`` by ``a``, applied to (x, y, z)."""
    c, s = math.cos(a), math.sin(a)
    if axis == 0:
        return x, c * y - s * z, s * y + c * z
    if axis == 1:
        return c * x + s * z, y, -s * x + c * z
    return c * x - s * y, s * x + c * y, z


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


@cached_njit(KEY, parallel=True)
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
        # pixel (1-based) -> optical frame (OpenCV's 0-based u, v)
        x, y, z = unproject_nb(lens_code, lens_p, col[k] - 1.0, row[k] - 1.0)
        # optical -> last joint frame -> ... -> gimbal base (or NED)
        x, y, z = _mul_T(R_cam_last, x, y, z)
        for j in range(nj - 1, -1, -1):
            x, y, z = _turn_back(axes[j], angles[k, j], x, y, z)
        if not earth_ref:
            if has_mount:
                x, y, z = _mul_T(R_base_body, x, y, z)
            x, y, z = _body_to_ned(heading[k], pitch[k], roll[k], x, y, z)
        # NED -> ECEF: columns N, E, D [Q17 eq. 5]
        sp, cp = math.sin(lat[k]), math.cos(lat[k])
        sl, cl = math.sin(lon[k]), math.cos(lon[k])
        dx = -sp * cl * x - sl * y - cp * cl * z
        dy = -sp * sl * x + cl * y - cp * sl * z
        dz = cp * x - sp * z
        rn = a_m / math.sqrt(1.0 - e2 * sp * sp)
        ox = (rn + h[k]) * cp * cl
        oy = (rn + h[k]) * cp * sl
        oz = (rn * (1.0 - e2) + h[k]) * sp
        if has_lever:
            lx, ly, lz = _body_to_ned(heading[k], pitch[k], roll[k], lever[0], lever[1], lever[2])
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
        out_lat[k], out_lon[k], out_h[k] = geodetic(px, py, pz)


def _col(a, shape):
    """A C-contiguous, writable float64 copy-or-view of ``a`` broadcast to ``shape``, flattened.

    Always the same array type, so numba compiles the kernel once (a readonly
    broadcast view would be a second signature).
    """
    a = np.asarray(a, float)
    if a.shape == shape and a.flags.c_contiguous and a.flags.writeable:
        return a.reshape(-1)  # already the kernel's array type: no copy
    return np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1)  # broadcast views are read-only: copy


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
    locate_kernel(*flat[:6], ang, *flat[6:], int(lens.code), np.ascontiguousarray(lens.as_array(), float),
                  float(lens.width), float(lens.height), outside == "flag", axes,
                  np.ascontiguousarray(sensor.R_cam_last), has_mount, np.ascontiguousarray(sensor.R_base_body),
                  np.array(sensor.lever_arm_m, float), bool(sensor.gimbal.earth_referenced),
                  ranges, lo, hi, float(A), float(B), float(E2),
                  out_lat, out_lon, out_h, out_ecef, out_s, out_o, out_d, out_status)
    return (out_lat.reshape(shape), out_lon.reshape(shape), out_h.reshape(shape),
            out_ecef.reshape(shape + (3,)), out_s.reshape(shape), out_status.reshape(shape),
            out_o.reshape(shape + (3,)), out_d.reshape(shape + (3,)))
