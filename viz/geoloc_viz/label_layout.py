"""Labels laid out on screen so that none overlaps another (overlapping labels cannot be read).

viser draws a label (``scene.add_label``, screen-size font) as a text block on a background
rectangle whose *anchor* corner sits at the label's 3D point, 12 CSS px per em whatever the
viewport (viser's ``label/LabelRenderer.tsx`` and ``label/labelLayout.ts``: padding 0.2 line
heights). Several labels at nearly one point (the frames of a turret at its origin, the
markers of a hit) then cover each other. :func:`layout` takes the labels of a scene and a
camera, computes each one's screen box (:func:`label_box`), and moves the ones that collide:
it tries the other anchors at the same point, then steps the label along the screen's
vertical, in label heights, and writes the new anchor and the 3D position that projects there
(the point moved in the camera's image plane at its depth) into the label's node; a label with no
free place near its point (a distant view of a few dozen labels at one aircraft) is hidden until a
camera leaves it room, lowest priority first. Each label's
own ("home") position and anchor are kept, so a layout for a new camera starts from them, and
a position its owner sets anew becomes its new home.

:class:`LabelLayout` runs it for a session: after every redraw and, throttled, after its
camera moves (the tab's camera; a server session's: the first tab's).

Text width is estimated at :data:`CHAR_EM` em per character (the system sans-serif stack's
average advance is 0.50-0.56 em for these labels' text, measured with the browser's
``measureText`` in ``tests/viz/test_viz_labels.py``): an overestimate, so boxes found apart here
are apart on screen.
"""

from __future__ import annotations

import threading
import time

import numpy as np

#: viser's screen-space label em [CSS px] at font_screen_scale 1.
EM_PX = 12.0
#: Estimated advance per character [em] (an overestimate, see the module docstring).
CHAR_EM = 0.62
#: Line height [em] (the font's ascent + descent, about 1.15-1.2 for the stack) and the
#: background padding (0.2 line heights, viser's BACKGROUND_PADDING_FRACTION).
LINE_EM = 1.2
PAD_FRACTION = 0.2
#: Gap kept between two boxes [px].
GAP_PX = 2.0
ANCHORS = (
    "bottom-left",
    "top-left",
    "bottom-right",
    "top-right",
    "center-left",
    "center-right",
    "bottom-center",
    "top-center",
)


def label_size_px(text: str, em_px: float = EM_PX, char_em: float = CHAR_EM) -> tuple:
    """(width, height) [px] of a label's background rectangle (text block plus padding)."""
    lines = str(text).split("\n")
    lh = LINE_EM * em_px
    pad = PAD_FRACTION * lh
    w = max(len(s) for s in lines) * char_em * em_px
    return w + pad, lh * len(lines) + pad


def handle_size_px(h) -> tuple:
    """(width, height) [px] of label handle ``h``'s rectangle at its own font scale
    (viser draws a screen-space label at ``EM_PX * font_screen_scale`` px per em)."""
    scale = float(getattr(h, "font_screen_scale", 1.0) or 1.0)
    return label_size_px(h.text, em_px=EM_PX * scale)


def label_box(u: float, v: float, size, anchor: str) -> np.ndarray:
    """Screen box (x0, y0, x1, y1) [px, y down] of a background rectangle ``size`` = (w, h) whose
    ``anchor`` ("top-left", "center-right", ...) sits at pixel (u, v); as viser's layoutLabel."""
    w, h = size
    vert, _, horiz = str(anchor).partition("-")
    x0 = u if horiz == "left" else u - w if horiz == "right" else u - w / 2
    y0 = v if vert == "top" else v - h if vert == "bottom" else v - h / 2
    return np.array([x0, y0, x0 + w, y0 + h])


def overlap(a, b, gap: float = 0.0) -> bool:
    """True when two boxes (x0, y0, x1, y1) overlap (closer than ``gap``)."""
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


def project(points, position, wxyz, fov_rad: float, width: int, height: int):
    """Pixels (u, v) and depths of world points seen by a viser camera (OpenCV axes: x right, y down,
    z forward; ``fov_rad`` vertical; pinhole f = height / 2 / tan(fov / 2))."""
    import viser.transforms as vtf

    R = vtf.SO3(np.asarray(wxyz, float)).as_matrix()
    pc = (np.atleast_2d(np.asarray(points, float)) - np.asarray(position, float)) @ R
    f = 0.5 * height / np.tan(0.5 * fov_rad)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([0.5 * width + f * pc[:, 0] / z, 0.5 * height + f * pc[:, 1] / z], axis=1)
    return uv, z, R, f


# ----------------------------------------------------------------------------- the scene's labels


def _node_pose(scene, name):
    """World (R, t) of node ``name``: its ancestors' poses composed (nodes absent: identity)."""
    import viser.transforms as vtf

    R, t = np.eye(3), np.zeros(3)
    parts = [p for p in name.split("/") if p]
    for k in range(1, len(parts) + 1):
        h = scene.get_handle_by_name("/" + "/".join(parts[:k]))
        if h is None:
            continue
        Rk = vtf.SO3(np.asarray(h.wxyz, float)).as_matrix()
        t = t + R @ np.asarray(h.position, float)
        R = R @ Rk
    return R, t


def _shown(scene, name) -> bool:
    parts = [p for p in name.split("/") if p]
    for k in range(1, len(parts) + 1):
        h = scene.get_handle_by_name("/" + "/".join(parts[:k]))
        if h is not None and not h.visible:
            return False
    return True


def scene_labels(scene, also=()):
    """[(name, handle)] of the scene's label nodes that are shown (they and their ancestors visible);
    the names in ``also`` count when only they themselves are hidden (hidden by the layout)."""
    import viser

    out = []
    for name, h in list(getattr(scene, "_handle_from_node_name", {}).items()):
        if not (isinstance(h, viser.LabelHandle) and h.text):
            continue
        if _shown(scene, name) or (name in also and _shown(scene, name.rsplit("/", 1)[0] or "/")):
            out.append((name, h))
    return out


def label_boxes(scene, camera, width: int, height: int, size_fn=None):
    """{name: (box, depth)} of the shown labels in front of ``camera`` (position, wxyz, fov)."""
    out = {}
    for name, h in scene_labels(scene):
        R, t = _node_pose(scene, name.rsplit("/", 1)[0]) if name.count("/") > 1 else (np.eye(3), np.zeros(3))
        p = R @ np.asarray(h.position, float) + t
        uv, z, *_ = project(p, camera.position, camera.wxyz, camera.fov, width, height)
        if z[0] <= 0:
            continue
        size = handle_size_px(h) if size_fn is None else size_fn(h.text)
        out[name] = (label_box(uv[0, 0], uv[0, 1], size, h.anchor), float(z[0]))
    return out


class LabelLayout:
    """Keeps one scene's labels apart on one camera's screen (see the module docstring).

    Parameters
    ----------
    scene : viser.SceneApi
    camera_source : callable
        Returns the camera to lay out for (``client.camera``) or None.
    priority : callable, optional
        ``priority(name) -> number``: lower is placed first (keeps its home); default by name.
    """

    def __init__(self, scene, camera_source, priority=None):
        self.scene = scene
        self.camera_source = camera_source
        self.priority = priority or (lambda name: 0)
        self.homes: dict = {}  # name -> (handle, home local position, home anchor, last set pos, anchor)
        self.moved: dict = {}
        self.hidden: dict = {}  # name -> handle: labels hidden for want of room
        self.closed = False
        self._timer = None
        self._lock = threading.Lock()
        self.last_layout_s = float("nan")

    def schedule(self, delay_s: float = 0.3) -> None:
        """Lay out ``delay_s`` after the last call (a camera drag: once it settles)."""
        if self.closed:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer = threading.Timer(delay_s, self.run)
        self._timer.daemon = True
        self._timer.start()

    def close(self) -> None:
        self.closed = True
        if self._timer is not None:
            self._timer.cancel()

    def _home(self, name, h):
        rec = self.homes.get(name)
        pos = np.asarray(h.position, float)
        if rec is None or rec[0] is not h or not (np.allclose(pos, rec[3]) and h.anchor == rec[4]):
            # new, re-created, or moved by its owner since our last layout: that is its home
            rec = (h, pos.copy(), str(h.anchor), pos.copy(), str(h.anchor))
            self.homes[name] = rec
        return rec

    def run(self) -> None:
        """Lay the labels out for the current camera (a no-op without one)."""
        if self.closed:
            return
        try:
            cam = self.camera_source()
        except Exception:
            cam = None
        if cam is None:
            return
        W, H = int(getattr(cam, "image_width", 0) or 0), int(getattr(cam, "image_height", 0) or 0)
        if W <= 0 or H <= 0:
            return
        with self._lock:
            t0 = time.perf_counter()
            try:
                self._run(cam, W, H)
            except (KeyError, RuntimeError, AttributeError):  # the tab left meanwhile
                return
            self.last_layout_s = time.perf_counter() - t0

    def _run(self, cam, W, H) -> None:
        # labels we hid last time (no room) are candidates again, unless their owner re-created them
        hidden = {n for n, h in self.hidden.items() if self.scene.get_handle_by_name(n) is h and not h.visible}
        labels = scene_labels(self.scene, hidden)
        items = []
        for name, h in labels:
            _, home, anchor, *_ = self._home(name, h)
            parent = name.rsplit("/", 1)[0]
            R, t = _node_pose(self.scene, parent) if parent else (np.eye(3), np.zeros(3))
            p = R @ home + t
            uv, z, Rc, f = project(p, cam.position, cam.wxyz, cam.fov, W, H)
            if not (z[0] > 0 and np.all(np.isfinite(uv))):
                continue
            items.append((self.priority(name), name, h, home, anchor, R, t, uv[0], float(z[0]), Rc, f))
        items.sort(key=lambda it: (it[0], it[1]))
        placed: list[np.ndarray] = []
        for _, name, h, home, anchor, R, t, uv, z, Rc, f in items:
            size = handle_size_px(h)
            best = None
            order = (anchor,) + tuple(a for a in ANCHORS if a != anchor)
            # a label whose own place is on the canvas is moved only to places on the canvas
            on = _inside(label_box(uv[0], uv[1], size, anchor), W, H)
            for step in range(0, 9):
                for sgn in (1,) if step == 0 else (-1, 1):
                    dv = sgn * step * size[1]
                    for a in order:
                        box = label_box(uv[0], uv[1] + dv, size, a)
                        if (not on or _inside(box, W, H)) and not any(overlap(box, b, GAP_PX) for b in placed):
                            best = (a, dv, box)
                            break
                    if best:
                        break
                if best:
                    break
            if best is None:
                # no room near its point: hidden until a camera leaves it some (no label covers another)
                if h.visible:
                    h.visible = False
                self.hidden[name] = h
                continue
            if name in self.hidden:
                self.hidden.pop(name)
                h.visible = True
            a, dv, box = best
            placed.append(box)
            # the home point moved down the screen by dv pixels, at its depth
            world = R @ home + t + Rc[:, 1] * (dv * z / f)
            local = R.T @ (world - t)
            if a != h.anchor:
                h.anchor = a
            if not np.allclose(local, np.asarray(h.position, float), atol=1e-9):
                h.position = tuple(local)
            self.homes[name] = (h, home, anchor, np.asarray(h.position, float).copy(), str(h.anchor))
            self.moved[name] = (a != anchor) or dv != 0.0


def _inside(box, W, H) -> bool:
    return box[0] >= 0 and box[1] >= 0 and box[2] <= W and box[3] <= H


def label_priority(name: str) -> int:
    """Placement order: the current frame's error label keeps its place first, then the flagged
    runs' labels, then the rest."""
    return -2 if "/focus/" in name else -1 if "/run_labels/" in name else 0


def attach(session) -> LabelLayout:
    """The label layout of a ``geoloc view`` session (a layer): after every redraw and camera move."""
    client = getattr(session, "client", None)
    server = session.server

    def camera():
        if client is not None:
            return client.camera
        clients = list(server.get_clients().values())
        return clients[0].camera if clients else None

    lay = LabelLayout(session.scene, camera, priority=label_priority)
    try:
        # in the redraw's panel batch (a timeline step's second batch, after the labels the panels
        # move): one render request in the browser, not another one 50 ms later
        session.on_refresh(lambda _g: lay.run(), deferred=True)
    except TypeError:  # a session without deferred callbacks
        session.on_refresh(lambda _g: lay.schedule(0.05))
    if client is not None:
        client.camera.on_update(lambda _c: lay.schedule())
    else:
        cbs = []

        def on_connect(c):
            if not lay.closed:
                c.camera.on_update(lambda _c: lay.schedule())

        # a server session: every tab's camera moves trigger it (the layout uses the first tab's)
        server.on_client_connect(on_connect)
        cbs.append(on_connect)
        for c in server.get_clients().values():
            on_connect(c)
    lay.schedule(0.05)
    return lay
