"""Print geoloc's agreement with Sen2VM's reference grids, per band and detector (docs/sentinel2.md).

    python tools/s2_agreement.py                       # the trimmed test product (tests/data/sentinel2)
    python tools/s2_agreement.py SEN2VM_CHECKOUT       # Sen2VM's whole TDS1: 72 granules x 13 bands

For each direct-location grid of Sen2VM (``testDirectLoc``: refining on, light-time and
aberration off), geoloc locates the same pixels with the same settings on the surface of each
point's own height, and prints the horizontal distance: per band and detector, the median
and the maximum over the detector's granules (metres); then, with light-time and aberration
on (geoloc's and Rugged's defaults), the same medians: what each correction adds.
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np
import rasterio

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.io import sentinel2 as s2
from geoloc.pipeline import Corrections, Pipeline
from geoloc.surfaces.height import HeightSurface

ROOT = Path(__file__).resolve().parents[1]
STEP = {10: 600, 20: 300, 60: 100}


def layout(arg):
    """(product folder, folder of the reference's granule folders) for the test data or a Sen2VM checkout."""
    if arg is None:
        d = ROOT / "tests" / "data" / "sentinel2"
        return d / "L1B", d / "ref" / "direct", None
    repo = Path(arg)
    tds1 = repo / "src/test/resources/tests/input/TDS1"
    # Sen2VM keeps the GIPP and IERS files beside the product: link them into one folder
    tmp = Path(tempfile.mkdtemp(prefix="s2_agreement_"))
    for name in ("DATASTRIP", "GRANULE"):
        (tmp / name).symlink_to(tds1 / "L1B_all" / name)
    (tmp / "GIPP").symlink_to(tds1 / "inputs/GIPP")
    (tmp / "IERS").symlink_to(tds1 / "inputs/IERS")
    return tmp, repo / "src/test/resources/tests/ref/testDirectLoc/GRANULE", tmp


def distances(product, granule, band, ref_file, corrections):
    _, _, size, _ = s2.band_info(band)
    step = STEP[size]
    with rasterio.open(ref_file) as ds:
        a = ds.read().astype(float)
    r0 = int(np.floor((granule.first_row(band) - 1 + step / 2) / step))
    i, j = np.meshgrid(np.arange(a.shape[1]) + r0, np.arange(a.shape[2]), indexing="ij")
    lon, lat, h = np.radians(a[0]), np.radians(a[1]), a[2]
    sensor = product.sensor(band, granule.detector)
    hit = Pipeline(sensor, HeightSurface(h, "geodetic"), corrections).locate(1.0 + i * step, 1.0 + j * step)
    p = geodetic_to_ecef(hit.lat, hit.lon, h)
    return np.linalg.norm(p - geodetic_to_ecef(lat, lon, h), axis=-1).ravel()


def main(argv) -> int:
    prod_dir, ref_dir, _tmp = layout(argv[1] if len(argv) > 1 else None)
    product = s2.read_product(prod_dir)
    sen2vm = Corrections()
    rugged = Corrections(light_time=True, aberration=True)
    table: dict[tuple, list[list]] = {}  # (band, detector) -> [Sen2VM's, Rugged's corrections] distances
    for gdir in sorted(p for p in ref_dir.iterdir() if p.is_dir()):
        if gdir.name not in product.granules:
            continue
        g = product.granules[gdir.name]
        for f in sorted(gdir.rglob("*.tif")):
            m = re.search(r"_(B\w\w)\.tif$", f.name)
            assert m is not None, f"{f}: not a band's grid (..._Bxx.tif)"
            band = m.group(1)
            d0 = distances(product, g, band, f, sen2vm)
            d1 = distances(product, g, band, f, rugged)
            t = table.setdefault((band, g.detector), [[], []])
            t[0].append(d0)
            t[1].append(d1)
    print("geoloc vs Sen2VM direct-location grids, horizontal distance [m] at the grid's heights")
    print(f"product {prod_dir}")
    print("band det grids points  median    max   | light-time + aberration on: median")
    all0, n = [], 0
    for (band, det), (d0, d1) in sorted(table.items()):
        a0, a1 = np.concatenate(d0), np.concatenate(d1)
        all0.append(a0)
        n += len(d0)
        print(
            f"{band}  {det}  {len(d0):5d} {a0.size:6d}  {np.median(a0):6.3f} {a0.max():6.3f}   | {np.median(a1):7.2f}"
        )
    a = np.concatenate(all0)
    print(f"all        {n:5d} {a.size:6d}  {np.median(a):6.3f} {a.max():6.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
