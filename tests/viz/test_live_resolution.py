"""A sender that changes its video resolution mid-stream, as a robust receiver must take it:
counted and reported in the live debugger's stream panel, the picture layer showing both
sizes, every KLV packet used, never a crash.

The stream is made here with PyAV: one H.264 video PID whose first 20 pictures are 320 x 240
and the next 20 are 480 x 272 (a second encoder muxed into the same stream, as an aircraft's
encoder restarting at a new size does: new SPS / PPS at its key frame), and the bundled
flight's first 40 KLV packets at the pictures' time stamps, 10 Hz.
"""

from __future__ import annotations

import time
from fractions import Fraction

import numpy as np

from geoloc.io.klv import Packet, encode_packet, read_klv_file
from test_live import KLV, _bound, free_port
from test_viz_browser import wait_for

SIZES = ((320, 240), (480, 272))
N_EACH = 20
TICKS = 9000  # 10 Hz on the 90 kHz clock


def _stream_with_a_resolution_change(path) -> int:
    import av

    pk = [p for p in read_klv_file(KLV) if isinstance(p, Packet)][: 2 * N_EACH]
    with av.open(str(path), "w", format="mpegts") as out:
        vs = out.add_stream("libx264", rate=10)
        vs.width, vs.height = SIZES[0]
        vs.pix_fmt = "yuv420p"
        vs.time_base = Fraction(1, 90000)
        ds = out.add_data_stream(codec_name="klv")
        k = 0
        for w, h in SIZES:
            enc = av.CodecContext.create("libx264", "w")
            enc.width, enc.height, enc.pix_fmt = w, h, "yuv420p"
            enc.time_base = Fraction(1, 90000)
            enc.framerate = Fraction(10)
            enc.gop_size = 5
            enc.options = {"preset": "ultrafast", "bf": "0", "tune": "zerolatency"}
            for _ in range(N_EACH):
                img = np.zeros((h, w, 3), np.uint8)
                img[:, : (k * 13) % w] = 200  # something that moves
                fr = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format="yuv420p")
                fr.pts = (k + 1) * TICKS
                for p in enc.encode(fr):
                    p.stream = vs
                    out.mux(p)
                kp = av.Packet(encode_packet(pk[k].fields, unknown=pk[k].unknown))
                kp.stream = ds
                kp.pts = kp.dts = (k + 1) * TICKS
                out.mux(kp)
                k += 1
            for p in enc.encode(None):
                p.stream = vs
                out.mux(p)
    return k


def test_a_sender_that_changes_its_resolution_is_counted_in_the_panel(tmp_path):
    import av

    from geoloc.io.live import send
    from geoloc_viz.app import make_server
    from geoloc_viz.live_view import LiveFeed, LiveTab, LiveViewer

    path = tmp_path / "resize.ts"
    n = _stream_with_a_resolution_change(path)
    with av.open(str(path)) as c:  # what FFmpeg itself decodes of the file: both sizes
        sizes = [(f.width, f.height) for f in c.decode(video=0)]
    assert sizes == [SIZES[0]] * N_EACH + [SIZES[1]] * N_EACH, sizes

    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"duration_s": 120})
    server = make_server(port=0)
    viewer = LiveViewer(server, feed)
    shapes = set()
    try:
        tab = LiveTab(viewer.flight, server, None)  # a tab on the server's own scene and panel
        viewer.tabs[-1] = tab
        feed.start()
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        sent = send(path, url, speed=1.0)  # 4 s of stream, real time: the debugger follows it
        t0 = time.monotonic()
        while time.monotonic() - t0 < 30 and (feed.rx.stats.klv_packets < n or tab.n < n):
            im = getattr(tab, "_images", None)
            if im is not None and im.image is not None:
                shapes.add(im.image.shape[:2])
            time.sleep(0.05)
        # the latest frame loaded (a follow step a second at most), its picture the new size
        wait_for(
            lambda: tab.current == tab.n - 1 == n - 1 and tab.session.scn.record_index == n - 1,
            60,
            "the debugger on the last frame",
        )
        wait_for(
            lambda: (
                tab._images is not None and tab._images.image is not None and tab._images.image.shape[:2] == (272, 480)
            ),
            10,
            "the last frame's picture",
        )
        shapes.add(tab._images.image.shape[:2])
        # and a person scrubbing back to a frame before the change gets its picture at the old size
        tab.scrubbed(5)
        tab.layer.go(5)
        shapes.add(tab._images.image.shape[:2])
        assert sent["sent"] == feed.rx.stats.datagrams and feed.rx.stats.klv_packets == n
        assert tab.n == n and not feed.error, feed.error
        # FFmpeg's decoder followed the new size: counted once, the panel says it
        assert feed.video_size == SIZES[1] and feed.resolution_changes == 1 and feed.decode_errors == 0
        wait_for(
            lambda: "video 480 x 272 pixels; 1 resolution change(s), 0 undecodable" in tab.md_stats.content,
            10,
            "the stream panel to report the change",
        )
        # the picture layer showed pictures of both sizes (each at the video's own size: 320 x 240, then
        # 480 x 272), following the stream and scrubbed back
        assert {(240, 320), (272, 480)} <= shapes, shapes
        # every frame located, before and after the change
        assert np.isfinite(tab.layer.model.residual_m).sum() == n
    finally:
        viewer.stop()
        server.stop()


def test_the_last_frame_of_an_ended_stream_has_its_picture():
    """The bundled stream (300 H.264 pictures, a second apart, and its KLV) sent over UDP once: when it
    ends the feed flushes its decoder (the parser's last access unit, the decoder's held frames), so it
    has decoded every picture FFmpeg decodes of the file itself (PyAV, the peer), the newest kept being
    the file's last one, pixel for pixel. Before the flush 298: the last frame of a stream that ended
    never had its picture."""
    import av

    from geoloc.io.live import send
    from geoloc_viz.live_view import LiveFeed, LiveImages
    from test_live import TS

    with av.open(str(TS)) as c:
        frames = [(int(f.pts), f.to_ndarray(format="rgb24")) for f in c.decode(video=0)]
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    feed = LiveFeed(url, limits={"idle_s": 2.0, "duration_s": 120}).start()
    try:
        wait_for(lambda: _bound(port), 20, "the feed to listen")
        send(TS, url, speed=50.0)  # 300 s of stream in 6 s: loopback keeps up at this speed
        wait_for(lambda: feed.done, 60, "the stream to end (2 s idle)")
        assert not feed.error, feed.error
        assert feed.pictures_total == len(frames) and feed.decode_errors == 0, (feed.pictures_total, len(frames))
        serial, pts, img = feed.pictures[-1]
        assert serial == len(frames) - 1 and pts == frames[-1][0]
        assert np.array_equal(img, frames[-1][1])  # the same FFmpeg decoder: the same pixels
        assert not np.array_equal(frames[-2][1], frames[-1][1])  # (the last two pictures differ)
        # the picture layer's source: one time per image, by serial number (the caption's "picture at T s"
        # of a serial past the 64 kept read another picture's time, or none)
        t = LiveImages(feed).times_s
        kept = [p[0] for p in feed.pictures]
        assert len(t) == len(LiveImages(feed)) == len(frames)
        assert np.isfinite(t[kept]).all() and np.isnan(t[: kept[0]]).all()
        assert t[-1] * 90000.0 == frames[-1][0]
    finally:
        feed.stop()
