"""A small MPEG-TS writer for the tests: KLV carried the ways real multiplexers carry it.

Written from ISO/IEC 13818-1 (TS packets 2.4.3.2, PES 2.4.3.6, PAT / PMT sections 2.4.4 with
their CRC-32 of Annex A, the metadata access-unit cells of 2.12.4, the registration and
metadata descriptors 2.6.8 / 2.6.60) and MISB ST 1402 (asynchronous KLV: stream type 0x06,
stream id 0xBD, registration ``KLVA``; synchronous KLV: stream type 0x15, stream id 0xFC,
metadata descriptor with ``KLVA``), independently of geoloc's demuxer (its own CRC, bit by
bit): the tests read these bytes with geoloc and with PyAV (FFmpeg).
"""

from __future__ import annotations


def crc32_mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 bit by bit (polynomial 0x04C11DB7, initial 0xFFFFFFFF, no reflection)."""
    crc = 0xFFFFFFFF
    for b in data:
        for i in range(7, -1, -1):
            top = (crc >> 31) & 1
            crc = (crc << 1) & 0xFFFFFFFF
            if top ^ ((b >> i) & 1):
                crc ^= 0x04C11DB7
    return crc


class Mux:
    """TS packets in order, with a continuity counter per PID."""

    def __init__(self):
        self.cc: dict[int, int] = {}
        self.out: list[bytes] = []

    def packets(self, pid: int, payload: bytes, pusi: bool = True) -> None:
        """``payload`` on ``pid``: 184 bytes a packet, the last stuffed by an adaptation field."""
        k = 0
        first = True
        while first or k < len(payload):
            chunk = payload[k : k + 184]
            k += len(chunk)
            cc = self.cc.get(pid, 0)
            self.cc[pid] = (cc + 1) & 0x0F
            b1 = (0x40 if (pusi and first) else 0) | (pid >> 8)
            if len(chunk) == 184:
                head = bytes((0x47, b1, pid & 0xFF, 0x10 | cc))
                self.out.append(head + chunk)
            else:
                stuff = 184 - len(chunk) - 1  # adaptation field length byte, then flags + 0xFF
                af = bytes((stuff,)) + (bytes((0x00,)) + b"\xff" * (stuff - 1) if stuff else b"")
                head = bytes((0x47, b1, pid & 0xFF, 0x30 | cc))
                self.out.append(head + af + chunk)
            first = False

    def section(self, pid: int, sec: bytes) -> None:
        """A PSI section (with its CRC) on ``pid``, pointer field 0."""
        self.packets(pid, b"\x00" + sec + crc32_mpeg2(sec).to_bytes(4, "big"))

    def bytes(self) -> bytes:
        return b"".join(self.out)


def pat(programs: dict[int, int], tsid: int = 1) -> bytes:
    """The PAT section (without CRC): program number -> PMT PID."""
    body = b"".join(p.to_bytes(2, "big") + (0xE000 | pid).to_bytes(2, "big") for p, pid in programs.items())
    length = 5 + len(body) + 4
    return bytes((0x00, 0xB0 | (length >> 8), length & 0xFF)) + tsid.to_bytes(2, "big") + b"\xc1\x00\x00" + body


def registration(fmt: bytes = b"KLVA") -> bytes:
    return bytes((0x05, len(fmt))) + fmt


def metadata_descriptor() -> bytes:
    """ISO/IEC 13818-1 metadata_descriptor as MISB ST 1402 fills it for KLV (service id 0)."""
    body = b"\xff\xff" + b"KLVA" + b"\xff" + b"KLVA" + b"\x00" + b"\x0f"
    return bytes((0x26, len(body))) + body


def pmt(program: int, pcr_pid: int, streams) -> bytes:
    """The PMT section (without CRC): streams = [(stream_type, pid, descriptors bytes)]."""
    es = b"".join(
        bytes((st,)) + (0xE000 | pid).to_bytes(2, "big") + (0xF000 | len(d)).to_bytes(2, "big") + d
        for st, pid, d in streams
    )
    length = 9 + len(es) + 4
    return (
        bytes((0x02, 0xB0 | (length >> 8), length & 0xFF))
        + program.to_bytes(2, "big")
        + b"\xc1\x00\x00"
        + (0xE000 | pcr_pid).to_bytes(2, "big")
        + b"\xf0\x00"
        + es
    )


def _ts(pts: int, marker: int = 0x21) -> bytes:
    return bytes(
        (
            marker | ((pts >> 29) & 0x0E),
            (pts >> 22) & 0xFF,
            0x01 | ((pts >> 14) & 0xFE),
            (pts >> 7) & 0xFF,
            0x01 | ((pts << 1) & 0xFE),
        )
    )


def pes(stream_id: int, payload: bytes, pts: int | None) -> bytes:
    """A PES packet with an optional PTS (its length field set; 0 when too long)."""
    header = (b"\x80\x80\x05" + _ts(pts)) if pts is not None else b"\x80\x00\x00"
    n = len(header) + len(payload)
    return b"\x00\x00\x01" + bytes((stream_id,)) + (n if n <= 0xFFFF else 0).to_bytes(2, "big") + header + payload


def au_cell(klv: bytes, service_id: int = 0, seq: int = 0) -> bytes:
    """One metadata access-unit cell (ISO/IEC 13818-1 2.12.4): 5-byte header, then the KLV."""
    # cell_fragment_indication '11' (a complete AU), decoder_config_flag 0, random_access 1
    return bytes((service_id, seq & 0xFF, 0xC0 | 0x10 | 0x0F)) + len(klv).to_bytes(2, "big") + klv


def stream(
    klv_packets,
    *,
    sync: bool = False,
    pid: int = 0x101,
    programs=None,
    psi: bool = True,
    stream_id: int | None = None,
    rate_ticks: int = 3000,
    video_pid: int | None = None,
) -> bytes:
    """A transport stream carrying ``klv_packets`` (bytes each), one PES each at ``rate_ticks``.

    ``sync``: stream type 0x15 in metadata AU cells (stream id 0xFC), else 0x06 KLVA (0xBD).
    ``programs``: extra programs before the KLV one, each a video-only PMT (no video data).
    ``psi``: False writes no PAT and no PMT at all. ``stream_id`` overrides the PES stream id.
    """
    m = Mux()
    sid = stream_id if stream_id is not None else (0xFC if sync else 0xBD)
    progs = {}
    extra = list(range(1, 1 + (programs or 0)))
    for i in extra:
        progs[i] = 0x100 + 0x10 * i
    klv_prog = len(extra) + 1
    progs[klv_prog] = 0x1000
    if psi:
        m.section(0, pat(progs))
        for i in extra:
            m.section(progs[i], pmt(i, 0x200 + i, [(0x1B, 0x200 + i, b"")]))
        desc = metadata_descriptor() if sync else registration()
        klv_streams = [(0x15 if sync else 0x06, pid, desc)]
        if video_pid is not None:
            klv_streams.insert(0, (0x1B, video_pid, b""))
        m.section(0x1000, pmt(klv_prog, pid, klv_streams))
    for i, b in enumerate(klv_packets):
        payload = au_cell(b, seq=i) if sync else b
        m.packets(pid, pes(sid, payload, i * rate_ticks))
    return m.bytes()
