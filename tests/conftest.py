"""Fixtures shared by several test modules."""

import os
from pathlib import Path

import pytest

# geoloc caches its compiled kernels in the user's cache folder (geoloc.geodesy._nbgeo.cache_dir),
# found from HOME: tests that start geoloc with HOME pointed at a temporary folder (for rerun,
# Chromium) would compile every kernel afresh there. One cache for the whole session: numba reads
# NUMBA_CACHE_DIR when it is imported, in this process and in every child (tests/test_first_run.py
# takes it out for the probes that check the default).
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.environ.get("XDG_CACHE_HOME")
                                                      or os.path.expanduser("~/.cache"), "geoloc", "numba"))


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


def pytest_collection_modifyitems(config, items):
    """Every test of a module that opens headless Chromium runs on one pytest-xdist worker
    (``tools/test.sh`` runs ``-n 2 --dist loadgroup``): two software-WebGL browsers at once on a
    2-core machine made 60 s waits for the first view fail, while one browser beside one CPU-bound
    worker holds. Without xdist the group mark is inert."""
    opens_chromium: dict[str, bool] = {}
    for item in items:
        path = str(item.path)
        if path not in opens_chromium:
            opens_chromium[path] = "chromium(" in Path(path).read_text(encoding="utf-8")
        if opens_chromium[path]:
            item.add_marker(pytest.mark.xdist_group("chromium"))
