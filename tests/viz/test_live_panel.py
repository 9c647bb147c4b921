"""The live debugger under a bad network: datagrams lost,
swapped and repeated, then the sender stopping and starting the flight again. Counted, said in
the tab's stream panel, every intact packet a frame of the debugger, never a crash.

A tab on the server's own scene and panel (no browser: the panel's text is the server's), fed by
``geoloc.io.live.send`` over loopback. Which KLV packets are intact is decided independently of
the receiver, from the file's TS headers and the datagrams the sender dropped
(``tests.test_live.pes_datagrams``), the packets themselves by FFmpeg's read of the file.
"""

from __future__ import annotations

import time

import numpy as np

from geoloc.io.klv import Packet
from test_live import TS, _bound, free_port, klv_pid, pes_datagrams, reference
from test_viz_browser import wait_for


def wait_while_growing(value, target, idle_s, what):
    """Wait until ``value() >= target``, as long as it keeps growing: fail only after ``idle_s`` [s]
    without progress. On a loaded machine the feed's thread replays slower, but a packet lost for good
    stops the count, so this bound does not depend on the load while a loss still fails."""
    last, t_last = value(), time.monotonic()
    while value() < target:
        v = value()
        if v != last:
            last, t_last = v, time.monotonic()
        elif time.monotonic() - t_last > idle_s:
            raise AssertionError(f"{what}: stuck at {v} of {target} for {idle_s} s")
        time.sleep(0.1)


def test_loss_and_a_restart_are_counted_in_the_panel_and_every_intact_packet_is_a_frame():
    from geoloc.io.live import send
    from geoloc_viz.app import make_server
    from geoloc_viz.live_view import LiveFeed, LiveTab, LiveViewer

    data = TS.read_bytes()
    spans = pes_datagrams(data, klv_pid(data))
    ref = [r for r in reference() if isinstance(r, Packet)]
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"duration_s": 180})
    server = make_server(port=0)
    viewer = LiveViewer(server, feed)
    try:
        tab = LiveTab(viewer.flight, server, None)  # a tab on the server's own scene and panel
        viewer.tabs[-1] = tab
        feed.start()
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        # pass 1: 5 % lost, 5 % swapped, 3 % repeated, at 20x (15 s); 3 s of silence; pass 2 clean
        first = send(TS, url, speed=20.0, loss=0.05, reorder=0.05, duplicate=0.03, rng=np.random.default_rng(11))
        time.sleep(3.0)
        send(TS, url, speed=20.0)
        dropped = set(first["dropped_index"])
        intact = [r for r in ref if not spans[r.offset] & dropped]
        want = len(intact) + len(ref)
        wait_while_growing(lambda: feed.replay.rows_total, want, 60, "every intact packet replayed")
        time.sleep(1.5)  # nothing more comes (a packet twice would show here)
        st = feed.rx.stats
        assert first["dropped"] > 0 and first["duplicated"] > 0 and first["reordered"] > 0, first
        assert feed.replay.rows_total == want and not feed.error, (feed.replay.rows_total, want, feed.error)
        # the rows of pass 1 are exactly the intact packets, in order, decoded as FFmpeg reads the file
        # (the live replay's pts_s is the PES time stamp over 90 kHz: the same division, exact)
        pts = feed.replay.columns()["pts_s"]
        assert pts[: len(intact)].tolist() == [r.pts / 90000 for r in intact]
        assert pts[len(intact) :].tolist() == [r.pts / 90000 for r in ref]
        assert st.cc_errors > 0 and st.duplicates > 0 and st.restarts == 1 and st.stalls >= 1, st
        # the debugger has every one of them that makes a viewer record as a frame (the file view's rule:
        # packet 275 has no sensor angles, in both passes), and the panel says what happened
        from geoloc_viz.scenario import records_from_columns

        frames = len(records_from_columns(feed.replay.columns(), feed.sensor)[0])
        assert want - 4 <= frames <= want, (frames, want)
        wait_while_growing(lambda: tab.n, frames, 60, f"the debugger's frames ({frames} frames)")
        wait_for(lambda: tab.n == frames and tab.current == tab.n - 1, 60, "the debugger on the last frame")
        wait_for(lambda: tab.md_stats.content == feed.stats_markdown(), 10, "the panel to be up to date")
        panel = tab.md_stats.content
        for text in (
            f"{st.cc_errors} TS continuity errors",
            f"{st.duplicates} duplicates",
            f"{st.restarts} restarts",
            f"{st.stalls} stalls",
            f"{st.bad_packets} bad KLV packets",
        ):
            assert text in panel, (text, panel)
    finally:
        viewer.stop()
        server.stop()
