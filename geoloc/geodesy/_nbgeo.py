"""Scalar ECEF -> geodetic for numba kernels (terrain walk, fused locate), and the cache
key every compiled kernel of the project uses.

Vermeille's closed form (J. Geodesy 76:451-454, 2002; 78:94-95, 2004): numba
compiles the very function behind :func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`
(:func:`geoloc.geodesy.ellipsoid.vermeille`) for scalars, so that compiled kernels can
call it per point. Conventions: ``docs/conventions.md``.

Why a cache key of our own (:func:`cached_njit`): numba's on-disk cache
(``cache=True``) is invalidated only when the *kernel's own* source file changes,
and it freezes the module globals a kernel reads (``A``, ``E2``, the status codes)
and the code of every function it calls into the cached machine code. A change to
``ellipsoid.py`` (a constant, or the body of ``vermeille``) would then leave the
terrain walk and the fused locate kernel running the old numbers from a stale
cache. :func:`cached_njit` adds :func:`dependency_key` to numba's index key: the
values of the ellipsoid constants and the sources of the modules the kernel takes
code or constants from, so that any change there compiles afresh (and the old
entry stays, so switching back costs no compile). ``tests/surfaces/test_numba_cache.py``
edits a constant in a scratch copy of the package and checks that the compiled
code follows.

Where the cache lives: numba's default puts it in ``__pycache__`` beside the
sources, which ``pip install --upgrade`` / a reinstall deletes, so every reinstall paid the
first-run compile again (48 s and 1 GB on 2 cores then; 15 s and 390 MB since the walk's
helpers are no longer numba-inlined). geoloc's kernels are cached in
:func:`cache_dir`: the user's ``NUMBA_CACHE_DIR`` when set, else a user cache folder
(``$XDG_CACHE_HOME/geoloc/numba``, ``~/.cache/geoloc/numba``; ``~/Library/Caches`` on macOS,
``%LOCALAPPDATA%`` on Windows), else (unwritable) numba's own places. The entries stay valid
across a reinstall because numba stamps each index with a SHA-256 of the source file (not its
time) and :func:`dependency_key` hashes the sources it depends on.

The first compile says what is happening, once per process, on stderr
(:data:`ANNOUNCE`): "compiling the terrain kernels once, about N s; cached in DIR".
``geoloc warm`` (``tools/run.sh`` runs it) compiles them ahead of the first real call.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
import time
import types
from pathlib import Path

from geoloc.geodesy import ellipsoid
from geoloc.geodesy.ellipsoid import vermeille

#: numba's cache API is there (set when numba is imported: :func:`_activate`); None before.
_CACHE_API: bool | None = None

#: Say on stderr, once per process, that kernels are being compiled: True, False, or None
#: (the default: when stderr is a terminal, or the environment sets GEOLOC_ANNOUNCE_COMPILE=1).
ANNOUNCE: bool | None = None
#: CPU seconds of a first call that compiles the terrain walk on a cold cache, 2 cores (measured:
#: 14-15 s for ``geoloc view``'s first scene: ``view --export`` cold 17.3 s of CPU in all, the
#: flat bilinear walk's compile 10.8 s of it, 12-14 s before the walk was compiled per model,
#: 41-48 s while its helpers were numba-inlined; a small call (a one-ray ``locate --dem``, the
#: viewer's first scene) compiles no walk: ``terrain_numba.PY_WALK_MAX_RAYS`` and
#: ``terrain_numba.uncompiled_budget``;
#: ``benchmarks/bench_first_run.py`` measures each verb): the announcement's "about N s"
#: (wall time is that or more on a busy machine).
FIRST_COMPILE_CPU_S = 15
#: Compiles of this process: (kernel name, seconds) as they finish (``geoloc warm`` prints them).
COMPILED: list = []
_announced = False


def cache_dir() -> Path:
    """The folder geoloc's compiled kernels are cached in: ``NUMBA_CACHE_DIR`` when the user set
    one, else the user's cache folder + ``geoloc/numba`` (XDG on Linux, ``~/Library/Caches`` on
    macOS, ``%LOCALAPPDATA%`` on Windows): outside the installed package, so a reinstall keeps it."""
    # numba's config reads NUMBA_CACHE_DIR when numba is imported; before that, the environment
    cfg = sys.modules.get("numba.core.config")
    user = getattr(cfg, "CACHE_DIR", "") if cfg is not None else os.environ.get("NUMBA_CACHE_DIR", "")
    if user:
        return Path(user)
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "geoloc" / "numba"


def _announce(name: str) -> None:
    global _announced
    if _announced:
        return
    on = ANNOUNCE
    if on is None:
        on = os.environ.get("GEOLOC_ANNOUNCE_COMPILE") == "1" or bool(getattr(sys.stderr, "isatty", lambda: False)())
    if not on:
        return
    _announced = True
    print(
        f"geoloc: compiling the terrain and camera kernels once (about {FIRST_COMPILE_CPU_S} s of CPU on "
        f"2 cores, the first run only; `geoloc warm` does it ahead); cached in {cache_dir()}",
        file=sys.stderr,
        flush=True,
    )


def dependency_key(*modules) -> str:
    """SHA-256 of the WGS-84 constants' values and of the sources of ``modules``.

    The values are read now (a constant patched before the kernel module is imported
    is part of the key too); ``geoloc.geodesy.ellipsoid`` is always included.
    """
    h = hashlib.sha256()
    h.update(repr((ellipsoid.A, ellipsoid.F, ellipsoid.B, ellipsoid.E2)).encode())
    seen = set()
    for m in (ellipsoid, *modules):
        path = Path(m.__file__)
        if path in seen:
            continue
        seen.add(path)
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _numba_cache_classes() -> bool:
    """Import numba's cache machinery and define this module's cache classes on it (they become
    this module's globals: ``_KeyedFunctionCache`` ...); False when this numba has no such API
    (then kernels compile without a disk cache: slower to start, never stale).

    Called when the first kernel is made (:func:`_activate`), not at import: numba's import is
    most of a one-pixel ``geoloc locate``'s start-up, which calls no kernel."""
    global _CACHE_API
    try:
        from numba.core import config as _nb_config
        from numba.core.caching import CompileResultCacheImpl as _CacheImpl
        from numba.core.caching import FunctionCache as _FunctionCache
        from numba.core.caching import UserProvidedCacheLocator as _UserLocator
    except ImportError:  # pragma: no cover - a numba without it
        _CACHE_API = False
        return False

    class _GeolocCacheLocator(_UserLocator):
        """numba's user-folder locator pointed at :func:`cache_dir` (when ``NUMBA_CACHE_DIR`` is
        not set: then numba's own locator serves it first). Unwritable: None, numba's next."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(str(cache_dir()), self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if _nb_config.CACHE_DIR:
                return None
            return super(_UserLocator, cls).from_function(py_func, py_file)

    class _GeolocCacheImpl(_CacheImpl):
        _locator_classes = [_UserLocator, _GeolocCacheLocator] + [
            c for c in _CacheImpl._locator_classes if c is not _UserLocator
        ]

    class _KeyedFunctionCache(_FunctionCache):
        """numba's function cache with ``key`` appended to every index key, kept in
        :func:`cache_dir`; a miss (a compile to come) is announced once (:data:`ANNOUNCE`)."""

        _impl_class = _GeolocCacheImpl

        def __init__(self, py_func, key: str):
            super().__init__(py_func)
            self.dependency_key = key
            self.kernel_name = py_func.__name__
            self._t_miss = None

        def _index_key(self, sig, codegen):
            return super()._index_key(sig, codegen) + (self.dependency_key,)

        def load_overload(self, sig, target_context):
            got = super().load_overload(sig, target_context)
            if got is None and self._enabled and self._lock is None:
                # another process may be compiling this kernel now (two pytest-xdist workers, two
                # verbs started together): wait for it and load its result, not compile it again
                self._lock = os.path.join(self._cache_path, self._cache_file._index_name + ".lock")
                _compile_lock(self._lock)
                got = super().load_overload(sig, target_context)
                if got is not None:
                    self._unlock()
            if got is None and self._enabled:
                _announce(self.kernel_name)
                self._t_miss = time.process_time()
            return got

        def save_overload(self, sig, data):
            if self._t_miss is not None:
                COMPILED.append((self.kernel_name, time.process_time() - self._t_miss))
                self._t_miss = None
            try:
                return super().save_overload(sig, data)
            finally:
                self._unlock()

        _lock = None

        def _unlock(self) -> None:
            path, self._lock = self._lock, None
            fd = _HELD.pop(path, None) if path is not None else None
            if fd is not None:
                os.close(fd)  # closing the file releases its flock

    globals().update(
        _GeolocCacheLocator=_GeolocCacheLocator,
        _GeolocCacheImpl=_GeolocCacheImpl,
        _KeyedFunctionCache=_KeyedFunctionCache,
    )
    _CACHE_API = True
    return True


#: Seconds a process waits for another one compiling the same kernel before it compiles it itself
#: (a process that failed to compile keeps its lock until it exits). The longest compiles are the
#: fused uncertainty kernels', 77-98 s of CPU (``tools/compile_time.py``), and a test run's three
#: workers on two cores stretch that past 200 s of wall time: with 120 s the second worker gave up
#: and compiled ``chain_surface_kernel`` again (about 100 s of CPU more, in every cold run).
COMPILE_WAIT_S = 600.0


#: The compile locks this process holds: lock file path -> its file descriptor.
_HELD: dict = {}


def _compile_lock(path: str) -> None:
    """Take an exclusive ``flock`` on ``path`` (created) and note it in :data:`_HELD`; nothing when
    this process holds it already (two dispatchers of one kernel share its cache files), when
    locking is not possible here (no ``fcntl``, an unwritable cache) or after :data:`COMPILE_WAIT_S`.

    Without it two processes that miss the cache at once (the two workers of ``tools/test.sh`` on
    a cold cache) both compiled every kernel they share: the second waits, then loads the first's."""
    if path in _HELD:
        return
    try:
        import fcntl

        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except (ImportError, OSError):
        return
    deadline = time.monotonic() + COMPILE_WAIT_S
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            _HELD[path] = fd
            return
        except BlockingIOError:
            if time.monotonic() > deadline:
                break
            time.sleep(0.05)
        except OSError:
            break
    os.close(fd)


def cached_njit(key: str, **options):
    """``numba.njit(cache=True, **options)`` whose cache entries are also keyed on ``key``.

    ``key`` is a :func:`dependency_key` of the modules the kernel reads constants or
    calls code from. Without numba's cache class (another numba version) the kernel is
    compiled without a disk cache: slower to start, never stale.

    numba is not imported here: until a kernel is first called (or numba is imported by
    something else), the decorated function is a :class:`LazyKernel`, and the first call
    makes every kernel's dispatcher at once (:func:`_activate`). A one-pixel ``geoloc
    locate`` runs the numpy path and so never imports numba (0.2-0.3 s of its start-up).

    No C-callable (``cfunc``) wrapper is made: nothing takes these kernels as first-class
    function pointers, and the wrapper was 2 % of the first compile's Python work (measured).
    """

    def deco(fn):
        with _LOCK:
            if not (_ACTIVE or "numba" in sys.modules):
                lazy = LazyKernel(fn, key, options)
                _PENDING.append(lazy)
                return lazy
        _activate()  # numba is loaded already: nothing left to save
        return _dispatcher(fn, key, options)

    return deco


def _dispatcher(fn, key, options):
    """numba's dispatcher of ``fn`` with :class:`_KeyedFunctionCache` (numba imported)."""
    from numba import njit
    from numba.core.dispatcher import Dispatcher

    disp = njit(cache=False, no_cfunc_wrapper=True, **options)(fn)
    if _CACHE_API and isinstance(disp, Dispatcher):
        disp._cache = _KeyedFunctionCache(disp.py_func, key)  # noqa: F821 (made by _numba_cache_classes)
    return disp


class LazyKernel:
    """A :func:`cached_njit` kernel before numba is imported: ``fn`` and its options.

    Calling it, or reading any attribute of numba's dispatcher from it (``signatures``,
    ``stats``, ...), imports numba and makes the dispatcher (:func:`_activate`, for every
    kernel at once); ``py_func`` is ``fn`` without that. After :func:`_activate` no module
    holds one any more (each global and closure cell that held one holds its dispatcher, so
    that numba compiles and inlines the kernels a kernel calls); a reference kept elsewhere
    still calls, and numba types it as the dispatcher (``_numba_type_``), not inlined.
    """

    def __init__(self, fn, key: str, options: dict):
        self.py_func = fn
        self._key = key
        self._options = options
        self._disp = None
        for name in ("__module__", "__name__", "__qualname__", "__doc__"):
            setattr(self, name, getattr(fn, name, None))

    def dispatcher(self):
        """numba's dispatcher of this kernel (numba imported now if it was not)."""
        if self._disp is None:
            _activate()
        return self._disp

    def __call__(self, *args, **kwargs):
        return self.dispatcher()(*args, **kwargs)

    def __getattr__(self, name):  # only for names the object lacks: numba's dispatcher's
        if name.startswith("__") or name in ("_disp", "_key", "_options", "py_func"):
            raise AttributeError(name)
        return getattr(self.dispatcher(), name)

    @property
    def _numba_type_(self):  # numba's typeof: a kernel compiled with this object as a global
        from numba.core import types as nb_types

        return nb_types.Dispatcher(self.dispatcher())

    def __repr__(self) -> str:
        state = "not yet compiled, numba not imported" if self._disp is None else repr(self._disp)
        return f"<LazyKernel {self.__qualname__}: {state}>"


def prange(*args):
    """``numba.prange`` for a kernel module that should not import numba: ``range`` in Python,
    and swapped for ``numba.prange`` in every module's globals by :func:`_activate`, before
    numba reads the globals of a ``parallel=True`` kernel."""
    return range(*args)


#: Kernels made before numba was imported, waiting for :func:`_activate`.
_PENDING: list = []
_ACTIVE = False
_LOCK = threading.RLock()


def _activate() -> None:
    """Import numba, make the dispatcher of every :class:`LazyKernel` made so far, and put each
    dispatcher (and ``numba.prange`` for :func:`prange`) in place of the lazy object in every
    module's globals and in the kernels' closure cells.

    numba reads a kernel's globals when it compiles it, and inlines a called kernel
    (``inline="always"``) only when that global is the dispatcher itself: so every kernel is
    made here at once, before any is compiled (the cost of making them is what importing
    the kernel modules cost before: ~1 ms each)."""
    global _ACTIVE
    with _LOCK:  # two threads calling their first kernels: one makes them all, the other waits
        if _ACTIVE:
            return
        import numba

        _numba_cache_classes()
        pending = list(_PENDING)
        for lazy in pending:
            lazy._disp = _dispatcher(lazy.py_func, lazy._key, lazy._options)
        # id -> (the object, what replaces it); _nbgeo's own name prange is replaced too
        swap = {id(lazy): (lazy, lazy._disp) for lazy in pending}
        swap[id(prange)] = (prange, numba.prange)
        # exact modules only: a lazy module's subclass may load itself when its __dict__ is read
        for mod in list(sys.modules.values()):
            if type(mod) is types.ModuleType:
                _swap(mod.__dict__, swap)
        for lazy in pending:
            for cell in lazy.py_func.__closure__ or ():
                try:
                    value = cell.cell_contents
                except ValueError:  # an empty cell
                    continue
                old, new = swap.get(id(value), (None, None))
                if value is old:
                    cell.cell_contents = new
        _PENDING.clear()
        _ACTIVE = True


def _swap(ns: dict, swap: dict) -> None:
    """In ``ns``, each value that is a key's object of ``swap`` (id -> (object, new)) becomes its new."""
    for name, value in list(ns.items()):
        old, new = swap.get(id(value), (None, None))
        if value is old:
            ns[name] = new


#: The key of this module's kernels: the constants and ellipsoid.py (vermeille's body).
KEY = dependency_key(ellipsoid, sys.modules[__name__])

_vermeille = cached_njit(KEY, error_model="numpy", inline="always")(vermeille)


@cached_njit(KEY, error_model="numpy")
def geodetic(x, y, z):
    """Scalar ECEF -> (lat, lon, h), as geoloc.geodesy.ellipsoid.ecef_to_geodetic."""
    lat, lon, h, _, _, _ = _vermeille(x, y, z)
    return lat, lon, h


@cached_njit(KEY, error_model="numpy")
def geodetic_up(x, y, z):
    """As :func:`geodetic`, plus the outward normal (cos phi cos lam, cos phi sin lam, sin phi).

    phi = atan2(z, d) in Vermeille's notation, so the normal needs no trigonometry.
    """
    lat, lon, h, d, dz, rho = _vermeille(x, y, z)
    cphi = d / dz
    return lat, lon, h, cphi * x / rho, cphi * y / rho, z / dz
