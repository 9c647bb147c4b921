"""What one drawn frame of the viewer's canvas costs under software WebGL, and what in it costs.

One command: ``python benchmarks/bench_frame.py [--window 4] [--rounds 3]``.

Headless Debian Chromium through playwright with software WebGL (SwiftShader: the GPU process
draws on the CPU), ``geoloc view``'s per-tab viewer on the bundled example flight with its video
(every default layer), as ``bench_viewer.py`` opens it. viser draws on demand (a frame a second
while idle, its heartbeat; each scene update opens a 250 ms window of continuous frames), so to
time a frame the server keeps the canvas drawing: a tiny node far under the terrain is moved
every 40 ms (each move asks for frames; the node is never in view). Over ``--window`` seconds, per
configuration:

* **frame interval**: the median time between consecutive animation frames that drew (a WebGL
  draw call in the callback): what one frame costs the browser end to end;
* **main thread**: the median time of that animation-frame callback (three.js walking the scene
  and issuing the draw calls; SwiftShader executes them later, in the GPU process);
* **GPU process CPU per frame** and the renderer's whole CPU per frame (``/proc``), draw calls
  and indices per frame.

Configurations, each in turn (rounds alternate their order, ABC CBA, so a load that drifts during the
run weighs on all alike; medians over rounds):

* **scene**: everything shown; ``/flight`` hidden; the terrain mesh alone (its triangles
  printed); every node hidden (the empty canvas: clear and present);
* **canvas**: the page at 1000 x 640 (the default of the benchmarks) and at half its width and
  height, device pixel ratio 1 and 2 (``?fixedDpr``), and antialiasing (MSAA) off (forced through
  ``getContext``'s attributes: viser asks for it; a benchmark-only patch).

Prints the medians, the load average before and after, and the ratio of the default frame to the
empty canvas's last.

``--pair NAME [--shots DIR]``: two configurations of the same page (:data:`PAIRS`), windows
alternating ABBA, medians and the ratio B / A of the GPU process's CPU a frame (a screenshot of
each into ``DIR``): ``layout`` (the control panel floating over the canvas, or beside it: fewer
canvas pixels), ``lights`` (viser's two directional lights, or one), ``terrain-quad`` (the terrain,
or two flat triangles over its extent: what its triangles cost beyond its pixels),
``terrain-flat`` (its mesh flattened: the same triangles and colours), ``terrain-sorted`` (its
triangles near the camera first) and ``terrain-textured`` (a 41 x 41 mesh with the colours and
hillshade in a 1024 px texture).
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

#: Logs every animation-frame callback that drew: ``[start (ms), callback duration (ms), draws,
#: indices]`` into ``window.__geolocRaf.log``.
RAF_LOG = """(() => {
  const st = {log: [], draws: 0, prims: 0}; window.__geolocRaf = st;
  for (const P of [WebGL2RenderingContext.prototype, WebGLRenderingContext.prototype]) {
    for (const m of ['drawElements', 'drawArrays', 'drawElementsInstanced', 'drawArraysInstanced']) {
      const f = P[m]; if (!f) continue;
      P[m] = function(...a) {
        st.draws++;
        const inst = m.endsWith('Instanced') ? a[a.length - 1] : 1;
        st.prims += (m.startsWith('drawElements') ? a[1] : a[2]) * inst;
        return f.apply(this, a);
      };
    }
  }
  const raf = window.requestAnimationFrame.bind(window);
  window.requestAnimationFrame = (cb) => raf((t) => {
    const d0 = st.draws, p0 = st.prims, t0 = performance.now(), e0 = Date.now();
    cb(t);
    if (st.draws > d0) {
      st.log.push([t0, performance.now() - t0, st.draws - d0, st.prims - p0, e0]);
      if (st.log.length > 4000) st.log.splice(0, 2000);
    }
  });
})();"""

#: Logs each message batch the page's websocket worker hands to the main thread (viser receives in a
#: worker; a batch arrives as one message): ``[Date.now(), messages, scene messages]`` into
#: ``window.__geolocMsgs``.
MSG_LOG = """(() => {
  const log = []; window.__geolocMsgs = log;
  const W = window.Worker;
  window.Worker = function(...a) {
    const w = new W(...a);
    w.addEventListener('message', (e) => {
      const d = e.data;
      if (d && d.type === 'message_batch') {
        const scene = d.messages.filter((m) => typeof m.name === 'string' && m.name.startsWith('/')).length;
        log.push([Date.now(), d.messages.length, scene]);
      }
    });
    return w;
  };
  window.Worker.prototype = W.prototype;
})();"""

#: Asks for WebGL without multisampling (viser's canvas asks for it; three.js's default).
NO_MSAA = """(() => {
  const g = HTMLCanvasElement.prototype.getContext;
  HTMLCanvasElement.prototype.getContext = function(type, attrs) {
    if (typeof type === 'string' && type.startsWith('webgl')) attrs = {...(attrs || {}), antialias: false};
    return g.call(this, type, attrs);
  };
})();"""


def _renderer_cpu_s() -> float:
    """CPU seconds of Chromium's renderer processes (``--type=renderer``) under this process."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/cmdline", "rb") as f:
                cmd = f.read()
            if b"--type=renderer" not in cmd or b"chrom" not in cmd:
                continue
            with open(f"/proc/{d}/stat") as f:
                st = f.read()
        except OSError:
            continue
        rest = st[st.rindex(")") + 2 :].split()
        total += (int(rest[11]) + int(rest[12])) / tick
    return total


class _Tab:
    """One page on the viewer, its session, and a node moved to keep the canvas drawing."""

    def __init__(self, browser, server, viewer, built, width, height, dpr, msaa, trace=False):
        import numpy as np

        self.page = browser.new_page(viewport={"width": width, "height": height})
        self.page.add_init_script(RAF_LOG)
        if not msaa:
            self.page.add_init_script(NO_MSAA)
        if trace:
            from bench_browser import PROBE

            self.page.add_init_script(MSG_LOG)
            self.page.add_init_script(PROBE)
        before = set(built)
        self.page.goto(f"http://127.0.0.1:{server.get_port()}/?fixedDpr={dpr:g}", timeout=120000)
        t0 = time.time()
        while len(set(built) - before) < 1 and time.time() - t0 < 240:
            time.sleep(0.2)
        self.session = viewer.session_of((set(built) - before).pop())
        self.api = self.session.scene
        time.sleep(8.0)  # the scene in and drawn
        # far below the terrain (the scene's Up is +z), a few metres wide: never seen
        self.dummy = self.api.add_icosphere("/bench_kick", radius=1.0, color=(0, 0, 0), position=(0.0, 0.0, -2e5))
        self.np = np

    def names(self) -> list:
        return sorted(self.api._handle_from_node_name)  # viser's node table (private: a benchmark only)

    def show_only(self, keep) -> None:
        """Hides every top-level node not in ``keep`` and not on the way to one (a hidden parent
        hides its subtree), shows the rest of the top levels."""
        table = self.api._handle_from_node_name
        for n in self.names():
            if n in ("/bench_kick",) or n.count("/") > 2:
                continue
            on_path = any(k == n or k.startswith(n + "/") for k in keep)
            inside = any(n.startswith(k + "/") for k in keep)
            if n.count("/") == 1 or n.startswith("/enu/"):
                table[n].visible = keep == ["*"] or on_path or inside

    def window(self, seconds: float) -> dict:
        from bench_browser import _browser_cpu_s

        time.sleep(1.5)  # the visibility change drawn
        n0 = self.page.evaluate("window.__geolocRaf.log.length")
        c0, r0 = _browser_cpu_s(), _renderer_cpu_s()
        t0 = time.time()
        k = 0
        while time.time() - t0 < seconds:
            k += 1
            self.dummy.position = (float(k % 7), 0.0, -2e5)
            time.sleep(0.04)
        c1, r1 = _browser_cpu_s(), _renderer_cpu_s()
        log = self.page.evaluate("window.__geolocRaf.log")[n0:]
        nfr = max(len(log), 1)
        gaps = [b[0] - a[0] for a, b in zip(log, log[1:], strict=False)]
        return {
            "interval_ms": statistics.median(gaps) if gaps else float("nan"),
            "main_ms": statistics.median(x[1] for x in log) if log else float("nan"),
            "fps": len(log) / seconds,
            "gpu_ms": (c1[1] - c0[1]) / nfr * 1e3,
            "renderer_ms": (r1 - r0) / nfr * 1e3,
            "draws": statistics.median(x[2] for x in log) if log else 0,
            "prims": statistics.median(x[3] for x in log) if log else 0,
        }

    def close(self) -> None:
        self.page.close()


def _terrain_triangles(session) -> int:
    from geoloc_viz.scene_geoloc import terrain_mesh_cached

    return -1 if session.scn.dem is None else len(terrain_mesh_cached(session.scn).faces)


def _step_trace(tab, n: int, load0, ab: bool = False) -> int:
    """``--step-trace N``: N timeline steps, each traced in the page: when its batches reached the
    page's main thread, the frames drawn after, and the canvas's first change (the probe).

    ``--ab``: 2N steps alternating (ABBA) between the session's way of sending a step's scene batch
    (``GeolocSession._send_scene``: flushed, then waited for until viser's sender has taken it) and
    the way before (flushed only: the panels' atomic block, opened at once, can hold it back)."""
    import numpy as np
    from bench_browser import _frames, _settled

    fl = tab.session.layers[0]
    tab.dummy.remove()
    t_wait = time.time()
    _, seen = _settled(tab.page, t_wait - 60.0, quiet_s=1.5)
    rows = []
    session = tab.session
    target = session.client if session.client is not None else session.server
    ways = ("flush only (before)", "wait for the sender (now)")
    for j in range(2 * n if ab else n):
        way = ways[(j + j // 2) % 2] if ab else ways[1]
        if way == ways[0]:
            session._send_scene = lambda: target.flush()  # an instance attribute hides the method
        else:
            session.__dict__.pop("_send_scene", None)
        nm, nf = tab.page.evaluate("[window.__geolocMsgs.length, window.__geolocRaf.log.length]")
        t_step = time.time()
        s0 = time.process_time()
        fl.sl_frame.value = (int(fl.sl_frame.value) + 1) % len(fl.model)
        server = (time.time() - t_step, time.process_time() - s0)
        _, seen2 = _settled(tab.page, t_step, quiet_s=1.5, after=seen)
        fr = [f for f in _frames(tab.page)[seen:] if f[0] >= t_step]
        seen = seen2
        msgs = tab.page.evaluate("window.__geolocMsgs")[nm:]
        raf = tab.page.evaluate("window.__geolocRaf.log")[nf:]
        ms = lambda t: (t / 1e3 - t_step) * 1e3  # noqa: E731  (epoch ms to ms after the step)
        first = (fr[0][0] - t_step) * 1e3 if fr else float("nan")
        scene_at = [ms(m[0]) for m in msgs if m[2] > 0]
        frames = [ms(r[4]) for r in raf]
        before_change = [f for f in frames if f <= first]
        after_scene = [f for f in before_change if scene_at and f >= scene_at[0]]
        rows.append((server, first, msgs, scene_at, frames, after_scene, way))
        print(
            f"  step ({way}): server {server[0] * 1e3:.0f} ms wall ({server[1] * 1e3:.0f} ms CPU); batches at "
            + ", ".join(f"{ms(m[0]):.0f} ms ({m[1]} msgs, {m[2]} scene)" for m in msgs)
            + f"; frames started at {', '.join(f'{f:.0f}' for f in frames[:8])} ms; first canvas change "
            f"{first:.0f} ms ({len(after_scene)} frames started between the scene batch and it)"
        )
    med = statistics.median
    load1 = os.getloadavg()
    print(f"traced steps, load average {load0[0]:.1f} before, {load1[0]:.1f} after; medians over {n} a way:")
    out = {}
    for way in ways if ab else ways[1:]:
        rs = [r for r in rows if r[6] == way and r[3] and np.isfinite(r[1])]
        out[way] = (med(r[3][0] for r in rs), med(r[1] for r in rs))
        print(
            f"  {way}: server's step {med(r[0][0] for r in rs) * 1e3:.0f} ms wall, "
            f"{med(r[0][1] for r in rs) * 1e3:.0f} ms CPU; the scene batch in the page after {out[way][0]:.0f} ms, "
            f"before the server's step ended in {sum(r[3][0] < r[0][0] * 1e3 for r in rs)} of {len(rs)}; "
            f"first canvas change {out[way][1]:.0f} ms; frames started from the scene batch to the change "
            f"{med(len(r[5]) for r in rs):.0f}"
        )
    if ab:
        print(
            f"ratio: now / before: the scene batch in the page {out[ways[1]][0] / out[ways[0]][0]:.2f}, the first "
            f"canvas change {out[ways[1]][1] / out[ways[0]][1]:.2f}"
        )
    return 0


def _terrain_ab(tab, args, tri, load0) -> int:
    """``--terrain-ab N``: the drawn terrain against a copy on an N x N grid, in one page, windows
    alternating ABBA; medians."""
    from geoloc_viz import terrain_link
    from geoloc_viz.scene_geoloc import unlit_glb

    s = tab.session
    fine = s.scene._handle_from_node_name["/enu/terrain"]
    mesh = terrain_link.terrain_mesh(s.scn, nodes=args.terrain_ab)
    coarse = s.scene.add_glb("/enu/terrain_ab", unlit_glb(mesh), scale=s.view._terrain_scale(), visible=False)
    rows: dict = {}
    names = (f"terrain {tri} triangles", f"terrain {len(mesh.faces)} triangles")
    for j in range(4 * args.rounds):
        b = (j + j // 2) % 2  # ABBA ...
        fine.visible, coarse.visible = not b, bool(b)
        rows.setdefault(names[b], []).append(tab.window(args.window))
    load1 = os.getloadavg()
    med = statistics.median
    print(f"paired terrain grids, load average {load0[0]:.1f} before, {load1[0]:.1f} after")
    for label, rs in rows.items():
        print(
            f"  {label:28s} frame interval {med(r['interval_ms'] for r in rs):6.0f} ms; CPU per frame: GPU process "
            f"{med(r['gpu_ms'] for r in rs):5.0f} ms, renderer {med(r['renderer_ms'] for r in rs):5.0f} ms; "
            f"{med(r['prims'] for r in rs):8.0f} indices a frame"
        )
    a, b = (med(r["gpu_ms"] for r in rows[n]) for n in names)
    print(f"ratio: GPU process CPU per frame, coarse / drawn {b / a:.2f}")
    return 0


def _theme(tab, layout: str) -> None:
    """The page's control panel ``layout`` (viser's ``control_layout``), the rest of the theme as
    :func:`geoloc_viz.app.make_server` sets it."""
    from geoloc_viz.app import THEME

    target = tab.session.client if tab.session.client is not None else tab.session.server
    target.gui.configure_theme(**{**THEME, "control_layout": layout})


def _lights(tab, few: bool) -> None:
    """viser's default lights (two directional lights, :func:`geoloc_viz.app.configure_lighting`) or,
    ``few``, one directional light of the same direction instead (the ambient light either way)."""
    s = tab.api
    s.configure_default_lights(not few, cast_shadow=False)
    if few and "/bench_sun" not in s._handle_from_node_name:
        s.add_light_directional("/bench_sun", intensity=3.0, position=(-0.2, 0.2, 1.0))
    elif not few:
        s.remove_by_name("/bench_sun")


def _terrain_copy(tab, name: str, make):
    """A hidden copy of the drawn terrain as ``name`` (``make(tab)``'s mesh, unlit as the viewer
    draws it), made once; returns the handles (drawn terrain, copy)."""
    from geoloc_viz.scene_geoloc import unlit_glb

    s = tab.session
    table = s.scene._handle_from_node_name
    if name not in table:
        s.scene.add_glb(name, unlit_glb(make(tab)), scale=s.view._terrain_scale(), visible=False)
        time.sleep(3.0)  # parsed and uploaded before any window
    return table["/enu/terrain"], table[name]


def _terrain_swap(tab, b: bool, name: str, make) -> None:
    fine, other = _terrain_copy(tab, name, make)
    fine.visible, other.visible = not b, b


def _quad_mesh(tab):
    """The drawn terrain's extent as two flat triangles at its mean height, one colour: the
    pixels the terrain covers without its triangles."""
    import trimesh

    from geoloc_viz.scene_geoloc import terrain_mesh_cached

    v = terrain_mesh_cached(tab.session.scn).vertices
    lo, hi, z = v.min(axis=0), v.max(axis=0), float(v[:, 2].mean())
    q = [[lo[0], lo[1], z], [hi[0], lo[1], z], [hi[0], hi[1], z], [lo[0], hi[1], z]]
    m = trimesh.Trimesh(q, [[0, 1, 2], [0, 2, 3]], process=False)
    m.visual.vertex_colors = [[120, 160, 110, 255]] * 4
    return m


def _flat_mesh(tab):
    """The drawn terrain, its triangles and colours, flattened to its mean height."""
    from geoloc_viz.scene_geoloc import terrain_mesh_cached

    m = terrain_mesh_cached(tab.session.scn).copy()
    v = m.vertices.copy()
    v[:, 2] = v[:, 2].mean()
    m.vertices = v
    return m


def _sorted_mesh(tab):
    """The drawn terrain with its triangles ordered nearest the page's camera first (each pixel
    shaded once where the depth test rejects what lies behind)."""
    import numpy as np

    from geoloc_viz.scene_geoloc import terrain_mesh_cached

    m = terrain_mesh_cached(tab.session.scn).copy()
    cam = np.asarray(tab.session.client.camera.position, float) / np.asarray(tab.session.view._terrain_scale())
    d = np.linalg.norm(m.vertices[m.faces].mean(axis=1) - cam, axis=1)
    m.faces = m.faces[np.argsort(d)]
    return m


def _textured_mesh(tab, nodes: int = 41, px: int = 1024):
    """The terrain as a coarse mesh (``mesh_grid``'s ``nodes x nodes``) with its colours and
    hillshade in a ``px x px`` texture on the same level-of-detail grid (so node (i, j) is texel
    (i, j) (px - 1) / (nodes - 1)); normals of the texture's grid: the cross product of its ENU
    tangents (central differences). Tried against the drawn terrain, not kept (docs/viz.md)."""
    import io

    import numpy as np
    import PIL.Image
    import trimesh

    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc_viz import terrain_link as tl

    scn = tab.session.scn
    dem, enu = scn.dem, scn.enu

    def grid(n):
        lats, lons = tl.mesh_grid(scn, nodes=n)
        LON, LAT = np.meshgrid(lons, lats)
        return LAT, LON, dem.height(np.deg2rad(LAT), np.deg2rad(LON))

    LAT, LON, H = grid(px)
    P = enu.from_ecef(geodetic_to_ecef(np.deg2rad(LAT), np.deg2rad(LON), np.nan_to_num(H)).reshape(-1, 3))
    P = P.reshape(px, px, 3)
    n = np.cross(np.gradient(P, axis=1), np.gradient(P, axis=0))
    n *= np.where(n[..., 2:3] < 0.0, -1.0, 1.0)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    rgb = tl._terrain_colours(H, np.nanmin(H), np.nanmax(H))[..., :3] * tl._shade(n)[..., None]
    buf = io.BytesIO()
    PIL.Image.fromarray((np.clip(rgb, 0.0, 1.0) * 255).astype(np.uint8)).save(buf, format="JPEG", quality=90)
    buf.seek(0)
    mesh = tl._grid_trimesh(*grid(nodes), enu)
    t = (np.linspace(0.0, px - 1.0, nodes) + 0.5) / px  # texel centres; trimesh's v counts up
    U, V = np.meshgrid(t, 1.0 - t)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.stack([U.ravel(), V.ravel()], 1), image=PIL.Image.open(buf))
    return mesh


#: ``--pair NAME``: (what A is, what B is, the function that sets the page to A (False) or B (True)).
PAIRS = {
    "layout": (
        "panel floating over the canvas",
        "panel beside the canvas",
        lambda t, b: _theme(t, "fixed" if b else "floating"),
    ),
    "lights": ("viser's two directional lights", "one directional light", _lights),
    "terrain-quad": (
        "the terrain",
        "a flat quad over its extent",
        lambda t, b: _terrain_swap(t, b, "/enu/terrain_quad", _quad_mesh),
    ),
    "terrain-textured": (
        "the terrain, vertex colours",
        "a coarse mesh, textured",
        lambda t, b: _terrain_swap(t, b, "/enu/terrain_textured", _textured_mesh),
    ),
    "terrain-flat": (
        "the terrain",
        "its mesh flattened",
        lambda t, b: _terrain_swap(t, b, "/enu/terrain_flat", _flat_mesh),
    ),
    "terrain-sorted": (
        "the terrain",
        "its triangles near to far",
        lambda t, b: _terrain_swap(t, b, "/enu/terrain_sorted", _sorted_mesh),
    ),
}


def _pair(tab, args, load0) -> int:
    """``--pair NAME``: configuration A against B (:data:`PAIRS`) in one page, windows
    alternating ABBA, medians; with ``--shots DIR``, a screenshot of each way (its first window)."""
    la, lb, apply = PAIRS[args.pair]
    rows: dict = {}
    apply(tab, False)
    for j in range(4 * args.rounds):
        b = (j + j // 2) % 2  # ABBA ...
        apply(tab, bool(b))
        rows.setdefault((la, lb)[b], []).append(tab.window(args.window))
        if args.shots and len(rows[(la, lb)[b]]) == 1:
            Path(args.shots).mkdir(parents=True, exist_ok=True)
            tab.page.screenshot(path=str(Path(args.shots) / f"{args.pair}_{'ab'[b]}.png"))
    apply(tab, False)
    load1 = os.getloadavg()
    med = statistics.median
    print(
        f"paired --pair {args.pair}, {4 * args.rounds} windows ABBA, load average {load0[0]:.1f} before, {load1[0]:.1f} after"
    )
    for label, rs in rows.items():
        print(
            f"  {label:32s} frame interval {med(r['interval_ms'] for r in rs):6.0f} ms; CPU per frame: GPU process "
            f"{med(r['gpu_ms'] for r in rs):5.0f} ms, renderer {med(r['renderer_ms'] for r in rs):5.0f} ms; "
            f"{med(r['draws'] for r in rs):4.0f} draw calls"
        )
    a, b = (med(r["gpu_ms"] for r in rows[n]) for n in (la, lb))
    print(f"ratio: GPU process CPU per frame, B / A {b / a:.2f}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--window", type=float, default=4.0, help="seconds of drawing per measure (default 4)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds over the configurations (default 3)")
    ap.add_argument("--no-canvas", action="store_true", help="only the scene's configurations")
    ap.add_argument(
        "--nodes",
        action="store_true",
        help="also: each node under /flight and /enu hidden alone (what it adds to a frame)",
    )
    ap.add_argument(
        "--terrain-ab",
        type=int,
        default=0,
        metavar="N",
        help="only compare, paired in one page, the drawn terrain with a copy on an N x N node grid",
    )
    ap.add_argument("--step-trace", type=int, default=0, metavar="N", help="only trace N timeline steps in the page")
    ap.add_argument("--ab", action="store_true", help="with --step-trace: the scene batch's send, before and now")
    ap.add_argument("--pair", choices=sorted(PAIRS), help="only compare, paired in one page, two configurations")
    ap.add_argument("--shots", metavar="DIR", help="with --pair: a screenshot of each configuration into DIR")
    args = ap.parse_args(argv)

    from bench_browser import served_flight_viewer
    from test_viz_browser import chromium

    load0 = os.getloadavg()
    server, viewer, built = served_flight_viewer()
    scene_rows: dict = {}
    canvas_rows: dict = {}
    node_rows: dict = {}
    tri = -1
    try:
        with tempfile.TemporaryDirectory() as tmp, chromium(Path(tmp)) as browser:
            tab = _Tab(browser, server, viewer, built, 1000, 640, 1, True, trace=bool(args.step_trace))
            if args.step_trace:
                return _step_trace(tab, args.step_trace, load0, args.ab)
            tri = _terrain_triangles(tab.session)
            if args.terrain_ab:
                return _terrain_ab(tab, args, tri, load0)
            if args.pair:
                return _pair(tab, args, load0)
            configs = [
                ("everything shown", ["*"]),
                ("/flight hidden", ["/enu"]),
                ("the terrain mesh alone", ["/enu/terrain"]),
                ("every node hidden", []),
            ]
            for r in range(args.rounds):
                for label, keep in configs if r % 2 == 0 else configs[::-1]:
                    tab.show_only(keep)
                    scene_rows.setdefault(label, []).append(tab.window(args.window))
            tab.show_only(["*"])
            if args.nodes:
                table = tab.api._handle_from_node_name
                groups = [n for n in tab.names() if n.count("/") == 2 and n.startswith(("/flight/", "/enu/"))]
                for r in range(args.rounds):
                    order = ["(none)", *groups] if r % 2 == 0 else [*groups[::-1], "(none)"]
                    for n in order:
                        was = table[n].visible if n in table else None
                        if was:
                            table[n].visible = False
                        if was or n == "(none)":
                            node_rows.setdefault(n, []).append(tab.window(args.window))
                        if was:
                            table[n].visible = True
            tab.close()
            if not args.no_canvas:
                canvases = [
                    ("1000 x 640, dpr 1, MSAA", (1000, 640, 1, True)),
                    ("500 x 320, dpr 1, MSAA", (500, 320, 1, True)),
                    ("1000 x 640, dpr 2, MSAA", (1000, 640, 2, True)),
                    ("1000 x 640, dpr 1, no MSAA", (1000, 640, 1, False)),
                ]
                for r in range(max(args.rounds - 1, 1)):
                    for label, cfg in canvases if r % 2 == 0 else canvases[::-1]:
                        tab = _Tab(browser, server, viewer, built, *cfg)
                        canvas_rows.setdefault(label, []).append(tab.window(args.window))
                        tab.close()
    finally:
        server.stop()
    load1 = os.getloadavg()
    med = statistics.median
    print(
        f"headless Chromium (software WebGL), geoloc view's example flight with its video, {os.cpu_count()} "
        f"cores, load average {load0[0]:.1f} before, {load1[0]:.1f} after; terrain mesh {tri} triangles"
    )

    def show(title, rows):
        print(title)
        for label, rs in rows.items():
            print(
                f"  {label:28s} frame interval {med(r['interval_ms'] for r in rs):6.0f} ms, main thread "
                f"{med(r['main_ms'] for r in rs):5.0f} ms, {med(r['fps'] for r in rs):5.2f} frames/s; CPU per frame: "
                f"GPU process {med(r['gpu_ms'] for r in rs):5.0f} ms, renderer {med(r['renderer_ms'] for r in rs):5.0f} "
                f"ms; {med(r['draws'] for r in rs):4.0f} draw calls, {med(r['prims'] for r in rs):8.0f} indices a frame"
            )

    show(f"scene (1000 x 640, dpr 1, MSAA), medians over {args.rounds} rounds of {args.window:g} s:", scene_rows)
    if canvas_rows:
        show("canvas (everything shown), medians over the rounds:", canvas_rows)
    if node_rows:
        show("each node hidden alone (everything else shown):", node_rows)
    full = med(r["interval_ms"] for r in scene_rows["everything shown"])
    empty = med(r["interval_ms"] for r in scene_rows["every node hidden"])
    print(f"ratio: a default frame / an empty canvas's frame {full / empty:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
