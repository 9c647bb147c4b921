"""Digital elevation models on rasterio: bilinear heights above the WGS-84 ellipsoid.

A :class:`DEM` is a grid of *nodes* (the raster's pixel centres) with
bilinear interpolation between the four nodes of each cell (``docs/method.md``
section 4). Heights are converted once, node by node, to ellipsoidal heights:
real DEMs are orthometric (``datum="egm96"``: h = H + N with the bundled EGM96
grid, :func:`geoloc.geodesy.geoid.egm96_undulation`); synthetic ones may already be
ellipsoidal (``datum="ellipsoid"``).

A raster covers half a pixel more than its node hull on each side; GDAL samples
that band, and so does a DEM read with :meth:`DEM.open`: there the edge nodes'
values continue (``NodeGrid.margin = 0.5``). The exact solver of
:mod:`geoloc.surfaces.terrain` walks the cells between nodes, so its hits stay
inside the node hull.

Any CRS: :meth:`DEM.open` warps a raster in a projected CRS to a geographic
(EPSG:4326) grid of about the same resolution, each new node the source's
bilinear height at that point (``docs/terrain.md`` states the error this adds
between the nodes), so that every solver, ``exact`` included, works on it.
:meth:`DEM.from_array` and ``DEM.open(..., geographic=False)`` keep a projected
grid: queries are then transformed from geodetic WGS-84 to the grid's CRS with
pyproj; the iterative solvers work with it, the exact walk needs
:meth:`DEM.to_geographic` first.

Conventions: ``docs/conventions.md`` (radians inside; ``_deg`` only at edges).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.extras import require
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.geodesy.geoid import NodeGrid, egm96_undulation
from geoloc.status import Status
from geoloc.userfiles import note_input

if TYPE_CHECKING:
    from geoloc.frames.enu import EnuFrame

DATUMS = ("egm96", "ellipsoid")


def _check_datum(datum):
    if datum not in DATUMS:
        raise ValueError(f"datum must be one of {DATUMS}, got {datum!r}")


class DEM:
    """A DEM as a node grid of ellipsoidal heights with bilinear sampling.

    Build with :meth:`open` (a raster file) or :meth:`from_array` (synthetic).

    Attributes
    ----------
    grid : geoloc.geodesy.geoid.NodeGrid
        Ellipsoidal node heights [m] (NaN = no data), in the DEM's CRS
        coordinates (degrees for geographic CRS: ``lat_north_deg`` is the
        y of row 0, ``lon_west_deg`` the x of column 0).
    orthometric : ndarray or None
        The heights as read (before adding N), for ``datum="egm96"``.
    crs : pyproj.CRS
        Horizontal CRS of the grid.
    datum : {"egm96", "ellipsoid"}
        Vertical datum of the source heights.
    path : str or None
        Source file.
    """

    #: The exact walk's tables, made on first use and kept with the DEM
    #: (:func:`geoloc.surfaces.terrain._exact_tables`; absent until then).
    _exact_tables: dict

    def __init__(
        self,
        grid: NodeGrid,
        crs: Any = None,
        datum: str = "ellipsoid",
        orthometric: np.ndarray | None = None,
        path: str | os.PathLike[str] | None = None,
    ):
        import pyproj

        _check_datum(datum)
        self.grid = grid
        self.crs = pyproj.CRS.from_user_input(crs if crs is not None else "EPSG:4326")
        self.datum = datum
        self.orthometric = orthometric
        self.path = path
        self.is_geographic = bool(self.crs.is_geographic)
        self._to_crs = None
        if not self.is_geographic:
            self._to_crs = pyproj.Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)
            self._from_crs = pyproj.Transformer.from_crs(self.crs, "EPSG:4326", always_xy=True)
        self._cell_max: np.ndarray | None = None
        self._has_data: bool | None = None
        self._surface_range = None  # (lowest, highest) of the surface a window is cut from (from_grid)
        #: The CRS of the file before :meth:`to_geographic` warped it (WKT), or None.
        self.source_crs = None

    # ------------------------------------------------------------------ building
    @classmethod
    def open(cls, path: str | os.PathLike[str], datum: str = "egm96", band: int = 1, geographic: bool = True) -> "DEM":
        """Read a north-up raster (GeoTIFF, any GDAL format) with rasterio.

        Parameters
        ----------
        path : path-like
            Raster file; its pixel centres are taken as the nodes, and the grid
            is defined up to the raster's outer edge (half a pixel beyond the
            outer nodes, the edge values continued there, as GDAL samples it).
        datum : {"egm96", "ellipsoid"}
            Vertical datum of the file's heights. Real DEMs (SRTM, ASTER,
            ETOPO) are orthometric: "egm96" (the default) adds N.
        band : int
            Band to read.
        geographic : bool
            A raster in a projected CRS is warped to a geographic grid
            (:meth:`to_geographic`) unless this is False.

        Raises
        ------
        FileNotFoundError
            No such file.
        ValueError
            A folder, a file GDAL cannot read, a raster without georeferencing
            (no geotransform or no CRS), a rotated or south-up raster, a bad
            datum or band. The message names the file and what is wrong.
        """

        import rasterio
        from rasterio.errors import NotGeoreferencedWarning, RasterioError

        _check_datum(datum)
        path = Path(path)
        if path.is_dir():
            raise ValueError(f"DEM {path} is a folder, not a raster file: give the DEM file itself (e.g. a GeoTIFF)")
        if not path.is_file():
            raise FileNotFoundError(f"DEM file not found: {path}")
        note_input(path)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path) as src:
                    t, crs = src.transform, src.crs
                    if crs is None and t.is_identity:
                        raise ValueError(
                            f"DEM {path} ({src.driver}) has no georeferencing: neither a "
                            "geotransform nor a CRS; a DEM must say where its pixels are "
                            "(e.g. a GeoTIFF, or a world file and .prj beside the image)"
                        )
                    if crs is None:
                        raise ValueError(
                            f"DEM {path}: the file has no CRS (its geotransform "
                            "alone does not say which coordinates it uses)"
                        )
                    if t.is_identity:
                        raise ValueError(
                            f"DEM {path}: the file has a CRS but no geotransform (pixel positions unknown)"
                        )
                    if t.b != 0 or t.d != 0:
                        raise ValueError(
                            f"DEM {path}: transform {tuple(t)[:6]} is rotated, "
                            "not north-up (warp it to a north-up grid, e.g. "
                            "gdalwarp)"
                        )
                    if t.e >= 0:
                        raise ValueError(
                            f"DEM {path}: transform {tuple(t)[:6]} is south-up "
                            "(row 0 at the south edge), not north-up (flip it, "
                            "e.g. gdalwarp)"
                        )
                    if not 1 <= band <= src.count:
                        raise ValueError(f"DEM {path}: band {band} requested, the file has {src.count}")
                    if min(src.height, src.width) < 2:
                        raise ValueError(f"DEM {path}: {src.height} x {src.width} pixels; a DEM needs at least 2 x 2")
                    v = src.read(band, masked=True).astype(float).filled(np.nan)
                    crs = crs.to_wkt()
        except RasterioError as e:
            raise ValueError(f"DEM {path}: not a raster that GDAL can read ({e})") from None
        grid = NodeGrid(v, t.f + t.e / 2, t.c + t.a / 2, -t.e, t.a, str(path), margin=0.5)
        source_crs = None
        if geographic:
            import pyproj

            if not pyproj.CRS.from_user_input(crs).is_geographic:
                source_crs = crs
                grid, crs = _warp_to_geographic(grid, crs), "EPSG:4326"
        dem = cls._with_datum(grid, crs, datum, str(path))
        dem.source_crs = source_crs
        return dem

    def to_geographic(self) -> "DEM":
        """This DEM on a geographic (EPSG:4326) grid; itself if it is geographic already.

        The nodes form the north-up grid that ``rasterio.warp.calculate_default_transform``
        chooses for the source's extent (about the source's resolution); each node's
        height is the source's bilinear height at that point (orthometric heights are
        warped and N added at the new nodes). Nodes outside the source footprint have
        no data. Between nodes the result differs from the source by the change of
        interpolation grid: measured in ``docs/terrain.md``.
        """
        if self.is_geographic:
            return self
        src = (
            self.grid
            if self.orthometric is None
            else NodeGrid(
                self.orthometric,
                self.grid.lat_north_deg,
                self.grid.lon_west_deg,
                self.grid.dlat_deg,
                self.grid.dlon_deg,
                self.grid.path,
                self.grid.margin,
            )
        )
        crs = self.crs.to_wkt()
        dem = self._with_datum(_warp_to_geographic(src, crs), "EPSG:4326", self.datum, self.path)
        dem.source_crs = crs
        return dem

    @classmethod
    def from_array(
        cls,
        heights: ArrayLike,
        lat_north_deg: float,
        lon_west_deg: float,
        dlat_deg: float,
        dlon_deg: float,
        datum: str = "ellipsoid",
        nodata: float | None = None,
        crs: Any = "EPSG:4326",
    ) -> "DEM":
        """A DEM from an array of node heights (row 0 north), e.g. synthetic terrain.

        Parameters
        ----------
        heights : array_like (nrows, ncols)
            Node heights [m]; at least 2 x 2.
        lat_north_deg, lon_west_deg : float
            Position of node (0, 0) [deg] (CRS units for a projected ``crs``).
        dlat_deg, dlon_deg : float
            Positive node spacings [deg]; rows go south, columns east.
        datum : {"ellipsoid", "egm96"}
            Vertical datum of ``heights``.
        nodata : float, optional
            Value marking missing nodes (NaN always does).
        """
        _check_datum(datum)
        h = np.array(heights, dtype=float)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"heights must be a 2-D array of at least 2 x 2 nodes, got shape {h.shape}")
        for name, val in (("dlat_deg", dlat_deg), ("dlon_deg", dlon_deg)):
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a positive spacing, got {val!r}")
        if nodata is not None:
            h[h == nodata] = np.nan
        grid = NodeGrid(h, float(lat_north_deg), float(lon_west_deg), float(dlat_deg), float(dlon_deg))
        return cls._with_datum(grid, crs, datum, None)

    @classmethod
    def from_grid(
        cls,
        grid: NodeGrid,
        crs: Any = "EPSG:4326",
        datum: str = "egm96",
        path: str | os.PathLike[str] | None = None,
        height_range_m: tuple[float, float] | None = None,
    ) -> "DEM":
        """A DEM from a :class:`~geoloc.geodesy.geoid.NodeGrid` of heights as read (a window of a file).

        The heights are converted to ellipsoidal node by node exactly as :meth:`open`
        does (``datum="egm96"`` adds the bundled EGM96 N at each node), so a window
        cut from a raster gives, node for node, the heights of the whole raster
        opened with :meth:`open` (:mod:`geoloc.surfaces.mosaic` builds its regions so).

        Parameters
        ----------
        height_range_m : (float, float), optional
            (lowest, highest) ellipsoidal height [m] of the whole surface the window
            is cut from: :meth:`min_height` / :meth:`max_height` without a region
            return them (the H_max and H_min where the solvers start and stop), so
            that a window gives the same hits as the whole surface. They must bound
            the window's own nodes (ValueError otherwise).
        """
        _check_datum(datum)
        dem = cls._with_datum(grid, crs, datum, None if path is None else str(path))
        if height_range_m is not None:
            lo, hi = (float(x) for x in height_range_m)
            v = dem.grid.values
            if np.isfinite(v).any() and not (lo <= np.nanmin(v) and np.nanmax(v) <= hi):
                raise ValueError(
                    f"height_range_m = {height_range_m!r} does not bound the window's nodes "
                    f"({np.nanmin(v):.3f} to {np.nanmax(v):.3f} m)"
                )
            dem._surface_range = (lo, hi)
        return dem

    @classmethod
    def _with_datum(cls, grid, crs, datum, path):
        dem = cls(grid, crs=crs, datum=datum, path=path)
        if datum == "egm96":
            lat_deg, lon_deg = dem.node_latlon_deg()
            n = egm96_undulation(np.deg2rad(lat_deg), np.deg2rad(lon_deg))
            ortho = grid.values
            grid = NodeGrid(
                ortho + n, grid.lat_north_deg, grid.lon_west_deg, grid.dlat_deg, grid.dlon_deg, grid.path, grid.margin
            )
            dem = cls(grid, crs=crs, datum=datum, orthometric=ortho, path=path)
        return dem

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple:
        """(nrows, ncols) of nodes."""
        return self.grid.values.shape

    def node_latlon_deg(self) -> tuple[np.ndarray, np.ndarray]:
        """Geodetic latitude and longitude [deg] of every node, each (nrows, ncols)."""
        g = self.grid
        nr, nc = self.shape
        y = g.lat_north_deg - g.dlat_deg * np.arange(nr)
        x = g.lon_west_deg + g.dlon_deg * np.arange(nc)
        X, Y = np.meshgrid(x, y)
        if self.is_geographic:
            return Y, X
        lon, lat = self._from_crs.transform(X, Y)
        return np.asarray(lat), np.asarray(lon)

    def _xy(self, lat, lon):
        """Geodetic [rad] -> grid CRS coordinates (y, x)."""
        lat_deg = np.rad2deg(np.asarray(lat, float))
        lon_deg = np.rad2deg(np.asarray(lon, float))
        if self.is_geographic:
            g = self.grid
            # bring the longitude to the grid's 360-degree window
            lon_deg = (lon_deg - g.lon_west_deg + 180.0) % 360.0 + g.lon_west_deg - 180.0
            return lat_deg, lon_deg
        x, y = self._to_crs.transform(lon_deg, lat_deg)
        return np.asarray(y), np.asarray(x)

    @property
    def bounds_deg(self) -> tuple:
        """(west, south, east, north) [deg] of the node hull, where heights are defined.

        For a projected CRS: the geodetic bounding box of the hull (pyproj
        ``transform_bounds``).
        """
        g = self.grid
        w, s, e, n = g.lon_west_deg, g.lat_south_deg, g.lon_east_deg, g.lat_north_deg
        if self.is_geographic:
            return (w, s, e, n)
        return tuple(self._from_crs.transform_bounds(w, s, e, n))

    @property
    def extent_deg(self) -> tuple:
        """(west, south, east, north) [deg] where :meth:`sample` gives heights.

        The node hull grown by ``grid.margin`` cells: for a raster read with
        :meth:`open`, the raster's outer edges. Geodetic bounding box for a
        projected CRS.
        """
        g = self.grid
        mx, my = g.margin * g.dlon_deg, g.margin * g.dlat_deg
        w, s, e, n = g.lon_west_deg - mx, g.lat_south_deg - my, g.lon_east_deg + mx, g.lat_north_deg + my
        if self.is_geographic:
            return (w, s, e, n)
        return tuple(self._from_crs.transform_bounds(w, s, e, n))

    # ------------------------------------------------------------------ sampling
    def sample(self, lat: ArrayLike, lon: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Ellipsoidal height and status at geodetic points.

        Parameters
        ----------
        lat, lon : array_like
            Geodetic latitude and longitude [rad], broadcasting.

        Returns
        -------
        h : ndarray
            Bilinear ellipsoidal height [m]; NaN outside :attr:`extent_deg` or
            where a node of the cell has no data.
        status : ndarray of uint8
            OK, LEFT_DEM (outside), NODATA, or INVALID_INPUT (non-finite).
        """
        lat, lon = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float))
        y, x = self._xy(lat, lon)
        finite = np.isfinite(y) & np.isfinite(x)
        inside = finite & self.grid.contains(y, x)
        h = self.grid.interp(y, x)
        status = np.full(lat.shape, Status.OK, dtype=np.uint8)
        status[~finite] = Status.INVALID_INPUT
        status[finite & ~inside] = Status.LEFT_DEM
        status[inside & ~np.isfinite(h)] = Status.NODATA
        return np.where(status == Status.OK, h, np.nan), status

    def height(self, lat: ArrayLike, lon: ArrayLike) -> np.ndarray:
        """Bilinear ellipsoidal height [m] at geodetic (lat, lon) [rad]; NaN outside / no data."""
        return self.sample(lat, lon)[0]

    def _region_nodes(self, region):
        v = self.grid.values
        if region is None:
            return v
        w, s, e, n = (float(x) for x in region)
        if not (w <= e and s <= n):
            raise ValueError(f"region must be (west, south, east, north) in degrees, got {region!r}")
        if not self.is_geographic:
            xs, ys = self._to_crs.transform([w, e, w, e], [s, s, n, n])
            w, e, s, n = min(xs), max(xs), min(ys), max(ys)
        g = self.grid
        r0, c0 = g.grid_coords(n, w)
        r1, c1 = g.grid_coords(s, e)
        nr, nc = v.shape
        # nodes of every cell that touches the region: an upper/lower bound of the bilinear surface
        i0, i1 = int(np.clip(np.floor(r0), 0, nr - 1)), int(np.clip(np.ceil(r1), 0, nr - 1))
        j0, j1 = int(np.clip(np.floor(c0), 0, nc - 1)), int(np.clip(np.ceil(c1), 0, nc - 1))
        return v[i0 : i1 + 1, j0 : j1 + 1]

    def max_height(self, region: tuple[float, float, float, float] | None = None) -> float:
        """Highest ellipsoidal node height [m] (of the cells touching ``region``).

        Bilinear cells never exceed their nodes, so this bounds the surface: it
        is the H_max that starts the descending steps of [Q17 section 2.3]. A
        window built with ``from_grid(..., height_range_m=)`` returns the whole
        surface's highest height when no region is given.

        Parameters
        ----------
        region : (west, south, east, north) in degrees, optional
        """
        if region is None and self._surface_range is not None:
            return self._surface_range[1]
        return float(np.nanmax(self._region_nodes(region)))

    def min_height(self, region: tuple[float, float, float, float] | None = None) -> float:
        """Lowest ellipsoidal node height [m] (of the cells touching ``region``)."""
        if region is None and self._surface_range is not None:
            return self._surface_range[0]
        return float(np.nanmin(self._region_nodes(region)))

    @property
    def has_data(self) -> bool:
        """Whether any node has a height (False: the raster is all no-data, int16 nodata or NaN).

        The solvers give such a DEM status NODATA for every ray that reaches it, rather than
        starting from a NaN highest node (which read as SKY, a wrong reason)."""
        if self._has_data is None:
            self._has_data = bool(np.isfinite(self.grid.values).any())
        return self._has_data

    def cell_max(self) -> np.ndarray:
        """Per-cell maximum of the 4 node heights, (nrows-1, ncols-1); NaN if any node is missing."""
        if self._cell_max is None:
            v = self.grid.values
            self._cell_max = np.maximum(np.maximum(v[:-1, :-1], v[:-1, 1:]), np.maximum(v[1:, :-1], v[1:, 1:]))
        return self._cell_max

    # ------------------------------------------------------------------ meshes
    def mesh(self, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Triangle mesh of the nodes in ECEF: two triangles per cell.

        Each cell (i, j) with corners p00 = node(i, j), p10 = node(i, j+1)
        (east), p01 = node(i+1, j) (south), p11 = node(i+1, j+1) is split along
        the p00-p11 diagonal into (p00, p01, p11) and (p00, p11, p10), the
        triangles the exact solver uses with ``dem_model="triangles"``. Cells
        with a missing node are left out.

        Returns
        -------
        vertices_ecef : ndarray (nrows * ncols, 3)
            Node positions in ECEF [m] (missing nodes at height 0).
        faces : ndarray (n_faces, 3) of int
        """
        if not (isinstance(stride, (int, np.integer)) and stride >= 1):
            raise ValueError(f"stride must be a positive integer, got {stride!r}")
        lat_deg, lon_deg = self.node_latlon_deg()
        h = self.grid.values
        lat_deg, lon_deg, h = (a[::stride, ::stride] for a in (lat_deg, lon_deg, h))
        v = geodetic_to_ecef(np.deg2rad(lat_deg), np.deg2rad(lon_deg), np.nan_to_num(h)).reshape(-1, 3)
        return v, grid_faces(np.isfinite(h))

    def enu_frame(
        self, origin_lat: float | None = None, origin_lon: float | None = None, origin_h: float = 0.0
    ) -> EnuFrame:
        """A :class:`geoloc.frames.enu.EnuFrame` at the given origin (default: the DEM's centre, h 0)."""
        from geoloc.frames.enu import EnuFrame

        w, s, e, n = self.bounds_deg
        lat0 = np.deg2rad(0.5 * (s + n)) if origin_lat is None else float(origin_lat)
        lon0 = np.deg2rad(0.5 * (w + e)) if origin_lon is None else float(origin_lon)
        return EnuFrame(lat0, lon0, float(origin_h))

    def to_trimesh(
        self,
        stride: int = 1,
        origin_lat: float | None = None,
        origin_lon: float | None = None,
        origin_h: float = 0.0,
        frame: str = "enu",
    ) -> Any:
        """The :meth:`mesh` as a ``trimesh.Trimesh`` in a local ENU frame (or ECEF).

        Use ENU for drawing (three.js and embree use float32: ECEF magnitudes
        lose half a metre) and for ray casting with trimesh.

        Parameters
        ----------
        stride : int
            Take every ``stride``-th node.
        origin_lat, origin_lon : float, optional
            ENU origin [rad]; default the DEM's centre.
        origin_h : float
            ENU origin height [m].
        frame : {"enu", "ecef"}

        Returns
        -------
        trimesh.Trimesh
            With ``metadata["enu_frame"]`` holding the :class:`EnuFrame` for "enu".
        """
        trimesh = require("trimesh", "the DEM as a triangle mesh (DEM.mesh)")

        v, f = self.mesh(stride)
        if frame == "enu":
            fr = self.enu_frame(origin_lat, origin_lon, origin_h)
            m = trimesh.Trimesh(fr.from_ecef(v), f, process=False)
            m.metadata["enu_frame"] = fr
            return m
        if frame == "ecef":
            return trimesh.Trimesh(v, f, process=False)
        raise ValueError(f"frame must be 'enu' or 'ecef', got {frame!r}")

    def __repr__(self):
        w, s, e, n = self.bounds_deg
        return (
            f"DEM({self.path or 'array'}, {self.shape[0]}x{self.shape[1]} nodes, "
            f"W{w:.4f} S{s:.4f} E{e:.4f} N{n:.4f}, datum={self.datum})"
        )


def grid_faces(ok: ArrayLike) -> NDArray[np.intp]:
    """Two triangles per cell of a grid of nodes (row-major indices), :meth:`DEM.mesh`'s split.

    Each cell (i, j) with corners p00 = node(i, j), p10 = node(i, j+1), p01 = node(i+1, j),
    p11 = node(i+1, j+1) gives (p00, p01, p11) and (p00, p11, p10), the triangles of the exact
    solver's ``dem_model="triangles"``; a cell with a node not ``ok`` (a missing height) is left
    out. ``ok``: (rows, columns) bool. Returns (faces, 3) int node indices.
    """
    ok = np.asarray(ok, bool)
    nr, nc = ok.shape
    idx = np.arange(nr * nc).reshape(nr, nc)
    p00, p10, p01, p11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    good = (ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]).ravel()
    f1 = np.stack([p00, p01, p11], axis=-1).reshape(-1, 3)[good]
    f2 = np.stack([p00, p11, p10], axis=-1).reshape(-1, 3)[good]
    return np.stack([f1, f2], axis=1).reshape(-1, 3)


def upsampled_dem(src: DEM, n: int, rng: np.random.Generator, roughness_m: float = 3.0) -> DEM:
    """``src`` resampled bilinearly to n x n nodes over the same area, plus Gaussian roughness.

    A large synthetic DEM for tests and benchmarks (``benchmarks/bench_terrain.py --size``,
    ``tests/surfaces/test_terrain_hierarchy.py``): sigma ``roughness_m`` [m], drawn from ``rng``;
    heights ellipsoidal, as ``src.grid.values`` are (``DEM.open`` adds EGM96's undulation).
    """
    g = src.grid
    z = np.asarray(g.values, float)
    for axis in (0, 1):
        m = z.shape[axis]
        x = np.linspace(0.0, m - 1, n)
        i = np.minimum(x.astype(int), m - 2)
        w = (x - i).reshape((n, 1) if axis == 0 else (1, n))
        z = np.take(z, i, axis) * (1 - w) + np.take(z, i + 1, axis) * w
    z += rng.normal(0.0, roughness_m, z.shape)
    return DEM.from_array(
        z,
        g.lat_north_deg,
        g.lon_west_deg,
        g.dlat_deg * (g.values.shape[0] - 1) / (n - 1),
        g.dlon_deg * (g.values.shape[1] - 1) / (n - 1),
        datum="ellipsoid",
    )


def _warp_to_geographic(grid: NodeGrid, crs_wkt: str) -> NodeGrid:
    """A projected node grid resampled (bilinear) at the nodes of a geographic grid.

    The geographic grid is the one GDAL would choose for the raster
    (``calculate_default_transform``: same extent, about the same resolution);
    each of its nodes (pixel centres) is transformed to the source CRS with pyproj
    and the source grid's bilinear height read there; nodes outside the source's
    extent have no data. The result has ``margin = 0.5`` like any opened raster.
    """

    import pyproj
    from rasterio.warp import calculate_default_transform

    nr, nc = grid.values.shape
    mx, my = grid.margin * grid.dlon_deg, grid.margin * grid.dlat_deg
    left, right = grid.lon_west_deg - mx, grid.lon_east_deg + mx
    bottom, top = grid.lat_south_deg - my, grid.lat_north_deg + my
    # the raster's own extent and pixel count (margin 0: node hull plus half a cell)
    w_px = nc - 1 + 2 * grid.margin if grid.margin else nc
    h_px = nr - 1 + 2 * grid.margin if grid.margin else nr
    with warnings.catch_warnings():  # rasterio 1.4's own use of Affine's "*" (its business)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        t, width, height = calculate_default_transform(
            crs_wkt, "EPSG:4326", int(round(w_px)), int(round(h_px)), left, bottom, right, top
        )
    lon = t.c + t.a * (np.arange(width) + 0.5)
    lat = t.f + t.e * (np.arange(height) + 0.5)
    LON, LAT = np.meshgrid(lon, lat)
    tr = pyproj.Transformer.from_crs("EPSG:4326", pyproj.CRS.from_wkt(crs_wkt), always_xy=True)
    x, y = tr.transform(LON, LAT)
    x, y = np.asarray(x), np.asarray(y)
    v = grid.interp(y, x)
    v[~grid.contains(y, x)] = np.nan
    return NodeGrid(v, float(lat[0]), float(lon[0]), float(-t.e), float(t.a), grid.path, margin=0.5)
