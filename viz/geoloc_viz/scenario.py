"""Scenarios for the viewer: the bundled default and user-given records files.

The default scenario (``geoloc view`` with no arguments) is the first [Q17]
flight-test record (``assets/records/qiao2017_flight_tests.csv``, table T3,
point 1, with the fitted camera ``assets/cameras/qiao2017.toml``) over the
bundled terrain of the flight-test area (``assets/dem/``) when it is present,
else over the ellipsoid inflated to the record's ``paper_height_m``.

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geoloc.assets import ASSETS, DEFAULT_CAMERA, DEFAULT_RECORDS
from geoloc.frames.enu import EnuFrame
from geoloc.io.records import load_records
from geoloc.sensors.sensor_file import load_sensor
from geoloc_viz.model import Inputs, RecordInfo, Scenario
from geoloc_viz.terrain_link import default_dem_path  # noqa: F401  (here since phase 1)


def _num(row: dict, key: str) -> float:
    v = row.get(key, "")
    v = v.strip() if isinstance(v, str) else v
    return float(v) if v not in ("", None) else np.nan


def records_from_csv(path, camera=None) -> list:
    """Load a records CSV with :func:`geoloc.io.records.load_records`; return [(RecordInfo, Inputs)].

    The sensor's gimbal names the angle columns (``<angle>_deg``; default the
    [Q17] gimbal's). Bad rows are left out by the loader (their errors are on
    ``Records.errors``).
    """
    names = camera.angle_names if camera is not None else ("gimbal_roll", "gimbal_pitch")
    recs = load_records(path, angles=names)
    out = []
    for label, row in zip(recs.labels(), recs.rows):
        info = RecordInfo(
            label,
            _num(row, "paper_lat_deg"),
            _num(row, "paper_lon_deg"),
            _num(row, "paper_height_m"),
            _num(row, "truth_lat_deg"),
            _num(row, "truth_lon_deg"),
            _num(row, "paper_error_m"),
        )
        target_h = info.paper_height_m if np.isfinite(info.paper_height_m) else 0.0
        inp = Inputs(
            _num(row, "ac_lat_deg"),
            _num(row, "ac_lon_deg"),
            _num(row, "ac_h_m"),
            _num(row, "heading_deg"),
            _num(row, "pitch_deg"),
            _num(row, "roll_deg"),
            _num(row, "gimbal_roll_deg") if "gimbal_roll" in names else 0.0,
            _num(row, "gimbal_pitch_deg") if "gimbal_pitch" in names else 0.0,
            _num(row, "row"),
            _num(row, "col"),
            target_h=target_h,
            angles_deg={a: _num(row, f"{a}_deg") for a in names if a not in ("gimbal_roll", "gimbal_pitch")},
        )
        out.append((info, inp))
    if not out:
        raise ValueError(f"records file {path}: no valid rows ({len(recs.errors)} rejected)")
    return out


#: File suffixes read as MISB ST 0601 KLV (raw or in a video container).
KLV_SUFFIXES = (".klv", ".bin", ".ts", ".mpg", ".mpeg", ".mp4", ".m2ts")


def records_from_klv(path, camera=None):
    """A MISB ST 0601 file as viewer records: one per good packet, its own frame centre as the
    published point. Returns (sensor, [(RecordInfo, Inputs)], velocity): ``velocity`` (n, 3) is
    each record's platform velocity, north-east-down [m/s] (NaN where unknown), as the KLV replay
    takes it for a budget's ``time_s`` (:func:`geoloc.workflows.klv_replay.platform_velocity_ned`:
    tags 79 / 80, else the packets' positions differenced over their time stamps)."""
    from geoloc.workflows.klv_replay import klv_pose_deg, platform_velocity_ned, read_klv, replay_klv

    read = read_klv(path)
    r = replay_klv(read, sensor=camera)  # one row per packet read
    c = r.columns
    out, kept = records_from_columns(c, r.sensor)
    if not out:
        raise ValueError(f"{path}: no packet with a pose and sensor angles")
    pos = np.array(
        [[klv_pose_deg(c, k)[f] for f in ("lat_deg", "lon_deg", "h_m")] for k in range(len(c["packet"]))], float
    ).reshape(-1, 3)
    tag = lambda name: np.asarray(read.columns[name], float) if name in read.columns else None  # noqa: E731
    vel, _ = platform_velocity_ned(
        pos[:, 0],
        pos[:, 1],
        pos[:, 2],
        np.asarray(c["time_s"], float),
        tag("sensor_north_velocity_m_s"),
        tag("sensor_east_velocity_m_s"),
    )
    return r.sensor, out, vel[kept]


def records_from_columns(c, sensor) -> tuple[list, list]:
    """([(RecordInfo, Inputs)], their row indices) of a KLV replay's columns
    (:mod:`geoloc.workflows.klv_replay`, or a live replay's batch): one per packet with a pose and
    sensor angles, labelled ``packet N``."""
    from geoloc.workflows.klv_replay import klv_pose_deg

    out, kept = [], []
    for k in range(len(c["packet"])):

        def v(name):
            x = c[name][k]
            return float(x) if x is not None else np.nan

        info = RecordInfo(
            f"packet {int(c['packet'][k])}",
            v("reported_lat_deg"),
            v("reported_lon_deg"),
            v("reported_h_m"),
            np.nan,
            np.nan,
            v("frame_center_error_m"),
        )
        pose = klv_pose_deg(c, k)
        # ST 0601 headings run 0..360 deg, the viewer's heading slider -180..180: the same angle, wrapped
        pose["heading_deg"] = (pose["heading_deg"] + 180.0) % 360.0 - 180.0
        inp = Inputs(
            **pose,
            row=(sensor.rows + 1) / 2,
            col=(sensor.cols + 1) / 2,
            target_h=v("reported_h_m") if np.isfinite(v("reported_h_m")) else 0.0,
        )
        if np.isfinite(inp.angles_deg["azimuth"]) and np.isfinite(inp.angles_deg["elevation"]):
            out.append((info, inp))
            kept.append(k)
    return out, kept


def enu_origin_for(info: RecordInfo, inp: Inputs) -> EnuFrame:
    """Scene origin near the target: the published position (else the surveyed one, else below the aircraft),
    rounded by :meth:`geoloc.frames.enu.EnuFrame.scene_origin`."""
    if np.isfinite(info.paper_lat_deg):
        lat, lon = info.paper_lat_deg, info.paper_lon_deg
        h = info.paper_height_m if np.isfinite(info.paper_height_m) else 0.0
    elif np.isfinite(info.truth_lat_deg):
        lat, lon, h = info.truth_lat_deg, info.truth_lon_deg, inp.target_h
    else:
        lat, lon, h = inp.lat_deg, inp.lon_deg, inp.target_h
    return EnuFrame.scene_origin(lat, lon, h)


def load_view_scenario(
    records_path=None,
    record: str | int | None = None,
    camera_path=None,
    dem_path=None,
    use_dem: bool = True,
    dem_datum: str = "egm96",
) -> Scenario:
    """Build a geolocation scenario from a records file (default: the bundled [Q17] flight test).

    Parameters
    ----------
    records_path : path-like, optional
        Records CSV (columns of ``docs/records.md``).
    record : str or int, optional
        Label (``T3-1``) or 0-based index of the record to open; default the first.
    camera_path : path-like, optional
        Sensor TOML or first-phase camera TOML; default ``assets/cameras/qiao2017.toml`` (a KLV
        file: the sensor made from its packets). Its ``[uncertainty]`` table, if any, becomes
        ``Scenario.budget``: the viewer's predicted ellipse, the triangulated target's covariance
        and the flight debugger's 99 % rule (``docs/uncertainty.md``).
    dem_path : path-like, optional
        DEM GeoTIFF; default a bundled one covering the target, if any.
    use_dem : bool
        False to stay on the ellipsoid at each record's ``paper_height_m``.
    """
    records_path = Path(records_path) if records_path else Path(ASSETS).joinpath(*DEFAULT_RECORDS)
    velocity = None
    if records_path.suffix.lower() in KLV_SUFFIXES:
        camera, recs, velocity = records_from_klv(records_path, load_sensor(camera_path) if camera_path else None)
    else:
        camera_path = camera_path or Path(ASSETS).joinpath(*DEFAULT_CAMERA)
        camera = load_sensor(camera_path)
        recs = records_from_csv(records_path, camera)
    idx = 0
    if record is not None:
        labels = [r[0].label for r in recs]
        if isinstance(record, int) or str(record).isdigit():
            idx = int(record)
            if not 0 <= idx < len(recs):
                raise ValueError(f"record = {record}: index out of range 0..{len(recs) - 1}")
        elif record in labels:
            idx = labels.index(record)
        else:
            from geoloc.io.records import describe_labels

            raise ValueError(f"record = {record!r}: not in {records_path.name} ({describe_labels(record, labels)})")
    info, inp = recs[idx]
    scn = Scenario(
        name=f"{records_path.name} {info.label}",
        camera=camera,
        inputs=inp,
        enu=enu_origin_for(info, inp),
        records=recs,
        record_index=idx,
        use_dem=use_dem,
        source=records_path.name,
        description=f"records {records_path}, camera {camera.name or camera_path}",
    )
    scn._user_dem = dem_path  # kept when another record is selected
    scn.dem_datum = dem_datum
    scn.record_velocity_ned = velocity
    if camera_path:  # the sensor file's [uncertainty] table: the ellipse, the target's rays, the 99 % rule
        from geoloc.sensors.sensor_file import load_sensor_budget

        scn.budget = load_sensor_budget(camera_path)
    if use_dem:
        from geoloc_viz import terrain_link

        terrain_link.attach_dem(scn, dem_path, strict=dem_path is not None)
    else:
        scn.dem_name = "none (no DEM): ellipsoid at each record's paper_height_m"
    return scn


def select_record(scn: Scenario, idx: int) -> None:
    """Load record ``idx`` into the scenario: its inputs, a new ENU origin, the DEM that covers it."""
    info, inp = scn.records[idx]
    scn.record_index = idx
    scn.name = f"{scn.source} {info.label}"
    scn.inputs = inp.replace()
    scn.enu = enu_origin_for(info, inp)
    if scn.use_dem:
        from geoloc_viz import terrain_link

        terrain_link.attach_dem(scn, scn._user_dem)
