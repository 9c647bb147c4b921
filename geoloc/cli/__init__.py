"""The ``geoloc`` command line: one verb per module in :mod:`geoloc.cli`, and the verbs
other installed packages add through the ``geoloc.verbs`` entry points (the viewer's
``view`` and ``log``, from ``viz/``).

Each verb module defines ``register(subparsers)``, adding its parser with
``set_defaults(func=run)``; ``run(args)`` returns the process exit code. Degrees
and metres at this edge; the core works in radians. A viewer verb whose package is
not installed is still listed, and says how to install it (exit status 2).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from importlib.metadata import entry_points

from geoloc import __version__
from geoloc.extras import VIEWER_INSTALL, MissingExtra

#: The entry-point group through which another package adds verbs (name -> module).
VERB_GROUP = "geoloc.verbs"
#: Verbs the viewer package adds: listed even when it is not installed.
VIEWER_VERBS = {
    "view": "open the interactive 3D scene in the browser (needs the viewer package)",
    "log": "write a rerun recording (.rrd) (needs the viewer package)",
}


def _verb_modules():
    """(name, module name) of every verb: the core's modules, then the entry points."""
    out = {info.name: f"{__name__}.{info.name}" for info in pkgutil.iter_modules(__path__)
           if not info.name.startswith("_")}  # helpers (_options), not verbs
    for ep in entry_points(group=VERB_GROUP):
        out.setdefault(ep.name, ep.value)
    return sorted(out.items())


def _missing_viewer(args) -> int:
    print(f"geoloc {args.verb}: the viewer is not installed: {VIEWER_INSTALL}", file=sys.stderr)
    return 2

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="geoloc",
        description="Direct geolocation of ground targets from airborne and spaceborne cameras.",
    )
    parser.add_argument("--version", action="version", version=f"geoloc {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    verbs = _verb_modules()
    for name, module in verbs:
        importlib.import_module(module).register(sub)
    for name, help_text in VIEWER_VERBS.items():
        if name not in dict(verbs):
            p = sub.add_parser(name, help=help_text, add_help=False)
            p.add_argument("rest", nargs=argparse.REMAINDER)
            p.set_defaults(func=_missing_viewer)
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
    except (ValueError, OSError, MissingExtra) as e:
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
