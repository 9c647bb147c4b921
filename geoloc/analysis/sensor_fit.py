"""Fit any named parameters of a sensor to ground control: mount, boresight, lever arm, lens.

The on-orbit calibration of [L12 eq. 2] (``docs/method.md``) generalised to every
sensor behind :class:`geoloc.sensors.base.Sensor`: the parameters to fit are
named (``sensor.params``: ``mount_y``, ``boresight_z``, ``lever_arm_x_m``, ``fx``,
``cx``, ``k1``, ...), and each trial sensor is ``sensor.with_params(...)``.
Residuals are the horizontal error vectors (east, north) [m] of each record's
computed ground point minus its surveyed truth, the ground point taken on a
surface (a constant height or a DEM: :mod:`geoloc.surfaces`). Uncertainties are
the linearised least-squares ones, ``cov = s^2 (J^T J)^-1`` with
``s^2 = |r|^2 / (m - p)``; leave-one-out refits without each record in turn and
reports that record's error against the fit it took no part in.

This is the one calibrator: a first-phase camera file is fitted as its sensor
(:func:`geoloc.sensors.camera.as_sensor`: its ``mount_deg`` / ``boresight_deg`` are
``mount_*`` / ``boresight_*``, its principal row / column ``cy`` / ``cx`` in 1-based
pixels), its one focal length as the pseudo-parameter ``f`` (:data:`TIED`: fx and fy
together), and written back with :func:`geoloc.sensors.camera.camera_from_sensor`.
Camera resection (:func:`resect_sensor` of ``f, cx, cy``) is how the bundled camera of
``assets/cameras/qiao2017.toml`` was derived.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.local import R_ecef_ned
from geoloc.io.records import Records
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.status import Status
from geoloc.surfaces.base import Surface
from geoloc.surfaces.height import HeightSurface, for_records
from geoloc.surfaces.terrain_numba import compiled_walk

#: Residual given to a record whose ray finds no ground point during the fit [m].
FAILED_RESIDUAL_M = 1.0e4

#: Pseudo-parameters: one fitted value for several of the sensor's parameters. ``f`` is a
#: camera file's single focal length [px]: the lens's fx and fy together (offered when
#: they are equal).
TIED = {"f": ("fx", "fy")}

#: |correlation| above which two fitted parameters are reported as not separable.
DEGENERATE_CORRELATION = 0.99


def fit_params(sensor: Any) -> dict:
    """The parameters :func:`fit_sensor_params` can fit: ``sensor.params`` and the :data:`TIED` ones."""
    p = dict(sensor.params)
    for t, parts in TIED.items():
        if all(k in p for k in parts) and len({float(p[k]) for k in parts}) == 1:
            p[t] = p[parts[0]]
    return p


def with_fit_params(sensor: Any, values: dict) -> Any:
    """``sensor.with_params`` with the :data:`TIED` pseudo-parameters spread over their parts."""
    out = {}
    for k, v in values.items():
        for part in TIED.get(k, (k,)):
            out[part] = v
    return sensor.with_params(**out)


def _check_names(sensor, names) -> dict:
    known = fit_params(sensor)
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise ValueError(f"cannot fit {unknown}: the sensor's parameters are {sorted(known)}")
    return known


def _covariance(jac, resid, n_params):
    """Linearised covariance ``s^2 (J^T J)^-1``, ``s^2 = |r|^2 / (m - p)``; NaN where not determined.

    The columns are scaled before inverting (the parameters mix radians, pixels and
    metres); a scaled normal matrix with condition above 1e12 is numerically singular
    and gives NaN ("not determined") rather than noise. Returns ``(cov, s2)``.
    """
    m = resid.size
    dof = m - n_params
    nan = np.full((n_params, n_params), np.nan)
    if dof <= 0:
        return nan, float("nan")
    s2 = float(resid @ resid) / dof
    JtJ = jac.T @ jac
    d = np.sqrt(np.diag(JtJ))
    if np.any(d == 0) or not np.all(np.isfinite(d)):
        return nan, s2
    A = JtJ / np.outer(d, d)
    if np.linalg.cond(A) > 1e12:
        return nan, s2
    return s2 * np.linalg.inv(A) / np.outer(d, d), s2


def degenerate_pairs(names: Sequence[str], corr: np.ndarray) -> list:
    """Pairs of parameters the records cannot separate: |correlation| > 0.99, or not determined."""
    return [
        [names[a], names[b]]
        for a in range(len(names))
        for b in range(a + 1, len(names))
        if not np.isfinite(corr[a, b]) or abs(corr[a, b]) > DEGENERATE_CORRELATION
    ]


@dataclass
class SensorFit:
    """Result of :func:`fit_sensor_params`.

    Attributes
    ----------
    names : list of str
        The fitted parameters.
    start, values, sd : ndarray
        Start values, fitted values and their standard deviations (SI units of ``sensor.params``).
    correlation : ndarray (p, p)
    sensor : the fitted sensor
    rms_before_m, rms_after_m : float
        RMS horizontal error to truth before and after.
    errors_after_m : ndarray
        Per-record horizontal error after the fit.
    loo_errors_m : ndarray or None
        Per-record error of the fit without that record (leave-one-out).
    residual_m : ndarray (n, 2)
        (east, north) residual of each used record after the fit [m].
    sigma_m : float
        ``s``, the root of the residual variance factor (per component) [m].
    success : bool
        The solver's convergence flag.
    """

    names: list
    start: np.ndarray
    values: np.ndarray
    sd: np.ndarray
    correlation: np.ndarray
    sensor: object
    rms_before_m: float
    rms_after_m: float
    errors_after_m: np.ndarray
    loo_errors_m: np.ndarray | None = None
    dof: int = 0
    extra: dict = field(default_factory=dict)
    residual_m: np.ndarray | None = None
    sigma_m: float = float("nan")
    success: bool = True

    def report(self) -> dict:
        deg = {n: n.startswith(("mount_", "boresight_")) for n in self.names}
        conv = {n: (np.rad2deg(1.0) if deg[n] else 1.0) for n in self.names}
        unit = {
            n: (
                "deg"
                if deg[n]
                else "m"
                if n.endswith("_m")
                else "px"
                if n in ("f", "fx", "fy", "cx", "cy", "skew")
                else ""
            )
            for n in self.names
        }
        out = {
            "parameters": {
                n: {"start": float(s * conv[n]), "value": float(v * conv[n]), "sd": float(d * conv[n]), "unit": unit[n]}
                for n, s, v, d in zip(self.names, self.start, self.values, self.sd)
            },
            "correlation": np.round(self.correlation, 3).tolist(),
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "dof": self.dof,
            "sigma_m": self.sigma_m,
            "converged": self.success,
            # pairs the records cannot separate: their values are not meaningful one by one
            # (e.g. the mount's pitch and yaw within one flight)
            "degenerate_pairs": degenerate_pairs(self.names, self.correlation),
        }
        if self.loo_errors_m is not None:
            out["rms_loo_m"] = float(np.sqrt(np.nanmean(self.loo_errors_m**2)))
        return out


def _enu_residuals(hit, truth_lat, truth_lon) -> np.ndarray:
    """(east, north) of computed minus truth [m], in the local level frame at the truth, (n, 2)."""

    t = geodetic_to_ecef(truth_lat, truth_lon, hit.h)
    d = np.einsum("...ji,...j->...i", R_ecef_ned(truth_lat, truth_lon), hit.ecef - t)
    out = np.stack([d[..., 1], d[..., 0]], axis=-1)
    bad = hit.status != Status.OK
    out[bad] = FAILED_RESIDUAL_M
    return out


def _ground(sensor, pose, row, col, surface_of, corrections: Corrections = NO_CORRECTIONS):
    # through the location pipeline; recorded image points: off-sensor pixels extend the lens
    # model (the verb reports them)
    return Pipeline(sensor, surface_of, corrections).locate(row, col, pose, outside="extrapolate")


@dataclass(frozen=True)
class _FitProblem:
    """The records' poses, pixels and surveyed truth [rad] for fitting ``names`` of ``sensor``:
    the (east, north) residuals [m] of any trial sensor on any subset of the records."""

    sensor: Any
    names: list
    p0: np.ndarray
    pose: Any
    row: np.ndarray
    col: np.ndarray
    truth_lat: np.ndarray
    truth_lon: np.ndarray
    surface_of: Callable
    corrections: Corrections

    def trial(self, p: np.ndarray) -> Any:
        """The sensor with the fitted parameters at ``p``."""
        return with_fit_params(self.sensor, dict(zip(self.names, p)))

    def errors(self, s: Any, ii: np.ndarray) -> np.ndarray:
        """(east, north) of records ``ii``'s ground points with sensor ``s`` minus their truth, (len(ii), 2)."""
        hit = _ground(s, self.pose.take(ii), self.row[ii], self.col[ii], self.surface_of(ii), self.corrections)
        return _enu_residuals(hit, self.truth_lat[ii], self.truth_lon[ii])

    def solve(self, ii: np.ndarray):
        """``scipy.optimize.least_squares`` from the start values on records ``ii``."""
        return least_squares(
            lambda p: self.errors(self.trial(p), ii).ravel(),
            self.p0,
            x_scale="jac",
            method="lm" if 2 * len(ii) >= len(self.names) else "trf",
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
            max_nfev=200 * (len(self.names) + 1),
        )


def _fit_problem(
    records: Records, sensor: Any, names: list, surface: Surface, corrections: Corrections, truth_prefix: str, idx
) -> tuple[_FitProblem, np.ndarray]:
    """The problem of :func:`fit_sensor_params` and the records to use, or ValueError naming what
    is wrong: an unknown parameter, no parameter, fewer equations than parameters, a record
    without its truth."""
    known = _check_names(sensor, names)
    if not names:
        raise ValueError("name at least one parameter to fit")
    idx = np.arange(len(records)) if idx is None else np.asarray(idx, int)
    if 2 * idx.size < len(names):
        raise ValueError(
            f"{idx.size} record(s) give {2 * idx.size} equations for {len(names)} parameters; "
            f"need at least {(len(names) + 1) // 2} records"
        )
    pose, row, col = records.pose(), records.column("row"), records.column("col")
    tlat = np.deg2rad(records.column(f"{truth_prefix}_lat_deg"))
    tlon = np.deg2rad(records.column(f"{truth_prefix}_lon_deg"))
    if not np.all(np.isfinite(tlat[idx]) & np.isfinite(tlon[idx])):
        raise ValueError(f"{records.path}: every record to fit needs {truth_prefix}_lat_deg and _lon_deg")
    p0 = np.array([known[n] for n in names], float)
    problem = _FitProblem(sensor, names, p0, pose, row, col, tlat, tlon, partial(for_records, surface), corrections)
    return problem, idx


def _correlation(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations and the correlation matrix of a covariance (NaN where not determined)."""
    sd = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        return sd, cov / np.outer(sd, sd)


def _loo_errors(problem: _FitProblem, idx: np.ndarray) -> np.ndarray:
    """Each record's horizontal error [m] against the fit to the other records of ``idx``."""
    out = np.full(len(idx), np.nan)
    for k in range(len(idx)):
        s_k = problem.trial(problem.solve(np.delete(idx, k)).x)
        out[k] = float(np.linalg.norm(problem.errors(s_k, idx[k : k + 1])))
    return out


def _rms_m(r: np.ndarray) -> float:
    """RMS horizontal length of (east, north) vectors (n, 2) [m]."""
    return float(np.sqrt(np.mean(np.sum(r**2, -1))))


@compiled_walk()  # a fit locates its records at every trial: the kernel, not the Python walk
def fit_sensor_params(
    records: Records,
    sensor: Any,
    names: Sequence[str],
    surface: Surface,
    *,
    corrections: Corrections = NO_CORRECTIONS,
    truth_prefix: str = "truth",
    idx: ArrayLike | None = None,
    loo: bool = False,
) -> SensorFit:
    """Least-squares fit of the named parameters of ``sensor`` to the records' surveyed truth.

    Parameters
    ----------
    records : Records
        With the pose, pixel and ``<truth_prefix>_lat_deg`` / ``_lon_deg`` columns.
    sensor : FrameSensor (or any sensor with ``params`` / ``with_params``)
    names : sequence of str
        Parameters to fit (``sensor.params`` keys); unknown names are an error naming them.
    surface : Surface
        Where each record's target lies: a :class:`geoloc.surfaces.height.HeightSurface`,
        a :class:`geoloc.surfaces.height.PerRecordHeightSurface` (e.g. the truth heights, one
        per record: subsets take theirs, :func:`geoloc.surfaces.height.for_records`) or a
        :class:`geoloc.surfaces.terrain.DemSurface`.
    idx : array of int, optional
        Records to use (default all).
    loo : bool
        Also refit without each record (leave-one-out).
    """
    names = list(names)
    problem, idx = _fit_problem(records, sensor, names, surface, corrections, truth_prefix, idx)
    r0 = problem.errors(sensor, idx)
    sol = problem.solve(idx)
    fitted = problem.trial(sol.x)
    r1 = problem.errors(fitted, idx)
    cov, s2 = _covariance(sol.jac, sol.fun, len(names))
    sd, corr = _correlation(cov)
    return SensorFit(
        names,
        problem.p0,
        sol.x,
        sd,
        corr,
        fitted,
        _rms_m(r0),
        _rms_m(r1),
        np.linalg.norm(r1, axis=-1),
        _loo_errors(problem, idx) if loo else None,
        r1.size - len(names),
        residual_m=r1,
        sigma_m=float(np.sqrt(s2)) if np.isfinite(s2) else float("nan"),
        success=bool(sol.success),
    )


# --------------------------------------------------------------------------- per flight
@compiled_walk()  # a fit locates its records at every trial: the kernel, not the Python walk
def fit_sensor_groups(
    records: Records,
    sensor: Any,
    names: Sequence[str],
    surface: Surface,
    *,
    corrections: Corrections = NO_CORRECTIONS,
    group_column: str | None = "table",
    joint: bool = False,
    exclude_outliers: bool = False,
    loo: bool = False,
    truth_prefix: str = "truth",
    k_sigma: float = 3.5,
) -> tuple[dict, dict]:
    """Per-flight errors before and after fitting ``names``, with outlier flags and leave-one-out.

    Each flight (``group_column``) gets its own fit (or, with ``joint``, one fit to
    all flights). Records are flagged as outliers by the robust rule of
    :func:`geoloc.analysis.errors.outlier_flags` (distance from the flight's median
    error vector over ``k_sigma`` robust sigmas) applied to the residuals of a first
    fit with every record, and with ``exclude_outliers`` left out of a second fit
    (they are still measured). ``outlier_before`` gives the flags against the
    nominal sensor too.

    Returns
    -------
    report : dict
        ``{"groups": {name: {"n", "n_used_in_fit", "rms_before_m", "rms_after_m",
        "rms_loo_m", "mean_error_before_m", "mean_error_after_m", "mean_error_loo_m",
        "parameters", "correlation", "sigma_m", "degenerate_pairs", "before", "after",
        "records"}}}`` (JSON-ready; ``before`` / ``after`` are
        :func:`geoloc.analysis.errors.group_summary` dicts; each record's ``loo`` holds
        its leave-one-out ``east_m``, ``north_m``, ``distance_m``), and ``"joint_fit"``
        with ``joint``.
    sensors : dict
        The fitted sensor per group name (and ``"joint"``).
    """
    from geoloc.analysis.errors import error_vectors, group_labels, group_summary

    groups = group_labels(records, group_column)
    names_g = list(dict.fromkeys(groups))
    all_idx = np.arange(len(records))
    surf = partial(for_records, surface)
    pose_all = records.pose()
    row_all, col_all = records.column("row"), records.column("col")

    def measure(s, idx):
        sub = records.subset(idx)
        hit = _ground(s, pose_all.take(idx), row_all[idx], col_all[idx], surf(idx), corrections)
        return error_vectors(sub, s, hit, groups[idx], truth_prefix)

    before = measure(sensor, all_idx)
    use = before.status == Status.OK
    outlier_before = np.zeros(len(records), bool)
    for g in names_g:
        m = groups == g
        outlier_before[np.flatnonzero(m)[group_summary(before, m, k_sigma)["outliers"]]] = True

    def fit_all(use):
        return _fit_groups(records, sensor, names, surface, groups, use, joint, corrections, truth_prefix)

    fits = fit_all(use)
    # Outliers are judged against the model, not the nominal sensor: before a fit, the
    # very error being calibrated (a mount of a few tenths of a degree) varies with the
    # geometry by tens of metres and would be flagged. So: fit with every record, flag
    # each flight's residuals by the robust rule, and (exclude_outliers) refit without them.
    outlier = np.zeros(len(records), bool)
    for g in names_g:
        m = groups == g
        first = measure(fits[g].sensor, all_idx[m])
        outlier[np.flatnonzero(m)[group_summary(first, np.ones(m.sum(), bool), k_sigma)["outliers"]]] = True
    if exclude_outliers and np.any(outlier):
        use = use & ~outlier
        fits = fit_all(use)
    sensors = {"joint": fits[names_g[0]].sensor} if joint else {g: f.sensor for g, f in fits.items()}

    loo_d = np.full(len(records), np.nan)
    loo_en = np.full((len(records), 2), np.nan)
    if loo:
        loo_d, loo_en = _leave_one_out(
            lambda train: (
                fit_sensor_params(
                    records, sensor, names, surface, corrections=corrections, truth_prefix=truth_prefix, idx=train
                ).sensor
            ),
            measure,
            groups,
            use,
            joint,
        )

    labels = records.labels()
    per_group: dict[str, dict] = {}
    report = {
        "parameters_fitted": list(names),
        "joint": joint,
        "exclude_outliers": exclude_outliers,
        "outlier_rule": f"residual after a first fit with every record: distance from the flight's "
        f"median residual vector > {k_sigma} robust sigma (sigma = median distance / "
        "sqrt(2 ln 2), floor 0.5 m)",
        "groups": per_group,
    }
    for g in names_g:
        m = groups == g
        idx = all_idx[m]
        after = measure(fits[g].sensor, idx)
        entry = _group_entry(fits[g].report(), before, after, m, use, loo_d if loo else None, k_sigma)
        for j, k in enumerate(idx):
            rec = {
                "label": labels[k],
                "line": int(records.lines[k]),
                "outlier": bool(outlier[k]),
                "outlier_before": bool(outlier_before[k]),
                "before": before.as_dict(k),
                "after": after.as_dict(j),
            }
            if loo:
                rec["loo_distance_m"] = _rnd(loo_d[k])
                rec["loo"] = {
                    "east_m": _rnd(loo_en[k, 0]),
                    "north_m": _rnd(loo_en[k, 1]),
                    "distance_m": _rnd(loo_d[k]),
                }
            entry["records"].append(rec)
        per_group[g] = entry
    if joint:
        report["joint_fit"] = {**fits[names_g[0]].report(), "n": int(use.sum())}
    return report, sensors


def _fit_groups(
    records: Records,
    sensor: Any,
    names: Sequence[str],
    surface: Surface,
    groups: np.ndarray,
    use: np.ndarray,
    joint: bool,
    corrections: Corrections,
    truth_prefix: str,
) -> dict:
    """Group name -> its :class:`SensorFit` on the records ``use`` marks; with ``joint`` one fit to
    every group's records, the same for each. ValueError naming the group when a group has too
    few records for the parameters (no more than half as many as ``names``)."""
    all_idx = np.arange(len(records))
    names_g = list(dict.fromkeys(groups))
    if joint:
        jf = fit_sensor_params(
            records,
            sensor,
            names,
            surface,
            corrections=corrections,
            truth_prefix=truth_prefix,
            idx=all_idx[use],
            loo=False,
        )
        return {g: jf for g in names_g}
    fits = {}
    for g in names_g:
        idx = all_idx[(groups == g) & use]
        if 2 * idx.size <= len(names):
            raise ValueError(
                f"group {g!r}: {idx.size} usable record(s) cannot determine "
                f"{len(names)} parameters ({', '.join(names)})"
            )
        fits[g] = fit_sensor_params(
            records, sensor, names, surface, corrections=corrections, truth_prefix=truth_prefix, idx=idx
        )
    return fits


def _leave_one_out(
    fit: Callable[[np.ndarray], Any],
    measure: Callable[[Any, np.ndarray], Any],
    groups: np.ndarray,
    use: np.ndarray,
    joint: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Each record's error when left out of its fit: distance (n,) and east, north (n, 2) [m].

    ``fit(train)`` is the sensor fitted to the records ``train`` (indices); ``measure(sensor, idx)``
    the error vectors of records ``idx`` with it. A record is measured against the fit to the other
    usable records of its group (with ``joint``, of every group)."""
    n = len(groups)
    all_idx = np.arange(n)
    loo_d = np.full(n, np.nan)
    loo_en = np.full((n, 2), np.nan)
    for g in dict.fromkeys(groups):
        for k in all_idx[groups == g]:
            train = all_idx[use] if joint else all_idx[(groups == g) & use]
            ev = measure(fit(train[train != k]), np.array([k]))
            loo_d[k] = float(ev.distance_m[0])
            loo_en[k] = float(ev.east_m[0]), float(ev.north_m[0])
    return loo_d, loo_en


def _rnd(v: Any, nd: int = 4) -> float | None:
    """A figure for the JSON report: rounded to ``nd`` decimals, None where not finite."""
    v = float(v)
    return round(v, nd) if np.isfinite(v) else None


def _rms(a: Any) -> float:
    """Root mean square of the finite values (NaN when none)."""
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")


def _group_entry(
    frep: dict, before: Any, after: Any, m: np.ndarray, use: np.ndarray, loo_d: np.ndarray | None, k_sigma: float
) -> dict[str, Any]:
    """One group's report entry without its records: counts, errors before, after and left out
    (``loo_d``, None without), the fit's own report ``frep``; ``m`` marks the group's records in
    ``before`` and ``use``, ``after`` holds the group's records only."""
    from geoloc.analysis.errors import group_summary

    return {
        "n": int(m.sum()),
        "n_used_in_fit": int((m & use).sum()),
        "rms_before_m": _rnd(_rms(before.distance_m[m])),
        "rms_after_m": _rnd(_rms(after.distance_m)),
        "rms_loo_m": _rnd(_rms(loo_d[m])) if loo_d is not None else None,
        "mean_error_before_m": _rnd(np.nanmean(before.distance_m[m])),
        "mean_error_after_m": _rnd(np.nanmean(after.distance_m)),
        "mean_error_loo_m": _rnd(np.nanmean(loo_d[m])) if loo_d is not None else None,
        **{k: frep[k] for k in ("parameters", "correlation", "sigma_m", "degenerate_pairs", "converged")},
        "before": {k: (_rnd(v) if isinstance(v, float) else v) for k, v in group_summary(before, m, k_sigma).items()},
        "after": {
            k: (_rnd(v) if isinstance(v, float) else v)
            for k, v in group_summary(after, np.ones(int(m.sum()), bool), k_sigma).items()
        },
        "records": [],
    }


@dataclass
class SensorResection:
    """Result of :func:`resect_sensor`: the fitted parameters, their uncertainties and the heights."""

    fit: SensorFit
    heights_m: np.ndarray
    rms_m: float
    success: bool

    def report(self) -> dict:
        return {
            **self.fit.report(),
            "rms_misfit_m": self.rms_m,
            "heights_m": [round(float(h), 2) for h in self.heights_m],
            "converged": self.success,
        }


@compiled_walk()  # a fit locates its records at every trial: the kernel, not the Python walk
def resect_sensor(
    records: Records,
    sensor: Any,
    names: Sequence[str] = ("fx", "cx", "cy"),
    *,
    corrections: Corrections = NO_CORRECTIONS,
    computed_prefix: str = "paper",
    initial_height_m: float = 0.0,
) -> SensorResection:
    """Fit the named parameters (default focal length and principal point) to published positions.

    Unknowns are the named parameters and each record's target height h_k;
    equations are the (east, north) offsets between record k's line of sight at
    h_k (the ellipsoid inflated to h_k, [Q17 eq. 8-11]) and its published
    position ``{computed_prefix}_lat_deg`` / ``_lon_deg``. Since a focal length
    and a height trade against each other only through the spread of slant
    ranges, at least ``len(names) + 1`` records are needed (2n equations, n + p unknowns).

    Returns
    -------
    SensorResection
        ``rms_m`` is the RMS of the 2n residual components [m].
    """

    names = list(names)
    known = _check_names(sensor, names)
    n, p = len(records), len(names)
    if 2 * n < n + p + 1:
        raise ValueError(f"resection of {p} parameters needs at least {p + 1} records, got {n}")
    pose = records.pose()
    row, col = records.column("row"), records.column("col")
    tlat = np.deg2rad(records.column(f"{computed_prefix}_lat_deg"))
    tlon = np.deg2rad(records.column(f"{computed_prefix}_lon_deg"))
    if not np.all(np.isfinite(tlat) & np.isfinite(tlon)):
        raise ValueError(f"{records.path}: every record needs {computed_prefix}_lat_deg and _lon_deg")
    p0 = np.array([known[k] for k in names], float)
    scale = np.where(np.abs(p0) > 0, np.abs(p0), 1.0)

    def resid(x):
        s = with_fit_params(sensor, dict(zip(names, p0 + x[:p] * scale)))
        hit = _ground(s, pose, row, col, HeightSurface(x[p:] * 1000.0), corrections)  # heights in km inside
        return _enu_residuals(hit, tlat, tlon).ravel()

    x0 = np.concatenate([np.zeros(p), np.full(n, initial_height_m / 1000.0)])
    sol = least_squares(resid, x0, method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    m = sol.fun.size
    # The uncertainties from central differences at the solution, steps 1e-5 of max(1, |x|)
    # (the parameters are offsets relative to p0: 1e-5 |p0|, e.g. 0.01 px of an 1100-px
    # principal point, 1 mm on the ground at 18 km; heights in km: >= 1 cm). The solver's
    # own forward-difference Jacobian steps 1.5e-8 (2e-5 px of that principal point, a
    # ground shift of ~1e-6 m, where float64 ECEF rounding, ~1e-9 m, costs 1e-3 of the
    # derivative and so of the sd: 17.20 px instead of 17.19 for the bundled camera's j0).
    steps = 1e-5 * np.maximum(1.0, np.abs(sol.x))
    jac = np.stack(
        [(resid(sol.x + h * e) - resid(sol.x - h * e)) / (2.0 * h) for h, e in zip(steps, np.eye(x0.size))], axis=-1
    )
    cov, s2 = _covariance(jac, sol.fun, x0.size)
    sd = np.sqrt(np.diag(cov))[:p] * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = (cov / np.outer(np.sqrt(np.diag(cov)), np.sqrt(np.diag(cov))))[:p, :p]
    values = p0 + sol.x[:p] * scale
    fitted = with_fit_params(sensor, dict(zip(names, values)))
    r = sol.fun.reshape(-1, 2)
    r0 = resid(x0).reshape(-1, 2)
    fit = SensorFit(
        names,
        p0,
        values,
        sd,
        corr,
        fitted,
        float(np.sqrt(np.mean(np.sum(r0**2, -1)))),
        float(np.sqrt(np.mean(np.sum(r**2, -1)))),
        np.linalg.norm(r, axis=-1),
        None,
        m - x0.size,
        residual_m=r,
        sigma_m=float(np.sqrt(s2)) if np.isfinite(s2) else float("nan"),
        success=bool(sol.success),
    )
    return SensorResection(fit, sol.x[p:] * 1000.0, float(np.sqrt(np.mean(r**2))), bool(sol.success))


def error_vector_panels(report: dict, records: Records, exaggeration: float = 1.0, truth_prefix: str = "truth") -> list:
    """Panels for :func:`geoloc.analysis.errors.plot_error_vectors` from a :func:`fit_sensor_groups` report.

    Truth positions are placed in the ENU frame at each flight's mean truth
    (:class:`geoloc.frames.enu.EnuFrame`); arrows are the error vectors before (red),
    after (blue) and left-one-out (green, when present).
    """
    from geoloc.frames.enu import EnuFrame

    labels = records.labels()
    lat = records.column(f"{truth_prefix}_lat_deg")
    lon = records.column(f"{truth_prefix}_lon_deg")
    index = {lab: k for k, lab in enumerate(labels)}
    panels = []
    for g, e in report["groups"].items():
        ks = [index[r["label"]] for r in e["records"]]
        frame = EnuFrame.from_deg(float(np.mean(lat[ks])), float(np.mean(lon[ks])), 0.0)
        p = frame.from_geodetic(np.deg2rad(lat[ks]), np.deg2rad(lon[ks]), 0.0)

        def comp(stage, c):
            return [np.nan if (r.get(stage) or {}).get(c) is None else r[stage][c] for r in e["records"]]

        vectors = [
            (
                f"before (mean {e['mean_error_before_m']:.1f} m)",
                comp("before", "east_m"),
                comp("before", "north_m"),
                "tab:red",
            ),
            (
                f"after (mean {e['mean_error_after_m']:.1f} m)",
                comp("after", "east_m"),
                comp("after", "north_m"),
                "tab:blue",
            ),
        ]
        if e.get("mean_error_loo_m") is not None:
            vectors.append(
                (
                    f"leave-one-out (mean {e['mean_error_loo_m']:.1f} m)",
                    comp("loo", "east_m"),
                    comp("loo", "north_m"),
                    "tab:green",
                )
            )
        panels.append(
            {
                "name": f"flight {g}",
                "east_m": p[:, 0],
                "north_m": p[:, 1],
                "vectors": vectors,
                "exaggeration": exaggeration,
                "labels": [r["label"] for r in e["records"]],
            }
        )
    return panels
