"""An incremental MPEG-TS demultiplexer of KLV and video (ISO/IEC 13818-1 Section 2.4.3).

:class:`TsDemuxer` takes bytes as they come (a file read in chunks, or UDP datagrams)
and returns each PES of a KLV or video stream as soon as it is complete: TS packets,
continuity counters, PAT / PMT sections with their CRC-32, PES packets, the two KLV
carriages of MISB ST 1402 (asynchronous: stream type 0x06 with the ``KLVA``
registration; synchronous: stream type 0x15, metadata access-unit cells), and, with no
PMT, the PES whose data starts with a UAS LS or EG 0104 key. It is used by the live
receiver (:mod:`geoloc.io.live`, which re-exports it) and by
:func:`geoloc.io.klv.read_ts_klv` for a transport stream in which FFmpeg finds no data
stream. It imports nothing of the KLV decoder (its keys come from
:mod:`geoloc.io.klv_sets`).

References: ISO/IEC 13818-1 (MPEG-2 systems: TS packets, PSI, PES, CRC-32 of sections,
metadata carriage), MISB ST 1402 (MPEG-2 transport of KLV metadata).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, fields

from geoloc.io.klv_sets import EG0104_KEY, UAS_LS_KEY

__all__ = ["TS_PACKET", "MAX_PES", "VIDEO_WINDOW", "PesUnit", "LiveStats", "TsDemuxer", "crc32_mpeg2"]

#: Bytes of one MPEG-TS packet (ISO/IEC 13818-1 Section 2.4.3.2).
TS_PACKET = 188
#: A partial PES longer than this is dropped (counted) [bytes]: KLV and video.
MAX_PES = {"klv": 1 << 20, "video": 8 << 20}
#: Video access units kept for binding KLV packets to frames (about 10 minutes at 30 Hz).
VIDEO_WINDOW = 18000
_STREAM_TYPES_VIDEO = {0x01: "mpeg1video", 0x02: "mpeg2video", 0x10: "mpeg4", 0x1B: "h264", 0x24: "hevc"}
_KLV_STREAM_IDS = (0xBD, 0xFC)  # private_stream_1, metadata_stream (ISO/IEC 13818-1 Table 2-22)
_NO_PES_HEADER_IDS = {0xBC, 0xBE, 0xBF, 0xF0, 0xF1, 0xF2, 0xF8, 0xFF}


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
    more than :data:`geoloc.io.live.STALL_S` between datagrams; ``pmt_changes`` new PMT
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
        return (
            f"{self.datagrams} datagrams, {self.klv_packets} KLV packets ({self.bad_packets} bad, "
            f"{self.bad_checksums} bad checksums), {self.video_units} video frames; "
            f"{self.cc_errors} TS continuity errors, {self.duplicates} duplicates, {self.resyncs} resyncs, "
            f"{self.orphans} orphan PES fragments, {self.restarts} restarts, {self.stalls} stalls"
        )

    def markdown(self) -> str:
        """The loss panel's text."""
        return (
            "| received | lost / bad |\n|---|---|\n"
            f"| {self.datagrams} datagrams | {self.cc_errors} TS continuity errors |\n"
            f"| {self.klv_packets} KLV packets | {self.bad_packets} bad KLV packets "
            f"({self.bad_checksums} checksums) |\n"
            f"| {self.video_units} video frames | {self.duplicates} duplicates, {self.resyncs} resyncs |\n"
            f"| {self.ts_packets} TS packets | {self.orphans} orphan PES, {self.damaged_pes} damaged PES |\n"
            f"| {self.restarts} restarts | {self.stalls} stalls, {self.transport_errors} TS errors |"
        )


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

    def __init__(
        self,
        stats: LiveStats | None = None,
        keep_video: bool = True,
        reorder: bool = True,
        reorder_s: float = 0.1,
        video_window: int = VIDEO_WINDOW,
    ):
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
        self._held: tuple[bytes, float] | None = None  # (datagram, time) held for reordering
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
        pkt = buf[i : i + TS_PACKET]
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
        cc: dict[int, int] = {}
        count: dict[int, int] = {}
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
                if (
                    len(payload) >= 4
                    and payload[:3] == b"\x00\x00\x01"
                    and (payload[3] in _KLV_STREAM_IDS or _starts_with_klv(payload))
                ):
                    self.streams[pid] = ("klv", 0)
                    kind = "klv"
                else:
                    return
            b = _PesBuf(offset)
            if len(payload) >= 6 and payload[:3] == b"\x00\x00\x01":
                ln = (payload[4] << 8) | payload[5]
                b.expected = 6 + ln if ln else 0
                if (
                    kind == "video"
                    and len(payload) >= 14
                    and payload[3] not in _NO_PES_HEADER_IDS
                    and payload[7] & 0x80
                    and payload[8] >= 5
                ):
                    self.video_starts.append(_timestamp(payload, 9))
            self._pes[pid] = b
        elif kind is None:
            return
        held = self._pes.get(pid)
        if held is None:
            st.orphans += 1  # a PES whose start we never saw (joined mid-PES, or its first packet lost)
            return
        held.parts.append(payload)
        held.size += len(payload)
        if held.size > MAX_PES.get(kind, 1 << 20):
            st.oversize += 1
            del self._pes[pid]
            return
        if held.expected and held.size >= held.expected:
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
            data = data[: b.expected]
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
            h = data[9 : 9 + hlen]
            if flags & 0x80 and len(h) >= 5:
                pts = _timestamp(h, 0)
            if flags & 0x40 and len(h) >= 10:
                dts = _timestamp(h, 5)
            body = data[9 + hlen :]
        if kind == "klv" and (stype == 0x15 or (stype == 0 and body[:4] != _KLV_PREFIX and body[5:9] == _KLV_PREFIX)):
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
                prev += payload[1 : 1 + ptr]
                self._try_section(pid, prev)
            self._psi[pid] = bytearray(payload[1 + ptr :])
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
        s = bytes(sec[: 3 + slen])
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
                desc = s[k + 5 : k + 5 + eslen]
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
    body = payload[9 + payload[8] :]
    return any(body.startswith(k, at) for k in _KLV_KEYS for at in (0, 5))


def _registration(desc: bytes) -> bytes | None:
    k = 0
    while k + 2 <= len(desc):
        tag, ln = desc[k], desc[k + 1]
        if tag == 0x05 and ln >= 4:
            return bytes(desc[k + 2 : k + 6])
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
        out.append(body[k + 5 : k + 5 + ln])
        k += 5 + ln
    return b"".join(out) if out else body
