"""Image sources: the pictures behind the records (a photo, a video's frames, rendered frames).

One interface, :class:`ImageSource`, for every kind of picture geoloc shows or
measures in (docs/images.md):

- :class:`PhotoImage`: one JPEG or TIFF (a drone photo), one image, no time;
- :class:`VideoFrames`: the frames of a video (MPEG-TS, MP4, anything FFmpeg
  demuxes) through PyAV, decoded lazily on request (a seek to the key frame before,
  then decoding forward), kept in a cache bounded in bytes; the index of
  presentation time stamps (PTS) is built by demuxing packets without decoding
  pixels, so an hour of video opens about as fast as a minute;
- :class:`ArrayImages`: images already in memory (frames rendered by
  :mod:`geoloc.workflows.render`).

Times. ``times_s`` are presentation times in seconds on the metadata's clock: for a
video, the container PTS of each frame minus the source's ``time_offset_s``. The
offset is the named metadata-to-video offset, *video time = metadata time +
offset*: the frame showing the scene a metadata record describes at time ``t`` has
the PTS ``t + time_offset_s``. A KLV record read from the same container carries its
own container PTS (``pts_s``, :mod:`geoloc.io.klv`, :mod:`geoloc.workflows.klv_replay`),
so ``source.index_at(record_pts_s)`` is the frame for that record; a video whose
frames run ahead of their metadata by ``d`` seconds (the frame at PTS ``p`` shows
the scene of metadata time ``p + d``) is matched with ``time_offset_s = -d``.

Pixels. ``image(i)`` is a ``(rows, cols, 3)`` uint8 RGB array whose array row 0 /
column 0 is pixel (1, 1), the top-left pixel (docs/conventions.md, "Pixels"):
pixel ``(row, col)`` is ``image[row - 1, col - 1]``.

This module is layer 5 (``io``): it imports no viewer.
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from fractions import Fraction
from pathlib import Path
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike
from geoloc.extras import require

__all__ = [
    "ImageSource",
    "PhotoImage",
    "VideoFrames",
    "ArrayImages",
    "open_images",
    "nearest_index",
    "PHOTO_SUFFIXES",
    "VIDEO_SUFFIXES",
]

#: Still-image suffixes :func:`open_images` opens as a :class:`PhotoImage`.
PHOTO_SUFFIXES = {".jpg", ".jpeg", ".tif", ".tiff", ".png"}
#: Video suffixes :func:`open_images` opens as :class:`VideoFrames` (anything else FFmpeg reads works too).
VIDEO_SUFFIXES = {".ts", ".m2ts", ".mts", ".mpg", ".mpeg", ".mp4", ".mov", ".mkv", ".trp", ".avi"}

DEFAULT_CACHE_BYTES = 256 * 2**20


@runtime_checkable
class ImageSource(Protocol):
    """What the viewers and the measurements read pictures through.

    Attributes
    ----------
    rows, cols : int
        Image height and width [pixels].
    times_s : ndarray, shape (n,)
        Presentation time of each image [s] on the metadata's clock (container PTS
        minus ``time_offset_s`` for a video); NaN for a still photo.
    """

    # read-only: a video's are properties over its frame index
    @property
    def rows(self) -> int: ...

    @property
    def cols(self) -> int: ...

    @property
    def times_s(self) -> np.ndarray: ...

    def __len__(self) -> int: ...

    def image(self, index: int) -> np.ndarray:
        """Image ``index`` as ``(rows, cols, 3)`` uint8 RGB, array row 0 = pixel row 1 (top)."""
        ...

    def index_at(self, t_s: float) -> int:
        """The image nearest time ``t_s`` (by PTS); -1 when there is none."""
        ...


def nearest_index(times_s: np.ndarray, t_s: float, max_gap_s: float) -> int:
    """Index of the time in sorted ``times_s`` nearest ``t_s`` (ties: the earlier one).

    Returns -1 when ``t_s`` is not finite, ``times_s`` is empty, or ``t_s`` lies more
    than ``max_gap_s`` before the first or after the last time (outside the stream).
    """
    n = len(times_s)
    try:
        t = float(t_s)
    except (TypeError, ValueError):
        return -1
    if n == 0 or not math.isfinite(t):
        return -1
    if t < times_s[0] - max_gap_s or t > times_s[-1] + max_gap_s:
        return -1
    k = int(np.searchsorted(times_s, t, side="left"))
    if k == 0:
        return 0
    if k >= n:
        return n - 1
    return k - 1 if (t - times_s[k - 1]) <= (times_s[k] - t) else k


def _check_index(index, n: int, what: str) -> int:
    try:
        i = int(index)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: image index must be an integer, got {index!r}") from None
    if i != index or not 0 <= i < n:
        raise ValueError(f"{what}: image index {index!r} is outside 0..{n - 1}")
    return i


def _check_offset(time_offset_s) -> float:
    try:
        v = float(time_offset_s)
    except (TypeError, ValueError):
        raise ValueError(f"time_offset_s must be a number of seconds, got {time_offset_s!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"time_offset_s must be finite, got {time_offset_s!r}")
    return v


def _check_cache(cache_bytes) -> int:
    try:
        v = int(cache_bytes)
    except (TypeError, ValueError):
        raise ValueError(f"cache_bytes must be an integer number of bytes, got {cache_bytes!r}") from None
    if v < 0:
        raise ValueError(f"cache_bytes must be >= 0, got {cache_bytes!r}")
    return v


def _as_rgb8(a: ArrayLike, what: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"{what}: an image must be (rows, cols, 3) RGB, got shape {a.shape}")
    if a.shape[2] == 4:
        a = a[:, :, :3]
    if a.dtype != np.uint8:
        raise ValueError(f"{what}: an image must be uint8, got {a.dtype}")
    return np.ascontiguousarray(a)


class PhotoImage:
    """One still picture (JPEG, TIFF, PNG), read with Pillow on first use.

    ``rows`` and ``cols`` come from the file's header (no pixels decoded); the pixels
    are decoded once, on the first :meth:`image` call, as stored (the EXIF orientation
    tag is not applied: geoloc's pixels are the stored raster's, as its photo reader's).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    """

    def __init__(self, path: str | os.PathLike[str]):
        from PIL import Image

        self.path = Path(path)
        try:
            with Image.open(self.path) as im:
                self.cols, self.rows = (int(v) for v in im.size)
        except FileNotFoundError:
            raise
        except OSError as e:
            raise ValueError(f"{self.path}: not an image Pillow reads: {e}") from e
        self.times_s = np.array([np.nan])
        self._pixels: np.ndarray | None = None

    def __len__(self) -> int:
        return 1

    def __repr__(self) -> str:
        return f"PhotoImage({str(self.path)!r}, {self.rows}x{self.cols})"

    def image(self, index: int = 0) -> np.ndarray:
        _check_index(index, 1, str(self.path))
        if self._pixels is None:
            from PIL import Image

            with Image.open(self.path) as im:
                self._pixels = _as_rgb8(np.asarray(im.convert("RGB")), str(self.path))
        return self._pixels

    def index_at(self, t_s: float) -> int:
        """Always 0: a photo is the picture of its one record, whatever the time."""
        return 0


class ArrayImages:
    """Images held in memory (rendered frames, a test's pictures).

    Parameters
    ----------
    images : array_like, shape (n, rows, cols, 3), uint8, or a sequence of such images
    times_s : array_like, shape (n,), optional
        Their times [s], increasing; default ``0, 1, ..., n-1``.
    """

    def __init__(self, images: np.ndarray | Sequence[ArrayLike], times_s: ArrayLike | None = None):
        if isinstance(images, np.ndarray) and images.ndim == 4:
            imgs = [_as_rgb8(images[i], "ArrayImages") for i in range(len(images))]
        else:
            imgs = [_as_rgb8(im, "ArrayImages") for im in images]
        if not imgs:
            raise ValueError("ArrayImages: no images")
        shapes = {im.shape for im in imgs}
        if len(shapes) != 1:
            raise ValueError(f"ArrayImages: images of different sizes {sorted(shapes)}")
        self._images = imgs
        self.rows, self.cols = imgs[0].shape[:2]
        t = np.arange(len(imgs), dtype=float) if times_s is None else np.asarray(times_s, float).reshape(-1)
        if len(t) != len(imgs):
            raise ValueError(f"ArrayImages: {len(t)} times_s for {len(imgs)} images")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("ArrayImages: times_s must be finite and strictly increasing")
        self.times_s = t
        self._gap = float(np.median(np.diff(t))) if len(t) > 1 else math.inf

    def __len__(self) -> int:
        return len(self._images)

    def image(self, index: int) -> np.ndarray:
        return self._images[_check_index(index, len(self._images), "ArrayImages")]

    def index_at(self, t_s: float) -> int:
        return nearest_index(self.times_s, t_s, self._gap)


class _FrameCache:
    """Decoded frames by PTS, least recently used out first, bounded in bytes."""

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self.nbytes = 0
        self._d: OrderedDict[int, np.ndarray] = OrderedDict()

    def get(self, key):
        a = self._d.get(key)
        if a is not None:
            self._d.move_to_end(key)
        return a

    def put(self, key, a: np.ndarray):
        if a.nbytes > self.max_bytes:
            return
        old = self._d.pop(key, None)
        if old is not None:
            self.nbytes -= old.nbytes
        self._d[key] = a
        self.nbytes += a.nbytes
        while self.nbytes > self.max_bytes:
            _, b = self._d.popitem(last=False)
            self.nbytes -= b.nbytes

    def __len__(self):
        return len(self._d)


class _Decoder:
    """One opened container and its video stream's decoding state, shared by the
    :class:`VideoFrames` views of a file (they differ only in their time offset)."""

    def __init__(self, path: Path, stream: int | None, cache_bytes: int):
        av = require("av", "reading video frames")

        self.path = path
        try:
            self.container = av.open(os.fspath(path))
        except FileNotFoundError:
            raise
        except av.error.FFmpegError as e:
            raise ValueError(f"{path}: PyAV cannot open it: {e}") from e
        videos = list(self.container.streams.video)
        if not videos:
            self.container.close()
            raise ValueError(f"{path}: the container has no video stream")
        if stream is None:
            self.stream = videos[0]
        else:
            match = [s for s in videos if s.index == stream]
            if not match:
                self.container.close()
                raise ValueError(
                    f"{path}: stream {stream} is not a video stream (video streams: {[s.index for s in videos]})"
                )
            self.stream = match[0]
        self.stream.thread_type = "AUTO"
        tb = self.stream.time_base
        self.time_base = Fraction(tb.numerator, tb.denominator)
        cc = self.stream.codec_context
        self.cols, self.rows = int(cc.width), int(cc.height)
        self.cache = _FrameCache(cache_bytes)
        self.lock = threading.RLock()
        self._pts: np.ndarray | None = None
        self.pts_s: np.ndarray | None = None
        self._frames = None  # the running decode generator
        self._last = None  # PTS of the last frame it gave
        self.decoded = 0  # frames decoded so far (a benchmark reads it)
        self.seeks = 0

    # ---- the index of PTS, by demuxing (no pixel decoded)
    @property
    def pts(self) -> np.ndarray:
        if self._pts is None:
            with self.lock:
                if self._pts is None:
                    self._pts = self._build_index()
        return self._pts

    def _build_index(self) -> np.ndarray:
        """Frame PTS in presentation order, and for each frame the decode time stamp of
        the key frame to seek to (the last key packet at or before its own packet in
        decode order); from the packets alone (``demux``), no pixel decoded."""
        av = require("av", "reading video frames")

        pts_list: list[int] = []
        seek_list: list[int] = []
        key = None
        with av.open(os.fspath(self.path)) as c:
            s = c.streams[self.stream.index]
            for p in c.demux(s):
                if p.pts is None or p.size == 0:
                    continue
                ts = p.dts if p.dts is not None else p.pts
                if p.is_keyframe or key is None:
                    key = ts
                pts_list.append(p.pts)
                seek_list.append(key)
        if not pts_list:
            raise ValueError(f"{self.path}: the video stream has no frame with a time stamp")
        pts = np.asarray(pts_list, np.int64)
        order = np.argsort(pts, kind="stable")
        pts, seek = pts[order], np.asarray(seek_list, np.int64)[order]
        keep = np.concatenate([[True], np.diff(pts) > 0])
        self._seek = seek[keep]
        self._keys = np.unique(self._seek)
        return pts[keep]

    def close(self):
        with self.lock:
            self._frames = None
            self.container.close()

    # ---- decoding
    def _restart(self, target_pts: int, back: int = 0):
        """Seek to the key frame of the frame at ``target_pts`` (``back`` key frames
        earlier still, when a seek landed late), ready to decode forward."""
        i = int(np.searchsorted(self.pts, target_pts))
        j = int(np.searchsorted(self._keys, self._seek[min(i, len(self.pts) - 1)])) - back
        # FFmpeg's timestamp seek in an MPEG-TS lands on the first key frame whose time
        # stamp is >= the request: asking for the key frame's own DTS lands on it
        self.container.seek(int(self._keys[max(j, 0)]), stream=self.stream, backward=True, any_frame=False)
        self.seeks += 1
        self._frames = self.container.decode(self.stream)
        self._last = None

    def _next(self):
        try:
            f = next(self._frames)
        except (StopIteration, EOFError):
            self._frames = None
            return None
        self.decoded += 1
        p = f.pts
        rgb = f.to_ndarray(format="rgb24")
        self._last = p
        return p, rgb

    def frame(self, target_pts: int, keep_every: bool) -> np.ndarray:
        """The decoded RGB frame with PTS ``target_pts`` (one of :attr:`pts`)."""
        with self.lock:
            a = self.cache.get(target_pts)
            if a is not None:
                return a
            # continue the running decode when the target is a little ahead of it
            # (playback), else seek to the key frame at or before the target
            ahead = (
                self._frames is not None
                and self._last is not None
                and target_pts > self._last
                and np.searchsorted(self.pts, target_pts) - np.searchsorted(self.pts, self._last) <= 12
            )
            if not ahead:
                self._restart(target_pts)
            attempt = 0
            while True:
                got = self._next()
                if got is not None and got[0] == target_pts:
                    self.cache.put(target_pts, got[1])
                    return got[1]
                if got is None or (got[0] is not None and got[0] > target_pts):
                    # at the end, or past the target without meeting it: the seek landed
                    # after it; seek one key frame further back each time
                    attempt += 1
                    if attempt > 3:
                        raise ValueError(f"{self.path}: cannot decode the frame at PTS {target_pts}")
                    self._restart(target_pts, back=attempt)
                    continue
                p, rgb = got
                if keep_every and p is not None:
                    self.cache.put(p, rgb)


class VideoFrames:
    """The frames of a video file, decoded lazily through PyAV.

    Parameters
    ----------
    path : str or os.PathLike
        An MPEG-TS, MP4, ... file with a video stream.
    time_offset_s : float
        The metadata-to-video time offset [s]: video time = metadata time + offset
        (module docstring). ``times_s`` = PTS - offset.
    cache_bytes : int
        Bound of the decoded-frame cache [bytes] (RGB frames, ``rows * cols * 3``
        each). Default 256 MiB. 0 keeps nothing.
    stream : int, optional
        Index of the video stream; default the first.

    Notes
    -----
    Opening reads the container's header only (size, time base); the PTS index is
    built on first use of ``times_s``, ``len`` or ``index_at`` by demuxing the video
    packets, no pixel decoded. ``image(i)`` seeks to the key frame at or before frame
    ``i`` and decodes forward to it (frames met on the way are cached), or, when the
    decoder is a few frames behind ``i`` already (playback), just decodes on.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        time_offset_s: float = 0.0,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        *,
        stream: int | None = None,
        _decoder: _Decoder | None = None,
    ):
        self.time_offset_s = _check_offset(time_offset_s)
        self.path = Path(path)
        self._dec = _decoder if _decoder is not None else _Decoder(self.path, stream, _check_cache(cache_bytes))
        self.rows, self.cols = self._dec.rows, self._dec.cols
        self._times: np.ndarray | None = None

    def __repr__(self) -> str:
        return f"VideoFrames({str(self.path)!r}, {self.rows}x{self.cols}, time_offset_s={self.time_offset_s})"

    def with_time_offset(self, time_offset_s: float) -> "VideoFrames":
        """The same frames (same decoder and cache) with another metadata-to-video offset."""
        return VideoFrames(self.path, time_offset_s, _decoder=self._dec)

    @property
    def pts_s(self) -> np.ndarray:
        """Container PTS of each frame [s], increasing (``times_s + time_offset_s``)."""
        if self._dec.pts_s is None:
            # integer PTS x numerator / denominator: each value the correctly rounded
            # float(pts * time_base), as a KLV packet's time_s (geoloc.io.klv)
            tb = self._dec.time_base
            self._dec.pts_s = (self._dec.pts * tb.numerator) / tb.denominator
        return self._dec.pts_s

    @property
    def times_s(self) -> np.ndarray:
        if self._times is None:
            self._times = self.pts_s - self.time_offset_s
        return self._times

    @property
    def frame_interval_s(self) -> float:
        """Median spacing of the frames [s] (inf for a single frame)."""
        t = self.pts_s
        return float(np.median(np.diff(t))) if len(t) > 1 else math.inf

    @property
    def cache_nbytes(self) -> int:
        """Bytes held by the decoded-frame cache now (at most ``cache_bytes``)."""
        return self._dec.cache.nbytes

    @property
    def cache_bytes(self) -> int:
        return self._dec.cache.max_bytes

    @property
    def frames_decoded(self) -> int:
        """Frames decoded since the file was opened (all views of it)."""
        return self._dec.decoded

    def __len__(self) -> int:
        return len(self._dec.pts)

    def image(self, index: int) -> np.ndarray:
        i = _check_index(index, len(self), str(self.path))
        return self._dec.frame(int(self._dec.pts[i]), keep_every=True)

    def index_at(self, t_s: float) -> int:
        """The frame whose ``times_s`` is nearest ``t_s``; -1 for a non-finite time or one
        more than a frame interval before the first frame or after the last."""
        return nearest_index(self.times_s, t_s, self.frame_interval_s)

    def close(self) -> None:
        """Close the file (every view of it)."""
        self._dec.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_images(
    path: str | os.PathLike[str], *, time_offset_s: float = 0.0, cache_bytes: int = DEFAULT_CACHE_BYTES
) -> ImageSource:
    """Open a picture file as an :class:`ImageSource`: a still image (``.jpg``, ``.tif``,
    ``.png``) as :class:`PhotoImage`, anything else as :class:`VideoFrames`.

    Parameters
    ----------
    path : str or os.PathLike
    time_offset_s : float
        Metadata-to-video offset [s] (video time = metadata time + offset); ignored for a photo.
    cache_bytes : int
        Decoded-frame cache bound [bytes] of a video.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A file that is no picture or video, naming it.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such image or video file")
    _check_offset(time_offset_s)
    if p.suffix.lower() in PHOTO_SUFFIXES:
        return PhotoImage(p)
    return VideoFrames(p, time_offset_s=time_offset_s, cache_bytes=_check_cache(cache_bytes))
