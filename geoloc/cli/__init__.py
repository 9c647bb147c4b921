"""The ``geoloc`` command line: one verb per module in :mod:`geoloc.cli`.

Each verb module defines ``register(subparsers)``, adding its parser with
``set_defaults(func=run)``; ``run(args)`` returns the process exit code. Degrees
and metres at this edge; the core works in radians.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from geoloc import __version__

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="geoloc",
        description="Direct geolocation of ground targets from airborne and spaceborne cameras.",
    )
    parser.add_argument("--version", action="version", version=f"geoloc {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):  # helpers (_options), not verbs
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv=None) -> int:
    """Parse, check every output against every input (before anything runs), run the verb.

    A refused output, a bad value or an unreadable or unwritable file is one line on
    stderr and exit status 2 (docs/architecture.md, "The user's files").
    """
    from geoloc.cli._options import check_outputs
    from geoloc.userfiles import command_files

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        inputs = check_outputs(parser, args)
        with command_files(inputs):
            return int(args.func(args) or 0)
    except (ValueError, OSError) as e:
        print(f"geoloc {args.verb}: error: {_one_line(e)}", file=sys.stderr)
        return 2


def _one_line(e: Exception) -> str:
    """The error's message on one line; an OSError names its path and reason."""
    if isinstance(e, OSError) and not isinstance(e, FileNotFoundError) and e.filename:
        msg = f"{e.filename}: {e.strerror or e}"
    elif isinstance(e, FileNotFoundError) and e.filename and not str(e).startswith(str(e.filename)):
        msg = f"{e.filename}: no such file or folder"
    else:
        msg = str(e)
    return " ".join(msg.split())


if __name__ == "__main__":
    sys.exit(main())
