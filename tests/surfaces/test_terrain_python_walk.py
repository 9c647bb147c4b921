"""The walk's Python source run uncompiled for a small call (terrain_numba.PY_WALK_MAX_RAYS), and
for the first rays of a larger one within an uncompiled budget (so that a one-ray ``locate``
and the viewer's first scene compile nothing) against the compiled kernel on the same rays:
oblique views of the bundled SRTM crop and rays that graze a rough DEM for kilometres, leave
it across an edge or start outside it, both cell models, with and without the climb."""

import numpy as np
import pytest
from test_terrain_hierarchy import _grazing_and_edge_rays, _rough_dem  # tests/ is on sys.path

from geoloc.assets import asset_path
from geoloc.surfaces import terrain
from geoloc.surfaces import terrain_numba as tn
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays


def _both(los, dem, model, monkeypatch, **kw):
    """(Python walk's result, compiled kernel's result), the Python one checked to have run
    without falling back to the kernel."""
    ran = []
    real = tn._python_walk

    def spy(kernel):
        f = real(kernel)
        return lambda *a: (f(*a), ran.append(kernel))[0]

    monkeypatch.setattr(tn, "_python_walk", spy)
    monkeypatch.setattr(tn, "_python_ok", lambda n, nodes: True)
    py = intersect_dem(los, dem, "exact", dem_model=model, **kw)
    assert ran, "the Python walk fell back to the kernel"
    monkeypatch.setattr(tn, "_python_ok", lambda n, nodes: False)
    nb = intersect_dem(los, dem, "exact", dem_model=model, **kw)
    return py, nb


def _assert_same(py, nb):
    assert np.array_equal(py.status, nb.status)
    assert np.array_equal(py.dem_evaluations, nb.dem_evaluations)  # the same cells visited
    # the same code; the kernel rounds once where LLVM fuses a multiply and an add (FMA,
    # fastmath "contract"; the module docstring: hits move by at most 1e-7 m), Python twice.
    # 1e-6 m: ten times that bound, and 5 orders of magnitude under a DEM cell (30-50 m)
    assert np.allclose(py.ecef, nb.ecef, rtol=0.0, atol=1e-6, equal_nan=True)
    assert np.allclose(py.slant_range, nb.slant_range, rtol=0.0, atol=1e-6, equal_nan=True)
    assert np.allclose(py.lat, nb.lat, rtol=0.0, atol=1e-12, equal_nan=True)  # 1e-12 rad: 6 um


@pytest.mark.parametrize("model", ["bilinear", "triangles"])
def test_python_walk_matches_kernel_on_the_crop(model, monkeypatch):
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    los = random_oblique_rays(dem, 300, np.random.default_rng(3), frame_angle_deg=(10.0, 82.0))
    py, nb = _both(los, dem, model, monkeypatch, trace=True)
    _assert_same(py, nb)
    assert (nb.status == 0).sum() > 250  # most of them hit
    # the traces too: where the ray entered each cell it stepped through (1e-6 m, as the hits)
    assert np.allclose(py.trace.ecef, nb.trace.ecef, rtol=0.0, atol=1e-6, equal_nan=True)


@pytest.mark.parametrize("climb", ["auto", "always"])
def test_python_walk_matches_kernel_grazing_and_outside(climb, monkeypatch):
    dem = _rough_dem(300, seed=7)
    rng = np.random.default_rng(11)
    monkeypatch.setattr(terrain, "CLIMB", climb)
    monkeypatch.setattr(terrain, "CLIMB_FROM", 2)
    for outside in (False, True):
        los = _grazing_and_edge_rays(dem, 150, rng, outside=outside)
        for model in ("bilinear", "triangles"):
            py, nb = _both(los, dem, model, monkeypatch)
            _assert_same(py, nb)


def test_small_calls_walk_uncompiled_whatever_the_process_compiled(monkeypatch):
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    kernel = tn._kernel_for(np.zeros((0, 4), np.int64), tn.BLOCK, False)
    assert tn._python_ok(1, 2000)  # one ray
    assert not tn._python_ok(tn.PY_WALK_MAX_RAYS + 1, 10)
    assert not tn._python_ok(2, tn.PY_WALK_MAX_WORK)  # a large DEM
    # the choice is the call's, not the process's: compiled or not, the same bits
    los = random_oblique_rays(dem, 12, np.random.default_rng(5))
    used = []
    real = tn._python_walk
    monkeypatch.setattr(tn, "_python_walk", lambda k: (used.append(k), real(k))[1])
    first = intersect_dem(los, dem, "exact")
    intersect_dem(random_oblique_rays(dem, 500, np.random.default_rng(6)), dem, "exact")  # compiles
    assert kernel.signatures or tn._kernel_for(np.zeros((0, 4), np.int64), tn.BLOCK, False).signatures
    again = intersect_dem(los, dem, "exact")
    assert len(used) == 2 and np.array_equal(first.status, again.status) and first.status[0] == 0
    assert np.array_equal(first.ecef, again.ecef, equal_nan=True)


def test_within_compiled_walk_a_small_call_takes_the_kernel(monkeypatch):
    """A fit's loop of small calls (compiled_walk) walks them compiled: the Python walk is not
    entered, and the hits are the uncompiled ones within the kernel's rounding (_assert_same)."""
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    los = random_oblique_rays(dem, 12, np.random.default_rng(5))
    used = []
    real = tn._python_walk
    monkeypatch.setattr(tn, "_python_walk", lambda k: (used.append(k), real(k))[1])
    py = intersect_dem(los, dem, "exact")
    assert len(used) == 1
    with tn.compiled_walk():
        nb = intersect_dem(los, dem, "exact")
    assert len(used) == 1  # not entered again
    _assert_same(py, nb)
    assert (nb.status == 0).sum() >= 10
    intersect_dem(los, dem, "exact")  # the block ended: small calls uncompiled again
    assert len(used) == 2


def _prefix_spy(monkeypatch):
    """A list that receives (rays walked uncompiled, rays in the call) for each walk call."""
    seen = []
    real = tn._python_prefix

    def spy(kernel, rays, grid, out, nodes):
        k = real(kernel, rays, grid, out, nodes)
        seen.append((k, len(rays.order)))
        return k

    monkeypatch.setattr(tn, "_python_prefix", spy)
    return seen


def test_within_a_budget_the_start_uncompiled_while_the_projected_cost_fits(monkeypatch):
    """uncompiled_budget: a call whose projected cost (cell steps plus PY_WALK_RAY_STEPS a ray)
    fits walks uncompiled to its end; a larger one walks chunks of PY_WALK_MAX_RAYS while the
    projection fits, then the kernel walks the rest; outside the block the same call is compiled
    from its first ray. Either way the statuses and cells are the all-compiled walk's and the hits
    within its FMA rounding (1e-6 m, as above)."""
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    los = random_oblique_rays(dem, 1000, np.random.default_rng(21))
    seen = _prefix_spy(monkeypatch)
    nb = intersect_dem(los, dem, "exact")
    assert seen == [(0, 1000)]  # no budget: compiled
    steps = int(nb.dem_evaluations.sum())
    cost = steps + tn.PY_WALK_RAY_STEPS * 1000
    assert cost < tn.PY_WALK_MAX_STEPS  # 1000 oblique rays over the crop fit the default budget
    seen.clear()
    with tn.uncompiled_budget():
        whole = intersect_dem(los, dem, "exact")
    assert seen == [(1000, 1000)]
    _assert_same(whole, nb)
    # a budget of 3.5 chunks' cost: 1000 rays cost more, so the first chunk then the kernel
    seen.clear()
    with tn.uncompiled_budget(int(cost * 3.5 * tn.PY_WALK_MAX_RAYS / 1000)):
        part = intersect_dem(los, dem, "exact")
    assert seen == [(tn.PY_WALK_MAX_RAYS, 1000)]
    _assert_same(part, nb)
    # twice the call's cost: every chunk uncompiled (no chunk's prefix is twice the mean)
    seen.clear()
    with tn.uncompiled_budget(2 * cost):
        intersect_dem(los, dem, "exact")
    assert seen == [(1000, 1000)]
    seen.clear()
    intersect_dem(los, dem, "exact")  # the block closed: compiled again
    assert seen == [(0, 1000)]


def test_serial_and_threaded_walks_give_the_same_bits(monkeypatch):
    """walk_parallel decides the uncompiled start once for the whole call, as walk does, so the
    threads change nothing: bit for bit, for a call walked wholly uncompiled and for one whose
    start only is (within a budget)."""
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    for n in (2000, 30000):
        los = random_oblique_rays(dem, n, np.random.default_rng(n))
        seen = _prefix_spy(monkeypatch)
        with tn.uncompiled_budget():
            a = intersect_dem(los, dem, "exact", parallel=False)
            b = intersect_dem(los, dem, "exact", parallel=True)
        monkeypatch.undo()
        assert seen[0] == seen[1] and len(seen) == 2, seen  # one decision, the same, each way
        assert (seen[0][0] == n) == (n == 2000) and seen[0][0] >= tn.PY_WALK_MAX_RAYS
        assert np.array_equal(a.status, b.status) and np.array_equal(a.dem_evaluations, b.dem_evaluations)
        assert np.array_equal(a.ecef, b.ecef, equal_nan=True)
        assert np.array_equal(a.slant_range, b.slant_range, equal_nan=True)


def test_python_walk_failure_falls_back_to_the_kernel_with_the_inputs_restored(monkeypatch):
    """Where Python's arithmetic raises (int(nan), a sqrt of a negative, an index past an end)
    and numba's does not, the kernel walks the call: from the status the caller gave, not the
    one the Python walk had half written."""
    dem = DEM.open(asset_path("dem", "srtm_jacksboro.tif"))
    los = random_oblique_rays(dem, 20, np.random.default_rng(9))
    monkeypatch.setattr(tn, "_python_ok", lambda n, nodes: False)
    nb = intersect_dem(los, dem, "exact")

    def broken(kernel):
        def run(*a):
            status = a[-4]
            status[:] = 99  # scribbled on, then a failure
            a[-7][:] = -1.0
            raise ValueError("math domain error")

        return run

    monkeypatch.setattr(tn, "_python_ok", lambda n, nodes: True)
    monkeypatch.setattr(tn, "_python_walk", broken)
    fb = intersect_dem(los, dem, "exact")
    assert np.array_equal(fb.status, nb.status)
    assert np.array_equal(fb.ecef, nb.ecef, equal_nan=True)
