"""A module's source at another git revision, loaded as a scratch module (for the A/B benchmarks)."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import io
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def module_at(rev: str, relpath: str):
    """``relpath`` (e.g. ``geoloc/sensors/_fastlocate.py``) as it is at git revision ``rev``, imported
    under a scratch name; numba compiles its kernels afresh in this process (their cache key reads
    the scratch file)."""
    src = subprocess.run(
        ["git", "show", f"{rev}:{relpath}"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout
    path = Path(tempfile.mkdtemp(prefix="bench_ab_")) / f"{Path(relpath).stem}_{rev.replace('/', '_')}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod  # dependency_key reads the module's file
    spec.loader.exec_module(mod)
    return mod


#: Where whole copies of the package at other revisions are kept (``package_at``): one folder per
#: commit (or per content of a folder), reused by the next run, so numba's cache of the copy's
#: kernels (keyed on the copy's path: numba's cache_dir) stays warm after the first compile.
CACHE = Path(
    os.environ.get("GEOLOC_GUARD_CACHE")
    or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "geoloc" / "guard"
)

_FROM = re.compile(r"^(\s*)from geoloc(?=[.\s])", re.MULTILINE)
_IMPORT = re.compile(r"^\s*import geoloc\b", re.MULTILINE)


def _rewrite(pkg_dir: Path, name: str) -> None:
    """Point every absolute ``from geoloc...`` import of the copy in ``pkg_dir`` at ``name``."""
    for f in pkg_dir.rglob("*.py"):
        src = f.read_text(encoding="utf-8")
        if _IMPORT.search(src):  # would bind the name `geoloc`: this copy cannot be renamed
            raise RuntimeError(f"{f}: `import geoloc...` cannot be renamed; use `from geoloc... import`")
        f.write_text(_FROM.sub(rf"\1from {name}", src), encoding="utf-8")


def _install(dest: Path, name: str, fill) -> None:
    """Make ``dest/name`` (a renamed copy of the package) once: ``fill(tmp)`` writes the package's
    files into ``tmp/geoloc``; the folder appears whole or not at all."""
    if (dest / ".complete").exists():
        return
    CACHE.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".part_", dir=CACHE))
    try:
        fill(tmp)
        for cache in (tmp / "geoloc").rglob("__pycache__"):
            shutil.rmtree(cache)
        _rewrite(tmp / "geoloc", name)
        (tmp / "geoloc").rename(tmp / name)
        (tmp / "assets").symlink_to(ROOT / "assets")  # geoloc.assets: assets/ beside the package
        (tmp / ".complete").write_text("")
        try:
            tmp.rename(dest)
        except OSError:  # another run made it meanwhile
            if not (dest / ".complete").exists():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def package_at(rev_or_dir: str) -> tuple[str, str]:
    """The whole ``geoloc`` package at git revision ``rev_or_dir`` (or in the folder of that name,
    a checkout holding ``geoloc/``), imported as a package of another name; returns
    (import name, label). Its modules import one another under that name, so the revision's
    wrappers call the revision's kernels, which numba compiles (once: the copy stays in
    ``CACHE``). Objects of the copy are its own classes: build each side's inputs with its own."""
    d = Path(rev_or_dir)
    if d.is_dir() and (d / "geoloc" / "__init__.py").is_file():
        h = hashlib.sha256(str(ROOT).encode() + b"\0")  # the copy's assets link points into this checkout
        for f in sorted((d / "geoloc").rglob("*.py")):
            h.update(str(f.relative_to(d)).encode() + b"\0" + f.read_bytes())
        tag, label = "d" + h.hexdigest()[:12], f"folder {d}"

        def fill(tmp):
            shutil.copytree(d / "geoloc", tmp / "geoloc", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    else:
        sha = subprocess.run(
            ["git", "rev-parse", "--verify", f"{rev_or_dir}^{{commit}}"],
            cwd=ROOT,
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
        where = hashlib.sha256(str(ROOT).encode()).hexdigest()[:6]  # the copy's assets link points here
        tag, label = f"r{sha[:12]}{where}", sha[:12]

        def fill(tmp):
            tar = subprocess.run(
                ["git", "archive", "--format=tar", sha, "geoloc"], cwd=ROOT, check=True, capture_output=True
            ).stdout
            with tarfile.open(fileobj=io.BytesIO(tar)) as t:
                t.extractall(tmp, filter="data")

    name = f"geoloc_{tag}"
    dest = CACHE / tag
    _install(dest, name, fill)
    _link_assets(dest)
    os.utime(dest / ".complete")  # last used: _prune keeps the latest KEEP
    _prune()
    if str(dest) not in sys.path:
        sys.path.insert(0, str(dest))
    importlib.import_module(name)
    return name, label


def _link_assets(dest: Path) -> None:
    """Point the copy's ``assets`` at this checkout's, if it points anywhere else: the cache
    outlives checkouts (a CI clone, a removed worktree), and a dangling link makes every kernel's
    inputs unreadable. Replaced by rename, so a concurrent reader sees one link or the other."""
    link = dest / "assets"
    if link.is_symlink() and os.readlink(link) == str(ROOT / "assets"):
        return
    tmp = dest / f".assets.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(ROOT / "assets")
    os.replace(tmp, link)


#: Copies kept in CACHE (the most recently used): a few revisions and folders, about 5 MB each
#: plus their compiled kernels.
KEEP = 8


def _prune() -> None:
    done = sorted(CACHE.glob("*/.complete"), key=lambda p: p.stat().st_mtime, reverse=True)
    for old in done[KEEP:]:
        _drop_compiled(old.parent)
        shutil.rmtree(old.parent, ignore_errors=True)


def _drop_compiled(copy: Path) -> None:
    """Remove numba's cache entries of a copy's modules (geoloc's cache folder keys them by the
    source folder's path, numba's ``get_suitable_cache_subpath``)."""
    try:
        from numba.core.caching import _CacheLocator

        from geoloc.geodesy._nbgeo import cache_dir
    except ImportError:
        return
    for d in {f.parent for f in copy.rglob("*.py")}:
        shutil.rmtree(cache_dir() / _CacheLocator.get_suitable_cache_subpath(str(d / "x.py")), ignore_errors=True)
