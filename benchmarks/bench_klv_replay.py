"""KLV replay speed: decode MISB ST 0601 packets and recompute every frame centre and corner.

Encodes 100 000 UAS Datalink LS packets (an aircraft at 2.5-3.5 km over the
Jacksboro SRTM crop: position, attitude with the full-range pitch and roll, turret
angles, a field of view that changes every packet, reported frame centre with both
heights, full corners, slant range, time stamp; ~190 bytes each), then times

- decode: ``read_klv(data)`` (numpy columns, checksums verified);
- decode + replay: ``replay_klv(data)``, the frame centre and the four corners of every
  packet at the packet's own frame-centre height, errors to the reported ones,
  outliers (what ``geoloc replay FILE.klv`` does, without writing the CSV);
- decode + replay on the DEM: ``replay_klv(data, surface=surface_for(dem=DEM))`` (exact solver);
- writing the CSV of the replay (``write_klv_csv``), once.

Peers, measured in the same run:

- klvdata (an independent decoder, no checksum check): ``StreamParser`` + ``MetadataList``
  of the first ``--klvdata-packets`` packets (default 10 000: it is much slower);
- pymap3d ``lookAtSpheroid`` (vectorised numpy) on the five lines of sight per packet
  (frame centre and corners, azimuth and tilt given), intersection with the ellipsoid only:
  no decoding, no attitude chain, no errors.

Each figure is the median of ``--repeat`` runs (default 5; 3 for klvdata), wall time
(time.perf_counter) and CPU time (time.process_time). Prints packets per second and
``ratio: X`` = ours (decode + replay, packets/s) / klvdata (decode only, packets/s).

Run: python benchmarks/bench_klv_replay.py [--packets N] [--repeat R] [--klvdata-packets M]
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from geoloc.io.klv import encode_packet
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.klv_replay import read_klv, replay_klv, write_klv_csv

from _timing import timed  # benchmarks/_timing.py (the script's folder is on sys.path)

ROOT = Path(__file__).resolve().parents[1]


def make_packets(n, seed=0):
    from pymap3d.los import lookAtSpheroid

    rng = np.random.default_rng(seed)
    lat = rng.uniform(36.55, 36.63, n)
    lon = rng.uniform(-84.30, -84.19, n)
    h = rng.uniform(2500, 3500, n)
    heading = rng.uniform(0, 360, n)
    pitch = rng.normal(2, 1, n)
    roll = rng.normal(0, 5, n)
    az = rng.uniform(0, 360, n)
    el = rng.uniform(-70, -30, n)
    sroll = rng.uniform(-2, 2, n) % 360
    hfov = rng.uniform(2, 20, n)
    vfov = np.degrees(2 * np.arctan(np.tan(np.radians(hfov) / 2) * 9 / 16))
    # reported centres: the level-aircraft ray on the ellipsoid (so tens of metres off where the
    # aircraft pitches or banks: errors to find, as in real streams)
    fc_lat, fc_lon, rng_m = lookAtSpheroid(lat, lon, h, (heading + az) % 360, 90 + el)
    t0 = 1_700_000_000_000_000
    cols = dict(
        platform_heading_deg=heading,
        platform_pitch_deg=pitch,
        platform_roll_deg=roll,
        sensor_latitude_deg=lat,
        sensor_longitude_deg=lon,
        sensor_true_altitude_m=h + 30.6,
        sensor_horizontal_fov_deg=hfov,
        sensor_vertical_fov_deg=vfov,
        sensor_relative_azimuth_deg=az,
        sensor_relative_elevation_deg=el,
        sensor_relative_roll_deg=sroll,
        slant_range_m=rng_m,
        frame_center_latitude_deg=fc_lat,
        frame_center_longitude_deg=fc_lon,
        frame_center_elevation_m=np.full(n, 30.6),
        sensor_ellipsoid_height_m=h,
        frame_center_hae_m=np.zeros(n),
        platform_pitch_full_deg=pitch,
        platform_roll_full_deg=roll,
    )
    for k in range(4):
        cols[f"corner_latitude_{k + 1}_deg"] = fc_lat + rng.normal(0, 0.003, n)
        cols[f"corner_longitude_{k + 1}_deg"] = fc_lon + rng.normal(0, 0.003, n)
    lists = {k: v.tolist() for k, v in cols.items()}
    blobs = []
    for i in range(n):
        f = {k: v[i] for k, v in lists.items()}
        f["precision_time_stamp_us"] = t0 + 33_367 * i
        f["uas_ls_version"] = 17
        blobs.append(encode_packet(f))
    return blobs


def line(label, n, w, c, extra=""):
    print(f"{label:<44} wall {w * 1e3:9.1f} ms  cpu {c * 1e3:9.1f} ms  {n / w:12,.0f} packets/s{extra}")
    return n / w


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--packets", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--klvdata-packets", type=int, default=10_000)
    ap.add_argument("--klvdata-repeat", type=int, default=3)
    args = ap.parse_args()

    from geoloc.surfaces.dem import DEM

    dem = DEM.open(ROOT / "assets" / "dem" / "srtm_jacksboro.tif")
    t = time.perf_counter()
    blobs = make_packets(args.packets)
    t_enc = time.perf_counter() - t
    data = b"".join(blobs)
    n = len(blobs)
    print(
        f"packets: {n}, {len(data) / n:.0f} bytes each, {len(data) / 1e6:.1f} MB "
        f"(encoded in {t_enc:.2f} s, {n / t_enc:,.0f} packets/s)"
    )
    replay_klv(b"".join(blobs[:2000]))  # compile / warm the kernels outside the timings
    replay_klv(b"".join(blobs[:2000]), surface=surface_for(dem=dem))

    w, c, rd = timed(lambda: read_klv(data), args.repeat)
    assert len(rd) == n and not rd.errors
    line("decode (read_klv: numpy columns)", n, w, c)
    w, c, r = timed(lambda: replay_klv(data), args.repeat)
    assert len(r) == n
    ours = line("decode + replay (frame-centre height)", n, w, c)
    ok = np.mean(r.columns["status"] == 0)
    print(
        f"    {ok:.1%} located; frame-centre error median {r.summary.median_m:.1f} m; "
        f"{len(r.summary.outliers)} outliers"
    )
    w, c, rdem = timed(lambda: replay_klv(data, surface=surface_for(dem=dem)), args.repeat)
    line("decode + replay (DEM, exact)", n, w, c)
    okd = np.mean(rdem.columns["status"] == 0)
    print(f"    {okd:.1%} located on the DEM")
    with tempfile.TemporaryDirectory() as tmp:
        w, c, _ = timed(lambda: write_klv_csv(Path(tmp) / "f.csv", r), 1)
        line(f"write the CSV ({len(r.columns)} columns)", n, w, c)

    # pymap3d on the same lines of sight: azimuth and tilt from the replay's directions
    from pymap3d.los import lookAtSpheroid

    from geoloc.frames.chain import Pose
    from geoloc.geodesy.local import R_ecef_ned
    from geoloc.locate import line_of_sight

    cc = r.columns
    pose = Pose.from_deg(
        cc["sensor_lat_deg"],
        cc["sensor_lon_deg"],
        cc["sensor_h_m"],
        cc["platform_heading_deg"],
        cc["platform_pitch_deg"],
        cc["platform_roll_deg"],
        angles_deg={
            "azimuth": cc["sensor_relative_azimuth_deg"],
            "elevation": cc["sensor_relative_elevation_deg"],
            "sensor_roll": cc["sensor_relative_roll_deg"],
        },
    )
    s = r.sensor
    rows = np.array([s.center_pixel[0], 0.5, 0.5, s.rows + 0.5, s.rows + 0.5])[:, None]
    colp = np.array([s.center_pixel[1], 0.5, s.cols + 0.5, s.cols + 0.5, 0.5])[:, None]
    los = line_of_sight(pose, s, rows, colp, outside="extrapolate")
    d_ned = np.einsum("...ji,...j->...i", R_ecef_ned(pose.lat, pose.lon), los.direction_ecef)
    az = np.degrees(np.arctan2(d_ned[..., 1], d_ned[..., 0])) % 360
    tilt = np.degrees(np.arccos(np.clip(d_ned[..., 2], -1, 1)))
    la0 = np.broadcast_to(cc["sensor_lat_deg"], az.shape)
    lo0 = np.broadcast_to(cc["sensor_lon_deg"], az.shape)
    # pymap3d meets h = 0; the packets' frame-centre height (tag 78) decodes to 0.026 m: start
    # that much lower (the points then differ by ~0.026 m x range / R_earth, 1e-5 m)
    h0 = np.broadcast_to(cc["sensor_h_m"] - cc["reported_h_m"], az.shape)
    w, c, pm = timed(lambda: lookAtSpheroid(la0, lo0, h0, az, tilt), args.repeat)
    pm3 = line("pymap3d lookAtSpheroid (5 rays per packet)", n, w, c, "  (intersection only)")
    from geoloc.geodesy.geodesic import horizontal_distance_m

    dd = horizontal_distance_m(pm[0][0], pm[1][0], cc["lat_deg"], cc["lon_deg"])
    print(f"    pymap3d vs ours on the frame centres: max {np.nanmax(dd) * 1e3:.2f} mm apart")

    import klvdata

    m = min(args.klvdata_packets, n)
    sub = b"".join(blobs[:m])
    w, c, kd = timed(lambda: [p.MetadataList() for p in klvdata.StreamParser(sub)], args.klvdata_repeat)
    assert len(kd) == m
    theirs = line(f"klvdata decode only ({m} packets)", m, w, c)
    print(f"ours (decode + replay) / pymap3d (intersection only): {ours / pm3:.2f}")
    print(f"ratio: {ours / theirs:.1f}")


if __name__ == "__main__":
    main()
