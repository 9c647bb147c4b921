"""Progress of long work on stderr: a bar on a terminal, a plain line every 10 s in a log.

One mechanism for every long verb (``montecarlo`` and its sweeps, ``replay``, ``ortho``,
``rpc``: docs/cli.md, "Progress"). A verb counts its units of work (samples, records, rays,
fit stages) and calls :meth:`Progress.update` after each chunk; :class:`Progress` decides
what, if anything, to print. The command line's ``--progress`` / ``--no-progress``
(:func:`geoloc.cli._options.add_progress_options`) give ``enabled``.
"""

from __future__ import annotations

import math
import sys
import time
from typing import TextIO

#: Seconds between two progress lines when stderr is not a terminal (a log, a batch job): docs/cli.md.
PROGRESS_INTERVAL_S = 10.0


def _now() -> float:
    """The progress clock [s] (monotonic; a test replaces it)."""
    return time.perf_counter()


class Progress:
    """Progress on stderr: a one-line bar (``\r``-updated) on a terminal, a line every
    :data:`PROGRESS_INTERVAL_S` seconds in a log; silent when disabled.

    Parameters
    ----------
    total : int
        Units of work (samples, sweep points, records, rays, stages).
    label : str
    enabled : bool or None
        None (the default of the command line): the bar when the stream is a terminal,
        else a plain line every :data:`PROGRESS_INTERVAL_S` s (nothing for a run shorter
        than that); True: the bar; False: nothing.
    """

    def __init__(self, total: int, label: str = "progress", enabled: bool | None = None, stream: TextIO | None = None):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.mode = ("bar" if tty or enabled else "lines") if enabled is not False else "off"
        self.enabled = self.mode != "off"
        self.done = 0
        self.t0 = _now()
        self.next_line = self.t0 + PROGRESS_INTERVAL_S
        self.lines = 0

    def update(self, k: int) -> None:
        self.done += int(k)
        if not self.enabled:
            return
        now = _now()
        if self.mode == "lines" and now < self.next_line:
            return
        frac = min(self.done / self.total, 1.0)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        if self.mode == "lines":
            self.next_line = now + PROGRESS_INTERVAL_S
            self.lines += 1
            self.stream.write(
                f"{self.label}: {self.done}/{self.total} ({100 * frac:.1f}%), {_clock(el)} elapsed, "
                f"{_clock(eta)} left\n"
            )
        else:
            bar = "#" * int(30 * frac)
            self.stream.write(
                f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% "
                f"{self.done}/{self.total}  {_clock(el)} elapsed, {_clock(eta)} left "
            )
        self.stream.flush()

    def close(self) -> None:
        if self.mode == "bar":
            self.stream.write("\n")
            self.stream.flush()


def _clock(seconds: float) -> str:
    """``73.2`` -> ``"1m13s"``; ``"?"`` when unknown."""
    if not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    if s < 60:
        return f"{seconds:.1f}s" if seconds < 10 else f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"
