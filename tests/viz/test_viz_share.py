"""Send the point on: the texts the "Send the point on" folder shows.

Each text is checked outside the code that made it:

* the ``geoloc locate`` line is run (a subprocess of the CLI, argv from ``shlex.split`` of the shown
  text): its point is the picked point to 1 mm (ECEF distance by pyproj), for a pixel pick and for
  a terrain click;
* the CoT event is parsed with ``xml.etree`` against the CoT Event schema's required attributes
  (``event``: version, uid, type, time, start, stale, how; ``point``: lat, lon, hae, ce, le);
  the same event sent over UDP to a socket of the test, and written to a file, parse the same way;
* the MGRS reference is NGA's GEOTRANS (the ``mgrs`` package) of the point;
* the field of view is the KLV packet's own (tags 16 and 17, decoded by klvdata) and, for the
  [Q17] camera, ``2 atan(size / 2 f)`` from its camera file read with tomllib.

In headless Chromium a person clicks a pixel of the picture, opens the folder, reads the texts
from the page and presses "copy": the command and the event read from the page pass the same
checks. Screenshot: ``test-artifacts/viz_share_pick.png``.
"""

from __future__ import annotations

import copy
import json
import math
import re
import shlex
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from datetime import datetime

import numpy as np
import pytest
from test_viz_picture import flight  # noqa: F401  (the module fixture: the example flight with frames)

COT_EVENT_REQUIRED = ("version", "uid", "type", "time", "start", "stale", "how")
COT_POINT_REQUIRED = ("lat", "lon", "hae", "ce", "le")


def _make(scn):
    from geoloc_viz import image_layer, share_layer, uncertainty_layer
    from geoloc_viz.app import GeolocApp, make_server

    server = make_server(port=0)
    app = GeolocApp(server, copy.copy(scn), layers=(image_layer.attach, uncertainty_layer.attach, share_layer.attach))
    return server, app, app.layers[0], app.layers[2]


def run_shown_command(text: str, extra=()) -> subprocess.CompletedProcess:
    """The shown command line, run: ``geoloc`` as this interpreter's ``python -m geoloc``."""
    argv = shlex.split(text)
    assert argv[:2] == ["geoloc", "locate"], argv[:2]
    out = subprocess.run(
        [sys.executable, "-m", "geoloc", *argv[1:], *extra], capture_output=True, text=True, check=False, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return out


def ecef(lat, lon, h):
    """WGS 84 geodetic -> ECEF by PROJ (EPSG:4979 -> EPSG:4978), not the core's geodesy."""
    from pyproj import Transformer

    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(t.transform(lon, lat, h))


def parse_cot(xml: str) -> dict:
    """The event's attributes by an independent reader (xml.etree), checked against the schema."""
    ev = ET.fromstring(xml)
    assert ev.tag == "event"
    for a in COT_EVENT_REQUIRED:
        assert ev.get(a), f"event lacks {a}"
    assert float(ev.get("version")) >= 2.0
    assert re.fullmatch(r"\w+(-\w+)*", ev.get("type")) and re.fullmatch(r"\w(-\w+)*", ev.get("how"))
    times = {a: datetime.fromisoformat(ev.get(a).replace("Z", "+00:00")) for a in ("time", "start", "stale")}
    assert times["time"] <= times["stale"] and times["start"] < times["stale"]
    pt = ev.find("point")
    assert pt is not None
    vals = {a: float(pt.get(a)) for a in COT_POINT_REQUIRED}
    assert all(math.isfinite(v) for v in vals.values())
    assert -90 <= vals["lat"] <= 90 and -180 <= vals["lon"] <= 180 and vals["ce"] >= 0 and vals["le"] >= 0
    return {**vals, "uid": ev.get("uid"), "remarks": ev.findtext("detail/remarks") or ""}


def check_texts(texts: dict, point) -> dict:
    """The shown command reproduces ``point`` (lat, lon, h) to 1 mm; the CoT event carries it."""
    import mgrs

    ref = json.loads(run_shown_command(texts["locate"], ["--json"]).stdout)
    # 1 mm: the brief's bound; the command carries every float as repr (17 digits) and the
    # sensor file its lens as repr, so only the solver's own round-off is left (< 1 um here)
    d = np.linalg.norm(ecef(ref["lat_deg"], ref["lon_deg"], ref["h_m"]) - ecef(*point))
    assert d < 1e-3, d
    # the shown text, as a person runs it (no --json): its printed 7 decimals (1 cm) and 2 in h
    txt = run_shown_command(texts["locate"]).stdout
    m = re.search(r"lat ([-0-9.]+) deg\s+lon ([-0-9.]+) deg\s+h ([-0-9.]+) m", txt)
    assert m, txt
    assert float(m.group(1)) == pytest.approx(point[0], abs=0.6e-7)
    assert float(m.group(2)) == pytest.approx(point[1], abs=0.6e-7)
    assert float(m.group(3)) == pytest.approx(point[2], abs=0.006)
    cot = parse_cot(texts["cot"])
    # CoT carries the point as floats (repr): the same point to 1e-9 deg (0.1 mm) and 1 mm in hae
    assert cot["lat"] == pytest.approx(point[0], abs=1e-9) and cot["lon"] == pytest.approx(point[1], abs=1e-9)
    assert cot["hae"] == pytest.approx(point[2], abs=1e-3)
    assert texts["mgrs"] == mgrs.MGRS().toMGRS(point[0], point[1], MGRSPrecision=5) == ref["mgrs"]
    lat, lon = (float(v) for v in texts["latlon"].split(",")[:2])
    assert lat == pytest.approx(point[0], abs=0.6e-8) and lon == pytest.approx(point[1], abs=0.6e-8)
    assert "ellipsoidal, WGS 84" in texts["latlon"] and "EGM96" in texts["latlon"]
    return cot


def test_a_picked_pixel_is_sent_as_mgrs_latlon_command_and_cot(flight):  # noqa: F811
    server, app, pic, share = _make(flight)
    try:
        assert share.point is not None and share.point.what == "scene pixel"
        p = pic.pick_pixel(40.0, 171.0)
        assert share.point.what == "picked pixel" and p.ok
        point = (p.lat_deg(), p.lon_deg(), float(p.hit.h))
        cot = check_texts(share.texts, point)
        # ce / le: one sigma (the schema's meaning) of the predicted CE90 / LE90 the panel quotes:
        # CE90 = sqrt(2 ln 10) sigma (Rayleigh), LE90 = 1.6449 sigma (normal), scipy's quantiles
        from scipy.stats import norm, rayleigh

        assert cot["ce"] == pytest.approx(share.point.ce90_m / rayleigh.ppf(0.9), rel=1e-9)
        assert cot["le"] == pytest.approx(share.point.le90_m / norm.ppf(0.95), rel=1e-9)
        assert f"CE90 {share.point.ce90_m:.1f} m" in share.md_head.content
        assert "row 40" in share.md_head.content
    finally:
        server.stop()


def test_a_terrain_click_is_sent_with_the_pixel_that_sees_it(flight):  # noqa: F811
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    server, app, pic, share = _make(flight)
    try:
        # a browser's click ray through the ground point of pixel (90, 60), from 2 km up
        c0 = pic.pick_pixel(90.0, 60.0)
        G = geodetic_to_ecef(c0.hit.lat, c0.hit.lon, c0.hit.h)
        g_scene = app.view.disp.z(app.scn.enu.from_ecef(G))
        eye = g_scene + np.array([1.0, -0.5, 2.0])
        gp = pic.pick_ground(eye, g_scene - eye)
        assert gp.ok and gp.visible and share.point.what == "terrain pick"
        point = (math.degrees(float(gp.hit.lat)), math.degrees(float(gp.hit.lon)), float(gp.hit.h))
        check_texts(share.texts, point)
        assert "--method exact" in share.texts["locate"]
        # a point no pixel of the frame sees: no command, and the panel says why
        far = g_scene + np.array([15.0, 15.0, 0.0])
        gp2 = pic.pick_ground(far + np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -1.0]))
        assert gp2.ok and not gp2.in_frame
        assert share.texts["locate"].startswith("(none: no pixel of this frame sees it (outside the frame)")
        parse_cot(share.texts["cot"])  # the point itself is still sent
    finally:
        server.stop()


def test_the_cot_event_goes_over_udp_and_to_a_file(flight):  # noqa: F811
    server, app, pic, share = _make(flight)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(10.0)
        assert share.tx_url.value == "udp://127.0.0.1:6969"  # this machine unless told otherwise
        pic.pick_pixel(70.0, 118.0)
        share.tx_url.value = f"udp://127.0.0.1:{rx.getsockname()[1]}"
        msg = share.send_udp()
        data, _ = rx.recvfrom(65536)
        got = parse_cot(data.decode("utf-8"))
        p = share.point
        assert got["lat"] == pytest.approx(p.lat_deg, abs=1e-12) and "sent 1 CoT event" in msg
        path = share.write_file()
        assert parse_cot(path.read_text())["hae"] == pytest.approx(p.h_m, abs=1e-9)
        share.tx_url.value = "http://nowhere"
        assert share.send_udp().startswith("not sent: --cot 'http://nowhere'")
    finally:
        rx.close()
        server.stop()


def test_the_field_of_view_is_the_lens_s(flight):  # noqa: F811
    import tomllib

    from test_klv import klvdata_values

    from geoloc.assets import ASSETS
    from geoloc_viz import share as sh

    server, app, pic, share = _make(flight)
    try:
        pic.pick_pixel(10.0, 10.0)
        # packet 0's tags 16, 17 by klvdata (it formats them to ~1e-4 deg: the tolerance)
        with open(f"{ASSETS}/klv/example_flight.klv", "rb") as f:
            tags = klvdata_values(f.read(200000))[0]
        h, v = (float(re.match(r"[-0-9.]+", str(tags[t])).group(0)) for t in (16, 17))
        assert share.fov_deg[0] == pytest.approx(h, abs=2e-3) and share.fov_deg[1] == pytest.approx(v, abs=2e-3)
        assert f"field of view **{share.fov_deg[0]:.3f} x {share.fov_deg[1]:.3f} deg**" in share.md_head.content
    finally:
        server.stop()
    # the [Q17] camera file (focal length and principal point in pixels, 1-based centres): the
    # angle from the left edge (column 0.5) to the principal point plus from there to the right
    # edge (N + 0.5); the same down the rows
    from geoloc.frames.chain import Pose
    from geoloc.sensors.sensor_file import load_sensor

    path = f"{ASSETS}/cameras/qiao2017.toml"
    with open(path, "rb") as f:
        cam = tomllib.load(f)
    fpx = cam["focal_length_px"]
    want = [
        math.degrees(math.atan((c0 - 0.5) / fpx) + math.atan((n + 0.5 - c0) / fpx))
        for c0, n in ((cam["principal_col"], cam["cols"]), (cam["principal_row"], cam["rows"]))
    ]
    hv = sh.field_of_view_deg(load_sensor(path), Pose.from_deg(30.0, 110.0, 3000.0, 0, 0, 0, 0, 0))
    # the edge rays run through the middle row / column, 0.1 px off the principal one: a change
    # of the order (0.1 / f)^2 rad, nothing at f = 166841 px; 1e-9 deg is the floats' round-off
    assert hv == pytest.approx(want, abs=1e-9)


# ------------------------------------------------------------------ headless Chromium


@pytest.mark.browser
def test_a_person_picks_a_pixel_and_copies_what_to_send_in_chromium(flight, tmp_path):  # noqa: F811
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for
    from test_viz_picture import _panel_pixel_xy

    ARTIFACTS.mkdir(exist_ok=True)
    server, app, pic, share = _make(flight)
    try:
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1280, 1000)
            page.wait_for_selector("#geoloc-picture", timeout=60000)
            # zoom 4x, as tests/viz/test_viz_picture.py does: at 1x an image pixel is about 1.4 screen px,
            # so a click meant for its centre lands on the next row when the layout moves by a pixel
            pic.sl_zoom.value = 2
            wait_for(
                lambda: page.locator("#geoloc-picture").get_attribute("data-w") == str(pic.image.shape[1] // 4),
                60,
                "the panel to show the 4x crop",
            )
            r, c = 70.0, 118.0
            x, y = _panel_pixel_xy(page, r, c)
            page.mouse.click(x, y)
            wait_for(
                lambda: share.point is not None and share.point.what == "picked pixel",
                60,
                "the click to reach the server",
            )
            page.get_by_text("Send the point on").click()
            page.wait_for_selector("#geoloc-share-locate", timeout=60000)
            wait_for(
                lambda: "--row 70.0 --col 118.0" in page.locator("#geoloc-share-locate").inner_text(),
                60,
                "the panel to show the pick's command",
            )
            texts = {k: page.locator(f"#geoloc-share-{k}").inner_text() for k in ("mgrs", "latlon", "locate", "cot")}
            p = share.point
            check_texts(texts, (p.lat_deg, p.lon_deg, p.h_m))
            fov = page.get_by_text("field of view").first.inner_text()
            assert re.search(r"field of view \d+\.\d{3} x \d+\.\d{3} deg", fov), fov
            btn = page.locator("#geoloc-share-copy-cot")
            btn.scroll_into_view_if_needed()
            btn.click()
            # the clipboard (granted or not in headless Chromium) or the block selected for Ctrl+C
            wait_for(lambda: btn.inner_text() in ("copied", "selected: Ctrl+C"), 20, "the copy button to answer")
            if btn.inner_text() == "selected: Ctrl+C":
                assert page.evaluate("window.getSelection().toString()") == texts["cot"]
            time.sleep(0.5)
            page.screenshot(path=str(ARTIFACTS / "viz_share_pick.png"))
    finally:
        server.stop()
