"""01: geodetic <-> ECEF on WGS-84, closed form, checked against pyproj."""

import numpy as np
from pyproj import Transformer

from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef

lat_deg, lon_deg, h = 35.48, 80.97, 18000.0
xyz = geodetic_to_ecef(np.deg2rad(lat_deg), np.deg2rad(lon_deg), h)
print("ECEF [m]:", np.round(xyz, 3))
ref = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(lon_deg, lat_deg, h)
print("pyproj  :", np.round(ref, 3), " difference", np.linalg.norm(xyz - ref), "m")
lat, lon, hh = ecef_to_geodetic(xyz)
print(f"back    : {np.rad2deg(lat):.10f} N {np.rad2deg(lon):.10f} E {hh:.6f} m")
