"""51: share one flight-test record as a self-contained HTML scene (no server needed).

Picks the record whose published error is largest, builds its scene with the
descending-steps method (so the recording walks through every step), and writes
``outlier_<label>.html``: open it in any browser, or send it to a colleague.
Same as ``geoloc view --record <label> --method steps --export outlier.html``.
"""

import numpy as np

from geoloc_viz.app import GeolocApp, make_server
from geoloc_viz.scenario import load_view_scenario

scn = load_view_scenario()
errors = [info.paper_error_m for info, _ in scn.records]
worst = int(np.nanargmax(errors))
label = scn.records[worst][0].label
print(f"largest published error: {label}, {errors[worst]:.1f} m")

scn = load_view_scenario(record=label)
scn.inputs = scn.inputs.replace(method="steps", eps_h=50.0)
server = make_server(port=0)
app = GeolocApp(server, scn)
path = app.export(f"outlier_{label}.html")
print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); {len(app.geometry.iterations.H)} steps animated")
server.stop()
