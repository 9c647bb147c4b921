"""Command-line verbs: each module defines ``register(subparsers)`` (see :mod:`geoloc.cli`)."""
