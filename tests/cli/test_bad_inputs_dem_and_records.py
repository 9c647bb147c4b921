"""Every input told the truth. One test (or a few) per kind of bad DEM or record,
each the bad input, the status or message expected (naming the file, the field, the value)
and, where a batch is concerned, the good rows still produced. Each failed before its mend."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.frames.enu import EnuFrame
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem

ROOT = Path(__file__).resolve().parents[2]
SRTM = asset_path("dem", "srtm_jacksboro.tif")
DRONE = asset_path("records", "drone_targets.csv")
DRONE_SENSOR = asset_path("sensors", "drone_camera.toml")
TURRET = asset_path("sensors", "eo_turret.toml")
TURRET_ARGS = [
    "locate",
    "--sensor",
    str(TURRET),
    "--lat-deg",
    "36.6",
    "--lon-deg",
    "-84.25",
    "--h-m",
    "2500",
    "--heading-deg",
    "45",
    "--angle",
    "azimuth=90",
    "--angle",
    "elevation=-30",
]
METHODS = ("steps", "bisect", "exact")


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------ an all-nodata DEM
@pytest.fixture(scope="module")
def empty_dems(tmp_path_factory):
    """The bundled SRTM crop's grid with no data at all: int16 with its nodata value, and float NaN."""
    d = tmp_path_factory.mktemp("empty_dems")
    with rasterio.open(SRTM) as src:
        prof, shape = src.profile.copy(), (src.height, src.width)
    out = {}
    prof.update(dtype="int16", nodata=-32768)
    with rasterio.open(d / "int16.tif", "w", **prof) as dst:
        dst.write(np.full(shape, -32768, np.int16), 1)
    prof.update(dtype="float32", nodata=None)
    with rasterio.open(d / "nan.tif", "w", **prof) as dst:
        dst.write(np.full(shape, np.nan, np.float32), 1)
    out["int16"], out["nan"] = d / "int16.tif", d / "nan.tif"
    return out


@pytest.mark.parametrize("kind", ["int16", "nan"])
@pytest.mark.parametrize("method", METHODS)
def test_all_nodata_dem_is_nodata_not_sky(empty_dems, kind, method, capsys):
    # before: exact and bisect said "points above the horizon" / "invalid input" for a ray 30 deg
    # down, steps "cannot convert float NaN to integer"
    assert main(TURRET_ARGS + ["--dem", str(empty_dems[kind]), "--method", method]) == 1
    err = capsys.readouterr().err
    assert "DEM has no data where the line of sight meets it" in err, err
    assert "NaN to integer" not in err and "horizon" not in err


@pytest.mark.parametrize("method", METHODS)
def test_all_nodata_dem_batch_statuses(method):
    # a ray up stays SKY (it misses every ellipsoid), a NaN origin INVALID_INPUT, the rays down NODATA
    dem = DEM.from_array(np.full((21, 21), np.nan), 36.1, 78.0, 0.01, 0.01)
    fr = EnuFrame.from_deg(36.0, 78.1, 0.0)
    o = fr.to_ecef(np.array([[0, 0, 3000.0], [0, 0, 3000.0], [np.nan, 0, 3000.0], [-2000, 3000, 3000.0]]))
    d = np.einsum("ij,...j->...i", fr.R_ecef_enu, np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -1.0], [-1, 0, -0.1]]))
    hit = intersect_dem(LineOfSight(o, d, np.zeros(4, np.uint8)), dem, method, trace=True)
    assert list(hit.status) == [Status.SKY, Status.NODATA, Status.INVALID_INPUT, Status.NODATA]
    assert np.isnan(hit.lat).all() and np.isnan(hit.ecef).all()
    # the same DEM with data: the downward ray hits (the NODATA above is the missing data, not the geometry)
    ok = intersect_dem(
        LineOfSight(o, d, np.zeros(4, np.uint8)),
        DEM.from_array(np.full((21, 21), 100.0), 36.1, 78.0, 0.01, 0.01),
        method,
    )
    assert ok.status[1] == Status.OK


def test_all_nodata_dem_replay_rows_say_nodata(empty_dems, tmp_path, capsys):
    # before: replay exited 0 with every row `sky`
    out = tmp_path / "out.csv"
    assert (
        main(
            ["replay", str(DRONE), "--sensor", str(DRONE_SENSOR), "--dem", str(empty_dems["int16"]), "--out", str(out)]
        )
        == 1
    )  # exit 1: some records not located (docs/cli.md)
    rows = _read_csv(out)
    assert len(rows) == 20 and {r["status"] for r in rows} == {"nodata"}


def test_mosaic_tile_without_data_is_nodata(empty_dems, tmp_path):
    # a mosaic of the SRTM crop's west half with data and its east half all nodata: a ray
    # down into the east half is NODATA (its region has no data at all), the west one hits
    from geoloc.surfaces.mosaic import DemMosaic

    with rasterio.open(SRTM) as src:
        prof, v = src.profile.copy(), src.read(1)
    half = v.shape[1] // 2
    prof.update(nodata=-32768, width=half + 1)
    from rasterio.windows import Window, transform as wtransform

    for name, c0, fill in (("west.tif", 0, None), ("east.tif", half, -32768)):
        with rasterio.open(SRTM) as src:
            t = wtransform(Window(c0, 0, half + 1, v.shape[0]), src.transform)
        block = v[:, c0 : c0 + half + 1].copy()
        if fill is not None:
            block[:] = fill
        with rasterio.open(tmp_path / name, "w", **{**prof, "transform": t, "width": block.shape[1]}) as dst:
            dst.write(block, 1)
    mos = DemMosaic.open(tmp_path, "egm96")
    w, s, e, n = mos.bounds_deg
    lat = np.deg2rad(0.5 * (s + n))
    lon = np.deg2rad([w + 0.25 * (e - w), w + 0.75 * (e - w)])
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    o = geodetic_to_ecef(np.full(2, lat), lon, np.full(2, 3000.0))
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.full(2, np.sin(lat))], -1)
    hit = mos.intersect(LineOfSight(o, -up, np.zeros(2, np.uint8)))
    assert list(hit.status) == [Status.OK, Status.NODATA]
    # a mosaic with no data in any file is refused when opened, naming a file
    for name in ("west.tif",):
        (tmp_path / name).unlink()
    with pytest.raises(ValueError, match=r"east\.tif.*has no data at all"):
        DemMosaic.open(tmp_path, "egm96")


# ------------------------------------------------------------------ a pixel far off the sensor
def _drone_records(tmp_path, edits, name="drone.csv"):
    """The bundled drone records with ``edits`` {(line index from 1, column): value}."""
    with open(DRONE, newline="") as f:
        rows = list(csv.reader(f))
    for (k, col), v in edits.items():
        rows[k][rows[0].index(col)] = v
    p = tmp_path / name
    with open(p, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return p


def test_drone_target_far_off_the_sensor_is_outside_sensor_with_a_message(tmp_path, capsys):
    # the drone camera has 3000 rows: row 3001 was outside_sensor with a message, row 9000
    # (where the Brown model gives no ray) invalid_input, its message claiming it was located
    recs = _drone_records(tmp_path, {(1, "row"): "3001", (2, "row"): "9000"})
    out = tmp_path / "out.csv"
    assert (
        main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--target-h-m", "300", "--out", str(out)]) == 1
    )  # exit 1: some records not located (docs/cli.md)
    err = capsys.readouterr().err
    assert "line 2 (survey1-1): row = 3001 (rows 1-3000) is outside the sensor; located by extending" in err
    assert (
        "line 3 (survey1-2): row = 9000 (rows 1-3000) is outside the sensor; too far out for the lens "
        "model to give a ray there: not located, flagged outside_sensor"
    ) in err
    rows = _read_csv(out)
    assert [r["status"] for r in rows[:3]] == ["outside_sensor", "outside_sensor", "ok"]
    assert rows[1]["lat_deg"] == "" and rows[0]["lat_deg"] != ""
    assert all(r["status"] == "ok" and r["lat_deg"] for r in rows[2:])  # the good rows still located


@pytest.mark.parametrize("row", ["1081", "5000", "1e9"])
def test_locate_far_off_the_sensor_names_its_size_on_stderr(row, capsys):
    # before: 5000 and 1e9 said "invalid input"; 1081 "rows 0.5..M+0.5" with the letters unfilled; on stdout
    assert main(TURRET_ARGS + ["--target-h-m", "300", "--row", row]) == 1
    cap = capsys.readouterr()
    assert cap.out == ""
    assert "pixel is outside the sensor (rows 0.5..1080.5, columns 0.5..1920.5)" in cap.err, cap.err


def test_line_of_sight_off_sensor_is_outside_sensor_in_both_engines():
    # the numpy path and the compiled kernel agree: off the sensor first, then the lens's NaN
    from geoloc.frames.chain import Pose
    from geoloc.sensors.sensor_file import load_sensor

    cam = load_sensor(DRONE_SENSOR)
    pose = Pose.from_deg(36.6, -84.2, 500.0, angles_deg={"gimbal_yaw": 0.0, "gimbal_pitch": -60.0, "gimbal_roll": 0.0})
    rows = np.array([1500.0, 3001.0, 9000.0, 1e9, np.nan])
    for engine in ("numpy", "numba"):
        los = cam.line_of_sight(rows, np.full(5, 2000.0), pose, engine=engine)
        assert list(los.status) == [
            Status.OK,
            Status.OUTSIDE_SENSOR,
            Status.OUTSIDE_SENSOR,
            Status.OUTSIDE_SENSOR,
            Status.INVALID_INPUT,
        ], engine


# ------------------------------------------------------------------ replay --out without a DEM
def test_replay_out_without_dem_has_a_status_column(tmp_path):
    # before: no status column without --dem, so a row without a position was just blank.
    # Record 1's aircraft put 200 m below a 300 m target height: origin_below
    recs = _drone_records(tmp_path, {(1, "ac_h_m"): "100.0"})
    out = tmp_path / "out.csv"
    assert (
        main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--target-h-m", "300", "--out", str(out)]) == 1
    )  # exit 1: some records not located (docs/cli.md)
    rows = _read_csv(out)
    assert rows[0]["status"] == "origin_below" and rows[0]["lat_deg"] == ""
    assert {r["status"] for r in rows[1:]} == {"ok"} and all(r["lat_deg"] for r in rows[1:])


# ------------------------------------------------------------------ records CSVs: names, separators, bytes
QIAO = asset_path("records", "qiao2017_flight_tests.csv")


def _qiao_with(tmp_path, name, transform):
    with open(QIAO, newline="") as f:
        rows = list(csv.reader(f))
    p = tmp_path / name
    transform(rows, p)
    return p


def test_duplicate_column_names_are_refused_naming_column_and_file(tmp_path, capsys):
    # before: a second `row` column (the row + 50) was used without a word: RMS 0.36 -> 72.83 m
    def dup(rows, p):
        rows[0].append("row")
        for r in rows[1:]:
            r.append(str(float(r[2]) + 50))
        with open(p, "w", newline="") as f:
            csv.writer(f).writerows(rows)

    p = _qiao_with(tmp_path, "dup.csv", dup)
    assert main(["replay", str(p), "--height-column", "paper_height_m"]) == 2
    err = capsys.readouterr().err
    assert f"{p}: duplicate column name(s): 'row' in columns 3, 19" in err, err

    # trailing empty header cells (a spreadsheet's) are not duplicates: the file still replays
    def blanks(rows, p):
        with open(p, "w", newline="") as f:
            csv.writer(f).writerows([r + ["", ""] for r in rows])

    assert main(["replay", str(_qiao_with(tmp_path, "blank.csv", blanks)), "--height-column", "paper_height_m"]) == 0
    assert "RMS distance to the published positions 0.36 m over 20 records" in capsys.readouterr().out


def test_semicolon_csv_gets_a_hint(tmp_path, capsys):
    def semi(rows, p):
        with open(p, "w", newline="") as f:
            csv.writer(f, delimiter=";").writerows(rows)

    p = _qiao_with(tmp_path, "semi.csv", semi)
    assert main(["replay", str(p), "--height-column", "paper_height_m"]) == 2
    err = capsys.readouterr().err
    assert "missing required column(s)" in err and "the header holds semicolons" in err
    assert "comma-separated" in err and str(p) in err


@pytest.fixture()
def binary_file(tmp_path):
    p = tmp_path / "photo.csv"
    p.write_bytes(asset_path("photos", "DJI_0001.JPG").read_bytes()[:4096])
    return p


@pytest.mark.parametrize("verb", ["replay", "export", "report"])
def test_binary_file_is_named(binary_file, tmp_path, verb, capsys):
    # before (export, report): "'utf-8' codec can't decode byte 0xff ..." without the file's name
    args = {
        "replay": ["replay", str(binary_file), "--target-h-m", "0"],
        "export": ["export", str(binary_file), "--out", str(tmp_path / "x.gpkg")],
        "report": ["report", str(binary_file)],
    }[verb]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert str(binary_file) in err and "not a text CSV (UTF-8)" in err and "binary file" in err, err
    assert "codec" not in err


def test_export_of_records_never_replayed_is_refused(tmp_path, capsys):
    # before: exit 0 and six layers, every computed point an empty geometry
    out = tmp_path / "x.gpkg"
    assert main(["export", str(QIAO), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{QIAO}: no computed positions (columns lat_deg and lon_deg)" in err
    assert "geoloc replay FILE --out results.csv" in err
    assert not out.exists()


# ------------------------------------------------------------------ report: ranges
def test_report_leaves_out_a_latitude_of_95_naming_line_and_column(tmp_path, capsys):
    res = tmp_path / "res.csv"
    assert main(["replay", str(DRONE), "--sensor", str(DRONE_SENSOR), "--dem", str(SRTM), "--out", str(res)]) == 0
    rows = list(csv.reader(open(res, newline="")))
    rows[3][rows[0].index("truth_lat_deg")] = "95"
    bad = tmp_path / "res95.csv"
    with open(bad, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    capsys.readouterr()
    assert main(["report", str(bad), "--json"]) == 0
    cap = capsys.readouterr()
    assert "res95.csv line 4: truth_lat_deg = '95' is out of range [-90, 90]: row left out" in cap.err
    rep = json.loads(cap.out)
    overall = rep["overall"]
    # the 19 good rows still reported; before, the CE90 was 1 091 124 m over 20
    assert overall["n"] == 19 and overall["ce90_m"] < 10.0
    # the core refuses the value itself, naming the argument, index and value
    from geoloc.analysis.accuracy import accuracy_report

    with pytest.raises(ValueError, match=r"ref_lat_deg\[1\] = 95 is out of range \[-90, 90\]"):
        accuracy_report([36.6, 36.6], [-84.2, -84.2], [300, 300], [36.6, 95.0], [-84.2, -84.2], [300, 300])


# ------------------------------------------------------------------ angle names the gimbal does not have
@pytest.mark.parametrize(
    "given, named",
    [
        (["--gimbal-roll-deg", "40", "--angle", "elevation=-30"], "--gimbal-roll-deg 40"),  # before: ignored, exit 0
        (["--angle", "tilt=-30"], "--angle tilt=-30"),  # before: "missing angle(s) ['elevation']", tilt unnamed
    ],
)
def test_angle_the_gimbal_has_not_is_named_with_the_gimbals_angles(given, named, capsys):
    base = [
        "locate",
        "--sensor",
        str(TURRET),
        "--lat-deg",
        "36.6",
        "--lon-deg",
        "-84.25",
        "--h-m",
        "2500",
        "--angle",
        "azimuth=90",
        "--target-h-m",
        "300",
    ]
    assert main(base + given) == 2
    err = capsys.readouterr().err
    assert (
        f"{named}: the sensor's azimuth-elevation gimbal has no angle" in err
        and "its angles are ['azimuth', 'elevation']" in err
    ), err
    # the good call still locates
    assert main(base + ["--angle", "elevation=-30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "ok"


# ------------------------------------------------------------------ plausibility warnings
def test_column_in_feet_mapped_without_unit_is_warned_and_flagged_by_its_errors(tmp_path, capsys):
    # the drone records' heights in feet, in a column Alt_ft mapped without unit = "ft"
    with open(DRONE, newline="") as f:
        rows = list(csv.reader(f))
    i = rows[0].index("ac_h_m")
    rows[0][i] = "Alt_ft"
    for r in rows[1:]:
        r[i] = f"{float(r[i]) / 0.3048:.3f}"
    recs = tmp_path / "drone_ft.csv"
    with open(recs, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    out = tmp_path / "out.csv"
    args = ["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--dem", str(SRTM), "--out", str(out)]
    (tmp_path / "map.toml").write_text('[columns]\nac_h_m = "Alt_ft"\n')
    assert main(args + ["--columns", str(tmp_path / "map.toml")]) == 0
    err = capsys.readouterr().err
    assert (
        "ac_h_m = 'Alt_ft': the column's name says feet but the map gives no unit, so it is read in "
        "metres; write ac_h_m = {column = 'Alt_ft', unit = 'ft'}"
    ) in err, err
    assert "line 2 (survey1-1): located 621 m from its truth, 47 % of its slant range (1320 m)" in err
    assert "... and 15 more record(s) far from their truth" in err
    # warnings only: the numbers are those of the heights as read (all ok)
    assert {r["status"] for r in _read_csv(out)} == {"ok"}
    # with its unit: no warning, and docs/tour_sensors.md's 2.70 m mean error to truth
    (tmp_path / "map_ft.toml").write_text('[columns]\nac_h_m = {column = "Alt_ft", unit = "ft"}\n')
    assert main(args + ["--columns", str(tmp_path / "map_ft.toml")]) == 0
    cap = capsys.readouterr()
    assert "says feet" not in cap.err and "far from their truth" not in cap.err and "truth, " not in cap.err
    assert "mean error to truth 2.70 m" in cap.out


def test_camera_below_the_terrain_is_warned(tmp_path, capsys):
    recs = _drone_records(tmp_path, {(1, "ac_h_m"): "150.0"})
    assert (
        main(["replay", str(recs), "--sensor", str(DRONE_SENSOR), "--dem", str(SRTM)]) == 1
    )  # exit 1: some records not located (docs/cli.md)
    err = capsys.readouterr().err
    assert "line 2 (survey1-1): the camera (ac_h_m = 150.0 m) is 141 m below the terrain under it (291.1 m" in err
    assert err.count("warning: line") == 1  # one record, one warning (its error to truth not said twice)


def test_bundled_records_give_no_plausibility_warning(capsys):
    # the check is not a noise source: the bundled turret and drone flights are plausible
    for recs, sensor in ((DRONE, DRONE_SENSOR), (asset_path("records", "eo_turret_flight.csv"), TURRET)):
        assert main(["replay", str(recs), "--sensor", str(sensor), "--dem", str(SRTM)]) == 0
        assert "warning: line" not in capsys.readouterr().err


# ------------------------------------------------------------------ a drone photo written by GDAL
PHOTO = asset_path("photos", "DJI_0001.JPG")


def _gdal_copy(dst_path, factor):
    """A resized TIFF copy of the bundled photo written by GDAL through rasterio, its EXIF items
    and its XMP domain copied the way a script does (and public test sets come): GDAL stores
    the XMP tag as ``xml:XMP=<?xpacket ...`` and the EXIF items in its GDAL_METADATA tag."""
    import warnings

    from rasterio.enums import Resampling
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(PHOTO) as src:
            w, h = src.width // factor, src.height // factor
            data = src.read(out_shape=(src.count, h, w), resampling=Resampling.average)
            with rasterio.open(
                dst_path, "w", driver="GTiff", width=w, height=h, count=src.count, dtype=data.dtype
            ) as dst:
                dst.write(data)
                dst.update_tags(**src.tags())
                dst.update_tags(ns="xml:XMP", **src.tags(ns="xml:XMP"))
    return w, h


def test_gdal_tiff_copy_replays_as_the_jpeg(tmp_path, capsys):
    # before: "XMP packet is not well-formed XML"; with that mended, the TIFF's EXIF size was not
    # read, the lens not scaled to the raster: pixels off the axis ~95 m away
    from geoloc.io.photos import lens_from_photo, read_photo

    tif = tmp_path / "DJI_0001.tif"
    w, h = _gdal_copy(tif, 4)
    assert tif.read_bytes().find(b"xml:XMP=<?xpacket") > 0  # the form this test is about
    m = read_photo(tif)
    assert (m.width, m.height, m.full_width, m.full_height) == (w, h, 800, 600) and m.resized
    with open(asset_path("photos", "targets.csv"), newline="") as f:
        targets = list(csv.DictReader(f))
    lens = lens_from_photo(read_photo(PHOTO))
    off_axis_deg = [
        np.degrees(np.arctan(np.hypot(float(t["col"]) - 1 - lens.cx, float(t["row"]) - 1 - lens.cy) / lens.fx))
        for t in targets
    ]
    assert min(off_axis_deg) < 1.0 and max(off_axis_deg) > 15.0  # on and off the optical axis
    # the same targets at the resized raster's pixels: DJI's corner origin scales exactly,
    # 1-based centre r -> (r - 0.5) / 4 + 0.5
    tt = tmp_path / "targets.csv"
    with open(tt, "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["image", "row", "col"])
        for t in targets:
            wr.writerow([PHOTO.name, t["row"], t["col"]])
            wr.writerow([tif.name, (float(t["row"]) - 0.5) / 4 + 0.5, (float(t["col"]) - 0.5) / 4 + 0.5])
    out = tmp_path / "out.csv"
    assert main(["replay", str(PHOTO), str(tif), "--targets", str(tt), "--dem", str(SRTM), "--out", str(out)]) == 0
    rows = _read_csv(out)
    jpg = [r for r in rows if r["image"] == PHOTO.name]
    tiff = [r for r in rows if r["image"] == tif.name]
    assert len(jpg) == len(tiff) == len(targets) and {r["status"] for r in rows} == {"ok"}
    for a, b in zip(jpg, tiff):
        # the scale 1/4 is a power of two, so the scaled lens is the full one to the last bit
        # but for its principal point's (u0 + 0.5) / 4 - 0.5; the lens's Newton inversion and
        # the walk converge to ~1e-12 of a degree. 1e-9 deg is 0.1 mm on the ground; an unscaled
        # lens moves the off-axis points by tens of metres
        assert float(b["lat_deg"]) == pytest.approx(float(a["lat_deg"]), abs=1e-9)
        assert float(b["lon_deg"]) == pytest.approx(float(a["lon_deg"]), abs=1e-9)
