"""In-process scene tests: the viser nodes sit where the core (and PROJ) say.

Each test builds the app on a viser server bound to 127.0.0.1 on a free port
(port 0), with no browser, and inspects the scene nodes by name.
"""

import math

import numpy as np
import pyproj
import pytest
import viser.transforms as vtf

from geoloc.assets import asset_path
from geoloc.frames.chain import FrameChain, Pose
from geoloc.locate import line_of_sight
from geoloc.sensors.camera import Camera
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem
from geoloc_viz.app import GeolocApp, make_server
from geoloc_viz.scenario import load_view_scenario
from geoloc_viz.scene_geoloc import WORLD_SCALE

# The first record of the bundled flight test (T3-1), as in the CSV.
T31 = dict(
    lat=36.39895,
    lon=78.72927,
    h=17987.25,
    heading=30.0457,
    pitch=3.3903,
    roll=-0.0110,
    groll=-45.2273,
    gpitch=-2.4880,
    row=526,
    col=1550,
)


@pytest.fixture(scope="module")
def app():
    server = make_server(port=0)
    a = GeolocApp(server, load_view_scenario())
    yield a
    server.stop()


def node(app, name):
    name = "/enu" + name  # the scene root
    h = app.server.scene.get_handle_by_name(name)
    assert h is not None, f"scene node {name} missing"
    return h


def pos(app, name):
    """Node position in ENU metres (the scene's world unit is the km)."""
    return np.asarray(node(app, name).position, float) / WORLD_SCALE


def pyproj_enu(app, lat_deg, lon_deg, h):
    """ENU of a geodetic point by PROJ (EPSG:4979 -> 4978, then +proj=topocentric)."""
    enu = app.scn.enu
    geo = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x0, y0, z0 = geo.transform(math.degrees(enu.lon0), math.degrees(enu.lat0), enu.h0)
    x, y, z = geo.transform(lon_deg, lat_deg, h)
    topo = pyproj.Transformer.from_pipeline(f"+proj=topocentric +ellps=WGS84 +X_0={x0!r} +Y_0={y0!r} +Z_0={z0!r}")
    return np.array(topo.transform(x, y, z))


def core_t31():
    pose = Pose.from_deg(
        T31["lat"], T31["lon"], T31["h"], T31["heading"], T31["pitch"], T31["roll"], T31["groll"], T31["gpitch"]
    )
    cam = Camera.from_toml(asset_path("cameras", "qiao2017.toml"))
    return pose, cam, line_of_sight(pose, cam, T31["row"], T31["col"])


def test_default_scene_has_every_element(app):
    names = {n.removeprefix("/enu") for n in app.server.scene._handle_from_node_name}
    for n in [
        "/terrain",
        "/aircraft",
        "/aircraft/mesh",
        "/los",
        "/frustum",
        "/hit/result",
        "/hit/hmax",
        "/hit/exact",
        "/iterations/points",
        "/iterations/verticals",
        "/iterations/brackets",
        "/iterations/current",
        "/record/published",
        "/record/surveyed",
        "/record/error",
        "/origin",
        "/scale_bar",
    ] + [f"/frames/{f}" for f in ("ned", "body", "gimbal_outer", "cam")]:
        assert n in names, n
    assert app.error == ""


def test_frame_labels_show_in_the_teaching_view_only(app):
    """[Q17]'s 20 records are a flight: its first view has no frame name labels at the aircraft (seven
    of them covered the flight); the teaching panel's row shown brings them, hiding it removes them."""
    frames = ("ned", "body", "gimbal_outer", "cam")
    scene = app.server.scene

    def labels():
        return {f for f in frames if scene.get_handle_by_name(f"/enu/frames/{f}/label") is not None}

    tp = next(x for x in app.layers if hasattr(x, "flight_view"))  # the teaching panel
    assert tp.flight_view and not tp.cb_show.value
    assert labels() == set()
    tp.cb_show.value = True
    assert labels() == set(frames)
    assert scene.get_handle_by_name("/enu/frames/cam/label").text == "camera: Z = line of sight"
    tp.cb_show.value = False
    assert labels() == set()
    # the origin's axes say what they are: the scene's ENU origin (at the scene's (0, 0, 0), which the
    # summary places), which colour is which axis
    lab = scene.get_handle_by_name("/enu/origin/label")
    assert lab.visible and lab.text == "ENU origin: E red, N green, U blue"
    assert np.allclose(scene.get_handle_by_name("/enu/origin").position, 0.0)
    assert "scene: local East-North-Up, origin " in app.md_summary.content


def test_hit_marker_at_the_terrain_hit_in_pyproj_enu(app):
    pose, cam, los = core_t31()
    dem = DEM.open(asset_path("dem", "etopo5_flight_area.tif"), datum="egm96")
    hit = intersect_dem(los, dem, "bisect", eps_h=20.0, threshold=1.0)
    expected = pyproj_enu(app, float(hit.lat_deg), float(hit.lon_deg), float(hit.h))
    # 1e-3 m: float64 positions on the wire (in km: 1e-3 scaling costs ~1e-12 relative);
    # PROJ and our ENU agree to 1e-6 m (test_enu).
    np.testing.assert_allclose(pos(app, "/hit/result"), expected, atol=1e-3)
    exact = intersect_dem(los, dem, "exact")
    np.testing.assert_allclose(
        pos(app, "/hit/exact"), pyproj_enu(app, float(exact.lat_deg), float(exact.lon_deg), float(exact.h)), atol=1e-3
    )
    # The aircraft node sits at the POS position of the record.
    np.testing.assert_allclose(pos(app, "/aircraft"), pyproj_enu(app, T31["lat"], T31["lon"], T31["h"]), atol=1e-3)
    # The line of sight runs from the aircraft to the hit (float32 vertices: ~2 mm at 20 km).
    seg = (np.asarray(node(app, "/los").points, float) / WORLD_SCALE)[0]
    np.testing.assert_allclose(seg[0], pos(app, "/aircraft"), atol=0.01)
    np.testing.assert_allclose(seg[1], expected, atol=0.01)


def test_frames_orientation_closed_form(app):
    R = {
        f: vtf.SO3(np.asarray(node(app, f"/frames/{f}").wxyz)).as_matrix()
        for f in ("ned", "body", "gimbal_outer", "cam")
    }
    # NED at the aircraft vs ENU at the origin ~16 km away: axes differ by the
    # angle between the two normals, 16 km / 6371 km = 2.5e-3 rad.
    np.testing.assert_allclose(R["ned"], [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=4e-3)
    # Body X (nose): azimuth = heading 30.0457 deg, elevation = pitch 3.3903 deg.
    x = R["body"][:, 0]
    assert math.degrees(math.atan2(x[0], x[1])) == pytest.approx(T31["heading"], abs=0.3)
    assert math.degrees(math.asin(x[2])) == pytest.approx(T31["pitch"], abs=0.3)
    # Outer gimbal shares body X ([Q17 eq. 7]: roll about X); its Y is turned by the gimbal roll.
    np.testing.assert_allclose(R["gimbal_outer"][:, 0], x, atol=1e-9)
    cosang = R["gimbal_outer"][:, 1] @ R["body"][:, 1]
    assert math.degrees(math.acos(cosang)) == pytest.approx(abs(T31["groll"]), abs=1e-6)
    # gimbal roll -45 deg looks right of track (conventions.md): camera Z has a
    # positive component on the body's right wing.
    assert R["cam"][:, 2] @ R["body"][:, 1] > 0.6


def test_step_slider_walks_the_core_trace(app):
    pose, cam, los = core_t31()
    dem = app.scn.dem
    hit = intersect_dem(los, dem, "bisect", threshold=1.0, trace=True)
    tr = hit.trace.ray()
    app.cb_all_steps.value = False
    try:
        kept = None
        for k in (0, 2, len(tr["H"]) - 1):
            app.sl_step.value = k
            # another count of iterations updates the nodes' arrays: the browser keeps the nodes
            now = [node(app, f"/iterations/{n}") for n in ("points", "verticals", "brackets")]
            assert kept is None or all(a is b for a, b in zip(now, kept))
            kept = now
            np.testing.assert_allclose(pos(app, "/iterations/current"), app.scn.enu.from_ecef(tr["ecef"][k]), atol=1e-6)
            pts = np.asarray(node(app, "/iterations/points").points)
            assert len(pts) == k + 1
            # Vertical segment from H_n on the line of sight down (or up) to the DEM height h_n.
            v = (np.asarray(node(app, "/iterations/verticals").points, float) / WORLD_SCALE)[k]
            up = app.scn.enu.from_geodetic(tr["lat"][k], tr["lon"][k], tr["h_dem"][k])
            np.testing.assert_allclose(v[1], up, atol=0.01)
            above = tr["H"][k] - tr["h_dem"][k] > 0
            col = np.asarray(node(app, "/iterations/verticals").colors)[k, 0]
            assert (col[2] > col[0]) == above  # blue above the terrain, red below
    finally:
        app.cb_all_steps.value = True


def test_vertical_exaggeration_scales_up_only(app):
    before = np.array(pos(app, "/hit/result"))
    app.sl_vexag.value = 3.0
    try:
        after = np.array(pos(app, "/hit/result"))
        np.testing.assert_allclose(after, before * [1, 1, 3], rtol=1e-12)
        assert node(app, "/terrain").scale == pytest.approx((1e-3, 1e-3, 3e-3))
    finally:
        app.sl_vexag.value = 1.0


def test_gui_pose_change_moves_the_line_of_sight(app):
    old = np.array(pos(app, "/hit/result"))
    app.num["gimbal_roll_deg"].value = -40.0
    try:
        assert app.dd_record.value == "(custom pose)"
        pose = Pose.from_deg(
            T31["lat"], T31["lon"], T31["h"], T31["heading"], T31["pitch"], T31["roll"], -40.0, T31["gpitch"]
        )
        cam = Camera.from_toml(asset_path("cameras", "qiao2017.toml"))
        hit = intersect_dem(line_of_sight(pose, cam, T31["row"], T31["col"]), app.scn.dem, "bisect")
        new = np.array(pos(app, "/hit/result"))
        np.testing.assert_allclose(new, app.scn.enu.from_ecef(hit.ecef), atol=1e-6)
        assert np.linalg.norm(new - old) > 1000.0  # 5 deg at ~18 km slant range: km-scale shift
    finally:
        app.dd_record.value = app.record_option("T4-1")
        app.dd_record.value = app.record_option("T3-1")


def test_teaching_panel_shows_the_core_matrices_and_highlights(app):
    pose, cam, _ = core_t31()
    chain = cam.to_sensor().frames(pose)
    # the sensor's graph walks the [Q17] chain: its frames sit where FrameChain (eq. 4-9) puts them
    # (the optical "cam" frame is S turned 90 deg about the line of sight, conventions.md)
    q17 = FrameChain(pose)
    for f in ("ned", "body", "gimbal_outer"):
        np.testing.assert_allclose(chain.T_ecef(f), q17.T_ecef(f), rtol=0, atol=1e-6)
    np.testing.assert_allclose(chain.T_ecef("cam")[:3, 2], q17.T_ecef("cam")[:3, 2], atol=1e-15)
    assert [h.name for h in chain.hops] == [
        "T_ecef_ned",
        "T_ned_body",
        "T_body_gimbal_base",
        "T_gimbal_base_gimbal_outer",
        "T_gimbal_outer_gimbal_inner",
        "T_gimbal_inner_cam",
    ]
    # the teaching view (the teaching panel's row shown): the frames carry their name labels
    next(x for x in app.layers if hasattr(x, "flight_view")).cb_show.value = True
    for hop in chain.hops:
        app.dd_hop.value = hop.name
        text = app.md_hop.content
        # Every entry of the core's matrix appears, formatted as shown.
        for r in range(3):
            assert f"{hop.T[r, 3]: .3f}" in text
            for c in range(3):
                assert f"{hop.T[r, c]: .6f}" in text
        # Selecting T_dst_src highlights the frame it maps from (thicker axes, marked label).
        assert node(app, f"/frames/{hop.src}/label").text.startswith("> ")
        assert node(app, f"/frames/{hop.src}").axes_radius == pytest.approx(
            0.05 * node(app, f"/frames/{hop.src}").axes_length
        )
        # [Q17] eq. 5's four factors are shown under T_ecef_ned and under no other hop
        assert ("max |difference|" in app.md_q17.content) == (hop.name == "T_ecef_ned")
    app.dd_hop.value = "T_ecef_ned"
    diff = float(app.md_q17.content.split("max |difference| = ")[1].split()[0])
    assert diff < 1e-6  # [Q17 eq. 5] four factors = direct form (float64 at 6.4e6 m)
    app.dd_hop.value = "(none)"


def test_record_dropdown_loads_published_and_surveyed(app):
    app.dd_record.value = app.record_option("T4-3")
    try:
        # T4-3 in the CSV: published 35.59935 N 80.85938 E at paper_height 4799.9 m.
        np.testing.assert_allclose(
            pos(app, "/record/published"), pyproj_enu(app, 35.59935, 80.85938, 4799.9), atol=1e-3
        )
        assert app.inputs.gimbal_roll_deg == pytest.approx(51.9420)
        assert "T4-3" in app.md_summary.content
        # The ENU origin moved near the new target (float32 safety): within 1 km.
        assert np.linalg.norm(pos(app, "/hit/result")[:2]) < 2000.0
    finally:
        app.dd_record.value = app.record_option("T3-1")


def _decode_recording(raw: bytes):
    """A viser recording: an 8-byte size, zstd, then an 8-byte length and msgpack (the .viser file,
    and the base64 payload of an HTML export)."""
    import msgspec.msgpack
    import zstandard

    inner = zstandard.ZstdDecompressor().decompress(raw[8:], max_output_size=int.from_bytes(raw[:8], "little"))
    n = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8 : 8 + n])


def test_export_writes_static_recordings(app, tmp_path):
    # both exports read back message by message: every node the live scene placed is in the
    # recording, at the live handle's last position (and so at the core's, tested above)
    import base64
    import re

    p = app.export(tmp_path / "scene.viser")
    h = app.export(tmp_path / "scene.html", animate_steps=False)
    html = h.read_text()
    assert html.lstrip().lower().startswith("<!doctype html")
    b64 = re.search(r'window\.__VISER_EMBED_DATA__="([^"]*)"', html).group(1)
    for rec in (_decode_recording(p.read_bytes()), _decode_recording(base64.b64decode(b64))):
        last = {}
        for _, m in rec["messages"]:
            if m.get("type") == "SetPositionMessage":
                last[m["name"]] = np.asarray(m["position"], float)
        names = ["/enu/aircraft", "/enu/hit/result", "/enu/frames/body", "/enu/frames/cam", "/enu/frames/ned"]
        for name in names:
            live = np.asarray(node(app, name[4:]).position, float)
            # the recording keeps viser's float64 positions exactly
            np.testing.assert_array_equal(last[name], live, err_msg=name)
        kinds = {m.get("type") for _, m in rec["messages"]}
        assert {"GlbMessage", "IcosphereMessage", "FrameMessage", "LineSegmentsMessage"} <= kinds


def test_labels_say_3d_or_horizontal_and_the_drawing_factor(app):
    # before: the 3D label and the panel's horizontal figure were both unlabelled
    import re

    geod = pyproj.Geod(ellps="WGS84")
    ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    info = app.scn.records[app.scn.record_index][0]
    hit = app.geometry.hit
    lat, lon, h = float(hit.lat_deg), float(hit.lon_deg), float(hit.h)
    text = node(app, "/record/error/label").text
    m = re.fullmatch(r"error vector \(3D, true length\): ([\d.]+) m", text)
    assert m, text
    e3 = float(m.group(1))
    # the surveyed point sits on the DEM (the records give no truth height): the DEM's
    # ellipsoidal height there (geoloc.surfaces.dem, checked against rasterio in its own tests)
    h_truth = float(app.scn.dem.height(math.radians(info.truth_lat_deg), math.radians(info.truth_lon_deg)))
    d3 = np.linalg.norm(
        np.subtract(ecef.transform(lon, lat, h), ecef.transform(info.truth_lon_deg, info.truth_lat_deg, h_truth))
    )
    assert e3 == pytest.approx(d3, abs=0.051)  # PROJ's ECEF chord; the label rounds to 0.1 m
    horiz = geod.inv(lon, lat, info.truth_lon_deg, info.truth_lat_deg)[2]
    summary = app.md_summary.content
    m2 = re.search(r"to surveyed: ([\d.]+) m \(horizontal\)", summary)
    assert m2 and float(m2.group(1)) == pytest.approx(horiz, abs=0.06)  # pyproj's geodesic
    # 3D = horizontal and vertical together (closed form over ~0.5 km): the geodesic is on the
    # ellipsoid, the points ~4.6 km above it, where the same angle spans (1 + h/R) more metres
    # (0.35 m here; R's choice between the meridian and normal radii: 3 mm); the normals tilt
    # by 8e-5 rad over the distance, a few mm of the 70 m height difference
    h_mean = 0.5 * (h + h_truth)
    assert e3 == pytest.approx(math.hypot(horiz * (1 + h_mean / 6.371e6), h - h_truth), abs=0.1)
    assert f"error vector to surveyed (3D, surveyed point on the terrain): {e3:.1f} m, true length" in summary
    # drawn at true length: the node's vector is the surveyed point minus the hit (float32 km: < 0.1 m)
    seg = np.asarray(node(app, "/record/error").points, float)[0] / WORLD_SCALE
    assert seg[1] - seg[0] == pytest.approx(app.geometry.surveyed_enu - app.geometry.hit_enu, abs=0.1)
    app.sl_err.value = 10.0
    try:
        assert node(app, "/record/error/label").text == f"error vector (3D, drawn x10): {e3:.1f} m"
        assert f"{e3:.1f} m, drawn x10" in app.md_summary.content
    finally:
        app.sl_err.value = 1.0
    # the aircraft's display scale, next to it and in the panel
    assert node(app, "/aircraft/label").text == "aircraft drawn x200"
    assert "aircraft drawn x200 (display only)" in summary
    app.sl_ac.value = 50.0
    try:
        assert node(app, "/aircraft/label").text == "aircraft drawn x50"
        assert "aircraft drawn x50" in app.md_summary.content
        assert node(app, "/aircraft/mesh").scale == pytest.approx(50.0 * WORLD_SCALE)
    finally:
        app.sl_ac.value = 200.0


def test_header_says_custom_pose_after_an_edit(app):
    # before: the header kept the old record's name after an edit
    assert app.md_summary.content.startswith("**qiao2017_flight_tests.csv: frame 0 (T3-1)**")
    app.num["h_m"].value = app.inputs.h_m + 100.0
    try:
        head = app.md_summary.content.splitlines()[0]
        assert head == "**qiao2017_flight_tests.csv: custom pose (edited from frame 0 (T3-1))**  "
        assert "to surveyed" not in app.md_summary.content  # no record's truth for a custom pose
    finally:
        app.dd_record.value = app.record_option("T4-1")
        app.dd_record.value = app.record_option("T3-1")
    assert app.md_summary.content.startswith("**qiao2017_flight_tests.csv: frame 0 (T3-1)**")


def test_export_html_carries_record_method_and_errors(app, tmp_path):
    import re

    page = app.export(tmp_path / "s.html", animate_steps=False).read_text()
    panel = re.search(r'<div id="geoloc-summary"[^>]*>(.*?)</div>', page, re.S).group(1)
    for text in (
        "qiao2017_flight_tests.csv: frame 0 (T3-1)",
        "method: bisection [L23], threshold 1 m",
        "to surveyed:",
        "(horizontal)",
        "error vector to surveyed (3D",
        "true length",
        "aircraft drawn x200",
    ):
        assert text in panel, text


def test_bad_input_is_reported_not_raised(app):
    app.num["h_m"].value = 1.0e9  # out of the Pose range
    try:
        assert "h = 1e+09 m" in app.error
        assert "input error" in app.md_summary.content
    finally:
        app.dd_record.value = app.record_option("T4-1")
        app.dd_record.value = app.record_option("T3-1")
    assert app.error == ""


def test_viewer_line_of_sight_keeps_the_camera_mount_and_boresight():
    # A camera with a mount and a boresight: the scene's line of sight and hit must be the
    # core's (line_of_sight applies both). The first-phase viewer built FrameChain(pose)
    # and dropped them: with mount_deg = [0, 0.22, 0] its hit landed 51 m away.
    import dataclasses

    from geoloc.surfaces.height import intersect_los_height
    from geoloc_viz import model

    scn = load_view_scenario()
    cam = dataclasses.replace(
        scn.camera, mount=(0.0, math.radians(0.22), 0.0), boresight=(math.radians(0.05), 0.0, math.radians(-0.1))
    )
    scn = dataclasses.replace(scn, camera=cam, dem=None)
    inp = scn.inputs.replace(target_h=4600.0)
    g = model.compute(scn, inp)
    pose = inp.pose()
    los = line_of_sight(pose, cam, inp.row, inp.col)
    want = intersect_los_height(los, 4600.0)
    d_enu = scn.enu.vector_from_ecef(los.direction_ecef)
    # 1e-12: the same float64 operations in another order; a dropped 0.22 deg mount is 4e-3
    np.testing.assert_allclose(g.los_dir_enu, d_enu, atol=1e-12)
    # 1 mm at 18 km slant: float64 rounding only (the bug was 51 m)
    np.testing.assert_allclose(g.hit_enu, scn.enu.from_ecef(want.ecef), atol=1e-3)


RIG_ANGLES = {
    "roll-pitch": {"gimbal_roll_deg": -30.0, "gimbal_pitch_deg": 4.0},
    "azimuth-elevation": {"angles_deg": {"azimuth": 70.0, "elevation": -40.0}},
    "azimuth-elevation-roll": {"angles_deg": {"azimuth": 250.0, "elevation": -35.0, "sensor_roll": 12.0}},
    "yaw-pitch-roll": {"angles_deg": {"gimbal_yaw": 40.0}, "gimbal_pitch_deg": -70.0, "gimbal_roll_deg": 2.0},
}


@pytest.mark.parametrize("preset", list(RIG_ANGLES))
def test_viewer_and_rerun_lines_of_sight_equal_the_core_for_every_preset(preset, tmp_path):
    # mount, boresight, lever arm and a distorted lens set: the scene's and the rerun
    # recording's lines of sight are the core's, and the drawn frames are the sensor's graph
    import dataclasses

    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import PRESETS
    from geoloc.sensors.lenses import BrownLens
    from geoloc_viz import model
    from geoloc_viz.rerun_model import steps_from_records

    lens = BrownLens(
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
    mount = (0.0, 0.0, 0.0) if PRESETS[preset].earth_referenced else (2e-3, -1e-3, 4e-3)
    s = FrameSensor(lens, PRESETS[preset], mount=mount, boresight=(1e-3, 2e-3, -3e-3), lever_arm_m=(1.5, 0.2, 0.7))
    scn = load_view_scenario()
    scn = dataclasses.replace(scn, camera=s, dem=None)
    inp = scn.inputs.replace(h_m=3000.0, row=200.0, col=1500.0, target_h=500.0, **RIG_ANGLES[preset])
    g = model.compute(scn, inp)
    pose = inp.pose()
    los = line_of_sight(pose, s, inp.row, inp.col)
    np.testing.assert_allclose(g.los_dir_enu, scn.enu.vector_from_ecef(los.direction_ecef), atol=1e-12)
    np.testing.assert_allclose(g.aircraft_enu, scn.enu.from_ecef(los.origin_ecef), atol=1e-6)
    assert tuple(g.frames) == s.graph.frames[1:]
    # rerun: a records file with this sensor's angle columns, replayed into a recording
    cols = {
        "gimbal_roll_deg": inp.gimbal_roll_deg,
        "gimbal_pitch_deg": inp.gimbal_pitch_deg,
        **{f"{k}_deg": v for k, v in inp.angles_deg.items()},
    }
    names = ["row", "col", "ac_lat_deg", "ac_lon_deg", "ac_h_m", "heading_deg", "pitch_deg", "roll_deg", *cols]
    vals = [
        inp.row,
        inp.col,
        inp.lat_deg,
        inp.lon_deg,
        inp.h_m,
        inp.heading_deg,
        inp.pitch_deg,
        inp.roll_deg,
        *cols.values(),
    ]
    f = tmp_path / "rec.csv"
    f.write_text(",".join(names) + "\n" + ",".join(repr(float(v)) for v in vals) + "\n")
    steps, _ = steps_from_records(f, s, target_h_m=500.0)
    np.testing.assert_allclose(steps.los.direction_ecef[0], los.direction_ecef, atol=1e-15)
    np.testing.assert_allclose(steps.los.origin_ecef[0], los.origin_ecef, atol=1e-9)
    paths = steps.entity_paths()
    assert set(paths) == set(s.graph.frames[1:]) and paths["cam"].endswith("/cam")


def test_viewer_flags_a_pixel_outside_the_sensor():
    # before: row 99999 on a 2323-row sensor said "ok"; now the scene says so and why
    import dataclasses

    from geoloc.status import Status
    from geoloc_viz import model

    scn = dataclasses.replace(load_view_scenario(), dem=None)
    g = model.compute(scn, scn.inputs.replace(row=99999.0, target_h=4600.0))
    assert g.status == Status.OUTSIDE_SENSOR
    assert "pixel outside the sensor" in g.message and "rows 1-2323" in g.message
    inside = model.compute(scn, scn.inputs.replace(target_h=4600.0))
    assert inside.status == Status.OK and "outside" not in inside.message


def test_viewer_opens_a_misb_klv_flight():
    # `geoloc view --records FILE.klv`: one record per packet, the packet's frame centre as the
    # published point; the example flight's centres were computed on the same SRTM crop, so the
    # scene's exact hit lands on them (5 mm: the reported centre's quantisation in tags 23-24)
    from geoloc.geodesy.geodesic import horizontal_distance_m
    from geoloc_viz import model

    scn = load_view_scenario(asset_path("klv", "example_flight.klv"), "packet 12")
    assert len(scn.records) == 298 and scn.camera.gimbal.name == "azimuth-elevation-roll"
    g = model.compute(scn, scn.inputs.replace(method="exact"))
    info = scn.records[scn.record_index][0]
    d = float(horizontal_distance_m(g.hit.lat_deg, g.hit.lon_deg, info.paper_lat_deg, info.paper_lon_deg))
    assert g.status == 0 and d < 0.01


def test_hillshade_lambert_on_planes_closed_form():
    """A plane of slope angle a facing azimuth b under the sun (azimuth 315, elevation 45 deg):
    brightness 0.45 + 0.55 cos(angle to the sun) / sin(45 deg) (Lambert's cosine law), flat ground 1."""
    from geoloc_viz.terrain_link import hillshade

    x, y = np.meshgrid(np.arange(5.0) * 100.0, np.arange(5.0) * 100.0)
    i = np.arange(25).reshape(5, 5)
    faces = np.concatenate(
        [
            np.stack([i[:-1, :-1], i[:-1, 1:], i[1:, 1:]], -1).reshape(-1, 3),
            np.stack([i[:-1, :-1], i[1:, 1:], i[1:, :-1]], -1).reshape(-1, 3),
        ]
    )
    el, az_sun = math.radians(45.0), math.radians(315.0)
    sun = np.array([math.sin(az_sun) * math.cos(el), math.cos(az_sun) * math.cos(el), math.sin(el)])
    # level; towards the sun (brighter); away (darker); across; steep away (in shadow: 0.45)
    for slope_deg, facing_deg in ((0.0, 0.0), (20.0, 315.0), (20.0, 135.0), (30.0, 90.0), (60.0, 135.0)):
        a, b = math.radians(slope_deg), math.radians(facing_deg)
        # height falls towards the facing azimuth: z = -tan(a) (x sin b + y cos b)
        z = -math.tan(a) * (x * math.sin(b) + y * math.cos(b))
        v = np.stack([x.ravel(), y.ravel(), z.ravel()], -1)
        n = np.array([math.sin(a) * math.sin(b), math.sin(a) * math.cos(b), math.cos(a)])
        want = float(np.clip(0.45 + 0.55 * max(n @ sun, 0.0) / math.sin(el), 0.3, 1.3))
        # either winding of the faces: normals are turned Up
        for f in (faces, faces[:, ::-1]):
            got = hillshade(v, f)
            assert np.allclose(got, want, atol=1e-12), (slope_deg, facing_deg, got[:3], want)


def test_terrain_is_sent_unlit_with_the_mesh_unchanged(app):
    """The terrain node's GLB, read back by trimesh (an independent glTF reader), holds the same
    vertices and faces as the mesh, and its one material is KHR_materials_unlit (the glTF 2.0
    extension three.js draws as a MeshBasicMaterial)."""
    import io
    import json
    import struct

    import trimesh

    from geoloc_viz.scene_geoloc import terrain_glb_cached, terrain_mesh_cached

    scn = app.scn
    glb, mesh = terrain_glb_cached(scn), terrain_mesh_cached(scn)
    h = app.server.scene.get_handle_by_name("/enu/terrain")
    assert h is not None and h.glb_data == glb
    (jlen,) = struct.unpack_from("<I", glb, 12)
    assert struct.unpack_from("<I", glb, 8)[0] == len(glb)
    doc = json.loads(glb[20 : 20 + jlen])
    assert "KHR_materials_unlit" in doc["extensionsUsed"]
    assert [m["extensions"] for m in doc["materials"]] == [{"KHR_materials_unlit": {}}]
    back = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    assert np.array_equal(np.asarray(back.faces), np.asarray(mesh.faces))
    assert np.allclose(back.vertices, mesh.vertices, atol=0.0, rtol=1e-6)  # float32 in the file
    # the colours (trimesh drops COLOR_0 once a material is set): the accessor read by hand (glTF 2.0
    # 3.6: a buffer view into the binary chunk, which starts after the JSON chunk's 8-byte header)
    prim = doc["meshes"][0]["primitives"][0]
    acc = doc["accessors"][prim["attributes"]["COLOR_0"]]
    view = doc["bufferViews"][acc["bufferView"]]
    assert acc["componentType"] == 5121 and acc["type"] == "VEC4"  # unsigned bytes, RGBA
    start = 20 + jlen + 8 + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    rgba = np.frombuffer(glb, np.uint8, acc["count"] * 4, start).reshape(-1, 4)
    # linear in the file (glTF 2.0 3.7.2.1), the mesh's sRGB colours through IEC 61966-2-1's curve
    srgb = mesh.visual.vertex_colors[:, :3] / 255.0
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4) * 255.0
    assert np.abs(rgba[:, :3] - lin).max() <= 0.5 + 1e-9  # rounded to 8 bits
    assert np.array_equal(rgba[:, 3], mesh.visual.vertex_colors[:, 3])


def test_unlit_glb_keeps_a_texture_white_and_bilinear():
    """A textured mesh (``bench_frame.py --pair terrain-textured``): the glTF, read back by trimesh
    and by hand, holds the image as a JPEG (to a few levels), a white base colour (the
    texture's colours unchanged) and one sampler, LINEAR both ways (9729, glTF 2.0 5.26: no
    mipmaps read in software WebGL), the material unlit."""
    import io
    import json
    import struct

    import PIL.Image
    import trimesh

    from geoloc_viz.scene_geoloc import unlit_glb

    y, x = np.mgrid[0:16, 0:16] * 16
    rgb = np.stack([x, y, 255 - x], axis=-1).astype(np.uint8)  # smooth: JPEG keeps it to a few levels
    buf = io.BytesIO()
    PIL.Image.fromarray(rgb).save(buf, format="JPEG", quality=90)
    jpeg = buf.getvalue()
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    mesh = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=v[:, :2], image=PIL.Image.open(io.BytesIO(jpeg)))
    glb = unlit_glb(mesh)
    (jlen,) = struct.unpack_from("<I", glb, 12)
    assert struct.unpack_from("<I", glb, 8)[0] == len(glb)
    doc = json.loads(glb[20 : 20 + jlen])
    (mat,) = doc["materials"]
    assert mat["extensions"] == {"KHR_materials_unlit": {}}
    assert mat["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    assert doc["samplers"] == [{"magFilter": 9729, "minFilter": 9729}]
    assert all(t["sampler"] == 0 for t in doc["textures"])
    (img,) = doc["images"]
    view = doc["bufferViews"][img["bufferView"]]
    start = 20 + jlen + 8 + view.get("byteOffset", 0)
    assert img["mimeType"] == "image/jpeg"
    # trimesh writes the image again (one more JPEG encoding: a few levels on this smooth image)
    back_rgb = np.asarray(PIL.Image.open(io.BytesIO(glb[start : start + view["byteLength"]])).convert("RGB"), float)
    assert back_rgb.shape == rgb.shape and np.abs(back_rgb - rgb).mean() < 4.0
    back = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    assert np.allclose(back.vertices, v) and np.allclose(back.visual.uv, v[:, :2])


def test_terrain_mesh_level_of_detail_and_its_height_bound():
    """The drawn terrain, a level of detail: its nodes spaced as 1 + d / MESH_LOD_M at a
    distance d from the scene origin, its vertices on the DEM's surface at their nodes, and
    mesh_height_bound an upper bound of the drawn surface: checked by trimesh's ray casts (an
    outside oracle) straight down onto the mesh at 2000 random points of the example flight."""
    import trimesh

    from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
    from geoloc_viz import terrain_link as tl
    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    lats, lons = tl.mesh_grid(scn)
    n = tl.MESH_NODES
    assert lats.shape == lons.shape == (n,) and np.all(np.diff(lats) < 0) and np.all(np.diff(lons) > 0)
    w, s, e, nn = scn.dem.bounds_deg
    assert (lats[0], lats[-1], lons[0], lons[-1]) == (
        min(nn, lats[0]),
        max(s, lats[-1]),
        max(w, lons[0]),
        min(e, lons[-1]),
    )
    # the spacing at each gap against the rule, from the gap's mid-point's distance to the origin:
    # equal steps of F (r0 ln(1 + d / r0)) give dx = dF (1 + d / r0) to first order in the step
    lat0 = np.degrees(scn.enu.lat0)
    d_m = np.radians(np.abs(0.5 * (lats[1:] + lats[:-1]) - lat0)) * 6.36e6
    dx = np.radians(-np.diff(lats)) * 6.36e6
    ratio = dx / (1 + d_m / tl.MESH_LOD_M)
    assert ratio.max() / ratio.min() < 1.05  # the second-order term: under 5 % at these steps
    assert dx.max() > 3 * dx.min()  # coarse at the edge, fine at the origin
    mesh = tl.terrain_mesh(scn)
    assert len(mesh.vertices) == n * n and len(mesh.faces) == 2 * (n - 1) ** 2  # the crop has no holes
    LON, LAT = np.meshgrid(lons, lats)
    la, lo, h = ecef_to_geodetic(scn.enu.to_ecef(mesh.vertices))
    assert np.allclose(h, scn.dem.height(np.radians(LAT), np.radians(LON)).ravel(), atol=1e-6)
    assert np.allclose(np.degrees(la), LAT.ravel(), atol=1e-9) and np.allclose(np.degrees(lo), LON.ravel(), atol=1e-9)
    # trimesh's ray casts down the local vertical onto the mesh, at random points in it
    rng = np.random.default_rng(4)
    pla = rng.uniform(lats[-1], lats[0], 2000)
    plo = rng.uniform(lons[0], lons[-1], 2000)
    top = scn.enu.from_ecef(geodetic_to_ecef(np.radians(pla), np.radians(plo), np.full(2000, 3000.0)))
    bot = scn.enu.from_ecef(geodetic_to_ecef(np.radians(pla), np.radians(plo), np.full(2000, 0.0)))
    d = (bot - top) / np.linalg.norm(bot - top, axis=1, keepdims=True)
    loc, ray, _ = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_location(top, d, multiple_hits=False)
    assert len(ray) > 1990  # every ray meets the mesh (a few may slip between two triangles' edges)
    _, _, h_mesh = ecef_to_geodetic(scn.enu.to_ecef(loc))
    bound = tl.mesh_height_bound(scn, pla[ray], plo[ray])
    # 1 mm: the ray cast's float64 round trip through ENU and ECEF, far under any relief
    assert np.all(np.isfinite(bound)) and np.all(h_mesh <= bound + 1e-3), (h_mesh - bound).max()
