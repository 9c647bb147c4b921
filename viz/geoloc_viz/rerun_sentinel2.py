"""A rerun recording (``.rrd``) of a Sentinel-2 detector: orbit, attitude, its line of sight sweeping the ground.

The numbers are the core's (:mod:`geoloc.io.sentinel2`, the band and detector's
:class:`geoloc.sensors.pushbroom_inertial.InertialPushbroomSensor` and the location pipeline);
this module lays them out as rerun entities, in ECEF kilometres (the scene is 14 000 km
wide: metres would put the satellite 7 million units from the origin), on the timeline
``time`` (seconds from the detector's first line).

==========================================  =============================================
``world``                                   ECEF, km, Z up to the north pole (``ViewCoordinates`` RFU)
``world/orbit``                             static: the GPS points of the datastrip
``world/satellite``                         Transform3D per step: position, R_ecef_body
``world/satellite/axes``                    the body (piloting) frame's X, Y, Z arrows (100 km)
``world/los``                               per step: the first, middle and last pixel's lines of sight
``world/footprint``                         static: the ground under the first and last pixels over
                                            the whole datastrip, and its first and last lines
``series/attitude/{roll,pitch,yaw}_deg``    the body frame against the orbital frame (b3 to the
                                            centre, b2 right of the Earth-fixed velocity):
                                            yaw shows the yaw steering
``series/ephemeris/altitude_km``            the orbit's geodetic height
``series/ephemeris/speed_km_s``             its Earth-fixed speed
==========================================  =============================================
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.pipeline import Corrections, Pipeline
from geoloc.sensors.pushbroom import R_ecef_orbital
from geoloc.surfaces.height import HeightSurface
from geoloc.userfiles import atomic_path

KM = 1e-3


def detector_steps(sensor, n_steps: int = 60, height_m: float = 0.0):
    """The recording's numbers: per step, time, position, R_ecef_body, the three lines of sight'
    ground points; and the footprint. Returns a dict of arrays (metres, seconds, radians)."""
    rows = np.linspace(1.0, sensor.rows, n_steps)
    t = sensor.line_time(rows)
    p, v = sensor.orbit.state(t)
    R_ecef_body = sensor.earth.R_ecef_in(t) @ sensor._R_in_body(t)
    cols = np.array([1.0, (sensor.cols + 1) / 2, float(sensor.cols)])
    pipe = Pipeline(sensor, HeightSurface(height_m, "geodetic"), Corrections.for_sensor(sensor))
    R, C = np.meshgrid(rows, cols, indexing="ij")
    ground = pipe.locate(R, C).ecef
    fr = np.linspace(1.0, sensor.rows, 200)
    edges = pipe.locate(np.stack([fr, fr], -1), np.broadcast_to([1.0, float(sensor.cols)], (200, 2))).ecef
    R_orb_body = np.swapaxes(R_ecef_orbital(p, v), -1, -2) @ R_ecef_body
    # body = Rx(roll) Ry(pitch) Rz(yaw) orbital, passive (geoloc.sensors.pushbroom.R_zyx): its matrix
    # R_body_orb = R_orb_body^T; the angles from its elements
    M = np.swapaxes(R_orb_body, -1, -2)
    pitch = -np.arcsin(np.clip(M[:, 0, 2], -1, 1))
    roll = np.arctan2(M[:, 1, 2], M[:, 2, 2])
    yaw = np.arctan2(M[:, 0, 1], M[:, 0, 0])
    return {
        "t_s": t - t[0],
        "position": p,
        "velocity": v,
        "R_ecef_body": R_ecef_body,
        "ground": ground,
        "edges": edges,
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
    }


def log_detector(rec: rr.RecordingStream, sensor, n_steps: int = 60) -> dict:
    """Log a detector's recording into ``rec``; returns the numbers logged (:func:`detector_steps`)."""
    s = detector_steps(sensor, n_steps)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    orbit = sensor.orbit.position * KM
    rec.log("world/orbit", rr.LineStrips3D([orbit], colors=[[255, 200, 0]]), static=True)
    e = s["edges"] * KM
    ring = [e[:, 0], e[:, 1], np.stack([e[0, 0], e[0, 1]]), np.stack([e[-1, 0], e[-1, 1]])]
    rec.log("world/footprint", rr.LineStrips3D(ring, colors=[[0, 200, 255]]), static=True)
    height = ecef_to_geodetic(s["position"])[2]
    for k, t in enumerate(s["t_s"]):
        rec.set_time("time", duration=float(t))
        pos = s["position"][k] * KM
        rec.log("world/satellite", rr.Transform3D(translation=pos, mat3x3=s["R_ecef_body"][k]))
        rec.log(
            "world/satellite/axes",
            rr.Arrows3D(vectors=np.eye(3) * 100.0, colors=[[255, 0, 0], [0, 255, 0], [0, 0, 255]]),
        )
        rec.log("world/los", rr.LineStrips3D([[pos, g * KM] for g in s["ground"][k]], colors=[[255, 255, 255]]))
        rec.log("series/attitude/roll_deg", rr.Scalars(np.degrees(s["roll"][k])))
        rec.log("series/attitude/pitch_deg", rr.Scalars(np.degrees(s["pitch"][k])))
        rec.log("series/attitude/yaw_deg", rr.Scalars(np.degrees(s["yaw"][k])))
        rec.log("series/ephemeris/altitude_km", rr.Scalars(height[k] * KM))
        rec.log("series/ephemeris/speed_km_s", rr.Scalars(np.linalg.norm(s["velocity"][k]) * KM))
    return s


def write(sensor, out, n_steps: int = 60) -> dict:
    """Write the recording of ``sensor`` to the ``.rrd`` file ``out`` (a temporary file, then renamed)."""
    rec = rr.RecordingStream("geoloc", recording_id=f"geoloc-sentinel2-{sensor.name}")
    stream = rr.binary_stream(recording=rec)
    s = log_detector(rec, sensor, n_steps)
    rec.flush()
    data = stream.read(flush=True) or b""
    rec.disconnect()
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return s


__all__ = ["detector_steps", "log_detector", "write"]
