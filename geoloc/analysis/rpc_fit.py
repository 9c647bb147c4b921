"""Fit an RPC to a rigorous sensor model, terrain-independently [L12 section 4.1].

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md``. The RPC model
itself (terms, normalisation, evaluation, GDAL metadata) is
:mod:`geoloc.sensors.rpc`.

A 3-D grid of ground points is made by intersecting the sensor's lines of
sight for a grid of pixels with several surfaces of constant ellipsoidal
height, and the 78 coefficients are found by linear least squares on
``NUM - x * DEN' = x`` with the denominators' weights refined iteratively
(Tao & Hu, PE&RS 67(12), 2001). Check points are a second, staggered grid
never used in the fit. [L12] reports ZY-3 RPCs fitted to the rigorous model
better than 0.15 % of a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.base import Sensor
from geoloc.sensors.rpc import RPCModel, rpc_terms
from geoloc.status import Status
from geoloc.surfaces.height import HeightSurface


@dataclass(frozen=True)
class RPCFit:
    """Result of :func:`fit_rpc`.

    Attributes
    ----------
    model : RPCModel
    fit_rms_px, fit_max_px : float
        Image distance (hypot of row and column error) between the RPC and the
        rigorous model at the fit points: RMS and maximum [px].
    check_rms_px, check_max_px : float
        The same on the independent check points.
    n_fit, n_check : int
        Number of points.
    check_residuals : ndarray (n_check, 2)
        Row and column residuals (RPC minus rigorous) at the check points.
    """

    model: RPCModel
    fit_rms_px: float
    fit_max_px: float
    check_rms_px: float
    check_max_px: float
    n_fit: int
    n_check: int
    check_residuals: np.ndarray = field(repr=False)


def grid_points(
    sensor: Sensor,
    n_rows: int,
    n_cols: int,
    heights: ArrayLike,
    staggered: bool = False,
    corrections: Corrections = NO_CORRECTIONS,
) -> tuple[
    NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int
]:
    """Pixels on a regular grid spanning the image and the ground points at each height.

    The grid runs from the image's outer edges (0.5 and rows + 0.5); with
    ``staggered`` it takes the cell centres of that grid instead. Returns
    ``(rows, cols, lat, lon, h, n_lost)`` for the pixels whose ray met the
    height surface, and how many did not.
    """
    if staggered:  # cell centres of the fit grid
        fr = (np.arange(n_rows) + 0.5) / n_rows
        fc = (np.arange(n_cols) + 0.5) / n_cols
    else:
        fr = np.linspace(0.0, 1.0, n_rows)
        fc = np.linspace(0.0, 1.0, n_cols)
    rows = 0.5 + fr * sensor.rows
    cols = 0.5 + fc * sensor.cols
    R, C, Hh = np.meshgrid(rows, cols, np.asarray(heights, float), indexing="ij")
    # the rigorous model's ground points through the location pipeline, on the exact surfaces of
    # constant geodetic height (an RPC's heights are geodetic)
    g = Pipeline(sensor, HeightSurface(Hh.ravel(), "geodetic"), corrections).locate(R.ravel(), C.ravel())
    ok = g.status == Status.OK
    return R.ravel()[ok], C.ravel()[ok], g.lat[ok], g.lon[ok], g.h[ok], int(np.sum(~ok))


def solve_ratio(
    T: NDArray[np.float64], x: NDArray[np.float64], n_iter: int = 4, ridge: float = 1e-12
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least squares for NUM(T)/DEN(T) = x, DEN[0] = 1 (Tao & Hu 2001 iterative weights).

    Linearised: T a - x (T' b') = x, with weights 1 / DEN(T)^2 from the previous
    solution. Columns are scaled to unit norm and a tiny ridge (relative
    1e-12) keeps the near-degenerate directions (a frame camera is almost a
    ratio of linear forms) from blowing up the coefficients.

    Returns
    -------
    num, den : ndarray (20,)
        ``den[0] = 1``.
    """
    if not (isinstance(n_iter, int) and n_iter >= 1):  # no pass: no coefficients to return
        raise ValueError(f"n_iter = {n_iter!r}: must be an integer >= 1")
    M = np.hstack([T, -x[:, None] * T[:, 1:]])
    w = np.ones(len(x))
    coef = np.zeros(M.shape[1])
    for _ in range(n_iter):
        Mw = M * w[:, None]
        xw = x * w
        scale = np.linalg.norm(Mw, axis=0)
        scale[scale == 0] = 1.0
        Ms = Mw / scale
        # einsum, not BLAS: these products are tiny and a threaded BLAS on a loaded
        # 2-core machine spends seconds spinning on them
        N = np.einsum("ij,ik->jk", Ms, Ms)
        lam = ridge * np.trace(N)  # unit columns: trace = number of unknowns >= the largest eigenvalue
        A_ = N + lam * np.eye(Ms.shape[1])
        sol = np.linalg.solve(A_, np.einsum("ij,i->j", Ms, xw)) / scale
        coef = sol
        den = 1.0 + np.einsum("ij,j->i", T[:, 1:], sol[20:])
        w = 1.0 / np.abs(den)
    num = coef[:20]
    den = np.concatenate([[1.0], coef[20:]])
    return num, den


def fit_rpc(
    sensor: Sensor,
    height_min: float,
    height_max: float,
    grid: tuple[int, int, int] = (21, 21, 7),
    check_grid: tuple[int, int, int] = (20, 20, 6),
    corrections: Corrections = NO_CORRECTIONS,
) -> RPCFit:
    """Fit the 78 RPC coefficients to a sensor model over a 3-D grid [L12 section 4.1].

    Parameters
    ----------
    sensor : Sensor
        A rigorous sensor (``PushbroomSensor``, a frame sensor bound to its pose:
        ``geoloc.workflows.rpc_scenario.FrameCameraSensor``; any ``Sensor`` whose state is
        None), located through :class:`geoloc.pipeline.Pipeline`.
    height_min, height_max : float
        Ellipsoidal height range of the fit [m] (the terrain's range plus a margin).
    grid : (int, int, int)
        Fit points: pixel rows x pixel columns x height layers, spanning the
        image edges and the height range. At least 39 points are needed per
        image axis; the default (3087) is the usual generous choice.
    check_grid : (int, int, int)
        Check points: a staggered grid (cell centres of a grid this size, and
        heights between the fit layers), never used in the fit.
    corrections : Corrections
        The rigorous model's line-of-sight corrections (:class:`geoloc.pipeline.Corrections`):
        the RPC then holds them, as a maker's RPC holds its own.

    Returns
    -------
    RPCFit
    """
    if not (math.isfinite(height_min) and math.isfinite(height_max) and height_max > height_min):
        raise ValueError(f"height range [{height_min!r}, {height_max!r}] m must be finite and increasing")
    for name, g in (("grid", grid), ("check_grid", check_grid)):
        if len(g) != 3 or any((not isinstance(v, int)) or v < 2 for v in g):
            raise ValueError(f"{name} = {g!r} must be 3 integers >= 2")
    if grid[0] * grid[1] * grid[2] < 39:
        raise ValueError(f"grid = {grid!r} gives fewer than the 39 points per axis the fit needs")
    hs = np.linspace(height_min, height_max, grid[2])
    r, c, lat, lon, h, lost = grid_points(sensor, grid[0], grid[1], hs, corrections=corrections)
    if lost or r.size < 39:
        raise ValueError(
            f"{lost} fit-grid pixels have no ground point (rays missing the surface); "
            "check the sensor geometry and height range"
        )
    lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
    lon_mid = np.rad2deg(np.arctan2(np.mean(np.sin(lon)), np.mean(np.cos(lon))))
    dlon = (lon_deg - lon_mid + 180.0) % 360.0 - 180.0
    lat_off = 0.5 * (lat_deg.max() + lat_deg.min())
    long_off = lon_mid + 0.5 * (dlon.max() + dlon.min())
    model0 = dict(
        line_off=(sensor.rows - 1) / 2.0,
        samp_off=(sensor.cols - 1) / 2.0,
        lat_off=lat_off,
        long_off=(long_off + 180.0) % 360.0 - 180.0,
        height_off=0.5 * (height_min + height_max),
        line_scale=sensor.rows / 2.0,
        samp_scale=sensor.cols / 2.0,
        lat_scale=0.5 * (lat_deg.max() - lat_deg.min()),
        long_scale=0.5 * (dlon.max() - dlon.min()),
        height_scale=0.5 * (height_max - height_min),
    )
    tmp = RPCModel(
        **model0, line_num=np.zeros(20), line_den=np.eye(20)[0], samp_num=np.zeros(20), samp_den=np.eye(20)[0]
    )
    T = rpc_terms(*tmp.normalise(lat, lon, h))
    ln = (r - 1.0 - model0["line_off"]) / model0["line_scale"]
    sn = (c - 1.0 - model0["samp_off"]) / model0["samp_scale"]
    lnum, lden = solve_ratio(T, ln)
    snum, sden = solve_ratio(T, sn)
    model = RPCModel(**model0, line_num=lnum, line_den=lden, samp_num=snum, samp_den=sden)

    rr, cc = model.ground_to_pixel(lat, lon, h)
    res_fit = np.hypot(rr - r, cc - c)
    hs_c = height_min + (np.arange(check_grid[2]) + 0.5) / check_grid[2] * (height_max - height_min)
    r2, c2, lat2, lon2, h2, _ = grid_points(
        sensor, check_grid[0], check_grid[1], hs_c, staggered=True, corrections=corrections
    )
    rr2, cc2 = model.ground_to_pixel(lat2, lon2, h2)
    res = np.stack([rr2 - r2, cc2 - c2], axis=-1)
    d = np.hypot(res[:, 0], res[:, 1])
    return RPCFit(
        model,
        float(np.sqrt(np.mean(res_fit**2))),
        float(res_fit.max()),
        float(np.sqrt(np.mean(d**2))),
        float(d.max()),
        int(r.size),
        int(r2.size),
        res,
    )


__all__ = ["RPCFit", "fit_rpc", "grid_points", "solve_ratio"]
