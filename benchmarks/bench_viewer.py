"""Is the viewer fast enough to scrub? First useful view, a step to the next frame, playback at 10 fps.

One command: ``python benchmarks/bench_viewer.py [--repeat 3] [--steps 8] [--play-s 12]``
(``--paired-text N``: only a paired comparison of where a step writes the panels' text, below).

Headless Debian Chromium through playwright with software WebGL (SwiftShader), a 1000 x 640
page on ``geoloc view``'s per-tab viewer (every default layer) on the bundled example flight with
its video. The server is up before the clock starts (the scenario loaded, the port open); a first
page load warms what every tab shares (the flight model, the terrain mesh). Then, per page load:

* **first useful view**: from ``page.goto`` to the later of (a) the first canvas frame showing
  the scene (200+ distinct colours, once the tab's session is built) and (b) the panel naming
  the frame (the summary's "frame 0 of 0 .. N"); goal 5 s. Its settled time (the canvas's last
  change before 2 s without one) beside it;
* **step to the next frame**: the timeline moved by one frame (as the GUI's slider does), to the
  first canvas change; goal 300 ms;
* **peer, measured in the same page**: viser's own bare scene update: one small ball, added to
  the tab's scene at the camera's look-at point, moved; to the first canvas change. The ratio
  step / peer says how much of a step is the viewer's, not the browser's floor;
* **playback** at 10 frames per second asked (the player waits for the browser's
  acknowledgement of each step): frames shown per second over ``--play-s`` seconds, counted
  on the server (frames the timeline reached) and on the canvas (changes the probe saw).

Where a step's time goes, per step (medians), beside the same figures for the peer:

* **the wire**: the messages the server queued for the tab from the step to the canvas settled
  (viser's message buffer, counted in this process: a benchmark-only hook), their bytes as viser
  encodes them (msgpack plus the raw arrays; before its zstd of the msgpack part), split into
  scene and GUI messages, the biggest kind named; scene nodes touched and nodes created;
* **the browser**: frames drawn (animation frames with a WebGL draw call, ``bench_browser.COUNTER``),
  the renderer's main-thread busy time and its script time (CDP ``Performance.getMetrics``:
  ``TaskDuration``, ``ScriptDuration``), and the CPU of Chromium's processes (its GPU process, where
  SwiftShader draws, apart);
* **the server**: the step's wall and CPU time (``time.process_time`` of this process), and its
  wall time to the scene batch's flush (the step's scene on its way to the browser; the panels'
  batch follows), so a step's first change splits into the server's part and the browser's.

``--paired-text N`` measures one cut alone, paired in time in one page: 2N steps alternating
(ABBA) between the panels' text and pose boxes written with the panels' batch (``session.later``,
the viewer's way) and written at once, in the step's scene batch; each to its first canvas change,
medians and the ratio.

CPU beside wall: Chromium's processes (``/proc``; its GPU process, where SwiftShader draws, apart)
and this process (the server), over the same intervals. The canvas is watched from inside the
page every 50 ms (``bench_browser.PROBE``). Prints medians, the load average before and after,
and the ratio last.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "viz")]  # the browser helpers of tests/viz
sys.path.insert(0, str(ROOT / "benchmarks"))

#: Records, in the page, when the panel first names a frame: ``window.__geolocPanelAt`` [ms, epoch].
PANEL_PROBE = """(() => {
  window.__geolocPanelAt = null;
  const rx = /frame \\d+ of 0 \\.\\. \\d+/;
  function look() {
    if (window.__geolocPanelAt === null && document.body && rx.test(document.body.innerText)) {
      window.__geolocPanelAt = Date.now(); return;
    }
    setTimeout(look, 50);
  }
  look();
})();"""


class _Wire:
    """What the server queues for the browsers: every message pushed into a viser message buffer
    while ``on`` (a benchmark-only wrap of ``AsyncMessageBuffer.push``; sizes computed afterwards,
    off the server's clock)."""

    def __init__(self):
        from viser.infra._async_message_buffer import AsyncMessageBuffer

        self.on, self.log = False, []
        orig = AsyncMessageBuffer.push
        wire = self

        def push(buf, message):
            if wire.on:
                wire.log.append(message)
            return orig(buf, message)

        AsyncMessageBuffer.push = push

    def start(self) -> None:
        self.log, self.on = [], True

    def stop(self) -> dict:
        """(messages, scene messages, GUI messages, bytes, nodes touched, nodes created, biggest kind)."""
        import collections

        import msgspec

        self.on = False
        size, nodes, created = collections.Counter(), set(), 0
        scene = gui = 0
        for m in self.log:
            bufs: list = []
            d = m.as_serializable_dict(bufs)
            kind = type(m).__name__
            size[kind] += len(msgspec.msgpack.encode(d)) + sum(b.nbytes for b in bufs)
            if kind.startswith("Gui"):
                gui += 1
            name = getattr(m, "name", None)
            if isinstance(name, str) and name.startswith("/"):
                scene += 1
                nodes.add(name)
                # a node's own message (PointCloudMessage, LineSegmentsMessage, ...) makes it anew in
                # the browser; updates are SceneNodeUpdateMessage and Set*Message (viser 1.1.1 has no
                # lifecycle field, which this counted before: always 0)
                created += not (kind.startswith(("Set", "Remove")) or kind == "SceneNodeUpdateMessage")
        big = size.most_common(1)[0] if size else ("none", 0)
        return {
            "messages": len(self.log),
            "scene": scene,
            "gui": gui,
            "bytes": sum(size.values()),
            "nodes": len(nodes),
            "created": created,
            "biggest": big,
        }


def _renderer_s(cdp) -> tuple[float, float]:
    """(the renderer main thread's busy seconds, its script seconds) so far (CDP Performance)."""
    m = {x["name"]: x["value"] for x in cdp.send("Performance.getMetrics")["metrics"]}
    return m.get("TaskDuration", float("nan")), m.get("ScriptDuration", float("nan"))


def _draws(page) -> dict:
    return page.evaluate("({...(window.__geolocDraws || {frames: 0, draws: 0, prims: 0})})")


class _Probe:
    """The browser's and the wire's figures over one interval (a step or a peer update)."""

    def __init__(self, page, cdp, wire):
        self.page, self.cdp, self.wire = page, cdp, wire

    def start(self) -> None:
        from bench_browser import _browser_cpu_s

        self.wire.start()
        self.r0, self.d0, self.c0 = _renderer_s(self.cdp), _draws(self.page), _browser_cpu_s()

    def stop(self) -> dict:
        from bench_browser import _browser_cpu_s

        r1, d1, c1 = _renderer_s(self.cdp), _draws(self.page), _browser_cpu_s()
        out = self.wire.stop()
        out.update(
            frames=d1["frames"] - self.d0["frames"],
            task_s=r1[0] - self.r0[0],
            script_s=r1[1] - self.r0[1],
            browser_s=c1[0] - self.c0[0],
            gpu_s=c1[1] - self.c0[1],
        )
        return out


def _first_scene_frame(page, t0, ready, min_colours=200, timeout=240.0):
    """Epoch time of the first probe frame with ``min_colours`` colours seen once ``ready()``."""
    from bench_browser import _frames

    while time.time() - t0 < timeout:
        if ready():
            for t, _h, n in _frames(page):
                if n >= min_colours:
                    return t
        time.sleep(0.05)
    raise RuntimeError(f"no scene on the canvas within {timeout} s")


def _first_change(page, seen, t_from, timeout=120.0):
    """Seconds from ``t_from`` to the first probe frame after index ``seen`` taken at or after
    ``t_from``: a late frame of the update before (at a high load frames come over a second apart,
    after the 1 s of quiet that ended its wait) is not this update's change."""
    from bench_browser import _frames

    while time.time() - t_from < timeout:
        fr = [f for f in _frames(page)[seen:] if f[0] >= t_from]
        if fr:
            return fr[0][0] - t_from
        time.sleep(0.01)
    raise RuntimeError(f"the canvas did not change within {timeout} s")


def paired_text(n: int) -> int:
    """``--paired-text N``: in one page, 2N steps alternating (ABBA) between the panels' text and
    pose boxes written with the panels' batch (``session.later``, the viewer's way) and written at
    once, inside the step's scene batch (the way before); each step to its first canvas change.
    Paired in time, so a load that drifts during the run weighs on both alike."""
    from bench_browser import PROBE, _frames, _settled, served_flight_viewer
    from test_viz_browser import chromium

    load0 = os.getloadavg()
    server, viewer, built = served_flight_viewer()
    res: dict = {"panels' batch": [], "scene batch": []}
    try:
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            page = browser.new_page(viewport={"width": 1000, "height": 640})
            page.add_init_script(PROBE)
            page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
            t0 = time.time()
            while not built and time.time() - t0 < 240:
                time.sleep(0.2)
            _settled(page, t0)
            session = viewer.session_of(next(iter(built)))
            fl = session.layers[0]
            seen = len(_frames(page))
            for j in range(2 * n):
                way = ("panels' batch", "scene batch")[(j + j // 2) % 2]  # ABBA ...
                if way == "scene batch":
                    session.later = lambda fn: fn()  # an instance attribute: the class's method hidden
                else:
                    session.__dict__.pop("later", None)
                t_step = time.time()
                fl.sl_frame.value = (int(fl.sl_frame.value) + 1) % len(fl.model)
                res[way].append(_first_change(page, seen, t_step))
                _, seen = _settled(page, t_step, quiet_s=1.0, after=seen)
    finally:
        server.stop()
    med = statistics.median
    load1 = os.getloadavg()
    print(f"paired steps, {n} each way, load average {load0[0]:.1f} before, {load1[0]:.1f} after")
    for way, v in res.items():
        print(f"text and pose boxes in the {way}: step to the first canvas change, median {med(v) * 1e3:.0f} ms wall")
    a, b = med(res["panels' batch"]), med(res["scene batch"])
    print(f"ratio: panels' batch / scene batch {a / b:.2f}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="page loads measured (default 3)")
    ap.add_argument("--steps", type=int, default=8, help="steps (and peer updates) per load (default 8)")
    ap.add_argument("--play-s", type=float, default=12.0, help="seconds of playback per load (default 12)")
    ap.add_argument(
        "--paired-text",
        type=int,
        default=0,
        metavar="N",
        help="only compare, in one page, N steps with the panels' text in the panels' batch and N with it "
        "in the scene batch (alternating)",
    )
    args = ap.parse_args(argv)
    if args.paired_text:
        return paired_text(args.paired_text)

    import numpy as np
    import viser
    from bench_browser import COUNTER, PROBE, _browser_cpu_s, _frames, _settled, served_flight_viewer
    from test_viz_browser import chromium

    load0 = os.getloadavg()
    wire = _Wire()
    server, viewer, built = served_flight_viewer()
    flushed: list = []  # perf_counter of each client flush (a step's first one sends its scene batch)
    orig_flush = viser.ClientHandle.flush

    def timed_flush(self):
        flushed.append(time.perf_counter())
        return orig_flush(self)

    viser.ClientHandle.flush = timed_flush
    view, settle, view_cpu, steps, step_cpu, server_step, peers, play = [], [], [], [], [], [], [], []
    to_scene: list = []  # the server's wall time from a step to its scene batch's flush
    step_where, peer_where = [], []
    try:
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            for k in range(args.repeat + 1):
                page = browser.new_page(viewport={"width": 1000, "height": 640})
                page.add_init_script(PROBE)
                page.add_init_script(PANEL_PROBE)
                page.add_init_script(COUNTER)
                cdp = page.context.new_cdp_session(page)
                cdp.send("Performance.enable")
                probe = _Probe(page, cdp, wire)
                before = set(built)
                cpu0, scpu0 = _browser_cpu_s(), time.process_time()
                t0 = time.time()
                page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
                ready = lambda: len(set(built) - before) == 1  # noqa: E731
                t_scene = _first_scene_frame(page, t0, ready)
                while page.evaluate("window.__geolocPanelAt") is None and time.time() - t0 < 240:
                    time.sleep(0.05)
                t_panel = page.evaluate("window.__geolocPanelAt") / 1e3
                useful = max(t_scene, t_panel) - t0
                cpu1, scpu1 = _browser_cpu_s(), time.process_time()
                dt_settle, seen = _settled(page, t0, ready=ready)
                cid = (set(built) - before).pop()
                session = viewer.session_of(cid)
                fl = session.layers[0]
                client = server.get_clients()[cid]
                if k == 0:  # the warm-up load
                    page.close()
                    continue
                view.append(useful)
                settle.append(dt_settle)
                view_cpu.append((cpu1[0] - cpu0[0], cpu1[1] - cpu0[1], scpu1 - scpu0))
                # the peer: a small ball at the camera's look-at point, moved sideways each time
                look = np.array(client.camera.look_at, float)
                dist = float(np.linalg.norm(np.array(client.camera.position, float) - look))
                ball = session.scene.add_icosphere(
                    "/bench_peer", radius=0.02 * dist, color=(255, 0, 255), position=tuple(look)
                )
                time.sleep(2.0)
                seen = len(_frames(page))
                for j in range(args.steps):
                    # a step to the next frame, as the GUI's slider sets it
                    probe.start()
                    c0, s0 = _browser_cpu_s(), time.process_time()
                    t_step = time.time()
                    flushed.clear()
                    w = time.perf_counter()
                    fl.sl_frame.value = (int(fl.sl_frame.value) + 1) % len(fl.model)
                    server_step.append((time.perf_counter() - w, time.process_time() - s0))
                    to_scene.append(flushed[0] - w if flushed else float("nan"))
                    steps.append(_first_change(page, seen, t_step))
                    c1 = _browser_cpu_s()
                    step_cpu.append((c1[0] - c0[0], c1[1] - c0[1]))
                    _, seen = _settled(page, t_step, quiet_s=1.0, after=seen)
                    step_where.append(probe.stop())
                    # the peer: the bare update
                    probe.start()
                    t_peer = time.time()
                    ball.position = tuple(look + (0.04 * dist * (1 if j % 2 == 0 else -1), 0.0, 0.0))
                    peers.append(_first_change(page, seen, t_peer))
                    _, seen = _settled(page, t_peer, quiet_s=1.0, after=seen)
                    peer_where.append(probe.stop())
                ball.remove()
                # playback at 10 frames per second asked
                fl.num_fps.value = 10.0
                time.sleep(1.0)
                seen = len(_frames(page))
                f0, t_play = fl.current, time.time()
                c0 = _browser_cpu_s()
                fl.toggle_play()
                time.sleep(args.play_s)
                fl.toggle_play()
                dt = time.time() - t_play
                c1 = _browser_cpu_s()
                shown = (fl.current - f0) % len(fl.model)
                changes = len(_frames(page)) - seen
                play.append((shown / dt, changes / dt, (c1[0] - c0[0]) / dt))
                page.close()
    finally:
        server.stop()
    med = statistics.median
    load1 = os.getloadavg()
    print(
        f"headless Chromium (software WebGL), 1000 x 640, geoloc view's example flight with its video, "
        f"{os.cpu_count()} cores, load average {load0[0]:.1f} before, {load1[0]:.1f} after"
    )
    print(
        f"first useful view (scene on the canvas and the panel naming the frame): median {med(view):.2f} s "
        f"wall over {len(view)} loads (goal 5 s); settled {med(settle):.2f} s; browser CPU "
        f"{med(v[0] for v in view_cpu):.2f} s (GPU process {med(v[1] for v in view_cpu):.2f} s), server CPU "
        f"{med(v[2] for v in view_cpu):.2f} s"
    )
    print(
        f"step to the next frame, to the first canvas change: median {med(steps) * 1e3:.0f} ms wall over "
        f"{len(steps)} steps (goal 300 ms); browser CPU {med(c[0] for c in step_cpu) * 1e3:.0f} ms (GPU process "
        f"{med(c[1] for c in step_cpu) * 1e3:.0f} ms); the server's step {med(s[0] for s in server_step) * 1e3:.0f} "
        f"ms wall, {med(s[1] for s in server_step) * 1e3:.0f} ms CPU, its scene batch sent after "
        f"{med(to_scene) * 1e3:.0f} ms wall"
    )
    print(f"peer: viser's bare scene update (one ball moved) to the canvas: median {med(peers) * 1e3:.0f} ms wall")
    for label, rows in (("a step", step_where), ("the peer", peer_where)):
        big = statistics.mode(r["biggest"][0] for r in rows)
        print(
            f"where {label}'s time goes (medians, from the update to the canvas settled): "
            f"{med(r['messages'] for r in rows):.0f} messages ({med(r['scene'] for r in rows):.0f} scene, "
            f"{med(r['gui'] for r in rows):.0f} GUI), {med(r['bytes'] for r in rows) / 1e3:.1f} kB "
            f"(biggest kind {big}: {med(r['biggest'][1] for r in rows if r['biggest'][0] == big) / 1e3:.1f} kB); "
            f"{med(r['nodes'] for r in rows):.0f} scene nodes touched, {med(r['created'] for r in rows):.0f} created; "
            f"{med(r['frames'] for r in rows):.0f} frames drawn; renderer main thread "
            f"{med(r['task_s'] for r in rows) * 1e3:.0f} ms busy ({med(r['script_s'] for r in rows) * 1e3:.0f} ms "
            f"script); Chromium CPU {med(r['browser_s'] for r in rows) * 1e3:.0f} ms (GPU process "
            f"{med(r['gpu_s'] for r in rows) * 1e3:.0f} ms)"
        )
    print(
        f"playback, 10 frames per second asked: {med(p[0] for p in play):.2f} frames/s reached by the timeline, "
        f"{med(p[1] for p in play):.2f} canvas changes/s, browser CPU {med(p[2] for p in play):.2f} s per s "
        f"(medians over {len(play)} runs of {args.play_s:g} s)"
    )
    print(
        f"ratio: step / bare update {med(steps) / med(peers):.2f} (Chromium CPU "
        f"{med(r['browser_s'] for r in step_where) / max(med(r['browser_s'] for r in peer_where), 1e-3):.2f}); "
        f"playback reached / asked "
        f"{med(p[0] for p in play) / 10.0:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
