"""The geolocation scene: draws a :class:`geoloc_viz.model.Geometry` into a viser scene.

All coordinates come from the core through :func:`geoloc_viz.model.compute`, in the
scene's local East-North-Up frame (metres, origin near the target; see
:mod:`geoloc.frames.enu`). The only transformations here are for display: the vertical
exaggeration multiplies the Up coordinate of every point (and scales the terrain
node), and the aircraft and frame axes have a display size.

Scene nodes (stable names, used by the tests and docs/viz.md), all under the
root ``/enu``. The browser's world unit is the **kilometre** (:data:`WORLD_SCALE`:
viser's own renders clip at 1000 units, and node scales do not propagate to
children), so a node at ENU ``p`` metres sits at ``p / 1000`` (Up also times the
vertical exaggeration):

``/origin`` (+ ``/origin/label``), ``/grid``, ``/terrain``, ``/aircraft``
(+ ``/aircraft/mesh``), ``/frames/{ned,body,gimbal_outer,cam}`` (+ ``/label``),
(+ ``/aircraft/label``: "aircraft drawn xN", the display scale),
``/frustum``, ``/los``, ``/los_beyond``, ``/hit/hmax``, ``/hit/result``,
``/hit/exact`` (each + ``/label``), ``/iterations/{points,verticals,brackets,current}``,
``/record/{published,surveyed,error}``.

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import collections
import functools
import io
import json
import struct
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual import ColorVisuals, TextureVisuals
import viser
import viser.transforms as vtf

from geoloc.assets import ASSETS
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.surfaces.dem import grid_faces
from geoloc_viz.model import Geometry, Scenario
from geoloc_viz.palette import rgb

#: Root node of the scene, and scene units per metre (the world unit is the km).
ROOT = "/enu"
WORLD_SCALE = 1e-3

#: Axis length of each frame, in multiples of the aircraft display scale (nested so all show).
FRAME_AXES = {"ned": 16.0, "body": 13.0, "gimbal_base": 11.5, "gimbal_outer": 10.0, "gimbal_inner": 8.5, "cam": 7.5}
FRAME_LABELS = {
    "ned": "NED: N",
    "body": "body: X nose",
    "gimbal_base": "gimbal base (mount): Z",
    "gimbal_outer": "outer gimbal: Y",
    "gimbal_inner": "inner gimbal: X",
    "cam": "camera: Z = line of sight",
}
#: Which axis tip carries each frame's label (0 = X, 1 = Y, 2 = Z): distinct tips, no overlap.
LABEL_AXIS = {"ned": 0, "body": 0, "gimbal_base": 2, "gimbal_outer": 1, "gimbal_inner": 0, "cam": 2}


def frame_style(name: str, index: int) -> tuple:
    """(axis length in display units, label text, label axis) of a drawn frame; joints of
    other gimbals get lengths between the body's and the camera's and a label on their Y tip."""
    L = FRAME_AXES.get(name, max(7.5, 12.0 - 1.2 * index))
    return L, FRAME_LABELS.get(name, f"{name.replace('_', ' ')}: Y"), LABEL_AXIS.get(name, 1)


#: The scene's colours (RGB 0-255), from the viewer's one colour table (:mod:`geoloc_viz.palette`).
COLORS = {
    k: rgb(k)
    for k in ("los", "los_beyond", "hmax", "result", "exact", "published", "surveyed", "error", "above", "below")
    + ("frustum", "bracket")
}


def origin_label(enu) -> str:
    """The label of the scene's origin axes: what they are and which colour is which axis (where it is:
    the summary's "scene" line, to 0.001 deg and 100 m)."""
    return "ENU origin: E red, N green, U blue"


@dataclass
class Display:
    """Display-only settings (no effect on the geometry)."""

    vertical_exaggeration: float = 1.0
    aircraft_scale: float = 200.0  # the 15 m mesh drawn 200x larger: ~3 km
    error_exaggeration: float = 1.0  # true length unless the "error vector drawn x" control enlarges it
    marker_radius_m: float = 220.0
    step: int | None = None  # iteration shown (None: all)
    frames_visible: dict = field(default_factory=dict)  # frame -> shown (default shown)
    terrain_visible: bool = True
    highlight: str | None = None  # frame highlighted by the teaching panel
    marker_labels: bool = False  # labels of the hit markers (they overlap at the default zoom)
    #: the frames' name labels at the aircraft ("NED: N", "camera: Z = line of sight", ...): they teach
    #: the chain, so they show in the teaching view; a flight's view hides them (GeolocScene.set_frame_labels)
    frame_labels: bool = True

    def z(self, p) -> np.ndarray:
        """Scene position (km) of ENU points (..., 3) [m]: Up multiplied by the exaggeration."""
        p = np.asarray(p, float)
        return p * (WORLD_SCALE * np.array([1.0, 1.0, self.vertical_exaggeration]))


def drawn_factor(exaggeration: float) -> str:
    """How a quantity is drawn, for its label: ``"true length"`` at 1, else ``"drawn x10"``."""
    return "true length" if float(exaggeration) == 1.0 else f"drawn x{float(exaggeration):g}"


def error_label(err_enu, exaggeration: float) -> str:
    """Label of the error vector: its true 3D length and whether it is drawn longer (``drawn x10``)."""
    return f"error vector (3D, {drawn_factor(exaggeration)}): {float(np.linalg.norm(err_enu)):.1f} m"


def camera_pose_for(g: Geometry, d: Display, kind: str = "overview"):
    """(position, look_at) in scene units for a named view of geometry ``g``.

    ``"overview"``: a side view showing the aircraft, the frames, the line of
    sight and the terrain at once. ``"target"``: close to the hit, where the
    iterations, brackets and hits are, from the same side.
    """
    if kind not in ("overview", "target"):
        raise ValueError(f"camera view = {kind!r}: 'overview' or 'target'")
    a = d.z(g.aircraft_enu)
    b = d.z(g.hit_enu if np.all(np.isfinite(g.hit_enu)) else g.aircraft_enu + 20e3 * g.los_dir_enu)
    horiz = (b - a)[:2]
    L = max(float(np.linalg.norm(b - a)), 1e-3)
    u = np.r_[horiz / max(np.linalg.norm(horiz), 1e-9), 0.0]
    side = np.array([u[1], -u[0], 0.0])  # to the right of the ground track
    up = np.array([0.0, 0.0, 1.0])
    if kind == "target":
        # The iterations span the last ~15 % of the line of sight above the hit.
        aim = b + 0.08 * (a - b)
        return aim + side * 0.4 * L + up * 0.15 * L - u * 0.1 * L, aim
    mid = 0.5 * (a + b)
    # Step back to the right of the track and up; aim a little beyond the middle so the
    # scene sits left of the GUI panel.
    pos = mid + side * 0.7 * L + up * 0.55 * L - u * 0.2 * L
    return pos, mid - side * 0.1 * L + u * 0.1 * L - up * 0.12 * L


@functools.lru_cache(maxsize=1)
def load_aircraft_mesh() -> trimesh.Trimesh:
    """The bundled aircraft mesh (body frame, metres), made by tools/make_aircraft_mesh.py.

    Loaded once and shared by every session (read only)."""
    path = Path(ASSETS) / "meshes" / "aircraft.ply"
    mesh = trimesh.load(path, force="mesh")
    if not isinstance(mesh, trimesh.Trimesh):  # force="mesh" concatenates a scene's meshes into one
        raise TypeError(f"aircraft mesh {path}: a {type(mesh).__name__}, not one triangle mesh")
    return mesh


#: Terrain meshes by (DEM object, scene origin): every tab on the same record shares one
#: (a few MB each; a handful of records at most are in use at once).
_TERRAIN_CACHE: "collections.OrderedDict" = collections.OrderedDict()
_TERRAIN_CACHE_SIZE = 4
_TERRAIN_LOCK = threading.Lock()


def _terrain_entry(scn):
    from geoloc_viz import terrain_link

    enu = scn.enu
    key = (id(scn.dem), float(enu.lat0), float(enu.lon0), float(enu.h0))
    with _TERRAIN_LOCK:
        hit = _TERRAIN_CACHE.get(key)
        if hit is not None and hit[0] is scn.dem:
            _TERRAIN_CACHE.move_to_end(key)
            return hit
    mesh = terrain_link.terrain_mesh(scn)
    entry = (scn.dem, mesh, unlit_glb(mesh))
    with _TERRAIN_LOCK:
        _TERRAIN_CACHE[key] = entry
        while len(_TERRAIN_CACHE) > _TERRAIN_CACHE_SIZE:
            _TERRAIN_CACHE.popitem(last=False)
    return entry


def terrain_mesh_cached(scn) -> trimesh.Trimesh:
    """:func:`geoloc_viz.terrain_link.terrain_mesh` of ``scn``, shared between sessions."""
    return _terrain_entry(scn)[1]


def terrain_glb_cached(scn) -> bytes:
    """:func:`unlit_glb` of :func:`terrain_mesh_cached` (exported once, shared between sessions)."""
    return _terrain_entry(scn)[2]


def srgb_to_linear_u8(c) -> np.ndarray:
    """8-bit sRGB colour values to 8-bit linear ones (IEC 61966-2-1's transfer function, inverted)."""
    x = np.asarray(c, float) / 255.0
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return np.round(lin * 255.0).astype(np.uint8)


def unlit_glb(mesh: trimesh.Trimesh) -> bytes:
    """Binary glTF of ``mesh`` with its material marked ``KHR_materials_unlit`` (glTF 2.0 extension:
    three.js loads it as a ``MeshBasicMaterial``, vertex colours without lighting).

    For the terrain, whose relief is baked into its colours (:func:`geoloc_viz.terrain_link.hillshade`):
    in headless Chromium with software WebGL the lit material (physically based, with viser's default
    environment map) over a 51 k-triangle terrain filling the canvas cost 1.9-2.6 s a frame, unlit
    0.4-0.45 s, about what the scene costs without the terrain (machine load 10-12;
    a 161 or an 81 node grid made no difference: the lit material's cost is per pixel). Unlit, what
    is left of the terrain's cost is in its triangles: two flat triangles over its extent draw a
    frame in 0.64 of its time, its own mesh flattened in the same time
    (``benchmarks/bench_frame.py --pair terrain-quad``, ``--pair terrain-flat``).

    A textured mesh goes with a white base colour and a bilinear sampler without mipmaps (the
    texture's colours as they are, one texture read a pixel).
    """
    # glTF's COLOR_0 is linear (glTF 2.0, 3.7.2.1) and three.js converts it to sRGB on output: the
    # colours (sRGB, as a colour map gives them) go in linearised, so the unlit terrain shows them
    # as they are instead of washed out towards white
    # (a texture is sRGB in glTF: it goes as it is)
    m = mesh.copy()
    if isinstance(mesh.visual, ColorVisuals) and isinstance(m.visual, ColorVisuals):
        rgba = np.asarray(mesh.visual.vertex_colors, np.uint8)
        m.visual.vertex_colors = np.concatenate([srgb_to_linear_u8(rgba[:, :3]), rgba[:, 3:]], axis=1)
    elif not isinstance(mesh.visual, TextureVisuals):
        raise TypeError(
            f"unlit_glb: the mesh's visual is a {type(mesh.visual).__name__}, not vertex colours or a texture"
        )
    buf = io.BytesIO()
    m.export(buf, file_type="glb")
    b = buf.getvalue()
    magic, version, _ = struct.unpack_from("<III", b, 0)
    jlen, jtype = struct.unpack_from("<II", b, 12)
    doc = json.loads(b[20 : 20 + jlen])
    rest = b[20 + jlen :]
    mats = doc.setdefault("materials", [])
    if not mats:  # trimesh writes none for a vertex-coloured mesh
        mats.append({"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}})
        for m in doc.get("meshes", []):
            for p in m["primitives"]:
                p["material"] = 0
    for m in mats:
        m.setdefault("extensions", {})["KHR_materials_unlit"] = {}
        pbr = m.get("pbrMetallicRoughness", {})
        if "baseColorTexture" in pbr:  # the texture's colours as they are (trimesh's material greys them)
            pbr["baseColorFactor"] = [1.0, 1.0, 1.0, 1.0]
    if doc.get("textures"):
        # bilinear, no mipmaps (glTF 2.0 sampler LINEAR = 9729): one texture read a pixel, where
        # three.js's default (trilinear over generated mipmaps) reads two levels in software WebGL
        doc["samplers"] = [{"magFilter": 9729, "minFilter": 9729}]
        for t in doc["textures"]:
            t["sampler"] = 0
    used = doc.setdefault("extensionsUsed", [])
    if "KHR_materials_unlit" not in used:
        used.append("KHR_materials_unlit")
    j = json.dumps(doc, separators=(",", ":")).encode()
    j += b" " * (-len(j) % 4)  # chunks are 4-byte aligned (glTF 2.0, GLB file format)
    return struct.pack("<III", magic, version, 20 + len(j) + len(rest)) + struct.pack("<II", len(j), jtype) + j + rest


def earth_patch(lat0_deg: float, lon0_deg: float, half_deg: float, nodes: int):
    """A patch of the WGS-84 ellipsoid (h = 0) for a scene's Earth: ``nodes`` x ``nodes`` nodes over
    ``half_deg`` either side of (``lat0_deg``, ``lon0_deg``), latitudes kept within +-89.9 deg.
    Returns (lat, lon [rad], (nodes, nodes) each; ECEF [m], (nodes, nodes, 3); faces, two
    triangles a cell as :func:`geoloc.surfaces.dem.grid_faces` splits them)."""
    la = np.deg2rad(np.clip(np.linspace(lat0_deg - half_deg, lat0_deg + half_deg, nodes), -89.9, 89.9))
    lo = np.deg2rad(np.linspace(lon0_deg - half_deg, lon0_deg + half_deg, nodes))
    LO, LA = np.meshgrid(lo, la)
    return LA, LO, geodetic_to_ecef(LA, LO, np.zeros_like(LA)), grid_faces(np.ones(LA.shape, bool))


def wxyz(R) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation matrix, for viser's node orientation."""
    return vtf.SO3.from_matrix(np.asarray(R, float)).wxyz


class GeolocScene:
    """Owns the geolocation nodes of one viser scene and redraws them from a Geometry."""

    def __init__(self, scene: viser.SceneApi, scn: Scenario, disp: Display | None = None):
        self.scene = scene
        self.scn = scn
        self.disp = disp or Display()
        self.geometry: Geometry | None = None
        self.terrain_handle: viser.GlbHandle | None = None
        self.aircraft_mesh = load_aircraft_mesh()
        self.handles: dict = {}
        self._cache: dict = {}  # node name -> (handle, creation key), see _alive

    # ------------------------------------------------------------ static parts
    def draw_static(self) -> None:
        """Origin, grid and terrain: redrawn when the scenario (ENU origin, DEM) changes."""
        s = self.scene
        W = WORLD_SCALE
        s.add_frame(ROOT, show_axes=False)
        s.add_frame("/enu/origin", axes_length=600.0 * W, axes_radius=25.0 * W, origin_radius=60.0 * W)
        # the origin is the scene's East-North-Up origin (EnuFrame.scene_origin: the record's published or
        # reported point rounded to 0.001 deg and 100 m), so its axes sit by the target: the label says what they are
        s.add_label("/enu/origin/label", origin_label(self.scn.enu), position=(0.0, 0.0, 0.0), anchor="top-right")
        if self.scn.dem is None:  # a 1 km grid on the origin's level when there is no terrain
            s.add_grid(
                "/enu/grid",
                width=40000.0 * W,
                height=40000.0 * W,
                cell_size=1000.0 * W,
                section_size=5000.0 * W,
                plane="xy",
                cell_color=(120, 120, 120),
                section_color=(90, 90, 90),
                fade_distance=200.0,
                shadow_opacity=0.0,
            )
        else:
            s.remove_by_name("/enu/grid")
        # Scale bar: 5 km along East with 1 km ticks, set 6 km south-west of the origin.
        x0 = np.array([-11000.0, -6000.0, 0.0])
        bar = np.array(
            [[x0, x0 + [5000.0, 0, 0]]]
            + [[x0 + [x, 0, 0], x0 + [x, 0, 400.0]] for x in (0.0, 1000.0, 2000.0, 3000.0, 4000.0, 5000.0)]
        )
        s.add_line_segments(
            "/enu/scale_bar", (bar * W).astype(np.float32), (255, 255, 255), thickness=3.0, thickness_units="screen"
        )
        s.add_label(
            "/enu/scale_bar/label",
            "5 km, ticks 1 km (East)",
            position=(x0 + [2500.0, 0.0, 400.0]) * W,
            anchor="bottom-center",
        )
        self.draw_terrain()
        self.handles["aircraft"] = s.add_frame("/enu/aircraft", show_axes=False)
        self.handles["aircraft_mesh"] = s.add_mesh_trimesh(
            "/enu/aircraft/mesh",
            self.aircraft_mesh,
            scale=self.disp.aircraft_scale * W,
            cast_shadow=False,
            receive_shadow=False,
        )
        self.handles["aircraft_label"] = s.add_label(
            "/enu/aircraft/label", self.aircraft_label(), position=(0.0, 0.0, 0.0), anchor="bottom-left"
        )

    def _draw_frames(self, g: Geometry) -> None:
        """The frames at the aircraft (NED, body, gimbal joints, camera), each with its name label while
        :attr:`Display.frame_labels` (a node re-created when its length, highlight or label changes)."""
        d, s = self.disp, self.scene
        for index, (name, f) in enumerate(g.frames.items()):
            big = d.highlight == name
            length, text, label_axis = frame_style(name, index)
            L = length * d.aircraft_scale * (1.4 if big else 1.0) * WORLD_SCALE
            labelled = d.frame_labels
            key = (L, big, labelled)
            fh = self._alive(f"/enu/frames/{name}", key)
            if fh is None:
                fh = s.add_frame(
                    f"/enu/frames/{name}",
                    axes_length=L,
                    axes_radius=L * (0.05 if big else 0.02),
                    origin_radius=L * 0.04,
                    position=d.z(f.origin_enu),
                    wxyz=wxyz(f.R_enu_frame),
                    visible=d.frames_visible.get(name, True),
                )
                self._cache[f"/enu/frames/{name}"] = (fh, key)
            else:
                fh.position = d.z(f.origin_enu)
                fh.wxyz = wxyz(f.R_enu_frame)
                fh.visible = d.frames_visible.get(name, True)
                continue
            tip = np.zeros(3)
            tip[label_axis] = L * 1.05
            if labelled:
                s.add_label(
                    f"/enu/frames/{name}/label", ("> " if big else "") + text, position=tip, anchor="center-left"
                )
            else:
                s.remove_by_name(f"/enu/frames/{name}/label")

    def set_frame_labels(self, visible: bool) -> None:
        """Show or remove the frames' name labels (:attr:`Display.frame_labels`): the teaching view shows
        them; a flight's view does not, where seven labels at the aircraft covered the flight. Removed,
        not hidden: the label layout re-shows labels it hid itself."""
        if bool(visible) == self.disp.frame_labels:
            return
        self.disp.frame_labels = bool(visible)
        if self.geometry is not None:
            self._draw_frames(self.geometry)

    def aircraft_label(self) -> str:
        """The aircraft's label: it is drawn larger than life, by the display scale."""
        return f"aircraft drawn x{self.disp.aircraft_scale:g}"

    def _terrain_scale(self):
        W = WORLD_SCALE
        return (W, W, W * self.disp.vertical_exaggeration)

    def draw_terrain(self) -> None:
        if self.scn.dem is None:
            self.terrain_handle = None
            self.scene.remove_by_name("/enu/terrain")
            return
        # unlit, its relief baked into its colours: the cheap material in software WebGL (unlit_glb)
        self.terrain_handle = self.scene.add_glb(
            "/enu/terrain",
            terrain_glb_cached(self.scn),
            scale=self._terrain_scale(),
            visible=self.disp.terrain_visible,
            cast_shadow=False,
            receive_shadow=False,
        )

    # ------------------------------------------------------------ dynamic parts
    def _alive(self, name, key):
        """The cached handle of ``name`` if it still exists and was made with ``key``."""
        h, k = self._cache.get(name, (None, None))
        if h is not None and k == key and self.scene.get_handle_by_name(name) is h:
            return h
        return None

    def _sphere(self, name, p, color, label=None, radius=None, anchor="bottom-left", show_label=None):
        # Moving an existing node costs one small message; re-creating it costs a full one.
        r = (radius or self.disp.marker_radius_m) * WORLD_SCALE
        rgb = tuple(int(c) for c in color)
        # a new radius re-creates the node; a new colour is one property update (the current
        # iteration's ball turns red below the terrain on most steps: re-creating it cost a
        # geometry and a material in the browser on every timeline step)
        key = r
        h = self._alive(name, key)
        if h is not None and tuple(int(c) for c in h.color) != rgb:
            h.color = rgb
        if h is None:
            h = self.scene.add_icosphere(
                name,
                radius=r,
                color=color,
                subdivisions=2,
                position=self.disp.z(p),
                cast_shadow=False,
                receive_shadow=False,
            )
            self._cache[name] = (h, key)
        else:
            h.position = self.disp.z(p)
            h.visible = True
        if label is not None:
            lh = self._alive(name + "/label", anchor)
            if lh is None:
                lh = self.scene.add_label(name + "/label", label, position=(0.0, 0.0, 0.0), anchor=anchor)
                self._cache[name + "/label"] = (lh, anchor)
            elif lh.text != label:
                lh.text = label
            lh.visible = self.disp.marker_labels if show_label is None else show_label
        return h

    def _array_node(self, name, key, pts, colors, create):
        """The node ``name`` showing ``pts`` in ``colors``: a step moves them (one update message,
        only for what changed), also to another count (the iterations of a frame: viser's client
        rebuilds the buffer, keeping the node and its material), instead of re-creating the node
        (the browser mounts a new one); ``create()`` makes it when ``key`` changed."""
        h = self._alive(name, key)
        if h is None:
            h = create()
            self._cache[name] = (h, key)
        else:
            if not np.array_equal(h.points, pts):
                h.points = pts
            if not np.array_equal(h.colors, colors):
                h.colors = colors
        return h

    def _points(self, name, pts, colors, point_size):
        pts = self.disp.z(np.asarray(pts, float).reshape(-1, 3)).astype(np.float32)
        colors = np.broadcast_to(np.asarray(colors, np.uint8), pts.shape).copy()
        return self._array_node(
            name,
            float(point_size),
            pts,
            colors,
            lambda: self.scene.add_point_cloud(
                name, pts, colors, point_size=point_size, point_shape="circle", precision="float32"
            ),
        )

    def _segments(self, name, pts, color, thickness=3.0):
        pts = self.disp.z(np.asarray(pts, float).reshape(-1, 2, 3)).astype(np.float32)
        colors = np.broadcast_to(np.asarray(color, np.uint8), pts.shape).copy()
        return self._array_node(
            name,
            float(thickness),
            pts,
            colors,
            lambda: self.scene.add_line_segments(name, pts, colors, thickness=thickness, thickness_units="screen"),
        )

    def update(self, g: Geometry) -> None:
        """Redraw every dynamic node from ``g`` (call inside ``server.atomic()``)."""
        self.geometry = g
        d, s = self.disp, self.scene
        self.handles["aircraft"].position = d.z(g.aircraft_enu)
        self.handles["aircraft"].wxyz = wxyz(g.R_enu_body)
        self.handles["aircraft_mesh"].scale = d.aircraft_scale * WORLD_SCALE
        lab = self.handles.get("aircraft_label")
        if lab is not None and lab.text != self.aircraft_label():
            lab.text = self.aircraft_label()
        if self.terrain_handle is not None:
            self.terrain_handle.scale = self._terrain_scale()
            self.terrain_handle.visible = d.terrain_visible
        self._draw_frames(g)
        # Line of sight: aircraft -> answer, then faintly on to the end of its usefulness.
        ok = np.all(np.isfinite(g.hit_enu))
        end = g.hit_enu if ok else g.aircraft_enu + 40e3 * g.los_dir_enu
        if ok and g.raw_hit_enu is not None and np.all(np.isfinite(g.raw_hit_enu)):
            end = g.raw_hit_enu  # refraction on: the straight line ends at its own hit; the bent ray beside it
        self._segments("/enu/los", [g.aircraft_enu, end], COLORS["los"], 4.0)
        beyond = end + 0.15 * np.linalg.norm(end - g.aircraft_enu) * g.los_dir_enu
        self._segments("/enu/los_beyond", [end, beyond], COLORS["los_beyond"], 2.0)
        if g.footprint_enu is not None and np.all(np.isfinite(g.footprint_enu)):
            fp = g.footprint_enu
            segs = [[g.aircraft_enu, c] for c in fp] + [[fp[i], fp[(i + 1) % 4]] for i in range(4)]
            self._segments("/enu/frustum", segs, COLORS["frustum"], 1.5)
        else:
            s.remove_by_name("/enu/frustum")
        self._sphere("/enu/hit/result", g.hit_enu if ok else g.aircraft_enu, COLORS["result"], g.hit_label)
        result = s.get_handle_by_name("/enu/hit/result")
        if result is None:  # _sphere has just made it
            raise RuntimeError("scene node /enu/hit/result is missing after it was drawn")
        result.visible = bool(ok)
        if g.hit_hmax_enu is not None:
            self._sphere(
                "/enu/hit/hmax",
                g.hit_hmax_enu,
                COLORS["hmax"],
                f"ellipsoid hit at H_max = {g.hmax:.0f} m",
                radius=0.7 * d.marker_radius_m,
                anchor="center-right",
            )
        if g.exact_enu is not None and np.all(np.isfinite(g.exact_enu)):
            self._sphere(
                "/enu/hit/exact",
                g.exact_enu,
                COLORS["exact"],
                "exact first hit",
                radius=0.8 * d.marker_radius_m,
                anchor="top-right",
            )
        self._draw_iterations(g)
        self._draw_record(g)

    def _draw_iterations(self, g: Geometry) -> None:
        s, d, it = self.scene, self.disp, g.iterations
        if it is None or len(it.H) == 0:
            for part in ("points", "verticals", "brackets", "current"):
                s.remove_by_name(f"/enu/iterations/{part}")
            return
        n = len(it.H) if d.step is None else int(np.clip(d.step, 0, len(it.H) - 1)) + 1
        above = (it.H - it.h_dem)[:n] > 0
        cols = np.where(above[:, None], COLORS["above"], COLORS["below"]).astype(np.uint8)
        self._points("/enu/iterations/points", it.on_los_enu[:n], cols, 0.6 * d.marker_radius_m * WORLD_SCALE)
        self._segments(
            "/enu/iterations/verticals",
            np.stack([it.on_los_enu[:n], it.dem_enu[:n]], 1),
            np.repeat(cols[:, None], 2, 1),
            2.5,
        )
        if it.brackets_enu is not None:
            self._segments("/enu/iterations/brackets", it.brackets_enu[:n], COLORS["bracket"], 6.0)
        k = n - 1
        self._sphere(
            "/enu/iterations/current",
            it.on_los_enu[k],
            COLORS["above"] if above[k] else COLORS["below"],
            f"{it.method} n={k}: H={it.H[k]:.1f} m, DEM h={it.h_dem[k]:.1f} m, H-h={it.H[k] - it.h_dem[k]:+.1f} m",
            radius=0.5 * d.marker_radius_m,
            anchor="center-left",
            show_label=d.step is not None or d.marker_labels,
        )

    def _draw_record(self, g: Geometry) -> None:
        s, d = self.scene, self.disp
        if g.published_enu is not None:
            self._sphere(
                "/enu/record/published",
                g.published_enu,
                COLORS["published"],
                "published [Q17]",
                radius=0.6 * d.marker_radius_m,
                anchor="top-left",
            )
        if g.surveyed_enu is not None:
            self._sphere(
                "/enu/record/surveyed",
                g.surveyed_enu,
                COLORS["surveyed"],
                "surveyed",
                radius=0.6 * d.marker_radius_m,
                anchor="bottom-right",
            )
            if np.all(np.isfinite(g.hit_enu)):
                tip = g.hit_enu + d.error_exaggeration * (g.surveyed_enu - g.hit_enu)
                eh = self._segments("/enu/record/error", [g.hit_enu, tip], COLORS["error"], 5.0)
                text = error_label(g.surveyed_enu - g.hit_enu, d.error_exaggeration)
                # (keyed on its parent: a re-created parent drops its children in the browser, while
                # viser keeps their handles)
                key = ("top-left", id(eh))
                lh = self._alive("/enu/record/error/label", key)
                if lh is None:
                    lh = s.add_label("/enu/record/error/label", text, position=d.z(tip), anchor="top-left")
                    self._cache["/enu/record/error/label"] = (lh, key)
                else:
                    lh.text, lh.position = text, d.z(tip)

    # ------------------------------------------------------------ camera
    def camera_pose(self, kind: str = "overview"):
        """(position, look_at) in scene units for a named view; see :func:`camera_pose_for`."""
        if self.geometry is None:
            raise RuntimeError("camera_pose: the scene has no geometry yet (GeolocScene.update draws one)")
        return camera_pose_for(self.geometry, self.disp, kind)

    def set_initial_camera(self, server: viser.ViserServer) -> None:
        """Start new browsers on the overview (see :meth:`camera_pose`)."""
        pos, aim = self.camera_pose("overview")
        cam = server.initial_camera
        cam.up = (0.0, 0.0, 1.0)
        cam.near = 0.02  # km (world units, see ROOT)
        cam.far = 1000.0
        cam.position = tuple(pos)
        cam.look_at = tuple(aim)

    def move_clients(self, server: viser.ViserServer, kind: str) -> None:
        """Move every connected browser's camera to a named view."""
        pos, aim = self.camera_pose(kind)
        for client in server.get_clients().values():
            with client.atomic():
                client.camera.up_direction = (0.0, 0.0, 1.0)
                # viser shifts look_at with the position: position first
                client.camera.position = tuple(pos)
                client.camera.look_at = tuple(aim)
