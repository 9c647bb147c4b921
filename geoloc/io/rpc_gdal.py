"""RPCs in and out of GDAL (through rasterio): GeoTIFF RPC tags, sidecars, GDAL's RPC transformer.

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md``. The model is
:mod:`geoloc.sensors.rpc`. This project's pixels are 1-based centres; GDAL's
pixel/line space has (0.5, 0.5) at the centre of the first pixel, so
GDAL = ours - 0.5 (and RPC line/sample = ours - 1).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.sensors.rpc import RPCModel, RPCSensor, rpc_terms

if TYPE_CHECKING:
    from geoloc.surfaces.dem import DEM
from geoloc.userfiles import atomic_path, note_input


# --------------------------------------------------------------- GeoTIFF I/O
def write_rpc_geotiff(
    path: str | os.PathLike[str], model: RPCModel, rows: int, cols: int, image: np.ndarray | None = None
) -> Path:
    """Write a GeoTIFF carrying ``model`` as GDAL RPC metadata (the TIFF RPC tag).

    Parameters
    ----------
    path : path-like
    model : RPCModel
    rows, cols : int
        Image size (lines, samples).
    image : ndarray (rows, cols) of uint16, optional
        Pixel values. Without it the file is written sparse (no tile is
        stored; readers see zeros), so a 24 576 x 24 576 scene costs about 75 kB.

    Returns
    -------
    Path
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    path = Path(path)
    profile = dict(
        driver="GTiff",
        width=int(cols),
        height=int(rows),
        count=1,
        dtype="uint16",
        tiled=True,
        blockxsize=256,
        blockysize=256,
        compress="deflate",
        SPARSE_OK=True,
    )
    with warnings.catch_warnings():
        # raised at creation, before the RPCs below are attached: not true of the file written
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with atomic_path(path) as tmp, rasterio.open(tmp, "w", **profile) as dst:
            dst.rpcs = model.to_rasterio()
            if image is not None:
                dst.write(np.asarray(image, np.uint16), 1)
    return path


def read_rpc_geotiff(path: str | os.PathLike[str]) -> RPCModel:
    """Read the RPC metadata of a raster back into an :class:`RPCModel`."""
    note_input(path)
    import rasterio

    with rasterio.open(path) as src:
        if src.rpcs is None:
            raise ValueError(f"{path}: no RPC metadata")
        return RPCModel.from_rasterio(src.rpcs)


# ------------------------------------------------------------------ NITF RPC00B
#: The RPC00B TRE's text fields (STDI-0002 Appendix E): name -> (width, decimals) of the
#: normalisation constants; every coefficient is +d.ddddddE+d (12 characters: 7 significant
#: digits, a one-digit exponent, so |c| < 1e-9 is written as 0 by GDAL).
RPC00B_FIELDS = {
    "line_off": (6, 0),
    "samp_off": (5, 0),
    "lat_off": (8, 4),
    "long_off": (9, 4),
    "height_off": (5, 0),
    "line_scale": (6, 0),
    "samp_scale": (5, 0),
    "lat_scale": (8, 4),
    "long_scale": (9, 4),
    "height_scale": (5, 0),
}


def rpc00b_renormalized(model: RPCModel) -> RPCModel:
    """The same RPC with offsets and scales that the RPC00B TRE stores exactly.

    RPC00B keeps LINE_OFF, SAMP_OFF, HEIGHT_OFF and the image and height scales as
    whole numbers and the latitude / longitude offsets and scales to 1e-4 deg.
    Rounding them alone (as GDAL does when it writes a NITF) moves the model:
    a LINE_OFF of 12287.5 written as 12288 is half a pixel. Changing a
    normalisation is an affine change of the normalised variables, under which
    a cubic stays a cubic, so the same ratios are re-expressed exactly in the
    rounded normalisation: the ground polynomials are refitted on 4 x 4 x 4
    points of the new cube (exact: 64 points for 20 coefficients of a cubic),
    the image side is ``num' = (num * S + (O - O') * den) / S'``, and both
    polynomials are divided by the denominator's new constant term so it is 1.

    The only loss left when writing is the coefficients' 7 significant digits.
    """

    new = {}
    for k, (_w, dec) in RPC00B_FIELDS.items():
        v = float(getattr(model, k))
        q = round(v, dec) if dec else float(round(v))
        if k.endswith("scale") and q <= 0:
            q = 10.0**-dec
        new[k] = q
    # ground side: old normalised (L, P, H) as affine functions of the new ones
    g = np.linspace(-1.0, 1.0, 4)
    Ln, Pn, Hn = (a.ravel() for a in np.meshgrid(g, g, g, indexing="ij"))

    def old_of(axis, x):
        return (x * new[f"{axis}_scale"] + new[f"{axis}_off"] - getattr(model, f"{axis}_off")) / getattr(
            model, f"{axis}_scale"
        )

    T_old = rpc_terms(old_of("long", Ln), old_of("lat", Pn), old_of("height", Hn))
    T_new = rpc_terms(Ln, Pn, Hn)
    coef = {}
    for img, scale_k, off_k in (("line", "line_scale", "line_off"), ("samp", "samp_scale", "samp_off")):
        num, den = getattr(model, f"{img}_num"), getattr(model, f"{img}_den")
        S, O, S2, O2 = getattr(model, scale_k), getattr(model, off_k), new[scale_k], new[off_k]
        num = (num * S + (O - O2) * den) / S2
        num2 = np.linalg.lstsq(T_new, T_old @ num, rcond=None)[0]
        den2 = np.linalg.lstsq(T_new, T_old @ den, rcond=None)[0]
        c0 = den2[0]
        coef[f"{img}_num"], coef[f"{img}_den"] = num2 / c0, den2 / c0
        coef[f"{img}_den"][0] = 1.0
    # the offsets and scales (floats) and the four coefficient arrays, by their field names, which
    # the checker cannot tell apart in a dict: held as Any
    fields: dict[str, Any] = {**new, **coef}
    return replace(model, **fields)


def write_rpc_nitf(
    path: str | os.PathLike[str], model: RPCModel, rows: int, cols: int, renormalize: bool = True
) -> Path:
    """Write a NITF 2.1 image whose RPC00B TRE carries ``model``, through GDAL (rasterio).

    GDAL's NITF driver writes the RPC00B TRE from the "RPC" metadata domain when
    it copies a dataset (CreateCopy), so the model goes on a temporary GeoTIFF
    first (GDAL's PAM is off for the copy, so no side-car ``.aux.xml`` holds a
    full-precision copy of the RPC that readers would take instead of the TRE):
    the file alone carries the model. Written through
    :func:`geoloc.userfiles.atomic_path`. With ``renormalize`` (default) the offsets
    and scales are first made ones RPC00B stores exactly
    (:func:`rpc00b_renormalized`).

    Parameters
    ----------
    path : path-like
        The ``.ntf`` to write.
    model : RPCModel
    rows, cols : int
        Image size (a blank uint8 image; NITF has no sparse files, so keep it small
        when the pixels do not matter: the RPC does not depend on the size).
    renormalize : bool

    Returns
    -------
    Path
    """
    import rasterio
    import rasterio.shutil
    from rasterio.errors import NotGeoreferencedWarning

    path = Path(path)
    m = rpc00b_renormalized(model) if renormalize else model
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        src = os.path.join(tmp, "rpc.tif")
        with rasterio.open(src, "w", driver="GTiff", width=int(cols), height=int(rows), count=1, dtype="uint8") as dst:
            dst.rpcs = m.to_rasterio()
        with atomic_path(path) as part:
            with rasterio.Env(GDAL_PAM_ENABLED="NO"):
                rasterio.shutil.copy(src, part, driver="NITF")
            Path(str(part) + ".aux.xml").unlink(missing_ok=True)
    return path


def _is_sidecar(path: Path) -> bool:
    n = path.name.upper()
    return n.endswith((".RPB", "_RPC.TXT"))


def read_rpc(
    path: str | os.PathLike[str], rows: int | None = None, cols: int | None = None, **sensor_options: Any
) -> RPCSensor:
    """An :class:`RPCSensor` from any source GDAL reads RPCs from, through rasterio.

    * a raster with RPC metadata (a GeoTIFF's RPC tag, a NITF's RPC00B TRE, ...);
    * a raster with a sidecar next to it: ``NAME.RPB`` (DigitalGlobe / Maxar)
      or ``NAME_RPC.TXT`` (GeoEye / Ikonos RPC00B text); GDAL finds these by
      the image's name and reports them in ``dataset.rpcs``;
    * a bare sidecar file (``.RPB`` or ``_RPC.TXT``): it is shown to GDAL
      beside a throw-away 1 x 1 raster of the matching name, so GDAL's own
      parser reads it. A sidecar carries no image size, so ``rows`` and
      ``cols`` are then required.

    Parameters
    ----------
    path : path-like
    rows, cols : int, optional
        Image size; default the raster's (height, width).
    **sensor_options
        Passed to :class:`RPCSensor` (``domain_latlon``, ``row_bias``, ...).

    Returns
    -------
    RPCSensor
    """
    note_input(path)
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    sensor_options.setdefault("name", path.stem)
    if _is_sidecar(path):
        if rows is None or cols is None:
            raise ValueError(f"{path}: a sidecar RPC file has no image size; give rows and cols")
        suffix = ".RPB" if path.name.upper().endswith(".RPB") else "_RPC.TXT"
        with tempfile.TemporaryDirectory() as tmp:
            stem = "image"
            shutil.copyfile(path, os.path.join(tmp, stem + suffix))
            img = os.path.join(tmp, stem + ".tif")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(img, "w", driver="GTiff", width=1, height=1, count=1, dtype="uint8") as dst:
                    dst.write(np.zeros((1, 1, 1), np.uint8))
                with rasterio.open(img) as src:
                    rpcs = _rpcs(src, path)
        if rpcs is None:
            raise ValueError(f"{path}: GDAL found no RPC in this file (not an RPB / RPC00B text file?)")
        return RPCSensor(RPCModel.from_rasterio(rpcs), int(rows), int(cols), **sensor_options)
    from rasterio.errors import RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as src:
                rpcs = _rpcs(src, path)
                size = (src.height, src.width)
    except RasterioError as e:  # found by fuzzing: "Cannot read 400040 bytes for NITF header", no file named
        raise ValueError(f"{path}: not a raster GDAL can read ({' '.join(str(e).split())})") from None
    if rpcs is None:
        raise ValueError(f"{path}: no RPC metadata (no RPC tag, and no .RPB or _RPC.TXT beside it)")
    return RPCSensor(
        RPCModel.from_rasterio(rpcs),
        int(size[0] if rows is None else rows),
        int(size[1] if cols is None else cols),
        **sensor_options,
    )


def _rpcs(src, path):
    """``src.rpcs``, with a value rasterio cannot read named with the file (fuzzing found a
    coefficient ``+0.0d+00`` raised "could not convert string to float" naming nothing)."""
    try:
        return src.rpcs
    except (ValueError, TypeError, KeyError, IndexError) as e:  # an empty value: IndexError in rasterio
        raise ValueError(f"{path}: RPC metadata that cannot be read: {type(e).__name__}: {e}") from None


# ------------------------------------------------------------------- GDAL
def gdal_rpc_to_ground(
    model: RPCModel,
    row: ArrayLike,
    col: ArrayLike,
    *,
    dem_path: str | os.PathLike[str] | None = None,
    height: float = 0.0,
    pixel_error_threshold: float | None = None,
    max_iterations: int | None = None,
    vdatum_shift: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
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
        Radians; NaN where GDAL fails on a point (rasterio >= 1.4 returns inf
        there with a ``TransformWarning``; older versions raised).
    """
    import rasterio
    from rasterio.errors import TransformWarning
    from rasterio.transform import RPCTransformer

    row = np.atleast_1d(np.asarray(row, float)).ravel()
    col = np.atleast_1d(np.asarray(col, float)).ravel()
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
    if row.size == 0:
        return np.zeros(0), np.zeros(0)
    # the Env registers GDAL's drivers, which RPC_DEM needs to open its file
    with rasterio.Env(), RPCTransformer(model.to_rasterio(), **opts) as tr, warnings.catch_warnings():
        warnings.simplefilter("ignore", TransformWarning)  # the failed points are NaN below
        try:
            x, y = tr.xy(row - 1.0, col - 1.0, zs=zs, offset="center")
            x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
        except Exception:  # rasterio < 1.4 raises on a failed point: one call per point then
            x, y = np.full(row.size, np.nan), np.full(row.size, np.nan)
            for i in range(row.size):
                try:
                    xi, yi = tr.xy(row[i] - 1.0, col[i] - 1.0, zs=zs[i], offset="center")
                    x[i], y[i] = float(np.ravel(xi)[0]), float(np.ravel(yi)[0])
                except Exception:
                    pass
    bad = ~(np.isfinite(x) & np.isfinite(y))
    x[bad] = np.nan
    y[bad] = np.nan
    return np.deg2rad(y), np.deg2rad(x)


# ------------------------------------------------------- GDAL RPC_DEM copy
def write_ellipsoidal_dem(dem: DEM, path: str | os.PathLike[str]) -> Path:
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
    with (
        atomic_path(path) as tmp,
        rasterio.open(
            tmp,
            "w",
            driver="GTiff",
            width=v.shape[1],
            height=v.shape[0],
            count=1,
            dtype="float64",
            crs="EPSG:4326",
            transform=t,
            nodata=np.nan,
        ) as dst,
    ):
        dst.write(v, 1)
        dst.update_tags(VERTICAL_DATUM="WGS-84 ellipsoidal heights (h = H + N, EGM96)", SOURCE=str(dem.path))
    return path


__all__ = [
    "RPC00B_FIELDS",
    "gdal_rpc_to_ground",
    "read_rpc",
    "read_rpc_geotiff",
    "rpc00b_renormalized",
    "write_ellipsoidal_dem",
    "write_rpc_geotiff",
    "write_rpc_nitf",
]
