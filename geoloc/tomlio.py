"""Reading the project's TOML files (cameras, scenarios) with errors that name the file."""

from __future__ import annotations

import tomllib
from pathlib import Path

from geoloc.userfiles import note_input


def read_toml(path, what: str = "scenario file") -> dict:
    """Parse a TOML file.

    Raises ``FileNotFoundError`` ("<what> not found: <path>") if it is missing and
    ``ValueError`` ("<what> <path>: not valid TOML: ...") if it does not parse.
    """
    note_input(path)
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{what} {path}: not valid TOML: {e}") from None
