"""Line of sight x DEM: three solvers behind one interface (docs/method.md section 4).

* ``"steps"``: the descending steps of [Q17 section 2.3]: H_0 = H_max (the
  highest DEM node), locate the target on the ellipsoid inflated to H_n
  [Q17 eq. 10-11], read the DEM height h_n there, and while H_n - h_n > 0 set
  H_(n+1) = H_n - eps_h. The answer is the point at the first H_n below the
  terrain; its height is within eps_h of the crossing.
* ``"bisect"``: the halving search of [L23] on the target height between the
  DEM's lowest and highest nodes: at the midpoint H compare H with the DEM
  height under the line of sight, keep the half holding the sign change, stop
  when |H - h| < threshold. At grazing angles it can return a crossing hidden
  behind a ridge: ``TerrainHit.hidden`` flags those rays.
* ``"exact"``: walk the DEM cells under the ray (exact cell boundaries, see
  :mod:`geoloc.surfaces.terrain_numba`) from the height H_max down, skip cells whose
  highest node is below a rigorous lower bound of the ray's height there, and
  solve the cell's surface: the bilinear patch (root of the exact residual,
  polished to 1e-7 m along the ray) or two planar triangles (Moller-Trumbore,
  the same mesh as :meth:`geoloc.surfaces.dem.DEM.to_trimesh`). No threshold.

Conventions: ``docs/conventions.md``. Batch functions return NaN and a
:class:`geoloc.status.Status` per ray, never raise for a bad ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import E2, A, B, ecef_to_geodetic, prime_vertical_radius
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight, MosaicSource, Surface, is_mosaic
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import ray_inflated_ellipsoid

if TYPE_CHECKING:  # numba's import is a start-up cost the walk's first call pays, not this module's
    from geoloc.surfaces.terrain_numba import WalkGrid

METHODS = ("steps", "bisect", "exact")
#: Status codes as plain ints for the comparisons over whole batches: numpy compares an array with
#: an IntEnum member by way of the enum's attribute lookups (7 us a call against 1 us with an int;
#: 0.21 against 0.08 ms right after a walk of the crop's 10 000 rays, load 13).
_OK = int(Status.OK)
_BELOW_TERRAIN = int(Status.BELOW_TERRAIN)
#: How the exact solver reads between DEM nodes (``dem_model``; never called a "surface").
DEM_MODELS = ("bilinear", "triangles")
#: Margin [m] above H_max / below H_min where the exact walk starts / ends: the
#: inflated ellipsoid of [Q17 eq. 11] departs from the constant-height surface
#: by millimetres at these heights (geoloc.surfaces.height), far below 1 m.
_MARGIN_M = 1.0


@dataclass(frozen=True)
class TerrainTrace:
    """Iterations of a DEM solver, padded with NaN to the longest ray.

    Attributes (``batch`` is the shape of the line-of-sight batch, ``m`` the
    longest iteration count)
    ----------
    H : ndarray (batch + (m,))
        Trial height H_n [m] (steps, bisection), or the ray's height where it
        enters each visited cell (exact).
    lat, lon : ndarray (batch + (m,))
        Ground point on the line of sight at H_n [rad].
    ecef : ndarray (batch + (m, 3))
        The same point in ECEF [m].
    h_dem : ndarray (batch + (m,))
        DEM height h_n under that point [m].
    lo, hi : ndarray (batch + (m,))
        Bisection bracket [m] before each step (NaN for the other methods).
    cell : ndarray (batch + (m, 2)) of int
        Exact solver: (row, col) of each visited cell; -1 otherwise.
    count : ndarray (batch) of int
        Number of valid entries per ray.
    """

    method: str
    H: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    ecef: np.ndarray
    h_dem: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    cell: np.ndarray
    count: np.ndarray

    def ray(self, index: Any = ()) -> dict[str, np.ndarray]:
        """The trace of one ray as a dict of 1-D arrays (``index`` into the batch)."""
        n = int(np.asarray(self.count)[index])
        out = {}
        for k in ("H", "lat", "lon", "ecef", "h_dem", "lo", "hi", "cell"):
            out[k] = np.asarray(getattr(self, k))[index][:n]
        return out


@dataclass(frozen=True)
class TerrainHit(GroundPoint):
    """Result of :func:`intersect_dem`: a :class:`GroundPoint` (the one hit type) with the DEM's extras.

    Attributes
    ----------
    lat, lon, h, ecef, slant_range, status, los
        As :class:`geoloc.surfaces.base.GroundPoint`; status OK, SKY, LEFT_DEM,
        NODATA, ORIGIN_BELOW, BELOW_TERRAIN (the camera under the terrain),
        INVALID_INPUT, NO_CONVERGENCE, OUTSIDE_SENSOR.
    dem_evaluations : ndarray of int
        DEM reads: heights evaluated (steps, bisection) or cells visited (exact).
    hidden : ndarray of bool
        Bisection only: the answer is not the first visible crossing (the
        line of sight meets the terrain earlier and comes out again).
    method, dem_model : str
    trace : TerrainTrace or None
    """

    # keyword-only: every hit has them, and they follow the base class's fields that have defaults
    dem_evaluations: np.ndarray = field(kw_only=True)
    hidden: np.ndarray = field(kw_only=True)
    method: str = ""
    dem_model: str = ""
    trace: TerrainTrace | None = None

    @property
    def surface(self) -> str:
        """The first-phase name of :attr:`dem_model`."""
        return self.dem_model


# --------------------------------------------------------------------------- helpers
def _flat_los(los: LineOfSight, normalise: bool = True):
    o = np.asarray(los.origin_ecef, float)
    d = np.asarray(los.direction_ecef, float)
    st = np.asarray(los.status, np.uint8)
    shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1], st.shape)
    # broadcast only what needs it (a 1-ray call spent a fifth of its time here)
    o = np.ascontiguousarray((o if o.shape[:-1] == shape else np.broadcast_to(o, shape + (3,))).reshape(-1, 3))
    d = np.ascontiguousarray((d if d.shape[:-1] == shape else np.broadcast_to(d, shape + (3,))).reshape(-1, 3))
    st = (st if st.shape == shape else np.broadcast_to(st, shape)).reshape(-1).copy()
    if normalise:  # the exact kernel normalises and checks each ray itself
        with np.errstate(invalid="ignore", divide="ignore"):
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        bad = ~(np.all(np.isfinite(o), axis=-1) & np.all(np.isfinite(d), axis=-1))
        st[bad & (st == Status.OK)] = Status.INVALID_INPUT
    return shape, o, d, st


def _ground(dem: DEM, p):
    lat, lon, h = ecef_to_geodetic(p)
    hd, st = dem.sample(lat, lon)
    return lat, lon, h, hd, st


#: Highest |h_max| [m] up to which :func:`below_terrain` tests the origins against the
#: ellipsoid inflated to the DEM's highest node first (the height-h surface leaves that
#: ellipsoid by 0.14 m at 100 km, within the 1 m margin; about 1 m at 270 km).
ABOVE_TEST_MAX_M = 100_000.0


def below_terrain(o: np.ndarray, st: np.ndarray, dem: DEM | MosaicSource, h_max: float | None = None) -> None:
    """Set BELOW_TERRAIN (in place, in ``st``) for the rays still OK whose origin ``o`` (ECEF, (n, 3))
    is below the DEM's height under it. ``h_max``: the DEM's highest node [m] when known
    (:meth:`DEM.max_height` otherwise, a scan of every node of a DEM that is not a window).

    Such a ray meets the terrain at its origin: the walk answered the camera's own position
    with a slant range of 0 m and status OK, a hit no one can use. Where the DEM has no height under the
    camera (outside it, no data) nothing is said here: the solver's own status stands.
    """
    ok = st == _OK
    if h_max is None:
        if not ok.any():  # nothing to test: no scan of the DEM for its highest node
            return
        h_max = dem.max_height()
    if abs(h_max) < ABOVE_TEST_MAX_M:
        # an origin outside the ellipsoid inflated to the highest node plus the margin,
        # (a + H, b + H) [Q17 eq. 11], is above every height of the DEM: the surface of
        # geodetic height h_max lies inside it (it bulges out of (a + h, b + h) by at most
        # 1.3 cm at h = 9 km and 0.14 m at 100 km, less than the 1 m margin). Those origins
        # are neither converted nor sampled (this test was a third of a 10 000-ray walk's
        # CPU time on the bundled crop); NaN origins fail the test and are sampled. Tested on
        # every origin, not gathered first: a gather of the rows still OK was 0.1 ms a
        # 10 000-ray call, more than the test itself (the whole function 0.37 against 0.67 ms
        # with the caches flushed before it, load 16).
        ia = 1.0 / (A + h_max + _MARGIN_M) ** 2
        ib = 1.0 / (B + h_max + _MARGIN_M) ** 2
        with np.errstate(invalid="ignore"):
            ok &= ~((o[:, 0] * o[:, 0] + o[:, 1] * o[:, 1]) * ia + o[:, 2] * o[:, 2] * ib > 1.0)
    ok = np.flatnonzero(ok)
    if ok.size == 0:
        return
    lat, lon, h = ecef_to_geodetic(o[ok])
    hd, sst = dem.sample(lat, lon)
    with np.errstate(invalid="ignore"):
        st[ok[(sst == _OK) & (h < hd)]] = _BELOW_TERRAIN


def _top_height(o, dem: DEM):
    """H_0: the DEM's highest node, or just below the camera if it flies lower."""
    h_cam = ecef_to_geodetic(o)[2]
    return np.minimum(dem.max_height(), h_cam - 1e-3)


class _Tracer:
    def __init__(self, n, on):
        self.on = on
        self.rows = []  # (idx, H, lat, lon, ecef, h_dem, lo, hi)

    def add(self, idx, H, lat, lon, ecef, hd, lo=None, hi=None):
        if self.on:
            nan = np.full(len(idx), np.nan)
            self.rows.append((idx, H, lat, lon, ecef, hd, nan if lo is None else lo, nan if hi is None else hi))

    def build(self, method, n, shape, count):
        if not self.on:
            return None
        m = int(count.max()) if count.size else 0
        H, lat, lon, hd, lo, hi = (np.full((n, m), np.nan) for _ in range(6))
        ecef = np.full((n, m, 3), np.nan)
        k = np.zeros(n, dtype=int)
        for idx, *vals in self.rows:
            kk = k[idx]
            for arr, v in zip((H, lat, lon, ecef, hd, lo, hi), vals):
                arr[idx, kk] = v
            k[idx] += 1
        cell = np.full((n, m, 2), -1, dtype=np.int64)
        r = lambda a, extra=(): a.reshape(shape + (m,) + extra)  # noqa: E731
        return TerrainTrace(
            method, r(H), r(lat), r(lon), r(ecef, (3,)), r(hd), r(lo), r(hi), r(cell, (2,)), count.reshape(shape)
        )


# --------------------------------------------------------------------------- steps [Q17]
#: Bound of the descending steps of one call (without ``max_iter``): the Earth's relief, from the
#: Challenger Deep (-10 935 m) to Everest (8 849 m), at the default 1 m step is 19 784 steps; a
#: smaller ``eps_h`` that would need more stops there with NO_CONVERGENCE instead of iterating
#: for hours (``--eps-h 1e-7`` over 600 m of relief is 6e9 steps).
STEPS_MAX = 20_000


def _steps(o, d, st, dem, eps_h, tracer, max_iter):
    n = len(o)
    H = _top_height(o, dem)
    out = np.full((n, 3), np.nan)
    evals = np.zeros(n, dtype=np.int64)
    active = st == Status.OK
    n_max = max_iter or min(int(np.ceil((dem.max_height() - dem.min_height()) / eps_h)) + 3, STEPS_MAX)
    for _ in range(n_max):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        hit = ray_inflated_ellipsoid(o[idx], d[idx], H[idx])  # [Q17 eq. 10-11]
        lat, lon, hr, hd, sst = _ground(dem, hit.ecef)
        evals[idx] += hit.status == Status.OK
        tracer.add(idx, H[idx], lat, lon, hit.ecef, hd)
        bad = hit.status != Status.OK
        sst = np.where(bad, hit.status, sst)
        stop_bad = sst != Status.OK
        st[idx[stop_bad]] = sst[stop_bad]
        below = ~stop_bad & (H[idx] - hd <= 0.0)
        out[idx[below]] = hit.ecef[below]
        active[idx[stop_bad | below]] = False
        H[idx] -= eps_h
    st[active] = Status.NO_CONVERGENCE
    return out, evals


# --------------------------------------------------------------------------- bisection [L23]
def _bisect(o, d, st, dem, threshold, tracer, max_iter):
    n = len(o)
    hi = _top_height(o, dem)
    lo = np.full(n, dem.min_height())
    out = np.full((n, 3), np.nan)
    evals = np.zeros(n, dtype=np.int64)
    active = st == Status.OK
    for _ in range(max_iter or 64):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        mid = 0.5 * (lo[idx] + hi[idx])
        hit = ray_inflated_ellipsoid(o[idx], d[idx], mid)  # [Q17 eq. 10-11] at the midpoint
        lat, lon, hr, hd, sst = _ground(dem, hit.ecef)
        evals[idx] += hit.status == Status.OK
        tracer.add(idx, mid, lat, lon, hit.ecef, hd, lo[idx].copy(), hi[idx].copy())
        sst = np.where(hit.status != Status.OK, hit.status, sst)
        stop_bad = sst != Status.OK
        st[idx[stop_bad]] = sst[stop_bad]
        diff = mid - hd
        done = ~stop_bad & (np.abs(diff) < threshold)
        out[idx[done]] = hit.ecef[done]
        above = ~stop_bad & ~done & (diff > 0)
        below = ~stop_bad & ~done & (diff <= 0)
        hi[idx[above]] = mid[above]
        lo[idx[below]] = mid[below]
        active[idx[stop_bad | done]] = False
    st[active] = Status.NO_CONVERGENCE
    return out, evals


def _hidden(o, d, s_bis, s_first, dem, ok):
    """True where the ray comes back above the terrain between the first crossing and s_bis.

    Samples every quarter of the smallest DEM cell along the ray (an emergence
    narrower than that is not seen).
    """
    hidden = np.zeros(len(o), dtype=bool)
    cand = np.flatnonzero(ok & np.isfinite(s_first) & (s_bis > s_first))
    if cand.size == 0:
        return hidden
    g = dem.grid
    cell_m = min(g.dlat_deg, g.dlon_deg) * (np.pi / 180 * A if dem.is_geographic else 1.0)
    if dem.is_geographic:
        cell_m *= np.cos(np.deg2rad(max(abs(g.lat_north_deg), abs(g.lat_south_deg))))
    step = max(cell_m / 4.0, 0.01)
    for r in cand:
        ns = int(min(np.ceil((s_bis[r] - s_first[r]) / step), 20000))
        s = np.linspace(s_first[r], s_bis[r], ns + 1)[1:-1]
        if s.size == 0:
            continue
        p = o[r] + s[:, None] * d[r]
        lat, lon, h = ecef_to_geodetic(p)
        hd = dem.height(lat, lon)
        hidden[r] = bool(np.any(h - hd > 0.0))
    return hidden


# --------------------------------------------------------------------------- exact
def _floor_inv(h_floor):
    """(1/(a+h_floor)^2, 1/(b+h_floor)^2): the reference the walk's offset tables are taken
    from (:func:`_offsets32`), computed as the kernel computes its ``ia_floor``, ``ib_floor``."""
    return np.array([1.0 / ((A + h_floor) * (A + h_floor)), 1.0 / ((B + h_floor) * (B + h_floor))])


def _offsets32(inv64, h_floor):
    """The walk's form of a table of (1/(a+H)^2, 1/(b+H)^2) (``inv64``, overwritten): float32
    offsets from the floor's (1/(a+h_floor)^2, 1/(b+h_floor)^2), which the kernel adds back
    in float64 (its ``ia_floor``, ``ib_floor``, from :func:`geoloc.surfaces.terrain_numba.walk`'s
    ``h_floor``: the tables are made for the floor they are walked with).

    float32 halves the table (100 MB instead of 200 on 3601 x 3601 nodes; its loads are
    the walk's largest stall), and an offset keeps float32's relative precision on
    H - h_floor: 2.4e-4 m at most on a 1 km range, where float32 of 1/(a+H)^2 itself lost
    up to 0.4 m (a looser skip test: more cells tested for nothing). Rounded down, then
    one float32 step further, i.e. to a slightly larger ellipsoid (by up to two steps,
    2.4e-7 (H - h_floor)); that step is far above the float64 rounding of the kernel's sum
    (~1e-16 relative), so a skipped cell or block is clear of the terrain and the hits do
    not change. NaN (no data) stays NaN.
    """
    off = np.subtract(inv64, _floor_inv(h_floor), out=inv64)  # in place, and compared without a float64 copy
    off32 = np.ascontiguousarray(off, dtype=np.float32)  # of off32: 200 MB less at the peak
    up = off32 > off
    off32[up] = np.nextafter(off32[up], np.float32(-np.inf))
    np.nextafter(off32, np.float32(-np.inf), out=off32)
    return off32


def _exact_tables(dem: DEM):
    tab = getattr(dem, "_exact_tables", None)
    if tab is not None:
        return tab
    if not dem.is_geographic:
        raise ValueError(
            f"method 'exact' needs a geographic (lat/lon) grid, got CRS {dem.crs.name!r}: "
            "use dem.to_geographic() (DEM.open does it for a file unless "
            "geographic=False), or the 'steps' / 'bisect' methods"
        )
    g = dem.grid
    hgt = np.ascontiguousarray(g.values, dtype=float)
    nr = hgt.shape[0]
    lat_n = np.deg2rad(g.lat_north_deg)
    lon_w = np.deg2rad(g.lon_west_deg)
    dlat = np.deg2rad(g.dlat_deg)
    dlon = np.deg2rad(g.dlon_deg)
    # node latitudes and longitudes as DEM.mesh has them: the cell boundaries below and
    # the triangle nodes of the kernel (geodetic_to_ecef's operations on these tables
    # give the mesh's vertices) come from the same numbers
    lat_deg, lon_deg = dem.node_latlon_deg()
    lat_rows, lon_cols = np.deg2rad(lat_deg[:, 0]), np.deg2rad(lon_deg[0, :])
    rn = prime_vertical_radius(lat_rows)
    sin_lat = np.sin(lat_rows)
    row_geo = np.ascontiguousarray(np.stack([rn, np.cos(lat_rows), rn * (1.0 - E2), sin_lat, lat_rows], -1))
    # parallel of geodetic latitude phi: z + R_N e^2 sin(phi) = rho tan(phi)
    tan_row = np.tan(lat_rows)
    c_row = rn * E2 * sin_lat
    cmax = np.ascontiguousarray(dem.cell_max())
    # skip test of the walk: the ellipsoid inflated to the cell's highest node + margin
    # [Q17 eq. 11]; it departs from the constant-height surface by far less than the margin
    hs = cmax + _MARGIN_M
    # the DEM's height range, once (a nanmax over 13 M nodes is 20 ms on a 3601 x 3601 DEM)
    h_max, h_min = dem.max_height(), dem.min_height()
    h_floor = h_min - _MARGIN_M  # where the walk ends: its ellipsoid is the tables' reference
    cinv = _offsets32(np.stack([1 / (A + hs) ** 2, 1 / (B + hs) ** 2], -1), h_floor)
    block = block_cells(dlat, dlon, lat_n - 0.5 * dlat * (nr - 1))
    binv, hinv, hlev = _block_tables(cmax, block, h_floor)
    tab = dict(
        h_max=h_max,
        h_min=h_min,
        h_floor=h_floor,
        hgt=hgt,
        lon_col=lon_cols,
        cinv=cinv,
        binv=binv,
        block=block,
        hinv=hinv,
        hlev=hlev,
        row_geo=row_geo,
        lat_n=lat_n,
        lon_w=lon_w,
        dlat=dlat,
        dlon=dlon,
        tan_row=tan_row,
        c_row=c_row,
        sin_col=np.sin(lon_cols),
        cos_col=np.cos(lon_cols),
    )
    for v in tab.values():  # read-only: shared by every call, and passed to the walk as they are
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    dem._exact_tables = tab
    return tab


#: The ground a block of the walk spans, about [m] (:func:`block_cells`).
BLOCK_GROUND_M = 100.0


def block_cells(dlat: float, dlon: float, lat: float) -> int:
    """Cells per side of the walk's blocks on a grid of ``dlat`` x ``dlon`` rad cells at
    latitude ``lat``: the nearest to :data:`BLOCK_GROUND_M` metres of ground (the cell's side
    taken as the geometric mean of its two), at least
    :data:`geoloc.surfaces.terrain_numba.BLOCK` (8) and at most 16.

    A block that is not clear is walked cell by cell from where the ray comes down to its
    highest node, so larger blocks mean fewer block steps and more cells walked: the balance
    is one of ground distances (how far a ray runs while it descends through the relief of a
    block), not of cells. Measured, the walk alone, the same rays and hits
    (docs/terrain.md, "The block side"): 8.6 m cells (the 3601 x 3601 benchmark DEM) 12
    cells best (0.93 of the time with 8), 17 m cells 12 (0.97-0.98), 26 m cells (a 1''
    tile) 8 (12 cells: 1.13), 31 m and the crop's 90 m cells 8 (12: 1.02).
    """
    from geoloc.surfaces.terrain_numba import BLOCK

    cell_m = A * math.sqrt(abs(dlat) * abs(dlon) * abs(math.cos(lat)))
    if not cell_m > 0:
        return BLOCK
    return int(min(max(round(BLOCK_GROUND_M / cell_m), BLOCK), 16))


def _block_tables(cmax, block, h_floor):
    """The walk's tables above the cells for blocks of ``block`` x ``block`` cells, from the
    cell maxima ``cmax``: binv (float32 offsets from the floor's ellipsoid, as the cell
    table) and the hierarchy above the blocks (:func:`_hierarchy`)."""
    nr, nc = cmax.shape[0] + 1, cmax.shape[1] + 1
    nbr, nbc = -(-(nr - 1) // block), -(-(nc - 1) // block)
    bmax = np.full((nbr * block, nbc * block), -np.inf)
    bmax[: nr - 1, : nc - 1] = cmax  # NaN (no data) propagates: such blocks are never skipped
    bmax = bmax.reshape(nbr, block, nbc, block).max(axis=(1, 3)) + _MARGIN_M
    binv = _offsets32(np.stack([1 / (A + bmax) ** 2, 1 / (B + bmax) ** 2], -1), h_floor)
    hinv, hlev = _hierarchy(bmax)
    return binv, hinv, hlev


def hierarchy_levels(bmax: np.ndarray) -> list[np.ndarray]:
    """The min/max hierarchy above the blocks: level k (k = 1, 2, ...) holds the highest
    node of each 2^k x 2^k group of blocks (block x 2^k cells, the block side of
    :func:`block_cells`), halving the rows and columns (rounded up) until one node is left.

    ``bmax`` (blocks' highest node, no data NaN) is level 0; a group at the grid's
    south or east edge holds the blocks it has. NaN propagates: a node over a
    cell without data is never skipped. Returns the list of levels 1, 2, ...
    (the idea of a maximum mipmap / Orekit Rugged's min/max tile tree; docs/terrain.md).
    """
    levels = []
    cur = np.asarray(bmax, float)
    while cur.shape[0] > 1 or cur.shape[1] > 1:
        r, c = -(-cur.shape[0] // 2), -(-cur.shape[1] // 2)
        pad = np.full((2 * r, 2 * c), -np.inf)
        pad[: cur.shape[0], : cur.shape[1]] = cur
        cur = pad.reshape(r, 2, c, 2).max(axis=(1, 3))
        levels.append(cur)
    return levels


def _hierarchy(bmax):
    """The kernel's form of :func:`hierarchy_levels` (heights already + margin): one
    (n, 2) table of (1/(a+H)^2, 1/(b+H)^2) per node [Q17 eq. 11], levels one after the
    other, and (offset, rows, columns, level k) per level (docs/terrain.md)."""
    levels = hierarchy_levels(bmax)
    hlev = np.zeros((len(levels), 4), np.int64)
    off = 0
    for k, lv in enumerate(levels):
        hlev[k] = off, lv.shape[0], lv.shape[1], k + 1
        off += lv.size
    hh = np.concatenate([lv.ravel() for lv in levels]) if levels else np.zeros(0)
    hinv = np.ascontiguousarray(np.stack([1 / (A + hh) ** 2, 1 / (B + hh) ** 2], -1))
    return hinv, hlev


#: The exact walk takes the rays in an order that keeps the DEM tables it reads in the
#: processor's caches (:func:`geoloc.surfaces.terrain_numba.ray_order`) when there are
#: this many rays and the cell table is this large (an L2 cache of 1 MB per core here; the
#: bundled crop's 1.1 MB table is read from the caches in any order). Measured in
#: docs/terrain.md (the hierarchy section).
_SORT_MIN_RAYS = 4096
_SORT_MIN_BYTES = 4 << 20
#: The lowest hierarchy level the walk climbs to from a clear block (level k: 2^k x 2^k
#: blocks). A jump costs the node's side crossings and the next block's, about as much as
#: a few block steps: over a 2 x 2 or 4 x 4 node it lost time (docs/terrain.md, measured).
CLIMB_FROM = 5
#: Side of the ground tiles of that order, in cells.
_SORT_TILE = 64
#: Whether the walk climbs the levels above the blocks: ``"auto"`` (where it can pay, see
#: :func:`climbs`), ``"always"`` or ``"never"``. The hits are the same either way, bit for bit.
CLIMB = "auto"
#: ``"auto"`` climbs when the rays' median horizontal run through the DEM's height range is
#: longer than this many nodes of level :data:`CLIMB_FROM`: a shorter run cannot jump a node.
CLIMB_MIN_NODES = 2.0


def climbs(o: np.ndarray, d: np.ndarray, tab: dict) -> bool:
    """Whether :func:`_exact` hands the walk its levels above the blocks (:data:`CLIMB`).

    A ray crosses the DEM's height range (its lowest to its highest node, plus the margins)
    over a horizontal run of (height range) / tan(depression). When the median run (of up
    to 256 of the rays) is shorter than :data:`CLIMB_MIN_NODES` nodes of level
    :data:`CLIMB_FROM` (block x 2^CLIMB_FROM cells), no jump can pay for the climb's tests,
    and the walk is the compiled variant without them (a flat walk of
    ``terrain_numba.KERNELS``), whose cell walk is 4-10 % faster (docs/terrain.md). Oblique
    views (8-45 deg below the horizon from 1500 m, ``benchmarks/bench_terrain.py``) do not
    climb; grazing views over a large DEM do.
    """
    if CLIMB != "auto":
        if CLIMB not in ("always", "never"):
            raise ValueError(f"terrain.CLIMB must be 'auto', 'always' or 'never', got {CLIMB!r}")
        return CLIMB == "always" and len(tab["hlev"]) >= CLIMB_FROM
    if len(tab["hlev"]) < CLIMB_FROM or len(o) == 0:
        return False
    from geoloc.surfaces.terrain_numba import _readonly, median_run

    # read-only float64 views, as the walk takes them: one compiled signature
    run_m = median_run(
        _readonly("o", o, np.float64, 2),
        _readonly("d", d, np.float64, 2),
        float(tab["h_max"] - tab["h_min"] + 2 * _MARGIN_M),
        256,
    )
    if math.isnan(run_m):  # no ray without NaN
        return False
    lat_mid = tab["lat_n"] - 0.5 * tab["dlat"] * (tab["hgt"].shape[0] - 1)
    cell_m = A * min(tab["dlat"], tab["dlon"] * math.cos(lat_mid))
    span_m = tab["block"] * 2**CLIMB_FROM * cell_m
    return bool(run_m > CLIMB_MIN_NODES * span_m)


def _exact(o, d, st, dem, dem_model, trace_on, max_cells=4096, parallel=False):
    """The compiled walk: (ECEF hit, cells visited, s, trace, (lat, lon, h, range)); NaN where no hit."""
    from geoloc.surfaces import terrain_numba as tn

    tab = _exact_tables(dem)
    n = len(o)
    order = None
    if n >= _SORT_MIN_RAYS and tab["cinv"].nbytes >= _SORT_MIN_BYTES:
        nt = -(-max(tab["hgt"].shape) // _SORT_TILE) + 2
        order = tn.ray_order(
            o,
            d,
            0.5 * (tab["h_max"] + tab["h_min"]),
            tab["lat_n"],
            tab["lon_w"],
            tab["dlat"],
            tab["dlon"],
            _SORT_TILE,
            nt,
        )
    out = tn.walk_outputs(st, max_cells if trace_on else 0)
    (tn.walk_parallel if parallel else tn.walk)(
        o, d, walk_grid(tab, climbs(o, d, tab)), out, dem_model == "triangles", order=order
    )
    return out.p_out, out.ncell, out.s_out, (out.trace_s, out.trace_ij), out.geo_out.T


def walk_grid(tab: dict, climb: bool) -> WalkGrid:
    """The walk's :class:`geoloc.surfaces.terrain_numba.WalkGrid` from :func:`_exact_tables`'s ``tab``:
    the walk starts at the highest node plus the margin and ends at the tables' floor; with the
    levels above the blocks from :data:`CLIMB_FROM` up when ``climb`` (:func:`climbs`), else none."""
    from geoloc.surfaces import terrain_numba as tn

    return tn.WalkGrid(
        h_top=tab["h_max"] + _MARGIN_M,
        h_floor=tab["h_floor"],
        hgt=tab["hgt"],
        lon_col=tab["lon_col"],
        cinv=tab["cinv"],
        binv=tab["binv"],
        blk=tab["block"],
        hinv=tab["hinv"],
        hlev=tab["hlev"][CLIMB_FROM - 1 :] if climb else tab["hlev"][:0],
        row_geo=tab["row_geo"],
        lat_n=tab["lat_n"],
        lon_w=tab["lon_w"],
        dlat=tab["dlat"],
        dlon=tab["dlon"],
        tan_row=tab["tan_row"],
        c_row=tab["c_row"],
        sin_col=tab["sin_col"],
        cos_col=tab["cos_col"],
    )


# --------------------------------------------------------------------------- front end
def intersect_dem(
    los: LineOfSight,
    dem: DEM,
    method: str = "exact",
    *,
    eps_h: float = 1.0,
    threshold: float = 1.0,
    dem_model: str = "bilinear",
    trace: bool = False,
    max_iter: int | None = None,
    parallel: bool = False,
) -> TerrainHit:
    """Intersect lines of sight with a DEM (docs/method.md section 4).

    Parameters
    ----------
    los : LineOfSight
        Any batch shape (:func:`geoloc.locate.line_of_sight`).
    dem : geoloc.surfaces.dem.DEM
    method : {"steps", "bisect", "exact"}
        [Q17 section 2.3] descending steps, [L23] bisection, or the exact first hit.
    eps_h : float
        Step of the descending method [m] (> 0).
    threshold : float
        Bisection stops when |H - h_DEM| < threshold [m] (> 0).
    dem_model : {"bilinear", "triangles"}
        How the exact solver reads between nodes: bilinear cells (what
        ``dem.height`` samples, used by the iterative methods too) or two planar
        triangles per cell (the :meth:`DEM.to_trimesh` mesh). (The word
        *surface* means only what a line of sight meets: ``docs/architecture.md``.)
    trace : bool
        Record every iteration in ``TerrainHit.trace``.
    max_iter : int, optional
        Iteration limit of the iterative methods (default: enough to reach
        the DEM's lowest node for steps, at most :data:`STEPS_MAX`; 64 halvings
        for bisection). A ray still searching at the limit gets NO_CONVERGENCE.
    parallel : bool
        Exact solver: spread the rays over all cores (numba threads).

    Returns
    -------
    TerrainHit
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if dem_model not in DEM_MODELS:
        raise ValueError(f"dem_model must be one of {DEM_MODELS}, got {dem_model!r}")
    if not (np.isfinite(eps_h) and eps_h > 0):
        raise ValueError(f"eps_h must be a positive number of metres, got {eps_h!r}")
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a positive number of metres, got {threshold!r}")
    shape, o, d, st = _flat_los(los, normalise=method != "exact")
    n = len(o)
    if not dem.has_data:  # an all no-data raster: nothing to meet (its H_max is NaN: no start for any method)
        return _no_terrain(los, shape, o, d, st, method, dem_model, trace)
    below_terrain(o, st, dem, _exact_tables(dem)["h_max"] if method == "exact" else None)
    tracer = _Tracer(n, trace)
    hidden = np.zeros(n, dtype=bool)
    tr = None
    if method == "steps":
        p, evals = _steps(o, d, st, dem, float(eps_h), tracer, max_iter)
        tr = tracer.build(method, n, shape, evals)
    elif method == "bisect":
        p, evals = _bisect(o, d, st, dem, float(threshold), tracer, max_iter)
        tr = tracer.build(method, n, shape, evals)
        ok = st == Status.OK
        s_bis = np.sum((p - o) * d, -1)
        if dem.is_geographic:
            s_first = _exact(o, d, st.copy(), dem, "bilinear", False)[2]
        else:
            s_first = _first_sampled(o, d, dem)
        hidden = _hidden(o, d, s_bis, s_first, dem, ok)
    else:
        p, evals, s, (ts, tij), geo = _exact(o, d, st, dem, dem_model, trace, parallel=parallel)
        if trace:
            m = int(evals.max()) if n else 0
            m = min(m, ts.shape[1])
            ts, tij = ts[:, :m], tij[:, :m]
            pe = o[:, None, :] + ts[..., None] * d[:, None, :]
            lat, lon, H = ecef_to_geodetic(pe)
            hd = dem.height(lat, lon)
            tr = TerrainTrace(
                method,
                H.reshape(shape + (m,)),
                lat.reshape(shape + (m,)),
                lon.reshape(shape + (m,)),
                pe.reshape(shape + (m, 3)),
                hd.reshape(shape + (m,)),
                np.full(shape + (m,), np.nan),
                np.full(shape + (m,), np.nan),
                tij.reshape(shape + (m, 2)),
                np.minimum(evals, m).reshape(shape),
            )
    if method == "exact":  # the kernel converted its hits (NaN elsewhere); none is hidden
        lat, lon, h, rng = geo
    else:
        ok = st == _OK
        p = np.where(ok[:, None], p, np.nan)
        lat, lon, h = ecef_to_geodetic(p)
        rng = np.linalg.norm(p - o, axis=-1)
        hidden &= ok
    r = lambda a: a.reshape(shape)  # noqa: E731
    return TerrainHit(
        r(lat),
        r(lon),
        r(h),
        p.reshape(shape + (3,)),
        r(rng),
        r(st),
        los if isinstance(los, LineOfSight) else None,
        dem_evaluations=r(evals),
        hidden=r(hidden),
        method=method,
        dem_model=dem_model,
        trace=tr,
    )


#: Below any land or sea floor (the Challenger Deep is at about -10 935 m) [m, ellipsoidal
#: within the geoid's +-110 m]: a ray that misses this ellipsoid points above every horizon.
LOWEST_TERRAIN_M = -11_500.0


def _no_terrain(los, shape, o, d, st, method, dem_model, trace):
    """The hit of a DEM without a single height: NODATA for every ray still OK that comes down
    to the ellipsoid inflated to :data:`LOWEST_TERRAIN_M` (no terrain lies lower); SKY above it
    (a NaN highest node fails every comparison: without this each ray would be SKY)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)  # (the exact method's rays come unnormalised)
    bad = ~(np.all(np.isfinite(o), axis=-1) & np.all(np.isfinite(d), axis=-1))
    st[bad & (st == Status.OK)] = Status.INVALID_INPUT
    ok = np.flatnonzero(st == Status.OK)
    down = ray_inflated_ellipsoid(o[ok], d[ok], np.full(len(ok), LOWEST_TERRAIN_M)).status == Status.OK
    st[ok] = np.where(down, Status.NODATA, Status.SKY)
    nan = np.full(shape, np.nan)
    tr = None
    if trace:
        e = np.full(shape + (0,), np.nan)
        tr = TerrainTrace(
            method,
            e,
            e,
            e,
            np.full(shape + (0, 3), np.nan),
            e,
            e,
            e,
            np.full(shape + (0, 2), -1, dtype=np.int64),
            np.zeros(shape, dtype=np.int64),
        )
    return TerrainHit(
        nan,
        nan.copy(),
        nan.copy(),
        np.full(shape + (3,), np.nan),
        nan.copy(),
        st.reshape(shape),
        los if isinstance(los, LineOfSight) else None,
        dem_evaluations=np.zeros(shape, np.int64),
        hidden=np.zeros(shape, bool),
        method=method,
        dem_model=dem_model,
        trace=tr,
    )


def _first_sampled(o, d, dem):
    """First ray parameter below the terrain, sampled (non-geographic DEMs)."""
    hit = intersect_dem(
        LineOfSight(o, d, np.zeros(len(o), np.uint8)),
        dem,
        "steps",
        eps_h=max(0.1, (dem.max_height() - dem.min_height()) / 2000),
    )
    return np.sum((hit.ecef - o) * d, -1)


def random_oblique_rays(
    dem: DEM,
    n: int,
    rng: np.random.Generator,
    frame_angle_deg: tuple[float, float] = (45.0, 82.0),
    clearance_m: float = 1500.0,
    inner: float = 0.5,
) -> LineOfSight:
    """Random lines of sight over a DEM, for tests and benchmarks.

    Each ray aims at a random point of the DEM's central ``inner`` fraction,
    from a camera ``clearance_m`` above that point's terrain, with an
    off-nadir (frame) angle uniform in ``frame_angle_deg`` and a uniform
    azimuth. The aimed point need not be the first hit (terrain may occlude it).
    """
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc.geodesy.local import R_ecef_enu

    w, s, e, nn = dem.bounds_deg
    cx, cy, hw, hh = 0.5 * (w + e), 0.5 * (s + nn), 0.5 * inner * (e - w), 0.5 * inner * (nn - s)
    lat = np.deg2rad(rng.uniform(cy - hh, cy + hh, n))
    lon = np.deg2rad(rng.uniform(cx - hw, cx + hw, n))
    hT = dem.height(lat, lon)
    off_min_deg, off_max_deg = frame_angle_deg
    off = np.deg2rad(rng.uniform(off_min_deg, off_max_deg, n))
    az = rng.uniform(0, 2 * np.pi, n)
    d_enu = np.stack([np.sin(az) * np.sin(off), np.cos(az) * np.sin(off), -np.cos(off)], -1)
    d = np.einsum("...ij,...j->...i", R_ecef_enu(lat, lon), d_enu)
    t = geodetic_to_ecef(lat, lon, hT)
    o = t - (clearance_m / np.cos(off))[:, None] * d
    return LineOfSight(o, d, np.zeros(n, np.uint8))


class DemSurface:
    """A DEM as a surface: the first visible crossing of each line of sight (:func:`intersect_dem`).

    Parameters
    ----------
    dem : geoloc.surfaces.dem.DEM or a mosaic (:class:`geoloc.surfaces.base.MosaicSource`)
        A mosaic is solved region by region, within its memory bound (its ``with_solver``).
    method : {"steps", "bisect", "exact"}
        [Q17 section 2.3] descending steps, [L23] bisection, or the exact first hit.
    dem_model : {"bilinear", "triangles"}
        How the exact solver reads between nodes (``intersect_dem``'s ``dem_model=``).
    **options
        ``eps_h``, ``threshold``, ``trace``, ``max_iter``, ``parallel`` of :func:`intersect_dem`.
    """

    def __init__(
        self, dem: DEM | MosaicSource, method: str = "exact", dem_model: str = "bilinear", **options: Any
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"DEM method = {method!r}: must be one of {METHODS}")
        self.dem: DEM | MosaicSource = dem
        self.method, self.dem_model, self.options = method, dem_model, options

    def intersect(self, los: LineOfSight) -> TerrainHit:
        if is_mosaic(self.dem):  # region by region, within the mosaic's memory bound
            return cast(TerrainHit, self.dem.with_solver(self.method, self.dem_model, **self.options).intersect(los))
        return intersect_dem(los, cast(DEM, self.dem), self.method, dem_model=self.dem_model, **self.options)

    def __repr__(self) -> str:
        return f"DemSurface({self.dem!r}, method={self.method!r}, dem_model={self.dem_model!r})"


class DemElseHeight:
    """The DEM, and a height surface for the rays the DEM cannot serve.

    A ray that leaves the DEM (``LEFT_DEM``) or meets no data (``NODATA``) on
    ``dem_surface`` takes its crossing with ``height_surface`` instead (its status
    then is that surface's); every other ray keeps the DEM's hit. The viewers'
    flight footprint uses it, so a corner past the DEM's edge still has a point.

    Parameters
    ----------
    dem_surface : DemSurface or geoloc.surfaces.mosaic.DemMosaic
    height_surface : geoloc.surfaces.height.HeightSurface
    """

    #: The DEM's statuses that fall back to the height.
    FALLBACK = (Status.LEFT_DEM, Status.NODATA)

    def __init__(self, dem_surface: DemSurface | MosaicSource, height_surface: Surface):
        self.dem_surface, self.height_surface = dem_surface, height_surface

    @property
    def dem(self) -> DEM | MosaicSource:
        """The DEM source read (:func:`geoloc.surfaces.base.terrain_of`)."""
        d = self.dem_surface
        return d.dem if isinstance(d, DemSurface) else d

    def intersect(self, los: LineOfSight) -> GroundPoint:
        g = self.dem_surface.intersect(los)
        st = np.asarray(g.status)
        miss = np.isin(st, self.FALLBACK)
        if not miss.any():
            return g
        f = self.height_surface.intersect(los)
        lat, lon, h, rng = (
            np.where(miss, b, a)
            for a, b in ((g.lat, f.lat), (g.lon, f.lon), (g.h, f.h), (g.slant_range, f.slant_range))
        )
        ecef = np.where(miss[..., None], f.ecef, g.ecef)
        return GroundPoint(lat, lon, h, ecef, rng, np.where(miss, f.status, st).astype(np.uint8), g.los)

    def __repr__(self) -> str:
        return f"DemElseHeight({self.dem_surface!r}, {self.height_surface!r})"


def surface_for(
    target_h: ArrayLike | None = None,
    dem: DEM | MosaicSource | None = None,
    *,
    method: str = "exact",
    kind: str = "inflated",
    dem_model: str = "bilinear",
    per_record: bool = False,
    else_height: bool = False,
    **options: Any,
) -> Surface:
    """The one place the "constant height or DEM" choice is made: a DEM if given, else a height.

    Parameters
    ----------
    target_h : float or array_like, optional
        Target ellipsoidal height [m]; with ``per_record``, one per record.
    dem : DemSource, optional
        A DEM raster or a mosaic.
    method, dem_model, **options
        The DEM solver (:class:`DemSurface`).
    kind : {"inflated", "geodetic"}
        The height surface's kind.
    per_record : bool
        ``target_h`` is one height per record: a
        :class:`geoloc.surfaces.height.PerRecordHeightSurface`.
    else_height : bool
        With a DEM and a target height: :class:`DemElseHeight` (the height where the
        DEM has no hit) instead of the DEM alone.

    Returns
    -------
    Surface
        ValueError when neither a DEM nor a target height is given.
    """
    from geoloc.surfaces.height import HeightSurface, PerRecordHeightSurface

    height = None
    if target_h is not None:
        height = PerRecordHeightSurface(target_h, kind) if per_record else HeightSurface(target_h, kind)
    if dem is not None:
        terrain = (
            DemSurface(dem, method, dem_model, **options)
            if isinstance(dem, DEM)
            else dem.with_solver(method, dem_model, **options)  # a mosaic: a surface itself
        )
        return DemElseHeight(terrain, height) if else_height and height is not None else terrain
    if height is None:
        raise ValueError("give a DEM or a target height (ellipsoidal, metres)")
    return height
