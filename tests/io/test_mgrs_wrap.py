"""MGRS references of longitudes outside -180..180 (geoloc.io.mgrs_grid.latlon_to_mgrs).

The function accepts longitudes in [-360, 360] (its docstring and its range check) and names the
same meridian for ``lon`` and ``lon -+ 360``. A mutation audit found no test that tried one. The
referee is ``tests/io/test_mgrs.py``'s ``oracle``: pyproj's UTM / UPS projections and the standard's
letter and zone rules (NGA.STND.0037), given the longitude wrapped **here** by ``math.remainder``
(IEEE remainder: the representative in [-180, 180]), never by the code under test. Exactly
+-180 deg is left out: the same meridian, named in zone 1 or zone 60 (a convention, not a
wrap), and the zone-edge test of ``test_mgrs.py`` stays clear of it too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_mgrs import EDGE, oracle

from geoloc.io.mgrs_grid import latlon_to_mgrs, mgrs_column, mgrs_text
from geoloc.status import Status


def wrapped(lon):
    return math.remainder(lon, 360.0)


POINTS = [
    (38.9, 181.0),
    (38.9, 359.5),
    (-33.9, -181.0),
    (10.0, -359.0),
    (0.5, 360.0),
    (-0.5, -360.0),
    (60.0, -355.0),  # Norway's 32V (5 E) reached through the wrap
    (78.0, -350.0),
    (78.0, -340.0),  # Svalbard's 33X (10 E, 20 E)
    (38.9, 180.0 + EDGE),
    (38.9, -180.0 - EDGE),
    (38.9, 360.0 - EDGE),
    (38.9, -360.0 + EDGE),
    (38.9, 282.0 + EDGE),
    (38.9, 282.0 - EDGE),  # 78 W's zone edge seen as 282 E
    (87.0, 225.0),
    (87.0, -225.0),
    (-85.0, -190.0),
    (-85.0, 315.0),  # the UPS caps, both sides
]


@pytest.mark.parametrize("lat,lon", POINTS)
def test_longitudes_beyond_180_name_the_wrapped_meridians_square(lat, lon):
    assert abs(lon) > 180.0
    r = latlon_to_mgrs(lat, lon)
    assert int(r.status) == Status.OK, r.reason
    assert r.text[()] == oracle(lat, wrapped(lon))


def test_random_longitudes_outside_180_in_a_batch():
    rng = np.random.default_rng(50)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, 300)))
    lon = rng.uniform(180.0 + 1e-6, 360.0, 300) * rng.choice([-1.0, 1.0], 300)
    r = latlon_to_mgrs(lat, lon)
    assert np.all(r.status == Status.OK)
    bad = [(a, o, t) for a, o, t in zip(lat, lon, r.text) if t != oracle(a, wrapped(o))]
    assert not bad, bad[:5]
    assert mgrs_column(lat[:3], lon[:3]) == [oracle(a, wrapped(o)) for a, o in zip(lat[:3], lon[:3])]


def test_the_ends_of_the_accepted_range():
    """+-360 are accepted (the prime meridian); beyond them a reason naming the value."""
    r = latlon_to_mgrs([0.5, 0.5, 0.5, 0.5], [360.0, -360.0, 360.0 + 1e-9, -360.0 - 1e-9])
    assert r.status.tolist() == [Status.OK, Status.OK, Status.INVALID_INPUT, Status.INVALID_INPUT]
    assert list(r.text[:2]) == [oracle(0.5, 0.0)] * 2
    assert "[-360, 360]" in r.reason[2] and "360.000000001" in r.reason[2]
    assert mgrs_text(38.9, 181.0).startswith(f"MGRS {oracle(38.9, -179.0)} (USNG ")


def test_precision_table_is_the_standards_square_sides():
    """NGA.STND.0037: k digits per axis name a square of 10^(5 - k) m (5: 1 m ... 0: 100 km)."""
    from geoloc.io.mgrs_grid import PRECISION_M

    assert PRECISION_M == {k: 10.0 ** (5 - k) for k in range(6)}
    full = oracle(38.9, -77.0)
    for k in range(6):
        assert latlon_to_mgrs(38.9, -77.0, precision=k).text[()] == full[:5] + full[5 : 5 + k] + full[10 : 10 + k]
    for bad in (-1, 6):
        with pytest.raises(ValueError, match="precision"):
            latlon_to_mgrs(0.0, 0.0, precision=bad)


def test_references_the_grid_does_not_have_are_refused_in_a_batch():
    """Well-formed references naming squares that do not exist (NGA.STND.0037): column A in zone
    18 (zone set 3 has the columns S-Z), zone 32X (Svalbard has 31X, 33X, 35X, 37X only). Each gets
    NaN, INVALID_INPUT and a reason naming it; the good reference between them is read."""
    from geoloc.io.mgrs_grid import mgrs_to_latlon

    good = oracle(38.9, -77.0)
    r = mgrs_to_latlon(["18SAA1234", good, "32XMF12"])
    assert r.status.tolist() == [Status.INVALID_INPUT, Status.OK, Status.INVALID_INPUT]
    assert np.isnan(r.lat_deg[[0, 2]]).all() and np.isfinite(r.lat_deg[1])
    assert "18SAA1234" in r.reason[0] and "32XMF12" in r.reason[2]
