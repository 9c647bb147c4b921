"""63: a real satellite: one Sentinel-2 L1B pixel to the ground and back, against ESA's Sen2VM.

The trimmed Sen2VM test product (tests/data/sentinel2, a checkout's test data): band B02 of
detector 06, the pixel (row 1201, column 1201) of its first granule, on the sea (the surface of
the height Sen2VM's grid gives there). Sen2VM made its grid with light-time and aberration off;
geoloc's default (Rugged's) has them on: the example prints both.

Run: python examples/63_sentinel2_pixel_to_ground.py
"""

from pathlib import Path

import numpy as np
import rasterio

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.io.sentinel2 import read_product
from geoloc.pipeline import Corrections, Pipeline
from geoloc.surfaces.height import HeightSurface

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "sentinel2"
product = read_product(DATA / "L1B")
sensor = product.sensor("B02", 6)
print(f"{sensor.name}: {sensor.rows} lines x {sensor.cols} pixels, line period {sensor.line_period_s * 1e3:.4f} ms")
print(f"Earth orientation from {Path(product.eop_source).name}")

# Sen2VM's grid point (2, 2) of the granule is pixel (1201, 1201): lon, lat, height bands
ref_file = next((DATA / "ref" / "direct").glob("*120222_D06_N05.00/*_B02.tif"))
with rasterio.open(ref_file) as ds:
    lon_ref, lat_ref, h_ref = (float(b[2, 2]) for b in ds.read())
print(f"Sen2VM:                     {lat_ref:.7f} N {lon_ref:.7f} E, h {h_ref:.2f} m (WGS 84 ellipsoid)")

surface = HeightSurface(h_ref, "geodetic")
ref = geodetic_to_ecef(np.radians(lat_ref), np.radians(lon_ref), h_ref)
for label, corr in (
    ("as Sen2VM (no light-time, no aberration)", Corrections()),
    ("Rugged's default (light-time, aberration)", Corrections.for_sensor(sensor)),
):
    pipe = Pipeline(sensor, surface, corr)
    hit = pipe.locate(1201.0, 1201.0)
    d = float(np.linalg.norm(hit.ecef - ref))
    back = pipe.ground_to_pixel(hit.lat, hit.lon, hit.h)
    print(f"geoloc, {label}: {np.degrees(hit.lat):.7f} N {np.degrees(hit.lon):.7f} E, {d:.3f} m from Sen2VM")
    print(f"  and back: row {float(back.row):.4f}, col {float(back.col):.4f}")
