"""Server memory under connection churn: ``python benchmarks/bench_viz_churn.py [N]``.

Tabs that come and go: a ``geoloc view`` server (a
:class:`geoloc_viz.app.GeolocViewer`, one session per tab) is connected to and
dropped by ``N`` (default 500) clients over loopback, a few at a time. Each client
speaks viser's own protocol over ``websockets`` (no browser): it opens the
websocket with viser's subprotocol, sends one ``ViewerCameraMessage`` (what makes
viser register a client and build its session), reads what the server sends for
its tab until the stream goes quiet, and closes.

Printed: RSS before and after a warm-up (the first connections fill the shared
caches: terrain mesh, aircraft mesh, the calibration fit, numba), the idle RSS
after the warm-up, the peak during the churn, and the RSS after the churn and
``gc.collect()``, with the ratio after/idle (goal: within 10 %); the sessions
still alive (weak references; goal 0); and the median wall and CPU time of one
connect-build-drop against a bare viser server's in the same run (the peer).

Bounded in time: each client waits at most ``CLIENT_TIMEOUT_S`` for the stream.
The machine is shared (2 cores, several agents): treat times as loaded figures.
"""

from __future__ import annotations

import asyncio
import gc
import statistics
import sys
import threading
import time
import weakref
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import rss_mb  # noqa: E402  (benchmarks/_timing.py, beside this file)

#: A client waits at most this long for its tab's messages (bounded time per client).
CLIENT_TIMEOUT_S = 60.0
#: Clients connected and dropped before the idle RSS is read (fewer when N is smaller).
WARM_UP = 20
#: The server's stream to a tab counts as done after this long without a message.
QUIET_S = 0.25


def camera_message(position=(0.0, 0.0, 10.0), look_at=(0.0, 0.0, 0.0), wxyz=(1.0, 0.0, 0.0, 0.0)) -> bytes:
    """A browser's camera report (the first one registers the tab), msgpack-encoded as
    viser's client sends it (scene units)."""
    import msgspec.msgpack

    return msgspec.msgpack.encode(
        {
            "type": "ViewerCameraMessage",
            "wxyz": [float(x) for x in wxyz],
            "position": [float(x) for x in position],
            "fov": 1.3,
            "near": 0.02,
            "far": 1000.0,
            "image_height": 480,
            "image_width": 640,
            "look_at": [float(x) for x in look_at],
            "up_direction": [0.0, 0.0, 1.0],
        }
    )


#: Bytes that mark the end of a tab's session build in the stream (the calibration layer's
#: GUI folder, the last default layer) and, for a bare viser server, the end of its backlog.
BUILT = b"Teaching: a vector through the chain"  # the GUI folder of the last default layer
REPLAY_DONE = b"ReplayDoneMessage"


def decode_window(data: bytes) -> bytes:
    """The msgpack part of one of viser's websocket frames (zstd after two 8-byte sizes)."""
    import zstandard

    n, c = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
    return zstandard.ZstdDecompressor().decompress(data[16 : 16 + c], max_output_size=n)


async def one_client(port: int, until: bytes = BUILT, hold_s: float = 0.0) -> tuple:
    """Connect, register (camera message), read until a frame contains ``until`` (or
    ``CLIENT_TIMEOUT_S``), hold ``hold_s``, close. Returns (frames, bytes received, seen)."""
    import viser
    import websockets

    n = nbytes = 0
    seen = False
    async with websockets.connect(
        f"ws://127.0.0.1:{port}",
        subprotocols=[f"viser-v{viser.__version__}"],
        max_size=None,
        open_timeout=CLIENT_TIMEOUT_S,
    ) as ws:
        await ws.send(camera_message())
        t0 = time.monotonic()
        while not seen and time.monotonic() - t0 < CLIENT_TIMEOUT_S:
            try:
                m = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            n += 1
            nbytes += len(m)
            seen = until in decode_window(m)
        if hold_s:
            await asyncio.sleep(hold_s)
    return n, nbytes, seen


def churn(port: int, n: int, concurrency: int = 4, until: bytes = BUILT, hold_s: float = 0.0) -> list:
    """``n`` clients, ``concurrency`` at a time; returns [(wall time [s], saw ``until``)] per client."""
    times = []

    async def worker(k):
        for i in range(k, n, concurrency):
            t = time.perf_counter()
            _, _, seen = await one_client(port, until, hold_s)
            times.append((time.perf_counter() - t, seen))

    async def main():
        await asyncio.gather(*(worker(k) for k in range(concurrency)))

    asyncio.run(main())
    return times


def wait_drained(server, timeout: float = 20.0) -> None:
    """Until viser has run every disconnect (no client registered)."""
    t0 = time.monotonic()
    while server.get_clients() and time.monotonic() - t0 < timeout:
        time.sleep(0.05)
    time.sleep(0.3)  # the disconnect callbacks run on viser's thread pool


def settle(wait_s: float = 1.5) -> float:
    """RSS after the server's own release of dropped tabs (``GeolocViewer`` frees them and
    trims the heap 0.5 s after the last close; we wait ``wait_s``) and a ``gc.collect()``.
    No ``malloc_trim`` here: what is measured is what the server gives back by itself."""
    time.sleep(wait_s)
    gc.collect()
    return rss_mb()


class Peak:
    """Peak RSS, sampled by a background thread every 50 ms."""

    def __init__(self):
        self.peak = rss_mb()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        while not self._stop.wait(0.05):
            self.peak = max(self.peak, rss_mb())

    def stop(self) -> float:
        self._stop.set()
        self._t.join()
        return self.peak


def tracked_viewer(*args, **kw):
    """A :class:`GeolocViewer` that keeps a weak reference to every session it builds (``.refs``),
    including those of tabs that closed while their session was being built."""
    from geoloc_viz.app import GeolocSession, GeolocViewer

    refs = []

    def factory(*a, **k):
        s = GeolocSession(*a, **k)
        refs.append(weakref.ref(s))
        return s

    v = GeolocViewer(*args, **kw)
    v.session_factory = factory
    v.refs = refs
    return v


def main(n: int = 500) -> dict:
    import viser

    from geoloc_viz.app import make_server
    from geoloc_viz.scenario import load_view_scenario

    out = {}
    rss0 = rss_mb()
    # ---- the peer: a bare viser server, same churn (its own per-connection cost)
    bare = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        churn(bare.get_port(), 10, until=REPLAY_DONE)
        t_bare = churn(bare.get_port(), min(n, 100), until=REPLAY_DONE)
    finally:
        bare.stop()
    # ---- ours
    server = make_server(port=0)
    try:
        viewer = tracked_viewer(server, load_view_scenario(), max_clients=16)
        refs = viewer.refs
        rss_built = settle()
        # warm-up: shared caches, numba, first GUI messages (the first client fills them; a tiny
        # run of N < 20 clients warms up with N)
        out["warm"] = warm = min(WARM_UP, n)
        churn(server.get_port(), warm)
        wait_drained(server)
        idle = settle()
        peak = Peak()
        t0 = time.perf_counter()
        t_ours = churn(server.get_port(), n)
        wall = time.perf_counter() - t0
        wait_drained(server)
        pk = peak.stop()
        after = settle()
        alive = sum(r() is not None for r in refs)
        out.update(
            rss_start=rss0,
            rss_built=rss_built,
            idle=idle,
            peak=pk,
            after=after,
            ratio=after / idle,
            alive=alive,
            built=len(refs),
            n=n,
            wall=wall,
            per_client_ours=statistics.median(t for t, _ in t_ours),
            per_client_bare=statistics.median(t for t, _ in t_bare),
            served=sum(ok for _, ok in t_ours),
            n_bare=len(t_bare),
            sessions_left=len(viewer.sessions),
        )
    finally:
        server.stop()
    return out


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 500
    c0 = time.process_time()
    r = main(n)
    cpu = time.process_time() - c0
    print(
        f"connection churn: {r['n']} clients over loopback, 4 at a time, each registering a tab "
        f"(one GeolocSession) and dropping it"
    )
    print(f"  RSS at start {r['rss_start']:.0f} MB, server + viewer built {r['rss_built']:.0f} MB")
    print(f"  idle (after a {r['warm']}-client warm-up, gc)   {r['idle']:.0f} MB")
    print(f"  peak during the churn                  {r['peak']:.0f} MB")
    print(
        f"  after the churn + gc                   {r['after']:.0f} MB  (after / idle = {r['ratio']:.3f}; goal <= 1.10)"
    )
    print(f"  clients that saw their tab built: {r['served']} of {r['n']}")
    print(
        f"  sessions built {r['built']} (with the warm-up), still alive after the churn {r['alive']} (goal 0); "
        f"viewer.sessions left {r['sessions_left']}"
    )
    print(
        f"  one connect + session build + drop, median wall: ours {1e3 * r['per_client_ours']:.0f} ms, "
        f"bare viser server {1e3 * r['per_client_bare']:.0f} ms ({r['n_bare']} clients) "
        f"(ratio {r['per_client_ours'] / r['per_client_bare']:.1f}); churn {r['wall']:.0f} s wall, "
        f"whole run {cpu:.0f} s CPU (this process)"
    )
