"""The KLV write-back's parts on a replay table written in the test (geoloc.workflows.klv_fix).

``tests/workflows/test_klv_fix.py`` runs whole flights; here a one-row replay is laid out by hand, so each
item the write-back chooses (MISB ST 0601 tags 45/46, 82-89) and each line of its summary is
checked against values the test states: the tag numbers of ST 0601's table (82 + 2 (corner - 1)
for a latitude, one more for its longitude), the items' encodings by ``geoloc.io.klv`` (not the
module under test), the counts given.
"""

import math

import numpy as np
import pytest

from geoloc.io.klv import TAG_BY_NAME, encode_packet, encode_value
from geoloc.status import Status, describe
from geoloc.workflows import klv_fix
from geoloc.workflows.klv_fix import KlvFix


class _Replay:
    """The columns of a KlvReplay the write-back reads, for rows given as dicts."""

    def __init__(self, **cols):
        self.columns = {k: np.asarray(v) if not isinstance(v, list) else v for k, v in cols.items()}

    def __len__(self):
        return len(self.columns["status"])


def _row(status=Status.OK, corner_status=Status.OK, ce90=5.0, le90=7.0, **extra):
    cols = dict(
        status=[int(status)],
        corner_status=[int(corner_status)],
        note=[""],
        lat_deg=[36.5],
        lon_deg=[-84.2],
        h_m=[400.0],
        ce90_m=[ce90],
        le90_m=[le90],
        packet=[7],
        offset=[0],
    )
    for j in range(4):
        cols[f"corner{j + 1}_lat_deg"] = [36.5 + 0.001 * (j + 1)]
        cols[f"corner{j + 1}_lon_deg"] = [-84.2 - 0.002 * (j + 1)]
    cols.update(extra)
    return _Replay(**cols)


def test_full_corners_go_to_tags_82_to_89_latitude_then_longitude():
    notes = []
    out = klv_fix._new_values(_row(), 0, set(range(82, 90)), notes)
    assert sorted(out) == list(range(82, 90)) and notes == []
    for j in range(4):
        assert out[82 + 2 * j] == encode_value(f"corner_latitude_{j + 1}_deg", 36.5 + 0.001 * (j + 1))
        assert out[83 + 2 * j] == encode_value(f"corner_longitude_{j + 1}_deg", -84.2 - 0.002 * (j + 1))


def test_target_error_tags_written_capped_or_left_with_a_note():
    hi = TAG_BY_NAME["target_error_ce90_m"].hi
    assert hi == 4095.0  # ST 0601 tags 45/46: 0..4095 m
    notes = []
    out = klv_fix._new_values(_row(ce90=5000.0, le90=math.nan), 0, set(), notes, errors=True)
    assert out == {45: encode_value("target_error_ce90_m", 4095.0)}
    assert notes == [
        "tag 45: predicted CE90 5000 m is beyond the item's 4095 m: written as 4095 m",
        "tag 46: no predicted LE90 for this centre: left as it was",
    ]
    notes = []
    out = klv_fix._new_values(_row(ce90=12.0, le90=20.0), 0, set(), notes, errors=True)
    assert out == {45: encode_value("target_error_ce90_m", 12.0), 46: encode_value("target_error_le90_m", 20.0)}
    assert notes == []


def test_why_a_packet_is_left_unchanged():
    r = _row(status=Status.LEFT_DEM)
    assert klv_fix._why_unchanged(r, 0) == f"left_dem: {describe(Status.LEFT_DEM)}"
    r.columns["note"] = ["over the sea"]
    assert klv_fix._why_unchanged(r, 0) == "left_dem: over the sea"


def test_added_tags_are_counted_per_packet():
    fix = KlvFix("in.klv", "out.klv")
    rw = klv_fix._Rewriter(_row(), fix, errors=True)
    blob = encode_packet({"precision_time_stamp_us": 1_700_000_000_000_000, "frame_center_latitude_deg": 1.0})
    rw.packet(blob)
    assert fix.added == {45: 1, 46: 1} and fix.items == {23: 1, 45: 1, 46: 1} and fix.rewritten == 1


def test_a_raw_file_whose_packets_are_not_where_the_replay_read_them_is_refused():
    a = encode_packet({"precision_time_stamp_us": 1_700_000_000_000_000, "frame_center_latitude_deg": 1.0})
    fix = KlvFix("in.klv", "out.klv")
    r = _row(offset=[len(a)])  # the replay read its one packet further on
    with pytest.raises(RuntimeError, match=rf"packet at byte 0: the replay's row 0 is at byte {len(a)}"):
        klv_fix._fix_bytes(a, klv_fix._Rewriter(r, fix), verify=True, raw=True)
    # more packets than rows: the stream changed while it was read
    fix = KlvFix("in.klv", "out.klv")
    with pytest.raises(RuntimeError, match="more good packets than replay rows"):
        klv_fix._fix_bytes(a + a, klv_fix._Rewriter(_row(), fix), verify=True, raw=True)


def test_the_summary_counts():
    fix = KlvFix(
        "in.klv",
        "out.klv",
        packets=30,
        rewritten=5,
        unchanged=[(k, "no_intersection: x") for k in range(25)],
        items={45: 3, 46: 2},
        budget_source="cam.toml",
        added={45: 1, 46: 0},
    )
    text = str(fix)
    assert "in.klv: 30 packets read, 5 rewritten, 25 left unchanged, 0 bad packet(s) copied" in text
    assert "items rewritten: tag 45: 3, tag 46: 2" in text
    assert "[uncertainty] budget of cam.toml (3 / 2 packets; tag 45 added to 1 packet(s) that had none)" in text
    # one line per reason, not per packet
    assert text.count("unchanged: no_intersection: x") == 1
    assert "  packets 0-24 (25): unchanged: no_intersection: x" in text
    # 25 reasons: the first 20 a line each, the other five counted
    many = KlvFix("in.klv", "out.klv", packets=25, unchanged=[(k, f"reason {k}") for k in range(25)])
    lines = str(many).splitlines()
    assert [ln for ln in lines if ": unchanged: reason " in ln] == [
        f"  packet {k}: unchanged: reason {k}" for k in range(20)
    ]
    assert "  ... 5 more unchanged, for 5 other reasons" in lines
