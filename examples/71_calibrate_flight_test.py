"""71: the [Q17] flight test, debugged: ~50 m systematic errors, a fitted mounting rotation, ~6 m honest.

Runs the calibration of issue 8 on the bundled records (assets/records/
qiao2017_flight_tests.csv) with the target heights of `paper_height_m`:
per flight (one mounting rotation each) and jointly (one rotation for both
flights), with leave-one-out cross-validation, then draws the error vectors
per flight (docs/figures/71_error_vectors.png, or the path given as argv[1]).
Same numbers as:

    geoloc calibrate --height-column paper_height_m --group-by table --loo
"""

import sys
from pathlib import Path

import numpy as np

from geoloc.analysis.calibrate import (
    calibrate_groups,
    error_vector_panels,
    resect_camera,
)
from geoloc.analysis.errors import plot_error_vectors
from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.io.records import load_records
from geoloc.sensors.camera import Camera
from geoloc.surfaces.height import PerRecordHeightSurface

records = load_records(asset_path(*DEFAULT_RECORDS))
camera = Camera.from_toml(asset_path(*DEFAULT_CAMERA))
surface = PerRecordHeightSurface(records.column("paper_height_m"))  # each target at its height

for model, joint in (("mount", False), ("mount", True), ("camera", False), ("camera", True)):
    report, _ = calibrate_groups(records, camera, surface, "table", model=model, joint=joint, loo=True)
    print(f"model {model!r}, {'one rotation for both flights' if joint else 'one rotation per flight'}:")
    for g, e in report["groups"].items():
        b = e["before"]
        ang = ", ".join(f"{a:+.3f}+-{s:.3f}" for a, s in zip(e["angles_deg"], e["angles_sd_deg"]))
        print(f"  {g}: before {e['mean_error_before_m']:5.1f} m (bias along {b['bias_along_m']:+.1f} m, "
              f"cross {b['bias_cross_m']:+.1f} m), after {e['mean_error_after_m']:4.1f} m, "
              f"leave-one-out {e['mean_error_loo_m']:4.1f} m; angles (x, y, z) deg: {ang}")
    if model == "mount" and joint:
        figure_report = report

r = resect_camera(records, Camera(150000.0, 1100.0, 1100.0, camera.rows, camera.cols))
print(f"resection from the published positions: f = {r.camera.focal_length_px:.1f} +- {r.sd_focal_px:.0f} px, "
      f"i0 = {r.camera.principal_row:.2f} +- {r.sd_principal_row:.2f}, "
      f"j0 = {r.camera.principal_col:.2f} +- {r.sd_principal_col:.2f}, RMS misfit {r.rms_m:.2f} m "
      f"(bundled camera: 166841.0, 1162.12, 1146.42)")

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "docs" / "figures" / "71_error_vectors.png"
out.parent.mkdir(parents=True, exist_ok=True)
plot_error_vectors(out, error_vector_panels(figure_report, records, exaggeration=10.0),
                   title="[Q17] flight test: error vectors (computed - truth), one mounting rotation for both flights")
print(f"wrote {out}")
print("max leave-one-out flight mean [m]:",
      np.round(max(e["mean_error_loo_m"] for e in figure_report["groups"].values()), 2))
