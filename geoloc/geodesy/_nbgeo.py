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
entry stays, so switching back costs no compile). ``tests/test_numba_cache.py``
edits a constant in a scratch copy of the package and checks that the compiled
code follows.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

from numba import njit

from geoloc.geodesy import ellipsoid
from geoloc.geodesy.ellipsoid import vermeille

try:  # numba's per-function cache; its index key is what we extend
    from numba.core.caching import FunctionCache as _FunctionCache
    from numba.core.dispatcher import Dispatcher as _Dispatcher
except ImportError:  # pragma: no cover - a numba without it: compile without a disk cache
    _FunctionCache = None
    _Dispatcher = ()


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


if _FunctionCache is not None:
    class _KeyedFunctionCache(_FunctionCache):
        """numba's function cache with ``key`` appended to every index key."""

        def __init__(self, py_func, key: str):
            super().__init__(py_func)
            self.dependency_key = key

        def _index_key(self, sig, codegen):
            return super()._index_key(sig, codegen) + (self.dependency_key,)
else:  # pragma: no cover
    _KeyedFunctionCache = None


def cached_njit(key: str, **options):
    """``numba.njit(cache=True, **options)`` whose cache entries are also keyed on ``key``.

    ``key`` is a :func:`dependency_key` of the modules the kernel reads constants or
    calls code from. Without numba's cache class (another numba version) the kernel is
    compiled without a disk cache: slower to start, never stale.
    """
    def deco(fn):
        disp = njit(cache=False, **options)(fn)
        if _KeyedFunctionCache is not None and isinstance(disp, _Dispatcher):
            disp._cache = _KeyedFunctionCache(disp.py_func, key)
        return disp

    return deco


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
