"""The "Your own sensor" figures of docs/tour_sensors.md (once the README's own section), pinned
(regression guards; correctness of the chain itself is shown against pymap3d and FrameChain in
test_sensors.py and test_gimbals.py)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def geoloc(*args):
    r = subprocess.run([sys.executable, "-m", "geoloc", *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout


def test_readme_turret_locate():
    out = json.loads(
        geoloc(
            "locate",
            "--sensor",
            "assets/sensors/eo_turret.toml",
            "--lat-deg",
            "36.6",
            "--lon-deg",
            "-84.25",
            "--h-m",
            "2500",
            "--heading-deg",
            "45",
            "--pitch-deg",
            "2",
            "--roll-deg",
            "1",
            "--angle",
            "azimuth=90",
            "--angle",
            "elevation=-30",
            "--dem",
            "assets/dem/srtm_jacksboro.tif",
            "--json",
        )
    )
    # the docs/tour_sensors.md prints 6 decimals of degrees and 2 of metres
    assert out["lat_deg"] == pytest.approx(36.577575, abs=5e-7)
    assert out["lon_deg"] == pytest.approx(-84.221019, abs=5e-7)
    assert out["h_m"] == pytest.approx(343.26, abs=5e-3)
    assert out["slant_range_m"] == pytest.approx(4191.87, abs=5e-3)


@pytest.mark.parametrize(
    "records,sensor,group,mean",
    [
        ("eo_turret_flight.csv", "eo_turret.toml", "orbit1", 22.87),
        ("drone_targets.csv", "drone_camera.toml", "survey1", 2.70),
    ],
)
def test_readme_sensor_replays(records, sensor, group, mean):
    out = geoloc(
        "replay",
        f"assets/records/{records}",
        "--sensor",
        f"assets/sensors/{sensor}",
        "--dem",
        "assets/dem/srtm_jacksboro.tif",
    )
    m = re.search(rf"group {group}: n=(\d+), mean error to truth ([0-9.]+) m", out)
    assert m and float(m.group(2)) == pytest.approx(mean, abs=0.005)


def test_readme_distortion_figures():
    out = subprocess.run(
        [sys.executable, "examples/11_sensor_drone_camera_distortion.py"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    ).stdout
    assert "471.3 px away" in out and "moves the target 145.1 m" in out


def test_bundled_paths_resolve_from_any_folder(tmp_path):
    # docs/tour_sensors.md's `assets/...` arguments name bundled files wherever the command runs
    # (one rule in geoloc.cli.main for every verb's file options)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "geoloc",
            "locate",
            "--sensor",
            "assets/sensors/eo_turret.toml",
            "--lat-deg",
            "36.6",
            "--lon-deg",
            "-84.25",
            "--h-m",
            "2500",
            "--heading-deg",
            "45",
            "--pitch-deg",
            "2",
            "--roll-deg",
            "1",
            "--angle",
            "azimuth=90",
            "--angle",
            "elevation=-30",
            "--dem",
            "assets/dem/srtm_jacksboro.tif",
            "--json",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["lat_deg"] == pytest.approx(36.577575, abs=5e-7)
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "limb", "assets/scenarios/tiangong2_limb.toml", "--out", "limb.csv"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "limb.csv").is_file()


def test_readme_klv_example_flight():
    with_dem = geoloc("replay", "assets/klv/example_flight.klv", "--dem", "assets/dem/srtm_jacksboro.tif")
    assert "299 packets read, 1 bad packet(s) skipped" in with_dem
    assert "bad packet at byte 32400: checksum mismatch" in with_dem
    assert "median 0.003 m, 90th percentile 0.004 m" in with_dem
    assert "22 packet(s): packets 100-109, 200-204, 250-256" in with_dem
    bare = geoloc("replay", "assets/klv/example_flight.klv")
    assert "frame-centre error (recomputed vs reported, horizontal): median 0.091 m" in bare
    assert re.search(r"corner error \(mean of the corners\): median 58\.\d+ m", bare)


def test_readme_klv_example_video_replays_as_the_raw_file():
    ts = geoloc("replay", "assets/klv/example_flight.ts")
    assert "299 packets read, 1 bad packet(s) skipped" in ts
    assert "median 0.091 m" in ts and "22 packet(s): packets 100-109, 200-204, 250-256" in ts


def test_readme_drone_photo_example():
    out = geoloc(
        "replay",
        "assets/photos/DJI_0001.JPG",
        "--targets",
        "assets/photos/targets.csv",
        "--dem",
        "assets/dem/srtm_jacksboro.tif",
    )
    assert "DJI_0001.JPG: 5/5 targets located, error to truth mean 1.66 m, max 2.48 m" in out
    assert "camera AbsoluteAltitude taken as EGM96 geoid (orthometric)" in out
