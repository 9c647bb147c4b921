"""`geoloc log FILE.klv`: the replay's residuals as rerun time series, read back with rerun's reader."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from geoloc.assets import ASSETS
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.klv_replay import replay_klv

KLV = Path(ASSETS) / "klv" / "example_flight.klv"


def series(path, entity):
    """(packet, value) of a scalar series, sorted by packet."""
    from rerun.chunk import RrdReader

    pk, val = [], []
    for ch in RrdReader(path).stream():
        if ch.entity_path != entity:
            continue
        b = ch.to_record_batch()
        if "packet" not in b.schema.names:
            continue
        pk += b.column("packet").to_pylist()
        val += [r[0] for r in b.column("Scalars:scalars").to_pylist()]
    order = np.argsort(pk)
    return np.asarray(pk)[order], np.asarray(val, float)[order]


def test_klv_log_series_are_the_replay_residuals(tmp_path, rerun_home):
    out = tmp_path / "klv.rrd"
    r = subprocess.run(
        [sys.executable, "-m", "geoloc", "log", str(KLV), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "skipped bad packet at byte 32400" in r.stderr and "299 steps" in r.stdout
    # no --dem: the bundled SRTM crop covering the flight (the DEM `geoloc view` draws), exact walk
    from geoloc.surfaces.spec import SurfaceSpec

    srtm = Path(ASSETS) / "dem" / "srtm_jacksboro.tif"
    assert f"DEM {srtm}" in r.stderr
    rep = replay_klv(KLV, surface=SurfaceSpec(dem=srtm, method="exact").build()).columns
    pk, err = series(out, "/series/error/to_published_m")
    want = dict(zip(rep["packet"], rep["frame_center_error_m"]))
    ok = np.isfinite([want[p] for p in pk])
    # float64 series, written as computed: exactly the replay's frame-centre residuals
    np.testing.assert_array_equal(err[ok], np.asarray([want[p] for p in pk])[ok])
    pk2, flag = series(out, "/series/klv/outlier")
    flagged = set(pk2[flag > 0.5].tolist())
    assert flagged == set(np.asarray(rep["packet"])[np.asarray(rep["outlier"]).astype(bool)].tolist())
    assert {100, 109, 200, 204, 250, 256} <= flagged and 150 not in pk2  # the planted faults; the bad packet


def test_klv_log_honours_the_dem_method(tmp_path, rerun_home):
    # `geoloc log FILE.klv --dem D --method steps` replays with that solver, as the records path
    # does: the series are replay_klv's with method="steps", not the default exact walk's
    from geoloc.surfaces.dem import DEM

    dem_path = Path(ASSETS) / "dem" / "srtm_jacksboro.tif"
    out = tmp_path / "klv_steps.rrd"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "geoloc",
            "log",
            str(KLV),
            "--dem",
            str(dem_path),
            "--method",
            "steps",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    dem = DEM.open(dem_path, datum="egm96")
    steps = replay_klv(KLV, surface=surface_for(dem=dem, method="steps")).columns
    exact = replay_klv(KLV, surface=surface_for(dem=dem, method="exact")).columns
    pk, err = series(out, "/series/error/to_published_m")
    want = dict(zip(steps["packet"], steps["frame_center_error_m"]))
    other = dict(zip(exact["packet"], exact["frame_center_error_m"]))
    w = np.asarray([want[p] for p in pk])
    o = np.asarray([other[p] for p in pk])
    ok = np.isfinite(w)
    np.testing.assert_array_equal(err[ok], w[ok])
    # the two solvers differ somewhere on this flight, so the equality above tells them apart
    assert np.nanmax(np.abs(w - o)) > 1e-6
