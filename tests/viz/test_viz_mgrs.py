"""MGRS (and USNG) beside latitude and longitude in the viewer's panels.

The panel's text is read (in a session, and in headless Chromium as a person reads it) and
its MGRS reference checked against the ``mgrs`` package (NGA's GEOTRANS code) for the panel's
own latitude and longitude, and against pyproj's UTM: the reference's 1 m square, truncated as
NGA.STND.0037 says, holds the point.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_viz_browser import served

MGRS_RE = re.compile(r"MGRS (\d{1,2}[C-X][A-Z]{2}\d{10}) \(USNG (\d{1,2}[C-X]) ([A-Z]{2}) (\d{5}) (\d{5})\)")
HIT_RE = re.compile(r"\*\*[^*]+\*\*: ([-0-9.]+) N, ([-0-9.]+) E")


def _check_reference(text, lat_deg, lon_deg, exact=True):
    """The MGRS/USNG of ``text`` against the mgrs package and pyproj's UTM for (lat, lon).

    ``exact``: (lat, lon) is the point itself, so the reference is the mgrs package's to the
    letter and its digits pyproj's easting and northing mod 100 km truncated to the metre.
    Otherwise (lat, lon) is the panel's printed position, rounded to 1e-6 deg (0.11 m north,
    0.09 m east here), which may sit across a 1 m square's edge from the point: the digits
    are then within 1 m + 0.2 m of pyproj's."""
    import mgrs
    from pyproj import Transformer

    m = MGRS_RE.search(text)
    assert m, text
    ref, zone, square, e5, n5 = m.groups()
    assert ref == f"{zone}{square}{e5}{n5}"  # USNG: the same reference in groups
    if exact:
        assert ref == mgrs.MGRS().toMGRS(lat_deg, lon_deg, MGRSPrecision=5)
    else:
        assert ref[:5] == mgrs.MGRS().toMGRS(lat_deg, lon_deg, MGRSPrecision=5)[:5]
    # pyproj's UTM of the point (the zone from the reference; Norway/Svalbard do not reach here)
    z = int(zone[:-1])
    epsg = (32600 if lat_deg >= 0 else 32700) + z
    e, n = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(lon_deg, lat_deg)
    if exact:
        assert int(e5) == int(np.floor(e)) % 100000 and int(n5) == int(np.floor(n)) % 100000
    else:
        assert abs(int(e5) + 0.5 - e % 100000) <= 0.5 + 0.2 and abs(int(n5) + 0.5 - n % 100000) <= 0.5 + 0.2


def test_summary_panel_shows_mgrs_of_its_hit():
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        text = app.md_summary.content
        hit = HIT_RE.search(text)
        assert hit, text
        lat, lon = float(hit.group(1)), float(hit.group(2))
        _check_reference(text, lat, lon, exact=False)  # the panel's own printed position
        g = float(app.geometry.hit.lat_deg), float(app.geometry.hit.lon_deg)
        assert abs(g[0] - lat) < 5e-7 and abs(g[1] - lon) < 5e-7
        _check_reference(text, *g)  # the hit itself: to the letter


def test_pick_panels_show_mgrs():
    from geoloc.io.mgrs_grid import mgrs_text
    from geoloc_viz import picture_model as pm

    # a point with no position (NaN) has no reference and says so instead of a made-up square
    assert mgrs_text(float("nan"), 0.0).startswith("MGRS: none (")
    text = mgrs_text(36.6, -84.2)
    _check_reference(text, 36.6, -84.2)
    # the pixel-pick panel: tests/viz/test_viz_picture.py::test_pixel_pick_equals_geoloc_locate reads it
    assert "mgrs_text" in pm.pick_markdown.__code__.co_names and "mgrs_text" in pm.ground_markdown.__code__.co_names


@pytest.mark.browser
def test_mgrs_in_the_panel_in_chromium(tmp_path):
    from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

    from geoloc_viz.app import GeolocApp
    from geoloc_viz.scenario import load_view_scenario

    with served() as server:
        app = GeolocApp(server, load_view_scenario())
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 800, 520)
            page.wait_for_selector("text=USNG", timeout=60000)
            mg = page.locator("text=MGRS").first.inner_text()
            # the position the same panel prints, read from the page too
            body = page.locator("body").inner_text()
            hit = re.search(r": ([-0-9.]+) N, ([-0-9.]+) E, h", body)
            assert hit, body[:2000]
            _check_reference(mg, float(hit.group(1)), float(hit.group(2)), exact=False)
            _check_reference(mg, float(app.geometry.hit.lat_deg), float(app.geometry.hit.lon_deg))
            # a new aircraft height typed in: the panel's reference follows the new hit
            box = page.get_by_label("height (m, ellipsoidal)")
            box.fill("12000")
            box.press("Enter")
            wait_for(lambda: abs(app.inputs.h_m - 12000.0) < 1e-6, 30, "the height to reach the server")
            wait_for(lambda: page.locator("text=MGRS").first.inner_text() != mg, 30, "the panel to update")
            body = page.locator("body").inner_text()
            hit = re.search(r": ([-0-9.]+) N, ([-0-9.]+) E, h", body)
            mg2 = page.locator("text=MGRS").first.inner_text()
            _check_reference(mg2, float(hit.group(1)), float(hit.group(2)), exact=False)
            _check_reference(mg2, float(app.geometry.hit.lat_deg), float(app.geometry.hit.lon_deg))
            page.locator("text=MGRS").first.scroll_into_view_if_needed()
            page.screenshot(path=str(ARTIFACTS / "viz_mgrs_panel.png"))
