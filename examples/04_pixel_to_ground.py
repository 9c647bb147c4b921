"""04: pixels -> ground at a target height, batched, with rays to the sky as NaN + status."""

import numpy as np

from geoloc import Camera, Pose, locate
from geoloc.status import names

cam = Camera.from_toml("assets/cameras/qiao2017.toml")
pose = Pose.from_deg(
    35.48,
    80.97,
    18000,
    heading_deg=45,
    pitch_deg=3.5,
    gimbal_roll_deg=np.array([50.0, 50.0, 95.0]),
    gimbal_pitch_deg=-2.6,
)
g = locate(pose, cam, row=np.array([1.0, 1162.0, 1162.0]), col=1146.0, target_h=5083.5)
for la, lo, h, r, s in zip(g.lat_deg, g.lon_deg, g.h, g.slant_range, names(g.status)):
    print(f"{la:11.6f} N {lo:11.6f} E  h {h:8.2f} m  range {r:9.1f} m  {s}")
