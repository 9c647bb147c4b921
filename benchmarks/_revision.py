"""A module's source at another git revision, loaded as a scratch module (for the A/B benchmarks)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def module_at(rev: str, relpath: str):
    """``relpath`` (e.g. ``geoloc/sensors/_fastlocate.py``) as it is at git revision ``rev``, imported
    under a scratch name; numba compiles its kernels afresh in this process (their cache key reads
    the scratch file)."""
    src = subprocess.run(["git", "show", f"{rev}:{relpath}"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp(prefix="bench_ab_")) / f"{Path(relpath).stem}_{rev.replace('/', '_')}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod  # dependency_key reads the module's file
    spec.loader.exec_module(mod)
    return mod
