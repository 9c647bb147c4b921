"""Heights and conventions audited from the data (geoloc.analysis.height_audit).

Each fault signature is planted at a known size in a bundled flight (the EO turret orbit over the
Jacksboro SRTM crop, the KLV example flight) and the audit must name it, with an estimate within
its own stated uncertainty of the planted size; the clean flight gets no finding. The planted
geoid sizes are EGM96 N from outside geoloc (pyproj's grid when it has one, else the bundled
15' crop read here with rasterio and interpolated by this test); a take-off height is the DEM's.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from geoloc.analysis.height_audit import FAULTS, audit_flight, audit_klv_columns, audit_records
from geoloc.cli import main
from geoloc.io.records import load_records
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces import dem as dem_module
from geoloc.surfaces.height import HeightSurface
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.surfaces.terrain import surface_for

ROOT = Path(__file__).resolve().parents[2]
SENSOR = ROOT / "assets" / "sensors" / "eo_turret.toml"
RECORDS = ROOT / "assets" / "records" / "eo_turret_flight.csv"
DEM = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"
KLV = ROOT / "assets" / "klv" / "example_flight.klv"
QIAO = ROOT / "assets" / "records" / "qiao2017_flight_tests.csv"  # the bundled copy of [Q17]'s tables
ETOPO = ROOT / "assets" / "dem" / "etopo5_flight_area.tif"


def reference_undulation(lat_deg, lon_deg):
    """EGM96 N [m] not from geoloc: pyproj (refusing its ballpark N = 0), else the bundled
    Jacksboro 15' crop read with rasterio, bilinear between its pixel-centre nodes here."""
    from pyproj import Transformer

    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    t = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    if "ballpark" not in t.description.lower():
        return -np.asarray(t.transform(lon, lat, np.zeros_like(lat))[2], float)
    import rasterio

    with rasterio.open(ROOT / "assets" / "geoid" / "egm96_jacksboro.tif") as src:
        z, tr = src.read(1).astype(float), src.transform
    r = (lat - (tr.f + tr.e / 2)) / tr.e
    c = (lon - (tr.c + tr.a / 2)) / tr.a
    i, j = np.floor(r).astype(int), np.floor(c).astype(int)
    v, u = r - i, c - j
    return (1 - u) * (1 - v) * z[i, j] + u * (1 - v) * z[i, j + 1] + (1 - u) * v * z[i + 1, j] + u * v * z[i + 1, j + 1]


@pytest.fixture(scope="module")
def flight():
    """The EO turret orbit, its DEM, and clean reported centres: each record's pixel located on the
    DEM from its own pose (what a correct encoder reports)."""
    sensor = load_sensor(SENSOR)
    records = load_records(RECORDS, angles=sensor.angle_names)
    surface = SurfaceSpec(dem=str(DEM)).build()
    pose = records.pose()
    row, col = records.column("row"), records.column("col")
    g = surface.intersect(sensor.line_of_sight(row, col, pose))
    assert np.all(g.status == 0)
    n_ref = reference_undulation(np.rad2deg(pose.lat), np.rad2deg(pose.lon))
    return dict(
        sensor=sensor,
        records=records,
        surface=surface,
        pose=pose,
        row=row,
        col=col,
        lat=np.rad2deg(g.lat),
        lon=np.rad2deg(g.lon),
        h=np.asarray(g.h),
        n=n_ref,
    )


def _audit(f, pose=None, lat=None, lon=None, h=None, sensor=None):
    return audit_flight(
        f["pose"] if pose is None else pose,
        f["sensor"] if sensor is None else sensor,
        f["row"],
        f["col"],
        f["surface"],
        f["lat"] if lat is None else lat,
        f["lon"] if lon is None else lon,
        f["h"] if h is None else h,
        source="test",
    )


def _one(audit, kind):
    assert audit.kinds() == [kind], audit.lines()
    return audit.findings[0]


def test_a_clean_flight_has_no_finding(flight):
    a = _audit(flight)
    assert a.findings == [], a.lines()
    assert "no convention fault found" in a.lines()[0]


# (kind, the planted platform height offset h_read - h_true [m] as a function of the flight)
PLATFORM_FAULTS = {
    "msl_read_as_ellipsoidal": lambda f: -f["n"],  # the file's H = h - N read as h
    "ellipsoidal_read_as_msl": lambda f: f["n"],  # h read as H, N added: h + N
    "geoid_wrong_sign": lambda f: -2 * f["n"],  # h = H - N: h - 2N
    # a height above the take-off point (the terrain under the first record) read as absolute
    "relative_height_read_as_absolute": lambda f: (
        -np.full(len(f["n"]), float(f["surface"].dem.height(f["pose"].lat[0], f["pose"].lon[0])))
    ),
}


@pytest.mark.parametrize("kind", sorted(PLATFORM_FAULTS))
def test_a_planted_platform_height_fault_is_named_with_its_size(flight, kind):
    planted = PLATFORM_FAULTS[kind](flight)
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h + planted)
    f = _one(_audit(flight, pose=pose), kind)
    assert f.subject == "platform height"
    # the estimate within its own stated uncertainty of the planted (median) size; N varies by
    # 0.3 m along the orbit, inside the 0.5 m floor
    assert abs(f.offset - np.median(planted)) <= f.uncertainty, f.line()
    assert f.misfit_after_m < f.misfit_before_m / 3, f.line()


def test_agl_read_as_absolute_is_named(flight):
    ground = flight["surface"].dem.height(flight["pose"].lat, flight["pose"].lon)
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h - ground)
    f = _one(_audit(flight, pose=pose), "agl_read_as_absolute")
    assert abs(f.offset - np.median(-ground)) <= f.uncertainty, f.line()
    assert f.misfit_after_m < 1.0, f.line()  # the terrain added back record by record: the DEM solver's 1 m


def test_flat_earth_frame_centres_are_named(flight):
    g0 = HeightSurface(0.0, "geodetic").intersect(
        flight["sensor"].line_of_sight(flight["row"], flight["col"], flight["pose"])
    )
    a = _audit(flight, lat=np.rad2deg(g0.lat), lon=np.rad2deg(g0.lon), h=np.zeros(len(flight["row"])))
    f = _one(a, "flat_earth_frame_centre")
    assert abs(f.offset - 0.0) <= f.uncertainty, f.line()  # the rays meet them at h = 0, planted
    assert f.misfit_after_m < 0.5 < 100 < f.misfit_before_m, f.line()


@pytest.mark.parametrize("terrain_m, named", [(5.0, True), (4.99, False)])
def test_flat_earth_centres_over_terrain_of_five_metres_are_named_and_under_it_not(flight, terrain_m, named):
    # docs/height_audit.md: offsets under 5 m are not named (a DEM's own vertical error explains
    # them), so terrain of 5 m itself is. A flat DEM at exactly that height (5.0 and its bilinear
    # mixtures are exact in binary) under the whole orbit; the reported centres where the rays
    # meet it, their heights -0.25 m (within the 0.5 m floor of h = 0): 5.25 m below the DEM
    lat = np.r_[np.rad2deg(flight["pose"].lat), flight["lat"]]
    lon = np.r_[np.rad2deg(flight["pose"].lon), flight["lon"]]
    north, west = lat.max() + 0.1, lon.min() - 0.1
    dem = dem_module.DEM.from_array(
        np.full((3, 3), terrain_m), north, west, (north - lat.min() + 0.1) / 2, (lon.max() + 0.1 - west) / 2
    )
    los = flight["sensor"].line_of_sight(flight["row"], flight["col"], flight["pose"])
    g = HeightSurface(terrain_m, "geodetic").intersect(los)
    a = audit_flight(
        flight["pose"],
        flight["sensor"],
        flight["row"],
        flight["col"],
        surface_for(dem=dem),
        np.rad2deg(g.lat),
        np.rad2deg(g.lon),
        np.full(len(flight["row"]), -0.25),
        source="test",
    )
    assert ("flat_earth_frame_centre" in a.kinds()) is named, a.lines()


def test_frame_centre_heights_in_msl_are_named(flight):
    n_fc = reference_undulation(flight["lat"], flight["lon"])
    f = _one(_audit(flight, h=flight["h"] - n_fc), "msl_read_as_ellipsoidal")
    assert f.subject == "frame-centre height"
    assert abs(f.offset - np.median(-n_fc)) <= f.uncertainty, f.line()


@pytest.mark.parametrize("k", [3, -3])
def test_a_time_offset_is_named_in_records(flight, k):
    # record j reports the centre of record j + k: late by k records, or early (k < 0)
    pad = np.full(abs(k), np.nan)

    def shifted(v):
        return np.r_[v[k:], pad] if k > 0 else np.r_[pad, v[:k]]

    f = _one(
        _audit(flight, lat=shifted(flight["lat"]), lon=shifted(flight["lon"]), h=shifted(flight["h"])), "time_offset"
    )
    assert abs(f.offset - k) <= f.uncertainty and f.unit == "records", f.line()


def test_a_boresight_bias_is_named_in_mrad(flight):
    planted = 5e-3  # rad, about the turret's boresight y
    s = flight["sensor"]
    biased = s.with_params(boresight_y=s.params["boresight_y"] + planted)
    g = flight["surface"].intersect(biased.line_of_sight(flight["row"], flight["col"], flight["pose"]))
    f = _one(_audit(flight, lat=np.rad2deg(g.lat), lon=np.rad2deg(g.lon), h=g.h), "boresight_bias")
    assert abs(f.offset - planted * 1e3) <= f.uncertainty, f.line()


def test_noisy_surveyed_truth_still_names_the_datum(flight):
    """The file's own surveyed truth (20 m of pointing noise) as the reference: a datum fault is
    still named, and corrected as a height, not as a boresight (the tie rule)."""
    r = flight["records"]
    for kind, planted in (("msl_read_as_ellipsoidal", -flight["n"]), ("ellipsoidal_read_as_msl", flight["n"])):
        pose = dataclasses.replace(flight["pose"], h=flight["pose"].h + planted)
        f = _one(
            _audit(
                flight, pose=pose, lat=r.column("truth_lat_deg"), lon=r.column("truth_lon_deg"), h=r.column("truth_h_m")
            ),
            kind,
        )
        assert abs(f.offset - np.median(planted)) <= f.uncertainty, f.line()
    clean = _audit(flight, lat=r.column("truth_lat_deg"), lon=r.column("truth_lon_deg"), h=r.column("truth_h_m"))
    assert clean.findings == [], clean.lines()


def test_the_findings_are_data(flight):
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h - flight["n"])
    d = _audit(flight, pose=pose).to_dict()
    import json

    back = json.loads(json.dumps(d))
    assert [x["kind"] for x in back["findings"]] == ["msl_read_as_ellipsoidal"]
    assert set(back["findings"][0]) >= {"offset", "uncertainty", "unit", "expected", "fix", "text"}
    assert set(FAULTS) >= {x["kind"] for x in back["findings"]}


def test_the_audit_needs_a_dem(flight):
    with pytest.raises(ValueError, match="needs a DEM"):
        audit_flight(
            flight["pose"],
            flight["sensor"],
            flight["row"],
            flight["col"],
            HeightSurface(0.0),
            flight["lat"],
            flight["lon"],
        )


def _write_records(path, records, ac_h_m, lat, lon, h):
    """The records file with its aircraft heights and its truth replaced."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        cols = [c for c in records.source_header]
        w.writerow(cols)
        for k, row in enumerate(records.rows):
            out = dict(
                row,
                ac_h_m=repr(float(ac_h_m[k])),
                truth_lat_deg=repr(float(lat[k])),
                truth_lon_deg=repr(float(lon[k])),
                truth_h_m=repr(float(h[k])),
            )
            w.writerow([out[c] for c in cols])


def test_replay_prints_the_finding_and_the_fix_makes_it_go(flight, tmp_path, capsys):
    """End to end: a records file whose heights are MSL; `geoloc replay --dem --audit` names it and
    its fix; with that fix (--altitude-datum egm96) the misfit shrinks and nothing is named."""
    p = tmp_path / "msl.csv"
    _write_records(p, flight["records"], flight["pose"].h - flight["n"], flight["lat"], flight["lon"], flight["h"])
    base = ["replay", str(p), "--sensor", str(SENSOR), "--dem", str(DEM), "--audit"]
    assert main(base) == 0
    out = capsys.readouterr().out
    lines = [x for x in out.splitlines() if "read as ellipsoidal" in x and "platform height" in x]
    assert len(lines) == 1 and "fix: --altitude-datum egm96" in lines[0], out[-2000:]
    assert main(base + ["--altitude-datum", "egm96"]) == 0
    fixed = capsys.readouterr().out
    head = next(x for x in fixed.splitlines() if x.startswith("height audit"))
    assert head.endswith("no convention fault found"), head
    # the replay's own error to the (clean) centres shrinks from tens of metres to the DEM solver's tolerance
    before = float(out.split("mean error to truth ")[1].split(" m")[0])
    after = float(fixed.split("mean error to truth ")[1].split(" m")[0])
    assert before > 30 and after < 1.0, (before, after)


def test_replay_audit_without_a_dem_is_refused(capsys):
    assert main(["replay", str(RECORDS), "--sensor", str(SENSOR), "--audit"]) == 2
    assert "--audit" in capsys.readouterr().err


@pytest.fixture(scope="module")
def klv():
    from geoloc.workflows.klv_replay import read_klv

    return read_klv(KLV), SurfaceSpec(dem=str(DEM)).build()


def test_the_klv_example_is_clean_and_tag_75_in_msl_is_named(klv):
    """The bundled KLV flight (its planted local faults are outliers, not conventions) gets no
    finding; with tag 75 (HAE) holding tag 15's MSL altitude in every packet, the audit names it."""
    from geoloc.workflows.klv_replay import replay_klv

    read, surface = klv
    rep = replay_klv(read, surface=surface)
    a = audit_klv_columns(rep.columns, rep.sensor, surface)
    assert a.findings == [], a.lines()
    cols = dict(read.columns)
    cols["sensor_ellipsoid_height_m"] = np.asarray(cols["sensor_true_altitude_m"], float)
    rep = replay_klv(dataclasses.replace(read, columns=cols), surface=surface)
    f = _one(audit_klv_columns(rep.columns, rep.sensor, surface), "msl_read_as_ellipsoidal")
    lat, lon = np.asarray(rep.columns["sensor_lat_deg"], float), np.asarray(rep.columns["sensor_lon_deg"], float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    # planted: h75 - h15 was N in the clean file (tag quantisation aside); now 0, so -N
    planted = -np.median(reference_undulation(lat[ok], lon[ok]))
    assert abs(f.offset - planted) <= f.uncertainty, f.line()
    assert "tag 75" in f.fix
    # its frames are the replay's rows it rests on: every located packet
    located = np.flatnonzero(np.asarray(rep.columns["status"]) == 0)
    assert len(f.frames) == f.records and set(f.frames) <= set(located.tolist())


def test_real_flight_tests_on_a_coarse_dem_name_no_convention():
    """[Q17]'s published positions (ASTER GDEM) against the bundled 5' ETOPO5: hundreds of metres
    apart in the Karakoram, and the audit says so as a misfit no signature explains, with no
    datum, time or boresight fault named."""
    sensor = load_sensor(ROOT / "assets" / "cameras" / "qiao2017.toml")
    records = load_records(QIAO, angles=sensor.angle_names)
    a = audit_records(records, sensor, SurfaceSpec(dem=str(ETOPO)).build())
    assert set(a.kinds()) <= {"height_offset"}, a.lines()
    assert a.checks["misfit_median_m"] > 100 and "none of the signatures" in a.lines()[0], a.lines()


def test_report_audits_a_replay_csv(flight, tmp_path, capsys):
    """`geoloc report --audit --dem` on a replay's --out CSV: the finding printed and in report.json."""
    import json

    p, out, rep_dir = tmp_path / "msl.csv", tmp_path / "replay.csv", tmp_path / "rep"
    _write_records(p, flight["records"], flight["pose"].h - flight["n"], flight["lat"], flight["lon"], flight["h"])
    assert main(["replay", str(p), "--sensor", str(SENSOR), "--dem", str(DEM), "--out", str(out)]) == 0
    capsys.readouterr()
    assert (
        main(["report", str(out), "--sensor", str(SENSOR), "--dem", str(DEM), "--audit", "--out-dir", str(rep_dir)])
        == 0
    )
    assert "fix: --altitude-datum egm96" in capsys.readouterr().out
    audit = json.loads((rep_dir / "report.json").read_text())["meta"]["height_audit"]
    (f,) = audit["findings"]
    assert f["kind"] == "msl_read_as_ellipsoidal"
    assert abs(f["offset"] - np.median(-flight["n"])) <= f["uncertainty"], f


def test_the_height_signatures_and_their_texts_by_hand():
    """Each platform-height fault's expected shift and its text, for N = -31.2 m and a take-off
    terrain of 250.4 m: MSL read as ellipsoidal moves the heights by -N, the geoid's wrong sign by -2N."""
    from geoloc.analysis.height_audit import _height_signatures

    assert _height_signatures(-31.2, 250.4) == [
        ("msl_read_as_ellipsoidal", 31.2, "-N = +31.2 m"),
        ("ellipsoidal_read_as_msl", -31.2, "+N = -31.2 m"),
        ("geoid_wrong_sign", 62.4, "-2N = +62.4 m"),
        ("relative_height_read_as_absolute", -250.4, "-take-off terrain = -250.4 m"),
    ]


def test_the_audit_heading_with_no_figures_measured():
    """A flight where nothing could be compared (no check measured): the heading counts 0 records
    and names no finding."""
    from geoloc.analysis.height_audit import HeightAudit

    (line,) = HeightAudit("f.csv", [], {}).lines()
    assert "over 0 records" in line and line.endswith(": no convention fault found")
    assert line.startswith("height audit (f.csv): platform ")


def test_a_records_files_surveyed_heights_in_msl_are_named(flight, tmp_path):
    """Through ``audit_records``: the records' own ``truth_h_m`` column is read as the reported
    centres' heights, so heights written as MSL (h - N, N from outside geoloc) are named."""
    n_fc = reference_undulation(flight["lat"], flight["lon"])
    rec = flight["records"]
    header = [c for c in rec.header if not c.startswith("truth_")] + ["truth_lat_deg", "truth_lon_deg", "truth_h_m"]
    out = tmp_path / "records.csv"
    with out.open("w", newline="") as fh:
        w = csv.DictWriter(fh, header, extrasaction="ignore")
        w.writeheader()
        for k, row in enumerate(rec.rows):
            row = dict(row, truth_lat_deg=repr(float(flight["lat"][k])), truth_lon_deg=repr(float(flight["lon"][k])))
            w.writerow(dict(row, truth_h_m=repr(float(flight["h"][k] - n_fc[k]))))
    records = load_records(out, angles=flight["sensor"].angle_names)
    f = _one(audit_records(records, flight["sensor"], flight["surface"]), "msl_read_as_ellipsoidal")
    assert f.subject == "frame-centre height"
    assert abs(f.offset - np.median(-n_fc)) <= f.uncertainty, f.line()


# --------------------------------------------------------------------------- the relative azimuth read as true

CORPUS = ROOT / "tests" / "data" / "misb"


def _wrap(a):
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def test_real_frame_centres_that_leave_the_heading_out_are_named():
    """FFmpeg's "Day Flight" sample (a real encoder's KLV): its frame centres lie at the bearing of tag 18
    from north, heading left out. No DEM is bundled there, so the replay ends each ray on the packet's own
    frame-centre height (ellipsoidal) and the audit runs the bearing check only, which needs no terrain.
    The bearings here are pymap3d's Vincenty, from the packets' raw items, not the audit's geodesics."""
    from pymap3d.vincenty import vdist

    from geoloc.io import klv
    from geoloc.workflows.klv_replay import replay_klv

    path = CORPUS / "ffmpeg_day_flight.klv"
    r = replay_klv(path)
    a = audit_klv_columns(r.columns, r.sensor, None, source=path.name)
    f = _one(a, "azimuth_from_north")
    assert "no DEM" in a.lines()[0] and len(a.lines()) == 2
    packets = list(klv.iter_packets(path.read_bytes()))
    b = np.array(
        [
            vdist(
                p["sensor_latitude_deg"],
                p["sensor_longitude_deg"],
                p["frame_center_latitude_deg"],
                p["frame_center_longitude_deg"],
            )[1]
            for p in packets
        ]
    )
    t18 = np.array([p["sensor_relative_azimuth_deg"] for p in packets])
    heading = np.array([p["platform_heading_deg"] for p in packets])
    # every packet follows tag 18 alone: the centres' 4e-8 deg steps at 10 km and more from the sensor
    # are far under 0.01 deg of bearing (0.05: margin)
    assert np.all(np.abs(_wrap(b - t18)) < 0.05)
    assert f.frames == tuple(range(len(packets)))
    # the estimated turn from the standard's bearing is about minus the heading: heading + tag 18 by hand
    # leaves the platform's pitch (3-4 deg) and roll (under 1 deg) out, which at these 4-6 deg
    # depressions turn a bearing by tenths of a degree: 1 deg
    assert abs(f.offset - np.median(_wrap(b - t18 - heading))) < 1.0, f.line()
    assert abs(f.offset - f.expected) <= f.uncertainty and f.unit == "deg"
    assert "geoloc klv fix" in f.fix and "tag 18" in f.line()


def test_a_writer_that_adds_the_heading_gets_no_azimuth_finding():
    """Esri's Cheyenne flight (another real writer; its heading turns the centres 157-200 deg from tag 18
    alone) and a clean synthetic stream: no convention named without a DEM."""
    from geoloc.workflows.klv_replay import replay_klv

    for path in (CORPUS / "esri_cheyenne.bin", KLV):
        r = replay_klv(path)
        a = audit_klv_columns(r.columns, r.sensor, None, source=path.name)
        assert a.findings == [], a.lines()
        assert a.lines()[0].endswith("no convention fault found")


def test_replay_audit_of_klv_without_a_dem_names_the_azimuth_and_klv_fix_removes_it(tmp_path, capsys):
    """`geoloc replay FILE.klv --audit` without --dem: one line for the finding; the fix it names
    (`geoloc klv fix`, tags 23-24 rewritten from heading + tag 18) leaves nothing to name."""
    src = CORPUS / "ffmpeg_day_flight.klv"
    assert main(["replay", str(src), "--audit"]) == 0
    out = capsys.readouterr().out
    lines = [x for x in out.splitlines() if "from true north" in x]
    assert len(lines) == 1 and "geoloc klv fix" in lines[0], out[-2000:]
    fixed = tmp_path / "fixed.klv"
    assert main(["klv", "fix", str(src), "--out", str(fixed)]) == 0
    capsys.readouterr()
    assert main(["replay", str(fixed), "--audit"]) == 0
    head = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("height audit"))
    assert head.endswith("no convention fault found"), head


def test_report_of_a_klv_replay_without_a_dem_puts_the_finding_in_its_page(tmp_path, capsys):
    """`geoloc report RESULTS.csv --audit` of a KLV replay (no DEM: the bearing check alone): the finding
    in report.json with its frames, and in report.html's own section with them as runs."""
    import json

    out, rep_dir = tmp_path / "day.csv", tmp_path / "rep"
    assert main(["replay", str(CORPUS / "ffmpeg_day_flight.klv"), "--out", str(out)]) == 0
    assert main(["report", str(out), "--audit", "--out-dir", str(rep_dir)]) == 0
    assert "from true north" in capsys.readouterr().out
    (f,) = json.loads((rep_dir / "report.json").read_text())["meta"]["height_audit"]["findings"]
    assert f["kind"] == "azimuth_from_north" and f["frames"] == [0, 1, 2, 3, 4, 5] and f["unit"] == "deg"
    page = (rep_dir / "report.html").read_text()
    section = page.split("<h2>Heights and conventions")[1].split("</ul>")[0]
    assert "from true north" in section and "frames (rows of the CSV, from 0): 0 .. 5 (6)" in section
    # a records CSV without a DEM is still refused before any work (its checks need the terrain)
    assert main(["report", str(RECORDS), "--audit"]) == 2
    assert "--dem" in capsys.readouterr().err


def test_the_stated_uncertainty_is_three_standard_errors_of_the_median_at_least_half_a_metre():
    from scipy.stats import median_abs_deviation

    from geoloc.analysis.height_audit import median_uncertainty

    # docs/height_audit.md, "How sure": 3 x 1.2533 x 1.4826 x MAD / sqrt(n), at least 0.5 m; the MAD
    # scaled to a normal sigma by scipy, the median's standard error sqrt(pi / 2) sigma / sqrt(n)
    rng = np.random.default_rng(3)
    wide = 40.0 + rng.normal(0.0, 6.0, 25)  # three standard errors ~4.5 m: above the floor
    sigma = median_abs_deviation(wide, scale="normal")
    med, u, n = median_uncertainty(np.concatenate([wide, [np.nan]]))
    assert (med, n) == (np.median(wide), 25)
    assert u == pytest.approx(3 * np.sqrt(np.pi / 2) * sigma / 5.0, rel=1e-4)  # scipy's 1.4826 to 5 digits
    # a tight sample (formula 0.12 m) and a constant one (MAD 0): the documented floor, 0.5 m
    tight = 40.0 + rng.normal(0.0, 0.16, 25)
    assert 3 * np.sqrt(np.pi / 2) * median_abs_deviation(tight, scale="normal") / 5.0 < 0.5
    assert median_uncertainty(tight)[1] == 0.5
    assert median_uncertainty([7.0, 7.0, 7.0]) == (7.0, 0.5, 3)


@pytest.mark.parametrize("elevation_deg, measured", [(-55.0, True), (-89.9, False)])
def test_a_height_over_the_centre_needs_a_ground_track_of_two_centimetres_a_metre(flight, elevation_deg, measured):
    """The docs' cut (a ray off nadir by under 1.1 deg, a track under 0.02 m per m of height, says
    little about heights): a ray 35 deg off nadir gives the height at which it passes over its
    reported centre, which for a centre on the DEM is the DEM's height there; one 0.1 deg off gives
    none. (The bundled orbit looks 75 to 80 deg off nadir: it never came near the cut.)"""
    f = flight
    n = len(f["row"])
    zero = np.zeros(n)
    pose = dataclasses.replace(
        f["pose"],
        pitch=zero,
        roll=zero,
        angles={"azimuth": zero, "elevation": np.full(n, np.deg2rad(elevation_deg))},
    )
    row, col = np.full(n, 540.5), np.full(n, 960.5)  # the principal point: the gimbal's own direction
    los = f["sensor"].line_of_sight(row, col, pose)
    # each ray's angle off the ellipsoid's normal at the platform, the normal written out here
    lat, lon = np.asarray(pose.lat, float), np.asarray(pose.lon, float)
    down = -np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    c = np.einsum("ni,ni->n", los.direction_ecef, down)
    tan_off = np.sqrt(1 - c**2) / c
    if measured:
        assert np.all((tan_off > 0.5) & (tan_off < 0.9)), tan_off  # far above 0.02, below 1 (45 deg)
    else:
        assert np.all(tan_off < 0.01), tan_off  # half the cut (0.1 deg, mount and boresight: 0.3 deg in all)
    g = f["surface"].intersect(los)
    assert np.all(g.status == 0)
    a = audit_flight(
        pose, f["sensor"], row, col, f["surface"], np.rad2deg(g.lat), np.rad2deg(g.lon), g.h, source="test"
    )
    h_over = a.columns["height_over_reported_m"]
    if measured:
        # the DEM's height at each centre; 0.5 m: the audit walks a straight ground track between two
        # heights (0 m and the DEM's), the ray's track over 600 m of height bends by centimetres, and
        # the located centre is on the DEM to the solver's tolerance
        np.testing.assert_allclose(h_over, np.asarray(g.h), atol=0.5)
    else:
        assert np.all(np.isnan(h_over))


def test_a_height_offset_that_is_no_signature_is_named_a_plain_offset(flight):
    """+100 m on every platform height: 70 m from +-N (30.6 m), 39 m from -2N, 580 m from the take-off
    terrain's -483 m. No signature is that near; the audit names a plain height offset of +100 m."""
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h + 100.0)
    f = _one(_audit(flight, pose=pose), "height_offset")
    assert abs(f.offset - 100.0) <= f.uncertainty, f.line()


def test_no_record_shift_is_reported_where_every_shift_fits_worse(flight):
    # 100 m on the platform heights: every centre is off, and pairing it with another record's
    # recomputed centre fits worse still (the turret looks at other ground), so no shift is a model
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h + 100.0)
    a = _audit(flight, pose=pose)
    assert a.checks["misfit_median_m"] > 10.0
    assert "misfit_after_shift_m" not in a.checks, a.checks


@pytest.mark.parametrize("k", [7, 9])
def test_the_record_shift_search_is_the_same_both_ways(flight, k):
    """A shift of k records late and k records early get mirror verdicts: the search runs over
    -n/3 .. n/3 (24 records: 8 each way), so 7 is named both ways and 9 neither way as 9."""
    pad = np.full(k, np.nan)
    late = {c: np.r_[flight[c][k:], pad] for c in ("lat", "lon", "h")}
    early = {c: np.r_[pad, flight[c][:-k]] for c in ("lat", "lon", "h")}
    a, b = _audit(flight, **late), _audit(flight, **early)
    offs = []
    for audit in (a, b):
        shift = [f for f in audit.findings if f.kind == "time_offset"]
        offs.append(round(shift[0].offset) if shift else None)
    assert (offs == [7, -7]) if k == 7 else (9 not in offs and -9 not in offs), offs


def test_a_boresight_bias_states_its_uncertainty_in_the_lens_own_angle_per_pixel(flight):
    """The boresight finding's uncertainty: three standard errors of the median pixel offset, at
    least half a pixel, turned into mrad by the angle one row spans at the first record's pixel. That
    angle is computed here with OpenCV (the Brown lens of eo_turret.toml through ``cv2.projectPoints``, inverted by scipy)."""
    cv2 = pytest.importorskip("cv2")
    from scipy.stats import median_abs_deviation

    planted = 5e-3
    s = flight["sensor"]
    biased = s.with_params(boresight_y=s.params["boresight_y"] + planted)
    g = flight["surface"].intersect(biased.line_of_sight(flight["row"], flight["col"], flight["pose"]))
    a = _audit(flight, lat=np.rad2deg(g.lat), lon=np.rad2deg(g.lon), h=g.h)
    f = _one(a, "boresight_bias")
    drow, dcol = a.columns["reported_drow_px"], a.columns["reported_dcol_px"]
    ok = np.isfinite(drow) & np.isfinite(dcol)
    k = int(np.flatnonzero(ok)[0])
    K = np.array([[2200.0, 0.0, 959.5], [0.0, 2195.0, 539.5], [0.0, 0.0, 1.0]])  # 1-based centres made 0-based
    dist = np.array([-0.21, 0.07, 0.0004, -0.0002, -0.01])  # k1 k2 p1 p2 k3, OpenCV's order
    from scipy.optimize import fsolve

    def ray(u, v):  # the normalised point OpenCV's projectPoints takes to pixel (u, v), solved by scipy
        def miss(xy):
            uv = cv2.projectPoints(np.array([[xy[0], xy[1], 1.0]]), np.zeros(3), np.zeros(3), K, dist)[0]
            return uv.reshape(2) - (u, v)

        return fsolve(miss, ((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]), xtol=1e-14)

    u0, v0 = flight["col"][k] - 1, flight["row"][k] - 1
    xy = np.array([ray(u0, v0), ray(u0, v0 + 1)])
    rays = np.c_[xy, np.ones(2)]
    per_px = 1e3 * np.arctan2(np.linalg.norm(np.cross(rays[0], rays[1])), rays[0] @ rays[1])
    n = int(np.sum(np.isfinite(drow)))
    spread = median_abs_deviation(drow[ok], scale="normal"), median_abs_deviation(dcol[ok], scale="normal")
    want = max(3 * np.sqrt(np.pi / 2) * np.hypot(*spread) / np.sqrt(n), 0.5) * per_px
    # 1e-4: scipy's normal scale 1.482602 against the module's 1.4826 and OpenCV's undistortion
    assert f.uncertainty == pytest.approx(want, rel=1e-4), (f.uncertainty, want)


def test_frame_centre_heights_with_the_geoid_subtracted_twice_say_minus_2n(flight):
    # h - 2N on every reported centre; the text's size is -2N of the reference geoid (pyproj or the
    # bundled grid read here), to its one printed decimal
    n_fc = reference_undulation(flight["lat"], flight["lon"])
    f = _one(_audit(flight, h=flight["h"] - 2 * n_fc), "geoid_wrong_sign")
    assert f.subject == "frame-centre height"
    assert abs(f.offset - np.median(-2 * n_fc)) <= f.uncertainty, f.line()
    assert (
        f.expected_text.startswith("-2N = +6")
        and abs(float(f.expected_text.split("=")[1].split()[0]) - np.median(-2 * n_fc)) <= 0.1
    ), f.expected_text


def test_the_boresight_detail_gives_each_axis_in_the_lens_own_angle(flight):
    """The detail's per-axis angles: the median row and column offsets turned into the angle between
    the rays of the first record's pixel and the pixel so moved, computed with OpenCV's projectPoints
    (inverted by scipy) for the Brown lens of eo_turret.toml."""
    cv2 = pytest.importorskip("cv2")
    from scipy.optimize import fsolve

    s = flight["sensor"]
    biased = s.with_params(boresight_y=s.params["boresight_y"] + 5e-3, boresight_x=s.params["boresight_x"] + 3e-3)
    g = flight["surface"].intersect(biased.line_of_sight(flight["row"], flight["col"], flight["pose"]))
    a = _audit(flight, lat=np.rad2deg(g.lat), lon=np.rad2deg(g.lon), h=g.h)
    f = _one(a, "boresight_bias")
    drow, dcol = a.columns["reported_drow_px"], a.columns["reported_dcol_px"]
    k = int(np.flatnonzero(np.isfinite(drow) & np.isfinite(dcol))[0])
    dr, dc = np.nanmedian(drow), np.nanmedian(dcol)
    K = np.array([[2200.0, 0.0, 959.5], [0.0, 2195.0, 539.5], [0.0, 0.0, 1.0]])
    dist = np.array([-0.21, 0.07, 0.0004, -0.0002, -0.01])

    def ray(u, v):
        def miss(xy):
            return cv2.projectPoints(np.array([[xy[0], xy[1], 1.0]]), np.zeros(3), np.zeros(3), K, dist)[0].reshape(
                2
            ) - (u, v)

        x, y = fsolve(miss, ((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]), xtol=1e-14)
        return np.array([x, y, 1.0])

    def mrad(a, b):
        return 1e3 * np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)

    u0, v0 = flight["col"][k] - 1, flight["row"][k] - 1
    a_row = np.copysign(mrad(ray(u0, v0), ray(u0, v0 + dr)), dr)
    a_col = np.copysign(mrad(ray(u0, v0), ray(u0 + dc, v0)), dc)
    assert f"{dr:+.1f} px in rows ({a_row:+.2f} mrad)" in f.detail, (f.detail, a_row)
    assert f"{dc:+.1f} px in columns ({a_col:+.2f} mrad)" in f.detail, (f.detail, a_col)
