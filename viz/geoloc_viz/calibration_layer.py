"""Flight-test error vectors in the viser scene, before and after calibration: what the fit removed and what is left.

Each record's error (computed minus surveyed truth) is drawn as a line segment
from the truth point to ``truth + exaggeration * (computed - truth)``, in the
scene's local ENU frame (:class:`geoloc.frames.enu.EnuFrame`, metres; three.js stores
float32, hence the local origin). The truth is placed at the computed point's
height (the records give no truth height), so the segments are horizontal.
Geometry comes from the core only (:func:`geoloc.locate.locate`,
:mod:`geoloc.frames.enu`); the calibrated sensor is the one of ``geoloc calibrate
--write-camera`` / ``--write-sensor`` or :func:`geoloc.analysis.sensor_fit.fit_sensor_groups`.

Conventions: ``docs/conventions.md``. Scene nodes (under ``name``, default
``/calibration``; ``/enu/calibration`` in the ``geoloc view`` app): ``truth``
(points), ``before`` and ``after`` (segments). Coordinates are ENU metres times
``world_scale`` (scene units per metre: 1e-3 in the app, whose world unit is
the km); the vertical exaggeration is a node scale (1, 1, v) about the ENU
origin, as the app's terrain.
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geoloc.frames.enu import EnuFrame
from geoloc.io.records import Records
from geoloc.locate import locate

if TYPE_CHECKING:
    from viser import LineSegmentsHandle

#: Segment colours (RGB 0-255): before red, after blue; truth markers white.
COLORS = {"before": (220, 40, 40), "after": (40, 90, 230), "truth": (255, 255, 255)}
STAGES = ("before", "after", "both")


@dataclass
class ErrorGeometry:
    """Truth and computed positions in the scene's ENU frame [m].

    Attributes
    ----------
    truth : ndarray (n, 3)
    computed : dict
        Stage name (``"before"``, ``"after"``) -> ndarray (n, 3); NaN rows for
        records whose ray failed (they are not drawn).
    labels : list of str
    """

    truth: np.ndarray
    computed: dict
    labels: list

    def segments(self, stage: str, exaggeration: float) -> np.ndarray:
        """Segments (m, 2, 3): truth -> truth + exaggeration * (computed - truth), failed rays dropped."""
        c = self.computed[stage]
        ok = np.all(np.isfinite(c), axis=1) & np.all(np.isfinite(self.truth), axis=1)
        t = self.truth[ok]
        return np.stack([t, t + exaggeration * (c[ok] - t)], axis=1)


def error_geometry(
    records: Records, frame: EnuFrame, heights, cameras: dict, truth_prefix: str = "truth"
) -> ErrorGeometry:
    """Locate every record with each camera (at ``heights``) and express all in ENU.

    Parameters
    ----------
    records : Records
        With ``{truth_prefix}_lat_deg`` / ``_lon_deg``.
    frame : EnuFrame
        The scene's origin.
    heights : array_like
        Target ellipsoidal height of each record [m] (e.g. ``paper_height_m``).
    cameras : dict
        Stage name -> sensor (a camera file's ``Camera`` or any sensor :func:`geoloc.locate.locate`
        takes), e.g. ``{"before": nominal, "after": calibrated}``.
    """
    h = np.asarray(heights, float)
    pose, row, col = records.pose(), records.column("row"), records.column("col")
    computed, hh = {}, None
    for stage, cam in cameras.items():
        g = locate(pose, cam, row, col, h, outside="extrapolate")  # recorded pixels (T4-3 is off the sensor)
        computed[stage] = frame.from_ecef(g.ecef)
        hh = g.h if hh is None else np.where(np.isfinite(hh), hh, g.h)
    tlat = np.deg2rad(records.column(f"{truth_prefix}_lat_deg"))
    tlon = np.deg2rad(records.column(f"{truth_prefix}_lon_deg"))
    truth = frame.from_geodetic(tlat, tlon, h if hh is None else np.where(np.isfinite(hh), hh, h))
    return ErrorGeometry(truth, computed, records.labels())


class CalibrationLayer:
    """Error-vector nodes in a viser scene with a before/after stage and an exaggeration.

    Parameters
    ----------
    scene : viser.SceneApi
        ``server.scene`` (or a session's ``scene``).
    geometry : ErrorGeometry
    name : str
        Parent node name.
    exaggeration : float
        Arrow scale (> 0; default 1, true length); the errors are ~50 m over a ~10 km scene, so a
        viewer may enlarge them: the label on the drawing (``name/truth/label``) gives the factor.
    stage : {"before", "after", "both"}
    world_scale : float
        Scene units per metre (1: metres; ``geoloc_viz.scene_geoloc.WORLD_SCALE`` = 1e-3
        in the ``geoloc view`` app, whose world unit is the km).
    """

    def __init__(
        self,
        scene,
        geometry: ErrorGeometry,
        name: str = "/calibration",
        exaggeration: float = 1.0,
        stage: str = "both",
        thickness: float = 3.0,
        world_scale: float = 1.0,
    ):
        self.scene = scene
        self.geometry = geometry
        self.world_scale = float(world_scale)
        self.name = name.rstrip("/")
        self.thickness = thickness
        self.exaggeration = self._check_exaggeration(exaggeration)
        self.stage = self._check_stage(stage)
        self.vertical = 1.0
        self.handles: dict[str, LineSegmentsHandle] = {}
        self.truth_handle = scene.add_point_cloud(
            f"{self.name}/truth",
            (geometry.truth * self.world_scale).astype(np.float32),
            COLORS["truth"],
            point_size=60.0 * self.world_scale,
            point_shape="circle",
            precision="float32",
        )
        # an exaggerated drawing says its scale beside the first record's truth (a child of the truth
        # points: it goes with them); at true length it is hidden, as it would sit on a surveyed
        # point the single-point view measures from, and the folder's name says what the vectors are
        first = geometry.truth[0] if len(geometry.truth) else np.zeros(3)
        self.shown = True
        self.label_handle = scene.add_label(
            f"{self.name}/truth/label",
            self.label_text(),
            position=tuple(float(x) for x in first * self.world_scale),
            anchor="top-left",
            visible=self.exaggeration != 1.0,
        )
        self._draw()

    def label_text(self) -> str:
        """The label on the drawing: what it shows and at what scale ("true length" or "drawn x20")."""
        how = "true length" if self.exaggeration == 1.0 else f"drawn x{self.exaggeration:g}"
        return f"error vectors of all records ({self.stage}), {how}"

    @staticmethod
    def _check_exaggeration(x) -> float:
        x = float(x)
        if not (np.isfinite(x) and x > 0):
            raise ValueError(f"exaggeration = {x}: must be a finite number > 0")
        return x

    def _check_stage(self, stage: str) -> str:
        if stage not in STAGES:
            raise ValueError(f"stage = {stage!r}: must be one of {STAGES}")
        if stage != "both" and stage not in self.geometry.computed:
            raise ValueError(f"stage = {stage!r}: no camera given for it (have {sorted(self.geometry.computed)})")
        return stage

    def _draw(self) -> None:
        lab = getattr(self, "label_handle", None)
        if lab is not None and lab.text != self.label_text():
            lab.text = self.label_text()
        if lab is not None and lab.visible != (self.shown and self.exaggeration != 1.0):
            lab.visible = self.shown and self.exaggeration != 1.0
        for stage in self.geometry.computed:
            seg = self.geometry.segments(stage, self.exaggeration) * self.world_scale
            visible = self.stage in (stage, "both")
            if stage in self.handles:
                # viser casts to float32 anyway; its property says so
                self.handles[stage].points = seg.astype(np.float32)
                self.handles[stage].visible = visible
            else:
                self.handles[stage] = self.scene.add_line_segments(
                    f"{self.name}/{stage}",
                    seg,
                    COLORS.get(stage, (200, 200, 0)),
                    thickness=self.thickness,
                    thickness_units="screen",
                    visible=visible,
                )

    def set_exaggeration(self, x: float) -> None:
        """Rescale every vector (the truth end stays)."""
        self.exaggeration = self._check_exaggeration(x)
        self._draw()

    def set_vertical_exaggeration(self, v: float) -> None:
        """Scale the layer's U axis like the scene's terrain (node scale (1, 1, v) about the ENU origin)."""
        v = float(v)
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"vertical exaggeration = {v}: must be a finite number > 0")
        self.vertical = v
        for h in (*self.handles.values(), self.truth_handle):
            h.scale = (1.0, 1.0, v)

    def set_stage(self, stage: str) -> None:
        """Show ``"before"``, ``"after"`` or ``"both"``."""
        self.stage = self._check_stage(stage)
        self._draw()

    def set_visible(self, visible: bool) -> None:
        self.shown = bool(visible)
        self.truth_handle.visible = bool(visible)
        self.label_handle.visible = bool(visible) and self.exaggeration != 1.0
        for stage, h in self.handles.items():
            h.visible = bool(visible) and self.stage in (stage, "both")

    def add_gui(self, gui, folder: str = "Calibration: error vectors"):
        """GUI folder with a before/after/both dropdown and an exaggeration slider.

        Returns the (dropdown, slider) handles.
        """
        with gui.add_folder(folder):
            dd = gui.add_dropdown("show", list(STAGES), initial_value=self.stage)
            sl = gui.add_slider("exaggeration", 1.0, 200.0, 1.0, self.exaggeration)

        @dd.on_update
        def _(_event) -> None:
            self.set_stage(dd.value)

        @sl.on_update
        def _(_event) -> None:
            self.set_exaggeration(sl.value)

        return dd, sl


def add_error_vectors(
    scene, records: Records, frame: EnuFrame, heights, camera_before, camera_after=None, **kw
) -> CalibrationLayer:
    """Add the error vectors of all records (before and, if given, after calibration) to a scene.

    Parameters
    ----------
    scene : viser.SceneApi
    records : Records
    frame : EnuFrame
        The scene's local ENU origin.
    heights : array_like
        Target height per record [m].
    camera_before, camera_after : sensor
        Nominal and calibrated sensors (or camera files' ``Camera``).
    **kw
        Passed to :class:`CalibrationLayer` (``exaggeration``, ``stage``, ``name``).
    """
    cams = {"before": camera_before}
    if camera_after is not None:
        cams["after"] = camera_after
    return CalibrationLayer(scene, error_geometry(records, frame, heights, cams), **kw)


# --------------------------------------------------------------------------- the geoloc view app
def records_from_scenario(scn) -> Records:
    """A :class:`geoloc.io.records.Records` from a viewer scenario's ``(RecordInfo, Inputs)`` list.

    The flight (``table``) is the label's part before ``-`` (``T3-1`` -> ``T3``).
    """
    header = [
        "table",
        "point",
        "row",
        "col",
        "ac_lat_deg",
        "ac_lon_deg",
        "ac_h_m",
        "heading_deg",
        "pitch_deg",
        "roll_deg",
        "gimbal_roll_deg",
        "gimbal_pitch_deg",
        "paper_height_m",
        "truth_lat_deg",
        "truth_lon_deg",
    ]
    rows = []
    for info, inp in scn.records:
        table, _, point = info.label.partition("-")
        vals = [
            inp.row,
            inp.col,
            inp.lat_deg,
            inp.lon_deg,
            inp.h_m,
            inp.heading_deg,
            inp.pitch_deg,
            inp.roll_deg,
            inp.gimbal_roll_deg,
            inp.gimbal_pitch_deg,
            info.paper_height_m,
            info.truth_lat_deg,
            info.truth_lon_deg,
        ]
        rows.append(
            dict(zip(header, [table, point or table] + ["" if not np.isfinite(v) else repr(float(v)) for v in vals]))
        )
    return Records(getattr(scn, "source", "scenario"), header, rows, np.arange(2, len(rows) + 2), [])


#: What the app fits: the mounting rotation (the [Q17] installation error, docs/calibration.md).
MOUNT_NAMES = ("mount_x", "mount_y", "mount_z")

#: Fitted cameras by (records list, sensor) of a scenario: every tab of a viewer shares the
#: records and the sensor, so the fit runs once, not once per tab (0.3 s each).
_FIT_CACHE: "collections.OrderedDict" = collections.OrderedDict()
_FIT_LOCK = threading.Lock()


class AppCalibration:
    """The calibration layer of a ``geoloc view`` app: fit once, redraw on a new ENU origin.

    The "after" sensor is one mounting rotation (``mount_x``, ``mount_y``, ``mount_z``) fitted
    to all records with a surveyed truth and a ``paper_height_m``
    (:func:`geoloc.analysis.sensor_fit.fit_sensor_groups`, joint fit).
    """

    def __init__(self, app, exaggeration: float = 1.0, stage: str = "both", world_scale=None, name=None):
        from geoloc.analysis.sensor_fit import fit_sensor_groups
        from geoloc.surfaces.height import PerRecordHeightSurface

        if world_scale is None or name is None:
            try:  # the app's world unit (km) and scene root
                from geoloc_viz.scene_geoloc import ROOT, WORLD_SCALE
            except ImportError:
                ROOT, WORLD_SCALE = "", 1.0
            world_scale = WORLD_SCALE if world_scale is None else world_scale
            name = f"{ROOT}/calibration" if name is None else name
        self.world_scale, self.name = float(world_scale), name
        self.app = app
        self.message = ""
        self.layer: CalibrationLayer | None = None
        key = (id(app.scn.records), id(app.scn.camera))
        with _FIT_LOCK:
            hit = _FIT_CACHE.get(key)
        if hit is not None and hit[0] is app.scn.records and hit[1] is app.scn.camera:
            # the same records and sensor as another tab's session: the same fit
            self.records, self.cameras = hit[2], dict(hit[3])
        else:
            self.records = records_from_scenario(app.scn)
            self.cameras = {"before": app.scn.camera}
            heights = self.records.column("paper_height_m")
            ok = (
                np.isfinite(heights)
                & np.isfinite(self.records.column("truth_lat_deg"))
                & np.isfinite(self.records.column("truth_lon_deg"))
            )
            if ok.sum() >= 2 and ok.all():
                _, fitted = fit_sensor_groups(
                    self.records,
                    app.scn.camera,
                    MOUNT_NAMES,
                    PerRecordHeightSurface(heights),
                    group_column="table",
                    joint=True,
                )
                self.cameras["after"] = fitted["joint"]
            with _FIT_LOCK:
                _FIT_CACHE[key] = (app.scn.records, app.scn.camera, self.records, dict(self.cameras))
                while len(_FIT_CACHE) > 4:
                    _FIT_CACHE.popitem(last=False)
        self.heights = self.records.column("paper_height_m")
        ok = (
            np.isfinite(self.heights)
            & np.isfinite(self.records.column("truth_lat_deg"))
            & np.isfinite(self.records.column("truth_lon_deg"))
        )
        if "after" not in self.cameras:
            # in the words of the input: a surveyed target is what the records lack
            self.message = (
                "no mounting calibration: it needs a surveyed target (latitude, longitude and height) "
                f"on every record, and {int(ok.sum())} of {len(ok)} records have one"
            )
        self.exaggeration, self.stage, self.visible, self.vertical = exaggeration, stage, True, 1.0
        if ok.all():
            self.rebuild()

    def rebuild(self) -> None:
        """(Re)draw in the app's current ENU frame (call after the origin moves)."""
        if self.layer is not None:
            self.exaggeration, self.stage = self.layer.exaggeration, self.layer.stage
            for h in (*self.layer.handles.values(), self.layer.truth_handle):
                h.remove()
        if "after" not in self.cameras and self.stage != "before":
            self.stage = "before"
        geom = error_geometry(self.records, self.app.scn.enu, self.heights, self.cameras)
        self.layer = CalibrationLayer(
            _scene_of(self.app),
            geom,
            name=self.name,
            exaggeration=self.exaggeration,
            stage=self.stage,
            world_scale=self.world_scale,
        )
        self.layer.set_visible(self.visible)
        self.layer.set_vertical_exaggeration(self.vertical)

    def add_gui(self, gui, folder: str = "Calibration: error vectors of all records"):
        """Folder with a show checkbox, a before/after/both dropdown and an exaggeration slider
        (1: true length; the label on the drawing says the factor). Records without a surveyed
        truth have no error vectors: the folder is not offered."""
        if self.layer is None:
            self.cb_show = self.dd_stage = self.sl_exag = None
            return
        with gui.add_folder(folder, expand_by_default=False):
            self.cb_show = cb_show = gui.add_checkbox("show", True)
            stages = list(STAGES) if "after" in self.cameras else ["before"]
            self.dd_stage = dd_stage = gui.add_dropdown(
                "before / after calibration", stages, initial_value=self.stage if self.stage in stages else stages[0]
            )
            self.sl_exag = sl_exag = gui.add_slider(
                "error vectors drawn x",
                1.0,
                200.0,
                1.0,
                self.exaggeration,
                hint="Draw every record's error vector this many times its length (1: true length); "
                "the label on the drawing says the factor",
            )
            if self.message:
                gui.add_markdown(self.message)

        # the callbacks close over the handles themselves, not the attributes (None without a layer)
        @cb_show.on_update
        def _(_e) -> None:
            self.visible = bool(cb_show.value)
            if self.layer is not None:
                self.layer.set_visible(self.visible)

        @dd_stage.on_update
        def _(_e) -> None:
            if self.layer is not None:
                self.layer.set_stage(str(dd_stage.value))
                self.layer.set_visible(self.visible)

        @sl_exag.on_update
        def _(_e) -> None:
            if self.layer is not None:
                self.layer.set_exaggeration(float(sl_exag.value))
                self.layer.set_visible(self.visible)


def _scene_of(app):
    """The scene a session draws on (``session.scene``; an older app object: its server's)."""
    scene = getattr(app, "scene", None)
    return scene if scene is not None else app.server.scene


def _gui_of(app):
    gui = getattr(app, "gui", None)
    return gui if gui is not None else app.server.gui


def attach(app) -> AppCalibration:
    """Add the calibration layer and its GUI folder to a viewer session
    (``geoloc_viz.app.GeolocSession``: its ``scene`` and ``gui``; interface in ``geoloc_viz.app``).

    Follows the session's vertical-exaggeration slider (``app.sl_vexag``) when it has one,
    and redraws in the new ENU frame when the session loads another record (``on_record``).
    """
    cal = AppCalibration(app)
    cal.add_gui(_gui_of(app))
    slider = getattr(app, "sl_vexag", None)
    if slider is not None:

        def follow(_e=None) -> None:
            cal.vertical = float(slider.value)
            if cal.layer is not None:
                cal.layer.set_vertical_exaggeration(cal.vertical)

        slider.on_update(follow)
        follow()
    if hasattr(app, "on_record"):
        # the ENU origin moved with the record: redraw what was drawn (records without truth, as a
        # KLV flight's, have no error vectors to draw)
        app.on_record(lambda _idx: cal.rebuild() if cal.layer is not None else None)
    return cal
