"""82: the [Q17] flight test as a rerun recording a debugger can use.

One entity tree and scene origin per flight (T3 and T4 are ~200 km apart), the
record labels in a log on the timeline, the error components (north, east,
along, across) and outlier flags as series, the errors before and after the
per-flight mounting calibration, an offline 2D target/truth plot and a 3D view
that follows the current hit (docs/rerun.md). Writes the recording to argv[1]
(default /tmp/flight_test_debugger.rrd); open it with ``rerun FILE``. Same as:

    geoloc log assets/records/qiao2017_flight_tests.csv --out flight_test.rrd
"""

import sys

import numpy as np

from geoloc_viz.rerun_log import write
from geoloc_viz.rerun_model import steps_from_records

out = sys.argv[1] if len(sys.argv) > 1 else "/tmp/flight_test_debugger.rrd"
steps, _ = steps_from_records("assets/records/qiao2017_flight_tests.csv")
write(steps, out)

c, cal = steps.components, steps.calibration
print(f"{len(steps)} records written to {out}")
for g in steps.groups:
    m = steps.group_of == g
    e = steps.enu_for(g)
    print(
        f"flight {g}: origin {np.rad2deg(e.lat0):.3f} N {np.rad2deg(e.lon0):.3f} E {e.h0:.0f} m; "
        f"mean error along {c['along_m'][m].mean():+.1f} m, across {c['across_m'][m].mean():+.1f} m; "
        f"before {cal['before_m'][m].mean():.1f} m, after calibration {cal['after_m'][m].mean():.1f} m; "
        f"outliers {int(steps.outlier[m].sum())}"
    )
