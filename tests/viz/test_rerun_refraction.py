"""``geoloc log --refraction standard``: the correction per frame in the recording.

The recording is read back with rerun's own reader (``rerun.chunk.RrdReader``): ``series/refraction_m``
on the ``record`` timeline equals, record by record, how far refraction moved each point in the
core's own pipeline (``geoloc.pipeline.Pipeline`` with ``Corrections.for_sensor(sensor, "standard")``
on the same DEM surface; not the viewer's code), and the first record's equals ``geoloc locate
--refraction standard --json``'s ``refraction_m`` (a subprocess of the CLI); the recording's notes
name the correction. Without ``--refraction`` there is no such series.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RECORDS = ROOT / "assets" / "records" / "qiao2017_flight_tests.csv"
DEM = ROOT / "assets" / "dem" / "etopo5_flight_area.tif"


def read(path) -> dict:
    """Entity path -> list of pyarrow record batches of the recording."""
    from rerun.chunk import RrdReader

    out: dict = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, []).append(ch.to_record_batch())
    return out


def series(batches, name="Scalars:scalars"):
    """(record, value) of a scalar series, sorted by record."""
    k, v = [], []
    for b in batches:
        if "record" in b.schema.names and name in b.schema.names:
            k += b.column("record").to_pylist()
            v += [x[0] if x is not None else np.nan for x in b.column(name).to_pylist()]
    order = np.argsort(k)
    return np.asarray(k)[order], np.asarray(v, float)[order]


def texts(rec) -> str:
    out = []
    for batches in rec.values():
        for b in batches:
            for name in b.schema.names:
                if name.endswith(":text"):
                    out += [str(x) for x in b.column(name).to_pylist()]
    return "\n".join(out)


def log(tmp, *extra):
    from geoloc.cli import main

    out = tmp / "run.rrd"
    assert (
        main(
            [
                "log",
                str(RECORDS),
                "--group-by",
                "none",
                "--dem",
                str(DEM),
                "--method",
                "bisect",
                "--threshold",
                "1",
                "--no-calibration",
                "--out",
                str(out),
                *extra,
            ]
        )
        == 0
    )
    return read(out)


def test_refraction_series_is_the_pipelines(tmp_path, rerun_home):
    from geoloc.io.records import load_records
    from geoloc.pipeline import Corrections, Pipeline
    from geoloc.sensors.sensor_file import load_sensor
    from geoloc.surfaces.spec import SurfaceSpec

    rec = log(tmp_path, "--refraction", "standard")
    assert "/series/refraction_m" in rec, sorted(k for k in rec if "series" in k)
    k, got = series(rec["/series/refraction_m"])
    # the core's figures: its pipeline on the same DEM surface (bisection, 1 m), the bundled camera
    sensor = load_sensor(ROOT / "assets" / "cameras" / "qiao2017.toml")
    recs = load_records(RECORDS, angles=sensor.angle_names)
    surface = SurfaceSpec(dem=str(DEM), dem_datum="egm96", method="bisect", threshold=1.0).build()
    want = (
        Pipeline(sensor, surface, Corrections.for_sensor(sensor, "standard"))
        .locate(recs.column("row"), recs.column("col"), recs.pose(), outside="extrapolate")
        .refraction_m
    )
    assert list(k) == list(range(len(recs)))
    # logged as float64 scalars, read back exactly: the same computation, so 1e-9 m
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert np.all((got > 0.1) & (got < 10.0))  # metres of shift from 18 km (docs/refraction.md: 1.2-2.6 m)
    # the first record by the CLI (geoloc locate, its own path from the command line)
    r = next(iter(recs.rows))
    argv = [
        sys.executable,
        "-m",
        "geoloc",
        "locate",
        "--lat-deg",
        r["ac_lat_deg"],
        "--lon-deg",
        r["ac_lon_deg"],
        "--h-m",
        r["ac_h_m"],
        "--heading-deg",
        r["heading_deg"],
        "--pitch-deg",
        r["pitch_deg"],
        "--roll-deg",
        r["roll_deg"],
        "--gimbal-roll-deg",
        r["gimbal_roll_deg"],
        "--gimbal-pitch-deg",
        r["gimbal_pitch_deg"],
        "--row",
        r["row"],
        "--col",
        r["col"],
        "--dem",
        str(DEM),
        "--method",
        "bisect",
        "--threshold",
        "1",
        "--refraction",
        "standard",
        "--json",
    ]
    cli = json.loads(
        subprocess.run([str(a) for a in argv], capture_output=True, text=True, check=True, timeout=300).stdout
    )
    assert abs(got[0] - cli["refraction_m"]) < 1e-6  # the same pipeline by another path: micrometres
    notes = texts(rec)
    assert "line-of-sight corrections (docs/refraction.md): refraction (U.S. Standard Atmosphere 1976)" in notes


def test_no_refraction_no_series(tmp_path, rerun_home):
    rec = log(tmp_path)
    assert not any(k.endswith("refraction_m") for k in rec)
    assert "line-of-sight corrections" not in texts(rec)
