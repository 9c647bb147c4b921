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
    out = [HopView(h.name, h.dst, h.src, np.asarray(h.T), h.equation, h.description)
           for h in chain.hops]
    out.append(HopView("T_ecef_cam", "ecef", "cam", chain.T_ecef("cam"), "Q17 eq. 9, generalised",
                       "the whole chain: camera to ECEF (product of the hops above)"))
    return out


def fmt_matrix(T: np.ndarray) -> str:
    """A 4x4 matrix as a fixed-width block: rotation to 6 decimals, translation in metres."""
    lines = []
    for r in range(T.shape[0]):
        cells = [f"{T[r, c]: .6f}" if c < 3 else f"{T[r, c]: .3f}" for c in range(T.shape[1])]
        lines.append("[" + "  ".join(cells) + "]")
    return "\n".join(lines)


def hop_markdown(h: HopView) -> str:
    return (f"**{h.key}** ({h.equation}): maps `{h.src}` coordinates to `{h.dst}`.  \n"
            f"{h.description}\n\n```\n{fmt_matrix(h.T)}\n```\n")


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
    parts.append(f"Product minus the direct form `inv(T_ecef_ned)`: max |difference| = {diff:.2e} "
                 f"(m in the translation column; float64 rounding at 6.4e6 m is ~1e-9 m).\n")
    return "\n".join(parts)


def chain_markdown(chain) -> str:
    """The whole chain as Markdown: the order of the product, then every hop."""
    names = [h.name for h in chain.hops]
    inner = [h.dst for h in reversed(chain.hops)]
    head = (f"`T_ecef_cam = {' @ '.join(names)}` [Q17 eq. 9, generalised]: read right to left, "
            f"a camera vector goes to {', '.join(inner[:-1])} and {inner[-1]}.\n")
    return head + "\n".join(hop_markdown(h) for h in hops(chain))
