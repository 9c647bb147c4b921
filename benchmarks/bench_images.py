"""Speed and memory of the pictures: frame switching, an hour of video, a frame's ortho.

One command: ``python benchmarks/bench_images.py [--repeat 5] [--hour-s 3600] [--size 1280x720]``
(``--size``: the switch video's and the ortho frame's pixels, for a quick check; the targets are
720p's).

Everything is synthetic and generated at run time in a temporary folder (nothing is bundled):

* **switch** (target <= 150 ms for 720p): a 1280 x 720 H.264 MPEG-TS (30 fps, 300 frames, a key
  frame every 30, a moving pattern so no frame repeats) is opened with
  :class:`geoloc.io.images.VideoFrames` behind the bundled example flight (one frame per record);
  a switch is the picture layer's whole update for a new record (decode the frame, its sensor,
  the reprojected marks, the terrain horizon, the panel's PNG, the frustum's texture), timed on
  random records (a seek each: the worst case) and on the next record (playback). The decode alone
  is printed too, and the peer: OpenCV's ``cv2.VideoCapture`` seeking to the same frames
  (``CAP_PROP_POS_FRAMES``; an independent FFmpeg wrapper) in the same run;
* **hour** (RSS bounded): a one-hour, low-bitrate video (320 x 180, 10 fps: 36 000 frames, mostly
  still, libx264 ``ultrafast``) is written, opened, its PTS index built, and 400 frames spread over
  the hour decoded with a 64 MiB cache: RSS printed at the start, after opening and at the end,
  against a one-minute cut of the same video (open time and RSS), and the cache's bytes;
* **ortho** (target <= 1 s): a 1280 x 720 frame of the example flight orthorectified
  (:func:`geoloc.workflows.ortho.orthorectify`, what ``geoloc ortho --ortho-out`` runs) at the
  frame's own ground sample (1 m cells), occlusion test included, from a frame grid at step 8 (as
  the viewer's drape sizes it); peer: GDAL's warp of the same image with the frame's per-pixel
  latitude and longitude as geolocation arrays (``rasterio.warp.reproject``, no occlusion test,
  bilinear), onto the same grid, in the same run.

Medians of wall and CPU time (``_timing.timed``). The machine has 2 cores shared with other jobs:
wall times are inflated by the load (printed), CPU times less so.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import rss_mb, timed


def write_video(path, n, size, fps, gop, preset="medium", crf=28, pattern=True):
    """An H.264 MPEG-TS of ``n`` frames ``size`` (w, h) at ``fps``: a gradient with a moving bar (and
    the frame number's bits as blocks, so every frame differs)."""
    import av

    w, h = size
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([(xx * 255 // max(w - 1, 1)), (yy * 255 // max(h - 1, 1)), np.full_like(xx, 96)], -1).astype(
        np.uint8
    )
    with av.open(str(path), "w", format="mpegts") as out:
        vs = out.add_stream("libx264", rate=fps)
        vs.width, vs.height, vs.pix_fmt = w, h, "yuv420p"
        vs.gop_size = gop
        vs.options = {"preset": preset, "crf": str(crf), "bf": "0"}
        for i in range(n):
            img = base.copy()
            if pattern:
                x = (i * 7) % w
                img[:, x : x + max(w // 64, 2)] = 255
            bits = [(i >> b) & 1 for b in range(17)]
            s = max(h // 24, 2)
            for b, on in enumerate(bits):
                if on:
                    img[:s, b * s : (b + 1) * s] = (255, 0, 0)
            fr = av.VideoFrame.from_ndarray(img, format="rgb24")
            fr.pts = i
            fr.time_base = Fraction(1, fps)
            for p in vs.encode(fr):
                out.mux(p)
        for p in vs.encode():
            out.mux(p)


def bench_switch(tmp, repeat, size=(1280, 720)):
    import cv2

    from geoloc.io.images import open_images
    from geoloc_viz import image_layer
    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    path = Path(tmp) / "v720.ts"
    t = time.perf_counter()
    write_video(path, 300, size, 30, 30, preset="ultrafast")
    print(
        f"switch: wrote a {size[0]} x {size[1]} H.264 video, 300 frames, gop 30 ({path.stat().st_size / 1e6:.1f} MB) "
        f"in {time.perf_counter() - t:.1f} s"
    )
    scn = default_flight_scenario()
    scn.images = open_images(path)
    scn.image_index = np.arange(len(scn.records)) % len(scn.images)
    scn.record_times_s = None
    server = make_server(port=0)
    try:
        app = GeolocApp(server, scn, layers=(image_layer.attach,))
        layer = app.layers[0]
        rng = np.random.default_rng(7)
        n = len(scn.records)

        def switch_to(k):
            scn.record_index = int(k)  # what load_record sets; the layer's own redraw is timed
            layer.update()

        order = iter(rng.permutation(n).tolist() * 4)
        switch_to(next(order))
        w_r, c_r, _ = timed(lambda: switch_to(next(order)), max(repeat, 15))
        cur = [0]

        def step():
            cur[0] = (cur[0] + 1) % n
            switch_to(cur[0])

        switch_to(0)
        w_s, c_s, _ = timed(step, max(repeat, 15))
        w_full, c_full, _ = timed(lambda: app.load_record(int(next(order)), move_camera=False), max(repeat, 5))
    finally:
        server.stop()
    src = open_images(path, cache_bytes=0)
    ks = iter(np.random.default_rng(8).integers(0, len(src), 200).tolist())
    w_d, c_d, _ = timed(lambda: src.image(next(ks)), max(repeat, 15))
    cap = cv2.VideoCapture(str(path))
    ks2 = iter(np.random.default_rng(8).integers(0, len(src), 200).tolist())

    def cv_seek():
        cap.set(cv2.CAP_PROP_POS_FRAMES, next(ks2))
        ok, _ = cap.read()
        assert ok

    w_cv, c_cv, _ = timed(cv_seek, max(repeat, 15))
    cap.release()
    print(
        f"switch, random record (a seek each), the picture layer's update: median wall {w_r * 1e3:.0f} ms, "
        f"CPU {c_r * 1e3:.0f} ms (target <= 150 ms)"
    )
    print(f"switch, next record (playback): median wall {w_s * 1e3:.0f} ms, CPU {c_s * 1e3:.0f} ms")
    print(
        f"  whole load_record (the session's redraw of the record + the layer): median wall "
        f"{w_full * 1e3:.0f} ms, CPU {c_full * 1e3:.0f} ms"
    )
    print(
        f"  decode alone, random frame, no cache (VideoFrames.image): median wall {w_d * 1e3:.1f} ms, "
        f"CPU {c_d * 1e3:.1f} ms; peer cv2.VideoCapture seek + read: wall {w_cv * 1e3:.1f} ms, "
        f"CPU {c_cv * 1e3:.1f} ms; ratio peer / ours {w_cv / w_d:.2f}x (wall)"
    )


def bench_hour(tmp, hour_s):
    import av

    from geoloc.io.images import open_images

    r0 = rss_mb()
    fps, size = 10, (320, 180)
    n = int(hour_s * fps)
    long, short = Path(tmp) / "hour.ts", Path(tmp) / "minute.ts"
    t = time.perf_counter()
    write_video(long, n, size, fps, 250, preset="ultrafast", crf=35)
    write_video(short, 60 * fps, size, fps, 250, preset="ultrafast", crf=35)
    print(
        f"hour: wrote {n} frames {size[0]} x {size[1]} at {fps} fps ({n / fps / 3600:.2f} h, "
        f"{long.stat().st_size / 1e6:.1f} MB) and a one-minute cut in {time.perf_counter() - t:.0f} s"
    )
    with av.open(str(long)) as c:  # the peer for the index: PyAV's own demux of every packet
        t = time.perf_counter()
        n_pk = sum(1 for p in c.demux(c.streams.video[0]) if p.size)
        t_demux = time.perf_counter() - t
    r1 = rss_mb()

    def open_and_index(p):
        s = open_images(p, cache_bytes=64 * 2**20)
        len(s)  # builds the PTS index (packets demuxed, no pixel decoded)
        return s

    w_min, c_min, _ = timed(lambda: open_and_index(short), 3)
    w_hr, c_hr, src = timed(lambda: open_and_index(long), 3)
    r2 = rss_mb()
    ks = np.linspace(0, len(src) - 1, 400).astype(int)
    t = time.perf_counter()
    peak = r2
    for i, k in enumerate(ks):
        src.image(int(k))
        if i % 50 == 0:
            peak = max(peak, rss_mb())
    t_dec = time.perf_counter() - t
    r3 = rss_mb()
    print(
        f"hour: open + PTS index, one hour ({len(src)} frames): median wall {w_hr:.3f} s, CPU {c_hr:.3f} s; "
        f"one minute: wall {w_min:.3f} s, CPU {c_min:.3f} s; peer PyAV demux of the hour's {n_pk} packets "
        f"{t_demux:.3f} s"
    )
    print(
        f"hour: 400 frames spread over the hour decoded in {t_dec:.1f} s ({t_dec / 400 * 1e3:.0f} ms each, "
        f"{src.frames_decoded} frames decoded), cache {src.cache_nbytes / 2**20:.1f} MiB "
        f"(bound {src.cache_bytes / 2**20:.0f} MiB)"
    )
    print(
        f"hour: RSS at start {r0:.0f} MiB, after writing {r1:.0f} MiB, after opening {r2:.0f} MiB, "
        f"peak while decoding {peak:.0f} MiB, at the end {r3:.0f} MiB"
    )


def bench_ortho(tmp, repeat, size=(1280, 720)):
    import warnings

    import rasterio
    from rasterio.crs import CRS
    from rasterio.enums import Resampling
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.warp import reproject

    from geoloc_viz import picture_model as pm
    from geoloc_viz.flight_model import default_flight_scenario
    from geoloc.workflows.ortho import locate_frame, ortho_grid, orthorectify

    scn = default_flight_scenario()
    idx = 10
    inputs = scn.records[idx][1]
    sensor = pm.frame_sensor(scn, idx, size[1], size[0])
    pose = inputs.pose()
    img = np.random.default_rng(0).integers(0, 255, (3, size[1], size[0]), dtype=np.uint8)
    gsd = 1280 / size[0]  # the frame's own ground sample: 1 m at 1280 pixels across
    frame = locate_frame(sensor, pose, scn.dem, step=8)
    out = Path(tmp) / "ortho.tif"
    orthorectify(img, sensor, pose, scn.dem, out, gsd_m=gsd, frame=frame)  # warm the compiled kernels
    w_o, c_o, info = timed(lambda: orthorectify(img, sensor, pose, scn.dem, out, gsd_m=gsd, frame=frame), repeat)
    w_f, c_f, _ = timed(lambda: locate_frame(sensor, pose, scn.dem, step=8), repeat)
    full = locate_frame(sensor, pose, scn.dem, step=1)  # GDAL's geolocation arrays: every pixel
    grid = ortho_grid(frame, gsd)
    dst = np.zeros((3, grid.height, grid.width), np.float32)
    geo = np.stack([full.lon_deg, full.lat_deg])

    def gdal():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            reproject(
                img.astype(np.float32),
                dst,
                src_geoloc_array=geo,
                src_crs=CRS.from_epsg(4326),
                dst_transform=grid.transform,
                dst_crs=CRS.from_epsg(4326),
                resampling=Resampling.bilinear,
            )

    w_g, c_g, _ = timed(gdal, max(1, repeat // 2))
    del rasterio
    print(
        f"ortho: {size[0]} x {size[1]} frame at {gsd:g} m cells ({info['width']} x {info['height']}, "
        f"{info['cells_seen']} seen, {info['cells_hidden']} hidden): median wall {w_o:.3f} s, CPU {c_o:.3f} s "
        f"(target <= 1 s); + frame grid at step 8: wall {w_f:.3f} s, CPU {c_f:.3f} s"
    )
    print(
        f"ortho: peer GDAL warp with geolocation arrays (no occlusion test): median wall {w_g:.3f} s, "
        f"CPU {c_g:.3f} s; ratio peer / ours {w_g / w_o:.2f}x (wall)"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--hour-s", type=float, default=3600.0, help="length of the long video [s]")
    ap.add_argument("--only", choices=("switch", "hour", "ortho"), default=None)
    ap.add_argument("--size", default="1280x720", help="WxH of the switch video and the ortho frame")
    a = ap.parse_args(argv)
    try:
        size = tuple(int(v) for v in a.size.lower().split("x"))
        assert len(size) == 2 and min(size) >= 16
    except (ValueError, AssertionError):
        ap.error(f"--size {a.size!r}: must be WIDTHxHEIGHT in pixels, each >= 16 (e.g. 1280x720)")
    print(f"2-core machine shared with other jobs: load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory(prefix="geoloc-bench-images-") as tmp:
        if a.only in (None, "hour"):  # first: its RSS at the start is the bare process's
            bench_hour(tmp, a.hour_s)
        if a.only in (None, "switch"):
            bench_switch(tmp, a.repeat, size)
        if a.only in (None, "ortho"):
            bench_ortho(tmp, a.repeat, size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
