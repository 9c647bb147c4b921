"""One contract per interface of the user's files: every flight reader, every output writer.

As tests/pipeline/test_contract.py runs one contract against every sensor, surface and correction
(Orekit Rugged's AbstractAlgorithmTest), each test function here is parametrised over every
implementation of its interface:

- **readers** (records CSV, raw KLV, KLV in MPEG-TS, DJI photos, DJI SRT): a bad row, packet,
  photo or block between two good ones is reported where it is (line, byte offset or file
  name) and the good ones around it are kept; every height read says its datum; a time going
  back is reported.
- **writers** (the results CSV of a photo replay, the SRT flight CSV, GeoJSON, GeoPackage, KML,
  CZML, Cursor-on-Target, NITF with RPC00B, GeoTIFF with RPC, the ellipsoidal DEM GeoTIFF): a
  regular file is replaced by a rename of a temporary file (a hard link to the old file keeps
  the old bytes), a symlink is written through to its target and stays a link, a FIFO is written
  through and stays a FIFO, an unwritable path is refused in one line naming it; what is
  written reads back through a reader that is not geoloc's (``csv``, ``json``, lxml, SQLite
  with the GeoPackage binary header parsed here, GDAL through rasterio) with the values given.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import shutil
import sqlite3
import stat
import struct
import threading
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import asset_path

etree = pytest.importorskip("lxml.etree")
rasterio = pytest.importorskip("rasterio")

# --------------------------------------------------------------------------- readers


@dataclass
class Read:
    """What a reader gave, in one shape: the good items' ids in order, the bad ones' reports."""

    kept: list
    #: (where, text): where is the line, byte offset or file name the reader gave
    bad: list
    #: the datum each height read carries (one entry per height kind)
    datums: list
    #: the times of the kept items, in the order given, and the reports of a time going back
    times: list = field(default_factory=list)
    time_reports: list = field(default_factory=list)


# -- records CSV: rows 1 and 3 good, row 2 (line 3) has a latitude out of range

_RECORD_HEADER = (
    "table,point,row,col,ac_lat_deg,ac_lon_deg,ac_h_m,heading_deg,pitch_deg,roll_deg,gimbal_roll_deg,gimbal_pitch_deg"
)


def _record(point, lat):
    return f"T,{point},100,200,{lat},-84.2,1500,10,1,2,0,-45"


def _records_file(tmp_path):
    p = tmp_path / "records.csv"
    p.write_text("\n".join([_RECORD_HEADER, _record("a", 36.5), _record("b", 96.5), _record("c", 36.6)]) + "\n")
    return p, ["a", "c"], 3


def _read_records(p):
    from geoloc.io.records import load_records

    r = load_records(p, altitude_datum="egm96")
    return Read(
        [row["point"] for row in r.rows],
        [(e.line, f"{r.path}: {e}") for e in r.errors],
        [r.altitude.sentence()],
    )


# -- raw KLV: three packets, the middle one's checksum wrong; its byte offset is the first one's length


def _klv_packets(times_us):
    from geoloc.io.klv import encode_packet

    return [
        encode_packet(
            {
                "precision_time_stamp_us": t,
                "sensor_latitude_deg": 36.5 + 1e-3 * k,
                "sensor_longitude_deg": -84.2,
                "sensor_true_altitude_m": 1500.0,
                "sensor_ellipsoid_height_m": 1470.0,
                "mission_id": f"P{k}",
            }
        )
        for k, t in enumerate(times_us)
    ]


_T0_US = 1_700_000_000_000_000


def _spoil_checksum(pkt: bytes) -> bytes:
    return pkt[:-1] + bytes([pkt[-1] ^ 0xFF])


def _klv_file(tmp_path):
    a, b, c = _klv_packets([_T0_US, _T0_US + 100_000, _T0_US + 200_000])
    p = tmp_path / "flight.klv"
    p.write_bytes(a + _spoil_checksum(b) + c)
    return p, ["P0", "P2"], len(a)


def _klv_read(items):
    from geoloc.io.klv import TAG_BY_NAME, KlvError

    kept, bad, times, datums, back = [], [], [], set(), []
    for it in items:
        if isinstance(it, KlvError):
            bad.append((it.offset, str(it)))
            continue
        kept.append(it.fields["mission_id"])
        times.append(it.fields["precision_time_stamp_us"])
        datums |= {TAG_BY_NAME[n].datum for n in it.fields if TAG_BY_NAME.get(n) and TAG_BY_NAME[n].datum}
        if it.time_back:
            back.append((it.offset, it.time_back))
    return kept, bad, times, sorted(datums), back


def _read_klv(p):
    from geoloc.io.klv import read_klv_file

    kept, bad, times, datums, back = _klv_read(read_klv_file(p))
    return Read(kept, [(o, f"{p.name} {t}") for o, t in bad], datums, times, back)


# -- KLV in MPEG-TS: the same three packets, one per PES; the bad one is found at its PES's byte position


def _ts_file(tmp_path):
    from geoloc.io.klv import write_ts

    a, b, c = _klv_packets([_T0_US, _T0_US + 100_000, _T0_US + 200_000])
    p = tmp_path / "flight.ts"
    write_ts(p, [a, _spoil_checksum(b), c])
    # the byte position of the TS packet that starts the second PES
    return p, ["P0", "P2"], _klv_pes_starts(p.read_bytes())[1]


def _klv_pes_starts(data: bytes) -> list:
    """The byte positions of the TS packets that start a KLV PES, found by walking the 188-byte
    packets here: the KLV PID's payload_unit_start_indicator packets, in order (ISO 13818-1 2.4.3.2)."""
    starts = []
    for k in range(0, len(data), 188):
        pusi, pid = data[k + 1] & 0x40, ((data[k + 1] & 0x1F) << 8) | data[k + 2]
        if pusi and pid not in (0, 0x11, 0x1FFF) and b"KLVA" not in data[k : k + 188] and pid >= 0x100:
            starts.append(k)
    return starts


def _read_ts(p):
    from geoloc.io.klv import read_ts_klv

    kept, bad, times, datums, back = _klv_read(read_ts_klv(p))
    return Read(kept, [(o, f"{p.name} {t}") for o, t in bad], datums, times, back)


# -- photos: two copies of the bundled DJI photo around a JPEG whose XMP is cut


def _photo_files(tmp_path):
    src = asset_path("photos", "DJI_0001.JPG")
    a, c = tmp_path / "DJI_A.JPG", tmp_path / "DJI_C.JPG"
    shutil.copy(src, a)
    shutil.copy(src, c)
    bad = tmp_path / "DJI_B.JPG"
    bad.write_bytes(src.read_bytes()[:600])  # the JPEG's header and no image: not a photo geoloc can read
    targets = tmp_path / "targets.csv"
    rows = next(iter(asset_path("photos", "targets.csv").read_text().splitlines()[1:2]))
    cells = rows.split(",")[1:]
    targets.write_text(
        "image,row,col,truth_lat_deg,truth_lon_deg,truth_h_m\n"
        + "".join(",".join([name] + cells) + "\n" for name in ("DJI_A.JPG", "DJI_B.JPG", "DJI_C.JPG"))
    )
    return (a, bad, c, targets), ["DJI_A.JPG", "DJI_C.JPG"], "DJI_B.JPG"


def _read_photos(files):
    from geoloc.workflows.photo_replay import replay_photos

    *photos, targets = files
    rows, messages = replay_photos(photos, targets)
    # the photo's own report (the count of its targets skipped follows it)
    bad = [(m.split(":")[0].strip(), m) for m in messages if "skipped:" in m]
    return Read(
        [r["image"] for r in rows],
        bad,
        sorted({r["h_datum"] for r in rows} | {r["altitude_datum"] for r in rows}),
    )


# -- DJI SRT: blocks 1 and 3 good, block 2's latitude is not a number (the file's line 7)


def _srt_block(k, t0, t1, lat):
    return f"{k}\n00:00:0{t0},000 --> 00:00:0{t1},000\n[latitude: {lat}] [longitude: -84.21] [rel_alt: 100.0 abs_alt: 412.6] [FrameCnt: {k}]\n\n"


def _srt_file(tmp_path):
    p = tmp_path / "DJI_0001.SRT"
    p.write_text(_srt_block(1, 0, 1, "36.52") + _srt_block(2, 1, 2, "36.5x") + _srt_block(3, 2, 3, "36.53"))
    return p, [1, 3], 7


def _read_srt(p):
    from geoloc.io.dji_srt import read_srt, write_srt_records

    f = read_srt(p)
    out = p.with_suffix(".csv")
    write_srt_records(out, f)
    rows = list(csv.DictReader(out.open()))
    return Read(
        [r.frame for r in f.records],
        [(line, f"{Path(f.path).name} line {line}: {m}") for line, m in f.errors],
        sorted({r["h_datum"] for r in rows} | {r["abs_alt_datum"] for r in rows} | {r["rel_alt_datum"] for r in rows}),
        [r.start_s for r in f.records],
        list(f.warnings),
    )


READERS = {
    "records-csv": (_records_file, _read_records),
    "klv": (_klv_file, _read_klv),
    "klv-in-ts": (_ts_file, _read_ts),
    "photos": (_photo_files, _read_photos),
    "dji-srt": (_srt_file, _read_srt),
}


def _name_of(files) -> str:
    return Path(files).name if not isinstance(files, tuple) else ""


@pytest.mark.parametrize("reader", list(READERS))
def test_a_reader_keeps_the_good_items_around_a_bad_one_and_reports_where_it_is(reader, tmp_path):
    make, read = READERS[reader]
    files, good, where = make(tmp_path)
    got = read(files)
    assert got.kept == good  # both neighbours of the bad item, in file order
    assert len(got.bad) == 1, got.bad
    position, text = got.bad[0]
    assert position == where  # the line, byte offset or file name counted in the test
    assert str(where) in text and (_name_of(files) in text)


#: What each reader's heights must say: the datum words, counted in the file formats' documents
#: (MISB ST 0601: tag 15 MSL, tag 75 HAE; DJI: AbsoluteAltitude / abs_alt above sea level, taken
#: as EGM96, RelativeAltitude / rel_alt above take-off) and geoloc's one output datum.
DATUM_WORDS = {
    "records-csv": ["EGM96"],
    "klv": ["HAE", "MSL"],
    "klv-in-ts": ["HAE", "MSL"],
    "photos": ["EGM96", "ellipsoid (WGS 84)"],
    "dji-srt": ["EGM96", "above the take-off point", "ellipsoid (WGS 84)"],
}


@pytest.mark.parametrize("reader", list(READERS))
def test_every_height_a_reader_gives_says_its_datum(reader, tmp_path):
    make, read = READERS[reader]
    files, _, _ = make(tmp_path)
    datums = read(files).datums
    assert datums and all(d.strip() for d in datums)
    for word in DATUM_WORDS[reader]:
        assert any(word in d for d in datums), (word, datums)


def _klv_back(tmp_path, suffix):
    """Three packets, the third's Precision Time Stamp 0.1 s before the second's; (file, the third
    packet's byte offset: after the first two packets in a raw file, the third PES's first TS packet
    in a transport stream)."""
    from geoloc.io.klv import write_ts

    a, b, c = _klv_packets([_T0_US, _T0_US + 200_000, _T0_US + 100_000])  # the third goes back 0.1 s
    p = tmp_path / f"back{suffix}"
    if suffix == ".klv":
        p.write_bytes(a + b + c)
        return p, len(a) + len(b)
    write_ts(p, [a, b, c])
    return p, _klv_pes_starts(p.read_bytes())[2]


def _srt_back(tmp_path):
    p = tmp_path / "back.SRT"
    p.write_text(_srt_block(1, 0, 1, "36.52") + _srt_block(2, 2, 3, "36.53") + _srt_block(3, 1, 2, "36.54"))
    return p, 9  # block 3 of the SRT starts on the file's line 9


#: Readers whose items carry a time (the records CSV has no time column; a photo's file order is
#: the user's, not a time order). Each is given three items, the third's time before the second's.
TIMED = {
    "klv": (lambda tmp: _klv_back(tmp, ".klv"), _read_klv),
    "klv-in-ts": (lambda tmp: _klv_back(tmp, ".ts"), _read_ts),
    "dji-srt": (_srt_back, _read_srt),
}


@pytest.mark.parametrize("reader", list(TIMED))
def test_a_time_going_back_is_kept_in_file_order_and_reported(reader, tmp_path):
    make, read = TIMED[reader]
    path, where = make(tmp_path)
    got = read(path)
    assert len(got.kept) == 3  # nothing is dropped or reordered for its time
    t = np.asarray(got.times, float)
    assert t[2] < t[1] and t[1] > t[0]
    assert len(got.time_reports) == 1, got.time_reports
    position, text = got.time_reports[0]
    assert "back" in text
    assert position == where  # the line or byte offset counted in the test
    if reader != "dji-srt":  # the packet's index and offset, and how far back (0.1 s written above)
        assert f"packet 3 (byte {where})" in text and "0.100000 s" in text, text


# --------------------------------------------------------------------------- writers


TABLE = {
    "table": ["F1", "F1", "F1"],
    "point": ["1", "2", "3"],
    "lat_deg": np.array([36.5, 36.51, 36.52]),
    "lon_deg": np.array([-84.2, -84.21, -84.22]),
    "h_m": np.array([400.0, 410.0, 420.0]),
    "h_datum": ["ellipsoid (WGS 84)"] * 3,
    "status": ["OK", "OK", "OK"],
    "time_s": np.array([0.0, 1.0, 2.0]),
}


def _lonlat():
    return np.c_[TABLE["lon_deg"], TABLE["lat_deg"]]


def _write_gis(fmt):
    def write(path):
        from geoloc.io.gis import export

        export({k: (list(v) if isinstance(v, list) else v.copy()) for k, v in TABLE.items()}, path, fmt)

    return write


def _gpkg_points(path):
    """Every point geometry of every feature table, read with sqlite3 and the GeoPackage binary header."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        tables = con.execute(
            "SELECT c.table_name, g.column_name FROM gpkg_contents c JOIN gpkg_geometry_columns g "
            "ON c.table_name = g.table_name WHERE c.data_type = 'features'"
        ).fetchall()
        out = {}
        for table, col in tables:
            pts = []
            for (blob,) in con.execute(f'SELECT "{col}" FROM "{table}"'):
                # GeoPackage 1.3 2.1.3: 'GP', version, flags (bit 0 byte order, bits 1-3 envelope kind)
                assert blob[:2] == b"GP"
                flags = blob[3]
                env = {0: 0, 1: 32, 2: 48, 3: 48, 4: 64}[(flags >> 1) & 7]
                wkb = blob[8 + env :]
                order = "<" if wkb[0] == 1 else ">"
                (kind,) = struct.unpack(order + "I", wkb[1:5])
                if kind % 1000 == 1:  # Point, Point Z (1001) or ISO/EWKB Z flag
                    pts.append(struct.unpack(order + "2d", wkb[5:21]))
            out[table] = pts
        return out
    finally:
        con.close()


def _check_gpkg(path):
    pts = _gpkg_points(path)
    point_layers = [np.array(v) for v in pts.values() if len(v) == 3]
    assert any(np.allclose(v, _lonlat(), atol=1e-12, rtol=0) for v in point_layers), pts


def _check_geojson(path):
    doc = json.loads(Path(path).read_text())
    xy = [f["geometry"]["coordinates"] for f in doc["features"] if f["geometry"]["type"] == "Point"]
    assert np.allclose(np.array(xy)[:, :2], _lonlat(), atol=1e-9, rtol=0)
    assert np.allclose(np.array(xy)[:, 2], TABLE["h_m"], atol=1e-6, rtol=0)


def _check_kml(path):
    root = etree.parse(str(path)).getroot()
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    coords = [c.text.strip() for c in root.iterfind(".//k:Placemark/k:Point/k:coordinates", ns)]
    xyz = np.array([[float(v) for v in c.split(",")] for c in coords])
    # the points layer's placemarks are among them (KML holds the ellipse and track layers too)
    assert any(np.allclose(xyz[k : k + 3, :2], _lonlat(), atol=1e-9, rtol=0) for k in range(len(xyz) - 2)), xyz


def _check_czml(path):
    doc = json.loads(Path(path).read_text())
    assert doc[0]["id"] == "document"
    pos = [p["position"]["cartographicDegrees"] for p in doc[1:] if "position" in p and "point" in p]
    xy = np.array([p[-3:-1] if len(p) % 4 == 0 else p[:2] for p in pos])
    assert np.allclose(xy[:3], _lonlat(), atol=1e-9, rtol=0), pos


def _write_cot(path):
    from geoloc.io.cot import cot_events, write_cot

    write_cot(cot_events(TABLE, now=datetime(2026, 12, 6, 12, 0, tzinfo=UTC)), path)


def _check_cot(path):
    lines = [ln for ln in Path(path).read_bytes().splitlines() if ln.strip()]
    pts = [etree.fromstring(ln).find("point") for ln in lines]
    xy = np.array([[float(p.get("lon")), float(p.get("lat"))] for p in pts])
    assert np.allclose(xy, _lonlat(), atol=1e-9, rtol=0)


def _rpc_model():
    from geoloc.sensors.rpc import RPCModel

    rng = np.random.default_rng(3)
    coef = rng.normal(size=(4, 20)) * 0.05
    coef[:, 0] = [0.1, 1.0, -0.2, 1.0]
    return RPCModel(
        1000.0, 2000.0, 36.5, -84.2, 600.0, 1000.0, 2000.0, 0.2, 0.25, 800.0, coef[0], coef[1], coef[2], coef[3]
    )


def _write_nitf(path):
    from geoloc.io.rpc_gdal import write_rpc_nitf

    write_rpc_nitf(path, _rpc_model(), 64, 64, renormalize=False)


def _write_rpc_tif(path):
    from geoloc.io.rpc_gdal import write_rpc_geotiff

    write_rpc_geotiff(path, _rpc_model(), 64, 64)


def _check_rpc(rel_coef):
    def check(path):
        m = _rpc_model()
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path) as src:
            r = src.rpcs
            assert (src.width, src.height) == (64, 64)
        assert (r.lat_off, r.long_off, r.height_off) == pytest.approx((36.5, -84.2, 600.0), abs=1e-4)
        assert (r.line_scale, r.samp_scale, r.height_scale) == pytest.approx((1000.0, 2000.0, 800.0), abs=0.5)
        for name in ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff"):
            mine = getattr(m, name.replace("_coeff", ""))
            # the NITF's RPC00B keeps 7 significant digits (+d.ddddddE+d), a GeoTIFF's text 15
            assert np.allclose(getattr(r, name), mine, rtol=rel_coef, atol=1e-9), name

    return check


def _dem():
    from geoloc.surfaces.dem import DEM

    h = 300.0 + np.arange(12.0).reshape(3, 4)
    return DEM.from_array(h, 36.6, -84.3, 0.01, 0.01, datum="ellipsoid")


def _write_dem(path):
    from geoloc.io.rpc_gdal import write_ellipsoidal_dem

    write_ellipsoidal_dem(_dem(), path)


def _check_dem(path):
    with rasterio.open(path) as src:
        v = src.read(1)
        t = src.transform
    assert np.array_equal(v, 300.0 + np.arange(12.0).reshape(3, 4))
    # pixel-centre nodes: the first node's centre is (west, north), the cell 0.01 deg
    assert (t.c + t.a / 2, t.f + t.e / 2) == pytest.approx((-84.3, 36.6), abs=1e-12)


PHOTO_ROWS = [
    {"image": "A.JPG", "row": 1.5, "col": 2.5, "lat_deg": 36.5, "lon_deg": -84.2, "h_m": 400.0},
    {"image": "B.JPG", "row": 3.5, "col": 4.5, "lat_deg": 36.51, "lon_deg": -84.21, "h_m": math.nan},
]


def _write_photo_rows(path):
    from geoloc.workflows.photo_replay import write_rows

    write_rows(path, [dict(r) for r in PHOTO_ROWS])


def _check_photo_rows(path):
    rows = list(csv.DictReader(Path(path).open(encoding="utf-8")))
    assert [r["image"] for r in rows] == ["A.JPG", "B.JPG"]
    assert [float(r["lat_deg"]) for r in rows] == [36.5, 36.51]
    assert rows[1]["h_m"] == ""  # NaN is an empty cell


def _write_srt_csv(path):
    from geoloc.io.dji_srt import SrtFlight, SrtRecord, write_srt_records

    recs = [SrtRecord(1, 1, 0.0, 1.0, 36.52, -84.21, 412.6, 100.2, 1), SrtRecord(2, 5, 1.0, 2.0, 36.53, -84.2)]
    write_srt_records(path, SrtFlight("x.SRT", recs, []))


def _check_srt_csv(path):
    rows = list(csv.DictReader(Path(path).open(encoding="utf-8")))
    assert [(float(r["ac_lat_deg"]), float(r["ac_lon_deg"])) for r in rows] == [(36.52, -84.21), (36.53, -84.2)]
    assert rows[0]["abs_alt_m"] == "412.6" and rows[1]["ac_h_m"] == ""


WRITERS = {
    "photo-results-csv": (".csv", _write_photo_rows, _check_photo_rows),
    "srt-flight-csv": (".csv", _write_srt_csv, _check_srt_csv),
    "geojson": (".geojson", _write_gis("geojson"), _check_geojson),
    "gpkg": (".gpkg", _write_gis("gpkg"), _check_gpkg),
    "kml": (".kml", _write_gis("kml"), _check_kml),
    "czml": (".czml", _write_gis("czml"), _check_czml),
    "cot": (".cot", _write_cot, _check_cot),
    "nitf-rpc": (".ntf", _write_nitf, _check_rpc(1e-6)),
    "geotiff-rpc": (".tif", _write_rpc_tif, _check_rpc(1e-12)),
    "geotiff-dem": (".tif", _write_dem, _check_dem),
}


def _leftovers(folder: Path, keep=()):
    return sorted(p.name for p in folder.iterdir() if ".geoloc-" in p.name and p.name not in keep)


def _regular_is_renamed(suffix, write, check, tmp_path):
    out = tmp_path / f"out{suffix}"
    out.write_bytes(b"the old output")
    os.link(out, tmp_path / "old.bak")  # a second name of the old file: an in-place write would change it
    ino = out.stat().st_ino
    write(out)
    assert (tmp_path / "old.bak").read_bytes() == b"the old output"
    assert out.stat().st_ino != ino and stat.S_ISREG(out.stat().st_mode)
    assert _leftovers(tmp_path) == []
    check(out)


def _symlink_written_through(suffix, write, check, tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / f"data{suffix}"
    target.write_bytes(b"the old output")
    link = tmp_path / f"out{suffix}"
    link.symlink_to(target)
    write(link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert _leftovers(tmp_path) == [] and _leftovers(tmp_path / "real") == []
    check(target)


def _fifo_written_through(suffix, write, check, tmp_path):
    fifo = tmp_path / f"out{suffix}"
    os.mkfifo(fifo)
    got = io.BytesIO()

    def drain():
        with open(fifo, "rb") as fh:
            got.write(fh.read())

    th = threading.Thread(target=drain, daemon=True)
    th.start()
    try:
        write(fifo)
        # looked at before anything below may touch the path
        still_fifo = stat.S_ISFIFO(os.lstat(fifo).st_mode)
    finally:
        if stat.S_ISFIFO(os.lstat(fifo).st_mode):
            th.join(timeout=30)  # the reader takes what the writer left in the pipe
            if th.is_alive():  # the writer never opened the FIFO: open it to free the reader
                with contextlib.suppress(OSError):
                    os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
                th.join(timeout=5)
        # else the FIFO was replaced: a reader blocked on it is left (a daemon thread, on a deleted FIFO)
    assert still_fifo
    assert _leftovers(tmp_path) == []
    copy = tmp_path / f"copy{suffix}"
    copy.write_bytes(got.getvalue())
    check(copy)


def _unwritable_is_one_line(suffix, write, check, tmp_path):
    missing = tmp_path / "no such folder" / f"out{suffix}"
    read_only = tmp_path / f"ro{suffix}"
    read_only.write_bytes(b"keep me")
    read_only.chmod(0o444)
    for path in (missing, read_only):
        with pytest.raises((ValueError, OSError)) as e:
            write(path)
        text = str(e.value)
        assert "\n" not in text.strip() and str(path) in text, text
    assert read_only.read_bytes() == b"keep me"
    assert not missing.parent.exists()


CONTRACTS = {
    "regular-file-renamed": _regular_is_renamed,
    "symlink-written-through": _symlink_written_through,
    "fifo-written-through": _fifo_written_through,
    "unwritable-one-line": _unwritable_is_one_line,
}


@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_writer_replaces_a_regular_file_by_renaming_a_temporary_one(writer, tmp_path):
    _regular_is_renamed(*WRITERS[writer], tmp_path)


@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_writer_writes_through_a_symlink_to_its_target(writer, tmp_path):
    _symlink_written_through(*WRITERS[writer], tmp_path)


@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_writer_writes_through_a_fifo_and_leaves_it_a_fifo(writer, tmp_path):
    _fifo_written_through(*WRITERS[writer], tmp_path)


@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_writer_refuses_an_unwritable_path_in_one_line_naming_it(writer, tmp_path):
    _unwritable_is_one_line(*WRITERS[writer], tmp_path)


def _in_place(path):
    """A naive writer: opens the path and writes (through a link, into a FIFO, over a read-only file as root)."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("image,lat_deg\nA.JPG,36.5\n")


def _replaces(path):
    """Another naive one: a temporary file renamed over whatever the path is (a link or a FIFO too)."""
    tmp = Path(f"{path}.part")
    tmp.write_text("image,lat_deg\nA.JPG,36.5\n", encoding="utf-8")
    os.replace(tmp, path)


def _check_naive(path):
    assert next(csv.DictReader(Path(path).open()))["lat_deg"] == "36.5"


@pytest.mark.parametrize(
    "naive,broken",
    [
        # root writes over permission bits, so the read-only file is written over
        (_in_place, {"regular-file-renamed", "unwritable-one-line"}),
        (_replaces, {"symlink-written-through", "fifo-written-through", "unwritable-one-line"}),
    ],
    ids=["in-place", "rename-over-anything"],
)
def test_the_writer_contracts_fail_the_naive_writers(naive, broken, tmp_path):
    """Each contract can fail: the two usual shortcuts break exactly the contracts they should."""
    failed = set()
    for name, contract in CONTRACTS.items():
        folder = tmp_path / name
        folder.mkdir()
        try:
            contract(".csv", naive, _check_naive, folder)
        except (Exception, pytest.fail.Exception):  # an assertion, or a check with nothing to read
            failed.add(name)
    if os.geteuid() != 0:  # a user who is not root is refused the read-only file by the system, in one line
        broken = broken - {"unwritable-one-line"} if naive is _in_place else broken
    assert failed == broken
