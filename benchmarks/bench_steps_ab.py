"""Functions split into named steps, this tree's against git revision REV's, in one process.

    python benchmarks/bench_steps_ab.py [REV] [--pairs N] [--only K1,K2]

REV (default ``main``) is imported as a package of another name (``benchmarks/_revision.package_at``,
as ``guard.py`` does), so each side runs its own code on inputs it builds with its own classes.
Calls alternate old/new in ABBA order (``guard.measure``); per function one line: the median of
the pairs' CPU ratios old / new (> 1: this tree is faster) with its quartiles, the fastest
quarters' ratio, both sides' median CPU and wall time per call, the load, and whether the two
sides' results are equal. Functions:

- ``replay``: ``klv_replay._replay`` of the bundled example flight (299 packets, each packet's
  own frame-centre height);
- ``fit``: ``sensor_fit.fit_sensor_params`` of the mount (3 angles) to the bundled [Q17] flight
  tests with their paper heights, leave-one-out on;
- ``geotiff``: ``ortho.write_frame_geotiff`` of the [Q17] camera's frame, every 4th pixel, on
  the first record's pose and a constant height;
- ``maker``: ``photos._read_maker`` of a Skydio photo's tags (position, heights, angles, lens),
  200 times a call (one is about a millisecond's fifth: too short to time alone).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]
from _revision import package_at  # noqa: E402
from guard import low_ratio, measure, ratios  # noqa: E402

SKYDIO_NS = "http://www.skydio.com/drone-skydio/1.0/"
SKYDIO_TAGS = {
    "Latitude": "36.52",
    "Longitude": "-84.21",
    "AbsoluteAltitude": "412.5",
    "RelativeAltitude": "120.0",
    "CameraOrientationNED/Yaw": "30.0",
    "CameraOrientationNED/Pitch": "-45.0",
    "CameraOrientationNED/Roll": "0.5",
    "CalibratedFocalLength/X": "2000.5",
    "CalibratedFocalLength/Y": "2001.0",
    "CalibratedOpticalCenter/X": "2010.0",
    "CalibratedOpticalCenter/Y": "1500.0",
}


def cases(pkg: str, tmp: Path) -> dict:
    """Name -> a call of ``pkg``'s function on inputs built with ``pkg``'s own classes."""
    m = lambda name: importlib.import_module(f"{pkg}.{name}")  # noqa: E731
    kr, assets = m("workflows.klv_replay"), m("assets")
    read = kr.read_klv(assets.asset_path("klv", "example_flight.klv"))
    records = m("io.records").load_records(assets.asset_path(*assets.DEFAULT_RECORDS))
    cam = m("locate").as_sensor(m("sensors.camera").Camera.from_toml(assets.asset_path(*assets.DEFAULT_CAMERA)))
    paper_h = m("surfaces.height").PerRecordHeightSurface(records.column("paper_height_m"))
    fit = m("analysis.sensor_fit").fit_sensor_params
    mount = ["mount_x", "mount_y", "mount_z"]
    ortho = m("workflows.ortho")
    pose0, flat = records.pose().take([0]), m("surfaces.height").HeightSurface(0.0, "geodetic")
    photos = m("io.photos")
    maker = m("io.photo_makers").maker_by_name("Skydio")

    def read_maker():
        for _ in range(200):
            meta = photos.PhotoMeta(path="x.jpg", width=4000, height=3000, xmp={}, notes=[])
            photos._read_maker(meta, maker, {SKYDIO_NS: SKYDIO_TAGS}, {}, [])
        return (meta.lat_deg, meta.gimbal_yaw_deg, meta.calibrated_focal_px, meta.missing)

    return {
        "replay": lambda: kr._replay(read, None, None).columns["frame_center_error_m"],
        "fit": lambda: fit(records, cam, mount, paper_h, loo=True).values,
        "geotiff": lambda: ortho.write_frame_geotiff(tmp / f"{pkg}.tif", cam, pose0, flat, step=4)["counts"],
        "maker": read_maker,
    }


def _equal(a, b) -> bool:
    try:
        return bool(np.array_equal(np.asarray(a, float), np.asarray(b, float), equal_nan=True))
    except (TypeError, ValueError):
        return a == b


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", nargs="?", default="main")
    ap.add_argument("--pairs", type=int, default=15)
    ap.add_argument("--only", default="", help="comma-separated names (default all)")
    a = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)  # CPU time is then the function's own work
    old_pkg, old_label = package_at(a.rev)
    with tempfile.TemporaryDirectory() as d:
        old, new = cases(old_pkg, Path(d)), cases("geoloc", Path(d))
        for k in [s.strip() for s in a.only.split(",")] if a.only else list(new):
            load0 = os.getloadavg()[0]
            cpu, wall, (r_old, r_new) = measure(old[k], new[k], a.pairs)
            med, q1, q3 = ratios(cpu)
            print(
                f"{k:8s} CPU old/new {med:.3f} (quartiles {q1:.3f}-{q3:.3f}, fastest quarters {low_ratio(cpu):.3f}); "
                f"per call CPU {np.median(cpu[:, 0]) * 1e3:.3g} / {np.median(cpu[:, 1]) * 1e3:.3g} ms, "
                f"wall {np.median(wall[:, 0]) * 1e3:.3g} / {np.median(wall[:, 1]) * 1e3:.3g} ms; "
                f"load {load0:.1f}-{os.getloadavg()[0]:.1f}; {a.pairs} pairs against {old_label}; "
                f"results equal: {_equal(r_old, r_new)}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
