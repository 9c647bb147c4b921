"""The first run: numba's compiled kernels cached where a reinstall keeps them
(the user's cache folder, or NUMBA_CACHE_DIR when set), the first compile said once on
stderr, and ``geoloc warm`` compiling ahead. Timings are in benchmarks/bench_first_run.py.

Each probe is a new Python process (numba reads NUMBA_CACHE_DIR when it is imported) on a
scratch copy of the package, compiling one small kernel (``_nbgeo.geodetic``, ~1 s)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROBE = r"""
import json, sys
from geoloc.geodesy import _nbgeo
lat, lon, h = _nbgeo.geodetic(6378137.0 + 100.0, 0.0, 0.0)
print(json.dumps({"h": h, "compiled": [n for n, _ in _nbgeo.COMPILED], "dir": str(_nbgeo.cache_dir()),
                  "cache_path": _nbgeo.geodetic._cache.cache_path}))
"""


def _copy_package(dst: Path) -> Path:
    shutil.copytree(ROOT / "geoloc", dst / "geoloc", ignore=shutil.ignore_patterns("__pycache__"))
    return dst


def _probe(src: Path, home: Path, **env_extra) -> tuple[dict, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "GEOLOC_ANNOUNCE_COMPILE")}
    env.update(PYTHONPATH=str(src), HOME=str(home), XDG_CACHE_HOME=str(home / "xdg-cache"), **env_extra)
    r = subprocess.run([sys.executable, "-c", PROBE], cwd=src, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def test_kernels_cached_in_the_user_cache_folder_and_kept_by_a_reinstall(tmp_path):
    src, home = _copy_package(tmp_path / "site"), tmp_path / "home"
    out, err = _probe(src, home, GEOLOC_ANNOUNCE_COMPILE="1")
    want = home / "xdg-cache" / "geoloc" / "numba"
    assert out["h"] == pytest.approx(100.0, abs=1e-6)  # on the equator, 100 m above the ellipsoid
    assert out["dir"] == str(want) and Path(out["cache_path"]).is_relative_to(want)
    assert "geodetic" in out["compiled"]
    assert list(want.rglob("_nbgeo.geodetic-*.nbi")), sorted(want.rglob("*"))
    assert not list((src / "geoloc").rglob("*.nbi"))  # nothing in the package's own folders
    # said once, naming the folder
    assert err.count("geoloc: compiling the terrain and camera kernels once") == 1, err
    assert f"cached in {want}" in err
    # a reinstall: the package deleted and copied afresh (new files, new times) at the same place
    shutil.rmtree(src / "geoloc")
    _copy_package(src)
    out2, err2 = _probe(src, home, GEOLOC_ANNOUNCE_COMPILE="1")
    assert out2["compiled"] == [] and "compiling" not in err2, (out2, err2)  # loaded, not compiled
    # an edited source compiles afresh (numba stamps the index with the file's SHA-256)
    f = src / "geoloc" / "geodesy" / "_nbgeo.py"
    f.write_text(f.read_text() + "\n# edited\n")
    out3, _ = _probe(src, home)
    assert "geodetic" in out3["compiled"]


def test_numba_cache_dir_wins_when_set(tmp_path):
    src, home, user = _copy_package(tmp_path / "site"), tmp_path / "home", tmp_path / "mine"
    out, err = _probe(src, home, NUMBA_CACHE_DIR=str(user))
    assert out["dir"] == str(user) and Path(out["cache_path"]).is_relative_to(user)
    assert list(user.rglob("_nbgeo.geodetic-*.nbi")) and not (home / "xdg-cache").exists()
    assert "compiling" not in err  # not a terminal and not asked: silent (pipes, tests, logs)


def test_geoloc_warm_prints_each_step(capsys):
    from geoloc.cli import main

    assert main(["warm", "--skip-view"]) == 0
    out = capsys.readouterr().out
    assert "geoloc warm: compiling what locate, replay and view need, once; cache:" in out
    for what in (
        "geoloc locate --sensor eo_turret.toml --dem srtm_jacksboro.tif",
        "geoloc replay drone_targets.csv",
        "geoloc replay example_flight.klv",
        "the terrain walk of a large batch: 20 000 rays",
    ):
        line = next(x for x in out.splitlines() if what in x)
        assert ("nothing to compile" in line or "compiled" in line) and "s CPU)" in line, line
    assert "geoloc view --export" not in out and "geoloc warm: done in" in out


def test_run_sh_warms_before_it_serves():
    text = (ROOT / "tools" / "run.sh").read_text().splitlines()
    warm = next(i for i, x in enumerate(text) if x.strip().startswith('"$VENV/bin/geoloc" warm'))
    view = next(i for i, x in enumerate(text) if 'geoloc" view' in x)
    assert warm < view


PROBE_SCENE = r"""
import json
from geoloc.geodesy import _nbgeo
from geoloc_viz.flight_model import build, default_flight_scenario
m = build(default_flight_scenario())
print(json.dumps({"frames": len(m), "compiled": [n for n, _ in _nbgeo.COMPILED]}))
"""


def test_the_viewers_first_scene_compiles_no_walk(tmp_path):
    """The viewer's first scene starts without a compile: the example flight's model (the first scene's 5364 footprint rays and 110 centre
    and record rays) walks uncompiled on a cold cache: no walk kernel is compiled for it
    (terrain_numba.PY_WALK_MAX_STEPS); bench_first_run.py times it."""
    env = {k: v for k, v in os.environ.items() if k != "GEOLOC_ANNOUNCE_COMPILE"}
    env.update(PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path / "cold"))  # this tree, an empty cache
    r = subprocess.run(
        [sys.executable, "-c", PROBE_SCENE], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["frames"] == 298
    assert not [n for n in out["compiled"] if "walk" in n], out["compiled"]
