"""52: the TianGong-2 limb scene [L18] from Python: tangent height against the view angle.

Builds the limb scene (``geoloc view --scenario limb``) and sweeps the view
angle alpha, printing the [L18] virtual-ellipsoid limb height, the exact
minimum height and the Newton-Raphson iteration count, as the GUI slider would;
then what the drawing exaggerates (and that the drawn ellipsoid stays tangent to
the drawn line), and where a line that meets the Earth stops.
"""

import numpy as np
import pyproj

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.status import describe
from geoloc_viz.app import make_server
from geoloc_viz.scene_geoloc import WORLD_SCALE
from geoloc_viz.scene_limb import LimbApp, load_limb

server = make_server(port=0)
app = LimbApp(server, load_limb())
print(app.scn.name)
print(" alpha_deg  L18_h_km  exact_h_km  diff_m  NR_steps")
for alpha in (-1.2, -0.6, 0.0, 0.6, 1.2):
    app.sl_alpha.value = alpha
    t = app.tan
    if int(t.status) != 0:
        print(f"{alpha:+9.2f}  no tangent: {describe(int(t.status))}")
        continue
    print(
        f"{alpha:+9.2f}  {float(t.tangent_h) / 1e3:8.3f}  {float(t.exact_h) / 1e3:10.3f}  "
        f"{float(t.h_difference):+.1e}  {int(t.nr_iterations):3d}"
    )

# What the drawing exaggerates (docs/limb.md): the virtual ellipsoid's departure from a shell
# at the limb height, about the tangent point (the line stays tangent), and the tangent offset.
app.sl_alpha.value = 0.0
t = app.tan
off_m = float(np.linalg.norm(t.exact_ecef - t.tangent_ecef))
print(f"Delta a - limb height: {float(t.delta_a) - float(t.tangent_h_geodetic):.2f} m, drawn x{app.exaggeration:g}")
print(
    f"exact minimum to [L18] tangent point: {off_m:.1f} m along the line, drawn x{app.offset_exaggeration:g} "
    f"= {off_m * app.offset_exaggeration / 1e3:.1f} km"
)
r = app.marker_radii_km()
print(
    f"marker radii: tangent {r['tangent']:.2f} km, exact {r['exact']:.2f} km "
    f"(below half the drawn separation, {off_m * app.offset_exaggeration / 2e3:.1f} km)"
)
sec = app.drawn_virtual(*app.section_geodetic)
o, d = np.asarray(app.chain.origin_ecef), np.asarray(app.chain.direction_ecef)
r_ = sec - o
gap = np.linalg.norm(r_ - (r_ @ d)[:, None] * d, axis=1).min()
print(f"drawn virtual ellipsoid to the line of sight: closest {gap:.1e} m (tangent)")
app.sl_alpha.value = -1.5
lon, lat, h = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*app.los_ecef[-1])
print(
    f"alpha -1.5 deg: {describe(int(app.tan.status))}; the drawn line ends at h = {h:.1e} m ({lat:.3f} N, {lon:.3f} E)"
)

# Where the camera stands (docs/limb.md, "Where the Earth and the camera go"): above the Earth,
# which is drawn around what the frame is about, also when the line meets the Earth and at frame 600.
for frame, alpha in ((0, -1.5), (600, 0.0), (600, -1.5)):
    app.sl_frame.value, app.sl_alpha.value = frame, alpha
    pos, aim, _ = app.camera_pose()
    ecef = app.enu.to_ecef(np.asarray(pos) / WORLD_SCALE)  # scene km -> ENU m -> ECEF
    _, _, h_cam = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*ecef)
    c = app.w(geodetic_to_ecef(*app.focus_latlon, 0.0))
    f, dc = (aim - pos) / np.linalg.norm(aim - pos), (c - pos) / np.linalg.norm(c - pos)
    print(
        f"frame {frame}, alpha {alpha:+.1f} deg: camera {h_cam / 1e3:.0f} km above WGS-84, the Earth "
        f"patch's centre {np.rad2deg(np.arccos(f @ dc)):.1f} deg from the view axis"
    )
server.stop()
