"""21: open a real DEM, sample heights (NaN + status outside), bounds and the highest node."""

import numpy as np

from geoloc.status import names
from geoloc.surfaces.dem import DEM

dem = DEM.open("assets/dem/srtm_jacksboro.tif")  # SRTM is orthometric: datum "egm96" (default)
print(dem)
print("bounds_deg (W, S, E, N):", np.round(dem.bounds_deg, 5))
print(f"heights {dem.min_height():.1f} .. {dem.max_height():.1f} m above the ellipsoid")
lat = np.deg2rad([36.6, 36.6, 40.0])
lon = np.deg2rad([-84.25, -84.2501, -84.25])
h, st = dem.sample(lat, lon)
for la, lo, hh, s in zip(np.rad2deg(lat), np.rad2deg(lon), h, names(st)):
    print(f"{la:.4f} N {lo:.4f} E  h = {hh:8.2f} m  {s}")
