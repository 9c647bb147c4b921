"""Live MISB ST 0601 over UDP: an MPEG-TS (STANAG 4609) received datagram by datagram.

A ground station receives the aircraft's transport stream as UDP datagrams, each
normally seven 188-byte TS packets. This module reads them with a plain socket
and demultiplexes them incrementally (:class:`TsDemuxer`, ISO/IEC 13818-1 Section
2.4.3: TS packets, continuity counters, PAT / PMT sections, PES packets) so every
KLV packet is decoded as soon as its PES is complete, with no probing delay and no
end of file to wait for. KLV comes in the two carriages of MISB ST 1402:

* **asynchronous** metadata: stream type 0x06 with the ``KLVA`` registration
  descriptor (private_stream_1 or metadata stream id), the PES payload is KLV;
* **synchronous** metadata: stream type 0x15 (metadata in PES), the payload is a
  sequence of metadata access-unit cells (ISO/IEC 13818-1 Section 2.12.4: a
  5-byte header, then the KLV).

Video PES (MPEG-2, H.264, HEVC: stream types 0x02, 0x1B, 0x24) are kept as access
units with their PTS in a rolling window (:attr:`LiveReceiver.video`), so each
KLV packet can be bound to the nearest-timestamp frame
(:meth:`LiveReceiver.nearest_video_pts`).

Nothing the network does stops the reader: a lost datagram shows as a
continuity-counter jump (counted; the PES it broke is scanned anyway and every
intact KLV packet in it is used, the broken ones fail their checksum and are
reported), a duplicated TS packet is dropped (counted), a datagram that is not
whole TS packets is resynchronised on the sync byte (counted), a PES started
before we joined is skipped (counted), a transport-error packet is dropped, a
PSI section with a bad CRC is ignored, a stream that stops and restarts (its
clock jumps back) is counted as a restart, and a sender that changes its
streams is followed through the new PMT. All of it is in :class:`LiveStats`.
Memory is bounded: partial PES are capped in size, the windows of packets and
video access units have a maximum length.

Safe by default (:func:`open_socket`): the socket binds only the address given;
a multicast group is joined only when the URL's address is a multicast group;
a bind outside loopback prints what is exposed (:func:`exposure_note`).

The sender (:func:`send`, ``python -m geoloc.io.live send FILE.ts udp://HOST:PORT``)
streams a transport-stream file at its own pace (the PTS of its PES packets,
times ``--speed``) or as fast as it can, optionally dropping, duplicating and
reordering datagrams for tests.

References: ISO/IEC 13818-1 (MPEG-2 systems: TS packets, PSI, PES, CRC-32 of
sections, metadata carriage), MISB ST 1402 (MPEG-2 transport of KLV metadata),
MISB ST 0601 (the UAS Datalink Local Set, :mod:`geoloc.io.klv`).
"""

from __future__ import annotations

import argparse
import errno
import ipaddress
import os
import socket
import struct
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import TYPE_CHECKING, Callable, Iterator
from urllib.parse import parse_qs, urlsplit

from geoloc.io.klv import KlvError, Packet, _scan, _ScanState
from geoloc.io.ts_demux import (  # the demultiplexer the receiver runs
    _NO_PES_HEADER_IDS,
    TS_PACKET,
    VIDEO_WINDOW,
    LiveStats,
    TsDemuxer,
    _timestamp,
)

if TYPE_CHECKING:  # numpy is imported where the sender draws its losses
    import numpy as np

__all__ = [
    "TS_PACKET",
    "DATAGRAM_PACKETS",
    "UdpUrl",
    "parse_udp_url",
    "is_stream_url",
    "exposure_note",
    "open_socket",
    "listening",
    "wait_for_listener",
    "LiveStats",
    "LiveReceiver",
    "receive",
    "send",
    "main",
]

#: TS packets per datagram (the usual UDP carriage: 7 x 188 = 1316 bytes, under a 1500-byte MTU).
DATAGRAM_PACKETS = 7
#: The 90 kHz PES clock (PTS, DTS) [s per tick].
PES_TIME_BASE = Fraction(1, 90000)
#: KLV packets kept in :attr:`LiveReceiver.window` (about 10 minutes at 30 Hz).
PACKET_WINDOW = 18000
#: A KLV clock going back by more than this is a restart of the sender [s] (two swapped datagrams
#: at the start of a 1 Hz stream put a packet 1 s back: not a restart).
RESTART_BACK_S = 5.0
#: A datagram that does not continue its streams' counters waits at most this long for the one
#: before it (two swapped datagrams are put back in order) [s].
REORDER_S = 0.1
#: No datagram for longer than this, then one: a stall, counted [s] (on the kernel's arrival times where
#: the socket gives them, so a receiver busy with a backlog neither hides a stall nor makes one).
STALL_S = 1.0
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS, asm-generic/socket.h): each datagram's arrival time in its
#: ancillary data, a struct timespec of CLOCK_REALTIME (Python's socket module does not name it).
_SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("@qq")


# --------------------------------------------------------------------------- addresses


@dataclass(frozen=True)
class UdpUrl:
    """A parsed ``udp://HOST:PORT[?iface=ADDR]``.

    Attributes
    ----------
    host : str
        The address to bind (unicast: one of this machine's addresses, ``0.0.0.0``
        for every interface) or the multicast group to join.
    port : int
    multicast : bool
        True when ``host`` is an IPv4 multicast group (224.0.0.0/4): then, and only
        then, the group is joined.
    iface : str
        Multicast: the interface address to join on (``?iface=``; default
        ``0.0.0.0``, the kernel's choice).
    text : str
        The URL as given.
    """

    host: str
    port: int
    multicast: bool = False
    iface: str = "0.0.0.0"
    text: str = ""

    def __str__(self) -> str:
        return self.text or f"udp://{self.host}:{self.port}"

    @property
    def loopback(self) -> bool:
        """True when only this machine can send to the bound address."""
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return self.host == "localhost"


def is_stream_url(text: str) -> bool:
    """True for ``udp://...`` (a network stream, not a path)."""
    return isinstance(text, str) and text.lower().startswith("udp://")


def parse_udp_url(text: str) -> UdpUrl:
    """``udp://HOST:PORT`` (unicast bind), ``udp://GROUP:PORT`` (multicast, joined), ``udp://@GROUP:PORT``
    (FFmpeg's spelling of the same), ``?iface=ADDR`` for the multicast interface.

    Raises
    ------
    ValueError
        Naming the URL and what is wrong (no port, a port outside 1..65535, a host
        that is not an IPv4 address or ``localhost``, an unknown query field).
    """
    s = str(text)
    if not is_stream_url(s):
        raise ValueError(f"stream URL {s!r}: expected udp://HOST:PORT")
    u = urlsplit(s.replace("udp://@", "udp://", 1))
    host = u.hostname
    try:
        port = u.port
    except ValueError:
        raise ValueError(f"stream URL {s!r}: the port is not a number in 0..65535") from None
    if not host:
        raise ValueError(f"stream URL {s!r}: no host (udp://127.0.0.1:5600 listens on this machine only)")
    if port is None or not 1 <= port <= 65535:
        raise ValueError(f"stream URL {s!r}: give a port in 1..65535 (udp://{host}:5600)")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(f"stream URL {s!r}: host {host!r} is not an IPv4 address") from None
    if addr.version != 4:
        raise ValueError(f"stream URL {s!r}: host {host!r}: only IPv4 is supported")
    q = parse_qs(u.query)
    unknown = set(q) - {"iface", "localaddr"}
    if unknown:
        raise ValueError(f"stream URL {s!r}: unknown query field(s) {', '.join(sorted(unknown))} (known: iface)")
    iface = (q.get("iface") or q.get("localaddr") or ["0.0.0.0"])[0]
    try:
        ipaddress.IPv4Address(iface)
    except ValueError:
        raise ValueError(f"stream URL {s!r}: iface {iface!r} is not an IPv4 address") from None
    if not addr.is_multicast and (q.get("iface") or q.get("localaddr")):
        raise ValueError(f"stream URL {s!r}: iface is for a multicast group; {host} is a unicast address")
    return UdpUrl(host, int(port), addr.is_multicast, iface, s)


def exposure_note(url: UdpUrl) -> str | None:
    """What a bind outside loopback exposes (None on loopback)."""
    if url.loopback:
        return None
    if url.multicast:
        return (
            f"note: joining multicast group {url.host} on port {url.port} (interface {url.iface}): "
            "any host on that network segment that sends to the group feeds this session; the "
            "datagrams are parsed as MPEG-TS / KLV, nothing in them is executed"
        )
    where = "every interface" if url.host == "0.0.0.0" else url.host
    return (
        f"note: listening for UDP on {where}, port {url.port}: any host that can reach this machine "
        "there can send datagrams into this session; they are parsed as MPEG-TS / KLV, nothing in them "
        "is executed (udp://127.0.0.1:PORT listens on this machine only)"
    )


def open_socket(url: UdpUrl, rcvbuf: int = 4 << 20) -> socket.socket:
    """A UDP socket bound to exactly ``url`` (the group joined only for a multicast URL).

    Raises
    ------
    OSError
        The address cannot be bound (in use, not an address of this machine), with
        the URL in the message.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    try:
        if url.multicast:  # several listeners may join one group; a unicast port is ours alone
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, int(rcvbuf))
        except OSError:
            pass
        sock.bind((url.host, url.port))
        _arrival_stamps(sock)  # from the first datagram queued: the kernel stamps it as it comes
        if url.multicast:
            mreq = socket.inet_aton(url.host) + socket.inet_aton(url.iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    except OSError as e:
        sock.close()
        raise OSError(e.errno, f"{url}: cannot listen there: {e.strerror or e}") from None
    return sock


def _proc_udp_listening(host: str, port: int) -> bool | None:
    """Whether a UDP socket of this machine is bound to ``host:port`` (or to any address on that
    port), read from Linux's ``/proc/net/udp`` (local address as the native-order hex of the IPv4
    address, a colon, the port in hex); None where that table cannot be read."""
    try:
        with open("/proc/net/udp", encoding="ascii") as fh:
            lines = fh.read().splitlines()[1:]
    except OSError:
        return None
    want = {f"{int.from_bytes(socket.inet_aton(host), sys.byteorder):08X}", "00000000"}
    for line in lines:
        parts = line.split()
        if len(parts) > 1 and ":" in parts[1]:
            addr, p = parts[1].split(":")
            if int(p, 16) == port and addr.upper() in want:
                return True
    return False


def listening(url: str | UdpUrl) -> bool:
    """True when a program of this machine listens on ``url``'s address and port.

    Read from ``/proc/net/udp`` where there is one: looking never binds the port, so a
    listener starting at that moment cannot find it taken (a probe bind would hold it for an
    instant, and a receiver binding then fails with "Address already in use"). Elsewhere, a
    probe bind: a unicast listener binds without ``SO_REUSEADDR`` (:func:`open_socket`), so
    the probe fails once it is there.
    """
    u = url if isinstance(url, UdpUrl) else parse_udp_url(url)
    seen = _proc_udp_listening(u.host, u.port)
    if seen is not None:
        return seen
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((u.host, u.port))
        except OSError as e:
            return e.errno == errno.EADDRINUSE
    return False


def _own_address(host: str) -> bool:
    """True when this machine can bind ``host`` (one of its own addresses, or a group), tried on
    an ephemeral port so that no listener's port is touched."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((host, 0))
        except OSError:
            return False
    return True


def wait_for_listener(url: str | UdpUrl, timeout_s: float) -> bool:
    """Wait until a program of this machine listens on ``url``'s port (at most ``timeout_s``).

    True when it does (:func:`listening`, which never binds the port); False on timeout, or
    at once for an address this machine cannot bind (not one of its own: nothing to look for).
    """
    u = url if isinstance(url, UdpUrl) else parse_udp_url(url)
    if not _own_address(u.host):
        return False
    t0 = time.monotonic()
    while True:
        if listening(u):
            return True
        if time.monotonic() - t0 >= timeout_s:
            return False
        time.sleep(0.05)


# --------------------------------------------------------------------------- the receiver


class LiveReceiver:
    """Datagrams in, decoded KLV packets out: the demuxer, the KLV scanner, the counts and the windows.

    Use :meth:`push` with each datagram's bytes (or :meth:`push_bytes` with a
    continuous byte stream, e.g. a recorded ``.ts``); each returns the
    :class:`geoloc.io.klv.Packet` and :class:`geoloc.io.klv.KlvError` it completed,
    in arrival order, with the same ``offset`` (byte of the TS packet that started
    the PES, counted from the first byte received), ``pts`` and ``time_base`` as
    :func:`geoloc.io.klv.read_ts_klv` gives for the same bytes read from a file.

    Parameters
    ----------
    verify_checksum : bool
        Check each KLV packet's checksum (MISB ST 0601 tag 1). Default True.
    window : int
        KLV packets kept in :attr:`window` (the oldest go first).
    video_window : int
        Video access units (pts, bytes) kept in :attr:`video`.
    keep_video_data : bool
        Keep the video bytes (for decoding a picture), not only their time stamps.
    """

    def __init__(
        self,
        *,
        verify_checksum: bool = True,
        window: int = PACKET_WINDOW,
        video_window: int = VIDEO_WINDOW,
        keep_video_data: bool = True,
        reorder: bool = True,
        reorder_s: float = REORDER_S,
    ):
        self.stats = LiveStats()
        self.demux = TsDemuxer(self.stats, reorder=reorder, reorder_s=reorder_s, video_window=video_window)
        self.verify = verify_checksum
        self.window: deque = deque(maxlen=int(window))
        self.video: deque = deque(maxlen=int(video_window))  # (pts, bytes or None, pid)
        self.keep_video_data = keep_video_data
        self.first_datagram_s: float | None = None  # time.monotonic()
        self.first_datagram_unix_s: float | None = None  # time.time(), to compare with other clocks
        self.last_datagram_s: float | None = None
        self.last_arrival_s: float | None = None  # time.monotonic() clock, the kernel's arrival time if known
        self._last_klv_pts: int | None = None

    def push(self, datagram: bytes, now: float | None = None, arrived: float | None = None) -> list:
        """One datagram; returns the KLV results it completed.

        ``now``: when it is taken [s, ``time.monotonic()``]; ``arrived``: when it reached this machine, on
        the same clock (the kernel's time stamp, :func:`receive`), default ``now``. Stalls are counted on
        arrival times: a receiver that falls behind reads queued datagrams back to back, and a gap in
        the stream would not show in the times it takes them."""
        now = time.monotonic() if now is None else now
        arrived = now if arrived is None else arrived
        st = self.stats
        if self.first_datagram_s is None:
            self.first_datagram_s = now
            self.first_datagram_unix_s = time.time()
        elif self.last_arrival_s is not None and arrived - self.last_arrival_s > STALL_S:
            st.stalls += 1
        self.last_datagram_s = now
        self.last_arrival_s = arrived
        st.datagrams += 1
        st.bytes += len(datagram)
        self.demux.now = now
        units = self.demux.feed_datagram(datagram)
        return self._units(self.demux.expire(now, units))

    def tick(self, now: float | None = None) -> list:
        """Time passed without data: release the packets held for reordering too long."""
        now = time.monotonic() if now is None else now
        self.demux.now = now
        return self._units(self.demux.expire(now))

    def push_bytes(self, data: bytes) -> list:
        """Bytes of a continuous stream (a ``.ts`` file in chunks); returns the KLV results."""
        self.stats.bytes += len(data)
        return self._units(self.demux.feed(data))

    def flush(self) -> list:
        """The results of the held packets and of the PES still open (the end of the stream)."""
        units = self.demux.expire(float("inf"))
        return self._units(units + self.demux.flush())

    def nearest_video_pts(self, pts: int | None) -> int | None:
        """The PTS of the video frame nearest ``pts`` among those whose start arrived (None if none).

        A frame counts from its first TS packet (its PES header has the PTS; :attr:`TsDemuxer.video_starts`),
        not only once its access unit is complete (:attr:`video`): a video PES has no length, so it
        completes at the next frame's start, and a KLV packet muxed beside its frame would otherwise be
        bound to the frame before (180 of the bundled flight's 299 packets were).
        """
        if pts is None:
            return None
        best, dbest = None, None
        for seq in (self.demux.video_starts, [u[0] for u in self.video]):
            for vp in reversed(seq):  # newest first: live packets bind to recent frames
                if vp is None:
                    continue
                d = abs(vp - pts)
                if dbest is None or d < dbest:
                    best, dbest = vp, d
                elif vp < pts and d > dbest:
                    break
        return best

    def _units(self, units) -> list:
        out = []
        st = self.stats
        for u in units:
            if u.kind == "video":
                st.video_units += 1
                self.video.append((u.pts, u.data if self.keep_video_data else None, u.pid))
                continue
            if not u.data:
                continue
            if (
                u.pts is not None
                and self._last_klv_pts is not None
                and u.pts < self._last_klv_pts - RESTART_BACK_S * 90000
            ):
                st.restarts += 1
            if u.pts is not None:
                self._last_klv_pts = u.pts
            res, _ = _scan(u.data, 0, True, _ScanState(0), self.verify)
            for r in res:
                if isinstance(r, Packet):
                    r.offset, r.pts, r.time_base = u.offset, u.pts, PES_TIME_BASE
                    st.klv_packets += 1
                    self.window.append(r)
                else:
                    r = KlvError(u.offset, r.reason, u.pts)
                    st.bad_packets += 1
                    if "checksum" in r.reason:
                        st.bad_checksums += 1
                out.append(r)
        return out


def _arrival_stamps(sock: socket.socket) -> bool:
    """Ask the kernel for each datagram's arrival time (Linux); False where it cannot give them."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def _clock_offset_s() -> float:
    """``time.time() - time.monotonic()`` [s], the real-time clock read between two monotonic reads,
    the closest pair of five. Read once per datagram, a thread descheduled between the two clocks
    under load moved that one datagram's arrival by as long (a 1.5 s gap read as under 1 s: a stall
    missed in a CI run at load 6)."""
    best_w, best = float("inf"), 0.0
    for _ in range(5):
        m1 = time.monotonic()
        r = time.time()
        m2 = time.monotonic()
        if m2 - m1 < best_w:
            best_w, best = m2 - m1, r - 0.5 * (m1 + m2)
        if best_w < 1e-4:
            break
    return best


class _ClockOffset:
    """:func:`_clock_offset_s`, read again when a second has passed (a clock set meanwhile)."""

    def __init__(self) -> None:
        self.value_s, self.read_at_s = _clock_offset_s(), time.monotonic()

    def now_s(self) -> float:
        now = time.monotonic()
        if now - self.read_at_s > 1.0:
            self.value_s, self.read_at_s = _clock_offset_s(), now
        return self.value_s


def _read_datagram(sock: socket.socket, buf: bytearray, offset: "_ClockOffset | None") -> tuple[int, float | None]:
    """One datagram into ``buf``: its length and arrival (:func:`_arrival`; None unstamped, ``offset`` None)."""
    if offset is None:
        return sock.recv_into(buf), None
    n, anc, _, _ = sock.recvmsg_into([buf], 64)
    return n, _arrival(anc, offset.now_s())


def _idle(rx: "LiveReceiver", idle_s: float | None) -> bool:
    """Whether ``idle_s`` [s] have passed since ``rx`` took its last datagram (never before its first)."""
    return idle_s is not None and rx.last_datagram_s is not None and time.monotonic() - rx.last_datagram_s >= idle_s


def _arrival(ancillary, offset_s: float) -> float | None:
    """A datagram's arrival time on the ``time.monotonic()`` clock, from its SO_TIMESTAMPNS ancillary data
    (CLOCK_REALTIME, moved onto the monotonic clock by ``offset_s``, :class:`_ClockOffset`'s); None
    without one."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return (sec + nsec * 1e-9) - offset_s
    return None


def receive(
    url: str | UdpUrl,
    *,
    duration_s: float | None = None,
    packets: int | None = None,
    idle_s: float | None = None,
    record: Callable[[bytes], object] | None = None,  # its return is not read (a file's write)
    receiver: LiveReceiver | None = None,
    on_batch: Callable[[list], None] | None = None,
    poll_s: float = 0.05,
    announce: Callable[[str], None] | None = None,
    stop: Callable[[], bool] | None = None,
    sock: socket.socket | None = None,
) -> Iterator[Packet | KlvError]:
    """Listen on ``url`` and yield every KLV result as it is decoded.

    Parameters
    ----------
    url : str or UdpUrl
        ``udp://HOST:PORT`` (see :func:`parse_udp_url`).
    duration_s : float, optional
        Stop after this long [s] from the start.
    packets : int, optional
        Stop after this many KLV packets (good and bad).
    idle_s : float, optional
        Stop when nothing arrived for this long [s] after the first datagram.
    record : callable, optional
        Called with each datagram's bytes as it arrives (``--record FILE.ts``).
    receiver : LiveReceiver, optional
        The receiver to use (its counts and windows are the caller's to read).
    poll_s : float
        Socket timeout between checks of the stop conditions [s].
    announce : callable, optional
        Called with the exposure note of a non-loopback bind (default: print to stderr).
    stop : callable, optional
        Polled between datagrams: True stops the reception.
    sock : socket.socket, optional
        A socket already bound by :func:`open_socket` (bind early, so that nothing sent while
        the caller starts up is lost: the kernel queues it); closed at the end.

    Notes
    -----
    Stops on any of the conditions, on ``KeyboardInterrupt`` (then returns
    normally), or never when none is given. At the end the receiver is flushed
    (:meth:`LiveReceiver.flush`): what it completes is yielded and given to
    ``on_batch`` like every other batch.
    """
    u = url if isinstance(url, UdpUrl) else parse_udp_url(url)
    rx = receiver if receiver is not None else LiveReceiver()
    if sock is None:
        note = exposure_note(u)
        if note:
            (announce or (lambda m: print(m, file=sys.stderr, flush=True)))(note)
        sock = open_socket(u)
    sock.settimeout(poll_s)
    offset = _ClockOffset() if _arrival_stamps(sock) else None
    t0 = time.monotonic()
    got = 0
    buf = bytearray(65536)
    try:
        while True:
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            if stop is not None and stop():
                break
            try:
                n, arrived = _read_datagram(sock, buf, offset)
            except socket.timeout:  # idle only when nothing is queued (not when the reader fell behind)
                if _idle(rx, idle_s):
                    break
                res = rx.tick()  # no datagram: what is due (a stalled stream's held packets)
            except InterruptedError:
                continue
            else:
                data = bytes(buf[:n])
                if record is not None:
                    record(data)
                res = rx.push(data, arrived=arrived)
            if on_batch is not None and res:
                on_batch(res)
            for r in res:
                yield r
                got += 1
                if packets is not None and got >= packets:
                    return
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
    # the end of the stream: the held datagram and the PES still open (one with no length field ends only
    # at the next start on its PID, so the stream's last one is complete only now), to ``on_batch`` as well
    res = rx.flush()
    if packets is not None:
        res = res[: max(packets - got, 0)]
    if on_batch is not None and res:
        on_batch(res)
    yield from res


# --------------------------------------------------------------------------- the sender


def _pes_pts_at(data: bytes) -> list:
    """For each TS packet of ``data``: the PTS of the PES its payload belongs to (None if unknown)."""
    out = []
    cur: dict = {}
    for i in range(0, len(data) - TS_PACKET + 1, TS_PACKET):
        pid = ((data[i + 1] & 0x1F) << 8) | data[i + 2]
        afc = (data[i + 3] >> 4) & 3
        p = i + 4 + (1 + data[i + 4] if afc & 2 else 0)
        if data[i] == 0x47 and data[i + 1] & 0x40 and afc & 1 and p + 14 <= i + TS_PACKET:
            if data[p : p + 3] == b"\x00\x00\x01" and data[p + 3] not in _NO_PES_HEADER_IDS and data[p + 7] & 0x80:
                cur[pid] = _timestamp(data, p + 9)
            else:
                cur[pid] = None
        out.append(cur.get(pid) if afc & 1 else None)
    return out


def _datagram_times(data: bytes, per: int) -> list:
    """Each datagram's send time on the PES clock: the earliest PTS of the PES it carries bytes of
    (the rest of a PES leaves with its start, as a multiplexer sends it), None where it has none."""
    at = _pes_pts_at(data)
    out = []
    for k in range(0, len(at), per):
        ts = [t for t in at[k : k + per] if t is not None]
        out.append(min(ts) if ts else None)
    return out


def datagrams_of(data: bytes, per: int = DATAGRAM_PACKETS) -> list[bytes]:
    """``data`` (a TS file's bytes) cut into datagrams of ``per`` TS packets."""
    size = per * TS_PACKET
    return [data[k : k + size] for k in range(0, len(data), size)]


def klv_as_ts(path: str | os.PathLike[str]) -> tuple[bytes, int, int]:
    """A raw KLV file (concatenated packets) as the MPEG-TS a receiver decodes: (TS bytes, packets
    wrapped, packets left out).

    Every packet the reader decodes (ST 0601 and EG 0104, quirks and all) goes byte for byte
    into one PES of an asynchronous KLV stream (stream type 0x06, ``KLVA`` registration: MISB
    ST 1402), written by :func:`geoloc.io.klv.write_ts`; packets the reader refuses (a bad
    checksum, truncated) are left out, as a receiver would drop them. The PES time stamps are
    the packets' Precision Time Stamps (tag 2) from the first, when every packet has one and
    they never go back, else 30 a second, so ``send`` paces them as they were recorded.

    Raises
    ------
    ValueError
        No packet of the file can be decoded (nothing a receiver could use).
    """
    import tempfile

    from geoloc.io.klv import Packet, _packet_end, read_klv_file, write_ts

    data = open(os.fspath(path), "rb").read()
    blobs, stamps, bad = [], [], 0
    for r in read_klv_file(path):
        if not isinstance(r, Packet):
            bad += 0 if r.reason.endswith("are not a UAS LS packet") else 1
            continue
        off = r.offset
        assert off is not None  # a file's reader gives each packet its byte offset
        blobs.append(data[off : off + _packet_end(data[off : off + 26])])
        stamps.append(r.fields.get("precision_time_stamp_us"))
    if not blobs:
        raise ValueError(
            f"{path}: no packet of it can be decoded ({bad} bad): nothing a receiver could use "
            "(geoloc klv dump names what is wrong with each)"
        )
    pts = None
    us = [t for t in stamps if isinstance(t, int)]
    if len(us) == len(stamps) and all(b >= a for a, b in zip(us, us[1:])):
        pts = [(t - us[0]) * 9 // 100 for t in us]  # microseconds -> 90 kHz ticks
    with tempfile.TemporaryDirectory(prefix="geoloc-klv-send-") as d:
        ts = os.path.join(d, "klv.ts")
        write_ts(ts, blobs, pts=pts)
        with open(ts, "rb") as f:
            return f.read(), len(blobs), bad


def send(
    source: str | os.PathLike[str] | bytes,
    url: str | UdpUrl,
    *,
    speed: float | None = 1.0,
    per: int = DATAGRAM_PACKETS,
    loss: float = 0.0,
    reorder: float = 0.0,
    duplicate: float = 0.0,
    rng: np.random.Generator | None = None,
    start_delay_s: float = 0.0,
    sock: socket.socket | None = None,
    stop: Callable[[], bool] | None = None,
) -> dict:
    """Stream a transport stream to ``url`` as UDP datagrams of ``per`` TS packets.

    Parameters
    ----------
    source : path or bytes
        A ``.ts`` file (or its bytes).
    url : str or UdpUrl
        Where to send (``udp://127.0.0.1:5600``; a multicast group with TTL 1, out of ``?iface=``).
    speed : float or None
        Pace: each datagram that starts a PES leaves at its PTS (from the first one)
        divided by ``speed``: 1 is real time, 10 ten times faster; None: as fast as
        possible (with a short pause every 64 datagrams so a loopback receiver keeps up).
    per : int
        TS packets per datagram (default 7).
    loss, reorder, duplicate : float
        For tests: the fraction of datagrams dropped, swapped with the next one, sent
        twice (``rng`` draws them). No swap within two datagrams of a drop (there raw
        UDP's 4-bit TS counters cannot tell the pair's order, see
        :meth:`TsDemuxer.feed_datagram`).
    rng : numpy.random.Generator, optional
    stop : callable, optional
        Polled before each datagram: True ends the stream there (the rest is not sent).

    Returns
    -------
    dict
        ``sent``, ``dropped``, ``reordered``, ``duplicated`` counts, ``dropped_index``
        (indices of the dropped datagrams in the file) and ``first_sent_s`` (the
        ``time.monotonic()`` of the first datagram sent).
    """
    import numpy as np

    u = url if isinstance(url, UdpUrl) else parse_udp_url(url)
    if isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
    else:
        with open(os.fspath(source), "rb") as f:
            data = f.read()
    if speed is not None and not speed > 0:
        raise ValueError(f"speed = {speed!r}: must be > 0 (or None: as fast as possible)")
    grams = datagrams_of(data, per)
    rng = rng if rng is not None else np.random.default_rng(0)
    n = len(grams)
    drop = rng.random(n) < loss if loss else np.zeros(n, bool)
    swap = rng.random(n) < reorder if reorder else np.zeros(n, bool)
    dup = rng.random(n) < duplicate if duplicate else np.zeros(n, bool)
    near = np.convolve(drop, np.ones(5), "same") > 0 if n else drop  # within two datagrams of a loss
    order = list(range(n))
    k = 0
    reordered = 0
    while k < n - 1:
        if swap[k] and not near[k] and not near[k + 1]:
            order[k], order[k + 1] = order[k + 1], order[k]
            reordered += 1
            k += 2
        else:
            k += 1
    pts = _datagram_times(data, per)
    own = sock is None
    if sock is None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        if u.multicast:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
            if u.iface != "0.0.0.0":  # ?iface=: out of that interface (127.0.0.1: this machine only)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(u.iface))
    dest = (u.host, u.port)
    if start_delay_s:
        time.sleep(start_delay_s)
    t0 = None
    p0 = None
    sent = dups = 0
    first = None
    try:
        for j, k in enumerate(order):
            if stop is not None and stop():
                break
            if speed is not None and pts[k] is not None:
                if p0 is None:
                    p0 = pts[k]
                    t0 = time.monotonic()
                wait = t0 + (pts[k] - p0) / 90000.0 / speed - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            elif speed is None and j and j % 64 == 0:
                time.sleep(0.001)
            if drop[k]:
                continue
            sock.sendto(grams[k], dest)
            if first is None:
                first = time.monotonic()
            sent += 1
            if dup[k]:
                sock.sendto(grams[k], dest)
                dups += 1
    finally:
        if own:
            sock.close()
    return {
        "sent": sent,
        "dropped": int(drop.sum()),
        "reordered": reordered,
        "duplicated": dups,
        "dropped_index": [int(i) for i in np.flatnonzero(drop)],
        "datagrams": n,
        "first_sent_s": first,
    }


# --------------------------------------------------------------------------- python -m geoloc.io.live


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m geoloc.io.live send FILE.ts udp://HOST:PORT [--speed X | --fast] [--loop N]``."""
    p = argparse.ArgumentParser(
        prog="python -m geoloc.io.live",
        description="Stream an MPEG-TS file (STANAG 4609: video + MISB ST 0601 KLV) "
        "to a UDP address, 7 TS packets a datagram, paced by its time stamps.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    s = sub.add_parser("send", help="stream a .ts file to udp://HOST:PORT")
    s.add_argument("file", metavar="FILE.ts")
    s.add_argument("url", metavar="udp://HOST:PORT")
    s.add_argument("--speed", type=float, default=1.0, help="pace: 1 = real time (default), 10 = ten times faster")
    s.add_argument("--fast", action="store_true", help="as fast as possible (no pacing)")
    s.add_argument("--loop", type=int, default=1, help="send the file this many times (default 1)")
    s.add_argument("--loss", type=float, default=0.0, help="test: fraction of datagrams dropped")
    s.add_argument("--reorder", type=float, default=0.0, help="test: fraction of datagrams swapped")
    args = p.parse_args(argv)
    if args.action != "send":
        p.print_help(sys.stderr)
        return 2
    try:
        for _ in range(max(args.loop, 1)):
            r = send(args.file, args.url, speed=None if args.fast else args.speed, loss=args.loss, reorder=args.reorder)
            print(
                f"sent {r['sent']} datagrams of {args.file} to {args.url} ({r['dropped']} dropped, "
                f"{r['reordered']} reordered)",
                file=sys.stderr,
            )
    except KeyboardInterrupt:
        return 0
    except (ValueError, OSError) as e:
        print(f"python -m geoloc.io.live: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
