"""Where a run of the suite spends its time: a log of every test phase, and its summary.

Logging: ``GEOLOC_TEST_TIMELOG=FILE bash tools/test.sh`` appends one line per test phase (setup,
call, teardown) as pytest's controller receives it (``tests/conftest.py`` registers this module as
a plugin when the variable is set): seconds since the session started, the 1-minute load average,
the worker (``gw0`` ... or ``main`` without pytest-xdist), the phase, its duration, its outcome and
the test's id (pytest-xdist's grouped tests end in ``@GROUP``).

Summary: ``python tools/suite_time.py FILE [--top N]`` prints, per worker and per xdist group
(``chromium``, ``install``, the rest as ``other``), the number of tests, the sum of their phases
and the span from the first phase's start to the last one's end; when each worker started its
first test outside a group (pytest-xdist's ``loadgroup`` gives the groups out first); and the N
longest phases. Shared-machine figures are relative: compare runs made under the same load
(docs/testing.md, "The suite's time").
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

#: The environment variable naming the log file; unset, nothing is logged.
ENV = "GEOLOC_TEST_TIMELOG"


@dataclass
class Phase:
    """One logged test phase; ``end_s`` is seconds since the session started."""

    end_s: float
    load: float
    worker: str
    when: str
    duration_s: float
    outcome: str
    nodeid: str

    @property
    def group(self) -> str:
        """The pytest-xdist group (``nodeid@group``), else ``other``."""
        head, _, group = self.nodeid.rpartition("@")
        # a parameter may hold an "@" ("test_x[a@b]"); xdist's suffix comes after the brackets
        return group if head and not any(c in group for c in "]:/") else "other"


@dataclass
class Tally:
    """Tests, summed phase time and span of a worker or a group."""

    tests: int = 0
    sum_s: float = 0.0
    first_s: float = float("inf")
    last_s: float = 0.0
    workers: set[str] = field(default_factory=set)

    def add(self, p: Phase) -> None:
        self.tests += p.when == "call"
        self.sum_s += p.duration_s
        self.first_s = min(self.first_s, p.end_s - p.duration_s)
        self.last_s = max(self.last_s, p.end_s)
        self.workers.add(p.worker)


def read_log(path: str | os.PathLike[str]) -> list[Phase]:
    """The phases of a log written by this plugin; a malformed line raises naming its number."""
    phases = []
    for i, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line or line.startswith("#"):
            continue
        f = line.split("\t")
        try:
            phases.append(Phase(float(f[0]), float(f[1]), f[2], f[3], float(f[4]), f[5], f[6]))
        except (IndexError, ValueError) as e:
            raise ValueError(f"{path}: line {i} is not a phase of the time log ({e}): {line!r}") from None
    return phases


def summarise(phases: list[Phase], top: int = 15) -> list[str]:
    """The summary's lines (see the module's docstring)."""
    if not phases:
        return ["no phases logged"]
    workers: dict[str, Tally] = {}
    groups: dict[str, Tally] = {}
    first_other: dict[str, float] = {}
    for p in phases:
        workers.setdefault(p.worker, Tally()).add(p)
        groups.setdefault(p.group, Tally()).add(p)
        if p.group == "other":
            first_other[p.worker] = min(first_other.get(p.worker, float("inf")), p.end_s - p.duration_s)
    loads = sorted(p.load for p in phases)
    not_passed = sum(p.outcome != "passed" for p in phases)
    out = [
        f"{len(phases)} phases, {not_passed} not passed; last at {max(p.end_s for p in phases):.0f} s; "
        f"load min {loads[0]:.1f}, median {loads[len(loads) // 2]:.1f}, max {loads[-1]:.1f}"
    ]
    for name, t in sorted(workers.items()):
        out.append(f"worker {name}: {t.tests} tests, phases {t.sum_s:.0f} s, from {t.first_s:.0f} to {t.last_s:.0f} s")
    for name, t in sorted(groups.items()):
        out.append(
            f"group {name}: {t.tests} tests, phases {t.sum_s:.0f} s, from {t.first_s:.0f} to {t.last_s:.0f} s, "
            f"on {', '.join(sorted(t.workers))}"
        )
    out.append(
        "first test outside a group: "
        + ", ".join(f"{w} at {s:.0f} s" for w, s in sorted(first_other.items()))
        + "".join(f", {w} none" for w in sorted(workers) if w not in first_other)
    )
    for p in sorted(phases, key=lambda p: -p.duration_s)[:top]:
        out.append(f"{p.duration_s:8.1f} s  {p.when:<8} {p.worker:<4} load {p.load:4.1f}  {p.nodeid}")
    return out


class TimeLog:
    """The pytest plugin: the controller (or the only process) appends each phase's line."""

    def __init__(self, path: str) -> None:
        self.t0 = time.time()
        self.file: IO[str] = open(path, "a", buffering=1)  # line-buffered: a killed run keeps its lines

    def pytest_runtest_logreport(self, report: Any) -> None:
        node = getattr(report, "node", None)  # pytest-xdist: the worker that sent the report
        worker = node.gateway.id if node is not None else "main"
        self.file.write(
            f"{time.time() - self.t0:.2f}\t{os.getloadavg()[0]:.2f}\t{worker}\t{report.when}\t"
            f"{report.duration:.3f}\t{report.outcome}\t{report.nodeid}\n"
        )

    def pytest_unconfigure(self) -> None:
        self.file.close()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help=f"a file written with {ENV}=FILE")
    ap.add_argument("--top", type=int, default=15, help="how many of the longest phases to list")
    a = ap.parse_args(argv)
    print("\n".join(summarise(read_log(a.log), a.top)))


if __name__ == "__main__":
    main()
