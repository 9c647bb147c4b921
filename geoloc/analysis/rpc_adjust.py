"""Refine an RPC with ground control points: the image-space bias / affine correction.

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md``.

An RPC delivered with an image carries the systematic errors of the attitude
and ephemeris it was fitted to; over a scene they show up as an image-space
shift (and, for long strips, a small drift). Grodecki & Dial (PE&RS 69(1),
2003) correct them in image space, leaving the 78 coefficients alone:

    row = r + row_bias + row_per_row * r + row_per_col * c
    col = c + col_bias + col_per_row * r + col_per_col * c

with (r, c) the RPC's 1-based projection of a ground point. The correction is
linear in its parameters, so ground control points (GCPs: ground points with
measured pixels) give them by linear least squares, the row and column
equations separately. [L12] refines the rigorous ZY-3 model with GCPs in the
same spirit; this is the RPC counterpart (:class:`geoloc.sensors.rpc.RPCSensor`
carries the six parameters as its ``params``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from geoloc.sensors.rpc import PARAM_NAMES, RPCSensor
from geoloc.status import Status

#: Parameters solved for by each correction model (the others are set to 0).
MODELS = {
    "bias": ("row_bias", "col_bias"),
    "affine": PARAM_NAMES,
}


@dataclass(frozen=True)
class RPCAdjustment:
    """What :func:`adjust_rpc` reports.

    Residuals are measured minus predicted pixel, ``(n, 2)`` arrays of (row, col) [px].

    Attributes
    ----------
    model : str
        ``"bias"`` or ``"affine"``.
    params : dict
        The fitted parameters (all six; those not in the model are 0).
    std : dict
        A-posteriori standard deviations of the fitted parameters (same units),
        from the residual variance of each axis; NaN without redundancy.
    sigma0_px : (float, float)
        A-posteriori standard deviation of a measurement, row and column [px].
    residuals_before, residuals_after : ndarray (n, 2)
        With the sensor as given, and with the fitted correction.
    loo_residuals : ndarray (n, 2)
        Leave-one-out: each GCP against the correction fitted to the others
        (exact closed form, e_i / (1 - h_ii), h the hat matrix diagonal).
    rms_before_px, rms_after_px, rms_loo_px : float
        RMS of the image distance (hypot of row and column) of the three.
    n_gcps, dof : int
        Number of GCPs; degrees of freedom per axis (n - parameters per axis).
    """

    model: str
    params: dict
    std: dict
    sigma0_px: tuple
    residuals_before: np.ndarray = field(repr=False)
    residuals_after: np.ndarray = field(repr=False)
    loo_residuals: np.ndarray = field(repr=False)
    rms_before_px: float
    rms_after_px: float
    rms_loo_px: float
    n_gcps: int
    dof: int


def _rms(res):
    return float(np.sqrt(np.mean(np.sum(res**2, axis=-1)))) if res.size else float("nan")


def adjust_rpc(
    sensor: RPCSensor,
    gcps_lat: ArrayLike,
    gcps_lon: ArrayLike,
    gcps_h: ArrayLike,
    rows: ArrayLike,
    cols: ArrayLike,
    model: str = "bias",
) -> tuple[RPCSensor, RPCAdjustment]:
    """Least-squares image-space bias or affine correction of an RPC from GCPs.

    Parameters
    ----------
    sensor : RPCSensor
        Its current correction only enters ``residuals_before``: the fit is
        linear, so the result does not depend on it.
    gcps_lat, gcps_lon, gcps_h : array_like (n,)
        Ground control points: latitude, longitude [rad], ellipsoidal height [m].
    rows, cols : array_like (n,)
        Their measured 1-based image pixels.
    model : {"bias", "affine"}
        ``"bias"``: ``row_bias``, ``col_bias`` (n >= 1; >= 2 for standard
        deviations). ``"affine"``: all six (n >= 3 not on a line; >= 4 for
        standard deviations).

    Returns
    -------
    (RPCSensor, RPCAdjustment)
        The corrected sensor (``sensor.with_params(...)``) and the report.

    Raises
    ------
    ValueError
        Unknown model, mismatched or non-finite input, too few GCPs, GCPs the
        RPC cannot project (outside its validity domain: named by index), or
        GCPs on a line (affine).
    """
    if model not in MODELS:
        raise ValueError(f"model = {model!r} must be one of {sorted(MODELS)}")
    arrs = [np.atleast_1d(np.asarray(a, float)).ravel() for a in (gcps_lat, gcps_lon, gcps_h, rows, cols)]
    n = arrs[0].size
    if any(a.size != n for a in arrs):
        raise ValueError(f"GCP arrays differ in length: {[a.size for a in arrs]}")
    lat, lon, h, row_m, col_m = arrs
    bad = np.flatnonzero(~np.all(np.isfinite(np.stack(arrs)), axis=0))
    if bad.size:
        raise ValueError(f"GCP(s) {bad.tolist()}: non-finite coordinates or pixels")
    p = 1 if model == "bias" else 3
    if n < p:
        raise ValueError(f"model {model!r} needs at least {p} GCPs, got {n}")
    raw = sensor.with_params(**dict.fromkeys(PARAM_NAMES, 0.0)).ground_to_pixel(lat, lon, h)
    refused = np.flatnonzero((raw.status != Status.OK) & (raw.status != Status.OUTSIDE_SENSOR))
    if refused.size:
        raise ValueError(
            f"GCP(s) {refused.tolist()}: outside the RPC's validity domain "
            f"(status {sorted({int(s) for s in raw.status[refused]})}); not used for an adjustment"
        )
    r, c = raw.row, raw.col
    before = sensor.ground_to_pixel(lat, lon, h)
    res_before = np.stack([row_m - before.row, col_m - before.col], axis=-1)

    # design in centred, scaled pixel coordinates (well conditioned for 24 576-pixel images)
    r0, c0 = float(np.mean(r)), float(np.mean(c))
    s = float(max(sensor.rows, sensor.cols)) / 2.0
    u, v = (r - r0) / s, (c - c0) / s
    A = np.ones((n, 1)) if model == "bias" else np.stack([np.ones(n), u, v], axis=-1)
    if model == "affine" and np.linalg.matrix_rank(A) < 3:
        raise ValueError("model 'affine' needs GCPs that are not all on one line in the image")
    # back to the parameters: a0 = d0 - a1 r0 - a2 c0, a1 = d1 / s, a2 = d2 / s
    M = np.eye(1) if model == "bias" else np.array([[1.0, -r0 / s, -c0 / s], [0.0, 1.0 / s, 0.0], [0.0, 0.0, 1.0 / s]])
    Q = np.linalg.inv(A.T @ A)  # cofactor matrix of the scaled unknowns
    hat = np.einsum("ij,jk,ik->i", A, Q, A)
    dof = n - p
    params = dict.fromkeys(PARAM_NAMES, 0.0)
    std = {}
    sig0, after, loo = [], [], []
    names = {"row": ("row_bias", "row_per_row", "row_per_col"), "col": ("col_bias", "col_per_row", "col_per_col")}
    for axis, (obs, pred) in (("row", (row_m, r)), ("col", (col_m, c))):
        y = obs - pred
        d = Q @ (A.T @ y)
        e = y - A @ d
        s0 = float(np.sqrt(e @ e / dof)) if dof > 0 else float("nan")
        a = M @ d
        cov = (s0**2) * (M @ Q @ M.T)
        for k, name in enumerate(names[axis][:p]):
            params[name] = float(a[k])
            std[name] = float(np.sqrt(cov[k, k]))
        sig0.append(s0)
        after.append(e)
        with np.errstate(divide="ignore", invalid="ignore"):
            loo.append(np.where(hat < 1.0 - 1e-12, e / (1.0 - hat), np.nan))
    adjusted = sensor.with_params(**params)
    res_after = np.stack(after, axis=-1)
    res_loo = np.stack(loo, axis=-1)
    report = RPCAdjustment(
        model,
        params,
        std,
        tuple(sig0),
        res_before,
        res_after,
        res_loo,
        _rms(res_before),
        _rms(res_after),
        _rms(res_loo) if np.all(np.isfinite(res_loo)) else float("nan"),
        n,
        dof,
    )
    return adjusted, report


__all__ = ["MODELS", "RPCAdjustment", "adjust_rpc"]
