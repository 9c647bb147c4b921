"""Terrain in the recording, read back with rerun.chunk.RrdReader: DEM mesh, evaluations, H_n - h_n.

Expected values come from geoloc.surfaces.terrain.intersect_dem and geoloc.surfaces.dem.DEM called
here directly, and from the closed-form rule of the descending steps [Q17 section 2.3].
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import ASSETS
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.locate import line_of_sight
from geoloc.sensors.camera import Camera
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem
from geoloc.workflows.flight import FlightScenario, simulate

SCENARIO = Path(ASSETS) / "scenarios" / "flight_scan.toml"
DEM_PATH = Path(ASSETS) / "dem" / "etopo5_flight_area.tif"
CAMERA = Path(ASSETS) / "cameras" / "qiao2017.toml"


def short_scenario() -> FlightScenario:
    """The bundled scan, first 10 s at 2 Hz (21 rays, one sweep from 10 to 82 deg frame angle), to keep the test fast."""
    d = tomllib.loads(SCENARIO.read_text())
    d["time"] = {"duration_s": 10.0, "rate_hz": 2.0}
    return FlightScenario.from_dict(d, base=SCENARIO.parent, source=str(SCENARIO))


@pytest.fixture(scope="module")
def rec(rerun_home, tmp_path_factory):
    from rerun.chunk import RrdReader

    from geoloc_viz.rerun_log import write
    from geoloc_viz.rerun_model import steps_from_flight

    scn = short_scenario()
    steps = steps_from_flight(scn)
    out = tmp_path_factory.mktemp("rrd") / "terrain.rrd"
    write(steps, out)
    data = {}
    for ch in RrdReader(out).stream():
        b = ch.to_record_batch()
        kind = "temporal" if "frame" in b.schema.names else "static"
        ent = data.setdefault(ch.entity_path, {}).setdefault(kind, {})
        for n in b.schema.names:
            if n in ("rerun.controls.RowId", "log_time", "log_tick"):
                continue
            col = b.column(n)
            if str(col.type).startswith("duration"):
                col = col.cast("int64")
            ent.setdefault(n, []).extend(col.to_pylist())
    return scn, steps, data


@pytest.fixture(scope="module")
def core(rec):
    """The same rays through the core, directly."""
    scn = rec[0]
    p = simulate(scn).pose
    los = line_of_sight(p, Camera.from_toml(CAMERA))
    dem = DEM.open(DEM_PATH, datum="egm96")
    steps = intersect_dem(los, dem, "steps", eps_h=10.0, trace=True)
    exact = intersect_dem(los, dem, "exact")
    return p, dem, steps, exact


def _by(ent, key="frame"):
    ent = ent["temporal"]
    order = np.argsort(ent[key])
    return {n: [v[i] for i in order] for n, v in ent.items()}


def test_dem_evaluations_per_ray(rec, core):
    scn, steps, data = rec
    p, dem, hit, exact = core
    ent = _by(data["/series/dem/evaluations"])
    assert ent["frame"] == list(range(21))
    np.testing.assert_array_equal([r[0] for r in ent["Scalars:scalars"]], hit.dem_evaluations.astype(float))


def test_H_minus_h_per_iteration_is_the_trace(rec, core):
    scn, steps, data = rec
    p, dem, hit, exact = core
    ent = _by(data["/convergence/H_minus_h_m"])
    assert ent["frame"] == list(range(21))
    for k, bars in enumerate(ent["BarChart:values"]):
        got = np.array(bars[0]["buffer"])
        r = hit.trace.ray(k)
        np.testing.assert_array_equal(got, r["H"] - r["h_dem"])
        # [Q17 section 2.3]: H_0 = H_max, H_(n+1) = H_n - eps_h, stop at the first H_n - h_n < 0.
        np.testing.assert_allclose(np.diff(r["H"]), -10.0, atol=1e-9)  # float64 sums of 10 m steps
        assert np.all(got[:-1] > 0) and got[-1] < 0
        assert r["H"][0] == pytest.approx(dem.max_height(), abs=1e-9)


def test_truth_is_the_exact_hit_and_errors_match(rec, core):
    scn, steps, data = rec
    p, dem, hit, exact = core
    enu = steps.enu
    ent = _by(data["/world/truth"])
    np.testing.assert_array_equal(
        np.array([r[0] for r in ent["Points3D:positions"]]), enu.from_ecef(exact.ecef).astype(np.float32)
    )
    err = np.array([r[0] for r in _by(data["/series/error/to_truth_m"])["Scalars:scalars"]])
    np.testing.assert_array_equal(err, horizontal_distance_m(hit.lat_deg, hit.lon_deg, exact.lat_deg, exact.lon_deg))
    # The descending steps stop within eps_h = 10 m (in height, along the line of sight) below
    # the crossing, so the point is within 10 m x tan(off-nadir angle) of the exact hit along
    # the ground. Off-nadir angle <= frame angle + 5 deg (pitch 3.5 deg and Earth curvature,
    # 0.6 deg at 70 km).
    bound = 10.0 * np.tan(np.abs(p.gimbal_roll) + np.deg2rad(5.0))
    assert np.all(err <= bound)
    from geoloc.surfaces.height import intersect_los_height

    ell = intersect_los_height(line_of_sight(p, Camera.from_toml(CAMERA)), 5083.0)
    got = np.array([r[0] for r in _by(data["/series/ellipsoid_model/to_truth_m"])["Scalars:scalars"]])
    np.testing.assert_array_equal(got, horizontal_distance_m(ell.lat_deg, ell.lon_deg, exact.lat_deg, exact.lon_deg))


def test_dem_mesh_is_static_and_on_the_dem(rec, core):
    scn, steps, data = rec
    p, dem, hit, exact = core
    assert "temporal" not in data["/world/dem"]  # static only
    ent = data["/world/dem"]["static"]
    v = np.array(ent["Mesh3D:vertex_positions"][0], dtype=float)
    f = np.array(ent["Mesh3D:triangle_indices"][0])
    assert len(v) > 100 and f.max() < len(v)
    lat, lon, h = steps.enu.to_geodetic(v)
    # Every vertex is a DEM node: its height is the DEM's there. 0.05 m: float32 ENU
    # coordinates of points up to ~100 km from the origin (ulp 0.008 m) moved through ENU -> geodetic.
    np.testing.assert_allclose(h, dem.height(lat, lon), atol=0.05)
    # The mesh covers the hits (with the crop margin) and every exact hit lies within its extent.
    tl, tn = exact.lat_deg, exact.lon_deg
    assert np.rad2deg(lat).min() <= tl.min() and np.rad2deg(lat).max() >= tl.max()
    assert np.rad2deg(lon).min() <= tn.min() and np.rad2deg(lon).max() >= tn.max()


def test_iteration_points_lie_on_the_los_and_the_dem(rec, core):
    scn, steps, data = rec
    p, dem, hit, exact = core
    on = _by(data["/world/iterations/on_los"])
    seg = _by(data["/world/iterations/to_dem"])
    k = 7
    r = hit.trace.ray(k)
    np.testing.assert_array_equal(
        np.array(on["Points3D:positions"][k], dtype=np.float32), steps.enu.from_ecef(r["ecef"]).astype(np.float32)
    )
    lower = np.array([s[1] for s in seg["LineStrips3D:strips"][k]], dtype=float)
    lat, lon, h = steps.enu.to_geodetic(lower)
    np.testing.assert_allclose(h, r["h_dem"], atol=0.05)  # float32 ENU, as above


def test_records_on_the_dem_by_bisection(rec, tmp_path):
    """`geoloc log RECORDS --dem ... --method bisect`: evaluations and hits are the core's."""
    from rerun.chunk import RrdReader

    from geoloc.cli import main
    from geoloc.io.records import load_records

    records = Path(ASSETS) / "records" / "qiao2017_flight_tests.csv"
    out = tmp_path / "rec_dem.rrd"
    assert (
        main(["log", str(records), "--dem", str(DEM_PATH), "--method", "bisect", "--threshold", "5", "--out", str(out)])
        == 0
    )
    recs = load_records(records)
    los = line_of_sight(
        recs.pose(), Camera.from_toml(CAMERA), recs.column("row"), recs.column("col"), outside="extrapolate"
    )  # as the recording: T4-3 is off the sensor
    hit = intersect_dem(los, DEM.open(DEM_PATH, datum="egm96"), "bisect", threshold=5.0)
    ev, geo = {}, {}
    for ch in RrdReader(out).stream():
        b = ch.to_record_batch()
        if "record" not in b.schema.names:
            continue
        if ch.entity_path in ("/series/T3/dem/evaluations", "/series/T4/dem/evaluations"):  # one per flight
            ev.update(zip(b.column("record").to_pylist(), [r[0] for r in b.column("Scalars:scalars").to_pylist()]))
        if ch.entity_path in ("/map/T3/target", "/map/T4/target"):  # one map subtree per flight
            geo.update(zip(b.column("record").to_pylist(), [r[0] for r in b.column("GeoPoints:positions").to_pylist()]))
    assert sorted(ev) == list(range(20))
    np.testing.assert_array_equal([ev[k] for k in range(20)], hit.dem_evaluations.astype(float))
    np.testing.assert_array_equal([geo[k] for k in range(20)], np.c_[hit.lat_deg, hit.lon_deg])
    # each flight's DEM mesh and iterations live under its own tree, in its own scene frame
    ents = {ch.entity_path for ch in RrdReader(out).stream()}
    assert {"/world/T3/dem", "/world/T4/dem", "/world/T3/iterations/on_los", "/world/T4/iterations/to_dem"} <= ents
    assert "/world/dem" not in ents


def test_cep_series_is_the_core_monte_carlo(rec, core):
    """The optional per-step CEP (scenario [montecarlo]) read back equals geoloc.workflows.flight.step_cep."""
    from geoloc.analysis.errormodel import ErrorModel
    from geoloc.workflows.flight import step_cep

    scn, steps, data = rec
    ref = step_cep(
        simulate(scn),
        ErrorModel.from_toml(scn.mc_model_path),
        scn.target_h_m,
        scn.mc_samples,
        np.random.default_rng(scn.mc_seed),
    )
    for key in ("cep_m", "cep50_empirical_m"):
        ent = _by(data[f"/series/cep/{key}"])
        assert ent["frame"] == list(range(21))
        np.testing.assert_array_equal([r[0] for r in ent["Scalars:scalars"]], ref[key])
    # [Q17] Fig. 10a: the CEP grows with the frame angle (monotone over this one sweep 10 -> 82 deg).
    # Every 4th step (14 deg apart), well beyond the 5 % sampling noise of 200 samples.
    assert np.all(np.diff(ref["cep_m"][::4]) > 0)


def test_the_recording_opens_its_dem_once(monkeypatch):
    # method "steps" with a DEM: the located points, the exact truth and the mesh come from one raster,
    # read once (it was read twice: once per solver)
    from geoloc_viz import rerun_model

    opened = []
    real = DEM.open.__func__

    def counting(cls, path, *a, **kw):
        opened.append(Path(path).name)
        return real(cls, path, *a, **kw)

    monkeypatch.setattr(DEM, "open", classmethod(counting))
    scn = short_scenario()
    steps = rerun_model.steps_from_flight(scn)
    assert opened == [DEM_PATH.name]
    assert steps.terrain.method == "steps" and steps.terrain.dem_path == str(scn.dem_path)
