"""83: before / after calibration of a sensor file on a DEM, as rerun series.

The bundled EO turret flight (one orbit, 24 records with a survey) is located on the
SRTM crop around it, then the turret's mounting rotation (mount_x, mount_y, mount_z)
is fitted to the survey by ``geoloc.analysis.sensor_fit.fit_sensor_groups`` on the
same DEM; ``series/calibration/before_m`` and ``after_m`` hold each record's
horizontal error to the truth before and after (docs/rerun.md). Writes the recording
to argv[1] (default /tmp/turret_calibration.rrd). Same as:

    geoloc log assets/records/eo_turret_flight.csv --camera assets/sensors/eo_turret.toml \\
        --dem assets/dem/srtm_jacksboro.tif --fit mount_x,mount_y,mount_z --out turret.rrd
"""

import sys

import numpy as np

from geoloc_viz.rerun_log import write
from geoloc_viz.rerun_model import load_camera, steps_from_records

out = sys.argv[1] if len(sys.argv) > 1 else "/tmp/turret_calibration.rrd"
steps, _ = steps_from_records(
    "assets/records/eo_turret_flight.csv",
    load_camera("assets/sensors/eo_turret.toml"),
    dem_path="assets/dem/srtm_jacksboro.tif",
    fit_names=["mount_x", "mount_y", "mount_z"],
)
write(steps, out)

cal = steps.calibration
print(f"{len(steps)} records written to {out}")
print(
    f"mean error to truth: before {np.mean(cal['before_m']):.2f} m, after {np.mean(cal['after_m']):.2f} m; "
    f"worst after {np.max(cal['after_m']):.1f} m ({steps.labels[int(np.argmax(cal['after_m']))]})"
)
for g, e in cal["report"]["groups"].items():
    fitted = ", ".join(f"{k} {v['value']:+.3f} +- {v['sd']:.3f} deg" for k, v in e["parameters"].items())
    print(f"fitted mount ({g}): {fitted}")
