"""24: the bisection trap at grazing angles: a ridge in front of a valley (synthetic DEM)."""

import numpy as np

from geoloc.frames.enu import EnuFrame
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem

lon = 78.0 + 0.0005 * np.arange(121)
profile = 300.0 * np.clip(1 - np.abs(lon - 78.02) / 0.0025, 0, None)  # a 300 m ridge on a 0 m floor
dem = DEM.from_array(np.tile(profile, (21, 1)), 36.05, 78.0, 0.005, 0.0005)  # ellipsoidal heights
fr = EnuFrame.from_deg(36.0, 78.002, 0.0)
d = fr.R_ecef_enu @ (np.array([1.0, 0.0, -0.12]) / np.linalg.norm([1.0, 0.0, -0.12]))  # 83 deg frame angle
los = LineOfSight(fr.to_ecef([0, 0, 400.0]), d, np.uint8(0))
for method in ("steps", "bisect", "exact"):
    hit = intersect_dem(los, dem, method, eps_h=1.0, threshold=1.0)
    print(
        f"{method:6s} h = {float(hit.h):6.1f} m at {float(hit.slant_range):7.1f} m, "
        f"{int(hit.dem_evaluations):3d} evaluations, hidden = {bool(hit.hidden)}"
    )
