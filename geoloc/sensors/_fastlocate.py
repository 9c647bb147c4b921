"""Fused numba kernel for :func:`geoloc.locate.locate` on the inflated ellipsoid.

The same mathematics as the numpy reference path (FrameChain -> line of
sight -> [Q17 eq. 10-11] -> Vermeille), written per ray so that a million
rays cost one pass over memory instead of ~100 temporary arrays. The vector
is rotated hop by hop (camera -> outer gimbal -> body -> NED -> ECEF) with the
transposes of the passive elementary rotations of ``docs/conventions.md``.
``tests/test_fastlocate.py`` checks it against the reference path.

Why numba: the numpy path is bound by temporaries (3.5 s for 1 M rays on the
2-core machine, 0.28 M rays/s); the fused kernel removes them. See
``benchmarks/bench_locate.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from geoloc.geodesy._nbgeo import geodetic
from geoloc.geodesy.ellipsoid import E2, A, B
from geoloc.status import Status

_OK = int(Status.OK)
_SKY = int(Status.SKY)
_BELOW = int(Status.ORIGIN_BELOW)
_INVALID = int(Status.INVALID_INPUT)


@njit(cache=True, inline="always")
def _in(v, lo, hi):
    return math.isfinite(v) and lo <= v <= hi


@njit(parallel=True, cache=True)
def locate_kernel(lat, lon, h, heading, pitch, roll, groll, gpitch, row, col, target_h,
                  f, i0, j0, ranges, out_lat, out_lon, out_h, out_ecef, out_s, out_o, out_d,
                  out_status):
    n = lat.shape[0]
    for k in prange(n):
        ok = (_in(lat[k], ranges[0, 0], ranges[0, 1]) and _in(lon[k], ranges[1, 0], ranges[1, 1])
              and _in(h[k], ranges[2, 0], ranges[2, 1])
              and _in(heading[k], ranges[3, 0], ranges[3, 1])
              and _in(pitch[k], ranges[4, 0], ranges[4, 1]) and _in(roll[k], ranges[5, 0], ranges[5, 1])
              and _in(groll[k], ranges[6, 0], ranges[6, 1])
              and _in(gpitch[k], ranges[7, 0], ranges[7, 1])
              and math.isfinite(row[k]) and math.isfinite(col[k]))
        # pixel -> camera [Q17 eq. 8]
        x = row[k] - i0
        y = j0 - col[k]
        z = f
        nrm = math.sqrt(x * x + y * y + z * z)
        x /= nrm
        y /= nrm
        z /= nrm
        # camera -> outer gimbal: ry(gimbal_pitch)^T
        c, s = math.cos(gpitch[k]), math.sin(gpitch[k])
        x, z = c * x + s * z, -s * x + c * z
        # outer gimbal -> body: rx(gimbal_roll)^T
        c, s = math.cos(groll[k]), math.sin(groll[k])
        y, z = c * y - s * z, s * y + c * z
        # body -> NED: (rx(roll) ry(pitch) rz(heading))^T = rz^T ry^T rx^T [Q17 eq. 6]
        c, s = math.cos(roll[k]), math.sin(roll[k])
        y, z = c * y - s * z, s * y + c * z
        c, s = math.cos(pitch[k]), math.sin(pitch[k])
        x, z = c * x + s * z, -s * x + c * z
        c, s = math.cos(heading[k]), math.sin(heading[k])
        x, y = c * x - s * y, s * x + c * y
        # NED -> ECEF: columns N, E, D [Q17 eq. 5]
        sp, cp = math.sin(lat[k]), math.cos(lat[k])
        sl, cl = math.sin(lon[k]), math.cos(lon[k])
        dx = -sp * cl * x - sl * y - cp * cl * z
        dy = -sp * sl * x + cl * y - cp * sl * z
        dz = cp * x - sp * z
        rn = A / math.sqrt(1.0 - E2 * sp * sp)
        ox = (rn + h[k]) * cp * cl
        oy = (rn + h[k]) * cp * sl
        oz = (rn * (1.0 - E2) + h[k]) * sp
        out_o[k, 0], out_o[k, 1], out_o[k, 2] = ox, oy, oz
        out_d[k, 0], out_d[k, 1], out_d[k, 2] = dx, dy, dz
        # ray x inflated ellipsoid [Q17 eq. 10-11]
        ht = target_h[k]
        aa = A + ht
        bb = B + ht
        ok = ok and math.isfinite(ht) and bb > 0.0
        status = _OK
        sol = math.nan
        if not ok:
            status = _INVALID
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


def locate_fast(pose, camera, row, col, target_h):
    """Run :func:`locate_kernel` on broadcast inputs; returns arrays shaped like the batch."""
    fields = [pose.lat, pose.lon, pose.h, pose.heading, pose.pitch, pose.roll,
              pose.gimbal_roll, pose.gimbal_pitch, row, col, target_h]
    arrs = np.broadcast_arrays(*(np.asarray(v, float) for v in fields))
    shape = arrs[0].shape
    flat = [np.ascontiguousarray(a).reshape(-1) for a in arrs]
    n = flat[0].size
    ranges = np.array([pose.RANGES[k] for k in ("lat", "lon", "h", "heading", "pitch", "roll",
                                                "gimbal_roll", "gimbal_pitch")], dtype=float)
    out_lat, out_lon, out_h, out_s = (np.empty(n) for _ in range(4))
    out_ecef, out_o, out_d = (np.empty((n, 3)) for _ in range(3))
    out_status = np.empty(n, dtype=np.uint8)
    locate_kernel(*flat, float(camera.focal_length_px), float(camera.principal_row),
                  float(camera.principal_col), ranges, out_lat, out_lon, out_h, out_ecef, out_s,
                  out_o, out_d, out_status)
    return (out_lat.reshape(shape), out_lon.reshape(shape), out_h.reshape(shape),
            out_ecef.reshape(shape + (3,)), out_s.reshape(shape), out_status.reshape(shape),
            out_o.reshape(shape + (3,)), out_d.reshape(shape + (3,)))
