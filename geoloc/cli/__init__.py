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

#: Modules of this package that are helpers, not verbs.
NOT_VERBS = {"terrain_options"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="geoloc",
        description="Direct geolocation of ground targets from airborne and spaceborne cameras.",
    )
    parser.add_argument("--version", action="version", version=f"geoloc {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_") or info.name in NOT_VERBS:
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        print(f"geoloc {args.verb}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
