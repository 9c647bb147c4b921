"""One limb line of sight: [L18] virtual-ellipsoid tangent vs the exact minimum geodetic height.

Two lines are built horizontal at 45 N, 10 E, 40 km above WGS-84 (so their
true tangent height is 40 km), one due north and one due east, seen from
2 200 km away as from a 390 km orbit.

Run:  python examples/40_limb_tangent_one_line.py
"""

import numpy as np

from geoloc.geodesy.ellipsoid import geodetic_to_ecef, up_normal_ecef
from geoloc.sensors.limb import limb_tangent

lat, lon, h = np.radians(45.0), np.radians(10.0), 40e3
p0 = geodetic_to_ecef(lat, lon, h)
up = up_normal_ecef(lat, lon)
north = np.cross(np.cross(up, [0.0, 0.0, 1.0]), up)
north /= np.linalg.norm(north)
east = np.cross(north, up)
for name, d in (("north", north), ("east", east)):
    origin = p0 - 2.2e6 * d
    r = limb_tangent(origin, d)
    print(f"--- line due {name}; status {int(r.status)} (0 = OK)")
    print(
        f"[L18] Delta a         {float(r.delta_a):12.3f} m   (not the height: the ellipsoid grows with equal flattening)"
    )
    print(f"[L18] tangent lat/lon {float(r.tangent_lat_deg):.6f} {float(r.tangent_lon_deg):.6f} deg (eq. 18-19)")
    print(f"[L18] limb height     {float(r.tangent_h):12.4f} m   (eq. 21-26)")
    print(
        f"exact tangent height  {float(r.exact_h):12.4f} m   at {float(r.exact_lat_deg):.6f} {float(r.exact_lon_deg):.6f} deg"
    )
    print(f"difference L18-exact  {1e3 * float(r.h_difference):12.4f} mm")
    print(f"tangent points apart  {float(np.linalg.norm(r.tangent_ecef - r.exact_ecef)):12.1f} m")
