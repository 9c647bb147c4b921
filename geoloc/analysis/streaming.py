"""Monte Carlo statistics in constant memory: samples in, chunk by chunk; no sample is kept.

:class:`StreamingStats` takes located samples (lat, lon, h, status) one chunk at a
time and gives, at the end, what :func:`geoloc.analysis.montecarlo.statistics`
gives for all samples at once:

* the mean, standard deviations and the full covariance of (lat, lon, h), merged
  chunk by chunk with the pairwise update of Chan, Golub and LeVeque (exact up to
  rounding; the offsets are taken from the first sample, so 1e9 samples lose no
  digits to the absolute latitude);
* the CEP of [Q17 eq. 18], from the streamed standard deviations;
* the empirical 50 % radius (the median horizontal distance to the mean point)
  from a fixed-bin two-dimensional histogram of the horizontal offsets.

The histogram is laid on the first chunk: centred on its mean, ``half_width``
standard deviations of the chunk on either side along north and east, ``bins``
cells a side (default 1024 x 1024 = 8 MB of counts). At the end each cell's count
is put at the cell's centre, the cells' distances to the final mean are sorted
and the 50 % radius is read off the cumulative counts, interpolated linearly.
A point moves by at most half a cell diagonal, so the radius is off by at most
``0.71 * 2 * half_width / bins`` standard deviations (0.011 sigma with the
defaults), and in practice far less, the displacements averaging out: 1e-4 of
the radius on normal clouds of 1e6 points, against a sampling error of the
median itself of 1e-3 (``tests/analysis/test_montecarlo_streaming.py``). Samples beyond
the histogram are counted as overflow (distance unknown, larger than the box):
the radius is exact unless the 50 % circle about the final mean leaves the box,
which :meth:`StreamingStats.result` reports as a warning and a NaN radius.

Conventions: ``docs/conventions.md`` (radians inside). See ``docs/montecarlo.md``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import meridian_radius, prime_vertical_radius
from geoloc.status import Status

#: Keys of the statistics (``geoloc montecarlo --out stats.json``, an interface other tools read);
#: :data:`geoloc.analysis.montecarlo.STATS_KEYS` is this tuple.
STATS_KEYS = (
    "mean_lat_deg",
    "mean_lon_deg",
    "mean_h_m",
    "std_lat_deg",
    "std_lon_deg",
    "std_h_m",
    "cep_m",
    "cep50_empirical_m",
)

#: Histogram cells per side and its half-width in standard deviations of the first chunk.
BINS = 1024
HALF_WIDTH_SIGMA = 8.0


def cep_eq18(s_lat: float, s_lon: float, lat: float, h: float) -> float:
    """[Q17 eq. 18]: sqrt((s_lon (R_N + h) cos phi)^2 + (s_lat (R_M + h))^2) [m] from standard
    deviations of latitude and longitude [rad] about the mean latitude and height."""
    return float(
        math.hypot(
            s_lon * (float(prime_vertical_radius(lat)) + h) * math.cos(lat), s_lat * (float(meridian_radius(lat)) + h)
        )
    )


def summary(m_lat: float, m_lon: float, m_h: float, s_lat: float, s_lon: float, s_h: float, cep50: float) -> dict:
    """The :data:`STATS_KEYS` from means and standard deviations [rad, m] and an empirical 50 % radius."""
    return {
        "mean_lat_deg": math.degrees(m_lat),
        "mean_lon_deg": math.degrees((m_lon + np.pi) % (2 * np.pi) - np.pi),
        "mean_h_m": float(m_h),
        "std_lat_deg": math.degrees(s_lat),
        "std_lon_deg": math.degrees(s_lon),
        "std_h_m": float(s_h),
        "cep_m": cep_eq18(s_lat, s_lon, m_lat, m_h),
        "cep50_empirical_m": cep50,
    }


class StreamingStats:
    """Mean, covariance, [Q17 eq. 18] CEP and empirical 50 % radius of samples fed in chunks.

    Parameters
    ----------
    bins : int
        Histogram cells per side (memory: 8 bytes x bins^2).
    half_width_sigma : float
        Half-width of the histogram in standard deviations of the first chunk.

    Examples
    --------
    >>> s = StreamingStats()
    >>> for lat, lon, h, st in chunks:           # doctest: +SKIP
    ...     s.add(lat, lon, h, st)
    >>> s.result()["cep50_empirical_m"]           # doctest: +SKIP
    """

    def __init__(self, bins: int = BINS, half_width_sigma: float = HALF_WIDTH_SIGMA):
        if bins < 2 or not half_width_sigma > 0:
            raise ValueError(f"bins = {bins!r} (>= 2), half_width_sigma = {half_width_sigma!r} (> 0)")
        self.bins = int(bins)
        self.half_width_sigma = float(half_width_sigma)
        self.n = 0  # OK samples
        self.n_failed = 0
        self.status_counts = np.zeros(len(Status), np.int64)
        self.ref: tuple[float, float, float] | None = None  # (lat, lon, h) of the first OK sample [rad, rad, m]
        self.mean = np.zeros(3)  # of (dlat, dlon, dh)
        self.m2 = np.zeros((3, 3))  # sum of outer products of deviations
        self.hist: np.ndarray | None = None  # (bins, bins) counts: rows north offset, columns east
        self.grid: tuple[float, float, float, float] | None = None  # (dlat0, dlon0, half_lat, half_lon) [rad]
        self.overflow = 0

    # ------------------------------------------------------------------ feeding
    def add(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike, status: ArrayLike | None = None) -> None:
        """Add a chunk: lat, lon [rad], h [m], status (OK samples only are used)."""
        lat = np.asarray(lat, float).ravel()
        lon = np.asarray(lon, float).ravel()
        h = np.asarray(h, float).ravel()
        ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
        if status is not None:
            st = np.asarray(status).ravel()
            ok &= st == Status.OK
            self.status_counts += np.bincount(st.astype(np.intp), minlength=len(Status))[: len(Status)]
        else:
            self.status_counts[Status.OK] += int(ok.sum())
            self.status_counts[Status.INVALID_INPUT] += int((~ok).sum())
        self.n_failed += int((~ok).sum())
        lat_ok, lon_ok, h_ok = lat[ok], lon[ok], h[ok]
        k = lat_ok.size
        if k == 0:
            return
        if self.ref is None:
            self.ref = (float(lat_ok[0]), float(lon_ok[0]), float(h_ok[0]))
        ref = self.ref
        x = np.empty((k, 3))
        x[:, 0] = lat_ok - ref[0]
        x[:, 1] = (lon_ok - ref[1] + np.pi) % (2 * np.pi) - np.pi  # no wrap at +-180 deg
        x[:, 2] = h_ok - ref[2]
        mb = x.mean(axis=0)
        dev = x - mb
        m2b = dev.T @ dev
        # pairwise merge (Chan, Golub and LeVeque 1979)
        n = self.n
        tot = n + k
        delta = mb - self.mean
        self.mean = self.mean + delta * (k / tot)
        self.m2 = self.m2 + m2b + np.outer(delta, delta) * (n * k / tot)
        self.n = tot
        self._histogram(x[:, 0], x[:, 1], mb, dev)

    def _histogram(self, dlat, dlon, mb, dev) -> None:
        if self.grid is None:
            if dlat.size < 2:
                self.overflow += dlat.size  # too few to lay the grid on (rare: a 1-sample chunk)
                return
            s = np.sqrt(np.maximum(np.diag(dev.T @ dev) / (dlat.size - 1), 0.0))
            tiny = 1e-15  # rad (6 nm): a cloud with no spread in one axis still gets a grid
            self.grid = (
                float(mb[0]),
                float(mb[1]),
                max(self.half_width_sigma * float(s[0]), tiny),
                max(self.half_width_sigma * float(s[1]), tiny),
            )
            self.hist = np.zeros((self.bins, self.bins), np.int64)
        assert self.hist is not None  # laid out with the grid
        c_lat, c_lon, hw_lat, hw_lon = self.grid
        b = self.bins
        i = np.floor((dlat - (c_lat - hw_lat)) * (b / (2 * hw_lat)))
        j = np.floor((dlon - (c_lon - hw_lon)) * (b / (2 * hw_lon)))
        inside = (i >= 0) & (i < b) & (j >= 0) & (j < b)
        self.overflow += int((~inside).sum())
        flat = i[inside].astype(np.int64) * b + j[inside].astype(np.int64)
        self.hist += np.bincount(flat, minlength=b * b).reshape(b, b)

    def merge(self, other: "StreamingStats") -> None:
        """Add another accumulator's samples (same reference and grid, e.g. a copy of this one)."""
        if other.n == 0:
            self.n_failed += other.n_failed
            self.status_counts += other.status_counts
            return
        if self.n and (other.ref != self.ref or other.grid != self.grid):
            raise ValueError("merge needs accumulators with the same reference point and grid")
        n, k = self.n, other.n
        tot = n + k
        delta = other.mean - self.mean
        self.mean = self.mean + delta * (k / tot)
        self.m2 = self.m2 + other.m2 + np.outer(delta, delta) * (n * k / tot)
        if self.n == 0:
            self.ref, self.grid = other.ref, other.grid
            self.hist = None if other.hist is None else other.hist.copy()
        elif other.hist is not None:
            self.hist += other.hist
        self.n = tot
        self.n_failed += other.n_failed
        self.overflow += other.overflow
        self.status_counts += other.status_counts

    # ------------------------------------------------------------------ results
    @property
    def covariance(self) -> np.ndarray:
        """Sample covariance (ddof 1) of (lat [rad], lon [rad], h [m]), 3 x 3; NaN if n < 2."""
        if self.n < 2:
            return np.full((3, 3), np.nan)
        return self.m2 / (self.n - 1)

    def covariance_neu_m2(self) -> np.ndarray:
        """The covariance in local metres: north, east, up [m^2] at the mean point."""
        m_lat, _, m_h = self._mean_abs()
        k = np.diag([meridian_radius(m_lat) + m_h, (prime_vertical_radius(m_lat) + m_h) * math.cos(m_lat), 1.0])
        return k @ self.covariance @ k

    def _mean_abs(self):
        return (self.ref[0] + self.mean[0], self.ref[1] + self.mean[1], self.ref[2] + self.mean[2])

    def cep50(self) -> tuple[float, str | None]:
        """The empirical 50 % radius [m] from the histogram, and a warning (or None)."""
        if self.n < 2 or self.hist is None or self.grid is None:
            return math.nan, None
        m_lat, _, m_h = self._mean_abs()
        kn = meridian_radius(m_lat) + m_h
        ke = (prime_vertical_radius(m_lat) + m_h) * math.cos(m_lat)
        c_lat, c_lon, hw_lat, hw_lon = self.grid
        b = self.bins
        centres_lat = c_lat - hw_lat + (np.arange(b) + 0.5) * (2 * hw_lat / b)
        centres_lon = c_lon - hw_lon + (np.arange(b) + 0.5) * (2 * hw_lon / b)
        north = (centres_lat - self.mean[0]) * kn
        east = (centres_lon - self.mean[1]) * ke
        counts = self.hist.ravel()
        nz = np.flatnonzero(counts)
        r = np.hypot(north[nz // b], east[nz % b])
        order = np.argsort(r, kind="stable")
        r, c = r[order], counts[nz][order]
        cum = np.cumsum(c)
        # the median as np.median has it: the mean of the order statistics (n-1)/2 and n/2 (0-based)
        vals = []
        for q in ((self.n - 1) // 2, self.n // 2):
            k = int(np.searchsorted(cum, q + 1))  # first cell holding order statistic q
            if k >= len(r):
                return math.nan, (
                    f"the 50 % radius lies beyond the histogram ({self.overflow} of {self.n} samples outside it)"
                )
            # spread the cell's points evenly between the previous cell's radius and its own
            lo = r[k - 1] if k > 0 else 0.0
            before = cum[k - 1] if k > 0 else 0
            vals.append(lo + (r[k] - lo) * (q + 1 - before) / c[k])
        r50 = 0.5 * (vals[0] + vals[1])
        warn = None
        if self.overflow:
            # the circle about the mean must lie in the box for the overflow to be farther out
            d_lat = abs(self.mean[0] - c_lat) * kn
            d_lon = abs(self.mean[1] - c_lon) * ke
            if r50 + d_lat > hw_lat * kn or r50 + d_lon > hw_lon * ke:
                return math.nan, (
                    f"the 50 % circle leaves the histogram ({self.overflow} of "
                    f"{self.n} samples outside it): no empirical radius"
                )
        return float(r50), warn

    def result(self) -> dict:
        """The :data:`STATS_KEYS`, ``n_ok``, ``n_failed``, the covariance.

        Extra keys: ``cov_neu_m2`` (3 x 3 list, north-east-up metres),
        ``cep50_method`` ("histogram") and ``warnings`` (list of str).
        """
        warnings: list[str] = []
        out: dict[str, Any] = {k: math.nan for k in STATS_KEYS}
        out.update(n_ok=int(self.n), n_failed=int(self.n_failed), warnings=warnings)
        if self.n < 2:
            return out
        m_lat, m_lon, m_h = self._mean_abs()
        s_lat, s_lon, s_h = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        r50, warn = self.cep50()
        out.update(summary(m_lat, m_lon, m_h, s_lat, s_lon, s_h, r50))
        out["cov_neu_m2"] = self.covariance_neu_m2().tolist()
        out["cep50_method"] = "histogram"
        if warn:
            warnings.append(warn)
        return out
