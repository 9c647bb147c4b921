"""The GIS layers' steps, each alone (geoloc.io.gis: ``_row_labels``, ``_time_base``,
``_Rows.position``, ``_footprint_layer``, ``_track_layer``, ``_error_vector_layer``), on tables
written here by hand.

Oracles: Python's datetime for the time base, PROJ's vgridshift on the bundled EGM96 grid for N
(tests/workflows/test_klv_replay.py's ``proj_undulation``), RFC 7946 section 3.1.6 for the ring's
orientation (checked with a shoelace written here, on the ring as written).
"""

from datetime import UTC, datetime

import numpy as np
import pytest

from geoloc.io import gis
from test_klv_replay import proj_undulation

LAT, LON = 36.60, -84.25  # on the bundled EGM96 crop (Jacksboro)


def rows_of(table, group_by=None, epoch=gis.DEFAULT_EPOCH):
    n = gis._nrows(table)
    ids, labels = gis._row_labels(table, n)
    fields, values, _status, egm96 = gis._row_fields(table, n, ids, group_by)
    _base, seconds, _src = gis._time_base(table, n, epoch)
    return gis._Rows(table, n, labels, fields, values, egm96, seconds)


def test_row_labels_join_the_ids_present_else_name_the_row():
    ids, labels = gis._row_labels({"table": ["f1", "f1", ""], "point": ["P1", "", ""]}, 3)
    assert ids == ["table", "point"]
    assert labels == ["f1/P1", "f1", "row 2"]


def test_time_base_is_the_earliest_utc_stamp_else_the_epoch():
    base, sec, src = gis._time_base({"time_utc": ["2024-05-01T10:00:05Z", "", "2024-05-01T10:00:00Z"]}, 3, None)
    assert (base, src) == (datetime(2024, 5, 1, 10, 0, 0, tzinfo=UTC), "time_utc")
    assert sec[0] == 5.0 and np.isnan(sec[1]) and sec[2] == 0.0
    base, sec, src = gis._time_base({"time_s": [3.5, 1.0]}, 2, "2020-01-01T00:00:00Z")
    assert (base, sec.tolist(), src) == (datetime(2020, 1, 1, tzinfo=UTC), [3.5, 1.0], "time_s")
    base, sec, src = gis._time_base({"lat_deg": [1.0, 2.0, 3.0]}, 3, gis.DEFAULT_EPOCH)
    assert (base, sec.tolist(), src) == (datetime(1970, 1, 1, tzinfo=UTC), [0.0, 1.0, 2.0], "row_order")


def test_a_position_on_egm96_rows_is_made_ellipsoidal_with_n():
    table = {"lat_deg": [LAT, LAT], "lon_deg": [LON, LON], "h_m": [300.0, 300.0], "h_datum": ["EGM96", "WGS 84"]}
    lat, lon, h, hcol = rows_of(table).position("lat_deg", "lon_deg", ("h_m",))
    # 1 mm: the bundled grid read bilinearly by two codes (the project's and PROJ's)
    assert h[0] == pytest.approx(300.0 + proj_undulation(LAT, LON), abs=1e-3)
    assert h[1] == 300.0 and hcol == "h_m"
    assert rows_of(table).position("nope_lat", "lon_deg", ("h_m",)) is None


def shoelace(ring):
    return 0.5 * sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(ring, ring[1:]))


@pytest.mark.parametrize("clockwise", [False, True])
def test_footprint_ring_is_closed_and_counterclockwise(clockwise):
    # corners 1..4 around a 0.01 deg square, counterclockwise or clockwise as given
    square = [(0.0, 0.0), (0.01, 0.0), (0.01, 0.01), (0.0, 0.01)]
    if clockwise:
        square = square[::-1]
    table = {}
    for i, (dx, dy) in enumerate(square, start=1):
        table[f"corner{i}_lat_deg"], table[f"corner{i}_lon_deg"] = [LAT + dy], [LON + dx]
        table[f"corner{i}_h_m"] = [300.0]
    lay = gis._footprint_layer(rows_of(table))
    (f,) = lay.features
    assert f.coords[0] == f.coords[-1] and len(f.coords) == 5
    assert shoelace([(c[0] - LON, c[1] - LAT) for c in f.coords]) > 0
    assert f.attrs["ring_corners"] == ("1,4,3,2,1" if clockwise else "1,2,3,4,1")


def test_track_keeps_one_sample_per_time_in_time_order_per_group():
    table = {
        "table": ["a", "a", "a", "b", "a"],
        "time_s": [2.0, 1.0, 2.0, 0.0, np.nan],
        "ac_lat_deg": [LAT + 0.2, LAT + 0.1, LAT + 0.9, LAT, LAT],
        "ac_lon_deg": [LON] * 5,
        "ac_h_m": [1000.0] * 5,
    }
    lay = gis._track_layer(rows_of(table, "table"), "table", "time_s")
    a, b = lay.features
    # group a: row 1 (t = 1), then row 0 (the first at t = 2; row 2 at the same time is dropped),
    # row 4 has no time
    assert (a.attrs["table"], a.attrs["n_samples"], a.attrs["first_row"], a.attrs["last_row"]) == ("a", 2, 1, 0)
    assert [s[1] for s in a.samples] == pytest.approx([LAT + 0.1, LAT + 0.2])
    assert a.times == [1.0, 2.0]
    assert b.attrs["n_samples"] == 1 and b.coords is None  # one sample is no line


def test_error_vector_ends_at_the_computed_height_when_the_target_has_none():
    table = {
        "lat_deg": [LAT],
        "lon_deg": [LON],
        "h_m": [310.0],
        "truth_lat_deg": [LAT + 1e-4],
        "truth_lon_deg": [LON],
        "error_to_truth_m": [11.1],
    }
    rows = rows_of(table)
    comp, truth = rows.position("lat_deg", "lon_deg", ("h_m",)), rows.position(*gis._TRUTH[1:])
    (f,) = gis._error_vector_layer(rows, comp, [("truth", truth)]).features
    assert f.coords == [(LON, LAT, 310.0), (LON, LAT + 1e-4, 310.0)]
    assert f.attrs["end_h_from"] == "h_m (target height unknown)" and f.attrs["error_m"] == 11.1
