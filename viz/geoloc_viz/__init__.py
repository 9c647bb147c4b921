"""geoloc's browser 3D viewer (viser): the geolocation scene and the limb scene.

Everything drawn comes from the core (:mod:`geoloc`); this package only lays it
out in a local East-North-Up scene (:mod:`geoloc.frames.enu`) and wires the GUI.
User guide: ``docs/viz.md``. Conventions: ``docs/conventions.md``.
"""
