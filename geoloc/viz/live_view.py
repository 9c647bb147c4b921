"""``geoloc view --live udp://HOST:PORT``: the flight debugger following a flight as it flies.

A :class:`LiveFeed` (one per viewer, shared by its tabs) receives the stream on a
thread (:func:`geoloc.io.live.receive`) and replays every batch of KLV packets as it
arrives (:class:`geoloc.workflows.live_replay.LiveReplay`: each packet's frame centre
and corners from its own pose, compared with the packet's own), keeping a rolling
window of rows; with ``journal`` / ``record`` it journals the rows and the raw stream.
With video in the stream it decodes the frames as they come (PyAV) and keeps the
last few, so the current packet shows the nearest-timestamp picture.

Each browser tab gets a :class:`LiveTab` (its own ``client.scene`` / ``client.gui``):

* the scene, in a local ENU frame at the first packet's frame centre (km, as the
  rest of the viewer): the track, every frame's footprint (outliers red), the
  recomputed (red) and reported (violet) frame centres, and the current frame's
  footprint (magenta), line of sight and aircraft;
* a **Live** folder: the timeline (a frame slider that grows as packets arrive),
  "following the latest frame" until the user scrubs back, a **live** button that
  returns to it, the current frame's text and (with video) its picture;
* **Live: stream**: what arrived and what was lost (:meth:`geoloc.io.live.LiveStats.markdown`);
* **Live: outliers first** and **Live: accuracy** over the window.

The tabs are updated by one thread a few times a second; each update sends only
what changed (the batched nodes when new packets came, the highlight otherwise).
Heights ellipsoidal (WGS 84). Conventions: ``docs/conventions.md``; guide: ``docs/live.md``.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque

import numpy as np

from geoloc.frames.enu import EnuFrame
from geoloc.viz.flight_layer import COLORS as FLIGHT_COLORS
from geoloc.viz.scene_geoloc import WORLD_SCALE

ROOT = "/live"
#: The flight debugger's colours for what both draw (one legend), and the live view's own
COLORS = {**{k: FLIGHT_COLORS[k] for k in ("track", "footprint", "footprint_outlier", "current", "recomputed",
                                           "reported")},
          "los": (255, 230, 0), "aircraft": (255, 255, 255)}
#: Frames drawn in the scene (the newest): bounds the messages sent to a browser.
SCENE_FRAMES = 2000
#: Tabs are updated at most this often [s] (the current frame, the slider, the texts) ...
UPDATE_S = 0.2
#: ... the batched nodes (track, footprints, points: all frames) and the tables at most this often [s] ...
DRAW_S = 1.0
#: ... and the picture at most this often [s] (a JPEG each time).
PICTURE_S = 0.5
#: Decoded pictures kept (the newest), and their width [pixels].
PICTURES = 64
PICTURE_WIDTH = 480
TOP_N = 10

_LIFT_M = 8.0  # display only: outlines above the ground they lie on, so the depth test shows them


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

    def __init__(self, url, *, sensor=None, surface=None, limits=None, journal=None, record=None,
                 decode_video: bool = True, window: int | None = None, sock=None):
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
        self.replay = LiveReplay(self.url, surface=surface, sensor=sensor, journal=journal,
                                 receiver=self.rx, window=window or WINDOW)
        self.limits = dict(limits or {})
        self.record = record
        self.decode_video = decode_video
        self.version = 0  # bumped by every batch with a located packet
        self.first_row_s: float | None = None  # time.monotonic() of the first located packet
        self.error: str = ""
        self.done = False
        self._lock = threading.Lock()
        self._stop = False
        self._cols: dict = {}
        self._thread: threading.Thread | None = None
        self._decoder = None
        self._video_done = 0
        self.pictures: deque = deque(maxlen=PICTURES)  # (pts, RGB uint8 array)

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
            for _ in receive(self.url, receiver=self.rx, record=self.record, on_batch=self._batch,
                             stop=lambda: self._stop, sock=self.sock, **self.limits):
                pass
        except Exception as e:  # a bind that fails, a bug: shown in the panel, never a dead viewer
            self.error = f"{type(e).__name__}: {e}"
            print(f"geoloc view --live: {self.error}", file=sys.stderr)
        finally:
            self.done = True

    def _batch(self, results) -> None:
        r = self.replay.add(results)
        if self.decode_video:
            self._decode()
        if r is None:
            return
        cols = self.replay.columns()
        with self._lock:
            self._cols = cols
            self.version += 1
            if self.first_row_s is None:
                self.first_row_s = time.monotonic()

    def _decode(self) -> None:
        """Decode the video access units that came since the last call (newest pictures kept)."""
        import av

        video = self.rx.video
        n_new = self.rx.stats.video_units - self._video_done
        if n_new <= 0:
            return
        self._video_done = self.rx.stats.video_units
        units = list(video)[-min(n_new, len(video)):]
        try:
            if self._decoder is None:
                from geoloc.io.live import _STREAM_TYPES_VIDEO

                stype = self.rx.demux.streams.get(units[0][2], ("video", 0x1B))[1]
                self._decoder = av.CodecContext.create(_STREAM_TYPES_VIDEO.get(stype, "h264"), "r")
            for pts, data, _pid in units:
                if data is None:
                    continue
                for pkt in self._decoder.parse(data):
                    pkt.pts = pts
                    for fr in self._decoder.decode(pkt):
                        w = PICTURE_WIDTH
                        h = max(2, round(fr.height * w / max(fr.width, 1)) // 2 * 2)
                        img = fr.to_ndarray(format="rgb24", width=w, height=h)
                        self.pictures.append((fr.pts if fr.pts is not None else pts, img))
        except (av.error.FFmpegError, ValueError) as e:  # a broken access unit: the next key frame recovers
            self._decoder = None if "codec" in str(e).lower() else self._decoder

    def picture_at(self, pts_s: float):
        """The decoded picture nearest ``pts_s`` [s] (None without video)."""
        if not self.pictures or not np.isfinite(pts_s):
            return None
        t = pts_s * 90000.0
        return min(list(self.pictures), key=lambda p: abs((p[0] if p[0] is not None else 0) - t))[1]

    def snapshot(self) -> tuple[int, dict]:
        """(version, columns of the window) at one instant."""
        with self._lock:
            return self.version, self._cols


class LiveTab:
    """One tab's live scene and GUI (see the module docstring)."""

    def __init__(self, feed: LiveFeed, scene, gui, client=None):
        self.feed = feed
        self.scene, self.gui, self.client = scene, gui, client
        self.enu: EnuFrame | None = None
        self.following = True
        self.current = -1
        self.version = -1
        self.n = 0
        self.cols: dict = {}
        self.closed = False
        self._mute = False
        self._camera_set = False
        self._nodes: dict = {}
        self._drawn_s = -1e9
        self._drawn_n = 0
        self._picture_s = -1e9
        self._build_gui()

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        g = self.gui
        self.md_title = g.add_markdown(f"**live: {self.feed.url}**: waiting for the first packet ...")
        with g.add_folder("Live"):
            self.md_follow = g.add_markdown("following the latest frame")
            self.sl_frame = g.add_slider("frame", 0, 1, 1, 0, disabled=True,
                                         hint="Scrub back through the frames received; 'live' returns")
            self.bt_live = g.add_button("live", hint="Follow the latest frame again")
            self.md_frame = g.add_markdown("")
            self.img = None
        with g.add_folder("Live: stream"):
            self.md_stats = g.add_markdown(self.feed.rx.stats.markdown())
        with g.add_folder("Live: outliers first"):
            self.md_table = g.add_markdown("")
        with g.add_folder("Live: accuracy"):
            self.md_accuracy = g.add_markdown("")
        self.sl_frame.on_update(self._on_slider)
        self.bt_live.on_click(lambda _e: self.go_live())

    def _on_slider(self, event=None) -> None:
        # a person moved it (the event names a client); our own updates (client None) are not a scrub
        if self.closed or self.n == 0 or (event is not None and getattr(event, "client", None) is None):
            return
        idx = int(self.sl_frame.value)
        self.following = idx >= self.n - 1
        self._follow_text()
        self.highlight(idx)

    def go_live(self) -> None:
        """Follow the latest frame again (the **live** button)."""
        self.following = True
        self._follow_text()
        if self.n:
            self._set_slider(self.n - 1)
            self.highlight(self.n - 1)

    def _follow_text(self) -> None:
        self.md_follow.content = ("following the latest frame" if self.following else
                                  "**scrubbed back**: the timeline still grows; press **live** to follow again")

    def _set_slider(self, idx: int) -> None:
        self._mute = True
        try:
            if self.sl_frame.max != max(self.n - 1, 1):
                self.sl_frame.max = max(self.n - 1, 1)
            self.sl_frame.disabled = self.n < 2
            if int(self.sl_frame.value) != idx:
                self.sl_frame.value = idx
        finally:
            self._mute = False

    # ------------------------------------------------------------ updates
    def update(self) -> None:
        """Bring the tab up to the feed: new frames drawn, the slider grown, the latest frame followed."""
        if self.closed:
            return
        text = self.feed.rx.stats.markdown() + (f"\n\n**error**: {self.feed.error}" if self.feed.error else "")
        if text != self.md_stats.content:
            self.md_stats.content = text
        version, cols = self.feed.snapshot()
        if version == self.version or not cols:
            return
        self.version = version
        self.cols = cols
        self.n = len(cols["packet"])
        if self.enu is None:
            ok = np.isfinite(cols["lat_deg"])
            k = int(np.argmax(ok)) if ok.any() else 0
            la, lo, h = (cols["lat_deg"][k], cols["lon_deg"][k], cols["h_m"][k]) if ok.any() else \
                (cols["sensor_lat_deg"][k], cols["sensor_lon_deg"][k], 0.0)
            self.enu = EnuFrame.scene_origin(float(la), float(lo), float(h))
        now = time.monotonic()
        if now - self._drawn_s >= DRAW_S or self._drawn_n == 0:  # the batched nodes: at most once a DRAW_S
            self._draw()
            self._drawn_s, self._drawn_n = now, self.n
            self.md_table.content = self._table()
            self.md_accuracy.content = self._accuracy()
        self.md_title.content = (f"**live: {self.feed.url}**: {self.n} frames in the window, "
                                 f"{self.feed.replay.rows_total} located since the start")
        if self.following or self.current < 0:
            self._set_slider(self.n - 1)
            self.highlight(self.n - 1)
        else:
            self._set_slider(min(self.current, self.n - 1))
        if not self._camera_set:
            self._camera_set = self._frame_camera()

    def _enu(self, lat, lon, h):
        lat, lon, h = (np.asarray(x, float) for x in (lat, lon, h))
        return self.enu.from_geodetic(np.radians(lat), np.radians(lon), np.where(np.isfinite(h), h, 0.0))

    def _pts(self):
        c = self.cols
        sl = slice(max(self.n - SCENE_FRAMES, 0), self.n)
        track = self._enu(c["sensor_lat_deg"][sl], c["sensor_lon_deg"][sl], c["sensor_h_m"][sl])
        rec = self._enu(c["lat_deg"][sl], c["lon_deg"][sl], c["h_m"][sl])
        rep = self._enu(c["reported_lat_deg"][sl], c["reported_lon_deg"][sl], c["reported_h_m"][sl])
        corners = np.stack([self._enu(c[f"corner{j}_lat_deg"][sl], c[f"corner{j}_lon_deg"][sl],
                                      c[f"corner{j}_h_m"][sl]) for j in (1, 2, 3, 4)], axis=1)
        return sl, track, rec, rep, corners

    def _draw(self) -> None:
        s, W = self.scene, WORLD_SCALE
        sl, track, rec, rep, corners = self._pts()
        out = np.asarray(self.cols["outlier"][sl], bool)
        f32 = lambda a: (np.nan_to_num(np.asarray(a, float)) * W).astype(np.float32)  # noqa: E731
        s.add_frame(ROOT, show_axes=False)
        if len(track) > 1:
            seg = np.stack([track[:-1], track[1:]], axis=1)
            ok = np.all(np.isfinite(seg), axis=(1, 2))
            if ok.any():
                s.add_line_segments(f"{ROOT}/track", f32(seg[ok]), COLORS["track"], thickness=2.0,
                                    thickness_units="screen")
        ring = corners + np.array([0.0, 0.0, _LIFT_M])
        seg = np.stack([ring, np.roll(ring, -1, axis=1)], axis=2).reshape(-1, 2, 3)
        col = np.where(np.repeat(out, 4)[:, None], COLORS["footprint_outlier"], COLORS["footprint"]).astype(np.uint8)
        ok = np.all(np.isfinite(seg), axis=(1, 2))
        if ok.any():
            s.add_line_segments(f"{ROOT}/footprints", f32(seg[ok]), np.repeat(col[ok, None], 2, axis=1),
                                thickness=1.0, thickness_units="screen")
        extent = np.nanmax(np.ptp(np.nan_to_num(track[:, :2]), axis=0)) if len(track) > 1 else 1e3
        self.point_size = float(np.clip(extent / 150.0, 15.0, 400.0)) * W
        for name, pts in (("recomputed", rec), ("reported", rep)):
            ok = np.all(np.isfinite(pts), axis=1)
            if ok.any():
                s.add_point_cloud(f"{ROOT}/{name}", f32(pts[ok]), COLORS[name], point_size=self.point_size,
                                  point_shape="circle", precision="float32")

    def highlight(self, idx: int) -> None:
        """Frame ``idx`` of the window: its footprint magenta, its line of sight, its text and picture."""
        if self.n == 0:
            return
        idx = int(np.clip(idx, 0, self.n - 1))
        self.current = idx
        c, W = self.cols, WORLD_SCALE
        corners = np.stack([self._enu(c[f"corner{j}_lat_deg"][idx], c[f"corner{j}_lon_deg"][idx],
                                      c[f"corner{j}_h_m"][idx]) for j in (1, 2, 3, 4)])
        ring = corners + np.array([0.0, 0.0, 2 * _LIFT_M])
        seg = (np.nan_to_num(np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)) * W).astype(np.float32)
        ac = self._enu(c["sensor_lat_deg"][idx], c["sensor_lon_deg"][idx], c["sensor_h_m"][idx])
        hit = self._enu(c["lat_deg"][idx], c["lon_deg"][idx], c["h_m"][idx])
        los = (np.nan_to_num(np.stack([ac, np.where(np.isfinite(hit), hit, ac)])[None]) * W).astype(np.float32)
        h = self._nodes
        if not h:  # made once, then moved: a step sends a few numbers, not new nodes
            h["current"] = self.scene.add_line_segments(f"{ROOT}/current", seg, COLORS["current"], thickness=6.0,
                                                        thickness_units="screen")
            h["aircraft"] = self.scene.add_icosphere(f"{ROOT}/aircraft", radius=self.point_size * 0.8,
                                                     color=COLORS["aircraft"], position=tuple(los[0, 0]))
            h["los"] = self.scene.add_line_segments(f"{ROOT}/los", los, COLORS["los"], thickness=3.0,
                                                    thickness_units="screen")
        else:
            h["current"].points = seg
            h["aircraft"].position = tuple(float(x) for x in los[0, 0])
            h["los"].points = los
        self.md_frame.content = self._frame_text(idx)
        self._picture(idx)

    def _picture(self, idx: int) -> None:
        t = float(self.cols["frame_pts_s"][idx]) if "frame_pts_s" in self.cols else float("nan")
        if not np.isfinite(t):
            t = float(self.cols["pts_s"][idx])
        now = time.monotonic()
        if self.img is not None and now - self._picture_s < PICTURE_S:
            return
        img = self.feed.picture_at(t)
        if img is None:
            return
        self._picture_s = now
        if self.img is None:
            with self.gui.add_folder("Live: picture"):
                self.img = self.gui.add_image(img, label="nearest video frame", format="jpeg")
        else:
            self.img.image = img

    def _frame_text(self, idx: int) -> str:
        from geoloc.status import names

        c = self.cols
        f = lambda v, spec: "n/a" if not np.isfinite(float(v)) else format(float(v), spec)  # noqa: E731
        st = names(np.asarray([c["status"][idx]]))[0]
        text = (f"**packet {int(c['packet'][idx])}** (frame {idx + 1} of {self.n}), {c['time_utc'][idx]}, "
                f"pts {f(c['pts_s'][idx], '.3f')} s  \nrecomputed frame centre {f(c['lat_deg'][idx], '.6f')}, "
                f"{f(c['lon_deg'][idx], '.6f')}, h {f(c['h_m'][idx], '.1f')} m (ellipsoidal), {st}  \n"
                f"vs the packet's own: {f(c['frame_center_error_m'][idx], '.2f')} m; corners "
                f"{f(c['corner_error_m'][idx], '.2f')} m" + ("  \n**outlier**" if c["outlier"][idx] else ""))
        vt = c.get("frame_pts_s")
        if vt is not None and np.isfinite(float(vt[idx])):
            text += f"  \nvideo frame at pts {float(vt[idx]):.3f} s"
        return text

    def _table(self) -> str:
        c = self.cols
        err = np.asarray(c["frame_center_error_m"], float)
        order = np.argsort(np.where(np.isfinite(err), -err, np.inf), kind="stable")[:TOP_N]
        L = ["frames by frame-centre error (recomputed vs the packet's own, horizontal)  ", "",
             "| # | packet | error m | corners m | flag |", "|---|---|---|---|---|"]
        for r, i in enumerate(order, 1):
            if not np.isfinite(err[i]):
                break
            L.append(f"| {r} | {int(c['packet'][i])} | {err[i]:.1f} | {float(c['corner_error_m'][i]):.1f} | "
                     f"{'**outlier**' if c['outlier'][i] else ''} |")
        return "\n".join(L)

    def _accuracy(self) -> str:
        c = self.cols
        err = np.asarray(c["frame_center_error_m"], float)
        fin = err[np.isfinite(err)]
        if not len(fin):
            return "no frame compared yet"
        return (f"**frame centre, recomputed vs the packet's own** ({len(fin)} frames in the window; heights "
                f"ellipsoidal)  \nmedian {np.median(fin):.2f} m, 90th percentile {np.percentile(fin, 90):.2f} m, "
                f"max {np.max(fin):.2f} m  \nrobust outliers (causal median / MAD rule): "
                f"{int(np.sum(np.asarray(c['outlier'], bool)))}")

    def _frame_camera(self) -> bool:
        if self.client is None:
            return True
        c = self.cols
        i = self.n - 1
        ac = self._enu(c["sensor_lat_deg"][i], c["sensor_lon_deg"][i], c["sensor_h_m"][i])
        hit = self._enu(c["lat_deg"][i], c["lon_deg"][i], c["h_m"][i])
        if not (np.all(np.isfinite(ac)) and np.all(np.isfinite(hit))):
            return False
        d = ac - hit
        pos = (hit + 1.3 * d + np.array([0.3 * d[1], -0.3 * d[0], 0.2 * abs(d[2])])) * WORLD_SCALE
        with self.client.atomic():
            self.client.camera.up_direction = (0.0, 0.0, 1.0)
            self.client.camera.position = tuple(float(x) for x in pos)
            self.client.camera.look_at = tuple(float(x) for x in hit * WORLD_SCALE)
        return True

    def close(self) -> None:
        self.closed = True


class LiveViewer:
    """The live viewer on a server: a :class:`LiveTab` per tab, all fed by one :class:`LiveFeed`.

    ``tabs`` maps client ids to tabs; :meth:`stop` ends the updates and the feed.
    """

    def __init__(self, server, feed: LiveFeed, max_clients: int = 16):
        self.server = server
        self.feed = feed
        self.max_clients = int(max_clients)
        self.tabs: dict[int, LiveTab] = {}
        self._lock = threading.Lock()
        self._stop = False
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)
        self._thread = threading.Thread(target=self._run, daemon=True, name="geoloc-live-tabs")
        self._thread.start()

    def _on_connect(self, client) -> None:
        with self._lock:
            if len(self.tabs) >= self.max_clients:
                client.gui.add_markdown(f"this viewer serves {self.max_clients} tabs at most (--max-clients)")
                return
            client.scene.set_up_direction("+z")
            tab = LiveTab(self.feed, client.scene, client.gui, client)
            self.tabs[client.client_id] = tab
        tab.update()

    def _on_disconnect(self, client) -> None:
        with self._lock:
            tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()

    def _run(self) -> None:
        while not self._stop:
            t0 = time.monotonic()
            with self._lock:
                tabs = list(self.tabs.values())
            for tab in tabs:
                try:
                    tab.update()
                except Exception as e:  # a tab that left while we drew: dropped on its disconnect
                    if not tab.closed:
                        print(f"geoloc view --live: tab update: {type(e).__name__}: {e}", file=sys.stderr)
            time.sleep(max(UPDATE_S - (time.monotonic() - t0), 0.02))

    def stop(self) -> None:
        self._stop = True
        self._thread.join(5)
        self.feed.stop()
