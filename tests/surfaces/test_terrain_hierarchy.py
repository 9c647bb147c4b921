"""The exact walk's min/max hierarchy: its levels against a direct numpy
maximum over the DEM nodes, and its hits against trimesh/embree's ray cast on a rough
600 x 600 DEM, including rays that graze it for kilometres and leave it across an edge."""

import numpy as np
import pytest
from test_terrain_trimesh import (  # tests/ is on sys.path (no __init__)
    trimesh_first_hits,
    walk_against_embree,
)

from geoloc.assets import asset_path
from geoloc.geodesy.ellipsoid import A, B, geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_enu
from geoloc.status import Status
from geoloc.surfaces import terrain
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DEM, upsampled_dem
from geoloc.surfaces.terrain import _MARGIN_M, intersect_dem, random_oblique_rays


def _rough_dem(n, seed, roughness_m=3.0):
    """The bundled SRTM crop resampled bilinearly to n x n nodes over the same area, plus
    seeded Gaussian roughness (sigma ``roughness_m``): cells ~50 m at n = 600."""
    return upsampled_dem(DEM.open(asset_path("dem", "srtm_jacksboro.tif")), n, np.random.default_rng(seed), roughness_m)


def _decode(inv):
    """Height H [m] from the kernel's (1/(a+H)^2, 1/(b+H)^2)."""
    return 1.0 / np.sqrt(inv[..., 0]) - A


@pytest.mark.parametrize("block", [8, 12, 13])
def test_levels_are_the_maximum_over_their_cells(block, monkeypatch):
    """Level k holds, for each 2^k x 2^k group of blocks, the highest DEM node of its cells:
    computed here straight from the heights with numpy slices (the nodes of rows r0..r1,
    columns c0..c1 bound the cells between them), with no data (NaN) propagating, on a DEM
    whose sides are not multiples of the block (partial groups at the south and east);
    for the blocks of 8 cells and two larger sides (terrain.block_cells: ~100 m of ground)."""
    # the cells of this DEM are ~33 x 36 m (0.0003 x 0.0004 deg at 36.5 deg N): ground
    # sizes that round to the wanted number of cells
    cell_m = A * np.sqrt(np.deg2rad(0.0003) * np.deg2rad(0.0004) * np.cos(np.deg2rad(36.5)))
    monkeypatch.setattr(terrain, "BLOCK_GROUND_M", block * cell_m)
    rng = np.random.default_rng(3)
    z = 300.0 + 80.0 * rng.standard_normal((203, 157))
    z[150, 40] = np.nan  # one missing node: its four cells, and every node above them
    dem = DEM.from_array(z, 36.5, -84.3, 0.0003, 0.0004)
    tab = terrain._exact_tables(dem)
    hinv, hlev = tab["hinv"], tab["hlev"]
    nr, nc = z.shape
    BLOCK = tab["block"]
    assert BLOCK == block
    nbr, nbc = -(-(nr - 1) // BLOCK), -(-(nc - 1) // BLOCK)
    assert tab["binv"].shape[:2] == (nbr, nbc)
    assert hlev[-1, 1:3].tolist() == [1, 1]  # up to the one root node
    assert hlev[:, 3].tolist() == list(range(1, len(hlev) + 1))
    root_max = None
    for off, rows, cols, k in hlev:
        span = BLOCK << k
        assert (rows, cols) == (-(-(nr - 1) // span), -(-(nc - 1) // span))
        got = _decode(hinv[off : off + rows * cols].reshape(rows, cols, 2))
        want = np.empty((rows, cols))
        for a in range(rows):
            for b in range(cols):
                want[a, b] = z[
                    a * span : min((a + 1) * span, nr - 1) + 1, b * span : min((b + 1) * span, nc - 1) + 1
                ].max()
        assert np.array_equal(np.isnan(got), np.isnan(want))
        # 1/(a+H)^2 and back loses ~1e-16 of a + H = 6.4e6 m: 1e-9 m; 1e-6 m is far below any
        # height difference that would matter and far above that rounding
        fin = ~np.isnan(want)
        np.testing.assert_allclose(got[fin], want[fin] + _MARGIN_M, rtol=0, atol=1e-6)
        root_max = want
    assert np.isnan(root_max[0, 0])  # the missing node reaches the root: never skipped
    # without the missing node the root holds the DEM's highest node
    dem2 = DEM.from_array(np.nan_to_num(z, nan=0.0), 36.5, -84.3, 0.0003, 0.0004)
    tab2 = terrain._exact_tables(dem2)
    assert _decode(tab2["hinv"][-1]) == pytest.approx(np.nanmax(z) + _MARGIN_M, abs=1e-6)


def _grazing_and_edge_rays(dem, n, rng, outside=False):
    """Rays at 0.3-4 deg below the horizontal from 20-200 m above the DEM's highest node:
    they cross kilometres of terrain, mostly far above it (where the hierarchy skips), and
    many leave the DEM across an edge. ``outside``: all start beyond one of its four
    edges (west, east, north or south of it) and aim inwards."""
    w, s, e, nn = dem.bounds_deg
    lat = rng.uniform(s, nn, n)
    lon = rng.uniform(w, e, n)
    out = np.full(n, bool(outside))
    side = rng.integers(0, 4, n)
    pad_lon, pad_lat = 0.08 * (e - w), 0.08 * (nn - s)
    lon = np.where(out & (side == 0), w - pad_lon, np.where(out & (side == 1), e + pad_lon, lon))
    lat = np.where(out & (side == 2), nn + pad_lat, np.where(out & (side == 3), s - pad_lat, lat))
    # inward azimuths for the outside ones (east, west, south, north), any for the others
    az_in = np.array([90.0, 270.0, 180.0, 0.0])[side] + rng.uniform(-60, 60, n)
    az = np.deg2rad(np.where(out, az_in, rng.uniform(0, 360, n)))
    el = np.deg2rad(rng.uniform(0.3, 4.0, n))
    h0 = dem.max_height() + rng.uniform(20.0, 200.0, n)
    la, lo = np.deg2rad(lat), np.deg2rad(lon)
    d_enu = np.stack([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), -np.sin(el)], -1)
    d = np.einsum("...ij,...j->...i", R_ecef_enu(la, lo), d_enu)
    return LineOfSight(geodetic_to_ecef(la, lo, h0), d, np.zeros(n, np.uint8))


@pytest.fixture(scope="module")
def rough600():
    return _rough_dem(600, seed=5)


def _without_hierarchy(dem, los, surface):
    """The same walk with the levels above the blocks removed (the two-level walk of before)."""
    tab = terrain._exact_tables(dem)
    full = tab["hlev"]
    tab["hlev"] = full[:0]
    try:
        return intersect_dem(los, dem, "exact", dem_model=surface)
    finally:
        tab["hlev"] = full


@pytest.mark.parametrize("climb_from", [1, terrain.CLIMB_FROM])
@pytest.mark.parametrize("kind", ["oblique", "grazing_and_edge"])
def test_hits_with_the_hierarchy_equal_trimesh(rough600, kind, climb_from, monkeypatch):
    """Every level in use (climb_from 1: from 2 x 2 blocks up) and the default; the climbing
    kernel forced (CLIMB "always") against the one compiled without the climb (no levels)."""
    monkeypatch.setattr(terrain, "CLIMB_FROM", climb_from)
    monkeypatch.setattr(terrain, "CLIMB", "always")
    dem = rough600
    rng = np.random.default_rng(17)
    if kind == "oblique":
        los = random_oblique_rays(dem, 6000, rng, frame_angle_deg=(0.0, 82.0))
    else:
        los = _grazing_and_edge_rays(dem, 6000, rng)
    hit = intersect_dem(los, dem, "exact", dem_model="triangles")
    ok = hit.status == Status.OK
    hit_tm, err = trimesh_first_hits(dem, los, hit)
    assert ok.sum() > 1500 and (kind == "oblique" or (hit.status == Status.LEFT_DEM).sum() > 200)
    # the outside oracle: the same rays hit, at the same points. 1e-7 m: the walk's fused
    # multiply-adds against trimesh's float64 recomputation on embree's triangle
    # (tests/surfaces/test_terrain_trimesh.py measured 6.6e-8 m on the SRTM crop)
    assert np.array_equal(ok, hit_tm)
    assert err.max() < 1e-7
    assert set(np.unique(hit.status[~ok])) <= {Status.LEFT_DEM, Status.SKY}
    # and bit for bit what the walk gives without the levels above the blocks: the
    # hierarchy only decides what is skipped, it never moves an entry point
    for surface in ("triangles", "bilinear"):
        h1 = hit if surface == "triangles" else intersect_dem(los, dem, "exact", dem_model=surface)
        h0 = _without_hierarchy(dem, los, surface)
        assert np.array_equal(h1.status, h0.status)
        assert np.array_equal(h1.ecef, h0.ecef, equal_nan=True)
        assert np.array_equal(h1.h, h0.h, equal_nan=True)
        if kind != "oblique":
            # grazing rays: the levels above the blocks replace block steps, most of them
            # with every level in use (measured: 25.9 steps a ray -> 9.2 with all levels, 21.8
            # from the default level; bounds 0.5 and 0.9 leave room for a changed seed)
            assert h1.dem_evaluations.mean() < (0.5 if climb_from == 1 else 0.9) * h0.dem_evaluations.mean()


def test_hierarchy_with_a_trace_and_no_data(rough600, monkeypatch):
    """With a trace (the kernel then finds the cell at every step, jumps included) and with
    a hole of no data in the DEM (a node above it is never skipped): the statuses and hits
    equal the walk without the levels above the blocks."""
    monkeypatch.setattr(terrain, "CLIMB", "always")
    z = np.array(rough600.grid.values, float)
    z[250:260, 300:330] = np.nan
    g = rough600.grid
    dem = DEM.from_array(z, g.lat_north_deg, g.lon_west_deg, g.dlat_deg, g.dlon_deg)
    los = _grazing_and_edge_rays(dem, 3000, np.random.default_rng(4))
    h1 = intersect_dem(los, dem, "exact", dem_model="triangles", trace=True)
    h0 = _without_hierarchy(dem, los, "triangles")
    assert (h1.status == Status.NODATA).sum() > 10
    assert np.array_equal(h1.status, h0.status)
    assert np.array_equal(h1.ecef, h0.ecef, equal_nan=True)


def test_rays_from_beyond_an_edge_are_left_dem(rough600):
    """docs/terrain.md, statuses: a ray that is outside the DEM where it comes down to the
    DEM's highest node is LEFT_DEM (the same rule for all methods), even where it would
    come over the edge lower down and hit (trimesh finds those): with the hierarchy as
    before. Rays from 20-200 m above H_max beyond an edge, aimed inwards."""
    los = _grazing_and_edge_rays(rough600, 2000, np.random.default_rng(8), outside=True)
    hit = intersect_dem(los, rough600, "exact", dem_model="triangles")
    hit_tm, err = trimesh_first_hits(rough600, los, hit)
    ok = hit.status == Status.OK
    missed = hit_tm & ~ok
    assert missed.sum() > 100  # trimesh meets the mesh after the edge on many of them
    assert (hit.status[missed] == Status.LEFT_DEM).all()
    # the rays that come down to H_max inside the DEM: trimesh's hits, to 1e-7 m as above
    assert not (ok & ~hit_tm).any()
    assert ok.sum() > 50 and np.nanmax(err) < 1e-7  # NaN: the rays that left the DEM here
    h0 = _without_hierarchy(rough600, los, "triangles")
    assert np.array_equal(h0.status, hit.status)


def test_auto_climbs_for_grazing_views_only(rough600, monkeypatch):
    """terrain.climbs ("auto"): the oblique views of the benchmark (8-45 deg below the horizon)
    cannot jump a level-CLIMB_FROM node and walk without the climb; grazing views (0.3-4 deg)
    over the 600 x 600 DEM climb. Either way the hits are the climbing walk's, bit for bit."""
    from geoloc.surfaces import terrain_numba as tn

    monkeypatch.setattr(terrain, "CLIMB_FROM", 3)  # nodes of 64 cells: the 600-node DEM holds several
    tab = terrain._exact_tables(rough600)
    rng = np.random.default_rng(23)
    oblique = random_oblique_rays(rough600, 3000, rng, frame_angle_deg=(45.0, 82.0))
    grazing = _grazing_and_edge_rays(rough600, 3000, rng)
    flat = lambda los: (los.origin_ecef.reshape(-1, 3), los.direction_ecef.reshape(-1, 3))
    assert not terrain.climbs(*flat(oblique), tab)
    assert terrain.climbs(*flat(grazing), tab)
    used = []
    real = tn._kernel_for
    monkeypatch.setattr(
        tn,
        "_kernel_for",
        lambda hlev, block=tn.BLOCK, triangles=False: (used.append(len(hlev)), real(hlev, block, triangles))[1],
    )
    for los in (oblique, grazing):
        auto = intersect_dem(los, rough600, "exact", dem_model="triangles")
        monkeypatch.setattr(terrain, "CLIMB", "always")
        forced = intersect_dem(los, rough600, "exact", dem_model="triangles")
        monkeypatch.setattr(terrain, "CLIMB", "auto")
        assert np.array_equal(auto.status, forced.status)
        assert np.array_equal(auto.ecef, forced.ecef, equal_nan=True)
    assert used[0] == 0 and used[1] > 0 and used[2] > 0 and used[3] > 0  # oblique auto: no levels
    monkeypatch.setattr(terrain, "CLIMB", "sometimes")
    with pytest.raises(ValueError, match="sometimes"):
        terrain.climbs(*flat(oblique), tab)


def test_median_run_closed_form():
    """terrain_numba.median_run, the figure terrain.climbs decides on: a ray from R u (u a unit
    vector, the geocentric up) with direction cos(e) t - sin(e) u (t a unit vector normal to
    u) descends at e, so it runs dh / tan(e) over a drop of dh; ascending and horizontal rays
    run forever, a ray with NaN is left out; over more rays than m, m spread evenly (first
    and last included)."""
    from geoloc.surfaces import terrain_numba as tn

    rng = np.random.default_rng(9)
    u = rng.standard_normal((9, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    t = np.cross(u, rng.standard_normal(3))
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    e = np.deg2rad([1.0, 2.0, 5.0, 10.0, 30.0, 60.0, -5.0, 0.0, 45.0])
    o = 6.4e6 * u
    d = 3.0 * (np.cos(e)[:, None] * t - np.sin(e)[:, None] * u)  # not unit: the run is the same
    d[8] = np.nan
    dh = 700.0
    runs = np.where(e > 0, dh / np.tan(np.where(e > 0, e, 1.0)), np.inf)[:8]
    # 1e-9 relative: the dot products of 6.4e6 m vectors, rounding only
    assert tn.median_run(o, d, dh, 256) == pytest.approx(np.median(runs), rel=1e-9)
    assert tn.median_run(o[:2], d[:2], dh, 256) == pytest.approx(0.5 * (runs[0] + runs[1]), rel=1e-9)
    # m = 3 of the 9: rays 0, 4 and 8 (8 has NaN): the median of rays 0 and 4
    assert tn.median_run(o, d, dh, 3) == pytest.approx(0.5 * (runs[0] + runs[4]), rel=1e-9)
    assert np.isnan(tn.median_run(o[8:], d[8:], dh, 256))
    assert tn.median_run(o[6:8], d[6:8], dh, 256) == np.inf


def test_walk_order_changes_no_hit(rough600, monkeypatch):
    """The kernel walks the rays in ray_order's tile-by-tile order (reading each ray through
    the order, writing its results in its own row): the statuses, hits, heights and steps
    equal those of the walk in the given order, bit for bit, serial and on two threads;
    the order is a permutation."""
    from geoloc.surfaces import terrain_numba as tn

    los = random_oblique_rays(rough600, 5000, np.random.default_rng(31), frame_angle_deg=(0.0, 82.0))
    monkeypatch.setattr(terrain, "_SORT_MIN_RAYS", 10**9)
    plain = intersect_dem(los, rough600, "exact", dem_model="triangles")
    monkeypatch.setattr(terrain, "_SORT_MIN_RAYS", 1)
    monkeypatch.setattr(terrain, "_SORT_MIN_BYTES", 0)  # the 600 x 600 tables are below the default
    for parallel in (False, True):
        got = intersect_dem(los, rough600, "exact", dem_model="triangles", parallel=parallel)
        assert np.array_equal(got.status, plain.status)
        assert np.array_equal(got.ecef, plain.ecef, equal_nan=True)
        assert np.array_equal(got.h, plain.h, equal_nan=True)
        assert np.array_equal(got.dem_evaluations, plain.dem_evaluations)
    tab = terrain._exact_tables(rough600)
    o, d = los.origin_ecef.reshape(-1, 3), los.direction_ecef.reshape(-1, 3)
    order = tn.ray_order(
        o,
        d,
        0.5 * (tab["h_max"] + tab["h_min"]),
        tab["lat_n"],
        tab["lon_w"],
        tab["dlat"],
        tab["dlon"],
        64,
        -(-600 // 64) + 2,
    )
    assert np.array_equal(np.sort(order), np.arange(len(o)))


def test_tile_keys_against_geodetic_tiles(rough600):
    """ray_order's keys take the angles from the DEM's corner as their tangents (no atan2):
    against tiles computed from the exact latitude and longitude (pyproj) of the point where
    each ray meets the middle height, the tile row and column agree for all but the rays
    within 1e-6 of a tile's width of a tile boundary (tan x - x ~ x^3/3 ~ 1e-7 of the
    0.1-degree DEM), here none of 5000."""
    import pyproj

    from geoloc.surfaces import terrain_numba as tn

    los = random_oblique_rays(rough600, 5000, np.random.default_rng(32), frame_angle_deg=(0.0, 82.0))
    tab = terrain._exact_tables(rough600)
    o = np.ascontiguousarray(los.origin_ecef.reshape(-1, 3))
    d = np.ascontiguousarray(los.direction_ecef.reshape(-1, 3))
    h_mid, cells = 0.5 * (tab["h_max"] + tab["h_min"]), 64
    nt = -(-600 // cells) + 2
    keys = np.empty(len(o), np.int64)
    tn._tile_keys(
        o,
        d,
        1.0 / (A + h_mid) ** 2,
        1.0 / (B + h_mid) ** 2,
        np.tan(tab["lat_n"]),
        np.sin(tab["lon_w"]),
        np.cos(tab["lon_w"]),
        tab["dlat"] * cells,
        tab["dlon"] * cells,
        nt,
        keys,
    )
    # the point at height h_mid on each ray: pyproj's geodetic coordinates of the ray points,
    # bisected on the ray parameter (the rays come down from 1500 m above the terrain)
    ecef_to_lla = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    un = d / np.linalg.norm(d, axis=1, keepdims=True)
    lo_s, hi_s = np.zeros(len(o)), np.full(len(o), 2e5)
    for _ in range(60):
        mid = 0.5 * (lo_s + hi_s)
        p = o + mid[:, None] * un
        _, _, hh = ecef_to_lla.transform(p[:, 0], p[:, 1], p[:, 2])
        above = hh > h_mid
        lo_s, hi_s = np.where(above, mid, lo_s), np.where(above, hi_s, mid)
    p = o + hi_s[:, None] * un
    lon, lat, _ = ecef_to_lla.transform(p[:, 0], p[:, 1], p[:, 2])
    fi = (tab["lat_n"] - np.deg2rad(lat)) / (tab["dlat"] * cells)
    fj = (np.deg2rad(lon) - tab["lon_w"]) / (tab["dlon"] * cells)
    ti = np.clip(np.floor(fi + 1.0), 0, nt - 1).astype(int)
    tj = np.clip(np.floor(fj + 1.0), 0, nt - 1).astype(int)
    want = ti * nt + np.where(ti % 2 == 1, nt - 1 - tj, tj)
    near_edge = (np.abs(fi - np.round(fi)) < 1e-6) | (np.abs(fj - np.round(fj)) < 1e-6)
    assert np.array_equal(keys[~near_edge], want[~near_edge]) and near_edge.sum() == 0


def test_walk_refuses_a_bad_order(rough600):
    from geoloc.surfaces import terrain_numba as tn

    tab = terrain._exact_tables(rough600)
    o = np.array([[A + 2000.0, 0.0, 0.0]])
    d = np.array([[-1.0, 0.0, 0.0]])
    grid = terrain.walk_grid(tab, climb=False)
    out = tn.walk_outputs(np.zeros(1, np.uint8))
    for bad in (np.array([1]), np.array([-1]), np.zeros((1, 1), np.int64)):
        with pytest.raises(ValueError, match="order"):
            tn.walk(o, d, grid, out, True, order=bad)
    tn.walk(o, d, grid, out, True, order=np.array([0]))  # a good one runs
    # a cell or block table not in the kernel's float32 offset form is refused, not cast
    # (a float64 table of the values themselves would be read as offsets: wrong skips)
    for k in ("cinv", "binv"):
        bad_grid = grid._replace(**{k: getattr(grid, k).astype(np.float64)})
        with pytest.raises(ValueError, match=k + " must be float32 offsets"):
            tn.walk(o, d, bad_grid, out, True)
    # a block side other than the one binv was made for is refused (it would read wrong blocks)
    assert tab["block"] == 8
    with pytest.raises(ValueError, match="binv has 75 x 75 blocks, but block = 12"):
        tn.walk(o, d, grid._replace(blk=12), out, True)
    for blk in (0, 17):
        with pytest.raises(ValueError, match=f"blocks of {blk} cells"):
            tn.walk(o, d, grid._replace(blk=blk), out, True)


def test_block_index_without_a_division():
    """The walk finds a cell's block as (i * ceil(2^28 / blk)) >> 28 instead of i // blk:
    equal for every row or column index the walk takes (below 2^24) and every block side it
    allows (1 to 16)."""
    i = np.arange(1 << 24, dtype=np.int64)
    for blk in range(1, 17):
        assert np.array_equal((i * (((1 << 28) + blk - 1) // blk)) >> 28, i // blk), blk


def test_block_cells_is_about_100_m_of_ground():
    """terrain.block_cells: the cells per block side nearest to 100 m of ground (the cell's
    side the geometric mean of its north-south and east-west sides), between 8 and 16."""
    ang = lambda m: m / A  # a cell side in metres as an angle on the equator
    assert terrain.block_cells(ang(8.6), ang(8.6), 0.0) == 12  # the 3601 x 3601 benchmark DEM
    assert terrain.block_cells(ang(7.1), ang(7.1), 0.0) == 14  # 100 / 7.1 = 14.08
    assert terrain.block_cells(ang(1.0), ang(1.0), 0.0) == 16  # at most 16
    assert terrain.block_cells(ang(30.0), ang(30.0), 0.0) == 8  # a 1'' tile: at least 8
    # at 60 deg N a cell of equal angles is half as wide: sqrt(10 x 5) m = 7.07 m -> 14
    assert terrain.block_cells(ang(10.0), ang(10.0), np.deg2rad(60.0)) == 14
    assert terrain.block_cells(0.0, ang(10.0), 0.0) == 8  # a degenerate grid: the least


def test_larger_blocks_change_no_hit(monkeypatch):
    """On a DEM of 7.7 m cells the walk takes blocks of 13 cells (terrain.block_cells); its
    statuses, hits and heights are those of the walk over blocks of 8 cells, bit for bit
    (a block only decides what is skipped), and the same rays hit as in trimesh/embree's
    cast, at the same points but where the referee finds the walk's (embree's float32 test)."""
    rng = np.random.default_rng(12)
    n = 420
    x = np.linspace(0, 6 * np.pi, n)
    z = 300.0 + 40.0 * np.sin(x)[:, None] * np.cos(0.7 * x)[None, :] + 3.0 * rng.standard_normal((n, n))
    step = np.rad2deg(7.7 / A)  # 7.7 m on the meridian
    make = lambda: DEM.from_array(z, 36.5, -84.3, step, step / np.cos(np.deg2rad(36.5)))
    dem13 = make()
    los = random_oblique_rays(dem13, 6000, np.random.default_rng(13), frame_angle_deg=(0.0, 82.0))
    assert terrain._exact_tables(dem13)["block"] == 13
    hit13 = intersect_dem(los, dem13, "exact", dem_model="triangles")
    monkeypatch.setattr(terrain, "BLOCK_GROUND_M", 0.0)
    dem8 = make()
    assert terrain._exact_tables(dem8)["block"] == 8
    hit8 = intersect_dem(los, dem8, "exact", dem_model="triangles")
    ok = hit8.status == Status.OK
    assert ok.sum() > 3000
    assert np.array_equal(hit13.status, hit8.status)
    assert np.array_equal(hit13.ecef, hit8.ecef, equal_nan=True)
    assert np.array_equal(hit13.h, hit8.h, equal_nan=True)
    from geoloc.surfaces.referee import judge

    _hit, _mesh, fr, loc, idx, _tri, apart = walk_against_embree(dem8, los)  # checks: the same rays hit
    assert np.median(apart) < 1e-8
    # where embree's float32 test lands elsewhere (measured: 26 um on one ray of these), the
    # extended-precision referee finds the walk's hit (docs/terrain.md, where embree differs)
    o, d = los.origin_ecef.reshape(-1, 3), los.direction_ecef.reshape(-1, 3)
    for k in np.nonzero(apart > 1e-7)[0]:
        r = idx[k]
        assert judge(dem8, o[r], d[r], hit8.ecef[r], fr.to_ecef(loc[k]))[0] in ("a", "both"), r


def test_table_offsets_are_conservative_and_tight():
    """terrain._offsets32: the cell and block tables hold float32 offsets from the floor's
    (1/(a+h_floor)^2, 1/(b+h_floor)^2). Added back in float64 (as the kernel does) they give
    an ellipsoid never smaller than the one of H (a skipped cell stays clear: the decoded
    height is >= H, in both semi-axes), and at most 2.5e-3 m larger for H up to 10 km above
    the floor (rounded down plus one more float32 step: two steps of 1.2e-7 relative on
    H - h_floor, 2.4e-3 m there); the absolute float32 form this replaced lost up to
    0.4 m. NaN (no data) stays NaN."""
    rng = np.random.default_rng(9)
    h_floor = -431.0  # the Dead Sea shore, below the ellipsoid: offsets of both signs of H
    H = np.concatenate([h_floor + rng.uniform(0.0, 10_000.0, 200_000), [h_floor + 1e-6, np.nan]])
    inv64 = np.stack([1 / (A + H) ** 2, 1 / (B + H) ** 2], -1)
    off = terrain._offsets32(inv64.copy(), h_floor)  # it overwrites its argument
    assert off.dtype == np.float32
    ref = np.array([1.0 / ((A + h_floor) * (A + h_floor)), 1.0 / ((B + h_floor) * (B + h_floor))])
    dec = ref + off.astype(np.float64)
    Ha = 1.0 / np.sqrt(dec[:, 0]) - A
    Hb = 1.0 / np.sqrt(dec[:, 1]) - B
    fin = ~np.isnan(H)
    assert np.isnan(dec[~fin]).all()
    # compared as squared reciprocals (exact in the test's float64): never a smaller ellipsoid
    assert (dec[fin] <= inv64[fin]).all()
    assert (Ha[fin] - H[fin]).max() < 2.5e-3 and (Hb[fin] - H[fin]).max() < 2.5e-3
    assert (Ha[fin] - H[fin]).min() > -1e-6  # the sqrt's own rounding of a + H, ~1e-9 m
