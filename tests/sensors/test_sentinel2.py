"""Sentinel-2 L1B's rigorous model against ESA's own viewing model, Sen2VM (Orekit Rugged).

The data is a trimmed copy of Sen2VM's test product TDS1 with its reference grids
(``tests/data/sentinel2/README.md``): detectors 06 and 07 (an even and an odd one: they look
forwards and backwards along track), bands B01 (60 m), B02 (10 m) and B05 (20 m).

Sen2VM's reference grids were made with light-time and aberration of light OFF
(``ruggedManager.setLightTimeCorrection(false)``, ``setAberrationOfLightCorrection(false)`` in
its ``Sen2VM.java``), refining ON, heights from its DEM and geoid (the sea here: the geoid);
the direct grids hold each point's height, so geoloc meets its line of sight with the surface of
that geodetic height and the comparison is horizontal.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import Transformer

from geoloc.corrections.lighttime import C_LIGHT, OMEGA_EARTH
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io import sentinel2 as s2
from geoloc.pipeline import Corrections, Pipeline
from geoloc.status import Status
from geoloc.surfaces.height import HeightSurface

DATA = Path(__file__).parents[1] / "data" / "sentinel2"
PRODUCT = DATA / "L1B"
#: Sen2VM's direct-location steps of testDirectLoc, in pixels of each band (600 for 10 m bands)
DIRECT_STEP = {10: 600, 20: 300, 60: 100}
#: testInverseLoc: the UTM 28N area (upper left, lower right) and its steps in metres per band size
INVERSE_UL, INVERSE_LR = (199980.0, 3700020.0), (309780.0, 3590220.0)
INVERSE_STEP = {10: 6000.0, 20: 3000.0, 60: 1000.0}
SEN2VM = Corrections()  # no light-time, no aberration: as the reference grids were made


@pytest.fixture(scope="module")
def product():
    return s2.read_product(PRODUCT)


def direct_cases():
    out = []
    for d in sorted((DATA / "ref" / "direct").iterdir()):
        for f in sorted(d.glob("*.tif")):
            out.append((d.name, re.search(r"_(B\w\w)\.tif$", f.name).group(1), f))
    return out


def reference_points(product, granule_id, band, f):
    """The reference grid's pixels (geoloc's 1-based rows and columns) and its lon, lat, height.

    Sen2VM's grid point (i, j) of a granule is Rugged's line 1 + step * i and pixel step * j of
    the detector's datastrip (``DirectLocGrid.get2Dgrid``: its 0.5 convention offsets cancel);
    Rugged's line L is dated first-line time + (L - 1) periods, as geoloc's row L, and its
    0-based pixel p is geoloc's column p + 1. A granule's grid starts at the grid row holding
    the granule's first line (``extractPointsDirectLoc``).
    """
    g = product.granules[granule_id]
    _, _, size, _ = s2.band_info(band)
    step = DIRECT_STEP[size]
    with rasterio.open(f) as ds:
        a = ds.read().astype(float)
    r0 = int(np.floor((g.first_row(band) - 1 + step / 2) / step))
    i, j = np.meshgrid(np.arange(a.shape[1]) + r0, np.arange(a.shape[2]), indexing="ij")
    return g, 1.0 + i * step, 1.0 + j * step, np.radians(a[0]), np.radians(a[1]), a[2]


def horizontal_m(lat1, lon1, lat2, lon2, h):
    p1 = geodetic_to_ecef(lat1, lon1, h)
    p2 = geodetic_to_ecef(lat2, lon2, h)
    return np.linalg.norm(p1 - p2, axis=-1)


def test_reader_finds_the_geometry_of_the_product(product):
    """The datastrip's GPS points (1 Hz), quaternions (10 Hz), line period and granules, as the file says."""
    ds = product.datastrip
    assert np.allclose(np.diff(ds.orbit_t).astype(np.int64), 1e9)
    assert np.allclose(np.diff(ds.attitude_t).astype(np.int64), 1e8)
    assert ds.line_period_10m_s == pytest.approx(1.565873622e-3)
    # the GPS orbit: |r| of a 786 km orbit (Sentinel-2's mean altitude) and |v| of 6.9-7.0 km/s Earth-fixed
    r = np.linalg.norm(ds.orbit_position_itrf, axis=1)
    assert np.all((r > 7.14e6) & (r < 7.19e6))
    assert np.allclose(np.linalg.norm(ds.q_eme2000_to_piloting, axis=1), 1.0, atol=1e-9)
    assert [g for g, _ in ds.granules["06"]][0].endswith("S20200816T120222_D06_N05.00")
    assert [p for _, p in ds.granules["06"]] == [1, 2305, 4609, 6913, 9217, 11521]
    # row 1 of B02 D06 is dated its GPS stamp plus half a 10 m line period
    t = product.datastrip.first_line_time("B02", 6)
    stamp = product.datastrip.first_line[(1, "06")][1]
    assert (t - stamp).astype(np.int64) == round(1.565873622e-3 / 2 * 1e9)
    assert product.datastrip.refining is not None
    assert product.eop_source.endswith(".txt")


@pytest.mark.parametrize("granule_id, band, f", direct_cases(), ids=lambda x: getattr(x, "name", str(x))[-30:])
def test_direct_location_matches_sen2vm_reference_grid(product, granule_id, band, f):
    """Every point of Sen2VM's direct-location grids within 0.5 m horizontally (measured: median
    0.04-0.22 m per grid, max 0.36 m).

    The tolerance: Rugged interpolates the attitude by Hermite polynomials over its neighbouring
    quaternions and Orekit the Earth orientation by its own rule; geoloc takes SLERP between
    two quaternions 0.1 s apart and a linear EOP; the 0.5 m bound is half the required 1 m and
    a twentieth of a 10 m pixel, where a half-line error would show 5 m and an unrefined
    model 4 m (test_refining_and_corrections_show_their_size).
    """
    g, row, col, lon, lat, h = reference_points(product, granule_id, band, f)
    sensor = product.sensor(band, g.detector)
    hit = Pipeline(sensor, HeightSurface(h, "geodetic"), SEN2VM).locate(row, col, outside="extrapolate")
    assert np.all(hit.status == Status.OK)
    d = horizontal_m(hit.lat, hit.lon, lat, lon, h)
    assert np.max(d) < 0.5, f"{granule_id} {band}: median {np.median(d):.3f} m, max {np.max(d):.3f} m"


def test_heights_on_sen2vm_geoid_match_every_grid(product):
    """Every point of the 36 reference grids, located on Sen2VM's own geoid (its EGM2008 15' grid,
    ``tests/data/sentinel2/geoid``, bilinear: the heights it writes are that geoid at its points
    to 1e-5 m), has Sen2VM's height to 1 cm (measured 4e-5 m at worst, over 870 points): the
    heights differ only by the geoid's slope (< 1e-4 here) times the 0.5 m horizontal
    difference. 0.5 m is required. On geoloc's bundled EGM96 the same heights differ by up
    to 1.76 m (median 0.22 m): the geoid model, not the location."""
    from geoloc.geodesy.geoid import grid_undulation
    from geoloc.workflows.sentinel2 import locate_on_geoid

    N = grid_undulation(DATA / "geoid" / "S2__OPER_DEM_GEOIDF_crop.tif")
    by_sensor: dict = {}  # one batch per band and detector: the granules' grids together
    for granule_id, band, f in direct_cases():
        g, row, col, _, _, h = reference_points(product, granule_id, band, f)
        by_sensor.setdefault((band, g.detector), []).append((row.ravel(), col.ravel(), h.ravel()))
    worst, worst96, n = 0.0, 0.0, 0
    for (band, det), parts in by_sensor.items():
        row, col, h = (np.concatenate(x) for x in zip(*parts))
        sensor = product.sensor(band, det)
        hit = locate_on_geoid(lambda hh: Pipeline(sensor, HeightSurface(hh, "geodetic"), SEN2VM), row, col, N)
        assert np.all(hit.status == Status.OK)
        worst = max(worst, float(np.max(np.abs(hit.h - h))))
        worst96 = max(worst96, float(np.max(np.abs(egm96_undulation(hit.lat, hit.lon) - h))))
        n += h.size
    assert n == 870 and len(by_sensor) == 6
    assert worst < 0.01, worst
    assert worst96 > 1.0, worst96


def test_refining_and_corrections_show_their_size(product):
    """Off the reference's settings the difference grows by what each term predicts.

    - light-time on: the ground point turns east by omega_E rho / c about the Earth's axis
      (rho the slant range): 1.0 m at 33.7 N from 786 km;
    - aberration on: the line of sight tilts by |v_inertial| sin(angle) / c towards the velocity,
      times the range: about 20 m along track;
    - refining off: the MSI rotation polynomials (3-4 microradians) move the grid by 3-4 m.
    """
    gid, band, f = next((g, b, f) for g, b, f in direct_cases() if "_D06_" in g and b == "B02")
    g, row, col, lon, lat, h = reference_points(product, gid, band, f)
    sensor = product.sensor(band, g.detector)
    surface = HeightSurface(h, "geodetic")
    base = Pipeline(sensor, surface, SEN2VM).locate(row, col)
    lt = Pipeline(sensor, surface, Corrections(light_time=True)).locate(row, col)
    ab = Pipeline(sensor, surface, Corrections(aberration=True)).locate(row, col)
    los = sensor.line_of_sight(row, col)
    rho = np.linalg.norm(base.ecef - los.origin_ecef, axis=-1)
    # light-time, closed form: an eastward turn of omega rho / c at the distance from the axis
    predicted_lt = OMEGA_EARTH * rho / C_LIGHT * np.hypot(base.ecef[..., 0], base.ecef[..., 1])
    moved_lt = np.linalg.norm(lt.ecef - base.ecef, axis=-1)
    assert np.allclose(moved_lt, predicted_lt, rtol=1e-3)
    assert 0.9 < np.median(moved_lt) < 1.1
    # aberration, first order: the direction turns by |v x u| / c; on the ground rho times that,
    # stretched by the slant of the ground under the ray (1 / cos of the view angle < 1.02 here)
    v = los.velocity_ecef + np.cross([0.0, 0.0, OMEGA_EARTH], los.origin_ecef)
    u = los.direction_ecef
    predicted_ab = rho * np.linalg.norm(np.cross(v, u), axis=-1) / C_LIGHT
    moved_ab = np.linalg.norm(ab.ecef - base.ecef, axis=-1)
    assert np.all(moved_ab / predicted_ab > 0.99) and np.all(moved_ab / predicted_ab < 1.03)
    assert 18 < np.median(moved_ab) < 22
    # the reference agrees with neither correction on: each adds its own shift to the difference
    d0 = horizontal_m(base.lat, base.lon, lat, lon, h)
    d_lt = horizontal_m(lt.lat, lt.lon, lat, lon, h)
    d_ab = horizontal_m(ab.lat, ab.lon, lat, lon, h)
    assert np.all(d_lt > moved_lt - d0 - 1e-6) and np.median(d_lt) > 0.8
    assert np.all(d_ab > moved_ab - d0 - 1e-6) and np.median(d_ab) > 17
    raw = product.sensor(band, g.detector, refining=False)
    hit_raw = Pipeline(raw, surface, SEN2VM).locate(row, col)
    d_raw = horizontal_m(hit_raw.lat, hit_raw.lon, lat, lon, h)
    assert 3.0 < np.median(d_raw) < 5.0, np.median(d_raw)


def inverse_cases():
    return sorted((DATA / "ref" / "inverse").glob("*.tif"))


@pytest.mark.parametrize("f", inverse_cases(), ids=lambda f: f.name[-11:-4])
def test_inverse_location_matches_sen2vm_reference_grid(product, f):
    """Sen2VM's inverse grid (UTM 28N points -> pixel): rows and columns to 0.04 px, medians < 0.01 px.

    The ground points: Sen2VM's grid over the configured area (``InverseLocGrid``: the first
    point at the upper left corner, then every step), EPSG:32628 -> WGS-84 by pyproj, at the
    geoid's height (the sea; geoloc's EGM96, whose 30' copy is within 0.6 m of the 15' grid:
    at these detectors' view angles, below 0.02 m on the ground). Sen2VM writes its pixels with
    the first pixel's centre at 0.5 (``get3Dgrid``: pixel + 0.5, line - 0.5 from Rugged's), so
    geoloc's 1-based centres are the reference + 0.5. The tolerance is the direct test's 0.5 m
    at 10 m and 20 m pixels (0.05 and 0.025 px); measured max 0.035 px (B02) and 0.018 (B05).
    """
    m = re.search(r"_D(\d\d)_(B\w\w)\.tif$", f.name)
    det, band = m.group(1), m.group(2)
    _, _, size, _ = s2.band_info(band)
    with rasterio.open(f) as ds:
        a = ds.read().astype(float)
    step = INVERSE_STEP[size]
    x = INVERSE_UL[0] + np.arange(a.shape[2]) * step
    y = INVERSE_UL[1] - np.arange(a.shape[1]) * step
    X, Y = np.meshgrid(x, y)
    lon_deg, lat_deg = Transformer.from_crs(32628, 4326, always_xy=True).transform(X, Y)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    h = egm96_undulation(lat, lon)
    px = Pipeline(product.sensor(band, det), HeightSurface(0.0), SEN2VM).ground_to_pixel(lat, lon, h)
    seen = np.isfinite(a[0])
    assert seen.sum() > 50
    # where Sen2VM finds no pixel the point is off this detector's image; geoloc says so too.
    # Sen2VM answers up to a few pixels beyond the image's columns (Rugged's inverse location
    # searches a margin around the sensor): geoloc gives those pixels too, flagged OUTSIDE_SENSOR
    assert np.all(np.isin(px.status[seen], (Status.OK, Status.OUTSIDE_SENSOR)))
    out = seen & (px.status == Status.OUTSIDE_SENSOR)
    assert np.all((px.col[out] > -10) & (px.col[out] < product.sensor(band, det).cols + 10))  # measured 8.2 px
    assert np.all(px.status[~seen] != Status.OK)
    dr = px.row[seen] - (a[1][seen] + 0.5)
    dc = px.col[seen] - (a[0][seen] + 0.5)
    tol = 0.5 / size
    assert np.max(np.abs(dr)) < tol and np.max(np.abs(dc)) < tol, (np.abs(dr).max(), np.abs(dc).max())
    assert np.median(np.abs(dr)) < 0.01 and np.median(np.abs(dc)) < 0.01
    # where the difference comes from: geoloc's pixel, located by geoloc's direct model, is ON the
    # ground point (measured < 1e-4 m: the inverse is exact), while Sen2VM's pixel, located by the
    # same direct model, lands 0.09-0.10 m (median) and up to 0.42 m away: the size of the two
    # direct models' disagreement on Sen2VM's direct grids (median 0.09 m, max 0.36 m here).
    # The residual against Sen2VM's inverse grid is the direct models' difference in pixels.
    sensor = product.sensor(band, det)
    on = Pipeline(sensor, HeightSurface(h[seen], "geodetic"), SEN2VM)
    ground = geodetic_to_ecef(lat[seen], lon[seen], h[seen])
    own = on.locate(px.row[seen], px.col[seen], outside="extrapolate").ecef
    theirs = on.locate(a[1][seen] + 0.5, a[0][seen] + 0.5, outside="extrapolate").ecef
    assert np.max(np.linalg.norm(own - ground, axis=-1)) < 1e-3
    miss = np.linalg.norm(theirs - ground, axis=-1)
    assert 0.05 < np.median(miss) < 0.15 and np.max(miss) < 0.5, (np.median(miss), np.max(miss))


def test_sen2vm_direct_points_inverted_give_its_pixels_to_the_direct_difference(product):
    """geoloc's inverse of Sen2VM's DIRECT grid points (each at its own height) returns Sen2VM's
    pixels to within the direct models' disagreement in pixels (0.5 m: 0.05 px at 10 m, 0.025 px
    at 20 m, 0.008 px at 60 m); measured medians 0.009 (B02), 0.004 (B05), 0.002 px (B01) and
    maxima 0.027, 0.018, 0.005 px: the same sizes as against Sen2VM's inverse grids (0.035 px),
    so Sen2VM's own direct and inverse agree with each other and differ from geoloc's by the
    direct model's 0.1-0.5 m. Three granules (one per band, both detectors) keep it fast."""
    picked = [c for c in direct_cases() if "S20200816T120226" in c[0]]
    assert len(picked) == 6
    for granule_id, band, f in picked:
        g, row, col, lon, lat, h = reference_points(product, granule_id, band, f)
        px = Pipeline(product.sensor(band, g.detector), HeightSurface(h, "geodetic"), SEN2VM).ground_to_pixel(
            lat, lon, h
        )
        e = np.hypot(px.row - row, px.col - col)
        assert np.all(np.isfinite(e))
        assert np.max(e) < 0.5 / s2.band_info(band)[2], (granule_id, band, np.max(e))


def test_round_trip_returns_every_pixel_to_a_millionth(product):
    """Pixel -> ground -> pixel with geoloc's own direct model, light-time and aberration on, over
    the whole image of a 10 m band (a 31 x 21 lattice from the first to the last line and column,
    corners included) and at two heights: back to 1e-6 px (0.01 px is required; measured
    4.2e-10 px at worst over 60 000 pixels of every band and detector of the test product, the
    Newton iteration on the line time stopping at 1e-7 line)."""
    sensor = product.sensor("B02", 6)
    row, col = np.meshgrid(np.linspace(1, sensor.rows, 31), np.linspace(1, sensor.cols, 21), indexing="ij")
    for h in (0.0, 3000.0):
        pipe = Pipeline(sensor, HeightSurface(h, "geodetic"), Corrections.for_sensor(sensor))
        hit = pipe.locate(row, col)
        back = pipe.ground_to_pixel(hit.lat, hit.lon, hit.h)
        assert np.all(back.status == Status.OK)
        assert np.max(np.abs(back.row - row)) < 1e-6 and np.max(np.abs(back.col - col)) < 1e-6


def test_frames_put_the_gps_orbit_on_the_onboard_inertial_orbit(product):
    """The ITRF -> EME2000 rotation (astropy/ERFA with the product's IERS values) carries the GPS
    orbit onto the satellite's own on-board (AOCS) EME2000 ephemeris, an independent source in
    the same metadata, to 29 m (measured 27.8-29.0 m: the on-board propagator's error, smooth and
    along track); without the UT1-UTC of the product's file the same check misses by 94-96 m
    (the Earth turning 0.27 s more), without precession-nutation since J2000 by kilometres.
    """
    from geoloc.frames.earth import EarthOrientation, R_itrs_eme2000
    from geoloc.sensors.pushbroom import Orbit

    ds = product.datastrip
    epoch = ds.orbit_t[0]

    def secs(t):
        return (t - epoch).astype(np.int64) * 1e-9

    orbit = Orbit(secs(ds.orbit_t), ds.orbit_position_itrf, ds.orbit_velocity_itrf)
    ta = secs(ds.aocs_t)
    ok = (ta > orbit.span[0]) & (ta < orbit.span[1])
    assert ok.sum() >= 10
    p_itrs, _ = orbit.state(ta[ok])

    def miss(eop):
        R = R_itrs_eme2000(ds.aocs_t[ok], eop)
        return np.linalg.norm(np.einsum("nji,nj->ni", R, p_itrs) - ds.aocs_position[ok], axis=1)

    assert np.all(miss(product.eop) < 29.5)
    e = product.eop
    no_ut1 = EarthOrientation(e.mjd_utc, 0 * e.ut1_utc_s, e.xp_arcsec, e.yp_arcsec)
    assert np.all(miss(no_ut1) > 80)  # measured 94-96 m


def test_frames_agree_with_the_equinox_based_route():
    """ERFA's CIO-based c2t06a (the route geoloc takes) against the classical equinox-based one
    written out here: polar motion x Greenwich apparent sidereal time x precession-nutation-bias
    (IERS Conventions 2010 eq. 5.1 vs 5.2; ERFA pom00, gst06, pnm06a), at the product's date.
    The two must agree to the microarcsecond level (the models' difference, IERS TN36 5.5.4)."""
    import erfa

    from geoloc.frames.earth import EarthOrientation, R_itrs_eme2000, TT_MINUS_TAI_S, gps_to_astropy

    eop = EarthOrientation(np.array([59077.0, 59078.0]), [-0.27381, -0.27347], [0.2393, 0.2396], [0.3620, 0.3603])
    t = np.array(["2020-08-16T12:02:30", "2020-08-16T12:02:50"], "datetime64[ns]")
    R = R_itrs_eme2000(t, eop)
    tai = gps_to_astropy(t)
    utc = tai.utc
    dut1, xp, yp = eop.at(utc.mjd)
    tt1, tt2 = tai.jd1, tai.jd2 + TT_MINUS_TAI_S / 86400
    ut1, ut2 = utc.jd1, utc.jd2 + dut1 / 86400
    npb = erfa.pnm06a(tt1, tt2)  # GCRS -> true equator and equinox of date
    gst = erfa.gst06(ut1, ut2, tt1, tt2, npb)
    w = erfa.pom00(xp, yp, erfa.sp00(tt1, tt2))
    rb, _, _ = erfa.bp06(tt1, tt2)
    rz = np.stack([[[np.cos(g), np.sin(g), 0], [-np.sin(g), np.cos(g), 0], [0, 0, 1]] for g in gst])
    R2 = w @ rz @ npb @ np.swapaxes(rb, -1, -2)
    # the largest element of R - R2 bounds the small angle between them (arccos of the trace
    # would drown 1e-10 rad in its own rounding)
    assert np.abs(R - R2).max() < 1e-10  # 20 microarcseconds; 1e-10 rad is 0.08 mm at 786 km


def test_ut1utc_file_reads_the_bulletin_rows():
    """The IERS file's 2020-08-16 row (MJD 59077): x 0.2393", y 0.3620", UT1-UTC -0.27381 s,
    the same values as the datastrip's own IERS_Bulletin element."""
    from geoloc.frames.earth import ARCSEC

    eop = s2.read_ut1utc(next((PRODUCT / "IERS").glob("*UT1UTC*")))
    dut1, xp, yp = eop.at(np.array([59077.0]))
    assert dut1[0] == pytest.approx(-0.27381)
    assert xp[0] == pytest.approx(0.2393 * ARCSEC)
    assert yp[0] == pytest.approx(0.3620 * ARCSEC)
    ds = s2.read_datastrip(next(PRODUCT.glob("DATASTRIP/*/*.xml")))
    assert ds.iers == pytest.approx((-0.27381, 0.2393, 0.362))
    with pytest.raises(ValueError, match="outside the Earth orientation table"):
        eop.at(np.array([50000.0]))


def test_gps_dates_become_utc_with_the_leap_seconds():
    """GPS = UTC + 18 s in 2020 (TAI - UTC = 37 s since 2017-01-01, GPS = TAI - 19 s)."""
    from geoloc.frames.earth import utc_to_gps

    t = np.datetime64("2020-08-16T12:02:33.085", "ns")
    assert utc_to_gps(t) - t == np.timedelta64(18, "s")


def test_bad_product_is_named(tmp_path, product):
    with pytest.raises(ValueError, match="not a folder"):
        s2.read_product(tmp_path / "nothing")
    with pytest.raises(ValueError, match="band = 'B13'"):
        product.sensor("B13", 6)
    with pytest.raises(ValueError, match="detector = 13"):
        product.sensor("B02", 13)
    bad = tmp_path / "ds.xml"
    bad.write_text("<root><General_Info/></root>")
    with pytest.raises(ValueError, match="Datastrip_Time_Info"):
        s2.read_datastrip(bad)
    with pytest.raises(ValueError, match="no granule metadata for detector 01"):
        product.granule(1)


def test_a_point_located_and_inverted_returns_its_pixel(product):
    """Pixel -> ground (with light-time and aberration) -> pixel returns the pixel to 1e-6 px."""
    sensor = product.sensor("B05", 7)
    pipe = Pipeline(sensor, HeightSurface(50.0, "geodetic"), Corrections.for_sensor(sensor))
    row = np.array([1.0, 500.5, 5000.0, 6912.0])
    col = np.array([1.0, 638.0, 1276.0, 17.25])
    hit = pipe.locate(row, col)
    assert hit.corrections == ("aberration", "light_time")
    back = pipe.ground_to_pixel(hit.lat, hit.lon, hit.h)
    assert np.all(back.status == Status.OK)
    assert np.allclose(back.row, row, atol=1e-6) and np.allclose(back.col, col, atol=1e-6)
    lat, lon, h = ecef_to_geodetic(hit.ecef)
    assert np.allclose(h, 50.0, atol=1e-6)


def test_frames_download_nothing(monkeypatch):
    """The Earth orientation runs with the network cut: astropy's IERS auto-download is off
    (geoloc sets it before building any astropy time) and the IERS values are the product's."""
    import socket

    from astropy.utils import iers

    from geoloc.frames.earth import EarthOrientation, R_itrs_eme2000, utc_to_gps

    def refuse(*a, **k):
        raise AssertionError("a network connection was attempted")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    eop = EarthOrientation(np.array([59077.0, 59078.0]), [-0.27381, -0.27347], [0.2393, 0.2396], [0.3620, 0.3603])
    t = utc_to_gps(np.array(["2020-08-16T18:00:00"], "datetime64[ns]"))
    R = R_itrs_eme2000(t, eop)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-12)
    assert iers.conf.auto_download is False


def test_dem_surface_of_the_sea_gives_the_geoid_grid(tmp_path):
    """``--dem`` with a DEM of zeros (orthometric, EGM96: the sea) gives the ``--geoid`` grid: the
    DEM path of the grid verb, to 2 cm: 24 of 25 points agree to 1e-8 m, one by 1.5 cm (the DEM
    walk meets the geoid as heights of the DEM's 0.02 deg cells, the geoid surface samples N
    bilinearly between its 30' nodes at the hit: where the ray crosses a kink of N they differ)."""
    import warnings

    from affine import Affine
    from rasterio.errors import NotGeoreferencedWarning

    from geoloc.cli import main

    dem = tmp_path / "sea.tif"
    with rasterio.open(
        dem, "w", driver="GTiff", width=200, height=200, count=1, dtype="float32", crs="EPSG:4326",
        transform=Affine(0.02, 0.0, -19.5, 0.0, -0.02, 34.5),
    ) as ds:  # fmt: skip
        ds.write(np.zeros((1, 200, 200), np.float32))
    common = ["s2", "grid", str(PRODUCT), "--band", "B01", "--detector", "7", "--granule", "1"]
    assert main([*common, "--dem", str(dem), "--out", str(tmp_path / "d.tif")]) == 0
    assert main([*common, "--geoid", "--out", str(tmp_path / "g.tif")]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # the grids are in the image's geometry
        with rasterio.open(tmp_path / "d.tif") as a, rasterio.open(tmp_path / "g.tif") as b:
            x, y = a.read(), b.read()
    p = geodetic_to_ecef(np.radians(x[1]), np.radians(x[0]), x[2])
    q = geodetic_to_ecef(np.radians(y[1]), np.radians(y[0]), y[2])
    assert np.max(np.linalg.norm(p - q, axis=-1)) < 0.02


def _product_with(tmp_path, old: str, new: str):
    """The test product with one element of its datastrip metadata rewritten (the rest linked)."""
    import shutil

    root = tmp_path / "L1B"
    for name in ("GRANULE", "GIPP", "IERS"):
        (root / name).mkdir(parents=True)
        for p in (PRODUCT / name).iterdir():
            (root / name / p.name).symlink_to(p)
    src = next(PRODUCT.glob("DATASTRIP/*/*.xml"))
    dst = root / "DATASTRIP" / src.parent.name / src.name
    dst.parent.mkdir(parents=True)
    text = src.read_text()
    assert text.count(old) == 1
    dst.write_text(text.replace(old, new))
    shutil.copymode(src, dst)
    return s2.read_product(root)


def test_focal_plane_refining_turns_its_focal_plane_only(tmp_path, product):
    """A ``Focal_Plane_State`` rotation of 2 microradians about the VNIR focal plane's X (its
    along-track axis: u = [tan psi_y, -tan psi_x, 1]) turns a VNIR band's lines of sight across
    track: on the ground, the slant range times 2e-6 rad (1.6 m from 790 km), stretched by the
    slant of the ground under the ray (measured ratios 0.99996-1.0006; 1 % allowed, the stretch
    at detector 06's view angles), at right angles to the ground track (its along-track part
    measured below 3e-4 of the shift; 1 % allowed); the same term on the SWIR focal plane leaves
    the VNIR bands exactly where they were, and the round trip still returns each pixel."""
    eps = 2e-6
    rotation = (
        f"<Rotation><X><DEGREE>0</DEGREE><COEFFICIENTS>{eps!r}</COEFFICIENTS></X>"
        "<Y><DEGREE>0</DEGREE><COEFFICIENTS>0</COEFFICIENTS></Y><Z><DEGREE>0</DEGREE><COEFFICIENTS>0</COEFFICIENTS></Z>"
        "</Rotation>"
    )
    row = np.array([1.0, 3000.0, 9000.0, 13824.0])
    col = np.array([1.0, 1276.0, 2000.0, 2552.0])
    base_sensor = product.sensor("B02", 6)
    surface = HeightSurface(45.0, "geodetic")
    base = Pipeline(base_sensor, surface, SEN2VM).locate(row, col)

    vnir = _product_with(
        tmp_path / "v",
        '<Focal_Plane_State focalPlaneId="VNIR" />',
        f'<Focal_Plane_State focalPlaneId="VNIR">{rotation}</Focal_Plane_State>',
    )
    assert vnir.datastrip.refining.focal_plane["VNIR"][0][0] == (eps,)
    sensor = vnir.sensor("B02", 6)
    pipe = Pipeline(sensor, surface, SEN2VM)
    hit = pipe.locate(row, col)
    moved = hit.ecef - base.ecef
    los = base_sensor.line_of_sight(row, col)
    rho = np.linalg.norm(base.ecef - los.origin_ecef, axis=-1)
    ratio = np.linalg.norm(moved, axis=-1) / (rho * eps)
    assert np.all((ratio > 0.99) & (ratio < 1.01)), ratio
    # the ground track's direction: the velocity, made horizontal at the ground point
    up = base.ecef / np.linalg.norm(base.ecef, axis=-1, keepdims=True)
    v = los.velocity_ecef - np.sum(los.velocity_ecef * up, axis=-1, keepdims=True) * up
    along = np.abs(np.sum(moved * v, axis=-1)) / np.linalg.norm(v, axis=-1)
    assert np.all(along < 0.01 * np.linalg.norm(moved, axis=-1))
    back = pipe.ground_to_pixel(hit.lat, hit.lon, hit.h)
    assert np.allclose(back.row, row, atol=1e-6) and np.allclose(back.col, col, atol=1e-6)

    swir = _product_with(
        tmp_path / "s",
        '<Focal_Plane_State focalPlaneId="SWIR" />',
        f'<Focal_Plane_State focalPlaneId="SWIR">{rotation}</Focal_Plane_State>',
    )
    same = Pipeline(swir.sensor("B02", 6), surface, SEN2VM).locate(row, col)
    assert np.array_equal(same.ecef, base.ecef)


def test_spacecraft_position_refining_is_refused_by_name(tmp_path):
    """``Spacecraft_Position`` offsets are given "in the local spacecraft reference frame" with
    no axes named by the format or used in Sen2VM's own code (it hands them to a library not in
    its repository): a product that carries them is refused by name with refining on, and
    located without any refining when asked."""
    poly = "<X><DEGREE>0</DEGREE><COEFFICIENTS>1.5</COEFFICIENTS></X>"
    prod = _product_with(tmp_path, "<Spacecraft_Position />", f"<Spacecraft_Position>{poly}</Spacecraft_Position>")
    assert prod.datastrip.refining.position == ((1.5,), (0.0,), (0.0,))
    with pytest.raises(ValueError, match="Spacecraft_Position.*no-refining"):
        prod.sensor("B02", 6)
    raw = prod.sensor("B02", 6, refining=False)
    assert raw.refining_rotation == ((0.0,), (0.0,), (0.0,))
