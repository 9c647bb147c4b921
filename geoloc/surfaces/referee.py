"""A referee for one ray's first hit on a DEM's triangles, by a route independent of the walk.

When two solvers disagree on a ray (the exact walk of :mod:`geoloc.surfaces.terrain` and
trimesh/embree's ray cast, say), :func:`referee_first_hit` decides. It uses none of the
walk's tables or code:

- the triangles are :meth:`geoloc.surfaces.dem.DEM.mesh`'s: two per cell, split along the
  p00-p11 diagonal;
- their vertices come from pyproj (EPSG:4979 -> EPSG:4978, the WGS-84 geodetic to ECEF
  conversion of PROJ), not from :func:`geoloc.geodesy.ellipsoid.geodetic_to_ecef`;
- the ray-triangle test is Moller and Trumbore's (J. Graphics Tools 2(1):21-28, 1997) in
  ``numpy.longdouble``: 80-bit extended precision on x86-64 (64-bit mantissa, so 11 more
  bits than float64), plain float64 where the platform has no wider type;
- every triangle of a window of cells is tested, with no skipping.

It is slow (a few milliseconds a ray for a window of 20 x 20 cells): a tool for the rays
in question, not a solver. ``benchmarks/bench_terrain.py`` runs it on every ray where the
walk and embree land more than 1 mm apart, and ``tests/surfaces/test_terrain_trimesh.py`` holds the
walk to it (docs/terrain.md, "Where embree and the walk differ").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from geoloc.surfaces.dem import DEM

_LD = np.longdouble

#: Cells tested at a time by :func:`referee_first_hit`: a window is searched in bands of rows
#: of at most this many cells, so its memory stays bounded (~1 kB a cell in flight) however
#: large the window.
_BAND_CELLS = 100_000


@dataclass(frozen=True)
class RefereeHit:
    """One ray's first hit on a set of triangles, in extended precision.

    Attributes
    ----------
    range_m : float
        Distance from the ray's origin to the hit along the unit direction [m]; inf for none.
    inside_m : float
        In the triangle's plane [m]: > 0 inside, the distance from the hit to the line of
        its nearest edge; < 0 outside (:func:`referee_triangle`), minus the distance to the
        line of the edge the point lies furthest beyond. NaN for no hit.
    cell : tuple of int
        (row, column) of the hit's cell (its north-west node); (-1, -1) for none.
    nodes : tuple of (int, int)
        The triangle's three nodes (row, column), in :meth:`DEM.mesh`'s order.
    """

    range_m: float
    inside_m: float
    cell: tuple
    nodes: tuple


@lru_cache(maxsize=2)
def _transformer(src="EPSG:4979", dst="EPSG:4978"):
    """pyproj's WGS-84 geodetic -> ECEF (or back), made once: building one takes milliseconds,
    and a window's bands and every judged ray use it."""
    from pyproj import Transformer

    return Transformer.from_crs(src, dst, always_xy=True)


def _nodes_ecef(dem, rows, cols):
    """ECEF [m] of the nodes (rows, cols) by pyproj, in extended precision; NaN height stays NaN."""
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    g = dem.grid
    if dem.is_geographic:  # DEM.node_latlon_deg's numbers, for these nodes only
        lat = g.lat_north_deg - g.dlat_deg * rows
        lon = g.lon_west_deg + g.dlon_deg * cols
    else:
        lat_all, lon_all = dem.node_latlon_deg()
        lat, lon = lat_all[rows, cols], lon_all[rows, cols]
    h = np.asarray(g.values, float)[rows, cols]
    x, y, z = _transformer().transform(lon, lat, h)
    return np.stack([np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)], -1).astype(_LD)


def _unit_ray(origin_ecef, direction_ecef):
    o = np.asarray(origin_ecef, float).reshape(3).astype(_LD)
    d = np.asarray(direction_ecef, float).reshape(3).astype(_LD)
    n = np.sqrt(np.sum(d * d))
    if not (np.isfinite(n) and n > 0) or not np.all(np.isfinite(o)):
        raise ValueError(
            f"referee: the ray needs a finite origin and a non-zero direction, got origin "
            f"{np.asarray(origin_ecef).tolist()} and direction {np.asarray(direction_ecef).tolist()}"
        )
    return o, d / n


def _moller_trumbore(o, d, a, b, c):
    """Ray parameter t and signed in-plane distance to the nearest edge [m] for triangles (..., 3)."""
    e1 = b - a
    e2 = c - a
    pv = np.cross(d, e2)
    det = np.sum(e1 * pv, -1)
    tv = o - a
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.sum(tv * pv, -1) / det
        qv = np.cross(tv, e1)
        v = np.sum(d * qv, -1) / det
        t = np.sum(e2 * qv, -1) / det
        # barycentric weight of each vertex times that vertex's height over the opposite edge
        two_area = np.sqrt(np.sum(np.cross(e1, e2) ** 2, -1))
        w = np.stack([1 - u - v, u, v], -1)  # weights of a, b, c
        opp = np.stack(
            [np.sqrt(np.sum((c - b) ** 2, -1)), np.sqrt(np.sum((c - a) ** 2, -1)), np.sqrt(np.sum((b - a) ** 2, -1))],
            -1,
        )
        inside = np.min(w * (two_area[..., None] / opp), -1)
    return t, inside


def window_around(dem: DEM, points_ecef: ArrayLike, pad_cells: int = 3) -> tuple[int, int, int, int]:
    """The cells (row0, row1, col0, col1; half-open) spanning ``points_ecef`` (..., 3) plus
    ``pad_cells`` on each side, clipped to the grid. Latitude and longitude by pyproj."""
    if not dem.is_geographic:
        raise ValueError(f"referee: window_around needs a geographic grid, got CRS {dem.crs.name!r}")
    p = np.asarray(points_ecef, float).reshape(-1, 3)
    if not np.all(np.isfinite(p)):
        raise ValueError(f"referee: window_around needs finite points, got {p.tolist()}")
    lon, lat, _ = _transformer("EPSG:4978", "EPSG:4979").transform(p[:, 0], p[:, 1], p[:, 2])
    g = dem.grid
    nr, nc = dem.shape
    fi = (g.lat_north_deg - np.asarray(lat)) / g.dlat_deg
    fj = (np.asarray(lon) - g.lon_west_deg) / g.dlon_deg
    # at least one cell, even for points off the grid (cells 0 .. nr - 2 and 0 .. nc - 2)
    r0 = int(np.clip(np.floor(fi.min()) - pad_cells, 0, nr - 2))
    r1 = int(np.clip(np.floor(fi.max()) + pad_cells + 1, r0 + 1, nr - 1))
    c0 = int(np.clip(np.floor(fj.min()) - pad_cells, 0, nc - 2))
    c1 = int(np.clip(np.floor(fj.max()) + pad_cells + 1, c0 + 1, nc - 1))
    return r0, r1, c0, c1


def referee_first_hit(
    dem: DEM, origin_ecef: ArrayLike, direction_ecef: ArrayLike, window: tuple[int, int, int, int]
) -> RefereeHit:
    """The first hit of one ray on the triangles of the cells in ``window``.

    Parameters
    ----------
    dem : geoloc.surfaces.dem.DEM
        Heights ellipsoidal, as :meth:`DEM.mesh` uses them.
    origin_ecef, direction_ecef : array_like (3,)
        The ray [m]; the direction need not be a unit vector.
    window : tuple of int
        (row0, row1, col0, col1): cells i in [row0, row1), j in [col0, col1) (a cell is
        named by its north-west node), e.g. from :func:`window_around`.

    Returns
    -------
    RefereeHit
        ``range_m`` inf when no triangle of the window is hit. A hit exactly on an edge
        counts (``inside_m`` 0); of two triangles hit at the same range (a ray through
        their shared edge), either may be returned.

    Notes
    -----
    The window is searched in bands of rows of at most :data:`_BAND_CELLS` cells, so the
    memory stays bounded for any window; the time grows with its number of cells.
    """
    o, d = _unit_ray(origin_ecef, direction_ecef)
    r0, r1, c0, c1 = (int(x) for x in window)
    nr, nc = dem.shape
    if not (0 <= r0 < r1 <= nr - 1 and 0 <= c0 < c1 <= nc - 1):
        raise ValueError(f"referee: window must hold cells within the {nr - 1} x {nc - 1} grid of cells, got {window}")
    best = RefereeHit(np.inf, np.nan, (-1, -1), ())
    band = max(1, _BAND_CELLS // (c1 - c0))
    for b0 in range(r0, r1, band):  # rows of cells [b0, b1): nodes b0 .. b1
        b1 = min(b0 + band, r1)
        rows, cols = np.meshgrid(np.arange(b0, b1 + 1), np.arange(c0, c1 + 1), indexing="ij")
        P = _nodes_ecef(dem, rows, cols)
        p00, p10, p01, p11 = P[:-1, :-1], P[:-1, 1:], P[1:, :-1], P[1:, 1:]  # 10: east, 01: south
        for k, (a, b, c) in enumerate(((p00, p01, p11), (p00, p11, p10))):
            t, inside = _moller_trumbore(o, d, a, b, c)
            ok = np.isfinite(t) & (t > 0) & (inside >= 0)
            if not ok.any():
                continue
            flat = np.where(ok, t, np.inf).ravel()
            m = int(np.argmin(flat))
            if flat[m] < best.range_m:
                i, j = divmod(m, c1 - c0)
                i += b0
                j += c0
                nodes = ((i, j), (i + 1, j), (i + 1, j + 1)) if k == 0 else ((i, j), (i + 1, j + 1), (i, j + 1))
                best = RefereeHit(float(flat[m]), float(inside.ravel()[m]), (i, j), nodes)
    return best


def referee_triangle(
    dem: DEM, origin_ecef: ArrayLike, direction_ecef: ArrayLike, nodes: Sequence[tuple[int, int]]
) -> RefereeHit:
    """Where one ray meets the plane of one triangle (three (row, column) nodes), and by how
    much it is inside (``inside_m`` > 0) or outside (< 0) the triangle there."""
    o, d = _unit_ray(origin_ecef, direction_ecef)
    nodes = tuple((int(r), int(c)) for r, c in nodes)
    if len(nodes) != 3:
        raise ValueError(f"referee: a triangle has three nodes, got {nodes}")
    rows, cols = np.array(nodes).T
    P = _nodes_ecef(dem, rows, cols)
    t, inside = _moller_trumbore(o, d, P[0], P[1], P[2])
    cell = (min(rows), min(cols))
    return RefereeHit(float(t), float(inside), cell, nodes)


def judge(
    dem: DEM,
    origin_ecef: ArrayLike,
    direction_ecef: ArrayLike,
    hit_a_ecef: ArrayLike,
    hit_b_ecef: ArrayLike,
    pad_cells: int = 3,
    tol_m: float = 1e-6,
) -> tuple[str, RefereeHit]:
    """Which of two solvers' first hits of one ray the referee finds: ``"a"``, ``"b"``,
    ``"both"`` (within ``tol_m`` of each other and of the referee) or ``"neither"``.

    The referee searches every triangle of the cells around both hits (:func:`window_around`,
    ``pad_cells`` more each side). A hit of NaN (no hit) is judged right when the referee
    finds none in that window. ``tol_m`` [m]: 1e-6 by default. pyproj's and geoloc's ECEF
    conversions agree to rounding (``tests/geodesy/test_ellipsoid.py``), so what is left is a
    solver's float64 rounding of its hit: 7e-8 m measured for the walk against trimesh's
    recomputation on the SRTM crop, and more for a hit met at a shallow angle to its
    triangle; 1e-6 m leaves a factor of ten for that.

    Returns
    -------
    verdict : str
    ref : RefereeHit
    """
    o, d = _unit_ray(origin_ecef, direction_ecef)
    pts = [np.asarray(p, float).reshape(3) for p in (hit_a_ecef, hit_b_ecef)]
    finite = [p for p in pts if np.all(np.isfinite(p))]
    if not finite:
        raise ValueError("referee: judge needs at least one of the two hits")
    ref = referee_first_hit(dem, origin_ecef, direction_ecef, window_around(dem, finite, pad_cells))

    def agrees(p):
        if not np.all(np.isfinite(p)):
            return not np.isfinite(ref.range_m)
        return bool(
            np.isfinite(ref.range_m) and np.sqrt(np.sum((o + _LD(ref.range_m) * d - p.astype(_LD)) ** 2)) <= tol_m
        )

    a, b = agrees(pts[0]), agrees(pts[1])
    return ("both" if a and b else "a" if a else "b" if b else "neither"), ref
