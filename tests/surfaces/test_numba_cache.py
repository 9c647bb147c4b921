"""Compiled kernels: one compile per kernel, and a cache that follows the constants it froze.

numba's disk cache is invalidated only by a change to the kernel's own source file,
while a kernel freezes the module globals it reads (A, B, E2) and the code it calls
(``geoloc.geodesy._nbgeo``'s Vermeille, whose body is in ``ellipsoid.py``). These tests
edit ``ellipsoid.py`` in a scratch copy of the package and check that the compiled code
follows, and count the walk's compiled signatures over every kind of input
(read-only and writable origins and directions, a float32 DEM, the bisection's
internal call).
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geoloc.geodesy import _nbgeo, ellipsoid
from geoloc.surfaces import terrain
from geoloc.surfaces import terrain_numba as tn
from geoloc.surfaces.base import LineOfSight
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays

ROOT = Path(__file__).resolve().parents[2]


def _dispatchers(module):
    from numba.core.dispatcher import Dispatcher

    own = {k: v for k, v in vars(module).items() if isinstance(v, Dispatcher)}
    if module is tn:  # _nbgeo's conversions, imported: checked with _nbgeo
        own = {k: v for k, v in own.items() if getattr(_nbgeo, k, None) is not v}
        own.update({f"KERNELS[{k}]": v for k, v in tn.KERNELS.items()})  # the walks, one per variant
    return own


def test_every_kernel_has_the_dependency_keyed_cache():
    # a numba upgrade that renames the cache class would drop the key silently: fail instead
    for module in (_nbgeo, tn):
        ds = _dispatchers(module)
        assert len(ds) >= (3 if module is _nbgeo else 12), sorted(ds)
        for name, d in ds.items():
            assert isinstance(d._cache, _nbgeo._KeyedFunctionCache), (module.__name__, name)
            assert d._cache.dependency_key == module.KEY, (module.__name__, name)


def test_key_changes_with_a_constant(monkeypatch):
    k0 = _nbgeo.dependency_key(ellipsoid)
    assert _nbgeo.dependency_key(ellipsoid) == k0  # deterministic
    monkeypatch.setattr(ellipsoid, "F", 1.0 / 298.257222101)  # GRS80's flattening
    assert _nbgeo.dependency_key(ellipsoid) != k0


def test_walk_compiles_once_for_every_kind_of_input(monkeypatch):
    # read-only origin and direction (a full batch: np.broadcast_to views), writable ones
    # (one origin broadcast to many directions: a copy), the bisection's internal call
    # with normalised (writable) directions, triangles, a float32 DEM and a trace: one
    # signature, so a cold cache compiles the walk once (it compiled it four times)
    monkeypatch.setattr(tn, "_python_ok", lambda n, nodes: False)  # small calls: uncompiled
    z32 = (300.0 + 200.0 * np.random.default_rng(0).random((30, 30))).astype(np.float32)
    dem32 = DEM.from_array(z32, 36.1, 78.0, 0.002, 0.002)
    dem = DEM.from_array(z32.astype(float), 36.1, 78.0, 0.002, 0.002)
    rng = np.random.default_rng(1)
    for d_ in (dem, dem32):
        los = random_oblique_rays(d_, 20, rng)
        one = LineOfSight(los.origin_ecef[0], los.direction_ecef, los.status)
        ro = LineOfSight(*(np.broadcast_to(a, a.shape) for a in (los.origin_ecef, los.direction_ecef)), los.status)
        assert not ro.origin_ecef.flags.writeable
        for l_ in (los, one, ro):
            for method in ("exact", "bisect"):
                intersect_dem(l_, d_, method)
            intersect_dem(l_, d_, "exact", dem_model="triangles", trace=True)
        # the climbing kernel too: these rays would not climb, and the 30 x 30 DEM has no level 5
        climb, climb_from = terrain.CLIMB, terrain.CLIMB_FROM
        terrain.CLIMB, terrain.CLIMB_FROM = "always", 1
        try:
            intersect_dem(los, d_, "exact", dem_model="triangles")
            intersect_dem(ro, d_, "exact", dem_model="triangles", trace=True)
        finally:
            terrain.CLIMB, terrain.CLIMB_FROM = climb, climb_from
    # each compilation of the walk (with the climb, without it, without it for another block
    # side: a DEM of 7.7 m cells takes blocks of 13) has one signature
    fine = DEM.from_array(z32.astype(float), 36.1, 78.0, 7e-5, 7e-5)
    assert terrain._exact_tables(fine)["block"] > tn.BLOCK
    los = random_oblique_rays(fine, 20, rng)
    intersect_dem(los, fine, "exact", dem_model="triangles")
    intersect_dem(los, fine, "exact", trace=True)
    # one compiled walk per (climb, block side, cell model) used (a call compiles only
    # its own model; other tests of the session may have compiled more, hence >=)
    used = {k for k, kernel in tn.KERNELS.items() if kernel.signatures}
    assert used >= {
        ("climb", "triangles"),
        ("flat", "bilinear"),
        ("flat", "triangles"),
        ("flat_block", "bilinear"),
        ("flat_block", "triangles"),
    }, used
    for kernel in (tn.KERNELS[k] for k in used):
        assert len(kernel.signatures) == 1, kernel.signatures
        # the one signature takes read-only inputs (so writable ones never need a second)
        rays, grid, out = kernel.signatures[0]  # the records WalkRays, WalkGrid, WalkOut
        assert not rays[0].mutable and not rays[1].mutable and not grid[2].mutable and out[0].mutable


def test_walk_refuses_outputs_it_cannot_fill():
    # an output that is read-only or of another dtype would need a copy the caller never sees
    import pytest

    with pytest.raises(ValueError, match="status"):
        tn._output("status", np.zeros(3, np.int32), np.uint8, 1)
    ro = np.zeros(3)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="s_out"):
        tn._output("s_out", ro, np.float64, 1)


# ----------------------------------------------------------------- a changed constant
PROBE = """
import json, numpy as np
from geoloc.geodesy import _nbgeo, ellipsoid
from geoloc.surfaces import terrain_numba as tn
p = np.array([3004765.4345236067, 1093645.1791185443, 5501343.159342423])  # 60 N 20 E 1000 m, pyproj
lat, lon, h = _nbgeo.geodetic(*p)
la_np, lo_np, h_np = ellipsoid.ecef_to_geodetic(p)
bl, _ = tn.latlon(*p)
print(json.dumps(dict(F=ellipsoid.F, h=h, lat=lat, h_np=float(h_np), lat_np=float(la_np), bowring=bl,
                      hits=sum(_nbgeo.geodetic.stats.cache_hits.values()),
                      bowring_hits=sum(tn.latlon.stats.cache_hits.values()))))
"""


def _probe(src: Path, cache: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(src))
    r = subprocess.run([sys.executable, "-c", PROBE], cwd=src, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_changed_constant_reaches_the_compiled_code(tmp_path):
    """Edit WGS-84's flattening to GRS80's in a scratch copy (a mutation the cache must see):
    the kernels compiled before must not be loaded for the new constants.

    Before the fix the second run after the edit loaded the cached machine code with
    WGS-84 frozen in: the compiled height then differed from the numpy one by 8e-5 m
    (b changes by 0.1 mm; at 60 deg the height by 0.75 of that)."""
    src = tmp_path / "src"
    shutil.copytree(ROOT / "geoloc", src / "geoloc", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    cold = _probe(src, cache)
    warm = _probe(src, cache)
    assert cold["hits"] == 0 and warm["hits"] >= 1 and warm["bowring_hits"] >= 1  # the cache works
    assert warm["h"] == cold["h"]
    ell = src / "geoloc" / "geodesy" / "ellipsoid.py"
    text = ell.read_text()
    assert "F = 1.0 / 298.257223563" in text
    ell.write_text(text.replace("F = 1.0 / 298.257223563", "F = 1.0 / 298.257222101"))
    grs = _probe(src, cache)
    assert grs["F"] == 1.0 / 298.257222101
    assert grs["hits"] == 0 and grs["bowring_hits"] == 0  # compiled afresh, not loaded
    # the compiled code uses the new flattening: it agrees with numpy (which reads the
    # module's globals at call time) to rounding, and differs from the WGS-84 answer
    assert abs(grs["h"] - grs["h_np"]) < 1e-8
    assert abs(grs["h"] - cold["h"]) > 5e-5
    assert abs(grs["bowring"] - grs["lat_np"]) < 1e-9


def test_a_second_process_waits_for_the_compile_of_a_kernel_and_loads_it(tmp_path):
    # two processes that miss a cold cache at once (the two pytest-xdist workers of tools/test.sh, two
    # verbs started together) compiled every kernel they share twice. Now the second waits on the
    # first's lock and loads what it compiled. Played in order: the test holds the lock (as a
    # compiling process does), B misses and waits on it, A (told not to wait) compiles and caches the
    # kernel, the lock is released: B must load A's kernel, not compile its own
    import fcntl
    import time

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc to see that the second process waits on the lock")
    cache = tmp_path / "cache"
    own = _nbgeo.geodetic._cache
    lock = cache / Path(own._cache_path).name / (own._cache_file._index_name + ".lock")
    lock.parent.mkdir(parents=True)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    code = (
        "import json, sys; from geoloc.geodesy import _nbgeo; _nbgeo.COMPILE_WAIT_S = float(sys.argv[1]); "
        "_nbgeo.geodetic(6378137.0, 0.0, 0.0); print(json.dumps([n for n, _ in _nbgeo.COMPILED]))"
    )
    with open(lock, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        b = subprocess.Popen([sys.executable, "-c", code, "600"], env=env, stdout=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120  # B's imports, seconds on a busy machine
            while not any(os.path.realpath(f) == str(lock.resolve()) for f in _open_files(b.pid)):
                assert b.poll() is None and time.monotonic() < deadline, "B did not wait on the lock"
                time.sleep(0.05)
            a = subprocess.run([sys.executable, "-c", code, "0"], env=env, capture_output=True, text=True, check=True)
            assert json.loads(a.stdout) == ["geodetic"]  # A compiled it (and saved it)
        finally:
            fcntl.flock(held, fcntl.LOCK_UN)
        out, _ = b.communicate(timeout=300)
    assert b.returncode == 0 and json.loads(out) == [], out  # B loaded A's kernel: no compile of its own


def _open_files(pid: int) -> list:
    try:
        return [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
    except OSError:  # a file closed while listed
        return []
