"""60: the synthetic ZY-3-like pushbroom scene [L12]: footprint, ground sample, ground -> image.

Run: python examples/60_pushbroom_scene.py
"""

import numpy as np

from geoloc.assets import asset_path
from geoloc.sensors.pushbroom import PushbroomSensor
from geoloc.pipeline import at_height

s = PushbroomSensor.from_toml(asset_path("scenarios", "zy3_nadir.toml"))
print(f"{s.name}: {s.rows} lines x {s.cols} detectors, line period {s.line_period_s * 1e3:.4f} ms")

# the four corners and the centre of the scene on the ellipsoid-height surface h = 300 m
rows = np.array([1, 1, s.rows, s.rows, (s.rows + 1) / 2])
cols = np.array([1, s.cols, 1, s.cols, (s.cols + 1) / 2])
g = at_height(s, rows, cols, 300.0)
for r, c, la, lo in zip(rows, cols, g.lat_deg, g.lon_deg):
    print(f"  pixel ({r:8.1f}, {c:8.1f}) -> {la:.6f} N {lo:.6f} E")

# ground sample distance at the centre, across and along track
r0, c0 = (s.rows + 1) / 2, (s.cols + 1) / 2
e = at_height(s, [r0, r0, r0 + 1], [c0, c0 + 1, c0], 300.0).ecef
print(
    f"ground sample: across {np.linalg.norm(e[1] - e[0]):.3f} m, along {np.linalg.norm(e[2] - e[0]):.3f} m"
    " ([L12] Table 2: 2.1 m)"
)

# ground -> image: iteration over the line time
row, col, st = s.ground_to_pixel(g.lat, g.lon, g.h)
print("ground -> image round trip, max error [px]:", float(np.max(np.hypot(row - rows, col - cols))))
