"""One contract, run against every sensor, surface, correction and executor (as Rugged's AbstractAlgorithmTest).

For each (sensor, surface, corrections) triple, through the one location pipeline
(:class:`geoloc.pipeline.Pipeline`): pixel -> ground -> pixel comes back to the pixel, and
every executor (the numpy reference, the compiled engines) gives the same ground points; a
correction a sensor cannot take is refused by name (an RPC takes none: its maker's fit
already holds them; a frame sensor's pose has no velocity for aberration). A pixel off the
sensor is OUTSIDE_SENSOR with no ground point; a named parameter, perturbed, moves the
answer. Frame sensors also see the sky (SKY). The DEM is a synthetic hill field laid under
each sensor's footprint, so every sensor meets real relief.
"""

import math

from pathlib import Path

import numpy as np
import pytest

from geoloc.analysis.rpc_fit import fit_rpc
from geoloc.assets import DEFAULT_CAMERA, asset_path
from geoloc.frames.chain import Pose
from geoloc.pipeline import Corrections, Pipeline
from geoloc.sensors.base import Sensor
from geoloc.sensors.camera import Camera
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens, FisheyeLens
from geoloc.sensors.rpc import RPCSensor
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import HeightSurface
from geoloc.surfaces.terrain import DemSurface
from geoloc.workflows.scenario import load_scenario
from geoloc.io.sentinel2 import read_product

#: Round-trip tolerance per sensor [px]. Frame cameras and the pushbroom: the hit lies on the
#: sensor's own ray, so only the lens inverse (1e-14 normalised) and the pushbroom's line-time
#: iteration (1e-6 line) are left: 1e-6 px. The RPC's straight line departs from its own curved
#: locus by up to 2.6e-6 px inside the domain (tests/sensors/test_rpc_sensor.py): 5e-6 px.
ROUND_TRIP_PX = {"q17": 1e-6, "turret": 1e-6, "drone": 1e-6, "pushbroom": 1e-6, "sentinel2": 1e-6, "rpc": 5e-6}


def _sensors():
    q17 = Camera.from_toml(asset_path(*DEFAULT_CAMERA)).to_sensor()
    brown = BrownLens(
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
    fish = FisheyeLens(
        fx=1900.0, fy=1900.0, cx=1999.5, cy=1499.5, width=4000, height=3000, k1=0.03, k2=-0.01, k3=0.002, k4=-0.0003
    )
    turret = FrameSensor(
        brown,
        PRESETS["azimuth-elevation"],
        mount=(2e-3, -1e-3, 4e-3),
        boresight=(1e-3, 2e-3, -3e-3),
        lever_arm_m=(1.5, 0.2, 0.7),
    )
    drone = FrameSensor(fish, PRESETS["yaw-pitch-roll"], boresight=(0.0, 1e-3, 0.0), lever_arm_m=(0.1, 0.0, 0.2))
    sc = load_scenario(asset_path("scenarios", "zy3_nadir.toml"))
    rpc = RPCSensor(
        fit_rpc(sc.sensor, sc.height_min, sc.height_max, sc.grid, sc.check_grid).model, sc.sensor.rows, sc.sensor.cols
    )
    return {
        "q17": (q17, Pose.from_deg(36.39895, 78.72927, 17987.25, 30.0457, 3.3903, -0.011, -45.2273, -2.488)),
        "turret": (
            turret,
            Pose.from_deg(36.35, -84.17, 2500.0, 40.0, 2.0, -3.0, angles_deg={"azimuth": 75.0, "elevation": -35.0}),
        ),
        "drone": (
            drone,
            Pose.from_deg(
                36.35,
                -84.17,
                1500.0,
                200.0,
                4.0,
                3.0,
                angles_deg={"gimbal_yaw": 30.0, "gimbal_pitch": -80.0, "gimbal_roll": 0.0},
            ),
        ),
        "pushbroom": (sc.sensor, None),
        # a real satellite: Sentinel-2 B05 of detector 07 over its whole datastrip (tests/data/sentinel2)
        "sentinel2": (read_product(Path(__file__).parents[1] / "data" / "sentinel2" / "L1B").sensor("B05", 7), None),
        "rpc": (rpc, None),
    }


SENSORS = _sensors()


def _hills_under(sensor, state):
    """A 1 km-relief synthetic DEM (EPSG:4326, ellipsoidal) around the image's ground footprint."""
    rows = np.array([0.5, 0.5, sensor.rows + 0.5, sensor.rows + 0.5, (sensor.rows + 1) / 2])
    cols = np.array([0.5, sensor.cols + 0.5, sensor.cols + 0.5, 0.5, (sensor.cols + 1) / 2])
    g = HeightSurface(0.0, "geodetic").intersect(sensor.line_of_sight(rows, cols, state))
    lat, lon = np.rad2deg(g.lat), np.rad2deg(g.lon)
    pad = 0.02
    n0, w0 = np.nanmax(lat) + pad, np.nanmin(lon) - pad
    ny, nx = 120, 120
    dlat, dlon = (
        (np.nanmax(lat) - np.nanmin(lat) + 2 * pad) / (ny - 1),
        (np.nanmax(lon) - np.nanmin(lon) + 2 * pad) / (nx - 1),
    )
    y, x = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    h = 300.0 + 350.0 * np.sin(x / 9.0) * np.cos(y / 13.0) + 150.0 * np.cos((x + y) / 5.0)
    return DEM.from_array(h, n0, w0, dlat, dlon, datum="ellipsoid")


def _surfaces(name):
    sensor, state = SENSORS[name]
    return {
        "inflated": HeightSurface(250.0, "inflated"),
        "geodetic": HeightSurface(250.0, "geodetic"),
        "dem-exact": DemSurface(_hills_under(sensor, state), "exact"),
        "dem-bisect": DemSurface(_hills_under(sensor, state), "bisect", threshold=1e-4),
    }


#: The corrections, as ``Corrections.for_sensor`` options.
CORRECTIONS = {
    "none": {"light_time": False, "aberration": False},
    "refraction": {"refraction": "standard", "light_time": False, "aberration": False},
    "light_time": {"light_time": True, "aberration": False},
    "aberration": {"light_time": False, "aberration": True},
    "all": {"refraction": "standard", "light_time": True, "aberration": True},
}
#: Round trip with a correction on [px]: ``Refraction.aim`` stops when its bent ray misses the
#: point by less than 1e-4 m, and the smallest ground pixel here is the [Q17] camera's 0.11 m
#: (18 km / 166 841 px): 1e-3 px. (Measured: 4e-7 px.)
ROUND_TRIP_CORRECTED_PX = 1e-3
#: Executors agree to 1 mm (the executors' agreed bound); the fused kernel's hit differs from numpy's by
#: the rounding of two chains written apart (tests/sensors/test_fastlocate.py: micrometres).
EXECUTORS_AGREE_M = 1e-3
SURFACES = ("inflated", "geodetic", "dem-exact", "dem-bisect")
CASES = [(s, f, c) for s in SENSORS for f in SURFACES for c in CORRECTIONS]


def _refusal(name, corr):
    """The words a refused combination must be refused with, or None when it is served."""
    if name == "rpc" and corr != "none":
        return "RPC"
    if name in ("q17", "turret", "drone") and CORRECTIONS[corr].get("aberration"):
        return "no platform velocity"
    return None


def _pixels(sensor, n=9):
    r, c = np.meshgrid(np.linspace(0.5, sensor.rows + 0.5, n), np.linspace(0.5, sensor.cols + 0.5, n), indexing="ij")
    return r.ravel(), c.ravel()


@pytest.mark.parametrize("name,surface,corr", CASES)
def test_pixel_ground_pixel_round_trip(name, surface, corr):
    sensor, state = SENSORS[name]
    assert isinstance(sensor, Sensor)
    refused = _refusal(name, corr)
    if refused:
        with pytest.raises(ValueError, match=refused):
            Corrections.for_sensor(sensor, **CORRECTIONS[corr])
        return
    pipe = Pipeline(sensor, _surfaces(name)[surface], Corrections.for_sensor(sensor, **CORRECTIONS[corr]))
    row, col = _pixels(sensor)
    hits = {engine: pipe.locate(row, col, state, engine=engine) for engine in ("numpy", "numba")}
    hit = hits["numpy"]
    ok = hit.status == Status.OK
    assert ok.mean() > 0.9, np.unique(hit.status, return_counts=True)
    assert hit.corrections == tuple(k for k in ("aberration", "light_time", "refraction") if corr in (k, "all"))
    assert np.all((hit.refraction_m[ok] > 0) if corr in ("refraction", "all") else (hit.refraction_m[ok] == 0))
    for engine, other in hits.items():
        np.testing.assert_array_equal(other.status, hit.status, err_msg=engine)
        assert np.nanmax(np.linalg.norm(other.ecef - hit.ecef, axis=-1)) < EXECUTORS_AGREE_M, engine
    back = pipe.ground_to_pixel(hit.lat[ok], hit.lon[ok], hit.h[ok], state)
    assert np.all(np.isin(back.status, (Status.OK, Status.OUTSIDE_SENSOR)))
    tol = ROUND_TRIP_PX[name] if corr == "none" else ROUND_TRIP_CORRECTED_PX
    np.testing.assert_allclose(back.row, row[ok], atol=tol)
    np.testing.assert_allclose(back.col, col[ok], atol=tol)


@pytest.mark.parametrize("name", list(SENSORS))
def test_a_pixel_off_the_sensor_gets_no_ground_point(name):
    sensor, state = SENSORS[name]
    row = np.array([(sensor.rows + 1) / 2, sensor.rows + 40.0, -3.0])
    col = np.array([(sensor.cols + 1) / 2, (sensor.cols + 1) / 2, 10.0])
    los = sensor.line_of_sight(row, col, state)
    assert list(los.status) == [Status.OK, Status.OUTSIDE_SENSOR, Status.OUTSIDE_SENSOR]
    served = [c for c in CORRECTIONS if not _refusal(name, c)]
    for surf in _surfaces(name).values():
        for corr in served:
            hit = Pipeline(sensor, surf, Corrections.for_sensor(sensor, **CORRECTIONS[corr])).intersect(los)
            assert list(hit.status[1:]) == [Status.OUTSIDE_SENSOR] * 2, corr
            assert np.all(np.isnan(hit.lat[1:])) and np.isfinite(hit.lat[0]), corr
            assert np.all(np.isnan(hit.refraction_m[1:])), corr


@pytest.mark.parametrize("name", ["q17", "turret", "drone"])
def test_a_ray_above_the_horizon_is_sky(name):
    sensor, state = SENSORS[name]
    up = state.with_angles(
        **(
            {"gimbal_roll": math.radians(100.0)}
            if name == "q17"
            else {"elevation": math.radians(30.0)}
            if name == "turret"
            else {"gimbal_pitch": math.radians(20.0)}
        )
    )
    los = sensor.line_of_sight((sensor.rows + 1) / 2, (sensor.cols + 1) / 2, up)
    for surf in _surfaces(name).values():
        for corr in ("none", "refraction", "light_time"):
            pipe = Pipeline(sensor, surf, Corrections.for_sensor(sensor, **CORRECTIONS[corr]))
            assert int(pipe.intersect(los).status) in (Status.SKY, Status.LEFT_DEM), corr
    assert int(HeightSurface(0.0).intersect(los).status) == Status.SKY


@pytest.mark.parametrize("name", list(SENSORS))
def test_every_named_parameter_moves_the_answer(name):
    sensor, state = SENSORS[name]
    # off the centre (a fifth of the way in from a corner), so the lens terms act
    row, col = np.array([0.2 * sensor.rows]), np.array([0.8 * sensor.cols])
    surf = HeightSurface(250.0, "geodetic")
    base = surf.intersect(sensor.line_of_sight(row, col, state))
    assert sensor.params, "a sensor must name its parameters"
    for key, value in sensor.params.items():
        # steps of a size a calibration would meet: 1 mrad, 1 m, 1 px, 1 % of a coefficient
        step = {"t0_s": 0.5, "line_period_s": 1e-5}.get(
            key,
            1e-3
            if "_x" in key[-2:] or key in ("mount_x", "mount_y", "mount_z", "boresight_x", "boresight_y", "boresight_z")
            else 1.0
            if key.endswith("_m") or key in ("cx", "cy")
            else 0.01 * sensor.params["fx"]
            if key == "skew"
            else 0.01 * max(abs(value), 1.0),
        )
        los = sensor.with_params(**{key: value + step}).line_of_sight(row, col, state)
        moved = surf.intersect(los)
        # the answer moves, or (a lever arm along the line of sight) the ray's origin does
        shift = max(
            float(np.linalg.norm(moved.ecef - base.ecef)), float(np.linalg.norm(los.origin_ecef - base.los.origin_ecef))
        )
        assert shift > 1e-3, f"{key}: moved {shift:.2e} m"
    with pytest.raises(ValueError, match="no parameter"):
        sensor.with_params(not_a_parameter=1.0)


@pytest.mark.parametrize("corr", ["all", "light_time"])
@pytest.mark.parametrize("name", ["pushbroom", "sentinel2"])
def test_a_corrected_pushbroom_round_trip_closes_to_a_millionth_of_a_pixel(name, corr):
    """A pushbroom's optical centre moves with the row, so ``Pipeline.ground_to_pixel`` repeats from
    the new row's centre until the pixel moves by less than its ``tol_px`` (1e-7 px). With every
    correction on, or light time alone (the aim then a direction of the range's length, normalised
    before the point is put back at the range), the round trip closes to 1e-6 px: measured 3e-7 px (the aim's own stop, 1e-4 m
    on ground pixels of 2 m and 20 m); an iteration stopped at a pixel's move (a tolerance of 1 px)
    leaves Sentinel-2's rows 3e-6 px off, one pass ZY3's 3e-5 px."""
    sensor, state = SENSORS[name]
    pipe = Pipeline(sensor, _surfaces(name)["geodetic"], Corrections.for_sensor(sensor, **CORRECTIONS[corr]))
    row, col = _pixels(sensor)
    hit = pipe.locate(row, col, state)
    ok = hit.status == Status.OK
    assert ok.mean() > 0.9
    back = pipe.ground_to_pixel(hit.lat[ok], hit.lon[ok], hit.h[ok], state)
    np.testing.assert_allclose(back.row, row[ok], rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.col, col[ok], rtol=0, atol=1e-6)
