"""The optional parts of the core and the one message for a missing one.

The core (``pip install .``) needs only what ``locate``, ``replay``, ``report`` and the
exports use. Heavier libraries are extras, imported by the function that needs them
through :func:`require`, so a core install runs everything else and a missing extra is
one line naming the ``pip install`` that brings it (``docs/architecture.md``, "Two
packages"). The viewer is not an extra but its own package, ``viz/`` (``geoloc_viz``).
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: extra -> the modules it brings (``pyproject.toml``, ``[project.optional-dependencies]``)
EXTRAS = {
    "video": ("av", "cv2"),
    "campaign": ("dask", "distributed", "pyarrow"),
    "mesh": ("trimesh",),
    "space": ("astropy", "erfa"),
}

#: The command that installs the viewer package beside the core, from a clone.
VIEWER_INSTALL = "pip install ./viz (from a clone of geoloc: it installs geoloc-viz, the viewer)"


class MissingExtra(ImportError):
    """An optional library is not installed; the message names the extra that brings it."""


def extra_of(module: str) -> str:
    """The extra whose install brings ``module`` (its top-level name)."""
    top = module.split(".")[0]
    for extra, mods in EXTRAS.items():
        if top in mods:
            return extra
    raise KeyError(f"module {module!r} belongs to no extra of geoloc ({sorted(EXTRAS)})")


def require(module: str, what: str) -> ModuleType:
    """Import ``module``, or raise :class:`MissingExtra` naming the extra to install.

    Parameters
    ----------
    module : str
        The module to import, e.g. ``"av"`` or ``"pyarrow.parquet"``.
    what : str
        What needs it, in the user's words (``"reading MPEG-TS video"``): the message
        says "``what`` needs ``module``".
    """
    try:
        return importlib.import_module(module)
    except ImportError as e:
        extra = extra_of(module)
        raise MissingExtra(
            f"{what} needs {module.split('.')[0]}, which is not installed: "
            f"pip install 'geoloc[{extra}]' (or, from a clone, pip install '.[{extra}]')"
        ) from e
