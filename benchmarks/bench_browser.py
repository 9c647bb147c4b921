"""The viewer in a real browser (issue 34 item 5): time to a fully rendered canvas, and to a timeline step.

One command: ``python benchmarks/bench_browser.py [--repeat 3] [--steps 5]``.

Headless Debian Chromium through playwright with software WebGL (SwiftShader: a laptop without
acceleration, a remote desktop, this machine), a 1000 x 640 page on ``geoloc view``'s viewer (one
session per tab, the default layers) on the bundled example flight. Measured, medians:

* **default view**: from ``page.goto`` to the first canvas screenshot after which the canvas stays
  the same (two more identical screenshots 0.3 s apart): the page, the scene and the GUI all in
  (target 5 s);
* **timeline step**: from setting the frame slider (as the GUI would) to the first canvas
  screenshot that differs from the one before the step (target 1 s);
* **peer**: the server's own compute time for the same things: building the tab's session (all
  its layers) and one step (``FlightLayer.go``), wall and CPU (``time.process_time`` of this
  process, which runs the server);
* **browser CPU** beside each wall time: the CPU seconds (user + system, ``/proc/PID/stat``) of
  Chromium's processes over the same interval, its GPU process (SwiftShader, where software WebGL
  draws) apart: on 2 cores a wall time well above them is time spent waiting for a core.

Screenshots of the canvas element are PNG (lossless), compared exactly.
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


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
                rest = st[st.rindex(")") + 2:].split()  # after "pid (comm) "
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


def _canvas(page) -> np.ndarray:
    import PIL.Image

    png = page.locator("canvas").first.screenshot(timeout=120000, animations="disabled")
    return np.asarray(PIL.Image.open(io.BytesIO(png)).convert("RGB"))


def _settled(page, t0, timeout=240.0, same=2, gap_s=0.3, ready=lambda: True, min_colours=200):
    """(seconds from t0 to the first of ``same`` + 1 identical canvas screenshots, image), counting
    only once ``ready()`` (the tab's session is built) and the canvas shows a scene (``min_colours``
    distinct colours: a blank or half-loaded canvas is flat)."""
    last, first_t, run = None, None, 0
    while time.perf_counter() - t0 < timeout:
        t = time.perf_counter()
        img = _canvas(page)
        full = ready() and len(np.unique((img // 8).reshape(-1, 3), axis=0)) >= min_colours
        if full and last is not None and img.shape == last.shape and np.array_equal(img, last):
            run += 1
            if run >= same:
                return first_t - t0, img
        else:
            run, first_t = 0, t
        last = img
        time.sleep(gap_s)
    raise RuntimeError(f"the canvas did not settle within {timeout} s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="page loads (default 3)")
    ap.add_argument("--steps", type=int, default=5, help="timeline steps per load (default 5)")
    args = ap.parse_args(argv)

    from test_viz_browser import chromium, wait_for

    from geoloc.viz.app import GeolocViewer, make_server
    from geoloc.viz.flight_model import default_flight_scenario

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
    view_s, step_s, peer_build, peer_step, view_cpu, step_cpu = [], [], [], [], [], []
    try:
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            # a first load warms the caches every tab shares (the flight model, the terrain mesh)
            for k in range(args.repeat + 1):
                page = browser.new_page(viewport={"width": 1000, "height": 640})
                before = set(built)
                cpu0 = _browser_cpu_s()
                t0 = time.perf_counter()
                page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr=1", timeout=120000)
                dt, img = _settled(page, t0, ready=lambda: len(set(built) - before) == 1)
                cpu1 = _browser_cpu_s()
                cid = (set(built) - before).pop()
                if k > 0:
                    view_s.append(dt)
                    view_cpu.append((cpu1[0] - cpu0[0], cpu1[1] - cpu0[1]))
                    peer_build.append(built[cid])
                fl = viewer.session_of(cid).layers[0]
                for j in range(args.steps if k > 0 else 0):
                    ref = img
                    cpu0 = _browser_cpu_s()
                    w, c = time.perf_counter(), time.process_time()
                    fl.sl_frame.value = (int(fl.sl_frame.value) + 7) % len(fl.model)  # as the GUI would
                    peer_step.append((time.perf_counter() - w, time.process_time() - c))
                    while True:
                        img = _canvas(page)
                        if not np.array_equal(img, ref) or time.perf_counter() - w > 120:
                            break
                    step_s.append(time.perf_counter() - w)
                    cpu1 = _browser_cpu_s()
                    step_cpu.append((cpu1[0] - cpu0[0], cpu1[1] - cpu0[1]))
                    _, img = _settled(page, time.perf_counter())
                page.close()
    finally:
        server.stop()
    med = statistics.median
    print(f"headless Chromium (software WebGL), 1000 x 640, example flight, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"default view to a settled canvas: median {med(view_s):.2f} s wall over {len(view_s)} loads "
          f"(target 5 s); peer: the server builds the tab's session in {med(b[0] for b in peer_build):.2f} s "
          f"wall, {med(b[1] for b in peer_build):.2f} s CPU; ratio {med(view_s) / med(b[0] for b in peer_build):.1f}")
    print(f"  browser CPU over it: {med(v[0] for v in view_cpu):.2f} s (GPU process "
          f"{med(v[1] for v in view_cpu):.2f} s)")
    print(f"timeline step to the canvas: median {med(step_s):.2f} s wall over {len(step_s)} steps (target 1 s); "
          f"peer: the server's step {med(p[0] for p in peer_step) * 1e3:.0f} ms wall, "
          f"{med(p[1] for p in peer_step) * 1e3:.0f} ms CPU; ratio {med(step_s) / med(p[0] for p in peer_step):.0f}")
    print(f"  browser CPU over it: {med(v[0] for v in step_cpu):.2f} s (GPU process "
          f"{med(v[1] for v in step_cpu):.2f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
