"""62: an RPC file as a sensor: its lines of sight meet the SRTM DEM, and GDAL's RPC_DEM agrees.

The RPC of the ZY-3-like scene is fitted (as in example 61) and written as a
GeoTIFF; ``read_rpc`` reads it back as an ``RPCSensor``, whose lines of sight
come from the RPC alone (its inverse at two heights). They go through the same
DEM intersection as every other sensor, and the result is compared with GDAL's
RPC transformer (RPC_DEM) on the same file.

Run: python examples/62_rpc_sensor_on_dem.py
"""

import tempfile
from pathlib import Path

import numpy as np

from geoloc.analysis.rpc_fit import fit_rpc
from geoloc.assets import asset_path
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.io.rpc_gdal import (
    gdal_rpc_to_ground,
    read_rpc,
    write_ellipsoidal_dem,
    write_rpc_geotiff,
)
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem
from geoloc.workflows.rpc_scenario import dem_pixels
from geoloc.workflows.scenario import load_scenario

sc = load_scenario(asset_path("scenarios", "zy3_nadir.toml"))
fit = fit_rpc(sc.sensor, sc.height_min, sc.height_max, sc.grid, sc.check_grid)
dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))  # EGM96 heights, h = H + N node by node

with tempfile.TemporaryDirectory() as tmp:
    tif = write_rpc_geotiff(Path(tmp) / "zy3.tif", fit.model, sc.sensor.rows, sc.sensor.cols)
    rpc = read_rpc(tif)  # an RPCSensor: rows and cols from the raster
    print(
        f"RPC sensor from {tif.name}: {rpc.rows} x {rpc.cols} px, heights "
        f"{rpc.model.height_off - rpc.model.height_scale:.0f} .. {rpc.model.height_off + rpc.model.height_scale:.0f} m"
    )

    # pixels whose ground lies on the DEM; the RPC's lines of sight through the exact DEM solver
    rows, cols = dem_pixels(rpc, dem, (12, 12))
    hit = intersect_dem(rpc.line_of_sight(rows, cols), dem, method="exact")
    ok = hit.status == Status.OK
    rows, cols = rows[ok], cols[ok]
    print(
        f"{ok.sum()} of {ok.size} pixels meet the DEM; e.g. pixel ({rows[0]:.1f}, {cols[0]:.1f}) -> "
        f"{hit.lat_deg[ok][0]:.6f} N {hit.lon_deg[ok][0]:.6f} E, h {hit.h[ok][0]:.2f} m"
    )

    # the line is a chord of the RPC's curved locus: project the hits back with the RPC
    back = rpc.ground_to_pixel(hit.lat[ok], hit.lon[ok], hit.h[ok])
    print(f"line of sight vs RPC at the terrain, max [px]: {np.max(np.hypot(back.row - rows, back.col - cols)):.2e}")

    # GDAL on the same RPC, given an ellipsoidal-height copy of the DEM (docs/rpc.md, the two traps)
    ell = write_ellipsoidal_dem(dem, Path(tmp) / "dem_h.tif")
    lat, lon = gdal_rpc_to_ground(
        rpc.model, rows, cols, dem_path=ell, height=0.0, pixel_error_threshold=1e-6, max_iterations=100
    )
    h = dem.height(lat, lon)
    g = rpc.ground_to_pixel(lat, lon, h)
    d_m = np.linalg.norm(geodetic_to_ecef(lat, lon, h) - hit.ecef[ok], axis=-1)
    print(
        f"GDAL RPC_DEM vs RPC sensor: max {np.max(np.hypot(g.row - back.row, g.col - back.col)):.2e} px, "
        f"{d_m.max():.2e} m (threshold 1e-6 px)"
    )

    # out of the model's domain: refused, not extrapolated
    far = rpc.ground_to_pixel(np.deg2rad(rpc.model.lat_off + 5.0), np.deg2rad(rpc.model.long_off), 500.0)
    print(f"a point 5 degrees north of the scene: status {Status(int(far.status)).name}")
