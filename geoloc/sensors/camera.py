"""Frame camera: pixel <-> line of sight [Q17 eq. 8, generalised].

Conventions: ``docs/conventions.md``. Pixels are (row i, column j), 1-based as
in [Q17] (pixel (1, 1) is the centre of the first pixel). In the camera frame S
(Z_S the line of sight, at zero gimbal angles S coincides with the aircraft
body frame), the line of sight through pixel (i, j) is

    d_S = [i - i0, j0 - j, f]          (f in pixels)

[Q17 eq. 8] with (i0, j0) = ((M+1)/2, (N+1)/2) and f = focal length / pixel
pitch; here (i0, j0) is a principal point and f a focal length in pixels.

Camera file (TOML), e.g. ``assets/cameras/qiao2017.toml``::

    focal_length_px = 166841.0   # focal length / pixel pitch
    principal_row = 1162.12      # i0, 1-based rows
    principal_col = 1146.42      # j0, 1-based columns
    rows = 2323                  # M
    cols = 2292                  # N
    pixel_pitch_m = 7.0e-6       # optional: gives the sensor size in metres
    name = "..."                 # optional
    boresight_deg = [0.0, 0.0, 0.0]  # optional: camera in the inner gimbal (R_cam_inner)
    mount_deg = [0.0, 0.22, 0.0]     # optional: gimbal base in the aircraft body (R_base_body)

The two optional calibration rotations (written by ``geoloc calibrate
--write-camera``, see ``docs/calibration.md``) are three small angles
(x, y, z) in degrees, each giving the passive rotation
``rx(x) @ ry(y) @ rz(z)`` (``docs/conventions.md``):

- ``boresight_deg``: ``R_cam_inner``, the camera (optical axes) relative to
  the inner gimbal frame, ``v_cam = R_cam_inner @ v_inner``;
- ``mount_deg``: ``R_base_body``, the gimbal base relative to the aircraft
  body (POS) axes, ``v_base = R_base_body @ v_body``.

They enter the frame chain of :class:`geoloc.frames.chain.FrameChain` exactly where
its ``R_cam_inner`` / ``R_base_body`` hooks are (:meth:`Camera.chain`). Absent (the
default), the camera behaves as before.

A camera is a file format: every consumer takes its :class:`geoloc.sensors.frame.FrameSensor`
(:meth:`Camera.to_sensor`, a pinhole on the [Q17] roll-pitch gimbal). The paper's own
form of the chain, :class:`FrameChain` with its 4x4 hops ([Q17] eq. 4-9), stays here
as the reference the tests hold the sensor to: :meth:`Camera.chain` and
:meth:`Camera.chain_line_of_sight` (the first-phase ``line_of_sight(..., chain=)``).

Lens distortion: none in [Q17]; :meth:`Camera.undistort` /
:meth:`Camera.distort` are the hook (identity here) that a distortion model
overrides in a subclass.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames.chain import FrameChain, Pose
from geoloc.frames.rotations import rx, ry, rz
from geoloc.sensors.base import check_outside, flag_outside
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.tomlio import read_toml
from geoloc.userfiles import write_text

if TYPE_CHECKING:  # the sensor module imports this one
    from geoloc.sensors.base import Sensor
    from geoloc.sensors.frame import FrameSensor

#: What :func:`as_sensor` takes: a frame sensor, or a camera file's :class:`Camera` (made one).
#: Callers name this, not :class:`Camera`, which only the camera file format imports.
FrameSensorLike: TypeAlias = "FrameSensor | Camera"
#: What :func:`sensor_of` takes: any sensor, or a camera file's :class:`Camera`.
SensorLike: TypeAlias = "Sensor | Camera"


@dataclass(frozen=True)
class Camera:
    """Pinhole frame camera.

    Attributes
    ----------
    focal_length_px : float
        Focal length in pixels (f / a of [Q17 eq. 8]).
    principal_row, principal_col : float
        Principal point (i0, j0), 1-based pixel coordinates.
    rows, cols : int
        Sensor size M x N in pixels.
    pixel_pitch_m : float or None
        Pixel pitch a [m]; optional, only for the sensor size in metres.
    name : str
        Free text.
    boresight : tuple of 3 float or None
        Angles (x, y, z) [rad] of ``R_cam_inner = rx(x) @ ry(y) @ rz(z)``,
        the camera relative to the inner gimbal (file key ``boresight_deg``).
    mount : tuple of 3 float or None
        Angles (x, y, z) [rad] of ``R_base_body = rx(x) @ ry(y) @ rz(z)``,
        the gimbal base relative to the aircraft body (file key ``mount_deg``).
    """

    focal_length_px: float
    principal_row: float
    principal_col: float
    rows: int
    cols: int
    pixel_pitch_m: float | None = None
    name: str = ""
    boresight: tuple | None = None
    mount: tuple | None = None

    def __post_init__(self):
        def bad(field, value, why):
            raise ValueError(f"camera field {field} = {value!r}: {why}")

        f = self.focal_length_px
        if not (isinstance(f, (int, float)) and math.isfinite(f) and f > 0):
            bad("focal_length_px", f, "must be a finite number > 0")
        for k in ("principal_row", "principal_col"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                bad(k, v, "must be a finite number")
        for k in ("rows", "cols"):
            v = getattr(self, k)
            if not (isinstance(v, int) and not isinstance(v, bool) and v > 0):
                bad(k, v, "must be a positive integer")
        p = self.pixel_pitch_m
        if p is not None and not (isinstance(p, (int, float)) and math.isfinite(p) and p > 0):
            bad("pixel_pitch_m", p, "must be a finite number > 0 (metres)")
        for k in ("boresight", "mount"):
            v = getattr(self, k)
            if v is None:
                continue
            ok = (
                isinstance(v, (tuple, list))
                and len(v) == 3
                and all(
                    isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) and abs(a) <= math.pi
                    for a in v
                )
            )
            if not ok:
                bad(k, v, "must be three finite angles in [-pi, pi] radians")
            object.__setattr__(self, k, tuple(float(a) for a in v))

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> "Camera":
        """Load a camera file; unknown keys and missing keys are errors naming the key."""
        path = Path(path)
        data = read_toml(path, "camera file")
        return cls.from_dict(data, source=str(path))

    @classmethod
    def from_dict(cls, data: dict, source: str = "camera") -> "Camera":
        known = {
            "focal_length_px",
            "principal_row",
            "principal_col",
            "rows",
            "cols",
            "pixel_pitch_m",
            "name",
            "boresight_deg",
            "mount_deg",
        }
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(known)}")
        missing = [k for k in ("focal_length_px", "principal_row", "principal_col", "rows", "cols") if k not in data]
        if missing:
            raise ValueError(f"{source}: missing key(s) {missing}")
        data = dict(data)
        for k in ("boresight", "mount"):
            if f"{k}_deg" in data:
                v = data.pop(f"{k}_deg")
                if not (
                    isinstance(v, list)
                    and len(v) == 3
                    and all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in v)
                ):
                    raise ValueError(f"{source}: {k}_deg = {v!r}: must be a list of three numbers (degrees)")
                data[k] = tuple(math.radians(a) for a in v)
        return cls(**data)

    def to_toml(self, path: str | os.PathLike[str]) -> None:
        """Write the camera as TOML (the format of :meth:`from_toml`)."""
        lines = []
        for k, v in asdict(self).items():
            if v is None or (k == "name" and not v):
                continue
            if k in ("boresight", "mount"):
                lines.append(f"{k}_deg = [{', '.join(repr(math.degrees(a)) for a in v)}]")
                continue
            lines.append(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"')
        write_text(path, "\n".join(lines) + "\n")

    # ------------------------------------------------------------ geometry
    @staticmethod
    def _rotation(angles):

        if angles is None:
            return None
        x, y, z = angles
        return rx(x) @ ry(y) @ rz(z)

    @property
    def R_cam_inner(self) -> np.ndarray | None:
        """Boresight rotation inner gimbal -> camera (3, 3), or None if the camera has none."""
        return self._rotation(self.boresight)

    @property
    def R_base_body(self) -> np.ndarray | None:
        """Mounting rotation aircraft body -> gimbal base (3, 3), or None if the camera has none."""
        return self._rotation(self.mount)

    @property
    def center_pixel(self) -> tuple[float, float]:
        """CCD centre ((M+1)/2, (N+1)/2) in 1-based pixels [Q17 eq. 8]."""
        return (self.rows + 1) / 2.0, (self.cols + 1) / 2.0

    @property
    def sensor_size_m(self) -> tuple[float, float] | None:
        """Sensor height and width in metres, if the pixel pitch is known."""
        if self.pixel_pitch_m is None:
            return None
        return self.rows * self.pixel_pitch_m, self.cols * self.pixel_pitch_m

    def undistort(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Distortion hook: measured pixel -> ideal pinhole pixel (identity: [Q17] has none)."""
        return np.asarray(row, float), np.asarray(col, float)

    def distort(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Distortion hook: ideal pinhole pixel -> measured pixel (identity)."""
        return np.asarray(row, float), np.asarray(col, float)

    def pixel_to_los(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        """Unit line-of-sight direction in the camera frame S [Q17 eq. 8, generalised].

        d_S = [i - i0, j0 - j, f] / |.|. Pixels outside the sensor are allowed
        (the geometry is the same); :meth:`in_image` tells.

        Parameters
        ----------
        row, col : array_like
            1-based pixel coordinates (i, j), broadcasting.

        Returns
        -------
        ndarray (..., 3)
        """
        i, j = self.undistort(row, col)
        i, j = np.broadcast_arrays(i, j)
        d = np.stack(
            [i - self.principal_row, self.principal_col - j, np.full(i.shape, float(self.focal_length_px))], axis=-1
        )
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def los_to_pixel(self, d_cam: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera-frame direction -> pixel (the inverse of :meth:`pixel_to_los`).

        Parameters
        ----------
        d_cam : array_like (..., 3)
            Direction in the camera frame (any length).

        Returns
        -------
        row, col : ndarray
            1-based pixel coordinates; NaN where the direction is behind the
            camera (z_S <= 0).
        status : ndarray of uint8
            OK or BEHIND_CAMERA.
        """
        d = np.asarray(d_cam, float)
        z = d[..., 2]
        behind = ~(z > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            i = self.principal_row + self.focal_length_px * d[..., 0] / z
            j = self.principal_col - self.focal_length_px * d[..., 1] / z
        i = np.where(behind, np.nan, i)
        j = np.where(behind, np.nan, j)
        i, j = self.distort(i, j)
        status = np.where(behind, Status.BEHIND_CAMERA, Status.OK).astype(np.uint8)
        return i, j, status

    def to_sensor(self) -> FrameSensor:
        """This camera as a :class:`geoloc.sensors.frame.FrameSensor`: a pinhole on the [Q17] ``roll-pitch`` gimbal.

        The lens's principal point is (cx, cy) = (j0 - 1, i0 - 1) in OpenCV's
        0-based pixels; mount and boresight carry over unchanged.
        """
        from geoloc.sensors.frame import FrameSensor
        from geoloc.sensors.lenses import PinholeLens

        f = float(self.focal_length_px)
        lens = PinholeLens(
            fx=f,
            fy=f,
            cx=float(self.principal_col) - 1.0,
            cy=float(self.principal_row) - 1.0,
            width=int(self.cols),
            height=int(self.rows),
        )
        return FrameSensor(
            lens,
            mount=self.mount or (0.0, 0.0, 0.0),
            boresight=self.boresight or (0.0, 0.0, 0.0),
            name=self.name,
            pixel_pitch_m=self.pixel_pitch_m,
        )

    def chain(self, pose: Pose) -> FrameChain:
        """The [Q17] frame chain of ``pose`` with this camera's boresight and mounting rotations.

        The paper's own form of the roll-pitch chain (:class:`geoloc.frames.chain.FrameChain`,
        eq. 4-9, with its 4x4 hops and the eq. 5 factors); the sensor's frame graph gives the
        same rotations (``tests/sensors/test_sensors.py``).
        """

        return FrameChain(pose, R_cam_inner=self.R_cam_inner, R_base_body=self.R_base_body)

    def chain_line_of_sight(
        self, pose: Pose, row: ArrayLike, col: ArrayLike, chain: FrameChain | None = None, outside: str = "flag"
    ) -> LineOfSight:
        """The [Q17] reference line of sight: pixel -> eq. 8 -> the :class:`FrameChain` (eq. 9).

        Parameters
        ----------
        pose : geoloc.frames.chain.Pose
        row, col : array_like
            1-based pixels.
        chain : FrameChain, optional
            A prebuilt chain (Monte Carlo's reference passes one with batched, perturbed
            rotations: :func:`geoloc.analysis.montecarlo.perturbed_geometry`); default
            :meth:`chain` of ``pose``.
        outside : {"flag", "extrapolate"}
            A pixel off the sensor gets OUTSIDE_SENSOR, or its ray beyond the edge.

        Returns
        -------
        geoloc.surfaces.base.LineOfSight
        """

        check_outside(outside)
        chain = self.chain(pose) if chain is None else chain
        d_ecef = chain.cam_to_ecef(self.pixel_to_los(row, col))
        o = chain.origin_ecef
        shape = np.broadcast_shapes(o.shape, d_ecef.shape)[:-1]
        o, d_ecef = np.broadcast_to(o, shape + (3,)), np.broadcast_to(d_ecef, shape + (3,))
        bad = np.broadcast_to(pose.invalid_mask(), shape) | ~np.all(np.isfinite(d_ecef), axis=-1)
        status = np.where(bad, Status.INVALID_INPUT, Status.OK).astype(np.uint8)
        if outside == "flag":
            r, c = np.broadcast_to(np.asarray(row, float), shape), np.broadcast_to(np.asarray(col, float), shape)
            status = flag_outside(status, r, c, self.rows, self.cols)
        return LineOfSight(o, d_ecef, status)

    def in_image(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        """True where (row, col) lies on the sensor: 0.5 <= i <= M + 0.5, same for j."""
        row, col = np.asarray(row, float), np.asarray(col, float)
        return (row >= 0.5) & (row <= self.rows + 0.5) & (col >= 0.5) & (col <= self.cols + 0.5)


def camera_from_sensor(sensor: Any, pixel_pitch_m: float | None = None) -> Camera:
    """The camera file of a :class:`geoloc.sensors.frame.FrameSensor`: the inverse of :meth:`Camera.to_sensor`.

    How a fitted sensor is written back as a first-phase camera file
    (``geoloc calibrate --write-camera``): the sensor must be what a camera file can
    say, a distortion-free pinhole with ``fx == fy`` and no skew on the [Q17]
    ``roll-pitch`` gimbal with no lever arm; anything else is a ValueError naming the
    field and its value (write a sensor file instead). Zero mount / boresight angles
    are left out of the file. ``pixel_pitch_m``: default the sensor's own (a camera
    file's sensor carries the file's pitch; a sensor file's has none).
    """
    from geoloc.sensors.frame import FrameSensor
    from geoloc.sensors.gimbals import PRESETS
    from geoloc.sensors.lenses import PinholeLens

    def bad(field, value, why):
        raise ValueError(
            f"sensor {sensor.name or 'frame camera'}: {field} = {value!r}: {why}; a camera file "
            "cannot hold it (write a sensor file, --write-sensor)"
        )

    if not isinstance(sensor, FrameSensor):
        raise ValueError(f"sensor = {sensor!r}: only a FrameSensor can be written as a camera file")
    lens = sensor.lens
    if type(lens) is not PinholeLens:
        bad("lens", type(lens).__name__, "a camera file is a distortion-free pinhole")
    if float(lens.fx) != float(lens.fy):
        bad("lens.fy", float(lens.fy), f"a camera file has one focal length (fx = {float(lens.fx)!r})")
    if float(lens.skew) != 0.0:
        bad("lens.skew", float(lens.skew), "a camera file has no skew")
    q17 = PRESETS["roll-pitch"]
    g = sensor.gimbal
    if not (
        g is q17 or (g.joints == q17.joints and not g.earth_referenced and np.array_equal(g.R_opt_last, q17.R_opt_last))
    ):
        bad("gimbal", sensor.gimbal.name, "a camera file is on the [Q17] roll-pitch gimbal")
    if any(float(v) != 0.0 for v in sensor.lever_arm_m):
        bad("lever_arm_m", tuple(sensor.lever_arm_m), "a camera file has no lever arm")

    def angles(v):
        v = tuple(float(a) for a in v)
        return None if all(a == 0.0 for a in v) else v

    return Camera(
        focal_length_px=float(lens.fx),
        principal_row=float(lens.cy) + 1.0,
        principal_col=float(lens.cx) + 1.0,
        rows=int(lens.height),
        cols=int(lens.width),
        pixel_pitch_m=sensor.pixel_pitch_m if pixel_pitch_m is None else pixel_pitch_m,
        name=sensor.name,
        boresight=angles(sensor.boresight),
        mount=angles(sensor.mount),
    )


@lru_cache(maxsize=64)
def _camera_sensor(camera: Camera):
    return camera.to_sensor()


def as_sensor(sensor: Any) -> FrameSensor:
    """The :class:`geoloc.sensors.frame.FrameSensor` of a frame sensor or a first-phase :class:`Camera`.

    The one place a camera file's :class:`Camera` becomes its sensor (cached, so a
    caller may ask for it at every call); :func:`geoloc.locate.as_sensor` is this.
    ValueError for anything else.
    """
    from geoloc.sensors.frame import FrameSensor

    if isinstance(sensor, FrameSensor):
        return sensor
    if isinstance(sensor, Camera):
        return _camera_sensor(sensor)
    raise ValueError(f"sensor = {sensor!r}: must be a FrameSensor or a Camera")


def sensor_of(sensor: Any) -> Any:
    """Any sensor as itself, a first-phase :class:`Camera` as its :class:`FrameSensor` (:func:`as_sensor`)."""
    return _camera_sensor(sensor) if isinstance(sensor, Camera) else sensor
