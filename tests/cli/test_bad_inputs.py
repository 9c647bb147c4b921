"""The second bad-input catalogue: each case pinned by a test that failed before
it was mended (the KLV cases and ``view --export`` have their own tests elsewhere).

Exit codes, ``--out`` rules, interrupts, broken pipes and progress: docs/cli.md.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import asset_path
from geoloc.cli import main

ROOT = Path(__file__).resolve().parents[2]
GEOLOC = [sys.executable, "-m", "geoloc"]
SCEN = asset_path("scenarios", "qiao2017_table1.toml")
SRTM = asset_path("dem", "srtm_jacksboro.tif")
ETOPO = asset_path("dem", "etopo5_flight_area.tif")
TURRET = asset_path("sensors", "eo_turret.toml")
TURRET_CSV = asset_path("records", "eo_turret_flight.csv")


# ------------------------------------------------------------------ rpc of a scenario of another kind
def test_rpc_of_a_montecarlo_scenario_is_one_clear_line(tmp_path, capsys):
    # before: AttributeError: 'ErrorModel' object has no attribute 'dem_path' (a traceback)
    out = tmp_path / "x.tif"
    assert main(["rpc", str(SCEN), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "montecarlo" in err and "'pushbroom' or 'frame'" in err, err
    assert not out.exists()


# ------------------------------------------------------------------ Ctrl-C and a closed pipe
#: Runs geoloc in a child whose first write of an output file, half done, is hit by a real SIGINT
#: (sent by the process to itself: no timing, the handler runs as soon as os.kill returns).
_INTERRUPTED_WRITE = """
import os, pathlib, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal (a background job ignores SIGINT)
real = pathlib.Path.write_text
def half_then_ctrl_c(self, data, *a, **k):
    real(self, data[: len(data) // 2], *a, **k)
    os.kill(os.getpid(), signal.SIGINT)
    return real(self, data, *a, **k)
pathlib.Path.write_text = half_then_ctrl_c
from geoloc.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_is_one_line_exit_130_and_leaves_no_partial_file(tmp_path):
    # before: a KeyboardInterrupt traceback, killed by SIGINT (return code -2)
    out = tmp_path / "stats.json"
    out.write_text("the old statistics\n")
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            _INTERRUPTED_WRITE,
            "montecarlo",
            str(SCEN),
            "--samples",
            "20",
            "--seed",
            "0",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert p.returncode == 130, p.stderr
    assert p.stderr.strip().splitlines() == ["geoloc montecarlo: interrupted (Ctrl-C)"], p.stderr
    assert sorted(x.name for x in tmp_path.iterdir()) == ["stats.json"]  # no temporary file left
    assert out.read_text() == "the old statistics\n"  # the earlier output whole


def test_a_closed_pipe_ends_quietly_with_141():
    # before: "BrokenPipeError: [Errno 32] Broken pipe" traceback(s) and exit 1 (or 120 at the last flush)
    r, w = os.pipe()
    os.close(r)  # the reader is gone before the first line: `geoloc klv dump ... | head -0`
    try:
        p = subprocess.run(
            GEOLOC + ["klv", "dump", str(asset_path("klv", "example_flight.klv"))],
            stdout=w,
            stderr=subprocess.PIPE,
            text=True,
            timeout=300,
        )
    finally:
        os.close(w)
    assert p.returncode == 141 and p.stderr == "", p.stderr


def test_a_closed_pipe_after_the_first_line_ends_quietly():
    # `geoloc replay ... | head -1`: the reader takes one line and goes
    p = subprocess.Popen(
        GEOLOC + ["replay", "--height-column", "paper_height_m", "--print-rows"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = p.stdout.readline()
    p.stdout.close()
    err = p.stderr.read()
    rc = p.wait(timeout=300)
    assert first.startswith("record") and rc in (0, 141) and "Traceback" not in err and "Broken" not in err, err


# ------------------------------------------------------------------ help texts
def _parsers():
    import argparse

    from geoloc.cli import build_parser

    todo, out = [("geoloc", build_parser())], []
    while todo:
        name, p = todo.pop()
        out.append((name, p))
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {k}", q) for k, q in a.choices.items()]
    return out


def test_no_help_text_shows_a_doubled_percent_sign():
    # before: `geoloc montecarlo --help` printed "the empirical 50 %% radius" (a description is not %-formatted)
    shown = {name: p.format_help() for name, p in _parsers()}
    assert len(shown) > 15
    assert [name for name, text in shown.items() if "%%" in text] == []


def test_geoloc_help_names_every_action_of_a_verb_that_has_actions():
    # before: `geoloc --help` said "klv ... dump the decoded packets" only (fix and send were not named)
    import argparse

    from geoloc.cli import build_parser

    top = build_parser()
    verbs = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in verbs._choices_actions}
    checked = 0
    for verb, p in verbs.choices.items():
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                missing = [k for k in a.choices if k not in helps[verb]]
                assert missing == [], f"geoloc --help, {verb}: {helps[verb]!r} does not name {missing}"
                checked += 1
    assert checked >= 1  # klv


# ------------------------------------------------------------------ --out -: standard output for text
def test_out_dash_is_standard_output_for_a_csv_and_the_messages_go_to_stderr(tmp_path, capsys, monkeypatch):
    # before: a file named "-" was written, and the summary went to stdout
    monkeypatch.chdir(tmp_path)
    assert main(["replay", "--height-column", "paper_height_m", "--out", "-"]) == 0
    out, err = capsys.readouterr()
    rows = list(csv.DictReader(out.splitlines()))
    assert (
        len(rows) == 20 and rows[0]["table"] == "T3" and float(rows[0]["lat_deg"]) == pytest.approx(36.3377, abs=1e-4)
    )
    assert "group T3" in err and "wrote 20 rows to -" in err
    assert list(tmp_path.iterdir()) == []


def test_out_dash_with_export_still_writes_the_gis_file(tmp_path, capsys, monkeypatch):
    # --export re-read the --out CSV: with --out - it tried to read a file named "-"
    monkeypatch.chdir(tmp_path)
    assert main(["replay", "--height-column", "paper_height_m", "--out", "-", "--export", "r.kml"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 21 and (tmp_path / "r.kml").read_text().count("<Placemark") >= 20
    assert sorted(x.name for x in tmp_path.iterdir()) == ["r.kml"]


def test_out_dash_for_a_json_output(tmp_path, capsys, monkeypatch):
    import json

    monkeypatch.chdir(tmp_path)
    assert main(["montecarlo", str(SCEN), "--samples", "50", "--seed", "0", "--out", "-"]) == 0
    out = capsys.readouterr().out
    assert abs(json.loads(out)["mean_lat_deg"] - 35.57709) < 0.001  # [Q17] Table 2: the target at 35.57709 N
    assert list(tmp_path.iterdir()) == []


def test_out_dash_for_a_binary_output_is_one_line(tmp_path, capsys):
    assert main(["ortho", "--record", "T3-1", "--out", "-"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "standard output is for text outputs" in err, err


# ------------------------------------------------------------------ geoloc export
@pytest.fixture(scope="module")
def results_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("results")
    out = d / "r.csv"
    assert main(["replay", "--height-column", "paper_height_m", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize(
    "content, needle",
    [(b"", "empty (no header line, no rows)"), (b"table,point,lat_deg,lon_deg\n", "a header and no rows")],
)
def test_export_of_an_empty_csv_is_one_line(tmp_path, capsys, content, needle):
    # before: a 0-byte CSV made a GeoPackage of seven empty layers, exit 0
    src, out = tmp_path / "empty.csv", tmp_path / "out.gpkg"
    src.write_bytes(content)
    assert main(["export", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and str(src) in err, err
    assert not out.exists()


def test_export_takes_its_output_as_the_readme_writes_it(results_csv, tmp_path, capsys):
    # docs/tour_accuracy.md (the README's before it became one screen): `geoloc export r.csv out.gpkg`
    # (before: "unrecognized arguments: out.gpkg")
    page = (ROOT / "docs" / "tour_accuracy.md").read_text()
    assert "geoloc export r.csv out.gpkg" in page
    out = tmp_path / "out.gpkg"
    assert main(["export", str(results_csv), str(out)]) == 0
    from pyogrio import raw

    assert len(raw.read(str(out), layer="points")[2]) == 20  # the 20 records of [Q17] Tables 3-4
    assert main(["export", str(results_csv), str(tmp_path / "a.kml"), "--out", str(tmp_path / "b.kml")]) == 2
    assert "two outputs given" in capsys.readouterr().err


def test_export_to_standard_output(results_csv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # (before: a file named "-" was written here)
    assert main(["export", str(results_csv), "--out", "-", "--format", "kml"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("<?xml") and out.count("<Placemark") >= 20 and "wrote kml" in err
    for fmt, needle in ((None, "give --format"), ("gpkg", "is a binary file"), ("geojson", "one file per layer")):
        argv = ["export", str(results_csv), "--out", "-"] + (["--format", fmt] if fmt else [])
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err


# ------------------------------------------------------------------ replay --group-by
def test_replay_group_by_a_missing_column_names_the_columns(capsys):
    # before: one group "all", exit 0
    assert main(["replay", "--height-column", "paper_height_m", "--group-by", "NO_SUCH_COLUMN"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'NO_SUCH_COLUMN': no such column" in err, err
    assert "table, point, row, col, ac_lat_deg" in err  # the bundled [Q17] records' header


def test_replay_group_by_a_column_that_is_there(capsys):
    assert main(["replay", "--height-column", "paper_height_m", "--group-by", "point"]) == 0
    out = capsys.readouterr().out
    assert "group 1: n=2" in out and "group 10: n=2" in out  # T3-k and T4-k share point k


# ------------------------------------------------------------------ every iteration bounded
def _ramp_and_nadir_ray():
    from geoloc.frames.enu import EnuFrame
    from geoloc.surfaces.base import LineOfSight
    from geoloc.surfaces.dem import DEM

    # 1000 m of relief: a west-east ramp 0..1000 m over 0.2 deg, the aircraft at 2000 m over its middle
    dem = DEM.from_array(np.tile(np.linspace(0.0, 1000.0, 21), (21, 1)), 36.1, 78.0, 0.01, 0.01)
    frame = EnuFrame(np.deg2rad(36.0), np.deg2rad(78.1), 2000.0)
    o = frame.to_ecef(np.zeros(3))
    d = frame.R_ecef_enu @ np.array([0.0, 0.0, -1.0])  # straight down: meets the ramp at 500 m
    return dem, LineOfSight(o[None], d[None], np.zeros(1, np.uint8))


def test_the_descending_steps_stop_at_their_bound_with_no_convergence(monkeypatch):
    # before: eps_h = 1e-7 over 1000 m of relief is 1e10 steps (hours: `locate --eps-h 1e-7` hung)
    import geoloc.surfaces.terrain as terrain
    from geoloc.status import Status

    assert terrain.STEPS_MAX >= 19_784  # the Earth's relief (-10 935 m .. 8 849 m) at the default 1 m step
    monkeypatch.setattr(terrain, "STEPS_MAX", 600)  # the bound, whatever its value, turns into a status
    dem, los = _ramp_and_nadir_ray()
    hit = terrain.intersect_dem(los, dem, "steps", eps_h=1e-7)
    assert hit.status.tolist() == [Status.NO_CONVERGENCE] and np.isnan(hit.lat).all()
    assert hit.dem_evaluations.tolist() == [600]
    ok = terrain.intersect_dem(los, dem, "steps", eps_h=1.0)  # 500 steps from the top, 1000 m: under 600
    assert ok.status.tolist() == [Status.OK] and abs(float(ok.h[0]) - 500.0) < 1.5  # ramp's middle; 1 m steps


# ------------------------------------------------------------------ an aircraft below the terrain
@pytest.mark.parametrize("method", ["exact", "steps", "bisect"])
@pytest.mark.parametrize("down", [True, False])
def test_a_camera_below_the_terrain_gets_its_own_status(method, down):
    # before: status ok and slant range 0 m (the walk met the terrain at the camera)
    from geoloc.frames.enu import EnuFrame
    from geoloc.status import Status, describe
    from geoloc.surfaces.base import LineOfSight
    from geoloc.surfaces.terrain import intersect_dem

    dem, _ = _ramp_and_nadir_ray()  # the ramp is 500 m high at 78.1 E
    frame = EnuFrame(np.deg2rad(36.0), np.deg2rad(78.1), 100.0)  # 400 m under it
    o = frame.to_ecef(np.zeros(3))
    d = frame.R_ecef_enu @ np.array([0.6, 0.0, -0.8 if down else 0.8])
    hit = intersect_dem(LineOfSight(o[None], d[None], np.zeros(1, np.uint8)), dem, method)
    assert hit.status.tolist() == [Status.BELOW_TERRAIN] and np.isnan(hit.slant_range).all()
    assert "below the terrain" in describe(Status.BELOW_TERRAIN)
    frame_above = EnuFrame(np.deg2rad(36.0), np.deg2rad(78.1), 600.0)  # 100 m above it: a hit, not this status
    hit = intersect_dem(
        LineOfSight(frame_above.to_ecef(np.zeros(3))[None], d[None] * (1 if down else -1), np.zeros(1, np.uint8)),
        dem,
        method,
    )
    assert hit.status.tolist() == [Status.OK] and hit.slant_range[0] > 50.0


@pytest.mark.parametrize("mosaic", [False, True])
def test_locate_below_the_terrain_says_so(mosaic, tmp_path, capsys):
    import shutil

    dem = SRTM
    if mosaic:  # a folder of tiles: a DemMosaic
        (tmp_path / "tiles").mkdir()
        shutil.copy(SRTM, tmp_path / "tiles" / "a.tif")
        dem = tmp_path / "tiles"
    # the README's turret at 100 m (ellipsoidal): the SRTM terrain there is about 370 m
    rc = main(
        [
            "locate",
            "--sensor",
            str(TURRET),
            "--lat-deg",
            "36.6",
            "--lon-deg",
            "-84.25",
            "--h-m",
            "100",
            "--angle",
            "azimuth=90",
            "--angle",
            "elevation=-30",
            "--dem",
            str(dem),
            "--json",
        ]
    )
    import json

    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["status"] == "below_terrain" and "camera is below the terrain" in out["error"], out
    assert "slant_range_m" not in out


# ------------------------------------------------------------------ what a replay could not locate
def test_replay_summary_says_which_records_were_not_located_and_exits_1(capsys):
    # the turret's flight (Tennessee) over the ETOPO5 crop of [Q17]'s area (Tibet): no record can be
    # located. Before: 24 rows of left_dem, a summary "group orbit1: n=24", no word, exit 0
    rc = main(["replay", str(TURRET_CSV), "--sensor", str(TURRET), "--dem", str(ETOPO)])
    out, err = capsys.readouterr()
    assert rc == 1
    assert "group orbit1: n=24; 24 not located" in out
    assert "not located: 24 of 24 records: 24 left_dem (line of sight left the DEM before meeting the terrain)" in out
    # the DEM's bounds against the data's: ETOPO5 crop 76-83 E, 34-38 N; the flight near 84.25 W, 36.6 N
    line = next(ln for ln in err.splitlines() if "does not cover" in ln)
    assert "24 of 24 aircraft positions are outside it and 24 lines of sight left it" in line
    assert "DEM W 75.9583 S 33.9583 E 83.0417 N 38.0417 deg" in line
    assert "aircraft W -84.33" in line and "N 36.66" in line


def test_replay_where_every_record_is_located_exits_0_without_those_words(capsys):
    assert main(["replay", str(TURRET_CSV), "--sensor", str(TURRET), "--dem", str(SRTM)]) == 0
    out, err = capsys.readouterr()
    assert "not located" not in out and "does not cover" not in err


# ------------------------------------------------------------------ progress of a long Monte Carlo
def test_montecarlo_prints_a_progress_line_every_10_s_in_a_log(monkeypatch, capsys):
    # before: 1e7 samples with --chunk 10 ran 36 minutes without a word when stderr was not a terminal.
    # The clock is a fake one that advances 3 s at each reading (no timed test): 20 chunks, 10 s apart
    # at most three chunks -> a line every 4 readings (12 s), the first after 10 s.
    import geoloc.progress as progress

    t = iter(range(0, 10_000, 3))
    monkeypatch.setattr(progress, "_now", lambda: float(next(t)))
    assert main(["montecarlo", str(SCEN), "--samples", "2000", "--chunk", "100", "--seed", "0"]) == 0
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.startswith("montecarlo qiao2017_table1: ")]
    assert len(lines) == 5 and "\r" not in err, err  # readings at 3, 6, ..., 60 s: lines at 12, 24, 36, 48, 60
    assert lines[0] == "montecarlo qiao2017_table1: 400/2000 (20.0%), 12s elapsed, 48s left"
    assert lines[-1].startswith("montecarlo qiao2017_table1: 2000/2000 (100.0%)")
    assert "elapsed" not in out


def test_progress_is_a_bar_on_a_terminal_and_nothing_when_refused():
    import io

    import geoloc.progress as progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty = Tty()
    bar = progress.Progress(4, "x", stream=tty)
    bar.update(2)
    bar.close()
    assert tty.getvalue().startswith("\rx [###############               ]  50.0% 2/4")
    quiet = io.StringIO()
    bar = progress.Progress(4, "x", enabled=False, stream=quiet)
    bar.update(4)
    bar.close()
    assert quiet.getvalue() == ""


# ------------------------------------------------------------------ arguments checked before the work
@pytest.mark.parametrize(
    "crs, needle",
    [
        ("EPSG:99999", "not a CRS that pyproj knows"),
        ("EPSG:4269", "is not a projected CRS"),  # NAD83: degrees
        ("EPSG:2227", "not metres"),
    ],
)  # California 3: US feet
def test_ortho_crs_is_checked_before_any_pixel_is_located(crs, needle, tmp_path, capsys, monkeypatch):
    # before: `--ortho-crs EPSG:99999` raised a CRSError traceback after the whole frame was located
    import geoloc.workflows.ortho as wo

    def no_work(*a, **k):
        raise AssertionError("geoloc ortho located the frame before checking --ortho-crs")

    monkeypatch.setattr(wo, "write_frame_geotiff", no_work)
    out, ortho = tmp_path / "grid.tif", tmp_path / "ortho.tif"
    rc = main(
        [
            "ortho",
            "--photo",
            str(asset_path("photos", "DJI_0001.JPG")),
            "--dem",
            str(SRTM),
            "--out",
            str(out),
            "--ortho-out",
            str(ortho),
            "--gsd-m",
            "5",
            "--ortho-crs",
            crs,
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and f"--ortho-crs '{crs}'" in err and needle in err, err
    assert not out.exists() and not ortho.exists()


def test_check_crs_takes_the_words_and_projected_crs_in_metres():
    from geoloc.cli._options import check_crs

    for ok in ("geographic", "utm", "EPSG:32617", "+proj=utm +zone=17 +datum=WGS84 +units=m"):
        assert check_crs("--x", ok) == ok


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["replay", "--dem", str(ETOPO), "--export", "{tmp}/x.shp"], "--export {tmp}/x.shp: cannot tell the format"),
        (
            ["rpc", str(asset_path("scenarios", "zy3_nadir.toml")), "--out", "{tmp}/z.png", "--no-gdal"],
            "--out {tmp}/z.png: must be a GeoTIFF",
        ),
        (
            [
                "ortho",
                "--record",
                "T3-1",
                "--out",
                "{tmp}/grid.tif",
                "--photo",
                str(asset_path("photos", "DJI_0001.JPG")),
                "--ortho-out",
                "{tmp}/o.png",
                "--gsd-m",
                "5",
            ],
            "--ortho-out {tmp}/o.png: must be a GeoTIFF",
        ),
    ],
)
def test_an_output_format_is_checked_before_the_work(argv, needle, tmp_path, capsys, monkeypatch):
    # before: replay located every record, then refused x.shp; rpc wrote a GeoTIFF named z.png (exit 0)
    import geoloc.cli.replay as cr
    import geoloc.workflows.ortho as wo
    import geoloc.workflows.rpc_scenario as wrpc

    def no_work(*a, **k):
        raise AssertionError("the verb computed before checking its output's format")

    for mod, name in ((cr, "replay_records"), (wrpc, "rpc_report"), (wo, "write_frame_geotiff")):
        monkeypatch.setattr(mod, name, no_work)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and needle.replace("{tmp}", str(tmp_path)) in err, err
    assert list(tmp_path.iterdir()) == []
