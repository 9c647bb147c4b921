"""``geoloc klv fix``: KLV written back with geoloc's frame centres and corners (geoloc.workflows.klv_fix).

Checked with klvdata, the independent ST 0601 decoder of the test extra (its own
packet parser, value mappings and checksum function), by comparing the bytes of
input and output (only the rewritten items' values and the checksums may
differ), and by replaying the output: its reported centres and corners then
agree with the recomputed ones to the items' quantisation (millimetres for the
centre's 4-byte items and the full corners; the offset corners' 2-byte items
have steps of 0.25 m).
"""

import math
from fractions import Fraction
from pathlib import Path

import av
import klvdata
import numpy as np
import pytest
from klvdata.common import packet_checksum

from geoloc.cli import main
from geoloc.io.klv import TAG_BY_NAME, decode_packet, encode_packet, iter_packets, local_set_items, write_ts
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.klv_fix import CENTRE_TAGS, FULL_CORNER_TAGS, OFFSET_CORNER_TAGS, fix_klv
from geoloc.workflows.klv_replay import replay_klv

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "assets" / "klv" / "example_flight.klv"
DEM_PATH = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"
FAULTED = list(range(100, 110)) + list(range(200, 205)) + list(range(250, 257))  # assets/README.md
REWRITABLE = set(CENTRE_TAGS) | set(FULL_CORNER_TAGS) | set(OFFSET_CORNER_TAGS)

M_PER_DEG = 111_320.0


def half_step_m(lat_name, lon_name, lat_deg):
    """Half a step of a latitude / longitude item pair as a horizontal distance [m] (upper bound)."""
    a, b = TAG_BY_NAME[lat_name].step, TAG_BY_NAME[lon_name].step
    return math.hypot(0.5 * a * M_PER_DEG, 0.5 * b * M_PER_DEG * math.cos(math.radians(lat_deg))) * 1.01


CENTRE_BOUND_M = half_step_m("frame_center_latitude_deg", "frame_center_longitude_deg", 36.6)  # 4.5 mm
FULL_CORNER_BOUND_M = half_step_m("corner_latitude_1_deg", "corner_longitude_1_deg", 36.6)
# an offset corner is the centre (4-byte items) plus a 2-byte offset: both roundings add
OFFSET_CORNER_BOUND_M = CENTRE_BOUND_M + half_step_m(
    "offset_corner_latitude_1_deg", "offset_corner_longitude_1_deg", 36.6
)


@pytest.fixture(scope="module")
def dem():
    return DEM.open(DEM_PATH)


def packets_of(data: bytes):
    """(offset, bytes) of every packet klvdata's own parser finds."""
    out, pos = [], 0
    for p in klvdata.StreamParser(data):
        b = bytes(p)
        k = data.index(b[:17], pos)
        out.append((k, b))
        pos = k + len(b)
    return out


def changed_ranges_allowed(blob: bytes) -> np.ndarray:
    """Mask of the bytes of a packet that a fix may change: rewritable items' values and the checksum."""
    ok = np.zeros(len(blob), bool)
    for t, a, b in local_set_items(blob):
        if t in REWRITABLE or t == 1:
            ok[a:b] = True
    return ok


def check_copy(a: bytes, b: bytes, rewritten: set):
    """The output differs from the input only where allowed; packets not rewritten are identical."""
    assert len(a) == len(b)
    pa, pb = packets_of(a), packets_of(b)
    assert [k for k, _ in pa] == [k for k, _ in pb]
    for n, ((k, x), (_, y)) in enumerate(zip(pa, pb)):
        diff = np.frombuffer(x, np.uint8) != np.frombuffer(y, np.uint8)
        if n not in rewritten:
            assert not diff.any(), n
            continue
        assert not (diff & ~changed_ranges_allowed(x)).any(), n
        # klvdata: the rewritten packet's checksum is right, and every other item decodes the same
        assert packet_checksum(y) == y[-2:], n
        ix, iy = klvdata.StreamParser(x), klvdata.StreamParser(y)
        mx, my = next(iter(ix)).MetadataList(), next(iter(iy)).MetadataList()
        assert set(mx) == set(my)
        for tag in mx:
            if tag not in REWRITABLE and tag != 1:
                assert mx[tag] == my[tag], (n, tag)
    # outside the packets (none in these files) nothing may change either
    ends = [(k, k + len(x)) for k, x in pa]
    mask = np.ones(len(a), bool)
    for s, e in ends:
        mask[s:e] = False
    assert np.array_equal(np.frombuffer(a, np.uint8)[mask], np.frombuffer(b, np.uint8)[mask])


def klvdata_value(blob: bytes, tag: int) -> float:
    return float(next(iter(klvdata.StreamParser(blob))).MetadataList()[tag][3])


def test_fix_the_bundled_flight_on_the_dem(tmp_path, dem):
    before = replay_klv(EXAMPLE, surface=surface_for(dem=dem))
    c0 = before.columns
    faulted = np.isin(c0["packet"], FAULTED)
    assert np.all(c0["frame_center_error_m"][faulted] > 4.0)  # 5 m to 114 m before the fix
    out = tmp_path / "fixed.klv"
    fix = fix_klv(EXAMPLE, out, surface=surface_for(dem=dem))
    assert fix.packets == 299 and fix.rewritten == 298 and len(fix.bad) == 1
    assert [k for k, _ in fix.unchanged] == [275]  # the packet without tags 18, 19
    assert fix.items[23] == fix.items[89] == 298
    a, b = EXAMPLE.read_bytes(), out.read_bytes()
    rewritten = set(int(p) for p, st in zip(c0["packet"], c0["status"]) if st == Status.OK)
    check_copy(a, b, rewritten)
    # klvdata reads the recomputed values: the replay's to half a step of each item
    pb = packets_of(b)
    for k in np.flatnonzero(c0["status"] == Status.OK)[::13]:
        blob = pb[int(c0["packet"][k])][1]
        assert abs(klvdata_value(blob, 23) - c0["lat_deg"][k]) <= TAG_BY_NAME["frame_center_latitude_deg"].step / 2
        assert abs(klvdata_value(blob, 24) - c0["lon_deg"][k]) <= TAG_BY_NAME["frame_center_longitude_deg"].step / 2
        assert abs(klvdata_value(blob, 78) - c0["h_m"][k]) <= TAG_BY_NAME["frame_center_hae_m"].step / 2
        assert abs(klvdata_value(blob, 88) - c0["corner4_lat_deg"][k]) <= TAG_BY_NAME["corner_latitude_4_deg"].step / 2
    # replaying the copy: every located packet's tags now agree to the quantisation, the faulted ones too
    after = replay_klv(out, surface=surface_for(dem=dem))
    c1 = after.columns
    ok = c1["status"] == Status.OK
    assert ok.sum() == 298 and len(after.errors) == 1
    assert np.nanmax(c1["frame_center_error_m"][ok]) <= CENTRE_BOUND_M
    assert np.nanmax(c1["corner_error_m"][ok]) <= FULL_CORNER_BOUND_M
    print(
        f"after the fix: frame-centre error max {np.nanmax(c1['frame_center_error_m'][ok]) * 1000:.2f} mm "
        f"(bound {CENTRE_BOUND_M * 1000:.2f}), on the faulted packets before: "
        f"{np.min(c0['frame_center_error_m'][faulted]):.1f}-{np.max(c0['frame_center_error_m'][faulted]):.1f} m"
    )
    # the heights: tag 78 the DEM hit's HAE, tag 25 that minus N at the new centre
    k = int(np.flatnonzero(c1["packet"] == 105)[0])
    assert abs(c1["frame_center_hae_m"][k] - c0["h_m"][k]) <= TAG_BY_NAME["frame_center_hae_m"].step / 2
    assert (
        abs(c1["frame_center_hae_m"][k] - c1["frame_center_elevation_msl_m"][k] - c1["sensor_geoid_n_m"][k]) < 0.7
    )  # N at the centre vs at the sensor (2.6 km apart) + 2 steps


def _offset_corner_packets(n=12, start=98):
    """Packets of the bundled flight (faulted 100-109 among them) re-encoded with offset corners (26-33)
    instead of full ones and without tag 78 (so tag 25, MSL, carries the centre's height)."""
    data = EXAMPLE.read_bytes()
    good = [p for p in iter_packets(data) if hasattr(p, "fields")][start : start + n]
    out = []
    for p in good:
        f = dict(p.fields)
        for j in range(1, 5):
            f[f"offset_corner_latitude_{j}_deg"] = f.pop(f"corner_latitude_{j}_deg") - f["frame_center_latitude_deg"]
            f[f"offset_corner_longitude_{j}_deg"] = f.pop(f"corner_longitude_{j}_deg") - f["frame_center_longitude_deg"]
        f.pop("frame_center_hae_m")
        out.append(encode_packet(f))
    return out


def _demux(path):
    with av.open(str(path)) as c:
        streams = [(s.type, s.codec_context.name if s.codec_context else None, s.id) for s in c.streams]
        pk = [(p.stream.index, p.stream.type, p.pts, p.dts, bytes(p)) for p in c.demux() if p.size]
    return streams, pk


def test_ts_with_video_is_remuxed_and_the_video_left_alone(tmp_path, dem):
    blobs = _offset_corner_packets()
    ts = tmp_path / "clip.ts"
    # a real MPEG-2 video stream, one frame per packet (PyAV encodes it), beside the KLV data stream
    write_ts(ts, blobs, rate=1.0, video=True, video_size=(64, 48), time_base=Fraction(1, 90000))
    s_in, p_in = _demux(ts)
    assert [t for t, _, _ in s_in] == ["video", "data"]
    out = tmp_path / "fixed.ts"
    fix = fix_klv(ts, out, surface=surface_for(dem=dem))
    assert fix.rewritten == len(blobs) and fix.other_packets > 0
    assert set(fix.items) == {23, 24, 25} | set(OFFSET_CORNER_TAGS)
    s_out, p_out = _demux(out)
    assert s_out == s_in  # same streams, codecs and PIDs
    vin = [p for p in p_in if p[1] == "video"]
    vout = [p for p in p_out if p[1] == "video"]
    assert len(vin) == len(vout) >= len(blobs) and vin == vout  # every video packet, bytes and time stamps
    kin = [p for p in p_in if p[1] == "data"]
    kout = [p for p in p_out if p[1] == "data"]
    assert [p[2:4] for p in kin] == [p[2:4] for p in kout]
    check_copy(b"".join(p[4] for p in kin), b"".join(p[4] for p in kout), set(range(len(blobs))))
    after = replay_klv(out, surface=surface_for(dem=dem))
    c = after.columns
    assert np.all(c["status"] == Status.OK)
    assert np.max(c["frame_center_error_m"]) <= CENTRE_BOUND_M
    assert np.max(c["corner_error_m"]) <= OFFSET_CORNER_BOUND_M
    before = replay_klv(ts, surface=surface_for(dem=dem)).columns["frame_center_error_m"]
    assert before[2:12].min() > 80  # packets 100-109: the heading fault
    # tag 25 (MSL) written as HAE - N at the new centre: the replay makes it HAE again the same way
    assert (
        np.max(np.abs(c["reported_h_m"] - replay_klv(ts, surface=surface_for(dem=dem)).columns["h_m"]))
        <= TAG_BY_NAME["frame_center_elevation_m"].step / 2 + 1e-6
    )


def test_a_calibration_is_applied(tmp_path, dem):
    from geoloc.sensors.sensor_file import load_sensor

    sensor = load_sensor(ROOT / "assets" / "sensors" / "eo_turret.toml")  # mount, boresight, lever arm
    out = tmp_path / "cal.klv"
    fix_klv(EXAMPLE, out, surface=surface_for(dem=dem), sensor=sensor)
    with_cal = replay_klv(out, surface=surface_for(dem=dem), sensor=sensor).columns
    without = replay_klv(out, surface=surface_for(dem=dem)).columns
    ok = with_cal["status"] == Status.OK
    assert np.max(with_cal["frame_center_error_m"][ok]) <= CENTRE_BOUND_M
    # without the calibration the copy's centres are off by exactly what the calibration moves them
    # (the two replays of the input, with and without it), to the quantisation
    from geoloc.geodesy.geodesic import horizontal_distance_m

    a, b = (
        replay_klv(EXAMPLE, surface=surface_for(dem=dem), sensor=sensor).columns,
        replay_klv(EXAMPLE, surface=surface_for(dem=dem)).columns,
    )
    moved = horizontal_distance_m(a["lat_deg"], a["lon_deg"], b["lat_deg"], b["lon_deg"])
    assert np.median(moved[ok]) > 50 * CENTRE_BOUND_M  # 0.39 m: the mount, boresight and lever arm matter
    assert np.max(np.abs(without["frame_center_error_m"][ok] - moved[ok])) <= CENTRE_BOUND_M


def test_cli_and_refusals(tmp_path, capsys):
    out = tmp_path / "f.klv"
    assert main(["klv", "fix", str(EXAMPLE), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "299 packets read, 298 rewritten" in text and "packet 275: unchanged" in text
    assert "byte 32400: checksum mismatch" in text
    assert main(["klv", "fix", str(EXAMPLE), "--out", str(EXAMPLE)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert main(["klv", "fix", str(EXAMPLE), "--out", str(tmp_path / "x.ts")]) == 2
    assert "same kind" in capsys.readouterr().err
    assert main(["klv", "fix", str(EXAMPLE), "--out", str(tmp_path / "nope" / "x.klv")]) == 2
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]  # no temporary file left behind


def test_replace_values_keeps_every_other_byte():
    from geoloc.io.klv import encode_value, replace_values

    blob = _offset_corner_packets(1)[0]
    new = replace_values(blob, {23: encode_value("frame_center_latitude_deg", 36.5)})
    assert decode_packet(new)["frame_center_latitude_deg"] == pytest.approx(36.5, abs=5e-8)
    assert packet_checksum(new) == new[-2:]
    diff = np.flatnonzero(np.frombuffer(blob, np.uint8) != np.frombuffer(new, np.uint8))
    (t23,) = [(a, b) for t, a, b in local_set_items(blob) if t == 23]
    assert all(t23[0] <= i < t23[1] or i >= len(blob) - 2 for i in diff)
    with pytest.raises(ValueError, match="tag 82 is not in the packet"):
        replace_values(blob, {82: b"\0\0\0\0"})
    with pytest.raises(ValueError, match="3 new bytes"):
        replace_values(blob, {23: b"\0\0\0"})


BUDGET_TOML = """
[uncertainty]
north_m = 2.0
east_m = 2.0
up_m = 3.0
heading_deg = 0.05
pitch_deg = 0.02
roll_deg = 0.02
azimuth_deg = 0.03
elevation_deg = 0.03
dem_m = 9.73
"""


def test_a_budget_writes_the_predicted_ce90_le90_into_tags_45_46(tmp_path, dem, capsys):
    """With the sensor file's [uncertainty] budget, tags 45 / 46 (Target Error Estimate CE90 / LE90)
    get the replay's predicted CE90 / LE90: added before the checksum where a packet has none (the
    bundled flight), rewritten in place where it has them; klvdata decodes them and every other item
    as before."""
    from geoloc.sensors.sensor_file import load_sensor, load_sensor_budget

    sfile = tmp_path / "turret.toml"
    sfile.write_text((ROOT / "assets" / "sensors" / "eo_turret.toml").read_text() + BUDGET_TOML)
    out = tmp_path / "fixed.klv"
    assert main(["klv", "fix", str(EXAMPLE), "--out", str(out), "--dem", str(DEM_PATH), "--sensor", str(sfile)]) == 0
    text = capsys.readouterr().out
    assert "tags 45 / 46 hold the predicted CE90 / LE90" in text and "tag 45 added to 298" in text
    sensor, budget = load_sensor(sfile), load_sensor_budget(sfile)
    ref = replay_klv(EXAMPLE, surface=surface_for(dem=dem), sensor=sensor, budget=budget).columns
    ok = ref["status"] == Status.OK
    assert ok.sum() == 298 and np.all(np.isfinite(ref["ce90_m"][ok]))
    a, b = EXAMPLE.read_bytes(), out.read_bytes()
    pa, pb = packets_of(a), packets_of(b)
    assert len(pa) == len(pb) == 300  # klvdata's parser finds the bad packet too (packet numbers index both)
    half = {t: TAG_BY_NAME[n].step / 2 + 1e-9 for t, n in ((45, "target_error_ce90_m"), (46, "target_error_le90_m"))}
    for k in range(len(ref["packet"])):
        n = int(ref["packet"][k])
        x, y = pa[n][1], pb[n][1]
        if not ok[k]:
            assert x == y  # the packet that could not be located (275): copied as it was
            continue
        assert packet_checksum(y) == y[-2:], n
        my = next(iter(klvdata.StreamParser(y))).MetadataList()
        mx = next(iter(klvdata.StreamParser(x))).MetadataList()
        assert set(my) == set(mx) | {45, 46}
        for tag in mx:
            if tag not in REWRITABLE and tag != 1:
                assert mx[tag] == my[tag], (n, tag)
        assert abs(float(my[45][3]) - ref["ce90_m"][k]) <= half[45], n
        assert abs(float(my[46][3]) - ref["le90_m"][k]) <= half[46], n
        assert local_set_items(y)[-1][0] == 1  # the checksum stays the last item
    # a packet that has the tags already: rewritten in place (same length)
    f = dict(next(p for p in iter_packets(a) if hasattr(p, "fields")).fields)
    f.update(target_error_ce90_m=1000.0, target_error_le90_m=2000.0)
    src, dst = tmp_path / "with.klv", tmp_path / "with_fixed.klv"
    src.write_bytes(encode_packet(f))
    fix = fix_klv(src, dst, surface=surface_for(dem=dem), sensor=sensor, budget=budget)
    assert fix.items[45] == fix.items[46] == 1 and not fix.added
    y = dst.read_bytes()
    assert len(y) == src.stat().st_size and packet_checksum(y) == y[-2:]
    back = replay_klv(dst, surface=surface_for(dem=dem), sensor=sensor, budget=budget).columns
    assert abs(back["reported_ce90_m"][0] - back["ce90_m"][0]) <= half[45]
    assert abs(back["reported_le90_m"][0] - back["le90_m"][0]) <= half[46]
    # without a budget the tags are left alone
    fix_klv(src, dst, surface=surface_for(dem=dem), sensor=sensor)
    assert decode_packet(dst.read_bytes())["target_error_ce90_m"] == pytest.approx(1000.0, abs=half[45])


def test_add_items_keeps_every_other_item():
    from geoloc.io.klv import add_items, encode_value

    blob = _offset_corner_packets(1)[0]
    new = add_items(
        blob, {46: encode_value("target_error_le90_m", 7.5), 45: encode_value("target_error_ce90_m", 12.25)}
    )
    assert packet_checksum(new) == new[-2:]
    old_items = local_set_items(blob)
    new_items = local_set_items(new)
    assert [t for t, _, _ in new_items] == [t for t, _, _ in old_items[:-1]] + [45, 46, 1]
    for (t, a, b), (_, c, d) in zip(old_items[:-1], new_items):
        assert blob[a:b] == new[c:d], t
    m = next(iter(klvdata.StreamParser(new))).MetadataList()
    assert float(m[45][3]) == pytest.approx(12.25, abs=0.032) and float(m[46][3]) == pytest.approx(7.5, abs=0.032)
    with pytest.raises(ValueError, match="tag 23 is in the packet already"):
        add_items(blob, {23: b"\0\0\0\0"})
