"""Refraction in the viewer: the bent ray beside the straight one, and its shift.

Checked outside the viewer's code: the shift the panel states and the located point are
``geoloc locate ... --refraction standard --json``'s (a subprocess of the CLI, its argv written here
from the records CSV read with ``csv``), the straight line's end is ``--refraction none``'s, both
to 1 mm (ECEF distances by pyproj). On the scene's nodes: the drawn bent polyline ends on the
located point (the red marker), and its offset from the drawn straight line of sight scales with
the exaggeration whose factor the label on the drawing gives ("x100").

In headless Chromium a person opens the "Refraction" folder, picks "standard", reads the shift in
the panel, types 100 into "bent ray drawn x"; screenshots in ``test-artifacts/viz_refraction_*.png``.
"""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_viz_browser import ARTIFACTS, chromium, look_at_wxyz, n_colours, open_viewer, served, wait_for

pytestmark = [pytest.mark.browser]
ROOT = Path(__file__).resolve().parents[2]
RECORDS = ROOT / "assets" / "records" / "qiao2017_flight_tests.csv"
DEM = ROOT / "assets" / "dem" / "etopo5_flight_area.tif"


def t3_1() -> dict:
    """The first [Q17] record (the viewer's default scene), read with csv."""
    with open(RECORDS, newline="") as fh:
        return next(csv.DictReader(fh))


def cli_locate(refraction: str, method=("--method", "bisect", "--threshold", "1")) -> dict:
    """``geoloc locate`` of T3-1's pixel on the bundled DEM, bisection at 1 m (the scene's method)."""
    r = t3_1()
    pose = [
        f"--{k.replace('_', '-')}" if i == 0 else r[k]
        for k in ("heading_deg", "pitch_deg", "roll_deg", "gimbal_roll_deg", "gimbal_pitch_deg")
        for i in (0, 1)
    ]
    argv = [
        sys.executable,
        "-m",
        "geoloc",
        "locate",
        "--lat-deg",
        r["ac_lat_deg"],
        "--lon-deg",
        r["ac_lon_deg"],
        "--h-m",
        r["ac_h_m"],
        *pose,
        "--row",
        r["row"],
        "--col",
        r["col"],
        "--dem",
        str(DEM),
        *method,
        "--refraction",
        refraction,
        "--json",
    ]
    out = subprocess.run(argv, capture_output=True, text=True, check=True, timeout=300)
    return json.loads(out.stdout)


def ecef(lat_deg, lon_deg, h_m):
    """WGS 84 geodetic -> ECEF by PROJ (EPSG:4979 -> EPSG:4978), not the core's geodesy."""
    from pyproj import Transformer

    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(t.transform(lon_deg, lat_deg, h_m))


def _layer(app):
    return next(lay for lay in app.layers if type(lay).__name__ == "RefractionLayer")


def node_points_m(server, app, name):
    """A line-segment node's points back in ENU metres (scene km, Up times the vertical exaggeration)."""
    from geoloc_viz.scene_geoloc import WORLD_SCALE

    d = app.view.disp
    seg = np.asarray(server.scene.get_handle_by_name(name).points, float)
    return seg / (WORLD_SCALE * np.array([1.0, 1.0, d.vertical_exaggeration]))


def off_line_m(pts, a, b):
    """Distances of points from the line through a and b [m]."""
    u = (b - a) / np.linalg.norm(b - a)
    v = pts - a
    return np.linalg.norm(v - (v @ u)[:, None] * u, axis=-1)


def enu_to_ecef(app, p):
    return np.asarray(app.scn.enu.to_ecef(np.asarray(p, float)), float)


def check_scene(server, app, bent_cli, straight_cli):
    """The scene's nodes against the CLI's points (see the module docstring)."""
    # float32 nodes in km within 20 km of the origin: 1.2e-6 km steps, so 5 mm on node positions
    node_tol = 5e-3
    hit = np.array(server.scene.get_handle_by_name("/enu/hit/result").position, float) / 1e-3
    bent = node_points_m(server, app, "/enu/refraction/bent")
    los = node_points_m(server, app, "/enu/los")[0]
    # the polyline's end is the located point (the red marker), its start the camera (the line's start)
    assert np.linalg.norm(bent[-1, 1] - hit) < node_tol
    assert np.linalg.norm(bent[0, 0] - los[0]) < node_tol
    # the located point and the straight line's end are the CLI's, with and without refraction (1 mm)
    want_bent = ecef(bent_cli["lat_deg"], bent_cli["lon_deg"], bent_cli["h_m"])
    want_raw = ecef(straight_cli["lat_deg"], straight_cli["lon_deg"], straight_cli["h_m"])
    g = app.geometry
    assert np.linalg.norm(enu_to_ecef(app, g.hit_enu) - want_bent) < 1e-3
    assert np.linalg.norm(enu_to_ecef(app, g.raw_hit_enu) - want_raw) < 1e-3
    assert np.linalg.norm(los[1] - g.raw_hit_enu) < node_tol
    return bent, los


def test_view_refraction_option_reaches_the_scene():
    """``geoloc view --scenario flight-test --refraction standard`` (the core's option helper)."""
    from geoloc.cli import build_parser
    from geoloc_viz.cli.view import app_factory

    bent_cli, straight_cli = cli_locate("standard"), cli_locate("none")
    assert bent_cli["corrections"] == "refraction" and straight_cli["corrections"] == "none"
    args = build_parser().parse_args(["view", "--scenario", "flight-test", "--refraction", "standard"])
    with served() as server:
        app = app_factory(args)(server)
        lay = _layer(app)
        assert app.scn.corrections.names == ("refraction",) and lay.dd.value == "standard"
        assert app.inputs.method == "bisect" and app.inputs.threshold == 1.0  # what cli_locate asks for
        # the panel's shift is the CLI's refraction_m to 1 mm (printed to 1 mm: 0.5 mm rounding)
        shift = float(re.search(r"moved the point \*\*(\d+\.\d{3}) m", lay.md.content).group(1))
        assert abs(shift - bent_cli["refraction_m"]) < 1e-3
        assert "corrections: refraction; refraction moved the point" in app.md_summary.content
        bent, los = check_scene(server, app, bent_cli, straight_cli)
        # the predicted ellipse sits on the corrected point (the CLI's, 1 mm), not the straight one
        unc = next(lay for lay in app.layers if type(lay).__name__ == "UncertaintyLayer")
        unc.update()
        p_unc = ecef(math.degrees(float(unc.pu.lat)), math.degrees(float(unc.pu.lon)), float(unc.pu.h))
        assert np.linalg.norm(p_unc - ecef(bent_cli["lat_deg"], bent_cli["lon_deg"], bent_cli["h_m"])) < 1e-3
        # the two ends are refraction_m apart (the CLI's two points, by PROJ)
        d_cli = np.linalg.norm(
            ecef(bent_cli["lat_deg"], bent_cli["lon_deg"], bent_cli["h_m"])
            - ecef(straight_cli["lat_deg"], straight_cli["lon_deg"], straight_cli["h_m"])
        )
        assert abs(d_cli - bent_cli["refraction_m"]) < 1e-3
        lab = server.scene.get_handle_by_name("/enu/refraction/label")
        assert lab.text.startswith("bent ray (refraction), true size")
        off1 = off_line_m(bent.reshape(-1, 3), los[0], los[1]).max()
        lay.sl_scale.value = 100.0
        wait_for(lambda: lab.text.startswith("bent ray (refraction), x100"), 30, "the label x100")
        off100 = off_line_m(node_points_m(server, app, "/enu/refraction/bent").reshape(-1, 3), los[0], los[1]).max()
        # drawn offsets 100 x the true ones (node rounding: 5 mm at x1, 0.5 m at x100)
        assert off100 == pytest.approx(100 * off1, abs=0.5 + 100 * 5e-3)
        assert off1 > 0.5  # the bend is there at true size (1.4 m at the end)
        # off again: no bent ray, the straight line back to the located point
        lay.set_refraction("none")
        assert not server.scene.get_handle_by_name("/enu/refraction/bent").visible
        assert app.geometry.raw_hit_enu is None and "corrections: **none**" in lay.md.content


def test_a_person_turns_refraction_on_in_chromium(tmp_path):
    import PIL.Image

    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    bent_cli, straight_cli = cli_locate("standard"), cli_locate("none")
    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        lay = _layer(app)
        assert lay.dd.value == "none" and app.geometry.bent is None
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 900, 700)
            page.wait_for_selector("canvas", timeout=90000)
            client = next(iter(server.get_clients().values()))
            page.get_by_text("Refraction", exact=True).click(timeout=60000)
            box = page.get_by_label("refraction", exact=True)
            box.click(timeout=120000)
            page.get_by_role("option", name="standard").click(timeout=120000)
            wait_for(lambda: app.geometry.bent is not None, 120, "refraction on the server")
            # the shift as a person reads it in the page
            el = page.get_by_text(re.compile(r"refraction moved the point \d+\.\d{3} m \(from")).first
            el.wait_for(timeout=60000)
            shift = float(re.search(r"moved the point (\d+\.\d{3}) m", el.inner_text()).group(1))
            assert abs(shift - bent_cli["refraction_m"]) < 1e-3  # printed to 1 mm
            check_scene(server, app, bent_cli, straight_cli)
            page.screenshot(path=str(ARTIFACTS / "viz_refraction_panel.png"))
            num = page.locator(
                "xpath=//label[normalize-space()='bent ray drawn x']/ancestor::div"
                "[.//input[@inputmode='decimal']][1]//input[@inputmode='decimal']"
            )
            num.fill("100", timeout=60000)
            num.press("Enter")
            wait_for(lambda: lay.scale == 100.0, 30, "the factor to reach the server")
            lab = server.scene.get_handle_by_name("/enu/refraction/label")
            wait_for(lambda: lab.text.startswith("bent ray (refraction), x100"), 60, "the label x100")
            # look along the last kilometres of both lines, from the side, at the hit
            hit = np.array(server.scene.get_handle_by_name("/enu/hit/result").position)
            los = np.asarray(server.scene.get_handle_by_name("/enu/los").points, float)[0]
            mid = hit + 0.15 * (los[0] - hit)
            side = np.cross(los[0] - hit, [0.0, 0.0, 1.0])
            pos = mid + 1.2 * side / np.linalg.norm(side) + np.array([0.0, 0.0, 0.6])
            img = None
            for _ in range(40):
                img = client.get_render(
                    600,
                    900,
                    position=tuple(pos),
                    wxyz=look_at_wxyz(pos, mid),
                    fov=1.0,
                    transport_format="png",
                    timeout=60,
                )
                if n_colours(img) > 20:
                    break
            PIL.Image.fromarray(img[..., :3]).save(ARTIFACTS / "viz_refraction_x100.png")
            page.screenshot(path=str(ARTIFACTS / "viz_refraction_x100_page.png"))


def test_limb_scene_marks_the_refracted_tangent_point(tmp_path):
    """``--scenario limb --refraction standard``: the panel's refracted tangent height, as a person
    reads it in the page, is ``geoloc limb --origin-ecef ... --direction-ecef ... --refraction
    standard --json``'s for the scene's ray, and the lime marker sits at the refracted tangent
    point, below the straight line's tangent point."""
    from geoloc.cli import build_parser
    from geoloc_viz.cli.view import app_factory

    args = build_parser().parse_args(["view", "--scenario", "limb", "--refraction", "standard"])
    with served() as server:
        app = app_factory(args)(server)
        o, d = (np.asarray(v, float).reshape(3) for v in (app.chain.origin_ecef, app.chain.direction_ecef))
        argv = [
            sys.executable,
            "-m",
            "geoloc",
            "limb",
            "--origin-ecef",
            *(repr(float(x)) for x in o),
            "--direction-ecef",
            *(repr(float(x)) for x in d),
            "--refraction",
            "standard",
            "--json",
        ]
        cli = json.loads(subprocess.run(argv, capture_output=True, text=True, check=True, timeout=300).stdout)
        shown = float(re.search(r"refracted tangent \*\*h = (\d+\.\d) m\*\*", app.md.content).group(1))
        assert abs(shown - cli["refracted_tangent_h_m"]) < 0.051  # printed to 0.1 m
        with chromium(tmp_path) as browser:  # and in the page, where a person reads it
            page = open_viewer(browser, server, 900, 700)
            el = page.get_by_text(re.compile(r"refracted tangent h = \d+\.\d m")).first
            el.wait_for(timeout=120000)
            seen = float(re.search(r"refracted tangent h = (\d+\.\d) m", el.inner_text()).group(1))
            assert abs(seen - cli["refracted_tangent_h_m"]) < 0.051  # printed to 0.1 m
            page.screenshot(path=str(ARTIFACTS / "viz_limb_refracted_panel.png"))
        assert cli["refracted_tangent_h_m"] < cli.get("tangent_h_m", cli.get("exact_tangent_h_m", np.inf))
        refr = np.asarray(server.scene.get_handle_by_name("/limb/refracted").position, float)
        tan = np.asarray(server.scene.get_handle_by_name("/limb/tangent").position, float)
        want = app.w(np.asarray(app.lref.refracted_tangent_ecef).reshape(3))
        assert np.allclose(refr, want, atol=1e-6)  # km: the node is the core's point
        assert refr[2] < tan[2]  # lower than the straight line's tangent point (scene Up, km)
        app.dd_refraction.value = "none"
        wait_for(lambda: app.lref is None, 30, "refraction off")


def test_switching_refraction_relocates_the_whole_flight():
    """The Refraction folder's switch reaches the flight debugger: every frame is located again
    through the new pipeline. The current frame's point is `geoloc locate --method exact`'s (the
    flight model's solver), with and without refraction (1 mm), and switching back gives the first
    point again."""
    from geoloc.cli import build_parser
    from geoloc_viz.cli.view import app_factory

    want = {r: cli_locate(r, ("--method", "exact")) for r in ("none", "standard")}
    args = build_parser().parse_args(["view", "--scenario", "flight-test"])
    with served() as server:
        app = app_factory(args)(server)
        fl = next(lay for lay in app.layers if type(lay).__name__ == "FlightLayer")
        k = app.scn.record_index

        def frame_point():
            m = fl.model
            return ecef(float(m.recomputed_lat_deg[k]), float(m.recomputed_lon_deg[k]), float(m.recomputed_h_m[k]))

        def cli(r):
            return ecef(want[r]["lat_deg"], want[r]["lon_deg"], want[r]["h_m"])

        p0 = frame_point()
        assert np.linalg.norm(p0 - cli("none")) < 1e-3
        _layer(app).set_refraction("standard")
        p1 = frame_point()
        assert np.linalg.norm(p1 - cli("standard")) < 1e-3
        assert np.linalg.norm(p1 - p0) > 1.0  # T3-1: 1.4 m
        _layer(app).set_refraction("none")
        assert np.linalg.norm(frame_point() - p0) < 1e-6
