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


#: Exit status of a command that ends on Ctrl-C: 128 + SIGINT, as a shell reports it (docs/cli.md).
EXIT_INTERRUPTED = 130

#: Exit status of a command whose standard output was closed early (``geoloc ... | head -1``):
#: 128 + SIGPIPE, what a shell reports for ``yes | head -1``'s ``yes`` (docs/cli.md).
EXIT_BROKEN_PIPE = 141


def main(argv=None) -> int:
    """Parse, check every output against every input (before anything runs), run the verb.

    Exit status (docs/cli.md): 0 all done; 1 the command ran but some records could not be
    located (the summary says how many and why); 2 bad usage or input: a refused output, a
    bad value or an unreadable or unwritable file is one line on stderr (docs/architecture.md,
    "The user's files"); 130 Ctrl-C (one line, no partial output file: :func:`geoloc.userfiles.atomic_path`
    removes its temporary file); 141 standard output closed by its reader (``| head -1``:
    the command ends quietly).
    """
    verb = prog = "geoloc"
    try:
        import contextlib

        from geoloc.cli._options import check_outputs, chosen_parsers, writes_stdout
        from geoloc.userfiles import command_files, stdout_is_data

        parser = build_parser()
        args = parser.parse_args(argv)
        verb = f"geoloc {args.verb}" if getattr(args, "verb", None) else "geoloc"
        prog = chosen_parsers(parser, args)[-1].prog  # "geoloc klv dump"
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        try:
            inputs = check_outputs(parser, args)
            data = stdout_is_data() if writes_stdout(parser, args) else contextlib.nullcontext()
            with command_files(inputs), data:  # --out -: the messages go to stderr, the data to stdout
                code = int(args.func(args) or 0)
            sys.stdout.flush()  # a closed pipe shows here, inside the handlers, not at exit
            return code
        except BrokenPipeError as e:
            if _stdout_closed():
                return _quiet_broken_pipe()
            print(f"{verb}: error: {_one_line(e)}", file=sys.stderr)  # another pipe than stdout
            return 2
        except (ValueError, OSError, MissingExtra) as e:
            print(f"{verb}: error: {_one_line(e)}", file=sys.stderr)
            return 2
    except KeyboardInterrupt:
        nl = "\n" if sys.stderr.isatty() else ""  # after the terminal's "^C"
        print(f"{nl}{prog}: interrupted (Ctrl-C)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the usage or help text itself, into a closed pipe
        if not _stdout_closed():
            raise
        return _quiet_broken_pipe()


def _stdout_closed() -> bool:
    """Whether standard output is a pipe (or socket) whose reader has gone (POLLERR on Linux)."""
    import select

    try:
        fd = sys.stdout.fileno()
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no real stdout (a test's capture): trust the error
        return True


def _quiet_broken_pipe() -> int:
    """End quietly when the reader of standard output has gone (the recipe of the Python docs,
    "Note on SIGPIPE"): what is still buffered goes to /dev/null, so the interpreter's last flush
    does not print "Exception ignored ... BrokenPipeError"."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):
        pass
    return EXIT_BROKEN_PIPE


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
