"""The limb scene [L18]: Earth, virtual ellipsoid, spacecraft, line of sight, tangent point.

Everything comes from the core: the line of sight from
:func:`geoloc.sensors.limb.line_of_sight_l18` (eq. 1-11), the tangent from
:func:`geoloc.sensors.limb.limb_tangent` (virtual ellipsoid by Newton-Raphson on eq. 17,
eq. 18-26 height, and the exact minimum geodetic height), surfaces from
:func:`geoloc.geodesy.ellipsoid.geodetic_to_ecef`, positions in a local ENU frame
(:mod:`geoloc.frames.enu`) at the foot of the exact tangent. The virtual ellipsoid of
eq. 13 has the WGS-84 flattening and semi-major axis a + Delta a, so it is the
WGS-84 ellipsoid scaled about the Earth's centre by (a + Delta a) / a: that is
how its surface is drawn (with a display exaggeration of Delta a).

Scene nodes (under ``/limb``, world unit km like the geolocation scene):
``earth``, ``earth_section``, ``virtual``, ``virtual_section``, ``nr/iterate_<k>``,
``spacecraft`` (+ ``label``), ``velocity``, ``los``, ``tangent`` (+ ``label``),
``exact`` (+ ``label``).

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import viser

from geoloc.assets import ASSETS
from geoloc.frames.enu import EnuFrame
from geoloc.geodesy.ellipsoid import A, ecef_to_geodetic, geodetic_to_ecef
from geoloc.sensors.limb import limb_tangent, line_of_sight_l18
from geoloc.status import describe
from geoloc.viz.scene_geoloc import WORLD_SCALE
from geoloc.workflows.limb_scenario import load_scenario

DEFAULT_LIMB = ("scenarios", "tiangong2_limb.toml")


def load_limb(path=None):
    """The limb scenario at ``path`` (default: the bundled TianGong-2-like one)."""
    return load_scenario(path or Path(ASSETS).joinpath(*DEFAULT_LIMB))


class LimbApp:
    """The limb scene with its GUI (frame, view angle alpha, Delta a exaggeration)."""

    def __init__(self, server: viser.ViserServer, scenario):
        self.server, self.scn = server, scenario
        self.frame = 0
        self.alpha_deg = 0.0
        self.exaggeration = 1.0
        self.last_update_s = float("nan")
        gui = server.gui
        self.md = gui.add_markdown("")
        with gui.add_folder("Limb viewing [L18]"):
            half = max(np.rad2deg(scenario.fov) / 2.0 * 3.0, 1.0)
            self.sl_alpha = gui.add_slider("view angle alpha (deg)", -half, half, 0.01, 0.0)
            self.sl_frame = gui.add_slider("frame", 0, max(scenario.n_frames - 1, 1), 1, 0)
            self.sl_exag = gui.add_slider("Delta a exaggeration", 1.0, 20.0, 0.5, 1.0)
            for h in (self.sl_alpha, self.sl_frame, self.sl_exag):
                h.on_update(lambda _: self._on_gui())
        self.compute()
        self.draw(reset_camera=True)

    # ------------------------------------------------------------ core
    def compute(self) -> None:
        s = self.scn
        p, v = s.state_ecef(np.array([s.times()[min(self.frame, s.n_frames - 1)]]))
        self.p, self.v = p[0], v[0]
        self.chain = line_of_sight_l18(self.p, self.v, s.yaw, s.roll, s.pitch, s.theta_mount,
                                       np.deg2rad(self.alpha_deg))
        self.tan = limb_tangent(self.chain.origin_ecef, self.chain.direction_ecef)
        ok = int(self.tan.status) == 0
        foot = self.tan.exact_ecef if ok else self.p
        lat, lon, _ = ecef_to_geodetic(foot)
        # The scene origin: on the ellipsoid below the exact tangent (or below the spacecraft).
        if not hasattr(self, "enu") or not ok:
            self.enu = EnuFrame(float(lat), float(lon), 0.0)
        # Ground track of the line of sight on WGS-84 (h = 0 below each of its points).
        s_end = 2.0 * float(self.tan.exact_s) if ok else 3.0e6
        ss = np.linspace(0.0, s_end, 121)
        pts = self.chain.origin_ecef + ss[:, None] * self.chain.direction_ecef
        la, lo, _ = ecef_to_geodetic(pts)
        self.section_ecef = geodetic_to_ecef(la, lo, np.zeros_like(la))
        self.los_ecef = pts[[0, -1]]

    # ------------------------------------------------------------ drawing
    def w(self, p_ecef) -> np.ndarray:
        """ECEF [m] -> scene (ENU, km)."""
        return self.enu.from_ecef(p_ecef) * WORLD_SCALE

    def _virtual(self, p_ecef, delta_a):
        # eq. 13: same flattening, a + Delta a: the WGS-84 surface scaled about the centre.
        return np.asarray(p_ecef) * ((A + self.exaggeration * delta_a) / A)

    def draw(self, reset_camera: bool = False) -> None:
        t0 = time.perf_counter()
        sc, tan = self.server.scene, self.tan
        ok = int(tan.status) == 0
        with self.server.atomic():
            sc.add_frame("/limb", show_axes=False)
            # Earth patch around the scene origin: 30 x 30 deg of WGS-84 at h = 0.
            lat0, lon0 = np.rad2deg(self.enu.lat0), np.rad2deg(self.enu.lon0)
            la = np.deg2rad(np.clip(np.linspace(lat0 - 15, lat0 + 15, 61), -89.9, 89.9))
            lo = np.deg2rad(np.linspace(lon0 - 15, lon0 + 15, 61))
            LO, LA = np.meshgrid(lo, la)
            earth = geodetic_to_ecef(LA, LO, np.zeros_like(LA))
            idx = np.arange(LA.size).reshape(LA.shape)
            faces = np.concatenate([
                np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
            sc.add_mesh_simple("/limb/earth", self.w(earth.reshape(-1, 3)).astype(np.float32), faces,
                               color=(40, 90, 170), side="double", cast_shadow=False, receive_shadow=False)
            self._polyline("/limb/earth_section", self.w(self.section_ecef), (120, 170, 255), 2.0)
            if ok:
                da = float(tan.delta_a)
                virt = self._virtual(earth.reshape(-1, 3), da)
                sc.add_mesh_simple("/limb/virtual", self.w(virt).astype(np.float32), faces,
                                   color=(255, 170, 60), opacity=0.25, side="double",
                                   cast_shadow=False, receive_shadow=False)
                self._polyline("/limb/virtual_section", self.w(self._virtual(self.section_ecef, da)),
                               (255, 170, 60), 3.0)
                hist = np.asarray(tan.nr_delta_a_history).reshape(-1)
                hist = hist[np.isfinite(hist)]
                sc.remove_by_name("/limb/nr")
                for k, dk in enumerate(hist[:-1]):
                    g = int(80 + 150 * k / max(len(hist) - 1, 1))
                    self._polyline(f"/limb/nr/iterate_{k}", self.w(self._virtual(self.section_ecef, dk)),
                                   (g, g, 255 - g // 2), 1.5)
            # Spacecraft, its velocity (60 s of flight), the line of sight.
            sp = self.w(self.p)
            sc.add_icosphere("/limb/spacecraft", radius=25.0, color=(250, 250, 250), position=sp,
                             cast_shadow=False, receive_shadow=False)
            sc.add_label("/limb/spacecraft/label", f"spacecraft, {np.linalg.norm(self.v) / 1e3:.2f} km/s",
                         anchor="bottom-left")
            vel = np.stack([sp, self.w(self.p + 60.0 * self.v)])[None]
            sc.add_arrows("/limb/velocity", vel.astype(np.float32), (255, 255, 255), shaft_radius=6.0,
                          head_radius=15.0, head_length=40.0)
            self._polyline("/limb/los", self.w(self.los_ecef), (255, 210, 0), 3.0)
            if ok:
                sc.add_icosphere("/limb/tangent", radius=12.0, color=(255, 120, 0),
                                 position=self.w(tan.tangent_ecef), cast_shadow=False, receive_shadow=False)
                sc.add_label("/limb/tangent/label",
                             f"[L18] tangent: h = {float(tan.tangent_h) / 1e3:.3f} km", anchor="bottom-left")
                sc.add_icosphere("/limb/exact", radius=9.0, color=(20, 220, 90),
                                 position=self.w(tan.exact_ecef), cast_shadow=False, receive_shadow=False)
                sc.add_label("/limb/exact/label",
                             f"exact minimum: h = {float(tan.exact_h) / 1e3:.3f} km", anchor="top-left")
            else:
                for n in ("tangent", "exact", "virtual", "virtual_section", "nr"):
                    sc.remove_by_name(f"/limb/{n}")
        self._text()
        if reset_camera:
            tp = self.w(tan.exact_ecef) if ok else np.zeros(3)
            L = np.linalg.norm(sp - tp)
            # Side view of the grazing line: spacecraft at the left edge, tangent left of the
            # middle (the GUI panel covers the right third), a little from above.
            aim = sp + 1.23 * (tp - sp)
            side = np.cross(tp - sp, [0.0, 0.0, 1.0])
            side /= max(np.linalg.norm(side), 1e-9)
            cam = self.server.initial_camera
            cam.up = (0.0, 0.0, 1.0)
            cam.near, cam.far = 1.0, 2.0e4
            cam.position = tuple(aim + side * 1.1 * L + np.array([0, 0, 0.25 * L]))
            cam.look_at = tuple(aim)
        self.last_update_s = time.perf_counter() - t0

    def _polyline(self, name, pts, color, thickness):
        pts = np.asarray(pts, np.float32)
        seg = np.stack([pts[:-1], pts[1:]], axis=1)
        self.server.scene.add_line_segments(name, seg, color, thickness=thickness, thickness_units="screen")

    def _text(self) -> None:
        t = self.tan
        lines = [f"**{self.scn.name}**  ",
                 f"frame {self.frame}, alpha {self.alpha_deg:+.2f} deg; scene: local ENU at the exact "
                 f"tangent's foot, km  "]
        if int(t.status) == 0:
            lines += [f"virtual ellipsoid Delta a = {float(t.delta_a) / 1e3:.3f} km after "
                      f"{int(t.nr_iterations)} Newton-Raphson steps (eq. 17); drawn x{self.exaggeration:g}  ",
                      f"[L18] limb height {float(t.tangent_h) / 1e3:.3f} km, exact minimum "
                      f"{float(t.exact_h) / 1e3:.3f} km, difference {float(t.h_difference):+.2e} m  ",
                      "Newton-Raphson Delta a iterates (km): "
                      + ", ".join(f"{x / 1e3:.3f}" for x in np.asarray(t.nr_delta_a_history).reshape(-1)
                                  if np.isfinite(x))]
        else:
            lines.append(f"no tangent: {describe(int(t.status))}")
        self.md.content = "\n".join(lines)

    def _on_gui(self) -> None:
        self.alpha_deg = float(self.sl_alpha.value)
        self.frame = int(self.sl_frame.value)
        self.exaggeration = float(self.sl_exag.value)
        self.compute()
        self.draw()

    def export(self, path) -> Path:
        """Write the scene as ``.viser`` or self-contained ``.html`` (see GeolocApp.export)."""
        path = Path(path)
        ser = self.server.get_scene_serializer()
        if path.suffix.lower() == ".html":
            from geoloc.viz.export_html import with_summary

            path.write_text(with_summary(ser.as_html(dark_mode=True), "geoloc view: limb",
                                         self.md.content,
                                         "Static export of geoloc view --scenario limb (no controls)."))
        else:
            path.write_bytes(ser.serialize())
        return path
