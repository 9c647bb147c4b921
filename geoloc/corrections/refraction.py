"""Atmospheric refraction of a line of sight: the ray bent through a spherically stratified atmosphere.

The correction is built as Orekit Rugged builds its own (``AtmosphericRefraction
.applyCorrection(position, los, rawIntersection, algorithm)``): the straight line of sight
is first met with the surface (the *raw hit*); :meth:`Refraction.correct` then returns
another straight line, the tangent of the bent ray where the bent ray reaches the raw
hit's height, and the caller meets that line with the same surface. Near the raw hit
the two agree to the ray's curvature (the tangent line is 3 cm off the bent ray 500 m of
terrain relief away at 70 degrees, 10 cm along the ground); the location pipeline
(:class:`geoloc.pipeline.Pipeline`) repeats the step at the new hit's height until the
height settles (the fixed point), and :meth:`Refraction.aim` inverts it (ground point -> the direction leaving the camera).

The model
---------
The atmosphere is spherically stratified about the centre of curvature of the Earth
below the ray's lower end (the raw hit; the camera instead when it looks up at the hit,
for the densest air is there): a sphere tangent to the ellipsoid at that point, with the radius of
curvature of the ellipsoid's normal section along the ray's azimuth there (Euler:
1/R_a = cos^2 a / M + sin^2 a / N). Heights on that sphere are the geodetic heights
near the hit to 1 mm within 60 km of it (its third-order departure from the ellipsoid).
In a spherically stratified medium a ray stays in one plane through the centre and
keeps Bouguer's invariant n r sin z = c (Snell's law in spherical form; e.g. Born &
Wolf, Principles of Optics, chapter 3, rays in a spherically stratified medium). The camera's direction is the
direction in the air at the platform, so c = n(h_p) c0 where c0 = r_p sin z_p is the
straight line's distance from the centre.

The ray's polar angle is alpha(r) = alpha_p + int c dr / (r sqrt(n^2 r^2 - c^2)). The
code integrates only its difference from the straight line's (which is closed form),
in the straight line's own coordinate w (signed distance along the line from its
foot, r^2 = w^2 + c0^2), where the integrand has no singularity and no cancellation:

    d(theta_bent - theta_straight)/dw = c0 (n_p^2 - n^2) / (S (n_p |w| + S)),
    S^2 = w^2 + (n^2 - 1) r^2 - (n_p^2 - 1) c0^2   (= n^2 r^2 - c^2)

Gauss-Legendre quadrature on panels whose ends are the layer boundaries of the
atmosphere (where n's slope jumps) gives the angle; the bent ray's zenith angle at
the hit follows from the invariant, sin z = c / (n r). Piecewise-constant layers
(Rugged's ``MultiLayerModel``: :class:`Layers`) are the same integral with n constant in
each panel: Snell's law at each interface, the ray straight in between.

The limb (a ray from orbit that misses the Earth): the refracted tangent radius solves
n(r_t) r_t = c (:meth:`Refraction.limb`); the tangent point's polar angle is the same
integral from r_t, substituting r = r_t + x^2 to remove the square-root singularity.

Accuracy
--------
Against an exact integration of the ray equation d/ds(n dx/ds) = grad n in ECEF, with n
a function of the *geodetic* height (the ellipsoidal stratification; scipy ``solve_ivp``,
DOP853, rtol 1e-12, written in ``tests/corrections/test_refraction.py``): the corrected ground point
is within 0.4 / 1.4 / 4.1 / 5.2 / 6.2 mm of it from 18 km at 30 / 45 / 60 / 70 / 80 degrees
off nadir (shifts of 1.3-387 m), within 3 mm from 700 km at 20-50 degrees, 28 mm of a
401 m shift for a look 1 degree up; the limb's refracted tangent height within 0.2 m.
Those millimetres are the trace's own reproducibility (its answer moves by 2-4 mm when
it is given the tabulated n instead of the exact profile). The quadrature itself (4
nodes a panel) is within 1e-6 of the shift of a 64-node one (the floor is the table's
linear interpolation). The model's own limits: the standard atmosphere is a yearly
mid-latitude mean (the real refraction differs by the weather: 1 % per 3 K or per 10 hPa at the ground, more near
the horizon), and the Earth's curvature is taken as that of the osculating sphere at
the hit (1 mm of height within 60 km of it). A long look up is anchored at the camera, where
the air that bends it is: the direction it leaves the air in is within 0.05-0.23 microradians
of the trace's (from sea level 2-3 degrees up to 100 km, 850-930 km away), but its *point* at
a far height is not held to millimetres there: 36-190 m off the trace at 430-930 km out and
30-100 km up (the osculating sphere's radius is then far from the ellipsoid's along the path).
Within 26 km of the camera it is millimetres (above).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from geoloc.corrections.atmosphere import CUT_M, LAYER_TOPS_M, STANDARD, StandardAtmosphere
from geoloc.geodesy import _nbgeo
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, geodetic_up, prange
from geoloc.geodesy.ellipsoid import A, E2, ecef_to_geodetic
from geoloc import status as _status_module
from geoloc.status import Status

#: The kernels' cache key: the WGS-84 constants and the sources of the modules whose code or
#: constants they compile in (geodetic_up, the status codes, this file).
KEY = dependency_key(_nbgeo, _status_module, sys.modules[__name__])

#: LLVM's fast-math flags that keep NaN and infinity semantics (no "nnan", "ninf": the kernel
#: tests its input for NaN): fused multiply-adds, reassociation, reciprocals, approximate
#: functions. The shifts move by below 1e-9 of themselves (tests/corrections/test_refraction.py holds the
#: model to the independent trace and to Rugged's figures).
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}

_OK = int(Status.OK)
_INVALID = int(Status.INVALID_INPUT)
_NOCONV = int(Status.NO_CONVERGENCE)

#: Gauss-Legendre nodes a panel of the ground-ray quadrature, and of the limb's (which
#: integrates the whole angle, not a small difference, so it takes more).
NODES = 4
LIMB_NODES = 24
_GL_X, _GL_W = np.polynomial.legendre.leggauss(NODES)
_GLL_X, _GLL_W = np.polynomial.legendre.leggauss(LIMB_NODES)


# ---------------------------------------------------------------------------------------------
# the refractivity profile the kernels read: a table (mode 0) or constant layers (mode 1)
# ---------------------------------------------------------------------------------------------
@cached_njit(KEY, inline="always", error_model="numpy")
def _eps(h, mode, h0, step, table, bottoms, values):
    """n - 1 at height h: linear in ``table`` (mode 0) or the value of the layer holding h (mode 1)."""
    if mode == 0:
        x = (h - h0) / step
        if not x > 0.0:  # NaN too: int(NaN) would index far outside the table
            return table[0]
        k = int(x)
        if k >= table.shape[0] - 1:
            return table[table.shape[0] - 1]
        f = x - k
        return table[k] * (1.0 - f) + table[k + 1] * f
    j = 0
    for i in range(bottoms.shape[0]):
        if h >= bottoms[i]:
            j = i
    return values[j]


@cached_njit(KEY, inline="always", error_model="numpy")
def _deps(h, mode, h0, step, table):
    """d(n - 1)/dh of the table's linear pieces (zero for constant layers)."""
    if mode != 0:
        return 0.0
    x = (h - h0) / step
    if not x > 0.0:  # NaN too
        return 0.0
    k = int(x)
    if k >= table.shape[0] - 1:
        return 0.0
    return (table[k + 1] - table[k]) / step


@cached_njit(KEY, inline="always", error_model="numpy")
def _dtheta(c0, q_lo, q_hi, R, eps_p, mode, h0, step, table, bottoms, values, bounds, top, gx, gw):
    """int_{q_lo}^{q_hi} c0 (n_p^2 - n^2) / (S (n_p q + S)) dq: bent minus straight polar angle.

    Panels end at the heights in ``bounds`` (ascending) that fall inside; above ``top`` the
    index is the top layer's, and where it equals the platform's the integrand is zero.
    """
    if q_hi <= q_lo:
        return 0.0
    r_lo = math.sqrt(q_lo * q_lo + c0 * c0)
    r_hi = math.sqrt(q_hi * q_hi + c0 * c0)
    h_lo = r_lo - R
    h_hi = r_hi - R
    eps_top = _eps(top + 1.0, mode, h0, step, table, bottoms, values)
    if h_hi > top and eps_top == eps_p:
        h_hi = top
        if h_hi <= h_lo:
            return 0.0
        r_hi = R + h_hi
        q_hi = math.sqrt(max(r_hi * r_hi - c0 * c0, 0.0))
    n_p = 1.0 + eps_p
    a_p = eps_p * (2.0 + eps_p) * c0 * c0
    total = 0.0
    qa = q_lo
    nb = bounds.shape[0]
    for j in range(nb + 1):
        if j < nb:
            hb = bounds[j]
            if hb <= h_lo:
                continue
            if hb >= h_hi:
                qb = q_hi
            else:
                rb = R + hb
                qb = math.sqrt(max(rb * rb - c0 * c0, 0.0))
        else:
            qb = q_hi
        if qb > qa:
            mid = 0.5 * (qa + qb)
            half = 0.5 * (qb - qa)
            s = 0.0
            for k in range(gx.shape[0]):
                q = mid + half * gx[k]
                r2 = q * q + c0 * c0
                e = _eps(math.sqrt(r2) - R, mode, h0, step, table, bottoms, values)
                S = math.sqrt(q * q + e * (2.0 + e) * r2 - a_p)
                s += gw[k] * (eps_p - e) * (2.0 + eps_p + e) / (S * (n_p * q + S))
            total += half * s
        qa = qb
        if qa >= q_hi:
            break
    return c0 * total


@cached_njit(KEY, inline="always", error_model="numpy")
def _radius_along(ux, uy, uz, dx, dy, dz):
    """Radius of curvature of the ellipsoid's normal section along d's azimuth where the ellipsoid's
    normal is u (Euler; sin(lat) = u_z)."""
    sl = uz
    w2 = 1.0 - E2 * sl * sl
    N = A / math.sqrt(w2)
    M = A * (1.0 - E2) / (w2 * math.sqrt(w2))
    du = dx * ux + dy * uy + dz * uz
    hx, hy, hz = dx - du * ux, dy - du * uy, dz - du * uz
    hh = hx * hx + hy * hy + hz * hz
    if hh <= 1e-30:
        return N
    # north = (-sin(lat) cos(lon), -sin(lat) sin(lon), cos(lat)); with up = (cos lat cos lon, ...):
    cl = math.sqrt(ux * ux + uy * uy)
    if cl <= 1e-15:
        return N
    nx, ny, nz = -uz * ux / cl, -uz * uy / cl, cl
    cn = (hx * nx + hy * ny + hz * nz) ** 2 / hh  # cos^2 of the azimuth
    return 1.0 / (cn / M + (1.0 - cn) / N)


@cached_njit(KEY, inline="always", error_model="numpy")
def _nan_row(out_org, out_hit, out_dir, out_llh, out_shift, i):
    for k in range(3):
        out_org[i, k] = math.nan
        out_hit[i, k] = math.nan
        out_dir[i, k] = math.nan
        out_llh[i, k] = math.nan
    out_shift[i, 0] = math.nan
    out_shift[i, 1] = math.nan


@cached_njit(KEY, error_model="numpy")
def _finite_rows(o, d, p, h, out):
    """out[i]: every coordinate of ray i finite (outside the fast-math kernel, which may fold the test)."""
    for i in range(o.shape[0]):
        out[i] = math.isfinite(
            o[i, 0] + o[i, 1] + o[i, 2] + d[i, 0] + d[i, 1] + d[i, 2] + p[i, 0] + p[i, 1] + p[i, 2] + h[i]
        )


@cached_njit(KEY, parallel=True, error_model="numpy", fastmath=FAST)
def _correct_kernel(
    o,
    d,
    p,
    at_h,
    finite,
    lat_in,
    lon_in,
    h_in,
    have_llh,
    mode,
    h0,
    step,
    table,
    bottoms,
    values,
    bounds,
    top,
    gx,
    gw,
    out_org,
    out_hit,
    out_dir,
    out_llh,
    out_shift,
    out_status,
):
    """Per ray: the bent ray's point and tangent at the sphere height ``at_h`` (see the module doc)."""
    n = o.shape[0]
    for i in prange(n):
        out_status[i] = _OK
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        bad = not finite[i] or dn == 0.0  # finite: tested outside (fast-math folds x - x to 0)
        if bad:
            out_status[i] = _INVALID
            _nan_row(out_org, out_hit, out_dir, out_llh, out_shift, i)
            continue
        dx, dy, dz = dx / dn, dy / dn, dz / dn
        # the sphere osculates the ellipsoid at the ray's lower end: the hit, or the camera when
        # it looks up at the hit (there the atmosphere the ray crosses is densest)
        if have_llh:
            lat, lon, hg = lat_in[i], lon_in[i], h_in[i]
            cl = math.cos(lat)
            rho_p = math.sqrt(px * px + py * py)  # cos and sin of the longitude from the point itself
            if rho_p > 0.0:
                ux, uy, uz = cl * px / rho_p, cl * py / rho_p, math.sin(lat)
            else:
                ux, uy, uz = cl * math.cos(lon), cl * math.sin(lon), math.sin(lat)
        else:
            lat, lon, hg, ux, uy, uz = geodetic_up(px, py, pz)
        ax, ay, az, ha = px, py, pz, hg
        at_hit = True
        if (ox - px) * ux + (oy - py) * uy + (oz - pz) * uz <= 0.0:  # the camera may be the lower end
            lat_o, lon_o, ho, uox, uoy, uoz = geodetic_up(ox, oy, oz)
            if ho < hg:
                ax, ay, az, ha, lat, ux, uy, uz = ox, oy, oz, ho, lat_o, uox, uoy, uoz
                at_hit = False
        R = _radius_along(ux, uy, uz, dx, dy, dz)
        cx, cy, cz = ax - (R + ha) * ux, ay - (R + ha) * uy, az - (R + ha) * uz
        ocx, ocy, ocz = ox - cx, oy - cy, oz - cz
        wp = ocx * dx + ocy * dy + ocz * dz
        fx, fy, fz = ocx - wp * dx, ocy - wp * dy, ocz - wp * dz
        c0 = math.sqrt(fx * fx + fy * fy + fz * fz)
        # the straight line's point at the sphere radius of at_h, on the side of the given point
        rg = R + at_h[i]
        wq = (px - cx) * dx + (py - cy) * dy + (pz - cz) * dz
        if rg < c0:
            out_status[i] = _NOCONV  # the line never reaches that height
            _nan_row(out_org, out_hit, out_dir, out_llh, out_shift, i)
            continue
        qg = math.sqrt(rg * rg - c0 * c0)
        wg = -qg if wq <= 0.0 else qg
        if -1e-9 * rg < wp < 0.0 and wg > 0.0:
            wp = 0.0  # a level look from the anchor itself: its foot, up to rounding
        rp = math.sqrt(wp * wp + c0 * c0)
        eps_p = _eps(rp - R, mode, h0, step, table, bottoms, values)
        if wg < wp or (wp < 0.0 < wg):
            # the height is behind the camera, or the line passes its lowest point on the way
            # (an upward look at terrain past the line's foot): not served
            out_status[i] = _NOCONV
            _nan_row(out_org, out_hit, out_dir, out_llh, out_shift, i)
            continue
        qp = abs(wp)
        dth = _dtheta(
            c0, min(qp, qg), max(qp, qg), R, eps_p, mode, h0, step, table, bottoms, values, bounds, top, gx, gw
        )
        if c0 > 0.0:
            e1x, e1y, e1z = fx / c0, fy / c0, fz / c0
        else:
            e1x, e1y, e1z = 0.0, 0.0, 0.0
        # the straight point's polar angle a_s (cos a_s = c0 / rg, sin a_s = wg / rg) turned by dth,
        # written with sin and cos of dth / 2 only, and without the cancellation of
        # cos(a_s + dth) - cos(a_s): cos dth - 1 = -2 sh^2, sin dth = 2 sh ch
        ca_s, sa_s = c0 / rg, wg / rg
        sh = math.sin(0.5 * dth)
        ch = math.cos(0.5 * dth)
        cm1 = -2.0 * sh * sh
        sd = 2.0 * sh * ch
        dcos = ca_s * cm1 - sa_s * sd
        dsin = sa_s * cm1 + ca_s * sd
        # the straight point at at_h and the bent one
        sx, sy, sz = cx + c0 * e1x + wg * dx, cy + c0 * e1y + wg * dy, cz + c0 * e1z + wg * dz
        mx, my, mz = rg * (dcos * e1x + dsin * dx), rg * (dcos * e1y + dsin * dy), rg * (dcos * e1z + dsin * dz)
        out_hit[i, 0], out_hit[i, 1], out_hit[i, 2] = sx + mx, sy + my, sz + mz
        out_shift[i, 0] = math.sqrt(mx * mx + my * my + mz * mz)
        # the bent ray's direction there: sin z = c / (n r), cos z = S / (n r)
        e_g = _eps(at_h[i], mode, h0, step, table, bottoms, values)
        n_g = 1.0 + e_g
        S_g = math.sqrt(max(qg * qg + e_g * (2.0 + e_g) * rg * rg - eps_p * (2.0 + eps_p) * c0 * c0, 0.0))
        sinz = (1.0 + eps_p) * c0 / (n_g * rg)
        cosz = S_g / (n_g * rg)
        if wg < 0.0:
            cosz = -cosz
        ca, sa = ca_s + dcos, sa_s + dsin  # cos and sin of the bent point's polar angle a_s + dth
        # e_r = ca e1 + sa d, e_t = -sa e1 + ca d
        out_dir[i, 0] = cosz * (ca * e1x + sa * dx) + sinz * (-sa * e1x + ca * dx)
        out_dir[i, 1] = cosz * (ca * e1y + sa * dy) + sinz * (-sa * e1y + ca * dy)
        out_dir[i, 2] = cosz * (ca * e1z + sa * dz) + sinz * (-sa * e1z + ca * dz)
        # the line's origin, backed off from the bent point by the raw slant range; the bent point's
        # geodetic coordinates
        back = math.sqrt((ox - px) ** 2 + (oy - py) ** 2 + (oz - pz) ** 2)
        for k in range(3):
            out_org[i, k] = out_hit[i, k] - back * out_dir[i, k]
        bx, by, bz = out_hit[i, 0], out_hit[i, 1], out_hit[i, 2]
        out_shift[i, 1] = math.sqrt((bx - ox) ** 2 + (by - oy) ** 2 + (bz - oz) ** 2)
        if at_hit:
            # the bent point lies at geodetic height at_h (to the sphere's third-order departure over
            # the shift, 1e-9 m), so its latitude is closed-form: tan(lat) = z / (rho (1 - e2 N / (N + h))),
            # N at the raw hit's latitude (the result moves by e2 h dN / (N + h)^2: 1e-11 rad for 400 m)
            sl = uz  # sin(lat) of the raw hit (the sphere's anchor: at_hit)
            Nr = A / math.sqrt(1.0 - E2 * sl * sl)
            rho = math.sqrt(bx * bx + by * by)
            out_llh[i, 0] = math.atan2(bz, rho * (1.0 - E2 * Nr / (Nr + at_h[i])))
            out_llh[i, 1] = math.atan2(by, bx)
            out_llh[i, 2] = at_h[i]
        else:
            lat_b, lon_b, h_b, _, _, _ = geodetic_up(bx, by, bz)
            out_llh[i, 0], out_llh[i, 1], out_llh[i, 2] = lat_b, lon_b, h_b


# ---------------------------------------------------------------------------------------------
# the limb
# ---------------------------------------------------------------------------------------------
@cached_njit(KEY, error_model="numpy")
def _limb_kernel(c0, rp, R, eps_p, mode, h0, step, table, bottoms, values, bounds, top, gx, gw, out):
    """Per ray: refracted tangent radius r_t (n(r_t) r_t = c) and the polar angle from r_t to r_p.

    ``out[i] = (r_t, angle from tangent to platform, status)``; the angle substitutes r = r_t + x^2.
    """
    for i in range(c0.shape[0]):
        c = (1.0 + eps_p[i]) * c0[i]
        Ri = R[i]
        # Newton on f(r) = r (1 + eps(r - R)) - c, from the straight tangent radius (f >= 0 there)
        r = c0[i]
        ok = False
        for _ in range(60):
            e = _eps(r - Ri, mode, h0, step, table, bottoms, values)
            f = r * (1.0 + e) - c
            df = 1.0 + e + r * _deps(r - Ri, mode, h0, step, table)
            if df <= 0.0:
                break  # ducting: n r not increasing
            dr = f / df
            r -= dr
            if abs(dr) < 1e-7:
                ok = True
                break
        if not ok:
            out[i, 0], out[i, 1], out[i, 2] = math.nan, math.nan, _NOCONV
            continue
        rt = r
        ct = rt * (1.0 + _eps(rt - Ri, mode, h0, step, table, bottoms, values))  # c, consistent with r_t
        r_cut = Ri + top
        r_up = min(rp[i], r_cut)
        # panels in x = sqrt(r - r_t): first the near-tangent ones, then the layer boundaries
        total = 0.0
        xa = 0.0
        x_end = math.sqrt(max(r_up - rt, 0.0))
        nb = bounds.shape[0]
        while xa < x_end:
            # next panel end above xa: 100 m, 1 km and 5 km above the tangent, then the layer tops
            nxt = r_up
            for cand in (rt + 100.0, rt + 1000.0, rt + 5000.0):
                if cand > rt + xa * xa + 1e-6 and cand < nxt:
                    nxt = cand
            for k in range(nb):
                rb = Ri + bounds[k]
                if rb > rt + xa * xa + 1e-6 and rb < nxt:
                    nxt = rb
            xb = math.sqrt(nxt - rt)
            mid = 0.5 * (xa + xb)
            half = 0.5 * (xb - xa)
            s = 0.0
            for k in range(gx.shape[0]):
                x = mid + half * gx[k]
                rr = rt + x * x
                e = _eps(rr - Ri, mode, h0, step, table, bottoms, values)
                # n r - c = x^2 + e rr - eps_t rt, no cancellation
                nrc = x * x + e * rr - (ct - rt)
                if nrc <= 0.0:
                    continue
                s += gw[k] * 2.0 * x * ct / (rr * math.sqrt(nrc * ((1.0 + e) * rr + ct)))
            total += half * s
            xa = xb
        if rp[i] > r_cut:  # above the atmosphere the ray is straight: closed form
            total += math.acos(min(ct / rp[i], 1.0)) - math.acos(min(ct / r_cut, 1.0))
        out[i, 0], out[i, 1], out[i, 2] = rt, total, _OK


# ---------------------------------------------------------------------------------------------
# the models
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Layers:
    """Constant-index layers, as Rugged's ``MultiLayerModel``: ``(lowest height [m], n)`` pairs.

    Layer k holds n_k from its lowest height up to the next layer's; the highest layer
    extends upwards and the lowest downwards. Rugged's built-in table is :data:`RUGGED_LAYERS`.
    """

    layers: tuple

    def __post_init__(self):
        rows = sorted((float(h), float(n)) for h, n in self.layers)
        if not rows:
            raise ValueError("Layers: layers must hold at least one (height_m, n) pair, got none")
        for h, n in rows:
            if not (np.isfinite(h) and np.isfinite(n) and 0.5 < n < 2.0):
                raise ValueError(f"Layers: each layer needs a finite height and 0.5 < n < 2, got ({h!r}, {n!r})")
        object.__setattr__(self, "layers", tuple(rows))

    def refractive_index(self, h_m: ArrayLike) -> np.ndarray:
        h = np.asarray(h_m, float)
        bottoms = np.array([r[0] for r in self.layers])
        values = np.array([r[1] for r in self.layers])
        j = np.clip(np.searchsorted(bottoms, h, side="right") - 1, 0, len(bottoms) - 1)
        return values[j]


#: The layers Rugged's ``MultiLayerModel(ellipsoid)`` builds in (its source,
#: ``org/orekit/rugged/refraction/MultiLayerModel.java``, Rugged 2.x): lowest height [m], n.
RUGGED_LAYERS = Layers(
    (
        (100000.0, 1.000000),
        (50000.0, 1.000000),
        (40000.0, 1.000001),
        (30000.0, 1.000004),
        (23000.0, 1.000012),
        (18000.0, 1.000028),
        (14000.0, 1.000052),
        (11000.0, 1.000083),
        (9000.0, 1.000106),
        (7000.0, 1.000134),
        (5000.0, 1.000167),
        (3000.0, 1.000206),
        (1000.0, 1.000252),
        (0.0, 1.000278),
        (-1000.0, 1.000306),
    )
)


@dataclass(frozen=True)
class RefractedLine:
    """The bent ray near the raw hit, as a straight line to meet the surface with.

    Attributes
    ----------
    origin_ecef : ndarray (..., 3)
        A point of the line, backed off from ``hit_ecef`` along it by the raw slant range
        (so that it is above the terrain, like the camera) [m].
    direction_ecef : ndarray (..., 3)
        Unit tangent of the bent ray at the height asked for.
    hit_ecef : ndarray (..., 3)
        The bent ray's point at that height [m]: on a surface of that constant height, the
        corrected ground point itself (no second intersection needed).
    lat, lon, h : ndarray (...)
        Its geodetic coordinates [rad, rad, m].
    shift_m : ndarray (...)
        Distance from the straight line's point at that height to the bent ray's [m].
    range_m : ndarray (...)
        Distance from ``origin`` (the camera) to the bent ray's point [m].
    status : ndarray (...) of uint8
        OK; INVALID_INPUT (NaN input); NO_CONVERGENCE where the line never reaches the
        height, the height lies behind the camera, or the line passes its lowest point
        before reaching it (looking up at terrain beyond the line's foot: not served).
    """

    origin_ecef: np.ndarray
    direction_ecef: np.ndarray
    hit_ecef: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    shift_m: np.ndarray
    status: np.ndarray
    range_m: np.ndarray


@dataclass(frozen=True)
class LimbRefraction:
    """A limb ray's straight and refracted tangent points.

    Attributes
    ----------
    tangent_h_m, refracted_tangent_h_m : ndarray (...)
        Geodetic height of the straight line's lowest point and of the bent ray's [m].
    tangent_ecef, refracted_tangent_ecef : ndarray (..., 3)
        The two tangent points [m].
    bending_rad : ndarray (...)
        How far the ray has turned between the platform and its tangent point (half of
        the whole bending of a ray that leaves the atmosphere again) [rad].
    status : ndarray (...) of uint8
        OK; HITS_EARTH where the bent ray meets the ellipsoid before its tangent point;
        INVALID_INPUT; NO_CONVERGENCE (a ducting layer).
    """

    tangent_h_m: np.ndarray
    refracted_tangent_h_m: np.ndarray
    tangent_ecef: np.ndarray
    refracted_tangent_ecef: np.ndarray
    bending_rad: np.ndarray
    status: np.ndarray


def _vecs(a, shape):
    a = np.asarray(a, float)
    full = shape + (3,)
    if a.shape != full or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(np.broadcast_to(a, full), dtype=float, order="C")
    return a.reshape(-1, 3)


def _scalars(a, shape):
    a = np.asarray(a, float)
    if a.shape != shape or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(np.broadcast_to(a, shape), dtype=float, order="C")
    return a.reshape(-1)


def _as_rays(*arrays):
    shape = np.broadcast_shapes(*(np.shape(a)[:-1] for a in arrays))
    return shape, [_vecs(a, shape) for a in arrays]


@dataclass(frozen=True)
class Refraction:
    """Atmospheric refraction through ``atmosphere`` (a :class:`StandardAtmosphere` or :class:`Layers`).

    Every method is vectorised over rays ``(..., 3)`` in ECEF and returns NaN plus a
    :class:`geoloc.status.Status` per ray rather than raising.
    """

    atmosphere: StandardAtmosphere | Layers = field(default=STANDARD)

    def _profile(self):
        atm = self.atmosphere
        if isinstance(atm, StandardAtmosphere):
            h0, step, table = atm.table()
            table = np.array(table)  # writable, as the kernels' one signature has it (44 kB)
            bounds = np.array(LAYER_TOPS_M[1:], dtype=float)
            empty = np.zeros(1)
            return 0, h0, step, table, empty, empty, bounds, float(CUT_M)
        if isinstance(atm, Layers):
            bottoms = np.array([r[0] for r in atm.layers])
            values = np.array([r[1] for r in atm.layers]) - 1.0
            bounds = bottoms[1:].copy() if len(bottoms) > 1 else np.array([bottoms[0]])
            return 1, 0.0, 1.0, np.zeros(2), bottoms, values, bounds, float(bottoms[-1])
        raise TypeError(f"Refraction: atmosphere must be a StandardAtmosphere or Layers, got {type(atm).__name__}")

    def refractive_index(self, h_m: ArrayLike) -> np.ndarray:
        """n at geometric height ``h_m`` as the ray tracer sees it (table interpolation or layers)."""
        atm = self.atmosphere
        if isinstance(atm, Layers):
            return atm.refractive_index(h_m)
        h0, step, table = atm.table()
        return 1.0 + np.interp(np.asarray(h_m, float), h0 + step * np.arange(table.size), table)

    def correct(
        self,
        origin: ArrayLike,
        direction: ArrayLike,
        hit: ArrayLike,
        at_h: ArrayLike | None = None,
        hit_llh: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
    ) -> RefractedLine:
        """The bent ray near a raw hit, as a line to meet the surface with (Rugged's ``applyCorrection``).

        Parameters
        ----------
        origin : array_like (..., 3)
            The camera (platform) position, ECEF [m].
        direction : array_like (..., 3)
            The direction leaving the camera, in the air at the platform (need not be unit).
        hit : array_like (..., 3)
            The straight line's raw hit with the surface, ECEF [m] (any point near the ray's
            end will do: it fixes the sphere of the stratification).
        at_h : array_like (...), optional
            Height at which to return the bent ray [m]; the raw hit's geodetic height by default.
        hit_llh : tuple of array_like (...), optional
            The raw hit's geodetic (lat, lon, h) [rad, rad, m] when the caller has them (a
            ``GroundPoint``): saves converting ``hit`` again.

        Returns
        -------
        RefractedLine
        """
        shape, (o, d, p) = _as_rays(origin, direction, hit)
        if hit_llh is not None:
            lat_in, lon_in, h_in = (_scalars(v, shape) for v in hit_llh)
        else:
            lat_in = lon_in = h_in = np.zeros(1)
        if at_h is None:
            h = h_in if hit_llh is not None else np.array(ecef_to_geodetic(p)[2], dtype=float, order="C")
        else:
            h = _scalars(at_h, shape)
        mode, h0, step, table, bottoms, values, bounds, top = self._profile()
        n = o.shape[0]
        org = np.empty((n, 3))
        hit_out = np.empty((n, 3))
        dir_out = np.empty((n, 3))
        out_llh = np.empty((n, 3))
        shift = np.empty((n, 2))  # the shift, and the range from the origin to the bent point
        status = np.empty(n, np.uint8)
        finite = np.empty(n, np.bool_)
        _finite_rows(o, d, p, h, finite)
        _correct_kernel(
            o,
            d,
            p,
            h,
            finite,
            lat_in,
            lon_in,
            h_in,
            hit_llh is not None,
            mode,
            h0,
            step,
            table,
            bottoms,
            values,
            bounds,
            top,
            _GL_X,
            _GL_W,
            org,
            hit_out,
            dir_out,
            out_llh,
            shift,
            status,
        )
        return RefractedLine(
            org.reshape(shape + (3,)),
            dir_out.reshape(shape + (3,)),
            hit_out.reshape(shape + (3,)),
            out_llh[:, 0].reshape(shape),
            out_llh[:, 1].reshape(shape),
            out_llh[:, 2].reshape(shape),
            shift[:, 0].reshape(shape),
            status.reshape(shape),
            shift[:, 1].reshape(shape),
        )

    def aim(
        self, origin: ArrayLike, ground: ArrayLike, max_iter: int = 8, tol_m: float = 1e-4
    ) -> tuple[np.ndarray, np.ndarray]:
        """The direction leaving the camera whose bent ray reaches ``ground``: the inverse of :meth:`correct`.

        A fixed point on the aim point: aim at A_k, trace the bent ray to the ground's
        height, move the aim point by the miss (A_{k+1} = A_k - (X_k - G)). The bent
        ray's miss changes with the aim point at a rate of the refraction's own
        gradient (1e-4), so each step gains about four digits.

        Returns
        -------
        (direction (..., 3) unit, status (...)): NO_CONVERGENCE where ``max_iter`` steps leave
        a miss above ``tol_m`` [m].
        """
        shape, (o, g) = _as_rays(origin, ground)
        hg = ecef_to_geodetic(g)[2]
        aimp = g.copy()
        status = np.zeros(len(o), np.uint8)
        miss = np.full(len(o), np.inf)
        for _ in range(max_iter):
            d = aimp - o
            line = self.correct(o, d, g, at_h=hg)
            err = line.hit_ecef - g
            miss = np.linalg.norm(err, axis=-1)
            status = line.status
            if np.all((miss < tol_m) | (status != Status.OK)):
                break
            aimp = aimp - np.where((status == Status.OK)[:, None], err, 0.0)
        d = aimp - o
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        status = np.where((status == Status.OK) & ~(miss < tol_m), np.uint8(Status.NO_CONVERGENCE), status)
        d = np.where((status == Status.OK)[:, None], d, np.nan)
        return d.reshape(shape + (3,)), status.astype(np.uint8).reshape(shape)

    def limb(self, origin: ArrayLike, direction: ArrayLike) -> LimbRefraction:
        """The straight and the refracted tangent points of limb rays (from orbit, missing the Earth).

        The straight tangent point is the line's lowest point above the ellipsoid
        (Newton on the geodetic height along the line); the sphere of the stratification
        osculates the ellipsoid there along the ray's azimuth. The refracted tangent
        radius solves n(r_t) r_t = n_p c0 (Newton), and the tangent point's polar angle
        integrates the ray from r_t up to the platform.
        """
        shape, (o, d) = _as_rays(origin, direction)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        n = len(o)
        # the straight line's lowest point: Newton on s for up(P(s)) . d = 0
        s = -np.sum(o * d, axis=-1)
        for _ in range(8):
            p = o + s[:, None] * d
            lat, lon, h = ecef_to_geodetic(p)
            up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
            g = np.sum(up * d, axis=-1)
            Rn = A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
            s = s - g * (Rn + h) * 0.99  # dg/ds ~ 1 / (radius); the factor keeps it from overshooting
        p = o + s[:, None] * d
        lat, lon, h_t = ecef_to_geodetic(p)
        up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
        sl = np.sin(lat)
        w2 = 1.0 - E2 * sl * sl
        N = A / np.sqrt(w2)
        M = A * (1.0 - E2) / (w2 * np.sqrt(w2))
        north = np.stack([-sl * np.cos(lon), -sl * np.sin(lon), np.cos(lat)], axis=-1)
        dh = d - np.sum(d * up, axis=-1, keepdims=True) * up
        cn = np.sum(dh * north, axis=-1) ** 2 / np.maximum(np.sum(dh * dh, axis=-1), 1e-300)
        R = 1.0 / (cn / M + (1.0 - cn) / N)
        C = p - (R + h_t)[:, None] * up
        oc = o - C
        wp = np.sum(oc * d, axis=-1)
        f = oc - wp[:, None] * d
        c0 = np.linalg.norm(f, axis=-1)
        e1 = f / c0[:, None]
        rp = np.sqrt(wp * wp + c0 * c0)
        mode, h0, step, table, bottoms, values, bounds, top = self._profile()
        eps_p = self.refractive_index(rp - R) - 1.0
        out = np.empty((n, 3))
        finite = np.isfinite(c0) & np.isfinite(rp) & (wp < 0)
        c0k = np.where(finite, c0, R)
        _limb_kernel(
            np.array(c0k, dtype=float),
            np.array(np.where(finite, rp, R + 1e6), dtype=float),
            np.array(R, dtype=float),
            np.array(np.where(finite, eps_p, 0.0), dtype=float),
            mode,
            h0,
            step,
            table,
            bottoms,
            values,
            bounds,
            top,
            _GLL_X,
            _GLL_W,
            out,
        )
        rt, ang, st = out[:, 0], out[:, 1], out[:, 2].astype(np.uint8)
        a_p = np.arctan2(wp, c0)
        a_t = a_p + ang
        pt = C + rt[:, None] * (np.cos(a_t)[:, None] * e1 + np.sin(a_t)[:, None] * d)
        h_rt = ecef_to_geodetic(pt)[2]
        st = np.where(finite, st, np.uint8(Status.INVALID_INPUT))
        # a line through the Earth has no tangent point above it (its lowest point is not found)
        inputs_ok = np.all(np.isfinite(o), axis=-1) & np.all(np.isfinite(d), axis=-1)
        through = inputs_ok & ~(h_t >= 0.0)
        st = np.where(through, np.uint8(Status.HITS_EARTH), st).astype(np.uint8)
        st = np.where((st == Status.OK) & (h_rt < 0.0), np.uint8(Status.HITS_EARTH), st).astype(np.uint8)
        st = np.where((st == Status.OK) & (h_t < 0.0), np.uint8(Status.HITS_EARTH), st).astype(np.uint8)
        good = st == Status.OK
        nan3 = np.full((n, 3), np.nan)
        return LimbRefraction(
            np.where(np.isfinite(c0), h_t, np.nan).reshape(shape),
            np.where(good, h_rt, np.nan).reshape(shape),
            np.where(np.isfinite(c0)[:, None], p, nan3).reshape(shape + (3,)),
            np.where(good[:, None], pt, nan3).reshape(shape + (3,)),
            np.where(good, a_t, np.nan).reshape(shape),
            st.reshape(shape),
        )


#: Refraction through the U.S. Standard Atmosphere 1976, visible light.
STANDARD_REFRACTION = Refraction()
