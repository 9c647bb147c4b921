"""50: build the flight-test scene on a viser server from Python and read it back.

What `geoloc view` does, without a browser: load the bundled record T3-1 over
the bundled ETOPO5 terrain, build the scene, then move the gimbal from Python
and print where the hit marker went (scene world unit: km, ENU at the target).
Open the printed URL in a browser to watch while the script sleeps (Ctrl+C ends).
"""

import sys
import time

import numpy as np

from geoloc_viz.app import GeolocApp, make_server
from geoloc_viz.scenario import load_view_scenario
from geoloc_viz.scene_geoloc import WORLD_SCALE

server = make_server(port=0)  # 127.0.0.1, a free port
app = GeolocApp(server, load_view_scenario(record="T3-1"))
print(f"viewer at http://127.0.0.1:{server.get_port()}")
print(app.md_summary.content.replace("  \n", "\n"))

hit = lambda: np.asarray(server.scene.get_handle_by_name("/enu/hit/result").position) / WORLD_SCALE  # noqa: E731
print("hit marker, ENU [m]:", np.round(hit(), 1))
for roll in (-40.0, -50.0):
    app.num["gimbal_roll_deg"].value = roll  # same callback as the GUI slider
    print(
        f"gimbal roll {roll:+.0f} deg -> hit ENU [m] {np.round(hit(), 1)}, "
        f"scene updated in {1e3 * app.last_update_s:.0f} ms"
    )

if "--wait" in sys.argv:
    try:
        time.sleep(3600)
    except KeyboardInterrupt:
        pass
server.stop()
