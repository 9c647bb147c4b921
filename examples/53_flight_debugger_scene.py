"""A whole flight for the viewer, built in Python: footprints, residuals, outliers, what they look like.

The bundled example flight (MISB ST 0601 KLV over the SRTM crop, ``assets/klv/example_flight.klv``)
in one batch (:func:`geoloc_viz.flight_model.build`): every frame's footprint on the DEM, its
recomputed frame centre against the reported one, the robust outlier flags, and the fault that
best explains each run of outliers. ``geoloc view`` draws the same model (docs/flight_debugger.md).

Run: ``python examples/53_flight_debugger_scene.py``
"""

import math
import time

import numpy as np

from geoloc_viz.flight_model import build, default_flight_scenario

scn = default_flight_scenario()
t0 = time.perf_counter()
m = build(scn)
dt = time.perf_counter() - t0

P = m.footprint_enu.shape[1]
print(f"{len(m)} frames of {scn.source}; footprints of {P} points each on {m.surface}")
print(f"built in {dt:.2f} s (one batch of {len(m) * (P + 2)} lines of sight); heights {m.H_DATUM}")
print(f"{int(m.outlier.sum())} outliers (robust median / MAD rule on the residual, recomputed vs {m.reference})")
print("top outliers:")
for i in m.top(5):
    c = m.components
    print(
        f"  {m.labels[i]}: {m.residual_m[i]:.1f} m (along {c['along_m'][i]:+.1f} m, across {c['across_m'][i]:+.1f} m)"
    )
print("runs of outliers and what they look like:")
for f in m.faults:
    print(f"  {f.headline()}")
ok = ~m.outlier & np.isfinite(m.residual_m)
print(f"the other {int(ok.sum())} frames: median residual {np.median(m.residual_m[ok]) * 1e3:.1f} mm")
w = np.linalg.norm(m.corners_enu[:, 1] - m.corners_enu[:, 0], axis=1)
print(
    f"footprint width (top edge): {w.min():.0f} to {w.max():.0f} m as the turret zooms "
    f"(largest heading-bias fit {max((math.degrees(f.value) for f in m.faults if f.kind == 'attitude'), default=0):+.2f} deg)"
)
