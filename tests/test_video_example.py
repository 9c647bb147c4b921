"""The bundled example flight's video (issue 28 item 5): rendered frames beside the KLV stream.

``assets/klv/example_flight.ts`` (``tools/make_klv_example.py --ts``) holds an H.264 video
rendered by geoloc from the *true* pose, frame i at packet i's time stamp, and the same KLV
packets as ``assets/klv/example_flight.klv``. The planted faults are known from the generator
(``VIDEO_FAULTS``: frames 40-79 show the scene 1.5 s ahead of their metadata; ``FAULTS``:
packets 100-109 carry a heading 2.5 deg too large). Oracles here:

* the container read by an independent PyAV loop (demux and decode, no geoloc code): the frame
  nearest each packet's PTS, hashed, against the frame the viewer's scenario shows for it;
* the KLV bytes of the file's data stream, against the raw ``.klv`` file;
* the planted offset (1.5 s) and heading bias (2.5 deg), and the surveyed targets
  (``assets/klv/example_flight_targets.csv``), with distances on the ground from pyproj's geodesic.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
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
    from geoloc.viz.flight_model import default_flight_scenario

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
    from geoloc.viz import picture_model as pm

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
    from geoloc.viz.flight_model import read_targets
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
    from geoloc.viz import picture_model as pm

    p0 = pm.locate_pixel(scn, inputs, sensor, r, c)
    out = []
    for dr, dc in ((1, 0), (0, 1)):
        p1 = pm.locate_pixel(scn, inputs, sensor, r + dr, c + dc)
        out.append(geod.inv(p0.lon_deg(), p0.lat_deg(), p1.lon_deg(), p1.lat_deg())[2])
    return max(out)


@pytest.mark.parametrize("packet", CLEAN)
def test_a_painted_cross_clicked_in_a_clean_frame_lands_on_its_survey(flight, packet):
    from pyproj import Geod

    from geoloc.viz import picture_model as pm
    from geoloc.viz.flight_model import read_targets
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

    from geoloc.viz import picture_model as pm

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
    from tests.test_viz_picture import make_app

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
