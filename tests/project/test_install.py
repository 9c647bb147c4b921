"""Both wheels work anywhere: build them, install them into new virtual environments, run them elsewhere.

The core (``geoloc``, ``pip install .``) and the viewer (``geoloc-viz``, ``pip install ./viz``)
are two packages (docs/architecture.md, "Two packages"). Here:

1. the project's packaging files, ``geoloc/``, ``viz/`` and ``assets/`` are copied to a
   temporary folder (so a build never writes ``build/`` into the working tree) and both
   wheels are built there, offline: ``pip wheel --no-deps --no-build-isolation`` (the build
   backend is the running environment's setuptools, a test dependency);
2. **the core alone, from the package registry**: a new virtual environment gets the core
   wheel and the dependencies it declares, resolved by pip as a user's ``pip install .``
   would. None of the viewer's libraries, nor the extras', is importable there, and
   ``locate``, ``replay``, ``report`` and ``export`` run; ``view`` and a video input each say
   in one line what to install;
3. **both wheels, from the package registry**: the same environment then gets both wheels, as
   a user who adds the viewer to a core install does (``pip install . ./viz``): pip resolves
   every dependency the two declare against the registry and installs what the core's install
   lacks, so the viewer's own declared dependencies (viser, rerun, and the core's ``mesh`` and
   ``video`` extras) are the ones it runs with, and the wheels' packages are the ones imported
   (checked). One environment, not two: the registry's wheels of the core's dependencies
   (numpy, scipy, numba, rasterio, matplotlib, pyarrow ...) are downloaded once, not twice (this
   machine's pip keeps no HTTP cache, so every install downloads them: ``pip download`` of the
   core's took 99 s of the 116 s of its install, load 11-15), one ``python -m venv`` (ensurepip:
   39 s at load 12) is made, and the kernels the core's commands compiled in the installed copy
   are not compiled again. The core-alone tests run first (the file's order); one run after the
   viewer was added fails and says so;
Marked ``install`` (``pytest -m install`` selects it, ``-m "not install"`` skips it); it
runs in the normal suite (its time: docs/testing.md, "The suite's time").
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

# one worker builds the wheels and the two environments once (the fixtures are per module, so
# tests spread over two xdist workers would each install them)
pytestmark = [pytest.mark.install, pytest.mark.xdist_group("install")]

ROOT = Path(__file__).resolve().parents[2]
PACKAGING = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md")
#: Libraries a core install must not have: the viewer's and the extras' (pyproject.toml)
NOT_IN_CORE = ("viser", "rerun", "trimesh", "geoloc_viz", "av", "cv2", "dask", "distributed", "pyarrow", "astropy")
#: pip's options for the two environments. ``--no-compile``: pip byte-compiles every file of every
#: installed library (numpy, scipy, numba, rasterio, matplotlib, viser, rerun ...), 13.5 s of the 25 s
#: of CPU of the core's install here (``time pip install`` with and without it); what gets installed,
#: and how pip resolves it, is the same, and Python compiles the modules the tests import as it imports
#: them (the tests' first commands take longer: this file 523 s -> 465 s at load 13-18, both setups
#: 395 s -> 261 s, the calls 110 s -> 176 s).
PIP_INSTALL = ("-q", "--no-compile")
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc", "*.egg-info")


def _run(cmd, cwd, env=None, timeout=600):
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def wheels(tmp_path_factory):
    """(core wheel, viewer wheel), built from a copy of the checkout."""
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    for name in PACKAGING:
        shutil.copy2(ROOT / name, src / name)
    for folder in ("geoloc", "assets", "viz"):
        shutil.copytree(ROOT / folder, src / folder, ignore=IGNORE)
    for where in (src, src / "viz"):
        _run(
            [
                sys.executable,
                "-m",
                "pip",
                "wheel",
                "--no-deps",
                "--no-build-isolation",
                "--no-index",
                "-q",
                "-w",
                base / "dist",
                where,
            ],
            cwd=base,
        )
    (core,) = (base / "dist").glob("geoloc-*.whl")
    (viz,) = (base / "dist").glob("geoloc_viz-*.whl")
    return core, viz


def _clean_env(env_dir: Path, work: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("GEOLOC_ASSETS", "PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = f"{env_dir / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    return env


@pytest.fixture(scope="module")
def _env(wheels, tmp_path_factory):
    """One new environment, the core wheel alone installed; ``venv`` adds the viewer's wheel."""
    base = tmp_path_factory.mktemp("env")
    env_dir = base / "env"
    _run([sys.executable, "-m", "venv", env_dir], cwd=base)
    env = _clean_env(env_dir, base)
    py = env_dir / "bin" / "python"
    _run([py, "-m", "pip", "install", *PIP_INSTALL, wheels[0]], cwd=base, env=env, timeout=900)
    return dict(py=py, bin=env_dir / "bin", base=base, env=env, installed=["core"])


@pytest.fixture
def core_venv(_env):
    """The core wheel alone, its declared dependencies resolved by pip (a user's ``pip install .``)."""
    assert _env["installed"] == ["core"], (
        "a core-alone test ran after the viewer's wheel was added to the environment: "
        "run the core-alone tests first (this file's order)"
    )
    work = _env["base"] / "elsewhere-core"  # outside the repository, no assets/ here
    work.mkdir(exist_ok=True)
    return dict(_env, work=work)


@pytest.fixture(scope="module")
def venv(_env, wheels):
    """Both wheels, their declared dependencies resolved by pip (a user's ``pip install . ./viz``
    over the core's install)."""
    py, base, env = _env["py"], _env["base"], _env["env"]
    _run([py, "-m", "pip", "install", *PIP_INSTALL, *wheels], cwd=base, env=env, timeout=900)
    _env["installed"] = ["core", "viewer"]
    purelib = _run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=base).stdout.strip()
    work = base / "elsewhere"  # outside the repository, no assets/ here
    work.mkdir()
    return dict(_env, purelib=Path(purelib), work=work)


def geoloc(venv, *args, timeout=600):
    return _run([venv["bin"] / "geoloc", *args], cwd=venv["work"], env=venv["env"], timeout=timeout)


def test_the_wheels_carry_the_data_and_the_type_marker(wheels):
    names = set(zipfile.ZipFile(wheels[0]).namelist())
    for f in (ROOT / "assets").rglob("*"):
        if f.is_file():
            assert f"geoloc/_assets/{f.relative_to(ROOT / 'assets').as_posix()}" in names, f
    assert "geoloc/py.typed" in names
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"geoloc"}  # the core alone, no viewer
    assert not any(n.startswith(("assets/", "viz/", "geoloc_viz/", "tests/")) for n in names)
    viz = zipfile.ZipFile(wheels[1])
    assert {n.split("/")[0] for n in viz.namelist() if ".dist-info" not in n} == {"geoloc_viz"}
    meta = viz.read(next(n for n in viz.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    requires = [line.split(": ", 1)[1] for line in meta.splitlines() if line.startswith("Requires-Dist: ")]
    # the same release's core, with the extras the viewer runs (meshes; video frames and their marks)
    assert any(r.replace(" ", "").startswith("geoloc[mesh,video]==") for r in requires), requires
    assert {"viser", "rerun-sdk"} <= {re.split(r"[<>=\[ ;]", r)[0] for r in requires}
    eps = viz.read(next(n for n in viz.namelist() if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "[geoloc.verbs]" in eps and "view = geoloc_viz.cli.view" in eps and "log = geoloc_viz.cli.log" in eps


def core(venv, *args):
    return subprocess.run(
        [str(venv["bin"] / "geoloc"), *map(str, args)],
        cwd=venv["work"],
        env=venv["env"],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_the_core_alone_has_none_of_the_viewers_libraries(core_venv):
    code = "import importlib.util as u; print(' '.join(m for m in %r if u.find_spec(m)))" % (NOT_IN_CORE,)
    found = _run([core_venv["py"], "-c", code], cwd=core_venv["work"], env=core_venv["env"]).stdout.strip()
    assert found == "", f"a core install brought {found}"


def test_the_core_alone_locates_replays_reports_and_exports(core_venv):
    # docs/tour_cli.md's one-pixel example: aircraft at 18 km, the target on the ellipsoid at 0 m
    # docs/tour_cli.md's one-pixel example, Table 1 of [Q17]: 35.57709 N, 80.84918 E as published
    r = core(
        core_venv,
        "locate",
        "--lat-deg",
        "35.48",
        "--lon-deg",
        "80.97",
        "--h-m",
        "18000",
        "--heading-deg",
        "45",
        "--pitch-deg",
        "3.5",
        "--gimbal-roll-deg",
        "50",
        "--gimbal-pitch-deg",
        "-2.6",
        "--target-h-m",
        "5083.5",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    # the paper prints 5 decimals: half a unit of the last one is the tolerance
    assert abs(out["lat_deg"] - 35.57709) < 5e-6 and abs(out["lon_deg"] - 80.84918) < 5e-6, out
    r = core(core_venv, "replay", "--height-column", "paper_height_m", "--out", "r.csv")
    assert r.returncode == 0, r.stderr
    assert "all: RMS distance to the published positions 0.36 m over 20 records" in r.stdout
    r = core(core_venv, "report", "r.csv", "--out", "report")
    assert r.returncode == 0, r.stderr
    assert (core_venv["work"] / "report" / "report.html").is_file()
    r = core(core_venv, "export", "r.csv", "--out", "r.gpkg")
    assert r.returncode == 0, r.stderr
    assert (core_venv["work"] / "r.gpkg").stat().st_size > 0


def test_the_core_alone_names_what_to_install(core_venv):
    r = core(core_venv, "view")
    assert r.returncode == 2 and "pip install ./viz" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1  # one line, no traceback
    r = core(core_venv, "log", "flight_scan", "--out", "x.rrd")
    assert r.returncode == 2 and "pip install ./viz" in r.stderr, r.stderr
    r = core(core_venv, "klv", "dump", "assets/klv/example_flight.ts")
    assert r.returncode == 2 and "geoloc[video]" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "view" in core(core_venv, "--help").stdout  # still listed


def test_installed_package_reads_its_own_data(venv):
    code = (
        "import geoloc, geoloc.assets as a, geoloc_viz, numpy as np;"
        "from geoloc.geodesy.geoid import GEOID_DIR, egm96_undulation;"
        "print(geoloc.__file__); print(a.ASSETS); print(a.ASSETS_SOURCE); print(GEOID_DIR);"
        "print(round(float(egm96_undulation(np.deg2rad(35.58), np.deg2rad(80.85))), 2))"
    )
    out = _run([venv["py"], "-c", code], cwd=venv["work"], env=venv["env"]).stdout.split("\n")
    pkg = venv["purelib"] / "geoloc"
    assert Path(out[0]).parent == pkg
    assert Path(out[1]) == pkg / "_assets" and out[2] == "package data"
    assert Path(out[3]) == pkg / "_assets" / "geoid"
    assert out[4] == "-26.79"
    assert (pkg / "py.typed").is_file()
    assert not (venv["work"] / "assets").exists()


def test_reproduce_qiao2017(venv):
    text = geoloc(venv, "reproduce", "qiao2017", "--samples", "2000", "--sweep-samples", "300").stdout
    assert "35.57709 N  80.84918 E" in text  # Table 1 nominal point, as published
    assert "RMS distance to the published positions 0.36 m" in text


def test_replay_on_the_bundled_records(venv):
    text = geoloc(venv, "replay", "--height-column", "paper_height_m").stdout
    assert "T3-1 " in text and "all: RMS distance to the published positions 0.36 m over 20 records" in text
    # the docs' form, a path under assets/, from a folder that has none
    text = geoloc(
        venv,
        "replay",
        "assets/records/qiao2017_flight_tests.csv",
        "--camera",
        "assets/cameras/qiao2017.toml",
        "--height-column",
        "paper_height_m",
        "--out",
        "out.csv",
    ).stdout
    assert "wrote 20 rows to out.csv" in text and "T3-1 " not in text
    assert len((venv["work"] / "out.csv").read_text().splitlines()) == 21


def test_dem_run_with_the_egm96_datum(venv):
    text = geoloc(
        venv,
        "replay",
        "--dem",
        "assets/dem/etopo5_flight_area.tif",
        "--dem-datum",
        "egm96",
        "--method",
        "exact",
        "--out",
        "dem.csv",
    ).stdout
    # docs/tour_terrain.md: over the ETOPO5 crop the targets land 521 m RMS from the paper's positions
    assert "all: RMS distance to the published positions 521.1" in text
    rows = (venv["work"] / "dem.csv").read_text().splitlines()
    assert len(rows) == 21 and "dem_evaluations" in rows[0]


def test_view_export(venv):
    # the default scene: the bundled KLV example flight (its .klv and the SRTM crop come from the wheel)
    r = geoloc(venv, "view", "--export", "x.html", timeout=900)
    assert r.stdout.strip() == "wrote x.html"
    page = (venv["work"] / "x.html").read_text()
    assert 'id="geoloc-summary"' in page and "example_flight.klv: frame " in page and "srtm_jacksboro" in page
    assert len(page) > 100_000  # the scene itself is in the file
