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
from collections.abc import Sequence
from importlib.metadata import entry_points

from geoloc import __version__
from geoloc.extras import VIEWER_INSTALL, MissingExtra

#: The entry-point group through which another package adds verbs (name -> module).
VERB_GROUP = "geoloc.verbs"
#: Each verb's one-line help: the one source of it (each verb's ``register`` reads it here), so
#: ``geoloc --help`` lists the verbs without importing them (a verb imports only when it runs).
VERB_HELP = {
    "calibrate": "flight-test debugger: error vectors, outliers, mounting/boresight fit, resection",
    "export": "write replay results to GeoPackage, GeoJSON, KML, CZML or Cursor-on-Target (TAK)",
    "klv": "MISB ST 0601 KLV metadata: dump the packets (JSON lines), fix a copy's frame-centre and "
    "corner tags, send an MPEG-TS to udp://HOST:PORT",
    "limb": "limb viewing: tangent height of lines of sight ([L18] virtual ellipsoid + exact minimum)",
    "locate": "geolocate one pixel (aircraft pose + gimbal angles + camera + target height)",
    "montecarlo": "Monte Carlo error analysis of a scenario TOML (statistics, CEP, Fig. 10 sweeps)",
    "ortho": "every pixel of a frame onto the DEM: per-pixel lat/lon/h GeoTIFF, and a photo's orthophoto",
    "pixel": "which pixel sees a ground point (lat/lon or MGRS), and whether the camera sees it",
    "replay": "replay flight-test records: locate each one and measure the errors",
    "report": "accuracy report of a replay's output CSV: CEP, CE90, LE90, MAE, bias, plots, HTML",
    "reproduce": "reproduce a paper's results: the published numbers and geoloc's side by side",
    "s2": "Sentinel-2 L1B: direct-location grids (lon, lat, h GeoTIFF) and the pixel of a ground point",
    "rpc": "fit RPC coefficients to a sensor model, write GDAL RPC metadata, cross-check with GDAL RPC_DEM",
    "warm": "compile the terrain and camera kernels once, ahead of the first locate / replay / view",
    # the viewer package's verbs (entry points), listed even when it is not installed
    "view": "open the interactive 3D scene in the browser (default: the bundled example flight)",
    "log": "write a rerun recording (.rrd) of a simulated scan or of flight-test records",
}
#: Verbs the viewer package adds: listed even when it is not installed.
VIEWER_VERBS = ("view", "log")


def _verb_modules():
    """(name, module name) of every verb: the core's modules, then the entry points."""
    out = {
        info.name: f"{__name__}.{info.name}" for info in pkgutil.iter_modules(__path__) if not info.name.startswith("_")
    }  # helpers (_options), not verbs
    for ep in entry_points(group=VERB_GROUP):
        out.setdefault(ep.name, ep.value)
    return sorted(out.items())


def _missing_viewer(args) -> int:
    print(f"geoloc {args.verb}: the viewer is not installed: {VIEWER_INSTALL}", file=sys.stderr)
    return 2


def build_parser(only: str | None = None, *, lazy: bool = False) -> argparse.ArgumentParser:
    """The ``geoloc`` parser.

    Parameters
    ----------
    only : str, optional
        With ``lazy``: the one verb whose module is imported and whose options are declared.
    lazy : bool
        Every other verb is listed by its :data:`VERB_HELP` line only, its module not imported
        (``geoloc --help`` and ``geoloc VERB ...`` import one verb at most). False: every verb
        whole (what the tests read each verb's options from).
    """
    parser = argparse.ArgumentParser(
        prog="geoloc",
        description="Direct geolocation of ground targets from airborne and spaceborne cameras.",
    )
    parser.add_argument("--version", action="version", version=f"geoloc {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    verbs = dict(_verb_modules())
    for name in sorted(set(verbs) | set(VIEWER_VERBS)):
        if name not in verbs:  # a viewer verb without the viewer installed
            p = sub.add_parser(name, help=f"{VERB_HELP[name]} (needs the viewer: pip install ./viz)", add_help=False)
            p.add_argument("rest", nargs=argparse.REMAINDER)
            p.set_defaults(func=_missing_viewer)
        elif lazy and name != only:
            sub.add_parser(name, help=VERB_HELP.get(name))
        else:
            importlib.import_module(verbs[name]).register(sub)
    return parser


def _verb_of(argv) -> str | None:
    """The verb a command line names: its first word that is not an option (the top-level
    options, ``--help`` and ``--version``, take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


#: Exit status of a command that ends on Ctrl-C: 128 + SIGINT, as a shell reports it (docs/cli.md).
EXIT_INTERRUPTED = 130

#: Exit status of a command whose standard output was closed early (``geoloc ... | head -1``):
#: 128 + SIGPIPE, what a shell reports for ``yes | head -1``'s ``yes`` (docs/cli.md).
EXIT_BROKEN_PIPE = 141


def main(argv: Sequence[str] | None = None) -> int:
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
        argv = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(_verb_of(argv), lazy=True)  # the one verb named is imported, no other
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2

        import contextlib

        from geoloc.cli._options import check_outputs, chosen_parsers, writes_stdout
        from geoloc.userfiles import command_files, stdout_is_data

        verb = f"geoloc {args.verb}" if getattr(args, "verb", None) else "geoloc"
        prog = chosen_parsers(parser, args)[-1].prog  # "geoloc klv dump"
        try:
            inputs = check_outputs(parser, args)
            data = stdout_is_data() if writes_stdout(parser, args) else contextlib.nullcontext()
            with command_files(inputs), data, _warnings_as_lines(prog):  # --out -: messages to stderr
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


def _warnings_as_lines(prog: str):
    """geoloc's own warnings (a category defined in ``geoloc``: a DEM tile that cannot be read) as one
    line each, ``geoloc VERB: warning: ...``; others as Python shows them."""
    import contextlib
    import warnings

    @contextlib.contextmanager
    def block():
        with warnings.catch_warnings():
            shown = warnings.showwarning

            def show(message, category, filename, lineno, file=None, line=None):
                if getattr(category, "__module__", "").startswith("geoloc"):
                    print(f"{prog}: warning: {' '.join(str(message).split())}", file=sys.stderr)
                else:
                    shown(message, category, filename, lineno, file, line)

            warnings.showwarning = show
            yield

    return block()


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
