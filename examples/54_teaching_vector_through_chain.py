"""54: a vector through the chain: one pixel's ray in every frame, and the partial products.

The teaching panel of ``geoloc view`` (``geoloc_viz.teaching_panel``) shows these numbers
beside the 4x4 matrices; here they are printed for record T3-1 of [Q17] and for the
bundled azimuth-elevation turret. The ray of a pixel starts in the optical frame ``cam``
(the lens's back-projection); each hop ``T_dst_src`` of the sensor's frame graph turns it
into the next frame out, and in ECEF it is the core's line of sight.
"""

import numpy as np

from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.sensors.sensor_file import load_sensor
from geoloc_viz import teaching


def show(title, sensor, pose, row, col):
    chain = sensor.frames(pose)
    v_cam = teaching.pixel_ray_cam(sensor, row, col)
    coords = teaching.vector_in_frames(chain, v_cam, "cam")
    print(f"{title}: pixel (row {row:g}, column {col:g})")
    print("  frame               x          y          z")
    for f, c in coords.items():
        print(f"  {f:<16s} {c[0]:+.6f}  {c[1]:+.6f}  {c[2]:+.6f}")
    los = sensor.line_of_sight(row, col, pose)
    diff = float(np.max(np.abs(coords["ecef"] - np.asarray(los.direction_ecef))))
    print(f"  ecef row minus sensor.line_of_sight direction: max |difference| = {diff:.1e}")
    names = [name for name, _, _ in teaching.partial_products(chain)]
    print("  partial products: " + ", ".join(names))
    T = teaching.partial_products(chain)[-1][2]
    print(f"  T_ecef_cam translation (optical centre, ECEF m): {T[0, 3]:.3f} {T[1, 3]:.3f} {T[2, 3]:.3f}")
    print("  angles the panel animates from 0: " + ", ".join(teaching.animatable_angles(chain)))
    print()


q17 = load_sensor(asset_path("cameras", "qiao2017.toml"))  # a camera file loads as its FrameSensor
pose = Pose.from_deg(36.39895, 78.72927, 17987.25, 30.0457, 3.3903, -0.0110, -45.2273, -2.4880)
show("[Q17] T3-1, roll-pitch gimbal", q17, pose, 526.0, 1550.0)

turret = load_sensor(asset_path("sensors", "eo_turret.toml"))
pose = Pose.from_deg(36.65999, -84.24996, 2502.48, 89.93, 2.05, 1.48, angles_deg={"azimuth": 93.64, "elevation": -9.76})
show("EO turret, azimuth-elevation gimbal", turret, pose, 598.32, 842.37)

# the [Q17] eq. 5 factors pass through three frames between ECEF and NED
chain = q17.frames(Pose.from_deg(36.39895, 78.72927, 17987.25))
for name, T in teaching.q17_intermediate_frames(chain):
    print(f"{name}: origin {T[0, 3]:.3f} {T[1, 3]:.3f} {T[2, 3]:.3f} m")
