"""22: one line of sight, three DEM solvers: steps [Q17], bisection [L23], exact first hit."""

import numpy as np

from geoloc.status import names
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

dem = DEM.open("assets/dem/srtm_jacksboro.tif")
los = random_oblique_rays(dem, 5, np.random.default_rng(4), frame_angle_deg=(60, 80))
for method, kw in [("steps", dict(eps_h=5.0)), ("bisect", dict(threshold=5.0)), ("exact", {})]:
    hit = intersect_dem(los, dem, method, **kw)
    print(
        f"{method:6s} h = {np.round(hit.h, 1)}  evaluations = {hit.dem_evaluations}  "
        f"status = {list(names(hit.status))}  hidden = {hit.hidden}"
    )
