"""The live debugger's flight model: grown batch by batch (``flight_model.extend``), it is the
model ``flight_model.build`` makes of the same frames at once (the file view's), and a window
keeps the newest frames with everything derived again over them."""

from __future__ import annotations

import copy

import numpy as np

from geoloc_viz import flight_model


def _scn(base, recs):
    s = copy.copy(base)
    s.records = list(recs)
    return s


def _close(x, y, k):
    # the flight model's batches walk the terrain kernel's Python source within a budget
    # (terrain_numba.uncompiled_budget), a larger one the compiled kernel after its first rays, whose fused multiply-adds round once where Python rounds twice:
    # hits within 2.5e-8 m (tests/surfaces/test_terrain_python_walk.py holds them to 1e-6 m). So the flight grown
    # in batches equals the one built at once to 1e-6 (metres, radians, degrees); integers and flags exactly
    x, y = np.asarray(x), np.asarray(y)
    if x.dtype.kind == "f":
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-6, equal_nan=True, err_msg=k)
    else:
        np.testing.assert_array_equal(x, y, err_msg=k)


def _same(a, b):
    assert a.labels == b.labels and a.reference == b.reference
    for k in flight_model.PER_FRAME + ("residual_m", "outlier", "order", "track_heading_rad", "speed_m_per_frame"):
        _close(getattr(a, k), getattr(b, k), k)
    for k in a.components:
        _close(a.components[k], b.components[k], k)
    assert [(f.first, f.last, f.kind) for f in a.faults] == [(f.first, f.last, f.kind) for f in b.faults]
    np.testing.assert_allclose([f.value for f in a.faults], [f.value for f in b.faults], rtol=0, atol=1e-6)
    assert a.summary_markdown() == b.summary_markdown() and a.outlier_markdown() == b.outlier_markdown()


def test_a_flight_grown_in_batches_is_the_flight_built_at_once():
    scn = flight_model.default_flight_scenario()
    recs, fov = scn.records, scn.frame_fov_deg
    whole = flight_model.build(scn, fov_deg=fov)
    assert len(whole.faults) == 3  # the example's three planted runs: a test that can see a difference
    m = None
    cuts = [0, 1, 40, 103, 150, 201, 252, len(recs)]  # cuts inside the runs (100-109, 200-204, 250-256)
    for a, b in zip(cuts[:-1], cuts[1:]):
        new = flight_model.build(_scn(scn, recs[a:b]), enu=scn.enu, fov_deg=fov[a:b], diagnose_faults=False)
        m = flight_model.extend(m, new, _scn(scn, recs[:b]))
    _same(m, whole)


def test_a_window_keeps_the_newest_frames_derived_again():
    scn = flight_model.default_flight_scenario()
    recs, fov = scn.records, scn.frame_fov_deg
    keep = 120
    m = None
    for a, b in ((0, 100), (100, 180), (180, 260)):
        new = flight_model.build(_scn(scn, recs[a:b]), enu=scn.enu, fov_deg=fov[a:b], diagnose_faults=False)
        m = flight_model.extend(m, new, _scn(scn, recs[max(b - keep, 0) : b]), keep=keep)
    want = flight_model.build(_scn(scn, recs[140:260]), fov_deg=fov[140:260])
    _same(m, want)
