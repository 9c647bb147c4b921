"""Build step that puts the bundled data inside the package.

All metadata is in ``pyproject.toml``; this file only extends ``build_py``. The
repository keeps its data in the top-level ``assets/`` folder (the one source);
a wheel must carry it inside the package, so ``build_py`` copies ``assets/`` to
``<build>/geoloc/_assets/``, which :mod:`geoloc.assets` reads through
``importlib.resources``. An editable install (``pip install -e .``) runs from the
checkout and reads ``assets/`` in place, so nothing is copied for it. The sdist
carries ``assets/`` (``MANIFEST.in``), so a wheel built from the sdist gets it too.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "assets"
TARGET = ("geoloc", "_assets")


class build_py_with_assets(build_py):
    """``build_py``, then ``assets/`` copied to ``geoloc/_assets`` in the build folder."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        if not SOURCE.is_dir():
            raise FileNotFoundError(
                f"{SOURCE}: the bundled data folder is missing; build from a whole checkout or sdist"
            )
        dst = Path(self.build_lib).joinpath(*TARGET)
        shutil.rmtree(dst, ignore_errors=True)  # no stale files from an earlier build
        shutil.copytree(SOURCE, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))

    def get_outputs(self, include_bytecode=True):
        out = list(super().get_outputs(include_bytecode))
        if SOURCE.is_dir() and not getattr(self, "editable_mode", False):
            base = Path(self.build_lib).joinpath(*TARGET)
            out += [str(base / p.relative_to(SOURCE)) for p in SOURCE.rglob("*") if p.is_file()]
        return out


setup(cmdclass={"build_py": build_py_with_assets})
