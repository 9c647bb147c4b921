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

The first-phase :mod:`geoloc.analysis.calibrate` (the [Q17] mount/boresight
angles of a camera file, and camera resection) stays as it is; this module is
for any sensor file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from geoloc.geodesy.local import R_ecef_ned
from geoloc.io.records import Records
from geoloc.status import Status

#: Residual given to a record whose ray finds no ground point during the fit [m].
FAILED_RESIDUAL_M = 1.0e4


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

    def report(self) -> dict:
        deg = {n: n.startswith(("mount_", "boresight_")) for n in self.names}
        conv = {n: (np.rad2deg(1.0) if deg[n] else 1.0) for n in self.names}
        unit = {n: ("deg" if deg[n] else "m" if n.endswith("_m") else "px" if n in ("fx", "fy", "cx", "cy", "skew")
                    else "") for n in self.names}
        out = {
            "parameters": {n: {"start": float(s * conv[n]), "value": float(v * conv[n]), "sd": float(d * conv[n]),
                               "unit": unit[n]} for n, s, v, d in zip(self.names, self.start, self.values, self.sd)},
            "correlation": np.round(self.correlation, 3).tolist(),
            "rms_before_m": self.rms_before_m, "rms_after_m": self.rms_after_m, "dof": self.dof,
        }
        if self.loo_errors_m is not None:
            out["rms_loo_m"] = float(np.sqrt(np.nanmean(self.loo_errors_m ** 2)))
        return out


def _enu_residuals(hit, truth_lat, truth_lon) -> np.ndarray:
    """(east, north) of computed minus truth [m], in the local level frame at the truth, (n, 2)."""
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    t = geodetic_to_ecef(truth_lat, truth_lon, hit.h)
    d = np.einsum("...ji,...j->...i", R_ecef_ned(truth_lat, truth_lon), hit.ecef - t)
    out = np.stack([d[..., 1], d[..., 0]], axis=-1)
    bad = hit.status != Status.OK
    out[bad] = FAILED_RESIDUAL_M
    return out


def _ground(sensor, pose, row, col, surface_of):
    from geoloc.locate import line_of_sight

    # recorded image points: off-sensor pixels extend the lens model (the verb reports them)
    return surface_of.intersect(line_of_sight(pose, sensor, row, col, outside="extrapolate"))


def fit_sensor_params(records: Records, sensor, names, surface, *, truth_prefix: str = "truth",
                      idx=None, loo: bool = False) -> SensorFit:
    """Least-squares fit of the named parameters of ``sensor`` to the records' surveyed truth.

    Parameters
    ----------
    records : Records
        With the pose, pixel and ``<truth_prefix>_lat_deg`` / ``_lon_deg`` columns.
    sensor : FrameSensor (or any sensor with ``params`` / ``with_params``)
    names : sequence of str
        Parameters to fit (``sensor.params`` keys); unknown names are an error naming them.
    surface : object with ``intersect(los)``, or a callable ``idx -> surface``
        Where each record's target lies: :class:`geoloc.surfaces.height.HeightSurface`
        (e.g. the truth heights) or :class:`geoloc.surfaces.terrain.DemSurface`. A callable
        gets the record indices, for per-record heights.
    idx : array of int, optional
        Records to use (default all).
    loo : bool
        Also refit without each record (leave-one-out).
    """
    names = list(names)
    unknown = sorted(set(names) - set(sensor.params))
    if unknown:
        raise ValueError(f"cannot fit {unknown}: the sensor's parameters are {sorted(sensor.params)}")
    if not names:
        raise ValueError("name at least one parameter to fit")
    idx = np.arange(len(records)) if idx is None else np.asarray(idx, int)
    pose_all = records.pose()
    row_all, col_all = records.column("row"), records.column("col")
    tlat_all = np.deg2rad(records.column(f"{truth_prefix}_lat_deg"))
    tlon_all = np.deg2rad(records.column(f"{truth_prefix}_lon_deg"))
    if not np.all(np.isfinite(tlat_all[idx]) & np.isfinite(tlon_all[idx])):
        raise ValueError(f"{records.path}: every record to fit needs {truth_prefix}_lat_deg and _lon_deg")
    surf = surface if callable(surface) and not hasattr(surface, "intersect") else (lambda _i: surface)
    p0 = np.array([sensor.params[n] for n in names], float)

    def errors(s, ii):
        hit = _ground(s, pose_all.take(ii), row_all[ii], col_all[ii], surf(ii))
        return _enu_residuals(hit, tlat_all[ii], tlon_all[ii])

    def solve(ii):
        def resid(p):
            return errors(sensor.with_params(**dict(zip(names, p))), ii).ravel()

        return least_squares(resid, p0, x_scale="jac", method="lm" if 2 * len(ii) >= len(names) else "trf",
                             xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200 * (len(names) + 1))

    r0 = errors(sensor, idx)
    sol = solve(idx)
    fitted = sensor.with_params(**dict(zip(names, sol.x)))
    r1 = errors(fitted, idx)
    m, p = r1.size, len(names)
    dof = m - p
    cov = np.full((p, p), np.nan)
    if dof > 0:
        s2 = float(sol.fun @ sol.fun) / dof
        try:
            cov = s2 * np.linalg.inv(sol.jac.T @ sol.jac)
        except np.linalg.LinAlgError:
            pass
    sd = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    loo_err = None
    if loo:
        loo_err = np.full(len(idx), np.nan)
        for k in range(len(idx)):
            rest = np.delete(idx, k)
            s_k = sensor.with_params(**dict(zip(names, solve(rest).x)))
            loo_err[k] = float(np.linalg.norm(errors(s_k, idx[k:k + 1])))
    return SensorFit(names, p0, sol.x, sd, corr, fitted,
                     float(np.sqrt(np.mean(np.sum(r0 ** 2, -1)))), float(np.sqrt(np.mean(np.sum(r1 ** 2, -1)))),
                     np.linalg.norm(r1, axis=-1), loo_err, dof)
