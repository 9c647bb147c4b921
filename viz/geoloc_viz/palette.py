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


def rgb(key: str) -> tuple[int, int, int]:
    """The sRGB colour (0-255) of meaning ``key``."""
    return PALETTE[key].rgb


def word(key: str) -> str:
    """The legend's bold name of meaning ``key``'s colour (markdown ``**name**``)."""
    return f"**{PALETTE[key].name}**"


def colour_table_markdown() -> str:
    """The colour table of ``docs/viz.md``: meaning, scene nodes, name, RGB (one row per meaning)."""
    rows = ["| meaning | scene nodes | colour | sRGB |", "|---|---|---|---|"]
    for c in PALETTE.values():
        rows.append(f"| {c.meaning} | {c.nodes} | {c.name} | {c.rgb[0]}, {c.rgb[1]}, {c.rgb[2]} |")
    return "\n".join(rows) + "\n"


def _check_unique() -> None:
    """One name per colour and one colour per name (a legend word must name one colour)."""
    by_name: dict[str, tuple[int, int, int]] = {}
    for key, c in PALETTE.items():
        if by_name.setdefault(c.name, c.rgb) != c.rgb:
            raise ValueError(f"palette: colour name {c.name!r} of {key!r} names two colours")


_check_unique()


if __name__ == "__main__":  # the table of docs/viz.md: python -m geoloc_viz.palette
    print(colour_table_markdown(), end="")
