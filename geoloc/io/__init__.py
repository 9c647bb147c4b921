"""Inputs and outputs: files in and out of geoloc (docs/architecture.md)."""
