"""SurfaceSpec.dem takes what its annotation says: a path (str or path-like), a sequence of them, or
None; the spec holds one path as a str and several as a tuple of str, so that it is hashable."""

from __future__ import annotations

from pathlib import Path

import pytest

from geoloc.surfaces.spec import SurfaceSpec


@pytest.mark.parametrize(
    "given, held",
    [
        (None, None),
        ("a.tif", "a.tif"),
        (Path("dem") / "a.tif", str(Path("dem") / "a.tif")),
        ([Path("a.tif")], "a.tif"),  # one path in a sequence is that path
        ((Path("a.tif"), "b.tif"), ("a.tif", "b.tif")),
        (["a.tif", Path("b.tif")], ("a.tif", "b.tif")),
    ],
)
def test_dem_is_held_as_str_or_tuple_of_str(given, held):
    spec = SurfaceSpec(dem=given)
    assert spec.dem == held and type(spec.dem) is type(held)
    assert hash(spec) == hash(SurfaceSpec(dem=held))  # a campaign's cache key


def test_a_mosaic_is_no_raster_and_is_named():
    with pytest.raises(ValueError, match=r"--dem a.tif, b.tif is a mosaic"):
        SurfaceSpec(dem=[Path("a.tif"), Path("b.tif")]).raster()
