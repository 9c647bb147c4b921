"""The DEM type (geoloc.surfaces.dem): datum, bilinear sampling, bounds, no-data, CRS, meshes."""

from pathlib import Path

import numpy as np
import pytest
import rasterio

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.status import Status
from geoloc.surfaces.dem import DEM

ASSETS = Path(__file__).resolve().parents[2] / "assets" / "dem"
SRTM = ASSETS / "srtm_jacksboro.tif"
ETOPO = ASSETS / "etopo5_flight_area.tif"
r = np.deg2rad


def test_srtm_crop_matches_matplotlib_sample():
    # The committed crop must hold matplotlib's sample heights, row 0 north, edges from the npz keys.
    import matplotlib.cbook as cbook

    d = cbook.get_sample_data("jacksboro_fault_dem.npz")
    with rasterio.open(SRTM) as src:
        assert np.array_equal(src.read(1), d["elevation"])
        assert src.bounds.top == pytest.approx(float(d["ymin"]), abs=1e-9)  # ymin is the north edge
        assert src.bounds.left == pytest.approx(float(d["xmin"]), abs=1e-9)
        assert "EGM96" in src.tags()["VERTICAL_DATUM"] and "LICENCE" in src.tags()


def test_heights_at_nodes_are_orthometric_plus_n():
    dem = DEM.open(SRTM)  # datum egm96 by default
    with rasterio.open(SRTM) as src:
        z = src.read(1).astype(float)
        lon_deg, lat_deg = src.xy(100, 200)  # pixel centre = node, computed by rasterio
    h = dem.height(r(lat_deg), r(lon_deg))
    # h = H + N (docs/method.md section 4); 1e-6 m: only float rounding of the node position
    assert h == pytest.approx(z[100, 200] + egm96_undulation(r(lat_deg), r(lon_deg)), abs=1e-6)
    ell = DEM.open(SRTM, datum="ellipsoid")
    assert ell.height(r(lat_deg), r(lon_deg)) == pytest.approx(z[100, 200], abs=1e-9)


def test_bilinear_against_scipy():
    from scipy.interpolate import RegularGridInterpolator

    dem = DEM.open(SRTM, datum="ellipsoid")
    with rasterio.open(SRTM) as src:
        z = src.read(1).astype(float)
        t = src.transform
    lats = t.f + t.e / 2 + t.e * np.arange(z.shape[0])
    lons = t.c + t.a / 2 + t.a * np.arange(z.shape[1])
    ref = RegularGridInterpolator((lats[::-1], lons), z[::-1], method="linear")
    rng = np.random.default_rng(0)
    w, s, e, n = dem.bounds_deg
    la, lo = rng.uniform(s, n, 2000), rng.uniform(w, e, 2000)
    # same bilinear formula, different code: agreement to float rounding (1e-6 m)
    assert np.max(np.abs(dem.height(r(la), r(lo)) - ref(np.c_[la, lo]))) < 1e-6


def test_bounds_max_min_and_status():
    dem = DEM.open(ETOPO)
    w, s, e, n = dem.bounds_deg
    assert (w, s, e, n) == pytest.approx((76.0, 34.0, 83.0, 38.0), abs=1e-9)  # node hull of the crop
    with rasterio.open(ETOPO) as src:
        z = src.read(1).astype(float)
    lat_deg, lon_deg = dem.node_latlon_deg()
    hn = z + egm96_undulation(r(lat_deg), r(lon_deg))
    assert dem.max_height() == pytest.approx(hn.max(), abs=1e-6)
    assert dem.min_height() == pytest.approx(hn.min(), abs=1e-6)
    reg = (80.0, 35.0, 81.0, 36.0)
    sel = (lon_deg >= 80 - 1e-9) & (lon_deg <= 81 + 1e-9) & (lat_deg >= 35 - 1e-9) & (lat_deg <= 36 + 1e-9)
    assert dem.max_height(reg) == pytest.approx(hn[sel].max(), abs=1e-6)
    h, st = dem.sample(r(np.array([35.5, 39.0, np.nan])), r(np.array([80.0, 80.0, 80.0])))
    assert list(st) == [Status.OK, Status.LEFT_DEM, Status.INVALID_INPUT]
    assert np.isfinite(h[0]) and np.isnan(h[1:]).all()
    with pytest.raises(ValueError, match="region"):
        dem.max_height((81, 35, 80, 36))


def test_from_array_nodata_and_validation():
    z = np.array([[10.0, 20.0, 30.0], [40.0, -9999.0, 60.0], [70.0, 80.0, 90.0]])
    dem = DEM.from_array(z, 1.0, 2.0, 0.5, 0.5, nodata=-9999.0)
    # cell (0, 0) touches the missing node -> NODATA; a point on the outer edge of cell (0,0) too
    h, st = dem.sample(r(np.array([0.8, 1.0])), r(np.array([2.2, 2.0])))
    assert st[0] == Status.NODATA and st[1] == Status.OK and h[1] == pytest.approx(10.0)
    with pytest.raises(ValueError, match="dlat_deg"):
        DEM.from_array(z, 1.0, 2.0, -0.5, 0.5)
    with pytest.raises(ValueError, match="datum"):
        DEM.from_array(z, 1.0, 2.0, 0.5, 0.5, datum="wgs84")
    with pytest.raises(FileNotFoundError):
        DEM.open("no/such/file.tif")


def test_projected_crs_via_pyproj():
    import pyproj

    # UTM zone 17N DEM whose height is linear in easting/northing: bilinear reproduces it exactly
    x0, y0, dx = 500000.0, 4060000.0, 100.0
    X, Y = np.meshgrid(x0 + dx * np.arange(30), y0 - dx * np.arange(20))
    z = 100.0 + 0.01 * (X - x0) + 0.02 * (y0 - Y)
    dem = DEM.from_array(z, y0, x0, dx, dx, crs="EPSG:32617")
    tr = pyproj.Transformer.from_crs("EPSG:32617", "EPSG:4326", always_xy=True)
    lo, la = tr.transform(x0 + 1234.5, y0 - 987.6)
    # 1e-6 m: pyproj's round trip is sub-micrometre
    assert dem.height(r(la), r(lo)) == pytest.approx(100 + 12.345 + 19.752, abs=1e-6)
    w, s, e, n = dem.bounds_deg
    assert s < la < n and w < lo < e


def test_mesh_vertices_and_enu():
    dem = DEM.open(SRTM)
    v, f = dem.mesh()
    nr, nc = dem.shape
    assert v.shape == (nr * nc, 3) and f.shape == (2 * (nr - 1) * (nc - 1), 3)
    lat_deg, lon_deg = dem.node_latlon_deg()
    # vertex k is node k in ECEF at its ellipsoidal height (independent: core conversion)
    k = 5 * nc + 7
    ref = geodetic_to_ecef(r(lat_deg.flat[k]), r(lon_deg.flat[k]), dem.grid.values.flat[k])
    assert np.allclose(v[k], ref, atol=1e-6)
    m = dem.to_trimesh(stride=4)
    fr = m.metadata["enu_frame"]
    # ENU vertices are small (float32-safe) and map back to ECEF
    assert np.abs(m.vertices).max() < 3e4
    assert np.allclose(fr.to_ecef(m.vertices[0]), dem.to_trimesh(stride=4, frame="ecef").vertices[0], atol=1e-6)
