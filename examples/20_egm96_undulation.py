"""20: orthometric -> ellipsoidal heights with the bundled EGM96 grid (h = H + N)."""

import numpy as np

from geoloc.geodesy.geoid import egm96_undulation

for name, lat_deg, lon_deg in [
    ("Table 1 target [Q17]", 35.58, 80.85),
    ("0 N 0 E", 0.0, 0.0),
    ("Jacksboro SRTM tile", 36.6, -84.25),
]:
    n = float(egm96_undulation(np.deg2rad(lat_deg), np.deg2rad(lon_deg)))
    print(f"{name:22s} N = {n:7.2f} m   (a peak at H = 5000 m is at h = {5000 + n:.2f} m)")
