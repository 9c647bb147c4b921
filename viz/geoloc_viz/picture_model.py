"""The picture of a frame, computed by the core (no viser here): its sensor, picked pixels, marks.

What :mod:`geoloc_viz.image_layer` draws, as numbers the tests compare with independent
core calls and with ``geoloc locate``:

* :func:`frame_sensor`: the sensor through which record ``idx``'s image was taken, sized to the
  image: the scenario's sensor, or for a zooming MISB ST 0601 sensor (``scn.frame_fov_deg``) the
  frame's own ``lens_from_fov(hfov_i, vfov_i, cols, rows)`` on the same gimbal, mount and lever
  arm (:func:`geoloc.workflows.klv_replay.klv_sensor`'s rule), or the sensor's lens scaled to a
  resized image (:func:`geoloc.io.photos.scale_lens`);
* :func:`locate_pixel`: a pixel's line of sight (``sensor.line_of_sight``) and its hit on the
  scene's surface (:func:`geoloc_viz.terrain_link.scene_surface`: the DEM with the GUI's method,
  or the record's constant height), with the DEM evaluations and the iteration trace;
* :func:`ground_pick`: a ray of the browser (a click on the terrain) intersected with the same
  surface (exact first hit), that ground point's pixel (``sensor.ground_to_pixel``) and whether
  the camera sees it (the camera's ray to that pixel cast back through the surface: hidden when
  it meets the terrain first);
* :func:`image_marks`: the pixels of the surveyed truth and targets, of the reported frame
  centre and of the recomputed one, reprojected through ``ground_to_pixel``;
* :func:`terrain_horizon`: where in the image the rays stop meeting the terrain (per sampled
  column, bisected to a pixel), through the surface as well.

Pixels are 1-based pixel centres ``(row, col)`` (``docs/conventions.md``); heights are
ellipsoidal (WGS 84), with the EGM96 orthometric height beside them where shown.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geoloc.io.mgrs_grid import mgrs_text
from geoloc.locate import point_view
from geoloc.pipeline import NO_CORRECTIONS, Pipeline
from geoloc.status import Status, describe
from geoloc.surfaces.base import GroundPoint, LineOfSight, terrain_of

if TYPE_CHECKING:  # imported where they are computed, not at the viewer's start
    from geoloc.analysis.time_offset import TimeOffsetFit
    from geoloc.analysis.triangulate import Triangulation

#: Height datum of every height in this module.
H_DATUM = "ellipsoidal, WGS 84"


def images_of(scn):
    """The scenario's image source (:class:`geoloc.io.images.ImageSource`), or None."""
    return getattr(scn, "images", None)


def image_index(scn, idx) -> int:
    """Index into ``scn.images`` of record ``idx``'s image; -1 when it has none.

    ``scn.image_index`` (one per record) when the scenario says; else the nearest image by time
    to ``scn.record_times_s[idx]`` (seconds on the stream clock, ``ImageSource.index_at``); else
    the record's own index (one image per record, in order).
    """
    images = images_of(scn)
    if images is None or idx is None:
        return -1
    table = getattr(scn, "image_index", None)
    if table is not None:
        k = int(np.asarray(table)[int(idx)])
    else:
        times = getattr(scn, "record_times_s", None)
        if times is not None and np.isfinite(times[int(idx)]):
            k = int(images.index_at(float(times[int(idx)])))
        else:
            k = int(idx)
    return k if 0 <= k < len(images) else -1


def frame_sensor(scn, idx, rows: int, cols: int):
    """The sensor of record ``idx``'s image of ``rows`` x ``cols`` pixels (module docstring)."""
    base = scn.camera
    fov = getattr(scn, "frame_fov_deg", None)
    if fov is not None and idx is not None:
        h, v = (float(x) for x in np.asarray(fov, float)[int(idx)])
        if math.isfinite(h) and math.isfinite(v):
            from geoloc.sensors.lenses import lens_from_fov

            return dataclasses.replace(base, lens=lens_from_fov(math.radians(h), math.radians(v), cols, rows))
    if (base.rows, base.cols) == (rows, cols):
        return base
    from geoloc.io.photos import scale_lens

    return dataclasses.replace(base, lens=scale_lens(base.lens, cols, rows))


@dataclass
class PixelPick:
    """A picked pixel and its ground point (angles in degrees: the panel's edge)."""

    row: float
    col: float
    in_frame: bool
    los: LineOfSight
    hit: GroundPoint  # a TerrainHit on a DEM
    method: str
    iterations: int  # DEM evaluations (heights read, or cells visited by the exact walk)
    trace_ecef: np.ndarray | None = None  # (n, 3) the method's iterates on the line of sight

    @property
    def ok(self) -> bool:
        return int(self.hit.status) == Status.OK

    def lat_deg(self) -> float:
        return float(np.rad2deg(self.hit.lat))

    def lon_deg(self) -> float:
        return float(np.rad2deg(self.hit.lon))


def locate_pixel(scn, inputs, sensor, row, col) -> PixelPick:
    """Pixel ``(row, col)`` of ``sensor`` at the pose of ``inputs``, on the scene's surface."""
    from geoloc_viz import terrain_link

    pose = inputs.pose()
    los = sensor.line_of_sight(float(row), float(col), pose)
    surface = terrain_link.scene_surface(scn, inputs, trace=True)
    hit = Pipeline(sensor, surface, terrain_link.scene_corrections(scn)).intersect(los)
    evals = int(np.asarray(getattr(hit, "dem_evaluations", 0)))
    tr = getattr(hit, "trace", None)
    trace = None
    if tr is not None:
        t = tr.ray()
        trace = np.asarray(t["ecef"], float).reshape(-1, 3)
    method = inputs.method if terrain_of(surface) is not None else "constant height"
    return PixelPick(float(row), float(col), bool(sensor.in_image(row, col)), los, hit, method, evals, trace)


def pick_markdown(p: PixelPick, geoid=True) -> str:
    """The panel's text for a picked pixel: latitude, longitude, height and datum, range, status."""
    head = f"**pixel** row {p.row:g}, column {p.col:g}"
    if not p.in_frame:
        head += " (**outside the frame**)"
    if not p.ok:
        return head + f"  \n**no ground point**: {describe(int(p.hit.status))}"
    lines = [
        head + "  ",
        f"latitude **{p.lat_deg():.8f}** deg  ",
        f"longitude **{p.lon_deg():.8f}** deg  ",
        mgrs_text(p.lat_deg(), p.lon_deg()) + "  ",  # the grid reference a user hands on
        f"height **{float(p.hit.h):.2f} m** ({H_DATUM})",
    ]
    if geoid:
        from geoloc.geodesy.geoid import egm96_undulation

        n = float(egm96_undulation(float(p.hit.lat), float(p.hit.lon)))
        lines[-1] += f", {float(p.hit.h) - n:.2f} m above EGM96 (MSL)"
    lines[-1] += "  "
    lines.append(f"slant range {float(p.hit.slant_range):.1f} m; status {describe(int(p.hit.status))}  ")
    lines.append(f"surface: {p.method}; DEM evaluations {p.iterations}")
    if bool(np.asarray(getattr(p.hit, "hidden", False))):
        lines[-1] += "; **hidden**: the line of sight meets the terrain earlier"
    return "\n".join(lines)


@dataclass
class GroundPick:
    """A point of the terrain picked in the scene, and its pixel in the frame."""

    hit: GroundPoint  # the browser's ray on the terrain
    row: float
    col: float
    pixel_status: int  # Status of ground_to_pixel
    in_frame: bool
    visible: bool
    occluder_range_m: float  # where the camera's ray meets the terrain first [m from the camera]
    range_m: float  # camera to the picked point [m]

    @property
    def ok(self) -> bool:
        return int(self.hit.status) == Status.OK

    def verdict(self) -> str:
        if not self.ok:
            return f"no terrain along this ray: {describe(int(self.hit.status))}"
        if self.pixel_status == Status.BEHIND_CAMERA or not self.in_frame:
            return "outside the frame"
        return "in the frame" if self.visible else "hidden behind terrain from this camera"


def ground_pick(scn, inputs, sensor, origin_ecef, direction_ecef) -> GroundPick:
    """The terrain point on a browser ray, its pixel, and whether the camera sees it.

    The ray meets the scene's terrain at its exact first hit (on a scene without a DEM: the
    record's constant height). Its pixel is ``sensor.ground_to_pixel``; it is in the frame
    when that status is OK (``OUTSIDE_SENSOR``: computed, off the sensor; ``BEHIND_CAMERA``).
    Visibility is :func:`geoloc.locate.point_view`'s: the camera's line of sight through that
    pixel (extrapolated beyond the sensor's edge if need be) is cast through the same surface;
    the point is hidden when that ray meets the terrain more than :data:`geoloc.locate.HIDDEN_TOLERANCE_M`
    before it.
    """
    from geoloc.surfaces.terrain import surface_for

    d = np.asarray(direction_ecef, float)
    d = d / np.linalg.norm(d)
    ray = LineOfSight(np.asarray(origin_ecef, float), d, np.zeros((), np.uint8))
    dem = scn.dem if getattr(scn, "use_dem", True) else None
    surface = surface_for(inputs.target_h, dem, method="exact")
    hit = surface.intersect(ray)  # the browser's ray (not a line of sight): the surface alone
    nan = float("nan")
    if int(hit.status) != Status.OK:
        return GroundPick(hit, nan, nan, int(Status.INVALID_INPUT), False, False, nan, nan)
    from geoloc_viz.terrain_link import scene_corrections

    v = point_view(Pipeline(sensor, surface, scene_corrections(scn)), inputs.pose(), hit.lat, hit.lon, hit.h)
    return GroundPick(
        hit, v.row, v.col, v.pixel_status, v.pixel_status == Status.OK, v.visible, v.occluder_range_m, v.range_m
    )


def ground_markdown(g: GroundPick) -> str:
    """The panel's text for a picked terrain point."""
    if not g.ok:
        return f"**terrain pick**: {g.verdict()}"
    lines = [
        f"**terrain pick**: {float(np.rad2deg(g.hit.lat)):.7f} N, {float(np.rad2deg(g.hit.lon)):.7f} E, "
        f"h {float(g.hit.h):.1f} m ({H_DATUM})  ",
        mgrs_text(float(np.rad2deg(g.hit.lat)), float(np.rad2deg(g.hit.lon))) + "  ",
    ]  # the MGRS line: the grid reference a user hands on
    if np.isfinite(g.row):
        lines.append(f"pixel row {g.row:.2f}, column {g.col:.2f}: **{g.verdict()}**")
    else:
        lines.append(f"**{g.verdict()}** ({describe(g.pixel_status)})")
    if np.isfinite(g.occluder_range_m) and not g.visible:
        lines[-1] += (
            f"  \nthe camera's ray meets the terrain at {g.occluder_range_m:.0f} m, "
            f"{g.range_m - g.occluder_range_m:.0f} m before the point"
        )
    return "\n".join(lines)


def image_marks(scn, idx, sensor, inputs, centre: "PixelPick | None" = None) -> dict:
    """Name -> (row, col, status) of the points reprojected into the frame (``ground_to_pixel``).

    ``truth``: the record's surveyed position (on the DEM when there is one); ``reported``: the
    record's reported frame centre (MISB tags 23-25 / 78, or [Q17]'s published point);
    ``recomputed``: the image centre's own hit on the scene's surface (so its mark is the centre
    pixel, drawn to compare with the reported one); and each of ``scn.targets``
    (``(label, lat_deg, lon_deg, h_m)``, ellipsoidal heights; NaN height: on the DEM).
    """
    from geoloc_viz import terrain_link

    pose = inputs.pose()
    pts = {}
    info = scn.records[int(idx)][0] if idx is not None and scn.records else None

    def dem_h(lat, lon, h):
        if scn.dem is not None and not np.isfinite(h):
            return terrain_link.dem_height(scn.dem, lat, lon)
        return h

    if info is not None:
        if np.isfinite(info.truth_lat_deg):
            pts["truth"] = (
                info.truth_lat_deg,
                info.truth_lon_deg,
                dem_h(info.truth_lat_deg, info.truth_lon_deg, np.nan if scn.dem is not None else info.paper_height_m),
            )
        if np.isfinite(info.paper_lat_deg):
            h = info.paper_height_m if np.isfinite(info.paper_height_m) else np.nan
            pts["reported"] = (info.paper_lat_deg, info.paper_lon_deg, dem_h(info.paper_lat_deg, info.paper_lon_deg, h))
    if centre is None:  # the image centre's pick (a caller that has it passes it)
        centre = locate_pixel(scn, inputs, sensor, *sensor.center_pixel)
    if centre.ok:
        pts["recomputed"] = (centre.lat_deg(), centre.lon_deg(), float(centre.hit.h))
    for t in getattr(scn, "targets", ()) or ():
        label, la, lo, h = t
        pts[f"target {label}"] = (la, lo, dem_h(la, lo, h))
    out = {}
    for name, (la, lo, h) in pts.items():
        if not np.all(np.isfinite([la, lo, h])):
            continue
        px = sensor.ground_to_pixel(np.deg2rad(la), np.deg2rad(lo), h, pose)
        out[name] = (float(px.row), float(px.col), int(px.status))
    return out


def terrain_horizon(scn, inputs, sensor, n_cols: int = 32, refine: int = 13):
    """(k, 2) (row, col) of the terrain's horizon in the frame: per sampled column whose top ray
    misses the terrain (sky, or off the DEM) and whose bottom ray meets it, the row where the rays
    start meeting it, bisected ``refine`` times between the two (the frame's height over
    2^refine: 0.13 px for 1080 rows); empty when no column's top misses and bottom meets.

    Every ray goes through ``sensor.line_of_sight`` and the scene's surface (exact first hit).
    The columns are bisected, not sampled on a grid of rows first: 2 ``n_cols`` rays, then
    ``n_cols`` or fewer a halving, each call small enough to walk uncompiled (64 rays or fewer:
    ``terrain_numba.PY_WALK_MAX_RAYS``), where a 33 x 24 grid's 792 rays compiled the walk on a
    cold cache (5-15 s of CPU before the first picture).
    """
    from geoloc.surfaces.terrain import surface_for

    M, N = sensor.rows, sensor.cols
    pose = inputs.pose()
    dem = scn.dem if getattr(scn, "use_dem", True) else None
    surface = surface_for(inputs.target_h, dem, method="exact")

    pipe = Pipeline(sensor, surface, getattr(scn, "corrections", NO_CORRECTIONS))  # the scene's corrections

    def meets(r, c):
        return np.asarray(pipe.locate(r, c, pose, outside="extrapolate").status) == Status.OK

    cols = np.linspace(0.5, N + 0.5, n_cols)
    top, bottom = 0.5, M + 0.5
    ok = meets(np.repeat([top, bottom], n_cols), np.tile(cols, 2)).reshape(2, n_cols)
    cand = ~ok[0] & ok[1]
    if not cand.any():
        return np.zeros((0, 2))
    cc = cols[cand]
    lo_r, hi_r = np.full(len(cc), top), np.full(len(cc), bottom)  # lo misses, hi meets
    for _ in range(int(refine)):
        mid = 0.5 * (lo_r + hi_r)
        hit = meets(mid, cc)
        hi_r = np.where(hit, mid, hi_r)
        lo_r = np.where(hit, lo_r, mid)
    return np.stack([0.5 * (lo_r + hi_r), cc], axis=1)


#: A pattern of painted marks further than this from its reprojection disagrees with the metadata [px]:
#: in the bundled flight's fault-free frames the painted crosses' centres (find_marks on the H.264
#: frames) lie 0.4 px rms from the targets' reprojections; 3 px is well clear of that noise.
MARKS_DISAGREE_PX = 3.0


@dataclass
class FoundMarks:
    """The painted marks found in a frame against the targets' reprojections."""

    found: np.ndarray  # (m, 2) (row, col) of the red marks found in the image
    predicted: np.ndarray  # (p, 2) the targets' reprojected pixels (in the frame)
    offset_px: np.ndarray  # (2,) centroid of the found minus centroid of the predicted (row, col)
    angle_deg: float  # the angle between the two centroids' lines of sight [deg]

    @property
    def agree(self) -> bool:
        return bool(np.hypot(*self.offset_px) <= MARKS_DISAGREE_PX)


def found_marks(scn, image, marks, sensor, inputs) -> FoundMarks | None:
    """The red marks painted in ``image`` (:func:`geoloc.workflows.render.find_marks`) against the
    ``target`` marks of :func:`image_marks`: how far the pattern of marks seen lies from where the
    record's pose puts the targets (pixels, and the angle between the two centroids' lines of sight).
    None when the scenario has no targets, none is in the frame, or no mark is found."""
    from geoloc.workflows.render import find_marks

    pred = np.array(
        [(r, c) for name, (r, c, st) in marks.items() if name.startswith("target ") and st == Status.OK], float
    ).reshape(-1, 2)
    if not len(pred):
        return None
    found, _ = find_marks(image)
    if not len(found):
        return None
    a, b = found.mean(axis=0), pred.mean(axis=0)
    pose = inputs.pose()
    la = sensor.line_of_sight(a[0], a[1], pose, outside="extrapolate").direction_ecef
    lb = sensor.line_of_sight(b[0], b[1], pose, outside="extrapolate").direction_ecef
    ang = float(np.degrees(np.arccos(np.clip(np.dot(np.ravel(la), np.ravel(lb)), -1.0, 1.0))))
    return FoundMarks(found, pred, a - b, ang)


def found_markdown(f: FoundMarks | None) -> str:
    """The panel's line on the painted marks (empty without them)."""
    if f is None:
        return ""
    dr, dc = (float(x) for x in f.offset_px)
    verdict = "**agree** with the metadata" if f.agree else "**disagree**: the picture and the metadata's pose part"
    return (
        f"**painted marks**: {len(f.found)} found for {len(f.predicted)} targets in the frame; their "
        f"centre lies **{math.hypot(dr, dc):.1f} px** ({f.angle_deg:.2f} deg; row {dr:+.1f}, "
        f"column {dc:+.1f}) from the targets' reprojection: {verdict}"
    )


# ------------------------------------------------------------------ one target in several frames
@dataclass
class TargetRays:
    """A target picked in several frames and triangulated from its rays (no DEM).

    ``frames`` are the record indices; ``origins``, ``directions`` each frame's line of sight
    (ECEF); ``closest`` the point of each ray nearest the triangulated point (its residual's
    foot); ``tri`` the :class:`geoloc.analysis.triangulate.Triangulation`; ``surface`` its
    comparison with each frame's DEM hit (:func:`geoloc.analysis.triangulate.compare_with_surface`);
    ``budget_note`` which budget gave the covariance.
    """

    frames: list
    picks: list
    origins: np.ndarray
    directions: np.ndarray
    closest: np.ndarray
    tri: Triangulation
    surface: dict
    budget_note: str = ""


def triangulate_picks(
    scn, frames: dict, budget=None, budget_note: str = "", velocities: dict | None = None
) -> TargetRays | None:
    """The least-squares intersection of the rays of one target picked in several frames.

    Parameters
    ----------
    frames : dict
        Record index -> ``(sensor, inputs, PixelPick)``: each frame's own sensor (its zoom), its
        platform state and the pick (whose ``los`` is the ray).
    budget : ErrorBudget, optional
        Gives each ray's weight and the covariance (:func:`geoloc.analysis.triangulate.triangulate_rays`:
        the sensor's own keys shared by every frame, the rest independent per frame).
    velocities : dict, optional
        Record index -> the platform's velocity (north, east, down) [m/s]: needed when the budget
        has ``time_s``.

    Returns
    -------
    TargetRays or None
        None for fewer than two frames.
    """
    from geoloc.analysis.triangulate import compare_with_surface, triangulate_rays
    from geoloc.analysis.uncertainty import chain_derivatives

    if len(frames) < 2:
        return None
    keys = sorted(frames)
    picks = [frames[k][2] for k in keys]
    O = np.stack([np.asarray(p.los.origin_ecef, float).reshape(3) for p in picks])
    D = np.stack([np.asarray(p.los.direction_ecef, float).reshape(3) for p in picks])
    D = D / np.linalg.norm(D, axis=-1, keepdims=True)
    ok = np.array([int(np.asarray(p.los.status)) in (Status.OK, Status.OUTSIDE_SENSOR) for p in picks])
    tri = None
    if budget is not None:
        ders = [
            chain_derivatives(
                frames[k][0],
                frames[k][1].pose(),
                frames[k][2].row,
                frames[k][2].col,
                budget,
                None if velocities is None else velocities.get(k),
            )
            for k in keys
        ]
        if all(d[0] == ders[0][0] for d in ders):  # the same sources in every frame
            dO = np.concatenate([d[1].reshape(1, 3, -1) for d in ders])
            dD = np.concatenate([d[2].reshape(1, 3, -1) for d in ders])
            tri = triangulate_rays(O, D, ok, ders[0][0], dO, dD)
    if tri is None:
        tri = triangulate_rays(O, D, ok)
        budget_note = "no budget: no covariance"
    X = np.asarray(tri.ecef, float)
    t = np.einsum("ni,ni->n", X[None, :] - O, D)
    closest = O + t[:, None] * D
    surface = {}
    if tri.status == Status.OK:
        h = np.array([float(p.hit.h) if p.ok else np.nan for p in picks])
        surface = compare_with_surface(tri, h, np.array([p.ok for p in picks]))
    return TargetRays(keys, picks, O, D, closest, tri, surface, budget_note)


def target_ellipse_enu(enu, tri, n: int = 72, scale: float = 1.0) -> np.ndarray:
    """The triangulated point's 90 % horizontal ellipse (n, 3) in the scene's ENU frame [m], level at
    the point's height (``scale`` enlarges it about the point, as the error vectors are drawn)."""
    from geoloc.analysis.uncertainty import ELLIPSE90_PER_SIGMA
    from geoloc.geodesy.local import ellipse_ring_enu, enu_to_geodetic

    a, b = (float(v) * ELLIPSE90_PER_SIGMA * scale for v in (tri.ellipse_major_m, tri.ellipse_minor_m))
    ring = ellipse_ring_enu(a, b, float(tri.ellipse_azimuth_deg), n)
    lat, lon, h = enu_to_geodetic(ring, tri.lat, tri.lon, tri.h)
    return enu.from_geodetic(lat, lon, h)


def target_markdown(t: TargetRays | None, n_frames: int = 0) -> str:
    """The panel's text for a target picked in several frames: the triangulated position, its
    covariance, each ray's residual and the comparison with each frame's DEM hit."""
    if t is None:
        if n_frames == 1:
            return (
                "**target rays**: 1 frame picked; pick the same target in another frame (move the "
                "timeline) to triangulate it"
            )
        return ""
    tri = t.tri
    head = f"**target rays**: {len(t.frames)} frames (records {', '.join(str(k + 1) for k in t.frames)})"
    if tri.status != Status.OK:
        return head + "  \nnot triangulated: fewer than two rays, or rays within 1 deg of each other"
    lines = [
        head + "  ",
        f"triangulated latitude **{tri.lat_deg:.8f}** deg, longitude **{tri.lon_deg:.8f}** deg, "
        f"height **{tri.h:.2f} m** ({H_DATUM})  ",
    ]
    if tri.cov_enu is not None:
        c = tri.cov_enu
        lines.append(f"CE90 **{tri.ce90_m:.2f} m**, LE90 **{tri.le90_m:.2f} m** ({t.budget_note})  ")
        lines.append(
            "covariance ENU [m^2]: " + "; ".join(" ".join(f"{c[i, j]:.3g}" for j in range(3)) for i in range(3)) + "  "
        )
    elif t.budget_note:
        lines.append(f"({t.budget_note})  ")
    diff = t.surface.get("differences_m") if t.surface else None
    for i, k in enumerate(t.frames):
        p = t.picks[i]
        s = f"record {k + 1}: pixel ({p.row:g}, {p.col:g}), ray residual **{tri.residual_m[i]:.2f} m**"
        if diff is not None and np.isfinite(diff[i]):
            s += f", DEM hit {float(p.hit.h):.1f} m: DEM minus triangulated {diff[i]:+.1f} m"
        lines.append(s + "  ")
    if t.surface and math.isfinite(t.surface.get("mean_m", math.nan)):
        lines.append(
            f"DEM minus triangulated, mean **{t.surface['mean_m']:+.1f} m** (standard error "
            f"{t.surface['se_m']:.1f} m)" + (f"; **{t.surface['warning']}**" if t.surface["warning"] else "")
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- a video timing fault

#: Shortest run of frames whose painted marks disagree with the metadata that is fitted as a
#: video timing fault: a few frames can disagree for other reasons (a mark on a ridge's edge).
TIMING_MIN_FRAMES = 5
#: Frames of agreement a run may hold and stay one run: while the aircraft moves slowly across the
#: line of sight a 1.5 s offset moves the marks by under 3 px (the bundled run has 6 such frames).
TIMING_MAX_GAP = 8
#: The fit must explain the run: at its offset the marks lie within the agreement threshold, and
#: at least twice closer than at offset 0.
TIMING_EXPLAINED = 0.5


@dataclass
class VideoTimingFault:
    """A run of frames whose picture is shifted in time against its metadata (record indices,
    inclusive), with the fitted offset (:func:`geoloc.workflows.video_sync.fit_klv_time_offset`:
    video time = metadata time + ``fit.time_offset_s``)."""

    first: int
    last: int
    fit: TimeOffsetFit

    def contains(self, idx) -> bool:
        return idx is not None and self.first <= int(idx) <= self.last

    def ahead(self) -> str:
        d = -float(self.fit.time_offset_s)
        return f"{abs(d):.2f} s {'ahead of' if d > 0 else 'behind'}"

    def markdown(self) -> str:
        f = self.fit
        return (
            f"**video timing fault, frames {self.first} .. {self.last}**: the picture runs {self.ahead()} its "
            f"metadata: the painted crosses are where the projected marks (white x) will be "
            f"{abs(f.time_offset_s):.2f} s {'later' if f.time_offset_s < 0 else 'earlier'}. Fitted time "
            f"offset **{f.time_offset_s:+.3f} s** (video time = metadata time + offset) from {f.n_marks} "
            f"marks in {f.n_frames} frames: rms {f.rms_px:.2f} px (at offset 0: {f.rms_at_zero_px:.2f} px)"
        )


#: Pictures decoded between two looks at ``should_stop`` (a stop waits for at most this many).
MARKS_CHUNK = 25


def frame_mark_disagreement(scn, predictor, frames, *, should_stop=lambda: False) -> np.ndarray:
    """Median distance [px] from each target's projection at the record's own time (the metadata's
    word) to the nearest painted mark found in the record's picture, per record index in ``frames``;
    NaN where no mark lies within 40 px or the record has no picture. ``should_stop`` is asked
    between chunks of :data:`MARKS_CHUNK` pictures; when it says so, the rest stays NaN."""
    from geoloc.workflows.video_sync import frame_marks, mark_offsets

    frames = np.asarray(list(frames), int)
    ks = np.array([image_index(scn, i) for i in frames])
    out = np.full(len(frames), np.nan)
    has = ks >= 0
    if not has.any():
        return out
    images, marks = images_of(scn), []
    for a in range(0, int(has.sum()), MARKS_CHUNK):
        if should_stop():
            return out
        marks += list(frame_marks(images, ks[has][a : a + MARKS_CHUNK]))
    pred = predictor(np.asarray(scn.record_times_s, float)[frames[has]])
    med = []
    for m, p in zip(marks, pred):
        o = mark_offsets(m, p)
        d = np.hypot(o[:, 0], o[:, 1])
        med.append(np.nanmedian(d) if np.isfinite(d).any() else np.nan)
    out[has] = med
    return out


def video_timing_faults(scn, exclude=None, *, should_stop=lambda: False) -> list:
    """The runs of frames where the picture and its metadata disagree in time, each fitted.

    Each record's painted marks are compared with the targets projected at the record's own time
    (:func:`frame_mark_disagreement`); runs of frames over :data:`MARKS_DISAGREE_PX` (gaps of up to
    :data:`TIMING_MAX_GAP` frames, at least :data:`TIMING_MIN_FRAMES`), leaving out the frames in
    ``exclude`` (a mask: frames whose metadata is already flagged against its own reported
    centres, a fault of the metadata, not of the picture's timing), are each fitted with
    :func:`geoloc.workflows.video_sync.fit_klv_time_offset`; a run is kept when the fitted offset
    explains it (:data:`TIMING_EXPLAINED`). Needs a STANAG 4609 stream (``scn.video_path``), its
    pictures' time stamps (``scn.record_times_s``) and surveyed targets (``scn.targets``); else [].
    """
    from geoloc_viz.flight_model import outlier_runs
    from geoloc.workflows.klv_replay import replay_klv
    from geoloc.workflows.video_sync import fit_klv_time_offset, klv_predictor

    path, targets, images = getattr(scn, "video_path", None), getattr(scn, "targets", None), images_of(scn)
    if path is None or not targets or images is None or getattr(scn, "record_times_s", None) is None:
        return []
    pts = [(la, lo, h) for _, la, lo, h in targets]
    replay = replay_klv(path)
    pred = klv_predictor(replay, pts, images.rows, images.cols)
    n = len(scn.records)
    d = frame_mark_disagreement(scn, pred, range(n), should_stop=should_stop)
    if should_stop():
        return []
    bad = np.nan_to_num(d, nan=0.0) > MARKS_DISAGREE_PX
    if exclude is not None:
        bad &= ~np.asarray(exclude, bool)[:n]
    out = []
    for a, b in outlier_runs(bad, max_gap=TIMING_MAX_GAP):
        if should_stop():
            break
        if b - a + 1 < TIMING_MIN_FRAMES:
            continue
        ks = [k for k in (image_index(scn, i) for i in range(a, b + 1)) if k >= 0]
        fit = fit_klv_time_offset(path, pts, ks, replay=replay, images=images)
        if fit.rms_px <= MARKS_DISAGREE_PX and fit.rms_px <= TIMING_EXPLAINED * fit.rms_at_zero_px:
            out.append(VideoTimingFault(int(a), int(b), fit))
    return out


_TIMING_CACHE: dict = {}
_TIMING_LOCK = threading.Lock()


def _timing_key(scn, exclude) -> tuple:
    """What the timing search reads, by value: the stream file (path, size, modification time),
    the records, their pictures' times, the targets and ``exclude``. Two scenarios loaded from one
    file share the answer (each new tab of a flight, each scenario switch, built its own scenario
    and searched again: 5.7 s of CPU a time for the example flight)."""
    path = getattr(scn, "video_path", None)
    try:
        st = os.stat(path) if path is not None else None
        stamp = None if st is None else (st.st_size, st.st_mtime_ns)
    except OSError:
        stamp = None
    h = hashlib.blake2b(repr(scn.records).encode(), digest_size=16)
    times = getattr(scn, "record_times_s", None)
    if times is not None:
        h.update(np.ascontiguousarray(times, float).tobytes())
    if exclude is not None:
        h.update(np.asarray(exclude, bool).tobytes())
    return (str(path), stamp, repr(getattr(scn, "targets", None)), h.hexdigest())


def cached_video_timing_faults(scn, exclude=None, *, should_stop=lambda: False) -> list:
    """:func:`video_timing_faults` once per stream and records (:func:`_timing_key`): the first
    caller computes, the others wait for its answer. A search stopped by ``should_stop`` answers
    [] and is not kept."""
    key = _timing_key(scn, exclude)
    with _TIMING_LOCK:
        hit = _TIMING_CACHE.get(key)
        if hit is not None:
            return hit
        out = video_timing_faults(scn, exclude, should_stop=should_stop)
        if should_stop():
            return []
        if len(_TIMING_CACHE) > 4:
            _TIMING_CACHE.clear()
        _TIMING_CACHE[key] = out
        return out
