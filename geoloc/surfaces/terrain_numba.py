"""Compiled kernel of the exact first-hit DEM solver (see :mod:`geoloc.surfaces.terrain`).

Why numba: the walk is a per-ray loop over a data-dependent number of cells
(tens, with early exit at the first hit); in numpy it would be a masked loop
over the longest ray with a dozen temporary arrays per step, about two orders
of magnitude slower than the 1 M rays/s goal. The kernel is compiled once
(numba's disk cache keeps the machine code, keyed also on the ellipsoid constants and
the modules the kernels take code from: :func:`geoloc.geodesy._nbgeo.cached_njit`), and
once only: :func:`walk` always passes the same argument types.

The kernel works in ECEF with the exact cell boundaries of a geographic grid:
a meridian lambda = lambda_j is a plane through the Z axis, and a parallel
phi = phi_i of constant *geodetic* latitude is the cone

    z + R_N(phi) e^2 sin(phi) = rho tan(phi),   rho = sqrt(x^2 + y^2)

(from x = (R_N + h) cos phi, z = (R_N (1 - e^2) + h) sin phi, docs/method.md
section 1), so the cell where the ray leaves the current one is found with one
division per meridian and one quadratic per parallel, without approximation.
The walk is a digital differential analyser on these boundaries (:func:`_walk`):
each crossing is computed once, when its boundary becomes a side of the ray's
cell or block; above the blocks a min/max hierarchy (all levels) lets it jump over
large clear nodes.

The hit's latitude, longitude and height are computed in the kernel from the
corner of its cell (:func:`_geodetic_near`; Vermeille's closed form of
:func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`, from :mod:`geoloc.geodesy._nbgeo`, where that
does not apply); ``tests/surfaces/test_terrain.py`` checks them against the core's.

The helpers (:func:`_par_exit`, :func:`_mer_exit`, :func:`_tri`, ...) are ordinary compiled
functions, not ``inline="always"``: numba's IR inlining put a copy of each into the walk's
own IR before type inference, and the walk's first compile took 41-55 s of CPU and 1 GB
(most of it numba's passes over that IR: SSA, rewrites, typing; LLVM 5 %); called, LLVM
inlines the small ones at the machine-code level (:func:`_mer_exit`, :func:`_tri`, the skip
test; :func:`_par_exit`, :func:`_cell_triangles` and :func:`_geodetic_near` stay calls in the
flat triangle walk's assembly), and the first compile of the flat walk is 12-14 s and under 400 MB (``benchmarks/bench_first_run.py``: a cold first call is what a
user of ``geoloc locate --dem`` waits for). Measured
against the inlined walk (crop, 10 000 rays, one thread, 21 calls in turn, a loaded
machine): 0.95-1.02 of its time; the triangles' hits and statuses equal bit for bit, the
bilinear hits within 9.1e-13 m along the ray (the FMAs LLVM forms differ where the code
meets; the Newton polish stops at 1e-7 m). The climb's code is under ``if _CLIMB``, which
numba prunes before typing in the flat kernels.

What the first compile costs is numba's Python-side passes (typing, lowering, SSA: about
four fifths of it; LLVM the rest), in proportion to the code compiled, plus a fixed cost per
kernel and per signature. So a helper is compiled for one signature
(:data:`_NORTH`: a float, where a bool constant was typed as a literal of its own and
compiled :func:`_par_exit` twice); :func:`median_run` is numpy; the walk calls
:func:`geodetic_up` alone, not :func:`geodetic` too; :func:`latlon` is one kernel, and the
bilinear interpolation is written out, not a kernel. Counted in Python calls made during a
cold ``geoloc locate --dem`` (a figure the machine's load does not move): 13.25 M before,
about 11.0 M after. Kernels split out of the walk (its start cell, a cell's two triangles,
a cell's bilinear step) saved little more (10.6 M) and made the walk 9-16 % slower: a kernel
taking arrays pays their reference counts on every call.
Inlined at numba's IR level (``inline="always"``) such a step pays them all the same (an
array argument becomes a local bound to the caller's, counted in and out around the step's
loops): the start cell, the cell where the ray enters a block, the step into the next block and
the hit's conversion as inlined steps ran at 0.81 of the walk's speed (crop, triangles, 10 000
rays, one thread, called in turn in one process; the block step alone 0.93). So only the steps
on scalars are functions of their own, each inlined at its one call site and tested alone
(``tests/surfaces/test_terrain_steps.py``): :func:`_ray_span` (where a ray's walk starts and
ends), :func:`_ray_terms` (the ray's products every test reuses), :func:`_start_guess` and
:func:`_start_cell_geodetic` (the start cell), :func:`_block_entry` (a block skipped, or where
its cell walk starts), :func:`_bilinear_step` (a cell's bilinear test and the geodetic state it
hands the next cell) and :func:`_hit_geodetic` (the hit's coordinates); the steps that read the
tables (the start cell's correction, the climb, the cell loop, the step into the next block)
stay in the walk's body, and the walk's arguments travel as three records (:class:`WalkRays`, :class:`WalkGrid`,
:class:`WalkOut`), unpacked once a call (measured: 0.998 of the walk with 28 arguments).

A small call is not compiled at all (:data:`PY_WALK_MAX_RAYS`: up to 64 rays over a DEM of
modest size): :func:`walk` runs the same source uncompiled (:func:`_python_walk`, about 70 us a
ray and 5 us a cell step on the bundled crop), so a one-ray ``geoloc locate --dem`` or a short
``replay`` starts in about 1 s of CPU on a cold cache instead of 15 s. Within an
:func:`uncompiled_budget` (the viewer's first scene) a larger call starts uncompiled too, while
its projected cost fits. Its statuses and cells are the kernel's; its hits differ from the
kernel's by the FMA rounding below (2.5e-8 m on the crop's 300 oblique rays, bilinear;
``tests/surfaces/test_terrain_python_walk.py`` holds them to 1e-6 m).

``fastmath={"contract"}`` only lets LLVM fuse a multiply and an add (FMA, one
rounding instead of two): 10 % faster; hits move by at most 1e-7 m on grazing
rays. No other fast-math flag: the walk relies on NaN and infinity.

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import contextlib
import contextvars
from concurrent.futures import ThreadPoolExecutor
import math
import sys
import types
from collections.abc import Iterator
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray
from llvmlite import ir
from numba import prange
from numba.core import cgutils
from numba.core import types as nbtypes
from numba.core.dispatcher import Dispatcher
from numba.extending import intrinsic

from geoloc import status as _status_module
from geoloc.geodesy import _nbgeo, ellipsoid
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, geodetic_up
from geoloc.geodesy.ellipsoid import E2, A, B
from geoloc.status import Status

_OK = int(Status.OK)
_SKY = int(Status.SKY)
_LEFT = int(Status.LEFT_DEM)
_NODATA = int(Status.NODATA)
_NOCONV = int(Status.NO_CONVERGENCE)
_INVALID = int(Status.INVALID_INPUT)
#: Cells per side of a block of the min/max hierarchy, the least the tables use: the side is a
#: property of the tables (``geoloc.surfaces.terrain.block_cells``: about 100 m of ground, at
#: least this many cells) and reaches the walk as its ``blk`` argument.
BLOCK = 8
#: Nodes from which the walk prefetches a block's rows when it walks the block cell by cell
#: (:func:`_prefetch`): 2^19, a cell table of 4 MB, the size from which the rays are also
#: walked in tile order (``terrain._SORT_MIN_BYTES``). Below it the tables stay in the caches
#: and the hints only cost time (crop: 0.97 of the walk with them; 3601 x 3601: 1.28 without).
PREFETCH_MIN_NODES = 1 << 19
#: True in the ``"climb"`` walks of :data:`KERNELS`, False in the flat ones (the same source
#: compiled with the climb above the blocks left out: numba reads a global as a constant, so
#: LLVM drops that code and the cell walk compiles as tightly as the two-level walk did).
_CLIMB = True
#: 0 in the ``"climb"`` and ``"flat_block"`` walks of :data:`KERNELS` (the block side is the
#: walk's ``blk`` argument); :data:`BLOCK` in the ``"flat"`` ones, where LLVM then folds the side
#: into the code as the walk had it before the side became an argument (the crop's walk was
#: 1-3 % slower with the side read at run time).
_FIXED_BLOCK = 0
#: The cell model: each compiled walk is one model's (:data:`KERNELS`), so a call compiles the
#: model it walks and not the other one (half the first compile): ``_TRIANGLES`` is a constant numba prunes
#: the other model's branch on before typing (:func:`walk`'s ``triangles`` picks the kernel).
_TRIANGLES = False
#: The direction argument of :func:`_par_exit`: a float, not a bool, so that numba compiles the
#: helper once (a constant True or False is typed as a literal of its own: two compiles of
#: 0.4-0.6 s on a cold cache); LLVM folds it where it inlines the helper.
_NORTH = 1.0
_SOUTH = -1.0
#: The cache key of this module's kernels (:func:`geoloc.geodesy._nbgeo.cached_njit`): they
#: freeze A, B, E2, the status codes and the code of _nbgeo's conversions, so a change to
#: any of those modules must compile them afresh, not load a stale cache.
KEY = dependency_key(ellipsoid, _nbgeo, _status_module, sys.modules[__name__])


class WalkRays(NamedTuple):
    """The rays of a walk: ECEF origins ``o`` [m] and directions ``d`` (n, 3), and ``order``, the
    indices of the rays to walk in the order to walk them (:func:`ray_order`)."""

    o: np.ndarray
    d: np.ndarray
    order: np.ndarray


class WalkGrid(NamedTuple):
    """The DEM as the walk reads it (:func:`geoloc.surfaces.terrain._exact_tables` builds the tables;
    :func:`_walk`'s docstring says what each holds). One record, so that the kernel, its wrappers and
    its callers name the tables once: numba types a tuple of arrays and scalars as one argument and
    passes its members as it passes separate ones (the walk's machine code does not change).

    ``h_top``, ``h_floor``: the heights [m, ellipsoidal] the walk starts from and ends at; ``blk``:
    the cells per side of a block of ``binv`` and ``hinv``; ``hlev`` empty: no levels to climb."""

    h_top: float
    h_floor: float
    hgt: np.ndarray
    lon_col: np.ndarray
    cinv: np.ndarray
    binv: np.ndarray
    blk: int
    hinv: np.ndarray
    hlev: np.ndarray
    row_geo: np.ndarray
    lat_n: float
    lon_w: float
    dlat: float
    dlon: float
    tan_row: np.ndarray
    c_row: np.ndarray
    sin_col: np.ndarray
    cos_col: np.ndarray


class WalkOut(NamedTuple):
    """What the walk fills, one row a ray: ``s_out`` (the hit's ray parameter), ``p_out`` (ECEF [m]),
    ``geo_out`` (latitude, longitude [rad], height [m], range [m]), ``status`` (read first: a ray
    whose status is not OK is not walked), ``ncell`` (cells and blocks visited), and the trace
    ``trace_s`` (n, m), ``trace_ij`` (n, m, 2) (m = 0: no trace). :func:`walk_outputs` makes one."""

    s_out: np.ndarray
    p_out: np.ndarray
    geo_out: np.ndarray
    status: np.ndarray
    ncell: np.ndarray
    trace_s: np.ndarray
    trace_ij: np.ndarray


def walk_outputs(status: np.ndarray, trace_cells: int = 0) -> WalkOut:
    """A :class:`WalkOut` for ``len(status)`` rays (``status`` used in place: the walk reads and
    writes it), with room for a trace of ``trace_cells`` steps a ray."""
    n = len(status)
    return WalkOut(
        np.empty(n),
        np.empty((n, 3)),
        np.empty((n, 4)),
        status,
        np.empty(n, dtype=np.int64),
        np.full((n, trace_cells), np.nan),
        np.full((n, trace_cells, 2), -1, dtype=np.int64),
    )


@intrinsic
def _prefetch(typingctx, arr, i, j):
    """A hint to the CPU to bring the cache line of ``arr[i, j]`` (``arr[i, j, 0]`` for a 3-d
    array) in now: ``llvm.prefetch`` (read, keep in all cache levels). No load, no fault,
    no effect on any result; indices are not checked (a hint off the array is dropped).

    The walk issues it for the rows of a block when it starts walking that block cell by
    cell: the cell table and the heights of a 3601 x 3601 DEM are 100 MB each, one row of
    a block is one or two cache lines 28.8 kB apart, and without the hint each row the ray
    reached was a miss waited for in turn (a fifth of the walk's time, sampled with perf).
    On a DEM of fewer than :data:`PREFETCH_MIN_NODES` nodes it does not (the rows are cached).
    """

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [args[1], args[2]] + [ir.Constant(ir.IntType(64), 0)] * (aryty.ndim - 2)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), "llvm.prefetch.p0"
        )
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    if not (
        isinstance(arr, nbtypes.Array)
        and arr.ndim in (2, 3)
        and isinstance(i, nbtypes.Integer)
        and isinstance(j, nbtypes.Integer)
    ):
        return None
    return nbtypes.void(arr, i, j), codegen


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _roots(ox, oy, oz, dx, dy, dz, ia, ib):
    """Near and far ray parameters on the ellipsoid (a+h, a+h, b+h) [Q17 eq. 10-11].

    ``ia``, ``ib`` = 1/(a+h)^2, 1/(b+h)^2. The compiled twin of
    :func:`geoloc.surfaces.height.ray_inflated_ellipsoid` (which returns the near root
    only); NaN, NaN when the line misses or the near root is behind; ``inside``
    when the origin is inside.
    """
    qa = (dx * dx + dy * dy) * ia + dz * dz * ib
    qb = 2.0 * ((ox * dx + oy * dy) * ia + oz * dz * ib)
    qc = (ox * ox + oy * oy) * ia + oz * oz * ib - 1.0
    disc = qb * qb - 4.0 * qa * qc
    inside = qc < 0.0
    if disc < 0.0 or (qb >= 0.0 and not inside):
        return np.nan, np.nan, inside
    q = -0.5 * (qb - math.sqrt(disc))
    near = min(q / qa, qc / q)
    far = max(q / qa, qc / q)
    return near, far, inside


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def latlon(x: float, y: float, z: float) -> tuple[float, float]:
    """Geodetic latitude and longitude by Bowring's one-step formula (no height).

    B. R. Bowring, Survey Review 23(181):323-327, 1976: with the parametric
    latitude theta from tan(theta) = a z / (b rho),
    tan(phi) = (z + e'^2 b sin^3 theta) / (rho - e^2 a cos^3 theta).
    Used only to find the cell under a point (error < 1e-9 rad for heights
    -1 km..20 km, tested); heights come from :func:`geodetic`.
    """
    rho = math.sqrt(x * x + y * y)
    za = z * A
    rb = rho * B
    q = math.sqrt(za * za + rb * rb)
    st = za / q
    ct = rb / q
    ep2 = E2 / (1.0 - E2)
    return math.atan2(z + ep2 * B * st * st * st, rho - E2 * A * ct * ct * ct), math.atan2(y, x)


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _wrap(lon, lon_west):
    """Longitude into the grid's window [lon_west - pi, lon_west + pi)."""
    return (lon - lon_west + math.pi) % (2.0 * math.pi) + lon_west - math.pi


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _mer_exit(sin_m, cos_m, ox, oy, dx, dy, s, east):
    """Ray parameter where the ray, inside a cell at s, crosses meridian m (sin, cos of
    lambda_m) eastward (``east``) or westward; s if rounding puts it behind; inf if never.

    f(s) = cos_m y(s) - sin_m x(s) is the signed distance to the meridian plane (> 0 east
    of it) and is linear in s, so the crossing is one division. Its slope at a crossing
    of the meridian's own half-plane is (o x d)_z / rho, whose sign says which way the
    longitude runs (it is monotonic along a straight line): only the meridian ahead is
    ever tested, and a root ahead lies on the right half-plane (a cell spans < pi).
    """
    b = cos_m * dy - sin_m * dx
    if east:
        if not b > 0.0:
            return np.inf
    elif not b < 0.0:
        return np.inf
    r = (sin_m * ox - cos_m * oy) / b
    return r if r > s else s


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _par_exit(tanp, cpar, oz, dz, dz2, dxy2, oxd, oxy2, s, way):
    """(exit, again): where the ray, inside the row at s, next crosses the parallel
    (tan phi, c) northward (``way`` :data:`_NORTH`) or southward (:data:`_SOUTH`), and where
    it crosses that parallel again afterwards (the next row's exit through it); inf for never.

    G(s) = z + c - rho tan(phi) (> 0 north of the parallel) is zero on the cone of
    the module docstring; G(s) G*(s), with G* its mirror nappe z + c + rho tan(phi),
    is the quadratic qa s^2 + 2 hb s + qc in s (absolute ray parameters, so every
    call for one parallel gives the same roots to the last bit). At a root on the
    right nappe, G* has the sign of tan(phi), so G rises there iff (qa r + hb) tan(phi)
    > 0: the direction of each crossing is known without evaluating G, and the root
    that leaves the row is picked without comparing it with s (robust for a point
    on or a rounding error off the parallel). A tangency (double root) is no crossing.
    """
    north = way > 0.0
    zc = oz + cpar
    if tanp == 0.0:  # the equator: the plane z = 0
        if dz == 0.0 or (dz > 0.0) != north:
            return np.inf, np.inf
        r = -zc / dz
        return (r if r > s else s), np.inf
    t2 = tanp * tanp
    qa = dz2 - t2 * dxy2
    hb = zc * dz - t2 * oxd
    qc = zc * zc - t2 * oxy2
    if qa == 0.0:  # the ray is parallel to a generator of the cone: one root
        if hb == 0.0 or ((hb * tanp) > 0.0) != north:
            return np.inf, np.inf
        r = -0.5 * qc / hb
        zr = zc + r * dz
        if (zr < 0.0) if tanp > 0.0 else (zr > 0.0):  # on the other nappe
            return np.inf, np.inf
        return (r if r > s else s), np.inf
    disc = hb * hb - qa * qc
    if not disc > 0.0:  # no crossing, or a tangency
        return np.inf, np.inf
    sq = math.sqrt(disc)
    sg = math.copysign(1.0, hb)
    qq = -(hb + sg * sq)
    inv = 1.0 / (qq * qa)  # one division for both roots
    r0 = qq * qq * inv  # = qq / qa: qa r0 + hb = -sg sq
    r1 = qc * qa * inv  # = qc / qq: qa r1 + hb = +sg sq
    if ((sg * tanp) > 0.0) == north:  # G rises at r1
        rx = r1
        re = r0
    else:
        rx = r0
        re = r1
    zx = zc + rx * dz
    if (zx < 0.0) if tanp > 0.0 else (zx > 0.0):
        return np.inf, np.inf
    ze = zc + re * dz
    if re > rx and not ((ze < 0.0) if tanp > 0.0 else (ze > 0.0)):
        # inside before rx and after re: which of the two is s in?
        if s < 0.5 * (rx + re):
            return (rx if rx > s else s), re
        return np.inf, np.inf
    return (rx if rx > s else s), np.inf


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _par_exit_kept(same, kept, kept2, tanp, cpar, oz, dz, dz2, dxy2, oxd, oxy2, s, way):
    """:func:`_par_exit`, or (kept, kept2) when the parallel is one whose crossings are known
    (``same``: a side shared with the node or block the ray is leaving keeps its crossing)."""
    if same:
        return kept, kept2
    return _par_exit(tanp, cpar, oz, dz, dz2, dxy2, oxd, oxy2, s, way)


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _mer_ahead_kept(along, same, kept, sin_m, cos_m, ox, oy, dx, dy, s, east):
    """The crossing of the meridian ahead: inf if the line crosses none (``along`` False),
    ``kept`` when that meridian is a shared side whose crossing is known, else :func:`_mer_exit`."""
    if not along:
        return np.inf
    if same:
        return kept
    return _mer_exit(sin_m, cos_m, ox, oy, dx, dy, s, east)


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _geodetic_near(x, y, z, lat0, s0, c0, lon0, sl0, cl0):
    """ECEF -> (lat, lon, h) of a point near the parallel lat0 (sin, cos s0, c0) and the
    meridian lon0 (sin, cos sl0, cl0), e.g. a hit and the corner of its cell.

    lon = lon0 + atan(u), u = tan(lon - lon0) from the meridian's plane, by its series;
    lat = lat0 + delta, the root of the foot-of-normal condition
    W(phi) (rho sin(phi) - z cos(phi)) - e^2 a sin(phi) cos(phi) = 0, W = sqrt(1 - e^2 sin^2 phi)
    (R_N W = a; from x = (R_N + h) cos phi cos lambda, z = (R_N (1 - e^2) + h) sin phi),
    by chord steps with the derivative at lat0 (the first step is Newton's; each
    next one gains a factor |delta| <= a cell), sin and cos of lat0 + delta from the
    tables and the series of delta; then h = rho cos(phi) + z sin(phi) - a W.
    One division and no libm call (the closed form's atan2, atan2, pow and hypot
    were a tenth of the walk). Returns NaN, NaN, NaN when the point is more than
    2e-3 rad from the corner (the caller then uses :func:`geodetic`).
    """
    rho = math.sqrt(x * x + y * y)
    u = (cl0 * y - sl0 * x) / (cl0 * x + sl0 * y)
    if not abs(u) < 2e-3:
        return np.nan, np.nan, np.nan
    u2 = u * u
    lon = lon0 + u * (1.0 - u2 * (1.0 / 3.0 - u2 * (0.2 - u2 / 7.0)))
    if lon > math.pi:
        lon -= 2.0 * math.pi
    elif lon <= -math.pi:
        lon += 2.0 * math.pi
    w = math.sqrt(1.0 - E2 * s0 * s0)
    f = rho * s0 - z * c0
    g = w * f - E2 * A * s0 * c0
    dg = -E2 * s0 * c0 / w * f + w * (rho * c0 + z * s0) - E2 * A * (c0 * c0 - s0 * s0)
    idg = 1.0 / dg
    dl = -g * idg
    sp = s0
    cp = c0
    for _ in range(8):
        if not abs(dl) < 2e-3:
            return np.nan, np.nan, np.nan
        d2 = dl * dl
        sd = dl * (1.0 - d2 * (1.0 / 6.0 - d2 / 120.0))
        cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 / 720.0))
        sp = s0 * cd + c0 * sd
        cp = c0 * cd - s0 * sd
        w = math.sqrt(1.0 - E2 * sp * sp)
        step = (w * (rho * sp - z * cp) - E2 * A * sp * cp) * idg
        dl -= step
        if abs(step) < 1e-13:  # the error left is ~ |delta| |step| < 1e-16 rad
            break
    # h at the previous iterate: a latitude error e changes h by ~ R e^2 (< 1e-12 m)
    h = rho * cp + z * sp - A * w
    return lat0 + dl, lon, h


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _tri(ox, oy, oz, dx, dy, dz, p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z):
    """Moller-Trumbore ray x triangle (p0, p1, p2); ray parameter or inf.

    Scalars only: an array argument of a helper costs a reference-count
    increment and decrement (atomic) per call, which was a third of the walk's time.
    The barycentric tests (tolerance 1e-12) compare u det, v det and t det with |det|,
    so that a miss costs no division.
    """
    e1x = p1x - p0x
    e1y = p1y - p0y
    e1z = p1z - p0z
    e2x = p2x - p0x
    e2y = p2y - p0y
    e2z = p2z - p0z
    hx = dy * e2z - dz * e2y
    hy = dz * e2x - dx * e2z
    hz = dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if det == 0.0:
        return np.inf
    sx = ox - p0x
    sy = oy - p0y
    sz = oz - p0z
    uu = sx * hx + sy * hy + sz * hz  # u det
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    vv = dx * qx + dy * qy + dz * qz  # v det
    tt = e2x * qx + e2y * qy + e2z * qz  # t det
    if det < 0.0:  # compare u, v, t times |det|: one division, for a hit only
        det = -det
        uu = -uu
        vv = -vv
        tt = -tt
    tol = 1e-12 * det
    if uu < -tol or uu > det + tol or vv < -tol or uu + vv > det + tol or tt <= 0.0:
        return np.inf
    return tt / det


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _ellipsoid_quadratic(ia, ib, dxy2, dz2, oxd, ozd, oxy2, oz2):
    """(qa, hb, qc): F(s) = qa s^2 + 2 hb s + qc = |P'(s)|^2 - 1, the ray P(s) = o + s d scaled
    by the inflated ellipsoid's ``ia`` = 1/(a+H)^2 and ``ib`` = 1/(b+H)^2 [Q17 eq. 11]; F > 0
    outside it. The ray's terms come in precomputed: dxy2 = dx^2 + dy^2, dz2 = dz^2,
    oxd = ox dx + oy dy, ozd = oz dz, oxy2 = ox^2 + oy^2, oz2 = oz^2."""
    return dxy2 * ia + dz2 * ib, oxd * ia + ozd * ib, oxy2 * ia + oz2 * ib - 1.0


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _clear_between(qa, hb, qc, s, e):
    """Whether the ray stays outside the inflated ellipsoid of :func:`_ellipsoid_quadratic` from
    s to e (s <= e), so above every height under it: F is convex, so it is positive on [s, e]
    iff it is at both ends and, when its vertex -hb/qa lies between them, there too
    (F(vertex) = qc - hb^2/qa, tested without a division). False when a coefficient is NaN."""
    return (
        ((qa * s + 2.0 * hb) * s + qc > 0.0)
        and ((qa * e + 2.0 * hb) * e + qc > 0.0)
        and not (qa * s < -hb and -hb < qa * e and hb * hb >= qa * qc)
    )


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _cell_triangles(ox, oy, oz, dx, dy, dz, ra, ca, rba, sa, rb, cb, rbb, sb, cl0, sl0, cl1, sl1, h00, h01, h10, h11):
    """Ray parameters (t1, t2) where the ray meets the two triangles of a cell, inf for a miss.

    The nodes (i, j), (i+1, j), (i+1, j+1) make the first triangle, (i, j), (i+1, j+1),
    (i, j+1) the second ([Q17]'s grid split as ``DEM.mesh`` splits it). A node's ECEF
    position is computed from its height h as ``geodetic_to_ecef`` computes it for the mesh:
    ((R_N + h) cos phi cos lambda, (R_N + h) cos phi sin lambda, (R_N (1 - e^2) + h) sin phi),
    from the rows' (R_N, cos phi, R_N (1 - e^2), sin phi) (``ra, ca, rba, sa`` of row i,
    ``rb, cb, rbb, sb`` of row i+1) and the columns' (cos, sin) of lambda (``cl0, sl0`` of
    column j, ``cl1, sl1`` of j+1): the same vertices as the trimesh mesh, bit for bit.
    Scalars only (an array argument costs reference counting on every call).
    """
    n0x = (ra + h00) * ca * cl0
    n0y = (ra + h00) * ca * sl0
    n0z = (rba + h00) * sa
    n1x = (rb + h10) * cb * cl0
    n1y = (rb + h10) * cb * sl0
    n1z = (rbb + h10) * sb
    n2x = (rb + h11) * cb * cl1
    n2y = (rb + h11) * cb * sl1
    n2z = (rbb + h11) * sb
    t1 = _tri(ox, oy, oz, dx, dy, dz, n0x, n0y, n0z, n1x, n1y, n1z, n2x, n2y, n2z)
    t2 = _tri(
        ox,
        oy,
        oz,
        dx,
        dy,
        dz,
        n0x,
        n0y,
        n0z,
        n2x,
        n2y,
        n2z,
        (ra + h01) * ca * cl1,
        (ra + h01) * ca * sl1,
        (rba + h01) * sa,
    )
    return t1, t2


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _bilinear_cell(
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    sa,
    sb,
    lat_a,
    lon_a,
    h_a,
    g_a,
    lat_b,
    lon_b,
    h_b,
    z00,
    z10,
    z01,
    z11,
    i,
    j,
    lat_n,
    lon_w,
    dlat,
    dlon,
):
    """First root of h_ray(s) - bilinear(lat(s), lon(s)) on [sa, sb]; inf if none.

    Model on the cell: (u, v) linear between the exact entry/exit grid
    coordinates and h(t) quadratic matching h_a, dh/ds(a) and h_b; the model
    root is then polished by Newton steps on the exact residual (exact
    geodetic conversion of the ray point), to 1e-7 m along the ray.
    """
    L = sb - sa
    ua = (lon_a - (lon_w + j * dlon)) / dlon
    va = ((lat_n - i * dlat) - lat_a) / dlat
    ub = (lon_b - (lon_w + j * dlon)) / dlon
    vb = ((lat_n - i * dlat) - lat_b) / dlat
    du = ub - ua
    dv = vb - va
    B = z10 - z00
    C = z01 - z00
    D = z00 - z10 - z01 + z11
    k = h_b - h_a - g_a * L
    c0 = h_a - (z00 + B * ua + C * va + D * ua * va)
    c1 = g_a * L - (B * du + C * dv + D * (ua * dv + va * du))
    c2 = k - D * du * dv
    t = np.inf
    if c0 <= 0.0:
        t = 0.0
    else:
        if abs(c2) < 1e-12 * (abs(c1) + abs(c0) + 1e-300):
            if c1 < 0.0:
                r = -c0 / c1
                if r <= 1.0:
                    t = r
        else:
            disc = c1 * c1 - 4.0 * c2 * c0
            if disc >= 0.0:
                sq = math.sqrt(disc)
                qq = -0.5 * (c1 + math.copysign(sq, c1))
                r1 = qq / c2
                r2 = c0 / qq if qq != 0.0 else np.inf
                for r in (r1, r2):
                    if 0.0 <= r <= 1.0 and r < t:
                        t = r
            if t == np.inf and c2 > 0.0:
                # near-tangency: check the exact residual at the model's minimum
                tm = -c1 / (2.0 * c2)
                if 0.0 < tm < 1.0 and c0 + c1 * tm + c2 * tm * tm < 1e-2:
                    s = sa + tm * L
                    la, lo, hh, _, _, _ = geodetic_up(ox + s * dx, oy + s * dy, oz + s * dz)
                    lo = _wrap(lo, lon_w)
                    u = (lo - (lon_w + j * dlon)) / dlon
                    v = ((lat_n - i * dlat) - la) / dlat
                    if hh - ((1.0 - v) * ((1.0 - u) * z00 + u * z10) + v * ((1.0 - u) * z01 + u * z11)) <= 0.0:
                        # a root in [0, tm]: bisect the model there, Newton below polishes
                        lo_t = 0.0
                        hi_t = tm
                        for _ in range(60):
                            mid = 0.5 * (lo_t + hi_t)
                            if c0 + c1 * mid + c2 * mid * mid > 0.0:
                                lo_t = mid
                            else:
                                hi_t = mid
                        t = hi_t
    if t == np.inf:
        return np.inf
    s = sa + t * L
    if t == 0.0:
        return s
    for _ in range(6):
        la, lo, hh, _, _, _ = geodetic_up(ox + s * dx, oy + s * dy, oz + s * dz)
        lo = _wrap(lo, lon_w)
        u = (lo - (lon_w + j * dlon)) / dlon
        v = ((lat_n - i * dlat) - la) / dlat
        res = hh - ((1.0 - v) * ((1.0 - u) * z00 + u * z10) + v * ((1.0 - u) * z01 + u * z11))
        tt = (s - sa) / L
        slope = (c1 + 2.0 * c2 * tt) / L
        if slope >= 0.0:
            break
        step = res / slope
        if not (sa - 1e-6 <= s - step <= sb + 1e-6):
            # near a tangency the model's slope can vanish: a step out of the cell is
            # no root of this cell (it once returned s = -7.5e13 as a hit); keep s
            break
        s = s - step
        if abs(step) < 1e-7:
            break
    return s


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _bilinear_step(
    ox, oy, oz, dx, dy, dz, s, s_b, geo_ok, lat, lon, h, g, z00, z10, z01, z11, i, j, lat_n, lon_w, dlat, dlon
):
    """(t, lat_b, lon_b, h_b, g_b): the bilinear model's test of the cell (i, j) the ray crosses
    from s to ``s_b``, with node heights ``z00`` (i, j), ``z10`` (i, j + 1), ``z01`` (i + 1, j),
    ``z11`` (i + 1, j + 1): ``t`` the first hit on [s, s_b] (:func:`_bilinear_cell`), inf for none.

    The geodetic state at s (latitude, longitude in the grid's window, height and g = dh/ds, the
    up vector's component along the unit ray) is ``lat, lon, h, g`` when ``geo_ok`` (kept from
    the cell before, whose exit is this cell's entry), else computed here (:func:`geodetic_up`);
    the state at ``s_b`` is returned for the next cell. Scalars only; inlined into the walk.
    """
    if not geo_ok:
        lat, lon, h, nx, ny, nz = geodetic_up(ox + s * dx, oy + s * dy, oz + s * dz)
        lon = _wrap(lon, lon_w)
        g = nx * dx + ny * dy + nz * dz
    lat_b, lon_b, h_b, nx, ny, nz = geodetic_up(ox + s_b * dx, oy + s_b * dy, oz + s_b * dz)
    lon_b = _wrap(lon_b, lon_w)
    t = _bilinear_cell(
        ox,
        oy,
        oz,
        dx,
        dy,
        dz,
        s,
        s_b,
        lat,
        lon,
        h,
        g,
        lat_b,
        lon_b,
        h_b,
        z00,
        z10,
        z01,
        z11,
        i,
        j,
        lat_n,
        lon_w,
        dlat,
        dlon,
    )
    return t, lat_b, lon_b, h_b, nx * dx + ny * dy + nz * dz


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _hit_geodetic(x, y, z, lat0, s0, c0, lon0, sl0, cl0):
    """(lat, lon, h) of a hit at ECEF (x, y, z) [m] in the cell whose north-west corner is at
    latitude ``lat0`` (sin, cos ``s0``, ``c0``) and longitude ``lon0`` (sin, cos ``sl0``,
    ``cl0``): :func:`_geodetic_near` from that corner, or the closed form (:func:`geodetic_up`)
    where the hit is too far from it. Scalars only; inlined into the walk (once a hit)."""
    la, lo, hh = _geodetic_near(x, y, z, lat0, s0, c0, lon0, sl0, cl0)
    if la != la:
        la, lo, hh, _, _, _ = geodetic_up(x, y, z)
    return la, lo, hh


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _ray_span(ox, oy, oz, dx, dy, dz, ia_top, ib_top, ia_floor, ib_floor):
    """(status, ux, uy, uz, 1/|d|, s, send, st_end): where the walk of the ray o + s u (u = d / |d|)
    starts and ends.

    It starts where the ray enters the ellipsoid inflated to the top height (``ia_top``,
    ``ib_top`` = 1/(a+H)^2, 1/(b+H)^2 [Q17 eq. 10-11]; s = 0 when o is inside it) and ends, at
    ``send``, where it meets the floor's ellipsoid (status ``st_end`` = NO_CONVERGENCE there: no
    terrain is lower) or else leaves the top's one (SKY: the ray grazes and climbs away). The
    status is INVALID_INPUT for a direction of zero or infinite length or an infinite origin,
    SKY for a ray that misses the top's ellipsoid; OK when the walk is to run.
    Inlined into the walk (called once a ray).
    """
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (dn > 0.0 and dn < np.inf) or not (abs(ox) + abs(oy) + abs(oz) < np.inf):
        return _INVALID, dx, dy, dz, np.nan, np.nan, np.nan, _SKY
    idn = 1.0 / dn
    dx *= idn
    dy *= idn
    dz *= idn
    s0, s1, inside = _roots(ox, oy, oz, dx, dy, dz, ia_top, ib_top)
    if inside:
        s0 = 0.0
    elif s0 != s0:
        return _SKY, dx, dy, dz, idn, np.nan, np.nan, _SKY
    f0, f1, finside = _roots(ox, oy, oz, dx, dy, dz, ia_floor, ib_floor)
    end_is_floor = not finside and f0 == f0
    send = f0 if end_is_floor else s1
    st_end = _NOCONV if end_is_floor else _SKY  # status when the ray reaches send
    return _OK, dx, dy, dz, idn, s0, send, st_end


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _ray_terms(ox, oy, oz, dx, dy, dz):
    """(dxy2, dz2, oxd, ozd, oxy2, oz2, east, along, dj): the terms of the ray o + s d that every
    crossing and clearance test of its walk reuses, computed once a ray.

    dxy2 = dx^2 + dy^2, dz2 = dz^2, oxd = ox dx + oy dy, ozd = oz dz, oxy2 = ox^2 + oy^2,
    oz2 = oz^2 (the coefficients of :func:`_ellipsoid_quadratic` and :func:`_par_exit`);
    ``east``: the longitude grows along the ray ((o x d)_z > 0: it is monotonic along a straight
    line, :func:`_mer_exit`), ``along``: the line crosses meridians at all ((o x d)_z != 0, False
    for a line in a meridian plane), ``dj``: the column step, +1 east, -1 west.
    Scalars only; inlined into the walk (called once a ray).
    """
    lz = ox * dy - oy * dx  # (o x d)_z
    east = lz > 0.0
    return (
        dx * dx + dy * dy,
        dz * dz,
        ox * dx + oy * dy,
        oz * dz,
        ox * ox + oy * oy,
        oz * oz,
        east,
        lz != 0.0,
        1 if east else -1,
    )


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _start_guess(qx, qy, qz, cos_w, sin_w, tan_n, dlat, dlon, nr, nc):
    """(ok, i, j, rho): a first guess of the cell of the point q without atan2, for a grid whose
    west meridian has (cos, sin) ``cos_w``, ``sin_w`` and whose north parallel has tan phi
    ``tan_n``; ``rho`` = sqrt(qx^2 + qy^2).

    The column from u = tan(lon - lon_w) (from the meridian plane, by two terms of atan's series),
    the row from tan(lat - lat_n), with tan(lat) = z / (rho (1 - e^2)) the latitude of the point
    on the ellipsoid (off by ~e^2 h / a above it): a few cells off at most, within [0, nr - 2] x
    [0, nc - 2]; the walk then corrects it on the exact cell boundaries. ``ok`` False where the
    series does not hold (|lon - lon_w| or |lat - lat_n| about 0.47 rad or more, the point behind
    the grid's meridian or on the axis): the caller then takes :func:`_start_cell_geodetic`.
    Scalars only; inlined into the walk (called once a ray).
    """
    den = cos_w * qx + sin_w * qy
    num = cos_w * qy - sin_w * qx
    if not (den > 0.0 and abs(num) < 0.5 * den):
        return False, -1, -1, 0.0
    u = num / den  # tan(lon - lon_w), |lon - lon_w| < 0.47 rad
    j = min(max(int((u - u * u * u / 3.0) / dlon), 0), nc - 2)
    rho = math.sqrt(qx * qx + qy * qy)
    t = qz / (rho * (1.0 - E2))  # tan(lat) on the ellipsoid; ~e^2 h / a off above it
    w = (t - tan_n) / (1.0 + t * tan_n)  # tan(lat - lat_n)
    if not abs(w) < 0.5:  # also False for NaN (on the axis)
        return False, -1, j, rho
    i = min(max(int(-(w - w * w * w / 3.0) / dlat), 0), nr - 2)
    return True, i, j, rho


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _start_cell_geodetic(qx, qy, qz, lat_n, lon_w, dlat, dlon, nr, nc):
    """(i, j): the cell of the point q from its latitude and longitude (:func:`latlon`), the
    walk's start where :func:`_start_guess` does not apply: floor((lat_n - lat) / dlat),
    floor((lon - lon_w) / dlon) with lon in the grid's window (:func:`_wrap`), except that a
    point on the last node row or column (within 1e-9 of a cell) belongs to the last cell. The
    cell may lie off the grid (the caller tests it). Scalars only; inlined into the walk."""
    la0, lo0 = latlon(qx, qy, qz)
    lo0 = _wrap(lo0, lon_w)
    fi = (lat_n - la0) / dlat
    fj = (lo0 - lon_w) / dlon
    i = int(math.floor(fi))
    j = int(math.floor(fj))
    if i == nr - 1 and fi - i < 1e-9:
        i = nr - 2
    if j == nc - 1 and fj - j < 1e-9:
        j = nc - 2
    return i, j


@cached_njit(KEY, error_model="numpy", fastmath={"contract"}, inline="always")
def _block_entry(ia, ib, dxy2, dz2, oxd, ozd, oxy2, oz2, s, sx, send):
    """(clear, s, entered): the block-level test of the walk, for a block whose inflated
    ellipsoid is ``ia``, ``ib`` = 1/(a+H)^2, 1/(b+H)^2 (NaN: no data in the block, never clear).

    ``clear``: the ray stays outside that ellipsoid from s to where it leaves the block (``sx``,
    or ``send`` if sooner), so above all of the block's terrain: the walk skips the block in one
    step. Otherwise, if the ray at s is still outside the ellipsoid and enters it before ``sx``,
    every cell before that entry is clear too: s moves to the entry (the first root of the
    quadratic F of :func:`_ellipsoid_quadratic`, clamped to ``sx``) and ``entered`` is True (the
    cell at the new s is then found inside the block). Scalars only; inlined into the walk.
    """
    if not ia == ia:
        return False, s, False
    e = sx if sx < send else send
    qa, hb, qc = _ellipsoid_quadratic(ia, ib, dxy2, dz2, oxd, ozd, oxy2, oz2)
    if _clear_between(qa, hb, qc, s, e):
        return True, s, False
    if (qa * s + 2.0 * hb) * s + qc > 0.0:
        disc = hb * hb - qa * qc
        if disc > 0.0:
            s_in = qc / (math.sqrt(disc) - hb)  # the smaller root (hb < 0 here)
            if s_in > s:
                return False, (s_in if s_in < sx else sx), True
    return False, s, False


def _walk(rays, grid, out):
    """Exact first hit for each ray (see module docstring); fills s_out, status, ncell,
    and for the hits p_out (ECEF [m]) and geo_out (latitude, longitude [rad], height
    [m], range [m]); NaN elsewhere.

    A two-level digital differential analyser on the exact cell boundaries: the ray
    parameter where the ray next crosses each side of its block (blk x blk cells)
    and of its cell is kept, and a step recomputes only the side it crossed (one
    division for a meridian, one quadratic for a parallel; the parallel just crossed
    keeps its second root). The longitude runs one way along a straight line, so only
    the meridian ahead is tested.

    cinv[i, j] = (1/(a+H)^2, 1/(b+H)^2) of the ellipsoid inflated to H = cell max + margin,
    as float32 offsets from the floor's (1/(a+h_floor)^2, 1/(b+h_floor)^2), rounded by the
    caller toward a slightly larger ellipsoid (:func:`geoloc.surfaces.terrain._offsets32`;
    the tables are made for the ``h_floor`` they are walked with):
    the ray's part in a cell is skipped when it stays outside that ellipsoid (the
    quadratic |P'(s)|^2 - 1 of [Q17 eq. 11] is convex in s, so its minimum on the
    cell's interval decides). binv is the same for blocks (their highest node): a
    block the ray crosses clear of it is skipped in one step (a two-level min/max
    hierarchy); in a block that is not, the cell walk starts where the ray meets the
    block's ellipsoid (its first root), since every cell is clear above it. row_geo[i] = (R_N, cos phi, R_N (1 - e^2), sin phi, phi) of node row i
    and lon_col[j] the longitude of node column j: the triangle nodes are computed from
    the heights (a third of the memory of an ECEF node table, whose loads stalled the
    walk), and a hit's latitude and longitude from the corner of its cell
    (:func:`_geodetic_near`). cinv is NaN exactly where a cell has no data. trace_s /
    trace_ij have shape (n, m); m = 0 disables the trace. ``order`` lists the rays to walk,
    in the order to walk them (their indices into o, d and the outputs: walked in
    :func:`ray_order`'s order, consecutive rays read nearby parts of the tables, without
    gathering the rays into that order and the results back).

    Above the blocks, the min/max hierarchy (docs/terrain.md): hinv[hlev[l, 0] + a
    hlev[l, 2] + b] is the (1/(a+H)^2, 1/(b+H)^2) pair of node (a, b) of level
    k = hlev[l, 3] (2^k x 2^k blocks; hlev[l, 1:3] its rows and columns), for the
    levels the walk climbs (none: the two-level walk). From a clear block the walk
    climbs while the node holding it is clear of the ray from s to where the ray
    leaves it, then jumps to that point of the largest clear node, into the block
    beyond; the node that stopped the climb is not tested again while the ray is in
    it. A jump lands on the block boundary crossing the block-by-block walk would
    compute (same function, same absolute parameters), so the hits do not change.

    The steps, in the order a ray meets them (those on scalars are functions of their own,
    inlined; those that read the tables are marked ``# ----`` in the body): the ray's span and
    terms (:func:`_ray_span`, :func:`_ray_terms`); the start cell (:func:`_start_guess` corrected
    on the exact sides, else :func:`_start_cell_geodetic`); per block, its test
    (:func:`_block_entry`) and the cell at s; for a clear block the climb through the levels and
    the jump beyond the largest clear node; for the others the cell loop, each cell's test
    (:func:`_cell_triangles` or :func:`_bilinear_step`) and its step to the next cell; the step into
    the next block; and the exit: the status and the hit's coordinates (:func:`_hit_geodetic`).
    """
    # the records unpacked once a call: in the loop these are the locals they were as arguments
    o = rays.o
    d = rays.d
    order = rays.order
    h_top = grid.h_top
    h_floor = grid.h_floor
    hgt = grid.hgt
    lon_col = grid.lon_col
    cinv = grid.cinv
    binv = grid.binv
    blk = grid.blk
    hinv = grid.hinv
    hlev = grid.hlev
    row_geo = grid.row_geo
    lat_n = grid.lat_n
    lon_w = grid.lon_w
    dlat = grid.dlat
    dlon = grid.dlon
    tan_row = grid.tan_row
    c_row = grid.c_row
    sin_col = grid.sin_col
    cos_col = grid.cos_col
    s_out = out.s_out
    p_out = out.p_out
    geo_out = out.geo_out
    status = out.status
    ncell = out.ncell
    trace_s = out.trace_s
    trace_ij = out.trace_ij
    n = order.shape[0]
    nr = hgt.shape[0]
    nc = hgt.shape[1]
    nbr = binv.shape[0]
    nbc = binv.shape[1]
    nlev = hlev.shape[0]
    climb = nlev > 0 and _CLIMB  # _CLIMB False: numba prunes the climb before typing (the flat kernels)
    if _FIXED_BLOCK > 0:  # a constant too (the "flat" walks, which _kernel_for takes only for blk == BLOCK)
        blk = _FIXED_BLOCK
    mtrace = trace_s.shape[1]
    # the start cell's fast path needs the grid within 0.4 rad of its west meridian
    wide_ok = (nc - 1) * dlon < 0.4 and nr >= 2 and nc >= 2
    ia_top = 1.0 / ((A + h_top) * (A + h_top))
    ib_top = 1.0 / ((B + h_top) * (B + h_top))
    ia_floor = 1.0 / ((A + h_floor) * (A + h_floor))
    ib_floor = 1.0 / ((B + h_floor) * (B + h_floor))
    # the rows' prefetch pays where the tables outgrow the caches; on a small DEM (the crop:
    # 1 MB of cell table) the rows are already there and the hints cost 3 % of the walk
    fetch_rows = nr * nc >= PREFETCH_MIN_NODES
    # i // blk as (i * bdiv) >> 28: exact for 1 <= blk <= 16 and 0 <= i < 2^24 (ceil(2^28 / blk),
    # the reciprocal of a shift 4 bits longer than the numerator: checked for every such i in
    # tests/surfaces/test_terrain_hierarchy.py; _call refuses larger grids); a division was 1 % of the crop's walk
    bdiv = ((1 << 28) + blk - 1) // blk
    max_steps = 4 * (nr + nc) + 16  # a straight ray crosses each meridian once, each parallel twice
    for q in prange(n):
        r = order[q]  # rays are walked in this order (ray_order: the DEM tile by tile)
        if q + 1 < n:  # the next ray's origin and direction, fetched while this one walks
            _prefetch(o, np.uint64(order[q + 1]), np.uint64(0))
            _prefetch(d, np.uint64(order[q + 1]), np.uint64(0))
        s_out[r] = np.nan
        for c in range(3):
            p_out[r, c] = np.nan
            geo_out[r, c] = np.nan
        geo_out[r, 3] = np.nan
        ncell[r] = 0
        if status[r] != _OK:
            continue
        ox = o[r, 0]
        oy = o[r, 1]
        oz = o[r, 2]
        dx = d[r, 0]
        dy = d[r, 1]
        dz = d[r, 2]
        st, dx, dy, dz, idn, s, send, st_end = _ray_span(ox, oy, oz, dx, dy, dz, ia_top, ib_top, ia_floor, ib_floor)
        if st != _OK:
            status[r] = st
            continue
        dxy2, dz2, oxd, ozd, oxy2, oz2, east, along, dj = _ray_terms(ox, oy, oz, dx, dy, dz)
        lat = 0.0
        lon = 0.0
        h = 0.0
        g = 0.0
        geo_ok = False  # lat, lon, h, g hold the geodetic state at s only when True
        # ------------------------------------------------ the start cell, without atan2: a
        # guess (_start_guess, a few cells off at most), then corrected on the exact cell
        # boundaries (the side of the meridian planes and parallel cones, as in the walk).
        # Near the grid's edges, for a wide grid or a far guess: the atan2 path.
        qx = ox + s * dx
        qy = oy + s * dy
        qz = oz + s * dz
        i = -1
        j = -1
        rho = 0.0
        fast = wide_ok
        if fast:
            fast, i, j, rho = _start_guess(qx, qy, qz, cos_col[0], sin_col[0], tan_row[0], dlat, dlon, nr, nc)
        if fast:
            for _ in range(16):  # west of meridian j / east of j + 1: move
                if cos_col[j] * qy - sin_col[j] * qx < 0.0:
                    if j == 0:
                        fast = False
                        break
                    j -= 1
                elif cos_col[j + 1] * qy - sin_col[j + 1] * qx >= 0.0:
                    if j == nc - 2:
                        fast = False
                        break
                    j += 1
                else:
                    break
            else:
                fast = False
            for _ in range(16):  # north of parallel i / on or south of i + 1: move
                if qz + c_row[i] - rho * tan_row[i] > 0.0:
                    if i == 0:
                        fast = False
                        break
                    i -= 1
                elif qz + c_row[i + 1] - rho * tan_row[i + 1] <= 0.0:
                    if i == nr - 2:
                        fast = False
                        break
                    i += 1
                else:
                    break
            else:
                fast = False
        if not fast:
            i, j = _start_cell_geodetic(qx, qy, qz, lat_n, lon_w, dlat, dlon, nr, nc)
        if i < 0 or i >= nr - 1 or j < 0 or j >= nc - 1:
            status[r] = _LEFT
            continue
        if s > send:
            status[r] = st_end
            continue
        best = np.inf
        hit_i = 0
        hit_j = 0
        st = _LEFT
        steps = 0
        # the block and its sides; b* = next crossing of its north / south parallel or of
        # the meridian ahead, b*2 = the crossing after it of the same parallel
        if _FIXED_BLOCK > 0:
            bi = i // _FIXED_BLOCK  # a shift
            bj = j // _FIXED_BLOCK
        else:
            bi = (i * bdiv) >> 28  # i // blk, without a division (exact: see bdiv)
            bj = (j * bdiv) >> 28
        i0 = bi * blk
        i1 = min(i0 + blk, nr - 1)
        j0 = bj * blk
        j1 = min(j0 + blk, nc - 1)
        bM = np.inf
        if along:
            jm = j1 if east else j0
            bM = _mer_exit(sin_col[jm], cos_col[jm], ox, oy, dx, dy, s, east)
        bN, bN2 = _par_exit(tan_row[i0], c_row[i0], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH)
        bS, bS2 = _par_exit(tan_row[i1], c_row[i1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH)
        failed = -1  # the last hierarchy node (its index in hinv) this ray found not clear
        came = 4  # how the block was entered: 0 north side, 1 south side, 2 meridian;
        # 4: the cell (i, j) is known, 5: s is inside the block
        done = False
        side = 0
        while True:
            if steps > max_steps:
                st = _NOCONV
                break
            # ------------------------------------------------ block level
            sx = min(bN, bS, bM)
            # clear of the block's inflated ellipsoid up to where the ray leaves it: skipped;
            # else the cell walk starts where the ray meets that ellipsoid, not at the block's
            # side (those cells would all be skipped, one step each)
            clear, s, entered = _block_entry(
                ia_floor + binv[np.uint64(bi), np.uint64(bj), 0],
                ib_floor + binv[np.uint64(bi), np.uint64(bj), 1],
                dxy2,
                dz2,
                oxd,
                ozd,
                oxy2,
                oz2,
                s,
                sx,
                send,
            )
            if entered:
                came = 5
                geo_ok = False
            k = steps
            if not clear or k < mtrace:
                # the cell at s: the coordinate along the side the block was entered by is
                # known; the other is the side of the block's inner meridian planes (or
                # parallel cones) s is on (both inside the block: came 5)
                if came != 4:
                    qx = ox + s * dx
                    qy = oy + s * dy
                    if came == 0:
                        i = i0
                    elif came == 1:
                        i = i1 - 1
                    else:
                        qz = oz + s * dz
                        rho = math.sqrt(qx * qx + qy * qy)
                        i = i0
                        for m in range(i0 + 1, i1):
                            if qz + c_row[m] - rho * tan_row[m] >= 0.0:  # north of parallel m
                                break
                            i = m
                    if came == 2:
                        j = j0 if east else j1 - 1
                    else:
                        j = j0
                        for m in range(j0 + 1, j1):
                            if cos_col[m] * qy - sin_col[m] * qx < 0.0:  # west of meridian m
                                break
                            j = m
                    came = 4
                if k < mtrace:
                    trace_s[r, k] = s * idn
                    trace_ij[r, k, 0] = i
                    trace_ij[r, k, 1] = j
            if clear:
                steps = k + 1
                geo_ok = False
                if sx >= send:
                    st = st_end
                    break
                # ------------------------------------------------ climb the hierarchy: the
                # largest node above this block that the ray crosses clear of (from s to
                # where it leaves the node), then one jump to that node's side
                glv = -1
                if _CLIMB and climb:  # _CLIMB first: numba prunes the branch where it is False
                    gE = sx  # exit of the last clear node (first: this block)
                    gN = bN
                    gN2 = bN2
                    gS = bS
                    gS2 = bS2
                    gM = bM
                    gi0 = i0
                    gi1 = i1
                    gj0 = j0
                    gj1 = j1
                    gni = bi
                    gnj = bj
                    ended = False
                    for lv in range(nlev):
                        sh = hlev[lv, 3]
                        ni = bi >> sh
                        nj = bj >> sh
                        hk = hlev[lv, 0] + ni * hlev[lv, 2] + nj
                        if hk == failed:  # this ray found the node not clear before: not again
                            break
                        failed = hk
                        ia = hinv[hk, 0]
                        if ia != ia:  # no data under the node
                            break
                        ib = hinv[hk, 1]
                        qa, hb, qc = _ellipsoid_quadratic(ia, ib, dxy2, dz2, oxd, ozd, oxy2, oz2)
                        # necessary: clear up to the smaller node's exit (no side computed yet)
                        if not _clear_between(qa, hb, qc, s, gE):
                            break
                        span = blk << sh
                        a0 = ni * span
                        a1 = min(a0 + span, nr - 1)
                        c0 = nj * span
                        c1 = min(c0 + span, nc - 1)
                        # the node's sides: a side it shares with the smaller node keeps its crossing
                        nN, nN2 = _par_exit_kept(
                            a0 == gi0, gN, gN2, tan_row[a0], c_row[a0], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH
                        )
                        nS, nS2 = _par_exit_kept(
                            a1 == gi1, gS, gS2, tan_row[a1], c_row[a1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH
                        )
                        jm = c1 if east else c0
                        nM = _mer_ahead_kept(
                            along,
                            (c1 == gj1) if east else (c0 == gj0),
                            gM,
                            sin_col[jm],
                            cos_col[jm],
                            ox,
                            oy,
                            dx,
                            dy,
                            s,
                            east,
                        )
                        nE = min(nN, nS, nM)
                        if not _clear_between(qa, hb, qc, s, nE if nE < send else send):
                            break
                        failed = -1
                        glv = sh
                        gE = nE
                        gN = nN
                        gN2 = nN2
                        gS = nS
                        gS2 = nS2
                        gM = nM
                        gi0 = a0
                        gi1 = a1
                        gj0 = c0
                        gj1 = c1
                        gni = ni
                        gnj = nj
                        if nE >= send:
                            ended = True
                            break
                    if ended:
                        st = st_end
                        break
                if _CLIMB and glv >= 0:
                    # into the block beyond the node's side, at s = its crossing: the block
                    # along the side is found by the sides of the block lines at s
                    s = gE
                    side = 2 if gE == gM else (0 if gE == gN else 1)
                    sh = glv
                    qx = ox + s * dx
                    qy = oy + s * dy
                    if side == 2:
                        bj = ((gnj + 1) << sh) if east else ((gnj << sh) - 1)
                        if bj < 0 or bj >= nbc:
                            st = _LEFT
                            break
                        qz = oz + s * dz
                        rho = math.sqrt(qx * qx + qy * qy)
                        lo_b = gni << sh  # the last block row whose north parallel s is south of
                        hi_b = min(lo_b + (1 << sh), nbr)
                        while hi_b - lo_b > 1:
                            mid = (lo_b + hi_b) >> 1
                            m = mid * blk
                            if qz + c_row[m] - rho * tan_row[m] >= 0.0:  # north of parallel m
                                hi_b = mid
                            else:
                                lo_b = mid
                        bi = lo_b
                        i0 = bi * blk
                        i1 = min(i0 + blk, nr - 1)
                        j0 = bj * blk
                        j1 = min(j0 + blk, nc - 1)
                        bN, bN2 = _par_exit_kept(
                            i0 == gi0, gN, gN2, tan_row[i0], c_row[i0], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH
                        )
                        bS, bS2 = _par_exit_kept(
                            i1 == gi1, gS, gS2, tan_row[i1], c_row[i1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH
                        )
                        jm = j1 if east else j0
                        bM = _mer_exit(sin_col[jm], cos_col[jm], ox, oy, dx, dy, s, east)
                        came = 2
                    else:
                        if side == 0:
                            bi = (gni << sh) - 1
                            if bi < 0:
                                st = _LEFT
                                break
                        else:
                            bi = (gni + 1) << sh
                            if bi >= nbr:
                                st = _LEFT
                                break
                        lo_b = gnj << sh  # the last block column whose west meridian s is east of
                        hi_b = min(lo_b + (1 << sh), nbc)
                        while hi_b - lo_b > 1:
                            mid = (lo_b + hi_b) >> 1
                            m = mid * blk
                            if cos_col[m] * qy - sin_col[m] * qx < 0.0:  # west of meridian m
                                hi_b = mid
                            else:
                                lo_b = mid
                        bj = lo_b
                        j0 = bj * blk
                        j1 = min(j0 + blk, nc - 1)
                        if side == 0:
                            i1 = gi0
                            i0 = bi * blk
                            bS = gN2
                            bS2 = np.inf
                            bN, bN2 = _par_exit(tan_row[i0], c_row[i0], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH)
                            came = 1
                        else:
                            i0 = gi1
                            i1 = min(i0 + blk, nr - 1)
                            bN = gS2
                            bN2 = np.inf
                            bS, bS2 = _par_exit(tan_row[i1], c_row[i1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH)
                            came = 0
                        jm = j1 if east else j0
                        bM = _mer_ahead_kept(
                            along,
                            (j1 == gj1) if east else (j0 == gj0),
                            gM,
                            sin_col[jm],
                            cos_col[jm],
                            ox,
                            oy,
                            dx,
                            dy,
                            s,
                            east,
                        )
                    continue
                s = sx
                side = 2 if sx == bM else (0 if sx == bN else 1)
            else:
                # ------------------------------------------------ cell level, inside block (bi, bj)
                # the block's rows of the cell table and of the heights, fetched together now
                # rather than one miss per row as the ray reaches it (see _prefetch)
                if fetch_rows:
                    for m in range(i0, i1):
                        _prefetch(cinv, np.uint64(m), np.uint64(j0))
                    for m in range(i0, i1 + 1):
                        _prefetch(hgt, np.uint64(m), np.uint64(j0))
                        _prefetch(hgt, np.uint64(m), np.uint64(j1))
                cM = np.inf
                if along:
                    if (j + 1 == j1) if east else (j == j0):
                        cM = bM
                    else:
                        jm = j + 1 if east else j
                        cM = _mer_exit(sin_col[jm], cos_col[jm], ox, oy, dx, dy, s, east)
                if i == i0:
                    cN = bN
                    cN2 = bN2
                else:
                    cN, cN2 = _par_exit(tan_row[i], c_row[i], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH)
                if i + 1 == i1:
                    cS = bS
                    cS2 = bS2
                else:
                    cS, cS2 = _par_exit(tan_row[i + 1], c_row[i + 1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH)
                while True:
                    if steps > max_steps:
                        st = _NOCONV
                        done = True
                        break
                    cx = min(cN, cS, cM)
                    s_b = cx
                    if s_b > send:
                        s_b = send if send > s else s
                    k = steps
                    if k < mtrace:
                        trace_s[r, k] = s * idn
                        trace_ij[r, k, 0] = i
                        trace_ij[r, k, 1] = j
                    steps = k + 1
                    # cinv is NaN exactly where the cell has no data: one table read, not two
                    # unsigned indices (i, j >= 0 here): numba then emits no negative-index
                    # wraparound on the table reads (+3 %)
                    ui = np.uint64(i)
                    uj = np.uint64(j)
                    ia = ia_floor + cinv[ui, uj, 0]
                    if ia != ia:
                        st = _NODATA
                        done = True
                        break
                    ib = ib_floor + cinv[ui, uj, 1]
                    qa, hb, qc = _ellipsoid_quadratic(ia, ib, dxy2, dz2, oxd, ozd, oxy2, oz2)
                    if not _clear_between(qa, hb, qc, s, s_b):
                        if _TRIANGLES:  # a constant of the variant (KERNELS): pruned
                            # the cell's two triangles, from the heights and the rows' and columns' tables
                            t1, t2 = _cell_triangles(
                                ox,
                                oy,
                                oz,
                                dx,
                                dy,
                                dz,
                                row_geo[ui, 0],
                                row_geo[ui, 1],
                                row_geo[ui, 2],
                                row_geo[ui, 3],
                                row_geo[ui + np.uint64(1), 0],
                                row_geo[ui + np.uint64(1), 1],
                                row_geo[ui + np.uint64(1), 2],
                                row_geo[ui + np.uint64(1), 3],
                                cos_col[uj],
                                sin_col[uj],
                                cos_col[uj + np.uint64(1)],
                                sin_col[uj + np.uint64(1)],
                                hgt[ui, uj],
                                hgt[ui, uj + np.uint64(1)],
                                hgt[ui + np.uint64(1), uj],
                                hgt[ui + np.uint64(1), uj + np.uint64(1)],
                            )
                            if t1 < best or t2 < best:
                                best = min(t1, t2, best)
                                hit_i = i
                                hit_j = j
                            geo_ok = False
                        else:
                            # the geodetic state at s_b is the next cell's at its s
                            t1, lat, lon, h, g = _bilinear_step(
                                ox,
                                oy,
                                oz,
                                dx,
                                dy,
                                dz,
                                s,
                                s_b,
                                geo_ok,
                                lat,
                                lon,
                                h,
                                g,
                                hgt[i, j],
                                hgt[i, j + 1],
                                hgt[i + 1, j],
                                hgt[i + 1, j + 1],
                                i,
                                j,
                                lat_n,
                                lon_w,
                                dlat,
                                dlon,
                            )
                            if t1 < best:
                                best = t1
                                hit_i = i
                                hit_j = j
                            geo_ok = True
                    else:
                        geo_ok = False
                    if best <= s_b + 1e-9:
                        st = _OK
                        done = True
                        break
                    if s_b >= send or cx == np.inf:
                        st = st_end
                        done = True
                        break
                    s = cx
                    if cx == cM:
                        j += dj
                        if j < j0 or j >= j1:  # into the next block
                            side = 2
                            break
                        if (j + 1 == j1) if east else (j == j0):
                            cM = bM
                        else:
                            jm = j + 1 if east else j
                            cM = _mer_exit(sin_col[jm], cos_col[jm], ox, oy, dx, dy, s, east)
                    elif cx == cN:
                        i -= 1
                        if i < i0:
                            side = 0
                            break
                        cS = cN2
                        cS2 = np.inf
                        if i == i0:
                            cN = bN
                            cN2 = bN2
                        else:
                            cN, cN2 = _par_exit(tan_row[i], c_row[i], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH)
                    else:
                        i += 1
                        if i >= i1:
                            side = 1
                            break
                        cN = cS2
                        cN2 = np.inf
                        if i + 1 == i1:
                            cS = bS
                            cS2 = bS2
                        else:
                            cS, cS2 = _par_exit(tan_row[i + 1], c_row[i + 1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH)
                if done:
                    break
            # ------------------------------------------------ into the next block, through
            # side 0 (north), 1 (south) or 2 (the meridian ahead) of this one, at s
            if side == 2:
                bj += dj
                if bj < 0 or bj >= nbc:
                    st = _LEFT
                    break
                j0 = bj * blk
                j1 = min(j0 + blk, nc - 1)
                jm = j1 if east else j0
                bM = _mer_exit(sin_col[jm], cos_col[jm], ox, oy, dx, dy, s, east)
                came = 2
            elif side == 0:
                bi -= 1
                if bi < 0:
                    st = _LEFT
                    break
                i1 = i0
                i0 = bi * blk
                bS = bN2
                bS2 = np.inf
                bN, bN2 = _par_exit(tan_row[i0], c_row[i0], oz, dz, dz2, dxy2, oxd, oxy2, s, _NORTH)
                came = 1
            else:
                bi += 1
                if bi >= nbr:
                    st = _LEFT
                    break
                i0 = i1
                i1 = min(i0 + blk, nr - 1)
                bN = bS2
                bN2 = np.inf
                bS, bS2 = _par_exit(tan_row[i1], c_row[i1], oz, dz, dz2, dxy2, oxd, oxy2, s, _SOUTH)
                came = 0
        # ------------------------------------------------ the exit: status, and the hit
        ncell[r] = steps
        if best < np.inf and st != _OK:
            # a triangle sliver found beyond the last cell: still the first hit on the mesh
            st = _OK
        status[r] = st
        if st == _OK:
            s_out[r] = best * idn  # in units of the given direction vector
            hx = ox + best * dx
            hy = oy + best * dy
            hz = oz + best * dz
            p_out[r, 0] = hx
            p_out[r, 1] = hy
            p_out[r, 2] = hz
            la, lo, hh = _hit_geodetic(
                hx,
                hy,
                hz,
                row_geo[hit_i, 4],
                row_geo[hit_i, 3],
                row_geo[hit_i, 1],
                lon_col[hit_j],
                sin_col[hit_j],
                cos_col[hit_j],
            )
            geo_out[r, 0] = la
            geo_out[r, 1] = lo
            geo_out[r, 2] = hh
            geo_out[r, 3] = best


def _variant(fn, name, climb, fixed_block, triangles):
    """``fn`` under another name, reading its globals from a copy in which ``_CLIMB`` is
    ``climb``, ``_FIXED_BLOCK`` is ``fixed_block`` and the cell model is fixed to ``triangles``."""
    g = dict(fn.__globals__)
    g.update(_CLIMB=climb, _FIXED_BLOCK=fixed_block, _TRIANGLES=triangles)
    f = types.FunctionType(fn.__code__, g, name, fn.__defaults__, fn.__closure__)
    f.__qualname__ = name
    f.__module__ = fn.__module__
    return f


#: The compiled serial walks, keyed by (climb, block side, model), each releasing the GIL so that
#: :func:`walk_parallel` can run it on slices of the rays in threads (prange runs as range).
#: Call :func:`walk`, which picks one (:func:`_kernel_for`) and hands it the one signature it is
#: compiled for; each is compiled on its first use only, so a call compiles one walk.
#: ``"climb"``: with the climb above the blocks, the block side read at run time. ``"flat"``:
#: without it, for blocks of :data:`BLOCK` cells (the side folded into the code); what
#: :func:`walk` runs when it is given no levels (``hlev`` empty). The climb's code alone,
#: unused, made the cell walk 4-10 % slower (its registers and branches in the hot loop;
#: docs/terrain.md); the hits are the same bit for bit (the hierarchy only decides what is
#: skipped). ``"flat_block"``: the flat walk for tables of another block side
#: (``terrain.block_cells``: 12 on a grid of 8.7 m cells), the side read at run time.
#: The model, ``"bilinear"`` or ``"triangles"``: the other model's branch is left out (its
#: code and its helpers, :func:`_bilinear_cell` or :func:`_tri`, are not compiled);
#: :func:`walk`'s ``triangles`` picks the kernel and is not passed to it.
KERNELS = {
    (kind, model): cached_njit(KEY, error_model="numpy", fastmath={"contract"}, nogil=True)(
        _variant(_walk, f"_walk_{kind}_{model}", kind == "climb", BLOCK if kind == "flat" else 0, model == "triangles")
    )
    for kind in ("climb", "flat", "flat_block")
    for model in ("bilinear", "triangles")
}


def _kernel_for(hlev, block=BLOCK, triangles=False):
    kind = "climb" if np.shape(hlev)[0] > 0 else "flat" if int(block) == BLOCK else "flat_block"
    return KERNELS[kind, "triangles" if triangles else "bilinear"]


# One signature per kernel. numba compiles a kernel once per distinct argument type, and
# a read-only array is a type of its own: the origins and directions of a line-of-sight
# batch are read-only views when they need no broadcast (np.broadcast_to) and fresh
# writable arrays when they do, so the four combinations compiled the walk four times
# on a cold cache (16 s each). Inputs are therefore always passed as read-only, C-ordered
# views of the dtype below (a view: no copy), scalars as Python floats / bool, and the
# outputs are checked to be writable C-ordered arrays of the dtype the kernel fills.
#: The arrays of :class:`WalkGrid`, their dtype and dimensions.
_GRID_ARRAYS = {
    "hgt": (np.float64, 2),
    "lon_col": (np.float64, 1),
    "cinv": (np.float32, 3),
    "binv": (np.float32, 3),
    "hinv": (np.float64, 2),
    "hlev": (np.int64, 2),
    "row_geo": (np.float64, 2),
    "tan_row": (np.float64, 1),
    "c_row": (np.float64, 1),
    "sin_col": (np.float64, 1),
    "cos_col": (np.float64, 1),
}
#: The scalars of :class:`WalkGrid` (``blk`` apart: an int).
_GRID_FLOATS = ("h_top", "h_floor", "lat_n", "lon_w", "dlat", "dlon")
#: :class:`WalkOut`'s arrays, their dtype and dimensions.
_OUT = {
    "s_out": (np.float64, 1),
    "p_out": (np.float64, 2),
    "geo_out": (np.float64, 2),
    "status": (np.uint8, 1),
    "ncell": (np.int64, 1),
    "trace_s": (np.float64, 2),
    "trace_ij": (np.int64, 3),
}


#: The tables the kernel reads as float32 offsets from the floor's ellipsoid
#: (:func:`geoloc.surfaces.terrain._offsets32`): any other dtype is refused, not cast, since a
#: table of the values themselves (the form before the offsets) would be read as offsets.
_OFFSET_TABLES = ("cinv", "binv")


def _readonly(name, a, dtype, ndim):
    if (
        isinstance(a, np.ndarray)
        and a.dtype == dtype
        and a.ndim == ndim
        and not a.flags.writeable
        and a.flags.c_contiguous
    ):
        return a  # already the kernel's form (the tables of terrain._exact_tables are kept so)
    if name in _OFFSET_TABLES and np.asarray(a).dtype != dtype:
        raise ValueError(
            f"walk: {name} must be float32 offsets from the floor's ellipsoid "
            f"(geoloc.surfaces.terrain._offsets32), got dtype {np.asarray(a).dtype}"
        )
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.ndim != ndim:
        raise ValueError(f"walk: {name} must have {ndim} dimensions, got shape {a.shape}")
    v = a.view()
    v.flags.writeable = False
    return v


def _output(name, a, dtype, ndim):
    if not (
        isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == ndim and a.flags.c_contiguous and a.flags.writeable
    ):
        raise ValueError(
            f"walk: {name} must be a writable C-ordered {np.dtype(dtype).name} array with {ndim} dimensions"
        )
    return a


def _order(order, n):
    """The walk order as the kernel takes it: every ray in turn when None; else checked to
    index the rays (a wrong index would read and write outside the arrays)."""
    if order is None:
        return np.arange(n, dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if order.ndim != 1 or (len(order) and (order.min() < 0 or order.max() >= n)):
        raise ValueError(
            f"walk: order must list ray indices in [0, {n}), got shape {order.shape}"
            + (f" and values {order.min()}..{order.max()}" if order.ndim == 1 and len(order) else "")
        )
    return order


def _prepare(o, d, grid, out, triangles, order=None, order_checked=False):
    """(kernel, its arguments (rays, grid, out), the DEM's rows + columns): the rays, the
    :class:`WalkGrid` and the :class:`WalkOut` checked and put in the kernel's form (read-only
    C-ordered inputs of the dtypes of :data:`_GRID_ARRAYS`, floats as Python floats, writable
    outputs of :data:`_OUT`: one compiled signature), the kernel picked (:func:`_kernel_for`)."""
    o = _readonly("o", o, np.float64, 2)
    d = _readonly("d", d, np.float64, 2)
    grid = WalkGrid(
        **{
            k: (_readonly(k, v, *_GRID_ARRAYS[k]) if k in _GRID_ARRAYS else float(v) if k in _GRID_FLOATS else int(v))
            for k, v in zip(WalkGrid._fields, grid)
        }
    )
    out = WalkOut(*(_output(k, a, *_OUT[k]) for k, a in zip(WalkOut._fields, out)))
    # walk_parallel's slices of an order it has checked once: not scanned again per thread
    order = np.ascontiguousarray(order, dtype=np.int64) if order_checked else _order(order, len(o))
    for name, a in zip(WalkOut._fields, out):
        if len(a) != len(o):
            raise ValueError(f"walk: {name} has {len(a)} rows for {len(o)} rays")
    hgt, block = grid.hgt, grid.blk
    if max(hgt.shape) >= 1 << 24 or not 1 <= block <= 16:
        raise ValueError(
            f"walk: a grid of {hgt.shape[0]} x {hgt.shape[1]} nodes with blocks of {block} cells: "
            "the walk takes fewer than 2^24 rows and columns and blocks of 1 to 16 cells"
        )
    want = (-(-(hgt.shape[0] - 1) // block), -(-(hgt.shape[1] - 1) // block))
    if grid.binv.shape[:2] != want:
        # a block table made for another side would be read at the wrong blocks: refused
        raise ValueError(
            f"walk: binv has {grid.binv.shape[0]} x {grid.binv.shape[1]} blocks, but block = {block} "
            f"on {hgt.shape[0]} x {hgt.shape[1]} nodes needs {want}: pass the block side the "
            "tables were made with (geoloc.surfaces.terrain._exact_tables: 'block')"
        )
    kernel = _kernel_for(grid.hlev, block, triangles)
    return kernel, (WalkRays(o, d, order), grid, out), hgt.shape[0] + hgt.shape[1]


def _call(o, d, grid, out, triangles, order=None, order_checked=False, python=True):
    """Walk ``order``'s rays: the start uncompiled where the call is small (:func:`_python_prefix`,
    unless ``python`` is False), the rest by the compiled kernel. Returns how many rays of the
    order (checked) it walked uncompiled, and that order."""
    kernel, (rays, grid, out), nodes = _prepare(o, d, grid, out, triangles, order, order_checked)
    start = _python_prefix(kernel, rays, grid, out, nodes) if python else 0
    if start < len(rays.order):
        kernel(rays._replace(order=rays.order[start:]), grid, out)
    return start, rays.order


#: A call of at most this many rays, and at most :data:`PY_WALK_MAX_WORK` rays x (rows + columns)
#: of the DEM, runs the walk's Python source (:func:`_python_walk`) instead of its compiled
#: kernel, whatever the process compiled before: ``locate`` (one ray) and a short ``replay``
#: compile nothing (the compile is 5-15 s of CPU, for one ray; the Python walk about 70 us a ray and
#: 5 us a cell step on the bundled crop). The same code, run with numpy's float64 scalars: the
#: statuses are the kernel's, the hits within the rounding of the multiply-adds LLVM fuses
#: (``fastmath={"contract"}``; the bilinear polish stops at 1e-7 m anyway), checked in
#: ``tests/surfaces/test_terrain_python_walk.py``. The choice is the call's alone (its rays, its DEM, and
#: whether its caller opened an :func:`uncompiled_budget` or a :func:`compiled_walk`), never the process's history, so the
#: same call gives the same bits in any process: a campaign's worker equals the serial run
#: (tests/workflows/test_campaign.py), a viewer's step equals its first, a whole frame is the same in any
#: chunks (tests/workflows/test_ortho.py). A process making many one-ray calls (a live feed) pays about
#: 0.1 ms a ray for that (about 50 us compiled). 0: always compiled.
PY_WALK_MAX_RAYS = 64
#: Rays x (rows + columns): the most cells such a call could cross, bounded so that a grazing
#: batch over a large DEM still takes the kernel (a straight ray crosses each node line once
#: or twice; about 5-20 us a cell step in Python). Also the bound of a chunk under a budget.
PY_WALK_MAX_WORK = 1 << 16
#: The default of :func:`uncompiled_budget`: the uncompiled walk's cost, in cell steps (the
#: walk's ``ncell``: block and cell boundaries crossed) plus :data:`PY_WALK_RAY_STEPS` a ray, that
#: a larger call may take, projected from the rays walked so far. Fitted on the bundled crop
#: (2000-ray oblique batches, grazing rays over a rough DEM; 2 cores, idle): 70 us a ray and 5 us
#: a step, so 2^17 is about 0.65 s, a tenth of the compile or less.
PY_WALK_MAX_STEPS = 1 << 17
#: A ray's fixed cost in the uncompiled walk, in cell steps (70 us against 5 us, above).
PY_WALK_RAY_STEPS = 14
_BUDGET: contextvars.ContextVar = contextvars.ContextVar("geoloc_uncompiled_walk_budget", default=0)
_COMPILED: contextvars.ContextVar = contextvars.ContextVar("geoloc_compiled_walk", default=False)
_PY_FUNCS: dict = {}


@contextlib.contextmanager
def uncompiled_budget(steps: int | None = None) -> Iterator[None]:
    """Within this block, a walk larger than :data:`PY_WALK_MAX_RAYS` rays starts uncompiled too:
    :data:`PY_WALK_MAX_RAYS` rays at a time (fewer over a DEM of many rows + columns:
    :data:`PY_WALK_MAX_WORK`), while the cost of the rays walked so far (their cell steps plus
    :data:`PY_WALK_RAY_STEPS` a ray), projected over the call, stays within ``steps`` (default
    :data:`PY_WALK_MAX_STEPS`, about 0.65 s); the compiled kernel walks the rest.

    For a one-off batch that would otherwise compile the walk on a cold cache (5-15 s of CPU)
    though it walks in under a second uncompiled: the viewer's first scene, whose example flight
    has 5364 footprint rays (:func:`geoloc_viz.flight_model.build`), a first view that must not
    wait for a compile. Not for a loop of
    such calls in a warm process (a whole frame in chunks, a campaign): each would pay up to the
    budget where the kernel takes milliseconds. The choice stays the call's (its rays, their order,
    its DEM and this block: the steps counted are the walk's own), never the process's history
    or the machine's speed; :func:`walk_parallel` makes it once for the whole call.
    """
    token = _BUDGET.set(PY_WALK_MAX_STEPS if steps is None else max(int(steps), 0))
    try:
        yield
    finally:
        _BUDGET.reset(token)


@contextlib.contextmanager
def compiled_walk() -> Iterator[None]:
    """Within this block every walk takes the compiled kernel, however few its rays.

    For a loop of many small calls in one process: a least-squares fit locates its records
    again at every trial (``geoloc calibrate ... --dem --loo``: 2116 calls of at most 64 rays),
    and uncompiled each ray costs about 70 us and each cell step 5 us where the kernel takes
    under 1 us (57 s of a 103 s profiled run were the Python walk). The choice stays the call's
    caller's, never the process's history: the same fit gives the same bits in any process.
    Also a decorator (``@compiled_walk()``)."""
    token = _COMPILED.set(True)
    try:
        yield
    finally:
        _COMPILED.reset(token)


def _python_ok(n, nodes):
    """Whether a call of ``n`` rays over a DEM of ``nodes`` rows + columns walks uncompiled."""
    return n <= PY_WALK_MAX_RAYS and n * nodes <= PY_WALK_MAX_WORK


def _python_prefix(kernel, rays, grid, out, nodes) -> int:
    """Walk ``order``'s rays uncompiled from its start: all of a small call (:func:`_python_ok`),
    else, within an :func:`uncompiled_budget`, a chunk at a time while the cost projected over the
    whole call (the cell steps so far plus :data:`PY_WALK_RAY_STEPS` a ray, per ray walked, times
    the rays) stays within the budget. Returns how many rays of ``order`` it walked (0: none, the
    kernel walks the call). Where Python's arithmetic raises and numba's does not (int(nan), a
    sqrt of a negative, an index past an end) the chunk's outputs are restored and the kernel
    walks the rest from there."""
    order = rays.order
    n = len(order)
    if n == 0 or _COMPILED.get():
        return 0
    budget = None
    if _python_ok(n, nodes):
        chunk = n
    else:
        budget = _BUDGET.get()
        if not budget or nodes > PY_WALK_MAX_WORK:
            return 0
        chunk = max(1, min(PY_WALK_MAX_RAYS, PY_WALK_MAX_WORK // max(int(nodes), 1)))
    outs = out
    ncell = out.ncell
    # the scalars as numpy float64: a Python float plus a float32 table entry is float32
    # under numpy 2's promotion; numba's (and numpy's float64 + float32) is float64
    grid64 = grid._replace(**{k: np.float64(getattr(grid, k)) for k in _GRID_FLOATS})
    run = _python_walk(kernel)
    done, steps = 0, 0
    while done < n:
        sub = order[done : done + chunk]
        kept = [a[sub].copy() for a in outs]  # status is read too: restored if the kernel must redo them
        try:
            with np.errstate(all="ignore"):
                run(rays._replace(order=sub), grid64, out)
        except (ArithmeticError, ValueError, IndexError):
            for a, k in zip(outs, kept):
                a[sub] = k
            return done
        done += len(sub)
        steps += int(ncell[sub].sum())
        # the cost so far per ray walked, projected over the call's rays
        if budget is not None and done < n and (steps + PY_WALK_RAY_STEPS * done) * n > budget * done:
            return done
    return done


def _python_walk(kernel):
    """``kernel``'s Python function, with the compiled helpers it calls replaced by theirs
    (recursively), ``prange`` by ``range`` and the prefetch hint by nothing: runs uncompiled."""

    def plain(f):
        if f in _PY_FUNCS:
            return _PY_FUNCS[f]
        fn = getattr(f, "py_func", f)  # a kernel's Python function
        g = dict(fn.__globals__)
        out = types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)
        _PY_FUNCS[f] = out
        for name, v in list(g.items()):
            if isinstance(v, Dispatcher):
                g[name] = plain(v)
        g["prange"] = range
        g["_prefetch"] = _no_prefetch
        return out

    return plain(kernel)


def _no_prefetch(arr, i, j):
    return None


def _python_start(o, d, grid, out, triangles, order=None):
    """Walk the call's first rays uncompiled (:func:`_python_prefix`): (how many of the order, the order checked)."""
    kernel, (rays, grid, out), nodes = _prepare(o, d, grid, out, triangles, order)
    return _python_prefix(kernel, rays, grid, out, nodes), rays.order


def walk(
    o: np.ndarray,
    d: np.ndarray,
    grid: WalkGrid,
    out: WalkOut,
    triangles: bool,
    order: np.ndarray | None = None,
) -> None:
    """The exact first hit for each ray, serial: :func:`_walk` (its docstring) compiled once
    for the cell model (``triangles``) and the climb; a flat walk of :data:`KERNELS` when
    ``grid.hlev`` is empty (no levels above the blocks to climb). Fills ``out``.

    ``o``, ``d``: the rays' ECEF origins [m] and directions (n, 3); ``grid``: the DEM's tables
    (its ``blk`` the block side ``binv`` and ``hinv`` were made for, checked against ``binv``'s
    shape); ``order``: the rays to walk, in that order (default: all, in turn; :func:`ray_order`)."""
    _call(o, d, grid, out, triangles, order)


def walk_parallel(
    o: np.ndarray,
    d: np.ndarray,
    grid: WalkGrid,
    out: WalkOut,
    triangles: bool,
    threads: int | None = None,
    order: np.ndarray | None = None,
) -> None:
    """As :func:`walk`, the rays spread over all cores; identical results (each ray is walked alone).

    The serial kernel runs on contiguous slices of the order in threads (it releases the
    GIL), rather than as a second, ``parallel=True`` compilation of the walk: numba's
    parfor passes over the whole inlined walk took minutes of CPU on a cold cache, for
    the same per-ray code. ``threads`` defaults to numba's thread count (``numba.get_num_threads()``:
    the cores, or what the caller set, e.g. a campaign's workers).
    """
    # the uncompiled start decided once for the whole call, as the serial walk decides it (the same
    # rays walked uncompiled whatever the thread count); the threads share the compiled rest
    start, order = _python_start(o, d, grid, out, triangles, order)
    order = order[start:]
    n = len(order)
    k = max(1, min(int(threads or numba.get_num_threads()), n // 256 or 1))
    cuts = np.linspace(0, n, k + 1).astype(int)

    def part(a, b):  # each thread a contiguous run of the order: disjoint rays, disjoint output rows
        _call(o, d, grid, out, triangles, order[a:b], order_checked=True, python=False)

    if k == 1:
        part(0, n)
        return
    with ThreadPoolExecutor(k) as pool:
        for f in [pool.submit(part, a, b) for a, b in zip(cuts[:-1], cuts[1:])]:
            f.result()


@cached_njit(KEY, error_model="numpy", fastmath={"contract"})
def _tile_keys(o, d, ia, ib, tan_n, sin_w, cos_w, tile_lat, tile_lon, nt, keys):
    """keys[r] = the tile (rows of ``nt`` tiles, serpentine) under the point where ray r
    meets the ellipsoid with ia, ib = 1/(a+h)^2, 1/(b+h)^2 [Q17 eq. 10-11], under its
    origin if it misses it; tiles of ``tile_lat`` x ``tile_lon`` rad from the north
    parallel and the west meridian (tan, sin, cos of lat_n, lon_w), the outer ring for
    anything outside. An order key only (:func:`ray_order`): an error moves a ray to
    another tile, never its hit. So the angles from the corner are taken as their
    tangents (from the west meridian's plane, and tan(lat) = z / ((1 - e^2) rho) of a
    point on the ellipsoid): monotonic in the angles, no atan2 (it was two thirds of
    this function's time)."""
    for r in range(o.shape[0]):
        ox = o[r, 0]
        oy = o[r, 1]
        oz = o[r, 2]
        dx = d[r, 0]
        dy = d[r, 1]
        dz = d[r, 2]
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        s = 0.0
        if dn > 0.0 and dn < np.inf:
            s0, _, _ = _roots(ox, oy, oz, dx / dn, dy / dn, dz / dn, ia, ib)
            if s0 == s0 and s0 > 0.0:
                s = s0 / dn
        px = ox + s * dx
        py = oy + s * dy
        pz = oz + s * dz
        ti = 0
        tj = 0
        den = cos_w * px + sin_w * py  # > 0: within 90 deg of the west meridian
        rho = math.sqrt(px * px + py * py)
        if den > 0.0 and rho > 0.0 and abs(px) + abs(py) + abs(pz) < np.inf:
            tl = pz / ((1.0 - E2) * rho)
            fi = -(tl - tan_n) / (1.0 + tl * tan_n) / tile_lat  # tan(lat_n - lat)
            fj = (cos_w * py - sin_w * px) / den / tile_lon  # tan(lon - lon_w)
            ti = int(min(max(fi + 1.0, 0.0), nt - 1.0))
            tj = int(min(max(fj + 1.0, 0.0), nt - 1.0))
        if ti % 2 == 1:
            tj = nt - 1 - tj
        keys[r] = ti * nt + tj


def ray_order(
    o: NDArray[np.float64],
    d: NDArray[np.float64],
    h_mid: float,
    lat_n: float,
    lon_w: float,
    dlat: float,
    dlon: float,
    tile_cells: int,
    nt: int,
) -> NDArray[np.int64]:
    """A permutation of the rays that visits the DEM tile by tile (``tile_cells`` cells
    square, ``nt`` tiles a side with the outer ring), by the point where each ray meets
    the height ``h_mid`` [m, ellipsoidal]: walked in this order, consecutive rays read
    nearby parts of the cell and height tables (100 MB each on a 3601 x 3601 DEM).
    Stable: rays in one tile keep their order. The order changes no hit."""
    o = np.ascontiguousarray(o, dtype=np.float64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    keys = np.empty(len(o), dtype=np.int64)
    _tile_keys(
        o,
        d,
        1.0 / (A + h_mid) ** 2,
        1.0 / (B + h_mid) ** 2,
        math.tan(lat_n),
        math.sin(lon_w),
        math.cos(lon_w),
        float(dlat * tile_cells),
        float(dlon * tile_cells),
        int(nt),
        keys,
    )
    # keys < nt^2 <= 65536 for the tile sizes used: a 16-bit stable sort is a radix sort
    kt = np.uint16 if nt * nt <= 65536 else np.int64
    return np.argsort(keys.astype(kt), kind="stable").astype(np.int64)


def median_run(o: NDArray[np.float64], d: NDArray[np.float64], dh: float, m: int) -> float:
    """The median, over up to ``m`` of the rays spread over the batch, of the horizontal run
    over which a ray descends by ``dh`` metres: dh cot(depression), with the geocentric up
    (an order of magnitude is all :func:`geoloc.surfaces.terrain.climbs` asks); a ray that
    does not descend runs forever (inf), a ray with NaN in it is left out; NaN if none is
    left. In numpy on the (at most ``m``) rays picked, first and last included, where a
    compiled version cost 0.7-0.9 s of CPU to compile on a cold cache, for every first call
    of a verb. The run falls as the sine of the depression grows (each rounded operation of
    dh sqrt(1 - s^2) / s is monotonic), so the median run is the run of the median sine (the
    mean of the two middle runs for an even count, as ``np.median`` takes it), bit for bit:
    two runs computed, not one a ray, and under twenty numpy calls instead of about forty
    (each costs more right after a walk has filled the caches: 0.42 against 0.70 ms a call
    of 256 rays with the caches flushed before it, load 16)."""
    n = len(o)
    k = max(0, min(n, int(m)))
    if k == 0:
        return math.nan
    o = np.asarray(o, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if k < n:
        q = np.arange(k)
        pick = (q * (n - 1)) // (k - 1) if k > 1 else np.zeros(1, np.int64)
        o = o[pick]
        d = d[pick]
    # the sums in the order x, y, z (a sum of three is summed in turn; einsum's differs in the last bit)
    du = (d * o).sum(-1)
    nn = (o * o).sum(-1)
    nn *= (d * d).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sin_dep = -du / np.sqrt(nn)
    sin_dep = sin_dep[~np.isnan(sin_dep)]
    c = len(sin_dep)
    if c == 0:
        return math.nan
    # the runs ascending are the sines descending: the middle pair is the same pair of places
    mid = np.partition(sin_dep, ((c - 1) // 2, c // 2))
    lo, hi = float(mid[(c - 1) // 2]), float(mid[c // 2])

    def run(sd):
        return float(dh) * math.sqrt(max(1.0 - sd * sd, 0.0)) / sd if sd > 0.0 else math.inf

    return run(lo) if c % 2 else (run(lo) + run(hi)) / 2.0
