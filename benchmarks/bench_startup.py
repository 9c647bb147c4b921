"""How fast the command line answers: ``geoloc --help`` and a warm one-pixel ``geoloc locate``.

Each command runs as a new process (the start-up is what is measured), ``--repeat`` times,
alternating with the peer: a bare ``python -c "import numpy"``, the floor any numpy tool
starts from. Printed: median wall time, median CPU time (the child's user + system), peak
RSS, the machine's load, and the ratio of ours to the peer last. Goals: help in
0.3 s or less, a warm one-pixel locate in 0.5 s or less. ``--importtime`` also prints the
ten slowest imports of the one-pixel locate (``python -X importtime``).

    python benchmarks/bench_startup.py [--repeat 7] [--importtime]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time

LOCATE = [
    "locate",
    "--lat-deg",
    "35.48",
    "--lon-deg",
    "80.97",
    "--h-m",
    "18000",
    "--heading-deg",
    "45",
    "--pitch-deg",
    "3.5",
    "--gimbal-roll-deg",
    "50",
    "--gimbal-pitch-deg",
    "-2.6",
    "--target-h-m",
    "5083.5",
    "--json",
]  # [Q17] Table 1, the docs' first example
CASES = {
    "geoloc --help": [sys.executable, "-m", "geoloc", "--help"],
    "one-pixel locate": [sys.executable, "-m", "geoloc", *LOCATE],
    "peer: python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
}


def run_once(cmd) -> tuple[float, float, float]:
    """(wall [s], CPU [s], peak RSS [MiB]) of one run of ``cmd`` in a new process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {r.returncode}:\n{r.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, after.ru_maxrss / 1024.0  # the largest child so far, KiB on Linux


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="runs of each command, alternating (default 7)")
    ap.add_argument("--importtime", action="store_true", help="also the ten slowest imports of the locate")
    args = ap.parse_args(argv)
    for cmd in CASES.values():  # warm: numba's cache, the OS's file cache
        run_once(cmd)
    runs = {k: [] for k in CASES}
    for _ in range(args.repeat):
        for k, cmd in CASES.items():
            runs[k].append(run_once(cmd))
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores, {args.repeat} runs each, medians")
    med = {}
    for k, rs in runs.items():
        wall, cpu = statistics.median(r[0] for r in rs), statistics.median(r[1] for r in rs)
        med[k] = wall
        print(f"{k:32s} wall {wall:.3f} s  CPU {cpu:.3f} s")
    peer = med["peer: python -c 'import numpy'"]
    print(
        f"ratio geoloc --help / peer {med['geoloc --help'] / peer:.2f}x; "
        f"one-pixel locate / peer {med['one-pixel locate'] / peer:.2f}x"
    )
    if args.importtime:
        r = subprocess.run(
            [sys.executable, "-X", "importtime", "-m", "geoloc", *LOCATE], capture_output=True, text=True
        )
        rows = [line.split("|") for line in r.stderr.splitlines() if line.startswith("import time:")][1:]
        rows = sorted(((int(c), n.strip()) for _, c, n in rows), reverse=True)[:10]
        print("slowest imports of the one-pixel locate (cumulative):")
        for us, name in rows:
            print(f"  {us / 1e3:8.1f} ms  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
