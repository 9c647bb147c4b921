"""Build the small terrain and geoid GeoTIFF crops committed in ``assets/``.

Run once on a machine with the Debian packages ``proj-data`` and
``ferret-datasets`` and the ``matplotlib`` sample data (see
``assets/README.md``)::

    python tools/build_assets.py          # writes assets/dem/*.tif, assets/geoid/*.tif

Tests never run this script: they read the committed crops. Each file carries
its provenance (source package, file, licence, vertical datum, how it was cut)
in its GeoTIFF tags, and ``assets/README.md`` repeats it.

Grid registration: every source here is a grid of *nodes* (values at points).
A node grid is written as a GeoTIFF whose pixel centres are the nodes
(``AREA_OR_POINT=Area`` with the transform shifted by half a cell), which is
what GDAL and :class:`geoloc.surfaces.dem.DEM` assume when interpolating.
"""

from __future__ import annotations

import argparse
import datetime as _dt
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.transform import from_origin

ROOT = Path(__file__).resolve().parents[1]
EGM96_GTX = Path("/usr/share/proj/egm96_15.gtx")
ETOPO5_CDF = Path("/usr/share/ferret-vis/data/etopo5.cdf")

#: Flight-test area of [Q17] (Tables 1, 3, 4: 35.5-36.6 N, 78.7-81.0 E) with margin.
FLIGHT_AREA = dict(south=34.0, north=38.0, west=76.0, east=83.0)
#: Around the Jacksboro SRTM tile (36.45-36.73 N, 84.41-84.08 W) with margin.
JACKSBORO_AREA = dict(south=35.5, north=37.5, west=-85.5, east=-83.0)


def _write(path: Path, data, west_node, north_node, dlon, dlat, tags, nodata=None, predictor=2):
    """Write a node grid (row 0 = north) as a compressed GeoTIFF with tags."""
    path.parent.mkdir(parents=True, exist_ok=True)
    transform = from_origin(west_node - dlon / 2, north_node + dlat / 2, dlon, dlat)
    profile = dict(
        driver="GTiff",
        width=data.shape[1],
        height=data.shape[0],
        count=1,
        dtype=data.dtype.name,
        crs="EPSG:4326",
        transform=transform,
        compress="deflate",
        predictor=predictor,
        zlevel=9,
        nodata=nodata,
    )
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)
        dst.update_tags(
            AREA_OR_POINT="Area", BUILT_BY="tools/build_assets.py", BUILT_ON=_dt.date.today().isoformat(), **tags
        )
    print(
        f"{path.relative_to(ROOT)}: {data.shape[0]} x {data.shape[1]} {data.dtype}, {path.stat().st_size / 1024:.0f} kB"
    )


def build_geoid(out: Path):
    """EGM96 15' grid (NGA, public domain): crops at full resolution + 30' global copy."""
    with rasterio.open(EGM96_GTX) as src:
        n = src.read(1).astype(np.float32)
        t = src.transform
    # gtx: nodes at lon -180 + 0.25 k, lat 90 - 0.25 k (transform has the half-cell shift).
    lon0 = t.c + t.a / 2
    lat0 = t.f + t.e / 2
    step = t.a
    assert abs(lon0 + 180) < 1e-9 and abs(lat0 - 90) < 1e-9 and abs(step - 0.25) < 1e-12, t
    lons = lon0 + step * np.arange(n.shape[1])
    lats = lat0 - step * np.arange(n.shape[0])
    common = dict(
        SOURCE_PACKAGE="Debian proj-data",
        SOURCE_FILE=str(EGM96_GTX),
        LICENCE="public domain (NGA/NASA EGM96)",
        QUANTITY="geoid undulation N above WGS-84 [m]",
        VERTICAL_DATUM="EGM96 geoid height N (h = H + N)",
        INTERPOLATION="bilinear between nodes, as PROJ does for .gtx",
    )
    for name, area in (("egm96_flight_area", FLIGHT_AREA), ("egm96_jacksboro", JACKSBORO_AREA)):
        rows = np.where((lats >= area["south"] - 1e-9) & (lats <= area["north"] + 1e-9))[0]
        cols = np.where((lons >= area["west"] - 1e-9) & (lons <= area["east"] + 1e-9))[0]
        crop = n[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
        _write(
            out / f"{name}.tif",
            crop,
            lons[cols[0]],
            lats[rows[0]],
            step,
            step,
            dict(common, CUT=f"15' nodes, {area}"),
            predictor=3,
        )
    # Global copy at 30' (every second node, 1.0 MB budget): the full 15' grid as
    # float32 is 2.7 MB compressed. Add the +180 column so the grid closes.
    g = n[::2, ::2]
    g = np.concatenate([g, g[:, :1]], axis=1)
    _write(
        out / "egm96_global_30min.tif",
        g,
        -180.0,
        90.0,
        0.5,
        0.5,
        dict(common, CUT="every second 15' node (30' grid), -180..180 E, 90 S..90 N"),
        predictor=3,
    )


def build_etopo5(out: Path):
    """ETOPO5 (NOAA NGDC, public domain) over the [Q17] flight-test area."""
    from scipy.io import netcdf_file

    with netcdf_file(ETOPO5_CDF, "r", mmap=False) as f:
        x = f.variables["ETOPO05_X"].data.astype(float)
        y = f.variables["ETOPO05_Y"].data.astype(float)
        z = f.variables["ROSE"].data.astype(np.float32)
    # The file's Y axis is exactly -90..90 by 5'. Its X axis is 0..359.92 by
    # 0.0833341 deg, a rounding artefact of the ferret conversion (360/4320 is
    # 5' exactly and ETOPO5 is defined on the 5' grid with the first node at 0 E):
    # we use the exact 5' node longitudes k/12 deg.
    assert len(x) == 4320 and abs(x[0]) < 1e-9 and abs(y[1] - y[0] - 1 / 12) < 1e-9
    lon = np.arange(4320) / 12.0
    lat = y
    rows = np.where((lat >= FLIGHT_AREA["south"] - 1e-9) & (lat <= FLIGHT_AREA["north"] + 1e-9))[0]
    cols = np.where((lon >= FLIGHT_AREA["west"] - 1e-9) & (lon <= FLIGHT_AREA["east"] + 1e-9))[0]
    crop = z[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1][::-1]  # file rows go south -> north
    crop = np.round(crop).astype(np.int16)  # ETOPO5 heights are whole metres
    _write(
        out / "etopo5_flight_area.tif",
        crop,
        lon[cols[0]],
        lat[rows[-1]],
        1 / 12,
        1 / 12,
        dict(
            SOURCE_PACKAGE="Debian ferret-datasets",
            SOURCE_FILE=str(ETOPO5_CDF) + " variable ROSE",
            LICENCE="public domain (NOAA NGDC ETOPO5)",
            UNITS="metre",
            VERTICAL_DATUM="orthometric, mean sea level (use dem_datum='egm96')",
            CUT=f"5' nodes {FLIGHT_AREA}; node longitudes taken as exact k/12 deg "
            "(the file's X axis drifts to 359.92 at the last node)",
        ),
        nodata=-32768,
    )


def build_srtm(out: Path):
    """SRTM 3'' Jacksboro fault tile from matplotlib's sample data."""
    import matplotlib.cbook as cbook

    # numpy's NpzFile (np.load of the .npz); matplotlib's annotation says an array or a file
    d: Any = cbook.get_sample_data("jacksboro_fault_dem.npz")
    z = d["elevation"].astype(np.int16)
    dx, dy = float(d["dx"]), float(d["dy"])
    # Keys: xmin/xmax are the west/east *edges*; ymin (36.73292) is the NORTH edge
    # and ymax the south edge; row 0 is north. 403 * dx = xmax - xmin, so edges.
    west_edge, north_edge = float(d["xmin"]), float(d["ymin"])
    assert north_edge > float(d["ymax"])
    assert abs((float(d["xmax"]) - west_edge) / dx - z.shape[1]) < 1e-3
    assert abs((north_edge - float(d["ymax"])) / dy - z.shape[0]) < 1e-3
    _write(
        out / "srtm_jacksboro.tif",
        z,
        west_edge + dx / 2,
        north_edge - dy / 2,
        dx,
        dy,
        dict(
            SOURCE_PACKAGE="matplotlib (sample data)",
            SOURCE_FILE="matplotlib.cbook.get_sample_data('jacksboro_fault_dem.npz')",
            LICENCE="public domain (NASA/USGS SRTM 3 arc-second, via matplotlib sample data)",
            UNITS="metre",
            VERTICAL_DATUM="orthometric, EGM96 (use dem_datum='egm96')",
            CUT="whole tile, 3'' (about 90 m) cells; key ymin is the north edge",
        ),
    )


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "assets", help="assets folder (default: %(default)s)")
    a = p.parse_args(argv)
    build_geoid(a.out / "geoid")
    build_etopo5(a.out / "dem")
    build_srtm(a.out / "dem")


if __name__ == "__main__":
    main()
