"""One colour per meaning in the scene, each named once in the Legend.

The bundled example flight with its video, the flight, picture, uncertainty and refraction layers,
a pixel picked in the picture and a terrain point picked on the ground (a ray from the camera, as a
click on the canvas sends): every node's colours are read back from the scene (what the browser is
sent), grouped by what they mean. Two meanings may not share a colour: their CIEDE2000 colour
difference (sRGB D65 -> XYZ -> L*a*b*, CIE 15:2004; CIEDE2000 as Sharma, Wu and Dalal 2005 give it,
checked here against their published test pairs; computed here, not by the viewer) must be 10 or
more. A difference of about 1 is just noticeable for two large patches side by side; thin lines and
small balls far apart on a hillshade need several times that, so under 10 they count as one colour.
CIEDE2000, not the CIE 1976 distance: the 1976 one overstates differences among blues (the old
track's sky blue and the H_max hit's azure were 20.7 apart in 1976 units, 9.6 in CIEDE2000, and
looked one colour). Before the picked terrain point had its own colour it was drawn (255, 140, 0),
orange like the footprints, and the bent ray of refraction was the picked pixel's lime (difference 0).

Each meaning is drawn in its colour of the viewer's one colour table (:mod:`geoloc_viz.palette`),
and the Legend names it by that table's word: read from the GUI's markdown in-process, and once from
the page in Chromium as a person reads it.
"""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest

from test_viz_browser import ARTIFACTS, chromium, close_software_webgl_notice, open_viewer, served


def lab(rgb) -> np.ndarray:
    """CIE L*a*b* (D65) of an sRGB colour 0..255 (IEC 61966-2-1 transfer, CIE 15:2004)."""
    c = np.asarray(rgb, float) / 255.0
    c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    x, y, z = M @ c / np.array([0.95047, 1.0, 1.08883])

    def f(t):
        return np.cbrt(t) if t > (6 / 29) ** 3 else t / (3 * (6 / 29) ** 2) + 4 / 29

    return np.array([116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))])


def ciede2000(lab1, lab2) -> float:
    """CIEDE2000 colour difference of two CIE L*a*b* colours (kL = kC = kH = 1), as Sharma, Wu and
    Dalal, Color Res. Appl. 30 (2005) 21-30, eqs. 1-22 give it."""
    L1, a1, b1 = (float(v) for v in lab1)
    L2, a2, b2 = (float(v) for v in lab2)
    cb = (math.hypot(a1, b1) + math.hypot(a2, b2)) / 2
    g = 0.5 * (1 - math.sqrt(cb**7 / (cb**7 + 25.0**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1, c2 = math.hypot(a1p, b1), math.hypot(a2p, b2)

    def hue(b, a):
        return 0.0 if a == 0 and b == 0 else math.degrees(math.atan2(b, a)) % 360

    h1, h2 = hue(b1, a1p), hue(b2, a2p)
    dh = 0.0 if c1 * c2 == 0 else (h2 - h1 + 180) % 360 - 180
    dH = 2 * math.sqrt(c1 * c2) * math.sin(math.radians(dh / 2))
    lm, cm = (L1 + L2) / 2, (c1 + c2) / 2
    if c1 * c2 == 0:
        hm = h1 + h2
    elif abs(h1 - h2) <= 180:
        hm = (h1 + h2) / 2
    else:
        hm = (h1 + h2 + 360) / 2 if h1 + h2 < 360 else (h1 + h2 - 360) / 2
    r = math.radians
    t = 1 - 0.17 * math.cos(r(hm - 30)) + 0.24 * math.cos(r(2 * hm)) + 0.32 * math.cos(r(3 * hm + 6))
    t -= 0.20 * math.cos(r(4 * hm - 63))
    sl = 1 + 0.015 * (lm - 50) ** 2 / math.sqrt(20 + (lm - 50) ** 2)
    sc, sh = 1 + 0.045 * cm, 1 + 0.015 * cm * t
    rt = -math.sin(r(60 * math.exp(-(((hm - 275) / 25) ** 2)))) * 2 * math.sqrt(cm**7 / (cm**7 + 25.0**7))
    x, y, z = (L2 - L1) / sl, (c2 - c1) / sc, dH / sh
    return math.sqrt(x * x + y * y + z * z + rt * y * z)


def delta_e(rgb1, rgb2) -> float:
    """CIEDE2000 difference of two sRGB colours 0..255."""
    return ciede2000(lab(rgb1), lab(rgb2))


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
        # meaning -> (its keys in the colour table, the colours read from the scene)
        meanings = {
            "line of sight": (("los",), c("/enu/los")),
            "this frame's footprint (corner rays)": (("frustum",), c("/enu/frustum")),
            "the method's answer (recomputed point)": (
                ("result",),
                c("/enu/hit/result") | c("/flight/focus/recomputed"),
            ),
            "the exact first hit": (("exact",), c("/enu/hit/exact")),
            "the ellipsoid hit at H_max": (("hmax",), c("/enu/hit/hmax")),
            "the reported point": (("published",), c("/flight/focus/reference")),
            "the current error vector": (("error",), c("/flight/focus/error")),
            "every frame's error vector": (("errors",), c("/flight/errors")),
            "the track": (("track",), c("/flight/track")),
            "footprints": (("footprint",), c("/flight/footprints") - runs),
            "flagged: outlier footprints and runs": (("footprint_outlier",), runs),
            "the current footprint": (("current",), c("/flight/current")),
            "every frame's centre": (("centre",), c("/flight/centres")),
            "the picked pixel": (("pick",), c("/enu/picture/ray") | c("/enu/picture/hit")),
            "the picked terrain point": (("ground",), c("/enu/picture/ground")),
            "the 90 % ellipse": (("ellipse",), c("/enu/uncertainty/ellipse")),
            "the bent ray (refraction)": (("bent",), c("/enu/refraction/bent")),
            "bisection brackets": (("bracket",), c("/enu/iterations/brackets")),
            "iterations (above / below the terrain)": (("above", "below"), iters),
        }
        legend = app.md_legend.content
        picture = il.md_legend.content
    return meanings, legend, picture


# Sharma, Wu and Dalal (2005), Table 1: pairs (L*, a*, b*) and their CIEDE2000 difference, to the
# table's 4 decimals (pairs 1, 2, 7, 13, 17-19, 25 and 34: hue wrap, neutral, large and small differences)
SHARMA_PAIRS = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.49, -0.001), (50.0, -2.49, 0.0009), 7.1792),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((50.0, 2.5, 0.0), (61.0, -5.0, 29.0), 22.8977),
    ((50.0, 2.5, 0.0), (56.0, -27.0, -3.0), 31.9030),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
    ((2.0776, 0.0795, -1.1350), (0.9033, -0.0636, -0.5514), 0.9082),
]


@pytest.mark.parametrize("lab1, lab2, want", SHARMA_PAIRS)
def test_ciede2000_matches_the_published_test_pairs(lab1, lab2, want):
    assert abs(ciede2000(lab1, lab2) - want) < 5e-5  # the table's 4 decimals
    assert abs(ciede2000(lab2, lab1) - want) < 5e-5  # symmetric


def test_the_old_track_and_hmax_blues_count_as_one_colour():
    # the palette before: the track (90, 200, 255) and the H_max hit (0, 170, 255), 20.7 apart in CIE 1976
    # units (the test's former measure passed them) but 9.6 in CIEDE2000: under 10, this test's bound
    assert delta_e((90, 200, 255), (0, 170, 255)) < 10.0
    assert float(np.linalg.norm(lab((90, 200, 255)) - lab((0, 170, 255)))) > 10.0


def test_no_two_meanings_share_a_colour(drawn):
    meanings, _, _ = drawn
    for m, (_, cols) in meanings.items():
        assert cols, f"{m}: nothing drawn"
    # the footprints' outliers: one red for every flagged footprint and run
    assert len(meanings["flagged: outlier footprints and runs"][1]) == 1
    shared = []
    for (a, (_, ca)), (b, (_, cb)) in itertools.combinations(meanings.items(), 2):
        for x in ca:
            for y in cb:
                d = delta_e(x, y)
                if d < 10.0:
                    shared.append(f"{a} {x} ~ {b} {y}: CIEDE2000 {d:.1f}")
    assert not shared, "\n".join(shared)


def test_no_two_colours_of_the_table_look_alike():
    # what the scene does not draw in this fixture too (the triangulation's residuals, a hidden terrain pick)
    from geoloc_viz.palette import PALETTE

    close = [
        f"{a} {ca.rgb} ~ {b} {cb.rgb}: {delta_e(ca.rgb, cb.rgb):.1f}"
        for (a, ca), (b, cb) in itertools.combinations(PALETTE.items(), 2)
        if {a, b} != {"ground", "ground_hidden"} and delta_e(ca.rgb, cb.rgb) < 10.0  # one meaning, dimmed
    ]
    assert not close, close


def test_each_meaning_is_drawn_in_its_table_colour(drawn):
    from geoloc_viz.palette import PALETTE

    meanings, _, _ = drawn
    for m, (keys, cols) in meanings.items():
        assert cols == {PALETTE[k].rgb for k in keys}, (m, cols)
    # the old track / H_max pair is gone from the scene
    assert meanings["the ellipsoid hit at H_max"][1] != {(0, 170, 255)}


def _bold_words(text: str) -> list:
    return re.findall(r"\*\*([^*]+)\*\*", text)


def test_the_legend_names_what_is_drawn_by_the_tables_words(drawn):
    from geoloc_viz.palette import PALETTE

    meanings, legend, picture = drawn
    names = {c.name for c in PALETTE.values()}
    # every bold word of the two legends is a colour of the table (no colour word written by hand)
    for text in (legend, picture):
        words = _bold_words(text)
        assert words and set(words) <= names, set(words) - names
    # every meaning drawn is named in the Legend folder by its colour's word
    for m, (keys, _) in meanings.items():
        for k in keys:
            assert f"**{PALETTE[k].name}**" in legend, (m, k)
    assert re.search(r"\*\*light grey\*\*: the ellipsoid hit at H_max", legend)
    assert re.search(r"\*\*sky blue\*\* track", legend)


def test_the_legend_names_each_new_colour_once_with_its_meaning(drawn):
    meanings, legend, picture = drawn
    assert meanings["the picked terrain point"][1] == {(90, 30, 255)}  # indigo, shown in the legend as such
    assert meanings["the bent ray (refraction)"][1] == {(0, 255, 160)}  # spring green
    for text in (legend, picture):
        assert len(re.findall(r"\*\*indigo\*\*", text)) == 1 and "picked terrain point" in text
        assert "**orange** o" not in text  # the terrain point is no longer the footprints' orange
    assert len(re.findall(r"\*\*spring green\*\*", legend)) == 1
    assert re.search(r"\*\*spring green\*\* line \(with refraction on", legend)
    assert re.search(r"\*\*indigo\*\* a picked terrain point", legend)


def test_the_docs_colour_table_is_the_palettes():
    from pathlib import Path

    from geoloc_viz.palette import colour_table_markdown

    doc = (Path(__file__).resolve().parents[2] / "docs" / "viz.md").read_text()
    assert colour_table_markdown() in doc, "docs/viz.md: regenerate with python -m geoloc_viz.palette"


@pytest.mark.browser
def test_the_legend_on_the_page_names_the_drawn_colours_in_chromium(tmp_path):
    """As a person reads it: the Legend folder opened with a click, its bold colour words (rendered
    ``<strong>``) are the table's names of what the flight scene draws, each once per meaning line."""
    import copy

    from geoloc_viz import flight_layer, image_layer
    from geoloc_viz.app import GeolocApp
    from geoloc_viz.flight_model import default_flight_scenario
    from geoloc_viz.palette import PALETTE

    with served() as server:
        GeolocApp(server, copy.copy(default_flight_scenario()), layers=(flight_layer.attach, image_layer.attach))
        sc = server.scene
        drawn = {k: node_colours(sc, n) for k, n in (("track", "/flight/track"), ("hmax", "/enu/hit/hmax"))}
        drawn["result"] = node_colours(sc, "/enu/hit/result")
        drawn["current"] = node_colours(sc, "/flight/current")
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 1100, 900)
            close_software_webgl_notice(page)
            page.get_by_text("Legend", exact=True).first.click(timeout=60000)
            line = page.get_by_text("the ellipsoid hit at H_max", exact=False).first
            line.wait_for(timeout=60000)
            # the Legend's markdown, as rendered: its list items and their bold words
            items = page.locator("li", has_text="the ellipsoid hit at H_max").first.locator("xpath=..")
            words = items.locator("strong").all_inner_texts()
            text = items.inner_text()
            items.evaluate("e => e.scrollIntoView({block: 'start'})")  # the legend at the panel's top
            page.screenshot(path=str(ARTIFACTS / "viz_legend.png"), timeout=120000)
    names = {c.name for c in PALETTE.values()}
    assert words and set(words) <= names, set(words) - names
    for key, cols in drawn.items():  # what the page's words name is what the scene drew
        assert cols == {PALETTE[key].rgb} and PALETTE[key].name in words, (key, cols)
    assert "light grey: the ellipsoid hit at H_max" in text and "sky blue track" in text, text
    assert "light blue" not in text


# the viewer's other scenes and the rerun recordings: their colours come from the palette's tables
OTHER_MODULES = ("rerun_style", "scene_limb", "scene_sentinel2", "teaching_panel")


@pytest.mark.parametrize("module", OTHER_MODULES)
def test_no_colour_is_written_outside_the_palette(module):
    # an sRGB triple written in the module's source (a colour given by hand, not by the table)
    from pathlib import Path

    import geoloc_viz

    src = (Path(geoloc_viz.__file__).parent / f"{module}.py").read_text()
    triples = re.findall(r"\(\s*\d{1,3}\s*,\s*\d{1,3}\s*,\s*\d{1,3}\s*(?:,\s*\d{1,3}\s*)?\)", src)
    assert not triples, f"geoloc_viz/{module}.py: {triples}: give them a meaning in geoloc_viz.palette"


def _limb_ramp(n: int) -> set:
    """The Newton-Raphson iterates' colours as scene_limb draws n of them (g, g, 255 - g // 2)."""
    from geoloc_viz.palette import LIMB

    g0, g1 = LIMB["nr_first"].rgb[0], LIMB["nr_last"].rgb[0]
    return {(g, g, 255 - g // 2) for g in (int(g0 + (g1 - g0) * k / max(n - 1, 1)) for k in range(n))}


@pytest.mark.parametrize("table", ["flight", "limb", "sentinel2", "teaching", "rerun"])
def test_no_two_meanings_of_one_table_look_alike(table):
    # one table's colours can be on screen together (one scene, one recording); the scenes never are
    from geoloc_viz.palette import TABLES

    colours = TABLES[table][1]
    same = {frozenset({"ground", "ground_hidden"}), frozenset({"nr_first", "nr_last"})}  # one meaning each
    close = [
        f"{a} {ca.rgb} ~ {b} {cb.rgb}: {delta_e(ca.rgb, cb.rgb):.1f}"
        for (a, ca), (b, cb) in itertools.combinations(colours.items(), 2)
        if frozenset({a, b}) not in same and delta_e(ca.rgb, cb.rgb) < 10.0
    ]
    if table == "limb":  # every iterate of the ramp, for 2 to 12 iterates, against the other meanings
        for n in range(2, 13):
            for x in _limb_ramp(n):
                for k, c in colours.items():
                    if k not in ("nr_first", "nr_last") and delta_e(x, c.rgb) < 10.0:
                        close.append(f"iterate {x} ~ {k} {c.rgb}: {delta_e(x, c.rgb):.1f}")
    assert not close, close


def test_the_other_scenes_draw_their_tables_colours():
    from geoloc_viz import rerun_style, scene_limb, scene_sentinel2, teaching_panel
    from geoloc_viz.palette import FLIGHT_SERIES, LIMB, RERUN, SENTINEL2, TEACHING

    assert rerun_style.COLORS == {k: (*c.rgb, 255) for k, c in RERUN.items()}
    assert rerun_style.FLIGHT_COLORS == FLIGHT_SERIES
    assert scene_limb.REFRACTED_COLOR == LIMB["refracted"].rgb
    got = (scene_sentinel2.LOS_COLOR, scene_sentinel2.SWATH_COLOR, scene_sentinel2.FOOTPRINT_COLOR)
    assert got == tuple(SENTINEL2[k].rgb for k in ("los", "swath", "footprint"))
    assert scene_sentinel2.OTHER_FOOTPRINT_COLOR == SENTINEL2["other_footprint"].rgb
    assert scene_sentinel2.EARTH_COLOR == SENTINEL2["earth"].rgb
    assert teaching_panel.HIGHLIGHT == {"src": TEACHING["src"].rgb, "dst": TEACHING["dst"].rgb}
    assert teaching_panel.VECTOR_COLOR == TEACHING["vector"].rgb
    # the limb legend names what it draws by the table's words (each bold item starts with one)
    from types import SimpleNamespace

    from geoloc.status import Status

    for ok, lref, status in ((True, object(), Status.OK), (False, None, Status.HITS_EARTH)):
        me = SimpleNamespace(exaggeration=1.0, offset_exaggeration=1.0, lref=lref, tan=SimpleNamespace(status=status))
        items = _bold_words(scene_limb.LimbApp.legend_markdown(me, ok))  # type: ignore[arg-type]
        names = {c.name for c in LIMB.values()}
        assert items and all(any(w.startswith(nm) for nm in names) for w in items), items


def test_every_colour_name_names_one_colour_in_all_tables():
    from geoloc_viz.palette import TABLES

    by_name: dict = {}
    for _, table in TABLES.values():
        for c in table.values():
            by_name.setdefault(c.name, set()).add(c.rgb)
    assert all(len(v) == 1 for v in by_name.values()), {k: v for k, v in by_name.items() if len(v) > 1}


def test_the_docs_colour_tables_are_the_palettes():
    from pathlib import Path

    from geoloc_viz.palette import colour_tables_markdown

    doc = (Path(__file__).resolve().parents[2] / "docs" / "viz.md").read_text()
    assert colour_tables_markdown() in doc, "docs/viz.md: regenerate with python -m geoloc_viz.palette"
