"""Exact solver in triangle mode vs trimesh's ray cast, 10 000 random rays on the real SRTM crop."""

from pathlib import Path

import numpy as np
import pytest

from geoloc.dem import DEM
from geoloc.status import Status
from geoloc.terrain import intersect_dem, random_oblique_rays

SRTM = Path(__file__).resolve().parents[1] / "assets" / "dem" / "srtm_jacksboro.tif"


def test_triangles_agree_with_trimesh_embree():
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("embreex", reason="trimesh's embree backend (pip embreex); the pure-python "
                        "backend takes hours on 275 000 triangles")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    dem = DEM.open(SRTM)
    los = random_oblique_rays(dem, 10_000, np.random.default_rng(11), frame_angle_deg=(0.0, 82.0))
    hit = intersect_dem(los, dem, "exact", surface="triangles")
    m = dem.to_trimesh()  # same nodes, same diagonal split, in a local ENU frame (float32-safe)
    fr = m.metadata["enu_frame"]
    loc, idx, _ = RayMeshIntersector(m).intersects_location(
        fr.from_ecef(los.origin_ecef), fr.vector_from_ecef(los.direction_ecef), multiple_hits=False)
    ok = hit.status == Status.OK
    hit_tm = np.zeros(len(ok), bool)
    hit_tm[idx] = True
    assert np.array_equal(ok, hit_tm)  # the same rays hit
    err = np.linalg.norm(fr.from_ecef(hit.ecef[idx]) - loc, axis=-1)
    assert err.max() < 0.05  # issue: <= 5 cm
    assert (hit.status[~ok] == Status.LEFT_DEM).all()
