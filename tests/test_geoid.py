"""EGM96 undulation from the bundled grids (geoloc.geodesy.geoid)."""

from pathlib import Path

import numpy as np
import pytest

from geoloc.geodesy.geoid import GEOID_DIR, NodeGrid, egm96_undulation

GTX = Path("/usr/share/proj/egm96_15.gtx")


def test_published_values():
    # GEOMETRY.md section 4 / data README: N(35.58 N, 80.85 E) = -26.79 m, N(0, 0) = 17.16 m.
    # The published values have 2 decimals: 0.005 m is their rounding.
    n = egm96_undulation(np.deg2rad([35.58, 0.0]), np.deg2rad([80.85, 0.0]))
    assert n[0] == pytest.approx(-26.79, abs=0.005)
    assert n[1] == pytest.approx(17.16, abs=0.005)


def test_global_copy_alone_gives_n00(tmp_path):
    # N(0, 0) must come from the bundled global copy (no crop covers it): a node of the 30' grid.
    g = NodeGrid.from_geotiff(GEOID_DIR / "egm96_global_30min.tif")
    assert g.interp(0.0, 0.0) == pytest.approx(17.16, abs=0.005)
    assert g.interp(0.0, 180.0) == pytest.approx(g.interp(0.0, -180.0), abs=1e-6)  # grid closes


def test_missing_grid_is_an_error(tmp_path):
    # pyproj returns N = 0 silently without its grid; we must raise.
    with pytest.raises(FileNotFoundError, match="EGM96"):
        egm96_undulation(0.1, 0.2, folder=tmp_path)


def test_batch_and_bad_input():
    lat = np.deg2rad(np.array([[36.5, np.nan], [95.0, -89.9]]))
    lon = np.deg2rad(np.array([[-84.2, 0.0], [0.0, 370.0]]))
    n = egm96_undulation(lat, lon)
    assert n.shape == (2, 2)
    assert np.isfinite(n[0, 0]) and np.isnan(n[0, 1]) and np.isnan(n[1, 0]) and np.isfinite(n[1, 1])
    # longitude wraps: 370 E is 10 E
    assert n[1, 1] == pytest.approx(egm96_undulation(np.deg2rad(-89.9), np.deg2rad(10.0)), abs=1e-9)


@pytest.mark.skipif(not GTX.is_file(), reason="proj-data's egm96_15.gtx not installed (optional cross-check)")
def test_against_proj_with_full_grid():
    import pyproj

    pyproj.datadir.append_data_dir(str(GTX.parent))
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    rng = np.random.default_rng(3)
    # inside the crops PROJ's bilinear on the same 15' nodes must agree to float32 rounding (< 1 mm)
    for (s, n, w, e) in [(34.0, 38.0, 76.0, 83.0), (35.5, 37.5, -85.5, -83.0)]:
        la, lo = rng.uniform(s, n, 50), rng.uniform(w, e, 50)
        ref = -np.asarray(t.transform(lo, la, np.zeros(50))[2])
        assert np.max(np.abs(egm96_undulation(np.deg2rad(la), np.deg2rad(lo)) - ref)) < 1e-3
    # elsewhere the 30' copy: within 2 m of the 15' grid away from the poles (documented figure)
    la, lo = rng.uniform(-60, 60, 300), rng.uniform(-180, 180, 300)
    ref = -np.asarray(t.transform(lo, la, np.zeros(300))[2])
    err = np.abs(egm96_undulation(np.deg2rad(la), np.deg2rad(lo)) - ref)
    assert np.max(err) < 2.0
