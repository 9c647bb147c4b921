"""Paths of the bundled data in the repository's ``assets/`` folder (see ``assets/README.md``)."""

from __future__ import annotations

import os
from pathlib import Path

#: The assets folder: ``$GEOLOC_ASSETS`` if set, else ``assets/`` beside the package.
ASSETS = Path(os.environ.get("GEOLOC_ASSETS", Path(__file__).resolve().parents[1] / "assets"))


def asset_path(*parts: str) -> Path:
    """Path of a bundled file, e.g. ``asset_path("cameras", "qiao2017.toml")``; error if missing."""
    p = ASSETS.joinpath(*parts)
    if not p.exists():
        raise FileNotFoundError(f"bundled asset not found: {p} (is the repository checked out whole?)")
    return p


DEFAULT_CAMERA = ("cameras", "qiao2017.toml")
DEFAULT_RECORDS = ("records", "qiao2017_flight_tests.csv")
