"""Workflows: replay, paper reproductions, flight simulation and scenario files (docs/architecture.md)."""
