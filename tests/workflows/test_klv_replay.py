"""The KLV replay (geoloc.workflows.klv_replay, ``geoloc replay FILE.klv|FILE.ts``).

Oracles, none of them the project's own chain:

* pymap3d's ``lookAtSpheroid`` for the frame centres and corners: the packets are
  encoded (geoloc.io.klv.encode_packet) from known poses, the expected ground
  points computed by pymap3d from the *decoded* values (what a reader of the packet
  gets), and those points written into the packets as the reported centre and
  corners. For a level aircraft the line of sight's azimuth is heading + sensor
  azimuth and its tilt from nadir 90 + elevation; with attitude, the line of sight
  in NED comes from scipy's ``Rotation`` (body from NED z-y-x by heading, pitch,
  roll; the sensor z-y-x by azimuth, elevation, roll in the body, MISB ST 0601's
  order), written independently of geoloc.frames;
* PROJ (through pyproj, ``+proj=vgridshift`` on the bundled EGM96 crop) for N;
* the planted faults of the bundled example flight (tools/make_klv_example.py).

Tolerances. pymap3d intersects the ellipsoid itself (h = 0), and tag 78 cannot hold
0 exactly (its step is 0.30 m; 0 decodes to delta = +0.026 m). So the replay, which
intersects at the decoded height delta, is compared with pymap3d started delta lower:
the two points differ horizontally by about delta x range / R_earth, 2e-5 m at
5 km. The reported centre is then quantised by its encoding: latitude steps of
4.19e-8 deg, longitude steps of 8.38e-8 deg, so half a step is at most 2.33 mm in
latitude and 4.66 mm x cos(lat) in longitude: the frame-centre error must stay below
that hypotenuse (+0.1 mm), and the recomputed point within 1 mm of the unquantised
pymap3d point.
"""

import csv
import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymap3d.los import lookAtSpheroid
from scipy.spatial.transform import Rotation

from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.geodesy.geoid import GEOID_DIR
from geoloc.io.klv import TAG_BY_NAME, decode_packet, encode_packet, write_ts
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import lens_from_fov
from geoloc.status import Status
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows import klv_replay
from geoloc.workflows.klv_replay import (
    outlier_mask,
    read_klv,
    replay_klv,
    write_klv_csv,
)

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "assets" / "klv" / "example_flight.klv"
DEM_PATH = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"

LAT_STEP = TAG_BY_NAME["frame_center_latitude_deg"].step
LON_STEP = TAG_BY_NAME["frame_center_longitude_deg"].step
T0 = 1_700_000_000_000_000


def quantisation_bound_m(lat_deg) -> float:
    """Half a step of the reported frame centre's latitude and longitude, as a distance [m]."""
    m_per_deg = 111_320.0
    return math.hypot(0.5 * LAT_STEP * m_per_deg, 0.5 * LON_STEP * m_per_deg * math.cos(math.radians(lat_deg)))


def dec(fields: dict) -> dict:
    """What a reader of the encoded packet gets."""
    return decode_packet(encode_packet(fields)).fields


# ------------------------------------------------------------------ the independent oracle


def los_ned(heading, pitch, roll, az, el, sroll, d_sensor=(1.0, 0.0, 0.0)):
    """Line of sight in NED: scipy rotations, body from NED z-y-x, sensor z-y-x in the body.

    scipy's ``from_euler("ZYX", [a, b, c])`` is the intrinsic z-y'-x'' rotation, an active
    rotation of NED's axes onto the rotated frame's: ``apply`` takes a vector's coordinates
    in the rotated frame to NED. The sensor frame: X along the line of sight, Y the image's
    right, Z the image's down (MISB: top of the image is up at zero roll).
    """
    r_body = Rotation.from_euler("ZYX", [heading, pitch, roll], degrees=True)
    r_sens = Rotation.from_euler("ZYX", [az, el, sroll], degrees=True)
    return (r_body * r_sens).apply(np.asarray(d_sensor, float))


def oracle_point(lat, lon, h, v_ned, delta):
    """pymap3d's intersection of the NED direction v_ned from (lat, lon, h - delta) with h = 0."""
    v = np.asarray(v_ned, float) / np.linalg.norm(v_ned)
    az = math.degrees(math.atan2(v[1], v[0])) % 360.0
    tilt = math.degrees(math.acos(v[2]))
    la, lo, _ = lookAtSpheroid(lat, lon, h - delta, az, tilt)
    return float(la), float(lo)


def pose_fields(lat, lon, h, heading, az, el, pitch=0.0, roll=0.0, sroll=0.0, hfov=8.0, vfov=4.5, i=0, full=False):
    f = {
        "precision_time_stamp_us": T0 + 1_000_000 * i,
        "platform_heading_deg": heading,
        "platform_pitch_deg": pitch,
        "platform_roll_deg": roll,
        "sensor_latitude_deg": lat,
        "sensor_longitude_deg": lon,
        "sensor_ellipsoid_height_m": h,
        "sensor_horizontal_fov_deg": hfov,
        "sensor_vertical_fov_deg": vfov,
        "sensor_relative_azimuth_deg": az,
        "sensor_relative_elevation_deg": el,
        "sensor_relative_roll_deg": sroll,
        "frame_center_hae_m": 0.0,
    }
    if full:
        f["platform_pitch_full_deg"] = pitch
        f["platform_roll_full_deg"] = roll
    return f


def with_oracle(fields, corners=True):
    """The decoded fields plus the pymap3d frame centre (and full corners) as the reported ones.

    Returns (packet fields, expected centre (lat, lon), expected corners [(lat, lon)] * 4)."""
    d = dec(fields)
    pitch = d.get("platform_pitch_full_deg", d["platform_pitch_deg"])
    roll = d.get("platform_roll_full_deg", d["platform_roll_deg"])
    args = (
        d["platform_heading_deg"],
        pitch,
        roll,
        d["sensor_relative_azimuth_deg"],
        d["sensor_relative_elevation_deg"],
        d["sensor_relative_roll_deg"],
    )
    delta = d["frame_center_hae_m"]
    lat, lon, h = d["sensor_latitude_deg"], d["sensor_longitude_deg"], d["sensor_ellipsoid_height_m"]
    centre = oracle_point(lat, lon, h, los_ned(*args), delta)
    out = dict(d, frame_center_latitude_deg=centre[0], frame_center_longitude_deg=centre[1])
    tx = math.tan(math.radians(d["sensor_horizontal_fov_deg"]) / 2)
    ty = math.tan(math.radians(d["sensor_vertical_fov_deg"]) / 2)
    # corners 1-4: upper left, upper right, lower right, lower left (Y right, Z down)
    dirs = [(1.0, -tx, -ty), (1.0, tx, -ty), (1.0, tx, ty), (1.0, -tx, ty)]
    ks = [oracle_point(lat, lon, h, los_ned(*args, d_sensor=v), delta) for v in dirs]
    if corners:
        for j, (a, b) in enumerate(ks):
            out[f"corner_latitude_{j + 1}_deg"] = a
            out[f"corner_longitude_{j + 1}_deg"] = b
    return out, centre, ks


def stream(fields_list) -> bytes:
    return b"".join(encode_packet(f) for f in fields_list)


def check_against_oracle(r, expected, corner_expected=None):
    c = r.columns
    assert list(c["status"]) == [Status.OK] * len(expected)
    for k, (la, lo) in enumerate(expected):
        d = horizontal_distance_m(c["lat_deg"][k], c["lon_deg"][k], la, lo)
        assert d < 1e-3, (k, d)
        bound = quantisation_bound_m(la) + 1e-4
        assert c["frame_center_error_m"][k] < bound, (k, c["frame_center_error_m"][k], bound)
        if corner_expected is not None:
            for j, (ka, ko) in enumerate(corner_expected[k]):
                dk = horizontal_distance_m(c[f"corner{j + 1}_lat_deg"][k], c[f"corner{j + 1}_lon_deg"][k], ka, ko)
                assert dk < 1e-3, (k, j, dk)
            assert c["corner_error_m"][k] < bound, (k, c["corner_error_m"][k])


# ------------------------------------------------------------------ frame centres and corners vs pymap3d


def test_level_aircraft_against_pymap3d():
    """Level aircraft: line of sight azimuth heading + sensor azimuth, tilt 90 + elevation."""
    rng = np.random.default_rng(1)
    cases = [
        (36.6, -84.25, 2500.0, 30.0, 90.0, -30.0),
        (0.0, 0.0, 8000.0, 0.0, 0.0, -90.0),
        (-33.9, 151.2, 1200.0, 359.0, 271.0, -15.0),
        (60.2, 179.99, 5000.0, 90.0, 0.0, -45.0),
        (-75.0, -60.0, 3000.0, 200.0, 135.0, -60.0),
    ]
    for _ in range(15):
        cases.append(
            (
                rng.uniform(-70, 70),
                rng.uniform(-180, 180),
                rng.uniform(500, 9000),
                rng.uniform(0, 360),
                rng.uniform(0, 360),
                rng.uniform(-85, -12),
            )
        )
    packets, expected, kexp = [], [], []
    for i, (lat, lon, h, hdg, az, el) in enumerate(cases):
        f, centre, ks = with_oracle(
            pose_fields(lat, lon, h, hdg, az, el, hfov=rng.uniform(1, 40), vfov=rng.uniform(1, 30), i=i)
        )
        # the oracle's direction is the hand rule: azimuth heading + az, tilt 90 + el
        a2, b2, _ = lookAtSpheroid(
            f["sensor_latitude_deg"],
            f["sensor_longitude_deg"],
            f["sensor_ellipsoid_height_m"] - f["frame_center_hae_m"],
            (f["platform_heading_deg"] + f["sensor_relative_azimuth_deg"]) % 360,
            90.0 + f["sensor_relative_elevation_deg"],
        )
        assert horizontal_distance_m(a2, b2, *centre) < 1e-5  # the same rays (10 um: rounding at nadir)
        packets.append(f)
        expected.append(centre)
        kexp.append(ks)
    r = replay_klv(stream(packets))
    check_against_oracle(r, expected, kexp)
    assert r.summary.compared == len(cases) and r.summary.outliers == []
    assert r.summary.median_m < 5e-3


def test_attitude_and_sensor_roll_against_scipy_and_pymap3d():
    """Pitched, banked aircraft; turret azimuth, elevation and roll; the full-range items 90/91."""
    rng = np.random.default_rng(2)
    packets, expected, kexp = [], [], []
    for i in range(30):
        full = i % 2 == 0  # half the packets carry tags 90/91 (beyond +-20 / +-50 for some)
        pitch = rng.uniform(-35, 35) if full else rng.uniform(-19, 19)
        roll = rng.uniform(-70, 70) if full else rng.uniform(-45, 45)
        f = pose_fields(
            rng.uniform(-60, 60),
            rng.uniform(-180, 180),
            rng.uniform(1500, 9000),
            rng.uniform(0, 360),
            rng.uniform(0, 360),
            rng.uniform(-89, -20),
            pitch,
            roll,
            sroll=rng.uniform(0, 360),
            hfov=rng.uniform(2, 30),
            vfov=rng.uniform(2, 20),
            i=i,
            full=full,
        )
        d = dec(f)
        v = los_ned(
            d["platform_heading_deg"],
            d.get("platform_pitch_full_deg", d["platform_pitch_deg"]),
            d.get("platform_roll_full_deg", d["platform_roll_deg"]),
            d["sensor_relative_azimuth_deg"],
            d["sensor_relative_elevation_deg"],
            d["sensor_relative_roll_deg"],
        )
        if v[2] < 0.35:  # keep lines of sight well below the horizon (the corners too)
            continue
        f2, centre, ks = with_oracle(f)
        if not all(np.isfinite(ks).ravel()):
            continue
        packets.append(f2)
        expected.append(centre)
        kexp.append(ks)
    assert len(packets) >= 12
    r = replay_klv(stream(packets))
    check_against_oracle(r, expected, kexp)


def test_hand_written_sign_cases():
    """Signs a person can check: heading 0, turret 90 right, 45 down looks east, h/tan(45) away;
    a right bank of 10 deg with the turret at nadir looks 10 deg left of nadir (west, heading north)."""
    f = pose_fields(10.0, 20.0, 3000.0, 0.0, 90.0, -45.0)
    r = replay_klv(encode_packet(f))
    lat, lon = r.columns["lat_deg"][0], r.columns["lon_deg"][0]
    assert abs(lat - 10.0) < 2e-4 and lon > 20.0
    assert horizontal_distance_m(10.0, 20.0, lat, lon) == pytest.approx(3000.0, rel=2e-3)
    f = pose_fields(10.0, 20.0, 3000.0, 0.0, 0.0, -90.0, roll=10.0)
    r = replay_klv(encode_packet(f))
    lat, lon = r.columns["lat_deg"][0], r.columns["lon_deg"][0]
    assert lon < 20.0 and abs(lat - 10.0) < 1e-4
    assert horizontal_distance_m(10.0, 20.0, lat, lon) == pytest.approx(3000 * math.tan(math.radians(10)), rel=2e-3)


def test_fov_scaling_equals_one_sensor_per_packet():
    """Packets of different fields of view share one sensor; each packet's corners are those of
    ``lens_from_fov(its hfov, its vfov)`` at the image corners (0.5 and N + 0.5)."""
    from geoloc.frames.chain import Pose
    from geoloc.locate import locate

    fovs = [(2.0, 1.2), (10.0, 5.625), (30.0, 17.0), (55.0, 40.0)]
    packets = [
        pose_fields(36.6, -84.25, 3000.0, 40.0 * i, 80.0, -50.0, 3.0, -8.0, 25.0, h, v, i=i)
        for i, (h, v) in enumerate(fovs)
    ]
    r = replay_klv(stream(packets))
    for i, f in enumerate(packets):
        d = dec(f)
        s = FrameSensor(
            lens_from_fov(
                math.radians(d["sensor_horizontal_fov_deg"]), math.radians(d["sensor_vertical_fov_deg"]), 1920, 1080
            ),
            PRESETS["azimuth-elevation-roll"],
        )
        pose = Pose.from_deg(
            d["sensor_latitude_deg"],
            d["sensor_longitude_deg"],
            d["sensor_ellipsoid_height_m"],
            d["platform_heading_deg"],
            d["platform_pitch_deg"],
            d["platform_roll_deg"],
            angles_deg={
                "azimuth": d["sensor_relative_azimuth_deg"],
                "elevation": d["sensor_relative_elevation_deg"],
                "sensor_roll": d["sensor_relative_roll_deg"],
            },
        )
        g = locate(
            pose,
            s,
            np.array([0.5, 0.5, 1080.5, 1080.5]),
            np.array([0.5, 1920.5, 1920.5, 0.5]),
            target_h=d["frame_center_hae_m"],
            height_kind="geodetic",
        )
        for j in range(4):
            dk = horizontal_distance_m(
                r.columns[f"corner{j + 1}_lat_deg"][i],
                r.columns[f"corner{j + 1}_lon_deg"][i],
                g.lat_deg[j],
                g.lon_deg[j],
            )
            assert dk < 1e-6


# ------------------------------------------------------------------ outliers, bad packets, missing tags


def test_planted_300_m_shift_is_the_only_outlier():
    packets = []
    for i in range(40):
        f, _, _ = with_oracle(pose_fields(36.6 + 0.0005 * i, -84.25, 2800.0, 0.0, 90.0, -40.0, i=i), corners=False)
        packets.append(f)
    packets[17]["frame_center_latitude_deg"] += 300.0 / 111_000.0  # 300 m north
    r = replay_klv(stream(packets))
    assert list(np.flatnonzero(r.columns["outlier"])) == [17]
    assert r.columns["frame_center_error_m"][17] == pytest.approx(300.0, rel=0.01)
    assert r.summary.outliers == [17]
    assert "packets 17" in str(r.summary)


def test_outlier_rule():
    rng = np.random.default_rng(5)
    e = np.abs(rng.normal(10.0, 2.0, 500))
    e[[3, 99]] = [60.0, 45.0]
    e[7] = np.nan
    mask, med, mad, thr = outlier_mask(e)
    assert thr == pytest.approx(3.5 * 1.4826 * mad)
    assert mask[3] and mask[99] and not mask[7]
    # every flag is exactly the rule
    with np.errstate(invalid="ignore"):
        assert np.array_equal(mask, np.isfinite(e) & (np.abs(e - med) > thr))
    # millimetre-level errors: the 1 m floor keeps quantisation noise unflagged
    mask, _, _, thr = outlier_mask(rng.uniform(0, 0.005, 100))
    assert thr == 1.0 and not mask.any()
    assert outlier_mask([np.nan])[0].tolist() == [False]


def test_bad_packet_in_the_middle_reported_with_its_offset(tmp_path):
    packets = [
        with_oracle(pose_fields(36.6, -84.25 + 0.001 * i, 2500.0, 10.0 * i, 90.0, -35.0, i=i))[0] for i in range(12)
    ]
    blobs = [encode_packet(f) for f in packets]
    clean = replay_klv(b"".join(blobs))
    bad = bytearray(blobs[5])
    bad[30] ^= 0xFF
    blobs[5] = bytes(bad)
    offset = sum(len(b) for b in blobs[:5])
    p = tmp_path / "x.klv"
    p.write_bytes(b"".join(blobs))
    for fast in (True, False):
        r = replay_klv(p, fast=fast)
        assert [e.offset for e in r.errors] == [offset]
        assert "checksum mismatch" in r.errors[0].reason
        assert list(r.columns["packet"]) == [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]
        keep = [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]
        for name in ("lat_deg", "lon_deg", "frame_center_error_m", "corner1_lat_deg"):
            assert np.array_equal(r.columns[name], clean.columns[name][keep])
        assert f"byte {offset}" in str(r.summary)
    # stray bytes are no packet: reported, and they do not count as a packet
    p.write_bytes(b"".join(blobs[:3]) + b"garbage!" + b"".join(blobs[6:]))
    r = replay_klv(p)
    assert [e.offset for e in r.errors] == [sum(len(b) for b in blobs[:3])]
    assert list(r.columns["packet"]) == [0, 1, 2, 3, 4, 5, 6, 7, 8]


def test_fast_and_packet_by_packet_reads_agree():
    packets = [with_oracle(pose_fields(36.6, -84.25, 2500.0, 7.0 * i, 45.0, -50.0, i=i))[0] for i in range(40)]
    data = stream(packets)
    a, b = read_klv(data, fast=True), read_klv(data, fast=False)
    assert a.columns.keys() == b.columns.keys()
    for k in a.columns:
        assert np.array_equal(a.columns[k], b.columns[k], equal_nan=a.columns[k].dtype.kind == "f"), k


def test_replay_names_where_the_clock_goes_back_on_both_reads(tmp_path):
    # seconds after T0: one step back of 0.25 s (packet 4), then a clock that restarts 10 s back
    # (packet 6): every packet is kept and located in file order, and the summary says once how many
    # went back and where the first did, whichever read the bytes took (the columnar fast path that
    # tiles the file, or packet by packet)
    sec = [0.0, 1.0, 2.0, 1.75, 3.0, -7.0, -6.0]
    packets = []
    for i, x in enumerate(sec):
        f = with_oracle(pose_fields(36.6, -84.25, 2500.0, 7.0 * i, 45.0, -50.0, i=i))[0]
        f["precision_time_stamp_us"] = T0 + round(x * 1e6)
        packets.append(f)
    blobs = [encode_packet(f) for f in packets]
    offsets = np.concatenate([[0], np.cumsum([len(b) for b in blobs])[:-1]]).tolist()
    want = [
        f"2 packets, the first: packet 4 (byte {offsets[3]}): Precision Time Stamp goes back 0.250000 s "
        f"from packet 3 (byte {offsets[2]})"
    ]
    data = b"".join(blobs)
    for fast in (True, False):
        r = replay_klv(data, fast=fast)
        assert list(r.columns["status"]) == [Status.OK] * len(sec), fast
        assert r.summary.time_back == want, (fast, r.summary.time_back)
        assert f"  time goes back: {want[0]}" in str(r.summary).splitlines()
    # a clock that only runs forward says nothing
    assert replay_klv(stream(packets[:3])).summary.time_back == []
    # the command line prints the same line in its summary
    path = tmp_path / "back.klv"
    path.write_bytes(data)
    cli = run_cli("replay", str(path), "--out", str(tmp_path / "back.csv"))
    assert cli.returncode == 0, cli.stderr
    assert f"  time goes back: {want[0]}" in cli.stdout.splitlines(), cli.stdout


def test_missing_tags_named_and_the_good_packets_run():
    base = [with_oracle(pose_fields(36.6, -84.25, 2500.0, 20.0, 90.0, -35.0, i=i))[0] for i in range(6)]
    del base[1]["sensor_latitude_deg"]
    del base[2]["sensor_relative_elevation_deg"]
    del base[3]["frame_center_hae_m"]
    del base[4]["sensor_relative_roll_deg"]
    base[5]["platform_pitch_deg"] = math.nan  # the reserved "out of range" value, no tag 90
    r = replay_klv(stream(base))
    st = r.columns["status"]
    notes = r.columns["note"]
    assert st[0] == Status.OK and notes[0] == ""
    assert st[1] == Status.INVALID_INPUT and "tag 13 (Sensor Latitude)" in notes[1]
    assert st[2] == Status.INVALID_INPUT and "tag 19 (Sensor Relative Elevation Angle)" in notes[2]
    assert st[3] == Status.INVALID_INPUT and "tag 78" in notes[3] and "tag 25" in notes[3]
    assert st[5] == Status.INVALID_INPUT and "tag 90 or tag 6" in notes[5]
    # no sensor roll: the frame centre is the roll axis (no boresight), the corners need it
    assert st[4] == Status.OK and "corners not computed" in notes[4] and "tag 20" in notes[4]
    assert np.isnan(r.columns["corner1_lat_deg"][4]) and r.columns["corner_status"][4] == Status.INVALID_INPUT
    assert r.columns["frame_center_error_m"][4] < 6e-3
    assert np.isnan(r.columns["lat_deg"][1:4]).all()
    text = str(r.summary)
    assert "invalid_input 4" in text and "tag 13 (Sensor Latitude)" in text


def test_container_reads_same_as_raw(tmp_path):
    packets = [
        with_oracle(pose_fields(36.6, -84.25, 2500.0 + 10 * i, 12.0 * i, 80.0, -40.0, i=i))[0] for i in range(20)
    ]
    data = stream(packets)
    raw = replay_klv(data)
    ts = tmp_path / "clip.ts"
    write_ts(ts, [encode_packet(f) for f in packets], rate=5.0)
    r = replay_klv(ts)
    assert len(r) == 20 and r.errors == []
    for k in raw.columns:
        if k in ("file", "offset", "pts_s"):
            continue
        a, b = raw.columns[k], r.columns[k]
        if a.dtype.kind == "f":
            assert np.array_equal(a, b, equal_nan=True), k
        else:
            assert list(a) == list(b), k
    assert np.allclose(r.columns["pts_s"] - r.columns["pts_s"][0], np.arange(20) / 5.0)


# ------------------------------------------------------------------ datums


def proj_undulation(lat_deg, lon_deg):
    """N from PROJ's own vgridshift reading the bundled EGM96 crop (pyproj): independent code."""
    from pyproj import Transformer

    grids = f"@{GEOID_DIR / 'egm96_jacksboro.tif'},{GEOID_DIR / 'egm96_global_30min.tif'}"
    t = Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grids} +multiplier=1 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )
    return float(t.transform(lon_deg, lat_deg, 0.0)[2])


def test_msl_altitude_only_made_ellipsoidal_with_egm96():
    """Tag 15 (MSL) only, and tag 25 (MSL) only: h = H + N, N from PROJ on the bundled grid."""
    lat, lon, h_true = 36.60, -84.25, 2500.0
    n_s = proj_undulation(lat, lon)
    assert n_s == pytest.approx(-30.6, abs=0.2)  # the EGM96 N there
    f = pose_fields(lat, lon, h_true, 30.0, 90.0, -30.0)
    del f["sensor_ellipsoid_height_m"], f["frame_center_hae_m"]
    f["sensor_true_altitude_m"] = h_true - n_s
    f["frame_center_elevation_m"] = 0.0 - n_s  # the ground point at h = 0 is 30.6 m above the geoid
    d = dec(f)
    h_s = d["sensor_true_altitude_m"] + n_s
    v = los_ned(
        d["platform_heading_deg"], 0.0, 0.0, d["sensor_relative_azimuth_deg"], d["sensor_relative_elevation_deg"], 0.0
    )
    # N at the frame centre: 4 km east of the sensor, from PROJ too
    la0, lo0 = oracle_point(lat, lon, h_s, v, 0.0)
    n_fc = proj_undulation(la0, lo0)
    delta = d["frame_center_elevation_m"] + n_fc
    centre = oracle_point(d["sensor_latitude_deg"], d["sensor_longitude_deg"], h_s, v, delta)
    r = replay_klv(encode_packet(dict(d, frame_center_latitude_deg=centre[0], frame_center_longitude_deg=centre[1])))
    c = r.columns
    assert c["sensor_h_m"][0] == pytest.approx(h_s, abs=1e-6)
    assert c["sensor_h_from"][0] == "tag 15 (MSL) + EGM96 N"
    assert c["sensor_geoid_n_m"][0] == pytest.approx(n_s, abs=1e-6)
    assert c["reported_h_m"][0] == pytest.approx(delta, abs=1e-4)
    assert c["reported_h_from"][0] == "tag 25 (MSL) + EGM96 N"
    assert c["sensor_true_altitude_msl_m"][0] == d["sensor_true_altitude_m"]
    check_against_oracle(r, [centre])
    assert r.summary.sensor_h_sources["tag 15 (MSL) + EGM96 N"] == 1
    # ignoring N would have put the sensor 30.6 m low: tens of metres off at 30 deg depression
    f_wrong = dict(
        d,
        sensor_ellipsoid_height_m=d["sensor_true_altitude_m"],
        frame_center_latitude_deg=centre[0],
        frame_center_longitude_deg=centre[1],
    )
    r2 = replay_klv(encode_packet(f_wrong))
    assert r2.columns["frame_center_error_m"][0] > 40
    assert "tag 75 - tag 15 = +0.0 m but EGM96 N = -30.6 m" in r2.columns["datum_warning"][0]


def test_consistent_datums_give_no_warning():
    f = pose_fields(36.6, -84.25, 2500.0, 30.0, 90.0, -30.0)
    n_s = proj_undulation(36.6, -84.25)
    f["sensor_true_altitude_m"] = 2500.0 - n_s
    r = replay_klv(encode_packet(f))
    assert r.columns["datum_warning"][0] == "" and r.summary.datum_warnings == []
    assert set(r.columns["h_datum"]) == {"ellipsoid (WGS 84)"}


def test_time_stamp_to_utc():
    f = pose_fields(0.0, 0.0, 1000.0, 0.0, 0.0, -90.0)
    f["precision_time_stamp_us"] = 1224807209913000  # the standard's example: 2008-10-24 00:13:29.913
    r = replay_klv(encode_packet(f))
    assert r.columns["time_utc"][0] == "2008-10-24T00:13:29.913000Z"
    assert r.columns["time_s"][0] == 1224807209.913


# ------------------------------------------------------------------ sensor files


def test_sensor_file_gives_size_mount_lever_arm(tmp_path):
    from geoloc.sensors.sensor_file import load_sensor

    f = with_oracle(pose_fields(36.6, -84.25, 2500.0, 30.0, 90.0, -30.0, sroll=10.0))[0]
    ref = replay_klv(encode_packet(f))
    p = tmp_path / "s.toml"
    p.write_text(
        '[lens]\nmodel = "pinhole"\nfx = 900.0\nfy = 900.0\ncx = 640.5\ncy = 360.5\nwidth = 1280\n'
        'height = 720\n\n[gimbal]\npreset = "azimuth-elevation"\n'
    )
    r = replay_klv(encode_packet(f), sensor=load_sensor(p))
    assert (r.sensor.cols, r.sensor.rows) == (1280, 720)
    for k in ("lat_deg", "lon_deg", "corner1_lat_deg", "corner3_lon_deg"):
        assert r.columns[k][0] == pytest.approx(ref.columns[k][0], abs=1e-9)
    p.write_text(p.read_text() + "\n[lever_arm]\nx_m = 0.0\ny_m = 0.0\nz_m = 50.0\n")
    r = replay_klv(encode_packet(f), sensor=load_sensor(p))  # 50 m lower optical centre
    assert r.columns["frame_center_error_m"][0] == pytest.approx(50 / math.tan(math.radians(30)), rel=0.01)
    p.write_text(p.read_text().replace("azimuth-elevation", "roll-pitch"))
    with pytest.raises(ValueError, match="azimuth-elevation-roll"):
        replay_klv(encode_packet(f), sensor=load_sensor(p))


# ------------------------------------------------------------------ the bundled example flight


def load_tool():
    spec = importlib.util.spec_from_file_location("make_klv_example", ROOT / "tools" / "make_klv_example.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tool():
    return load_tool()


@pytest.fixture(scope="module")
def dem():
    from geoloc.surfaces.dem import DEM

    return DEM.open(DEM_PATH)


def planted(tool, *names):
    out = set()
    for name in names:
        a, b, _ = tool.FAULTS[name]
        out |= set(range(a, b + 1))
    return out


def test_bundled_example_is_what_the_tool_makes(tool, dem):
    blobs = tool.make_packets(dem)
    data = EXAMPLE.read_bytes()
    assert len(blobs) == tool.N_PACKETS == 300
    ours = read_klv(b"".join(blobs), fast=False)
    bundled = read_klv(data, fast=False)
    assert [e.offset for e in ours.errors] == [e.offset for e in bundled.errors]
    for k, spec in TAG_BY_NAME.items():
        if spec.kind in ("uint", "int"):
            a, b = ours.columns[k], bundled.columns[k]
            assert np.array_equal(np.isnan(a), np.isnan(b)), k
            assert np.nanmax(np.abs(a - b), initial=0.0) <= spec.step * 1.01, k


@pytest.mark.parametrize("with_dem", [False, True])
def test_example_flight_flags_the_planted_packets_and_no_others(tool, dem, with_dem):
    r = replay_klv(EXAMPLE, surface=surface_for(dem=dem) if with_dem else None)
    c = r.columns
    # the corrupted packet: reported at its offset, the 299 others replayed
    a, _, _ = tool.FAULTS["corrupted"]
    assert len(r.errors) == 1 and "checksum mismatch" in r.errors[0].reason
    assert r.errors[0].offset == sum(len(b) for b in tool.make_packets(dem)[:a])
    assert len(r) == 299 and a not in set(c["packet"])
    # file packet numbers match time stamps (1 Hz from 15:00:00 UTC)
    assert np.array_equal(c["time_s"] - c["time_s"][0], c["packet"].astype(float))
    flagged = set(c["packet"][c["outlier"] == 1].tolist())
    assert flagged == planted(tool, "yaw_bias", "wrong_datum", "stale_pose")
    warned = set(c["packet"][c["datum_warning"] != ""].tolist())
    assert warned == planted(tool, "wrong_datum")
    (missing,) = planted(tool, "missing_angles")
    k = int(np.flatnonzero(c["packet"] == missing)[0])
    assert c["status"][k] == Status.INVALID_INPUT and "tag 18" in c["note"][k] and "tag 19" in c["note"][k]
    good = (c["outlier"] == 0) & (c["status"] == Status.OK)
    assert good.sum() == 299 - 22 - 1
    e = c["frame_center_error_m"]
    yaw = np.isin(c["packet"], sorted(planted(tool, "yaw_bias")))
    assert np.all(e[yaw] > 80)  # 2.5 deg at ~2.6 km ground range
    if with_dem:
        # the platform's centres and corners were computed on this DEM from these very values
        assert e[good].max() < 0.01 and np.nanmax(c["corner_error_m"][good]) < 0.01
    else:
        # the centre at the packet's own height (tag 78, 0.3 m steps): decimetres; the corners
        # at that height instead of on the terrain: tens of metres (the terrain's effect)
        assert e[good].max() < 0.5
        assert np.nanmedian(c["corner_error_m"][good]) > 10


# ------------------------------------------------------------------ CSV and the command line


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "geoloc", *args], capture_output=True, text=True, cwd=cwd)


def test_csv_round_trip_through_gis_reader(tmp_path):
    from geoloc.io.gis import read_results

    r = replay_klv(EXAMPLE)
    out = tmp_path / "f.csv"
    assert write_klv_csv(out, r) == 299
    t = read_results(out)
    assert t["status"][0] == "ok" and t["h_datum"][0] == "ellipsoid (WGS 84)"
    assert np.allclose(t["lat_deg"], r.columns["lat_deg"], atol=1e-9, equal_nan=True)
    assert np.allclose(t["frame_center_error_m"], r.columns["frame_center_error_m"], atol=1e-4, equal_nan=True)
    assert t["time_utc"][0] == "2024-05-14T15:00:00.000000Z"
    with out.open() as fh:
        header = next(csv.reader(fh))
    for name in (
        "reported_lat_deg",
        "reported_lon_deg",
        "reported_h_m",
        "sensor_lat_deg",
        "sensor_lon_deg",
        "sensor_h_m",
        "corner4_lon_deg",
        "time_s",
        "time_utc",
        "h_datum",
        "outlier",
        "corner_error_m",
        "sensor_true_altitude_msl_m",
        "frame_center_elevation_msl_m",
    ):
        assert name in header


def test_cli_replay_klv_out_and_export(tmp_path):
    out, gpkg = tmp_path / "f.csv", tmp_path / "x.gpkg"
    p = run_cli("replay", str(EXAMPLE), "--out", str(out), "--export", str(gpkg))
    assert p.returncode == 0, p.stderr
    assert "299 packets read, 1 bad packet(s) skipped" in p.stdout
    assert "packets 100-109, 200-204, 250-256" in p.stdout
    assert "byte 32400" in p.stderr and "checksum mismatch" in p.stderr
    assert "wrote 299 rows" in p.stdout and "ellipsoidal" in p.stdout
    api = replay_klv(EXAMPLE)
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 299
    assert float(rows[10]["lat_deg"]) == pytest.approx(api.columns["lat_deg"][10], abs=1e-9)
    import pyogrio

    layers = {name for name, _ in pyogrio.list_layers(gpkg)}
    assert {"points", "reported", "footprints", "track"} <= layers
    from pyogrio import raw

    meta, _, geoms, _ = raw.read(str(gpkg), layer="points")
    assert len(geoms) == 299 and "frame_center_error_m" in list(meta["fields"])
    assert len(raw.read(str(gpkg), layer="footprints")[2]) == 299


def test_cli_replay_ts_with_dem_and_errors(tmp_path):
    packets = [
        with_oracle(pose_fields(36.6, -84.25 + 0.0005 * i, 2500.0, 5.0 * i, 90.0, -35.0, i=i))[0] for i in range(8)
    ]
    ts = tmp_path / "clip.ts"
    write_ts(ts, [encode_packet(f) for f in packets], rate=2.0)
    p = run_cli("replay", str(ts), "--dem", str(DEM_PATH))
    assert p.returncode == 0, p.stderr
    assert "8 packets read, 0 bad packet(s) skipped" in p.stdout and "surface: DEM" in p.stdout
    assert "frame-centre error" in p.stdout and "h_m (HAE)" in p.stdout  # rows printed (8 <= 50)
    p = run_cli("replay", str(ts), "--target-h-m", "100")
    assert p.returncode == 2 and "--target-h-m" in p.stderr
    p = run_cli("replay", str(ts), str(ROOT / "assets" / "records" / "qiao2017_flight_tests.csv"))
    assert p.returncode == 2 and "different kinds" in p.stderr
    empty = tmp_path / "empty.klv"
    empty.write_bytes(b"not a klv file at all")
    p = run_cli("replay", str(empty))
    assert p.returncode == 1 and "not a UAS LS packet" in p.stderr


def test_module_constants():
    assert klv_replay.is_klv_path("a.KLV") and klv_replay.is_klv_path("b.ts") and klv_replay.is_klv_path("c.mp4")
    assert not klv_replay.is_klv_path("d.csv")
