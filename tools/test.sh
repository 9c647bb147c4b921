#!/usr/bin/env bash
# The README's test command: installs everything a fresh Debian machine lacks
# (Debian chromium and proj-data for the tests, a virtual environment with the
# project and its test dependencies from the package registry) and runs pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
# Debian packages: chromium (browser tests) and proj-data (the full EGM96 15' grid, which
# the geoid tests measure the bundled 30' copy against)
PKGS=""
command -v chromium >/dev/null 2>&1 || PKGS="$PKGS chromium"
[ -f /usr/share/proj/egm96_15.gtx ] || PKGS="$PKGS proj-data"
if [ -n "$PKGS" ]; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $PKGS >/dev/null
fi
VENV="${GEOLOC_VENV:-.venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e ".[test]" -e ./viz
# Byte code: where PYTHONDONTWRITEBYTECODE is set (this machine) no .pyc is ever kept, so every
# Python process compiled what it imports from source: each worker geoloc, geoloc_viz and pytest's
# assertion rewrite of the ~250 test modules (`pytest --collect-only`: 33.4 s of user CPU without
# the .pyc files, 11.6 s with them), each `geoloc` subprocess of the suite geoloc's modules again
# (`import geoloc_viz.app, geoloc.cli`: median 3.07 s of user CPU without, 2.50 s with). The run
# writes them (__pycache__/: ignored by git and by every copy the tests make of the tree) and
# compiles the two packages first (1.5 s of CPU), so the workers and subprocesses share one compile
# (docs/testing.md, "The suite's time")
unset PYTHONDONTWRITEBYTECODE
# (a module that does not compile is left to pytest, which names it: no stop here)
"$VENV/bin/python" -m compileall -q -j 0 geoloc viz/geoloc_viz >/dev/null || true
# three workers on the machine's 2 cores: the tests that open Chromium share one of them
# (tests/conftest.py) and the install group holds another for minutes, so with two workers
# the other 3100 tests waited for one of the groups to end (docs/testing.md, "The suite's time").
# --durations=25: the run ends with its 25 slowest test phases, so a run that got slower says
# where (docs/testing.md, "The suite's time")
exec "$VENV/bin/python" -m pytest -n "${GEOLOC_TEST_WORKERS:-3}" --dist loadgroup --durations=25 "$@"
