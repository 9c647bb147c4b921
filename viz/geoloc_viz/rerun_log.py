"""Write a rerun recording (``.rrd``) of a flight replay or a simulated scan.

The numbers come from :mod:`geoloc_viz.rerun_model` (the core, in the scene's local
ENU frame); this module only lays them out as rerun entities, on the
timelines of the steps (``time`` in seconds and ``frame`` for a simulated
flight, ``record`` for flight-test records), and adds a default blueprint.

With several flights (records grouped by ``table``), every ``world/...``, ``map/...``
and ``plot/...`` entity below is per flight (``world/T3/ned``, ``map/T4/track``), each
in its own flight's scene frame, and so is every time series (``series/T3/error/north_m``:
no series has rows of two flights, so no plot line joins the last record of one flight
to the first of the next; each view of the blueprint shows every flight, one hue per
flight, :func:`series_styles`); ``log/`` stays shared.

Entities (all positions in the scene's ENU frame, metres):

==========================================  =============================================
``world``                                   scene root, ENU, Z up (``ViewCoordinates``)
``world/ned``                               Transform3D T_enu_ned: aircraft position, NED axes
``world/ned/body``                          Transform3D T_ned_body [Q17 eq. 6]
``world/ned/body/aircraft``                 the bundled aircraft mesh, scaled for display
``world/ned/body/gimbal_base``              Transform3D T_body_gimbal_base: mount and lever arm
``world/ned/body/gimbal_base/<joints>``     Transform3D per gimbal joint (``gimbal_outer``,
                                            ``gimbal_inner`` for [Q17] eq. 7; the sensor's own)
``.../cam``                                 Transform3D to the optical frame and a Pinhole
``world/los``                               line of sight, aircraft -> located target
``world/target``, ``world/truth``,          located, reference and published positions
``world/published``
``world/track``, ``world/footprint``        static: aircraft track and all located targets
``world/corners``, ``map/corners``          each step's image corners (a closed ring) on the
                                            surface it was located on (KLV replays)
``world/current``                           Transform3D at the current hit (the 3D eye tracks it)
``plot/*``                                  offline 2D plot, (east, -north) metres: targets,
                                            references, error arrows, outliers, current step
``world/dem``                               static DEM mesh (when a DEM is used)
``world/iterations``                        H_n on the line of sight and the DEM below it
``map/*``                                   the same points as GeoPoints (map view)
``series/attitude/*_deg``                   heading, pitch, roll
``series/gimbal/<joint>_deg``               the sensor's joint angles under its own names
                                            (``gimbal_roll``, ``gimbal_pitch`` of [Q17];
                                            ``azimuth``, ``elevation``, ``sensor_roll`` of MISB)
``series/range/slant_range_m``              optical centre to located target
``series/height/target_h_m``                ellipsoidal height of the located target
``series/error/*_m``                        horizontal error against truth / published, and
                                            components north, east, up, along, across
``series/outlier/flag``                     robust outlier flags (0 / 1)
``series/calibration/*_m``                  error to truth before / after calibration (the
                                            mounting fit of a camera file, or the sensor fit)
``series/ellipsoid_model/*_m``              the ellipsoid model's error (scan over a DEM)
``series/cep/*_m``                          per-step Monte Carlo CEP (optional)
``series/dem/evaluations``                  DEM evaluations of each ray
``convergence/H_minus_h_m``                 BarChart of H_n - h_n over the iterations
``log/record``, ``log/outliers``            TextLog: each step's label; one note per outlier
``log/status``                              TextLog of steps without a ground point
==========================================  =============================================

Rotations go in as 3x3 matrices (``Transform3D.mat3x3``), exactly the core's
hop matrices; rerun stores them and positions as float32.
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from geoloc.assets import ASSETS
from geoloc.frames.enu import EnuFrame
from geoloc.status import Status, describe
from geoloc.userfiles import atomic_path
from geoloc_viz.rerun_model import LogSteps
from geoloc_viz.rerun_style import COLORS, series_color

#: Axis length of each drawn frame [m] (distinct, so coinciding origins stay readable).
AXIS_LENGTH_M = {
    "ned": 4000.0,
    "body": 3000.0,
    "gimbal_base": 2600.0,
    "gimbal_outer": 2200.0,
    "gimbal_inner": 1800.0,
    "cam": 1500.0,
}
#: Sizes in the 3D scene, in UI points: the eye follows the current hit from close by, where
#: target, truth and published position are tens of metres apart, and also shows a whole
#: flight from ~20 km; radii in metres (once 500 m) filled the close view with one sphere.
SCENE_RADIUS_PT = {
    "track": rr.Radius.ui_points(2.0),
    "footprint": rr.Radius.ui_points(2.5),
    "los": rr.Radius.ui_points(1.5),
    "target": rr.Radius.ui_points(6.0),
    "reference": rr.Radius.ui_points(5.0),
}
#: Sizes in the 2D plot, in UI points (rr.Radius.ui_points): the targets of a flight spread over
#: kilometres while their errors are tens of metres, so sizes in metres are either invisible or
#: hide the arrows; UI points keep them readable at any zoom.
PLOT_RADIUS_PT = {
    "point": rr.Radius.ui_points(3.0),
    "outlier": rr.Radius.ui_points(7.0),
    "arrow": rr.Radius.ui_points(1.0),
    "current": rr.Radius.ui_points(6.0),
}
#: Axis length of the frame at the current hit [m]. The 3D eye tracks that entity and, once it
#: settles, frames its bounds: 300 m axes gave a close-up of nothing but the axes; ~1.5 km keeps
#: the hit, its truth and the neighbouring targets in view.
CURRENT_AXIS_M = 1500.0
#: Distance of the pinhole's image plane in the 3D view [m].
IMAGE_PLANE_M = 3000.0


#: Colours (RGBA).
def _index(steps: LogSteps, select=None) -> list:
    cols = []
    for name, (kind, values) in steps.timelines.items():
        v = np.asarray(values)
        if select is not None:
            v = v[select]
        if kind == "duration":
            cols.append(rr.TimeColumn(name, duration=v.astype(float)))
        else:
            cols.append(rr.TimeColumn(name, sequence=v.astype(np.int64)))
    return cols


def main_timeline(steps: LogSteps) -> str:
    """The timeline the viewer opens on: ``time`` for flights, ``record`` for records."""
    return "time" if "time" in steps.timelines else next(iter(steps.timelines))


#: Error component series (``series/error/<name>``) drawn together in one view.
COMPONENT_SERIES = ("north_m", "east_m", "up_m", "along_m", "across_m")


def series_values(steps: LogSteps) -> dict:
    """Every scalar time series, ``category/name`` (e.g. ``attitude/heading_deg``) -> (n,) values."""
    p = steps.pose
    d = np.rad2deg
    series = {
        "attitude/heading_deg": d(p.heading),
        "attitude/pitch_deg": d(p.pitch),
        "attitude/roll_deg": d(p.roll),
        # the sensor's own joints, by its names (azimuth, elevation, sensor_roll of a MISB turret;
        # gimbal_roll, gimbal_pitch of the [Q17] gimbal): not the [Q17] fields of every pose
        **{f"gimbal/{name}_deg": d(p.angle(name)) for name in steps.camera.angle_names},
        "range/slant_range_m": steps.ground.slant_range,
        "height/target_h_m": steps.ground.h,
    }
    if steps.truth is not None:
        series["error/to_truth_m"] = steps.truth["error_m"]
    if steps.published is not None:
        series["error/to_published_m"] = steps.published["error_m"]
    if steps.components is not None:
        series["error/horizontal_m"] = steps.components["horizontal_m"]
        for c in COMPONENT_SERIES:
            series[f"error/{c}"] = steps.components[c]
        if steps.outlier is not None:
            series["outlier/flag"] = steps.outlier.astype(float)
    if steps.calibration is not None:
        for c in ("before_m", "after_m", "after_along_m", "after_across_m"):
            series[f"calibration/{c}"] = steps.calibration[c]
    for k, v in steps.extra_series.items():
        series[k.removeprefix("series/")] = v
    if steps.terrain is not None and steps.terrain.method != "ellipsoid":
        series["dem/evaluations"] = steps.terrain.dem_evaluations.astype(float)
    n = len(steps)
    out = {}
    for k, v in series.items():
        v = np.broadcast_to(np.asarray(v, float), (n,))
        if np.any(np.isfinite(v)):  # a series without any value is not logged
            out[k] = v
    return out


def series_views(steps: LogSteps, present=None) -> list:
    """The time-series views: ``(title, category, [names])``, only those with a logged series.

    Heading has a view of its own (its tens of degrees would flatten pitch and roll).
    """
    present = series_values(steps) if present is None else present
    spec = [
        ("Heading [deg]", "attitude", ["heading_deg"]),
        ("Pitch and roll [deg]", "attitude", ["pitch_deg", "roll_deg"]),
        ("Gimbal angles [deg]", "gimbal", None),
        ("Slant range [m]", "range", None),
        ("Target height [m]", "height", None),
        ("Horizontal error [m]", "error", ["to_truth_m", "to_published_m", "horizontal_m"]),
        (f"Error components to {steps.reference} [m]", "error", list(COMPONENT_SERIES)),
        ("Outlier flags (1 = outlier)", "outlier", None),
        ("Before / after calibration: error to truth [m]", "calibration", None),
        ("KLV corner residual [m], outlier", "klv", None),
        ("Ellipsoid model: horizontal error [m]", "ellipsoid_model", None),
        ("Monte Carlo CEP per step [m]", "cep", None),
        ("DEM evaluations per ray", "dem", None),
    ]
    out = []
    for title, cat, names in spec:
        have = [k.split("/", 1)[1] for k in present if k.split("/", 1)[0] == cat]
        names = [x for x in (have if names is None else names) if x in have]
        if names:
            out.append((title, cat, names))
    return out


def series_styles(steps: LogSteps, present=None) -> dict:
    """Entity -> (colour, legend name) of every series of a recording with several flights.

    One hue per flight (:func:`geoloc_viz.rerun_style.series_color`), shaded per quantity
    within a view; the legend names the flight. Empty for one flight (rerun's defaults).
    """
    if not steps.multi:
        return {}
    out = {}
    for title, cat, names in series_views(steps, present):
        for i, g in enumerate(steps.groups):
            for k, name in enumerate(names):
                out[steps.series_path(g, f"{cat}/{name}")] = (series_color(i, k, len(names)), f"{g} {name}")
    return out


def blueprint(steps: LogSteps) -> rrb.Blueprint:
    """Default layout: per flight a 3D scene following the current hit and a 2D target / truth plot
    (tabs when there are several flights), the map, the record log; the time series on the right,
    heading apart from pitch and roll, each view showing every flight (one entity per flight)."""
    series: list[rrb.View] = []
    for title, cat, names in series_views(steps):
        if steps.multi:
            series.append(
                rrb.TimeSeriesView(
                    origin="/series",
                    name=title,
                    contents=["/" + steps.series_path(g, f"{cat}/{x}") for g in steps.groups for x in names],
                )
            )
        else:
            series.append(
                rrb.TimeSeriesView(origin=f"/series/{cat}", name=title, contents=[f"$origin/{x}" for x in names])
            )
    if steps.terrain is not None and steps.terrain.method != "ellipsoid":
        series.append(rrb.BarChartView(origin="/convergence", name="H_n - h_n per iteration [m]"))
    views3d, views2d = [], []
    for g in steps.groups:
        root = "/" + steps.root(g)
        title = f"{g}: " if steps.multi else ""
        eye_position, eye_target = default_eye(steps, g)
        views3d.append(
            rrb.Spatial3DView(
                origin=root,
                name=f"{title}scene (local ENU, m), following the current hit",
                eye_controls=rrb.archetypes.EyeControls3D(
                    position=eye_position,
                    look_target=eye_target,
                    eye_up=[0.0, 0.0, 1.0],
                    tracking_entity=f"{root}/current",
                ),
                line_grid=rrb.archetypes.LineGrid3D(visible=False),
            )
        )
        if steps.components is not None or steps.truth is not None or steps.published is not None:
            views2d.append(
                rrb.Spatial2DView(
                    origin="/" + steps.root(g, "plot"),
                    name=f"{title}targets and {steps.reference or 'reference'} (east, north m; offline)",
                )
            )
    scene = views3d[0] if len(views3d) == 1 else rrb.Tabs(*views3d)
    bottom = []
    if views2d:
        bottom.append(views2d[0] if len(views2d) == 1 else rrb.Tabs(*views2d))
    bottom.append(
        rrb.Tabs(
            rrb.TextLogView(origin="/log", name="Records and annotations"),
            rrb.MapView(origin="/map", name="Map (tiles need a network)", zoom=map_zoom(steps)),
            rrb.TextDocumentView(origin="/info", name="About"),
        )
    )
    left = rrb.Vertical(scene, rrb.Horizontal(*bottom), row_shares=[3, 2])
    return rrb.Blueprint(
        rrb.Horizontal(left, rrb.Grid(*series, grid_columns=2), column_shares=[1, 1]),
        rrb.TimePanel(timeline=main_timeline(steps), state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        collapse_panels=False,
    )


def default_eye(steps: LogSteps, group=None):
    """3D view camera: behind and to the side of the track, above it, looking at the scene's middle.

    The middle is halfway between the median aircraft position and the median target
    (of flight ``group``, default the first); the eye stands back by 0.6 times the
    scene's extent, on the side away from the line of sight and behind the aircraft,
    at 0.4 times the extent above the middle.
    """
    g = steps.groups[0] if group is None else group
    m = steps.group_of == g
    ac = steps.aircraft_enu[m]
    tgt = steps.target_enu[m]
    ok = np.all(np.isfinite(tgt), axis=-1)
    a = np.median(ac, axis=0)
    t = np.median(tgt[ok], axis=0) if np.any(ok) else a - np.array([0.0, 0.0, 10_000.0])
    mid = 0.5 * (a + t)
    pts = np.concatenate([ac, tgt[ok]])
    extent = max(float(np.max(np.linalg.norm((pts - mid)[:, :2], axis=-1))), 5_000.0)
    side = a[:2] - t[:2]
    side = side / (np.linalg.norm(side) or 1.0)
    psi = float(np.median(np.broadcast_to(steps.pose.heading, (len(steps),))[m]))
    fwd = np.array([np.sin(psi), np.cos(psi)])  # ENU (east, north) of the heading
    back = 0.8 * side - 0.6 * fwd
    back = back / (np.linalg.norm(back) or 1.0)
    pos = mid + 0.6 * extent * np.r_[back, 0.0] + np.array([0.0, 0.0, 0.4 * extent])
    return pos.tolist(), mid.tolist()


def map_zoom(steps: LogSteps) -> float:
    """Web-map zoom level that shows the aircraft and targets (tile width 360 deg / 2^zoom)."""
    lat = np.concatenate([np.rad2deg(np.broadcast_to(steps.pose.lat, (len(steps),))), steps.ground.lat_deg])
    lon = np.concatenate([np.rad2deg(np.broadcast_to(steps.pose.lon, (len(steps),))), steps.ground.lon_deg])
    ext = max(np.nanmax(lat) - np.nanmin(lat), np.nanmax(lon) - np.nanmin(lon), 0.01)
    return float(np.clip(np.log2(360.0 / ext) - 1.5, 2.0, 16.0))


def _aircraft_mesh():
    import trimesh

    m = trimesh.load(Path(ASSETS) / "meshes" / "aircraft.ply", force="mesh")
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.uint32)


def info_markdown(steps: LogSteps) -> str:
    lines = [
        f"**{steps.name}**",
        "",
        *[f"- {n}" for n in steps.notes],
        f"- camera: {steps.camera.name or 'unnamed'} (fx = {steps.camera.lens.fx:g} px)",
    ]
    for g in steps.groups:
        e = steps.enu_for(g)
        lines.append(
            f"- scene origin (ENU){' of ' + g if steps.multi else ''}: {np.rad2deg(e.lat0):.3f} N, "
            f"{np.rad2deg(e.lon0):.3f} E, {e.h0:.0f} m (ellipsoidal); X east, Y north, Z up, metres"
        )
    lines.append(f"- timelines: {', '.join(steps.timelines)}; each step's label is in the *Records* log")
    if steps.components is not None:
        lines.append(
            f"- error components: computed minus {steps.reference}, north / east / up in the "
            f"{steps.reference} point's local frame, along / across the local track (right +)"
        )
    lines += [
        "",
        f"Frames: {steps.root(steps.groups[0])}/{' / '.join(steps.chain.frames[1:])}, "
        "each a Transform3D equal to the hop of the sensor's frame graph ([Q17] eq. 4-7).",
    ]
    if steps.multi:
        lines.append(
            "Each flight has its own entity tree (world/<flight>, plot/<flight>, map/<flight>) "
            "and scene origin: they are hundreds of km apart."
        )
    return "\n".join(lines)


def log_steps(rec: rr.RecordingStream, steps: LogSteps, *, display_scale: float = 200.0) -> None:
    """Log every entity of a recording to ``rec`` (see the module docstring for the layout)."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("info", rr.TextDocument(info_markdown(steps), media_type=rr.MediaType.MARKDOWN), static=True)
    refs = {}
    for key in ("truth", "published"):
        ref = getattr(steps, key)
        if ref is not None:
            refs[key] = steps.geodetic_enu(ref["lat_deg"], ref["lon_deg"], ref["h_m"])
    labels = np.asarray(steps.labels, dtype=object)
    T = steps.hop_transforms()  # every record's, once: each flight logs its own
    mesh = _aircraft_mesh()
    ac_all, tgt_all = steps.aircraft_enu, steps.target_enu

    for g in steps.groups:
        m = steps.group_of == g
        if steps.multi:
            rec.log(steps.root(g), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        _log_frames(rec, steps, g, m, T, mesh, display_scale)
        _log_points(rec, steps, g, m, ac_all, tgt_all, refs, labels)
        if steps.corners is not None:
            _log_corners(rec, steps, g, m)
        # ---------------------------------------------------- 2D plot, offline
        _plot2d(rec, steps, g, m, refs, labels)
        _log_map(rec, steps, g, m, refs)

    _log_series(rec, steps)
    _log_texts(rec, steps, labels)
    if steps.terrain is not None:
        from geoloc_viz.rerun_terrain import log_terrain

        log_terrain(rec, steps, _index)


def _log_frames(
    rec: rr.RecordingStream, steps: LogSteps, g: str, m: np.ndarray, T: dict, mesh: tuple, display_scale: float
) -> None:
    """Flight ``g``'s (records ``m``) frames, each hop's transform per record (``T``: the
    recording's :meth:`LogSteps.hop_transforms`), its camera (images or a pinhole) and the
    aircraft's mesh (vertices, triangles) scaled by ``display_scale``."""
    n = len(steps)
    paths = steps.entity_paths()
    lens = steps.camera.lens
    v_mesh, f_mesh = mesh
    idx = _index(steps, m)
    root = steps.root(g)

    for name, path in paths.items():
        path = root + path[len("world") :]
        Tn = np.broadcast_to(T[name], (n, 4, 4))[m]
        cols = {"mat3x3": Tn[:, :3, :3]}
        if name == "ned" or np.any(Tn[:, :3, 3]):
            cols["translation"] = Tn[:, :3, 3]
        rec.send_columns(path, indexes=idx, columns=rr.Transform3D.columns(**cols))
        rec.log(path, rr.TransformAxes3D(axis_length=AXIS_LENGTH_M.get(name, 2000.0)), static=True)
    cam = root + paths["cam"][len("world") :]
    if steps.images is not None and np.any(np.asarray(steps.image_index)[m] >= 0):
        log_images(rec, steps, cam, m)
    else:
        rec.log(
            cam,
            rr.Pinhole(
                focal_length=[float(lens.fx), float(lens.fy)],
                width=int(lens.width),
                height=int(lens.height),
                # the lens's 0-based pixel centres (OpenCV's) -> rerun's continuous (u, v): +0.5
                principal_point=[lens.cx + 0.5, lens.cy + 0.5],
                # the optical frame of the lens: X right, Y down, Z the line of sight
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=IMAGE_PLANE_M,
            ),
            static=True,
        )
    body = root + paths["body"][len("world") :]
    rec.log(f"{body}/aircraft", rr.Transform3D(scale=display_scale), static=True)
    rec.log(
        f"{body}/aircraft",
        rr.Mesh3D(vertex_positions=v_mesh, triangle_indices=f_mesh, albedo_factor=COLORS["aircraft"]),
        static=True,
    )


def _log_points(
    rec: rr.RecordingStream,
    steps: LogSteps,
    g: str,
    m: np.ndarray,
    ac_all: np.ndarray,
    tgt_all: np.ndarray,
    refs: dict,
    labels: np.ndarray,
) -> None:
    """Flight ``g``'s (records ``m``) track, footprint, lines of sight, targets, references ``refs``
    (their ENU points by name) and the frame the 3D view's eye tracks; ``ac_all``, ``tgt_all``:
    every record's aircraft and target in ENU."""
    n = len(steps)
    f32 = np.float32
    idx = _index(steps, m)
    root = steps.root(g)

    ac, tgt = ac_all[m], tgt_all[m]
    rec.log(
        f"{root}/track",
        rr.LineStrips3D([ac.astype(f32)], colors=COLORS["track"], radii=SCENE_RADIUS_PT["track"]),
        static=True,
    )
    ok = np.all(np.isfinite(tgt), axis=-1)
    rec.log(
        f"{root}/footprint",
        rr.Points3D(tgt[ok].astype(f32), colors=COLORS["footprint"], radii=SCENE_RADIUS_PT["footprint"]),
        static=True,
    )
    # The line of sight ends at the target, or runs 200 km into the sky where there is none.
    d_enu = steps.enu_for(g).vector_from_ecef(np.broadcast_to(steps.los.direction_ecef, (n, 3))[m])
    end = np.where(ok[:, None], tgt, ac + 2.0e5 * d_enu)
    rec.send_columns(
        f"{root}/los",
        indexes=idx,
        columns=rr.LineStrips3D.columns(strips=list(np.stack([ac, end], axis=1).astype(f32))),
    )
    rec.log(f"{root}/los", rr.LineStrips3D.from_fields(colors=COLORS["los"], radii=SCENE_RADIUS_PT["los"]), static=True)
    _points(rec, steps, f"{root}/target", tgt_all, COLORS["target"], SCENE_RADIUS_PT["target"], m, labels)
    for key, p in refs.items():
        _points(rec, steps, f"{root}/{key}", p, COLORS[key], SCENE_RADIUS_PT["reference"], m)
    # the entity the 3D view's eye tracks: a frame at the current hit (the last hit where a step has none)
    cur = m & np.all(np.isfinite(tgt_all), axis=-1)
    if np.any(cur):
        rec.send_columns(
            f"{root}/current", indexes=_index(steps, cur), columns=rr.Transform3D.columns(translation=tgt_all[cur])
        )
        rec.log(f"{root}/current", rr.TransformAxes3D(axis_length=CURRENT_AXIS_M), static=True)


def _log_map(rec: rr.RecordingStream, steps: LogSteps, g: str, m: np.ndarray, refs: dict) -> None:
    """Flight ``g``'s (records ``m``) map: the track, the aircraft per record, the targets and the
    references of ``refs`` where they have a position."""
    n = len(steps)
    idx = _index(steps, m)

    mroot = steps.root(g, "map")
    lat_ac = np.broadcast_to(np.rad2deg(steps.pose.lat), (n,))[m]
    lon_ac = np.broadcast_to(np.rad2deg(steps.pose.lon), (n,))[m]
    rec.log(
        f"{mroot}/track",
        rr.GeoLineStrings(lat_lon=[np.c_[lat_ac, lon_ac]], colors=COLORS["track"], radii=rr.Radius.ui_points(2.0)),
        static=True,
    )
    rec.send_columns(f"{mroot}/aircraft", indexes=idx, columns=rr.GeoPoints.columns(positions=np.c_[lat_ac, lon_ac]))
    rec.log(
        f"{mroot}/aircraft",
        rr.GeoPoints.from_fields(colors=COLORS["aircraft"], radii=rr.Radius.ui_points(6.0)),
        static=True,
    )
    geo = {"target": (steps.ground.lat_deg, steps.ground.lon_deg)}
    for key in refs:
        ref = getattr(steps, key)
        geo[key] = (np.asarray(ref["lat_deg"], float), np.asarray(ref["lon_deg"], float))
    for key, (la, lo) in geo.items():
        good = m & np.isfinite(la) & np.isfinite(lo)
        if np.any(good):
            rec.send_columns(
                f"{mroot}/{key}",
                indexes=_index(steps, good),
                columns=rr.GeoPoints.columns(positions=np.c_[la[good], lo[good]]),
            )
            rec.log(
                f"{mroot}/{key}",
                rr.GeoPoints.from_fields(colors=COLORS[key], radii=rr.Radius.ui_points(5.0)),
                static=True,
            )


def _log_series(rec: rr.RecordingStream, steps: LogSteps) -> None:
    """The plotted series: one entity per flight and series, a missing value a gap."""
    grp = steps.group_of

    # one entity per flight and series (series/<flight>/...): no plot line joins two flights
    present = series_values(steps)
    styles = series_styles(steps, present)
    for rel, values in present.items():
        for g in steps.groups:
            path = steps.series_path(g, rel)
            good = np.isfinite(values) & (grp == g)  # a missing value is a gap, not a zero
            if not np.any(good):
                continue
            rec.send_columns(path, indexes=_index(steps, good), columns=rr.Scalars.columns(scalars=values[good]))
            if path in styles:
                color, name = styles[path]
                rec.log(path, rr.SeriesLines(colors=[color], names=[name]), static=True)


def _log_texts(rec: rr.RecordingStream, steps: LogSteps, labels: np.ndarray) -> None:
    """The text logs: each record's label (outliers flagged), the outliers' notes, the statuses other than OK."""
    n = len(steps)
    grp = steps.group_of

    flag = steps.outlier if steps.outlier is not None else np.zeros(n, bool)
    text = [
        f"{labels[k]}" + (f" ({grp[k]})" if steps.multi else "") + (" - outlier" if flag[k] else "") for k in range(n)
    ]
    rec.send_columns(
        "log/record",
        indexes=_index(steps),
        columns=rr.TextLog.columns(text=text, level=["WARN" if f else "INFO" for f in flag]),
    )
    if np.any(flag) and steps.components is not None:  # the flags are of the horizontal error
        hor = steps.components["horizontal_m"]
        notes = []
        for k in np.flatnonzero(flag):
            mk = (grp == grp[k]) & np.isfinite(hor)
            notes.append(
                f"{labels[k]}: outlier, horizontal error to {steps.reference} {hor[k]:.2f} m, "
                f"flight median {np.median(hor[mk]):.2f} m (median / MAD rule)"
            )
        rec.send_columns(
            "log/outliers",
            indexes=_index(steps, flag),
            columns=rr.TextLog.columns(text=notes, level=["WARN"] * len(notes)),
        )

    # ------------------------------------------------------ status messages
    st = np.asarray(steps.ground.status)
    bad = st != Status.OK
    if np.any(bad):
        text = [f"{steps.labels[k]}: {describe(st[k])}" for k in np.flatnonzero(bad)]
        rec.send_columns(
            "log/status", indexes=_index(steps, bad), columns=rr.TextLog.columns(text=text, level=["WARN"] * len(text))
        )


#: JPEG quality of the frames logged with their pinhole (a 640 x 360 frame: ~30 kB).
IMAGE_QUALITY = 85


def log_images(rec: rr.RecordingStream, steps: LogSteps, cam: str, m) -> None:
    """Each step's picture at the camera entity, with its own pinhole (so the picture lies in the camera's view).

    Per step with an image: an ``EncodedImage`` (JPEG of ``steps.images.image(k)``) and a
    ``Pinhole`` sized to that image, from the step's fields of view (``lens_from_fov`` of
    ``steps.image_fov_deg``, the replay's sensor rule) or else the recording's lens scaled to the
    image; so rerun's 3D view shows the frame in the camera's frustum at ``IMAGE_PLANE_M``.
    """
    import io
    import math

    import PIL.Image

    from geoloc.io.photos import scale_lens
    from geoloc.sensors.lenses import lens_from_fov

    images = steps.images
    if images is None:
        return
    base = steps.camera.lens
    idx = np.asarray(steps.image_index)
    fov = steps.image_fov_deg
    cache = {}
    for k in np.flatnonzero(m & (idx >= 0)):
        a = np.asarray(images.image(int(idx[k])))
        rows, cols = a.shape[:2]
        hv = tuple(fov[k]) if fov is not None and np.all(np.isfinite(fov[k])) else None
        key = (hv, rows, cols)
        if key not in cache:
            cache[key] = (
                lens_from_fov(math.radians(hv[0]), math.radians(hv[1]), cols, rows)
                if hv
                else scale_lens(base, cols, rows)
            )
        lens = cache[key]
        for name, (kind, values) in steps.timelines.items():
            v = values[k]
            if kind == "duration":
                rec.set_time(name, duration=float(v))
            else:
                rec.set_time(name, sequence=int(v))
        rec.log(
            cam,
            rr.Pinhole(
                focal_length=[float(lens.fx), float(lens.fy)],
                width=int(cols),
                height=int(rows),
                principal_point=[lens.cx + 0.5, lens.cy + 0.5],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=IMAGE_PLANE_M,
            ),
        )
        buf = io.BytesIO()
        PIL.Image.fromarray(np.ascontiguousarray(a[..., :3])).save(buf, format="JPEG", quality=IMAGE_QUALITY)
        rec.log(cam, rr.EncodedImage(contents=buf.getvalue(), media_type="image/jpeg"))
    rec.reset_time()


def plot_east_north(steps: LogSteps, g, pts_enu) -> np.ndarray:
    """(east, -north) of ENU points of flight ``g``: rerun's 2D view has y down, so north is up on screen."""
    p = np.asarray(pts_enu, float)
    return np.stack([p[..., 0], -p[..., 1]], axis=-1)


def _plot2d(rec, steps: LogSteps, g, m, refs, labels) -> None:
    """The offline 2D plot of flight ``g``: all targets and references (static), the error vectors
    (reference -> computed), and the current step's pair (temporal); metres of the flight's ENU frame."""
    root = steps.root(g, "plot")
    tgt = steps.target_enu[m]
    ok = np.all(np.isfinite(tgt), axis=-1)
    lab = [str(x) for x in labels[m][ok]]
    if not np.any(ok):
        return
    rec.log(
        f"{root}/targets",
        rr.Points2D(
            plot_east_north(steps, g, tgt[ok]),
            colors=COLORS["target"],
            radii=PLOT_RADIUS_PT["point"],
            labels=lab,
            show_labels=False,
        ),
        static=True,
    )
    if steps.outlier is not None and np.any(steps.outlier[m] & ok):
        o = steps.outlier[m] & ok
        rec.log(
            f"{root}/outliers",
            rr.Points2D(
                plot_east_north(steps, g, tgt[o]),
                colors=(255, 0, 255, 255),
                radii=PLOT_RADIUS_PT["outlier"],
                labels=[str(x) for x in labels[m][o]],
            ),
            static=True,
        )
    ref_key = steps.reference or next(iter(refs), None)
    for key, p in refs.items():
        pk = p[m]
        good = np.all(np.isfinite(pk), axis=-1)
        rec.log(
            f"{root}/{key}",
            rr.Points2D(plot_east_north(steps, g, pk[good]), colors=COLORS[key], radii=PLOT_RADIUS_PT["point"]),
            static=True,
        )
    if ref_key in refs:
        r = refs[ref_key][m]
        both = ok & np.all(np.isfinite(r), axis=-1)
        o2 = plot_east_north(steps, g, r[both])
        rec.log(
            f"{root}/errors",
            rr.Arrows2D(
                origins=o2,
                vectors=plot_east_north(steps, g, tgt[both]) - o2,
                colors=COLORS["los"],
                radii=PLOT_RADIUS_PT["arrow"],
            ),
            static=True,
        )
    cur = np.zeros(len(steps), bool)
    cur[np.flatnonzero(m)[ok]] = True
    rec.send_columns(
        f"{root}/current",
        indexes=_index(steps, cur),
        columns=rr.Points2D.columns(positions=plot_east_north(steps, g, steps.target_enu[cur]), labels=lab),
    )
    rec.log(
        f"{root}/current",
        rr.Points2D.from_fields(colors=(255, 255, 255, 255), radii=PLOT_RADIUS_PT["current"]),
        static=True,
    )


def _log_corners(rec, steps: LogSteps, g, m) -> None:
    """Each step's image footprint (its four corners on the surface it was located on, a closed
    ring) as ``world/corners`` (ENU, float32) and ``map/corners`` (latitude and longitude, float64)."""
    c = steps.corners
    if c is None:
        return
    lat, lon, h = (np.asarray(c[k], dtype=np.float64) for k in ("lat_deg", "lon_deg", "h_m"))
    good = m & np.all(np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h), axis=-1)
    if not np.any(good):
        return
    idx = np.flatnonzero(good)
    ring = np.r_[0, 1, 2, 3, 0]  # closed: upper left, upper right, lower right, lower left, upper left
    enu = steps.enu_for(g).from_geodetic(np.deg2rad(lat[idx]), np.deg2rad(lon[idx]), h[idx])  # (k, 4, 3)
    root, mroot = steps.root(g), steps.root(g, "map")
    rec.send_columns(
        f"{root}/corners",
        indexes=_index(steps, good),
        columns=rr.LineStrips3D.columns(strips=list(enu[:, ring].astype(np.float32))),
    )
    rec.log(
        f"{root}/corners",
        rr.LineStrips3D.from_fields(colors=COLORS["footprint"], radii=SCENE_RADIUS_PT["los"]),
        static=True,
    )
    rec.send_columns(
        f"{mroot}/corners",
        indexes=_index(steps, good),
        columns=rr.GeoLineStrings.columns(line_strings=list(np.stack([lat[idx][:, ring], lon[idx][:, ring]], axis=-1))),
    )
    rec.log(
        f"{mroot}/corners",
        rr.GeoLineStrings.from_fields(colors=COLORS["footprint"], radii=rr.Radius.ui_points(1.5)),
        static=True,
    )


def _points(rec, steps, path, pts, color, radius, mask=None, labels=None):
    good = np.all(np.isfinite(pts), axis=-1)
    if mask is not None:
        good &= mask
    if np.any(good):
        kw = {"labels": [str(x) for x in np.asarray(labels, dtype=object)[good]]} if labels is not None else {}
        rec.send_columns(
            path, indexes=_index(steps, good), columns=rr.Points3D.columns(positions=pts[good].astype(np.float32), **kw)
        )
        rec.log(path, rr.Points3D.from_fields(colors=color, radii=radius), static=True)


def recording_id(steps: LogSteps) -> str:
    """A recording id fixed by the input's name and kind (re-runs replace, not add)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"geoloc:{steps.kind}:{steps.name}"))


def write(
    steps: LogSteps,
    out,
    *,
    display_scale: float = 200.0,
    serve: bool = False,
    grpc_port: int = 9876,
    grpc_host: str = "127.0.0.1",
    spawn: bool = False,
) -> rr.RecordingStream:
    """Write ``steps`` to the ``.rrd`` file ``out`` (and optionally serve it or spawn a viewer).

    Parameters
    ----------
    steps : LogSteps
    out : path-like or None
        Output file; None for no file (only with ``serve`` or ``spawn``).
    display_scale : float
        Scale of the aircraft mesh in the 3D view (a 15 m aircraft is a speck at 20 km).
    serve : bool
        Also host a gRPC server (``rerun+http://127.0.0.1:PORT/proxy``) for viewers to
        connect to; the caller keeps the process alive (see :func:`serve_web`).
    grpc_port : int
    grpc_host : str
        Bind address of that server and of a spawned viewer (127.0.0.1 by default: this
        machine only; the SDK's and the viewer's own default is 0.0.0.0).
    spawn : bool
        Also open the native viewer (:func:`spawn_viewer`; it needs a display): on the written
        file when there is one (the file is complete and closed first), else streamed to it.

    Returns
    -------
    rerun.RecordingStream
        Flushed; disconnected unless ``serve`` is asked for.
    """
    if spawn:
        require_display()
    with contextlib.ExitStack() as stack:  # the .rrd is renamed into place once flushed and closed
        tmp = stack.enter_context(atomic_path(out)) if out is not None else None
        rec = _write(
            steps,
            tmp,
            display_scale,
            serve,
            grpc_port,
            grpc_host,
            stream_port=(grpc_port + 1 if serve else grpc_port) if spawn and out is None else None,
        )
        if not serve:
            rec.disconnect()
    if spawn and out is not None:
        spawn_viewer(grpc_host, grpc_port + 1 if serve else grpc_port, Path(out))
    return rec


def _write(steps, out, display_scale, serve, grpc_port, grpc_host, stream_port=None) -> rr.RecordingStream:
    rec = rr.RecordingStream("geoloc", recording_id=recording_id(steps))
    if out is not None and not serve:  # (--spawn with a file opens the written file afterwards)
        # a file alone: the recording is built in memory and written by Python, so that a full disk
        # or a read-only folder is an OSError naming the file (rerun's file-writer thread
        # printed its own error lines, then flush() raised "File-writer thread shut down prematurely"
        # or, in a process that had written recordings before, waited forever)
        stream = rr.binary_stream(recording=rec)
        rec.send_blueprint(blueprint(steps), make_active=False, make_default=True)
        log_steps(rec, steps, display_scale=display_scale)
        rec.flush()
        data = stream.read(flush=True) or b""
        rec.disconnect()
        with open(out, "wb") as fh:
            fh.write(data)
        return rec
    sinks: list[rr.FileSink | rr.GrpcServerSink | rr.GrpcSink] = []
    if out is not None:
        sinks.append(rr.FileSink(str(out)))
    if serve:
        sinks.append(rr.GrpcServerSink(bind_ip=grpc_host, port=grpc_port))
    if stream_port is not None:  # --spawn without a file: stream to the viewer started here
        sinks.append(rr.GrpcSink(spawn_viewer(grpc_host, stream_port)))
    if not sinks:
        raise ValueError("nothing to write to: give an output file, serve or spawn")
    rec.set_sinks(*sinks, default_blueprint=blueprint(steps))
    log_steps(rec, steps, display_scale=display_scale)
    rec.flush()
    return rec


def has_display() -> bool:
    """Whether a native window can open here: always on Windows and macOS; on Linux and the other
    Unixes only with an X11 or Wayland display (``DISPLAY`` or ``WAYLAND_DISPLAY`` set)."""
    import os

    if sys.platform.startswith(("win", "darwin")):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


#: What ``--spawn`` says on a machine without a display (before anything is computed).
NO_DISPLAY = (
    "--spawn opens rerun's native viewer window, which needs a display, and this session has "
    "none (DISPLAY and WAYLAND_DISPLAY are unset, e.g. a headless server or an SSH session "
    "without X forwarding): write the recording with --out FILE and open it where there is a "
    "display (`rerun FILE`), or use --serve for the web viewer (a browser on this machine, or "
    "through an SSH tunnel)"
)


def require_display() -> None:
    """ValueError (:data:`NO_DISPLAY`) when :func:`has_display` is false."""
    if not has_display():
        raise ValueError(NO_DISPLAY)


def spawn_viewer(host: str, port: int, path=None, timeout_s: float = 20.0) -> str:
    """Start the native viewer (the wheel's ``rerun`` binary) bound to ``host``, detached.

    ``path``: the ``.rrd`` it opens; without one it listens for a stream on ``port`` (gRPC, bound
    to ``host``: the binary's own default is 0.0.0.0) and the returned URL is where to send it.
    rerun-sdk's ``rr.spawn`` is not used: it acts on the global recording (``rr.init``), which
    these recordings never set ("Rerun is disabled - spawn() call ignored"), and it binds 0.0.0.0.

    Returns
    -------
    str
        The viewer's gRPC URL (``rerun+http://HOST:PORT/proxy``).

    Raises
    ------
    ValueError
        No display (:func:`require_display`).
    RuntimeError
        The viewer exited at once (its last lines of output quoted) or did not listen in time.
    """
    require_display()
    cmd = [rerun_executable(), "--bind", host, "--port", str(port)]
    if path is not None:
        cmd.append(str(path))
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
    )  # the viewer outlives `geoloc log`
    url = f"rerun+http://{_url_host(host)}:{port}/proxy"
    probe = "127.0.0.1" if host in ("0.0.0.0", "") else "::1" if host == "::" else host
    deadline = time.monotonic() + (SPAWN_GRACE_S if path is not None else timeout_s)
    while True:
        if proc.poll() is not None:
            if proc.returncode == 0 and path is not None:
                return url  # a viewer that handed the file to one already running
            log.seek(0)
            tail = log.read().decode(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(f"the rerun viewer exited at once (status {proc.returncode}): " + " | ".join(tail))
        if path is not None:
            if time.monotonic() > deadline:
                return url  # still running after the grace period: the window is up
            time.sleep(0.1)
            continue
        try:
            with socket.create_connection((probe, port), timeout=0.5):
                return url
        except OSError:
            if time.monotonic() > deadline:
                proc.terminate()
                raise RuntimeError(f"the rerun viewer did not listen on {host}:{port} within {timeout_s} s")
            time.sleep(0.1)


#: How long :func:`spawn_viewer` watches a viewer opened on a file for an immediate failure [s].
SPAWN_GRACE_S = 2.0


LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


def exposure_note(host: str, ports) -> str | None:
    """The warning printed when ``host`` is not a loopback address (None when it is)."""
    if host in LOOPBACK_HOSTS or host.startswith("127."):
        return None
    where = "every interface" if host in ("0.0.0.0", "::", "") else host
    return (
        f"warning: listening on {where} (ports {', '.join(str(p) for p in ports)}): anyone who "
        f"can reach this machine can read the recording (no authentication)"
    )


def _url_host(host: str) -> str:
    """The address a browser connects to for a server bound to ``host``."""
    if host in ("0.0.0.0", "::", ""):
        return socket.gethostname()
    return f"[{host}]" if ":" in host else host


def rerun_executable() -> str:
    """The ``rerun`` binary of the installed rerun-cli wheel (what ``rerun`` on PATH runs)."""
    import rerun_cli

    exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    if not exe.exists():
        raise FileNotFoundError(f"the rerun viewer binary is missing: {exe} (reinstall rerun-sdk)")
    return str(exe)


def serve_web(
    grpc_port: int = 9876, web_port: int = 9090, host: str = "127.0.0.1", timeout_s: float = 20.0
) -> tuple[str, subprocess.Popen]:
    """Host the web viewer (assets inside the rerun wheel, no network) connected to the gRPC server.

    The SDK's ``rr.serve_web_viewer`` (rerun-sdk 0.41) has no bind address and listens on
    0.0.0.0, so the viewer is served by the wheel's ``rerun`` CLI instead,
    ``rerun --serve-web --bind HOST --web-viewer-port PORT URL``, which with a URL hosts
    only the viewer's files and binds ``HOST`` alone.

    Parameters
    ----------
    grpc_port : int
        Port of the gRPC server of :func:`write` (``serve=True``) the viewer connects to.
    web_port : int
        Port of the web viewer's HTTP server.
    host : str
        Bind address of the HTTP server (127.0.0.1 by default: this machine only). Give the
        same to :func:`write` (``grpc_host``): the browser connects to both.
    timeout_s : float
        How long to wait for the viewer to listen.

    Returns
    -------
    url : str
        The URL to open in a browser.
    process : subprocess.Popen
        The viewer's process: terminate it when done.
    """
    grpc_url = f"rerun+http://{_url_host(host)}:{grpc_port}/proxy"
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        [rerun_executable(), "--serve-web", "--bind", host, "--web-viewer-port", str(web_port), grpc_url],
        stdin=subprocess.DEVNULL,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    probe = "127.0.0.1" if host in ("0.0.0.0", "") else "::1" if host == "::" else host
    deadline = time.monotonic() + timeout_s
    while True:
        if proc.poll() is not None:
            log.seek(0)
            tail = log.read().decode(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(f"the rerun web viewer did not start on {host}:{web_port}: " + " | ".join(tail))
        try:
            with socket.create_connection((probe, web_port), timeout=0.5):
                break
        except OSError:
            if time.monotonic() > deadline:
                proc.terminate()
                raise RuntimeError(f"the rerun web viewer did not listen on {host}:{web_port} within {timeout_s} s")
            time.sleep(0.1)
    log.close()
    return f"http://{_url_host(host)}:{web_port}/?url={grpc_url}", proc


class LiveRecording:
    """A rerun recording written as a live stream arrives (``geoloc log udp://...``).

    Each :meth:`add` logs a batch of received KLV results (:class:`geoloc.io.klv.Packet` /
    ``KlvError``) exactly as :func:`log_steps` logs a file's steps
    (:func:`geoloc_viz.rerun_model.steps_from_klv`), on one scene origin (the first located
    packet's, :func:`geoloc_viz.rerun_model.enu_origin`) and one clock (``time`` from the first
    packet's time stamp), with the causal outlier flags of :mod:`geoloc.workflows.live_replay`
    (the median / MAD rule over the packets received so far); the whole-flight drawings (the 3D
    track and footprint, the map's track, the 2D plot's points and error vectors) are logged
    again over the packets received (the newest ``window``). The sinks are flushed after each
    batch, so the ``.rrd`` (or a connected viewer) holds every batch logged: a session killed
    mid-flight leaves what arrived.

    Parameters
    ----------
    out : path-like or None
        The ``.rrd`` the recording streams to (None: only ``serve`` / ``spawn``).
    label : str
        The stream's name (its URL): the recording's name and id.
    camera, dem_path, dem_datum, method, eps_h_m, threshold_m
        As :func:`geoloc_viz.rerun_model.steps_from_klv`.
    display_scale, serve, grpc_port, grpc_host, spawn
        As :func:`write`.
    """

    def __init__(
        self,
        out,
        label: str,
        camera=None,
        *,
        dem_path=None,
        dem_datum: str = "egm96",
        method: str = "exact",
        eps_h_m=None,
        threshold_m=None,
        display_scale: float = 200.0,
        serve: bool = False,
        grpc_port: int = 9876,
        grpc_host: str = "127.0.0.1",
        spawn: bool = False,
        window: int = 18000,
    ):
        from collections import deque

        from geoloc.surfaces.spec import SurfaceSpec

        self.out, self.label, self.camera = out, str(label), camera
        self.kw = dict(method=method, eps_h_m=eps_h_m, threshold_m=threshold_m)
        self.dem = SurfaceSpec(dem=dem_path, dem_datum=dem_datum).raster()  # once a session
        self.display_scale = float(display_scale)
        self.serve, self.grpc_port, self.grpc_host, self.spawn = serve, int(grpc_port), str(grpc_host), spawn
        self.rec: rr.RecordingStream | None = None
        self.enu: EnuFrame | None = None
        self.t0_s: float | None = None
        self.steps_total = 0
        self.located_total = 0
        self.seq = 0  # packets received (good and bad, as the live replay numbers them)
        self.errors: list = []
        self._err: deque = deque(maxlen=int(window))  # frame-centre residuals, for the causal flags
        self._acc: deque = deque(maxlen=int(window))  # per step: (aircraft, target, reported, label, flag)
        self.timelines = ()

    def _open(self, steps) -> rr.RecordingStream:
        rec = rr.RecordingStream("geoloc", recording_id=recording_id(steps))
        sinks: list[rr.FileSink | rr.GrpcServerSink | rr.GrpcSink] = []
        if self.out is not None:
            sinks.append(rr.FileSink(str(self.out)))
        if self.serve:
            sinks.append(rr.GrpcServerSink(bind_ip=self.grpc_host, port=self.grpc_port))
        if self.spawn:
            port = self.grpc_port + 1 if self.serve else self.grpc_port
            sinks.append(rr.GrpcSink(spawn_viewer(self.grpc_host, port)))
        if not sinks:
            raise ValueError("nothing to write to: give an output file, serve or spawn")
        rec.set_sinks(*sinks, default_blueprint=blueprint(steps))
        return rec

    def add(self, results) -> int:
        """Log one batch (a list of results); returns the steps logged (0: no good packet in it)."""
        from geoloc.io.klv import KlvError, Packet
        from geoloc_viz.rerun_model import steps_from_klv
        from geoloc.workflows.klv_replay import _is_stray, outlier_mask

        results = list(results)
        self.errors += [r for r in results if isinstance(r, KlvError)]
        if not any(isinstance(r, Packet) for r in results):
            return 0
        if self.t0_s is None:
            us = [r.fields.get("precision_time_stamp_us") for r in results if isinstance(r, Packet)]
            t = np.asarray([np.nan if v is None else v / 1e6 for v in us], float)
            self.t0_s = float(np.nanmin(t)) if np.any(np.isfinite(t)) else 0.0

        def causal(err):  # the batch's residuals after those received before it (the live replay's rule)
            self._err.extend(np.asarray(err, float).tolist())
            return outlier_mask(np.array(self._err, float))[0][-len(err) :] if len(err) else np.zeros(0, bool)

        steps, _ = steps_from_klv(
            results,
            self.camera,
            dem=self.dem,
            label=self.label,
            enu=self.enu,
            t0_s=self.t0_s,
            outlier=causal,
            first_packet=self.seq,
            **self.kw,
        )
        self.seq += sum(1 for r in results if isinstance(r, Packet) or (isinstance(r, KlvError) and not _is_stray(r)))
        if self.enu is None:
            self.enu = steps.enu
        if self.rec is None:
            self.rec = self._open(steps)
        rec = self.rec
        log_steps(rec, steps, display_scale=self.display_scale)
        n = len(steps)
        ac, tgt = steps.aircraft_enu, steps.target_enu
        p = steps.published
        # steps_from_klv always gives the published position (the packets' frame centres)
        pub = steps.geodetic_enu(p["lat_deg"], p["lon_deg"], p["h_m"]) if p is not None else np.full((n, 3), np.nan)
        lat, lon = np.rad2deg(np.broadcast_to(steps.pose.lat, (n,))), np.rad2deg(np.broadcast_to(steps.pose.lon, (n,)))
        flag = steps.outlier if steps.outlier is not None else np.zeros(n, bool)
        for k in range(n):
            self._acc.append((ac[k], tgt[k], pub[k], steps.labels[k], bool(flag[k]), lat[k], lon[k]))
        self._log_whole_flight(rec)
        rec.flush()
        self.steps_total += n
        self.located_total += int((steps.ground.status == 0).sum())
        self.timelines = tuple(steps.timelines)
        return n

    def _log_whole_flight(self, rec: rr.RecordingStream) -> None:
        """The static drawings of every packet received (the window): those :func:`log_steps` drew
        for the batch alone (one flight: entity roots ``world``, ``map``, ``plot``)."""
        f32 = np.float32
        ac, tgt, pub, labels, flag, lat, lon = (np.asarray(x) for x in zip(*self._acc))
        tgt, pub = tgt.astype(float), pub.astype(float)
        flag = flag.astype(bool)
        rec.log(
            "world/track",
            rr.LineStrips3D([ac.astype(f32)], colors=COLORS["track"], radii=SCENE_RADIUS_PT["track"]),
            static=True,
        )
        ok = np.all(np.isfinite(tgt), axis=-1)
        rec.log(
            "world/footprint",
            rr.Points3D(tgt[ok].astype(f32), colors=COLORS["footprint"], radii=SCENE_RADIUS_PT["footprint"]),
            static=True,
        )
        rec.log(
            "map/track",
            rr.GeoLineStrings(lat_lon=[np.c_[lat, lon]], colors=COLORS["track"], radii=rr.Radius.ui_points(2.0)),
            static=True,
        )
        if not ok.any():
            return
        en = lambda p: np.stack([p[..., 0], -p[..., 1]], axis=-1)  # noqa: E731  (plot_east_north, one flight)
        rec.log(
            "plot/targets",
            rr.Points2D(
                en(tgt[ok]),
                colors=COLORS["target"],
                radii=PLOT_RADIUS_PT["point"],
                labels=[str(x) for x in labels[ok]],
                show_labels=False,
            ),
            static=True,
        )
        o = flag & ok
        if o.any():
            rec.log(
                "plot/outliers",
                rr.Points2D(
                    en(tgt[o]),
                    colors=(255, 0, 255, 255),
                    radii=PLOT_RADIUS_PT["outlier"],
                    labels=[str(x) for x in labels[o]],
                ),
                static=True,
            )
        good = np.all(np.isfinite(pub), axis=-1)
        rec.log(
            "plot/published",
            rr.Points2D(en(pub[good]), colors=COLORS["published"], radii=PLOT_RADIUS_PT["point"]),
            static=True,
        )
        both = ok & good
        o2 = en(pub[both])
        rec.log(
            "plot/errors",
            rr.Arrows2D(origins=o2, vectors=en(tgt[both]) - o2, colors=COLORS["los"], radii=PLOT_RADIUS_PT["arrow"]),
            static=True,
        )

    def close(self) -> None:
        """Flush and disconnect (a served or spawned viewer keeps what it received)."""
        if self.rec is not None:
            self.rec.flush()
            self.rec.disconnect()
