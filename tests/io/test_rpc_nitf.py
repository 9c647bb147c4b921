"""NITF 2.1 with an RPC00B TRE: written through GDAL (rasterio, NITF driver), read by read_rpc.

The independent reader of the TRE is this file: the RPC00B fields are cut from
the TRE's raw text (GDAL's "TRE" metadata domain) by the widths of STDI-0002
Appendix E, written out below, and compared with what GDAL's RPC reader gives
and with the known model, field by field, to the precision the text keeps.
"""

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from geoloc.analysis.rpc_fit import fit_rpc
from geoloc.assets import asset_path
from geoloc.io.rpc_gdal import read_rpc, rpc00b_renormalized, write_rpc_geotiff, write_rpc_nitf
from geoloc.sensors.rpc import RPCModel, rpc_terms
from geoloc.workflows.scenario import load_scenario

# RPC00B (STDI-0002 App. E): SUCCESS, ERR_BIAS, ERR_RAND, then the ten normalisation fields,
# then 4 x 20 coefficients of 12 characters (+d.ddddddE+d); (name, width, decimals)
TRE_FIELDS = [
    ("success", 1, 0),
    ("err_bias", 7, 2),
    ("err_rand", 7, 2),
    ("line_off", 6, 0),
    ("samp_off", 5, 0),
    ("lat_off", 8, 4),
    ("long_off", 9, 4),
    ("height_off", 5, 0),
    ("line_scale", 6, 0),
    ("samp_scale", 5, 0),
    ("lat_scale", 8, 4),
    ("long_scale", 9, 4),
    ("height_scale", 5, 0),
]
COEFFS = ("line_num", "line_den", "samp_num", "samp_den")
NORM = [f for f, _, _ in TRE_FIELDS[3:]]


def parse_rpc00b(text: str) -> dict:
    """The RPC00B TRE's text -> field name -> float (coefficients as arrays of 20)."""
    assert len(text) == 1 + 7 + 7 + 6 + 5 + 8 + 9 + 5 + 6 + 5 + 8 + 9 + 5 + 80 * 12 == 1041
    out, i = {}, 0
    for name, w, _ in TRE_FIELDS:
        out[name] = float(text[i : i + w])
        i += w
    for name in COEFFS:
        vals = [text[i + 12 * k : i + 12 * (k + 1)] for k in range(20)]
        assert all(len(v) == 12 and v[0] in "+-" and v[2] == "." and v[9] == "E" for v in vals), vals
        out[name] = np.array([float(v) for v in vals])
        i += 240
    return out


def tre_text(path) -> str:
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path) as src:
        assert src.driver == "NITF"
        return src.tags(ns="TRE")["RPC00B"]


def coeff_half_unit(c):
    """Half a unit of the 7th significant digit of +d.ddddddE+d; |c| < 1e-9 has no exponent digit (0)."""
    c = np.abs(np.asarray(c, float))
    e = np.floor(np.log10(np.where(c > 0, c, 1.0)))
    return np.where(c >= 1e-9, 0.5e-6 * 10.0**e, 1e-9)


@pytest.fixture(scope="module")
def zy3():
    sc = load_scenario(asset_path("scenarios", "zy3_nadir.toml"))
    fit = fit_rpc(sc.sensor, sc.height_min, sc.height_max, sc.grid, sc.check_grid)
    return sc, fit.model


def _cube_points(m: RPCModel, n=2000, seed=33):
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (3, n))
    return (
        np.deg2rad(m.lat_off + u[0] * m.lat_scale),
        np.deg2rad(m.long_off + u[1] * m.long_scale),
        m.height_off + u[2] * m.height_scale,
    )


def test_the_tre_holds_the_90_values_to_its_text_precision(zy3, tmp_path):
    _, m = zy3
    ntf = write_rpc_nitf(tmp_path / "plain.ntf", m, 64, 64, renormalize=False)
    assert not Path(str(ntf) + ".aux.xml").exists()  # the file alone carries the RPC
    tre = parse_rpc00b(tre_text(ntf))
    got = read_rpc(ntf, rows=24576, cols=24576).model
    # GDAL's reader and the text agree exactly on all 90 values (10 normalisation + 80 coefficients)
    for k in NORM:
        assert getattr(got, k) == tre[k], k
    for k in COEFFS:
        assert np.array_equal(getattr(got, k), tre[k]), k
    # and each is the known model's value to the text's precision: half a unit of the last digit
    for name, _, dec in TRE_FIELDS[3:]:
        assert abs(tre[name] - getattr(m, name)) <= 0.5 * 10.0**-dec + 1e-12, name
    for k in COEFFS:
        assert np.all(np.abs(tre[k] - getattr(m, k)) <= coeff_half_unit(getattr(m, k)) * (1 + 1e-9)), k
    assert sum(1 for _ in NORM) + 20 * len(COEFFS) == 90


def test_renormalized_nitf_is_read_exactly_and_locates_as_the_geotiff(zy3, tmp_path):
    sc, m = zy3
    ntf = write_rpc_nitf(tmp_path / "scene.ntf", m, 64, 64)
    tre = parse_rpc00b(tre_text(ntf))
    nitf = read_rpc(ntf, rows=sc.sensor.rows, cols=sc.sensor.cols)
    mn = nitf.model
    for k in NORM:  # the renormalised constants are what RPC00B stores exactly
        assert getattr(mn, k) == tre[k] == getattr(rpc00b_renormalized(m), k), k
    # the same RPC through the GeoTIFF path: every value equal, and image -> ground equal
    tif = write_rpc_geotiff(tmp_path / "scene.tif", mn, sc.sensor.rows, sc.sensor.cols)
    gt = read_rpc(tif)
    for k in NORM:
        assert getattr(gt.model, k) == getattr(mn, k), k
    for k in COEFFS:
        assert np.array_equal(getattr(gt.model, k), getattr(mn, k)), k
    rows, cols = np.meshgrid(np.linspace(1, sc.sensor.rows, 9), np.linspace(1, sc.sensor.cols, 9))
    for h in (200.0, 650.0, 1400.0):
        a = nitf.ground_at_height(rows, cols, h)
        b = gt.ground_at_height(rows, cols, h)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        assert np.isfinite(a[0]).all()
    hit = nitf.ground_to_pixel(a[0], a[1], np.full(a[0].shape, 1400.0))
    assert np.max(np.hypot(hit.row - rows, hit.col - cols)) < 1e-6  # and back: the inversion's tolerance


def test_renormalizing_keeps_the_model_and_plain_rounding_does_not(zy3, tmp_path):
    _, m = zy3
    lat, lon, h = _cube_points(m)
    r0, c0 = m.ground_to_pixel(lat, lon, h)
    # exact re-expression: only float64 rounding (the pixels are ~1e4, so 1e-8 px is 1e-12 relative)
    r1, c1 = rpc00b_renormalized(m).ground_to_pixel(lat, lon, h)
    assert np.max(np.hypot(r1 - r0, c1 - c0)) < 1e-8
    renorm = read_rpc(write_rpc_nitf(tmp_path / "r.ntf", m, 64, 64), rows=24576, cols=24576).model
    plain = read_rpc(write_rpc_nitf(tmp_path / "p.ntf", m, 64, 64, renormalize=False), rows=24576, cols=24576).model
    r2, c2 = renorm.ground_to_pixel(lat, lon, h)
    r3, c3 = plain.ground_to_pixel(lat, lon, h)
    # the bound of 7 significant digits: on the cube every |term| <= 1, so a ratio num/den moves by at
    # most (sum of num's half units + |ratio| * sum of den's half units) / |den|, times the image scale
    mr = rpc00b_renormalized(m)
    T = rpc_terms(*mr.normalise(lat, lon, h))
    bound = []
    for img in ("line", "samp"):
        num, den = getattr(mr, f"{img}_num"), getattr(mr, f"{img}_den")
        d = np.abs(T @ den)
        ratio = (T @ num) / (T @ den)
        hn, hd = coeff_half_unit(num).sum(), coeff_half_unit(den)[1:].sum()  # den[0] = 1 is exact
        bound.append((hn + np.abs(ratio) * hd) / (d - hd) * getattr(mr, f"{img}_scale"))
    assert np.all(np.abs(r2 - r0) <= bound[0]) and np.all(np.abs(c2 - c0) <= bound[1])
    moved = np.hypot(r2 - r0, c2 - c0).max()
    plain_moved = np.hypot(r3 - r0, c3 - c0).max()
    print(
        f"NITF RPC00B: renormalised max {moved:.2e} px (bound {max(b.max() for b in bound):.2e} px); "
        f"offsets just rounded max {plain_moved:.2f} px"
    )
    assert plain_moved > 100 * moved  # LINE_OFF 12287.5 -> 12288 alone is half a pixel


def test_read_rpc_on_a_nitf_without_rpc_says_so(tmp_path):
    from rasterio.errors import NotGeoreferencedWarning

    p = tmp_path / "plain.ntf"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(p, "w", driver="NITF", width=8, height=8, count=1, dtype="uint8") as dst:
            dst.write(np.zeros((1, 8, 8), np.uint8))
    with pytest.raises(ValueError, match="no RPC"):
        read_rpc(p)


def test_a_bare_sidecar_needs_both_rows_and_cols(tmp_path):
    """An .RPB or _RPC.TXT alone carries no image size: one of the two is not enough."""
    for name in ("alone.RPB", "alone_RPC.TXT"):
        p = tmp_path / name
        p.write_text("")
        for kw in ({}, {"rows": 64}, {"cols": 64}):
            with pytest.raises(ValueError, match="a sidecar RPC file has no image size; give rows and cols"):
                read_rpc(p, **kw)


def test_the_image_size_is_read_as_rows_then_cols(zy3, tmp_path):
    """A NITF and a GeoTIFF of 48 lines x 80 samples: the sensor has 48 rows and 80 columns (GDAL's
    height and width), unless rows and cols are given."""
    _, m = zy3
    for path in (write_rpc_nitf(tmp_path / "wide.ntf", m, 48, 80), write_rpc_geotiff(tmp_path / "wide.tif", m, 48, 80)):
        with rasterio.open(path) as src:
            assert (src.height, src.width) == (48, 80)
        s = read_rpc(path)
        assert (s.rows, s.cols) == (48, 80)
        s = read_rpc(path, rows=100, cols=200)
        assert (s.rows, s.cols) == (100, 200)
