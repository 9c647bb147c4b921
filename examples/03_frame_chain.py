"""03: the frame chain ECEF <- NED <- body <- outer gimbal <- camera as 4x4 matrices [Q17 eq. 4-9]."""

import numpy as np

from geoloc.frames.chain import FrameChain, Pose, T_ecef_ned, T_ned_ecef_q17_factors
from geoloc.frames.rotations import invert

np.set_printoptions(precision=4, suppress=True, linewidth=120)
pose = Pose.from_deg(
    35.48, 80.97, 18000, heading_deg=45, pitch_deg=3.5, roll_deg=0, gimbal_roll_deg=50, gimbal_pitch_deg=-2.6
)
chain = FrameChain(pose)
for hop in chain.hops:
    print(f"{hop.name}  ({hop.equation}): {hop.description}\n{hop.T}\n")
print("line of sight (camera Z) in ECEF:", chain.R_ecef_cam[:, 2])

factors = T_ned_ecef_q17_factors(pose.lat, pose.lon, pose.h)
product = factors[0] @ factors[1] @ factors[2] @ factors[3]
print(
    "eq. 5 as four factors equals the direct form:",
    np.allclose(product, invert(T_ecef_ned(pose.lat, pose.lon, pose.h)), atol=1e-6),
)
