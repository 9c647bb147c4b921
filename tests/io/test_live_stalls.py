"""Stalls of a live stream are counted on the datagrams' arrival times, not on when the receiver
gets to them.

The datagrams are queued in the kernel before the receiver reads any (it reads them back to back, as
a receiver that fell behind under load does): a gap of 1.5 s between two bursts, longer than
``STALL_S``, is one stall; the same datagrams without the gap are none. The oracle is the sender's
own clock (the sleep between the bursts), not the receiver's. Before, the stalls were measured
between the receiver's reads: 0 here, and on a loaded machine ``tests/viz/test_live_panel.py``'s
3 s silence between two passes went uncounted.
"""

from __future__ import annotations

import socket
import time

from test_live import TS, free_port

from geoloc.io.live import STALL_S, LiveReceiver, datagrams_of, open_socket, parse_udp_url, receive


def _wait_for_arrival_stamps(sock: socket.socket, url) -> None:
    """Until the kernel stamps datagrams as they arrive. Linux turns its receive time stamps on
    through a work queue after the first socket asks (net_enable_timestamp): until then a datagram
    is stamped when it is read, and a burst sent at once after open_socket on an idle, loaded
    machine read back to back showed no gap (a CI failure). A probe is sent, read 0.2 s later, and
    its stamp must be older than the read."""
    from geoloc.io.live import _arrival, _clock_offset_s

    t0 = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        while time.monotonic() - t0 < 30:
            tx.sendto(b"probe", (url.host, url.port))
            time.sleep(0.2)
            _, anc, _, _ = sock.recvmsg(64, 64)
            arrived = _arrival(anc, _clock_offset_s())
            if arrived is not None and time.monotonic() - arrived > 0.1:
                return
    raise AssertionError("the kernel never stamped a datagram on arrival within 30 s")


def _stalls(gap_s: float) -> LiveReceiver:
    grams = datagrams_of(TS.read_bytes())[:400]
    url = parse_udp_url(f"udp://127.0.0.1:{free_port()}")
    sock = open_socket(url)
    _wait_for_arrival_stamps(sock, url)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for k, g in enumerate(grams):
            if k == 200 and gap_s:
                time.sleep(gap_s)
            tx.sendto(g, (url.host, url.port))
    rx = LiveReceiver()
    for _ in receive(url, receiver=rx, sock=sock, idle_s=0.5, duration_s=60):
        pass
    assert rx.stats.datagrams == len(grams)
    return rx


def test_a_gap_in_arrival_is_a_stall_even_when_read_back_to_back():
    assert STALL_S < 1.5
    assert _stalls(1.5).stats.stalls == 1


def test_no_gap_no_stall_however_late_they_are_read():
    time.sleep(0.01)
    assert _stalls(0.0).stats.stalls == 0


def test_a_reader_that_falls_behind_reads_what_is_queued_before_idling():
    # idle_s means nothing arrived: a consumer slower than idle_s between two packets (a loaded
    # machine, a slow on_batch) stopped the reception with datagrams still queued in the socket
    grams = datagrams_of(TS.read_bytes())[:400]
    url = parse_udp_url(f"udp://127.0.0.1:{free_port()}")
    sock = open_socket(url)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for g in grams:
            tx.sendto(g, (url.host, url.port))
    rx = LiveReceiver()
    for k, _ in enumerate(receive(url, receiver=rx, sock=sock, idle_s=0.3, duration_s=60)):
        if k == 5:
            time.sleep(0.6)  # the consumer busy for twice idle_s, the rest of the stream queued
    assert rx.stats.datagrams == len(grams)
