"""The limb scene [L18]: Earth, virtual ellipsoid, spacecraft, line of sight, tangent point.

Everything comes from the core: the line of sight from
:func:`geoloc.sensors.limb.line_of_sight_l18` (eq. 1-11), the tangent from
:func:`geoloc.sensors.limb.limb_tangent` (virtual ellipsoid by Newton-Raphson on eq. 17,
eq. 18-26 height, and the exact minimum geodetic height), surfaces from
:func:`geoloc.geodesy.ellipsoid.geodetic_to_ecef`, positions in a local ENU frame
(:mod:`geoloc.frames.enu`) at the foot of the exact tangent. The virtual ellipsoid of
eq. 13 has the WGS-84 flattening and semi-major axis a + Delta a.

What the drawing exaggerates (so that what differs can be seen), display only:

- **Delta a minus the limb height.** The virtual ellipsoid is a *scaled* WGS-84,
  not a shell of constant height: it stands Delta a above the equator but only the
  limb height h_T (metres less) at the tangent latitude. It is drawn at the
  geodetic height ``H_k = H_V + (k - 1) (H_V - h_T - slope)`` above WGS-84
  (:func:`drawn_virtual_height`), where ``H_V`` is its true height above each
  foot point, ``h_T`` its height at the tangent point's foot and ``slope`` the
  first-order (linear in latitude and longitude) part of ``H_V - h_T`` there.
  The departure from a shell is exaggerated k times **about the tangent point**:
  the drawn surface keeps the true one's height and slope at the tangent point,
  so the drawn line of sight (the true one) stays tangent to it there.
- **The tangent-point offset.** The [L18] tangent point T and the exact minimum
  of the geodetic height X are a few tens of metres apart on the line; X is
  drawn at ``T + k_off (X - T)``, on the line, and both markers are sized below
  half the drawn separation (:func:`marker_radius_km`).

A line of sight that meets the Earth (HITS_EARTH) is drawn from the spacecraft
to its ground point ``earth_hit_ecef`` only, with a marker there.

Scene nodes (under ``/limb``, world unit km like the geolocation scene):
``earth``, ``earth_section``, ``virtual``, ``virtual_section``, ``nr/iterate_<k>``,
``spacecraft`` (+ ``label``), ``velocity``, ``los``, ``tangent`` (+ ``label``),
``exact`` (+ ``label``), ``earth_hit`` (+ ``label``, when the line meets the Earth).

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import viser

from geoloc.assets import ASSETS
from geoloc.frames.enu import EnuFrame
from geoloc.geodesy.ellipsoid import (
    E2,
    A,
    F,
    ecef_to_geodetic,
    geodetic_to_ecef,
    prime_vertical_radius,
)
from geoloc.sensors.limb import limb_tangent, line_of_sight_l18
from geoloc.status import Status, describe
from geoloc.userfiles import write_bytes, write_text
from geoloc_viz.palette import LIMB
from geoloc_viz.scene_geoloc import WORLD_SCALE, earth_patch
from geoloc.workflows.scenario import load_scenario

if TYPE_CHECKING:
    from geoloc.corrections.refraction import LimbRefraction

DEFAULT_LIMB = ("scenarios", "tiangong2_limb.toml")
#: Default exaggerations: the virtual ellipsoid's departure from a shell at the limb height
#: (metres over thousands of km), and the tangent-point offset (tens of metres at 2000 km).
SHAPE_EXAGGERATION = 1000.0
OFFSET_EXAGGERATION = 600.0
#: The scene origin follows the foot of what the view is about once it is this far away [deg].
RECENTRE_DEG = 5.0
#: Camera near and far planes [km, scene units]: the nearest geometry is hundreds of km from
#: the eye, the far side of the 30 x 30 deg Earth patch a few thousand.
CAMERA_NEAR_KM, CAMERA_FAR_KM = 1.0, 2.0e4
#: Least height of the camera above WGS-84, as a share of the spacecraft's distance to what it
#: frames (:meth:`LimbApp.camera_pose`).
CAMERA_CLEARANCE = 0.1
#: Marker radii [km] when nothing forces them smaller, and their share of a separation.
MARKER_KM = {"tangent": 12.0, "exact": 9.0}
#: The refracted tangent point's marker [km] and colour (:data:`geoloc_viz.palette.LIMB`).
REFRACTED_MARKER_KM = 6.0
REFRACTED_COLOR = LIMB["refracted"].rgb
MARKER_SHARE = 0.4


def virtual_height(lat, lon, delta_a):
    """Geodetic height above WGS-84 [m] of the eq. 13 virtual ellipsoid (a + Delta a, the WGS-84
    flattening) along the normal of each foot point (lat, lon) [rad]: a closed-form quadratic.

    The point ``((N + h) cos(lat) cos(lon), (N + h) cos(lat) sin(lon), (N (1 - e^2) + h) sin(lat))``
    lies on ``(x^2 + y^2) / a1^2 + z^2 / b1^2 = 1`` with ``a1 = a + Delta a``, ``b1 = (1 - f) a1``.
    """
    lat = np.asarray(lat, float)
    n = prime_vertical_radius(lat)
    a2 = (A + delta_a) ** 2
    b2 = ((1.0 - F) * (A + delta_a)) ** 2
    c2, s2 = np.cos(lat) ** 2, np.sin(lat) ** 2
    al = c2 / a2 + s2 / b2
    be = 2.0 * n * (c2 / a2 + (1.0 - E2) * s2 / b2)
    ga = n**2 * (c2 / a2 + (1.0 - E2) ** 2 * s2 / b2) - 1.0
    return (-be + np.sqrt(be**2 - 4.0 * al * ga)) / (2.0 * al) + 0.0 * np.asarray(lon, float)


def drawn_virtual_height(lat, lon, delta_a, lat_t, lon_t, k):
    """Drawn height [m] of the virtual ellipsoid above WGS-84: its departure from a shell at the
    tangent point's height exaggerated ``k`` times about the tangent point's foot (lat_t, lon_t).

    ``H_k = H_V + (k - 1) (H_V - h_T - dH/dlat dlat - dH/dlon dlon)``: equal to the true
    height ``H_V`` with the same slope at the tangent point (so a line tangent to the
    virtual ellipsoid there is tangent to the drawing), ``H_V`` itself for k = 1.
    """
    d = 1e-5  # rad (64 m): central differences of a smooth height; error ~ d^2 x third derivative, ~1e-12 m/rad
    h_t = virtual_height(lat_t, lon_t, delta_a)
    g_lat = (virtual_height(lat_t + d, lon_t, delta_a) - virtual_height(lat_t - d, lon_t, delta_a)) / (2 * d)
    g_lon = (virtual_height(lat_t, lon_t + d, delta_a) - virtual_height(lat_t, lon_t - d, delta_a)) / (2 * d)
    dlon = (np.asarray(lon, float) - lon_t + np.pi) % (2 * np.pi) - np.pi
    h_v = virtual_height(lat, lon, delta_a)
    lin = g_lat * (np.asarray(lat, float) - lat_t) + g_lon * dlon
    return h_v + (k - 1.0) * (h_v - h_t - lin)


def central_angle_deg(lat1, lon1, lat2, lon2) -> float:
    """Angle [deg] between two directions given by latitude and longitude [rad] (spherical)."""
    c = np.sin(lat1) * np.sin(lat2) + np.cos(lat1) * np.cos(lat2) * np.cos(lon2 - lon1)
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))


def marker_radius_km(kind: str, separation_km: float) -> float:
    """A marker's radius [km]: its default, but below half the drawn separation it must show."""
    return float(min(MARKER_KM[kind], MARKER_SHARE * separation_km))


def load_limb(path=None):
    """The limb scenario at ``path`` (default: the bundled TianGong-2-like one)."""
    return load_scenario(path or Path(ASSETS).joinpath(*DEFAULT_LIMB), expect="limb")


class LimbApp:
    """The limb scene with its GUI (frame, view angle alpha, Delta a exaggeration).

    ``server`` is a viser server (one state shared by every tab, and the export's), or a
    tab's ``ClientHandle`` (its own scene, GUI and camera: :class:`LimbViewer`).
    """

    #: The scene's ENU frame: set by the first :meth:`compute`, moved when the view's foot leaves it
    enu: EnuFrame

    def __init__(self, server: viser.ViserServer, scenario, refraction: bool = False):
        self.server, self.scn = server, scenario
        self.frame = 0
        self.alpha_deg = 0.0
        self.exaggeration = SHAPE_EXAGGERATION
        self.offset_exaggeration = OFFSET_EXAGGERATION
        #: atmospheric refraction (``geoloc view --refraction standard``, the "refraction" box): the
        #: refracted tangent point beside the straight line's (what refraction moves)
        self.refraction = bool(refraction)
        self.lref: LimbRefraction | None = None
        self.last_update_s = float("nan")
        gui = server.gui
        self.md = gui.add_markdown("")
        with gui.add_folder("Limb viewing [L18]"):
            half = max(np.rad2deg(scenario.fov) / 2.0 * 3.0, 1.0)
            self.sl_alpha = gui.add_slider("view angle alpha (deg)", -half, half, 0.01, 0.0)
            self.sl_frame = gui.add_slider("frame", 0, max(scenario.n_frames - 1, 1), 1, 0)
            self.sl_exag = gui.add_slider(
                "Delta a - limb height exaggeration",
                1.0,
                5000.0,
                1.0,
                SHAPE_EXAGGERATION,
                hint="The virtual ellipsoid's departure from a shell at the limb height, drawn this many "
                "times larger about the tangent point (the line stays tangent)",
            )
            self.sl_off = gui.add_slider(
                "tangent offset exaggeration",
                1.0,
                2000.0,
                1.0,
                OFFSET_EXAGGERATION,
                hint="The exact minimum is drawn this many times farther from the [L18] tangent point, on the line",
            )
            self.dd_refraction = gui.add_dropdown(
                "refraction",
                ("none", "standard"),
                initial_value="standard" if self.refraction else "none",
                hint="standard: the ray bent through the U.S. Standard Atmosphere 1976; its tangent point "
                "(lime) is drawn beside the straight line's",
            )
            self.dd_refraction.on_update(lambda _: self._on_gui())
            self.cb_follow = gui.add_checkbox(
                "camera follows the view angle",
                True,
                hint="Re-frame the spacecraft and the tangent point when "
                "alpha or the frame changes (they move by hundreds of km)",
            )
            for h in (self.sl_alpha, self.sl_frame, self.sl_exag, self.sl_off):
                h.on_update(lambda _: self._on_gui())
        with gui.add_folder("Legend"):
            self.md_legend = gui.add_markdown("")
        self.compute()
        self.draw(reset_camera=True)
        # labels kept apart on this tab's screen (overlapping ones cannot be read): after each redraw and camera move
        from geoloc_viz.label_layout import LabelLayout

        client = server if not hasattr(server, "get_clients") else None

        def camera():
            if client is not None:
                return client.camera
            tabs = list(server.get_clients().values())
            return tabs[0].camera if tabs else None

        self.labels = LabelLayout(server.scene, camera)
        if client is not None:
            client.camera.on_update(lambda _c: self.labels.schedule())
        self.labels.schedule(0.05)

    # ------------------------------------------------------------ core
    def compute(self) -> None:
        s = self.scn
        p, v = s.state_ecef(np.array([s.times()[min(self.frame, s.n_frames - 1)]]))
        self.p, self.v = p[0], v[0]
        self.chain = line_of_sight_l18(
            self.p, self.v, s.yaw, s.roll, s.pitch, s.theta_mount, np.deg2rad(self.alpha_deg)
        )
        self.tan = limb_tangent(self.chain.origin_ecef, self.chain.direction_ecef)
        ok = int(self.tan.status) == 0
        self.lref = None
        if self.refraction and ok:
            from geoloc.corrections.refraction import STANDARD_REFRACTION

            lr = STANDARD_REFRACTION.limb(self.chain.origin_ecef, self.chain.direction_ecef)
            self.lref = lr if int(np.asarray(lr.status).reshape(-1)[0]) == Status.OK else None
        hit = int(self.tan.status) == int(Status.HITS_EARTH)
        # What the view is about: the exact tangent, else the line down to where it meets the
        # Earth (the middle of it), else the spacecraft; the Earth patch is drawn around its foot (a patch fixed at
        # frame 0's tangent was out of sight ~95 deg of orbit later, at frame 600).
        foot = (
            self.tan.exact_ecef
            if ok
            else 0.5 * (self.p + self.tan.earth_hit_ecef)
            if hit  # the whole
            else self.p
        )  # line's ground
        lat, lon, _ = ecef_to_geodetic(foot)
        self.focus_latlon = (float(lat), float(lon))
        # The scene origin: on the ellipsoid below that foot, moved only when the foot is more
        # than RECENTRE_DEG away (a nudge of alpha keeps the scene where it is).
        if not hasattr(self, "enu") or central_angle_deg(self.enu.lat0, self.enu.lon0, lat, lon) > RECENTRE_DEG:
            self.enu = EnuFrame(float(lat), float(lon), 0.0)
        # Ground track of the line of sight on WGS-84 (h = 0 below each of its points), sampled
        # every 0.5 km within 50 km of the tangent point (where tangency is seen), coarser elsewhere.
        if ok:
            s_end = 2.0 * float(self.tan.exact_s)
            st = float(self.tan.s)
            ss = np.union1d(np.linspace(0.0, s_end, 121), np.clip(st + np.arange(-50e3, 50e3 + 1, 500.0), 0, s_end))
        elif hit:
            s_end = float(np.linalg.norm(self.tan.earth_hit_ecef - self.chain.origin_ecef))
            ss = np.linspace(0.0, s_end, 121)
        else:
            s_end = 3.0e6
            ss = np.linspace(0.0, s_end, 121)
        self.section_s = ss
        pts = self.chain.origin_ecef + ss[:, None] * self.chain.direction_ecef
        la, lo, _ = ecef_to_geodetic(pts)
        self.section_geodetic = (la, lo)
        self.section_ecef = geodetic_to_ecef(la, lo, np.zeros_like(la))
        # A line that meets the Earth stops there: drawn through the planet it would show a view no one has.
        self.los_ecef = np.stack([pts[0], self.tan.earth_hit_ecef if hit else pts[-1]])

    # ------------------------------------------------------------ drawing
    def w(self, p_ecef) -> np.ndarray:
        """ECEF [m] -> scene (ENU, km)."""
        return self.enu.from_ecef(p_ecef) * WORLD_SCALE

    def _virtual(self, p_ecef, delta_a):
        # eq. 13: same flattening, a + Delta a: the WGS-84 surface scaled about the centre (true size).
        return np.asarray(p_ecef) * ((A + delta_a) / A)

    def drawn_virtual(self, lat, lon) -> np.ndarray:
        """ECEF [m] of the drawn (exaggerated about the tangent point) virtual ellipsoid above
        the foot points (lat, lon) [rad]; see :func:`drawn_virtual_height`."""
        t = self.tan
        lat_t, lon_t, _ = ecef_to_geodetic(t.tangent_ecef)
        h = drawn_virtual_height(lat, lon, float(t.delta_a), float(lat_t), float(lon_t), self.exaggeration)
        return geodetic_to_ecef(lat, lon, h)

    def drawn_exact_ecef(self) -> np.ndarray:
        """Where the exact minimum is drawn: ``T + k_off (X - T)``, on the line of sight."""
        t = self.tan
        return t.tangent_ecef + self.offset_exaggeration * (t.exact_ecef - t.tangent_ecef)

    def marker_radii_km(self) -> dict:
        """Radii of the tangent and exact-minimum markers [km], below half their drawn separation."""
        sep_km = float(np.linalg.norm(self.drawn_exact_ecef() - self.tan.tangent_ecef)) * WORLD_SCALE
        return {k: marker_radius_km(k, sep_km) for k in MARKER_KM}

    def draw(self, reset_camera: bool = False) -> None:
        """Draw the whole scene in one atomic update: the Earth patch, the virtual ellipsoid and
        its Newton iterates (with a tangent), the spacecraft and its line of sight, the markers
        (or where the line meets the Earth); then the text, the legend and, with
        ``reset_camera``, the camera. ``last_update_s`` is the time it took [s]."""
        t0 = time.perf_counter()
        ok = int(self.tan.status) == 0
        with self.server.atomic():
            self.server.scene.add_frame("/limb", show_axes=False)
            LA, LO, faces = self._draw_earth()
            if ok:
                self._draw_virtual(LA, LO, faces)
            self._draw_spacecraft()
            if ok:
                self._draw_tangents()
            else:
                self._draw_no_tangent()
        self._text()
        self.md_legend.content = self.legend_markdown(ok)
        if reset_camera:
            self._reset_camera()
        self.last_update_s = time.perf_counter() - t0

    def _draw_earth(self):
        """The Earth patch around the foot of what the view is about (30 x 30 deg of WGS-84 at
        h = 0) and the Earth's section; returns the patch's grid (lat, lon [rad]) and faces."""
        lat0, lon0 = np.rad2deg(self.focus_latlon)
        LA, LO, earth, faces = earth_patch(lat0, lon0, 15.0, 61)
        self.server.scene.add_mesh_simple(
            "/limb/earth",
            self.w(earth.reshape(-1, 3)).astype(np.float32),
            faces,
            color=LIMB["earth"].rgb,
            side="double",
            cast_shadow=False,
            receive_shadow=False,
        )
        self._polyline("/limb/earth_section", self.w(self.section_ecef), LIMB["earth_section"].rgb, 2.0)
        return LA, LO, faces

    def _draw_virtual(self, LA, LO, faces) -> None:
        """The drawn virtual ellipsoid over the Earth patch's grid, its section, and the section
        at each Newton iterate of its semi-axis change (a ramp from first to last)."""
        sc, tan = self.server.scene, self.tan
        virt = self.drawn_virtual(LA.reshape(-1), LO.reshape(-1))
        sc.add_mesh_simple(
            "/limb/virtual",
            self.w(virt).astype(np.float32),
            faces,
            color=LIMB["virtual"].rgb,
            opacity=0.25,
            side="double",
            cast_shadow=False,
            receive_shadow=False,
        )
        self._polyline(
            "/limb/virtual_section",
            self.w(self.drawn_virtual(*self.section_geodetic)),
            LIMB["virtual"].rgb,
            3.0,
        )
        hist = np.asarray(tan.nr_delta_a_history).reshape(-1)
        hist = hist[np.isfinite(hist)]
        sc.remove_by_name("/limb/nr")
        g0, g1 = LIMB["nr_first"].rgb[0], LIMB["nr_last"].rgb[0]  # a ramp (g, g, 255 - g // 2)
        for k, dk in enumerate(hist[:-1]):
            g = int(g0 + (g1 - g0) * k / max(len(hist) - 1, 1))
            self._polyline(
                f"/limb/nr/iterate_{k}", self.w(self._virtual(self.section_ecef, dk)), (g, g, 255 - g // 2), 1.5
            )

    def _draw_spacecraft(self) -> None:
        """The spacecraft, its velocity (60 s of flight) and the line of sight."""
        sc = self.server.scene
        sp = self.w(self.p)
        sc.add_icosphere(
            "/limb/spacecraft",
            radius=25.0,
            color=LIMB["spacecraft"].rgb,
            position=sp,
            cast_shadow=False,
            receive_shadow=False,
        )
        sc.add_label(
            "/limb/spacecraft/label", f"spacecraft, {np.linalg.norm(self.v) / 1e3:.2f} km/s", anchor="bottom-left"
        )
        vel = np.stack([sp, self.w(self.p + 60.0 * self.v)])[None]
        sc.add_arrows(
            "/limb/velocity",
            vel.astype(np.float32),
            LIMB["spacecraft"].rgb,
            shaft_radius=6.0,
            head_radius=15.0,
            head_length=40.0,
        )
        self._polyline("/limb/los", self.w(self.los_ecef), LIMB["los"].rgb, 3.0)

    def _draw_tangents(self) -> None:
        """The [L18] tangent point and the exact minimum (drawn offset), labelled with their
        heights, and with refraction the refracted tangent; no Earth hit."""
        sc, tan = self.server.scene, self.tan
        r = self.marker_radii_km()
        off_m = float(np.linalg.norm(tan.exact_ecef - tan.tangent_ecef))
        sc.add_icosphere(
            "/limb/tangent",
            radius=r["tangent"],
            color=LIMB["tangent"].rgb,
            position=self.w(tan.tangent_ecef),
            cast_shadow=False,
            receive_shadow=False,
        )
        sc.add_label(
            "/limb/tangent/label",
            f"[L18] tangent: h = {float(tan.tangent_h) / 1e3:.3f} km",
            anchor="bottom-left",
        )
        sc.add_icosphere(
            "/limb/exact",
            radius=r["exact"],
            color=LIMB["exact"].rgb,
            position=self.w(self.drawn_exact_ecef()),
            cast_shadow=False,
            receive_shadow=False,
        )
        sc.add_label(
            "/limb/exact/label",
            f"exact minimum: h = {float(tan.exact_h) / 1e3:.3f} km, {off_m:.1f} m along the "
            f"line from the tangent (drawn x{self.offset_exaggeration:g})",
            anchor="top-left",
        )
        sc.remove_by_name("/limb/earth_hit")
        if self.lref is not None:
            self._draw_refracted(self.lref)
        else:
            sc.remove_by_name("/limb/refracted")

    def _draw_refracted(self, lr: LimbRefraction) -> None:
        """The refracted tangent point of the limb refraction ``lr``, labelled with its height and
        how much lower it is than the straight line's."""
        sc = self.server.scene
        drop = float(np.asarray(lr.tangent_h_m).reshape(-1)[0] - np.asarray(lr.refracted_tangent_h_m).reshape(-1)[0])
        sc.add_icosphere(
            "/limb/refracted",
            radius=REFRACTED_MARKER_KM,
            color=REFRACTED_COLOR,
            position=self.w(np.asarray(lr.refracted_tangent_ecef).reshape(3)),
            cast_shadow=False,
            receive_shadow=False,
        )
        sc.add_label(
            "/limb/refracted/label",
            f"refracted tangent: h = {self.refracted_h_m() / 1e3:.3f} km ({drop:.0f} m lower)",
            anchor="top-right",
        )

    def _draw_no_tangent(self) -> None:
        """No tangent: the tangent's drawings removed, and where the line of sight meets the
        Earth marked when it does."""
        sc, tan = self.server.scene, self.tan
        sc.remove_by_name("/limb/refracted")
        for n in ("tangent", "exact", "virtual", "virtual_section", "nr"):
            sc.remove_by_name(f"/limb/{n}")
        if int(tan.status) != int(Status.HITS_EARTH):
            sc.remove_by_name("/limb/earth_hit")
            return
        sc.add_icosphere(
            "/limb/earth_hit",
            radius=12.0,
            color=LIMB["earth_hit"].rgb,
            position=self.w(tan.earth_hit_ecef),
            cast_shadow=False,
            receive_shadow=False,
        )
        sc.add_label(
            "/limb/earth_hit/label",
            "the line of sight meets the Earth here: no tangent",
            anchor="bottom-left",
        )

    def _reset_camera(self) -> None:
        """The camera at :meth:`camera_pose`: on the server every new tab's and every open tab's,
        on one tab (a viser ClientHandle) its own."""
        pos, aim, up = self.camera_pose()
        if hasattr(self.server, "initial_camera"):  # the server: every new tab's camera
            cam = self.server.initial_camera
            cam.up = tuple(up)
            cam.near, cam.far = CAMERA_NEAR_KM, CAMERA_FAR_KM
            cam.position, cam.look_at = tuple(pos), tuple(aim)
            for c in list(self.server.get_clients().values()):  # and every open tab's
                try:
                    with c.atomic():
                        c.camera.up_direction = tuple(up)
                        c.camera.position = tuple(pos)
                        c.camera.look_at = tuple(aim)
                except Exception:  # a tab that left
                    pass
        else:  # one tab (a viser ClientHandle): its own camera (position first: viser moves look_at)
            cam = self.server.camera
            cam.up_direction = tuple(up)
            cam.near, cam.far = CAMERA_NEAR_KM, CAMERA_FAR_KM
            cam.position = tuple(pos)
            cam.look_at = tuple(aim)

    def camera_pose(self):
        """Where the camera frames this frame's geometry: (position, look-at, up), scene km.

        A side view of the line of sight from above the Earth, the spacecraft at the left edge
        and the point of interest left of the middle (the GUI panel covers the right third): the
        exact tangent, else the line's ground point when it meets the Earth, else the point
        2000 km along the line. The camera stands 1.1 L to the side of the line and 0.25 L
        above it (L: spacecraft to the point of interest), the side and "above" taken from the
        local vertical there, and is lifted until it is at least ``CAMERA_CLEARANCE`` L above
        WGS-84: an eye inside the Earth mesh (double-sided) sees one blue wall.
        """
        tan = self.tan
        ok = int(tan.status) == 0
        hit = int(tan.status) == int(Status.HITS_EARTH)
        sp_e = np.asarray(self.p, float)
        if ok:
            tp_e = np.asarray(tan.exact_ecef, float)
        elif hit:
            tp_e = np.asarray(tan.earth_hit_ecef, float)
        else:
            tp_e = sp_e + 2.0e6 * np.asarray(self.chain.direction_ecef, float)
        aim_e = sp_e + 1.23 * (tp_e - sp_e)  # the point of interest left of the middle
        L = float(np.linalg.norm(tp_e - sp_e))  # m
        la, lo, _ = ecef_to_geodetic(aim_e)
        up_e = geodetic_to_ecef(la, lo, 1.0) - geodetic_to_ecef(la, lo, 0.0)  # the local vertical at aim
        up_e /= np.linalg.norm(up_e)
        side_e = np.cross(tp_e - sp_e, up_e)
        if np.linalg.norm(side_e) < 1e-6 * max(L, 1.0):  # a vertical line: any horizontal side
            side_e = np.cross([0.0, 0.0, 1.0], up_e) if abs(up_e[2]) < 0.9 else np.cross([1.0, 0.0, 0.0], up_e)
        side_e /= np.linalg.norm(side_e)
        pos_e = aim_e + 1.1 * L * side_e + 0.25 * L * up_e
        for _ in range(40):
            if float(ecef_to_geodetic(pos_e)[2]) >= CAMERA_CLEARANCE * L:
                break
            pos_e = pos_e + 0.25 * L * up_e
        up = self.enu.vector_from_ecef(up_e)
        return self.w(pos_e), self.w(aim_e), up / np.linalg.norm(up)

    def refracted_h_m(self) -> float:
        """The refracted tangent point's geodetic height [m, WGS 84 ellipsoid]; NaN without refraction."""
        if self.lref is None:
            return float("nan")
        return float(np.asarray(self.lref.refracted_tangent_h_m).reshape(-1)[0])

    def legend_markdown(self, ok: bool) -> str:
        """The legend of what this frame draws (the colours of :meth:`draw`, named by the colour table
        :data:`geoloc_viz.palette.LIMB`), one line each."""

        def n(key: str) -> str:
            return LIMB[key].name

        rows = [
            (
                n("earth"),
                f"the Earth: WGS-84 ellipsoid, h = 0 (a 30 x 30 deg patch); {n('earth_section')} line: its "
                "section under the line of sight",
            )
        ]
        if ok:
            rows += [
                (
                    f"{n('virtual')}, translucent",
                    f"the virtual ellipsoid of [L18] eq. 13 (same flattening, a + Delta a; "
                    f"its departure from a shell drawn x{self.exaggeration:g}); {n('virtual')} line: its section",
                ),
                (
                    f"{n('nr_first')} to {n('nr_last')} lines",
                    "the Newton-Raphson iterates of eq. 17 (their virtual ellipsoids' "
                    "sections), converging onto the tangent one",
                ),
            ]
        rows += [
            (f"{n('spacecraft')} ball and arrow", "the spacecraft and 60 s of its velocity"),
            (n("los"), "the line of sight"),
        ]
        if ok:
            rows += [
                (f"{n('tangent')} ball", "the [L18] tangent point (eq. 21-26)"),
                (
                    f"{n('exact')} ball",
                    f"the exact minimum-height point (drawn x{self.offset_exaggeration:g} farther along the line)",
                ),
            ]
            if self.lref is not None:
                rows.append(
                    (
                        f"{n('refracted')} ball",
                        "the refracted tangent point: the lowest point of the ray bent through "
                        "the U.S. Standard Atmosphere 1976 (true position)",
                    )
                )
        elif int(self.tan.status) == int(Status.HITS_EARTH):
            rows.append((f"{n('earth_hit')} ball", "where the line of sight meets the Earth (no tangent)"))
        return "\n".join(f"- **{c}**: {w}" for c, w in rows) + "\n\nscene: local ENU at the exact tangent's foot, km"

    def _polyline(self, name, pts, color, thickness):
        pts = np.asarray(pts, np.float32)
        seg = np.stack([pts[:-1], pts[1:]], axis=1)
        self.server.scene.add_line_segments(name, seg, color, thickness=thickness, thickness_units="screen")

    def _text(self) -> None:
        t = self.tan
        lines = [
            f"**{self.scn.name}**  ",
            f"frame {self.frame}, alpha {self.alpha_deg:+.2f} deg; scene: local ENU at the exact tangent's foot, km  ",
        ]
        if int(t.status) == 0:
            da, ht = float(t.delta_a), float(t.tangent_h_geodetic)
            off_m = float(np.linalg.norm(t.exact_ecef - t.tangent_ecef))
            lines += [
                f"virtual ellipsoid Delta a = {da / 1e3:.3f} km after "
                f"{int(t.nr_iterations)} Newton-Raphson steps (eq. 17)  ",
                f"Delta a - limb height = {da - ht:.2f} m: the virtual ellipsoid is a scaled WGS-84, "
                f"not a shell; its departure from a shell at the limb height is drawn "
                f"x{self.exaggeration:g} about the tangent point (tangency kept)  ",
                f"exact minimum {off_m:.1f} m along the line from the [L18] tangent point, "
                f"drawn x{self.offset_exaggeration:g}  ",
                f"[L18] limb height {float(t.tangent_h) / 1e3:.3f} km, exact minimum "
                f"{float(t.exact_h) / 1e3:.3f} km, difference {float(t.h_difference):+.2e} m  ",
                "Newton-Raphson Delta a iterates (km): "
                + ", ".join(f"{x / 1e3:.3f}" for x in np.asarray(t.nr_delta_a_history).reshape(-1) if np.isfinite(x)),
            ]
            if self.lref is not None:
                lr = self.lref
                h0 = float(np.asarray(lr.tangent_h_m).reshape(-1)[0])
                hr = self.refracted_h_m()
                lines += [
                    "  ",
                    f"refraction (U.S. Standard Atmosphere 1976): refracted tangent "
                    f"**h = {hr:.1f} m** (WGS 84 ellipsoid), straight line's {h0:.1f} m: "
                    f"{h0 - hr:.1f} m lower; bending "
                    f"{float(np.asarray(lr.bending_rad).reshape(-1)[0]) * 1e3:.3f} mrad  ",
                ]
            elif self.refraction:
                lines.append("refraction: the bent ray has no tangent point here (it meets the Earth or ducts)  ")
        else:
            lines.append(f"no tangent: {describe(int(t.status))}")
        self.md.content = "\n".join(lines)

    def _on_gui(self) -> None:
        moved = (float(self.sl_alpha.value), int(self.sl_frame.value)) != (self.alpha_deg, self.frame)
        self.alpha_deg = float(self.sl_alpha.value)
        self.frame = int(self.sl_frame.value)
        self.exaggeration = float(self.sl_exag.value)
        self.offset_exaggeration = float(self.sl_off.value)
        self.refraction = str(self.dd_refraction.value) == "standard"
        self.compute()
        self.draw(reset_camera=moved and bool(self.cb_follow.value))
        self.labels.schedule(0.05)

    def export(self, path) -> Path:
        """Write the scene as ``.viser`` or self-contained ``.html`` (see GeolocApp.export)."""
        path = Path(path)
        ser = self.server.get_scene_serializer()
        if path.suffix.lower() == ".html":
            from geoloc_viz.export_html import with_summary

            write_text(
                path,
                with_summary(
                    ser.as_html(dark_mode=True),
                    "geoloc view: limb",
                    self.md.content,
                    "Static export of geoloc view --scenario limb (no controls).",
                ),
            )
        else:
            write_bytes(path, ser.serialize())
        return path


class LimbViewer:
    """What ``geoloc view --scenario limb`` serves: one :class:`LimbApp` per browser tab.

    Each tab gets its own scene, GUI and camera (its frame, view angle and exaggerations
    are its own), built on connect and dropped on disconnect, as the flight scene's
    sessions (:class:`geoloc_viz.app.GeolocViewer`).
    """

    def __init__(self, server: viser.ViserServer, scenario, refraction: bool = False):
        import threading

        self.server, self.scn = server, scenario
        self.refraction = refraction
        self.apps: dict[int, LimbApp] = {}
        self._lock = threading.Lock()
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    def _on_connect(self, client) -> None:
        with self._lock:
            app = LimbApp(client, self.scn, self.refraction)
            if client.client_id in self.server.get_clients():
                self.apps[client.client_id] = app

    def _on_disconnect(self, client) -> None:
        with self._lock:
            self.apps.pop(client.client_id, None)
