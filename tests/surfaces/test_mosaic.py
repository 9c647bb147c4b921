"""DEM mosaics (geoloc.surfaces.mosaic): tiles cut from the bundled SRTM crop with rasterio give the
same hits as the one raster (``DEM.open`` of the original file), opened as a folder, a list and a GDAL
VRT; the tile cache stays within its bound; missing tiles are NODATA; bad tiles are named."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.windows import Window

from geoloc.cli import main
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.mosaic import DemMosaic, TileCache
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

ROOT = Path(__file__).resolve().parents[2]
SRTM = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"
#: Hits agree to 1e-6 m: the exact walk polishes each root to 1e-7 m along the ray, and a window's
#: node positions differ from the whole raster's by float rounding (1e-14 deg, nanometres).
HIT_TOL_M = 1e-6


def cut_tiles(folder, n, overlap, skip=()):
    """Cut the SRTM crop into n x n GeoTIFF tiles with rasterio windows; ``overlap``: tiles share their
    edge node with the next one (as real SRTM tiles do). Returns the tile paths and their node windows."""
    folder.mkdir(parents=True, exist_ok=True)
    paths, wins = [], []
    with rasterio.open(SRTM) as src:
        H, W = src.shape
        rs = np.linspace(0, H, n + 1).astype(int)
        cs = np.linspace(0, W, n + 1).astype(int)
        prof = dict(src.profile)
        for k in ("blockxsize", "blockysize", "tiled"):
            prof.pop(k, None)
        for i in range(n):
            for j in range(n):
                if (i, j) in skip:
                    continue
                r1 = min(rs[i + 1] + overlap, H)
                c1 = min(cs[j + 1] + overlap, W)
                win = Window(cs[j], rs[i], c1 - cs[j], r1 - rs[i])
                p = folder / f"tile_{i}{j}.tif"
                with warnings.catch_warnings():  # rasterio 1.4's own use of Affine's "*" (its business)
                    warnings.simplefilter("ignore", PendingDeprecationWarning)
                    tr = src.window_transform(win)
                with rasterio.open(p, "w", **dict(prof, height=win.height, width=win.width, transform=tr)) as dst:
                    dst.write(src.read(1, window=win), 1)
                paths.append(p)
                wins.append((rs[i], r1, cs[j], c1))
    return paths, wins


def write_vrt(path, tiles, wins):
    """A GDAL VRT (the documented XML: one SimpleSource per tile) of the tiles, by hand: no gdalbuildvrt."""
    with rasterio.open(SRTM) as src:
        H, W, t, wkt = src.height, src.width, src.transform, src.crs.to_wkt()
    srcs = "".join(
        f'<SimpleSource><SourceFilename relativeToVRT="1">{p.name}</SourceFilename><SourceBand>1</SourceBand>'
        f'<SrcRect xOff="0" yOff="0" xSize="{c1 - c0}" ySize="{r1 - r0}"/>'
        f'<DstRect xOff="{c0}" yOff="{r0}" xSize="{c1 - c0}" ySize="{r1 - r0}"/></SimpleSource>'
        for p, (r0, r1, c0, c1) in zip(tiles, wins)
    )
    path.write_text(
        f'<VRTDataset rasterXSize="{W}" rasterYSize="{H}"><SRS>{wkt.replace("&", "&amp;").replace("<", "&lt;")}</SRS>'
        f"<GeoTransform>{t.c!r}, {t.a!r}, 0.0, {t.f!r}, 0.0, {t.e!r}</GeoTransform>"
        f'<VRTRasterBand dataType="Int16" band="1">{srcs}</VRTRasterBand></VRTDataset>'
    )
    return path


@pytest.fixture(scope="module")
def merged():
    return DEM.open(SRTM)


@pytest.fixture(scope="module")
def rays(merged):
    # oblique rays over 95 % of the crop: many cross a seam of a 2 x 2 or 3 x 3 cut
    return random_oblique_rays(merged, 1500, np.random.default_rng(18), inner=0.95)


def _seam_crossings(merged, los, hit, seams_lat, seams_lon):
    """Rays whose segment from the camera's H_max crossing to the hit crosses a seam (independent count)."""
    from geoloc.geodesy.ellipsoid import ecef_to_geodetic
    from geoloc.surfaces.height import ray_inflated_ellipsoid

    top = ray_inflated_ellipsoid(los.origin_ecef, los.direction_ecef, np.full(len(hit.h), merged.max_height()))
    la0, lo0, _ = ecef_to_geodetic(top.ecef)
    la0, lo0 = np.rad2deg(la0), np.rad2deg(lo0)
    la1, lo1 = hit.lat_deg, hit.lon_deg
    cross = np.zeros(len(la0), bool)
    for s in seams_lat:
        cross |= (np.minimum(la0, la1) < s) & (s < np.maximum(la0, la1))
    for s in seams_lon:
        cross |= (np.minimum(lo0, lo1) < s) & (s < np.maximum(lo0, lo1))
    return cross & (hit.status == Status.OK)


def _same_hits(a, b, tol=HIT_TOL_M):
    assert np.array_equal(a.status, b.status)
    ok = a.status == Status.OK
    assert ok.sum() > 0.9 * ok.size
    assert np.max(np.abs(a.ecef[ok] - b.ecef[ok])) < tol
    assert np.max(np.abs(a.slant_range[ok] - b.slant_range[ok])) < tol
    assert np.all(np.isnan(b.ecef[~ok]))


@pytest.mark.parametrize("n,overlap", [(2, 0), (3, 1)])
@pytest.mark.parametrize("how", ["folder", "list", "vrt"])
def test_seam_rays_same_hits_as_merged_raster(tmp_path, merged, rays, n, overlap, how):
    tiles, wins = cut_tiles(tmp_path / "tiles", n, overlap)
    src = {
        "folder": tmp_path / "tiles",
        "list": [str(p) for p in tiles],
        "vrt": write_vrt(tmp_path / "tiles" / "all.vrt", tiles, wins) if how == "vrt" else None,
    }[how]
    if how == "folder":
        assert len(list((tmp_path / "tiles").iterdir())) == n * n
    # a small cache and region bound: the batch is split in several regions
    m = DemMosaic.open(src, cache_bytes=300_000, block=64, max_region_nodes=30_000)
    assert m.shape == merged.shape and len(m.paths) == (1 if how == "vrt" else n * n)
    # bounds of the node hull: rasterio's pixel centres of the original file
    with rasterio.open(SRTM) as s:
        lon_w, lat_n = s.xy(0, 0)
        lon_e, lat_s = s.xy(s.height - 1, s.width - 1)
    assert np.allclose(m.bounds_deg, (lon_w, lat_s, lon_e, lat_n), atol=1e-9)  # 1e-9 deg: float rounding
    assert m.max_height() == pytest.approx(merged.max_height(), abs=1e-9)
    assert m.min_height() == pytest.approx(merged.min_height(), abs=1e-9)
    a = intersect_dem(rays, merged)
    b = m.intersect(rays)
    _same_hits(a, b)
    seams_lat = [lat_n - merged.grid.dlat_deg * k for k in np.linspace(0, merged.shape[0], n + 1).astype(int)[1:-1]]
    seams_lon = [lon_w + merged.grid.dlon_deg * k for k in np.linspace(0, merged.shape[1], n + 1).astype(int)[1:-1]]
    assert (
        _seam_crossings(merged, rays, a, seams_lat, seams_lon).sum() > 50
    )  # the seams are exercised (63 of 1500 rays on 2 x 2)
    assert m.cache.peak_bytes <= m.cache.max_bytes


def test_triangles_and_pieces_of_long_tracks(tmp_path, merged, rays):
    tiles, _ = cut_tiles(tmp_path / "t", 3, 1)
    a = intersect_dem(rays, merged, dem_model="triangles")
    b = DemMosaic.open(tmp_path / "t", dem_model="triangles", cache_bytes=300_000, block=64).intersect(rays)
    _same_hits(a, b)
    # a region bound below one ray's track (about 40 x 40 nodes here): each track is walked in pieces
    m = DemMosaic.open(tmp_path / "t", cache_bytes=300_000, block=64, max_region_nodes=200)
    calls = []
    real = m.window_dem
    m.window_dem = lambda *w: calls.append(w) or real(*w)
    sub = type(rays)(rays.origin_ecef[:200], rays.direction_ecef[:200], rays.status[:200])
    # 1e-5 m: each piece restarts the walk from a point of the ray (origin + a d, rounded in ECEF) and the
    # root's polish stops within 1e-7 m of the ray parameter from there (measured 1.9e-6 m)
    _same_hits(intersect_dem(sub, merged), m.intersect(sub), tol=1e-5)
    sizes = [(r1 - r0 + 1) * (c1 - c0 + 1) for r0, r1, c0, c1 in calls]
    assert len(calls) > 200 and max(sizes) <= 200  # pieces, each within the bound


def test_cache_never_exceeds_its_bound(tmp_path, merged, rays):
    cut_tiles(tmp_path / "t", 3, 1)
    bound = 5 * 32 * 32 * 8 + 100  # five 32 x 32 float64 blocks
    m = DemMosaic.open(tmp_path / "t", cache_bytes=bound, block=32, max_region_nodes=4000)
    seen = []
    get = m.cache.get

    def spy(key, load):  # instrument: the bytes held after every access
        out = get(key, load)
        seen.append(m.cache.bytes_used)
        return out

    m.cache.get = spy
    regions = []
    real = m.window_dem
    m.window_dem = lambda *w: regions.append(w) or real(*w)
    _same_hits(intersect_dem(rays, merged), m.intersect(rays))
    assert max(seen) <= bound and m.cache.peak_bytes <= bound
    # the bound was exercised: blocks were dropped and read again, and the batch was split
    n_blocks = sum(-(-s.nrows // 32) * -(-s.ncols // 32) for s in m.sources)
    assert m.cache.evictions > 0 and m.cache.misses > n_blocks and len(regions) > 4
    assert max((r1 - r0 + 1) * (c1 - c0 + 1) for r0, r1, c0, c1 in regions) <= 4000
    # the LRU rule by itself
    c = TileCache(100)
    for k in range(5):
        c.get(k, lambda: np.zeros(5))  # 40 bytes each: two fit
    assert len(c) == 2 and c.bytes_used == 80 and c.evictions == 3 and c.get(4, None) is not None
    with pytest.raises(ValueError, match="cache_bytes"):
        TileCache(0)
    with pytest.raises(ValueError, match="block = 64"):
        DemMosaic.open(tmp_path / "t", cache_bytes=1000, block=64)


def test_sample_matches_merged_raster_across_seams(tmp_path, merged):
    cut_tiles(tmp_path / "t", 3, 0)
    m = DemMosaic.open(tmp_path / "t", block=64)
    rng = np.random.default_rng(5)
    w, s, e, n = merged.extent_deg
    lat = np.deg2rad(rng.uniform(s - 0.01, n + 0.01, 5000))  # some outside: LEFT_DEM
    lon = np.deg2rad(rng.uniform(w - 0.01, e + 0.01, 5000))
    h1, s1 = merged.sample(lat, lon)
    h2, s2 = m.sample(lat, lon)
    assert np.array_equal(s1, s2) and {0, 4} <= set(s1.tolist())
    assert np.nanmax(np.abs(h1 - h2)) < 1e-6  # 1e-6 m: node positions differ by float rounding only
    assert np.array_equal(np.isnan(m.height(lat, lon)), np.isnan(h1))


def test_missing_tile_is_nodata_not_a_crash(tmp_path, merged, rays):
    _, wins = cut_tiles(tmp_path / "t", 3, 0, skip={(1, 1)})
    m = DemMosaic.open(tmp_path / "t", block=64)
    a = intersect_dem(rays, merged)
    b = m.intersect(rays)
    # the hole: nodes rows 114..228, columns 134..267 of the crop (linspace cut of 344 x 403)
    r0, r1, c0, c1 = 114, 229, 134, 268
    lat_n, lon_w, dy, dx = (
        merged.grid.lat_north_deg,
        merged.grid.lon_west_deg,
        merged.grid.dlat_deg,
        merged.grid.dlon_deg,
    )
    in_hole = (
        (a.lat_deg < lat_n - dy * (r0 - 1))
        & (a.lat_deg > lat_n - dy * r1)
        & (a.lon_deg > lon_w + dx * (c0 - 1))
        & (a.lon_deg < lon_w + dx * c1)
    )
    assert in_hole.sum() > 50
    assert set(b.status[in_hole].tolist()) <= {Status.NODATA, Status.LEFT_DEM}
    assert (b.status[in_hole] == Status.NODATA).mean() > 0.9
    # rays that meet the terrain before the hole are unchanged; the NODATA rays have NaN positions
    far = b.status == Status.OK
    assert far.sum() > 500 and np.max(np.abs(a.ecef[far] - b.ecef[far])) < HIT_TOL_M
    assert np.all(np.isnan(b.ecef[b.status == Status.NODATA]))
    # sampling inside the hole
    h, st = m.sample(np.deg2rad(lat_n - dy * 170), np.deg2rad(lon_w + dx * 200))
    assert np.isnan(h) and st == Status.NODATA


def test_a_mosaic_of_no_tiles_is_refused_by_name():
    # the constructor itself (DemMosaic.open checks its source first): it used to raise a bare
    # TypeError unpacking the reference tile it never found
    with pytest.raises(ValueError, match="at least one tile: paths is empty"):
        DemMosaic([])


def test_bad_tiles_are_named(tmp_path):
    tiles, _ = cut_tiles(tmp_path / "t", 2, 0)
    with rasterio.open(tiles[1]) as src:
        prof, data, t = dict(src.profile), src.read(1), src.transform
    bad = tmp_path / "bad_crs.tif"
    with rasterio.open(bad, "w", **dict(prof, crs="EPSG:4269")) as dst:
        dst.write(data, 1)
    with pytest.raises(ValueError, match="bad_crs.tif.*NAD83"):
        DemMosaic.open([tiles[0], bad])
    shifted = tmp_path / "shifted.tif"
    with rasterio.open(shifted, "w", **dict(prof, transform=t @ rasterio.Affine.translation(0.5, 0))) as dst:
        dst.write(data, 1)
    with pytest.raises(ValueError, match="shifted.tif.*lattice"):
        DemMosaic.open([tiles[0], shifted])
    coarse = tmp_path / "coarse.tif"
    with rasterio.open(coarse, "w", **dict(prof, transform=t @ rasterio.Affine.scale(2))) as dst:
        dst.write(data, 1)
    with pytest.raises(ValueError, match="coarse.tif.*spacing"):
        DemMosaic.open([tiles[0], coarse])
    ellip = tmp_path / "ellipsoidal.tif"  # a tile that states ellipsoidal heights (EPSG:4979)
    with rasterio.open(ellip, "w", **dict(prof, crs="EPSG:4979")) as dst:
        dst.write(data, 1)
    with pytest.raises(ValueError, match="ellipsoidal.tif.*ellipsoid heights.*egm96"):
        DemMosaic.open([tiles[0], ellip], datum="egm96")
    egm = tmp_path / "egm96.tif"  # a compound CRS stating EGM96 heights: fine with datum egm96
    with rasterio.open(egm, "w", **dict(prof, crs="EPSG:4326+5773")) as dst:
        dst.write(data, 1)
    assert len(DemMosaic.open([tiles[0], egm], datum="egm96").paths) == 2
    with pytest.raises(ValueError, match="egm96.tif.*egm96 heights"):
        DemMosaic.open([tiles[0], egm], datum="ellipsoid")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no raster tiles"):
        DemMosaic.open(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="nope.tif"):
        DemMosaic.open([tiles[0], tmp_path / "nope.tif"])


def test_cli_locate_and_replay_on_a_folder(tmp_path, capsys):
    cut_tiles(tmp_path / "t", 3, 1)
    args = [
        "locate",
        "--sensor",
        str(ROOT / "assets/sensors/eo_turret.toml"),
        "--lat-deg",
        "36.6",
        "--lon-deg",
        "-84.25",
        "--h-m",
        "2500",
        "--heading-deg",
        "45",
        "--pitch-deg",
        "2",
        "--roll-deg",
        "1",
        "--angle",
        "azimuth=90",
        "--angle",
        "elevation=-30",
        "--json",
    ]
    assert main(args + ["--dem", str(SRTM)]) == 0
    one = json.loads(capsys.readouterr().out)
    assert main(args + ["--dem", str(tmp_path / "t")]) == 0
    folder = json.loads(capsys.readouterr().out)
    tiles = sorted(str(p) for p in (tmp_path / "t").iterdir())
    assert main(args + sum((["--dem", p] for p in tiles), [])) == 0
    listed = json.loads(capsys.readouterr().out)
    for out in (folder, listed):
        assert out["status"] == "ok"
        for k in ("lat_deg", "lon_deg", "h_m", "slant_range_m"):
            assert out[k] == pytest.approx(one[k], abs=1e-6)  # printed to 1e-6
    # replay of the turret flight (docs/sensors.md) on the folder: every row as on the one raster
    rec, sen = str(ROOT / "assets/records/eo_turret_flight.csv"), str(ROOT / "assets/sensors/eo_turret.toml")
    for dem, out in ((str(SRTM), tmp_path / "a.csv"), (str(tmp_path / "t"), tmp_path / "b.csv")):
        assert main(["replay", rec, "--sensor", sen, "--dem", dem, "--out", str(out)]) == 0
    assert "mean error to truth 22.87 m" in capsys.readouterr().out
    import csv

    a, b = (list(csv.DictReader((tmp_path / f).open())) for f in ("a.csv", "b.csv"))
    assert len(a) == len(b) == 24
    for ra, rb in zip(a, b):
        # every column as written (positions to 1e-8 deg, heights to 1 mm), but the count of cells
        # visited: the walk's skip blocks are aligned to each region, not to the whole raster
        assert {k: v for k, v in ra.items() if k != "dem_evaluations"} == {
            k: v for k, v in rb.items() if k != "dem_evaluations"
        }
        assert int(rb["dem_evaluations"]) >= 1


def test_example_27_figures():
    # examples/27_dem_mosaic.py (also run by test_terrain_examples.py's glob): its printed figures
    import re
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "27_dem_mosaic.py")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    out = r.stdout
    assert "9 tiles, 344 x 403 nodes" in out and "same status on every ray: True" in out
    # the merged raster's heights (DEM.open of the original, h = H + N)
    merged = DEM.open(SRTM)
    assert f"heights {merged.min_height():.2f} to {merged.max_height():.2f} m" in out
    diff = float(re.search(r"merged raster: ([0-9.e+-]+) m", out).group(1))
    assert diff < HIT_TOL_M
    peak, bound = map(int, re.search(r"peak (\d+) bytes of a (\d+)-byte bound", out).groups())
    assert peak <= bound == 256 * 1024
    assert int(re.search(r"regions assembled: (\d+)", out).group(1)) > 1


def test_with_solver_shares_the_cache(tmp_path, merged, rays):
    cut_tiles(tmp_path / "t", 2, 1)
    m = DemMosaic.open(tmp_path / "t", block=64)
    tri = m.with_solver(dem_model="triangles")
    assert tri.cache is m.cache and tri.dem_model == "triangles" and m.dem_model == "bilinear"
    _same_hits(intersect_dem(rays, merged, dem_model="triangles"), tri.intersect(rays))
    with pytest.raises(ValueError, match="method"):
        m.with_solver("newton")
    assert "(4 files)" in m.path and m.datum == "egm96"


def test_dem_surface_takes_a_mosaic(tmp_path, merged, rays):
    # DemSurface(dem) takes a mosaic as well as a raster (its annotation: DEM | MosaicSource) and
    # solves it region by region: the raster's hits
    from geoloc.surfaces.terrain import DemSurface

    cut_tiles(tmp_path / "t", 2, 1)
    m = DemMosaic.open(tmp_path / "t", block=64)
    _same_hits(intersect_dem(rays, merged), DemSurface(m, "exact").intersect(rays))
