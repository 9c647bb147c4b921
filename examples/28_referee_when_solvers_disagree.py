"""28: when the walk and embree put a hit in different places, an independent referee decides.

A 401 x 401 DEM (the SRTM crop resampled, plus 3 m roughness), 100 000 oblique rays: the
exact walk and trimesh's ray cast (embree, float32) hit the same rays, but a few hits
land elsewhere. geoloc.surfaces.referee re-solves each such ray with pyproj's vertices
and extended precision over every triangle around both hits (docs/terrain.md, "Where
embree and the walk differ").
"""

import numpy as np

from geoloc.surfaces.dem import DEM, upsampled_dem
from geoloc.surfaces.referee import judge, referee_triangle
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

dem = upsampled_dem(DEM.open("assets/dem/srtm_jacksboro.tif"), 401, np.random.default_rng(0))
los = random_oblique_rays(dem, 100_000, np.random.default_rng(1), frame_angle_deg=(45.0, 82.0))
hit = intersect_dem(los, dem, "exact", dem_model="triangles")
mesh = dem.to_trimesh()  # local ENU frame
fr = mesh.metadata["enu_frame"]
loc, idx, tri = mesh.ray.intersects_location(
    fr.from_ecef(los.origin_ecef), fr.vector_from_ecef(los.direction_ecef), multiple_hits=False
)
apart = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
o, d, p = los.origin_ecef.reshape(-1, 3), los.direction_ecef.reshape(-1, 3), hit.ecef.reshape(-1, 3)
print(
    f"{len(idx)} rays hit in both ({type(mesh.ray).__module__}); {int((apart > 1e-3).sum())} hits more than 1 mm apart"
)
for k in np.nonzero(apart > 1e-3)[0]:
    r = idx[k]
    verdict, ref = judge(dem, o[r], d[r], p[r], fr.to_ecef(loc[k]))
    who = {"a": "the walk's", "b": "embree's", "both": "both", "neither": "neither"}[verdict]
    theirs = referee_triangle(dem, o[r], d[r], [divmod(int(v), dem.shape[1]) for v in mesh.faces[tri[k]]])
    why = (
        f"the ray passes {-theirs.inside_m * 1e3:.2f} mm outside embree's triangle"
        if theirs.inside_m < 0
        else "embree's triangle lies beyond the walk's hit"
    )
    print(f"ray {r}: {apart[k]:.3f} m apart; referee finds {who} hit ({ref.inside_m:.3f} m inside its triangle); {why}")
