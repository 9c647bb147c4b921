"""Monte Carlo through the sensor: the sensor's named mount / boresight parameters as error sources.

Oracles: the paper's explicit chain (tests/analysis/test_montecarlo.py's chain_reference: FrameChain
with batched rotations) and ``FrameSensor.with_params`` run draw by draw (the named-parameter
path of the sensor, not Monte Carlo's rotation algebra).
"""

import dataclasses
import math

import numpy as np
import pytest

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import Distribution, ErrorModel
from geoloc.assets import asset_path
from geoloc.locate import as_sensor, locate
from geoloc.status import Status
from test_montecarlo import chain_reference


@pytest.fixture(scope="module")
def model():
    m = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
    # a camera with a mount and a boresight of its own, so the draws compose with them
    cam = dataclasses.replace(m.camera, mount=(1e-3, math.radians(0.22), -2e-3), boresight=(5e-4, -3e-4, 1e-3))
    return dataclasses.replace(m, camera=cam)


def test_mount_and_boresight_draws_equal_the_sensor_with_those_parameters(model):
    rng = np.random.default_rng(4)
    n = 6
    draws = {f"{w}_{a}_deg": np.deg2rad(rng.normal(0, 0.05, n)) for w in ("mount", "boresight") for a in "xyz"}
    errs = dict(draws)
    lat_h, lon_h, h_h, st_h = mc.evaluate(model, errs)
    lat_c, lon_c, _, st_c = chain_reference(model, errs)
    # the engine (the sensor's graph) and the reference (the paper's chain with batched rotations)
    np.testing.assert_allclose(lat_h, lat_c, rtol=0, atol=1e-13)
    np.testing.assert_allclose(lon_h, lon_c, rtol=0, atol=1e-13)
    # and each draw is the sensor with its named parameters moved by the draw
    s = as_sensor(model.camera)
    pose = model.nominal_pose()
    for k in range(n):
        moved = s.with_params(
            **{
                f"{w}_{a}": s.params[f"{w}_{a}"] + draws[f"{w}_{a}_deg"][k]
                for w in ("mount", "boresight")
                for a in "xyz"
            }
        )
        g = locate(pose, moved, model.row, model.col, target_h=model.target_h_m, height_kind=model.height_kind)
        # 1e-13 rad = 0.6 um: the same rotations in another order
        assert float(g.lat) == pytest.approx(lat_h[k], abs=1e-13)
        assert float(g.lon) == pytest.approx(lon_h[k], abs=1e-13)
    assert np.all(st_h == Status.OK)


def test_a_mount_sigma_spreads_the_points_as_the_same_gimbal_encoder_sigma(model):
    # a mount draw about the body's x axis at zero attitude errors acts as a gimbal-roll error
    # of the same size ([Q17]'s outer gimbal turns about body X too): equal spreads
    base = dataclasses.replace(
        model, camera=dataclasses.replace(model.camera, mount=(0.0, 0.0, 0.0), boresight=(0.0, 0.0, 0.0)), errors={}
    )
    a = dataclasses.replace(base, errors={"mount_x_deg": Distribution("normal", math.radians(0.01))})
    b = dataclasses.replace(base, errors={"gimbal_roll_deg": Distribution("normal", math.radians(0.01))})
    ra = mc.run(a, 20_000, np.random.default_rng(1))
    rb = mc.run(b, 20_000, np.random.default_rng(1))
    # same draws (same seed, one source each): the same points to float64 rounding
    assert ra.stats["cep_m"] == pytest.approx(rb.stats["cep_m"], rel=1e-9)
    assert ra.stats["cep50_empirical_m"] == pytest.approx(rb.stats["cep50_empirical_m"], rel=1e-9)


def test_lever_arm_draws_move_the_point_by_the_body_offset(model):
    # at nadir-ish geometry a lever-arm draw shifts the optical centre and so the ground point by
    # the same horizontal offset (to first order: the line of sight's direction is unchanged)
    rng = np.random.default_rng(9)
    n = 5
    dx = rng.normal(0, 2.0, n)
    lat0, lon0, _, _ = mc.evaluate(model, {"lever_arm_x_m": np.zeros(n)})
    lat1, lon1, _, _ = mc.evaluate(model, {"lever_arm_x_m": dx})
    s = as_sensor(model.camera)
    pose = model.nominal_pose()
    for k in range(n):
        moved = s.with_params(lever_arm_x_m=s.params["lever_arm_x_m"] + dx[k])
        g = locate(pose, moved, model.row, model.col, target_h=model.target_h_m, height_kind=model.height_kind)
        assert float(g.lat) == pytest.approx(lat1[k], abs=1e-13) and float(g.lon) == pytest.approx(lon1[k], abs=1e-13)
    assert np.all(np.abs(lat1 - lat0) + np.abs(lon1 - lon0) > 0)
