"""How sure is this point? The first-order prediction of one located point against Monte Carlo.

An EO turret 3 km up looks 60 deg off nadir at the SRTM crop; its error budget (the sensor
file's ``[uncertainty]`` table: position, attitude, the turret's joints, boresight, focal
length, and SRTM's 16 m LE90) is propagated through the chain and the terrain's slope to the
point's covariance, its error ellipse, CE90 (exact for the ellipse) and LE90; then the same
budget is drawn 4000 times and every sample located again (docs/uncertainty.md).

Run:  python examples/34_predicted_uncertainty.py
"""

import numpy as np

from geoloc.analysis.uncertainty import empirical_ce90_le90, monte_carlo, propagate
from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.sensors.budget import ErrorBudget
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import DemSurface

sensor = load_sensor(asset_path("sensors", "eo_turret.toml"))
budget = ErrorBudget(
    {
        "north_m": 2.0,
        "east_m": 2.0,
        "up_m": 3.0,
        "heading_deg": 0.05,
        "pitch_deg": 0.02,
        "roll_deg": 0.02,
        "azimuth_deg": 0.02,
        "elevation_deg": 0.02,
        "boresight_x_deg": 0.01,
        "fx_px": 2.0,
    },
    dem_product="srtm",
)
surface = DemSurface(DEM.open(asset_path("dem", "srtm_jacksboro.tif")))
pose = Pose.from_deg(36.50, -84.20, 3000.0, 0.0, 1.0, 0.5, angles_deg={"azimuth": 0.0, "elevation": -30.0})

pu = propagate(sensor, pose, 540.5, 960.5, budget, surface=surface, jacobian=True)  # J: each source's share
print(
    f"located: {float(pu.lat) * 180 / np.pi:.6f} N {float(pu.lon) * 180 / np.pi:.6f} E "
    f"h {float(pu.h):.1f} m (ellipsoidal)"
)
print(
    f"1-sigma ellipse: {float(pu.ellipse_major_m):.2f} x {float(pu.ellipse_minor_m):.2f} m, "
    f"major axis at {float(pu.ellipse_azimuth_deg):.1f} deg from north"
)
print(f"predicted: CE90 {float(pu.ce90_m):.2f} m, LE90 {float(pu.le90_m):.2f} m")
enu, st = monte_carlo(sensor, pose, 540.5, 960.5, budget, surface, 4000, np.random.default_rng(0))
ce, le = empirical_ce90_le90(enu, st)
print(f"Monte Carlo (4000): CE90 {ce:.2f} m, LE90 {le:.2f} m")
print("the three largest sources (CE contribution, m):")
J = pu.jacobian_enu
share = np.hypot(J[0], J[1])
for k in np.argsort(share)[::-1][:3]:
    print(f"  {pu.sources[k]:16s} {share[k]:.2f}")
