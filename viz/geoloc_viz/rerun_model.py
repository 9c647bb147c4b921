"""What a rerun recording shows, computed by the core: one entry per time step.

No rerun import here: this module runs the core (:mod:`geoloc.workflows.flight`,
:mod:`geoloc.workflows.replay`, :mod:`geoloc.locate`, :mod:`geoloc.surfaces.terrain` when a DEM is
given) and expresses every result in the scene's local East-North-Up frame
(:mod:`geoloc.frames.enu`); :mod:`geoloc_viz.rerun_log` only writes these numbers. The tests
read the recording back and compare it with these arrays.

Scene origin: the convention of the viser scene (``geoloc_viz.scenario.enu_origin_for``):
near the target of the first step (the published position if the records
have one, else the located target), rounded to 0.001 deg and 100 m. Records
of several flights (the ``table`` column of [Q17]) get **one origin per
flight** (:attr:`LogSteps.enus`), by the same rule on each flight's first step,
and :mod:`geoloc_viz.rerun_log` gives each flight its own entity tree.

Error analysis per step (:func:`add_error_analysis`): the error components of
:func:`geoloc.analysis.accuracy.error_components` (computed minus the truth, else
minus the published position; along / across the local track of
:func:`geoloc.analysis.accuracy.track_azimuth_rad`), the robust outlier flags of
:func:`geoloc.analysis.accuracy.robust_outliers` per flight, and for records with
a surveyed truth the errors before and after a per-flight calibration: the named
sensor parameters (default the mounting rotation) of
:func:`geoloc.analysis.sensor_fit.fit_sensor_groups`, for a camera file as for a
sensor file (:func:`sensor_fit_series`).
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import os

from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from geoloc.assets import ASSETS, DEFAULT_CAMERA
from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.frames.enu import EnuFrame
from geoloc.frames.graph import BoundFrames
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.io.images import ImageSource
from geoloc.io.records import load_records
from geoloc.locate import as_sensor, line_of_sight  # as_sensor: the steps_from_* entrances
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.frame import FrameSensor
from geoloc.surfaces.base import GroundPoint, LineOfSight, terrain_of
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.surfaces.height import HeightSurface
from geoloc_viz.rerun_terrain import SolverOptions, TerrainSteps, dem_steps, solver_options
from geoloc.workflows.flight import FlightScenario, simulate
from geoloc.workflows.replay import result_from_ground


@dataclass
class LogSteps:
    """Every per-step quantity of a recording, SI units, radians, ENU metres.

    Attributes
    ----------
    kind : {"flight", "records"}
    name : str
    timelines : dict
        Timeline name -> ("duration", seconds) or ("sequence", int array).
    labels : list of str
    camera : FrameSensor
    pose : Pose
        Batched, one entry per step.
    chain : FrameChain
    row, col : ndarray (n,)
        Pixel of each line of sight (1-based).
    los : LineOfSight
    ground : GroundPoint
        The located target of each step.
    enu : EnuFrame
        Scene origin.
    truth : dict or None
        ``lat_deg, lon_deg, h_m`` of the reference position (surveyed, or the
        exact DEM hit in a simulation) and ``error_m`` (horizontal geodesic distance).
    published : dict or None
        ``lat_deg, lon_deg, error_m`` of the published computed position (records).
    terrain : TerrainSteps or None
    notes : list of str
        Plain-text description of the inputs (for the recording's info panel).
    extra_series : dict
        Further scalar series, entity path -> (n,) array (e.g. the ellipsoid model's error).
    group : ndarray of str or None
        Flight of each step (None: one flight); each flight has its own origin in ``enus``.
    enus : dict or None
        Flight -> scene origin (:class:`EnuFrame`); None: ``enu`` for every step.
    components : dict or None
        :func:`geoloc.analysis.accuracy.error_components` of each step against
        ``reference`` (with ``along_m``, ``across_m``), and ``track_rad``.
    reference : str
        ``"truth"`` or ``"published"``: what ``components`` are measured against.
    outlier : ndarray of bool or None
        Robust outlier flags of the horizontal error, per flight.
    calibration : dict or None
        ``before_m``, ``after_m`` (horizontal error to truth before / after the per-flight
        mounting fit), ``after_along_m``, ``after_across_m`` and ``note``.
    """

    kind: str
    name: str
    timelines: dict
    labels: list
    camera: FrameSensor
    pose: Pose
    chain: BoundFrames
    row: np.ndarray
    col: np.ndarray
    los: LineOfSight
    ground: GroundPoint
    enu: EnuFrame
    truth: dict | None = None
    published: dict | None = None
    terrain: TerrainSteps | None = None
    notes: list = field(default_factory=list)
    extra_series: dict = field(default_factory=dict)
    group: np.ndarray | None = None
    enus: dict | None = None
    components: dict | None = None
    reference: str = ""
    outlier: np.ndarray | None = None
    calibration: dict | None = None
    #: Each step's picture (what the camera saw): an ImageSource, the image index of each step (-1: none) and
    #: each step's fields of view [deg] (horizontal, vertical) for its pinhole at the image's size.
    images: ImageSource | None = None
    image_index: np.ndarray | None = None
    image_fov_deg: np.ndarray | None = None
    #: Each step's image corners on the surface it was located on (a KLV replay's):
    #: ``lat_deg``, ``lon_deg``, ``h_m`` (ellipsoidal, WGS 84), each (n, 4), corners in ring
    #: order (upper left, upper right, lower right, lower left); None: not computed.
    corners: dict | None = None

    def __len__(self) -> int:
        return len(self.labels)

    # ---------------------------------------------------------- flights
    @property
    def group_of(self) -> np.ndarray:
        """Flight label of every step (``"all"`` without groups)."""
        if self.group is None:
            return np.array(["all"] * len(self), dtype=object)
        return np.asarray(self.group, dtype=object)

    @property
    def groups(self) -> list:
        """Flight labels in order of first appearance."""
        return list(dict.fromkeys(self.group_of.tolist()))

    @property
    def multi(self) -> bool:
        """More than one flight (then each has its own entity tree and origin)."""
        return len(self.groups) > 1

    def root(self, g: str, base: str = "world") -> str:
        """Entity root of flight ``g``: ``world`` for one flight, ``world/<g>`` for several."""
        return f"{base}/{g}" if self.multi else base

    def series_path(self, g: str, rel: str) -> str:
        """Entity of the time series ``rel`` (``attitude/heading_deg``) of flight ``g``.

        ``series/<rel>`` for one flight; ``series/<g>/<rel>`` for several, so that no
        series has rows of two flights and no plot line joins the last step of one flight
        to the first of the next.
        """
        return f"series/{g}/{rel}" if self.multi else f"series/{rel}"

    def enu_for(self, g: str) -> EnuFrame:
        """Scene origin of flight ``g``."""
        return self.enus[g] if self.enus else self.enu

    def enu_of_step(self, k: int) -> EnuFrame:
        return self.enu_for(self.group_of[k])

    def _per_group(self, fn) -> np.ndarray:
        """(n, 3) array filled flight by flight with ``fn(enu, mask)``."""
        out = np.full((len(self), 3), np.nan)
        grp = self.group_of
        for g in self.groups:
            m = grp == g
            out[m] = fn(self.enu_for(g), m)
        return out

    # ---------------------------------------------------------- derived, ENU
    @property
    def aircraft_enu(self) -> np.ndarray:
        """Aircraft (optical centre) in its flight's scene frame, (n, 3) [m]."""
        o = np.broadcast_to(self.los.origin_ecef, (len(self), 3))
        return self._per_group(lambda enu, m: enu.from_ecef(o[m]))

    @property
    def target_enu(self) -> np.ndarray:
        """Located target in its flight's scene frame, (n, 3) [m]; NaN where no hit."""
        return self._per_group(lambda enu, m: enu.from_ecef(self.ground.ecef[m]))

    def geodetic_enu(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        """Geodetic points (one per step) in their flight's scene frame, (n, 3) [m]."""
        la, lo, h = (np.broadcast_to(np.asarray(v, float), (len(self),)) for v in (lat_deg, lon_deg, h_m))
        return self._per_group(lambda enu, m: enu.from_geodetic(np.deg2rad(la[m]), np.deg2rad(lo[m]), h[m]))

    def hop_transforms(self) -> dict:
        """4x4 transform of each entity of the frame hierarchy relative to its parent, root side first.

        ``ned``: T_enu_ned = T_enu_ecef @ T_ecef_ned (the first hop of the
        sensor's frame graph, re-expressed in the scene frame); every other
        frame: the graph's own hop T_parent_frame (mount, gimbal joints, camera).
        """
        n = len(self)
        T_enu_ecef = np.empty((n, 4, 4))
        grp = self.group_of
        for g in self.groups:
            e = self.enu_for(g)
            T_enu_ecef[grp == g] = rot.invert(rot.transform(e.R_ecef_enu, e.origin_ecef))
        if not self.multi:
            T_enu_ecef = T_enu_ecef[0]
        return {h.src: (T_enu_ecef @ h.T if h.dst == "ecef" else h.T) for h in self.chain.all_hops}

    def entity_paths(self) -> dict:
        """Frame -> rerun entity path (``world/ned/body/...``), one per frame of the graph."""
        out: dict[str, str] = {}
        for j in self.chain.graph.joints:
            out[j.child] = f"{out.get(j.parent, 'world')}/{j.child}"
        return out


def enu_origin(lat_deg: float, lon_deg: float, h_m: float) -> EnuFrame:
    """Scene origin near a target: :meth:`geoloc.frames.enu.EnuFrame.scene_origin`, as in the viser scene."""
    return EnuFrame.scene_origin(lat_deg, lon_deg, h_m)


def load_camera(path=None):
    """A sensor or first-phase camera TOML, default the bundled [Q17] flight-test camera."""
    from geoloc.sensors.sensor_file import load_sensor

    return load_sensor(path if path else Path(ASSETS).joinpath(*DEFAULT_CAMERA))


def _terrain(
    los: LineOfSight, dem, method: str, eps_h_m=None, threshold_m=None, corrections: Corrections = NO_CORRECTIONS
):
    """Intersect with a DEM through :mod:`geoloc.surfaces.terrain`; returns (GroundPoint, TerrainSteps)."""
    return dem_steps(los, dem, method, eps_h_m, threshold_m, corrections)


def add_corrections(steps: LogSteps, corrections) -> LogSteps:
    """Say the pipeline's line-of-sight corrections in the recording: a note naming them and, with
    refraction, ``series/refraction_m`` (how far refraction moved each step's located point,
    ``GroundPoint.refraction_m``) [m]."""
    if not corrections:
        return steps
    names = [f"{n} (U.S. Standard Atmosphere 1976)" if n == "refraction" else n for n in corrections.names]
    steps.notes.append("line-of-sight corrections (docs/refraction.md): " + ", ".join(names))
    shift = getattr(steps.ground, "refraction_m", None)
    if corrections.refraction is not None and shift is not None:
        steps.extra_series["series/refraction_m"] = np.asarray(shift, float)
        ok = np.isfinite(np.asarray(shift, float))
        if np.any(ok):
            steps.notes.append(
                f"refraction moved the located points {np.min(shift[ok]):.2f}-"
                f"{np.max(shift[ok]):.2f} m (series/refraction_m)"
            )
    return steps


def _first_finite(lat, lon, h):
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
    if not np.any(ok):
        raise ValueError("no step has a valid ground point: nothing to centre the scene on")
    k = int(np.argmax(ok))
    return lat[k], lon[k], h[k]


def _origin_at_ground(ground: GroundPoint) -> EnuFrame:
    """The scene origin at the first step with a ground point (:func:`enu_origin`)."""
    return enu_origin(*_first_finite(ground.lat_deg, ground.lon_deg, ground.h))


def _mesh_terrain(dem, dem_path, n: int) -> TerrainSteps:
    """A DEM drawn as the mesh only: the steps were not traced by a DEM solver ("ellipsoid": no
    per-ray iterations)."""
    return TerrainSteps("ellipsoid", dem, str(dem_path), np.zeros(n, int), [], [])


def _analysed(steps: LogSteps, corrections, heading_deg=None, outlier=None) -> LogSteps:
    """The steps with their corrections said (:func:`add_corrections`) and their errors analysed
    (:func:`add_error_analysis`): the last step of every ``steps_from_*``."""
    return add_error_analysis(add_corrections(steps, corrections), heading_deg=heading_deg, outlier=outlier)


def steps_from_flight(
    scn: FlightScenario, camera: FrameSensor | None = None, corrections: Corrections = NO_CORRECTIONS
) -> LogSteps:
    """Simulate a scenario (:func:`geoloc.workflows.flight.simulate`) and geolocate every step.

    The located target is the scenario's method: the ellipsoid inflated to
    ``target_h_m`` [Q17 eq. 11], or a DEM method. With a DEM, the reference
    ("truth") is the exact first hit on that DEM, so the error series shows
    what the chosen method costs at each frame angle.
    """
    camera = as_sensor(camera if camera is not None else load_camera(scn.camera_path))  # a Python Camera too
    track = simulate(scn)
    n = len(track)
    row = np.full(n, camera.center_pixel[0] if scn.row is None else scn.row)
    col = np.full(n, camera.center_pixel[1] if scn.col is None else scn.col)
    chain = camera.frames(track.pose)
    los = line_of_sight(track.pose, camera, row, col)
    truth = None
    extra: dict = {}
    # the scenario's DEM, opened once: the located points, the exact truth and the mesh
    dem_path = None if scn.dem_path is None else str(scn.dem_path)
    dem = SurfaceSpec(dem=dem_path, dem_datum=scn.dem_datum).raster(f"{scn.name}: dem")
    notes = [
        f"scenario: {scn.name}",
        f"{n} steps at {scn.rate_hz:g} Hz, "
        f"outer gimbal {scn.outer_min_deg:g}-{scn.outer_max_deg:g} deg ({scn.side}), "
        f"period {scn.scan_period_s:g} s",
    ]
    ground, terrain = _flight_ground(scn, los, dem, corrections, notes)
    if dem is not None:
        truth = _flight_truth(scn, los, ground, terrain, dem, corrections, notes, extra)
        terrain = terrain if terrain is not None else _mesh_terrain(dem, scn.dem_path, n)
    if scn.mc_model_path is not None:
        _flight_cep(scn, track, scn.mc_model_path, notes, extra)
    k = np.arange(n)
    steps = LogSteps(
        "flight",
        scn.name,
        {"time": ("duration", track.t), "frame": ("sequence", k)},
        [f"frame {i}" for i in k],
        camera,
        track.pose,
        chain,
        row,
        col,
        los,
        ground,
        _origin_at_ground(ground),
        truth=truth,
        terrain=terrain,
        notes=notes,
        extra_series=extra,
    )
    return _analysed(steps, corrections)


def _flight_ground(scn: FlightScenario, los: LineOfSight, dem, corrections, notes: list):
    """The located targets by the scenario's method, (GroundPoint, TerrainSteps or None): the
    ellipsoid inflated to ``target_h_m`` [Q17 eq. 11], or the DEM solver's traced steps."""
    # the scenario file's loader refuses either missing piece; a FlightScenario built in code may lack it
    if scn.method == "ellipsoid":
        if scn.target_h_m is None:
            raise ValueError(f"{scn.name}: method = 'ellipsoid' needs target_h_m")
        notes.append(f"located on the ellipsoid inflated to {scn.target_h_m:g} m [Q17 eq. 11]")
        return Pipeline(None, HeightSurface(scn.target_h_m), corrections).intersect(los), None
    if scn.dem_path is None or dem is None:
        raise ValueError(f"{scn.name}: method = {scn.method!r} needs a dem")
    ground, terrain = _terrain(los, dem, scn.method, scn.eps_h_m, scn.threshold_m, corrections)
    notes.append(f"located on {scn.dem_path.name} ({scn.dem_datum}) by '{scn.method}'")
    return ground, terrain


def _flight_truth(scn: FlightScenario, los, ground, terrain, dem, corrections, notes: list, extra: dict) -> dict:
    """The simulation's truth: the exact first hit on the DEM and each step's horizontal error to
    it; with a DEM method and a target height, the ellipsoid model's error too (a series)."""
    exact = (
        ground
        if (terrain is not None and scn.method == "exact")
        else _terrain(los, dem, "exact", corrections=corrections)[0]
    )
    truth = {
        "lat_deg": exact.lat_deg,
        "lon_deg": exact.lon_deg,
        "h_m": exact.h,
        "error_m": horizontal_distance_m(ground.lat_deg, ground.lon_deg, exact.lat_deg, exact.lon_deg),
    }
    notes.append("truth: exact first hit on the DEM")
    if scn.method != "ellipsoid" and scn.target_h_m is not None:
        ell = Pipeline(None, HeightSurface(scn.target_h_m), corrections).intersect(los)
        extra["series/ellipsoid_model/to_truth_m"] = horizontal_distance_m(
            ell.lat_deg, ell.lon_deg, exact.lat_deg, exact.lon_deg
        )
        notes.append(f"ellipsoid model at {scn.target_h_m:g} m compared with the truth too")
    return truth


def _flight_cep(scn: FlightScenario, track, model_path: Path, notes: list, extra: dict) -> None:
    """The scenario's ``[montecarlo]`` CEP per step (:func:`geoloc.workflows.flight.step_cep`) as series."""
    from geoloc.analysis.errormodel import ErrorModel
    from geoloc.workflows.flight import step_cep

    if scn.target_h_m is None:
        raise ValueError("[montecarlo] needs [terrain] target_h_m (the ellipsoid model's height)")
    mc = step_cep(
        track,
        ErrorModel.from_toml(model_path),
        scn.target_h_m,
        scn.mc_samples,
        np.random.default_rng(scn.mc_seed),
    )
    extra["series/cep/cep_m"] = mc["cep_m"]
    extra["series/cep/cep50_empirical_m"] = mc["cep50_empirical_m"]
    notes.append(f"CEP: {scn.mc_samples} Monte Carlo samples per step, errors of {model_path.name}, seed {scn.mc_seed}")


def steps_from_records(
    path,
    camera: FrameSensor | None = None,
    *,
    height_column: str | None = None,
    target_h_m: float | None = None,
    height_kind: str = "inflated",
    dem_path=None,
    dem_datum: str = "egm96",
    method: str = "exact",
    eps_h_m=None,
    threshold_m=None,
    group_column: str | None = "table",
    calibrate: bool = True,
    fit_names=None,
    corrections: Corrections = NO_CORRECTIONS,
) -> tuple[LogSteps, list]:
    """Geolocate every record of a flight-test CSV: one time step per record.

    Height source, first given wins: ``dem_path`` (method of :mod:`geoloc.surfaces.terrain`),
    ``target_h_m`` (one height), ``height_column``, else ``paper_height_m`` if the
    file has it. Errors are horizontal geodesic distances (:mod:`geoloc.workflows.replay`).
    Flights: the ``group_column`` (default ``table``; ignored when absent), one scene
    origin each. With a surveyed truth, ``calibrate`` adds the errors after a per-flight
    fit: :func:`geoloc.analysis.sensor_fit.fit_sensor_groups` of ``fit_names`` (default
    :data:`DEFAULT_FIT_NAMES`, the mounting rotation) on the same surface as the located
    targets (:func:`geoloc.surfaces.terrain.surface_for`).

    Returns
    -------
    LogSteps, list of RowError
        The steps and the rows the loader rejected.
    """
    camera = as_sensor(camera if camera is not None else load_camera())  # a Python Camera too
    recs = load_records(path, angles=camera.angle_names)
    if len(recs) == 0:
        raise ValueError(f"{path}: no valid record ({len(recs.errors)} rejected)")
    pose = recs.pose()
    row, col = recs.column("row"), recs.column("col")
    los = line_of_sight(pose, camera, row, col, outside="extrapolate")  # recorded pixels
    notes = [f"records: {Path(path).name} ({len(recs)} records)"]
    h = None
    if dem_path is not None:
        dem = SurfaceSpec(dem=dem_path, dem_datum=dem_datum).raster()
        ground, terrain = _terrain(los, dem, method, eps_h_m, threshold_m, corrections)
        notes.append(f"located on {Path(dem_path).name} ({dem_datum}) by '{method}'")
    else:
        h, terrain = _record_heights(path, recs, target_h_m, height_column, notes), None
        ground = Pipeline(None, HeightSurface(h, height_kind), corrections).intersect(los)
    truth, published = _records_references(recs, ground)
    ref = published or {"lat_deg": ground.lat_deg, "lon_deg": ground.lon_deg, "h_m": ground.h}
    grp, enus, enu = _flight_origins(recs, group_column, ref["lat_deg"], ref["lon_deg"], ref["h_m"])
    if grp is not None and enus is not None:  # both, or neither (one flight: no group)
        notes.append(f"flights ({group_column}): {', '.join(enus)}, each with its own scene origin")
    steps = LogSteps(
        "records",
        Path(path).name,
        {"record": ("sequence", np.arange(len(recs)))},
        recs.labels(),
        camera,
        pose,
        camera.frames(pose),
        row,
        col,
        los,
        ground,
        enu,
        truth=truth,
        published=published,
        terrain=terrain,
        notes=notes,
        group=grp,
        enus=enus,
    )
    _analysed(steps, corrections, heading_deg=recs.column("heading_deg"))
    if calibrate and truth is not None:
        names = list(DEFAULT_FIT_NAMES if fit_names is None else fit_names)
        surf = _targets_surface(steps, h, len(recs), method, height_kind, eps_h_m, threshold_m)
        steps.calibration = sensor_fit_series(steps, recs, names, surf, group_column if grp is not None else None)
    return steps, list(recs.errors)


def _record_heights(path, recs, target_h_m, height_column, notes: list) -> np.ndarray:
    """Each record's target height without a DEM: ``target_h_m``, else ``height_column``, else
    ``paper_height_m``; a column with an empty or non-finite height is refused by its lines."""
    if target_h_m is not None:
        notes.append(f"located at one target height {target_h_m:g} m")
        return np.full(len(recs), float(target_h_m))
    col_name = height_column or ("paper_height_m" if recs.has("paper_height_m") else None)
    if col_name is None:
        raise ValueError(
            f"{path}: give a height column, a target height or a DEM (no paper_height_m column to default to)"
        )
    h = recs.column(col_name)
    bad = ~np.isfinite(h)
    if np.any(bad):
        raise ValueError(
            f"height column {col_name!r} is empty or not finite on line(s) {[int(x) for x in recs.lines[bad]]}"
        )
    notes.append(f"located at each record's {col_name}")
    return h


def _records_references(recs, ground: GroundPoint) -> tuple[dict | None, dict | None]:
    """The records' surveyed truth and published positions (each None where the file lacks its
    columns), with the located targets' horizontal errors to them (:func:`result_from_ground`)."""
    res = result_from_ground(recs, ground)
    truth = published = None
    if recs.has("truth_lat_deg") and recs.has("truth_lon_deg"):
        truth = {
            "lat_deg": recs.column("truth_lat_deg"),
            "lon_deg": recs.column("truth_lon_deg"),
            "h_m": recs.column("truth_h_m") if recs.has("truth_h_m") else ground.h,
            "error_m": res.error_to_truth_m,
            "has_h": recs.has("truth_h_m"),
        }
    if recs.has("paper_lat_deg") and recs.has("paper_lon_deg"):
        published = {
            "lat_deg": recs.column("paper_lat_deg"),
            "lon_deg": recs.column("paper_lon_deg"),
            "error_m": res.error_to_paper_m,
            "h_m": recs.column("paper_height_m") if recs.has("paper_height_m") else ground.h,
        }
    return truth, published


def _flight_origins(recs, group_column: str | None, lat_deg, lon_deg, h_m) -> tuple:
    """The records' flights (the ``group_column``'s values, None for one flight or no such column),
    each flight's scene origin at its first finite reference position, and the first origin."""
    grp = None
    if group_column is not None and group_column in recs.header:
        grp = np.array(recs.text(group_column), dtype=object)
    enus: dict[str, EnuFrame] | None = None
    if grp is not None:
        enus = {}
        for g in dict.fromkeys(grp.tolist()):
            m = grp == g
            enus[g] = enu_origin(*_first_finite(lat_deg[m], lon_deg[m], np.broadcast_to(h_m, m.shape)[m]))
        if len(enus) == 1:
            grp, enus = None, None
    enu = next(iter(enus.values())) if enus else enu_origin(*_first_finite(lat_deg, lon_deg, h_m))
    return grp, enus, enu


def _targets_surface(steps: LogSteps, h, n: int, method: str, height_kind: str, eps_h_m, threshold_m):
    """The surface the records' targets lie on, for the per-flight fit: the DEM the steps were
    located on, else the per-record heights (as ``geoloc calibrate``'s ``--height-column``)."""
    from geoloc.surfaces.terrain import surface_for

    terrain = steps.terrain  # a dem_path was given: the steps were located on it
    options: SolverOptions = solver_options(eps_h_m, threshold_m) if terrain is not None else {}
    return surface_for(
        None if terrain is not None else np.broadcast_to(np.asarray(h, float), (n,)),
        terrain.dem if terrain is not None else None,
        method=method,
        kind=height_kind,
        per_record=True,
        **options,
    )


#: Parameters :func:`sensor_fit_series` fits by default (the sensor's mounting rotation).
DEFAULT_FIT_NAMES = ("mount_x", "mount_y", "mount_z")


def add_error_analysis(steps: LogSteps, heading_deg=None, outlier=None) -> LogSteps:
    """Fill ``components``, ``reference`` and ``outlier`` of ``steps`` (see the module docstring).

    The reference is the truth when there is one, else the published position;
    its height is used only where it is known (a truth without ``truth_h_m``
    gives horizontal components only). ``outlier``: flags to use instead of the
    per-flight :func:`geoloc.analysis.accuracy.robust_outliers` of the horizontal error.
    """
    from geoloc.analysis.accuracy import (
        error_components,
        robust_outliers,
        track_azimuth_rad,
    )

    ref, name = (steps.truth, "truth") if steps.truth is not None else (steps.published, "published")
    if ref is None:
        return steps
    n = len(steps)
    ac_lat = np.rad2deg(np.broadcast_to(steps.pose.lat, (n,)))
    ac_lon = np.rad2deg(np.broadcast_to(steps.pose.lon, (n,)))
    heading = np.deg2rad(heading_deg) if heading_deg is not None else np.broadcast_to(steps.pose.heading, (n,))
    track = track_azimuth_rad(ac_lat, ac_lon, steps.group_of, heading)
    ref_h = ref["h_m"] if ref.get("has_h", True) else np.full(n, np.nan)
    comp = error_components(
        steps.ground.lat_deg,
        steps.ground.lon_deg,
        steps.ground.h,
        ref["lat_deg"],
        ref["lon_deg"],
        ref_h,
        track_heading_rad=track,
    )
    comp["track_rad"] = track
    steps.components, steps.reference = comp, name
    if outlier is None:
        outlier = np.zeros(n, bool)
        grp = steps.group_of
        for g in steps.groups:
            m = grp == g
            outlier[m] = robust_outliers(comp["horizontal_m"][m])
    steps.outlier = np.asarray(outlier, bool)
    return steps


def sensor_fit_series(steps: LogSteps, recs, names, surface, group_column: str | None = None) -> dict:
    """Errors to truth before and after the per-flight fit of ``names`` (:func:`geoloc.analysis.sensor_fit.fit_sensor_groups`).

    ``surface``: where the targets lie (a :class:`geoloc.surfaces.terrain.DemSurface`, a
    height surface, per-record heights), the one the steps were located on. Each
    flight's records are located again with its fitted sensor on that surface, exactly
    as ``fit_sensor_groups`` measures them: ``after_m`` is the horizontal geodesic
    distance to the truth (:func:`geoloc.geodesy.geodesic.horizontal_distance_m`), and
    ``after_along_m`` / ``after_across_m`` the components of
    :func:`geoloc.analysis.accuracy.error_components` along the same track as before.
    ``before_m`` is the same distance for the nominal sensor (the ``to_truth_m`` series).
    """
    from geoloc.analysis.accuracy import error_components
    from geoloc.analysis.sensor_fit import fit_sensor_groups

    truth, components = steps.truth, steps.components
    if truth is None:
        raise ValueError(f"{steps.name}: the fit's errors need a surveyed truth (truth_lat_deg, truth_lon_deg)")
    if components is None:
        raise ValueError(f"{steps.name}: no error components to follow the track (add_error_analysis first)")
    sensor = steps.camera
    report, sensors = fit_sensor_groups(recs, sensor, names, surface, group_column=group_column)
    from geoloc.surfaces.height import for_records

    surf = partial(for_records, surface)
    n = len(steps)
    grp = steps.group_of
    after = {k: np.full(n, np.nan) for k in ("after_m", "after_along_m", "after_across_m")}
    tlat, tlon = np.asarray(truth["lat_deg"], float), np.asarray(truth["lon_deg"], float)
    rep_groups = list(report["groups"])
    for g, rg in zip(steps.groups, rep_groups):
        idx = np.flatnonzero(grp == g)
        los = line_of_sight(steps.pose.take(idx), sensors[rg], steps.row[idx], steps.col[idx], outside="extrapolate")
        gp = Pipeline(sensors[rg], surf(idx)).intersect(los)
        lat, lon = np.rad2deg(gp.lat), np.rad2deg(gp.lon)
        after["after_m"][idx] = horizontal_distance_m(lat, lon, tlat[idx], tlon[idx])
        c = error_components(
            lat, lon, gp.h, tlat[idx], tlon[idx], np.nan, track_heading_rad=components["track_rad"][idx]
        )
        after["after_along_m"][idx] = c["along_m"]
        after["after_across_m"][idx] = c["across_m"]
    bad = ~np.isfinite(after["after_m"])
    means = ", ".join(
        f"{g} {report['groups'][rg]['mean_error_before_m']:.1f} -> {report['groups'][rg]['mean_error_after_m']:.1f} m"
        for g, rg in zip(steps.groups, rep_groups)
    )
    where = "on the DEM" if terrain_of(surface) is not None else "at the target heights"
    note = (
        f"calibration: {', '.join(names)} fitted per flight (fit_sensor_groups, in-sample, {where}): "
        f"mean error to truth {means}"
        + (f"; {int(bad.sum())} record(s) without a ground point after" if np.any(bad) else "")
    )
    steps.notes.append(note)
    return {
        "before_m": np.asarray(truth["error_m"], float).copy(),
        **after,
        "note": note,
        "report": report,
        "names": list(names),
    }


def steps_from_klv(
    path,
    camera=None,
    *,
    dem_path=None,
    dem_datum: str = "egm96",
    method: str = "exact",
    eps_h_m=None,
    threshold_m=None,
    label: str | None = None,
    video=None,
    enu=None,
    t0_s: float | None = None,
    outlier=None,
    dem=None,
    first_packet: int = 0,
    corrections: Corrections = NO_CORRECTIONS,
) -> tuple[LogSteps, list]:
    """A MISB ST 0601 file replayed (:func:`geoloc.workflows.klv_replay.replay_klv`): one step per packet.

    ``method``, ``eps_h_m`` and ``threshold_m`` are the DEM solver and its tolerances, as
    for the records path (``geoloc log --method``). ``path`` may also be the results of a
    read (:class:`geoloc.io.klv.Packet` / ``KlvError``, e.g. received live), named ``label``;
    ``video`` is then the MPEG-TS whose pictures to attach (a live session's ``--record``).
    A live recording logs batch after batch on one scene and clock: ``enu`` (the scene origin),
    ``t0_s`` (the precision time stamp of the ``time`` timeline's zero), ``outlier`` (a function
    of the batch's frame-centre residuals giving its causal flags) and ``first_packet`` (the
    batch's first packet number on the session's ``packet`` timeline) are then given, and ``dem``
    (already open) for ``dem_path``.

    The recomputed frame centre is the target; the packet's own frame centre is the
    "published" position, so ``series/error/to_published_m`` is the frame-centre
    residual; the corner residual and the outlier flags are series too. Timelines:
    ``time`` (the precision time stamp, seconds from the first packet) and ``packet``.

    Returns
    -------
    LogSteps, list of KlvError
    """
    from geoloc.workflows.klv_replay import klv_pose, replay_klv

    surface, dem = _klv_surface(dem_path, dem_datum, method, eps_h_m, threshold_m, dem)
    r = replay_klv(path, surface=surface, sensor=camera, label=label, corrections=corrections)
    c = r.columns
    if len(r) == 0:
        raise ValueError(f"{label or path}: no good packet ({len(r.errors)} bad)")
    pose, sensor, n = klv_pose(c), r.sensor, len(r)
    row, col = np.full(n, (sensor.rows + 1) / 2), np.full(n, (sensor.cols + 1) / 2)
    los = sensor.line_of_sight(row, col, pose)
    ground = _klv_ground(c, los, corrections)
    _live_batch(c, outlier, first_packet)
    name = label or Path(path).name
    notes = [
        f"MISB ST 0601: {name}, {n} packets ({len(r.errors)} bad, skipped)",
        "published = the packet's own frame centre (tags 23-25 / 78); target = recomputed",
        f"outliers flagged: {int(np.sum(c['outlier']))}",
    ]
    steps = LogSteps(
        "klv",
        name,
        {"time": ("duration", _klv_time(c, t0_s, n)), "packet": ("sequence", np.asarray(c["packet"]))},
        [f"packet {k}" for k in c["packet"]],
        sensor,
        pose,
        sensor.frames(pose),
        row,
        col,
        los,
        ground,
        enu if enu is not None else _origin_at_ground(ground),
        published={k: np.asarray(c[v], float) for k, v in _KLV_PUBLISHED.items()},
        terrain=_klv_terrain(dem, dem_path, dem_datum, method, n, notes),
        notes=notes,
        extra_series={k: np.asarray(c[v], float) for k, v in _KLV_SERIES.items()},
        corners={key: _klv_corners(c, key) for key in ("lat_deg", "lon_deg", "h_m")},
    )
    # the replay's own flags (the same median / MAD rule, on its geodesic frame-centre residual)
    _analysed(steps, corrections, np.asarray(c["platform_heading_deg"], float), np.asarray(c["outlier"]).astype(bool))
    _attach_klv_pictures(steps, path if video is None and isinstance(path, (str, os.PathLike)) else video, c)
    return steps, list(r.errors)


#: The published position of a KLV step: the packet's own frame centre (LogSteps.published's key -> column).
_KLV_PUBLISHED = {
    "lat_deg": "reported_lat_deg",
    "lon_deg": "reported_lon_deg",
    "h_m": "reported_h_m",
    "error_m": "frame_center_error_m",
}


#: The further series of a KLV step (entity path -> column): the corner residual and the outlier flags.
_KLV_SERIES = {"series/klv/corner_error_m": "corner_error_m", "series/klv/outlier": "outlier"}


def _live_batch(c: dict, outlier, first_packet: int) -> None:
    """A live session's batch in the session's terms: ``outlier`` (a function of the batch's
    frame-centre residuals) gives its causal flags, and its packets are numbered from ``first_packet``."""
    if outlier is not None:
        c["outlier"] = np.asarray(outlier(np.asarray(c["frame_center_error_m"], float)), np.int64)
    if first_packet:
        c["packet"] = np.asarray(c["packet"], np.int64) + int(first_packet)


def _klv_corners(c: dict, key: str) -> np.ndarray:
    """The replay's four recomputed frame corners' ``key`` (``lat_deg``, ``lon_deg``, ``h_m``), (n, 4)."""
    return np.stack([np.asarray(c[f"corner{j + 1}_{key}"], float) for j in range(4)], axis=-1)


def _klv_surface(dem_path, dem_datum: str, method: str, eps_h_m, threshold_m, dem):
    """One surface for every ray (frame centres and corners), built as the core builds it:
    ``SurfaceSpec(...).build()``, or for a DEM already open (a live session's) the same
    :func:`geoloc.surfaces.terrain.surface_for`; None without a DEM. Returns (surface, dem)."""
    from geoloc.surfaces.terrain import surface_for

    spec = SurfaceSpec(
        dem=dem_path,
        dem_datum=dem_datum,
        method=method,
        eps_h=None if eps_h_m is None else float(eps_h_m),
        threshold=None if threshold_m is None else float(threshold_m),
    )
    if dem is not None:
        return surface_for(dem=dem, method=method, **spec.solver_options), dem
    if dem_path is not None:
        surface = spec.build()
        return surface, terrain_of(surface)  # the raster drawn as the mesh (one raster: the CLI refuses a mosaic)
    return None, None


def _klv_ground(c: dict, los: LineOfSight, corrections: Corrections) -> GroundPoint:
    """The replay's recomputed frame centres (its columns) as the steps' ground points."""
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    lat, lon = (np.deg2rad(np.asarray(c[k], float)) for k in ("lat_deg", "lon_deg"))
    h = np.asarray(c["h_m"], float)
    return GroundPoint(
        lat,
        lon,
        h,
        geodetic_to_ecef(lat, lon, h),
        np.asarray(c["range_m"], float),
        np.asarray(c["status"], np.uint8),
        los,
        corrections=corrections.names,
        refraction_m=np.asarray(c["refraction_m"], float) if "refraction_m" in c else None,
    )


def _klv_time(c: dict, t0_s: float | None, n: int) -> np.ndarray:
    """The ``time`` timeline [s]: the precision time stamps from ``t0_s``, else from the first
    packet (the packet index where no packet has a time stamp)."""
    t = np.asarray(c["time_s"], float)
    if t0_s is not None:
        return t - float(t0_s)
    return t - np.nanmin(t) if np.any(np.isfinite(t)) else np.arange(n, dtype=float)


def _klv_terrain(dem, dem_path, dem_datum: str, method: str, n: int, notes: list) -> TerrainSteps | None:
    """The DEM drawn as a mesh (the replay's solver keeps no per-ray trace), and the note saying
    where the frame centres and corners were located."""
    if dem is None:
        notes.append("no DEM: each packet located at its own frame-centre height (geodetic)")
        return None
    terrain = _mesh_terrain(dem, getattr(dem, "path", dem_path), n)
    notes.append(
        f"frame centres and corners located on {Path(str(terrain.dem_path)).name} "
        f"(heights {getattr(dem, 'datum', dem_datum)}) by '{method}'"
    )
    return terrain


def _attach_klv_pictures(steps: LogSteps, video, c: dict) -> None:
    """Each packet's picture from ``video`` (an MPEG-TS; None: no pictures) with the packet's
    fields of view (:func:`attach_klv_video`)."""
    if video is None:
        return
    fov_deg = np.stack(
        [np.asarray(c["sensor_horizontal_fov_deg"], float), np.asarray(c["sensor_vertical_fov_deg"], float)], -1
    )
    attach_klv_video(steps, video, np.asarray(c["packet"]), fov_deg)


def klv_default_dem(path):
    """A bundled DEM covering a KLV file's scene (``None`` if none): the DEM ``geoloc view`` would
    draw for it (:func:`geoloc_viz.terrain_link.default_dem_path` at the median reported frame
    centre, else the median sensor position)."""
    from geoloc.workflows.klv_replay import read_klv
    from geoloc_viz.terrain_link import default_dem_path

    c = read_klv(path).columns
    for la, lo in (
        ("frame_center_latitude_deg", "frame_center_longitude_deg"),
        ("sensor_latitude_deg", "sensor_longitude_deg"),
    ):
        lat, lon = (np.asarray(c.get(k, []), float) for k in (la, lo))
        ok = np.isfinite(lat) & np.isfinite(lon) if lat.shape == lon.shape else np.zeros(0, bool)
        if ok.any():
            return default_dem_path(float(np.median(lat[ok])), float(np.median(lon[ok])))
    return None


def records_default_dem(path, camera=None):
    """A bundled DEM covering a records file's targets when the file gives no target height
    (no ``paper_height_m`` column), else ``None``: the DEM ``geoloc view`` draws for it
    (:func:`geoloc_viz.terrain_link.default_dem_path` at the median surveyed target, else the
    median aircraft position)."""
    from geoloc_viz.terrain_link import default_dem_path

    camera = as_sensor(camera if camera is not None else load_camera())
    recs = load_records(path, angles=camera.angle_names)
    if len(recs) == 0 or recs.has("paper_height_m"):
        return None
    for la, lo in (("truth_lat_deg", "truth_lon_deg"), ("ac_lat_deg", "ac_lon_deg")):
        if recs.has(la) and recs.has(lo):
            lat, lon = recs.column(la), recs.column(lo)
            ok = np.isfinite(lat) & np.isfinite(lon)
            if ok.any():
                return default_dem_path(float(np.median(lat[ok])), float(np.median(lon[ok])))
    return None


def attach_klv_video(steps: LogSteps, path, packets, fov_deg) -> bool:
    """Give a KLV recording its pictures: the video of the MPEG-TS ``path`` itself, or of the
    ``.ts`` beside a ``.klv`` (STANAG 4609: video + KLV data stream), each step (packet number
    ``packets[k]``) showing the frame nearest its packet's container time stamp. False (nothing
    attached) without such a video."""
    from geoloc.io.images import open_images
    from geoloc.workflows.klv_replay import read_klv

    p = Path(path)
    ts = p if p.suffix.lower() != ".klv" else p.with_suffix(".ts")
    if not ts.is_file():
        return False
    try:
        images = open_images(ts)
        len(images)
    except ValueError:  # a KLV-only transport stream
        return False
    r = read_klv(ts)
    pts = {int(k): float(t) for k, t in zip(r.packet, r.pts_s)}
    idx = np.full(len(steps), -1, np.int64)
    for k, pk in enumerate(packets):
        t = pts.get(int(pk), np.nan)
        if np.isfinite(t):
            idx[k] = images.index_at(t)
    steps.images, steps.image_index, steps.image_fov_deg = images, idx, np.asarray(fov_deg, float)
    return bool(np.any(idx >= 0))
