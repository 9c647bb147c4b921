"""Fitting a sensor's named parameters to ground control (geoloc.analysis.sensor_fit).

Synthetic records with a known truth: targets are placed with a *true* sensor
(a mount, a boresight and a focal length the nominal file does not have), the
records carry the nominal sensor's view of them, and the fit must recover the
true values. Noise-free, so the optimum is exact up to the solver's tolerance.
"""

import csv
import math

import numpy as np
import pytest

from geoloc.analysis.sensor_fit import fit_sensor_params
from geoloc.assets import asset_path
from geoloc.frames.chain import Pose
from geoloc.io.records import load_records
from geoloc.locate import locate
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.height import HeightSurface

TRUE = {"mount_x": math.radians(0.4), "mount_y": math.radians(-0.25), "mount_z": math.radians(0.6), "fx": 2230.0}


def make_records(tmp_path, n=30, plant_m=0.0):
    nominal = load_sensor(asset_path("sensors", "eo_turret.toml"))
    true = nominal.with_params(**TRUE)
    rng = np.random.default_rng(7)
    az, el = rng.uniform(0, 360, n), rng.uniform(-80, -30, n)
    pose = Pose.from_deg(
        36.6 + rng.uniform(-0.05, 0.05, n),
        -84.25 + rng.uniform(-0.05, 0.05, n),
        rng.uniform(1500, 3500, n),
        rng.uniform(-180, 180, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-5, 5, n),
        angles_deg={"azimuth": az, "elevation": el},
    )
    row, col = rng.uniform(50, 1030, n), rng.uniform(50, 1870, n)
    g = locate(pose, true, row, col, target_h=300.0, height_kind="geodetic")
    tlat = g.lat_deg.copy()
    tlat[0] += plant_m / 111_000.0  # a surveyed point 'plant_m' metres off (north)
    f = tmp_path / "rec.csv"
    with f.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "row",
                "col",
                "ac_lat_deg",
                "ac_lon_deg",
                "ac_h_m",
                "heading_deg",
                "pitch_deg",
                "roll_deg",
                "azimuth_deg",
                "elevation_deg",
                "truth_lat_deg",
                "truth_lon_deg",
                "truth_h_m",
            ]
        )
        for k in range(n):
            w.writerow(
                [
                    repr(float(v))
                    for v in (
                        row[k],
                        col[k],
                        np.rad2deg(pose.lat[k]),
                        np.rad2deg(pose.lon[k]),
                        pose.h[k],
                        np.rad2deg(pose.heading[k]),
                        np.rad2deg(pose.pitch[k]),
                        np.rad2deg(pose.roll[k]),
                        az[k],
                        el[k],
                        tlat[k],
                        g.lon_deg[k],
                        300.0,
                    )
                ]
            )
    return load_records(f, angles=nominal.angle_names), nominal


def test_recovers_mount_and_focal_length(tmp_path):
    recs, nominal = make_records(tmp_path)
    fit = fit_sensor_params(recs, nominal, list(TRUE), HeightSurface(300.0, "geodetic"))
    assert fit.rms_before_m > 20.0  # a 0.6 deg mount at 2-3 km slant: tens of metres
    # noise-free: the true values to the solver's tolerance (1e-9 rad is 3 um at 3 km)
    np.testing.assert_allclose(fit.values[:3], [TRUE[k] for k in list(TRUE)[:3]], atol=1e-9)
    assert fit.values[3] == pytest.approx(TRUE["fx"], abs=1e-5)
    assert fit.rms_after_m < 1e-5
    rep = fit.report()
    assert rep["parameters"]["mount_z"]["unit"] == "deg"
    assert rep["parameters"]["mount_z"]["value"] == pytest.approx(0.6, abs=1e-7)


def test_leave_one_out_does_not_use_the_left_out_record(tmp_path):
    # one surveyed point 25 m off: fitted with the others, it keeps its whole 25 m error;
    # in the fit that includes it, the parameters lean towards it and its error shrinks
    recs, nominal = make_records(tmp_path, n=8, plant_m=25.0)
    fit = fit_sensor_params(recs, nominal, list(TRUE), HeightSurface(300.0, "geodetic"), loo=True)
    # without it, the seven clean records give the true sensor exactly: its error is the planted 25 m
    # (5 mm: the plant is 25 m of latitude at 111 km/deg, the error a geodesic on the ellipsoid)
    assert fit.loo_errors_m[0] == pytest.approx(25.0, abs=0.15)
    assert fit.errors_after_m[0] < 24.0 and np.all(fit.loo_errors_m[1:] > fit.errors_after_m[1:] - 1e-6)


def test_unknown_parameter_is_an_error(tmp_path):
    recs, nominal = make_records(tmp_path, n=5)
    with pytest.raises(ValueError, match=r"cannot fit \['focal'\]"):
        fit_sensor_params(recs, nominal, ["focal"], HeightSurface(300.0))
