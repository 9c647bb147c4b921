"""DJI flight-log subtitles (.SRT): samples written here in DJI's two published layouts.

The samples follow the subtitle text DJI's aircraft write beside their videos (the bracketed
``[latitude: ..] [longitude: ..] [rel_alt: .. abs_alt: ..]`` form of the Mavic 3 / Mini / Air
series, and the older ``GPS(lon,lat,alt) BAROMETER:h`` form of the Phantom 4); they are written
in the test from that layout, not copied from a real file. Heights: ``abs_alt`` is EGM96 (above
mean sea level), made ellipsoidal with NGA's EGM96 (checked against pyproj where its grid is).
"""

from __future__ import annotations

import csv
import math

import pytest

from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.dji_srt import read_srt, write_srt_records

NEW = """1
00:00:00,000 --> 00:00:00,033
<font size="28">FrameCnt: 1, DiffTime: 33ms
2023-06-01 10:11:12.345
[iso: 100] [shutter: 1/640.0] [fnum: 2.8] [ev: 0] [ct: 5500] [color_md: default] [focal_len: 24.00] [latitude: 36.520000] [longitude: -84.210000] [rel_alt: 100.200 abs_alt: 412.600] </font>

2
00:00:00,033 --> 00:00:00,066
<font size="28">FrameCnt: 2, DiffTime: 33ms
2023-06-01 10:11:12.378
[iso: 100] [shutter: 1/640.0] [fnum: 2.8] [ev: 0] [focal_len: 24.00] [latitude: 36.52x] [longitude: -84.210010] [rel_alt: 100.300 abs_alt: 412.700] </font>

3
00:00:00,066 --> 00:00:00,100
<font size="28">FrameCnt: 3, DiffTime: 34ms
2023-06-01 10:11:12.412
[iso: 100] [focal_len: 24.00] [dzoom_ratio: 1.00] [latitude: 36.520020] [longitude: -84.210020] [rel_alt: 100.400 abs_alt: 412.800] [gb_yaw: 37.5 gb_pitch: -45.0 gb_roll: 0.0] </font>

4
00:00:00,1OO --> 00:00:00,133
<font size="28">FrameCnt: 4</font>
"""

OLD = """1
00:00:00,000 --> 00:00:01,000
HOME(-84.2100,36.5200) 2017.08.05 14:11:51
GPS(-84.2100,36.5200,412.6) BAROMETER:100.2
ISO:100 Shutter:60 EV:0 Fnum:2.2

2
00:00:01,000 --> 00:00:02,000
HOME(-84.2100,36.5200) 2017.08.05 14:11:52
BAROMETER:100.4
"""


def test_bracketed_form_keeps_good_blocks_and_reports_bad_lines(tmp_path):
    p = tmp_path / "DJI_0001.SRT"
    p.write_text(NEW)
    f = read_srt(p)
    assert [r.frame for r in f.records] == [1, 3]
    r1, r3 = f.records
    assert (r1.lat_deg, r1.lon_deg, r1.rel_alt_m, r1.abs_alt_m) == (36.52, -84.21, 100.2, 412.6)
    assert (r1.start_s, r1.end_s, r1.focal_len_mm, r1.datetime) == (0.0, 0.033, 24.0, "2023-06-01 10:11:12.345")
    assert (r3.gimbal_yaw_deg, r3.gimbal_pitch_deg, r3.gimbal_roll_deg) == (37.5, -45.0, 0.0)
    # block 2: its latitude is on the file's line 11; block 4's time code on line 20 (counted in NEW)
    assert f.errors == [
        (11, "latitude = '36.52x' is not a number"),
        (20, "time code '00:00:00,1OO --> 00:00:00,133' is not 'HH:MM:SS,mmm --> HH:MM:SS,mmm'"),
    ]
    assert "2 bad block(s) skipped" in f.summary()


def test_old_gps_form_and_heights_written_with_their_datums(tmp_path):
    p = tmp_path / "DJI_0002.SRT"
    p.write_text(OLD)
    f = read_srt(p)
    assert len(f) == 1 and f.errors == [(7, "no position: neither [latitude: ..] [longitude: ..] nor GPS(lon,lat,alt)")]
    r = f.records[0]
    assert (r.lon_deg, r.lat_deg, r.abs_alt_m, r.rel_alt_m) == (-84.21, 36.52, 412.6, 100.2)
    out = tmp_path / "flight.csv"
    assert write_srt_records(out, f) == 1
    row = next(csv.DictReader(out.open()))
    # h = H + N: N from the bundled EGM96 grid, which agrees with PROJ's full grid to < 1 mm
    # inside its crops (assets/README.md); -31.0 m is NGA's EGM96 value near Jacksboro (within 0.5 m)
    n = float(egm96_undulation(math.radians(36.52), math.radians(-84.21)))
    assert n == pytest.approx(-31.0, abs=0.5)
    assert float(row["ac_h_m"]) == pytest.approx(412.6 + n, abs=1e-9)
    assert row["h_datum"] == "ellipsoid (WGS 84)" and row["abs_alt_datum"].startswith("EGM96")
    assert row["rel_alt_datum"] == "above the take-off point" and row["gimbal_yaw_deg"] == ""


def test_unreadable_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_srt(tmp_path / "none.SRT")
    bad = tmp_path / "bin.SRT"
    bad.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ValueError, match=r"bin\.SRT: not a text SRT file"):
        read_srt(bad)
    empty = tmp_path / "e.SRT"
    empty.write_text("1\n00:00:00,000 --> 00:00:01,000\nhello\n")
    with pytest.raises(ValueError, match=r"e\.SRT: no readable DJI SRT block \(line 1: no position"):
        read_srt(empty)


def test_geoloc_replay_reads_an_srt_as_a_flight(tmp_path, capsys):
    from geoloc.cli import main

    p = tmp_path / "DJI_0001.SRT"
    p.write_text(NEW)
    out = tmp_path / "flight.csv"
    assert main(["replay", str(p), "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "DJI_0001.SRT line 11: latitude = '36.52x' is not a number: skipped" in cap.err
    assert "2 SRT record(s)" in cap.out
    rows = list(csv.DictReader(out.open()))
    assert [r["frame"] for r in rows] == ["1", "3"] and rows[1]["gimbal_pitch_deg"] == "-45.0"


def test_time_codes_no_fix_lines_and_the_summary_span(tmp_path):
    """Time codes with hours, minutes and a one-digit millisecond field (SubRip: HH:MM:SS,mmm; "4"
    is 400 ms), a block at 0, 0 reported on its position's line in either form, the summary's span
    from the first block's start to the last one's end (worked by hand)."""
    p = tmp_path / "DJI_0003.SRT"
    p.write_text(
        "1\n01:02:03,4 --> 01:02:04,050\n[latitude: 36.52] [longitude: -84.21] [abs_alt: 412.6]\n\n"
        "2\n01:02:04,050 --> 01:02:05,100\n[iso: 100]\n[latitude: 0.0] [longitude: 0.0]\n\n"
        "3\n01:02:05,100 --> 01:02:06,150\n[latitude: 36.53] [longitude: -84.22]\n\n"
        "4\n01:02:06,150 --> 01:02:07,200\nHOME(0,0)\nGPS(0.0,0.0,12.0) BAROMETER:1.0\n\n"
        "5\n01:02:07,200 --> 01:02:08,250\n[latitude: 36.54] [longitude: -84.23]\n\n"
    )
    f = read_srt(p)
    assert [(r.start_s, r.end_s) for r in f.records] == [(3723.4, 3724.05), (3725.1, 3726.15), (3727.2, 3728.25)]
    assert f.errors == [(8, "latitude, longitude = 0, 0: no GPS fix"), (17, "latitude, longitude = 0, 0: no GPS fix")]
    assert "DJI_0003.SRT: 3 SRT record(s) (bracketed form), 3723.400-3728.250 s of video" in f.summary()
    from geoloc.io.dji_srt import SrtFlight

    assert SrtFlight("none.SRT", [], []).summary() == "none.SRT: 0 SRT record(s) (no form)"
