"""Geodesy: the ellipsoid, the geoid and local frames (docs/architecture.md)."""
