"""The picture behind a KLV packet: find the painted targets in the video, fit the time offset.

The bundled example flight's MPEG-TS (``assets/klv/example_flight.ts``) holds a video rendered by
geoloc from the true pose beside the KLV metadata (docs/picture.md). This example

1. opens the video lazily (:func:`geoloc.io.images.open_images`) and reads the packets' poses
   (:func:`geoloc.workflows.klv_replay.replay_klv`);
2. finds the five painted crosses in a clean frame and locates the first one through its pixel,
   as a click in the viewer's picture panel does, against its surveyed position;
3. fits the stream's metadata-to-video ``time_offset_s`` on frames 40-79, where the video was
   planted 1.5 s ahead of its metadata (:func:`geoloc.workflows.video_sync.fit_klv_time_offset`).

Run: ``python examples/55_picture_time_offset.py``
"""

from pyproj import Geod

from geoloc.io.images import open_images
from geoloc_viz import picture_model as pm
from geoloc_viz.flight_model import default_flight_scenario, read_targets
from geoloc.workflows.klv_replay import replay_klv
from geoloc.workflows.render import find_marks
from geoloc.workflows.video_sync import fit_klv_time_offset

TS = "assets/klv/example_flight.ts"
targets = read_targets("assets/klv/example_flight_targets.csv")
images = open_images(TS)
print(f"{TS}: {len(images)} frames {images.cols} x {images.rows}, time_offset_s = {images.time_offset_s}")

# 2. a clean frame: the crosses, and the first one located as a click locates it (exact DEM walk)
scn = default_flight_scenario()
idx = [str(i.label) for i, _ in scn.records].index("packet 90")
inputs = scn.records[idx][1].replace(method="exact")
img = scn.images.image(pm.image_index(scn, idx))
sensor = pm.frame_sensor(scn, idx, *img.shape[:2])
found, _ = find_marks(img)
print(f"packet 90: {len(found)} painted crosses found")
r, c = found[0]
p = pm.locate_pixel(scn, inputs, sensor, r, c)
geod = Geod(ellps="WGS84")
d, name = min((geod.inv(p.lon_deg(), p.lat_deg(), lo, la)[2], n) for n, la, lo, _ in targets)
print(
    f"cross at pixel ({r:.1f}, {c:.1f}) -> {p.lat_deg():.7f} N {p.lon_deg():.7f} E, h {float(p.hit.h):.1f} m "
    f"({pm.H_DATUM}): {d:.2f} m from surveyed {name}"
)

# 3. the timing fault: fit the offset from the crosses on frames 40-79
pts = [(la, lo, h) for _, la, lo, h in targets]
fit = fit_klv_time_offset(TS, pts, range(40, 80), replay=replay_klv(TS), images=images)
print(f"frames 40-79: {fit}")
print(f"planted: the video 1.5 s ahead, time_offset_s = -1.5; fitted {fit.time_offset_s:+.3f} s")
