"""Which kind the height audit names: an offset that matches no signature within its stated
uncertainty is an unexplained height offset, not the nearest convention (geoloc.analysis.height_audit).

The flight, its DEM and its clean reported centres are those of tests/analysis/test_height_audit.py
(the EO turret orbit over the Jacksboro SRTM crop). Its take-off terrain (the DEM under the first
record) is 483.7 m, and the terrain under the whole orbit spans 278 to 897 m: a planted -400 m is
84 m from the relative-height signature, which a tolerance made of the terrain's spread would accept.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import norm

from geoloc.analysis.height_audit import FAULTS, KLV_FIXES, RECORDS_FIXES, _height_finding
from test_height_audit import _audit, _one, flight  # noqa: F401  (the fixture)

#: SRTM's published absolute vertical accuracy, 16 m LE90 (Farr et al. 2007): the take-off terrain's own
#: error as a signature, one standard deviation = LE90 / the normal's 0.95 quantile (scipy, not geoloc).
SRTM_LE90_M = 16.0
SIGMA_TAKEOFF_M = SRTM_LE90_M / norm.ppf(0.95)


def test_a_planted_400_m_offset_is_an_unexplained_height_offset_not_a_relative_height(flight):  # noqa: F811
    planted = -400.0
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h + planted)
    f = _one(_audit(flight, pose=pose), "height_offset")
    assert f.subject == "platform height" and f.unit == "m"
    assert abs(f.offset - planted) <= f.uncertainty, f.line()
    # no signature's size and no signature's fix: the generic check of the height column
    assert np.isnan(f.expected) and f.expected_text == ""
    assert f.fix == RECORDS_FIXES["height_offset"]
    assert all(f.fix != RECORDS_FIXES[k] for k in RECORDS_FIXES if k != "height_offset")
    # still a finding, on every record it rests on, and the correction by its own size removes the misfit
    assert f.frames == tuple(range(len(flight["row"])))
    assert f.misfit_after_m < f.misfit_before_m / 3, f.line()
    line = f.line()
    assert "unexplained height offset" in line and "relative_height_read_as_absolute at -483.7 m" in line, line


def test_the_same_offset_against_noisy_truth_is_still_a_height_offset_not_a_boresight(flight):  # noqa: F811
    """The file's surveyed truth (20 m of pointing noise) as the reference: the boresight correction leaves
    ten times the height's misfit, so the tie rule never reaches it."""
    r = flight["records"]
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h - 400.0)
    a = _audit(flight, pose=pose, lat=r.column("truth_lat_deg"), lon=r.column("truth_lon_deg"), h=r.column("truth_h_m"))
    f = _one(a, "height_offset")
    assert abs(f.offset - (-400.0)) <= f.uncertainty, f.line()


@pytest.mark.parametrize("shift", [-84.0, -40.0, 40.0])
def test_offsets_off_the_take_off_terrain_by_more_than_its_tolerance_are_not_named(flight, shift):  # noqa: F811
    takeoff = float(flight["surface"].dem.height(flight["pose"].lat[0], flight["pose"].lon[0]))
    pose = dataclasses.replace(flight["pose"], h=flight["pose"].h - takeoff - shift)
    _one(_audit(flight, pose=pose), "height_offset")


def test_the_relative_height_tolerance_by_hand():
    """The match rule on made-up figures: estimate -483.7 + x +/- 0.5 m against the take-off terrain
    -483.7 m. Both uncertainties are 3-sigma bounds, combined in quadrature:
    hypot(0.5, 3 x 16 / 1.6449) = 29.19 m. Inside it the convention is named with its fix; outside, an
    unexplained offset. N = -30.6 m keeps the datum signatures far away."""
    tol = np.hypot(0.5, 3.0 * SIGMA_TAKEOFF_M)
    assert 29.1 < tol < 29.3
    args = dict(u_hat=0.5, n_dh=24, nbar=-30.6, takeoff=483.7, raw=1000.0, after=0.5, fixes=RECORDS_FIXES)
    for x, kind in ((tol - 0.05, "relative_height_read_as_absolute"), (tol + 0.05, "height_offset")):
        for sign in (1.0, -1.0):
            f = _height_finding(-483.7 + sign * x, **args)
            assert f.kind == kind, (x, f.line())
    # the KLV wording of the unexplained offset names the encoder's height tags, not a records column
    f = _height_finding(-400.0, **dict(args, fixes=dict(RECORDS_FIXES, **KLV_FIXES)))
    assert f.kind == "height_offset" and "tags (15 MSL, 75 HAE)" in f.fix


def test_the_datum_signatures_keep_their_tight_tolerance():
    """N and 2N: the geoid grid's 0.5 m bound in quadrature with the estimate's (0.5 m): 0.71 m."""
    args = dict(u_hat=0.5, n_dh=24, nbar=-30.6, takeoff=483.7, raw=100.0, after=0.2, fixes=RECORDS_FIXES)
    assert _height_finding(30.6 + 0.70, **args).kind == "msl_read_as_ellipsoidal"
    assert _height_finding(30.6 + 0.72, **args).kind == "height_offset"
    assert _height_finding(61.2 - 0.70, **args).kind == "geoid_wrong_sign"
    assert "height_offset" in FAULTS and FAULTS["height_offset"].startswith("an unexplained height offset")
