"""Reading the project's TOML files (cameras, scenarios) with errors that name the file."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

from geoloc.userfiles import note_input


def read_toml(path: str | os.PathLike[str], what: str = "scenario file") -> dict[str, Any]:
    """Parse a TOML file.

    Raises ``FileNotFoundError`` ("<what> not found: <path>") if it is missing and
    ``ValueError`` ("<what> <path>: not valid TOML: ...") if it does not parse or is not
    UTF-8 text (fuzzing found a binary file raising a bare ``UnicodeDecodeError``, naming no file).
    """
    note_input(path)
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except UnicodeDecodeError as e:
        raise ValueError(
            f"{what} {path}: not valid TOML: byte 0x{e.object[e.start]:02x} at offset {e.start} "
            "is not UTF-8 text (a binary file?)"
        ) from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{what} {path}: not valid TOML: {e}") from None
