"""Heights and conventions audited from the data: which convention fault a flight's metadata has.

A flight's metadata can disagree with itself in ways that follow a convention mix-up,
not noise: heights above mean sea level read as ellipsoidal (or the reverse), the geoid
applied with the wrong sign (about -2N), a height above the take-off point read as an
absolute one, frame centres an encoder computed on a flat earth at 0 m, a time offset
between the pose and the reported centres, a boresight bias. Each has a signature in
three comparisons that only need the flight itself, a DEM and the geoid:

* the platform's height against the terrain below it (DEM + EGM96 N);
* the reported frame centre's elevation against the DEM there;
* the frame centre recomputed from the angles (``sensor.line_of_sight`` then
  ``surface.intersect``) against the reported one.

The third is turned into numbers per record: the height at which the recomputed line of
sight passes over the reported centre (two intersections with surfaces of constant
geodetic height, interpolated along the ray's straight ground track), hence the platform
height offset ``dh = h_over - DEM(reported)`` (a platform read ``dh`` too high sees the
reported point ``dh`` above the terrain); the reported centre's pixel
(``sensor.ground_to_pixel``), hence a boresight offset; the recomputed centre of record
``k + s`` against the reported one of record ``k``, hence a shift in records. Each
signature's candidate correction is then applied and the centres located again through
``surface.intersect``: a fault is named when its correction cuts the median misfit by
:data:`MODEL_GAIN` and its estimated offset matches the signature (within the stated
uncertainty). The offset's uncertainty is the spread of the per-record offsets
(:func:`median_uncertainty`).

Heights are ellipsoidal (WGS 84) throughout unless a name says ``msl``; ``dh`` is the
height as read minus the height the data imply (so MSL read as ellipsoidal is ``-N``).
Conventions: ``docs/conventions.md``; the page: ``docs/height_audit.md``.

Layer 6 (``analysis``): reads surfaces, sensors and records; no workflow, no viewer.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.analysis.accuracy import MAD_SCALE
from geoloc.geodesy.geodesic import forward_azimuth_deg, horizontal_distance_m
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.geodesy.local import geodetic_to_enu
from geoloc.status import Status
from geoloc.frames.chain import Pose
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.height import HeightSurface
from geoloc.pipeline import Pipeline
from geoloc.sensors.budget import DEM_PRODUCTS, LE90_PER_SIGMA

if TYPE_CHECKING:
    from geoloc.io.records import Records
    from geoloc.sensors.base import Sensor
    from geoloc.sensors.frame import FrameSensor
    from geoloc.surfaces.base import Surface

__all__ = [
    "Finding",
    "HeightAudit",
    "audit_flight",
    "audit_records",
    "audit_klv_columns",
    "median_uncertainty",
    "azimuth_convention_finding",
    "FAULTS",
]

#: The fault kinds the audit names, and what each means.
FAULTS = {
    "msl_read_as_ellipsoidal": "heights above mean sea level (EGM96) read as ellipsoidal: too low by N",
    "ellipsoidal_read_as_msl": "ellipsoidal heights read as mean sea level (N added again): off by +N",
    "geoid_wrong_sign": "the geoid applied with the wrong sign (h = H - N): off by -2N",
    "relative_height_read_as_absolute": "a height above the take-off point read as absolute: too low by the "
    "take-off terrain's height",
    "agl_read_as_absolute": "a height above the ground below read as absolute: too low by the terrain",
    "flat_earth_frame_centre": "frame centres computed on a flat earth at h = 0 m, not on the terrain",
    "time_offset": "the reported centres belong to other records: a constant time offset",
    "boresight_bias": "a constant angular offset between the reported and the recomputed centres",
    "height_offset": "an unexplained height offset: constant, and no datum convention's signature within its "
    "uncertainty",
    "azimuth_from_north": "the reported centres lie at the bearing of the sensor's relative azimuth (MISB tag 18) "
    "from true north: the platform heading (tag 5) left out",
}

#: A median misfit (reported vs recomputed centre) below this [m] is a clean flight: the
#: reported positions' own rounding (MISB ST 0601 tags 23-24: 4e-8 deg, 5 mm; [Q17]'s published
#: five decimals: 0.8 m) and the DEM solver's tolerance (1 m by default) stay under it.
ERROR_FLOOR_M = 2.0
#: A signature's correction must cut the median misfit by at least this factor to be named:
#: one that explains the data leaves the rounding and the DEM's noise; a wrong one (a height fault
#: corrected as a boresight) leaves most of the misfit (measured: 0.3 to 0.9 of it).
MODEL_GAIN = 3.0
#: A height offset smaller than this [m] is not named: a DEM's own vertical error (SRTM: about
#: 5 m RMS over gentle terrain, 16 m LE90) and the encoder's DEM differing from ours explain it.
HEIGHT_FLOOR_M = 5.0
#: Floor of a stated uncertainty [m]: the EGM96 grid's interpolation (0.15 m RMS where the 30'
#: grid stands in for the 15' one; assets/README.md) and the exact solver's height tolerance.
UNCERTAINTY_FLOOR_M = 0.5
#: A height signature matches when the estimate is within this many stated uncertainties of it.
MATCH_K = 3.0
#: Corrections leaving misfits within this factor of the best one are a tie (the flight's random
#: errors, not the fault, set what is left): measured on the EO turret orbit with its own 20 m
#: pointing noise, a height fault corrected as a height leaves 19.4 m, as a boresight 18.8 m.
TIE_FACTOR = 1.25
#: Which correction a tie goes to, after a height that matches a datum signature: the ones with a
#: fixed size first (a flat earth, a whole-record shift, the terrain), the free ones last.
PREFERENCE = ("flat", "shift", "agl", "boresight", "height")
#: The take-off terrain's own uncertainty as a signature [m, one standard deviation]: the DEM's
#: vertical error at one point, SRTM's specification (16 m LE90, sigma 9.73 m:
#: :data:`geoloc.sensors.budget.DEM_PRODUCTS`), the product of the bundled DEMs; a better DEM only
#: makes the match more tolerant than it need be. Not the terrain's spread under the whole flight
#: (hundreds of metres over hills): that would let any offset of the terrain's size match.
TAKEOFF_SIGMA_M = DEM_PRODUCTS["srtm"][0] / LE90_PER_SIGMA
#: The largest record shift tried for a time offset (either way).
MAX_SHIFT = 10
#: A ray whose ground track moves less than this [m per m of height] says little about heights
#: (off nadir by under 1.1 deg): its per-record height offset is left out.
MIN_TRACK_SLOPE = 0.02
#: The median of n values of spread sigma has a standard error of about 1.2533 sigma / sqrt(n)
#: (normal errors, large n): sqrt(pi / 2).
MEDIAN_SE = math.sqrt(math.pi / 2)


def median_uncertainty(values: ArrayLike) -> tuple:
    """``(median, uncertainty, n)`` of the finite ``values``: the uncertainty is three standard
    errors of the median, ``3 * 1.2533 * 1.4826 * MAD / sqrt(n)``, floored at
    :data:`UNCERTAINTY_FLOOR_M` (a 99.7 % bound for normal per-record scatter)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan, 0
    med = float(np.median(v))
    mad = float(np.median(np.abs(v - med)))
    u = 3.0 * MEDIAN_SE * MAD_SCALE * mad / math.sqrt(v.size)
    return med, max(u, UNCERTAINTY_FLOOR_M), int(v.size)


@dataclass(frozen=True)
class Finding:
    """One convention fault found in a flight, with its estimated size.

    Attributes
    ----------
    kind : str
        A key of :data:`FAULTS`.
    subject : str
        What is wrong: ``"platform height"``, ``"frame-centre height"``, ``"frame centres"``,
        ``"time"``, ``"pointing"``.
    offset, uncertainty : float
        The estimate and its stated uncertainty (``unit``); heights: as read minus as implied.
    unit : str
        ``"m"``, ``"records"`` or ``"mrad"``.
    expected : float
        The signature's own size (e.g. -N for MSL read as ellipsoidal); NaN when it has none.
    expected_text : str
        How ``expected`` is made (``"-N = +30.7 m"``).
    records : int
        The records the estimate rests on.
    misfit_before_m, misfit_after_m : float
        Median horizontal distance between reported and recomputed centres, before and after the
        signature's correction (NaN for the height checks that do not recompute).
    fix : str
        The option or change that removes it.
    detail : str
        What else the estimate rests on.
    frames : tuple of int
        The records (indices into the flight audited) that show the signature: those the estimate
        rests on; empty when not said.
    """

    kind: str
    subject: str
    offset: float
    uncertainty: float
    unit: str
    expected: float = math.nan
    expected_text: str = ""
    records: int = 0
    misfit_before_m: float = math.nan
    misfit_after_m: float = math.nan
    fix: str = ""
    detail: str = ""
    frames: tuple = ()

    def line(self) -> str:
        """One line: what, how big and how sure, what the signature says, the fix."""
        spec = ".2f" if self.unit in ("mrad", "deg") else ".1f"
        sure = f" +/- {format(self.uncertainty, spec)}" if math.isfinite(self.uncertainty) else ""
        text = (
            f"{self.subject}: {FAULTS[self.kind]}; estimated {format(self.offset, '+' + spec)}{sure} "
            f"{self.unit} over {self.records} records"
        )
        if self.expected_text:
            text += f" (signature {self.expected_text})"
        if self.detail:
            text += f"; {self.detail}"
        if np.isfinite(self.misfit_before_m) and np.isfinite(self.misfit_after_m):
            text += f"; median misfit {self.misfit_before_m:.1f} m -> {self.misfit_after_m:.1f} m with it corrected"
        if self.fix:
            text += f"; fix: {self.fix}"
        return text

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["frames"] = [int(k) for k in self.frames]
        d["meaning"] = FAULTS[self.kind]
        d["text"] = self.line()
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


@dataclass
class HeightAudit:
    """What the audit of one flight found.

    Attributes
    ----------
    source : str
    findings : list of Finding
        Empty for a flight whose heights and conventions agree with the DEM and the geoid.
    checks : dict
        The figures behind them (medians, uncertainties, counts; NaN where not measured).
    columns : dict
        Per-record arrays (``platform_agl_m``, ``fc_minus_dem_m``, ``misfit_m``,
        ``height_over_reported_m``, ``platform_dh_m``, ``reported_drow_px``, ``reported_dcol_px``).
    """

    source: str
    findings: list
    checks: dict
    columns: dict = field(default_factory=dict)

    def lines(self) -> list:
        """The audit as the replay prints it: a heading and one line per finding."""
        c = self.checks
        if c.get("no_dem"):
            head = (
                f"height audit ({self.source}): no DEM, so no height checked; the bearing check only "
                f"(each packet's rays on its own frame-centre height, ellipsoidal), {c.get('records', 0)} records"
            )
            if not self.findings:
                return [head + ": no convention fault found"]
            return [head + f": {len(self.findings)} finding(s)"] + [f"  {f.line()}" for f in self.findings]
        head = (
            f"height audit ({self.source}): platform {_f(c.get('platform_agl_median_m'))} m above the "
            f"terrain (median), reported centres {_f(c.get('fc_minus_dem_median_m'), '+.1f')} m from the DEM, "
            f"median misfit {_f(c.get('misfit_median_m'))} m over {c.get('records_compared', 0)} records, "
            f"EGM96 N {_f(c.get('geoid_n_m'), '+.1f')} m"
        )
        if "unexplained_best" in c:
            head += (
                f"; the misfit is none of the signatures (the best, {c['unexplained_best'] or 'none'}, leaves "
                f"{_f(c.get('unexplained_after_m'))} m): random errors, or a fault of no convention"
            )
        if not self.findings:
            return [head + ": no convention fault found"]
        return [head + f": {len(self.findings)} finding(s)"] + [f"  {f.line()}" for f in self.findings]

    def to_dict(self) -> dict:
        """The findings and checks as plain values (JSON), for the report and the viewer."""
        checks = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.checks.items()}
        return {"source": self.source, "findings": [f.to_dict() for f in self.findings], "checks": checks}

    def kinds(self) -> list:
        return [f.kind for f in self.findings]


def _f(v, spec=".1f") -> str:
    return "n/a" if v is None or not np.isfinite(v) else format(float(v), spec)


def _dist(lat_a, lon_a, lat_b, lon_b):
    """Horizontal geodesic distance [m] between points given in radians (NaN in, NaN out)."""
    return horizontal_distance_m(np.rad2deg(lat_a), np.rad2deg(lon_a), np.rad2deg(lat_b), np.rad2deg(lon_b))


def _hit(surface, los):
    """``(lat, lon, h)`` [rad, rad, m] of the hits through the location pipeline (no correction: the
    reported centres an encoder wrote are straight lines), NaN where the status is not OK."""
    g = Pipeline(None, surface).intersect(los)
    ok = np.asarray(g.status) == Status.OK
    return (np.where(ok, g.lat, np.nan), np.where(ok, g.lon, np.nan), np.where(ok, g.h, np.nan))


def _mad(v) -> float:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(np.median(np.abs(v - np.median(v)))) if v.size else math.nan


def _median(v) -> float:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


#: The fix of each platform-height fault for a records CSV (``--altitude-datum``, docs/columns.md).
RECORDS_FIXES = {
    "msl_read_as_ellipsoidal": '--altitude-datum egm96 (or datum = "egm96" in the column map)',
    "ellipsoidal_read_as_msl": '--altitude-datum ellipsoid (or datum = "ellipsoid" in the column map)',
    "geoid_wrong_sign": "the heights hold H - N: give the MSL heights H with --altitude-datum egm96, "
    "or add 2N to the column",
    "relative_height_read_as_absolute": "add the take-off point's ellipsoidal height to the height column "
    "(a relative altitude is no absolute height)",
    "agl_read_as_absolute": "add the terrain's ellipsoidal height to the height column (AGL is no absolute height)",
    "flat_earth_frame_centre": "the reported centres are not on the terrain: compare with the replay's "
    "(--dem), not with the encoder's",
    "frame_centre_msl_read_as_ellipsoidal": "the reported heights are MSL: add N (= the EGM96 undulation)",
    "time_offset": "align the records (the reported centres are shifted)",
    "boresight_bias": "calibrate the boresight (geoloc calibrate) or put it in the sensor file's [boresight]",
    "height_offset": "check the height column's datum and unit (docs/columns.md) and the DEM's (--dem-datum)",
}


def audit_flight(
    pose: Pose,
    sensor: Sensor,
    row: ArrayLike,
    col: ArrayLike,
    surface: Surface | None,
    reported_lat_deg: ArrayLike,
    reported_lon_deg: ArrayLike,
    reported_h_m: ArrayLike | None = None,
    *,
    group: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    fixes: dict[str, str] | None = None,
    source: str = "flight",
    reported_name: str = "reported centre",
) -> HeightAudit:
    """Audit one flight's heights and conventions against a DEM and the geoid.

    Parameters
    ----------
    pose : Pose
        The records' poses (n,), heights ellipsoidal as read.
    sensor : Sensor
        The sensor the records were located with.
    row, col : array_like (n,)
        The pixel of each reported centre (1-based; a frame centre is the image centre).
    surface : Surface
        A DEM surface (``surfaces.terrain.surface_for`` with a DEM, or a mosaic): the terrain.
    reported_lat_deg, reported_lon_deg : array_like (n,)
        The reported centres (a KLV packet's frame centre, a record's published or surveyed
        position); NaN where a record has none.
    reported_h_m : array_like (n,), optional
        Their heights, ellipsoidal as read (NaN where none).
    group : array_like (n,), optional
        A flight label per record: a time shift pairs records of one group only.
    time_s : array_like (n,), optional
        Time stamps [s]: a record shift is also said in seconds.
    fixes : dict, optional
        Fault kind -> the fix to print (default :data:`RECORDS_FIXES`).
    source, reported_name : str
        How the flight and its reported centres are named in the lines.

    Returns
    -------
    HeightAudit
        ValueError when ``surface`` has no DEM (the audit compares with the terrain).
    """
    terrain = terrain_of(surface)
    if terrain is None:
        raise ValueError(
            f"the height audit compares heights with the terrain: it needs a DEM (--dem); got {type(surface).__name__}"
        )
    assert surface is not None  # terrain_of(None) is None: refused above
    fixes = dict(RECORDS_FIXES, **(fixes or {}))
    row = np.atleast_1d(np.asarray(row, float))
    n = row.shape[0]
    col = np.broadcast_to(np.asarray(col, float), (n,))
    shape = (n,)
    lat_p = np.broadcast_to(np.asarray(pose.lat, float), shape)
    lon_p = np.broadcast_to(np.asarray(pose.lon, float), shape)
    h_p = np.broadcast_to(np.asarray(pose.h, float), shape)
    rlat = np.deg2rad(np.broadcast_to(np.asarray(reported_lat_deg, float), shape))
    rlon = np.deg2rad(np.broadcast_to(np.asarray(reported_lon_deg, float), shape))
    rep_h = np.full(shape, np.nan) if reported_h_m is None else np.broadcast_to(np.asarray(reported_h_m, float), shape)

    # ---- platform against the terrain below; the geoid at both ends
    n_p = _where_finite(egm96_undulation, lat_p, lon_p)
    ground_p = _where_finite(terrain.height, lat_p, lon_p)
    agl = h_p - ground_p
    n_r = _where_finite(egm96_undulation, rlat, rlon)
    dem_r = _where_finite(terrain.height, rlat, rlon)
    fc_dem = rep_h - dem_r
    nbar = _median(n_p)

    # ---- recomputed centres on the DEM, and the misfit
    los = sensor.line_of_sight(row, col, pose, outside="extrapolate")
    lat_c, lon_c, h_c = _hit(surface, los)
    misfit = _dist(rlat, rlon, lat_c, lon_c)
    raw = _median(misfit)

    # ---- the height at which each ray passes over its reported centre
    h_over = _height_over_reported(los, rlat, rlon, dem_r, h_p)
    dh = h_over - dem_r  # platform height as read minus as the reported centres imply

    checks, columns = _figures(ground_p, agl, n_p, fc_dem, misfit, h_over, dh)
    findings = []

    # ---- the reported centres' own heights against the DEM
    findings += _frame_centre_height(rep_h, dem_r, fc_dem, n_r, fixes, reported_name, checks)

    # ---- the misfit: each signature's correction, located again
    if np.isfinite(raw) and raw > ERROR_FLOOR_M:
        fit = _misfit_models(
            pose, h_p, sensor, row, col, surface, los, rlat, rlon, rep_h, dem_r, dh, ground_p, lat_c, lon_c, raw, group
        )
        columns.update(reported_drow_px=fit.drow, reported_dcol_px=fit.dcol)
        models = fit.models
        checks.update({f"misfit_after_{k}_m": v for k, v in models.items()})
        height_named = (
            "height" in models
            and _height_finding(
                fit.d_hat, fit.u_hat, fit.n_dh, nbar, checks["takeoff_terrain_m"], raw, models["height"], fixes
            ).kind
            != "height_offset"
        )
        best = _pick_correction(models, raw, height_named)
        if best is not None:
            findings.append(
                _model_finding(
                    best,
                    fit,
                    raw,
                    nbar,
                    checks["takeoff_terrain_m"],
                    ground_p,
                    h_over,
                    dem_r,
                    sensor,
                    pose,
                    row,
                    col,
                    time_s,
                    fixes,
                    reported_name,
                )
            )
        else:  # random pointing errors, or a fault of no convention: said in the heading, not a finding
            least = min(models, key=models.__getitem__) if models else None
            checks["unexplained_best"] = least or ""
            checks["unexplained_after_m"] = models[least] if least else math.nan
    elif checks["platform_below_terrain"] > n // 2 and _median(agl) < -HEIGHT_FLOOR_M:
        # no reported centres to fit: the platform under the terrain is all the data say
        findings.append(_below_terrain_finding(agl, checks["takeoff_terrain_m"], fixes))
    findings = _with_frames(_one_flat_earth(findings), columns)
    return HeightAudit(source, findings, checks, columns)


def _where_finite(f: Callable[[np.ndarray, np.ndarray], ArrayLike], lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """``f(lat, lon)`` where both are finite, NaN elsewhere (a grid's reader takes no NaN)."""
    out = np.full(np.shape(lat), np.nan)
    ok = np.isfinite(lat) & np.isfinite(lon)
    out[ok] = f(lat[ok], lon[ok])
    return out


def _figures(
    ground_p: np.ndarray,
    agl: np.ndarray,
    n_p: np.ndarray,
    fc_dem: np.ndarray,
    misfit: np.ndarray,
    h_over: np.ndarray,
    dh: np.ndarray,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The audit's figures (a JSON object's values; the findings add theirs) and its per-record
    columns, from the per-record terrain below the platform, height above it, geoid, reported
    height above the DEM, misfit, height over the reported centre and platform height offset."""
    raw = _median(misfit)
    checks: dict[str, Any] = {
        "records": int(len(misfit)),
        "records_compared": int(np.isfinite(misfit).sum()),
        "geoid_n_m": _median(n_p),
        "platform_agl_median_m": _median(agl),
        "platform_below_terrain": int(np.sum(agl < 0)),
        "fc_minus_dem_median_m": _median(fc_dem),
        "misfit_median_m": raw,
        "height_over_reported_median_m": _median(h_over),
        "platform_dh_median_m": _median(dh),
        "takeoff_terrain_m": float(ground_p[np.flatnonzero(np.isfinite(ground_p))[0]])
        if np.isfinite(ground_p).any()
        else math.nan,
    }
    columns = {
        "platform_terrain_m": ground_p,
        "platform_agl_m": agl,
        "geoid_n_m": n_p,
        "fc_minus_dem_m": fc_dem,
        "misfit_m": misfit,
        "height_over_reported_m": h_over,
        "platform_dh_m": dh,
    }
    return checks, columns


def _pick_correction(models: Mapping[str, float], raw: float, height_named: bool) -> str | None:
    """The correction that explains the misfit: the name in ``models`` (correction -> median misfit
    after it [m]) whose misfit is at least :data:`MODEL_GAIN` times below ``raw``, the misfit before;
    None when none is. Corrections leaving about the same misfit (within :data:`TIE_FACTOR` of the
    least: the flight's random errors) are told apart by their estimate: a height that matches a
    datum signature (``height_named``) first, then :data:`PREFERENCE`'s order."""
    best = min(models, key=models.__getitem__) if models else None
    if best is None or models[best] * MODEL_GAIN > raw:
        return None
    near = [k for k in models if models[k] <= TIE_FACTOR * models[best] and models[k] * MODEL_GAIN <= raw]
    named = "height" in near and height_named
    return next(k for k in (("height",) if named else ()) + PREFERENCE if k in near)


def _below_terrain_finding(agl: np.ndarray, takeoff: float, fixes: Mapping[str, str]) -> Finding:
    """A relative height read as absolute, from the platform's heights above the terrain ``agl``
    alone (no reported centres to fit): the offset is a bound."""
    a_med, a_u, a_n = median_uncertainty(agl)
    return Finding(
        "relative_height_read_as_absolute",
        "platform height",
        a_med,
        a_u,
        "m",
        -takeoff,
        "the platform below the terrain",
        a_n,
        fix=fixes["relative_height_read_as_absolute"],
        detail="no reported centres: the offset is a bound (the height above the terrain as read)",
    )


def _with_frames(findings: list[Finding], columns: Mapping[str, np.ndarray]) -> list[Finding]:
    """Each finding without its records (``frames``) given the records its estimate rests on (the
    viewer lists them as frames): those with a finite value in the audit's column of its subject."""
    dh, agl, misfit = columns["platform_dh_m"], columns["platform_agl_m"], columns["misfit_m"]
    drow_c, dcol_c = columns.get("reported_drow_px"), columns.get("reported_dcol_px")
    rests_on = {
        "platform height": np.isfinite(dh) if np.isfinite(dh).any() else np.isfinite(agl),
        "frame-centre height": np.isfinite(columns["fc_minus_dem_m"]),
        "frame centres": np.isfinite(columns["height_over_reported_m"]),
        "pointing": (
            np.isfinite(drow_c) & np.isfinite(dcol_c)
            if drow_c is not None and dcol_c is not None
            else np.isfinite(misfit)
        ),
        "time": np.isfinite(misfit),
    }
    return [
        f if f.frames else dataclasses.replace(f, frames=tuple(int(k) for k in np.flatnonzero(rests_on[f.subject])))
        for f in findings
    ]


def _height_over_reported(
    los: Any, rlat: np.ndarray, rlon: np.ndarray, dem_r: np.ndarray, h_p: np.ndarray
) -> np.ndarray:
    """The height [m] at which each line of sight passes over its reported centre ``(rlat, rlon)``
    [rad]: the ray's ground track between its crossings of h = 0 and of the terrain there
    (``dem_r``; a segment of 50 m at least, below the platform height ``h_p``), the reported
    centre projected on it and the height taken linearly along it. NaN where the track moves
    less than :data:`MIN_TRACK_SLOPE` per metre of height (a ray near nadir says little of
    heights) or a crossing is missing."""
    h_a = np.zeros(np.shape(rlat))
    h_b = np.where(np.isfinite(dem_r), dem_r, 0.0)
    h_b = np.where(np.abs(h_b - h_a) < 50.0, h_a + 50.0, h_b)  # a segment of 50 m at least
    h_b = np.minimum(h_b, h_p - 1.0)  # below the platform, or the ray never gets there
    la, lo_a, _ = _hit(HeightSurface(h_a, "geodetic"), los)
    lb, lo_b, _ = _hit(HeightSurface(h_b, "geodetic"), los)
    ref = (np.where(np.isfinite(lb), lb, 0.0), np.where(np.isfinite(lo_b), lo_b, 0.0))
    A = geodetic_to_enu(la, lo_a, 0.0, ref[0], ref[1], 0.0)[..., :2]
    B = geodetic_to_enu(lb, lo_b, 0.0, ref[0], ref[1], 0.0)[..., :2]
    P = geodetic_to_enu(rlat, rlon, 0.0, ref[0], ref[1], 0.0)[..., :2]
    AB = B - A
    span = np.linalg.norm(AB, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.einsum("ni,ni->n", P - A, AB) / span**2
        slope = span / np.abs(h_b - h_a)
    return np.where(slope >= MIN_TRACK_SLOPE, h_a + s * (h_b - h_a), np.nan)


def _best_shift(
    rlat: np.ndarray, rlon: np.ndarray, lat_c: np.ndarray, lon_c: np.ndarray, raw: float, group: ArrayLike | None
) -> tuple[int, float]:
    """The record shift k (up to :data:`MAX_SHIFT` either way, at most a third of the records) that
    best pairs each reported centre ``(rlat, rlon)`` of record i with the recomputed centre
    ``(lat_c, lon_c)`` of record i + k, and its median misfit [m]; ``(0, raw)`` when none beats the
    unshifted median misfit ``raw``. Only records of one ``group`` are paired, and a shift must
    pair at least a third of the records (3 at least)."""
    n = len(rlat)
    best_s, best_m = 0, raw
    grp = None if group is None else np.asarray(group)
    for sh in range(-min(MAX_SHIFT, n // 3), min(MAX_SHIFT, n // 3) + 1):
        if sh == 0:
            continue
        k = np.arange(max(0, -sh), min(n, n - sh))
        same = np.ones(k.size, bool) if grp is None else grp[k] == grp[k + sh]
        if same.sum() < max(3, n // 3):
            continue
        m = _median(_dist(rlat[k[same]], rlon[k[same]], lat_c[k[same] + sh], lon_c[k[same] + sh]))
        if m < best_m:
            best_s, best_m = sh, m
    return best_s, best_m


@dataclass
class _Models:
    """Each fault signature's correction, located again: the median misfit [m] after it, by name,
    and what the findings quote (the height offset's median, uncertainty and count; the reported
    centres' pixel offsets; the best record shift and its misfit)."""

    models: dict[str, float]
    d_hat: float
    u_hat: float
    n_dh: int
    drow: np.ndarray
    dcol: np.ndarray
    best_s: int
    best_m: float


def _misfit_models(
    pose: Pose,
    h_p: np.ndarray,
    sensor: Sensor,
    row: np.ndarray,
    col: np.ndarray,
    surface: Surface,
    los: Any,
    rlat: np.ndarray,
    rlon: np.ndarray,
    rep_h: np.ndarray,
    dem_r: np.ndarray,
    dh: np.ndarray,
    ground_p: np.ndarray,
    lat_c: np.ndarray,
    lon_c: np.ndarray,
    raw: float,
    group: ArrayLike | None,
) -> _Models:
    """Each signature's correction applied and the centres located again on ``surface``: the
    platform height ``h_p`` less its median offset ``dh`` ("height"), the terrain below added back
    ("agl"), the centres on the ellipsoid at h = 0 ("flat"), the pixels moved by the reported
    centres' median pixel offset ("boresight"), the best record shift ("shift", only when one
    beats ``raw``)."""
    models: dict[str, float] = {}
    # platform height: the median offset taken off
    d_hat, u_hat, n_dh = median_uncertainty(dh)
    if np.isfinite(d_hat):
        p2 = dataclasses.replace(pose, h=h_p - d_hat)
        la2, lo2, _ = _hit(surface, sensor.line_of_sight(row, col, p2, outside="extrapolate"))
        models["height"] = _median(_dist(rlat, rlon, la2, lo2))
    # a height above the ground read as absolute: the terrain below added back
    if np.isfinite(ground_p).any():
        p3 = dataclasses.replace(pose, h=h_p + ground_p)
        la3, lo3, _ = _hit(surface, sensor.line_of_sight(row, col, p3, outside="extrapolate"))
        models["agl"] = _median(_dist(rlat, rlon, la3, lo3))
    # flat earth: the centres on the ellipsoid at h = 0
    la0, lo0, _ = _hit(HeightSurface(0.0, "geodetic"), los)
    models["flat"] = _median(_dist(rlat, rlon, la0, lo0))
    # boresight: the reported centres' pixels, their median offset applied
    h_rep_px = np.where(np.isfinite(rep_h), rep_h, dem_r)
    px = sensor.ground_to_pixel(rlat, rlon, h_rep_px, pose)
    drow, dcol = np.asarray(px.row, float) - row, np.asarray(px.col, float) - col
    dr_hat, dc_hat = _median(drow), _median(dcol)
    if np.isfinite(dr_hat) and np.isfinite(dc_hat):
        la4, lo4, _ = _hit(surface, sensor.line_of_sight(row + dr_hat, col + dc_hat, pose, outside="extrapolate"))
        models["boresight"] = _median(_dist(rlat, rlon, la4, lo4))
    # a shift of k records
    best_s, best_m = _best_shift(rlat, rlon, lat_c, lon_c, raw, group)
    if best_s:
        models["shift"] = best_m
    return _Models(models, d_hat, u_hat, n_dh, drow, dcol, best_s, best_m)


def _model_finding(
    best: str,
    fit: _Models,
    raw: float,
    nbar: float,
    takeoff: float,
    ground_p: np.ndarray,
    h_over: np.ndarray,
    dem_r: np.ndarray,
    sensor: Sensor,
    pose: Pose,
    row: np.ndarray,
    col: np.ndarray,
    time_s: ArrayLike | None,
    fixes: Mapping[str, str],
    reported_name: str,
) -> Finding:
    """The finding of the correction ``best`` (a key of ``fit.models``) that explains the misfit."""
    after = fit.models[best]
    if best == "height":
        return _height_finding(fit.d_hat, fit.u_hat, fit.n_dh, nbar, takeoff, raw, after, fixes)
    if best == "agl":
        g_med, _g_u, _g_n = median_uncertainty(-ground_p)
        return Finding(
            "agl_read_as_absolute",
            "platform height",
            fit.d_hat,
            fit.u_hat,
            "m",
            g_med,
            f"-terrain below = {g_med:+.1f} m (median)",
            fit.n_dh,
            raw,
            after,
            fixes["agl_read_as_absolute"],
        )
    if best == "flat":
        hm, hu, hn = median_uncertainty(h_over)
        return Finding(
            "flat_earth_frame_centre",
            "frame centres",
            hm,
            hu,
            "m",
            0.0,
            "the rays meet the reported centres at h ~ 0 m",
            hn,
            raw,
            after,
            fixes["flat_earth_frame_centre"],
            detail=f"terrain there {_median(dem_r):.0f} m (DEM, median)",
        )
    if best == "boresight":
        return _boresight_finding(sensor, pose, row, col, fit.drow, fit.dcol, raw, after, fixes)
    if best != "shift":
        raise ValueError(f"correction {best!r}: not one of {PREFERENCE}")
    dt = ""
    if time_s is not None:
        step = _median(np.diff(np.asarray(time_s, float)))
        if np.isfinite(step):
            dt = f"{fit.best_s * step:+.2f} s at {step:g} s per record"
    return Finding(
        "time_offset",
        "time",
        float(fit.best_s),
        0.5,
        "records",
        math.nan,
        "",
        len(row),
        raw,
        fit.best_m,
        fixes["time_offset"],
        detail=(
            f"the {reported_name} of record k is the recomputed centre "
            f"of record k {fit.best_s:+d}" + (f" ({dt})" if dt else "")
        ),
    )


def _one_flat_earth(findings: list[Finding]) -> list[Finding]:
    """One fault, one line: a flat earth seen in the reported heights and in the recomputation is
    one finding (the second, with the first's detail added)."""
    findings = list(findings)
    flat = [f for f in findings if f.kind == "flat_earth_frame_centre"]
    if len(flat) == 2:
        findings.remove(flat[0])
        findings[findings.index(flat[1])] = dataclasses.replace(flat[1], detail=f"{flat[1].detail}; {flat[0].detail}")
    return findings


def _height_signatures(nbar, takeoff):
    """``[(kind, expected dh, text)]`` of the platform-height signatures."""
    return [
        ("msl_read_as_ellipsoidal", -nbar, f"-N = {-nbar:+.1f} m"),
        ("ellipsoidal_read_as_msl", nbar, f"+N = {nbar:+.1f} m"),
        ("geoid_wrong_sign", -2 * nbar, f"-2N = {-2 * nbar:+.1f} m"),
        ("relative_height_read_as_absolute", -takeoff, f"-take-off terrain = {-takeoff:+.1f} m"),
    ]


def _height_finding(d_hat, u_hat, n_dh, nbar, takeoff, raw, after, fixes) -> Finding:
    """The platform-height finding: the closest signature within its uncertainty, else a plain offset.

    A signature ``e`` matches the estimate ``d_hat`` when ``|d_hat - e| <= hypot(u_hat, u_e)``: both
    are 99.7 % bounds (:data:`MATCH_K` standard deviations) of independent errors, so their standard
    deviations add in quadrature and so do the bounds. ``u_hat`` is the estimate's
    (:func:`median_uncertainty`); ``u_e`` the signature's own: for N (and 2N) the geoid grid's
    :data:`UNCERTAINTY_FLOOR_M`, for the take-off terrain :data:`MATCH_K` x :data:`TAKEOFF_SIGMA_M`
    (the DEM's vertical error at one point). An estimate no signature matches is a
    ``height_offset`` of its own size: no convention named, none of their fixes printed."""
    u_n = UNCERTAINTY_FLOOR_M  # N along a flight varies by decimetres: the grid's floor covers it
    u_t = MATCH_K * TAKEOFF_SIGMA_M
    best, nearest = None, None
    for kind, e, text in _height_signatures(nbar, takeoff):
        if not np.isfinite(e):
            continue
        u_e = u_t if kind == "relative_height_read_as_absolute" else u_n
        tol = math.hypot(u_hat, u_e)
        dist = abs(d_hat - e)
        if nearest is None or dist < nearest[3]:
            nearest = (kind, e, text, dist, tol)
        if dist <= tol and (best is None or dist < best[3]):
            best = (kind, e, text, dist)
    if best is None or abs(d_hat) < HEIGHT_FLOOR_M:
        why = f"N = {nbar:+.1f} m, take-off terrain {takeoff:.1f} m: none of their signatures explains it"
        if nearest is not None:
            kind, e, _, dist, tol = nearest
            why += (
                f" (the nearest, {kind} at {e:+.1f} m, is {dist:.1f} m away; it would match within "
                f"{tol:.1f} m, the estimate's and the signature's uncertainties in quadrature)"
            )
        return Finding(
            "height_offset",
            "platform height",
            d_hat,
            u_hat,
            "m",
            math.nan,
            "",
            n_dh,
            raw,
            after,
            fixes["height_offset"],
            detail=why,
        )
    kind, e, text, _ = best
    return Finding(kind, "platform height", d_hat, u_hat, "m", e, text, n_dh, raw, after, fixes[kind])


def _frame_centre_height(rep_h, dem_r, fc_dem, n_r, fixes, reported_name, checks) -> list:
    """Findings from the reported centres' own heights against the DEM under them."""
    d, u, m = median_uncertainty(fc_dem)
    checks.update(fc_minus_dem_uncertainty_m=u, fc_compared=m)
    if m == 0 or not np.isfinite(d) or abs(d) <= max(u, HEIGHT_FLOOR_M):
        return []
    nbar = _median(n_r)
    h_med, h_u, _ = median_uncertainty(rep_h)
    terrain = _median(dem_r)
    # a flat earth: the heights themselves ~0 (ellipsoidal, or MSL 0 made ellipsoidal: N) over real terrain
    for zero, text in ((0.0, "h = 0 m"), (nbar, f"MSL 0 m (h = N = {nbar:+.1f} m)")):
        if abs(h_med - zero) <= max(h_u, UNCERTAINTY_FLOOR_M) and abs(terrain - zero) >= HEIGHT_FLOOR_M:
            return [
                Finding(
                    "flat_earth_frame_centre",
                    "frame-centre height",
                    d,
                    u,
                    "m",
                    zero - terrain,
                    f"reported heights {text} over terrain {terrain:.0f} m",
                    m,
                    fix=fixes["flat_earth_frame_centre"],
                    detail=f"{reported_name} heights median {h_med:.1f} m",
                )
            ]
    sigs = [
        ("msl_read_as_ellipsoidal", -nbar, f"-N = {-nbar:+.1f} m"),
        ("ellipsoidal_read_as_msl", nbar, f"+N = {nbar:+.1f} m"),
        ("geoid_wrong_sign", -2 * nbar, f"-2N = {-2 * nbar:+.1f} m"),
    ]
    fits = [
        (abs(d - e), k, e, t)
        for k, e, t in sigs
        if abs(d - e) <= MATCH_K * math.hypot(u, UNCERTAINTY_FLOOR_M) / 3.0 or abs(d - e) <= u
    ]
    if fits:
        _, kind, e, text = min(fits)
        fix = (
            fixes["frame_centre_msl_read_as_ellipsoidal"]
            if kind == "msl_read_as_ellipsoidal"
            else f"the {reported_name} heights: {FAULTS[kind]}"
        )
        return [Finding(kind, "frame-centre height", d, u, "m", e, text, m, fix=fix)]
    return [
        Finding(
            "height_offset",
            "frame-centre height",
            d,
            u,
            "m",
            math.nan,
            "",
            m,
            detail=f"{reported_name} heights minus the DEM's, N = {nbar:+.1f} m there: a DEM in another "
            "datum (--dem-datum), or the encoder's DEM not this one",
        )
    ]


def _boresight_finding(sensor, pose, row, col, drow, dcol, raw, after, fixes) -> Finding:
    """The boresight finding: the median pixel offset turned into angles through the sensor's rays."""
    dr, ur, nr = median_uncertainty(drow)
    dc, uc, _ = median_uncertainty(dcol)
    k = int(np.flatnonzero(np.isfinite(drow) & np.isfinite(dcol))[0])
    p = pose.take(k) if hasattr(pose, "take") else pose

    def angle(r, c):
        a = np.asarray(sensor.line_of_sight(row[k], col[k], p, outside="extrapolate").direction_ecef, float).reshape(3)
        b = np.asarray(
            sensor.line_of_sight(row[k] + r, col[k] + c, p, outside="extrapolate").direction_ecef, float
        ).reshape(3)
        return float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))

    a_row = math.copysign(angle(dr, 0.0), dr) * 1e3
    a_col = math.copysign(angle(0.0, dc), dc) * 1e3
    total = angle(dr, dc) * 1e3
    per_px = angle(1.0, 0.0) * 1e3  # mrad per pixel: the pixel uncertainty in angle
    # floor: half a pixel, the rounding of a recorded pixel (median_uncertainty's floor is in metres)
    u = max(3.0 * MEDIAN_SE * MAD_SCALE * math.hypot(_mad(drow), _mad(dcol)) / math.sqrt(max(nr, 1)), 0.5) * per_px
    return Finding(
        "boresight_bias",
        "pointing",
        total,
        u,
        "mrad",
        math.nan,
        "",
        nr,
        raw,
        after,
        fixes["boresight_bias"],
        detail=f"the reported centres sit {dr:+.1f} px in rows ({a_row:+.2f} mrad) and {dc:+.1f} px in "
        f"columns ({a_col:+.2f} mrad) from the recomputed ones",
    )


def audit_records(
    records: Records, sensor: Sensor, surface: Surface | None, *, group_column: str = "table"
) -> HeightAudit:
    """Audit a records CSV (:class:`geoloc.io.records.Records`): the reported centres are the
    published positions (``paper_lat_deg``, ``paper_lon_deg``, ``paper_height_m``), else the
    surveyed ones (``truth_*``)."""
    ref = "paper" if records.has("paper_lat_deg") and records.has("paper_lon_deg") else "truth"
    name = {"paper": "published position", "truth": "surveyed position"}[ref]
    hcol = "paper_height_m" if ref == "paper" else "truth_h_m"
    if not (records.has(f"{ref}_lat_deg") and records.has(f"{ref}_lon_deg")):
        nan = np.full(len(records), np.nan)
        lat_r = lon_r = nan
        h_r: np.ndarray | None = nan
    else:
        lat_r, lon_r = records.column(f"{ref}_lat_deg"), records.column(f"{ref}_lon_deg")
        h_r = records.column(hcol) if records.has(hcol) else None
    group = records.text(group_column) if group_column in records.header else None
    time_s = records.column("time_s") if records.has("time_s") else None
    return audit_flight(
        records.pose(),
        sensor,
        records.column("row"),
        records.column("col"),
        surface,
        lat_r,
        lon_r,
        h_r,
        group=group,
        time_s=time_s,
        source=str(records.path),
        reported_name=name,
    )


#: The fixes of a KLV stream's faults: its datums are the standard's, the encoder is what is wrong.
KLV_FIXES = {
    "msl_read_as_ellipsoidal": "the encoder writes MSL into tag 75 (HAE): fix the encoder; meanwhile drop tag 75 "
    "so tag 15 + N is used (geoloc klv-fix)",
    "ellipsoidal_read_as_msl": "the encoder writes HAE into tag 15 (MSL): fix the encoder",
    "geoid_wrong_sign": "the encoder converts with h = H - N: fix the encoder's sign",
    "relative_height_read_as_absolute": "the encoder writes the height above take-off as tag 15/75: fix the encoder",
    "agl_read_as_absolute": "the encoder writes the height above ground as tag 15/75: fix the encoder",
    "flat_earth_frame_centre": "the encoder's frame centres ignore the terrain (tags 23-25): trust the replay "
    "with --dem, not tags 23-25",
    "frame_centre_msl_read_as_ellipsoidal": "the encoder writes MSL into tag 78 (HAE): fix the encoder",
    "time_offset": "the frame centres lag or lead the pose: fix the encoder's timing",
    "boresight_bias": "the encoder's boresight differs from the sensor file's: calibrate (geoloc calibrate)",
    "height_offset": "check the encoder's height tags (15 MSL, 75 HAE) against the take-off and the DEM's "
    "datum (--dem-datum)",
    "azimuth_from_north": "the encoder leaves the platform heading out of its frame centres (tags 23-24): "
    "geoloc klv fix IN --out OUT rewrites them from heading + tag 18, as MISB ST 0601 has it (or, if tag 18 "
    "itself is a true azimuth, fix the encoder to write it relative to the heading)",
}


#: A reported centre nearer than this [m] to the point below the sensor says little about its
#: bearing (5 mm of position rounding is 0.006 deg at 50 m; the platform's pitch and roll turn a
#: near-nadir ray's bearing by tens of degrees): left out of the bearing check.
MIN_BEARING_RANGE_M = 50.0
#: The bearing check's per-record residuals are rounded at about this [deg]: tags 23-24's
#: 4e-8 / 8e-8 deg steps at 200 m or more from the sensor give under 0.01 deg of bearing, tag 18's
#: step is 8.4e-8 deg. The floor of its stated uncertainty.
BEARING_ROUNDING_DEG = 0.01
#: The two conventions are told apart only when they point this far apart [deg]: the heading is
#: this far from north (under it, a boresight or heading bias of a degree or two explains as much).
BEARING_FLOOR_DEG = 5.0
#: The tag-18-from-north signature matches when the bearings to the reported centres are within
#: this [deg] of tag 18 alone (in the median): an encoder that leaves the heading out but keeps the
#: platform's pitch and roll turns its bearings by up to about pitch x tan(depression), degrees.
BEARING_MATCH_DEG = 2.0


def _wrap_deg(a):
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def azimuth_convention_finding(columns: dict, fix: str | None = None) -> Finding | None:
    """The relative azimuth measured from north: the reported centres (tags 23-24) lie at the bearing
    of tag 18 (Sensor Relative Azimuth) from true north, not of heading + tag 18 as MISB ST 0601
    (tag 18: "relative to the platform's longitudinal axis") has it.

    Per record: the geodesic bearing from the sensor to the reported centre, ``b_rep``, against the
    bearing to the centre recomputed by the standard (the replay's ``lat_deg``, ``lon_deg``), ``b_std``,
    and against tag 18 alone. The finding is named when the bearings follow tag 18 alone (median
    residual within :data:`BEARING_MATCH_DEG`, and :data:`MODEL_GAIN` times smaller than the standard's)
    while the standard's points :data:`BEARING_FLOOR_DEG` or more away. Its offset is the median turn
    ``b_rep - b_std`` [deg]; the signature's size is ``tag 18 - b_std`` (about minus the heading);
    the uncertainty is the spread of ``b_rep - tag 18`` (:func:`median_uncertainty`'s rule, floored at
    :data:`BEARING_ROUNDING_DEG`). Needs no terrain: bearings hardly change with the surface the rays
    end on (the replay's without a DEM: each packet's own frame-centre height, on the ellipsoid).

    Parameters
    ----------
    columns : dict
        :attr:`geoloc.workflows.klv_replay.KlvReplay.columns`.
    fix : str, optional
        The fix to print (default :data:`KLV_FIXES`'s).

    Returns
    -------
    Finding or None
        ``frames`` are the rows (indices into ``columns``) whose bearing follows tag 18 alone.
    """
    c = columns
    f = lambda k: np.asarray(c[k], float)  # noqa: E731
    lat_s, lon_s = f("sensor_lat_deg"), f("sensor_lon_deg")
    rlat, rlon = f("reported_lat_deg"), f("reported_lon_deg")
    b_rep = forward_azimuth_deg(lat_s, lon_s, rlat, rlon)
    b_std = forward_azimuth_deg(lat_s, lon_s, f("lat_deg"), f("lon_deg"))
    far = horizontal_distance_m(lat_s, lon_s, rlat, rlon) >= MIN_BEARING_RANGE_M
    d_std = np.where(far, _wrap_deg(b_rep - b_std), np.nan)
    d_north = np.where(far, _wrap_deg(b_rep - f("sensor_relative_azimuth_deg")), np.nan)
    use = np.isfinite(d_std) & np.isfinite(d_north)
    if use.sum() < 3:
        return None
    m_north = float(np.median(np.abs(d_north[use])))
    m_std = float(np.median(np.abs(d_std[use])))
    if not (m_std >= BEARING_FLOOR_DEG and m_north <= BEARING_MATCH_DEG and m_north * MODEL_GAIN <= m_std):
        return None
    frames = np.flatnonzero(use & (np.abs(np.nan_to_num(d_north, nan=np.inf)) <= BEARING_MATCH_DEG))
    turn = _wrap_deg(np.median(d_std[frames]))
    expected = _wrap_deg(np.median(_wrap_deg(d_std[frames] - d_north[frames])))
    u = max(3.0 * MEDIAN_SE * MAD_SCALE * _mad(d_north[frames]) / math.sqrt(frames.size), BEARING_ROUNDING_DEG)
    heading = _median(f("platform_heading_deg")[frames])
    return Finding(
        "azimuth_from_north",
        "frame centres",
        float(turn),
        float(u),
        "deg",
        float(expected),
        f"tag 18 - (heading + tag 18) = about -heading = {expected:+.2f} deg",
        int(frames.size),
        fix=fix or KLV_FIXES["azimuth_from_north"],
        detail=(
            f"bearings to the reported centres minus tag 18 alone: median {_median(d_north[frames]):+.3f} deg; "
            f"minus heading + tag 18 (the standard): median |{m_std:.1f}| deg (heading median {heading:.1f} deg)"
        ),
        frames=tuple(int(k) for k in frames),
    )


def audit_klv_columns(
    columns: Mapping[str, ArrayLike], sensor: FrameSensor, surface: Surface | None, source: str = "KLV"
) -> HeightAudit:
    """Audit a KLV replay (:attr:`geoloc.workflows.klv_replay.KlvReplay.columns`, ``sensor``
    the replay's): the reported centres are tags 23-24 (and 78 / 25 + N), the pixel the image centre.

    Without a DEM (``surface`` None) only the bearing check runs
    (:func:`azimuth_convention_finding`: it needs no terrain); with one, the heights too
    (:func:`audit_flight`). A finding's ``frames`` are rows of ``columns``."""

    c = {k: np.asarray(v) for k, v in columns.items()}
    f = lambda k: np.asarray(c[k], float)  # noqa: E731
    az = azimuth_convention_finding(c)
    if surface is None or terrain_of(surface) is None:
        checks = {"records": int(len(c["status"])), "no_dem": 1}
        return HeightAudit(source, [az] if az is not None else [], checks)
    ok = np.asarray(c["status"]) != Status.INVALID_INPUT
    idx = np.flatnonzero(ok)
    pose = Pose.from_deg(
        f("sensor_lat_deg")[idx],
        f("sensor_lon_deg")[idx],
        f("sensor_h_m")[idx],
        f("platform_heading_deg")[idx],
        f("platform_pitch_deg")[idx],
        f("platform_roll_deg")[idx],
        angles_deg={
            "azimuth": f("sensor_relative_azimuth_deg")[idx],
            "elevation": f("sensor_relative_elevation_deg")[idx],
            "sensor_roll": np.nan_to_num(f("sensor_relative_roll_deg")[idx]),
        },
    )
    r0, c0 = sensor.center_pixel
    m = idx.size
    audit = audit_flight(
        pose,
        sensor,
        np.full(m, r0),
        np.full(m, c0),
        surface,
        f("reported_lat_deg")[idx],
        f("reported_lon_deg")[idx],
        f("reported_h_m")[idx],
        time_s=f("time_s")[idx],
        fixes=KLV_FIXES,
        source=source,
        reported_name="reported frame centre",
    )
    # rows of the replay, not of its located subset; a heading left out is a convention too
    audit.findings = [dataclasses.replace(x, frames=tuple(int(idx[k]) for k in x.frames)) for x in audit.findings]
    if az is not None:
        audit.findings.append(az)
    return audit
