"""The Sentinel-2 scene: the orbit, the satellite's attitude frames, a detector's lines of sight
sweeping the ground, the detectors' footprints (``geoloc view --scenario PRODUCT``).

The numbers are the core's: each detector of the band is the product's
:class:`geoloc.sensors.pushbroom_inertial.InertialPushbroomSensor` (``read_product(...).sensor``),
the ground points come from the location pipeline on the ellipsoid (h = 0, light-time and
aberration on, as Rugged's default), the body frame is ``R_ecef_in(t) R_in_body(t)`` of the sensor.
This module lays them out in a local ENU frame (km, the unit of the flight scene) at the ground
of the chosen detector's middle pixel.

Scene nodes (under ``/s2``):

=================================  ===========================================================
``earth``                          WGS-84 at h = 0, a patch of +-3 deg around the scene origin
``orbit``                          the datastrip's GPS points (white)
``attitude/<k>``                   the body (piloting) frame at 9 lines along the datastrip
``satellite``                      the body frame at the chosen line (X red, Y green, Z blue)
``los/first``, ``middle``, ``last``  the chosen line's first, middle and last pixels' lines of sight (yellow)
``swath``                          the chosen line's ground: every detector pixel (orange)
``footprint/D<nn>``                each detector's ground outline over its datastrip
=================================  ===========================================================

Conventions: ``docs/conventions.md``; the model: ``docs/sentinel2.md``.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import viser

from geoloc.frames.enu import EnuFrame
from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.io.sentinel2 import Sentinel2Product, band_info, detector_id, read_product
from geoloc.pipeline import Corrections, Pipeline
from geoloc.sensors.pushbroom_inertial import InertialPushbroomSensor
from geoloc.surfaces.height import HeightSurface
from geoloc_viz.palette import SENTINEL2
from geoloc_viz.scene_geoloc import WORLD_SCALE, earth_patch, wxyz

#: body frames drawn along the datastrip, and the length of their axes [km]
N_ATTITUDE = 9
ATTITUDE_AXES_KM, SATELLITE_AXES_KM = 40.0, 90.0
#: the Earth patch around the scene origin [deg] and its nodes per side
EARTH_HALF_DEG, EARTH_NODES = 3.0, 41
#: colours: lines of sight, the line's ground, the chosen detector's footprint, the others'
#: (:data:`geoloc_viz.palette.SENTINEL2`)
LOS_COLOR, SWATH_COLOR = SENTINEL2["los"].rgb, SENTINEL2["swath"].rgb
FOOTPRINT_COLOR, OTHER_FOOTPRINT_COLOR = SENTINEL2["footprint"].rgb, SENTINEL2["other_footprint"].rgb
EARTH_COLOR = SENTINEL2["earth"].rgb
#: camera near and far planes [km]: the satellite is 790 km above the ground it looks at
CAMERA_NEAR_KM, CAMERA_FAR_KM = 1.0, 2.0e4


def is_product(path: str | Path) -> bool:
    """Whether ``path`` is a Sentinel-2 L1B product folder (holding DATASTRIP and GRANULE)."""
    p = Path(path)
    return p.is_dir() and (p / "DATASTRIP").is_dir() and (p / "GRANULE").is_dir()


class Sentinel2App:
    """The scene of one band of a product, its GUI (the line, the detector) and its numbers.

    ``server`` is a viser server or a tab's ``ClientHandle`` (:class:`Sentinel2Viewer`).
    """

    def __init__(
        self, server: Any, product: Sentinel2Product, band: str = "B02", detector: int | str | None = None
    ) -> None:
        self.server, self.product = server, product
        self.band = band_info(band)[0]
        dets = sorted({g.detector for g in product.granules.values()})
        if not dets:
            raise ValueError(f"{product.path}: no granule metadata: no detector to show")
        self.detectors = dets
        self.detector = detector_id(detector) if detector is not None else dets[0]
        if self.detector not in dets:
            raise ValueError(f"detector = {detector!r}: the product has {', '.join(dets)}")
        self.sensors: dict[str, InertialPushbroomSensor] = {d: product.sensor(self.band, d) for d in dets}
        self.pipes = {
            d: Pipeline(s, HeightSurface(0.0, "geodetic"), Corrections.for_sensor(s)) for d, s in self.sensors.items()
        }
        s = self.sensors[self.detector]
        self.row = float((s.rows + 1) // 2)
        mid = self.pipes[self.detector].locate(self.row, (s.cols + 1) / 2.0)
        self.enu = EnuFrame(float(mid.lat), float(mid.lon), 0.0)
        self.footprints = {d: self._footprint(d) for d in dets}
        gui = server.gui
        self.md = gui.add_markdown("")
        with gui.add_folder(f"Sentinel-2 {self.band}"):
            self.dd_detector = gui.add_dropdown("detector", tuple(dets), initial_value=self.detector)
            self.sl_line = gui.add_slider("line", 1, s.rows, 1, int(self.row))
            self.dd_detector.on_update(lambda _: self._on_gui())
            self.sl_line.on_update(lambda _: self._on_gui())
        self.draw_static()
        self.draw(reset_camera=True)

    # ------------------------------------------------------------ numbers
    @property
    def sensor(self) -> InertialPushbroomSensor:
        return self.sensors[self.detector]

    def w(self, p_ecef: np.ndarray) -> np.ndarray:
        """ECEF [m] -> scene (ENU, km), float64 (lines and meshes go to the browser as float32)."""
        return np.asarray(self.enu.from_ecef(p_ecef) * WORLD_SCALE, float)

    def R_ecef_body(self, t: np.ndarray) -> np.ndarray:
        """The body (piloting) frame -> ECEF at times ``t`` [s from the sensor's epoch]."""
        s = self.sensor
        return s.earth.R_ecef_in(t) @ s._R_in_body(t)

    def _footprint(self, det: str) -> np.ndarray:
        """The ground outline (ECEF, closed) of a detector over its datastrip: first column down the
        lines, last line across, last column back up, first line back."""
        s = self.sensors[det]
        rows = np.linspace(1.0, s.rows, 60)
        cols = np.linspace(1.0, s.cols, 20)
        r = np.concatenate([rows, np.full(20, float(s.rows)), rows[::-1], np.ones(20)])
        c = np.concatenate([np.ones(60), cols, np.full(60, float(s.cols)), cols[::-1]])
        return np.asarray(self.pipes[det].locate(r, c).ecef)

    def line_geometry(self) -> dict:
        """The chosen line: time, satellite position, body frame, the first, middle and last pixels'
        ground points and the ground of every 10th pixel (ECEF metres)."""
        s = self.sensor
        t = np.array([s.line_time(self.row)])
        p, _ = s.orbit.state(t)
        cols = np.array([1.0, (s.cols + 1) / 2.0, float(s.cols)])
        los = self.pipes[self.detector].locate(np.full(3, self.row), cols)
        swath = self.pipes[self.detector].locate(
            np.full(s.cols // 10 + 1, self.row), np.linspace(1.0, s.cols, s.cols // 10 + 1)
        )
        return {
            "t_s": float(t[0]),
            "position": p[0],
            "R_ecef_body": self.R_ecef_body(t)[0],
            "ground": np.asarray(los.ecef),
            "swath": np.asarray(swath.ecef),
        }

    # ------------------------------------------------------------ drawing
    def _polyline(self, name: str, pts: np.ndarray, color: tuple, thickness: float) -> None:
        pts = np.asarray(pts, np.float32)
        seg = np.stack([pts[:-1], pts[1:]], axis=1)
        self.server.scene.add_line_segments(name, seg, color, thickness=thickness, thickness_units="screen")

    def draw_static(self) -> None:
        """The Earth patch, the orbit, the attitude frames along the datastrip, the footprints."""
        sc = self.server.scene
        s = self.sensor
        _, _, earth, faces = earth_patch(
            np.rad2deg(self.enu.lat0), np.rad2deg(self.enu.lon0), EARTH_HALF_DEG, EARTH_NODES
        )
        with self.server.atomic():
            sc.add_frame("/s2", show_axes=False)
            sc.add_mesh_simple(
                "/s2/earth",
                self.w(earth.reshape(-1, 3)).astype(np.float32),
                faces,
                color=EARTH_COLOR,
                side="double",
                cast_shadow=False,
                receive_shadow=False,
            )
            t = np.linspace(s.orbit.span[0], s.orbit.span[1], 200)
            p, _ = s.orbit.state(t)
            self._polyline("/s2/orbit", self.w(p), SENTINEL2["orbit"].rgb, 2.0)
            ta = s.line_time(np.linspace(1.0, s.rows, N_ATTITUDE))
            pa, _ = s.orbit.state(ta)
            R = self.R_ecef_body(ta)
            for k in range(N_ATTITUDE):
                sc.add_frame(
                    f"/s2/attitude/{k}",
                    axes_length=ATTITUDE_AXES_KM,
                    axes_radius=ATTITUDE_AXES_KM / 25,
                    wxyz=wxyz(self.enu.R_enu_ecef @ R[k]),
                    position=self.w(pa[k]),
                )
        self.draw_footprints()

    def draw_footprints(self) -> None:
        with self.server.atomic():
            for d, outline in self.footprints.items():
                mine = d == self.detector
                self._polyline(
                    f"/s2/footprint/D{d}",
                    self.w(outline),
                    FOOTPRINT_COLOR if mine else OTHER_FOOTPRINT_COLOR,
                    4.0 if mine else 3.0,
                )

    def draw(self, reset_camera: bool = False) -> None:
        """The chosen line: the satellite's body frame, three lines of sight, the line's ground."""
        sc = self.server.scene
        g = self.line_geometry()
        self.geometry = g
        sp = self.w(g["position"])
        with self.server.atomic():
            sc.add_frame(
                "/s2/satellite",
                axes_length=SATELLITE_AXES_KM,
                axes_radius=SATELLITE_AXES_KM / 20,
                origin_radius=12.0,
                wxyz=wxyz(self.enu.R_enu_ecef @ g["R_ecef_body"]),
                position=sp,
            )
            for name, q in zip(("first", "middle", "last"), g["ground"]):
                self._polyline(f"/s2/los/{name}", np.stack([sp, self.w(q)]), LOS_COLOR, 3.0)
            self._polyline("/s2/swath", self.w(g["swath"]), SWATH_COLOR, 5.0)
        self._text()
        if reset_camera:
            self._camera()

    def _text(self) -> None:
        s, g = self.sensor, self.geometry
        _, _, h = ecef_to_geodetic(g["position"])
        lat, lon, _ = ecef_to_geodetic(g["ground"][1])
        self.md.content = (
            f"**{s.name}**, line {self.row:.0f} of {s.rows} ({s.cols} pixels), "
            f"{g['t_s'] - s.line_time(1.0):.3f} s after the first line  \n"
            f"satellite {float(h) / 1e3:.1f} km above WGS 84; middle pixel's ground "
            f"{np.rad2deg(float(lat)):.5f}, {np.rad2deg(float(lon)):.5f} deg (h = 0, light-time and aberration on)  \n"
            "white: the GPS orbit; axes: the body frame (X red, Y green, Z blue) at the line and along the "
            "datastrip; yellow: the first, middle and last pixels' lines of sight; orange: the line's ground; "
            "magenta: this detector's footprint, light blue: the others'"
        )

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, look-at, up) in scene km: an oblique view from behind along the track and
        above, so that the fan of the line's lines of sight opens across the screen, with the
        satellite and the footprints left of the middle (the GUI panel covers the right part)."""
        g = self.geometry
        sp = self.w(g["position"])
        gr = self.w(g["ground"][1])
        across = self.w(g["ground"][2]) - self.w(g["ground"][0])
        across[2] = 0.0
        across /= np.linalg.norm(across)
        up = np.array([0.0, 0.0, 1.0])
        along = np.cross(up, across)
        L = float(np.linalg.norm(sp - gr))
        aim = gr + 0.5 * (sp - gr)
        pos = aim + 0.95 * L * along + 0.2 * L * across + 0.15 * L * up
        right = np.cross(aim - pos, up)
        right /= np.linalg.norm(right)
        shift = 0.2 * L * right  # the scene left of the middle
        return pos + shift, aim + shift, up

    def _camera(self) -> None:
        pos, aim, up = self.camera_pose()
        if hasattr(self.server, "initial_camera"):
            cam = self.server.initial_camera
            cam.up = tuple(up)
            cam.near, cam.far = CAMERA_NEAR_KM, CAMERA_FAR_KM
            cam.position, cam.look_at = tuple(pos), tuple(aim)
        else:
            cam = self.server.camera
            cam.up_direction = tuple(up)
            cam.near, cam.far = CAMERA_NEAR_KM, CAMERA_FAR_KM
            cam.position = tuple(pos)
            cam.look_at = tuple(aim)

    def _on_gui(self) -> None:
        det = str(self.dd_detector.value)
        changed = det != self.detector
        self.detector = det
        if changed:
            self.sl_line.max = self.sensor.rows
        self.row = float(min(int(self.sl_line.value), self.sensor.rows))
        if changed:
            self.draw_footprints()
        self.draw()

    def export(self, path: str | Path) -> Path:
        """Write the scene as ``.viser`` or self-contained ``.html`` (as the limb scene's export)."""
        from geoloc.userfiles import write_bytes, write_text

        path = Path(path)
        ser = self.server.get_scene_serializer()
        if path.suffix.lower() == ".html":
            from geoloc_viz.export_html import with_summary

            write_text(
                path,
                with_summary(
                    ser.as_html(dark_mode=True),
                    f"geoloc view: {self.sensor.name}",
                    self.md.content,
                    "Static export of geoloc view --scenario PRODUCT (no controls).",
                ),
            )
        else:
            write_bytes(path, ser.serialize())
        return path


class Sentinel2Viewer:
    """What ``geoloc view --scenario PRODUCT`` serves: one :class:`Sentinel2App` per browser tab."""

    def __init__(
        self, server: viser.ViserServer, product: Sentinel2Product, band: str = "B02", detector: int | str | None = None
    ) -> None:
        self.server, self.product, self.band, self.detector = server, product, band, detector
        self.apps: dict[int, Sentinel2App] = {}
        self._lock = threading.Lock()
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    def _on_connect(self, client: Any) -> None:
        with self._lock:
            app = Sentinel2App(client, self.product, self.band, self.detector)
            if client.client_id in self.server.get_clients():
                self.apps[client.client_id] = app

    def _on_disconnect(self, client: Any) -> None:
        with self._lock:
            self.apps.pop(client.client_id, None)


def load(path: str | Path) -> Sentinel2Product:
    """The product at ``path`` (its GIPP and IERS folders beside DATASTRIP, as ``geoloc s2``)."""
    return read_product(path)


__all__ = ["Sentinel2App", "Sentinel2Viewer", "is_product", "load"]
