"""The viewer's link to the terrain core (:mod:`geoloc.surfaces.dem`, :mod:`geoloc.surfaces.terrain`).

Kept in one module so the geolocation scene still works on the ellipsoid alone
when the terrain core or a DEM is missing. Heights and meshes come from
:class:`geoloc.surfaces.dem.DEM` (its bilinear surface, sampled; its ``to_trimesh`` in the
scene's ENU frame); intersections and their iterations from
:func:`geoloc.surfaces.terrain.intersect_dem`. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geoloc.assets import ASSETS
from geoloc.pipeline import Pipeline
from geoloc.surfaces.base import GroundPoint, terrain_of
from geoloc.surfaces.spec import SurfaceSpec

from geoloc.surfaces import dem as _dem
from geoloc.surfaces import terrain as _terrain

METHODS = ("steps", "bisect", "exact")
#: Half width of the terrain drawn around the scene origin [m] (the scene spans ~20-30 km).
WINDOW_M = 30e3
#: Nodes per side of the drawn terrain: a resampling of the DEM's bilinear surface on a grid
#: spaced by distance from the scene origin (:func:`mesh_grid`, a level of detail).
MESH_NODES = 81
#: The drawn terrain's node spacing grows as ``1 + d / MESH_LOD_M`` at a distance ``d`` [m] from
#: the scene origin (:func:`mesh_grid`): 60 m at the origin and 300 m at 6 km over the bundled
#: SRTM crop, where a uniform 161 x 161 grid had 75 m everywhere and 4 times the triangles.
MESH_LOD_M = 1500.0


@dataclass
class IterationView:
    """The iterations of a DEM method in ENU: H_n on the line of sight, the DEM below it."""

    method: str
    H: np.ndarray  # (n,) line-of-sight heights H_n [m]
    h_dem: np.ndarray  # (n,) DEM heights h_n below [m]
    on_los_enu: np.ndarray  # (n, 3) ground point of the line of sight at H_n
    dem_enu: np.ndarray  # (n, 3) the same horizontal position at the DEM height
    brackets_enu: np.ndarray | None = None  # (n, 2, 3) bisection bracket ends on the los


def default_dem_path(lat_deg: float, lon_deg: float) -> Path | None:
    """A bundled DEM in ``assets/dem/`` covering (lat, lon), preferring the finest; None if none."""
    folder = Path(ASSETS) / "dem"
    if not folder.is_dir():
        return None
    try:
        from geoloc.surfaces.dem import DEM  # noqa: F401  (terrain support present?)
    except ImportError:
        return None
    best = None
    for p in sorted(folder.glob("*.tif")):
        cell = dem_covers(p, lat_deg, lon_deg)
        if cell is not None and (best is None or cell < best[0]):
            best = (cell, p)
    return None if best is None else best[1]


def dem_covers(path, lat_deg, lon_deg):
    """Node spacing [deg] of the GeoTIFF at ``path`` if its bounds contain (lat, lon), else None."""
    import rasterio

    with rasterio.open(path) as src:
        if src.crs is None or not src.crs.is_geographic:
            return None
        b = src.bounds
        if b.left <= lon_deg <= b.right and b.bottom <= lat_deg <= b.top:
            return float(abs(src.res[0]))
    return None


def attach_dem(scn, path=None, strict: bool = False) -> None:
    """Open the DEM at ``path`` (default: a bundled one covering the scene origin) into ``scn.dem``.

    The file's heights are in ``scn.dem_datum`` (bundled DEMs: orthometric, EGM96;
    ``geoloc view --dem-datum``); :meth:`geoloc.surfaces.spec.SurfaceSpec.raster` opens
    it and converts them to ellipsoidal heights. A DEM that does not cover the scene origin is
    an error naming the path and bounds when ``strict`` (a DEM the user asked
    for), else the scene falls back to the ellipsoid.
    """

    lat, lon = np.rad2deg(scn.enu.lat0), np.rad2deg(scn.enu.lon0)
    if path is None:
        path = default_dem_path(lat, lon)
    if path is None:
        scn.dem = None
        scn.dem_name = "none: ellipsoid at the record's paper_height_m"
        return
    datum = getattr(scn, "dem_datum", "egm96")
    if (getattr(scn, "_dem_path", None), getattr(scn, "_dem_path_datum", None)) != (str(path), datum):
        scn.dem = SurfaceSpec(dem=path, dem_datum=datum).raster("--dem")  # the one way to a DEM
        scn._dem_path, scn._dem_path_datum = str(path), datum  # what is open, and in which datum
    w, s_, e, n = scn.dem.bounds_deg
    if not (s_ <= lat <= n and w <= lon <= e):
        msg = (
            f"dem = {path}: does not cover the target at {lat:.4f} N {lon:.4f} E "
            f"(DEM bounds W {w:.4f} S {s_:.4f} E {e:.4f} N {n:.4f})"
        )
        if strict:
            raise ValueError(msg)
        scn.dem, scn._dem_path = None, None
        scn.dem_name = f"none: {Path(path).name} does not cover this target (ellipsoid at paper_height_m)"
        return
    scn.dem_name = f"{Path(path).name} (EGM96 heights + N)"


def dem_height(dem, lat_deg, lon_deg) -> float:
    """Ellipsoidal DEM height [m] at (lat, lon) [deg] (NaN outside)."""
    return float(dem.height(np.deg2rad(lat_deg), np.deg2rad(lon_deg)))


def _lod_axis(a: float, b: float, c: float, n: int, r0: float) -> np.ndarray:
    """``n`` coordinates from ``a`` to ``b`` spaced in proportion to ``1 + |x - c| / r0``: equal
    steps of ``F(x) = sign(x - c) r0 ln(1 + |x - c| / r0)``, whose derivative is the inverse of
    that spacing (``c`` clipped into the interval)."""
    c = min(max(c, min(a, b)), max(a, b))

    def F(x):
        return np.sign(x - c) * r0 * np.log1p(np.abs(x - c) / r0)

    y = np.linspace(F(a), F(b), n)
    x = c + np.sign(y) * r0 * np.expm1(np.abs(y) / r0)
    x[0], x[-1] = a, b  # the ends exactly
    return x


def mesh_grid(scn, window_m: float = WINDOW_M, nodes: int = MESH_NODES, lod_m: float = MESH_LOD_M):
    """(latitudes [deg], north to south; longitudes [deg], west to east) of the drawn terrain's
    ``nodes x nodes`` grid: +-``window_m`` around the scene origin, clipped to the DEM, the nodes
    spaced as ``1 + d / lod_m`` at a distance ``d`` from the origin along each axis (a level of
    detail: fine where the aircraft, the hit and the iterations are, coarse at the window's edge).
    """
    dem, enu = scn.dem, scn.enu
    lat0, lon0 = np.rad2deg(enu.lat0), np.rad2deg(enu.lon0)
    dlat = np.rad2deg(window_m / 6.36e6)  # metres to degrees (display window only)
    dlon = dlat / np.cos(enu.lat0)
    r_lat = np.rad2deg(lod_m / 6.36e6)
    w, s, e, n = dem.bounds_deg
    north, south = min(lat0 + dlat, n), max(lat0 - dlat, s)
    west, east = max(lon0 - dlon, w), min(lon0 + dlon, e)
    return (_lod_axis(north, south, lat0, nodes, r_lat), _lod_axis(west, east, lon0, nodes, r_lat / np.cos(enu.lat0)))


def _grid_trimesh(LAT, LON, H, enu):
    """A trimesh of a (possibly unevenly spaced) grid of nodes (``LAT``, ``LON`` [deg], ``H`` [m]:
    (rows, columns)) in ``enu``: two triangles per cell, split along the north-west to south-east
    diagonal as :meth:`geoloc.surfaces.dem.DEM.mesh` splits its cells (``grid_faces``); cells with a
    missing node left out (missing nodes at height 0)."""
    import trimesh

    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    v = enu.from_ecef(geodetic_to_ecef(np.deg2rad(LAT), np.deg2rad(LON), np.nan_to_num(H)).reshape(-1, 3))
    return trimesh.Trimesh(v, _dem.grid_faces(np.isfinite(H)), process=False)


def terrain_mesh(scn, window_m: float = WINDOW_M, nodes: int = MESH_NODES, lod_m: float = MESH_LOD_M):
    """The DEM around the scene origin as a vertex-coloured trimesh in the scene's ENU frame.

    The DEM's own bilinear surface (:meth:`geoloc.surfaces.dem.DEM.height`, what the
    solvers intersect) is sampled on :func:`mesh_grid`'s ``nodes x nodes`` geographic grid
    (+-``window_m`` around the origin, clipped to the DEM, spaced by distance from the origin)
    and turned into two triangles a cell in ``scn.enu``. Colours:
    a hypsometric colour map of the height, shaded by :func:`hillshade` (the viewer draws the
    terrain unlit: the relief is in the colours, see :func:`geoloc_viz.scene_geoloc.unlit_glb`).

    In software WebGL a frame's cost follows the triangles drawn (``benchmarks/bench_browser.py
    --groups``): the terrain cost 0.16 s of a 0.36 s frame on a uniform 161 x 161 grid, 0.064 s
    on 81 x 81.
    """
    dem, enu = scn.dem, scn.enu
    lats, lons = mesh_grid(scn, window_m, nodes, lod_m)
    LON, LAT = np.meshgrid(lons, lats)
    H = dem.height(np.deg2rad(LAT), np.deg2rad(LON))
    mesh = _grid_trimesh(LAT, LON, H, enu)
    rgba = _terrain_colours(H.ravel(), np.nanmin(H), np.nanmax(H))
    rgba[:, :3] *= hillshade(mesh.vertices, mesh.faces)[:, None]
    mesh.visual.vertex_colors = (np.clip(rgba, 0.0, 1.0) * 255).astype(np.uint8)
    return mesh


#: The sun of :func:`hillshade`: azimuth (clockwise from North) and elevation [deg], the cartographic
#: convention (light from the north-west, 45 deg up: slopes facing it read as lit, relief as raised).
SUN_AZ_EL_DEG = (315.0, 45.0)


def hillshade(vertices_enu, faces, sun_az_el_deg=SUN_AZ_EL_DEG) -> np.ndarray:
    """Brightness factor per vertex of an ENU height mesh under a fixed sun (display only).

    Lambert's cosine ``max(n . s, 0)`` of the vertex normal ``n`` (area-weighted mean of the
    adjacent faces' normals, turned to point Up) and the unit vector ``s`` to the sun, divided by
    its value on flat ground (``sin(elevation)``), so that level terrain keeps its colour; mapped
    to ``0.45 + 0.55 x`` and clipped to [0.3, 1.3] (slopes in shadow stay readable, lit ones do
    not saturate). Baked into the vertex colours, it lets the browser draw the terrain unlit:
    in software WebGL a lit, image-based-lighting material over the terrain costs most of a
    frame (``benchmarks/bench_browser.py``).
    """
    v = np.asarray(vertices_enu, float)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length: twice the area
    fn *= np.where(fn[:, 2:3] < 0.0, -1.0, 1.0)
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return _shade(n, sun_az_el_deg)


def _shade(n_up, sun_az_el_deg=SUN_AZ_EL_DEG) -> np.ndarray:
    """:func:`hillshade`'s brightness factor of unit normals ``n_up`` (..., 3), ENU, pointing Up."""
    az, el = np.deg2rad(sun_az_el_deg[0]), np.deg2rad(sun_az_el_deg[1])
    sun = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    lam = np.maximum(n_up @ sun, 0.0) / np.sin(el)
    lam[~np.isfinite(lam)] = 1.0
    return np.clip(0.45 + 0.55 * lam, 0.3, 1.3)


def _terrain_colours(H, lo, hi):
    """:func:`terrain_mesh`'s hypsometric colours (RGBA in [0, 1]) of heights ``H`` [m] between ``lo``
    and ``hi`` (missing heights take ``lo``'s colour)."""
    import matplotlib

    t = (np.nan_to_num(H, nan=lo) - lo) / max(hi - lo, 1.0)
    return matplotlib.colormaps["gist_earth"](0.2 + 0.7 * t)


def scene_surface(scn, inp, trace: bool = True):
    """The surface the scene's line of sight meets: the one choice of :func:`geoloc.surfaces.terrain.surface_for`.

    The scenario's DEM with the GUI's method, step and threshold (and the
    iteration trace the scene draws), else the ellipsoid inflated to the
    record's target height [Q17 eq. 11].
    """
    from geoloc.surfaces.terrain import surface_for

    if scn.dem is None:
        return surface_for(inp.target_h)
    return surface_for(dem=scn.dem, method=inp.method, eps_h=inp.eps_h, threshold=inp.threshold, trace=trace)


def hit_geometry(scn, inp, los) -> dict:
    """The hit fields of :class:`geoloc_viz.model.Geometry` on the scene's surface (:func:`scene_surface`).

    On a DEM: :func:`terrain_geometry` (the method's hit, the exact first hit,
    the iterations); on a constant height: its hit alone.
    """
    surface = scene_surface(scn, inp)
    if terrain_of(surface) is not None:
        return terrain_geometry(scn, inp, los, surface)
    hit = Pipeline(None, surface, scene_corrections(scn)).intersect(los)
    label = f"hit at h = {inp.target_h:.1f} m"
    if scn.dem is not None:  # a DEM without the terrain core
        label += " (terrain solver not available)"
    return dict(hit=hit, hit_enu=scn.enu.from_ecef(hit.ecef), hit_label=label, **bent_fields(scn, los, surface, hit))


def scene_corrections(scn):
    """The scene's line-of-sight corrections (``Scenario.corrections``; none on an older scenario)."""
    from geoloc.pipeline import NO_CORRECTIONS

    return getattr(scn, "corrections", None) or NO_CORRECTIONS


def bent_fields(scn, los, surface, hit, raw=None) -> dict:
    """With refraction on: the Geometry's ``raw_hit_enu`` (the straight line's own hit, through the
    pipeline without corrections) and ``bent`` (:func:`bent_ray`); else nothing."""
    c = scene_corrections(scn)
    if c.refraction is None:
        return {}
    if raw is None:
        raw = Pipeline(None, surface).intersect(los)
    return {"raw_hit_enu": scn.enu.from_ecef(raw.ecef), "bent": bent_ray(los, raw, hit, c, scn.enu)}


def _terrain_hit(hit: GroundPoint, surface: object) -> _terrain.TerrainHit:
    """``hit`` as the DEM solver's :class:`geoloc.surfaces.terrain.TerrainHit` (its evaluations,
    hidden flag and trace are what the scene draws); a surface that gives a plain ground point
    (a height, or a DEM with a height where it has no hit) is an error naming it."""
    if not isinstance(hit, _terrain.TerrainHit):
        raise TypeError(
            f"terrain_geometry: surface {surface!r} gave a {type(hit).__name__}, not a TerrainHit "
            "(a DEM surface alone: the scene draws its solver's iterations)"
        )
    return hit


def terrain_geometry(scn, inp, los, surface=None) -> dict:
    """Run the chosen terrain method on ``los`` (with its trace) and express it in ENU.

    Returns the fields of :class:`geoloc_viz.model.Geometry` for the terrain: the
    chosen method's hit, the exact first hit (for comparison), the ellipsoid
    hit at H_max (the DEM's highest node, where [Q17]'s steps start), and the
    iterations: each H_n with its ground point on the line of sight, the DEM
    height h_n below it, and the bisection brackets as points on the line of sight.
    ``surface`` is the scene's :class:`geoloc.surfaces.terrain.DemSurface` (default
    :func:`scene_surface`).
    """
    from geoloc.status import describe
    from geoloc.surfaces.height import intersect_los_height

    enu, dem = scn.enu, scn.dem
    hmax = dem.max_height()
    # the teaching drawing: where the straight line of sight crosses the heights the iteration
    # tries (H_max, the bisection's brackets): the solver's own steps, not located points
    out = {"hmax": hmax, "hit_hmax_enu": enu.from_ecef(intersect_los_height(los, hmax).ecef)}
    surface = scene_surface(scn, inp) if surface is None else surface
    corr = scene_corrections(scn)
    hit = _terrain_hit(Pipeline(None, surface, corr).intersect(los), surface)
    exact = hit if inp.method == "exact" else Pipeline(None, _terrain.DemSurface(dem, "exact"), corr).intersect(los)
    names = {
        "steps": f"descending steps [Q17], eps_h {inp.eps_h:g} m",
        "bisect": f"bisection [L23], threshold {inp.threshold:g} m",
        "exact": "exact first hit",
    }
    msg = f"{names[inp.method]}: {int(hit.dem_evaluations)} DEM evaluations"
    if int(hit.status) != 0:
        msg += f"; {describe(int(hit.status))}"
    if bool(hit.hidden):
        msg += "; **hidden**: the line of sight meets the terrain earlier (see the exact hit)"
    if int(exact.status) == 0 and int(hit.status) == 0:
        msg += f"; {float(np.linalg.norm(hit.ecef - exact.ecef)):.1f} m from the exact first hit"
    it = None
    if hit.trace is not None:
        tr = hit.trace.ray()
        on_los = enu.from_ecef(tr["ecef"])
        below = enu.from_geodetic(tr["lat"], tr["lon"], tr["h_dem"])
        brackets = None
        if inp.method == "bisect" and len(tr["lo"]):
            lo = intersect_los_height(los, tr["lo"]).ecef
            hi = intersect_los_height(los, tr["hi"]).ecef
            brackets = np.stack([enu.from_ecef(lo), enu.from_ecef(hi)], axis=1)
        it = IterationView(inp.method, tr["H"], tr["h_dem"], on_los, below, brackets)
    out.update(
        hit=hit,
        hit_enu=enu.from_ecef(hit.ecef),
        hit_label=names[inp.method].split(",")[0],
        exact_enu=enu.from_ecef(exact.ecef),
        iterations=it,
        message=msg,
        terrain_result=hit,
        **bent_fields(scn, los, scene_surface(scn, inp, trace=False), hit),
    )
    return out


def mesh_height_bound(
    scn, lat_deg, lon_deg, window_m: float = WINDOW_M, nodes: int = MESH_NODES, lod_m: float = MESH_LOD_M
):
    """Highest node of the terrain mesh's grid cell under each point [m, ellipsoidal]: an upper
    bound of the drawn terrain surface there (any triangulation of a cell lies below its highest
    node). NaN outside the mesh or without a DEM.

    The mesh (:func:`terrain_mesh`) resamples the DEM on :func:`mesh_grid`'s nodes (cells of tens
    to hundreds of metres), so between nodes it can lie tens of metres above the DEM's own
    surface, where the hits are: a display that must not be hidden by the mesh is lifted above
    this bound.
    """
    lat = np.atleast_1d(np.asarray(lat_deg, float))
    lon = np.atleast_1d(np.asarray(lon_deg, float))
    dem = getattr(scn, "dem", None)
    if dem is None:
        return np.full(lat.shape, np.nan)
    lats, lons = mesh_grid(scn, window_m, nodes, lod_m)
    # the cell: rows run north to south (lats decreasing), columns west to east
    inside = (lat <= lats[0]) & (lat >= lats[-1]) & (lon >= lons[0]) & (lon <= lons[-1])
    i0 = np.clip(np.searchsorted(-lats, -np.nan_to_num(lat), side="right") - 1, 0, nodes - 2)
    j0 = np.clip(np.searchsorted(lons, np.nan_to_num(lon), side="right") - 1, 0, nodes - 2)
    best = np.full(lat.shape, -np.inf)
    for ii in (i0, i0 + 1):
        for jj in (j0, j0 + 1):
            h = dem.height(np.deg2rad(lats[ii]), np.deg2rad(lons[jj]))
            best = np.fmax(best, np.asarray(h, float))
    best[~inside | ~np.isfinite(best)] = np.nan
    return best


#: Heights along the bent ray drawn between the hit and the camera.
BENT_SAMPLES = 30


@dataclass
class BentRay:
    """The refracted ray from the camera to the located point, in the scene's ENU frame [m].

    ``bent_enu[k]`` and ``straight_enu[k]`` are the bent ray's and the straight line of sight's
    points at the same geodetic height ``h_m[k]`` (ellipsoidal, WGS 84), from the camera (first)
    down to the located point's height (last): the drawing multiplies their difference by its
    exaggeration. ``shift_m``: how far refraction moved the located point (``GroundPoint.refraction_m``).
    """

    h_m: np.ndarray
    bent_enu: np.ndarray
    straight_enu: np.ndarray
    shift_m: float
    corrections: tuple

    def drawn(self, exaggeration: float = 1.0) -> np.ndarray:
        """(n, 3) the bent ray as drawn: its offset from the straight line times ``exaggeration``."""
        return self.straight_enu + float(exaggeration) * (self.bent_enu - self.straight_enu)


def bent_ray(los, raw_hit, hit, corrections, enu, n: int = BENT_SAMPLES) -> BentRay | None:
    """The bent ray of a located point (:class:`BentRay`), or None without refraction or a hit.

    ``raw_hit`` is the straight line's hit on the surface (what the pipeline refracts near:
    it fixes the atmosphere's sphere), ``hit`` the pipeline's located point. Each sample is
    :meth:`geoloc.corrections.refraction.Refraction.correct` at a height between the hit's and
    the camera's (its ``hit_ecef``: the bent ray's point at that height); the last is at the
    hit's own height, which on a DEM is the pipeline's fixed point (within its 1 mm).
    """
    from geoloc.geodesy.ellipsoid import ecef_to_geodetic
    from geoloc.status import Status
    from geoloc.surfaces.base import LineOfSight
    from geoloc.surfaces.height import HeightSurface

    ref = corrections.refraction
    if ref is None or int(np.asarray(hit.status)) != Status.OK or int(np.asarray(raw_hit.status)) != Status.OK:
        return None
    o = np.asarray(los.origin_ecef, float).reshape(3)
    d = np.asarray(los.direction_ecef, float).reshape(3)
    h_cam = float(ecef_to_geodetic(o)[2])
    h_hit = float(np.asarray(hit.h))
    # heights from just below the camera down to the hit; the camera itself is where both start
    H = np.linspace(h_hit, h_cam, n + 1)[::-1][1:]
    line = ref.correct(
        np.broadcast_to(o, (len(H), 3)),
        np.broadcast_to(d, (len(H), 3)),
        np.broadcast_to(np.asarray(raw_hit.ecef, float).reshape(3), (len(H), 3)),
        at_h=H,
    )
    ok = np.asarray(line.status) == Status.OK
    H = H[ok]
    bent = np.asarray(line.hit_ecef, float)[ok]
    # the straight line's points at the same heights: the pipeline without corrections, on the
    # surfaces of those constant geodetic heights
    rays = LineOfSight(np.broadcast_to(o, (len(H), 3)), np.broadcast_to(d, (len(H), 3)), np.zeros(len(H), np.uint8))
    straight = np.asarray(Pipeline(None, HeightSurface(H, "geodetic")).intersect(rays).ecef, float)
    H = np.concatenate([[h_cam], H])
    bent = np.concatenate([o[None], bent])
    straight = np.concatenate([o[None], straight])
    return BentRay(
        H, enu.from_ecef(bent), enu.from_ecef(straight), float(np.asarray(hit.refraction_m)), tuple(hit.corrections)
    )
