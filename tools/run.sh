#!/usr/bin/env bash
# The README's main command: install into .venv and open the visualiser on
# its default scenario (a bundled flight-test record over bundled terrain).
# Extra arguments go to `geoloc view` (e.g. --record T4-3, --scenario limb).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${GEOLOC_VENV:-.venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e . -e ./viz
# numba compiles the terrain and camera kernels on a machine's first run (15-30 s of
# CPU on 2 cores, once): do it here, saying so, so the viewer starts from the cache
# (~/.cache/geoloc/numba, or NUMBA_CACHE_DIR; a reinstall keeps it). Seconds when warm.
"$VENV/bin/geoloc" warm
exec "$VENV/bin/geoloc" view "$@"
