"""Accuracy report of located targets against reference positions: CEP, CE90, LE90, bias, trends.

The numbers drone and flight-test accuracy reports publish,
from per-target errors **computed minus reference**:

* :func:`error_components`: the error vector in the reference point's local
  NED frame (:func:`geoloc.geodesy.local.geodetic_to_ned`): north, east, up
  (= -down), horizontal (``hypot(north, east)``), vertical (= up), slant (3D
  length), and along / across the platform's track when its heading is given
  (along positive forward, across positive to the right of track).
* :func:`robust_outliers`: the median / MAD rule (modified z-score of Iglewicz
  and Hoaglin, with a floor in metres), the one rule the KLV replay also uses
  (:func:`geoloc.workflows.klv_replay.outlier_mask` calls :func:`outlier_rule`).
* :func:`accuracy_report`: per group (flight) and overall, an :class:`AccuracyReport`.

Definitions (every one stated again in :attr:`AccuracyReport.meta`):

* **CEP** = the 50th percentile of the horizontal errors; **CE90** = the 90th
  percentile of the horizontal errors; **LE90** = the 90th percentile of the
  absolute vertical errors ``|up|``. Percentiles are numpy's default
  (``np.percentile(..., method="linear")``: linear interpolation between order
  statistics, Hyndman and Fan's definition 7). These are empirical
  percentiles of the errors about the **reference** (bias included), as drone
  accuracy tests publish them.
* [Q17 eq. 18]'s radial RMS is a different figure and keeps its own name,
  ``radial_rms_eq18_m``: :func:`geoloc.analysis.streaming.cep_eq18` of the
  standard deviations (ddof = 1) of the north and east errors, i.e. the spread
  about the mean error (bias removed).
* **MAE**: mean of the horizontal errors and mean of ``|up|``.
* **Bias vector**: the means of north, east, up (and along, across).
* **Trends**: medians of the horizontal and of ``|up|`` errors in bins of slant
  range, off-nadir angle and pixel radius from the image centre (bins of equal
  counts: edges at the quantiles of the variable, :data:`N_BINS` bins at most,
  at least :data:`MIN_PER_BIN` targets each).
* **Linear model in slant range**: ``horizontal_m = intercept_m + m_per_m * slant_range_m``,
  ordinary least squares (``np.linalg.lstsq``) over the targets with both finite.
* **Datum warning**: with ``n >= 3`` vertical errors, when
  ``|mean(up)| > DATUM_SE_FACTOR x SE`` (SE = std(up, ddof=1) / sqrt(n)) **and**
  ``|mean(up)| > DATUM_MIN_BIAS_M``: a vertical offset shared by all targets and
  large against their spread is what a height in the wrong datum looks like
  (ellipsoid vs mean sea level differ by the geoid undulation N, tens of metres).

NaN rows (a failed location, a missing reference) stay NaN in the components and
are left out of every statistic; each statistic says its own ``n``.

Conventions: ``docs/conventions.md`` (degrees only at the edges, heights
ellipsoidal WGS-84). See ``docs/report.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.analysis.streaming import cep_eq18
from geoloc.geodesy.ellipsoid import meridian_radius, prime_vertical_radius
from geoloc.geodesy.local import geodetic_to_ned

_GEOD = None


def _geod():
    global _GEOD
    if _GEOD is None:
        from pyproj import Geod

        _GEOD = Geod(ellps="WGS84")
    return _GEOD


__all__ = [
    "DATUM_MIN_BIAS_M",
    "DATUM_SE_FACTOR",
    "MAD_SCALE",
    "MIN_EXCESS_M",
    "OUTLIER_K",
    "AccuracyReport",
    "accuracy_report",
    "binned_medians",
    "datum_warning",
    "error_components",
    "linear_model",
    "outlier_rule",
    "robust_outliers",
    "sight_geometry",
    "track_azimuth_rad",
]

#: Outlier cut in robust standard deviations (1.4826 MAD): the modified z-score cut of Iglewicz and Hoaglin.
OUTLIER_K = 3.5
#: Normal-consistency factor of the MAD (1 / Phi^-1(3/4)).
MAD_SCALE = 1.4826
#: Smallest departure from the median flagged as an outlier [m].
MIN_EXCESS_M = 1.0
#: Datum warning: |mean up| must exceed this many standard errors of the mean ...
DATUM_SE_FACTOR = 3.0
#: ... and this many metres (smaller shared offsets are left to the bias line) [m].
DATUM_MIN_BIAS_M = 5.0
#: Bins of the trend tables at most, and targets per bin at least.
N_BINS = 5
MIN_PER_BIN = 3

PERCENTILE_TEXT = (
    "numpy's default percentile (method='linear': linear interpolation between order "
    "statistics, Hyndman-Fan definition 7)"
)


# --------------------------------------------------------------------------- ranges

#: Valid range of each kind of position value (inclusive): latitude [deg], longitude [deg]
#: (0-360 accepted, as the records' columns), ellipsoidal height [m] (the records' aircraft
#: range: below the deepest sea floor to beyond the Moon).
POSITION_RANGES = {"lat": (-90.0, 90.0), "lon": (-180.0, 360.0), "h": (-1.2e4, 1.0e8)}


def position_kind(name: str) -> str | None:
    """``"lat"``, ``"lon"`` or ``"h"`` for a position column name (``*lat_deg``, ``*lon_deg``,
    ``*h_m``, ``*height_m``), else None."""
    if name.endswith("lat_deg"):
        return "lat"
    if name.endswith("lon_deg"):
        return "lon"
    if name.endswith("_h_m") or name == "h_m" or name.endswith("height_m"):
        return "h"
    return None


def out_of_range(values: ArrayLike, kind: str) -> np.ndarray:
    """True where a finite value lies outside :data:`POSITION_RANGES` ``[kind]`` (NaN: missing, not out)."""
    lo, hi = POSITION_RANGES[kind]
    v = np.asarray(values, float)
    return np.isfinite(v) & ((v < lo) | (v > hi))


def _check_ranges(**named):
    """ValueError naming the argument, the first index and value out of its range (a
    latitude of 95 gave a CE90 of 1 091 124 m without a word)."""
    for name, v in named.items():
        if v is None:
            continue
        kind = position_kind(name)
        bad = np.flatnonzero(np.ravel(out_of_range(v, kind)))
        if bad.size:
            lo, hi = POSITION_RANGES[kind]
            k = int(bad[0])
            raise ValueError(
                f"{name}[{k}] = {float(np.ravel(np.asarray(v, float))[k]):g} is out of range "
                f"[{lo:g}, {hi:g}] ({bad.size} value(s) out of range)"
            )


# --------------------------------------------------------------------------- components


def error_components(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    h_m: ArrayLike,
    ref_lat_deg: ArrayLike,
    ref_lon_deg: ArrayLike,
    ref_h_m: ArrayLike,
    *,
    track_heading_rad: ArrayLike | None = None,
) -> dict:
    """Error vector (computed minus reference) in the reference point's local frame.

    ``(north, east, down) = geodetic_to_ned(computed; origin = reference)``
    (:func:`geoloc.geodesy.local.geodetic_to_ned`, checked against pymap3d's
    ``geodetic2ned``); ``up = -down``. Where the reference height is NaN (a
    surveyed truth without height) the reference is taken at the computed
    height, so north and east are the horizontal error, and ``up_m`` /
    ``vertical_m`` are NaN. Along / across track, with the track azimuth psi
    (clockwise from north): ``along = north cos psi + east sin psi`` (forward
    positive), ``across = east cos psi - north sin psi`` (right of track positive).

    Parameters
    ----------
    lat_deg, lon_deg, h_m : array_like
        Computed positions [deg, deg, m ellipsoidal WGS-84].
    ref_lat_deg, ref_lon_deg, ref_h_m : array_like
        Reference (truth or reported) positions [deg, deg, m ellipsoidal WGS-84].
    track_heading_rad : array_like, optional
        Track azimuth of the platform at each target [rad, clockwise from north].

    Returns
    -------
    dict of ndarray
        ``north_m, east_m, up_m, horizontal_m, vertical_m, slant_m`` and, with a
        track, ``along_m, across_m``; all broadcast to one shape. A row with a
        NaN in the computed position or the reference's latitude / longitude is
        NaN in every key.
    """
    lat, lon, h, rlat, rlon, rh = np.broadcast_arrays(
        *(np.asarray(v, float) for v in (lat_deg, lon_deg, h_m, ref_lat_deg, ref_lon_deg, ref_h_m))
    )
    no_ref_h = ~np.isfinite(rh)
    rh_used = np.where(no_ref_h, h, rh)
    ned = geodetic_to_ned(np.deg2rad(lat), np.deg2rad(lon), h, np.deg2rad(rlat), np.deg2rad(rlon), rh_used)
    north, east, up = ned[..., 0], ned[..., 1], -ned[..., 2]
    up = np.where(no_ref_h, np.nan, up)
    horizontal = np.hypot(north, east)
    slant = np.where(no_ref_h, horizontal, np.sqrt(north**2 + east**2 + np.nan_to_num(up) ** 2))
    slant = np.where(np.isfinite(horizontal), slant, np.nan)
    out = {
        "north_m": north,
        "east_m": east,
        "up_m": up,
        "horizontal_m": horizontal,
        "vertical_m": up.copy(),
        "slant_m": slant,
    }
    if track_heading_rad is not None:
        psi = np.broadcast_to(np.asarray(track_heading_rad, float), north.shape)
        out["along_m"] = north * np.cos(psi) + east * np.sin(psi)
        out["across_m"] = east * np.cos(psi) - north * np.sin(psi)
    return out


# --------------------------------------------------------------------------- geometry of each target


#: Below this baseline between neighbouring platform positions [m] the track falls back to the heading.
MIN_TRACK_BASELINE_M = 100.0


def track_azimuth_rad(
    platform_lat_deg: ArrayLike,
    platform_lon_deg: ArrayLike,
    group: ArrayLike | None = None,
    heading_rad: ArrayLike | None = None,
    min_baseline_m: float = MIN_TRACK_BASELINE_M,
) -> np.ndarray:
    """The platform's local track azimuth at each target [rad, clockwise from north].

    Within each group, in input order, the geodesic azimuth (WGS-84, pyproj)
    from the previous platform position to the next one (one-sided at the ends);
    where those are less than ``min_baseline_m`` apart (a hover, repeated
    positions) or missing, the heading (crab angle then ignored), else NaN. A
    local track follows turns, where one first-to-last azimuth per flight
    (:func:`geoloc.analysis.errors.track_azimuths`) does not.
    """
    lat = np.asarray(platform_lat_deg, float).ravel()
    lon = np.asarray(platform_lon_deg, float).ravel()
    n = lat.size
    grp = np.zeros(n, dtype=object) if group is None else np.asarray(group, dtype=object).ravel()
    head = np.full(n, np.nan) if heading_rad is None else np.broadcast_to(np.asarray(heading_rad, float), (n,))
    out = np.array(head, float)
    for g in dict.fromkeys(grp.tolist()):
        idx = np.flatnonzero((grp == g) & np.isfinite(lat) & np.isfinite(lon))
        if idx.size < 2:
            continue
        prev = idx[np.maximum(np.arange(idx.size) - 1, 0)]
        nxt = idx[np.minimum(np.arange(idx.size) + 1, idx.size - 1)]
        az, _, dist = _geod().inv(lon[prev], lat[prev], lon[nxt], lat[nxt])
        good = np.asarray(dist) > min_baseline_m
        out[idx[good]] = np.deg2rad(np.asarray(az)[good])
    return out


def sight_geometry(
    platform_lat_deg: ArrayLike,
    platform_lon_deg: ArrayLike,
    platform_h_m: ArrayLike,
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    h_m: ArrayLike,
) -> dict:
    """Slant range and off-nadir angle of each target from its platform position.

    The target in the platform's local NED frame (:func:`geoloc.geodesy.local.geodetic_to_ned`):
    ``slant_range_m = |(n, e, d)|``, ``off_nadir_rad = atan2(hypot(n, e), d)``
    (0 straight down along the ellipsoid normal, pi/2 at the horizon).
    Heights ellipsoidal.
    """
    ned = geodetic_to_ned(
        np.deg2rad(np.asarray(lat_deg, float)),
        np.deg2rad(np.asarray(lon_deg, float)),
        np.asarray(h_m, float),
        np.deg2rad(np.asarray(platform_lat_deg, float)),
        np.deg2rad(np.asarray(platform_lon_deg, float)),
        np.asarray(platform_h_m, float),
    )
    n, e, d = ned[..., 0], ned[..., 1], ned[..., 2]
    return {"slant_range_m": np.sqrt(n * n + e * e + d * d), "off_nadir_rad": np.arctan2(np.hypot(n, e), d)}


# --------------------------------------------------------------------------- outliers


def outlier_rule(
    residual_m: ArrayLike, k: float = OUTLIER_K, min_excess_m: float = MIN_EXCESS_M
) -> tuple[np.ndarray, float, float, float]:
    """Robust outlier flags with their figures: ``|e - median| > max(k x 1.4826 x MAD, min_excess_m)``.

    MAD is the median absolute deviation from the median; 1.4826 MAD estimates
    the standard deviation of normal errors, so ``k = 3.5`` is the modified
    z-score cut of Iglewicz and Hoaglin (1993); the floor keeps errors that are
    all at a quantisation level (millimetres) from flagging noise.

    Parameters
    ----------
    residual_m : array_like
        Residuals or errors [m]; NaN entries are ignored and never flagged.
    k : float
        Cut in robust standard deviations.
    min_excess_m : float
        Smallest departure from the median that is flagged [m].

    Returns
    -------
    (mask, median, mad, threshold)
        ``mask`` (bool, the shape of ``residual_m``); the median, the MAD and the
        cut on ``|e - median|`` [m] (NaN when nothing is finite).
    """
    e = np.asarray(residual_m, float)
    ok = np.isfinite(e)
    if not ok.any():
        return np.zeros(e.shape, bool), math.nan, math.nan, math.nan
    med = float(np.median(e[ok]))
    mad = float(np.median(np.abs(e[ok] - med)))
    thr = max(k * MAD_SCALE * mad, float(min_excess_m))
    with np.errstate(invalid="ignore"):
        mask = ok & (np.abs(e - med) > thr)
    return mask, med, mad, thr


def robust_outliers(residual_m: ArrayLike, k: float = OUTLIER_K, min_excess_m: float = MIN_EXCESS_M) -> np.ndarray:
    """Outlier flags of :func:`outlier_rule` (median / MAD, floor ``min_excess_m``): a bool array."""
    return outlier_rule(residual_m, k, min_excess_m)[0]


# --------------------------------------------------------------------------- statistics


def _finite(v):
    v = np.asarray(v, float).ravel()
    return v[np.isfinite(v)]


def _pct(v, q) -> float:
    v = _finite(v)
    return float(np.percentile(v, q)) if v.size else math.nan


def _mean(v) -> float:
    v = _finite(v)
    return float(v.mean()) if v.size else math.nan


def binned_medians(
    x: ArrayLike, y: ArrayLike, n_bins: int = N_BINS, min_per_bin: int = MIN_PER_BIN, y2: ArrayLike | None = None
) -> list:
    """Medians of ``y`` (and ``y2``) in bins of ``x`` of equal counts.

    Edges are the quantiles of the finite ``x`` (numpy's linear definition);
    ``min(n_bins, n // min_per_bin)`` bins (at least one when any pair is
    finite). The last bin is closed on the right.

    Returns
    -------
    list of dict
        ``lo, hi, n, x_median, median`` (and ``median2`` with ``y2``) per bin.
    """
    x = np.asarray(x, float).ravel()
    y = np.asarray(y, float).ravel()
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return []
    nb = max(1, min(n_bins, int(ok.sum()) // max(min_per_bin, 1)))
    edges = np.quantile(x[ok], np.linspace(0.0, 1.0, nb + 1))
    out = []
    for j in range(nb):
        lo, hi = edges[j], edges[j + 1]
        m = ok & (x >= lo) & ((x <= hi) if j == nb - 1 else (x < hi))
        if not m.any():
            continue
        row = {
            "lo": float(lo),
            "hi": float(hi),
            "n": int(m.sum()),
            "x_median": float(np.median(x[m])),
            "median": float(np.median(y[m])),
        }
        if y2 is not None:
            v2 = np.asarray(y2, float).ravel()[m]
            v2 = v2[np.isfinite(v2)]
            row["median2"] = float(np.median(v2)) if v2.size else math.nan
        out.append(row)
    return out


def linear_model(x: ArrayLike, y: ArrayLike) -> dict:
    """Least-squares line ``y = intercept + slope x`` over the finite pairs (``np.linalg.lstsq``).

    Returns ``intercept_m, m_per_m, n, rms_residual_m`` (NaN with fewer than two
    distinct x).
    """
    x = np.asarray(x, float).ravel()
    y = np.asarray(y, float).ravel()
    ok = np.isfinite(x) & np.isfinite(y)
    n = int(ok.sum())
    if n < 2 or np.ptp(x[ok]) == 0:
        return {"intercept_m": math.nan, "m_per_m": math.nan, "n": n, "rms_residual_m": math.nan}
    A = np.stack([np.ones(n), x[ok]], axis=1)
    (c0, c1), *_ = np.linalg.lstsq(A, y[ok], rcond=None)
    res = y[ok] - (c0 + c1 * x[ok])
    return {"intercept_m": float(c0), "m_per_m": float(c1), "n": n, "rms_residual_m": float(np.sqrt(np.mean(res**2)))}


def datum_warning(up_m: ArrayLike) -> tuple:
    """``(text or None, mean_up_m, se_m)``: the datum rule of the module docstring on vertical errors."""
    u = _finite(up_m)
    if u.size < 3:
        return None, (float(u.mean()) if u.size else math.nan), math.nan
    mean = float(u.mean())
    se = float(u.std(ddof=1) / math.sqrt(u.size))
    if abs(mean) > DATUM_SE_FACTOR * se and abs(mean) > DATUM_MIN_BIAS_M:
        return (
            (
                f"vertical bias {mean:+.1f} m shared by all {u.size} targets (standard error {se:.2f} m): "
                "likely datum mismatch (ellipsoid vs MSL?)"
            ),
            mean,
            se,
        )
    return None, mean, se


def _radial_rms_eq18(north, east, lat_deg, h_m) -> float:
    ok = np.isfinite(north) & np.isfinite(east)
    if ok.sum() < 2:
        return math.nan
    lat = math.radians(float(np.nanmean(np.asarray(lat_deg, float)[ok])))
    hh = np.asarray(h_m, float)[ok]
    h = float(np.nanmean(hh)) if np.isfinite(hh).any() else 0.0
    s_lat = float(np.std(north[ok], ddof=1)) / (float(meridian_radius(lat)) + h)
    s_lon = float(np.std(east[ok], ddof=1)) / ((float(prime_vertical_radius(lat)) + h) * math.cos(lat))
    return cep_eq18(s_lat, s_lon, lat, h)


def _stats(comp: dict, m, extras: dict, lat_deg, h_m) -> dict:
    """Statistics of the rows ``m`` (bool) of the components."""
    hor = comp["horizontal_m"][m]
    up = comp["up_m"][m]
    absup = np.abs(up)
    warn, mean_up, se_up = datum_warning(up)
    flags, med, _mad, thr = outlier_rule(hor)
    s = {
        "n": int(np.isfinite(hor).sum()),
        "n_vertical": int(np.isfinite(up).sum()),
        "cep_m": _pct(hor, 50),
        "ce90_m": _pct(hor, 90),
        "le90_m": _pct(absup, 90),
        "mae_horizontal_m": _mean(hor),
        "mae_vertical_m": _mean(absup),
        "rmse_horizontal_m": float(np.sqrt(_mean(hor**2))),
        "max_horizontal_m": float(np.max(_finite(hor))) if _finite(hor).size else math.nan,
        "bias_north_m": _mean(comp["north_m"][m]),
        "bias_east_m": _mean(comp["east_m"][m]),
        "bias_up_m": mean_up,
        "bias_up_se_m": se_up,
        "bias_along_m": _mean(comp["along_m"][m]) if "along_m" in comp else math.nan,
        "bias_across_m": _mean(comp["across_m"][m]) if "across_m" in comp else math.nan,
        "radial_rms_eq18_m": _radial_rms_eq18(
            comp["north_m"][m], comp["east_m"][m], np.asarray(lat_deg)[m], np.asarray(h_m)[m]
        ),
        "datum_warning": warn,
        "outliers": [int(k) for k in np.flatnonzero(m)[flags]],
        "outlier_threshold_m": thr,
        "outlier_median_m": med,
    }
    for key, x in extras.items():
        if x is None:
            continue
        s[f"by_{key}"] = binned_medians(np.asarray(x)[m], hor, y2=absup)
    if extras.get("slant_range_m") is not None:
        s["slant_range_model"] = dict(linear_model(np.asarray(extras["slant_range_m"])[m], hor), error="horizontal_m")
    return s


# --------------------------------------------------------------------------- the report


def _clean(v):
    """JSON-ready: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def _f(v, spec=".2f") -> str:
    return "" if v is None or not math.isfinite(v) else format(v, spec)


#: Trend variables: key, column title, unit conversion for display.
TRENDS = (
    ("slant_range_m", "slant range [m]", 1.0),
    ("off_nadir_deg", "off-nadir [deg]", 1.0),
    ("pixel_radius_px", "pixel radius [px]", 1.0),
)


@dataclass
class AccuracyReport:
    """Accuracy statistics per group (flight) and over all targets.

    Attributes
    ----------
    groups : dict
        Group label -> statistics dict (keys in :func:`accuracy_report`).
    overall : dict
        The same statistics over every target.
    components : dict
        Per-target error components (:func:`error_components`) and the trend
        variables, arrays aligned with the input.
    group : ndarray
        Group label of every target.
    meta : dict
        Definitions: percentile, CEP/CE90/LE90, the datum rule, the outlier rule.
    """

    groups: dict
    overall: dict
    components: dict
    group: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def warnings(self) -> list:
        """Datum warnings, overall first then per group."""
        out = []
        if self.overall.get("datum_warning"):
            out.append(f"all: {self.overall['datum_warning']}")
        for g, s in self.groups.items():
            if s.get("datum_warning"):
                out.append(f"{g}: {s['datum_warning']}")
        return out

    def to_dict(self, per_target: bool = False) -> dict:
        """JSON-ready dict (NaN -> null): ``meta``, ``overall``, ``groups``, ``warnings`` (and the
        per-target components with ``per_target``)."""
        d: dict[str, Any] = {
            "meta": self.meta,
            "overall": self.overall,
            "groups": self.groups,
            "warnings": self.warnings,
        }
        if per_target:
            d["targets"] = {k: np.asarray(v).tolist() for k, v in self.components.items()}
            d["targets"]["group"] = [str(g) for g in self.group]
        return _clean(d)

    def rows(self) -> list:
        """(label, stats) pairs: each group, then ``all`` (only groups when there is one group)."""
        rows = list(self.groups.items())
        if len(rows) != 1:
            rows.append(("all", self.overall))
        return rows

    def markdown(self) -> str:
        """A markdown table of the main figures, the trend tables and the warnings."""
        head = (
            "| group | n | CEP [m] | CE90 [m] | LE90 [m] | MAE h [m] | MAE v [m] | bias N [m] | bias E [m] "
            "| bias U [m] | bias along [m] | bias across [m] | eq. 18 radial RMS [m] | outliers |"
        )
        L = [head, "|" + "---|" * 14]
        for g, s in self.rows():
            L.append(
                f"| {g} | {s['n']} | {_f(s['cep_m'])} | {_f(s['ce90_m'])} | {_f(s['le90_m'])} | "
                f"{_f(s['mae_horizontal_m'])} | {_f(s['mae_vertical_m'])} | {_f(s['bias_north_m'])} | "
                f"{_f(s['bias_east_m'])} | {_f(s['bias_up_m'])} | {_f(s['bias_along_m'])} | "
                f"{_f(s['bias_across_m'])} | {_f(s['radial_rms_eq18_m'])} | {len(s['outliers'])} |"
            )
        L.append("")
        L.append(
            "CEP = 50th, CE90 = 90th percentile of the horizontal errors; LE90 = 90th percentile of "
            "|vertical error|; " + PERCENTILE_TEXT + ". The eq. 18 radial RMS ([Q17]) is the spread "
            "about the mean error, not a CEP."
        )
        for g, s in self.rows():
            mdl = s.get("slant_range_model")
            if mdl and mdl["n"]:
                L.append(
                    f"\n{g}: horizontal error = {_f(mdl['intercept_m'], '.3f')} m + "
                    f"{_f(mdl['m_per_m'] * 1000.0, '.4f')} m per km of slant range (least squares, "
                    f"n = {mdl['n']}, RMS residual {_f(mdl['rms_residual_m'])} m)"
                )
            for key, title, _ in TRENDS:
                bins = s.get(f"by_{key}")
                if not bins:
                    continue
                L.append(f"\n{g}: median error by {title}\n")
                L.append(f"| {title} | n | median horizontal [m] | median |vertical| [m] |")
                L.append("|---|---|---|---|")
                for b in bins:
                    L.append(
                        f"| {_f(b['lo'], '.1f')} - {_f(b['hi'], '.1f')} | {b['n']} | {_f(b['median'])} | "
                        f"{_f(b.get('median2', math.nan))} |"
                    )
        for g, s in self.rows():
            b = s.get("budget")
            if b:
                L.append(f"\n{g}: {b['text']}")
                if b.get("vertical"):
                    L.append(f"{g}: {b['vertical']['text']}")
        if self.warnings:
            L.append("")
            L += [f"**warning** {w}" for w in self.warnings]
        return "\n".join(L)


def accuracy_report(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    h_m: ArrayLike,
    ref_lat_deg: ArrayLike,
    ref_lon_deg: ArrayLike,
    ref_h_m: ArrayLike,
    *,
    track_heading_rad: ArrayLike | None = None,
    slant_range_m: ArrayLike | None = None,
    off_nadir_rad: ArrayLike | None = None,
    pixel_radius_px: ArrayLike | None = None,
    group: ArrayLike | None = None,
    meta: dict | None = None,
) -> AccuracyReport:
    """Accuracy statistics of computed positions against references, per group and overall.

    Parameters
    ----------
    lat_deg, lon_deg, h_m : array_like, shape (n,)
        Computed positions [deg, deg, m ellipsoidal WGS-84].
    ref_lat_deg, ref_lon_deg, ref_h_m : array_like, shape (n,)
        Reference positions (NaN height: horizontal only, see :func:`error_components`).
    track_heading_rad : array_like, optional
        Track azimuth per target [rad]: adds along / across components and biases.
    slant_range_m, off_nadir_rad, pixel_radius_px : array_like, optional
        Trend variables per target (binned medians; the slant range also gets
        the linear model of the horizontal error).
    group : array_like of str, optional
        Flight of each target (default one group ``all``).
    meta : dict, optional
        Extra description merged into :attr:`AccuracyReport.meta` (e.g. the reference used).

    Raises
    ------
    ValueError
        A finite latitude, longitude or height outside :data:`POSITION_RANGES` (naming the
        argument, the index and the value): the caller drops such rows first, saying which.

    Returns
    -------
    AccuracyReport
        Each statistics dict has ``n, n_vertical, cep_m, ce90_m, le90_m,
        mae_horizontal_m, mae_vertical_m, rmse_horizontal_m, max_horizontal_m,
        bias_north_m, bias_east_m, bias_up_m, bias_up_se_m, bias_along_m,
        bias_across_m, radial_rms_eq18_m, datum_warning, outliers`` (indices into
        the input of the horizontal-error outliers of :func:`outlier_rule`),
        ``outlier_threshold_m, outlier_median_m``, ``by_slant_range_m``,
        ``by_off_nadir_deg``, ``by_pixel_radius_px`` (bins, when given) and
        ``slant_range_model``.
    """
    _check_ranges(
        lat_deg=lat_deg, lon_deg=lon_deg, h_m=h_m, ref_lat_deg=ref_lat_deg, ref_lon_deg=ref_lon_deg, ref_h_m=ref_h_m
    )
    comp = error_components(
        lat_deg, lon_deg, h_m, ref_lat_deg, ref_lon_deg, ref_h_m, track_heading_rad=track_heading_rad
    )
    comp = {k: np.ravel(v) for k, v in comp.items()}
    n = comp["north_m"].size
    grp = np.array(
        ["all"] * n if group is None else [str(g) for g in np.ravel(np.asarray(group, dtype=object))], dtype=object
    )
    if grp.size != n:
        raise ValueError(f"group has {grp.size} labels for {n} targets")

    def col(v, name, scale=1.0):
        if v is None:
            return None
        a = np.broadcast_to(np.asarray(v, float), (n,)) * scale
        return np.array(a)

    extras = {
        "slant_range_m": col(slant_range_m, "slant_range_m"),
        "off_nadir_deg": col(off_nadir_rad, "off_nadir_rad", 180.0 / math.pi),
        "pixel_radius_px": col(pixel_radius_px, "pixel_radius_px"),
    }
    lat = np.broadcast_to(np.asarray(lat_deg, float), (n,))
    h = np.broadcast_to(np.asarray(h_m, float), (n,))
    groups = {g: _stats(comp, grp == g, extras, lat, h) for g in dict.fromkeys(grp.tolist())}
    overall = _stats(comp, np.ones(n, bool), extras, lat, h)
    for k, v in extras.items():
        if v is not None:
            comp[k] = v
    info = {
        "error": "computed minus reference, in the reference point's local NED frame (geoloc.geodesy.local)",
        "cep": "50th percentile of the horizontal errors",
        "ce90": "90th percentile of the horizontal errors",
        "le90": "90th percentile of |vertical error|",
        "percentile": PERCENTILE_TEXT,
        "radial_rms_eq18": "[Q17] eq. 18 (geoloc.analysis.streaming.cep_eq18) of the std (ddof=1) of the north "
        "and east errors: spread about the mean error, not a CEP",
        "datum_rule": f"|mean up| > {DATUM_SE_FACTOR:g} x its standard error and > {DATUM_MIN_BIAS_M:g} m "
        "(n >= 3): likely datum mismatch (ellipsoid vs MSL?)",
        "outlier_rule": f"|horizontal - median| > max({OUTLIER_K:g} x {MAD_SCALE} x MAD, {MIN_EXCESS_M:g} m)",
        "bins": f"equal-count bins of the variable, at most {N_BINS}, at least {MIN_PER_BIN} targets each",
        "slant_range_model": "horizontal_m = intercept_m + m_per_m * slant_range_m, least squares",
        "heights": "ellipsoidal (WGS 84)",
    }
    info.update(meta or {})
    return AccuracyReport(groups=groups, overall=overall, components=comp, group=grp, meta=info)
