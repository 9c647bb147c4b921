"""Every input tells the truth: a drone kilometres up is warned about.

The rule (docs/records.md, "Plausibility checks"): a platform is a drone when the photo is a
drone photo, or when the sensor file's ``platform``, a records ``platform`` cell or a KLV
Platform Designation names one (geoloc.sensors.platform.DRONE_WORDS); a drone's camera more
than 1000 m above the terrain (or the target) under it, or above 7000 m, is warned about with
the line, the field and the value, and what it likely is. The rows still run as read.
"""

from __future__ import annotations

import csv

import pytest

from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.sensors.platform import DRONE_CEILING_M, DRONE_MAX_HEIGHT_M, FOOT_M, is_drone
from geoloc.sensors.sensor_file import load_sensor, sensor_from_dict, sensor_to_toml
from geoloc.status import Status

SRTM = asset_path("dem", "srtm_jacksboro.tif")
DRONE = asset_path("records", "drone_targets.csv")
DRONE_SENSOR = asset_path("sensors", "drone_camera.toml")
Q17 = asset_path("records", "qiao2017_flight_tests.csv")
PHOTO = asset_path("photos", "DJI_0001.JPG")
TARGETS = asset_path("photos", "targets.csv")


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.reader(f))


def _write(path, rows):
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return path


def _in_feet(tmp_path):
    """The bundled drone records, ac_h_m in feet (x 1/0.3048, the international foot) under its metre name."""
    rows = _rows(DRONE)
    i = rows[0].index("ac_h_m")
    for r in rows[1:]:
        r[i] = f"{float(r[i]) / FOOT_M:.3f}"
    return _write(tmp_path / "drone_ft.csv", rows), rows


def test_the_numbers_of_the_rule():
    # 120 m (EU 2019/947, FAA Part 107's 400 ft = 121.9 m) and DJI's 500 m firmware cap lie well under
    # the threshold; 7000 m is the highest multirotor service ceiling (DJI Matrice 350 RTK)
    assert 400 * FOOT_M < 500 < DRONE_MAX_HEIGHT_M == 1000.0 and DRONE_CEILING_M == 7000.0


@pytest.mark.parametrize(
    "text, drone",
    [
        ("drone", True),
        ("DJI Matrice 300 RTK", True),
        ("Mavic 3E", True),
        ("quadcopter", True),
        ("small UAV", True),
        ("Small_UAS", True),
        ("Parrot Anafi USA", True),
        ("sUAS", True),
        ("MQ-9 Reaper UAV", False),
        ("RQ-4 Global Hawk", False),
        ("King Air 350", False),
        ("UAS", False),
        ("", False),
        (None, False),
        ("androne", False),
    ],
)
def test_what_names_a_drone(text, drone):
    assert is_drone(text) is drone


def test_drone_records_at_their_height_give_no_warning(capsys):
    # the bundled drone flight, about 130-300 m above the terrain (a drone's height): no warning,
    # on the DEM and at the surveyed target heights
    for extra in (["--dem", str(SRTM)], ["--height-column", "truth_h_m"]):
        assert main(["replay", str(DRONE), "--sensor", str(DRONE_SENSOR)] + extra) == 0
        err = capsys.readouterr().err
        assert "drone" not in err and "warning: line" not in err, err


def test_drone_records_in_feet_are_warned_naming_line_field_and_value(tmp_path, capsys):
    recs, rows = _in_feet(tmp_path)
    out = tmp_path / "out.csv"
    assert main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--dem", str(SRTM), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    # line 2: 425.3902335 m / 0.3048 = 1395.637 "m", over terrain at 291 m (the DEM): 1.1 km up
    assert (
        "warning: line 2 (survey1-1): ac_h_m = 1395.637: a drone's camera 1.1 km above the terrain under "
        "it (291.1 m), while drones fly below 1000 m above the ground and 7000 m above the sea: likely feet "
        "read as metres (x 0.3048: 425.4 m, 134 m above it); a height column in feet needs unit = 'ft'"
    ) in err, err
    assert "... and 15 more record(s) too high for a drone" in err  # every record: 5 shown, then a count
    # a warning, not an error: every row located as read, status ok, in the batch output
    got = _rows(out)
    assert len(got) == len(rows) and {r[got[0].index("status")] for r in got[1:]} == {"ok"}
    # at the targets' heights (no DEM) the reference is the target, said so
    assert main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--height-column", "truth_h_m"]) == 0
    assert (
        "line 2 (survey1-1): ac_h_m = 1395.637: a drone's camera 1.1 km above the target (287.4 m)"
        in capsys.readouterr().err
    )


def test_mapped_feet_column_names_the_files_column(tmp_path, capsys):
    recs, rows = _in_feet(tmp_path)
    rows[0][rows[0].index("ac_h_m")] = "Alt"
    _write(recs, rows)
    (tmp_path / "map.toml").write_text('[columns]\nac_h_m = "Alt"\n')
    assert (
        main(
            [
                "replay",
                str(recs),
                "--sensor",
                str(DRONE_SENSOR),
                "--dem",
                str(SRTM),
                "--columns",
                str(tmp_path / "map.toml"),
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "line 2 (survey1-1): Alt (read as ac_h_m, m, ellipsoid) = 1395.637: a drone's camera 1.1 km" in err, err
    # with its unit the same file is plausible
    (tmp_path / "map_ft.toml").write_text('[columns]\nac_h_m = {column = "Alt", unit = "ft"}\n')
    assert (
        main(
            [
                "replay",
                str(recs),
                "--sensor",
                str(DRONE_SENSOR),
                "--dem",
                str(SRTM),
                "--columns",
                str(tmp_path / "map_ft.toml"),
            ]
        )
        == 0
    )
    assert "too high for a drone" not in capsys.readouterr().err


def test_q17_flight_at_18_km_is_not_a_drone(tmp_path, capsys):
    # [Q17]'s aircraft at about 18 km with its own camera (no platform said): no drone warning
    assert main(["replay", str(Q17), "--height-column", "paper_height_m"]) == 0
    assert "drone" not in capsys.readouterr().err
    # a platform column decides per row: a manned aircraft is none, a drone is warned
    rows = _rows(Q17)
    rows[0].append("platform")
    for k, r in enumerate(rows[1:]):
        r.append("King Air 350" if k else "DJI Matrice 300 RTK")
    recs = _write(tmp_path / "q17_platform.csv", rows)
    assert main(["replay", str(recs), "--height-column", "paper_height_m"]) == 0
    err = capsys.readouterr().err
    assert err.count("a drone's camera") == 1 and "line 2 (T3-1): ac_h_m = " in err, err
    # 17987.25 m over a target at 4629.9 m; as feet, 5482.5 m: a drone's height over the Tibetan plateau
    assert (
        "ac_h_m = 17987.25: a drone's camera 13.4 km above the target (4629.9 m)" in err
        and "likely feet read as metres (x 0.3048: 5482.5 m, 853 m above it)" in err
    ), err


def test_row_platform_overrides_the_sensor_files(tmp_path, capsys):
    recs, rows = _in_feet(tmp_path)
    rows[0].append("platform")
    for k, r in enumerate(rows[1:]):
        r.append("Cessna 208" if k else "")  # an empty cell: the sensor file's platform (drone)
    _write(recs, rows)
    assert main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--dem", str(SRTM)]) == 0
    err = capsys.readouterr().err
    assert err.count("a drone's camera") == 1 and "line 2 (survey1-1): ac_h_m = 1395.637" in err, err


def test_sensor_file_platform_round_trip_and_error(tmp_path):
    s = load_sensor(DRONE_SENSOR)
    assert s.platform == "drone"
    sensor_to_toml(s, tmp_path / "s.toml")
    assert load_sensor(tmp_path / "s.toml").platform == "drone"
    with pytest.raises(ValueError, match=r"x.toml: platform = 3: must be a string"):
        sensor_from_dict(
            {
                "lens": {"model": "pinhole", "fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "width": 2, "height": 2},
                "platform": 3,
            },
            "x.toml",
        )


def test_drone_photo_in_feet_is_warned_naming_the_tag(tmp_path, capsys):
    b = PHOTO.read_bytes()
    # AbsoluteAltitude 503.00 m (EGM96) as feet: 503.00 / 0.3048 = 1650.3; same length, the JPEG stays whole
    up = tmp_path / PHOTO.name
    up.write_bytes(b.replace(b'AbsoluteAltitude="+503.00"', b'AbsoluteAltitude="+1650.3"'))
    out = tmp_path / "out.csv"
    assert main(["replay", str(up), "--targets", str(TARGETS), "--dem", str(SRTM), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert (
        "DJI_0001.JPG: warning: implausible for a drone: the camera is 1.3 km above the DEM under it" in err
        and "drone-dji:AbsoluteAltitude = 1650.3: likely feet read as metres (x 0.3048: 503.0 m" in err
    ), err
    rows = list(csv.DictReader(open(out)))
    assert len(rows) == 5 and {r["status"] for r in rows} == {"ok"}
    assert main(["replay", str(PHOTO), "--targets", str(TARGETS), "--dem", str(SRTM)]) == 0
    assert "implausible for a drone" not in capsys.readouterr().err


# ------------------------------------------------------------------ KLV: Platform Designation (tag 10)
KLV = asset_path("klv", "example_flight.klv")


def _klv(tmp_path, name, designation=None, sensor_above_m=None, n=12):
    """The first ``n`` good packets of the bundled flight, re-encoded with a Platform Designation and
    the sensor ``sensor_above_m`` above the packet's frame centre (tags 75 and 15 moved together)."""
    from geoloc.io import klv

    out = []
    for p in klv.read_packets(KLV):
        if isinstance(p, klv.KlvError) or "sensor_relative_azimuth_deg" not in p.fields:
            continue
        f = dict(p.fields)
        if designation is not None:
            f["platform_designation"] = designation
        if sensor_above_m is not None:
            dh = f["frame_center_hae_m"] + sensor_above_m - f["sensor_ellipsoid_height_m"]
            f["sensor_ellipsoid_height_m"] += dh
            f["sensor_true_altitude_m"] += dh
        out.append(klv.encode_packet(f))
        if len(out) == n:
            break
    path = tmp_path / name
    path.write_bytes(b"".join(out))
    return path


def test_klv_drone_designation_kilometres_up_is_warned(tmp_path, capsys):
    # the bundled flight: 2.4 km above its frame centres (2900.5 m HAE over 524.7 m), no designation: none
    assert main(["replay", str(_klv(tmp_path, "plain.klv"))]) == 0
    assert "too high for a drone" not in capsys.readouterr().out
    # a non-drone designation (MISB ST 0601's own example, an MQ-1B): none
    assert main(["replay", str(_klv(tmp_path, "mq1.klv", "MQ1-B"))]) == 0
    assert "too high for a drone" not in capsys.readouterr().out
    # a DJI drone at 120 m above its frame centres: none
    assert main(["replay", str(_klv(tmp_path, "m300.klv", "DJI Matrice 300 RTK", 120.0))]) == 0
    assert "too high for a drone" not in capsys.readouterr().out
    # the same in feet: (524.7 + 120) / 0.3048 m, 1.6 km above the frame centre: warned, packet by packet
    path = _klv(tmp_path, "m300_ft.klv", "DJI Matrice 300 RTK", None)
    from geoloc.io import klv

    ft = []
    for p in klv.read_packets(path):
        f = dict(p.fields)
        f["sensor_ellipsoid_height_m"] = (f["frame_center_hae_m"] + 120.0) / FOOT_M
        f.pop("sensor_true_altitude_m")
        ft.append(klv.encode_packet(f))
    path.write_bytes(b"".join(ft))
    out_csv = tmp_path / "out.csv"
    assert main(["replay", str(path), "--out", str(out_csv)]) == 0
    out = capsys.readouterr().out
    assert "warning: 12 packet(s) too high for a drone" in out, out
    assert (
        "packet 0 (byte 0): tag 75 (Sensor Ellipsoid Height) = 2115.3 m: a drone's camera (Platform "
        "Designation 'DJI Matrice 300 RTK') 1.6 km above the frame centre (tag 78) (524.7 m): likely feet "
        "read as metres (x 0.3048: 644.7 m, 120 m above it)"
    ) in out, out
    assert "... and 7 more" in out
    rows = list(csv.DictReader(open(out_csv)))
    assert len(rows) == 12 and {r["status"] for r in rows} == {"ok"}  # used as read


def test_the_docs_list_the_rule_as_the_code_has_it():
    from pathlib import Path

    from geoloc.sensors.platform import DRONE_WORDS

    doc = (Path(__file__).resolve().parents[2] / "docs" / "records.md").read_text()
    section = doc[doc.index("## Plausibility checks") :]
    flat = " ".join(section.split())
    for w in DRONE_WORDS:
        assert f"`{w}`".lower() in flat.lower(), w
    assert "1000 m above the terrain" in flat and "7000 m" in flat and "x 0.3048" in flat


def test_locate_with_a_drone_sensor_kilometres_up_is_warned(capsys):
    args = [
        "locate",
        "--sensor",
        str(DRONE_SENSOR),
        "--lat-deg",
        "36.6",
        "--lon-deg",
        "-84.2",
        "--angle",
        "gimbal_yaw=0",
        "--angle",
        "gimbal_pitch=-90",
        "--angle",
        "gimbal_roll=0",
        "--target-h-m",
        "300",
    ]
    assert main(args + ["--h-m", "420"]) == 0  # 120 m above the target: none
    err = capsys.readouterr().err
    assert "a drone's camera" not in err, err
    # 420 m written in feet: 420 / 0.3048 = 1377.95 "m"
    assert main(args + ["--h-m", f"{420 / FOOT_M:.2f}", "--json"]) == 0
    cap = capsys.readouterr()
    assert (
        "geoloc locate: warning: --h-m = 1378.0 m: a drone's camera (the sensor file's platform 'drone') "
        "1.1 km above the target (300.0 m)"
    ) in cap.err and "x 0.3048: 420.0 m, 120 m above it" in cap.err
    assert '"status": "ok"' in cap.out  # the point is still given


def test_campaign_units_say_the_drone_check(tmp_path):
    # the scaled replay (docs/scale.md) gives the same check per unit: a count and the first row
    from geoloc.surfaces.spec import SurfaceSpec
    from geoloc.workflows.campaign import CampaignConfig, run_campaign

    recs, _ = _in_feet(tmp_path)
    cfg = CampaignConfig(sensor=str(DRONE_SENSOR), surface=SurfaceSpec(dem=str(SRTM)))
    res = run_campaign([recs], tmp_path / "c", cfg, scheduler="none")
    got = [m for m in res.messages if "too high" in m or "of a drone" in m]
    assert len(got) == 1 and "20 row(s) of a drone more than 1000 m above" in got[0], res.messages
    assert "first row 0 (ac_h_m = 1395.64: 1.1 km above the terrain under it (291.1 m))" in got[0], got
    assert "likely feet read as metres (x 0.3048: 425.4 m" in got[0]
    assert set(res.table().column("status").to_pylist()) == {Status.OK}  # every row ok: used as read
    ok = run_campaign([DRONE], tmp_path / "ok", cfg, scheduler="none")
    assert not [m for m in ok.messages if "of a drone" in m], ok.messages
    # KLV: the packets of a drone kilometres up
    res = run_campaign(
        [_klv(tmp_path, "m300.klv", "DJI Matrice 300 RTK")], tmp_path / "k", CampaignConfig(), scheduler="none"
    )
    assert any("12 packet(s) too high for a drone, first packet 0 (byte 0): tag 75" in m for m in res.messages), (
        res.messages
    )
