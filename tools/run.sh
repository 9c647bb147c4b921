#!/usr/bin/env bash
# The README's main command: install into .venv and open the visualiser on
# the bundled data (until the visualiser lands: the flight-test replay).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${GEOLOC_VENV:-.venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e .
exec "$VENV/bin/geoloc" replay --height-column paper_height_m "$@"
