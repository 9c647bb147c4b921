"""The Sentinel-2 scene in headless Chromium, as a person opens it and drags the line slider.

`geoloc view --scenario PRODUCT` serves one :class:`Sentinel2App` per tab (:class:`Sentinel2Viewer`).
The tab opens on the middle line of detector 06; the page's canvas is screenshotted
(``test-artifacts/s2_view_*.png``) and its pixels counted by colour: the yellow lines of sight,
the magenta footprint of the detector shown and the light blue one of the other, and the Earth's
blue. Then the line is moved to the first line (as the slider does, from Python) and the view
must change where the lines of sight are.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np

from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

W, H = 900, 560
PRODUCT = Path(__file__).parents[1] / "data" / "sentinel2" / "L1B"
#: the canvas left of the GUI panel and below the browser's "Software WebGL" notice: the 3D scene
SCENE_COLS, SCENE_ROWS = slice(0, 490), slice(160, None)


def colour_mask(rgb, target, tol=60) -> np.ndarray:
    """Pixels within ``tol`` (per channel) of a drawn colour (the lines are unlit: their own colour)."""
    return np.all(np.abs(rgb.astype(int) - np.asarray(target)) < tol, axis=-1)


def shot(page, name):
    import PIL.Image

    png = page.locator("canvas").first.screenshot(timeout=60000)
    (ARTIFACTS / f"s2_view_{name}.png").write_bytes(png)
    return np.asarray(PIL.Image.open(io.BytesIO(png)).convert("RGB"))[SCENE_ROWS, SCENE_COLS]


def settle(page, name, before=None, timeout=60.0):
    """Screenshot once two shots agree (and differ from ``before``)."""
    t0 = time.monotonic()
    prev = None
    while True:
        img = shot(page, name)
        if (
            prev is not None
            and np.abs(img.astype(int) - prev.astype(int)).mean() < 0.5
            and (before is None or np.abs(img.astype(int) - before.astype(int)).mean() > 0.2)
        ):
            return img
        if time.monotonic() - t0 > timeout:
            return img
        prev = img
        time.sleep(2.0)


def test_sentinel2_scene_shows_lines_of_sight_and_footprints(tmp_path):
    from geoloc_viz.scene_sentinel2 import (
        EARTH_COLOR,
        FOOTPRINT_COLOR,
        LOS_COLOR,
        OTHER_FOOTPRINT_COLOR,
        SWATH_COLOR,
        Sentinel2Viewer,
        load,
    )

    with served() as server:
        viewer = Sentinel2Viewer(server, load(PRODUCT))
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, W, H)
            page.wait_for_selector("canvas", timeout=40000)
            cid = next(iter(server.get_clients()))
            wait_for(lambda: cid in viewer.apps, 90, "the tab's Sentinel-2 scene")
            app = viewer.apps[cid]
            img = settle(page, "middle_line")
            counts = {
                "los": int(colour_mask(img, LOS_COLOR).sum()),
                "footprint": int(colour_mask(img, FOOTPRINT_COLOR).sum()),
                "other_footprint": int(colour_mask(img, OTHER_FOOTPRINT_COLOR, 40).sum()),
                "earth": float(colour_mask(img, EARTH_COLOR, 40).mean()),
            }
            print(counts)
            # measured: 65 yellow, 181 magenta, 32 light blue pixels, Earth 22 % of the view (at a
            # slightly closer camera); the bounds are about half of each: the satellite 790 km above
            # a detector's 25 km wide footprint makes thin lines and small outlines, a person zooms in
            assert counts["los"] > 30, counts
            assert counts["footprint"] > 80, counts
            assert counts["other_footprint"] > 12, counts
            assert 0.05 < counts["earth"] < 0.9, counts
            swath_before = np.argwhere(colour_mask(img, SWATH_COLOR, 40)).mean(axis=0)
            app.sl_line.value = 1
            wait_for(lambda: app.row == 1.0, 20, "line 1 on the server")
            img2 = settle(page, "first_line", before=img)
            assert colour_mask(img2, LOS_COLOR).sum() > 30
            # the line's ground (orange) went from the footprint's middle to its near end, towards
            # the camera (behind the satellite along the track): lower on the screen
            swath_after = np.argwhere(colour_mask(img2, SWATH_COLOR, 40)).mean(axis=0)
            print("swath centroid (row, col)", swath_before, swath_after)
            assert swath_after[0] - swath_before[0] > 8
