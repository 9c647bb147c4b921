"""Local level frames at a point of the ellipsoid: NED and ENU axes.

Conventions: ``docs/conventions.md`` (frames ``ned`` and ``enu``). Radians;
arrays broadcast over leading axes.
"""

from __future__ import annotations

import numpy as np


def R_ecef_ned(lat, lon):
    """Rotation NED -> ECEF at (phi, lambda): columns N, E, D in ECEF [Q17 eq. 5].

    N = (-sin phi cos lambda, -sin phi sin lambda, cos phi),
    E = (-sin lambda, cos lambda, 0),
    D = (-cos phi cos lambda, -cos phi sin lambda, -sin phi).
    """
    lat, lon = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float))
    sp, cp, sl, cl = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    n = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    e = np.stack([-sl, cl, z], axis=-1)
    d = np.stack([-cp * cl, -cp * sl, -sp], axis=-1)
    return np.stack([n, e, d], axis=-1)


#: Permutation taking NED coordinates to ENU coordinates: v_enu = P @ v_ned.
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def R_ecef_enu(lat, lon):
    """Rotation ENU -> ECEF at (phi, lambda): columns E, N, U in ECEF.

    E = (-sin lambda, cos lambda, 0), N = (-sin phi cos lambda, -sin phi sin lambda, cos phi),
    U = (cos phi cos lambda, cos phi sin lambda, sin phi) (the NED axes of [Q17 eq. 5]
    reordered, U = -D).
    """
    return R_ecef_ned(lat, lon) @ R_ENU_NED.T
