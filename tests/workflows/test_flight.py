"""The simulated flight (geoloc.workflows.flight): track checked with pyproj's inverse geodesic, scan in closed form."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod

from geoloc.assets import ASSETS
from geoloc.workflows.flight import FlightScenario, simulate, whisk_broom

SCENARIO = Path(ASSETS) / "scenarios" / "flight_scan.toml"


def _data():
    return tomllib.loads(SCENARIO.read_text())


def test_bundled_scenario_loads():
    s = FlightScenario.from_toml(SCENARIO)
    assert s.n_steps == 241  # 60 s x 4 Hz + the step at t = 0
    assert (s.outer_min_deg, s.outer_max_deg) == (10.0, 82.0)  # the frame-angle range of [Q17] Fig. 10
    assert s.camera_path.resolve() == (Path(ASSETS) / "cameras" / "qiao2017.toml").resolve()


def test_track_is_the_geodesic_at_speed_and_height():
    s = FlightScenario.from_toml(SCENARIO)
    tr = simulate(s)
    p = tr.pose
    lat, lon = np.rad2deg(p.lat), np.rad2deg(p.lon)
    g = Geod(ellps="WGS84")
    az12, az21, dist = g.inv(np.full(len(tr), s.start_lon_deg), np.full(len(tr), s.start_lat_deg), lon, lat)
    # The inverse problem recovers the direct one: 1e-6 m in distance and 1e-7 deg in azimuth
    # (Karney's solver is accurate to ~15 nm; degrees -> radians -> degrees adds 1e-14 deg).
    np.testing.assert_allclose(dist, s.speed_m_s * tr.t, rtol=0, atol=1e-6)
    np.testing.assert_allclose(az12[1:], s.heading_deg, atol=1e-7)
    # Heading at each step is the geodesic's forward azimuth there (back azimuth + 180).
    fwd = np.mod(np.asarray(az21[1:]) + 360.0, 360.0) - 180.0
    np.testing.assert_allclose(np.rad2deg(p.heading[1:]), fwd, atol=1e-7)
    assert np.all(p.h == 18000.0)
    assert np.all(np.rad2deg(p.pitch) == pytest.approx(3.5, abs=1e-12))
    # Roll: 0.5 deg sine of period 7 s (scenario file): a quarter period in, +0.5 deg.
    k = int(np.flatnonzero(np.isclose(tr.t, 1.75))[0])
    assert np.rad2deg(p.roll[k]) == pytest.approx(0.5, abs=1e-12)


def test_whisk_broom_closed_form():
    t = np.array([0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0])
    np.testing.assert_allclose(whisk_broom(t, 10.0, 82.0, 20.0), [10, 46, 82, 46, 10, 46, 82], atol=1e-12)


def test_right_side_is_negative_gimbal_roll():
    d = _data()
    d["scan"]["side"] = "right"
    s = FlightScenario.from_dict(d, base=SCENARIO.parent)
    g = np.rad2deg(simulate(s).pose.gimbal_roll)
    assert g.max() == pytest.approx(-10.0) and g.min() == pytest.approx(-82.0)


@pytest.mark.parametrize(
    "section, key, value, needle",
    [
        ("aircraft", "h_m", float("nan"), "[aircraft] h_m = nan"),
        ("aircraft", "start_lat_deg", 95.0, "[aircraft] start_lat_deg = 95.0"),
        ("scan", "side", "up", "side = 'up'"),
        ("scan", "outer_max_deg", 5.0, "outer_max_deg = 5.0"),
        ("time", "rate_hz", "fast", "rate_hz = 'fast'"),
        ("terrain", "method", "magic", "method = 'magic'"),
        ("aircraft", "speed_kts", 300.0, "unknown key(s) ['speed_kts']"),
    ],
)
def test_bad_fields_are_named(section, key, value, needle):
    d = copy.deepcopy(_data())
    d[section][key] = value
    with pytest.raises(ValueError) as e:
        FlightScenario.from_dict(d, base=SCENARIO.parent, source="s.toml")
    assert needle in str(e.value)


def test_missing_pieces_are_named(tmp_path):
    d = _data()
    d["terrain"] = {"method": "ellipsoid"}
    with pytest.raises(ValueError, match="give target_h_m"):
        FlightScenario.from_dict(d)
    d["terrain"] = {"target_h_m": 5000.0, "method": "steps"}
    with pytest.raises(ValueError, match="method = 'steps' needs a dem"):
        FlightScenario.from_dict(d)
    d = _data()
    del d["aircraft"]["h_m"]
    with pytest.raises(ValueError, match=r"\[aircraft\] h_m: missing"):
        FlightScenario.from_dict(d)
    with pytest.raises(FileNotFoundError, match="scenario file not found"):
        FlightScenario.from_toml(tmp_path / "nope.toml")


def test_the_ellipsoid_method_with_a_dem_needs_its_target_height():
    # the dem is then the truth only: without target_h_m there is no surface to locate on (the
    # recording failed later on formatting None)
    d = _data()
    d["terrain"] = {"dem": "../dem/etopo5_flight_area.tif", "method": "ellipsoid"}
    with pytest.raises(ValueError, match=r"s.toml \[terrain\] method = 'ellipsoid' needs target_h_m"):
        FlightScenario.from_dict(d, base=SCENARIO.parent, source="s.toml")
    d["terrain"]["target_h_m"] = 5083.0
    assert FlightScenario.from_dict(d, base=SCENARIO.parent, source="s.toml").target_h_m == 5083.0


def test_step_cep_reproduces_q17_table1_monte_carlo():
    """One step at the [Q17] Table 1 nominal (gimbal roll 50 deg): the per-step CEP is the paper's.

    [Q17] section 3.2 reports standard deviations 0.00048 deg (lat) and 0.00060 deg (lon)
    for N = 5000 (ellipsoid model, terrain sigma 62.47 m); [Q17 eq. 18] turns them into
    a CEP, the reference here (computed from the published numbers, not by the code under test).
    """
    from geoloc.analysis.errormodel import ErrorModel
    from geoloc.geodesy.ellipsoid import meridian_radius, prime_vertical_radius
    from geoloc.workflows.flight import step_cep

    d = _data()
    d["time"] = {"duration_s": 0.0, "rate_hz": 1.0}
    d["scan"].update(outer_min_deg=50.0, outer_max_deg=50.0)
    d["terrain"] = {"target_h_m": 5083.5}
    s = FlightScenario.from_dict(d, base=SCENARIO.parent)
    model = ErrorModel.from_toml(Path(ASSETS) / "scenarios" / "qiao2017_table1.toml")
    got = step_cep(simulate(s), model, 5083.5, 5000, np.random.default_rng(3))["cep_m"]
    lat, h = np.deg2rad(35.57709), 5083.5
    ref = np.hypot(
        np.deg2rad(0.00060) * (prime_vertical_radius(lat) + h) * np.cos(lat),
        np.deg2rad(0.00048) * (meridian_radius(lat) + h),
    )
    # 5 %: the sampling error of a standard deviation from 5000 samples is 1 % (1 / sqrt(2N)),
    # and the paper rounds its standard deviations to two digits (0.00048: +-1 %, 0.00060: +-0.8 %).
    assert got.shape == (1,)
    assert got[0] == pytest.approx(ref, rel=0.05)
