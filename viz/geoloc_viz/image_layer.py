"""The picture in the scene: a layer showing each frame's image, and picking through it.

:func:`attach` (a layer of :class:`geoloc_viz.app.GeolocSession`) is None unless the scenario
has images (``scn.images``, an :class:`geoloc.io.images.ImageSource`; which image belongs to
which record: :func:`geoloc_viz.picture_model.image_index`). It adds

* the current frame's image **in its frustum** (scene node ``/enu/picture/frame``, a viser
  image node in the camera's optical frame, at a chosen fraction of the range to the frame
  centre, with an opacity), and a **2D image panel** (a "Picture" GUI folder) with a zoom;
  the timeline (and the record dropdown) shows each frame's own image;
* **pick a pixel**: click the panel's image (or type ``row, col`` into "picked pixel"), or click
  the image in the frustum (the pixel is where the click's ray crosses the image's plane): the
  scene draws that pixel's ray to its ground point (``/enu/picture/ray``, ``/enu/picture/hit``,
  the method's iterates ``/enu/picture/iterations``) and the panel gives latitude, longitude,
  height and its datum, slant range, status and the DEM evaluations;
* **one target in several frames**: each frame's last pick is one ray of a target, kept across
  frames (the timeline) until "clear target rays"; from two frames on the rays are intersected
  without any DEM (:func:`geoloc_viz.picture_model.triangulate_picks`, the least squares of
  :mod:`geoloc.analysis.triangulate`, weighted by the scenario's sensor file's ``[uncertainty]``
  budget or the illustrative one: :func:`geoloc_viz.uncertainty_layer.scenario_budget`)
  and the scene draws each ray meeting at the triangulated point (``/enu/picture/target/rays``,
  ``.../point``), its 90 % ellipse (``.../ellipse``) and each ray's residual (``.../residuals``),
  those two at the error vectors' exaggeration; the panel gives the position, covariance, CE90 /
  LE90, each ray's residual and each frame's DEM hit against the intersection;
* **pick the terrain**: click the terrain in the scene: the point is marked
  (``/enu/picture/ground``), its pixel is marked in the image (``ground_to_pixel``), or the panel
  says "outside the frame" or "hidden behind terrain from this camera";
* **marks in the image**: the reprojected surveyed truth and targets, the reported and the
  recomputed frame centres, and the terrain horizon, so a fault shows in the picture itself;
  and the **painted marks** found in the frame against the targets' reprojection
  (:func:`geoloc_viz.picture_model.found_marks`: agree / disagree, in pixels and degrees);
* **export**: :meth:`ImageLayer.export_html` gives the frame with its marks and the picks' text
  for ``geoloc view --export`` (which records the scene, not the GUI).

Every number comes from :mod:`geoloc_viz.picture_model` (sensor, surface, ``ground_to_pixel``);
this module only draws and maps clicks to pixels. The panel's image is an HTML element whose
click handler writes the clicked pixel into the "picked pixel" text box (viser's GUI image sends
no clicks): the pick then reaches the server as a typed one would.
Conventions: ``docs/conventions.md`` (1-based pixel centres); user guide: ``docs/viz.md``.
"""

from __future__ import annotations

import atexit
import base64
import html
import io
import math
import re
import sys
import threading
import traceback
import weakref

import numpy as np

from geoloc.status import Status
from geoloc_viz import picture_model as pm
from geoloc_viz import palette
from geoloc_viz.palette import rgb
from geoloc_viz.scene_geoloc import WORLD_SCALE, drawn_factor, wxyz
from geoloc_viz.layer_safety import call_safely, own_update

ROOT = "/enu/picture"
#: Width of the panel's image [screen px] (the crop is scaled to it, nearest neighbour).
PANEL_WIDTH = 560
#: Largest side of the texture sent for the frustum [px] (the panel shows full resolution). The
#: picture in its frustum spans 20-300 screen pixels in the views the viewer frames (the whole
#: flight, an error, the aircraft followed): 320 is its display size; 640 sent four times the
#: pixels to decode and upload to software WebGL on every timeline step (bench_viewer.py).
TEXTURE_MAX = 320
ZOOMS = (1, 2, 4, 8, 16, 32)
#: Picks of one frame kept for an export (the scene shows the last one's ray).
MAX_PICKS = 20
#: RGB colours of the marks (the same in the scene and in the image), from the viewer's one colour table
#: (:mod:`geoloc_viz.palette`). The picked terrain point is indigo, a colour of its own (it was the orange of
#: the footprints); hidden behind terrain from the camera, dimmed. One target's rays from several frames are
#: lines of sight (yellow); its 90 % ellipse is teal, as every 90 % ellipse.
COLORS = {
    "pick": rgb("pick"),
    "ground": rgb("ground"),
    "ground_hidden": rgb("ground_hidden"),
    "truth": rgb("surveyed"),
    "target": rgb("surveyed"),
    "reported": rgb("published"),
    "recomputed": rgb("result"),
    "horizon": rgb("bracket"),
    "target_rays": rgb("los"),
    "residual": rgb("residual"),
    "target_ellipse": rgb("ellipse"),
}
_PIXEL_RE = re.compile(r"^\s*\(?\s*([-+0-9.eE]+)\s*[, ;]\s*([-+0-9.eE]+)\s*\)?\s*$")


def parse_pixel(text: str):
    """``"row, col"`` (or ``row col``) -> (row, col) floats; None for an empty or partial entry."""
    m = _PIXEL_RE.match(text or "")
    if not m:
        return None
    try:
        r, c = float(m.group(1)), float(m.group(2))
    except ValueError:
        return None
    return (r, c) if math.isfinite(r) and math.isfinite(c) else None


def crop_window(rows: int, cols: int, zoom: int, centre=None):
    """(first row, first col, n rows, n cols) of the panel's crop: 1/zoom of the image about
    ``centre`` (row, col; default the image centre), kept inside the image."""
    z = max(int(zoom), 1)
    h, w = max(int(math.ceil(rows / z)), 1), max(int(math.ceil(cols / z)), 1)
    rc, cc = centre if centre is not None else ((rows + 1) / 2, (cols + 1) / 2)
    r1 = int(np.clip(int(round(rc - h / 2 + 0.5)), 1, rows - h + 1))
    c1 = int(np.clip(int(round(cc - w / 2 + 0.5)), 1, cols - w + 1))
    return r1, c1, h, w


def _encode(img: np.ndarray, fmt: str = "JPEG") -> str:
    import PIL.Image

    buf = io.BytesIO()
    im = PIL.Image.fromarray(img)
    if fmt == "JPEG":
        im.save(buf, "JPEG", quality=90)
    else:
        im.save(buf, "PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def draw_marks(img: np.ndarray, marks, to_xy, size: float) -> np.ndarray:
    """Draw ``marks`` ((kind, row, col, label) each) into a copy of ``img`` (RGB uint8) at
    ``to_xy(row, col)`` -> (x, y) image coordinates; crosses, circles and squares ``size`` px."""
    import PIL.Image
    import PIL.ImageDraw

    im = PIL.Image.fromarray(np.ascontiguousarray(img[..., :3]))
    d = PIL.ImageDraw.Draw(im)
    s = max(float(size), 3.0)
    w = max(int(round(s / 5)), 1)
    for kind, r, c, label in marks:
        if kind == "horizon":
            xy = [to_xy(rr, cc) for rr, cc in zip(r, c)]
            if len(xy) > 1:
                d.line(xy, fill=COLORS["horizon"], width=w)
            continue
        if not (np.isfinite(r) and np.isfinite(c)):
            continue
        x, y = to_xy(r, c)
        col = COLORS.get(kind.split()[0], (255, 255, 255))
        if kind in ("pick",):  # crosshair with a gap: the pixel itself stays visible
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                d.line(
                    [(x + dx * s * 0.35, y + dy * s * 0.35), (x + dx * s * 1.6, y + dy * s * 1.6)],
                    fill=col,
                    width=w + 1,
                )
        elif kind.startswith("ground"):
            d.ellipse([x - s, y - s, x + s, y + s], outline=col, width=w + 1)
        elif kind in ("reported", "recomputed"):
            d.rectangle([x - s, y - s, x + s, y + s], outline=col, width=w)
        else:  # truth, targets: an X
            d.line([(x - s, y - s), (x + s, y + s)], fill=col, width=w)
            d.line([(x - s, y + s), (x + s, y - s)], fill=col, width=w)
        if label:
            d.text((x + s + 2, y - s - 2), label, fill=col)
    return np.asarray(im)


class ImageLayer:
    """The picture of the current frame in one session (module docstring)."""

    def __init__(self, session):
        self.session = session
        self.scene, self.gui, self.scn = session.scene, session.gui, session.scn
        self.images = pm.images_of(self.scn)
        self.closed = False
        self._lock = threading.RLock()
        self._mute = False
        self.index = None  # record index shown
        self.k = -1  # image index shown
        self.image = None
        self.sensor = None
        self.pick: pm.PixelPick | None = None
        self.picks: list = []  # this frame's picks, oldest first (at most MAX_PICKS): what an export carries
        self.ground: pm.GroundPick | None = None
        #: Which pick was made last: "pixel", "ground" or None (what "Send the point on" sends);
        #: the inputs (pose) of the last terrain pick, which is not recomputed when the pose changes.
        self.last_pick: str | None = None
        self.ground_inputs = None
        self._pick_cbs: list = []
        #: One target picked in several frames: record index -> (sensor, inputs, PixelPick), the
        #: last pick of each frame; kept across frames until "clear target rays".
        self.target: dict = {}
        self.target_rays: pm.TargetRays | None = None
        self.marks: dict = {}
        self.found: pm.FoundMarks | None = None
        self.centre: pm.PixelPick | None = None  # the image centre's pick of the current update
        self.horizon = np.zeros((0, 2))
        self.crop = None
        self.plane = None  # (position (3,), R_enu_cam (3, 3), width, height) of the frustum image [scene units]
        self.handles: dict = {}
        #: Runs of frames whose picture is shifted in time against its metadata
        #: (:func:`geoloc_viz.picture_model.video_timing_faults`); None until the search is done.
        self.timing: list | None = None
        self._build_gui()
        session.on_refresh(lambda _g: self._safe(self.update), deferred=True)
        self.scene.on_click()(self._on_scene_click)
        self._safe(self.update)
        # the thread holds the layer weakly: a tab closed meanwhile frees its session (the search
        # itself, shared by every tab, finishes into the cache)
        t = threading.Thread(
            target=_find_timing, args=(weakref.ref(self), session.scn), daemon=True, name="geoloc-video-timing"
        )
        _TIMING_THREADS.add(t)
        t.start()

    # ------------------------------------------------------------ a video timing fault
    def timing_fault_of(self, idx):
        """The video timing fault whose run holds record ``idx``, or None."""
        return next((f for f in self.timing or () if f.contains(idx)), None)

    def show_timing(self) -> None:
        """The panel's timing line: on a frame of a run, the run, how far the picture runs ahead
        and the fitted offset; elsewhere the flight's runs in one line (and the button to go)."""
        if self.timing is None:
            return
        f = self.timing_fault_of(self.index)
        if f is not None:
            self.md_timing.content = f.markdown()
        elif self.timing:
            self.md_timing.content = "video timing faults of this flight: " + "; ".join(
                f"frames {x.first} .. {x.last} (the picture {x.ahead()} its metadata)" for x in self.timing
            )
        else:
            self.md_timing.content = ""
        if self.timing:
            x = self.timing[0]
            self.bt_timing.label = f"go to the video timing fault: frames {x.first} .. {x.last}"
        self.bt_timing.visible = bool(self.timing) and f is None

    def go_to_timing_fault(self) -> None:
        """The timeline (the flight layer's, when there is one) to the first frame of the first run."""
        if not self.timing:
            return
        idx = self.timing[0].first
        fl = next((x for x in getattr(self.session, "layers", ()) if hasattr(x, "sl_frame")), None)
        if fl is not None:
            fl.go(idx, camera=False)
        else:
            self.session.load_record(idx)

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        g = self.gui
        head = getattr(self.session, "md_summary", None)
        base = getattr(head, "order", None)
        order = None if base is None else float(base) + 0.015  # under the Flight folder (timeline), before its tables
        with g.add_folder("Picture", order=order):
            w = palette.word  # every colour word is the colour table's name of what is drawn
            self.md_legend = g.add_markdown(
                f"Click the image to locate a pixel; click the terrain to find its pixel. Marks: {w('pick')} +: "
                f"picked pixel; {w('ground')} o: picked terrain point ({w('ground_hidden')}: hidden from the camera); "
                f"{w('surveyed')} x: surveyed truth and targets; squares {w('published')} / {w('result')}: reported / "
                f"recomputed frame centre; {w('bracket')} line: terrain horizon. Pick one target in several frames: "
                f"its rays ({w('los')}, lines of sight) meet at the triangulated point, with its 90 % ellipse "
                f"({w('ellipse')}, as every 90 % ellipse) and residuals ({w('residual')}), both at true size unless "
                '"error vector drawn x" (Display) enlarges them'
            )
            self.html = g.add_html("")
            self.sl_zoom = g.add_slider(
                "zoom (x)",
                0,
                len(ZOOMS) - 1,
                1,
                0,
                hint="Zoom the panel's image about the picked pixel: 1, 2, 4, ... 32 x",
            )
            self.tx_pixel = g.add_text(
                "picked pixel",
                "",
                hint="row, col (1-based pixel centres): a click on the image writes it; type one to locate it",
            )
            self.md_pick = g.add_markdown("")
            self.md_target = g.add_markdown("")
            self.bt_clear_target = g.add_button(
                "clear target rays",
                visible=False,  # offered once there are rays to clear
                hint="Forget the picks of the other frames: the next pick starts "
                "a new target (each frame's last pick is one of its rays)",
            )
            self.md_ground = g.add_markdown("")
            self.md_found = g.add_markdown("")
            # a video timing fault, found in the background (a few seconds of mark finding and a fit)
            self.md_timing = g.add_markdown("")
            self.bt_timing = g.add_button(
                "go to the video timing fault",
                visible=False,
                hint="The timeline to the first frame of the run whose picture runs ahead of its metadata",
            )
            self.cb_frustum = g.add_checkbox("picture in the frustum", True)
            self.sl_dist = g.add_slider(
                "picture distance (x range)",
                0.05,
                1.0,
                0.05,
                0.35,
                hint="Where the image sits along the frustum: a fraction of the range to the frame centre",
            )
            self.sl_opacity = g.add_slider("picture opacity", 0.1, 1.0, 0.05, 1.0)
            self.cb_marks = g.add_checkbox("marks: truth, targets, frame centres", True)
            self.cb_horizon = g.add_checkbox("mark: terrain horizon", True)
            self.cb_drape = g.add_checkbox(
                "drape the frame on the terrain",
                False,
                hint="The frame orthorectified (geoloc ortho: each ground cell's pixel "
                "by ground_to_pixel, cells hidden from the camera left out) and laid "
                "on the terrain as a texture",
            )
        self.bt_timing.on_click(lambda _e: self._safe(self.go_to_timing_fault))
        self.cb_drape.on_update(lambda _e: self._safe(self.drape))
        self.bt_clear_target.on_click(lambda _e: self._safe(self.clear_target))
        self.sl_zoom.on_update(lambda _e: self._safe(self.redraw_images))
        self.tx_pixel.on_update(self._on_pixel_text)
        for h in (self.cb_frustum, self.sl_dist, self.sl_opacity, self.cb_marks, self.cb_horizon):
            h.on_update(lambda _e: self._safe(self.redraw_images))

    @property
    def zoom(self) -> int:
        return ZOOMS[int(np.clip(int(self.sl_zoom.value), 0, len(ZOOMS) - 1))]

    def _safe(self, fn, *a):
        return None if self.closed else call_safely(fn, *a, what="the picture layer", lock=self._lock)

    # ------------------------------------------------------------ the frame
    def update(self) -> None:
        """Follow the session: its record's image and sensor, the marks; redraw."""
        s = self.session
        idx = s.scn.record_index
        if idx != self.index:
            self.index = idx
            self.pick = self.ground = None
            self.last_pick = None
            self.picks = []
            self._mute = True
            try:
                self.tx_pixel.value = ""
            finally:
                self._mute = False
            self.md_pick.content = self.md_ground.content = ""
        k = pm.image_index(s.scn, idx)
        if k != self.k or self.image is None:
            self.k = k
            self.image = None if k < 0 else np.asarray(self.images.image(k))
        if self.image is None:
            self.sensor = None
            self.found = None
            self.md_found.content = ""
            self.html.content = "<p>no image for this record</p>"
            self._hide(f"{ROOT}/frame")
            return
        M, N = self.image.shape[:2]
        self.sensor = pm.frame_sensor(s.scn, idx, M, N)
        # the image centre's pick: the recomputed mark and the frustum picture's distance
        self.centre = pm.locate_pixel(s.scn, s.inputs, self.sensor, *self.sensor.center_pixel)
        self.marks = pm.image_marks(s.scn, idx, self.sensor, s.inputs, self.centre)
        self.found = pm.found_marks(s.scn, self.image, self.marks, self.sensor, s.inputs)
        self.md_found.content = pm.found_markdown(self.found)
        self.show_timing()
        self.horizon = pm.terrain_horizon(s.scn, s.inputs, self.sensor)
        if self.pick is not None:  # the pose may have changed under the picked pixel
            self.pick = pm.locate_pixel(s.scn, s.inputs, self.sensor, self.pick.row, self.pick.col)
            self.md_pick.content = pm.pick_markdown(self.pick)
            self._add_to_target()
        self.redraw_images()
        self.draw_pick()
        self.drape()

    def _mark_list(self):
        out = []
        if self.cb_marks.value:
            for name, (r, c, st) in self.marks.items():
                if st in (Status.OK, Status.OUTSIDE_SENSOR):
                    out.append((name, r, c, name))
        if self.cb_horizon.value and len(self.horizon):
            out.append(("horizon", self.horizon[:, 0], self.horizon[:, 1], None))
        if self.ground is not None and self.ground.ok and np.isfinite(self.ground.row):
            out.append(("ground" if self.ground.visible else "ground_hidden", self.ground.row, self.ground.col, None))
        if self.pick is not None:
            out.append(("pick", self.pick.row, self.pick.col, None))
        return out

    def redraw_images(self) -> None:
        """The panel's crop (with the marks) and the frustum's texture and placement."""
        if self.image is None:
            return
        import PIL.Image

        M, N = self.image.shape[:2]
        centre = (self.pick.row, self.pick.col) if self.pick is not None else None
        r1, c1, h, w = self.crop = crop_window(M, N, self.zoom, centre)
        crop = self.image[r1 - 1 : r1 - 1 + h, c1 - 1 : c1 - 1 + w, :3]
        s = PANEL_WIDTH / w
        H = max(int(round(h * s)), 1)
        disp = np.asarray(
            PIL.Image.fromarray(np.ascontiguousarray(crop)).resize((PANEL_WIDTH, H), PIL.Image.Resampling.NEAREST)
        )
        marks = self._mark_list()
        disp = draw_marks(disp, marks, lambda r, c: ((c - (c1 - 0.5)) * s, (r - (r1 - 0.5)) * s), 7.0)
        self.html.content = self._panel_html(disp, r1, c1, h, w)
        self._draw_frame(marks)

    def caption(self) -> str:
        """The picture's caption: the frame's one name (its timeline index, time and label:
        :func:`geoloc_viz.model.frame_name`), when the picture was taken and its pixel grid, the grid
        every pixel of the page is in. The image source's own frame count is not shown: a video
        holds frames the records skip, and a second numbering would not match the timeline."""
        from geoloc_viz.model import frame_name

        M, N = self.image.shape[:2]
        t = np.asarray(getattr(self.images, "times_s", []), float)
        when = f"picture at {t[self.k]:.2f} s; " if 0 <= self.k < len(t) and np.isfinite(t[self.k]) else ""
        return f"{frame_name(self.session.scn, self.index)}: {when}{N} x {M} px"

    def _panel_html(self, disp, r1, c1, h, w) -> str:
        uuid = self.tx_pixel._impl.uuid
        # the click handler: the clicked position as a fraction of the shown crop -> the pixel
        # (1-based centres: pixel k spans k - 0.5 .. k + 0.5), written into the "picked pixel"
        # box as typing would (React reads the native value setter's 'input' event)
        js = (
            "var b=this.getBoundingClientRect();"
            "var x=(event.clientX-b.left)/b.width,y=(event.clientY-b.top)/b.height;"
            f"var r=Math.floor({r1 - 0.5}+y*{h}+0.5),c=Math.floor({c1 - 0.5}+x*{w}+0.5);"
            f"var l=document.querySelector('label[for=\"{uuid}\"]');if(!l)return;"
            "var p=l.parentElement;while(p&&!p.querySelector('input'))p=p.parentElement;if(!p)return;"
            "var i=p.querySelector('input');"
            "Object.getOwnPropertyDescriptor(HTMLInputElement.prototype,'value').set.call(i,r+', '+c);"
            "i.dispatchEvent(new Event('input',{bubbles:true}));"
        )
        cap = self.caption() + f"; shown rows {r1}-{r1 + h - 1}, columns {c1}-{c1 + w - 1} (zoom {self.zoom} x)"
        return (
            f'<div style="padding:0 0.5em"><img id="geoloc-picture" alt="frame image" '
            f'data-r1="{r1}" data-c1="{c1}" data-h="{h}" data-w="{w}" '
            f'src="data:image/jpeg;base64,{_encode(disp)}" '
            f'style="width:100%;display:block;cursor:crosshair;image-rendering:pixelated" '
            f'onclick="{html.escape(js, quote=True)}">'
            f'<div style="font-size:0.75em;opacity:0.8">{html.escape(cap)}</div></div>'
        )

    # ------------------------------------------------------------ the frustum image
    def _hide(self, name) -> None:
        h = self.handles.get(name)
        if h is not None:
            try:
                h.visible = False
            except Exception:
                pass

    def _draw_frame(self, marks) -> None:
        s, g = self.session, self.session.geometry
        if not self.cb_frustum.value or g is None or self.sensor is None:
            self._hide(f"{ROOT}/frame")
            self.plane = None
            return
        pose = s.inputs.pose()
        sensor, enu, d = self.sensor, s.scn.enu, s.view.disp
        T = sensor.frames(pose).T_ecef("cam")
        R_enu_cam = enu.R_enu_from(T[:3, :3])
        C_enu = enu.from_ecef(T[:3, 3])
        M, N = sensor.rows, sensor.cols
        # the image's outline rays, through the sensor, in the optical frame; on the plane z = D
        rr = np.array([0.5, 0.5, M + 0.5, M + 0.5, (M + 1) / 2, (M + 1) / 2, 0.5, M + 0.5])
        cc = np.array([0.5, N + 0.5, N + 0.5, 0.5, 0.5, N + 0.5, (N + 1) / 2, (N + 1) / 2])
        los = sensor.line_of_sight(rr, cc, pose, outside="extrapolate")
        v = los.direction_ecef @ T[:3, :3]  # R_cam_ecef @ d for each ray
        centre = self.centre
        if centre is None:
            centre = pm.locate_pixel(s.scn, s.inputs, sensor, *sensor.center_pixel)
        rng = float(centre.hit.slant_range) if centre.ok else 5e3
        D = float(self.sl_dist.value) * rng
        p = D * v / v[:, 2:3]
        x_left, x_right = p[4, 0], p[5, 0]
        y_top, y_bottom = p[6, 1], p[7, 1]
        width, height = x_right - x_left, y_bottom - y_top
        mid_cam = np.array([(x_left + x_right) / 2, (y_top + y_bottom) / 2, D])
        W = WORLD_SCALE
        pos = d.z(C_enu) + W * (R_enu_cam @ mid_cam)
        # the texture: the image (downscaled for transport) with its marks, alpha = opacity
        import PIL.Image

        f = min(1.0, TEXTURE_MAX / max(M, N))
        tw, th = max(int(round(N * f)), 1), max(int(round(M * f)), 1)
        tex = np.asarray(
            PIL.Image.fromarray(np.ascontiguousarray(self.image[..., :3])).resize(
                (tw, th), PIL.Image.Resampling.BILINEAR
            )
        )
        tex = draw_marks(tex, marks, lambda r, c: ((c - 0.5) * tw / N, (r - 0.5) * th / M), max(tw / 120, 3))
        op = float(self.sl_opacity.value)
        if op < 0.999:
            tex = np.concatenate([tex, np.full(tex.shape[:2] + (1,), int(round(op * 255)), np.uint8)], axis=-1)
        name = f"{ROOT}/frame"
        fmt = "png" if tex.shape[2] == 4 else "jpeg"
        h = self.handles.get(name)
        if h is not None and self.scene.get_handle_by_name(name) is h and h.format == fmt:
            # a step sends the new picture and pose to the node, which the browser keeps (a re-created node is rebuilt)
            h.image = tex
            h.render_width, h.render_height = float(width * W), float(height * W)
            h.position, h.wxyz = tuple(pos), tuple(wxyz(R_enu_cam))
            if not h.visible:
                h.visible = True
        else:
            self.handles[name] = self.scene.add_image(
                name,
                tex,
                float(width * W),
                float(height * W),
                format=fmt,
                position=tuple(pos),
                wxyz=tuple(wxyz(R_enu_cam)),
                cast_shadow=False,
                receive_shadow=False,
            )
        self.plane = (pos, R_enu_cam, width * W, height * W)

    def pixel_on_frame(self, ray_origin, ray_direction):
        """(row, col) where a ray of the browser (scene units) crosses the frustum image; None if it misses."""
        if self.plane is None or self.sensor is None:
            return None
        pos, R, w, h = self.plane
        o, dvec = np.asarray(ray_origin, float), np.asarray(ray_direction, float)
        n = R[:, 2]
        den = float(dvec @ n)
        if abs(den) < 1e-12:
            return None
        t = float((pos - o) @ n) / den
        if t <= 0:
            return None
        local = R.T @ (o + t * dvec - pos)
        u, v = local[0] / w + 0.5, local[1] / h + 0.5
        if not (0.0 <= u <= 1.0 and 0.0 <= v <= 1.0):
            return None
        M, N = self.sensor.rows, self.sensor.cols
        # the pixel whose square holds the point (1-based centres)
        return (
            float(np.clip(math.floor(0.5 + v * M + 0.5), 1, M)),
            float(np.clip(math.floor(0.5 + u * N + 0.5), 1, N)),
        )

    # ------------------------------------------------------------ draping
    def drape(self) -> None:
        """The frame orthorectified (:func:`geoloc.workflows.ortho.orthorectify`) as a texture on a
        mesh of the DEM over the ortho's extent (``/enu/picture/drape``), when the toggle is on."""
        name = f"{ROOT}/drape"
        s = self.session
        if not self.cb_drape.value or self.image is None or s.scn.dem is None:
            self._hide(name)
            return
        key = (self.index, self.k, s.inputs, s.view.disp.vertical_exaggeration)
        if getattr(self, "_drape_key", None) == key and name in self.handles:
            self.handles[name].visible = True
            return
        mesh, info = drape_mesh(s.scn, s.inputs, self.sensor, self.image, s.view.disp)
        self.drape_info = info
        if mesh is None:
            self._hide(name)
            return
        self.handles[name] = self.scene.add_mesh_trimesh(name, mesh, cast_shadow=False, receive_shadow=False)
        self._drape_key = key

    # ------------------------------------------------------------ picking
    def on_pick(self, callback):
        """Register ``callback(layer)``, called after each pixel or terrain pick; returns it."""
        self._pick_cbs.append(callback)
        return callback

    def _emit_pick(self) -> None:
        for cb in list(self._pick_cbs):
            try:
                cb(self)
            except Exception:  # a listener's bug must not undo the pick
                traceback.print_exc(file=sys.stderr)

    def _on_pixel_text(self, event=None) -> None:
        if self.closed or own_update(self, event):
            return
        rc = parse_pixel(str(self.tx_pixel.value))
        if rc is not None:
            self._safe(self.pick_pixel, *rc)

    def pick_pixel(self, row: float, col: float) -> pm.PixelPick | None:
        """Locate pixel (row, col) of the current frame; draw its ray, hit and marks; fill the panel."""
        with self._lock:
            if self.sensor is None:
                return None
            s = self.session
            self.pick = pm.locate_pixel(s.scn, s.inputs, self.sensor, row, col)
            self.picks = (self.picks + [self.pick])[-MAX_PICKS:]
            text = f"{row:g}, {col:g}"
            if parse_pixel(str(self.tx_pixel.value)) != (row, col):
                self._mute = True
                try:
                    self.tx_pixel.value = text
                finally:
                    self._mute = False
            self.md_pick.content = pm.pick_markdown(self.pick)
            self._add_to_target()
            self.redraw_images()
            self.draw_pick()
            self.last_pick = "pixel"
            self._emit_pick()
            return self.pick

    # ------------------------------------------------------------ one target, several frames
    def _budget(self, velocity_known: bool = False):
        """(budget, note): the scenario's sensor file's, as this frame's sensor can carry it, else the
        illustrative one (:func:`geoloc_viz.uncertainty_layer.scenario_budget`)."""
        from geoloc_viz.uncertainty_layer import scenario_budget

        b, note, _ = scenario_budget(self.scn, self.sensor, velocity_known)
        return b, note

    def _add_to_target(self) -> None:
        """The current frame's pick becomes its ray of the target; triangulate when two frames have one."""
        import copy

        s = self.session
        if self.pick is None or self.index is None:
            return
        from geoloc_viz.uncertainty_layer import record_velocity

        self.target[self.index] = (self.sensor, copy.deepcopy(s.inputs), self.pick)
        vel = {k: record_velocity(s.scn, k) for k in self.target}  # a KLV flight's: a time_s term
        known = all(v is not None for v in vel.values())
        budget, note = self._budget(known)
        self.target_rays = pm.triangulate_picks(s.scn, self.target, budget, note, vel if known else None)
        self.md_target.content = pm.target_markdown(self.target_rays, len(self.target))
        self.draw_target()

    def clear_target(self) -> None:
        self.target = {}
        self.target_rays = None
        self.md_target.content = ""
        self.draw_target()

    def draw_target(self) -> None:
        """Each frame's ray of the target to just past the triangulated point, the point, its 90 %
        ellipse and each ray's residual (ray to point), the last two at the error vectors' scale."""
        s = self.session
        enu = s.scn.enu
        old = [n for n in self.handles if n.startswith(f"{ROOT}/target/")]
        t = self.target_rays
        shown = set()
        if t is not None and t.tri.status == Status.OK:
            X = enu.from_ecef(np.asarray(t.tri.ecef, float))
            k = float(getattr(s.view.disp, "error_exaggeration", 1.0))
            rays = []
            for o, c in zip(t.origins, t.closest):
                a = enu.from_ecef(o)
                b = enu.from_ecef(c)
                rays.append([a, a + 1.08 * (b - a)])
            self._line(f"{ROOT}/target/rays", rays, COLORS["target_rays"], 2.5)
            res = [[X, X + k * (enu.from_ecef(c) - X)] for c in t.closest]
            self._line(f"{ROOT}/target/residuals", res, COLORS["residual"], 4.0)
            self._ball(f"{ROOT}/target/point", X, COLORS["target_rays"], 1.0)
            # the drawing says its own scale: a person reading the residuals must know they are enlarged
            self.handles[f"{ROOT}/target/label"] = self.scene.add_label(
                f"{ROOT}/target/label",
                "triangulated target: residuals and 90 % ellipse " + ("at true size" if k == 1.0 else drawn_factor(k)),
                position=tuple(s.view.disp.z(X)),
                anchor="top-left",
            )
            shown |= {f"{ROOT}/target/rays", f"{ROOT}/target/residuals", f"{ROOT}/target/point"}
            shown.add(f"{ROOT}/target/label")
            if t.tri.cov_enu is not None and np.isfinite(t.tri.ellipse_major_m):
                pts = pm.target_ellipse_enu(enu, t.tri, scale=k)
                self._line(
                    f"{ROOT}/target/ellipse",
                    np.stack([pts, np.roll(pts, -1, axis=0)], 1),
                    COLORS["target_ellipse"],
                    4.0,
                )
                shown.add(f"{ROOT}/target/ellipse")
        for n in old + [f"{ROOT}/target/{x}" for x in ("rays", "residuals", "point", "ellipse", "label")]:
            if n not in shown:
                self._hide(n)
        # a button with nothing to do is not offered
        if self.bt_clear_target.visible != bool(self.target):
            self.bt_clear_target.visible = bool(self.target)

    def export_html(self) -> str:
        """The picture for a static export (``geoloc view --export``, which records the 3D scene
        but not the GUI): the whole frame with its marks and the picked pixel as a JPEG, and the
        panel's text (the pick's latitude, longitude, height and datum, range, status; the terrain
        pick; the painted marks)."""
        if self.image is None:
            return ""
        import PIL.Image

        from geoloc_viz.export_html import markdown_to_html

        M, N = self.image.shape[:2]
        s = PANEL_WIDTH / N
        disp = np.asarray(
            PIL.Image.fromarray(np.ascontiguousarray(self.image[..., :3])).resize(
                (PANEL_WIDTH, max(int(round(M * s)), 1)), PIL.Image.Resampling.BILINEAR
            )
        )
        marks = self._mark_list() + [("pick", p.row, p.col, None) for p in self.picks[:-1]]
        disp = draw_marks(disp, marks, lambda r, c: ((c - 0.5) * s, (r - 0.5) * s), 7.0)
        buf = io.BytesIO()
        PIL.Image.fromarray(disp).save(buf, format="JPEG", quality=88)
        b64 = base64.b64encode(buf.getvalue()).decode("ascii")
        text = [pm.pick_markdown(p) for p in self.picks]
        text += [t for t in (self.md_ground.content, self.md_found.content, self.md_timing.content) if t]
        cap = self.caption()
        return (
            f'<div id="geoloc-export-picture"><img alt="frame image" data-rows="{M}" data-cols="{N}" '
            f'style="width:100%;display:block;margin:6px 0" src="data:image/jpeg;base64,{b64}">'
            f'<span style="opacity:0.7">{html.escape(cap)}</span><br>'
            + "<br>".join(markdown_to_html(t) for t in text)
            + "</div>"
        )

    def pick_ground(self, origin_scene, direction_scene) -> pm.GroundPick | None:
        """A ray of the browser (scene units, vertical exaggeration included) on the terrain:
        its ground point, that point's pixel in the frame and whether the camera sees it."""
        with self._lock:
            if self.sensor is None:
                return None
            s = self.session
            k = WORLD_SCALE * np.array([1.0, 1.0, s.view.disp.vertical_exaggeration])
            # the scene's display map is linear: the browser's ray, unscaled, is a ray in ENU metres
            o_enu = np.asarray(origin_scene, float) / k
            d_enu = np.asarray(direction_scene, float) / k
            enu = s.scn.enu
            o_ecef = enu.to_ecef(o_enu)
            d_ecef = enu.R_ecef_enu @ (d_enu / np.linalg.norm(d_enu))
            self.ground = pm.ground_pick(s.scn, s.inputs, self.sensor, o_ecef, d_ecef)
            self.md_ground.content = pm.ground_markdown(self.ground)
            self.redraw_images()
            self.draw_pick()
            import copy

            self.ground_inputs = copy.deepcopy(s.inputs)
            self.last_pick = "ground"
            self._emit_pick()
            return self.ground

    def _on_scene_click(self, event) -> None:
        s = self.session
        if self.closed:
            return
        if s.client is not None and getattr(event, "client_id", s.client.client_id) != s.client.client_id:
            return  # presenter mode: only the driver picks
        px = self._safe(self.pixel_on_frame, event.ray_origin, event.ray_direction)
        if px is not None:
            self._safe(self.pick_pixel, *px)
        else:
            self._safe(self.pick_ground, event.ray_origin, event.ray_direction)

    # ------------------------------------------------------------ the picks in the scene
    def _line(self, name, pts, color, thickness=3.0):
        d = self.session.view.disp
        seg = d.z(np.asarray(pts, float).reshape(-1, 2, 3)).astype(np.float32)
        self.handles[name] = self.scene.add_line_segments(
            name, seg, color, thickness=thickness, thickness_units="screen"
        )

    def _ball(self, name, p, color, radius_factor=0.8):
        d = self.session.view.disp
        self.handles[name] = self.scene.add_icosphere(
            name,
            radius=radius_factor * d.marker_radius_m * WORLD_SCALE,
            color=color,
            position=tuple(d.z(p)),
            cast_shadow=False,
            receive_shadow=False,
        )

    def draw_pick(self) -> None:
        s = self.session
        enu = s.scn.enu
        names = (f"{ROOT}/ray", f"{ROOT}/hit", f"{ROOT}/iterations", f"{ROOT}/ground", f"{ROOT}/ground_ray")
        shown = set()
        p = self.pick
        if p is not None:
            a = enu.from_ecef(np.asarray(p.los.origin_ecef))
            if p.ok:
                b = enu.from_ecef(np.asarray(p.hit.ecef))
            else:
                b = a + 40e3 * enu.vector_from_ecef(np.asarray(p.los.direction_ecef))
            self._line(f"{ROOT}/ray", [a, b], COLORS["pick"], 4.0)
            shown.add(f"{ROOT}/ray")
            if p.ok:
                self._ball(f"{ROOT}/hit", b, COLORS["pick"])
                shown.add(f"{ROOT}/hit")
            if p.trace_ecef is not None and len(p.trace_ecef):
                pts = s.view.disp.z(enu.from_ecef(p.trace_ecef)).astype(np.float32)
                self.handles[f"{ROOT}/iterations"] = self.scene.add_point_cloud(
                    f"{ROOT}/iterations",
                    pts,
                    COLORS["pick"],
                    point_size=0.4 * s.view.disp.marker_radius_m * WORLD_SCALE,
                    point_shape="circle",
                    precision="float32",
                )
                shown.add(f"{ROOT}/iterations")
        gp = self.ground
        if gp is not None and gp.ok:
            col = COLORS["ground"] if gp.visible or not gp.in_frame else COLORS["ground_hidden"]
            gpt = enu.from_ecef(np.asarray(gp.hit.ecef))
            self._ball(f"{ROOT}/ground", gpt, col)
            shown.add(f"{ROOT}/ground")
            if gp.in_frame and self.sensor is not None:
                cam = enu.from_ecef(self.sensor.optical_centre_ecef(s.inputs.pose()))
                self._line(f"{ROOT}/ground_ray", [cam, gpt], col, 1.5)
                shown.add(f"{ROOT}/ground_ray")
        for n in names:
            if n not in shown:
                self._hide(n)

    def close(self) -> None:
        self.closed = True
        self._pick_cbs.clear()


#: Lift of the draped frame above the DEM [m], display only (the depth test would otherwise let
#: the terrain mesh, a coarser resampling of the DEM, poke through it).
DRAPE_LIFT_M = 40.0
#: Cells across the draped ortho (its ground sample follows) and mesh nodes per side.
DRAPE_CELLS = 320
DRAPE_NODES = 48


#: The timing searches running, and the word that stops them when the interpreter exits: a
#: daemon thread left inside the video decoder's native code as the process ends aborts it
#: ("terminate called without an active exception", SIGABRT: `geoloc view --export` did).
_TIMING_THREADS: weakref.WeakSet = weakref.WeakSet()
_TIMING_STOP = threading.Event()


@atexit.register
def _stop_timing_searches() -> None:
    _TIMING_STOP.set()
    for t in list(_TIMING_THREADS):
        t.join(timeout=60.0)  # a chunk of pictures at most (picture_model.MARKS_CHUNK)


def _search_over(layer_ref) -> bool:
    """Whether the timing search should stop: the interpreter is ending, or no one will see the
    answer (the layer is gone or closed, its server stopped). A search left running after its
    viewer closed kept decoding pictures in the background of whatever ran next."""
    if _TIMING_STOP.is_set():
        return True
    layer = layer_ref()
    return layer is None or layer.closed or _server_stopped(layer.session)


def _find_timing(layer_ref, scn) -> None:
    """Search the flight for video timing faults (:func:`geoloc_viz.picture_model.
    cached_video_timing_faults`) on a thread at low priority (the first view and a step keep the
    cores), then have the layer, if it is still open, name the current frame's run in its panel."""
    import os

    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)  # Linux: this thread only
    except (AttributeError, OSError):
        pass
    try:
        found = pm.cached_video_timing_faults(scn, should_stop=lambda: _search_over(layer_ref))
    except Exception:
        traceback.print_exc(file=sys.stderr)
        found = []
    layer = layer_ref()
    if layer is not None and not layer.closed:
        layer.timing = found
        if not _server_stopped(layer.session):  # a panel of a stopped server would never arrive
            layer._safe(layer.show_timing)


def _server_stopped(session) -> bool:
    """Whether the session's viser server was stopped (viser 1.1 sets its websocket server's
    ``_stop_event``; private, so anything unexpected counts as running)."""
    ws = getattr(getattr(session, "server", None), "_websock_server", None)
    ev = getattr(ws, "_stop_event", None)
    try:
        return bool(ev is not None and ev.is_set())
    except Exception:
        return False


def drape_mesh(scn, inputs, sensor, image, disp):
    """(trimesh with the ortho as its texture, ortho info) of a frame; (None, info) if nothing is seen.

    The ortho comes from :func:`geoloc.workflows.ortho.orthorectify` (written to a temporary
    GeoTIFF, read back with rasterio): geographic cells, alpha 0 where the camera does not see
    the cell. The mesh samples the DEM (``DEM.height``) on ``DRAPE_NODES`` x ``DRAPE_NODES``
    nodes over the ortho's bounds, in the scene's ENU frame (display map ``disp.z``).
    """
    import tempfile
    from pathlib import Path

    import PIL.Image
    import rasterio
    import trimesh

    from geoloc.workflows.ortho import locate_frame, orthorectify

    pose = inputs.pose()
    dem = scn.dem
    frame = locate_frame(sensor, pose, dem, step=max(1, min(sensor.rows, sensor.cols) // 60))
    with tempfile.TemporaryDirectory(prefix="geoloc-drape-") as d:
        # a first grid at 1 m would be huge for a wide frame: size the cell from the frame's extent
        probe = orthorectify(
            image.transpose(2, 0, 1), sensor, pose, dem, Path(d) / "probe.tif", gsd_m=50.0, frame=frame
        )
        extent_m = 50.0 * max(probe["width"], probe["height"])
        gsd = max(extent_m / DRAPE_CELLS, 0.25)
        info = orthorectify(image.transpose(2, 0, 1), sensor, pose, dem, Path(d) / "ortho.tif", gsd_m=gsd, frame=frame)
        with rasterio.open(info["path"]) as src:
            rgba = np.moveaxis(src.read(), 0, -1)
            T, w, h = src.transform, src.width, src.height
    if info["cells_seen"] == 0:
        return None, info
    n = DRAPE_NODES
    u = np.linspace(0.0, 1.0, n)
    U, V = np.meshgrid(u, u)  # V = 0 at the raster's top row
    lon = T.c + U * w * T.a
    lat = T.f + V * h * T.e
    H = dem.height(np.radians(lat), np.radians(lon))
    H = np.where(np.isfinite(H), H, np.nanmean(H)) + DRAPE_LIFT_M
    enu = scn.enu.from_geodetic(np.radians(lat), np.radians(lon), H)
    verts = disp.z(enu).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, e = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    faces = np.concatenate([np.stack([a, e, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    uv = np.stack([U.reshape(-1), 1.0 - V.reshape(-1)], axis=1)  # glTF/trimesh: v up from the bottom row
    mat = trimesh.visual.material.PBRMaterial(
        baseColorTexture=PIL.Image.fromarray(np.ascontiguousarray(rgba)),
        alphaMode="BLEND",
        doubleSided=True,
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    mesh = trimesh.Trimesh(verts, faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return mesh, info


def attach(session):
    """The picture layer when the session's scenario has images (``scn.images``), else None."""
    if pm.images_of(session.scn) is None:
        return None
    return ImageLayer(session)
