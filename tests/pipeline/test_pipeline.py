"""The location pipeline's corrections at the command line and in the API, against outside numbers.

Oracles: the independent ray trace of tests/raytrace.py (the ray equation integrated with
scipy, n of the geodetic height); pymap3d's ``lookAtSpheroid`` for the straight line; the
geometry of a nadir view (a shift toward nadir shortens the ground distance from the
aircraft's nadir point). The contract (every sensor x surface x correction x executor) is
tests/pipeline/test_contract.py.
"""

from __future__ import annotations

import json
import math

import numpy as np
from pymap3d.los import lookAtSpheroid
import pytest
from raytrace import exact_n, trace  # tests/raytrace.py

from geoloc import Camera, Pose
from geoloc.cli import main
from geoloc.corrections.refraction import STANDARD_REFRACTION
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.locate import ground_to_pixel, locate
from geoloc.pipeline import Corrections, Pipeline
from geoloc.sensors.camera import as_sensor
from geoloc.status import Status
from geoloc.surfaces.height import HeightSurface

LAT, LON, H = 35.48, 80.97, 18000.0
ROOT_ASSETS = __import__("pathlib").Path(__file__).resolve().parents[2] / "assets" / "scenarios"
POSE_ARGS = [
    "--lat-deg",
    str(LAT),
    "--lon-deg",
    str(LON),
    "--h-m",
    str(H),
    "--heading-deg",
    "0",
    "--pitch-deg",
    "0",
    "--roll-deg",
    "0",
    "--gimbal-roll-deg",
    "0",
]


def _locate_json(capsys, *extra):
    assert main(["locate", *POSE_ARGS, "--target-h-m", "0", "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_locate_refraction_from_18_km_grows_and_points_to_nadir(capsys):
    """`geoloc locate --refraction standard` from 18 km at 30-70 deg off nadir (the [Q17] camera
    looking along the gimbal pitch, north): the shift grows with the angle, the point moves
    toward nadir, and it lands where the independent ray trace does."""
    shifts = []
    for angle in (30, 45, 60, 70):
        # the principal point (the camera file's), so that the line of sight is the boresight
        pp = ["--gimbal-pitch-deg", str(angle), "--row", "1162.12", "--col", "1146.42"]
        straight = _locate_json(capsys, *pp)
        bent = _locate_json(capsys, *pp, "--refraction", "standard")
        assert straight["corrections"] == "none" and straight["refraction_m"] == 0.0
        assert bent["corrections"] == "refraction"
        p0 = geodetic_to_ecef(math.radians(straight["lat_deg"]), math.radians(straight["lon_deg"]), 0.0)
        p1 = geodetic_to_ecef(math.radians(bent["lat_deg"]), math.radians(bent["lon_deg"]), 0.0)
        # refraction_m is the distance the point moved, measured here from the two outputs (1 mm:
        # the JSON's lat/lon carry 1e-15 deg, far below)
        assert np.linalg.norm(p1 - p0) == pytest.approx(bent["refraction_m"], abs=1e-3)
        # toward nadir: the bent point is nearer the aircraft's nadir point (both on h = 0)
        nadir = geodetic_to_ecef(math.radians(LAT), math.radians(LON), 0.0)
        assert np.linalg.norm(p1 - nadir) < np.linalg.norm(p0 - nadir)
        # the independent trace: the camera's direction is the straight line's (pymap3d's
        # lookAtSpheroid gives the same straight hit, to 1 mm: an outside check of the raw line)
        tilt = angle  # gimbal pitch tilts the boresight from nadir toward north
        lat_s, lon_s, _ = lookAtSpheroid(LAT, LON, H, 0.0, tilt)
        assert np.linalg.norm(geodetic_to_ecef(math.radians(lat_s), math.radians(lon_s), 0.0) - p0) < 1e-3
        o = geodetic_to_ecef(math.radians(LAT), math.radians(LON), H)
        ref = trace(o, p0 - o, 0.0, exact_n)
        # docs/refraction.md: the model is within 0.13 mm of the trace up to 70 deg (1.4 mm at 80);
        # 1 mm here
        assert np.linalg.norm(ref - p1) < 0.001, angle
        shifts.append(bent["refraction_m"])
    assert all(a < b for a, b in zip(shifts, shifts[1:])), shifts
    # docs/refraction.md's published figures (rounded to the centimetre there)
    np.testing.assert_allclose(shifts, [1.29, 3.38, 11.83, 41.22], atol=0.01)


def test_locate_text_says_which_corrections(capsys):
    assert main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0"]) == 0
    assert "corrections: none" in capsys.readouterr().out
    assert (
        main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--refraction", "standard"]) == 0
    )
    assert "refraction moved the point 11.83 m" in capsys.readouterr().out


def test_aberration_on_a_frame_sensor_is_refused_by_name(capsys):
    assert main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--light-time"]) == 0
    out = json.loads(
        main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--light-time", "--json"]) == 0
        and capsys.readouterr().out.splitlines()[-1]
    )
    assert out["corrections"] == "light_time"
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    with pytest.raises(ValueError, match="no platform velocity"):
        Corrections.for_sensor(cam, aberration=True)
    with pytest.raises(ValueError, match="refraction = 'strong'"):
        Corrections.for_sensor(cam, refraction="strong")


def test_pixel_inverts_locate_with_refraction(capsys):
    """`geoloc pixel --refraction standard` of `geoloc locate --refraction standard`'s point
    gives back the pixel; without the correction it is off by the shift's worth of pixels."""
    bent = _locate_json(capsys, "--gimbal-pitch-deg", "60", "--row", "400", "--col", "1800", "--refraction", "standard")
    args = [
        "pixel",
        *POSE_ARGS,
        "--gimbal-pitch-deg",
        "60",
        "--point-lat-deg",
        repr(bent["lat_deg"]),
        "--point-lon-deg",
        repr(bent["lon_deg"]),
        "--point-h-m",
        "0",
        "--json",
    ]
    assert main([*args, "--refraction", "standard"]) == 0
    back = json.loads(capsys.readouterr().out)
    # Refraction.aim stops within 1e-4 m; a pixel is 0.2 m here (36 km / 166 841 px): 1e-3 px
    assert back["row"] == pytest.approx(400.0, abs=1e-3) and back["col"] == pytest.approx(1800.0, abs=1e-3)
    main(args)
    plain = json.loads(capsys.readouterr().out)
    assert abs(plain["row"] - 400.0) > 10.0  # 11.8 m at about 0.2 m a pixel along the line


def test_api_locate_and_ground_to_pixel_take_corrections():
    cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 70)
    c = Corrections.for_sensor(as_sensor(cam), "standard")
    g = locate(pose, cam, 1000.0, 900.0, 250.0, corrections=c, height_kind="geodetic")
    assert g.corrections == ("refraction",) and g.refraction_m > 30.0
    row, col, st = ground_to_pixel(pose, cam, g.lat, g.lon, g.h, corrections=c)
    assert int(st) == Status.OK
    assert float(row) == pytest.approx(1000.0, abs=1e-3) and float(col) == pytest.approx(900.0, abs=1e-3)
    # the pipeline and the functional front are one path
    p = Pipeline(as_sensor(cam), HeightSurface(250.0, "geodetic"), c).locate(1000.0, 900.0, pose)
    np.testing.assert_array_equal(p.ecef, g.ecef)


def _limb_ray(tangent_h):
    """A ray from 400 km whose straight line grazes the ellipsoid's equator at tangent_h."""
    r_t = 6378137.0 + tangent_h
    r_p = 6378137.0 + 400e3
    x = math.sqrt(r_p**2 - r_t**2)
    return np.array([r_t, -x, 0.0]), np.array([0.0, 1.0, 0.0])


@pytest.mark.parametrize("tangent_h", [5000.0, 15000.0])
def test_limb_cli_prints_the_refracted_tangent_height(capsys, tangent_h):
    o, d = _limb_ray(tangent_h)
    args = [
        "limb",
        "--origin-ecef",
        *(repr(float(x)) for x in o),
        "--direction-ecef",
        *(repr(float(x)) for x in d),
        "--json",
    ]
    assert main(args) == 0
    plain = json.loads(capsys.readouterr().out)
    assert "refracted_tangent_h_m" not in plain and plain["corrections"] == "none"
    assert main([*args, "--refraction", "standard"]) == 0
    out = json.loads(capsys.readouterr().out)
    # the straight-line tangent height is as before
    assert out["exact_tangent_h_m"] == pytest.approx(plain["exact_tangent_h_m"], abs=1e-9)
    assert out["exact_tangent_h_m"] == pytest.approx(tangent_h, abs=1e-3)
    # the independent trace, stopped where the bent ray turns level: its height (0.2 m:
    # docs/refraction.md, the limb model against the trace)
    from geoloc.geodesy.ellipsoid import ecef_to_geodetic

    ref = trace(o, d, 0.0, exact_n, limb=True)
    assert out["refracted_tangent_h_m"] == pytest.approx(float(ecef_to_geodetic(ref)[2]), abs=0.2)
    # hundreds of metres to kilometres below the straight tangent (the bent ray's drop over a limb path)
    assert out["refraction_m"] > 100.0


def test_limb_scenario_csv_has_the_refracted_columns(tmp_path, capsys):
    out = tmp_path / "limb.csv"
    assert (
        main(
            [
                "limb",
                "assets/scenarios/tiangong2_limb.toml",
                "--frames",
                "2",
                "--refraction",
                "standard",
                "--json",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["corrections"] == "refraction" and summary["max_refraction_m"] > 100.0
    header = out.read_text().splitlines()[0].split(",")
    assert {"refracted_tangent_h_m", "refraction_m"} <= set(header)


def test_refraction_model_object_is_shared():
    assert Corrections.for_sensor(None, "standard").refraction is STANDARD_REFRACTION


def _replay_csv(tmp_path, name, *extra):
    import csv

    out = tmp_path / name
    main(["replay", "--height-column", "paper_height_m", "--out", str(out), *extra])
    return list(csv.DictReader(out.open()))


def test_replay_rows_say_which_corrections_and_how_far(tmp_path, capsys):
    """Every replay row names its corrections; refraction_m is the distance between the two runs'
    points, measured here with pyproj's geodetic -> ECEF (1 mm: the CSV's 8 decimals of a degree are
    1 mm, its heights 1 mm)."""
    from pyproj import Transformer

    plain = _replay_csv(tmp_path, "plain.csv")
    bent = _replay_csv(tmp_path, "bent.csv", "--refraction", "standard")
    capsys.readouterr()
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    for a, b in zip(plain, bent):
        assert a["corrections"] == "none" and float(a["refraction_m"]) == 0.0
        assert b["corrections"] == "refraction"
        pa = np.array(to_ecef.transform(float(a["lon_deg"]), float(a["lat_deg"]), float(a["h_m"])))
        pb = np.array(to_ecef.transform(float(b["lon_deg"]), float(b["lat_deg"]), float(b["h_m"])))
        assert np.linalg.norm(pb - pa) == pytest.approx(float(b["refraction_m"]), abs=2e-3)
        assert float(b["refraction_m"]) > 0.5  # 18 km, 30-60 deg off nadir: metres


def test_replay_says_once_when_refraction_left_off_matters(tmp_path, capsys):
    """A budget whose CE90 is small beside refraction's metres: the summary says so, once."""
    from geoloc.assets import DEFAULT_CAMERA, asset_path

    cam = tmp_path / "cam.toml"
    cam.write_text(asset_path(*DEFAULT_CAMERA).read_text() + "\n[uncertainty]\nnorth_m = 0.1\neast_m = 0.1\n")
    _replay_csv(tmp_path, "plain.csv", "--sensor", str(cam))
    err = capsys.readouterr().err
    assert err.count("refraction is off, but the standard atmosphere would move") == 1
    _replay_csv(tmp_path, "bent.csv", "--sensor", str(cam), "--refraction", "standard")
    assert "refraction is off" not in capsys.readouterr().err


def test_klv_replay_carries_the_corrections(tmp_path, capsys):
    """A KLV replay with --refraction standard: each frame centre moved by its refraction_m, the
    distance between the two runs' centres (through pyproj, 2 mm: the CSV's precision)."""
    import csv

    from pyproj import Transformer

    runs = {}
    for name, extra in (("plain", []), ("bent", ["--refraction", "standard"])):
        out = tmp_path / f"{name}.csv"
        main(["replay", "assets/klv/example_flight.klv", "--out", str(out), *extra])
        runs[name] = list(csv.DictReader(out.open()))
    capsys.readouterr()
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    moved = 0
    for a, b in zip(runs["plain"], runs["bent"]):
        assert a["corrections"] == "none" and b["corrections"] == "refraction"
        if a["status"] != "ok":
            continue
        pa = np.array(to_ecef.transform(float(a["lon_deg"]), float(a["lat_deg"]), float(a["h_m"])))
        pb = np.array(to_ecef.transform(float(b["lon_deg"]), float(b["lat_deg"]), float(b["h_m"])))
        assert np.linalg.norm(pb - pa) == pytest.approx(float(b["refraction_m"]), abs=2e-3)
        moved += float(b["refraction_m"]) > 0.0
    assert moved > 0


def test_whole_frame_grid_executor_agrees_with_the_pipeline_with_refraction():
    """geoloc ortho's compiled grid of lines of sight is one more executor of the pipeline: with
    refraction on, its points equal the numpy pipeline's pixel by pixel (1 mm, the contract's)."""
    from geoloc.workflows.ortho import locate_frame

    cam = as_sensor(Camera(1000.0, 240.5, 320.5, 480, 640))
    pose = Pose.from_deg(LAT, LON, H, 20.0, 1.0, -2.0, 3.0, 55.0)
    c = Corrections.for_sensor(cam, "standard")
    grid = locate_frame(cam, pose, HeightSurface(300.0, "geodetic"), step=40, corrections=c)
    R, C = np.meshgrid(grid.rows, grid.cols, indexing="ij")
    ref = Pipeline(cam, HeightSurface(300.0, "geodetic"), c).locate(R, C, pose, engine="numpy")
    ok = ref.status == Status.OK
    assert ok.all()
    p_grid = geodetic_to_ecef(grid.lat, grid.lon, grid.h)
    assert np.max(np.linalg.norm(p_grid - ref.ecef, axis=-1)) < 1e-3
    assert np.min(ref.refraction_m) > 1.0  # 18 km, 35-75 deg off nadir: metres


def test_a_sensor_file_names_its_corrections(tmp_path, capsys):
    """A sensor file's [corrections] table is the default of every verb that reads it; the command
    line's option wins; a bad value is one clear error naming the file, the table and the key."""
    from geoloc.assets import DEFAULT_CAMERA, asset_path

    base = asset_path(*DEFAULT_CAMERA).read_text()
    good = tmp_path / "bent.toml"
    good.write_text(base + '\n[corrections]\nrefraction = "standard"\n')
    args = ["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--json", "--sensor", str(good)]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["corrections"] == "refraction"
    assert main([*args, "--refraction", "none"]) == 0
    assert json.loads(capsys.readouterr().out)["corrections"] == "none"
    bad = tmp_path / "bad.toml"
    bad.write_text(base + '\n[corrections]\nrefraction = "tropical"\n')
    assert main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--sensor", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml [corrections]: refraction = 'tropical'" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_refraction_as_a_source_of_the_error_budget(engine):
    """A budget's ``refraction = 0.1``: one more term, 0.1 of the refraction shift along the shift.
    Alone, the predicted ellipse is a segment: its 1-sigma semi-major axis is 0.1 of the shift's
    horizontal length, measured here with the independent ray trace, along the north-south line
    the camera looks down (the semi-minor axis 0)."""
    from geoloc.analysis.uncertainty import propagate
    from geoloc.sensors.budget import ErrorBudget

    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 60)
    pu = propagate(cam, pose, 1162.12, 1146.42, ErrorBudget({"refraction": 0.1}), target_h=0.0, engine=engine)
    assert pu.sources[-1] == "refraction"
    o = geodetic_to_ecef(math.radians(LAT), math.radians(LON), H)
    lat_s, lon_s, _ = lookAtSpheroid(LAT, LON, H, 0.0, 60.0)
    p0 = geodetic_to_ecef(math.radians(lat_s), math.radians(lon_s), 0.0)
    ref = trace(o, p0 - o, 0.0, exact_n)
    from pymap3d import ecef2enu

    e, n, _ = ecef2enu(*ref, lat_s, lon_s, 0.0)
    # 1e-3 m: the model is within 1 cm of the trace, a tenth of it here
    assert float(pu.ellipse_major_m) == pytest.approx(0.1 * math.hypot(e, n), abs=1e-3)
    assert float(pu.ellipse_minor_m) < 1e-6
    assert float(pu.ellipse_azimuth_deg) % 180.0 == pytest.approx(0.0, abs=0.1) or float(
        pu.ellipse_azimuth_deg
    ) % 180.0 == pytest.approx(180.0, abs=0.1)


def _lorentz_source_direction(u_apparent, v_inertial):
    """The light's direction for a sensor moving at v that sees it along u_apparent: the photon's
    velocity transformed from the sensor's frame to the inertial one by the Lorentz boost (Jackson,
    Classical Electrodynamics, 11.4: u_par = (u'_par - v) / (1 - v u'_par / c^2) for the motion
    toward the scene, u_perp = u'_perp / (gamma (1 - v u'_par / c^2))), written out here."""
    c = 299792458.0
    u = np.asarray(u_apparent, float) / np.linalg.norm(u_apparent)
    v = np.asarray(v_inertial, float)
    s = np.linalg.norm(v)
    n = v / s
    g = 1.0 / math.sqrt(1.0 - (s / c) ** 2)
    # the photon travels from the scene to the sensor: its velocity is -c u in both frames
    w = -c * u
    w_par = np.dot(w, n)
    w_perp = w - w_par * n
    den = 1.0 + s * w_par / c**2
    w_in = ((w_par + s) * n + w_perp / g) / den
    return -w_in / np.linalg.norm(w_in)


def test_limb_scenario_with_aberration_against_the_lorentz_boost(tmp_path, capsys):
    """A limb scenario with aberration on: each tangent height equals the exact tangent of the
    direction turned by the Lorentz boost written above (the classical form the pipeline uses
    differs by (v/c)^2 = 7e-10 rad: 1.5 mm at 2 200 km; 1 cm allowed); the bundled [L18] file
    names aberration off, as the paper; light_time in a limb file is refused by name."""
    from geoloc.corrections.lighttime import inertial_velocity
    from geoloc.sensors.limb import limb_tangent
    from geoloc.workflows.limb_scenario import load_limb_scenario

    src = (ROOT_ASSETS / "tiangong2_limb.toml").read_text()
    assert "aberration = false" in src
    on = tmp_path / "on.toml"
    on.write_text(src.replace("aberration = false", "aberration = true"))
    sc = load_limb_scenario(on).with_frames(2)
    chain, r = sc.solve()
    off = load_limb_scenario(ROOT_ASSETS / "tiangong2_limb.toml").with_frames(2)
    chain0, r0 = off.solve()
    p, v = sc.state_ecef()
    checked = 0
    for f in range(2):
        vi = inertial_velocity(p[f], v[f])
        for k in range(0, sc.n_pixels, 7):
            if r.status[f, k] != Status.OK:
                continue
            d = _lorentz_source_direction(chain0.direction_ecef[f, k], vi)
            ref = limb_tangent(chain0.origin_ecef[f, k], d)
            assert float(r.exact_h[f, k]) == pytest.approx(float(ref.exact_h), abs=0.01)
            assert abs(float(r.exact_h[f, k]) - float(r0.exact_h[f, k])) > 1.0  # metres of tangent height
            checked += 1
    assert checked >= 8
    bad = tmp_path / "bad.toml"
    bad.write_text(src.replace("aberration = false", "light_time = true"))
    assert main(["limb", str(bad), "--frames", "1"]) == 2
    assert "light_time does not apply to a limb scenario" in capsys.readouterr().err


def test_limb_raw_mode_takes_a_velocity(capsys):
    o, d = _limb_ray(20000.0)
    v = np.array([0.0, 7600.0, 0.0])
    args = [
        "limb",
        "--origin-ecef",
        *(repr(float(x)) for x in o),
        "--direction-ecef",
        *(repr(float(x)) for x in d),
        "--json",
    ]
    assert main([*args, "--velocity-ecef", *(repr(float(x)) for x in v)]) == 0
    out = json.loads(capsys.readouterr().out)
    from geoloc.corrections.lighttime import inertial_velocity
    from geoloc.sensors.limb import limb_tangent

    ref = limb_tangent(o, _lorentz_source_direction(d, inertial_velocity(o, v)))
    assert out["corrections"] == "aberration"
    assert out["exact_tangent_h_m"] == pytest.approx(float(ref.exact_h), abs=0.01)
    assert main([*args, "--velocity-ecef", *(repr(float(x)) for x in v), "--no-aberration"]) == 0
    assert json.loads(capsys.readouterr().out)["exact_tangent_h_m"] == pytest.approx(20000.0, abs=1e-3)


def test_report_says_which_corrections_the_replay_applied(tmp_path, capsys):
    rows = _replay_csv(tmp_path, "bent.csv", "--refraction", "standard")
    assert main(["report", str(tmp_path / "bent.csv"), "--out-dir", str(tmp_path / "rep")]) == 0
    capsys.readouterr()
    meta = json.loads((tmp_path / "rep" / "report.json").read_text())["meta"]
    assert meta["corrections"] == "refraction"
    shifts = [float(r["refraction_m"]) for r in rows if r["refraction_m"]]
    assert meta["refraction_m_max"] == pytest.approx(max(shifts), abs=1e-3)  # the CSV's 3 decimals


def test_triangulation_meets_the_bent_rays():
    """Two frames from 18 km see one target at 300 m through the standard atmosphere. The pixels
    that see it come from the pipeline's inverse; that each one's bent ray really passes through
    the target is checked with the independent ray trace (1 cm). Triangulated with refraction,
    the rays meet at the target (5 mm); as straight lines they meet metres away."""
    from geoloc.analysis.triangulate import triangulate

    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    c = Corrections.for_sensor(cam, "standard")
    target = (math.radians(35.75), math.radians(81.02), 300.0)
    T = geodetic_to_ecef(*target)
    poses = [
        Pose.from_deg(LAT, LON, H, 10.0, 0, 0, 0, 55.0),
        Pose.from_deg(LAT + 0.05, LON + 0.25, H, 330.0, 0, 0, 0, 55.0),
    ]
    rows, cols = [], []
    for pose in poses:
        # aim the gimbal roughly, then the pixel that sees the target exactly
        row, col, st = Pipeline(cam, None, c).ground_to_pixel(*target, pose)
        assert int(st) in (Status.OK, Status.OUTSIDE_SENSOR)
        los = cam.line_of_sight(float(row), float(col), pose, outside="extrapolate")
        hit = trace(np.asarray(los.origin_ecef), np.asarray(los.direction_ecef), 300.0, exact_n)
        assert np.linalg.norm(hit - T) < 0.01
        rows.append(float(row))
        cols.append(float(col))
    pose2 = Pose(
        *(
            np.array([getattr(p, f) for p in poses])
            for f in ("lat", "lon", "h", "heading", "pitch", "roll", "gimbal_roll", "gimbal_pitch")
        )
    )
    bent = triangulate(cam, pose2, np.array(rows), np.array(cols), corrections=c)
    straight = triangulate(cam, pose2, np.array(rows), np.array(cols))
    assert bent.status == Status.OK
    assert np.linalg.norm(np.asarray(bent.ecef) - T) < 5e-3
    assert np.linalg.norm(np.asarray(straight.ecef) - T) > 1.0
    print(
        f"triangulated {np.linalg.norm(np.asarray(bent.ecef) - T) * 1e3:.2f} mm from the target with refraction, "
        f"{np.linalg.norm(np.asarray(straight.ecef) - T):.2f} m without"
    )


def test_refraction_through_a_measured_ground(capsys):
    """``--ground-p-pa`` / ``--ground-t-k`` fit the standard atmosphere to a measured ground (a warm,
    low-pressure day: thinner air, a smaller shift). With a measured pressure alone the point
    equals the independent ray trace through that atmosphere (1 cm, as for the standard one);
    a measured temperature also steps the density at the tropopause (the model keeps the
    standard temperatures above 11 km), which the trace's finite-difference gradient cannot
    follow, so there the shift is held to the P / T scaling only. Without --refraction standard
    the ground options are one clear error."""
    from geoloc.corrections.atmosphere import StandardAtmosphere

    pp = ["--gimbal-pitch-deg", "60", "--row", "1162.12", "--col", "1146.42"]
    std = _locate_json(capsys, *pp, "--refraction", "standard")
    low = _locate_json(capsys, *pp, "--refraction", "standard", "--ground-p-pa", "95000")
    warm = _locate_json(capsys, *pp, "--refraction", "standard", "--ground-p-pa", "95000", "--ground-t-k", "308.15")
    straight = _locate_json(capsys, *pp)
    assert low["corrections"] == warm["corrections"] == "refraction"
    # n - 1 at the ground scales with P / T: 0.937 (pressure) and 0.937 x 0.935 = 0.876 (both) of the
    # standard's; the shift, which the upper air shares, less so
    assert 0.90 * std["refraction_m"] < low["refraction_m"] < 0.99 * std["refraction_m"]
    assert 0.85 * std["refraction_m"] < warm["refraction_m"] < low["refraction_m"]
    atm = StandardAtmosphere(ground_p_pa=95000.0)
    o = geodetic_to_ecef(math.radians(LAT), math.radians(LON), H)
    p0 = geodetic_to_ecef(math.radians(straight["lat_deg"]), math.radians(straight["lon_deg"]), 0.0)
    ref = trace(o, p0 - o, 0.0, lambda h: 1.0 + atm.refractivity(h))
    p1 = geodetic_to_ecef(math.radians(low["lat_deg"]), math.radians(low["lon_deg"]), 0.0)
    assert np.linalg.norm(ref - p1) < 0.01
    assert main(["locate", *POSE_ARGS, *pp, "--target-h-m", "0", "--ground-p-pa", "95000"]) == 2
    assert "ground_p_pa given, but refraction = 'none'" in capsys.readouterr().err


def test_a_fitted_sensor_file_keeps_the_corrections_it_was_fitted_with(tmp_path, capsys):
    """calibrate --refraction standard --write-sensor: the fitted file says refraction = "standard"
    (the parameters absorbed the rest of the error with the bend taken out), so every verb that reads
    it locates with it; Corrections.to_table reads back to the same corrections, a measured ground
    included."""
    from geoloc.corrections.atmosphere import StandardAtmosphere
    from geoloc.corrections.refraction import Refraction
    from geoloc.pipeline import corrections_from_table
    from geoloc.sensors.sensor_file import load_sensor_corrections

    out = tmp_path / "fitted.toml"
    assert (
        main(
            [
                "calibrate",
                "--height-column",
                "paper_height_m",
                "--fit",
                "mount_x,mount_y",
                "--joint",
                "--refraction",
                "standard",
                "--write-sensor",
                str(out),
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert load_sensor_corrections(out) == {"refraction": "standard", "light_time": False, "aberration": False}
    assert (
        main(["locate", *POSE_ARGS, "--gimbal-pitch-deg", "60", "--target-h-m", "0", "--json", "--sensor", str(out)])
        == 0
    )
    assert json.loads(capsys.readouterr().out)["corrections"] == "refraction"
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    c = Corrections(refraction=Refraction(StandardAtmosphere(ground_h_m=250.0, ground_p_pa=95000.0)))
    assert c.to_table() == {
        "refraction": "standard",
        "light_time": False,
        "aberration": False,
        "ground_h_m": 250.0,
        "ground_p_pa": 95000.0,
    }
    assert corrections_from_table(cam, c.to_table()) == c


def test_command_line_over_a_scenarios_corrections():
    """montecarlo and rpc hold a scenario's corrections (``base``); the command line changes only
    what it names, and a ground measurement goes with the refraction it fits."""
    import argparse

    from geoloc.cli._options import corrections_from_args
    from geoloc.corrections.atmosphere import StandardAtmosphere
    from geoloc.corrections.refraction import Refraction

    sensor = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    base = Corrections(refraction=Refraction(StandardAtmosphere(ground_p_pa=95000.0)))

    def args(**given):
        keys = ("refraction", "light_time", "aberration", "ground_h_m", "ground_p_pa", "ground_t_k")
        return argparse.Namespace(**{k: given.get(k) for k in keys})

    kept = corrections_from_args(args(), sensor, base=base)
    assert kept.refraction.atmosphere == StandardAtmosphere(ground_p_pa=95000.0) and not kept.light_time
    both = corrections_from_args(args(ground_t_k=300.0), sensor, base=base)  # the scenario's pressure kept
    assert both.refraction.atmosphere == StandardAtmosphere(ground_p_pa=95000.0, ground_t_k=300.0)
    off = corrections_from_args(args(refraction="none", light_time=True), sensor, base=base)
    assert off.refraction is None and off.light_time and off.label == "light_time"
    with pytest.raises(ValueError, match="ground_t_k given, but refraction = 'none'"):
        corrections_from_args(args(ground_t_k=300.0), sensor, base=Corrections())


def test_refracted_points_on_a_sloping_dem_lie_on_it():
    """On a DEM the refracted ray is met with the terrain again (a fixed point), not kept at the
    straight hit's height: on a plane sloping 1 in 3 the points lie on the plane, whose height the
    test writes (bilinear interpolation of a plane is the plane), within 1 cm, for a batch of rays."""
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import DemSurface

    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 60)
    lat_s, lon_s, _ = lookAtSpheroid(LAT, LON, H, 0.0, 60.0)
    # the grid reaches 0.05 deg south of the straight hit at h = 0, where the ray (3.2 km) is above the
    # DEM's highest node (2300 m): a ray must enter the grid from above it (docs/terrain.md, LEFT_DEM)
    n0, w0, step = lat_s + 0.01, lon_s - 0.03, 0.001
    y = np.arange(61.0)[:, None]
    h = np.tile(500.0 + 30.0 * y, (1, 61))  # 30 m a row of ~110 m, rising south, toward the camera

    def plane(lat_deg):
        return 500.0 + 30.0 * (n0 - lat_deg) / step

    dem = DEM.from_array(h, n0, w0, step, step, datum="ellipsoid")
    rows, cols = np.array([1162.12, 1000.0]), np.array([1146.42, 1300.0])
    c = Corrections.for_sensor(cam, "standard")
    bent = Pipeline(cam, DemSurface(dem, "exact"), c).locate(rows, cols, pose)
    straight = Pipeline(cam, DemSurface(dem, "exact")).locate(rows, cols, pose)
    assert np.all(bent.status == Status.OK)
    assert np.all(np.asarray(bent.refraction_m) > 0.5)  # metres at 60 deg off nadir from 18 km
    assert np.allclose(bent.h, plane(np.rad2deg(bent.lat)), atol=0.01, rtol=0)
    assert np.allclose(straight.h, plane(np.rad2deg(straight.lat)), atol=0.01, rtol=0)
    # refraction moves the point toward nadir, up the slope: its height changed with its latitude
    assert np.all(np.abs(np.asarray(bent.h) - np.asarray(straight.h)) > 0.05)
    # and back to the pixels, the batch at once: the fixed point stops within a millimetre on the
    # ground, 0.005 px at 36 km and 166 841 px a radian
    px = Pipeline(cam, None, c).ground_to_pixel(bent.lat, bent.lon, bent.h, pose)
    assert np.allclose(px.row, rows, atol=0.01, rtol=0) and np.allclose(px.col, cols, atol=0.01, rtol=0)


def test_overridden_corrections_change_only_what_is_given():
    """A command line's flags over a file's table: each given setting replaces the table's, None keeps it."""
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    base = Corrections.for_sensor(cam, "standard", True, False)
    assert (base.refraction is STANDARD_REFRACTION, base.light_time, base.aberration) == (True, True, False)
    kept = base.overridden(cam)
    assert (kept.refraction is STANDARD_REFRACTION, kept.light_time, kept.aberration) == (True, True, False)
    off = base.overridden(cam, light_time=False)
    assert (off.refraction is STANDARD_REFRACTION, off.light_time, off.aberration) == (True, False, False)
    on = Corrections.for_sensor(cam, None, False, False).overridden(cam, light_time=True)
    assert (on.refraction, on.light_time) == (None, True)


def test_the_fused_kernel_serves_only_an_inflated_height_surface(monkeypatch):
    """Which executor runs: the fused chain-and-ellipsoid kernel for an inflated height surface
    (asked by name, or a batch of COMPILED_MIN_RAYS), never for another surface or ``numpy``."""
    from geoloc.pipeline import COMPILED_MIN_RAYS
    from geoloc.sensors import _fastlocate

    monkeypatch.setattr(_fastlocate, "locate_fast", lambda *a, **k: "fused")
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 60)
    assert _fastlocate.serves(cam)
    inflated = Pipeline(cam, HeightSurface(250.0, "inflated"))
    assert inflated._fused(1000.0, 900.0, pose, "numba", "flag") == "fused"
    assert inflated._fused(1000.0, 900.0, pose, "numpy", "flag") is None
    assert inflated._fused(1000.0, 900.0, pose, "auto", "flag") is None  # one ray
    rows = np.full(COMPILED_MIN_RAYS, 1000.0)
    assert inflated._fused(rows, rows, pose, "auto", "flag") == "fused"
    assert Pipeline(cam, HeightSurface(250.0, "geodetic"))._fused(1000.0, 900.0, pose, "numba", "flag") is None


def test_locate_takes_its_pixels_by_name_and_its_options_only_by_name():
    """``Pipeline.locate(row, col, state=None, *, outside=..., engine=...)``: the pixels and the state
    by place or by name, an option only by name (a caller's positional flag would be read as another)."""
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 30)
    pipe = Pipeline(cam, HeightSurface(0.0, "geodetic"))
    by_name = pipe.locate(row=1000.0, col=1200.0, state=pose, outside="flag")
    by_place = pipe.locate(1000.0, 1200.0, pose)
    np.testing.assert_array_equal(by_name.ecef, by_place.ecef)
    with pytest.raises(TypeError):
        pipe.locate(1000.0, 1200.0, pose, "extrapolate")  # an option is never taken by its place


@pytest.mark.parametrize("light_time", [False, True])
def test_the_slant_range_of_a_corrected_point_is_its_distance_from_the_optical_centre(light_time):
    """With refraction (and light time) on the exact surface of a height, the slant range is the
    distance from the sensor's own optical centre to the point given, measured here with numpy."""
    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    pose = Pose.from_deg(LAT, LON, H, 0, 0, 0, 0, 60)
    rows, cols = np.array([1162.12, 900.0]), np.array([1146.42, 1400.0])
    c = Corrections.for_sensor(cam, "standard", light_time, False)
    hit = Pipeline(cam, HeightSurface(300.0, "geodetic"), c).locate(rows, cols, pose)
    assert np.all(hit.status == Status.OK) and np.all(np.asarray(hit.refraction_m) > 0.5)
    o = np.asarray(cam.line_of_sight(rows, cols, pose).origin_ecef, float)
    # 1 um: two distances of 36 km computed apart, to the rounding of their coordinates
    np.testing.assert_allclose(hit.slant_range, np.linalg.norm(np.asarray(hit.ecef) - o, axis=-1), rtol=0, atol=1e-6)


@pytest.mark.parametrize("off_nadir_deg, tol_m", [(20.0, 0.003), (50.0, 0.006)])
def test_a_bent_line_near_a_point_passes_through_the_traced_ray_there(off_nadir_deg, tol_m):
    """``lines_near`` (the straight lines triangulation meets) from 700 km: the independent ray
    trace's point at 300 m lies on the line given for it. Tolerances as test_refraction.py's ray
    trace from 700 km (the model's 0.3 and 2.7 mm there, and the trace's own 2-4 mm); a sphere
    osculating the ellipsoid at the camera instead of near the point misses by 19 mm at 50 deg."""
    from raytrace import look

    from geoloc.surfaces.base import LineOfSight

    o, d = look(math.radians(35.0), math.radians(80.0), 700e3, off_nadir_deg, azimuth_deg=53.0)
    target = trace(o, d, 300.0, exact_n)
    los = LineOfSight(o[None], d[None], np.zeros(1, np.uint8))
    line = Pipeline(None, None, Corrections(refraction=STANDARD_REFRACTION)).lines_near(los, target[None])
    assert line.status[0] == Status.OK
    bo, bd = np.asarray(line.origin_ecef[0], float), np.asarray(line.direction_ecef[0], float)
    v = target - bo
    assert np.linalg.norm(v - (v @ bd) * bd) < tol_m
    assert np.linalg.norm(np.cross(target - o, d)) > 1.0  # the straight ray misses it by metres


def test_a_nadir_ray_on_a_dem_is_not_bent_and_settles_at_once():
    """A vertical ray is not bent (Snell's law in spherical layers: n r sin z is constant and z = 0):
    on a DEM its refracted point is its straight one and its status OK, alone or in a batch with an
    oblique ray, whose point moves by metres and settles at the DEM's height."""
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import DemSurface

    cam = as_sensor(Camera(166841.0, 1162.12, 1146.42, 2323, 2292))
    lat_s, lon_s, _ = lookAtSpheroid(LAT, LON, H, 0.0, 60.0)
    n0, w0, step = max(LAT, lat_s) + 0.02, LON - 0.03, 0.001
    ny = int((n0 - min(LAT, lat_s) + 0.02) / step) + 1
    dem = DEM.from_array(np.full((ny, 61), 500.0), n0, w0, step, step, datum="ellipsoid")
    c = Corrections.for_sensor(cam, "standard")
    pose = Pose(
        *(np.array([v, v]) for v in (math.radians(LAT), math.radians(LON), H, 0.0, 0.0, 0.0, 0.0)),
        np.radians([0.0, 60.0]),
    )
    rows, cols = np.full(2, 1162.12), np.full(2, 1146.42)  # the principal point: the gimbal's direction
    for k in ([0], [0, 1]):
        p = Pose(
            *(
                np.asarray(getattr(pose, f))[k]
                for f in ("lat", "lon", "h", "heading", "pitch", "roll", "gimbal_roll", "gimbal_pitch")
            )
        )
        bent = Pipeline(cam, DemSurface(dem, "exact"), c).locate(rows[k], cols[k], p)
        straight = Pipeline(cam, DemSurface(dem, "exact")).locate(rows[k], cols[k], p)
        assert np.all(bent.status == Status.OK), bent.status
        # 1 mm: the fixed point's own tolerance (REFRACTION_TOL_M)
        assert np.linalg.norm(np.asarray(bent.ecef[0]) - np.asarray(straight.ecef[0])) < 1e-3
        np.testing.assert_allclose(bent.h, 500.0, rtol=0, atol=1e-3)
        if len(k) == 2:
            assert np.linalg.norm(np.asarray(bent.ecef[1]) - np.asarray(straight.ecef[1])) > 1.0
