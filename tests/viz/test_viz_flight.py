"""The viewer as a whole-flight debugger: geoloc_viz.flight_model / flight_layer.

Oracles from outside the code:

* footprint corners on the ellipsoid: pymap3d ``lookAtSpheroid`` (its own closed-form ray /
  ellipsoid intersection at h = 0) along corner directions built here by hand in NED from the
  turret's azimuth and elevation and the fields of view (``docs/conventions.md``, "Gimbal
  presets"), not through geoloc's frame graph;
* outlier ordering: the 22 packets the KLV replay flags (``geoloc.workflows.klv_replay``, whose own
  test holds them to the faults planted by ``tools/make_klv_example.py``) come first, and the
  fitted faults give back the planted sizes (2.5 deg of heading, N of height, 1 frame of staleness);
* browser tests (headless Chromium, the launcher and viewer helpers of ``tests/viz/test_viz_browser.py``):
  scrubbing the timeline moves the magenta footprint on the canvas (pixel statistics of the
  browser's render), choosing an outlier moves the browser's camera (positions the browser reports).
"""

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_viz_browser import served

from geoloc.frames.enu import EnuFrame
from geoloc_viz.model import frame_name
from geoloc_viz.palette import PALETTE
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import lens_from_fov
from geoloc_viz import flight_model
from geoloc_viz.model import Inputs, RecordInfo, Scenario

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ footprints against pymap3d
def _turret_scenario(n=6, seed=3):
    rng = np.random.default_rng(seed)
    hfov, vfov = math.radians(20.0), math.radians(11.25)
    sensor = FrameSensor(lens_from_fov(hfov, vfov, 1920, 1080), PRESETS["azimuth-elevation-roll"])
    recs = []
    for k in range(n):
        inp = Inputs(
            36.5 + 0.01 * k,
            -84.2 + 0.013 * k,
            float(rng.uniform(2000, 6000)),
            float(rng.uniform(-180, 180)),
            0.0,
            0.0,
            0.0,
            0.0,
            540.5,
            960.5,
            target_h=0.0,
            angles_deg={
                "azimuth": float(rng.uniform(0, 360)),
                "elevation": float(rng.uniform(-80, -30)),
                "sensor_roll": 0.0,
            },
        )
        recs.append((RecordInfo(f"f{k}"), inp))
    scn = Scenario(
        "synthetic",
        sensor,
        recs[0][1],
        EnuFrame.from_deg(36.5, -84.2, 0.0),
        records=recs,
        record_index=0,
        dem=None,
        use_dem=False,
    )
    return scn, hfov, vfov


def _corner_dirs_ned(heading, az, el, hfov, vfov):
    """Corner directions in NED for level flight, by hand: LOS X at azimuth heading + az and elevation el,
    image right Y horizontal, image down Z = X x Y; corners (-+tan(h/2), -+tan(v/2), 1) in (right, down, LOS)."""
    A = heading + az
    X = np.array([math.cos(el) * math.cos(A), math.cos(el) * math.sin(A), -math.sin(el)])
    Y = np.array([-math.sin(A), math.cos(A), 0.0])
    Z = np.cross(X, Y)
    tx, ty = math.tan(hfov / 2), math.tan(vfov / 2)
    out = []
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):  # top-left, top-right, bottom-right, bottom-left
        d = X + sx * tx * Y + sy * ty * Z
        out.append(d / np.linalg.norm(d))
    return np.array(out)


def test_footprint_corners_equal_pymap3d_look_at_spheroid():
    from pymap3d.los import lookAtSpheroid

    scn, hfov, vfov = _turret_scenario()
    m = flight_model.build(scn, diagnose_faults=False)
    assert m.reference == "reported" and m.footprint_enu.shape == (6, 4 * flight_model.EDGE_SAMPLES, 3)
    for k, (_, inp) in enumerate(scn.records):
        d = _corner_dirs_ned(
            math.radians(inp.heading_deg),
            math.radians(inp.angles_deg["azimuth"]),
            math.radians(inp.angles_deg["elevation"]),
            hfov,
            vfov,
        )
        az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
        tilt = np.degrees(np.arccos(d[:, 2]))  # from nadir (pymap3d's convention)
        lat, lon, _ = lookAtSpheroid(inp.lat_deg, inp.lon_deg, inp.h_m, az, tilt)
        from pyproj import Geod

        _, _, dist = Geod(ellps="WGS84").inv(m.corner_lon_deg[k], m.corner_lat_deg[k], lon, lat)
        # 1 mm: both intersect the same ellipsoid in closed form; slant ranges <= 30 km, so float64
        # round-off of ECEF coordinates (~1e-9 m) and of the hand-built directions stay far below it
        assert np.max(dist) < 1e-3, (k, dist)
        np.testing.assert_allclose(m.corner_h_m[k], 0.0, atol=1e-3)


def test_outline_samples_lie_on_the_edges_and_bad_input_is_named():
    scn, _, _ = _turret_scenario(n=2)
    s = scn.camera
    rows, cols = flight_model.outline_pixels(s, 3)
    # the ring walks the outer edge: every point has a row or a column on the sensor's edge
    assert np.all((np.isin(rows, (0.5, s.rows + 0.5))) | (np.isin(cols, (0.5, s.cols + 0.5))))
    assert len(rows) == 12 and (rows[0], cols[0]) == (0.5, 0.5)
    with pytest.raises(ValueError, match="edge_samples = 0"):
        flight_model.outline_pixels(s, 0)
    with pytest.raises(ValueError, match="fov_deg: shape"):
        flight_model.build(scn, fov_deg=np.ones((3, 2)))


# ------------------------------------------------------------------ the bundled KLV flight
@pytest.fixture(scope="module")
def klv_model():
    scn = flight_model.default_flight_scenario()
    return scn, flight_model.build(scn)


@pytest.fixture(scope="module")
def replay_flags():
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import DemSurface
    from geoloc.workflows.klv_replay import replay_klv

    dem = DEM.open(ROOT / "assets" / "dem" / "srtm_jacksboro.tif", datum="egm96")
    r = replay_klv(ROOT / "assets" / "klv" / "example_flight.klv", surface=DemSurface(dem))
    return r.summary.outliers


def test_outliers_first_are_the_planted_packets(klv_model, replay_flags):
    _, m = klv_model
    assert len(replay_flags) == 22
    planted = {f"packet {p}" for p in replay_flags}
    top = [m.labels[i] for i in m.top(22)]
    assert set(top) == planted
    assert {m.labels[i] for i in np.flatnonzero(m.outlier)} == planted
    # and no other frame comes close: the 23rd residual is quantisation (the reported centres were
    # computed on the same DEM), the 22nd a fault's (the smallest stale-pose error is ~6 m)
    r = m.residual_m[m.order]
    assert r[21] > 5.0 and r[22] < 0.1


def test_the_fitted_faults_give_back_the_planted_sizes(klv_model):
    from geoloc.geodesy.geoid import egm96_undulation

    scn, m = klv_model
    kinds = {(m.labels[f.first], m.labels[f.last]): f for f in m.faults}
    assert set(kinds) == {("packet 100", "packet 109"), ("packet 200", "packet 204"), ("packet 250", "packet 256")}
    yaw, datum, stale = (
        kinds[("packet 100", "packet 109")],
        kinds[("packet 200", "packet 204")],
        kinds[("packet 250", "packet 256")],
    )
    assert (yaw.kind, datum.kind, stale.kind) == ("attitude", "datum", "timing")
    # planted: heading + 2.5 deg; 0.1 deg: the linearisation over a 2.5 deg step and the 0.0055 deg
    # quantisation of the heading tag
    assert math.degrees(yaw.value) == pytest.approx(2.5, abs=0.1)
    # planted: tag 75 holds MSL = HAE - N, so the sensor is -N too high; 1 m: 0.3 m quantisation steps
    # of the height tags, and the DEM's slope under a 43 m slide of the hits
    inp = scn.records[[i.label for i, _ in scn.records].index("packet 200")][1]
    N = float(egm96_undulation(math.radians(inp.lat_deg), math.radians(inp.lon_deg)))
    assert datum.value == pytest.approx(-N, abs=1.0)
    # planted: the previous packet's pose (1 frame stale); 0.1 frame: the run's last frame is fitted with
    # the next frame's fresh pose
    assert stale.value == pytest.approx(-1.0, abs=0.1)
    text = m.faults_markdown()
    for kind in ("attitude", "datum", "timing"):
        assert flight_model.WHAT_IT_LOOKS_LIKE[kind] in text


def test_footprints_follow_the_zoom(klv_model):
    # tags 16/17: 12 deg, then 7 deg from packet 100, 4.5 deg from 200 (tools/make_klv_example.py ZOOM);
    # the footprint's top-edge width scales with tan(hfov / 2) at a like range
    _, m = klv_model
    lab = m.labels
    w = np.linalg.norm(m.corners_enu[:, 1] - m.corners_enu[:, 0], axis=1)
    rng = np.linalg.norm(m.centre_enu - m.track_enu, axis=1)
    k0, k1 = lab.index("packet 50"), lab.index("packet 230")
    ratio = (w[k1] / rng[k1]) / (w[k0] / rng[k0])
    # 10 %: the far edge's range differs from the centre's by the terrain and the obliquity
    assert ratio == pytest.approx(math.tan(math.radians(2.25)) / math.tan(math.radians(6.0)), rel=0.1)


def test_accuracy_panel_agrees_with_a_direct_computation(klv_model):
    from pyproj import Geod

    _, m = klv_model
    ok = np.isfinite(m.residual_m)
    _, _, d = Geod(ellps="WGS84").inv(
        m.recomputed_lon_deg[ok], m.recomputed_lat_deg[ok], m.reported_lon_deg[ok], m.reported_lat_deg[ok]
    )
    # rtol 1e-4: the geodesic runs on the ellipsoid, the local-NED distance at the target's ~525 m
    # height, longer by (R + h) / R - 1 = 8e-5; 1e-6 m for the millimetre residuals
    np.testing.assert_allclose(m.residual_m[ok], d, rtol=1e-4, atol=1e-6)
    s = m.report().overall
    assert s["cep_m"] == pytest.approx(np.percentile(d, 50), rel=1e-4)
    assert s["ce90_m"] == pytest.approx(np.percentile(d, 90), rel=1e-4)
    # against the reported positions the panel gives an agreement, in mm where it is that
    # small, never a CEP (an accuracy) nor an error model: the records carry no truth
    text = m.summary_markdown()
    assert "**agreement with the reported positions**" in text and "**accuracy: unknown**" in text
    assert f"median {np.median(d) * 1e3:.1f} mm" in text
    assert "CEP" not in text.replace("no CEP", "") and "0.00 m" not in text and "error model:" not in text


def test_the_flight_test_panel_shows_no_negative_intercept_model_and_says_why_its_error_is_large():
    # [Q17]'s 20 records on ETOPO5: accuracy against truth, with the slant-range line refused when its
    # intercept is negative (numpy's own polyfit of the horizontal errors on the slant ranges), and the
    # session's panel explaining 486 m against the published 51 m by the DEM's 9 km cells
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    scn = load_view_scenario()
    m = flight_model.build(scn, diagnose_faults=False)
    assert m.reference == "truth"
    ok = np.isfinite(m.residual_m)
    slant = np.linalg.norm(m.recomputed_enu - m.track_enu, axis=1)
    slope, intercept = np.polyfit(slant[ok], m.residual_m[ok], 1)
    text = m.summary_markdown()
    assert "**accuracy against the surveyed truth**" in text and "CEP" in text
    assert "agreement with the reported positions (not an accuracy)" in text
    if intercept < 0:
        assert m.error_model()[0] is None and "negative intercept" in text
        assert "horizontal error =" not in text
    with served() as server:
        app = GeolocApp(server, scn, layers=())
        summary = app.md_summary.content
        # ETOPO5: 5 arc-minutes = 9.3 km north-south
        assert "cells of about 9 km" in summary and "published 51 m" in summary, summary


# ------------------------------------------------------------------ the layer on a server (no browser)
def test_whole_flight_footprints_keep_the_corners_at_half_the_points():
    """The whole flight's footprints, a level of detail: every frame's outline through
    every second outline point, its four corners among them (outline_pixels: corners at 0, k, 2k,
    3k of 4k points), lifted by LIFT_M; the scene node holds exactly those segments (km)."""
    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        scn = flight_model.default_flight_scenario()
        app = GeolocApp(server, scn, layers=(flight_layer.attach,))
        m = app.layers[-1].model
        P = m.footprint_enu.shape[1]
        assert P == 4 * flight_model.EDGE_SAMPLES and flight_model.EDGE_SAMPLES % flight_layer.FOOTPRINT_EVERY == 0
        seg = m.footprint_segments(flight_layer.FOOTPRINT_EVERY)
        keep = np.arange(0, P, flight_layer.FOOTPRINT_EVERY)
        assert set(np.arange(0, P, flight_model.EDGE_SAMPLES)) <= set(keep)  # the corners
        want = np.stack([m.footprint_enu[:, keep], m.footprint_enu[:, np.roll(keep, -1)]], axis=2).reshape(-1, 2, 3)
        np.testing.assert_array_equal(seg, want)
        # the trail is thinned: every k-th frame (k = ceil(298 / 60) = 5) and every outlier
        trail = m.trail_frames(flight_layer.TRAIL_MAX)
        k = int(np.ceil(len(m) / flight_layer.TRAIL_MAX))
        assert set(range(0, len(m), k)) | set(np.flatnonzero(m.outlier)) == set(trail.tolist())
        assert len(trail) < len(m) / 2
        want = want.reshape(len(m), P // 2, 2, 3)[trail].reshape(-1, 2, 3)
        ok = np.all(np.isfinite(want), axis=(1, 2))
        got = np.array(server.scene.get_handle_by_name("/flight/footprints").points)
        lifted = (want[ok] + [0.0, 0.0, flight_layer.LIFT_M["footprints"]]) * 1e-3
        assert got.shape == lifted.shape == (ok.sum(), 2, 3) and ok.sum() > 0.9 * len(trail) * P // 2
        np.testing.assert_allclose(got, lifted, rtol=0, atol=1e-6)  # float32 km: under a millimetre
        with pytest.raises(ValueError, match="must divide the 16 outline points"):
            m.footprint_segments(3)


def test_timeline_moves_only_the_highlight():
    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        scn = flight_model.default_flight_scenario()
        app = GeolocApp(server, scn, layers=(flight_layer.attach,))
        fl = app.layers[-1]
        fp = server.scene.get_handle_by_name("/flight/footprints")
        pts0 = np.array(fp.points)
        cur0 = np.array(server.scene.get_handle_by_name("/flight/current").points)
        fl.sl_frame.value = 150  # as the GUI would
        assert app.scn.record_index == 150
        assert server.scene.get_handle_by_name("/flight/footprints") is fp  # not rebuilt
        np.testing.assert_array_equal(np.array(fp.points), pts0)
        cur1 = np.array(server.scene.get_handle_by_name("/flight/current").points)
        assert np.abs(cur1 - cur0).max() > 0.05  # km: the zoomed footprint of another side of the orbit
        # the highlighted ring is the model's footprint of frame 150, in the scene frame of that record
        F, S = fl.model.enu, app.scn.enu
        ring = S.from_ecef(F.to_ecef(fl.model.footprint_enu[150])) * 1e-3
        root = server.scene.get_handle_by_name("/flight")
        import viser.transforms as vtf

        R = vtf.SO3(np.asarray(root.wxyz)).as_matrix()
        drawn = cur1[:, 0] @ R.T + np.asarray(root.position) - R[:, 2] * flight_layer.LIFT_M["current"] * 1e-3
        # 1 mm: float32 scene coordinates of a few km (steps ~0.5 mm)
        np.testing.assert_allclose(drawn, ring, atol=1e-6 * 1e3)
        # choosing the top outlier jumps the timeline
        fl.dd_goto.value = fl.opts[0]
        assert app.scn.record_index == fl.top_idx[0] == int(fl.sl_frame.value)
        assert fl.model.outlier[fl.top_idx[0]]


def test_a_persons_move_goes_through_while_another_thread_mutes_the_layer():
    """The layer mutes its callbacks while the server sets its own widgets (a live tab growing the
    timeline sets the slider's range from its update thread). A person's move arriving meanwhile (from
    viser's thread pool, its event naming the client) must still step: muting it left the slider on
    frame 3 and the view on frame 107 (a CI run's live test). The server's own set stays muted."""
    from viser import GuiEvent

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.live_view import _first

    with served() as server:
        scn = flight_model.default_flight_scenario()
        app = GeolocApp(server, scn, layers=(flight_layer.attach,))
        fl = app.layers[-1]
        fl.sl_frame.value = 10
        assert app.scn.record_index == 10
        order: list = []
        _first(fl.sl_frame, lambda e: order.append(("hook", app.scn.record_index)))
        fl._mute = True  # as another thread holds it
        try:
            fl.sl_frame.value = 150  # the server's own set: not a step
            assert app.scn.record_index == 10 and fl.current == 10
            fl.sl_frame._impl.value = 120  # viser stores a person's value, then calls each callback
            for cb in list(fl.sl_frame._impl.update_cb):  # (each in a thread of its pool)
                cb(GuiEvent(object(), 7, fl.sl_frame))
        finally:
            fl._mute = False
        assert app.scn.record_index == 120 == fl.current == int(fl.sl_frame.value)
        # the hook ran before the step, for the server's set and the person's, in the same call (one
        # callable: viser's pool has no thread to put between them)
        assert len(fl.sl_frame._impl.update_cb) == 1 and order == [("hook", 10), ("hook", 10)]


def test_a_step_sends_its_scene_first_and_the_panel_text_after(monkeypatch):
    """A timeline step's first batch (flushed to the browser before the panels are worked out) holds
    the scene and no markdown: the browser handles a batch with scene messages in the frame that draws
    it, and the panels' text would delay that frame. The text follows in a batch with no scene
    message (a GUI-only batch draws no frame), the hidden teaching row not moved. A step skipped for
    a newer one leaves its text to that step, even one that redraws nothing."""
    from viser.infra._async_message_buffer import AsyncMessageBuffer

    from geoloc_viz import flight_layer, teaching_panel, uncertainty_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        scn = flight_model.default_flight_scenario()
        app = GeolocApp(server, scn, layers=(flight_layer.attach, uncertainty_layer.attach, teaching_panel.attach))
        fl, unc = app.layers[0], app.layers[1]
        log: list = []
        push = AsyncMessageBuffer.push
        monkeypatch.setattr(AsyncMessageBuffer, "push", lambda buf, m: (log.append(m), push(buf, m))[1])
        flush = server.flush
        monkeypatch.setattr(server, "flush", lambda: (log.append("flush"), flush())[1])
        fl.go(40)
        cut = log.index("flush")
        before, after = log[:cut], [m for m in log[cut + 1 :] if m != "flush"]
        markdown = lambda ms: [m for m in ms if "_markdown" in getattr(m, "updates", {})]  # noqa: E731
        scene = lambda ms: [m for m in ms if str(getattr(m, "name", "")).startswith("/")]  # noqa: E731
        assert scene(before) and not markdown(before)
        assert not scene(after) and len(markdown(after)) >= 3  # the summary, the frame, the ellipse's panel
        # the pose and pixel boxes too (the timeline's own slider moves with the scene)
        boxes = {h._impl.uuid for h in app.num.values()}
        values = lambda ms: [m.uuid for m in ms if "value" in getattr(m, "updates", {})]  # noqa: E731
        assert not boxes & set(values(before)) and boxes & set(values(after))
        rec = app.scn.records[40][1]
        assert float(app.num["h_m"].value) == rec.h_m and float(app.num["row"].value) == rec.row
        assert not any(str(m.name).startswith(teaching_panel.ROOT) for m in scene(log))
        assert frame_name(app.scn, 40) in app.md_summary.content
        assert f"CE90 {float(unc.pu.ce90_m):.1f} m" in unc.md.content
        # a step skipped for a newer one (a slider drag): its text waits ...
        with app.deferring(skip=lambda: True):
            app.load_record(41, move_camera=False)
        assert frame_name(app.scn, 41) not in app.md_summary.content
        # ... for the next step, here one back to the frame already loaded, which redraws nothing
        with app.deferring():
            pass
        assert frame_name(app.scn, 41) in app.md_summary.content
        assert f"CE90 {float(unc.pu.ce90_m):.1f} m" in unc.md.content


def test_example_53_prints_the_frames_and_the_top_outliers():
    out = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "53_flight_debugger_scene.py")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "298 frames" in out.stdout
    assert "22 outliers" in out.stdout
    assert "heading bias +2.4" in out.stdout or "heading bias +2.5" in out.stdout


# ------------------------------------------------------------------ in headless Chromium
def _magenta(img):
    """Pixels of the highlight colour (255, 0, 255): nothing else in the scene has green < 60 with red
    and blue > 180 (flight_layer.COLORS)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 180) & (b > 180) & (g < 60)


@pytest.mark.browser
def test_scrubbing_the_timeline_moves_the_footprint_on_the_canvas(tmp_path):
    from test_viz_browser import ARTIFACTS, chromium, look_at_wxyz, open_viewer, served

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        app.sl_marker.value = 10.0  # the current record's hit markers (220 m balls) would cover the outline
        app.cb_terrain.value = False  # software WebGL on a shared 2-core machine: fewer triangles per render
        with chromium(tmp_path) as browser:
            open_viewer(browser, server, 640, 420)
            client = next(iter(server.get_clients().values()))

            def shot(idx, name):
                fl.sl_frame.value = idx
                # a fixed camera above the flight's target (scene frame of the record: km)
                F, S = fl.model.enu, app.scn.enu
                c = S.from_ecef(F.to_ecef(fl.model.centre_enu[idx])) * 1e-3
                pos = c + np.array([0.0, -0.4, 1.6])
                # the old fault's vector may still be on screen (the browser applies the camera
                # before the scene): it lies elsewhere, so its pixels are not where this one projects
                t0 = time.monotonic()
                while True:
                    img = client.get_render(
                        200,
                        280,
                        position=tuple(pos),
                        wxyz=look_at_wxyz(pos, c),
                        fov=0.9,
                        transport_format="png",
                        timeout=60,
                    )[..., :3]
                    if _magenta(img).sum() > 20 or time.monotonic() - t0 > 25:
                        break
                    time.sleep(0.5)
                import PIL.Image

                PIL.Image.fromarray(img).save(ARTIFACTS / name)
                return _magenta(img)

            a = shot(20, "flight_frame_20.png")
            b = shot(170, "flight_frame_170.png")
            assert a.sum() > 20 and b.sum() > 20, (a.sum(), b.sum())
            ya, xa = np.argwhere(a).mean(axis=0)
            yb, xb = np.argwhere(b).mean(axis=0)
            iou = (a & b).sum() / (a | b).sum()
            # another side of the orbit and a 12 -> 7 deg zoom: the outline turns and shrinks, so
            # its pixels barely overlap, and its centroid moves by several pixels
            assert iou < 0.3, iou
            assert math.hypot(xb - xa, yb - ya) > 2.0


@pytest.mark.browser
def test_choosing_an_outlier_moves_the_browser_camera(tmp_path):
    from test_viz_browser import chromium, open_viewer, served, wait_for

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        with chromium(tmp_path) as browser:
            open_viewer(browser, server, 640, 420)
            client = next(iter(server.get_clients().values()))
            wait_for(lambda: client.camera.update_timestamp > 0, 20, "the browser's first camera report")
            reported = []
            client.camera.on_update(lambda cam: reported.append(np.array(cam.position)))
            before = np.array(client.camera.position)
            fl.dd_goto.value = fl.opts[0]  # as the GUI would
            pos, _ = fl.camera_pose(fl.top_idx[0])
            # the browser applies the new camera and reports it back
            # 0.05 km: the browser reports float32 positions after orbit-control damping settles
            try:
                wait_for(
                    lambda: any(np.linalg.norm(p - pos) < 0.05 for p in reported),
                    20,
                    "the browser to report the outlier's camera",
                )
            except AssertionError:
                raise AssertionError(f"target {pos}, before {before}, reported {reported[-3:]}")
            assert np.linalg.norm(pos - before) > 0.1  # km
            assert app.scn.record_index == fl.top_idx[0]


def _pink(img):
    """Pixels of the current error vector's colour (255, 90, 200): red > 225, green 50-150, blue 150-245.
    Not the red (255, 40, 40) or violet (180, 80, 255) markers, the magenta highlight (green 0), the
    other frames' mauve error vectors (165, 95, 145) or the terrain (flight_layer.COLORS)."""
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (r > 225) & (g > 50) & (g < 150) & (b > 150) & (b < 245)


def project_px(pts, pos, wxyz, fov, width, height):
    """Pixel (u, v) of scene points seen by a viser camera (OpenCV axes: x right, y down, z forward;
    ``fov`` vertical), by hand: a pinhole with f = (height / 2) / tan(fov / 2)."""
    import viser.transforms as vtf

    R = vtf.SO3(np.asarray(wxyz, float)).as_matrix()  # camera -> world
    pc = (np.asarray(pts, float) - np.asarray(pos, float)) @ R
    f = 0.5 * height / math.tan(0.5 * fov)
    return np.stack([0.5 * width + f * pc[:, 0] / pc[:, 2], 0.5 * height + f * pc[:, 1] / pc[:, 2]], 1), pc[:, 2]


@pytest.mark.browser
def test_at_each_planted_fault_the_error_vector_shows_on_the_canvas(tmp_path):
    # after "go to" the heading-bias burst, the datum run and the stale pose,
    # the browser's camera frames the error, its pink vector's pixels are on the canvas between the
    # two markers (not covered by them, nor by the terrain mesh) and its length is in the page
    import PIL.Image
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        W_, H_ = 640, 420
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, W_, H_)
            client = next(iter(server.get_clients().values()))
            wait_for(lambda: client.camera.update_timestamp > 0, 30, "the browser's first camera report")
            for lab in ("packet 100", "packet 203", "packet 250"):
                opt = next(o for o in fl.opts if o.strip().endswith(")") and f", {lab} (" in o)
                fl.dd_goto.value = opt  # as the GUI would
                idx = fl.model.labels.index(lab)
                assert app.scn.record_index == idx
                pos, aim = fl.camera_pose(idx)
                D = np.linalg.norm(pos - aim)
                # 2 % of the distance: the browser reports float32 positions after the damping settles
                wait_for(
                    lambda: np.linalg.norm(np.array(client.camera.position) - pos) < 0.02 * D,
                    30,
                    f"the browser camera to frame {lab}'s error",
                )
                a, b = fl.focus_world()
                # the markers of the frame are sized to its error (a tenth), the session's hit markers too
                err = fl.focus_info["error_m"]
                assert fl.focus_info["radius_m"] == pytest.approx(0.1 * err)
                assert app.view.disp.marker_radius_m == pytest.approx(0.1 * err)
                cam = client.camera
                cpos, cwxyz, fov = np.array(cam.position), np.array(cam.wxyz), float(cam.fov)
                t = np.linspace(0.2, 0.8, 13)  # the markers cover at most 0.1 of each end
                uv, depth = project_px(a + t[:, None] * (b - a), cpos, cwxyz, fov, W_, H_)
                assert np.all(depth > 0)
                length_px = np.linalg.norm(uv[-1] - uv[0]) / 0.6
                assert length_px > 60, length_px  # the vector spans a good part of the view
                # the old fault's vector may still be on screen (the browser applies the camera
                # before the scene): it lies elsewhere, so its pixels are not where this one projects
                t0 = time.monotonic()
                while True:
                    img = client.get_render(
                        H_, W_, position=tuple(cpos), wxyz=tuple(cwxyz), fov=fov, transport_format="png", timeout=90
                    )[..., :3]
                    pink = _pink(img)
                    hits = [pink[max(int(v) - 3, 0) : int(v) + 4, max(int(u) - 3, 0) : int(u) + 4].any() for u, v in uv]
                    if np.mean(hits) >= 0.9 or time.monotonic() - t0 > 60:
                        break
                    time.sleep(1.0)
                PIL.Image.fromarray(img).save(ARTIFACTS / f"flight_error_{lab.replace(' ', '_')}.png")
                # 90 %: one sample may fall where the vector passes behind its own label's background
                assert np.mean(hits) >= 0.9, (lab, hits, uv.round(1))
                # the label's text (the vector's length) is in the page's panel and on the label node
                label = fl.focus_info["label"]
                assert f"error {err:.1f} m" in label
                assert server.scene.get_handle_by_name("/flight/focus/label").text == label
                page.wait_for_selector(f"text=error {err:.1f} m", timeout=60000, state="attached")


def test_the_html_export_panel_states_the_frames_error_and_its_fault(tmp_path):
    # the static page of an outlier says its residual, its error vector's length and
    # the fault of its run (the planted datum run, 200-204), not only the record's header
    import re

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        idx = fl.model.labels.index("packet 203")
        fl.go(idx, camera=True)
        page = app.export(tmp_path / "outlier.html", animate_steps=False).read_text()
        panel = re.search(r'<div id="geoloc-summary"[^>]*>(.*?)</div>', page, re.S).group(1)
        err = fl.error_m(idx)
        for text in (
            f"example_flight.klv: {frame_name(app.scn, idx, of=False)}",  # the one name: frame 202 (.., packet 203)
            f"residual {fl.model.residual_m[idx]:.2f} m",
            f"error {err:.1f} m",
            "sensor height off by",
            "height in the wrong datum",
        ):
            assert text in panel, text
        # the sidebar names the error vector by the palette's word for its colour (one source)
        assert f"**{PALETTE['error'].name} vector**" in fl._frame_text(idx)


def test_one_legend_per_scenario_from_what_it_draws():
    # the KLV flight has reported centres and no truth (no "[Q17]", no "surveyed"), the [Q17]
    # flight test its published and surveyed points, the turret its own gimbal frames (no "outer gimbal")
    from geoloc.assets import asset_path
    from geoloc_viz.app import legend_markdown
    from geoloc_viz.scenario import load_view_scenario

    klv = legend_markdown(flight_model.default_flight_scenario())
    assert "reported position" in klv and "[Q17]" not in klv.replace("[Q17]'s steps", "")
    assert "surveyed" not in klv and "bright pink" in klv and "outer gimbal" not in klv
    q17 = legend_markdown(load_view_scenario())
    assert "published position [Q17]" in q17 and "**white**: surveyed" in q17 and "outer gimbal" in q17
    turret = legend_markdown(
        load_view_scenario(
            asset_path("records", "eo_turret_flight.csv"), "orbit1-5", asset_path("sensors", "eo_turret.toml")
        )
    )
    assert "gimbal azimuth" in turret and "gimbal elevation" in turret and "outer gimbal" not in turret


def test_a_flight_without_surveyed_truth_is_not_offered_a_calibration():
    """A MISB stream carries no surveyed target: the calibration folder (error vectors of every
    record against its truth) has nothing to draw and is not offered, and no text on the page names
    the records file's internal column names ("paper_height_m")."""
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario())
        cal = app.calibration
        assert cal is not None and cal.layer is None and cal.cb_show is None
        assert "paper_height_m" not in cal.message and "surveyed target" in cal.message
        for text in (app.md_summary.content, app.md_legend.content):
            assert "paper_height" not in text and "truth_lat" not in text


def test_the_flight_label_names_its_solver_beside_the_frames_own():
    # one point, two numbers: the flight's frames are located by the exact walk, the viewer's current
    # frame by its own method (bisection [L23] in the [Q17] flight test), 0.9 m apart at T3-1 on
    # ETOPO5; the label said only "recomputed" beside the panel's other figure. Both now name their
    # solver, so the 487.1 m and 486.5 m a person reads are told apart.
    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        fl.go(0, camera=False)
        label = fl.error_text(0)
        assert "exact first hit on the DEM -> truth" in label, label
        assert f"error {fl.error_m(0):.1f} m" in label
        panel = app.md_summary.content
        assert "bisection [L23]" in panel and "from the exact first hit" in panel, panel
