"""EGM96 undulation from the bundled grids (geoloc.geodesy.geoid)."""

import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from pyproj import Transformer

from geoloc.geodesy.geoid import GEOID_DIR, NodeGrid, egm96_undulation


def test_published_values():
    # docs/method.md section 4 / data README: N(35.58 N, 80.85 E) = -26.79 m, N(0, 0) = 17.16 m.
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


def _proj_vgridshift(grids: str):
    """PROJ's own vertical grid shift (+proj=vgridshift) reading the given GeoTIFF grids:
    (lon, lat, 0) in degrees -> N [m]. PROJ takes the first grid of the list that covers a
    point (``@``: optional), as egm96_undulation takes the finest bundled grid."""
    return Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grids} +multiplier=1 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )


def test_against_proj_reading_the_bundled_grids():
    """PROJ's bilinear interpolation of the very grids we bundle (GeoTIFF, nodes at pixel
    centres) against ours: the crops (15') where they hold a point, the global 30' copy
    elsewhere. Same float32 nodes, both bilinear in double: equal to rounding (measured
    2.5e-13 m; 1e-9 m). No Debian proj-data needed."""
    crops = ",".join(f"@{GEOID_DIR / n}" for n in ("egm96_flight_area.tif", "egm96_jacksboro.tif"))
    t = _proj_vgridshift(f"{crops},{GEOID_DIR / 'egm96_global_30min.tif'}")
    rng = np.random.default_rng(3)
    for s, n, w, e in [(34.0, 38.0, 76.0, 83.0), (35.5, 37.5, -85.5, -83.0), (-89.0, 89.0, -180.0, 180.0)]:
        la, lo = rng.uniform(s, n, 300), rng.uniform(w, e, 300)
        ref = np.asarray(t.transform(lo, la, np.zeros(la.size))[2])
        ours = egm96_undulation(np.deg2rad(la), np.deg2rad(lo))
        assert np.max(np.abs(ours - ref)) < 1e-9
    # the published checks through PROJ too: -26.79 m and +17.16 m
    ref = np.asarray(t.transform([80.85, 0.0], [35.58, 0.0], [0.0, 0.0])[2])
    assert ref == pytest.approx([-26.79, 17.16], abs=0.005)


def test_30min_copy_against_the_15min_crops():
    # assets/README: the 30' global copy stands in for the 15' grid outside the crops.
    # Inside the crops both exist: there the 30' copy is within 2 m (measured 1.58 m over
    # the Karakoram / Kunlun crop, RMS 0.34 m; 0.41 m over Jacksboro). The whole-globe
    # figure (within 1 m, RMS 0.1 m, 60 S-60 N) needs the full 15' grid (Debian
    # proj-data, tools/build_assets.py): a measurement, docs/testing.md.
    g = NodeGrid.from_geotiff(GEOID_DIR / "egm96_global_30min.tif")
    rng = np.random.default_rng(4)
    for (s, n, w, e), mx in [((34.0, 38.0, 76.0, 83.0), 2.0), ((35.5, 37.5, -85.5, -83.0), 0.5)]:
        la, lo = rng.uniform(s, n, 2000), rng.uniform(w, e, 2000)
        d = g.interp(la, lo) - egm96_undulation(np.deg2rad(la), np.deg2rad(lo))
        assert np.max(np.abs(d)) < mx


def test_proj_egm96_crs_with_the_bundled_grid(tmp_path):
    """EPSG:4979 -> EPSG:4326+5773 (EGM96 height), PROJ's own definition of the datum: with
    the bundled 30' grid written into a temporary PROJ data folder under the name PROJ
    looks for (us_nga_egm96_15.tif), H = h - N must equal our 30' interpolation, sign
    included. In a subprocess: pyproj's data path is process-wide state."""
    shutil.copy(GEOID_DIR / "egm96_global_30min.tif", tmp_path / "us_nga_egm96_15.tif")
    code = textwrap.dedent(f"""
        import json, numpy as np, pyproj, pyproj.datadir, pyproj.network
        pyproj.network.set_network_enabled(False)
        pyproj.datadir.append_data_dir({str(tmp_path)!r})
        t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
        rng = np.random.default_rng(3)
        la, lo = rng.uniform(-80, 80, 300), rng.uniform(-180, 180, 300)
        H = t.transform(lo, la, np.zeros(300))[2]
        print(json.dumps([list(map(float, la)), list(map(float, lo)), list(map(float, H))]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    la, lo, H = (np.array(v) for v in json.loads(r.stdout.strip().splitlines()[-1]))
    g = NodeGrid.from_geotiff(GEOID_DIR / "egm96_global_30min.tif")
    assert np.max(np.abs(-H - g.interp(la, lo))) < 1e-9
    assert np.max(np.abs(H)) > 10  # the grid was used (without it PROJ's "ballpark" gives 0)
