"""A drone camera with strong lens distortion, on an earth-referenced gimbal, over terrain.

The bundled sensor (``assets/sensors/drone_camera.toml``) has a wide Brown lens and a
yaw-pitch-roll gimbal whose angles are in NED (as DJI reports them), so the
airframe's own attitude does not turn the camera. A corner pixel is located on the
bundled SRTM terrain twice: with the lens model, and as if the lens were a pinhole.
"""

import dataclasses

from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.locate import line_of_sight
from geoloc.sensors.lenses import PinholeLens
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import DemSurface

sensor = load_sensor(asset_path("sensors", "drone_camera.toml"))
dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"), datum="egm96")
pose = Pose.from_deg(
    36.62,
    -84.20,
    700.0,
    heading_deg=10.0,
    pitch_deg=3.0,
    roll_deg=-4.0,
    angles_deg={"gimbal_yaw": 30.0, "gimbal_pitch": -60.0, "gimbal_roll": 0.0},
)
row, col = 150.0, 3850.0  # near the top-right corner

lens = sensor.lens
pin = PinholeLens(lens.fx, lens.fy, lens.cx, lens.cy, lens.width, lens.height)
d = lens.unproject(col - 1, row - 1)
pu, pv, _ = pin.project(d)
print(
    f"distortion at pixel ({row:g}, {col:g}): the ideal pinhole pixel is "
    f"({float(pv) + 1:.1f}, {float(pu) + 1:.1f}), {float(((pu - (col - 1)) ** 2 + (pv - (row - 1)) ** 2) ** 0.5):.1f} px away"
)

surface = DemSurface(dem, "exact")
hit = surface.intersect(line_of_sight(pose, sensor, row, col))
naive = surface.intersect(line_of_sight(pose, dataclasses.replace(sensor, lens=pin), row, col))
print(
    f"with the lens model: {float(hit.lat_deg):.6f} N {float(hit.lon_deg):.6f} E, h {float(hit.h):.1f} m "
    f"(ellipsoidal), range {float(hit.slant_range):.0f} m"
)
print(f"as a pinhole:        {float(naive.lat_deg):.6f} N {float(naive.lon_deg):.6f} E")
print(
    f"ignoring the distortion moves the target {float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, naive.lat_deg, naive.lon_deg)):.1f} m"
)

tilted = dataclasses.replace(pose, roll=pose.roll + 0.3)
again = surface.intersect(line_of_sight(tilted, sensor, row, col))
print(
    f"airframe rolled 17 deg more: the target moves {float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, again.lat_deg, again.lon_deg)):.2f} m "
    "(only through the lever arm: the gimbal holds its NED angles)"
)
