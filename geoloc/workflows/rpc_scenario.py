"""Rational polynomial (RPC) sensor models: fit, evaluate, write as GDAL metadata [L12 section 4.1].

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md``.

An RPC maps geodetic (latitude P, longitude L, ellipsoidal height H) to the
image: with normalised values ``Pn = (P - LAT_OFF) / LAT_SCALE`` (and the same
for L, H, line and sample),

    line_n = LINE_NUM(Ln, Pn, Hn) / LINE_DEN(Ln, Pn, Hn)
    samp_n = SAMP_NUM(Ln, Pn, Hn) / SAMP_DEN(Ln, Pn, Hn)

with four cubic polynomials of 20 terms each in the RPC00B order (the order
GDAL uses): 1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P,
P^3, PH^2, L^2H, P^2H, H^3. The two denominators' constant terms are 1, so a
model has 4 x 20 - 2 = 78 free coefficients. [L12] reports ZY-3 RPCs fitted to
the rigorous model better than 0.15 % of a pixel.

Edge units of the format: degrees for P and L, metres above the WGS-84
ellipsoid for H, and image coordinates with (0, 0) at the *centre* of the
upper-left pixel (GDAL, ``alg/gdal_rpc.cpp``, adds 0.5 to reach its own
corner-based pixel/line). So RPC line = row - 1 and RPC sample = col - 1
with this project's 1-based (row, col).

The fit is the terrain-independent one: a 3-D grid of ground points is made
by intersecting the sensor's lines of sight for a grid of pixels with several
surfaces of constant ellipsoidal height, and the coefficients are found by
linear least squares on ``NUM - x * DEN' = x`` with the denominators' weights
refined iteratively (Tao & Hu, PE&RS 67(12), 2001). Check points are a second,
staggered grid never used in the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from geoloc.frames.chain import FrameChain, Pose
from geoloc.locate import ground_to_pixel, line_of_sight, locate
from geoloc.sensors.camera import Camera
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint
from geoloc.tomlio import read_toml

#: Names of the 20 RPC00B terms, in order (L = longitude, P = latitude, H = height).
TERMS = ("1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH",
         "PLH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH")


def rpc_terms(L, P, H):
    """The 20 cubic terms of RPC00B for normalised (L, P, H), shape (..., 20)."""
    L, P, H = np.broadcast_arrays(np.asarray(L, float), np.asarray(P, float), np.asarray(H, float))
    one = np.ones_like(L)
    return np.stack([one, L, P, H, L * P, L * H, P * H, L * L, P * P, H * H,
                     P * L * H, L**3, L * P * P, L * H * H, L * L * P, P**3, P * H * H,
                     L * L * H, P * P * H, H**3], axis=-1)


@dataclass(frozen=True)
class RPCModel:
    """One RPC00B model (the 78 coefficients and 10 normalisation constants).

    Offsets and scales are in the units of the format: degrees (lat, long),
    metres (height), pixels with (0, 0) at the centre of the upper-left pixel
    (line, samp). Coefficient arrays have 20 entries; ``line_den[0]`` and
    ``samp_den[0]`` are 1.
    """

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num: np.ndarray
    line_den: np.ndarray
    samp_num: np.ndarray
    samp_den: np.ndarray
    err_bias: float = -1.0
    err_rand: float = -1.0

    def normalise(self, lat, lon, h):
        """Normalised (Ln, Pn, Hn) from latitude, longitude [rad] and height [m]."""
        lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
        dl = (lon_deg - self.long_off + 180.0) % 360.0 - 180.0  # the antimeridian, as GDAL
        return (dl / self.long_scale, (lat_deg - self.lat_off) / self.lat_scale,
                (np.asarray(h, float) - self.height_off) / self.height_scale)

    def ground_to_pixel(self, lat, lon, h):
        """Ground (lat, lon [rad], ellipsoidal h [m]) -> 1-based (row, col) by the RPC equations.

        Returns
        -------
        row, col : ndarray
        """
        T = rpc_terms(*self.normalise(lat, lon, h))
        with np.errstate(invalid="ignore", divide="ignore"):
            ln = np.einsum("...i,i->...", T, self.line_num) / np.einsum("...i,i->...", T, self.line_den)
            sn = np.einsum("...i,i->...", T, self.samp_num) / np.einsum("...i,i->...", T, self.samp_den)
        return ln * self.line_scale + self.line_off + 1.0, sn * self.samp_scale + self.samp_off + 1.0

    # ------------------------------------------------------------ GDAL I/O
    def to_gdal(self) -> dict:
        """The GDAL "RPC" metadata domain (RFC 22) as a dict of strings."""
        def f(v):
            return f"{float(v):.15g}"

        md = {k.upper(): f(getattr(self, k)) for k in (
            "line_off", "samp_off", "lat_off", "long_off", "height_off",
            "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale",
            "err_bias", "err_rand")}
        for k in ("line_num", "line_den", "samp_num", "samp_den"):
            md[f"{k.upper()}_COEFF"] = " ".join(f(v) for v in getattr(self, k))
        return md

    def to_rasterio(self):
        """A :class:`rasterio.rpc.RPC` (for ``dataset.rpcs = ...`` and ``RPCTransformer``)."""
        from rasterio.rpc import RPC

        return RPC.from_gdal(self.to_gdal())

    @classmethod
    def from_rasterio(cls, rpc) -> "RPCModel":
        return cls(rpc.line_off, rpc.samp_off, rpc.lat_off, rpc.long_off, rpc.height_off,
                   rpc.line_scale, rpc.samp_scale, rpc.lat_scale, rpc.long_scale, rpc.height_scale,
                   np.asarray(rpc.line_num_coeff, float), np.asarray(rpc.line_den_coeff, float),
                   np.asarray(rpc.samp_num_coeff, float), np.asarray(rpc.samp_den_coeff, float),
                   -1.0 if rpc.err_bias is None else rpc.err_bias,
                   -1.0 if rpc.err_rand is None else rpc.err_rand)


# ------------------------------------------------------------------ sensors
@dataclass(frozen=True)
class FrameCameraSensor:
    """The aircraft frame camera of [Q17] (one pose) seen as a generic sensor model.

    Gives the interface the RPC fit uses (``rows``, ``cols``, ``line_of_sight``,
    ``locate``, ``ground_to_pixel``) on top of :mod:`geoloc.locate`.
    """

    pose: Pose
    camera: Camera
    chain: FrameChain | None = None
    name: str = ""

    @property
    def rows(self) -> int:
        return self.camera.rows

    @property
    def cols(self) -> int:
        return self.camera.cols

    def line_of_sight(self, row, col):
        return line_of_sight(self.pose, self.camera, row, col, chain=self.chain)

    def locate(self, row, col, target_h=0.0, surface: str = "geodetic") -> GroundPoint:
        """Exact constant-geodetic-height surface by default (RPC heights are geodetic)."""
        return locate(self.pose, self.camera, row, col, target_h, surface=surface, chain=self.chain)

    def ground_to_pixel(self, lat, lon, h):
        return ground_to_pixel(self.pose, self.camera, lat, lon, h, chain=self.chain)

    def in_image(self, row, col):
        return self.camera.in_image(row, col)


# ---------------------------------------------------------------------- fit
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


def _grid_points(sensor, n_rows, n_cols, heights, staggered=False):
    """Pixels on a regular grid spanning the image and the ground points at each height."""
    if staggered:  # cell centres of the fit grid
        fr = (np.arange(n_rows) + 0.5) / n_rows
        fc = (np.arange(n_cols) + 0.5) / n_cols
    else:
        fr = np.linspace(0.0, 1.0, n_rows)
        fc = np.linspace(0.0, 1.0, n_cols)
    rows = 0.5 + fr * sensor.rows
    cols = 0.5 + fc * sensor.cols
    R, C, Hh = np.meshgrid(rows, cols, np.asarray(heights, float), indexing="ij")
    g = sensor.locate(R.ravel(), C.ravel(), Hh.ravel())
    ok = g.status == Status.OK
    return R.ravel()[ok], C.ravel()[ok], g.lat[ok], g.lon[ok], g.h[ok], int(np.sum(~ok))


def _solve_ratio(T, x, n_iter=4, ridge=1e-12):
    """Least squares for NUM(T)/DEN(T) = x, DEN[0] = 1 (Tao & Hu 2001 iterative weights).

    Linearised: T a - x (T' b') = x, with weights 1 / DEN(T)^2 from the previous
    solution. Columns are scaled to unit norm and a tiny ridge (relative
    1e-12) keeps the near-degenerate directions (a frame camera is almost a
    ratio of linear forms) from blowing up the coefficients.
    """
    M = np.hstack([T, -x[:, None] * T[:, 1:]])
    w = np.ones(len(x))
    coef = None
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


def fit_rpc(sensor, height_min, height_max, grid=(21, 21, 7), check_grid=(20, 20, 6)) -> RPCFit:
    """Fit the 78 RPC coefficients to a sensor model over a 3-D grid [L12 section 4.1].

    Parameters
    ----------
    sensor : PushbroomSensor or FrameCameraSensor
        Anything with ``rows``, ``cols``, ``locate(row, col, h)`` and
        ``ground_to_pixel(lat, lon, h)``.
    height_min, height_max : float
        Ellipsoidal height range of the fit [m] (the terrain's range plus a margin).
    grid : (int, int, int)
        Fit points: pixel rows x pixel columns x height layers, spanning the
        image edges and the height range. At least 39 points are needed per
        image axis; the default (3087) is the usual generous choice.
    check_grid : (int, int, int)
        Check points: a staggered grid (cell centres of a grid this size, and
        heights between the fit layers), never used in the fit.

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
    r, c, lat, lon, h, lost = _grid_points(sensor, grid[0], grid[1], hs)
    if lost or r.size < 39:
        raise ValueError(f"{lost} fit-grid pixels have no ground point (rays missing the surface); "
                         "check the sensor geometry and height range")
    lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
    lon_mid = np.rad2deg(np.arctan2(np.mean(np.sin(lon)), np.mean(np.cos(lon))))
    dlon = (lon_deg - lon_mid + 180.0) % 360.0 - 180.0
    lat_off = 0.5 * (lat_deg.max() + lat_deg.min())
    long_off = lon_mid + 0.5 * (dlon.max() + dlon.min())
    model0 = dict(
        line_off=(sensor.rows - 1) / 2.0, samp_off=(sensor.cols - 1) / 2.0,
        lat_off=lat_off, long_off=(long_off + 180.0) % 360.0 - 180.0,
        height_off=0.5 * (height_min + height_max),
        line_scale=sensor.rows / 2.0, samp_scale=sensor.cols / 2.0,
        lat_scale=0.5 * (lat_deg.max() - lat_deg.min()),
        long_scale=0.5 * (dlon.max() - dlon.min()),
        height_scale=0.5 * (height_max - height_min),
    )
    tmp = RPCModel(**model0, line_num=np.zeros(20), line_den=np.eye(20)[0],
                   samp_num=np.zeros(20), samp_den=np.eye(20)[0])
    T = rpc_terms(*tmp.normalise(lat, lon, h))
    ln = (r - 1.0 - model0["line_off"]) / model0["line_scale"]
    sn = (c - 1.0 - model0["samp_off"]) / model0["samp_scale"]
    lnum, lden = _solve_ratio(T, ln)
    snum, sden = _solve_ratio(T, sn)
    model = RPCModel(**model0, line_num=lnum, line_den=lden, samp_num=snum, samp_den=sden)

    rr, cc = model.ground_to_pixel(lat, lon, h)
    res_fit = np.hypot(rr - r, cc - c)
    hs_c = height_min + (np.arange(check_grid[2]) + 0.5) / check_grid[2] * (height_max - height_min)
    r2, c2, lat2, lon2, h2, _ = _grid_points(sensor, check_grid[0], check_grid[1], hs_c, staggered=True)
    rr2, cc2 = model.ground_to_pixel(lat2, lon2, h2)
    res = np.stack([rr2 - r2, cc2 - c2], axis=-1)
    d = np.hypot(res[:, 0], res[:, 1])
    return RPCFit(model, float(np.sqrt(np.mean(res_fit**2))), float(res_fit.max()),
                  float(np.sqrt(np.mean(d**2))), float(d.max()), int(r.size), int(r2.size), res)


# --------------------------------------------------------------- GeoTIFF I/O
def write_rpc_geotiff(path, model: RPCModel, rows: int, cols: int, image=None) -> Path:
    """Write a GeoTIFF carrying ``model`` as GDAL RPC metadata (the TIFF RPC tag).

    Parameters
    ----------
    path : path-like
    model : RPCModel
    rows, cols : int
        Image size (lines, samples).
    image : ndarray (rows, cols) of uint16, optional
        Pixel values. Without it the file is written sparse (no tile is
        stored; readers see zeros), so a 24 576 x 24 576 scene costs ~150 kB.

    Returns
    -------
    Path
    """
    import rasterio

    path = Path(path)
    profile = dict(driver="GTiff", width=int(cols), height=int(rows), count=1, dtype="uint16",
                   tiled=True, blockxsize=256, blockysize=256, compress="deflate",
                   SPARSE_OK=True)
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        # raised at creation, before the RPCs below are attached: not true of the file written
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as dst:
            dst.rpcs = model.to_rasterio()
            if image is not None:
                dst.write(np.asarray(image, np.uint16), 1)
    return path


def read_rpc_geotiff(path) -> RPCModel:
    """Read the RPC metadata of a raster back into an :class:`RPCModel`."""
    import rasterio

    with rasterio.open(path) as src:
        if src.rpcs is None:
            raise ValueError(f"{path}: no RPC metadata")
        return RPCModel.from_rasterio(src.rpcs)


# ------------------------------------------------------------------- GDAL
def gdal_rpc_to_ground(model: RPCModel, row, col, *, dem_path=None, height=0.0,
                       pixel_error_threshold=None, max_iterations=None, vdatum_shift=False):
    """Pixel -> ground with GDAL's RPC transformer (through rasterio).

    With ``dem_path`` the GDAL option ``RPC_DEM`` is set: GDAL then treats
    ``height`` as an *offset above the DEM* (not an absolute height) and uses
    the DEM's values as heights above the WGS-84 ellipsoid unless the DEM's
    CRS has a vertical component and ``RPC_DEM_APPLY_VDATUM_SHIFT`` is on.
    This function sets that option explicitly (``vdatum_shift``, default
    off): give it a DEM whose values are already ellipsoidal (see
    :func:`write_ellipsoidal_dem`).

    Parameters
    ----------
    model : RPCModel
    row, col : array_like
        1-based pixels of this project (converted to rasterio's 0-based
        indices with ``offset="center"``: GDAL pixel = col - 0.5, RPC sample = col - 1).
    dem_path : path-like, optional
        ``RPC_DEM``.
    height : float
        Height [m]: above the DEM with ``dem_path``, else ellipsoidal.
    pixel_error_threshold : float, optional
        ``RPC_PIXEL_ERROR_THRESHOLD`` (GDAL's default 0.1 pixel if None).
    max_iterations : int, optional
        ``RPC_MAX_ITERATIONS`` (GDAL's default 20 with a DEM, 10 without).

    Returns
    -------
    lat, lon : ndarray
        Radians; NaN where GDAL reports a failed transform.
    """
    import rasterio
    from rasterio.transform import RPCTransformer

    row = np.atleast_1d(np.asarray(row, float))
    col = np.atleast_1d(np.asarray(col, float))
    opts = {}
    if dem_path is not None:
        opts["RPC_DEM"] = str(dem_path)
        opts["RPC_DEMINTERPOLATION"] = "bilinear"
        opts["RPC_DEM_APPLY_VDATUM_SHIFT"] = "TRUE" if vdatum_shift else "FALSE"
    if pixel_error_threshold is not None:
        opts["RPC_PIXEL_ERROR_THRESHOLD"] = repr(float(pixel_error_threshold))
    if max_iterations is not None:
        opts["RPC_MAX_ITERATIONS"] = str(int(max_iterations))
    zs = np.full(row.shape, float(height))
    # the Env registers GDAL's drivers, which RPC_DEM needs to open its file
    with rasterio.Env(), RPCTransformer(model.to_rasterio(), **opts) as tr:
        lons, lats = [], []
        for i in range(row.size):  # one call per point so that a failure only loses that point
            try:
                x, y = tr.xy(row[i] - 1.0, col[i] - 1.0, zs=zs[i], offset="center")
            except Exception:  # rasterio raises on a failed GDAL transform
                x, y = np.nan, np.nan
            lons.append(float(x))
            lats.append(float(y))
    return np.deg2rad(np.asarray(lats)), np.deg2rad(np.asarray(lons))


# ------------------------------------------------------- GDAL RPC_DEM check
def write_ellipsoidal_dem(dem, path) -> Path:
    """Write a geoloc DEM's *ellipsoidal* node heights as a plain EPSG:4326 GeoTIFF.

    GDAL's RPC transformer uses ``RPC_DEM`` values as heights above the WGS-84
    ellipsoid unless the DEM's CRS carries a vertical datum (and
    ``RPC_DEM_APPLY_VDATUM_SHIFT`` is on, and its PROJ finds the geoid grid).
    The bundled DEMs are orthometric (EGM96) with a 2-D CRS, so GDAL would use
    H instead of h = H + N. This copy holds h (the nodes of
    :class:`geoloc.surfaces.dem.DEM`, where N was added node by node), on the same
    pixel-centre nodes, so GDAL's bilinear sampling equals the project's.

    Parameters
    ----------
    dem : geoloc.surfaces.dem.DEM
        A geographic (lat/lon) DEM.
    path : path-like

    Returns
    -------
    Path
    """
    import rasterio
    from affine import Affine

    if not dem.is_geographic:
        raise ValueError(f"DEM {dem.path}: RPC_DEM copy needs a geographic (lat/lon) grid, got {dem.crs}")
    g = dem.grid
    v = np.asarray(g.values, float)
    t = Affine(g.dlon_deg, 0.0, g.lon_west_deg - g.dlon_deg / 2, 0.0, -g.dlat_deg, g.lat_north_deg + g.dlat_deg / 2)
    path = Path(path)
    with rasterio.open(path, "w", driver="GTiff", width=v.shape[1], height=v.shape[0], count=1,
                       dtype="float64", crs="EPSG:4326", transform=t, nodata=np.nan) as dst:
        dst.write(v, 1)
        dst.update_tags(VERTICAL_DATUM="WGS-84 ellipsoidal heights (h = H + N, EGM96)",
                        SOURCE=str(dem.path))
    return path


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


def dem_pixels(sensor, dem, grid=(12, 12), margin=0.05):
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
    R, C = np.meshgrid(np.linspace(r0 + dr, r1 - dr, grid[0]), np.linspace(c0 + dc, c1 - dc, grid[1]),
                       indexing="ij")
    return R.ravel(), C.ravel()


def crosscheck_gdal_dem(sensor, model: RPCModel, dem, dem_path_for_gdal, row, col, *,
                        pixel_error_threshold=1e-6, max_iterations=100) -> DemCrossCheck:
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
    from geoloc.surfaces.terrain import intersect_dem

    row, col = np.broadcast_arrays(np.asarray(row, float).ravel(), np.asarray(col, float).ravel())
    hit = intersect_dem(sensor.line_of_sight(row, col), dem, method="exact")
    ok = hit.status == Status.OK
    row, col = row[ok], col[ok]
    lat_e, lon_e, h_e, p_e = hit.lat[ok], hit.lon[ok], hit.h[ok], hit.ecef[ok]
    lat_g, lon_g = gdal_rpc_to_ground(model, row, col, dem_path=dem_path_for_gdal, height=0.0,
                                      pixel_error_threshold=pixel_error_threshold,
                                      max_iterations=max_iterations)
    h_g = dem.height(lat_g, lon_g)
    r_g, c_g, st = sensor.ground_to_pixel(lat_g, lon_g, h_g)
    err_px = np.where(st == Status.OK, np.hypot(r_g - row, c_g - col), np.nan)
    err_m = np.linalg.norm(geodetic_to_ecef(lat_g, lon_g, h_g) - p_e, axis=-1)
    opts = {"RPC_DEM": str(dem_path_for_gdal), "RPC_DEMINTERPOLATION": "bilinear",
            "RPC_DEM_APPLY_VDATUM_SHIFT": "FALSE", "RPC_HEIGHT": "0 (zs = 0 above the DEM)",
            "RPC_PIXEL_ERROR_THRESHOLD": pixel_error_threshold, "RPC_MAX_ITERATIONS": max_iterations}
    return DemCrossCheck(row, col, lat_e, lon_e, h_e, lat_g, lon_g, err_px, err_m,
                         int(np.sum(~np.isfinite(lat_g))), opts)


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
    """

    name: str
    kind: str
    sensor: object
    height_min: float
    height_max: float
    grid: tuple
    check_grid: tuple
    dem_path: Path | None
    dem_datum: str
    cross_check_grid: tuple


def _resolve(rel: str, base: Path, field_name: str) -> Path:
    from geoloc.assets import ASSETS

    p = Path(rel)
    for cand in ((p,) if p.is_absolute() else (base / p, ASSETS / p)):
        if cand.exists():
            return cand
    raise FileNotFoundError(f"{field_name} = {rel!r}: not found (tried beside the scenario and in {ASSETS})")


def _int_tuple(d, key, n, default, source):
    v = d.get(key, default)
    if (not isinstance(v, (list, tuple)) or len(v) != n
            or any(isinstance(x, bool) or not isinstance(x, int) or x < 2 for x in v)):
        raise ValueError(f"{source}: {key} = {v!r} must be {n} integers >= 2")
    return tuple(v)


def load_scenario(path) -> RPCScenario:
    """Read an RPC scenario file (``assets/scenarios/zy3_nadir.toml``, ``qiao2017_frame.toml``).

    Format: docs/rpc.md. Errors name the file, the table and the key.
    """
    from geoloc.sensors.pushbroom import PushbroomSensor

    path = Path(path)
    data = read_toml(path, "scenario file")
    src = str(path)
    kind = data.get("kind")
    if kind == "pushbroom":
        sensor = PushbroomSensor.from_dict(data, source=src)
    elif kind == "frame":
        cam_rel = data.get("camera")
        if not isinstance(cam_rel, str):
            raise ValueError(f"{src}: camera = {cam_rel!r} must be the path of a camera file")
        camera = Camera.from_toml(_resolve(cam_rel, path.parent, f"{src}: camera"))
        pose_d = data.get("pose")
        if not isinstance(pose_d, dict):
            raise ValueError(f"{src}: missing table [pose]")
        allowed = ("lat_deg", "lon_deg", "h_m", "heading_deg", "pitch_deg", "roll_deg",
                   "gimbal_roll_deg", "gimbal_pitch_deg")
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
    return RPCScenario(str(data.get("name", path.stem)), kind, sensor, hr[0], hr[1], grid, check,
                       dem_path, datum, cc)


def rpc_report(scenario: RPCScenario, out_tif, *, gdal: bool = True, pixel_error_threshold: float = 1e-6,
               dem_copy=None) -> dict:
    """Fit, write and cross-check the RPC of a scenario: what ``geoloc rpc`` reports.

    Parameters
    ----------
    scenario : RPCScenario
    out_tif : path-like
        GeoTIFF to write (RPC metadata, sparse pixels).
    gdal : bool
        Run the GDAL RPC_DEM cross-check (needs ``scenario.dem_path``).
    pixel_error_threshold : float
        GDAL's ``RPC_PIXEL_ERROR_THRESHOLD`` for the main figure [px].
    dem_copy : path-like, optional
        Where to keep the ellipsoidal-height DEM given to GDAL (default: a
        temporary file, deleted).

    Returns
    -------
    dict
        JSON-ready: ``fit_rms_px``, ``check_rms_px``, ``check_max_px``,
        ``gdal_vs_exact_max_px`` and the supporting figures (docs/rpc.md).
    """
    import tempfile

    s = scenario.sensor
    fit = fit_rpc(s, scenario.height_min, scenario.height_max, scenario.grid, scenario.check_grid)
    write_rpc_geotiff(out_tif, fit.model, s.rows, s.cols)
    rep = {
        "scenario": scenario.name, "kind": scenario.kind, "image": str(out_tif),
        "rows": int(s.rows), "cols": int(s.cols),
        "height_range_m": [scenario.height_min, scenario.height_max],
        "n_fit": fit.n_fit, "n_check": fit.n_check,
        "fit_rms_px": fit.fit_rms_px, "fit_max_px": fit.fit_max_px,
        "check_rms_px": fit.check_rms_px, "check_max_px": fit.check_max_px,
    }
    if not gdal or scenario.dem_path is None:
        rep["gdal_vs_exact_max_px"] = None
        rep["gdal_note"] = "skipped" if not gdal else "no [dem] in the scenario"
        return rep
    from geoloc.surfaces.dem import DEM

    dem = DEM.open(scenario.dem_path, datum=scenario.dem_datum)
    rows, cols = dem_pixels(s, dem, scenario.cross_check_grid)
    with tempfile.TemporaryDirectory() as tmp:
        ell = Path(dem_copy) if dem_copy is not None else Path(tmp) / "dem_ellipsoidal.tif"
        write_ellipsoidal_dem(dem, ell)
        cc = crosscheck_gdal_dem(s, fit.model, dem, ell, rows, cols,
                                 pixel_error_threshold=pixel_error_threshold)
        cc_default = crosscheck_gdal_dem(s, fit.model, dem, ell, cc.row, cc.col,
                                         pixel_error_threshold=None, max_iterations=None)
    # GDAL's default handling of the bundled file: orthometric values taken as ellipsoidal
    cc_raw = crosscheck_gdal_dem(s, fit.model, dem, scenario.dem_path, cc.row, cc.col,
                                 pixel_error_threshold=pixel_error_threshold)
    rep.update({
        "gdal_vs_exact_max_px": cc.max_px, "gdal_vs_exact_rms_px": cc.rms_px,
        "gdal_vs_exact_max_m": cc.max_m, "gdal_points": int(cc.row.size), "gdal_failed": cc.n_failed,
        "gdal_options": {k: str(v) for k, v in cc.options.items() if k != "RPC_DEM"},
        "gdal_default_threshold_max_px": cc_default.max_px,
        "gdal_orthometric_dem_max_px": cc_raw.max_px, "gdal_orthometric_dem_max_m": cc_raw.max_m,
        "dem": str(scenario.dem_path), "dem_datum": scenario.dem_datum,
    })
    if dem_copy is not None:
        rep["ellipsoidal_dem"] = str(dem_copy)
    return rep


__all__ = ["TERMS", "DemCrossCheck", "FrameCameraSensor", "RPCFit", "RPCModel", "RPCScenario",
           "crosscheck_gdal_dem", "dem_pixels", "fit_rpc", "gdal_rpc_to_ground", "load_scenario",
           "read_rpc_geotiff", "rpc_report", "rpc_terms", "write_ellipsoidal_dem", "write_rpc_geotiff"]
