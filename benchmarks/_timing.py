"""Shared timing for the benchmarks: medians of wall and CPU time over repeated calls."""

from __future__ import annotations

import statistics
import time


def timed(fn, repeat: int):
    """(median wall time [s], median CPU time [s], last result) of ``repeat`` calls of ``fn``."""
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return statistics.median(walls), statistics.median(cpus), out


def rss_mb() -> float:
    """Resident set size of this process now [MiB] (Linux: /proc/self/status VmRSS)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")
