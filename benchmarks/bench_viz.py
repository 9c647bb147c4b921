"""Viewer speed: sending a 1 M-triangle DEM mesh, and slider-to-scene latency.

Run: ``python benchmarks/bench_viz.py [--nodes N] [--updates K]``. Prints medians and a final ``ratio:``
line (vertex-coloured trimesh/GLB path over viser's plain ``add_mesh_simple``
for the same mesh, measured in the same run).

* Mesh: a synthetic 708 x 708-node DEM (1.0 M triangles; ``--nodes N``: N x N) built by
  :meth:`geoloc.surfaces.dem.DEM.from_array` and :meth:`~geoloc.surfaces.dem.DEM.to_trimesh` in
  ENU, coloured by height, sent with ``add_mesh_trimesh`` (the viewer's path:
  GLB export + message queue) on a server with no browser attached: the
  server-side cost. Goal <= 3 s.
* Latency: the default scenario (flight test T3-1 over ETOPO5); a pose slider
  is moved from Python (the same callback a browser triggers) and the time from
  the change to the updated scene (core recompute + node messages) is
  ``GeolocApp.last_update_s``. Goal <= 100 ms. ``--updates K`` (default 21) slider moves
  per method and for the step slider.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def median_time(fn, n):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=708, help="DEM nodes a side (default 708: 1.0 M triangles)")
    ap.add_argument("--updates", type=int, default=21, help="slider moves timed per case (default 21)")
    a = ap.parse_args(argv)
    import matplotlib

    from geoloc.surfaces.dem import DEM
    from geoloc_viz.app import GeolocApp, make_server
    from geoloc_viz.scenario import load_view_scenario

    server = make_server(port=0)
    n = a.nodes  # 2 (n-1)^2 triangles: 999 698 for 708
    y, x = np.mgrid[0:n, 0:n] / (n - 1)
    heights = 1000 + 400 * np.sin(6 * x) * np.cos(5 * y) + 80 * np.sin(40 * x * y)
    dem = DEM.from_array(heights, 36.5, 78.7, 0.3 / (n - 1), 0.3 / (n - 1), datum="ellipsoid")
    mesh = dem.to_trimesh()
    t = (heights.ravel() - heights.min()) / np.ptp(heights)
    mesh.visual.vertex_colors = (matplotlib.colormaps["gist_earth"](0.2 + 0.7 * t) * 255).astype(np.uint8)
    print(f"mesh: {len(mesh.faces):,} triangles, {len(mesh.vertices):,} vertices")
    k = [0]

    def send_trimesh():
        k[0] += 1
        server.scene.add_mesh_trimesh(f"/bench/trimesh{k[0] % 2}", mesh)

    def send_simple():
        k[0] += 1
        server.scene.add_mesh_simple(
            f"/bench/simple{k[0] % 2}",
            mesh.vertices.astype(np.float32),
            mesh.faces.astype(np.uint32),
            color=(120, 160, 90),
        )

    t_tri = median_time(send_trimesh, 3)
    t_simple = median_time(send_simple, 3)
    server.scene.remove_by_name("/bench")
    size = "1 M-triangle" if n == 708 else f"{len(mesh.faces):,}-triangle"
    print(f"send {size} DEM mesh, vertex colours (add_mesh_trimesh): median {t_tri:.3f} s (goal <= 3 s for 1 M)")
    print(f"send {size} DEM mesh, one colour (add_mesh_simple):     median {t_simple:.3f} s")

    app = GeolocApp(server, load_view_scenario())
    for method in ("bisect", "steps", "exact"):
        app.dd_method.value = method
        lat = []
        for i in range(a.updates):
            app.num["gimbal_roll_deg"].value = -45.0 + 0.1 * (i % 5)
            lat.append(app.last_update_s)
        print(
            f"slider -> updated scene, method {method:6s}: median {1e3 * statistics.median(lat):.1f} ms, "
            f"max {1e3 * max(lat):.1f} ms (goal <= 100 ms)"
        )
    lat = []
    for i in range(a.updates):
        app.sl_step.disabled = False
        app.cb_all_steps.value = False
        app.sl_step.value = i % 5
        lat.append(app.last_update_s)
    print(f"step slider -> updated scene (display only): median {1e3 * statistics.median(lat):.1f} ms")
    server.stop()
    print(f"ratio: {t_tri / t_simple:.2f}")


if __name__ == "__main__":
    main()
