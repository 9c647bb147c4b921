"""Predicted uncertainty in the scene: the 90 % error ellipse on the terrain at the hit, beside the measured errors.

:func:`attach` (a layer of :class:`geoloc_viz.app.GeolocSession`) draws, for the current record or
pose, the predicted 90 % horizontal error ellipse of the located point
(:func:`geoloc.analysis.uncertainty.propagate`: the sensor's error budget carried through the
chain and the scene's surface) as a closed line draped on the terrain (each vertex at the DEM's
height there; at the hit's height without a DEM), scene node ``/enu/uncertainty/ellipse``, in its
own colour (:data:`COLOR`, teal: no other meaning has it), at true size by default; the panel's
"ellipse drawn x" control enlarges it about the point, and the label on the drawing
(``/enu/uncertainty/label``, at the end of the major axis) then says the factor ("x10"); and in
a "Predicted uncertainty" GUI folder the predicted CE90 / LE90 beside the actual error: the
distance from the located point to the surveyed truth (or the published point) and where it lies
against its own ellipse (1 = on the 90 % ellipse).

The budget is the scenario's sensor file's ``[uncertainty]`` table (``scn.budget``, read by
:func:`geoloc_viz.scenario.load_view_scenario`), less what the viewer cannot carry, said in the
panel (:func:`usable_budget`: ``time_s`` where the record has no platform velocity, a records CSV;
a KLV flight's records have theirs, ``Scenario.record_velocity_ned``; lens keys the frame's lens
lacks, a KLV frame's lens being made from its fields of view); without one an illustrative budget
(:func:`view_budget`) is used and the panel says so (:func:`scenario_budget`).
Every number comes from the core; this module only draws. Conventions: ``docs/conventions.md``;
the method: ``docs/uncertainty.md``.
"""

from __future__ import annotations

import math

import numpy as np

from geoloc.analysis.uncertainty import ELLIPSE90_PER_SIGMA, normalised_errors, propagate
from geoloc.geodesy.local import ellipse_ring_enu, enu_to_geodetic
from geoloc.sensors.budget import LENS_KEYS, ErrorBudget
from geoloc.status import Status
from geoloc_viz.layer_safety import call_safely
from geoloc_viz.palette import PALETTE

ROOT = "/enu/uncertainty"
#: The predicted 90 % ellipse's colour, one meaning one colour (layers are told apart by it): not the flight layer's
#: magenta current footprint, nor any other colour of the scene (``app.legend_markdown``).
COLOR = PALETTE["ellipse"].rgb
COLOR_NAME = PALETTE["ellipse"].name
#: The largest enlargement of the drawn ellipse the panel offers.
SCALE_MAX = 100.0
VERTICES = 96
#: The drawn ellipse floats this much above the terrain [m] (the scene's mesh and the DEM's bilinear
#: surface differ between nodes: a line exactly on the DEM dips in and out of the mesh).
LIFT_M = 5.0


def view_budget(sensor, on_dem: bool) -> ErrorBudget:
    """The illustrative budget of a scenario without one: 2 m / 3 m of position, 0.05 deg of
    heading, 0.03 deg of pitch, roll and every joint, and the surface's SRTM LE90 (or 10 m)."""
    b = {"north_m": 2.0, "east_m": 2.0, "up_m": 3.0, "heading_deg": 0.05, "pitch_deg": 0.03, "roll_deg": 0.03}
    b.update({f"{a}_deg": 0.03 for a in sensor.angle_names})
    if on_dem:
        return ErrorBudget(b, "srtm", "illustrative budget")
    b["height_m"] = 10.0
    return ErrorBudget(b, None, "illustrative budget")


def usable_budget(budget: ErrorBudget, sensor, velocity_known: bool = False) -> tuple[ErrorBudget, list]:
    """``budget`` less the keys the viewer cannot propagate for ``sensor``, and a note per key left out.

    ``time_s`` moves the platform by its velocity: without one (``velocity_known`` False: a records
    CSV carries none) it is left out, as ``geoloc replay`` leaves it out; a lens key (``k1``,
    ``fx_px``, ...) of a parameter the frame's lens does not have is the sensor file's lens's, not
    this frame's (a KLV frame's lens is made from its fields of view:
    ``geoloc.workflows.klv_replay.klv_sensor``)."""
    lens_params = sensor.lens.params
    keep, notes = {}, []
    for k, v in budget.sigmas.items():
        if k == "time_s" and v > 0 and not velocity_known:
            notes.append(f"time_s = {v:g} s left out (no platform velocity for this record)")
        elif k in LENS_KEYS and LENS_KEYS[k] not in lens_params:
            notes.append(f"{k} = {v:g} left out (this frame's lens has no {LENS_KEYS[k]})")
        else:
            keep[k] = v
    return ErrorBudget(keep, budget.dem_product, budget.source), notes


def record_velocity(scn, index) -> np.ndarray | None:
    """Record ``index``'s platform velocity (north, east, down) [m/s] (``Scenario.record_velocity_ned``,
    a KLV flight's), or None where it is not known."""
    v = getattr(scn, "record_velocity_ned", None)
    if v is None or index is None or not 0 <= int(index) < len(v):
        return None
    v = np.asarray(v[int(index)], float)
    return v if np.all(np.isfinite(v)) else None


def scenario_budget(scn, sensor=None, velocity_known: bool = False) -> tuple[ErrorBudget, str, bool]:
    """``(budget, note, illustrative)``: the budget the viewer propagates for ``sensor`` (default the
    scenario's): the scenario's sensor file's (``scn.budget``) through :func:`usable_budget`, the
    note naming the file and what was left out (``time_s`` kept with ``velocity_known``, and said
    to move the platform by the record's velocity); else :func:`view_budget`'s, ``illustrative`` True."""
    b = getattr(scn, "budget", None)
    if b is None:
        return view_budget(scn.camera, scn.dem is not None), "illustrative budget", True
    b, notes = usable_budget(b, scn.camera if sensor is None else sensor, velocity_known)
    if b.sigma("time_s") > 0:
        notes.append(f"time_s = {b.sigma('time_s'):g} s moves the platform by the packets' velocity")
    note = f"the budget of {b.source}" + (f"; {'; '.join(notes)}" if notes else "")
    return b, note, False


def ellipse_points_enu(scn, pu, enu, n: int = VERTICES, scale: float = 1.0) -> np.ndarray:
    """The 90 % ellipse's vertices (n, 3) in the scene's ENU frame [m], draped on the scene's DEM;
    ``scale`` draws it larger about the point (the display's error-vector exaggeration)."""
    a, b = (float(v) * ELLIPSE90_PER_SIGMA * scale for v in (pu.ellipse_major_m, pu.ellipse_minor_m))
    lat0, lon0, h0 = (float(np.asarray(v)) for v in (pu.lat, pu.lon, pu.h))
    lat, lon, h = enu_to_geodetic(ellipse_ring_enu(a, b, float(pu.ellipse_azimuth_deg), n), lat0, lon0, h0)
    if scn.dem is not None:
        hd = np.asarray(scn.dem.height(lat, lon), float)
        h = np.where(np.isfinite(hd), hd, h0)
    else:
        h = np.full(n, h0)
    return enu.from_geodetic(lat, lon, h + LIFT_M)


class UncertaintyLayer:
    def __init__(self, session):
        self.session = session
        self.scene = session.scene
        self.handle = None
        self.pu = None
        g = session.gui
        with g.add_folder("Predicted uncertainty", expand_by_default=False):
            self.cb_show = g.add_checkbox("90 % error ellipse at the hit", True)
            self.sl_scale = g.add_slider(
                "ellipse drawn x",
                1.0,
                SCALE_MAX,
                1.0,
                1.0,
                hint="Draw the ellipse this many times its size about the point "
                "(display only); the label on the drawing gives the factor",
            )
            self.md = g.add_markdown("")
        self.label = None
        self.cb_show.on_update(lambda _e: self._safe(self.update))
        self.sl_scale.on_update(lambda _e: self._safe(self.update))
        session.on_refresh(lambda _g: self._safe(self.update))
        self._safe(self.update)

    def _safe(self, fn, *a):
        return call_safely(fn, *a)

    @property
    def scale(self) -> float:
        """The drawn ellipse's enlargement (1: true size)."""
        return float(np.clip(float(self.sl_scale.value), 1.0, SCALE_MAX))

    def _hide(self) -> None:
        for h in (self.handle, self.label):
            if h is not None and h.visible:
                h.visible = False

    def budget(self, velocity_known: bool = False):
        """``(budget, note, illustrative)`` (:func:`scenario_budget`)."""
        return scenario_budget(self.session.scn, velocity_known=velocity_known)

    def update(self) -> None:
        s = self.session
        g = s.geometry
        if g is None or g.status != Status.OK:
            self._hide()
            self._text("no located point")
            return
        from geoloc_viz import terrain_link

        vel = record_velocity(s.scn, s.scn.record_index)
        budget, note, illustrative = self.budget(vel is not None)
        inp = s.inputs
        pu = propagate(
            s.scn.camera,
            inp.pose(),
            inp.row,
            inp.col,
            budget,
            surface=terrain_link.scene_surface(s.scn, inp, trace=False),
            outside="extrapolate",
            velocity_ned_m_s=vel if budget.sigma("time_s") > 0 else None,
            corrections=s.scn.corrections,
        )  # the ellipse about the scene's (corrected) point
        self.pu = pu
        if pu.status != Status.OK:
            self._hide()
            self._text("no predicted uncertainty (the ray has no ground point)")
            return
        k = self.scale
        pts = ellipse_points_enu(s.scn, pu, s.scn.enu, scale=k)
        if self.cb_show.value:
            seg = s.view.disp.z(np.stack([pts, np.roll(pts, -1, axis=0)], 1)).astype(np.float32)
            h = self.handle
            if h is not None and self.scene.get_handle_by_name(f"{ROOT}/ellipse") is h and h.points.shape == seg.shape:
                # a timeline step moves the ellipse (one update message), not a remove and an add
                h.points = seg
                h.visible = True
            else:
                self._hide()
                self.handle = self.scene.add_line_segments(
                    f"{ROOT}/ellipse", seg, COLOR, thickness=4.0, thickness_units="screen"
                )
            # the label on the drawing: at the end of the major axis (the vertex farthest from the point)
            c = s.scn.enu.from_geodetic(*(float(np.asarray(v)) for v in (pu.lat, pu.lon, pu.h)))
            tip = pts[int(np.argmax(np.hypot(*(pts[:, :2] - c[:2]).T)))]
            text = label_text(pu, k)
            pos = tuple(float(v) for v in s.view.disp.z(tip))
            lb = self.label
            if lb is not None and self.scene.get_handle_by_name(f"{ROOT}/label") is lb:
                lb.text, lb.position = text, pos
                lb.visible = True
            else:
                self.label = self.scene.add_label(f"{ROOT}/label", text, position=pos, anchor="bottom-left")
        else:
            self._hide()
        lines = [
            f"predicted **CE90 {float(pu.ce90_m):.1f} m**, **LE90 {float(pu.le90_m):.1f} m** "
            f"(90 % ellipse {float(pu.ellipse_major_m) * ELLIPSE90_PER_SIGMA:.1f} x "
            f"{float(pu.ellipse_minor_m) * ELLIPSE90_PER_SIGMA:.1f} m, major axis at "
            f"{float(pu.ellipse_azimuth_deg):.0f} deg; "
            + ("drawn at true size)" if k == 1.0 else f"**drawn x{k:g}**, its label says so)")
        ]
        ref, name = (
            (g.surveyed_enu, "surveyed truth") if g.surveyed_enu is not None else (g.published_enu, "published point")
        )
        if ref is not None and np.all(np.isfinite(ref)) and np.all(np.isfinite(g.hit_enu)):
            d = np.asarray(g.hit_enu, float) - np.asarray(ref, float)
            r = (
                float(normalised_errors(d[0], d[1], pu.ellipse_major_m, pu.ellipse_minor_m, pu.ellipse_azimuth_deg))
                / ELLIPSE90_PER_SIGMA
            )
            lines.append(
                f"actual error to the {name}: **{math.hypot(d[0], d[1]):.1f} m** horizontal, "
                f"{r:.2f} x its own 90 % ellipse ({'inside' if r <= 1 else 'outside'})"
            )
        if illustrative:
            lines.append(
                "_illustrative budget (the scenario's sensor has no [uncertainty] table): "
                "2 m / 3 m position, 0.05 deg heading, 0.03 deg attitude and joints, "
                + ("SRTM 16 m LE90_" if s.scn.dem is not None else "10 m height_")
            )
        else:
            lines.append(f"budget: {note}")
        self._text("  \n".join(lines))

    def _text(self, text: str) -> None:
        """The panel's text; during a timeline step with the panels' batch, after the scene."""
        later = getattr(self.session, "later", None)
        if later is not None:
            later(lambda: setattr(self.md, "content", text))
        else:
            self.md.content = text


def label_text(pu, k: float) -> str:
    """The label on the drawn ellipse: what it is, its factor when enlarged, and its CE90."""
    size = "true size" if k == 1.0 else f"x{k:g}"
    return f"90 % ellipse, {size} (CE90 {float(pu.ce90_m):.1f} m)"


def attach(session):
    """The predicted-uncertainty layer (every scenario with a frame sensor)."""
    return UncertaintyLayer(session)
