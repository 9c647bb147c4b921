"""The user's files: inputs noted while a command runs, outputs written atomically, never over an input.

Three rules hold for every file geoloc writes (docs/architecture.md, "The user's
files"):

- **No output is one of the command's inputs.** While a command runs
  (:func:`command_files`), every loader notes the files it opens
  (:func:`note_input`); :func:`check_output` refuses a path that is the same file as
  a noted input (by identity, :func:`os.path.samefile`: symlinks, hard links and
  relative paths alike), a file of the bundled data, or a folder.
- **An output is written whole or not at all.** :func:`atomic_path` yields a
  temporary path in the output's folder, with the same suffix (GDAL, pyogrio and
  matplotlib choose their format by it), and renames it into place with
  :func:`os.replace` when the block ends without an exception; otherwise the
  temporary file is removed and the old output, if any, is left as it was.
- **What is there is written through, not replaced.** An output that is a device
  (``/dev/null``, ``/dev/full``), a FIFO or a socket is opened and written as it is; an
  output that is a symlink is written atomically beside its target and renamed onto the
  target, so the link stays. An existing regular output keeps its permission bits; a
  read-only one (no write bit) is refused, even for root. A path that ends with ``/`` or
  is a folder is refused: an output file needs a file name (docs/cli.md).
- **An unwritable path is one clear line.** A missing folder, a folder that cannot
  be written (probed by creating a file there, so it holds for root and read-only
  mounts too) or a path whose parent is a file raise :class:`OutputRefused`, a
  ``ValueError`` naming the option, the path and the reason.

Outside a command (the Python API) nothing is noted, so :func:`atomic_path` only
makes the write atomic: a script may read a file and write it back on purpose.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import shutil
import stat
import sys
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Iterator

__all__ = [
    "OutputRefused",
    "TempFileLeft",
    "command_files",
    "note_input",
    "noted_inputs",
    "check_output",
    "check_output_dir",
    "atomic_path",
    "write_text",
    "write_bytes",
    "growing_path",
]


class OutputRefused(ValueError):
    """An output path that is an input, a folder, bundled data, or cannot be written."""


#: The inputs noted by the command running in this context (None: no command runs).
_INPUTS: contextvars.ContextVar = contextvars.ContextVar("geoloc_inputs", default=None)


@contextlib.contextmanager
def command_files(inputs: Iterable[str | os.PathLike[str]] = ()) -> Iterator[list]:
    """Note inputs for the duration of one command; yields the list of noted paths.

    ``inputs`` are the command's declared inputs (its path options), noted at once;
    loaders add the files they open with :func:`note_input`.
    """
    token = _INPUTS.set([])
    try:
        for p in inputs:
            note_input(p)
        yield _INPUTS.get()
    finally:
        _INPUTS.reset(token)


def note_input(path: str | os.PathLike[str]) -> None:
    """Note ``path`` (a file or folder the running command reads); a no-op outside a command."""
    noted = _INPUTS.get()
    if noted is None or path is None:
        return
    try:
        p = Path(os.fspath(path))
    except TypeError:  # an open file object, a URL object: nothing on disk to protect
        return
    if str(p).startswith(("udp://", "tcp://", "rtp://", "http://", "https://")):
        return
    if p not in noted:
        noted.append(p)


def noted_inputs() -> list:
    """The inputs noted so far by the running command (empty outside a command)."""
    return list(_INPUTS.get() or [])


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one file: by identity (symlinks, hard links, relative paths),
    or, when one of them does not exist yet, by their resolved paths (two outputs to be
    written to one place)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def _bundled_root() -> Path | None:
    from geoloc.assets import ASSETS

    try:
        return Path(ASSETS).resolve()
    except OSError:
        return None


def _inside(p: Path, root: Path) -> bool:
    try:
        p.resolve().relative_to(root)
        return True
    except ValueError:
        return False


def _probe_folder(folder: Path, option: str, path) -> None:
    """Raise OutputRefused unless a file can be created in ``folder``."""
    where = f"{option} {path}" if option else str(path)
    if not folder.exists():
        raise OutputRefused(f"{where}: folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputRefused(f"{where}: {folder} is a file, not a folder")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".geoloc-probe-"):
            pass
    except OSError as e:
        raise OutputRefused(f"{where}: cannot write in folder {folder}: {e.strerror or e}") from None


def _kind(p: Path) -> str:
    """``"missing"``, ``"file"``, ``"folder"`` or ``"special"`` (a device, FIFO or socket), following symlinks."""
    try:
        mode = os.stat(p).st_mode
    except OSError:  # not there; or a symlink loop, a path through a file: the folder probe names it
        return "missing"
    if stat.S_ISDIR(mode):
        return "folder"
    return "file" if stat.S_ISREG(mode) else "special"


def write_target(path: str | os.PathLike[str]) -> Path:
    """The file a write to ``path`` lands on: ``path`` itself, or a symlink's target (followed to the end)."""
    p = Path(os.fspath(path))
    return Path(os.path.realpath(p)) if p.is_symlink() else p


def check_output(
    path: str | os.PathLike[str], option: str = "", *, inputs: Iterable[str | os.PathLike[str]] | None = None
) -> Path:
    """Refuse an output path that must not or cannot be written; returns it as a ``Path``.

    Parameters
    ----------
    path : str or path-like
        The file to be written.
    option : str
        How the user named it (``"--out"``), for the message.
    inputs : iterable of paths, optional
        The inputs to compare with; default the running command's noted inputs.

    Raises
    ------
    OutputRefused
        ``path`` is one of the inputs, a file of the bundled data, an existing folder or
        a path ending with ``/``, a read-only existing file (refused even for root, who
        writes through permission bits), or its folder (a symlink's: its target's) is
        missing or cannot be written. A device, FIFO or socket is not probed: it is
        written through (:func:`atomic_path`), and a write that fails is one line then.
    """
    p = Path(os.fspath(path))
    where = f"{option} {path}" if option else str(path)
    if str(os.fspath(path)) == STDOUT:
        return p
    for q in noted_inputs() if inputs is None else [Path(os.fspath(x)) for x in inputs]:
        if same_file(p, q):
            same = "" if str(q) == str(path) else f" ({q})"
            raise OutputRefused(
                f"{where} is an input of this command{same}: refusing to overwrite it; give another output path"
            )
    root = _bundled_root()
    if root is not None and p.exists() and _inside(p, root):
        raise OutputRefused(f"{where} is a file of geoloc's bundled data ({root}): refusing to overwrite it")
    text = str(os.fspath(path))
    kind = _kind(p)
    if kind == "folder":
        raise OutputRefused(f"{where} is a folder: give a file name")
    if text.endswith(("/", os.sep)) or (os.altsep and text.endswith(os.altsep)):
        raise OutputRefused(
            f"{where} ends with '/', a folder's path: give a file name "
            f"(e.g. {text.rstrip('/' + os.sep)}/out{_suffix_hint(option)})"
        )
    if kind == "special":
        return p  # written through (a device, a FIFO): nothing is replaced
    target = write_target(p)
    if kind == "file" and not (os.stat(target).st_mode & 0o222):
        shown = "" if target == p else f" (the link's target {target})"
        raise OutputRefused(
            f"{where}{shown} is read-only: refusing to replace it (make it writable, or give another output path)"
        )
    _probe_folder(target.parent if str(target.parent) else Path("."), option, path)
    return p


def _suffix_hint(option: str) -> str:
    return ".tif" if "ortho" in option else ".csv"


def check_output_dir(
    path: str | os.PathLike[str], option: str = "", *, inputs: Iterable[str | os.PathLike[str]] | None = None
) -> Path:
    """Refuse an output folder that is an input, a file, bundled data, or cannot be made or written."""
    p = Path(os.fspath(path))
    where = f"{option} {path}" if option else str(path)
    for q in noted_inputs() if inputs is None else [Path(os.fspath(x)) for x in inputs]:
        if same_file(p, q):
            raise OutputRefused(f"{where} is an input of this command: refusing to write into it")
    root = _bundled_root()
    if root is not None and _inside(p, root):
        raise OutputRefused(f"{where} is inside geoloc's bundled data ({root}): refusing to write into it")
    if p.exists() and not p.is_dir():
        raise OutputRefused(f"{where} is a file, not a folder")
    parent = p
    while not parent.exists() and parent != parent.parent:  # the first existing ancestor is made into
        parent = parent.parent
    _probe_folder(parent, option, path)
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], option: str = "") -> Iterator[Path]:
    """A temporary path beside ``path``, renamed onto it when the block succeeds.

    The temporary file is in the same folder (so the rename is atomic) and keeps the
    suffix (``out.tif`` -> ``.out.tif.geoloc-XXXX.tif``). On an exception (Ctrl-C too)
    it is removed and ``path`` is untouched. :func:`check_output` is applied first.

    What is already there decides how it is written (docs/cli.md): a symlink is written
    beside its target and renamed onto the target (the link stays); a device, FIFO or
    socket (``/dev/null``) is written through, never replaced: the block writes a
    temporary file whose bytes are then copied into it (a library given the device's own
    path may delete it and create a file: GDAL's GeoPackage driver does); an existing
    file's permission bits are given to the new file. ``"-"`` is standard output, the
    same way.
    """
    p = check_output(path, option)
    if str(p) == STDOUT:
        with _through_temp(option, "-", "", _copy_to_stdout) as tmp:
            yield tmp
        return
    if _kind(p) == "special":  # copied in at the end: a library given the path itself may delete it first
        with _through_temp(option, path, p.suffix, lambda fh: _copy_to_special(fh, p)) as tmp, _naming(path):
            yield tmp
        return
    target = write_target(p)
    old_mode = stat.S_IMODE(os.stat(target).st_mode) if _kind(target) == "file" else None
    folder = target.parent if str(target.parent) else Path(".")
    with _as_output(path):  # a folder made read-only since the checks: the user's path, not the temp's
        fd, tmp_name = tempfile.mkstemp(dir=folder, prefix=f".{target.name}.geoloc-", suffix=p.suffix)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        tmp.unlink()  # the writer creates it: its own default mode, and some libraries refuse a file
        with _naming(path, folder):
            yield tmp
        if not tmp.exists():
            raise OutputRefused(f"{option + ' ' if option else ''}{path}: the writer produced no file")
        with _naming(path, folder):
            _verify(tmp)
        with _as_output(path):
            if old_mode is not None and tmp.is_file():
                os.chmod(tmp, old_mode)
            os.replace(tmp, target)
    finally:
        _remove_temp(tmp, path)


class TempFileLeft(UserWarning):
    """A temporary output file that could not be removed (its folder turned read-only between
    the writer and the rename): one line naming it, so the user can delete it."""


def _remove_temp(tmp: Path, path) -> None:
    """Remove :func:`atomic_path`'s temporary file or folder ``tmp``, if it is there.

    Never raises: it runs while an exception (the rename refused, Ctrl-C) is on its way and must
    not replace it (a failed removal once ended the command with an error naming the hidden temp
    file instead of the output). What cannot be removed is a :class:`TempFileLeft` warning, one
    line naming it (``geoloc VERB: warning: ...``)."""
    import shutil
    import warnings

    try:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp)
        else:
            tmp.unlink()
    except FileNotFoundError:
        return
    except OSError as e:
        if not os.path.lexists(tmp):  # gone after all (rmtree met a file removed meanwhile)
            return
        warnings.warn(
            TempFileLeft(
                f"{os.fspath(path)}: its temporary file {tmp} could not be removed "
                f"({e.strerror or e}); delete it by hand"
            ),
            stacklevel=2,
        )


@contextlib.contextmanager
def _as_output(path) -> Iterator[None]:
    """An OSError of atomic_path's own steps (the temporary file's creation, its mode, the rename)
    said of the user's output ``path``: the temporary file's hidden name means nothing to them."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        if e.errno is None:
            raise
        raise OSError(e.errno, e.strerror or str(e), os.fspath(path)) from None


#: Free space under which a filesystem on which a writer failed is taken as full [bytes].
FULL_BELOW = 256 * 1024


def _fault_of(folder) -> int | None:
    """``errno.EROFS`` or ``errno.ENOSPC`` when ``folder``'s filesystem is read-only or (nearly) full."""

    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return None
    if st.f_flag & getattr(os, "ST_RDONLY", 1):
        return errno.EROFS
    if st.f_bavail * st.f_frsize < FULL_BELOW:
        return errno.ENOSPC
    return None


@contextlib.contextmanager
def _naming(path, folder=None) -> Iterator[None]:
    """The writer's failure as one line naming the output.

    An OSError that names no file (``fh.write`` on a full disk: ``[Errno 28] No space left on
    device``) is raised again naming the output. A library's own error (GDAL through pyogrio:
    "Failed to commit transaction"; an unreadable raster, :func:`_verify`) when the output's
    filesystem is full or read-only is that OSError (a full or read-only disk is a fault a user meets)."""

    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        vague = e.errno in (None, errno.EIO)
        fault = _fault_of(folder) if folder is not None and vague else None
        if fault is not None:
            raise OSError(fault, os.strerror(fault), os.fspath(path)) from e
        if e.filename is not None or e.errno is None:
            raise
        raise OSError(e.errno, e.strerror or str(e), os.fspath(path)) from None
    except (RuntimeError, ValueError) as e:
        fault = _fault_of(folder) if folder is not None and not isinstance(e, OutputRefused) else None
        if fault is None:
            raise
        raise OSError(fault, os.strerror(fault), os.fspath(path)) from e


#: Suffixes of the files GDAL writes (rasterio): opened once before they replace anything.
GDAL_RASTERS = (".tif", ".tiff", ".ntf", ".nitf")


def _verify(tmp: Path) -> None:
    """Raise when a GDAL raster just written cannot be opened: on a full disk rasterio 1.4 closes a
    GeoTIFF without an error (GDALClose's status is not looked at) and leaves a file of 0 bytes,
    which replaced the old output (found by writing on a full filesystem)."""
    if tmp.suffix.lower() not in GDAL_RASTERS or not tmp.is_file():
        return

    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)  # a frame grid has none
            with rasterio.open(tmp):
                pass
    except rasterio.errors.RasterioError as e:
        import errno

        raise OSError(errno.EIO, f"the raster written cannot be read back ({e})") from None


#: The output path that means standard output (``--out -``).
STDOUT = "-"

#: Where ``--out -`` writes: the real standard output (binary), set by :func:`stdout_is_data`
#: while a command's own messages go to stderr.
_DATA_OUT: contextvars.ContextVar = contextvars.ContextVar("geoloc_data_out", default=None)


@contextlib.contextmanager
def stdout_is_data() -> Iterator[None]:
    """While a command writes ``--out -``: its messages (``print``) go to stderr, so that standard
    output carries the data alone; :func:`atomic_path` writes ``-`` to the real standard output."""

    real = sys.stdout
    token = _DATA_OUT.set(real)
    sys.stdout = sys.stderr
    try:
        yield
    finally:
        sys.stdout = real
        _DATA_OUT.reset(token)


@contextlib.contextmanager
def _through_temp(option: str, path, suffix: str, sink) -> Iterator[Path]:
    """A temporary file (in a folder of its own, with ``suffix``) whose bytes ``sink(fh)`` copies
    where they go when the block succeeds: standard output, a device, a FIFO."""

    folder = Path(tempfile.mkdtemp(prefix="geoloc-out-"))
    try:
        tmp = folder / f"out{suffix}"
        yield tmp
        if not tmp.is_file():
            raise OutputRefused(
                f"{option + ' ' if option else ''}{path}: the writer produced no single file to copy there"
            )
        with tmp.open("rb") as fh:
            sink(fh)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _copy_to_stdout(fh) -> None:

    out = _DATA_OUT.get() or sys.stdout
    out.flush()
    shutil.copyfileobj(fh, out.buffer)
    out.flush()


def _copy_to_special(fh, p: Path) -> None:
    """Write the bytes through a device, FIFO or socket file, never replacing it (``/dev/full``: the
    OSError names the path)."""

    try:
        with open(p, "wb") as dst:
            shutil.copyfileobj(fh, dst)
    except OSError as e:
        if e.filename is None and e.errno is not None:
            raise OSError(e.errno, e.strerror or str(e), str(p)) from None
        raise


def write_text(path: str | os.PathLike[str], text: str, option: str = "", encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path, option) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(os.fspath(path))


def write_bytes(path: str | os.PathLike[str], data: bytes, option: str = "") -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path, option) as tmp:
        tmp.write_bytes(data)
    return Path(os.fspath(path))


@contextlib.contextmanager
def growing_path(path: str | os.PathLike[str], option: str = "") -> Iterator[Path]:
    """A file that grows while a command runs (a live journal), put in place when the command ends.

    The journal grows beside ``path`` as ``STEM.partial.SUFFIX`` (``STEM.partial-2.SUFFIX``
    if that exists: an earlier session's journal is never overwritten), so it can be read
    while it grows and a crash leaves every row written so far; when the block ends
    (normally, or by Ctrl-C) it is renamed onto ``path`` with :func:`os.replace`, so an
    older ``path`` stays whole until the new one is complete. On any other exception the
    partial file is left where it is. :func:`check_output` is applied to both names.
    """
    if str(os.fspath(path)) == STDOUT:
        raise OutputRefused(
            f"{option + ' ' if option else ''}-: a live journal grows as a file (its rows are "
            "printed on standard output anyway): give a file name"
        )
    p = check_output(path, option)
    parent = p.parent if str(p.parent) else Path(".")
    k = 1
    while True:
        tmp = parent / f"{p.stem}.partial{'' if k == 1 else f'-{k}'}{p.suffix}"
        if not tmp.exists():
            break
        k += 1
    check_output(tmp, option)
    try:
        yield tmp
    except KeyboardInterrupt:
        if tmp.exists():
            os.replace(tmp, p)
        raise
    if not tmp.exists():
        raise OutputRefused(f"{option + ' ' if option else ''}{path}: the writer produced no file")
    os.replace(tmp, p)
