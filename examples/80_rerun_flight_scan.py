"""80: log the bundled whisk-broom scan to a rerun recording and print what it holds.

Run from the repository root: ``python examples/80_rerun_flight_scan.py`` then
``rerun /tmp/flight_scan.rrd`` (or ``rerun --serve-web /tmp/flight_scan.rrd``).
"""

import numpy as np

from geoloc_viz.rerun_log import write
from geoloc_viz.rerun_model import steps_from_flight
from geoloc.workflows.flight import FlightScenario

scn = FlightScenario.from_toml("assets/scenarios/flight_scan.toml")
steps = steps_from_flight(scn)
write(steps, "/tmp/flight_scan.rrd")

frame_deg = np.rad2deg(steps.pose.gimbal_roll)
err = steps.truth["error_m"]
ell = steps.extra_series["series/ellipsoid_model/to_truth_m"]
cep = steps.extra_series.get("series/cep/cep_m")
print(f"{len(steps)} steps written to /tmp/flight_scan.rrd (scene origin {steps.enu})")
print("frame angle [deg]  steps error [m]  ellipsoid-model error [m]  CEP [m]  DEM evaluations")
for k in range(0, 41, 5):  # the first sweep, 10 -> 82 deg
    c = f"{cep[k]:7.1f}" if cep is not None else "      -"
    print(f"{frame_deg[k]:17.1f}  {err[k]:15.1f}  {ell[k]:25.1f}  {c}  {steps.terrain.dem_evaluations[k]:15d}")
