"""Line-of-sight corrections: atmospheric refraction, light-time and aberration of light.

The physics is in the modules (:mod:`~geoloc.corrections.atmosphere`,
:mod:`~geoloc.corrections.refraction`, :mod:`~geoloc.corrections.lighttime`); the location
pipeline (:mod:`geoloc.pipeline`) applies them. Here: the one check of a file's
``[corrections]`` table (sensor, scenario and error-model files), which the readers of every
layer call.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

#: The ground measurement a standard atmosphere can be fitted to (``StandardAtmosphere``'s own
#: parameters: the height of the measurement [m], pressure [Pa], temperature [K]).
GROUND_KEYS = ("ground_h_m", "ground_p_pa", "ground_t_k")
#: The keys of a ``[corrections]`` table.
TABLE_KEYS = ("refraction", "light_time", "aberration") + GROUND_KEYS
#: The refraction models a table or ``--refraction`` names: off, or the U.S. Standard Atmosphere 1976.
REFRACTION_MODELS = ("none", "standard")


def check_table(table: Mapping[str, Any], source: str = "[corrections]") -> dict:
    """A ``[corrections]`` table checked: ``refraction = "none" | "standard"``, ``light_time`` and
    ``aberration`` true or false, nothing else. Errors name ``source``, the key and the value."""
    if not isinstance(table, dict):
        raise ValueError(f"{source}: must be a table of {', '.join(TABLE_KEYS)}, got {table!r}")
    unknown = sorted(set(table) - set(TABLE_KEYS))
    if unknown:
        raise ValueError(f"{source}: {unknown[0]!r} is not a correction; the keys are {', '.join(TABLE_KEYS)}")
    if "refraction" in table and table["refraction"] not in REFRACTION_MODELS:
        raise ValueError(f"{source}: refraction = {table['refraction']!r} must be one of {list(REFRACTION_MODELS)}")
    for key in ("light_time", "aberration"):
        if key in table and not isinstance(table[key], bool):
            raise ValueError(f"{source}: {key} = {table[key]!r} must be true or false")
    for key in GROUND_KEYS:
        v = table.get(key)
        if key in table and (
            isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) == float("inf")
        ):
            raise ValueError(f"{source}: {key} = {v!r} must be a finite number")
    return dict(table)
