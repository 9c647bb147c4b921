#!/usr/bin/env bash
# The README's main command: install into .venv and open the visualiser on
# its default scenario (a bundled flight-test record over bundled terrain).
# Extra arguments go to `geoloc view` (e.g. --record T4-3, --scenario limb).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${GEOLOC_VENV:-.venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e .
exec "$VENV/bin/geoloc" view "$@"
