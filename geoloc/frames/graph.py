"""A graph of named frames joined by fixed and revolute joints.

The airborne chain of every platform camera is one path of such a graph::

    ecef <- ned <- body <- gimbal_base <- joint frames ... <- cam

Each :class:`Joint` says how a child frame sits in its parent for a given
state (a :class:`geoloc.frames.chain.Pose`): its passive rotation
``R_child_parent`` (``v_child = R_child_parent @ v_parent``) and its origin
offset. A *revolute* joint turns about one axis of its parent by a named angle
of the state, as a URDF joint does; a *fixed* joint is a constant rotation
(mount, boresight, the permutation to the optical frame); *attitude* is the
z-y-x aircraft attitude [Q17 eq. 6]; *geodetic* is NED at the state's position
[Q17 eq. 4-5]. The viewers and the teaching panel walk :meth:`FrameGraph.hops`,
so they draw whatever joints a sensor has.

Conventions: ``docs/conventions.md`` (passive elementary rotations, names say
the direction). Radians and metres; arrays broadcast over the state's batch.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames import rotations as rot
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_ned

_ELEMENTARY = {"x": rot.rx, "y": rot.ry, "z": rot.rz}

#: Joint kinds.
KINDS = ("fixed", "revolute", "attitude", "geodetic")


@dataclass(frozen=True)
class Joint:
    """How ``child`` sits in ``parent``.

    Attributes
    ----------
    parent, child : str
        Frame names.
    kind : {"fixed", "revolute", "attitude", "geodetic"}
    axis : {"x", "y", "z"} or None
        Revolute joints: the parent axis turned about (the passive elementary
        rotation of ``docs/conventions.md``).
    angle : str or None
        Revolute joints: the name of the state's angle (``Pose.angle(name)``).
    R : ndarray (3, 3) or None
        Fixed joints: ``R_child_parent``.
    offset_m : ndarray (3,)
        The child's origin relative to the parent's origin [m], in the axes of
        ``offset_frame`` (default the parent's).
    offset_frame : str or None
        Frame whose axes ``offset_m`` is written in (a lever arm is given in
        body axes even when the joint hangs off NED).
    equation, description : str
        For the teaching panel.
    """

    parent: str
    child: str
    kind: str
    axis: str | None = None
    angle: str | None = None
    R: np.ndarray | None = None
    offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    offset_frame: str | None = None
    equation: str = ""
    description: str = ""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"joint {self.child!r}: kind = {self.kind!r}: must be one of {KINDS}")
        if self.kind == "revolute":
            if self.axis not in _ELEMENTARY:
                raise ValueError(f"joint {self.child!r}: axis = {self.axis!r}: must be 'x', 'y' or 'z'")
            if not self.angle:
                raise ValueError(f"joint {self.child!r}: a revolute joint needs an angle name")
        if self.kind == "fixed":
            # (3, 3), or a batch (..., 3, 3) (Monte Carlo draws a mount perturbation per sample)
            R = np.asarray(self.R if self.R is not None else np.eye(3), float)
            if (
                R.shape[-2:] != (3, 3)
                or not np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-9)
                or np.any(np.linalg.det(R) < 0)
            ):
                raise ValueError(f"joint {self.child!r}: R must be a 3x3 rotation matrix (or a stack of them)")
            object.__setattr__(self, "R", R)
        off = np.asarray(self.offset_m, float)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ValueError(f"joint {self.child!r}: offset_m = {self.offset_m!r}: must be 3 finite numbers (metres)")
        object.__setattr__(self, "offset_m", off)

    @property
    def _R(self) -> np.ndarray:
        # a fixed joint's rotation: __post_init__ sets it (the identity when None was given)
        assert self.R is not None, f"joint {self.child!r} ({self.kind}) has no fixed rotation"
        return self.R

    @property
    def _axis(self) -> str:
        # a revolute joint's axis: __post_init__ checked it is one of x, y, z
        assert self.axis is not None, f"joint {self.child!r} ({self.kind}) has no axis"
        return self.axis

    def R_child_parent(self, state: Any) -> np.ndarray:
        """The joint's passive rotation for ``state``: ``v_child = R @ v_parent``."""
        if self.kind == "fixed":
            return self._R
        if self.kind == "revolute":
            return _ELEMENTARY[self._axis](state.angle(self.angle))
        if self.kind == "attitude":
            return rot.rx(state.roll) @ rot.ry(state.pitch) @ rot.rz(state.heading)
        return np.swapaxes(R_ecef_ned(state.lat, state.lon), -1, -2)  # geodetic: R_ned_ecef

    def rotate_to_parent(self, v: ArrayLike, state: Any) -> np.ndarray:
        """``R_parent_child @ v`` hop by hop (elementary rotations applied to the vectors)."""
        v = np.asarray(v, float)
        if self.kind == "fixed":
            return rot.rotate(np.swapaxes(self._R, -1, -2), v)
        if self.kind == "revolute":
            return rot.rotate_axis(self._axis, state.angle(self.angle), v, transpose=True)
        if self.kind == "attitude":
            v = rot.rotate_axis("x", state.roll, v, transpose=True)
            v = rot.rotate_axis("y", state.pitch, v, transpose=True)
            return rot.rotate_axis("z", state.heading, v, transpose=True)
        return rot.rotate(R_ecef_ned(state.lat, state.lon), v)

    def rotate_to_child(self, v: ArrayLike, state: Any) -> np.ndarray:
        """``R_child_parent @ v``: the inverse of :meth:`rotate_to_parent`."""
        v = np.asarray(v, float)
        if self.kind == "fixed":
            return rot.rotate(self._R, v)
        if self.kind == "revolute":
            return rot.rotate_axis(self._axis, state.angle(self.angle), v)
        if self.kind == "attitude":
            v = rot.rotate_axis("z", state.heading, v)
            v = rot.rotate_axis("y", state.pitch, v)
            return rot.rotate_axis("x", state.roll, v)
        return np.einsum("...ji,...j->...i", R_ecef_ned(state.lat, state.lon), v)

    @property
    def name(self) -> str:
        return f"T_{self.parent}_{self.child}"


@dataclass(frozen=True)
class Hop:
    """One hop for the teaching panel: ``T`` maps homogeneous ``src`` coordinates to ``dst``."""

    dst: str
    src: str
    T: np.ndarray
    equation: str
    description: str
    joint: Joint | None = None  # None for the [Q17] FrameChain's own hops

    @property
    def name(self) -> str:
        return f"T_{self.dst}_{self.src}"


class FrameGraph:
    """A tree of frames rooted at ``ecef``, built from :class:`Joint` objects.

    Parameters
    ----------
    joints : sequence of Joint
        Each child frame once; every parent must be ``ecef`` or an earlier child.
    """

    ROOT = "ecef"

    def __init__(self, joints: Iterable[Joint]):
        self.joints = tuple(joints)
        self._by_child: dict[str, Joint] = {}
        for j in self.joints:
            if j.child in self._by_child or j.child == self.ROOT:
                raise ValueError(f"frame {j.child!r} is defined twice")
            if j.parent != self.ROOT and j.parent not in self._by_child:
                raise ValueError(f"joint {j.child!r}: parent frame {j.parent!r} is not defined before it")
            self._by_child[j.child] = j
        for j in self.joints:
            if j.offset_frame is not None and j.offset_frame not in self.frames:
                raise ValueError(f"joint {j.child!r}: offset_frame {j.offset_frame!r} is not a frame")

    @property
    def frames(self) -> tuple:
        """Frame names, root first, in definition order."""
        return (self.ROOT,) + tuple(j.child for j in self.joints)

    @property
    def angle_names(self) -> tuple:
        """Names of the state angles the revolute joints read, in joint order."""
        return tuple(j.angle for j in self.joints if j.kind == "revolute")

    def path(self, frame: str) -> list:
        """Joints from the root down to ``frame`` (root side first)."""
        if frame != self.ROOT and frame not in self._by_child:
            raise ValueError(f"unknown frame {frame!r}; frames: {list(self.frames)}")
        out = []
        while frame != self.ROOT:
            j = self._by_child[frame]
            out.append(j)
            frame = j.parent
        return out[::-1]

    # ------------------------------------------------------------ rotations
    def rotate_to_ecef(self, v: ArrayLike, frame: str, state: Any) -> np.ndarray:
        """Vectors (..., 3) in ``frame`` -> ECEF, hop by hop (innermost first)."""
        for j in reversed(self.path(frame)):
            v = j.rotate_to_parent(v, state)
        return np.asarray(v, float)

    def rotate_from_ecef(self, v: ArrayLike, frame: str, state: Any) -> np.ndarray:
        """ECEF vectors (..., 3) -> ``frame``: the inverse of :meth:`rotate_to_ecef`."""
        for j in self.path(frame):
            v = j.rotate_to_child(v, state)
        return np.asarray(v, float)

    def R_ecef(self, frame: str, state: Any) -> np.ndarray:
        """``R_ecef_frame`` (..., 3, 3): the columns are the frame's axes in ECEF."""
        R = np.eye(3)
        for j in self.path(frame):
            R = R @ np.swapaxes(j.R_child_parent(state), -1, -2)
        return R

    def origin_ecef(self, frame: str, state: Any) -> np.ndarray:
        """The frame's origin in ECEF [m] (..., 3)."""
        o = np.zeros(3)
        for j in self.path(frame):
            if j.kind == "geodetic":
                o = geodetic_to_ecef(state.lat, state.lon, state.h)
            elif np.any(j.offset_m):
                o = o + self.rotate_to_ecef(j.offset_m, j.offset_frame or j.parent, state)
        return np.asarray(o, float)

    def T_ecef(self, frame: str, state: Any) -> np.ndarray:
        """4x4 from ``frame`` to ECEF."""
        R = self.R_ecef(frame, state)
        o = self.origin_ecef(frame, state)
        shape = np.broadcast_shapes(R.shape[:-2], o.shape[:-1])
        return rot.transform(np.broadcast_to(R, shape + (3, 3)), np.broadcast_to(o, shape + (3,)))

    def T(self, dst: str, src: str, state: Any) -> np.ndarray:
        """4x4 mapping coordinates in ``src`` to ``dst`` (any two frames)."""
        return rot.invert(self.T_ecef(dst, state)) @ self.T_ecef(src, state)

    def hops(self, state: Any, frame: str | None = None) -> list:
        """The joints on the path to ``frame`` (default the last frame) as 4x4 :class:`Hop`, outermost first."""
        frame = frame or self.frames[-1]
        out = []
        for j in self.path(frame):
            T = self.T(j.parent, j.child, state)
            out.append(Hop(j.parent, j.child, T, j.equation, j.description, j))
        return out


class BoundFrames:
    """A :class:`FrameGraph` evaluated for one state: what the viewers and the teaching panel read.

    It offers the same calls as the [Q17] :class:`geoloc.frames.chain.FrameChain`
    (``hops``, ``T_ecef``, ``T``, ``pose``), for whatever joints the graph has.
    """

    def __init__(self, graph: FrameGraph, state: Any, leaf: str | None = None):
        self.graph = graph
        self.pose = state
        self.leaf = leaf or graph.frames[-1]

    @property
    def frames(self) -> tuple:
        """Frames on the path root -> leaf, root first."""
        return (FrameGraph.ROOT,) + tuple(j.child for j in self.graph.path(self.leaf))

    @cached_property
    def hops(self) -> list:
        """The hops on the path root -> leaf (what the chain of 4x4 matrices multiplies)."""
        return self.graph.hops(self.pose, self.leaf)

    @cached_property
    def all_hops(self) -> list:
        """One hop per joint of the whole graph (side branches too: the body of an
        earth-referenced gimbal), parents before children."""
        return [
            Hop(j.parent, j.child, self.graph.T(j.parent, j.child, self.pose), j.equation, j.description, j)
            for j in self.graph.joints
        ]

    def T_ecef(self, frame: str) -> np.ndarray:
        return self.graph.T_ecef(frame, self.pose)

    def T(self, dst: str, src: str) -> np.ndarray:
        return self.graph.T(dst, src, self.pose)

    @property
    def R_ecef_cam(self) -> np.ndarray:
        return self.graph.R_ecef(self.leaf, self.pose)

    @property
    def origin_ecef(self) -> np.ndarray:
        return self.graph.origin_ecef(self.leaf, self.pose)
