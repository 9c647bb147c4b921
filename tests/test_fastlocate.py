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
    pose = Pose.from_deg(rng.uniform(-89, 89, n), rng.uniform(-180, 180, n), rng.uniform(-100, 40000, n),
                         rng.uniform(-180, 180, n), rng.uniform(-20, 20, n), rng.uniform(-30, 30, n),
                         rng.uniform(-100, 100, n), rng.uniform(-30, 30, n))
    pose = Pose(np.where(rng.random(n) < 0.01, np.nan, pose.lat), pose.lon, pose.h, pose.heading,
                pose.pitch, pose.roll, pose.gimbal_roll, pose.gimbal_pitch)
    h = rng.uniform(-50, 6000, n)
    _compare(pose, rng.uniform(1, 2323, n), rng.uniform(1, 2292, n), h)
    st_ = locate(pose, CAM, rng.uniform(1, 2323, n), rng.uniform(1, 2292, n), target_h=h).status
    for code in (Status.OK, Status.SKY, Status.INVALID_INPUT, Status.ORIGIN_BELOW):
        assert np.any(st_ == code)  # the batch really exercises every branch


@settings(max_examples=40, deadline=None)
@given(st.floats(-89.9, 89.9), st.floats(-180, 180), st.floats(100, 1e6), st.floats(-180, 180),
       st.floats(-80, 80), st.floats(-90, 90))
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
        p = Pose.from_deg(rng.uniform(30, 40, n), 80.0, 1000.0, 10.0, 1.0, 1.0, 5.0, -70.0,
                          angles_deg={a: 10.0 for a in s.angle_names if a not in ("gimbal_roll", "gimbal_pitch")})
        locate(p, s, 500.0, 500.0, target_h=0.0, engine="numba")
    assert len(locate_kernel.signatures) == 1, locate_kernel.signatures
