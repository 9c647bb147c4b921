"""27: a folder of DEM tiles as one surface, read in windows through a bounded tile cache (docs/scale.md).

Cuts the bundled SRTM crop into 3 x 3 GeoTIFF tiles that share their edge nodes (as real
SRTM tiles do) with rasterio, opens the folder as a DemMosaic with a 256 KiB cache, and
casts 2000 oblique lines of sight across the tile seams: the hits are those of the one
merged raster (DEM.open of the original file), and the cache never held more than its bound.
"""

import tempfile
import warnings
from pathlib import Path

import numpy as np
import rasterio
from rasterio.windows import Window

from geoloc.assets import asset_path
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.mosaic import DemMosaic
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

srtm = asset_path("dem", "srtm_jacksboro.tif")
with tempfile.TemporaryDirectory() as tmp:
    with rasterio.open(srtm) as src:
        H, W = src.shape
        prof = {k: v for k, v in src.profile.items() if k not in ("blockxsize", "blockysize", "tiled")}
        rows, cols = np.linspace(0, H, 4).astype(int), np.linspace(0, W, 4).astype(int)
        for i in range(3):
            for j in range(3):
                r1, c1 = min(rows[i + 1] + 1, H), min(cols[j + 1] + 1, W)  # one shared node
                win = Window(cols[j], rows[i], c1 - cols[j], r1 - rows[i])
                with warnings.catch_warnings():  # rasterio 1.4's own Affine "*"
                    warnings.simplefilter("ignore", PendingDeprecationWarning)
                    t = src.window_transform(win)
                with rasterio.open(
                    Path(tmp) / f"tile_{i}{j}.tif", "w", **dict(prof, height=win.height, width=win.width, transform=t)
                ) as dst:
                    dst.write(src.read(1, window=win), 1)

    mosaic = DemMosaic.open(tmp, cache_bytes=256 * 1024, block=64, max_region_nodes=20_000)
    merged = DEM.open(srtm)
    print(
        f"mosaic: {len(mosaic.paths)} tiles, {mosaic.shape[0]} x {mosaic.shape[1]} nodes, "
        f"heights {mosaic.min_height():.2f} to {mosaic.max_height():.2f} m (ellipsoidal, EGM96 + N)"
    )
    los = random_oblique_rays(merged, 2000, np.random.default_rng(27), inner=0.95)
    regions = []
    window_dem = mosaic.window_dem
    mosaic.window_dem = lambda *w: regions.append(w) or window_dem(*w)  # count the regions read
    a = intersect_dem(los, merged)
    b = mosaic.intersect(los)
    ok = a.status == Status.OK
    print(f"hits: {int(ok.sum())} of {ok.size}, same status on every ray: {bool(np.array_equal(a.status, b.status))}")
    print(f"largest difference to the merged raster: {np.max(np.abs(a.ecef[ok] - b.ecef[ok])):.1e} m")
    print(f"regions assembled: {len(regions)} (at most {mosaic.max_region_nodes} nodes each)")
    c = mosaic.cache
    print(
        f"tile cache: peak {c.peak_bytes} bytes of a {c.max_bytes}-byte bound, "
        f"{c.misses} window reads, {c.hits} hits, {c.evictions} evictions"
    )
