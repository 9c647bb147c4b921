"""Teaching panel: the chain of 4x4 matrices for the current pose, whatever the sensor's joints.

Every matrix shown is the core's own (the hops of the sensor's frame graph,
:class:`geoloc.frames.graph.BoundFrames`, and
:func:`geoloc.frames.chain.T_ned_ecef_q17_factors`); this module only formats them.
Conventions: ``docs/conventions.md`` (``T_dst_src`` maps ``src`` coordinates to ``dst``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.frames import rotations as rot
from geoloc.frames.chain import T_ned_ecef_q17_factors

Q17_FACTOR_NAMES = (
    "Tz(R_N + h): origin along D to the aircraft",
    "M(phi): axes turned to N, E, D",
    "Rz(lambda): into the meridian plane",
    "Tz(R_N e^2 sin phi): origin to the prime-vertical centre",
)


@dataclass(frozen=True)
class HopView:
    """A hop as shown: its name, frames, equation, and the core's matrix."""

    key: str
    dst: str
    src: str
    T: np.ndarray
    equation: str
    description: str


def hops(chain) -> list:
    """The chain's hops, outermost first, plus the composed ECEF <- cam transform."""
    out = [HopView(h.name, h.dst, h.src, np.asarray(h.T), h.equation, h.description) for h in chain.hops]
    out.append(
        HopView(
            "T_ecef_cam",
            "ecef",
            "cam",
            chain.T_ecef("cam"),
            "Q17 eq. 9, generalised",
            "the whole chain: camera to ECEF (product of the hops above)",
        )
    )
    return out


def fmt_matrix(T: np.ndarray) -> str:
    """A 4x4 matrix as a fixed-width block: rotation to 6 decimals, translation in metres."""
    lines = []
    for r in range(T.shape[0]):
        cells = [f"{T[r, c]: .6f}" if c < 3 else f"{T[r, c]: .3f}" for c in range(T.shape[1])]
        lines.append("[" + "  ".join(cells) + "]")
    return "\n".join(lines)


def hop_markdown(h: HopView) -> str:
    return (
        f"**{h.key}** ({h.equation}): maps `{h.src}` coordinates to `{h.dst}`.  \n"
        f"{h.description}\n\n```\n{fmt_matrix(h.T)}\n```\n"
    )


def q17_factors_markdown(chain) -> str:
    """The four factors of [Q17 eq. 5] and the check that their product equals the core's T_ned_ecef."""
    p = chain.pose
    factors = T_ned_ecef_q17_factors(p.lat, p.lon, p.h)
    prod = factors[0] @ factors[1] @ factors[2] @ factors[3]
    direct = rot.invert(chain.hops[0].T)
    diff = float(np.max(np.abs(prod - direct)))
    parts = ["**T_ned_ecef as the four factors of [Q17 eq. 5]** (leftmost first):\n"]
    for name, F in zip(Q17_FACTOR_NAMES, factors):
        parts.append(f"{name}\n```\n{fmt_matrix(F)}\n```\n")
    parts.append(
        f"Product minus the direct form `inv(T_ecef_ned)`: max |difference| = {diff:.2e} "
        f"(m in the translation column; float64 rounding at 6.4e6 m is ~1e-9 m).\n"
    )
    return "\n".join(parts)


def chain_markdown(chain) -> str:
    """The whole chain as Markdown: the order of the product, then every hop."""
    names = [h.name for h in chain.hops]
    inner = [h.dst for h in reversed(chain.hops)]
    head = (
        f"`T_ecef_cam = {' @ '.join(names)}` [Q17 eq. 9, generalised]: read right to left, "
        f"a camera vector goes to {', '.join(inner[:-1])} and {inner[-1]}.\n"
    )
    return head + "\n".join(hop_markdown(h) for h in hops(chain))


# ---------------------------------------------------------------- a vector through the chain
#: The attitude angles of a platform pose [Q17 eq. 6], animated by the teaching panel.
ATTITUDE_ANGLES = ("heading", "pitch", "roll")


def chain_frames(chain) -> tuple:
    """Frames on the chain's path, ECEF first (``ecef, ned, body, ..., cam``)."""
    return tuple(chain.frames)


def partial_products(chain) -> list:
    """The partial products ``T_ecef_<frame>`` of the chain, one per frame after ECEF.

    ``T_ecef_body = T_ecef_ned @ T_ned_body``, ``T_ecef_gimbal_base = T_ecef_body @ ...``
    and so on to ``T_ecef_cam`` ([Q17 eq. 9], generalised to the sensor's joints).
    Each is the running product of the hops (what the slide writes), not a
    separate evaluation of the graph.

    Returns
    -------
    list of (str, str, ndarray (4, 4))
        ``(name, frame, T_ecef_frame)``, outermost first.
    """
    out, T = [], np.eye(4)
    for h in chain.hops:
        T = T @ np.asarray(h.T, float)
        out.append((f"T_ecef_{h.src}", h.src, T.copy()))
    return out


def pixel_ray_cam(sensor, row, col) -> np.ndarray:
    """Unit direction (3,) of pixel (row, col) (1-based centres) in the optical frame ``cam``.

    The lens model's own back-projection (``sensor.lens.unproject``), the first
    step of ``sensor.line_of_sight``.
    """
    d = np.asarray(sensor.lens.unproject(float(col) - 1.0, float(row) - 1.0), float)
    return d / np.linalg.norm(d)


def vector_in_frames(chain, v, frame: str, point: bool = False) -> dict:
    """Coordinates of one vector (or point) in every frame of the chain.

    Parameters
    ----------
    chain : BoundFrames
        The sensor's frame graph at one pose.
    v : array_like (3,)
        The vector's coordinates in ``frame``.
    frame : str
        One of :func:`chain_frames`.
    point : bool
        False (default): a free vector (a direction): only rotations act,
        ``v_dst = R_dst_src @ v_src``. True: a point, homogeneous coordinates,
        ``p_dst = T_dst_src @ [p_src, 1]`` (origins count; metres).

    Returns
    -------
    dict
        frame -> ndarray (3,), in :func:`chain_frames` order.

    Raises
    ------
    ValueError
        Naming ``frame`` or ``v`` when they are not a frame of the chain / 3 finite numbers.
    """
    frames = chain_frames(chain)
    if frame not in frames:
        raise ValueError(f"frame = {frame!r}: not a frame of this chain; frames: {list(frames)}")
    v = np.asarray(v, float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"v = {v.tolist()!r}: must be 3 finite numbers")
    T_src = chain.T_ecef(frame)
    out = {}
    for f in frames:
        T = rot.invert(chain.T_ecef(f)) @ T_src  # T_f_src
        out[f] = T[:3, :3] @ v + (T[:3, 3] if point else 0.0)
    return out


def hop_frames(key: str, chain) -> tuple:
    """(destination, source) frames of a hop key such as ``T_ned_body`` or ``T_ecef_cam``."""
    for h in hops(chain):
        if h.key == key:
            return h.dst, h.src
    raise ValueError(f"hop = {key!r}: not a hop of this chain; hops: {[h.key for h in hops(chain)]}")


def animatable_angles(chain) -> tuple:
    """Angle names the panel can animate from 0: the attitude (heading, pitch, roll), then the
    revolute joints of the sensor's own graph, in chain order."""
    joints = tuple(j.angle for j in chain.graph.path(chain.leaf) if j.kind == "revolute")
    return ATTITUDE_ANGLES + joints


def pose_angle(pose, name: str) -> float:
    """The pose's angle ``name`` [rad] (attitude field or joint angle)."""
    if name in ATTITUDE_ANGLES:
        return float(np.asarray(getattr(pose, name)))
    return float(np.asarray(pose.angle(name)))


def pose_with_angle(pose, name: str, value: float):
    """A copy of ``pose`` with the attitude or joint angle ``name`` set to ``value`` [rad]."""
    import dataclasses

    if name in ATTITUDE_ANGLES:
        return dataclasses.replace(pose, **{name: np.array(float(value))})
    pose.angle(name)  # ValueError naming it if the pose has no such angle
    return pose.with_angles(**{name: np.array(float(value))})


def q17_intermediate_frames(chain) -> list:
    """The frames between ECEF and NED that the four factors of [Q17 eq. 5] pass through.

    ``T_ned_ecef = Tz(R_N + h) . M(phi) . Rz(lambda) . Tz(R_N e^2 sin phi)`` read
    right to left: F1 = ECEF axes with the origin moved to the prime-vertical
    centre (on the polar axis, R_N e^2 sin phi below the equator plane for phi > 0),
    F2 = F1 turned by lambda about Z (X in the meridian plane), F3 = F2's axes
    turned to N, E, D, and NED = F3 with the origin moved R_N + h up the normal.

    Returns
    -------
    list of (str, ndarray (4, 4))
        ``(description, T_ecef_frame)`` for F1, F2, F3 and NED.
    """
    p = chain.pose
    F = T_ned_ecef_q17_factors(p.lat, p.lon, p.h)
    names = (
        "F1: origin at the prime-vertical centre, Tz(R_N e^2 sin phi)",
        "F2: turned into the meridian plane, Rz(lambda)",
        "F3: axes N, E, D, M(phi)",
        "NED: origin R_N + h up the normal, Tz(R_N + h)",
    )
    out, T_k_ecef = [], np.eye(4)
    for name, Fk in zip(names, F[::-1]):
        T_k_ecef = np.asarray(Fk, float) @ T_k_ecef
        out.append((name, rot.invert(T_k_ecef)))
    return out


def _fmt3(v, point: bool) -> list:
    return [f"{x:.3f}" if point else f"{x:+.6f}" for x in v]


def vector_markdown(chain, v, frame: str, hop: str | None = None, point: bool = False, what: str = "the vector") -> str:
    """The vector's coordinates in every frame (a Markdown table), the source and destination of
    ``hop`` marked, then the partial products ``T_ecef_<frame>``."""
    coords = vector_in_frames(chain, v, frame, point)
    dst, src = hop_frames(hop, chain) if hop else (None, None)
    unit = " [m]" if point else " (unit-free direction)"
    # four columns, the hop's frames tagged in their own cell: the table fits the GUI panel
    # (a fifth column of tags overflowed it)
    roles = f" **(src)** is the hop's **source** `{src}`, **(dst)** its **destination** `{dst}`." if hop else ""
    lines = [
        f"**Coordinates of {what} in every frame**{unit}, given in `{frame}`.{roles}\n",
        "| frame | x | y | z |",
        "|---|---:|---:|---:|",
    ]
    for f, c in coords.items():
        mark = " (dst)" if f == dst else " (src)" if f == src else ""
        x, y, z = _fmt3(c, point)
        name = f"**{f}{mark}**" if mark else f
        lines.append(f"| {name} | {x} | {y} | {z} |")
    if hop:
        a, b = coords[src], coords[dst]
        lines.append(
            f"\nCheck: `{hop}` @ ({', '.join(_fmt3(a, point))}) = "
            f"({', '.join(_fmt3(b, point))}), the `{dst}` row "
            f"({'T' if point else 'the rotation block of T'} times the `{src}` row)."
        )
    lines.append("\n**Partial products** (running product of the hops, from ECEF in):\n")
    acc = []
    for h, (name, f, T) in zip(chain.hops, partial_products(chain)):
        acc.append(h.name)
        lines.append(f"`{name}` = `{' @ '.join(acc)}`\n```\n{fmt_matrix(T)}\n```\n")
    return "\n".join(lines)
