"""The viewer reads a DEM in the vertical datum it is told (``geoloc view --dem-datum``).

Before, the scene opened every DEM as EGM96 heights whatever the file held, so a DEM of
ellipsoidal heights (a LiDAR product, a DEM already converted) was drawn and intersected
about N (-27 m here) too low. The oracle is the file's own node values read with rasterio.
"""

import numpy as np
import rasterio

from geoloc.assets import asset_path
from geoloc.geodesy.geoid import egm96_undulation
from geoloc_viz.scenario import load_view_scenario


def _node(path):
    """The centre node of the file: (lat, lon) [rad] and its height as stored [m]."""
    with rasterio.open(path) as src:
        r, c = src.height // 2, src.width // 2
        z = float(src.read(1)[r, c])
        lon, lat = src.xy(r, c)  # the node's centre
    return np.radians(lat), np.radians(lon), z


def test_the_scene_reads_the_dem_in_the_datum_given():
    path = asset_path("dem", "etopo5_flight_area.tif")
    lat, lon, z = _node(path)
    n = float(egm96_undulation(lat, lon))
    assert abs(n) > 10  # the check below tells the datums apart here
    ell = load_view_scenario(dem_path=path, dem_datum="ellipsoid")
    msl = load_view_scenario(dem_path=path)  # the default: orthometric, EGM96, as the bundled DEMs are
    assert ell.dem_datum == "ellipsoid" and msl.dem_datum == "egm96"
    # at a node the bilinear DEM is the node's value: 1 mm is float round-off of the geoid sum
    assert abs(float(ell.dem.height(lat, lon)) - z) < 1e-3
    assert abs(float(msl.dem.height(lat, lon)) - (z + n)) < 1e-3
