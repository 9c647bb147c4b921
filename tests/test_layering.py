"""The core never imports the visualisation stack: viz/ depends on geoloc/, not the reverse."""

import pkgutil
import subprocess
import sys

import geoloc


def test_core_modules_import_no_viser_rerun_or_viz():
    core = [m.name for m in pkgutil.walk_packages(geoloc.__path__, "geoloc.")
            if not m.name.startswith(("geoloc.commands", "geoloc.__main__"))]
    code = (
        "import importlib, sys\n"
        f"for m in {core!r}: importlib.import_module(m)\n"
        "bad = sorted(k for k in sys.modules if k.split('.')[0] in ('viser', 'rerun', 'viz'))\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"core pulled in: {r.stdout.strip()}"
    assert len(core) >= 15  # the walk really found the core modules
