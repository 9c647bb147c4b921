"""Which platform carries the camera: the rule that says "a drone" (the plausibility checks).

A drone's camera flies low: a records row, a photo or a KLV packet whose drone is kilometres
above the terrain under it holds a height in the wrong unit or datum, or is not a drone's.
The warnings (``geoloc.workflows.replay.plausibility_warnings``, the photo and KLV replays)
need to know that the platform is a drone; this module is the one rule for it:

- a drone photo (EXIF/XMP the photo reader knows: every photo ``geoloc replay --targets`` takes);
- a text that names a drone, by :data:`DRONE_WORDS`: the sensor file's ``platform`` key, a
  records CSV's ``platform`` column, a KLV packet's Platform Designation (tag 10).

"UAV" or "UAS" alone does not say drone: an MQ-9 or a Global Hawk is one and flies at
15-18 km. Nothing is guessed from the lens: a sensor file gives its focal length in pixels,
not the physical sensor, and wide small cameras fly on manned aircraft too.
The numbers and their sources: ``docs/records.md``, "Plausibility checks".
"""

from __future__ import annotations

import re

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Words (case-insensitive, whole words) that make a platform text a drone: small multirotors
#: and small fixed-wing UAS, and their makers' product names (DJI's Mavic, Phantom, Matrice,
#: Inspire, Mini, Air; Autel's EVO; Parrot's Anafi; Skydio).
DRONE_WORDS = (
    "drone",
    "multirotor",
    "multicopter",
    "quadcopter",
    "quadrotor",
    "hexacopter",
    "octocopter",
    "suas",
    "suav",
    "small uav",
    "small uas",
    "dji",
    "mavic",
    "phantom",
    "matrice",
    "inspire",
    "autel",
    "anafi",
    "parrot",
    "skydio",
)
_DRONE_RE = re.compile(
    r"\b(" + "|".join(re.escape(w).replace(r"\ ", r"[\s_-]+") for w in DRONE_WORDS) + r")\b", re.IGNORECASE
)

#: Height above the terrain (or the target) [m] beyond which a drone's camera is implausible.
#: The rules cap drones at 120 m above the ground (EU 2019/947 open category; FAA Part 107:
#: 400 ft), DJI's firmware at 500 m above the take-off point; taking off from a ridge above a
#: valley adds its few hundred metres. 1000 m is twice the firmware cap, eight times the rule.
DRONE_MAX_HEIGHT_M = 1000.0
#: Height [m] above which a drone's camera is implausible wherever it is: the highest service
#: ceilings of multirotor drones are 6-7 km above mean sea level (DJI Mavic 3: 6000 m; Matrice
#: 350 RTK: 7000 m with its high-altitude propellers). Ellipsoidal heights differ from MSL by
#: |N| < 110 m, nothing against this margin.
DRONE_CEILING_M = 7000.0
#: Feet to metres (international foot).
FOOT_M = 0.3048


def is_drone(text: str | None) -> bool:
    """True if the platform ``text`` names a drone by :data:`DRONE_WORDS` (None, "": False)."""
    return bool(text) and _DRONE_RE.search(str(text)) is not None


def drone_too_high(
    h_m: ArrayLike,
    fallback_m: ArrayLike,
    ground_m: ArrayLike | None = None,
    fallback_what: str | ArrayLike = "the target",
    ground_what: str | ArrayLike = "the terrain under it",
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.object_]]:
    """Which drone camera heights cannot be a drone's (docs/records.md, "Plausibility checks").

    Parameters
    ----------
    h_m : array_like
        The camera's height (m, in the datum of the others).
    fallback_m : array_like
        What it is judged against where there is no terrain: the target or the located point.
    ground_m : array_like or None
        The terrain under the camera (NaN where the DEM has none); None: no DEM.
    fallback_what, ground_what : str or array_like
        What the two references are, for the message.

    Returns
    -------
    high : ndarray of bool
        More than :data:`DRONE_MAX_HEIGHT_M` above the reference, or above :data:`DRONE_CEILING_M`.
    ref_m : ndarray
        The reference each height was judged against (NaN where neither is known).
    what : ndarray of object
        What that reference is.
    """
    h = np.asarray(h_m, float)
    ref = np.array(np.broadcast_to(np.asarray(fallback_m, float), h.shape))
    what = np.array(np.broadcast_to(np.asarray(fallback_what, dtype=object), h.shape))
    if ground_m is not None:
        g = np.broadcast_to(np.asarray(ground_m, float), h.shape)
        has = np.isfinite(g)
        ref[has] = g[has]
        what[has] = ground_what
    with np.errstate(invalid="ignore"):
        high = (h - ref > DRONE_MAX_HEIGHT_M) | (h > DRONE_CEILING_M)
    return high, ref, what


def drone_height_where(h_m: float, ref_m: float, what: str) -> str:
    """'1.1 km above the terrain under it (291.1 m)', or the ceiling where ``ref_m`` is unknown."""
    if np.isfinite(ref_m):
        return f"{(h_m - ref_m) / 1000:.1f} km above {what} ({ref_m:.1f} m)"
    return f"above a drone's ceiling ({DRONE_CEILING_M:.0f} m)"


def drone_height_hint(h_m: float, ref_m: float | None, unit: str = "m", advice: str = "") -> str:
    """What a drone's implausible height ``h_m`` above ``ref_m`` (the terrain or the target under
    it, in the same datum; None if unknown) likely is: feet read as metres, when that puts it at
    a drone's height (then ``advice`` is added), else a height in another unit or datum, or not
    a drone's."""
    if unit == "m":
        as_m = h_m * FOOT_M
        above = as_m - (ref_m if ref_m is not None else 0.0)
        if 0.0 <= above <= DRONE_MAX_HEIGHT_M and (ref_m is not None or as_m <= DRONE_CEILING_M):
            where = f", {above:.0f} m above it" if ref_m is not None else ""
            return f"likely feet read as metres (x {FOOT_M}: {as_m:.1f} m{where})" + (f"; {advice}" if advice else "")
    return (
        "perhaps a height in another unit (feet, decimetres) or of another platform (MSL and the "
        "ellipsoid differ by tens of metres only, so not a datum alone)"
    )
