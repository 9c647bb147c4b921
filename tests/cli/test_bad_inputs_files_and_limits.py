"""Bad input files and limits: each test the bad input, the message or status expected
(naming the file, the field, the value) and the good inputs still served. Each failed before
its mend (the "before" comments quote what was printed)."""

from __future__ import annotations

import csv
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import asset_path
from geoloc.cli import main

ROOT = Path(__file__).resolve().parents[2]
TURRET = asset_path("sensors", "eo_turret.toml")
SRTM = asset_path("dem", "srtm_jacksboro.tif")
KLV_TS = asset_path("klv", "example_flight.ts")
KLV_RAW = asset_path("klv", "example_flight.klv")
PHOTO = asset_path("photos", "DJI_0001.JPG")
TARGETS = asset_path("photos", "targets.csv")
LOCATE = [
    "locate",
    "--lat-deg",
    "36.6",
    "--lon-deg",
    "-84.25",
    "--h-m",
    "2500",
    "--heading-deg",
    "45",
    "--angle",
    "azimuth=90",
    "--angle",
    "elevation=-30",
    "--target-h-m",
    "300",
]


# ------------------------------------------------------------------ a. a sensor file without [lens]
def test_sensor_file_without_lens_says_lens_is_missing(tmp_path, capsys):
    text = TURRET.read_text()
    no_lens = re.sub(r"\[lens\].*?(?=\n\[gimbal\])", "", text, flags=re.S)
    assert "[lens]" not in no_lens and "[gimbal]" in no_lens
    p = tmp_path / "no_lens.toml"
    p.write_text(no_lens)
    for verb in (
        ["locate", "--sensor", str(p)] + LOCATE[1:],
        ["replay", str(asset_path("records", "eo_turret_flight.csv")), "--sensor", str(p), "--target-h-m", "300"],
    ):
        assert main(verb) == 2
        err = capsys.readouterr().err
        # before: "unknown key(s) ['boresight', 'gimbal', 'lever_arm', 'mount']; allowed: [...focal_length_px...]"
        assert f"{p}: missing table [lens]" in err, err
        assert "[gimbal], [mount], [boresight], [lever_arm]" in err and "unknown key" not in err
    # the file with its lens still locates
    assert main(["locate", "--sensor", str(TURRET)] + LOCATE[1:] + ["--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "ok"


# ------------------------------------------------------------------ b. a TS with no KLV stream
@pytest.fixture(scope="module")
def ts_without_klv(tmp_path_factory):
    """An MPEG-TS of 30 grey MPEG-2 frames and no data stream, written by PyAV."""
    import av

    p = tmp_path_factory.mktemp("noklv") / "video_only.ts"
    with av.open(str(p), "w", format="mpegts") as out:
        vs = out.add_stream("mpeg2video", rate=30)
        vs.width, vs.height, vs.pix_fmt = 64, 48, "yuv420p"
        for i in range(30):
            fr = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 8 * i, np.uint8), format="rgb24")
            fr.pts = i
            for pkt in vs.encode(fr):
                out.mux(pkt)
        for pkt in vs.encode():
            out.mux(pkt)
    with av.open(str(p)) as c:  # an independent look: PyAV sees one video stream and no data stream
        assert [s.type for s in c.streams] == ["video"]
    return p


@pytest.mark.parametrize("verb", ["replay", "dump", "fix"])
def test_ts_without_klv_names_the_file(ts_without_klv, tmp_path, verb, capsys):
    args = {
        "replay": ["replay", str(ts_without_klv)],
        "dump": ["klv", "dump", str(ts_without_klv)],
        "fix": ["klv", "fix", str(ts_without_klv), "--out", str(tmp_path / "fixed.ts")],
    }[verb]
    assert main(args) == 2
    err = capsys.readouterr().err
    # before: "the container has no data (KLV) stream" without the file's name
    assert f"{ts_without_klv}: the container has no data (KLV) stream (its streams: video (mpeg2video))" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "fixed.ts").exists()


# ------------------------------------------------------------------ c. a lying extension
def _ts_sync_ok(path) -> bool:
    """The test's own look at the bytes (ISO/IEC 13818-1: 0x47 every 188 bytes)."""
    b = Path(path).read_bytes()
    return len(b) % 188 == 0 and all(b[i] == 0x47 for i in range(0, len(b), 188))


@pytest.mark.parametrize("suffix", [".klv", ".dat", ""])
def test_ts_under_a_lying_name_is_read_as_mpegts(tmp_path, suffix, capsys):
    lying = tmp_path / f"flight{suffix}"
    lying.write_bytes(KLV_TS.read_bytes())
    assert _ts_sync_ok(lying)
    out_true, out_lying = tmp_path / "true.csv", tmp_path / "lying.csv"
    assert main(["replay", str(KLV_TS), "--out", str(out_true)]) == 0
    capsys.readouterr()
    # before (.klv): 301 lines of "no checksum item"; (.dat) read as a records CSV
    assert main(["replay", str(lying), "--out", str(out_lying)]) == 0
    err = capsys.readouterr().err
    assert "no checksum item" not in err
    a, b = list(csv.DictReader(open(out_true))), list(csv.DictReader(open(out_lying)))
    assert len(a) == len(b) > 250
    for col in ("packet", "frame_center_lat_deg", "lat_deg", "lon_deg", "h_m", "status"):
        if col in a[0]:
            assert [r[col] for r in a] == [r[col] for r in b], col
    # klv dump: the same packets as the true name's
    assert main(["klv", "dump", str(KLV_TS)]) in (0, 1)
    ref = capsys.readouterr().out.splitlines()
    assert main(["klv", "dump", str(lying)]) in (0, 1)
    got = capsys.readouterr()
    assert got.out.splitlines() == ref and len(ref) > 250 and "no checksum item" not in got.err


def test_sniff_klv_file_kinds(tmp_path):
    from geoloc.io.klv import is_container_file, sniff_klv_file

    assert sniff_klv_file(KLV_TS) == "mpegts" and sniff_klv_file(KLV_RAW) == "klv"
    # the UAS LS key of MISB ST 0601 (06 0E 2B 34 ...), read by the test from the raw file's first bytes
    assert KLV_RAW.read_bytes()[:4] == bytes.fromhex("060e2b34")
    raw_as_ts = tmp_path / "raw.ts"
    raw_as_ts.write_bytes(KLV_RAW.read_bytes())
    assert not is_container_file(raw_as_ts)  # a raw KLV named .ts is read as the raw KLV it is
    assert sniff_klv_file(PHOTO) is None  # a JPEG is neither (FF D8)
    m2ts = tmp_path / "x.m2ts.bin"  # Blu-ray's 192-byte packets: a 4-byte time code, then 0x47
    m2ts.write_bytes(b"".join(b"\0\0\0\0" + b"\x47" + bytes(187) for _ in range(6)))
    assert sniff_klv_file(m2ts) == "mpegts"


def test_raw_klv_named_ts_replays(tmp_path, capsys):
    p = tmp_path / "raw.ts"
    p.write_bytes(KLV_RAW.read_bytes())
    out = tmp_path / "o.csv"
    assert main(["replay", str(p), "--out", str(out)]) == 0
    assert len(list(csv.DictReader(open(out)))) > 250


# ------------------------------------------------------------------ d. view --record with no such label
def test_view_record_not_found_is_short(capsys):
    assert main(["view", "--records", str(KLV_RAW), "--record", "packet 9999", "--port", "0"]) == 2
    err = capsys.readouterr().err
    # before: all 299 labels
    assert len(err) < 400 and err.count("packet") < 10, err
    assert "record = 'packet 9999': not in example_flight.klv" in err
    assert "'packet 0' .. 'packet 299'" in err and "nearest: 'packet 299'" in err


def test_describe_labels():
    from geoloc.io.records import describe_labels

    labels = [f"T{i}-{j}" for i in range(1, 6) for j in range(1, 5)]
    text = describe_labels("T3-9", labels)
    assert text.startswith("20 records, 'T1-1' .. 'T5-4'") and "'T3-4'" in text.split("nearest:")[1]
    assert describe_labels("x", ["a", "b"]) == "2 records: 'a', 'b'"
    assert describe_labels("x", []) == "the file has no records"
    many = describe_labels("packet 12", [f"packet {i}" for i in range(300)])
    assert "nearest: 'packet 12', 'packet 11', 'packet 13'" in many and many.count("'packet") == 7


# ------------------------------------------------------------------ e. montecarlo bounds
def test_montecarlo_chunk_bounded_by_memory(capsys):
    from geoloc.analysis import montecarlo as mc

    avail = mc.available_memory_bytes()
    meminfo = Path("/proc/meminfo")
    if meminfo.exists():  # the figure the cap is made of, read here independently
        kb = int(next(x for x in meminfo.read_text().splitlines() if x.startswith("MemAvailable:")).split()[1])
        # MemAvailable moves while other processes run: within 20 % between two reads
        assert avail == pytest.approx(kb * 1024, rel=0.2)
    cap = mc.max_chunk()
    assert cap * mc.BYTES_PER_SAMPLE <= 0.5 * avail * 1.2 and cap >= mc.CHUNK // 10
    assert mc.max_chunk(8 << 30) == int(0.5 * (8 << 30)) // 2000
    # before: --chunk 1e8 was taken (as "1e8", not even parsed) and grew to 7.2 GB
    assert main(["montecarlo", "assets/scenarios/qiao2017_table1.toml", "--samples", "1e8", "--chunk", "1e8"]) == 2
    err = capsys.readouterr().err
    assert "--chunk = 100000000: a chunk that size needs about 200 GB" in err and "at most" in err, err
    with pytest.raises(ValueError, match=r"chunk = 100000000"):
        mc.run(None, 10, np.random.default_rng(0), chunk=10**8)


def test_montecarlo_samples_1e20_refused(capsys):
    # before: accepted
    assert main(["montecarlo", "assets/scenarios/qiao2017_table1.toml", "--samples", "1e20"]) == 2
    err = capsys.readouterr().err
    assert "--samples = 1e+20: more than 1e+12 samples is refused" in err, err
    # a good run, with a chunk in scientific notation, still runs
    assert (
        main(
            [
                "montecarlo",
                "assets/scenarios/qiao2017_table1.toml",
                "--samples",
                "3000",
                "--chunk",
                "1e3",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    assert "3000 located, 0 failed" in capsys.readouterr().out


# ------------------------------------------------------------------ f. ortho and OpenCV
def test_opencv_is_in_the_video_extra():
    # the core installs without it (docs/architecture.md, "Two packages"); geoloc[video] brings it
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert any(d.startswith("opencv-python-headless") for d in extras["video"]), extras["video"]


def test_ortho_without_opencv_writes_nothing(tmp_path, monkeypatch, capsys):
    import sys

    # a plain install without cv2 (before: ModuleNotFoundError after --out was written)
    monkeypatch.setitem(sys.modules, "cv2", None)
    out, ortho = tmp_path / "grid.tif", tmp_path / "ortho.tif"
    assert (
        main(
            [
                "ortho",
                "--photo",
                str(PHOTO),
                "--dem",
                str(SRTM),
                "--out",
                str(out),
                "--ortho-out",
                str(ortho),
                "--gsd-m",
                "2",
                "--step",
                "8",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--ortho-out (a photo's pixels) needs cv2" in err and "pip install 'geoloc[video]'" in err, err
    assert not out.exists() and not ortho.exists()


# ------------------------------------------------------------------ g. a drone kilometres up
def test_drone_photo_kilometres_up_is_warned(tmp_path, capsys):
    b = PHOTO.read_bytes()
    assert b'AbsoluteAltitude="+503.00"' in b and b'RelativeAltitude="+150.00"' in b
    up = tmp_path / PHOTO.name  # the same photo 3 km higher (same-length XMP values: the JPEG stays whole)
    up.write_bytes(
        b.replace(b'AbsoluteAltitude="+503.00"', b'AbsoluteAltitude="+3503.0"').replace(
            b'RelativeAltitude="+150.00"', b'RelativeAltitude="+3150.0"'
        )
    )
    out = tmp_path / "out.csv"
    assert main(["replay", str(up), "--targets", str(TARGETS), "--dem", str(SRTM), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "DJI_0001.JPG: warning: implausible for a drone: the camera is 3.2 km above the DEM under it" in err, err
    assert "RelativeAltitude (above the take-off point) is 3150.0 m" in err
    rows = list(csv.DictReader(open(out)))
    assert len(rows) == 5 and {r["status"] for r in rows} == {"ok"}  # warned, still located as read
    # the bundled photo (150 m up) gives no such warning
    assert main(["replay", str(PHOTO), "--targets", str(TARGETS), "--dem", str(SRTM)]) == 0
    assert "implausible for a drone" not in capsys.readouterr().err
