"""Live mode speaks one pixel grid and one frame name, as ``geoloc view FILE.ts`` does.

The bundled example stream (``assets/klv/example_flight.ts``): its KLV names no image size, so its
sensor is made on a nominal 1920 x 1080 grid, while its video is 640 x 360. Oracles:

* no browser: frames that arrive before the first decoded picture and frames after it all end in
  the video's grid, converted once: every record's pixel (the frame centre) is (180.5, 320.5), and the
  converted sensor's rays are the nominal sensor's at the matching pixels (pixel edges map onto each
  other, docs/conventions.md "Pixels": ``r_nominal - 0.5 = 3 (r - 0.5)``, written out here);
  the Live folder's line names a frame as the timeline does ("frame I of 0 .. N (t T s, packet P)"),
  its packet read from the replay's own columns;
* headless Chromium, as a person does it: the stream sent over loopback, the page opened, a frame
  typed into the timeline's box: every panel (the Live folder, the summary, the picture's caption, the flight
  panel) names the one frame index, the picture is 640 x 360, the page names the nominal grid once;
  a pixel clicked in the picture is located as ``geoloc locate`` locates that pixel of the video's grid
  (a subprocess, the frame's sensor written to a file).
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from geoloc.io.klv import Packet, read_klv_file
from test_live import KLV, TS, _bound, free_port
from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for

#: A frame's one name on the page (geoloc_viz.model.frame_name).
FRAME_RX = re.compile(r"frame (\d+) of 0 \.\. (\d+) \(t ([0-9.]+) s, packet (\d+)\)")


class _Feed:
    """What :class:`geoloc_viz.live_view.LiveFlight` reads of a feed: the replay's batches, the sensor,
    and the size of the first decoded picture once there is one (``video_size``: width, height)."""

    url = "udp://127.0.0.1:0"
    decode_video = True
    pictures_total = 0

    def __init__(self, batches, sensor):
        self.batches, self.sensor, self.video_size = list(batches), sensor, None

    def take_batches(self):
        out, self.batches = self.batches[:1], self.batches[1:]
        return out


def _replayed(n):
    from geoloc.workflows.live_replay import LiveReplay

    packets = [p for p in read_klv_file(KLV) if isinstance(p, Packet)][:n]
    r = LiveReplay("test")
    a, b = r.add(packets[: n // 2]), r.add(packets[n // 2 :])
    return [a.columns, b.columns], a.sensor


@pytest.mark.parametrize("picture_first", [False, True], ids=["frames-before-the-picture", "picture-first"])
def test_live_frames_are_converted_once_to_the_videos_grid(picture_first):
    from geoloc_viz.live_view import LiveFlight

    (c1, c2), nominal = _replayed(20)
    assert (nominal.rows, nominal.cols) == (1080, 1920)
    feed = _Feed([c1, c2], nominal)
    flight = LiveFlight(feed, use_dem=False)
    if picture_first:
        feed.video_size = (640, 360)
    assert flight.update()
    feed.video_size = (640, 360)  # the first picture decoded (after the first batch, or before it)
    assert flight.update()
    assert flight.grid == (360, 640)
    scn = flight.scenario()
    assert (scn.camera.rows, scn.camera.cols) == (360, 640)
    assert "640 x 360" in scn.pixel_grid and "1920 x 1080" in scn.pixel_grid
    # every frame, before and after the picture, at the image centre of the video's grid: converted once
    assert len(scn.records) == 20 and {(inp.row, inp.col) for _, inp in scn.records} == {(180.5, 320.5)}
    pose = scn.records[12][1].pose()
    rows = np.array([0.5, 1.0, 180.5, 360.5, 77.25])
    cols = np.array([0.5, 640.5, 320.5, 1.0, 501.75])
    a = scn.camera.line_of_sight(rows, cols, pose).direction_ecef
    b = nominal.line_of_sight(0.5 + (rows - 0.5) * 3, 0.5 + (cols - 0.5) * 3, pose).direction_ecef
    # one lens resampled: the same rays to rounding (1e-12 rad, far under a 640-px pixel's 2e-4 rad)
    assert np.abs(a - b).max() < 1e-12
    # the Live folder's line: the timeline's index (0-based, in the window), the time, the packet
    # (the .klv file carries no time stamps: no "t" here; the stream's are read in Chromium below)
    m = re.search(r"frame (\d+) of 0 \.\. (\d+) \(packet (\d+)\)", flight.frame_text(15))
    assert m and m.groups() == ("15", "19", str(int(c2["packet"][15 - 10])))
    assert not re.search(r"\(frame \d+ of \d+\)", flight.frame_text(15))  # the old second numbering


def _panels(page):
    return page.evaluate("() => document.body.innerText")


@pytest.mark.browser
def test_a_live_picture_click_is_located_on_the_videos_grid_in_chromium(tmp_path):
    from geoloc.io.live import send
    from geoloc_viz.app import make_server
    from geoloc_viz.live_view import LiveFeed, LiveViewer
    from test_viz_picture import click_picture_and_read_latlon, locate_cli

    ARTIFACTS.mkdir(exist_ok=True)
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"duration_s": 300})
    server = make_server(port=0)
    viewer = LiveViewer(server, feed)
    try:
        feed.start()
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        send(TS, url, speed=20.0)  # the whole flight, 15 s: the page then opens on a still last frame

        def settled():  # the replay and the flight model lag the sender on a busy machine
            n = len(viewer.flight)
            time.sleep(2.0)
            return n == len(viewer.flight) and n >= 290  # the bundled flight: 298 frames

        wait_for(settled, 180, "the flight to take every frame")
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1280, 900)
            wait_for(lambda: viewer.tabs, 60, "the tab")
            tab = next(iter(viewer.tabs.values()))
            wait_for(lambda: tab.layer is not None and tab.current == tab.n - 1 == len(viewer.flight) - 1, 120, "last")
            wait_for(lambda: tab._images is not None, 60, "the picture layer")
            il, last = tab._images, tab.n - 1
            # a person scrubs back a few frames (the stream's last picture stays in the decoder: it holds a
            # frame until the next comes), typing into the timeline's box (arrow keys would move the camera)
            sel = last - 5
            box = page.locator(
                "xpath=//label[normalize-space()='frame index']/ancestor::div"
                "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
            )
            for attempt in range(3):  # a value typed while the server moves the box is overwritten: again
                box.fill(str(sel), timeout=120000)
                box.press("Enter", timeout=120000)
                try:
                    wait_for(lambda: tab.current == sel and il.index == sel and il.image is not None, 40, "the frame")
                    break
                except AssertionError:
                    if attempt == 2:
                        raise AssertionError(f"typed {sel}: on {tab.current} of {tab.n}, following {tab.following}")
            page.wait_for_selector("#geoloc-picture", timeout=120000)
            # every panel on that frame: the Live folder, the summary, the picture's caption, the flight panel
            wait_for(lambda: len(FRAME_RX.findall(_panels(page))) >= 4, 120, "four panels naming the frame")
            wait_for(lambda: {m[0] for m in FRAME_RX.findall(_panels(page))} == {str(sel)}, 120, "one frame")
            text = _panels(page)
            names = set(FRAME_RX.findall(text))
            assert len(names) == 1, names
            (idx, top, t, packet) = names.pop()
            assert (int(idx), int(top)) == (sel, last)
            assert int(packet) == int(viewer.flight.rows["packet"][sel])  # the replay's own packet number
            assert "scrubbed back" in text
            assert not re.search(r"\(frame \d+ of \d+\)", text)  # the Live folder's old second numbering
            # one pixel grid: the summary's pixel, the picture's size; the nominal grid named once
            m = re.search(r"pixel row ([0-9.]+), column ([0-9.]+) in the image's own grid, 640 x 360 px", text)
            assert m and (float(m[1]), float(m[2])) == (180.5, 320.5), text
            img = page.locator("#geoloc-picture")
            assert (img.get_attribute("data-h"), img.get_attribute("data-w")) == ("360", "640")  # zoom 1
            assert "1920" not in re.sub(r"nominal 1920 x 1080", "", text)
            # a click on the picture: the pixel in the video's grid, located as `geoloc locate` does
            r, c = 150.0, 333.0
            lat, lon = click_picture_and_read_latlon(page, il, r, c)
            assert (il.sensor.rows, il.sensor.cols) == (360, 640)  # the command's sensor file: the video's grid
            ref = locate_cli(tab.session.scn, il.sensor, tab.session.inputs, r, c, tmp_path)
            # the panel prints 8 decimals: 5e-9 deg of rounding, under the 1e-7 deg asked (1 cm)
            assert lat == pytest.approx(ref["lat_deg"], abs=1e-7)
            assert lon == pytest.approx(ref["lon_deg"], abs=1e-7)
            page.screenshot(path=str(ARTIFACTS / "live_one_grid.png"), timeout=120000)
    finally:
        viewer.stop()
        server.stop()
