"""A target seen from many frames, located without a DEM: the least-squares intersection of its rays.

The turret circles a target 4 km away, 3 km up, and sees it in 12 frames; each frame's ray is
built from the target's pixel through a pose with its own errors (position, attitude, joints).
The rays' weighted intersection, its predicted CE90 / LE90 and each ray's residual; then a DEM
30 m too high (say MSL heights read as ellipsoidal) is caught against the intersection
(docs/uncertainty.md).

Run:  python examples/35_triangulate_target.py
"""

import math

import numpy as np

from geoloc.analysis.triangulate import compare_with_surface, triangulate
from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import geodetic_to_ecef, meridian_radius, prime_vertical_radius
from geoloc.geodesy.local import ecef_to_enu
from geoloc.sensors.budget import ErrorBudget
from geoloc.sensors.sensor_file import load_sensor

sensor = load_sensor(asset_path("sensors", "eo_turret.toml"))
noise = {
    "north_m": 2.0,
    "east_m": 2.0,
    "up_m": 3.0,
    "heading_deg": 0.05,
    "pitch_deg": 0.03,
    "roll_deg": 0.03,
    "azimuth_deg": 0.03,
    "elevation_deg": 0.03,
}
lat0, lon0, h0 = math.radians(36.5), math.radians(-84.25), 400.0
n, r = 12, 4000.0
a = np.linspace(0, 2 * math.pi, n, endpoint=False)
lat = lat0 + r * np.cos(a) / (meridian_radius(lat0) + h0)
lon = lon0 + r * np.sin(a) / ((prime_vertical_radius(lat0) + h0) * math.cos(lat0))
heading = np.mod(np.degrees(a) + 90.0, 360.0)
bearing = np.degrees(np.arctan2(-np.sin(a), -np.cos(a)))
nominal = Pose.from_deg(
    np.degrees(lat),
    np.degrees(lon),
    np.full(n, h0 + 3000.0),
    heading,
    np.zeros(n),
    np.zeros(n),
    angles_deg={
        "azimuth": np.mod(bearing - heading, 360.0),
        "elevation": np.full(n, -math.degrees(math.atan2(3000.0, r))),
    },
)
# the true poses differ from the recorded ones by the budget's noise: the pixels are where the target really is
rng = np.random.default_rng(7)
d = {k: rng.standard_normal(n) * s for k, s in noise.items()}
true = Pose(
    nominal.lat + d["north_m"] / (meridian_radius(lat) + nominal.h),
    nominal.lon + d["east_m"] / ((prime_vertical_radius(lat) + nominal.h) * np.cos(lat)),
    nominal.h + d["up_m"],
    nominal.heading + np.radians(d["heading_deg"]),
    nominal.pitch + np.radians(d["pitch_deg"]),
    nominal.roll + np.radians(d["roll_deg"]),
).with_angles(
    azimuth=nominal.angle("azimuth") + np.radians(d["azimuth_deg"]),
    elevation=nominal.angle("elevation") + np.radians(d["elevation_deg"]),
)
row, col, _ = sensor.ground_to_pixel(lat0, lon0, h0, true)

tri = triangulate(sensor, nominal, row, col, ErrorBudget(noise))
err = ecef_to_enu(tri.ecef, lat0, lon0, h0)
print(f"triangulated from {tri.n_rays} rays: {tri.lat_deg:.7f} N {tri.lon_deg:.7f} E h {tri.h:.2f} m (ellipsoidal)")
print(f"error: east {err[0]:+.2f} m, north {err[1]:+.2f} m, up {err[2]:+.2f} m")
print(
    f"predicted: CE90 {tri.ce90_m:.2f} m, LE90 {tri.le90_m:.2f} m; ray residuals {np.nanmax(tri.residual_m):.2f} m at most"
)
print(f"distance from the target itself: {np.linalg.norm(tri.ecef - geodetic_to_ecef(lat0, lon0, h0)):.2f} m")
check = compare_with_surface(tri, np.full(n, h0 + 30.0) + rng.normal(0, 2.0, n))
print(f"DEM check: {check['warning']}")
