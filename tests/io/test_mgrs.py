"""MGRS / USNG references (geoloc.io.mgrs_grid) against an outside oracle.

The oracle: pyproj's UTM (EPSG:326zz / 327zz) and UPS (EPSG:32661 / 32761)
projections for the coordinates, and the grid's own rules written out here from
NGA.STND.0037 (MGRS on WGS 84, the "AA" lettering) - the zone number with the
Norway (32V) and Svalbard (31X, 33X, 35X, 37X) exceptions, the 8 deg latitude
bands C-X (X 12 deg), the 100 km column letters by zone set, the row letters
offset by 5 in even zones, the UPS zones A/B/Y/Z and their letter tables - and
digits truncated, never rounded. None of it is taken from the code under test.
"""

import math

import numpy as np
import pytest
from pyproj import Transformer

from geoloc.io.mgrs_grid import (
    format_usng,
    latlon_to_mgrs,
    mgrs_column,
    mgrs_to_latlon,
    normalize_mgrs,
    parse_mgrs,
)
from geoloc.status import Status

BANDS = "CDEFGHJKLMNPQRSTUVWX"
ROWS_UTM = "ABCDEFGHJKLMNPQRSTUV"
COLS_UTM = ("ABCDEFGH", "JKLMNPQR", "STUVWXYZ")


def zone_of(lat, lon):
    """UTM zone number with the Norway and Svalbard exceptions (NGA.STND.0037)."""
    z = int(math.floor((lon + 180.0) / 6.0)) + 1
    z = 60 if z == 61 else z
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        return 32
    if 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        return 31 if lon < 9 else 33 if lon < 21 else 35 if lon < 33 else 37
    return z


def oracle(lat, lon):
    """The 1 m MGRS reference by pyproj + the standard's rules."""
    if -80.0 <= lat <= 84.0:
        z = zone_of(lat, lon)
        epsg = (32600 if lat >= 0 else 32700) + z
        e, n = Transformer.from_crs(4326, epsg, always_xy=True).transform(lon, lat)
        band = BANDS[min(int(math.floor((lat + 80.0) / 8.0)), 19)]
        col = COLS_UTM[(z - 1) % 3][int(e // 100000) - 1]
        row = ROWS_UTM[(int(n // 100000) + (5 if z % 2 == 0 else 0)) % 20]
        return f"{z:02d}{band}{col}{row}{int(e % 100000):05d}{int(n % 100000):05d}"
    north = lat > 0
    e, n = Transformer.from_crs(4326, 32661 if north else 32761, always_xy=True).transform(lon, lat)
    west = lon < 0
    if north:
        zl = "Y" if west else "Z"
        cols, e0 = ("JKLPQRSTUXYZ", 800000) if west else ("ABCFGHJ", 2000000)
        rows, n0 = "ABCDEFGHJKLMNP", 1300000
    else:
        zl = "A" if west else "B"
        cols, e0 = ("JKLPQRSTUXYZ", 800000) if west else ("ABCFGHJKLPQR", 2000000)
        rows, n0 = "ABCDEFGHJKLMNPQRSTUVWXYZ", 800000
    col = cols[int((e - e0) // 100000)]
    row = rows[int((n - n0) // 100000)]
    return f"{zl}{col}{row}{int(e % 100000):05d}{int(n % 100000):05d}"


EDGE = 1e-4  # deg, about 11 m: each side of a zone / band edge, well clear of rounding

EDGE_POINTS = [
    # zone edges at mid latitude, both hemispheres, and the antimeridian
    (38.9, -78.0 - EDGE),
    (38.9, -78.0 + EDGE),
    (-33.9, 18.0 - EDGE),
    (-33.9, 18.0 + EDGE),
    (0.0, 180.0 - EDGE),
    (0.0, -180.0 + EDGE),
    (EDGE, 0.0),
    (-EDGE, -EDGE),
    # band edges (8 deg) and the equator
    (8.0 - EDGE, 10.0),
    (8.0 + EDGE, 10.0),
    (-8.0 - EDGE, 10.0),
    (-8.0 + EDGE, 10.0),
    (64.0 - EDGE, 20.0),
    (64.0 + EDGE, 20.0),
    (72.0 - EDGE, 20.0),
    (72.0 + EDGE, 20.0),
    # Norway: 32V is 3-12 E in 56-64 N; 31V is cut to 0-3 E
    (60.0, 3.0 - EDGE),
    (60.0, 3.0 + EDGE),
    (60.0, 12.0 - EDGE),
    (60.0, 12.0 + EDGE),
    (56.0 - EDGE, 5.0),
    (56.0 + EDGE, 5.0),
    (64.0 - EDGE, 5.0),
    (64.0 + EDGE, 5.0),
    # Svalbard: 31X 0-9, 33X 9-21, 35X 21-33, 37X 33-42 E in 72-84 N (32X, 34X, 36X do not exist)
    (78.0, EDGE),
    (78.0, 9.0 - EDGE),
    (78.0, 9.0 + EDGE),
    (78.0, 21.0 - EDGE),
    (78.0, 21.0 + EDGE),
    (78.0, 33.0 - EDGE),
    (78.0, 33.0 + EDGE),
    (78.0, 42.0 - EDGE),
    (78.0, 42.0 + EDGE),
    (72.0 + EDGE, 10.0),
    (72.0 - EDGE, 10.0),
    (83.9, 30.0),
    # UTM / UPS limits: 84 N and 80 S, and the poles' caps on both sides of the 0 meridian
    (84.0 - EDGE, 10.0),
    (84.0 + EDGE, 10.0),
    (-80.0 + EDGE, -60.0),
    (-80.0 - EDGE, -60.0),
    (87.0, -EDGE),
    (87.0, EDGE),
    (87.0, -135.0),
    (87.0, 135.0),
    (89.99, 60.0),
    (-85.0, -EDGE),
    (-85.0, EDGE),
    (-85.0, -45.0),
    (-85.0, 170.0),
    (-89.99, -100.0),
]


@pytest.mark.parametrize("lat,lon", EDGE_POINTS)
def test_edges_match_pyproj_and_the_standard(lat, lon):
    r = latlon_to_mgrs(lat, lon)
    assert int(r.status) == Status.OK, r.reason
    assert r.text[()] == oracle(lat, lon)


def test_random_points_everywhere_match():
    rng = np.random.default_rng(33)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, 400)))
    lon = rng.uniform(-180, 180, 400)
    r = latlon_to_mgrs(lat, lon)
    assert np.all(r.status == Status.OK)
    bad = [(a, o, t, oracle(a, o)) for a, o, t in zip(lat, lon, r.text) if t != oracle(a, o)]
    assert not bad, bad[:5]


def test_poles_and_exceptions_by_name():
    # the poles are UPS (2 000 000 m E and N): north in square Z A H, south in B A N
    # (letters from the UPS tables in oracle()); exceptions named outright
    assert latlon_to_mgrs(90.0, 0.0).text[()] == "ZAH0000000000"
    assert latlon_to_mgrs(-90.0, 0.0).text[()] == "BAN0000000000"
    assert latlon_to_mgrs(60.0, 5.0).text[()].startswith("32V")  # zone 31 would be by the 6 deg rule
    assert latlon_to_mgrs(78.0, 10.0).text[()].startswith("33X")  # zone 32 would be
    assert latlon_to_mgrs(78.0, 20.0).text[()].startswith("33X")  # zone 34 would be


def test_truncated_not_rounded_and_precision():
    # pyproj puts this point at 323 486.737 E, 4 306 483.048 N in zone 18: truncation gives 23486
    e, n = Transformer.from_crs(4326, 32618, always_xy=True).transform(-77.0352, 38.8895)
    assert 0.5 < e % 1 < 1.0  # rounding would have given ...487
    assert latlon_to_mgrs(38.8895, -77.0352).text[()] == f"18SUJ{int(e) % 100000:05d}{int(n) % 100000:05d}"
    assert latlon_to_mgrs(38.8895, -77.0352, precision=3).text[()] == "18SUJ234064"
    assert latlon_to_mgrs(38.8895, -77.0352, precision=0).text[()] == "18SUJ"
    with pytest.raises(ValueError, match="precision"):
        latlon_to_mgrs(0, 0, precision=6)


def test_back_to_latlon_is_the_square_centre():
    # the square of a 1 m reference is [E, E + 1) x [N, N + 1): its centre at +0.5 m each way
    ref = oracle(38.8895, -77.0352)
    r = mgrs_to_latlon([ref, format_usng(ref), ref.lower(), "18SUJ2306"])
    assert np.all(r.status == Status.OK)
    to_utm = Transformer.from_crs(4326, 32618, always_xy=True)
    e, n = to_utm.transform(r.lon_deg, r.lat_deg)
    # pyproj and GEOTRANS agree to well under a millimetre on UTM; 1e-3 m allows for it
    np.testing.assert_allclose(e[:3], 300000 + int(ref[5:10]) + 0.5, atol=1e-3)
    np.testing.assert_allclose(n[:3], 4300000 + int(ref[10:]) + 0.5, atol=1e-3)
    np.testing.assert_allclose([e[3], n[3]], [323500.0, 4306500.0], atol=1e-3)  # 1 km square's centre


def test_usng_groups():
    assert format_usng("18SUJ2348606483") == "18S UJ 23486 06483"
    assert format_usng("04QFJ12345678") == "4Q FJ 1234 5678"
    assert format_usng("ZAH") == "Z AH"
    assert normalize_mgrs(" 4q fj 1234 5678 ") == "04QFJ12345678"


def test_batch_bad_points_give_empty_and_reason():
    r = latlon_to_mgrs([np.nan, 91.0, 45.0, 10.0], [0.0, 0.0, np.inf, 370.0])
    assert list(r.text) == ["", "", "", ""]
    assert np.all(r.status == Status.INVALID_INPUT)
    assert "not a finite" in r.reason[0] and "91.0" in r.reason[1] and "370.0" in r.reason[3]
    assert mgrs_column([45.0, np.nan], [7.0, 7.0])[1] == ""
    b = mgrs_to_latlon(["18SUJ2348606483", "hello", "18SUJ123", "18SII1234", 5])
    assert b.status.tolist() == [0, 3, 3, 3, 3]
    assert np.isnan(b.lat_deg[1:]).all()
    assert "odd" in b.reason[2] or "digits" in b.reason[2]


def test_parse_mgrs_names_the_value():
    lat, lon = parse_mgrs("18S UJ 23486 06483")
    assert abs(lat - 38.8895) < 1e-4 and abs(lon + 77.0352) < 1e-4
    with pytest.raises(ValueError, match=r"--mgrs 'XX12'"):
        parse_mgrs("XX12")


# ------------------------------------------------------------ where references are written
def test_locate_json_has_mgrs_and_usng(capsys):
    import json

    from geoloc.cli import main

    rc = main(
        [
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
            "--target-h-m",
            "5083.5",
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["mgrs"] == oracle(out["lat_deg"], out["lon_deg"])
    assert out["usng"] == format_usng(out["mgrs"]) and out["usng"].startswith("44S ")


def test_replay_csv_has_mgrs_after_lon(tmp_path, capsys):
    import csv

    from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
    from geoloc.cli import main

    out = tmp_path / "out.csv"
    assert (
        main(
            [
                "replay",
                str(asset_path(*DEFAULT_RECORDS)),
                "--camera",
                str(asset_path(*DEFAULT_CAMERA)),
                "--height-column",
                "paper_height_m",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    with out.open() as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        header = reader.fieldnames
    assert header.index("mgrs") == header.index("lon_deg") + 1
    for r in rows:
        # the CSV's 8-decimal degrees (1 mm) may sit across a 1 m line from the full-precision point:
        # the reference must equal the oracle's at the written point, or be its 1 m neighbour
        ref = oracle(float(r["lat_deg"]), float(r["lon_deg"]))
        assert r["mgrs"][:5] == ref[:5]
        assert abs(int(r["mgrs"][5:10]) - int(ref[5:10])) <= 1 and abs(int(r["mgrs"][10:]) - int(ref[10:])) <= 1


def test_klv_replay_csv_and_gis_points_have_mgrs(tmp_path):
    import csv

    import pyogrio.raw

    from geoloc.assets import asset_path
    from geoloc.io.gis import export, read_results
    from geoloc.workflows.klv_replay import replay_klv, write_klv_csv

    r = replay_klv(asset_path("klv", "example_flight.klv"))
    out = tmp_path / "f.csv"
    write_klv_csv(out, r)
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    lat, lon = r.columns["lat_deg"], r.columns["lon_deg"]
    for k in range(0, len(rows), 25):
        assert rows[k]["mgrs"] == (oracle(lat[k], lon[k]) if np.isfinite(lat[k]) else "")
    gpkg = tmp_path / "f.gpkg"
    export(read_results(out), gpkg)
    meta, _, _, fields = pyogrio.raw.read(str(gpkg), layer="points")
    names = list(meta["fields"])
    got = fields[names.index("mgrs")]
    rep = pyogrio.raw.read(str(gpkg), layer="reported")
    rep_mgrs = rep[3][list(rep[0]["fields"]).index("mgrs")]
    rlat, rlon = r.columns["reported_lat_deg"], r.columns["reported_lon_deg"]
    for k in range(0, len(rows), 25):
        # the GIS attribute is made from the CSV's 9-decimal degrees (0.1 mm): the same 1 m square
        # as the full-precision point except within 0.1 mm of a line, which these rows are not
        assert got[k] == (oracle(lat[k], lon[k]) if np.isfinite(lat[k]) else None)
        if np.isfinite(rlat[k]):
            assert rep_mgrs[k] == oracle(rlat[k], rlon[k])
