"""``geoloc view --live udp://HOST:PORT``: the flight debugger of ``geoloc view``, following a flight as it flies.

A :class:`LiveFeed` (one per viewer) receives the stream on a thread
(:func:`geoloc.io.live.receive`) and replays every batch of KLV packets as it arrives
(:class:`geoloc.workflows.live_replay.LiveReplay`); with ``journal`` / ``record`` it
journals the rows and the raw stream. With video in the stream it decodes the pictures as
they come (PyAV), keeps the newest (:class:`LiveImages`, an image source for the picture
layer) and counts what the decoder saw (resolution changes, undecodable units).

A :class:`LiveFlight` (one per feed, shared by the tabs) turns the new packets into viewer
records (:func:`geoloc_viz.scenario.records_from_columns`, as ``geoloc view FILE.ts``
does) and grows the flight model with them (:func:`geoloc_viz.flight_model.build` of the
new frames in the flight's fixed ENU frame, then :func:`geoloc_viz.flight_model.extend`:
the outlier flags, order, fault runs and accuracy over the window, exactly as for a file),
keeping the newest :data:`FLIGHT_WINDOW` frames (a rolling window: memory bounded; the
journal on disk has them all).

Each browser tab gets a :class:`LiveTab`: a **Live** folder (following / scrubbed back,
the **live** button, the current packet, what arrived and what was lost) and, from the
first located packet on, the full flight debugger of ``geoloc view``: a
:class:`geoloc_viz.app.GeolocSession` on the tab's ``client.scene`` / ``client.gui``
with the default layers (the flight layer, the picture, the teaching panel, ...), its
scenario's records replaced by the window as it grows
(:meth:`geoloc_viz.flight_layer.FlightLayer.set_model`). The view follows the latest
frame (its full chain, line of sight, iterations and picture) until the user scrubs back
(the timeline, "go to", "worst fault", play or the record dropdown); **live** returns.

Heights ellipsoidal (WGS 84). Conventions: ``docs/conventions.md``; guide: ``docs/live.md``.
"""

from __future__ import annotations

import copy
import sys
import threading
import time
from collections import deque
from types import SimpleNamespace
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    import av

    from geoloc.sensors.frame import FrameSensor
    from geoloc_viz.app import GeolocSession
    from geoloc_viz.flight_layer import FlightLayer
    from geoloc_viz.flight_model import FlightModel
    from geoloc_viz.model import Scenario

#: Frames of the flight debugger's window (the newest): bounds memory and the batched nodes sent.
FLIGHT_WINDOW = 1000
#: Tabs are updated at most this often [s] (the followed frame, the texts) ...
UPDATE_S = 0.2
#: ... the flight's batched nodes and tables at most this often [s] (redrawn when frames came) ...
DRAW_S = 1.0
#: ... and the latest frame loaded (its chain, iterations, picture) at most this often [s]: a browser
#: drawing in software WebGL on a busy machine falls minutes behind a stream it is sent every frame of
FOLLOW_S = 1.0
#: Decoded pictures kept (the newest): at most this many, and at most this many bytes. Each is kept at
#: the video's own size, the grid every pixel of the debugger is in (:meth:`LiveFlight.update`):
#: a 640 x 360 stream keeps 64 (44 MB), a 1920 x 1080 one 21 (about 130 MB).
PICTURES = 64
PICTURE_BYTES = 128 * 2**20
#: A frame's picture is the kept one nearest its time stamp within this [s] (else none: scrubbed
#: back beyond the pictures kept). A sender that restarts repeats its time stamps: a frame of an
#: earlier pass can then get the picture of the same time stamp of the newest pass.
PICTURE_GAP_S = 0.5
#: Batches kept for the flight when nobody takes them.
PENDING = 4096


class LiveFeed:
    """The stream received and replayed on a thread; :meth:`snapshot` gives the tabs a consistent view.

    Parameters
    ----------
    url : str
        ``udp://HOST:PORT``.
    sensor, surface
        As :func:`geoloc.workflows.klv_replay.replay_klv` (default surface: each packet's own
        frame-centre height).
    limits : dict
        Stop conditions of :func:`geoloc.io.live.receive` (``duration_s``, ``packets``, ``idle_s``).
    journal : text file, optional
        The rows as CSV as they come.
    record : callable, optional
        Called with each datagram (``--record-ts``).
    decode_video : bool
        Decode the video stream's pictures (for the picture panel).
    sock : socket.socket, optional
        Already bound (:func:`geoloc.io.live.open_socket`); default: bound here.
    """

    def __init__(
        self,
        url,
        *,
        sensor=None,
        surface=None,
        limits=None,
        journal=None,
        record=None,
        decode_video: bool = True,
        window: int | None = None,
        sock=None,
    ):
        from geoloc.io.live import LiveReceiver, exposure_note, open_socket, parse_udp_url
        from geoloc.workflows.live_replay import WINDOW, LiveReplay

        self.url = str(url)
        u = parse_udp_url(self.url)
        if sock is None:
            note = exposure_note(u)
            if note:
                print(note, file=sys.stderr, flush=True)
            sock = open_socket(u)
        self.sock = sock  # bound now: what comes while the viewer starts waits in the kernel
        self.rx = LiveReceiver()
        self.replay = LiveReplay(
            self.url, surface=surface, sensor=sensor, journal=journal, receiver=self.rx, window=window or WINDOW
        )
        self.limits = dict(limits or {})
        self.record = record
        self.decode_video = decode_video
        self.version = 0  # bumped by every batch with a located packet
        self.first_row_s: float | None = None  # time.monotonic() of the first located packet
        self.sensor = sensor  # the replay's sensor (its default for the stream once a packet came)
        self.error: str = ""
        self.done = False
        self._lock = threading.Lock()
        self._stop = False
        self._pending: list = []  # the batches' columns not yet taken by the flight (take_batches)
        self._thread: threading.Thread | None = None
        self._decoder: av.VideoCodecContext | None = None
        self._video_done = 0
        self.pictures: deque = deque()  # (serial, pts [90 kHz], RGB uint8 array), PICTURES / PICTURE_BYTES at most
        self._picture_bytes = 0
        self.pictures_total = 0
        #: (width, height) of the last decoded picture, the changes of it seen, and access units the
        #: decoder refused (a sender that changes its resolution; a broken unit: the next key frame recovers)
        self.video_size: tuple | None = None
        self.resolution_changes = 0
        self.decode_errors = 0

    def start(self) -> "LiveFeed":
        """Warm the replay up (its first call compiles; the first packet must not wait for it), then
        listen on a thread."""
        self.warm_up()
        self._thread = threading.Thread(target=self._run, daemon=True, name="geoloc-live-feed")
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop = True
        if self._thread is not None:
            self._thread.join(5)
        else:
            self.sock.close()

    def warm_up(self) -> None:
        """Replay the bundled example's first packet once, through a throw-away replay."""
        from geoloc.assets import ASSETS
        from geoloc.io.klv import Packet, read_klv_file
        from geoloc.workflows.live_replay import LiveReplay

        path = ASSETS / "klv" / "example_flight.klv"
        try:
            first = next(p for p in read_klv_file(path) if isinstance(p, Packet))
        except (OSError, StopIteration):
            return
        r = self.replay
        LiveReplay("warm-up", surface=r.surface, sensor=r.sensor).add([first])

    def _run(self) -> None:
        from geoloc.io.live import receive

        try:
            for _ in receive(
                self.url,
                receiver=self.rx,
                record=self.record,
                on_batch=self._batch,
                stop=lambda: self._stop,
                sock=self.sock,
                **self.limits,
            ):
                pass
            if self.decode_video:  # the stream ended: its last access unit and the decoder's held pictures
                self._decode(end=True)
            self._took(self.replay.flush())  # the packets still waiting for their video frame
        except Exception as e:  # a bind that fails, a bug: shown in the panel, never a dead viewer
            self.error = f"{type(e).__name__}: {e}"
            print(f"geoloc view --live: {self.error}", file=sys.stderr)
        finally:
            self.done = True

    def _batch(self, results) -> None:
        r = self.replay.add(results)
        if self.decode_video:
            self._decode()
        self._took(r)

    def _took(self, r) -> None:
        """A replayed batch to the tabs (None: nothing was ready)."""
        if r is None:
            return
        with self._lock:
            if self.sensor is None:
                self.sensor = r.sensor
            self._pending.append(r.columns)
            del self._pending[:-PENDING]  # nobody takes them (no tab yet): the newest only
            self.version += 1
            if self.first_row_s is None:
                self.first_row_s = time.monotonic()

    def take_batches(self) -> list:
        """The columns of the batches replayed since the last call (oldest first)."""
        with self._lock:
            out, self._pending = self._pending, []
            return out

    def _decode(self, end: bool = False) -> None:
        """Decode the video access units that came since the last call (newest pictures kept).

        Each video PES of the stream is one access unit (ISO/IEC 13818-1 Section 2.4.3.7; the
        demultiplexer completes a PES at the next one's start): it goes to the decoder whole, as a
        packet carrying its own PTS, so each picture comes out with its unit's time stamp. (FFmpeg's
        parser, given the units' bytes, hands a unit out only when the next one starts: its pictures
        were stamped with the next unit's time, one frame late.) ``end``: the stream ended; the
        pictures the decoder holds back are drained (``decode(None)``), or the stream's last frames
        would never have a picture.
        """
        import av

        video = self.rx.video
        n_new = self.rx.stats.video_units - self._video_done
        if n_new <= 0 and not (end and self._decoder is not None):
            return
        self._video_done = self.rx.stats.video_units
        units = list(video)[-min(n_new, len(video)) :] if n_new > 0 else []
        for pts, data, _pid in units:
            if data is None:
                continue
            try:
                if self._decoder is None:
                    from geoloc.io.ts_demux import _STREAM_TYPES_VIDEO

                    stype = self.rx.demux.streams.get(units[0][2], ("video", 0x1B))[1]
                    ctx = av.CodecContext.create(_STREAM_TYPES_VIDEO.get(stype, "h264"), "r")
                    if not isinstance(ctx, av.VideoCodecContext):  # a video stream type names a video codec
                        raise ValueError(f"stream type 0x{stype:02x}: codec {ctx.name} is not a video decoder")
                    self._decoder = ctx
                pkt = av.Packet(data)
                pkt.pts = pts
                self._pictures(self._decoder.decode(pkt), pts)
            except (av.error.FFmpegError, ValueError) as e:  # a broken access unit: the next key frame recovers
                self.decode_errors += 1
                if "codec" in str(e).lower():
                    self._decoder = None
        if end and self._decoder is not None:  # the pictures the decoder holds back (reordering, threads)
            try:
                self._pictures(self._decoder.decode(None), None)
            except (av.error.FFmpegError, ValueError):
                self.decode_errors += 1

    def _pictures(self, frames, pts) -> None:
        """Keep decoded video frames (``pts``: the access unit's, for a frame without its own)."""
        for fr in frames:
            size = (int(fr.width), int(fr.height))
            if self.video_size is not None and size != self.video_size:
                self.resolution_changes += 1
            self.video_size = size
            img = fr.to_ndarray(format="rgb24")  # the video's own pixels: no resampling
            self._keep((self.pictures_total, fr.pts if fr.pts is not None else pts, img))
            self.pictures_total += 1

    def _keep(self, picture) -> None:
        """Keep a decoded picture, dropping the oldest beyond :data:`PICTURES` or :data:`PICTURE_BYTES`
        (the newest always kept). Called on the feed's thread only: readers copy the deque."""
        self.pictures.append(picture)
        self._picture_bytes += picture[2].nbytes
        while len(self.pictures) > 1 and (len(self.pictures) > PICTURES or self._picture_bytes > PICTURE_BYTES):
            self._picture_bytes -= self.pictures.popleft()[2].nbytes

    def video_markdown(self) -> str:
        """The picture decoder's line of the stream panel ('' without video)."""
        if self.video_size is None and not self.decode_errors:
            return ""
        w, h = self.video_size or (0, 0)
        return (
            f"video {w} x {h} pixels; {self.resolution_changes} resolution change(s), "
            f"{self.decode_errors} undecodable access unit(s)"
        )

    def stats_markdown(self) -> str:
        """The stream panel: what arrived, what was lost, what the decoder saw, the feed's error."""
        v = self.video_markdown()
        return (
            self.rx.stats.markdown()
            + (f"\n\n{v}" if v else "")
            + (f"\n\n**error**: {self.error}" if self.error else "")
        )

    def picture_at(self, pts_s: float):
        """The decoded picture nearest ``pts_s`` [s] (None without video)."""
        k = self.picture_index_at(pts_s)
        return None if k < 0 else self.picture(k)

    def picture_index_at(self, pts_s: float, max_gap_s: float = PICTURE_GAP_S) -> int:
        """Serial number of the decoded picture nearest ``pts_s`` [s]; -1 without one within
        ``max_gap_s`` (a frame older than the pictures kept has none)."""
        pics = list(self.pictures)
        if not pics or not np.isfinite(pts_s):
            return -1
        t = pts_s * 90000.0
        best = min(pics, key=lambda p: abs((p[1] if p[1] is not None else 0) - t))
        return best[0] if abs((best[1] or 0) - t) <= max_gap_s * 90000.0 else -1

    def picture(self, serial: int):
        """Picture ``serial`` (the oldest kept if it left the window); None before the first."""
        pics = list(self.pictures)
        if not pics:
            return None
        return min(pics, key=lambda p: abs(p[0] - serial))[2]

    def snapshot(self) -> tuple[int, dict]:
        """(version, columns of the replay's window) at one instant (made on demand: O(window))."""
        with self._lock:
            return self.version, self.replay.columns()


class LiveImages:
    """A feed's decoded pictures as an image source (:class:`geoloc.io.images.ImageSource`) for the
    picture layer: image ``k`` is the ``k``-th picture decoded since the start (only the newest
    :data:`PICTURES` are kept: an older ``k`` gives the oldest kept); their times are the stream's
    presentation times [s]. ``rows`` / ``cols`` are the newest picture's (the video's own size; after
    a change of resolution the picture layer scales the lens to each image's own size)."""

    def __init__(self, feed: LiveFeed):
        self.feed = feed

    def __len__(self) -> int:
        return self.feed.pictures_total

    @property
    def times_s(self) -> np.ndarray:
        """Each picture's time [s], indexed by its serial number as :meth:`image` is (``ImageSource``:
        one per image): NaN for those no longer kept. Made on demand, never stored (it was the kept
        pictures' only, so past :data:`PICTURES` pictures a serial read another picture's time or none)."""
        t = np.full(self.feed.pictures_total, np.nan)
        for k, pts, _ in list(self.feed.pictures):
            if pts is not None and 0 <= k < len(t):
                t[k] = pts / 90000.0
        return t

    @property
    def rows(self) -> int:
        img = self.feed.picture(self.feed.pictures_total - 1)
        return 0 if img is None else int(img.shape[0])

    @property
    def cols(self) -> int:
        img = self.feed.picture(self.feed.pictures_total - 1)
        return 0 if img is None else int(img.shape[1])

    def image(self, index: int) -> np.ndarray:
        img = self.feed.picture(int(index))
        if img is None:
            raise IndexError(f"image {index}: no picture decoded yet")
        return img

    def index_at(self, t_s: float) -> int:
        return self.feed.picture_index_at(t_s)


class FlightFeed(Protocol):
    """What :class:`LiveFlight` reads of a feed (a :class:`LiveFeed`; the warm-up's stand-in): the
    stream's name, the replay's sensor (there once a batch came), whether pictures are decoded and
    the first one's size (width, height; None before it), the replay's batches since the last call."""

    @property
    def url(self) -> str: ...

    @property
    def sensor(self) -> FrameSensor: ...

    @property
    def decode_video(self) -> bool: ...

    @property
    def video_size(self) -> tuple | None: ...

    def take_batches(self) -> list: ...


class LiveFlight:
    """The flight debugger's records and flight model of a feed, grown as packets arrive (module docstring).

    Parameters
    ----------
    feed : FlightFeed
        A :class:`LiveFeed`.
    dem_path : path-like, optional
        The scene's DEM (``--dem``); default a bundled one covering the first frame, as ``geoloc view``.
    use_dem : bool
        False: footprints on each packet's frame-centre height (``--no-dem``).
    window : int
        Frames kept (the newest).
    dem_datum : {"egm96", "ellipsoid"}
        The vertical datum of the DEM file's heights (``--dem-datum``).
    """

    def __init__(
        self,
        feed: FlightFeed,
        *,
        dem_path=None,
        use_dem: bool = True,
        window: int = FLIGHT_WINDOW,
        dem_datum: str = "egm96",
    ):
        self.feed = feed
        self.dem_path, self.use_dem, self.window = dem_path, bool(use_dem), int(window)
        self.dem_datum = dem_datum
        self.base: Scenario | None = None  # the scenario of the first frame: sensor, DEM, the flight's ENU frame
        self.records: list = []
        self.fov_deg = np.zeros((0, 2))
        self.times_s = np.zeros(0)
        self.rows: dict = {}  # the replay's own columns of the window's frames (the panel's text)
        self.model: FlightModel | None = None
        self.version = 0  # bumped when frames came
        self.dropped = 0  # frames dropped off the window's start since the start
        self.first_frame_s: float | None = None  # time.monotonic() when the first frame was modelled
        self.last_build_s = float("nan")
        #: (rows, cols) of the video's own pixel grid, the one every pixel of the debugger is in: fixed by
        #: the first decoded picture (None before it, and without video: the sensor's grid then)
        self.grid: tuple | None = None
        self._lock = threading.RLock()

    def __len__(self) -> int:
        return len(self.records)

    ROW_KEYS = (
        "packet",
        "time_utc",
        "pts_s",
        "frame_pts_s",
        "lat_deg",
        "lon_deg",
        "h_m",
        "status",
        "frame_center_error_m",
        "corner_error_m",
        "outlier",
    )

    def _scenario(self, recs):
        from geoloc_viz import terrain_link
        from geoloc_viz.model import Scenario
        from geoloc_viz.scenario import enu_origin_for

        info, inp = recs[0]
        url = self.feed.url
        scn = Scenario(
            name=f"{url} {info.label}",
            camera=self.feed.sensor,
            inputs=inp,
            enu=enu_origin_for(info, inp),
            records=list(recs),
            record_index=0,
            use_dem=self.use_dem,
            source=url,
            description=f"live stream {url}",
        )
        scn._user_dem, scn.dem_datum = self.dem_path, self.dem_datum
        if self.use_dem:
            terrain_link.attach_dem(scn, self.dem_path, strict=self.dem_path is not None)
        else:
            scn.dem_name = "none (no DEM): ellipsoid at each packet's frame-centre height"
        if self.grid is not None:
            from geoloc_viz.model import use_image_grid

            use_image_grid(scn, *self.grid)
        if self.feed.decode_video:
            scn.images = LiveImages(self.feed)
        return scn

    def _take_grid(self) -> None:
        """Fix the pixel grid at the first decoded picture's size, once. A MISB ST 0601 stream names no
        image size: its sensor is made on a nominal grid (:func:`geoloc.workflows.klv_replay.klv_sensor`),
        converted here to the video's own (:func:`geoloc_viz.model.use_image_grid`, the rule of
        ``geoloc view FILE.ts``). Frames that came before the first picture move to it now."""
        size = self.feed.video_size if self.feed.decode_video else None
        if self.grid is not None or size is None:
            return
        from geoloc_viz.model import records_in_grid, use_image_grid

        cols, rows = size
        with self._lock:
            self.grid = (int(rows), int(cols))
            if self.base is not None:
                nominal = (self.base.camera.rows, self.base.camera.cols)
                use_image_grid(self.base, *self.grid)
                self.records = records_in_grid(self.records, nominal, self.grid)
                self.version += 1  # the tabs take the moved frames (LiveTab._grow)

    def update(self) -> bool:
        """Take the feed's new batches into the window and the model; True when frames came."""
        from geoloc_viz import flight_model
        from geoloc_viz.scenario import records_from_columns

        batches = self.feed.take_batches()
        if not batches:
            return False
        keys = [k for k in batches[0] if all(k in b for b in batches)]
        c = {k: np.concatenate([np.asarray(b[k]) for b in batches]) for k in keys}
        self._take_grid()
        recs, kept_list = records_from_columns(c, self.feed.sensor)  # on the sensor's own (nominal) grid
        if not recs:
            return False
        kept = np.asarray(kept_list, int)
        fov = np.stack(
            [
                np.asarray(c["sensor_horizontal_fov_deg"], float)[kept],
                np.asarray(c["sensor_vertical_fov_deg"], float)[kept],
            ],
            axis=1,
        )
        vt, pt = (np.asarray(c[k], float)[kept] for k in ("frame_pts_s", "pts_s"))
        t0 = time.perf_counter()
        with self._lock:
            if self.base is None:
                self.base = self._scenario(recs)  # its sensor and records put in the video's grid
            if self.grid is not None:  # the new frames' pixels converted once, as they arrive
                from geoloc_viz.model import records_in_grid

                recs = records_in_grid(recs, (self.feed.sensor.rows, self.feed.sensor.cols), self.grid)
            new_scn = copy.copy(self.base)
            new_scn.records = recs
            # no audit per batch: a convention shows over a flight, not over a few new frames
            new = flight_model.build(new_scn, enu=self.base.enu, fov_deg=fov, diagnose_faults=False, audit=False)
            records = (self.records + recs)[-self.window :]
            dropped = len(self.records) + len(recs) - len(records)
            scn = copy.copy(self.base)
            scn.records = records
            self.model = flight_model.extend(self.model, new, scn, keep=self.window)
            self.records = records
            w = self.window
            self.fov_deg = np.concatenate([self.fov_deg, fov])[-w:]
            self.times_s = np.concatenate([self.times_s, np.where(np.isfinite(vt), vt, pt)])[-w:]
            self.rows = {
                k: np.concatenate([self.rows.get(k, np.zeros(0, np.asarray(c[k]).dtype)), np.asarray(c[k])[kept]])[-w:]
                for k in self.ROW_KEYS
                if k in c
            }
            self.dropped += dropped
            self.version += 1
            if self.first_frame_s is None:
                self.first_frame_s = time.monotonic()
        self.last_build_s = time.perf_counter() - t0
        return True

    def scenario(self, idx: int | None = None):
        """A scenario of the window (for a new tab's session), record ``idx`` (default the latest) loaded."""
        from geoloc_viz.scenario import select_record

        with self._lock:
            if self.base is None:
                raise RuntimeError("LiveFlight.scenario: no frame has come from the stream yet")
            scn = copy.copy(self.base)
            scn.records = list(self.records)
            scn.frame_fov_deg = self.fov_deg.copy()
            scn.record_times_s = self.times_s.copy()
            select_record(scn, len(self.records) - 1 if idx is None else idx)
            return scn

    def frame_text(self, idx: int) -> str:
        """The Live folder's line for frame ``idx``: its one name (:func:`geoloc_viz.model.frame_name`:
        the timeline's index, the time, the packet, as every panel names it), the packet's UTC time,
        the replay's recomputed centre and its agreement with the packet's own, the video frame's time."""
        from geoloc.status import names
        from geoloc_viz.model import frame_name

        c = self.rows
        f = lambda v, spec: "n/a" if v is None or not np.isfinite(float(v)) else format(float(v), spec)  # noqa: E731
        st = names(np.asarray([c["status"][idx]]))[0]
        name = frame_name(SimpleNamespace(records=self.records, record_times_s=self.times_s), idx)
        text = (
            f"**{name}**, {c['time_utc'][idx]}, KLV packet at pts {f(c['pts_s'][idx], '.3f')} s  \n"
            "recomputed frame centre "
            f"{f(c['lat_deg'][idx], '.6f')}, {f(c['lon_deg'][idx], '.6f')}, h {f(c['h_m'][idx], '.1f')} m "
            f"(ellipsoidal), {st}; vs the packet's own: {f(c['frame_center_error_m'][idx], '.2f')} m"
            + (" **outlier** (causal)" if c["outlier"][idx] else "")
        )
        vt = c.get("frame_pts_s")
        if vt is not None and np.isfinite(float(vt[idx])):
            text += f"  \nvideo frame at pts {float(vt[idx]):.3f} s"
        return text


def _attach_later(session, attach) -> None:
    obj = attach(session)
    if obj is not None:
        session.layers.append(obj)


class LiveTab:
    """One tab: the Live folder, then the flight debugger of ``geoloc view`` (module docstring)."""

    def __init__(self, flight: LiveFlight, server, client):
        if not isinstance(flight.feed, LiveFeed):  # the tab shows the feed's pictures and statistics too
            raise TypeError(f"LiveTab: flight.feed is a {type(flight.feed).__name__}, not a LiveFeed")
        self.flight, self.feed = flight, flight.feed
        self.server, self.client = server, client
        self.gui = client.gui if client is not None else server.gui
        self.session: GeolocSession | None = None
        self.layer: FlightLayer | None = None  # the session's FlightLayer (from the second frame on)
        self.following = True
        self.version = -1
        self.dropped = 0
        self.closed = False
        self._drawn_s = self._followed_s = -1e9
        #: time.time() when the first frame's text was sent, and when the debugger was built
        self.first_text_unix_s: float | None = None
        self.debugger_unix_s: float | None = None
        self._build_gui()

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        g = self.gui
        with g.add_folder("Live", order=-100.0):
            self.md_title = g.add_markdown(f"**live: {self.feed.url}**: waiting for the first packet ...")
            self.md_follow = g.add_markdown("following the latest frame")
            self.bt_live = g.add_button("live", hint="Follow the latest frame again")
            self.md_frame = g.add_markdown("")
        with g.add_folder("Live: stream", order=-99.0):
            self.md_stats = g.add_markdown(self.feed.stats_markdown())
        self.bt_live.on_click(lambda _e: self.go_live())

    @property
    def n(self) -> int:
        return len(self.session.scn.records) if self.session is not None else 0

    @property
    def current(self) -> int:
        """The frame shown (index into the window), -1 before the first."""
        s = self.session
        if s is None:
            return -1
        if self.layer is not None and self.layer.current is not None:
            return int(self.layer.current)
        return -1 if s.scn.record_index is None else int(s.scn.record_index)

    def _follow_text(self) -> None:
        self.md_follow.content = (
            "following the latest frame"
            if self.following
            else "**scrubbed back**: the timeline still grows; press **live** to follow again"
        )

    def scrubbed(self, idx=None) -> None:
        """A person moved through the flight (to frame ``idx`` if known): stop following, unless it is the latest."""
        self.following = idx is not None and int(idx) >= self.n - 1
        self._follow_text()

    def go_live(self) -> None:
        """Follow the latest frame again (the **live** button)."""
        self.following = True
        self._follow_text()
        self._follow(force=True)

    def _on_user(self, event, idx_fn=None) -> None:
        if self.closed or getattr(event, "client", None) is None:  # our own updates: not a person
            return
        self.scrubbed(idx_fn() if idx_fn is not None else None)

    def _hook(self, fl) -> None:
        # before the layer's own callbacks: the following stops before the layer moves, so the
        # follower cannot step to the latest frame between the person's move and our noticing it
        _first(fl.sl_frame, lambda e: self._on_user(e, lambda: int(fl.sl_frame.value)))
        _first(fl.dd_goto, lambda e: self._on_user(e) if fl.dd_goto.value != flight_layer_choose() else None)
        _first(fl.bt_worst, lambda e: self._on_user(e))
        _first(fl.bt_play, lambda e: self._on_user(e))
        if getattr(fl, "cb_follow", None) is not None:  # the camera moves with the aircraft while following
            fl.cb_follow.value = True

    # ------------------------------------------------------------ updates
    def update(self) -> None:
        """Bring the tab up to the flight: the session built (first frame) or grown, the latest followed."""
        if self.closed:
            return
        text = self.feed.stats_markdown()
        if text != self.md_stats.content:
            self.md_stats.content = text
        fl = self.flight
        if fl.version != self.version and len(fl):
            now = time.monotonic()
            if self.session is None:
                # the first located frame's text at once; the debugger (a second or so to build) after it
                self.md_frame.content = fl.frame_text(len(fl) - 1)
                self.first_text_unix_s = time.time()
                self._flush()  # on its way before the build holds the interpreter for a second
                self._build()
                self.debugger_unix_s = time.time()
            elif now - self._drawn_s >= DRAW_S:
                self._grow()
            if now - self._drawn_s >= DRAW_S:
                self._drawn_s = now
                self.md_title.content = (
                    f"**live: {self.feed.url}**: {len(fl)} frames in the window, "
                    f"{self.feed.replay.rows_total} packets located since the start"
                )
        self._follow()
        self.refresh_text()

    def _flush(self) -> None:
        try:
            (self.client if self.client is not None else self.server).flush()
        except Exception:  # a tab that left
            pass

    def _layers(self):
        from geoloc_viz import app, flight_layer, image_layer

        def attach_flight(session):
            if len(session.scn.records) < 2:
                return None
            self.layer = flight_layer.FlightLayer(session, model=self.flight.model)
            self._hook(self.layer)
            return self.layer

        out = []
        for a in app.DEFAULT_LAYERS:
            if a is app.attach_flight:
                out.append(attach_flight)
            elif a is image_layer.attach:
                out.append(self._attach_images)
            else:
                out.append(a)
        return tuple(out)

    def _attach_images(self, session):
        from geoloc_viz import image_layer

        if not self.feed.pictures_total:  # no picture yet: attached when one is decoded
            return None
        self._images = image_layer.attach(session)
        return self._images

    def _build(self) -> None:
        from geoloc_viz.app import GeolocSession

        fl = self.flight
        with fl._lock:
            scn = fl.scenario()
            self.version, self.dropped = fl.version, fl.dropped
        self._images = None
        s = GeolocSession(self.server, scn, client=self.client, layers=self._layers())
        self.session = s
        s.dd_record.on_update(lambda e: self._on_user(e, lambda: self._record_idx()))
        if self.layer is None:  # one frame: the frame itself (the flight layer frames the whole flight)
            s.move_camera("overview")

    def _record_idx(self):
        from geoloc_viz.app import record_options

        labels = record_options(self.session.scn)
        v = self.session.dd_record.value
        return labels.index(v) if v in labels else None

    def _grow(self) -> None:
        """The session's records and the flight layer's model replaced by the flight's window."""
        from geoloc_viz import flight_layer
        from geoloc_viz.app import CUSTOM, record_options

        s, fl = self.session, self.flight
        if s is None or fl.base is None or fl.model is None:  # _build made the session from the first frame
            raise RuntimeError("LiveTab._grow: no session or no flight yet (the first frame builds them)")
        with s._lock, fl._lock:
            shift = fl.dropped - self.dropped
            self.version, self.dropped = fl.version, fl.dropped
            n = len(fl.records)
            cur = self.current
            keep = n - 1 if self.following or cur < 0 else int(np.clip(cur - shift, 0, n - 1))
            scn = s.scn
            scn.records = list(fl.records)
            # the first picture came after the session was built: its frames moved to the video's grid
            regrid = scn.camera is not fl.base.camera
            if regrid:
                scn.camera, scn.pixel_grid = fl.base.camera, getattr(fl.base, "pixel_grid", None)
            scn.frame_fov_deg = fl.fov_deg.copy()
            scn.record_times_s = fl.times_s.copy()
            if scn.record_index is not None:
                scn.record_index = int(np.clip(scn.record_index - shift, 0, n - 1))
            labels = record_options(scn)
            s._mute = True
            try:
                value = s.dd_record.value
                s.dd_record.options = labels + [CUSTOM]
                # the same record under its new frame index (the window slid by ``shift``)
                if value != CUSTOM and scn.record_index is not None:
                    value = labels[scn.record_index]
                if value in labels or value == CUSTOM:
                    # viser's value setter is not next to its getter: mypy sees the property read-only
                    s.dd_record.value = value  # type: ignore[misc]
            finally:
                s._mute = False
            if self.layer is None and n >= 2:
                self.layer = flight_layer.FlightLayer(s, model=fl.model)
                self._hook(self.layer)
                s.layers.insert(0, self.layer)
            elif self.layer is not None:
                self.layer.set_model(fl.model, current=keep)
            if getattr(self, "_images", None) is None and self.feed.pictures_total:
                from geoloc_viz import image_layer

                self._images = image_layer.attach(s)
                if self._images is not None:
                    s.layers.append(self._images)
        # scrubbed back: set_model kept the highlight on the frame shown, whose record the session still
        # has (its index shifted with the window); a person's step that raced this one ends after it
        if self.following:  # the newest frame with the new window (not a second later)
            self._follow(force=True)
        elif regrid and s.scn.record_index is not None:  # the frame shown, its pixel in the new grid
            s.load_record(s.scn.record_index, move_camera=False)

    def _follow(self, force: bool = False) -> None:
        """On the latest frame while following: its full chain, the highlight, the picture, the text."""
        s = self.session
        if s is None or not (self.following or force):
            return
        now = time.monotonic()
        if not force and now - self._followed_s < FOLLOW_S:
            return
        self._followed_s = now
        n = self.n
        if self.layer is not None:
            if self.layer.current != n - 1 or s.scn.record_index != n - 1 or force:
                with s._lock:
                    if not self.following:  # a person moved meanwhile
                        return
                    self.layer.go(n - 1)
        elif s.scn.record_index != n - 1:
            s.load_record(n - 1, move_camera=False)

    def refresh_text(self) -> None:
        """The Live folder's frame line for the frame shown (after a scrub)."""
        idx = self.current
        if (
            self.session is not None
            and 0 <= idx < min(self.n, len(self.flight.records))
            and self.dropped == self.flight.dropped
        ):  # (the same indices until the window slides)
            text = self.flight.frame_text(idx)
            if text != self.md_frame.content:
                self.md_frame.content = text

    def close(self) -> None:
        self.closed = True
        if self.session is not None:
            self.session.close()


def _first(handle, cb) -> None:
    """Run ``cb`` before a GUI handle's update (or click) callbacks, in the same thread.

    viser submits each callback of a person's update to its own thread of a pool, so a callback
    listed first is only started first: the tab's "stop following" and the layer's step raced,
    and the follower could step back to the latest frame after the person's move. The handle's
    callbacks so far become one callable that runs ``cb`` and then them, in order; the public
    ``on_update`` (last) where the list is not there."""
    cbs = getattr(getattr(handle, "_impl", None), "update_cb", None)
    if not isinstance(cbs, list):
        handle.on_update(cb)
        return
    rest = list(cbs)

    def chained(event) -> None:
        cb(event)
        for c in rest:
            c(event)

    cbs[:] = [chained]


def flight_layer_choose() -> str:
    from geoloc_viz.flight_layer import CHOOSE

    return CHOOSE


class LiveViewer:
    """The live viewer on a server: one :class:`LiveFlight` of the feed, a :class:`LiveTab` per tab.

    ``tabs`` maps client ids to tabs; :meth:`stop` ends the updates and the feed. ``dem_path`` and
    ``use_dem`` are those of :class:`LiveFlight` (``--dem``, ``--no-dem``).
    """

    def __init__(
        self,
        server,
        feed: LiveFeed,
        max_clients: int = 16,
        *,
        dem_path=None,
        use_dem: bool = True,
        dem_datum: str = "egm96",
        window: int = FLIGHT_WINDOW,
        warm: bool = True,
    ):
        self.server = server
        self.feed = feed
        self.flight = LiveFlight(feed, dem_path=dem_path, use_dem=use_dem, window=window, dem_datum=dem_datum)
        self.max_clients = int(max_clients)
        self.tabs: dict[int, LiveTab] = {}
        self._lock = threading.Lock()
        self._stop = False
        if warm:
            self.warm_up()
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)
        self._thread = threading.Thread(target=self._run, daemon=True, name="geoloc-live-tabs")
        self._thread.start()

    def warm_up(self) -> None:
        """The bundled example's first packets through the debugger's path once (its compiled
        kernels: the flight model's DEM rays, the frame's chain and iterations), so the first
        packet of the stream does not wait for a compiler."""
        from geoloc.assets import ASSETS
        from geoloc.io.klv import Packet, read_klv_file
        from geoloc_viz import flight_model
        from geoloc_viz.model import compute
        from geoloc_viz.scenario import records_from_columns
        from geoloc.workflows.live_replay import LiveReplay

        try:
            packets = [p for p in read_klv_file(ASSETS / "klv" / "example_flight.klv") if isinstance(p, Packet)][:3]
            r = LiveReplay("warm-up").add(packets)
            if r is None:
                raise ValueError("the example's first packets made no frame")
            recs, _ = records_from_columns(r.columns, r.sensor)
            probe = LiveFlight(
                _WarmFeed(r.sensor),
                dem_path=self.flight.dem_path,
                use_dem=self.flight.use_dem,
                dem_datum=self.flight.dem_datum,
            )
            scn = probe._scenario(recs)
            # the first picture's grid (use_image_grid): its module loaded now (0.35 s of imports on a quiet
            # machine, seconds under load), not while the first packet waits for its line
            from geoloc_viz.model import use_image_grid

            use_image_grid(scn, 360, 640)
            flight_model.build(scn)
            for method in ("exact", "bisect", "steps"):
                compute(scn, scn.inputs.replace(method=method))
            from geoloc.analysis.uncertainty import ce90

            ce90(1.0, 0.5)  # the uncertainty layer's CE90 table (built once per process: seconds)
        except Exception as e:  # a warm-up is an optimisation: say why it did not run, go on
            print(f"geoloc view --live: warm-up skipped ({type(e).__name__}: {e})", file=sys.stderr)

    def _on_connect(self, client) -> None:
        with self._lock:
            if len(self.tabs) >= self.max_clients:
                client.gui.add_markdown(f"this viewer serves {self.max_clients} tabs at most (--max-clients)")
                return
            client.scene.set_up_direction("+z")
            self.tabs[client.client_id] = LiveTab(self.flight, self.server, client)

    def _on_disconnect(self, client) -> None:
        with self._lock:
            tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()

    def _run(self) -> None:
        while not self._stop:
            t0 = time.monotonic()
            try:
                self.flight.update()
            except Exception as e:  # a bug must not stop the stream: said on stderr and in the panel
                self.feed.error = f"flight model: {type(e).__name__}: {e}"
                print(f"geoloc view --live: {self.feed.error}", file=sys.stderr)
            with self._lock:
                tabs = list(self.tabs.values())
            for tab in tabs:
                try:
                    tab.update()
                except Exception as e:  # a tab that left while we drew: dropped on its disconnect
                    if not tab.closed:
                        import traceback

                        print(f"geoloc view --live: tab update: {type(e).__name__}: {e}", file=sys.stderr)
                        traceback.print_exc(file=sys.stderr)
            time.sleep(max(UPDATE_S - (time.monotonic() - t0), 0.02))

    def stop(self) -> None:
        self._stop = True
        self._thread.join(10)
        self.feed.stop()


class _WarmFeed:
    """What :meth:`LiveFlight._scenario` reads of a feed, for the warm-up."""

    url = "warm-up"
    decode_video = False
    video_size = None

    def __init__(self, sensor):
        self.sensor = sensor

    def take_batches(self) -> list:
        return []
