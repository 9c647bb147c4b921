"""81: the [Q17] flight-test records on the bundled ETOPO5 crop, one rerun step per record.

What a 5' DEM costs against the paper's heights: the recording's error series
against the surveyed positions, and the heights the bisection of [L23] finds.
Run from the repository root; open ``/tmp/flight_test_dem.rrd`` with ``rerun``.
"""

import numpy as np

from geoloc_viz.rerun_log import write
from geoloc_viz.rerun_model import steps_from_records

records = "assets/records/qiao2017_flight_tests.csv"
at_paper, _ = steps_from_records(records)  # paper_height_m
on_dem, _ = steps_from_records(records, dem_path="assets/dem/etopo5_flight_area.tif", method="bisect", threshold_m=5.0)
write(on_dem, "/tmp/flight_test_dem.rrd")

print("record   h paper [m]  h ETOPO5 [m]  to truth, paper h [m]  to truth, ETOPO5 [m]  DEM evals")
for k, label in enumerate(on_dem.labels):
    print(
        f"{label:<8} {at_paper.ground.h[k]:11.1f}  {on_dem.ground.h[k]:12.1f}  "
        f"{at_paper.truth['error_m'][k]:21.1f}  {on_dem.truth['error_m'][k]:20.1f}  "
        f"{on_dem.terrain.dem_evaluations[k]:9d}"
    )
print(
    f"mean error to truth: {np.nanmean(at_paper.truth['error_m']):.1f} m at the paper's heights, "
    f"{np.nanmean(on_dem.truth['error_m']):.1f} m on ETOPO5 -> /tmp/flight_test_dem.rrd"
)
