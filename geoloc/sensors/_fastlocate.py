"""Fused numba kernel for :func:`geoloc.locate.locate` on the inflated ellipsoid, for any frame sensor.

The same mathematics as the numpy reference path (lens -> frame graph -> line
of sight -> [Q17 eq. 10-11] -> Vermeille), written per ray so that a million
rays cost one pass over memory instead of ~100 temporary arrays. The chain is
passed as data, not code: the lens as a model code and its parameter vector
(:meth:`geoloc.sensors.lenses.Lens.as_array`), the gimbal joints as axis codes
with one array of angles each, the boresight/optical turn and the mount as
3x3 matrices, the lever arm as a vector, and a flag for earth-referenced
gimbals. So every preset, lens, mount, boresight and lever arm runs compiled
(no silent fallback). ``tests/sensors/test_fastlocate.py`` holds it equal to the
reference path, ray for ray.

The ellipsoid constants are arguments too, so a cached compile never keeps a
stale constant.

What makes it fast (``benchmarks/bench_locate.py``; each step checked against the
numpy reference path, and each lane function against libm or PROJ, by
``tests/sensors/test_fastlocate.py``):

- the rays run in blocks of :data:`_BLOCK`, hop by hop: each hop is one loop over the
  block (a ``*_block`` function) whose body has selects instead of branches, so LLVM
  compiles it to SIMD code (four rays per AVX2 instruction). The lane versions cover
  every valid case; the rare lanes they refuse (an angle beyond 64 rad, a pixel off the
  undistortion map or not converged, a geodetic case outside the cube root's range or on
  the polar axis) are recomputed by the scalar code right after the loop. Against the
  one-ray-at-a-time kernel: 1.85x per CPU second on both benchmark sensors;
- every angle's sine and cosine come from one range reduction and two short
  polynomials (:func:`sincos_lanes`, fdlibm's kernels; within 2.3e-16 of libm's
  values for the angles a pose may hold), computed once per ray and shared by the line
  of sight and the lever arm;
- the lens is passed as :meth:`geoloc.sensors.lenses.Lens.kernel_array`: for a
  Brown lens its undistortion map, so the inverse is a bilinear guess and two
  Newton steps (:func:`geoloc.sensors.lenses.unproject_map_lanes`) instead of a full
  iteration from the distorted point (5-8 steps); the lens's slots are read into a tuple
  before the loop over pixels, and the map's gathers run in a loop of their own, so that
  the Newton steps (and a pinhole's K^-1) compile to SIMD code: 42 -> 6 ns a ray for the
  [Q17] pinhole, 60 -> 23 ns for the benchmark's Brown lens (one thread, CPU time);
- an input holding one value for every ray (a frame's pose, one target height) reaches the
  kernel as that one value (:func:`_col`, :func:`_part`), not broadcast to the batch; the line of
  sight's statuses and the result's refraction shift (0 where OK) are written by the kernel, not
  by numpy passes afterwards: fewer bytes on fresh pages, whose faults were a quarter of the
  CPU time of ``locate()`` (sys time; 1 M rays). Against the previous kernel and wrapper in
  one process, calls alternating (load 17-22), outputs bit for bit the same: a frame (one
  pose, 1 M pixels) 1.34x per CPU second, the benchmark's pinhole 1.03x, its turret 1.08x;
- ECEF -> geodetic is Vermeille's closed form (:func:`geodetic_lanes`) with ``sqrt``
  for ``hypot``, Cephes' ``atan`` (:func:`atan_lanes`, :func:`atan2_lanes`) and the
  cube root as a series and three Newton steps; :func:`geodetic_fast` is the scalar
  version the refused lanes take.

Why numba: the numpy path is bound by temporaries; see ``benchmarks/bench_locate.py``.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from geoloc import status as _status_module
from geoloc.geodesy import _nbgeo
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, geodetic, prange  # noqa: F401 (geodetic: public helper)
from geoloc.geodesy.ellipsoid import E2, A, B
from geoloc.sensors import lenses as _lenses_module
from geoloc.sensors.lenses import (
    _N_SLOTS,
    BROWN,
    PINHOLE,
    _from_pixel_nb,
    _unit_nb,
    _slots,
    _unproject_map_guess,
    unproject_map_nb,
    _unproject_map_refine,
    unproject_nb,
)
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

#: The one fast-math flag of the arithmetic hops (sines and cosines, lens, rotations, geodetic):
#: ``contract``, a * b + c as one fused multiply-add (FMA), rounded once instead of twice. Safe
#: here: it never reorders an expression and keeps NaN and infinity (the flags ``nnan``/``ninf``
#: would drop the isfinite / isnan tests that make a bad lane's status), each fused operation
#: is at least as accurate as the pair it replaces, and the error-free steps the polynomials
#: rely on stay exact (fn * pi/2's first 33 bits is exact with or without FMA; fdlibm's
#: (1 - w) - hz is exact by Sterbenz's lemma). The hit (``_hit_block``) keeps separate roundings:
#: its status tests (origin below the surface, discriminant < 0) decide as the numpy path's do,
#: for a ray that grazes the surface too. Measured: 1.07-1.09x per CPU second on the benchmark
#: rays; the results move by < 2e-15 rad (1e-8 m).
_CONTRACT = {"contract"}


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
    return (
        R[0, 0] * x + R[1, 0] * y + R[2, 0] * z,
        R[0, 1] * x + R[1, 1] * y + R[2, 1] * z,
        R[0, 2] * x + R[1, 2] * y + R[2, 2] * z,
    )


@cached_njit(KEY, inline="always")
def _body_to_ned(heading, pitch, roll, x, y, z):
    """(rx(roll) ry(pitch) rz(heading))^T (x, y, z) [Q17 eq. 6, transposed]."""
    x, y, z = _turn_back(0, roll, x, y, z)
    x, y, z = _turn_back(1, pitch, x, y, z)
    return _turn_back(2, heading, x, y, z)


# fdlibm's (and musl's) __sin / __cos kernels on [-pi/4, pi/4] (Sun Microsystems, 1993;
# errors below 1 ulp there) and its medium-size Cody-Waite reduction by pi/2 in two parts.
_INV_PIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e00  # first 33 bits of pi/2: fn * _PIO2_1 is exact for |fn| < 2^20
_PIO2_1T = 6.07710050650619224932e-11  # pi/2 - _PIO2_1
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
_SINCOS_MAX = 64.0  # beyond (never for a valid pose: its angles are within 2 pi), libm's sin and cos


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
    held to ``ecef_to_geodetic`` by ``tests/sensors/test_fastlocate.py``.
    """
    e4, rho, q, r, g = _vermeille_front(x, y, z, a_m, e2)
    d, dz, h = _vermeille_back(np.cbrt(g), e4, rho, z, q, r, e2)
    return 2.0 * math.atan(z / (d + dz)), math.atan2(y, x), h


@cached_njit(KEY, inline="always", error_model="numpy")
def _vermeille_front(x, y, z, a_m, e2):
    """Vermeille's closed form up to its cube root's argument g = 1 + s + sqrt(s (2 + s)):
    (e^4, rho, q, r, g) (:func:`geoloc.geodesy.ellipsoid.vermeille`)."""
    e4 = e2 * e2
    rho2 = x * x + y * y
    rho = math.sqrt(rho2)
    p = rho2 / (a_m * a_m)
    q = (1.0 - e2) * z * z / (a_m * a_m)
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r * r * r)
    return e4, rho, q, r, 1.0 + s + math.sqrt(s * (2.0 + s))


@cached_njit(KEY, inline="always", error_model="numpy")
def _vermeille_back(t, e4, rho, z, q, r, e2):
    """Vermeille's closed form from the cube root t = cbrt(g) on: (d, sqrt(d^2 + z^2), h); the
    latitude is then 2 atan(z / (d + dz)) (:func:`geoloc.geodesy.ellipsoid.vermeille`)."""
    u = r * (1.0 + t + 1.0 / t)
    v = math.sqrt(u * u + e4 * q)
    w = e2 * (u + v - q) / (2.0 * v)
    k = math.sqrt(u + v + w * w) - w
    d = k * rho / (k + e2)
    dz = math.sqrt(d * d + z * z)
    return d, dz, (k + e2 - 1.0) / k * dz


# Lane versions: the same mathematics with selects for branches, so that a loop over a block
# of rays compiles to SIMD code (AVX2: four rays per instruction). The kernel runs them over
# blocks of _BLOCK rays and fixes the rare lanes they do not cover with the scalar versions.
_BLOCK = 256


@cached_njit(KEY, inline="always", error_model="numpy")
def sincos_lanes(a):
    """(sin a, cos a) with one range reduction and the quadrant by selects (no branches).

    Absolute error < 2.3e-16 for |a| <= 64, NaN for NaN and inf.

    Beyond 64 rad the two-part reduction loses digits: the kernel recomputes those with libm.
    """
    fn = np.floor(a * _INV_PIO2 + 0.5)  # a float (math.floor is an int in numba: garbage for inf)
    r = (a - fn * _PIO2_1) - fn * _PIO2_1T
    z = r * r
    w = z * z
    s = r + z * r * (_S1 + z * (_S2 + z * (_S3 + z * _S4) + z * w * (_S5 + z * _S6)))
    cr = z * (_C1 + z * (_C2 + z * _C3)) + w * w * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    ww = 1.0 - hz
    c = ww + (((1.0 - ww) - hz) + z * cr)
    q = fn - 4.0 * np.floor(fn * 0.25)  # the quadrant, 0..3, as a float
    odd = (q == 1.0) | (q == 3.0)
    s2 = c if odd else s
    c2 = s if odd else c
    s2 = -s2 if q >= 2.0 else s2
    c2 = -c2 if (q == 1.0) | (q == 2.0) else c2
    return s2, c2


# Cephes' atan (S. L. Moshier, 1984-2000; atan.c): reduction to |x| <= 0.66 and a rational
# P(z)/Q(z) of degree 4/5 in z = x^2; peak relative error 1.8e-16 over the real line.
_T3P8 = 2.41421356237309504880  # tan(3 pi / 8)
_MOREBITS = 6.123233995736765886130e-17  # pi/2 - (pi/2 rounded)
_AP0, _AP1, _AP2 = -8.750608600031904122785e-01, -1.615753718733365076637e01, -7.500855792314704667340e01
_AP3, _AP4 = -1.228866684490136173410e02, -6.485021904942025371773e01
_AQ0, _AQ1, _AQ2 = 2.485846490142306297962e01, 1.650270098316988542046e02, 4.328810604912902668951e02
_AQ3, _AQ4 = 4.853903996359136964868e02, 1.945506571482613964425e02
_PIO2 = 1.5707963267948966
_PIO4 = 0.7853981633974483


@cached_njit(KEY, inline="always", error_model="numpy")
def atan_lanes(x):
    """atan(x) without branches (Cephes' reduction by selects); NaN for NaN."""
    ax = abs(x)
    big = ax > _T3P8
    mid = ax > 0.66
    t = -1.0 / ax if big else ((ax - 1.0) / (ax + 1.0) if mid else ax)
    y0 = _PIO2 if big else (_PIO4 if mid else 0.0)
    extra = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    z = t * t
    p = (((_AP0 * z + _AP1) * z + _AP2) * z + _AP3) * z + _AP4
    q = ((((z + _AQ0) * z + _AQ1) * z + _AQ2) * z + _AQ3) * z + _AQ4
    r = y0 + ((t * (z * p / q) + t) + extra)
    return -r if x < 0.0 else r


@cached_njit(KEY, inline="always", error_model="numpy")
def atan2_lanes(y, x):
    """atan2(y, x) from :func:`atan_lanes` of the smaller over the larger magnitude; NaN at (0, 0).

    The kernel recomputes a NaN from finite inputs with libm (atan2(0, 0) = 0).
    """
    ax, ay = abs(x), abs(y)
    swap = ay > ax
    r = atan_lanes((ax / ay) if swap else (ay / ax))
    r = (_PIO2 - r) if swap else r
    r = (math.pi - r) if x < 0.0 else r
    return -r if y < 0.0 else r


@cached_njit(KEY, inline="always", error_model="numpy")
def geodetic_lanes(x, y, z, a_m, e2):
    """:func:`geodetic_fast` without library calls or branches; ``ok`` False where it does not apply.

    Vermeille's cube root t = cbrt(g), g = 1 + s + sqrt(s (2 + s)), is two terms of its
    series about 1 and three Newton steps (error below 1e-16 for 1 <= g <= 1.1; g < 1.04 for
    any point above a quarter of the Earth's radius below its surface). ``ok`` is False for
    g outside [1, 1.1] or a NaN; the kernel recomputes those lanes with :func:`geodetic_fast`.
    """
    e4, rho, q, r, g = _vermeille_front(x, y, z, a_m, e2)
    ok = (g >= 1.0) & (g <= 1.1)
    d1 = g - 1.0
    t = 1.0 + d1 * (1.0 / 3.0) - d1 * d1 * (1.0 / 9.0)
    t = (2.0 * t + g / (t * t)) * (1.0 / 3.0)
    t = (2.0 * t + g / (t * t)) * (1.0 / 3.0)
    t = t - (t * t * t - g) / (3.0 * t * t)
    d, dz, h = _vermeille_back(t, e4, rho, z, q, r, e2)
    lat = 2.0 * atan_lanes(z / (d + dz))
    lon = atan2_lanes(y, x)
    ok = ok & (not math.isnan(lon)) & (not math.isnan(lat)) & (not math.isnan(h))
    return lat, lon, h, ok


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _sincos_block(a, s, c):
    """s[i], c[i] = :func:`sincos_lanes` (a[i]), libm's beyond 64 rad (never a valid pose's angle)."""
    for i in range(a.shape[0]):
        s[i], c[i] = sincos_lanes(a[i])
    for i in range(a.shape[0]):
        if abs(a[i]) > _SINCOS_MAX:
            s[i], c[i] = math.sin(a[i]), math.cos(a[i])


@cached_njit(KEY, error_model="numpy")
def _valid_block(lat, lon, h, heading, pitch, roll, row, col, target_h, ranges, b_m, ok):
    """ok[i] = 1.0 where the pose, the pixel and the target height are valid, else 0.0."""
    for i in range(lat.shape[0]):
        v = (
            _in(lat[i], ranges[0, 0], ranges[0, 1])
            & _in(lon[i], ranges[1, 0], ranges[1, 1])
            & _in(h[i], ranges[2, 0], ranges[2, 1])
            & _in(heading[i], ranges[3, 0], ranges[3, 1])
            & _in(pitch[i], ranges[4, 0], ranges[4, 1])
            & _in(roll[i], ranges[5, 0], ranges[5, 1])
            & math.isfinite(row[i])
            & math.isfinite(col[i])
            & math.isfinite(target_h[i])
            & (b_m + target_h[i] > 0.0)
        )
        ok[i] = 1.0 if v else 0.0


@cached_njit(KEY, error_model="numpy")
def _angle_valid_block(a, lo, hi, ok):
    """ok[i] = 0.0 where the joint angle a[i] is outside [lo, hi] or not finite."""
    for i in range(a.shape[0]):
        ok[i] = ok[i] if _in(a[i], lo, hi) else 0.0


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _unproject_block(code, p, row, col, x, y, z, good):
    """1-based pixels -> unit directions in the optical frame (OpenCV's 0-based u, v).

    The lens slots are read once into a tuple (:func:`geoloc.sensors.lenses._slots`) so that
    the loops over pixels touch no memory but the pixels' and the outputs': LLVM cannot prove
    that ``p`` and the outputs do not overlap, and a load from ``p`` inside the loop (the Brown
    map's nodes above all: an index computed from the pixel) kept it scalar (measured: 42 ns a
    ray for a pinhole, 60 for the Brown lens, before; the same values, bit for bit, after).
    """
    pt = _slots(p)
    if code == BROWN and p.shape[0] > _N_SLOTS:
        for i in range(row.shape[0]):  # the map's bilinear guess: gathers, scalar
            x[i], y[i], good[i] = _unproject_map_guess(p, col[i] - 1.0, row[i] - 1.0)
        for i in range(row.shape[0]):  # two Newton steps, on registers only: SIMD
            x[i], y[i], z[i], good[i] = _unproject_map_refine(pt, col[i] - 1.0, row[i] - 1.0, x[i], y[i], good[i])
        for i in range(row.shape[0]):
            if not good[i]:  # off the map or not converged in two steps: the full iteration
                x[i], y[i], z[i] = unproject_nb(code, p, col[i] - 1.0, row[i] - 1.0)
    elif code == PINHOLE:
        for i in range(row.shape[0]):  # unproject_nb's pinhole case: K^-1 (u, v, 1), normalised
            xt, yt = _from_pixel_nb(pt, col[i] - 1.0, row[i] - 1.0)
            x[i], y[i], z[i] = _unit_nb(xt, yt)
    else:
        for i in range(row.shape[0]):
            x[i], y[i], z[i] = unproject_map_nb(code, p, col[i] - 1.0, row[i] - 1.0)


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _mul_T_block(R, x, y, z):
    """(x, y, z)[i] = R^T (x, y, z)[i]."""
    for i in range(x.shape[0]):
        x[i], y[i], z[i] = _mul_T(R, x[i], y[i], z[i])


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _turn_back_block(axis, s, c, x, y, z):
    """(x, y, z)[i] turned back about ``axis`` by the angle of sine s[i] and cosine c[i]."""
    if axis == 0:
        for i in range(x.shape[0]):
            x[i], y[i], z[i] = _turn_back_cs(0, c[i], s[i], x[i], y[i], z[i])
    elif axis == 1:
        for i in range(x.shape[0]):
            x[i], y[i], z[i] = _turn_back_cs(1, c[i], s[i], x[i], y[i], z[i])
    else:
        for i in range(x.shape[0]):
            x[i], y[i], z[i] = _turn_back_cs(2, c[i], s[i], x[i], y[i], z[i])


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _body_to_ned_block(sc, x, y, z):
    """(x, y, z)[i] from body to NED, with the attitude's sines and cosines in rows 0-5 of ``sc``."""
    for i in range(x.shape[0]):
        x[i], y[i], z[i] = _body_to_ned_cs(sc[1, i], sc[0, i], sc[3, i], sc[2, i], sc[5, i], sc[4, i], x[i], y[i], z[i])


@cached_njit(KEY, error_model="numpy")
def _hit_block(
    sc,
    x,
    y,
    z,
    okv,
    h,
    target_h,
    row,
    col,
    flag_off,
    width,
    height,
    lever,
    a_m,
    b_m,
    e2,
    out_o,
    out_d,
    out_s,
    out_ecef,
    out_status,
    px,
    py,
    pz,
):
    """NED -> ECEF [Q17 eq. 5], the optical centre with the lever arm, and ray x inflated ellipsoid [Q17 eq. 10-11]."""
    for i in range(x.shape[0]):
        xi, yi, zi = x[i], y[i], z[i]
        sp, cp, sl, cl = sc[6, i], sc[7, i], sc[8, i], sc[9, i]
        dx = -sp * cl * xi - sl * yi - cp * cl * zi
        dy = -sp * sl * xi + cl * yi - cp * sl * zi
        dz = cp * xi - sp * zi
        rn = a_m / math.sqrt(1.0 - e2 * sp * sp)
        ox = (rn + h[i]) * cp * cl
        oy = (rn + h[i]) * cp * sl
        oz = (rn * (1.0 - e2) + h[i]) * sp
        lx, ly, lz = _body_to_ned_cs(
            sc[1, i], sc[0, i], sc[3, i], sc[2, i], sc[5, i], sc[4, i], lever[0], lever[1], lever[2]
        )
        ox += -sp * cl * lx - sl * ly - cp * cl * lz
        oy += -sp * sl * lx + cl * ly - cp * sl * lz
        oz += cp * lx - sp * lz
        out_o[i, 0], out_o[i, 1], out_o[i, 2] = ox, oy, oz
        out_d[i, 0], out_d[i, 1], out_d[i, 2] = dx, dy, dz
        ht = target_h[i]
        aa = a_m + ht
        bb = b_m + ht
        opx, opy, opz = ox / aa, oy / aa, oz / bb
        dpx, dpy, dpz = dx / aa, dy / aa, dz / bb
        qa = dpx * dpx + dpy * dpy + dpz * dpz
        qb = 2.0 * (opx * dpx + opy * dpy + opz * dpz)
        qc = opx * opx + opy * opy + opz * opz - 1.0
        disc = qb * qb - 4.0 * qa * qc
        q = -0.5 * (qb - math.sqrt(disc))
        s1, s2 = q / qa, qc / q
        r_, c_ = row[i], col[i]
        # a finite pixel off the sensor is OUTSIDE_SENSOR even where the lens has no ray for it
        # (a distortion model beyond its domain gives NaN): the first reason wins: off the sensor says what to fix
        given = (okv[i] != 0.0) & math.isfinite(r_) & math.isfinite(c_)
        inside = (not flag_off) | ((r_ >= 0.5) & (r_ <= height + 0.5) & (c_ >= 0.5) & (c_ <= width + 0.5))
        status = (
            _INVALID
            if not given
            else _OUTSIDE
            if not inside
            else _INVALID
            if not math.isfinite(dx)
            else _BELOW
            if qc < 0.0
            else _SKY
            if (disc < 0.0) | (qb >= 0.0)
            else _OK
        )
        sol = min(s1, s2) if status == _OK else math.nan
        out_status[i] = status
        out_s[i] = sol
        px[i], py[i], pz[i] = ox + sol * dx, oy + sol * dy, oz + sol * dz
        out_ecef[i, 0], out_ecef[i, 1], out_ecef[i, 2] = px[i], py[i], pz[i]


@cached_njit(KEY, error_model="numpy", fastmath=_CONTRACT)
def _geodetic_block(x, y, z, a_m, e2, status, lat, lon, h, good):
    """:func:`geodetic_lanes` over arrays; NaN where ``status`` is not OK, :func:`geodetic_fast` where a lane failed."""
    for i in range(x.shape[0]):
        lat[i], lon[i], h[i], good[i] = geodetic_lanes(x[i], y[i], z[i], a_m, e2)
    for i in range(x.shape[0]):
        if status[i] != _OK:
            lat[i], lon[i], h[i] = math.nan, math.nan, math.nan
        elif not good[i]:
            lat[i], lon[i], h[i] = geodetic_fast(x[i], y[i], z[i], a_m, e2)


@cached_njit(KEY, inline="always")
def _joint_angles(j, angle0, angle1, angle2, angles_more):
    """The angles of joint ``j``: one of the first three joints' arrays, else row j - 3 of ``angles_more``."""
    if j == 0:
        return angle0
    if j == 1:
        return angle1
    if j == 2:
        return angle2
    return angles_more[j - 3]


@cached_njit(KEY, inline="always")
def _part(a, k0, k1, buf):
    """The block's values of a per-ray input: ``a[k0:k1]``, or ``buf`` filled with ``a[0]`` when ``a``
    holds one value for every ray (a frame's pose, one target height): the caller passes such an
    input as one value, not broadcast to the batch (an array of n doubles written, then read)."""
    if a.shape[0] == 1:
        buf[:] = a[0]
        return buf
    return a[k0:k1]


@cached_njit(KEY, error_model="numpy")
def _status_block(status, los_status, shift):
    """The line of sight's status (INVALID_INPUT and OUTSIDE_SENSOR kept, else OK) and, when
    ``shift`` has room, the refraction shift of a result without refraction (0.0 where OK, else NaN)."""
    for i in range(status.shape[0]):
        st = status[i]
        los_status[i] = st if (st == _INVALID) | (st == _OUTSIDE) else _OK
    if shift.shape[0] > 0:
        for i in range(status.shape[0]):
            shift[i] = 0.0 if status[i] == _OK else math.nan


@cached_njit(KEY, parallel=True, error_model="numpy")
def locate_kernel(
    n,
    lat,
    lon,
    h,
    heading,
    pitch,
    roll,
    angle0,
    angle1,
    angle2,
    angles_more,
    row,
    col,
    target_h,
    lens_code,
    lens_p,
    width,
    height,
    flag_off,
    axes,
    R_cam_last,
    has_mount,
    R_base_body,
    lever,
    earth_ref,
    ranges,
    angle_lo,
    angle_hi,
    a_m,
    b_m,
    e2,
    out_lat,
    out_lon,
    out_h,
    out_ecef,
    out_s,
    out_o,
    out_d,
    out_status,
    out_los_status,
    out_shift,
):
    """The fused chain over blocks of :data:`_BLOCK` rays, hop by hop, each hop one loop over the block.

    Each hop's loop (a ``*_block`` function) is branch-free (selects), so that LLVM compiles
    it to SIMD code; the few lanes a lane version does not cover (an angle beyond 64 rad, a
    pixel off the undistortion map or not converged, a geodetic case outside the cube root's
    range) are recomputed by the scalar code right after. Rows of the per-block scratch
    ``sc``: sine and cosine of heading, pitch, roll, latitude, longitude and of each joint,
    then the direction x, y, z, a validity flag (1.0 / 0.0), and the hit x, y, z.

    ``n`` rays; each per-ray input (pose fields, joint angles, pixel, target height) holds n
    values or one for all (:func:`_part`). ``out_los_status``: the line of sight's statuses;
    ``out_shift``: n values of a refraction shift of 0 where OK, NaN elsewhere, or empty (not wanted).
    """
    nj = axes.shape[0]
    rx = 10 + 2 * nj
    rok = rx + 3
    rp = rx + 4
    nblocks = (n + _BLOCK - 1) // _BLOCK
    for b in prange(nblocks):
        k0 = b * _BLOCK
        k1 = min(n, k0 + _BLOCK)
        m = k1 - k0
        sc = np.empty((rx + 7, _BLOCK))
        inp = np.empty((9 + nj, _BLOCK))  # the block's values of the inputs given as one value
        good = np.empty(_BLOCK, dtype=np.bool_)
        x, y, z = sc[rx, :m], sc[rx + 1, :m], sc[rx + 2, :m]
        lat_b = _part(lat, k0, k1, inp[0, :m])
        lon_b = _part(lon, k0, k1, inp[1, :m])
        h_b = _part(h, k0, k1, inp[2, :m])
        heading_b = _part(heading, k0, k1, inp[3, :m])
        pitch_b = _part(pitch, k0, k1, inp[4, :m])
        roll_b = _part(roll, k0, k1, inp[5, :m])
        row_b = _part(row, k0, k1, inp[6, :m])
        col_b = _part(col, k0, k1, inp[7, :m])
        th_b = _part(target_h, k0, k1, inp[8, :m])
        _sincos_block(heading_b, sc[0, :m], sc[1, :m])
        _sincos_block(pitch_b, sc[2, :m], sc[3, :m])
        _sincos_block(roll_b, sc[4, :m], sc[5, :m])
        _sincos_block(lat_b, sc[6, :m], sc[7, :m])
        _sincos_block(lon_b, sc[8, :m], sc[9, :m])
        for j in range(nj):
            a_j = _part(_joint_angles(j, angle0, angle1, angle2, angles_more), k0, k1, inp[9 + j, :m])
            _sincos_block(a_j, sc[10 + 2 * j, :m], sc[11 + 2 * j, :m])
        _valid_block(
            lat_b,
            lon_b,
            h_b,
            heading_b,
            pitch_b,
            roll_b,
            row_b,
            col_b,
            th_b,
            ranges,
            b_m,
            sc[rok, :m],
        )
        for j in range(nj):
            a_j = _part(_joint_angles(j, angle0, angle1, angle2, angles_more), k0, k1, inp[9 + j, :m])
            _angle_valid_block(a_j, angle_lo[j], angle_hi[j], sc[rok, :m])
        # pixel -> optical frame -> last joint frame -> ... -> gimbal base (or NED) -> body -> NED
        _unproject_block(lens_code, lens_p, row_b, col_b, x, y, z, good[:m])
        _mul_T_block(R_cam_last, x, y, z)
        for j in range(nj - 1, -1, -1):
            _turn_back_block(axes[j], sc[10 + 2 * j, :m], sc[11 + 2 * j, :m], x, y, z)
        if not earth_ref:
            if has_mount:
                _mul_T_block(R_base_body, x, y, z)
            _body_to_ned_block(sc, x, y, z)
        _hit_block(
            sc,
            x,
            y,
            z,
            sc[rok, :m],
            h_b,
            th_b,
            row_b,
            col_b,
            flag_off,
            width,
            height,
            lever,
            a_m,
            b_m,
            e2,
            out_o[k0:k1],
            out_d[k0:k1],
            out_s[k0:k1],
            out_ecef[k0:k1],
            out_status[k0:k1],
            sc[rp, :m],
            sc[rp + 1, :m],
            sc[rp + 2, :m],
        )
        # ECEF -> geodetic, Vermeille's closed form (as geoloc.geodesy.ellipsoid.ecef_to_geodetic)
        _geodetic_block(
            sc[rp, :m],
            sc[rp + 1, :m],
            sc[rp + 2, :m],
            a_m,
            e2,
            out_status[k0:k1],
            out_lat[k0:k1],
            out_lon[k0:k1],
            out_h[k0:k1],
            good[:m],
        )
        _status_block(out_status[k0:k1], out_los_status[k0:k1], out_shift[k0:k1] if out_shift.shape[0] else out_shift)


def _col(a, shape: tuple) -> np.ndarray:
    """A C-contiguous, writable float64 array of the values of ``a`` for a batch of ``shape``: one
    value (length 1) when ``a`` holds one, else ``a`` broadcast to ``shape``, flattened.

    Always the same array type, so numba compiles the kernel once (a readonly broadcast view
    would be a second signature). One value is not broadcast: the kernel reads it for every ray
    (:func:`_part`), where a broadcast copy was n doubles written to fresh pages and read back
    (a frame's pose: nine such arrays; the benchmark's one target height: 8 MB per 1 M rays).
    """
    a = np.asarray(a, float)
    if a.size == 1:
        return np.array([a.reshape(-1)[0]])
    if a.shape == shape and a.flags.c_contiguous and a.flags.writeable:
        return a.reshape(-1)  # already the kernel's array type: no copy
    return np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1)  # broadcast views are read-only: copy


def _lens_vector(lens) -> np.ndarray:
    """The kernel's lens vector: :meth:`Lens.kernel_array` (with a Brown lens's undistortion map), writable.

    A writable copy so that the kernel keeps one signature (the cached array is read-only).
    """
    return np.array(lens.kernel_array(), float)


def serves(sensor) -> bool:
    """True if the kernel computes ``sensor`` exactly: a FrameSensor with one (unbatched) lens and
    no per-sample Monte Carlo perturbation (``R_base_extra``, ``R_bore_extra``, ``lever_extra_m``)."""
    return bool(getattr(sensor, "compiled", False))  # FrameSensor.compiled (no import: frame.py imports this)


def line_of_sight_fast(pose, sensor, row, col, outside="flag"):
    """:meth:`geoloc.sensors.frame.FrameSensor.line_of_sight` through :func:`locate_kernel`: (o, d, status).

    The kernel's line of sight, with the statuses a line of sight has (INVALID_INPUT,
    OUTSIDE_SENSOR, else OK; the kernel's hit on the ellipsoid is dropped).
    """
    out = locate_fast(pose, sensor, row, col, 0.0, outside=outside)
    return out[6], out[7], out[8]


def locate_fast(pose, sensor, row, col, target_h, outside="flag", refraction_m: bool = False) -> tuple:
    """Run :func:`locate_kernel` for a :class:`geoloc.sensors.frame.FrameSensor`; arrays shaped like the batch.

    Returns
    -------
    lat, lon, h, ecef, slant_range, status, origin_ecef, direction_ecef, los_status, shift
        ``los_status``: the line of sight's statuses (INVALID_INPUT and OUTSIDE_SENSOR kept, else
        OK); ``shift``: with ``refraction_m``, a result's refraction shift when refraction is off
        (0.0 where OK, NaN elsewhere), else None. Both are written by the kernel while each block's
        statuses are in the cache, not by numpy passes over the batch afterwards.
    """
    if not serves(sensor):
        raise ValueError(
            "the compiled kernel takes a FrameSensor with one lens and no per-sample perturbations; use engine='numpy'"
        )
    names = sensor.angle_names
    angles = [pose.angle(a) for a in names]
    fields = [pose.lat, pose.lon, pose.h, pose.heading, pose.pitch, pose.roll, row, col, target_h, *angles]
    shape = np.broadcast_shapes(*(np.shape(v) for v in fields))
    flat = [_col(v, shape) for v in fields]
    n = math.prod(shape)
    # the first three joints' angles as the pose holds them (no copy when they are the batch's
    # float64 arrays already: a copy into one (n, k) array cost 6.5 ns a ray of ~150), more in rows
    joint = flat[9:12] + [flat[0][:0]] * (3 - len(flat[9:12]))  # unused: empty
    extra = flat[12:]
    width_more = max((len(a) for a in extra), default=n)  # rows of one length: n, or 1 when all hold one value
    more = np.stack([np.broadcast_to(a, (width_more,)) for a in extra]) if extra else np.empty((0, n))
    has_mount = not np.array_equal(sensor.R_base_body, np.eye(3))
    ranges = np.array([pose.RANGES[k] for k in ("lat", "lon", "h", "heading", "pitch", "roll")], dtype=float)
    lo = np.array([pose.RANGES.get(a, pose.ANGLE_RANGE)[0] for a in names], dtype=float)
    hi = np.array([pose.RANGES.get(a, pose.ANGLE_RANGE)[1] for a in names], dtype=float)
    axes = np.array([_AXIS[j.axis] for j in sensor.gimbal.joints], dtype=np.int64)
    out_lat, out_lon, out_h, out_s = (np.empty(n) for _ in range(4))
    out_ecef, out_o, out_d = (np.empty((n, 3)) for _ in range(3))
    out_status = np.empty(n, dtype=np.uint8)
    out_los_status = np.empty(n, dtype=np.uint8)
    out_shift = np.empty(n if refraction_m else 0)
    lens = sensor.lens
    locate_kernel(
        n,
        *flat[:6],
        *joint,
        more,
        *flat[6:9],
        int(lens.code),
        _lens_vector(lens),
        float(lens.width),
        float(lens.height),
        outside == "flag",
        axes,
        np.ascontiguousarray(sensor.R_cam_last),
        has_mount,
        np.ascontiguousarray(sensor.R_base_body),
        np.array(sensor.lever_arm_m, float),
        bool(sensor.gimbal.earth_referenced),
        ranges,
        lo,
        hi,
        float(A),
        float(B),
        float(E2),
        out_lat,
        out_lon,
        out_h,
        out_ecef,
        out_s,
        out_o,
        out_d,
        out_status,
        out_los_status,
        out_shift,
    )
    return (
        out_lat.reshape(shape),
        out_lon.reshape(shape),
        out_h.reshape(shape),
        out_ecef.reshape(shape + (3,)),
        out_s.reshape(shape),
        out_status.reshape(shape),
        out_o.reshape(shape + (3,)),
        out_d.reshape(shape + (3,)),
        out_los_status.reshape(shape),
        out_shift.reshape(shape) if refraction_m else None,
    )
