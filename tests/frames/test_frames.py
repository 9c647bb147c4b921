"""The frame chain [Q17 eq. 4-9] against scipy, pymap3d and pyproj, and the paper's sign checks."""

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod
from scipy.spatial.transform import Rotation

from geoloc.frames import rotations as rot
from geoloc.frames.chain import (
    FRAMES,
    FrameChain,
    Pose,
    R_body_ned,
    R_cam_body,
    T_ecef_ned,
    T_ned_ecef_q17_factors,
)
from geoloc.geodesy.local import R_ecef_ned
from geoloc.locate import locate
from geoloc.sensors.camera import Camera

GEOD = Geod(ellps="WGS84")
angles = st.floats(-np.pi, np.pi, allow_nan=False)
# Rotation matrices are products of a few sines and cosines: agreement to
# 1e-12 is float64 rounding, far below any geometric effect (1e-12 rad = 70 nm at 70 km).
EPS = 1e-12


@pytest.mark.parametrize("fn,axis", [(rot.rx, "x"), (rot.ry, "y"), (rot.rz, "z")])
@settings(max_examples=50, deadline=None)
@given(a=angles)
def test_elementary_rotations_are_passive(fn, axis, a):
    # passive = transpose of scipy's active right-hand rotation
    active = Rotation.from_euler(axis, a).as_matrix()
    assert np.allclose(fn(a), active.T, atol=EPS)


@settings(max_examples=100, deadline=None)
@given(angles, st.floats(-np.pi / 2, np.pi / 2), angles)
def test_body_attitude_is_aerospace_zyx(heading, pitch, roll):
    # The aerospace yaw-pitch-roll convention: body -> NED is the active
    # intrinsic Z-Y-X rotation (scipy "ZYX"); [Q17 eq. 6] is its transpose.
    R_ned_body = Rotation.from_euler("ZYX", [heading, pitch, roll]).as_matrix()
    assert np.allclose(R_body_ned(heading, pitch, roll), R_ned_body.T, atol=EPS)


@settings(max_examples=100, deadline=None)
@given(st.floats(-90, 90), st.floats(-180, 180))
def test_R_ecef_ned_matches_pymap3d(lat_deg, lon_deg):
    R = R_ecef_ned(np.deg2rad(lat_deg), np.deg2rad(lon_deg))
    for k, (n, e, d) in enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1)]):
        ref = pymap3d.ned2ecef(n, e, d, lat_deg, lon_deg, 0.0) - np.array(pymap3d.geodetic2ecef(lat_deg, lon_deg, 0.0))
        assert np.allclose(R[:, k], ref, atol=1e-9)  # pymap3d subtracts 6e6-size numbers
    assert np.allclose(R @ R.T, np.eye(3), atol=EPS)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=EPS)


@settings(max_examples=100, deadline=None)
@given(st.floats(-89.9, 89.9), st.floats(-180, 180), st.floats(-1000, 50000))
def test_q17_four_factor_form_equals_direct_form(lat_deg, lon_deg, h):
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    factors = T_ned_ecef_q17_factors(lat, lon, h)
    assert len(factors) == 4
    product = factors[0] @ factors[1] @ factors[2] @ factors[3]
    direct = rot.invert(T_ecef_ned(lat, lon, h))
    # rotation part to rounding; translations are ~6.4e6 m, so 1e-6 m is float64 rounding
    assert np.allclose(product[:3, :3], direct[:3, :3], atol=EPS)
    assert np.allclose(product[:3, 3], direct[:3, 3], atol=1e-6)


def test_chain_hops_compose_to_R_ecef_cam():
    pose = Pose.from_deg([35.48, 36.4], [80.97, 78.7], 18000, [45, 30], 3.5, 0.1, [50, -45], -2.6)
    chain = FrameChain(pose)
    assert [h.src for h in chain.hops] == list(FRAMES[1:])
    assert [h.dst for h in chain.hops] == list(FRAMES[:-1])
    T = chain.T_ecef("cam")
    assert T.shape == (2, 4, 4)
    assert np.allclose(T[..., :3, :3], chain.R_ecef_cam, atol=EPS)
    assert np.allclose(T[..., :3, 3], chain.origin_ecef, atol=1e-6)
    assert np.allclose(chain.T_ecef("ecef"), np.eye(4))
    # body->cam through the chain equals [Q17 eq. 7]
    T_cam_body = chain.T("cam", "body")
    assert np.allclose(T_cam_body[..., :3, :3], R_cam_body(pose.gimbal_roll, pose.gimbal_pitch), atol=1e-9)
    assert np.allclose(T_cam_body[..., :3, 3], 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="frame"):
        chain.T_ecef("camera")


def _azimuth_deg(pose, camera, h=0.0):
    g = locate(pose, camera, target_h=h)
    return GEOD.inv(np.rad2deg(pose.lon), np.rad2deg(pose.lat), g.lon_deg, g.lat_deg)[0]


CAM = Camera(166841.0, 1162.0, 1146.5, 2323, 2292)


def test_sign_check_gimbal_roll_minus_45_looks_right_of_track():
    # docs/method.md section 2: heading 30, gimbal roll -45 -> right of track, azimuth ~120 deg
    pose = Pose.from_deg(36.4, 78.73, 17987.0, 30.0, 0.0, 0.0, -45.0, 0.0)
    az = _azimuth_deg(pose, CAM)
    # level aircraft, zero gimbal pitch: the line of sight is exactly abeam, so the
    # geodesic azimuth is heading + 90 up to the ellipsoid's skew (< 0.1 deg at 18 km).
    assert az == pytest.approx(120.0, abs=0.1)


def test_sign_check_gimbal_roll_plus_48_looks_left_of_track():
    pose = Pose.from_deg(35.48, 80.98, 17987.0, 45.0, 0.0, 0.0, 48.0, 0.0)
    az = _azimuth_deg(pose, CAM)
    assert az == pytest.approx(-45.0, abs=0.1)


def test_sign_checks_hold_with_the_flight_attitude():
    # with the flight test's 3.4-3.8 deg nose-up pitch and gimbal pitch -2.5 the
    # line of sight is still on the stated side, within a few degrees of abeam
    right = _azimuth_deg(Pose.from_deg(36.4, 78.73, 17987.0, 30.0, 3.39, 0.0, -45.2, -2.49), CAM, 4600)
    left = _azimuth_deg(Pose.from_deg(35.48, 80.98, 17987.0, 45.07, 3.78, 0.0, 48.5, -2.56), CAM, 5000)
    assert 110 < right < 130
    assert -55 < left < -35


def test_pose_validation_names_field_and_value():
    with pytest.raises(ValueError, match=r"pitch = 95 deg"):
        Pose.from_deg(35, 80, 1000, 0, 95).validate()
    with pytest.raises(ValueError, match=r"lat = nan"):
        Pose.from_deg(np.nan, 80, 1000).validate()
    pose = Pose.from_deg([35, 91, 35], 80, 1000)
    assert list(pose.invalid_mask()) == [False, True, False]


def test_hop_by_hop_rotation_equals_the_matrix_product():
    rng = np.random.default_rng(5)
    n = 200
    pose = Pose.from_deg(
        rng.uniform(-89, 89, n),
        rng.uniform(-180, 180, n),
        1e4,
        rng.uniform(-180, 180, n),
        rng.uniform(-30, 30, n),
        rng.uniform(-60, 60, n),
        rng.uniform(-90, 90, n),
        rng.uniform(-30, 30, n),
    )
    extra = Rotation.from_rotvec(rng.normal(0, 0.01, (2, n, 3))).as_matrix()
    v = rng.normal(size=(n, 3))
    for kw in ({}, {"R_cam_inner": extra[0], "R_base_body": extra[1]}):
        chain = FrameChain(pose, **kw)
        ref = np.einsum("nij,nj->ni", chain.R_ecef_cam, v)
        assert np.allclose(chain.cam_to_ecef(v), ref, rtol=0, atol=EPS)
        assert np.allclose(chain.ecef_to_cam(ref), v, rtol=0, atol=EPS)
        # and the hops still compose to the same rotation
        assert np.allclose(chain.T_ecef("cam")[..., :3, :3], chain.R_ecef_cam, atol=EPS)


@pytest.mark.parametrize("axis,fn", [("x", rot.rx), ("y", rot.ry), ("z", rot.rz)])
def test_rotate_axis_equals_the_matrix(axis, fn):
    rng = np.random.default_rng(2)
    a = rng.uniform(-np.pi, np.pi, 50)
    v = rng.normal(size=(50, 3))
    assert np.allclose(rot.rotate_axis(axis, a, v), np.einsum("nij,nj->ni", fn(a), v), atol=EPS)
    assert np.allclose(rot.rotate_axis(axis, a, v, transpose=True), np.einsum("nji,nj->ni", fn(a), v), atol=EPS)
    # one angle, many vectors, and one vector, many angles
    assert rot.rotate_axis(axis, 0.3, v).shape == (50, 3)
    assert rot.rotate_axis(axis, a, v[0]).shape == (50, 3)
    with pytest.raises(ValueError, match="axis"):
        rot.rotate_axis("w", 0.1, v)
