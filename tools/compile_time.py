"""Where a cold numba cache's time goes: each of geoloc's kernels compiled afresh, its CPU seconds.

    python tools/compile_time.py [--only W1,W2] [--keep DIR]

Runs, in this process, with an empty private cache (a new temporary ``NUMBA_CACHE_DIR``, set before
numba is imported; the user's cache, ``~/.cache/geoloc/numba``, is neither read nor touched), the
calls that compile every kernel the tests and verbs use, each the way they make it: the fused
locate (``locate(..., engine="numba")``, with and without refraction), the uncertainty kernels
(``propagate(..., engine="numba")`` on a height and on the DEM, with and without the Jacobian, the
fisheye's central differences), the terrain walk of a large batch and the refraction kernels
(``geoloc warm``'s steps) and the frame grid (``geoloc.workflows.ortho.frame_line_of_sight``).

Prints, per workload, its CPU and wall seconds on the cold cache and again at once (compiled: its
run alone), so that ``cold - again`` is the compile; then per kernel the CPU seconds of its
compiles (:data:`geoloc.geodesy._nbgeo.COMPILED`, its own time: the kernels it calls that compiled
inside it are taken out and listed on their own lines) and how many specialisations numba made of
it (``dispatcher.signatures``: more than one is one kernel compiled again for another argument
type or layout); last the totals and the load average. Figures are CPU seconds
(``time.process_time``): a shared machine stretches the wall time, not the CPU time.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _private_cache(keep: str | None) -> str:
    """An empty ``NUMBA_CACHE_DIR`` for this process, set before numba is imported."""
    if "numba" in sys.modules:
        raise RuntimeError("numba imported before the private cache was set")
    d = keep or tempfile.mkdtemp(prefix="geoloc-compile-time-")
    os.makedirs(d, exist_ok=True)
    if any(Path(d).iterdir()):
        raise SystemExit(f"compile_time: --keep {d} is not empty (the cache must start cold)")
    os.environ["NUMBA_CACHE_DIR"] = d
    return d


def _turret():
    from geoloc.sensors.sensor_file import load_sensor

    return load_sensor(ROOT / "assets" / "sensors" / "eo_turret.toml")


def _poses(n, seed=0):
    import numpy as np

    from geoloc.frames.chain import Pose

    rng = np.random.default_rng(seed)
    pose = Pose.from_deg(
        36.47 + rng.uniform(0, 0.1, n),
        -84.246 + rng.uniform(0, 0.1, n),
        rng.uniform(2000, 4000, n),
        rng.uniform(0, 360, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-3, 3, n),
        angles_deg={"azimuth": rng.uniform(0, 360, n), "elevation": rng.uniform(-85, -30, n)},
    )
    vel = np.stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(-3, 3, n)], -1)
    return pose, rng.uniform(1, 1080, n), rng.uniform(1, 1920, n), vel


def w_locate():
    """The fused locate kernel (``engine="numba"``), without and with refraction."""
    from geoloc.corrections.refraction import STANDARD_REFRACTION
    from geoloc.locate import locate
    from geoloc.pipeline import Corrections

    s = _turret()
    pose, row, col, _ = _poses(64)
    locate(pose, s, row, col, 500.0, engine="numba")
    locate(pose, s, row, col, 500.0, engine="numba", corrections=Corrections(refraction=STANDARD_REFRACTION))


def _budget(s, lens_keys=True):
    from geoloc.sensors.budget import ErrorBudget

    b = {"north_m": 2.0, "east_m": 2.0, "up_m": 3.0, "heading_deg": 0.03, "pitch_deg": 0.02, "roll_deg": 0.02}
    b.update({f"{a}_deg": 0.01 for a in s.angle_names})
    b.update(mount_x_deg=0.01, boresight_y_deg=0.01, lever_arm_x_m=0.05, time_s=0.005, height_m=10.0, dem_m=9.73)
    if lens_keys:
        b.update(fx_px=2.0, cx_px=0.5, k1=0.001)
    return ErrorBudget(b)


def w_uncertainty():
    """``propagate(engine="numba")`` on a height and on the SRTM crop, with and without the Jacobian,
    a Brown lens and a fisheye (the chain kernel's central differences)."""
    import dataclasses

    from geoloc.analysis import uncertainty as U
    from geoloc.sensors.lenses import FisheyeLens
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.height import HeightSurface
    from geoloc.surfaces.terrain import DemSurface

    dem = DEM.open(ROOT / "assets" / "dem" / "srtm_jacksboro.tif")
    s = _turret()
    fish = dataclasses.replace(
        s, lens=FisheyeLens(fx=900.0, fy=900.0, cx=960.5, cy=540.5, width=1920, height=1080, k1=0.02)
    )
    pose, row, col, vel = _poses(64, 1)
    for sensor in (s, fish):
        b = _budget(sensor)
        for surf in (HeightSurface(500.0), DemSurface(dem)):
            for jac in (True, False):
                U.propagate(sensor, pose, row, col, b, surface=surf, velocity_ned_m_s=vel, engine="numba", jacobian=jac)


def w_walk():
    """``geoloc warm``'s large batch: the compiled terrain walk (bilinear cells) of 20 000 rays."""
    from geoloc.cli import warm

    warm._large_batch()


def w_refraction():
    """``geoloc warm``'s refraction step: a ray on a height, on the DEM, and a limb ray."""
    from geoloc.cli import warm

    warm._refraction()


def w_grid():
    """The frame grid's lines of sight (``geoloc ortho``)."""
    import numpy as np

    from geoloc.workflows.ortho import frame_line_of_sight

    from geoloc.frames.chain import Pose

    pose = Pose.from_deg(36.5, -84.2, 3000.0, 45.0, 1.0, 0.5, angles_deg={"azimuth": 90.0, "elevation": -40.0})
    frame_line_of_sight(_turret(), pose, np.arange(1, 9.0), np.arange(1, 17.0))


WORKLOADS = {
    "locate": w_locate,
    "uncertainty": w_uncertainty,
    "walk": w_walk,
    "refraction": w_refraction,
    "grid": w_grid,
}


def _timed(fn):
    c, w = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - w


def _spans():
    """Wrap the kernel cache's miss and save so that each compile's CPU interval is kept:
    [(kernel, start, end)] (a kernel compiled inside another one lies within its interval)."""
    from geoloc.geodesy import _nbgeo

    _nbgeo._activate()
    cls = _nbgeo._KeyedFunctionCache  # made by _activate (numba's cache API)
    spans: list = []
    load, save = cls.load_overload, cls.save_overload

    def load_overload(self, sig, target_context):
        got = load(self, sig, target_context)
        if got is None and self._t_miss is not None:
            self._t_start = self._t_miss
        return got

    def save_overload(self, sig, data):
        start = getattr(self, "_t_start", None)
        try:
            return save(self, sig, data)
        finally:
            if start is not None:
                spans.append((self.kernel_name, start, time.process_time()))
                self._t_start = None

    cls.load_overload, cls.save_overload = load_overload, save_overload
    return spans


def _self_times(spans):
    """Each span's own CPU seconds: its length less the spans nested directly in it."""
    out = []
    for k, (name, a, b) in enumerate(spans):
        inner = [(x, y) for j, (_n, x, y) in enumerate(spans) if j != k and a <= x and y <= b]
        # only the outermost of the nested ones
        top = [(x, y) for (x, y) in inner if not any((u <= x and y <= v) and (u, v) != (x, y) for (u, v) in inner)]
        out.append((name, b - a, b - a - sum(y - x for x, y in top)))
    return out


def _dispatchers():
    """Every compiled kernel of geoloc loaded now: (module, name, dispatcher)."""
    from numba.core.dispatcher import Dispatcher

    seen, out = set(), []
    for mname, mod in sorted(sys.modules.items()):
        if not mname.startswith("geoloc") or mod is None:
            continue
        for name, obj in vars(mod).items():
            if isinstance(obj, Dispatcher) and id(obj) not in seen and obj.py_func.__module__ == mname:
                seen.add(id(obj))
                out.append((mname, name, obj))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", help="comma-separated workloads: " + ", ".join(WORKLOADS))
    ap.add_argument("--keep", help="use (and keep) this empty folder as the cache instead of a temporary one")
    args = ap.parse_args(argv)
    cache = _private_cache(args.keep)
    sys.path.insert(0, str(ROOT))
    names = args.only.split(",") if args.only else list(WORKLOADS)
    try:
        import numba

        spans = _spans()
        print(f"numba {numba.__version__}, cold cache {cache}, threads {numba.get_num_threads()}")
        print(f"{'workload':12s} {'cold CPU':>9s} {'again CPU':>9s} {'compile':>8s} {'cold wall':>9s}  load")
        total_cold = total_run = 0.0
        for name in names:
            fn = WORKLOADS[name]
            c1, w1 = _timed(fn)
            c2, _w2 = _timed(fn)
            total_cold += c1
            total_run += c2
            print(f"{name:12s} {c1:9.1f} {c2:9.1f} {c1 - c2:8.1f} {w1:9.1f}  {os.getloadavg()[0]:.1f}", flush=True)
        print()
        print(f"{'kernel':32s} {'own CPU s':>9s} {'with callees':>12s} {'sigs':>4s}")
        per: dict[str, tuple[float, float, int]] = {}
        for kname, whole, own in _self_times(spans):
            w0, o0, n0 = per.get(kname, (0.0, 0.0, 0))
            per[kname] = (w0 + whole, o0 + own, n0 + 1)
        sigs = {name: len(d.signatures) for _m, name, d in _dispatchers()}
        for kname, (whole, own, _n) in sorted(per.items(), key=lambda kv: -kv[1][1]):
            print(f"{kname:32s} {own:9.1f} {whole:12.1f} {sigs.get(kname, 0):4d}")
        many = sorted(f"{n} ({k})" for n, k in sigs.items() if k > 1)
        print()
        print(
            f"total: {sum(o for _w, o, _n in per.values()):.1f} s CPU compiling {len(per)} kernels "
            f"({len(spans)} compiles); the workloads {total_cold:.1f} s CPU cold, {total_run:.1f} s again, "
            f"{total_cold - total_run:.1f} s the difference; load {os.getloadavg()[0]:.1f}"
        )
        print("specialised more than once: " + (", ".join(many) if many else "none"))
    finally:
        if not args.keep:
            shutil.rmtree(cache, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
