"""DEM mosaics: a folder of tiles, a list of rasters or a GDAL VRT as ONE surface, read on demand.

:meth:`geoloc.surfaces.dem.DEM.open` reads one whole raster into memory. A
:class:`DemMosaic` instead keeps only an index of its files (each file's place
on one common node grid) and reads node *blocks* through rasterio windows when a
batch of lines of sight needs them, through a :class:`TileCache` whose size in
bytes is bounded (least recently used blocks are dropped first).

For a batch of rays (``docs/scale.md``):

1. each ray's *ground track* is bounded: the part of the ray between the
   ellipsoid inflated to the mosaic's highest node and the one inflated to its
   lowest node [Q17 eq. 11] (the terrain lies between the two, so the first
   crossing lies on that segment), sampled in :data:`TRACK_SAMPLES` points,
   converted to node indices and grown by :data:`PAD_NODES` nodes;
2. the rays are grouped so that the union of their tracks (a window of nodes)
   holds at most ``max_region_nodes`` nodes; a group that would be larger is
   split spatially in two at the median of its tracks' centres along the longer
   side, recursively; one ray whose own track is longer is walked in pieces
   along the ray, nearest first;
3. for each group the window's blocks are read through the cache and assembled
   into a :class:`~geoloc.surfaces.dem.DEM` (:meth:`DEM.from_grid`: the same
   node heights, h = H + N with EGM96, as ``DEM.open`` of one merged raster),
   handed to :func:`geoloc.surfaces.terrain.intersect_dem`, and the hits are
   put back in the batch's order.

Why an own tile index rather than an in-memory VRT of the list: every block
read is one rasterio window read of one file, so the cache's keys and byte
counts are exact, a bad file is named in the error, tiles that overlap by one
node (as SRTM tiles do) need no GDAL source-order rules (the first file that has
a value at a node gives it), and nothing is written anywhere. A ``.vrt`` file is
opened by GDAL itself as one source (its own mosaicking rules apply).

All files must share one geographic CRS, one node spacing and one node lattice
(offsets whole multiples of the spacing), and one vertical datum: the
``datum`` argument, checked against a vertical CRS that a file states (a
compound CRS); a file that disagrees is an error naming it. Areas no file
covers have no data (status NODATA where a ray meets them), beyond the mosaic's
outer edge LEFT_DEM, as for one raster. Heights are ellipsoidal (WGS 84) once
read, as everywhere in geoloc.

Memory: the cache holds at most ``cache_bytes`` (default
:data:`DEFAULT_CACHE_BYTES`); one assembled region at most ``max_region_nodes``
nodes (about 40 bytes per node with the exact solver's tables). GDAL keeps its
own raster block cache besides (``GDAL_CACHEMAX``), outside this bound.

Conventions: ``docs/conventions.md`` (radians inside, ``_deg`` at the edges).
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import A, B, ecef_to_geodetic
from geoloc.geodesy.geoid import NodeGrid, egm96_undulation
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DATUMS, DEM
from geoloc.userfiles import note_input

if TYPE_CHECKING:  # the terrain module imports this one
    from geoloc.surfaces.terrain import TerrainHit

#: What names a DEM's files (:func:`mosaic_paths`): a folder, a ``.vrt``, one raster, or several rasters.
DemPaths = str | os.PathLike[str] | Iterable[str | os.PathLike[str]]

#: Default bound of the tile cache [bytes] (64 MiB: 2.2 M float64 nodes, a sixth of a 1'' SRTM tile).
DEFAULT_CACHE_BYTES = 64 * 2**20
#: Default block edge [nodes] of a cache entry (256 x 256 float64 = 512 KiB).
DEFAULT_BLOCK = 256
#: Raster suffixes taken from a folder.
TILE_SUFFIXES = (".tif", ".tiff", ".hgt", ".dt0", ".dt1", ".dt2", ".img", ".bil", ".vrt")
#: Points sampled along each ray's track segment: the track of a straight line in
#: lat/lon bows away from the chord between samples by about (L/16)^2 tan(lat) / (8 R)
#: for a segment of length L, under the pad below for segments up to hundreds of km.
TRACK_SAMPLES = 17
#: Nodes added on every side of a track's box (the bilinear cell under a sample
#: needs the next node; one more for the bow of the track between samples).
PAD_NODES = 2
#: Metres added above the highest / below the lowest node when bounding the tracks:
#: the exact walk starts 1 m above H_max (terrain._MARGIN_M) and the inflated
#: ellipsoid departs from the constant-height surface by millimetres.
_TRACK_MARGIN_M = 3.0


class TileCache:
    """An LRU cache of node blocks bounded in bytes, instrumented.

    Attributes
    ----------
    max_bytes : int
        The bound: :attr:`bytes_used` never exceeds it.
    bytes_used, peak_bytes : int
        Bytes held now, and the most ever held.
    hits, misses, evictions : int
        Counters (a miss is one rasterio window read).
    """

    def __init__(self, max_bytes: int = DEFAULT_CACHE_BYTES):
        if not (isinstance(max_bytes, (int, np.integer)) and max_bytes > 0):
            raise ValueError(f"cache_bytes must be a positive number of bytes, got {max_bytes!r}")
        self.max_bytes = int(max_bytes)
        self._d: OrderedDict = OrderedDict()
        self.bytes_used = self.peak_bytes = 0
        self.hits = self.misses = self.evictions = 0

    def get(self, key: Any, load: Callable[[], np.ndarray]) -> np.ndarray:
        """The block of ``key``; ``load()`` reads it on a miss."""
        if key in self._d:
            self._d.move_to_end(key)
            self.hits += 1
            return self._d[key]
        self.misses += 1
        arr = load()
        nb = int(arr.nbytes)
        if nb > self.max_bytes:  # cannot be held within the bound: hand it out uncached
            return arr
        while self._d and self.bytes_used + nb > self.max_bytes:
            _, old = self._d.popitem(last=False)
            self.bytes_used -= int(old.nbytes)
            self.evictions += 1
        self._d[key] = arr
        self.bytes_used += nb
        self.peak_bytes = max(self.peak_bytes, self.bytes_used)
        return arr

    def clear(self) -> None:
        self._d.clear()
        self.bytes_used = 0

    def __len__(self) -> int:
        return len(self._d)

    def __repr__(self) -> str:
        return (
            f"TileCache({self.bytes_used}/{self.max_bytes} bytes, {len(self)} blocks, "
            f"hits={self.hits}, misses={self.misses}, evictions={self.evictions})"
        )


@dataclass
class _Source:
    path: str
    band: int
    row0: int  # global node row of the file's node (0, 0)
    col0: int
    nrows: int
    ncols: int


class DemTileWarning(UserWarning):
    """A tile of a mosaic that cannot be read in part (truncated, corrupt): its cells are no data."""


def mosaic_paths(source: DemPaths) -> list[str]:
    """The raster files of ``source``: a folder (its rasters, sorted by name), one file, or a list."""
    if isinstance(source, (str, os.PathLike)):
        p = Path(source)
        if p.is_dir():
            files = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in TILE_SUFFIXES)
            if not files:
                raise ValueError(
                    f"DEM {p} is a folder with no raster tiles ({', '.join(TILE_SUFFIXES)}): "
                    "give a raster file, or a folder of DEM tiles"
                )
            return [str(q) for q in files]
        if not p.is_file():
            raise FileNotFoundError(f"DEM file not found: {p}")
        return [str(p)]
    paths = [str(x) for x in source]
    if not paths:
        raise ValueError("DEM mosaic: no files given")
    for x in paths:
        if Path(x).is_dir():
            raise ValueError(f"DEM mosaic: {x} is a folder; give a folder alone, or a list of files")
        if not Path(x).is_file():
            raise FileNotFoundError(f"DEM file not found: {x}")
    return paths


def _vertical_datum(crs, path):
    """'egm96', 'ellipsoid' or None (the file states no vertical CRS) from a rasterio CRS."""
    import pyproj

    c = pyproj.CRS.from_wkt(crs.to_wkt())
    if c.is_compound:
        for sub in c.sub_crs_list:
            if sub.is_vertical:
                name = sub.name.lower()
                if "egm96" in name or "egm 96" in name:
                    return "egm96"
                raise ValueError(
                    f"DEM tile {path}: vertical CRS {sub.name!r} is neither EGM96 heights nor "
                    "ellipsoidal; convert the tile (e.g. gdalwarp) to EGM96 or ellipsoidal heights"
                )
    if c.is_geographic and len(c.axis_info) == 3:
        return "ellipsoid"
    return None


class DemMosaic:
    """Many DEM rasters as one surface, read in windows on demand (module docstring).

    Build with :meth:`open`. Satisfies the ``Surface`` interface
    (:meth:`intersect`) and samples like a :class:`~geoloc.surfaces.dem.DEM`
    (:meth:`sample`, :meth:`height`).

    Attributes
    ----------
    paths : list of str
    datum : {"egm96", "ellipsoid"}
        Vertical datum of the files' heights (made ellipsoidal on reading).
    shape : (int, int)
        Nodes of the whole mosaic (rows north to south, columns west to east).
    lat_north_deg, lon_west_deg, dlat_deg, dlon_deg : float
        The common node lattice (node (0, 0) and the spacings).
    cache : TileCache
    method, dem_model, options
        What :meth:`intersect` hands to :func:`geoloc.surfaces.terrain.intersect_dem`.
    """

    def __init__(
        self,
        paths: Iterable[str | os.PathLike[str]],
        datum: str = "egm96",
        *,
        band: int = 1,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        block: int = DEFAULT_BLOCK,
        max_region_nodes: int | None = None,
        height_range_m: tuple[float, float] | None = None,
        method: str = "exact",
        dem_model: str = "bilinear",
        **options: Any,
    ):
        import pyproj
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning, RasterioError

        from geoloc.surfaces.terrain import DEM_MODELS, METHODS

        if datum not in DATUMS:
            raise ValueError(f"datum must be one of {DATUMS}, got {datum!r}")
        if method not in METHODS:
            raise ValueError(f"DEM method = {method!r}: must be one of {METHODS}")
        if dem_model not in DEM_MODELS:
            raise ValueError(f"dem_model must be one of {DEM_MODELS}, got {dem_model!r}")
        if options.get("trace"):
            raise ValueError(
                "trace=True is not available on a DEM mosaic (the batch is solved in regions): "
                "trace on a DEM from DemMosaic.region_dem"
            )
        if not (isinstance(block, (int, np.integer)) and block >= 2):
            raise ValueError(f"block must be an integer of at least 2 nodes, got {block!r}")
        self.cache = TileCache(cache_bytes)
        if block * block * 8 > self.cache.max_bytes:
            raise ValueError(
                f"block = {block} nodes ({block * block * 8} bytes) does not fit the cache bound "
                f"cache_bytes = {self.cache.max_bytes}: give a smaller block or a larger bound"
            )
        self.max_region_nodes = int(
            max_region_nodes if max_region_nodes is not None else max(self.cache.max_bytes // 8, 16)
        )
        if self.max_region_nodes < 16:
            raise ValueError(f"max_region_nodes must be at least 16, got {max_region_nodes!r}")
        self.paths = [os.fspath(p) for p in paths]
        self.datum, self.band, self.block = datum, int(band), int(block)
        self.method, self.dem_model, self.options = method, dem_model, options
        self._open: dict[int, Any] = {}  # source index -> its open rasterio dataset
        ref: tuple | None = None  # (path, crs, dlat, dlon, lat_n, lon_w, vertical datum)
        found = []
        for path in self.paths:
            note_input(path)  # every tile is an input: no output may be written over one
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", NotGeoreferencedWarning)
                    with rasterio.open(path) as src:
                        t, crs, h, w, count = src.transform, src.crs, src.height, src.width, src.count
            except RasterioError as e:
                raise ValueError(f"DEM tile {path}: not a raster that GDAL can read ({e})") from None
            if crs is None or t.is_identity:
                raise ValueError(f"DEM tile {path}: no georeferencing (CRS {crs}, transform {tuple(t)[:6]})")
            if t.b != 0 or t.d != 0 or t.e >= 0:
                raise ValueError(f"DEM tile {path}: transform {tuple(t)[:6]} is not north-up")
            if not 1 <= band <= count:
                raise ValueError(f"DEM tile {path}: band {band} requested, the file has {count}")
            if min(h, w) < 2:
                raise ValueError(f"DEM tile {path}: {h} x {w} pixels; a tile needs at least 2 x 2")
            horiz = pyproj.CRS.from_wkt(crs.to_wkt())
            if horiz.is_compound:
                horiz = next(c for c in horiz.sub_crs_list if not c.is_vertical)
            if horiz.is_geographic and len(horiz.axis_info) == 3:
                horiz = horiz.to_2d()  # EPSG:4979 (ellipsoidal heights) is EPSG:4326 horizontally
            if not horiz.is_geographic:
                raise ValueError(
                    f"DEM tile {path}: CRS {horiz.name!r} is projected; a mosaic needs geographic "
                    "(lat/lon) tiles: warp them first (gdalwarp -t_srs EPSG:4326)"
                )
            vdat = _vertical_datum(crs, path)
            if vdat is not None and vdat != datum:
                raise ValueError(
                    f"DEM tile {path}: its CRS states {vdat} heights, the mosaic's datum is "
                    f"{datum!r} (every tile must have the same vertical datum)"
                )
            lat_n, lon_w, dlat, dlon = t.f + t.e / 2, t.c + t.a / 2, -t.e, t.a
            if ref is None:
                ref = (path, horiz, dlat, dlon, lat_n, lon_w, vdat)
            else:
                rp, rcrs, rdlat, rdlon, rlat, rlon, rvd = ref
                if not horiz.equals(rcrs, ignore_axis_order=True):
                    raise ValueError(
                        f"DEM tile {path}: CRS {horiz.name!r} differs from {rcrs.name!r} of {rp}; "
                        "every tile of a mosaic must have the same CRS"
                    )
                if vdat != rvd and None not in (vdat, rvd):
                    raise ValueError(f"DEM tile {path}: vertical datum {vdat} differs from {rvd} of {rp}")
                # 1e-9 relative: the spacings of tiles cut from one grid agree to float rounding
                if abs(dlat - rdlat) > 1e-9 * rdlat or abs(dlon - rdlon) > 1e-9 * rdlon:
                    raise ValueError(
                        f"DEM tile {path}: node spacing {dlat!r} x {dlon!r} deg differs from "
                        f"{rdlat!r} x {rdlon!r} deg of {rp}; resample the tiles to one grid"
                    )
                for off in ((rlat - lat_n) / rdlat, (lon_w - rlon) / rdlon):
                    # 1e-6 of a node: a float-rounded transform, not a shifted lattice
                    if abs(off - round(off)) > 1e-6:
                        raise ValueError(
                            f"DEM tile {path}: its nodes are {off - round(off):+.4f} of a node off "
                            f"the lattice of {rp}; resample the tiles to one grid"
                        )
            found.append((path, lat_n, lon_w, h, w))
        if ref is None:
            raise ValueError("a DEM mosaic needs at least one tile: paths is empty")
        _, self._crs, self.dlat_deg, self.dlon_deg, lat0, lon0, _ = ref
        # the lattice's node (0, 0): the north-west-most node of any tile (offsets rounded to whole nodes)
        di = [round((lat0 - f[1]) / self.dlat_deg) for f in found]
        dj = [round((f[2] - lon0) / self.dlon_deg) for f in found]
        i0, j0 = min(di), min(dj)
        self.lat_north_deg = lat0 - self.dlat_deg * i0
        self.lon_west_deg = lon0 + self.dlon_deg * j0
        self.sources = [_Source(p, self.band, a - i0, b - j0, h, w) for (p, _, _, h, w), a, b in zip(found, di, dj)]
        self.shape = (max(s.row0 + s.nrows for s in self.sources), max(s.col0 + s.ncols for s in self.sources))
        if height_range_m is None:
            self.min_h, self.max_h = self._scan_heights()
        else:
            lo, hi = (float(x) for x in height_range_m)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"height_range_m must be (lowest, highest) ellipsoidal metres, got {height_range_m!r}")
            self.min_h, self.max_h = lo, hi

    # ------------------------------------------------------------------ building
    @classmethod
    def open(cls, source: DemPaths, datum: str = "egm96", **kwargs: Any) -> "DemMosaic":
        """A mosaic of a folder of tiles, a ``.vrt``, one raster, or a list of rasters.

        Parameters
        ----------
        source : path or list of paths
            A folder (every raster in it, :data:`TILE_SUFFIXES`, sorted by name: where
            tiles overlap the first one that has a value gives it), a GDAL VRT or any
            raster (GDAL reads it as one source), or a list of raster files.
        datum : {"egm96", "ellipsoid"}
            Vertical datum of the files' heights (real DEMs: "egm96").
        **kwargs
            ``band``, ``cache_bytes``, ``block``, ``max_region_nodes``,
            ``height_range_m`` (skip the opening scan for the highest and lowest
            node: (lowest, highest) ellipsoidal metres, which must bound them),
            ``method``, ``dem_model`` and the options of
            :func:`geoloc.surfaces.terrain.intersect_dem`.

        Raises
        ------
        FileNotFoundError, ValueError
            Naming the file: unreadable, not north-up, projected, another CRS, node
            spacing or lattice, or a stated vertical datum other than ``datum``.
        """
        return cls(mosaic_paths(source), datum, **kwargs)

    def _dataset(self, k):
        import rasterio

        ds = self._open.get(k)
        if ds is None:
            ds = self._open[k] = rasterio.open(self.sources[k].path)
        return ds

    def with_solver(self, method: str | None = None, dem_model: str | None = None, **options: Any) -> "DemMosaic":
        """The same mosaic (files, cache, heights) solving with another method / dem_model / options."""
        from geoloc.surfaces.terrain import DEM_MODELS, METHODS

        m = object.__new__(type(self))
        m.__dict__.update(self.__dict__)  # shares the tile cache and the open files (copy() would not)
        m.method = self.method if method is None else method
        m.dem_model = self.dem_model if dem_model is None else dem_model
        m.options = {**self.options, **options}
        if m.method not in METHODS:
            raise ValueError(f"DEM method = {m.method!r}: must be one of {METHODS}")
        if m.dem_model not in DEM_MODELS:
            raise ValueError(f"dem_model must be one of {DEM_MODELS}, got {m.dem_model!r}")
        if m.options.get("trace"):
            raise ValueError("trace=True is not available on a DEM mosaic")
        return m

    @property
    def path(self) -> str:
        """The file, or the folder of the first file and the count (for messages)."""
        return self.paths[0] if len(self.paths) == 1 else f"{Path(self.paths[0]).parent} ({len(self.paths)} files)"

    def close(self) -> None:
        for ds in self._open.values():
            ds.close()
        self._open.clear()
        self.cache.clear()

    def __getstate__(self):  # picklable (Dask workers): open files and cached blocks stay behind
        st = dict(self.__dict__)
        st["_open"] = {}
        st["cache"] = TileCache(self.cache.max_bytes)
        return st

    def _block(self, k, bi, bj):
        """Block (bi, bj) of source k: float64 heights as read (NaN for no data)."""
        s, b = self.sources[k], self.block

        def load():
            from rasterio.errors import RasterioError
            from rasterio.windows import Window

            r0, c0 = bi * b, bj * b
            win = Window(c0, r0, min(b, s.ncols - c0), min(b, s.nrows - r0))
            try:
                return self._dataset(k).read(s.band, window=win, masked=True).astype(float).filled(np.nan)
            except (RasterioError, OSError) as e:  # a truncated or corrupt tile: no data there, the others serve
                self._unreadable(s.path, r0, c0, win, e)
                return np.full((int(win.height), int(win.width)), np.nan)

        return self.cache.get((k, bi, bj), load)

    def _unreadable(self, path, r0, c0, win, e) -> None:
        """Note a block of a tile that GDAL cannot read; warn once per tile (:class:`DemTileWarning`:
        ``geoloc`` prints it as one line). Its cells are no data: a ray that meets them is NODATA,
        the others run (docs/cli.md, "Faults of the machine")."""
        bad = self.__dict__.setdefault("unreadable", {})
        first = path not in bad
        bad.setdefault(path, []).append((r0, c0, int(win.height), int(win.width)))
        if first:
            reason = " ".join(str(e.__cause__ or e).split())[:200]  # rasterio: "Read failed. See previous ..."
            warnings.warn(
                DemTileWarning(
                    f"DEM tile {path}: rows {r0}-{r0 + int(win.height) - 1}, columns {c0}-{c0 + int(win.width) - 1} "
                    f"cannot be read ({reason}); its unreadable cells are no data (a ray meeting them: status "
                    "nodata), the other tiles are used"
                ),
                stacklevel=2,
            )

    def _scan_heights(self):
        """Lowest and highest ellipsoidal node of the mosaic, block by block (memory: one block)."""
        lo, hi = np.inf, -np.inf
        b = self.block
        for k, s in enumerate(self.sources):
            for bi in range(-(-s.nrows // b)):
                for bj in range(-(-s.ncols // b)):
                    v = self._block(k, bi, bj)
                    if not np.isfinite(v).any():
                        continue
                    if self.datum == "egm96":
                        r = s.row0 + bi * b + np.arange(v.shape[0])
                        c = s.col0 + bj * b + np.arange(v.shape[1])
                        lat = np.deg2rad(self.lat_north_deg - self.dlat_deg * r)[:, None]
                        lon = np.deg2rad(self.lon_west_deg + self.dlon_deg * c)[None, :]
                        v = v + egm96_undulation(lat, lon)
                    lo, hi = min(lo, float(np.nanmin(v))), max(hi, float(np.nanmax(v)))
        if not np.isfinite(lo):
            raise ValueError(f"DEM mosaic of {len(self.paths)} file(s) ({self.paths[0]}, ...) has no data at all")
        return lo, hi

    def window_nodes(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Heights as read (before N) of global nodes rows r0..r1, columns c0..c1 (inclusive); NaN: no data."""
        out = np.full((r1 - r0 + 1, c1 - c0 + 1), np.nan)
        b = self.block
        for k, s in enumerate(self.sources):
            # the window in the source's own node indices
            a0, a1 = max(r0 - s.row0, 0), min(r1 - s.row0, s.nrows - 1)
            e0, e1 = max(c0 - s.col0, 0), min(c1 - s.col0, s.ncols - 1)
            if a0 > a1 or e0 > e1:
                continue
            for bi in range(a0 // b, a1 // b + 1):
                for bj in range(e0 // b, e1 // b + 1):
                    v = self._block(k, bi, bj)
                    ra, rb = max(a0, bi * b), min(a1, bi * b + v.shape[0] - 1)
                    ca, cb = max(e0, bj * b), min(e1, bj * b + v.shape[1] - 1)
                    src = v[ra - bi * b : rb - bi * b + 1, ca - bj * b : cb - bj * b + 1]
                    dst = out[ra + s.row0 - r0 : rb + s.row0 - r0 + 1, ca + s.col0 - c0 : cb + s.col0 - c0 + 1]
                    empty = np.isnan(dst)  # the first file with a value at a node gives it
                    dst[empty] = src[empty]
        return out

    def window_dem(self, r0: int, r1: int, c0: int, c1: int) -> DEM:
        """The :class:`DEM` of global nodes rows r0..r1, columns c0..c1 (inclusive), as ``DEM.open`` reads it."""
        nr, nc = self.shape
        r0, r1 = int(max(r0, 0)), int(min(r1, nr - 1))
        c0, c1 = int(max(c0, 0)), int(min(c1, nc - 1))
        if r1 - r0 < 1:  # a DEM needs 2 x 2 nodes
            r0, r1 = (r0, r0 + 1) if r0 + 1 < nr else (r1 - 1, r1)
        if c1 - c0 < 1:
            c0, c1 = (c0, c0 + 1) if c0 + 1 < nc else (c1 - 1, c1)
        n = (r1 - r0 + 1) * (c1 - c0 + 1)
        if n > max(self.max_region_nodes, 4):
            raise ValueError(
                f"DEM mosaic window of {r1 - r0 + 1} x {c1 - c0 + 1} nodes exceeds max_region_nodes = "
                f"{self.max_region_nodes}"
            )
        v = self.window_nodes(r0, r1, c0, c1)
        # margin 0.5: at the mosaic's outer edges the raster covers half a cell more (as DEM.open);
        # inside, the windows are cut wider than any track (PAD_NODES), so the band is never reached
        grid = NodeGrid(
            v,
            self.lat_north_deg - self.dlat_deg * r0,
            self.lon_west_deg + self.dlon_deg * c0,
            self.dlat_deg,
            self.dlon_deg,
            self.paths[0],
            margin=0.5,
        )
        label = self.path
        # the whole mosaic's H_max / H_min: the solvers start and stop where they would on one
        # merged raster (the walk calls a ray LEFT_DEM when it starts off the grid)
        return DEM.from_grid(grid, "EPSG:4326", self.datum, label, height_range_m=(self.min_h, self.max_h))

    def region_dem(self, region_deg: tuple[float, float, float, float]) -> DEM:
        """The :class:`DEM` of the nodes of every cell touching ``(west, south, east, north)`` [deg]."""
        w, s, e, n = (float(x) for x in region_deg)
        if not (w <= e and s <= n):
            raise ValueError(f"region must be (west, south, east, north) in degrees, got {region_deg!r}")
        r0 = int(np.floor((self.lat_north_deg - n) / self.dlat_deg))
        r1 = int(np.ceil((self.lat_north_deg - s) / self.dlat_deg))
        c0 = int(np.floor((w - self.lon_west_deg) / self.dlon_deg))
        c1 = int(np.ceil((e - self.lon_west_deg) / self.dlon_deg))
        return self.window_dem(r0, r1, c0, c1)

    def to_dem(self) -> DEM:
        """The whole mosaic as one :class:`DEM` (ValueError if it holds more than ``max_region_nodes``)."""
        return self.window_dem(0, self.shape[0] - 1, 0, self.shape[1] - 1)

    # ------------------------------------------------------------------ geometry
    @property
    def lat_south_deg(self) -> float:
        return self.lat_north_deg - self.dlat_deg * (self.shape[0] - 1)

    @property
    def lon_east_deg(self) -> float:
        return self.lon_west_deg + self.dlon_deg * (self.shape[1] - 1)

    @property
    def bounds_deg(self) -> tuple:
        """(west, south, east, north) [deg] of the node hull."""
        return (self.lon_west_deg, self.lat_south_deg, self.lon_east_deg, self.lat_north_deg)

    @property
    def extent_deg(self) -> tuple:
        """(west, south, east, north) [deg]: the node hull grown by half a cell (the rasters' outer edges)."""
        w, s, e, n = self.bounds_deg
        return (w - self.dlon_deg / 2, s - self.dlat_deg / 2, e + self.dlon_deg / 2, n + self.dlat_deg / 2)

    def max_height(self) -> float:
        """Highest ellipsoidal node height [m] of the mosaic (or the given ``height_range_m``)."""
        return self.max_h

    def min_height(self) -> float:
        """Lowest ellipsoidal node height [m] of the mosaic (or the given ``height_range_m``)."""
        return self.min_h

    def _rc(self, lat, lon):
        """Fractional global (row, col) of geodetic points [rad]."""
        lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
        lon_deg = (lon_deg - self.lon_west_deg + 180.0) % 360.0 + self.lon_west_deg - 180.0
        return (self.lat_north_deg - lat_deg) / self.dlat_deg, (lon_deg - self.lon_west_deg) / self.dlon_deg

    # ------------------------------------------------------------------ grouping
    def _groups(self, box):
        """Index groups whose union box (r0, r1, c0, c1 per row of ``box``) has at most max_region_nodes nodes.

        Items whose own box is larger come back alone (the caller cuts them).
        """
        out = []
        stack = [np.arange(len(box))]
        while stack:
            idx = stack.pop()
            if idx.size == 0:
                continue
            b = box[idx]
            r0, r1, c0, c1 = b[:, 0].min(), b[:, 1].max(), b[:, 2].min(), b[:, 3].max()
            if (r1 - r0 + 1) * (c1 - c0 + 1) <= self.max_region_nodes or idx.size == 1:
                out.append((idx, (r0, r1, c0, c1)))
                continue
            axis = (0, 1) if (r1 - r0) >= (c1 - c0) else (2, 3)
            centre = b[:, axis[0]] + b[:, axis[1]]
            order = np.argsort(centre, kind="stable")
            half = idx.size // 2
            stack += [idx[order[:half]], idx[order[half:]]]
        return out

    # ------------------------------------------------------------------ sampling
    def sample(self, lat: ArrayLike, lon: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Ellipsoidal height and status at geodetic points [rad], as :meth:`DEM.sample`.

        Returns
        -------
        h : ndarray
            Bilinear ellipsoidal height [m]; NaN outside or without data.
        status : ndarray of uint8
            OK, LEFT_DEM (outside the mosaic's extent), NODATA, INVALID_INPUT.
        """
        lat, lon = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float))
        shape = lat.shape
        lat, lon = lat.ravel(), lon.ravel()
        h = np.full(lat.shape, np.nan)
        st = np.full(lat.shape, Status.OK, dtype=np.uint8)
        finite = np.isfinite(lat) & np.isfinite(lon)
        st[~finite] = Status.INVALID_INPUT
        r, c = self._rc(np.where(finite, lat, 0.0), np.where(finite, lon, 0.0))
        nr, nc = self.shape
        t = 0.5 + 1e-9  # the half-cell band of the outer edges (NodeGrid.contains' tolerance)
        inside = finite & (r >= -t) & (r <= nr - 1 + t) & (c >= -t) & (c <= nc - 1 + t)
        st[finite & ~inside] = Status.LEFT_DEM
        idx = np.flatnonzero(inside)
        if idx.size:
            rr, cc = np.clip(r[idx], 0, nr - 1), np.clip(c[idx], 0, nc - 1)
            box = np.stack([np.floor(rr) - 1, np.ceil(rr) + 1, np.floor(cc) - 1, np.ceil(cc) + 1], -1).astype(np.int64)
            for g, (r0, r1, c0, c1) in self._groups(box):
                dem = self.window_dem(r0, r1, c0, c1)
                hh, ss = dem.sample(lat[idx[g]], lon[idx[g]])
                h[idx[g]], st[idx[g]] = hh, ss
        return h.reshape(shape), st.reshape(shape)

    def height(self, lat: ArrayLike, lon: ArrayLike) -> np.ndarray:
        """Bilinear ellipsoidal height [m] at geodetic (lat, lon) [rad]; NaN outside / no data."""
        return self.sample(lat, lon)[0]

    # ------------------------------------------------------------------ rays
    def _tracks(self, o, d):
        """Per ray: (s_start, s_end) of the segment between the inflated H_max and H_min, and a reach flag."""

        def roots(h):
            ia, ib = 1.0 / (A + h) ** 2, 1.0 / (B + h) ** 2  # the inflated ellipsoid [Q17 eq. 11]
            qa = (d[:, 0] ** 2 + d[:, 1] ** 2) * ia + d[:, 2] ** 2 * ib
            hb = (o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]) * ia + o[:, 2] * d[:, 2] * ib
            qc = (o[:, 0] ** 2 + o[:, 1] ** 2) * ia + o[:, 2] ** 2 * ib - 1.0
            disc = hb * hb - qa * qc
            sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
            return (-hb - sq) / qa, (-hb + sq) / qa, qc < 0

        t0, t1, t_in = roots(self.max_h + _TRACK_MARGIN_M)
        f0, f1, f_in = roots(self.min_h - _TRACK_MARGIN_M)
        start = np.where(t_in, 0.0, t0)
        reach = t_in | (np.isfinite(t0) & (t1 >= 0))
        start = np.maximum(start, 0.0)
        floor = ~f_in & np.isfinite(f0) & (f0 >= 0)
        end = np.where(f_in, start, np.where(floor, f0, t1))
        return start, np.maximum(end, start), reach

    def _track_box(self, o, d, s0, s1):
        """Global node box (r0, r1, c0, c1) of each ray's track between s0 and s1; empty: r0 > r1."""
        s = s0[:, None] + (s1 - s0)[:, None] * np.linspace(0.0, 1.0, TRACK_SAMPLES)[None, :]
        p = o[:, None, :] + s[..., None] * d[:, None, :]
        lat, lon, _ = ecef_to_geodetic(p)
        r, c = self._rc(lat, lon)
        nr, nc = self.shape
        box = np.stack(
            [
                np.floor(r.min(1)) - PAD_NODES,
                np.ceil(r.max(1)) + PAD_NODES,
                np.floor(c.min(1)) - PAD_NODES,
                np.ceil(c.max(1)) + PAD_NODES,
            ],
            -1,
        )
        box[:, 0], box[:, 2] = np.maximum(box[:, 0], 0), np.maximum(box[:, 2], 0)
        box[:, 1], box[:, 3] = np.minimum(box[:, 1], nr - 1), np.minimum(box[:, 3], nc - 1)
        return box.astype(np.int64)

    def intersect(self, los: LineOfSight) -> TerrainHit:
        """First visible crossing of each line of sight with the mosaic (the ``Surface`` interface).

        Region by region, :func:`geoloc.surfaces.terrain.intersect_dem` with this mosaic's
        ``method``, ``dem_model`` and options on the region's :class:`DEM` (module docstring).

        Returns
        -------
        geoloc.surfaces.terrain.TerrainHit
            As on one merged raster: NaN and a status (SKY, LEFT_DEM, NODATA, ...)
            where there is no hit; ``trace`` is None.
        """
        from geoloc.surfaces.terrain import TerrainHit, _flat_los, below_terrain, intersect_dem

        shape, o, d, st = _flat_los(los, normalise=True)
        below_terrain(o, st, self)  # a region's window may not hold the camera: asked of the whole mosaic
        n = len(o)
        lat, lon, h, rng = (np.full(n, np.nan) for _ in range(4))
        ecef = np.full((n, 3), np.nan)
        evals = np.zeros(n, np.int64)
        hidden = np.zeros(n, bool)
        todo = np.flatnonzero(st == Status.OK)
        s0, s1, reach = self._tracks(o[todo], d[todo])
        st[todo[~reach]] = Status.SKY  # never below the highest node: what the walk says too
        keep = reach
        todo, s0, s1 = todo[keep], s0[keep], s1[keep]
        box = self._track_box(o[todo], d[todo], s0, s1) if todo.size else np.zeros((0, 4), np.int64)
        off = (box[:, 0] > box[:, 1]) | (box[:, 2] > box[:, 3])
        st[todo[off]] = Status.LEFT_DEM  # the track misses the mosaic
        todo, s0, s1, box = todo[~off], s0[~off], s1[~off], box[~off]
        opts = dict(self.options)

        def solve(idx, dem, origin):
            sub = LineOfSight(origin, d[idx], np.zeros(len(idx), np.uint8))
            return intersect_dem(sub, dem, self.method, dem_model=self.dem_model, **opts)

        for g, (r0, r1, c0, c1) in self._groups(box):
            idx = todo[g]
            if (r1 - r0 + 1) * (c1 - c0 + 1) <= self.max_region_nodes:
                hit = solve(idx, self.window_dem(r0, r1, c0, c1), o[idx])
                shift = np.zeros(len(idx))
            else:  # one ray with a track longer than a region: walk it in pieces, nearest first
                hit, shift = self._pieces(idx[0], o, d, s0[g[0]], s1[g[0]], solve)
            lat[idx], lon[idx], h[idx], ecef[idx] = hit.lat, hit.lon, hit.h, hit.ecef
            rng[idx] = hit.slant_range + shift
            st[idx], evals[idx] = hit.status, hit.dem_evaluations
            hidden[idx] = hit.hidden
        r = lambda a: a.reshape(shape)  # noqa: E731
        return TerrainHit(
            r(lat),
            r(lon),
            r(h),
            ecef.reshape(shape + (3,)),
            r(rng),
            r(st),
            los if isinstance(los, LineOfSight) else None,
            dem_evaluations=r(evals),
            hidden=r(hidden),
            method=self.method,
            dem_model=self.dem_model,
            trace=None,
        )

    def _pieces(self, k, o, d, s0, s1, solve):
        """Ray k's track cut along the ray into pieces that each fit a region; the first hit wins."""
        nparts = 2
        while True:
            cuts = np.linspace(s0, s1, nparts + 1)
            boxes = self._track_box(
                np.repeat(o[k : k + 1], nparts, 0), np.repeat(d[k : k + 1], nparts, 0), cuts[:-1], cuts[1:]
            )
            sizes = (boxes[:, 1] - boxes[:, 0] + 1) * (boxes[:, 3] - boxes[:, 2] + 1)
            if sizes.max() <= self.max_region_nodes:
                break
            nparts *= 2
        evals = 0
        hit = None
        for a, bx in zip(cuts[:-1], boxes):
            if bx[0] > bx[1] or bx[2] > bx[3]:
                continue
            origin = o[k : k + 1] + a * d[k : k + 1]
            hit = solve(np.array([k]), self.window_dem(*bx), origin)
            evals += int(hit.dem_evaluations[0])
            if hit.status[0] in (
                Status.OK,
                Status.NODATA,
                Status.ORIGIN_BELOW,
                Status.BELOW_TERRAIN,
                Status.INVALID_INPUT,
            ):
                break
            if hit.status[0] == Status.LEFT_DEM and evals == 0:
                break  # it starts off the mosaic: LEFT_DEM, as the walk says on one raster

        if hit is None:
            raise RuntimeError("no piece of the track is on the mosaic")  # excluded by the caller
        return replace(hit, dem_evaluations=np.array([evals])), (a if hit.status[0] == Status.OK else 0.0)

    def __repr__(self) -> str:
        w, s, e, n = self.bounds_deg
        return (
            f"DemMosaic({len(self.paths)} file(s), {self.shape[0]}x{self.shape[1]} nodes, W{w:.4f} S{s:.4f} "
            f"E{e:.4f} N{n:.4f}, datum={self.datum}, cache {self.cache.max_bytes} bytes)"
        )


def open_dem_or_mosaic(source: DemPaths, datum: str = "egm96", **kwargs: Any) -> DEM | DemMosaic:
    """``--dem``: one raster file -> :meth:`DEM.open`; a folder, a ``.vrt`` or several files -> :class:`DemMosaic`."""
    if not isinstance(source, (str, os.PathLike)):
        items = list(source)
        if len(items) != 1:
            return DemMosaic.open(items, datum, **kwargs)
        source = items[0]
    p = Path(source)
    if p.is_dir() or p.suffix.lower() == ".vrt":
        return DemMosaic.open(p, datum, **kwargs)
    return DEM.open(p, datum=datum)
