"""Calibration file importers (geoloc.sensors.lens_io) on files in their real formats."""

import json
import re

import numpy as np
import pytest

from geoloc.sensors.lens_io import (
    read_colmap_cameras,
    read_lens_file,
    read_opencv_yaml,
    read_opensfm_cameras,
    read_ros_camera_info,
)
from geoloc.sensors.lenses import BrownLens, FisheyeLens, PinholeLens

import cv2  # noqa: E402  (opencv-python-headless: a test dependency, never skipped)

K = np.array([[503.25, 0.0, 321.75], [0.0, 502.5, 239.125], [0.0, 0.0, 1.0]])
D5 = np.array([[-0.21, 0.043, 1.2e-3, -6e-4, -5e-3]])
D8 = np.array([[0.9, 0.25, 1e-3, -5e-4, 0.005, 1.3, 0.45, 0.03]])
D4 = np.array([[-0.0073, 0.044, -0.042, 0.0078]])


def write_filestorage(path, **items):
    """A calibration file written by cv2.FileStorage itself (YAML or JSON by the extension)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in items.items():
        fs.write(key, value)
    fs.release()
    return path


# --------------------------------------------------------------------------- OpenCV FileStorage
@pytest.mark.parametrize("ext", ["yml", "json"])
def test_opencv_filestorage_brown(tmp_path, ext):
    path = write_filestorage(
        tmp_path / f"calib.{ext}", image_width=640, image_height=480, camera_matrix=K, distortion_coefficients=D5
    )
    for lens in (read_opencv_yaml(path), read_lens_file(path)):
        assert type(lens) is BrownLens
        np.testing.assert_array_equal(lens.K, K)  # OpenCV pixels are ours: unchanged
        np.testing.assert_array_equal(lens.dist_coeffs, np.concatenate([D5.ravel(), np.zeros(3)]))
        assert (lens.width, lens.height) == (640, 480)


def test_opencv_filestorage_rational_and_alternative_keys(tmp_path):
    path = write_filestorage(tmp_path / "c.yaml", imageSize=(800, 600), cameraMatrix=K, distCoeffs=D8)
    lens = read_opencv_yaml(path)
    assert lens.dist_coeffs.tolist() == D8.ravel().tolist() and (lens.width, lens.height) == (800, 600)
    path = write_filestorage(tmp_path / "d.yaml", width=800, height=600, K=K, D=D8[:, :4])
    lens = read_opencv_yaml(path)
    assert lens.dist_coeffs.tolist() == [0.9, 0.25, 1e-3, -5e-4, 0, 0, 0, 0]


def test_opencv_filestorage_fisheye(tmp_path):
    path = write_filestorage(
        tmp_path / "f.yml",
        image_width=848,
        image_height=800,
        camera_matrix=K,
        distortion_coefficients=D4,
        distortion_model="fisheye",
    )
    lens = read_opencv_yaml(path)
    assert type(lens) is FisheyeLens and lens.dist_coeffs.tolist() == D4.ravel().tolist()
    assert read_opencv_yaml(path, model="fisheye") == lens
    with pytest.raises(ValueError, match=r"f\.yml: distortion_model = 'fisheye' contradicts model='brown'"):
        read_opencv_yaml(path, model="brown")
    # without the key, the caller says
    path = write_filestorage(
        tmp_path / "g.yml", image_width=848, image_height=800, camera_matrix=K, distortion_coefficients=D4
    )
    assert read_opencv_yaml(path, model="fisheye") == lens
    assert type(read_opencv_yaml(path)) is BrownLens  # 4 coefficients read as k1, k2, p1, p2


def test_opencv_4_yaml_header(tmp_path):
    # OpenCV 4.x writes the non-standard directive "%YAML:1.0" and exponents without dots
    text = """%YAML:1.0
---
image_width: 1280
image_height: 960
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1.2104e+03, 0., 6.4130e+02, 0., 1.2045e+03, 4.7820e+02, 0.,
       0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -8.0e-02, 2.0e-02, 2e-4, -1e-4, -2.0e-03 ]
avg_reprojection_error: 2.1e-01
"""
    path = tmp_path / "out_camera_data.yml"
    path.write_text(text)
    lens = read_lens_file(path)
    assert (lens.fx, lens.fy, lens.cx, lens.cy) == (1210.4, 1204.5, 641.3, 478.2)
    assert lens.dist_coeffs.tolist() == [-0.08, 0.02, 2e-4, -1e-4, -2e-3, 0, 0, 0]


def test_opencv_yaml_errors(tmp_path):
    path = write_filestorage(
        tmp_path / "a.yml",
        image_width=640,
        image_height=480,
        camera_matrix=K,
        distortion_coefficients=np.zeros((1, 14)),
    )
    with pytest.raises(ValueError, match=r"a\.yml: .*14 values are not supported"):
        read_opencv_yaml(path)
    path = write_filestorage(tmp_path / "b.yml", image_width=640, image_height=480, distortion_coefficients=D5)
    with pytest.raises(ValueError, match=r"b\.yml: missing key: one of \['camera_matrix', 'K', 'cameraMatrix'\]"):
        read_opencv_yaml(path)
    path = write_filestorage(tmp_path / "c.yml", image_width=640, image_height=-480, camera_matrix=K)
    with pytest.raises(ValueError, match=r"c\.yml: image_height = -480: must be a positive integer"):
        read_opencv_yaml(path)
    path = write_filestorage(tmp_path / "d.yml", image_width=640, image_height=480, camera_matrix=K[:2])
    with pytest.raises(ValueError, match=r"d\.yml: camera_matrix = .*expected 3x3"):
        read_opencv_yaml(path)
    path = write_filestorage(
        tmp_path / "e.yml", image_width=640, image_height=480, camera_matrix=K, distortion_model="kb8"
    )
    with pytest.raises(ValueError, match=r"e\.yml: distortion_model = 'kb8': not a supported"):
        read_opencv_yaml(path)
    path = tmp_path / "f.yml"
    path.write_text(
        "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
        "  data: [1, 0, 1, 0, 1, 1, 0, 0, x]\nimage_width: 4\nimage_height: 4\n"
    )
    with pytest.raises(ValueError, match=r"f\.yml: camera_matrix = 'x': must be a number"):
        read_opencv_yaml(path)
    path.write_text("camera_matrix: [1, 2\n")
    with pytest.raises(ValueError, match=r"f\.yml: not valid YAML"):
        read_opencv_yaml(path)
    with pytest.raises(FileNotFoundError, match="lens file not found"):
        read_opencv_yaml(tmp_path / "missing.yml")


# --------------------------------------------------------------------------- ROS
ROS_YAML = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [503.25, 0, 321.75, 0, 502.5, 239.125, 0, 0, 1]
distortion_model: {model}
distortion_coefficients:
  rows: 1
  cols: {n}
  data: [{coeffs}]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [450.1, 0, 320.2, 0, 0, 449.8, 240.7, 0, 0, 0, 1, 0]
"""


@pytest.mark.parametrize(
    "model, coeffs, cls",
    [
        ("plumb_bob", D5.ravel(), BrownLens),
        ("rational_polynomial", D8.ravel(), BrownLens),
        ("equidistant", D4.ravel(), FisheyeLens),
    ],
)
def test_ros_camera_info(tmp_path, model, coeffs, cls):
    path = tmp_path / "camera.yaml"
    path.write_text(ROS_YAML.format(model=model, n=len(coeffs), coeffs=", ".join(repr(float(c)) for c in coeffs)))
    for lens in (read_ros_camera_info(path), read_lens_file(path)):
        assert type(lens) is cls
        np.testing.assert_array_equal(lens.K, K)  # ROS pixels are OpenCV's: unchanged
        assert lens.dist_coeffs[: len(coeffs)].tolist() == coeffs.tolist()
        assert (lens.width, lens.height) == (640, 480)


def test_ros_camera_info_errors(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text(ROS_YAML.format(model="fov", n=1, coeffs="0.9"))
    with pytest.raises(ValueError, match=r"camera\.yaml: distortion_model = 'fov': must be one of"):
        read_ros_camera_info(path)
    path.write_text(ROS_YAML.format(model="equidistant", n=5, coeffs="0, 0, 0, 0, 0"))
    with pytest.raises(ValueError, match=r"camera\.yaml: .*fisheye model takes exactly 4"):
        read_ros_camera_info(path)
    path.write_text(ROS_YAML.format(model="plumb_bob", n=6, coeffs="0, 0, 0, 0, 0"))
    with pytest.raises(ValueError, match=r"camera\.yaml: distortion_coefficients: rows x cols = 1 x 6 but 5"):
        read_ros_camera_info(path)
    path.write_text(re.sub(r"image_height: 480\n", "", ROS_YAML.format(model="plumb_bob", n=1, coeffs="0")))
    with pytest.raises(ValueError, match=r"camera\.yaml: missing key 'image_height'"):
        read_ros_camera_info(path)


# --------------------------------------------------------------------------- COLMAP
COLMAP_TXT = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
# Number of cameras: 7
1 SIMPLE_PINHOLE 640 480 500.0 320.0 240.0
2 PINHOLE 640 480 500.0 501.0 320.0 240.0

3 SIMPLE_RADIAL 3072 2304 2559.81 1536 1152 -0.0218531
4 RADIAL 640 480 500.0 320.0 240.0 -0.1 0.01
5 OPENCV 640 480 500.0 501.0 320.0 240.0 -0.2 0.04 1e-3 -5e-4
6 FULL_OPENCV 640 480 300.0 301.0 320.7 239.6 0.9 0.25 1e-3 -5e-4 0.005 1.3 0.45 0.03
7 OPENCV_FISHEYE 848 800 285.0 285.7 425.1 400.8 -0.0073 0.044 -0.042 0.0078
"""


def test_colmap_cameras(tmp_path):
    path = tmp_path / "cameras.txt"
    path.write_text(COLMAP_TXT)
    lenses = read_colmap_cameras(path)
    assert sorted(lenses) == [1, 2, 3, 4, 5, 6, 7]
    assert [type(lenses[i]) for i in range(1, 8)] == [
        PinholeLens,
        PinholeLens,
        BrownLens,
        BrownLens,
        BrownLens,
        BrownLens,
        FisheyeLens,
    ]
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5): (320.0, 240.0) -> (319.5, 239.5)
    assert (lenses[1].cx, lenses[1].cy) == (319.5, 239.5)
    assert (lenses[1].fx, lenses[1].fy) == (500.0, 500.0)
    assert (lenses[2].fx, lenses[2].fy, lenses[2].cx, lenses[2].cy) == (500.0, 501.0, 319.5, 239.5)
    assert lenses[3].k1 == -0.0218531 and (lenses[3].cx, lenses[3].cy) == (1535.5, 1151.5)
    assert (lenses[3].width, lenses[3].height) == (3072, 2304)
    assert (lenses[4].k1, lenses[4].k2, lenses[4].fy) == (-0.1, 0.01, 500.0)
    assert lenses[5].dist_coeffs.tolist() == [-0.2, 0.04, 1e-3, -5e-4, 0, 0, 0, 0]
    assert lenses[6].dist_coeffs.tolist() == [0.9, 0.25, 1e-3, -5e-4, 0.005, 1.3, 0.45, 0.03]
    assert lenses[6].cx == pytest.approx(320.2) and lenses[6].cy == pytest.approx(239.1)
    assert lenses[7].dist_coeffs.tolist() == [-0.0073, 0.044, -0.042, 0.0078]
    # COLMAP's own OPENCV projection (pixel = f * distorted + c, COLMAP pixels) is ours + 0.5
    x, y = 0.3, -0.2
    k1, k2, p1, p2 = -0.2, 0.04, 1e-3, -5e-4
    r2 = x * x + y * y
    radial = k1 * r2 + k2 * r2 * r2
    du = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    dv = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    u, v, _ = lenses[5].project([x, y, 1.0])
    assert float(u) + 0.5 == pytest.approx(500.0 * (x + du) + 320.0, abs=1e-9)
    assert float(v) + 0.5 == pytest.approx(501.0 * (y + dv) + 240.0, abs=1e-9)


@pytest.mark.parametrize(
    "line, pattern",
    [
        ("8 THIN_PRISM_FISHEYE 640 480 1 1 1 1 0 0 0 0 0 0 0 0", r"line 4: camera model 'THIN_PRISM_FISHEYE' is not"),
        ("8 OPENCV 640 480 500 500 320 240 0.1", r"line 4: OPENCV takes 8 parameters"),
        ("8 PINHOLE 640 480 500 abc 320 240", r"line 4: fy = 'abc': must be a number"),
        ("8 PINHOLE 640 480.5 500 500 320 240", r"line 4: CAMERA_ID, WIDTH, HEIGHT = '8', '640', '480.5'"),
        ("8 PINHOLE 640 480 -500 500 320 240", r"line 4: lens field fx = -500.0: must be a finite number > 0"),
        ("1 PINHOLE 640 480 500 500 320 240", r"line 4: camera id 1 appears twice"),
        ("8 PINHOLE 640", r"line 4: '8 PINHOLE 640': expected CAMERA_ID MODEL WIDTH HEIGHT"),
    ],
)
def test_colmap_errors(tmp_path, line, pattern):
    path = tmp_path / "cameras.txt"
    path.write_text("# comment\n1 PINHOLE 640 480 500 500 320 240\n\n" + line + "\n")
    with pytest.raises(ValueError, match=r"cameras\.txt: " + pattern):
        read_colmap_cameras(path)


# --------------------------------------------------------------------------- OpenSfM
OPENSFM = {
    "v2 sony a7 1600 1200 perspective 0.85": {
        "projection_type": "perspective",
        "width": 1600,
        "height": 1200,
        "focal": 0.85,
        "k1": -0.05,
        "k2": 0.01,
        "focal_prior": 0.85,
    },
    "brown cam": {
        "projection_type": "brown",
        "width": 1200,
        "height": 1600,
        "focal_x": 0.8,
        "focal_y": 0.81,
        "c_x": 0.01,
        "c_y": -0.02,
        "k1": -0.1,
        "k2": 0.02,
        "k3": -0.001,
        "p1": 1e-3,
        "p2": -5e-4,
    },
    "fish": {"projection_type": "fisheye", "width": 848, "height": 800, "focal": 0.336, "k1": -0.01, "k2": 0.04},
    "fish cv": {
        "projection_type": "fisheye_opencv",
        "width": 848,
        "height": 800,
        "focal_x": 0.336,
        "focal_y": 0.337,
        "c_x": 0.001,
        "c_y": 0.0,
        "k1": -0.0073,
        "k2": 0.044,
        "k3": -0.042,
        "k4": 0.0078,
    },
    "default type": {"width": 640, "height": 480, "focal": 1.0},
}


def opensfm_brown_pixel(cam, x, y):
    """OpenSfM's brown camera (docs "Geometric Models"), to normalised image coordinates,
    then to OpenCV pixels by OpenSfM's H = [[s, 0, (w-1)/2], [0, s, (h-1)/2], [0, 0, 1]]."""
    r2 = x * x + y * y
    d = 1 + cam["k1"] * r2 + cam["k2"] * r2**2 + cam["k3"] * r2**3
    xn = cam["focal_x"] * (d * x + 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)) + cam["c_x"]
    yn = cam["focal_y"] * (d * y + 2 * cam["p2"] * x * y + cam["p1"] * (r2 + 2 * y * y)) + cam["c_y"]
    s = max(cam["width"], cam["height"])
    return s * xn + (cam["width"] - 1) / 2, s * yn + (cam["height"] - 1) / 2


def test_opensfm_cameras(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(OPENSFM, indent=4))
    lenses = read_opensfm_cameras(path)
    assert list(lenses) == list(OPENSFM)
    p = lenses["v2 sony a7 1600 1200 perspective 0.85"]
    assert type(p) is BrownLens
    assert (p.fx, p.fy, p.cx, p.cy) == (0.85 * 1600, 0.85 * 1600, 799.5, 599.5)
    assert (p.k1, p.k2, p.p1, p.k3) == (-0.05, 0.01, 0.0, 0.0)
    b = lenses["brown cam"]
    assert b.fx == pytest.approx(0.8 * 1600) and b.fy == pytest.approx(0.81 * 1600)
    assert b.cx == pytest.approx(599.5 + 16.0) and b.cy == pytest.approx(799.5 - 32.0)
    assert b.dist_coeffs.tolist() == [-0.1, 0.02, 1e-3, -5e-4, -0.001, 0, 0, 0]
    for x, y in ((0.2, -0.3), (-0.4, 0.1)):
        u, v, _ = b.project([x, y, 1.0])
        assert (float(u), float(v)) == pytest.approx(opensfm_brown_pixel(OPENSFM["brown cam"], x, y), abs=1e-9)
    f = lenses["fish"]
    assert type(f) is FisheyeLens and f.fx == f.fy == pytest.approx(0.336 * 848)
    assert (f.cx, f.cy, f.k1, f.k2, f.k3, f.k4) == (423.5, 399.5, -0.01, 0.04, 0.0, 0.0)
    fc = lenses["fish cv"]
    assert fc.dist_coeffs.tolist() == [-0.0073, 0.044, -0.042, 0.0078] and fc.cx == pytest.approx(423.5 + 0.848)
    d = lenses["default type"]
    assert type(d) is BrownLens and d.fx == 640.0 and (d.cx, d.cy) == (319.5, 239.5)
    with pytest.raises(ValueError, match=r"5 cameras"):
        read_lens_file(path)
    assert read_lens_file(path, camera="fish") == f


@pytest.mark.parametrize(
    "cam, pattern",
    [
        (
            {"projection_type": "spherical", "width": 2, "height": 1},
            r"camera 'c': projection_type = 'spherical' is not",
        ),
        (
            {"projection_type": "brown", "width": 640, "height": 480, "focal_x": 1.0},
            r"camera 'c': missing key 'focal_y' of a brown camera",
        ),
        (
            {"projection_type": "fisheye", "width": 0, "height": 480, "focal": 1.0},
            r"camera 'c': width = 0: must be a positive integer",
        ),
        (
            {"projection_type": "perspective", "width": 640, "height": 480, "focal": "one"},
            r"camera 'c': focal = 'one': must be a number",
        ),
    ],
)
def test_opensfm_errors(tmp_path, cam, pattern):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"c": cam}))
    with pytest.raises(ValueError, match=r"cameras\.json: " + pattern):
        read_opensfm_cameras(path)


# --------------------------------------------------------------------------- dispatch
def test_read_lens_file_dispatch(tmp_path):
    path = tmp_path / "cameras.txt"
    path.write_text(COLMAP_TXT)
    assert read_lens_file(path, camera=7) == read_colmap_cameras(path)[7]
    with pytest.raises(ValueError, match=r"camera 9 not in the file"):
        read_lens_file(path, camera=9)
    with pytest.raises(ValueError, match=r"states its cameras' models"):
        read_lens_file(path, model="fisheye", camera=7)
    one = tmp_path / "one.txt"
    one.write_text("3 PINHOLE 640 480 500 500 320 240\n")
    assert read_lens_file(one).cx == 319.5
    sfm = tmp_path / "cams.json"
    sfm.write_text(json.dumps({"only": OPENSFM["fish"]}))
    assert type(read_lens_file(sfm)) is FisheyeLens
    ros = tmp_path / "ost.yaml"
    ros.write_text(ROS_YAML.format(model="equidistant", n=4, coeffs="0.1, 0.01, 0.001, 0.0001"))
    assert type(read_lens_file(ros)) is FisheyeLens
