"""``geoloc limb``: raw and scenario modes, JSON/CSV output and error messages."""

import csv
import json
import math
from pathlib import Path

import numpy as np
from pyproj import Transformer

from geoloc.cli import main

SCENARIO = str(Path(__file__).resolve().parents[2] / "assets" / "scenarios" / "tiangong2_limb.toml")
TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def tangent_line(lat, lon, h, az, dist=2.2e6):
    """Line horizontal at a pyproj point of height h: its exact tangent height is h."""
    p0 = np.array(TO_ECEF.transform(lon, lat, h))
    la, lo, a = map(math.radians, (lat, lon, az))
    north = np.array([-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)])
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    d = math.cos(a) * north + math.sin(a) * east
    return p0 - dist * d, d


def test_raw_json(capsys):
    o, d = tangent_line(20.0, 30.0, 35e3, 60.0)
    rc = main(
        [
            "limb",
            "--origin-ecef",
            *(repr(float(x)) for x in o),
            "--direction-ecef",
            *(repr(float(x)) for x in d),
            "--json",
        ]
    )
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["status"] == "ok"
    # The constructed line's minimum height is 35 km (1 mm: pyproj and float rounding).
    assert abs(out["exact_tangent_h_m"] - 35e3) < 1e-3
    assert abs(out["exact_tangent_lat_deg"] - 20.0) < 1e-7 and abs(out["exact_tangent_lon_deg"] - 30.0) < 1e-7
    # [L18] height: a lower bound within the e^4 h^2 sin^2(2 lat) / (8 R) ~ 0.4 mm of this line.
    assert -1e-3 < out["h_difference_m"] <= 1e-6
    assert out["h_difference_m"] == round(out["tangent_h_m"] - out["exact_tangent_h_m"], 6)
    # eq. 19 latitude is biased north by ~ e^2 (h/R) sin cos (~1e-3 deg at 35 km, 20 deg).
    assert 0 < out["tangent_lat_deg"] - 20.0 < 2e-3
    assert 2 <= out["nr_iterations"] <= 6 and abs(out["nr_residual"]) < 1e-12


def test_raw_text_and_hits_earth(capsys):
    o, d = tangent_line(-40.0, 170.0, 12e3, 0.0)
    assert (
        main(["limb", "--origin-ecef", *(repr(float(x)) for x in o), "--direction-ecef", *(repr(float(x)) for x in d)])
        == 0
    )
    text = capsys.readouterr().out
    assert "virtual ellipsoid" in text and "exact" in text and "12000.000 m" in text
    o, d = tangent_line(-40.0, 170.0, -2e3, 0.0)
    rc = main(
        [
            "limb",
            "--origin-ecef",
            *(repr(float(x)) for x in o),
            "--direction-ecef",
            *(repr(float(x)) for x in d),
            "--json",
        ]
    )
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert rc == 1 and out["status"] == "hits_earth" and out["exact_tangent_h_m"] is None
    assert "hits the Earth" in cap.err
    assert abs(out["earth_hit_lon_deg"] - 170.0) < 20  # the ground point is near, not NaN


def test_scenario_csv(tmp_path, capsys):
    out = tmp_path / "limb.csv"
    rc = main(["limb", SCENARIO, "--frames", "3", "--out", str(out), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["frames"] == 3 and summary["pixels"] == 48
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 3 * 48
    assert rows[0]["frame"] == "0" and rows[-1]["pixel"] == "47"
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) + sum(r["status"] == "hits_earth" for r in rows) == len(rows)
    h = np.array([float(r["exact_tangent_h_m"]) for r in ok])
    assert h.min() < 10e3 and h.max() > 60e3
    diff = np.array([float(r["h_difference_m"]) for r in ok])
    assert np.all(np.abs(diff) < 0.01)
    assert summary["status_counts"]["ok"] == len(ok)


def test_errors(capsys):
    assert main(["limb"]) == 2
    assert "give a SCENARIO file" in capsys.readouterr().err
    assert main(["limb", SCENARIO, "--origin-ecef", "7e6", "0", "0", "--direction-ecef", "0", "1", "0"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["limb", "--origin-ecef", "7e6", "0", "0", "--direction-ecef", "0", "0", "0"]) == 2
    assert "--direction-ecef must be finite and non-zero, got [0.0, 0.0, 0.0]" in capsys.readouterr().err
    assert main(["limb", "--origin-ecef", "7e6", "0", "0"]) == 2
    assert "--direction-ecef" in capsys.readouterr().err
    assert main(["limb", SCENARIO, "--frames", "0"]) == 2
    assert "--frames must be >= 1, got 0" in capsys.readouterr().err
    assert main(["limb", "/nonexistent/scenario.toml"]) == 2
    assert "scenario.toml" in capsys.readouterr().err
