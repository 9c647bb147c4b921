"""Local East-North-Up (ENU) frame: the viewer's scene frame.

Conventions: ``docs/conventions.md`` (frame ``enu``: E east, N north, U along the
outward ellipsoid normal at a chosen origin). Used by the 3D viewers because
three.js stores vertices as float32 (a 0.5 m step at ECEF magnitudes): scenes
are built in metres relative to an origin near the target.

The rotation is the NED one of [Q17 eq. 5] with the axes reordered
(E = N_ned's second column, N = first, U = -D), so it reuses
:func:`geoloc.geodesy.local.R_ecef_ned`. Radians and metres; arrays broadcast over
leading axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from geoloc.frames import rotations as rot
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_enu


def T_ecef_enu(lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> np.ndarray:
    """4x4 ENU -> ECEF with the ENU origin at geodetic (lat, lon, h)."""
    return rot.transform(R_ecef_enu(lat, lon), geodetic_to_ecef(lat, lon, h))


@dataclass(frozen=True)
class EnuFrame:
    """A local ENU frame with its origin at geodetic (lat0, lon0, h0) [rad, rad, m].

    Examples
    --------
    >>> import numpy as np
    >>> f = EnuFrame(np.deg2rad(36.3), np.deg2rad(78.8), 4000.0)
    >>> np.allclose(f.from_ecef(f.origin_ecef), 0)
    True
    """

    lat0: float
    lon0: float
    h0: float = 0.0

    @classmethod
    def from_deg(cls, lat0_deg: float, lon0_deg: float, h0_m: float = 0.0) -> "EnuFrame":
        return cls(float(np.deg2rad(lat0_deg)), float(np.deg2rad(lon0_deg)), float(h0_m))

    @classmethod
    def scene_origin(cls, lat_deg: float, lon_deg: float, h_m: float) -> "EnuFrame":
        """The 3D scenes' origin near a target: rounded to 0.001 deg and 100 m.

        Readable when printed, and close enough that scene coordinates stay
        within tens of km, where float32 steps are below 2 mm. The viser scene
        and the rerun recordings share this rule so their ENU coordinates agree.
        """
        return cls.from_deg(round(float(lat_deg), 3), round(float(lon_deg), 3), round(float(h_m), -2))

    @property
    def origin_ecef(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat0, self.lon0, self.h0)

    @property
    def R_ecef_enu(self) -> np.ndarray:
        return R_ecef_enu(self.lat0, self.lon0)

    @property
    def R_enu_ecef(self) -> np.ndarray:
        return self.R_ecef_enu.T

    def from_ecef(self, p_ecef: ArrayLike) -> np.ndarray:
        """ECEF points (..., 3) -> ENU coordinates (..., 3) [m]."""
        return rot.rotate(self.R_enu_ecef, np.asarray(p_ecef, float) - self.origin_ecef)

    def to_ecef(self, p_enu: ArrayLike) -> np.ndarray:
        """ENU coordinates (..., 3) -> ECEF points (..., 3) [m]."""
        return rot.rotate(self.R_ecef_enu, np.asarray(p_enu, float)) + self.origin_ecef

    def vector_from_ecef(self, v_ecef: ArrayLike) -> np.ndarray:
        """ECEF direction vectors (..., 3) -> ENU components (no translation)."""
        return rot.rotate(self.R_enu_ecef, v_ecef)

    def from_geodetic(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> np.ndarray:
        """Geodetic (rad, rad, m) -> ENU coordinates (..., 3)."""
        return self.from_ecef(geodetic_to_ecef(lat, lon, h))

    def to_geodetic(self, p_enu: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ENU coordinates -> geodetic (lat, lon, h) [rad, rad, m]."""
        return ecef_to_geodetic(self.to_ecef(p_enu))

    def R_enu_from(self, R_ecef_x: ArrayLike) -> np.ndarray:
        """Rotation of a frame x into ENU: R_enu_x = R_enu_ecef @ R_ecef_x."""
        return self.R_enu_ecef @ np.asarray(R_ecef_x, float)
