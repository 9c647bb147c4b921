"""Make the bundled example records for the two example sensors (synthetic, seeded).

``python tools/make_sensor_examples.py`` writes

* ``assets/records/eo_turret_flight.csv``: an EO turret (``assets/sensors/eo_turret.toml``)
  on an aircraft orbiting at 2.5 km over the Jacksboro SRTM crop, 24 targets;
* ``assets/records/drone_targets.csv``: a drone camera (``assets/sensors/drone_camera.toml``)
  120-300 m above the same terrain, 20 targets.

How: targets are drawn on the bundled SRTM terrain (their truth is a DEM node
height made ellipsoidal with EGM96); each target's pixel is the sensor's
projection from the *true* pose; the records then carry a pose with seeded
errors of the size real navigation and gimbal encoders have (0.05-0.1 deg,
a few metres), so the replay's errors to truth are what those errors cost.
This is example data for the README and the viewer, not a test oracle.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from geoloc.frames.chain import Pose
from geoloc.sensors.sensor_file import load_sensor
from geoloc.status import Status
from geoloc.surfaces.dem import DEM

ROOT = Path(__file__).resolve().parents[1]
DEM_PATH = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"


def targets_on_dem(dem, rng, n, centre, radius_deg):
    lat = centre[0] + rng.uniform(-radius_deg, radius_deg, n)
    lon = centre[1] + rng.uniform(-radius_deg, radius_deg, n) / math.cos(math.radians(centre[0]))
    h = dem.height(np.deg2rad(lat), np.deg2rad(lon))
    return lat, lon, h


def look_at(sensor, pose_fn, lat, lon, h):
    """Poses whose image centre looks at each target, and the target's pixel in that image."""
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc.geodesy.local import R_ecef_ned

    out = []
    for k in range(len(lat)):
        pose = pose_fn(k)
        o = geodetic_to_ecef(pose.lat, pose.lon, pose.h)
        t = geodetic_to_ecef(math.radians(lat[k]), math.radians(lon[k]), h[k])
        d = R_ecef_ned(pose.lat, pose.lon).T @ (t - o)
        az = math.atan2(d[1], d[0])
        el = math.atan2(-d[2], math.hypot(d[0], d[1]))
        out.append((pose, az, el))
    return out


def write(path, rows, header):
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=header)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {len(rows)} records to {path.relative_to(ROOT)}")


def turret(dem, rng):
    sensor = load_sensor(ROOT / "assets" / "sensors" / "eo_turret.toml")
    centre = (36.59, -84.25)
    lat, lon, h = targets_on_dem(dem, rng, 24, centre, 0.05)
    rows = []
    for k in range(24):
        bearing = 2 * math.pi * k / 24
        alat = centre[0] + 0.07 * math.cos(bearing)
        alon = centre[1] + 0.07 * math.sin(bearing) / math.cos(math.radians(centre[0]))
        heading = (math.degrees(bearing) + 90.0 + 180.0) % 360.0 - 180.0  # orbiting clockwise
        pose = Pose.from_deg(alat, alon, 2500.0, heading, 2.0, 1.5)
        # point the turret at the target (the true angles), then read its pixel
        ((p0, az, el),) = look_at(sensor, lambda _: pose, lat[k : k + 1], lon[k : k + 1], h[k : k + 1])
        az_rel = (math.degrees(az) - heading) % 360.0
        true = Pose.from_deg(
            alat,
            alon,
            2500.0,
            heading,
            2.0,
            1.5,
            angles_deg={
                "azimuth": az_rel + rng.uniform(-1.5, 1.5),
                "elevation": math.degrees(el) + rng.uniform(-1.0, 1.0),
            },
        )
        # the target: a pixel near the image centre, met on the terrain from the true pose (so it
        # is the first visible crossing; a point drawn on the DEM could hide behind a ridge)
        from geoloc.surfaces.terrain import intersect_dem

        for _ in range(50):  # a pixel whose ray meets the terrain inside the crop
            r, c = rng.uniform(300, sensor.rows - 300), rng.uniform(500, sensor.cols - 500)
            hit = intersect_dem(sensor.line_of_sight(r, c, true), dem, "exact")
            if int(hit.status) == Status.OK:
                break
        assert int(hit.status) == Status.OK, hit.status
        px = type("P", (), {"row": r, "col": c})
        lat[k], lon[k], h[k] = float(hit.lat_deg), float(hit.lon_deg), float(hit.h)
        noisy = dict(
            ac_lat_deg=alat + rng.normal(0, 2.0) / 111_000.0,
            ac_lon_deg=alon + rng.normal(0, 2.0) / 89_000.0,
            ac_h_m=2500.0 + rng.normal(0, 3.0),
            heading_deg=heading + rng.normal(0, 0.1),
            pitch_deg=2.0 + rng.normal(0, 0.05),
            roll_deg=1.5 + rng.normal(0, 0.05),
            azimuth_deg=math.degrees(true.angle("azimuth")) + rng.normal(0, 0.05),
            elevation_deg=math.degrees(true.angle("elevation")) + rng.normal(0, 0.05),
        )
        rows.append(
            {
                "table": "orbit1",
                "point": k + 1,
                "row": f"{float(px.row):.2f}",
                "col": f"{float(px.col):.2f}",
                **{kk: f"{v:.7f}" for kk, v in noisy.items()},
                "truth_lat_deg": f"{lat[k]:.8f}",
                "truth_lon_deg": f"{lon[k]:.8f}",
                "truth_h_m": f"{h[k]:.2f}",
            }
        )
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
        "azimuth_deg",
        "elevation_deg",
        "truth_lat_deg",
        "truth_lon_deg",
        "truth_h_m",
    ]
    write(ROOT / "assets" / "records" / "eo_turret_flight.csv", rows, header)


def drone(dem, rng):
    sensor = load_sensor(ROOT / "assets" / "sensors" / "drone_camera.toml")
    centre = (36.62, -84.20)
    rows = []
    for k in range(20):
        alat = centre[0] + rng.uniform(-0.02, 0.02)
        alon = centre[1] + rng.uniform(-0.025, 0.025)
        ground = float(dem.height(math.radians(alat), math.radians(alon)))
        ah = ground + rng.uniform(120.0, 300.0)
        yaw, pitch = rng.uniform(-180, 180), rng.uniform(-90, -45)
        true = Pose.from_deg(
            alat,
            alon,
            ah,
            yaw + rng.normal(0, 5),
            rng.normal(0, 3),
            rng.normal(0, 3),
            angles_deg={"gimbal_yaw": yaw, "gimbal_pitch": pitch, "gimbal_roll": 0.0},
        )
        # a target somewhere in the image: a random pixel, located on the DEM from the true pose
        from geoloc.surfaces.terrain import intersect_dem

        r, c = rng.uniform(200, sensor.rows - 200), rng.uniform(200, sensor.cols - 200)
        hit = intersect_dem(sensor.line_of_sight(r, c, true), dem, "exact")
        if int(hit.status) != Status.OK:
            continue
        noisy = dict(
            ac_lat_deg=alat + rng.normal(0, 1.5) / 111_000.0,
            ac_lon_deg=alon + rng.normal(0, 1.5) / 89_000.0,
            ac_h_m=ah + rng.normal(0, 2.0),
            heading_deg=math.degrees(true.heading),
            pitch_deg=math.degrees(true.pitch),
            roll_deg=math.degrees(true.roll),
            gimbal_yaw_deg=yaw + rng.normal(0, 0.3),
            gimbal_pitch_deg=pitch + rng.normal(0, 0.1),
            gimbal_roll_deg=rng.normal(0, 0.1),
        )
        rows.append(
            {
                "table": "survey1",
                "point": len(rows) + 1,
                "row": f"{r:.2f}",
                "col": f"{c:.2f}",
                **{kk: f"{v:.7f}" for kk, v in noisy.items()},
                "truth_lat_deg": f"{float(hit.lat_deg):.8f}",
                "truth_lon_deg": f"{float(hit.lon_deg):.8f}",
                "truth_h_m": f"{float(hit.h):.2f}",
            }
        )
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
        "gimbal_yaw_deg",
        "gimbal_pitch_deg",
        "gimbal_roll_deg",
        "truth_lat_deg",
        "truth_lon_deg",
        "truth_h_m",
    ]
    write(ROOT / "assets" / "records" / "drone_targets.csv", rows, header)


def main() -> None:
    dem = DEM.open(DEM_PATH, datum="egm96")
    turret(dem, np.random.default_rng(2026))
    drone(dem, np.random.default_rng(2027))


if __name__ == "__main__":
    main()
