"""An EO turret on an azimuth-elevation gimbal: the sensor file, one pixel, the image footprint.

The bundled sensor (``assets/sensors/eo_turret.toml``) has a Brown lens, a mount, a
lever arm and a boresight; its gimbal reads MISB ST 0601's sensor-relative azimuth
(clockwise from the nose) and elevation (negative down). Here the aircraft flies
north-east at 2500 m and the turret looks 90 deg right of the nose, 30 deg down.
pymap3d's ``lookAtSpheroid`` then intersects the same line of sight on its own.
"""

import numpy as np
from pymap3d.los import lookAtSpheroid

from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.geodesy.local import R_ecef_ned
from geoloc.locate import locate
from geoloc.sensors.sensor_file import load_sensor

sensor = load_sensor(asset_path("sensors", "eo_turret.toml"))
pose = Pose.from_deg(
    36.6,
    -84.25,
    2500.0,
    heading_deg=45.0,
    pitch_deg=2.0,
    roll_deg=1.0,
    angles_deg={"azimuth": 90.0, "elevation": -30.0},
)
print(f"sensor: {sensor.name}; gimbal {sensor.gimbal.name}, angles {list(sensor.angle_names)}")

centre = locate(pose, sensor, 540.5, 960.5, target_h=0.0, height_kind="geodetic")
print(
    f"principal point on the ellipsoid: {float(centre.lat_deg):.7f} N {float(centre.lon_deg):.7f} E, "
    f"slant range {float(centre.slant_range):.1f} m"
)

# the same ray through pymap3d: azimuth and tilt in the NED frame at the optical centre
o_lat, o_lon, o_h = ecef_to_geodetic(centre.los.origin_ecef)
d = R_ecef_ned(o_lat, o_lon).T @ centre.los.direction_ecef
az, tilt = np.degrees(np.arctan2(d[1], d[0])) % 360, np.degrees(np.arccos(d[2]))
lat, lon, rng = lookAtSpheroid(np.degrees(o_lat), np.degrees(o_lon), o_h, az, tilt)
print(
    f"line of sight: azimuth {az:.3f} deg, {tilt:.3f} deg from nadir "
    f"(heading 45 + azimuth 90 = 135 and elevation -30 = 60 from nadir, turned by the "
    f"aircraft's pitch and roll, the mount and the boresight)"
)
print(
    f"pymap3d lookAtSpheroid: {float(lat):.7f} N {float(lon):.7f} E; "
    f"difference {abs(float(rng) - float(centre.slant_range)):.1e} m in range"
)

corners = locate(
    pose,
    sensor,
    np.array([0.5, 0.5, 1080.5, 1080.5]),
    np.array([0.5, 1920.5, 1920.5, 0.5]),
    target_h=0.0,
    height_kind="geodetic",
)
for name, a, b in zip(("top left", "top right", "bottom right", "bottom left"), corners.lat_deg, corners.lon_deg):
    print(f"footprint {name:12s}: {a:.6f} N {b:.6f} E")
