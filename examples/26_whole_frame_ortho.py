"""26: a whole frame onto the DEM in one call, written as a GeoTIFF; a drone photo's orthophoto.

Every 8th pixel of the 2323 x 2292 [Q17] sensor at record T3-1 over the bundled
ETOPO5 DEM (``step=8``: 291 x 287 = 83 517 rays; the full frame is 5.3 M rays,
``benchmarks/bench_whole_frame.py``), then the bundled DJI photo orthorectified at
0.5 m on the SRTM crop. The same as::

    geoloc ortho --record T3-1 --step 8 --out frame.tif
    geoloc ortho --photo assets/photos/DJI_0001.JPG --dem assets/dem/srtm_jacksboro.tif \
        --out photo_grid.tif --ortho-out photo_ortho.tif --gsd-m 0.5
"""

import tempfile
from pathlib import Path

import numpy as np

from geoloc.io.photos import photo_sensor, pose_from_photo, read_photo
from geoloc.io.records import load_records
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.dem import DEM
from geoloc.workflows.ortho import (
    locate_frame,
    orthorectify,
    read_photo_pixels,
    write_frame_geotiff,
)

sensor = load_sensor("assets/cameras/qiao2017.toml")  # a camera file loads as its FrameSensor
pose = load_records("assets/records/qiao2017_flight_tests.csv").subset([0]).pose()  # T3-1
dem = DEM.open("assets/dem/etopo5_flight_area.tif")  # heights EGM96, made ellipsoidal on reading

grid = locate_frame(sensor, pose, dem, step=8)
print(f"frame grid {grid.shape[0]} x {grid.shape[1]} (step {grid.step}): {grid.counts()}")
for name, (i, j) in {
    "top-left": (0, 0),
    "top-right": (0, -1),
    "bottom-left": (-1, 0),
    "bottom-right": (-1, -1),
}.items():
    print(
        f"  {name:12s} pixel ({grid.rows[i]:.0f}, {grid.cols[j]:.0f}): lat {grid.lat_deg[i, j]:.6f} deg "
        f"lon {grid.lon_deg[i, j]:.6f} deg h {grid.h[i, j]:.1f} m ({grid.h_datum})"
    )

with tempfile.TemporaryDirectory() as tmp:
    info = write_frame_geotiff(Path(tmp) / "frame.tif", sensor, pose, dem, step=8)
    print(f"GeoTIFF bands lat_deg, lon_deg, h_m, status: {info['shape'][0]} x {info['shape'][1]}")

    meta = read_photo("assets/photos/DJI_0001.JPG")
    s, _ = photo_sensor(meta)
    srtm = DEM.open("assets/dem/srtm_jacksboro.tif")
    o = orthorectify(read_photo_pixels(meta.path), s, pose_from_photo(meta), srtm, Path(tmp) / "ortho.tif", gsd_m=0.5)
    seen = o["cells_seen"] / (o["width"] * o["height"])
    print(
        f"orthophoto {o['width']} x {o['height']} cells of {o['gsd_m']:g} m ({o['crs']}): "
        f"{o['cells_seen']} seen ({100 * seen:.0f} %), {o['cells_hidden']} hidden behind terrain"
    )
    print(f"footprint diagonal {np.hypot(o['width'], o['height']) * o['gsd_m']:.0f} m")
