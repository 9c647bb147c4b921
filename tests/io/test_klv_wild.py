"""MISB KLV as writers in the wild produce it, and the bad KLV inputs a user meets.

Every stream here is built in the test, the way a writer in the wild builds it (docs/klv.md,
"Encoders in the wild", says which writer and where it is documented); nothing fetched is
committed. Values are checked item by item against klvdata, the independent ST 0601 decoder
of the test extra, wherever klvdata decodes the item; EG 0104 against values written from the
standard's item table (float32 / float64 per item), its keys against the "US key" column of
ST 0601's table as klvdata transcribes it; transport streams are written by tests/ts_builder.py
(from ISO/IEC 13818-1) and read by geoloc's demuxer and by PyAV (FFmpeg).
"""

from __future__ import annotations

import io
import json
import math
import struct
import subprocess
import sys
import threading
from pathlib import Path

import klvdata  # test dependency: an independent decoder (installed by the test extras, never skipped)
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from klvdata.misb0102 import SecurityClassification

import ts_builder as tb
from geoloc.io import klv
from geoloc.io.klv import Packet, QuirkTally
from geoloc.io.klv_sets import EG0104_ITEMS, EG0104_KEY, encode_local_set
from geoloc.io.live import LiveReceiver, klv_as_ts

ROOT = Path(__file__).resolve().parents[2]
KEY = klv.UAS_LS_KEY


def item(tag: int, value: bytes) -> bytes:
    return klv.ber_oid(tag) + klv.ber_length(len(value)) + value


def packet(items: bytes) -> bytes:
    """A UAS LS packet of these items with its checksum (MISB ST 0601 tag 1), computed in the test:
    the 16-bit sum of the big-endian words from the key to the checksum's length byte."""
    head = KEY + klv.ber_length(len(items) + 4) + items + b"\x01\x02"
    words = head + (b"\0" if len(head) % 2 else b"")  # an odd last byte is the high byte of a word
    s = sum(int.from_bytes(words[i : i + 2], "big") for i in range(0, len(words), 2)) & 0xFFFF
    return head + s.to_bytes(2, "big")


def raw_of(spec, value: float, n: int) -> bytes:
    """The item's raw count at the standard's step, written in n bytes (big-endian, two's
    complement for a signed item): how the writers below pad or trim an integer item."""
    raw = round((value - spec.lo) / spec.step) if spec.kind == "uint" else round(value / spec.step)
    return raw.to_bytes(n, "big", signed=spec.kind == "int")


def klvdata_items(data: bytes) -> list[dict]:
    """klvdata's decoding of each packet: tag -> value string."""
    return [{tag: v[3] for tag, v in p.MetadataList().items()} for p in klvdata.StreamParser(data)]


def agree_with_klvdata(ours: Packet, theirs: dict) -> int:
    """Every ST 0601 field of ours that klvdata decodes equals klvdata's value; returns the count."""
    n = 0
    for name, v in ours.fields.items():
        spec = klv.TAG_BY_NAME.get(name)
        if spec is None or spec.tag not in theirs:
            continue
        s = theirs[spec.tag]
        if spec.kind == "str":
            assert s == v, name
        elif spec.kind == "u64":
            from datetime import datetime

            assert abs(datetime.fromisoformat(s).timestamp() * 1e6 - v) < 2, name  # klvdata: float seconds
        elif isinstance(v, float) and math.isnan(v):
            # ours: out of what the standard's length holds, NaN flagged; klvdata maps it anyway,
            # beyond the item's range: both say it is not a value of the standard's range
            assert ours.flags[name] in ("out of range", "error"), name
            assert not spec.lo <= float(s) <= spec.hi or ours.flags[name] == "error", (name, s)
        else:
            # the same line (slope (hi - lo) / (standard's max - min)), so equal up to float rounding
            assert float(s) == pytest.approx(v, rel=1e-12, abs=1e-12 * max(spec.hi - spec.lo, 1)), (name, s, v)
        n += 1
    return n


# --------------------------------------------------------------------------- the checksum helper


def test_the_tests_checksum_is_the_standards():
    # MISB ST 0601 Tag 1's example: 06 0E 2B 34 02 00 81 BB sums to 0xB4FD (klvdata's too)
    from klvdata.common import packet_checksum

    p = packet(item(5, b"\x71\xc2"))
    assert klv.decode_packet(p).checksum == int.from_bytes(packet_checksum(p), "big")


# --------------------------------------------------------------------------- lengths


def test_target_width_in_four_bytes_is_decoded_and_agrees_with_klvdata():
    """Before: `klv dump` refused every packet of a stream whose tag 22 (Target Width) is 4 bytes
    ("has length 4, expected 2", once per packet); klvdata read the same packets."""
    spec = klv.TAG_BY_NUMBER[22]
    rows = []
    for i, width in enumerate([150.0, 722.82, 0.0, 9999.8]):
        items = (
            item(2, (1_600_000_000_000_000 + i * 33_333).to_bytes(8, "big"))
            + item(5, raw_of(klv.TAG_BY_NUMBER[5], 159.97, 2))
            + item(13, raw_of(klv.TAG_BY_NUMBER[13], 36.3, 4))
            + item(22, raw_of(spec, width, 4))
        )
        rows.append(packet(items))
    data = b"".join(rows)
    res = list(klv.iter_packets(data))
    assert all(isinstance(r, Packet) for r in res) and len(res) == 4
    theirs = klvdata_items(data)
    for r, t, width in zip(res, theirs, [150.0, 722.82, 0.0, 9999.8]):
        assert agree_with_klvdata(r, t) == 4
        assert abs(r["target_width_m"] - width) <= spec.step / 2  # the writer's value, to a half step
        assert r.quirks == (
            "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's step",
        )
    # once per kind: one line, the count, the first packet's offset
    tally = QuirkTally()
    for r in res:
        tally.add(r)
    assert tally.lines() == [
        "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with "
        "the standard's step (4 packets, the first at byte 0)"
    ]


def _domain(spec) -> tuple[int, int]:
    """The raw counts the standard's length holds (klvdata's domain; the sentinel excluded)."""
    if spec.kind == "int":
        m = (1 << (8 * spec.size - 1)) - 1
        return -m, m
    return 0, (1 << (8 * spec.size)) - 1


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_any_integer_item_at_any_length_agrees_with_klvdata(data):
    """Each mapped or integer item given in 1 to 8 bytes (leading bytes added or left out, as the
    writers of docs/klv.md do), its raw count random: where the standard's length holds the count,
    our value is klvdata's; where it does not (klvdata refuses the item), ours is NaN flagged
    'out of range' (or the reserved meaning, for the standard's sentinel sign-extended)."""
    specs = [s for s in klv.TAGS if s.kind in ("uint", "int")]
    chosen = data.draw(st.lists(st.sampled_from(specs), min_size=1, max_size=6, unique_by=lambda s: s.tag))
    inside, outside = b"", []
    for s in chosen:
        n = data.draw(st.integers(1, 8))
        signed = s.kind == "int"
        lo, hi = (-(1 << (8 * n - 1)), (1 << (8 * n - 1)) - 1) if signed else (0, (1 << (8 * n)) - 1)
        raw = data.draw(st.integers(lo, hi))
        b = item(s.tag, raw.to_bytes(n, "big", signed=signed))
        a, z = _domain(s)
        if a <= raw <= z:
            inside += b
        else:
            outside.append((s, raw, b))
    if inside:
        p = packet(inside)
        (ours,) = klv.iter_packets(p)
        assert isinstance(ours, Packet)
        (theirs,) = klvdata_items(p)
        assert agree_with_klvdata(ours, theirs) == len(ours.fields)
        # the batch decoder (numpy) gives the same packets
        for b in klv.iter_packets(p * 20):
            assert b.flags == ours.flags and b.quirks == ours.quirks and b.fields == ours.fields
    for s, raw, b in outside:
        (ours,) = klv.iter_packets(packet(b))
        assert math.isnan(ours[s.name]), (s.name, raw)
        sentinel = raw == -(1 << (8 * s.size - 1))
        assert ours.flags[s.name] == (s.reserved if sentinel else "out of range")
        batched = list(klv.iter_packets(packet(b) * 20))
        assert all(math.isnan(q[s.name]) and q.flags == ours.flags for q in batched)


def test_short_and_empty_items_and_the_limit_of_eight_bytes(tmp_path):
    """Leading zero bytes left out (tag 21 in 2 bytes, tag 65 in 2 with a leading zero), an empty
    tag 25 (taken as absent), a signed item in 1 byte: kept; a 9-byte integer: the packet dropped
    with its offset and reason."""
    good = packet(item(21, (12345).to_bytes(2, "big")) + item(65, b"\x00\x0d") + item(25, b"") + item(19, b"\xfe"))
    bad = packet(item(5, bytes(7) + b"\x71\xc2"))
    path = tmp_path / "w.klv"
    path.write_bytes(good + bad + good)
    res = list(klv.read_klv_file(path))
    assert [type(r).__name__ for r in res] == ["Packet", "KlvError", "Packet"]
    p = res[0]
    assert p["slant_range_m"] == pytest.approx(12345 * klv.TAG_BY_NUMBER[21].step, rel=1e-15)
    assert p["uas_ls_version"] == 13 and "frame_center_elevation_m" not in p.fields
    assert p["sensor_relative_elevation_deg"] == pytest.approx(-2 * klv.TAG_BY_NUMBER[19].step, rel=1e-15)
    assert agree_with_klvdata(p, klvdata_items(good)[0]) == 3
    assert res[1].offset == len(good) and "tag 5 (Platform Heading Angle) has length 9" in res[1].reason
    # the CLI: the dropped packet named (file, byte offset), each quirk once with its count, exit 1
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "klv", "dump", str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode == 1, r.stderr
    err = r.stderr.splitlines()
    assert f"geoloc klv: {path}: byte {len(good)}: tag 5 (Platform Heading Angle) has length 9" in err[0]
    quirks = [e for e in err if ": quirk: " in e]
    assert len(quirks) == 4  # 21 in 2 bytes, 65 in 2, 25 empty, 19 in 1: each once, for 2 packets
    assert all(e.endswith("(2 packets, the first at byte 0)") for e in quirks), quirks
    assert len(r.stdout.splitlines()) == 2


def test_quirks_are_counted_alike_by_the_batch_and_the_packet_decoders():
    spec = klv.TAG_BY_NUMBER[22]
    plain = packet(item(5, b"\x71\xc2"))
    wide = packet(item(5, b"\x71\xc2") + item(22, raw_of(spec, 300.0, 4)))
    data = plain * 3 + wide * 40 + plain + wide * 5
    by_packet = QuirkTally()
    for r in klv.iter_packets(data):
        by_packet.add(r)
    batch = QuirkTally()
    cols = klv.packets_to_columns(data, quirks=batch)
    assert len(cols["offset"]) == 49
    assert (
        by_packet.lines()
        == batch.lines()
        == [
            "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's step "
            f"(45 packets, the first at byte {3 * len(plain)})"
        ]
    )
    np.testing.assert_allclose(cols["target_width_m"][3:43], 300.0, atol=spec.step / 2)


def test_non_minimal_ber_lengths_are_read():
    """A BER length in more bytes than it needs (82 00 04 for 4), as jmisb wrote some before its
    fix (jmisb #124): the same value, nothing to report."""
    items = b"\x05\x82\x00\x02\x71\xc2" + item(13, raw_of(klv.TAG_BY_NUMBER[13], 36.3, 4))
    head = KEY + b"\x83\x00\x00" + bytes((len(items) + 4,)) + items + b"\x01\x02"
    words = head + (b"\0" if len(head) % 2 else b"")
    ck = sum(int.from_bytes(words[i : i + 2], "big") for i in range(0, len(words), 2)) & 0xFFFF
    p = head + ck.to_bytes(2, "big")
    (ours,) = klv.iter_packets(p)
    assert ours.quirks == () and ours["platform_heading_deg"] == pytest.approx(0x71C2 * 360 / 65535)
    assert agree_with_klvdata(ours, klvdata_items(p)[0]) == 2


def test_the_replay_of_a_quirky_older_stream_equals_the_standard_ones():
    """An older writer's packets (no version tag 65, no time stamp, no HAE items: ST 0601's early
    item set) with Target Width in 4 bytes: the replay reads every packet, says the quirk once,
    and locates each frame centre as for the same packets written to the standard."""
    from geoloc.workflows.klv_replay import replay_klv

    base = dict(
        platform_heading_deg=90.0,
        platform_pitch_deg=1.0,
        platform_roll_deg=0.5,
        sensor_latitude_deg=36.3,
        sensor_longitude_deg=-84.2,
        sensor_true_altitude_m=1500.0,
        sensor_horizontal_fov_deg=10.0,
        sensor_vertical_fov_deg=6.0,
        sensor_relative_azimuth_deg=10.0,
        sensor_relative_elevation_deg=-45.0,
        sensor_relative_roll_deg=0.0,
        frame_center_latitude_deg=36.31,
        frame_center_longitude_deg=-84.19,
        frame_center_elevation_m=300.0,
    )
    spec = klv.TAG_BY_NUMBER[22]
    std, quirky = [], []
    for i in range(20):
        f = dict(base, platform_heading_deg=90.0 + i)
        body = klv.encode_packet(f, with_checksum=False)[17:]
        std.append(packet(body + item(22, raw_of(spec, 150.0, 2))))
        quirky.append(packet(body + item(22, raw_of(spec, 150.0, 4))))
    a, b = replay_klv(b"".join(std)), replay_klv(b"".join(quirky))
    assert len(a) == len(b) == 20 and not b.errors
    assert [line for line in str(b.summary).splitlines() if "quirk" in line] == [
        "  quirk: tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's "
        "step (20 packets, the first at byte 0)"
    ]
    for name in ("lat_deg", "lon_deg", "h_m", "frame_center_error_m"):
        assert np.isfinite(a.columns[name]).all()
        np.testing.assert_array_equal(a.columns[name], b.columns[name])


def test_klv_dump_exit_codes():
    """Before: `klv dump` of a file with no decodable packet exited 0. Now 0 all decoded,
    1 some not, 2 none."""
    good = packet(item(5, b"\x71\xc2"))
    bad = bytearray(good)
    bad[-1] ^= 0xFF

    def run(data, tmp):
        p = tmp / "x.klv"
        p.write_bytes(data)
        return subprocess.run(
            [sys.executable, "-m", "geoloc", "klv", "dump", str(p)],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
        )

    import tempfile

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        assert run(good * 2, d).returncode == 0
        r = run(good + bytes(bad), d)
        assert r.returncode == 1 and "1 packets decoded, 1 could not be" in r.stderr
        r = run(bytes(bad) * 3, d)
        assert r.returncode == 2 and r.stdout == ""
        assert "3 packets found, none could be decoded" in r.stderr and r.stderr.count("checksum mismatch") == 3


# --------------------------------------------------------------------------- EG 0104


def _udskey(tag: int) -> bytes | None:
    """klvdata's transcription of the 'US key' column of ST 0601's table for one tag."""
    import klvdata.misb0601 as m

    for obj in vars(m).values():
        if isinstance(obj, type) and getattr(obj, "TAG", None) == tag:
            k = getattr(obj, "UDSKey", "-").strip()
            return None if k == "-" else bytes.fromhex(k.replace(" ", ""))
    return None


def test_eg0104_keys_are_the_us_keys_of_st0601s_table():
    """EG 0104's item keys are the universal keys ST 0601 lists for its items ('US key'): each
    of ours equals klvdata's transcription, byte 8 (the registry version) aside."""
    checked = 0
    for key, (name, _) in EG0104_ITEMS.items():
        spec = klv.TAG_BY_NAME.get(name)
        if spec is None:
            continue
        theirs = _udskey(spec.tag)
        if theirs is None:
            continue
        assert key[:7] + key[8:] == theirs[:7] + theirs[8:], name
        checked += 1
    assert checked >= 20


# Values written from EG 0104.5's item table: angles, altitudes, ranges as IEEE floats (4 bytes),
# latitudes and longitudes as doubles (8 bytes), the time stamp as microseconds (8 bytes), text.
_EG = {
    "platform_heading_deg": (">f", 159.97),
    "platform_pitch_full_deg": (">f", -0.43),
    "platform_roll_full_deg": (">f", 3.41),
    "sensor_latitude_deg": (">d", 60.1768229669783),
    "sensor_longitude_deg": (">d", 128.426759042045),
    "sensor_true_altitude_m": (">f", 14190.7),
    "sensor_horizontal_fov_deg": (">f", 2.5),
    "sensor_vertical_fov_deg": (">f", 1.4),
    "slant_range_m": (">f", 7500.25),
    "target_width_m": (">f", 722.8),
    "frame_center_latitude_deg": (">d", 60.1121),
    "frame_center_longitude_deg": (">d", 128.4912),
    "frame_center_elevation_m": (">f", 312.5),
    "corner_latitude_1_deg": (">d", 60.12),
    "corner_longitude_4_deg": (">d", 128.48),
    "eg0104_angle_to_north_deg": (">f", 211.5),
    "eg0104_obliquity_angle_deg": (">f", 35.25),
}


def eg0104_packet(i: int = 0, extra=()) -> bytes:
    key_of = {name: k for k, (name, _) in EG0104_ITEMS.items()}
    items = [
        (key_of["precision_time_stamp_us"], (1_224_807_209_913_000 + i * 33_000).to_bytes(8, "big")),
        (key_of["mission_id"], b"EPISODE 7"),
        (key_of["image_source_sensor"], b"EO Nose"),
    ]
    items += [(key_of[n], struct.pack(f, v)) for n, (f, v) in _EG.items()]
    items += list(extra)
    body = b"".join(k + klv.ber_length(len(v)) + v for k, v in items)
    return EG0104_KEY + klv.ber_length(len(body)) + body


def check_eg0104(p: Packet, i: int = 0):
    assert p["precision_time_stamp_us"] == 1_224_807_209_913_000 + i * 33_000
    assert p["mission_id"] == "EPISODE 7" and p["image_source_sensor"] == "EO Nose"
    for name, (f, v) in _EG.items():
        want = float(np.float32(v)) if f == ">f" else v  # a float32 item holds the nearest float32
        assert p[name] == want, name


def test_eg0104_packets_read_into_the_st0601_fields_beside_st0601_ones():
    st0601 = packet(item(5, b"\x71\xc2"))
    unknown_item = (bytes.fromhex("060E2B34010101010E01020304050607"), b"\x01\x02")
    # byte 8 of a key (the registry version) as another writer sets it: the same item
    other_version = bytearray(next(k for k, (n, _) in EG0104_ITEMS.items() if n == "slant_range_m"))
    data = st0601 + eg0104_packet(0, [unknown_item]) + b"junk" + eg0104_packet(1) + st0601
    res = list(klv.iter_packets(data))
    kinds = [type(r).__name__ for r in res]
    assert kinds == ["Packet", "Packet", "KlvError", "Packet", "Packet"], res
    check_eg0104(res[1], 0)
    check_eg0104(res[3], 1)
    assert res[1].offset == len(st0601) and res[1].checksum is None
    assert "4 bytes before the next UAS LS key" in res[2].reason
    tally = QuirkTally()
    for r in res:
        tally.add(r)
    assert len(tally) == 1 and tally.lines()[0].startswith("EG 0104 Predator UAV Basic Universal Set")
    assert "(2 packets, the first at byte " in tally.lines()[0]
    # streamed in small chunks: the same results
    small = list(klv.iter_packets(io.BytesIO(data), chunk_size=7))
    assert [type(r).__name__ for r in small] == kinds and small[3].fields == res[3].fields
    other_version[7] = 0x02
    p = list(
        klv.iter_packets(EG0104_KEY + klv.ber_length(21) + bytes(other_version) + b"\x04" + struct.pack(">f", 1234.5))
    )
    assert p[0]["slant_range_m"] == 1234.5


def test_eg0104_in_a_transport_stream(tmp_path):
    data = tb.stream([eg0104_packet(i) for i in range(3)])
    path = tmp_path / "eg0104.ts"
    path.write_bytes(data)
    for res in (list(klv.read_packets(path)), _live(data)):
        assert [r.pts for r in res] == [0, 3000, 6000]
        for i, r in enumerate(res):
            check_eg0104(r, i)


# --------------------------------------------------------------------------- nested sets


def test_security_local_set_agrees_with_klvdata():
    sec = encode_local_set([(1, b"\x03"), (2, b"\x07"), (3, b"//USA"), (5, b"REL TO"), (22, b"\x00\x0c")])
    p = packet(item(5, b"\x71\xc2") + item(48, sec))
    (ours,) = klv.iter_packets(p)
    (theirs,) = klvdata.StreamParser(p)
    nested = next(e for e in theirs.items.values() if type(e).__name__ == "SecurityLocalMetadataSet")
    cls = nested.items[b"\x01"]
    assert ours["security_classification"] == SecurityClassification._classification[bytes(cls.value.value)]
    assert ours["security_classification"] == "CONFIDENTIAL"
    assert ours["security_classifying_country"] == "//USA" and ours["security_caveats"] == "REL TO"
    assert ours["security_version"] == 12 and ours.unknown[48] == sec  # the raw set kept
    # written back: the encoder skips the derived names and writes the raw set
    again = klv.encode_packet(ours.fields, unknown=ours.unknown)
    assert klv.decode_packet(again).fields == ours.fields


def vmti_value(width: int, targets) -> bytes:
    """An ST 0903 VMTI Local Set written in the test from the standard's layout: tag 4 version,
    8 frame width, 9 frame height, 101 VTarget Series of (BER length, target id, items 1 centroid,
    2 and 3 the box corners as pixel numbers column + (row - 1) x width, 5 confidence)."""

    def tlv(tag, v):
        return bytes((tag,)) + bytes((len(v),)) + v

    def pixnum(row, col):
        n = col + (row - 1) * width
        return n.to_bytes(4, "big")

    series = b""
    for tid, c, tl, br, conf in targets:
        pack = bytes((tid,)) + tlv(1, pixnum(*c)) + tlv(2, pixnum(*tl)) + tlv(3, pixnum(*br)) + tlv(5, bytes((conf,)))
        series += bytes((len(pack),)) + pack
    return (
        tlv(4, b"\x05")
        + tlv(5, b"\x02")
        + tlv(6, b"\x02")
        + tlv(8, width.to_bytes(2, "big"))
        + tlv(9, (720).to_bytes(2, "big"))
        + bytes((101,))
        + klv.ber_length(len(series))
        + series
    )


def test_vmti_detections_pixel_boxes():
    targets = [(1, (360, 640), (350, 600), (371, 681), 90), (2, (1, 1), (1, 1), (720, 1280), 40)]
    p = packet(item(5, b"\x71\xc2") + item(74, vmti_value(1280, targets)))
    (ours,) = klv.iter_packets(p)
    assert ours["vmti_frame_width_px"] == 1280 and ours["vmti_frame_height_px"] == 720
    assert ours["vmti_targets_reported"] == 2 and ours["vmti_version"] == 5
    dets = ours["vmti_detections"]
    assert [d["id"] for d in dets] == [1, 2]
    for d, (_, c, tl, br, conf) in zip(dets, targets):
        assert (d["centroid_row"], d["centroid_col"]) == c
        assert (d["box_top_left_row"], d["box_top_left_col"]) == tl
        assert (d["box_bottom_right_row"], d["box_bottom_right_col"]) == br
        assert d["confidence_pct"] == conf
    json.dumps(ours.to_json(), allow_nan=False)  # the dump line
    # klvdata 0.0.3 cannot read tag 74 (its VMTILocalSet is an abstract class: TypeError): it
    # checks the ST 0601 items of the same packet without it
    assert agree_with_klvdata(ours, klvdata_items(packet(item(5, b"\x71\xc2")))[0]) == 1


def test_a_vmti_set_that_cannot_be_read_keeps_the_packet_once_per_kind():
    broken = vmti_value(1280, [(1, (2, 2), (1, 1), (3, 3), 50)])[:-3]  # its series cut short
    p = packet(item(5, b"\x71\xc2") + item(74, broken))
    res = list(klv.iter_packets(p * 30))
    assert len(res) == 30 and all(isinstance(r, Packet) for r in res)
    assert res[0]["platform_heading_deg"] == pytest.approx(0x71C2 * 360 / 65535)
    assert "vmti_detections" not in res[0].fields and res[0].unknown[74] == broken
    tally = QuirkTally()
    for r in res:
        tally.add(r)
    (line,) = tally.lines()
    assert (
        line.startswith("tag 74 (VMTI Local Set, ST 0903) cannot be read")
        and "(30 packets, the first at byte 0)" in line
    )


# --------------------------------------------------------------------------- transport streams


def _live(data: bytes, chunk: int = 1000) -> list:
    rx = LiveReceiver()
    out = []
    for k in range(0, len(data), chunk):
        out += rx.push_bytes(data[k : k + chunk])
    return out + rx.flush()


def _wild_packets(n=4, vmti=True):
    """ST 0601 packets of 317 bytes (two TS packets each) with a 4-byte tag 22 and a VMTI set
    (``vmti=False``: the same without it, for klvdata, which cannot read tag 74)."""
    out = []
    for i in range(n):
        items = (
            item(2, (1_600_000_000_000_000 + i * 33_333).to_bytes(8, "big"))
            + item(3, b"M" * 100)
            + item(5, raw_of(klv.TAG_BY_NUMBER[5], 10.0 * i, 2))
            + item(22, raw_of(klv.TAG_BY_NUMBER[22], 150.0 + i, 4))
            + (item(74, vmti_value(1280, [(1, (360, 640), (350, 600), (371, 681), 90)])) if vmti else b"")
            + item(200, b"x" * 100)
        )
        out.append(packet(items))
    return out


@pytest.mark.parametrize(
    "layout", ["async", "sync", "programs", "no_psi_bd", "no_psi_fc", "no_psi_foreign_id", "async_type_sync_id"]
)
def test_klv_in_transport_streams_as_multiplexers_write_them(tmp_path, layout):
    # async_type_sync_id: stream type 0x06 (KLVA) with the metadata stream id 0xFC, as jmisb wrote
    # it before its fix (jmisb #119)
    kw = {
        "async": {},
        "sync": {"sync": True},
        "programs": {"programs": 2},
        "async_type_sync_id": {"stream_id": 0xFC},
        "no_psi_bd": {"psi": False},
        "no_psi_fc": {"psi": False, "sync": True},
        "no_psi_foreign_id": {"psi": False, "stream_id": 0xC0},
    }[layout]
    pk = _wild_packets()
    assert all(len(b) > 184 for b in pk)  # each split across TS packets
    data = tb.stream(pk, **kw)
    path = tmp_path / f"{layout}.ts"
    path.write_bytes(data)
    theirs = klvdata_items(b"".join(_wild_packets(vmti=False)))
    for res in (list(klv.read_packets(path)), _live(data)):
        assert [type(r).__name__ for r in res] == ["Packet"] * 4, res
        assert [r.pts for r in res] == [0, 3000, 6000, 9000]
        for r, t, b in zip(res, theirs, pk):
            assert r.fields == klv.decode_packet(b).fields
            assert agree_with_klvdata(r, t) == 4
            assert r["vmti_detections"][0]["centroid_col"] == 640


def test_a_transport_stream_without_klv_still_says_so(tmp_path):
    m = tb.Mux()
    m.section(0, tb.pat({1: 0x1000}))
    m.section(0x1000, tb.pmt(1, 0x100, [(0x1B, 0x100, b"")]))
    m.packets(0x100, tb.pes(0xE0, b"\x00\x00\x00\x01\x09\xf0" * 40, 0))
    path = tmp_path / "video.ts"
    path.write_bytes(m.bytes())
    with pytest.raises(ValueError, match="no data"):
        list(klv.read_packets(path))


# --------------------------------------------------------------------------- klv send of a raw .klv


def test_klv_send_of_raw_klv_sends_what_the_receiver_decodes(tmp_path, capsys):
    """Before: `klv send` of a raw .klv reported "sent" while the receiver decoded 0 packets."""
    from geoloc.cli import main
    from geoloc.io.live import open_socket, parse_udp_url, receive

    def free_port() -> int:
        import socket

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as so:
            so.bind(("127.0.0.1", 0))
            return so.getsockname()[1]

    pk = _wild_packets(6) + [eg0104_packet(3)]
    bad = bytearray(pk[2])
    bad[-1] ^= 0xFF
    pk[2] = bytes(bad)
    path = tmp_path / "flight.klv"
    path.write_bytes(b"".join(pk))
    ts, n, nbad = klv_as_ts(path)
    assert (n, nbad) == (6, 1)
    got = _live(ts)
    want = [r for r in klv.read_klv_file(path) if isinstance(r, Packet)]
    assert len(got) == 6 and [g.fields for g in got] == [w.fields for w in want]
    # over UDP, through the verb
    url = f"udp://127.0.0.1:{free_port()}"
    sock = open_socket(parse_udp_url(url))
    box = {}
    th = threading.Thread(
        target=lambda: box.update(res=list(receive(url, sock=sock, idle_s=1.0, duration_s=60))), daemon=True
    )
    th.start()
    assert main(["klv", "send", str(path), url, "--fast"]) == 0
    th.join(30)
    out = capsys.readouterr().out
    assert "6 KLV packets in an MPEG-TS" in out and "1 bad packets left out" in out
    assert [r.fields for r in box["res"] if isinstance(r, Packet)] == [w.fields for w in want]
    # nothing decodable: refused, exit 2, no datagram sent
    junk = tmp_path / "junk.klv"
    junk.write_bytes(bytes(bad) * 2)
    assert main(["klv", "send", str(junk), url, "--fast"]) == 2
    assert "no packet of it can be decoded" in capsys.readouterr().err


# --------------------------------------------------------------------------- fuzzing


def _consume(data: bytes) -> list:
    """Every reader of raw bytes: none may raise."""
    res = list(klv.iter_packets(data))
    list(klv.iter_packets(io.BytesIO(data), chunk_size=37))
    klv.packets_to_columns(data, quirks=QuirkTally())
    for r in res:
        json.dumps(r.to_json() if isinstance(r, Packet) else str(r), allow_nan=False)
    return res


_KEYS = st.sampled_from([KEY, EG0104_KEY, KEY[:9], b"\x06\x0e\x2b\x34"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(st.binary(max_size=64), _KEYS), max_size=12))
def test_random_bytes_around_keys_never_raise(parts):
    data = b"".join(parts)
    _consume(data)
    rx = LiveReceiver()
    rx.push_bytes(data)
    rx.flush()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_a_mutated_packet_never_raises_and_the_good_ones_around_it_are_kept(data):
    pk = _wild_packets(3) + [eg0104_packet(0), packet(item(5, b"\x71\xc2") + item(22, b"\x00\x00\x03\xd7"))]
    pk = pk * 2
    i = data.draw(st.integers(0, len(pk) - 1))
    b = bytearray(pk[i])
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["flip", "insert", "delete"]))
        k = data.draw(st.integers(0, max(len(b) - 1, 0)))
        if op == "flip" and b:
            b[k] ^= data.draw(st.integers(1, 255))
        elif op == "insert":
            b[k:k] = data.draw(st.binary(min_size=1, max_size=8))
        elif b:
            del b[k]
    mutated = pk[:i] + [bytes(b)] + pk[i + 1 :]
    res = _consume(b"".join(mutated))
    good = [r for r in res if isinstance(r, Packet)]
    # every untouched packet is found at its offset with its values
    offsets = np.cumsum([0] + [len(x) for x in mutated])
    by_offset = {r.offset: r for r in good}
    for j, x in enumerate(mutated):
        if j == i:
            continue
        r = by_offset.get(int(offsets[j]))
        assert r is not None, (j, [(type(q).__name__, q.offset) for q in res])
        assert r.fields.keys() == next(iter(klv.iter_packets(x))).fields.keys()


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutated_transport_streams_never_raise_and_keep_the_untouched_packets(data):
    pk = _wild_packets(4)
    sync = data.draw(st.booleans())
    ts = bytearray(tb.stream(pk, sync=sync))
    n = len(ts) // 188
    hit = data.draw(st.integers(0, n - 1))
    for _ in range(data.draw(st.integers(1, 6))):
        k = hit * 188 + data.draw(st.integers(0, 187))
        ts[k] ^= data.draw(st.integers(1, 255))
    res = _live(bytes(ts), chunk=data.draw(st.sampled_from([188, 1316, 1000, 7])))
    rx = LiveReceiver()
    for g in range(0, len(ts), 1316):
        rx.push(bytes(ts[g : g + 1316]), now=g / 1e6)
    rx.flush()
    # a flipped byte damages at most the PES of that TS packet: the other three are decoded (a
    # broken PAT or PMT hides nothing: the PES are found by their stream id and key)
    good = [r for r in res if isinstance(r, Packet)]
    want = [klv.decode_packet(b).fields for b in pk]
    assert len(good) >= 3 and all(r.fields in want for r in good)


def test_klv_fix_rewrites_an_item_given_at_another_length(tmp_path):
    """`klv fix` replaces the frame-centre items: one a writer gave in 4 bytes (tag 25) is
    rewritten at the standard's 2 bytes (the packet's length redone), every other item kept."""
    from geoloc.workflows.klv_fix import fix_klv

    base = dict(
        platform_heading_deg=90.0,
        platform_pitch_deg=1.0,
        platform_roll_deg=0.5,
        sensor_latitude_deg=36.3,
        sensor_longitude_deg=-84.2,
        sensor_true_altitude_m=1500.0,
        sensor_horizontal_fov_deg=10.0,
        sensor_vertical_fov_deg=6.0,
        sensor_relative_azimuth_deg=10.0,
        sensor_relative_elevation_deg=-45.0,
        sensor_relative_roll_deg=0.0,
        frame_center_latitude_deg=36.31,
        frame_center_longitude_deg=-84.19,
    )
    spec = klv.TAG_BY_NUMBER[25]
    pk = [
        packet(
            klv.encode_packet(dict(base, platform_heading_deg=90.0 + i), with_checksum=False)[17:]
            + item(25, raw_of(spec, 300.0, 4))
            + item(22, raw_of(klv.TAG_BY_NUMBER[22], 80.0, 4))
        )
        for i in range(5)
    ]
    src, out = tmp_path / "in.klv", tmp_path / "out.klv"
    src.write_bytes(b"".join(pk))
    fix = fix_klv(src, out)
    assert fix.packets == 5 and fix.rewritten == 5
    res = list(klv.read_klv_file(out))
    assert all(isinstance(r, Packet) for r in res) and len(res) == 5
    for r, b in zip(res, pk):
        old = klv.decode_packet(b)
        assert r.quirks == (
            "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's step",
        )  # tag 25 now at the standard's length
        assert r["target_width_m"] == old["target_width_m"] and r["platform_heading_deg"] == old["platform_heading_deg"]
        assert np.isfinite(r["frame_center_elevation_m"])
    # an EG 0104 packet among them is copied as it is, and said so
    eg = eg0104_packet(0)
    src.write_bytes(pk[0] + eg + pk[1])
    fix = fix_klv(src, out)
    assert fix.rewritten == 2 and any("EG 0104" in why for _, why in fix.unchanged)
    data = out.read_bytes()
    assert eg in data  # byte for byte
    kinds = [type(r).__name__ for r in klv.read_klv_file(out)]
    assert kinds == ["Packet"] * 3


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200), st.sampled_from(["vmti", "security", "eg0104"]))
def test_the_set_decoders_raise_only_their_own_error(value, which):
    """Random bytes into the nested-set and EG 0104 decoders: a value, or SetError (which the
    reader turns into a quirk of the packet, or a bad EG 0104 packet with its offset)."""
    from geoloc.io import klv_sets

    dec = {"vmti": klv_sets.decode_vmti, "security": klv_sets.decode_security, "eg0104": klv_sets.decode_eg0104}[which]
    try:
        dec(value)
    except klv_sets.SetError:
        pass
    # the same bytes inside a packet never raise, and the packet is kept
    tag = {"vmti": 74, "security": 48, "eg0104": 200}[which]
    (p,) = klv.iter_packets(packet(item(5, b"\x71\xc2") + item(tag, value)))
    assert isinstance(p, Packet) and p.unknown[tag] == value
    json.dumps(p.to_json(), allow_nan=False)


def test_filler_between_packets_is_named_a_few_times_then_counted(tmp_path):
    """Bytes between every packet (a writer's stuffing): no packet is lost; `klv dump` names the
    first three runs and counts the others in one line, instead of one line per packet."""
    good = packet(item(5, b"\x71\xc2"))
    path = tmp_path / "stuffed.klv"
    path.write_bytes((good + b"\xff" * 7) * 50)
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "klv", "dump", str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode == 0 and len(r.stdout.splitlines()) == 50
    err = r.stderr.splitlines()
    assert len(err) == 4 and err[-1].endswith(
        "and 47 more runs of bytes that are no UAS LS packet between packets (no packet lost)"
    )
