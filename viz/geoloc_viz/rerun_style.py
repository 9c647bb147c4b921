"""The rerun recordings' colours (for the log and the terrain layers), from the viewer's colour table."""

import numpy as np

from geoloc_viz.palette import FLIGHT_SERIES, RERUN, rgba

#: meaning -> RGBA (:data:`geoloc_viz.palette.RERUN`, alpha 255)
COLORS = {key: rgba(RERUN, key) for key in RERUN}

#: One hue per flight in the time-series views (:data:`geoloc_viz.palette.FLIGHT_SERIES`).
FLIGHT_COLORS = FLIGHT_SERIES


def series_color(flight: int, k: int = 0, n: int = 1) -> tuple:
    """RGBA of series ``k`` of ``n`` in one view for flight number ``flight``.

    The flight's hue, darkest for the first series and mixed towards white by up to 55 %
    for the last, so a view with several quantities keeps one hue per flight.
    """
    base = np.array(FLIGHT_COLORS[flight % len(FLIGHT_COLORS)], float)
    w = 0.55 * k / (n - 1) if n > 1 else 0.0
    rgb = np.round(base + w * (255.0 - base)).astype(int)
    return (int(rgb[0]), int(rgb[1]), int(rgb[2]), 255)
