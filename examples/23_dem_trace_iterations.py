"""23: the trace of the iterations (what the visualiser draws): H_n, ground point, h_n."""

import numpy as np

from geoloc import Camera, Pose
from geoloc.locate import locate_dem
from geoloc.surfaces.dem import DEM

dem = DEM.open("assets/dem/etopo5_flight_area.tif")  # ETOPO5 5' crop of the [Q17] flight area
cam = Camera.from_toml("assets/cameras/qiao2017.toml")
pose = Pose.from_deg(35.48, 80.97, 18000, heading_deg=45, pitch_deg=3.5, gimbal_roll_deg=50, gimbal_pitch_deg=-2.6)
for method, kw in [("steps", dict(eps_h=100.0)), ("bisect", dict(threshold=10.0))]:
    hit = locate_dem(pose, cam, dem=dem, method=method, trace=True, **kw)
    t = hit.trace.ray()
    print(
        f"{method}: {int(hit.dem_evaluations)} DEM evaluations -> {float(hit.lat_deg):.5f} N "
        f"{float(hit.lon_deg):.5f} E h {float(hit.h):.1f} m"
    )
    for k in range(len(t["H"])):
        extra = f"  bracket [{t['lo'][k]:.0f}, {t['hi'][k]:.0f}]" if method == "bisect" else ""
        print(
            f"  H_{k} = {t['H'][k]:7.1f} m  ground {np.rad2deg(t['lat'][k]):.5f} N "
            f"{np.rad2deg(t['lon'][k]):.5f} E  DEM h_{k} = {t['h_dem'][k]:7.1f} m{extra}"
        )
