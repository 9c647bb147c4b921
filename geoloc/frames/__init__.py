"""Frames: passive rotations, the frame graph and the [Q17] chain (docs/architecture.md)."""
