"""Send a picked point on (to another tool or person): its texts, computed by the core (no viser here).

A point picked in the viewer (a pixel of the picture, a terrain click in the scene, or without
a picture the scene's own pixel) becomes a :class:`SharedPoint`, and :mod:`geoloc_viz.share_layer`
shows it as texts to copy:

* :func:`mgrs_of`: its MGRS reference (:func:`geoloc.io.mgrs_grid.latlon_to_mgrs`, 1 m);
* :func:`latlon_text`: latitude, longitude and the height with its datum (ellipsoidal, WGS 84,
  and above EGM96 beside it);
* :func:`locate_args`: a ``geoloc locate`` command line that reproduces the point: the pose, the
  joint angles by the sensor's own names, the pixel, the frame's sensor written to a sensor file
  (:func:`geoloc.sensors.sensor_file.sensor_to_toml`), and the surface (``--dem`` with its datum
  and the method, step and threshold, or ``--target-h-m``); every number as Python's ``repr``, so
  the command's floats are the viewer's;
* :func:`cot_event`: a Cursor-on-Target event (:func:`geoloc.io.cot.cot_events`: ``ce`` / ``le``
  one sigma, from the predicted CE90 / LE90 when known);
* :func:`field_of_view_deg`: the sensor's horizontal and vertical field of view from its lens.

Heights are ellipsoidal (WGS 84) throughout; conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING

import numpy as np

from geoloc.io.mgrs_grid import mgrs_column
from geoloc.status import Status
from geoloc.pipeline import NO_CORRECTIONS
from geoloc.sensors.base import Sensor

if TYPE_CHECKING:  # the model imports the viewer's layers; its type is enough here
    from geoloc_viz.model import Inputs

#: The datum of every height of a shared point.
H_DATUM = "ellipsoidal, WGS 84"


@dataclass
class SharedPoint:
    """A point to send on, with what reproduces it (degrees, metres: the panel's edge)."""

    what: str  # "picked pixel", "terrain pick", "scene pixel"
    lat_deg: float
    lon_deg: float
    h_m: float  # ellipsoidal, WGS 84
    row: float  # the pixel whose line of sight reaches it (1-based centres); NaN if none
    col: float
    sensor: Sensor  # the frame's sensor
    inputs: Inputs  # the pose
    method: str  # the DEM method of the surface ("exact" for a terrain pick); ignored without a DEM
    label: str  # the record (or "custom pose")
    reproducible: bool = True  # a pixel of this frame sees the point (a hidden terrain pick: False)
    note: str = ""  # why not reproducible
    ce90_m: float = float("nan")
    le90_m: float = float("nan")


def field_of_view_deg(sensor, pose) -> tuple[float, float]:
    """(horizontal, vertical) field of view [deg] of ``sensor``'s lens: the angle between the lines
    of sight through the outer edges of the image (columns 0.5 and N + 0.5 on the middle row; rows
    0.5 and M + 0.5 on the middle column). Independent of the pose (one rigid rotation of all rays)."""
    M, N = sensor.rows, sensor.cols
    rr = np.array([(M + 1) / 2, (M + 1) / 2, 0.5, M + 0.5])
    cc = np.array([0.5, N + 0.5, (N + 1) / 2, (N + 1) / 2])
    d = np.asarray(sensor.line_of_sight(rr, cc, pose, outside="extrapolate").direction_ecef, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ang = [math.degrees(math.atan2(np.linalg.norm(np.cross(d[i], d[i + 1])), float(d[i] @ d[i + 1]))) for i in (0, 2)]
    return ang[0], ang[1]


def mgrs_of(p: SharedPoint) -> str:
    """The point's MGRS reference at 1 m (``''`` where it has none)."""
    return mgrs_column([p.lat_deg], [p.lon_deg], 5)[0]


def latlon_text(p: SharedPoint) -> str:
    """``lat, lon`` to 1e-8 deg (1 mm), the height with its datum, and above EGM96."""
    from geoloc.geodesy.geoid import egm96_undulation

    n = float(egm96_undulation(math.radians(p.lat_deg), math.radians(p.lon_deg)))
    return f"{p.lat_deg:.8f}, {p.lon_deg:.8f}, h {p.h_m:.3f} m ({H_DATUM}); {p.h_m - n:.3f} m above EGM96 (MSL)"


def _pose_args(sensor, inputs) -> list:
    a = [
        "--lat-deg",
        repr(float(inputs.lat_deg)),
        "--lon-deg",
        repr(float(inputs.lon_deg)),
        "--h-m",
        repr(float(inputs.h_m)),
        "--altitude-datum",
        "ellipsoid",
        "--heading-deg",
        repr(float(inputs.heading_deg)),
        "--pitch-deg",
        repr(float(inputs.pitch_deg)),
        "--roll-deg",
        repr(float(inputs.roll_deg)),
    ]
    for name in sensor.angle_names:  # the sensor's own joints, by the names its gimbal gives them
        if name in ("gimbal_roll", "gimbal_pitch"):
            a += [f"--{name.replace('_', '-')}-deg", repr(float(getattr(inputs, f"{name}_deg")))]
        else:
            a += ["--angle", f"{name}={float(inputs.angles_deg.get(name, 0.0))!r}"]
    return a


def locate_args(scn, p: SharedPoint, sensor_path) -> list:
    """``geoloc locate`` argv (starting ``["geoloc", "locate"]``) that reproduces ``p``: its pose,
    pixel, the sensor file at ``sensor_path`` (the caller writes it) and the scene's surface."""
    a = [
        "geoloc",
        "locate",
        "--sensor",
        str(sensor_path),
        *_pose_args(p.sensor, p.inputs),
        "--row",
        repr(float(p.row)),
        "--col",
        repr(float(p.col)),
    ]
    dem_path = getattr(scn, "_dem_path", None)
    on_dem = scn.dem is not None and (p.what != "terrain pick" or getattr(scn, "use_dem", True))
    if on_dem and dem_path:
        a += ["--dem", str(dem_path), "--dem-datum", str(getattr(scn, "dem_datum", "egm96")), "--method", p.method]
        if p.method == "bisect":
            a += ["--threshold", repr(float(p.inputs.threshold))]
        elif p.method == "steps":
            a += ["--eps-h", repr(float(p.inputs.eps_h))]
    else:
        a += ["--target-h-m", repr(float(p.inputs.target_h))]
    c = getattr(scn, "corrections", None)  # the scene's line-of-sight corrections (the Refraction folder)
    if c is not None and c.refraction is not None:
        a += ["--refraction", "standard"]
    if c is not None and c.light_time:
        a += ["--light-time"]
    return a


def command_text(args) -> str:
    """The argv as one shell line."""
    return shlex.join(args)


def cot_event(p: SharedPoint, *, source: str = "view", now: datetime | None = None) -> str:
    """The point as one Cursor-on-Target event (:func:`geoloc.io.cot.cot_events`)."""
    from geoloc.io.cot import cot_events

    table = {
        "lat_deg": np.array([p.lat_deg]),
        "lon_deg": np.array([p.lon_deg]),
        "h_m": np.array([p.h_m]),
        "h_datum": ["ellipsoid"],
        "ce90_m": np.array([p.ce90_m]),
        "le90_m": np.array([p.le90_m]),
        "record": [f"{p.label} {p.what} row {p.row:.2f} col {p.col:.2f}"],
        "status": ["ok"],
    }
    ev = cot_events(table, source=source, now=now)
    if not ev.events:
        raise ValueError(f"no CoT event: {ev.skipped}")
    return ev.events[0].decode("utf-8")


def predicted_90(scn, p: SharedPoint, surface, velocity=None, budget=None) -> tuple[float, float]:
    """(CE90, LE90) [m] of ``p``'s pixel on ``surface`` (:func:`geoloc.analysis.uncertainty.propagate`
    with the scenario's budget: :func:`geoloc_viz.uncertainty_layer.scenario_budget`); NaN if none."""
    from geoloc.analysis.uncertainty import propagate
    from geoloc_viz.uncertainty_layer import scenario_budget

    if not (np.isfinite(p.row) and np.isfinite(p.col)):
        return float("nan"), float("nan")
    if budget is None:
        budget, _, _ = scenario_budget(scn, p.sensor, velocity is not None)
    pu = propagate(
        p.sensor,
        p.inputs.pose(),
        p.row,
        p.col,
        budget,
        surface=surface,
        outside="extrapolate",
        velocity_ned_m_s=velocity if budget.sigma("time_s") > 0 else None,
        corrections=getattr(scn, "corrections", NO_CORRECTIONS),
    )
    if int(pu.status) != Status.OK:
        return float("nan"), float("nan")
    return float(pu.ce90_m), float(pu.le90_m)
