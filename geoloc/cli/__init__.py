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
NOT_VERBS: set = set()


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


#: Options that name an input file: ``assets/...`` there means a bundled file wherever geoloc
#: is installed (:func:`geoloc.assets.resolve_user_path`), so the README's commands run from any folder.
PATH_OPTIONS = ("records", "camera", "dem", "scenario", "input", "columns", "targets", "inputs")


def _resolve_paths(args) -> None:
    from geoloc.assets import resolve_user_path

    for name in PATH_OPTIONS:
        v = getattr(args, name, None)
        if isinstance(v, str):
            setattr(args, name, str(resolve_user_path(v)))
        elif isinstance(v, list) and all(isinstance(x, str) for x in v):
            setattr(args, name, [str(resolve_user_path(x)) for x in v])


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _resolve_paths(args)
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
