"""The frame chain of an aircraft gimbal camera [Q17 section 2.1, eq. 4-9].

ECEF <- NED <- aircraft body <- outer gimbal (roll) <- inner gimbal = camera (pitch).

Conventions: ``docs/conventions.md``. Names say which way a matrix maps:
``R_ned_body`` takes body coordinates to NED coordinates, ``T_ecef_cam`` takes
homogeneous camera coordinates to ECEF; in a product the inner frame names
meet (``R_ecef_ned @ R_ned_body``). The paper's ``C^B_A`` (from A to B) is our
``R_B_A``.

All functions take radians and broadcast over leading axes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames import rotations as rot
from geoloc.frames.graph import Hop
from geoloc.geodesy.ellipsoid import E2, geodetic_to_ecef, prime_vertical_radius
from geoloc.geodesy.local import R_ecef_ned

#: Frame names of the chain, outermost first.
FRAMES = ("ecef", "ned", "body", "gimbal_outer", "cam")


def R_body_ned(heading: ArrayLike, pitch: ArrayLike, roll: ArrayLike) -> np.ndarray:
    """NED -> aircraft body: Rx(roll) Ry(pitch) Rz(heading) [Q17 eq. 6] (passive, z-y-x)."""
    return rot.rx(roll) @ rot.ry(pitch) @ rot.rz(heading)


def R_ned_body(heading: ArrayLike, pitch: ArrayLike, roll: ArrayLike) -> np.ndarray:
    """Aircraft body -> NED: the transpose of :func:`R_body_ned`."""
    return np.swapaxes(R_body_ned(heading, pitch, roll), -1, -2)


def R_outer_body(gimbal_roll: ArrayLike) -> np.ndarray:
    """Body -> outer gimbal: Rx(gimbal_roll), about the aircraft roll axis [Q17 eq. 7]."""
    return rot.rx(gimbal_roll)


def R_cam_outer(gimbal_pitch: ArrayLike) -> np.ndarray:
    """Outer gimbal -> inner gimbal / camera: Ry(gimbal_pitch) [Q17 eq. 7]."""
    return rot.ry(gimbal_pitch)


def R_cam_body(gimbal_roll: ArrayLike, gimbal_pitch: ArrayLike) -> np.ndarray:
    """Body -> camera: Ry(gimbal_pitch) Rx(gimbal_roll) [Q17 eq. 7]."""
    return R_cam_outer(gimbal_pitch) @ R_outer_body(gimbal_roll)


def T_ecef_ned(lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> np.ndarray:
    """4x4 NED -> ECEF with the NED origin at (lat, lon, h): [[R_ecef_ned, O_ecef], [0, 1]]."""
    return rot.transform(R_ecef_ned(lat, lon), geodetic_to_ecef(lat, lon, h))


def T_ned_ecef_q17_factors(lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> list[np.ndarray]:
    """The four homogeneous factors of [Q17 eq. 5], in the paper's order.

    C^NED_ECEF = Tz(R_N + h) . M(phi) . Rz(lambda) . Tz(R_N e^2 sin phi), where
    Tz(c) translates by c along Z, M(phi) = [[-sin phi, 0, cos phi], [0, 1, 0],
    [-cos phi, 0, -sin phi]] and Rz is the passive rotation about Z.
    Read right to left: move the origin to the centre of the prime-vertical
    circle (on the polar axis, R_N e^2 sin phi below the equator plane for phi > 0),
    turn into the meridian plane, turn the axes to N, E, D, and move the origin
    along D to the aircraft (R_N + h above that centre).

    Returns
    -------
    list of 4 ndarrays (..., 4, 4)
        The factors, leftmost first. Their product equals
        ``rotations.invert(T_ecef_ned(lat, lon, h))`` (checked in the tests).
    """
    lat, lon, h = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float))
    rn = prime_vertical_radius(lat)
    z = np.zeros_like(lat)
    sp, cp = np.sin(lat), np.cos(lat)
    one = np.ones_like(lat)
    M = np.stack(
        [
            np.stack([-sp, z, cp], -1),
            np.stack([z, one, z], -1),
            np.stack([-cp, z, -sp], -1),
        ],
        -2,
    )
    return [
        rot.translation(np.stack([z, z, rn + h], -1)),
        rot.transform(M),
        rot.transform(rot.rz(lon)),
        rot.translation(np.stack([z, z, rn * E2 * sp], -1)),
    ]


@dataclass(frozen=True)
class Pose:
    """Aircraft position, attitude and gimbal angles (SI units, radians).

    Every field is an array broadcastable against the others, so one Pose can
    hold one record or a million Monte Carlo samples.

    Attributes
    ----------
    lat, lon, h : ndarray
        Camera / aircraft origin, geodetic [rad, rad, m] (POS output).
    heading, pitch, roll : ndarray
        Aircraft attitude psi, theta, phi [rad], [Q17 eq. 6].
    gimbal_roll, gimbal_pitch : ndarray
        Outer (roll) and inner (pitch) gimbal encoder angles [rad], [Q17 eq. 7].
    angles : dict of str -> ndarray
        Any other named joint angles [rad] of the sensor's gimbal
        (``azimuth``, ``elevation``, ``sensor_roll``, ``gimbal_yaw``, ...;
        ``docs/conventions.md``, "Gimbal presets"). :meth:`angle` reads a joint
        angle by name from here or from the two [Q17] fields.
    """

    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    heading: np.ndarray = field(default_factory=lambda: np.array(0.0))
    pitch: np.ndarray = field(default_factory=lambda: np.array(0.0))
    roll: np.ndarray = field(default_factory=lambda: np.array(0.0))
    gimbal_roll: np.ndarray = field(default_factory=lambda: np.array(0.0))
    gimbal_pitch: np.ndarray = field(default_factory=lambda: np.array(0.0))
    angles: dict = field(default_factory=dict)

    #: Valid range of every joint angle in ``angles`` [rad].
    ANGLE_RANGE = (-2 * np.pi, 2 * np.pi)

    def __post_init__(self):
        # one home per angle: the [Q17] two live in their fields even when given by name
        angles = dict(self.angles)
        for k in ("gimbal_roll", "gimbal_pitch"):
            if k in angles:
                object.__setattr__(self, k, angles.pop(k))
        object.__setattr__(self, "angles", angles)

    #: Valid ranges [rad or m] checked by :meth:`invalid_mask` / :meth:`validate`.
    RANGES = {
        "lat": (-np.pi / 2, np.pi / 2),
        "lon": (-2 * np.pi, 2 * np.pi),
        "h": (-1.2e4, 1.0e8),
        "heading": (-2 * np.pi, 2 * np.pi),
        "pitch": (-np.pi / 2, np.pi / 2),
        "roll": (-np.pi, np.pi),
        "gimbal_roll": (-np.pi, np.pi),
        "gimbal_pitch": (-np.pi, np.pi),
    }

    @classmethod
    def from_deg(
        cls,
        lat_deg: ArrayLike,
        lon_deg: ArrayLike,
        h_m: ArrayLike,
        heading_deg: ArrayLike = 0.0,
        pitch_deg: ArrayLike = 0.0,
        roll_deg: ArrayLike = 0.0,
        gimbal_roll_deg: ArrayLike = 0.0,
        gimbal_pitch_deg: ArrayLike = 0.0,
        angles_deg: Mapping[str, ArrayLike] | None = None,
    ) -> "Pose":
        """Build a Pose from degrees (the edge of the core) and metres.

        ``angles_deg`` maps joint angle names to degrees (``{"azimuth": 90}``).
        """
        r = np.deg2rad
        angles = {k: r(np.asarray(v, float)) for k, v in (angles_deg or {}).items()}
        return cls(
            r(np.asarray(lat_deg, float)),
            r(np.asarray(lon_deg, float)),
            np.asarray(h_m, float),
            r(np.asarray(heading_deg, float)),
            r(np.asarray(pitch_deg, float)),
            r(np.asarray(roll_deg, float)),
            r(np.asarray(gimbal_roll_deg, float)),
            r(np.asarray(gimbal_pitch_deg, float)),
            angles,
        )

    #: The two joint angles [Q17] keeps as fields; every other one lives in ``angles``.
    FIELD_ANGLES = ("gimbal_roll", "gimbal_pitch")

    def angle(self, name: str) -> np.ndarray:
        """The joint angle ``name`` [rad]; ValueError naming it (and those given) if absent."""
        if name in self.angles:
            return self.angles[name]
        if name in self.FIELD_ANGLES:
            return getattr(self, name)
        given = sorted(set(self.angles) | set(self.FIELD_ANGLES))
        raise ValueError(f"missing angle {name!r}: the pose has {given}")

    def with_angles(self, **angles: np.ndarray) -> "Pose":
        """A copy with joint angles set by name [rad] (the [Q17] two go to their fields)."""
        import dataclasses

        fields_kw = {k: angles.pop(k) for k in list(angles) if k in self.FIELD_ANGLES}
        return dataclasses.replace(self, angles={**self.angles, **angles}, **fields_kw)

    def take(self, idx: Any) -> "Pose":
        """The samples ``idx`` of the batch (every field and angle broadcast to :attr:`shape` first)."""
        shape = self.shape

        def pick(v):
            return np.broadcast_to(np.asarray(v, float), shape)[idx]

        kw = {f.name: pick(getattr(self, f.name)) for f in fields(self) if f.name != "angles"}
        return Pose(**kw, angles={k: pick(v) for k, v in self.angles.items()})

    @property
    def shape(self) -> tuple:
        return np.broadcast_shapes(
            *(np.shape(getattr(self, f.name)) for f in fields(self) if f.name != "angles"),
            *(np.shape(v) for v in self.angles.values()),
        )

    def batch_size(self, *arrays: ArrayLike) -> int:
        """Samples in the broadcast of this batch with ``arrays`` (pixels, heights): the rays of a call."""
        return int(np.prod(np.broadcast_shapes(self.shape, *(np.shape(a) for a in arrays))))

    def _checked(self):
        """(name, value, (lo, hi)) for every range-checked field and joint angle."""
        for name, rng in self.RANGES.items():
            yield name, np.asarray(getattr(self, name), float), rng
        for name, v in self.angles.items():
            yield name, np.asarray(v, float), self.ANGLE_RANGE

    def invalid_mask(self) -> np.ndarray:
        """Boolean mask (shape :attr:`shape`) of samples with a NaN/inf or out-of-range field."""
        bad = np.zeros(self.shape, dtype=bool)
        for _, v, (lo, hi) in self._checked():
            with np.errstate(invalid="ignore"):
                bad = bad | ~np.isfinite(v) | (v < lo) | (v > hi)
        return bad

    def validate(self) -> "Pose":
        """Raise ``ValueError`` naming the first bad field and value; return self if valid."""
        for name, v, (lo, hi) in self._checked():
            with np.errstate(invalid="ignore"):
                bad = ~np.isfinite(v) | (v < lo) | (v > hi)
            if np.any(bad):
                val = v[bad].flat[0] if v.ndim else float(v)
                unit = "m" if name == "h" else "deg"
                shown = val if name == "h" else np.rad2deg(val)
                lo_s, hi_s = (lo, hi) if name == "h" else (np.rad2deg(lo), np.rad2deg(hi))
                raise ValueError(f"{name} = {shown:g} {unit} is not a finite value in [{lo_s:g}, {hi_s:g}] {unit}")
        return self


def _rotate_T(R, v):
    """R^T v for stacks of rotations (..., 3, 3) and vectors (..., 3)."""
    return np.einsum("...ji,...j->...i", R, v)


class FrameChain:
    """The named frames of [Q17 eq. 4-9] for one pose (or a batch of poses).

    Parameters
    ----------
    pose : Pose
        Aircraft position, attitude and gimbal angles.
    R_cam_inner : array_like (..., 3, 3), optional
        Extra rotation after the inner gimbal (boresight / collimation error);
        identity by default. Used by calibration and Monte Carlo.
    R_base_body : array_like (..., 3, 3), optional
        Extra rotation between the aircraft body and the gimbal base (mounting
        error, shock-absorber vibration); identity by default.

    Attributes
    ----------
    hops : list of Hop
        ECEF <- NED <- body <- gimbal_outer <- cam, outermost first.
    """

    def __init__(self, pose: Pose, R_cam_inner: ArrayLike | None = None, R_base_body: ArrayLike | None = None):
        self.pose = pose
        self.R_cam_inner = None if R_cam_inner is None else np.asarray(R_cam_inner, float)
        self.R_base_body = None if R_base_body is None else np.asarray(R_base_body, float)

    # The matrices are built on first use: a batch of a million rays that only
    # needs its lines of sight (cam_to_ecef) never pays for 4x4 hops or for
    # stacked 3x3 products, which cost ~0.2 s per product per million.
    @cached_property
    def R_ecef_ned(self) -> np.ndarray:
        """NED -> ECEF at the aircraft [Q17 eq. 5]."""
        return R_ecef_ned(self.pose.lat, self.pose.lon)

    @cached_property
    def origin_ecef(self) -> np.ndarray:
        """The aircraft / optical centre in ECEF [Q17 eq. 4]."""
        p = self.pose
        return geodetic_to_ecef(p.lat, p.lon, p.h)

    @cached_property
    def R_ned_body(self) -> np.ndarray:
        """Body -> NED [Q17 eq. 6, transposed]."""
        p = self.pose
        return R_ned_body(p.heading, p.pitch, p.roll)

    @cached_property
    def R_body_outer(self) -> np.ndarray:
        """Outer gimbal -> body: (Rx(gimbal_roll) R_base_body)^T [Q17 eq. 7]."""
        R_ob = R_outer_body(self.pose.gimbal_roll)
        if self.R_base_body is not None:
            R_ob = R_ob @ self.R_base_body
        return np.swapaxes(R_ob, -1, -2)

    @cached_property
    def R_outer_cam(self) -> np.ndarray:
        """Camera -> outer gimbal: (R_cam_inner Ry(gimbal_pitch))^T [Q17 eq. 7]."""
        R_co = R_cam_outer(self.pose.gimbal_pitch)
        if self.R_cam_inner is not None:
            R_co = self.R_cam_inner @ R_co
        return np.swapaxes(R_co, -1, -2)

    @cached_property
    def hops(self) -> list:
        """ECEF <- NED <- body <- gimbal_outer <- cam as :class:`Hop` objects, outermost first."""
        return [
            Hop(
                "ecef",
                "ned",
                rot.transform(self.R_ecef_ned, self.origin_ecef),
                "Q17 eq. 4-5",
                "local North-East-Down at the aircraft to Earth-centred Earth-fixed",
            ),
            Hop(
                "ned",
                "body",
                rot.transform(self.R_ned_body),
                "Q17 eq. 6",
                "aircraft body (X nose, Y right wing, Z down) to NED",
            ),
            Hop(
                "body",
                "gimbal_outer",
                rot.transform(self.R_body_outer),
                "Q17 eq. 7",
                "outer gimbal (roll about the body X axis) to body",
            ),
            Hop(
                "gimbal_outer",
                "cam",
                rot.transform(self.R_outer_cam),
                "Q17 eq. 7",
                "inner gimbal / camera (pitch about the outer gimbal Y axis; Z is the line of sight) to outer gimbal",
            ),
        ]

    def cam_to_ecef(self, v_cam: ArrayLike) -> np.ndarray:
        """Rotate camera-frame vectors (..., 3) to ECEF, hop by hop [Q17 eq. 9].

        Equal to ``R_ecef_cam @ v`` but applies each elementary rotation to the
        vector (transposed passive rotations, innermost first), which is several
        times cheaper than forming the stacked matrix product for large batches.
        """
        p = self.pose
        v = np.asarray(v_cam, float)
        if self.R_cam_inner is not None:
            v = _rotate_T(self.R_cam_inner, v)
        v = rot.rotate_axis("y", p.gimbal_pitch, v, transpose=True)
        v = rot.rotate_axis("x", p.gimbal_roll, v, transpose=True)
        if self.R_base_body is not None:
            v = _rotate_T(self.R_base_body, v)
        v = rot.rotate_axis("x", p.roll, v, transpose=True)
        v = rot.rotate_axis("y", p.pitch, v, transpose=True)
        v = rot.rotate_axis("z", p.heading, v, transpose=True)
        return rot.rotate(self.R_ecef_ned, v)

    def ecef_to_cam(self, v_ecef: ArrayLike) -> np.ndarray:
        """Rotate ECEF vectors (..., 3) to the camera frame: the inverse of :meth:`cam_to_ecef`."""
        p = self.pose
        v = _rotate_T(self.R_ecef_ned, np.asarray(v_ecef, float))
        v = rot.rotate_axis("z", p.heading, v)
        v = rot.rotate_axis("y", p.pitch, v)
        v = rot.rotate_axis("x", p.roll, v)
        if self.R_base_body is not None:
            v = rot.rotate(self.R_base_body, v)
        v = rot.rotate_axis("x", p.gimbal_roll, v)
        v = rot.rotate_axis("y", p.gimbal_pitch, v)
        if self.R_cam_inner is not None:
            v = rot.rotate(self.R_cam_inner, v)
        return v

    @property
    def R_ecef_cam(self) -> np.ndarray:
        """Camera -> ECEF rotation, R_ecef_ned @ R_ned_body @ R_body_outer @ R_outer_cam [Q17 eq. 9]."""
        return self.R_ecef_ned @ self.R_ned_body @ self.R_body_outer @ self.R_outer_cam

    def T_ecef(self, frame: str) -> np.ndarray:
        """4x4 transform from ``frame`` to ECEF (composition of the hops)."""
        if frame not in FRAMES:
            raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")
        T = np.broadcast_to(np.eye(4), self.hops[0].T.shape).copy()
        for hop in self.hops:
            if hop.dst == frame:
                break
            T = T @ hop.T
        return T

    def T(self, dst: str, src: str) -> np.ndarray:
        """4x4 transform mapping coordinates in ``src`` to ``dst`` (any two frames)."""
        return rot.invert(self.T_ecef(dst)) @ self.T_ecef(src)
