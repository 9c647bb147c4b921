"""The docs' other viewer pictures, from the real page: ``geoloc view``'s scenes in headless Debian
Chromium (software WebGL), each taken once its canvas has settled (watched from inside the page as
``benchmarks/bench_browser.py`` watches it: 2 s without a change), never after a fixed sleep.

* ``flight_debugger.png`` (1100 x 700, docs/flight_debugger.md, docs/tour_viewer.md): the bundled KLV
  example flight in the flight debugger, its top outlier chosen, the camera on its footprints;
* ``viewer_turret.png`` (1100 x 700, docs/tour_sensors.md): the EO turret (``eo_turret.toml``, record
  orbit1-5) over the SRTM crop, the camera beside the aircraft, its gimbal frames and angle sliders;
* ``viewer_flight_test.png`` (1400 x 850): the [Q17] flight test (record T3-1) over the ETOPO5 crop,
  the camera beside the aircraft and its line of sight to the hit;
* ``viewer_uncertainty_ellipse.png`` (960 x 640, docs/tour_accuracy.md, docs/uncertainty.md): the
  browser's render of T3-1's hit from 3 km, its predicted 90 % ellipse drawn x10 (the folder's own
  factor, as ``tests/viz/test_viz_uncertainty.py`` sets it);
* ``viewer_target_rays.png`` (1280 x 900, docs/tour_accuracy.md, docs/uncertainty.md): one ground point
  clicked in the picture panel of records 1, 21 and 41 of the example orbit (as
  ``tests/viz/test_viz_triangulate.py`` clicks it), the three rays seen from the side;
* ``teaching_vector_panel.png`` (1280 x 800, docs/teaching.md): the teaching panel on T3-1, hop
  ``T_ned_body``, "frame the aircraft", the panel scrolled to the hop's matrices;
* ``teaching_q17_globe.png`` (1280 x 800): hop ``T_ecef_ned``, the globe with [Q17] eq. 5's frames,
  the panel scrolled to the factor block;
* ``teaching_turret_row.png`` (880 x 470, a clip of the 3D view left of the panel): the turret's row of frames,
  framed;
* ``limb_overview.png`` and ``limb_tangent.png`` (1280 x 800, docs/limb.md): ``geoloc view --limb``
  at frame 0, alpha 0: its own first view, then the camera close to the [L18] tangent (deep orange)
  and the exact minimum (green).

The two rerun pictures are ``examples/89_rerun_screenshot.py``'s (docs/rerun.md).

Run: ``python tools/make_scene_screenshots.py [--out docs/img] [--only NAME ...]`` (NAME without
``.png``). Each PNG is written to a temporary file and renamed into place. Look at each picture.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from typing import Any
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz"), str(ROOT / "benchmarks"), str(ROOT / "tools")]


#: distinct colours (5 bits a channel) on the probe's 250 x 160 copy of the canvas before it counts as
#: drawn: a blank or half-loaded canvas has 1-70, the turret's first view 193, the flight's over 200
MIN_COLOURS = 100


class Tab:
    """A page on a viser server whose canvas is watched (``bench_browser.PROBE``)."""

    def __init__(self, browser, server, width: int, height: int, ready=lambda: True):
        from bench_browser import PROBE, _settled

        self._settled = _settled
        self.server = server
        self.page = browser.new_page(viewport={"width": width, "height": height})
        self.page.add_init_script(PROBE)
        t0 = time.time()
        self.page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
        _, self.seen = _settled(
            self.page, t0, ready=lambda: len(server.get_clients()) > 0 and ready(), min_colours=MIN_COLOURS
        )

    def settle(self) -> None:
        """Wait for the canvas to change after what was just done, then hold still for 2 s."""
        t1 = time.time()
        _, self.seen = self._settled(self.page, t1, after=self.seen, min_colours=MIN_COLOURS)

    def shot(self, path: Path, clip=None) -> None:
        from make_viewer_screenshots import shot

        if clip is None:
            shot(self.page, path)
            return
        orig = self.page.screenshot
        self.page.screenshot = lambda **kw: orig(clip=clip, **kw)
        try:
            shot(self.page, path)
        finally:
            self.page.screenshot = orig

    def close(self) -> None:
        """Close the page (software WebGL on 2 cores: one page drawing at a time)."""
        self.page.close()


def scroll_to(page, bold: str) -> None:
    """Scroll the GUI panel so that the first bold text ``bold`` (a hop's name) is at its top."""
    # the visible one: the session's own (closed) hop folder holds the same bold name
    page.locator("strong", has_text=bold).locator("visible=true").first.evaluate(
        "e => e.scrollIntoView({block: 'start'})"
    )
    time.sleep(0.5)  # the panel's scroll is the browser's own, drawn at the next frame


def turret_scenario():
    from geoloc.assets import asset_path
    from geoloc_viz.scenario import load_view_scenario

    return load_view_scenario(
        asset_path("records", "eo_turret_flight.csv"), "orbit1-5", asset_path("sensors", "eo_turret.toml")
    )


def node(server, name: str) -> Any:
    """The scene node ``name`` (a label's ``text``, a marker's ``position``); a missing one is named."""
    h = server.scene.get_handle_by_name(name)
    if h is None:
        raise LookupError(f"make_scene_screenshots: the scene has no node {name!r}")
    return h


def position_km(server, name: str) -> np.ndarray:
    return np.asarray(node(server, name).position, dtype=np.float64)


def hit_km(server) -> np.ndarray:
    return position_km(server, "/enu/hit/result")


# ------------------------------------------------------------------ the pictures
def flight_debugger(browser, out: Path) -> None:
    from geoloc_viz import flight_layer
    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    server = make_server(port=0)
    try:
        app = GeolocApp(server, default_flight_scenario(), layers=(flight_layer.attach,))
        fl = app.layers[-1]
        tab = Tab(browser, server, 1100, 700)
        fl.go(fl.top_idx[0])
        c = app.scn.enu.from_ecef(fl.model.enu.to_ecef(np.nanmean(fl.model.centre_enu, axis=0))) * 1e-3
        # viser's value setter is not next to its getter: mypy sees the property read-only
        app.sl_marker.value = app.sl_ac.value = 60.0  # type: ignore[misc]
        app.move_camera((c + [0.6, -1.2, 1.4], c + [-0.3, 0.1, 0.0]))
        tab.settle()
        tab.shot(out / "flight_debugger.png")
        tab.close()
    finally:
        server.stop()


def _pose_shot(browser, out: Path, name: str, scn, size, scroll=None, zoom: float = 1.0) -> None:
    """The View folder's overview, the camera then ``zoom`` times as far from the aircraft."""
    from geoloc_viz.app import GeolocApp, make_server

    server = make_server(port=0)
    try:
        app = GeolocApp(server, scn)
        tab = Tab(browser, server, *size)
        # the View folder's "overview: aircraft, frames, line of sight", nearer the aircraft by ``zoom``
        pos, aim = (np.asarray(v, float) for v in app.view.camera_pose("overview"))
        ac = position_km(server, "/enu/aircraft")
        app.move_camera((ac + zoom * (pos - ac), ac + zoom * (aim - ac)))
        tab.settle()
        if scroll is not None:
            tab.page.get_by_text(scroll, exact=True).first.evaluate("e => e.scrollIntoView({block: 'center'})")
        tab.shot(out / name)
        tab.close()
    finally:
        server.stop()


def viewer_turret(browser, out: Path) -> None:
    _pose_shot(browser, out, "viewer_turret.png", turret_scenario(), (1100, 700), "azimuth (deg)", 0.45)


def viewer_flight_test(browser, out: Path) -> None:
    from geoloc_viz.scenario import load_view_scenario

    _pose_shot(browser, out, "viewer_flight_test.png", load_view_scenario(), (1400, 850))


def viewer_uncertainty_ellipse(browser, out: Path) -> None:
    import PIL.Image
    from test_viz_browser import look_at_wxyz, n_colours, wait_for

    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.scenario import load_view_scenario

    server = make_server(port=0)
    try:
        app = GeolocApp(server, load_view_scenario())
        lay = next(x for x in app.layers if type(x).__name__ == "UncertaintyLayer")
        tab = Tab(browser, server, 800, 520)
        lay.sl_scale.value = 10.0  # its own factor: the label on the drawing says x10
        wait_for(
            lambda: node(server, "/enu/uncertainty/label").text.startswith("90 % ellipse, x10"),
            60,
            "the ellipse drawn x10",
        )
        client = next(iter(server.get_clients().values()))
        hit = hit_km(server)
        pos = hit + np.array([0.6, -2.0, 2.4])  # km: 3 km off, looking down at the hit
        prev = None
        for _ in range(40):  # the browser's render, until two in a row agree (the scene is drawn)
            img = client.get_render(
                640, 960, position=tuple(pos), wxyz=look_at_wxyz(pos, hit), fov=0.9, transport_format="png", timeout=60
            )
            if n_colours(img) > 20 and prev is not None and np.abs(img.astype(float) - prev).mean() < 0.5:
                break
            prev = img.astype(float)
        path = out / "viewer_uncertainty_ellipse.png"
        PIL.Image.fromarray(img[..., :3]).save(path, optimize=True)
        print(f"wrote {path}")
        tab.close()
    finally:
        server.stop()


def viewer_target_rays(browser, out: Path) -> None:
    from test_viz_browser import wait_for
    from test_viz_picture import _panel_pixel_xy, make_app, render_frame
    from test_viz_triangulate import FRAMES, _pixel_of, _target

    from geoloc.io.images import ArrayImages
    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    scn.images = ArrayImages([render_frame(scn, i) for i in FRAMES])
    idx = np.full(len(scn.records), -1)
    idx[list(FRAMES)] = np.arange(len(FRAMES))
    scn.image_index = idx
    server, app, layer = make_app(copy.copy(scn))
    try:
        g = _target(app, layer)
        tab = Tab(browser, server, 1280, 900)
        page = tab.page
        page.wait_for_selector("#geoloc-picture", timeout=120000)
        layer.sl_zoom.value = 2  # 4x: an image pixel is ~9 screen px, a click lands inside it
        for k in FRAMES:
            app.load_record(k, move_camera=False)
            wait_for(lambda: layer.index == k and layer.image is not None, 120, f"record {k + 1}'s image")
            r, c = (float(round(v)) for v in _pixel_of(app, layer, g))
            wait_for(
                lambda: page.locator("#geoloc-picture").get_attribute("data-w") == str(240 // 4),
                120,
                "the panel to show the 4x crop",
            )
            for _ in range(10):  # the panel may redraw its picture under the locator: look it up again
                try:
                    page.locator("#geoloc-picture").scroll_into_view_if_needed(timeout=60000)
                    break
                except Exception:
                    time.sleep(1.0)
            x, y = _panel_pixel_xy(page, r, c)
            page.mouse.click(x, y)
            wait_for(
                lambda: layer.pick is not None and (layer.pick.row, layer.pick.col) == (r, c) and k in layer.target,
                120,
                "the click to reach the server",
            )
        t = layer.target_rays
        panel = page.locator("text=triangulated latitude").first
        wait_for(lambda: f"{t.tri.lat_deg:.8f}" in panel.inner_text(), 120, "the panel to show three frames'")
        G = np.asarray(t.tri.ecef, float)
        z = lambda p: np.asarray(app.view.disp.z(app.scn.enu.from_ecef(p)), float)  # noqa: E731
        Gs, m = z(G), np.mean([z(o) for o in t.origins], 0) - z(G)
        side = np.cross(m, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        app.move_camera((Gs + 0.45 * m + 0.9 * np.linalg.norm(m) * side, Gs + 0.3 * m))
        panel.evaluate("e => e.scrollIntoView({block: 'center'})")
        tab.settle()
        tab.shot(out / "viewer_target_rays.png")
        tab.close()
    finally:
        server.stop()


def _teaching(browser, out: Path, scn, size, hop: str, shots, globe: bool = False) -> None:
    """The teaching panel at ``hop``, "frame the aircraft" clicked; with ``globe`` the camera then
    2.5 times nearer, on the inset globe (in the middle of what the GUI panel leaves free)."""
    from test_viz_browser import wait_for

    from geoloc_viz.app import GeolocApp, make_server

    server = make_server(port=0)
    try:
        app = GeolocApp(server, scn)
        tp = next(x for x in app.layers if type(x).__name__ == "TeachingPanel")
        tab = Tab(browser, server, *size)
        if tp.dd_hop.value != hop:
            tp.dd_hop.value = hop  # as the dropdown would
            wait_for(lambda: tp.hop == hop, 60, f"the hop {hop}")
        if tp.flight_view:  # a flight opens its teaching folder closed: a person opens it
            tab.page.get_by_text("Teaching: a vector through the chain", exact=True).first.click(timeout=120000)
        if not globe:
            tab.page.get_by_role("button", name="frame the aircraft").first.click(timeout=120000)
            tab.settle()
        else:  # "frame the aircraft"'s pose, then nearer the globe: one camera move
            from geoloc_viz.teaching_panel import PANEL_PX

            tp.cb_show.value = True
            wait_for(lambda: tp.cb_show.value, 60, "the frames row shown")
            eye, aim = (np.asarray(v, dtype=np.float64) for v in tp.camera_pose(*size))
            _, g, u = tp.layout(tp.chain)
            geo = app.geometry
            assert geo is not None  # the scenario was drawn: the overview above shows it
            g = np.asarray(app.view.disp.z(geo.aircraft_enu), dtype=np.float64) + g
            w, h = size
            dist = 0.4 * float(np.linalg.norm(eye - aim))
            f = 0.5 * h / np.tan(0.5 * float(next(iter(server.get_clients().values())).camera.fov))
            aim2 = g + u * 0.5 * PANEL_PX * dist / f  # the globe in the middle of the free part
            app.move_camera((aim2 + 0.4 * (eye - aim), aim2))
            tab.settle()
        for name, text, clip in shots:
            if text is not None:
                scroll_to(tab.page, text)
            tab.shot(out / name, clip=clip)
        tab.close()
    finally:
        server.stop()


def teaching_vector_panel(browser, out: Path) -> None:
    from geoloc_viz.scenario import load_view_scenario

    _teaching(
        browser,
        out,
        load_view_scenario(),
        (1280, 800),
        "T_ned_body",
        [("teaching_vector_panel.png", "T_ned_body", None)],
    )


def teaching_q17_globe(browser, out: Path) -> None:
    from geoloc_viz.scenario import load_view_scenario

    _teaching(
        browser,
        out,
        load_view_scenario(),
        (1280, 800),
        "T_ecef_ned",
        [("teaching_q17_globe.png", "T_ecef_ned", None)],
        globe=True,
    )


def teaching_turret_row(browser, out: Path) -> None:
    _teaching(
        browser,
        out,
        turret_scenario(),
        (1280, 800),
        "T_ned_body",
        [("teaching_turret_row.png", None, {"x": 0, "y": 240, "width": 880, "height": 470})],
    )


def _limb(browser, out: Path) -> None:
    from geoloc_viz.app import make_server
    from geoloc_viz.scene_limb import LimbApp, load_limb

    server = make_server(port=0)
    try:
        app = LimbApp(server, load_limb())
        tab = Tab(browser, server, 1280, 800)
        tab.shot(out / "limb_overview.png")
        tan = position_km(server, "/limb/tangent")
        ex = position_km(server, "/limb/exact")
        pos, aim, up = app.camera_pose()
        mid = 0.5 * (tan + ex)
        d = np.asarray(pos, float) - mid
        eye = mid + d / np.linalg.norm(d) * 4.0 * max(float(np.linalg.norm(ex - tan)), 1e-3)
        client = next(iter(server.get_clients().values()))
        with client.atomic():
            client.camera.up_direction = tuple(up)
            client.camera.position = tuple(eye)
            client.camera.look_at = tuple(mid)
        tab.settle()
        tab.shot(out / "limb_tangent.png")
        tab.close()
    finally:
        server.stop()


SHOTS = {
    "flight_debugger": flight_debugger,
    "viewer_turret": viewer_turret,
    "viewer_flight_test": viewer_flight_test,
    "viewer_uncertainty_ellipse": viewer_uncertainty_ellipse,
    "viewer_target_rays": viewer_target_rays,
    "teaching_vector_panel": teaching_vector_panel,
    "teaching_q17_globe": teaching_q17_globe,
    "teaching_turret_row": teaching_turret_row,
    "limb": _limb,  # limb_overview.png and limb_tangent.png
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="folder of the PNGs (docs/img)")
    ap.add_argument("--only", nargs="+", choices=sorted(SHOTS), help="take only these (default: all)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    from test_viz_browser import chromium

    with tempfile.TemporaryDirectory() as home, chromium(Path(home)) as browser:
        for name in args.only or SHOTS:
            t0 = time.monotonic()
            SHOTS[name](browser, args.out)
            print(f"{name}: {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
