"""The viewer's one colour table: each meaning drawn in the scene -> its colour's name and RGB.

Every layer draws with :data:`PALETTE` (``scene_geoloc``, ``flight_layer``, ``image_layer``,
``uncertainty_layer``, ``refraction_layer`` take their colours from it), and every colour word of
the Legend folder (:func:`geoloc_viz.app.legend_markdown`), the Picture folder's marks and the
colour table of ``docs/viz.md`` (:func:`colour_table_markdown`) is this table's name for it, so the
words a person reads are the colours drawn. One meaning, one colour; a name is never shared by two
colours. Two colours of different meanings differ by a CIEDE2000 colour difference of 10 or more
(checked in ``tests/viz/test_viz_colours.py`` on the scene as drawn).

RGB are 8-bit sRGB. The scene's lines and points are drawn unlit (the colour given is the colour
seen); balls are lit (their shaded side darker).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Colour:
    """One meaning's colour: the word the legend uses, its sRGB value, what it means, where it is drawn."""

    name: str
    rgb: tuple[int, int, int]
    meaning: str
    nodes: str


#: meaning key -> colour. The keys are those of the layers' ``COLORS`` dicts (kept for their callers).
PALETTE: dict[str, Colour] = {
    "los": Colour("yellow", (255, 210, 0), "line of sight (and one target's rays from several frames)", "`/enu/los`"),
    "los_beyond": Colour("dark yellow", (140, 120, 40), "the line of sight beyond the answer", "`/enu/los_beyond`"),
    # the ellipsoid hit at H_max was (0, 170, 255), the track's sky blue (90, 200, 255) beside it: CIEDE2000 8.4,
    # one colour to the eye; a light grey ball now
    "hmax": Colour(
        "light grey", (175, 175, 175), "the ellipsoid hit at H_max (where [Q17]'s steps start)", "`/enu/hit/hmax`"
    ),
    "result": Colour(
        "red",
        (255, 40, 40),
        "the chosen method's answer (the recomputed point)",
        "`/enu/hit/result`, `/flight/focus/recomputed`",
    ),
    "exact": Colour("green", (20, 220, 90), "the exact first hit", "`/enu/hit/exact`"),
    "published": Colour(
        "violet", (180, 80, 255), "the published or reported position", "`/enu/record/published`, `/flight/reported`"
    ),
    "surveyed": Colour(
        "white",
        (255, 255, 255),
        "the surveyed truth (and the picture's targets)",
        "`/enu/record/surveyed`, `/flight/truth`",
    ),
    "error": Colour(
        "bright pink", (255, 90, 200), "the current frame's error vector", "`/enu/record/error`, `/flight/focus/error`"
    ),
    "above": Colour("blue", (60, 140, 255), "an iteration above the terrain (H_n - h_n > 0)", "`/enu/iterations/*`"),
    "below": Colour(
        "orange-red", (255, 105, 45), "an iteration below the terrain (H_n - h_n < 0)", "`/enu/iterations/*`"
    ),
    "frustum": Colour("orange", (255, 170, 60), "this frame's footprint (corner rays)", "`/enu/frustum`"),
    "bracket": Colour(
        "cyan", (0, 230, 230), "bisection brackets (and the picture's terrain horizon)", "`/enu/iterations/brackets`"
    ),
    "track": Colour("sky blue", (90, 200, 255), "the flight's track", "`/flight/track`"),
    "footprint": Colour("ochre", (195, 150, 75), "every frame's footprint (a thinned trail)", "`/flight/footprints`"),
    "footprint_outlier": Colour(
        "dark red", (190, 0, 40), "flagged: the outliers' footprints and runs", "`/flight/footprints`, `/flight/runs`"
    ),
    "current": Colour("magenta", (255, 0, 255), "the current frame's footprint", "`/flight/current`"),
    "centre": Colour("pale yellow", (255, 240, 150), "every frame's centre", "`/flight/centres`"),
    "errors": Colour("mauve", (165, 95, 145), "every frame's error vector", "`/flight/errors`"),
    "pick": Colour(
        "lime", (170, 255, 0), "a picked pixel's ray and ground point", "`/enu/picture/ray`, `/enu/picture/hit`"
    ),
    "ground": Colour("indigo", (90, 30, 255), "a picked terrain point", "`/enu/picture/ground`"),
    "ground_hidden": Colour(
        "dim indigo", (60, 40, 140), "a picked terrain point hidden from the camera", "`/enu/picture/ground`"
    ),
    "ellipse": Colour(
        "teal",
        (0, 200, 170),
        "a predicted 90 % error ellipse",
        "`/enu/uncertainty/ellipse`, `/enu/picture/target/ellipse`",
    ),
    "bent": Colour("spring green", (0, 255, 160), "the bent ray (refraction on)", "`/enu/refraction/bent`"),
    "residual": Colour(
        "rose", (255, 45, 135), "a target ray's residual to the triangulated point", "`/enu/picture/target/residuals`"
    ),
}


#: The limb scene (``geoloc_viz.scene_limb``, ``geoloc view --limb``): meaning -> colour. Its legend
#: (:meth:`geoloc_viz.scene_limb.LimbApp.legend_markdown`) names each by this table's word.
LIMB: dict[str, Colour] = {
    "earth": Colour("dark blue", (40, 90, 170), "the Earth: WGS-84 ellipsoid, h = 0 (a patch)", "`/limb/earth`"),
    "earth_section": Colour(
        "light blue", (120, 170, 255), "the Earth's section under the line of sight", "`/limb/earth_section`"
    ),
    "virtual": Colour(
        "orange",
        (255, 170, 60),
        "the virtual ellipsoid of [L18] eq. 13 (translucent) and its section",
        "`/limb/virtual`, `/limb/virtual_section`",
    ),
    # the Newton-Raphson iterates are a ramp (g, g, 255 - g // 2), g from 80 to 230: first and last here
    "nr_first": Colour("slate blue", (80, 80, 215), "the first Newton-Raphson iterate of eq. 17", "`/limb/nr/*`"),
    "nr_last": Colour("pale khaki", (230, 230, 140), "the last Newton-Raphson iterate of eq. 17", "`/limb/nr/*`"),
    "spacecraft": Colour(
        "white", (255, 255, 255), "the spacecraft and 60 s of its velocity", "`/limb/spacecraft`, `/limb/velocity`"
    ),
    "los": Colour("yellow", (255, 210, 0), "the line of sight", "`/limb/los`"),
    "tangent": Colour("deep orange", (255, 120, 0), "the [L18] tangent point (eq. 21-26)", "`/limb/tangent`"),
    "exact": Colour("green", (20, 220, 90), "the exact minimum-height point", "`/limb/exact`"),
    "refracted": Colour("lime", (170, 255, 0), "the refracted tangent point", "`/limb/refracted`"),
    "earth_hit": Colour(
        "light red", (255, 60, 60), "where the line of sight meets the Earth (no tangent)", "`/limb/earth_hit`"
    ),
}

#: The Sentinel-2 scene (``geoloc_viz.scene_sentinel2``, ``geoloc view --sentinel2``): meaning -> colour.
SENTINEL2: dict[str, Colour] = {
    "earth": Colour("dark blue", (40, 90, 170), "the Earth: WGS-84 ellipsoid (a patch)", "`/s2/earth`"),
    "orbit": Colour("near white", (250, 250, 250), "the datastrip's orbit", "`/s2/orbit`"),
    "los": Colour("yellow", (255, 210, 0), "the chosen line's lines of sight", "`/s2/los/*`"),
    "swath": Colour("deep orange", (255, 120, 0), "the chosen line's ground", "`/s2/swath`"),
    "footprint": Colour("hot pink", (255, 60, 200), "the chosen detector's footprint", "`/s2/footprints/*`"),
    "other_footprint": Colour("pale cyan", (120, 220, 255), "the other detectors' footprints", "`/s2/footprints/*`"),
}

#: The teaching panel (``geoloc_viz.teaching_panel``, the frame chain drawn apart): meaning -> colour.
TEACHING: dict[str, Colour] = {
    "src": Colour("magenta", (255, 0, 255), "the chosen hop's source frame", "`/enu/teach/row/*`"),
    "dst": Colour("bright cyan", (0, 255, 255), "the chosen hop's destination frame", "`/enu/teach/row/*`"),
    "vector": Colour("yellow", (255, 210, 0), "the vector carried along the chain", "`/enu/teach/row/*/vector`"),
    "leader": Colour("silver", (200, 200, 200), "the leader from the row to the aircraft", "`/enu/teach/leader`"),
    "earth": Colour("navy", (30, 50, 150), "the Earth (translucent, to scale) of an ECEF hop", "`/enu/teach/*/earth`"),
    "aircraft": Colour("red", (255, 40, 40), "the aircraft beside the Earth to scale", "`/enu/teach/*/aircraft`"),
    "normal": Colour("white", (255, 255, 255), "the ellipsoid normal of [Q17]'s frames", "`/enu/teach/*/q17/normal`"),
}

#: The rerun recordings (``geoloc log``, ``geoloc_viz.rerun_log`` and ``rerun_terrain``): meaning -> colour
#: (RGB; the recordings add alpha 255). The track and the published points take the viewer's colours of
#: the same meanings (they were grey (200, 200, 200), 8.5 from the aircraft's (235, 235, 240), and blue
#: (80, 160, 255), 9.7 from the iterations below the terrain: CIEDE2000 under 10, one colour to the eye).
RERUN: dict[str, Colour] = {
    "los": Colour("amber", (255, 200, 40), "line of sight", "`*/los`"),
    "target": Colour("light red", (255, 60, 60), "the recomputed target", "`*/target`"),
    "truth": Colour("leaf green", (60, 220, 90), "the surveyed truth", "`*/truth`"),
    "published": Colour("violet", (180, 80, 255), "the published or reported position", "`*/published`"),
    "track": Colour("sky blue", (90, 200, 255), "the flight's track", "`*/track`"),
    "footprint": Colour("salmon", (255, 140, 140), "the footprints", "`*/footprint`"),
    "aircraft": Colour("ghost white", (235, 235, 240), "the aircraft", "`*/aircraft`"),
    "above": Colour("light orange", (255, 150, 40), "a terrain iteration above the terrain", "`*/iterations`"),
    "below": Colour("cornflower", (70, 130, 255), "a terrain iteration below the terrain", "`*/iterations`"),
}

#: One hue per flight in the rerun recordings' time-series views (matplotlib's tab10 blue, orange, green,
#: red, purple, brown; each series of a view a shade of its flight's hue, ``rerun_style.series_color``).
FLIGHT_SERIES: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
)

#: Every table: its title and meanings. Colours of one table can be on screen together (their meanings
#: differ by CIEDE2000 10 or more, ``tests/viz/test_viz_colours.py``); the scenes are never drawn together.
TABLES: dict[str, tuple[str, dict[str, Colour]]] = {
    "flight": ("the flight debugger (`geoloc view`)", PALETTE),
    "limb": ("the limb scene (`geoloc view --limb`)", LIMB),
    "sentinel2": ("the Sentinel-2 scene", SENTINEL2),
    "teaching": ("the teaching panel (drawn in the flight debugger)", TEACHING),
    "rerun": ("the rerun recordings (`geoloc log`)", RERUN),
}


def rgb(key: str) -> tuple[int, int, int]:
    """The sRGB colour (0-255) of meaning ``key``."""
    return PALETTE[key].rgb


def word(key: str) -> str:
    """The legend's bold name of meaning ``key``'s colour (markdown ``**name**``)."""
    return f"**{PALETTE[key].name}**"


def colour_table_markdown(table: str = "flight") -> str:
    """A colour table of ``docs/viz.md``: meaning, scene nodes, name, RGB (one row per meaning).

    ``table``: a key of :data:`TABLES` (default the flight debugger's, :data:`PALETTE`).
    """
    rows = ["| meaning | scene nodes | colour | sRGB |", "|---|---|---|---|"]
    for c in TABLES[table][1].values():
        rows.append(f"| {c.meaning} | {c.nodes} | {c.name} | {c.rgb[0]}, {c.rgb[1]}, {c.rgb[2]} |")
    return "\n".join(rows) + "\n"


def colour_tables_markdown() -> str:
    """Every table of :data:`TABLES`, each under a line naming where it is drawn (``docs/viz.md``)."""
    return "\n".join(f"Colours of {title}:\n\n{colour_table_markdown(key)}" for key, (title, _) in TABLES.items())


def rgba(table: dict[str, Colour], key: str) -> tuple[int, int, int, int]:
    """``table[key]``'s colour with alpha 255 (rerun's colours)."""
    r, g, b = table[key].rgb
    return (r, g, b, 255)


def tables_digest(*tables: str) -> str:
    """A short digest of the named tables' colours (keys and sRGB; names and meanings left out): a
    picture of the docs records the digest of the tables it shows when it is taken
    (``docs/img/palette_stamps.json``), so a later colour change names the pictures to retake."""
    import hashlib
    import json

    rows = [[t, k, list(c.rgb)] for t in sorted(set(tables)) for k, c in sorted(TABLES[t][1].items())]
    return hashlib.sha256(json.dumps(rows).encode()).hexdigest()[:16]


def _check_unique() -> None:
    """One name per colour and one colour per name, over every table (a legend word must name one colour)."""
    by_name: dict[str, tuple[int, int, int]] = {}
    for tk, (_, table) in TABLES.items():
        for key, c in table.items():
            if by_name.setdefault(c.name, c.rgb) != c.rgb:
                raise ValueError(f"palette: colour name {c.name!r} of {tk} {key!r} names two colours")


_check_unique()


if __name__ == "__main__":  # the tables of docs/viz.md: python -m geoloc_viz.palette
    print(colour_tables_markdown(), end="")
