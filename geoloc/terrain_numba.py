"""Compiled kernel of the exact first-hit DEM solver (see :mod:`geoloc.terrain`).

Why numba: the walk is a per-ray loop over a data-dependent number of cells
(tens, with early exit at the first hit); in numpy it would be a masked loop
over the longest ray with a dozen temporary arrays per step, about two orders
of magnitude slower than the 1 M rays/s goal. The kernel is compiled once
(``cache=True`` keeps the machine code in ``__pycache__``).

The kernel works in ECEF with the exact cell boundaries of a geographic grid:
a meridian lambda = lambda_j is a plane through the Z axis, and a parallel
phi = phi_i of constant *geodetic* latitude is the cone

    z + R_N(phi) e^2 sin(phi) = rho tan(phi),   rho = sqrt(x^2 + y^2)

(from x = (R_N + h) cos phi, z = (R_N (1 - e^2) + h) sin phi, GEOMETRY.md
section 1), so the cell where the ray leaves the current one is found with one
division per meridian and one quadratic per parallel, without approximation.

It carries a scalar copy of Vermeille's ECEF -> geodetic closed form of
:func:`geoloc.ellipsoid.ecef_to_geodetic` (numba cannot call the vectorised
numpy version per point); ``tests/test_terrain.py`` checks the two agree.

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
import types

import numpy as np
from numba import njit, prange

from ._nbgeo import geodetic, geodetic_up
from .ellipsoid import A, B, E2
from .status import Status

_OK = int(Status.OK)
_SKY = int(Status.SKY)
_LEFT = int(Status.LEFT_DEM)
_NODATA = int(Status.NODATA)
_NOCONV = int(Status.NO_CONVERGENCE)
_INVALID = int(Status.INVALID_INPUT)
#: Cells per side of a block of the min/max hierarchy.
BLOCK = 8




@njit(cache=True, error_model="numpy")
def _roots(ox, oy, oz, dx, dy, dz, h):
    """Near and far ray parameters on the ellipsoid (a+h, a+h, b+h) [Q17 eq. 10-11].

    The compiled twin of :func:`geoloc.intersect.ray_inflated_ellipsoid` (which
    returns the near root only); NaN, NaN when the line misses or the near root is
    behind; ``inside`` when the origin is inside.
    """
    ia = 1.0 / ((A + h) * (A + h))
    ib = 1.0 / ((B + h) * (B + h))
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


@njit(cache=True, error_model="numpy", inline="always")
def latlon(x, y, z):
    """Geodetic latitude and longitude by Bowring's one-step formula (no height).

    B. R. Bowring, Survey Review 23(181):323-327, 1976: with the parametric
    latitude theta from tan(theta) = a z / (b rho),
    tan(phi) = (z + e'^2 b sin^3 theta) / (rho - e^2 a cos^3 theta).
    Used only to find the cell under a point (error < 1e-9 rad for heights
    -1 km..20 km, tested); heights come from :func:`geodetic`.
    """
    return _lat_bowring(x, y, z), math.atan2(y, x)


@njit(cache=True, error_model="numpy", inline="always")
def _lat_bowring(x, y, z):
    """The latitude of :func:`latlon` alone."""
    rho = math.sqrt(x * x + y * y)
    za = z * A
    rb = rho * B
    q = math.sqrt(za * za + rb * rb)
    st = za / q
    ct = rb / q
    ep2 = E2 / (1.0 - E2)
    return math.atan2(z + ep2 * B * st * st * st, rho - E2 * A * ct * ct * ct)


@njit(cache=True, error_model="numpy", inline="always")
def _wrap(lon, lon_west):
    """Longitude into the grid's window [lon_west - pi, lon_west + pi)."""
    return (lon - lon_west + math.pi) % (2.0 * math.pi) + lon_west - math.pi


@njit(cache=True, error_model="numpy", inline="always")
def _cone_cross(px, py, pz, dx, dy, dz, tanp, cpar, skip_small):
    """Smallest Delta > 0 with p + Delta d on the parallel cone (tan phi, c); inf if none."""
    zp = pz + cpar
    t2 = tanp * tanp
    qa = dz * dz - t2 * (dx * dx + dy * dy)
    qb = 2.0 * (zp * dz - t2 * (px * dx + py * dy))
    qc = zp * zp - t2 * (px * px + py * py)
    r0 = np.inf
    r1 = np.inf
    if abs(qa) < 1e-300:
        if qb != 0.0:
            r0 = -qc / qb
    else:
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:
            return np.inf
        sq = math.sqrt(disc)
        qq = -0.5 * (qb + math.copysign(sq, qb))
        if qq != 0.0:
            r0 = qq / qa
            r1 = qc / qq
        else:
            r0 = 0.0
    best = np.inf
    for r in (r0, r1):
        if r <= skip_small or r == np.inf:
            continue
        zr = zp + r * dz
        if tanp > 1e-15 and zr < 0.0:  # the other nappe
            continue
        if tanp < -1e-15 and zr > 0.0:
            continue
        if r < best:
            best = r
    return best


@njit(cache=True, error_model="numpy", inline="always")
def _plane_cross(px, py, sl, cl, dx, dy, skip_small):
    """Smallest Delta > 0 with p + Delta d on the meridian half-plane (sin, cos of lambda)."""
    den = -sl * dx + cl * dy
    if den == 0.0:
        return np.inf
    r = -(-sl * px + cl * py) / den
    if r <= skip_small:
        return np.inf
    if cl * (px + r * dx) + sl * (py + r * dy) < 0.0:  # the antimeridian half of the plane
        return np.inf
    return r


@njit(cache=True, error_model="numpy", inline="always")
def _tri(ox, oy, oz, dx, dy, dz, p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z):
    """Moller-Trumbore ray x triangle (p0, p1, p2); ray parameter or inf.

    Scalars only: an array argument of an inlined helper costs a reference-count
    increment and decrement (atomic) per call, which was a third of the walk's time.
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
    inv = 1.0 / det
    sx = ox - p0x
    sy = oy - p0y
    sz = oz - p0z
    u = (sx * hx + sy * hy + sz * hz) * inv
    if u < -1e-12 or u > 1.0 + 1e-12:
        return np.inf
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -1e-12 or u + v > 1.0 + 1e-12:
        return np.inf
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t <= 0.0:
        return np.inf
    return t


@njit(cache=True, error_model="numpy", inline="always")
def _bilin(z00, z10, z01, z11, u, v):
    return ((1.0 - v) * ((1.0 - u) * z00 + u * z10)
            + v * ((1.0 - u) * z01 + u * z11))


@njit(cache=True, error_model="numpy")
def _bilinear_cell(ox, oy, oz, dx, dy, dz, sa, sb, lat_a, lon_a, h_a, g_a, lat_b, lon_b, h_b,
                   z00, z10, z01, z11, i, j, lat_n, lon_w, dlat, dlon):
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
                    la, lo, hh = geodetic(ox + s * dx, oy + s * dy, oz + s * dz)
                    lo = _wrap(lo, lon_w)
                    u = (lo - (lon_w + j * dlon)) / dlon
                    v = ((lat_n - i * dlat) - la) / dlat
                    if hh - _bilin(z00, z10, z01, z11, u, v) <= 0.0:
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
        la, lo, hh = geodetic(ox + s * dx, oy + s * dy, oz + s * dz)
        lo = _wrap(lo, lon_w)
        u = (lo - (lon_w + j * dlon)) / dlon
        v = ((lat_n - i * dlat) - la) / dlat
        res = hh - _bilin(z00, z10, z01, z11, u, v)
        tt = (s - sa) / L
        slope = (c1 + 2.0 * c2 * tt) / L
        if slope >= 0.0:
            break
        step = res / slope
        s = s - step
        if abs(step) < 1e-7:
            break
    return s


@njit(cache=True, error_model="numpy", inline="always")
def _exit(px, py, pz, dx, dy, dz, tan_n, c_n, tan_s, c_s, sin_w, cos_w, sin_e, cos_e,
          sk_n, sk_s, sk_w, sk_e):
    """Where the ray from p leaves the band between the north and south parallels
    (tan phi, c of each cone) and the west and east meridians (sin, cos of each
    lambda): (Delta, via) with via 0 N, 1 S, 2 W, 3 E, -1 none. Scalars, not the
    tables: see :func:`_tri`.

    The meridian planes are tried first (one division each); the sign of
    z + c - rho tan(phi) (increasing with latitude) at that point says whether the
    ray is still between the parallels, so at most one cone quadratic is solved.
    sk_*: the skip distance for a root at the boundary the ray stands on; a
    negative value leaves that meridian out (a line meets a plane once).
    """
    sp = np.inf
    vp = -1
    if sk_w >= 0.0:
        c = _plane_cross(px, py, sin_w, cos_w, dx, dy, sk_w)
        if c < sp:
            sp = c
            vp = 2
    if sk_e >= 0.0:
        c = _plane_cross(px, py, sin_e, cos_e, dx, dy, sk_e)
        if c < sp:
            sp = c
            vp = 3
    if sp < np.inf:
        qx = px + sp * dx
        qy = py + sp * dy
        qz = pz + sp * dz
        rho = math.sqrt(qx * qx + qy * qy)
        fn = qz + c_n - rho * tan_n
        fs = qz + c_s - rho * tan_s
        if fn <= 0.0 and fs >= 0.0:
            return sp, vp
        if fn > 0.0:
            c = _cone_cross(px, py, pz, dx, dy, dz, tan_n, c_n, sk_n)
            if c < sp:
                return c, 0
        else:
            c = _cone_cross(px, py, pz, dx, dy, dz, tan_s, c_s, sk_s)
            if c < sp:
                return c, 1
        return sp, vp
    ex = np.inf
    via = -1
    c = _cone_cross(px, py, pz, dx, dy, dz, tan_n, c_n, sk_n)
    if c < ex:
        ex = c
        via = 0
    c = _cone_cross(px, py, pz, dx, dy, dz, tan_s, c_s, sk_s)
    if c < ex:
        ex = c
        via = 1
    return ex, via


def _walk(o, d, h_top, h_floor, hgt, cmax, cinv, binv, nodes, lat_n, lon_w, dlat, dlon,
         tan_row, c_row, sin_col, cos_col, triangles, s_out, status, ncell, trace_s, trace_ij):
    """Exact first hit for each ray (see module docstring); fills s_out, status, ncell.

    cinv[i, j] = (1/(a+H)^2, 1/(b+H)^2) of the ellipsoid inflated to H = cell max + margin
    (float32 rounded toward zero by the caller, i.e. a slightly larger ellipsoid):
    the ray's part in a cell is skipped when it stays outside that ellipsoid (the
    quadratic |P'(s)|^2 - 1 of [Q17 eq. 11] is convex in s, so its minimum on the
    cell's interval decides). binv is the same for blocks of BLOCK x BLOCK cells (their
    highest node): a block the ray crosses clear of it is skipped in one step (a
    two-level min/max hierarchy). trace_s / trace_ij have shape (n, m); m = 0 disables
    the trace. cmax is not read (cinv is NaN exactly where it is: no data); it stays
    in the signature for the callers.
    """
    n = o.shape[0]
    nr = hgt.shape[0]
    nc = hgt.shape[1]
    mtrace = trace_s.shape[1]
    # the start cell's fast path needs the grid within 0.4 rad of its west meridian
    wide_ok = (nc - 1) * dlon < 0.4 and nr >= 2 and nc >= 2
    for r in prange(n):
        s_out[r] = np.nan
        ncell[r] = 0
        if status[r] != _OK:
            continue
        ox = o[r, 0]
        oy = o[r, 1]
        oz = o[r, 2]
        dx = d[r, 0]
        dy = d[r, 1]
        dz = d[r, 2]
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not (dn > 0.0 and dn < np.inf) or not (abs(ox) + abs(oy) + abs(oz) < np.inf):
            status[r] = _INVALID
            continue
        dx /= dn
        dy /= dn
        dz /= dn
        # walk from the ellipsoid inflated to H_max + margin down to H_min - margin [Q17 eq. 11]
        s0, s1, inside = _roots(ox, oy, oz, dx, dy, dz, h_top)
        if inside:
            s0 = 0.0
        elif s0 != s0:
            status[r] = _SKY
            continue
        f0, f1, finside = _roots(ox, oy, oz, dx, dy, dz, h_floor)
        end_is_floor = not finside and f0 == f0
        send = f0 if end_is_floor else s1
        s_start_r = s0
        dxy2 = dx * dx + dy * dy
        dz2 = dz * dz
        oxd = ox * dx + oy * dy
        ozd = oz * dz
        oxy2 = ox * ox + oy * oy
        oz2 = oz * oz
        s = s_start_r
        lat = 0.0
        lon = 0.0
        h = 0.0
        g = 0.0
        geo_ok = False  # lat, lon, h, g hold the geodetic state at s only when True
        # Start cell without atan2: a guess from tan(lon - lon_w) and the latitude on
        # the ellipsoid (a few cells off at most), then corrected on the exact cell
        # boundaries (the side of the meridian planes and parallel cones, as in the
        # walk). Near the grid's edges, for a wide grid or a far guess: the atan2 path.
        qx = ox + s * dx
        qy = oy + s * dy
        qz = oz + s * dz
        i = -1
        j = -1
        fast = wide_ok
        if fast:
            den = cos_col[0] * qx + sin_col[0] * qy
            num = cos_col[0] * qy - sin_col[0] * qx
            fast = den > 0.0 and abs(num) < 0.5 * den
        if fast:
            u = num / den  # tan(lon - lon_w), |lon - lon_w| < 0.47 rad
            j = min(max(int((u - u * u * u / 3.0) / dlon), 0), nc - 2)
            rho = math.sqrt(qx * qx + qy * qy)
            t = qz / (rho * (1.0 - E2))  # tan(lat) on the ellipsoid; ~e^2 h / a off above it
            w = (t - tan_row[0]) / (1.0 + t * tan_row[0])  # tan(lat - lat_n)
            fast = abs(w) < 0.5  # also False for NaN (on the axis)
        if fast:
            i = min(max(int(-(w - w * w * w / 3.0) / dlat), 0), nr - 2)
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
            la0, lo0 = latlon(qx, qy, qz)
            lo0 = _wrap(lo0, lon_w)
            fi = (lat_n - la0) / dlat
            fj = (lo0 - lon_w) / dlon
            i = int(math.floor(fi))
            j = int(math.floor(fj))
            # a start point on the last node line belongs to the last cell
            if i == nr - 1 and fi - i < 1e-9:
                i = nr - 2
            if j == nc - 1 and fj - j < 1e-9:
                j = nc - 2
        best = np.inf
        st = _LEFT
        came = -1  # boundary we entered through: 0 north, 1 south, 2 west, 3 east
        max_steps = 4 * (nr + nc) + 16  # a straight ray crosses each meridian/parallel at most twice
        fail_bi = -1
        fail_bj = -1
        while True:
            if ncell[r] > max_steps:
                st = _NOCONV
                break
            if i < 0 or i >= nr - 1 or j < 0 or j >= nc - 1:
                st = _LEFT
                break
            if s > send:
                st = _NOCONV if end_is_floor else _SKY
                break
            px = ox + s * dx
            py = oy + s * dy
            pz = oz + s * dz
            tiny = 1e-6
            bi = i // BLOCK
            bj = j // BLOCK
            if bi != fail_bi or bj != fail_bj:
                i0 = bi * BLOCK
                i1 = min(i0 + BLOCK, nr - 1)
                j0 = bj * BLOCK
                j1 = min(j0 + BLOCK, nc - 1)
                bx, bvia = _exit(px, py, pz, dx, dy, dz, tan_row[i0], c_row[i0], tan_row[i1], c_row[i1],
                                 sin_col[j0], cos_col[j0], sin_col[j1], cos_col[j1],
                                 tiny, tiny, tiny, tiny)
                ia = binv[bi, bj, 0]
                clear = False
                if bvia >= 0 and ia == ia:
                    ib = binv[bi, bj, 1]
                    sb2 = s + bx
                    qa = dxy2 * ia + dz2 * ib
                    qb = 2.0 * (oxd * ia + ozd * ib)
                    qc = oxy2 * ia + oz2 * ib - 1.0
                    sm = -qb / (2.0 * qa)
                    if sm < s:
                        sm = s
                    elif sm > sb2:
                        sm = sb2
                    clear = (qa * sm + qb) * sm + qc > 0.0 and sb2 < send
                if clear:
                    k = ncell[r]
                    if k < mtrace:
                        trace_s[r, k] = s / dn
                        trace_ij[r, k, 0] = i
                        trace_ij[r, k, 1] = j
                    ncell[r] = k + 1
                    s = s + bx
                    # only the coordinate along the boundary crossed is needed: the side of
                    # the block's inner meridian planes (or parallel cones) the point is on,
                    # read from the tables (no atan2, no geodetic latitude)
                    ii = i0
                    jj = j0
                    qx = ox + s * dx
                    qy = oy + s * dy
                    if bvia <= 1:
                        for m in range(j0 + 1, j1):
                            if cos_col[m] * qy - sin_col[m] * qx < 0.0:  # west of meridian m
                                break
                            jj = m
                    else:
                        qz = oz + s * dz
                        rho = math.sqrt(qx * qx + qy * qy)
                        for m in range(i0 + 1, i1):
                            if qz + c_row[m] - rho * tan_row[m] >= 0.0:  # north of parallel m
                                break
                            ii = m
                    geo_ok = False
                    if bvia == 0:
                        i = i0 - 1
                        j = jj
                        came = 1
                    elif bvia == 1:
                        i = i1
                        j = jj
                        came = 0
                    elif bvia == 2:
                        i = ii
                        j = j0 - 1
                        came = 3
                    else:
                        i = ii
                        j = j1
                        came = 2
                    continue
                fail_bi = bi
                fail_bj = bj
            # exit through the cell's four exact boundaries (after the block test: a
            # skipped block does not need it)
            ex, via = _exit(px, py, pz, dx, dy, dz, tan_row[i], c_row[i], tan_row[i + 1], c_row[i + 1],
                            sin_col[j], cos_col[j], sin_col[j + 1], cos_col[j + 1],
                            tiny if came == 0 else 0.0, tiny if came == 1 else 0.0,
                            -1.0 if came == 2 else 0.0, -1.0 if came == 3 else 0.0)
            if ex < 0.0:
                ex = 0.0
            s_b = s + ex
            if s_b > send:
                s_b = send if send > s else s
            k = ncell[r]
            if k < mtrace:
                trace_s[r, k] = s / dn
                trace_ij[r, k, 0] = i
                trace_ij[r, k, 1] = j
            ncell[r] = k + 1
            # cinv is NaN exactly where cmax is (no data): one table read instead of two
            ia = cinv[i, j, 0]
            if ia != ia:
                st = _NODATA
                break
            # skip test: min over [s, s_b] of F(s) = |P'(s)|^2 - 1 for the cell's inflated ellipsoid
            ib = cinv[i, j, 1]
            qa = dxy2 * ia + dz2 * ib
            qb = 2.0 * (oxd * ia + ozd * ib)
            qc = oxy2 * ia + oz2 * ib - 1.0
            sm = -qb / (2.0 * qa)
            if sm < s:
                sm = s
            elif sm > s_b:
                sm = s_b
            if (qa * sm + qb) * sm + qc <= 0.0:
                if triangles:
                    n0x = nodes[i, j, 0]  # the cell's nodes (i, j), (i+1, j), (i+1, j+1), then (i, j+1)
                    n0y = nodes[i, j, 1]
                    n0z = nodes[i, j, 2]
                    n1x = nodes[i + 1, j, 0]
                    n1y = nodes[i + 1, j, 1]
                    n1z = nodes[i + 1, j, 2]
                    n2x = nodes[i + 1, j + 1, 0]
                    n2y = nodes[i + 1, j + 1, 1]
                    n2z = nodes[i + 1, j + 1, 2]
                    t1 = _tri(ox, oy, oz, dx, dy, dz, n0x, n0y, n0z, n1x, n1y, n1z, n2x, n2y, n2z)
                    t2 = _tri(ox, oy, oz, dx, dy, dz, n0x, n0y, n0z, n2x, n2y, n2z,
                              nodes[i, j + 1, 0], nodes[i, j + 1, 1], nodes[i, j + 1, 2])
                    if t1 < best:
                        best = t1
                    if t2 < best:
                        best = t2
                    geo_ok = False
                else:
                    if not geo_ok:
                        lat, lon, h, nx, ny, nz = geodetic_up(px, py, pz)
                        lon = _wrap(lon, lon_w)
                        g = nx * dx + ny * dy + nz * dz
                    lat_b, lon_b, h_b, nx, ny, nz = geodetic_up(ox + s_b * dx, oy + s_b * dy, oz + s_b * dz)
                    lon_b = _wrap(lon_b, lon_w)
                    t1 = _bilinear_cell(ox, oy, oz, dx, dy, dz, s, s_b, lat, lon, h, g,
                                        lat_b, lon_b, h_b, hgt[i, j], hgt[i, j + 1], hgt[i + 1, j],
                                        hgt[i + 1, j + 1], i, j, lat_n, lon_w, dlat, dlon)
                    if t1 < best:
                        best = t1
                    lat = lat_b
                    lon = lon_b
                    h = h_b
                    g = nx * dx + ny * dy + nz * dz
                    geo_ok = True
            else:
                geo_ok = False
            if best <= s_b + 1e-9:
                st = _OK
                break
            if s_b >= send:
                st = _NOCONV if end_is_floor else _SKY
                break
            if via < 0 or ex == np.inf:
                st = _NOCONV if end_is_floor else _SKY
                break
            s = s_b
            if via == 0:
                i -= 1
                came = 1
            elif via == 1:
                i += 1
                came = 0
            elif via == 2:
                j -= 1
                came = 3
            else:
                j += 1
                came = 2
        if best < np.inf and st != _OK:
            # a triangle sliver found beyond the last cell: still the first hit on the mesh
            st = _OK
        status[r] = st
        if st == _OK:
            s_out[r] = best / dn  # in units of the given direction vector


def _renamed(fn, name):
    """A copy of ``fn`` under another name, so that its numba cache file is its own.

    numba names a cache file after the function's qualified name and line and keys
    its index by signature only, not by the ``parallel`` flag: two dispatchers of
    the same function share the file, and whichever compiled first was loaded by
    the other (the "parallel" walk ran the serial code, or the reverse).
    """
    f = types.FunctionType(fn.__code__, fn.__globals__, name, fn.__defaults__, fn.__closure__)
    f.__qualname__ = name
    return f


#: Serial walk (prange runs as range).
walk = njit(cache=True, error_model="numpy")(_walk)
#: The same walk over rays on all cores (numba threads); identical results.
walk_parallel = njit(cache=True, parallel=True, error_model="numpy")(_renamed(_walk, "_walk_parallel"))
