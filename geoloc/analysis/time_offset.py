"""The metadata-to-video time offset: interpolated poses and the offset's fit from image marks.

A video's frames and its metadata (MISB ST 0601 KLV) share a clock, the container's
presentation time stamps, but an encoder, a multiplexer or a sensor's own latency
can put the pictures ahead of (or behind) the metadata that describes them. The
offset is a named parameter of the stream, ``time_offset_s``
(:class:`geoloc.io.images.VideoFrames`): *video time = metadata time + offset*, so
the frame with PTS ``p`` shows the scene the metadata describes at time
``p - time_offset_s``.

:func:`fit_time_offset` fits it as any other parameter is fitted: from points seen
in the frames (the centres of painted or surveyed marks, 1-based pixels) and a
model that predicts where those points are in the image at a metadata time (the
surveyed positions reprojected through the sensor with the metadata's pose,
:func:`interpolate_pose_deg` between packets). The cost is the sum over frames
and marks of the squared pixel distance from each observed mark to the nearest
predicted one (capped at ``gate_px``, so a mark with no counterpart costs a
constant instead of dragging the fit); it is scanned on a grid of offsets (the
pose is piecewise linear in time, so the cost has kinks at whole packet steps and
may have local minima), then refined by a bounded scalar minimisation around the
best grid point.

Layer 6 (``analysis``): no viewer, no workflow.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["interpolate_pose_deg", "fit_time_offset", "TimeOffsetFit", "ANGLE_KEYS", "LINEAR_KEYS"]

#: Pose keys (those of :meth:`geoloc.frames.chain.Pose.from_deg`) interpolated linearly.
LINEAR_KEYS = ("lat_deg", "lon_deg", "h_m")
#: Pose keys interpolated as angles, the shorter way round.
ANGLE_KEYS = ("heading_deg", "pitch_deg", "roll_deg")


def _interp_angle(t, tk, v):
    """Linear interpolation of angles [deg] the shorter way (unwrapped first)."""
    u = np.rad2deg(np.unwrap(np.deg2rad(v)))
    return np.interp(t, tk, u)


def interpolate_pose_deg(times_s: ArrayLike, pose_deg: dict[str, Any], t_s: ArrayLike) -> dict[str, Any]:
    """The pose at times ``t_s``, linear between the samples at ``times_s`` (a packet's pose).

    Parameters
    ----------
    times_s : array (n,)
        Increasing sample times [s] (the metadata packets' time stamps).
    pose_deg : dict
        The keyword arguments of :meth:`geoloc.frames.chain.Pose.from_deg` for the n samples
        (``lat_deg, lon_deg, h_m`` and the attitude ``heading_deg, pitch_deg, roll_deg`` as
        arrays, ``angles_deg`` a dict of arrays: the gimbal's joint angles), as
        :func:`geoloc.workflows.klv_replay.klv_pose_deg` gives them. Heights keep their datum
        (ellipsoidal for a ``Pose``).
    t_s : array_like
        Times [s] to interpolate at. Outside ``[times_s[0], times_s[-1]]``: NaN (no extrapolation).

    Returns
    -------
    dict
        The same keys, arrays of ``np.shape(t_s)``. Angles (attitude and joint angles) are
        interpolated the shorter way round; positions linearly in latitude, longitude and
        height (over a second of flight the error of linear interpolation in geodetic
        coordinates is micrometres).
    """
    tk = np.asarray(times_s, float)
    if tk.ndim != 1 or len(tk) < 2 or not np.all(np.diff(tk) > 0):
        raise ValueError("times_s must be at least two increasing sample times")
    t = np.asarray(t_s, float)
    out = np.isnan(t) | (t < tk[0]) | (t > tk[-1])
    tc = np.where(out, tk[0], t)
    nan = np.where(out, np.nan, 0.0)
    res = {}
    for k in LINEAR_KEYS:
        res[k] = np.interp(tc, tk, np.asarray(pose_deg[k], float)) + nan
    for k in ANGLE_KEYS:
        res[k] = _interp_angle(tc, tk, np.asarray(pose_deg[k], float)) + nan
    res["angles_deg"] = {
        k: _interp_angle(tc, tk, np.asarray(v, float)) + nan for k, v in (pose_deg.get("angles_deg") or {}).items()
    }
    return res


@dataclass
class TimeOffsetFit:
    """The fitted metadata-to-video offset.

    Attributes
    ----------
    time_offset_s : float
        The fitted ``time_offset_s`` [s] (video time = metadata time + offset).
    rms_px : float
        Root mean square distance from each observed mark to its nearest prediction at the
        fitted offset [px] (capped terms included).
    rms_at_zero_px : float
        The same with the offset 0 (what a reader that trusts the time stamps sees).
    n_frames, n_marks : int
        Frames and observed marks used.
    grid_s, cost_grid : ndarray
        The scanned offsets and the mean squared distance at each [px^2].
    """

    time_offset_s: float
    rms_px: float
    rms_at_zero_px: float
    n_frames: int
    n_marks: int
    grid_s: np.ndarray
    cost_grid: np.ndarray

    def __str__(self) -> str:
        return (
            f"time_offset_s = {self.time_offset_s:+.3f} s (video time = metadata time + offset) from "
            f"{self.n_marks} marks in {self.n_frames} frames: rms {self.rms_px:.2f} px "
            f"(at offset 0: {self.rms_at_zero_px:.2f} px)"
        )


def fit_time_offset(
    frame_pts_s: ArrayLike,
    observed_px: Sequence[ArrayLike],
    predict_px: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    *,
    bounds_s: tuple[float, float] = (-3.0, 3.0),
    step_s: float = 0.05,
    gate_px: float = 40.0,
) -> TimeOffsetFit:
    """Fit ``time_offset_s`` from marks seen in frames and their predicted pixels.

    Parameters
    ----------
    frame_pts_s : array (n,)
        Each frame's presentation time [s] on the metadata's clock with offset 0 (its PTS).
    observed_px : sequence of n arrays (m_k, 2)
        The marks seen in frame k, 1-based ``(row, col)`` (e.g.
        :func:`geoloc.workflows.render.find_marks`); no correspondence needed.
    predict_px : callable
        ``predict_px(t_s)`` with ``t_s`` an array (n,) of metadata times returns an array
        (n, p, 2) of the p points' predicted pixels in each frame at those times (NaN where
        not in the image or no metadata).
    bounds_s : (float, float)
        Offsets searched [s].
    step_s : float
        Grid step of the scan [s]; the refinement searches one step each side of the best.
    gate_px : float
        Cap of one mark's distance [px] (a mark farther than this from every prediction
        costs ``gate_px ** 2``).

    Returns
    -------
    TimeOffsetFit
    """
    from scipy.optimize import minimize_scalar

    pts = np.asarray(frame_pts_s, float)
    if pts.ndim != 1 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise ValueError("frame_pts_s must be a non-empty 1-d array of finite times")
    if len(observed_px) != len(pts):
        raise ValueError(f"observed_px: {len(observed_px)} frames for {len(pts)} time stamps")
    lo, hi = (float(b) for b in bounds_s)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"bounds_s = {bounds_s!r}: need two finite offsets, low < high")
    if not (step_s > 0 and gate_px > 0):
        raise ValueError(f"step_s = {step_s!r}, gate_px = {gate_px!r}: both must be positive")
    obs = [np.asarray(o, float).reshape(-1, 2) for o in observed_px]
    n_marks = sum(len(o) for o in obs)
    if n_marks == 0:
        raise ValueError("observed_px: no mark in any frame")
    g2 = float(gate_px) ** 2

    def cost(d: float) -> float:
        pred = np.asarray(predict_px(pts - d), float)  # frame k shows metadata time pts_k - d
        total = 0.0
        for k, o in enumerate(obs):
            if len(o) == 0:
                continue
            p = pred[k]
            d2 = np.sum((o[:, None, :] - p[None, :, :]) ** 2, axis=-1)
            d2 = np.where(np.isfinite(d2), d2, np.inf)
            total += float(np.sum(np.minimum(d2.min(axis=1) if d2.shape[1] else np.full(len(o), np.inf), g2)))
        return total / n_marks

    grid = np.arange(lo, hi + 0.5 * step_s, step_s)
    cg = np.array([cost(d) for d in grid])
    k = int(np.argmin(cg))
    a, b = max(lo, grid[k] - step_s), min(hi, grid[k] + step_s)
    r = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-4})
    best, c = (float(r.x), float(r.fun)) if r.fun <= cg[k] else (float(grid[k]), float(cg[k]))
    return TimeOffsetFit(best, float(np.sqrt(c)), float(np.sqrt(cost(0.0))), len(pts), n_marks, grid, cg)
