"""The end of a live stream: the KLV of the last PES, still open when the stream ends, reaches the
callers that take batches (``receive(on_batch=...)``: the live replay, ``geoloc log``, the viewer).

A KLV PES may have no length field (PES_packet_length 0, ISO/IEC 13818-1 Section 2.4.3.7: allowed,
and written by some encoders); such a PES ends only at the next start on its PID, so the stream's
last one is complete only when the receiver is flushed at the end. The stream is built in the test
byte by byte (PAT, PMT with stream type 0x15, one PES per packet with a metadata access-unit cell),
carrying the bundled flight's packets re-encoded: the oracle is what was sent (the encoder's input
fields and the PES time stamps written), not the receiver's output.
"""

from __future__ import annotations

import socket

from test_live import _section, _ts_packets, free_port
from test_live_gaps import TICKS, _klv_packets, _pts_bytes

from geoloc.io.klv import Packet, encode_packet
from geoloc.io.live import LiveReceiver, datagrams_of, open_socket, parse_udp_url, receive


def _unbounded_pes_stream(pts_list, packets) -> bytes:
    """PAT, PMT, then one KLV PES per packet, each with PES_packet_length 0 (ends at the next start)."""
    pat = _section(0x00, bytes([0x00, 0x01, 0xE1, 0x00]))  # program 1 -> PMT PID 0x100
    pmt = _section(0x02, bytes([0xFF, 0xFF, 0xF0, 0x00, 0x15, 0xE1, 0x01, 0xF0, 0x00]))  # 0x15 on PID 0x101
    out = [_ts_packets(0, b"\x00" + pat)[0][0], _ts_packets(0x100, b"\x00" + pmt)[0][0]]
    cc = 0
    for i, (pts, p) in enumerate(zip(pts_list, packets)):
        b = encode_packet(p.fields, unknown=p.unknown)
        cell = bytes([0x00, i & 0xFF, 0xDF]) + len(b).to_bytes(2, "big") + b
        pes = b"\x00\x00\x01\xfc\x00\x00" + bytes([0x84, 0x80, 0x05]) + _pts_bytes(pts) + cell
        pk, cc = _ts_packets(0x101, pes, cc)
        out += pk
    return b"".join(out)


def test_the_last_open_pes_of_an_ended_stream_reaches_on_batch():
    n = 12
    sent = _klv_packets(n)
    pts = [(1000 + k) * TICKS for k in range(n)]
    ts = _unbounded_pes_stream(pts, sent)
    url = parse_udp_url(f"udp://127.0.0.1:{free_port()}")
    sock = open_socket(url)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:  # queued in the kernel before reading
        for g in datagrams_of(ts):
            tx.sendto(g, (url.host, url.port))
    batches: list = []
    rx = LiveReceiver()
    yielded = list(receive(url, receiver=rx, sock=sock, on_batch=batches.append, idle_s=0.5, duration_s=60))
    assert rx.stats.cc_errors == 0 and rx.stats.datagrams == len(datagrams_of(ts))
    given = [r for b in batches for r in b]
    for got in (yielded, given):
        assert all(isinstance(r, Packet) for r in got)
        assert [r.pts for r in got] == pts, f"{len(got)} of {n} packets; the last open PES lost"
        assert [r.fields for r in got] == [p.fields for p in sent]


def test_a_packet_limit_met_by_the_end_flush():
    n = 5
    sent = _klv_packets(n)
    pts = [(1000 + k) * TICKS for k in range(n)]
    ts = _unbounded_pes_stream(pts, sent)
    url = parse_udp_url(f"udp://127.0.0.1:{free_port()}")
    sock = open_socket(url)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for g in datagrams_of(ts):
            tx.sendto(g, (url.host, url.port))
    batches: list = []
    got = list(receive(url, sock=sock, on_batch=batches.append, packets=n, idle_s=0.5, duration_s=60))
    assert len(got) == n == sum(len(b) for b in batches)
