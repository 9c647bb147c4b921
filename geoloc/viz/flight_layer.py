"""The viewer as a whole-flight debugger: a layer that attaches to a ``geoloc view`` session.

:func:`attach` (``attach(session)``, a layer of :class:`geoloc.viz.app.GeolocSession`) draws the
flight of the session's scenario (:func:`geoloc.viz.flight_model.build`, one batch for all
frames) and adds a **Flight** GUI folder:

* scene (one node each, batched): the track, every frame's footprint (outliers red), the
  frame centres, the reported / recomputed / truth points and the error vectors; the current
  frame's footprint highlighted in magenta (``/flight/current``);
* a **timeline**: a frame slider, play / pause and a speed; moving it loads that frame into the
  session (``session.load_record(idx)``: its full chain, line of sight and iterations, as
  one record) and moves only the highlight (the batched nodes are never rebuilt);
* the **outliers**: the frames sorted by residual as a markdown table, with the robust flags,
  and a "go to" dropdown that jumps the timeline and the camera (``session.move_camera``) to
  the chosen frame;
* what the outlier runs look like (:func:`geoloc.viz.flight_model.diagnose`) and the flight's
  **accuracy** (:mod:`geoloc.analysis.accuracy`).

Scene nodes live under ``/flight``, a frame whose pose is the flight model's ENU frame in the
session's scene frame (the session's ENU origin moves with the record: one node update, the
children stay). World unit: the km, as the rest of the scene (:data:`geoloc.viz.scene_geoloc.WORLD_SCALE`);
vertical exaggeration: a (1, 1, v) node scale, as the terrain. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import inspect
import threading
import time

import numpy as np

from geoloc.viz import flight_model
from geoloc.viz.scene_geoloc import WORLD_SCALE, wxyz

ROOT = "/flight"
#: Colours (RGB 0-255). The highlight is pure magenta: nothing else in the scene has it
#: (the terrain's gist_earth colours, the pink error (255, 90, 200) and violet published (180, 80, 255)
#: all have green > 60), so a browser test can find it by pixel statistics.
COLORS = {
    "track": (90, 200, 255),
    "footprint": (205, 150, 70),
    "footprint_outlier": (235, 50, 50),
    "current": (255, 0, 255),
    "centre": (255, 230, 120),
    "reported": (180, 80, 255),
    "recomputed": (255, 60, 60),
    "truth": (255, 255, 255),
    "error": (255, 90, 200),
}
TOP_N = 12
#: Display-only lift of the draped outlines above the terrain mesh [m], so the depth test does not
#: hide lines that lie on it (the mesh resamples the DEM: it is tens of metres off between nodes).
LIFT_M = {"footprints": 8.0, "current": 25.0}
CHOOSE = "(choose a frame)"

_CACHE: dict = {}  # id(records) -> (records, model): one model per scenario, shared by every tab


def model_for(scn, **kw) -> flight_model.FlightModel:
    """The flight model of ``scn`` (built once per records list; tabs share their scenario's records)."""
    key = (id(scn.records), id(getattr(scn, "dem", None)))
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is scn.records:
        return hit[1]
    m = flight_model.build(scn, **kw)
    if len(_CACHE) > 8:
        _CACHE.clear()
    _CACHE[key] = (scn.records, m)
    return m


def _scene(session):
    return getattr(session, "scene", None) or session.server.scene


def _gui(session):
    return getattr(session, "gui", None) or session.server.gui


class FlightLayer:
    """The flight nodes and the Flight GUI of one session (see the module docstring).

    Parameters
    ----------
    session : GeolocSession (or the older GeolocApp)
    model : FlightModel, optional
        Default :func:`model_for` the session's scenario.
    top_n : int
        Rows of the outlier table and entries of the "go to" dropdown.
    """

    def __init__(self, session, model: flight_model.FlightModel | None = None, top_n: int = TOP_N):
        self.session = session
        self.scene = _scene(session)
        self.gui = _gui(session)
        self.model = model if model is not None else model_for(session.scn)
        self.top_n = int(top_n)
        self.current = None
        self.closed = False
        self._mute = False
        self._playing = False
        self._thread = None
        self._enu_key = None
        self.last_step_s = float("nan")
        self.handles = {}
        self._draw()
        self._build_gui()
        self._follow_session()
        idx = session.scn.record_index
        self.highlight(0 if idx is None else int(idx))

    # ------------------------------------------------------------ scene
    def _disp(self):
        view = getattr(self.session, "view", None)
        return getattr(view, "disp", None)

    def _vexag(self) -> float:
        d = self._disp()
        return float(getattr(d, "vertical_exaggeration", 1.0)) if d is not None else 1.0

    def _draw(self) -> None:
        m, s, W = self.model, self.scene, WORLD_SCALE
        extent = np.nanmax(np.ptp(np.nan_to_num(m.track_enu[:, :2]), axis=0)) if len(m) > 1 else 1e3
        self.point_size = float(np.clip(extent / 150.0, 15.0, 400.0)) * W  # display only: km
        f32 = lambda a: (np.nan_to_num(np.asarray(a, float)) * W).astype(np.float32)
        self.handles["root"] = s.add_frame(ROOT, show_axes=False)
        if len(m) > 1:
            self.handles["track"] = s.add_line_segments(f"{ROOT}/track", f32(m.track_segments()), COLORS["track"],
                                                        thickness=2.0, thickness_units="screen")
        seg = m.footprint_segments() + np.array([0.0, 0.0, LIFT_M["footprints"]])
        P = m.footprint_enu.shape[1]
        col = np.where(np.repeat(m.outlier, P)[:, None], COLORS["footprint_outlier"], COLORS["footprint"])
        good = np.all(np.isfinite(seg), axis=(1, 2))
        self.handles["footprints"] = s.add_line_segments(
            f"{ROOT}/footprints", f32(seg[good]), np.repeat(col[good, None].astype(np.uint8), 2, axis=1),
            thickness=1.0, thickness_units="screen")
        for name, pts in (("centres", m.centre_enu), ("reported", m.reported_enu),
                          ("recomputed", m.recomputed_enu), ("truth", m.truth_enu)):
            ok = np.all(np.isfinite(pts), axis=1)
            if ok.any():
                self.handles[name] = s.add_point_cloud(
                    f"{ROOT}/{name}", f32(pts[ok]), COLORS["centre" if name == "centres" else name],
                    point_size=self.point_size * (0.6 if name == "centres" else 1.0), point_shape="circle",
                    precision="float32")
        err = m.error_segments()
        ok = np.all(np.isfinite(err), axis=(1, 2))
        if ok.any():
            self.handles["errors"] = s.add_line_segments(f"{ROOT}/errors", f32(err[ok]), COLORS["error"],
                                                         thickness=2.5, thickness_units="screen")
        self.handles["current"] = s.add_line_segments(
            f"{ROOT}/current", np.zeros((P, 2, 3), np.float32), COLORS["current"], thickness=6.0,
            thickness_units="screen")
        self.handles["label"] = s.add_label(f"{ROOT}/current/label", "", position=(0.0, 0.0, 0.0),
                                            anchor="bottom-left")
        self._place_root()

    def _place_root(self) -> None:
        """Pose ``/flight`` (the model's ENU frame) in the session's scene frame; scale Up."""
        scene_enu, F = self.session.scn.enu, self.model.enu
        v = self._vexag()
        key = (scene_enu, v)
        if key == self._enu_key:
            return
        self._enu_key = key
        t = scene_enu.from_ecef(F.origin_ecef)
        R = scene_enu.R_enu_ecef @ F.R_ecef_enu
        self.handles["root"].position = tuple(t * WORLD_SCALE * np.array([1.0, 1.0, v]))
        self.handles["root"].wxyz = tuple(wxyz(R))
        for k, h in self.handles.items():
            if k not in ("root", "label"):
                h.scale = (1.0, 1.0, v)

    def highlight(self, idx: int) -> None:
        """Move the highlight to frame ``idx`` (the current footprint and its label): small messages only."""
        m = self.model
        idx = int(np.clip(idx, 0, len(m) - 1))
        t0 = time.perf_counter()
        self.current = idx
        self._place_root()
        ring = m.footprint_enu[idx] + np.array([0.0, 0.0, LIFT_M["current"]])
        seg = np.nan_to_num(np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)) * WORLD_SCALE
        self.handles["current"].points = seg.astype(np.float32)
        c = m.centre_enu[idx]
        lab = self.handles["label"]
        if np.all(np.isfinite(c)):
            v = self._vexag()
            lab.position = tuple(c * WORLD_SCALE * np.array([1.0, 1.0, v]))
        res = m.residual_m[idx]
        f = m.fault_of(idx)
        lab.text = (f"{m.labels[idx]}: residual {res:.1f} m" if np.isfinite(res) else m.labels[idx]) + \
            (f" ({f.kind})" if f is not None else "")
        if hasattr(self, "md_frame"):
            self.md_frame.content = self._frame_text(idx)
        self.last_step_s = time.perf_counter() - t0

    def _frame_text(self, idx: int) -> str:
        m, c = self.model, self.model.components
        f = m.fault_of(idx)
        text = (f"**{m.labels[idx]}** (frame {idx + 1} of {len(m)}): residual {m.residual_m[idx]:.2f} m "
                f"(recomputed vs {m.reference}, horizontal); along {c['along_m'][idx]:+.1f}, across "
                f"{c['across_m'][idx]:+.1f}, up {c['up_m'][idx]:+.1f} m"
                + (" **outlier**" if m.outlier[idx] else ""))
        if f is not None:
            text += f"  \nrun: {f.headline()}"
        return text

    # ------------------------------------------------------------ GUI
    def _order(self, k: int):
        """GUI order of our k-th folder: right under the session's summary (a flight first), else last."""
        head = getattr(self.session, "md_summary", None)
        base = getattr(head, "order", None)
        return None if base is None else float(base) + 0.01 * (k + 1)

    def _build_gui(self) -> None:
        g, m = self.gui, self.model
        n = len(m)
        with g.add_folder("Flight", order=self._order(0)):
            self.md_head = g.add_markdown(
                f"**{n} frames**, footprints on {m.surface.split(' (')[0]}. **magenta**: the current frame; "
                "**red** outlines: outliers; **blue**: track; points **violet** / **red** / **white**: "
                "reported / recomputed / truth; **pink**: error vectors (true length)")
            self.sl_frame = g.add_slider("frame", 0, max(n - 1, 1), 1, 0, disabled=n < 2,
                                         hint="Scrub through the frames; each loads as the current record")
            self.bt_play = g.add_button("play", hint="Play / pause the timeline")
            self.num_fps = g.add_number("frames per second", 2.0, min=0.2, max=30.0, step=0.1)
            self.md_frame = g.add_markdown("")
        with g.add_folder("Flight: outliers first", order=self._order(1)):
            top = m.top(self.top_n)
            self.top_idx = [int(i) for i in top]
            self.opts = [f"{r}. {m.labels[i]} ({m.residual_m[i]:.1f} m)" for r, i in enumerate(self.top_idx, 1)]
            self.dd_goto = g.add_dropdown("go to", [CHOOSE] + self.opts, initial_value=CHOOSE,
                                          hint="Jump the timeline and the camera to this frame")
            self.md_table = g.add_markdown(m.outlier_markdown(self.top_n))
        with g.add_folder("Flight: what the outliers look like", order=self._order(2)):
            self.md_faults = g.add_markdown(m.faults_markdown())
        with g.add_folder("Flight: accuracy", expand_by_default=False, order=self._order(3)):
            self.md_accuracy = g.add_markdown(m.summary_markdown())
        self.sl_frame.on_update(lambda _e: self._on_slider())
        self.bt_play.on_click(lambda _e: self.toggle_play())
        self.dd_goto.on_update(lambda _e: self._on_goto())

    def _on_slider(self) -> None:
        if self._mute or self.closed:
            return
        self.go(int(self.sl_frame.value))

    def _on_goto(self) -> None:
        if self._mute or self.closed or self.dd_goto.value == CHOOSE:
            return
        idx = self.top_idx[self.opts.index(self.dd_goto.value)]
        self.go(idx, camera=True)

    # ------------------------------------------------------------ moving through the flight
    def _load(self, idx: int) -> None:
        s = self.session
        if s.scn.record_index == idx:
            return
        fn = s.load_record
        try:
            takes_camera = "move_camera" in inspect.signature(fn).parameters
        except (TypeError, ValueError):
            takes_camera = False
        fn(idx, move_camera=False) if takes_camera else fn(idx)

    def go(self, idx: int, camera: bool = False) -> None:
        """Frame ``idx``: load it into the session, move the highlight, sync the slider (and the camera)."""
        idx = int(np.clip(idx, 0, len(self.model) - 1))
        self._load(idx)
        self.highlight(idx)
        if int(self.sl_frame.value) != idx:
            self._mute = True
            try:
                self.sl_frame.value = idx
            finally:
                self._mute = False
        if camera:
            self.move_camera_to(idx)

    def camera_pose(self, idx: int):
        """(position, look_at) in scene units (km) framing frame ``idx``: its footprint from the aircraft's side."""
        m = self.model
        scene_enu = self.session.scn.enu
        v = np.array([1.0, 1.0, self._vexag()]) * WORLD_SCALE
        F = m.enu

        def to_scene(p):
            return scene_enu.from_ecef(F.to_ecef(p)) * v

        c = m.centre_enu[idx] if np.all(np.isfinite(m.centre_enu[idx])) else m.recomputed_enu[idx]
        aim, a = to_scene(c), to_scene(m.track_enu[idx])
        L = max(float(np.linalg.norm(a - aim)), 1e-3)
        horiz = (a - aim)[:2]
        u = np.r_[horiz / max(np.linalg.norm(horiz), 1e-9), 0.0]
        side = np.array([-u[1], u[0], 0.0])
        pos = aim + 0.55 * L * u + 0.25 * L * side + np.array([0.0, 0.0, 0.45 * L])
        return pos, aim

    def move_camera_to(self, idx: int) -> None:
        pos, aim = self.camera_pose(idx)
        s = self.session
        if hasattr(s, "move_camera"):
            try:
                s.move_camera((pos, aim))
                return
            except (TypeError, ValueError):
                pass
        for client in s.server.get_clients().values():  # the older app: every tab
            with client.atomic():
                client.camera.up_direction = (0.0, 0.0, 1.0)
                client.camera.look_at = tuple(aim)
                client.camera.position = tuple(pos)

    def toggle_play(self) -> None:
        """Start or pause the timeline (a daemon thread steps ``frames per second``)."""
        if self._playing:
            self._playing = False
            self.bt_play.label = "play"
            return
        self._playing = True
        self.bt_play.label = "pause"
        self._thread = threading.Thread(target=self._play, daemon=True, name="geoloc-flight-timeline")
        self._thread.start()

    def _play(self) -> None:
        while self._playing and not self.closed:
            t0 = time.monotonic()
            nxt = (self.current + 1) % len(self.model)
            try:
                self.go(nxt)
            except (RuntimeError, KeyError, ValueError):  # the tab left (its handles are gone): stop
                self._playing = False
                break
            dt = 1.0 / max(float(self.num_fps.value), 1e-3)
            time.sleep(max(dt - (time.monotonic() - t0), 0.0))

    # ------------------------------------------------------------ session hooks
    def _follow_session(self) -> None:
        s = self.session
        if hasattr(s, "on_record"):
            s.on_record(self._on_session_record)
        if hasattr(s, "on_refresh"):
            s.on_refresh(lambda _g: self._place_root())

    def _on_session_record(self, idx) -> None:
        # the record dropdown (or our own go()) loaded a frame: follow it
        if idx is None or self.closed:
            return
        self.highlight(int(idx))
        if int(self.sl_frame.value) != int(idx):
            self._mute = True
            try:
                self.sl_frame.value = int(idx)
            finally:
                self._mute = False

    def close(self) -> None:
        """Stop the timeline (the session drops its callbacks; the tab's nodes go with it)."""
        self._playing = False
        self.closed = True


def attach(session) -> FlightLayer:
    """Add the flight layer to a ``geoloc view`` session: ``GeolocApp(server, scn, layers=(attach, ...))``."""
    return FlightLayer(session)
