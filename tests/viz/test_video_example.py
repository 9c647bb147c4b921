"""The bundled example flight's video: rendered frames beside the KLV stream.

``assets/klv/example_flight.ts`` (``tools/make_klv_example.py --ts``) holds an H.264 video
rendered by geoloc from the *true* pose, frame i at packet i's time stamp, and the same KLV
packets as ``assets/klv/example_flight.klv``. The planted faults are known from the generator
(``VIDEO_FAULTS``: frames 40-79 show the scene 1.5 s ahead of their metadata; ``FAULTS``:
packets 100-109 carry a heading 2.5 deg too large). Oracles here:

* the container read by an independent PyAV loop (demux and decode, no geoloc code): the frame
  nearest each packet's PTS, hashed, against the frame the viewer's scenario shows for it;
* the KLV bytes of the file's data stream, against the raw ``.klv`` file;
* the planted offset (1.5 s) and heading bias (2.5 deg), and the surveyed targets
  (``assets/klv/example_flight_targets.csv``), with distances on the ground from pyproj's geodesic;
* ``geoloc log``'s recording read back with rerun's own ``RrdReader`` (images against PyAV's
  frames, pinholes against klvdata's fields of view), and ``geoloc view --export --pixel``'s page
  against ``geoloc locate`` and viser's recording decoded message by message.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
TS = ROOT / "assets" / "klv" / "example_flight.ts"
KLV = ROOT / "assets" / "klv" / "example_flight.klv"
TARGETS = ROOT / "assets" / "klv" / "example_flight_targets.csv"

#: The planted faults (tools/make_klv_example.py): the video 1.5 s ahead in frames 40-79; the
#: heading 2.5 deg too large in packets 100-109. Written out here, not imported, as the oracle.
VIDEO_AHEAD = (40, 79, 1.5)
HEADING_BIAS = (100, 109, 2.5)
#: Frames with no fault of the KLV (FAULTS) nor of the video (VIDEO_FAULTS): 40-79 timing, 100-109
#: heading, 150 corrupted, 200-204 datum, 250-256 stale, 275 no angles.
CLEAN = (0, 17, 33, 90, 120, 170, 230, 280, 299)


def _md5(a) -> str:
    return hashlib.md5(np.ascontiguousarray(a).tobytes()).hexdigest()


@pytest.fixture(scope="module")
def decoded():
    """An independent read of the file with PyAV: video frame PTS and hashes, KLV packets and PTS."""
    import av

    with av.open(str(TS)) as c:
        v = c.streams.video[0]
        info = (v.codec_context.name, v.codec_context.width, v.codec_context.height, float(v.time_base))
        frames = [(f.pts, _md5(f.to_ndarray(format="rgb24"))) for f in c.decode(v)]
    with av.open(str(TS)) as c:
        d = c.streams.data[0]
        klv = [(p.pts, bytes(p)) for p in c.demux(d) if p.size]
    return info, frames, klv


@pytest.fixture(scope="module")
def flight():
    from geoloc_viz.flight_model import default_flight_scenario

    return default_flight_scenario()


def _record(scn, packet: int) -> int:
    return [str(info.label) for info, _ in scn.records].index(f"packet {packet}")


def test_bundled_ts_is_h264_video_beside_the_same_klv_stream(decoded):
    (codec, w, h, tb), frames, klv = decoded
    assert codec == "h264" and (w, h) == (640, 360) and tb == 1 / 90000
    assert len(frames) == 300 and len(klv) == 300
    # the data stream carries the raw file's packets, byte for byte, in order, on a 1 s clock
    assert b"".join(b for _, b in klv) == KLV.read_bytes()
    assert [p for p, _ in klv] == [90000 * i for i in range(300)]
    assert [p for p, _ in frames] == [90000 * i for i in range(300)]
    assert len({m for _, m in frames}) == 300  # every frame its own picture
    assert TS.stat().st_size < 4e6  # small enough to bundle


def test_the_frame_drawn_for_each_packet_is_the_nearest_by_pts(decoded, flight):
    from geoloc_viz import picture_model as pm

    _, frames, klv = decoded
    fpts = np.array([p for p, _ in frames], float)
    hashes = [m for _, m in frames]
    n = 0
    for idx, (info, _) in enumerate(flight.records):
        packet = int(str(info.label).split()[-1])
        want = hashes[int(np.argmin(np.abs(fpts - klv[packet][0])))]  # the nearest PTS, PyAV's own read
        k = pm.image_index(flight, idx)
        assert _md5(flight.images.image(k)) == want, info.label
        n += 1
    assert n == 298  # 300 packets less the corrupted one (150) and the one without angles (275)


def test_fitting_the_time_offset_on_the_timing_fault_recovers_it():
    from geoloc_viz.flight_model import read_targets
    from geoloc.workflows.klv_replay import replay_klv
    from geoloc.workflows.video_sync import fit_klv_time_offset
    from geoloc.io.images import open_images

    pts = [(la, lo, h) for _, la, lo, h in read_targets(TARGETS)]
    images, rep = open_images(TS), replay_klv(TS)
    a, b, d = VIDEO_AHEAD
    fit = fit_klv_time_offset(TS, pts, range(a, b + 1), replay=rep, images=images)
    # video ahead by d: the frame at PTS p shows metadata time p + d, i.e. time_offset_s = -d. The
    # crosses' centres in the H.264 frames scatter 0.3-0.4 px; the targets' image moves about 3 px/s
    # (4.9 px rms at offset 0), so each mark pins the offset to ~0.1 s and 200 marks to ~0.01 s: 0.05 s
    assert fit.time_offset_s == pytest.approx(-d, abs=0.05), str(fit)
    assert fit.rms_px < 1.0 < 3.0 < fit.rms_at_zero_px, str(fit)
    # the fault-free frames before it: no offset (same tolerance)
    clean = fit_klv_time_offset(TS, pts, range(10, a), replay=rep, images=images)
    assert clean.time_offset_s == pytest.approx(0.0, abs=0.05) and clean.rms_px < 1.0, str(clean)
    # applying the fitted offset: the stream's named parameter, on the metadata clock
    shifted = images.with_time_offset(fit.time_offset_s)
    assert np.allclose(shifted.times_s, images.pts_s - fit.time_offset_s)


def _ground_sample_m(scn, inputs, sensor, r, c, geod):
    """The larger of the ground distances between pixel (r, c)'s hit and its neighbours' (r+1, c), (r, c+1)."""
    from geoloc_viz import picture_model as pm

    p0 = pm.locate_pixel(scn, inputs, sensor, r, c)
    out = []
    for dr, dc in ((1, 0), (0, 1)):
        p1 = pm.locate_pixel(scn, inputs, sensor, r + dr, c + dc)
        out.append(geod.inv(p0.lon_deg(), p0.lat_deg(), p1.lon_deg(), p1.lat_deg())[2])
    return max(out)


@pytest.mark.parametrize("packet", CLEAN)
def test_a_painted_cross_clicked_in_a_clean_frame_lands_on_its_survey(flight, packet):
    from pyproj import Geod

    from geoloc_viz import picture_model as pm
    from geoloc_viz.flight_model import read_targets
    from geoloc.workflows.render import find_marks

    import dataclasses

    geod = Geod(ellps="WGS84")
    idx = _record(flight, packet)
    # the exact DEM walk (the "method" dropdown): the viewer's default, [L23] bisection, stops within
    # its eps_h of the terrain, which slides the hit up to eps_h / tan(depression) along the ground
    inputs = dataclasses.replace(flight.records[idx][1], method="exact")
    img = flight.images.image(pm.image_index(flight, idx))
    sensor = pm.frame_sensor(flight, idx, *img.shape[:2])
    found, _ = find_marks(img)
    targets = read_targets(TARGETS)
    assert len(found) == len(targets) == 5
    for r, c in found:
        p = pm.locate_pixel(flight, inputs, sensor, r, c)  # what a click on that pixel gives
        assert p.ok
        dist = [geod.inv(p.lon_deg(), p.lat_deg(), lo, la)[2] for _, la, lo, _ in targets]
        k = int(np.argmin(dist))
        gsd = _ground_sample_m(flight, inputs, sensor, r, c, geod)
        # the bound: 2 ground samples (0.6-2.3 m here, by zoom step). The frame is rendered
        # through the same sensor model on the same DEM, so what remains is the KLV's quantisation
        # and the cross's centroid in a compressed frame (under 0.8 px: a cross's arms foreshorten
        # differently and H.264 smears its chroma)
        assert dist[k] < 2 * gsd, (packet, targets[k][0], dist[k], gsd)


def test_the_heading_bias_shows_in_the_frames_and_is_reported(flight):
    import dataclasses

    from geoloc_viz import picture_model as pm

    a, b, bias = HEADING_BIAS
    for packet in (a - 2, *range(a, b + 1), b + 2):
        idx = _record(flight, packet)
        inputs = flight.records[idx][1]
        img = flight.images.image(pm.image_index(flight, idx))
        sensor = pm.frame_sensor(flight, idx, *img.shape[:2])
        f = pm.found_marks(flight, img, pm.image_marks(flight, idx, sensor, inputs), sensor, inputs)
        text = pm.found_markdown(f)
        if a <= packet <= b:
            # the crosses part from their reprojections: tens of pixels (a 2.5 deg turn about the
            # vertical at a 44 deg depression is ~1.8 deg of line of sight, 90 px/deg at 7 deg hfov)
            assert not f.agree and np.hypot(*f.offset_px) > 50 and "disagree" in text, (packet, text)
            assert 1.5 < f.angle_deg < 2.5, (packet, f.angle_deg)
            # the planted bias taken out of the heading: the marks meet their reprojections again
            fixed = dataclasses.replace(inputs, heading_deg=inputs.heading_deg - bias)
            g = pm.found_marks(flight, img, pm.image_marks(flight, idx, sensor, fixed), sensor, fixed)
            assert g.agree, (packet, g.offset_px)
        else:
            assert f.agree and "agree" in text, (packet, text)


def test_the_panel_reports_the_painted_marks(flight):
    from test_viz_picture import make_app

    server, app, layer = make_app(flight)
    try:
        app.load_record(_record(flight, 105), move_camera=False)
        assert "disagree" in layer.md_found.content and "5 found for 5 targets" in layer.md_found.content
        app.load_record(_record(flight, 90), move_camera=False)
        assert "**agree**" in layer.md_found.content
    finally:
        server.stop()


def test_bundled_photo_is_rendered_with_the_targets_on_their_pixels():
    import csv

    from PIL import Image

    from geoloc.workflows.render import find_marks

    photo = ROOT / "assets" / "photos" / "DJI_0001.JPG"
    assert photo.stat().st_size < 1e6
    img = np.asarray(Image.open(photo).convert("RGB"))
    assert img.shape == (600, 800, 3) and img.std() > 3  # a picture, not one flat colour
    with open(ROOT / "assets" / "photos" / "targets.csv", newline="") as f:
        px = np.array([(float(t["row"]), float(t["col"])) for t in csv.DictReader(f)])
    found, _ = find_marks(img)
    assert len(found) == 5
    d = np.hypot(*(found[:, None, :] - px[None]).transpose(2, 0, 1)).min(axis=0)
    # painted from the true tags at each target's truth: the JPEG (quality 85, chroma at half
    # resolution) moves a 12 x 3 px cross's centroid by tenths of a pixel: 1 px
    assert d.max() < 1.0, d


def test_geoloc_log_puts_each_frame_in_its_pinhole(tmp_path, monkeypatch, decoded):
    # `geoloc log FILE.ts` logs each packet's frame with its pinhole at the camera
    # entity, so rerun's 3D view draws it in the frustum; read back with rerun's own RrdReader
    import io

    import klvdata
    from PIL import Image
    from rerun.chunk import RrdReader

    from geoloc.cli import main

    monkeypatch.setenv("HOME", str(tmp_path))  # rerun writes under ~/.config
    out = tmp_path / "klv.rrd"
    assert main(["log", str(TS), "--out", str(out)]) == 0
    blobs, pins = {}, {}
    for ch in RrdReader(str(out)).stream():
        if not ch.entity_path.endswith("/cam"):
            continue
        b = ch.to_record_batch()
        if "packet" not in b.schema.names:
            continue
        pk = b.column("packet").to_pylist()
        if "EncodedImage:blob" in b.schema.names:
            for k, v in zip(pk, b.column("EncodedImage:blob").to_pylist()):
                blobs[k] = bytes(v[0])
        if "Pinhole:image_from_camera" in b.schema.names:
            for k, m, r in zip(
                pk, b.column("Pinhole:image_from_camera").to_pylist(), b.column("Pinhole:resolution").to_pylist()
            ):
                pins[k] = (np.array(m[0]), r[0])
    good = sorted(set(range(300)) - {150})  # the corrupted packet is no step
    assert sorted(blobs) == good and sorted(pins) == good
    # the frame of packet k is the video's frame at packet k's PTS (frame k), JPEG-encoded: compare
    # with PyAV's own decode (JPEG quality 85 moves pixels by a few grey levels on average)
    import av

    with av.open(str(TS)) as c:
        want = {
            f.pts // 90000: f.to_ndarray(format="rgb24")
            for f in c.decode(c.streams.video[0])
            if f.pts // 90000 in (0, 105, 299)
        }
    for k, ref in want.items():
        got = np.asarray(Image.open(io.BytesIO(blobs[k])).convert("RGB"))
        assert got.shape == ref.shape and np.abs(got.astype(int) - ref).mean() < 3.0, k
    # each pinhole from the packet's own fields of view (klvdata's decoding of tags 16 and 17) at the
    # video's 640 x 360: f = (w / 2) / tan(hfov / 2), principal point at the centre; rerun stores
    # float32 (relative 6e-8), the KLV's 16-bit FOV quantisation enters both sides alike
    values = {i: v for i, v in enumerate(_klvdata_values(klvdata, KLV.read_bytes()))}
    for k in (0, 105, 250, 299):
        m, res = pins[k]
        hfov, vfov = math.radians(float(values[k][16])), math.radians(float(values[k][17]))
        assert res == [640.0, 360.0]
        assert m[0] == pytest.approx(320 / math.tan(hfov / 2), rel=1e-6)
        assert m[4] == pytest.approx(180 / math.tan(vfov / 2), rel=1e-6)
        assert (m[6], m[7], m[8]) == (320.0, 180.0, 1.0)  # column-major: cx, cy, 1


def _klvdata_values(klvdata, data: bytes) -> list:
    """klvdata's decoding of every packet (tag -> value string), the corrupted one kept in place."""
    out = []
    for p in klvdata.StreamParser(data):
        try:
            out.append({tag: v[3] for tag, v in p.MetadataList().items()})
        except Exception:  # the corrupted packet (its checksum): a placeholder keeps the numbering
            out.append({})
    return out


def test_view_export_carries_the_picture_and_the_clicked_points(tmp_path, monkeypatch, flight):
    # `geoloc view --export FILE.html --pixel ROW,COL`: the page holds the frame
    # (with its marks) and each picked pixel's numbers, equal to `geoloc locate`'s; the scene holds
    # the frame's image node and the pick's ray, read back from viser's own recording
    import base64
    import io
    import re

    from PIL import Image

    from geoloc.cli import main
    from geoloc_viz import picture_model as pm
    from test_viz_picture import locate_cli
    from test_viz_scene import _decode_recording

    monkeypatch.setenv("HOME", str(tmp_path))
    out = tmp_path / "packet90.html"
    picks = [(273.0, 310.0), (100.0, 500.0)]
    assert (
        main(
            ["view", "--export", str(out), "--record", "packet 90"]
            + sum((["--pixel", f"{r:g},{c:g}"] for r, c in picks), [])
        )
        == 0
    )
    page = out.read_text()
    m = re.search(
        r'id="geoloc-export-picture"><img alt="frame image" data-rows="(\d+)" data-cols="(\d+)"'
        r'[^>]*src="data:image/jpeg;base64,([^"]+)"',
        page,
    )
    assert m and (int(m.group(1)), int(m.group(2))) == (360, 640)
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(m.group(3)))).convert("RGB"))
    assert img.shape[1] == 560 and img.std() > 3  # the panel's width; a picture, not a blank
    lats = [float(x) for x in re.findall(r"latitude <b>([-0-9.]+)</b>", page)]
    lons = [float(x) for x in re.findall(r"longitude <b>([-0-9.]+)</b>", page)]
    assert len(lats) == len(lons) == 2
    idx = _record(flight, 90)
    inputs = flight.records[idx][1]
    sensor = pm.frame_sensor(flight, idx, 360, 640)
    for (r, c), la, lo in zip(picks, lats, lons):
        ref = locate_cli(flight, sensor, inputs, r, c, tmp_path)
        # the page prints 8 decimals: 5e-9 deg of rounding
        assert la == pytest.approx(ref["lat_deg"], abs=1e-7) and lo == pytest.approx(ref["lon_deg"], abs=1e-7)
    b64 = re.search(r'window\.__VISER_EMBED_DATA__="([^"]*)"', page).group(1)
    names = {msg.get("name") for _, msg in _decode_recording(base64.b64decode(b64))["messages"]}
    assert "/enu/picture/frame" in names and "/enu/picture/ray" in names, sorted(n for n in names if n)


def test_the_timing_search_runs_once_per_stream_and_records_not_per_scenario(monkeypatch):
    # every tab of a flight built its own scenario and searched the whole video again (5.7 s of
    # CPU for this flight): two scenarios read from one file now share the answer, and a scenario
    # whose records differ (one record's reported position moved) is searched again
    import dataclasses

    from geoloc_viz import picture_model as pm
    from geoloc_viz.flight_model import default_flight_scenario

    calls = []
    monkeypatch.setattr(pm, "_TIMING_CACHE", {})
    monkeypatch.setattr(pm, "video_timing_faults", lambda scn, exclude=None, **kw: calls.append(scn) or ["run"])
    a, b = default_flight_scenario(), default_flight_scenario()
    assert a.records is not b.records
    assert pm.cached_video_timing_faults(a) == ["run"] and pm.cached_video_timing_faults(b) == ["run"]
    assert calls == [a]
    info, inp = b.records[5]
    b.records[5] = (dataclasses.replace(info, paper_lat_deg=info.paper_lat_deg + 1e-4), inp)
    pm.cached_video_timing_faults(b)
    assert calls == [a, b]
    # a search stopped midway is not kept
    c = default_flight_scenario()
    c.records[7] = (dataclasses.replace(c.records[7][0], paper_lon_deg=0.0), c.records[7][1])
    assert pm.cached_video_timing_faults(c, should_stop=lambda: True) == []
    pm.cached_video_timing_faults(c)
    assert calls == [a, b, c, c]
