"""GIS export (geoloc.io.gis, geoloc export): every file read back with a reader that is not the writer.

GPKG and GeoJSON through GDAL (pyogrio.raw.read) with the WKB decoded by a
parser written here; KML through xml.etree against the KML 2.2 element
structure; CZML through json and czml3's own model. Coordinates are compared
with the input table to 1e-9 deg.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import czml3  # noqa: E402  (test dependencies: installed by the project, never skipped)
import pyogrio  # noqa: E402
import simplekml  # noqa: E402, F401

from pyogrio import raw

from geoloc.cli import main
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.gis import LAYERS, export, read_results

ROOT = Path(__file__).resolve().parents[2]
TOL_DEG = 1e-9
TOL_M = 1e-6
KML = "{http://www.opengis.net/kml/2.2}"
nan = float("nan")


# --------------------------------------------------------------------------- independent readers


def parse_wkb(b: bytes):
    """(kind, list of rings/points) from ISO or extended (0x80000000 Z flag) WKB."""
    e = "<" if b[0] == 1 else ">"
    (t,) = struct.unpack(e + "I", b[1:5])
    z = bool(t & 0x80000000) or (t & 0xFFFF) // 1000 in (1, 3)
    base = (t & 0xFFFF) % 1000
    dim = 3 if z else 2
    off = 5

    def points(count):
        nonlocal off
        out = [struct.unpack(e + "d" * dim, b[off + 8 * dim * i : off + 8 * dim * (i + 1)]) for i in range(count)]
        off += 8 * dim * count
        return out

    def count():
        nonlocal off
        (c,) = struct.unpack(e + "I", b[off : off + 4])
        off += 4
        return c

    if base == 1:
        return "Point", points(1), z
    if base == 2:
        return "LineString", points(count()), z
    if base == 3:
        return "Polygon", [points(count()) for _ in range(count())], z
    raise AssertionError(f"unexpected WKB type {t}")


def read_layer(path, layer=None):
    """GDAL read: meta, list of decoded geometries (None for empty), dict field -> values."""
    meta, _, geoms, data = raw.read(str(path), layer=layer)
    fields = {name: list(v) for name, v in zip(meta["fields"], data)}
    return meta, [None if g is None else parse_wkb(g) for g in geoms], fields


def N(lat_deg, lon_deg):
    return float(egm96_undulation(math.radians(lat_deg), math.radians(lon_deg)))


def kml_tree(path):
    root = ET.parse(path).getroot()
    assert root.tag == KML + "kml"
    docs = root.findall(KML + "Document")
    assert len(docs) == 1
    return docs[0]


def kml_coords(text):
    return [tuple(float(v) for v in c.split(",")) for c in text.split()]


def kml_data(placemark):
    return {d.get("name"): d.findtext(KML + "value") for d in placemark.iter(KML + "Data")}


# --------------------------------------------------------------------------- tables


def synthetic():
    """Two flights, a row without a position, times out of order, a clockwise footprint."""
    lat = np.array([36.1234567891, 36.2000000004, nan, 35.5, 35.6])
    lon = np.array([78.1000000007, 78.2, nan, 80.9876543219, 81.0])
    h = np.array([4600.123456789, 4700.5, nan, 4800.25, 4900.0])
    t = {
        "table": ["F1", "F1", "F1", "F2", "F2"],
        "point": ["1", "2", "3", "1", "2"],
        "image": ["img-10", "img-11", "img-12", "img-20", "img-21"],
        "time_utc": [
            "2024-05-01T10:00:02Z",
            "2024-05-01T10:00:00Z",
            "2024-05-01T10:00:01.5Z",
            "2024-05-01T11:00:00Z",
            "2024-05-01T11:00:04Z",
        ],
        "lat_deg": lat,
        "lon_deg": lon,
        "h_m": h,
        "status": ["ok", "ok", "sky", "ok", "no_convergence"],
        "method": ["exact", "exact", "exact", "bisect", "bisect"],
        "dem_evaluations": np.array([3, 5, nan, 7, 2]),
        "error_to_truth_m": np.array([12.5, 8.25, nan, 3.0, 4.0]),
        "error_to_paper_m": np.array([0.5, 0.25, nan, 0.125, 1.0]),
        "truth_lat_deg": np.array([36.1235567891, 36.2001, 36.3, 35.5001, 35.6001]),
        "truth_lon_deg": np.array([78.1001, 78.2001, 78.3, 80.9877, 81.0001]),
        "truth_h_m": np.array([4601.0, 4701.0, 4800.0, 4801.0, 4901.0]),
        "paper_lat_deg": np.array([36.12346, 36.20001, 36.3, 35.50001, 35.60001]),
        "paper_lon_deg": np.array([78.10001, 78.20001, 78.3, 80.98766, 81.00001]),
        "paper_height_m": np.array([4600.0, 4700.0, 4800.0, 4800.0, 4900.0]),
        "reported_lat_deg": np.array([36.12347, nan, 36.3, 35.50002, 35.60002]),
        "reported_lon_deg": np.array([78.10002, nan, 78.3, 80.98767, 81.00002]),
        "reported_h_m": np.array([4602.0, nan, 4802.0, 4802.0, 4902.0]),
        "ac_lat_deg": np.array([36.02, 36.0, 36.015, 35.4, 35.45]),
        "ac_lon_deg": np.array([78.02, 78.0, 78.015, 80.9, 80.95]),
        "ac_h_m": np.array([18000.5, 18000.0, 18000.25, 17000.0, 17010.0]),
        "h_datum": ["ellipsoid (WGS 84)"] * 5,
    }
    # footprints around each computed point (row 2: around the truth); row 3 clockwise
    c_lat = np.where(np.isfinite(lat), lat, 36.3)
    c_lon = np.where(np.isfinite(lon), lon, 78.3)
    offsets = [(-0.01, -0.01), (-0.01, 0.01), (0.01, 0.01), (0.01, -0.01)]  # counterclockwise in (lon, lat)
    for i, (dlat, dlon) in enumerate(offsets, start=1):
        t[f"corner{i}_lat_deg"] = c_lat + dlat
        t[f"corner{i}_lon_deg"] = c_lon + dlon
        t[f"corner{i}_h_m"] = np.full(5, 4500.0 + i)
    for i, j in ((2, 4),):  # make row 3 clockwise by swapping corners 2 and 4
        for s in ("lat_deg", "lon_deg"):
            a, b = t[f"corner{i}_{s}"].copy(), t[f"corner{j}_{s}"].copy()
            t[f"corner{i}_{s}"][3], t[f"corner{j}_{s}"][3] = b[3], a[3]
    return t


@pytest.fixture(scope="module")
def replay_csv(tmp_path_factory):
    """The bundled records replayed by the CLI: `python -m geoloc replay --height-column paper_height_m`."""
    d = tmp_path_factory.mktemp("replay")
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "replay", "--height-column", "paper_height_m", "--out", "out.csv"],
        cwd=d,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    return d / "out.csv"


def csv_rows(path):
    with open(path, newline="", encoding="utf-8-sig") as fh:
        return list(csv.DictReader(fh))


def close(a, b, tol=TOL_DEG):
    return abs(float(a) - float(b)) <= tol


# --------------------------------------------------------------------------- read_results


def test_read_results_types_bom_and_short_rows(tmp_path):
    p = tmp_path / "r.csv"
    p.write_bytes("\ufefftable,point,lat_deg,lon_deg,status,note\nT3,1,36.5,78.25,ok,a\nT3,2,,,sky\n".encode())
    t = read_results(p)
    assert list(t) == ["table", "point", "lat_deg", "lon_deg", "status", "note"]  # BOM gone
    assert t["table"] == ["T3", "T3"] and t["point"] == ["1", "2"]  # ids stay text
    assert t["lat_deg"].dtype == float and t["lat_deg"][0] == 36.5 and np.isnan(t["lat_deg"][1])
    assert t["status"] == ["ok", "sky"] and t["note"] == ["a", ""]
    (tmp_path / "e.csv").write_text("")
    assert read_results(tmp_path / "e.csv") == {}


def test_read_results_missing_file_names_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="no_such_results.csv"):
        read_results(tmp_path / "no_such_results.csv")


# --------------------------------------------------------------------------- GeoPackage


def check_points(fields, geoms, t, lat_col, lon_col, h_col, rows=None):
    """Features of a point layer against the table: coordinates and h_m."""
    for i, k in enumerate(fields["row_index"]):
        if rows is not None:
            assert k == rows[i]
        lat, lon = t[lat_col][k], t[lon_col][k]
        if not (np.isfinite(lat) and np.isfinite(lon)):
            assert geoms[i] is None
            continue
        kind, pts, z = geoms[i]
        assert kind == "Point"
        assert close(pts[0][0], lon) and close(pts[0][1], lat)
        if h_col is not None and z:
            assert close(pts[0][2], t[h_col][k], TOL_M)


def test_gpkg_layers_coordinates_and_attributes(tmp_path):
    t = synthetic()
    out = tmp_path / "r.gpkg"
    s = export(t, out)
    assert s.format == "gpkg" and s.paths == [str(out)]
    layers = {name: gtype for name, gtype in pyogrio.list_layers(out)}
    assert layers == {
        "points": "Point Z",
        "truth": "Point Z",
        "reported": "Point Z",
        "error_vectors": "LineString Z",
        "footprints": "Polygon Z",
        "track": "LineString Z",
        "ellipses": "Polygon Z",
    }

    meta, geoms, f = read_layer(out, "points")
    assert meta["crs"] == "EPSG:4979"
    assert f["row_index"] == [0, 1, 2, 3, 4]
    check_points(f, geoms, t, "lat_deg", "lon_deg", "h_m")
    assert geoms[2] is None  # the row without a position is still a feature
    for k in range(5):
        for c in ("table", "point", "image", "time_utc", "status", "method"):
            assert f[c][k] == t[c][k]
        assert f["h_datum"][k] == "ellipsoid (WGS 84)" and f["h_datum_input"][k] == t["h_datum"][k]
        for c in ("error_to_truth_m", "error_to_paper_m", "h_m"):
            assert (np.isnan(f[c][k]) and np.isnan(t[c][k])) or close(f[c][k], t[c][k], 0)
    assert meta["ogr_types"][list(meta["fields"]).index("dem_evaluations")] == "OFTInteger64"
    assert [None if np.isnan(v) else int(v) for v in np.asarray(f["dem_evaluations"], float)] == [3, 5, None, 7, 2]
    assert s.rows_without_position == [2] and "sky" in s.missing[0]
    assert s.features["points"] == 5 and s.without_geometry["points"] == 1

    _, geoms, f = read_layer(out, "truth")
    check_points(f, geoms, t, "truth_lat_deg", "truth_lon_deg", "truth_h_m", rows=[0, 1, 2, 3, 4])

    _, geoms, f = read_layer(out, "reported")
    assert f["source"] == ["paper"] * 5 + ["reported"] * 5
    paper = [i for i, s_ in enumerate(f["source"]) if s_ == "paper"]
    rep = [i for i, s_ in enumerate(f["source"]) if s_ == "reported"]
    check_points(
        {"row_index": [f["row_index"][i] for i in paper]},
        [geoms[i] for i in paper],
        t,
        "paper_lat_deg",
        "paper_lon_deg",
        "paper_height_m",
    )
    check_points(
        {"row_index": [f["row_index"][i] for i in rep]},
        [geoms[i] for i in rep],
        t,
        "reported_lat_deg",
        "reported_lon_deg",
        "reported_h_m",
    )
    assert geoms[rep[1]] is None  # reported position missing on row 1

    _, geoms, f = read_layer(out, "error_vectors")
    assert f["target"] == ["truth"] * 5 + ["paper"] * 5 + ["reported"] * 5
    for i, (k, target) in enumerate(zip(f["row_index"], f["target"])):
        prefix = target
        hcol = {"truth": "truth_h_m", "paper": "paper_height_m", "reported": "reported_h_m"}[target]
        if not np.isfinite(t["lat_deg"][k]) or not np.isfinite(t[f"{prefix}_lat_deg"][k]):
            assert geoms[i] is None
            continue
        kind, pts, z = geoms[i]
        assert kind == "LineString" and z and len(pts) == 2
        assert close(pts[0][0], t["lon_deg"][k]) and close(pts[0][1], t["lat_deg"][k])
        assert close(pts[0][2], t["h_m"][k], TOL_M)
        assert close(pts[1][0], t[f"{prefix}_lon_deg"][k]) and close(pts[1][1], t[f"{prefix}_lat_deg"][k])
        assert close(pts[1][2], t[hcol][k], TOL_M)
        err = t.get(f"error_to_{target}_m")
        if err is not None:
            assert close(f["error_m"][i], err[k], 0)

    _, geoms, f = read_layer(out, "footprints")
    for i, k in enumerate(f["row_index"]):
        kind, rings, z = geoms[i]
        assert kind == "Polygon" and len(rings) == 1 and z
        ring = rings[0]
        assert len(ring) == 5 and ring[0] == ring[-1]  # closed
        order = [int(c) for c in f["ring_corners"][i].split(",")]
        assert order in ([1, 2, 3, 4, 1], [1, 4, 3, 2, 1])
        for (x, y, zz), c in zip(ring, order):
            assert close(x, t[f"corner{c}_lon_deg"][k]) and close(y, t[f"corner{c}_lat_deg"][k])
            assert close(zz, t[f"corner{c}_h_m"][k], TOL_M)
        area = sum(x1 * y2 - x2 * y1 for (x1, y1, _), (x2, y2, _) in itertools.pairwise(ring))
        assert area > 0  # counterclockwise
    assert f["ring_corners"][3] == "1,4,3,2,1" and f["ring_corners"][0] == "1,2,3,4,1"

    _, geoms, f = read_layer(out, "track")
    assert f["table"] == ["F1", "F2"]
    assert f["start_time_utc"] == ["2024-05-01T10:00:00Z", "2024-05-01T11:00:00Z"]
    assert f["end_time_utc"] == ["2024-05-01T10:00:02Z", "2024-05-01T11:00:04Z"]
    assert f["n_samples"] == [3, 2] and f["time_source"] == ["time_utc"] * 2
    kind, pts, z = geoms[0]
    assert kind == "LineString" and z
    for p, k in zip(pts, [1, 2, 0]):  # ordered by time, not by row
        assert close(p[0], t["ac_lon_deg"][k]) and close(p[1], t["ac_lat_deg"][k])
        assert close(p[2], t["ac_h_m"][k], TOL_M)


def test_gpkg_track_single_sample_groups_have_empty_geometry(tmp_path):
    t = synthetic()
    s = export(t, tmp_path / "g.gpkg", group_by="image")
    _, geoms, f = read_layer(tmp_path / "g.gpkg", "track")
    assert f["image"] == t["image"] and all(g is None for g in geoms) and f["n_samples"] == [1] * 5
    assert s.without_geometry["track"] == 5
    with pytest.raises(ValueError, match="flight_no"):
        export(t, tmp_path / "x.gpkg", group_by="flight_no")


def test_gpkg_two_d_layer_when_heights_are_missing(tmp_path, replay_csv):
    """The bundled truth has no height: a 2D layer in EPSG:4326, no invented Z."""
    t = read_results(replay_csv)
    export(t, tmp_path / "b.gpkg")
    meta, geoms, f = read_layer(tmp_path / "b.gpkg", "truth")
    assert meta["geometry_type"] == "Point" and meta["crs"] == "EPSG:4326"
    assert all(not g[2] for g in geoms)
    check_points(f, geoms, t, "truth_lat_deg", "truth_lon_deg", None)
    # error vectors to a target without height stay at the computed height (horizontal)
    _, geoms, f = read_layer(tmp_path / "b.gpkg", "error_vectors")
    i = f["target"].index("truth")
    assert f["end_h_from"][i].startswith("h_m")
    assert geoms[i][1][0][2] == geoms[i][1][1][2]


def test_egm96_input_heights_become_ellipsoidal(tmp_path):
    t = synthetic()
    t["h_datum"] = ["EGM96 geoid (orthometric)"] + ["ellipsoid (WGS 84)"] * 4
    export(t, tmp_path / "d.gpkg")
    _, geoms, f = read_layer(tmp_path / "d.gpkg", "points")
    n0 = N(t["lat_deg"][0], t["lon_deg"][0])
    assert abs(n0) > 1.0
    assert close(geoms[0][1][0][2], t["h_m"][0] + n0, TOL_M)
    assert close(geoms[1][1][0][2], t["h_m"][1], TOL_M)
    assert f["h_datum"][0] == "ellipsoid (WGS 84)" and f["h_datum_input"][0].startswith("EGM96")
    export(t, tmp_path / "d.kml")
    folder = {fo.findtext(KML + "name"): fo for fo in kml_tree(tmp_path / "d.kml").findall(KML + "Folder")}
    pm = folder["points"].findall(KML + "Placemark")[0]
    assert close(kml_coords(pm.find(f"{KML}Point/{KML}coordinates").text)[0][2], t["h_m"][0], TOL_M)
    t["h_datum"][1] = "furlongs above the pub"
    with pytest.raises(ValueError, match="furlongs"):
        export(t, tmp_path / "e.gpkg")


def test_status_codes_become_names(tmp_path):
    t = synthetic()
    t["status"] = ["0", "0", "1", "0", "6"]
    export(t, tmp_path / "s.gpkg")
    _, _, f = read_layer(tmp_path / "s.gpkg", "points")
    assert f["status"] == ["ok", "ok", "sky", "ok", "no_convergence"]


# --------------------------------------------------------------------------- GeoJSON


def test_geojson_one_file_per_layer_rfc7946(tmp_path):
    t = synthetic()
    out = tmp_path / "r.geojson"
    s = export(t, out)
    expected = [out] + [tmp_path / f"r_{name}.geojson" for name in LAYERS[1:]]
    assert s.paths == [str(p) for p in expected] and all(p.is_file() for p in expected)
    for name, p in zip(LAYERS, expected):
        doc = json.loads(p.read_text())
        assert doc["type"] == "FeatureCollection" and doc["name"] == name
        assert "crs" not in doc  # RFC 7946: WGS 84 implied
        for feat in doc["features"]:
            assert feat["properties"]["h_datum"] == "ellipsoid (WGS 84)"
        if name == "footprints":
            for feat in doc["features"]:
                ring = feat["geometry"]["coordinates"][0]
                area = sum(x1 * y2 - x2 * y1 for (x1, y1, _), (x2, y2, _) in itertools.pairwise(ring))
                assert area > 0  # RFC 7946 exterior ring counterclockwise
    _, geoms, f = read_layer(out)
    assert f["row_index"] == [0, 1, 2, 3, 4] and geoms[2] is None
    check_points(f, geoms, t, "lat_deg", "lon_deg", "h_m")
    assert json.loads(out.read_text())["features"][2]["geometry"] is None
    assert f["status"] == t["status"] and f["image"] == t["image"]
    _, geoms, f = read_layer(tmp_path / "r_truth.geojson")
    check_points(f, geoms, t, "truth_lat_deg", "truth_lon_deg", "truth_h_m", rows=[0, 1, 2, 3, 4])
    _, geoms, f = read_layer(tmp_path / "r_track.geojson")
    assert [len(g[1]) for g in geoms] == [3, 2]
    assert close(geoms[1][1][1][0], t["ac_lon_deg"][4]) and close(geoms[1][1][1][2], t["ac_h_m"][4], TOL_M)


# --------------------------------------------------------------------------- KML


def test_kml_structure_heights_and_times(tmp_path):
    t = synthetic()
    out = tmp_path / "r.kml"
    export(t, out)
    doc = kml_tree(out)
    assert "row 2 (F1/3/img-12): status sky" in doc.findtext(KML + "description")
    folders = doc.findall(KML + "Folder")
    assert [f.findtext(KML + "name") for f in folders] == list(LAYERS)
    for fo in folders:  # schema order: name and description before the Style
        tags = [c.tag for c in fo]
        if KML + "Style" in tags:
            assert tags.index(KML + "name") < tags.index(KML + "Style")
        for pm in fo.findall(KML + "Placemark"):
            ptags = [c.tag.replace(KML, "") for c in pm]
            geom = [g for g in ("Point", "LineString", "Polygon") if g in ptags]
            assert len(geom) == 1 and ptags.index("ExtendedData") < ptags.index(geom[0])
            assert ptags[0] == "name"
        for el in fo.iter():
            if "id" in el.attrib:
                assert el.get("id")[0].isalpha()
    folder = dict(zip(LAYERS, folders))

    pms = folder["points"].findall(KML + "Placemark")
    assert len(pms) == 4  # the row without a position is listed, not drawn
    assert "row 2" in folder["points"].findtext(KML + "description")
    for pm in pms:
        d = kml_data(pm)
        k = int(d["row_index"])
        assert d["table"] == t["table"][k] and d["status"] == t["status"][k] and d["image"] == t["image"][k]
        assert d["h_datum"] == "ellipsoid (WGS 84)" and float(d["h_m"]) == t["h_m"][k]
        pt = pm.find(KML + "Point")
        assert pt.findtext(KML + "altitudeMode") == "absolute"
        ((lon, lat, alt),) = kml_coords(pt.findtext(KML + "coordinates"))
        assert close(lon, t["lon_deg"][k]) and close(lat, t["lat_deg"][k])
        n = N(lat, lon)
        assert 10 < abs(n) < 60  # the flight area has N of about -27 m
        assert close(alt, t["h_m"][k] - n, TOL_M)  # KML altitude: EGM96 orthometric
        assert close(float(d["egm96_undulation_m"]), n, TOL_M)
        when = pm.findtext(f"{KML}TimeStamp/{KML}when")
        assert when.replace(".500000", ".5") == t["time_utc"][k]

    track = folder["track"].findall(KML + "Placemark")
    assert [p.findtext(KML + "name") for p in track] == ["track F1", "track F2"]
    line = track[0].find(KML + "LineString")
    coords = kml_coords(line.findtext(KML + "coordinates"))
    for (lon, lat, alt), k in zip(coords, [1, 2, 0]):
        assert close(lon, t["ac_lon_deg"][k]) and close(lat, t["ac_lat_deg"][k])
        assert close(alt, t["ac_h_m"][k] - N(lat, lon), TOL_M)
    assert track[0].findtext(f"{KML}TimeSpan/{KML}begin") == "2024-05-01T10:00:00Z"

    polys = folder["footprints"].findall(KML + "Placemark")
    assert len(polys) == 5
    ring = kml_coords(polys[0].find(f"{KML}Polygon/{KML}outerBoundaryIs/{KML}LinearRing/{KML}coordinates").text)
    assert len(ring) == 5 and ring[0] == ring[-1]
    assert len(folder["error_vectors"].findall(KML + "Placemark")) == 4 + 4 + 3
    # and GDAL's KML reader (another independent reader) sees one layer per folder
    assert [row[0] for row in pyogrio.list_layers(out)] == list(LAYERS)
    _, geoms, f = read_layer(out, "points")
    assert len(geoms) == 4 and [int(v) for v in f["row_index"]] == [0, 1, 3, 4]


def test_kml_clamps_positions_without_height(tmp_path, replay_csv):
    export(read_results(replay_csv), tmp_path / "b.kml")
    folder = dict(zip(LAYERS, kml_tree(tmp_path / "b.kml").findall(KML + "Folder")))
    rows = csv_rows(replay_csv)
    pms = folder["truth"].findall(KML + "Placemark")
    assert len(pms) == len(rows)
    for pm, row in zip(pms, rows):
        pt = pm.find(KML + "Point")
        assert pt.findtext(KML + "altitudeMode") == "clampToGround"
        lon, lat = kml_coords(pt.findtext(KML + "coordinates"))[0][:2]
        assert close(lon, row["truth_lon_deg"]) and close(lat, row["truth_lat_deg"])


# --------------------------------------------------------------------------- CZML


def test_czml_document_clock_platform_and_points(tmp_path):
    t = synthetic()
    out = tmp_path / "r.czml"
    export(t, out)
    packets = json.loads(out.read_text())
    doc = czml3.Document.load(out)  # czml3's own model validates every packet
    assert len(doc.packets) == len(packets)
    first = packets[0]
    assert first["id"] == "document" and first["version"] == "1.0"
    assert first["clock"]["interval"] == "2024-05-01T10:00:00Z/2024-05-01T11:00:05Z"
    assert first["clock"]["currentTime"] == "2024-05-01T10:00:00Z" and first["clock"]["range"] == "CLAMPED"
    assert "row 2 (F1/3/img-12): status sky" in first["description"]
    by_id = {p["id"]: p for p in packets}
    assert len(by_id) == len(packets)  # unique ids

    plat = by_id["platform/F1"]
    pos = plat["position"]
    assert pos["epoch"] == "2024-05-01T10:00:00Z"
    v = pos["cartographicDegrees"]
    assert len(v) == 3 * 4
    times = v[0::4]
    assert times == [0.0, 1.5, 2.0]
    for j, k in enumerate([1, 2, 0]):
        assert close(v[4 * j + 1], t["ac_lon_deg"][k]) and close(v[4 * j + 2], t["ac_lat_deg"][k])
        assert close(v[4 * j + 3], t["ac_h_m"][k], TOL_M)  # ellipsoidal, as CZML specifies
    assert plat["availability"] == "2024-05-01T10:00:00Z/2024-05-01T10:00:02Z" and "path" in plat

    points = [p for p in packets if p["id"].startswith("points/")]
    assert sorted(int(p["id"].split("/")[1]) for p in points) == [0, 1, 3, 4]
    for p in points:
        k = p["properties"]["row_index"]
        lon, lat, hh = p["position"]["cartographicDegrees"]
        assert close(lon, t["lon_deg"][k]) and close(lat, t["lat_deg"][k]) and close(hh, t["h_m"][k], TOL_M)
        assert p["availability"].split("/")[0].replace(".500000", ".5") == t["time_utc"][k]
        assert p["properties"]["status"] == t["status"][k] and p["properties"]["table"] == t["table"][k]
    truth = [p for p in packets if p["id"].startswith("truth/")]
    assert len(truth) == 5
    for p in truth:
        k = p["properties"]["row_index"]
        assert close(p["position"]["cartographicDegrees"][2], t["truth_h_m"][k], TOL_M)
    vec = by_id["error_vectors/truth/0"]["polyline"]["positions"]["cartographicDegrees"]
    assert close(vec[0], t["lon_deg"][0]) and close(vec[3], t["truth_lon_deg"][0]) and close(vec[5], 4601.0, TOL_M)
    poly = by_id["footprints/0"]["polygon"]
    assert poly["perPositionHeight"] is True and len(poly["positions"]["cartographicDegrees"]) == 12


def test_czml_synthesizes_time_and_says_so(tmp_path, replay_csv):
    out = tmp_path / "b.czml"
    s = export(read_results(replay_csv), out)
    assert s.time_source == "row_order" and any("synthesized" in n for n in s.notes)
    packets = json.loads(out.read_text())
    czml3.Document.load(out)
    assert "synthesized, one second per row" in packets[0]["description"]
    assert packets[0]["clock"]["interval"] == "1970-01-01T00:00:00Z/1970-01-01T00:00:20Z"
    rows = csv_rows(replay_csv)
    t3 = next(p for p in packets if p["id"] == "platform/T3")["position"]["cartographicDegrees"]
    assert t3[0::4] == [float(i) for i in range(10)]
    assert close(t3[1], rows[0]["ac_lon_deg"]) and close(t3[3], rows[0]["ac_h_m"], TOL_M)
    truth0 = next(p for p in packets if p["id"] == "truth/0")
    assert truth0["point"]["heightReference"]["heightReference"] == "CLAMP_TO_GROUND"


# --------------------------------------------------------------------------- empty tables


@pytest.mark.parametrize("fmt", ["gpkg", "geojson", "kml", "czml"])
def test_empty_results_write_valid_empty_layers(tmp_path, fmt):
    header = "table,point,lat_deg,lon_deg,h_m,error_to_paper_m,error_to_truth_m\n"
    (tmp_path / "e.csv").write_text(header)
    for name, table in (("hdr", read_results(tmp_path / "e.csv")), ("none", {})):
        out = tmp_path / f"{name}.{fmt}"
        s = export(table, out)
        assert s.rows == 0 and s.rows_without_position == [] and set(s.features.values()) == {0}
        if fmt == "gpkg":
            assert [row[0] for row in pyogrio.list_layers(out)] == list(LAYERS)
            for layer in LAYERS:
                assert len(raw.read(str(out), layer=layer)[2]) == 0
        elif fmt == "geojson":
            assert len(s.paths) == len(LAYERS)
            for p in s.paths:
                assert json.loads(Path(p).read_text())["features"] == []
                assert len(raw.read(p)[2]) == 0
        elif fmt == "kml":
            doc = kml_tree(out)
            assert [f.findtext(KML + "name") for f in doc.findall(KML + "Folder")] == list(LAYERS)
            assert not list(doc.iter(KML + "Placemark"))
        else:
            packets = json.loads(out.read_text())
            assert [p["id"] for p in packets] == ["document"] and "clock" in packets[0]
            czml3.Document.load(out)


# --------------------------------------------------------------------------- command line


def test_cli_end_to_end_on_the_bundled_replay(tmp_path, replay_csv, capsys):
    rows = csv_rows(replay_csv)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "geoloc",
            "export",
            str(replay_csv),
            "--format",
            "gpkg",
            "--out",
            str(tmp_path / "q.gpkg"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    assert "points" in r.stdout and "20 features" in r.stdout and "rows without a computed position: 0" in r.stdout
    meta, geoms, f = read_layer(tmp_path / "q.gpkg", "points")
    assert meta["crs"] == "EPSG:4979" and len(geoms) == len(rows) == 20
    for g, k, tab, pt in zip(geoms, f["row_index"], f["table"], f["point"]):
        row = rows[k]
        assert (tab, pt) == (row["table"], row["point"])
        assert close(g[1][0][0], row["lon_deg"]) and close(g[1][0][1], row["lat_deg"])
        assert close(g[1][0][2], row["h_m"], TOL_M)
    assert close(f["error_to_truth_m"][0], rows[0]["error_to_truth_m"], 0)
    _, tgeoms, tf = read_layer(tmp_path / "q.gpkg", "track")
    assert tf["table"] == ["T3", "T4"] and [len(g[1]) for g in tgeoms] == [10, 10]

    for fmt, name in (("geojson", "q.geojson"), ("kml", "q.kml"), ("czml", "q.czml")):
        assert main(["export", str(replay_csv), "--out", str(tmp_path / name), "--group-by", "table"]) == 0
        assert f"wrote {fmt}" in capsys.readouterr().out
    assert (tmp_path / "q_track.geojson").is_file()


def test_cli_missing_input_names_it(tmp_path, capsys):
    missing = tmp_path / "nowhere" / "results.csv"
    assert main(["export", str(missing), "--out", str(tmp_path / "x.kml")]) == 2
    assert str(missing) in capsys.readouterr().err


def test_unknown_format_names_it_and_the_allowed_ones(tmp_path, replay_csv, capsys):
    assert main(["export", str(replay_csv), "--out", str(tmp_path / "x.kml"), "--format", "shapefile"]) == 2
    err = capsys.readouterr().err
    assert "'shapefile'" in err and all(f in err for f in ("gpkg", "geojson", "kml", "czml"))
    assert main(["export", str(replay_csv), "--out", str(tmp_path / "x.shp")]) == 2
    err = capsys.readouterr().err
    assert "'.shp'" in err and "gpkg" in err and ".czml" in err
    with pytest.raises(ValueError, match="dxf"):
        export({}, tmp_path / "a.gpkg", format="dxf")


def test_replay_export_option_writes_the_same_points(tmp_path, replay_csv):
    # `geoloc replay --export` writes the rows it computed, as `geoloc export` on its --out would
    rows = csv_rows(replay_csv)
    assert main(["replay", "--height-column", "paper_height_m", "--export", str(tmp_path / "r.gpkg")]) == 0
    _, geoms, f = read_layer(tmp_path / "r.gpkg", "points")
    assert len(geoms) == len(rows) == 20
    for g, k in zip(geoms, f["row_index"]):
        assert close(g[1][0][0], rows[k]["lon_deg"]) and close(g[1][0][1], rows[k]["lat_deg"])
    _, tgeoms, tf = read_layer(tmp_path / "r.gpkg", "track")
    assert tf["table"] == ["T3", "T4"]


def test_predicted_ellipses_are_polygons_of_the_right_size_and_turn(tmp_path):
    """The ``ellipses`` layer: the 90 % ellipse (the 1-sigma columns x sqrt(chi2(2, 0.9)), scipy)
    measured with pyproj's geodesics: its area is pi a b (a 72-gon has 0.13 % less), the vertex
    along the azimuth lies at the semi-major axis, the ring is counterclockwise; a row without
    a point or without an ellipse has an empty geometry."""
    from pyproj import Geod
    from scipy.stats import chi2

    t = synthetic()
    t["ellipse_major_m"] = np.array([20.0, 8.0, 5.0, 30.0, nan])
    t["ellipse_minor_m"] = np.array([5.0, 8.0, 5.0, 10.0, nan])
    t["ellipse_azimuth_deg"] = np.array([30.0, 0.0, 0.0, 120.0, nan])
    t["ce90_m"] = np.array([40.0, 17.2, 10.7, 70.0, nan])
    out = tmp_path / "e.gpkg"
    export(t, out)
    _, geoms, f = read_layer(out, "ellipses")
    assert geoms[2] is None and geoms[4] is None  # no position; no ellipse
    g = Geod(ellps="WGS84")
    r90 = math.sqrt(chi2.ppf(0.9, 2))
    for k in (0, 1, 3):
        ring = geoms[k][1][0]  # (kind, rings)
        lon = [p[0] for p in ring]
        lat = [p[1] for p in ring]
        area, _ = g.polygon_area_perimeter(lon, lat)
        a, b = r90 * t["ellipse_major_m"][k], r90 * t["ellipse_minor_m"][k]
        n = len(ring) - 1
        inscribed = math.pi * a * b * math.sin(2 * math.pi / n) / (2 * math.pi / n)
        # the ring is at the point's height h, the geodesics on the ellipsoid: lengths shrink by
        # R / (R + h) (R the Gaussian radius there; the direction's own radius differs by < 1e-5)
        la = math.radians(t["lat_deg"][k])
        w = 1 - 0.00669437999014 * math.sin(la) ** 2
        R = 6378137.0 * math.sqrt(1 - 0.00669437999014) / w
        sc = R / (R + t["h_m"][k])
        assert area == pytest.approx(inscribed * sc * sc, rel=2e-5)  # > 0: counterclockwise
        az, _, dist = g.inv(t["lon_deg"][k], t["lat_deg"][k], lon[0], lat[0])
        assert dist == pytest.approx(a * sc, rel=1e-5)
        assert (az - t["ellipse_azimuth_deg"][k] + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-4)
        assert all(abs(p[2] - t["h_m"][k]) < 1e-6 for p in ring)
        assert f["semi_major_90_m"][k] == pytest.approx(a)
