"""Atmospheric refraction in the scene (what it moves, made visible): the bent ray beside the straight one.

:func:`attach` (a layer of :class:`geoloc_viz.app.GeolocSession`) adds a "Refraction" GUI folder:

* **refraction** ``none`` / ``standard`` (``geoloc view --refraction``): the scene's
  :class:`geoloc.pipeline.Corrections` (``Scenario.corrections``), through which every located
  point of the session goes (the scene's hit, the picture's picks; :func:`geoloc_viz.model.compute`
  and :func:`geoloc_viz.picture_model.locate_pixel` call ``Pipeline(sensor, surface, corrections)``);
* **bent ray drawn x**: the bent ray's offset from the straight line of sight, multiplied for the
  drawing (a 10 m bend over 40 km is invisible at true size); true size by default, and the label on
  the drawing says the factor ("x100");
* the panel: which corrections are on and how far refraction moved the located point
  (``GroundPoint.refraction_m``, metres, to the millimetre).

The bent ray is scene node ``/enu/refraction/bent`` (:data:`COLOR`, spring green: no other meaning has it; lime is the picked pixel's),
a polyline of :data:`geoloc_viz.terrain_link.BENT_SAMPLES` points from the camera down to the located point
(:class:`geoloc_viz.terrain_link.BentRay`: ``Refraction.correct(..., at_h=H)``'s points); the straight line
of sight (yellow) then ends at its own raw hit. Every number comes from the core; this module only
draws. Method: ``docs/refraction.md``.
"""

from __future__ import annotations


import numpy as np
from geoloc_viz.layer_safety import call_safely
from geoloc_viz.palette import PALETTE

ROOT = "/enu/refraction"
#: The bent ray's colour, one meaning one colour: not the line of sight's yellow, the exact hit's
#: green nor any other colour of the scene (``app.legend_markdown``).
COLOR = PALETTE["bent"].rgb
COLOR_NAME = PALETTE["bent"].name
#: The largest exaggeration of the bent ray's offset the panel offers.
SCALE_MAX = 1000.0
#: The atmosphere's name, as the CLI prints it.
ATMOSPHERE = "U.S. Standard Atmosphere 1976"


def corrections_text(corrections) -> str:
    """``"refraction (U.S. Standard Atmosphere 1976)"``, ``"none"``, ...: which corrections are on."""
    names = list(corrections.names)
    return ", ".join(f"{n} ({ATMOSPHERE})" if n == "refraction" else n.replace("_", "-") for n in names) or "none"


def label_text(shift_m: float, k: float) -> str:
    """The label on the drawn bent ray: what it is, its factor when exaggerated, and the shift."""
    size = "true size" if k == 1.0 else f"x{k:g}"
    return f"bent ray (refraction), {size}: moved the point {shift_m:.2f} m"


class RefractionLayer:
    def __init__(self, session):
        self.session = session
        self.scene = session.scene
        self.handle = None
        self.label = None
        g = session.gui
        c = session.scn.corrections
        with g.add_folder("Refraction", expand_by_default=c.refraction is not None):
            self.dd = g.add_dropdown(
                "refraction",
                ("none", "standard"),
                initial_value="none" if c.refraction is None else "standard",
                hint="Atmospheric refraction of the line of sight: none (as the papers) "
                "or the ray bent through the U.S. Standard Atmosphere 1976",
            )
            self.sl_scale = g.add_slider(
                "bent ray drawn x",
                1.0,
                SCALE_MAX,
                1.0,
                1.0,
                hint="Draw the bent ray's offset from the straight line of sight this "
                "many times its size (display only); the label on the drawing says so",
            )
            self.md = g.add_markdown("")
        self.dd.on_update(lambda _e: self._safe(self.set_refraction, str(self.dd.value)))
        self.sl_scale.on_update(lambda _e: self._safe(self.update))
        session.on_refresh(lambda _g: self._safe(self.update))
        self._safe(self.update)

    def _safe(self, fn, *a):
        return call_safely(fn, *a)

    @property
    def scale(self) -> float:
        """The drawn offset's exaggeration (1: true size)."""
        return float(np.clip(float(self.sl_scale.value), 1.0, SCALE_MAX))

    def set_refraction(self, model: str) -> None:
        """Turn refraction ``"none"`` / ``"standard"`` for the scene and locate again."""
        s = self.session
        c = s.scn.corrections
        new = c.overridden(s.scn.camera, refraction=model)
        if new == c:
            return
        s.scn.corrections = new
        if self.dd.value != model:
            self.dd.value = model
        s.refresh()  # every located point again, through the new pipeline (then update, via on_refresh)
        for lay in getattr(s, "layers", ()):  # the whole flight too (the flight debugger's every frame)
            rebuild = getattr(lay, "rebuild", None)
            if rebuild is not None and not getattr(lay, "closed", False):
                rebuild()

    def _hide(self) -> None:
        for h in (self.handle, self.label):
            if h is not None and h.visible:
                h.visible = False

    def update(self) -> None:
        s = self.session
        g = s.geometry
        c = s.scn.corrections
        head = f"corrections: **{corrections_text(c)}**"
        bent = None if g is None else g.bent
        if c.refraction is None or bent is None:
            self._hide()
            why = "" if c.refraction is None else "  \nno located point to refract"
            self.md.content = head + why
            return
        k = self.scale
        pts = bent.drawn(k)
        seg = s.view.disp.z(np.stack([pts[:-1], pts[1:]], 1)).astype(np.float32)
        h = self.handle
        if h is not None and self.scene.get_handle_by_name(f"{ROOT}/bent") is h and h.points.shape == seg.shape:
            h.points = seg
            h.visible = True
        else:
            if h is not None:
                self.scene.remove_by_name(f"{ROOT}/bent")
            self.handle = self.scene.add_line_segments(
                f"{ROOT}/bent", seg, COLOR, thickness=4.0, thickness_units="screen"
            )
        text = label_text(bent.shift_m, k)
        # the label at the bent ray's middle, where it is farthest from the straight line
        pos = tuple(float(v) for v in s.view.disp.z(pts[len(pts) // 2]))
        lb = self.label
        if lb is not None and self.scene.get_handle_by_name(f"{ROOT}/label") is lb:
            lb.text, lb.position = text, pos
            lb.visible = True
        else:
            self.label = self.scene.add_label(f"{ROOT}/label", text, position=pos, anchor="bottom-left")
        off = np.linalg.norm(bent.bent_enu - bent.straight_enu, axis=-1)
        self.md.content = "  \n".join(
            [
                head,
                f"refraction moved the point **{bent.shift_m:.3f} m** (from the straight line of sight's hit)",
                f"bent ray: at most {float(off.max()):.2f} m from the straight line on its way down; "
                + ("drawn at true size" if k == 1.0 else f"**drawn x{k:g}** (its label says so)"),
            ]
        )


def attach(session):
    """The refraction layer (every scenario with a frame sensor)."""
    return RefractionLayer(session)
