"""``geoloc view --live``: the debugger following a stream, in headless Chromium, as a person uses it.

A sender thread streams the bundled example flight (H.264 video + MISB ST 0601 KLV)
to udp://127.0.0.1:PORT; the page is open before the first datagram. The first
located frame must be on the page within 2 s of the first datagram; the view
follows the latest frame; a person scrubs back by typing a frame into the
slider's box (the timeline keeps growing, the view stays there); the **live**
button returns to the latest frame; the loss panel shows the counts.
Screenshots go to ``test-artifacts/``.
"""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from tests.test_live import TS, _bound, free_port
from tests.test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for

pytestmark = [pytest.mark.browser]


def _packet_on_page(page) -> int | None:
    m = re.search(r"packet (\d+)\*?\*? \(frame", page.locator("body").inner_text())
    return int(m.group(1)) if m else None


def test_live_view_follows_the_flight_in_chromium(tmp_path):
    from geoloc.io.live import send
    from geoloc.viz.app import make_server
    from geoloc.viz.live_view import LiveFeed, LiveViewer

    ARTIFACTS.mkdir(exist_ok=True)
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"duration_s": 240})
    server = make_server(port=0)
    viewer = LiveViewer(server, feed)
    sent = {}
    try:
        feed.start()
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 900, 640)
            page.wait_for_selector("text=waiting for the first packet", timeout=30000)
            # the page notes when the first frame's text reaches its DOM (its own clock: a software-WebGL
            # page on 2 busy cores may stall later, while it first draws the scene, and delay our polling)
            page.evaluate(r"""() => {
                window.__first = null;
                new MutationObserver(() => {
                    if (window.__first === null && /\(frame \d+ of \d+\)/.test(document.body.textContent))
                        window.__first = Date.now();
                }).observe(document.body, {subtree: true, childList: true, characterData: true});
            }""")
            # the stream starts: 4x real time (75 s of flight in about 19 s)
            th = threading.Thread(target=lambda: sent.update(send(TS, url, speed=4.0)), daemon=True)
            th.start()
            page.wait_for_function("() => window.__first !== null", polling=100, timeout=60000)
            first_ms = page.evaluate("() => window.__first")
            first = feed.rx.first_datagram_unix_s
            # the same machine's clock on both sides (time.time() and the page's Date.now())
            assert first is not None and first_ms / 1e3 - first < 2.0, first_ms / 1e3 - first
            tab = next(iter(viewer.tabs.values()))

            # it follows: the page's packet number grows with the stream
            wait_for(lambda: (_packet_on_page(page) or 0) >= 10, 60, "the view to follow to packet 10")
            page.screenshot(path=str(ARTIFACTS / "live_following.png"))
            assert tab.following

            # a person scrubs back: types frame 3 into the slider's number box (the box beside the slider
            # the label names; arrow keys on the slider would move the 3D camera too)
            box = page.locator("xpath=//label[normalize-space()='frame']/ancestor::div"
                               "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']")
            box.fill("3")
            box.press("Enter")
            wait_for(lambda: not tab.following and tab.current == 3, 20, "the scrub to reach the server")
            n_then = tab.n
            wait_for(lambda: tab.n >= n_then + 5, 60, "the timeline to keep growing")
            assert tab.current == 3 and _packet_on_page(page) == int(tab.cols["packet"][3])
            assert page.locator("text=scrubbed back").count() >= 1

            # ... and presses "live": back to the newest frame, following again
            page.get_by_role("button", name="live").click()
            wait_for(lambda: tab.following and tab.current == tab.n - 1, 20, "live to return to the latest")
            wait_for(lambda: (_packet_on_page(page) or 0) >= int(tab.cols["packet"][-1]) - 3, 20,
                     "the page to show the latest frame")
            # the stream panel counts what arrived
            text = page.locator("body").inner_text()
            assert re.search(r"\d+ datagrams", text) and "TS continuity errors" in text
            page.screenshot(path=str(ARTIFACTS / "live_after_live_button.png"))
            if feed.rx.stats.video_units:  # the re-rendered example flight carries video: its picture
                wait_for(lambda: tab.img is not None, 30, "the live picture")
    finally:
        viewer.stop()
        server.stop()
