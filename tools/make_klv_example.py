"""Make the bundled example flight: MISB ST 0601 KLV over the Jacksboro SRTM crop (synthetic, seeded).

``python tools/make_klv_example.py`` writes ``assets/klv/example_flight.klv``: 300
UAS Datalink LS packets at 1 Hz (raw KLV, concatenated packets) of an aircraft
orbiting a point of the bundled terrain (``assets/dem/srtm_jacksboro.tif``) at
2 900 m above the ellipsoid, 2.6 km from it, its turret tracking the point and
zooming in twice. ``--ts FILE`` also writes the same packets as an MPEG-TS (PyAV)
with a rendered video stream beside them (STANAG 4609 layout: H.264 video + KLV
data stream, frame i at packet i's time stamp); ``--no-video`` leaves it out.
It also writes ``assets/klv/example_flight_targets.csv``: the surveyed targets
painted on the ground as crosses.

How each packet is made:

1. the true pose: position on the orbit, heading along it (with a slow crab and
   noise), the coordinated-turn bank, a 2 deg pitch; the turret's azimuth and
   elevation point the line of sight at the tracked point plus a slow wander
   (tens of metres) and 0.03 deg of encoder noise; the sensor roll wanders about 0;
2. it is encoded and decoded, so that what follows uses exactly the values a
   reader of the file gets (the items are quantised: the heading, for instance,
   in steps of 0.0055 deg);
3. the platform's own answers are computed from those decoded values on the DEM
   (geoloc's exact DEM solver, one ``lens_from_fov`` sensor per zoom step, no
   pixel scaling): frame centre (tags 23, 24, 25 as MSL, 78 as HAE), slant range
   (21) and the four full corners (82-89). So a replay with ``--dem`` gives them back
   to the quantisation of the frame centre (millimetres), and one without shows the
   terrain's effect on the corners;
4. faults of the kinds users meet are planted, after step 3 (so the reported
   centres stay those of the true geometry): see :data:`FAULTS`.

5. the video (``--ts``): frame i is rendered by geoloc itself
   (:func:`geoloc.workflows.render.render_frame`: every pixel's exact hit on the
   DEM, coloured from the hillshade with the surveyed targets painted as crosses)
   from the *true* pose of step 1 as decoded, at 640 x 360, so the faults of step 4
   show in the frames; and the video's own fault, :data:`VIDEO_FAULTS`: in frames
   40-79 the video runs 1.5 s ahead of its metadata (frame i shows the scene of
   time i + 1.5 s, the true pose linearly interpolated between packets), the KLV
   packets being right.

This is example data for the README, the docs and the viewer, and the test that the
replay flags the planted packets and no others; the oracle tests of the chain are
elsewhere (pymap3d, in ``tests/workflows/test_klv_replay.py``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from geoloc.frames.chain import Pose, R_body_ned
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.geodesy.local import R_ecef_ned, enu_to_geodetic
from geoloc.io.klv import decode_packet, encode_packet
from geoloc.locate import line_of_sight
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import lens_from_fov
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import DemSurface

ROOT = Path(__file__).resolve().parents[1]
DEM_PATH = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"
OUT = ROOT / "assets" / "klv" / "example_flight.klv"

SEED = 20240514
N_PACKETS = 300
T0_US = 1_715_698_800_000_000  # 2024-05-14T15:00:00Z
TARGET = (36.5900, -84.2450)  # the tracked point (deg); its height is the DEM's
ORBIT_RADIUS_M = 2600.0
ORBIT_HAE_M = 2900.0
WIDTH, HEIGHT = 1920, 1080
#: Horizontal field of view per zoom step: (first packet, hfov_deg); vfov from the 16:9 image.
ZOOM = ((0, 12.0), (100, 7.0), (200, 4.5))

#: The planted faults: name -> (first file packet, last file packet, what). File packet i
#: is at 15:00:00 + i s UTC (its precision time stamp); packet numbers count every packet
#: written, the corrupted one too.
FAULTS = {
    "yaw_bias": (
        100,
        109,
        "heading (tag 5) 2.5 deg too large: a heading-reference error burst; the reported centres are the true ones",
    ),
    "wrong_datum": (
        200,
        204,
        "tag 75 (Sensor Ellipsoid Height, HAE) holds the MSL altitude (tag 15's "
        "value): 30.6 m too high, since N = -30.6 m here",
    ),
    "stale_pose": (
        250,
        256,
        "platform position and attitude (tags 5-7, 13-15, 75, 90, 91) are the previous "
        "packet's (1 s stale), the sensor angles and the reported centre current",
    ),
    "missing_angles": (275, 275, "tags 18, 19, 20 (sensor-relative angles) left out"),
    "corrupted": (150, 150, "one byte of the packet flipped after encoding: checksum mismatch"),
}

#: Faults of the video alone (the KLV is right): name -> (first frame, last frame, seconds, what).
#: Frame i has packet i's time stamp.
VIDEO_FAULTS = {
    "video_ahead": (
        40,
        79,
        1.5,
        "the video runs 1.5 s ahead of its metadata: frame i shows the scene of "
        "metadata time i + 1.5 s (time_offset_s = -1.5 matches them)",
    ),
}
#: Video frame size (width, height) [pixels], 16:9 as the packets' fields of view.
VIDEO_SIZE = (640, 360)
#: The surveyed targets, painted as crosses: (name, east, north) [m] from the centre of the DEM
#: cell that holds the tracked point. All five lie inside that one cell (3'' SRTM: 74 m east-west,
#: 93 m north-south here), 7 m or more from its edges: a cross across a cell edge would sit on a
#: fold of the bilinear terrain, whose two sides foreshorten its arms differently.
SURVEYED = (("T1", 0.0, 0.0), ("T2", 18.0, 22.0), ("T3", -18.0, 22.0), ("T4", -18.0, -22.0), ("T5", 18.0, -22.0))
CROSS_ARM_M, CROSS_WIDTH_M = 10.0, 3.0
TARGETS_OUT = ROOT / "assets" / "klv" / "example_flight_targets.csv"

POSE_FIELDS = (
    "platform_heading_deg",
    "platform_pitch_deg",
    "platform_roll_deg",
    "sensor_latitude_deg",
    "sensor_longitude_deg",
    "sensor_true_altitude_m",
    "sensor_ellipsoid_height_m",
    "platform_pitch_full_deg",
    "platform_roll_full_deg",
)


def _vfov(hfov_deg):
    return math.degrees(2 * math.atan(math.tan(math.radians(hfov_deg) / 2) * HEIGHT / WIDTH))


def true_fields(dem, rng):
    """The true pose and pointing of every packet, as ST 0601 fields (degrees, metres)."""
    t = np.arange(N_PACKETS, dtype=float)
    lat_t, lon_t = map(math.radians, TARGET)
    phi = math.radians(200.0) + 2 * math.pi * t / N_PACKETS  # bearing from the point to the aircraft
    speed = 2 * math.pi * ORBIT_RADIUS_M / N_PACKETS
    up = ORBIT_HAE_M + 6.0 * np.sin(2 * math.pi * t / 97.0)
    enu = np.stack([ORBIT_RADIUS_M * np.sin(phi), ORBIT_RADIUS_M * np.cos(phi), up], -1)
    lat, lon, h = enu_to_geodetic(enu, lat_t, lon_t, 0.0)
    heading = (np.degrees(phi) + 90.0 + 1.5 * np.sin(2 * math.pi * t / 150.0) + rng.normal(0, 0.15, N_PACKETS)) % 360.0
    bank = math.degrees(math.atan(speed**2 / (9.80665 * ORBIT_RADIUS_M)))
    roll = bank + rng.normal(0, 0.3, N_PACKETS)
    pitch = 2.0 + rng.normal(0, 0.2, N_PACKETS)

    # the turret: line of sight to the tracked point plus a slow ground wander, then encoder noise
    wander = np.stack([25 * np.sin(2 * math.pi * t / 41.0), 20 * np.cos(2 * math.pi * t / 67.0)], -1)
    aim_lat, aim_lon, _ = enu_to_geodetic(np.column_stack([wander, np.zeros(N_PACKETS)]), lat_t, lon_t, 0.0)
    aim_h = dem.height(aim_lat, aim_lon)
    o = geodetic_to_ecef(lat, lon, h)
    p = geodetic_to_ecef(aim_lat, aim_lon, aim_h)
    d_ned = np.einsum("nji,nj->ni", R_ecef_ned(lat, lon), p - o)
    d_body = np.einsum("nij,nj->ni", R_body_ned(np.radians(heading), np.radians(pitch), np.radians(roll)), d_ned)
    az = (np.degrees(np.arctan2(d_body[:, 1], d_body[:, 0])) + rng.normal(0, 0.03, N_PACKETS)) % 360.0
    el = np.degrees(np.arctan2(-d_body[:, 2], np.hypot(d_body[:, 0], d_body[:, 1]))) + rng.normal(0, 0.03, N_PACKETS)
    sroll = (1.0 * np.sin(2 * math.pi * t / 120.0) + rng.normal(0, 0.05, N_PACKETS)) % 360.0

    hfov = np.zeros(N_PACKETS)
    for first, hf in ZOOM:
        hfov[first:] = hf
    n_s = egm96_undulation(lat, lon)
    out = []
    for i in range(N_PACKETS):
        out.append(
            {
                "precision_time_stamp_us": T0_US + 1_000_000 * i,
                "mission_id": "GEOLOC-EXAMPLE",
                "platform_tail_number": "SYNTH-1",
                "platform_heading_deg": float(heading[i]),
                "platform_pitch_deg": float(pitch[i]),
                "platform_roll_deg": float(roll[i]),
                "image_source_sensor": "EO",
                "image_coordinate_system": "WGS-84",
                "sensor_latitude_deg": math.degrees(lat[i]),
                "sensor_longitude_deg": math.degrees(lon[i]),
                "sensor_true_altitude_m": float(h[i] - n_s[i]),
                "sensor_horizontal_fov_deg": float(hfov[i]),
                "sensor_vertical_fov_deg": _vfov(hfov[i]),
                "sensor_relative_azimuth_deg": float(az[i]),
                "sensor_relative_elevation_deg": float(el[i]),
                "sensor_relative_roll_deg": float(sroll[i]),
                "uas_ls_version": 17,
                "sensor_ellipsoid_height_m": float(h[i]),
                "platform_pitch_full_deg": float(pitch[i]),
                "platform_roll_full_deg": float(roll[i]),
            }
        )
    return out


def platform_answers(dem, decoded):
    """Frame centre, slant range and corners on the DEM from the decoded fields (one sensor per zoom step)."""
    surf = DemSurface(dem, "exact")
    g = lambda k: np.array([d[k] for d in decoded], float)  # noqa: E731
    pose = Pose.from_deg(
        g("sensor_latitude_deg"),
        g("sensor_longitude_deg"),
        g("sensor_ellipsoid_height_m"),
        g("platform_heading_deg"),
        g("platform_pitch_full_deg"),
        g("platform_roll_full_deg"),
        angles_deg={
            "azimuth": g("sensor_relative_azimuth_deg"),
            "elevation": g("sensor_relative_elevation_deg"),
            "sensor_roll": g("sensor_relative_roll_deg"),
        },
    )
    fov = np.stack([g("sensor_horizontal_fov_deg"), g("sensor_vertical_fov_deg")], -1)
    out = [{} for _ in decoded]
    for hv in np.unique(fov, axis=0):
        idx = np.flatnonzero(np.all(fov == hv, axis=1))
        s = FrameSensor(
            lens_from_fov(math.radians(hv[0]), math.radians(hv[1]), WIDTH, HEIGHT), PRESETS["azimuth-elevation-roll"]
        )
        p = pose.take(idx)
        rows = np.array([(HEIGHT + 1) / 2, 0.5, 0.5, HEIGHT + 0.5, HEIGHT + 0.5])[:, None]
        cols = np.array([(WIDTH + 1) / 2, 0.5, WIDTH + 0.5, WIDTH + 0.5, 0.5])[:, None]
        hit = surf.intersect(line_of_sight(p, s, rows, cols))
        if np.any(hit.status != Status.OK):
            raise RuntimeError(f"a ray of the example flight misses the DEM: {np.unique(hit.status)}")
        lat, lon, h = np.degrees(hit.lat), np.degrees(hit.lon), hit.h
        n_c = egm96_undulation(hit.lat[0], hit.lon[0])
        for j, i in enumerate(idx):
            o = out[i]
            o["frame_center_latitude_deg"] = float(lat[0, j])
            o["frame_center_longitude_deg"] = float(lon[0, j])
            o["frame_center_hae_m"] = float(h[0, j])
            o["frame_center_elevation_m"] = float(h[0, j] - n_c[j])
            o["slant_range_m"] = float(hit.slant_range[0, j])
            for k in range(4):
                o[f"corner_latitude_{k + 1}_deg"] = float(lat[k + 1, j])
                o[f"corner_longitude_{k + 1}_deg"] = float(lon[k + 1, j])
    return out


def decoded_truth(dem) -> list:
    """Step 1 and 2: the true fields of every packet as a reader of an unfaulted packet decodes them."""
    rng = np.random.default_rng(SEED)
    return [decode_packet(encode_packet(f)).fields for f in true_fields(dem, rng)]


def make_packets(dem=None) -> list:
    """The 300 packets (bytes), faults planted."""
    dem = dem if dem is not None else DEM.open(DEM_PATH)
    decoded = decoded_truth(dem)
    answers = platform_answers(dem, decoded)
    fields = [{**d, **a} for d, a in zip(decoded, answers)]
    planted = [dict(f) for f in fields]
    a, b, _ = FAULTS["yaw_bias"]
    for i in range(a, b + 1):
        planted[i]["platform_heading_deg"] = (fields[i]["platform_heading_deg"] + 2.5) % 360.0
    a, b, _ = FAULTS["wrong_datum"]
    for i in range(a, b + 1):
        planted[i]["sensor_ellipsoid_height_m"] = fields[i]["sensor_true_altitude_m"]
    a, b, _ = FAULTS["stale_pose"]
    for i in range(a, b + 1):
        for k in POSE_FIELDS:
            planted[i][k] = fields[i - 1][k]
    a, _, _ = FAULTS["missing_angles"]
    for k in ("sensor_relative_azimuth_deg", "sensor_relative_elevation_deg", "sensor_relative_roll_deg"):
        del planted[a][k]
    blobs = [encode_packet(f) for f in planted]
    a, _, _ = FAULTS["corrupted"]
    bad = bytearray(blobs[a])
    bad[40] ^= 0x5A  # inside the local set: the checksum no longer matches
    blobs[a] = bytes(bad)
    return blobs


# --------------------------------------------------------------------------- the video


def surveyed_targets(dem) -> list:
    """The surveyed targets: name, lat_deg, lon_deg, h_m (the DEM's height there, ellipsoidal WGS 84)."""
    g = dem.grid
    i = math.floor((g.lat_north_deg - TARGET[0]) / g.dlat_deg)
    j = math.floor((TARGET[1] - g.lon_west_deg) / g.dlon_deg)
    lat_t = math.radians(g.lat_north_deg - (i + 0.5) * g.dlat_deg)
    lon_t = math.radians(g.lon_west_deg + (j + 0.5) * g.dlon_deg)
    en = np.array([[e, n, 0.0] for _, e, n in SURVEYED])
    lat, lon, _ = enu_to_geodetic(en, lat_t, lon_t, 0.0)
    h = dem.height(lat, lon)
    return [
        {
            "name": name,
            "lat_deg": round(math.degrees(a), 8),
            "lon_deg": round(math.degrees(b), 8),
            "h_m": round(float(c), 3),
            "arm_m": CROSS_ARM_M,
            "width_m": CROSS_WIDTH_M,
        }
        for (name, _, _), a, b, c in zip(SURVEYED, lat, lon, h)
    ]


_ANGLES = (
    "platform_heading_deg",
    "platform_pitch_full_deg",
    "platform_roll_full_deg",
    "sensor_relative_azimuth_deg",
    "sensor_relative_elevation_deg",
    "sensor_relative_roll_deg",
)
_LINEAR = ("sensor_latitude_deg", "sensor_longitude_deg", "sensor_ellipsoid_height_m")


def state_at(decoded, tau: float) -> dict:
    """The true pose at fractional packet time ``tau`` [s from packet 0]: linear between packets
    (angles along the shorter way), the fields of view of packet floor(tau)."""
    i = min(int(math.floor(tau)), len(decoded) - 2)
    f = tau - i
    a, b = decoded[i], decoded[i + 1]
    out = {k: a[k] for k in ("sensor_horizontal_fov_deg", "sensor_vertical_fov_deg")}
    for k in _LINEAR:
        out[k] = a[k] + f * (b[k] - a[k])
    for k in _ANGLES:
        out[k] = a[k] + f * ((b[k] - a[k] + 180.0) % 360.0 - 180.0)
    return out


def frame_content_times() -> np.ndarray:
    """Time [s from packet 0] of the scene each frame shows (i, or i + 1.5 in the fault)."""
    t = np.arange(N_PACKETS, dtype=float)
    a, b, d, _ = VIDEO_FAULTS["video_ahead"]
    t[a : b + 1] += d
    return t


def video_sensor_pose(st: dict):
    """The video's sensor (lens_from_fov at VIDEO_SIZE, azimuth-elevation-roll) and pose for a state."""
    w, h = VIDEO_SIZE
    s = FrameSensor(
        lens_from_fov(math.radians(st["sensor_horizontal_fov_deg"]), math.radians(st["sensor_vertical_fov_deg"]), w, h),
        PRESETS["azimuth-elevation-roll"],
    )
    p = Pose.from_deg(
        st["sensor_latitude_deg"],
        st["sensor_longitude_deg"],
        st["sensor_ellipsoid_height_m"],
        st["platform_heading_deg"],
        st["platform_pitch_full_deg"],
        st["platform_roll_full_deg"],
        angles_deg={
            "azimuth": st["sensor_relative_azimuth_deg"],
            "elevation": st["sensor_relative_elevation_deg"],
            "sensor_roll": st["sensor_relative_roll_deg"],
        },
    )
    return s, p


def texture(dem):
    from geoloc.workflows.render import Cross, ground_texture

    return ground_texture(
        dem, [Cross(t["lat_deg"], t["lon_deg"], t["arm_m"], t["width_m"], t["name"]) for t in surveyed_targets(dem)]
    )


def render_video(dem, frames=None, log=None):
    """Yield the rendered frames (RGB uint8, VIDEO_SIZE), frame i from the true pose at its content time."""
    from geoloc.workflows.render import render_frame

    decoded = decoded_truth(dem)
    tex = texture(dem)
    times = frame_content_times()
    for i in range(N_PACKETS) if frames is None else frames:
        s, p = video_sensor_pose(state_at(decoded, float(times[i])))
        yield render_frame(s, p, dem, tex).image
        if log and i % 25 == 0:
            log(f"  frame {i}/{N_PACKETS}")


def write_targets_csv(path, dem):
    rows = surveyed_targets(dem)
    lines = ["name,lat_deg,lon_deg,h_m,arm_m,width_m"] + [
        f"{t['name']},{t['lat_deg']:.8f},{t['lon_deg']:.8f},{t['h_m']:.3f},{t['arm_m']},{t['width_m']}" for t in rows
    ]
    Path(path).write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(OUT), help=f"raw KLV output (default {OUT.relative_to(ROOT)})")
    ap.add_argument(
        "--ts", default=None, metavar="FILE", help="also write the packets as an MPEG-TS (1 Hz) with the rendered video"
    )
    ap.add_argument("--no-video", action="store_true", help="the MPEG-TS without its video stream")
    ap.add_argument("--targets", default=str(TARGETS_OUT), help="surveyed targets CSV output")
    args = ap.parse_args(argv)
    dem = DEM.open(DEM_PATH)
    blobs = make_packets(dem)
    write_targets_csv(args.targets, dem)
    print(f"wrote {len(SURVEYED)} surveyed targets to {args.targets}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(b"".join(blobs))
    print(f"wrote {len(blobs)} packets ({out.stat().st_size} bytes) to {out}")
    if args.ts:
        from geoloc.io.klv import write_ts

        frames = None if args.no_video else render_video(dem, log=print)
        write_ts(args.ts, blobs, rate=1.0, frames=frames, codec_options={"crf": 30})  # 2.3 MB
        what = "KLV data stream" if args.no_video else f"H.264 {VIDEO_SIZE[0]}x{VIDEO_SIZE[1]} + KLV data stream"
        print(f"wrote {len(blobs)} packets to {args.ts} (MPEG-TS, {what}, 1 Hz; {Path(args.ts).stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
