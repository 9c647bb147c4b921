"""Column maps (geoloc.io.columns) and explicit vertical datums on the records path.

Any CSV through a column map (``--columns`` or the sensor file's ``[columns]``) must
replay exactly as the canonical CSV whose values this test computes itself:
feet * 0.3048, radians by ``math.degrees``, MSL + N with N independent of
``geoloc.geodesy.geoid`` (see :func:`reference_undulation`: PROJ reading the full
NGA EGM96 15' grid when pyproj or Debian's proj-data has it, else the bundled
grid read here with rasterio and interpolated bilinearly by this test).
"""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.cli import main
from geoloc.io.columns import (
    ELLIPSOID_DATUM,
    ColumnMap,
    HeightSource,
    datum_warnings,
    load_column_map,
)
from geoloc.io.records import load_records
from geoloc.sensors.sensor_file import load_sensor, load_sensor_columns

ROOT = Path(__file__).resolve().parents[2]
RECORDS = asset_path(*DEFAULT_RECORDS)
CAMERA = asset_path(*DEFAULT_CAMERA)
ETOPO = ROOT / "assets" / "dem" / "etopo5_flight_area.tif"
EO_TURRET = ROOT / "assets" / "sensors" / "eo_turret.toml"
FT = 0.3048
PROJ_DATA_EGM96 = Path("/usr/share/proj/egm96_15.gtx")


# --------------------------------------------------------------------------- reference N


def reference_undulation(lat_deg, lon_deg):
    """EGM96 N [m] not from geoloc, and how it was obtained.

    1. pyproj's own EGM96 (EPSG:4979 -> EPSG:4326+5773) if its data folder has the
       grid (without it PROJ falls back to a "ballpark" N = 0: refused);
    2. else PROJ's vgridshift on Debian proj-data's full 15' grid ``egm96_15.gtx``;
    3. else the bundled 15' crop ``assets/geoid/egm96_flight_area.tif`` read here with
       rasterio, bilinear between its pixel-centre nodes (the test's own interpolation).
    """
    from pyproj import Transformer

    lat = np.asarray(lat_deg, float)
    lon = np.asarray(lon_deg, float)
    t = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    if "ballpark" not in t.description.lower():
        _, _, h_ortho = t.transform(lon, lat, np.zeros_like(lat))
        return -np.asarray(h_ortho, float), "pyproj EPSG:4979 -> EPSG:4326+5773"
    if PROJ_DATA_EGM96.is_file():
        t = Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
            f"+step +proj=vgridshift +grids={PROJ_DATA_EGM96} +multiplier=1 "
            "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
        )
        _, _, n = t.transform(lon, lat, np.zeros_like(lat))
        return np.asarray(n, float), f"PROJ vgridshift on {PROJ_DATA_EGM96}"
    import rasterio

    with rasterio.open(ROOT / "assets" / "geoid" / "egm96_flight_area.tif") as src:
        z = src.read(1).astype(float)
        tr = src.transform
    r = (lat - (tr.f + tr.e / 2)) / tr.e
    c = (lon - (tr.c + tr.a / 2)) / tr.a
    i, j = np.floor(r).astype(int), np.floor(c).astype(int)
    v, u = r - i, c - j
    n = (1 - u) * (1 - v) * z[i, j] + u * (1 - v) * z[i, j + 1] + (1 - u) * v * z[i + 1, j] + u * v * z[i + 1, j + 1]
    return n, "bundled egm96_flight_area.tif read with rasterio, bilinear in the test"


# --------------------------------------------------------------------------- test data


def _bundled_rows():
    with RECORDS.open(newline="") as fh:
        return list(csv.DictReader(fh))


FOREIGN_HEADER = [
    "Flight",
    "Target",
    "PixelY",
    "PixelX",
    "Latitude",
    "Longitude",
    "Alt_ft",
    "Yaw",
    "Pitch",
    "Roll",
    "OuterGimbal",
    "InnerGimbal",
    "PubLat",
    "PubLon",
    "PubHeight_ft",
    "TruthLat",
    "TruthLon",
]

MAP_TOML = """\
[columns]
table = "Flight"
point = "Target"
row = "PixelY"
col = {column = "PixelX", pixel = "zero-based"}
ac_lat_deg = "Latitude"
ac_lon_deg = "Longitude"
ac_h_m = {column = "Alt_ft", unit = "ft", datum = "egm96"}
heading_deg = {column = "Yaw", unit = "rad"}
pitch_deg = {column = "Pitch", unit = "rad"}
roll_deg = "Roll"
gimbal_roll_deg = {column = "OuterGimbal", unit = "rad"}
gimbal_pitch_deg = {column = "InnerGimbal", unit = "deg"}
paper_lat_deg = "PubLat"
paper_lon_deg = "PubLon"
paper_height_m = {column = "PubHeight_ft", unit = "ft", datum = "ellipsoid"}
truth_lat_deg = "TruthLat"
truth_lon_deg = "TruthLon"
"""


def foreign_rows():
    """The bundled flight test rewritten as someone else's log: their names, feet (MSL),
    radians, zero-based pixel columns. The numbers are just numbers: what they mean is the map's."""
    out = []
    for r in _bundled_rows():
        out.append(
            {
                "Flight": r["table"],
                "Target": r["point"],
                "PixelY": r["row"],
                "PixelX": repr(float(r["col"]) - 1.0),
                "Latitude": r["ac_lat_deg"],
                "Longitude": r["ac_lon_deg"],
                "Alt_ft": f"{float(r['ac_h_m']) / FT:.3f}",
                "Yaw": f"{math.radians(float(r['heading_deg'])):.12f}",
                "Pitch": f"{math.radians(float(r['pitch_deg'])):.12f}",
                "Roll": r["roll_deg"],
                "OuterGimbal": f"{math.radians(float(r['gimbal_roll_deg'])):.12f}",
                "InnerGimbal": r["gimbal_pitch_deg"],
                "PubLat": r["paper_lat_deg"],
                "PubLon": r["paper_lon_deg"],
                "PubHeight_ft": f"{float(r['paper_height_m']) / FT:.3f}",
                "TruthLat": r["truth_lat_deg"],
                "TruthLon": r["truth_lon_deg"],
            }
        )
    return out


def canonical_rows(foreign):
    """The canonical columns computed here from the foreign ones, independently of geoloc."""
    lat = np.array([float(r["Latitude"]) for r in foreign])
    lon = np.array([float(r["Longitude"]) for r in foreign])
    n, _ = reference_undulation(lat, lon)
    out = []
    for k, r in enumerate(foreign):
        out.append(
            {
                "table": r["Flight"],
                "point": r["Target"],
                "row": r["PixelY"],
                "col": repr(float(r["PixelX"]) + 1.0),
                "ac_lat_deg": r["Latitude"],
                "ac_lon_deg": r["Longitude"],
                "ac_h_m": repr(float(r["Alt_ft"]) * FT + float(n[k])),
                "heading_deg": repr(math.degrees(float(r["Yaw"]))),
                "pitch_deg": repr(math.degrees(float(r["Pitch"]))),
                "roll_deg": r["Roll"],
                "gimbal_roll_deg": repr(math.degrees(float(r["OuterGimbal"]))),
                "gimbal_pitch_deg": r["InnerGimbal"],
                "paper_lat_deg": r["PubLat"],
                "paper_lon_deg": r["PubLon"],
                "paper_height_m": repr(float(r["PubHeight_ft"]) * FT),
                "truth_lat_deg": r["TruthLat"],
                "truth_lon_deg": r["TruthLon"],
            }
        )
    return out


def write_csv(path, rows, header=None, bom=False):
    header = header or list(rows[0])
    with open(path, "w", newline="", encoding="utf-8-sig" if bom else "utf-8") as fh:
        w = csv.DictWriter(fh, header)
        w.writeheader()
        w.writerows(rows)
    return path


def read_csv(path):
    with open(path, newline="", encoding="utf-8-sig") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture
def foreign(tmp_path):
    rows = foreign_rows()
    p = write_csv(tmp_path / "log.csv", rows, FOREIGN_HEADER)
    m = tmp_path / "map.toml"
    m.write_text(MAP_TOML)
    return p, m, rows


def _replay(args, capsys):
    rc = main(["replay", *args])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return cap


def _numbers(rows, name):
    return np.array([float(r[name]) if r[name] else np.nan for r in rows])


# --------------------------------------------------------------------------- the map


def test_foreign_csv_through_a_map_replays_as_the_canonical_csv(tmp_path, foreign, capsys):
    log, mapfile, rows = foreign
    canon = write_csv(tmp_path / "canon.csv", canonical_rows(rows))
    out_f, out_c = tmp_path / "f.csv", tmp_path / "c.csv"
    cap = _replay(
        [str(log), "--columns", str(mapfile), "--height-column", "paper_height_m", "--out", str(out_f)], capsys
    )
    assert "group T3" in cap.out and "group T4" in cap.out
    assert "read as egm96 (MSL, orthometric)" in cap.out and "h = H + N" in cap.out
    _replay(
        [str(canon), "--height-column", "paper_height_m", "--altitude-datum", "ellipsoid", "--out", str(out_c)], capsys
    )
    f, c = read_csv(out_f), read_csv(out_c)
    assert len(f) == len(c) == 20
    # N here and in geoloc differ by < 1 mm in the bundled 15' crop: the aircraft heights agree
    # to 2 mm, the ground points to 5e-8 deg (5 mm; the CSV keeps 1e-8 deg)
    assert np.max(np.abs(_numbers(f, "ac_h_m") - _numbers(c, "ac_h_m"))) < 2e-3
    for name, tol in (
        ("lat_deg", 5e-8),
        ("lon_deg", 5e-8),
        ("h_m", 2e-3),
        ("error_to_paper_m", 5e-3),
        ("error_to_truth_m", 5e-3),
    ):
        np.testing.assert_allclose(_numbers(f, name), _numbers(c, name), atol=tol, rtol=0, err_msg=name)
    assert [r["table"] for r in f] == [r["table"] for r in c]
    # the user's own columns are carried through untouched, the canonical ones added
    for k, r in enumerate(f):
        assert all(r[h] == rows[k][h] for h in FOREIGN_HEADER)
    assert float(f[0]["col"]) == float(rows[0]["PixelX"]) + 1.0
    # and the datums are written: every height ellipsoidal, the aircraft's read as MSL by the map
    assert {r["h_datum"] for r in f} == {ELLIPSOID_DATUM}
    assert f[0]["ac_h_datum_input"].startswith("egm96 (column map") and "Alt_ft, ft" in f[0]["ac_h_datum_input"]
    assert {r["h_datum"] for r in c} == {ELLIPSOID_DATUM}
    assert c[0]["ac_h_datum_input"] == "ellipsoid (--altitude-datum)"


def test_reference_undulation_is_the_project_one():
    """The reference N of this file agrees with geoloc's bundled grid (which method: printed)."""
    from geoloc.geodesy.geoid import egm96_undulation

    rows = _bundled_rows()
    lat = np.array([float(r["ac_lat_deg"]) for r in rows])
    lon = np.array([float(r["ac_lon_deg"]) for r in rows])
    n, how = reference_undulation(lat, lon)
    print("reference N:", how)
    assert np.all(np.abs(n) > 10)  # not a silent N = 0
    np.testing.assert_allclose(egm96_undulation(np.deg2rad(lat), np.deg2rad(lon)), n, atol=1e-3)


def test_load_records_applies_the_map_before_validation(foreign):
    log, mapfile, rows = foreign
    rec = load_records(log, columns=load_column_map(mapfile))
    assert len(rec) == 20 and rec.errors == []
    np.testing.assert_allclose(
        rec.column("heading_deg"), [math.degrees(float(r["Yaw"])) for r in rows], rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(rec.column("col"), [float(r["PixelX"]) + 1 for r in rows], rtol=0, atol=0)
    assert rec.labels()[0] == "T3-1"
    assert rec.source_header == FOREIGN_HEADER
    assert rec.header[: len(FOREIGN_HEADER)] == FOREIGN_HEADER
    assert rec.altitude == HeightSource("ac_h_m", "Alt_ft", "egm96", "ft", f"column map {mapfile}")
    # a dict (the [columns] table) works as well as the file
    import tomllib

    again = load_records(log, columns=tomllib.loads(MAP_TOML)["columns"])
    np.testing.assert_array_equal(again.column("ac_h_m"), rec.column("ac_h_m"))


def test_bom_prefixed_header_keeps_its_first_column(tmp_path, capsys):
    # A spreadsheet's UTF-8 byte-order mark: without utf-8-sig the first column reads
    # '\ufefftable', 'table' vanishes and the two flights collapse into one group.
    p = write_csv(tmp_path / "bom.csv", _bundled_rows(), bom=True)
    assert p.read_bytes().startswith(b"\xef\xbb\xbf")
    rec = load_records(p)
    assert rec.header[0] == "table" and rec.labels()[0] == "T3-1"
    assert sorted(set(rec.text("table"))) == ["T3", "T4"]
    cap = _replay([str(p), "--height-column", "paper_height_m"], capsys)
    assert "group T3: n=10" in cap.out and "group T4: n=10" in cap.out and "group all" not in cap.out
    # and a map naming the first column finds it
    rows = foreign_rows()
    q = write_csv(tmp_path / "bom_log.csv", rows, FOREIGN_HEADER, bom=True)
    rec = load_records(q, columns=ColumnMap.from_table({**_map_table(), "table": "Flight"}))
    assert sorted(set(rec.text("table"))) == ["T3", "T4"] and rec.source_header[0] == "Flight"


def _map_table():
    import tomllib

    return tomllib.loads(MAP_TOML)["columns"]


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "entry, words",
    [
        ({"altitude": "Alt_ft"}, ["altitude", "Alt_ft", "unknown canonical column"]),
        ({"heading_deg": {"column": "Yaw", "unit": "grad"}}, ["heading_deg", "grad", "deg", "rad"]),
        ({"ac_h_m": {"column": "Alt_ft", "unit": "yd"}}, ["ac_h_m", "yd", "ft"]),
        ({"ac_h_m": {"column": "Alt_ft", "datum": "msl"}}, ["ac_h_m", "msl", "egm96", "ellipsoid"]),
        ({"col": {"column": "PixelX", "pixel": "zero"}}, ["col", "zero", "zero-based", "one-based"]),
        ({"heading_deg": {"column": "Yaw", "datum": "egm96"}}, ["heading_deg", "datum", "not allowed"]),
        ({"row": {"column": "PixelY", "unit": "m"}}, ["row", "unit", "not allowed"]),
        ({"roll_deg": 3}, ["roll_deg", "3"]),
        ({"roll_deg": {"unit": "deg"}}, ["roll_deg", "column"]),
    ],
)
def test_bad_map_entries_name_the_key_and_the_value(entry, words):
    with pytest.raises(ValueError) as e:
        ColumnMap.from_table(entry, "m.toml")
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_map_errors_against_the_file_and_the_sensor(foreign, tmp_path, capsys):
    log, _, _ = foreign
    # a source column the file does not have: named, with the file's header
    with pytest.raises(ValueError, match=r"ac_h_m = 'Altitude'.*no column 'Altitude'.*header is \['Flight'"):
        load_records(log, columns={**_map_table(), "ac_h_m": "Altitude"})
    # a joint the sensor's gimbal does not have
    with pytest.raises(ValueError, match=r"azimuth_deg = 'Yaw'.*no joint angle 'azimuth'.*gimbal_roll"):
        load_records(log, columns={**_map_table(), "azimuth_deg": "Yaw"})
    # a required column neither in the file nor mapped
    table = _map_table()
    del table["gimbal_pitch_deg"]
    with pytest.raises(ValueError, match=r"missing required column\(s\) \['gimbal_pitch_deg'\].*docs/columns.md"):
        load_records(log, columns=table)
    # on the command line: exit 2 and the message
    bad = tmp_path / "bad.toml"
    bad.write_text('[columns]\nheading_deg = {column = "Yaw", unit = "grad"}\n')
    assert main(["replay", str(log), "--columns", str(bad), "--target-h-m", "0"]) == 2
    err = capsys.readouterr().err
    assert "heading_deg" in err and "'grad'" in err and str(bad) in err
    other = tmp_path / "other.toml"
    other.write_text('[cols]\nrow = "PixelY"\n')
    with pytest.raises(ValueError, match=r"\[columns\] table.*cols"):
        load_column_map(other)


def test_bad_rows_are_reported_by_line_and_the_good_ones_run(tmp_path, capsys):
    rows = foreign_rows()[:5]
    rows[1]["Alt_ft"] = "high"  # line 3: not a number, named by the user's column
    rows[2]["Yaw"] = "10"  # line 4: 573 deg, out of range, named by the user's column
    rows[3]["Latitude"] = "95"  # line 5: the aircraft's latitude (needed for N too)
    p = write_csv(tmp_path / "log.csv", rows, FOREIGN_HEADER)
    with p.open("a") as fh:
        fh.write("T9,1,2\n")  # line 7: too few fields
    m = tmp_path / "map.toml"
    m.write_text(MAP_TOML)
    rec = load_records(p, columns=load_column_map(m))
    assert list(rec.lines) == [2, 6]
    msgs = [str(e) for e in rec.errors]
    assert msgs[0] == "line 3: Alt_ft = 'high': not a number (mapped to ac_h_m)"
    assert msgs[1].startswith("line 4: Yaw = '10': out of range [-360, 360] (as heading_deg = 572.9")
    assert msgs[2].startswith("line 5: Latitude = '95': out of range [-90, 90]")
    assert msgs[3].startswith("line 7: *") and "3 fields" in msgs[3]
    out = tmp_path / "o.csv"
    cap = _replay([str(p), "--columns", str(m), "--height-column", "paper_height_m", "--out", str(out)], capsys)
    assert "skipped line 3: Alt_ft = 'high'" in cap.err and "skipped line 4: Yaw" in cap.err
    got = read_csv(out)
    assert [r["Target"] for r in got] == ["1", "5"] and all(r["lat_deg"] for r in got)


# --------------------------------------------------------------------------- sensor file [columns]


def test_columns_table_in_a_sensor_file(tmp_path, foreign, capsys):
    log, mapfile, _ = foreign
    cam = tmp_path / "cam.toml"
    cam.write_text(CAMERA.read_text() + "\n" + MAP_TOML)  # a first-phase camera file + [columns]
    assert load_sensor_columns(cam) == _map_table()
    assert load_sensor_columns(CAMERA) is None
    assert load_sensor(cam).lens.fx == 166841.0  # the camera itself is unchanged
    out_s, out_m = tmp_path / "s.csv", tmp_path / "m.csv"
    _replay([str(log), "--sensor", str(cam), "--height-column", "paper_height_m", "--out", str(out_s)], capsys)
    _replay([str(log), "--columns", str(mapfile), "--height-column", "paper_height_m", "--out", str(out_m)], capsys)
    s, m = read_csv(out_s), read_csv(out_m)
    assert [r["lat_deg"] for r in s] == [r["lat_deg"] for r in m]
    assert s[0]["ac_h_datum_input"].startswith(f"egm96 (column map {cam}")
    # --columns replaces the sensor file's table
    plain = tmp_path / "plain.toml"
    plain.write_text(MAP_TOML.replace('datum = "egm96"', 'datum = "ellipsoid"'))
    out_p = tmp_path / "p.csv"
    _replay(
        [
            str(log),
            "--sensor",
            str(cam),
            "--columns",
            str(plain),
            "--height-column",
            "paper_height_m",
            "--out",
            str(out_p),
        ],
        capsys,
    )
    assert read_csv(out_p)[0]["ac_h_datum_input"].startswith("ellipsoid (column map")
    bad = tmp_path / "bad.toml"
    bad.write_text(CAMERA.read_text() + '\ncolumns = "map.toml"\n')
    with pytest.raises(ValueError, match=r"\[columns\] must be a table"):
        load_sensor(bad)


def test_columns_table_maps_a_turret_s_joint_angles(tmp_path, capsys):
    """An azimuth-elevation turret's angles in radians under the user's names (sensor file [columns])."""
    sensor = tmp_path / "turret.toml"
    sensor.write_text(
        EO_TURRET.read_text() + '\n[columns]\nazimuth_deg = {column = "TurretAz", unit = "rad"}\n'
        'elevation_deg = {column = "TurretEl", unit = "rad"}\nac_h_m = {column = "Alt", unit = "ft"}\n'
    )
    base = {
        "row": "540.5",
        "col": "960.5",
        "ac_lat_deg": "36.4",
        "ac_lon_deg": "78.7",
        "heading_deg": "30",
        "pitch_deg": "1",
        "roll_deg": "-0.5",
    }
    angles = [(90.0, -40.0), (45.0, -60.0), (-20.0, -75.0)]
    foreign = [
        {**base, "Alt": f"{3000.0 / FT:.4f}", "TurretAz": repr(math.radians(a)), "TurretEl": repr(math.radians(e))}
        for a, e in angles
    ]
    canon = [
        {
            **base,
            "ac_h_m": repr(float(r["Alt"]) * FT),
            "azimuth_deg": repr(math.degrees(float(r["TurretAz"]))),
            "elevation_deg": repr(math.degrees(float(r["TurretEl"]))),
        }
        for r in foreign
    ]
    pf, pc = write_csv(tmp_path / "f.csv", foreign), write_csv(tmp_path / "c.csv", canon)
    of, oc = tmp_path / "of.csv", tmp_path / "oc.csv"
    _replay([str(pf), "--sensor", str(sensor), "--target-h-m", "1200", "--out", str(of)], capsys)
    _replay([str(pc), "--sensor", str(EO_TURRET), "--target-h-m", "1200", "--out", str(oc)], capsys)
    f, c = read_csv(of), read_csv(oc)
    np.testing.assert_allclose(_numbers(f, "lat_deg"), _numbers(c, "lat_deg"), atol=1e-8, rtol=0)
    np.testing.assert_allclose(_numbers(f, "lon_deg"), _numbers(c, "lon_deg"), atol=1e-8, rtol=0)
    assert all(r["TurretAz"] for r in f)


# --------------------------------------------------------------------------- datums


def test_altitude_datum_egm96_without_a_map(tmp_path, capsys):
    rows = _bundled_rows()[:4]
    p = write_csv(tmp_path / "msl.csv", rows)
    rec = load_records(p, altitude_datum="egm96")
    n, _ = reference_undulation(_numbers(rows, "ac_lat_deg"), _numbers(rows, "ac_lon_deg"))
    np.testing.assert_allclose(rec.column("ac_h_m"), _numbers(rows, "ac_h_m") + n, atol=1e-3, rtol=0)
    np.testing.assert_array_equal(rec.column("ac_h_m_input"), _numbers(rows, "ac_h_m"))  # the file's value kept
    out = tmp_path / "o.csv"
    cap = _replay([str(p), "--altitude-datum", "egm96", "--target-h-m", "4600", "--out", str(out)], capsys)
    assert "read as egm96 (MSL, orthometric) (--altitude-datum)" in cap.out
    got = read_csv(out)
    assert got[0]["ac_h_m_input"] == rows[0]["ac_h_m"] and got[0]["ac_h_datum_input"] == "egm96 (--altitude-datum)"
    # the map's datum wins over --altitude-datum, with a note
    m = tmp_path / "m.toml"
    m.write_text('[columns]\nac_h_m = {column = "ac_h_m", datum = "ellipsoid"}\n')
    cap = _replay([str(p), "--columns", str(m), "--altitude-datum", "egm96", "--target-h-m", "4600"], capsys)
    assert (
        "--altitude-datum egm96 not used for ac_h_m" in cap.err and "read as ellipsoid (WGS 84) (column map" in cap.out
    )


def test_locate_altitude_datum(capsys):
    base = [
        "locate",
        "--lat-deg",
        "35.48",
        "--lon-deg",
        "80.97",
        "--heading-deg",
        "45",
        "--pitch-deg",
        "3.5",
        "--gimbal-roll-deg",
        "50",
        "--gimbal-pitch-deg",
        "-2.6",
        "--target-h-m",
        "5083.5",
        "--json",
    ]
    n = float(reference_undulation(np.array([35.48]), np.array([80.97]))[0][0])
    assert main([*base, "--h-m", "18000", "--altitude-datum", "egm96"]) == 0
    msl = json.loads(capsys.readouterr().out)
    assert main([*base, "--h-m", repr(18000 + n)]) == 0
    ell = json.loads(capsys.readouterr().out)
    assert msl["ac_h_m"] == pytest.approx(18000 + n, abs=1e-3)
    assert msl["lat_deg"] == pytest.approx(ell["lat_deg"], abs=1e-9)
    assert msl["h_datum"] == ELLIPSOID_DATUM and msl["ac_h_datum_input"] == "egm96 (--altitude-datum)"
    assert ell["ac_h_datum_input"] == "ellipsoid (default, not stated)"
    assert main([*base[:-1], "--h-m", "18000", "--altitude-datum", "egm96"]) == 0
    assert "read as egm96 (MSL, orthometric)" in capsys.readouterr().out


WARN_DEFAULT = (
    "the DEM is orthometric (egm96) and the aircraft heights are taken as ellipsoidal (default): "
    "if they are MSL, pass --altitude-datum egm96"
)


def test_datum_warning_texts():
    w = datum_warnings("egm96", HeightSource())
    assert len(w) == 1 and w[0].startswith(WARN_DEFAULT)
    assert datum_warnings("egm96", HeightSource.of_option("ellipsoid")) == []
    assert datum_warnings("egm96", HeightSource.of_option("egm96")) == []
    assert datum_warnings("ellipsoid", HeightSource()) == []
    w = datum_warnings("ellipsoid", HeightSource("ac_h_m", "Alt_ft", "egm96", "ft", "column map m.toml"))
    assert len(w) == 1 and "aircraft heights are MSL (egm96, column map m.toml" in w[0]
    assert "--dem-datum ellipsoid" in w[0] and "check the DEM's vertical datum" in w[0] and "--dem-datum egm96" in w[0]


def test_datum_warnings_on_the_command_line(tmp_path, foreign, capsys):
    p = write_csv(tmp_path / "mine.csv", _bundled_rows()[:3])
    cap = _replay([str(p), "--dem", str(ETOPO)], capsys)
    assert f"geoloc replay: warning: {WARN_DEFAULT}" in cap.err
    cap = _replay([str(p), "--dem", str(ETOPO), "--altitude-datum", "ellipsoid"], capsys)
    assert "DEM is orthometric" not in cap.err
    # the bundled flight test's heights are ellipsoidal by docs/records.md: stated
    cap = _replay(["--dem", str(ETOPO)], capsys)
    assert "DEM is orthometric" not in cap.err and "(docs/records.md)" in cap.out
    # an egm96 height column meeting a DEM taken as ellipsoidal
    log, mapfile, _ = foreign
    cap = _replay([str(log), "--columns", str(mapfile), "--dem", str(ETOPO), "--dem-datum", "ellipsoid"], capsys)
    assert "geoloc replay: warning: the aircraft heights are MSL (egm96" in cap.err
    assert "check the DEM's vertical datum" in cap.err
    # locate: never stated -> warned; stated -> not
    base = [
        "locate",
        "--lat-deg",
        "35.48",
        "--lon-deg",
        "80.97",
        "--h-m",
        "18000",
        "--heading-deg",
        "45",
        "--pitch-deg",
        "3.5",
        "--gimbal-roll-deg",
        "50",
        "--gimbal-pitch-deg",
        "-2.6",
        "--dem",
        str(ETOPO),
        "--json",
    ]
    assert main(base) == 0
    assert f"geoloc locate: warning: {WARN_DEFAULT}" in capsys.readouterr().err
    assert main([*base, "--altitude-datum", "ellipsoid"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_h_datum_is_written_and_read_back(tmp_path, foreign, capsys):
    from geoloc.io import gis

    assert gis.ELLIPSOID_DATUM == ELLIPSOID_DATUM
    log, mapfile, _ = foreign
    out = tmp_path / "o.csv"
    _replay([str(log), "--columns", str(mapfile), "--height-column", "paper_height_m", "--out", str(out)], capsys)
    table = gis.read_results(out)
    assert table["h_datum"] == [ELLIPSOID_DATUM] * 20
    # read back as records: its h_datum agrees with the (default) ellipsoidal reading
    rec = load_records(out)
    assert len(rec) == 20 and rec.errors == [] and rec.altitude.stated == "the file's h_datum column"
    # ... and a file whose h_datum contradicts the datum it is read in loses those rows, by line
    rows = read_csv(out)[:2]
    rows[1]["h_datum"] = "EGM96 geoid (orthometric)"
    q = write_csv(tmp_path / "q.csv", rows)
    rec = load_records(q)
    assert list(rec.lines) == [2]
    assert str(rec.errors[0]).startswith(
        "line 3: h_datum = 'EGM96 geoid (orthometric)': says egm96 but ac_h_m is read as ellipsoid (the default)"
    )
    assert "--altitude-datum egm96" in str(rec.errors[0])
