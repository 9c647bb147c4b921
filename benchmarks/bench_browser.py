"""The viewer in a real browser: time to a fully rendered canvas, and to a timeline step.

One command: ``python benchmarks/bench_browser.py [--repeat 3] [--steps 5]``.

Headless Debian Chromium through playwright with software WebGL (SwiftShader: a laptop without
acceleration, a remote desktop, this machine), a 1000 x 640 page on ``geoloc view``'s viewer (one
session per tab, the default layers) on the bundled example flight. Measured, medians:

* **default view**: from ``page.goto`` to the canvas's last change before 2 s without one (the
  page, the scene and the GUI all in; target 5 s);
* **timeline step**: from setting the frame slider (as the GUI would) to the first change of the
  canvas (target 1 s), and to its last change before 2 s without one (a followed camera glides);
* **peer**: the server's own compute time for the same things: building the tab's session (all
  its layers) and one step (``FlightLayer.go``), wall and CPU (``time.process_time`` of this
  process, which runs the server);
* **browser CPU** beside each wall time: the CPU seconds (user + system, ``/proc/PID/stat``) of
  Chromium's processes over the same interval, its GPU process (SwiftShader, where software WebGL
  draws) apart: on 2 cores a wall time well above them is time spent waiting for a core.

The canvas is watched from inside the page (``PROBE``, every 50 ms): a Playwright screenshot of it
costs 0.8 s in this browser, which the previous instrument added to every figure.

``--groups``: where a frame's time goes, on one more tab without the probe (``COUNTER`` counts
WebGL draw calls and their indices per animation frame): over ``--window`` seconds (6) of a still default view (viser
renders on demand: a frame a second, the heartbeat), frames per second, draw calls and indices
per frame and the GPU process's CPU seconds per frame, with nothing hidden and then with each
node group hidden in turn (cumulative): ``/flight``, ``/enu/terrain``, the rest of ``/enu``.
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


def _browser_cpu_s() -> tuple[float, float]:
    """(CPU seconds of every Chromium process under this one, of its GPU process alone), from
    ``/proc/PID/stat`` (utime + stime, fields 14-15, in clock ticks); Linux only, else NaN."""
    try:
        tick = os.sysconf("SC_CLK_TCK")
        procs = {}
        for d in os.listdir("/proc"):
            if d.isdigit():
                try:
                    with open(f"/proc/{d}/stat") as f:
                        st = f.read()
                    with open(f"/proc/{d}/cmdline", "rb") as f:
                        cmd = f.read()
                except OSError:
                    continue
                rest = st[st.rindex(")") + 2 :].split()  # after "pid (comm) "
                procs[int(d)] = (int(rest[1]), (int(rest[11]) + int(rest[12])) / tick, cmd)
    except (OSError, ValueError, AttributeError):
        return float("nan"), float("nan")
    mine, todo = set(), [os.getpid()]
    while todo:
        p = todo.pop()
        kids = [c for c, (pp, _, _) in procs.items() if pp == p and c not in mine]
        mine.update(kids)
        todo += kids
    chrome = [procs[c] for c in mine if b"chrom" in procs[c][2]]
    return (sum(t for _, t, _ in chrome), sum(t for _, t, cmd in chrome if b"--type=gpu-process" in cmd))


#: An in-page probe, installed before the viewer's scripts (``add_init_script``): every
#: ``PROBE_MS`` it draws the largest canvas (viser's WebGL one) into a 250 x 160 2D canvas
#: (``drawImage`` of a WebGL canvas copies the frame last presented), hashes its pixels and, when
#: the hash changes, appends ``[Date.now(), hash, distinct colours]`` to ``window.__geolocFrames``.
#: About 10 ms a probe here; a Playwright screenshot of the canvas costs 0.8 s, so a wait by
#: screenshots measured mostly itself.
PROBE_MS = 50
PROBE = (
    """(() => {
  const frames = []; window.__geolocFrames = frames;
  const small = document.createElement('canvas'); small.width = 250; small.height = 160;
  let last = null;
  function probe() {
    const cs = [...document.querySelectorAll('canvas')].filter(c => c !== small && c.width > 0 && c.height > 0);
    if (cs.length) {
      const c = cs.reduce((a, b) => a.width * a.height >= b.width * b.height ? a : b);
      const g = small.getContext('2d', {willReadFrequently: true});
      g.clearRect(0, 0, 250, 160);
      g.drawImage(c, 0, 0, 250, 160);
      const d = g.getImageData(0, 0, 250, 160).data;
      let h = 0; const colours = new Set();
      for (let i = 0; i < d.length; i += 4) {
        h = (Math.imul(h, 31) + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) | 0;
        colours.add(((d[i] >> 3) << 10) | ((d[i + 1] >> 3) << 5) | (d[i + 2] >> 3));
      }
      if (h !== last) { frames.push([Date.now(), h, colours.size]); last = h; }
    }
    setTimeout(probe, %d);
  }
  probe();
})();"""
    % PROBE_MS
)


def _frames(page) -> list:
    """The probe's changes so far: [(time [s, epoch], hash, distinct colours)]."""
    return [(t / 1e3, h, n) for t, h, n in page.evaluate("window.__geolocFrames || []")]


def _settled(page, t0, timeout=240.0, quiet_s=2.0, ready=lambda: True, min_colours=200, after=0):
    """(seconds from ``t0`` [epoch] to the last canvas change before ``quiet_s`` without one,
    counting only once ``ready()`` (the tab's session is built) and the canvas shows a scene
    (``min_colours`` distinct colours: a blank or half-loaded canvas is flat)); changes before
    index ``after`` of the probe's list are ignored."""
    while time.time() - t0 < timeout:
        fr = _frames(page)[after:]
        if fr and ready() and fr[-1][2] >= min_colours and time.time() - fr[-1][0] >= quiet_s:
            return fr[-1][0] - t0, len(fr) + after
        time.sleep(0.2)
    raise RuntimeError(f"the canvas did not settle within {timeout} s")


def _screenshot_s(page) -> float:
    """Wall seconds of one Playwright screenshot of the canvas (the instrument this replaced)."""
    t = time.perf_counter()
    page.locator("canvas").first.screenshot(timeout=120000, animations="disabled")
    return time.perf_counter() - t


#: Counts, per animation frame that drew, the WebGL draw calls and their indices (vertices for
#: ``drawArrays``; times the instances for the instanced calls) into ``window.__geolocDraws``.
COUNTER = """(() => {
  const st = {frames: 0, draws: 0, prims: 0}; window.__geolocDraws = st;
  let cur = 0;
  for (const P of [WebGL2RenderingContext.prototype, WebGLRenderingContext.prototype]) {
    for (const m of ['drawElements', 'drawArrays', 'drawElementsInstanced', 'drawArraysInstanced']) {
      const f = P[m]; if (!f) continue;
      P[m] = function(...a) {
        st.draws++; cur++;
        const inst = m.endsWith('Instanced') ? a[a.length - 1] : 1;
        st.prims += (m.startsWith('drawElements') ? a[1] : a[2]) * inst;
        return f.apply(this, a);
      };
    }
  }
  const raf = window.requestAnimationFrame.bind(window);
  window.requestAnimationFrame = (cb) => raf((t) => { if (cur) { st.frames++; cur = 0; } cb(t); });
})();"""


def _census(browser, server, viewer, built, window_s=6.0) -> list:
    """(label, frames/s, draws/frame, indices/frame, GPU-process CPU s/frame) over a still default
    view, then with each node group hidden in turn (``--groups``)."""
    page = browser.new_page(viewport={"width": 1000, "height": 640})
    page.add_init_script(COUNTER)
    before = set(built)
    page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
    t0 = time.time()
    while len(set(built) - before) < 1 and time.time() - t0 < 120:
        time.sleep(0.2)
    api = viewer.session_of((set(built) - before).pop()).scene
    time.sleep(10.0)  # the scene in and drawn (the default view settles in 3-7 s here)
    names = sorted(api._handle_from_node_name)  # viser's node table (private: a benchmark only)
    rows = []

    def window(label):
        s0 = page.evaluate("({...window.__geolocDraws})")
        c0, w = _browser_cpu_s(), time.time()
        time.sleep(window_s)
        c1, dt = _browser_cpu_s(), time.time() - w
        s1 = page.evaluate("({...window.__geolocDraws})")
        fr = max(s1["frames"] - s0["frames"], 1)
        rows.append(
            (
                label,
                (s1["frames"] - s0["frames"]) / dt,
                (s1["draws"] - s0["draws"]) / fr,
                (s1["prims"] - s0["prims"]) / fr,
                (c1[1] - c0[1]) / fr,
            )
        )

    window("nothing hidden")
    for group, label in (
        ("/flight", "/flight hidden"),
        ("/enu/terrain", "and /enu/terrain"),
        ("/enu", "and the rest of /enu"),
    ):
        for n in names:  # the group's node and its children (a hidden parent hides its subtree)
            if n == group or (n.startswith(group + "/") and n.count("/") == group.count("/") + 1):
                api._handle_from_node_name[n].visible = False
        window(label)
    page.close()
    return rows


def served_flight_viewer():
    """The default flight's viewer on a fresh local server: (server, viewer, built), ``built``
    mapping each tab's client id to ``time.time()`` when its tab was built (the server's side of a
    first view)."""
    from geoloc_viz.app import GeolocViewer, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    server = make_server(port=0)
    built: dict = {}
    viewer = GeolocViewer(server, default_flight_scenario())
    orig = viewer._build_tab

    def timed_build(client, name):
        orig(client, name)
        built[client.client_id] = time.time()

    viewer._build_tab = timed_build
    return server, viewer, built


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="page loads (default 3)")
    ap.add_argument("--steps", type=int, default=5, help="timeline steps per load (default 5)")
    ap.add_argument(
        "--groups",
        action="store_true",
        help="also: a frame's draw calls and GPU time with each node group hidden in turn",
    )
    ap.add_argument("--window", type=float, default=6.0, help="with --groups: seconds per measure (default 6)")
    args = ap.parse_args(argv)

    from test_viz_browser import chromium

    from geoloc_viz.app import GeolocViewer, make_server
    from geoloc_viz.flight_model import default_flight_scenario

    scn = default_flight_scenario()
    server = make_server(port=0)
    built: dict = {}
    viewer = GeolocViewer(server, scn)
    orig = viewer._build_tab

    def timed_build(client, name):
        w, c = time.perf_counter(), time.process_time()
        orig(client, name)
        built[client.client_id] = (time.perf_counter() - w, time.process_time() - c)

    viewer._build_tab = timed_build
    view_s, step_s, settle_s, peer_build, peer_step, view_cpu, step_cpu, shots = [], [], [], [], [], [], [], []
    try:
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            # a first load warms the caches every tab shares (the flight model, the terrain mesh)
            for k in range(args.repeat + 1):
                page = browser.new_page(viewport={"width": 1000, "height": 640})
                page.add_init_script(PROBE)
                before = set(built)
                cpu0 = _browser_cpu_s()
                t0 = time.time()
                page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
                dt, seen = _settled(page, t0, ready=lambda: len(set(built) - before) == 1)
                cpu1 = _browser_cpu_s()
                cid = (set(built) - before).pop()
                if k > 0:
                    view_s.append(dt)
                    view_cpu.append((cpu1[0] - cpu0[0], cpu1[1] - cpu0[1]))
                    peer_build.append(built[cid])
                    shots.append(_screenshot_s(page))
                    seen = len(_frames(page))
                fl = viewer.session_of(cid).layers[0]
                for j in range(args.steps if k > 0 else 0):
                    cpu0 = _browser_cpu_s()
                    t_step = time.time()
                    w, c = time.perf_counter(), time.process_time()
                    fl.sl_frame.value = (int(fl.sl_frame.value) + 7) % len(fl.model)  # as the GUI would
                    peer_step.append((time.perf_counter() - w, time.process_time() - c))
                    fr = _frames(page)
                    while len(fr) == seen and time.time() - t_step < 120:
                        time.sleep(0.02)
                        fr = _frames(page)
                    if len(fr) == seen:
                        raise RuntimeError("a timeline step did not reach the canvas within 120 s")
                    step_s.append(fr[seen][0] - t_step)  # the first frame that differs
                    cpu1 = _browser_cpu_s()
                    step_cpu.append((cpu1[0] - cpu0[0], cpu1[1] - cpu0[1]))
                    dt_settle, seen = _settled(page, t_step, after=seen)
                    settle_s.append(dt_settle)
                page.close()
            census = _census(browser, server, viewer, built, args.window) if args.groups else []
    finally:
        server.stop()
    med = statistics.median
    print(
        f"headless Chromium (software WebGL), 1000 x 640, example flight, {os.cpu_count()} cores, "
        f"load {os.getloadavg()[0]:.1f}"
    )
    print(
        f"default view to a settled canvas: median {med(view_s):.2f} s wall over {len(view_s)} loads "
        f"(target 5 s); peer: the server builds the tab's session in {med(b[0] for b in peer_build):.2f} s "
        f"wall, {med(b[1] for b in peer_build):.2f} s CPU; ratio {med(view_s) / med(b[0] for b in peer_build):.1f}"
    )
    print(
        f"  browser CPU over it: {med(v[0] for v in view_cpu):.2f} s (GPU process {med(v[1] for v in view_cpu):.2f} s)"
    )
    print(
        f"timeline step to the canvas: median {med(step_s):.2f} s wall over {len(step_s)} steps (target 1 s), "
        f"to a settled canvas {med(settle_s):.2f} s; "
        f"peer: the server's step {med(p[0] for p in peer_step) * 1e3:.0f} ms wall, "
        f"{med(p[1] for p in peer_step) * 1e3:.0f} ms CPU; ratio {med(step_s) / med(p[0] for p in peer_step):.0f}"
    )
    print(
        f"  browser CPU over it: {med(v[0] for v in step_cpu):.2f} s (GPU process {med(v[1] for v in step_cpu):.2f} s)"
    )
    print(
        f"instrument: the canvas probed in the page every {PROBE_MS} ms (about 10 ms a probe); one "
        f"Playwright screenshot of the canvas takes {med(shots):.2f} s, the previous instrument"
    )
    if census:
        print("a still default view, frame by frame (viser draws on demand: its heartbeat is a frame a second):")
        for label, fps, draws, prims, gpu in census:
            print(
                f"  {label:24s} {fps:5.2f} frames/s, {draws:4.0f} draw calls and {prims:8.0f} indices a frame, "
                f"GPU process {gpu:.3f} s CPU a frame"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
