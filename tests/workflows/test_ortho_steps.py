"""The image-grid GeoTIFF's steps (geoloc.workflows.ortho.write_frame_geotiff: ``_geotiff_profile``,
``_geotiff_tags``, ``_label_bands``, ``_write_chunks``), each alone, read back by GDAL (through
rasterio) from a file they wrote.

Oracles: GDAL's own report of what the file holds (its structure metadata, its tags, block shapes
and band descriptions), and closed forms for the chunks: degrees of the radians written, a count
per status equal to numpy's count of the codes handed in.
"""

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from geoloc.io.columns import ELLIPSOID_DATUM
from geoloc.status import Status
from geoloc.workflows import ortho


class _Bar:
    def __init__(self):
        self.done = 0

    def update(self, n):
        self.done += n


def _open_new(path, width, height):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # the image grid has no CRS by design
        return rasterio.open(path, "w", **ortho._geotiff_profile(width, height))


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return rasterio.open(path)


def test_profile_is_what_gdal_reads_back(tmp_path):
    f = tmp_path / "p.tif"
    with _open_new(f, 300, 20):
        pass
    with _read(f) as src:
        assert (src.width, src.height, src.count) == (300, 20, 4)
        assert src.dtypes == ("float64",) * 4
        assert math.isnan(src.nodata)
        assert src.block_shapes[0] == (256, 256)  # tiled: GDAL gives (rows, cols) of a block
        structure = src.tags(ns="IMAGE_STRUCTURE")
        assert structure["COMPRESSION"] == "DEFLATE" and structure["PREDICTOR"] == "3"


def test_tags_and_band_labels_are_what_gdal_reads_back(tmp_path):
    f = tmp_path / "t.tif"
    sensor = SimpleNamespace(rows=1080, cols=1920)
    with _open_new(f, 4, 3) as dst:
        dst.update_tags(**ortho._geotiff_tags(sensor, 4, {"flight": 7, "step": "caller's"}))
        ortho._label_bands(dst)
    with _read(f) as src:
        tags = src.tags()
        assert tags["sensor_rows"] == "1080" and tags["sensor_cols"] == "1920"
        assert tags["h_datum"] == ELLIPSOID_DATUM and tags["row_first"] == tags["col_first"] == "1"
        assert tags["flight"] == "7" and tags["step"] == "caller's"  # the caller's tags win, as text
        # every status code named once, by its number
        assert tags["status_codes"] == ", ".join(f"{int(s)}={s.name.lower()}" for s in Status)
        assert src.descriptions == ortho.BAND_DESCRIPTIONS
        assert [src.tags(b)["name"] for b in (1, 2, 3, 4)] == list(ortho.BANDS)
        # the status band's empty unit: GDAL keeps no empty item
        assert [src.tags(b).get("unit") for b in (1, 2, 3, 4)] == ["deg", "deg", "m", None]
        assert src.tags(3)["datum"] == ELLIPSOID_DATUM and "datum" not in src.tags(1)


def test_chunks_are_written_in_degrees_and_counted_per_status(tmp_path):
    rng = np.random.default_rng(3)
    width, height = 5, 7
    lat = np.radians(rng.uniform(-80, 80, (height, width)))
    lon = np.radians(rng.uniform(-180, 180, (height, width)))
    h = rng.uniform(0, 1000, (height, width))
    st = rng.choice([int(Status.OK), int(Status.SKY), int(Status.NODATA)], (height, width)).astype(np.uint8)
    lat[st != Status.OK] = np.nan
    # two chunks of whole rows, the second shorter
    chunks = [(0, 4, lat[:4], lon[:4], h[:4], st[:4]), (4, 7, lat[4:], lon[4:], h[4:], st[4:])]
    f, bar = tmp_path / "c.tif", _Bar()
    with _open_new(f, width, height) as dst:
        counts = ortho._write_chunks(dst, iter(chunks), width, bar)
    assert counts.tolist() == np.bincount(st.ravel(), minlength=len(Status)).tolist()
    assert bar.done == width * height
    with _read(f) as src:
        a, b, c, d = src.read()
    np.testing.assert_array_equal(a, np.degrees(lat))  # NaN where no point, the nodata value
    np.testing.assert_array_equal(b, np.degrees(lon))
    np.testing.assert_array_equal(c, h)
    np.testing.assert_array_equal(d, st.astype(float))


@pytest.mark.parametrize("step", [1, 3])
def test_tags_say_the_step(step):
    assert ortho._geotiff_tags(SimpleNamespace(rows=2, cols=3), step, None)["step"] == str(step)
