"""The video of a MISB ST 0601 stream against its KLV: marks in the frames, the time offset fitted.

A STANAG 4609 MPEG-TS carries the video and the KLV metadata on one clock (the
container PTS). Given surveyed points visible in the frames (painted crosses, ground
control points), this module

* finds them in the decoded frames (:func:`frame_marks`:
  :func:`geoloc.workflows.render.find_marks` on each frame of
  :class:`geoloc.io.images.VideoFrames`), and
* predicts where the metadata puts them (:func:`klv_predictor`: the KLV poses
  interpolated to any time, :func:`geoloc.analysis.time_offset.interpolate_pose_deg`,
  the frame's sensor ``lens_from_fov`` of the packet's fields of view at the video's
  size on the ``azimuth-elevation-roll`` gimbal, :func:`geoloc.workflows.klv_replay.klv_sensor`'s
  rule, and ``ground_to_pixel``), so that
* :func:`fit_klv_time_offset` fits the stream's ``time_offset_s`` (video time =
  metadata time + offset) on chosen frames, and :func:`mark_offsets` gives, per
  frame, how far each mark seen lies from its prediction at the packet's own time:
  a heading bias shows as the marks turned away from their predictions, a timing
  fault as marks displaced by the motion over the offset.

Heights are ellipsoidal (WGS 84) throughout.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.analysis.time_offset import TimeOffsetFit, fit_time_offset, interpolate_pose_deg
from geoloc.frames.chain import Pose

if TYPE_CHECKING:
    from geoloc.io.images import ImageSource, VideoFrames
    from geoloc.sensors.frame import FrameSensor
    from geoloc.workflows.klv_replay import KlvReplay

__all__ = ["KlvPredictor", "klv_predictor", "frame_marks", "fit_klv_time_offset", "mark_offsets"]


@dataclass
class KlvPredictor:
    """Where the KLV metadata puts points ``(lat, lon, h)`` in the video's frames, at any time.

    Call it with metadata times [s on the container clock], shape (n,): it returns (n, p, 2)
    1-based ``(row, col)`` (NaN behind the camera, without metadata, or outside the packets' span).
    """

    times_s: np.ndarray  # the packets' PTS [s] (packets with a complete pose)
    pose_deg: dict  # their poses (klv_pose_deg), arrays
    fov_deg: np.ndarray  # (k, 2) their fields of view (horizontal, vertical) [deg]
    lat: np.ndarray  # (p,) [rad]
    lon: np.ndarray
    h_m: np.ndarray  # (p,) ellipsoidal [m]
    rows: int
    cols: int

    def sensor(self, hfov_deg: float, vfov_deg: float) -> FrameSensor:
        from geoloc.sensors.frame import FrameSensor
        from geoloc.sensors.gimbals import PRESETS
        from geoloc.sensors.lenses import lens_from_fov

        return FrameSensor(
            lens_from_fov(math.radians(hfov_deg), math.radians(vfov_deg), self.cols, self.rows),
            PRESETS["azimuth-elevation-roll"],
        )

    def __call__(self, t_s: ArrayLike) -> NDArray[np.float64]:

        t = np.atleast_1d(np.asarray(t_s, float))
        p = interpolate_pose_deg(self.times_s, self.pose_deg, t)
        col = lambda a: np.asarray(a, float)[:, None]  # noqa: E731  (n, 1) against the points (1, p)
        pose = Pose.from_deg(
            col(p["lat_deg"]),
            col(p["lon_deg"]),
            col(p["h_m"]),
            col(p["heading_deg"]),
            col(p["pitch_deg"]),
            col(p["roll_deg"]),
            angles_deg={k: col(v) for k, v in p["angles_deg"].items()},
        )
        # the fields of view of the packet at or before each time (they change in steps: a zoom)
        k = np.clip(
            np.searchsorted(self.times_s, np.where(np.isfinite(t), t, self.times_s[0]), "right") - 1,
            0,
            len(self.times_s) - 1,
        )
        out = np.full((len(t), len(self.lat), 2), np.nan)
        fov = self.fov_deg[k]
        for hv in np.unique(fov, axis=0):
            sel = np.flatnonzero(np.all(fov == hv, axis=1))
            px = self.sensor(*hv).ground_to_pixel(self.lat[None], self.lon[None], self.h_m[None], pose.take(sel))
            good = np.isfinite(px.row) & np.isfinite(px.col)
            out[sel, :, 0] = np.where(good, px.row, np.nan)
            out[sel, :, 1] = np.where(good, px.col, np.nan)
        return out


def klv_predictor(replay: KlvReplay, points_deg: ArrayLike, rows: int, cols: int) -> KlvPredictor:
    """A :class:`KlvPredictor` from a KLV replay (:func:`geoloc.workflows.klv_replay.replay_klv` of
    the MPEG-TS, its ``columns`` with ``pts_s``) for points ``[(lat_deg, lon_deg, h_m), ...]``
    (ellipsoidal heights) in a ``rows x cols`` video. Packets without a complete pose or fields of
    view are left out."""
    from geoloc.workflows.klv_replay import klv_pose_deg

    c = replay.columns
    pd = klv_pose_deg(c)
    t = np.asarray(c["pts_s"], float)
    fov = np.stack(
        [np.asarray(c["sensor_horizontal_fov_deg"], float), np.asarray(c["sensor_vertical_fov_deg"], float)], -1
    )
    arrays = [pd[k] for k in ("lat_deg", "lon_deg", "h_m", "heading_deg", "pitch_deg", "roll_deg")]
    arrays += [pd["angles_deg"][k] for k in ("azimuth", "elevation")]
    ok = np.isfinite(t) & np.all(np.isfinite(np.stack(arrays)), axis=0) & np.all(np.isfinite(fov), axis=1)
    if ok.sum() < 2:
        raise ValueError(
            f"{getattr(replay.summary, 'source', 'KLV')}: fewer than two packets with a pose, "
            "fields of view and a container time stamp"
        )
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(t[idx], kind="stable")]
    keep = np.concatenate([[True], np.diff(t[idx]) > 0])
    idx = idx[keep]
    sub = {k: np.asarray(v)[idx] for k, v in pd.items() if k != "angles_deg"}
    sub["angles_deg"] = {k: np.asarray(v)[idx] for k, v in pd["angles_deg"].items()}
    pts = np.asarray(points_deg, float).reshape(-1, 3)
    return KlvPredictor(
        t[idx], sub, fov[idx], np.deg2rad(pts[:, 0]), np.deg2rad(pts[:, 1]), pts[:, 2], int(rows), int(cols)
    )


def frame_marks(images: ImageSource, frames: Iterable[int]) -> list[NDArray[np.float64]]:
    """The painted marks (:func:`geoloc.workflows.render.find_marks`) in each of ``frames`` (indices)
    of an image source: a list of (m, 2) arrays of 1-based ``(row, col)``."""
    from geoloc.workflows.render import find_marks

    return [find_marks(images.image(int(k)))[0] for k in frames]


def fit_klv_time_offset(
    ts_path: str | os.PathLike[str],
    points_deg: ArrayLike,
    frames: ArrayLike,
    *,
    bounds_s: tuple[float, float] = (-3.0, 3.0),
    step_s: float = 0.05,
    gate_px: float = 40.0,
    replay: KlvReplay | None = None,
    images: VideoFrames | None = None,
) -> TimeOffsetFit:
    """Fit the MPEG-TS's metadata-to-video ``time_offset_s`` on ``frames`` (video frame indices).

    Parameters
    ----------
    ts_path : path
        An MPEG-TS (STANAG 4609: video + KLV data stream).
    points_deg : sequence of (lat_deg, lon_deg, h_m)
        Surveyed points painted (or visible) in the frames, heights ellipsoidal (WGS 84).
    frames : sequence of int
        The frames to fit on (a run suspected of a timing fault).
    bounds_s, step_s, gate_px :
        Those of :func:`geoloc.analysis.time_offset.fit_time_offset`.
    replay, images : optional
        The stream's :func:`~geoloc.workflows.klv_replay.replay_klv` and
        :func:`~geoloc.io.images.open_images`, when already open.

    Returns
    -------
    TimeOffsetFit
        ``time_offset_s``: apply it with ``images.with_time_offset(fit.time_offset_s)``.
    """
    from geoloc.io.images import VideoFrames, open_images
    from geoloc.workflows.klv_replay import replay_klv

    video = open_images(ts_path) if images is None else images
    if not isinstance(video, VideoFrames):  # a still picture has no frames' time stamps to fit
        raise ValueError(f"{ts_path}: not a video with time-stamped frames (an MPEG-TS with a KLV stream)")
    replay = replay_klv(ts_path) if replay is None else replay
    idx = np.asarray(frames, int)
    pred = klv_predictor(replay, points_deg, video.rows, video.cols)
    pts = np.asarray(video.pts_s, float)[idx]
    return fit_time_offset(pts, frame_marks(video, idx), pred, bounds_s=bounds_s, step_s=step_s, gate_px=gate_px)


def mark_offsets(observed_px: ArrayLike, predicted_px: ArrayLike, gate_px: float = 40.0) -> NDArray[np.float64]:
    """Each predicted point's offset to the nearest observed mark, ``observed - predicted``
    [px, (row, col)], shape (p, 2); NaN when no mark lies within ``gate_px`` or no prediction."""
    o = np.asarray(observed_px, float).reshape(-1, 2)
    p = np.asarray(predicted_px, float).reshape(-1, 2)
    out = np.full(p.shape, np.nan)
    if len(o) == 0:
        return out
    d = o[None, :, :] - p[:, None, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    dist = np.where(np.isfinite(dist), dist, np.inf)
    j = np.argmin(dist, axis=1)
    near = dist[np.arange(len(p)), j] <= gate_px
    out[near] = d[np.flatnonzero(near), j[near]]
    return out
