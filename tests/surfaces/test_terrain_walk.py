"""The exact walk's outputs: hit coordinates against the core's conversion, bilinear
hits on the surface at grazing angles, and hits on both sides of 180 deg against the
referee (triangles) and a marched reference (bilinear); the equator / antimeridian case
against embree is in test_terrain_trimesh.py."""

from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

ASSETS = Path(__file__).resolve().parents[2] / "assets" / "dem"


@pytest.mark.parametrize("name", ["srtm_jacksboro", "etopo5_flight_area"])
@pytest.mark.parametrize("surface", ["triangles", "bilinear"])
def test_hit_coordinates_match_core_conversion(name, surface):
    """The kernel converts its hits from the corner of their cell (Newton on the latitude,
    a series for the longitude); the core's Vermeille closed form is the reference.
    1e-12 rad is 6 micrometres, 1e-6 m far above the two methods' rounding (measured
    3e-16 rad, 4e-9 m) and far below any use."""
    dem = DEM.open(ASSETS / f"{name}.tif")
    los = random_oblique_rays(dem, 5000, np.random.default_rng(5), frame_angle_deg=(0.0, 89.0), inner=1.0)
    hit = intersect_dem(los, dem, "exact", dem_model=surface)
    ok = hit.status == Status.OK
    assert ok.sum() > 4000
    lat, lon, h = ecef_to_geodetic(hit.ecef)
    assert np.array_equal(np.isfinite(lat), ok)  # NaN exactly where there is no hit
    assert np.abs(hit.lat - lat)[ok].max() < 1e-12
    assert np.abs(hit.lon - lon)[ok].max() < 1e-12
    assert np.abs(hit.h - h)[ok].max() < 1e-6
    rng = np.linalg.norm(hit.ecef - los.origin_ecef, axis=-1)
    assert np.abs(hit.slant_range - rng)[ok].max() < 1e-6


def test_bilinear_grazing_hits_lie_on_the_surface():
    """Grazing rays (to 89.9 deg off nadir) over the ETOPO5 crop's mountains: every hit is
    on the bilinear surface. Newton polishes to 1e-7 m along the ray; at a near-tangency
    the model root is kept (0.1 mm off, measured), so 1 mm. A vanishing Newton slope
    once sent one of these rays to s = -7.5e13 m with status OK. Cameras that this
    generator puts under a mountain (range 0: the line starts inside the terrain) are
    left out."""
    dem = DEM.open(ASSETS / "etopo5_flight_area.tif")
    los = random_oblique_rays(dem, 20_000, np.random.default_rng(3), frame_angle_deg=(0.0, 89.9), inner=1.2)
    hit = intersect_dem(los, dem, "exact")
    ok = (hit.status == Status.OK) & (hit.slant_range > 0)
    assert ok.sum() > 13_000
    res = np.abs(hit.h - dem.height(hit.lat, hit.lon))[ok]
    assert np.isfinite(res).all()
    assert res.max() < 1e-3


def test_readme_evaluations_per_ray_table():
    """docs/tour_terrain.md / docs/terrain.md: DEM evaluations per ray on the bench's 10 000 rays (seed 0,
    frame angle 45-82 deg, SRTM crop; ``python benchmarks/bench_terrain.py`` part (a)):
    counts, not timings, so deterministic. Exact: 6.3 cells or blocks visited per ray (a
    skip table that never skips gives dozens). Held to half a unit of the printed digit;
    the steps column 0.01 more: the docs rounded the bench's 2-decimal print (60.55,
    13.35) a second time (60.6, 13.4; the means are 60.547 and 13.348)."""
    from geoloc.geodesy.ellipsoid import A

    dem = DEM.open(ASSETS / "srtm_jacksboro.tif")
    los = random_oblique_rays(dem, 10_000, np.random.default_rng(0), frame_angle_deg=(45.0, 82.0))
    g = dem.grid
    lat_mid = np.deg2rad(0.5 * (g.lat_north_deg + g.lat_south_deg))
    cell_m = 0.5 * np.deg2rad(g.dlat_deg) * A + 0.5 * np.deg2rad(g.dlon_deg) * A * np.cos(lat_mid)
    assert round(cell_m, 1) == 83.6  # docs: "cell ~ 84 m", thresholds 8.4, 41.8, 83.6 m
    ex = intersect_dem(los, dem, "exact")
    ok = ex.status == Status.OK
    assert ok.all()
    assert ex.dem_evaluations.mean() == pytest.approx(6.3, abs=0.05)
    for frac, steps, bisect, saves, hidden in (
        (0.1, 60.6, 4.6, 92.4, 5.8),
        (0.5, 13.4, 2.6, 80.3, 5.7),
        (1.0, 7.4, 2.0, 73.1, 5.5),
    ):
        st = intersect_dem(los, dem, "steps", eps_h=frac * cell_m)
        bi = intersect_dem(los, dem, "bisect", threshold=frac * cell_m)
        both = ok & (st.status == Status.OK) & (bi.status == Status.OK)
        ns, nb = st.dem_evaluations[both].mean(), bi.dem_evaluations[both].mean()
        assert ns == pytest.approx(steps, abs=0.06)
        assert nb == pytest.approx(bisect, abs=0.05)
        assert 100 * (1 - nb / ns) == pytest.approx(saves, abs=0.05)
        assert 100 * bi.hidden[both].mean() == pytest.approx(hidden, abs=0.05)


# ---------------------------------------------------------------- across the antimeridian
def _antimeridian_dem(seed):
    """Rough terrain (300-550 m, ellipsoidal) at 40 deg S whose columns cross 180 deg:
    nodes at 179.95 .. 180.05 deg east (the eastern half is -179.95 .. -180 for the core)."""
    rng = np.random.default_rng(seed)
    return DEM.from_array(300.0 + 250.0 * rng.random((21, 21)), -39.95, 179.95, 0.005, 0.005), rng


def _both_sides(lon):
    return (lon > 0).sum() > 20 and (lon < 0).sum() > 20


def test_triangle_hits_across_the_antimeridian_equal_the_referee():
    """Triangle hits of the walk on a DEM across 180 deg equal the referee's
    (geoloc.surfaces.referee: pyproj vertices, every triangle of the DEM tested in extended
    precision, no wrap of its own: node longitudes beyond 180 deg go to PROJ as they are).
    The same rays hit; ranges agree to 1e-6 m (the walk and embree agree to 7e-8 m on the
    SRTM crop; measured here 7.8e-9 m). A second reference beside embree's
    (test_terrain_trimesh.py), so that the walk's longitude wrap is held by two tests."""
    from geoloc.surfaces.referee import referee_first_hit

    dem, rng = _antimeridian_dem(35)
    los = random_oblique_rays(dem, 150, rng, frame_angle_deg=(0.0, 80.0), clearance_m=800.0, inner=0.8)
    hit = intersect_dem(los, dem, "exact", dem_model="triangles")
    ok = hit.status == Status.OK
    assert ok.sum() > 120 and _both_sides(hit.lon[ok])
    window = (0, dem.shape[0] - 1, 0, dem.shape[1] - 1)  # every cell
    ref = np.array([referee_first_hit(dem, o, d, window).range_m for o, d in zip(los.origin_ecef, los.direction_ecef)])
    assert np.array_equal(np.isfinite(ref), ok)
    assert np.abs(hit.slant_range[ok] - ref[ok]).max() < 1e-6


def _bilinear_first_hit(dem, o, d, step_m=0.5):
    """First crossing of one ray with the DEM's bilinear surface, written out: points every
    ``step_m`` along the ray, geodetic by pyproj (EPSG:4978 -> 4979), longitude continued
    past 180 deg, the bilinear interpolation of the four nodes around each, the first sign
    change of h - z bisected to 1e-9 m. inf when the ray leaves the grid first."""
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    g = dem.grid
    z = dem.grid.values
    nr, nc = dem.shape

    def f(s):
        p = o + np.multiply.outer(s, d)
        lon, lat, h = tr.transform(p[..., 0], p[..., 1], p[..., 2])
        lon = np.where(lon < 0.0, lon + 360.0, lon)  # this DEM lies at 179.95 .. 180.05 deg east
        fi = (g.lat_north_deg - lat) / g.dlat_deg
        fj = (lon - g.lon_west_deg) / g.dlon_deg
        inside = (fi >= 0) & (fi <= nr - 1) & (fj >= 0) & (fj <= nc - 1)
        i = np.clip(np.floor(fi).astype(int), 0, nr - 2)
        j = np.clip(np.floor(fj).astype(int), 0, nc - 2)
        v, u = fi - i, fj - j
        zb = (
            (1 - u) * (1 - v) * z[i, j]
            + u * (1 - v) * z[i, j + 1]
            + (1 - u) * v * z[i + 1, j]
            + u * v * z[i + 1, j + 1]
        )
        return h - zb, inside

    s = np.arange(0.0, 30_000.0, step_m)
    r, inside = f(s)
    entered = np.flatnonzero(inside)
    if entered.size == 0:
        return np.inf
    k0 = entered[0]
    leave = np.flatnonzero(~inside[k0:])
    k1 = k0 + (leave[0] if leave.size else inside.size - k0)
    below = np.flatnonzero(r[k0:k1] <= 0.0)
    if below.size == 0:
        return np.inf
    k = k0 + below[0]
    if k == k0:
        return s[k]  # starts under the surface (not generated here)
    lo, hi = s[k - 1], s[k]
    while hi - lo > 1e-9:
        mid = 0.5 * (lo + hi)
        if f(np.array([mid]))[0][0] > 0.0:
            lo = mid
        else:
            hi = mid
    return hi


def test_bilinear_hits_across_the_antimeridian_equal_a_marched_reference():
    """Bilinear hits of the walk on a DEM across 180 deg equal a reference that marches
    each ray in 0.5 m steps (pyproj's geodetic conversion, the bilinear interpolation and
    the longitude continued past 180 deg written here, :func:`_bilinear_first_hit`). The
    same rays hit; ranges agree to 1e-4 m: Newton polishes the walk's root to 1e-7 m and the
    bisection the reference's to 1e-9 m, but a ray could in principle cross and recross
    the surface within one 0.5 m step, unseen by the march; measured 1.5e-8 m."""
    dem, rng = _antimeridian_dem(36)
    los = random_oblique_rays(dem, 120, rng, frame_angle_deg=(0.0, 75.0), clearance_m=800.0, inner=0.8)
    hit = intersect_dem(los, dem, "exact", dem_model="bilinear")
    ok = hit.status == Status.OK
    assert ok.sum() > 100 and _both_sides(hit.lon[ok])
    o = los.origin_ecef
    d = los.direction_ecef / np.linalg.norm(los.direction_ecef, axis=-1, keepdims=True)
    ref = np.array([_bilinear_first_hit(dem, o[k], d[k]) for k in range(len(o))])
    assert np.array_equal(np.isfinite(ref), ok)
    assert np.abs(hit.slant_range[ok] - ref[ok]).max() < 1e-4


def test_bilinear_hits_across_the_equator_and_antimeridian_lie_on_the_surface():
    """On the DEM of test_terrain_trimesh.py's equator / antimeridian case, with the bilinear
    surface: every ray is aimed at a point of the terrain from above it
    (random_oblique_rays), so every ray hits; every hit lies on
    the surface by the DEM's own evaluation (DEM.height, which continues longitudes past
    180 deg on its own), to 1 mm as on ETOPO5 above (Newton to 1e-7 m; measured 6e-9 m);
    and the hits are on both sides of both lines."""
    rng = np.random.default_rng(21)
    n = 41
    dem = DEM.from_array(300.0 + 250.0 * rng.random((n, n)), 0.1, 179.9, 0.005, 0.005)
    los = random_oblique_rays(dem, 3000, rng, frame_angle_deg=(0.0, 85.0), clearance_m=800.0, inner=0.8)
    hit = intersect_dem(los, dem, "exact", dem_model="bilinear")
    assert (hit.status == Status.OK).all()
    res = np.abs(hit.h - dem.height(hit.lat, hit.lon))
    assert res.max() < 1e-3
    assert (hit.lat > 0).sum() > 500 and (hit.lat < 0).sum() > 500
    assert (hit.lon > 0).sum() > 500 and (hit.lon < 0).sum() > 500


# --------------------------------------------------------------------------- the walk's steps, alone
def test_clear_between_agrees_with_the_quadratic_sampled_densely():
    """_clear_between (the skip test of every block and cell) against F(s) = qa s^2 + 2 hb s + qc
    sampled at 4001 points of [s, e] and at its vertex: clear iff the smallest sample is > 0.
    Cases whose smallest value lies within 1e-9 of zero (where sampling cannot decide) are left
    out; the quadratics are drawn so that all three answers occur (positive throughout, a dip
    below zero between the ends, an end below zero)."""
    from geoloc.surfaces.terrain_numba import _clear_between

    rng = np.random.default_rng(11)
    decided = {True: 0, False: 0}
    for _ in range(3000):
        qa = rng.uniform(0.1, 2.0)
        v = rng.uniform(-1.0, 2.0)  # the vertex, sometimes outside [0, 1]
        fmin = rng.uniform(-0.3, 0.3)
        hb, qc = -qa * v, fmin + qa * v * v
        s, e = np.sort(rng.uniform(-0.2, 1.2, 2))
        t = np.linspace(s, e, 4001)
        if s < v < e:
            t = np.append(t, v)
        m = np.min((qa * t + 2.0 * hb) * t + qc)
        if abs(m) < 1e-9:
            continue
        got = _clear_between(qa, hb, qc, s, e)
        assert got == (m > 0.0), (qa, hb, qc, s, e, m)
        decided[bool(got)] += 1
    assert min(decided.values()) > 500
    assert not _clear_between(np.nan, 0.0, 1.0, 0.0, 1.0)  # no data: never skipped


def test_cell_triangles_meet_the_ray_where_trimesh_does():
    """_cell_triangles (a cell's two triangles, nodes from the heights) against trimesh's own ray
    cast (pure Python backend) on DEM.to_trimesh's ECEF mesh of a one-cell DEM: the same rays hit,
    at the same distance. 1e-6 m: both are float64 Moller-Trumbore on coordinates of 6.4e6 m
    (rounding ~1e-9 m a coordinate, grown by the small angle between ray and triangle)."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.terrain import _exact_tables
    from geoloc.surfaces.terrain_numba import _cell_triangles

    dem = DEM.from_array(np.array([[310.0, 402.0], [255.0, 377.0]]), 36.30, 78.10, 0.01, 0.01)
    tab = _exact_tables(dem)
    mesh = dem.to_trimesh(frame="ecef")
    assert len(mesh.faces) == 2
    rng = np.random.default_rng(4)
    n = 400
    fr = EnuFrame.from_deg(36.295, 78.105, 0.0)
    # aimed at points inside and around the cell (0.9 km a side), from 2 km up, 0-70 deg off nadir
    aim = np.stack([rng.uniform(-700, 700, n), rng.uniform(-800, 800, n), np.full(n, 330.0)], -1)
    off, az = np.deg2rad(rng.uniform(0, 70, n)), rng.uniform(0, 2 * np.pi, n)
    d_enu = -np.stack([np.sin(off) * np.sin(az), np.sin(off) * np.cos(az), np.cos(off)], -1)
    o = fr.to_ecef(aim - 2500.0 * d_enu)
    d = np.einsum("ij,nj->ni", fr.R_ecef_enu, d_enu)
    rg, sc, cc, hg = tab["row_geo"], tab["sin_col"], tab["cos_col"], tab["hgt"]
    got = np.array(
        [
            min(
                _cell_triangles(
                    *o[k],
                    *d[k],
                    *rg[0, :4],
                    *rg[1, :4],
                    cc[0],
                    sc[0],
                    cc[1],
                    sc[1],
                    hg[0, 0],
                    hg[0, 1],
                    hg[1, 0],
                    hg[1, 1],
                )
            )
            for k in range(n)
        ]
    )
    loc, idx, _ = RayMeshIntersector(mesh).intersects_location(o, d, multiple_hits=False)
    want = np.full(n, np.inf)
    want[idx] = np.linalg.norm(loc - o[idx], axis=-1)
    assert 100 < np.isfinite(want).sum() < n - 100  # hits and misses both
    assert np.array_equal(np.isfinite(got), np.isfinite(want))
    ok = np.isfinite(want)
    assert np.abs(got[ok] - want[ok]).max() < 1e-6


# the walk's named steps, called alone
def _ecef(lat, lon, h):
    """(lat, lon [rad], h [m]) -> ECEF [m] by pyproj (EPSG:4979 -> EPSG:4978), the outside reference."""
    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.stack(t.transform(np.rad2deg(lon), np.rad2deg(lat), h), -1)


def test_ray_span_starts_and_ends_on_the_heights_along_a_plumb_line():
    """A ray straight down the normal from 5000 m enters the top height h_top at s = 5000 - h_top
    and reaches the floor at 5000 - h_floor (distances along the normal are geodetic heights);
    the walk's surfaces are the inflated ellipsoids (a + h, b + h), which depart from the constant
    height h by millimetres at these heights [Q17 eq. 11] (hence 0.02 m). A direction of any length
    gives the same span (s in metres; 1/|d| returned); a zero direction is invalid, an upward ray SKY."""
    from geoloc.geodesy.ellipsoid import A, B
    from geoloc.surfaces.terrain_numba import _ray_span

    lat, lon = np.deg2rad(36.3), np.deg2rad(78.1)
    o = _ecef(lat, lon, 5000.0)
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    inv = [1.0 / (A + h) ** 2 for h in (1200.0, -50.0)] + [1.0 / (B + h) ** 2 for h in (1200.0, -50.0)]
    ia_top, ia_floor, ib_top, ib_floor = inv
    for scale in (1.0, 7.0):
        st, ux, uy, uz, idn, s, send, st_end = _ray_span(*o, *(-scale * up), ia_top, ib_top, ia_floor, ib_floor)
        assert st == Status.OK and st_end == Status.NO_CONVERGENCE
        assert idn == pytest.approx(1.0 / scale, rel=1e-15)
        assert np.allclose([ux, uy, uz], -up, atol=1e-15)
        assert s == pytest.approx(5000.0 - 1200.0, abs=0.02)
        assert send == pytest.approx(5000.0 + 50.0, abs=0.02)
    assert _ray_span(*o, 0.0, 0.0, 0.0, ia_top, ib_top, ia_floor, ib_floor)[0] == Status.INVALID_INPUT
    assert _ray_span(*o, *up, ia_top, ib_top, ia_floor, ib_floor)[0] == Status.SKY
