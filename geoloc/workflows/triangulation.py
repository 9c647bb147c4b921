"""Targets seen in several records: triangulate each one and check the surface against it.

A records file with a ``target_id`` column names the same target in several rows (frames);
so does a drone photos' targets file (``geoloc replay PHOTOS... --targets T.csv``: each row a
pixel of one photo, :func:`triangulate_ids` from each photo's own ray, in
:func:`geoloc.workflows.photo_replay.replay_photos`). :func:`triangulate_records` intersects each target's rays
(:func:`geoloc.analysis.triangulate.triangulate`), gives its covariance when the sensor has an
error budget, each ray's residual, and compares the intersection with each frame's hit on the
surface the replay used (:func:`geoloc.analysis.triangulate.compare_with_surface`): a consistent
height difference is reported as a likely DEM or datum error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from geoloc.analysis.triangulate import Triangulation, compare_with_surface, triangulate
from geoloc.io.records import Records
from geoloc.status import Status
from geoloc.pipeline import NO_CORRECTIONS, Corrections

if TYPE_CHECKING:
    from geoloc.sensors.budget import ErrorBudget
    from geoloc.sensors.camera import FrameSensorLike

#: The column naming a target seen in several rows.
TARGET_ID_COLUMN = "target_id"


@dataclass
class TargetResult:
    """One target's triangulation, the rows it came from and the surface check."""

    target_id: str
    rows: np.ndarray  # indices into the records
    lines: list  # their line numbers in the file
    tri: Triangulation
    surface: dict = field(default_factory=dict)  # compare_with_surface's result (empty without hits)


def triangulate_records(
    records: Records,
    sensor: FrameSensorLike,
    budget: ErrorBudget | None = None,
    surface_h_m: ArrayLike | None = None,
    surface_ok: ArrayLike | None = None,
    column: str = TARGET_ID_COLUMN,
    corrections: Corrections = NO_CORRECTIONS,
) -> list[TargetResult]:
    """Triangulate every target named in two rows or more of ``column``.

    Parameters
    ----------
    records : Records
    sensor : FrameSensor or Camera
    budget : ErrorBudget, optional
        The sensor file's ``[uncertainty]``: weights and the covariance (``time_s`` left out:
        records carry no platform velocity).
    surface_h_m, surface_ok : array_like (n,), optional
        Each record's located height on the replay's surface and whether it was located (the
        replay's ``h_m`` and status): the DEM / datum check.
    corrections : Corrections
        The replay's line-of-sight corrections: the rays are met as they arrive near the target
        (:func:`geoloc.analysis.triangulate.triangulate`).
    """
    if column not in records.header:
        return []
    if budget is not None and budget.sigma("time_s") > 0:  # records carry no velocity (the replay says so)
        from geoloc.sensors.budget import ErrorBudget

        budget = ErrorBudget(
            {k: v for k, v in budget.sigmas.items() if k != "time_s"}, budget.dem_product, budget.source
        )
    ids = [r.get(column, "").strip() for r in records.rows]
    pose = records.pose()
    row, col = records.column("row"), records.column("col")
    out = []
    for tid in dict.fromkeys(i for i in ids if i):
        idx = np.array([k for k, i in enumerate(ids) if i == tid])
        if idx.size < 2:
            continue
        p = pose.take(idx)
        tri = triangulate(sensor, p, row[idx], col[idx], budget, corrections=corrections)
        res = TargetResult(tid, idx, [int(records.lines[k]) for k in idx], tri)
        if surface_h_m is not None and tri.status == Status.OK:
            ok = None if surface_ok is None else np.asarray(surface_ok)[idx]
            res.surface = compare_with_surface(tri, np.asarray(surface_h_m, float)[idx], ok)
        out.append(res)
    return out


def triangulate_ids(
    ids: Sequence[object],
    origins: ArrayLike,
    directions: ArrayLike,
    ok: ArrayLike,
    lines: Sequence[int],
    surface_h_m: ArrayLike | None = None,
    surface_ok: ArrayLike | None = None,
) -> list[TargetResult]:
    """Triangulate every target id named by two rays or more, from the rays themselves (each ray
    from its own frame's sensor: drone photos each have theirs), without a budget.

    Parameters
    ----------
    ids : sequence of str
        Each ray's target id ('' for none).
    origins, directions : array_like (n, 3)
        The rays in ECEF [m] (:class:`geoloc.surfaces.base.LineOfSight`'s).
    ok : array_like (n,) of bool
        Rays that may be used.
    lines : sequence of int
        Each ray's line in its file (for the messages).
    surface_h_m, surface_ok : array_like (n,), optional
        Each ray's located height on the replay's surface and whether it was located: the
        DEM / datum check (:func:`geoloc.analysis.triangulate.compare_with_surface`).

    Returns
    -------
    list of TargetResult
        In the order the ids first appear.
    """
    from geoloc.analysis.triangulate import triangulate_rays

    O = np.asarray(origins, float).reshape(-1, 3)
    D = np.asarray(directions, float).reshape(-1, 3)
    ok = np.asarray(ok, bool).reshape(-1)
    names = [str(i).strip() for i in ids]
    out = []
    for tid in dict.fromkeys(i for i in names if i):
        idx = np.array([k for k, i in enumerate(names) if i == tid])
        if idx.size < 2:
            continue
        tri = triangulate_rays(O[idx], D[idx], ok[idx])
        res = TargetResult(tid, idx, [int(lines[k]) for k in idx], tri)
        if surface_h_m is not None and tri.status == Status.OK:
            good = ok[idx] if surface_ok is None else ok[idx] & np.asarray(surface_ok, bool)[idx]
            res.surface = compare_with_surface(tri, np.asarray(surface_h_m, float)[idx], good)
        out.append(res)
    return out


def summary_lines(results: list) -> list:
    """One line per target (position, rays, CE90 / LE90, worst residual) and its surface check."""
    L = []
    for r in results:
        t = r.tri
        if t.status != Status.OK:
            L.append(
                f"target {r.target_id}: {t.n_rays} usable rays (lines {r.lines}): not triangulated "
                "(fewer than two rays, or rays within 1 deg of each other)"
            )
            continue
        unc = f", CE90 {t.ce90_m:.1f} m, LE90 {t.le90_m:.1f} m" if math.isfinite(t.ce90_m) else ""
        L.append(
            f"target {r.target_id}: {t.lat_deg:.7f} {t.lon_deg:.7f} h {t.h:.1f} m (ellipsoidal, WGS 84) "
            f"from {t.n_rays} rays{unc}; worst ray residual {np.nanmax(t.residual_m):.1f} m"
        )
        s = r.surface
        if s and math.isfinite(s.get("mean_m", math.nan)):
            L.append(
                f"target {r.target_id}: surface minus intersection {s['mean_m']:+.1f} m "
                f"(standard error {s['se_m']:.1f} m)" + (f"; warning: {s['warning']}" if s["warning"] else "")
            )
    return L
