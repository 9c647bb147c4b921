"""02: the paper's ECEF -> geodetic iteration [Q17 eq. 12] and how fast it converges."""

import numpy as np

from geoloc.geodesy.ellipsoid import (
    ecef_to_geodetic,
    ecef_to_geodetic_q17,
    geodetic_to_ecef,
)

xyz = geodetic_to_ecef(np.deg2rad(35.577), np.deg2rad(80.849), 5083.5)
exact_lat, _, exact_h = ecef_to_geodetic(xyz)
it = ecef_to_geodetic_q17(xyz, n_iter=5)
print(" i   height error [m]   latitude error [arcsec]")
for i, (la, h) in enumerate(zip(it.lat_history, it.h_history)):
    print(f"{i:2d}   {h - exact_h:16.3e}   {np.rad2deg(la - exact_lat) * 3600:16.3e}")
print("[Q17]: 4 iterations give h to 0.001 m and latitude to 0.00001 arcsec")
