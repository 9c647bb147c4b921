"""One frame index and one pixel grid on every panel; a video timing fault named on its frames.

The bundled example flight (``assets/klv/example_flight.klv`` with its video ``.ts``): its KLV
names no image size, so its sensor is built on a nominal 1920 x 1080 grid, while the video is
640 x 360; its records skip packets 150 and 275, so frame index 202 is packet 203. Oracles:

* no browser: the pixel grid converted at load gives the nominal sensor's rays at the matching
  pixels (pixel edges map onto each other: ``r' - 0.5 = (r - 0.5) / 3``), and the converted lens is
  ``lens_from_fov`` of the KLV's fields of view at the video's size (the rule of
  ``geoloc.workflows.klv_replay.klv_sensor``, built here from the packet's tags); the [Q17] flight
  test, where the robust rule flags no frame, offers no "worst fault" button;
* headless Chromium, as a person does it: type a frame index into the timeline's box, read every
  panel's frame name (the summary, the picture's caption, the flight panel) and pixel grid from the
  page: one index, one time, one grid; click a pixel of the picture and read its latitude and
  longitude: ``geoloc locate`` of that pixel in the video's grid (a subprocess, the frame's sensor
  written to a file); on a frame of the video's planted timing fault (``tools/make_klv_example.py``
  ``VIDEO_FAULTS``: frames 40-79 run 1.5 s ahead of their metadata) the picture panel names the
  fault and its fitted offset, and off it a button goes there.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

#: The planted offset of the bundled video (tools/make_klv_example.py VIDEO_FAULTS), written out
#: as the oracle: video time = metadata time - 1.5 s over packets 40..79.
PLANTED_OFFSET_S, PLANTED_FIRST, PLANTED_LAST = -1.5, 40, 79


@pytest.fixture(scope="module")
def flight():
    from geoloc_viz.flight_model import default_flight_scenario

    return default_flight_scenario()


def test_pixels_are_converted_once_to_the_videos_grid(flight):
    import math

    from geoloc.sensors.lenses import lens_from_fov
    from geoloc_viz.scenario import records_from_klv

    assert (flight.camera.rows, flight.camera.cols) == (flight.images.rows, flight.images.cols) == (360, 640)
    assert "640 x 360" in flight.pixel_grid and "1920 x 1080" in flight.pixel_grid
    # every record's pixel (the image centre) in the video's grid
    assert {(inp.row, inp.col) for _, inp in flight.records} == {(180.5, 320.5)}
    nominal, recs, _ = records_from_klv(flight.video_path)
    assert (nominal.rows, nominal.cols) == (1080, 1920)
    pose = recs[100][1].pose()
    rows = np.array([0.5, 1.0, 180.5, 360.5, 77.25])
    cols = np.array([0.5, 640.5, 320.5, 1.0, 501.75])
    a = flight.camera.line_of_sight(rows, cols, pose).direction_ecef
    b = nominal.line_of_sight(0.5 + (rows - 0.5) * 3, 0.5 + (cols - 0.5) * 3, pose).direction_ecef
    # one lens resampled: the same rays to rounding (1e-12 rad, far under a 640-px pixel's 2e-4 rad)
    assert np.abs(a - b).max() < 1e-12
    # and the lens is the nominal one's fields of view at the video's size (lens_from_fov, the
    # replay's own rule for a KLV sensor): the field of view read off the nominal pinhole
    hfov = 2 * math.atan(960.0 / nominal.lens.fx)
    vfov = 2 * math.atan(540.0 / nominal.lens.fy)
    ref = lens_from_fov(hfov, vfov, 640, 360)
    assert flight.camera.lens.fx == pytest.approx(ref.fx, rel=1e-12)
    assert flight.camera.lens.fy == pytest.approx(ref.fy, rel=1e-12)
    assert flight.camera.center_pixel == pytest.approx((180.5, 320.5), abs=1e-12)


def test_a_flight_with_nothing_flagged_offers_no_worst_fault():
    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        # [Q17]'s 20 records on ETOPO5: every error is large, none stands out from the others
        assert not fl.model.outlier.any()
        assert fl.worst is None and not fl.bt_worst.visible
        # the largest residual is still in the table and the "go to" list, as a frame, not a fault
        assert fl.opts and fl.opts[0].startswith("1. frame ")


def test_clear_target_rays_is_offered_only_with_rays_to_clear(flight):
    from test_viz_picture import make_app

    server, app, layer = make_app(flight)
    try:
        assert not layer.bt_clear_target.visible  # nothing picked: nothing to clear
        layer.pick_pixel(150.0, 333.0)
        assert layer.target and layer.bt_clear_target.visible
        layer.clear_target()
        assert not layer.target and not layer.bt_clear_target.visible
    finally:
        server.stop()


# ------------------------------------------------------------------ headless Chromium

FRAME_RX = re.compile(r"frame (\d+) of 0 \.\. (\d+) \(t ([0-9.]+) s, (packet \d+)\)")


def _type_frame(page, idx, shown=None):
    """Type ``idx`` into the timeline's number box, as a person does (arrow keys would move the camera).

    ``shown``: the frame the box must show first. A person types once the page has caught up with a
    button that moved the timeline; typing before the server's update of the box reaches the page
    lets that update overwrite what was typed (CI at a load of about 5)."""
    num = page.locator(
        "xpath=//label[normalize-space()='frame index']/ancestor::div"
        "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
    )
    if shown is not None:
        wait_for(lambda: num.input_value(timeout=60000) == str(shown), 120, f"the frame box to show {shown}")
    num.fill(str(idx), timeout=60000)
    num.press("Enter")


def _panels(page):
    return page.evaluate("() => document.body.innerText")


def _app(flight):
    import copy

    from geoloc_viz import flight_layer, image_layer
    from geoloc_viz.app import GeolocApp

    def make(server):
        app = GeolocApp(server, copy.copy(flight), layers=(image_layer.attach, flight_layer.attach))
        return app, app.layers[0], app.layers[1]

    return make


def test_every_panel_shows_one_frame_index_and_one_pixel_grid_in_chromium(flight, tmp_path):
    from test_viz_picture import click_picture_and_read_latlon, locate_cli

    ARTIFACTS.mkdir(exist_ok=True)
    with served() as server:
        app, il, fl = _app(flight)(server)
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1000, 660)
            page.wait_for_selector("#geoloc-picture", timeout=120000)
            _type_frame(page, 202)
            wait_for(lambda: fl.current == 202 and il.index == 202, 120, "the timeline to reach frame 202")
            page.wait_for_selector("text=/frame 202 of 0 \\.\\. 297/", timeout=120000)
            # every panel has drawn frame 202: the summary, the picture's caption, the flight panel
            wait_for(lambda: len(FRAME_RX.findall(_panels(page))) >= 3, 120, "the three panels")
            wait_for(
                lambda: {m[0] for m in FRAME_RX.findall(_panels(page))} == {"202"}, 120, "every panel on frame 202"
            )
            text = _panels(page)
            names = FRAME_RX.findall(text)
            # the summary, the picture's caption and the flight panel: one index, one time, one label
            assert len(names) >= 3 and set(names) == {("202", "297", "203.00", "packet 203")}, names
            assert "timeline frame index" not in text  # the second numbering is gone
            # the record box and the summary's header: the same name, not the stream's "packet 203" alone
            assert app.dd_record.value == "frame 202 (t 203.00 s, packet 203)"
            assert "example_flight.klv: frame 202 (t 203.00 s, packet 203)" in text
            assert not re.search(r"(?<!, )packet 203(?!\))", text), "a packet number outside a frame's name"
            assert fl.sl_frame.value == 202
            # the scene's labels (canvas, not page text) name the frame the same way
            assert server.scene.get_handle_by_name("/flight/focus/label").text.startswith(
                "frame 202 (t 203.00 s, packet 203)"
            )
            # one pixel grid: the summary's pixel, the picture's size, the teaching ray's pixel
            m = re.search(r"pixel row ([0-9.]+), column ([0-9.]+) in the image's own grid, 640 x 360 px", text)
            assert m and (float(m[1]), float(m[2])) == (180.5, 320.5)
            assert "640 x 360 px" in re.search(r"picture at [^\n]*", text)[0]
            img = page.locator("#geoloc-picture")
            assert (img.get_attribute("data-h"), img.get_attribute("data-w")) == ("360", "640")  # zoom 1
            assert "1920" not in re.sub(r"nominal 1920 x 1080", "", text)  # the nominal grid only named once
            # a click on the picture: the pixel in the video's grid, located as `geoloc locate` does
            r, c = 150.0, 333.0
            lat, lon = click_picture_and_read_latlon(page, il, r, c)
            assert (il.sensor.rows, il.sensor.cols) == (360, 640)  # the command's sensor file: the video's grid
            ref = locate_cli(app.scn, il.sensor, app.inputs, r, c, tmp_path)
            # the panel prints 8 decimals: 5e-9 deg of rounding, under the 1e-7 deg asked (1 cm)
            assert lat == pytest.approx(ref["lat_deg"], abs=1e-7)
            assert lon == pytest.approx(ref["lon_deg"], abs=1e-7)
            time.sleep(1.0)
            page.screenshot(path=str(ARTIFACTS / "viz_one_numbering.png"))


def test_the_video_timing_fault_is_named_on_its_frames_in_chromium(flight, tmp_path):
    ARTIFACTS.mkdir(exist_ok=True)
    with served() as server:
        app, il, fl = _app(flight)(server)
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1000, 660)
            page.wait_for_selector("#geoloc-picture", timeout=120000)
            wait_for(lambda: il.timing is not None, 240, "the search for timing faults")
            assert [(f.first, f.last) for f in il.timing] == [(PLANTED_FIRST, PLANTED_LAST)]
            # the fit's grid is 0.05 s, refined: the bundled fit is -1.502 s (docs/picture.md); the
            # marks are found to 0.3 px, which at this flight's image motion is about 0.02 s
            assert il.timing[0].fit.time_offset_s == pytest.approx(PLANTED_OFFSET_S, abs=0.05)
            # off the run the panel offers to go there; a frame of another fault (the
            # heading bias at 100) is not called a timing fault
            _type_frame(page, 100)
            wait_for(lambda: il.index == 100, 120, "frame 100")
            page.wait_for_selector("text=/go to the video timing fault: frames 40 \\.\\. 79/", timeout=120000)
            assert "video timing fault, frames" not in _panels(page)
            page.get_by_role("button", name=re.compile("go to the video timing fault")).click(timeout=120000)
            wait_for(lambda: fl.current == PLANTED_FIRST and il.index == PLANTED_FIRST, 120, "the run's first frame")
            _type_frame(page, 62, shown=PLANTED_FIRST)
            wait_for(lambda: il.index == 62, 120, "frame 62")
            page.wait_for_selector("text=/video timing fault, frames 40 \\.\\. 79/", timeout=120000)
            # frame 40's panel says the same fault: wait until the page has drawn frame 62's (the
            # server is there already; under load the browser lags a few seconds behind)
            wait_for(lambda: (FRAME_RX.search(_panels(page)) or [None, None])[1] == "62", 60, "frame 62 in the page")
            text = _panels(page)
            m = re.search(r"the picture runs ([0-9.]+) s ahead of its metadata", text)
            assert m and float(m[1]) == pytest.approx(-PLANTED_OFFSET_S, abs=0.05)
            m = re.search(r"Fitted time offset ([-+0-9.]+) s", text)
            assert m and float(m[1]) == pytest.approx(PLANTED_OFFSET_S, abs=0.05)
            assert FRAME_RX.search(text)[1] == "62"
            # the picture shows it: its painted crosses disagree with the projected marks
            assert "disagree" in text
            time.sleep(1.0)
            page.screenshot(path=str(ARTIFACTS / "viz_video_timing_fault.png"))
