"""``geoloc view --live``: the flight debugger of ``geoloc view`` following a stream, in headless
Chromium, as a person uses it.

A sender in its own process (``python -m geoloc.io.live send``: the aircraft is another
machine; a thread would share the viewer's interpreter and be paced by it) streams the bundled
example flight (H.264 video + MISB ST 0601 KLV) to udp://127.0.0.1:PORT at 3x real time, three
times over (a sender that restarts: a software-WebGL page on a busy machine takes up to a minute
per screenshot, and the person's steps must happen while the flight still streams); the page is open before the first datagram. The first
located frame is on the page (the Live folder's line, and the debugger's own panel: the frame's hit
and slant range) while the stream still comes: before the feed has received the first pass's
last packet (an order of events, not a time: a viewer that waited for the stream to end fails it on
any machine, a prompt one passes on a loaded one; the seconds are printed); the flight's timeline, outlier table,
faults and accuracy grow with the stream (the example's heading-bias burst, packets 100-109,
is fitted live as in the file's debugger); the view follows the latest frame (its picture
too); a person scrubs back by typing a frame into the timeline's box (the timeline keeps
growing, the view stays there); the **live** button returns to the latest packet.
Screenshots go to ``test-artifacts/``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from test_live import TS, _bound, free_port
from test_viz_browser import ARTIFACTS, chromium, open_viewer, wait_for

pytestmark = [pytest.mark.browser]
#: Good KLV packets in one pass of the bundled stream (the sender loops it three times).
N_PACKETS = 299


def _packet_on_page(page) -> int | None:
    # the first frame name on the page is the Live folder's (the top folder): "frame I of 0 .. N (t T s, packet P)"
    m = re.search(r"frame \d+ of 0 \.\. \d+ \(t [0-9.]+ s, packet (\d+)\)", page.locator("body").inner_text())
    return int(m.group(1)) if m else None


def _frames_on_page(page) -> int | None:
    m = re.search(r"(\d+) frames\*?\*?, footprints on", page.locator("body").inner_text())
    return int(m.group(1)) if m else None


def _picture_on_page(page) -> float | None:
    """The picture panel's picture time [s on the stream clock] (its caption: 'frame I of 0 .. N
    (t T s, packet P): picture at T s; W x H px'); the bundled stream has a picture a second."""
    m = re.search(r"picture at ([0-9.]+) s; \d+ x \d+ px", page.locator("body").inner_text())
    return float(m.group(1)) if m else None


def _shot(page, name):
    # a software-WebGL page that is sent a frame a second on 2 cores shared by several jobs: a
    # screenshot waits for its next frame, seconds to a minute
    page.screenshot(path=str(ARTIFACTS / f"{name}.png"), timeout=120000)


def _sender(url, speed, loop=1):
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen(
        [sys.executable, "-m", "geoloc.io.live", "send", str(TS), url, "--speed", str(speed), "--loop", str(loop)],
        env=env,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_live_debugger_follows_the_flight_in_chromium(tmp_path):
    from geoloc_viz.app import make_server
    from geoloc_viz.live_view import LiveFeed, LiveViewer

    ARTIFACTS.mkdir(exist_ok=True)
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"duration_s": 300})
    server = make_server(port=0)
    viewer = LiveViewer(server, feed)
    proc = None
    try:
        feed.start()
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 880, 600)
            page.wait_for_selector("text=waiting for the first packet", timeout=30000)
            # the page notes when the first frame reaches its DOM (its own clock: a software-WebGL page
            # on 2 busy cores may stall later, while it first draws the scene, and delay our polling):
            # the Live folder's line, and the debugger's summary of the loaded frame (its hit)
            page.evaluate(r"""() => {
                window.__first = null; window.__debugger = null;
                new MutationObserver(() => {
                    const t = document.body.textContent;
                    if (window.__first === null && /frame \d+ of 0 \.\. \d+ \(/.test(t)) window.__first = Date.now();
                    if (window.__debugger === null && /slant range [\d.]+ km/.test(t)) window.__debugger = Date.now();
                }).observe(document.body, {subtree: true, childList: true, characterData: true});
            }""")
            proc = _sender(url, 3.0, loop=3)
            page.wait_for_function(
                "() => window.__first !== null && window.__debugger !== null", polling=100, timeout=60000
            )
            # read after the page showed both: no more packets had come when it showed them
            received_by_then = feed.rx.stats.klv_packets
            first = feed.rx.first_datagram_unix_s
            t_text = page.evaluate("() => window.__first") / 1e3 - first
            t_debugger = page.evaluate("() => window.__debugger") / 1e3 - first
            print(
                f"first located frame on the page {t_text:.2f} s after the first datagram; "
                f"the debugger's frame {t_debugger:.2f} s"
            )
            tab = next(iter(viewer.tabs.values()))

            def since(t):  # the server's stamps may still be unset when the page has drawn (a busy machine)
                return "not yet" if t is None else f"{t - first:.2f} s"

            print(
                f"server side: the first frame's line sent {since(tab.first_text_unix_s)}, the debugger "
                f"built {since(tab.debugger_unix_s)} after the first datagram"
            )
            # the same machine's clock on both sides (time.time() and the page's Date.now()): the seconds are
            # printed, not bounded (a unit test measures no speed; they were 0.3-1.9 s and 1.4-9.1 s at loads
            # of 8-19, and a 2 s bound failed above 20). What the first frame must show is order: the first
            # located frame (its packet, recomputed centre and agreement, in the Live folder) and the
            # debugger's session for it (its GUI, terrain mesh, chain and iterations) are on the page while
            # the stream still comes, before the first of the sender's three passes (299 packets, 100 s at
            # 3x) has all arrived; a viewer that drew only at the stream's end (or after a pass) fails it
            assert first is not None and 0 < received_by_then < N_PACKETS, (received_by_then, t_text, t_debugger)
            _shot(page, "live_first_frame")

            # the full debugger: its Flight timeline grows with the stream, and it follows the latest
            wait_for(lambda: (_frames_on_page(page) or 0) >= 20, 60, "the flight's timeline to grow to 20")
            n1 = _frames_on_page(page)
            wait_for(lambda: (_frames_on_page(page) or 0) >= n1 + 8, 60, "the timeline to keep growing")
            assert tab.following and tab.layer is not None
            wait_for(
                lambda: tab.current == tab.n - 1 and tab.session.scn.record_index == tab.n - 1,
                10,
                "the latest frame loaded (its chain, line of sight, iterations)",
            )
            # the picture panel is the live frame: it moves on as the view follows, and it is the picture
            # nearest the followed packet's time (the layer's own choice, against the feed's pictures)
            seen = []  # the page read once per poll: it may move on between two reads
            wait_for(lambda: seen.append(_picture_on_page(page)) or seen[-1] is not None, 60, "the live picture")
            k1 = seen[-1]
            # 4 pictures on (a picture a second; half a picture of margin)
            wait_for(lambda: (_picture_on_page(page) or 0) >= k1 + 3.5, 30, "the picture to follow the stream")

            # read on the server, where the tab may be between two states: the looped sender's restart
            # rebuilds the session, whose new picture layer shows nothing (k = -1) until its first frame
            # is followed (seen once in a full suite: (-1, 95)). Within 8 pictures (those decoded between
            # the two reads) at some instant of 20 s: a layer that never picks the nearest picture fails
            def _picture_near():
                images, idx = tab._images, tab.current
                if images is None or not 0 <= idx < len(tab.session.scn.record_times_s):
                    return None
                want = feed.picture_index_at(float(tab.session.scn.record_times_s[idx]))
                return (images.k, want) if want >= 0 and abs(images.k - want) <= 8 else None

            wait_for(_picture_near, 20, "the picture layer on the picture nearest the followed frame")
            _shot(page, "live_following")

            m = re.search(r"; (\d+) frames\)", tab.layer.md_accuracy.content)  # the accuracy panel, so far
            n_acc = int(m.group(1)) if m else 0
            # a person scrubs back: types frame 3 into the timeline's number box (the box beside the slider
            # its label names; arrow keys on the slider would move the 3D camera too)
            box = page.locator(
                "xpath=//label[normalize-space()='frame index']/ancestor::div"
                "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
            )
            # while the view follows, the server moves that box once a second: a value typed just before
            # its update is overwritten before Enter (a person types it again). A person sees it: the box no
            # longer reads 3 while the view still follows; then it is typed again at once, and again 20 s
            # after a try nothing came of (before, each lost try waited its 20 s: 20-40 s of a run at load 17).
            # 120 s in all, as six tries of 20 s were (each fill and Enter is a round trip to a busy page)
            t0, typed = time.monotonic(), None
            while not (not tab.following and tab.current == 3):
                if time.monotonic() - t0 > 120:
                    raise AssertionError(
                        f"timed out after 120 s waiting for the scrub to reach the server: following "
                        f"{tab.following}, current {tab.current}, n {tab.n}, slider {tab.layer.sl_frame.value}"
                    )
                lost = typed is not None and tab.following and box.input_value(timeout=120000) != "3"
                if typed is None or lost or time.monotonic() - typed > 20:
                    box.fill("3", timeout=120000)  # (a page that takes up to a minute a frame: see _shot)
                    box.press("Enter", timeout=120000)
                    typed = time.monotonic()
                time.sleep(0.1)
            n_then = tab.n
            wait_for(lambda: tab.n >= n_then + 5, 60, "the timeline to keep growing")
            assert tab.current == 3 and tab.session.scn.record_index == 3
            want = int(tab.flight.rows["packet"][3])
            wait_for(lambda: _packet_on_page(page) == want, 20, "the page to stay on frame 3")
            assert page.locator("text=scrubbed back").count() >= 1
            _shot(page, "live_scrubbed_back")

            # ... and presses "live": back to the newest packet, following again
            page.get_by_role("button", name="live", exact=True).click(no_wait_after=True, timeout=120000)
            wait_for(lambda: tab.following and tab.current == tab.n - 1, 20, "live to return to the latest")
            # the page shows the newest packet (within 4 s of stream: the follow step once a second, and a
            # software-WebGL page's lag behind the server)
            wait_for(
                lambda: (_packet_on_page(page) or 0) >= int(tab.flight.rows["packet"][-1]) - 12,
                60,
                "the page to show the latest packet",
            )
            _shot(page, "live_after_live_button")
            # the example's heading-bias burst (packets 100-109) arrives: the outlier table, the faults and
            # the accuracy panel say it, fitted on the frames received so far as the file's debugger does
            wait_for(
                lambda: tab.n >= 118 and "heading bias" in tab.layer.md_faults.content,
                120,
                "the heading-bias run to be fitted live",
            )
            m = re.search(r"heading bias ([+-][\d.]+) deg", tab.layer.md_faults.content)
            assert m and abs(float(m.group(1)) - 2.5) < 0.2, tab.layer.md_faults.content  # planted +2.5 deg
            table = tab.layer.md_table.content
            # the feed loops the 300-packet file: a slow page may meet the burst's second pass (packets
            # 400-409) too, which then shares the 12-row table with the first (CI saw 100, 400, 102, 402, ...);
            # so the rows are counted, each by its packet within the file: at least 8 of the 12 are the burst
            rows = [int(p) % 300 for p in re.findall(r"\| \d+ \(packet (\d+)\) \|", table)]
            assert len(rows) >= 10 and sum(100 <= p < 110 for p in rows) >= 8, table
            m = re.search(r"; (\d+) frames\)", tab.layer.md_accuracy.content)
            assert m and int(m.group(1)) > n_acc, (n_acc, tab.layer.md_accuracy.content)  # the panel grew
            wait_for(lambda: "heading bias" in page.locator("body").inner_text(), 30, "the faults on the page")

            text = page.locator("body").inner_text()
            assert re.search(r"\d+ datagrams", text) and "TS continuity errors" in text  # the stream panel
            assert re.search(r"video 640 x 360 pixels; 0 resolution change", text)
            _shot(page, "live_faults_fitted")
            proc.kill()  # the aircraft lands
            proc.wait(30)
            time.sleep(3)  # the last datagrams in, the last batch drawn (DRAW_S)
            wait_for(lambda: tab.n == len(tab.flight) and tab.current == tab.n - 1, 30, "the last frames")
            # memory bounded: the window and the pictures kept
            assert tab.n <= tab.flight.window and len(feed.pictures) <= 64
            st = feed.rx.stats
            # nothing lost over loopback but at the passes' joins: a restarted sender's continuity counters
            # start again (a jump on each of its 4 PIDs: PAT, PMT, video, KLV, and the PES it cut)
            # (the person's steps may all happen within the first pass: then no restart and no jump at all)
            assert st.cc_errors <= 8 * st.restarts and st.klv_packets >= 118, st
            assert np.isfinite(tab.layer.model.residual_m).all()  # every frame of the window located
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        viewer.stop()
        server.stop()
