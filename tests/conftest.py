"""Fixtures shared by several test modules."""

import inspect
import os
import types

import pytest

# geoloc caches its compiled kernels in the user's cache folder (geoloc.geodesy._nbgeo.cache_dir),
# found from HOME: tests that start geoloc with HOME pointed at a temporary folder (for rerun,
# Chromium) would compile every kernel afresh there. One cache for the whole session: numba reads
# NUMBA_CACHE_DIR when it is imported, in this process and in every child (tests/cli/test_first_run.py
# takes it out for the probes that check the default).
os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "geoloc", "numba"),
)


@pytest.fixture(scope="module")
def rerun_home(tmp_path_factory):
    """rerun (and its analytics) write under ~/.config and ~/.local/share: point HOME and
    the XDG directories at a temp dir for the module's tests."""
    d = tmp_path_factory.mktemp("home")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HOME", str(d))
        mp.setenv("XDG_CONFIG_HOME", str(d / ".config"))
        mp.setenv("XDG_DATA_HOME", str(d / ".local" / "share"))
        yield d


def pytest_configure(config):
    # GEOLOC_TEST_TIMELOG=FILE: the controller logs every test phase there (tools/suite_time.py
    # summarises the log; docs/testing.md, "The suite's time"); the workers send it their reports
    # taken out of the environment: a pytest a test starts (tests/project/test_suite_time.py) logs
    # elsewhere or not at all, never into this run's log
    path = os.environ.pop("GEOLOC_TEST_TIMELOG", None)
    if path and not hasattr(config, "workerinput"):
        import importlib.util
        import sys
        from pathlib import Path

        tool = Path(__file__).resolve().parents[1] / "tools" / "suite_time.py"
        spec = importlib.util.spec_from_file_location("geoloc_suite_time", tool)
        mod = sys.modules["geoloc_suite_time"] = importlib.util.module_from_spec(spec)  # for its dataclasses
        spec.loader.exec_module(mod)
        config.pluginmanager.register(mod.TimeLog(path), "geoloc_suite_time")


#: Set for each test's run by pytest_runtest_setup: "1" in the Chromium group, "0" outside it;
#: ``tests.test_viz_browser.chromium`` refuses to launch under "0" (a browser test the static
#: look-up below missed would otherwise run beside another browser on the other worker).
CHROMIUM_GROUP_ENV = "GEOLOC_CHROMIUM_GROUP"


def _code_names(code):
    """Global and attribute names a code object uses, with those of its nested functions,
    lambdas and comprehensions."""
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _code_names(c)
    return names


def _opens_chromium(fn, seen) -> bool:
    """Whether ``fn`` launches headless Chromium: it names ``chromium`` (tests/viz/test_viz_browser.py's
    launcher, imported at module level or inside the function), or calls a function of a test
    module that does (a helper such as test_viz_labels' ``_check``), followed to any depth."""
    fn = inspect.unwrap(fn)
    if not isinstance(fn, types.FunctionType) or fn in seen:
        return False
    seen.add(fn)
    names = _code_names(fn.__code__)
    if "chromium" in names:
        return True
    for name in names:
        obj = fn.__globals__.get(name)
        if (
            isinstance(obj, types.FunctionType)
            and getattr(obj, "__name__", None) == "chromium"
            and "test_viz_browser" in (obj.__module__ or "")
        ):
            return True  # imported under another name
        mod = getattr(inspect.unwrap(obj), "__module__", None) if callable(obj) else None
        if mod and mod.rpartition(".")[2].startswith(("test_", "conftest")) and _opens_chromium(obj, seen):
            return True
    return False


def _item_opens_chromium(item) -> bool:
    fns = [getattr(item, "function", None)]
    info = getattr(item, "_fixtureinfo", None)
    for defs in info.name2fixturedefs.values() if info is not None else ():
        fns += [d.func for d in defs]
    seen: set = set()
    return any(f is not None and _opens_chromium(f, seen) for f in fns)


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's own, which renames the grouped tests
def pytest_collection_modifyitems(config, items):
    """Every test that opens headless Chromium (its own code, a helper it calls or a fixture it
    uses: ``_opens_chromium``) runs on one pytest-xdist worker (``tools/test.sh`` runs ``-n 3
    --dist loadgroup``): two software-WebGL browsers at once on a 2-core machine made 60 s waits
    for the first view fail, while one browser beside one CPU-bound worker holds. The other tests
    of the same modules run on either worker. Those tests are also marked ``browser``
    (``pytest -m browser`` runs them). Without xdist the group mark is inert."""
    for item in items:
        if _item_opens_chromium(item):
            item.add_marker(pytest.mark.xdist_group("chromium"))
            item.add_marker(pytest.mark.browser)


def in_chromium_group(item) -> bool:
    return any(m.args[:1] == ("chromium",) for m in item.iter_markers("xdist_group"))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    # before the item's fixtures: a module fixture that opened Chromium is caught too
    os.environ[CHROMIUM_GROUP_ENV] = "1" if in_chromium_group(item) else "0"
    if not in_chromium_group(item):
        _close_shared_chromium()  # the group's tests are done on this worker (they run as one batch)
    if (
        in_chromium_group(item)
        and os.environ.get("PYTEST_XDIST_WORKER")
        and item.config.getvalue("loadgroup")
        and not item.nodeid.endswith("@chromium")
    ):
        # pytest-xdist groups a test by renaming it NODEID@GROUP; when that rename does not take (pytest 9
        # with xdist 3.8) the group's tests are spread over the workers and browsers run side by side
        pytest.fail(
            f"{item.nodeid}: pytest-xdist did not put this test in its group 'chromium' (pytest "
            f"{pytest.__version__}; pyproject.toml's test extras pin the pytest that groups)",
            pytrace=False,
        )


#: The kernels each process of the run compiled (a cold cache): {worker: [(kernel, CPU s), ...]}.
_COMPILED: dict = {}


def _compiled_here() -> list:
    import sys

    nbgeo = sys.modules.get("geoloc.geodesy._nbgeo")  # only if a test imported it
    return [list(c) for c in getattr(nbgeo, "COMPILED", [])]


def _close_shared_chromium() -> None:
    """Close the browser the Chromium group's tests shared (tests/viz/test_viz_browser.py), if one is open."""
    import sys

    mod = sys.modules.get("test_viz_browser")
    if mod is not None and getattr(mod, "_SHARED", None):
        mod.close_shared_chromium()


def pytest_sessionfinish(session):
    os.environ.pop(CHROMIUM_GROUP_ENV, None)
    _close_shared_chromium()
    worker = getattr(session.config, "workeroutput", None)
    if worker is not None:  # a pytest-xdist worker: its compiles go to the controller
        worker["geoloc_compiled"] = _compiled_here()
    else:
        _COMPILED["main"] = _compiled_here()


def pytest_testnodedown(node, error):
    _COMPILED[getattr(node, "gateway", None) and node.gateway.id or "worker"] = node.workeroutput.get(
        "geoloc_compiled", []
    )


@pytest.hookimpl(trylast=True)  # after pytest's --durations table (tools/test.sh): the run's last lines
def pytest_terminal_summary(terminalreporter):
    # where a cold numba cache's time goes: a fresh machine compiles every kernel the tests call
    # (geoloc.geodesy._nbgeo.COMPILED); nothing is printed on a warm cache
    done = {w: c for w, c in _COMPILED.items() if c}
    if not done:
        return
    names = [k for c in done.values() for k in {k for k, _t in c}]  # each process's kernels, once
    twice = sorted({k for k in names if names.count(k) > 1})
    terminalreporter.write_line(
        "numba kernels compiled (cold cache): "
        + "; ".join(f"{w} {len(c)} in {sum(t for _k, t in c):.0f} s CPU" for w, c in sorted(done.items()))
        + " (a kernel's time includes the kernels it calls that compiled with it)"
        + (f"; in more than one process: {', '.join(twice)}" if twice else "")
    )
