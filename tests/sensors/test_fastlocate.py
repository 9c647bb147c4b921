"""The fused numba kernel equals the numpy FrameChain reference path ray for ray."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from geoloc.frames.chain import Pose
from geoloc.locate import locate
from geoloc.sensors.camera import Camera
from geoloc.status import Status

CAM = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)


def _compare(pose, rows, cols, h):
    ref = locate(pose, CAM, rows, cols, target_h=h, engine="numpy")
    fast = locate(pose, CAM, rows, cols, target_h=h, engine="numba")
    assert np.array_equal(ref.status, fast.status)
    ok = ref.status == Status.OK
    # Same formulas in another order of floating-point operations: 1e-6 m on
    # 6.4e6-m coordinates is a few ulps; 1e-12 rad is 6 um on the ground.
    assert np.allclose(ref.ecef[ok], fast.ecef[ok], rtol=0, atol=1e-6)
    assert np.allclose(ref.lat[ok], fast.lat[ok], rtol=0, atol=1e-12)
    assert np.allclose(ref.lon[ok], fast.lon[ok], rtol=0, atol=1e-12)
    assert np.allclose(ref.h[ok], fast.h[ok], rtol=0, atol=1e-6)
    assert np.allclose(ref.los.direction_ecef, fast.los.direction_ecef, rtol=0, atol=1e-12, equal_nan=True)
    assert np.all(np.isnan(fast.lat[~ok]))


def test_random_batch_with_sky_invalid_and_below():
    rng = np.random.default_rng(3)
    n = 20_000
    pose = Pose.from_deg(
        rng.uniform(-89, 89, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-100, 40000, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-20, 20, n),
        rng.uniform(-30, 30, n),
        rng.uniform(-100, 100, n),
        rng.uniform(-30, 30, n),
    )
    pose = Pose(
        np.where(rng.random(n) < 0.01, np.nan, pose.lat),
        pose.lon,
        pose.h,
        pose.heading,
        pose.pitch,
        pose.roll,
        pose.gimbal_roll,
        pose.gimbal_pitch,
    )
    h = rng.uniform(-50, 6000, n)
    _compare(pose, rng.uniform(1, 2323, n), rng.uniform(1, 2292, n), h)
    st_ = locate(pose, CAM, rng.uniform(1, 2323, n), rng.uniform(1, 2292, n), target_h=h).status
    for code in (Status.OK, Status.SKY, Status.INVALID_INPUT, Status.ORIGIN_BELOW):
        assert np.any(st_ == code)  # the batch really exercises every branch


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-89.9, 89.9),
    st.floats(-180, 180),
    st.floats(100, 1e6),
    st.floats(-180, 180),
    st.floats(-80, 80),
    st.floats(-90, 90),
)
def test_single_rays(lat, lon, h, heading, groll, gpitch):
    pose = Pose.from_deg(lat, lon, h, heading, 2.0, -1.0, groll, gpitch)
    _compare(pose, 100.0, 2000.0, 0.0)


def test_auto_engine_respects_camera_boresight():
    # a camera with a boresight rotation must not take the kernel (which has none)
    cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292, boresight=(0.0, 0.01, 0.0))
    n = 12_000
    pose = Pose.from_deg(np.full(n, 35.48), 80.97, 18000.0, 45, 3.5, 0, 50, -2.6)
    auto = locate(pose, cam, target_h=5000.0)
    ref = locate(pose, cam, target_h=5000.0, engine="numpy")
    assert np.allclose(auto.ecef, ref.ecef, rtol=0, atol=1e-6)
    plain = locate(pose, CAM, target_h=5000.0)
    assert np.min(np.linalg.norm(auto.ecef - plain.ecef, axis=-1)) > 1.0


def test_kernel_compiles_once_for_readonly_writable_and_every_preset():
    # one signature whatever the caller hands in: read-only broadcast views, writable arrays,
    # scalars, any gimbal preset or lens (the chain is data, not code)
    from geoloc.sensors._fastlocate import locate_kernel
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import PRESETS
    from geoloc.sensors.lenses import BrownLens

    n = 10_000
    rng = np.random.default_rng(1)
    pose = Pose.from_deg(rng.uniform(30, 40, n), 80.0, 18000.0, 45.0, 3.5, 0.0, 50.0, -2.6)
    ro = np.broadcast_to(np.array(1162.0), (n,))  # read-only view
    locate(pose, CAM, ro, np.full(n, 1146.0), target_h=5083.5, engine="numba")
    locate(pose, CAM, np.full(n, 1162.0), 1146.0, target_h=np.full(n, 5083.5), engine="numba")
    lens = BrownLens(fx=1000.0, fy=1000.0, cx=499.5, cy=499.5, width=1000, height=1000, k1=-0.1)
    for preset in PRESETS:
        s = FrameSensor(lens, PRESETS[preset], lever_arm_m=(1.0, 0.0, 0.0))
        p = Pose.from_deg(
            rng.uniform(30, 40, n),
            80.0,
            1000.0,
            10.0,
            1.0,
            1.0,
            5.0,
            -70.0,
            angles_deg={a: 10.0 for a in s.angle_names if a not in ("gimbal_roll", "gimbal_pitch")},
        )
        locate(p, s, 500.0, 500.0, target_h=0.0, engine="numba")
    assert len(locate_kernel.signatures) == 1, locate_kernel.signatures


# ----------------------------------------------------------------- the speed-ups, each against an outside oracle
def test_sincos_block_equals_libm():
    # one range reduction + fdlibm's polynomials (sincos_lanes) against numpy's sin / cos (libm):
    # an absolute error of 2.3e-16 is two ulps of 1 (0.5 ulp from each of the reduction and the
    # polynomial); beyond 64 rad the block takes libm's own values
    from geoloc.sensors._fastlocate import _sincos_block

    rng = np.random.default_rng(5)
    a = np.concatenate(
        [
            rng.uniform(-64, 64, 200_000),
            rng.uniform(-1e-3, 1e-3, 1000),
            np.arange(-80, 81) * np.pi / 4,
            [0.0, -0.0, 5e-324, 2 * np.pi, -2 * np.pi, 100.0, -1e5],
        ]
    )
    s, c = np.empty_like(a), np.empty_like(a)
    _sincos_block(a, s, c)
    assert np.max(np.abs(s - np.sin(a))) <= 2.3e-16
    assert np.max(np.abs(c - np.cos(a))) <= 2.3e-16
    s1, c1 = np.empty(3), np.empty(3)
    _sincos_block(np.array([np.nan, np.inf, -np.inf]), s1, c1)
    assert np.all(np.isnan(s1)) and np.all(np.isnan(c1))


def test_geodetic_fast_equals_pyproj():
    # Vermeille with sqrt for hypot and atan for atan2, against PROJ's ECEF -> geodetic
    # (an outside implementation): 1e-14 rad is 0.06 um, 1e-7 m is rounding at 6.4e6 m
    import pyproj
    from numba import njit

    from geoloc.geodesy.ellipsoid import E2, A
    from geoloc.sensors._fastlocate import geodetic_fast

    @njit
    def run(x, y, z, out):
        for k in range(x.size):
            out[k, 0], out[k, 1], out[k, 2] = geodetic_fast(x[k], y[k], z[k], A, E2)

    rng = np.random.default_rng(6)
    n = 20_000
    lat, lon, h = rng.uniform(-89.99, 89.99, n), rng.uniform(-180, 180, n), rng.uniform(-500, 1e6, n)
    tr = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = tr.transform(lon, lat, h)
    out = np.empty((n, 3))
    run(np.asarray(x), np.asarray(y), np.asarray(z), out)
    np.testing.assert_allclose(np.rad2deg(out[:, 0]), lat, rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(np.rad2deg(out[:, 1]), lon, rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(out[:, 2], h, rtol=0, atol=1e-7)


def _turret():
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import PRESETS
    from geoloc.sensors.lenses import BrownLens

    lens = BrownLens(
        fx=2200.0,
        fy=2195.0,
        cx=959.5,
        cy=539.5,
        width=1920,
        height=1080,
        k1=-0.21,
        k2=0.07,
        p1=4e-4,
        p2=-2e-4,
        k3=-0.01,
    )
    return FrameSensor(
        lens,
        PRESETS["azimuth-elevation"],
        mount=(2e-3, -1e-3, 4e-3),
        boresight=(1e-3, 2e-3, -3e-3),
        lever_arm_m=(1.5, 0.2, 0.7),
    )


def _turret_poses(rng, n, heading_deg):
    """n random turret poses: anywhere within 60 deg of the equator, 300-8000 m, headings within
    +-heading_deg, azimuth over two turns, elevation -90 to -20 deg."""
    return Pose.from_deg(
        rng.uniform(-60, 60, n),
        rng.uniform(-180, 180, n),
        rng.uniform(300, 8000, n),
        rng.uniform(-heading_deg, heading_deg, n),
        rng.uniform(-8, 8, n),
        rng.uniform(-10, 10, n),
        angles_deg={"azimuth": rng.uniform(-360, 360, n), "elevation": rng.uniform(-90, -20, n)},
    )


def test_turret_kernel_equals_numpy_path_ray_for_ray():
    # the bench's second sensor: Brown lens through its undistortion map, az-el joints through
    # sincos, mount, boresight, lever arm sharing the attitude's trigonometry; pixels over the
    # whole sensor, its edges and off it (OUTSIDE_SENSOR, and extrapolated: off the map, so the
    # full Newton iteration), against the numpy reference path (libm, numpy Newton, Vermeille)
    s = _turret()
    rng = np.random.default_rng(8)
    n = 30_000
    pose = _turret_poses(rng, n, heading_deg=360)
    rows = np.concatenate([rng.uniform(0.5, 1080.5, n - 400), rng.choice([0.5, 1080.5, -30.0, 1200.0], 400)])
    cols = np.concatenate([rng.uniform(0.5, 1920.5, n - 400), rng.uniform(-40, 1990, 400)])
    h = rng.uniform(-50, 200, n)
    for outside in ("flag", "extrapolate"):
        ref = locate(pose, s, rows, cols, target_h=h, engine="numpy", outside=outside)
        fast = locate(pose, s, rows, cols, target_h=h, engine="numba", outside=outside)
        assert np.array_equal(ref.status, fast.status)
        ok = ref.status == Status.OK
        assert ok.sum() > 0.9 * n
        # tolerances as _compare: rounding of the same formulas in another order; the map's
        # two Newton steps reach the full iteration's root to ~1e-16 (tests/sensors/test_lenses.py)
        np.testing.assert_allclose(fast.ecef[ok], ref.ecef[ok], rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.lat[ok], ref.lat[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.lon[ok], ref.lon[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.h[ok], ref.h[ok], rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.los.direction_ecef[ok], ref.los.direction_ecef[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.los.origin_ecef[ok], ref.los.origin_ecef[ok], rtol=0, atol=1e-6)
    off = (rows < 0.5) | (rows > 1080.5) | (cols < 0.5) | (cols > 1920.5)
    assert np.sum(ok & off) > 100  # extrapolated: pixels off the sensor (and off the map) were compared too


# ------------------------------------------------ the lane (SIMD) versions and their scalar fall-backs
def test_lane_trigonometry_equals_libm():
    # sincos_lanes, atan_lanes and atan2_lanes (selects instead of branches, so LLVM vectorises
    # them) against numpy's sin, cos, arctan, arctan2 (libm). sincos: 2.3e-16 absolute as the
    # branchy sincos above. atan: Cephes' rational form, peak relative error 1.8e-16 (its
    # documentation), so 3.4e-16 relative = about 1.5 ulp; atan2 adds one rounding (pi/2 - r,
    # pi - r): 4.5e-16 absolute on values up to pi.
    from numba import njit

    from geoloc.sensors._fastlocate import atan2_lanes, atan_lanes, sincos_lanes

    @njit(error_model="numpy")  # as the kernel: atan2_lanes(0, 0) divides 0 by 0
    def run(a, b, s, c, t, t2):
        for k in range(a.size):
            s[k], c[k] = sincos_lanes(a[k])
            t[k] = atan_lanes(a[k])
            t2[k] = atan2_lanes(a[k], b[k])

    rng = np.random.default_rng(11)
    a = np.concatenate(
        [
            rng.uniform(-64, 64, 200_000),
            rng.uniform(-1e-3, 1e-3, 1000),
            10.0 ** rng.uniform(-300, 300, 2000),
            np.arange(-80, 81) * np.pi / 4,
            [0.0, -0.0, 5e-324, 2.41421356237309504880, 0.66, -0.66],
        ]
    )
    b = np.concatenate([rng.uniform(-64, 64, a.size - 7), [0.0, -1.0, 1.0, 0.0, -0.0, -3.0, 1e-300]])
    s, c, t, t2 = (np.empty_like(a) for _ in range(4))
    run(a, b, s, c, t, t2)
    small = np.abs(a) <= 64
    assert np.max(np.abs(s[small] - np.sin(a[small]))) <= 2.3e-16
    assert np.max(np.abs(c[small] - np.cos(a[small]))) <= 2.3e-16
    np.testing.assert_allclose(t, np.arctan(a), rtol=3.4e-16, atol=0)
    np.testing.assert_allclose(t2, np.arctan2(a, b), rtol=0, atol=4.5e-16)
    out = np.empty((4, 3))
    run(np.array([np.nan, np.inf, -np.inf]), np.array([1.0, 1.0, 1.0]), *out)
    assert np.all(np.isnan(out[0:2]))  # sin, cos of NaN and inf
    assert np.isnan(out[2, 0]) and out[2, 1] == np.pi / 2 and out[2, 2] == -np.pi / 2


def test_lane_geodetic_and_the_blocks_fall_backs_against_pyproj():
    # geodetic_lanes (a series + Newton cube root, atan_lanes) against PROJ, tolerances as
    # test_geodetic_fast_equals_pyproj; then _geodetic_block on the cases the lanes refuse
    # (points on the polar axis: atan2(0, 0); a point deep inside the Earth: the cube root's
    # argument beyond 1.1), which the block's scalar fall-back must still get right; and
    # _sincos_block beyond 64 rad, where it must take libm's values.
    import pyproj
    from numba import njit

    from geoloc.geodesy.ellipsoid import E2, A, B
    from geoloc.sensors._fastlocate import (
        _geodetic_block,
        _sincos_block,
        geodetic_fast,
        geodetic_lanes,
    )

    @njit(error_model="numpy")  # as the kernel: a division by zero is inf / NaN, not an exception
    def run(x, y, z, out, ok):
        for k in range(x.size):
            out[k, 0], out[k, 1], out[k, 2], ok[k] = geodetic_lanes(x[k], y[k], z[k], A, E2)

    rng = np.random.default_rng(12)
    n = 20_000
    lat, lon, h = rng.uniform(-89.99, 89.99, n), rng.uniform(-180, 180, n), rng.uniform(-500, 1e6, n)
    tr = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = (np.asarray(v) for v in tr.transform(lon, lat, h))
    out, ok = np.empty((n, 3)), np.empty(n, dtype=np.bool_)
    run(x, y, z, out, ok)
    assert ok.all()
    np.testing.assert_allclose(np.rad2deg(out[:, 0]), lat, rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(np.rad2deg(out[:, 1]), lon, rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(out[:, 2], h, rtol=0, atol=1e-7)

    # on the polar axis the lanes' atan2(0, 0) is NaN; 6000 km below the surface Vermeille's cube
    # root argument is 1.36 (beyond the series' range), where PROJ and Vermeille themselves part
    # (the evolute region), so that lane is held to the scalar Vermeille it falls back to
    hard = np.array([[0.0, 0.0, B + 100.0], [0.0, 0.0, -(B + 2500.0)], [3e5, 2e5, 1e5]])
    m = len(hard)
    cols = [np.ascontiguousarray(hard[:, i]) for i in range(3)]
    lanes_out, lanes_ok = np.empty((m, 3)), np.empty(m, dtype=np.bool_)
    run(*cols, lanes_out, lanes_ok)
    assert not lanes_ok.any()  # every one of them is a case the lanes hand to the scalar code
    la, lo, hh, good = np.empty(m), np.empty(m), np.empty(m), np.empty(m, dtype=np.bool_)
    _geodetic_block(*cols, A, E2, np.zeros(m, np.uint8), la, lo, hh, good)
    back = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*hard[:2].T)
    np.testing.assert_allclose(np.rad2deg(la[:2]), back[1], rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(np.rad2deg(lo[:2]), back[0], rtol=0, atol=np.rad2deg(1e-14))
    np.testing.assert_allclose(hh[:2], back[2], rtol=0, atol=1e-7)
    assert (la[2], lo[2], hh[2]) == geodetic_fast(*hard[2], A, E2)

    a = np.array([100.0, -1e5, 3e7, 0.5])
    s, c = np.empty(4), np.empty(4)
    _sincos_block(a, s, c)
    np.testing.assert_array_equal(s[:3], np.sin(a[:3]))  # libm's own values beyond 64 rad
    np.testing.assert_array_equal(c[:3], np.cos(a[:3]))


def test_line_of_sight_auto_takes_the_kernel_and_equals_the_numpy_path():
    # FrameSensor.line_of_sight on 10 000 rays or more runs the compiled kernel (the replays'
    # and campaigns' lines of sight); it must equal the numpy reference path ray for ray,
    # statuses included (tolerances as _compare); a sensor with a per-sample perturbation
    # (Monte Carlo's lever_extra_m) is not the kernel's: auto keeps numpy, numba refuses.
    import dataclasses

    import pytest

    from geoloc.sensors import _fastlocate

    s = _turret()
    rng = np.random.default_rng(13)
    n = 12_000
    pose = _turret_poses(rng, n, heading_deg=180)
    rows = rng.uniform(-20, 1100, n)
    cols = rng.uniform(-20, 1940, n)
    rows[:50] = np.nan
    calls = []
    real = _fastlocate.locate_kernel
    _fastlocate.locate_kernel = lambda *a: (calls.append(1), real(*a))
    try:
        auto = s.line_of_sight(rows, cols, pose)
    finally:
        _fastlocate.locate_kernel = real
    assert calls  # it really took the kernel
    ref = s.line_of_sight(rows, cols, pose, engine="numpy")
    assert np.array_equal(auto.status, ref.status)
    assert {int(v) for v in np.unique(ref.status)} == {
        int(Status.OK),
        int(Status.OUTSIDE_SENSOR),
        int(Status.INVALID_INPUT),
    }
    ok = ref.status == Status.OK
    np.testing.assert_allclose(auto.direction_ecef[ok], ref.direction_ecef[ok], rtol=0, atol=1e-12)
    np.testing.assert_allclose(auto.origin_ecef[ok], ref.origin_ecef[ok], rtol=0, atol=1e-6)

    perturbed = dataclasses.replace(s, lever_extra_m=rng.normal(0, 0.1, (n, 3)))
    assert not perturbed.compiled
    got = perturbed.line_of_sight(rows, cols, pose)  # auto: the numpy path, with the perturbation
    lever = np.array(s.lever_arm_m) + perturbed.lever_extra_m
    moved = np.linalg.norm(got.origin_ecef[ok] - ref.origin_ecef[ok], axis=-1)
    np.testing.assert_allclose(moved, np.linalg.norm(lever - np.array(s.lever_arm_m), axis=-1)[ok], atol=1e-6)
    with pytest.raises(ValueError, match="per-sample"):
        locate(pose, perturbed, rows, cols, engine="numba")


def test_kernel_takes_any_number_of_joints_as_the_numpy_path():
    # the kernel reads the first three joints' angle arrays as the pose holds them and any
    # further ones from rows of one array: a one-joint and a five-joint custom gimbal (two
    # joints beyond the three) against the numpy reference path, ray for ray; one signature
    from geoloc.sensors._fastlocate import locate_kernel
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import Gimbal, GimbalJoint
    from geoloc.sensors.lenses import BrownLens

    lens = BrownLens(fx=1000.0, fy=1000.0, cx=499.5, cy=499.5, width=1000, height=1000, k1=-0.1)
    axes = ("z", "y", "x", "z", "y")
    rng = np.random.default_rng(5)
    n = 2000
    for k in (1, 5):
        joints = tuple(GimbalJoint(f"j{i}", axes[i], f"f{i}", "") for i in range(k))
        s = FrameSensor(lens, Gimbal(f"custom{k}", joints, np.eye(3)), lever_arm_m=(0.5, -0.2, 0.3))
        # the joints turn the line of sight off the body's Z (down) by a few degrees each
        angles = {f"j{i}": rng.uniform(-8, 8, n) for i in range(k)}
        pose = Pose.from_deg(
            rng.uniform(30, 40, n), 80.0, rng.uniform(500, 3000, n), rng.uniform(0, 360, n), 2.0, -1.0,
            angles_deg=angles,
        )  # fmt: skip
        rows, cols = rng.uniform(1, 1000, n), rng.uniform(1, 1000, n)
        ref = locate(pose, s, rows, cols, target_h=0.0, engine="numpy")
        fast = locate(pose, s, rows, cols, target_h=0.0, engine="numba")
        assert np.array_equal(ref.status, fast.status)
        ok = ref.status == Status.OK
        assert ok.sum() > 0.9 * n
        # tolerances as _compare: the same formulas, rounded in another order
        np.testing.assert_allclose(fast.ecef[ok], ref.ecef[ok], rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.lat[ok], ref.lat[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.lon[ok], ref.lon[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.los.direction_ecef[ok], ref.los.direction_ecef[ok], rtol=0, atol=1e-12)
    assert len(locate_kernel.signatures) == 1, locate_kernel.signatures


def test_one_value_inputs_equal_the_numpy_path_and_their_broadcast_arrays():
    # a frame's pose (one value a field) and one target height reach the kernel as one value each,
    # read for every ray, not broadcast to the batch: the results must equal the numpy reference path
    # (statuses, the line of sight's statuses and refraction_m exactly; positions as _compare), and,
    # bit for bit, the kernel given the same values as full arrays. A five-joint gimbal mixes one-value
    # and per-ray joint angles (the rows beyond the first three joints); a NaN pose gives INVALID_INPUT
    # on every ray, a pixel off the sensor OUTSIDE_SENSOR.
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import Gimbal, GimbalJoint
    from geoloc.sensors.lenses import BrownLens

    lens = BrownLens(fx=1000.0, fy=1000.0, cx=499.5, cy=499.5, width=1000, height=1000, k1=-0.1)
    joints = tuple(GimbalJoint(f"j{i}", ax, f"f{i}", "") for i, ax in enumerate("zyxzy"))
    s = FrameSensor(lens, Gimbal("custom5", joints, np.eye(3)), lever_arm_m=(0.5, -0.2, 0.3))
    rng = np.random.default_rng(21)
    n = 3000
    rows, cols = rng.uniform(-5, 1005, n), rng.uniform(1, 1000, n)
    per_ray = {"j1": rng.uniform(-8, 8, n), "j4": rng.uniform(-8, 8, n)}
    for heading in (33.0, np.nan):
        angles = {"j0": 4.0, "j1": per_ray["j1"], "j2": -3.0, "j3": 2.0, "j4": per_ray["j4"]}
        one = Pose.from_deg(35.2, 80.1, 2500.0, heading, 2.0, -1.0, angles_deg=angles)
        full = Pose.from_deg(
            *(np.full(n, v) for v in (35.2, 80.1, 2500.0, heading, 2.0, -1.0)),
            angles_deg={k: np.broadcast_to(v, (n,)).copy() for k, v in angles.items()},
        )
        ref = locate(one, s, rows, cols, target_h=120.0, engine="numpy")
        fast = locate(one, s, rows, cols, target_h=120.0, engine="numba")
        wide = locate(full, s, rows, cols, target_h=np.full(n, 120.0), engine="numba")
        assert np.array_equal(fast.status, ref.status)
        assert np.array_equal(fast.los.status, ref.los.status)
        np.testing.assert_array_equal(fast.refraction_m, ref.refraction_m)  # 0 where OK, NaN elsewhere
        ok = ref.status == Status.OK
        if np.isnan(heading):
            assert np.all(ref.status == Status.INVALID_INPUT)
        else:
            assert 0.9 * n < ok.sum() < n and np.any(ref.status == Status.OUTSIDE_SENSOR)
        # tolerances as _compare: the same formulas, rounded in another order
        np.testing.assert_allclose(fast.ecef[ok], ref.ecef[ok], rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.lat[ok], ref.lat[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.lon[ok], ref.lon[ok], rtol=0, atol=1e-12)
        for f in ("lat", "lon", "h", "ecef", "slant_range", "status", "refraction_m"):
            assert np.array_equal(getattr(fast, f), getattr(wide, f), equal_nan=True), f
        for f in ("origin_ecef", "direction_ecef", "status"):
            assert np.array_equal(getattr(fast.los, f), getattr(wide.los, f), equal_nan=True), f
