"""Time scales and the inertial-to-Earth-fixed rotation, by astropy (ERFA), from given IERS values.

Conventions: ``docs/conventions.md``; the Sentinel-2 use: ``docs/sentinel2.md``.

A satellite's attitude is measured against the stars (an inertial frame); its GPS orbit and the
ground are Earth-fixed. Between them lies the rotation of IERS Conventions 2010, chapter 5:
``v_itrs = W(t) R(t) Q(t) v_gcrs`` (polar motion W, Earth rotation angle R, precession-nutation
Q, IAU 2006/2000A), which ERFA's ``c2t06a`` computes. EME2000 (the mean equator and equinox of
J2000.0, Orekit's ``EME2000``, in which Sentinel-2's attitude quaternions are given) differs
from the GCRS by the constant frame bias B (IERS Conventions 2010, eq. 5.21; ERFA ``bp06``):
``v_eme2000 = B v_gcrs``. So ``R_itrs_eme2000(t) = c2t06a(t) B^T``.

Time scales: GPS = TAI - 19 s exactly; TT = TAI + 32.184 s; UTC from TAI by the leap seconds
that astropy carries (no download); UT1 = UTC + (UT1 - UTC), the IERS value given by the
caller (a Sentinel-2 product ships its own, in its UT1-UTC file and in the datastrip's IERS
bulletin), and the pole coordinates x_p, y_p likewise. Nothing is downloaded: astropy's IERS
auto-download is switched off before any astropy time is built.

The library is astropy's ERFA binding (``pyerfa``, installed with astropy): the ``space`` extra.
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike

from geoloc.extras import require

#: GPS time = TAI - 19 s (the offset fixed when GPS time began, 1980-01-06).
GPS_MINUS_TAI_S = -19.0
#: TT = TAI + 32.184 s (IAU 1991 Resolution A4).
TT_MINUS_TAI_S = 32.184
#: one arcsecond [rad]
ARCSEC = np.pi / (180.0 * 3600.0)
_DAY_S = 86400.0


def _astropy_time():
    """astropy.time, with the IERS auto-download off: geoloc downloads nothing at run time."""
    require("astropy", "Earth orientation (Sentinel-2 frames)")
    from astropy.utils import iers

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    from astropy import time

    return time


@dataclass(frozen=True)
class EarthOrientation:
    """IERS Earth orientation values by UTC day, interpolated linearly between days.

    Attributes
    ----------
    mjd_utc : ndarray (K,)
        Modified Julian dates (UTC) of the values, increasing.
    ut1_utc_s : ndarray (K,)
        UT1 - UTC [s].
    xp_arcsec, yp_arcsec : ndarray (K,)
        Pole coordinates [arcsec] (IERS Bulletin A columns x, y).
    source : str
        Where the values came from (for error messages).
    """

    mjd_utc: np.ndarray
    ut1_utc_s: np.ndarray
    xp_arcsec: np.ndarray
    yp_arcsec: np.ndarray
    source: str = ""

    def __post_init__(self):
        mjd = np.atleast_1d(np.asarray(self.mjd_utc, float))
        for name in ("ut1_utc_s", "xp_arcsec", "yp_arcsec"):
            v = np.atleast_1d(np.asarray(getattr(self, name), float))
            if v.shape != mjd.shape or not np.all(np.isfinite(v)):
                raise ValueError(f"{self.source}: {name} must be {mjd.size} finite values, got {v.shape}")
            object.__setattr__(self, name, v)
        if mjd.size < 1 or not np.all(np.diff(mjd) > 0):
            raise ValueError(f"{self.source}: mjd_utc must be increasing, got {mjd[:4].tolist()}")
        object.__setattr__(self, "mjd_utc", mjd)

    def at(self, mjd_utc: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(UT1-UTC [s], x_p [rad], y_p [rad]) at the UTC dates ``mjd_utc``.

        Raises ValueError for a date outside the table (one day of margin): values are never
        extrapolated (a prediction older than its date would move a ground point by ~460 m
        per second of UT1 error at the equator).
        """
        mjd = np.asarray(mjd_utc, float)
        lo, hi = self.mjd_utc[0] - 1.0, self.mjd_utc[-1] + 1.0
        if np.any(~np.isfinite(mjd)) or np.any(mjd < lo) or np.any(mjd > hi):
            raise ValueError(
                f"{self.source}: date MJD {np.nanmin(mjd):.3f}..{np.nanmax(mjd):.3f} is outside the "
                f"Earth orientation table (MJD {self.mjd_utc[0]:.0f}..{self.mjd_utc[-1]:.0f})"
            )
        if self.mjd_utc.size == 1:
            f = lambda v: np.full(mjd.shape, v[0])  # noqa: E731
        else:
            f = lambda v: np.interp(mjd, self.mjd_utc, v)  # noqa: E731
        return f(self.ut1_utc_s), f(self.xp_arcsec) * ARCSEC, f(self.yp_arcsec) * ARCSEC


def gps_to_astropy(t_gps: ArrayLike) -> Any:
    """GPS dates (``numpy.datetime64``, any precision) -> astropy ``Time`` in TAI.

    GPS time is TAI - 19 s by definition, so the date read as TAI is moved 19 s on.
    """
    time = _astropy_time()
    t = np.asarray(t_gps, "datetime64[ns]")
    # split into whole days and the rest: two doubles keep the nanoseconds (ERFA's two-part dates)
    days = t.astype("datetime64[D]")
    frac_s = (t - days).astype("timedelta64[ns]").astype(np.int64) * 1e-9 - GPS_MINUS_TAI_S
    jd1 = days.astype(np.int64).astype(float) + 2440587.5  # 1970-01-01 is JD 2440587.5
    return time.Time(jd1, frac_s / _DAY_S, format="jd", scale="tai")


def utc_to_gps(t_utc: ArrayLike) -> np.ndarray:
    """UTC dates (datetime64) -> the same instants as GPS dates (datetime64[ns]): + (TAI-UTC) - 19 s.

    TAI - UTC (the leap seconds) from astropy's own table (37 s since 2017: GPS = UTC + 18 s).
    """
    time = _astropy_time()
    t = np.asarray(t_utc, "datetime64[ns]")
    days = t.astype("datetime64[D]")
    frac_s = (t - days).astype("timedelta64[ns]").astype(np.int64) * 1e-9
    jd1 = days.astype(np.int64).astype(float) + 2440587.5
    tu = time.Time(jd1, frac_s / _DAY_S, format="jd", scale="utc")
    tai = tu.tai
    tai_minus_utc = ((tai.jd1 - tu.jd1) + (tai.jd2 - tu.jd2)) * _DAY_S
    shift_ns = np.round((tai_minus_utc + GPS_MINUS_TAI_S) * 1e9).astype(np.int64)
    return t + shift_ns.astype("timedelta64[ns]")


def R_itrs_eme2000(t_gps: ArrayLike, eop: EarthOrientation) -> np.ndarray:
    """The rotation EME2000 -> ITRS at GPS dates ``t_gps``: ``v_itrs = R @ v_eme2000``.

    ``c2t06a`` (IAU 2006/2000A precession-nutation, Earth rotation angle from UT1, polar
    motion with the TIO locator s') times the transposed frame bias of ``bp06``
    (IERS Conventions 2010, eq. 5.1 and 5.21).

    Parameters
    ----------
    t_gps : array_like of datetime64
    eop : EarthOrientation
        UT1-UTC and the pole, e.g. from the product's IERS file.

    Returns
    -------
    ndarray (..., 3, 3)
    """
    erfa = require("erfa", "Earth orientation (Sentinel-2 frames)")
    t_tai = gps_to_astropy(t_gps)
    t_utc = t_tai.utc
    mjd_utc = t_utc.mjd
    dut1, xp, yp = eop.at(mjd_utc)
    tt1, tt2 = t_tai.jd1, t_tai.jd2 + TT_MINUS_TAI_S / _DAY_S
    ut11, ut12 = t_utc.jd1, t_utc.jd2 + dut1 / _DAY_S
    c2t = erfa.c2t06a(tt1, tt2, ut11, ut12, xp, yp)
    rb, _, _ = erfa.bp06(tt1, tt2)
    return c2t @ np.swapaxes(rb, -1, -2)


def eme2000_to_itrs(
    t_gps: ArrayLike, eop: EarthOrientation, position: ArrayLike, velocity: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Inertial (EME2000) position and velocity -> ITRS, at GPS dates ``t_gps``.

    The velocity is the Earth-fixed one: the rotated inertial velocity minus omega x r, with the
    Earth's angular velocity from the rotation itself (its derivative by a centred difference
    over 1 s: the rotation's second derivative changes the result by < 1e-9 m/s).
    """
    R = R_itrs_eme2000(t_gps, eop)
    p = np.einsum("...ij,...j->...i", R, np.asarray(position, float))
    if velocity is None:
        return p, None
    t = np.asarray(t_gps, "datetime64[ns]")
    dt = np.timedelta64(500_000_000, "ns")
    dR = (R_itrs_eme2000(t + dt, eop) - R_itrs_eme2000(t - dt, eop)) / 1.0
    v = np.einsum("...ij,...j->...i", R, np.asarray(velocity, float)) + np.einsum(
        "...ij,...j->...i", dR, np.asarray(position, float)
    )
    return p, v


@dataclass(frozen=True)
class EarthRotationTable:
    """``R_itrs_eme2000`` tabulated every ``step_s`` over a time span and interpolated linearly.

    Between samples 0.5 s apart the Earth turns by 3.6e-5 rad; linear interpolation of the
    matrix elements departs from the rotation by at most (omega dt)^2 / 8 = 1.7e-10 rad
    (0.1 mm at 800 km), so a pushbroom's thousands of line times cost a few dozen ERFA calls;
    the blend is made orthogonal again (one Newton-Schulz step), so its transpose inverts it.

    Attributes
    ----------
    epoch : datetime64
        GPS date of t = 0.
    t_s : ndarray (K,)
        Sample times [s from the epoch].
    R : ndarray (K, 3, 3)
        EME2000 -> ITRS at the samples.
    """

    epoch: np.datetime64
    t_s: np.ndarray
    R: np.ndarray

    @classmethod
    def build(
        cls, epoch: np.datetime64 | str, t_start_s: float, t_end_s: float, eop: EarthOrientation, step_s: float = 0.5
    ) -> EarthRotationTable:
        n = max(2, int(np.ceil((t_end_s - t_start_s) / step_s)) + 1)
        t = t_start_s + np.arange(n) * step_s
        t_epoch = np.asarray(epoch, "datetime64[ns]")
        dates = t_epoch + (t * 1e9).round().astype("timedelta64[ns]")
        return cls(cast(np.datetime64, t_epoch[()]), t, R_itrs_eme2000(dates, eop))

    def R_ecef_in(self, t: ArrayLike) -> np.ndarray:
        """EME2000 -> ITRS at times ``t`` [s from the epoch] (..., 3, 3); NaN outside the table."""
        t = np.asarray(t, float)
        x = (t - self.t_s[0]) / (self.t_s[1] - self.t_s[0])
        i = np.clip(np.floor(np.nan_to_num(x)).astype(int), 0, self.t_s.size - 2)
        f = (x - i)[..., None, None]
        out = self.R[i] * (1.0 - f) + self.R[i + 1] * f
        # the blend is 1.7e-10 from orthogonal: one Newton-Schulz step, R <- (3R - R R^T R) / 2,
        # squares that to 1e-20, so that R^T is R's inverse (a sensor's inverse uses R^T)
        out = 1.5 * out - 0.5 * out @ np.swapaxes(out, -1, -2) @ out
        outside = ~((t >= self.t_s[0]) & (t <= self.t_s[-1]))
        return np.where(outside[..., None, None], np.nan, out)


__all__ = [
    "EarthRotationTable",
    "ARCSEC",
    "EarthOrientation",
    "GPS_MINUS_TAI_S",
    "R_itrs_eme2000",
    "TT_MINUS_TAI_S",
    "eme2000_to_itrs",
    "gps_to_astropy",
    "utc_to_gps",
]
