"""Boresight / mounting calibration and camera resection from flight-test records.

The idea is the on-orbit calibration of [L12 eq. 2] (docs/method.md section 7): an
exterior rotation, fitted by least squares to ground control, absorbs the
mounting bias of the sensor; here it is applied to the aircraft gimbal camera of
[Q17] (frame chain docs/method.md section 2, [Q17 eq. 6-9]).

Two places in the chain can hold the rotation (both are hooks of
:class:`geoloc.frames.chain.FrameChain`, and both can be saved in the camera file,
see :mod:`geoloc.sensors.camera`):

- ``"mount"`` (default): ``R_base_body``, the gimbal base relative to the
  aircraft body (POS) axes, between [Q17 eq. 6] and eq. 7:
  ``R_cam_body = Ry(gimbal_pitch) Rx(gimbal_roll) R_base_body``. This is the
  installation error that [Q17] blames. It is fixed in the aircraft, so the
  ground error it causes turns with the gimbal: records taken at different
  gimbal angles (the two flights, roll -45 and +50 deg) separate its three
  angles, and one rotation serves every flight.
- ``"camera"``: ``R_cam_inner``, the camera's optical axes relative to the
  inner gimbal (a collimation / boresight error of the camera head), after
  eq. 7: ``R_cam_body = R_cam_inner Ry(gimbal_pitch) Rx(gimbal_roll)``. Its
  rotation about the line of sight (z) moves a target only through the pixel's
  offset from the principal point (about 1000 / 166841 rad here), so that
  angle is weakly determined.

Within one flight the gimbal angles hardly change (roll within 5 deg), so the
two models fit equally well and the ``mount`` angles are strongly correlated
(two combinations are determined, see ``docs/calibration.md``); fitting all
flights together (``joint``) determines all three.

Each rotation is ``rx(x) @ ry(y) @ rz(z)`` (passive, ``docs/conventions.md``)
with small angles (x, y, z) [rad]. Optionally the focal length and principal
point are fitted too (the principal point is degenerate with the x/y angles
when the gimbal angles do not vary; the reported correlations show it).

Residuals are the horizontal error vectors (east, north) [m] of the computed
position minus the surveyed truth (:mod:`geoloc.analysis.errors`), the computed
position taken at the target height of a column or on a DEM. Uncertainties are
the usual linearised least-squares ones: ``cov = s^2 (J^T J)^-1`` with
``s^2 = |r|^2 / (m - p)`` (m residuals, p parameters).

Camera resection (:func:`resect_camera`): how the bundled camera of
``assets/cameras/qiao2017.toml`` was derived. The published computed positions
([Q17] Tables 3-4, ``paper_lat_deg``, ``paper_lon_deg``) must lie on the line
of sight of their pixel; with the target heights unknown (ASTER GDEM values are
not published), the fit solves for f, i0, j0 and one height per record:
2n equations, n + 3 unknowns.

Conventions: ``docs/conventions.md``. SI and radians inside; degrees only in the
JSON report and the camera file.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from geoloc.analysis.errors import error_vectors, group_labels, group_summary
from geoloc.frames import rotations as rot
from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.geodesy.local import R_ecef_enu
from geoloc.io.records import Records
from geoloc.locate import line_of_sight
from geoloc.sensors.camera import Camera
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint
from geoloc.surfaces.height import PerRecordHeightSurface, for_records

#: Calibration models: name -> the Camera field holding the rotation.
MODELS = {"mount": "mount", "camera": "boresight"}

#: Residual [m] given to a record whose ray fails during the iterations (it
#: pushes the solver back without a NaN).
FAILED_RESIDUAL_M = 1.0e4


def _subset_pose(pose: Pose, idx) -> Pose:
    return pose.take(idx)


@dataclass
class _Data:
    """The arrays of the records used by a fit (all records; fits select by index)."""

    pose: Pose
    row: np.ndarray
    col: np.ndarray
    ref_lat: np.ndarray  # reference (truth or published) position [rad]
    ref_lon: np.ndarray
    surface: object  # where the targets lie (a Surface; per-record heights take their subset)

    def locate(self, camera: Camera, idx, surface=None) -> GroundPoint:
        # recorded image points: a pixel off the sensor is reported by the verb, not dropped here
        los = line_of_sight(_subset_pose(self.pose, idx), camera, self.row[idx], self.col[idx],
                            outside="extrapolate")
        return for_records(self.surface if surface is None else surface, idx).intersect(los)

    def east_north(self, ground: GroundPoint, idx) -> np.ndarray:
        """(east, north) of computed minus reference, at the computed height, (n, 2) [m]."""
        lat, lon = self.ref_lat[idx], self.ref_lon[idx]
        ref = geodetic_to_ecef(lat, lon, ground.h)
        d = rot.rotate(np.swapaxes(R_ecef_enu(lat, lon), -1, -2), ground.ecef - ref)
        return d[..., :2]


def _records_data(records: Records, surface, prefix: str) -> _Data:
    for c in (f"{prefix}_lat_deg", f"{prefix}_lon_deg"):
        if not records.has(c):
            raise ValueError(f"{records.path}: column {c!r} is missing or empty; calibration needs "
                             f"the surveyed position of each record")
    return _Data(records.pose(), records.column("row"), records.column("col"),
                 np.deg2rad(records.column(f"{prefix}_lat_deg")),
                 np.deg2rad(records.column(f"{prefix}_lon_deg")), surface)


# --------------------------------------------------------------------------- parameters
def _param_names(model: str, fit_focal: bool, fit_pp: bool) -> list:
    names = [f"{model}_x", f"{model}_y", f"{model}_z"]
    if fit_focal:
        names.append("focal_length")
    if fit_pp:
        names += ["principal_row", "principal_col"]
    return names


def _camera_from_params(camera: Camera, model: str, p, fit_focal: bool, fit_pp: bool) -> Camera:
    """Camera with the rotation angles p[:3] [rad]; focal as f0 (1 + p), principal point as f0 p [px]."""
    kw = {MODELS[model]: tuple(float(a) for a in p[:3])}
    k = 3
    f0 = camera.focal_length_px
    if fit_focal:
        kw["focal_length_px"] = f0 * (1.0 + float(p[k]))
        k += 1
    if fit_pp:
        kw["principal_row"] = camera.principal_row + f0 * float(p[k])
        kw["principal_col"] = camera.principal_col + f0 * float(p[k + 1])
    return dataclasses.replace(camera, **kw)


def _covariance(jac, resid, n_params):
    """Linearised covariance s^2 (J^T J)^-1, s^2 = |r|^2 / (m - p); NaN if not determined."""
    m = resid.size
    dof = m - n_params
    if dof <= 0:
        return np.full((n_params, n_params), np.nan), float("nan")
    s2 = float(resid @ resid) / dof
    JtJ = jac.T @ jac
    # scale columns before inverting: the parameters mix radians and relative units
    d = np.sqrt(np.diag(JtJ))
    if np.any(d == 0):
        return np.full((n_params, n_params), np.nan), s2
    A = JtJ / np.outer(d, d)
    if np.linalg.cond(A) > 1e12:  # numerically singular: report "not determined"
        return np.full((n_params, n_params), np.nan), s2
    return s2 * np.linalg.inv(A) / np.outer(d, d), s2


@dataclass
class MountFit:
    """Result of :func:`fit_mounting`.

    Attributes
    ----------
    model : str
        ``"mount"`` or ``"camera"``.
    names : list of str
        Parameter names (angles [rad], ``focal_length`` relative, principal
        point in units of f0 pixels).
    x, sd : ndarray
        Estimates and standard deviations in those units.
    corr : ndarray (p, p)
        Correlation matrix.
    camera : Camera
        The calibrated camera (rotation, and intrinsics if fitted).
    residual_m : ndarray (n, 2)
        (east, north) error of each used record after the fit [m].
    idx : ndarray
        Record indices used.
    sigma_m : float
        Root of the residual variance factor s^2 (per component) [m].
    success : bool
    message : str
    """

    model: str
    names: list
    x: np.ndarray
    sd: np.ndarray
    corr: np.ndarray
    camera: Camera
    residual_m: np.ndarray
    idx: np.ndarray
    sigma_m: float
    success: bool
    message: str
    f0: float = float("nan")  # focal length [px] the relative parameters refer to

    @property
    def angles(self) -> np.ndarray:
        return self.x[:3]

    @property
    def angles_sd(self) -> np.ndarray:
        return self.sd[:3]

    def report(self) -> dict:
        """JSON-ready parameters: angles in degrees, intrinsics in pixels."""
        out = {"model": self.model,
               "angles_deg": [float(np.rad2deg(a)) for a in self.angles],
               "angles_sd_deg": [float(np.rad2deg(a)) for a in self.angles_sd],
               "parameter_names": self.names,
               "correlation": [[None if not np.isfinite(c) else round(float(c), 4) for c in row]
                               for row in self.corr],
               "sigma_m": self.sigma_m,
               "converged": self.success}
        # pairs the records cannot separate (|correlation| > 0.99): their values are
        # not meaningful one by one (e.g. mount angles within one flight)
        out["degenerate_pairs"] = [[self.names[a], self.names[b]]
                                   for a in range(len(self.names)) for b in range(a + 1, len(self.names))
                                   if not np.isfinite(self.corr[a, b]) or abs(self.corr[a, b]) > 0.99]
        cam = self.camera
        for k, name in enumerate(self.names[3:], start=3):
            key = "focal_length_px" if name == "focal_length" else name
            out[key] = float(getattr(cam, key))
            out[f"{key}_sd" if name != "focal_length" else "focal_length_sd_px"] = float(self.f0 * self.sd[k])
        return out


def _fit(data: _Data, camera: Camera, idx, model: str, fit_focal: bool, fit_pp: bool) -> MountFit:
    if model not in MODELS:
        raise ValueError(f"model = {model!r}: must be one of {sorted(MODELS)}")
    idx = np.asarray(idx)
    names = _param_names(model, fit_focal, fit_pp)
    start = getattr(camera, MODELS[model]) or (0.0, 0.0, 0.0)
    x0 = np.zeros(len(names))
    x0[:3] = start
    base = camera  # focal / principal point parameters are offsets from it

    def resid(p):
        cam = _camera_from_params(base, model, p, fit_focal, fit_pp)
        g = data.locate(cam, idx)
        r = data.east_north(g, idx)
        r[g.status != Status.OK] = FAILED_RESIDUAL_M
        return r.ravel()

    # Finite-difference Jacobian (default relative step ~1.5e-8 of max(|x|, 1)): an
    # 18-km ray moves ~0.3 mm, far above float64 ECEF rounding (~1e-9 m).
    sol = least_squares(resid, x0, method="lm", x_scale=np.full(len(names), 1e-3))
    cov, s2 = _covariance(sol.jac, sol.fun, len(names))
    sd = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    cam = _camera_from_params(base, model, sol.x, fit_focal, fit_pp)
    return MountFit(model, names, sol.x, sd, corr, cam, sol.fun.reshape(-1, 2), idx,
                    float(np.sqrt(s2)) if np.isfinite(s2) else float("nan"),
                    bool(sol.success), str(sol.message), float(base.focal_length_px))


def fit_mounting(records: Records, camera: Camera, surface, idx=None, model: str = "mount",
                 fit_focal: bool = False, fit_pp: bool = False, truth_prefix: str = "truth") -> MountFit:
    """Fit the mounting (or boresight) rotation to records with surveyed truth.

    Parameters
    ----------
    records : Records
        With ``{truth_prefix}_lat_deg`` / ``_lon_deg``.
    camera : Camera
        Starting camera (its existing rotation of the model is the start value).
    surface : Surface
        Where the lines of sight end: a
        :class:`geoloc.surfaces.height.PerRecordHeightSurface` (a height per record), a
        :class:`geoloc.surfaces.height.HeightSurface`, a DEM's
        :class:`geoloc.surfaces.terrain.DemSurface` or a mosaic.
    idx : array_like of int, optional
        Records to use (default all).
    model : {"mount", "camera"}
        Where the rotation sits (module docstring).
    fit_focal, fit_pp : bool
        Also fit the focal length / principal point.

    Returns
    -------
    MountFit

    Raises
    ------
    ValueError
        If fewer records than needed (each gives 2 equations) or no truth columns.
    """
    data = _records_data(records, surface, truth_prefix)
    idx = np.arange(len(records)) if idx is None else np.asarray(idx)
    n_par = len(_param_names(model, fit_focal, fit_pp))
    if 2 * idx.size <= n_par:
        raise ValueError(f"{idx.size} record(s) give {2 * idx.size} equations for {n_par} parameters; "
                         f"need at least {n_par // 2 + 1} records")
    return _fit(data, camera, idx, model, fit_focal, fit_pp)


def leave_one_out(records: Records, camera: Camera, surface, idx=None, model: str = "mount",
                  fit_focal: bool = False, fit_pp: bool = False, truth_prefix: str = "truth"):
    """Leave-one-out cross-validation: fit without record k, then measure k.

    Returns
    -------
    east_north : ndarray (n, 2)
        Error (east, north) of each left-out record under the fit of the others [m].
    distance : ndarray (n,)
        Its horizontal geodesic distance to the truth [m] (pyproj).
    """
    data = _records_data(records, surface, truth_prefix)
    idx = np.arange(len(records)) if idx is None else np.asarray(idx)
    out = np.full((idx.size, 2), np.nan)
    dist = np.full(idx.size, np.nan)
    for j, k in enumerate(idx):
        rest = idx[idx != k]
        fit = _fit(data, camera, rest, model, fit_focal, fit_pp)
        g = data.locate(fit.camera, np.array([k]))
        if g.status[0] == Status.OK:
            out[j] = data.east_north(g, np.array([k]))[0]
            dist[j] = horizontal_distance_m(g.lat_deg[0], g.lon_deg[0], np.rad2deg(data.ref_lat[k]),
                                            np.rad2deg(data.ref_lon[k]))
    return out, dist


# --------------------------------------------------------------------------- resection
@dataclass
class Resection:
    """Result of :func:`resect_camera`: fitted intrinsics, their uncertainties and the heights."""

    camera: Camera
    sd_focal_px: float
    sd_principal_row: float
    sd_principal_col: float
    corr: np.ndarray
    heights_m: np.ndarray
    rms_m: float
    rms_distance_m: float
    success: bool

    def report(self) -> dict:
        c = self.camera
        return {"focal_length_px": c.focal_length_px, "focal_length_sd_px": self.sd_focal_px,
                "principal_row": c.principal_row, "principal_row_sd": self.sd_principal_row,
                "principal_col": c.principal_col, "principal_col_sd": self.sd_principal_col,
                "correlation_f_i0_j0": [[round(float(v), 4) for v in r] for r in self.corr],
                "rms_misfit_m": self.rms_m,
                "rms_distance_m": self.rms_distance_m,
                "heights_m": [round(float(h), 2) for h in self.heights_m],
                "converged": self.success}


def resect_camera(records: Records, camera: Camera, computed_prefix: str = "paper",
                  initial_height_m: float = 0.0) -> Resection:
    """Fit focal length and principal point to published computed positions.

    Unknowns: f, i0, j0 and the target height h_k of each record; equations:
    the (east, north) offset between the line of sight of record k at height
    h_k and its published position ``{computed_prefix}_lat_deg/_lon_deg``
    ([Q17 eq. 8-11]). ``camera`` gives the start values (and the sensor size);
    its boresight / mount, if any, are kept fixed.

    Returns
    -------
    Resection
        ``rms_m`` is the RMS of the 2n residual components (east and north,
        the "RMS misfit" of ``docs/records.md``); ``rms_distance_m``
        the RMS horizontal distance per record (sqrt 2 larger).
    """
    n = len(records)
    if n < 3:
        raise ValueError(f"resection needs at least 3 records (n + 3 unknowns, 2n equations), got {n}")
    heights = np.full(n, float(initial_height_m))
    data = _records_data(records, PerRecordHeightSurface(heights), computed_prefix)
    idx = np.arange(n)
    f0 = camera.focal_length_px

    def cam_of(p):
        return dataclasses.replace(camera, focal_length_px=f0 * (1.0 + p[0]),
                                   principal_row=camera.principal_row + f0 * p[1],
                                   principal_col=camera.principal_col + f0 * p[2])

    def resid(p):
        t = PerRecordHeightSurface(p[3:] * 1000.0)  # heights in km inside the solver
        g = data.locate(cam_of(p), idx, surface=t)
        r = data.east_north(g, idx)
        r[g.status != Status.OK] = FAILED_RESIDUAL_M
        return r.ravel()

    x0 = np.concatenate([[0.0, 0.0, 0.0], heights / 1000.0])
    sol = least_squares(resid, x0, method="trf", x_scale="jac")
    cov, s2 = _covariance(sol.jac, sol.fun, x0.size)
    sd = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = (cov / np.outer(sd, sd))[:3, :3]
    r = sol.fun.reshape(-1, 2)
    return Resection(cam_of(sol.x), float(f0 * sd[0]), float(f0 * sd[1]), float(f0 * sd[2]), corr,
                     sol.x[3:] * 1000.0, float(np.sqrt(np.mean(r ** 2))),
                     float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))), bool(sol.success))


# --------------------------------------------------------------------------- per flight
def _round(v, nd=3):
    v = float(v)
    return round(v, nd) if np.isfinite(v) else None


def calibrate_groups(records: Records, camera: Camera, surface, group_column: str | None = "table",
                     model: str = "mount", fit_focal: bool = False, fit_pp: bool = False,
                     loo: bool = False, joint: bool = False, exclude_outliers: bool = False,
                     truth_prefix: str = "truth", k_sigma: float = 3.5) -> tuple[dict, dict]:
    """Per-flight errors before and after calibration, with optional leave-one-out.

    Parameters
    ----------
    records, camera, surface
        As :func:`fit_mounting`.
    group_column : str or None
        Column naming each record's flight; one group ``"all"`` if None.
    joint : bool
        Fit one rotation to all flights together (reported per flight); else
        one fit per flight.
    exclude_outliers : bool
        Leave the records flagged as outliers before calibration out of the fit
        (they are still measured).

    Returns
    -------
    report : dict
        ``{"groups": {name: {"n", "mean_error_before_m", "mean_error_after_m",
        "mean_error_loo_m", "angles_deg", "angles_sd_deg", "correlation", ...}}}``
        plus ``"joint"`` when ``joint``.
    cameras : dict
        Calibrated camera per group name (and ``"joint"``).
    """
    groups = group_labels(records, group_column)
    data = _records_data(records, surface, truth_prefix)
    all_idx = np.arange(len(records))
    labels = records.labels()
    g0 = data.locate(camera, all_idx)
    before = error_vectors(records, camera, g0, groups, truth_prefix)
    use = before.status == Status.OK
    outlier = np.zeros(len(records), bool)
    names = list(dict.fromkeys(groups))
    for g in names:
        m = groups == g
        s = group_summary(before, m, k_sigma)
        outlier[np.flatnonzero(m)[s["outliers"]]] = True
    if exclude_outliers:
        use &= ~outlier

    def do_fit(idx):
        return _fit(data, camera, idx, model, fit_focal, fit_pp)

    n_par = len(_param_names(model, fit_focal, fit_pp))
    fits, cameras = {}, {}
    if joint:
        jf = do_fit(all_idx[use])
        for g in names:
            fits[g] = jf
        cameras["joint"] = jf.camera
    else:
        for g in names:
            idx = all_idx[(groups == g) & use]
            if 2 * idx.size <= n_par:
                raise ValueError(f"group {g!r}: {idx.size} usable record(s) cannot determine "
                                 f"{n_par} parameters")
            fits[g] = do_fit(idx)
            cameras[g] = fits[g].camera

    # after: every record measured with its group's calibrated camera
    after = {k: np.full(len(records), np.nan) for k in ("east_m", "north_m")}
    after_ev = {}
    for g in names:
        m = groups == g
        idx = all_idx[m]
        cam = fits[g].camera
        ev = error_vectors(_sub_records(records, idx), cam, data.locate(cam, idx), groups[idx], truth_prefix)
        after_ev[g] = ev
        after["east_m"][idx], after["north_m"][idx] = ev.east_m, ev.north_m

    loo_en = np.full((len(records), 2), np.nan)
    loo_d = np.full(len(records), np.nan)
    if loo:
        for g in names:
            for k in all_idx[groups == g]:
                train = all_idx[use] if joint else all_idx[(groups == g) & use]
                train = train[train != k]
                f = do_fit(train)
                gk = data.locate(f.camera, np.array([k]))
                if gk.status[0] == Status.OK:
                    loo_en[k] = data.east_north(gk, np.array([k]))[0]
                    loo_d[k] = horizontal_distance_m(gk.lat_deg[0], gk.lon_deg[0],
                                                     np.rad2deg(data.ref_lat[k]), np.rad2deg(data.ref_lon[k]))

    report = {"model": model, "joint": joint, "fit_focal": fit_focal, "fit_principal_point": fit_pp,
              "outlier_rule": f"distance from the flight's median error vector > {k_sigma} robust sigma "
                              "(sigma = median distance / sqrt(2 ln 2), floor 0.5 m)",
              "groups": {}}
    for g in names:
        m = groups == g
        idx = all_idx[m]
        ev = after_ev[g]
        fit = fits[g]
        entry = {
            "n": int(m.sum()),
            "n_used_in_fit": int(np.isin(fit.idx, idx).sum()),
            "mean_error_before_m": _round(np.nanmean(before.distance_m[m])),
            "mean_error_after_m": _round(np.nanmean(ev.distance_m)),
            "mean_error_loo_m": _round(np.nanmean(loo_d[m])) if loo else None,
            **{k: (v if not isinstance(v, float) else _round(v, 6)) for k, v in fit.report().items()},
            "before": {k: (_round(v) if isinstance(v, float) else v)
                       for k, v in group_summary(before, m, k_sigma).items()},
            "after": {k: (_round(v) if isinstance(v, float) else v)
                      for k, v in group_summary(ev, np.ones(idx.size, bool), k_sigma).items()},
            "records": [],
        }
        for j, k in enumerate(idx):
            rec = {"label": labels[k], "line": int(records.lines[k]),
                   "outlier_before": bool(outlier[k]),
                   "before": before.as_dict(k), "after": ev.as_dict(j)}
            if loo:
                rec["loo"] = {"east_m": _round(loo_en[k, 0], 4), "north_m": _round(loo_en[k, 1], 4),
                              "distance_m": _round(loo_d[k], 4)}
            entry["records"].append(rec)
        report["groups"][g] = entry
    if joint:
        report["joint_fit"] = {k: (v if not isinstance(v, float) else _round(v, 6))
                               for k, v in fits[names[0]].report().items()}
        report["joint_fit"]["n"] = int(fits[names[0]].idx.size)
    return report, cameras


def _sub_records(records: Records, idx) -> Records:
    """A Records view of some rows (same header, angle columns and datums)."""
    return records.subset(idx)


def error_vector_panels(report: dict, records: Records, exaggeration: float = 1.0,
                        truth_prefix: str = "truth") -> list:
    """Panels for :func:`geoloc.analysis.errors.plot_error_vectors` from a :func:`calibrate_groups` report.

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
            return [np.nan if r.get(stage, {}).get(c) is None else r[stage][c] for r in e["records"]]

        vectors = [(f"before (mean {e['mean_error_before_m']:.1f} m)", comp("before", "east_m"),
                    comp("before", "north_m"), "tab:red"),
                   (f"after (mean {e['mean_error_after_m']:.1f} m)", comp("after", "east_m"),
                    comp("after", "north_m"), "tab:blue")]
        if e.get("mean_error_loo_m") is not None:
            vectors.append((f"leave-one-out (mean {e['mean_error_loo_m']:.1f} m)", comp("loo", "east_m"),
                            comp("loo", "north_m"), "tab:green"))
        panels.append({"name": f"flight {g}", "east_m": p[:, 0], "north_m": p[:, 1], "vectors": vectors,
                       "exaggeration": exaggeration, "labels": [r["label"] for r in e["records"]]})
    return panels
