"""The ``geoloc view`` application: viser sessions with the scene and its GUI.

A **session** (:class:`GeolocSession`) is one complete viewer state: a scenario
(record, DEM, ENU origin), the inputs, the display settings, the drawn scene and
the GUI that edits them. It wires the GUI controls (pose, gimbal, pixel, method,
record, display) to :func:`geoloc_viz.model.compute` (the core) and
:class:`geoloc_viz.scene_geoloc.GeolocScene` (drawing).

Where sessions live:

- :class:`GeolocViewer` (what ``geoloc view`` runs): by default **one session per
  browser tab**, built on the client's own ``client.scene`` / ``client.gui`` when
  it connects and dropped when it disconnects; with ``presenter=True`` one client
  drives a session drawn on the shared ``server.scene`` and the others follow
  read-only. ``max_clients`` caps the tabs served.
- :class:`GeolocApp`: a session on the server itself (``server.scene`` /
  ``server.gui``, shared by every tab): used by the static export, by scripts
  and tests.

:func:`make_server` starts viser on 127.0.0.1 by default.

Session interface (stable: the layers of other modules attach to it)
--------------------------------------------------------------------
``session.scene``
    the viser ``SceneApi`` the session draws on (``client.scene`` or ``server.scene``).
``session.gui``
    the viser ``GuiApi`` of its controls.
``session.server``, ``session.client``
    the ``ViserServer``; the ``ClientHandle`` of its tab (None for a server session).
``session.scn``
    its :class:`geoloc_viz.model.Scenario` (each tab has its own copy).
``session.view``
    its :class:`geoloc_viz.scene_geoloc.GeolocScene` (``.enu`` the scene's
    :class:`geoloc.frames.enu.EnuFrame`, ``.disp`` the :class:`Display`).
``session.geometry``
    the last :class:`geoloc_viz.model.Geometry` drawn (None before the first).
``session.inputs``
    the current :class:`geoloc_viz.model.Inputs`.
``session.load_record(idx)``
    load record ``idx`` of ``scn.records`` (new ENU origin, DEM), redraw, frame it.
``session.refresh(recompute=True)``
    recompute through the core and redraw; then every ``on_refresh`` callback.
``session.move_camera(kind)``
    this tab's camera (a server session: every tab's) to ``"overview"``,
    ``"target"`` or a ``(position, look_at)`` pair in scene units (km, ENU).
``session.on_refresh(callback)``
    ``callback(geometry)`` after each redraw (usable as a decorator).
``session.later(fn)``
    ``fn()`` now, or during a timeline step (``session.deferring()``) with the panels' batch, after
    the step's scene went out: for text the scene does not need (the panels' markdown).
``session.on_record(callback)``
    ``callback(idx)`` after a record is loaded and the ENU origin moved, before the redraw.
``layers=(attach_fn, ...)``
    constructor argument: each ``attach_fn(session)`` builds its GUI and scene parts
    once the session has drawn its first frame; what it returns is kept in
    ``session.layers`` (in order). Default :data:`DEFAULT_LAYERS`.

A layer must not keep the session alive after it closes: register callbacks on the
session (dropped by :meth:`GeolocSession.close`) or on the session's own GUI
handles (dropped with the tab), never on the server.

Conventions: ``docs/conventions.md``. User guide: ``docs/viz.md``.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import viser

from geoloc.io.mgrs_grid import mgrs_text
from geoloc.status import describe
from geoloc.userfiles import write_bytes, write_text
from geoloc_viz import (
    calibration_layer,
    flight_layer,
    image_layer,
    label_layout,
    palette,
    refraction_layer,
    panel_layer,
    share_layer,
    teaching,
    teaching_panel,
    uncertainty_layer,
)
from geoloc_viz.layer_safety import own_update
from geoloc_viz.model import Geometry, Inputs, Scenario, compute, drawn_frames, frame_name
from geoloc_viz.scenario import select_record
from geoloc_viz.scene_geoloc import Display, GeolocScene, camera_pose_for, drawn_factor

#: (field, label, min, max, step) of the pose sliders, degrees.
ANGLE_SLIDERS = (
    ("heading_deg", "heading psi (deg)", -180.0, 180.0, 0.0001),
    ("pitch_deg", "pitch theta (deg)", -30.0, 30.0, 0.0001),
    ("roll_deg", "roll phi (deg)", -60.0, 60.0, 0.0001),
    ("gimbal_roll_deg", "gimbal roll (deg)", -85.0, 85.0, 0.0001),
    ("gimbal_pitch_deg", "gimbal pitch (deg)", -30.0, 30.0, 0.0001),
)
CUSTOM = "(custom pose)"
#: Browser tabs served at once by default (``--max-clients``).
MAX_CLIENTS = 16
#: A timeline step waits at most this long [s] for viser's sender to take its scene batch before the
#: panels' batch (:meth:`GeolocSession._send_scene`): a tab that reads nothing does not hold a step.
SEND_WAIT_S = 0.5
#: The ambient light that stands in for viser's environment map (:func:`configure_lighting`).
AMBIENT_LIGHT = "/ambient_light"
AMBIENT_INTENSITY = 1.0
#: The control panel's theme (``GuiApi.configure_theme``).
THEME: dict[str, Any] = {"dark_mode": True, "control_width": "large"}


def attach_flight(session):
    """The flight debugger (:mod:`geoloc_viz.flight_layer`) when the scenario has a flight (2+ records)."""
    return flight_layer.attach(session) if len(session.scn.records) > 1 else None


#: The layers every session gets unless told otherwise (``attach_fn(session)`` each): the
#: flight debugger, the picture of the frame (when the scenario has images), the calibration
#: error vectors, the predicted 90 % ellipse at the hit, refraction and the bent ray, sending the picked point
#: on (MGRS, lat/lon/height, a ``geoloc locate`` line, a CoT event), the large panel (the
#: picture at full resolution, a map, plots against time), the teaching panel, and
#: the label layout (labels kept apart on screen).
DEFAULT_LAYERS = (
    attach_flight,
    image_layer.attach,
    calibration_layer.attach,
    uncertainty_layer.attach,
    refraction_layer.attach,
    share_layer.attach,
    panel_layer.attach,
    teaching_panel.attach,
    label_layout.attach,
)
METHOD_NAMES = {"steps": "descending steps [Q17]", "bisect": "bisection [L23]", "exact": "exact first hit (cell walk)"}


def dem_cell_m(dem) -> float:
    """A DEM's cell size [m] (north-south; degrees at 111.32 km for a geographic grid), NaN if unknown."""
    g = getattr(dem, "grid", None)
    d = float(getattr(g, "dlat_deg", np.nan)) if g is not None else np.nan
    return abs(d) * 111.32e3 if getattr(dem, "is_geographic", True) else abs(d)


def coarse_dem_note(scn, inp, error_m: float, published_error_m: float) -> str:
    """Why the error to the surveyed point exceeds the published one, when the DEM is coarse (cells
    over 1 km): the panel says it where the numbers are (empty otherwise)."""
    dem = getattr(scn, "dem", None)
    if dem is None or not (np.isfinite(error_m) and np.isfinite(published_error_m)):
        return ""
    cell = dem_cell_m(dem)
    if not (np.isfinite(cell) and cell > 1000.0 and error_m > 2.0 * published_error_m):
        return ""
    name = str(getattr(scn, "dem_name", "") or "the DEM").split(" (")[0]
    return (
        f"**why {error_m:.0f} m, not the published {published_error_m:.0f} m**: the terrain here is "
        f"{name}, cells of about {cell / 1e3:.0f} km ([Q17] used ASTER GDEM, 30 m cells); a coarse DEM "
        "misplaces the terrain height by hundreds of metres, and at a gimbal roll of "
        f"{abs(inp.gimbal_roll_deg):.0f} deg a height error moves the target about as much "
        "horizontally. Without terrain (`--no-dem`) the published positions come back to 0.3 m"
    )


#: The note a tab shows while its session is built (removed once the scene and the panel are sent).
LOADING_NOTE = (
    "**Loading the scene...** locating every frame of the flight and sending the terrain takes a few "
    "seconds (longer while another tab is being built)"
)


def record_options(scn) -> list:
    """The record dropdown's entries: each record's one name (:func:`geoloc_viz.model.frame_name`
    without the range: its frame index, time and own label), as the timeline and the panels name it."""
    return [frame_name(scn, k, of=False) for k in range(len(scn.records))]


def legend_markdown(scn) -> str:
    """The Legend folder of a scenario, written from what its scene draws: the markers its records
    carry (a [Q17] published point, or a MISB reported frame centre; a surveyed point only with
    truth), the frames of its own sensor by name, and the flight layer's colours for a flight."""
    from geoloc_viz.scene_geoloc import frame_style

    recs = [info for info, _ in scn.records]
    has_truth = any(np.isfinite(i.truth_lat_deg) for i in recs)
    has_paper = any(np.isfinite(i.paper_lat_deg) for i in recs)
    q17 = has_truth  # a published point beside a surveyed one: [Q17]'s records; else a reported one
    frames = drawn_frames(scn.camera)
    names = ", ".join(frame_style(f, k)[1].split(":")[0] for k, f in enumerate(frames))
    w = palette.word  # every colour word is the colour table's name of what is drawn
    L = [
        f"- {w('result')} ball: the chosen method's answer; {w('exact')}: the exact first hit; {w('hmax')}: "
        "the ellipsoid hit at H_max (where [Q17]'s steps start)",
        f"- {w('los')} line: line of sight (also one target's lines of sight from several frames, Picture "
        f"folder), {w('los_beyond')} beyond the answer; {w('frustum')}: image footprint (corner rays)",
        "- iterations: dots on the line of sight at H_n with a segment to the DEM height h_n below, "
        f"{w('above')} if H_n - h_n > 0 (above the terrain), {w('below')} below; {w('bracket')}: bisection brackets",
    ]
    if has_paper:
        pub = "published position" + (" [Q17]" if "qiao2017" in str(getattr(scn, "source", "")) else "")
        L.append(
            f"- {w('published')}: "
            + (pub if q17 else "reported position (the record's own, e.g. the MISB frame centre)")
        )
    if has_truth:
        L.append(
            f"- {w('surveyed')}: surveyed; {w('error')}: error vector computed -> surveyed, at true length unless "
            '"error vector drawn x" enlarges it (its label then says the factor, e.g. x10)'
        )
    L.append(
        f"- {w('ellipse')} ring on the terrain: the predicted 90 % error ellipse of the located point, at "
        'true size unless "ellipse drawn x" enlarges it (its label then says the factor, e.g. x10)'
    )
    L.append(
        f'- {w("bent")} line (with refraction on, "Refraction" folder): the bent ray from the camera to '
        f"the located point, beside the straight line of sight ({palette.PALETTE['los'].name}, then ending at "
        'its own hit); its offset drawn at true size unless "bent ray drawn x" enlarges it (its label then says x100)'
    )
    if getattr(scn, "images", None) is not None:
        L.append(
            f"- picks (Picture folder): {w('pick')} a picked pixel's ray and ground point; {w('ground')} a picked "
            f"terrain point ({w('ground_hidden')}: hidden from the camera)"
        )
    L += [
        '- the aircraft is drawn larger than life by the "aircraft display scale" factor; frames scale with it',
        f"- frames at the aircraft, largest first: {names}; axes x red, y green, z blue",
        "- scene: East-North-Up at the target, world unit km; zoom with the wheel, rotate with the "
        "left button, pan with the right",
    ]
    if len(recs) > 1:
        L.append(
            f"- flight (every frame): {w('track')} track; {w('footprint_outlier')}: flagged, the outliers' footprints "
            f"and the runs (thick, labelled with their fault); footprints {w('footprint')}, the current one "
            f"{w('current')}; centres {w('centre')}; points {w('published')} / {w('result')} / {w('surveyed')}: "
            f"reported / recomputed (the answer) / truth; {w('errors')}: every frame's error vector; "
            f"{w('error')}: the current frame's, labelled with its length"
        )
    return "\n".join(L) + "\n"


def make_server(host: str = "127.0.0.1", port: int = 8080, verbose: bool = False) -> viser.ViserServer:
    """A viser server bound to ``host`` (local only by default); ``port=0`` picks a free port."""
    server = viser.ViserServer(host=host, port=port, label="geoloc", verbose=verbose)
    server.scene.set_up_direction("+z")
    server.gui.configure_theme(**THEME)
    # viser's default fog is tuned for scenes of a few metres; ours spans tens of km.
    server.scene.configure_fog(1.0, 1.0, enabled=False)
    configure_lighting(server.scene)
    return server


def configure_lighting(scene) -> None:
    """The lights of a viewer scene (again after a ``scene.reset()``, which removes the ambient one).

    Shadow maps over tens of km cost much and show little (and are slow in software WebGL). No
    environment map (viser's client loads its "city" one unless told otherwise): with software
    WebGL its decoding and prefiltering held the first view back, the canvas fading in only once
    it was loaded; an ambient light lifts the lit markers' shadowed sides instead.
    """
    scene.configure_default_lights(True, cast_shadow=False)
    scene.configure_environment_map(None)
    scene.add_light_ambient(AMBIENT_LIGHT, intensity=AMBIENT_INTENSITY)


def release_memory() -> None:
    """Free the dropped sessions now and hand freed heap back to the OS.

    A session holds reference cycles (its GUI callbacks refer to it), so only the cyclic
    collector frees it; and glibc keeps freed memory in the arenas of viser's callback
    threads (32 of them) instead of returning it: measured over 120 tabs opened and closed,
    RSS stayed 50 MB above idle after ``gc.collect()`` and fell back below idle after
    ``malloc_trim(0)`` (``benchmarks/bench_viz_churn.py``).
    """
    import gc

    gc.collect()
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to trim
        pass


def _set_camera(client, pos, aim) -> None:
    # viser moves look_at with the position (keeping the orientation): set the position
    # first, then the point to look at
    with client.atomic():
        client.camera.up_direction = (0.0, 0.0, 1.0)
        client.camera.position = tuple(float(x) for x in pos)
        client.camera.look_at = tuple(float(x) for x in aim)


class GeolocSession:
    """One viewer state (scenario, inputs, display, scene, GUI); interface in the module docstring.

    Parameters
    ----------
    server : viser.ViserServer
    scn : Scenario
        The scenario; with ``copy_scenario`` the session works on a copy, so
        loading another record leaves ``scn`` (and other sessions) alone.
    disp : Display, optional
        Display settings (copied with ``copy_scenario``).
    client : viser.ClientHandle, optional
        The tab this session belongs to: it draws on ``client.scene`` and
        ``client.gui`` unless ``scene`` / ``gui`` say otherwise. None: the server.
    scene, gui : optional
        Override where the session draws and where its controls go (presenter
        mode: the shared ``server.scene`` with the driver's ``client.gui``).
    layers : sequence of callables, optional
        ``attach_fn(session)`` each; default :data:`DEFAULT_LAYERS`.
    inputs : Inputs, optional
        Start from these inputs instead of the scenario's (a presenter hand-over).
    """

    def __init__(
        self,
        server: viser.ViserServer,
        scn: Scenario,
        disp: Display | None = None,
        *,
        client=None,
        scene=None,
        gui=None,
        layers=None,
        inputs: Inputs | None = None,
        copy_scenario: bool = False,
    ):
        self.server = server
        self.client = client
        self.scene = scene if scene is not None else (client.scene if client is not None else server.scene)
        self.gui = gui if gui is not None else (client.gui if client is not None else server.gui)
        if copy_scenario:
            scn = copy.copy(scn)
            disp = dataclasses.replace(disp, frames_visible=dict(disp.frames_visible)) if disp else None
        self.scn = scn
        self.view = GeolocScene(self.scene, scn, disp)
        self.inputs: Inputs = (inputs or scn.inputs).replace()
        self.geometry: Geometry | None = None
        self.error: str = ""
        self.last_update_s = float("nan")
        self.closed = False
        self._mute = False
        self._lock = threading.RLock()
        self._refresh_cbs: list = []
        self._deferred_cbs: list = []
        self._later: list = []  # later(fn) calls of the running step, run first in its panels' batch
        self._carry = False  # a skipped step's panels' batch waits for the next step
        self._defer_depth = 0
        self._deferred_due: Geometry | None = None
        self._record_cbs: list = []
        self.layers: list = []
        self.calibration = None
        self._build_gui()
        if inputs is not None:
            self._sync_record_box()
        self.view.draw_static()
        self.refresh()
        if client is None:
            self.view.set_initial_camera(server)
        for attach in DEFAULT_LAYERS if layers is None else layers:
            obj = attach(self)
            self.layers.append(obj)
            if attach is calibration_layer.attach:
                # error vectors of all records, before/after a fitted mounting rotation: what calibration removes
                self.calibration = obj

    # ------------------------------------------------------------ interface
    def on_refresh(self, callback, deferred: bool = False):
        """Register ``callback(geometry)``, called after each redraw; returns it (a decorator).

        ``deferred``: a panel's work (the picture, the teaching text), which during a timeline step
        (:meth:`deferring`) runs after the step's scene went out, in a second batch, and is skipped
        when a newer step is already waiting."""
        (self._deferred_cbs if deferred else self._refresh_cbs).append(callback)
        return callback

    def later(self, fn: Callable[[], None]) -> None:
        """``fn()`` now, or within :meth:`deferring` with the panels' batch, before the deferred
        callbacks (a follower's mirror copies what it wrote). For GUI text the step's scene does not
        need: a scene batch with no markdown in it is applied by the browser sooner (its messages
        are handled in the frame that draws them), and the panels' batch, GUI only, without a frame."""
        if self._defer_depth:
            self._later.append(fn)
        else:
            fn()

    @contextlib.contextmanager
    def deferring(self, skip: Callable[[], bool] = lambda: False) -> Iterator[None]:
        """Within: a redraw leaves its deferred callbacks (``on_refresh(..., deferred=True)``) for
        later. On exit (after the caller's atomic batch, flushed: the browser draws the scene
        first), they run in a batch of their own, unless ``skip()`` (a newer step waits, which
        will run them)."""
        with self._lock:
            if not self._defer_depth and not self._carry:
                self._deferred_due = None  # (left by a step that raised)
                self._later.clear()
            self._carry = False
            self._defer_depth += 1
            try:
                yield
            except BaseException:
                self._later.clear()
                raise
            finally:
                self._defer_depth -= 1
            if self._defer_depth:  # an outer deferring() runs them
                return
            g, self._deferred_due = self._deferred_due, None
            later, self._later = self._later, []
            if (g is None and not later) or self.closed:
                return
            self._send_scene()
            if skip():
                # the waiting step runs them (after its own: a step back to the frame already loaded
                # redraws nothing, and its panels would otherwise keep the frame before)
                self._deferred_due, self._later, self._carry = g, later, True
                return
            with self._atomic():
                for fn in later:
                    self._call(lambda _g, fn=fn: fn(), g)
                if g is not None:
                    for cb in list(self._deferred_cbs):
                        self._call(cb, g)

    def _send_scene(self, timeout_s: float = SEND_WAIT_S) -> None:
        """Flush the step's scene batch and wait (at most ``timeout_s``) until viser's sender has
        taken it for every browser, before the panels' batch opens its atomic block.

        viser's sender (its event loop thread) takes no message while an atomic block is open
        (``AsyncMessageBuffer``'s window loop checks ``atomic_counter``), and ``flush`` only
        schedules it: the panels' block, opened at once, held the scene back until the panels were
        done, so a step's first canvas change waited for the panels' work too. Private viser state
        (its message buffer's per-browser cursors) is read here; without it nothing waits."""
        target = self.client if self.client is not None else self.server
        target.flush()
        conn = getattr(target, "_websock_connection", None) or getattr(target, "_websock_server", None)
        buf = getattr(conn, "get_message_buffer", lambda: None)()
        cursors, last = getattr(buf, "generator_cursors", None), getattr(buf, "message_counter", 0) - 1
        if buf is None or not isinstance(cursors, dict):  # another viser: no wait
            return
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not buf.done:
            left = [c for c in list(cursors.values()) if c < last]
            if not left:
                return
            time.sleep(0.001)  # the sender needs the GIL

    def on_record(self, callback):
        """Register ``callback(idx)``, called after record ``idx`` is loaded, before the redraw."""
        self._record_cbs.append(callback)
        return callback

    def move_camera(self, kind) -> None:
        """This tab's camera (a server session: every tab's) to a named view or a
        ``(position, look_at)`` pair in scene units; see :meth:`GeolocScene.camera_pose`."""
        if isinstance(kind, str):
            if self.geometry is None:
                return
            pos, aim = self.view.camera_pose(kind)
        else:
            pos, aim = (np.asarray(v, float) for v in kind)
            if pos.shape != (3,) or aim.shape != (3,):
                raise ValueError(
                    f"move_camera: kind = {kind!r}: 'overview', 'target' or a (position, look_at) pair of 3-vectors"
                )
        clients = [self.client] if self.client is not None else list(self.server.get_clients().values())
        for c in clients:
            try:
                _set_camera(c, pos, aim)
            except Exception:  # a tab that left while we moved it: nothing to move
                pass

    def close(self) -> None:
        """Drop callbacks and layers (the tab's GUI and scene go with its connection)."""
        self.closed = True
        for obj in self.layers:
            if hasattr(obj, "close"):
                try:
                    obj.close()
                except Exception:
                    traceback.print_exc(file=sys.stderr)
        self._refresh_cbs.clear()
        self._deferred_cbs.clear()
        self._record_cbs.clear()
        self.layers.clear()
        self.calibration = None

    def _atomic(self):
        return (self.client if self.client is not None else self.server).atomic()

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.gui
        self.md_summary = gui.add_markdown("")
        labels = record_options(self.scn)
        with gui.add_folder("Flight-test record"):
            init = labels[self.scn.record_index] if self.scn.record_index is not None else CUSTOM
            self.dd_record = gui.add_dropdown(
                "record",
                labels + [CUSTOM],
                initial_value=init,
                hint="Load a record by its frame index (the timeline's), its time and its own label",
            )
            self.dd_record.on_update(self._on_record)
        with gui.add_folder("Aircraft and gimbal"):
            i = self.inputs
            self.num = {
                "lat_deg": gui.add_number("latitude (deg)", i.lat_deg, min=-90.0, max=90.0, step=1e-5),
                "lon_deg": gui.add_number("longitude (deg)", i.lon_deg, min=-180.0, max=180.0, step=1e-5),
                "h_m": gui.add_number("height (m, ellipsoidal)", i.h_m, min=0.0, max=1e5, step=0.01),
            }
            for key, label, lo, hi, step in self._angle_sliders():
                self.num[key] = gui.add_slider(label, lo, hi, step, self._input_value(i, key))
            self.num["row"] = gui.add_number("pixel row i", i.row, step=0.01)
            self.num["col"] = gui.add_number("pixel column j", i.col, step=0.01)
            for h in self.num.values():
                h.on_update(self._on_inputs)
        with gui.add_folder("Terrain method", expand_by_default=False):
            from geoloc_viz import terrain_link

            self.dd_method = gui.add_dropdown("method", terrain_link.METHODS, initial_value=i.method)
            self.num_eps = gui.add_number("eps_h steps (m)", i.eps_h, min=0.1, max=1000.0, step=0.1)
            self.num_thr = gui.add_number("bisect threshold (m)", i.threshold, min=0.01, max=1000.0, step=0.01)
            for h in (self.dd_method, self.num_eps, self.num_thr):
                h.on_update(self._on_inputs)
            self.cb_all_steps = gui.add_checkbox("show all iterations", True)
            self.sl_step = gui.add_slider("iteration n", 0, 1, 1, 0, disabled=True)
            self.cb_all_steps.on_update(self._on_display)
            self.sl_step.on_update(self._on_display)
        with gui.add_folder("View"):
            self.bt_overview = gui.add_button("overview: aircraft, frames, line of sight")
            self.bt_target = gui.add_button("target: iterations and hits")
            self.bt_overview.on_click(lambda _: self.move_camera("overview"))
            self.bt_target.on_click(lambda _: self.move_camera("target"))
        with gui.add_folder("Legend", expand_by_default=False):
            self.md_legend = gui.add_markdown(legend_markdown(self.scn))
        with gui.add_folder("Display", expand_by_default=False):
            d = self.view.disp
            self.sl_vexag = gui.add_slider("vertical exaggeration", 1.0, 10.0, 0.5, d.vertical_exaggeration)
            self.sl_ac = gui.add_slider(
                "aircraft display scale",
                1.0,
                300.0,
                1.0,
                d.aircraft_scale,
                hint="The aircraft is drawn this many times its size (display only)",
            )
            self.sl_err = gui.add_slider(
                "error vector drawn x",
                1.0,
                100.0,
                1.0,
                d.error_exaggeration,
                hint="Draw the error vector (and the picture's triangulation residuals and ellipse) this many "
                "times their size; 1 is true size. The label on the drawing says the factor and the true length",
            )
            self.sl_marker = gui.add_slider(
                "marker radius (m)",
                0.25,
                500.0,
                0.25,
                d.marker_radius_m,
                hint="Radius of the hit markers; the flight layer sizes them to the current frame's error",
            )
            self.cb_frames = {
                f: gui.add_checkbox(f"frame {f}", d.frames_visible.get(f, True)) for f in drawn_frames(self.scn.camera)
            }
            self.cb_terrain = gui.add_checkbox("terrain", d.terrain_visible)
            self.cb_labels = gui.add_checkbox(
                "marker labels", d.marker_labels, hint="Labels of the hit markers (they overlap until you zoom in)"
            )
            for h in (
                self.sl_vexag,
                self.sl_ac,
                self.sl_err,
                self.sl_marker,
                self.cb_terrain,
                self.cb_labels,
                *self.cb_frames.values(),
            ):
                h.on_update(self._on_display)
        with gui.add_folder("Teaching: the chain of 4x4 matrices", expand_by_default=False):
            hops0 = teaching.hops(self._chain0())
            self._hop_src = {h.key: h.src for h in hops0}
            self.dd_hop = gui.add_dropdown(
                "hop", ["(none)"] + [h.key for h in hops0], hint="With the teaching panel: follows its 'teaching hop'"
            )
            self.dd_hop.on_update(self._on_display)
            self.md_hop = gui.add_markdown("")
            self.md_q17 = gui.add_markdown("")

    def _chain0(self):
        return self.scn.camera.frames(self.inputs.pose())

    def _angle_sliders(self):
        """Attitude sliders, then one per joint angle of the sensor's gimbal (``angle:NAME`` keys)."""
        out = list(ANGLE_SLIDERS[:3])
        sensor = self.scn.camera
        # [Q17]'s gimbal ranges only for its roll-pitch gimbal: a DJI gimbal_pitch runs to -90
        q17 = (
            {row[0][:-4]: row for row in ANGLE_SLIDERS[3:]}
            if getattr(getattr(sensor, "gimbal", None), "name", "roll-pitch") == "roll-pitch"
            else {}
        )
        for name in sensor.angle_names:
            # azimuths run 0..360 and some joints wind further: the whole valid range of a joint angle
            out.append(q17.get(name, (f"angle:{name}", f"{name.replace('_', ' ')} (deg)", -360.0, 360.0, 0.0001)))
        return out

    @staticmethod
    def _input_value(inp: Inputs, key: str) -> float:
        if key.startswith("angle:"):
            return float(inp.angles_deg.get(key[6:], 0.0))
        return float(getattr(inp, key))

    def _read_inputs(self) -> Inputs:
        vals = {k: float(h.value) for k, h in self.num.items() if not k.startswith("angle:")}
        angles = {k[6:]: float(h.value) for k, h in self.num.items() if k.startswith("angle:")}
        return self.inputs.replace(
            method=str(self.dd_method.value),
            eps_h=float(self.num_eps.value),
            threshold=float(self.num_thr.value),
            angles_deg=angles,
            **vals,
        )

    def _read_display(self) -> None:
        d = self.view.disp
        d.vertical_exaggeration = float(self.sl_vexag.value)
        d.aircraft_scale = float(self.sl_ac.value)
        d.error_exaggeration = float(self.sl_err.value)
        d.marker_radius_m = float(self.sl_marker.value)
        d.frames_visible = {f: bool(cb.value) for f, cb in self.cb_frames.items()}
        d.terrain_visible = bool(self.cb_terrain.value)
        d.marker_labels = bool(self.cb_labels.value)
        d.step = None if self.cb_all_steps.value else int(self.sl_step.value)
        hop = str(self.dd_hop.value)
        # Selecting a hop T_dst_src highlights the frame it maps from.
        d.highlight = None if hop == "(none)" else self._hop_src.get(hop)

    def _is_custom(self) -> bool:
        """True when the inputs differ from the loaded record's pose and pixel."""
        if self.scn.record_index is None:
            return True
        rec_inp = self.scn.records[self.scn.record_index][1]
        return any(abs(self._input_value(self.inputs, k) - self._input_value(rec_inp, k)) > 1e-9 for k in self.num)

    def _sync_record_box(self) -> None:
        if self._is_custom() and self.dd_record.value != CUSTOM:
            self._mute = True
            try:
                # viser's value setter is not next to its getter: mypy sees the property read-only
                self.dd_record.value = CUSTOM  # type: ignore[misc]
            finally:
                self._mute = False

    # ------------------------------------------------------------ callbacks
    def _on_inputs(self, event=None) -> None:
        if self.closed or own_update(self, event):
            return
        with self._lock:
            self.inputs = self._read_inputs()
            if self.dd_record.value != CUSTOM:
                self._sync_record_box()
            self.refresh()

    def _on_display(self, event=None) -> None:
        if self.closed or own_update(self, event):
            return
        with self._lock:
            self._read_display()
            self.refresh(recompute=False)

    def _on_record(self, event=None) -> None:
        if self.closed or own_update(self, event) or self.dd_record.value == CUSTOM:
            return
        labels = record_options(self.scn)
        if self.dd_record.value in labels:
            self.load_record(labels.index(self.dd_record.value))

    def record_option(self, key) -> str:
        """The record dropdown's entry of record ``key`` (its index, or its own label, e.g. "T4-1")."""
        if not isinstance(key, (int, np.integer)):
            key = [info.label for info, _ in self.scn.records].index(key)
        return frame_name(self.scn, int(key), of=False)

    def load_record(self, idx: int, move_camera: bool = True) -> None:
        """Load record ``idx``: pose, pixel, new ENU origin and terrain, redraw, and (``move_camera``)
        move this tab's camera (a server session: every tab's) to frame the aircraft and target.

        The static scene (origin, grid, terrain, aircraft mesh) is redrawn only when the
        record's rounded ENU origin or its DEM differs from the last one's: the frames of
        a flight share them, and a timeline step then updates only the moving parts.
        """
        with self._lock:
            before = self._static_key()
            select_record(self.scn, idx)
            keep = self.inputs
            self.inputs = self.scn.inputs.replace(method=keep.method, eps_h=keep.eps_h, threshold=keep.threshold)
            inputs = self.inputs

            def boxes() -> None:  # the pose and pixel boxes (with a step's panels: no frame waits for them)
                self._mute = True
                try:
                    for k, h in self.num.items():
                        # viser's value setter is not next to its getter: mypy sees the property read-only
                        h.value = self._input_value(inputs, k)  # type: ignore[misc]
                finally:
                    self._mute = False

            self.later(boxes)
            self._mute = True
            try:
                label = frame_name(self.scn, idx, of=False)
                if self.dd_record.value != label:
                    # viser's value setter is not next to its getter: mypy sees the property read-only
                    self.dd_record.value = label  # type: ignore[misc]
            finally:
                self._mute = False
            with self._atomic():
                if self._static_key() != before:
                    self.view.draw_static()
                for cb in list(self._record_cbs):
                    self._call(cb, idx)
            self.refresh()
            if not move_camera:
                return
            if self.client is None:
                self.view.set_initial_camera(self.server)
            self.move_camera("overview")

    def _static_key(self) -> tuple:
        """What the static scene depends on: the ENU origin and the DEM."""
        e = self.scn.enu
        return (float(e.lat0), float(e.lon0), float(e.h0), id(self.scn.dem))

    def _call(self, cb, arg) -> None:
        try:
            cb(arg)
        except Exception:  # a layer's bug must not take the viewer down: report it
            print(f"geoloc view: error in a layer callback {getattr(cb, '__qualname__', cb)}:", file=sys.stderr)
            traceback.print_exc(file=sys.stderr)

    # ------------------------------------------------------------ redraw
    def refresh(self, recompute: bool = True) -> None:
        """Recompute with the core (unless only the display changed) and redraw; time it;
        then call the ``on_refresh`` callbacks with the geometry."""
        with self._lock:
            t0 = time.perf_counter()
            if recompute or self.geometry is None:
                try:
                    self.geometry = compute(self.scn, self.inputs)
                    self.error = ""
                except ValueError as e:
                    self.error = str(e)
            g = self.geometry
            if g is not None:
                it = g.iterations
                n = 0 if it is None else len(it.H)
                self._mute = True
                try:
                    self.sl_step.max = max(n - 1, 1)
                    self.sl_step.disabled = n == 0 or bool(self.cb_all_steps.value)
                    if self.sl_step.value > n - 1:
                        # viser's value setter is not next to its getter: mypy sees the property read-only
                        self.sl_step.value = max(n - 1, 0)  # type: ignore[misc]
                finally:
                    self._mute = False
                with self._atomic():
                    self.view.update(g)
                self.later(lambda: self._update_text(g))
            self.last_update_s = time.perf_counter() - t0
            if g is not None:
                for cb in list(self._refresh_cbs):
                    self._call(cb, g)
                if self._defer_depth:
                    self._deferred_due = g
                else:
                    for cb in list(self._deferred_cbs):
                        self._call(cb, g)

    def header(self) -> str:
        """The panel's title: the records file and record, or a custom pose and where it came from."""
        scn = self.scn
        if scn.record_index is None:
            return f"{scn.name} (custom pose)"
        name = frame_name(scn, scn.record_index, of=False)
        if self.dd_record.value == CUSTOM:
            return f"{scn.source or scn.name}: custom pose (edited from {name})"
        # the records file and the frame's one name (its label, e.g. "packet 203", only inside it)
        return f"{scn.source}: {name}" if scn.source else scn.name

    def _update_text(self, g) -> None:
        scn, enu = self.scn, self.scn.enu
        d = self.view.disp
        inp = self.inputs
        if scn.dem is None:
            method = f"method: hit at the target height {inp.target_h:.1f} m (ellipsoidal); no DEM"
        else:
            method = f"method: {METHOD_NAMES.get(inp.method, inp.method)}"
            method += (
                f", eps_h {inp.eps_h:g} m"
                if inp.method == "steps"
                else f", threshold {inp.threshold:g} m"
                if inp.method == "bisect"
                else ""
            )
        lines = [
            f"**{self.header()}**  ",
            f"{frame_name(scn, scn.record_index)}; pixel row {inp.row:g}, column {inp.col:g} in "
            f"{getattr(scn, 'pixel_grid', None) or f'the sensor grid, {scn.camera.cols} x {scn.camera.rows} px'}  ",
            f"terrain: {scn.dem_name}  ",
            method + "  ",
            f"scene: local East-North-Up, origin {np.rad2deg(enu.lat0):.3f} N "
            f"{np.rad2deg(enu.lon0):.3f} E h {enu.h0:.0f} m; scale bar 5 km  ",
            f"aircraft drawn x{d.aircraft_scale:g} (display only)  ",
        ]
        if self.error:
            lines.append(f"\n**input error:** {self.error}")
        hit = g.hit
        if int(hit.status) == 0:
            lines.append(
                f"\n**{g.hit_label}**: {float(hit.lat_deg):.6f} N, {float(hit.lon_deg):.6f} E, "
                f"h {float(hit.h):.1f} m, slant range {float(hit.slant_range) / 1e3:.2f} km  "
            )
            lines.append(mgrs_text(float(hit.lat_deg), float(hit.lon_deg)) + "  ")  # the grid reference a user hands on
            if getattr(hit, "corrections", ()):  # which corrections moved the point, and refraction's shift
                shift = float(np.asarray(getattr(hit, "refraction_m", np.nan)))
                lines.append(
                    f"corrections: {'+'.join(hit.corrections)}"
                    + (f"; refraction moved the point {shift:.3f} m  " if np.isfinite(shift) else "  ")
                )
        else:
            lines.append(f"\n**no hit**: {describe(int(hit.status))}  ")
        if g.message:
            lines.append(g.message + "  ")
        if scn.record_index is not None and self.dd_record.value != CUSTOM:
            info = scn.records[scn.record_index][0]
            from geoloc.geodesy.geodesic import horizontal_distance_m

            if int(hit.status) == 0 and np.isfinite(info.truth_lat_deg):
                e_t = float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, info.truth_lat_deg, info.truth_lon_deg))
                e_p = float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, info.paper_lat_deg, info.paper_lon_deg))
                text = f"to surveyed: {e_t:.1f} m (horizontal)"
                if np.isfinite(info.paper_error_m):
                    text += f" (published error {info.paper_error_m:.1f} m)"
                if np.isfinite(e_p):
                    text += f"; to published: {e_p:.1f} m (horizontal)"
                lines.append(text + "  ")
                why = coarse_dem_note(scn, inp, e_t, info.paper_error_m)
                if why:
                    lines.append(why + "  ")
                if g.surveyed_enu is not None and np.all(np.isfinite(g.hit_enu)):
                    e3 = float(np.linalg.norm(g.surveyed_enu - g.hit_enu))
                    lines.append(
                        f"error vector to surveyed (3D, surveyed point on the terrain): "
                        f"{e3:.1f} m, {drawn_factor(d.error_exaggeration)}  "
                    )
        self.md_summary.content = "\n".join(lines)
        hop = str(self.dd_hop.value)
        hv = {h.key: h for h in teaching.hops(g.chain)}
        self.md_hop.content = teaching.hop_markdown(hv[hop]) if hop in hv else teaching.chain_markdown(g.chain)
        # [Q17] eq. 5's factors belong to T_ecef_ned only (the paper's chain): not under every hop
        self.md_q17.content = teaching.q17_factors_markdown(g.chain) if hop == "T_ecef_ned" else ""


class GeolocApp(GeolocSession):
    """A session on the server itself (``server.scene`` / ``server.gui``): every tab shares it.

    What the static export and scripts use; ``geoloc view`` serves a
    :class:`GeolocViewer` (a session per tab) instead.
    """

    def __init__(self, server: viser.ViserServer, scn: Scenario, disp: Display | None = None, *, layers=None):
        super().__init__(server, scn, disp, layers=layers)

    # ------------------------------------------------------------ export
    def export(self, path, animate_steps: bool = True) -> Path:
        """Write the current scene as a static recording: ``.viser`` or self-contained ``.html``.

        With ``animate_steps`` the recording then walks through the iterations
        of the terrain method one by one (0.4 s each). GUI controls are not exported;
        an ``.html`` page carries the summary panel's text (record, terrain, method,
        hit, errors) instead.
        """
        path = Path(path)
        ser = self.server.get_scene_serializer()
        g = self.geometry
        it = g.iterations if g is not None else None
        if animate_steps and g is not None and it is not None and len(it.H) > 1:
            d = self.view.disp
            saved = d.step
            ser.insert_sleep(1.0)
            for k in range(len(it.H)):
                d.step = k
                self.view.update(g)
                ser.insert_sleep(0.4)
            d.step = saved
            self.view.update(g)
            ser.insert_sleep(1.0)
        if path.suffix.lower() == ".html":
            from geoloc_viz.export_html import with_summary

            # the serializer records the scene, not the GUI: the summary (record, method, hit,
            # errors) goes into the page as a panel of its own
            # what the layers know of this record (the flight layer: its residual, error and fault)
            extra = [obj.export_markdown() for obj in self.layers if hasattr(obj, "export_markdown")]
            text = "\n\n".join([self.md_summary.content] + [t for t in extra if t])
            # and what they show (the picture layer: the frame with its marks and picks)
            extra_html = "".join(obj.export_html() for obj in self.layers if hasattr(obj, "export_html"))
            page = with_summary(
                ser.as_html(dark_mode=True),
                f"geoloc view: {self.header()}",
                text,
                "Static export of geoloc view (no controls); the scene animates the terrain method's iterations.",
                extra_html,
            )
            write_text(path, page)
        else:
            write_bytes(path, ser.serialize())
        return path


def driver_folders(session) -> list:
    """[(folder label, [markdown handles])] of a session's panel, in order: every folder holding
    text (the session's own and its layers'), for a presenter's followers to mirror."""
    gui = session.gui
    containers = getattr(gui, "_container_handle_from_uuid", {})
    groups: dict = {}
    objs = [session] + [o for o in session.layers if o is not None]
    for obj in objs:
        for v in list(vars(obj).values()):
            if not isinstance(v, viser.GuiMarkdownHandle) or v is getattr(session, "md_summary", None):
                continue
            folder = containers.get(getattr(v._impl, "parent_container_id", None))
            label = getattr(folder, "label", None)
            if label:
                groups.setdefault(label, []).append(v)

    # the panel's own order (a folder's order value), then first seen
    def order(item):
        h = item[1][0]
        f = containers.get(h._impl.parent_container_id)
        return float(getattr(f, "order", 0.0) or 0.0)

    return sorted(groups.items(), key=order)


class _FollowerPanel:
    """A presenter-mode follower's GUI: a note, the presenter's panel text and values, read-only."""

    def __init__(self, viewer: "GeolocViewer", client, driver: GeolocSession | None):
        self.client = client
        gui = client.gui
        self.md_note = gui.add_markdown("")
        self.bt_take = gui.add_button("take control", hint="Drive the scene; the presenter becomes a follower")
        cid = client.client_id
        self.bt_take.on_click(lambda _e: viewer.take_control(cid))
        self.dd_scenario = None
        if len(viewer.scenarios) > 1:  # the presenter's scenario, read-only (it follows theirs)
            self.dd_scenario = gui.add_dropdown(
                "scenario",
                tuple(viewer.scenarios),
                initial_value=viewer.driver_scenario,
                disabled=True,
                hint="The presenter's scenario (they switch it)",
            )
        self.viewer = viewer
        self.md_summary = gui.add_markdown("")
        self.num = {}
        self.mirrors: list = []  # (driver's markdown handle, ours)
        if driver is not None:
            with gui.add_folder("Presenter's inputs (read-only)"):
                self.dd_record = gui.add_dropdown(
                    "record", list(driver.dd_record.options), initial_value=driver.dd_record.value, disabled=True
                )
                for k, h in driver.num.items():
                    self.num[k] = gui.add_number(h.label, float(h.value), disabled=True)
            # every folder of the presenter's panel (the session's and its layers': flight,
            # outliers, accuracy, legend, teaching, ...), its text mirrored read-only
            for label, handles in driver_folders(driver):
                with gui.add_folder(label, expand_by_default=False):
                    for h in handles:
                        self.mirrors.append((h, gui.add_markdown(h.content)))
        self.update(driver)

    def update(self, driver: GeolocSession | None) -> None:
        if driver is None:
            return
        who = driver.client.client_id if driver.client is not None else "?"
        self.md_note.content = (
            f"**Presenter mode**: you follow tab #{who}, the presenter; the scene "
            "and the camera are theirs and the controls are read-only. Press "
            '"take control" to drive.'
        )
        self.md_summary.content = driver.md_summary.content
        if self.dd_scenario is not None and self.dd_scenario.value != self.viewer.driver_scenario:
            self.dd_scenario.value = self.viewer.driver_scenario
        for src, dst in self.mirrors:
            if dst.content != src.content:
                dst.content = src.content
        if self.num:
            self.dd_record.value = driver.dd_record.value
            for k, h in self.num.items():
                if k in driver.num:
                    h.value = float(driver.num[k].value)


class GeolocViewer:
    """What ``geoloc view`` serves: a session per browser tab, or presenter mode.

    Parameters
    ----------
    server : viser.ViserServer
    scn : Scenario
        The scenario every new tab starts from (its default record): never modified.
    presenter : bool
        False (default): each tab gets its own :class:`GeolocSession` on its
        ``client.scene`` / ``client.gui``, built on connect, dropped on
        disconnect. True: the first tab to connect drives a session drawn on the
        shared ``server.scene``; the others follow read-only (they see the
        driver's scene and camera and a disabled copy of its inputs) until one
        presses "take control"; when the driver leaves, the longest-connected
        follower drives.
    max_clients : int
        Tabs served at once; a tab beyond gets a message saying the limit and
        how to raise it (``--max-clients``), and a line on stderr.
    layers : sequence of callables, optional
        Passed to every session (default :data:`DEFAULT_LAYERS`).
    scenarios : dict, optional
        Name -> scenario (or a callable building it) for a "scenario" dropdown on top of
        each tab (per-tab mode; presenter mode: on the driver's panel, the followers showing
        it read-only and following it, :meth:`present`): the first entry is ``scn``, the
        others one click away (``geoloc view`` offers the example flight and the [Q17]
        flight test).
    """

    #: What builds a tab's session (same arguments as :class:`GeolocSession`).
    session_factory = GeolocSession

    def __init__(
        self,
        server: viser.ViserServer,
        scn: Scenario,
        disp: Display | None = None,
        *,
        presenter: bool = False,
        max_clients: int = MAX_CLIENTS,
        layers=None,
        scenarios=None,
    ):
        if int(max_clients) != max_clients or max_clients < 1:
            raise ValueError(f"max_clients = {max_clients!r}: must be a whole number >= 1")
        self.server, self.scn, self.disp = server, scn, disp or Display()
        self.presenter, self.max_clients, self.layers = bool(presenter), int(max_clients), layers
        self.sessions: dict[int, GeolocSession] = {}  # per-tab mode: client id -> session
        #: Named scenarios a tab may switch between (a dropdown; per-tab mode), the first being ``scn``;
        #: a value may be a callable building the scenario when first chosen.
        self.scenarios: dict = dict(scenarios or {})
        if self.scenarios:
            self.scenarios[next(iter(self.scenarios))] = scn
        self.tab_scenario: dict[int, str | None] = {}
        self.followers: dict[int, _FollowerPanel] = {}  # presenter mode
        self.driver: GeolocSession | None = None
        #: Presenter mode: the scenario the driver presents (a name of ``scenarios``, or None).
        self.driver_scenario: str | None = next(iter(self.scenarios)) if self.scenarios else None
        self.refused: set[int] = set()
        self._lock = threading.RLock()
        self._release_timer: threading.Timer | None = None
        #: Seconds after the last tab closes before memory is released (a burst of closes: once).
        self.release_delay_s = 0.5
        self.set_initial_camera()
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    def set_initial_camera(self) -> None:
        """New tabs open on the overview of the default record (server.initial_camera)."""
        g = compute(self.scn, self.scn.inputs)
        pos, aim = camera_pose_for(g, self.disp, "overview")
        cam = self.server.initial_camera
        cam.up = (0.0, 0.0, 1.0)
        cam.near = 0.02  # km (world units)
        cam.far = 1000.0
        cam.position = tuple(pos)
        cam.look_at = tuple(aim)

    @property
    def n_served(self) -> int:
        return len(self.sessions) + len(self.followers) + (self.driver is not None)

    def session_of(self, client_id: int) -> GeolocSession | None:
        """The session of a tab (presenter mode: the driver's, for the driver)."""
        if self.driver is not None and self.driver.client is not None and self.driver.client.client_id == client_id:
            return self.driver
        return self.sessions.get(client_id)

    # ------------------------------------------------------------ connections
    def _connected(self, client) -> bool:
        return client.client_id in self.server.get_clients()

    def _on_connect(self, client) -> None:
        # Builds under the viewer's lock (one build at a time: the machine has few cores and a
        # build is CPU bound). viser pops a leaving client from get_clients() before it runs
        # the disconnect callbacks, so a tab that closed while its session was being built is
        # seen below and its session dropped at once (else it would never be freed).
        # A note from the tab's first message on: a build takes seconds (more while another tab's
        # build holds the lock), and an empty page gave no hint that anything was coming.
        note = None
        try:
            note = client.gui.add_markdown(LOADING_NOTE, order=-1e9)
        except Exception:  # the tab left already
            pass
        try:
            self._build_on_connect(client)
        finally:
            if note is not None:
                try:
                    note.remove()
                except Exception:  # the tab left
                    pass

    def _build_on_connect(self, client) -> None:
        with self._lock:
            if not self._connected(client):
                return
            if self.n_served >= self.max_clients:
                self._refuse(client)
                return
            cid = client.client_id
            if not self.presenter:
                self._build_tab(client, next(iter(self.scenarios)) if self.scenarios else None)
            elif self.driver is None:
                self._make_driver(client, None)
                if not self._connected(client):
                    self._drop(client)
            else:
                self.followers[cid] = _FollowerPanel(self, client, self.driver)
                self._follow_camera_of(self.driver.client)
                if not self._connected(client):
                    self.followers.pop(cid, None)

    def _scenario(self, name):
        """The scenario a tab starts from: the viewer's own, or the named alternative (built once)."""
        if name is None:
            return self.scn
        sc = self.scenarios[name]
        if callable(sc):
            sc = self.scenarios[name] = sc()
        return sc

    def _build_tab(self, client, name) -> None:
        """Build a tab's session on scenario ``name`` (a scenario dropdown on top when there are several)."""
        cid = client.client_id
        if len(self.scenarios) > 1:
            dd = client.gui.add_dropdown(
                "scenario", tuple(self.scenarios), initial_value=name, hint="Open another bundled scenario in this tab"
            )
            dd.on_update(lambda _, c=client, d=dd: self.switch(c, str(d.value)))
        s = self.session_factory(
            self.server, self._scenario(name), self.disp, client=client, layers=self.layers, copy_scenario=True
        )
        if self._connected(client):
            self.sessions[cid] = s
            self.tab_scenario[cid] = name
        else:
            s.close()

    def switch(self, client, name: str) -> None:
        """Open scenario ``name`` in this tab: its session is dropped and a new one built (one click)."""
        with self._lock:
            cid = client.client_id
            if name not in self.scenarios or self.tab_scenario.get(cid) == name or not self._connected(client):
                return
            old = self.sessions.pop(cid, None)
            if old is not None:
                old.close()
            client.gui.reset()
            client.scene.reset()
            self._build_tab(client, name)
            s = self.sessions.get(cid)
            if s is not None:
                s.move_camera("overview")

    def _schedule_release(self) -> None:
        if self._release_timer is not None:
            self._release_timer.cancel()
        self._release_timer = threading.Timer(self.release_delay_s, release_memory)
        self._release_timer.daemon = True
        self._release_timer.start()

    def _on_disconnect(self, client) -> None:
        try:
            self._drop(client)
        finally:
            self._schedule_release()

    def _drop(self, client) -> None:
        cid = client.client_id
        with self._lock:
            self.refused.discard(cid)
            self.tab_scenario.pop(cid, None)
            s = self.sessions.pop(cid, None)
            if s is not None:
                s.close()
            self.followers.pop(cid, None)
            if self.driver is not None and self.driver.client is client:
                old, self.driver = self.driver, None
                old.close()
                if self.followers:
                    nxt = next(iter(self.followers))
                    panel = self.followers.pop(nxt)
                    try:
                        panel.client.gui.reset()  # its follower panel goes; the driver's comes
                    except Exception:
                        pass
                    self._make_driver(panel.client, old)
                    self._mirror()

    def _refuse(self, client) -> None:
        self.refused.add(client.client_id)
        n = self.max_clients
        text = (
            f"This viewer serves at most **{n}** browser tabs at once (`--max-clients {n}`), "
            f"and {self.n_served} are open. Close another tab and reload this page, or restart "
            f"the server with a higher limit: `geoloc view --max-clients {2 * n}`."
        )
        try:
            with client.gui.add_modal("geoloc view: too many browser tabs"):
                client.gui.add_markdown(text)
            client.gui.add_markdown("**Not served:** " + text)
        except Exception:  # it left already
            pass
        print(
            f"geoloc view: refused browser tab #{client.client_id}: {self.n_served} of "
            f"--max-clients {n} already served (raise it with --max-clients)",
            file=sys.stderr,
            flush=True,
        )

    # ------------------------------------------------------------ presenter mode
    def _make_driver(self, client, old: GeolocSession | None) -> GeolocSession:
        """Build the driving session on ``client.gui`` and the shared scene, from ``old``'s state
        (None: the presented scenario's default record); with several scenarios a "scenario"
        dropdown on top switches what is presented (:meth:`present`). Returns it (also
        :attr:`driver`)."""
        if len(self.scenarios) > 1:
            dd = client.gui.add_dropdown(
                "scenario",
                tuple(self.scenarios),
                initial_value=self.driver_scenario,
                hint="Present another bundled scenario (the followers follow)",
            )
            dd.on_update(lambda _, d=dd: self.present(str(d.value)))
        if old is None:
            driver = self.session_factory(
                self.server,
                self._scenario(self.driver_scenario),
                self.disp,
                client=client,
                scene=self.server.scene,
                layers=self.layers,
                copy_scenario=True,
            )
        else:
            driver = self.session_factory(
                self.server,
                old.scn,
                old.view.disp,
                client=client,
                scene=self.server.scene,
                layers=self.layers,
                inputs=old.inputs,
                copy_scenario=True,
            )
        # deferred, and registered after the layers' own: during a step the panels' text (the share
        # panel's CE90, the picture) is written in the deferred batch, and the followers copy it after
        self.driver = driver
        driver.on_refresh(lambda _g: self._mirror(), deferred=True)
        cid = client.client_id
        client.camera.on_update(lambda cam: self._on_driver_camera(cid, cam))
        return driver

    def present(self, name: str) -> None:
        """Presenter mode: the driver presents scenario ``name`` (one click in its "scenario"
        dropdown); the shared scene is rebuilt on it and every follower's panel follows (its
        folders are the new session's)."""
        with self._lock:
            d = self.driver
            if d is None or name not in self.scenarios or name == self.driver_scenario:
                return
            client = d.client
            d.close()
            self.driver = None
            self.driver_scenario = name
            try:
                client.gui.reset()
            except Exception:
                pass
            self.server.scene.reset()
            configure_lighting(self.server.scene)
            driver = self._make_driver(client, None)
            for cid, panel in list(self.followers.items()):
                try:
                    panel.client.gui.reset()
                    self.followers[cid] = _FollowerPanel(self, panel.client, driver)
                except Exception:  # a follower that left meanwhile
                    self.followers.pop(cid, None)
            driver.move_camera("overview")
            self._mirror()

    def take_control(self, client_id: int) -> None:
        """Presenter mode: the follower ``client_id`` drives; the driver follows."""
        with self._lock:
            panel = self.followers.pop(client_id, None)
            if panel is None or self.driver is None:
                return
            old = self.driver
            old.close()
            old_client = old.client
            try:
                old_client.gui.reset()
            except Exception:
                pass
            panel.client.gui.reset()
            self._make_driver(panel.client, old)
            if old_client is not None and old_client.client_id in self.server.get_clients():
                self.followers[old_client.client_id] = _FollowerPanel(self, old_client, self.driver)
            self._mirror()

    def _mirror(self) -> None:
        for p in list(self.followers.values()):
            try:
                p.update(self.driver)
            except Exception:  # a follower that left meanwhile
                pass

    def _on_driver_camera(self, cid: int, cam) -> None:
        d = self.driver
        if d is None or d.client is None or d.client.client_id != cid:
            return  # an old driver's camera: not followed any more
        self._follow_camera_of(d.client)

    def _follow_camera_of(self, client) -> None:
        # every driver camera message (the browser already rate-limits them): no throttle
        # here, so the followers always end on the driver's last view
        cam = client.camera
        pos, aim = np.array(cam.position), np.array(cam.look_at)
        for p in list(self.followers.values()):
            try:
                _set_camera(p.client, pos, aim)
            except Exception:
                pass
