"""The time offset's fit (geoloc.analysis.time_offset) on marks whose motion is written in closed form.

A mark moves on a straight line across the image at a known speed, so the pixel at any metadata
time is a line written here; the frames see it ``d`` seconds late. The fit must give ``d``, the
rms at the fit 0 (the observations are exact), and the rms at offset 0 the speed times ``d``,
each worked by hand: no geoloc model makes the expected values.
"""

import math

import numpy as np
import pytest

from geoloc.analysis.time_offset import fit_time_offset, interpolate_pose_deg

#: The mark's pixel at metadata time t: row 100 + 50 t, col 200 + 30 t [px]; speed sqrt(50^2 + 30^2).
V_ROW, V_COL = 50.0, 30.0


def _predict(t):
    t = np.asarray(t, float)
    return np.stack([100.0 + V_ROW * t, 200.0 + V_COL * t], axis=-1)[:, None, :]  # (n, 1 point, 2)


def _frames(d, pts):
    """What frame k shows: the mark at metadata time pts_k - d (video time = metadata time + d)."""
    return [_predict(np.array([p - d]))[0] for p in pts]


@pytest.mark.parametrize("d", [0.123, -0.4567])
def test_the_offset_between_grid_points_is_found_and_the_fit_is_exact(d):
    pts = np.linspace(0.0, 2.0, 9)
    fit = fit_time_offset(pts, _frames(d, pts), _predict)  # the default bounds (-3 s, 3 s), step 0.05 s
    # the cost is quadratic in the offset near the minimum: the bounded search's xatol (1e-4 s)
    # bounds the error; 2e-4 s is 0.012 px of this mark's motion
    assert fit.time_offset_s == pytest.approx(d, abs=2e-4)
    assert fit.rms_px < 0.02  # 2e-4 s x 58.3 px/s
    # at offset 0 every frame's mark is |v| d away from its prediction (under the 40 px gate)
    assert fit.rms_at_zero_px == pytest.approx(math.hypot(V_ROW, V_COL) * abs(d), rel=1e-12)
    assert (fit.n_frames, fit.n_marks) == (9, 9)
    assert fit.grid_s[0] == pytest.approx(-3.0) and fit.grid_s[-1] == pytest.approx(3.0)
    assert len(fit.grid_s) == 121 and len(fit.cost_grid) == 121


def test_one_mark_in_one_frame_is_enough_and_a_gate_below_one_pixel_is_allowed():
    pts = np.array([0.0, 1.0])
    obs = [np.empty((0, 2)), _frames(0.2, [1.0])[0]]
    fit = fit_time_offset(pts, obs, _predict, gate_px=0.5)
    assert fit.n_marks == 1 and fit.time_offset_s == pytest.approx(0.2, abs=2e-4)
    # at offset 0 the one mark is 58.3 * 0.2 = 11.7 px away: capped at the gate, cost 0.25, rms 0.5
    assert fit.rms_at_zero_px == pytest.approx(0.5, rel=1e-12)


def test_a_far_mark_costs_the_gate_squared():
    pts = np.array([0.0])
    far = [np.array([[1000.0, 1000.0], [100.0, 200.0]])]  # one mark far from everything, one on the line at t = 0
    fit = fit_time_offset(pts, far, _predict, bounds_s=(-0.1, 0.1), gate_px=40.0)
    assert fit.time_offset_s == pytest.approx(0.0, abs=2e-4)
    assert fit.rms_at_zero_px == pytest.approx(math.sqrt((40.0**2 + 0.0) / 2), rel=1e-12)


def test_bad_arguments_are_refused_by_name():
    pts = np.array([0.0, 1.0])
    obs = _frames(0.0, pts)
    with pytest.raises(ValueError, match="no mark in any frame"):
        fit_time_offset(pts, [np.empty((0, 2)), np.empty((0, 2))], _predict)
    with pytest.raises(ValueError, match="gate_px"):
        fit_time_offset(pts, obs, _predict, gate_px=0.0)
    with pytest.raises(ValueError, match="step_s"):
        fit_time_offset(pts, obs, _predict, step_s=0.0)
    with pytest.raises(ValueError, match="bounds_s"):
        fit_time_offset(pts, obs, _predict, bounds_s=(1.0, 1.0))
    with pytest.raises(ValueError, match="1 frames for 2 time stamps"):
        fit_time_offset(pts, obs[:1], _predict)
    with pytest.raises(ValueError, match="frame_pts_s"):
        fit_time_offset(np.array([0.0, np.nan]), obs, _predict)


def test_interpolated_pose_is_linear_and_takes_angles_the_short_way():
    t = np.array([0.0, 1.0, 3.0])
    pose = {
        "lat_deg": np.array([36.0, 36.1, 36.3]),
        "lon_deg": np.array([-84.0, -84.2, -84.6]),
        "h_m": np.array([1000.0, 1010.0, 1030.0]),
        "heading_deg": np.array([350.0, 10.0, 30.0]),  # across north: +20 deg, not -340
        "pitch_deg": np.array([0.0, 2.0, 6.0]),
        "roll_deg": np.array([-179.0, 179.0, 177.0]),  # across +-180: -2 deg
        "angles_deg": {"azimuth": np.array([0.0, 90.0, 270.0])},
    }
    got = interpolate_pose_deg(t, pose, np.array([0.5, 2.0, -0.1, 3.1]))
    assert got["lat_deg"][:2] == pytest.approx([36.05, 36.2], abs=1e-12)
    assert got["h_m"][:2] == pytest.approx([1005.0, 1020.0], abs=1e-9)
    assert got["heading_deg"][0] % 360.0 == pytest.approx(0.0, abs=1e-9)
    assert got["roll_deg"][0] % 360.0 == pytest.approx(180.0, abs=1e-9)
    assert got["angles_deg"]["azimuth"][1] == pytest.approx(180.0, abs=1e-9)
    for k in ("lat_deg", "lon_deg", "h_m", "heading_deg", "pitch_deg", "roll_deg"):
        assert np.isnan(got[k][2:]).all()  # no extrapolation
    with pytest.raises(ValueError, match="increasing"):
        interpolate_pose_deg([0.0, 0.0], pose, 0.0)
