"""06: a ground target seen from the aircraft: where it is in NED and in AER (azimuth, depression, range), and back."""

import numpy as np

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.local import (
    aer_to_geodetic_deg,
    geodetic_to_aer_deg,
    geodetic_to_ned_deg,
    ned_to_geodetic_deg,
)

# 1. The aircraft (the [Q17] flight-test pose) and a target on the ground, geodetic [deg, deg, m].
aircraft = (35.48, 80.97, 18000.0)
target = (35.577, 80.849, 5083.5)
print(
    f"1. aircraft {aircraft[0]} N {aircraft[1]} E h {aircraft[2]:.0f} m;"
    f" target {target[0]} N {target[1]} E h {target[2]} m"
)

# 2. NED at the aircraft: metres north, east and down along the aircraft's ellipsoid normal.
n, e, d = geodetic_to_ned_deg(*target, *aircraft)
print(f"2. NED: north {n:9.1f} m  east {e:9.1f} m  down {d:9.1f} m")

# 3. AER: azimuth clockwise from north, elevation from the local horizontal plane (negative:
#    the target is below the horizon, a depression angle), slant range along the line of sight.
az_deg, el_deg, srange = geodetic_to_aer_deg(*target, *aircraft)
print(f"3. AER: azimuth {az_deg:8.4f} deg  elevation {el_deg:8.4f} deg  slant range {srange:9.1f} m")
print(
    f"   by hand from NED: range |(n, e, d)| = {np.linalg.norm([n, e, d]):.1f} m,"
    f" azimuth atan2(e, n) mod 360 = {np.rad2deg(np.arctan2(e, n)) % 360:.4f} deg,"
    f" depression atan2(d, hypot(n, e)) = {np.rad2deg(np.arctan2(d, np.hypot(n, e))):.4f} deg = -elevation"
)

# 4. Back: from the aircraft along (az, el) for srange metres lands on the target; so does NED.
back_aer = aer_to_geodetic_deg(az_deg, el_deg, srange, *aircraft)
back_ned = ned_to_geodetic_deg(np.array([n, e, d]), *aircraft)
target_ecef = geodetic_to_ecef(np.deg2rad(target[0]), np.deg2rad(target[1]), target[2])
for name, (lat, lon, h) in [("AER", back_aer), ("NED", back_ned)]:
    miss_m = np.linalg.norm(geodetic_to_ecef(np.deg2rad(lat), np.deg2rad(lon), h) - target_ecef)
    print(f"4. back from {name}: {lat:.9f} N {lon:.9f} E h {h:.6f} m  (misses the target by {miss_m:.1e} m)")

# 5. The same figures from pymap3d, if installed (it is a test dependency: pip install geoloc[test]).
try:
    import pymap3d
except ImportError:
    print("5. pymap3d not installed: skipping the cross-check")
else:
    ref = pymap3d.geodetic2aer(*target, *aircraft)
    print(
        f"5. pymap3d.geodetic2aer: azimuth {ref[0]:8.4f} deg  elevation {ref[1]:8.4f} deg"
        f"  slant range {ref[2]:9.1f} m  (range differs by {abs(ref[2] - srange):.1e} m)"
    )
