"""Line of sight x DEM (geoloc.surfaces.terrain): synthetic DEMs with independent answers, statuses, traces."""

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import brentq

from geoloc.frames.enu import EnuFrame
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import ray_geodetic_height
from geoloc.surfaces.terrain import intersect_dem

r = np.deg2rad


def rays_enu(frame: EnuFrame, origins_enu, dirs_enu):
    o = frame.to_ecef(np.asarray(origins_enu, float))
    d = np.einsum("ij,...j->...i", frame.R_ecef_enu, np.asarray(dirs_enu, float))
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    o, d = np.broadcast_arrays(o, d)
    return LineOfSight(o, d, np.zeros(o.shape[:-1], np.uint8))


def reference_first_hit(o, d, terrain_h, s_max, ds=0.5):
    """First root of h_ray(s) - terrain(lat, lon) by a dense scan + brentq, with the core's
    ECEF -> geodetic conversion and an independent terrain function (deg in)."""

    def g(s):
        lat, lon, h = ecef_to_geodetic(o + np.asarray(s)[..., None] * d)
        return h - terrain_h(np.rad2deg(lat), np.rad2deg(lon))

    s = np.arange(0.0, s_max, ds)
    gs = g(s)
    k = np.flatnonzero((gs[:-1] > 0) & (gs[1:] <= 0))[0]
    return brentq(lambda x: float(np.ravel(g(np.array(x)))[0]), s[k], s[k + 1], xtol=1e-9)


def hit_s(hit, los):
    return np.sum((hit.ecef - los.origin_ecef) * los.direction_ecef, -1)


# --------------------------------------------------------------------------- flat
def test_flat_exact_equals_constant_height_surface():
    dem = DEM.from_array(np.full((21, 21), 250.0), 36.1, 78.0, 0.01, 0.01)
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    off = r(np.array([0, 30, 60, 75]))
    az = r(np.array([0, 100, 200, 300]))
    los = rays_enu(fr, [0, 0, 3000.0], np.c_[np.sin(az) * np.sin(off), np.cos(az) * np.sin(off), -np.cos(off)])
    ref = ray_geodetic_height(los.origin_ecef, los.direction_ecef, 250.0)  # core, Newton on h
    hit = intersect_dem(los, dem, "exact")
    assert (hit.status == Status.OK).all()
    # goal: exact to 1 cm
    assert np.max(np.linalg.norm(hit.ecef - ref.ecef, axis=-1)) < 0.01


# --------------------------------------------------------------------------- tilted plane
def plane_dem():
    lat_n, lon_w, step = 36.1, 78.0, 0.005
    la = lat_n - step * np.arange(41)
    lo = lon_w + step * np.arange(41)
    LO, LA = np.meshgrid(lo, la)

    def f(lat_deg, lon_deg):  # metres per degree: bilinear reproduces a plane in (lat, lon) exactly
        return 300.0 + 2000.0 * (lon_deg - 78.1) + 1500.0 * (lat_deg - 36.0)

    return DEM.from_array(f(LA, LO), lat_n, lon_w, step, step), f


def test_tilted_plane_all_methods():
    dem, f = plane_dem()
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    off = r(np.array([20, 45, 60, 70]))
    az = r(np.array([10, 130, 250, 330]))
    los = rays_enu(fr, [0, 0, 4000.0], np.c_[np.sin(az) * np.sin(off), np.cos(az) * np.sin(off), -np.cos(off)])
    s_ref = np.array([reference_first_hit(los.origin_ecef[k], los.direction_ecef[k], f, 20000.0) for k in range(4)])
    p_ref = los.origin_ecef + s_ref[:, None] * los.direction_ecef
    h_ref = ecef_to_geodetic(p_ref)[2]
    ex = intersect_dem(los, dem, "exact")
    assert (ex.status == Status.OK).all()
    assert np.max(np.linalg.norm(ex.ecef - p_ref, axis=-1)) < 0.01  # goal: 1 cm
    eps = 2.0
    st = intersect_dem(los, dem, "steps", eps_h=eps)
    # [Q17]: the first H_n below the terrain; the crossing lies within one step above it.
    # 0.01 m: the inflated ellipsoid's height departs from h_T by millimetres at these heights.
    assert np.all(st.h <= h_ref + 0.01) and np.all(st.h > h_ref - eps - 0.01)
    thr = 0.5
    bi = intersect_dem(los, dem, "bisect", threshold=thr)
    # [L23]'s contract: |H - h_DEM| < threshold at the answer (same 0.01 m for the inflated surface)
    assert np.all(np.abs(bi.h - dem.height(bi.lat, bi.lon)) < thr + 0.01)
    assert not bi.hidden.any()
    # evaluations: steps from H_max down, about (H_max - h) / eps_h + 1
    n_expected = np.floor((dem.max_height() - h_ref) / eps) + 1
    assert np.all(np.abs(st.dem_evaluations - n_expected) <= 1)


# --------------------------------------------------------------------------- hill
def hill_dem():
    step = 0.001
    la = 36.05 - step * np.arange(101)
    lo = 78.05 + step * np.arange(101)
    LO, LA = np.meshgrid(lo, la)
    z = 200.0 + 600.0 * np.exp(-(((LO - 78.1) / 0.012) ** 2 + ((LA - 36.0) / 0.01) ** 2))
    dem = DEM.from_array(z, 36.05, 78.05, step, step)
    interp = RegularGridInterpolator(
        (la[::-1], lo), z[::-1], method="linear", bounds_error=False
    )  # independent bilinear
    return dem, lambda lat_deg, lon_deg: interp(np.stack(np.broadcast_arrays(lat_deg, lon_deg), -1))


@pytest.mark.parametrize("surface", ["bilinear", "triangles"])
def test_hill_exact(surface):
    dem, f = hill_dem()
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    rng = np.random.default_rng(7)
    n = 12
    off = r(rng.uniform(45, 75, n))
    az = rng.uniform(0, 2 * np.pi, n)
    d = np.c_[np.sin(az) * np.sin(off), np.cos(az) * np.sin(off), -np.cos(off)]
    aim = np.c_[rng.uniform(-1500, 1500, n), rng.uniform(-1500, 1500, n), np.full(n, 500.0)]
    o = aim - (2500 / np.cos(off))[:, None] * d
    los = rays_enu(fr, o, d)
    hit = intersect_dem(los, dem, "exact", dem_model=surface)
    assert (hit.status == Status.OK).all()
    if surface == "bilinear":
        s_ref = np.array([reference_first_hit(los.origin_ecef[k], los.direction_ecef[k], f, 15000.0) for k in range(n)])
        assert np.max(np.abs(hit_s(hit, los) - s_ref)) < 0.01  # goal: 1 cm
    else:
        import trimesh

        m = dem.to_trimesh()
        frm = m.metadata["enu_frame"]
        # pure-python trimesh backend on this small mesh (20 000 triangles, 12 rays)
        tri = trimesh.ray.ray_triangle.RayMeshIntersector(m)
        loc, idx, _ = tri.intersects_location(
            frm.from_ecef(los.origin_ecef), frm.vector_from_ecef(los.direction_ecef), multiple_hits=False
        )
        assert sorted(idx) == list(range(n))
        mine = frm.from_ecef(hit.ecef)[idx]
        # the same triangles in float64 on both sides: rounding only (measured 8e-10 m); the
        # docs/tour_terrain.md's 7e-8 m for the embree comparison (test_terrain_trimesh.py) bounds it
        assert np.max(np.linalg.norm(mine - loc, axis=-1)) < 7e-8


# --------------------------------------------------------------------------- ridge and valley
def ridge_dem():
    """Terrain that depends on longitude only: a 300 m ridge 0.0025 deg wide on a 0 m floor."""
    step_lon, step_lat = 0.0005, 0.005
    lo = 78.0 + step_lon * np.arange(121)
    la = 36.05 - step_lat * np.arange(21)
    peak = 78.02

    def prof(lon_deg):
        return 300.0 * np.clip(1 - np.abs(np.asarray(lon_deg) - peak) / 0.0025, 0, None)

    z = np.tile(prof(lo), (len(la), 1))
    return DEM.from_array(z, 36.05, 78.0, step_lat, step_lon), (lambda lat_deg, lon_deg: prof(lon_deg))


def test_ridge_in_front_of_valley_grazing():
    dem, f = ridge_dem()
    fr = EnuFrame.from_deg(36.0, 78.002, 0.0)
    # due east, 6.8 deg below the horizon (frame angle 83 deg): meets the ridge face at about
    # 213 m, comes out of its back at about 196 m and reaches the floor 1.6 km further on.
    d = np.array([1.0, 0.0, -0.12])
    los = rays_enu(fr, [[0, 0, 400.0], [0, 50.0, 400.0]], d)
    s_ref = np.array([reference_first_hit(los.origin_ecef[k], los.direction_ecef[k], f, 4000.0) for k in range(2)])
    ex = intersect_dem(los, dem, "exact")
    assert np.max(np.abs(hit_s(ex, los) - s_ref)) < 0.01  # goal: 1 cm
    assert np.all(ex.h > 150)  # the ridge, not the floor
    st = intersect_dem(los, dem, "steps", eps_h=1.0)
    assert np.all(np.abs(st.h - ex.h) < 1.0 + 0.01)  # within eps_h (0.01 m: inflated surface)
    bi = intersect_dem(los, dem, "bisect", threshold=1.0)
    assert (bi.status == Status.OK).all()
    assert np.all(bi.h < 2.0)  # [L23]'s halving lands on the floor behind the ridge...
    assert bi.hidden.all()  # ...and is flagged
    ex_tri = intersect_dem(los, dem, "exact", dem_model="triangles")
    assert np.all(ex_tri.h > 150)


def test_hidden_flag_sees_a_one_cell_notch():
    """The bisection's answer is hidden behind terrain that the ray leaves for only one cell.

    A 300 m plateau (east of a face the ray meets at about 276 m) with a V-shaped notch,
    one node at 0 m, where the ray is 150 m up: the notch is one cell (45 m) wide at that
    height. [L23]'s first midpoint (150 m) lands in the notch, so the halving converges on
    the notch's far wall (149 m), behind the plateau's face. The ray comes out of the
    terrain only inside the notch: the flag must see a one-cell emergence (the solver
    samples every quarter cell; every 4 cells would step over it)."""
    step_lon, step_lat = 0.0005, 0.005
    lo = 78.0 + step_lon * np.arange(121)
    la = 36.05 - step_lat * np.arange(21)
    fr = EnuFrame.from_deg(36.0, 78.002, 0.0)
    d = np.array([1.0, 0.0, -0.12])
    los = rays_enu(fr, [[0, 0, 400.0], [0, 50.0, 400.0]], d)

    def lon_at_height(hh):  # the ray's longitude where it is hh above the ellipsoid (ENU ~ flat)
        s = (400.0 - hh) / 0.12 * np.hypot(1.0, 0.12)
        return np.rad2deg(ecef_to_geodetic(los.origin_ecef[0] + s * los.direction_ecef[0])[1])

    prof = np.where(lo >= lon_at_height(280.0), 300.0, 0.0)
    k = int(np.argmin(np.abs(lo - lon_at_height(150.0))))
    prof[k] = 0.0
    dem = DEM.from_array(np.tile(prof, (len(la), 1)), 36.05, 78.0, step_lat, step_lon)
    cell_m = np.deg2rad(step_lon) * 6378137.0 * np.cos(np.deg2rad(36.05))
    assert 40.0 < cell_m < 50.0
    ex = intersect_dem(los, dem, "exact")
    bi = intersect_dem(los, dem, "bisect", threshold=1.0)
    assert (ex.status == Status.OK).all() and (bi.status == Status.OK).all()
    assert np.all(np.abs(ex.h - 276.1) < 1.0)  # the face
    assert np.all(np.abs(bi.h - 150.0) < 2.0)  # the notch's far wall
    # the emergence is the notch alone: where the ray is above the terrain between the two
    # answers, densely sampled here (1 m), and it spans about one cell
    s0, s1 = hit_s(ex, los)[0], hit_s(bi, los)[0]
    s = np.arange(s0 + 1.0, s1 - 0.5, 1.0)
    lat, lon, h = ecef_to_geodetic(los.origin_ecef[0] + s[:, None] * los.direction_ecef[0])
    above = s[h > dem.height(lat, lon)]
    assert above.size and 0.5 * cell_m < above.max() - above.min() + 1.0 < 1.5 * cell_m
    assert bi.hidden.all()
    assert not ex.hidden.any()


# --------------------------------------------------------------------------- statuses, batches, traces
@pytest.mark.parametrize("method", ["steps", "bisect", "exact"])
def test_statuses(method):
    z = np.full((21, 21), 100.0)
    z[8:12, 8:12] = np.nan
    dem = DEM.from_array(z, 36.1, 78.0, 0.01, 0.01)
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    o = np.array([[0, 0, 3000.0], [3000, 3000, 3000.0], [-2000, 3000, 3000.0], [np.nan, 0, 3000.0]])
    d = np.array([[0, 0, 1.0], [0.0, 0.0, -1.0], [-1, 0, -0.1], [0, 0, -1.0]])
    los = rays_enu(fr, o, d)
    hit = intersect_dem(los, dem, method)
    assert list(hit.status) == [Status.SKY, Status.OK, Status.LEFT_DEM, Status.INVALID_INPUT]
    los2 = rays_enu(fr, [0, 0, 3000.0], [0, 0, -1.0])  # straight down into the hole
    assert int(intersect_dem(los2, dem, method).status) == Status.NODATA
    assert np.isnan(hit.lat[[0, 2, 3]]).all() and np.isfinite(hit.lat[1])


def test_batch_shape_and_trace():
    dem, f = hill_dem()
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    rng = np.random.default_rng(1)
    d = np.c_[rng.uniform(-0.5, 0.5, 6), rng.uniform(-0.5, 0.5, 6), -np.ones(6)].reshape(2, 3, 3)
    los = rays_enu(fr, [0, 0, 3000.0], d)
    for method in ("steps", "bisect", "exact"):
        hit = intersect_dem(los, dem, method, eps_h=5.0, threshold=1.0, trace=True)
        assert hit.lat.shape == (2, 3) and hit.ecef.shape == (2, 3, 3) and hit.status.shape == (2, 3)
        t = hit.trace.ray((1, 2))
        assert len(t["H"]) == hit.dem_evaluations[1, 2]
        # every trace point lies on the line of sight at its trial height (core conversion;
        # 0.01 m: inflated ellipsoid vs geodetic height) and h_dem is the DEM there
        lat, lon, h = ecef_to_geodetic(t["ecef"])
        assert np.allclose(h, t["H"], atol=0.01)
        o, dd = los.origin_ecef[1, 2], los.direction_ecef[1, 2]
        along = t["ecef"] - o
        assert np.allclose(np.cross(along, dd), 0, atol=1e-6 * np.linalg.norm(along, axis=-1).max())
        assert np.allclose(t["h_dem"], dem.height(lat, lon), equal_nan=True)
        if method == "steps":
            assert np.allclose(np.diff(t["H"]), -5.0)
            assert np.all(t["H"][:-1] > t["h_dem"][:-1]) and t["H"][-1] <= t["h_dem"][-1]
        if method == "bisect":
            assert np.allclose(t["H"], 0.5 * (t["lo"] + t["hi"]))
            assert np.allclose(np.diff(t["hi"] - t["lo"]), -0.5 * (t["hi"] - t["lo"])[:-1])
        if method == "exact":
            assert t["cell"].shape[1] == 2 and (t["cell"] >= 0).all()


def test_scalar_vermeille_matches_core():
    from geoloc.geodesy._nbgeo import geodetic, geodetic_up

    rng = np.random.default_rng(2)
    p = geodetic_to_ecef(r(rng.uniform(-89, 89, 50)), r(rng.uniform(-180, 180, 50)), rng.uniform(-400, 9e4, 50))
    ref = np.array(ecef_to_geodetic(p))
    for k in range(50):
        got = geodetic(*p[k])
        # same formula, compiled: angles to 1e-12 rad, height to 1e-6 m (float rounding)
        assert np.allclose(got[:2], ref[:2, k], rtol=0, atol=1e-12)
        assert abs(got[2] - ref[2, k]) < 1e-6
        lat, lon, h, nx, ny, nz = geodetic_up(*p[k])
        assert np.allclose(
            [nx, ny, nz], [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], atol=1e-12
        )


def test_bad_arguments():
    dem, _ = plane_dem()
    los = rays_enu(EnuFrame.from_deg(36, 78.1, 0), [0, 0, 3000.0], [0, 0, -1.0])
    with pytest.raises(ValueError, match="method"):
        intersect_dem(los, dem, "newton")
    with pytest.raises(ValueError, match="eps_h"):
        intersect_dem(los, dem, "steps", eps_h=0)
    with pytest.raises(ValueError, match="dem_model"):
        intersect_dem(los, dem, "exact", dem_model="quads")
    with pytest.raises(TypeError, match="surface"):  # dem_model's old alias is gone: "surface" names one thing
        intersect_dem(los, dem, "exact", surface="triangles")


def test_bowring_latlon_for_cell_lookup():
    from geoloc.surfaces.terrain_numba import latlon

    rng = np.random.default_rng(5)
    lat = r(rng.uniform(-85, 85, 200))
    lon = r(rng.uniform(-180, 180, 200))
    p = geodetic_to_ecef(lat, lon, rng.uniform(-1000, 20000, 200))
    got = np.array([latlon(*q) for q in p])
    # documented bound 1e-9 rad (6 mm): far below the 1e-5 rad of a 3'' cell
    assert np.max(np.abs(got[:, 0] - lat)) < 1e-9
    assert np.max(np.abs(got[:, 1] - lon)) < 1e-12


# --------------------------------------------------------------------------- origin below the terrain
def test_below_terrain_flags_the_same_origins_as_sampling_every_one():
    """below_terrain first sets aside the origins outside the ellipsoid inflated to the DEM's highest
    node plus the margin, without sampling them: that must set aside no origin below the terrain.
    The reference is independent of that test: pyproj's geodetic height of each origin (EPSG:4978
    to 4979) against the DEM's bilinear height under it. Origins are spread 60 m below to 60 m
    above the highest node (where the test decides) and near the ground."""
    import pyproj

    from geoloc.surfaces.terrain import below_terrain

    rng = np.random.default_rng(3)
    z = 100.0 + 400.0 * rng.random((31, 41))  # 100..500 m, one highest node
    dem = DEM.from_array(z, 36.3, 78.0, 0.01, 0.01)
    n = 4000
    lat = rng.uniform(36.0, 36.3, n)
    lon = rng.uniform(78.0, 78.4, n)
    h = np.where(rng.random(n) < 0.5, dem.max_height() + rng.uniform(-60.0, 60.0, n), rng.uniform(0.0, 600.0, n))
    lla_to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    o = np.stack(lla_to_ecef.transform(lon, lat, h), -1)
    st = np.zeros(n, np.uint8)
    st[:10] = Status.SKY  # a ray that is not OK keeps its status
    below_terrain(o, st, dem)
    ecef_to_lla = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon_p, lat_p, h_p = ecef_to_lla.transform(o[:, 0], o[:, 1], o[:, 2])
    ground = dem.height(r(lat_p), r(lon_p))
    want = np.where(h_p < ground, Status.BELOW_TERRAIN, Status.OK).astype(np.uint8)
    want[:10] = Status.SKY
    # pyproj's heights and the core's agree to ~1e-9 m: no origin lies that close to the ground here
    assert np.min(np.abs(h_p - ground)) > 1e-6
    assert 100 < np.sum(want == Status.BELOW_TERRAIN) < n - 100  # both kinds, and many of each
    assert st.tolist() == want.tolist()


@pytest.mark.parametrize("h_m", [-11_000.0, 0.0, 9_000.0, 100_000.0])
def test_surface_of_constant_height_lies_inside_the_ellipsoid_inflated_by_the_margin(h_m):
    """The premise of below_terrain's first test: the points of geodetic height h (pyproj, every
    0.01 deg of latitude) lie inside the ellipsoid with semi-axes (a + h + 1 m, b + h + 1 m)."""
    import pyproj

    from geoloc.geodesy.ellipsoid import A, B

    lat = np.linspace(-90.0, 90.0, 18001)
    x, y, z = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        np.zeros_like(lat), lat, np.full_like(lat, h_m)
    )
    q = (x * x + y * y) / (A + h_m + 1.0) ** 2 + z * z / (B + h_m + 1.0) ** 2
    # 1 - q >= 2.6e-7 at 100 km (0.83 m inside); rounding is ~1e-16
    assert q.max() < 1.0 - 1e-7
