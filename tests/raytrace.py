"""An independent ray trace through the standard atmosphere, for the tests (not geoloc code).

The ray equation d/ds (n dx/ds) = grad n integrated in ECEF with scipy's solve_ivp (DOP853,
rtol 1e-12; absolute tolerances 1e-6 m on the position and 1e-12 on p = n dx/ds), n a function of the geodetic height (so grad n = n'(h) times the ellipsoid's
normal), stopped by an event at the target height (or, for a limb ray, where it turns
level). Used by tests/corrections/test_refraction.py and tests/pipeline/test_pipeline.py.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from geoloc.corrections.atmosphere import STANDARD
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef, up_normal_ecef
from geoloc.geodesy.local import R_ecef_ned


def look(lat, lon, h, off_nadir_deg, azimuth_deg=0.0):
    """Camera at (lat, lon, h) and the unit ECEF direction off_nadir_deg from nadir towards azimuth_deg."""
    a, z = np.deg2rad(off_nadir_deg), np.deg2rad(azimuth_deg)
    d_ned = np.array([np.sin(a) * np.cos(z), np.sin(a) * np.sin(z), np.cos(a)])
    return geodetic_to_ecef(lat, lon, h), R_ecef_ned(lat, lon) @ d_ned


def trace(o, d, h_target, nfun, limb=False):
    """Independent ray trace: x' = p / n, p' = n'(h) up(x), from o along the direction d (in the air there).

    Stops where the geodetic height reaches h_target (or, ``limb``, where the ray turns level).
    n' by a central difference over +-0.5 m of ``nfun``.
    """
    d = np.asarray(d, float) / np.linalg.norm(d)
    if ecef_to_geodetic(o)[2] > 120e3:
        # above 110 km n = 1 (the model's cut; USSA76's refractivity is below 2e-11 there): the
        # ray is the straight line down to 120 km, where the integration starts
        lo, hi = 0.0, np.linalg.norm(o)
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ecef_to_geodetic(o + mid * d)[2] > 120e3 else (lo, mid)
        o = o + lo * d
    n0 = nfun(ecef_to_geodetic(o)[2])

    def rhs(s, y):
        lat, lon, h = ecef_to_geodetic(y[:3])
        return np.r_[y[3:] / nfun(h), (nfun(h + 0.5) - nfun(h - 0.5)) * up_normal_ecef(lat, lon)]

    def reach(s, y):
        return ecef_to_geodetic(y[:3])[2] - h_target

    def level(s, y):
        lat, lon, _ = ecef_to_geodetic(y[:3])
        return float(np.dot(up_normal_ecef(lat, lon), y[3:]))

    ev = level if limb else reach
    ev.terminal = True
    ev.direction = 1 if limb else -1
    # absolute tolerances per component: p = n dx/ds is of order 1 and bends by 1e-4 at most,
    # so 1e-7 on it (the old single atol) let the step control take steps whose error reached
    # 19 mm on the ground at 80 deg off nadir (scipy 1.17); at 1e-12 the trace is converged
    # (Radau at atol 1e-10, max_step 200 m lands within 0.05 mm of it on every test geometry)
    atol = np.r_[1e-6, 1e-6, 1e-6, 1e-12, 1e-12, 1e-12]
    sol = solve_ivp(
        rhs, (0.0, 6e6), np.r_[o, n0 * d], method="DOP853", rtol=1e-12, atol=atol, events=ev, max_step=2000.0
    )
    assert sol.status == 1, sol.message
    return sol.y_events[0][0][:3]


def exact_n(h):
    return 1.0 + STANDARD.refractivity(h)
