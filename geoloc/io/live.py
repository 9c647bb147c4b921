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
import sys
import time
from collections import deque
from dataclasses import dataclass, fields
from fractions import Fraction
from typing import Callable, Iterator
from urllib.parse import parse_qs, urlsplit

from geoloc.io.klv import EG0104_KEY, UAS_LS_KEY, KlvError, Packet, _scan, _ScanState

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
    "PesUnit",
    "TsDemuxer",
    "LiveStats",
    "LiveReceiver",
    "receive",
    "send",
    "main",
]

#: Bytes of one MPEG-TS packet (ISO/IEC 13818-1 Section 2.4.3.2).
TS_PACKET = 188
#: TS packets per datagram (the usual UDP carriage: 7 x 188 = 1316 bytes, under a 1500-byte MTU).
DATAGRAM_PACKETS = 7
#: The 90 kHz PES clock (PTS, DTS) [s per tick].
PES_TIME_BASE = Fraction(1, 90000)
#: A partial PES longer than this is dropped (counted) [bytes]: KLV and video.
MAX_PES = {"klv": 1 << 20, "video": 8 << 20}
#: Video access units kept for binding KLV packets to frames (about 10 minutes at 30 Hz).
VIDEO_WINDOW = 18000
#: KLV packets kept in :attr:`LiveReceiver.window` (about 10 minutes at 30 Hz).
PACKET_WINDOW = 18000
#: A KLV clock going back by more than this is a restart of the sender [s] (two swapped datagrams
#: at the start of a 1 Hz stream put a packet 1 s back: not a restart).
RESTART_BACK_S = 5.0
#: A datagram that does not continue its streams' counters waits at most this long for the one
#: before it (two swapped datagrams are put back in order) [s].
REORDER_S = 0.1
#: No datagram for longer than this, then one: a stall, counted [s].
STALL_S = 1.0

_STREAM_TYPES_VIDEO = {0x01: "mpeg1video", 0x02: "mpeg2video", 0x10: "mpeg4", 0x1B: "h264", 0x24: "hevc"}
_KLV_STREAM_IDS = (0xBD, 0xFC)  # private_stream_1, metadata_stream (ISO/IEC 13818-1 Table 2-22)
_NO_PES_HEADER_IDS = {0xBC, 0xBE, 0xBF, 0xF0, 0xF1, 0xF2, 0xF8, 0xFF}


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


def is_stream_url(text) -> bool:
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
        return (f"note: joining multicast group {url.host} on port {url.port} (interface {url.iface}): "
                "any host on that network segment that sends to the group feeds this session; the "
                "datagrams are parsed as MPEG-TS / KLV, nothing in them is executed")
    where = "every interface" if url.host == "0.0.0.0" else url.host
    return (f"note: listening for UDP on {where}, port {url.port}: any host that can reach this machine "
            "there can send datagrams into this session; they are parsed as MPEG-TS / KLV, nothing in them "
            "is executed (udp://127.0.0.1:PORT listens on this machine only)")


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


def listening(url) -> bool:
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


def wait_for_listener(url, timeout_s: float) -> bool:
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


# --------------------------------------------------------------------------- the demuxer


def _crc32_table():
    t = []
    for i in range(256):
        c = i << 24
        for _ in range(8):
            c = ((c << 1) ^ 0x04C11DB7) if c & 0x80000000 else (c << 1)
        t.append(c & 0xFFFFFFFF)
    return t


_CRC_TABLE = _crc32_table()


def crc32_mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 of a PSI section (ISO/IEC 13818-1 Annex A): 0 over a whole section with its CRC."""
    c = 0xFFFFFFFF
    t = _CRC_TABLE
    for b in data:
        c = ((c << 8) & 0xFFFFFFFF) ^ t[((c >> 24) ^ b) & 0xFF]
    return c


@dataclass
class PesUnit:
    """One PES packet of an elementary stream we keep.

    Attributes
    ----------
    kind : str
        ``"klv"`` or ``"video"``.
    pid : int
    stream_type : int
        From the PMT (0 when the PID was taken before any PMT, by its stream id).
    pts, dts : int or None
        90 kHz clock ticks.
    data : bytes
        The PES payload (for synchronous KLV: the cells' data, headers removed).
    offset : int
        Byte offset, in the stream, of the TS packet that started the PES.
    damaged : bool
        A TS packet of it was lost or cut (continuity error, short payload).
    """

    kind: str
    pid: int
    stream_type: int
    pts: int | None
    dts: int | None
    data: bytes
    offset: int
    damaged: bool = False

    @property
    def time_s(self) -> float | None:
        return None if self.pts is None else self.pts / 90000.0


@dataclass
class LiveStats:
    """Counts of what arrived and of what the network did to it (all start at 0).

    ``datagrams`` and ``bytes`` received; ``ts_packets`` parsed; ``cc_errors``
    continuity-counter jumps (a lost, reordered or cut TS packet);
    ``duplicates`` repeated TS packets dropped; ``resyncs`` times the sync byte
    was searched for (a datagram that is not whole TS packets), ``skipped_bytes``
    bytes dropped doing so; ``transport_errors`` packets with the error
    indicator; ``psi_errors`` PAT / PMT sections with a bad CRC; ``orphans`` PES
    fragments whose start was never seen; ``damaged_pes`` PES scanned despite a
    loss; ``oversize`` PES dropped for size; ``klv_packets`` good KLV packets,
    ``bad_packets`` bad ones (checksum, truncated, ...), ``bad_checksums`` those
    of them failing the checksum; ``video_units`` video access units;
    ``restarts`` KLV clock jumps back (a sender restarted); ``stalls`` gaps of
    more than :data:`STALL_S` between datagrams; ``pmt_changes`` new PMT
    versions (a sender that changed its streams, e.g. its resolution).
    """

    datagrams: int = 0
    bytes: int = 0
    ts_packets: int = 0
    cc_errors: int = 0
    duplicates: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0
    transport_errors: int = 0
    psi_errors: int = 0
    orphans: int = 0
    damaged_pes: int = 0
    oversize: int = 0
    klv_packets: int = 0
    bad_packets: int = 0
    bad_checksums: int = 0
    video_units: int = 0
    restarts: int = 0
    stalls: int = 0
    pmt_changes: int = 0

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def line(self) -> str:
        """One line: what arrived, what was lost."""
        return (f"{self.datagrams} datagrams, {self.klv_packets} KLV packets ({self.bad_packets} bad, "
                f"{self.bad_checksums} bad checksums), {self.video_units} video frames; "
                f"{self.cc_errors} TS continuity errors, {self.duplicates} duplicates, {self.resyncs} resyncs, "
                f"{self.orphans} orphan PES fragments, {self.restarts} restarts, {self.stalls} stalls")

    def markdown(self) -> str:
        """The loss panel's text."""
        return ("| received | lost / bad |\n|---|---|\n"
                f"| {self.datagrams} datagrams | {self.cc_errors} TS continuity errors |\n"
                f"| {self.klv_packets} KLV packets | {self.bad_packets} bad KLV packets "
                f"({self.bad_checksums} checksums) |\n"
                f"| {self.video_units} video frames | {self.duplicates} duplicates, {self.resyncs} resyncs |\n"
                f"| {self.ts_packets} TS packets | {self.orphans} orphan PES, {self.damaged_pes} damaged PES |\n"
                f"| {self.restarts} restarts | {self.stalls} stalls, {self.transport_errors} TS errors |")


class _PesBuf:
    __slots__ = ("parts", "size", "offset", "damaged", "expected")

    def __init__(self, offset):
        self.parts = []
        self.size = 0
        self.offset = offset
        self.damaged = False
        self.expected = 0  # total PES bytes from its length field (0: unbounded, ends at the next start)


class TsDemuxer:
    """An incremental MPEG-TS demultiplexer of the KLV and video streams (ISO/IEC 13818-1 Section 2.4.3).

    Feed it bytes as they come (:meth:`feed`: a byte stream, a TS packet may span two
    calls; :meth:`feed_datagram`: one UDP datagram, whole packets expected); each call
    returns the :class:`PesUnit` completed by it. A PES with a length field is complete
    when its last byte arrives; one without, at the next start on its PID (or at
    :meth:`flush`).

    Parameters
    ----------
    stats : LiveStats, optional
        Where to count (a new one by default).
    keep_video : bool
        Return video PES (default True); False drops them unassembled.
    """

    def __init__(self, stats: LiveStats | None = None, keep_video: bool = True, reorder: bool = True,
                 reorder_s: float = 0.1, video_window: int = VIDEO_WINDOW):
        self.stats = stats if stats is not None else LiveStats()
        #: PTS of the video PES whose start (its header) arrived, newest last: a frame's time is known
        #: from its first TS packet, while the PES itself (no length field) completes only at the next
        #: frame's start, after the KLV packet of the same time has come
        self.video_starts: deque = deque(maxlen=int(video_window))
        self.reorder = bool(reorder)
        self.reorder_s = float(reorder_s)
        self.keep_video = keep_video
        self.pos = 0  # bytes of the stream consumed (the offset of the next byte)
        self._carry = b""
        self._cc: dict[int, int] = {}
        self._recent: dict[int, deque] = {}
        self._pes: dict[int, _PesBuf] = {}
        self._psi: dict[int, bytearray] = {}
        self.pmt_pids: set[int] = set()
        self.streams: dict[int, tuple[str, int]] = {}  # pid -> (kind, stream_type)
        self._pmt_version: dict[int, int] = {}
        self._held = None  # (datagram, time) held for reordering
        self._seen: deque = deque(maxlen=16)
        self._seen_data: deque = deque(maxlen=16)
        self.now = 0.0

    # ---------------------------------------------------------------- input
    def feed_datagram(self, data: bytes) -> list[PesUnit]:
        """One datagram: whole TS packets expected; a cut one is resynchronised and its rest dropped.

        A repeated datagram (the same bytes as one of the last 16) is dropped. With
        ``reorder``, a datagram that does not continue the counters of its PIDs is held
        (one at most) until the next one: if that one fills the gap, both are taken in
        their order (two swapped datagrams put back), else the held one is taken as it is
        (a loss, counted); :meth:`expire` takes it when no datagram follows in ``reorder_s``.
        """
        data = bytes(data)
        h = hash(data)
        if h in self._seen and data in self._seen_data:
            self.stats.duplicates += 1
            return []
        self._seen.append(h)
        self._seen_data.append(data)
        if not self.reorder:
            return self._datagram(data)
        out: list[PesUnit] = []
        if self._held is not None:
            held, self._held = self._held[0], None
            if self._first(data, held):  # the one that was missing (or nearer it): it goes first
                out += self._datagram(data)
                out += self._datagram(held)
                return out
            out += self._datagram(held)
        if self._gap(data) == 0:
            out += self._datagram(data)
        else:
            self._held = (data, self.now)
        return out

    def _datagram(self, data: bytes) -> list[PesUnit]:
        if self._carry:
            self.stats.skipped_bytes += len(self._carry)
            self._carry = b""
        out = self._feed(data)
        if self._carry:  # a datagram ends on a whole packet: the rest is a cut packet
            self.stats.skipped_bytes += len(self._carry)
            self.pos += len(self._carry)
            self._carry = b""
        return out

    def feed(self, data: bytes) -> list[PesUnit]:
        """Bytes of a continuous stream (a file read in chunks)."""
        return self._feed(self._carry + bytes(data) if self._carry else bytes(data))

    def flush(self) -> list[PesUnit]:
        """The PES still open (end of the stream)."""
        out = []
        for pid in list(self._pes):
            u = self._finish(pid)
            if u is not None:
                out.append(u)
        return out

    def _feed(self, buf: bytes) -> list[PesUnit]:
        out: list[PesUnit] = []
        n = len(buf)
        i = 0
        base = self.pos  # the first byte of buf (a carried partial packet, then the new bytes)
        self._carry = b""
        while i + TS_PACKET <= n:
            if buf[i] != 0x47:
                j = self._resync(buf, i + 1)
                self.stats.resyncs += 1
                self.stats.skipped_bytes += j - i
                i = j
                continue
            self._packet(buf, i, base + i, out)
            i += TS_PACKET
        self._carry = buf[i:]
        self.pos = base + n - len(self._carry)
        return out

    @staticmethod
    def _resync(buf: bytes, start: int) -> int:
        """The next offset holding a sync byte followed by another one a packet later (or the last sync byte)."""
        n = len(buf)
        i = start
        while True:
            i = buf.find(b"\x47", i)
            if i < 0:
                return n
            if i + TS_PACKET >= n or buf[i + TS_PACKET] == 0x47:
                return i
            i += 1

    # ---------------------------------------------------------------- one TS packet
    def _packet(self, buf: bytes, i: int, offset: int, out: list) -> None:
        st = self.stats
        st.ts_packets += 1
        b1, b3 = buf[i + 1], buf[i + 3]
        pid = ((b1 & 0x1F) << 8) | buf[i + 2]
        if b1 & 0x80:  # transport_error_indicator
            st.transport_errors += 1
            if pid in self._pes:
                self._pes[pid].damaged = True
            return
        if pid == 0x1FFF:  # null packets
            return
        afc = (b3 >> 4) & 3
        if not afc & 1:
            return  # adaptation field only: no payload, the counter does not move
        pkt = buf[i:i + TS_PACKET]
        cc = b3 & 0x0F
        discontinuity = afc & 2 and pkt[4] and pkt[5] & 0x80
        last = self._cc.get(pid)
        if last is None or discontinuity or cc == (last + 1) & 0x0F:
            self._take(pid, cc, pkt, offset, out)
            return
        if (cc, pkt) in self._recent.get(pid, ()):
            st.duplicates += 1  # a duplicate packet (allowed once, ISO/IEC 13818-1 2.4.3.3): dropped
            return
        st.cc_errors += 1  # a packet lost (or one of another datagram's order, not put back)
        self._damage(pid)
        self._take(pid, cc, pkt, offset, out)

    def expire(self, now: float, out: list | None = None) -> list:
        """Process the datagram held for reordering once it waited ``reorder_s`` (time passed without data)."""
        out = [] if out is None else out
        if self._held is not None and now - self._held[1] > self.reorder_s:
            held, self._held = self._held[0], None
            out += self._datagram(held)
        return out

    def _counters(self, data: bytes):
        """(first counter, packets) per PID of the payload packets of ``data``; None for a cut datagram."""
        cc, count = {}, {}
        for i in range(0, len(data) - TS_PACKET + 1, TS_PACKET):
            if data[i] != 0x47:
                return None
            if not data[i + 3] & 0x10:
                continue
            pid = ((data[i + 1] & 0x1F) << 8) | data[i + 2]
            count[pid] = count.get(pid, 0) + 1
            if pid not in cc:
                cc[pid] = data[i + 3] & 0x0F
        return cc, count

    def _gap(self, data: bytes) -> int:
        """TS packets missing before ``data`` on its PIDs (counter steps; 0: it continues every one)."""
        c = self._counters(data)
        if c is None:
            return 0  # a cut datagram: nothing to gain by holding it
        return sum((v - self._cc[pid] - 1) & 0x0F for pid, v in c[0].items() if pid in self._cc)

    def _first(self, data: bytes, held: bytes) -> bool:
        """True when ``data`` (just come) goes before ``held`` (both do not continue the stream).

        It does when it continues every counter, or when the slow PIDs both carry (at most
        two packets in each: PAT, PMT, KLV) say it is nearer. The 4-bit counters wrap every
        16 packets and a video PID moves up to 7 a datagram, so with a datagram lost next to
        two swapped ones and only video in common, the order is not known: arrival order.
        """
        if self._gap(data) == 0:
            return True
        a, b = self._counters(data), self._counters(held)
        if a is None or b is None:
            return False
        da = db = 0
        common = False
        for pid, v in a[0].items():
            if pid in b[0] and pid in self._cc and a[1][pid] <= 2 and b[1][pid] <= 2:
                last = self._cc[pid]
                da += (v - last - 1) & 0x0F
                db += (b[0][pid] - last - 1) & 0x0F
                common = True
        return common and da < db

    def _take(self, pid: int, cc: int, pkt: bytes, offset: int, out: list) -> None:
        """One TS packet in its order: PSI or PES assembly."""
        st = self.stats
        self._cc[pid] = cc
        r = self._recent.get(pid)
        if r is None:
            r = self._recent[pid] = deque(maxlen=8)  # 8 < 16: a packet repeated a counter cycle later is new
        r.append((cc, pkt))
        pusi = pkt[1] & 0x40
        p = 4
        if pkt[3] & 0x20:
            alen = pkt[4]
            if alen > 183:
                st.transport_errors += 1
                return
            p += 1 + alen
        end = TS_PACKET
        buf = pkt
        payload = buf[p:end]
        if pid == 0 or pid in self.pmt_pids:
            self._section(pid, payload, pusi)
            return
        kind = self.streams.get(pid, (None, 0))[0]
        if kind == "video" and not self.keep_video:
            return
        if pusi:
            if pid in self._pes:
                u = self._finish(pid)
                if u is not None:
                    out.append(u)
            if kind is None:
                # no PMT yet (joined mid-stream, lost, or a stream written without PAT / PMT): a
                # metadata / private stream PES is taken as KLV (the UAS LS key check in the scanner
                # rejects anything else), and so is any PES whose data starts with a UAS LS or an
                # EG 0104 key (directly, or after a metadata access-unit cell header)
                if len(payload) >= 4 and payload[:3] == b"\x00\x00\x01" and \
                        (payload[3] in _KLV_STREAM_IDS or _starts_with_klv(payload)):
                    self.streams[pid] = ("klv", 0)
                else:
                    return
            b = _PesBuf(offset)
            if len(payload) >= 6 and payload[:3] == b"\x00\x00\x01":
                ln = (payload[4] << 8) | payload[5]
                b.expected = 6 + ln if ln else 0
                if kind == "video" and len(payload) >= 14 and payload[3] not in _NO_PES_HEADER_IDS \
                        and payload[7] & 0x80 and payload[8] >= 5:
                    self.video_starts.append(_timestamp(payload, 9))
            self._pes[pid] = b
        elif kind is None:
            return
        b = self._pes.get(pid)
        if b is None:
            st.orphans += 1  # a PES whose start we never saw (joined mid-PES, or its first packet lost)
            return
        b.parts.append(payload)
        b.size += len(payload)
        if b.size > MAX_PES.get(kind, 1 << 20):
            st.oversize += 1
            del self._pes[pid]
            return
        if b.expected and b.size >= b.expected:
            u = self._finish(pid)
            if u is not None:
                out.append(u)

    def _damage(self, pid: int) -> None:
        b = self._pes.get(pid)
        if b is not None:
            b.damaged = True

    def _finish(self, pid: int) -> PesUnit | None:
        b = self._pes.pop(pid)
        kind, stype = self.streams.get(pid, ("klv", 0))
        data = b"".join(b.parts)
        if b.expected and len(data) > b.expected:
            data = data[:b.expected]
        elif b.expected and len(data) < b.expected:
            b.damaged = True
        if len(data) < 6 or data[:3] != b"\x00\x00\x01":
            self.stats.orphans += 1
            return None
        sid = data[3]
        pts = dts = None
        if sid in _NO_PES_HEADER_IDS:
            body = data[6:]
        else:
            if len(data) < 9:
                return None
            flags, hlen = data[7], data[8]
            h = data[9:9 + hlen]
            if flags & 0x80 and len(h) >= 5:
                pts = _timestamp(h, 0)
            if flags & 0x40 and len(h) >= 10:
                dts = _timestamp(h, 5)
            body = data[9 + hlen:]
        if kind == "klv" and (stype == 0x15 or (stype == 0 and body[:4] != _KLV_PREFIX
                                                 and body[5:9] == _KLV_PREFIX)):
            body = _metadata_cells(body)  # synchronous metadata (or, with no PMT, cells before a key)
        if b.damaged:
            self.stats.damaged_pes += 1
        return PesUnit(kind, pid, stype, pts, dts, body, b.offset, b.damaged)

    # ---------------------------------------------------------------- PSI
    def _section(self, pid: int, payload: bytes, pusi) -> None:
        if pusi:
            ptr = payload[0]
            prev = self._psi.get(pid)
            if prev is not None and ptr:
                prev += payload[1:1 + ptr]
                self._try_section(pid, prev)
            self._psi[pid] = bytearray(payload[1 + ptr:])
        elif pid in self._psi:
            self._psi[pid] += payload
        else:
            return
        self._try_section(pid, self._psi[pid])

    def _try_section(self, pid: int, sec: bytearray) -> None:
        if len(sec) < 3 or sec[0] == 0xFF:
            return
        slen = ((sec[1] & 0x0F) << 8) | sec[2]
        if len(sec) < 3 + slen:
            if len(sec) > 4096:
                self._psi.pop(pid, None)
            return
        s = bytes(sec[:3 + slen])
        self._psi.pop(pid, None)
        if slen < 9 or crc32_mpeg2(s) != 0:
            self.stats.psi_errors += 1
            return
        if s[0] == 0x00 and pid == 0:  # PAT
            pmts = set()
            for k in range(8, 3 + slen - 4, 4):
                prog = (s[k] << 8) | s[k + 1]
                ppid = ((s[k + 2] & 0x1F) << 8) | s[k + 3]
                if prog != 0:
                    pmts.add(ppid)
            self.pmt_pids = pmts
        elif s[0] == 0x02:  # PMT
            version = (s[5] >> 1) & 0x1F
            if self._pmt_version.get(pid) not in (None, version):
                self.stats.pmt_changes += 1
            self._pmt_version[pid] = version
            pinfo = ((s[10] & 0x0F) << 8) | s[11]
            k = 12 + pinfo
            stop = 3 + slen - 4
            while k + 5 <= stop:
                stype = s[k]
                epid = ((s[k + 1] & 0x1F) << 8) | s[k + 2]
                eslen = ((s[k + 3] & 0x0F) << 8) | s[k + 4]
                desc = s[k + 5:k + 5 + eslen]
                kind = None
                if stype == 0x15 or (stype == 0x06 and _registration(desc) == b"KLVA"):
                    kind = "klv"
                elif stype in _STREAM_TYPES_VIDEO:
                    kind = "video"
                if kind is not None:
                    self.streams[epid] = (kind, stype)
                elif epid in self.streams and self.streams[epid][1] != 0:
                    del self.streams[epid]
                k += 5 + eslen


#: The first bytes of every SMPTE ST 336 universal key (UAS LS, EG 0104): 06 0E 2B 34.
_KLV_PREFIX = b"\x06\x0e\x2b\x34"
_KLV_KEYS = (UAS_LS_KEY, EG0104_KEY)


def _starts_with_klv(payload: bytes) -> bool:
    """True when a PES whose first bytes are ``payload`` carries KLV: its data (after the PES
    header) starts with a UAS LS or EG 0104 key, directly or after a 5-byte metadata cell header."""
    if len(payload) < 9 or payload[3] in _NO_PES_HEADER_IDS:
        return False
    body = payload[9 + payload[8]:]
    return any(body.startswith(k, at) for k in _KLV_KEYS for at in (0, 5))


def _registration(desc: bytes) -> bytes | None:
    k = 0
    while k + 2 <= len(desc):
        tag, ln = desc[k], desc[k + 1]
        if tag == 0x05 and ln >= 4:
            return bytes(desc[k + 2:k + 6])
        k += 2 + ln
    return None


def _timestamp(h: bytes, k: int) -> int:
    return (((h[k] >> 1) & 0x07) << 30) | (h[k + 1] << 22) | ((h[k + 2] >> 1) << 15) | (h[k + 3] << 7) | (h[k + 4] >> 1)


def _metadata_cells(body: bytes) -> bytes:
    """The data of the metadata access-unit cells of a synchronous-metadata PES (13818-1 Section 2.12.4)."""
    out = []
    k = 0
    n = len(body)
    while k + 5 <= n:
        ln = (body[k + 3] << 8) | body[k + 4]
        out.append(body[k + 5:k + 5 + ln])
        k += 5 + ln
    return b"".join(out) if out else body


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

    def __init__(self, *, verify_checksum: bool = True, window: int = PACKET_WINDOW,
                 video_window: int = VIDEO_WINDOW, keep_video_data: bool = True,
                 reorder: bool = True, reorder_s: float = REORDER_S):
        self.stats = LiveStats()
        self.demux = TsDemuxer(self.stats, reorder=reorder, reorder_s=reorder_s, video_window=video_window)
        self.verify = verify_checksum
        self.window: deque = deque(maxlen=int(window))
        self.video: deque = deque(maxlen=int(video_window))  # (pts, bytes or None, pid)
        self.keep_video_data = keep_video_data
        self.first_datagram_s: float | None = None  # time.monotonic()
        self.first_datagram_unix_s: float | None = None  # time.time(), to compare with other clocks
        self.last_datagram_s: float | None = None
        self._last_klv_pts: int | None = None

    def push(self, datagram: bytes, now: float | None = None) -> list:
        """One datagram; returns the KLV results it completed."""
        now = time.monotonic() if now is None else now
        st = self.stats
        if self.first_datagram_s is None:
            self.first_datagram_s = now
            self.first_datagram_unix_s = time.time()
        elif now - self.last_datagram_s > STALL_S:
            st.stalls += 1
        self.last_datagram_s = now
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
            if u.pts is not None and self._last_klv_pts is not None and \
                    u.pts < self._last_klv_pts - RESTART_BACK_S * 90000:
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


def receive(url, *, duration_s: float | None = None, packets: int | None = None, idle_s: float | None = None,
            record: Callable[[bytes], None] | None = None, receiver: LiveReceiver | None = None,
            on_batch: Callable[[list], None] | None = None, poll_s: float = 0.05,
            announce: Callable[[str], None] | None = None, stop: Callable[[], bool] | None = None,
            sock: socket.socket | None = None) -> Iterator[Packet | KlvError]:
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

    Stops on any of the conditions, on ``KeyboardInterrupt`` (then returns
    normally), or never when none is given.
    """
    u = url if isinstance(url, UdpUrl) else parse_udp_url(url)
    rx = receiver if receiver is not None else LiveReceiver()
    if sock is None:
        note = exposure_note(u)
        if note:
            (announce or (lambda m: print(m, file=sys.stderr, flush=True)))(note)
        sock = open_socket(u)
    sock.settimeout(poll_s)
    t0 = time.monotonic()
    got = 0
    buf = bytearray(65536)
    try:
        while True:
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            if idle_s is not None and rx.last_datagram_s is not None and now - rx.last_datagram_s >= idle_s:
                break
            if stop is not None and stop():
                break
            try:
                n = sock.recv_into(buf)
            except socket.timeout:
                res = rx.tick()  # no datagram: what is due (a stalled stream's held packets)
            except InterruptedError:
                continue
            else:
                data = bytes(buf[:n])
                if record is not None:
                    record(data)
                res = rx.push(data)
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
    for r in rx.flush():
        if packets is not None and got >= packets:
            break
        got += 1
        yield r


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
            if data[p:p + 3] == b"\x00\x00\x01" and data[p + 3] not in _NO_PES_HEADER_IDS and data[p + 7] & 0x80:
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
        ts = [t for t in at[k:k + per] if t is not None]
        out.append(min(ts) if ts else None)
    return out


def datagrams_of(data: bytes, per: int = DATAGRAM_PACKETS) -> list[bytes]:
    """``data`` (a TS file's bytes) cut into datagrams of ``per`` TS packets."""
    size = per * TS_PACKET
    return [data[k:k + size] for k in range(0, len(data), size)]


def klv_as_ts(path) -> tuple[bytes, int, int]:
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
        blobs.append(data[r.offset:r.offset + _packet_end(data[r.offset:r.offset + 26])])
        stamps.append(r.fields.get("precision_time_stamp_us"))
    if not blobs:
        raise ValueError(f"{path}: no packet of it can be decoded ({bad} bad): nothing a receiver could use "
                         "(geoloc klv dump names what is wrong with each)")
    pts = None
    if all(isinstance(t, int) for t in stamps) and all(b >= a for a, b in zip(stamps, stamps[1:])):
        pts = [(t - stamps[0]) * 9 // 100 for t in stamps]  # microseconds -> 90 kHz ticks
    with tempfile.TemporaryDirectory(prefix="geoloc-klv-send-") as d:
        ts = os.path.join(d, "klv.ts")
        write_ts(ts, blobs, pts=pts)
        with open(ts, "rb") as f:
            return f.read(), len(blobs), bad


def send(source, url, *, speed: float | None = 1.0, per: int = DATAGRAM_PACKETS, loss: float = 0.0,
         reorder: float = 0.0, duplicate: float = 0.0, rng=None, start_delay_s: float = 0.0,
         sock: socket.socket | None = None) -> dict:
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
    if own:
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
    return {"sent": sent, "dropped": int(drop.sum()), "reordered": reordered, "duplicated": dups,
            "dropped_index": [int(i) for i in np.flatnonzero(drop)], "datagrams": n, "first_sent_s": first}


# --------------------------------------------------------------------------- python -m geoloc.io.live


def main(argv=None) -> int:
    """``python -m geoloc.io.live send FILE.ts udp://HOST:PORT [--speed X | --fast] [--loop N]``."""
    p = argparse.ArgumentParser(prog="python -m geoloc.io.live",
                                description="Stream an MPEG-TS file (STANAG 4609: video + MISB ST 0601 KLV) "
                                "to a UDP address, 7 TS packets a datagram, paced by its time stamps.")
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
            r = send(args.file, args.url, speed=None if args.fast else args.speed, loss=args.loss,
                     reorder=args.reorder)
            print(f"sent {r['sent']} datagrams of {args.file} to {args.url} ({r['dropped']} dropped, "
                  f"{r['reordered']} reordered)", file=sys.stderr)
    except KeyboardInterrupt:
        return 0
    except (ValueError, OSError) as e:
        print(f"python -m geoloc.io.live: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
