"""52: the TianGong-2 limb scene [L18] from Python: tangent height against the view angle.

Builds the limb scene (``geoloc view --scenario limb``) and sweeps the view
angle alpha, printing the [L18] virtual-ellipsoid limb height, the exact
minimum height and the Newton-Raphson iteration count, as the GUI slider would.
"""

from geoloc.status import describe
from geoloc.viz.app import make_server
from geoloc.viz.scene_limb import LimbApp, load_limb

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
    print(f"{alpha:+9.2f}  {float(t.tangent_h) / 1e3:8.3f}  {float(t.exact_h) / 1e3:10.3f}  "
          f"{float(t.h_difference):+.1e}  {int(t.nr_iterations):3d}")
server.stop()
