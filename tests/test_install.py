"""The wheel works anywhere: build it, install it into a new virtual environment, run it elsewhere.

Issue 15: a wheel used to hold only ``.py`` files, so an installed ``geoloc`` found none
of its bundled data. Here:

1. the project's packaging files, ``geoloc/`` and ``assets/`` are copied to a temporary
   folder (so a build never writes ``build/`` into the working tree) and the wheel is
   built there, offline: ``pip wheel --no-deps --no-build-isolation`` (the build backend
   is the running environment's setuptools, a test dependency);
2. a new virtual environment (no pip in it, no access to the checkout) gets the wheel,
   installed by this environment's pip (``pip --python``) with ``--no-deps``; the
   dependencies (numpy, rasterio, numba, viser, ...) are *not* reinstalled: a ``.pth``
   file added after the install points at this environment's site-packages. That
   folder also holds this environment's editable ``geoloc``, but a ``.pth`` line only
   appends a folder to ``sys.path`` (the editable finder's own ``.pth`` is not run), and
   the wheel's ``geoloc`` comes first: the test checks it is the one imported;
3. from a folder outside the repository, with ``GEOLOC_ASSETS`` unset, the new
   environment's ``geoloc`` command runs ``reproduce qiao2017``, ``replay`` on the bundled
   records, ``replay`` on the bundled ETOPO5 DEM with the EGM96 datum, and
   ``view --export``, and the outputs are checked against the figures the README gives.

Marked ``install`` (``pytest -m install`` selects it, ``-m "not install"`` skips it); it
runs in the normal suite (about 40 s on this machine).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.install

ROOT = Path(__file__).resolve().parents[1]
PACKAGING = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md")
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc", "*.egg-info")


def _run(cmd, cwd, env=None, timeout=600):
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                       timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    for name in PACKAGING:
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(ROOT / "geoloc", src / "geoloc", ignore=IGNORE)
    shutil.copytree(ROOT / "assets", src / "assets", ignore=IGNORE)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "-q", "-w", base / "dist", src], cwd=base)
    (whl,) = (base / "dist").glob("geoloc-*.whl")
    return whl


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory):
    base = tmp_path_factory.mktemp("venv")
    env_dir = base / "env"
    _run([sys.executable, "-m", "venv", "--without-pip", env_dir], cwd=base)
    py = env_dir / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q",
          wheel], cwd=base)
    purelib = _run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                   cwd=base).stdout.strip()
    # the dependencies: this environment's site-packages, appended after the wheel's own
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    Path(purelib, "zz_geoloc_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    work = base / "elsewhere"  # outside the repository, no assets/ here
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("GEOLOC_ASSETS", "PYTHONPATH",
                                                             "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = f"{env_dir / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    return dict(py=py, bin=env_dir / "bin", purelib=Path(purelib), work=work, env=env)


def geoloc(venv, *args, timeout=600):
    return _run([venv["bin"] / "geoloc", *args], cwd=venv["work"], env=venv["env"], timeout=timeout)


def test_the_wheel_carries_the_data_and_the_type_marker(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for f in (ROOT / "assets").rglob("*"):
        if f.is_file():
            assert f"geoloc/_assets/{f.relative_to(ROOT / 'assets').as_posix()}" in names, f
    assert "geoloc/py.typed" in names
    assert any(n.startswith("geoloc/viz/") for n in names)
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"geoloc"}  # one package, no viz/
    assert not any(n.startswith(("assets/", "viz/", "tests/")) for n in names)


def test_installed_package_reads_its_own_data(venv):
    code = (
        "import geoloc, geoloc.assets as a, geoloc.viz, numpy as np;"
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
    # the README's form, a path under assets/, from a folder that has none
    text = geoloc(venv, "replay", "assets/records/qiao2017_flight_tests.csv", "--camera",
                  "assets/cameras/qiao2017.toml", "--height-column", "paper_height_m",
                  "--out", "out.csv").stdout
    assert "wrote 20 rows to out.csv" in text and "T3-1 " not in text
    assert len((venv["work"] / "out.csv").read_text().splitlines()) == 21


def test_dem_run_with_the_egm96_datum(venv):
    text = geoloc(venv, "replay", "--dem", "assets/dem/etopo5_flight_area.tif", "--dem-datum", "egm96",
                  "--method", "exact", "--out", "dem.csv").stdout
    # README: over the ETOPO5 crop the targets land 521 m RMS from the paper's positions
    assert "all: RMS distance to the published positions 521.1" in text
    rows = (venv["work"] / "dem.csv").read_text().splitlines()
    assert len(rows) == 21 and "dem_evaluations" in rows[0]


def test_view_export(venv):
    # the default scene: the bundled KLV example flight (its .klv and the SRTM crop come from the wheel)
    r = geoloc(venv, "view", "--export", "x.html", timeout=900)
    assert r.stdout.strip() == "wrote x.html"
    page = (venv["work"] / "x.html").read_text()
    assert 'id="geoloc-summary"' in page and "example_flight.klv packet" in page and "srtm_jacksboro" in page
    assert len(page) > 100_000  # the scene itself is in the file
