"""MISB ST 0601 KLV (geoloc.io.klv, geoloc klv dump).

The standard's own per-item examples (value <-> bytes), its example packet and
checksum, a cross-check against klvdata (an independent decoder), bad packets in
a stream, MPEG-TS through PyAV, encode -> decode round trips and the CLI verb.
"""

import io
import json
import math
import subprocess
import sys
from datetime import datetime, timezone
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geoloc.io import klv
from geoloc.io.klv import KlvError, Packet

import av  # PyAV, for MPEG-TS (a core dependency)
import klvdata  # test dependency: an independent decoder (installed by the test extras, never skipped)

ROOT = Path(__file__).resolve().parents[2]

# ----------------------------------------------------------------------------------------
# The standard's per-item examples (MISB ST 0601, the "Example Value" / "Example LS
# Packet" of each item's table; ST 0601.11 for most, ST 0601.17 where noted).
# (field, example value, value bytes)
EXAMPLES = [
    ("precision_time_stamp_us", 1224807209913000, "00 04 59 F4 A6 AA 4A A8"),  # 2008-10-24 00:13:29.913 UTC
    ("mission_id", "MISSION01", "4D 49 53 53 49 4F 4E 30 31"),
    ("platform_tail_number", "AF-101", "41 46 2D 31 30 31"),
    ("platform_heading_deg", 159.9744, "71 C2"),
    ("platform_pitch_deg", -0.4315251, "FD 3D"),
    ("platform_roll_deg", 3.405814, "08 B8"),
    ("platform_designation", "MQ1-B", "4D 51 31 2D 42"),
    ("image_source_sensor", "EO", "45 4F"),
    ("image_coordinate_system", "WGS-84", "57 47 53 2D 38 34"),
    ("sensor_latitude_deg", 60.17682296, "55 95 B6 6D"),
    ("sensor_longitude_deg", 128.42675904, "5B 53 60 C4"),
    ("sensor_true_altitude_m", 14190.72, "C2 21"),
    ("sensor_horizontal_fov_deg", 144.5713, "CD 9C"),
    ("sensor_vertical_fov_deg", 152.6436, "D9 17"),
    ("sensor_relative_azimuth_deg", 160.719211474396, "72 4A 0A 20"),
    ("sensor_relative_elevation_deg", -168.792324833941, "87 F8 4B 86"),
    ("sensor_relative_roll_deg", 176.865437690572, "7D C5 5E CE"),
    ("slant_range_m", 68590.98, "03 83 09 26"),  # the standard prints the value to 1 cm
    ("target_width_m", 722.8199, "12 81"),
    ("frame_center_latitude_deg", -10.5423886331461, "F1 01 A2 29"),
    ("frame_center_longitude_deg", 29.157890122923, "14 BC 08 2B"),
    ("frame_center_elevation_m", 3216.037, "34 F3"),
    # Offset corners: the corner minus the frame centre (-10.5423886331461, 29.157890122923).
    ("offset_corner_latitude_1_deg", -10.579637999887 + 10.5423886331461, "C0 6E"),
    ("offset_corner_longitude_1_deg", 29.1273677986333 - 29.157890122923, "CB E9"),
    ("offset_corner_latitude_2_deg", -10.5661816260963 + 10.5423886331461, "D7 65"),
    ("offset_corner_longitude_2_deg", 29.140824172424 - 29.157890122923, "E2 E0"),
    ("offset_corner_latitude_3_deg", -10.5527275411938 + 10.5423886331461, "EE 5B"),
    ("offset_corner_longitude_3_deg", 29.1542782573265 - 29.157890122923, "F9 D6"),
    ("offset_corner_latitude_4_deg", -10.5392711674031 + 10.5423886331461, "05 52"),
    ("offset_corner_longitude_4_deg", 29.1677346311172 - 29.157890122923, "10 CD"),
    ("target_location_latitude_deg", -79.1638500518929, "8F 69 52 62"),
    ("target_location_longitude_deg", 166.400812960416, "76 54 57 F2"),
    ("target_location_elevation_m", 18389.05, "F8 23"),
    ("target_error_ce90_m", 425.2152, "1A 95"),  # ST 0601.17
    ("target_error_le90_m", 608.9231, "26 11"),  # ST 0601.17
    ("uas_ls_version", 13, "0D"),  # ST 0601.17
    ("sensor_ellipsoid_height_m", 14190.72, "C2 21"),
    ("frame_center_hae_m", 9.445334, "0B B3"),
    ("corner_latitude_1_deg", -10.579637999887, "F0 F4 12 44"),
    ("corner_longitude_1_deg", 29.1273677986333, "14 B6 79 B9"),
    ("corner_latitude_2_deg", -10.5661816260963, "F0 F8 F8 7E"),
    ("corner_longitude_2_deg", 29.140824172424, "14 B8 EC D6"),
    ("corner_latitude_3_deg", -10.5527275411938, "F0 FD DE 81"),
    ("corner_longitude_3_deg", 29.1542782573265, "14 BB 5F D8"),
    ("corner_latitude_4_deg", -10.5392711674031, "F1 02 C4 BB"),
    ("corner_longitude_4_deg", 29.1677346311172, "14 BD D2 F5"),
    ("platform_pitch_full_deg", -0.4315251, "FF 62 E2 F2"),
    ("platform_roll_full_deg", 3.405814, "04 D8 04 DF"),
]
#: Printed precision of an example value where the standard rounds it more than a step.
PRINTED = {"slant_range_m": 0.005}

# The example local set of MISB ST 0601.17 (every item, tags 2..142, in the standard's
# order), one item a line: BER-OID tag, BER length, value. With the key, the long-form
# length 82 03 BB and the checksum item 01 02 58 02 it is the standard's example packet.
ST0601_17_ITEMS = """
02 08 00 04 59 F4 A6 AA 4A A8
03 09 4D 49 53 53 49 4F 4E 30 31
04 06 41 46 2D 31 30 31
05 02 71 C2
06 02 FD 3D
07 02 08 B8
08 01 93
09 01 9F
0A 05 4D 51 31 2D 42
0B 02 45 4F
0C 0E 47 65 6F 64 65 74 69 63 20 57 47 53 38 34
0D 04 55 95 B6 6D
0E 04 5B 53 60 C4
0F 02 C2 21
10 02 CD 9C
11 02 D9 17
12 04 72 4A 0A 20
13 04 87 F8 4B 86
14 04 7D C5 5E CE
15 04 03 83 09 26
16 02 12 81
17 04 F1 01 A2 29
18 04 14 BC 08 2B
19 02 34 F3
1A 02 17 50
1B 02 06 3F
1C 02 F9 C1
1D 02 17 50
1E 02 ED 1F
1F 02 F7 32
20 02 01 D0
21 02 EB 3F
22 01 02
23 02 A7 C4
24 01 B2
25 02 BE BA
26 02 CA 35
27 01 54
28 04 8F 69 52 62
29 04 76 54 57 F2
2A 02 F8 23
2B 01 03
2C 01 0F
2D 02 1A 95
2E 02 26 11
2F 01 31
30 00
31 02 3D 07
32 02 C8 83
33 02 D3 FE
34 02 DF 79
35 02 6A F4
36 02 76 70
37 01 81
38 01 8C
39 04 B3 8E AC F1
3A 02 A4 5D
3B 07 54 4F 50 20 47 55 4E
3C 02 AF D8
3D 01 BA
3E 02 06 CF
3F 01 02
40 02 DD C5
41 01 0D
43 04 85 A1 5A 39
44 04 00 1C 50 1C
45 02 0B B3
46 06 41 50 41 43 48 45
47 02 17 2F
48 08 00 02 D5 D0 24 66 01 80
49 00
4A 00
4B 02 C2 21
4C 02 0B B3
4D 01 01
4E 02 0B B3
4F 02 09 FB
50 02 04 BC
51 04 00 24 38 00
52 04 F1 06 9B 63
53 04 14 BC B2 C0
54 04 F1 00 4D 00
55 04 14 BE 84 C8
56 04 F0 FD 9B 17
57 04 14 BB 17 AF
58 04 F1 02 05 2A
59 04 14 B9 D1 76
5A 04 FF 62 E2 F2
5B 04 04 D8 04 DF
5C 04 F3 AB 48 EF
5D 04 DE 17 93 23
5E 22 01 70 F5 92 F0 23 73 36 4A F8 AA 91 62 C0 0F 2E B2 DA 16 B7 43 41 00 08 41 A0 BE 36 5B 5A B9 6A 36 45
5F 00
60 03 00 D9 2A
61 00
62 00
63 00
64 00
65 00
66 00
67 03 2F 92 1E
68 03 2F 92 1E
69 03 2F 92 1E
6A 04 42 4C 55 45
6B 06 42 41 53 45 30 31
6C 04 48 4F 4D 45
6D 03 00 01 A0
6E 02 4D AF
6F 02 0B B8
70 02 1F 40
71 03 05 F5 00
72 03 05 F7 40
73 13 05 11 46 6C 79 20 74 6F 20 57 61 79 70 6F 69 6E 74 20 31
74 02 03 07
75 02 3E 90
76 03 3E 80 11
77 02 3B 60
78 02 48 00
79 02 01 03
7A 0B 01 0E 03 43 41 4E 00 03 46 52 41
7B 01 07
7C 01 03
7D 01 09
7E 01 05
7F 05 83 D4 60 87 69
81 00 0E 0D 15 00 00 07 D0 00 00 0F A0 4E 4E 49 52
81 01 04 41 31 32 33
81 02 18 0B 40 6B C2 09 19 BD A5 54 07 0E 00 0B 40 78 3C B8 19 A2 92 74 07 C6 00
81 03 07 05 6F 27 1B 5E 41 B7
81 04 03 02 57 C0
81 05 02 27 10
81 06 02 37 00
81 07 14 46 72 65 71 75 65 6E 63 79 20 4D 6F 64 75 6C 61 74 69 6F 6E
81 08 01 1E
81 09 05 01 2B 8D C6 35
81 0A 3F 03 12 00 00 0F 56 49 53 20 4E 6F 73 65 20 43 61 6D 65 72 61 15 01 00 12 41 43 4D 45 20 56 49 53 20 4D 6F 64 65 6C 20 31 32 33 14 02 00 11 41 43 4D 45 20 49 52 20 4D 6F 64 65 6C 20 34 35 36
81 0B 01 0B
81 0C 2C 0E 01 01 01 03 82 03 07 48 61 72 70 6F 6F 6E 0F 01 01 02 02 9E 04 08 48 65 6C 6C 66 69 72 65 0C 01 02 01 01 03 06 47 42 55 2D 31 35
81 0D 40 0F 00 00 01 03 40 71 D8 94 19 BD BF E7 08 98 00 0F 01 00 02 02 40 71 D3 88 19 BC CE 24 08 FC 00 0F 02 7F FF 01 40 71 E3 08 19 BF 2C 1B 07 D0 00 0F 03 FF FE 00 40 71 E5 AF 19 BF 5A A7 09 60 00
81 0E 0E 06 34 80 00 4B 00 00 06 1A 40 00 0C 80 00
"""
KEY = bytes.fromhex("060E2B34020B01010E01030101000000")
ST0601_17_PACKET = KEY + bytes.fromhex("82 03 BB") + bytes.fromhex(ST0601_17_ITEMS) + bytes.fromhex("01 02 58 02")


def item(name, value_hex):
    spec = klv.TAG_BY_NAME[name]
    v = bytes.fromhex(value_hex)
    return klv.ber_oid(spec.tag) + klv.ber_length(len(v)) + v


def with_checksum(items: bytes) -> bytes:
    head = KEY + klv.ber_length(len(items) + 4) + items + b"\x01\x02"
    return head + klv.checksum(head + b"\0\0").to_bytes(2, "big")


#: A packet of the standard's example items (ST 0601.11 / .17 values), our checksum.
EXAMPLE_PACKET = with_checksum(b"".join(item(n, h) for n, _, h in EXAMPLES))


def fields_of(rng, i=0):
    """A packet's worth of in-range values for every decoded field."""
    f = {}
    for s in klv.TAGS:
        if s.kind in ("uint", "int"):
            f[s.name] = float(rng.uniform(s.lo, s.hi))
        elif s.kind == "u64":
            f[s.name] = 1_700_000_000_000_000 + 33_367 * i
        elif s.kind == "u8":
            f[s.name] = 17
        else:
            f[s.name] = f"{s.name[:8]}-{i % 7}"
    return f


def assert_fields_close(got: dict, want: dict, tol_steps=0.5):
    assert set(got) == set(want)
    for name, v in want.items():
        spec = klv.TAG_BY_NAME[name]
        if isinstance(v, float):
            assert abs(got[name] - v) <= tol_steps * spec.step * (1 + 1e-9) + 1e-12, (name, got[name], v)
        else:
            assert got[name] == v, name


# ----------------------------------------------------------------------------------------
# The standard's examples


@pytest.mark.parametrize("name,value,value_hex", EXAMPLES, ids=[e[0] for e in EXAMPLES])
def test_standard_item_examples(name, value, value_hex):
    spec = klv.TAG_BY_NAME[name]
    raw = item(name, value_hex)
    # Decoding the standard's bytes gives its value (to half a step, or its printed digits).
    p = klv.decode_local_set(raw)
    assert set(p.fields) == {name} and not p.flags and not p.unknown
    got = p.fields[name]
    if isinstance(value, float):
        assert abs(got - value) <= max(spec.step / 2, PRINTED.get(name, 0.0)), (got, value)
    else:
        assert got == value
    # Encoding the value gives the standard's bytes (the decoded value too, for a rounded print).
    encoded = klv.encode_packet({name: value}, with_checksum=False)
    assert encoded == KEY + klv.ber_length(len(raw)) + raw or name in PRINTED
    assert klv.encode_packet({name: got}, with_checksum=False)[17:] == raw


def test_standard_checksum_example():
    # MISB ST 0601, Tag 1: the 16-bit running sum of 06 0E 2B 34 02 00 81 BB is 0xB4FD.
    assert klv.checksum(bytes.fromhex("060E2B34020081BB") + b"\0\0") == 0xB4FD
    # An odd count: the last byte is at an even index, so it is added shifted by 8.
    assert klv.checksum(bytes([1, 2, 3]) + b"\0\0") == (0x0102 + 0x0300)


def test_standard_example_packet_st0601_17():
    """The full example packet of ST 0601.17: long-form BER length, two-byte BER-OID
    tags (128-142), nested sets kept raw, and its checksum 0x5802 verified."""
    assert klv.checksum(ST0601_17_PACKET) == 0x5802
    p = klv.decode_packet(ST0601_17_PACKET)
    assert p.checksum == 0x5802 and p.offset == 0 and not p.flags
    f = p.fields
    assert f["precision_time_stamp_us"] == 0x000459F4A6AA4AA8
    assert (
        datetime.fromtimestamp(f["precision_time_stamp_us"] / 1e6, timezone.utc).isoformat()
        == "2008-10-24T00:13:29.913000+00:00"
    )
    assert f["mission_id"] == "MISSION01" and f["platform_designation"] == "MQ1-B"
    assert f["image_coordinate_system"] == "Geodetic WGS84" and f["uas_ls_version"] == 13
    expect = {  # the decoded values of the standard's example bytes
        "platform_heading_deg": 159.97436484321355,
        "platform_pitch_deg": -0.4315317239906003,
        "platform_roll_deg": 3.4058656575212867,
        "sensor_latitude_deg": 60.176822966978335,
        "sensor_longitude_deg": 128.42675904204452,
        "sensor_true_altitude_m": 14190.719462882427,
        "sensor_horizontal_fov_deg": 144.57129777981231,
        "sensor_vertical_fov_deg": 152.64362554360267,
        "sensor_relative_azimuth_deg": 160.71921143697557,
        "sensor_relative_elevation_deg": -168.79232483394085,
        "sensor_relative_roll_deg": 176.86543764939194,
        "slant_range_m": 68590.98329874477,
        "target_width_m": 722.8198672465096,
        "frame_center_latitude_deg": -10.542388633146132,
        "frame_center_longitude_deg": 29.157890122923018,
        "frame_center_elevation_m": 3216.0372320134275,
        "offset_corner_latitude_1_deg": 0.013660084841456343,
        "offset_corner_longitude_1_deg": 0.0036599322489089632,
        "offset_corner_latitude_3_deg": -0.011062196722312082,
        "offset_corner_longitude_4_deg": -0.01216086306344798,
        "target_location_latitude_deg": -79.16385005189285,
        "target_location_longitude_deg": 166.40081296041646,
        "target_location_elevation_m": 18389.04707408255,
        "target_error_ce90_m": 425.2151522087434,
        "target_error_le90_m": 608.9230945296407,
        "sensor_ellipsoid_height_m": 14190.719462882427,
        "frame_center_hae_m": 9.445334554054966,
        "corner_latitude_1_deg": -10.528728394084018,
        "corner_longitude_1_deg": 29.161550416220702,
        "corner_latitude_4_deg": -10.541326436466223,
        "corner_longitude_4_deg": 29.14572990925318,
        "platform_pitch_full_deg": -0.4315251020861441,
        "platform_roll_full_deg": 3.4058139815022304,
    }
    for name, v in expect.items():
        assert f[name] == pytest.approx(v, rel=1e-13, abs=1e-15), name
    # Every other item raw: 8, 9, 34-39, 43, 44, 47, 48, ..., 127 and the two-byte tags 128-142.
    assert set(range(128, 143)) <= set(p.unknown)
    assert p.unknown[128] == bytes.fromhex("0D 15 00 00 07 D0 00 00 0F A0 4E 4E 49 52")
    assert p.unknown[48] == b"" and p.unknown[8] == b"\x93"
    assert len(p.fields) + len(p.unknown) == ST0601_17_ITEMS.strip().count("\n") + 1
    # Re-encoding the decoded packet reproduces the standard's bytes (same order: by tag).
    again = klv.encode_packet(p.fields, unknown=p.unknown)
    assert again == ST0601_17_PACKET


def test_ber_coding():
    assert klv.ber_length(0) == b"\x00" and klv.ber_length(127) == b"\x7f"
    assert klv.ber_length(128) == b"\x81\x80" and klv.ber_length(0x3BB) == b"\x82\x03\xbb"
    assert klv.ber_oid(1) == b"\x01" and klv.ber_oid(127) == b"\x7f"
    assert klv.ber_oid(128) == b"\x81\x00" and klv.ber_oid(142) == b"\x81\x0e"
    assert klv.ber_oid(16384) == b"\x81\x80\x00"
    # A long-form length that is not minimal (0x81 0x05) is still read.
    items = item("platform_heading_deg", "71 C2")
    head = KEY + b"\x81" + bytes([len(items) + 4]) + items + b"\x01\x02"
    pkt = head + klv.checksum(head + b"\0\0").to_bytes(2, "big")
    assert klv.decode_packet(pkt).fields == {"platform_heading_deg": 159.97436484321355}


def test_reserved_values_are_nan_with_flags():
    items = (
        item("platform_pitch_deg", "80 00")
        + item("sensor_latitude_deg", "80 00 00 00")
        + item("offset_corner_latitude_1_deg", "80 00")
        + item("platform_roll_full_deg", "80 00 00 00")
        + item("sensor_longitude_deg", "FF FF 80 00")
    )  # -32768 as int32 is a valid value
    p = klv.decode_packet(with_checksum(items))
    assert math.isnan(p["platform_pitch_deg"]) and math.isnan(p["sensor_latitude_deg"])
    assert math.isnan(p["offset_corner_latitude_1_deg"]) and math.isnan(p["platform_roll_full_deg"])
    assert p.flags == {
        "platform_pitch_deg": "out of range",
        "sensor_latitude_deg": "error",
        "offset_corner_latitude_1_deg": "error",
        "platform_roll_full_deg": "out of range",
    }
    assert p["sensor_longitude_deg"] == pytest.approx(-32768 * 360 / (2**32 - 2))
    # The encoder writes the reserved values: NaN, and beyond the range where it means "out of range".
    enc = klv.encode_packet(
        {
            "platform_pitch_deg": 25.0,
            "platform_roll_deg": -60.0,
            "sensor_latitude_deg": math.nan,
            "platform_pitch_full_deg": math.inf,
        }
    )
    q = klv.decode_packet(enc)
    assert q.flags == {
        "platform_pitch_deg": "out of range",
        "platform_roll_deg": "out of range",
        "sensor_latitude_deg": "error",
        "platform_pitch_full_deg": "out of range",
    }
    with pytest.raises(ValueError, match="sensor_latitude_deg = 95.0 is outside"):
        klv.encode_packet({"sensor_latitude_deg": 95.0})
    with pytest.raises(ValueError, match="platform_heading_deg"):
        klv.encode_packet({"platform_heading_deg": math.nan})
    with pytest.raises(ValueError, match="unknown UAS LS field"):
        klv.encode_packet({"heading": 3.0})
    j = p.to_json()
    assert j["platform_pitch_deg"] is None and j["flags"]["sensor_latitude_deg"] == "error"
    json.dumps(j, allow_nan=False)


# ----------------------------------------------------------------------------------------
# klvdata, an independent decoder


def klvdata_values(data: bytes) -> list[dict]:
    """klvdata's decoding of each packet: tag -> value string."""
    return [{tag: v[3] for tag, v in p.MetadataList().items()} for p in klvdata.StreamParser(data)]


def assert_matches_klvdata(ours: Packet, theirs: dict):
    checked = 0
    for name, v in ours.fields.items():
        spec = klv.TAG_BY_NAME[name]
        s = theirs[spec.tag]
        if spec.kind == "str":
            assert s == v, name
        elif spec.kind == "u64":
            t = datetime.fromisoformat(s)
            assert abs(t.timestamp() * 1e6 - v) < 2, name  # klvdata goes through float seconds
        else:
            # klvdata maps with slope (hi - lo) / (max - min) from the domain minimum: the same
            # line, so the same value up to float rounding.
            assert float(s) == pytest.approx(v, rel=1e-12, abs=1e-12 * (spec.hi - spec.lo)), (name, s, v)
        checked += 1
    return checked


def test_klvdata_on_the_standard_example_items():
    (theirs,) = klvdata_values(EXAMPLE_PACKET)
    ours = klv.decode_packet(EXAMPLE_PACKET)
    assert assert_matches_klvdata(ours, theirs) == len(EXAMPLES)
    assert theirs[1] == str(EXAMPLE_PACKET[-2:])  # both see the same checksum item (klvdata: raw bytes)


def test_klvdata_on_our_encoded_packets():
    rng = np.random.default_rng(1)
    blobs = [klv.encode_packet(fields_of(rng, i)) for i in range(40)]
    data = b"".join(blobs)
    theirs = klvdata_values(data)
    ours = [r for r in klv.iter_packets(data)]
    assert len(theirs) == len(ours) == 40 and all(isinstance(r, Packet) for r in ours)
    for o, t in zip(ours, theirs):
        assert assert_matches_klvdata(o, t) == len(klv.TAGS)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_klvdata_agrees_on_random_values(data):
    names = data.draw(
        st.lists(
            st.sampled_from([s.name for s in klv.TAGS if s.kind in ("uint", "int")]),
            min_size=1,
            max_size=12,
            unique=True,
        )
    )
    f = {}
    for n in names:
        s = klv.TAG_BY_NAME[n]
        f[n] = data.draw(st.floats(s.lo, s.hi, allow_nan=False))
    pkt = klv.encode_packet(f)
    (theirs,) = klvdata_values(pkt)
    assert_matches_klvdata(klv.decode_packet(pkt), theirs)


# ----------------------------------------------------------------------------------------
# Bad packets in a stream


def make_stream():
    """Good and bad packets with the expected results: (data, [(offset, Packet fields or reason)])."""
    rng = np.random.default_rng(7)
    goods = [klv.encode_packet(fields_of(rng, i)) for i in range(8)]
    parts, expect = [], []
    pos = 0

    def add(b, what):
        nonlocal pos
        parts.append(b)
        expect.append((pos, what))
        pos += len(b)

    add(goods[0], 0)
    flipped = bytearray(goods[1])
    flipped[-1] ^= 0x01  # checksum flipped
    add(bytes(flipped), "checksum mismatch")
    add(goods[2], 2)
    add(b"\x00garbage bytes\xff" * 3, "bytes before the next UAS LS key are not a UAS LS packet")
    add(goods[3], 3)
    longer = bytearray(goods[4])  # the packet's length byte says 40 bytes more than it has
    assert longer[16] == 0x82
    longer[18] += 40
    add(bytes(longer), "checksum")  # its end falls inside the next packet: no checksum there
    add(goods[5], 5)
    shorter = bytearray(goods[6])  # 20 bytes less: the local set no longer ends with the checksum
    shorter[18] -= 20
    add(bytes(shorter), "checksum")
    # An integer item longer than 8 bytes cannot be decoded at its length: heading as 9 bytes.
    add(
        with_checksum(item("platform_heading_deg", "00" * 7 + "71 C2")),
        "tag 5 (Platform Heading Angle) has length 9, expected 2",
    )
    # Heading in 3 bytes (a leading zero byte, as writers in the wild do): decoded at its
    # length with the standard's step, the packet kept (docs/klv.md, "Encoders in the wild").
    goods.append(with_checksum(item("platform_heading_deg", "00 71 C2")))
    add(goods[-1], len(goods) - 1)
    add(goods[7], 7)
    add(goods[0][:-30], "truncated: the length says")  # truncated at the end
    return b"".join(parts), expect, goods


def check_results(results, expect, goods):
    assert len(results) == len(expect), [type(r).__name__ for r in results]
    for r, (offset, what) in zip(results, expect):
        if isinstance(what, int):
            assert isinstance(r, Packet), r
            assert r.offset == offset
            assert r.fields == klv.decode_packet(goods[what]).fields
        else:
            assert isinstance(r, KlvError), (offset, what, r)
            assert r.offset == offset and what in r.reason, (r, offset, what)


def test_bad_packets_reported_with_offsets_and_good_ones_kept():
    data, expect, goods = make_stream()
    check_results(list(klv.iter_packets(data)), expect, goods)


@pytest.mark.parametrize("chunk", [1, 7, 100, 333, 4096])
def test_streaming_reads_give_the_same_results(chunk, tmp_path):
    data, expect, goods = make_stream()
    check_results(list(klv.iter_packets(io.BytesIO(data), chunk_size=chunk)), expect, goods)
    path = tmp_path / "stream.klv"
    path.write_bytes(data)
    check_results(list(klv.read_klv_file(path, chunk_size=chunk)), expect, goods)


def test_more_bad_cases():
    good = klv.encode_packet({"platform_heading_deg": 10.0})
    # A key with nothing after it, an indefinite BER length (0x80), a key cut in two.
    data = good + KEY + b"\x80" + good + KEY + good + KEY[:9]
    res = list(klv.iter_packets(data))
    n = len(good)
    kinds = [(type(r).__name__, r.offset) for r in res]
    assert kinds == [
        ("Packet", 0),
        ("KlvError", n),
        ("Packet", n + 17),
        ("KlvError", 2 * n + 17),
        ("Packet", 2 * n + 33),
        ("KlvError", 3 * n + 33),
    ]
    assert "invalid BER length byte 0x80" in res[1].reason
    assert "9 bytes at the end are not a UAS LS packet" in res[5].reason
    # After the bare key the next packet's key is read as its length (0x06) and local
    # set, which has no checksum item: reported, and the scan resumes inside it and finds
    # the real packet. No checksum item at all: bad unless the checksum is not asked for.
    bare = klv.encode_packet({"platform_heading_deg": 10.0}, with_checksum=False)
    (r,) = klv.iter_packets(bare)
    assert isinstance(r, KlvError) and "no checksum item" in r.reason
    (r,) = klv.iter_packets(bare, verify_checksum=False)
    assert isinstance(r, Packet) and r.checksum is None
    with pytest.raises(KlvError, match="checksum mismatch"):
        klv.decode_packet(good[:-1] + bytes([good[-1] ^ 0xFF]))
    with pytest.raises(KlvError, match="runs past the end"):
        klv.decode_local_set(bytes.fromhex("05 04 71 C2"))


def random_stream(seed, n=60):
    """Packets of random subsets of the fields (many layouts, short and long BER lengths)."""
    rng = np.random.default_rng(seed)
    blobs = []
    for i in range(n):
        f = fields_of(rng, i)
        keep = rng.random(len(f)) < rng.uniform(0.1, 1.0)
        blobs.append(klv.encode_packet({k: v for (k, v), m in zip(f.items(), keep) if m}))
    return blobs


def assert_same_columns(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if a[k].dtype == object:
            assert list(a[k]) == list(b[k]), k
        else:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=6),
    st.integers(1, 600),
)
def test_corrupted_streams_read_alike_every_way(seed, flips, chunk):
    """Whatever the damage, chunked reads, whole-buffer reads and the vectorised columns agree."""
    blobs = random_stream(seed, 25)
    data = bytearray(b"".join(blobs))
    for where, byte in flips:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    data = bytes(data)
    whole = list(klv.iter_packets(data))
    chunked = list(klv.iter_packets(io.BytesIO(data), chunk_size=chunk))
    assert [(type(r), r.offset) for r in whole] == [(type(r), r.offset) for r in chunked]
    assert [r.fields if isinstance(r, Packet) else r.reason for r in whole] == [
        r.fields if isinstance(r, Packet) else r.reason for r in chunked
    ]
    assert_same_columns(klv.packets_to_columns(data), klv.packets_to_columns(whole))
    # A damaged byte spoils the packet it is in (at worst its neighbour too), no more.
    assert sum(isinstance(r, Packet) for r in whole) >= len(blobs) - 2 * len(flips)


def comparable(p: Packet):
    j = p.to_json()
    j.pop("offset", None)
    return j, p.flags, p.unknown, p.checksum


def test_batch_decoding_equals_packet_by_packet(monkeypatch):
    """Long runs of packets are decoded in numpy batches: the same Packets as one at a time,
    with reserved values, raw items, repeated items and many layouts."""
    batches = []
    decode_batch = klv._decode_batch
    monkeypatch.setattr(klv, "_decode_batch", lambda *a: batches.append(len(a[1])) or decode_batch(*a))
    blobs = []
    for i, b in enumerate(random_stream(10, 300)):
        if i % 7 == 0:  # reserved values
            b = klv.encode_packet(
                {
                    "platform_pitch_deg": math.nan,
                    "sensor_latitude_deg": math.nan,
                    "platform_roll_deg": 3.0,
                    "mission_id": "M",
                    300: b"raw",
                    48: b"",
                }
            )
        if i % 11 == 0:  # a repeated item (the last one wins) and a raw one
            b = with_checksum(
                item("platform_heading_deg", "71 C2")
                + item("platform_pitch_deg", "80 00")
                + bytes.fromhex("08 01 93")
                + item("platform_heading_deg", "00 10")
                + item("platform_pitch_deg", "00 20")
            )
        blobs.append(b)
    data = b"".join(blobs)
    batched = list(klv.iter_packets(data))
    assert sum(batches) >= len(blobs) - klv._BATCH_MIN  # the runs went through the batch path
    single = [r for b in blobs for r in klv.iter_packets(b)]
    assert len(batched) == len(single) == len(blobs)
    assert [comparable(p) for p in batched] == [comparable(p) for p in single]
    offsets = np.cumsum([0] + [len(b) for b in blobs[:-1]])
    assert [p.offset for p in batched] == offsets.tolist()
    rep = batched[11]
    assert rep.fields["platform_heading_deg"] == pytest.approx(16 * 360 / 65535) and not rep.flags
    assert rep.unknown == {8: b"\x93"}
    assert batched[7].flags == {"platform_pitch_deg": "out of range", "sensor_latitude_deg": "error"}
    assert batched[7].unknown == {48: b"", 300: b"raw"}


def test_columns_from_bytes_equal_columns_from_packets():
    data, expect, goods = make_stream()
    rng = np.random.default_rng(3)
    clean = b"".join(klv.encode_packet(fields_of(rng, i)) for i in range(300))
    mixed = b"".join(random_stream(4, 200))
    assert {len(b) >= 128 + 17 for b in random_stream(4, 200)} == {True, False}
    for d in (clean, data, clean + data + clean, mixed, ST0601_17_PACKET * 3):
        assert_same_columns(klv.packets_to_columns(d), klv.packets_to_columns(klv.iter_packets(d)))
    cols = klv.packets_to_columns(data)
    assert len(cols["offset"]) == 6 and np.isnan(cols["pts"]).all()
    assert list(cols["offset"]) == [o for o, w in expect if isinstance(w, int)]
    # A field absent from every packet is all NaN; reserved values are NaN too.
    sparse = klv.encode_packet({"platform_heading_deg": 1.0}) + klv.encode_packet({"platform_pitch_deg": math.nan})
    c = klv.packets_to_columns(sparse)
    np.testing.assert_array_equal(np.isnan(c["platform_heading_deg"]), [False, True])
    assert np.isnan(c["platform_pitch_deg"]).all() and np.isnan(c["slant_range_m"]).all()
    assert list(c["mission_id"]) == [None, None]


# ----------------------------------------------------------------------------------------
# MPEG-TS through PyAV


def test_ts_round_trip(tmp_path):
    rng = np.random.default_rng(11)
    blobs = [klv.encode_packet(fields_of(rng, i)) for i in range(25)]
    path = tmp_path / "klv.ts"
    pts = [1000 + 3003 * i for i in range(len(blobs))]
    assert klv.write_ts(path, blobs, pts=pts) == len(blobs)
    res = list(klv.read_ts_klv(path))
    assert all(isinstance(r, Packet) for r in res) and len(res) == len(blobs)
    assert [r.pts for r in res] == pts
    assert all(r.time_base == Fraction(1, 90000) for r in res)
    assert res[1].time_s == pytest.approx((1000 + 3003) / 90000)
    for r, b in zip(res, blobs):
        assert r.fields == klv.decode_packet(b).fields and r.offset is not None
    # read_packets picks PyAV for .ts; the columns carry the pts.
    cols = klv.packets_to_columns(klv.read_packets(path))
    np.testing.assert_array_equal(cols["pts"], pts)


def test_ts_with_video_and_two_klv_packets_in_one_data_packet(tmp_path):
    rng = np.random.default_rng(12)
    blobs = [klv.encode_packet(fields_of(rng, i)) for i in range(6)]
    blobs[2] = blobs[2] + blobs[3]  # one PES carrying two KLV packets
    del blobs[3]
    path = tmp_path / "video.ts"
    klv.write_ts(path, blobs, rate=25.0, video=True)
    with av.open(str(path)) as c:
        assert {s.type for s in c.streams} == {"video", "data"}
    res = list(klv.read_ts_klv(path))
    assert len(res) == 6 and all(isinstance(r, Packet) for r in res)
    assert res[2].pts == res[3].pts
    # The muxer may shift every time stamp by the video's delay; the spacing is kept.
    assert np.diff([r.pts for r in res]).tolist() == [3600, 3600, 0, 3600, 3600]
    assert [r.fields for r in res] == [p.fields for b in blobs for p in klv.iter_packets(b)]


def test_ts_bad_packet_reported_with_pts(tmp_path):
    good = klv.encode_packet({"platform_heading_deg": 45.0})
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    path = tmp_path / "bad.ts"
    klv.write_ts(path, [good, bytes(bad), good], pts=[0, 3000, 6000])
    res = list(klv.read_ts_klv(path))
    assert [type(r).__name__ for r in res] == ["Packet", "KlvError", "Packet"]
    assert res[1].pts == 3000 and "checksum mismatch" in res[1].reason and res[1].offset is not None
    assert "pts 3000" in str(res[1])


def test_ts_without_data_stream(tmp_path):
    path = tmp_path / "novideo.ts"
    with av.open(str(path), "w", format="mpegts") as out:
        v = out.add_stream("mpeg2video", rate=25)
        v.width, v.height, v.pix_fmt = 64, 48, "yuv420p"
        for i in range(10):
            f = av.VideoFrame.from_ndarray(np.zeros((48, 64, 3), np.uint8), format="rgb24")
            f.pts = i
            for p in v.encode(f):
                out.mux(p)
        for p in v.encode():
            out.mux(p)
    with pytest.raises(ValueError, match="no data"):
        list(klv.read_ts_klv(path))


# ----------------------------------------------------------------------------------------
# Encode -> decode round trips


def spec_value(spec):
    if spec.kind in ("uint", "int"):
        return st.floats(spec.lo, spec.hi, allow_nan=False)
    if spec.kind == "u64":
        return st.integers(0, 2**64 - 1)
    if spec.kind == "u8":
        return st.integers(0, 255)
    return st.text(st.characters(codec="utf-8", exclude_categories=["Cs"]), max_size=30).filter(
        lambda s: len(s.encode("utf-8")) <= 127
    )


packet_fields = st.fixed_dictionaries({}, optional={s.name: spec_value(s) for s in klv.TAGS})


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(packet_fields)
def test_round_trip_within_half_a_step(fields):
    pkt = klv.encode_packet(fields)
    p = klv.decode_packet(pkt)
    assert_fields_close(p.fields, fields)
    assert not p.flags and not p.unknown
    # Quantised values re-encode to the same bytes.
    assert klv.encode_packet(p.fields) == pkt


@pytest.mark.parametrize("spec", [s for s in klv.TAGS if s.kind in ("uint", "int")], ids=lambda s: s.name)
def test_range_ends_and_steps(spec):
    for v in (spec.lo, spec.hi, 0.5 * (spec.lo + spec.hi), spec.lo + 0.49 * spec.step):
        got = klv.decode_packet(klv.encode_packet({spec.name: v}))[spec.name]
        assert abs(got - v) <= spec.step / 2 * (1 + 1e-9), (v, got)
    # ends are exact (0 and all ones / +-(2^(n-1) - 1))
    assert klv.decode_packet(klv.encode_packet({spec.name: spec.hi}))[spec.name] == pytest.approx(spec.hi, rel=1e-15)


# ----------------------------------------------------------------------------------------
# The CLI verb


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "geoloc", "klv", "dump", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )


def test_cli_dump_raw_file(tmp_path):
    data, expect, goods = make_stream()
    path = tmp_path / "stream.bin"
    path.write_bytes(data)
    r = run_cli(path)
    assert r.returncode == 1, r.stderr  # some packets could not be decoded (docs/cli.md)
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    good_expect = [(o, w) for o, w in expect if isinstance(w, int)]
    assert [d["offset"] for d in lines] == [o for o, _ in good_expect]
    for d, (_, w) in zip(lines, good_expect):
        want = klv.decode_packet(goods[w]).fields
        for name, v in want.items():
            assert d[name] == v, name
        if "precision_time_stamp_us" in want:
            assert list(d)[:2] == ["offset", "precision_time_stamp_us"]  # then tag order
        assert d["checksum"] == "0x" + goods[w][-2:].hex().upper()
    errors = r.stderr.strip().splitlines()
    # the heading in 3 bytes: one line for its kind, with its count and offset, at the end
    quirks = [e for e in errors if ": quirk: " in e]
    assert len(quirks) == 1 and "tag 5 (Platform Heading Angle) in 3 bytes" in quirks[0], quirks
    assert "(1 packet, the first at byte 2233)" in quirks[0]
    summary = errors[-1]
    assert summary.endswith("6 packets decoded, 5 could not be (see above)"), summary
    errors = [e for e in errors if ": quirk: " not in e and e != summary]
    bad_expect = [(o, w) for o, w in expect if not isinstance(w, int)]
    assert len(errors) == len(bad_expect)
    for line, (o, w) in zip(errors, bad_expect):
        assert f"byte {o}: " in line and w in line, line
    # --out writes the same lines to a file.
    out = tmp_path / "dump.jsonl"
    r2 = run_cli(path, "--out", out)
    assert r2.returncode == 1 and r2.stdout == "" and out.read_text() == r.stdout


def test_cli_dump_names_each_step_back_of_the_clock_and_keeps_every_packet(tmp_path):
    # seconds after t0: one step back of 0.25 s (packet 4), then a clock that restarts 10 s back
    # (packet 6) and runs on from there: two reports, every packet written in file order
    t0 = 1_700_000_000_000_000
    sec = [0.0, 1.0, 2.0, 1.75, 3.0, -7.0, -6.0]
    pkts = [
        klv.encode_packet({"precision_time_stamp_us": t0 + round(x * 1e6), "mission_id": f"M{k}"})
        for k, x in enumerate(sec)
    ]
    offsets = np.concatenate([[0], np.cumsum([len(b) for b in pkts])[:-1]]).tolist()
    path = tmp_path / "back.klv"
    path.write_bytes(b"".join(pkts))
    r = run_cli(path)
    assert r.returncode == 0, r.stderr  # a time going back is a note, not a bad packet
    assert [json.loads(line)["mission_id"] for line in r.stdout.splitlines()] == [f"M{k}" for k in range(7)]
    back = [e for e in r.stderr.splitlines() if "goes back" in e]
    assert back == [
        f"geoloc klv: {path}: packet 4 (byte {offsets[3]}): Precision Time Stamp goes back 0.250000 s "
        f"from packet 3 (byte {offsets[2]})",
        f"geoloc klv: {path}: packet 6 (byte {offsets[5]}): Precision Time Stamp goes back 10.000000 s "
        f"from packet 5 (byte {offsets[4]})",
    ], r.stderr


def test_cli_dump_ts_and_exit_codes(tmp_path):
    rng = np.random.default_rng(5)
    ts = tmp_path / "clip.ts"
    klv.write_ts(ts, [klv.encode_packet(fields_of(rng, i)) for i in range(3)], pts=[0, 3000, 6000])
    r = run_cli(ts)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert [d["pts"] for d in lines] == [0, 3000, 6000] and lines[1]["time_s"] == pytest.approx(3000 / 90000)
    # No good packet: exit code 2 (bad input: nothing could be decoded), the reasons on stderr.
    junk = tmp_path / "junk.klv"
    junk.write_bytes(b"not klv at all" * 10)
    r = run_cli(junk)
    assert r.returncode == 2 and r.stdout == ""
    assert "byte 0: 140 bytes at the end are not a UAS LS packet" in r.stderr
    r = run_cli(tmp_path / "missing.klv")
    assert r.returncode == 2 and "missing.klv" in r.stderr
