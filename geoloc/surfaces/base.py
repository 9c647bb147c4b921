"""What sensors hand to surfaces and surfaces hand back: lines of sight and ground points.

A sensor turns pixels into a :class:`LineOfSight` batch (ECEF origin, unit
direction, a :class:`geoloc.status.Status` per ray); a surface turns it into a
:class:`GroundPoint` batch. ``docs/architecture.md`` describes the two
interfaces; ``docs/conventions.md`` the frames and units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LineOfSight:
    """A batch of lines of sight in ECEF.

    Attributes
    ----------
    origin_ecef : ndarray (..., 3)
        Optical centre O_E [m].
    direction_ecef : ndarray (..., 3)
        Unit direction d_E.
    status : ndarray (...) of uint8
        INVALID_INPUT where the pose or pixel is not finite / out of range.
    """

    origin_ecef: np.ndarray
    direction_ecef: np.ndarray
    status: np.ndarray


class LatLonDeg:
    """``lat_deg`` / ``lon_deg`` of a result whose ``lat``, ``lon`` are in radians."""

    @property
    def lat_deg(self):
        return np.rad2deg(self.lat)

    @property
    def lon_deg(self):
        return np.rad2deg(self.lon)


@dataclass(frozen=True)
class GroundPoint(LatLonDeg):
    """Result of a batch geolocation.

    Attributes
    ----------
    lat, lon : ndarray
        Geodetic latitude and longitude of the target [rad]; NaN where no hit.
    h : ndarray
        Ellipsoidal height of the target [m].
    ecef : ndarray (..., 3)
        Target in ECEF [m].
    slant_range : ndarray
        Distance from the optical centre [m].
    status : ndarray of uint8
        :class:`geoloc.status.Status` per ray.
    los : LineOfSight
        The line of sight used.
    """

    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    ecef: np.ndarray
    slant_range: np.ndarray
    status: np.ndarray
    los: LineOfSight
