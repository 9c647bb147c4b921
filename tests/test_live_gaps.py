"""Live UDP (geoloc.io.live): the cases issue 50's mutation audit found never sent.

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
    return bytes([0x21 | ((pts >> 29) & 0x0E), (pts >> 22) & 0xFF, 0x01 | ((pts >> 14) & 0xFE), (pts >> 7) & 0xFF,
                  0x01 | ((pts << 1) & 0xFE)])


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
    sec = [0, 1, 2, 3, 4, 2, 3, 4, 5, 6, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]   # back 2 s, back 5 s (not over)
    pts = [base + s * TICKS for s in sec]
    pts += [pts[-1] - 5 * TICKS - 1]                      # back 5 s and one tick: a restart
    pts += [pts[-1] + TICKS, pts[-1] + 2 * TICKS]
    pts += [pts[-1] - 4 * TICKS - TICKS // 2]             # back 4.5 s: not a restart
    pts += [pts[-1] - 20 * TICKS]                         # back 20 s: a restart
    pts += [pts[-1] + 45]                                 # half a millisecond on
    pts += [pts[-1] - 60]                                 # back 2/3 ms: not a restart
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
            seq.append(p)                     # the same packet again, right after it (the same datagram)
    ts = b"".join(seq)
    # both copies of each repeated packet are in one 7-packet datagram
    for i in (first_of_4th, second_of_8th):
        j = seq.index(packets[i])
        assert j // 7 == (j + 1) // 7 and seq[j] == seq[j + 1]
    rx, out = _receive(ts)
    assert [r.pts for r in out] == pts                    # each once, in order
    assert [r.fields for r in out] == [p.fields for p in pk]
    assert rx.stats.duplicates == 2 and rx.stats.cc_errors == 0 and rx.stats.bad_packets == 0


def test_a_repeated_counter_with_other_bytes_is_a_continuity_error_not_a_duplicate():
    """The same counter on different bytes is no duplicate (2.4.3.3: a duplicate repeats the
    packet's bytes): a continuity error, the PES it broke is damaged, the others come out."""
    pts = [90000 * i for i in range(8)]
    pk = _klv_packets(len(pts))
    packets = _stream(pts, pk)
    klv = [i for i, p in enumerate(packets) if ((p[1] & 0x1F) << 8 | p[2]) == 0x101]
    k = klv[2 * 4 + 1]                                    # the second packet of the 5th PES
    fake = bytearray(packets[k])
    fake[-1] ^= 0xFF                                      # the same header and counter, another last byte
    seq = packets[:k + 1] + [bytes(fake)] + packets[k + 1:]
    rx, out = _receive(b"".join(seq))
    good = [r.pts for r in out if isinstance(r, Packet)]
    assert rx.stats.duplicates == 0 and rx.stats.cc_errors >= 1
    assert set(good) >= set(pts[:4] + pts[5:])            # every PES the fake packet did not touch
