"""The [L18] chain, eq. 1-11: from the view angle alpha to the ECEF line of sight, matrix by matrix.

Platform on a circular 390 km orbit, yaw 90 deg (the sensor's YZ plane along
track), sensor mounted 71.3 deg from nadir, pixel at alpha = +0.5 deg.

Run:  python examples/41_limb_l18_chain.py
"""

import numpy as np

from geoloc.sensors.limb import line_of_sight_l18
from geoloc.workflows.scenario import load_scenario

np.set_printoptions(precision=6, suppress=True)
sc = load_scenario("assets/scenarios/tiangong2_limb.toml")
p, v = sc.state_ecef(np.array(600.0))  # 10 minutes after the ascending node
c = line_of_sight_l18(p, v, sc.yaw, sc.roll, sc.pitch, sc.theta_mount, np.radians(0.5))

print("position P [m]        ", p, "\nvelocity V [m/s]      ", v)
print("eq. 1  View (sensor)  ", c.view_scs)
print("eq. 2  T_SCS/BODY = R_body_scs = rx(theta)\n", c.R_body_scs)
print("eq. 3  T_z (yaw)\n", c.T_z)
print("eq. 4  T_x (roll)\n", c.T_x)
print("eq. 5  T_y (pitch, printed form = ry(-pitch) in passive notation)\n", c.T_y)
print("eq. 6  T_BODY/ORB = T_y T_x T_z = R_orb_body\n", c.R_orb_body)
print("eq. 7-10 T_ORB/ECEF = [b1 b2 b3] = R_ecef_orb (b1 along track, b2 -orbit normal, b3 nadir)\n", c.R_ecef_orb)
print("eq. 11 V_ECEF         ", c.direction_ecef)
print("view vector in the orbital frame (forward, -normal, down):", c.R_orb_body @ c.R_body_scs @ c.view_scs)
