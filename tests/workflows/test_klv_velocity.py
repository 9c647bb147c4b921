"""A time-tag error moves the platform by its velocity: the velocity of a KLV flight.

MISB ST 0601 carries the platform's horizontal velocity (tags 79 and 80, +/-327 m/s over int16)
and no vertical one; where the tags are absent the velocity is the positions differenced over
the time stamps. The oracles: klvdata's decoding of tags 79/80, pyproj's geodesic (the designed
track's azimuth at each point) and the closed form of a time-only budget over a level surface
(the hit moves by v dt, so the error ellipse is a segment along the track: CE90 = 1.6449 |v| sigma).
"""

import math

import numpy as np
import pytest
import scipy.stats as sps
from pyproj import Geod

from geoloc.io.klv import decode_packet, encode_packet
from geoloc.sensors.budget import ErrorBudget
from geoloc.workflows.klv_replay import VELOCITY_MAX_GAP_S, platform_velocity_ned, replay_klv

GEOD = Geod(ellps="WGS84")
T0 = 1_700_000_000_000_000  # us since 1970


def track(n, speed, az_deg, climb=0.0, dt=1.0, lat0=36.5, lon0=-84.25, h0=3000.0):
    """Points along a geodesic at ``speed`` m/s, climbing ``climb`` m/s; the forward azimuth at each."""
    s = speed * dt * np.arange(n)
    lon, lat, back = GEOD.fwd(np.full(n, lon0), np.full(n, lat0), np.full(n, az_deg), s)
    return np.asarray(lat), np.asarray(lon), h0 + climb * dt * np.arange(n), dt * np.arange(n), np.asarray(back) + 180


def test_tags_79_80_round_trip_as_klvdata_reads_them():
    import klvdata

    pk = encode_packet(
        {"precision_time_stamp_us": T0, "sensor_north_velocity_m_s": -12.34, "sensor_east_velocity_m_s": 250.0}
    )
    mine = decode_packet(pk).fields
    theirs = next(iter(klvdata.StreamParser(pk))).MetadataList()
    # int16 over +/-327 m/s: one step is 654 / 65534 = 0.00998 m/s, half a step after rounding
    assert mine["sensor_north_velocity_m_s"] == pytest.approx(-12.34, abs=0.005)
    assert mine["sensor_east_velocity_m_s"] == pytest.approx(250.0, abs=0.005)
    assert float(theirs[79][3]) == pytest.approx(mine["sensor_north_velocity_m_s"], abs=1e-6)
    assert float(theirs[80][3]) == pytest.approx(mine["sensor_east_velocity_m_s"], abs=1e-6)


def test_differenced_velocity_follows_the_geodesic():
    lat, lon, h, t, az = track(60, 50.0, 30.0, climb=2.0)
    v, src = platform_velocity_ned(lat, lon, h, t)
    # the geodesic runs at 50 m/s on the ellipsoid; 3 km above it the same angular rates are faster by
    # (M + h) / M northward and (N + h) / N eastward (meridian and prime-vertical radii, WGS 84)
    a, e2 = 6378137.0, 6.69437999014e-3
    w = 1 - e2 * np.sin(np.radians(lat)) ** 2
    M, N = a * (1 - e2) / w**1.5, a / np.sqrt(w)
    # the chord of a 100 m step turns from its tangent by ~ s / R (1.6e-5 rad): 1e-3 m/s is 1.2x that
    np.testing.assert_allclose(v[:, 0], 50.0 * np.cos(np.radians(az)) * (M + h) / M, atol=1e-3)
    np.testing.assert_allclose(v[:, 1], 50.0 * np.sin(np.radians(az)) * (N + h) / N, atol=1e-3)
    np.testing.assert_allclose(v[:, 2], -2.0, atol=1e-3)
    assert set(src) == {"differenced"}


def test_a_gap_or_a_stalled_clock_is_not_differenced():
    lat, lon, h, t, _ = track(6, 50.0, 90.0, h0=0.0)  # on the ellipsoid: 50 m/s exactly
    t = t.copy()
    t[3:] += VELOCITY_MAX_GAP_S + 1  # a gap between packets 2 and 3: each side differenced on its own
    v, src = platform_velocity_ned(lat, lon, h, t)
    assert np.isfinite(v).all()
    # across the gap the platform flew 50 m in 7 s: a velocity differenced across it would read ~7 m/s
    np.testing.assert_allclose(v[:, 1], 50.0, atol=1e-2)
    lone = platform_velocity_ned(lat[:1], lon[:1], h[:1], t[:1])
    assert not np.isfinite(lone[0]).any() and lone[1][0] == ""
    same = platform_velocity_ned(lat[:2], lon[:2], h[:2], np.zeros(2))  # two packets, one time stamp
    assert not np.isfinite(same[0]).any()


def axis_off(az_deg, want_deg):
    """How far an axis (az and az + 180 the same) is from ``want_deg`` [deg]."""
    d = (np.asarray(az_deg, float) - want_deg) % 180.0
    return np.minimum(d, 180.0 - d)


def _flight(tmp_path, n=8, speed=50.0, az=0.0, tags=None):
    lat, lon, h, t, _ = track(n, speed, az)
    pk = []
    for i in range(n):
        f = {
            "precision_time_stamp_us": T0 + int(round(t[i] * 1e6)),
            "platform_heading_deg": az,
            "platform_pitch_deg": 0.0,
            "platform_roll_deg": 0.0,
            "sensor_latitude_deg": lat[i],
            "sensor_longitude_deg": lon[i],
            "sensor_ellipsoid_height_m": h[i],
            "sensor_horizontal_fov_deg": 8.0,
            "sensor_vertical_fov_deg": 4.5,
            "sensor_relative_azimuth_deg": 0.0,
            "sensor_relative_elevation_deg": -90.0,
            "sensor_relative_roll_deg": 0.0,
            "frame_center_hae_m": 0.0,
        }
        if tags:
            f.update(sensor_north_velocity_m_s=tags[0], sensor_east_velocity_m_s=tags[1])
        pk.append(encode_packet(f))
    path = tmp_path / "v.klv"
    path.write_bytes(b"".join(pk))
    return path


def test_a_time_error_over_level_ground_is_a_segment_along_the_track(tmp_path):
    """Nadir over a level surface: a time error dt moves the hit by v dt (north here), so the 1-sigma
    ellipse is 5 m by 0 and CE90 is the normal 90 % two-sided quantile times 5 m."""
    r = replay_klv(_flight(tmp_path, speed=50.0, az=0.0), budget=ErrorBudget({"time_s": 0.1}))
    c = r.columns
    assert set(c["velocity_from"]) == {"differenced"}
    # tag 13's step (4.2e-8 deg = 5 mm) over 1 s steps: 0.01 m/s of 50, and the local frame's turn
    # over 3 km: 2e-3 relative
    np.testing.assert_allclose(c["ce90_m"], sps.norm.ppf(0.95) * 5.0, rtol=2e-3)
    np.testing.assert_allclose(axis_off(c["ellipse_azimuth_deg"], 0.0), 0.0, atol=0.5)
    assert np.all(np.asarray(c["le90_m"]) < 0.05)
    assert any("differenced positions for 8" in m for m in r.summary.notes)


def test_tags_79_80_give_the_horizontal_velocity(tmp_path):
    """The packets say 30 m/s east while their positions move north: the tags are the platform's
    own velocity and are used (the positions only fill the vertical, zero here)."""
    r = replay_klv(_flight(tmp_path, speed=50.0, az=0.0, tags=(0.0, 30.0)), budget=ErrorBudget({"time_s": 0.1}))
    c = r.columns
    assert set(c["velocity_from"]) == {"tags 79, 80"}
    np.testing.assert_allclose(c["velocity_east_m_s"], 30.0, atol=0.005)
    np.testing.assert_allclose(c["ce90_m"], sps.norm.ppf(0.95) * 3.0, rtol=2e-3)
    np.testing.assert_allclose(axis_off(c["ellipse_azimuth_deg"], 90.0), 0.0, atol=0.5)


def test_one_packet_leaves_the_time_term_out_and_says_so(tmp_path):
    r = replay_klv(_flight(tmp_path, n=1), budget=ErrorBudget({"time_s": 0.1, "north_m": 4.0}))
    c = r.columns
    assert any("time_s = 0.1 s left out" in m and "no packet has a velocity" in m for m in r.summary.notes)
    # only the platform's north error is left: a segment of 4 m
    np.testing.assert_allclose(c["ce90_m"], sps.norm.ppf(0.95) * 4.0, rtol=2e-3)
    assert math.isnan(c["velocity_north_m_s"][0])
