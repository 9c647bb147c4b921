"""`geoloc log` on the [Q17] records as a debugger reads it: one tree per flight, labels, error components,
outliers, before/after calibration and the blueprint, all read back from the .rrd with rerun's reader.

Oracles: pyproj (the flights' separation), pymap3d (``geodetic2ned`` for the components), the core called
here directly (geoloc.workflows.replay, geoloc.analysis.accuracy, geoloc.analysis.sensor_fit) and the
published calibration figures of docs/calibration.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import pytest
from pyproj import Geod

from geoloc.analysis.accuracy import (
    error_components,
    robust_outliers,
    track_azimuth_rad,
)
from geoloc.assets import ASSETS
from geoloc.frames.enu import EnuFrame
from geoloc.io.records import load_records
from geoloc.sensors.camera import Camera
from geoloc.workflows.replay import replay_at_height

RECORDS = Path(ASSETS) / "records" / "qiao2017_flight_tests.csv"
CAMERA = Path(ASSETS) / "cameras" / "qiao2017.toml"
FLIGHTS = ("T3", "T4")


def read(path, store=None):
    """{entity: {"temporal"/"static": {column: rows}}}, temporal rows in record order."""
    from rerun.chunk import RrdReader

    r = RrdReader(path)
    out: dict = {}
    for ch in r.stream(store=store) if store is not None else r.stream():
        b = ch.to_record_batch()
        names = [n for n in b.schema.names if n not in ("rerun.controls.RowId", "log_time", "log_tick")]
        key = "temporal" if "record" in names else "static"
        dst = out.setdefault(ch.entity_path, {}).setdefault(key, {})
        for n in names:
            dst.setdefault(n, []).extend(b.column(n).to_pylist())
    for ent in out.values():
        t = ent.get("temporal")
        if t:
            order = np.argsort(t["record"], kind="stable")
            for n in t:
                t[n] = [t[n][i] for i in order]
    return out


def scalars(data, path):
    """(record, value) of a series; ``series/<rel>`` of a two-flight recording joins ``series/T3/<rel>``
    and ``series/T4/<rel>`` (one entity per flight) in record order."""
    if path not in data and path.startswith("/series/"):
        parts = [
            scalars(data, path.replace("/series/", f"/series/{g}/", 1))
            for g in FLIGHTS
            if path.replace("/series/", f"/series/{g}/", 1) in data
        ]
        if not parts:
            raise KeyError(path)
        k, v = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        o = np.argsort(k, kind="stable")
        return k[o], v[o]
    t = data[path]["temporal"]
    return np.array(t["record"]), np.array([r[0] for r in t["Scalars:scalars"]])


@pytest.fixture(scope="module")
def rec(rerun_home, tmp_path_factory):
    from geoloc_viz.rerun_log import write
    from geoloc_viz.rerun_model import steps_from_records

    steps, _ = steps_from_records(RECORDS)
    out = tmp_path_factory.mktemp("rrd") / "q17.rrd"
    write(steps, out)
    return steps, out, read(out)


@pytest.fixture(scope="module")
def core():
    """The replay and the error components straight from the core (not through geoloc_viz)."""
    recs = load_records(RECORDS)
    res = replay_at_height(recs, Camera.from_toml(CAMERA), "paper_height_m")
    table = np.array(recs.text("table"), dtype=object)
    track = track_azimuth_rad(
        recs.column("ac_lat_deg"), recs.column("ac_lon_deg"), table, np.deg2rad(recs.column("heading_deg"))
    )
    comp = error_components(
        res.lat_deg,
        res.lon_deg,
        res.h_m,
        recs.column("truth_lat_deg"),
        recs.column("truth_lon_deg"),
        np.nan,
        track_heading_rad=track,
    )
    return recs, res, table, comp


def test_one_tree_and_origin_per_flight_and_no_strip_joins_them(rec, core):
    steps, out, data = rec
    recs, res, table, _ = core
    # the two flights are ~200 km apart (pyproj): one shared scene would draw one grey line
    _, _, dist = Geod(ellps="WGS84").inv(
        recs.column("ac_lon_deg")[0],
        recs.column("ac_lat_deg")[0],
        recs.column("ac_lon_deg")[10],
        recs.column("ac_lat_deg")[10],
    )
    assert dist > 150e3
    for g in FLIGHTS:
        for ent in ("ned", "ned/body", "track", "footprint", "los", "target", "truth", "published", "current"):
            assert f"/world/{g}/{ent}" in data, (g, ent)
        assert f"/plot/{g}/targets" in data and f"/map/{g}/track" in data
    for shared in ("/world/ned", "/world/track", "/world/target", "/map/track", "/map/target"):
        assert shared not in data
    # each flight's track: its own 10 aircraft positions, in its own ENU frame (geoloc.frames.enu
    # called here with the rounded origin of its first published point)
    origins = {"T3": EnuFrame.from_deg(36.338, 78.858, 4600.0), "T4": EnuFrame.from_deg(35.574, 80.873, 5300.0)}
    pose = recs.pose()
    for g in FLIGHTS:
        m = table == g
        strip = np.array(data[f"/world/{g}/track"]["static"]["LineStrips3D:strips"][0][0])
        want = origins[g].from_geodetic(pose.lat[m], pose.lon[m], pose.h[m])
        np.testing.assert_array_equal(strip, want.astype(np.float32))  # float32 as rerun stores them
    # no line strip anywhere spans more than one flight (a flight's track is ~3 km, the gap 200 km);
    # the line of sight reaches 22 km
    for ent, d in data.items():
        for part in d.values():
            for strips in part.get("LineStrips3D:strips", []):
                for s in strips:
                    s = np.asarray(s, float)
                    assert np.ptp(s[:, :2], axis=0).max() < 40e3, ent


def test_record_labels_on_the_timeline(rec, core):
    steps, out, data = rec
    recs = core[0]
    t = data["/log/record"]["temporal"]
    assert t["record"] == list(range(20))
    labels = [x[0] for x in t["TextLog:text"]]
    assert labels == [f"{lab} ({g})" for lab, g in zip(recs.labels(), recs.text("table"))]
    assert labels[0] == "T3-1 (T3)" and labels[10] == "T4-1 (T4)"
    # and on the located points themselves
    for g in FLIGHTS:
        got = [x[0] for x in data[f"/world/{g}/target"]["temporal"]["Points3D:labels"]]
        assert got == [lab for lab, gg in zip(recs.labels(), recs.text("table")) if gg == g]


def test_error_components_equal_the_core_and_pymap3d(rec, core):
    steps, out, data = rec
    recs, res, table, comp = core
    for c in ("north_m", "east_m", "along_m", "across_m", "horizontal_m"):
        k, v = scalars(data, f"/series/error/{c}")
        assert list(k) == list(range(20))
        # float64 series; the recording locates through its own batch call (line_of_sight on the whole
        # pose, then the surface), the replay through its own: last-bit differences, 4e-13 m seen; 1e-9 m
        np.testing.assert_allclose(v, comp[c], rtol=0, atol=1e-9)
    assert not any(e.endswith("/error/up_m") for e in data)  # the survey gives no heights: no vertical component
    # outside the code: pymap3d about the truth at the computed height; 1e-6 m (float64 through ECEF)
    n, e, _ = pymap3d.geodetic2ned(
        res.lat_deg, res.lon_deg, res.h_m, recs.column("truth_lat_deg"), recs.column("truth_lon_deg"), res.h_m
    )
    np.testing.assert_allclose(scalars(data, "/series/error/north_m")[1], n, atol=1e-6)
    np.testing.assert_allclose(scalars(data, "/series/error/east_m")[1], e, atol=1e-6)
    # the flight test's errors are along track (docs/calibration.md: ~50 m behind, ~1 m across)
    along = scalars(data, "/series/error/along_m")[1]
    across = scalars(data, "/series/error/across_m")[1]
    assert np.all(along < -40) and np.all(np.abs(across) < 10)


def test_outlier_flags_as_series_and_annotations(rerun_home, tmp_path, rec, core):
    from geoloc_viz.rerun_log import write
    from geoloc_viz.rerun_model import steps_from_records

    steps, out, data = rec
    _, _, table, comp = core
    want = np.zeros(20, bool)
    for g in FLIGHTS:
        want[table == g] = robust_outliers(comp["horizontal_m"][table == g])
    np.testing.assert_array_equal(scalars(data, "/series/outlier/flag")[1], want.astype(float))
    assert not want.any() and "/log/outliers" not in data  # the bundled records have none
    # plant one: T3-5's column moved by 300 px (~2 km at 20 km slant range with f = 166841 px)
    lines = RECORDS.read_text().splitlines()
    row = lines[5].split(",")
    assert row[:2] == ["T3", "5"]
    row[3] = str(float(row[3]) + 300)
    lines[5] = ",".join(row)
    p = tmp_path / "planted.csv"
    p.write_text("\n".join(lines) + "\n")
    s2, _ = steps_from_records(p)
    o = tmp_path / "planted.rrd"
    write(s2, o)
    d2 = read(o)
    _, flag = scalars(d2, "/series/outlier/flag")
    assert np.flatnonzero(flag).tolist() == [4]
    t = d2["/log/outliers"]["temporal"]
    assert t["record"] == [4] and t["TextLog:text"][0][0].startswith("T3-5: outlier")
    assert d2["/log/record"]["temporal"]["TextLog:text"][4][0] == "T3-5 (T3) - outlier"
    assert "/plot/T3/outliers" in d2


def test_before_and_after_calibration(rec, core):
    from geoloc.analysis.sensor_fit import fit_sensor_groups
    from geoloc.locate import as_sensor
    from geoloc.surfaces.height import PerRecordHeightSurface

    steps, out, data = rec
    recs, res, table, comp = core
    _, before = scalars(data, "/series/calibration/before_m")
    _, after = scalars(data, "/series/calibration/after_m")
    # the replay's error to truth (the to_truth_m series); the components' horizontal_m above is at
    # the target height, longer by (R + h) / R (h ~ 5 km: 8e-4)
    np.testing.assert_allclose(before, res.error_to_truth_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(before, comp["horizontal_m"], rtol=1e-3)
    report, _ = fit_sensor_groups(
        recs,
        as_sensor(Camera.from_toml(CAMERA)),
        ["mount_x", "mount_y", "mount_z"],
        PerRecordHeightSurface(recs.column("paper_height_m")),
        group_column="table",
    )
    for g in FLIGHTS:
        m = table == g
        # calibrate's own mean (pyproj's geodesic on the ellipsoid, rounded to 1 mm) and ours (tangent plane
        # at the target's height, longer by h / R ~ 8e-4): 0.01 m at ~5 m
        assert after[m].mean() == pytest.approx(report["groups"][g]["mean_error_after_m"], abs=0.01)
        assert before[m].mean() == pytest.approx(report["groups"][g]["mean_error_before_m"], rel=1e-3)
    # docs/calibration.md: 50.0 / 50.5 m before, 5.0 / 5.1 m after (one mounting rotation per flight)
    assert after[table == "T3"].mean() == pytest.approx(5.0, abs=0.1)
    assert after[table == "T4"].mean() == pytest.approx(5.1, abs=0.1)


def test_offline_2d_plot_and_current_hit(rec):
    steps, out, data = rec
    for g in FLIGHTS:
        m = steps.group_of == g
        tgt = steps.target_enu[m]
        pts = np.array(data[f"/plot/{g}/targets"]["static"]["Points2D:positions"][0])
        # (east, -north): rerun's 2D view has y down, so north is up on the screen
        np.testing.assert_array_equal(pts, np.c_[tgt[:, 0], -tgt[:, 1]].astype(np.float32))
        tr = steps.enu_for(g).from_geodetic(
            np.deg2rad(steps.truth["lat_deg"][m]), np.deg2rad(steps.truth["lon_deg"][m]), steps.ground.h[m]
        )
        truth = np.array(data[f"/plot/{g}/truth"]["static"]["Points2D:positions"][0])
        np.testing.assert_array_equal(truth, np.c_[tr[:, 0], -tr[:, 1]].astype(np.float32))
        # the error arrows go from the truth to the computed point: ~50 m long (Tables 3-4)
        vec = np.array(data[f"/plot/{g}/errors"]["static"]["Arrows2D:vectors"][0], float)
        assert np.all((np.hypot(*vec.T) > 40) & (np.hypot(*vec.T) < 60))
        # the entity the 3D eye tracks sits on the current hit at every step of the flight
        cur = data[f"/world/{g}/current"]["temporal"]
        assert cur["record"] == np.flatnonzero(m).tolist()
        np.testing.assert_array_equal(np.array([r[0] for r in cur["Transform3D:translation"]]), tgt.astype(np.float32))


def test_blueprint_separates_heading_attitude_and_flights(rec):
    from rerun.chunk import RrdReader

    steps, out, data = rec
    bp = read(out, store=RrdReader(out).blueprints()[0])
    views = {}
    for ent, d in bp.items():
        s = d.get("static", {})
        if "ViewBlueprint:display_name" in s:
            views[s["ViewBlueprint:display_name"][0][0]] = {
                "kind": s["ViewBlueprint:class_identifier"][0][0],
                "origin": s["ViewBlueprint:space_origin"][0][0],
                "query": bp.get(f"{ent}/ViewContents", {}).get("static", {}).get("ViewContents:query", [[None]])[0],
                "eye": bp.get(f"{ent}/EyeControls3D", {}).get("static", {}),
            }
    # every time-series view shows both flights, each from its own entity; heading apart from pitch / roll
    assert views["Heading [deg]"]["query"] == ["/series/T3/attitude/heading_deg", "/series/T4/attitude/heading_deg"]
    assert views["Heading [deg]"]["origin"] == "/series"
    assert views["Pitch and roll [deg]"]["query"] == [
        f"/series/{g}/attitude/{a}_deg" for g in FLIGHTS for a in ("pitch", "roll")
    ]
    assert views["Error components to truth [m]"]["query"] == [
        f"/series/{g}/error/{c}_m" for g in FLIGHTS for c in ("north", "east", "along", "across")
    ]
    for v in views.values():
        if v["kind"] == "TimeSeries":
            assert v["origin"] == "/series" and {q.split("/")[2] for q in v["query"]} == set(FLIGHTS), v
    assert "Before / after calibration: error to truth [m]" in views
    assert "Outlier flags (1 = outlier)" in views
    assert views["Records and annotations"]["kind"] == "TextLog"
    for g in FLIGHTS:
        v3 = views[f"{g}: scene (local ENU, m), following the current hit"]
        assert v3["kind"] == "3D" and v3["origin"] == f"/world/{g}"
        assert v3["eye"]["EyeControls3D:tracking_entity"][0][0] == f"/world/{g}/current"
        v2 = views[f"{g}: targets and truth (east, north m; offline)"]
        assert v2["kind"] == "2D" and v2["origin"] == f"/plot/{g}"


def test_klv_pose_is_the_replay_columns():
    from geoloc.workflows.klv_replay import klv_pose, klv_pose_deg, replay_klv

    c = replay_klv(Path(ASSETS) / "klv" / "example_flight.klv").columns
    p = klv_pose(c)
    np.testing.assert_array_equal(p.lat, np.deg2rad(np.asarray(c["sensor_lat_deg"], float)))
    np.testing.assert_array_equal(p.heading, np.deg2rad(np.asarray(c["platform_heading_deg"], float)))
    np.testing.assert_array_equal(p.angles["azimuth"], np.deg2rad(np.asarray(c["sensor_relative_azimuth_deg"], float)))
    one = klv_pose_deg(c, 3)
    assert one["lat_deg"] == float(c["sensor_lat_deg"][3]) and isinstance(one["angles_deg"]["sensor_roll"], float)


def test_no_series_entity_has_rows_of_two_flights(rec, core):
    """Each flight's series is its own entity (series/<flight>/...), so no plot line joins T3-10 to T4-1."""
    from rerun.chunk import RrdReader

    steps, out, data = rec
    table = core[2]
    series = [e for e in data if e.startswith("/series/") and "temporal" in data[e]]
    assert len(series) == 2 * 19  # 19 quantities (attitude, gimbal, range, height, errors, flags, calibration)
    for ent in series:
        g = ent.split("/")[2]
        assert g in FLIGHTS, ent
        rows = data[ent]["temporal"]["record"]
        # the rows of this entity are exactly its flight's records (the table column of the file)
        assert rows == np.flatnonzero(table == g).tolist(), ent
    # one colour per flight: the same quantity is drawn in a different hue for T3 and T4, named by flight
    for rel in ("attitude/heading_deg", "error/along_m", "calibration/after_m"):
        st = {g: data[f"/series/{g}/{rel}"]["static"] for g in FLIGHTS}
        assert st["T3"]["SeriesLines:colors"] != st["T4"]["SeriesLines:colors"]
        assert [st[g]["SeriesLines:names"][0][0] for g in FLIGHTS] == [f"{g} {rel.split('/')[1]}" for g in FLIGHTS]
    # and the blueprint's time-series views exist (a check over an empty list proves nothing)
    bp = read(out, store=RrdReader(out).blueprints()[0])
    kinds = [
        d["static"]["ViewBlueprint:class_identifier"][0][0]
        for d in bp.values()
        if "ViewBlueprint:class_identifier" in d.get("static", {})
    ]
    # heading; pitch and roll; gimbal; range; height; horizontal error; components; outliers; calibration
    assert kinds.count("TimeSeries") == 9
