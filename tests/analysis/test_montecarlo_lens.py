"""Monte Carlo with the lens's parameters as error sources (fx_px, cx_px, k1, ...).

Oracles from outside the code under test: the pinhole's closed form at nadir (a
principal-point shift of s px moves the ground point by s * GSD, GSD = range / f;
a focal-length change leaves the principal ray where it is, and moves a pixel du
off it by range * du * df / f^2), pymap3d for the ground offsets (geodetic ->
ENU), ``cv2.undistortPoints`` for a distortion-coefficient draw, and the sensor's
named-parameter path (``FrameSensor.with_params``) draw by draw.
"""

import math

import cv2  # opencv-python-headless: a test dependency
import numpy as np
import pymap3d
import pytest

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.cli import main
from geoloc.locate import locate
from geoloc.status import Status

F = 2000.0  # px
H = 1000.0  # m above the target: at nadir the range, so GSD = H / F = 0.5 m per pixel
GSD = H / F
LENS = {"model": "pinhole", "fx": F, "fy": F, "cx": 960.5, "cy": 540.5, "width": 1920, "height": 1080}
BROWN = {**LENS, "model": "brown", "k1": -0.12, "k2": 0.03, "p1": 2e-4, "p2": -1e-4}


def _model(lens=LENS, errors=None, row=540.5, col=960.5, **nominal):
    """Nadir by default: level aircraft, gimbal at zero (the line of sight is the ellipsoid normal)."""
    nom = {
        "lat_deg": 30.0,
        "lon_deg": 80.0,
        "h_m": H,
        "heading_deg": 0.0,
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
        "gimbal_roll_deg": 0.0,
        "gimbal_pitch_deg": 0.0,
        **nominal,
    }
    data = {
        "camera": {"lens": dict(lens), "gimbal": {"preset": "roll-pitch"}},
        "nominal": nom,
        "target": {"h_m": 0.0, "row": row, "col": col},
        "errors": errors or {},
    }
    return ErrorModel.from_dict(data, source="test")


def _enu(model, lat, lon, h):
    """East, north, up [m] of located points from the error-free point (pymap3d)."""
    lat0, lon0, h0, _ = mc.nominal_point(model)
    return pymap3d.geodetic2enu(np.rad2deg(lat), np.rad2deg(lon), h, math.degrees(lat0), math.degrees(lon0), h0)


def test_principal_point_draws_move_the_ground_point_by_gsd_at_nadir():
    # closed form: the pixel at the nominal principal point sits -d px from a principal point moved
    # by +d; at nadir the ray then meets the ground H * d / F away. The roll-pitch camera at zero
    # angles has its rows along the nose (north) and its columns towards the left wing (west), so
    # +d in cx looks east and +d in cy looks south (docs/conventions.md, frame S)
    m = _model()
    d = np.array([-3.0, -1.0, -0.25, 0.0, 0.5, 2.0, 4.0])
    for source, axis, sign in (("cx_px", 0, +1.0), ("cy_px", 1, -1.0)):
        lat, lon, h, st = mc.evaluate(m, {source: d})
        assert np.all(st == Status.OK)
        enu = np.stack(_enu(m, lat, lon, h), -1)
        # the ellipsoid's curvature under a 2-m offset is 3e-7 m (offset^2 / 2R); 1e-6 m bounds it
        # and the rounding of 6.4e6-m coordinates (1e-9 m)
        np.testing.assert_allclose(enu[:, axis], sign * d * GSD, rtol=0, atol=1e-6)
        np.testing.assert_allclose(enu[:, 1 - axis], 0.0, rtol=0, atol=1e-6)


def test_principal_point_sigma_spreads_the_points_by_sigma_times_gsd():
    # one source of s px: the horizontal spread is s * GSD along one axis, so [Q17 eq. 18] is s * GSD;
    # N = 20 000: the standard error of a sample standard deviation is 1 / sqrt(2N) = 0.5 %, so 2.5 %
    # is five of them
    s = 2.0
    res = mc.run(_model(errors={"cx_px": {"dist": "normal", "sigma": s}}), 20_000, np.random.default_rng(3))
    assert res.stats["cep_m"] == pytest.approx(s * GSD, rel=0.025)
    # the empirical 50 % radius of a one-axis normal spread is 0.674 sigma (the normal's quartile)
    assert res.stats["cep50_empirical_m"] == pytest.approx(0.6745 * s * GSD, rel=0.03)


def test_focal_length_sigma_at_the_principal_point_has_no_effect():
    # closed form: the principal ray is the optical axis whatever f is, nadir or oblique
    for oblique in ({}, {"gimbal_roll_deg": 35.0, "gimbal_pitch_deg": -10.0, "heading_deg": 70.0}):
        errs = {k: {"dist": "normal", "sigma": 40.0} for k in ("fx_px", "fy_px", "focal_length_px")}
        res = mc.run(_model(errors=errs, **oblique), 5000, np.random.default_rng(4))
        # rounding only: a 1e-16 direction error over ~1.2 km is 1e-13 m
        assert res.stats["cep_m"] < 1e-6 and res.stats["n_ok"] == 5000


def test_focal_length_sigma_off_the_principal_point_matches_the_closed_form():
    # a pixel du = 500 px right of the principal point is H * du / f west of nadir; d/df of that is
    # -H du / f^2, so sigma_f = 10 px spreads it by H du sigma_f / f^2 = 1.25 m (first order: the
    # second-order term sigma_f / f = 0.5 % is the tolerance, with the sampling's 2.5 %)
    du, sf = 500.0, 10.0
    m = _model(errors={"fx_px": {"dist": "normal", "sigma": sf}}, col=960.5 + du)
    res = mc.run(m, 20_000, np.random.default_rng(5))
    assert res.stats["cep_m"] == pytest.approx(H * du * sf / F**2, rel=0.03)
    fo = mc.first_order(m)
    assert fo.cep_m == pytest.approx(H * du * sf / F**2, rel=1e-3)  # linear: the closed form to 0.5 % / 5


def test_first_order_agrees_with_monte_carlo_for_lens_sources():
    # an oblique Brown camera with every kind of lens source at a corner-ish pixel: the linear
    # propagation (central differences through the same chain) against 20 000 samples; the sampling
    # error of the CEP is ~0.5 %, the sources are small enough for the map to be linear: 3 %
    errs = {
        "cx_px": {"dist": "normal", "sigma": 0.8},
        "cy_px": {"dist": "uniform", "max": 1.0},
        "fx_px": {"dist": "normal", "sigma": 6.0},
        "fy_px": {"dist": "normal", "sigma": 6.0},
        "k1": {"dist": "normal", "sigma": 2e-3},
        "p2": {"dist": "normal", "sigma": 5e-5},
    }
    m = _model(
        BROWN,
        errs,
        row=200.0,
        col=1700.0,
        gimbal_roll_deg=30.0,
        gimbal_pitch_deg=-5.0,
        heading_deg=120.0,
        pitch_deg=2.0,
    )
    res = mc.run(m, 20_000, np.random.default_rng(6))
    fo = mc.first_order(m)
    assert res.stats["cep_m"] == pytest.approx(fo.cep_m, rel=0.03)
    assert res.stats["std_lat_deg"] == pytest.approx(fo.std_lat_deg, rel=0.03)
    assert res.stats["std_lon_deg"] == pytest.approx(fo.std_lon_deg, rel=0.03)
    assert set(fo.sources) == set(errs)


def test_distortion_draws_follow_opencv_undistortion():
    # a k1 draw at nadir: the ground point moves by H times the change of the undistorted normalised
    # point, which cv2.undistortPoints gives for the lens with k1 + d (at zero angles optical x
    # (columns) points west and optical y (rows) north, as above). Tolerance: the pixel looks 320 m
    # off nadir, where the ground has dropped by 320^2 / 2R = 8 mm; that moves the hit by ~3 mm, the
    # same for every draw to first order; what differs between draws of 0.15 m is ~2e-6 m, and
    # cv2's iteration converged to 1e-15 (1e-12 m): 1e-5 m
    m = _model(BROWN, row=540.5 + 300.0, col=960.5 + 600.0)
    d = np.array([-4e-3, -1e-3, 0.0, 1e-3, 3e-3])
    lat, lon, h, st = mc.evaluate(m, {"k1": d})
    assert np.all(st == Status.OK)
    east, north, _ = _enu(m, lat, lon, h)
    u, v = 600.0 + 959.5, 300.0 + 539.5  # OpenCV's 0-based pixel
    xy = []
    for dk in d:
        K = np.array([[F, 0, 959.5], [0, F, 539.5], [0, 0, 1.0]])
        dist = np.array([BROWN["k1"] + dk, BROWN["k2"], BROWN["p1"], BROWN["p2"], 0.0])
        pts = cv2.undistortPoints(
            np.array([[[u, v]]]), K, dist, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
        )
        xy.append(pts[0, 0])
    xy = np.array(xy)
    x0, y0 = xy[2]
    np.testing.assert_allclose(east, -H * (xy[:, 0] - x0), rtol=0, atol=1e-5)
    np.testing.assert_allclose(north, H * (xy[:, 1] - y0), rtol=0, atol=1e-5)
    assert np.ptp(east) > 0.2  # the draws really move the point (0.26 m here)


def test_lens_draws_equal_the_sensor_with_those_parameters():
    # batched lens parameters (one chunk) against one sensor per draw (FrameSensor.with_params,
    # the named-parameter path calibration uses); 1e-13 rad is 0.6 um, rounding of the batch's
    # Newton iteration taking a step more for some samples
    m = _model(BROWN, row=100.0, col=1800.0, gimbal_roll_deg=20.0, heading_deg=33.0)
    rng = np.random.default_rng(7)
    n = 6
    errs = {
        "fx_px": rng.normal(0, 5, n),
        "cy_px": rng.normal(0, 1, n),
        "k1": rng.normal(0, 1e-3, n),
        "focal_length_px": rng.normal(0, 3, n),
        "skew_px": rng.normal(0, 0.2, n),
    }
    lat, lon, _, st = mc.evaluate(m, errs)
    assert np.all(st == Status.OK)
    s = m.camera
    pose = m.nominal_pose()
    for k in range(n):
        moved = s.with_params(
            fx=s.params["fx"] + errs["fx_px"][k] + errs["focal_length_px"][k],
            fy=s.params["fy"] + errs["focal_length_px"][k],
            cy=s.params["cy"] + errs["cy_px"][k],
            k1=s.params["k1"] + errs["k1"][k],
            skew=errs["skew_px"][k],
        )
        g = locate(pose, moved, m.row, m.col, target_h=0.0, engine="numpy")
        assert float(g.lat) == pytest.approx(lat[k], abs=1e-13)
        assert float(g.lon) == pytest.approx(lon[k], abs=1e-13)


def test_a_draw_that_makes_no_lens_is_a_failed_sample_not_an_exception():
    m = _model(errors={"fx_px": {"dist": "normal", "sigma": 1.0}})
    lat, _, _, st = mc.evaluate(m, {"fx_px": np.array([0.0, -2.5 * F, 1.0])})
    assert st.tolist() == [Status.OK, Status.INVALID_INPUT, Status.OK] and np.isnan(lat[1])


def test_lens_sources_are_checked_against_the_lens():
    with pytest.raises(ValueError, match=r"k1: the camera's pinhole lens has no parameter 'k1'"):
        _model(errors={"k1": {"dist": "normal", "sigma": 1e-3}})
    with pytest.raises(ValueError, match="roll-pitch"):
        ErrorModel.from_dict(
            {
                "camera": {"lens": LENS, "gimbal": {"preset": "azimuth-elevation"}},
                "nominal": {"lat_deg": 0, "lon_deg": 0, "h_m": 1000},
                "target": {"h_m": 0},
            }
        )
    # the first-phase camera's pinhole takes the pinhole's sources
    q17 = ErrorModel.from_dict(
        {
            "camera": {"focal_length_px": 1e4, "principal_row": 50.5, "principal_col": 50.5, "rows": 100, "cols": 100},
            "nominal": {"lat_deg": 0, "lon_deg": 0, "h_m": 1000},
            "target": {"h_m": 0},
            "errors": {"focal_length_px": {"dist": "normal", "sigma": 5.0}, "cx_px": {"dist": "normal", "sigma": 0.5}},
        }
    )
    assert set(q17.errors) == {"focal_length_px", "cx_px"}


def test_cli_takes_lens_sources_from_the_scenario_and_the_command_line(tmp_path, capsys):
    scen = tmp_path / "drone.toml"
    scen.write_text("""name = "drone"
[camera.lens]
model = "brown"
fx = 2000.0
fy = 2000.0
cx = 960.5
cy = 540.5
width = 1920
height = 1080
k1 = -0.12
[camera.gimbal]
preset = "roll-pitch"
[nominal]
lat_deg = 30.0
lon_deg = 80.0
h_m = 1000.0
[target]
h_m = 0.0
[errors]
cx_px = { dist = "normal", sigma = 2.0 }
""")
    out = tmp_path / "stats.json"
    assert main(["montecarlo", str(scen), "--samples", "20000", "--seed", "1", "--out", str(out)]) == 0
    import json

    stats = json.loads(out.read_text())
    assert stats["cep_m"] == pytest.approx(2.0 * GSD, rel=0.025)  # as the closed-form test above
    text = capsys.readouterr().out
    assert "first order" in text and "eq. 18 1.00 m" in text  # linear: 2 px * 0.5 m exactly
    # --error adds a source (here one that cancels at the principal point, the scenario's default
    # target pixel: no spread of its own; its draws come first, so the cx draws are others)
    assert (
        main(
            [
                "montecarlo",
                str(scen),
                "--samples",
                "20000",
                "--seed",
                "1",
                "--out",
                str(out),
                "--error",
                "focal_length_px=normal:50",
            ]
        )
        == 0
    )
    assert json.loads(out.read_text())["cep_m"] == pytest.approx(2.0 * GSD, rel=0.025)
    assert "eq. 18 1.00 m" in capsys.readouterr().out
    # --sensor replaces the scenario's camera: a pinhole file has no k1 to draw
    sensor = tmp_path / "pinhole.toml"
    sensor.write_text(
        "[lens]\n"
        + "\n".join(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in LENS.items())
        + "\n"
    )
    assert (
        main(["montecarlo", str(scen), "--samples", "1000", "--sensor", str(sensor), "--error", "k1=normal:0.001"]) == 2
    )
    assert "no parameter 'k1'" in capsys.readouterr().err
    assert main(["montecarlo", str(scen), "--samples", "1000", "--error", "cx_px=gauss:1"]) == 2
    assert "--error 'cx_px=gauss:1'" in capsys.readouterr().err
