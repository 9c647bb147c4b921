"""Image sources (geoloc.io.images): photos, video frames, in-memory frames.

Oracles from outside the module:

* the encoder's input: each synthetic frame carries its own number as eight
  black/white blocks (robust to H.264 / MPEG-4 compression: a block is 20 x 20
  pixels of 0 or 255), so a decoded image names the frame it is, whatever route
  (seek, playback, cache) produced it; the blocks sit at fixed rows, so an image
  flipped or transposed would not read back;
* PyAV decoding the whole file straight through, no seek, for the frames' PTS;
* Pillow for a photo's pixels.
"""

import math

import av
import numpy as np
import pytest
from PIL import Image

from geoloc.assets import asset_path
from geoloc.io.images import ArrayImages, ImageSource, PhotoImage, VideoFrames, nearest_index, open_images

N_FRAMES = 90
W, H = 320, 180


def frame_rgb(i: int) -> np.ndarray:
    a = np.zeros((H, W, 3), np.uint8)
    a[:, :, 0] = (3 * i) % 256
    for b in range(8):
        a[40:60, 20 * b : 20 * b + 20, 1] = 255 if (i >> b) & 1 else 0
    a[:10, :10, 2] = 255  # top-left marker: pixel (1, 1) is array [0, 0]
    return a


def frame_number(img: np.ndarray) -> int:
    return sum(1 << b for b in range(8) if img[50, 20 * b + 10, 1] > 128)


def write_video(path, codec="libx264", bframes=True, gop=30, rate=30, n=N_FRAMES):
    with av.open(str(path), "w") as out:
        vs = out.add_stream(codec, rate=rate)
        vs.width, vs.height, vs.pix_fmt = W, H, "yuv420p"
        vs.gop_size = gop
        if codec == "libx264":
            vs.options = {"preset": "ultrafast", "bf": "2" if bframes else "0"}
        for i in range(n):
            f = av.VideoFrame.from_ndarray(frame_rgb(i), format="rgb24")
            f.pts = i
            for p in vs.encode(f):
                out.mux(p)
        for p in vs.encode():
            out.mux(p)
    return path


VARIANTS = [("ts", "libx264", True), ("ts", "libx264", False), ("mp4", "libx264", True), ("ts", "mpeg2video", True)]


@pytest.fixture(scope="module", params=VARIANTS, ids=lambda v: f"{v[0]}-{v[1]}-{'b' if v[2] else 'nob'}")
def video(request, tmp_path_factory):
    ext, codec, bf = request.param
    return write_video(tmp_path_factory.mktemp("vid") / f"v.{ext}", codec, bf)


def straight_pts_s(path):
    """Every frame's PTS [s] decoding the whole file with PyAV, no seek (the oracle)."""
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        return sorted(float(f.pts * s.time_base) for f in c.decode(s))


def test_video_random_access_gives_the_asked_frame(video):
    v = open_images(video)
    assert isinstance(v, VideoFrames) and isinstance(v, ImageSource)
    assert (v.rows, v.cols) == (H, W) and len(v) == N_FRAMES
    order = np.random.default_rng(7).permutation(np.tile(np.arange(N_FRAMES), 2))
    for i in order:
        img = v.image(int(i))
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        assert frame_number(img) == i
    assert v.image(0)[2, 2, 2] > 200 and v.image(0)[H - 3, W - 3, 2] < 50  # top-left is array [0, 0]


def test_video_without_cache_seeks_and_plays(video):
    v = open_images(video, cache_bytes=0)
    for i in (50, 3, 89, 0, 31, 29, 30, 60, 59):  # around the key frames (every 30)
        assert frame_number(v.image(i)) == i
    seeks = v._dec.seeks
    assert [frame_number(v.image(i)) for i in range(N_FRAMES)] == list(range(N_FRAMES))
    assert v._dec.seeks - seeks <= 1  # playback decodes on, it does not seek per frame
    assert v.cache_nbytes == 0


def test_times_are_the_decoders_pts(video):
    v = open_images(video)
    ref = straight_pts_s(video)
    assert len(ref) == N_FRAMES
    # exact: both are integers of the stream's time base scaled by the same Fraction
    np.testing.assert_array_equal(v.times_s, ref)
    np.testing.assert_array_equal(v.pts_s, ref)
    assert v.frame_interval_s == pytest.approx(1 / 30, rel=1e-9)


def test_index_at_is_the_nearest_frame(video):
    v = open_images(video)
    t = v.times_s
    rng = np.random.default_rng(3)
    for q in rng.uniform(t[0] - 0.02, t[-1] + 0.02, 200):
        assert v.index_at(q) == int(np.argmin(np.abs(t - q)))
    assert v.index_at(t[10]) == 10
    assert v.index_at(t[0] - 0.5) == -1 and v.index_at(t[-1] + 0.5) == -1
    assert v.index_at(math.nan) == -1


def test_time_offset_moves_the_match(video):
    v = open_images(video)
    d = 10 / 30  # ten frames
    w = open_images(video, time_offset_s=-d)  # video ahead of its metadata by d
    np.testing.assert_allclose(w.times_s, v.pts_s + d, atol=1e-12)
    # the record at metadata time t is shown by the frame at PTS t - d
    assert w.index_at(v.pts_s[40] + d) == 40
    assert v.with_time_offset(-d).index_at(v.pts_s[40] + d) == 40
    with pytest.raises(ValueError, match="time_offset_s"):
        open_images(video, time_offset_s=math.nan)


def test_cache_stays_within_its_bound(video):
    frame_bytes = H * W * 3
    bound = int(3.5 * frame_bytes)
    v = open_images(video, cache_bytes=bound)
    peak = 0
    for i in np.random.default_rng(1).integers(0, N_FRAMES, 60):
        assert frame_number(v.image(int(i))) == i
        peak = max(peak, v.cache_nbytes)
    assert peak <= bound and len(v._dec.cache) == 3
    assert v.cache_bytes == bound


def test_bad_inputs_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.ts"):
        open_images(tmp_path / "nope.ts")
    junk = tmp_path / "junk.ts"
    junk.write_bytes(b"not a video at all" * 10)
    with pytest.raises(ValueError, match="junk.ts"):
        open_images(junk)
    v = write_video(tmp_path / "v.ts", n=5)
    s = open_images(v)
    for bad in (5, -1, 1.5, "a"):
        with pytest.raises(ValueError, match="index"):
            s.image(bad)
    with pytest.raises(ValueError, match="cache_bytes"):
        open_images(v, cache_bytes=-1)
    with pytest.raises(ValueError, match="no video stream"):
        from geoloc.io.klv import write_ts

        k = tmp_path / "klv_only.ts"
        write_ts(k, [{"precision_time_stamp_us": 1}])
        open_images(k)


def test_photo_is_pillows_pixels(tmp_path):
    p = asset_path("photos/DJI_0001.JPG")
    ph = open_images(p)
    assert isinstance(ph, PhotoImage) and isinstance(ph, ImageSource) and len(ph) == 1
    with Image.open(p) as im:
        ref = np.asarray(im.convert("RGB"))
    assert (ph.rows, ph.cols) == ref.shape[:2]
    np.testing.assert_array_equal(ph.image(0), ref)
    assert ph.index_at(12.0) == 0 and math.isnan(ph.times_s[0])
    tif = tmp_path / "a.tif"
    Image.fromarray(frame_rgb(7)).save(tif)
    t = open_images(tif)
    assert frame_number(t.image(0)) == 7 and t.image(0)[0, 0, 2] == 255
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"xx")
    with pytest.raises(ValueError, match="bad.jpg"):
        open_images(bad)


def test_array_images():
    imgs = np.stack([frame_rgb(i) for i in range(4)])
    a = ArrayImages(imgs, [0.0, 0.5, 1.0, 1.5])
    assert isinstance(a, ImageSource) and len(a) == 4 and (a.rows, a.cols) == (H, W)
    assert frame_number(a.image(2)) == 2
    assert a.index_at(0.74) == 1 and a.index_at(0.76) == 2 and a.index_at(0.75) == 1  # ties: the earlier
    assert a.index_at(-1.0) == -1 and a.index_at(2.1) == -1
    with pytest.raises(ValueError, match="times_s"):
        ArrayImages(imgs, [0, 1, 1, 2])
    with pytest.raises(ValueError, match="uint8"):
        ArrayImages(imgs.astype(float))
    with pytest.raises(ValueError, match="different sizes"):
        ArrayImages([imgs[0], imgs[0][:10]])


def test_nearest_index_against_brute_force():
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.01, 0.2, 50))
    for q in rng.uniform(t[0], t[-1], 300):
        d = np.abs(t - q)
        assert nearest_index(t, q, 1.0) == int(np.flatnonzero(d == d.min())[0])
    assert nearest_index(np.array([]), 0.0, 1.0) == -1
