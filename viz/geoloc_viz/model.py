"""What the geolocation scene shows, computed by the core (no geometry here).

:func:`compute` takes the editable inputs (pose, pixel, method) of a
:class:`Scenario` and calls the core (:mod:`geoloc.frames.chain`, :mod:`geoloc.locate`,
:mod:`geoloc.frames.enu`, and :mod:`geoloc.surfaces.terrain` / :mod:`geoloc.surfaces.dem` when a DEM is
loaded) to get every point, frame and iteration, expressed in the scene's local
ENU frame. The viewer only draws these numbers; the tests compare the scene
nodes to independent core calls.

Conventions: ``docs/conventions.md`` (degrees only in :class:`Inputs`, the edge).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.frames.enu import EnuFrame
from geoloc.frames.graph import BoundFrames
from geoloc.locate import as_sensor, line_of_sight  # as_sensor: Scenario's entrance
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.frame import FrameSensor
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint
from geoloc.surfaces.height import HeightSurface
from geoloc_viz.terrain_link import BentRay, IterationView


def drawn_frames(sensor) -> tuple:
    """Frames drawn at the aircraft: the sensor's graph without ECEF (the Earth's centre:
    only in the teaching panel)."""
    return tuple(f for f in sensor.frames().frames if f != "ecef")


@dataclass
class Inputs:
    """The editable inputs of the geolocation scene (degrees and metres: the GUI edge)."""

    lat_deg: float
    lon_deg: float
    h_m: float
    heading_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    gimbal_roll_deg: float = 0.0
    gimbal_pitch_deg: float = 0.0
    row: float = 1162.0
    col: float = 1146.5
    method: str = "bisect"
    eps_h: float = 20.0
    threshold: float = 1.0
    target_h: float = 0.0  # used when the scenario has no DEM
    angles_deg: dict = field(default_factory=dict)  # other joint angles by name (azimuth, ...)

    def pose(self) -> Pose:
        return Pose.from_deg(
            self.lat_deg,
            self.lon_deg,
            self.h_m,
            self.heading_deg,
            self.pitch_deg,
            self.roll_deg,
            self.gimbal_roll_deg,
            self.gimbal_pitch_deg,
            angles_deg=self.angles_deg,
        )

    def replace(self, **kw) -> "Inputs":
        return dataclasses.replace(self, **kw)


@dataclass
class RecordInfo:
    """One flight-test record's reference positions (degrees, metres)."""

    label: str
    paper_lat_deg: float = np.nan
    paper_lon_deg: float = np.nan
    paper_height_m: float = np.nan
    truth_lat_deg: float = np.nan
    truth_lon_deg: float = np.nan
    paper_error_m: float = np.nan


@dataclass
class FrameView:
    """A frame of the chain in the scene: origin (ENU, m) and R_enu_frame."""

    name: str
    origin_enu: np.ndarray
    R_enu_frame: np.ndarray


@dataclass
class Geometry:
    """Everything the geolocation scene draws, in the scene's ENU frame [m]."""

    chain: BoundFrames
    frames: dict
    aircraft_enu: np.ndarray
    R_enu_body: np.ndarray
    los_dir_enu: np.ndarray
    hit: GroundPoint  # the chosen method's answer (or the hit at the target height)
    hit_enu: np.ndarray
    hit_label: str
    hmax: float | None = None
    hit_hmax_enu: np.ndarray | None = None
    exact_enu: np.ndarray | None = None
    iterations: IterationView | None = None
    footprint_enu: np.ndarray | None = None  # (4, 3) image corners on the ground
    published_enu: np.ndarray | None = None
    surveyed_enu: np.ndarray | None = None
    status: int = Status.OK
    message: str = ""
    terrain_result: object = None
    #: With refraction (``Scenario.corrections``): the straight line of sight's own hit on the
    #: surface (the raw hit, where the yellow line ends) and the bent ray (:class:`BentRay`).
    raw_hit_enu: np.ndarray | None = None
    bent: BentRay | None = None


@dataclass
class Scenario:
    """A scene's fixed data: sensor (or first-phase camera), records, DEM, ENU origin, initial inputs."""

    name: str
    camera: FrameSensor  # a sensor file's or a camera file's (sensor_file.load_sensor)
    inputs: Inputs
    enu: EnuFrame
    records: list = field(default_factory=list)  # list of (RecordInfo, Inputs)
    record_index: int | None = None
    dem: object = None
    dem_name: str = ""
    dem_datum: str = "egm96"  # vertical datum of the DEM file's heights (bundled DEMs: EGM96)
    use_dem: bool = True
    description: str = ""
    source: str = ""  # records file name, for the title
    budget: object = None  # the sensor's error budget (geoloc.sensors.budget.ErrorBudget), if known
    #: (n, 2) each record's horizontal and vertical field of view [deg] for a zooming sensor (a KLV
    #: flight's tags 16, 17: the footprints and pictures follow the zoom); None: the sensor's own
    frame_fov_deg: np.ndarray | None = None
    #: (n,) each record's time stamp on its video's clock [s] (a KLV flight's packet times), NaN
    #: where unknown; None: no video
    record_times_s: np.ndarray | None = None
    #: surveyed targets painted in the video, [(name, lat_deg, lon_deg, h_m)] (heights ellipsoidal,
    #: WGS 84; NaN: on the DEM); None: none
    targets: list | None = None
    #: which pixel grid the records and the sensor are in, in words (:func:`use_image_grid`: a
    #: video's own); None: the sensor file's
    pixel_grid: str | None = None
    #: The line-of-sight corrections every located point of the scene goes through (the pipeline's;
    #: ``geoloc view --refraction``, the "Refraction" folder): refraction off by default
    corrections: Corrections = NO_CORRECTIONS
    #: (n, 3) each record's platform velocity, north-east-down [m/s], NaN where unknown (a KLV
    #: flight's: the KLV replay's, geoloc.workflows.klv_replay.platform_velocity_ned); None: no velocity
    record_velocity_ned: object = None
    #: The DEM the user named (``geoloc view --dem``; None: a bundled one near the origin), kept
    #: when another record is selected (:func:`geoloc_viz.scenario.select_record`)
    _user_dem: str | os.PathLike[str] | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        # the viewer's one entrance for a sensor: a first-phase Camera built in Python becomes its
        # FrameSensor here, so everything downstream holds a Sensor (docs/architecture.md)
        self.camera = as_sensor(self.camera)


def frame_views(chain: BoundFrames, enu: EnuFrame) -> dict:
    """Each drawn frame's origin and orientation in ENU, from ``chain.T_ecef(frame)``."""
    out = {}
    for name in chain.graph.frames[1:]:
        T = chain.T_ecef(name)
        out[name] = FrameView(name, enu.from_ecef(T[:3, 3]), enu.R_enu_from(T[:3, :3]))
    return out


def _corner_footprint(pose, camera, enu, h):
    s = camera
    rows = np.array([0.5, 0.5, s.rows + 0.5, s.rows + 0.5])
    cols = np.array([0.5, s.cols + 0.5, s.cols + 0.5, 0.5])
    g = Pipeline(as_sensor(camera), HeightSurface(h)).intersect(line_of_sight(pose, camera, rows, cols))
    return enu.from_ecef(g.ecef)


def compute(scn: Scenario, inp: Inputs) -> Geometry:
    """Run the core for the current inputs and express the result in the scene's ENU frame.

    Raises
    ------
    ValueError
        Naming the field and value when an input is out of range (the GUI shows it).
    """
    pose = inp.pose().validate()
    cam = scn.camera
    # The sensor's own graph: mount, boresight, lever arm and whatever joints it has
    # (the first-phase viewer built FrameChain(pose) here and lost the mount).
    chain = cam.frames(pose)
    enu = scn.enu
    frames = frame_views(chain, enu)
    # A pixel off the sensor is drawn (the ray extends the lens model) and flagged below.
    los = line_of_sight(pose, cam, inp.row, inp.col, outside="extrapolate")
    aircraft = enu.from_ecef(los.origin_ecef)
    d_enu = enu.vector_from_ecef(los.direction_ecef)
    geo = dict(
        chain=chain, frames=frames, aircraft_enu=aircraft, R_enu_body=frames["body"].R_enu_frame, los_dir_enu=d_enu
    )
    from geoloc_viz import terrain_link

    # the height-or-DEM choice: surfaces.terrain.surface_for, through terrain_link.scene_surface
    geo.update(terrain_link.hit_geometry(scn, inp, los))
    g = Geometry(**geo)
    g.status = int(g.hit.status)
    sensor = cam
    if g.status == Status.OK and not bool(sensor.in_image(inp.row, inp.col)):
        g.status = int(Status.OUTSIDE_SENSOR)
        g.message = (
            f"**pixel outside the sensor**: row {inp.row:g}, column {inp.col:g} "
            f"(the sensor has rows 1-{sensor.rows}, columns 1-{sensor.cols}); "
            "the line of sight extends the lens model beyond its edge. " + g.message
        )
    if g.status in (Status.OK, Status.OUTSIDE_SENSOR):
        g.footprint_enu = _corner_footprint(pose, cam, enu, float(g.hit.h))
    if scn.record_index is not None:
        info = scn.records[scn.record_index][0]
        if np.isfinite(info.paper_lat_deg):
            g.published_enu = enu.from_geodetic(
                np.deg2rad(info.paper_lat_deg), np.deg2rad(info.paper_lon_deg), info.paper_height_m
            )
        if np.isfinite(info.truth_lat_deg):
            h_truth = info.paper_height_m
            if scn.dem is not None:
                from geoloc_viz import terrain_link

                h_truth = terrain_link.dem_height(scn.dem, info.truth_lat_deg, info.truth_lon_deg)
            g.surveyed_enu = enu.from_geodetic(np.deg2rad(info.truth_lat_deg), np.deg2rad(info.truth_lon_deg), h_truth)
    return g


def T_enu_frame(g: Geometry, name: str) -> np.ndarray:
    """4x4 of a drawn frame in the scene (ENU), for tests and the teaching panel."""
    f = g.frames[name]
    return rot.transform(f.R_enu_frame, f.origin_enu)


# --------------------------------------------------------------------------- one numbering, one grid


def frame_time_s(scn, idx) -> float:
    """Record ``idx``'s time [s] on the stream's clock (``scn.record_times_s``: a video's PTS of
    its KLV packet), NaN when the scenario has no times."""
    times = getattr(scn, "record_times_s", None)
    if times is None or idx is None or not 0 <= int(idx) < len(times):
        return float("nan")
    return float(times[int(idx)])


def frame_name(scn, idx, *, of: bool = True) -> str:
    """The one name of record ``idx`` on every panel, the picture, the report and the exports: its
    0-based **frame index** (the timeline's), the time beside it and the record's own label, e.g.
    ``frame 202 of 0 .. 297 (t 203.00 s, packet 203)``; ``of=False`` drops the range."""
    if idx is None:
        return "custom pose (no frame)"
    idx = int(idx)
    label = str(scn.records[idx][0].label) if 0 <= idx < len(scn.records) else ""
    extra = []
    t = frame_time_s(scn, idx)
    if np.isfinite(t):
        extra.append(f"t {t:.2f} s")
    if label and label != str(idx):
        extra.append(label)
    text = f"frame {idx}" + (f" of 0 .. {len(scn.records) - 1}" if of else "")
    return text + (f" ({', '.join(extra)})" if extra else "")


def pixel_to_grid(rc, from_size: int, to_size: int):
    """A 1-based pixel coordinate of a ``from_size`` axis in the grid of the same image resampled
    to ``to_size`` pixels: the image's edges (0.5 and size + 0.5, docs/conventions.md "Pixels")
    map onto each other, ``rc' - 0.5 = (rc - 0.5) * to / from`` (the rule of
    :func:`geoloc.io.photos.scale_lens` for the principal point)."""
    return 0.5 + (np.asarray(rc, float) - 0.5) * (float(to_size) / float(from_size))


def sensor_in_grid(sensor: FrameSensor, rows: int, cols: int) -> FrameSensor:
    """``sensor`` on a ``rows`` x ``cols`` grid: its lens resampled
    (:func:`geoloc.io.photos.scale_lens`: the same rays through the same image edges)."""
    from geoloc.io.photos import scale_lens

    if (sensor.rows, sensor.cols) == (int(rows), int(cols)):
        return sensor
    return dataclasses.replace(sensor, lens=scale_lens(sensor.lens, int(cols), int(rows)))


def records_in_grid(records, from_rc: tuple, to_rc: tuple) -> list:
    """Records ``[(info, Inputs)]`` whose pixels are on a ``from_rc`` (rows, cols) grid, moved to the
    ``to_rc`` grid of the same image (:func:`pixel_to_grid` per axis); new Inputs, the same infos."""
    (r0, c0), (r1, c1) = from_rc, to_rc
    return [
        (info, inp.replace(row=float(pixel_to_grid(inp.row, r0, r1)), col=float(pixel_to_grid(inp.col, c0, c1))))
        for info, inp in records
    ]


def use_image_grid(scn, rows: int, cols: int) -> bool:
    """Put the scenario's pixels in the grid of its images (``rows`` x ``cols``), once, at load.

    A MISB ST 0601 stream names no image size, so its sensor is made on a nominal 1920 x 1080 grid
    (:func:`geoloc.workflows.klv_replay.klv_sensor`) while its video is, e.g., 640 x 360. Here the
    sensor's lens is resampled to the video's size (:func:`geoloc.io.photos.scale_lens`: the same
    rays) and every record's pixel moved to that grid (:func:`pixel_to_grid`), so the inputs, the
    teaching ray, the footprints, the picture and the exported commands all speak the image's own
    pixels. ``scn.pixel_grid`` says what was done. False when the grids already agree."""
    cam = scn.camera
    rows, cols = int(rows), int(cols)
    if (cam.rows, cam.cols) == (rows, cols):
        scn.pixel_grid = f"the image's own grid, {cols} x {rows} px"
        return False
    r0, c0 = cam.rows, cam.cols
    scn.camera = sensor_in_grid(cam, rows, cols)
    recs = records_in_grid(scn.records, (r0, c0), (rows, cols))
    scn.records = recs
    if scn.record_index is not None:
        scn.inputs = recs[scn.record_index][1].replace()
    else:
        scn.inputs = scn.inputs.replace(
            row=float(pixel_to_grid(scn.inputs.row, r0, rows)), col=float(pixel_to_grid(scn.inputs.col, c0, cols))
        )
    scn.pixel_grid = (
        f"the image's own grid, {cols} x {rows} px (the sensor's nominal {c0} x {r0} converted once, at load)"
    )
    return True
