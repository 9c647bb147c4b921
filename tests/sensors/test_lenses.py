"""Lens models (geoloc.sensors.lenses) against OpenCV, closed forms and their own inverses.

OpenCV is a test dependency only (opencv-python-headless). Run with ``-s`` to
see the largest disagreement with OpenCV per model.
"""

import math

import numpy as np
import pytest
from numba import njit

from geoloc.sensors.lenses import (
    BROWN,
    FISHEYE,
    PARAM_LAYOUT,
    PINHOLE,
    BrownLens,
    FisheyeLens,
    Lens,
    PinholeLens,
    lens_from_dict,
    lens_from_fov,
    lens_from_opencv,
    lens_to_dict,
    project_nb,
    unproject_map_nb,
    unproject_nb,
)
from geoloc.status import Status

import cv2  # noqa: E402  (opencv-python-headless: a test dependency, never skipped)

# OpenCV's iterative undistortion, asked to converge as far as it can.
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
ZERO3 = np.zeros(3)

MILD = BrownLens(
    fx=1210.0, fy=1204.5, cx=641.3, cy=478.2, width=1280, height=960, k1=-0.08, k2=0.02, p1=2e-4, p2=-1e-4, k3=-0.002
)
# Strong barrel distortion: the corners are 52 deg off axis, 0.3 of the way short of the fold
# of the polynomial (det J = 0 at r = 1.52, the corners undistort to r = 1.27).
STRONG = BrownLens(
    fx=450.0, fy=450.0, cx=319.5, cy=239.5, width=640, height=480, k1=-0.35, k2=0.15, p1=1e-3, p2=-5e-4, k3=-0.03
)
# Rational model (cv2.CALIB_RATIONAL_MODEL), wide angle: the corners are 58 deg off axis.
RATIONAL = BrownLens(
    fx=300.0,
    fy=301.0,
    cx=320.2,
    cy=239.1,
    width=640,
    height=480,
    k1=0.9,
    k2=0.25,
    p1=1e-3,
    p2=-5e-4,
    k3=0.005,
    k4=1.3,
    k5=0.45,
    k6=0.03,
)
# Equidistant fisheye with coefficients of the order of a calibrated Intel RealSense T265
# lens: its 90 deg circle (180 deg field of view) has a radius of 400 px, inscribed in the
# 800 px height, so the corners of the sensor lie beyond 90 deg.
FISHEYE_180 = FisheyeLens(
    fx=285.0, fy=285.7, cx=424.6, cy=400.3, width=848, height=800, k1=-0.0073, k2=0.044, k3=-0.042, k4=0.0078
)

BROWN_LENSES = {"mild": MILD, "strong": STRONG, "rational": RATIONAL}

# Largest disagreement with OpenCV per case, printed at the end of the module (pytest -s).
WORST: dict[str, float] = {}


@pytest.fixture(scope="module", autouse=True)
def _report():
    yield
    for name, err in sorted(WORST.items()):
        print(f"\nlargest disagreement with OpenCV, {name}: {err:.3e} px")


def note(name, err):
    WORST[name] = max(WORST.get(name, 0.0), float(err))


def sensor_grid(lens, nu=97, nv=73):
    """Pixels covering the whole sensor, its outer edges and corners included."""
    u, v = np.meshgrid(np.linspace(-0.5, lens.width - 0.5, nu), np.linspace(-0.5, lens.height - 0.5, nv))
    return u.ravel(), v.ravel()


def cv_project(lens, dirs):
    """cv2.projectPoints (Brown) or cv2.fisheye.projectPoints (alpha = skew / fx)."""
    pts = np.ascontiguousarray(dirs, dtype=float).reshape(-1, 1, 3)
    if lens.model == "fisheye":
        img, _ = cv2.fisheye.projectPoints(pts, ZERO3, ZERO3, lens.K, lens.dist_coeffs, alpha=lens.skew / lens.fx)
    else:
        img, _ = cv2.projectPoints(pts, ZERO3, ZERO3, lens.K, lens.dist_coeffs)
    return img[:, 0, 0], img[:, 0, 1]


def cv_undistort(lens, u, v):
    """OpenCV's undistortion to normalised coordinates (x/z, y/z)."""
    pts = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(float)
    if lens.model == "fisheye":
        try:
            out = cv2.fisheye.undistortPoints(pts, lens.K, lens.dist_coeffs, criteria=CRITERIA)
        except TypeError:  # OpenCV before 4.6 has no criteria argument (10 iterations, 1e-8)
            out = cv2.fisheye.undistortPoints(pts, lens.K, lens.dist_coeffs)
    else:
        out = cv2.undistortPoints(pts, lens.K, lens.dist_coeffs, None, None, criteria=CRITERIA)
    return out[:, 0, 0], out[:, 0, 1]


def random_dirs(lens, n, rng, max_angle):
    """Directions up to max_angle off the axis (inside the sensor's field of view)."""
    th = max_angle * np.sqrt(rng.random(n))
    ph = 2 * np.pi * rng.random(n)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)


# --------------------------------------------------------------------------- forward model
@pytest.mark.parametrize("name", BROWN_LENSES)
def test_brown_project_equals_cv2_projectPoints(name):
    lens = BROWN_LENSES[name]
    u0, v0 = sensor_grid(lens)
    dirs = lens.unproject(u0, v0)  # directions that fill the whole sensor
    dirs = np.concatenate([dirs, random_dirs(lens, 2000, np.random.default_rng(1), 0.9)])
    u, v, status = lens.project(dirs * 3.7)  # any length
    uc, vc = cv_project(lens, dirs)
    err = np.max(np.hypot(u - uc, v - vc))
    note(f"brown/{name} project vs cv2.projectPoints", err)
    assert np.all(status == Status.OK)
    # Same formula in double precision: the two differ by rounding only (~1e-12 px here).
    assert err < 1e-4


def test_fisheye_project_equals_cv2_fisheye_projectPoints():
    # with a skew: cv2.fisheye's relative alpha = skew / fx
    for lens in (FISHEYE_180, FISHEYE_180.with_params(skew=0.8)):
        dirs = random_dirs(lens, 5000, np.random.default_rng(2), np.radians(89.0))
        u, v, status = lens.project(dirs)
        uc, vc = cv_project(lens, dirs)
        err = np.max(np.hypot(u - uc, v - vc))
        note("fisheye project vs cv2.fisheye.projectPoints", err)
        assert np.all(status == Status.OK)
        assert err < 1e-4  # same formula, rounding only


# --------------------------------------------------------------------------- inverse model
@pytest.mark.parametrize("name", BROWN_LENSES)
def test_brown_unproject_over_whole_sensor(name):
    lens = BROWN_LENSES[name]
    u, v = sensor_grid(lens)
    d = lens.unproject(u, v)
    assert not np.isnan(d).any(), "the inversion must converge everywhere on the sensor"
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-15)
    # Our own forward model: Newton stops at steps < 1e-14 in normalised coordinates, i.e.
    # < 1e-11 px at f < 1300 px; 1e-6 px leaves room for rounding in the corners.
    uu, vv, _ = lens.project(d)
    assert np.max(np.hypot(uu - u, vv - v)) < 1e-6
    # OpenCV's forward model of our directions must land on the pixel we started from.
    uc, vc = cv_project(lens, d)
    err = np.max(np.hypot(uc - u, vc - v))
    note(f"brown/{name} cv2.projectPoints(unproject) vs pixel", err)
    assert err < 1e-4
    # cv2.undistortPoints, where its fixed-point iteration converged (its own reprojection
    # lands within 1e-6 px); compared in normalised coordinates scaled by the focal length
    # (pixels on the undistorted image plane).
    xc, yc = cv_undistort(lens, u, v)
    ur, vr = cv_project(lens, np.stack([xc, yc, np.ones_like(xc)], axis=-1))
    converged = np.hypot(ur - u, vr - v) < 1e-6
    assert converged.mean() > 0.5
    x, y = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
    err = np.max(np.hypot(lens.fx * (x - xc), lens.fy * (y - yc))[converged])
    note(f"brown/{name} unproject vs cv2.undistortPoints ({converged.sum()}/{converged.size} converged)", err)
    assert err < 1e-4


def test_fisheye_unproject_over_whole_sensor():
    lens = FISHEYE_180
    u, v = sensor_grid(lens)
    d = lens.unproject(u, v)
    # Pixels beyond the 90 deg circle have no direction in front of the camera: NaN, and only those.
    xd, yd = (u - lens.cx - lens.skew * (v - lens.cy) / lens.fy) / lens.fx, (v - lens.cy) / lens.fy
    theta_d_90 = math.pi / 2 * (1 + sum(k * (math.pi / 2) ** (2 * i + 2) for i, k in enumerate(lens.dist_coeffs)))
    beyond = np.hypot(xd, yd) >= theta_d_90
    assert beyond.any() and not beyond.all()
    np.testing.assert_array_equal(np.isnan(d[:, 0]), beyond)
    inside = ~beyond
    d, u, v = d[inside], u[inside], v[inside]
    uu, vv, _ = lens.project(d)
    assert np.max(np.hypot(uu - u, vv - v)) < 1e-6  # Newton to 1e-14 rad; see the Brown test
    uc, vc = cv_project(lens, d)
    err = np.max(np.hypot(uc - u, vc - v))
    note("fisheye cv2.fisheye.projectPoints(unproject) vs pixel", err)
    assert err < 1e-4
    # cv2.fisheye.undistortPoints: compare angles (normalised coordinates grow as tan(theta),
    # which amplifies any difference near 90 deg), in pixels at the focal length.
    xc, yc = cv_undistort(lens, u, v)
    dc = np.stack([xc, yc, np.ones_like(xc)], axis=-1)
    dc /= np.linalg.norm(dc, axis=-1, keepdims=True)
    ur, vr = cv_project(lens, dc)
    converged = np.hypot(ur - u, vr - v) < 1e-6
    assert converged.mean() > 0.5
    angle = np.arctan2(np.linalg.norm(np.cross(d, dc), axis=-1), np.sum(d * dc, axis=-1))
    err = np.max(lens.fx * angle[converged])
    note(f"fisheye unproject vs cv2.fisheye.undistortPoints ({converged.sum()}/{converged.size} converged)", err)
    assert err < 1e-4


@pytest.mark.parametrize(
    "lens",
    [
        MILD,
        STRONG,
        RATIONAL,
        FISHEYE_180,
        PinholeLens(fx=800.0, fy=810.0, cx=300.2, cy=201.9, width=600, height=400, skew=1.5),
        STRONG.with_params(skew=2.0),
    ],
    ids=lambda lens: lens.model,
)
def test_round_trip_directions(lens):
    rng = np.random.default_rng(3)
    dirs = random_dirs(lens, 3000, rng, 0.7)
    u, v, status = lens.project(dirs)
    assert np.all(status == Status.OK)
    # Newton to 1e-14: the directions come back to ~1e-14 rad.
    np.testing.assert_allclose(lens.unproject(u, v), dirs, atol=1e-12)


def test_broadcasting_and_status():
    lens = STRONG
    dirs = np.array([[[0.1, 0.2, 1.0], [0.0, 0.0, -1.0]], [[0.3, 0.0, 0.0], [np.nan, 0.0, 1.0]]])
    u, v, status = lens.project(dirs)
    assert u.shape == v.shape == status.shape == (2, 2) and status.dtype == np.uint8
    assert status.tolist() == [[Status.OK, Status.BEHIND_CAMERA], [Status.BEHIND_CAMERA, Status.INVALID_INPUT]]
    assert np.isfinite(u[0, 0]) and np.isnan(u[0, 1]) and np.isnan(v[1, 0]) and np.isnan(u[1, 1])
    d = lens.unproject(np.array([[0.0], [100.0]]), np.array([10.0, 20.0, 30.0]))
    assert d.shape == (2, 3, 3)
    assert lens.unproject(319.5, 239.5).tolist() == [0.0, 0.0, 1.0]
    assert np.isnan(lens.unproject(np.nan, 0.0)).all()


def test_unproject_nan_outside_the_models_domain():
    # Far outside the sensor the strong barrel polynomial folds over (max r_d ~ 0.945 at
    # r ~ 1.52): no valid direction. (Newton finds the root x = -2.19, where R < 0 maps the
    # point to the other side of the axis; it is rejected.)
    d = STRONG.unproject(STRONG.cx + 450.0 * np.array([1.2, 0.99]), STRONG.cy)
    assert np.isnan(d).all()
    d = FISHEYE_180.unproject(FISHEYE_180.cx + np.array([0.0, 1e4]), FISHEYE_180.cy)
    assert np.isfinite(d[0]).all() and np.isnan(d[1]).all()


def test_in_image():
    lens = PinholeLens(fx=100.0, fy=100.0, cx=1.5, cy=0.5, width=4, height=2)
    u = np.array([-0.5, -0.51, 3.5, 3.51, 1.0, 1.0, 1.0])
    v = np.array([-0.5, 0.0, 1.5, 0.0, -0.51, 1.5, 1.51])
    assert lens.in_image(u, v).tolist() == [True, False, True, False, False, True, False]


# --------------------------------------------------------------------------- closed forms
def test_fov_90_edge_pixel_is_45_degrees():
    lens = lens_from_fov(math.radians(90.0), math.radians(60.0), 640, 480)
    assert lens.fx == pytest.approx(320.0) and lens.fy == pytest.approx(240.0 / math.tan(math.radians(30.0)))
    assert (lens.cx, lens.cy) == (319.5, 239.5)
    # outer edges of the sensor: u = -0.5, width - 0.5; v = -0.5, height - 0.5
    d = lens.unproject([-0.5, 639.5, 319.5, 319.5], [239.5, 239.5, -0.5, 479.5])
    angles = np.degrees(np.arccos(d[:, 2]))
    np.testing.assert_allclose(angles, [45.0, 45.0, 30.0, 30.0], atol=1e-12)
    np.testing.assert_allclose(d[0], [-math.sqrt(0.5), 0.0, math.sqrt(0.5)], atol=1e-15)
    u, v, _ = lens.project([1.0, 0.0, 1.0])
    assert (float(u), float(v)) == pytest.approx((639.5, 239.5))


def test_brown_closed_form_single_point():
    # x = 0.5, y = 0.25: r2 = 0.3125; R = 1 - 0.1 * 0.3125; tangential by hand
    lens = BrownLens(fx=100.0, fy=200.0, cx=10.0, cy=20.0, width=50, height=50, skew=3.0, k1=-0.1, p1=0.01, p2=0.02)
    x, y, r2 = 0.5, 0.25, 0.3125
    R = 1 - 0.1 * r2
    xd = x * R + 2 * 0.01 * x * y + 0.02 * (r2 + 2 * x * x)
    yd = y * R + 0.01 * (r2 + 2 * y * y) + 2 * 0.02 * x * y
    u, v, _ = lens.project([x, y, 1.0])
    assert float(u) == pytest.approx(100 * xd + 3 * yd + 10, abs=1e-12)
    assert float(v) == pytest.approx(200 * yd + 20, abs=1e-12)


# --------------------------------------------------------------------------- compiled path
@njit(cache=True)
def _nb_unproject_all(code, p, u, v):
    out = np.empty((u.size, 3))
    for i in range(u.size):
        out[i, 0], out[i, 1], out[i, 2] = unproject_nb(code, p, u[i], v[i])
    return out


@njit(cache=True)
def _nb_project_all(code, p, d):
    u = np.empty(d.shape[0])
    v = np.empty(d.shape[0])
    ok = np.empty(d.shape[0], dtype=np.bool_)
    for i in range(d.shape[0]):
        u[i], v[i], ok[i] = project_nb(code, p, d[i, 0], d[i, 1], d[i, 2])
    return u, v, ok


@pytest.mark.parametrize(
    "lens",
    [
        MILD,
        STRONG,
        RATIONAL,
        FISHEYE_180.with_params(skew=0.5),
        PinholeLens(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480),
    ],
    ids=lambda lens: lens.model,
)
def test_numba_kernels_equal_numpy_path(lens):
    u, v = sensor_grid(lens, 41, 31)
    u = np.concatenate([u, [np.nan, 1e9]])
    v = np.concatenate([v, [0.0, 0.0]])
    d_np = lens.unproject(u, v)
    d_nb = _nb_unproject_all(lens.code, lens.as_array(), u, v)
    np.testing.assert_array_equal(np.isnan(d_nb), np.isnan(d_np))
    np.testing.assert_allclose(d_nb, d_np, rtol=1e-12, atol=1e-15)
    dirs = np.concatenate(
        [
            random_dirs(lens, 500, np.random.default_rng(4), 0.8),
            [[0.0, 0.0, 1.0], [0.1, 0.1, -1.0], [0.1, 0.1, 0.0], [np.nan, 0.0, 1.0]],
        ]
    )
    uu, vv, status = lens.project(dirs)
    un, vn, ok = _nb_project_all(lens.code, lens.as_array(), dirs)
    np.testing.assert_array_equal(ok, status == Status.OK)
    np.testing.assert_allclose(un[ok], uu[ok], rtol=1e-12)
    np.testing.assert_allclose(vn[ok], vv[ok], rtol=1e-12)
    assert np.isnan(un[~ok]).all() and np.isnan(vn[~ok]).all()


def test_as_array_layout():
    assert PARAM_LAYOUT == ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
    assert (PINHOLE, BROWN, FISHEYE) == (0, 1, 2)
    assert RATIONAL.as_array().tolist() == [
        300.0,
        301.0,
        320.2,
        239.1,
        0.0,
        0.9,
        0.25,
        1e-3,
        -5e-4,
        0.005,
        1.3,
        0.45,
        0.03,
    ]
    f = FisheyeLens(fx=1.0, fy=2.0, cx=3.0, cy=4.0, width=5, height=6, skew=7.0, k1=8.0, k2=9.0, k3=10.0, k4=11.0)
    assert f.as_array().tolist() == [1.0, 2.0, 3.0, 4.0, 7.0, 8.0, 9.0, 0.0, 0.0, 10.0, 11.0, 0.0, 0.0]
    assert (PinholeLens.code, BrownLens.code, FisheyeLens.code) == (PINHOLE, BROWN, FISHEYE)


# --------------------------------------------------------------------------- parameters
def test_params_with_params_K_dist_coeffs():
    assert list(STRONG.params) == ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"]
    assert list(FISHEYE_180.params) == ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "k4"]
    assert list(PinholeLens(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=1, height=1).params) == [
        "fx",
        "fy",
        "cx",
        "cy",
        "skew",
    ]
    lens = STRONG.with_params(fx=451.0, k2=0.2)
    assert type(lens) is BrownLens and lens.fx == 451.0 and lens.k2 == 0.2 and lens.k1 == STRONG.k1
    assert STRONG.fx == 450.0  # frozen original untouched
    with pytest.raises(ValueError, match=r"k5.*fisheye|fisheye.*k5"):
        FISHEYE_180.with_params(k5=0.1)
    with pytest.raises(ValueError, match="lens field fy = -1.0"):
        STRONG.with_params(fy=-1.0)
    np.testing.assert_array_equal(STRONG.K, [[450.0, 0.0, 319.5], [0.0, 450.0, 239.5], [0.0, 0.0, 1.0]])
    assert STRONG.with_params(skew=2.0).K[0, 1] == 2.0
    assert STRONG.dist_coeffs.tolist() == [-0.35, 0.15, 1e-3, -5e-4, -0.03, 0.0, 0.0, 0.0]
    assert FISHEYE_180.dist_coeffs.tolist() == [-0.0073, 0.044, -0.042, 0.0078]
    assert PinholeLens(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=1, height=1).dist_coeffs.shape == (0,)
    assert (PinholeLens.model, BrownLens.model, FisheyeLens.model) == ("pinhole", "brown", "fisheye")
    with pytest.raises(TypeError):
        Lens(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=1, height=1)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("fx", -3.0, "lens field fx = -3.0: must be a finite number > 0"),
        ("fy", 0, "lens field fy = 0.0: must be a finite number > 0"),
        ("cx", float("nan"), "lens field cx = nan: must be a finite number"),
        ("skew", "1", "lens field skew = '1': must be a finite number"),
        ("k3", float("inf"), "lens field k3 = inf: must be a finite number"),
        ("width", 0, "lens field width = 0: must be a positive integer"),
        ("height", 480.0, "lens field height = 480.0: must be a positive integer"),
        ("width", True, "lens field width = True: must be a positive integer"),
    ],
)
def test_invalid_fields_name_field_and_value(field, value, message):
    args = {"fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}
    args[field] = value
    with pytest.raises(ValueError) as e:
        BrownLens(**args)
    assert str(e.value) == message


def test_fields_are_stored_as_python_numbers():
    lens = BrownLens(fx=np.float64(500), fy=500, cx=np.float32(1.5), cy=0, width=np.int64(640), height=480, k1=1)
    assert type(lens.fx) is float and type(lens.fy) is float and type(lens.k1) is float
    assert type(lens.width) is int and lens.cx == 1.5


def test_lens_from_fov_errors():
    with pytest.raises(ValueError, match="hfov = 3.2"):
        lens_from_fov(3.2, 1.0, 640, 480)
    with pytest.raises(ValueError, match="vfov = 0.0"):
        lens_from_fov(1.0, 0.0, 640, 480)
    with pytest.raises(ValueError, match="width = -640"):
        lens_from_fov(1.0, 1.0, -640, 480)


# --------------------------------------------------------------------------- OpenCV results
def test_lens_from_opencv():
    K = np.array([[500.0, 0.3, 319.0], [0.0, 501.0, 241.0], [0.0, 0.0, 1.0]])
    lens = lens_from_opencv(K, np.array([[-0.1, 0.01, 1e-4, 2e-4, 0.001]]), (640, 480))
    assert type(lens) is BrownLens and lens.skew == 0.3 and (lens.width, lens.height) == (640, 480)
    assert lens.dist_coeffs.tolist() == [-0.1, 0.01, 1e-4, 2e-4, 0.001, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(lens.K, K)
    assert lens_from_opencv(K, np.arange(8.0) / 100, (640, 480)).k6 == 0.07
    assert lens_from_opencv(K, [0.1, 0.2, 0.3, 0.4], (640, 480)).p2 == 0.4
    zero = lens_from_opencv(K, np.zeros(5), (640, 480))
    assert type(zero) is BrownLens and not zero.dist_coeffs.any()
    assert type(lens_from_opencv(K, None, (640, 480))) is BrownLens
    fish = lens_from_opencv(K, [0.1, 0.01, 0.001, 1e-4], (640, 480), model="fisheye")
    assert type(fish) is FisheyeLens and fish.k4 == 1e-4 and fish.skew == 0.3
    for n in (12, 14):
        with pytest.raises(ValueError, match=f"{n} values are not supported"):
            lens_from_opencv(K, np.zeros(n), (640, 480))
    with pytest.raises(ValueError, match="exactly 4"):
        lens_from_opencv(K, np.zeros(5), (640, 480), model="fisheye")
    with pytest.raises(ValueError, match="camera matrix"):
        lens_from_opencv(K.T, np.zeros(5), (640, 480))
    with pytest.raises(ValueError, match="'kb8'"):
        lens_from_opencv(K, np.zeros(4), (640, 480), model="kb8")


def test_lens_from_opencv_calibration_round_trip():
    """cv2.calibrateCamera on synthetic views of a planar target recovers our lens."""
    lens = MILD
    rng = np.random.default_rng(5)
    gx, gy = np.meshgrid(np.arange(-5, 6) * 0.05, np.arange(-4, 5) * 0.05)
    board = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=-1)
    objs, imgs = [], []
    for _ in range(12):
        rvec = rng.normal(0, 0.25, 3)
        tvec = np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(1.0, 1.4)])
        R, _ = cv2.Rodrigues(rvec)
        u, v, status = lens.project(board @ R.T + tvec)
        assert lens.in_image(u, v).all() and (status == Status.OK).all()
        objs.append(board.astype(np.float32))
        imgs.append(np.stack([u, v], axis=-1).astype(np.float32))
    _, K, dist, _, _ = cv2.calibrateCamera(
        objs,
        imgs,
        (lens.width, lens.height),
        None,
        None,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )
    fitted = lens_from_opencv(K, dist, (lens.width, lens.height))
    # float32 image points (~3e-5 px rounding): the fit reproduces the pixels to ~1e-3 px
    u, v = sensor_grid(lens, 17, 13)
    uf, vf, _ = fitted.project(lens.unproject(u, v))
    assert np.max(np.hypot(uf - u, vf - v)) < 0.01


# --------------------------------------------------------------------------- sensor file table
def test_lens_dict_round_trip_and_one_based_pixels():
    data = {
        "model": "brown",
        "fx": 450.0,
        "fy": 450.0,
        "cx": 320.5,
        "cy": 240.5,
        "width": 640,
        "height": 480,
        "k1": -0.35,
        "k2": 0.15,
        "p1": 1e-3,
        "p2": -5e-4,
        "k3": -0.03,
    }
    lens = lens_from_dict(data, "sensor.toml")
    assert lens == STRONG  # cx, cy 1-based in the file: 320.5 -> 319.5
    out = lens_to_dict(lens)
    assert out["cx"] == 320.5 and out["cy"] == 240.5 and out["model"] == "brown"
    assert lens_from_dict(out, "x") == lens
    for lens in (FISHEYE_180, PinholeLens(fx=800.0, fy=810.0, cx=300.0, cy=201.0, width=600, height=400, skew=1.5)):
        back = lens_from_dict(lens_to_dict(lens), "x")
        assert type(back) is type(lens)
        assert back.params == pytest.approx(lens.params, abs=1e-12)


def test_lens_dict_fov():
    lens = lens_from_dict({"model": "fov", "hfov_deg": 90.0, "vfov_deg": 60, "width": 640, "height": 480}, "s")
    assert type(lens) is PinholeLens and lens.fx == pytest.approx(320.0) and (lens.cx, lens.cy) == (319.5, 239.5)
    lens = lens_from_dict(
        {"model": "fov", "hfov_deg": 90.0, "vfov_deg": 60, "width": 640, "height": 480, "cx": 300.0, "cy": 200.0}, "s"
    )
    assert (lens.cx, lens.cy) == (299.0, 199.0)


@pytest.mark.parametrize(
    "data, pattern",
    [
        ({"fx": 1.0}, r"sensor\.toml: lens key model missing"),
        ({"model": "kb8"}, r"sensor\.toml: lens key model = 'kb8'"),
        (
            {"model": "pinhole", "fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4, "k1": 0.1},
            r"sensor\.toml: lens key k1 = 0\.1: not a key of a pinhole lens",
        ),
        (
            {"model": "brown", "fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4, "focal": 3.0},
            r"sensor\.toml: lens key focal = 3\.0: not a key of a brown lens",
        ),
        (
            {"model": "brown", "fx": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4},
            r"sensor\.toml: lens key\(s\) \['fy'\] missing",
        ),
        (
            {"model": "fisheye", "fx": "500", "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4},
            r"sensor\.toml: lens key fx = '500': must be a number",
        ),
        (
            {"model": "fisheye", "fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4.0, "height": 4},
            r"sensor\.toml: lens key width = 4\.0: must be an integer",
        ),
        (
            {"model": "fisheye", "fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4, "k5": 0.0},
            r"sensor\.toml: lens key k5 = 0\.0: not a key of a fisheye lens",
        ),
        (
            {"model": "brown", "fx": -3.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4},
            r"sensor\.toml: lens field fx = -3\.0: must be a finite number > 0",
        ),
        (
            {"model": "fov", "hfov_deg": 190.0, "vfov_deg": 60.0, "width": 4, "height": 4},
            r"sensor\.toml: lens key hfov_deg = 190\.0: must be a field of view in \(0, 180\) degrees",
        ),
        (
            {"model": "fov", "hfov_deg": 90.0, "vfov_deg": 60.0, "width": 4, "height": 4, "fx": 3.0},
            r"sensor\.toml: lens key fx = 3\.0: not a key of a fov lens",
        ),
        (
            {"model": "pinhole", "fx": True, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 4, "height": 4},
            r"sensor\.toml: lens key fx = True: must be a number",
        ),
    ],
)
def test_lens_dict_errors(data, pattern):
    with pytest.raises(ValueError, match=pattern):
        lens_from_dict(data, "sensor.toml")


# --------------------------------------------------------------------------- the fast path's map
def _nb_unproject_map_all(code, p, u, v):
    out = np.empty((u.size, 3))
    for i in range(u.size):
        out[i, 0], out[i, 1], out[i, 2] = unproject_map_nb(code, p, u[i], v[i])
    return out


_nb_unproject_map_all = njit(_nb_unproject_map_all)


@pytest.mark.parametrize("name", BROWN_LENSES)
def test_map_unproject_equals_full_newton_and_opencv(name):
    # the undistortion map + two Newton steps (the kernel's inverse) against the full iteration
    # over a dense grid of the whole sensor, its edges and a margin off it (off the map: the
    # full iteration), and against cv2.undistortPoints where OpenCV converged
    lens = BROWN_LENSES[name]
    p = lens.kernel_array()
    assert p.size > len(PARAM_LAYOUT) and lens.kernel_array() is p  # built once, cached on the lens
    u, v = sensor_grid(lens, 257, 193)
    rng = np.random.default_rng(11)
    u = np.concatenate([u, rng.uniform(-60, lens.width + 60, 4000), [np.nan, 1e9]])
    v = np.concatenate([v, rng.uniform(-60, lens.height + 60, 4000), [0.0, 0.0]])
    d_full = _nb_unproject_all(lens.code, lens.as_array(), u, v)
    d_map = _nb_unproject_map_all(lens.code, np.array(p), u, v)
    np.testing.assert_array_equal(np.isnan(d_map), np.isnan(d_full))
    ok = ~np.isnan(d_full[:, 0])
    # the same root: Newton's error after the second step is ~M e^2 with e ~1e-5 from the map,
    # i.e. rounding; 1e-15 on unit vectors is ~5 ulps, 1e-12 px at these focal lengths
    err = np.max(np.abs(d_map[ok] - d_full[ok]))
    note(f"brown/{name} map + 2 Newton steps vs full Newton (unit vectors)", err)
    assert err <= 1e-15
    on = lens.in_image(u, v) & ok
    xc, yc = cv_undistort(lens, u[on], v[on])
    ur, vr = cv_project(lens, np.stack([xc, yc, np.ones_like(xc)], axis=-1))
    conv = np.hypot(ur - u[on], vr - v[on]) < 1e-6
    x, y = d_map[on, 0] / d_map[on, 2], d_map[on, 1] / d_map[on, 2]
    assert np.max(np.hypot(lens.fx * (x - xc), lens.fy * (y - yc))[conv]) < 1e-4  # as the numpy path's test
    # a plain as_array() vector (no map) is the full iteration: the same steps, to the last bits. Compiled
    # apart (the full one cached by this file, the map one by its callers) LLVM may fuse a*b+c into one
    # multiply-add in one and not the other: CI saw 1-3 ulps (2.2e-16 to 6.7e-16 on these unit vectors);
    # 1e-15 is the bound of the map's own check above, and a wrong iteration is off by far more (1e-5)
    d_plain = _nb_unproject_map_all(lens.code, lens.as_array(), u, v)
    np.testing.assert_array_equal(np.isnan(d_plain), np.isnan(d_full))
    np.testing.assert_allclose(d_plain, d_full, rtol=0, atol=1e-15)


# --------------------------------------------------------------------------- per-sample parameters
def test_per_sample_parameters_equal_one_lens_per_sample():
    # a lens whose parameters are arrays (Monte Carlo's draws) gives, element by element, what the
    # scalar lens with that element's parameters gives (the oracle: one lens per sample), and a
    # sample that is not a lens (fx <= 0, NaN) gives NaN / INVALID_INPUT, not an exception
    rng = np.random.default_rng(12)
    n = 40
    draws = {
        "fx": MILD.fx + rng.normal(0, 5, n),
        "cy": MILD.cy + rng.normal(0, 2, n),
        "k1": MILD.k1 + rng.normal(0, 0.01, n),
        "p2": MILD.p2 + rng.normal(0, 1e-4, n),
    }
    draws["fx"][3] = -1.0
    draws["cy"][5] = np.nan
    batch = MILD.with_params(**draws)
    assert batch.batched and not MILD.batched
    u, v = rng.uniform(0, 1279, n), rng.uniform(0, 959, n)
    d = batch.unproject(u, v)
    dirs = random_dirs(MILD, n, rng, 0.8)
    pu, pv, st = batch.project(dirs)
    for k in range(n):
        if k in (3, 5):
            assert np.isnan(d[k]).all() and st[k] == Status.INVALID_INPUT and np.isnan(pu[k])
            continue
        one = MILD.with_params(**{name: float(a[k]) for name, a in draws.items()})
        # the batch iterates until every sample's Newton step is < 1e-14, so a sample may take one
        # step more than alone: rounding, 1e-15 on a unit vector (~5 ulps)
        np.testing.assert_allclose(d[k], one.unproject(u[k], v[k]), rtol=0, atol=1e-15)
        qu, qv, qs = one.project(dirs[k])
        assert (pu[k], pv[k], st[k]) == (float(qu), float(qv), int(qs))
    with pytest.raises(ValueError, match="per-sample"):
        batch.as_array()
    with pytest.raises(ValueError, match="lens field fx"):
        MILD.with_params(fx=np.array(["a", "b"]))
