"""Compiled first-order propagation: the Jacobian of every ray's chain and surface in numba kernels.

The same mathematics as the numpy reference path of :mod:`geoloc.analysis.uncertainty`
(:func:`~geoloc.analysis.uncertainty.chain_derivatives` and the surface step of
:func:`~geoloc.analysis.uncertainty.propagate`), written per ray so that a 100 000-frame flight
costs one pass over memory instead of a few hundred temporary arrays
(``benchmarks/bench_uncertainty.py``). ``tests/analysis/test_uncertainty.py`` holds the two engines equal
column for column, for every gimbal preset and lens model.

Three kernels:

* :func:`chain_kernel`: per ray, the frames on the path to the camera (NED at the platform,
  body, gimbal base, each joint), the turn of each angle source about its axis in ECEF
  (``dD = a x D``, ``dO = a x L``), the platform's displacement with the turn of its local
  frame, the lever arm and the time tag, all as in the reference; and each lens parameter by
  implicit differentiation of the lens's closed-form projection ``pi(a, b; p) = pixel`` at the
  ray's normalised point ``(a, b)``: ``d(a, b) = -[d pi / d(a, b)]^-1 d pi / dp``. For the
  pinhole and the Brown model both derivatives are in closed form (:func:`_lens_jac`,
  :func:`_lens_dparam`: the pixel is affine in every parameter but the rational k4..k6, so the
  derivative is the +-1 sigma secant exactly); k4..k6 and the fisheye take central differences
  of :func:`geoloc.sensors.lenses.project_nb` (over +-1 sigma in ``p``, as the reference's
  differences of ``unproject``, and +-1e-6 in ``(a, b)``: truncation ~1e-12 and rounding ~1e-13
  of the derivative), so every lens model is served without an iteration.
  Output: the point carried along its old range, ``free = dO + t dD`` (ECEF, per 1 sigma), for
  the numpy surface step (a projected DEM, a mosaic).
* :func:`chain_surface_kernel`: the same chain per ray, then the hit kept on a constant height
  (normal ``m`` the local up), ``dP = free - D (m . free) / (m . D)`` (and ``D dz / (m . D)`` for
  the surface's own vertical error), turned to ENU at the hit; the covariance ``J J^T``, the
  1-sigma ellipse (eigen decomposition of the 2x2 block in closed form), CE90 from the table of
  :func:`geoloc.analysis.uncertainty._ce_table` (linear interpolation on its uniform axis-ratio
  grid, as ``np.interp``) and LE90. The chain's columns stay in a scratch row per ray: no
  (n, 3, k) array is written and read back.
* :func:`chain_dem_kernel`: the same on a geographic DEM, whose normal is the DEM's local
  slope: at the hit, then the plane fitted over the predicted footprint (iterated), the terrain's
  departure from it and the grazing test, reading the DEM's node grid itself (the bilinear
  interpolation of :meth:`geoloc.geodesy.geoid.NodeGrid.interp`, stepped in rows and columns per
  metre from the hit's cell). The perturbed rays are never walked through the DEM again: the
  plane carries them.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import prange

from geoloc import status as _status_module
from geoloc.geodesy._nbgeo import cached_njit, dependency_key
from geoloc.sensors import _fastlocate as _fastlocate_module
from geoloc.sensors import lenses as _lenses_module
from geoloc.sensors._fastlocate import _SINCOS_MAX, sincos_lanes
from geoloc.sensors.lenses import BROWN, FISHEYE, PARAM_LAYOUT, _brown_distort_nb, project_nb
from geoloc.status import Status

#: The kernels' cache key: the constants and the sources of the modules whose code or constants they freeze.
KEY = dependency_key(_status_module, _lenses_module, _fastlocate_module, sys.modules[__name__])

_OK = int(Status.OK)
_BLOCK = 512

# source codes of the chain kernel's columns
SRC_NORTH, SRC_EAST, SRC_UP, SRC_TIME, SRC_HEADING, SRC_PITCH, SRC_ROLL = 0, 1, 2, 3, 4, 5, 6
SRC_JOINT = 10  # + joint index
SRC_MOUNT = 30  # + axis (x, y, z)
SRC_BORE = 33  # + axis
SRC_LEVER = 36  # + axis
SRC_LENS = 40  # + PARAM_LAYOUT slot


@cached_njit(KEY, inline="always", error_model="numpy")
def _sincos(a):
    """(sin a, cos a) with one range reduction (:func:`geoloc.sensors._fastlocate.sincos_lanes`,
    within 2.3e-16 of libm's) instead of two library calls; libm's beyond 64 rad and for NaN."""
    if abs(a) <= _SINCOS_MAX:
        return sincos_lanes(a)
    return math.sin(a), math.cos(a)


@cached_njit(KEY, inline="always")
def _turn_back_cols(axis, c, s, R, out):
    """out = R @ rot_axis(angle)^T (the passive elementary rotation's transpose), 3x3."""
    for i in range(3):
        x, y, z = R[i, 0], R[i, 1], R[i, 2]
        # row i of R times rot^T is rot applied to that row: rot = turn_back with the angle negated
        if axis == 0:
            out[i, 0], out[i, 1], out[i, 2] = x, c * y + s * z, -s * y + c * z
        elif axis == 1:
            out[i, 0], out[i, 1], out[i, 2] = c * x - s * z, y, s * x + c * z
        else:
            out[i, 0], out[i, 1], out[i, 2] = c * x + s * y, -s * x + c * y, z


@cached_njit(KEY, inline="always")
def _matmul(A, B, out):
    for i in range(3):
        for k in range(3):
            out[i, k] = A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k]


@cached_njit(KEY, inline="always")
def _matmul_T(A, B, out):
    """out = A @ B^T."""
    for i in range(3):
        for k in range(3):
            out[i, k] = A[i, 0] * B[k, 0] + A[i, 1] * B[k, 1] + A[i, 2] * B[k, 2]


@cached_njit(KEY, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


#: The first PARAM_LAYOUT slot of the Brown model's rational denominator (k4, k5, k6).
_SLOT_K4 = PARAM_LAYOUT.index("k4")


@cached_njit(KEY, inline="always")
def _lens_jac(lens_code, p, a, b):
    """The pinhole's or the Brown model's projection at the normalised point ``(a, b)`` in closed
    form: the distorted point ``(xd, yd)``, ``d pixel / d(a, b)`` (``j11 j12; j21 j22``: ``K``'s
    2x2 block times the distortion's Jacobian, that of :func:`geoloc.sensors.lenses._brown_newton_step`)
    and ``r2``, the radial factor's denominator ``den``. Replaces four projections of central
    differences (their truncation was ~1e-12 of the derivative)."""
    fx, fy, sk = p[0], p[1], p[4]
    r2 = a * a + b * b
    if lens_code == BROWN:
        k4, k5, k6, p1, p2 = p[10], p[11], p[12], p[7], p[8]
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        xd, yd, radial, d_radial = _brown_distort_nb(p, a, b)
        g = 2.0 * d_radial
        d11 = radial + g * a * a + 2.0 * p1 * b + 6.0 * p2 * a
        d12 = g * a * b + 2.0 * p1 * a + 2.0 * p2 * b
        d22 = radial + g * b * b + 6.0 * p1 * b + 2.0 * p2 * a
    else:  # pinhole: no distortion
        den = 1.0
        xd, yd = a, b
        d11, d12, d22 = 1.0, 0.0, 1.0
    return xd, yd, fx * d11 + sk * d12, fx * d12 + sk * d22, fy * d12, fy * d22, r2, den


@cached_njit(KEY, inline="always")
def _lens_dparam(lens_code, p, slot, a, b, xd, yd, r2, den):
    """``d pixel / d p`` of the pinhole's or the Brown model's parameter ``slot`` (PARAM_LAYOUT) at
    the normalised point ``(a, b)`` (distorted ``(xd, yd)``), in closed form: the pixel is affine in
    each of fx, fy, cx, cy, skew, k1, k2, k3, p1, p2, so this is exactly the central difference over
    +-1 sigma that it replaces (two projections). The pinhole has no distortion: zero for those."""
    if slot == 0:  # u = fx xd + skew yd + cx, v = fy yd + cy
        return xd, 0.0
    if slot == 1:
        return 0.0, yd
    if slot == 2:
        return 1.0, 0.0
    if slot == 3:
        return 0.0, 1.0
    if slot == 4:
        return yd, 0.0
    if lens_code != BROWN:
        return 0.0, 0.0
    if slot == 5 or slot == 6 or slot == 9:  # k1, k2, k3: the radial factor's numerator r2, r2^2, r2^3
        m = r2 if slot == 5 else (r2 * r2 if slot == 6 else r2 * r2 * r2)
        dx, dy = a * m / den, b * m / den
    elif slot == 7:  # p1
        dx, dy = 2.0 * a * b, r2 + 2.0 * b * b
    elif slot == 8:  # p2
        dx, dy = r2 + 2.0 * a * a, 2.0 * a * b
    else:
        return math.nan, math.nan  # k4..k6: the caller takes differences
    return p[0] * dx + p[4] * dy, p[1] * dy


@cached_njit(KEY, inline="always")
def _chain_ray(
    i,
    lat,
    lon,
    h,
    heading,
    pitch,
    roll,
    angles,
    D,
    ti,
    vel,
    axes,
    R_cam_last,
    R_base_body,
    lever,
    earth_ref,
    mount_axes,
    bore_axes,
    lens_code,
    lens_p,
    codes,
    sigmas,
    a_m,
    e2,
    scratch,
    out,
):
    """Ray ``i``'s ``out[:, k] = dO + ti dD`` per 1 sigma of source ``codes[k]`` (ECEF, metres);
    ``scratch`` is the caller's ``(Rn, Rb, Rt, Rt2, Rc, Rj, pp)`` (3x3 frames, the joints' frames,
    the lens's parameters), ``ti`` the ray's range to its hit. (At most 30 arguments: beyond that
    Python passes them as one tuple, which numba cannot inline.)"""
    Rn, Rb, Rt, Rt2, Rc, Rj, pp = scratch
    nj = axes.shape[0]
    ns = codes.shape[0]
    sp, cp = _sincos(lat[i])
    sl, cl = _sincos(lon[i])
    # R_ecef_ned: columns north, east, down
    Rn[0, 0], Rn[1, 0], Rn[2, 0] = -sp * cl, -sp * sl, cp
    Rn[0, 1], Rn[1, 1], Rn[2, 1] = -sl, cl, 0.0
    Rn[0, 2], Rn[1, 2], Rn[2, 2] = -cp * cl, -cp * sl, -sp
    # R_ecef_body = R_ecef_ned rz(heading)^T ry(pitch)^T rx(roll)^T
    sh, ch = _sincos(heading[i])  # kept: the pitch source's axis turns with the heading
    _turn_back_cols(2, ch, sh, Rn, Rt)
    s_, c_ = _sincos(pitch[i])
    _turn_back_cols(1, c_, s_, Rt, Rt2)
    s_, c_ = _sincos(roll[i])
    _turn_back_cols(0, c_, s_, Rt2, Rb)
    if earth_ref:
        Rj[0] = Rn
    else:
        _matmul_T(Rb, R_base_body, Rt)  # R_ecef_base = R_ecef_body R_base_body^T
        Rj[0] = Rt
    for j in range(nj):
        s_, c_ = _sincos(angles[i, j])
        _turn_back_cols(axes[j], c_, s_, Rj[j], Rj[j + 1])
    _matmul_T(Rj[nj], R_cam_last, Rc)  # R_ecef_cam
    d0, d1, d2 = D[i, 0], D[i, 1], D[i, 2]
    L0 = Rb[0, 0] * lever[0] + Rb[0, 1] * lever[1] + Rb[0, 2] * lever[2]
    L1 = Rb[1, 0] * lever[0] + Rb[1, 1] * lever[1] + Rb[1, 2] * lever[2]
    L2 = Rb[2, 0] * lever[0] + Rb[2, 1] * lever[1] + Rb[2, 2] * lever[2]
    w = 1.0 - e2 * sp * sp
    rn_h = a_m / math.sqrt(w) + h[i]  # prime vertical radius + h
    rm_h = a_m * (1.0 - e2) / (w * math.sqrt(w)) + h[i]  # meridian radius + h
    # the direction in the optical frame and its normalised point
    c0 = Rc[0, 0] * d0 + Rc[1, 0] * d1 + Rc[2, 0] * d2
    c1 = Rc[0, 1] * d0 + Rc[1, 1] * d1 + Rc[2, 1] * d2
    c2 = Rc[0, 2] * d0 + Rc[1, 2] * d1 + Rc[2, 2] * d2
    have_lens_jac = False
    have_move = False
    nO0 = nO1 = nO2 = eO0 = eO1 = eO2 = y0 = y1 = y2 = z0 = z1 = z2 = 0.0
    j11 = j12 = j21 = j22 = 0.0
    xd = yd = r2 = den = 0.0
    a_n, b_n = c0 / c2, c1 / c2
    for k in range(ns):
        code = codes[k]
        sg = sigmas[k]
        o0 = o1 = o2 = 0.0
        e0 = e1 = e2_ = 0.0
        if code == SRC_NORTH or code == SRC_EAST or code == SRC_TIME:
            if not have_move:  # once per ray: north, east and time share these
                # north: origin along north, the NED frame turns by w_n = -east / (R_M + h)
                wn0, wn1, wn2 = -Rn[0, 1] / rm_h, -Rn[1, 1] / rm_h, 0.0
                # east: w_e = z / ((R_N + h) cos lat)
                we2 = 1.0 / (rn_h * cp)
                x0, x1, x2 = _cross(wn0, wn1, wn2, L0, L1, L2)
                y0, y1, y2 = _cross(wn0, wn1, wn2, d0, d1, d2)
                nO0, nO1, nO2 = Rn[0, 0] + x0, Rn[1, 0] + x1, Rn[2, 0] + x2
                x0, x1, x2 = _cross(0.0, 0.0, we2, L0, L1, L2)
                z0, z1, z2 = _cross(0.0, 0.0, we2, d0, d1, d2)
                eO0, eO1, eO2 = Rn[0, 1] + x0, Rn[1, 1] + x1, Rn[2, 1] + x2
                have_move = True
            if code == SRC_NORTH:
                o0, o1, o2, e0, e1, e2_ = nO0, nO1, nO2, y0, y1, y2
            elif code == SRC_EAST:
                o0, o1, o2, e0, e1, e2_ = eO0, eO1, eO2, z0, z1, z2
            else:
                vn, ve, vd = vel[i, 0], vel[i, 1], vel[i, 2]
                o0 = vn * nO0 + ve * eO0 + vd * Rn[0, 2]  # -vd * up = vd * down
                o1 = vn * nO1 + ve * eO1 + vd * Rn[1, 2]
                o2 = vn * nO2 + ve * eO2 + vd * Rn[2, 2]
                e0, e1, e2_ = vn * y0 + ve * z0, vn * y1 + ve * z1, vn * y2 + ve * z2
        elif code == SRC_UP:
            o0, o1, o2 = -Rn[0, 2], -Rn[1, 2], -Rn[2, 2]
        elif code == SRC_LEVER or code == SRC_LEVER + 1 or code == SRC_LEVER + 2:
            c = code - SRC_LEVER
            o0, o1, o2 = Rb[0, c], Rb[1, c], Rb[2, c]
        elif code < SRC_LENS:
            turns = True
            if code == SRC_HEADING:
                a0, a1, a2 = Rn[0, 2], Rn[1, 2], Rn[2, 2]
                turns = not earth_ref
            elif code == SRC_PITCH:
                a0 = -sh * Rn[0, 0] + ch * Rn[0, 1]
                a1 = -sh * Rn[1, 0] + ch * Rn[1, 1]
                a2 = -sh * Rn[2, 0] + ch * Rn[2, 1]
                turns = not earth_ref
            elif code == SRC_ROLL:
                a0, a1, a2 = Rb[0, 0], Rb[1, 0], Rb[2, 0]
                turns = not earth_ref
            elif code < SRC_MOUNT:
                j = code - SRC_JOINT
                ax = axes[j]
                a0, a1, a2 = Rj[j + 1, 0, ax], Rj[j + 1, 1, ax], Rj[j + 1, 2, ax]
            elif code < SRC_BORE:
                v = mount_axes[code - SRC_MOUNT]
                a0 = Rb[0, 0] * v[0] + Rb[0, 1] * v[1] + Rb[0, 2] * v[2]
                a1 = Rb[1, 0] * v[0] + Rb[1, 1] * v[1] + Rb[1, 2] * v[2]
                a2 = Rb[2, 0] * v[0] + Rb[2, 1] * v[1] + Rb[2, 2] * v[2]
            else:
                v = bore_axes[code - SRC_BORE]
                R = Rj[nj]
                a0 = R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2]
                a1 = R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2]
                a2 = R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2]
            if code <= SRC_ROLL:  # the attitude turns the lever arm too
                o0, o1, o2 = _cross(a0, a1, a2, L0, L1, L2)
            if turns:
                e0, e1, e2_ = _cross(a0, a1, a2, d0, d1, d2)
        else:
            # lens: d(a, b) = -J^-1 d pi/dp, J = d pi / d(a, b) at the ray's normalised point
            if not have_lens_jac:
                if lens_code == FISHEYE:
                    hh = 1e-6
                    up_, vp_, _ = project_nb(lens_code, lens_p, a_n + hh, b_n, 1.0)
                    um_, vm_, _ = project_nb(lens_code, lens_p, a_n - hh, b_n, 1.0)
                    j11, j21 = (up_ - um_) / (2 * hh), (vp_ - vm_) / (2 * hh)
                    up_, vp_, _ = project_nb(lens_code, lens_p, a_n, b_n + hh, 1.0)
                    um_, vm_, _ = project_nb(lens_code, lens_p, a_n, b_n - hh, 1.0)
                    j12, j22 = (up_ - um_) / (2 * hh), (vp_ - vm_) / (2 * hh)
                else:
                    xd, yd, j11, j12, j21, j22, r2, den = _lens_jac(lens_code, lens_p, a_n, b_n)
                have_lens_jac = True
            slot = code - SRC_LENS
            if lens_code == FISHEYE or slot >= _SLOT_K4:
                # central differences over +-1 sigma of the projection (k4..k6 are in a denominator:
                # the secant is what the reference's secant of the inverse approximates)
                base = lens_p[slot]
                pp[slot] = base + sg
                up_, vp_, _ = project_nb(lens_code, pp, a_n, b_n, 1.0)
                pp[slot] = base - sg
                um_, vm_, _ = project_nb(lens_code, pp, a_n, b_n, 1.0)
                pp[slot] = base
                du, dv = (up_ - um_) / 2.0, (vp_ - vm_) / 2.0
            else:
                du, dv = _lens_dparam(lens_code, lens_p, slot, a_n, b_n, xd, yd, r2, den)
                du, dv = du * sg, dv * sg
            det = j11 * j22 - j12 * j21
            da = -(j22 * du - j12 * dv) / det
            db = -(j11 * dv - j21 * du) / det
            # d unit(a, b, 1) = (I - u u^T) (da, db, 0) / |(a, b, 1)|, u the unit direction
            nrm = math.sqrt(a_n * a_n + b_n * b_n + 1.0)
            u0, u1, u2 = a_n / nrm, b_n / nrm, 1.0 / nrm
            dot = u0 * da + u1 * db
            q0, q1, q2 = (da - u0 * dot) / nrm, (db - u1 * dot) / nrm, -u2 * dot / nrm
            e0 = Rc[0, 0] * q0 + Rc[0, 1] * q1 + Rc[0, 2] * q2
            e1 = Rc[1, 0] * q0 + Rc[1, 1] * q1 + Rc[1, 2] * q2
            e2_ = Rc[2, 0] * q0 + Rc[2, 1] * q1 + Rc[2, 2] * q2
            sg = 1.0  # the differences were over +-1 sigma already
        out[0, k] = (o0 + ti * e0) * sg
        out[1, k] = (o1 + ti * e1) * sg
        out[2, k] = (o2 + ti * e2_) * sg


@cached_njit(KEY, parallel=True, error_model="numpy")
def chain_kernel(
    lat,
    lon,
    h,
    heading,
    pitch,
    roll,
    angles,
    O,
    D,
    t,
    vel,
    axes,
    R_cam_last,
    R_base_body,
    lever,
    earth_ref,
    mount_axes,
    bore_axes,
    lens_code,
    lens_p,
    codes,
    sigmas,
    a_m,
    e2,
    free,
):
    """``free[i, :, k] = dO + t dD`` of ray ``i`` per 1 sigma of source ``codes[k]`` (ECEF, metres).

    ``sigmas`` are in SI (radians, metres, seconds, pixels); ``mount_axes`` (body frame) and
    ``bore_axes`` (last joint frame) are the axes of the three angles of ``rx ry rz``
    (:func:`geoloc.analysis.uncertainty._xyz_axes`), one per row.
    """
    n = lat.shape[0]
    nj = axes.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    for blk in prange(nb):
        Rn = np.empty((3, 3))
        Rb = np.empty((3, 3))
        Rt = np.empty((3, 3))
        Rt2 = np.empty((3, 3))
        Rc = np.empty((3, 3))
        Rj = np.empty((nj + 1, 3, 3))
        pp = lens_p.copy()
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            _chain_ray(
                i,
                lat,
                lon,
                h,
                heading,
                pitch,
                roll,
                angles,
                D,
                t[i],
                vel,
                axes,
                R_cam_last,
                R_base_body,
                lever,
                earth_ref,
                mount_axes,
                bore_axes,
                lens_code,
                lens_p,
                codes,
                sigmas,
                a_m,
                e2,
                (Rn, Rb, Rt, Rt2, Rc, Rj, pp),
                free[i],
            )


@cached_njit(KEY, inline="always")
def _range(O, P, i):
    """Ray ``i``'s range from its origin to its hit (NaN without a hit), as ``np.linalg.norm``."""
    x, y, z = P[i, 0] - O[i, 0], P[i, 1] - O[i, 1], P[i, 2] - O[i, 2]
    return math.sqrt(x * x + y * y + z * z)


@cached_njit(KEY, parallel=True, error_model="numpy")
def chain_surface_kernel(
    lat,
    lon,
    h,
    heading,
    pitch,
    roll,
    angles,
    O,
    D,
    P,
    vel,
    axes,
    R_cam_last,
    R_base_body,
    lever,
    earth_ref,
    mount_axes,
    bore_axes,
    lens_code,
    lens_p,
    codes,
    sigmas,
    a_m,
    e2,
    hit_lat,
    hit_lon,
    status,
    sz,
    qt_n,
    rt,
    le90_per_sigma,
    J,
    cov,
    major,
    minor,
    az,
    ce,
    le,
):
    """:func:`chain_kernel` and the surface step on a constant height in one pass: each ray's chain
    columns stay in a scratch row (3, k) instead of an (n, 3, k) array written and read back; then
    ``J`` (one more column than the sources when ``sz > 0``: the surface's own vertical error),
    ``cov``, the ellipse, CE90 and LE90 per ray (:func:`_step`, :func:`_ellipse_out`).

    ``P`` are the hits in ECEF (the range ``|P - O|`` carries the turned ray to the ground);
    ``hit_lat``, ``hit_lon`` their geodetic coordinates [rad].
    """
    n = lat.shape[0]
    nj = axes.shape[0]
    ns = codes.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    for blk in prange(nb):
        Rn = np.empty((3, 3))
        Rb = np.empty((3, 3))
        Rt = np.empty((3, 3))
        Rt2 = np.empty((3, 3))
        Rc = np.empty((3, 3))
        Rj = np.empty((nj + 1, 3, 3))
        pp = lens_p.copy()
        fr = np.empty((3, ns))
        Js = np.empty((3, J.shape[2]))  # the ray's Jacobian when the caller keeps none (J with no rows)
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            ti = _range(O, P, i)
            _chain_ray(
                i,
                lat,
                lon,
                h,
                heading,
                pitch,
                roll,
                angles,
                D,
                ti,
                vel,
                axes,
                R_cam_last,
                R_base_body,
                lever,
                earth_ref,
                mount_axes,
                bore_axes,
                lens_code,
                lens_p,
                codes,
                sigmas,
                a_m,
                e2,
                (Rn, Rb, Rt, Rt2, Rc, Rj, pp),
                fr,
            )
            sp, cp = _sincos(hit_lat[i])
            sl, cl = _sincos(hit_lon[i])
            E = (-sl, cl, 0.0)  # the ENU axes in ECEF
            N = (-sp * cl, -sp * sl, cp)
            U = (cp * cl, cp * sl, sp)
            inv, c00, c01, c02, c11, c12, c22 = _step(
                fr,
                D[i, 0],
                D[i, 1],
                D[i, 2],
                U[0],
                U[1],
                U[2],
                status[i] == _OK,
                sz,
                E,
                N,
                U,
                J[i] if J.shape[0] != 0 else Js,
            )
            _ellipse_out(i, c00, c01, c02, c11, c12, c22, qt_n, rt, le90_per_sigma, cov, major, minor, az, ce, le)


@cached_njit(KEY, inline="always")
def _ellipse_out(i, c00, c01, c02, c11, c12, c22, qt_n, rt, le90_per_sigma, cov, major, minor, az, ce, le):
    """Row ``i`` of the outputs from the ENU covariance's six entries: ``cov``, the 1-sigma ellipse
    (semi-axes, azimuth of the major axis clockwise from north), CE90 read from the table
    ``rt`` at the axis ratio (exact for the ellipse, :func:`geoloc.analysis.uncertainty.ce90`) and
    LE90."""
    cov[i, 0, 0], cov[i, 0, 1], cov[i, 0, 2] = c00, c01, c02
    cov[i, 1, 0], cov[i, 1, 1], cov[i, 1, 2] = c01, c11, c12
    cov[i, 2, 0], cov[i, 2, 1], cov[i, 2, 2] = c02, c12, c22
    mean = 0.5 * (c00 + c11)
    hd = 0.5 * (c00 - c11)
    dif = math.sqrt(hd * hd + c01 * c01)  # squares of m^2 entries: far from overflow, hypot's care not needed
    a = math.sqrt(max(mean + dif, 0.0))
    b = math.sqrt(max(mean - dif, 0.0))
    major[i], minor[i] = a, b
    theta = 0.5 * math.atan2(2.0 * c01, c00 - c11)
    az[i] = (90.0 - math.degrees(theta)) % 180.0
    q = b / a if a > 0 else 0.0
    x = q * qt_n
    nq = rt.shape[0]
    j0 = min(int(x), nq - 2)
    fr = x - j0
    ce[i] = a * (rt[j0] + fr * (rt[j0 + 1] - rt[j0]))
    le[i] = le90_per_sigma * math.sqrt(c22)


# --------------------------------------------------------------------- on a DEM
@cached_njit(KEY, inline="always")
def _grid_rc(lat_north, lon_west, idlat, idlon, lat, lon):
    """The fractional (row, column) of (lat, lon) [rad] on a geographic grid, the longitude brought
    to the grid's 360-degree window, as :meth:`geoloc.geodesy.geoid.NodeGrid.interp`."""
    lat_deg = math.degrees(lat)
    lon_deg = math.degrees(lon)
    x = lon_deg - lon_west + 180.0
    if not (0.0 <= x < 360.0):  # already in the window: x % 360 is x, without the remainder's cost
        x = x % 360.0
    lon_deg = x + lon_west - 180.0
    return (lat_north - lat_deg) * idlat, (lon_deg - lon_west) * idlon


@cached_njit(KEY, inline="always")
def _grid_at(Z, margin, cw, r, c):
    """The DEM's height at the fractional (row, column) ``(r, c)``, scalar: the bilinear
    interpolation of :meth:`geoloc.geodesy.geoid.NodeGrid.interp`.

    ``c`` is brought back into the grid's 360-degree window (``cw`` columns either side of its west
    edge), NaN off the node hull grown by ``margin`` cells (1e-9 cell tolerance), the position
    clamped to the hull inside that band, and a node without data spoiling the point only where its
    weight is not zero. The callers step from a hit's (row, column) by metres north and east times
    the grid's rows and columns per metre there: the same positions as converting each sample to
    degrees (a few 1e-12 of a cell apart by rounding), without two conversions per sample.
    """
    if not (math.isfinite(r) and math.isfinite(c)):
        return math.nan
    if not (-cw <= c < cw):
        c = (c + cw) % (2.0 * cw) - cw
    nr, nc = Z.shape
    tol = 1e-9 + margin
    if r < -tol or r > nr - 1 + tol or c < -tol or c > nc - 1 + tol:
        return math.nan
    r = min(max(r, 0.0), nr - 1.0)
    c = min(max(c, 0.0), nc - 1.0)
    r0 = min(max(int(math.floor(r)), 0), nr - 2)
    c0 = min(max(int(math.floor(c)), 0), nc - 2)
    v = r - r0
    u = c - c0
    out = 0.0
    w = (1.0 - u) * (1.0 - v)
    if w != 0.0:
        out += w * Z[r0, c0]
    w = u * (1.0 - v)
    if w != 0.0:
        out += w * Z[r0, c0 + 1]
    w = (1.0 - u) * v
    if w != 0.0:
        out += w * Z[r0 + 1, c0]
    w = u * v
    if w != 0.0:
        out += w * Z[r0 + 1, c0 + 1]
    return out


#: Nodes per side of a tile of :func:`dem_tiles` (its bounds cover its cells' corner nodes).
TILE = 8


@cached_njit(KEY)
def dem_tiles(Z):
    """The lowest and highest finite node of each tile of ``TILE x TILE`` cells of the grid ``Z``
    (rows ``a TILE .. a TILE + TILE`` of nodes, clipped), widened by 1e-6 of the height and 1e-6 m:
    ``(2, ceil((nr - 1) / TILE), ceil((nc - 1) / TILE))``, ``(+inf, -inf)`` for a tile without
    data. Every bilinear height of a cell in a tile lies inside (the widening covers the rounding
    of the four weights, ~1e-16 of the height), so a sample whose ray is farther than its band
    from both bounds cannot be grazing: :func:`_dem_ray` then skips its read."""
    nr, nc = Z.shape
    na = max((nr - 1 + TILE - 1) // TILE, 1)
    nb = max((nc - 1 + TILE - 1) // TILE, 1)
    out = np.empty((2, na, nb))
    for a in range(na):
        for b in range(nb):
            lo, hi = math.inf, -math.inf
            for r in range(a * TILE, min(a * TILE + TILE, nr - 1) + 1):
                for c in range(b * TILE, min(b * TILE + TILE, nc - 1) + 1):
                    z = Z[r, c]
                    if math.isfinite(z):
                        lo = min(lo, z)
                        hi = max(hi, z)
            out[0, a, b] = lo - 1e-6 * (1.0 + abs(lo)) if lo <= hi else math.inf
            out[1, a, b] = hi + 1e-6 * (1.0 + abs(hi)) if lo <= hi else -math.inf
    return out


@cached_njit(KEY, inline="always")
def _may_reach(tiles, nr, nc, margin, cw, r, c, lo, hi):
    """False where :func:`_grid_at` at ``(r, c)`` is NaN or surely outside ``[lo, hi]``: the
    bounds of the tile of the cell it interpolates in (the same window, hull and clamps), from
    :func:`dem_tiles`; True without tiles (an empty ``tiles``)."""
    if tiles.shape[1] == 0:
        return True
    if not (math.isfinite(r) and math.isfinite(c)):
        return False
    if not (-cw <= c < cw):
        c = (c + cw) % (2.0 * cw) - cw
    tol = 1e-9 + margin
    if r < -tol or r > nr - 1 + tol or c < -tol or c > nc - 1 + tol:
        return False
    r0 = min(int(min(max(r, 0.0), nr - 1.0)), nr - 2) if nr > 1 else 0
    c0 = min(int(min(max(c, 0.0), nc - 1.0)), nc - 2) if nc > 1 else 0
    a = r0 // TILE
    b = c0 // TILE
    return tiles[1, a, b] >= lo and tiles[0, a, b] <= hi


@cached_njit(KEY, inline="always")
def _step(fr, d0, d1, d2, m0, m1, m2, ok, sz, E, N, U, Jo):
    """The surface step of one ray (chain columns ``fr`` (3, k), direction ``d``) for the normal
    ``m``: ``Jo`` (3, kk) in ENU, returns 1 / (m . D) (NaN where the ray does not enter the surface
    or is not ``ok``: then every entry is NaN) and the covariance's six entries."""
    k = fr.shape[1]
    kk = Jo.shape[1]
    mD = m0 * d0 + m1 * d1 + m2 * d2
    inv = 1.0 / mD if (ok and mD < -1e-12) else math.nan
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for c in range(kk):
        if c < k:
            f0, f1, f2 = fr[0, c], fr[1, c], fr[2, c]
            s = (m0 * f0 + m1 * f1 + m2 * f2) * inv
            p0, p1, p2 = f0 - d0 * s, f1 - d1 * s, f2 - d2 * s
        else:
            s = sz * inv
            p0, p1, p2 = d0 * s, d1 * s, d2 * s
        je = E[0] * p0 + E[1] * p1 + E[2] * p2
        jn = N[0] * p0 + N[1] * p1 + N[2] * p2
        ju = U[0] * p0 + U[1] * p1 + U[2] * p2
        Jo[0, c], Jo[1, c], Jo[2, c] = je, jn, ju
        c00 += je * je
        c01 += je * jn
        c02 += je * ju
        c11 += jn * jn
        c12 += jn * ju
        c22 += ju * ju
    return inv, c00, c01, c02, c11, c12, c22


@cached_njit(KEY, inline="always")
def _gram(fr):
    """The six entries ``(g00, g01, g02, g11, g12, g22)`` of ``fr fr^T`` (chain columns ``fr`` (3, k))."""
    g00 = g01 = g02 = g11 = g12 = g22 = 0.0
    for c in range(fr.shape[1]):
        f0, f1, f2 = fr[0, c], fr[1, c], fr[2, c]
        g00 += f0 * f0
        g01 += f0 * f1
        g02 += f0 * f2
        g11 += f1 * f1
        g12 += f1 * f2
        g22 += f2 * f2
    return g00, g01, g02, g11, g12, g22


@cached_njit(KEY, inline="always")
def _horizontal_cov(G, d0, d1, d2, m0, m1, m2, sz, E, N):
    """:func:`_step`'s ``c00, c01, c11`` from the Gram matrix ``G`` of the chain's columns: the
    east row of the Jacobian is ``a_e . f`` with ``a_e = E - (E . D) m / (m . D)`` (so its sum of
    squares is ``a_e^T G a_e``), plus the surface's own column ``(E . D) sz / (m . D)``; NaN where
    the ray does not enter the surface. The same sums as :func:`_step`'s in another order."""
    g00, g01, g02, g11, g12, g22 = G
    mD = m0 * d0 + m1 * d1 + m2 * d2
    inv = 1.0 / mD if mD < -1e-12 else math.nan
    ed = (E[0] * d0 + E[1] * d1 + E[2] * d2) * inv
    nd = (N[0] * d0 + N[1] * d1 + N[2] * d2) * inv
    x0, x1, x2 = E[0] - ed * m0, E[1] - ed * m1, E[2] - ed * m2
    y0, y1, y2 = N[0] - nd * m0, N[1] - nd * m1, N[2] - nd * m2
    gx0 = g00 * x0 + g01 * x1 + g02 * x2
    gx1 = g01 * x0 + g11 * x1 + g12 * x2
    gx2 = g02 * x0 + g12 * x1 + g22 * x2
    gy0 = g00 * y0 + g01 * y1 + g02 * y2
    gy1 = g01 * y0 + g11 * y1 + g12 * y2
    gy2 = g02 * y0 + g12 * y1 + g22 * y2
    se, sn = ed * sz, nd * sz
    c00 = x0 * gx0 + x1 * gx1 + x2 * gx2 + se * se
    c01 = x0 * gy0 + x1 * gy1 + x2 * gy2 + se * sn
    c11 = y0 * gy0 + y1 * gy1 + y2 * gy2 + sn * sn
    return c00, c01, c11


@cached_njit(KEY, inline="always")
def _dem_nan(i, J, cov, major, minor, az, ce, le, rms, grazing):
    """Row ``i`` of the DEM step's outputs for a ray without a ground point: NaN, not grazing."""
    kk = J.shape[2] if J.shape[0] != 0 else 0
    for a in range(3):
        for c in range(kk):
            J[i, a, c] = math.nan
        for c in range(3):
            cov[i, a, c] = math.nan
    major[i] = minor[i] = az[i] = ce[i] = le[i] = rms[i] = math.nan
    grazing[i] = False


@cached_njit(KEY, error_model="numpy")
def _grazes(graze_r, ti, sig_t, fu2, sz, hi, mh, de_, dn_, du_, tiles, Z, margin, cw, r_h, c_h, kr, kc):
    """:func:`_dem_ray`'s grazing test: True where the ray (ENU direction ``de_, dn_, du_``, range
    ``ti``, hit height ``hi``) passes within 2 sigma of the terrain at one of the ranges
    ``graze_r ti`` farther than 3 ``sig_t`` from its hit (``fu2``: the chain's vertical variance,
    ``sz`` the surface's own sigma; the DEM as :func:`_grid_at` reads it, stepped from the hit's
    ``r_h, c_h`` by ``kr, kc`` rows and columns per metre), as
    :func:`geoloc.analysis.uncertainty._grazing`."""
    nr_ = graze_r.shape[0]
    nZr, nZc = Z.shape
    gz = False
    for q in range(nr_):
        kr_ = graze_r[q] * ti
        dr = kr_ - ti
        if abs(dr) <= 3.0 * sig_t:
            continue
        e_, n_, u_ = dr * de_, dr * dn_, dr * du_
        ray_h = hi + u_ + (e_ * e_ + n_ * n_) / (2.0 * mh)
        sig_v = math.sqrt(fu2 * (kr_ / ti) ** 2 + sz * sz)
        rq, cq = r_h + n_ * kr, c_h + e_ * kc
        # most samples are hundreds of metres above or below any node of their tile: no read
        if not _may_reach(tiles, nZr, nZc, margin, cw, rq, cq, ray_h - 2.0 * sig_v, ray_h + 2.0 * sig_v):
            continue
        ground = _grid_at(Z, margin, cw, rq, cq)
        if not math.isfinite(ground):
            continue
        if abs(ray_h - ground) < 2.0 * sig_v:
            gz = True
            break
    return gz


@cached_njit(KEY, error_model="numpy")
def _dem_ray(
    fr,
    i,
    d0,
    d1,
    d2,
    ti,
    la,
    lo,
    hi,
    sz,
    iterations,
    footprint,
    Z,
    tiles,
    lat_north,
    lon_west,
    idlat,
    idlon,
    margin,
    a_m,
    e2,
    gh_x,
    gh_w,
    graze_r,
    qt_n,
    rt,
    le90_per_sigma,
    Hf,
    outs,
):
    """The DEM surface step of one located ray ``i`` (chain columns ``fr`` (3, k), direction ``d``,
    range ``ti``, hit ``la, lo, hi``) into row ``i`` of the outputs; ``Hf`` is scratch for the
    footprint's heights, ``outs`` the outputs ``(J, cov, major, minor, az, ce, le, rms, grazing)``
    and ``Js``, scratch for the ray's (3, kk) Jacobian where ``J`` has no rows (the caller keeps none).

    The normal ``m = u - g_e e - g_n n`` starts from the DEM's slope at the hit (central
    differences over +-1 m east and north of the bilinear surface); with ``footprint`` it is then
    refitted ``iterations`` times to the plane of the DEM over the predicted footprint (5 x 5
    Gauss-Hermite nodes of N(0, C), ``g = L^-T E[z (h - h0)]``, ``C = L L^T`` the horizontal
    covariance of the step before, :func:`geoloc.analysis.uncertainty.surface_normal`). The plane
    is analytic: no perturbed ray is walked through the DEM again. Then the terrain's RMS
    departure from the plane over the final footprint (``rms``) and the grazing test of
    :func:`geoloc.analysis.uncertainty._grazing` (65 ranges from 0.5 to 1.5 times the hit's),
    and the covariance, ellipse, CE90 and LE90 as on a constant height.

    Not inlined into its kernel: numba's nested inlining of it with :func:`_grid_at` wrote row
    ``i``'s outputs to the wrong rows (measured: the ellipse and RMS garbage, the Jacobian right).
    """
    J, cov, major, minor, az, ce, le, rms, grazing, Js = outs
    ng = gh_x.shape[0]
    sp, cp = _sincos(la)
    sl, cl = _sincos(lo)
    E = (-sl, cl, 0.0)  # the ENU axes in ECEF
    N = (-sp * cl, -sp * sl, cp)
    U = (cp * cl, cp * sl, sp)
    w_ = 1.0 - e2 * sp * sp
    mh = a_m * (1.0 - e2) / (w_ * math.sqrt(w_)) + hi  # meridian radius + h
    nh = (a_m / math.sqrt(w_) + hi) * cp  # (prime vertical radius + h) cos lat
    # the hit's (row, column) and the grid's rows and columns per metre north and east there
    r_h, c_h = _grid_rc(lat_north, lon_west, idlat, idlon, la, lo)
    kr = -math.degrees(1.0 / mh) * idlat
    kc = math.degrees(1.0 / nh) * idlon
    cw = 180.0 * idlon
    # the slope of the bilinear surface at the hit: central differences over +-1 m
    g_n = (_grid_at(Z, margin, cw, r_h + kr, c_h) - _grid_at(Z, margin, cw, r_h - kr, c_h)) / 2.0
    g_e = (_grid_at(Z, margin, cw, r_h, c_h + kc) - _grid_at(Z, margin, cw, r_h, c_h - kc)) / 2.0
    Jo = J[i] if J.shape[0] != 0 else Js
    n_fit = iterations + 1 if footprint else 1
    G = _gram(fr) if n_fit > 1 else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    m0 = m1 = m2 = inv = 0.0
    # one more pass than the fits: the last footprint only measures the terrain's departure
    for it in range(n_fit + 1):
        if it > 0:
            # the footprint's plane: C = cov_en (NaN -> 0) + 1e-6 I = L L^T
            q00 = (c00 if math.isfinite(c00) else 0.0) + 1e-6
            q01 = c01 if math.isfinite(c01) else 0.0
            q11 = (c11 if math.isfinite(c11) else 0.0) + 1e-6
            l11 = math.sqrt(q00)
            l21 = q01 / l11
            l22 = math.sqrt(q11 - l21 * l21)
            sw = 0.0
            sh = 0.0
            for a in range(ng):
                for b in range(ng):
                    de = l11 * gh_x[a]
                    dn = l21 * gh_x[a] + l22 * gh_x[b]
                    H = _grid_at(Z, margin, cw, r_h + dn * kr, c_h + de * kc)
                    Hf[a * ng + b] = H  # the footprint's heights, read once per fit
                    if math.isfinite(H):
                        w = gh_w[a] * gh_w[b] / (2.0 * math.pi)
                        sw += w
                        sh += w * H
            h0 = sh / max(sw, 1e-300)
            eh0 = 0.0
            eh1 = 0.0
            for a in range(ng):
                for b in range(ng):
                    H = Hf[a * ng + b]
                    if math.isfinite(H):
                        w = gh_w[a] * gh_w[b] / (2.0 * math.pi)
                        eh0 += w * (H - h0) * gh_x[a]
                        eh1 += w * (H - h0) * gh_x[b]
            ge = eh0 / l11 - l21 / (l11 * l22) * eh1  # L^-T E[z (h - h0)]
            gn = eh1 / l22
            if it == n_fit:
                # the terrain's RMS departure from this plane over the footprint
                sr = 0.0
                for a in range(ng):
                    for b in range(ng):
                        de = l11 * gh_x[a]
                        dn = l21 * gh_x[a] + l22 * gh_x[b]
                        H = Hf[a * ng + b]
                        if math.isfinite(H):
                            w = gh_w[a] * gh_w[b] / (2.0 * math.pi)
                            dz = H - (h0 + de * ge + dn * gn)
                            sr += w * dz * dz
                rms[i] = math.sqrt(sr / max(sw, 1e-300))
                break
            g_e, g_n = ge, gn
        if not math.isfinite(g_e):
            g_e = 0.0  # at the DEM's edge: level
        if not math.isfinite(g_n):
            g_n = 0.0
        m0 = U[0] - g_e * E[0] - g_n * N[0]
        m1 = U[1] - g_e * E[1] - g_n * N[1]
        m2 = U[2] - g_e * E[2] - g_n * N[2]
        if it < n_fit - 1:
            # a footprint's fit needs only the horizontal covariance: a_x^T G a_y from the chain's
            # Gram matrix (3x3, summed once) instead of the (3, k) Jacobian; the last pass below
            # writes the Jacobian and the covariance column by column, as before
            c00, c01, c11 = _horizontal_cov(G, d0, d1, d2, m0, m1, m2, sz, E, N)
            continue
        inv, c00, c01, c02, c11, c12, c22 = _step(fr, d0, d1, d2, m0, m1, m2, True, sz, E, N, U, Jo)
    # grazing: the ray within 2 sigma of the terrain away from its hit
    k = fr.shape[1]
    st2 = 0.0
    fu2 = 0.0
    for c in range(k):
        f0, f1, f2 = fr[0, c], fr[1, c], fr[2, c]
        dt = -(m0 * f0 + m1 * f1 + m2 * f2) * inv
        st2 += dt * dt
        fu = U[0] * f0 + U[1] * f1 + U[2] * f2
        fu2 += fu * fu
    sig_t = math.sqrt(st2 + (sz * inv) ** 2)
    de_ = E[0] * d0 + E[1] * d1 + E[2] * d2
    dn_ = N[0] * d0 + N[1] * d1 + N[2] * d2
    du_ = U[0] * d0 + U[1] * d1 + U[2] * d2
    grazing[i] = _grazes(graze_r, ti, sig_t, fu2, sz, hi, mh, de_, dn_, du_, tiles, Z, margin, cw, r_h, c_h, kr, kc)
    _ellipse_out(i, c00, c01, c02, c11, c12, c22, qt_n, rt, le90_per_sigma, cov, major, minor, az, ce, le)


@cached_njit(KEY, parallel=True, error_model="numpy")
def chain_dem_kernel(
    lat,
    lon,
    h,
    heading,
    pitch,
    roll,
    angles,
    O,
    D,
    P,
    vel,
    axes,
    R_cam_last,
    R_base_body,
    lever,
    earth_ref,
    mount_axes,
    bore_axes,
    lens_code,
    lens_p,
    codes,
    sigmas,
    a_m,
    e2,
    hit_lat,
    hit_lon,
    hit_h,
    status,
    sz,
    iterations,
    footprint,
    Z,
    tiles,
    lat_north,
    lon_west,
    dlat,
    dlon,
    margin,
    gh_x,
    gh_w,
    graze_r,
    qt_n,
    rt,
    le90_per_sigma,
    J,
    cov,
    major,
    minor,
    az,
    ce,
    le,
    rms,
    grazing,
):
    """:func:`chain_kernel` and the DEM surface step (:func:`_dem_ray`) in one pass: each located ray's chain
    columns stay in a scratch row (3, k); a ray without a ground point skips the chain.

    ``P`` are the hits in ECEF (the range ``|P - O|``), ``hit_lat, hit_lon, hit_h`` their geodetic
    coordinates [rad, rad, m].
    """
    n = lat.shape[0]
    nj = axes.shape[0]
    ns = codes.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    for blk in prange(nb):
        Rn = np.empty((3, 3))
        Rb = np.empty((3, 3))
        Rt = np.empty((3, 3))
        Rt2 = np.empty((3, 3))
        Rc = np.empty((3, 3))
        Rj = np.empty((nj + 1, 3, 3))
        pp = lens_p.copy()
        fr = np.empty((3, ns))
        Hf = np.empty(gh_x.shape[0] * gh_x.shape[0])
        Js = np.empty((3, J.shape[2]))  # the ray's Jacobian when the caller keeps none (J with no rows)
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            if status[i] != _OK:
                _dem_nan(i, J, cov, major, minor, az, ce, le, rms, grazing)
                continue
            ti = _range(O, P, i)
            _chain_ray(
                i,
                lat,
                lon,
                h,
                heading,
                pitch,
                roll,
                angles,
                D,
                ti,
                vel,
                axes,
                R_cam_last,
                R_base_body,
                lever,
                earth_ref,
                mount_axes,
                bore_axes,
                lens_code,
                lens_p,
                codes,
                sigmas,
                a_m,
                e2,
                (Rn, Rb, Rt, Rt2, Rc, Rj, pp),
                fr,
            )
            _dem_ray(
                fr,
                i,
                D[i, 0],
                D[i, 1],
                D[i, 2],
                ti,
                hit_lat[i],
                hit_lon[i],
                hit_h[i],
                sz,
                iterations,
                footprint,
                Z,
                tiles,
                lat_north,
                lon_west,
                1.0 / dlat,
                1.0 / dlon,
                margin,
                a_m,
                e2,
                gh_x,
                gh_w,
                graze_r,
                qt_n,
                rt,
                le90_per_sigma,
                Hf,
                (J, cov, major, minor, az, ce, le, rms, grazing, Js),
            )
