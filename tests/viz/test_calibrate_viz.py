"""Error-vector layer on an in-process viser server: node positions against pymap3d.

pymap3d.geodetic2enu is the outside reference for the ENU placement; the
computed positions come from the core (geoloc.locate), the truth from the records.
"""

import numpy as np
import pymap3d
import pytest

import viser  # a dependency of the project (pyproject), so never a skip

from geoloc.surfaces.height import PerRecordHeightSurface

from geoloc.analysis.sensor_fit import fit_sensor_groups
from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.frames.enu import EnuFrame
from geoloc.io.records import load_records
from geoloc.locate import as_sensor, locate
from geoloc.sensors.camera import Camera
from geoloc.sensors.sensor_file import load_sensor
from geoloc_viz.calibration_layer import add_error_vectors


@pytest.fixture(scope="module")
def server():
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_error_vector_nodes(server):
    rec = load_records(asset_path(*DEFAULT_RECORDS))
    cam = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
    h = rec.column("paper_height_m")
    _, cams = fit_sensor_groups(
        rec,
        as_sensor(cam),
        ["mount_x", "mount_y", "mount_z"],
        PerRecordHeightSurface(h),
        group_column="table",
        joint=True,
    )
    lat0, lon0, h00 = 36.36, 78.87, 5000.0  # flight T3's area
    frame = EnuFrame.from_deg(lat0, lon0, h00)
    layer = add_error_vectors(server.scene, rec, frame, h, cam, cams["joint"], exaggeration=20.0)

    tl, tn = rec.column("truth_lat_deg"), rec.column("truth_lon_deg")
    truth = np.stack(pymap3d.geodetic2enu(tl, tn, h, lat0, lon0, h00), axis=-1)
    before = np.array(layer.handles["before"].points)  # copies: the handle reuses its buffer
    after = np.array(layer.handles["after"].points)
    assert before.shape == after.shape == (20, 2, 3)
    # start of every segment = truth. Tolerance 0.05 m: the truth is placed at the
    # computed height, which differs from paper_height_m by the inflated-ellipsoid
    # approximation (mm at 5 km, docs/method.md section 3), plus float32 storage of
    # coordinates up to ~250 km (T4 is 2.5 deg away): 250e3 * 6e-8 = 0.015 m.
    np.testing.assert_allclose(before[:, 0], truth, atol=0.05)
    np.testing.assert_allclose(layer.truth_handle.points, truth, atol=0.05)
    for stage, c, pts in (("before", cam, before), ("after", cams["joint"], after)):
        g = locate(rec.pose(), c, rec.column("row"), rec.column("col"), h, outside="extrapolate")
        comp = np.stack(pymap3d.geodetic2enu(g.lat_deg, g.lon_deg, g.h, lat0, lon0, h00), axis=-1)
        # end = truth + 20 (computed - truth); float32 error 0.015 m on each end
        np.testing.assert_allclose((pts[:, 1] - pts[:, 0]) / 20.0, comp - truth, atol=0.01)
    length = np.linalg.norm(before[:, 1] - before[:, 0], axis=1) / 20.0
    length_after = np.linalg.norm(after[:, 1] - after[:, 0], axis=1) / 20.0
    assert length.mean() > 45.0 and length_after.mean() < 8.0  # ~50 m -> ~5 m: the calibration's effect, drawn

    layer.set_stage("after")
    assert not layer.handles["before"].visible and layer.handles["after"].visible
    layer.set_exaggeration(5.0)
    np.testing.assert_allclose(
        layer.handles["after"].points[:, 1] - layer.handles["after"].points[:, 0],
        (after[:, 1] - after[:, 0]) / 4.0,
        atol=0.01,
    )
    with pytest.raises(ValueError, match="exaggeration"):
        layer.set_exaggeration(0.0)
    with pytest.raises(ValueError, match="stage"):
        layer.set_stage("during")
    dd, sl = layer.add_gui(server.gui)
    assert dd.value == "after" and sl.value == 5.0


def test_app_calibration_with_a_scenario_like_app(server):
    # A stand-in for geoloc_viz.app.GeolocApp: server, scn.enu, scn.camera and
    # scn.records as (info, inputs) pairs, as the viewer holds them.
    from types import SimpleNamespace

    from geoloc_viz.calibration_layer import attach

    rec = load_records(asset_path(*DEFAULT_RECORDS))
    cam = load_sensor(asset_path(*DEFAULT_CAMERA))  # what the app's Scenario holds: a FrameSensor
    c = rec.column
    pairs = []
    for k, label in enumerate(rec.labels()):
        info = SimpleNamespace(
            label=label,
            paper_height_m=c("paper_height_m")[k],
            truth_lat_deg=c("truth_lat_deg")[k],
            truth_lon_deg=c("truth_lon_deg")[k],
        )
        inp = SimpleNamespace(
            **{
                n: c(f)[k]
                for n, f in (
                    ("row", "row"),
                    ("col", "col"),
                    ("lat_deg", "ac_lat_deg"),
                    ("lon_deg", "ac_lon_deg"),
                    ("h_m", "ac_h_m"),
                    ("heading_deg", "heading_deg"),
                    ("pitch_deg", "pitch_deg"),
                    ("roll_deg", "roll_deg"),
                    ("gimbal_roll_deg", "gimbal_roll_deg"),
                    ("gimbal_pitch_deg", "gimbal_pitch_deg"),
                )
            }
        )
        pairs.append((info, inp))
    lat0, lon0, h00 = 35.59, 80.87, 4900.0  # flight T4's area
    scn = SimpleNamespace(records=pairs, camera=cam, enu=EnuFrame.from_deg(lat0, lon0, h00), source="x.csv")
    app = SimpleNamespace(server=server, scn=scn)
    cal = attach(app)
    # the app's world unit is the km (geoloc_viz.scene_geoloc.WORLD_SCALE) and its root /enu
    from geoloc_viz.scene_geoloc import ROOT, WORLD_SCALE

    assert WORLD_SCALE == 1e-3 and cal.layer.name == f"{ROOT}/calibration"
    h = c("paper_height_m")
    truth = np.stack(pymap3d.geodetic2enu(c("truth_lat_deg"), c("truth_lon_deg"), h, lat0, lon0, h00), -1)
    np.testing.assert_allclose(cal.layer.truth_handle.points / WORLD_SCALE, truth, atol=0.05)  # as above
    after = np.array(cal.layer.handles["after"].points) / WORLD_SCALE
    # drawn at true length by default; the scale label shows only on an exaggerated drawing (at true
    # length it would sit on the surveyed point)
    assert cal.layer.exaggeration == 1.0 and cal.layer.label_handle.text.endswith("true length")
    assert not cal.layer.label_handle.visible
    assert np.linalg.norm(after[:, 1] - after[:, 0], axis=1).mean() < 8.0
    # the GUI drives the layer
    cal.dd_stage.value = "before"
    cal.sl_exag.value = 10.0
    assert cal.layer.stage == "before" and cal.layer.exaggeration == 10.0
    assert cal.layer.label_handle.text == "error vectors of all records (before), drawn x10"
    assert cal.layer.label_handle.visible
    # moving the origin and rebuilding keeps stage and exaggeration, in the new frame
    scn.enu = EnuFrame.from_deg(36.36, 78.87, 5000.0)
    cal.rebuild()
    truth2 = np.stack(pymap3d.geodetic2enu(c("truth_lat_deg"), c("truth_lon_deg"), h, 36.36, 78.87, 5000.0), -1)
    np.testing.assert_allclose(cal.layer.truth_handle.points / WORLD_SCALE, truth2, atol=0.05)
    assert cal.layer.stage == "before" and cal.layer.exaggeration == 10.0
    assert not cal.layer.handles["after"].visible
    # vertical exaggeration as the scene's terrain: node scale (1, 1, v)
    cal.layer.set_vertical_exaggeration(3.0)
    np.testing.assert_allclose(cal.layer.handles["before"].scale, (1.0, 1.0, 3.0))
