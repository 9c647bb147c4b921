"""Each live picture carries its own access unit's time stamp, and the stream's last one comes out.

The bundled stream (300 H.264 pictures, a second apart, and its KLV) is pushed through a live feed's
receiver as a byte stream, in datagram-sized pieces, the feed decoding after each piece as it does
between datagrams; no socket traffic, no thread, no clock: what is checked does not depend on the
machine's load. The oracle is FFmpeg's own demuxer and decoder reading the file (PyAV): every
picture the feed keeps must be, pixel for pixel, the picture FFmpeg gives for the same presentation
time stamp. Fed the units' bytes through FFmpeg's parser (which hands a unit out only when the next
one starts), each picture had been stamped with the next unit's time: one frame (1 s here) late.
"""

from __future__ import annotations

import numpy as np

from test_live import TS, free_port


def test_each_live_picture_has_its_own_units_time_stamp_and_the_last_comes_out():
    import av

    from geoloc.io.live import DATAGRAM_PACKETS, TS_PACKET, open_socket, parse_udp_url
    from geoloc_viz.live_view import LiveFeed

    with av.open(str(TS)) as c:
        want = {int(f.pts): f.to_ndarray(format="rgb24") for f in c.decode(video=0)}
    assert len(want) == 300
    url = f"udp://127.0.0.1:{free_port()}"
    feed = LiveFeed(url, sock=open_socket(parse_udp_url(url)), decode_video=True)
    seen: list = []
    keep = feed._keep

    def check(picture):  # each picture as the feed keeps it: FFmpeg's picture of the same time stamp
        serial, pts, img = picture
        seen.append((pts, pts in want and np.array_equal(img, want[pts])))
        keep(picture)

    feed._keep = check  # type: ignore[method-assign]
    try:
        data = TS.read_bytes()
        step = DATAGRAM_PACKETS * TS_PACKET
        for k in range(0, len(data), step):
            feed.rx.push_bytes(data[k : k + step])
            feed._decode()
        feed.rx.flush()  # the end of the stream: the last video PES (no length field) completes now
        feed._decode(end=True)
    finally:
        feed.stop()
    assert feed.decode_errors == 0
    assert [p for p, _ in seen] == sorted(want), "one picture per access unit, in order"
    wrong = [p / 90000 for p, ok in seen if not ok]
    assert not wrong, f"{len(wrong)} pictures are not FFmpeg's picture of their time stamp: {wrong[:5]} s"
