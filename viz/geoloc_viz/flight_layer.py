"""The viewer as a whole-flight debugger: a layer that attaches to a ``geoloc view`` session.

:func:`attach` (``attach(session)``, a layer of :class:`geoloc_viz.app.GeolocSession`) draws the
flight of the session's scenario (:func:`geoloc_viz.flight_model.build`, one batch for all
frames) and adds a **Flight** GUI folder:

* scene (one node each, batched): the track, a thinned trail of footprints (every k-th frame,
  at most :data:`TRAIL_MAX`, and every outlier, in red), the frame centres, the reported /
  recomputed / truth points and the error vectors; the current frame's footprint bold, in
  magenta (``/flight/current``);
* a **timeline**: a frame slider, play / pause and a speed; moving it loads that frame into the
  session (``session.load_record(idx)``: its full chain, line of sight and iterations, as
  one record) and moves only the highlight (the batched nodes are never rebuilt);
* the **outliers**: the frames sorted by residual as a markdown table, with the robust flags,
  and a "go to" dropdown that jumps the timeline and the camera (``session.move_camera``) to
  the chosen frame;
* what the outlier runs look like (:func:`geoloc_viz.flight_model.diagnose`) and the flight's
  **accuracy** (:mod:`geoloc.analysis.accuracy`).

Scene nodes live under ``/flight``, a frame whose pose is the flight model's ENU frame in the
session's scene frame (the session's ENU origin moves with the record: one node update, the
children stay). World unit: the km, as the rest of the scene (:data:`geoloc_viz.scene_geoloc.WORLD_SCALE`);
vertical exaggeration: a (1, 1, v) node scale, as the terrain. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import collections
import inspect
import threading
import time
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from viser import LabelHandle, LineSegmentsHandle, PointCloudHandle, SceneNodeHandle

from geoloc_viz import flight_model
from geoloc_viz.layer_safety import own_update
from geoloc_viz.palette import PALETTE, rgb
from geoloc_viz.scene_geoloc import WORLD_SCALE, wxyz

if TYPE_CHECKING:
    from geoloc.frames.enu import EnuFrame

_Handle = TypeVar("_Handle", bound=SceneNodeHandle)

ROOT = "/flight"
#: Colours (RGB 0-255), from the viewer's one colour table (:mod:`geoloc_viz.palette`). The highlight is pure
#: magenta: nothing else in the scene has it (the terrain's gist_earth colours, the pink error and violet
#: published all have green > 60), so a browser test can find it by pixel statistics. Every frame's error
#: vector is a dimmer mauve than the current frame's bright pink one (red > 225 only for the bright one).
COLORS = {
    "track": rgb("track"),
    "footprint": rgb("footprint"),
    "footprint_outlier": rgb("footprint_outlier"),
    "current": rgb("current"),
    "centre": rgb("centre"),
    "reported": rgb("published"),
    "recomputed": rgb("result"),
    "truth": rgb("surveyed"),
    "error": rgb("error"),
    "errors": rgb("errors"),
}
TOP_N = 12
#: Marker radius at the current frame, as a fraction of its error (the error vector must stay visible
#: between the two markers at every scale: 10 % leaves 80 % of the vector uncovered), within these
#: bounds [m] (the upper one the session's default marker radius).
FOCUS_FRACTION = 0.1
FOCUS_RADIUS_M = (0.25, 220.0)
#: The camera framing an error stands this many error lengths from it (the vector then spans about a
#: third of the view at viser's 75 deg vertical field of view), at least FOCUS_MIN_DISTANCE_M.
FOCUS_DISTANCE = 2.2
FOCUS_MIN_DISTANCE_M = 60.0
#: Longest wait [s] for a browser to apply a timeline step before the player sends the next anyway.
PLAY_ACK_TIMEOUT_S = 30.0
#: Display-only lift of the draped outlines above the terrain mesh [m], so the depth test does not
#: hide lines that lie on it (the mesh resamples the DEM: it is tens of metres off between nodes).
LIFT_M = {"footprints": 8.0, "current": 25.0}
#: The whole flight's footprints through every second outline point (the corners kept: 8 segments
#: a frame, the current frame's own outline all 16), a level of detail: in software
#: WebGL a frame's cost follows the segments drawn, and the example flight's 4768 segments cost
#: 0.13 s of a 0.30 s frame (``benchmarks/bench_browser.py --groups``).
FOOTPRINT_EVERY = 2
#: Footprints of the whole flight drawn in the scene: at most this many (every k-th frame, outliers
#: always; :meth:`geoloc_viz.flight_model.FlightModel.trail_frames`): 300 overlapping outlines hid
#: each other and the terrain; the map's trail is thinned the same way.
TRAIL_MAX = 60
CHOOSE = "(choose a frame)"

_CACHE: dict = {}  # id(records) -> (records, model): one model per scenario, shared by every tab


def model_for(scn, **kw) -> flight_model.FlightModel:
    """The flight model of ``scn`` (built once per records list; tabs share their scenario's records)."""
    c = getattr(scn, "corrections", None)
    # the scene's corrections are part of the model (each frame located through the pipeline with them)
    key = (id(scn.records), id(getattr(scn, "dem", None)), None if c is None else (c.names, id(c.refraction)))
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
        self.current: int | None = None
        self.closed = False
        self._mute = False
        self._pending: int | None = None
        self._highlighted: int | None = None  # the frame the session's record callback highlighted
        self._busy = threading.Lock()
        self._playing = False
        self._thread: threading.Thread | None = None
        #: The frames the player sent in its last run, in order (the clock skips those a slow browser
        #: could not draw in time), bounded.
        self.played: collections.deque = collections.deque(maxlen=10000)
        self._enu_key: tuple[EnuFrame, float] | None = None  # (the scene's ENU frame, vertical exaggeration)
        self.last_step_s = float("nan")
        self.handles: dict[str, SceneNodeHandle] = {}
        # a flight's view: no frame name labels at the aircraft (the teaching view shows them)
        view = getattr(session, "view", None)
        if view is not None and hasattr(view, "set_frame_labels"):
            view.set_frame_labels(False)
        self._draw()
        self._build_gui()
        self._follow_session()
        idx = session.scn.record_index
        self.highlight(0 if idx is None else int(idx))
        # the first view orients: the whole flight, its worst runs marked (where to look first)
        if len(self.model) > 1:
            self.show_whole_flight(initial=True)

    # ------------------------------------------------------------ scene
    def _disp(self):
        view = getattr(self.session, "view", None)
        return getattr(view, "disp", None)

    def _handle(self, key: str, kind: type[_Handle]) -> _Handle:
        """The scene node ``key`` of :attr:`handles`, of the viser kind ``_draw`` made it."""
        h = self.handles[key]
        if not isinstance(h, kind):
            raise TypeError(f"flight handle {key!r} is a {type(h).__name__}, expected {kind.__name__}")
        return h

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
            self.handles["track"] = s.add_line_segments(
                f"{ROOT}/track", f32(m.track_segments()), COLORS["track"], thickness=2.0, thickness_units="screen"
            )
        P = m.footprint_enu.shape[1]  # the current frame's outline: every point
        # the trail thinned (every k-th frame, outliers always), as the map draws it; the current one bold
        trail = m.trail_frames(TRAIL_MAX)
        seg = m.footprint_segments(FOOTPRINT_EVERY).reshape(len(m), P // FOOTPRINT_EVERY, 2, 3)[trail]
        seg = seg.reshape(-1, 2, 3) + np.array([0.0, 0.0, LIFT_M["footprints"]])
        col = np.where(
            np.repeat(m.outlier[trail], P // FOOTPRINT_EVERY)[:, None], COLORS["footprint_outlier"], COLORS["footprint"]
        )
        good = np.all(np.isfinite(seg), axis=(1, 2))
        self.handles["footprints"] = s.add_line_segments(
            f"{ROOT}/footprints",
            f32(seg[good]),
            np.repeat(col[good, None].astype(np.uint8), 2, axis=1),
            thickness=1.0,
            thickness_units="screen",
        )
        for name, pts in (
            ("centres", m.centre_enu),
            ("reported", m.reported_enu),
            ("recomputed", m.recomputed_enu),
            ("truth", m.truth_enu),
        ):
            ok = np.all(np.isfinite(pts), axis=1)
            if ok.any():
                self.handles[name] = s.add_point_cloud(
                    f"{ROOT}/{name}",
                    f32(pts[ok]),
                    COLORS["centre" if name == "centres" else name],
                    point_size=self.point_size * (0.6 if name == "centres" else 1.0),
                    point_shape="circle",
                    precision="float32",
                )
        # the flagged runs: their stretch of the track in red, thick, labelled with the fault
        runs = sorted(m.faults, key=lambda f: -np.nanmax(m.residual_m[f.first : f.last + 1]))
        segs, self.run_labels = [], []
        for r, f in enumerate(runs, 1):
            a, b = f.first, min(f.last + 1, len(m) - 1)
            seg = (
                np.stack([m.track_enu[a:b], m.track_enu[a + 1 : b + 1]], axis=1)
                if b > a
                else np.stack([m.track_enu[a : a + 1], m.track_enu[a : a + 1] + [0.0, 0.0, 1.0]], axis=1)
            )
            segs.append(seg)
        if segs:  # (the parent node before its labels: re-creating a node drops its children)
            seg = np.concatenate(segs)
            ok = np.all(np.isfinite(seg), axis=(1, 2))
            self.handles["runs"] = s.add_line_segments(
                f"{ROOT}/runs", f32(seg[ok]), COLORS["footprint_outlier"], thickness=6.0, thickness_units="screen"
            )
        for r, f in enumerate(runs, 1):
            mid = m.track_enu[(f.first + f.last) // 2]
            what = f.headline().split(": ", 1)[-1]
            self.run_labels.append(
                s.add_label(
                    f"{ROOT}/run_labels/run{r}",
                    f"run {r}: {what}",
                    position=tuple(f32(mid[None])[0]),
                    anchor="bottom-center",
                )
            )
        err = m.error_segments()
        ok = np.all(np.isfinite(err), axis=(1, 2))
        if ok.any():
            self.handles["errors"] = s.add_line_segments(
                f"{ROOT}/errors", f32(err[ok]), COLORS["errors"], thickness=1.5, thickness_units="screen"
            )
        self.handles["current"] = s.add_line_segments(
            f"{ROOT}/current",
            np.zeros((P, 2, 3), np.float32),
            COLORS["current"],
            thickness=6.0,
            thickness_units="screen",
        )
        self.handles["label"] = s.add_label(f"{ROOT}/current/label", "", position=(0.0, 0.0, 0.0), anchor="bottom-left")
        # the current frame's error, drawn above everything around it (see focus()): the vector
        # (lifted over the terrain mesh), stems down to the true points, two markers sized to the
        # error, and a label with its length
        z = np.zeros((1, 2, 3), np.float32)
        self.focus_handles = {
            "error": s.add_line_segments(
                f"{ROOT}/focus/error", z, COLORS["error"], thickness=7.0, thickness_units="screen"
            ),
            "stems": s.add_line_segments(
                f"{ROOT}/focus/stems",
                np.zeros((2, 2, 3), np.float32),
                COLORS["error"],
                thickness=1.5,
                thickness_units="screen",
            ),
        }
        self._focus_key: float | None = None  # the markers' radius [m] they were made with
        self.focus_info: dict = {}
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
        for h in self.handles.values():
            if isinstance(h, (LineSegmentsHandle, PointCloudHandle)):  # all but the root frame and the label
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
        self._handle("current", LineSegmentsHandle).points = seg.astype(np.float32)
        c = m.centre_enu[idx]
        lab = self._handle("label", LabelHandle)
        if np.all(np.isfinite(c)):
            v = self._vexag()
            lab.position = tuple(c * WORLD_SCALE * np.array([1.0, 1.0, v]))
        res = m.residual_m[idx]
        f = m.fault_of(idx)
        name = self.frame_name(idx, of=False)
        lab.text = (f"{name}: residual {res:.1f} m" if np.isfinite(res) else name) + (
            f" ({f.kind})" if f is not None else ""
        )
        self.focus(idx)
        # an error worth seeing has its own label (frame, length, fault) above its vector: the frame's
        # label at the image centre would sit on the vector's start
        lab.visible = not (self.focus_info and self.focus_info["error_m"] > 0.5)
        if hasattr(self, "md_frame"):
            later = getattr(self.session, "later", None)
            text = lambda: setattr(self.md_frame, "content", self._frame_text(idx))  # noqa: E731
            later(text) if later is not None else text()
        self.last_step_s = time.perf_counter() - t0

    # ------------------------------------------------------------ the current frame's error
    def reference_enu(self) -> np.ndarray:
        m = self.model
        return m.truth_enu if m.reference == "truth" else m.reported_enu

    def error_m(self, idx: int) -> float:
        """3D length [m] of frame ``idx``'s error vector (recomputed -> reference; NaN if unknown)."""
        d = self.reference_enu()[idx] - self.model.recomputed_enu[idx]
        return float(np.linalg.norm(d)) if np.all(np.isfinite(d)) else float("nan")

    def focus_radius_m(self, idx: int) -> float:
        """Marker radius [m] at frame ``idx``: :data:`FOCUS_FRACTION` of its error, within :data:`FOCUS_RADIUS_M`."""
        e = self.error_m(idx)
        lo, hi = FOCUS_RADIUS_M
        return float(np.clip(FOCUS_FRACTION * e, lo, hi)) if np.isfinite(e) else hi

    def _lift_m(self, pts_enu) -> float | None:
        """Display lift [m] of the error vector over the session's terrain mesh (its cells' highest
        nodes under the ends and the middle), plus a margin; None without a DEM or with the terrain
        hidden."""
        from geoloc_viz import terrain_link

        scn = self.session.scn
        if getattr(scn, "dem", None) is None or not getattr(self._disp(), "terrain_visible", True):
            return None
        F = self.model.enu
        lat, lon, h = F.to_geodetic(np.asarray(pts_enu, float))
        top = terrain_link.mesh_height_bound(scn, np.degrees(lat), np.degrees(lon))
        gap = np.nanmax(np.r_[top - h, 0.0])
        return float(gap) if np.isfinite(gap) else 0.0

    def focus(self, idx: int) -> None:
        """Draw frame ``idx``'s error vector (recomputed -> reference), lifted clear of the terrain
        mesh with stems to the true points, its two markers sized to the error and its label."""
        m, W, s = self.model, WORLD_SCALE, self.scene
        a, b = m.recomputed_enu[idx], self.reference_enu()[idx]
        fh = self.focus_handles
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            self.focus_info = {}
            for h in fh.values():
                h.visible = False
            return
        e = float(np.linalg.norm(b - a))
        r = self.focus_radius_m(idx)
        lift = self._lift_m(np.stack([a, b, 0.5 * (a + b)]))
        up = np.array([0.0, 0.0, 1.0])
        # above the mesh by a margin (2 m, and 2 markers' radii so the markers clear it too)
        lift = 0.0 if lift is None else lift + 2.0 + 2.0 * r
        v = np.array([1.0, 1.0, self._vexag()]) * W
        a2, b2 = a + lift * up, b + lift * up
        fh["error"].points = (np.array([[a2, b2]]) * v).astype(np.float32)
        fh["stems"].points = (np.array([[a, a2], [b, b2]]) * v).astype(np.float32)
        key = round(r, 4)
        if key != self._focus_key or "recomputed" not in fh:
            self._focus_key = key
            fh["recomputed"] = s.add_icosphere(
                f"{ROOT}/focus/recomputed",
                radius=r * W,
                color=COLORS["recomputed"],
                subdivisions=2,
                cast_shadow=False,
                receive_shadow=False,
            )
            fh["reference"] = s.add_icosphere(
                f"{ROOT}/focus/reference",
                radius=r * W,
                color=COLORS["truth" if m.reference == "truth" else "reported"],
                subdivisions=2,
                cast_shadow=False,
                receive_shadow=False,
            )
        fh["recomputed"].position = tuple(a2 * v)
        fh["reference"].position = tuple(b2 * v)
        text = self.error_text(idx)
        mid = 0.5 * (a2 + b2) + up * max(0.35 * e, 3.0 * r)
        if "label" not in fh:
            fh["label"] = s.add_label(f"{ROOT}/focus/label", text, position=tuple(mid * v), anchor="bottom-center")
        else:
            fh["label"].position = tuple(mid * v)
            if fh["label"].text != text:
                fh["label"].text = text
        # a residual of millimetres (a frame that agrees) has nothing to show: the frame's own label says it
        for h in fh.values():
            h.visible = e > 0.5
        self.focus_info = {
            "idx": idx,
            "a_enu": a2,
            "b_enu": b2,
            "error_m": e,
            "radius_m": r,
            "lift_m": lift,
            "label": text,
        }

    def export_markdown(self) -> str:
        """The current frame's residual, error vector and fault (its run and what it looks like),
        for the static export's text panel."""
        if self.current is None:
            return ""
        m, idx = self.model, self.current
        f = m.fault_of(idx)
        text = self._frame_text(idx)
        if f is not None:
            text += "  \n" + flight_model.WHAT_IT_LOOKS_LIKE[f.kind]
        elif m.faults:
            text += "  \nflagged runs of this flight: " + "; ".join(x.headline() for x in m.faults)
        return text

    def error_text(self, idx: int) -> str:
        """The error vector's label: its 3D length, what it joins, and the display lift if any."""
        m = self.model
        e = self.error_m(idx)
        if not np.isfinite(e):
            return ""
        f = m.fault_of(idx)
        kind = f" ({KIND_NAMES.get(f.kind, f.kind)} run)" if f is not None else ""
        # the solver named: the viewer's own point of this frame may use another (its panel says which)
        return f"{self.frame_name(idx, of=False)}{kind}: error {e:.1f} m, {m.located_by} -> {m.reference}"

    def focus_world(self):
        """The lifted error vector's ends in the session's scene frame (km), for cameras and tests."""
        if not self.focus_info:
            return None
        scene_enu, F = self.session.scn.enu, self.model.enu
        v = np.array([1.0, 1.0, self._vexag()]) * WORLD_SCALE
        return tuple(
            scene_enu.from_ecef(F.to_ecef(p)) * v for p in (self.focus_info["a_enu"], self.focus_info["b_enu"])
        )

    def frame_name(self, idx: int, of: bool = True) -> str:
        """Frame ``idx``'s one name (:func:`geoloc_viz.model.frame_name`): its timeline index, time
        and record label, as the summary, the picture and the exports name it."""
        from geoloc_viz.model import frame_name

        return frame_name(self.session.scn, idx, of=of)

    def _frame_text(self, idx: int) -> str:
        m, c = self.model, self.model.components
        f = m.fault_of(idx)
        text = (
            f"**{self.frame_name(idx)}**: residual "
            f"{m.residual_m[idx]:.2f} m "
            f"(recomputed vs {m.reference}, horizontal); along {c['along_m'][idx]:+.1f}, across "
            f"{c['across_m'][idx]:+.1f}, up {c['up_m'][idx]:+.1f} m" + (" **outlier**" if m.outlier[idx] else "")
        )
        if f is not None:
            text += f"  \nrun: {f.headline()}"
        if self.focus_info.get("idx") == idx:
            fi = self.focus_info
            text += f"  \n**{PALETTE['error'].name} vector**: {fi['label']}; markers {fi['radius_m']:.2g} m" + (
                f", drawn {fi['lift_m']:.0f} m above the terrain mesh (stems to the true points)"
                if fi["lift_m"] > 0
                else ""
            )
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
        self.top_idx, self.opts = goto_entries(m, self.top_n)
        with g.add_folder("Flight", order=self._order(0)):
            self.md_head = g.add_markdown(
                f"**{n} frames**, footprints on {m.surface.split(' (')[0]}; {int(m.outlier.sum())} flagged in "
                f"{len(m.faults)} run(s). Colours: the Legend folder"
            )
            self.sl_frame = g.add_slider(
                "frame index",
                0,
                max(n - 1, 1),
                1,
                0,
                disabled=n < 2,
                hint="Scrub through the frames; each loads as the current record",
            )
            self.bt_whole = g.add_button(
                "whole flight", hint="The camera on the whole flight: track, footprints, the flagged runs in red"
            )
            self.worst = worst_flagged(m)
            self.bt_worst = g.add_button(
                worst_label(m, self.worst),
                visible=self.worst is not None,
                hint="Jump to the flagged frame of largest error, the camera framed on its error vector",
            )
            self.cb_follow = g.add_checkbox(
                "camera follows the timeline",
                False,
                hint="While the timeline moves, the camera moves with the aircraft",
            )
            self.bt_play = g.add_button("play", hint="Play / pause the timeline")
            self.num_fps = g.add_number("frames per second", 2.0, min=0.2, max=30.0, step=0.1)
            self.cb_auto_markers = g.add_checkbox(
                "markers sized to the error",
                True,
                hint="The hit markers shrink to a tenth of the current frame's error so they never cover "
                "its error vector (pink, with its length)",
            )
            self.md_frame = g.add_markdown("")
        with g.add_folder("Flight: outliers first", order=self._order(1)):
            self.dd_goto = g.add_dropdown(
                "go to",
                [CHOOSE] + self.opts,
                initial_value=CHOOSE,
                hint="Jump the timeline and the camera to this frame",
            )
            self.md_table = g.add_markdown(m.outlier_markdown(self.top_n))
        with g.add_folder("Flight: what the outliers look like", order=self._order(2)):
            self.md_faults = g.add_markdown(m.faults_markdown())
        with g.add_folder("Flight: accuracy", expand_by_default=False, order=self._order(3)):
            self.md_accuracy = g.add_markdown(m.summary_markdown())
        with g.add_folder("Flight: heights and conventions", order=self._order(4)):
            self.md_audit = g.add_markdown(m.audit_markdown())
        self.sl_frame.on_update(self._on_slider)
        self.bt_play.on_click(lambda _e: self.toggle_play())
        self.bt_whole.on_click(lambda _e: self.show_whole_flight())
        self.bt_worst.on_click(lambda _e: None if self.worst is None else self.go(self.worst, camera=True))
        self.dd_goto.on_update(self._on_goto)

    def rebuild(self) -> None:
        """The model of the session's scenario as it is now (its corrections switched in the GUI):
        every frame located again, drawn again (:meth:`set_model`)."""
        self.set_model(model_for(self.session.scn))

    def set_model(self, model: flight_model.FlightModel, current: int | None = None) -> None:
        """Show another model of the session's flight (a live flight that grew, its oldest frames
        dropped): the batched nodes drawn again, the timeline's range, the outlier table, the "go to"
        entries, the faults and the accuracy updated; the highlight on frame ``current`` (default
        the current index, clipped). The session's records must already be the model's frames."""
        self.model = model
        n = len(model)
        self._enu_key = None
        self._draw()
        self.top_idx, self.opts = goto_entries(model, self.top_n)
        self._mute = True
        try:
            self.sl_frame.max = max(n - 1, 1)
            self.sl_frame.disabled = n < 2
            self.dd_goto.options = [CHOOSE] + self.opts
            self.md_head.content = (
                f"**{n} frames**, footprints on {model.surface.split(' (')[0]}; {int(model.outlier.sum())} "
                f"flagged in {len(model.faults)} run(s). Colours: the Legend folder"
            )
            self.md_table.content = model.outlier_markdown(self.top_n)
            self.md_faults.content = model.faults_markdown()
            self.md_accuracy.content = model.summary_markdown()
            self.md_audit.content = model.audit_markdown()
            self.worst = worst_flagged(model)
            self.bt_worst.label = worst_label(model, self.worst)
            self.bt_worst.visible = self.worst is not None
        finally:
            self._mute = False
        idx = self.current if current is None else current
        self.current = None
        self.highlight(int(np.clip(0 if idx is None else idx, 0, n - 1)))

    def _on_slider(self, event=None) -> None:
        # coalesced: a drag sends many values; while one step runs only the latest waiting value is
        # loaded next (the others would only queue scenes the browser has to draw and throw away)
        if self.closed or own_update(self, event):
            return
        self._pending = int(self.sl_frame.value)
        while self._pending is not None and self._busy.acquire(blocking=False):
            try:
                while self._pending is not None and not self.closed:
                    idx, self._pending = self._pending, None
                    self.go(idx)
            finally:
                self._busy.release()

    def _on_goto(self, event=None) -> None:
        if self.closed or own_update(self, event) or self.dd_goto.value == CHOOSE:
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

    def size_markers(self, idx: int, points: bool = False) -> None:
        """The session's hit markers (and with ``points`` the flight's point clouds) sized to frame
        ``idx``'s error (:meth:`focus_radius_m`), so they never cover its error vector."""
        s, d = self.session, self._disp()
        cb = getattr(self, "cb_auto_markers", None)
        if d is None or (cb is not None and not cb.value):
            return
        r = self.focus_radius_m(idx)
        changed = abs(float(getattr(d, "marker_radius_m", r)) - r) > 1e-9
        d.marker_radius_m = r
        sl = getattr(s, "sl_marker", None)
        if sl is not None and abs(float(sl.value) - r) > 1e-9:
            s._mute = True
            try:
                sl.value = r
            finally:
                s._mute = False
        # every frame's points (viser draws a point about twice its size in world units across):
        # dots of a sixth of the current frame's markers, so the neighbours of a run stay off its vector
        size = 0.15 * r * WORLD_SCALE if points else self.point_size
        for name in ("centres", "reported", "recomputed", "truth"):
            h = self.handles.get(name)
            if isinstance(h, PointCloudHandle):  # None when the flight has no such point
                h.point_size = size * (0.6 if name == "centres" else 1.0)
        self._markers_changed = changed

    def go(self, idx: int, camera: bool = False) -> None:
        """Frame ``idx``: load it into the session, move the highlight, sync the slider (and the camera:
        framed on the frame's error, the markers sized to it).

        One atomic batch (the session's ``_atomic``): the client applies the step's parts (the record,
        its redraw, the highlight) together, not over several frames (docs/viz.md, bench_browser).
        The panels' work (the picture, the teaching text: the session's deferred redraw callbacks)
        follows in a second batch, once the scene is on its way, and is left to the next step when
        one already waits (a slider drag)."""
        deferring = getattr(self.session, "deferring", None)
        if deferring is None:  # the older app
            with self.session._atomic():
                self._go(idx, camera)
            return
        with deferring(skip=lambda: self._pending is not None):
            with self.session._atomic():
                self._go(idx, camera)

    def _go(self, idx: int, camera: bool) -> None:
        idx = int(np.clip(idx, 0, len(self.model) - 1))
        before = self.current
        self._markers_changed = False
        self.size_markers(idx, points=camera)
        loaded = self.session.scn.record_index == idx
        self._highlighted = None
        self._load(idx)
        if loaded and self._markers_changed and hasattr(self.session, "refresh"):
            self.session.refresh(recompute=False)
        if self._highlighted != idx:
            # (a load already moved it: the session's record callback; a second pass would cost the
            # step's server time again, before its scene batch, for messages viser drops as unchanged)
            self.highlight(idx)
        if int(self.sl_frame.value) != idx:
            self._mute = True
            try:
                self.sl_frame.value = idx
            finally:
                self._mute = False
        self.show_origin(not camera)
        if camera:
            self.move_camera_to(idx)
        elif (
            before is not None
            and before != idx
            and getattr(self, "cb_follow", None) is not None
            and self.cb_follow.value
        ):
            self.follow(before, idx)

    def follow(self, old: int, new: int) -> None:
        """Move the camera(s) by the aircraft's displacement from frame ``old`` to ``new`` (the view's
        orientation and zoom kept): the aircraft stays where it was on screen."""
        m = self.model
        scene_enu, F = self.session.scn.enu, m.enu
        v = np.array([1.0, 1.0, self._vexag()]) * WORLD_SCALE
        d = (scene_enu.from_ecef(F.to_ecef(m.track_enu[new])) - scene_enu.from_ecef(F.to_ecef(m.track_enu[old]))) * v
        if not np.all(np.isfinite(d)):
            return
        s = self.session
        client = getattr(s, "client", None)
        clients = [client] if client is not None else list(s.server.get_clients().values())
        for c in clients:
            try:
                pos, aim = np.asarray(c.camera.position, float), np.asarray(c.camera.look_at, float)
                with c.atomic():  # position first: viser moves look_at with it, then sets it exactly
                    c.camera.position = tuple(pos + d)
                    c.camera.look_at = tuple(aim + d)
            except Exception:  # a tab that left
                pass

    def show_origin(self, visible: bool) -> None:
        """Show or hide the scene's ENU origin axes: 600 m cylinders at the rounded target position,
        right where a framed error is (hidden while one is framed; "overview" shows them again)."""
        h = self.scene.get_handle_by_name("/enu/origin") if hasattr(self.scene, "get_handle_by_name") else None
        if h is not None and h.visible != visible:
            h.visible = visible

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
        ends = self.focus_world() if self.focus_info.get("idx") == idx else None
        e = self.error_m(idx)
        if ends is not None and np.isfinite(e) and e > 0.5:
            # framed on the error: looking down steeply from the aircraft's side, the vector
            # across the middle of the view
            aim = 0.5 * (ends[0] + ends[1])
            D = max(FOCUS_DISTANCE * e, FOCUS_MIN_DISTANCE_M) * WORLD_SCALE
            horiz = (a - aim)[:2]
            u = np.r_[horiz / max(np.linalg.norm(horiz), 1e-9), 0.0]
            # from the side away from the aircraft (its line of sight, iterations and frames then
            # lie beyond the error, above the view), across the vector (it runs left to right on
            # screen, and its label, above its middle, stays off it)
            u = -u
            dv = (ends[1] - ends[0])[:2]
            if np.linalg.norm(dv) > 0.2 * np.linalg.norm(ends[1] - ends[0]):
                p = np.r_[-dv[1], dv[0], 0.0] / np.linalg.norm(dv)
                u = p if p @ u >= 0 else -p
            w = 0.55 * u + np.array([0.0, 0.0, 0.83])
            return shift_left_of_panel(aim + D * w / np.linalg.norm(w), aim)
        L = max(float(np.linalg.norm(a - aim)), 1e-3)
        horiz = (a - aim)[:2]
        u = np.r_[horiz / max(np.linalg.norm(horiz), 1e-9), 0.0]
        side = np.array([-u[1], u[0], 0.0])
        pos = aim + 0.55 * L * u + 0.25 * L * side + np.array([0.0, 0.0, 0.45 * L])
        return pos, aim

    def whole_flight_pose(self):
        """(position, look_at) in scene units (km) framing the whole flight: the track and every
        footprint, from the south-east and above (about 50 deg down), the GUI panel on the right."""
        m = self.model
        scene_enu, F = self.session.scn.enu, m.enu
        v = np.array([1.0, 1.0, self._vexag()]) * WORLD_SCALE
        pts = np.concatenate([m.track_enu, m.footprint_enu.reshape(-1, 3)])
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        P = scene_enu.from_ecef(F.to_ecef(pts)) * v
        lo, hi = P.min(axis=0), P.max(axis=0)
        centre = 0.5 * (lo + hi)
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.5)
        # viser's 75 deg vertical field of view: a sphere of this radius fits at 1.25 radius / tan(37.5)
        D = 1.25 * radius / np.tan(np.radians(37.5))
        w = np.array([0.45, -0.55, 0.95])
        pos = centre + D * w / np.linalg.norm(w)
        return shift_left_of_panel(pos, centre)

    def show_whole_flight(self, initial: bool = False) -> None:
        """The camera on the whole flight (and, for a server session at the start, every new tab's)."""
        pos, aim = self.whole_flight_pose()
        s = self.session
        self.size_markers(self.current if self.current is not None else 0, points=False)
        # the aircraft drawn a tenth of the flight's extent (x200 makes a 3 km aircraft, as large as
        # the example flight's orbit); its label and the panel say the scale
        sl = getattr(s, "sl_ac", None)
        if sl is not None:
            m = self.model
            ext = float(np.nanmax(np.ptp(np.nan_to_num(m.track_enu[:, :2]), axis=0)))
            scale = float(np.clip(round(ext / 10.0 / 15.0), 1.0, float(sl.value)))
            if scale != float(sl.value):
                sl.value = scale
        self.show_origin(True)
        if initial and getattr(s, "client", None) is None and hasattr(s.server, "initial_camera"):
            cam = s.server.initial_camera
            cam.up = (0.0, 0.0, 1.0)
            cam.position, cam.look_at = tuple(pos), tuple(aim)
        self._move((pos, aim))

    def _move(self, pose) -> None:
        pos, aim = pose
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
                client.camera.position = tuple(pos)
                client.camera.look_at = tuple(aim)

    def move_camera_to(self, idx: int) -> None:
        self._move(self.camera_pose(idx))

    def toggle_play(self) -> None:
        """Start or pause the timeline (a daemon thread plays ``frames per second``).

        The displayed frame follows the clock: a browser slower than the asked rate (software
        WebGL draws a frame in a few tenths of a second) is sent the frame the clock has reached,
        the frames in between skipped, so the timeline runs at the asked rate and the picture
        keeps up as well as the browser can (:attr:`played` lists the frames sent).

        Pause is immediate: the player sends a step only once the browsers have applied the
        one before (:meth:`_caught_up`), so when pause is pressed at most the step already
        sent is still to be drawn; nothing queued runs on after it.
        """
        if self._playing:
            self._playing = False
            self.bt_play.label = "play"
            return
        self._playing = True
        self.played.clear()
        self.bt_play.label = "pause"
        self._thread = threading.Thread(target=self._play, daemon=True, name="geoloc-flight-timeline")
        self._thread.start()

    def _clients(self) -> list:
        """The browsers that draw this session: its tab's, or (a server session) every tab."""
        s = self.session
        c = getattr(s, "client", None)
        if c is not None:
            return [c]
        server = getattr(s, "server", None)
        return list(server.get_clients().values()) if server is not None else []

    def _caught_up(self, timeout_s: float = PLAY_ACK_TIMEOUT_S) -> bool:
        """Wait until every browser of the session has applied the messages sent so far.

        A round trip behind them: a localStorage read, which the browser answers from its
        message handler in the order the messages came (viser's ``LocalStorageHandle.get_item``).
        False when paused meanwhile or a browser left; a browser that does not answer in
        ``timeout_s`` is let be (the next step goes anyway).
        """
        for c in self._clients():
            while self._playing and not self.closed:
                try:
                    c.local_storage.get_item("geoloc-timeline-ack", timeout=min(timeout_s, 0.5))
                    break
                except TimeoutError:
                    timeout_s -= 0.5
                    if timeout_s <= 0:
                        break
                except (RuntimeError, AttributeError):  # the tab left (or an old viser)
                    break
        return self._playing and not self.closed

    def _play(self) -> None:
        # the clock: frame k (counted from the anchor frame, unwrapped) is due on screen at
        # anchor_t + k / fps; re-anchored when the rate changes or the timeline was moved by hand.
        # A step takes `lead` seconds from sending to drawn (the last one's, measured to the
        # browser's acknowledgement): the player sends the frame that will be due when it is drawn
        n = len(self.model)
        fps = max(float(self.num_fps.value), 1e-3)
        anchor_t, anchor_f, k, lead = time.monotonic(), int(self.current or 0), 0, 0.0
        while self._playing and not self.closed:
            f = max(float(self.num_fps.value), 1e-3)
            now = time.monotonic()
            if f != fps or self.current != (anchor_f + k) % n:
                fps, anchor_t, anchor_f, k = f, now, int(self.current or 0), 0
            # the next frame: the one due once drawn, at least one on; sent `lead` before it is due
            k_next = max(k + 1, int(np.floor((now + lead - anchor_t) * fps)))
            due = anchor_t + k_next / fps - lead
            while self._playing and not self.closed and time.monotonic() < due:
                time.sleep(min(0.05, max(due - time.monotonic(), 0.0)))
            if not self._playing or self.closed:
                break
            nxt = (anchor_f + k_next) % n
            sent = time.monotonic()
            try:
                self.go(nxt)
            except (RuntimeError, KeyError, ValueError):  # the tab left (its handles are gone): stop
                self._playing = False
                break
            k = k_next
            self.played.append(nxt)
            # the browsers first draw this step (software WebGL can take seconds a frame): a
            # player that ran ahead of them would leave steps queued that run on after pause
            if not self._caught_up():
                break
            lead = time.monotonic() - sent

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
        self._highlighted = int(idx)
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


#: The GUI panel covers the right of the canvas: cameras framing something put it this fraction of
#: its distance to the right of the view's centre line, so it shows left of the panel.
PANEL_SHIFT = 0.25


def shift_left_of_panel(pos, aim, k: float = PANEL_SHIFT):
    """(position, look_at) moved together along the view's right vector by ``k`` times their distance:
    what was aimed at appears left of the centre, clear of the GUI panel."""
    pos, aim = np.asarray(pos, float), np.asarray(aim, float)
    f = aim - pos
    r = np.cross(f, [0.0, 0.0, 1.0])
    n = np.linalg.norm(r)
    if n < 1e-12:
        return pos, aim
    d = k * np.linalg.norm(f) * r / n
    return pos + d, aim + d


KIND_NAMES = {
    "attitude": "heading bias",
    "datum": "height datum",
    "timing": "stale pose",
    "unexplained": "unexplained",
    "convention": "the audit's convention fault",
}


def goto_entries(m: flight_model.FlightModel, top_n: int = TOP_N):
    """(frame indices, option texts) of the "go to" dropdown: every flagged run, worst first, as
    its worst frame then each of its frames (so every outlier is one choice away); without runs
    the ``top_n`` largest residuals."""
    idx, opts = [], []
    runs = sorted(m.faults, key=lambda f: -np.nanmax(m.residual_m[f.first : f.last + 1]))
    for r, f in enumerate(runs, 1):
        frames = np.arange(f.first, f.last + 1)
        worst = int(frames[np.nanargmax(m.residual_m[frames])])
        idx.append(worst)
        opts.append(
            f"run {r} ({KIND_NAMES.get(f.kind, f.kind)}, {f.span()}): worst frame {worst}, {m.labels[worst]}, "
            f"{m.residual_m[worst]:.1f} m"
        )
        for i in frames:
            idx.append(int(i))
            opts.append(f"  run {r}: frame {i}, {m.labels[i]} ({m.residual_m[i]:.1f} m)")
    flagged = {int(i) for i in np.flatnonzero(m.outlier)}
    rest = [int(i) for i in m.order if int(i) in flagged and int(i) not in idx]
    if not runs:
        rest = [int(i) for i in m.top(top_n) if np.isfinite(m.residual_m[int(i)])]
    for k, i in enumerate(rest, 1):
        idx.append(i)
        opts.append(f"{k}. frame {i}, {m.labels[i]} ({m.residual_m[i]:.1f} m)")
    return idx, opts


def worst_flagged(m: flight_model.FlightModel):
    """The flagged frame of largest residual (what "worst fault" goes to), or None when no frame
    is flagged: then there is no fault to go to and the button is not offered."""
    flagged = np.flatnonzero(np.asarray(m.outlier, bool) & np.isfinite(m.residual_m))
    if not len(flagged):
        return None
    return int(flagged[np.argmax(m.residual_m[flagged])])


def worst_label(m: flight_model.FlightModel, worst) -> str:
    """The "worst fault" button's text: the frame (timeline index and label) and its fault's kind."""
    if worst is None:
        return "worst fault"
    f = m.fault_of(worst)
    return f"worst fault: frame {worst}, {m.labels[worst]}" + (
        f" ({KIND_NAMES.get(f.kind, f.kind)})" if f is not None else ""
    )


def attach(session) -> FlightLayer:
    """Add the flight layer to a ``geoloc view`` session: ``GeolocApp(server, scn, layers=(attach, ...))``."""
    return FlightLayer(session)
