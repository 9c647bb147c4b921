"""The named steps of the height audit (geoloc.analysis.height_audit.audit_flight), each alone.

The ray geometry is built with pymap3d (a point at a given azimuth, elevation and range from the
platform, both ends to ECEF), not with geoloc's own geodesy.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from geoloc.analysis.height_audit import (
    MODEL_GAIN,
    Finding,
    _best_shift,
    _height_over_reported,
    _one_flat_earth,
    _pick_correction,
)
from geoloc.surfaces.base import LineOfSight

LAT0, LON0, H0 = 36.6, -84.25, 3000.0  # a platform 3 km up over the Jacksboro crop


def _rays_to(points):
    """Lines of sight from the platform through each geodetic (lat_deg, lon_deg, h_m) point."""
    o = np.array(pymap3d.geodetic2ecef(LAT0, LON0, H0))
    p = np.array([pymap3d.geodetic2ecef(*q) for q in points])
    d = p - o
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return LineOfSight(np.broadcast_to(o, d.shape).copy(), d, np.zeros(len(points), np.uint8))


def _along(az_deg, el_deg, srange_m):
    return pymap3d.aer2geodetic(az_deg, el_deg, srange_m, LAT0, LON0, H0)


def test_height_over_the_reported_centre_is_where_the_ray_passes_over_it():
    # the reported centre is the ray's point near 300 m (about the terrain there: the segment's far
    # end) and near 150 m (halfway: the height read linearly along the ground track); the heights
    # are pymap3d's of those points (over a curved earth, 1.2 m and 0.5 m above the nominal ones)
    q300 = _along(60.0, -35.0, (H0 - 300.0) / math.sin(math.radians(35.0)))
    q150 = _along(200.0, -50.0, (H0 - 150.0) / math.sin(math.radians(50.0)))
    los = _rays_to([q300, q150])
    rlat = np.deg2rad([q300[0], q150[0]])
    rlon = np.deg2rad([q300[1], q150[1]])
    dem_r = np.array([300.0, 300.0])
    h = _height_over_reported(los, rlat, rlon, dem_r, np.full(2, H0))
    # linear along the track: the ray's height over a ground track of under 500 m between h = 0 and
    # h = 300 m departs from a straight line by the earth's curvature, (500 m)^2 / (2 R) = 0.02 m
    # (measured: 0.1 mm and 4.8 mm)
    np.testing.assert_allclose(h, [q300[2], q150[2]], atol=0.05)


def test_a_ray_near_nadir_says_nothing_of_the_height():
    # off nadir by 0.5 deg: the ground track moves under MIN_TRACK_SLOPE per metre of height
    q = _along(90.0, -89.5, H0 - 200.0)
    los = _rays_to([q])
    h = _height_over_reported(los, np.deg2rad([q[0]]), np.deg2rad([q[1]]), np.array([200.0]), np.array([H0]))
    assert np.isnan(h[0])


def test_best_shift_pairs_each_reported_centre_with_the_record_it_belongs_to():
    rng = np.random.default_rng(0)
    n = 30
    lat_c = np.deg2rad(36.6 + 0.001 * np.arange(n))  # recomputed centres ~110 m apart
    lon_c = np.deg2rad(-84.25 + rng.uniform(0, 1e-4, n))
    k = np.clip(np.arange(n) + 2, 0, n - 1)  # the reported centre of record i is record i + 2's
    rlat, rlon = lat_c[k], lon_c[k]
    raw = 220.0  # about the unshifted misfit
    s, m = _best_shift(rlat, rlon, lat_c, lon_c, raw, None)
    assert (s, m) == (2, 0.0)
    # two flights of 15: a shift never pairs records of two flights, and still finds the 2
    group = np.repeat(["a", "b"], 15)
    assert _best_shift(rlat, rlon, lat_c, lon_c, raw, group)[0] == 2
    # nothing better than the misfit as it is: no shift
    assert _best_shift(lat_c, lon_c, lat_c + 1e-3, lon_c, 0.0, None) == (0, 0.0)


def test_pick_correction_needs_the_gain_and_breaks_ties_by_preference():
    raw = 30.0
    # no correction cuts the misfit MODEL_GAIN times: none named
    assert _pick_correction({"flat": raw / MODEL_GAIN * 1.01, "height": raw}, raw, False) is None
    # the least misfit wins when alone within the tie
    assert _pick_correction({"boresight": 1.0, "flat": 5.0}, raw, False) == "boresight"
    # a tie (within TIE_FACTOR) goes to the fixed-size correction first ...
    assert _pick_correction({"height": 1.0, "flat": 1.1, "boresight": 1.05}, raw, False) == "flat"
    # ... unless the height matches a datum signature
    assert _pick_correction({"height": 1.0, "flat": 1.1}, raw, True) == "height"
    assert _pick_correction({"height": 1.2, "flat": 1.0}, raw, True) == "height"


def test_one_flat_earth_seen_twice_is_one_finding():
    def flat(detail):
        return Finding("flat_earth_frame_centre", "frame centres", 0.0, 1.0, "m", 0.0, "", 3, detail=detail)

    other = Finding("boresight_bias", "pointing", 0.1, 0.01, "deg", math.nan, "", 3)
    out = _one_flat_earth([flat("from the heights"), other, flat("from the rays")])
    assert [f.kind for f in out] == ["boresight_bias", "flat_earth_frame_centre"]
    assert out[1].detail == "from the rays; from the heights"
    assert _one_flat_earth([other, flat("x")]) == [other, flat("x")]
