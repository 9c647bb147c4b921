"""The ``geoloc view`` application: a viser server with the scene and its GUI.

:class:`GeolocApp` wires the GUI controls (pose, gimbal, pixel, method, record,
display) to :func:`geoloc.viz.model.compute` (the core) and :class:`geoloc.viz.scene_geoloc.GeolocScene`
(drawing). :func:`make_server` starts viser on 127.0.0.1 by default.
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import viser

from geoloc.locate import as_sensor
from geoloc.status import describe
from geoloc.viz import teaching
from geoloc.viz.model import Inputs, Scenario, compute, drawn_frames
from geoloc.viz.scenario import select_record
from geoloc.viz.scene_geoloc import Display, GeolocScene

#: (field, label, min, max, step) of the pose sliders, degrees.
ANGLE_SLIDERS = (
    ("heading_deg", "heading psi (deg)", -180.0, 180.0, 0.0001),
    ("pitch_deg", "pitch theta (deg)", -30.0, 30.0, 0.0001),
    ("roll_deg", "roll phi (deg)", -60.0, 60.0, 0.0001),
    ("gimbal_roll_deg", "gimbal roll (deg)", -85.0, 85.0, 0.0001),
    ("gimbal_pitch_deg", "gimbal pitch (deg)", -30.0, 30.0, 0.0001),
)
CUSTOM = "(custom pose)"
LEGEND = """\
- **red** ball: the chosen method's answer; **green**: the exact first hit;
  **light blue**: the ellipsoid hit at H_max (where [Q17]'s steps start)
- **yellow** line: line of sight; **orange**: image footprint (corner rays)
- iterations: dots on the line of sight at H_n with a segment to the DEM
  height h_n below, **blue** if H_n - h_n > 0 (above the terrain), **red** below;
  **cyan**: bisection brackets
- **violet**: published position [Q17]; **white**: surveyed; **pink**: error
  vector computed -> surveyed (exaggerated, see Display)
- frames at the aircraft: axes x red, y green, z blue; NED largest, then body,
  outer gimbal, camera (Z = optical axis)
- scene: East-North-Up at the target, world unit km; zoom with the wheel,
  rotate with the left button, pan with the right
"""


def make_server(host: str = "127.0.0.1", port: int = 8080, verbose: bool = False) -> viser.ViserServer:
    """A viser server bound to ``host`` (local only by default); ``port=0`` picks a free port."""
    server = viser.ViserServer(host=host, port=port, label="geoloc", verbose=verbose)
    server.scene.set_up_direction("+z")
    server.gui.configure_theme(dark_mode=True, control_width="large")
    # viser's default fog is tuned for scenes of a few metres; ours spans tens of km.
    server.scene.configure_fog(1.0, 1.0, enabled=False)
    # Shadow maps over tens of km cost much and show little (and are slow in software WebGL).
    server.scene.configure_default_lights(True, cast_shadow=False)
    return server


class GeolocApp:
    """The geolocation scene with its GUI on one server."""

    def __init__(self, server: viser.ViserServer, scn: Scenario, disp: Display | None = None):
        self.server = server
        self.scn = scn
        self.view = GeolocScene(server.scene, scn, disp)
        self.inputs: Inputs = scn.inputs.replace()
        self.geometry = None
        self.error: str = ""
        self.last_update_s = float("nan")
        self._mute = False
        self._build_gui()
        self.view.draw_static()
        self.refresh()
        self.view.set_initial_camera(server)
        # Issue 8: error vectors of all records, before/after a fitted mounting rotation.
        from geoloc.viz.calibration_layer import attach as attach_calibration

        self.calibration = attach_calibration(self)

    # ------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.server.gui
        self.md_summary = gui.add_markdown("")
        labels = [info.label for info, _ in self.scn.records]
        with gui.add_folder("Flight-test record"):
            init = labels[self.scn.record_index] if self.scn.record_index is not None else CUSTOM
            self.dd_record = gui.add_dropdown("record", labels + [CUSTOM], initial_value=init,
                                              hint="Load a bundled flight-test record of [Q17]")
            self.dd_record.on_update(lambda _: self._on_record())
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
                h.on_update(lambda _: self._on_inputs())
        with gui.add_folder("Terrain method"):
            from geoloc.viz import terrain_link

            self.dd_method = gui.add_dropdown("method", terrain_link.METHODS, initial_value=i.method)
            self.num_eps = gui.add_number("eps_h steps (m)", i.eps_h, min=0.1, max=1000.0, step=0.1)
            self.num_thr = gui.add_number("bisect threshold (m)", i.threshold, min=0.01, max=1000.0,
                                          step=0.01)
            for h in (self.dd_method, self.num_eps, self.num_thr):
                h.on_update(lambda _: self._on_inputs())
            self.cb_all_steps = gui.add_checkbox("show all iterations", True)
            self.sl_step = gui.add_slider("iteration n", 0, 1, 1, 0, disabled=True)
            self.cb_all_steps.on_update(lambda _: self._on_display())
            self.sl_step.on_update(lambda _: self._on_display())
        with gui.add_folder("View"):
            self.bt_overview = gui.add_button("overview: aircraft, frames, line of sight")
            self.bt_target = gui.add_button("target: iterations and hits")
            self.bt_overview.on_click(lambda _: self.view.move_clients(self.server, "overview"))
            self.bt_target.on_click(lambda _: self.view.move_clients(self.server, "target"))
        with gui.add_folder("Legend", expand_by_default=False):
            gui.add_markdown(LEGEND)
        with gui.add_folder("Display"):
            d = self.view.disp
            self.sl_vexag = gui.add_slider("vertical exaggeration", 1.0, 10.0, 0.5, d.vertical_exaggeration)
            self.sl_ac = gui.add_slider("aircraft display scale", 1.0, 300.0, 1.0, d.aircraft_scale)
            self.sl_err = gui.add_slider("error vector exaggeration", 1.0, 100.0, 1.0, d.error_exaggeration)
            self.sl_marker = gui.add_slider("marker radius (m)", 10.0, 500.0, 10.0, d.marker_radius_m)
            self.cb_frames = {f: gui.add_checkbox(f"frame {f}", True) for f in drawn_frames(self.scn.camera)}
            self.cb_terrain = gui.add_checkbox("terrain", True)
            self.cb_labels = gui.add_checkbox("marker labels", d.marker_labels,
                                              hint="Labels of the hit markers (they overlap until you zoom in)")
            for h in (self.sl_vexag, self.sl_ac, self.sl_err, self.sl_marker, self.cb_terrain, self.cb_labels,
                      *self.cb_frames.values()):
                h.on_update(lambda _: self._on_display())
        with gui.add_folder("Teaching: the chain of 4x4 matrices", expand_by_default=False):
            hops0 = teaching.hops(self._chain0())
            self._hop_src = {h.key: h.src for h in hops0}
            self.dd_hop = gui.add_dropdown("hop", ["(none)"] + [h.key for h in hops0])
            self.dd_hop.on_update(lambda _: self._on_display())
            self.md_hop = gui.add_markdown("")
            self.md_q17 = gui.add_markdown("")

    def _chain0(self):
        return as_sensor(self.scn.camera).frames(self.inputs.pose())

    def _angle_sliders(self):
        """Attitude sliders, then one per joint angle of the sensor's gimbal (``angle:NAME`` keys)."""
        out = list(ANGLE_SLIDERS[:3])
        q17 = {row[0][:-4]: row for row in ANGLE_SLIDERS[3:]}
        for name in as_sensor(self.scn.camera).angle_names:
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
        return self.inputs.replace(method=str(self.dd_method.value), eps_h=float(self.num_eps.value),
                                   threshold=float(self.num_thr.value), angles_deg=angles, **vals)

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

    # ------------------------------------------------------------ callbacks
    def _on_inputs(self) -> None:
        if self._mute:
            return
        self.inputs = self._read_inputs()
        if self.scn.record_index is not None and self.dd_record.value != CUSTOM:
            rec_inp = self.scn.records[self.scn.record_index][1]
            if any(abs(self._input_value(self.inputs, k) - self._input_value(rec_inp, k)) > 1e-9
                   for k in self.num):
                self._mute = True
                self.dd_record.value = CUSTOM
                self._mute = False
        self.refresh()

    def _on_display(self) -> None:
        if self._mute:
            return
        self._read_display()
        self.refresh(recompute=False)

    def _on_record(self) -> None:
        if self._mute or self.dd_record.value == CUSTOM:
            return
        labels = [info.label for info, _ in self.scn.records]
        self.load_record(labels.index(self.dd_record.value))

    def load_record(self, idx: int) -> None:
        """Load record ``idx``: pose, pixel, new ENU origin and terrain, then redraw."""
        select_record(self.scn, idx)
        keep = self.inputs
        self.inputs = self.scn.inputs.replace(method=keep.method, eps_h=keep.eps_h,
                                              threshold=keep.threshold)
        self._mute = True
        try:
            for k, h in self.num.items():
                h.value = self._input_value(self.inputs, k)
            label = self.scn.records[idx][0].label
            if self.dd_record.value != label:
                self.dd_record.value = label
        finally:
            self._mute = False
        with self.server.atomic():
            self.view.draw_static()
            if getattr(self, "calibration", None) is not None:
                self.calibration.rebuild()  # the ENU origin moved with the record
        self.refresh()
        self.view.set_initial_camera(self.server)

    # ------------------------------------------------------------ redraw
    def refresh(self, recompute: bool = True) -> None:
        """Recompute with the core (unless only the display changed) and redraw; time it."""
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
                    self.sl_step.value = max(n - 1, 0)
            finally:
                self._mute = False
            with self.server.atomic():
                self.view.update(g)
            self._update_text(g)
        self.last_update_s = time.perf_counter() - t0

    def _update_text(self, g) -> None:
        scn, enu = self.scn, self.scn.enu
        lines = [f"**{scn.name}**  ",
                 f"terrain: {scn.dem_name}  ",
                 f"scene: local East-North-Up, origin {np.rad2deg(enu.lat0):.3f} N "
                 f"{np.rad2deg(enu.lon0):.3f} E h {enu.h0:.0f} m; scale bar 5 km  "]
        if self.error:
            lines.append(f"\n**input error:** {self.error}")
        hit = g.hit
        if int(hit.status) == 0:
            lines.append(f"\n**{g.hit_label}**: {float(hit.lat_deg):.6f} N, {float(hit.lon_deg):.6f} E, "
                         f"h {float(hit.h):.1f} m, slant range {float(hit.slant_range) / 1e3:.2f} km  ")
        else:
            lines.append(f"\n**no hit**: {describe(int(hit.status))}  ")
        if g.message:
            lines.append(g.message + "  ")
        if scn.record_index is not None and self.dd_record.value != CUSTOM:
            info = scn.records[scn.record_index][0]
            from geoloc.geodesy.geodesic import horizontal_distance_m

            if int(hit.status) == 0 and np.isfinite(info.truth_lat_deg):
                e_t = float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, info.truth_lat_deg,
                                                  info.truth_lon_deg))
                e_p = float(horizontal_distance_m(hit.lat_deg, hit.lon_deg, info.paper_lat_deg,
                                                  info.paper_lon_deg))
                text = f"to surveyed: {e_t:.1f} m (horizontal)"
                if np.isfinite(info.paper_error_m):
                    text += f" (published error {info.paper_error_m:.1f} m)"
                if np.isfinite(e_p):
                    text += f"; to published: {e_p:.1f} m"
                lines.append(text)
        self.md_summary.content = "\n".join(lines)
        hop = str(self.dd_hop.value)
        hv = {h.key: h for h in teaching.hops(g.chain)}
        self.md_hop.content = (teaching.hop_markdown(hv[hop]) if hop in hv
                               else teaching.chain_markdown(g.chain))
        self.md_q17.content = teaching.q17_factors_markdown(g.chain)

    # ------------------------------------------------------------ export
    def export(self, path, animate_steps: bool = True) -> Path:
        """Write the current scene as a static recording: ``.viser`` or self-contained ``.html``.

        With ``animate_steps`` the recording then walks through the iterations
        of the terrain method one by one (0.4 s each). GUI controls are not exported.
        """
        path = Path(path)
        ser = self.server.get_scene_serializer()
        it = self.geometry.iterations if self.geometry is not None else None
        if animate_steps and it is not None and len(it.H) > 1:
            d = self.view.disp
            saved = d.step
            ser.insert_sleep(1.0)
            for k in range(len(it.H)):
                d.step = k
                self.view.update(self.geometry)
                ser.insert_sleep(0.4)
            d.step = saved
            self.view.update(self.geometry)
            ser.insert_sleep(1.0)
        if path.suffix.lower() == ".html":
            from geoloc.viz.export_html import with_summary

            # the serializer records the scene, not the GUI: the summary (record, hit,
            # error to the surveyed point) goes into the page as a panel of its own
            page = with_summary(ser.as_html(dark_mode=True), f"geoloc view: {self.scn.name}",
                                self.md_summary.content,
                                "Static export of geoloc view (no controls); "
                                "the scene animates the terrain method's iterations.")
            path.write_text(page)
        else:
            path.write_bytes(ser.serialize())
        return path
