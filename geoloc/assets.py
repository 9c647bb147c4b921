"""Where the bundled data lives (cameras, records, scenarios, DEM and geoid crops, meshes).

One rule, read once when ``geoloc`` is imported, for every module that reads bundled data
(``geoloc.geodesy.geoid`` included):

1. ``$GEOLOC_ASSETS``, if set: a folder laid out like the repository's ``assets/``;
2. else the package data ``geoloc/_assets`` of an installed wheel, found with
   :mod:`importlib.resources` (the build copies the repository's ``assets/`` there;
   see ``setup.py``);
3. else ``assets/`` beside the package: a source checkout, or an editable install
   (``pip install -e .``), which runs from the checkout.

``assets/README.md`` says where each file comes from and its licence.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.resources
import os
from pathlib import Path

#: Name of the package-data folder inside an installed ``geoloc``.
PACKAGE_DIR = "_assets"
#: The environment variable that overrides the folder.
ENV = "GEOLOC_ASSETS"


def _locate() -> tuple[Path, str]:
    env = os.environ.get(ENV)
    if env:
        return Path(env).expanduser(), f"${ENV}"
    try:
        res = importlib.resources.files("geoloc") / PACKAGE_DIR
        if res.is_dir():
            if isinstance(res, Path):
                return res, "package data"
            # a zipped install: extract once, for the life of the process (GDAL needs files)
            stack = contextlib.ExitStack()
            atexit.register(stack.close)
            return Path(stack.enter_context(importlib.resources.as_file(res))), "package data"
    except (ModuleNotFoundError, OSError):  # pragma: no cover - geoloc always importable here
        pass
    return Path(__file__).resolve().parents[1] / "assets", "source checkout"


#: The assets folder (see the module docstring for the rule).
ASSETS, ASSETS_SOURCE = _locate()


def asset_path(*parts: str) -> Path:
    """Path of a bundled file, e.g. ``asset_path("cameras", "qiao2017.toml")``; error if missing."""
    p = ASSETS.joinpath(*parts)
    if not p.exists():
        raise FileNotFoundError(
            f"bundled asset not found: {p} (assets folder from {ASSETS_SOURCE}; the installation "
            f"is incomplete: reinstall geoloc, or set {ENV} to a folder laid out like the "
            "repository's assets/)"
        )
    return p


def resolve_user_path(text: str | os.PathLike[str]) -> Path:
    """A path given on the command line; ``assets/...`` names a bundled file when absent here.

    The README's commands name bundled files as ``assets/records/...``: from a
    source checkout's root that is the file itself; anywhere else (an installed
    wheel) a path that does not exist and starts with ``assets/`` is taken inside
    :data:`ASSETS`. Any other path is returned unchanged (the caller reports it if
    it is missing).
    """
    p = Path(str(text))
    if p.exists() or p.is_absolute():
        return p
    parts = p.parts
    if len(parts) > 1 and parts[0] == "assets":
        cand = ASSETS.joinpath(*parts[1:])
        if cand.exists():
            return cand
    return p


DEFAULT_CAMERA = ("cameras", "qiao2017.toml")
DEFAULT_RECORDS = ("records", "qiao2017_flight_tests.csv")
