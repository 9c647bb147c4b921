"""The ``[uncertainty]`` table of a sensor file (geoloc.sensors.budget): read, checked, written back.

Expected numbers are the file's own (a reader must give back what it was given) and the
published LE90 of SRTM (16 m at 90 %, Farr et al. 2007) over the normal distribution's 0.95
quantile from scipy, not from the code.
"""

import math

import pytest
from scipy import stats as sps

from geoloc.assets import asset_path
from geoloc.sensors.budget import ErrorBudget
from geoloc.sensors.sensor_file import (
    load_sensor,
    load_sensor_budget,
    sensor_to_toml,
)
from geoloc.surfaces.dem import DEM

TURRET = asset_path("sensors", "eo_turret.toml")
DRONE = asset_path("sensors", "drone_camera.toml")


def with_table(tmp_path, base, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(base.read_text() + "\n[uncertainty]\n" + text)
    return p


def test_every_kind_of_key_is_read_with_its_unit(tmp_path):
    p = with_table(
        tmp_path,
        TURRET,
        """
north_m = 2.0
east_m = 2.5
up_m = 3.0
heading_deg = 0.05
pitch_deg = 0.02
roll_deg = 0.03
azimuth_deg = 0.01
elevation_deg = 0.015
mount_x_deg = 0.004
boresight_z_deg = 0.006
lever_arm_y_m = 0.05
time_s = 0.002
fx_px = 2.0
cx_px = 0.5
k1 = 0.001
height_m = 10.0
dem_product = "srtm"
""",
    )
    b = load_sensor_budget(p)
    assert b.sigma("north_m") == 2.0 and b.sigma("azimuth_deg") == 0.01 and b.sigma("k1") == 0.001
    assert b.sigma("roll_deg") == 0.03 and b.sigma("gimbal_roll_deg") == 0.0  # not this gimbal's
    # SRTM: 16 m LE90 -> sigma = 16 / z_0.95 (the two-sided 90 % interval of a normal error)
    assert b.dem_sigma_m() == pytest.approx(16.0 / sps.norm.ppf(0.95), rel=1e-12)
    # the sensor itself still loads as before, the table aside
    assert load_sensor(p) == load_sensor(TURRET)
    # written and read back
    sensor_to_toml(load_sensor(p), tmp_path / "back.toml", budget=b)
    assert load_sensor_budget(tmp_path / "back.toml") == ErrorBudget(b.sigmas, "srtm", str(tmp_path / "back.toml"))


def test_a_file_without_the_table_has_no_budget():
    assert load_sensor_budget(TURRET) is None


def test_first_phase_camera_file_takes_a_budget_on_its_roll_pitch_gimbal(tmp_path):
    p = with_table(tmp_path, asset_path("cameras", "qiao2017.toml"), "gimbal_roll_deg = 0.006\nheading_deg = 0.02\n")
    assert load_sensor_budget(p).sigma("gimbal_roll_deg") == 0.006
    load_sensor(p)  # a first-phase camera file, as its sensor
    with pytest.raises(ValueError, match="'k1'.*pinhole lens has no parameter 'k1'"):
        load_sensor(with_table(tmp_path, asset_path("cameras", "qiao2017.toml"), "k1 = 0.1\n", "k.toml"))
    with pytest.raises(ValueError, match="'azimuth_deg'.*roll-pitch gimbal's angles"):
        load_sensor(with_table(tmp_path, asset_path("cameras", "qiao2017.toml"), "azimuth_deg = 0.1\n", "b.toml"))


@pytest.mark.parametrize(
    "text, match",
    [
        ("nort_m = 1.0", "unknown key 'nort_m'"),
        ("gimbal_roll_deg = 0.01", "unknown key 'gimbal_roll_deg'.*angles are \\['azimuth', 'elevation'\\]"),
        ("focal_length_px = 1.0", "unknown key 'focal_length_px'"),
        ("north_m = -1.0", "north_m = -1.0: must be a standard deviation >= 0"),
        ('heading_deg = "0.1"', "heading_deg = '0.1'"),
        ('dem_product = "aster"', "dem_product = 'aster'"),
        ('dem_m = 3.0\ndem_product = "srtm"', "not both"),
    ],
)
def test_bad_keys_and_values_are_refused_naming_them(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        load_sensor(with_table(tmp_path, TURRET, text + "\n"))


def test_earth_referenced_gimbal_refuses_a_mount_error(tmp_path):
    with pytest.raises(ValueError, match="'mount_x_deg'.*has no mount"):
        load_sensor(with_table(tmp_path, DRONE, "mount_x_deg = 0.01\n"))
    b = load_sensor_budget(with_table(tmp_path, DRONE, "gimbal_yaw_deg = 0.1\ngimbal_pitch_deg = 0.05\n", "d.toml"))
    assert b.sigma("gimbal_yaw_deg") == 0.1


def test_dem_sigma_defaults_to_the_bundled_dem_product():
    b = ErrorBudget({}, None, "x")
    srtm = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    assert b.dem_sigma_m(srtm) == pytest.approx(16.0 / 1.6448536269514722)
    with pytest.raises(ValueError, match="etopo5_flight_area.tif has no published vertical accuracy.*dem_m"):
        b.dem_sigma_m(DEM.open(asset_path("dem", "etopo5_flight_area.tif")))
    assert ErrorBudget({"dem_m": 3.0}).dem_sigma_m(srtm) == 3.0
    # a budget scaled by 2 scales the DEM's default too
    assert ErrorBudget({}, "srtm").scaled(2.0).dem_sigma_m() == pytest.approx(2 * 16.0 / 1.6448536269514722)
    assert math.isclose(1.6448536269514722, sps.norm.ppf(0.95), rel_tol=1e-14)
