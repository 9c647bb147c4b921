"""Generate the bundled aircraft mesh ``assets/meshes/aircraft.ply`` from trimesh primitives.

Run: ``python tools/make_aircraft_mesh.py``. Deterministic (no randomness); the
committed file is its output.

The mesh is in the aircraft **body** frame of ``docs/conventions.md``:
X towards the nose, Y along the right wing, Z down; metres, origin at the
POS / optical centre (roughly the centre of the fuselage). It is a generic
15 m jet silhouette, drawn only to show attitude: a real aircraft
is a speck at 20 km, so the viewer scales it up (display scale control).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

OUT = Path(__file__).resolve().parents[1] / "assets" / "meshes" / "aircraft.ply"


def _cylinder_x(radius, length, x_center, sections=24):
    """Cylinder with its axis along body X."""
    c = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    c.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    c.apply_translation([x_center, 0, 0])
    return c


def build() -> trimesh.Trimesh:
    parts = []
    # Fuselage: 11 m cylinder, 0.8 m radius, with a 3 m nose cone and a 1.5 m tail cone.
    parts.append(_cylinder_x(0.8, 11.0, 0.0))
    nose = trimesh.creation.cone(radius=0.8, height=3.0, sections=24)
    nose.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    nose.apply_translation([5.5, 0, 0])
    parts.append(nose)
    tail = trimesh.creation.cone(radius=0.8, height=1.5, sections=24)
    tail.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [0, 1, 0]))
    tail.apply_translation([-5.5, 0, 0])
    parts.append(tail)
    # Main wing: 16 m span along Y, swept by a shear, slightly below the axis (Z down).
    for side in (-1, 1):
        half = trimesh.creation.box(extents=[2.4, 8.0, 0.25])
        verts = half.vertices.copy()
        verts[:, 0] -= 0.25 * np.abs(verts[:, 1] + 4.0 * side)  # sweep back towards the tip
        half = trimesh.Trimesh(verts, half.faces)
        half.apply_translation([0.5, side * 4.0, 0.3])
        parts.append(half)
    # Horizontal tail: 6 m span near the tail.
    parts.append(
        trimesh.creation.box(
            extents=[1.4, 6.0, 0.2], transform=trimesh.transformations.translation_matrix([-5.2, 0, 0])
        )
    )
    # Vertical fin: points up, i.e. towards body -Z.
    fin = trimesh.creation.box(extents=[1.8, 0.2, 2.6])
    fin.apply_translation([-5.0, 0, -1.9])
    parts.append(fin)
    # Camera pod under the fuselage (body +Z), where the gimbal sits.
    pod = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    pod.apply_translation([1.0, 0, 0.8])
    parts.append(pod)
    mesh = trimesh.util.concatenate(parts)
    # meshes concatenated are a mesh, coloured per face (the annotations say any geometry, any visuals)
    assert isinstance(mesh, trimesh.Trimesh) and isinstance(mesh.visual, trimesh.visual.ColorVisuals)
    mesh.visual.face_colors = np.tile([225, 228, 235, 255], (len(mesh.faces), 1)).astype(np.uint8)
    pod_faces = len(pod.faces)
    mesh.visual.face_colors[-pod_faces:] = [250, 60, 30, 255]
    return mesh


def main() -> None:
    mesh = build()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
    print(f"wrote {OUT} ({len(mesh.faces)} faces, extents {np.round(mesh.extents, 2)} m)")


if __name__ == "__main__":
    main()
