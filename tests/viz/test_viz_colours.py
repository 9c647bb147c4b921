"""One colour per meaning in the scene, each named once in the Legend.

The bundled example flight with its video, the flight, picture, uncertainty and refraction layers,
a pixel picked in the picture and a terrain point picked on the ground (a ray from the camera, as a
click on the canvas sends): every node's colours are read back from the scene (what the browser is
sent), grouped by what they mean. Two meanings may not share a colour: their CIE 1976 L*a*b*
difference (sRGB D65 -> XYZ -> L*a*b*, CIE 15:2004; computed here, not by the viewer) must be 10 or
more. A difference of 2.3 is just noticeable for two large patches side by side; thin lines and
small balls far apart on a hillshade need several times that, so under 10 they count as one colour.
Before the picked terrain point had its own colour it was drawn (255, 140, 0), orange like the
footprints, and the bent ray of refraction was the picked pixel's lime (difference 0).
"""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest

from test_viz_browser import served


def lab(rgb) -> np.ndarray:
    """CIE L*a*b* (D65) of an sRGB colour 0..255 (IEC 61966-2-1 transfer, CIE 15:2004)."""
    c = np.asarray(rgb, float) / 255.0
    c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    x, y, z = M @ c / np.array([0.95047, 1.0, 1.08883])

    def f(t):
        return np.cbrt(t) if t > (6 / 29) ** 3 else t / (3 * (6 / 29) ** 2) + 4 / 29

    return np.array([116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))])


def node_colours(scene, name) -> set:
    """The RGB colours a scene node is drawn with (a line's per-vertex colours, a ball's colour)."""
    h = scene.get_handle_by_name(name)
    assert h is not None, f"scene node {name} missing"
    if hasattr(h, "colors"):
        return {tuple(int(v) for v in c) for c in np.asarray(h.colors).reshape(-1, 3)}
    return {tuple(int(v) for v in h.color)}


@pytest.fixture(scope="module")
def drawn():
    """(meaning -> colours read from the scene, the Legend folder's text, the Picture folder's)."""
    import copy

    from geoloc_viz import flight_layer, image_layer, refraction_layer, uncertainty_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.flight_model import default_flight_scenario
    from geoloc_viz.scene_geoloc import WORLD_SCALE

    attach = (flight_layer.attach, image_layer.attach, uncertainty_layer.attach, refraction_layer.attach)
    with served() as server:
        app = GeolocApp(server, copy.copy(default_flight_scenario()), layers=attach)
        fl, il, _, rl = app.layers
        fl.go(100, camera=False)  # a frame of the heading-bias run: outliers in the footprints
        rl.set_refraction("standard")
        il.pick_pixel(150.0, 333.0)
        # a click on the terrain: the browser's ray from the camera through a pixel near the centre
        s = app
        cam = s.scn.enu.from_ecef(il.sensor.optical_centre_ecef(s.inputs.pose()))
        los = il.sensor.line_of_sight(170.0, 300.0, s.inputs.pose())
        d = s.scn.enu.vector_from_ecef(np.asarray(los.direction_ecef))
        k = WORLD_SCALE * np.array([1.0, 1.0, s.view.disp.vertical_exaggeration])
        gp = il.pick_ground(cam * k, d * k)
        assert gp is not None and gp.ok and gp.visible
        sc = server.scene
        c = lambda n: node_colours(sc, n)  # noqa: E731
        iters = c("/enu/iterations/verticals")
        runs = c("/flight/runs")
        meanings = {
            "line of sight": c("/enu/los"),
            "this frame's footprint (corner rays)": c("/enu/frustum"),
            "the method's answer (recomputed point)": c("/enu/hit/result") | c("/flight/focus/recomputed"),
            "the exact first hit": c("/enu/hit/exact"),
            "the ellipsoid hit at H_max": c("/enu/hit/hmax"),
            "the reported point": c("/flight/focus/reference"),
            "the current error vector": c("/flight/focus/error"),
            "every frame's error vector": c("/flight/errors"),
            "the track": c("/flight/track"),
            "footprints": c("/flight/footprints") - runs,
            "flagged: outlier footprints and runs": runs,
            "the current footprint": c("/flight/current"),
            "the picked pixel": c("/enu/picture/ray") | c("/enu/picture/hit"),
            "the picked terrain point": c("/enu/picture/ground"),
            "the 90 % ellipse": c("/enu/uncertainty/ellipse"),
            "the bent ray (refraction)": c("/enu/refraction/bent"),
            "bisection brackets": c("/enu/iterations/brackets"),
            "iterations (above / below the terrain)": iters,
        }
        legend = app.md_legend.content
        picture = il.md_legend.content
    return meanings, legend, picture


def test_no_two_meanings_share_a_colour(drawn):
    meanings, _, _ = drawn
    for m, cols in meanings.items():
        assert cols, f"{m}: nothing drawn"
    # the footprints' outliers: one red for every flagged footprint and run
    assert len(meanings["flagged: outlier footprints and runs"]) == 1
    shared = []
    for (a, ca), (b, cb) in itertools.combinations(meanings.items(), 2):
        for x in ca:
            for y in cb:
                d = float(np.linalg.norm(lab(x) - lab(y)))
                if d < 10.0:
                    shared.append(f"{a} {x} ~ {b} {y}: delta E {d:.1f}")
    assert not shared, "\n".join(shared)


def test_the_legend_names_each_new_colour_once_with_its_meaning(drawn):
    meanings, legend, picture = drawn
    assert meanings["the picked terrain point"] == {(90, 30, 255)}  # indigo, shown in the legend as such
    assert meanings["the bent ray (refraction)"] == {(0, 255, 160)}  # spring green
    for text in (legend, picture):
        assert len(re.findall(r"\*\*indigo\*\*", text)) == 1 and "picked terrain point" in text
        assert "**orange** o" not in text  # the terrain point is no longer the footprints' orange
    assert len(re.findall(r"\*\*spring green\*\*", legend)) == 1
    assert re.search(r"\*\*spring green\*\* line \(with refraction on", legend)
    assert re.search(r"\*\*indigo\*\* a picked terrain point", legend)
