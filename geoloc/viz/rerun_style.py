"""The rerun recordings' palette (one place, for the log and the terrain layers)."""

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
