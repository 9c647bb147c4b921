"""The picture panel's pixels (geoloc_viz.picture_model) against OpenCV on the image's own grid.

Why: ``tests/viz/test_viz_picture.py`` renders its frames through the panel's own sensor
and compares the picks with that sensor, so a lens sized with rows and columns swapped agrees
with itself. Here the expected pixel comes from ``cv2.projectPoints`` with a camera matrix built
in the test for the picture as it is (135 x 240 pixels, not the sensor's 1080 x 1920):

* a zooming KLV frame (``scn.frame_fov_deg``): fx = (cols / 2) / tan(hfov / 2) and the
  principal point at the grid's centre ((cols - 1) / 2 in OpenCV's 0-based pixel centres),
  from the definition of a field of view between the outer pixel edges (u = -0.5 and
  u = cols - 0.5), the same for rows and vfov;
* a picture resampled from the sensor's size: OpenCV's resize keeps the image's corner, so a
  pixel centre u of the sensor lands at (u + 0.5) s - 0.5 with s = new cols / old cols (and
  rows alike): the sensor's camera matrix (its lens parameters, an input of the scenario)
  carried by that map. The map itself is checked here on ``cv2.resize`` of a rendered spot.

The points: the scenario's five surveyed targets (ECEF by pyproj), in the optical frame of the
scenario's sensor at the record's pose (``ecef_to_cam``, the attitude chain tested in
``tests/sensors/test_gimbals.py`` / ``test_sensors.py``; the lens, which the panel sizes, is not used for
it); a click's ground point is projected back the same way. OpenCV's pixel (u, v) is the
panel's (col - 1, row - 1) (``docs/conventions.md``).
"""

from __future__ import annotations

import copy
import math

import cv2
import numpy as np
import pytest
from pyproj import Transformer

from geoloc_viz import picture_model as pm

ROWS, COLS = 135, 240  # the picture's own grid: a 1080 x 1920 sensor shown at an eighth
_TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@pytest.fixture(scope="module")
def scn():
    from geoloc_viz.flight_model import default_flight_scenario

    return default_flight_scenario()


def _cam_vectors(scn, idx, points_llh_deg):
    """The points (lat, lon, h) in the optical frame of the scenario's sensor at record idx's pose."""
    base = scn.camera
    pose = scn.records[idx][1].pose()
    ecef = np.array([_TO_ECEF.transform(lo, la, h) for la, lo, h in points_llh_deg])
    return base.ecef_to_cam(ecef - base.optical_centre_ecef(pose), pose)


def _opencv_rowcol(v_cam, K, dist=None):
    uv, _ = cv2.projectPoints(
        np.asarray(v_cam, np.float64).reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        np.asarray(K, np.float64),
        np.zeros(5) if dist is None else dist,
    )
    uv = uv.reshape(-1, 2)
    return uv[:, 1] + 1.0, uv[:, 0] + 1.0  # 1-based (row, col) of pixel centres


def _targets(scn):
    return [(la, lo, h) for _, la, lo, h in scn.targets]


def test_zooming_frame_pixels_equal_opencv_on_the_pictures_grid(scn):
    idx = 0
    hfov, vfov = (math.radians(float(x)) for x in scn.frame_fov_deg[idx])
    K = np.array(
        [
            [(COLS / 2) / math.tan(hfov / 2), 0.0, (COLS - 1) / 2],
            [0.0, (ROWS / 2) / math.tan(vfov / 2), (ROWS - 1) / 2],
            [0.0, 0.0, 1.0],
        ]
    )
    sensor = pm.frame_sensor(scn, idx, ROWS, COLS)
    assert (sensor.rows, sensor.cols) == (ROWS, COLS)
    inputs = scn.records[idx][1]
    pts = _targets(scn)
    row, col = _opencv_rowcol(_cam_vectors(scn, idx, pts), K)
    # the targets are in the frame (else the panel does not draw them)
    assert np.all((row > 0.5) & (row < ROWS + 0.5) & (col > 0.5) & (col < COLS + 0.5)), (row, col)
    marks = pm.image_marks(scn, idx, sensor, inputs)
    got = np.array([marks[f"target {t[0]}"][:2] for t in scn.targets])
    # 1e-6 px: the same pinhole evaluated twice (float rounding of 1e3 px coordinates)
    np.testing.assert_allclose(got[:, 0], row, atol=1e-6)
    np.testing.assert_allclose(got[:, 1], col, atol=1e-6)
    assert all(marks[f"target {t[0]}"][2] == 0 for t in scn.targets)


def test_a_click_on_the_zooming_frame_projects_back_to_its_pixel(scn):
    """A click's ground point (the panel's line of sight on the DEM), projected by OpenCV with the
    picture's camera matrix: the clicked pixel again."""
    idx = 0
    hfov, vfov = (math.radians(float(x)) for x in scn.frame_fov_deg[idx])
    K = np.array(
        [
            [(COLS / 2) / math.tan(hfov / 2), 0.0, (COLS - 1) / 2],
            [0.0, (ROWS / 2) / math.tan(vfov / 2), (ROWS - 1) / 2],
            [0.0, 0.0, 1.0],
        ]
    )
    sensor = pm.frame_sensor(scn, idx, ROWS, COLS)
    inputs = scn.records[idx][1]
    clicks = [(20.0, 30.0), (67.5, 200.25), (130.0, 235.0)]
    ground = []
    for r, c in clicks:
        p = pm.locate_pixel(scn, inputs, sensor, r, c)
        assert p.ok and p.in_frame
        ground.append((p.lat_deg(), p.lon_deg(), float(p.hit.h)))
    row, col = _opencv_rowcol(_cam_vectors(scn, idx, ground), K)
    # 1e-3 px: the DEM hit lies on the ray to the solver's tolerance (mm at 5 km: 1e-4 px here)
    np.testing.assert_allclose(row, [c[0] for c in clicks], atol=1e-3)
    np.testing.assert_allclose(col, [c[1] for c in clicks], atol=1e-3)


def _resampled_K(lens, rows, cols):
    """The sensor's camera matrix carried to a picture of rows x cols by OpenCV's resize map."""
    sx, sy = cols / lens.width, rows / lens.height
    return np.array(
        [
            [lens.fx * sx, lens.skew * sx, (lens.cx + 0.5) * sx - 0.5],
            [0.0, lens.fy * sy, (lens.cy + 0.5) * sy - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )


def test_opencv_resize_moves_a_pixel_centre_by_the_map_used_here():
    """cv2.resize (INTER_AREA) of a Gaussian spot at a sub-pixel (u, v) of a 1080 x 1920 image: the
    spot's centroid in the 135 x 240 picture is at ((u + 0.5) s - 0.5, (v + 0.5) s - 0.5)."""
    H, W = 1080, 1920
    u, v = 1234.3, 321.7
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    img = np.exp(-((x - u) ** 2 + (y - v) ** 2) / (2 * 40.0**2)).astype(np.float32)
    small = cv2.resize(img, (COLS, ROWS), interpolation=cv2.INTER_AREA)
    yy, xx = np.mgrid[0:ROWS, 0:COLS]
    cu, cv_ = float((small * xx).sum() / small.sum()), float((small * yy).sum() / small.sum())
    # 0.01 px: the centroid of a 5 px wide spot in float32, far from the picture's edges
    assert cu == pytest.approx((u + 0.5) * COLS / W - 0.5, abs=0.01)
    assert cv_ == pytest.approx((v + 0.5) * ROWS / H - 0.5, abs=0.01)


@pytest.mark.parametrize("rows,cols", [(ROWS, COLS), (270, 360)])  # the sensor's aspect, and another
def test_resampled_picture_pixels_equal_opencv_on_the_pictures_grid(scn, rows, cols):
    """A scenario without per-frame fields of view: the panel scales the sensor's lens to the
    picture; OpenCV projects with the sensor's matrix carried to the picture's grid."""
    plain = copy.copy(scn)
    plain.frame_fov_deg = None
    idx = 0
    sensor = pm.frame_sensor(plain, idx, rows, cols)
    assert (sensor.rows, sensor.cols) == (rows, cols)
    K = _resampled_K(scn.camera.lens, rows, cols)
    pose = scn.records[idx][1].pose()
    pts = _targets(scn)
    row, col = _opencv_rowcol(_cam_vectors(scn, idx, pts), K)
    ecef_pts = np.radians([(la, lo) for la, lo, _ in pts])
    px = sensor.ground_to_pixel(ecef_pts[:, 0], ecef_pts[:, 1], np.array([h for *_, h in pts]), pose)
    np.testing.assert_allclose(px.row, row, atol=1e-6)
    np.testing.assert_allclose(px.col, col, atol=1e-6)
    # the frame's centre pixel is the picture's: (rows + 1) / 2, (cols + 1) / 2 in 1-based centres
    assert sensor.center_pixel == pytest.approx(((rows + 1) / 2, (cols + 1) / 2))


def test_which_image_a_record_shows():
    """``image_index``: the scenario's table when it has one, else the image nearest the record's
    time (written out here: the smallest |t - t_k|), else the record's own index; -1 outside."""
    from types import SimpleNamespace

    from geoloc.io.images import ArrayImages

    imgs = ArrayImages(np.zeros((3, 2, 2, 3), np.uint8), times_s=[0.0, 0.5, 1.0])
    assert pm.image_index(SimpleNamespace(images=None), 0) == -1
    assert pm.image_index(SimpleNamespace(images=imgs), None) == -1
    table = SimpleNamespace(images=imgs, image_index=np.array([2, 0, -1, 3, 1]))
    assert [pm.image_index(table, k) for k in range(5)] == [2, 0, -1, -1, 1]
    times = np.array([0.1, 0.8, np.nan, 0.74, 0.26, 0.0])
    timed = SimpleNamespace(images=imgs, record_times_s=times)
    want = [int(np.argmin(np.abs(t - imgs.times_s))) if np.isfinite(t) else k for k, t in enumerate(times)]
    assert want == [0, 2, 2, 1, 1, 0]
    assert [pm.image_index(timed, k) for k in range(6)] == want
    plain = SimpleNamespace(images=imgs)
    assert [pm.image_index(plain, k) for k in range(4)] == [0, 1, 2, -1]


def test_every_mark_of_a_record_against_opencv(scn):
    """``image_marks`` on a scene without a DEM (heights as the record gives them): the surveyed
    truth, the reported centre, each target, all at OpenCV's pixel; the recomputed centre at the
    picture's centre pixel; a target without coordinates (listed first) left out, not the rest."""
    import dataclasses

    idx = 0
    flat = copy.copy(scn)
    flat.dem = None
    info, inputs = scn.records[idx]
    t1 = scn.targets[0]
    info = dataclasses.replace(info, truth_lat_deg=t1[1], truth_lon_deg=t1[2])
    flat.records = [(info, inputs)] + list(scn.records[1:])
    flat.targets = [("X", float("nan"), float("nan"), 500.0)] + list(scn.targets)
    hfov, vfov = (math.radians(float(x)) for x in scn.frame_fov_deg[idx])
    K = np.array(
        [
            [(COLS / 2) / math.tan(hfov / 2), 0.0, (COLS - 1) / 2],
            [0.0, (ROWS / 2) / math.tan(vfov / 2), (ROWS - 1) / 2],
            [0.0, 0.0, 1.0],
        ]
    )
    sensor = pm.frame_sensor(flat, idx, ROWS, COLS)
    marks = pm.image_marks(flat, idx, sensor, inputs)
    named = {
        "truth": (info.truth_lat_deg, info.truth_lon_deg, info.paper_height_m),
        "reported": (info.paper_lat_deg, info.paper_lon_deg, info.paper_height_m),
    }
    named.update({f"target {t[0]}": (t[1], t[2], t[3]) for t in scn.targets})
    assert set(marks) == set(named) | {"recomputed"}
    row, col = _opencv_rowcol(_cam_vectors(scn, idx, list(named.values())), K)
    for k, name in enumerate(named):
        assert marks[name][:2] == pytest.approx((row[k], col[k]), abs=1e-6), name
    # the image centre's own hit: its mark is the centre pixel (1e-3 px: the surface solver's tolerance)
    assert marks["recomputed"][:2] == pytest.approx(((ROWS + 1) / 2, (COLS + 1) / 2), abs=1e-3)


def test_a_frame_missing_one_field_of_view_falls_back_to_the_sensors_lens(scn):
    """A KLV frame whose vertical field of view is missing (NaN): not a zoom, the sensor's own
    lens carried to the picture's grid (OpenCV's resize map), as for a frame without any."""
    part = copy.copy(scn)
    fov = np.array(scn.frame_fov_deg, float).copy()
    fov[0, 1] = np.nan
    part.frame_fov_deg = fov
    sensor = pm.frame_sensor(part, 0, ROWS, COLS)
    K = _resampled_K(scn.camera.lens, ROWS, COLS)
    pts = _targets(scn)
    row, col = _opencv_rowcol(_cam_vectors(scn, 0, pts), K)
    ll = np.radians([(la, lo) for la, lo, _ in pts])
    px = sensor.ground_to_pixel(ll[:, 0], ll[:, 1], np.array([h for *_, h in pts]), scn.records[0][1].pose())
    np.testing.assert_allclose(px.row, row, atol=1e-6)
    np.testing.assert_allclose(px.col, col, atol=1e-6)


def test_a_click_without_a_dem_is_on_the_records_height_and_says_so(scn):
    """No DEM: the click's ground point is on the record's constant target height (ellipsoidal),
    OpenCV projects it back to the clicked pixel, and the panel names the surface."""
    flat = copy.copy(scn)
    flat.dem = None
    inputs = scn.records[0][1]
    hfov, vfov = (math.radians(float(x)) for x in scn.frame_fov_deg[0])
    K = np.array(
        [
            [(COLS / 2) / math.tan(hfov / 2), 0.0, (COLS - 1) / 2],
            [0.0, (ROWS / 2) / math.tan(vfov / 2), (ROWS - 1) / 2],
            [0.0, 0.0, 1.0],
        ]
    )
    sensor = pm.frame_sensor(flat, 0, ROWS, COLS)
    p = pm.locate_pixel(flat, inputs, sensor, 40.0, 100.0)
    assert p.ok and p.method == "constant height"
    assert float(p.hit.h) == pytest.approx(inputs.target_h, abs=1e-3)  # the surface's own tolerance
    row, col = _opencv_rowcol(_cam_vectors(scn, 0, [(p.lat_deg(), p.lon_deg(), float(p.hit.h))]), K)
    assert (row[0], col[0]) == pytest.approx((40.0, 100.0), abs=1e-3)
    with_dem = pm.locate_pixel(scn, inputs, sensor, 40.0, 100.0)
    assert with_dem.method == inputs.method and with_dem.iterations > 0
