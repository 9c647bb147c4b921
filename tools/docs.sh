#!/usr/bin/env bash
# The README's documentation command: builds the site (mkdocs.yml) into site/ with
# `mkdocs build --strict`, which fails on any warning (a broken link or anchor, a page left
# out of the nav, a docstring griffe cannot parse). On a clean clone it first makes .venv and
# installs the `docs` extra's tools into it (read from pyproject.toml, so the versions live in
# one place); the API reference is read from the sources by griffe, so the core itself need
# not be installed. Extra arguments go to `mkdocs build` (e.g. -d /tmp/site).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${GEOLOC_VENV:-.venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
if ! "$VENV/bin/python" -c "import mkdocs, material, mkdocstrings_handlers.python" 2>/dev/null; then
    "$VENV/bin/python" -m pip install -q --upgrade pip
    mapfile -t REQS < <("$VENV/bin/python" -c '
import tomllib
for r in tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]["docs"]:
    print(r)')
    "$VENV/bin/python" -m pip install -q "${REQS[@]}"
fi
# Material 9.7+ prints a banner about MkDocs 2 on every build; it is not a warning of ours
export NO_MKDOCS_2_WARNING=1
exec "$VENV/bin/python" -m mkdocs build --strict "$@"
