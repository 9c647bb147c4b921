"""Fixtures shared by several test modules."""

import pytest


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
