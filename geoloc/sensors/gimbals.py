"""Gimbals: ordered revolute joints with named angles, and the presets people use.

A gimbal is a list of revolute joints (each an axis of its parent frame and the
name of its encoder angle), then the fixed rotation from the last joint frame
to the camera's optical frame (x right, y down, z along the line of sight:
OpenCV's, as the lenses use). Body-referenced gimbals hang off the gimbal base
(the body turned by the mount); earth-referenced ones hang off NED.

Every preset's zero direction, axes and signs are on ``docs/conventions.md``
("Gimbal presets"); ``tests/sensors/test_gimbals.py`` checks each sign on a case a
person can check by eye.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Optical frame from a frame whose X axis is the line of sight (aerospace
#: convention: X forward, Y right, Z down): x_opt = Y, y_opt = Z, z_opt = X.
R_OPT_XFWD = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

#: Optical frame from the [Q17] camera frame S (X towards increasing rows, Y
#: towards decreasing columns, Z the line of sight, [Q17 eq. 8]):
#: x_opt = -Y_S, y_opt = X_S, z_opt = Z_S.
R_OPT_Q17 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class GimbalJoint:
    """One revolute joint: the ``axis`` of its parent turned by angle ``angle``; ``frame`` names the child."""

    angle: str
    axis: str
    frame: str
    description: str = ""


@dataclass(frozen=True)
class Gimbal:
    """An ordered list of revolute joints and the fixed turn to the optical frame.

    Attributes
    ----------
    name : str
        The preset name, or a user's name for a custom gimbal.
    joints : tuple of GimbalJoint
        Outermost (nearest the base) first.
    R_opt_last : ndarray (3, 3)
        Last joint frame -> optical frame (passive, ``v_opt = R @ v_last``).
    earth_referenced : bool
        True: the first joint hangs off NED, not the body (angles in NED, as DJI reports them).
    equation : str
        What the teaching panel cites.
    """

    name: str
    joints: tuple
    R_opt_last: np.ndarray
    earth_referenced: bool = False
    equation: str = ""

    def __post_init__(self):
        R = np.asarray(self.R_opt_last, float)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-12) or np.linalg.det(R) < 0:
            raise ValueError(f"gimbal {self.name!r}: R_opt_last must be a rotation matrix")
        object.__setattr__(self, "R_opt_last", R)
        object.__setattr__(self, "joints", tuple(self.joints))
        names = [j.angle for j in self.joints]
        if len(set(names)) != len(names):
            raise ValueError(f"gimbal {self.name!r}: angle names must differ, got {names}")
        for j in self.joints:
            if j.axis not in ("x", "y", "z"):
                raise ValueError(f"gimbal {self.name!r}: joint {j.angle!r} axis = {j.axis!r}: must be x, y or z")

    @property
    def angle_names(self) -> tuple:
        return tuple(j.angle for j in self.joints)


def _preset(name, joints, R, earth=False, eq=""):
    return Gimbal(name, tuple(GimbalJoint(*j) for j in joints), R, earth, eq)


#: The presets (``docs/conventions.md``, "Gimbal presets").
PRESETS = {
    "roll-pitch": _preset(
        "roll-pitch",
        [
            ("gimbal_roll", "x", "gimbal_outer", "outer gimbal: roll about the body X (nose) axis"),
            (
                "gimbal_pitch",
                "y",
                "gimbal_inner",
                "inner gimbal: pitch about the outer gimbal Y axis; Z is the line of sight",
            ),
        ],
        R_OPT_Q17,
        eq="Q17 eq. 7-8",
    ),
    "azimuth-elevation": _preset(
        "azimuth-elevation",
        [
            ("azimuth", "z", "gimbal_azimuth", "azimuth about the base's down axis, clockwise seen from above"),
            (
                "elevation",
                "y",
                "gimbal_elevation",
                "elevation about the turned Y axis, positive up; X is the line of sight",
            ),
        ],
        R_OPT_XFWD,
        eq="MISB ST 0601 tags 18-19",
    ),
    "azimuth-elevation-roll": _preset(
        "azimuth-elevation-roll",
        [
            ("azimuth", "z", "gimbal_azimuth", "sensor relative azimuth, clockwise seen from above"),
            ("elevation", "y", "gimbal_elevation", "sensor relative elevation, positive up"),
            (
                "sensor_roll",
                "x",
                "gimbal_roll_los",
                "sensor relative roll about the line of sight, clockwise looking out",
            ),
        ],
        R_OPT_XFWD,
        eq="MISB ST 0601 tags 18-20",
    ),
    "yaw-pitch-roll": _preset(
        "yaw-pitch-roll",
        [
            ("gimbal_yaw", "z", "gimbal_yaw_frame", "yaw from north about the local down axis"),
            (
                "gimbal_pitch",
                "y",
                "gimbal_pitch_frame",
                "pitch from the horizon, positive up (-90 looks straight down)",
            ),
            ("gimbal_roll", "x", "gimbal_roll_frame", "roll about the line of sight"),
        ],
        R_OPT_XFWD,
        earth=True,
        eq="earth-referenced z-y-x (DJI gimbal angles)",
    ),
}

DEFAULT = "roll-pitch"


def gimbal_from_dict(data: dict, source: str = "gimbal") -> Gimbal:
    """The ``[gimbal]`` table of a sensor file: ``preset = NAME`` or a custom joint list.

    A custom gimbal gives ``joints = [{angle = "pan", axis = "z"}, ...]``,
    ``line_of_sight = "x"`` (the last joint frame's axis along the line of
    sight, image x along its Y and image y along its Z) or ``"z"`` ([Q17]'s
    camera frame), and optionally ``earth_referenced = true``.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{source}: [gimbal] must be a table, got {data!r}")
    if "preset" in data:
        extra = sorted(set(data) - {"preset"})
        if extra:
            raise ValueError(f"{source}: [gimbal] preset = {data['preset']!r} takes no other key, got {extra}")
        name = data["preset"]
        if name not in PRESETS:
            raise ValueError(f"{source}: [gimbal] preset = {name!r}: must be one of {sorted(PRESETS)}")
        return PRESETS[name]
    known = {"name", "joints", "line_of_sight", "earth_referenced"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{source}: [gimbal] unknown key(s) {unknown}; allowed: preset, or {sorted(known)}")
    joints = data.get("joints")
    if not isinstance(joints, list) or not joints:
        raise ValueError(
            f"{source}: [gimbal] joints = {joints!r}: must be a non-empty list of {{angle = NAME, axis = 'x'|'y'|'z'}}"
        )
    out = []
    for k, j in enumerate(joints):
        if not isinstance(j, dict) or set(j) - {"angle", "axis", "frame"} or "angle" not in j or "axis" not in j:
            raise ValueError(f"{source}: [gimbal] joints[{k}] = {j!r}: must be {{angle = NAME, axis = 'x'|'y'|'z'}}")
        if not (isinstance(j["angle"], str) and j["angle"].isidentifier()):
            raise ValueError(
                f"{source}: [gimbal] joints[{k}].angle = {j['angle']!r}: must be a name (letters, digits, _)"
            )
        out.append(GimbalJoint(j["angle"], j["axis"], j.get("frame", f"joint_{j['angle']}")))
    los = data.get("line_of_sight", "x")
    if los not in ("x", "z"):
        raise ValueError(f"{source}: [gimbal] line_of_sight = {los!r}: must be 'x' or 'z'")
    earth = data.get("earth_referenced", False)
    if not isinstance(earth, bool):
        raise ValueError(f"{source}: [gimbal] earth_referenced = {earth!r}: must be true or false")
    return Gimbal(str(data.get("name", "custom")), tuple(out), R_OPT_XFWD if los == "x" else R_OPT_Q17, earth)


def gimbal_to_dict(g: Gimbal) -> dict:
    """Inverse of :func:`gimbal_from_dict`."""
    if g.name in PRESETS and PRESETS[g.name] is g:
        return {"preset": g.name}
    los = "x" if np.allclose(g.R_opt_last, R_OPT_XFWD) else "z"
    return {
        "name": g.name,
        "joints": [{"angle": j.angle, "axis": j.axis, "frame": j.frame} for j in g.joints],
        "line_of_sight": los,
        "earth_referenced": g.earth_referenced,
    }
