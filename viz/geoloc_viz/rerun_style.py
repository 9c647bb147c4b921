"""The rerun recordings' palette (one place, for the log and the terrain layers)."""

import numpy as np

COLORS = {
    "los": (255, 200, 40, 255),
    "target": (255, 60, 60, 255),
    "truth": (60, 220, 90, 255),
    "published": (80, 160, 255, 255),
    "track": (200, 200, 200, 255),
    "footprint": (255, 140, 140, 255),
    "aircraft": (235, 235, 240, 255),
    "above": (255, 150, 40, 255),
    "below": (70, 130, 255, 255),
}

#: One hue per flight in the time-series views (matplotlib's tab10 blue, orange, green, red, purple, brown).
FLIGHT_COLORS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))


def series_color(flight: int, k: int = 0, n: int = 1) -> tuple:
    """RGBA of series ``k`` of ``n`` in one view for flight number ``flight``.

    The flight's hue, darkest for the first series and mixed towards white by up to 55 %
    for the last, so a view with several quantities keeps one hue per flight.
    """
    base = np.array(FLIGHT_COLORS[flight % len(FLIGHT_COLORS)], float)
    w = 0.55 * k / (n - 1) if n > 1 else 0.0
    rgb = np.round(base + w * (255.0 - base)).astype(int)
    return (int(rgb[0]), int(rgb[1]), int(rgb[2]), 255)
