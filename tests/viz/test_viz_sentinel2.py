"""The Sentinel-2 scene (``geoloc view --scenario PRODUCT``), in process: what it draws is where
the product's geometry and independent references (pyproj's WGS-84, the geocentric vertical) say."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from geoloc_viz.app import make_server
from geoloc_viz.scene_geoloc import WORLD_SCALE

PRODUCT = Path(__file__).parents[1] / "data" / "sentinel2" / "L1B"


@pytest.fixture(scope="module")
def s2app():
    from geoloc_viz.scene_sentinel2 import Sentinel2App, load

    server = make_server(port=0)
    app = Sentinel2App(server, load(PRODUCT))
    yield app
    server.stop()


def handle(app, name):
    return app.server.scene._handle_from_node_name[name]


def ecef_of(app, p_scene):
    return app.enu.to_ecef(np.asarray(p_scene, float) / WORLD_SCALE)


def test_sentinel2_scene_draws_orbit_attitude_lines_of_sight_and_footprints(s2app):
    names = set(s2app.server.scene._handle_from_node_name)
    for n in (
        "earth",
        "orbit",
        "satellite",
        "los/first",
        "los/middle",
        "los/last",
        "swath",
        "footprint/D06",
        "footprint/D07",
    ):
        assert f"/s2/{n}" in names, n
    assert sum(n.startswith("/s2/attitude/") for n in names) == 9
    # the satellite node on the GPS orbit at the line's time (float64 on the wire: 1e-6 m)
    s = s2app.sensor
    p, _ = s.orbit.state(np.array([s.line_time(s2app.row)]))
    sat = handle(s2app, "/s2/satellite")
    assert np.linalg.norm(ecef_of(s2app, sat.position) - p[0]) < 1e-6
    # its body Z axis points to the Earth's centre: Sentinel-2 flies yaw-steered nadir pointing
    # (the body within 0.004 deg of the orbital frame whose Z is the geocentric down,
    # tests/viz/test_rerun_sentinel2.py); 0.01 deg allowed, where the geodetic vertical is 0.18 deg off
    w, x, y, z = np.asarray(sat.wxyz, float)
    R_enu_body = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    z_ecef = s2app.enu.R_ecef_enu @ R_enu_body[:, 2]
    down = -p[0] / np.linalg.norm(p[0])
    assert np.degrees(np.arccos(np.clip(z_ecef @ down, -1, 1))) < 0.01
    # the lines of sight run from the satellite to the ground: their far ends on WGS-84 (h = 0) by
    # PROJ, to 0.1 m (the segments are float32 km on the wire: 0.06 m at 800 km)
    to_geodetic = Transformer.from_crs(4978, 4979, always_xy=True)
    for n in ("first", "middle", "last"):
        seg = np.asarray(handle(s2app, f"/s2/los/{n}").points, float)[0]
        assert np.linalg.norm(ecef_of(s2app, seg[0]) - p[0]) < 0.1
        q = ecef_of(s2app, seg[1])
        _, _, h = to_geodetic.transform(*q)
        assert abs(h) < 0.1, (n, h)
    # the footprints of the two detectors: closed outlines on the ground, side by side and overlapping
    # across track by a few kilometres (Sentinel-2's staggered detectors)
    f6 = np.asarray(handle(s2app, "/s2/footprint/D06").points, float).reshape(-1, 3)
    f7 = np.asarray(handle(s2app, "/s2/footprint/D07").points, float).reshape(-1, 3)
    assert np.linalg.norm(f6[0] - f6[-1]) < 1e-3 and np.linalg.norm(f7[0] - f7[-1]) < 1e-3
    assert np.all(np.abs(f6[:, 2]) < 12.0)  # within the Earth's curvature of the patch: ground, not sky


def test_sentinel2_scene_follows_the_line_and_the_detector(s2app):
    """The line slider moves the satellite along its orbit and the lines of sight with it; line 1's
    first pixel's ground is the first point of the detector's footprint (both from the pipeline)."""
    import time

    before = np.asarray(handle(s2app, "/s2/satellite").position, float)
    s2app.sl_line.value = 1
    t0 = time.monotonic()
    while s2app.row != 1.0 and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    assert s2app.row == 1.0
    after = np.asarray(handle(s2app, "/s2/satellite").position, float)
    s = s2app.sensor
    dt = s.line_time(1.0) - s.line_time((s.rows + 1) // 2)
    _, v = s.orbit.state(np.array([s.line_time(1.0)]))
    # the satellite moved back by its speed times the time between the lines, to 0.1 % (the orbit's curvature)
    assert np.linalg.norm(after - before) / WORLD_SCALE == pytest.approx(abs(dt) * np.linalg.norm(v), rel=1e-3)
    first = np.asarray(handle(s2app, "/s2/los/first").points, float)[0][1]
    f6 = np.asarray(handle(s2app, "/s2/footprint/D06").points, float)[0][0]
    assert np.linalg.norm(first - f6) < 1e-4  # km: 0.1 m, float32 on the wire
    s2app.dd_detector.value = "07"
    t0 = time.monotonic()
    while s2app.detector != "07" and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    assert s2app.sensor.name.endswith("D07")
    s2app.dd_detector.value = "06"
    s2app.sl_line.value = (s.rows + 1) // 2


def test_view_of_a_product_folder_exports_its_scene(tmp_path):
    """``geoloc view --scenario PRODUCT --export s2.html``: the product folder is recognised as a
    Sentinel-2 scene and its static page names the band and detector shown."""
    from geoloc.cli import main

    out = tmp_path / "s2.html"
    assert main(["view", "--scenario", str(PRODUCT), "--s2-band", "B05", "--export", str(out)]) == 0
    text = out.read_text()
    assert "Sentinel-2 B05 D06" in text
