"""The sensor examples (10-11) run and print figures that outside references confirm."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NUM = r"[-+]?[0-9]*\.?[0-9]+(?:e[-+]?[0-9]+)?"


def run(name):
    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / name)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout


def nums(out, needle):
    line = next(ln for ln in out.splitlines() if needle in ln)
    return [float(v) for v in re.findall(NUM, line.split(":", 1)[-1] if ":" in line else line)]


def test_turret_example_agrees_with_pymap3d():
    out = run("10_sensor_turret_azimuth_elevation.py")
    lat, lon = nums(out, "principal point on the ellipsoid")[:2]
    az, tilt = nums(out, "line of sight")[:2]
    # the printed direction, given to pymap3d from the printed optical centre, lands on the printed point
    assert abs(az - 135.0) < 2.0 and abs(tilt - 60.0) < 2.0  # heading + azimuth, 90 + elevation (attitude 1-2 deg)
    plat, plon = nums(out, "pymap3d lookAtSpheroid")[:2]
    assert (plat, plon) == pytest.approx((lat, lon), abs=2e-7)  # the print's 7 decimals
    assert nums(out, "pymap3d lookAtSpheroid")[2] < 1e-6  # metres of range
    # the footprint is a quadrilateral around the principal point (right of a north-east track)
    corners = [nums(out, f"footprint {c}")[:2] for c in ("top left", "top right", "bottom right", "bottom left")]
    assert min(c[0] for c in corners) < lat < max(c[0] for c in corners)
    assert min(c[1] for c in corners) < lon < max(c[1] for c in corners)


def test_drone_example_distortion_and_earth_referenced_gimbal():
    out = run("11_sensor_drone_camera_distortion.py")
    shift = nums(out, "distortion at pixel")[-1]
    assert 300.0 < shift < 700.0  # k1 = -0.27 near a corner of a 4000 x 3000 image: hundreds of px
    moved = nums(out, "ignoring the distortion moves")[0]
    assert moved > 50.0
    # the gimbal holds its NED angles: rolling the airframe moves the target by the lever arm only
    assert nums(out, "airframe rolled")[-1] < 0.3
    # the located height lies between the bundled SRTM crop's extremes (205-1045 m)
    h = nums(out, "with the lens model")[-2]
    assert 205.0 < h < 1046.0


def test_06_local_frames_aer_ned():
    import numpy as np
    import pymap3d
    from pyproj import Transformer

    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    out = run("06_local_frames_aer_ned.py")
    aircraft, target = (35.48, 80.97, 18000.0), (35.577, 80.849, 5083.5)
    # NED and AER against pymap3d (degrees), printed to 0.1 m and 1e-4 deg
    np.testing.assert_allclose(nums(out, "2. NED"), pymap3d.geodetic2ned(*target, *aircraft), atol=0.05)
    az, el, srange = nums(out, "3. AER")
    ref_az, ref_el, _ = pymap3d.geodetic2aer(*target, *aircraft)
    assert az == pytest.approx(ref_az, abs=5e-5) and el == pytest.approx(ref_el, abs=5e-5)
    # the slant range is the straight-line distance between the two points (pyproj's ECEF)
    ac = np.array(to_ecef.transform(aircraft[1], aircraft[0], aircraft[2]))
    tg = np.array(to_ecef.transform(target[1], target[0], target[2]))
    assert srange == pytest.approx(np.linalg.norm(tg - ac), abs=0.05)
    # and back from AER and from NED lands on the target
    backs = [ln for ln in out.splitlines() if ln.startswith("4. back from")]
    assert len(backs) == 2
    for ln in backs:
        assert "35.577000000 N 80.849000000 E h 5083.500000 m" in ln
        assert float(re.findall(NUM, ln.split("misses the target by")[1])[0]) < 1e-6
