"""A whole flight for the viewer: track, footprints, positions, residuals, outliers (no viser here).

:func:`build` takes a viewer :class:`geoloc_viz.model.Scenario` (its ``records``,
a list of ``(RecordInfo, Inputs)``) and computes, for every frame at once,

* the **track**: the optical centre of each frame (``FrameSensor.line_of_sight``'s origin);
* the **footprint**: the image outline (the four corner rays and ``edge_samples - 1``
  more points on each edge), draped on the DEM (:class:`geoloc.surfaces.terrain.DemSurface`,
  exact first hit) when the scenario has one, else on the surface of constant
  ellipsoidal height at each record's target height
  (:class:`geoloc.surfaces.height.HeightSurface`); both through
  :func:`geoloc.surfaces.terrain.surface_for`. A footprint ray that leaves the DEM
  falls back to the record's target height (so a footprint is never torn open:
  :class:`geoloc.surfaces.terrain.DemElseHeight`);
* the **frame centre** (the image centre's ray) and the **recomputed** position (the
  record's pixel: the image centre for a KLV packet, the surveyed target's pixel
  for a [Q17] record);
* the **reported** (MISB frame centre, or [Q17]'s published) and the **truth**
  (surveyed) positions when the records carry them;
* the **residual** of each frame: recomputed vs truth when the truth is known, else
  recomputed vs reported (its components north/east/up and along/across track from
  :func:`geoloc.analysis.accuracy.error_components`), the robust outlier flags
  (:func:`geoloc.analysis.accuracy.robust_outliers`, the KLV replay's own rule) and the frames
  sorted by residual;
* what a **run of outliers** looks like (:func:`diagnose`): the residuals of the run
  fitted by three one-parameter faults, each linearised through the same sensor and
  surface (a heading bias, a sensor-height offset, a timing offset between pose and
  image), so the panel can say "a burst of yaw bias of +2.5 deg".

Every line of sight of the flight is one batched ``line_of_sight`` call on one
:class:`geoloc.frames.chain.Pose` of arrays (one sample per frame) and one
``surface.intersect``; nothing loops over frames.

Positions are also given in a fixed local East-North-Up frame (:attr:`FlightModel.enu`,
:class:`geoloc.frames.enu.EnuFrame`, metres). Every height is ellipsoidal (WGS 84);
the records' heights are ellipsoidal too (``docs/records.md``, ``docs/klv.md``).
Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from geoloc.analysis import accuracy
from geoloc.frames.chain import Pose
from geoloc.frames.enu import EnuFrame
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.status import Status
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.terrain import surface_for

if TYPE_CHECKING:
    from geoloc.analysis.height_audit import HeightAudit

#: Points per image edge (its first corner included): 4 gives a ring of 16 points per footprint.
EDGE_SAMPLES = 4
#: Heights in this module and in :class:`FlightModel`.
H_DATUM = "ellipsoid (WGS 84)"

#: Finite-difference steps of the fault models (small enough to stay linear over a footprint,
#: large enough to sit far above float64 round-off of ECEF coordinates: 1e-9 relative is 6 mm).
HEADING_STEP_RAD = math.radians(0.5)
HEIGHT_STEP_M = 10.0
TIME_STEP_FRAMES = 1.0
#: A fault model explains a run when it leaves less than this fraction of the run's residual
#: norm unexplained (a pure one-parameter fault leaves only its linearisation error, a few %).
EXPLAINED_FRACTION = 0.35

#: What each fault kind looks like in the residuals (the panel prints it under each run).
WHAT_IT_LOOKS_LIKE = {
    "attitude": (
        "**attitude (yaw) bias burst**: for a run of frames the error turns about the aircraft: it "
        "lies across the line of sight (along the track when the turret looks sideways), its size is "
        "ground range x bias angle, and it stops as suddenly as it started. Look at the heading "
        "reference (magnetic vs true north, an INS realignment, a gimbal encoder slip)."
    ),
    "datum": (
        "**height in the wrong datum**: a run of frames shares one vertical offset of the sensor "
        "height, so the hits slide along the line of sight's ground track by dh / tan(depression); "
        "dh close to the geoid undulation N means a mean-sea-level altitude written where an "
        "ellipsoidal (HAE) one belongs, or the reverse."
    ),
    "timing": (
        "**timing offset between metadata and frames**: the pose belongs to another instant, so the "
        "error lies along the track and is proportional to the speed (speed x offset), plus the "
        "attitude change over the offset (a turn's, and the frame-to-frame attitude noise: the run's "
        "errors then scatter in size); the fitted offset is in frames (seconds at 1 Hz)."
    ),
    "unexplained": (
        "**not one of the three simple faults**: neither a heading bias, a height offset nor a timing "
        "offset explains this run; look at the frame's chain (mount, gimbal angles, lens) and its "
        "iterations."
    ),
    "convention": (
        "**a convention fault the audit names**: the heights and conventions audit found a fault of "
        "convention in every frame of this run (its section gives the size, how sure and the fix); the "
        "one-parameter fit (heading bias, height, timing) is shown after it as what that fit alone would "
        "guess, not the cause. A burst on top of a whole-flight convention can still be the fit's: see "
        "whether the run stands out from the other frames the finding covers."
    ),
}

#: Short names of the audit's findings (geoloc.analysis.height_audit.FAULTS) for a run's headline.
CONVENTION_NAMES = {
    "msl_read_as_ellipsoidal": "MSL heights read as ellipsoidal",
    "ellipsoidal_read_as_msl": "ellipsoidal heights read as MSL",
    "geoid_wrong_sign": "the geoid applied with the wrong sign",
    "relative_height_read_as_absolute": "a height above take-off read as absolute",
    "agl_read_as_absolute": "a height above ground read as absolute",
    "flat_earth_frame_centre": "frame centres on a flat earth",
    "time_offset": "the reported centres shifted in time",
    "boresight_bias": "a boresight bias",
    "height_offset": "an unexplained height offset",
    "azimuth_from_north": "frame centres measured from north (tag 18 without the heading)",
}


@dataclass
class FaultRun:
    """A run of consecutive outlier frames and the fault that explains it best.

    Attributes
    ----------
    first, last : int
        Frame indices (inclusive) into the model.
    kind : str
        ``"attitude"``, ``"datum"``, ``"timing"`` or ``"unexplained"`` (keys of :data:`WHAT_IT_LOOKS_LIKE`);
        ``"convention"`` when the audit has a finding over every frame of the run (:func:`name_runs_by_audit`).
    value : float
        The fitted parameter: heading bias [rad], sensor-height offset [m] or time offset
        [frames] (the recorded pose is the true one at frame i + value: negative = stale).
    unexplained : dict
        Kind -> fraction of the run's residual norm each model leaves unexplained.
    findings : tuple
        The audit's findings (:class:`geoloc.analysis.height_audit.Finding`) whose frames cover the run.
    fit_kind : str
        The one-parameter fit's kind when ``kind`` is ``"convention"`` (else ``kind`` itself).
    """

    first: int
    last: int
    kind: str
    value: float
    unexplained: dict
    labels: tuple = ()
    findings: tuple = ()
    fit_kind: str = ""

    def headline(self) -> str:
        """One line: frames, kind and the fitted size in its unit; the audit's finding first when
        it covers the run."""
        if self.findings:
            named = "; ".join(
                f"{CONVENTION_NAMES.get(x.kind, x.kind)} (the audit's finding: "
                f"{format(x.offset, '+.2f' if x.unit in ('mrad', 'deg') else '+.1f')}"
                + (
                    f" +/- {format(x.uncertainty, '.2f' if x.unit in ('mrad', 'deg') else '.1f')}"
                    if math.isfinite(x.uncertainty)
                    else ""
                )
                + f" {x.unit})"
                for x in self.findings
            )
            return f"{self.span()}: {named}; the one-parameter fit alone would say: {self.fit_text()}"
        return f"{self.span()}: {self.fit_text()}"

    def fit_text(self) -> str:
        """The one-parameter fit's fault and its fitted size in its unit."""
        return {
            "attitude": f"heading bias {math.degrees(self.value):+.2f} deg",
            "datum": f"sensor height off by {self.value:+.1f} m",
            "timing": (
                f"pose {abs(self.value):.2f} frame(s) stale (from an earlier instant than the image)"
                if self.value < 0
                else f"pose {self.value:.2f} frame(s) ahead of the image"
            ),
            "unexplained": "no simple fault fits",
        }[self.fit_kind or self.kind]

    def span(self) -> str:
        """The run's frames by the timeline's index, with the records' own labels beside them:
        ``frames 100 .. 109 (packet 100 .. packet 109, 10 frames)``."""
        n = self.last - self.first + 1
        if self.first == self.last:
            return f"frame {self.first}" + (f" ({self.labels[0]})" if self.labels else "")
        labels = f"{self.labels[0]} .. {self.labels[-1]}, " if self.labels else ""
        return f"frames {self.first} .. {self.last} ({labels}{n} frames)"


@dataclass
class FlightModel:
    """Every frame of a flight, as arrays (frame index first). Angles in radians, heights ellipsoidal.

    ``*_enu`` arrays are in :attr:`enu` (metres); lat/lon in degrees (the edge: the table and
    the panel show them); NaN where a ray failed (``status``) or a record has no such position.
    """

    labels: list
    enu: EnuFrame
    track_enu: np.ndarray  # (n, 3) optical centres
    footprint_enu: np.ndarray  # (n, P, 3) image outline, ring order (corner 1, edge, corner 2, ...)
    footprint_status: np.ndarray  # (n, P) Status of each outline ray (OK also for the height fallback)
    corners_enu: np.ndarray  # (n, 4, 3) rows 0.5/M+0.5, cols 0.5/N+0.5 (top-left, top-right, ...)
    corner_lat_deg: np.ndarray  # (n, 4)
    corner_lon_deg: np.ndarray
    corner_h_m: np.ndarray
    centre_enu: np.ndarray  # (n, 3) the image centre's hit
    recomputed_lat_deg: np.ndarray  # (n,) the record's pixel
    recomputed_lon_deg: np.ndarray
    recomputed_h_m: np.ndarray
    recomputed_enu: np.ndarray
    status: np.ndarray  # (n,) Status of the recomputed ray
    reported_lat_deg: np.ndarray
    reported_lon_deg: np.ndarray
    reported_h_m: np.ndarray
    reported_enu: np.ndarray
    truth_lat_deg: np.ndarray
    truth_lon_deg: np.ndarray
    truth_h_m: np.ndarray
    truth_enu: np.ndarray
    reference: str  # "truth" or "reported": what the residual is measured against
    residual_m: np.ndarray  # (n,) horizontal, recomputed vs reference
    components: dict  # error_components(recomputed, reference): north_m, east_m, up_m, along_m, ...
    outlier: np.ndarray  # (n,) bool, robust flags of residual_m
    order: np.ndarray  # frame indices by residual, largest first, NaN last
    track_heading_rad: np.ndarray  # (n,) direction of travel (from the track), for along/across
    speed_m_per_frame: np.ndarray  # (n,)
    surface: str
    faults: list = field(default_factory=list)  # FaultRun, see diagnose()
    #: (n,) bool, with the scenario's error budget: the residual lies outside its own predicted 99 %
    #: ellipse (geoloc.analysis.uncertainty.outside_ellipse); None without a budget
    outside_ellipse99: np.ndarray | None = None
    notes: list = field(default_factory=list)
    #: the flight's heights and conventions audited (geoloc.analysis.height_audit.HeightAudit; its
    #: findings' ``frames`` are frame indices); None when the records report no positions
    audit: HeightAudit | None = None
    #: how each frame's pixel was located, for labels: "exact first hit on the DEM" (the flight's own
    #: solver, which may differ from the current frame's in the viewer) or "the record's target height"
    located_by: str = "recomputed"
    H_DATUM: str = H_DATUM
    _report: object = None

    def __len__(self) -> int:
        return len(self.labels)

    def top(self, n: int = 10) -> np.ndarray:
        """The ``n`` frames of largest residual (indices), largest first."""
        return self.order[:n]

    def footprint_segments(self, every: int = 1) -> np.ndarray:
        """(n * P / every, 2, 3) line segments of every closed footprint outline, frame by frame,
        through every ``every``-th of its P outline points (the corners kept when ``every``
        divides :data:`EDGE_SAMPLES`)."""
        every = int(every)
        if every < 1 or self.footprint_enu.shape[1] % every:
            raise ValueError(f"every = {every}: must divide the {self.footprint_enu.shape[1]} outline points")
        fp = self.footprint_enu[:, ::every]
        return np.stack([fp, np.roll(fp, -1, axis=1)], axis=2).reshape(-1, 2, 3)

    def trail_frames(self, max_n: int) -> np.ndarray:
        """Frame indices whose footprints a whole-flight drawing shows: every k-th (at most ``max_n``)
        and every outlier, so hundreds of overlapping outlines thin to a readable trail."""
        n = len(self)
        k = max(int(np.ceil(n / max(int(max_n), 1))), 1)
        keep = np.zeros(n, bool)
        keep[::k] = True
        keep |= np.asarray(self.outlier, bool)
        return np.flatnonzero(keep)

    def track_segments(self) -> np.ndarray:
        """(n - 1, 2, 3) segments joining consecutive optical centres."""
        return np.stack([self.track_enu[:-1], self.track_enu[1:]], axis=1)

    def error_segments(self) -> np.ndarray:
        """(n, 2, 3) recomputed -> reference (truth or reported) per frame."""
        ref = self.truth_enu if self.reference == "truth" else self.reported_enu
        return np.stack([self.recomputed_enu, ref], axis=1)

    def report(self, pose=None):
        """The accuracy report of the flight (:func:`geoloc.analysis.accuracy.accuracy_report`):
        recomputed vs the reference (truth or reported), with the track, slant range and off-nadir
        angle from each frame's optical centre; one group per flight (the label's part before ``-``
        for [Q17] records, ``T3-1`` -> ``T3``; one group for a KLV file)."""
        if getattr(self, "_report", None) is not None:
            return self._report
        ref = (
            (self.truth_lat_deg, self.truth_lon_deg, self.truth_h_m)
            if self.reference == "truth"
            else (self.reported_lat_deg, self.reported_lon_deg, self.reported_h_m)
        )
        tlat, tlon, th = self.enu.to_geodetic(self.track_enu)
        sight = accuracy.sight_geometry(
            np.degrees(tlat),
            np.degrees(tlon),
            th,
            self.recomputed_lat_deg,
            self.recomputed_lon_deg,
            self.recomputed_h_m,
        )
        group = [lab.partition("-")[0] if "-" in lab else "flight" for lab in self.labels]
        ok = self.status == Status.OK
        nan = lambda a: np.where(ok, a, np.nan)
        self._report = accuracy.accuracy_report(
            nan(self.recomputed_lat_deg),
            nan(self.recomputed_lon_deg),
            nan(self.recomputed_h_m),
            *ref,
            track_heading_rad=self.track_heading_rad,
            slant_range_m=sight["slant_range_m"],
            off_nadir_rad=sight["off_nadir_rad"],
            group=group,
            meta={"reference": f"recomputed vs {self.reference}", "surface": self.surface},
        )
        return self._report

    def error_model(self):
        """The slant-range model of the horizontal error (``intercept_m + m_per_m * slant``) when it is
        meaningful, else ``(None, why)``: only against truth (against the reported positions it
        models an agreement, not an accuracy), from 5 frames or more, with a non-negative intercept
        and slope (a negative intercept is no error at short range: a line through scatter), and
        explaining the spread (rms of its residuals under 90 % of the errors' own spread)."""
        if self.reference != "truth":
            return None, "no truth in the records: no accuracy model"
        mdl = self.report().overall.get("slant_range_model") or {}
        n = int(mdl.get("n") or 0)
        b, a, rms = (float(mdl.get(k, math.nan)) for k in ("intercept_m", "m_per_m", "rms_residual_m"))
        h = self.residual_m[np.isfinite(self.residual_m)]
        if n < 5 or not np.isfinite(b) or not np.isfinite(a):
            return None, f"{n} frames: too few for an error model"
        if b < 0:
            return None, (
                f"the least-squares line in slant range has a negative intercept ({b:.1f} m + "
                f"{a * 1e3:.2f} m per km): a line through scatter, not an accuracy"
            )
        if a < 0:
            return None, f"the errors shrink with slant range ({a * 1e3:.2f} m per km): no range model"
        if len(h) > 1 and not rms < 0.9 * float(np.std(h)):
            return None, "slant range does not explain the spread of the errors"
        return mdl, ""

    def summary_markdown(self) -> str:
        """The accuracy panel: agreement with the reported positions, kept apart from accuracy against
        truth (CEP, CE90, LE90, bias; the slant-range model only when :meth:`error_model` finds it
        meaningful), the robust outliers and the report's warnings."""
        r = self.report()
        s = r.overall
        f = lambda v, spec=".2f": "n/a" if v is None or not np.isfinite(v) else format(v, spec)
        L = []
        if self.reference == "truth":
            L += [
                f"**accuracy against the surveyed truth** (recomputed vs truth, {s['n']} frames; heights {H_DATUM})  ",
                f"CEP {f(s['cep_m'], '.1f')} m, CE90 {f(s['ce90_m'], '.1f')} m, LE90 {f(s['le90_m'], '.1f')} m  ",
                f"mean abs. error: horizontal {f(s['mae_horizontal_m'], '.1f')} m, vertical "
                f"{f(s['mae_vertical_m'], '.1f')} m  ",
                (
                    f"bias: N {f(s['bias_north_m'], '.1f')}, E {f(s['bias_east_m'], '.1f')}, U "
                    f"{f(s['bias_up_m'], '.1f')}, along {f(s['bias_along_m'], '.1f')}, across "
                    f"{f(s['bias_across_m'], '.1f')} m  "
                ),
            ]
            mdl, why = self.error_model()
            L.append(
                f"error model: horizontal error = {mdl['intercept_m']:.1f} m + {mdl['m_per_m'] * 1e3:.2f} m "
                "per km of slant range  "
                if mdl is not None
                else f"error model: none ({why})  "
            )
            rep = agreement(
                self.recomputed_lat_deg, self.recomputed_lon_deg, self.reported_lat_deg, self.reported_lon_deg
            )
            if rep is not None:
                L.append(
                    f"agreement with the reported positions (not an accuracy): median {_length(rep[0])}, "
                    f"90 % within {_length(rep[1])}, largest {_length(rep[2])}  "
                )
        else:
            h = self.residual_m[np.isfinite(self.residual_m)]
            L.append(
                f"**agreement with the reported positions** (recomputed vs the positions the records "
                f"report, e.g. the MISB frame centre; {len(h)} frames)  "
            )
            if len(h):
                L.append(
                    f"median {_length(np.median(h))}, 90 % within {_length(np.percentile(h, 90))}, largest "
                    f"{_length(h.max())}; {int((h < 1.0).sum())} of {len(h)} frames within 1 m  "
                )
            L.append(
                "**accuracy: unknown**: the records carry no surveyed truth, so how far either position "
                "is from the ground truth cannot be said (no CEP, no error model)  "
            )
        L.append(f"robust outliers: {int(self.outlier.sum())} of {len(self)} frames (median / MAD rule)  ")
        if self.outside_ellipse99 is not None:
            L.append(
                f"outside their own predicted 99 % ellipse: {int(self.outside_ellipse99.sum())} of "
                f"{len(self)} frames (the sensor's error budget)  "
            )
        L += [f"**warning** {w}  " for w in r.warnings]
        return "\n".join(L)

    def fault_of(self, idx: int):
        """The :class:`FaultRun` containing frame ``idx``, or None."""
        for f in self.faults:
            if f.first <= idx <= f.last:
                return f
        return None

    def outlier_markdown(self, n: int = 12) -> str:
        """A markdown table of the ``n`` largest residuals (frame, residual, components, flag, fault)."""
        c = self.components
        ref = "truth" if self.reference == "truth" else "reported"
        lines = [
            f"frames by residual (recomputed vs {ref}, horizontal; along/across track; up)  ",
            "",
            "| # | frame (record) | residual m | along m | across m | up m | flag | looks like |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for rank, i in enumerate(self.top(n), 1):
            f = self.fault_of(int(i))
            lines.append(
                f"| {rank} | {i} ({self.labels[i]}) | {self.residual_m[i]:.1f} | {c['along_m'][i]:+.1f} | "
                f"{c['across_m'][i]:+.1f} | {c['up_m'][i]:+.1f} | {self._flag(i)} | "
                f"{f.kind if f is not None else ''} |"
            )
        return "\n".join(lines)

    def _flag(self, i) -> str:
        flags = ["**outlier**"] if self.outlier[i] else []
        if self.outside_ellipse99 is not None and self.outside_ellipse99[i]:
            flags.append("outside 99 %")
        return ", ".join(flags)

    def audit_markdown(self) -> str:
        """The heights and conventions audit: each finding with its estimated offset, how sure (its
        stated uncertainty, against the signature's own size), its frames and the one fix."""
        a = self.audit
        if a is None:
            return (
                "not audited: a live flight (replay its recording with --audit), or records that report "
                "no positions (frame centres, published points, surveyed truth) to check against"
            )
        c = a.checks
        if c.get("no_dem"):
            what = (
                "no DEM, so no height checked: the bearing check only (the rays on each record's own "
                "height, ellipsoidal, WGS 84)"
            )
        else:
            what = (
                f"platform {_num_text(c.get('platform_agl_median_m'))} m above the DEM (median), reported "
                f"positions {_num_text(c.get('fc_minus_dem_median_m'), '+.1f')} m from it, EGM96 N "
                f"{_num_text(c.get('geoid_n_m'), '+.1f')} m, median misfit "
                f"{_num_text(c.get('misfit_median_m'))} m over {c.get('records_compared', 0)} frames"
            )
        if not a.findings:
            return f"**no convention fault found**  \n{what}"
        out = [f"**{len(a.findings)} convention fault(s) found**  \n{what}"]
        for f in a.findings:
            spec = ".2f" if f.unit in ("mrad", "deg") else ".1f"
            sure = f" +/- {format(f.uncertainty, spec)}" if np.isfinite(f.uncertainty) else ""
            sig = f"; signature {f.expected_text}" if f.expected_text else ""
            out.append(
                f"- **{f.subject}**: {FAULT_TEXT.get(f.kind, f.kind)}  \n"
                f"  estimated **{format(f.offset, '+' + spec)}{sure} {f.unit}** (how sure: the stated "
                f"uncertainty, a 99.7 % bound{sig})  \n"
                f"  {self.frames_text(f.frames)}  \n"
                f"  fix: {f.fix}" + (f"  \n  {f.detail}" if f.detail else "")
            )
        return "\n".join(out)

    def frames_text(self, frames) -> str:
        """``frames 0 .. 4, 7 (packet 1 .. packet 8, 6 frames)``: runs of consecutive indices."""
        k = sorted(int(i) for i in frames)
        if not k:
            return "frames: not said"
        runs, start = [], k[0]
        for a, b in zip(k, k[1:] + [k[-1] + 2]):  # a sentinel past the last run
            if b != a + 1:
                runs.append(f"{start}" if start == a else f"{start} .. {a}")
                start = b
        word = "frame" if len(k) == 1 else "frames"
        return f"{word} {', '.join(runs)} ({self.labels[k[0]]} .. {self.labels[k[-1]]}, {len(k)} {word})"

    def faults_markdown(self) -> str:
        """Each run of outliers with its fitted fault and what that fault looks like."""
        if not self.faults:
            return "no run of outliers: every residual is within the robust cut"
        out = []
        for f in self.faults:
            out.append(f"- {f.headline()}  \n  {WHAT_IT_LOOKS_LIKE[f.kind]}")
        return "\n".join(out)


def _num_text(v, spec: str = ".1f") -> str:
    return "n/a" if v is None or not np.isfinite(v) else format(float(v), spec)


def _fault_text() -> dict:
    from geoloc.analysis.height_audit import FAULTS

    return FAULTS


#: What each convention fault of the audit means (geoloc.analysis.height_audit.FAULTS).
FAULT_TEXT = _fault_text()


def flight_audit(scn, pose, sensor, row, col, surface, reported, centre_deg, angles_deg):
    """The heights and conventions audit of a flight (:mod:`geoloc.analysis.height_audit`): with a DEM,
    :func:`~geoloc.analysis.height_audit.audit_flight` of the reported positions; with a sensor
    relative azimuth (a KLV flight), also the bearing check, which needs no DEM. None when no record
    reports a position. ``reported`` is ``(lat_deg, lon_deg, h_m)``, ``centre_deg`` the image centre's
    hit ``(lat_deg, lon_deg)``, ``angles_deg`` the records' ``heading`` and ``azimuth`` [deg]."""
    from geoloc.analysis.height_audit import (
        KLV_FIXES,
        HeightAudit,
        audit_flight,
        azimuth_convention_finding,
    )
    from geoloc.workflows.klv_replay import is_klv_path

    rep_lat, rep_lon, rep_h = reported
    n = len(rep_lat)
    if not (np.isfinite(rep_lat) & np.isfinite(rep_lon)).any():
        return None
    klv = is_klv_path(str(getattr(scn, "source", "") or ""))
    source = str(getattr(scn, "source", "") or "flight")
    if terrain_of(surface) is not None:
        audit = audit_flight(
            pose,
            sensor,
            row,
            col,
            surface,
            rep_lat,
            rep_lon,
            rep_h,
            fixes=KLV_FIXES if klv else None,
            source=source,
            reported_name="reported frame centre" if klv else "reported position",
        )
    else:
        audit = HeightAudit(source, [], {"records": n, "no_dem": 1})
    if angles_deg.get("azimuth") is not None:
        cols = {
            "sensor_lat_deg": np.degrees(np.broadcast_to(np.asarray(pose.lat, float), (n,))),
            "sensor_lon_deg": np.degrees(np.broadcast_to(np.asarray(pose.lon, float), (n,))),
            "reported_lat_deg": rep_lat,
            "reported_lon_deg": rep_lon,
            "lat_deg": centre_deg[0],
            "lon_deg": centre_deg[1],
            "sensor_relative_azimuth_deg": angles_deg["azimuth"],
            "platform_heading_deg": angles_deg["heading"],
        }
        az = azimuth_convention_finding(cols)
        if az is not None:
            audit.findings.append(az)
    return audit


def _length(v_m: float) -> str:
    """A length with its unit chosen so it never reads 0.00: mm under 1 m, m above."""
    if not np.isfinite(v_m):
        return "n/a"
    return f"{v_m * 1e3:.1f} mm" if abs(v_m) < 1.0 else f"{v_m:.1f} m"


def agreement(lat_deg, lon_deg, ref_lat_deg, ref_lon_deg):
    """(median, 90th percentile, largest) horizontal distance [m] between two sets of positions
    (geodesics on WGS 84), or None when no pair is finite."""
    from geoloc.geodesy.geodesic import horizontal_distance_m

    a = [np.asarray(x, float) for x in (lat_deg, lon_deg, ref_lat_deg, ref_lon_deg)]
    ok = np.all([np.isfinite(x) for x in a], axis=0)
    if not ok.any():
        return None
    d = np.asarray(horizontal_distance_m(*(x[ok] for x in a)), float)
    return float(np.median(d)), float(np.percentile(d, 90)), float(d.max())


# --------------------------------------------------------------------------- inputs as arrays


def records_pose(records) -> tuple:
    """(Pose of arrays, row, col, target_h) of a Scenario's ``[(RecordInfo, Inputs)]`` (one sample each)."""
    inps = [inp for _, inp in records]
    a = lambda k: np.array([float(getattr(i, k)) for i in inps])
    names = sorted({k for i in inps for k in i.angles_deg})
    angles = {k: np.array([float(i.angles_deg.get(k, 0.0)) for i in inps]) for k in names}
    pose = Pose.from_deg(
        a("lat_deg"),
        a("lon_deg"),
        a("h_m"),
        a("heading_deg"),
        a("pitch_deg"),
        a("roll_deg"),
        a("gimbal_roll_deg"),
        a("gimbal_pitch_deg"),
        angles_deg=angles,
    )
    return pose, a("row"), a("col"), a("target_h")


def outline_pixels(sensor, edge_samples: int = EDGE_SAMPLES, fov_deg=None):
    """Rows and columns of the image outline, ring order: top edge left to right, right edge down, ...

    The outline is the sensor's outer edge (rows 0.5 and M + 0.5, columns 0.5 and
    N + 0.5; ``docs/conventions.md``, "Pixels"). With ``fov_deg`` (n, 2) per-frame
    horizontal / vertical fields of view (a zooming KLV sensor) the outline of frame i
    is the pixels whose rays are those of ``lens_from_fov(hfov_i, vfov_i)``'s outline:
    column c0 +- fx tan(hfov_i / 2) on the sensor's own pinhole (exact for a pinhole;
    :mod:`geoloc.workflows.klv_replay`, "Varying fields of view").

    Returns
    -------
    rows, cols : ndarray (P,) or (P, n)
        P = 4 * edge_samples.
    """
    k = int(edge_samples)
    if k < 1:
        raise ValueError(f"edge_samples = {edge_samples}: must be >= 1")
    t = np.arange(k) / k  # 0 .. 1 (exclusive): the first corner and k - 1 points along the edge
    # unit square ring in (u = column fraction, v = row fraction), corners at 0/1
    u = np.concatenate([t, np.ones(k), 1 - t, np.zeros(k)])
    v = np.concatenate([np.zeros(k), t, np.ones(k), 1 - t])
    M, N = sensor.rows, sensor.cols
    if fov_deg is None:
        return 0.5 + v * M, 0.5 + u * N
    fov = np.radians(np.asarray(fov_deg, float))
    lens = sensor.lens
    r0, c0 = sensor.center_pixel
    half_c = lens.fx * np.tan(fov[:, 0] / 2)  # (n,) columns from the centre to the edge
    half_r = lens.fy * np.tan(fov[:, 1] / 2)
    return r0 + (2 * v[:, None] - 1) * half_r, c0 + (2 * u[:, None] - 1) * half_c


# --------------------------------------------------------------------------- the model


#: how a frame was located, by DEM solver, in labels (the panel's names, app.METHOD_NAMES, say the same)
_LOCATED_BY = {
    "exact": "exact first hit on the DEM",
    "bisect": "bisection [L23] on the DEM",
    "steps": "descending steps [Q17] on the DEM",
}


def _surface(scn, target_h, method):
    """The footprint's surface: the DEM, else (off the DEM, or no data) each record's target height."""
    dem = scn.dem if getattr(scn, "use_dem", True) else None
    return surface_for(target_h, dem, method=method, else_height=True)


def _hit(surface, los, corrections: Corrections = NO_CORRECTIONS):
    """The batch's hits: (lat, lon, h, ECEF, status). Walked under an uncompiled budget
    (``terrain_numba.uncompiled_budget``): the example flight's 5364 footprint rays walk in
    0.5-0.9 s uncompiled, where a cold cache would compile the walk for them (5-15 s of CPU before
    the viewer's first scene); a long flight's batch walks its first rays so, then the
    compiled kernel."""
    from geoloc.surfaces.terrain_numba import uncompiled_budget

    with uncompiled_budget():
        g = Pipeline(None, surface, corrections).intersect(los)
    return g.lat, g.lon, g.h, g.ecef, np.asarray(g.status)


def _num(records, name) -> np.ndarray:
    return np.array([float(getattr(info, name)) for info, _ in records])


def _track_speed(track_enu):
    """Horizontal velocity [m per frame] (ENU, central differences) and its norm."""
    n = len(track_enu)
    if n < 2:
        return np.full((n, 3), np.nan), np.full(n, np.nan)
    v = np.gradient(track_enu, axis=0)
    return v, np.linalg.norm(v[:, :2], axis=1)


def _assessment(track, pose, rec_lat, rec_lon, rec_h, rec_st, ref_lat, ref_lon, ref_h) -> dict:
    """What :func:`build` derives from the positions: speed, track heading, the residual's
    components against the reference, the residual, the robust outlier flags and the order."""
    _, speed = _track_speed(track)
    # the local track azimuth (previous to next position; the heading where they nearly coincide)
    heading = accuracy.track_azimuth_rad(
        np.degrees(pose.lat), np.degrees(pose.lon), heading_rad=np.asarray(pose.heading, float)
    )
    comp = accuracy.error_components(rec_lat, rec_lon, rec_h, ref_lat, ref_lon, ref_h, track_heading_rad=heading)
    comp = {k_: np.asarray(v, float) for k_, v in comp.items()}
    residual = comp["horizontal_m"].copy()
    residual[rec_st != Status.OK] = np.nan
    outlier = np.asarray(accuracy.robust_outliers(residual), bool)
    key = np.where(np.isfinite(residual), -residual, np.inf)
    order = np.argsort(key, kind="stable")
    return {
        "speed": speed,
        "heading": heading,
        "components": comp,
        "residual": residual,
        "outlier": outlier,
        "order": order,
    }


#: FlightModel fields holding one entry per frame (frame index first): what :func:`extend` joins.
PER_FRAME = (
    "track_enu",
    "footprint_enu",
    "footprint_status",
    "corners_enu",
    "corner_lat_deg",
    "corner_lon_deg",
    "corner_h_m",
    "centre_enu",
    "recomputed_lat_deg",
    "recomputed_lon_deg",
    "recomputed_h_m",
    "recomputed_enu",
    "status",
    "reported_lat_deg",
    "reported_lon_deg",
    "reported_h_m",
    "reported_enu",
    "truth_lat_deg",
    "truth_lon_deg",
    "truth_h_m",
    "truth_enu",
)


def extend(
    model: FlightModel | None, new: FlightModel, scn, keep: int | None = None, diagnose_faults: bool = True
) -> FlightModel:
    """``model`` followed by the frames of ``new`` (a flight that grew: a live stream), the newest
    ``keep`` kept, with everything that depends on the whole flight derived again over the result
    exactly as :func:`build` derives it (speed, track heading, residual components, robust outlier
    flags, order, the fault runs): the same model as :func:`build` of those frames at once.

    Both models must share one ENU frame (``build(..., enu=model.enu)``) and one reference kind;
    ``scn`` is the scenario whose ``records`` are the frames of the result (for :func:`diagnose`).
    """
    if model is None or len(model) == 0:
        joined = {k: getattr(new, k) for k in PER_FRAME}
        labels = list(new.labels)
    else:
        if new.enu != model.enu:
            raise ValueError("extend: the new frames are in another ENU frame (build them with enu=model.enu)")
        joined = {k: np.concatenate([getattr(model, k), getattr(new, k)]) for k in PER_FRAME}
        labels = list(model.labels) + list(new.labels)
    if keep is not None and len(labels) > keep:
        joined = {k: v[-keep:] for k, v in joined.items()}
        labels = labels[-keep:]
    pose, row, col, target_h = records_pose(scn.records)
    if len(scn.records) != len(labels):
        raise ValueError(f"extend: scn has {len(scn.records)} records for {len(labels)} frames")
    m = _assessed(joined, labels, new.enu, pose, new.surface, new.located_by)
    if diagnose_faults:
        m.faults = diagnose(m, scn, pose=pose, row=row, col=col, target_h=target_h)
    return m


def build(
    scn,
    *,
    edge_samples: int = EDGE_SAMPLES,
    method: str = "exact",
    enu: EnuFrame | None = None,
    fov_deg=None,
    diagnose_faults: bool = True,
    audit: bool = True,
) -> FlightModel:
    """Compute the whole flight of ``scn.records`` in one batch (see the module docstring).

    Parameters
    ----------
    scn : geoloc_viz.model.Scenario
        Its ``camera`` (a sensor or first-phase camera), ``records``, ``dem`` / ``use_dem``.
    edge_samples : int
        Outline points per image edge (the corner included).
    method : {"exact", "bisect", "steps"}
        DEM solver of the flight's rays (the current frame's own method stays the viewer's).
    enu : EnuFrame, optional
        The model's local frame; default ``scn.enu``.
    fov_deg : array_like (n, 2), optional
        Per-frame horizontal / vertical fields of view [deg] (a zooming KLV sensor); default
        ``scn.frame_fov_deg`` when the scenario carries it, else the sensor's own lens.
    diagnose_faults : bool
        Fit the fault models to every run of outliers (:func:`diagnose`).
    audit : bool
        Audit the flight's heights and conventions (:func:`flight_audit`).

    Returns
    -------
    FlightModel
    """
    recs = list(scn.records)
    if not recs:
        raise ValueError(f"scenario {scn.name!r}: no records: a flight needs at least one frame")
    sensor = scn.camera
    enu = enu or scn.enu
    fov_deg = _frame_fov_deg(scn, fov_deg, len(recs))
    pose, row, col, target_h = records_pose(recs)
    surface = _surface(scn, target_h, method)
    dem = terrain_of(surface)
    corrections = getattr(scn, "corrections", NO_CORRECTIONS)
    located, centre_deg = _located(sensor, pose, row, col, surface, corrections, enu, edge_samples, fov_deg)
    refs = _references(recs, target_h, dem, enu)
    labels = [info.label for info, _ in recs]
    located_by = _LOCATED_BY.get(method, method) if dem is not None else "the record's target height"
    model = _assessed({**located, **refs}, labels, enu, pose, _surface_text(scn, dem, method), located_by)
    budget = getattr(scn, "budget", None)
    if budget is not None:  # the second outlier rule: outside the frame's own predicted 99 % ellipse
        model.outside_ellipse99 = outside_own_ellipse(
            sensor, pose, row, col, surface, budget, model.components, model.residual_m
        )
    if diagnose_faults:
        model.faults = diagnose(model, scn, pose=pose, row=row, col=col, target_h=target_h, method=method)
    if audit:
        _audit_model(model, scn, recs, pose, sensor, row, col, surface, centre_deg)
    return model


def _located(sensor, pose, row, col, surface, corrections, enu: EnuFrame, edge_samples: int, fov_deg):
    """The flight located in one batch (:func:`_flight_pixels`'s rays on the surface): the
    :class:`FlightModel` fields of the track, the footprints and their corners, the image centres
    and the records' own pixels (recomputed); and the image centres' (lat, lon) [deg]."""
    rows, cols = _flight_pixels(sensor, row, col, edge_samples, fov_deg)
    los = sensor.line_of_sight(rows, cols, pose, outside="extrapolate")
    lat, lon, h, ecef, st = _hit(surface, los, corrections)
    P = rows.shape[0] - 2  # the outline's pixels
    pts_enu = enu.from_ecef(ecef)  # (P + 2, n, 3)
    footprint = np.swapaxes(pts_enu[:P], 0, 1)  # (n, P, 3)
    corner_idx = np.arange(4) * int(edge_samples)
    lat_d, lon_d = np.degrees(lat), np.degrees(lon)
    fields = {
        "track_enu": enu.from_ecef(los.origin_ecef[0]),
        "footprint_enu": footprint,
        "footprint_status": np.swapaxes(st[:P], 0, 1),
        "corners_enu": footprint[:, corner_idx],
        "corner_lat_deg": lat_d[:P][corner_idx].T,
        "corner_lon_deg": lon_d[:P][corner_idx].T,
        "corner_h_m": h[:P][corner_idx].T,
        "centre_enu": pts_enu[P],
        "recomputed_lat_deg": lat_d[-1],
        "recomputed_lon_deg": lon_d[-1],
        "recomputed_h_m": h[-1],
        "recomputed_enu": pts_enu[-1],
        "status": st[-1],
    }
    return fields, (lat_d[P], lon_d[P])


def _references(recs, target_h, dem, enu: EnuFrame) -> dict:
    """The :class:`FlightModel` fields of the records' reported positions and surveyed truth
    (:func:`_truth_positions`; its height NaN where a record has no truth)."""
    rep_lat, rep_lon, rep_h = (_num(recs, x) for x in ("paper_lat_deg", "paper_lon_deg", "paper_height_m"))
    t_lat, t_lon, t_h = _truth_positions(recs, target_h, dem)

    def enu_of(la, lo, hh):
        return enu.from_geodetic(np.radians(la), np.radians(lo), np.where(np.isfinite(hh), hh, 0.0))

    return {
        "reported_lat_deg": rep_lat,
        "reported_lon_deg": rep_lon,
        "reported_h_m": rep_h,
        "reported_enu": enu_of(rep_lat, rep_lon, np.where(np.isfinite(rep_h), rep_h, target_h)),
        "truth_lat_deg": t_lat,
        "truth_lon_deg": t_lon,
        "truth_h_m": np.where(np.isfinite(t_lat) & np.isfinite(t_lon), t_h, np.nan),
        "truth_enu": enu_of(t_lat, t_lon, t_h),
    }


def _assessed(per_frame: dict, labels: list, enu: EnuFrame, pose, surface: str, located_by: str) -> FlightModel:
    """The flight's model from its per-frame fields (:data:`PER_FRAME`): the reference (the
    surveyed truth where a frame has one, else the reported positions; its height, where
    unknown, the recomputed one) and what :func:`_assessment` derives against it; ``surface``
    and ``located_by`` say how the frames were located."""
    has_truth = np.isfinite(per_frame["truth_lat_deg"]) & np.isfinite(per_frame["truth_lon_deg"])
    reference = "truth" if has_truth.any() else "reported"
    ref_h = per_frame[f"{reference}_h_m"]
    a = _assessment(
        per_frame["track_enu"],
        pose,
        per_frame["recomputed_lat_deg"],
        per_frame["recomputed_lon_deg"],
        per_frame["recomputed_h_m"],
        per_frame["status"],
        per_frame[f"{reference}_lat_deg"],
        per_frame[f"{reference}_lon_deg"],
        np.where(np.isfinite(ref_h), ref_h, per_frame["recomputed_h_m"]),
    )
    return FlightModel(
        labels=labels,
        enu=enu,
        **per_frame,
        reference=reference,
        residual_m=a["residual"],
        components=a["components"],
        outlier=a["outlier"],
        order=a["order"],
        track_heading_rad=a["heading"],
        speed_m_per_frame=a["speed"],
        surface=surface,
        located_by=located_by,
    )


def _frame_fov_deg(scn, fov_deg, n: int):
    """Each frame's (horizontal, vertical) fields of view [deg]: ``fov_deg``, else the scenario's
    ``frame_fov_deg``, else None (the sensor's own lens); refused unless of shape (n, 2)."""
    if fov_deg is None:
        fov_deg = getattr(scn, "frame_fov_deg", None)
    if fov_deg is not None:
        fov_deg = np.asarray(fov_deg, float)
        if fov_deg.shape != (n, 2):
            raise ValueError(f"fov_deg: shape {fov_deg.shape}, expected ({n}, 2) (one hfov, vfov per frame)")
    return fov_deg


def _flight_pixels(sensor, row, col, edge_samples: int, fov_deg):
    """The flight's pixels in one batch, (P + 2, n) rows and columns: the image outline's P
    pixels (:func:`outline_pixels`), the image centre and the record's own pixel."""
    n = len(row)
    rr, cc = outline_pixels(sensor, edge_samples, fov_deg)
    rr = np.broadcast_to(rr.reshape(len(rr), -1), (len(rr), n))
    cc = np.broadcast_to(cc.reshape(len(cc), -1), (len(cc), n))
    r0, c0 = sensor.center_pixel
    rows = np.concatenate([rr, np.full((1, n), r0), row[None]], axis=0)
    cols = np.concatenate([cc, np.full((1, n), c0), col[None]], axis=0)
    return rows, cols


def _truth_positions(recs, target_h, dem):
    """The records' surveyed truth (lat, lon [deg], h [m]). The records give no truth height: the
    truth sits on the DEM when there is one, else at the record's target height (the
    calibration layer does the same)."""
    t_lat, t_lon = _num(recs, "truth_lat_deg"), _num(recs, "truth_lon_deg")
    t_h = target_h.copy()
    if dem is not None and np.isfinite(t_lat).any():
        ok = np.isfinite(t_lat)
        dh = dem.height(np.radians(t_lat[ok]), np.radians(t_lon[ok]))
        t_h[ok] = np.where(np.isfinite(dh), dh, t_h[ok])
    return t_lat, t_lon, t_h


def _surface_text(scn, dem, method: str) -> str:
    """What the flight's rays were located on, in words."""
    if dem is None:
        return "ellipsoid at each record's target height (no DEM)"
    return (
        f"DEM {getattr(scn, 'dem_name', '') or 'given'}, {method} first hit (outline rays off the DEM: "
        "the record's target height)"
    )


def _audit_model(model: FlightModel, scn, recs, pose, sensor, row, col, surface, centre_deg) -> None:
    """The flight's heights and conventions audited (:func:`flight_audit`) with the recorded
    heading and azimuth, against the reported positions as the records audit takes them: the
    published ones, else the surveyed truth (its heights left out: the DEM's under it are no
    report); the fault runs named by the audit."""
    rep_lat, rep_lon = model.reported_lat_deg, model.reported_lon_deg
    if bool((np.isfinite(rep_lat) & np.isfinite(rep_lon)).any()):
        audited = (rep_lat, rep_lon, model.reported_h_m)
    else:
        audited = (model.truth_lat_deg, model.truth_lon_deg, np.full(len(recs), np.nan))
    az = [float(inp.angles_deg.get("azimuth", np.nan)) for _, inp in recs]
    angles = {
        "heading": np.array([float(inp.heading_deg) for _, inp in recs]),
        "azimuth": np.array(az) if np.isfinite(az).any() else None,
    }
    # under the same uncompiled budget as the footprints (_hit): the audit's 298 frame centres
    # must not compile the walk before the first scene on a cold cache
    from geoloc.surfaces.terrain_numba import uncompiled_budget

    with uncompiled_budget():
        model.audit = flight_audit(scn, pose, sensor, row, col, surface, audited, centre_deg, angles)
    model.faults = name_runs_by_audit(model.faults, model.audit)


def outside_own_ellipse(sensor, pose, row, col, surface, budget, components, residual, p: float = 0.99):
    """True for the frames whose residual lies outside their own predicted ``p`` ellipse (default 99 %).

    The ellipse is the recomputed point's (:func:`geoloc.analysis.uncertainty.propagate` of the
    budget as the viewer carries it, :func:`geoloc_viz.uncertainty_layer.usable_budget`: ``time_s``
    left out, records carry no velocity; lens keys the frames' lens lacks); the residual's east and north are
    ``components``'. Beside the robust rule, which compares a frame with the others, this one
    compares it with what its own geometry and budget allow (a 40 m error at 80 degrees off
    nadir may be normal, a 10 m error at nadir may not)."""
    from geoloc.analysis.uncertainty import outside_ellipse, propagate
    from geoloc_viz.uncertainty_layer import usable_budget

    b, _ = usable_budget(budget, sensor)
    pu = propagate(sensor, pose, row, col, b, surface=surface, outside="extrapolate")
    out = outside_ellipse(
        components["east_m"], components["north_m"], pu.ellipse_major_m, pu.ellipse_minor_m, pu.ellipse_azimuth_deg, p
    )
    return np.asarray(out & np.isfinite(residual) & (np.asarray(pu.status) == Status.OK), bool)


# --------------------------------------------------------------------------- what the outliers look like


def outlier_runs(mask, max_gap: int = 1) -> list:
    """(first, last) index pairs of runs of True in ``mask``, joining runs split by <= ``max_gap`` False."""
    idx = np.flatnonzero(np.asarray(mask, bool))
    if len(idx) == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > max_gap + 1)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    return list(zip(starts.tolist(), ends.tolist()))


def name_runs_by_audit(faults: list, audit) -> list:
    """The runs of ``faults`` (:class:`FaultRun`) with the audit's findings that cover them named first.

    A finding covers a run when every frame of the run is among the frames its estimate rests on
    (``Finding.frames``: frame indices of the model). Such a run gets ``kind = "convention"``, the
    covering findings, and keeps its one-parameter fit (``fit_kind``, ``value``) as the second
    guess: a convention the whole data name is a better cause than a fit to a few frames (a 1-frame
    "timing" fit to centres measured from north, say). Runs no finding covers are returned as they are.

    Parameters
    ----------
    faults : list of FaultRun
        :func:`diagnose`'s runs.
    audit : geoloc.analysis.height_audit.HeightAudit or None
        The flight's audit (:func:`flight_audit`); None: nothing to name.
    """
    if audit is None or not getattr(audit, "findings", None):
        return list(faults)
    out = []
    for f in faults:
        run = set(range(f.first, f.last + 1))
        cover = tuple(x for x in audit.findings if run <= {int(k) for k in x.frames})
        if cover:
            f = replace(f, kind="convention", fit_kind=f.fit_kind or f.kind, findings=cover)
        out.append(f)
    return out


def _pose_fields(pose: Pose, idx):
    p = pose.take(idx)
    return {k: np.asarray(getattr(p, k), float).copy() for k in ("lat", "lon", "h", "heading", "pitch", "roll")}, p


def diagnose(model: FlightModel, scn, *, pose=None, row=None, col=None, target_h=None, method="exact") -> list:
    """Fit each run of outliers with three one-parameter faults; the best explains the run.

    For frames i of a run, with d_i the ENU residual (recomputed - reference) and J_i^k the change of
    the recomputed point per unit of fault k (a finite difference through the same sensor and
    surface), the least-squares size of fault k is p_k = sum(J . d) / sum(J . J) and its
    unexplained fraction |d - p_k J| / |d| over the run. The faults:

    * ``attitude``: heading + p [rad] (the attitude bias the brief's example plants);
    * ``datum``: sensor height + p [m] (a height in the wrong datum shifts the whole run alike);
    * ``timing``: position and attitude of the next (or the previous) frame with this frame's gimbal
      angles, per frame of offset: pose and image from different instants (p < 0: a stale pose).
      One-sided steps between recorded poses, so a stale pose's frame-to-frame attitude noise is
      part of the model (a smooth rate would miss it: at 0.2 deg of attitude noise and 3 km of
      range that is 10 m, as much as the 54 m/s orbit's own step).

    The smallest unexplained fraction wins if below :data:`EXPLAINED_FRACTION`, else ``"unexplained"``.
    """
    runs = outlier_runs(model.outlier)
    if not runs:
        return []
    if pose is None:
        pose, row, col, target_h = records_pose(scn.records)
    sensor = scn.camera
    n = len(model)
    idx = np.concatenate([np.arange(a, b + 1) for a, b in runs])
    ref = model.truth_enu if model.reference == "truth" else model.reported_enu
    d = model.recomputed_enu[idx] - ref[idx]  # (m, 3)
    base, p0 = _pose_fields(pose, idx)
    # a timing offset puts the pose of another frame with this frame's gimbal angles: the
    # neighbouring frames' poses (one frame later, one earlier), frame-to-frame attitude noise included
    nxt, _ = _pose_fields(pose, np.clip(idx + 1, 0, n - 1))
    prv, _ = _pose_fields(pose, np.clip(idx - 1, 0, n - 1))
    variants = {
        "attitude": {**base, "heading": base["heading"] + HEADING_STEP_RAD},
        "datum": {**base, "h": base["h"] + HEIGHT_STEP_M},
        "timing+": nxt,
        "timing-": prv,
    }
    steps = {
        "attitude": HEADING_STEP_RAD,
        "datum": HEIGHT_STEP_M,
        "timing+": TIME_STEP_FRAMES,
        "timing-": -TIME_STEP_FRAMES,
    }
    kinds = list(variants)
    # one batch: the unperturbed pose and the variants, stacked on a leading axis
    stack = {k: np.stack([base[k]] + [variants[v][k] for v in kinds]) for k in base}
    shape = (len(kinds) + 1, len(idx))
    angles = {a: np.broadcast_to(np.asarray(v, float), shape) for a, v in p0.angles.items()}
    gr = np.broadcast_to(np.asarray(p0.gimbal_roll, float), shape)
    gp = np.broadcast_to(np.asarray(p0.gimbal_pitch, float), shape)
    pb = Pose(
        stack["lat"], stack["lon"], stack["h"], stack["heading"], stack["pitch"], stack["roll"], gr, gp, angles=angles
    )
    th = target_h[idx]
    surface = _surface(scn, th, method)
    los = sensor.line_of_sight(row[idx], col[idx], pb, outside="extrapolate")
    *_, ecef, _ = _hit(
        surface, los, getattr(scn, "corrections", NO_CORRECTIONS)
    )  # a failed variant is NaN: left out of its fit
    pts = model.enu.from_ecef(ecef)  # (1 + kinds, m, 3)
    J = {k: (pts[1 + j] - pts[0]) / steps[k] for j, k in enumerate(kinds)}
    # the first frame has no earlier one (and the last no later one): its one-sided step is zero
    J["timing+"][idx == n - 1] = np.nan
    J["timing-"][idx == 0] = np.nan
    out, pos = [], 0
    for a, b in runs:
        sl = slice(pos, pos + b - a + 1)
        pos += b - a + 1
        dd = d[sl]
        ok = np.all(np.isfinite(dd), axis=1)
        fits = {}
        for k in kinds:
            jj = J[k][sl]
            good = ok & np.all(np.isfinite(jj), axis=1)
            den = float(np.sum(jj[good] * jj[good]))
            if not good.any() or den == 0.0:
                fits[k] = (math.nan, math.inf)
                continue
            p = float(np.sum(jj[good] * dd[good])) / den
            rest = float(np.linalg.norm(dd[good] - p * jj[good])) / max(float(np.linalg.norm(dd[good])), 1e-12)
            fits[k] = (p, rest)
        # the timing fault: the better of the two one-sided steps
        tk = min(("timing+", "timing-"), key=lambda k: fits[k][1])
        fits["timing"] = fits[tk]
        named = ("attitude", "datum", "timing")
        best = min(named, key=lambda k: fits[k][1])
        kind = best if fits[best][1] < EXPLAINED_FRACTION else "unexplained"
        out.append(
            FaultRun(
                a,
                b,
                kind,
                fits[best][0] if kind != "unexplained" else math.nan,
                {k: fits[k][1] for k in named},
                tuple(model.labels[a : b + 1]),
            )
        )
    return out


# --------------------------------------------------------------------------- the first look


def klv_fov_deg(path, labels) -> np.ndarray:
    """(n, 2) horizontal / vertical fields of view [deg] of the KLV packets named by ``labels``
    (``"packet N"``, as :func:`geoloc_viz.scenario.records_from_klv` names them; tags 16, 17)."""
    from geoloc.workflows.klv_replay import read_klv

    r = read_klv(path)
    by_packet = {int(p): k for k, p in enumerate(r.packet)}
    h = np.asarray(r.columns["sensor_horizontal_fov_deg"], float)
    v = np.asarray(r.columns["sensor_vertical_fov_deg"], float)
    rows = []
    for lab in labels:
        k = by_packet.get(int(str(lab).split()[-1]))
        rows.append((h[k], v[k]) if k is not None else (np.nan, np.nan))
    return np.array(rows, float)


def default_flight_path() -> Path:
    """The bundled example flight: MISB ST 0601 KLV over the SRTM crop (``assets/klv/example_flight.klv``)."""
    from geoloc.assets import ASSETS

    return Path(ASSETS) / "klv" / "example_flight.klv"


def default_flight_scenario(
    record=None, path=None, camera_path=None, dem_path=None, use_dem: bool = True, dem_datum: str = "egm96"
):
    """The viewer's first look: the bundled KLV example flight over the SRTM crop, its worst frame open.

    Its planted faults (``tools/make_klv_example.py``, ``docs/klv.md``): a 2.5 deg heading-bias burst
    (packets 100-109), MSL written in the HAE tag (200-204), a 1 s stale pose (250-256), one
    corrupted packet (150, skipped by the reader and reported), one packet without sensor angles
    (275, not a frame). The scenario carries each frame's fields of view (``frame_fov_deg``) so the
    footprints follow the zoom. ``record`` (label or index) opens that frame first (default the first).
    ``path`` is another KLV file (``geoloc view --records FILE.klv``); ``camera_path``, ``dem_path``,
    ``use_dem`` and ``dem_datum`` are those of :func:`geoloc_viz.scenario.load_view_scenario`.
    """
    from geoloc_viz.scenario import load_view_scenario

    path = default_flight_path() if path is None else Path(path)
    scn = load_view_scenario(path, record, camera_path, dem_path, use_dem=use_dem, dem_datum=dem_datum)
    # (headings come wrapped into -180..180 from viz.scenario.records_from_klv, for the heading slider)
    scn.frame_fov_deg = klv_fov_deg(path, [info.label for info, _ in scn.records])
    targets = path.with_name(path.stem + "_targets.csv")
    if targets.is_file():  # the surveyed targets painted in the rendered video (tools/make_klv_example.py)
        scn.targets = read_targets(targets)
    attach_video(scn, path.with_suffix(".ts") if path.suffix.lower() != ".ts" else path)
    return scn


def read_targets(path) -> list:
    """[(name, lat_deg, lon_deg, h_m)] of a targets CSV (columns ``name, lat_deg, lon_deg, h_m``;
    heights ellipsoidal, WGS 84; an empty height: on the DEM)."""
    import csv

    out = []
    with open(path, newline="") as f:
        for k, row in enumerate(csv.DictReader(f), start=2):
            try:
                h = row.get("h_m", "")
                out.append(
                    (
                        row["name"],
                        float(row["lat_deg"]),
                        float(row["lon_deg"]),
                        float(h) if h not in ("", None) else math.nan,
                    )
                )
            except (KeyError, ValueError) as e:
                raise ValueError(f"{path}, line {k}: {e}: need name, lat_deg, lon_deg[, h_m]") from None
    return out


def attach_video(scn, ts_path) -> bool:
    """Give ``scn`` the frames of the video in ``ts_path`` (an MPEG-TS with the KLV stream beside
    its video, STANAG 4609): ``scn.images`` (:func:`geoloc.io.images.open_images`, decoded lazily)
    and ``scn.record_times_s``, each record's KLV packet time stamp on the container clock, so a
    record shows the frame nearest its packet (``ImageSource.index_at``); the sensor and the records'
    pixels are put in the video's own grid (:func:`geoloc_viz.model.use_image_grid`). False (and the scenario
    left without images) when the file is missing or has no video stream."""
    from geoloc.io.images import open_images
    from geoloc.workflows.klv_replay import read_klv

    ts_path = Path(ts_path)
    if not ts_path.is_file():
        return False
    try:
        images = open_images(ts_path)
        len(images)
    except ValueError:  # a KLV-only transport stream: no pictures
        return False
    r = read_klv(ts_path)
    pts = {int(p): float(t) for p, t in zip(r.packet, r.pts_s)}
    scn.images = images
    scn.video_path = ts_path  # the stream whose picture-to-metadata timing is fitted (picture_model)
    scn.record_times_s = np.array([pts.get(int(str(info.label).split()[-1]), np.nan) for info, _ in scn.records])
    # the one place the sensor's nominal pixel grid becomes the video's: every pixel shown from
    # here on (inputs, picture, footprints, exported commands) is one of the image's own
    from geoloc_viz.model import use_image_grid

    use_image_grid(scn, images.rows, images.cols)
    return True
