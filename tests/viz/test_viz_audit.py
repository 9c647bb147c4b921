"""The heights and conventions audit in the viewer's flight panel (geoloc_viz.flight_model.audit_markdown,
the folder "Flight: heights and conventions" of geoloc_viz.flight_layer).

Each finding is shown with its estimated offset, how sure (its stated uncertainty), its frames and its fix.
The oracle for the finding itself is tests/analysis/test_height_audit.py (pymap3d's bearings on the raw
packets); here: the same finding reaches the panel, a clean flight says so, and a person reads it in
headless Chromium (the launcher and viewer helpers of tests/viz/test_viz_browser.py).
"""

import re
from pathlib import Path

import pytest

from geoloc_viz import flight_model

ROOT = Path(__file__).resolve().parents[2]
DAY = ROOT / "tests" / "data" / "misb" / "ffmpeg_day_flight.klv"


@pytest.fixture(scope="module")
def day_model():
    return flight_model.build(flight_model.default_flight_scenario(path=DAY))


def test_the_panel_shows_the_real_flights_azimuth_finding_with_its_size_frames_and_fix(day_model):
    a = day_model.audit
    assert [f.kind for f in a.findings] == ["azimuth_from_north"]
    f = a.findings[0]
    text = day_model.audit_markdown()
    assert "1 convention fault(s) found" in text and "no DEM, so no height checked" in text
    assert f"estimated **{f.offset:+.2f} +/- {f.uncertainty:.2f} deg**" in text
    # the six packets of the file, by index and by the records' own labels
    assert "frames 0 .. 5 (packet 0 .. packet 5, 6 frames)" in text
    assert "fix: the encoder leaves the platform heading out" in text and "geoloc klv fix" in text


def test_a_clean_flight_panel_says_no_fault_and_what_was_compared():
    # about 5 s on an idle machine: the one bundled KLV flight over a DEM (298 packets) is built
    from geoloc_viz.scenario import load_view_scenario

    # the records and their DEM only (no video, no zoom): what the audit reads
    m = flight_model.build(load_view_scenario(flight_model.default_flight_path()), diagnose_faults=False)
    text = m.audit_markdown()
    assert text.startswith("**no convention fault found**"), text
    # the bundled flight over its DEM: heights compared (N at Jacksboro, about -30.6 m)
    assert re.search(r"EGM96 N -30\.\d m, median misfit \d+\.\d m over 298 frames", text), text


def test_a_records_flight_with_its_heights_lowered_shows_the_offset_on_every_frame(tmp_path):
    """The EO turret orbit (24 records, surveyed truth only, over its DEM) with ac_h_m lowered by 400 m:
    the panel shows a platform-height finding of -400 m within its stated uncertainty on frames 0 .. 23,
    labelled by the records, with its fix; the file as bundled shows none."""
    import csv

    from geoloc_viz.scenario import load_view_scenario

    records, sensor, dem = (
        ROOT / "assets" / "records" / "eo_turret_flight.csv",
        ROOT / "assets" / "sensors" / "eo_turret.toml",
        ROOT / "assets" / "dem" / "srtm_jacksboro.tif",
    )
    clean = flight_model.build(load_view_scenario(records, camera_path=sensor, dem_path=dem), diagnose_faults=False)
    assert clean.audit_markdown().startswith("**no convention fault found**")
    rows = list(csv.DictReader(records.open(newline="")))
    for r in rows:
        r["ac_h_m"] = repr(float(r["ac_h_m"]) - 400.0)
    low = tmp_path / "low.csv"
    with low.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    m = flight_model.build(load_view_scenario(low, camera_path=sensor, dem_path=dem), diagnose_faults=False)
    (f,) = m.audit.findings
    assert f.subject == "platform height" and abs(f.offset - (-400.0)) <= f.uncertainty, f.line()
    text = m.audit_markdown()
    assert f"estimated **{f.offset:+.1f} +/- {f.uncertainty:.1f} m**" in text
    assert "frames 0 .. 23 (orbit1-1 .. orbit1-24, 24 frames)" in text and f"fix: {f.fix}" in text


def test_frames_are_written_as_runs_with_their_labels(day_model):
    assert day_model.frames_text((0, 1, 2, 4)) == "frames 0 .. 2, 4 (packet 0 .. packet 4, 4 frames)"
    assert day_model.frames_text((3,)) == "frame 3 (packet 3 .. packet 3, 1 frame)"
    assert day_model.frames_text(()) == "frames: not said"


@pytest.mark.browser
def test_a_person_reads_the_audit_in_the_flight_panel(tmp_path):
    """`geoloc view --records ffmpeg_day_flight.klv`: the person opens the folder "Flight: heights and
    conventions" and reads the finding, its estimate, its frames and its fix (screenshot
    test-artifacts/viz_audit_panel.png)."""
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        app = GeolocApp(server, flight_model.default_flight_scenario(path=DAY), layers=(flight_layer.attach,))
        app.cb_terrain.value = False  # software WebGL on a shared 2-core machine: fewer triangles
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 900, 1100)
            title = page.get_by_text("Flight: heights and conventions", exact=True)
            wait_for(lambda: title.count() >= 1, 60, "the audit folder")
            # the other flight folders closed, as a person makes room; the audit folder's title in view
            for name in ("Flight", "Flight: outliers first", "Flight: what the outliers look like"):
                page.get_by_text(name, exact=True).first.click(timeout=60000)
            title.first.scroll_into_view_if_needed(timeout=60000)
            wait_for(lambda: "from true north" in page.locator("body").inner_text(), 60, "the finding on the page")
            text = page.locator("body").inner_text()
            assert "1 convention fault(s) found" in text
            assert re.search(r"estimated -82\.\d\d \+/- 0\.01 deg", text), text[-3000:]
            assert "frames 0 .. 5 (packet 0 .. packet 5, 6 frames)" in text
            assert "geoloc klv fix" in text
            page.screenshot(path=str(ARTIFACTS / "viz_audit_panel.png"), timeout=120000)
        assert app.layers[-1].md_audit.content == app.layers[-1].model.audit_markdown()
