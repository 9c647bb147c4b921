"""ENU conversions checked against PROJ's topocentric conversion (outside the code)."""

import numpy as np
import pyproj
import pytest

from geoloc.frames.enu import EnuFrame
from geoloc.geodesy.local import R_ecef_enu

# PROJ's +proj=topocentric (geocentric -> local ENU); pure arithmetic, no grids.
ORIGINS = [(36.3, 78.85, 4500.0), (-33.9, 151.2, 10.0), (0.0, 0.0, 0.0), (89.0, -170.0, 1000.0)]


@pytest.mark.parametrize("lat0, lon0, h0", ORIGINS)
def test_from_ecef_matches_pyproj_topocentric(lat0, lon0, h0):
    frame = EnuFrame.from_deg(lat0, lon0, h0)
    geo = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x0, y0, z0 = geo.transform(lon0, lat0, h0)
    topo = pyproj.Transformer.from_pipeline(f"+proj=topocentric +ellps=WGS84 +X_0={x0!r} +Y_0={y0!r} +Z_0={z0!r}")
    rng = np.random.default_rng(6)
    p = np.array([x0, y0, z0]) + rng.normal(0, 30e3, (50, 3))
    e, n, u = topo.transform(p[:, 0], p[:, 1], p[:, 2])
    ours = frame.from_ecef(p)
    # 1e-6 m: both are a rotation and a translation in float64 of vectors of
    # ~5e4 m (ulp 7e-12 m); PROJ's origin comes from its own geodetic->ECEF
    # (agreeing with ours to ~1e-9 m).
    np.testing.assert_allclose(ours, np.stack([e, n, u], -1), atol=1e-6)
    np.testing.assert_allclose(frame.to_ecef(ours), p, atol=1e-6)


def test_axes_closed_form_at_equator_prime_meridian():
    # At (0, 0): E = +Y, N = +Z, U = +X of ECEF (closed form).
    np.testing.assert_allclose(R_ecef_enu(0.0, 0.0), [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-15)


def test_origin_and_geodetic_round_trip():
    f = EnuFrame.from_deg(36.3, 78.85, 4500.0)
    np.testing.assert_allclose(f.from_geodetic(f.lat0, f.lon0, f.h0), 0.0, atol=1e-8)
    # A point 1000 m straight up the ellipsoid normal is (0, 0, 1000) in ENU.
    np.testing.assert_allclose(f.from_geodetic(f.lat0, f.lon0, f.h0 + 1000.0), [0, 0, 1000], atol=1e-8)
    lat, lon, h = f.to_geodetic([1000.0, -2000.0, 300.0])
    np.testing.assert_allclose(f.from_geodetic(lat, lon, h), [1000.0, -2000.0, 300.0], atol=1e-6)
