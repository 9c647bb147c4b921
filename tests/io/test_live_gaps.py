"""Live UDP (geoloc.io.live): the cases a mutation audit found no test ever sent.

* A KLV clock that goes **back without a restart** (a sender's reordered or re-stamped packets,
  1 to 5 s back) and one that goes back by more (a restart): the count of restarts is the test's
  own count over the PTS it wrote, ``RESTART_BACK_S`` (5 s) read in the 90 kHz clock of the PES
  header (ISO/IEC 13818-1 2.4.3.7: PTS in units of 1/90 000 s). A threshold in the wrong unit
  (milliseconds, 27 MHz, seconds) miscounts one of the steps here.
* A **TS packet repeated inside one datagram** (ISO/IEC 13818-1 2.4.3.3: a packet may be sent twice,
  the copy with the same continuity counter and bytes, and is then dropped): the first packet of
  a PES (its start) and the middle one of another; every KLV packet must come out once, decoded
  as it was encoded, with one duplicate counted per repeat and no continuity error.

The streams are built in the test byte by byte (PAT, PMT with stream type 0x15, PES with a
metadata AU cell: :func:`test_live._ts_packets`, written from the standard), carrying the bundled
flight's KLV packets re-encoded (:func:`geoloc.io.klv.encode_packet`), so the expected fields are
the encoder's input, not the receiver's output.
"""

from __future__ import annotations

from pathlib import Path

from test_live import _section, _ts_packets

from geoloc.assets import ASSETS
from geoloc.io.klv import Packet, encode_packet, read_klv_file
from geoloc.io.live import LiveReceiver, datagrams_of

KLV = Path(ASSETS) / "klv" / "example_flight.klv"
TICKS = 90000  # the PES clock [ticks per second]


def _pts_bytes(pts: int) -> bytes:
    """The 5-byte PTS field ('0010', PTS[32..30], marker, PTS[29..15], marker, PTS[14..0], marker)."""
    return bytes(
        [
            0x21 | ((pts >> 29) & 0x0E),
            (pts >> 22) & 0xFF,
            0x01 | ((pts >> 14) & 0xFE),
            (pts >> 7) & 0xFF,
            0x01 | ((pts << 1) & 0xFE),
        ]
    )


def _stream(pts_list, packets):
    """TS packets (a list of 188-byte packets): PAT and PMT, then one KLV PES per time stamp."""
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in packets]
    pat = _section(0x00, bytes([0x00, 0x01, 0xE1, 0x00]))  # program 1 -> PMT PID 0x100
    pmt = _section(0x02, bytes([0xFF, 0xFF, 0xF0, 0x00, 0x15, 0xE1, 0x01, 0xF0, 0x00]))  # 0x15 on PID 0x101
    out = [_ts_packets(0, b"\x00" + pat)[0][0], _ts_packets(0x100, b"\x00" + pmt)[0][0]]
    cc = 0
    for i, (pts, b) in enumerate(zip(pts_list, blobs)):
        cell = bytes([0x00, i & 0xFF, 0xDF]) + len(b).to_bytes(2, "big") + b
        body = bytes([0x84, 0x80, 0x05]) + _pts_bytes(pts) + cell
        pes = b"\x00\x00\x01\xfc" + len(body).to_bytes(2, "big") + body
        pk, cc = _ts_packets(0x101, pes, cc)
        out += pk
    return out


def _klv_packets(n):
    pk = [p for p in read_klv_file(KLV) if isinstance(p, Packet)]
    return (pk * (n // len(pk) + 1))[:n]


def _receive(ts: bytes):
    rx = LiveReceiver()
    out = []
    for k, g in enumerate(datagrams_of(ts)):
        out += rx.push(g, now=k * 1e-3)
    out += rx.flush()
    return rx, out


def test_klv_time_going_back_without_and_with_a_restart():
    base = 1000 * TICKS
    sec = [0, 1, 2, 3, 4, 2, 3, 4, 5, 6, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]  # back 2 s, back 5 s (not over)
    pts = [base + s * TICKS for s in sec]
    pts += [pts[-1] - 5 * TICKS - 1]  # back 5 s and one tick: a restart
    pts += [pts[-1] + TICKS, pts[-1] + 2 * TICKS]
    pts += [pts[-1] - 4 * TICKS - TICKS // 2]  # back 4.5 s: not a restart
    pts += [pts[-1] - 20 * TICKS]  # back 20 s: a restart
    pts += [pts[-1] + 45]  # half a millisecond on
    pts += [pts[-1] - 60]  # back 2/3 ms: not a restart
    pk = _klv_packets(len(pts))
    rx, out = _receive(b"".join(_stream(pts, pk)))
    # every packet, in arrival order, with its own time stamp and fields: time going back drops nothing
    assert [r.pts for r in out] == pts
    assert all(isinstance(r, Packet) for r in out)
    assert [r.fields for r in out] == [p.fields for p in pk]
    # the restarts: a step back of more than 5 s of the 90 kHz clock, counted here
    expected = sum(1 for a, b in zip(pts, pts[1:]) if a - b > 5 * TICKS)
    assert expected == 2
    assert rx.stats.restarts == expected
    assert rx.stats.cc_errors == 0 and rx.stats.duplicates == 0 and rx.stats.klv_packets == len(pts)
    assert len(rx.window) == len(pts)


def test_one_second_back_is_not_a_restart_in_any_unit():
    """A 1 Hz stream with one packet 1 s early (two packets swapped at the sender): no restart.
    A threshold read in milliseconds (5 000 ticks) or in ticks (5) would count one."""
    pts = [7 * TICKS + k * TICKS for k in range(6)]
    pts[2], pts[3] = pts[3], pts[2]
    pk = _klv_packets(len(pts))
    rx, out = _receive(b"".join(_stream(pts, pk)))
    assert [r.pts for r in out] == pts and rx.stats.restarts == 0


def test_a_ts_packet_repeated_inside_a_datagram_is_dropped_once():
    pts = [90000 * i + 1234 for i in range(12)]
    pk = _klv_packets(len(pts))
    packets = _stream(pts, pk)
    # each PES takes two TS packets on PID 0x101 (216-byte KLV + cell + PES header > 184 bytes)
    klv = [i for i, p in enumerate(packets) if ((p[1] & 0x1F) << 8 | p[2]) == 0x101]
    assert len(klv) == 2 * len(pts)
    first_of_4th, second_of_8th = klv[2 * 3], klv[2 * 7 + 1]
    assert packets[first_of_4th][1] & 0x40 and not packets[second_of_8th][1] & 0x40  # a start; a middle one
    seq = []
    for i, p in enumerate(packets):
        seq.append(p)
        if i in (first_of_4th, second_of_8th):
            seq.append(p)  # the same packet again, right after it (the same datagram)
    ts = b"".join(seq)
    # both copies of each repeated packet are in one 7-packet datagram
    for i in (first_of_4th, second_of_8th):
        j = seq.index(packets[i])
        assert j // 7 == (j + 1) // 7 and seq[j] == seq[j + 1]
    rx, out = _receive(ts)
    assert [r.pts for r in out] == pts  # each once, in order
    assert [r.fields for r in out] == [p.fields for p in pk]
    assert rx.stats.duplicates == 2 and rx.stats.cc_errors == 0 and rx.stats.bad_packets == 0


def test_a_repeated_counter_with_other_bytes_is_a_continuity_error_not_a_duplicate():
    """The same counter on different bytes is no duplicate (2.4.3.3: a duplicate repeats the
    packet's bytes): a continuity error, the PES it broke is damaged, the others come out."""
    pts = [90000 * i for i in range(8)]
    pk = _klv_packets(len(pts))
    packets = _stream(pts, pk)
    klv = [i for i, p in enumerate(packets) if ((p[1] & 0x1F) << 8 | p[2]) == 0x101]
    k = klv[2 * 4 + 1]  # the second packet of the 5th PES
    fake = bytearray(packets[k])
    fake[-1] ^= 0xFF  # the same header and counter, another last byte
    seq = packets[: k + 1] + [bytes(fake)] + packets[k + 1 :]
    rx, out = _receive(b"".join(seq))
    good = [r.pts for r in out if isinstance(r, Packet)]
    assert rx.stats.duplicates == 0 and rx.stats.cc_errors >= 1
    assert set(good) >= set(pts[:4] + pts[5:])  # every PES the fake packet did not touch


# ------------------------------------------------------------------ PMT, descriptors, video PES
# From the mutation run on live.py: the PMT's elementary-stream loop, the registration descriptor
# (ISO/IEC 13818-1 2.6.8: tag 5, length 4 or more, format_identifier; MISB ST 1402 asynchronous
# carriage: stream type 0x06 with 'KLVA'), stuffing where a section would start (table_id 0xFF,
# 2.4.4.4), video PES and their count, a padding PES (no PES header: Table 2-21's stream ids).


def _pmt(entries):
    """A PMT section (program 1, PCR PID 0x1FFF) of (stream_type, pid, ES descriptors) entries."""
    body = bytes([0xFF, 0xFF, 0xF0, 0x00])
    for stype, pid, desc in entries:
        body += bytes([stype, 0xE0 | (pid >> 8), pid & 0xFF, 0xF0 | (len(desc) >> 8), len(desc) & 0xFF]) + desc
    return _section(0x02, body)


def _pes(stream_id, pts, payload, length=True):
    hdr = bytes([0x84, 0x80, 0x05]) + _pts_bytes(pts)
    body = hdr + payload
    return b"\x00\x00\x01" + bytes([stream_id]) + (len(body).to_bytes(2, "big") if length else b"\x00\x00") + body


def _psi_packets(pat_pmt):
    pat = _section(0x00, bytes([0x00, 0x01, 0xE1, 0x00]))
    return [_ts_packets(0, b"\x00" + pat)[0][0], _ts_packets(0x100, b"\x00" + pat_pmt)[0][0]]


def test_asynchronous_klv_is_named_by_its_registration_descriptor_after_another_stream():
    """PMT: an H.264 stream with a 3-byte descriptor first, then stream type 0x06 whose descriptors
    are another one (tag 0x0A, 4 bytes) and then 'KLVA' (tag 5, length 4); a third entry of a
    stream type the receiver does not take. Each stream is known by the PMT's entry, read in turn
    (PIDs whose low byte is not their high bits: 0x1F0, 0x0A5, 0x1234)."""
    pk = _klv_packets(4)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    pmt = _pmt(
        [
            (0x1B, 0x0A5, bytes([0x28, 0x01, 0x4D])),
            (0x06, 0x1F0, bytes([0x0A, 0x04]) + b"eng\x00" + bytes([0x05, 0x04]) + b"KLVA"),
            (0x0F, 0x1234, b""),
        ]
    )
    seq = _psi_packets(pmt)
    cc = 0
    for i, b in enumerate(blobs):
        p, cc = _ts_packets(0x1F0, _pes(0xBD, 90000 * (i + 1), b), cc)
        seq += p
    rx, out = _receive(b"".join(seq))
    assert rx.demux.streams.get(0x1F0) == ("klv", 0x06)
    assert rx.demux.streams.get(0x0A5) == ("video", 0x1B)
    assert 0x1234 not in rx.demux.streams
    assert [r.fields for r in out] == [p.fields for p in pk] and rx.stats.psi_errors == 0


def test_a_registration_other_than_klva_is_not_klv():
    """Stream type 0x06 registered as another format ('ABCD'): not a KLV stream by the PMT."""
    pmt = _pmt([(0x06, 0x101, bytes([0x05, 0x04]) + b"ABCD")])
    rx, _ = _receive(b"".join(_psi_packets(pmt)))
    assert 0x101 not in rx.demux.streams and rx.stats.psi_errors == 0


def test_video_frames_are_counted_and_their_starts_timed_and_padding_is_not_a_frame():
    """Three H.264 PES (no length, as video carries them) with their PTS, and a padding PES
    (stream id 0xBE: no PES header, so no time) on the same PID: three frames, their PTS."""
    pmt = _pmt([(0x1B, 0x102, b""), (0x15, 0x101, b"")])
    seq = _psi_packets(pmt)
    cc = 0
    frames = [(0xE0, 3003 * k + 9000) for k in range(3)]
    for k, (sid, pts) in enumerate(frames):
        p, cc = _ts_packets(0x102, _pes(sid, pts, bytes([0, 0, 0, 1, 0x65]) + bytes(300), length=False), cc)
        seq += p
        if k == 1:  # a padding PES: 0xBE, then its length, then 0xFF bytes (no flags, no PTS)
            pad = b"\x00\x00\x01\xbe" + (40).to_bytes(2, "big") + b"\xff" * 40
            p, cc = _ts_packets(0x102, pad, cc)
            seq += p
    rx = LiveReceiver()
    out = []
    for g in datagrams_of(b"".join(seq)):
        out += rx.push(g)
    out += rx.flush()
    assert [p for p in rx.demux.video_starts] == [pts for _, pts in frames]
    assert rx.stats.video_units == len(frames) + 1  # the three frames and the padding PES, each a unit
    assert [u[0] for u in rx.video if u[0] is not None] == [pts for _, pts in frames]


def test_a_pes_header_too_short_for_its_flags_gives_no_time():
    """A KLV PES whose header says 'PTS present' but is 4 bytes long (a PTS takes 5): no time
    stamp rather than one read from the payload."""
    pk = _klv_packets(2)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    pmt = _pmt([(0x06, 0x101, bytes([0x05, 0x04]) + b"KLVA")])
    seq = _psi_packets(pmt)
    good = _pes(0xBD, 90000, blobs[0])
    short = bytes([0x84, 0x80, 0x04]) + _pts_bytes(180000)[:4]
    bad = b"\x00\x00\x01\xbd" + (len(short) + len(blobs[1])).to_bytes(2, "big") + short + blobs[1]
    cc = 0
    for pes in (good, bad):
        p, cc = _ts_packets(0x101, pes, cc)
        seq += p
    rx, out = _receive(b"".join(seq))
    assert [r.pts for r in out] == [90000, None]
    assert out[1].fields == pk[1].fields


def test_stuffing_where_a_section_would_start_is_no_section():
    """PID 0 packets of stuffing (pointer 0, then 0xFF to the end, 2.4.4.4), 23 of them: no
    section, no PSI error; the PAT after them is read."""
    stuff_first = bytes([0x47, 0x40, 0x00, 0x10]) + b"\x00" + b"\xff" * 183
    more = [bytes([0x47, 0x00, 0x00, 0x10 | (k & 0x0F)]) + b"\xff" * 184 for k in range(1, 23)]
    pmt = _pmt([(0x15, 0x101, b"")])
    pat = _section(0x00, bytes([0x00, 0x01, 0xE1, 0x00]))
    tail = [_ts_packets(0, b"\x00" + pat, cc0=23 & 0x0F)[0][0], _ts_packets(0x100, b"\x00" + pmt)[0][0]]
    rx = LiveReceiver(reorder=False)
    for g in datagrams_of(b"".join([stuff_first] + more + tail)):
        rx.push(g)
    assert rx.stats.psi_errors == 0 and rx.stats.cc_errors == 0
    assert rx.demux.pmt_pids == {0x100} and rx.demux.streams.get(0x101) == ("klv", 0x15)


def test_two_held_datagrams_whose_counters_tie_keep_their_arrival_order():
    """``TsDemuxer._first``'s rule: a datagram goes before the held one only when the slow PIDs
    they share say it is nearer. Here the PAT says the held one is nearer and the KLV PID says the
    new one is, by the same count (2 steps each): no order is known, so arrival order."""
    pk = _klv_packets(3)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    pat = _section(0x00, bytes([0x00, 0x01, 0xE1, 0x00]))
    pmt = _pmt([(0x15, 0x101, b"")])

    def pat_cc(cc):
        return _ts_packets(0, b"\x00" + pat, cc0=cc)[0][0]

    def klv(i, cc):
        cell = bytes([0x00, i, 0xDF]) + len(blobs[i]).to_bytes(2, "big") + blobs[i]
        return _ts_packets(0x101, _pes(0xFC, 90000 * (i + 1), cell), cc)[0]

    first = [pat_cc(0), _ts_packets(0x100, b"\x00" + pmt)[0][0]] + klv(0, 0)  # KLV counters 0, 1
    held = [pat_cc(1)] + klv(2, 4)  # PAT +0, KLV +2 missing
    new = [pat_cc(3)] + klv(1, 2)  # PAT +2 missing, KLV +0
    rx = LiveReceiver()
    out = []
    for g in (first, held, new):
        out += rx.push(b"".join(g))
    out += rx.flush()
    assert [r.pts for r in out] == [90000, 270000, 180000]


def test_a_datagram_nearer_by_its_two_packet_klv_pid_goes_first():
    """Both datagrams carry three video packets (a fast PID: its counter says nothing after a
    wrap) and a two-packet KLV PES (a slow PID: at most two packets, counted). The new one
    continues the KLV counter, the held one is two steps on: the new one goes first."""
    pk = _klv_packets(3)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    pmt = _pmt([(0x1B, 0x102, b""), (0x15, 0x101, b"")])

    def klv(i, cc):
        cell = bytes([0x00, i, 0xDF]) + len(blobs[i]).to_bytes(2, "big") + blobs[i]
        return _ts_packets(0x101, _pes(0xFC, 90000 * (i + 1), cell), cc)[0]

    def video(cc0):
        return [bytes([0x47, 0x01, 0x02, 0x10 | ((cc0 + j) & 0x0F)]) + bytes(184) for j in range(3)]

    first = _psi_packets(pmt) + klv(0, 0) + video(0)  # KLV 0, 1; video 0, 1, 2
    held = klv(2, 4) + video(9)  # KLV two steps on, video 6 on
    new = klv(1, 2) + video(6)  # KLV continues, video 3 on
    assert len(b"".join(held)) == len(b"".join(new)) == 5 * 188
    rx = LiveReceiver()
    out = []
    for g in (first, held, new):
        out += rx.push(b"".join(g))
    out += rx.flush()
    assert [r.pts for r in out if isinstance(r, Packet)] == [90000, 180000, 270000]


def test_a_video_pes_header_too_short_for_its_pts_starts_no_timed_frame():
    """A video PES whose flags say 'PTS present' but whose header data is 4 bytes (a PTS takes 5):
    no frame start with a time read from the payload; the well-formed frames around it keep theirs."""
    pmt = _pmt([(0x1B, 0x102, b"")])
    seq = _psi_packets(pmt)
    cc = 0
    short = b"\x00\x00\x01\xe0\x00\x00" + bytes([0x84, 0x80, 0x04]) + _pts_bytes(12345)[:4] + bytes(200)
    for pes in (_pes(0xE0, 9000, bytes(200), length=False), short, _pes(0xE0, 12003, bytes(200), length=False)):
        p, cc = _ts_packets(0x102, pes, cc)
        seq += p
    rx = LiveReceiver()
    for g in datagrams_of(b"".join(seq)):
        rx.push(g)
    rx.flush()
    assert list(rx.demux.video_starts) == [9000, 12003]


# ------------------------------------------------------------------ the second sample (seed 1)


def test_klv_without_any_pmt_is_taken_by_its_stream_id_and_a_pes_completes_at_its_length():
    """No PAT or PMT (joined mid-stream): a PES of stream id 0xFC (metadata_stream) is taken as KLV,
    its stream type 0 ('taken before any PMT', PesUnit's docstring; 0x01 would be MPEG-1 video). A
    PES with a length field is out as soon as its last byte came, not at the next PES start. A
    packet whose whole payload is a start code prefix (00 00 01, no stream id) is ignored."""
    pk = _klv_packets(2)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    rx = LiveReceiver()
    stub = bytes([0x47, 0x41, 0x07, 0x30, 180, 0x00]) + b"\xff" * 179 + b"\x00\x00\x01"  # 3 payload bytes
    assert len(stub) == 188
    assert rx.push(stub) == []
    first, cc = _ts_packets(0x1F0, _pes(0xFC, 90000, blobs[0]), 0)
    got = rx.push(b"".join(first))
    assert [r.pts for r in got] == [90000] and got[0].fields == pk[0].fields  # before any later packet
    assert rx.demux.streams[0x1F0] == ("klv", 0)
    second, _ = _ts_packets(0x1F0, _pes(0xFC, 180000, blobs[1]), cc)
    assert [r.pts for r in rx.push(b"".join(second))] == [180000]
    assert rx.stats.datagrams == 3


def test_an_adaptation_only_packet_does_not_count_as_the_next_in_its_pid():
    """A PID's packet with an adaptation field and no payload (adaptation_field_control '10')
    repeats the counter (2.4.3.3: it does not increment): the datagram it leads still continues the
    stream, taken at once, and the KLV PES around it come out in order, none damaged."""
    pk = _klv_packets(3)
    blobs = [encode_packet(p.fields, unknown=p.unknown) for p in pk]
    pmt = _pmt([(0x15, 0x101, b"")])

    def klv(i, cc):
        cell = bytes([0x00, i, 0xDF]) + len(blobs[i]).to_bytes(2, "big") + blobs[i]
        return _ts_packets(0x101, _pes(0xFC, 90000 * (i + 1), cell), cc)[0]

    af_only = bytes([0x47, 0x01, 0x01, 0x20 | 1, 183, 0x00]) + b"\xff" * 182  # counter 1 again, no payload
    grams = [_psi_packets(pmt) + klv(0, 0), [af_only] + klv(1, 2), klv(2, 4)]
    rx = LiveReceiver()
    per = [[r.pts for r in rx.push(b"".join(g))] for g in grams]
    # each PES is out with its own datagram: the second datagram was not held back as out of order
    assert per == [[90000], [180000], [270000]] and rx.flush() == []
    assert rx.stats.cc_errors == 0 and rx.stats.damaged_pes == 0 and rx.stats.datagrams == 3


def test_resyncs_damaged_pes_and_decoding_time_stamps_are_counted_and_read():
    """Ten stray bytes between two packets of a continuous stream: one resync, ten bytes skipped.
    A lost middle packet of a PES: one continuity error and one damaged PES. A video PES with PTS
    and DTS (flags '11', 10 header bytes): both read (2.4.3.7)."""
    pk = _klv_packets(3)
    pmt = _pmt([(0x15, 0x101, b""), (0x1B, 0x102, b"")])
    packets = _stream([90000 * (i + 1) for i in range(3)], pk)
    rx = LiveReceiver()
    ts = b"".join(packets[:3]) + bytes(range(1, 11)) + b"".join(packets[3:])
    rx.push_bytes(ts)
    assert rx.stats.resyncs == 1 and rx.stats.skipped_bytes == 10

    klv = [i for i, p in enumerate(packets) if ((p[1] & 0x1F) << 8 | p[2]) == 0x101]
    lossy = [p for i, p in enumerate(packets) if i != klv[3]]  # the second packet of the second PES
    rx2, out = _receive(b"".join(lossy))
    assert rx2.stats.cc_errors == 1 and rx2.stats.damaged_pes == 1
    assert [r.pts for r in out if isinstance(r, Packet)] == [90000, 270000]

    from geoloc.io.live import TsDemuxer

    pts, dts = 93003, 90000
    hdr = (
        bytes([0x84, 0xC0, 0x0A])
        + bytes([0x31 | ((pts >> 29) & 0x0E)])
        + _pts_bytes(pts)[1:]
        + bytes([0x11 | ((dts >> 29) & 0x0E)])
        + _pts_bytes(dts)[1:]
    )
    pes = b"\x00\x00\x01\xe0\x00\x00" + hdr + bytes(100)
    d = TsDemuxer()
    units = d.feed_datagram(b"".join(_psi_packets(pmt) + _ts_packets(0x102, pes, 0)[0]))
    units += d.flush()
    v = [u for u in units if u.kind == "video"]
    assert [(u.pts, u.dts) for u in v] == [(pts, dts)]
