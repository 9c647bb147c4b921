"""The frame camera on a gimbal: lens, gimbal joints, mount, boresight and lever arm.

The chain, outermost first (``docs/architecture.md``)::

    ecef <- ned <- body <- gimbal_base <- joint frames ... <- cam
           [Q17 eq. 4-5]  [eq. 6]  mount+lever arm  gimbal   boresight, optical turn

* ``ned``: at the navigation reference (the POS / INS output position).
* ``body``: X nose, Y right wing, Z down; attitude z-y-x [Q17 eq. 6].
* ``gimbal_base``: the body turned by the **mount** rotation
  ``R_base_body = rx(x) ry(y) rz(z)`` (the camera file's ``mount_deg``), its
  origin the optical centre: the body origin plus the **lever arm** (body axes, m).
* the gimbal's revolute joints (:mod:`geoloc.sensors.gimbals`); an
  earth-referenced gimbal's first joint hangs off ``ned`` instead.
* ``cam``: the optical frame of the lens (x right, y down, z forward), after the
  **boresight** rotation ``rx(x) ry(y) rz(z)`` in the last joint frame
  (``boresight_deg``) and the gimbal's fixed turn to the optical axes.

Pixels at this interface are 1-based pixel centres ``(row, col)``; the lens
works in OpenCV's 0-based ``(u, v) = (col - 1, row - 1)``
(``docs/conventions.md``, "Pixels").

For the ``roll-pitch`` preset with a pinhole lens this is exactly [Q17 eq. 4-9]
(the tests hold it to :class:`geoloc.frames.chain.FrameChain`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.frames.graph import BoundFrames, FrameGraph, Joint
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.sensors.base import (
    COMPILED_MIN_RAYS,
    PixelHit,
    check_outside,
    check_param_names,
    flag_outside,
    in_sensor,
)
from geoloc.sensors.gimbals import DEFAULT, PRESETS, Gimbal
from geoloc.sensors.lenses import Lens
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight

#: Names of the sensor's own (non-lens) parameters, SI units (radians, metres).
OWN_PARAMS = (
    "mount_x",
    "mount_y",
    "mount_z",
    "boresight_x",
    "boresight_y",
    "boresight_z",
    "lever_arm_x_m",
    "lever_arm_y_m",
    "lever_arm_z_m",
)


def small_rotation(angles: Sequence[float]) -> np.ndarray:
    """``rx(x) @ ry(y) @ rz(z)`` of three angles [rad] (mount and boresight, ``docs/conventions.md``)."""
    x, y, z = angles
    return rot.rx(x) @ rot.ry(y) @ rot.rz(z)


def _three(name, v):
    v = tuple(float(a) for a in v)
    if len(v) != 3 or not all(math.isfinite(a) for a in v):
        raise ValueError(f"sensor field {name} = {v!r}: must be three finite numbers")
    return v


@dataclass(frozen=True)
class FrameSensor:
    """A frame camera on a gimbal (see the module docstring).

    Attributes
    ----------
    lens : geoloc.sensors.lenses.Lens
    gimbal : Gimbal
        Default the [Q17] ``roll-pitch`` preset.
    mount : tuple of 3 float
        Angles (x, y, z) [rad] of ``R_base_body`` (gimbal base in the body).
    boresight : tuple of 3 float
        Angles (x, y, z) [rad] of the camera in the last joint frame.
    lever_arm_m : tuple of 3 float
        Optical centre minus navigation reference, body axes [m].
    name : str
    platform : str
        What carries the camera (the sensor file's ``platform``): a text that
        :func:`geoloc.sensors.platform.is_drone` may recognise as a drone, for the
        plausibility warnings; empty if not said.
    pixel_pitch_m : float or None
        The detector's pixel pitch [m], where the file says it (a camera file's
        ``pixel_pitch_m``): it turns error sources in micrometres on the CCD into pixels
        (Monte Carlo, docs/montecarlo.md). Not geometry: sensors compare without it.
    """

    lens: Lens
    gimbal: Gimbal = field(default_factory=lambda: PRESETS[DEFAULT])
    mount: tuple = (0.0, 0.0, 0.0)
    boresight: tuple = (0.0, 0.0, 0.0)
    lever_arm_m: tuple = (0.0, 0.0, 0.0)
    name: str = ""
    platform: str = ""
    pixel_pitch_m: float | None = field(default=None, compare=False)
    #: Per-sample perturbations (..., 3, 3), for Monte Carlo: ``v_base = R_mount @ R_base_extra @ v_body``
    #: (shock-absorber vibration) and ``v = R_bore_extra @ R_boresight @ v_last`` (collimation,
    #: gimbal non-orthogonality), both before the fixed turn to the optical axes. None: identity.
    R_base_extra: np.ndarray | None = field(default=None, compare=False, repr=False)
    R_bore_extra: np.ndarray | None = field(default=None, compare=False, repr=False)
    #: Per-sample lever-arm perturbation (..., 3) [m, body axes], for Monte Carlo. None: zero.
    lever_extra_m: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        if not isinstance(self.lens, Lens):
            raise ValueError(f"sensor field lens = {self.lens!r}: must be a geoloc.sensors.lenses lens")
        if not isinstance(self.gimbal, Gimbal):
            raise ValueError(f"sensor field gimbal = {self.gimbal!r}: must be a Gimbal")
        for k in ("mount", "boresight", "lever_arm_m"):
            object.__setattr__(self, k, _three(k, getattr(self, k)))
        p = self.pixel_pitch_m
        if p is not None:
            if isinstance(p, bool) or not (isinstance(p, (int, float)) and math.isfinite(p) and p > 0):
                raise ValueError(f"sensor field pixel_pitch_m = {p!r}: must be a finite number > 0 (metres)")
            object.__setattr__(self, "pixel_pitch_m", float(p))
        for k in ("mount", "boresight"):
            if any(abs(a) > math.pi for a in getattr(self, k)):
                raise ValueError(f"sensor field {k} = {getattr(self, k)!r}: angles must lie in [-pi, pi] rad")
        if self.gimbal.earth_referenced and (any(self.mount) or self.R_base_extra is not None):
            raise ValueError(
                f"sensor field mount = {self.mount!r}: an earth-referenced gimbal "
                f"({self.gimbal.name}) has no mount (its angles are in NED)"
            )

    # ----------------------------------------------------------- basics
    @property
    def rows(self) -> int:
        return int(self.lens.height)

    @property
    def cols(self) -> int:
        return int(self.lens.width)

    @property
    def center_pixel(self) -> tuple:
        """Image centre ((M+1)/2, (N+1)/2), 1-based."""
        return (self.rows + 1) / 2.0, (self.cols + 1) / 2.0

    @property
    def angle_names(self) -> tuple:
        """The joint angles a state must give (``Pose.angle``)."""
        return self.gimbal.angle_names

    def in_image(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        return in_sensor(row, col, self.rows, self.cols)

    @property
    def compiled(self) -> bool:
        """True if the compiled kernels (:mod:`geoloc.sensors._fastlocate`, ``_fastgrid``) serve this
        sensor: one (unbatched) lens and no per-sample Monte Carlo perturbation."""
        return (
            not self.lens.batched
            and self.R_base_extra is None
            and self.R_bore_extra is None
            and self.lever_extra_m is None
        )

    @cached_property
    def R_base_body(self) -> np.ndarray:
        R = small_rotation(self.mount)
        return R if self.R_base_extra is None else R @ np.asarray(self.R_base_extra, float)

    @cached_property
    def R_cam_last(self) -> np.ndarray:
        """Last joint frame -> optical frame: the gimbal's optical turn after the boresight."""
        R = small_rotation(self.boresight)
        if self.R_bore_extra is not None:
            R = np.asarray(self.R_bore_extra, float) @ R
        return self.gimbal.R_opt_last @ R

    # ----------------------------------------------------------- parameters
    @property
    def params(self) -> dict:
        """Named parameters: mount/boresight angles [rad], lever arm [m], and the lens's.

        The lens's principal point is given here in this project's 1-based
        pixels (``cx``, ``cy``), like every pixel at this interface.
        """
        p = dict(zip(OWN_PARAMS, self.mount + self.boresight + self.lever_arm_m))
        if self.gimbal.earth_referenced:  # its angles are in NED: no mount between body and gimbal
            for k in OWN_PARAMS[:3]:
                del p[k]
        lens = dict(self.lens.params)
        lens["cx"] += 1.0
        lens["cy"] += 1.0
        p.update(lens)
        return p

    def with_params(self, **changes: float) -> "FrameSensor":
        check_param_names(changes, self.params, f"sensor {self.name or 'frame camera'}")
        own = dict(zip(OWN_PARAMS, self.mount + self.boresight + self.lever_arm_m))
        lens_changes = {}
        for k, v in changes.items():
            if k in own:
                own[k] = float(v)
            else:
                lens_changes[k] = float(v) - (1.0 if k in ("cx", "cy") else 0.0)
        vals = [own[k] for k in OWN_PARAMS]
        lens = self.lens.with_params(**lens_changes) if lens_changes else self.lens
        return dataclasses.replace(
            self, lens=lens, mount=tuple(vals[0:3]), boresight=tuple(vals[3:6]), lever_arm_m=tuple(vals[6:9])
        )

    # ----------------------------------------------------------- frame graph
    @cached_property
    def graph(self) -> FrameGraph:
        """The sensor's frame graph (state-independent; evaluate it with a Pose)."""
        joints = [
            Joint(
                "ecef",
                "ned",
                "geodetic",
                equation="Q17 eq. 4-5",
                description="North-East-Down at the navigation reference, to ECEF",
            ),
            Joint(
                "ned",
                "body",
                "attitude",
                equation="Q17 eq. 6",
                description="aircraft body (X nose, Y right wing, Z down), z-y-x attitude, to NED",
            ),
        ]
        g = self.gimbal
        if g.earth_referenced:
            # the first joint hangs off NED at the lever arm, written in body axes
            base, offset_m, offset_frame = "ned", np.array(self.lever_arm_m), "body"
        else:
            joints.append(
                Joint(
                    "body",
                    "gimbal_base",
                    "fixed",
                    R=self.R_base_body,
                    offset_m=np.array(self.lever_arm_m),
                    equation="mount and lever arm",
                    description="gimbal base: the body turned by the mount, at the optical centre",
                )
            )
            base, offset_m, offset_frame = "gimbal_base", np.zeros(3), None
        parent = base
        for k, j in enumerate(g.joints):
            joints.append(
                Joint(
                    parent,
                    j.frame,
                    "revolute",
                    axis=j.axis,
                    angle=j.angle,
                    equation=g.equation,
                    description=j.description,
                    offset_m=offset_m if k == 0 else np.zeros(3),
                    offset_frame=offset_frame if k == 0 else None,
                )
            )
            parent = j.frame
        joints.append(
            Joint(
                parent,
                "cam",
                "fixed",
                R=self.R_cam_last,
                equation="boresight, optical axes",
                description="camera optical frame (x right, y down, z the line of sight)",
            )
        )
        return FrameGraph(joints)

    @overload
    def frames(self, state: None = None) -> FrameGraph: ...

    @overload
    def frames(self, state: Pose) -> BoundFrames: ...

    def frames(self, state: Pose | None = None) -> FrameGraph | BoundFrames:
        """The frame graph the viewers draw: the :class:`FrameGraph`, or with ``state`` its :class:`BoundFrames`."""
        return self.graph if state is None else BoundFrames(self.graph, state)

    def _check_state(self, state) -> None:
        for name in self.angle_names:
            try:
                state.angle(name)
            except ValueError as e:
                raise ValueError(f"{e}; the {self.gimbal.name} gimbal needs {list(self.angle_names)}") from None

    # ----------------------------------------------------------- geometry
    def optical_centre_ecef(self, state: Any) -> np.ndarray:
        """The optical centre in ECEF: the navigation reference plus the lever arm [m]."""
        o = geodetic_to_ecef(state.lat, state.lon, state.h)
        lever = np.array(self.lever_arm_m)
        if self.lever_extra_m is not None:
            lever = lever + np.asarray(self.lever_extra_m, float)
        if np.any(lever):
            o = o + self.graph.rotate_to_ecef(lever, "body", state)
        return o

    def cam_to_ecef(self, v_cam: ArrayLike, state: Any) -> np.ndarray:
        """Optical-frame vectors -> ECEF, hop by hop."""
        return self.graph.rotate_to_ecef(v_cam, "cam", state)

    def ecef_to_cam(self, v_ecef: ArrayLike, state: Any) -> np.ndarray:
        return self.graph.rotate_from_ecef(v_ecef, "cam", state)

    def line_of_sight(
        self,
        row: ArrayLike | None = None,
        col: ArrayLike | None = None,
        state: Any = None,
        *,
        outside: str = "flag",
        engine: str = "auto",
    ) -> LineOfSight:
        """1-based pixels -> lines of sight in ECEF (batched; NaN + Status).

        Status: INVALID_INPUT (pose out of range, NaN pixel); OUTSIDE_SENSOR
        for a pixel off the rows/columns, unless ``outside="extrapolate"``
        (the ray through the lens model beyond the edge, status OK: for a
        caller that has warned about it, such as the replay of recorded pixels).

        ``engine``: ``"numpy"`` is the reference path (lens, then the frame graph hop by
        hop); ``"numba"`` the compiled kernel of :mod:`geoloc.sensors._fastlocate` (the same
        mathematics; ``tests/sensors/test_fastlocate.py`` holds the two equal ray for ray); ``"auto"``
        takes the kernel for batches of ``COMPILED_MIN_RAYS`` (10 000) rays or more when it
        serves this sensor (one lens, no per-sample perturbation).
        """
        check_outside(outside)
        if engine not in ("auto", "numpy", "numba"):
            raise ValueError(f"engine must be 'auto', 'numpy' or 'numba', got {engine!r}")
        if state is None:
            raise ValueError("a frame camera needs a state (a Pose with its gimbal angles)")
        self._check_state(state)
        r0, c0 = self.center_pixel
        row = r0 if row is None else row
        col = c0 if col is None else col
        row, col = np.broadcast_arrays(np.asarray(row, float), np.asarray(col, float))
        if engine == "numba" or (
            engine == "auto"
            and self.compiled
            and isinstance(state, Pose)
            and state.batch_size(row) >= COMPILED_MIN_RAYS
        ):
            from geoloc.sensors import _fastlocate

            return LineOfSight(*_fastlocate.line_of_sight_fast(state, self, row, col, outside=outside))
        d_cam = self.lens.unproject(col - 1.0, row - 1.0)
        d = self.cam_to_ecef(d_cam, state)
        o = self.optical_centre_ecef(state)
        shape = np.broadcast_shapes(o.shape, d.shape)[:-1]
        o, d = np.broadcast_to(o, shape + (3,)), np.broadcast_to(d, shape + (3,))
        rb, cb = np.broadcast_to(row, shape), np.broadcast_to(col, shape)
        given = ~np.broadcast_to(state.invalid_mask(), shape) & np.isfinite(rb) & np.isfinite(cb)
        status = np.where(given, Status.OK, Status.INVALID_INPUT).astype(np.uint8)
        if outside == "flag":  # before the lens's NaN (none beyond a model's domain): off the sensor says more
            status = flag_outside(status, rb, cb, self.rows, self.cols)
        status[(status == Status.OK) & ~np.all(np.isfinite(d), axis=-1)] = Status.INVALID_INPUT
        return LineOfSight(o, d, status)

    def ground_to_pixel(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike, state: Any = None) -> PixelHit:
        """Geodetic points [rad, rad, m] -> 1-based pixels (NaN + BEHIND_CAMERA / OUTSIDE_SENSOR)."""
        if state is None:
            raise ValueError("a frame camera needs a state (a Pose with its gimbal angles)")
        self._check_state(state)
        p = geodetic_to_ecef(lat, lon, h)
        d_cam = self.ecef_to_cam(p - self.optical_centre_ecef(state), state)
        u, v, status = self.lens.project(d_cam)
        row, col = v + 1.0, u + 1.0
        bad = state.invalid_mask() | ~np.all(np.isfinite(p), axis=-1)
        status = np.where(np.broadcast_to(bad, np.shape(status)), np.uint8(Status.INVALID_INPUT), status)
        return PixelHit(row, col, flag_outside(status, row, col, self.rows, self.cols))
