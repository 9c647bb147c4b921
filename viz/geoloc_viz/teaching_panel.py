"""The teaching panel: a vector through the sensor's chain of frames, in the browser, to teach how each hop turns it.

A layer on a ``geoloc view`` session (:func:`attach`). It walks the sensor's own
frame graph (:class:`geoloc.frames.graph.BoundFrames`), so it works for every
gimbal preset, and shows:

- a vector (a pixel's ray, or any vector typed in any frame) as coordinates in
  **every** frame of the chain, beside the hop's 4x4 matrix and the partial
  products ``T_ecef_<frame>`` (numbers from :mod:`geoloc_viz.teaching`, which
  takes them from the core);
- the frames drawn **apart** in a row above the aircraft (they share one origin
  at the aircraft), a zigzag spaced by what each frame carries (:func:`row_offsets`:
  a turret's frames at one optical centre fanned out, their labels clear of each
  other), every axis labelled ``x <frame>``, ``y <frame>``,
  ``z <frame>``, the vector drawn from each frame's origin with its coordinates
  in that frame; the chosen hop ``T_dst_src`` highlights the source (magenta)
  and the destination (bright cyan) frames;
- ECEF as an inset globe (the Earth scaled to a few km, ECEF axes, the aircraft
  marked, the vector drawn there too), with the [Q17] eq. 5 intermediate frames
  when the hop is ``T_ecef_ned`` (only then is the factor block shown);
- previous / next hop buttons, a "frame the aircraft" view, an aircraft-mesh
  toggle, and "animate this angle from 0" (the chosen attitude or joint angle
  runs from 0 to its value, so signs and directions can be seen).

The session is what ``geoloc_viz.app`` hands its layers: ``.scene``, ``.gui``,
``.scn``, ``.view`` (a :class:`geoloc_viz.scene_geoloc.GeolocScene`),
``.geometry``, ``.inputs``, ``.refresh()``, ``.move_camera(...)``,
``.on_refresh(cb)``; until every app has those, the fallbacks read
``session.server``. The drawing is display only: the row of frames and the globe
are placed for reading, and each frame keeps its true orientation.

Scene nodes (under ``/enu/teach``, world unit km, placed at the aircraft):
``frames/<frame>`` (+ ``/x``, ``/y``, ``/z``, ``/name``, ``/coords`` labels),
``vector`` (arrows), ``highlight/src``, ``highlight/dst``, ``leader``,
``globe`` (+ ``/earth``, ``/axes`` (+ labels), ``/aircraft``, ``/vector``,
``/q17/<k>``).

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from geoloc.geodesy.ellipsoid import A
from geoloc_viz import teaching
from geoloc_viz.palette import TEACHING
from geoloc_viz.scene_geoloc import WORLD_SCALE, wxyz

ROOT = "/enu/teach"
#: Highlight colours (RGB): the hop's source and destination frames.
HIGHLIGHT = {"src": TEACHING["src"].rgb, "dst": TEACHING["dst"].rgb}
VECTOR_COLOR = TEACHING["vector"].rgb
NONE = "(none)"
PIXEL = "pixel ray (row, column)"
TYPED = "typed vector"
#: Frame size in metres per unit of the app's aircraft display scale (200 -> 1 km axes).
UNIT_PER_SCALE_M = 5.0
#: Row layout, in frame sizes U (a frame's axes are U long): the row's lower band above the
#: aircraft, the upper band above the lower (frames alternate between the two, a zigzag, so the
#: labels of neighbours never share a band), the least gap between neighbours.
LIFT, ZIG, GAP_MIN = 8.0, 3.2, 1.6
#: Frames are spaced by what they contain: the labels of frames in one band (every other
#: frame) may not meet. Widths are in label characters, turned into U at the framing scale:
#: "frame the aircraft" shows one U as :data:`PX_PER_U` CSS px, and a character of a label
#: takes at most ``label_layout.CHAR_EM`` em of ``label_layout.EM_PX`` x font scale px.
PX_PER_U = 36.0
AXIS_FONT, TEXT_FONT = 0.8, 0.85
#: Where the GUI panel covers the canvas: this many CSS px on its right side.
PANEL_PX = 400.0
#: Animation: steps and seconds per step.
ANIM_STEPS, ANIM_DT_S = 30, 0.1


def _scene(session):
    return getattr(session, "scene", None) or session.server.scene


def _gui(session):
    return getattr(session, "gui", None) or session.server.gui


#: Gap between the globe's centre and the first frame (ECEF) [U]: its axes (2.4 U) and their
#: labels ("X ecef (0 N, 0 E)", right of the tips) clear of the ECEF frame's.
GLOBE_GAP = 4.0


def label_u(n_chars: int, font: float) -> float:
    """Width [U] of a label of ``n_chars`` characters at font scale ``font`` when one U is
    :data:`PX_PER_U` px (the label layout's own estimate, padding included)."""
    from geoloc_viz import label_layout

    return label_layout.label_size_px("x" * int(n_chars), em_px=label_layout.EM_PX * font)[0] / PX_PER_U


def frame_extent(frame: str, coords_chars: int = 24, tag_chars: int = 12) -> tuple:
    """(left, right) extent [U] about its origin of what a row frame carries: its axes
    (1.25 U when highlighted, tips labelled at 1.08 of that), the axis labels (anchored at the
    tip's left, so they run right), and the name and coordinates labels centred under it."""
    tip = 1.25 * 1.08
    axis = tip + label_u(len(f"x {frame}"), AXIS_FONT)
    name = len(frame) + tag_chars + (len(" (origin: Earth's centre)") if frame == "ecef" else 0)
    text = 0.5 * label_u(max(coords_chars, name), TEXT_FONT)
    return max(tip, text), max(axis, text)


def row_offsets(frames) -> tuple:
    """(x, z) [U] of the row's frames: x along the row from the first, z = 0 (lower band) or
    :data:`ZIG` (upper band) alternately. Frames of one band are spaced so that their extents
    (:func:`frame_extent`) keep 0.4 U apart; neighbours at least :data:`GAP_MIN`."""
    ext = [frame_extent(f) for f in frames]
    x = np.zeros(len(frames))
    for k in range(1, len(frames)):
        x[k] = x[k - 1] + GAP_MIN
        if k >= 2:
            x[k] = max(x[k], x[k - 2] + ext[k - 2][1] + ext[k][0] + 0.4)
    z = np.where(np.arange(len(frames)) % 2 == 0, 0.0, ZIG)
    return x, z


class TeachingPanel:
    """The vector-through-the-chain panel and its scene nodes on one session."""

    def __init__(self, session):
        self.session = session
        self.scene = _scene(session)
        self.gui = _gui(session)
        self.sensor = session.scn.camera
        self.pose_override = None  # set while an animation runs
        self.animating = False
        self._lock = threading.Lock()
        self._handles: dict = {}
        self._mesh_visible = True
        self.anim_steps, self.anim_dt_s = ANIM_STEPS, ANIM_DT_S
        #: Sweeps run so far and the wall time [s] of the last one (start to the true pose redrawn).
        self.anim_count, self.last_anim_s = 0, float("nan")
        self._stop = threading.Event()
        #: A session that debugs a flight (its flight layer attached before this panel) is not a
        #: lesson: the panel starts folded and its row and globe hidden, so they do not sit on the
        #: flight; "frame the aircraft" (or the checkbox) brings them back.
        self.flight_view = any(type(o).__name__ == "FlightLayer" for o in (getattr(session, "layers", None) or ()))
        self._build_gui()
        self._hook_refresh()
        self.redraw()

    def _set_anim_speed(self) -> None:
        """The sweep takes "animation duration (s)": the same steps, each shorter or longer."""
        self.anim_dt_s = float(self.num_anim_s.value) / max(int(self.anim_steps), 1)

    # ------------------------------------------------------------ state
    @property
    def chain(self):
        """The chain being shown: the session's, or the animation's pose."""
        g = self.session.geometry
        pose = self.pose_override if self.pose_override is not None else g.chain.pose
        return self.sensor.frames(pose)

    @property
    def hop(self) -> str | None:
        v = str(self.dd_hop.value)
        return None if v == NONE else v

    def vector(self, chain=None):
        """(v, frame, description) of the vector shown."""
        if str(self.dd_vec.value) == PIXEL:
            r, c = float(self.num_row.value), float(self.num_col.value)
            return teaching.pixel_ray_cam(self.sensor, r, c), "cam", f"the ray of pixel (row {r:g}, column {c:g})"
        v = np.asarray(self.vec3.value, float)
        return (
            v,
            str(self.dd_frame.value),
            f"the vector ({v[0]:g}, {v[1]:g}, {v[2]:g}) given in `{self.dd_frame.value}`",
        )

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui, s = self.gui, self.session
        chain = self.chain
        self.hop_keys = [h.key for h in teaching.hops(chain)]
        frames = list(teaching.chain_frames(chain))
        with gui.add_folder("Teaching: a vector through the chain", expand_by_default=not self.flight_view):
            self.dd_hop = gui.add_dropdown(
                "teaching hop",
                [NONE] + self.hop_keys,
                initial_value="T_ned_body" if "T_ned_body" in self.hop_keys else NONE,
                hint=f"T_dst_src: source frame {TEACHING['src'].name}, destination {TEACHING['dst'].name}",
            )
            self.bt_hops = gui.add_button_group("step hop", ["previous hop", "next hop"])
            self.dd_vec = gui.add_dropdown("vector", [PIXEL, TYPED], initial_value=PIXEL)
            inp = getattr(s, "inputs", None)
            self.num_row = gui.add_number("ray row", float(getattr(inp, "row", self.sensor.center_pixel[0])), step=0.5)
            self.num_col = gui.add_number(
                "ray column", float(getattr(inp, "col", self.sensor.center_pixel[1])), step=0.5
            )
            self.vec3 = gui.add_vector3("typed vector", (1.0, 0.0, 0.0), step=0.1)
            self.dd_frame = gui.add_dropdown(
                "typed in frame", frames, initial_value="body" if "body" in frames else frames[1]
            )
            self.cb_show = gui.add_checkbox("show the frames row and globe", not self.flight_view)
            self.cb_mesh = gui.add_checkbox("aircraft mesh", True, hint="The mesh hides the camera frame")
            self.bt_frame = gui.add_button("frame the aircraft")
            angles = list(teaching.animatable_angles(chain))
            self.dd_angle = gui.add_dropdown(
                "angle to animate", angles, initial_value=angles[3] if len(angles) > 3 else angles[0]
            )
            self.num_anim_s = gui.add_slider(
                "animation duration (s)",
                0.5,
                20.0,
                0.5,
                self.anim_steps * self.anim_dt_s,
                hint="How long 'animate this angle from 0' takes to sweep the angle",
            )
            self.num_anim_s.on_update(lambda _: self._set_anim_speed())
            self.bt_anim = gui.add_button("animate this angle from 0")
            self.md_anim = gui.add_markdown("")
            self.md_hop = gui.add_markdown("")
            self.md_vec = gui.add_markdown("")
            self.md_q17 = gui.add_markdown("")
        for h in (self.dd_hop, self.dd_vec, self.num_row, self.num_col, self.vec3, self.dd_frame, self.cb_show):
            h.on_update(lambda _: self.redraw())
        self.bt_hops.on_click(lambda e: self.step_hop(-1 if e.target.value == "previous hop" else 1))
        self.cb_mesh.on_update(lambda _: self.set_mesh(bool(self.cb_mesh.value)))
        self.bt_frame.on_click(lambda _: self.frame_aircraft())
        self.bt_anim.on_click(lambda _: self.animate(str(self.dd_angle.value), wait=False))

    def _hook_refresh(self) -> None:
        s = self.session
        if hasattr(s, "on_refresh"):
            s.on_refresh(lambda *_: self.redraw(), deferred=True)
            return
        # Fallback until the app has on_refresh: wrap this instance's refresh.
        orig = s.refresh

        def refresh(*a, **k):
            out = orig(*a, **k)
            if getattr(self, "dd_hop", None) is not None:
                self.redraw()
            return out

        s.refresh = refresh

    def step_hop(self, k: int) -> None:
        """Previous (-1) / next (+1) hop, wrapping; (none) goes to the first."""
        keys = self.hop_keys
        cur = self.hop
        i = -1 if cur is None else keys.index(cur)
        self.dd_hop.value = keys[(i + k) % len(keys)]

    def set_mesh(self, visible: bool) -> None:
        """Show or hide the app's aircraft mesh (it hides the frames at the aircraft)."""
        self._mesh_visible = bool(visible)
        h = getattr(self.session.view, "handles", {}).get("aircraft_mesh")
        if h is not None:
            h.visible = self._mesh_visible

    # ------------------------------------------------------------ layout
    def unit_km(self) -> float:
        """Display size of one frame's axes, km (follows the app's aircraft display scale)."""
        return UNIT_PER_SCALE_M * float(self.session.view.disp.aircraft_scale) * WORLD_SCALE

    def layout(self, chain):
        """Row positions (relative to the aircraft, km) of the frames and of the globe, and the
        row's direction ``u``.

        Spaced by what the frames carry (so that their labels do not overlap): frame k and frame k + 2 (one band) sit at
        least their axes and their widest labels apart (:func:`row_offsets`), so a turret's
        frames, which all sit at one optical centre, are fanned out over the row and their
        labels do not collide.
        """
        g = self.session.geometry
        U = self.unit_km()
        d = np.asarray(g.los_dir_enu, float)
        u = np.r_[d[:2], 0.0]
        u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-9 else np.array([1.0, 0.0, 0.0])
        up = np.array([0.0, 0.0, 1.0])
        frames = teaching.chain_frames(chain)
        x, z = row_offsets(frames)
        x = x - 0.5 * (x[0] + x[-1])
        pos = {f: up * (LIFT + z[k]) * U + u * x[k] * U for k, f in enumerate(frames)}
        globe = up * (LIFT + ZIG) * U + u * (x[0] - GLOBE_GAP) * U
        return pos, globe, u

    # ------------------------------------------------------------ drawing
    def redraw(self) -> None:
        """Redraw the nodes and the text for the current chain (the session's, or the animation's)."""
        with self._lock:
            self._redraw()

    def _redraw(self) -> None:
        s = self.session
        if s.geometry is None:
            return
        chain, sc = self.chain, self.scene
        enu = s.scn.enu
        disp = s.view.disp
        hop = self.hop
        dst, src = teaching.hop_frames(hop, chain) if hop else (None, None)
        v, vframe, what = self.vector(chain)
        coords = teaching.vector_in_frames(chain, v, vframe)
        v_enu = enu.vector_from_ecef(coords["ecef"])
        v_enu = v_enu / max(np.linalg.norm(v_enu), 1e-300)
        U = self.unit_km()
        pos, globe, _ = self.layout(chain)
        aircraft = disp.z(enu.from_ecef(chain.T_ecef("body")[:3, 3]))
        show = bool(self.cb_show.value)
        # the frames' name labels at the aircraft are the teaching view's: shown with the row, or in a lesson
        if hasattr(s.view, "set_frame_labels"):
            s.view.set_frame_labels(show or not self.flight_view)

        def place_root(h):
            # hidden, the row is not moved: a scene message in a step's panel batch makes the browser
            # draw the scene again; showing it (the checkbox redraws) places it first
            if show:
                h.position = aircraft
            if h.visible != show:
                h.visible = show

        self._node(ROOT, None, lambda: sc.add_frame(ROOT, show_axes=False, position=aircraft, visible=show), place_root)
        if not show:
            # hidden (the flight view's default): the row is brought up to date when shown (the
            # checkbox redraws); a timeline step then sends the text, not some 45 node updates
            # nobody sees (benchmarks/bench_viewer.py)
            self._text(chain, v, vframe, what, hop)
            self.set_mesh(self._mesh_visible)
            return
        arrows = []
        for index, f in enumerate(teaching.chain_frames(chain)):
            T = chain.T_ecef(f)
            R_enu_f = enu.R_enu_from(T[:3, :3])
            role = "src" if f == src else "dst" if f == dst else None
            big = role is not None
            L = U * (1.25 if big else 1.0)
            name = f"{ROOT}/frames/{f}"
            key = (round(L, 9), big)
            h = self._handles.get(name)
            if h is None or h[1] != key:
                fh = sc.add_frame(
                    name,
                    axes_length=L,
                    axes_radius=L * (0.06 if big else 0.025),
                    origin_radius=L * 0.06,
                    position=pos[f],
                    wxyz=wxyz(R_enu_f),
                )
                for i, ax in enumerate("xyz"):
                    tip = np.zeros(3)
                    tip[i] = L * 1.08
                    sc.add_label(
                        f"{name}/{ax}", f"{ax} {f}", position=tip, anchor="center-left", font_screen_scale=AXIS_FONT
                    )
                self._handles[name] = (fh, key)
            else:
                fh = h[0]
                fh.position, fh.wxyz = pos[f], wxyz(R_enu_f)
            tag = {"src": "SOURCE ", "dst": "DESTINATION ", None: ""}[role]
            where = " (origin: Earth's centre)" if f == "ecef" else ""
            c = coords[f]
            # name and coordinates below a frame of the lower band, above one of the upper band
            # (past a tip label, so an axis pointing down or up leaves the name clear)
            z = -1.75 * U if index % 2 == 0 else 1.75 * U
            anchor = "top-center" if index % 2 == 0 else "bottom-center"
            self._label(f"{ROOT}/frames_name/{f}", f"{tag}{f}{where}", pos[f] + np.array([0, 0, z]), anchor)
            self._label(
                f"{ROOT}/frames_coords/{f}",
                f"({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f})",
                pos[f] + np.array([0, 0, z - 0.45 * U if index % 2 == 0 else z + 0.45 * U]),
                anchor,
            )
            arrows.append([pos[f], pos[f] + 1.1 * U * v_enu])
            for r in ("src", "dst"):
                if role == r:
                    self._highlight(r, pos[f], 0.45 * U)
        for r, fr in (("src", src), ("dst", dst)):
            if fr is None and self._handles.pop(f"{ROOT}/highlight/{r}", None) is not None:
                sc.remove_by_name(f"{ROOT}/highlight/{r}")
        self._arrows(f"{ROOT}/vector", np.asarray(arrows, np.float32), 0.03 * U, 0.08 * U, 0.2 * U)
        # a leader from the row down to the aircraft: the frames really share its origin
        # (its caption under the row's lower band of texts, above the aircraft's own frame labels)
        self._node(
            f"{ROOT}/leader",
            U,
            lambda: sc.add_line_segments(
                f"{ROOT}/leader",
                np.array([[[0, 0, 0], [0, 0, (LIFT - 3.0) * U]]], np.float32),
                TEACHING["leader"].rgb,
                thickness=1.5,
                thickness_units="screen",
            ),
        )
        self._label(
            f"{ROOT}/leader/label",
            "frames drawn apart: all but ECEF sit at the aircraft",
            np.array([0, 0, (LIFT - 3.0) * U]),
            "top-center",
        )
        self._draw_globe(chain, globe, U, coords, dst, src, hop == "T_ecef_ned")
        self._text(chain, v, vframe, what, hop)
        self.set_mesh(self._mesh_visible)

    def _node(self, name, key, make, update=None):
        """The node ``name``: made by ``make()`` the first time (or when its ``key``, what it was made
        with, changed, or the scene lost it), else kept and handed to ``update(handle)``. A step then
        moves nodes instead of re-creating them (the browser rebuilds a re-created node)."""
        h, k = self._handles.get(name, (None, None))
        alive = h is not None and k == key and getattr(self.scene, "get_handle_by_name", lambda n: h)(name) is h
        if not alive:
            h = make()
            self._handles[name] = (h, key)
        elif update is not None:
            update(h)
        return h

    def _arrows(self, name, points, shaft, head, head_length):
        """Arrows ``points`` (N, 2, 3) made once per count and size, then only their points moved."""

        def move(h):
            h.points = points

        return self._node(
            name,
            (points.shape, round(shaft, 12), round(head, 12), round(head_length, 12)),
            lambda: self.scene.add_arrows(
                name, points, VECTOR_COLOR, shaft_radius=shaft, head_radius=head, head_length=head_length
            ),
            move,
        )

    def _label(self, name, text, position, anchor):
        h = self._handles.get(name)
        if h is None or h[1] != anchor:
            lh = self.scene.add_label(name, text, position=position, anchor=anchor, font_screen_scale=TEXT_FONT)
            self._handles[name] = (lh, anchor)
        else:
            lh = h[0]
            lh.position = position
            if lh.text != text:
                lh.text = text
        return lh

    def _highlight(self, role, position, radius):
        name = f"{ROOT}/highlight/{role}"
        h = self._handles.get(name)
        if h is None or h[1] != radius:
            hh = self.scene.add_icosphere(
                name,
                radius=radius,
                color=HIGHLIGHT[role],
                subdivisions=2,
                position=position,
                cast_shadow=False,
                receive_shadow=False,
                material="toon3",
            )
            self._handles[name] = (hh, radius)
        else:
            h[0].position = position

    def _draw_globe(self, chain, center, U, coords, dst, src, q17) -> None:
        """The Earth scaled to radius 1.5 U about ``center``, ECEF axes, the aircraft and the vector."""
        sc, enu = self.scene, self.session.scn.enu
        R = 1.5 * U
        k = R / A  # scene km per ECEF metre in the inset
        R_enu_ecef = enu.R_enu_ecef
        name = f"{ROOT}/globe"

        def move_to(p):
            def move(h):
                h.position = p

            return move

        self._node(name, None, lambda: sc.add_frame(name, show_axes=False, position=center), move_to(center))
        self._node(
            name + "/earth",
            R,
            lambda: sc.add_icosphere(
                name + "/earth",
                radius=R,
                color=TEACHING["earth"].rgb,
                subdivisions=3,
                opacity=0.55,
                scale=(1.0, 1.0, 1.0),
                cast_shadow=False,
                receive_shadow=False,
            ),
        )
        big = dst == "ecef" or src == "ecef"
        L = 1.6 * R
        q_axes = wxyz(R_enu_ecef)

        def make_axes():
            ax = sc.add_frame(
                name + "/axes",
                axes_length=L,
                axes_radius=L * (0.03 if big else 0.015),
                origin_radius=L * 0.03,
                wxyz=q_axes,
            )
            for i, txt in enumerate(("X ecef (0 N, 0 E)", "Y ecef (0 N, 90 E)", "Z ecef (north pole)")):
                tip = np.zeros(3)
                tip[i] = L * 1.05
                sc.add_label(name + f"/axes/{'xyz'[i]}", txt, position=tip, anchor="center-left", font_screen_scale=0.8)
            return ax

        def turn(h):
            h.wxyz = q_axes

        self._node(name + "/axes", (round(L, 12), big), make_axes, turn)
        p = chain.T_ecef("body")[:3, 3]
        p_in = R_enu_ecef @ p * k

        def make_aircraft():
            h = sc.add_icosphere(
                name + "/aircraft",
                radius=0.08 * U,
                color=TEACHING["aircraft"].rgb,
                position=p_in,
                cast_shadow=False,
                receive_shadow=False,
            )
            sc.add_label(
                name + "/aircraft/label", "aircraft (Earth to scale)", anchor="top-left", font_screen_scale=0.8
            )
            return h

        self._node(name + "/aircraft", round(U, 12), make_aircraft, move_to(p_in))
        ve = enu.vector_from_ecef(coords["ecef"])
        ve = ve / max(np.linalg.norm(ve), 1e-300)
        self._arrows(
            name + "/vector", np.array([[p_in, p_in + 0.6 * U * ve]], np.float32), 0.02 * U, 0.06 * U, 0.15 * U
        )
        # (the ECEF highlight stays on the row's ecef frame: a ball at the globe's centre would be hidden)
        if self._handles.pop(name + "/q17", None) is not None or q17:
            sc.remove_by_name(name + "/q17")
        if q17:
            self._handles[name + "/q17"] = (None, None)
            for j, (txt, T) in enumerate(teaching.q17_intermediate_frames(chain)):
                o = R_enu_ecef @ T[:3, 3] * k
                Lq = 0.45 * U
                sc.add_frame(
                    name + f"/q17/{j}",
                    axes_length=Lq,
                    axes_radius=Lq * 0.04,
                    origin_radius=Lq * 0.05,
                    position=o,
                    wxyz=wxyz(R_enu_ecef @ T[:3, :3]),
                )
                tip = np.zeros(3)
                tip[j % 3] = Lq * 1.1
                sc.add_label(
                    name + f"/q17/{j}/label",
                    txt.split(",")[0] if j < 3 else "NED",
                    position=tip,
                    anchor="center-left",
                    font_screen_scale=0.75,
                )
            pv = R_enu_ecef @ teaching.q17_intermediate_frames(chain)[0][1][:3, 3] * k
            sc.add_line_segments(
                name + "/q17/normal",
                np.array([[pv, p_in]], np.float32),
                TEACHING["normal"].rgb,
                thickness=1.5,
                thickness_units="screen",
            )

    def _text(self, chain, v, vframe, what, hop) -> None:
        hv = {h.key: h for h in teaching.hops(chain)}
        if hop in hv:
            dst, src = hv[hop].dst, hv[hop].src
            parts = [teaching.hop_markdown(hv[hop])]
            for f in (dst, src):
                if f != "ecef":
                    parts.append(f"`T_ecef_{f}` (partial product):\n```\n{teaching.fmt_matrix(chain.T_ecef(f))}\n```\n")
            self.md_hop.content = "\n".join(parts)
        else:
            self.md_hop.content = (
                f"Choose a hop: its source frame is drawn {TEACHING['src'].name}, "
                f"its destination {TEACHING['dst'].name}."
            )
        self.md_vec.content = teaching.vector_markdown(chain, v, vframe, hop, what=what)
        if hop == "T_ecef_ned":
            frames = "\n".join(f"- {t}" for t, _ in teaching.q17_intermediate_frames(chain))
            self.md_q17.content = (
                teaching.q17_factors_markdown(chain) + "\nIntermediate frames (drawn on the globe):\n" + frames + "\n"
            )
            self.md_q17.visible = True
        else:
            self.md_q17.content = ""
            self.md_q17.visible = False

    # ------------------------------------------------------------ camera
    def camera_pose(self, width: int | None = None, height: int | None = None, fov_rad: float | None = None):
        """(position, look_at) in scene km showing the row of frames and the globe face on.

        The camera looks at the row square to it, from a distance at which one frame size is
        :data:`PX_PER_U` CSS px on a ``width`` x ``height`` canvas of vertical field of view
        ``fov_rad`` (default: the session's tab's camera, else 1280 x 800 at 75 deg), farther
        when the row would not fit left of the GUI panel; the row's middle is put in the middle
        of what the panel leaves free.
        """
        cam = self._camera()
        W = float(width or getattr(cam, "image_width", 0) or 1280)
        H = float(height or getattr(cam, "image_height", 0) or 800)
        fov = float(fov_rad or getattr(cam, "fov", 0.0) or np.deg2rad(75.0))
        chain = self.chain
        pos, globe, u = self.layout(chain)
        aircraft = self.session.view.disp.z(self.session.geometry.aircraft_enu)
        U = self.unit_km()
        pts = np.array(list(pos.values()) + [globe])
        along = (pts - pts.mean(0)) @ u
        # the globe's axes and labels on the left, the last frame's tip labels on the right
        lo, hi = float(along.min()) - 5.5 * U, float(along.max()) + 3.5 * U
        zs = pts[:, 2]
        centre = aircraft + pts.mean(0) + u * (0.5 * (lo + hi))
        centre[2] = aircraft[2] + 0.5 * (zs.min() - 3.4 * U + zs.max() + 2.6 * U)  # the texts below, above
        f = 0.5 * H / np.tan(0.5 * fov)
        free = max(W - PANEL_PX, 0.5 * W)
        dist = max(f * U / PX_PER_U, f * (hi - lo) / (0.92 * free))
        side = np.array([u[1], -u[0], 0.0])  # horizontal, square to the row; u points right on screen
        eye = centre + side * dist * np.cos(0.12) + np.array([0.0, 0.0, dist * np.sin(0.12)])
        # the row's middle at the middle of the free part: aim right of it by half the panel
        shift = 0.5 * (W - free) * dist / f
        return eye + u * shift, centre + u * shift

    def _camera(self):
        """The camera of the session's tab (a server session: its first tab's), or None."""
        c = getattr(self.session, "client", None)
        if c is None:
            server = getattr(self.session, "server", None)
            clients = list(server.get_clients().values()) if server is not None else []
            c = clients[0] if clients else None
        return getattr(c, "camera", None)

    def frame_aircraft(self) -> None:
        """Move the browsers' cameras to the aircraft (the wheel then zooms about it, not the ground hit),
        the frames row and globe shown (a teacher asking for them in a flight view)."""
        if not self.cb_show.value:
            self.cb_show.value = True  # its callback redraws the row
        eye, aim = self.camera_pose()
        mc = getattr(self.session, "move_camera", None)
        if mc is not None:
            mc((eye, aim))
            return
        server = self.session.server
        for client in server.get_clients().values():
            with client.atomic():
                client.camera.up_direction = (0.0, 0.0, 1.0)
                client.camera.look_at = tuple(aim)
                client.camera.position = tuple(eye)

    # ------------------------------------------------------------ animation
    def close(self) -> None:
        """Stop a running animation (the session is closing)."""
        self._stop.set()

    def stop_animation(self) -> None:
        """End a running animation now (the true pose is drawn again)."""
        self._stop.set()

    def animate(self, name: str, wait: bool = True, steps: int | None = None, dt_s: float | None = None):
        """Run angle ``name`` from 0 to its value in ``steps`` steps of ``dt_s`` seconds
        (step k drawn at k ``dt_s`` after the start, whatever a redraw takes).

        Only this layer's drawing moves (the session's pose and its line of
        sight stay); at the end the true pose is shown again. With ``wait``
        False the animation runs in a thread (the GUI button), returned.
        """
        chain = self.session.geometry.chain
        if name not in teaching.animatable_angles(chain):
            raise ValueError(
                f"angle = {name!r}: not an angle of this chain; angles: {list(teaching.animatable_angles(chain))}"
            )
        pose = chain.pose
        target = teaching.pose_angle(pose, name)
        steps = self.anim_steps if steps is None else int(steps)
        dt_s = self.anim_dt_s if dt_s is None else float(dt_s)

        self._stop.clear()

        def run():
            self.animating = True
            t0 = time.monotonic()
            try:
                for k in range(steps + 1):
                    if self._stop.is_set():
                        break
                    # paced by the clock: step k at t0 + k dt_s, so the sweep takes the duration
                    # asked for however long a redraw takes (a step whose time has passed while
                    # the one before was drawn is skipped; the last is always drawn)
                    t_k = t0 + k * dt_s
                    if dt_s > 0 and k < steps and time.monotonic() > t_k + dt_s:
                        continue
                    self._stop.wait(max(t_k - time.monotonic(), 0.0))
                    a = target * k / steps
                    self.pose_override = teaching.pose_with_angle(pose, name, a)
                    self.md_anim.content = (
                        f"animating **{name}**: {np.rad2deg(a):+.2f} of {np.rad2deg(target):+.2f} deg"
                    )
                    self.redraw()
            finally:
                self.pose_override = None
                self.md_anim.content = f"{name} = {np.rad2deg(target):+.2f} deg (animated from 0)"
                self.redraw()
                self.last_anim_s = time.monotonic() - t0
                self.anim_count += 1
                self.animating = False  # after the true pose is drawn again

        if wait:
            run()
            return None
        t = threading.Thread(target=run, daemon=True, name=f"teach-animate-{name}")
        t.start()
        return t


def attach(session) -> TeachingPanel:
    """Add the teaching panel (GUI folder and scene nodes) to a ``geoloc view`` session.

    The app wires it with ``self.teaching_panel = teaching_panel.attach(self)``
    after its own GUI and first refresh. One hop selector (one per session kept the panel readable): the session's own
    "Teaching: the chain of 4x4 matrices" folder then follows this panel's "teaching hop"
    (its own dropdown hidden), so the two folders always show the same hop.
    """
    panel = TeachingPanel(session)
    own = getattr(session, "dd_hop", None)
    if own is not None:
        own.visible = False

        def follow(_e=None) -> None:
            v = str(panel.dd_hop.value)
            target = v if v in own.options else own.options[0]
            if own.value != target:
                own.value = target

        panel.dd_hop.on_update(follow)
        follow()
    return panel
