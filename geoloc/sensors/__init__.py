"""Sensors: lenses, gimbals and the sensor models behind one interface (docs/architecture.md)."""
