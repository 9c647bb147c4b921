"""Live receiver (geoloc.io.live) over one hour of 30 Hz MISB ST 0601: speed and memory, against PyAV.

Builds an MPEG-TS of one hour of 30 Hz KLV metadata (108 000 UAS Datalink LS
packets: the bundled example flight's 299 good packets, cycled, each re-stamped
30 Hz later; written by ``geoloc.io.klv.write_ts`` through PyAV), then times:

- ours: every 7 x 188-byte datagram of it pushed through ``LiveReceiver.push``
  (the TS demuxer, the continuity / duplicate / reorder checks, the KLV scan
  and checksums, the rolling window), as the UDP path does, without the socket;
- peer: ``geoloc.io.klv.read_ts_klv`` of the same bytes as a file (FFmpeg's
  MPEG-TS demuxer through PyAV, then the same KLV scanner);
- ours over loopback once: a sender thread streaming the file to udp://127.0.0.1 at
  ``--loopback-speed`` times real time (default 100: the hour in 36 s) and
  ``geoloc.io.live.receive``; what the kernel drops is counted, not hidden (a sender
  faster than the receiver, ``--loopback-speed 0``, overflows the socket buffer).

Each of the first two is the median of ``--repeat`` runs (default 3), wall time
(time.perf_counter) and CPU time (time.process_time); packets per second are of the
wall time, ``ratio: X`` = ours / peer. Memory: the resident set size (VmRSS of
/proc/self/status) before the receiver starts, at each quarter of the hour and at
the end: the receiver keeps a window of 18 000 packets (10 minutes at 30 Hz), so it
grows until the window is full and not after.

Run: python benchmarks/bench_live.py [--hours H] [--repeat R] [--no-loopback] [--loopback-speed X]
"""

import argparse
import os
import socket
import tempfile
import threading
import time
from pathlib import Path

from geoloc.assets import ASSETS
from geoloc.io.klv import Packet, encode_packet, read_klv_file, read_ts_klv, write_ts
from geoloc.io.live import LiveReceiver, datagrams_of, receive, send

from _timing import rss_mb, timed  # benchmarks/_timing.py (the script's folder is on sys.path)

RATE_HZ = 30.0


def make_ts(path: Path, n: int) -> int:
    base = [p for p in read_klv_file(Path(ASSETS) / "klv" / "example_flight.klv") if isinstance(p, Packet)]
    t0 = base[0].fields["precision_time_stamp_us"]

    def blobs():
        for i in range(n):
            f = dict(base[i % len(base)].fields)
            f["precision_time_stamp_us"] = t0 + round(i * 1e6 / RATE_HZ)
            yield encode_packet(f)

    return write_ts(path, blobs(), rate=RATE_HZ)


def through_receiver(grams, marks=None):
    rx = LiveReceiver()
    got = 0
    q = len(grams) // 4
    for k, g in enumerate(grams):
        got += len(rx.push(g))
        if marks is not None and q and (k + 1) % q == 0:
            marks.append((k + 1, rss_mb(), got, len(rx.window)))
    got += len(rx.flush())
    return got, rx


def over_loopback(path: Path, speed):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"udp://127.0.0.1:{port}"
    rx = LiveReceiver()
    res = {}
    th = threading.Thread(target=lambda: res.update(send(path, url, speed=speed, start_delay_s=0.5)), daemon=True)
    t = time.perf_counter()
    th.start()
    n = sum(1 for _ in receive(url, receiver=rx, idle_s=1.0, duration_s=3600))
    th.join()
    wall = time.perf_counter() - t - 1.0 - 0.5  # less the idle second that ends it and the start delay
    return n, wall, rx, res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-loopback", action="store_true")
    ap.add_argument("--loopback-speed", type=float, default=100.0, help="x real time; 0: as fast as possible")
    args = ap.parse_args()
    n = int(round(args.hours * 3600 * RATE_HZ))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hour.ts"
        t = time.perf_counter()
        make_ts(path, n)
        data = path.read_bytes()
        grams = datagrams_of(data)
        print(
            f"stream: {n} KLV packets at {RATE_HZ:g} Hz ({n / RATE_HZ / 3600:.2f} h), {len(data) / 1e6:.1f} MB, "
            f"{len(grams)} datagrams (built in {time.perf_counter() - t:.1f} s)"
        )

        rss0 = rss_mb()
        marks = []
        got, rx = through_receiver(grams, marks)
        assert got == n and rx.stats.klv_packets == n and rx.stats.cc_errors == 0, rx.stats.line()
        print(f"RSS before the receiver: {rss0:.1f} MB (the stream's bytes in memory included)")
        for k, mb, pk, win in marks:
            print(f"  after {k:7d} datagrams ({pk:6d} packets, window {win:5d}): RSS {mb:7.1f} MB")
        print(f"RSS at the end: {rss_mb():.1f} MB")

        w, c, (got, _) = timed(lambda: through_receiver(grams), args.repeat)
        assert got == n
        ours = n / w
        print(
            f"ours (LiveReceiver.push per datagram):  wall {w:7.2f} s  cpu {c:7.2f} s  {ours:10,.0f} packets/s "
            f"({ours / RATE_HZ:,.0f} x real time)"
        )
        w, c, res = timed(lambda: sum(1 for _ in read_ts_klv(path)), args.repeat)
        assert res == n
        peer = n / w
        print(f"peer (read_ts_klv: PyAV/FFmpeg demux):  wall {w:7.2f} s  cpu {c:7.2f} s  {peer:10,.0f} packets/s")
        print(f"ratio: {ours / peer:.2f}")
        if not args.no_loopback:
            speed = args.loopback_speed or None
            got, wall, rx, res = over_loopback(path, speed)
            print(
                f"over loopback, sender at {f'{speed:g}x real time' if speed else 'full speed'}: {got} of {n} "
                f"packets in {wall:.1f} s "
                f"({got / max(wall, 1e-9):,.0f} packets/s); {rx.stats.line()}"
            )


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
