"""End-to-end: the viewer in real headless Chromium (Debian ``chromium``, playwright).

The page loads, the browser registers as a viser client (its WebGL canvas is
up), the 3D render is not blank (pixel statistics), and typing a new aircraft
height into the GUI moves the scene (server state, node positions and pixels);
the ``--export`` HTML file opens from file:// with no server.
Screenshots (the browser's own renders) go to ``test-artifacts/``.

Run alone: ``python -m pytest -q -m browser tests/viz/test_viz_browser.py``.
"""

import atexit
import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"

# tools/test.sh installs Debian chromium: no skip for want of it (a missing browser fails loudly)
pytestmark = [pytest.mark.browser]


def wait_for(cond, timeout, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def n_colours(img):
    return len(np.unique((img // 16).reshape(-1, 3), axis=0))


def look_at_wxyz(pos, target, up=(0.0, 0.0, 1.0)):
    """Quaternion of a viser camera (OpenCV axes: x right, y down, z forward) at pos looking at target."""
    import viser.transforms as vtf

    f = np.asarray(target, float) - np.asarray(pos, float)
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    return vtf.SO3.from_matrix(np.stack([r, np.cross(f, r), f], axis=1)).wxyz


def render(server, path, timeout=40.0, min_colours=20):
    """The browser's render of the viewer's initial view (JPEG, RGB), retried until it shows a scene.

    Right after connecting, the client may not have applied every scene message
    yet; a render that stays blank until ``timeout`` fails the test.
    """
    import PIL.Image

    client = next(iter(server.get_clients().values()))
    cam = server.initial_camera
    t0 = time.monotonic()
    while True:
        img = client.get_render(
            300,
            450,
            position=cam.position,
            wxyz=look_at_wxyz(cam.position, cam.look_at),
            fov=cam.fov,
            transport_format="jpeg",
            timeout=timeout,
        )
        if n_colours(img) > min_colours or time.monotonic() - t0 > timeout:
            break
        time.sleep(1.0)
    PIL.Image.fromarray(img).save(path)
    return img[..., :3].astype(float)


#: Several tabs at once: Chromium throttles (or stops) the pages not in front; these tests
#: need every tab to run its scene and GUI.
MULTI_TAB_FLAGS = [
    "--disable-renderer-backgrounding",
    "--disable-background-timer-throttling",
    "--disable-backgrounding-occluded-windows",
]


def close_software_webgl_notice(page) -> None:
    """Close the browser's "Software WebGL rendering detected" notice with its x, as a person would.

    Headless Chromium draws with SwiftShader, so viser warns about the machine, not the scene; a
    documentation picture should show the scene. Any other notice is left on the page."""
    note = page.locator(".mantine-Notification-root", has_text="Software WebGL rendering detected")
    if note.count():
        note.locator("button").first.click(timeout=10000)
        note.wait_for(state="detached", timeout=10000)


#: The worker's one browser: {"pw": the playwright instance, "browser": it, "flags": its extra flags, "home": its
#: HOME}. Launching headless Chromium for each test cost 8-10 s of waiting at load 13 (playwright's driver
#: 4.1 s, the browser and a first page 3.3-5.1 s, its close 0.6-1.2 s) on the Chromium group's one worker,
#: which the whole suite waits for (docs/testing.md, "The suite's time"). A test gets a clean browser all the same: its pages
#: are new contexts (``browser.new_page``: own cookies, storage and cache) and every context it opened
#: is closed when it leaves ``chromium()``.
_SHARED: dict = {}


def close_shared_chromium() -> None:
    """Close the worker's browser and its playwright driver (tests/conftest.py, once the group is done)."""
    browser, pw, home = _SHARED.pop("browser", None), _SHARED.pop("pw", None), _SHARED.pop("home", None)
    _SHARED.clear()
    try:
        if browser is not None and browser.is_connected():
            browser.close()
    finally:
        if pw is not None:
            pw.stop()
        if home is not None:
            shutil.rmtree(home, ignore_errors=True)


def _shared_chromium(extra_flags):
    import playwright.sync_api as playwright  # a test dependency: installed, never skipped

    # every launch carries the multi-tab flags: they change nothing for a page in front (a test's only page
    # is), and without them the three multi-tab tests relaunched the browser and the next test again
    flags = tuple(dict.fromkeys([*MULTI_TAB_FLAGS, *extra_flags]))
    browser = _SHARED.get("browser")
    if browser is not None and (_SHARED["flags"] != flags or not browser.is_connected()):
        if browser.is_connected():
            browser.close()  # one browser at a time on the worker
        del _SHARED["browser"]
        browser = None
    if "pw" not in _SHARED:
        # a script (the screenshot tools, the benchmarks) has no conftest to close it: at exit then
        atexit.register(close_shared_chromium)
        _SHARED["pw"] = playwright.sync_playwright().start()
        _SHARED["home"] = Path(tempfile.mkdtemp(prefix="geoloc-chromium-home-"))
    if browser is None:
        home = _SHARED["home"]
        env = {
            **os.environ,
            "HOME": str(home),
            "XDG_CONFIG_HOME": str(home / "config"),
            "XDG_CACHE_HOME": str(home / "cache"),
        }
        browser = _SHARED["pw"].chromium.launch(
            executable_path=CHROMIUM, args=FLAGS + list(flags), env=env, timeout=60000
        )
        _SHARED["browser"], _SHARED["flags"] = browser, flags
    return browser


@contextlib.contextmanager
def chromium(tmp_path, extra_flags=()):
    """Headless Debian chromium through playwright: the worker's one browser (``_SHARED``), launched with
    ``MULTI_TAB_FLAGS`` and ``extra_flags`` if it was not; every page the test opens is closed when it leaves. ``tmp_path``: the
    test's folder, unused since the browser is shared (its HOME/XDG folders are one temp folder)."""
    # tests/conftest.py sets this for each test: "0" means its look-up did not see this test open
    # Chromium, so under xdist it would run beside another browser (unset: not under pytest)
    if os.environ.get("GEOLOC_CHROMIUM_GROUP") == "0":
        raise AssertionError(
            f"{os.environ.get('PYTEST_CURRENT_TEST', 'this test')} opens Chromium outside the xdist group "
            "'chromium': tests/conftest.py's _opens_chromium did not find the call (name chromium, or "
            "call it through a function of a test module)"
        )
    browser = _shared_chromium(extra_flags)
    try:
        yield browser
    finally:
        if browser.is_connected():
            for ctx in list(browser.contexts):  # the test's pages, each in its own context
                ctx.close()


@contextlib.contextmanager
def served():
    """A viser server on a free loopback port (and the screenshot folder), stopped afterwards."""
    from geoloc_viz.app import make_server

    ARTIFACTS.mkdir(exist_ok=True)
    server = make_server(port=0)
    try:
        yield server
    finally:
        server.stop()


def open_viewer(browser, server, width, height):
    """A page on the viewer, once the browser has registered as a client (its WebGL canvas is up)."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=40000)
    wait_for(lambda: len(server.get_clients()) > 0, 40, "the browser to register")
    return page


def test_viewer_in_headless_chromium(tmp_path):
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 800, 520)
            page.wait_for_selector("canvas", timeout=20000)
            img0 = render(server, ARTIFACTS / "viz_default.png")
            # Not blank and not washed out: a blank canvas is one flat colour, and an unlit
            # terrain whose colours missed glTF's linearisation went nearly white (std 8,
            # before e6b7890). The default scene's coloured terrain and line of sight pass.
            assert img0.std(axis=(0, 1)).max() > 10.0
            assert n_colours(img0) > 20
            # The summary panel reached the page.
            page.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=20000)

            # Type a new aircraft height into the GUI, as a user would.
            before = np.array(server.scene.get_handle_by_name("/enu/hit/result").position)
            box = page.get_by_label("height (m, ellipsoidal)")
            box.fill("12000")
            box.press("Enter")
            wait_for(lambda: abs(app.inputs.h_m - 12000.0) < 1e-6, 20, "the height to reach the server")
            hit = lambda: np.array(server.scene.get_handle_by_name("/enu/hit/result").position)  # noqa: E731
            # A 6 km lower aircraft looking down at ~45 deg hits the ground km closer (scene unit: km).
            wait_for(lambda: np.linalg.norm(hit() - before) > 1.0, 20, "the scene to update")
            # the hit moves part way through the update (GUI callback thread): wait for the rest of
            # it (its labels) under the session's lock, so the render request queues after them
            with app._lock:
                pass
            ac = np.array(server.scene.get_handle_by_name("/enu/aircraft").position) * 1e3  # km -> m
            assert ac[2] == pytest.approx(12000.0 - app.scn.enu.h0, abs=50.0)  # ENU up ~ height
            img1 = render(server, ARTIFACTS / "viz_after_height_change.png")
            changed = np.abs(img1 - img0).max(axis=-1) > 30
            assert changed.mean() > 0.002, changed.mean()

            # --export: one HTML file that loads its embedded scene from file://, no server.
            out = app.export(tmp_path / "scene.html", animate_steps=False)
            page.close()  # software WebGL on 2 cores: render one page at a time
            page2 = browser.new_page(viewport={"width": 640, "height": 400})
            console = []
            page2.on("console", lambda m: console.append(m.text))
            page2.goto(out.as_uri(), timeout=40000)
            page2.wait_for_selector("canvas", timeout=40000)
            wait_for(
                lambda: any("Embedded data loaded" in m for m in console),
                30,
                "the exported page to load its embedded scene",
            )


def test_turret_sensor_in_headless_chromium(tmp_path):
    # an azimuth-elevation turret with a Brown lens (the bundled sensor file): the page shows
    # its own gimbal angles and frames, and the canvas renders the scene over the SRTM terrain
    from geoloc.assets import asset_path
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        scn = load_view_scenario(
            asset_path("records", "eo_turret_flight.csv"), "orbit1-5", asset_path("sensors", "eo_turret.toml")
        )
        app = GeolocApp(server, scn)
        assert [k for k in app.num if k.startswith("angle:")] == ["angle:azimuth", "angle:elevation"]
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1100, 700)
            # 60 s: right after loading, a 1100 x 700 software-WebGL page answers a query for an
            # element already shown in 13-30 s on the shared machine at load 8-10
            page.wait_for_selector("text=eo_turret_flight.csv: frame 4 (orbit1-5)", timeout=60000)
            page.wait_for_selector("text=azimuth (deg)", timeout=60000)
            img = render(server, ARTIFACTS / "viz_turret_render.png")
            assert n_colours(img) > 20
            before = np.array(server.scene.get_handle_by_name("/enu/hit/result").position)
            # a slider's value set from Python, as the GUI would (arrow keys also move the 3D camera)
            app.num["angle:azimuth"].value = app.inputs.angles_deg["azimuth"] + 10.0
            wait_for(
                lambda: (
                    np.linalg.norm(np.array(server.scene.get_handle_by_name("/enu/hit/result").position) - before) > 0.3
                ),
                20,
                "a 10 deg azimuth change to move the hit",
            )
            time.sleep(2.0)
            page.screenshot(path=str(ARTIFACTS / "viz_turret_page.png"))


def _open_tab(browser, server, width, height, before, timeout=90):
    """Another tab on the viewer: (its page, its client id, the one not in ``before``)."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=40000)
    wait_for(lambda: len(set(server.get_clients()) - before) == 1, timeout, "the new tab to register")
    return page, (set(server.get_clients()) - before).pop()


def test_two_tabs_keep_their_own_state_and_the_cap_in_chromium(tmp_path):
    # a state per tab, judged on each page's GUI text and on each browser's
    # own camera report; then a third tab over --max-clients 2 is told the limit
    from geoloc_viz.app import GeolocViewer
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        viewer = GeolocViewer(server, load_view_scenario(), max_clients=2)
        with chromium(tmp_path, MULTI_TAB_FLAGS) as browser:
            # one tab at a time until each is up (software WebGL on a loaded 2-core machine)
            pa = open_viewer(browser, server, 480, 320)
            ida = next(iter(server.get_clients()))
            pa.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=60000, state="attached")
            pb, idb = _open_tab(browser, server, 480, 320, {ida})
            pb.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=60000, state="attached")
            sa, sb = viewer.session_of(ida), viewer.session_of(idb)
            cam_b0 = np.array(server.get_clients()[idb].camera.position)
            # tab A: type a height (an edit: A's header says so), then choose T4-3
            box = pa.get_by_label("height (m, ellipsoidal)")
            box.fill("12000")
            box.press("Enter")
            wait_for(lambda: abs(sa.inputs.h_m - 12000.0) < 1e-6, 60, "A's height to reach A's session")
            pa.wait_for_selector("text=custom pose (edited from frame 0 (T3-1))", timeout=60000, state="attached")
            sa.dd_record.value = sa.record_option("T4-3")  # as A's dropdown would (a Mantine select is slow to drive)
            pa.wait_for_selector("text=qiao2017_flight_tests.csv: frame 12 (T4-3)", timeout=60000, state="attached")
            # A's browser reports the camera that frames T4-3's aircraft and target
            ca = server.get_clients()[ida].camera
            want = sa.view.camera_pose("overview")[0]
            wait_for(
                lambda: np.linalg.norm(np.array(ca.position) - want) < 0.05,
                20,
                "A's browser camera to move to T4-3's overview",
            )  # 50 m of km-unit scene
            pa.screenshot(path=str(ARTIFACTS / "viz_tab_a_T4-3.png"))
            # tab B: header, inputs, camera unchanged
            assert pb.locator("text=qiao2017_flight_tests.csv: frame 0 (T3-1)").count() >= 1
            assert pb.locator("text=qiao2017_flight_tests.csv: frame 12 (T4-3)").count() == 0
            assert pb.locator("text=custom pose (edited from").count() == 0
            assert pb.get_by_label("height (m, ellipsoidal)").input_value() != "12000"
            np.testing.assert_allclose(server.get_clients()[idb].camera.position, cam_b0, atol=1e-6)
            assert sb.scn.name.endswith("T3-1")
            pb.screenshot(path=str(ARTIFACTS / "viz_tab_b_T3-1.png"))
            # a third tab, over the cap: told the limit and how to raise it
            pc = browser.new_page(viewport={"width": 480, "height": 320})
            pc.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=40000)
            pc.wait_for_selector("text=too many browser tabs", timeout=60000, state="attached")
            assert pc.locator("text=--max-clients 4").count() >= 1
            pc.screenshot(path=str(ARTIFACTS / "viz_client_cap.png"))
            assert len(viewer.sessions) == 2 and len(viewer.refused) == 1


def test_presenter_mode_in_chromium(tmp_path):
    # presenter mode: the second tab follows the first: its controls are disabled, its panel
    # and camera follow the driver's (judged on the follower's page and its browser's camera)
    from geoloc_viz.app import GeolocViewer
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        viewer = GeolocViewer(server, load_view_scenario(), presenter=True)
        with chromium(tmp_path, MULTI_TAB_FLAGS) as browser:
            pa = open_viewer(browser, server, 480, 320)
            ida = next(iter(server.get_clients()))
            pa.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=60000, state="attached")
            pb, idb = _open_tab(browser, server, 480, 320, {ida})
            pb.wait_for_selector("text=take control", timeout=60000, state="attached")
            assert viewer.driver.client.client_id == ida and idb in viewer.followers
            follower_box = pb.get_by_label("height (m, ellipsoidal)")
            assert follower_box.is_disabled()
            # the driver types a height: the follower's read-only box and panel show it
            box = pa.get_by_label("height (m, ellipsoidal)")
            assert box.is_enabled()
            box.fill("12000")
            box.press("Enter")
            wait_for(
                lambda: follower_box.input_value().replace(",", "") in ("12000", "12000.0", "12000.00"),
                60,
                "the follower's box to show the driver's height",
            )
            pb.wait_for_selector("text=custom pose (edited from frame 0 (T3-1))", timeout=60000, state="attached")
            # the driver's view button moves its camera; the follower's browser follows
            viewer.driver.move_camera("target")
            want = viewer.driver.view.camera_pose("target")[0]
            cb = server.get_clients()[idb].camera
            wait_for(
                lambda: np.linalg.norm(np.array(cb.position) - want) < 0.05,
                20,
                "the follower's browser camera to follow the driver's",
            )
            # the follower sees every folder of the presenter's panel (flight, outliers,
            # accuracy, legend, teaching, ...), each with the presenter's text, read-only
            from geoloc_viz.app import driver_folders

            folders = [label for label, _ in driver_folders(viewer.driver)]
            assert {"Flight", "Flight: accuracy", "Legend"} <= set(folders), folders
            for label in folders:
                wait_for(lambda: pb.get_by_text(label, exact=True).count() >= 1, 60, f"the follower's folder {label!r}")
            panel = viewer.followers[idb]
            for src, dst in panel.mirrors:
                assert dst.content == src.content
            pb.screenshot(path=str(ARTIFACTS / "viz_presenter_follower.png"))


def test_presenter_switches_scenario_in_chromium(tmp_path):
    # the presenter chooses another scenario in their "scenario" dropdown, as a
    # person does (click the box, click the option); the follower's page shows the new scenario's
    # header and folders and its own read-only box showing the presenter's choice
    from geoloc_viz.app import GeolocViewer
    from geoloc_viz.flight_model import default_flight_scenario
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        q17 = load_view_scenario()
        viewer = GeolocViewer(
            server, q17, presenter=True, scenarios={"[Q17] flight test": q17, "example flight": default_flight_scenario}
        )
        with chromium(tmp_path, MULTI_TAB_FLAGS) as browser:
            pa = open_viewer(browser, server, 800, 600)
            ida = next(iter(server.get_clients()))
            pa.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=120000, state="attached")
            pb, idb = _open_tab(browser, server, 800, 600, {ida})
            pb.wait_for_selector("text=take control", timeout=120000, state="attached")
            wait_for(lambda: idb in viewer.followers, 60, "the follower's panel")
            assert pb.get_by_label("scenario").is_disabled()  # the follower's box is read-only
            box = pa.get_by_label("scenario")
            assert box.is_enabled()
            box.click(timeout=120000)
            pa.get_by_role("option", name="example flight").click(timeout=120000)
            wait_for(
                lambda: viewer.driver is not None and viewer.driver.scn.name.startswith("example_flight.klv"),
                300,
                "the presented scenario to switch",
            )
            assert viewer.driver.client.client_id == ida
            # the follower's page: the new header, the flight folders, its box on the presenter's choice
            pb.wait_for_selector("text=example_flight.klv", timeout=120000, state="attached")
            pb.wait_for_selector("text=Flight: outliers first", timeout=120000, state="attached")
            wait_for(
                lambda: pb.get_by_label("scenario").input_value() == "example flight",
                120,
                "the follower's scenario box",
            )
            assert pb.get_by_label("scenario").is_disabled()
            pb.screenshot(path=str(ARTIFACTS / "viz_presenter_switched_follower.png"))


def test_a_tab_says_it_is_loading_until_its_scene_is_built(tmp_path):
    """A tab's session takes seconds to build (more while another tab's holds the lock): the page
    says so from the tab's first message, and the note goes once the scene and the panel are there.
    The build is held back here (a session class that waits), so the note is seen for certain."""
    import threading

    from geoloc_viz.app import GeolocSession, GeolocViewer
    from geoloc_viz.scenario import load_view_scenario

    release = threading.Event()

    class HeldBack(GeolocSession):
        def __init__(self, *a, **kw):
            release.wait(180)
            super().__init__(*a, **kw)

    with served() as server:
        viewer = GeolocViewer(server, load_view_scenario())
        viewer.session_factory = HeldBack
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 900, 600)
            page.wait_for_selector("text=Loading the scene", timeout=60000)
            release.set()
            page.wait_for_selector("text=qiao2017_flight_tests.csv: frame 0 (T3-1)", timeout=120000, state="attached")
            page.wait_for_selector("text=Loading the scene", timeout=60000, state="detached")
