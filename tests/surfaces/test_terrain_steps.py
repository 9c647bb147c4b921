"""The DEM walk's steps (``geoloc.surfaces.terrain_numba``), each alone against an outside
oracle: pyproj's ECEF <-> geodetic conversion (EPSG:4978 / EPSG:4979, WGS 84), the roots of
the inflated ellipsoid's quadratic by numpy's polynomial roots, and the bilinear surface's
first hit by brentq on pyproj's heights. The walk as a whole is tested against trimesh and
embree in test_terrain_trimesh.py and test_terrain_hierarchy.py."""

import numpy as np
import pyproj
from scipy.optimize import brentq

from geoloc.surfaces import terrain_numba as tn

A = 6378137.0  # WGS 84, from its definition (not from the code under test)
F = 1.0 / 298.257223563
B = A * (1.0 - F)
LLA_TO_ECEF = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
ECEF_TO_LLA = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def _ecef(lat, lon, h):
    x, y, z = LLA_TO_ECEF.transform(np.asarray(lon), np.asarray(lat), np.asarray(h), radians=True)
    return np.stack([x, y, z], axis=-1)


def _lla(p):
    lon, lat, h = ECEF_TO_LLA.transform(p[..., 0], p[..., 1], p[..., 2], radians=True)
    return lat, lon, h


def test_ray_terms_closed_form():
    """The ray's products are the closed forms; ``east`` says that the longitude (numpy's
    atan2 of a point a metre along the ray) grows, ``dj`` the matching column step; a line in
    a meridian plane crosses no meridian (``along`` False)."""
    rng = np.random.default_rng(1)
    o = _ecef(rng.uniform(-1.2, 1.2, 200), rng.uniform(-3.0, 3.0, 200), rng.uniform(0.0, 9e3, 200))
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    for (ox, oy, oz), (dx, dy, dz) in zip(o, d):
        dxy2, dz2, oxd, ozd, oxy2, oz2, east, along, dj = tn._ray_terms(ox, oy, oz, dx, dy, dz)
        # the same products, so equal to the last bit but for a fused multiply-add (1 ulp)
        np.testing.assert_allclose(
            [dxy2, dz2, oxd, ozd, oxy2, oz2],
            [dx * dx + dy * dy, dz * dz, ox * dx + oy * dy, oz * dz, ox * ox + oy * oy, oz * oz],
            rtol=1e-15,
            atol=1e-9,
        )
        dlon = np.angle(np.exp(1j * (np.arctan2(oy + dy, ox + dx) - np.arctan2(oy, ox))))
        assert east == (dlon > 0.0) and along
        assert dj == (1 if dlon > 0.0 else -1)
    # a ray in the plane of the prime meridian (y = 0 exactly): no meridian crossed
    p = _ecef(0.5, 0.0, 100.0)
    assert not tn._ray_terms(p[0], 0.0, p[2], -1.0, 0.0, -0.5)[7]


def _grid():
    """A 1-degree grid of 1-arcsecond cells (SRTM's) at 33-34 deg N, 98-97 deg W."""
    dlat = dlon = np.radians(1.0 / 3600.0)
    lat_n = np.radians(34.0)
    lon_w = np.radians(-98.0)
    return lat_n, lon_w, dlat, dlon, 3601, 3601


def test_start_cell_against_pyproj():
    """The start cell of a point above the grid: by latitude and longitude it is the cell
    pyproj's coordinates fall in (points within 1e-3 cell of a cell side are left out: the
    one-step latitude is 1e-9 rad = 2e-4 cell off); the guess without atan2 is at most one
    cell off for heights to 9 km (its latitude is the ellipsoid's under the point, off by
    ~e^2 h / a sin(2 phi) / 2 = 4.5e-6 rad = 0.93 cell at 9 km) and refuses a point 0.6 rad
    east of the grid's west meridian, where the series for atan does not hold."""
    lat_n, lon_w, dlat, dlon, nr, nc = _grid()
    rng = np.random.default_rng(2)
    lat = lat_n - rng.uniform(0.0, 1.0, 2000) * (nr - 1) * dlat
    lon = lon_w + rng.uniform(0.0, 1.0, 2000) * (nc - 1) * dlon
    q = _ecef(lat, lon, rng.uniform(-400.0, 9e3, 2000))
    lat_p, lon_p, _ = _lla(q)
    fi = (lat_n - lat_p) / dlat
    fj = (lon_p - lon_w) / dlon
    sharp = (np.abs(fi - np.round(fi)) > 1e-3) & (np.abs(fj - np.round(fj)) > 1e-3)
    assert sharp.sum() > 1990
    tan_n = np.tan(lat_n)
    for k in np.flatnonzero(sharp):
        x, y, z = q[k]
        assert tn._start_cell_geodetic(x, y, z, lat_n, lon_w, dlat, dlon, nr, nc) == (
            int(np.floor(fi[k])),
            int(np.floor(fj[k])),
        )
        ok, i, j, rho = tn._start_guess(x, y, z, np.cos(lon_w), np.sin(lon_w), tan_n, dlat, dlon, nr, nc)
        assert ok
        assert abs(i - np.floor(fi[k])) <= 1 and abs(j - np.floor(fj[k])) <= 1
        assert abs(rho - np.hypot(x, y)) <= 1e-15 * rho  # 1 ulp: a fused multiply-add
    far = _ecef(lat_n - 0.01, lon_w + 0.6, 0.0)
    assert not tn._start_guess(*far, np.cos(lon_w), np.sin(lon_w), tan_n, dlat, dlon, nr, nc)[0]


def _inflated_F(o, d, H):
    """F(s) = |P'(s)|^2 - 1 of the ellipsoid (a+H, a+H, b+H) as polynomial coefficients."""
    ia = 1.0 / (A + H) ** 2
    ib = 1.0 / (B + H) ** 2
    w = np.array([ia, ia, ib])
    return ia, ib, np.array([np.sum(w * d * d), 2.0 * np.sum(w * o * d), np.sum(w * o * o) - 1.0])


def test_block_entry_against_the_ellipsoid_roots():
    """The block test on rays descending from 3-12 km through the ellipsoid inflated to H =
    0.5-2 km: ``clear`` iff F > 0 on 4001 points of [s, min(sx, send)] (and its roots by numpy
    are not in it), else, for a ray still outside at s, the walk moves to the near root of F
    (numpy's companion-matrix roots; 1e-4 m covers their error, ~1e-9 relative on roots of
    ~1e5 m, and the kernel's closed form's) or to ``sx`` if the block ends first."""
    rng = np.random.default_rng(4)
    n_clear = n_entered = 0
    for _ in range(400):
        lat, lon = rng.uniform(-1.3, 1.3), rng.uniform(-3.1, 3.1)
        H = rng.uniform(500.0, 2000.0)
        o = _ecef(lat, lon, H + rng.uniform(1000.0, 10_000.0))
        up = o / np.linalg.norm(o)
        d = -up * rng.uniform(0.05, 1.0) + rng.normal(size=3) * 0.5
        d /= np.linalg.norm(d)
        ia, ib, coef = _inflated_F(o, d, H)
        roots = np.roots(coef)
        real = np.sort(roots[np.abs(roots.imag) < 1e-9 * np.abs(roots)].real)
        s = rng.uniform(0.0, 1000.0)
        sx = s + rng.uniform(100.0, 60_000.0)
        send = s + rng.uniform(100.0, 60_000.0)
        e = min(sx, send)
        if np.any(np.abs(real[:, None] - [s, e]) < 1e-2):
            continue  # a root at a side: either answer is right
        terms = (
            d[0] ** 2 + d[1] ** 2,
            d[2] ** 2,
            o[0] * d[0] + o[1] * d[1],
            o[2] * d[2],
            o[0] ** 2 + o[1] ** 2,
            o[2] ** 2,
        )
        clear, s_new, entered = tn._block_entry(ia, ib, *terms, s, sx, send)
        grid = np.linspace(s, e, 4001)
        clear_ref = bool(np.all(np.polyval(coef, grid) > 0.0)) and not np.any((real > s) & (real < e))
        assert clear == clear_ref
        outside = np.polyval(coef, s) > 0.0
        if clear:
            n_clear += 1
            assert s_new == s and not entered
        elif outside and len(real) and real[0] > s:
            n_entered += 1
            assert entered
            assert abs(s_new - min(real[0], sx)) < 1e-4
        else:
            assert s_new == s and not entered
    assert n_clear > 50 and n_entered > 50
    # no data in the block (a NaN table entry): never clear, s kept
    assert tn._block_entry(np.nan, np.nan, *terms, s, sx, send) == (False, s, False)


def _bilinear_surface(lat, lon, z, lat_n, lon_w, dlat, dlon):
    u = (lon - lon_w) / dlon
    v = (lat_n - lat) / dlat
    z00, z10, z01, z11 = z
    return (1 - v) * ((1 - u) * z00 + u * z10) + v * ((1 - u) * z01 + u * z11)


def test_bilinear_step_against_brentq_on_pyproj():
    """One cell of 1e-4 rad (about 640 m) at 35 deg N with node heights 100-300 m, rays from
    1 km above it, 0-0.3 rad off the vertical: the step's first hit is brentq's root of
    h_ray(s) - bilinear(lat(s), lon(s)) on pyproj's coordinates (Newton stops at 1e-7 m;
    1e-6 m along the ray), and the state it hands the next cell (latitude, longitude,
    height and dh/ds at the cell's exit) is pyproj's (1e-12 rad, 1e-6 m; dh/ds by central
    differences of 1 m: 1e-6). Handed the state at s, it finds the same hit as computing it."""
    lat_n, lon_w, dlat, dlon = 0.61, 0.2, 1e-4, 1e-4
    z = (100.0, 300.0, 180.0, 240.0)  # (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)
    rng = np.random.default_rng(6)
    for _ in range(30):
        lat0 = lat_n - rng.uniform(0.3, 0.7) * dlat
        lon0 = lon_w + rng.uniform(0.3, 0.7) * dlon
        o = _ecef(lat0, lon0, 1000.0)
        up = o / np.linalg.norm(o)  # near the normal: within 0.2 deg
        d = -up + rng.normal(size=3) * 0.15
        d /= np.linalg.norm(d)

        def lla_at(s):
            return _lla(o + s * d)

        s_b = 950.0  # below the lowest node: the ray has hit by then if it stays in the cell
        lat_b, lon_b, h_b = lla_at(s_b)
        if not (0 < (lat_n - lat_b) / dlat < 1 and 0 < (lon_b - lon_w) / dlon < 1):
            continue
        t, la, lo, hh, g = tn._bilinear_step(
            *o, *d, 0.0, s_b, False, 0.0, 0.0, 0.0, 0.0, *z, 0, 0, lat_n, lon_w, dlat, dlon
        )
        assert abs(la - lat_b) < 1e-12 and abs(lo - lon_b) < 1e-12 and abs(hh - h_b) < 1e-6
        g_ref = (lla_at(s_b + 1.0)[2] - lla_at(s_b - 1.0)[2]) / 2.0
        assert abs(g - g_ref) < 1e-6

        def resid(s):
            la_s, lo_s, h_s = lla_at(s)
            return h_s - _bilinear_surface(la_s, lo_s, z, lat_n, lon_w, dlat, dlon)

        s_ref = brentq(resid, 0.0, s_b, xtol=1e-10)
        assert abs(t - s_ref) < 1e-6
        la0, lo0, h0 = lla_at(0.0)
        g0 = (lla_at(1.0)[2] - lla_at(-1.0)[2]) / 2.0
        t_kept = tn._bilinear_step(*o, *d, 0.0, s_b, True, la0, lo0, h0, g0, *z, 0, 0, lat_n, lon_w, dlat, dlon)[0]
        assert abs(t_kept - s_ref) < 1e-6
    # a ray that stays above the cell: no hit
    o = _ecef(lat_n - 0.5 * dlat, lon_w + 0.5 * dlon, 1000.0)
    east = np.array([-np.sin(lon_w), np.cos(lon_w), 0.0])
    t = tn._bilinear_step(*o, *east, 0.0, 30.0, False, 0.0, 0.0, 0.0, 0.0, *z, 0, 0, lat_n, lon_w, dlat, dlon)[0]
    assert t == np.inf


def test_hit_geodetic_against_pyproj():
    """A hit's latitude, longitude and height from the corner of its cell (a point within a
    cell of it) and, far from the corner (0.01 rad), by the closed form: pyproj's to 1e-12
    rad (6 micrometres) and 1e-6 m, far above both methods' rounding."""
    rng = np.random.default_rng(7)
    for far in (0.0, 0.01):
        lat0 = rng.uniform(-1.4, 1.4, 300)
        lon0 = rng.uniform(-3.1, 3.1, 300)
        lat = lat0 - rng.uniform(0.0, 1e-4, 300) - far
        lon = lon0 + rng.uniform(0.0, 1e-4, 300) + far
        p = _ecef(lat, lon, rng.uniform(-400.0, 9000.0, 300))
        lat_p, lon_p, h_p = _lla(p)
        for k in range(300):
            la, lo, hh = tn._hit_geodetic(
                *p[k], lat0[k], np.sin(lat0[k]), np.cos(lat0[k]), lon0[k], np.sin(lon0[k]), np.cos(lon0[k])
            )
            assert abs(la - lat_p[k]) < 1e-12
            assert abs(np.angle(np.exp(1j * (lo - lon_p[k])))) < 1e-12
            assert abs(hh - h_p[k]) < 1e-6
