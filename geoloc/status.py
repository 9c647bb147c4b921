"""Status codes returned by batch functions (one ``uint8`` per ray or sample).

Batch functions never raise for a bad ray: they return NaN in the numeric
outputs and one of these codes in a ``status`` array, so that one call can
serve a million rays of which a few look at the sky. Scalar front ends (the
command line) turn a non-OK status into an error message with
:func:`describe`.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike


class Status(IntEnum):
    """Why a ray did or did not give a ground point."""

    OK = 0  #: a valid hit / tangent point
    SKY = 1  #: the line of sight misses the (inflated) ellipsoid: it points above the horizon
    ORIGIN_BELOW = 2  #: the camera is below the target-height surface
    INVALID_INPUT = 3  #: NaN / infinite / out-of-range input for this ray
    LEFT_DEM = 4  #: the ray left the DEM's extent before hitting the terrain
    NODATA = 5  #: the DEM has no data where the ray meets it
    NO_CONVERGENCE = 6  #: an iteration did not converge within its limit
    HITS_EARTH = 7  #: limb viewing: the line of sight meets the Earth, there is no tangent point
    BEHIND_CAMERA = 8  #: ground -> pixel: the point is behind the camera
    OUTSIDE_SENSOR = 9  #: the pixel (or the projected point) lies outside the sensor's rows and columns
    OUTSIDE_DOMAIN = 10  #: the point is outside the model's validity domain (an RPC's offsets and scales)
    BELOW_TERRAIN = 11  #: the camera is below the DEM's terrain under it (a wrong height or datum, a tunnel)


_TEXT = {
    Status.OK: "ok",
    Status.SKY: "line of sight misses the Earth (points above the horizon)",
    Status.ORIGIN_BELOW: "camera is below the target height surface",
    Status.INVALID_INPUT: "invalid input (NaN, infinite or out of range)",
    Status.LEFT_DEM: "line of sight left the DEM before meeting the terrain",
    Status.NODATA: "DEM has no data where the line of sight meets it",
    Status.NO_CONVERGENCE: "iteration did not converge",
    Status.HITS_EARTH: "line of sight hits the Earth: no tangent point",
    Status.BEHIND_CAMERA: "point is behind the camera",
    Status.OUTSIDE_SENSOR: "pixel is outside the sensor (rows 0.5..M+0.5, columns 0.5..N+0.5)",
    Status.OUTSIDE_DOMAIN: "point is outside the model's validity domain (not extrapolated)",
    Status.BELOW_TERRAIN: "camera is below the terrain (DEM) under it: check its height and vertical datum",
}


def describe(code: int, rows: int | None = None, cols: int | None = None) -> str:
    """Human-readable text for a status code.

    ``rows`` and ``cols`` (the sensor's size, optional) fill OUTSIDE_SENSOR's span
    ("rows 0.5..1080.5" rather than "rows 0.5..M+0.5").
    """
    text = _TEXT[Status(int(code))]
    if rows is not None and cols is not None and int(code) == Status.OUTSIDE_SENSOR:
        text = text.replace("M+0.5", f"{int(rows) + 0.5:g}").replace("N+0.5", f"{int(cols) + 0.5:g}")
    return text


def names(status: ArrayLike) -> np.ndarray:
    """Array of lower-case status names (e.g. ``'sky'``) for an array of codes."""
    status = np.asarray(status)
    out = np.empty(status.shape, dtype=object)
    for s in Status:
        out[status == s] = s.name.lower()
    return out
