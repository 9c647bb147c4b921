"""Targets seen from many frames (geoloc.analysis.triangulate) against outside numbers.

* The intersection: rays built through a known point (numpy only) meet there; rays with a known
  offset give that offset's residuals.
* The covariance: Monte Carlo of the whole chain. For a target seen from 3, 10 and 30 frames of a
  simulated orbit, every frame's pose gets its own errors (position, attitude, gimbal joints:
  noise) and the sensor one set per trial (mount, boresight, focal length: biases); the pixel is
  the target's projection through the true pose and sensor, the ray the one the nominal pose and
  sensor give it. The predicted CE90 and LE90 must be within 10 % of the trials' (M = 1500: the
  90th percentile's sampling error is ~2.5 %, so 10 % is 4 of them).
* The DEM check: a DEM shifted by 30 m is reported; an unshifted one is not.
"""

import dataclasses
import math

import numpy as np
import pytest

from geoloc.analysis import triangulate as T
from geoloc.analysis.uncertainty import empirical_ce90_le90
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef, meridian_radius, prime_vertical_radius
from geoloc.geodesy.local import ecef_to_enu
from geoloc.sensors.budget import ErrorBudget
from geoloc.status import Status
from test_uncertainty import TURRET

TARGET = (math.radians(36.5), math.radians(-84.25), 400.0)
NOISE = {
    "north_m": 2.0,
    "east_m": 2.0,
    "up_m": 3.0,
    "heading_deg": 0.05,
    "pitch_deg": 0.03,
    "roll_deg": 0.03,
    "azimuth_deg": 0.03,
    "elevation_deg": 0.03,
}
BIAS = {"mount_z_deg": 0.02, "boresight_x_deg": 0.02, "boresight_y_deg": 0.02, "fx_px": 3.0}
BUDGET = ErrorBudget({**NOISE, **BIAS})


def test_rays_through_a_point_meet_there():
    rng = np.random.default_rng(1)
    X = np.array([1.2e6, -4.8e6, 4.0e6])
    O = X + rng.normal(0, 5000, (7, 3))
    X2, res, _, _ = T.intersect_rays(O, X - O)
    assert np.allclose(X2, X, atol=1e-6)  # exact rays: rounding of 1e7 m coordinates
    assert np.all(res < 1e-6)
    # two rays crossing 10 m apart: the midpoint, 5 m from each
    X3, res3, _, _ = T.intersect_rays([[0, 0, 0], [0, 0, 10.0]], [[1, 0, 0], [0, 1, 0.0]])
    assert np.allclose(X3, [0, 0, 5.0]) and np.allclose(res3, 5.0)


def orbit(n, arc=None):
    """n frames on a 4 km circle 3 km above the target, looking at it (angles from the geometry);
    over ``arc`` radians (default: a sixth of a turn per frame up to a whole turn)."""
    lat0, lon0, h0 = TARGET
    arc = 2 * math.pi * (1 - 1 / n) * min(1.0, n / 6) if arc is None else arc
    a = np.linspace(0, arc, n)
    r = 4000.0
    north, east = r * np.cos(a), r * np.sin(a)
    lat = lat0 + north / (meridian_radius(lat0) + h0)
    lon = lon0 + east / ((prime_vertical_radius(lat0) + h0) * math.cos(lat0))
    heading = np.mod(np.degrees(a) + 90.0, 360.0)  # flying the circle anticlockwise seen from above
    # the turret looks at the target: bearing from the aircraft minus heading, depression below the horizon
    bearing = np.degrees(np.arctan2(-east, -north))
    dep = math.degrees(math.atan2(3000.0, r))
    pose = Pose.from_deg(
        np.degrees(lat),
        np.degrees(lon),
        np.full(n, h0 + 3000.0),
        heading,
        np.zeros(n),
        np.zeros(n),
        angles_deg={"azimuth": np.mod(bearing - heading, 360.0), "elevation": np.full(n, -dep)},
    )
    return pose


def _target_pixels(sensor, pose):
    row, col, st = sensor.ground_to_pixel(*TARGET, pose)
    assert np.all(st == Status.OK), st
    return row, col


def test_the_orbit_sees_the_target_near_the_image_centre():
    pose = orbit(12)
    row, col = _target_pixels(TURRET, pose)
    assert np.all(np.abs(row - 540.5) < 200) and np.all(np.abs(col - 960.5) < 200)


def _perturbed(pose, draw, k):
    """The true pose of frame k: the nominal plus the drawn noise."""
    lat, lon, h = (np.asarray(getattr(pose, f))[k] for f in ("lat", "lon", "h"))
    d = {key: draw[key][k] for key in NOISE}
    return dict(
        lat=lat + d["north_m"] / (meridian_radius(lat) + h),
        lon=lon + d["east_m"] / ((prime_vertical_radius(lat) + h) * math.cos(lat)),
        h=h + d["up_m"],
        heading=np.asarray(pose.heading)[k] + math.radians(d["heading_deg"]),
        pitch=np.asarray(pose.pitch)[k] + math.radians(d["pitch_deg"]),
        roll=np.asarray(pose.roll)[k] + math.radians(d["roll_deg"]),
        azimuth=np.asarray(pose.angle("azimuth"))[k] + math.radians(d["azimuth_deg"]),
        elevation=np.asarray(pose.angle("elevation"))[k] + math.radians(d["elevation_deg"]),
    )


@pytest.mark.parametrize("n", [3, 10, 30])
def test_triangulated_error_within_10_percent_of_monte_carlo(n):
    rng = np.random.default_rng(100 + n)
    pose = orbit(n)
    row0, col0 = _target_pixels(TURRET, pose)
    pred = T.triangulate(TURRET, pose, row0, col0, BUDGET)
    assert pred.status == Status.OK and pred.n_rays == n
    X0 = geodetic_to_ecef(*TARGET)
    assert np.linalg.norm(pred.ecef - X0) < 1e-3  # the nominal rays meet at the target (1 mm: the lens's inverse)
    M = 1500
    err = np.empty((M, 3))
    for m in range(M):
        draw = {k: rng.standard_normal(n) * s for k, s in NOISE.items()}
        b = {k: rng.standard_normal() * s for k, s in BIAS.items()}
        true_sensor = dataclasses.replace(
            TURRET,
            lens=TURRET.lens.with_params(fx=TURRET.lens.params["fx"] + b["fx_px"]),
            mount=(TURRET.mount[0], TURRET.mount[1], TURRET.mount[2] + math.radians(b["mount_z_deg"])),
            boresight=(
                TURRET.boresight[0] + math.radians(b["boresight_x_deg"]),
                TURRET.boresight[1] + math.radians(b["boresight_y_deg"]),
                TURRET.boresight[2],
            ),
        )
        kw = [_perturbed(pose, draw, k) for k in range(n)]
        tp = Pose(
            **{f: np.array([w[f] for w in kw]) for f in ("lat", "lon", "h", "heading", "pitch", "roll")}
        ).with_angles(azimuth=np.array([w["azimuth"] for w in kw]), elevation=np.array([w["elevation"] for w in kw]))
        row, col, st = true_sensor.ground_to_pixel(*TARGET, tp)
        los = TURRET.line_of_sight(row, col, pose, outside="extrapolate", engine="numpy")
        X, _, _, _ = T.intersect_rays(los.origin_ecef, los.direction_ecef)
        err[m] = ecef_to_enu(X, *TARGET)
    ce, le = empirical_ce90_le90(err)
    assert pred.ce90_m == pytest.approx(ce, rel=0.10), (n, pred.ce90_m, ce)
    assert pred.le90_m == pytest.approx(le, rel=0.10), (n, pred.le90_m, le)


def test_more_frames_shrink_the_noise_but_not_the_biases():
    """On the same quarter turn: ten times the frames, noise down by about sqrt(10); a bias, the
    same in every frame, not averaged (on a whole turn it would cancel by symmetry instead)."""

    def ce(n, budget):
        p = orbit(n, arc=math.pi / 2)
        return T.triangulate(TURRET, p, *_target_pixels(TURRET, p), budget).ce90_m

    assert ce(30, ErrorBudget(NOISE)) == pytest.approx(ce(3, ErrorBudget(NOISE)) / math.sqrt(10), rel=0.35)
    assert ce(30, ErrorBudget(BIAS)) == pytest.approx(ce(3, ErrorBudget(BIAS)), rel=0.35)
    full = orbit(30, arc=2 * math.pi * 29 / 30)
    assert T.triangulate(TURRET, full, *_target_pixels(TURRET, full), ErrorBudget(BIAS)).ce90_m < 0.05


def test_a_shifted_dem_is_reported_and_a_right_one_is_not():
    pose = orbit(10)
    row, col = _target_pixels(TURRET, pose)
    tri = T.triangulate(TURRET, pose, row, col, BUDGET)
    rng = np.random.default_rng(3)
    right = TARGET[2] + rng.normal(0, 3.0, 10)  # a DEM with 3 m of noise at the target
    assert T.compare_with_surface(tri, right)["warning"] == ""
    shifted = right + 30.0  # e.g. MSL heights read as ellipsoidal where N = -30 m
    c = T.compare_with_surface(tri, shifted)
    assert "likely DEM or datum error" in c["warning"] and c["mean_m"] == pytest.approx(30.0, abs=3.0)


def test_parallel_rays_or_one_ray_are_refused():
    pose = orbit(3)
    row, col = _target_pixels(TURRET, pose)
    one = T.triangulate(
        TURRET,
        Pose(*(np.asarray(getattr(pose, f))[:1] for f in ("lat", "lon", "h", "heading", "pitch", "roll"))).with_angles(
            azimuth=np.asarray(pose.angle("azimuth"))[:1], elevation=np.asarray(pose.angle("elevation"))[:1]
        ),
        row[:1],
        col[:1],
    )
    assert one.status == Status.INVALID_INPUT and math.isnan(one.lat)
    lat, lon, h = ecef_to_geodetic(geodetic_to_ecef(*TARGET))
    assert abs(h - TARGET[2]) < 1e-6


def test_replay_triangulates_a_target_id_column_and_flags_a_shifted_height(tmp_path, capsys):
    """``geoloc replay`` on records naming one target in 10 rows: the intersection at the target
    (rays built from its projection), and the surface check against a height 30 m off."""
    import csv

    from geoloc.assets import asset_path
    from geoloc.cli import main
    from geoloc.sensors.sensor_file import load_sensor

    sensor_file = tmp_path / "turret.toml"
    sensor_file.write_text(
        asset_path("sensors", "eo_turret.toml").read_text()
        + "\n[uncertainty]\nnorth_m = 2.0\nheading_deg = 0.05\nelevation_deg = 0.03\n"
    )
    s = load_sensor(sensor_file)
    pose = orbit(10)
    row, col, st = s.ground_to_pixel(*TARGET, pose)
    assert np.all(st == Status.OK)
    recs = tmp_path / "recs.csv"
    with recs.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "target_id",
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
            ]
        )
        for k in range(10):
            w.writerow(
                [
                    "T1",
                    f"{row[k]:.6f}",
                    f"{col[k]:.6f}",
                    f"{math.degrees(pose.lat[k]):.10f}",
                    f"{math.degrees(pose.lon[k]):.10f}",
                    f"{pose.h[k]:.4f}",
                    f"{math.degrees(pose.heading[k]):.8f}",
                    "0",
                    "0",
                    f"{math.degrees(pose.angle('azimuth')[k]):.8f}",
                    f"{math.degrees(pose.angle('elevation')[k]):.8f}",
                ]
            )
    for h, warned in ((TARGET[2], False), (TARGET[2] + 30.0, True)):
        assert main(["replay", str(recs), "--sensor", str(sensor_file), "--target-h-m", f"{h}"]) == 0
        out = capsys.readouterr().out
        line = next(x for x in out.splitlines() if x.startswith("target T1:") and "rays" in x)
        lat, lon = (float(v) for v in line.split(":")[1].split()[:2])
        assert abs(lat - math.degrees(TARGET[0])) < 1e-7 and abs(lon - math.degrees(TARGET[1])) < 1e-7  # ~1 cm
        assert "from 10 rays" in line and "CE90" in line
        assert ("likely DEM or datum error" in out) == warned, out


def test_triangulate_rays_with_names_but_no_derivatives_says_so():
    # a budget's source names need each ray's derivatives: a ValueError naming them, not a
    # TypeError from adding None
    O = np.array([[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0]])
    D = np.array([[0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]])
    with pytest.raises(ValueError, match="dO and dD"):
        T.triangulate_rays(O, D, names=["north_m"])
