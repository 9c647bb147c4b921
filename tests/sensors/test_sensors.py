"""The frame camera on a gimbal: against the [Q17] chain, pymap3d, and its own compiled path.

Oracles from outside the sensor code: the paper's explicit chain (FrameChain,
eq. 4-9, its own rotation code), pymap3d's ``lookAtSpheroid`` and ``ned2ecef``
(an independent geodesy library), and hand-written directions.
"""

import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pymap3d
import pytest
from pymap3d.los import lookAtSpheroid

from geoloc.assets import DEFAULT_CAMERA, asset_path
from geoloc.frames.chain import FrameChain, Pose
from geoloc.locate import ground_to_pixel, locate
from geoloc.sensors.camera import Camera
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens, FisheyeLens, PinholeLens
from geoloc.sensors.sensor_file import load_sensor, sensor_from_dict, sensor_to_toml
from geoloc.status import Status

MINIMAL = """\
[lens]
model = "pinhole"
fx = 1500.0
fy = 1500.0
cx = 640.0
cy = 480.0
width = 1280
height = 960

[gimbal]
preset = "azimuth-elevation"
"""

BROWN = BrownLens(
    fx=1800.0, fy=1795.0, cx=1012.3, cy=757.9, width=2048, height=1536, k1=-0.28, k2=0.11, p1=6e-4, p2=-3e-4, k3=-0.02
)
FISHEYE = FisheyeLens(
    fx=400.0, fy=400.0, cx=639.5, cy=479.5, width=1280, height=960, k1=0.02, k2=-0.005, k3=0.001, k4=-0.0002
)

ANGLES = {
    "roll-pitch": ("gimbal_roll", "gimbal_pitch"),
    "azimuth-elevation": ("azimuth", "elevation"),
    "azimuth-elevation-roll": ("azimuth", "elevation", "sensor_roll"),
    "yaw-pitch-roll": ("gimbal_yaw", "gimbal_pitch", "gimbal_roll"),
}


def random_poses(rng, n, preset):
    """Poses over the globe with the preset's angles in ranges that look at the ground."""
    angles = {}
    for name in ANGLES[preset]:
        lo, hi = {
            "gimbal_roll": (-60, 60),
            "gimbal_pitch": (-100, 10) if preset == "yaw-pitch-roll" else (-20, 20),
            "azimuth": (0, 360),
            "elevation": (-90, -20),
            "sensor_roll": (-180, 180),
            "gimbal_yaw": (-180, 180),
        }[name]
        angles[name] = rng.uniform(lo, hi, n)
    q17 = {k: angles.pop(k) for k in ("gimbal_roll", "gimbal_pitch") if k in angles}
    return Pose.from_deg(
        rng.uniform(-70, 70, n),
        rng.uniform(-180, 180, n),
        rng.uniform(200, 12000, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-10, 10, n),
        rng.uniform(-15, 15, n),
        q17.get("gimbal_roll", 0.0),
        q17.get("gimbal_pitch", 0.0),
        angles_deg=angles,
    )


def rigged(preset, lens=BROWN):
    mount = (0.0, 0.0, 0.0) if PRESETS[preset].earth_referenced else (1e-3, -2e-3, 3e-3)
    return FrameSensor(
        lens, PRESETS[preset], mount=mount, boresight=(-4e-4, 5e-4, 2e-3), lever_arm_m=(0.8, -0.3, 1.2), name=preset
    )


def test_roll_pitch_pinhole_is_the_q17_chain_with_mount_and_boresight():
    cam = dataclasses.replace(
        Camera.from_toml(asset_path(*DEFAULT_CAMERA)),
        mount=(0.001, math.radians(0.22), -0.002),
        boresight=(9e-4, -4e-4, 3e-3),
    )
    rng = np.random.default_rng(11)
    pose = random_poses(rng, 2000, "roll-pitch")
    row, col = rng.uniform(1, cam.rows, 2000), rng.uniform(1, cam.cols, 2000)
    ref = cam.chain_line_of_sight(pose, row, col, chain=FrameChain(pose, cam.R_cam_inner, cam.R_base_body))
    got = cam.to_sensor().line_of_sight(row, col, pose)
    # 1e-15: unit vectors through the same rotations in another order (a few ulps)
    np.testing.assert_allclose(got.direction_ecef, ref.direction_ecef, rtol=0, atol=2e-15)
    np.testing.assert_array_equal(got.origin_ecef, ref.origin_ecef)


@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("lens", [BROWN, FISHEYE], ids=["brown", "fisheye"])
def test_compiled_path_equals_numpy_for_every_preset_lens_mount_boresight_and_lever_arm(preset, lens):
    s = rigged(preset, lens)
    rng = np.random.default_rng(5)
    n = 20_000
    pose = random_poses(rng, n, preset)
    # some pixels off the sensor and some invalid poses, so every status branch runs
    row = rng.uniform(-50, lens.height + 50, n)
    col = rng.uniform(-50, lens.width + 50, n)
    pose = dataclasses.replace(pose, lat=np.where(rng.random(n) < 0.01, np.nan, pose.lat))
    h = rng.uniform(-100, 3000, n)
    ref = locate(pose, s, row, col, target_h=h, engine="numpy")
    fast = locate(pose, s, row, col, target_h=h, engine="numba")
    np.testing.assert_array_equal(fast.status, ref.status)
    assert {Status.OK, Status.OUTSIDE_SENSOR, Status.INVALID_INPUT} <= set(np.unique(ref.status))
    ok = ref.status == Status.OK
    # 1e-6 m on 6.4e6 m ECEF and 1e-12 rad: the same formulas, other float64 operation order
    np.testing.assert_allclose(fast.ecef[ok], ref.ecef[ok], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast.lat[ok], ref.lat[ok], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.h[ok], ref.h[ok], rtol=0, atol=1e-6)
    fin = np.all(np.isfinite(ref.los.direction_ecef), axis=-1)
    np.testing.assert_allclose(fast.los.direction_ecef[fin], ref.los.direction_ecef[fin], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.los.origin_ecef[fin], ref.los.origin_ecef[fin], rtol=0, atol=1e-6)
    ex_ref = locate(pose, s, row, col, target_h=h, engine="numpy", outside="extrapolate")
    ex_fast = locate(pose, s, row, col, target_h=h, engine="numba", outside="extrapolate")
    np.testing.assert_array_equal(ex_fast.status, ex_ref.status)
    assert not np.any(ex_ref.status == Status.OUTSIDE_SENSOR)


def test_lever_arm_moves_the_optical_centre_by_the_body_offset():
    # Level flight heading east: body X = east, Y = south, Z = down. A lever arm (2, 1, -3) m in
    # body axes is 2 m east, 1 m south, 3 m up: pymap3d.ned2ecef gives the expected ECEF point.
    s = FrameSensor(
        PinholeLens(1000.0, 1000.0, 499.5, 499.5, 1000, 1000),
        PRESETS["azimuth-elevation"],
        lever_arm_m=(2.0, 1.0, -3.0),
    )
    pose = Pose.from_deg(47.3, 8.5, 900.0, 90.0, 0.0, 0.0, angles_deg={"azimuth": 0.0, "elevation": -45.0})
    o = s.line_of_sight(500.5, 500.5, pose).origin_ecef
    want = pymap3d.ned2ecef(-1.0, 2.0, -3.0, 47.3, 8.5, 900.0)
    # 1e-8 m: two float64 geodesy codes on 6.4e6-m coordinates
    np.testing.assert_allclose(o, want, rtol=0, atol=1e-8)


def test_minimal_sensor_file_locates_as_pymap3d_look_at_spheroid(tmp_path):
    f = tmp_path / "turret.toml"
    f.write_text(MINIMAL)
    # the principal point, azimuth 90 (the right wing), elevation -30, heading 20: an oblique ray
    # at azimuth 110 and 60 deg from nadir; pymap3d intersects the ellipsoid (h = 0) on its own
    cmd = [
        sys.executable,
        "-m",
        "geoloc",
        "locate",
        "--sensor",
        str(f),
        "--lat-deg",
        "35.1",
        "--lon-deg",
        "-106.6",
        "--h-m",
        "1500",
        "--heading-deg",
        "20",
        "--pitch-deg",
        "0",
        "--roll-deg",
        "0",
        "--angle",
        "azimuth=90",
        "--angle",
        "elevation=-30",
        "--row",
        "480",
        "--col",
        "640",
        "--target-h-m",
        "0",
        "--height-kind",
        "geodetic",
        "--json",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    lat, lon, _ = lookAtSpheroid(35.1, -106.6, 1500.0, 110.0, 60.0)
    # 1e-9 deg = 0.1 mm: both solve the same line-ellipsoid intersection in float64
    assert out["lat_deg"] == pytest.approx(float(lat), abs=1e-9)
    assert out["lon_deg"] == pytest.approx(float(lon), abs=1e-9)
    assert abs(out["h_m"]) < 1e-6
    # a missing angle is an error naming it and the gimbal's angles
    k = cmd.index("elevation=-30")
    bad = cmd[: k - 1] + cmd[k + 1 :]
    r = subprocess.run(bad, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "missing angle(s) ['elevation']" in r.stderr


def test_row_99999_is_outside_the_sensor_in_the_cli():
    cmd = [
        sys.executable,
        "-m",
        "geoloc",
        "locate",
        "--lat-deg",
        "35.48",
        "--lon-deg",
        "80.97",
        "--h-m",
        "18000",
        "--gimbal-roll-deg",
        "50",
        "--row",
        "99999",
        "--col",
        "1146",
        "--target-h-m",
        "5000",
        "--json",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert json.loads(r.stdout)["status"] == "outside_sensor"


def test_distorted_pixel_ground_pixel_round_trip():
    s = rigged("azimuth-elevation")
    rng = np.random.default_rng(2)
    n = 5000
    pose = random_poses(rng, n, "azimuth-elevation")
    row, col = rng.uniform(0.5, BROWN.height + 0.5, n), rng.uniform(0.5, BROWN.width + 0.5, n)
    g = locate(pose, s, row, col, target_h=100.0)
    ok = g.status == Status.OK
    assert ok.mean() > 0.9
    ph = ground_to_pixel(pose, s, g.lat, g.lon, g.h)
    # 1e-6 px: the lens inverse converges to 1e-14 in normalised coordinates; the
    # geodetic round trip of the ground point costs ~1e-9 m at a few km
    np.testing.assert_allclose(ph.row[ok], row[ok], atol=1e-6)
    np.testing.assert_allclose(ph.col[ok], col[ok], atol=1e-6)


def test_named_parameters_move_the_answer_and_keep_the_pixel_convention():
    s = rigged("azimuth-elevation-roll")
    p = s.params
    assert p["cx"] == pytest.approx(BROWN.cx + 1.0) and p["cy"] == pytest.approx(BROWN.cy + 1.0)
    assert {"mount_x", "boresight_z", "lever_arm_y_m", "fx", "k1", "p2"} <= set(p)
    pose = Pose.from_deg(
        30.0, 20.0, 3000.0, 10.0, 1.0, -2.0, angles_deg={"azimuth": 30.0, "elevation": -50.0, "sensor_roll": 5.0}
    )
    base = locate(pose, s, 700.0, 900.0, target_h=0.0)
    for name, delta in (
        ("mount_y", 1e-3),
        ("boresight_x", 1e-3),
        ("lever_arm_x_m", 5.0),
        ("fx", 20.0),
        ("cy", 3.0),
        ("k1", 0.01),
    ):
        moved = locate(pose, s.with_params(**{name: p[name] + delta}), 700.0, 900.0, target_h=0.0)
        assert np.linalg.norm(moved.ecef - base.ecef) > 0.01, name
    assert s.with_params(cx=p["cx"]).lens == s.lens  # 1-based in, 0-based lens: exact round trip
    with pytest.raises(ValueError, match=r"no parameter\(s\) \['focal'\]"):
        s.with_params(focal=1.0)


def test_sensor_file_round_trip_and_errors(tmp_path):
    s = rigged("azimuth-elevation")
    f = tmp_path / "s.toml"
    sensor_to_toml(s, f)
    back = load_sensor(f)
    assert back.lens == s.lens and back.gimbal == s.gimbal
    np.testing.assert_allclose(back.mount, s.mount, atol=1e-15)
    np.testing.assert_allclose(back.lever_arm_m, s.lever_arm_m, atol=0)
    for text, match in [
        (MINIMAL + "[lens2]\n", r"unknown key\(s\) or table\(s\) \['lens2'\]"),
        (MINIMAL.replace("fx = 1500.0", "fx = -3.0"), "fx = -3.0"),
        (MINIMAL.replace('preset = "azimuth-elevation"', 'preset = "pan"'), "preset = 'pan'"),
        (MINIMAL + "[mount]\ny_deg = 400\n", r"\[mount\] y_deg = 400"),
        (MINIMAL + "[lever_arm]\nx = 1\n", r"\[lever_arm\] unknown key\(s\) \['x'\]"),
    ]:
        f.write_text(text)
        with pytest.raises(ValueError, match=match):
            load_sensor(f)


def test_first_phase_camera_file_is_the_q17_preset():
    path = asset_path(*DEFAULT_CAMERA)
    cam = Camera.from_toml(path)  # the file format's reader
    s = load_sensor(path)  # a camera file loads as its sensor
    assert type(s) is FrameSensor and s == cam.to_sensor() and s.gimbal is PRESETS["roll-pitch"]
    assert isinstance(
        sensor_from_dict({"lens": {"model": "fov", "hfov_deg": 60.0, "vfov_deg": 45.0, "width": 640, "height": 480}}),
        FrameSensor,
    )


def test_pose_angle_ranges_are_checked():
    s = FrameSensor(BROWN, PRESETS["azimuth-elevation"])
    pose = Pose.from_deg([10.0, 10.0], 20.0, 1000.0, angles_deg={"azimuth": [10.0, 800.0], "elevation": -40.0})
    st = s.line_of_sight(100.0, 100.0, pose).status
    assert list(st) == [Status.OK, Status.INVALID_INPUT]
    with pytest.raises(ValueError, match="azimuth = 800 deg"):
        pose.validate()
