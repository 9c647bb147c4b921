"""25: the DEM as two triangles per cell: exact solver vs trimesh's ray cast on the same mesh."""

import numpy as np

from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

dem = DEM.open("assets/dem/srtm_jacksboro.tif")
los = random_oblique_rays(dem, 1000, np.random.default_rng(0))
hit = intersect_dem(los, dem, "exact", dem_model="triangles")
mesh = dem.to_trimesh()  # local ENU frame (float32-safe for viewers and embree)
fr = mesh.metadata["enu_frame"]
loc, idx, _ = mesh.ray.intersects_location(
    fr.from_ecef(los.origin_ecef), fr.vector_from_ecef(los.direction_ecef), multiple_hits=False
)
err = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
print(
    f"{len(idx)} rays hit in both; max difference {err.max():.2e} m; "
    f"mesh {len(mesh.faces)} triangles, ray backend {type(mesh.ray).__module__}"
)
