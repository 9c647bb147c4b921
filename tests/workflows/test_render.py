"""The renderer (geoloc.workflows.render): synthetic pictures of the terrain from a frame sensor.

Oracles:

* OpenCV's ``cv2.projectPoints`` (a pinhole K from the fields of view) with the camera's
  rotation built by scipy's ``Rotation`` (body from NED z-y-x by heading, pitch, roll;
  the turret z-y-x by azimuth, elevation, roll in the body: MISB ST 0601's order) and
  the target's NED coordinates from pymap3d: none of geoloc's frames or lenses. It
  predicts where each painted cross must appear; the cross is found in the rendered
  image by image processing (connected components of red, their centroids);
* matplotlib's ``LightSource.hillshade`` for the texture's shading;
* geoloc's own ``locate`` of the found cross, against the surveyed position, in
  ground samples (the rendering's required accuracy).
"""

import math
from pathlib import Path

import cv2
import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.locate import line_of_sight
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import DemSurface
from geoloc.workflows.render import Cross, find_marks, ground_texture, hillshade, read_crosses, render_frame
from test_klv_replay import tool  # noqa: F401  (the fixture: tools/make_klv_example.py, loaded once)

ROOT = Path(__file__).resolve().parents[2]
DEM_PATH = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"
TARGETS = ROOT / "assets" / "klv" / "example_flight_targets.csv"
#: Frames of the example flight without a fault of the metadata or the video, one per zoom step
#: and both sides of the orbit.
CLEAN = (5, 90, 130, 180, 230, 295)


@pytest.fixture(scope="module")
def dem():
    return DEM.open(DEM_PATH)


@pytest.fixture(scope="module")
def flight(tool, dem):
    decoded = tool.decoded_truth(dem)
    tex = tool.texture(dem)
    out = {}
    for i in CLEAN:
        st = tool.state_at(decoded, float(i))
        s, p = tool.video_sensor_pose(st)
        out[i] = (st, s, p, render_frame(s, p, dem, tex))
    return out


def opencv_pixels(st, targets, size):
    """1-based (row, col) of the targets by cv2.projectPoints, the rotation from scipy, NED from pymap3d."""
    w, h = size
    r_body = Rotation.from_euler(
        "ZYX", [st["platform_heading_deg"], st["platform_pitch_full_deg"], st["platform_roll_full_deg"]], degrees=True
    )
    r_sens = Rotation.from_euler(
        "ZYX",
        [st["sensor_relative_azimuth_deg"], st["sensor_relative_elevation_deg"], st["sensor_relative_roll_deg"]],
        degrees=True,
    )
    R_ned_sensor = (r_body * r_sens).as_matrix()  # sensor coordinates -> NED
    P = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # optical x, y, z = sensor Y, Z, X
    R_cam_ned = P @ R_ned_sensor.T
    ned = np.array(
        [
            pymap3d.geodetic2ned(
                t["lat_deg"],
                t["lon_deg"],
                t["h_m"],
                st["sensor_latitude_deg"],
                st["sensor_longitude_deg"],
                st["sensor_ellipsoid_height_m"],
            )
            for t in targets
        ]
    )
    fx = (w / 2) / math.tan(math.radians(st["sensor_horizontal_fov_deg"]) / 2)
    fy = (h / 2) / math.tan(math.radians(st["sensor_vertical_fov_deg"]) / 2)
    K = np.array([[fx, 0, (w - 1) / 2], [0, fy, (h - 1) / 2], [0, 0, 1.0]])
    rvec, _ = cv2.Rodrigues(R_cam_ned)
    uv, _ = cv2.projectPoints(ned.reshape(-1, 1, 3), rvec, np.zeros(3), K, None)
    uv = uv.reshape(-1, 2)
    return np.column_stack([uv[:, 1] + 1.0, uv[:, 0] + 1.0])  # OpenCV 0-based (u, v) -> 1-based (row, col)


def read_targets():
    import csv

    with open(TARGETS, newline="") as f:
        return [{k: (v if k == "name" else float(v)) for k, v in r.items()} for r in csv.DictReader(f)]


def test_crosses_appear_where_opencv_projects_them(flight, tool):
    targets = read_targets()
    worst = 0.0
    for i, (st, s, p, r) in flight.items():
        marks, sizes = find_marks(r.image)
        want = opencv_pixels(st, targets, tool.VIDEO_SIZE)
        inside = [k for k, (a, b) in enumerate(want) if 20 < a < s.rows - 20 and 20 < b < s.cols - 20]
        assert len(inside) >= 3, (i, want)
        assert len(marks) == len(inside), (i, marks, want)
        for k in inside:
            d = np.hypot(*(marks - want[k]).T).min()
            worst = max(worst, d)
    # The found centroid of a rendered cross vs the projected centre. The render has no
    # anti-aliasing (each pixel takes the colour at its centre's ground point), so the
    # binary outline of bars 3-7 px wide moves the centroid by a few tenths of a pixel;
    # the bilinear DEM cell under the cross is not a plane (its twist term tilts
    # opposite arms differently), a few tenths more at the 4.5 deg zoom (0.45 m/px).
    # Perspective across 20 m at 3-4 km: < 0.01 px. Measured 0.79 px worst, 0.2 typical;
    # OpenCV and geoloc.ground_to_pixel agree to 1e-6 px on the same targets.
    assert worst < 1.0, worst


def test_a_found_cross_locates_within_two_ground_samples(flight, dem):
    targets = read_targets()
    surf = DemSurface(dem, "exact")
    for i, (st, s, p, r) in flight.items():
        marks, _ = find_marks(r.image)
        for row, col in marks:
            rows = np.array([row, row + 1.0, row])
            cols = np.array([col, col, col + 1.0])
            hit = surf.intersect(line_of_sight(p, s, rows, cols))
            assert np.all(hit.status == Status.OK)
            lat, lon = np.rad2deg(hit.lat), np.rad2deg(hit.lon)
            gsd = max(
                horizontal_distance_m(lat[0], lon[0], lat[1], lon[1]),
                horizontal_distance_m(lat[0], lon[0], lat[2], lon[2]),
            )
            d = min(horizontal_distance_m(lat[0], lon[0], t["lat_deg"], t["lon_deg"]) for t in targets)
            assert d <= 2 * gsd, (i, row, col, d, gsd)


def test_status_colours_and_the_grid(flight, tool, dem):
    st, s, p, r = flight[5]
    assert r.image.shape == (s.rows, s.cols, 3) and r.image.dtype == np.uint8
    assert np.all(r.grid.status == Status.OK)
    # the same camera pitched up to the horizon: the top rows see sky
    up = dict(st, sensor_relative_elevation_deg=2.0)
    s2, p2 = tool.video_sensor_pose(up)
    r2 = render_frame(s2, p2, dem, tool.texture(dem))
    sky = r2.grid.status == Status.SKY
    left = r2.grid.status == Status.LEFT_DEM
    assert sky[0].mean() > 0.5 and sky.sum() > 1000 and not sky[-1].any()
    assert np.all(r2.image[sky] == (150, 190, 235))
    assert np.all(r2.image[left] == (200, 200, 205))
    assert (r2.grid.status == Status.OK).sum() > 1000


def test_hillshade_is_matplotlibs(dem):
    from matplotlib.colors import LightSource

    from geoloc.workflows.render import _node_spacing_m

    mine = hillshade(dem, 315.0, 45.0)
    dy, dx = _node_spacing_m(dem)
    ref = LightSource(azdeg=315, altdeg=45).hillshade(np.asarray(dem.grid.values, float), vert_exag=1, dx=dx, dy=dy)
    # matplotlib stretches its intensities to 0..1 (min-max): compare after the same stretch;
    # no clipping happens here (the sun at 45 deg lights every slope of this crop)
    assert mine.min() > 0
    stretched = (mine - mine.min()) / (mine.max() - mine.min())
    np.testing.assert_allclose(stretched, ref, atol=1e-9)


def test_crosses_and_bad_input(tmp_path, dem):
    with pytest.raises(ValueError, match="arm_m"):
        Cross(36.6, -84.2, arm_m=-1.0)
    with pytest.raises(ValueError, match="lat_deg"):
        Cross(float("nan"), -84.2)
    bad = tmp_path / "t.csv"
    bad.write_text("name,lat_deg,lon_deg\nA,36.6,x\n")
    with pytest.raises(ValueError, match="line 2"):
        read_crosses(bad)
    cs = read_crosses(TARGETS)
    assert [c.name for c in cs] == ["T1", "T2", "T3", "T4", "T5"] and cs[0].arm_m == 10.0
    tex = ground_texture(dem, cs)
    # a cross's centre and its arm ends are red; a point beyond the arm is not
    c = cs[0]
    lat, lon = math.radians(c.lat_deg), math.radians(c.lon_deg)
    m_per_rad_n = 6_378_137.0 * (1 - 0.00669438) / (1 - 0.00669438 * math.sin(lat) ** 2) ** 1.5
    d_in, d_out = (c.arm_m - 0.5) / m_per_rad_n, (c.arm_m + 0.5) / m_per_rad_n
    col = tex.colour(np.array([lat, lat + d_in, lat + d_out]), np.array([lon, lon, lon]))
    assert tuple(col[0]) == (255, 0, 0) and tuple(col[1]) == (255, 0, 0) and tuple(col[2]) != (255, 0, 0)
    assert tuple(tex.colour(np.array([np.nan]), np.array([0.0]))[0]) == (200, 200, 205)
