"""RPC scenarios: load one, fit its RPC, write it, cross-check GDAL's RPC_DEM; what ``geoloc rpc`` reports.

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md``. The pieces
live in their layers: the RPC model and :class:`~geoloc.sensors.rpc.RPCSensor`
in :mod:`geoloc.sensors.rpc`, the fit in :mod:`geoloc.analysis.rpc_fit`, the
bias / affine adjustment in :mod:`geoloc.analysis.rpc_adjust`, GeoTIFF and
GDAL I/O in :mod:`geoloc.io.rpc_gdal`. This module keeps the scenario file
loader, the frame camera bound to one pose (:class:`FrameCameraSensor`), the
DEM cross-check against GDAL and the report.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.progress import Progress
from geoloc.analysis.rpc_fit import fit_rpc
from geoloc.frames.chain import Pose
from geoloc.io.rpc_gdal import (
    gdal_rpc_to_ground,
    write_ellipsoidal_dem,
    write_rpc_geotiff,
)
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline, corrections_from_table
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.sensor_file import load_sensor
from geoloc.sensors.rpc import RPCModel
from geoloc.frames.graph import BoundFrames
from geoloc.sensors.base import PixelHit, Sensor
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.tomlio import read_toml

if TYPE_CHECKING:  # loaded with a pushbroom scenario only
    from geoloc.sensors.pushbroom import PushbroomSensor
    from geoloc.surfaces.dem import DEM


# ------------------------------------------------------------------ sensors
@dataclass(frozen=True)
class FrameCameraSensor:
    """The aircraft frame camera of [Q17] bound to one pose: a sensor whose state is None.

    The :class:`~geoloc.sensors.base.Sensor` calls the RPC fit and the location pipeline use
    (``rows``, ``cols``, ``line_of_sight``, ``ground_to_pixel``, ``in_image``), each the
    frame sensor's at :attr:`pose`.
    """

    pose: Pose
    camera: FrameSensor  # a camera or sensor file's (sensor_file.load_sensor)
    name: str = ""

    @property
    def rows(self) -> int:
        return self.camera.rows

    @property
    def cols(self) -> int:
        return self.camera.cols

    @property
    def params(self) -> Mapping[str, float]:
        return self.camera.params

    def with_params(self, **changes: float) -> "FrameCameraSensor":
        """The same pose with the camera's named parameters changed."""
        return dataclasses.replace(self, camera=self.camera.with_params(**changes))

    def line_of_sight(self, row: ArrayLike, col: ArrayLike, state: Any = None, *, outside: str = "flag") -> LineOfSight:
        return self.camera.line_of_sight(row, col, self.pose, outside=outside)

    def ground_to_pixel(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike, state: Any = None) -> PixelHit:
        return self.camera.ground_to_pixel(lat, lon, h, self.pose)

    def in_image(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        return self.camera.in_image(row, col)

    def frames(self, state: Any = None) -> BoundFrames:
        """The camera's frames at :attr:`pose` (``state`` is ignored: the pose is bound)."""
        return self.camera.frames(self.pose)


@dataclass(frozen=True)
class DemCrossCheck:
    """GDAL RPC + RPC_DEM against the project's exact DEM intersection (:func:`crosscheck_gdal_dem`).

    Attributes
    ----------
    row, col : ndarray
        Pixels compared (1-based).
    exact_lat, exact_lon, exact_h : ndarray
        Exact first hit of the rigorous line of sight with the DEM [rad, rad, m].
    gdal_lat, gdal_lon : ndarray
        GDAL's answer [rad] (NaN where GDAL failed).
    error_px : ndarray
        GDAL's ground point (at the DEM height there) projected by the rigorous
        model, distance to the pixel asked for [px].
    error_m : ndarray
        Distance between GDAL's and the exact ground point [m].
    n_failed : int
        Pixels where GDAL reported no solution.
    options : dict
        The GDAL transformer options used.
    """

    row: np.ndarray
    col: np.ndarray
    exact_lat: np.ndarray
    exact_lon: np.ndarray
    exact_h: np.ndarray
    gdal_lat: np.ndarray
    gdal_lon: np.ndarray
    error_px: np.ndarray
    error_m: np.ndarray
    n_failed: int
    options: dict

    @property
    def max_px(self) -> float:
        return float(np.nanmax(self.error_px)) if self.error_px.size else float("nan")

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.nanmean(self.error_px**2))) if self.error_px.size else float("nan")

    @property
    def max_m(self) -> float:
        return float(np.nanmax(self.error_m)) if self.error_m.size else float("nan")


def dem_pixels(
    sensor: Sensor, dem: DEM, grid: tuple[int, int] = (12, 12), margin: float = 0.05
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A grid of pixels whose ground points lie inside the DEM.

    The DEM's node hull is projected into the image (at its mean height); the
    grid spans the part of the image inside that projection and inside the
    image, shrunk by ``margin`` on each side. Pixels whose exact DEM
    intersection fails are dropped by the caller.
    """
    w, s_, e, n = dem.bounds_deg
    lat = np.deg2rad(np.linspace(s_, n, 9))
    lon = np.deg2rad(np.linspace(w, e, 9))
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    edge = np.zeros(LA.shape, bool)
    edge[[0, -1], :] = edge[:, [0, -1]] = True
    hm = float(np.nanmean(dem.grid.values))
    r, c, st = sensor.ground_to_pixel(LA[edge], LO[edge], np.full(int(edge.sum()), hm))
    ok = st == Status.OK
    r0 = max(0.5, np.nanmin(r[ok])) if ok.any() else 0.5
    r1 = min(sensor.rows + 0.5, np.nanmax(r[ok])) if ok.any() else sensor.rows + 0.5
    c0 = max(0.5, np.nanmin(c[ok])) if ok.any() else 0.5
    c1 = min(sensor.cols + 0.5, np.nanmax(c[ok])) if ok.any() else sensor.cols + 0.5
    dr, dc = margin * (r1 - r0), margin * (c1 - c0)
    R, C = np.meshgrid(np.linspace(r0 + dr, r1 - dr, grid[0]), np.linspace(c0 + dc, c1 - dc, grid[1]), indexing="ij")
    return R.ravel(), C.ravel()


def crosscheck_gdal_dem(
    sensor: Sensor,
    model: RPCModel,
    dem: DEM,
    dem_path_for_gdal: str | os.PathLike[str],
    row: ArrayLike,
    col: ArrayLike,
    *,
    pixel_error_threshold: float | None = 1e-6,
    max_iterations: int | None = 100,
    corrections: Corrections = NO_CORRECTIONS,
) -> DemCrossCheck:
    """Pixel -> ground by GDAL (RPC + ``RPC_DEM``) against the project's exact DEM intersection.

    The exact side intersects the rigorous line of sight with the DEM
    (:func:`geoloc.surfaces.terrain.intersect_dem`, ``method="exact"``: the visible first
    hit on the bilinear surface). The GDAL side runs rasterio's
    ``RPCTransformer`` with ``RPC_DEM=dem_path_for_gdal`` and height 0 above
    it. GDAL stops iterating when its back-projected pixel is within
    ``RPC_PIXEL_ERROR_THRESHOLD`` (default 0.1 px in GDAL; set tighter here).

    Parameters
    ----------
    sensor : PushbroomSensor or FrameCameraSensor
    model : RPCModel
        The RPC fitted to ``sensor``.
    dem : geoloc.surfaces.dem.DEM
        The project's DEM (ellipsoidal node heights).
    dem_path_for_gdal : path-like
        The file GDAL reads: normally :func:`write_ellipsoidal_dem` of ``dem``.
    row, col : array_like
        Pixels (1-based).

    Returns
    -------
    DemCrossCheck
        Pixels whose exact intersection fails (ray leaves the DEM) are dropped.
    """
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc.surfaces.terrain import DemSurface

    row_a, col_a = np.broadcast_arrays(np.asarray(row, float).ravel(), np.asarray(col, float).ravel())
    pipe = Pipeline(sensor, DemSurface(dem, "exact"), corrections)
    hit = pipe.locate(row_a, col_a)
    ok = hit.status == Status.OK
    row_k, col_k = row_a[ok], col_a[ok]
    lat_e, lon_e, h_e, p_e = hit.lat[ok], hit.lon[ok], hit.h[ok], hit.ecef[ok]
    lat_g, lon_g = gdal_rpc_to_ground(
        model,
        row_k,
        col_k,
        dem_path=dem_path_for_gdal,
        height=0.0,
        pixel_error_threshold=pixel_error_threshold,
        max_iterations=max_iterations,
    )
    h_g = dem.height(lat_g, lon_g)
    r_g, c_g, st = pipe.ground_to_pixel(lat_g, lon_g, h_g)
    err_px = np.where(st == Status.OK, np.hypot(r_g - row_k, c_g - col_k), np.nan)
    err_m = np.linalg.norm(geodetic_to_ecef(lat_g, lon_g, h_g) - p_e, axis=-1)
    opts = {
        "RPC_DEM": str(dem_path_for_gdal),
        "RPC_DEMINTERPOLATION": "bilinear",
        "RPC_DEM_APPLY_VDATUM_SHIFT": "FALSE",
        "RPC_HEIGHT": "0 (zs = 0 above the DEM)",
        "RPC_PIXEL_ERROR_THRESHOLD": pixel_error_threshold,
        "RPC_MAX_ITERATIONS": max_iterations,
    }
    return DemCrossCheck(
        row_k, col_k, lat_e, lon_e, h_e, lat_g, lon_g, err_px, err_m, int(np.sum(~np.isfinite(lat_g))), opts
    )


# --------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class RPCScenario:
    """A sensor plus what the ``geoloc rpc`` verb needs to fit and check its RPC.

    Attributes
    ----------
    name, kind : str
        ``kind`` is ``"pushbroom"`` or ``"frame"``.
    sensor : PushbroomSensor or FrameCameraSensor
    height_min, height_max : float
        Ellipsoidal height range of the fit [m].
    grid, check_grid : tuple of 3 int
    dem_path : Path or None
    dem_datum : str
        ``"egm96"`` (orthometric DEM) or ``"ellipsoid"``.
    cross_check_grid : tuple of 2 int
        Pixels (rows x cols) compared with GDAL RPC_DEM.
    corrections : Corrections
        The rigorous model's line-of-sight corrections (the file's ``[corrections]`` table over
        the sensor's defaults: light-time and aberration on for the pushbroom), which the
        fitted RPC then holds.
    """

    name: str
    kind: str
    sensor: PushbroomSensor | FrameCameraSensor
    height_min: float
    height_max: float
    grid: tuple
    check_grid: tuple
    dem_path: Path | None
    dem_datum: str
    cross_check_grid: tuple
    corrections: Corrections = NO_CORRECTIONS


def _resolve(rel: str, base: Path, field_name: str) -> Path:
    from geoloc.assets import ASSETS

    p = Path(rel)
    for cand in (p,) if p.is_absolute() else (base / p, ASSETS / p):
        if cand.exists():
            return cand
    raise FileNotFoundError(f"{field_name} = {rel!r}: not found (tried beside the scenario and in {ASSETS})")


def _int_tuple(d, key, n, default, source):
    v = d.get(key, default)
    if (
        not isinstance(v, (list, tuple))
        or len(v) != n
        or any(isinstance(x, bool) or not isinstance(x, int) or x < 2 for x in v)
    ):
        raise ValueError(f"{source}: {key} = {v!r} must be {n} integers >= 2")
    return tuple(v)


def load_rpc_scenario(path: str | os.PathLike[str]) -> RPCScenario:
    """Read an RPC scenario file (``assets/scenarios/zy3_nadir.toml``, ``qiao2017_frame.toml``).

    Format: docs/rpc.md. Errors name the file, the table and the key.
    """
    from geoloc.sensors.pushbroom import PushbroomSensor

    path = Path(path)
    data = read_toml(path, "scenario file")
    src = str(path)
    kind = data.get("kind")
    sensor: PushbroomSensor | FrameCameraSensor
    if kind == "pushbroom":
        try:
            sensor = PushbroomSensor.from_dict(data, source=src)
        except ValueError as e:  # found by fuzzing: the sensor's own checks ("tan_psi_x = ...") named no file
            if src in str(e):
                raise
            raise ValueError(f"{src}: {e}") from None
    elif kind == "frame":
        cam_rel = data.get("camera")
        if not isinstance(cam_rel, str):
            raise ValueError(f"{src}: camera = {cam_rel!r} must be the path of a camera or sensor file")
        camera = load_sensor(_resolve(cam_rel, path.parent, f"{src}: camera"))
        pose_d = data.get("pose")
        if not isinstance(pose_d, dict):
            raise ValueError(f"{src}: missing table [pose]")
        allowed = (
            "lat_deg",
            "lon_deg",
            "h_m",
            "heading_deg",
            "pitch_deg",
            "roll_deg",
            "gimbal_roll_deg",
            "gimbal_pitch_deg",
        )
        unknown = sorted(set(pose_d) - set(allowed))
        if unknown:
            raise ValueError(f"{src} [pose]: unknown key(s) {unknown}; allowed: {list(allowed)}")
        missing = [k for k in allowed[:3] if k not in pose_d]
        if missing:
            raise ValueError(f"{src} [pose]: missing key(s) {missing}")
        for k, v in pose_d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{src} [pose]: {k} = {v!r} must be a finite number")
        pose = Pose.from_deg(**pose_d).validate()
        sensor = FrameCameraSensor(pose, camera, name=str(data.get("name", "")))
    else:
        raise ValueError(f"{src}: kind = {kind!r} must be 'pushbroom' or 'frame'")
    r = data.get("rpc")
    if not isinstance(r, dict):
        raise ValueError(f"{src}: missing table [rpc]")
    hr = []
    for k in ("height_min_m", "height_max_m"):
        v = r.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{src} [rpc]: {k} = {v!r} must be a finite number (metres)")
        hr.append(float(v))
    if hr[1] <= hr[0]:
        raise ValueError(f"{src} [rpc]: height_max_m = {hr[1]!r} must exceed height_min_m = {hr[0]!r}")
    grid = _int_tuple(r, "grid", 3, [21, 21, 7], f"{src} [rpc]")
    check = _int_tuple(r, "check_grid", 3, [20, 20, 6], f"{src} [rpc]")
    dem = data.get("dem", {})
    dem_path, datum, cc = None, "egm96", (12, 12)
    if dem:
        if not isinstance(dem.get("path"), str):
            raise ValueError(f"{src} [dem]: path = {dem.get('path')!r} must be a file path")
        dem_path = _resolve(dem["path"], path.parent, f"{src} [dem]: path")
        datum = dem.get("datum", "egm96")
        if datum not in ("egm96", "ellipsoid"):
            raise ValueError(f"{src} [dem]: datum = {datum!r} must be 'egm96' or 'ellipsoid'")
        cc = _int_tuple(dem, "cross_check_grid", 2, [12, 12], f"{src} [dem]")
    table = data.get("corrections", {})
    if not isinstance(table, dict):
        raise ValueError(f"{src}: corrections must be a table [corrections], got {table!r}")
    corrections = corrections_from_table(sensor, table, f"{src} [corrections]")
    return RPCScenario(
        str(data.get("name", path.stem)), kind, sensor, hr[0], hr[1], grid, check, dem_path, datum, cc, corrections
    )


def rpc_report(
    scenario: RPCScenario,
    out_tif: str | os.PathLike[str],
    dem: DEM | None = None,
    *,
    gdal: bool = True,
    pixel_error_threshold: float = 1e-6,
    dem_copy: str | os.PathLike[str] | None = None,
    progress: bool | None = False,
) -> dict[str, Any]:
    """Fit, write and cross-check the RPC of a scenario: what ``geoloc rpc`` reports.

    Parameters
    ----------
    scenario : RPCScenario
    out_tif : path-like
        GeoTIFF to write (RPC metadata, sparse pixels).
    dem : geoloc.surfaces.dem.DEM, optional
        The scenario's DEM (``scenario.dem_path`` with ``scenario.dem_datum``), opened
        by the caller: a workflow does not open a DEM itself (``tests/sensors/test_one_model.py``).
        Needed for the GDAL cross-check when the scenario has a ``[dem]``.
    gdal : bool
        Run the GDAL RPC_DEM cross-check (needs ``scenario.dem_path``).
    pixel_error_threshold : float
        GDAL's ``RPC_PIXEL_ERROR_THRESHOLD`` for the main figure [px].
    dem_copy : path-like, optional
        Where to keep the ellipsoidal-height DEM given to GDAL (default: a
        temporary file, deleted).
    progress : bool or None
        :class:`geoloc.progress.Progress` on stderr, one update per stage: the fit, the GeoTIFF,
        each of the three GDAL cross-checks (None: the bar on a terminal, a line every 10 s
        elsewhere; False: nothing).

    Returns
    -------
    dict
        JSON-ready: ``fit_rms_px``, ``check_rms_px``, ``check_max_px``,
        ``gdal_vs_exact_max_px`` and the supporting figures (docs/rpc.md).
    """
    import tempfile

    s = scenario.sensor
    cross = gdal and scenario.dem_path is not None
    bar = Progress(5 if cross else 2, f"rpc {scenario.name}", progress)  # stages
    fit = fit_rpc(
        s,
        scenario.height_min,
        scenario.height_max,
        scenario.grid,
        scenario.check_grid,
        corrections=scenario.corrections,
    )
    bar.update(1)
    write_rpc_geotiff(out_tif, fit.model, s.rows, s.cols)
    bar.update(1)
    rep = {
        "scenario": scenario.name,
        "kind": scenario.kind,
        "image": str(out_tif),
        "rows": int(s.rows),
        "cols": int(s.cols),
        "height_range_m": [scenario.height_min, scenario.height_max],
        "n_fit": fit.n_fit,
        "n_check": fit.n_check,
        "fit_rms_px": fit.fit_rms_px,
        "fit_max_px": fit.fit_max_px,
        "check_rms_px": fit.check_rms_px,
        "check_max_px": fit.check_max_px,
        "corrections": scenario.corrections.label,
    }
    if not gdal or scenario.dem_path is None:
        rep["gdal_vs_exact_max_px"] = None
        rep["gdal_note"] = "skipped" if not gdal else "no [dem] in the scenario"
        bar.close()
        return rep
    if dem is None:
        raise ValueError(
            f"scenario {scenario.name!r} names the DEM {scenario.dem_path}: pass it opened, "
            "rpc_report(scenario, out_tif, DEM.open(scenario.dem_path, datum=scenario.dem_datum)), "
            "or gdal=False"
        )
    rows, cols = dem_pixels(s, dem, scenario.cross_check_grid)
    with tempfile.TemporaryDirectory() as tmp:
        ell = Path(dem_copy) if dem_copy is not None else Path(tmp) / "dem_ellipsoidal.tif"
        write_ellipsoidal_dem(dem, ell)
        cc = crosscheck_gdal_dem(
            s,
            fit.model,
            dem,
            ell,
            rows,
            cols,
            pixel_error_threshold=pixel_error_threshold,
            corrections=scenario.corrections,
        )
        bar.update(1)
        cc_default = crosscheck_gdal_dem(
            s,
            fit.model,
            dem,
            ell,
            cc.row,
            cc.col,
            pixel_error_threshold=None,
            max_iterations=None,
            corrections=scenario.corrections,
        )
        bar.update(1)
    # GDAL's default handling of the bundled file: orthometric values taken as ellipsoidal
    cc_raw = crosscheck_gdal_dem(
        s,
        fit.model,
        dem,
        scenario.dem_path,
        cc.row,
        cc.col,
        pixel_error_threshold=pixel_error_threshold,
        corrections=scenario.corrections,
    )
    bar.update(1)
    bar.close()
    rep.update(
        {
            "gdal_vs_exact_max_px": cc.max_px,
            "gdal_vs_exact_rms_px": cc.rms_px,
            "gdal_vs_exact_max_m": cc.max_m,
            "gdal_points": int(cc.row.size),
            "gdal_failed": cc.n_failed,
            "gdal_options": {k: str(v) for k, v in cc.options.items() if k != "RPC_DEM"},
            "gdal_default_threshold_max_px": cc_default.max_px,
            "gdal_orthometric_dem_max_px": cc_raw.max_px,
            "gdal_orthometric_dem_max_m": cc_raw.max_m,
            "dem": str(scenario.dem_path),
            "dem_datum": scenario.dem_datum,
        }
    )
    if dem_copy is not None:
        rep["ellipsoidal_dem"] = str(dem_copy)
    return rep


__all__ = [
    "DemCrossCheck",
    "FrameCameraSensor",
    "RPCScenario",
    "crosscheck_gdal_dem",
    "dem_pixels",
    "load_rpc_scenario",
    "rpc_report",
]
