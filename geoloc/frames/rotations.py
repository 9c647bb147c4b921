"""Elementary passive rotations and 4x4 homogeneous transforms.

Conventions: ``docs/conventions.md``. The rotations here are *passive*
(docs/method.md section 2): ``rx(a) @ v`` gives the coordinates, in a frame turned
by ``+a`` about X, of a vector whose coordinates were ``v``. So ``rx(a)`` is the
transpose of the active (right-hand-rule) rotation matrix.

Angles are radians and broadcast: ``rx(np.zeros(5))`` has shape ``(5, 3, 3)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def _stack33(rows):
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rx(a: ArrayLike) -> np.ndarray:
    """Passive rotation about X: [[1,0,0],[0,c,s],[0,-s,c]]; [Q17 eq. 6, 7]."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return _stack33([(o, z, z), (z, c, s), (z, -s, c)])


def ry(a: ArrayLike) -> np.ndarray:
    """Passive rotation about Y: [[c,0,-s],[0,1,0],[s,0,c]]; [Q17 eq. 6, 7]."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return _stack33([(c, z, -s), (z, o, z), (s, z, c)])


def rz(a: ArrayLike) -> np.ndarray:
    """Passive rotation about Z: [[c,s,0],[-s,c,0],[0,0,1]]; [Q17 eq. 5, 6]."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return _stack33([(c, s, z), (-s, c, z), (z, z, o)])


def rotate_axis(axis: str, a: ArrayLike, v: ArrayLike, transpose: bool = False) -> np.ndarray:
    """Apply the passive elementary rotation about ``axis`` (or its transpose) to vectors v (..., 3).

    Same result as ``rx(a) @ v`` (``rx(a).T @ v`` with ``transpose=True``), and
    likewise for "y" and "z", without forming the matrices: a few array
    operations per call, which matters for batches of millions.
    """
    a = np.asarray(a, float)
    v = np.asarray(v, float)
    c, s = np.cos(a), np.sin(a)
    if transpose:
        s = -s
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    if axis == "x":
        out = (np.broadcast_to(x, np.broadcast_shapes(x.shape, c.shape)), c * y + s * z, -s * y + c * z)
    elif axis == "y":
        out = (c * x - s * z, np.broadcast_to(y, np.broadcast_shapes(y.shape, c.shape)), s * x + c * z)
    elif axis == "z":
        out = (c * x + s * y, -s * x + c * y, np.broadcast_to(z, np.broadcast_shapes(z.shape, c.shape)))
    else:
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return np.stack(out, axis=-1)


def transform(R: ArrayLike, t: ArrayLike | None = None) -> np.ndarray:
    """4x4 homogeneous matrix [[R, t], [0, 1]] from R (..., 3, 3) and t (..., 3).

    ``transform(R_a_b, p_a_borigin)`` maps homogeneous coordinates in frame b to
    frame a: ``x_a = R_a_b x_b + t``.
    """
    R = np.asarray(R, float)
    if t is None:
        t = np.zeros(R.shape[:-1])
    t = np.asarray(t, float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def translation(t: ArrayLike) -> np.ndarray:
    """4x4 pure translation by t (..., 3)."""
    t = np.asarray(t, float)
    return transform(np.broadcast_to(np.eye(3), t.shape[:-1] + (3, 3)), t)


def invert(T: ArrayLike) -> np.ndarray:
    """Inverse of a rigid 4x4 transform: [[R^T, -R^T t], [0, 1]]."""
    T = np.asarray(T, float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return transform(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def apply(T: ArrayLike, p: ArrayLike) -> np.ndarray:
    """Apply a 4x4 transform to points p (..., 3)."""
    T = np.asarray(T, float)
    p = np.asarray(p, float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def rotate(R: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Apply a 3x3 rotation (..., 3, 3) to vectors v (..., 3)."""
    return np.einsum("...ij,...j->...i", np.asarray(R, float), np.asarray(v, float))
