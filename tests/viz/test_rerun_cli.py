"""``geoloc log``: the verb writes recordings the SDK reads back, serves them, and names bad input."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import ASSETS
from geoloc.cli import main
from geoloc.io.records import load_records

RECORDS = Path(ASSETS) / "records" / "qiao2017_flight_tests.csv"


pytestmark = pytest.mark.usefixtures("rerun_home")  # rerun writes under ~: a temp dir


def _series(path, entity):
    """(step, value) of a scalar series; for a two-flight recording ``/series/<rel>`` joins
    ``/series/T3/<rel>`` and ``/series/T4/<rel>`` (one entity per flight)."""
    from rerun.chunk import RrdReader

    idx, val = [], []
    wanted = {entity, entity.replace("/series/", "/series/T3/", 1), entity.replace("/series/", "/series/T4/", 1)}
    for ch in RrdReader(path).stream():
        if ch.entity_path not in wanted:
            continue
        b = ch.to_record_batch()
        if "Scalars:scalars" not in b.schema.names:  # the static SeriesLines style (colour, name)
            continue
        key = "record" if "record" in b.schema.names else "frame"
        idx += b.column(key).to_pylist()
        val += [r[0] for r in b.column("Scalars:scalars").to_pylist()]
    order = np.argsort(idx)
    return np.array(idx)[order], np.array(val)[order]


def short_scenario(tmp_path) -> Path:
    """The bundled scan file, cut to 10 s at 1 Hz (11 steps, one sweep 10 -> 82 deg), paths made absolute."""
    scen = Path(ASSETS) / "scenarios"
    text = (scen / "flight_scan.toml").read_text()
    text = text.replace('"../', f'"{scen.parent.as_posix()}/')
    text = text.replace('error_model = "', f'error_model = "{scen.as_posix()}/')
    text = text.replace("duration_s = 60.0", "duration_s = 10.0").replace("rate_hz = 4.0", "rate_hz = 1.0")
    p = tmp_path / "short_scan.toml"
    p.write_text(text)
    return p


def test_bundled_scenario_by_name():
    from geoloc_viz.cli.log import resolve_input

    assert resolve_input("flight_scan") == Path(ASSETS) / "scenarios" / "flight_scan.toml"


def test_log_scenario(tmp_path, capsys):
    out = tmp_path / "scan.rrd"
    assert main(["log", str(short_scenario(tmp_path)), "--out", str(out)]) == 0
    assert "11 steps (11 located)" in capsys.readouterr().out
    k, roll = _series(out, "/series/gimbal/gimbal_roll_deg")
    assert list(k) == list(range(11))
    # one sweep of the whisk broom, closed form: 10 + 72 t / 10 deg for t = 0..10 s
    np.testing.assert_allclose(roll, 10.0 + 7.2 * np.arange(11), atol=1e-12)


def test_log_records_at_one_height(tmp_path):
    out = tmp_path / "rec.rrd"
    assert main(["log", str(RECORDS), "--out", str(out), "--target-h-m", "5000"]) == 0
    k, h = _series(out, "/series/height/target_h_m")
    assert list(k) == list(range(20))
    # The inflated ellipsoid of [Q17 eq. 11] is within millimetres of the constant-height
    # surface at 5 km (geoloc.surfaces.height): 0.01 m.
    np.testing.assert_allclose(h, 5000.0, atol=0.01)


def test_log_records_with_a_bad_row_skips_it(tmp_path, capsys):
    lines = RECORDS.read_text().splitlines()
    bad = lines[1].split(",")
    bad[4] = "95.0"  # ac_lat_deg out of range
    p = tmp_path / "bad.csv"
    p.write_text("\n".join([lines[0], ",".join(bad)] + lines[2:]) + "\n")
    out = tmp_path / "bad.rrd"
    assert main(["log", str(p), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "line 2: ac_lat_deg = '95.0'" in err
    # two flights: one series entity each (T3's first record is the rejected one: 9 + 10 records)
    k3, e3 = _series(out, "/series/T3/error/to_truth_m")
    k4, e4 = _series(out, "/series/T4/error/to_truth_m")
    assert list(k3) == list(range(9)) and list(k4) == list(range(9, 19))
    e = np.r_[e3, e4]
    np.testing.assert_allclose(e, load_records(p).column("paper_error_m"), atol=2.0)  # see test_rerun_log


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["log", "no_such_scenario", "--out", "x.rrd"], "input not found: no_such_scenario"),
        (["log", "flight_scan"], "--out is required"),
        (["log", "flight_scan", "--out", "x.rrd", "--display-scale", "0"], "--display-scale = 0.0"),
    ],
)
def test_bad_input_is_named(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert needle in capsys.readouterr().err


def test_serve_hosts_a_grpc_server(tmp_path):
    from geoloc_viz.rerun_log import write
    from geoloc_viz.rerun_model import steps_from_records

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    steps, _ = steps_from_records(RECORDS)
    rec = write(steps, None, serve=True, grpc_port=port)
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass
    finally:
        rec.disconnect()
