"""Flight-test error vectors: per-record decomposition, per-flight bias and outliers.

For each record with a surveyed truth (``truth_lat_deg``, ``truth_lon_deg``),
the error is the **computed minus the true** position, expressed

- north / east in the local ENU frame at the truth point (:mod:`geoloc.frames.enu`,
  the truth taken at the computed point's height, so the vector is horizontal);
- along-track / cross-track: along the flight's track (positive forward) and
  across it (positive to the right of track);
- in image pixels: the measured pixel minus the pixel at which the truth
  projects through the same frame chain (:func:`geoloc.locate.ground_to_pixel`).

The **track** of a flight is the geodesic azimuth from its first to its last
aircraft position (WGS-84, pyproj) when they are more than 100 m apart, else the
mean aircraft heading (crab angle then ignored).

Outlier rule (per flight, documented in ``docs/calibration.md``): with ``d_k``
the distance of record k's (east, north) error from the flight's component-wise
median error, the robust scale is ``sigma = median(d) / sqrt(2 ln 2)`` (the
median of a Rayleigh distribution is sigma sqrt(2 ln 2)), floored at
``min_sigma_m``; record k is an outlier if ``d_k > k_sigma * sigma``. With
``k_sigma = 3.5`` a Gaussian record is flagged with probability
exp(-3.5^2 / 2) = 0.2 %.

Conventions: ``docs/conventions.md`` (metres, radians inside, degrees at the edges).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pyproj import Geod

from geoloc.frames import rotations as rot
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.geodesy.local import R_ecef_enu
from geoloc.io.records import Records
from geoloc.locate import ground_to_pixel
from geoloc.sensors.frame import FrameSensor
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint
from geoloc.userfiles import atomic_path

_GEOD = Geod(ellps="WGS84")

#: Below this aircraft displacement [m] a flight's track falls back to its heading.
MIN_TRACK_BASELINE_M = 100.0


@dataclass
class ErrorVectors:
    """Per-record errors (computed minus truth), arrays aligned with the records.

    Attributes
    ----------
    east_m, north_m : ndarray
        Horizontal error in the ENU frame at the truth point [m].
    along_m, cross_m : ndarray
        The same vector along the flight's track and across it (positive right) [m].
    distance_m : ndarray
        Horizontal geodesic distance computed <-> truth [m] (pyproj).
    row_px, col_px : ndarray
        Measured pixel minus the projection of the truth point [pixels].
    track_azimuth : ndarray
        Track azimuth used for each record [rad, clockwise from north].
    status : ndarray of uint8
        The ground point's status; INVALID_INPUT where the record has no truth.
    """

    east_m: np.ndarray
    north_m: np.ndarray
    along_m: np.ndarray
    cross_m: np.ndarray
    distance_m: np.ndarray
    row_px: np.ndarray
    col_px: np.ndarray
    track_azimuth: np.ndarray
    status: np.ndarray

    def as_dict(self, k: int) -> dict:
        """The errors of record ``k`` as plain floats (NaN -> None) for JSON."""
        out = {}
        for name in ("east_m", "north_m", "along_m", "cross_m", "distance_m", "row_px", "col_px"):
            v = float(getattr(self, name)[k])
            out[name] = round(v, 4) if np.isfinite(v) else None
        return out


def group_labels(records: Records, group_column: str | None) -> np.ndarray:
    """The group of every record (a column's text), or ``"all"`` without a column."""
    if group_column is None:
        return np.array(["all"] * len(records), dtype=object)
    if group_column not in records.header:
        raise ValueError(f"{records.path}: no group column {group_column!r}; columns are {records.header}")
    return np.array(records.text(group_column), dtype=object)


def track_azimuths(records: Records, groups: ArrayLike | None) -> np.ndarray:
    """Track azimuth of each record's flight [rad] (see the module docstring)."""
    groups = np.asarray(groups, dtype=object)
    lat, lon = records.column("ac_lat_deg"), records.column("ac_lon_deg")
    heading = np.deg2rad(records.column("heading_deg"))
    out = np.empty(len(records))
    for g in dict.fromkeys(groups):
        m = np.flatnonzero(groups == g)
        az, _, dist = _GEOD.inv(lon[m[0]], lat[m[0]], lon[m[-1]], lat[m[-1]])
        if dist > MIN_TRACK_BASELINE_M:
            out[m] = np.deg2rad(az)
        else:  # circular mean of the headings
            out[m] = np.arctan2(np.sin(heading[m]).mean(), np.cos(heading[m]).mean())
    return out


def error_vectors(
    records: Records,
    camera: FrameSensor,
    ground: GroundPoint,
    groups: ArrayLike | None = None,
    truth_prefix: str = "truth",
) -> ErrorVectors:
    """Decompose every record's error against its surveyed truth.

    Parameters
    ----------
    records : Records
        Must have ``{truth_prefix}_lat_deg`` and ``{truth_prefix}_lon_deg``.
    camera : FrameSensor
        The sensor that computed ``ground`` (its boresight / mount included),
        for the pixel errors.
    ground : GroundPoint
        Computed positions, one per record (from a height column or a DEM).
    groups : array_like, optional
        Flight of each record (for the track); default one flight.

    Returns
    -------
    ErrorVectors
        NaN where the ground point failed or the truth is missing.
    """
    n = len(records)
    groups = np.array(["all"] * n, dtype=object) if groups is None else np.asarray(groups, dtype=object)
    tlat = np.deg2rad(records.column(f"{truth_prefix}_lat_deg"))
    tlon = np.deg2rad(records.column(f"{truth_prefix}_lon_deg"))
    h = ground.h
    ok = (ground.status == Status.OK) & np.isfinite(tlat) & np.isfinite(tlon)
    status = np.where(ground.status != Status.OK, ground.status, np.where(ok, Status.OK, Status.INVALID_INPUT)).astype(
        np.uint8
    )
    truth_ecef = geodetic_to_ecef(tlat, tlon, h)
    d_enu = rot.rotate(np.swapaxes(R_ecef_enu(tlat, tlon), -1, -2), ground.ecef - truth_ecef)
    east, north = d_enu[..., 0], d_enu[..., 1]
    az = track_azimuths(records, groups)
    # unit track vector in (east, north) = (sin az, cos az); right of it = (cos az, -sin az)
    along = east * np.sin(az) + north * np.cos(az)
    cross = east * np.cos(az) - north * np.sin(az)
    dist = horizontal_distance_m(ground.lat_deg, ground.lon_deg, np.rad2deg(tlat), np.rad2deg(tlon))
    ti, tj, pst = ground_to_pixel(records.pose(), camera, tlat, tlon, h)
    row_px = records.column("row") - ti
    col_px = records.column("col") - tj

    def nan(a):
        return np.where(ok, a, np.nan)

    return ErrorVectors(nan(east), nan(north), nan(along), nan(cross), nan(dist), nan(row_px), nan(col_px), az, status)


def outlier_flags(
    east_m: ArrayLike, north_m: ArrayLike, k_sigma: float = 3.5, min_sigma_m: float = 0.5
) -> tuple[np.ndarray, np.ndarray, float]:
    """Robust outlier flags of one flight's error vectors (rule in the module docstring).

    Parameters
    ----------
    east_m, north_m : array_like
        Error components of the flight's records [m] (NaN: not flagged, ignored).
    k_sigma : float
        Threshold in robust sigmas.
    min_sigma_m : float
        Floor of the robust scale [m] (default 0.5 m: the rounding of the
        published coordinates to 1e-5 deg is about +-0.55 m), so that a flight
        of near-identical errors does not flag centimetre differences.

    Returns
    -------
    flags : ndarray of bool
    d : ndarray
        Distance of each error vector from the median vector [m].
    sigma : float
        The robust scale used [m].
    """
    e, nn = np.asarray(east_m, float), np.asarray(north_m, float)
    good = np.isfinite(e) & np.isfinite(nn)
    d = np.full(e.shape, np.nan)
    if not np.any(good):
        return np.zeros(e.shape, bool), d, float("nan")
    d[good] = np.hypot(e[good] - np.median(e[good]), nn[good] - np.median(nn[good]))
    sigma = max(float(np.median(d[good])) / np.sqrt(2 * np.log(2)), min_sigma_m)
    flags = good & (np.nan_to_num(d, nan=0.0) > k_sigma * sigma)
    return flags, d, sigma


def group_summary(ev: ErrorVectors, mask: ArrayLike, k_sigma: float = 3.5, min_sigma_m: float = 0.5) -> dict:
    """Per-flight bias, spread and outliers of the records selected by ``mask``.

    Returns a JSON-ready dict: ``mean_error_m`` (mean distance), ``bias_east_m``,
    ``bias_north_m``, ``bias_along_m``, ``bias_cross_m`` (mean vector),
    ``spread_m`` (RMS distance of the vectors from their mean),
    ``bias_row_px``, ``bias_col_px``, ``outliers`` (record indices within the
    mask order), ``robust_sigma_m``.
    """
    m = np.asarray(mask, bool)
    good = m & np.isfinite(ev.east_m)

    def mean(a):
        return float(np.mean(a[good])) if np.any(good) else float("nan")

    e, nn = ev.east_m[good], ev.north_m[good]
    spread = float(np.sqrt(np.mean((e - e.mean()) ** 2 + (nn - nn.mean()) ** 2))) if e.size else float("nan")
    flags, _, sigma = outlier_flags(ev.east_m[m], ev.north_m[m], k_sigma, min_sigma_m)
    return {
        "n_ok": int(good.sum()),
        "mean_error_m": mean(ev.distance_m),
        "bias_east_m": mean(ev.east_m),
        "bias_north_m": mean(ev.north_m),
        "bias_along_m": mean(ev.along_m),
        "bias_cross_m": mean(ev.cross_m),
        "bias_row_px": mean(ev.row_px),
        "bias_col_px": mean(ev.col_px),
        "spread_m": spread,
        "robust_sigma_m": sigma,
        "outliers": [int(k) for k in np.flatnonzero(flags)],
    }


def plot_error_vectors(path: str | os.PathLike[str], panels: Sequence[Mapping[str, Any]], title: str = "") -> None:
    """Matplotlib figure of error vectors per flight (PNG or any matplotlib format).

    Top row: a map of each flight's targets with the error vectors drawn as
    arrows from the truth (scaled by ``exaggeration``). Bottom row: the same
    vectors as points in error space (east error, north error), unscaled, with
    circles of 5 and 10 m.

    Parameters
    ----------
    path : path-like
        Output file.
    panels : list of dict
        One per flight: ``name``, ``east_m``/``north_m`` (truth positions relative
        to the flight's mean truth, metres), ``exaggeration``, optional
        ``labels``, and ``vectors``: a list of ``(label, east_err, north_err,
        color)``.
    title : str
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        2, len(panels), figsize=(6.0 * len(panels), 11), squeeze=False, gridspec_kw={"height_ratios": [1.4, 1]}
    )
    for col, p in enumerate(panels):
        ax, ax2 = axes[0, col], axes[1, col]
        x, y = np.asarray(p["east_m"], float), np.asarray(p["north_m"], float)
        ex = float(p.get("exaggeration", 1.0))
        xs, ys = [x], [y]
        for z, (label, de, dn, color) in enumerate(p["vectors"]):
            de, dn = np.asarray(de, float), np.asarray(dn, float)
            ax.quiver(
                x,
                y,
                de * ex,
                dn * ex,
                angles="xy",
                scale_units="xy",
                scale=1.0,
                color=color,
                width=0.005 if z == 0 else 0.004,
                label=label,
                zorder=2 + z,
            )
            xs.append(x + de * ex)
            ys.append(y + dn * ex)
            ax2.plot(de, dn, "o", color=color, ms=5, alpha=0.85, label=label, zorder=2 + z)
            ax2.plot(np.nanmean(de), np.nanmean(dn), "X", color=color, ms=11, mec="k", zorder=10)
        ax.plot(x, y, "k+", ms=9, label="surveyed truth", zorder=10)
        for k, lab in enumerate(p.get("labels", [])):
            ax.annotate(lab, (x[k], y[k]), fontsize=7, xytext=(4, -10), textcoords="offset points")
        allx, ally = np.concatenate(xs), np.concatenate(ys)
        pad = 0.05 * max(np.nanmax(allx) - np.nanmin(allx), np.nanmax(ally) - np.nanmin(ally), 1.0)
        ax.set_xlim(np.nanmin(allx) - pad, np.nanmax(allx) + pad)
        ax.set_ylim(np.nanmin(ally) - pad, np.nanmax(ally) + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("east of the flight's mean truth [m]")
        ax.set_ylabel("north [m]")
        ax.set_title(f"{p['name']}: error vectors" + (f" (arrows x{ex:g})" if ex != 1 else ""))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        t = np.linspace(0, 2 * np.pi, 200)
        for r in (5, 10):
            ax2.plot(r * np.cos(t), r * np.sin(t), "k:", lw=0.8)
        ax2.axhline(0, color="k", lw=0.5)
        ax2.axvline(0, color="k", lw=0.5)
        ax2.set_aspect("equal", adjustable="datalim")
        ax2.set_xlabel("east error (computed - truth) [m]")
        ax2.set_ylabel("north error [m]")
        ax2.set_title(f"{p['name']}: error space (X = mean; circles 5, 10 m)")
        ax2.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
