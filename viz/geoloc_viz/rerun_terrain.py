"""Terrain in a rerun recording: the DEM mesh (static), DEM evaluations and H_n - h_n per ray.

The numbers come from :func:`geoloc.surfaces.terrain.intersect_dem` with ``trace=True``
(docs/method.md section 4: descending steps of [Q17 section 2.3], bisection of
[L23], exact first hit) and the mesh from :meth:`geoloc.surfaces.dem.DEM.to_trimesh`, in
the scene's ENU frame. Entities:

* ``world/dem``: Mesh3D, static, vertex colours by height, cropped to the area
  around the aircraft and targets (records of several flights: ``world/<flight>/dem``
  and ``world/<flight>/iterations``, each in its flight's scene frame);
* ``world/iterations/on_los``: the points of the line of sight at each H_n;
  ``world/iterations/to_dem``: vertical segments from there to the DEM height h_n,
  orange where H_n - h_n > 0 (still above the terrain), blue where below;
* ``convergence/H_minus_h_m``: BarChart of H_n - h_n over the iterations n of the
  current step's ray (scrub the time line to see each ray converge).

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from geoloc.pipeline import NO_CORRECTIONS, Corrections
from geoloc.surfaces.base import GroundPoint, LineOfSight

if TYPE_CHECKING:
    from geoloc.surfaces.dem import DEM

#: Margin around the aircraft and targets kept of the DEM mesh [deg].
CROP_MARGIN_DEG = 0.1


class SolverOptions(TypedDict, total=False):
    """The DEM solver's tolerances that were given (:func:`geoloc.surfaces.terrain.intersect_dem`)."""

    eps_h: float  # descending steps' height step [m]
    threshold: float  # bisection's stopping threshold [m]


def solver_options(eps_h_m: float | None = None, threshold_m: float | None = None) -> SolverOptions:
    """The tolerances given, by the solver's names (an absent one: the solver's default)."""
    kw: SolverOptions = {}
    if eps_h_m is not None:
        kw["eps_h"] = float(eps_h_m)
    if threshold_m is not None:
        kw["threshold"] = float(threshold_m)
    return kw


@dataclass
class TerrainSteps:
    """DEM results per step (present only when a DEM is used).

    Attributes
    ----------
    method : str
    dem : geoloc.surfaces.dem.DEM
        The raster (for the static mesh).
    dem_evaluations : ndarray (n,) of int
    H : list of ndarray
        Per step, the trial heights H_n of the iteration [m].
    h_dem : list of ndarray
        Per step, the DEM height h_n below the line of sight at H_n [m].
    lat, lon, ecef : list of ndarray
        Per step, the point of the line of sight at H_n [rad, rad; ECEF m].
    """

    method: str
    dem: DEM
    dem_path: str
    dem_evaluations: np.ndarray
    H: list
    h_dem: list
    lat: list = field(default_factory=list)
    lon: list = field(default_factory=list)
    ecef: list = field(default_factory=list)


def dem_steps(
    los: LineOfSight,
    dem: DEM,
    method: str = "exact",
    eps_h_m: float | None = None,
    threshold_m: float | None = None,
    corrections: Corrections = NO_CORRECTIONS,
) -> tuple[GroundPoint, TerrainSteps]:
    """Intersect every line of sight with a DEM; the hits as a GroundPoint and the per-ray trace.

    Parameters
    ----------
    los : LineOfSight
        One ray per step, shape (n,).
    dem : geoloc.surfaces.dem.DEM
        The one raster whose solver trace and mesh are drawn, opened once by the caller
        (a mosaic solves region by region and keeps no trace).
    method : {"steps", "bisect", "exact"}
    eps_h_m, threshold_m : float, optional
        Step / threshold of the iterative methods [m] (terrain's defaults if None).
    corrections : geoloc.pipeline.Corrections
        The pipeline's line-of-sight corrections (none by default); the hits keep
        ``corrections`` and ``refraction_m``.
    """
    from geoloc.pipeline import Pipeline
    from geoloc.surfaces.terrain import DemSurface, TerrainHit

    surface = DemSurface(dem, method, trace=True, **solver_options(eps_h_m, threshold_m))
    hit = Pipeline(None, surface, corrections).intersect(los)
    if not isinstance(hit, TerrainHit) or hit.trace is None:
        raise TypeError(f"dem_steps: {surface!r} gave no solver trace (one DEM raster draws its iterations)")
    trace = hit.trace
    ground = GroundPoint(
        hit.lat,
        hit.lon,
        hit.h,
        hit.ecef,
        hit.slant_range,
        hit.status,
        los,
        corrections=hit.corrections,
        refraction_m=hit.refraction_m,
    )
    n = len(hit.status)
    tr: dict[str, list[np.ndarray]] = {"H": [], "h_dem": [], "lat": [], "lon": [], "ecef": []}
    for k in range(n):
        r = trace.ray(k)
        for key in tr:
            tr[key].append(np.asarray(r[key], float))
    return ground, TerrainSteps(
        method,
        dem,
        str(dem.path),
        np.asarray(hit.dem_evaluations),
        tr["H"],
        tr["h_dem"],
        tr["lat"],
        tr["lon"],
        tr["ecef"],
    )


def dem_mesh_enu(dem, enu, lat_range_deg, lon_range_deg, max_nodes: int = 250_000):
    """The DEM's triangle mesh in the scene's ENU frame, cropped to a lat/lon box.

    Returns
    -------
    vertices : ndarray (m, 3) [m], faces : ndarray (k, 3), heights : ndarray (m,) [m]
        Heights are the nodes' ellipsoidal heights (for colouring).
    """
    nr, nc = dem.shape
    stride = max(1, int(np.ceil(np.sqrt(nr * nc / max_nodes))))
    m = dem.to_trimesh(stride, origin_lat=enu.lat0, origin_lon=enu.lon0, origin_h=enu.h0)
    lat, lon = dem.node_latlon_deg()
    lat, lon = lat[::stride, ::stride].ravel(), lon[::stride, ::stride].ravel()
    h = dem.grid.values[::stride, ::stride].ravel()
    inside = (
        (lat >= lat_range_deg[0]) & (lat <= lat_range_deg[1]) & (lon >= lon_range_deg[0]) & (lon <= lon_range_deg[1])
    )
    faces = np.asarray(m.faces)
    keep = np.any(inside[faces], axis=1)
    faces = faces[keep]
    used = np.unique(faces)
    remap = np.full(len(lat), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return np.asarray(m.vertices)[used], remap[faces], h[used]


def height_colors(h):
    """RGBA uint8 per vertex from matplotlib's 'terrain' colour map (greens to browns), min..max of ``h``."""
    from matplotlib import colormaps

    lo, hi = np.nanmin(h), np.nanmax(h)
    x = (h - lo) / (hi - lo) if hi > lo else np.zeros_like(h)
    return (colormaps["terrain"](0.25 + 0.55 * x) * 255).astype(np.uint8)


def log_terrain(rec, steps, index) -> None:
    """Log the static DEM mesh and the per-ray iterations (``index(steps, mask)`` gives the time columns)."""
    import rerun as rr

    from geoloc_viz.rerun_style import COLORS

    ter = steps.terrain
    n = len(steps)
    grp = steps.group_of
    for g in steps.groups:  # one mesh per flight, in that flight's scene frame (world/<flight>/dem)
        m = grp == g
        root = steps.root(g)
        lat = np.concatenate([np.broadcast_to(np.rad2deg(steps.pose.lat), (n,))[m], steps.ground.lat_deg[m]])
        lon = np.concatenate([np.broadcast_to(np.rad2deg(steps.pose.lon), (n,))[m], steps.ground.lon_deg[m]])
        if steps.truth is not None:
            lat = np.concatenate([lat, np.asarray(steps.truth["lat_deg"], float)[m]])
            lon = np.concatenate([lon, np.asarray(steps.truth["lon_deg"], float)[m]])
        box_lat = (np.nanmin(lat) - CROP_MARGIN_DEG, np.nanmax(lat) + CROP_MARGIN_DEG)
        box_lon = (np.nanmin(lon) - CROP_MARGIN_DEG, np.nanmax(lon) + CROP_MARGIN_DEG)
        v, f, h = dem_mesh_enu(ter.dem, steps.enu_for(g), box_lat, box_lon)
        if len(f):
            rec.log(
                f"{root}/dem",
                rr.Mesh3D(vertex_positions=v.astype(np.float32), triangle_indices=f, vertex_colors=height_colors(h)),
                static=True,
            )
        if ter.method != "ellipsoid":
            rec.log(f"{root}/iterations/on_los", rr.Points3D.from_fields(radii=120.0), static=True)
            rec.log(f"{root}/iterations/to_dem", rr.LineStrips3D.from_fields(radii=40.0), static=True)
    if ter.method == "ellipsoid":
        return
    for k in range(n):
        H, hd = ter.H[k], ter.h_dem[k]
        good = np.isfinite(H) & np.isfinite(hd)
        one = np.zeros(n, dtype=bool)
        one[k] = True
        idx = index(steps, one)
        if not np.any(good):
            continue
        root = steps.root(grp[k])
        diff = (H - hd)[good]
        rec.send_columns("convergence/H_minus_h_m", indexes=idx, columns=rr.BarChart.columns(values=diff))
        r = steps_trace_points(steps, k)
        colors = np.where((diff > 0)[:, None], np.array(COLORS["above"], np.uint8), np.array(COLORS["below"], np.uint8))
        rec.send_columns(
            f"{root}/iterations/on_los",
            indexes=idx,
            columns=rr.Points3D.columns(positions=r["on_los"].astype(np.float32), colors=colors).partition([len(diff)]),
        )
        strips = np.stack([r["on_los"], r["dem"]], axis=1).astype(np.float32)
        rec.send_columns(
            f"{root}/iterations/to_dem",
            indexes=idx,
            columns=rr.LineStrips3D.columns(strips=list(strips), colors=colors).partition([len(diff)]),
        )


def steps_trace_points(steps, k: int) -> dict:
    """ENU points of ray ``k``'s iterations: on the line of sight at H_n, and on the DEM below (h_n).

    ``on_los`` is the trace's own ECEF point; ``dem`` the same latitude and longitude
    at the DEM height h_n that :func:`geoloc.surfaces.terrain.intersect_dem` read there.
    """
    ter = steps.terrain
    H, hd = ter.H[k], ter.h_dem[k]
    good = np.isfinite(H) & np.isfinite(hd)
    lat, lon = ter.lat[k][good], ter.lon[k][good]
    enu = steps.enu_of_step(k)  # the step's flight's scene frame
    return {"on_los": enu.from_ecef(ter.ecef[k][good]), "dem": enu.from_geodetic(lat, lon, hd[good])}
