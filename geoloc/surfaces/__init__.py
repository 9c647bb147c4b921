"""Surfaces: what a line of sight meets (constant height, DEM) and the ground points they return (docs/architecture.md)."""
