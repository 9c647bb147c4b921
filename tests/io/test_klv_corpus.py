"""Real MISB KLV files from other writers, decoded and replayed end to end.

The files under tests/data/misb/ were written by encoders other than geoloc (their sources,
licences and writers: tests/data/misb/README.md). Every packet geoloc decodes is compared
item by item with klvdata, the independent ST 0601 decoder of the test extra, driven here
one item at a time (klvdata's own KLV splitting and its per-tag parsers), so that an item
klvdata refuses (a reserved "error" value outside its mapping's domain) is seen as refused
instead of aborting the packet, as klvdata's ``StreamParser`` does.
"""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from klvdata.klvparser import KLVParser  # test dependency: the independent decoder
from klvdata.misb0102 import SecurityClassification, SecurityLocalMetadataSet
from klvdata.misb0601 import UASLocalMetadataSet

from geoloc.io import klv
from geoloc.io.klv import KlvError, Packet, QuirkTally

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "data" / "misb"

# file -> (UAS LS packets in the file, counted by their 16-byte key, each one a packet;
#          ST 0601 items geoloc decodes over the whole file, each compared with klvdata)
FILES = {
    "esri_cheyenne.bin": 407,
    "tekever_ar5_realflight.bin": 19,
    "ffmpeg_day_flight.klv": 6,
    "ffmpeg_night_flight_ir.klv": 18,
}


def klvdata_packets(data: bytes):
    """(byte offset, key, value) of each packet, split by klvdata (16-byte keys, BER lengths)."""
    src = io.BytesIO(data)
    while True:
        at = src.tell()
        try:
            key, value = next(KLVParser(src, 16))
        except StopIteration:
            return
        yield at, key, value


def klvdata_items(value: bytes) -> dict:
    """tag -> (status, value) of one UAS LS value, each item through klvdata's parser for its tag:
    ("value", float | str | datetime | bytes), ("refused", raw) where klvdata's mapping rejects
    the raw count (the standard's reserved values), ("unknown", raw) for a tag it has no parser for.
    """
    out = {}
    for key, v in KLVParser(value, 1):
        assert key[0] < 0x80, "a BER-OID tag above 127: klvdata's one-byte keys cannot split it"
        parser = UASLocalMetadataSet.parsers.get(key)
        if parser is None:
            out[key[0]] = ("unknown", v)
            continue
        try:
            el = parser(v).value  # a BaseValue (its .value decoded), or bytes for sets and raw items
            out[key[0]] = ("value", getattr(el, "value", el))
        except ValueError:
            out[key[0]] = ("refused", v)
    return out


def compare_packet(ours: Packet, theirs: dict) -> int:
    """Every ST 0601 field geoloc decodes equals klvdata's value for that tag; returns the number
    of items compared."""
    n = 0
    for name, v in ours.fields.items():
        spec = klv.TAG_BY_NAME.get(name)
        if spec is None:
            continue
        status, t = theirs[spec.tag]
        if status == "unknown":
            # klvdata 0.0.3 has no parser for this tag: nothing to compare with
            continue
        if status == "refused":
            # the standard's reserved value (0x80...: "error" / "out of range"): ours NaN, flagged
            assert isinstance(v, float) and math.isnan(v), (name, v)
            assert ours.flags[name] in ("error", "out of range"), (name, ours.flags)
        elif spec.kind == "str":
            assert v == t, (name, v, t)
        elif spec.kind == "u64":
            # klvdata builds its datetime from float seconds (int / 1e6): within 1 us of the count
            us = (t - datetime(1970, 1, 1, tzinfo=timezone.utc)) // timedelta(microseconds=1)
            assert abs(us - v) <= 1, (name, us, v)
        else:
            # both map the same raw count on the same line (lo + raw (hi - lo) / the standard's
            # count range): equal up to float rounding of that one multiply-add
            assert t == pytest.approx(v, rel=1e-12, abs=1e-12 * max(spec.hi - spec.lo, 1)), (name, v, t)
        n += 1
    return n


def compare_security(ours: Packet, raw: bytes) -> int:
    """The nested ST 0102 set (tag 48) against klvdata's SecurityLocalMetadataSet."""
    theirs = SecurityLocalMetadataSet(raw).items
    n = 0
    if b"\x01" in theirs:
        code = bytes(theirs[b"\x01"].value.value)
        assert ours["security_classification"] == SecurityClassification._classification[code]
        n += 1
    for key, name in ((b"\x02", None), (b"\x03", "security_classifying_country"), (b"\x04", "security_sci_shi")):
        if name and key in theirs:
            t = theirs[key].value
            t = getattr(t, "value", t)
            t = bytes(t).decode("ascii") if isinstance(t, (bytes, bytearray)) else str(t)  # klvdata keeps bytes
            assert ours[name] == t, (name, ours[name], t)
            n += 1
    return n


@pytest.mark.parametrize("name", sorted(FILES))
def test_every_packet_of_a_real_file_equals_klvdata_item_by_item(name):
    data = (CORPUS / name).read_bytes()
    results = list(klv.iter_packets(data))
    ours = [r for r in results if isinstance(r, Packet)]
    bad = [r for r in results if isinstance(r, KlvError)]
    theirs = list(klvdata_packets(data))
    assert data.count(klv.UAS_LS_KEY) == FILES[name] == len(theirs)
    assert bad == []  # every packet kept
    assert [p.offset for p in ours] == [at for at, _, _ in theirs]
    compared = 0
    for p, (_, key, value) in zip(ours, theirs):
        assert key == klv.UAS_LS_KEY
        items = klvdata_items(value)
        assert p.checksum == int.from_bytes(items[1][1], "big")
        compared += compare_packet(p, items)
        if 48 in items:
            compared += compare_security(p, items[48][1])
    print(name, len(ours), "packets,", compared, "items equal to klvdata")
    assert compared > 10 * len(ours)


def raw_packets(data: bytes) -> list[bytes]:
    """The file's packets as bytes, cut where klvdata's splitting puts them."""
    cuts = [at for at, _, _ in klvdata_packets(data)] + [len(data)]
    return [data[a:b] for a, b in zip(cuts, cuts[1:])]


def dump(path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "geoloc", "klv", "dump", str(path)], capture_output=True, text=True, timeout=120
    )


# the quirks each file shows, once per kind, with the number of packets and the first offset
QUIRKS = {
    "esri_cheyenne.bin": [],
    "tekever_ar5_realflight.bin": [],
    "ffmpeg_day_flight.klv": [
        "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's step (6 packets, the first at byte 0)"
    ],
    "ffmpeg_night_flight_ir.klv": [
        "tag 22 (Target Width) in 4 bytes, the standard's 2: decoded at its length with the standard's step (18 packets, the first at byte 0)"
    ],
}


@pytest.mark.parametrize("name", sorted(FILES))
def test_klv_dump_of_a_real_file_prints_every_packet_and_each_quirk_once(name):
    path = CORPUS / name
    r = dump(path)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(s) for s in r.stdout.splitlines()]
    packets = [p for p in klv.iter_packets(path.read_bytes())]
    assert len(lines) == FILES[name]
    assert [d["offset"] for d in lines] == [p.offset for p in packets]
    assert lines == [json.loads(json.dumps(p.to_json())) for p in packets]
    want = [f"geoloc klv: {path}: quirk: {q}" for q in QUIRKS[name]]
    assert r.stderr.splitlines() == want
    tally = QuirkTally()
    for p in packets:
        tally.add(p)
    assert tally.lines() == QUIRKS[name]


def test_klv_dump_exits_2_when_nothing_decodes(tmp_path):
    # the real file with every key's first byte changed: bytes, but no packet
    data = (CORPUS / "tekever_ar5_realflight.bin").read_bytes().replace(klv.UAS_LS_KEY, b"\x07" + klv.UAS_LS_KEY[1:])
    path = tmp_path / "nokeys.bin"
    path.write_bytes(data)
    r = dump(path)
    assert r.returncode == 2 and r.stdout == ""
    assert "not a UAS LS packet" in r.stderr


@pytest.mark.parametrize("layout", ["async", "sync", "programs", "no_psi"])
@pytest.mark.parametrize("name", ["esri_cheyenne.bin", "tekever_ar5_realflight.bin", "ffmpeg_night_flight_ir.klv"])
def test_real_packets_in_a_transport_stream_decode_as_in_the_raw_file(tmp_path, name, layout):
    """The real packets, each in one PES (Cheyenne's 258-byte packets and Tekever's first, of
    323, split across TS packets of 184 payload bytes), in the layouts multiplexers write: asynchronous KLVA, synchronous
    metadata AU cells, the KLV in the third program, no PAT / PMT at all (found by its key)."""
    import ts_builder as tb

    data = (CORPUS / name).read_bytes()
    pk = raw_packets(data)
    kw = {"async": {}, "sync": {"sync": True}, "programs": {"programs": 2}, "no_psi": {"psi": False}}[layout]
    path = tmp_path / f"{layout}.ts"
    path.write_bytes(tb.stream(pk, **kw))
    raw = [p for p in klv.iter_packets(data)]
    got = list(klv.read_packets(path))
    assert [type(r).__name__ for r in got] == ["Packet"] * len(raw)
    assert [r.pts for r in got] == [3000 * i for i in range(len(raw))]
    for a, b in zip(got, raw):
        assert json.dumps({k: v for k, v in a.to_json().items() if k not in ("offset", "pts", "time_s")}) == json.dumps(
            {k: v for k, v in b.to_json().items() if k != "offset"}
        )


# --------------------------------------------------------------------------- the replay of each file


def oracle_centre(p: Packet) -> tuple[float, float]:
    """The frame centre of packet p from its own pose and angles, computed independently: the
    line of sight from scipy's rotations (tests/workflows/test_klv_replay.py ``los_ned``), the heights made
    ellipsoidal with N from PROJ's vgridshift, the ray from pymap3d's ECEF cut in closed form with
    the ellipsoid whose semi-axes are raised by the reported frame-centre height h_f."""
    import pymap3d as pm
    from test_klv_replay import los_ned, proj_undulation

    wgs = pm.Ellipsoid.from_name("wgs84")
    lat, lon = p["sensor_latitude_deg"], p["sensor_longitude_deg"]
    h_s = p["sensor_true_altitude_m"] + proj_undulation(lat, lon)
    h_f = p["frame_center_elevation_m"] + proj_undulation(
        p["frame_center_latitude_deg"], p["frame_center_longitude_deg"]
    )
    n, e, d = los_ned(
        p["platform_heading_deg"],
        p["platform_pitch_deg"],
        p["platform_roll_deg"],
        p["sensor_relative_azimuth_deg"],
        p["sensor_relative_elevation_deg"],
        p["sensor_relative_roll_deg"],
    )
    o = np.array(pm.geodetic2ecef(lat, lon, h_s, ell=wgs))
    u = np.array(pm.enu2uvw(e, n, -d, lat, lon))
    s = 1.0 / np.array([wgs.semimajor_axis + h_f, wgs.semimajor_axis + h_f, wgs.semiminor_axis + h_f])
    qa, qb, qc = np.sum((u * s) ** 2), 2 * np.sum(o * u * s * s), np.sum((o * s) ** 2) - 1
    t = (-qb - math.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)  # the nearer of the two cuts
    la, lo, _ = pm.ecef2geodetic(*(o + t * u), ell=wgs)
    return float(la), float(lo)


def test_replay_of_the_esri_flight_equals_an_independent_ray_cast_and_its_writers_centres():
    from pyproj import Geod

    from geoloc.workflows.klv_replay import replay_klv

    path = CORPUS / "esri_cheyenne.bin"
    packets = list(klv.iter_packets(path.read_bytes()))
    r = replay_klv(path)
    s = r.summary
    assert s.packets == 407 and s.errors == [] and s.status_counts == {"ok": 407}
    # ST 0601 version 1: MSL heights only (tags 15, 25), made ellipsoidal with EGM96 N
    assert {k: v for k, v in s.sensor_h_sources.items() if v} == {"tag 15 (MSL) + EGM96 N": 407}
    assert {k: v for k, v in s.reported_h_sources.items() if v} == {"tag 25 (MSL) + EGM96 N": 407}
    geod = Geod(ellps="WGS84")
    for i in range(0, 407, 10):
        la, lo = oracle_centre(packets[i])
        d = geod.inv(lo, la, r.columns["lon_deg"][i], r.columns["lat_deg"][i])[2]
        # the ellipsoid with raised semi-axes lies within 3 mm of the surface h = h_f at 41 deg N
        # (h_f ~ 1850 m): <= 8 mm along these rays, 20 deg or more below the horizon; 2 cm
        assert d < 0.02, (i, d)
    # the writer's own frame centres (tags 23, 24): the replay of its angles lands 8.4 m from them
    # in the median (the writer's terrain and timing are not in the stream); a regression of the
    # angle conventions would put them hundreds of metres away, as in the FFmpeg samples below
    assert 5.0 < s.median_m < 12.0 and s.p90_m < 30.0


@pytest.mark.parametrize("name", ["ffmpeg_day_flight.klv", "ffmpeg_night_flight_ir.klv"])
def test_ffmpeg_samples_frame_centres_bear_the_relative_azimuth_as_if_it_were_true(name):
    """The FFmpeg samples' writer put its frame centre (tags 23, 24) at the bearing of tag 18
    from north, not from the platform's heading: the bearing from the sensor to the reported
    centre (pyproj's geodesic) equals tag 18 to its quantisation, while heading + tag 18 points
    elsewhere. The replay, which follows the standard, lands kilometres away, and says so."""
    from pyproj import Geod

    from geoloc.workflows.klv_replay import replay_klv

    geod = Geod(ellps="WGS84")
    packets = list(klv.iter_packets((CORPUS / name).read_bytes()))
    for p in packets:
        az = geod.inv(
            p["sensor_longitude_deg"],
            p["sensor_latitude_deg"],
            p["frame_center_longitude_deg"],
            p["frame_center_latitude_deg"],
        )[0]
        off = (az - p["sensor_relative_azimuth_deg"] + 180) % 360 - 180
        # the centres' 4e-8 / 8e-8 deg steps at 200 m or more from the sensor: < 0.01 deg of bearing
        # (0.05: margin); tag 18's own step is 8.4e-8 deg
        assert abs(off) < 0.05, (p.offset, off)
        wrong = (az - p["sensor_relative_azimuth_deg"] - p["platform_heading_deg"] + 180) % 360 - 180
        assert abs(wrong) > 5.0
    s = replay_klv(CORPUS / name).summary
    assert s.median_m > 1000.0


def test_replay_names_an_item_held_at_the_reserved_value_not_as_missing():
    """The Tekever AR5 sends tag 19 (and the frame centre, two corners) in every packet with the
    standard's error value 0x80000000: the packets are kept, and the replay says the item holds
    no value, where it said "missing tag 19" before."""
    from geoloc.workflows.klv_replay import read_klv, replay_klv

    path = CORPUS / "tekever_ar5_realflight.bin"
    for fast in (True, False):
        read = read_klv(path, fast=fast)
        assert [
            set(t) >= {"sensor_relative_elevation_deg", "frame_center_latitude_deg"} for t in read.columns["reserved"]
        ] == [True] * 19
    r = replay_klv(path)
    assert r.summary.status_counts == {"invalid_input": 19}
    (reason,) = r.summary.invalid_reasons
    assert reason.startswith("tag 19 (Sensor Relative Elevation Angle) holds the standard's reserved value")
    assert "missing" not in reason
    assert all(n.startswith("tag 19 (Sensor Relative Elevation Angle) holds") for n in r.columns["note"])


def test_geoloc_replay_runs_every_real_file_end_to_end_and_from_a_transport_stream(tmp_path):
    """One `geoloc replay` of the four raw files and of four transport streams carrying their
    packets (no PAT / PMT: found by their keys): the same rows, one per packet, each file's
    quirks once in its summary."""
    import csv

    import ts_builder as tb

    sources = []
    for name in sorted(FILES):
        ts = tmp_path / f"{name}.ts"
        ts.write_bytes(tb.stream(raw_packets((CORPUS / name).read_bytes()), psi=False))
        sources += [CORPUS / name, ts]
    out = tmp_path / "frames.csv"
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "replay", *map(str, sources), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    for name in FILES:
        assert r.stdout.count(f"{FILES[name]} packets read, 0 bad packet(s) skipped") >= 2
        for q in QUIRKS[name]:
            assert r.stdout.count(q) == 2  # once for the raw file, once for its TS
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    skip = {"file", "offset", "pts_s", "time_s"}  # where each row came from
    for name in FILES:
        raw = [{k: v for k, v in x.items() if k not in skip} for x in rows if x["file"] == name]
        via_ts = [{k: v for k, v in x.items() if k not in skip} for x in rows if x["file"] == f"{name}.ts"]
        assert len(raw) == FILES[name]
        assert raw == via_ts


# --------------------------------------------------------------------------- klv fix on the real files


def test_klv_fix_of_real_files_keeps_every_other_item_and_says_each_reason_once(tmp_path):
    """`geoloc klv fix` of the Esri flight (ST 0601 version 1: offset corners 26-33, MSL heights)
    rewrites the centre and corner items and nothing else (every other item, as klvdata reads
    it, as it was); of the Tekever flight, whose every packet lacks tag 19's value, copies the
    file byte for byte and says why in one line for the 19 packets (it printed one per packet).
    About 9 s: 407 real packets compared item by item before and after, and a replay."""
    from geoloc.workflows.klv_replay import replay_klv

    from geoloc.workflows.klv_fix import fix_klv

    src = CORPUS / "esri_cheyenne.bin"
    out = tmp_path / "fixed.bin"
    assert "407 packets read, 407 rewritten, 0 left unchanged" in str(fix_klv(src, out))
    rewritten = {23, 24, 25, *range(26, 34), 1}  # the centre, its MSL height, the offset corners, the checksum
    replay = replay_klv(src)
    step_lat = klv.TAG_BY_NUMBER[23].step
    step_lon = klv.TAG_BY_NUMBER[24].step
    before = list(klvdata_packets(src.read_bytes()))
    after = list(klvdata_packets(out.read_bytes()))
    assert len(after) == 407
    for i, ((_, _, v0), (_, _, v1)) in enumerate(zip(before, after)):
        a, b = klvdata_items(v0), klvdata_items(v1)
        assert a.keys() == b.keys()
        for tag in a.keys() - rewritten:
            assert a[tag][0] == b[tag][0] and str(a[tag][1]) == str(b[tag][1]), (i, tag)
        # the new centre is the replay's, to half a step of the items (klvdata's reading)
        assert abs(b[23][1] - replay.columns["lat_deg"][i]) <= step_lat / 2 + 1e-12
        assert abs(b[24][1] - replay.columns["lon_deg"][i]) <= step_lon / 2 + 1e-12
    assert [p.checksum is not None for p in klv.iter_packets(out.read_bytes())] == [True] * 407  # sums verified

    src = CORPUS / "tekever_ar5_realflight.bin"
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "klv", "fix", str(src), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == src.read_bytes()
    unchanged = [s for s in r.stdout.splitlines() if "unchanged:" in s]
    assert unchanged == [
        "  packets 0-18 (19): unchanged: invalid_input: tag 19 (Sensor Relative Elevation Angle) holds "
        "the standard's reserved value (error / out of range): no value"
    ]
