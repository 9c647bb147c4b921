"""The KLV replay of a live stream: each packet located as it arrives, journalled, a rolling window kept.

:class:`LiveReplay` takes the results of :func:`geoloc.io.live.receive` (or of
:class:`geoloc.io.live.LiveReceiver`) batch by batch and replays each batch exactly
as :func:`geoloc.workflows.klv_replay.replay_klv` replays a file (the same sensor,
surface, heights and columns: every packet is located from its own pose, so a
packet's row does not depend on the others), numbering packets in arrival order
(bad packets counted, as the file replay counts them). Two columns differ by
nature: ``outlier`` is causal, the robust rule of
:func:`geoloc.workflows.klv_replay.outlier_mask` over the window of packets
received so far (a file's replay judges each packet against the whole file), and
``file`` names the stream. A live row also has ``frame_pts_s``: the presentation
time of the nearest video frame (NaN without video). A muxer interleaves by time
stamp, so a packet nearer the next frame than the last one comes before that
frame: with video in the stream, a packet is replayed once a frame at or after
its time has started (the next frame's first TS packet; at most
:data:`BIND_WAIT_S` of the KLV clock), so that its frame is the nearest one, as
in the file; the packets after it wait with it (the rows keep their order), and
:meth:`LiveReplay.flush` replays the last ones at the end of the stream.

The journal (``journal``: a text file) gets the rows as CSV as they come, in the
format of :func:`geoloc.workflows.klv_replay.write_klv_csv`, flushed after every
batch. Memory: the rows of the last ``window`` packets (:attr:`LiveReplay.window`).
"""

from __future__ import annotations

import csv
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING, TextIO

import numpy as np

from geoloc.io.klv import KlvError, Packet, packets_to_columns
from geoloc.workflows.klv_replay import (
    KlvRead,
    KlvReplay,
    _column_text,
    _is_stray,
    _replay,
    outlier_mask,
)

if TYPE_CHECKING:
    from geoloc.io.live import LiveReceiver
    from geoloc.sensors.frame import FrameSensor
    from geoloc.surfaces.base import Surface

__all__ = ["LiveReplay", "WINDOW"]

#: Rows kept in memory (about 10 minutes at 30 Hz); the journal has them all.
WINDOW = 18000
#: A packet whose nearest video frame may still come (no frame at or after its time has started)
#: waits for one until a packet this much later on the KLV clock has come [s] (video stopped,
#: or far behind: it is then bound to the nearest frame there is).
BIND_WAIT_S = 0.5


class LiveReplay:
    """Replay KLV results batch by batch (see the module docstring).

    Parameters
    ----------
    label : str
        The stream's name (the ``file`` column), e.g. its URL.
    surface, sensor
        As :func:`geoloc.workflows.klv_replay.replay_klv` (default: each packet at its own
        frame-centre height).
    journal : text file, optional
        Where the CSV rows go as they come.
    window : int
        Rows kept in memory.
    receiver : geoloc.io.live.LiveReceiver, optional
        For ``frame_pts_s`` (the nearest video frame's time).
    """

    def __init__(
        self,
        label: str,
        *,
        surface: Surface | None = None,
        sensor: FrameSensor | None = None,
        journal: TextIO | None = None,
        window: int = WINDOW,
        receiver: LiveReceiver | None = None,
    ):
        self.label = str(label)
        self.surface, self.sensor = surface, sensor
        self.journal = journal
        self._writer = csv.writer(journal) if journal is not None else None
        self._header: list[str] | None = None  # the journal's columns, fixed by the first batch
        self.receiver = receiver
        self.seq = 0  # packets seen (good and bad), arrival order
        self.rows_total = 0
        self.errors: deque = deque(maxlen=1000)
        self.errors_total = 0
        self.window: deque = deque(maxlen=int(window))  # one dict of column -> value per row
        self._err: deque = deque(maxlen=int(window))  # frame-centre errors, for the causal outliers
        self.last: KlvReplay | None = None
        self._waiting: list = []  # (packet, number): their nearest frame may still come
        self._errs: list = []  # bad packets since the last replay (its read's errors)

    def add(self, results: Iterable[Packet | KlvError]) -> KlvReplay | None:
        """Replay one batch of :class:`Packet` / :class:`KlvError`; returns the replay of the packets
        it made ready (None: none; see the module docstring on packets waiting for their frame)."""
        for r in results:
            if isinstance(r, Packet):
                self._waiting.append((r, self.seq))
                self.seq += 1
            elif isinstance(r, KlvError):
                self._errs.append(r)
                self.errors.append(r)
                self.errors_total += 1
                self.seq += 0 if _is_stray(r) else 1
        return self._replay_ready(self._ready())

    def flush(self) -> KlvReplay | None:
        """Replay the packets still waiting for their frame (the end of the stream)."""
        return self._replay_ready(len(self._waiting))

    def _ready(self) -> int:
        """How many of the waiting packets (from the first) have their nearest frame known."""
        rx = self.receiver
        if not self._waiting:
            return 0
        if rx is None or not any(kind == "video" for kind, _ in rx.demux.streams.values()):
            return len(self._waiting)  # no video stream: nothing to wait for
        starts = rx.demux.video_starts
        newest_frame = max((starts[-k] for k in range(1, min(len(starts), 8) + 1)), default=None)
        newest_klv = self._waiting[-1][0].pts
        n = 0
        for p, _ in self._waiting:
            if p.pts is None or newest_klv is None or newest_klv < p.pts:  # no clock, or it went back
                n += 1
            elif newest_frame is not None and newest_frame >= p.pts:  # any later frame is farther
                n += 1
            elif newest_klv - p.pts >= BIND_WAIT_S * 90000:  # the frame does not come: no more waiting
                n += 1
            else:
                break
        return n

    def _replay_ready(self, n: int) -> KlvReplay | None:
        if not n:
            return None
        ready, self._waiting = self._waiting[:n], self._waiting[n:]
        packets = [p for p, _ in ready]
        number = [k for _, k in ready]
        errs, self._errs = self._errs, []
        pts_s = np.array([np.nan if p.time_s is None else p.time_s for p in packets], float)
        read = KlvRead(self.label, packets_to_columns(packets), errs, pts_s, np.array(number, np.int64))
        r = _replay(read, self.surface, self.sensor)
        c = r.columns
        n = len(r)
        self._err.extend(np.asarray(c["frame_center_error_m"], float).tolist())
        flags = outlier_mask(np.array(self._err, float))[0]
        c["outlier"] = np.asarray(flags[-n:], np.int64)
        fpts = np.full(n, np.nan)
        rx = self.receiver
        if rx is not None and (rx.video or rx.demux.video_starts):
            for k, p in enumerate(packets):
                v = rx.nearest_video_pts(p.pts)
                if v is not None:
                    fpts[k] = v / 90000.0
        c["frame_pts_s"] = fpts
        if self._writer is not None and self.journal is not None:  # the writer writes to the journal
            if self._header is None:
                self._header = list(c)
                self._writer.writerow(self._header)
            texts = [_column_text(k, c[k]) for k in self._header]
            self._writer.writerows(zip(*texts))
            self.journal.flush()
        keys = list(c)
        for k in range(n):
            self.window.append({name: c[name][k] for name in keys})
        self.rows_total += n
        self.last = r
        return r

    def columns(self) -> dict:
        """The window's rows as columns (numpy arrays)."""
        if not self.window:
            return {}
        keys = list(self.window[0])
        return {k: np.array([row[k] for row in self.window]) for k in keys}

    def summary(self) -> str:
        """A few lines: rows, bad packets, the frame-centre error over the window."""
        err = np.array(self._err, float)
        fin = err[np.isfinite(err)]
        L = [f"{self.label}: {self.rows_total} packets located, {self.errors_total} bad packet(s)"]
        for e in list(self.errors)[:20]:
            L.append(f"  bad packet at byte {e.offset} (pts {e.pts}): {e.reason}")
        if len(fin):
            L.append(
                f"  frame-centre error (recomputed vs reported, horizontal; last {len(err)} packets): median "
                f"{np.median(fin):.3f} m, 90th percentile {np.percentile(fin, 90):.3f} m, max "
                f"{np.max(fin):.3f} m"
            )
            out = int(np.sum(outlier_mask(err)[0]))
            L.append(f"  outliers in that window (median / MAD rule): {out}")
        else:
            L.append("  frame-centre error: no packet compared" if self.rows_total else "  no packet located")
        return "\n".join(L)

    def row_text(self, r: KlvReplay) -> str:
        """One line per packet of a batch: packet, time, recomputed centre, status, errors, outlier."""
        from geoloc.status import names

        c = r.columns
        st = names(c["status"])

        def f(v, spec):
            return format(float(v), spec) if v == v else ""

        return "\n".join(
            f"{c['packet'][k]:>6} {c['time_utc'][k]:<27} {f(c['lat_deg'][k], '11.6f'):>11} "
            f"{f(c['lon_deg'][k], '12.6f'):>12} {f(c['h_m'][k], '9.1f'):>9} {st[k]:>13} "
            f"{f(c['frame_center_error_m'][k], '12.3f'):>12} {f(c['corner_error_m'][k], '12.3f'):>12} "
            f"{'yes' if c['outlier'][k] else ''}"
            for k in range(len(r))
        )


HEADER = (
    f"{'packet':>6} {'time_utc':<27} {'lat_deg':>11} {'lon_deg':>12} {'h_m (HAE)':>9} {'status':>13} "
    f"{'centre_err_m':>12} {'corner_err_m':>12} outlier"
)
