"""The first run of a fresh install: ``locate --dem``, ``replay`` and ``view`` on a cold
numba cache, against the same call on the warm cache (the peer), in the same run.

Each call runs in a new process (``python -m geoloc ...``) with ``NUMBA_CACHE_DIR`` set to a
new empty folder (cold: numba compiles every kernel the call needs) and then again with that
folder filled (warm). ``view`` counts until it serves (its "geoloc view: http://..." line),
then is stopped. For each the child's wall time, CPU time (user + system, from
``os.wait4``'s rusage, or /proc/PID/stat for the server still running) and peak RSS
(``ru_maxrss`` / VmHWM). The target: the first call of each verb within
10 s and 500 MB. ``geoloc warm`` (tools/run.sh) compiles them ahead of that first call.

Run: ``python benchmarks/bench_first_run.py [--repeat N] [--only locate,replay,view,scene]``
(medians over N cold folders; 15-30 s of CPU per cold call on 2 cores).

Measured 2026-12-04 (2 cores, load 1.2-2.7, medians of 3), after the viewer's flight model
walked uncompiled while its cost projected over the batch fits (``terrain_numba.uncompiled_budget``)
and the picture's horizon became calls of 64 rays or fewer: cold locate 0.9 s wall, 1.1 s CPU, 300 MB; replay 0.9 s,
1.1 s, 300 MB; view 1.3 s, 1.5 s, 359 MB; scene 3.1 s, 3.9 s, 445 MB; each the same warm (the
scene's 5364 footprint rays walk uncompiled, 0.5-0.9 s, and nothing compiles). main cf216e5 in
the same session: scene cold 8.0 s wall, 8.8 s CPU, 518 MB (the walk's compile), warm 3.1 s,
3.9 s, 470 MB; locate cold 1.0 s, 1.2 s, 300 MB.

Measured 2026-12-03 (2 cores, load 1.7-2.7, medians of 3), after a call of up to 64 rays ran
the walk uncompiled and the walk was compiled per cell model: cold locate 2.4 s wall, 2.2 s
CPU, 217 MB; replay 2.6 s, 2.4 s, 217 MB; view 4.0 s, 3.1 s, 257 MB; warm 2.0 / 2.4 / 3.1 s
CPU. ``view`` is counted until it serves, and it now serves before it walks more than one ray:
the first scene a browser asks for compiles the walk: the ``scene`` row, ``geoloc view
--export`` (load 3.2-3.5, one run: cold 22.5 s wall, 17.8 s CPU, 419 MB; warm 9.7 s, 7.5 s
CPU, 361 MB; the walk's compile 10.8 s of CPU). Before
(main 2a78c8e, load 0.9-1.9): cold locate 19.1 s wall, 15.1 s CPU, 313 MB; replay 14.9 s,
13.7 s, 314 MB; view 16.2 s, 15.2 s, 365 MB.

Measured 2026-12-02 (2 cores at a load of 17-21, so wall times are 5-15x the CPU; one run
each), after the walk's helpers stopped being numba-inlined: cold locate 15.0 s CPU, 386 MB;
replay 16.7 s, 383 MB; view 18.0 s, 455 MB; warm 2.3 / 2.6 / 2.9 s CPU. Before: 41-48 s CPU
and ~1 GB each (the flat walk's compile alone 52-55 s of CPU, 1 GB).
"""

from __future__ import annotations

import argparse
import os
import queue
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
A = ROOT / "assets"
CALLS = {
    "locate": [
        "locate",
        "--sensor",
        str(A / "sensors/eo_turret.toml"),
        "--lat-deg",
        "36.6",
        "--lon-deg",
        "-84.25",
        "--h-m",
        "2500",
        "--heading-deg",
        "45",
        "--angle",
        "azimuth=90",
        "--angle",
        "elevation=-30",
        "--dem",
        str(A / "dem/srtm_jacksboro.tif"),
    ],
    "replay": [
        "replay",
        str(A / "records/drone_targets.csv"),
        "--sensor",
        str(A / "sensors/drone_camera.toml"),
        "--dem",
        str(A / "dem/srtm_jacksboro.tif"),
    ],
    "view": ["view", "--no-browser", "--port", "0"],
    # the scene a browser's first page asks for, built and written without a server: view counts
    # until it serves, and it serves before it walks more than one ray (the scene's 792 + 5364 +
    # 110 rays, which compiled the walk before they walked uncompiled)
    "scene": ["view", "--export", "{cache}/scene.html"],
}
CLK = os.sysconf("SC_CLK_TCK")


def _env(cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    env.pop("GEOLOC_ANNOUNCE_COMPILE", None)
    return env


def run_once(verb: str, cache: Path) -> dict:
    """One call in a new process: wall s, CPU s, peak RSS MB."""
    cmd = [sys.executable, "-m", "geoloc", *(a.replace("{cache}", str(cache)) for a in CALLS[verb])]
    t0 = time.perf_counter()
    if verb != "view":
        p = subprocess.Popen(cmd, env=_env(cache), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError(f"{verb}: exit {status}: {p.stderr.read().decode()[-400:]}")
        return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024}
    p = subprocess.Popen(cmd, env=_env(cache), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        # a thread reads the lines: a select() on the pipe then a buffered readline() misses a line
        # that came in one chunk with the one before (viser's banner, then geoloc's), and waited
        # for the next output or the timeout (the 103.8 s "first view" of an earlier run)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [lines.put(x) for x in iter(p.stdout.readline, "")], daemon=True).start()
        line = ""
        while "geoloc view: http" not in line:
            try:
                line = lines.get(timeout=600)
            except queue.Empty:
                raise RuntimeError("view: did not serve in 600 s") from None
        wall = time.perf_counter() - t0
        stat = Path(f"/proc/{p.pid}/stat").read_text().rsplit(")", 1)[1].split()
        cpu = (int(stat[11]) + int(stat[12])) / CLK  # utime, stime (fields 14, 15)
        hwm = next(x for x in Path(f"/proc/{p.pid}/status").read_text().splitlines() if x.startswith("VmHWM"))
        return {"wall": wall, "cpu": cpu, "rss_mb": int(hwm.split()[1]) / 1024}
    finally:
        p.terminate()
        p.wait(30)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--only", default="locate,replay,view,scene")
    a = ap.parse_args(argv)
    verbs = [v for v in a.only.split(",") if v]
    print(f"first call on a cold numba cache vs warm (peer); {os.cpu_count()} cores; median of {a.repeat}")
    print(
        f"{'call':8s} {'cold wall s':>11s} {'cold CPU s':>10s} {'cold RSS MB':>11s} {'warm wall s':>11s} "
        f"{'warm CPU s':>10s} {'warm RSS MB':>11s} {'cold/warm wall':>14s}"
    )
    for verb in verbs:
        cold, warm = [], []
        for _ in range(a.repeat):
            cache = Path(tempfile.mkdtemp(prefix="geoloc-bench-numba-"))
            try:
                cold.append(run_once(verb, cache))
                warm.append(run_once(verb, cache))
            finally:
                shutil.rmtree(cache, ignore_errors=True)
        m = {
            k: (statistics.median(x[k] for x in cold), statistics.median(x[k] for x in warm))
            for k in ("wall", "cpu", "rss_mb")
        }
        print(
            f"{verb:8s} {m['wall'][0]:11.1f} {m['cpu'][0]:10.1f} {m['rss_mb'][0]:11.0f} {m['wall'][1]:11.1f} "
            f"{m['cpu'][1]:10.1f} {m['rss_mb'][1]:11.0f} {m['wall'][0] / m['wall'][1]:14.1f}",
            flush=True,
        )
    print("target: cold within 10 s and 500 MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
