"""`geoloc log` of the turret flight (the bundled MISB ST 0601 example), read back
with rerun's own reader (``rerun.chunk.RrdReader``, rerun-sdk 0.41): the gimbal series under the
sensor's joint names, the DEM `geoloc view` draws and its mesh, and the footprint corners on that
DEM, checked against `geoloc locate --dem` of the corner pixels (another command, another sensor
built from a sensor file, one pixel at a time). ``--spawn``: refused without a display, and with
one it opens the viewer on the written file, bound to 127.0.0.1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import ASSETS
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.workflows.klv_replay import klv_pose_deg, replay_klv

KLV = Path(ASSETS) / "klv" / "example_flight.klv"
SRTM = Path(ASSETS) / "dem" / "srtm_jacksboro.tif"
#: Packets whose corners are located again (ordinary frames, away from the planted faults).
PACKETS = (5, 180)


def read(path) -> dict:
    """Entity path -> list of pyarrow record batches of the recording."""
    from rerun.chunk import RrdReader

    out: dict = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, []).append(ch.to_record_batch())
    return out


def column(batches, name):
    """(packet, value) rows of a temporal column, sorted by packet."""
    pk, val = [], []
    for b in batches:
        if "packet" in b.schema.names and name in b.schema.names:
            pk += b.column("packet").to_pylist()
            val += b.column(name).to_pylist()
    order = np.argsort(pk)
    return np.asarray(pk)[order], [val[i] for i in order]


@pytest.fixture(scope="module")
def turret(tmp_path_factory, rerun_home):
    out = tmp_path_factory.mktemp("turret") / "turret.rrd"
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "log", str(KLV), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert f"DEM {SRTM}" in r.stderr  # the bundled DEM covering the flight, said on stderr
    return read(out)


def test_gimbal_series_are_the_turret_joints_by_name(turret):
    # MISB ST 0601 tags 18-20, the azimuth-elevation-roll joints: under their own names, as the
    # packets give them (the [Q17] names, logged as zeros before, are gone)
    rep = replay_klv(KLV).columns
    want = dict(zip(rep["packet"], zip(rep["sensor_relative_azimuth_deg"], rep["sensor_relative_elevation_deg"])))
    assert "/series/gimbal/gimbal_roll_deg" not in turret and "/series/gimbal/gimbal_pitch_deg" not in turret
    for j, name in enumerate(("azimuth_deg", "elevation_deg")):
        pk, v = column(turret[f"/series/gimbal/{name}"], "Scalars:scalars")
        v = np.asarray([x[0] for x in v])
        # the decoded degrees, float64 through rad2deg(deg2rad(x)): a few ulp of 360
        np.testing.assert_allclose(v, [want[p][j] for p in pk], rtol=0, atol=1e-12)
        assert np.all(np.abs(v) > 1.0), name  # azimuth ~91 deg, elevation ~-36 deg: far from zero
    assert "/series/gimbal/sensor_roll_deg" in turret


def test_dem_and_its_mesh_are_logged(turret):
    mesh = [b for b in turret["/world/dem"] if "Mesh3D:triangle_indices" in b.schema.names]
    assert mesh, "no terrain mesh entity"
    tri = mesh[0].column("Mesh3D:triangle_indices").to_pylist()[0]
    assert len(tri) > 1000  # the SRTM crop around the flight, not a token patch
    text = turret["/info"][0].column("TextDocument:text").to_pylist()[0][0]
    assert "srtm_jacksboro.tif" in text


def test_corners_are_on_the_dem_as_geoloc_locate_finds_them(turret, tmp_path, rerun_home):
    rep = replay_klv(KLV).columns  # the pose as decoded (not the corners: those are what is tested)
    pk, rings = column(turret["/map/corners"], "GeoLineStrings:line_strings")
    _, rings3 = column(turret["/world/corners"], "LineStrips3D:strips")
    row_of = {int(p): k for k, p in enumerate(pk)}
    enu = scene_origin(turret)  # the 3D rings are in the scene's ENU frame
    checked = 0
    for packet in PACKETS:
        k = int(np.flatnonzero(np.asarray(rep["packet"]) == packet)[0])
        d = klv_pose_deg(rep, k)
        hfov, vfov = float(rep["sensor_horizontal_fov_deg"][k]), float(rep["sensor_vertical_fov_deg"][k])
        sensor = tmp_path / f"fov_{packet}.toml"
        # the packet's own lens (ST 0601 gives fields of view) on the MISB joints, as a sensor file
        sensor.write_text(
            f'name = "packet {packet}"\n[lens]\nmodel = "fov"\nhfov_deg = {hfov!r}\n'
            f"vfov_deg = {vfov!r}\nwidth = 1920\nheight = 1080\n"
            '[gimbal]\npreset = "azimuth-elevation-roll"\n'
        )
        ring = np.asarray(rings[row_of[packet]][0])  # (5, 2) lat, lon: a closed ring
        assert np.array_equal(ring[0], ring[4])
        # corners: upper left, upper right, lower right, lower left; the outer edges of the
        # corner pixels (1-based centres: rows 0.5 and M + 0.5, columns 0.5 and N + 0.5)
        for j, (row, col) in enumerate(((0.5, 0.5), (0.5, 1920.5), (1080.5, 1920.5), (1080.5, 0.5))):
            cmd = [
                sys.executable,
                "-m",
                "geoloc",
                "locate",
                "--json",
                "--sensor",
                str(sensor),
                "--lat-deg",
                repr(d["lat_deg"]),
                "--lon-deg",
                repr(d["lon_deg"]),
                "--h-m",
                repr(d["h_m"]),
                "--altitude-datum",
                "ellipsoid",
                "--heading-deg",
                repr(d["heading_deg"]),
                "--pitch-deg",
                repr(d["pitch_deg"]),
                "--roll-deg",
                repr(d["roll_deg"]),
                *[a for name, v in d["angles_deg"].items() for a in ("--angle", f"{name}={float(v)!r}")],
                "--row",
                str(row),
                "--col",
                str(col),
                "--dem",
                str(SRTM),
            ]
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            assert r.returncode == 0, r.stderr
            got = json.loads(r.stdout)
            # the exact DEM walk from two equal rays: the hits agree to well under 1 mm
            # (the recording's lat/lon are float64; the replay's corner pixel is scaled onto the
            # median lens, exact for a pinhole up to round-off)
            dist = horizontal_distance_m(ring[j, 0], ring[j, 1], got["lat_deg"], got["lon_deg"])
            assert dist < 1e-3, (packet, j, dist)
            # the 3D ring: float32 ENU coordinates within ~10 km of the origin (half an ulp: 0.5 mm)
            want = enu.from_geodetic(np.deg2rad(got["lat_deg"]), np.deg2rad(got["lon_deg"]), got["h_m"])
            np.testing.assert_allclose(np.asarray(rings3[row_of[packet]][0])[j], want, rtol=0, atol=2e-3)
            checked += 1
    assert checked == 4 * len(PACKETS)


def scene_origin(data):
    """The scene's ENU origin, read from the recording's About text (0.001 deg, whole metres)."""
    import re

    from geoloc.frames.enu import EnuFrame

    text = data["/info"][0].column("TextDocument:text").to_pylist()[0][0]
    m = re.search(r"scene origin \(ENU\): ([-\d.]+) N, ([-\d.]+) E, ([-\d.]+) m", text)
    lat, lon, h = (float(x) for x in m.groups())
    return EnuFrame.from_deg(lat, lon, h)


def test_spawn_without_a_display_is_refused_before_computing(tmp_path, rerun_home):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "log", str(KLV), "--spawn", "--out", str(tmp_path / "a.rrd")],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert r.returncode == 2
    assert "needs a display" in r.stderr and "--serve" in r.stderr and "rerun FILE" in r.stderr
    assert "spawn() ignored" not in r.stderr


def test_spawn_opens_the_viewer_on_the_written_file(tmp_path, monkeypatch, rerun_home):
    # a display, and a stand-in for the viewer binary that notes how it was started
    from geoloc_viz import rerun_log
    from geoloc_viz.rerun_model import steps_from_records

    argv_file = tmp_path / "argv.json"
    fake = tmp_path / "rerun"
    fake.write_text(f"#!{sys.executable}\nimport json, sys\njson.dump(sys.argv[1:], open({str(argv_file)!r}, 'w'))\n")
    fake.chmod(0o755)
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(rerun_log, "rerun_executable", lambda: str(fake))
    steps, _ = steps_from_records(Path(ASSETS) / "records" / "qiao2017_flight_tests.csv", calibrate=False)
    out = tmp_path / "spawned.rrd"
    rerun_log.write(steps, out, spawn=True)
    argv = json.loads(argv_file.read_text())
    assert argv == ["--bind", "127.0.0.1", "--port", "9876", str(out)]
    data = read(out)  # complete when the viewer opens it: the series of both flights (T3, T4)
    assert sum(k.endswith("/gimbal/gimbal_roll_deg") for k in data) == 2 and "/log/record" in data


def test_turret_records_without_heights_use_the_bundled_dem(tmp_path, rerun_home):
    # assets/records/eo_turret_flight.csv gives no target height: `geoloc log` locates it on the
    # bundled SRTM crop (as `geoloc view` does) instead of refusing, logs the mesh, and the
    # turret's joints under their names, equal to the file's columns (read here with csv)
    import csv

    records = Path(ASSETS) / "records" / "eo_turret_flight.csv"
    sensor = Path(ASSETS) / "sensors" / "eo_turret.toml"
    out = tmp_path / "turret_records.rrd"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "geoloc",
            "log",
            str(records),
            "--sensor",
            str(sensor),
            "--no-calibration",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert f"DEM {SRTM}" in r.stderr
    data = read(out)
    rows = list(csv.DictReader(records.open(newline="")))
    for name in ("azimuth", "elevation"):
        v = []
        for b in data[f"/series/gimbal/{name}_deg"]:
            if "record" in b.schema.names:
                v += [x[0] for x in b.column("Scalars:scalars").to_pylist()]
        # the file's degrees through rad2deg(deg2rad(x)): a few ulp
        np.testing.assert_allclose(v, [float(row[f"{name}_deg"]) for row in rows], rtol=0, atol=1e-12)
    assert any("Mesh3D:triangle_indices" in b.schema.names for b in data["/world/dem"])
    # two records' targets against `geoloc locate --dem` of their pixels (the exact walk both ways)
    pos = []
    for b in data["/map/target"]:
        if "record" in b.schema.names:
            pos += list(zip(b.column("record").to_pylist(), b.column("GeoPoints:positions").to_pylist()))
    target = dict(pos)
    for k in (0, 13):
        row = rows[k]
        cmd = [
            sys.executable,
            "-m",
            "geoloc",
            "locate",
            "--json",
            "--sensor",
            str(sensor),
            "--dem",
            str(SRTM),
            "--lat-deg",
            row["ac_lat_deg"],
            "--lon-deg",
            row["ac_lon_deg"],
            "--h-m",
            row["ac_h_m"],
            "--altitude-datum",
            "ellipsoid",
            "--heading-deg",
            row["heading_deg"],
            "--pitch-deg",
            row["pitch_deg"],
            "--roll-deg",
            row["roll_deg"],
            "--angle",
            f"azimuth={row['azimuth_deg']}",
            "--angle",
            f"elevation={row['elevation_deg']}",
            "--row",
            row["row"],
            "--col",
            row["col"],
        ]
        got = json.loads(subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True).stdout)
        lat, lon = target[k][0]
        # the same exact DEM walk from the same ray: well under 1 mm (float64 map positions)
        assert horizontal_distance_m(lat, lon, got["lat_deg"], got["lon_deg"]) < 1e-3, k
