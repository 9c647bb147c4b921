"""A run of outliers is named by the audit's finding when one covers it (geoloc_viz.flight_model.
name_runs_by_audit), before the one-parameter fit's guess.

FFmpeg's "Day Flight" sample: its frame centres lie at the bearing of tag 18 from north (the oracle is
tests/analysis/test_height_audit.py, pymap3d's bearings on the raw packets). Its one outlier frame
(packet 5, the one with a heading of 235 deg) is fitted best by a timing offset, which is no cause:
the audit's finding covers it. The diagnosis is a pure function of the runs and the audit, so no browser.
"""

from __future__ import annotations

import math

from geoloc.analysis.height_audit import FAULTS, Finding, HeightAudit
from geoloc_viz import flight_model
from geoloc_viz.flight_layer import KIND_NAMES, goto_entries
from geoloc_viz.flight_model import CONVENTION_NAMES, FaultRun, name_runs_by_audit
from test_viz_audit import day_model  # noqa: F401  (the fixture: the day flight's model)


def test_the_day_flights_outlier_run_is_named_by_the_audit_before_the_timing_fit(day_model):  # noqa: F811
    m = day_model
    (az,) = m.audit.findings
    assert az.kind == "azimuth_from_north"
    (run,) = m.faults
    assert (run.first, run.last) == (5, 5)
    assert run.kind == "convention" and run.findings == (az,)
    # the fit is kept, second: what it alone would say
    assert run.fit_kind == "timing" and math.isfinite(run.value)
    head = run.headline()
    name, fit = head.split("; the one-parameter fit alone would say: ")
    assert name.startswith("frame 5 (packet 5): frame centres measured from north (tag 18 without the heading)")
    assert f"{az.offset:+.2f} +/- {az.uncertainty:.2f} deg" in name
    assert "frame(s) ahead of the image" in fit or "frame(s) stale" in fit
    text = m.faults_markdown()
    assert text.index("measured from north") < text.index("frame(s)")
    assert flight_model.WHAT_IT_LOOKS_LIKE["convention"] in text
    # the "go to" dropdown names the run by the audit, not as a stale pose
    _, opts = goto_entries(m)
    assert opts[0].startswith("run 1 (the audit's convention fault, frame 5 (packet 5)")


def _finding(frames):
    return Finding("azimuth_from_north", "frame centres", -82.9, 0.01, "deg", frames=tuple(frames))


def _run(first, last, kind="timing"):
    return FaultRun(first, last, kind, 0.57, {"attitude": 0.9, "datum": 0.3, "timing": 0.2})


def test_a_finding_names_only_the_runs_it_covers_whole():
    audit = HeightAudit("f", [_finding(range(0, 6))], {})
    inside, across, outside = name_runs_by_audit([_run(2, 4), _run(4, 7), _run(8, 9, "attitude")], audit)
    assert inside.kind == "convention" and inside.fit_kind == "timing"
    assert across.kind == "timing" and across.findings == ()  # frames 6, 7 are not the finding's
    assert outside.kind == "attitude" and outside.headline() == "frames 8 .. 9 (2 frames): heading bias +32.66 deg"
    # no audit, or one without findings: the runs as they were
    assert name_runs_by_audit([_run(2, 4)], None)[0].kind == "timing"
    assert name_runs_by_audit([_run(2, 4)], HeightAudit("f", [], {}))[0].kind == "timing"


def test_every_convention_the_audit_names_has_a_short_name_and_a_kind_name():
    assert set(CONVENTION_NAMES) == set(FAULTS)
    assert "convention" in KIND_NAMES and "convention" in flight_model.WHAT_IT_LOOKS_LIKE
