"""The Sentinel-2 recording (geoloc_viz.rerun_sentinel2) read back with rerun's own reader.

Expected values come from outside the module: the core's orbit interpolation, pyproj's
ECEF -> geodetic (EPSG:4978 -> 4979), and a physical fact of the satellite: Sentinel-2 flies
nadir-pointing with yaw steering, so its body frame stays within hundredths of a degree of the
orbital frame built from the Earth-fixed velocity (a wrong quaternion convention or a wrong
inertial-to-Earth rotation would show degrees).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from geoloc.io.sentinel2 import read_product

PRODUCT = Path(__file__).parents[1] / "data" / "sentinel2" / "L1B"
TO_LLH = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def read_rrd(path):
    from rerun.chunk import RrdReader

    out: dict = {}
    for ch in RrdReader(path).stream():
        b = ch.to_record_batch()
        ent = out.setdefault(ch.entity_path, {})
        for n in b.schema.names:
            col = b.column(n)
            if str(col.type).startswith(("duration", "timestamp")):
                col = col.cast("int64")
            ent.setdefault(n, []).extend(col.to_pylist())
    return out


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from geoloc_viz.rerun_sentinel2 import write

    sensor = read_product(PRODUCT).sensor("B02", 6)
    out = tmp_path_factory.mktemp("s2") / "s2.rrd"
    steps = write(sensor, out, n_steps=12)
    return sensor, steps, read_rrd(out)


def test_the_satellite_is_on_its_orbit(recording):
    sensor, steps, data = recording
    sat = data["/world/satellite"]
    tr = np.array([r[0] for r in sat["Transform3D:translation"]])
    t = np.array(sat["time"]) * 1e-9 + sensor.line_time(1.0)
    p, _ = sensor.orbit.state(t)
    assert tr.shape == (12, 3)
    assert np.max(np.abs(tr - p * 1e-3)) < 1e-3  # km, float32 of 7000 km: 0.5 m
    alt = np.array([r[0] for r in data["/series/ephemeris/altitude_km"]["Scalars:scalars"]])
    _, _, h = TO_LLH.transform(p[:, 0], p[:, 1], p[:, 2])
    assert np.allclose(alt, h * 1e-3, atol=1e-6)
    assert np.all((alt > 780) & (alt < 800))  # Sentinel-2's 786 km orbit


def test_the_lines_of_sight_end_on_the_ground(recording):
    _, _, data = recording
    strips = data["/world/los"]["LineStrips3D:strips"]
    ends = np.array([[s[1] for s in row] for row in strips], float) * 1e3  # (steps, 3 lines, 3)
    _, _, h = TO_LLH.transform(ends[..., 0], ends[..., 1], ends[..., 2])
    assert ends.shape == (12, 3, 3)
    assert np.max(np.abs(h)) < 2.0  # the surface h = 0; float32 km coordinates: 0.5 m


def test_the_body_frame_follows_the_yaw_steered_orbital_frame(recording):
    _, steps, data = recording
    for name in ("roll", "pitch", "yaw"):
        v = np.array([r[0] for r in data[f"/series/attitude/{name}_deg"]["Scalars:scalars"]])
        assert np.allclose(v, np.degrees(steps[name]))
        assert np.max(np.abs(v)) < 0.05, name  # measured 0.0035 deg
