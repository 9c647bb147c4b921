"""Send the point on (to another tool or person): a "Send the point on" GUI folder of texts to copy.

:func:`attach` (a layer of :class:`geoloc_viz.app.GeolocSession`) shows, for the last point
picked in the picture (a pixel of the panel or of the frustum image) or in the scene (a terrain
click), and before any pick for the scene's own pixel, the texts of :mod:`geoloc_viz.share`:
its MGRS reference, latitude / longitude / height with the datum, a ``geoloc locate`` command
line that reproduces it, and a Cursor-on-Target event; each in a text block with a "copy"
button (the browser's clipboard where it has one; else the block is selected for Ctrl+C).
The CoT event is also written to a file or sent as one UDP datagram to the destination typed
in the panel (default ``udp://127.0.0.1:6969``, this machine; TAK's situational-awareness
multicast is ``udp://239.2.3.1:6969``). The folder also gives the frame's field of view
(horizontal and vertical, from its lens).

The sensor file the command names is the frame's sensor, written once per sensor into a folder
of this viewer's process (``tempfile.mkdtemp``), named by its content's hash.
Every number comes from the core through :mod:`geoloc_viz.share`; this module only lays out.
"""

from __future__ import annotations

import hashlib
import html
import math
import tempfile
import threading
from pathlib import Path

import numpy as np

from geoloc.status import Status
from geoloc_viz import share as sh
from geoloc_viz.layer_safety import call_safely

#: Where the CoT event goes by default: this machine (TAK's multicast must be asked for).
DEFAULT_COT_URL = "udp://127.0.0.1:6969"
_FOLDER = None
_FOLDER_LOCK = threading.Lock()


def pick_folder() -> Path:
    """This process's folder for the sensor files and CoT files the panel names (made once)."""
    global _FOLDER
    with _FOLDER_LOCK:
        if _FOLDER is None:
            _FOLDER = Path(tempfile.mkdtemp(prefix="geoloc-view-picks-"))
        return _FOLDER


def sensor_file(sensor) -> Path:
    """The frame's sensor as a sensor file (:func:`geoloc.sensors.sensor_file.sensor_to_toml`) in
    :func:`pick_folder`, named by the hash of its text (written once)."""
    from geoloc.sensors.sensor_file import sensor_to_toml

    folder = pick_folder()
    tmp = folder / f".probe-{threading.get_ident()}.toml"
    sensor_to_toml(sensor, tmp)
    digest = hashlib.sha256(tmp.read_bytes()).hexdigest()[:12]
    path = folder / f"sensor_{digest}.toml"
    if path.exists():
        tmp.unlink()
    else:
        tmp.replace(path)
    return path


#: A copy button: the clipboard where the page may write it, else select the block for Ctrl+C.
_COPY_JS = (
    "var b=this,p=b.parentElement.querySelector('pre'),t=p.textContent;"
    "function done(m){b.textContent=m;setTimeout(function(){b.textContent='copy'},2000)}"
    "function sel(){var r=document.createRange();r.selectNodeContents(p);var s=window.getSelection();"
    "s.removeAllRanges();s.addRange(r);var ok=false;try{ok=document.execCommand('copy')}catch(e){}"
    "done(ok?'copied':'selected: Ctrl+C')}"
    "if(navigator.clipboard&&window.isSecureContext){navigator.clipboard.writeText(t)"
    ".then(function(){done('copied')},sel)}else{sel()}"
)


def _block(key: str, title: str, text: str) -> str:
    return (
        f'<div style="margin:0.3em 0"><span style="font-weight:600">{html.escape(title)}</span> '
        f'<button id="geoloc-share-copy-{key}" style="font-size:0.75em;padding:0 0.5em" '
        f'onclick="{html.escape(_COPY_JS, quote=True)}">copy</button>'
        f'<pre id="geoloc-share-{key}" style="white-space:pre-wrap;word-break:break-all;font-size:0.72em;'
        f'margin:0.2em 0;padding:0.3em;background:rgba(128,128,128,0.15)">{html.escape(text)}</pre></div>'
    )


class ShareLayer:
    """The "Send the point on" folder of one session (module docstring)."""

    def __init__(self, session):
        from geoloc_viz.image_layer import ImageLayer

        self.session = session
        self.closed = False
        self._lock = threading.RLock()
        self.point: sh.SharedPoint | None = None
        self.texts: dict = {}
        self.fov_deg = (float("nan"), float("nan"))
        self.picture = next((obj for obj in session.layers if isinstance(obj, ImageLayer)), None)
        g = session.gui
        with g.add_folder("Send the point on", expand_by_default=False):
            self.md_head = g.add_markdown("")
            self.html = g.add_html("")
            self.tx_url = g.add_text(
                "CoT UDP destination",
                DEFAULT_COT_URL,
                hint="udp://HOST:PORT; this machine by default; TAK's situational-"
                "awareness multicast is udp://239.2.3.1:6969",
            )
            self.bt_send = g.add_button("send the CoT event (UDP)")
            self.bt_file = g.add_button("write the CoT event to a file")
            self.md_status = g.add_markdown("")
        self.bt_send.on_click(lambda _e: self._safe(self.send_udp))
        self.bt_file.on_click(lambda _e: self._safe(self.write_file))
        session.on_refresh(lambda _g: self._safe(self.update), deferred=True)
        if self.picture is not None:
            self.picture.on_pick(lambda _l: self._safe(self.update))
        self._safe(self.update)

    def _safe(self, fn, *a):
        return None if self.closed else call_safely(fn, *a, what="the send-the-point layer", lock=self._lock)

    # ------------------------------------------------------------ the point
    def _label(self) -> str:
        scn = self.session.scn
        i = scn.record_index
        return "custom pose" if i is None else str(scn.records[i][0].label)

    def current(self):
        """(SharedPoint or None, surface it lies on): the last pick, else the scene's pixel."""
        from geoloc.surfaces.terrain import surface_for
        from geoloc_viz import terrain_link

        s, pic = self.session, self.picture
        scn, inp = s.scn, s.inputs
        method = inp.method if scn.dem is not None else "constant height"
        if pic is not None and pic.sensor is not None:
            if pic.last_pick == "pixel" and pic.pick is not None and pic.pick.ok:
                p = pic.pick
                pt = sh.SharedPoint(
                    "picked pixel",
                    p.lat_deg(),
                    p.lon_deg(),
                    float(p.hit.h),
                    p.row,
                    p.col,
                    pic.sensor,
                    inp,
                    method,
                    self._label(),
                )
                return pt, terrain_link.scene_surface(scn, inp, trace=False)
            if pic.last_pick == "ground" and pic.ground is not None and pic.ground.ok:
                gp, gi = pic.ground, pic.ground_inputs or inp
                lat, lon = (math.degrees(float(v)) for v in (gp.hit.lat, gp.hit.lon))
                ok = bool(gp.in_frame and gp.visible)
                pt = sh.SharedPoint(
                    "terrain pick",
                    lat,
                    lon,
                    float(gp.hit.h),
                    gp.row,
                    gp.col,
                    pic.sensor,
                    gi,
                    "exact",
                    self._label(),
                    reproducible=ok,
                    note="" if ok else f"no pixel of this frame sees it ({gp.verdict()})",
                )
                dem = scn.dem if getattr(scn, "use_dem", True) else None
                return pt, surface_for(gi.target_h, dem, method="exact")
        g = s.geometry
        if g is None or g.status != Status.OK:
            return None, None
        pt = sh.SharedPoint(
            "scene pixel",
            math.degrees(float(g.hit.lat)),
            math.degrees(float(g.hit.lon)),
            float(g.hit.h),
            float(inp.row),
            float(inp.col),
            scn.camera,
            inp,
            method,
            self._label(),
        )
        return pt, terrain_link.scene_surface(scn, inp, trace=False)

    def update(self) -> None:
        from geoloc_viz.uncertainty_layer import UncertaintyLayer, record_velocity

        s = self.session
        pt, surface = self.current()
        self.point = pt
        if pt is None:
            self.texts = {}
            self.md_head.content = "no located point to send"
            self.html.content = ""
            return
        unc = next((obj for obj in s.layers if isinstance(obj, UncertaintyLayer)), None)
        if pt.what == "scene pixel" and unc is not None and unc.pu is not None and unc.pu.status == Status.OK:
            # the uncertainty layer's ellipse is of this very pixel, computed just before (its refresh first)
            pt.ce90_m, pt.le90_m = float(unc.pu.ce90_m), float(unc.pu.le90_m)
        else:
            pt.ce90_m, pt.le90_m = sh.predicted_90(s.scn, pt, surface, record_velocity(s.scn, s.scn.record_index))
        self.fov_deg = sh.field_of_view_deg(pt.sensor, pt.inputs.pose())
        texts = {"mgrs": sh.mgrs_of(pt) or "none", "latlon": sh.latlon_text(pt)}
        if pt.reproducible:
            texts["locate"] = sh.command_text(sh.locate_args(s.scn, pt, sensor_file(pt.sensor)))
        else:
            texts["locate"] = f"(none: {pt.note})"
        texts["cot"] = sh.cot_event(pt)
        self.texts = texts
        what = {
            "picked pixel": f"the picked pixel (row {pt.row:g}, column {pt.col:g})",
            "terrain pick": "the terrain point clicked in the scene"
            + (f" (pixel row {pt.row:.2f}, column {pt.col:.2f})" if pt.reproducible else ""),
            "scene pixel": f"the scene's pixel (row {pt.row:g}, column {pt.col:g}); click the picture "
            "or the terrain to send another point",
        }[pt.what]
        h, v = self.fov_deg
        ce = (
            f"predicted CE90 {pt.ce90_m:.1f} m, LE90 {pt.le90_m:.1f} m (CoT ce/le: one sigma)"
            if np.isfinite(pt.ce90_m)
            else "no predicted uncertainty (CoT ce/le unknown)"
        )
        self.md_head.content = (
            f"**{pt.label}**: {what}  \n"
            f"field of view **{h:.3f} x {v:.3f} deg** (horizontal x vertical, from the "
            f"lens; {pt.sensor.cols} x {pt.sensor.rows} px)  \n{ce}"
        )
        self.html.content = (
            '<div id="geoloc-share" style="padding:0 0.5em">'
            + _block("mgrs", "MGRS (1 m)", texts["mgrs"])
            + _block("latlon", "latitude, longitude, height", texts["latlon"])
            + _block("locate", "geoloc locate (reproduces the point)", texts["locate"])
            + _block("cot", "Cursor-on-Target event", texts["cot"])
            + "</div>"
        )

    # ------------------------------------------------------------ sending
    def _fresh_event(self) -> bytes:
        """The current point's CoT event, made now (its time, start and stale from now)."""
        if self.point is None:
            raise ValueError("no located point to send")
        return sh.cot_event(self.point).encode("utf-8")

    def send_udp(self) -> str:
        from geoloc.io.cot import CotEvents, send_udp

        url = str(self.tx_url.value).strip()
        try:
            n = send_udp(CotEvents(events=[self._fresh_event()]), url)
            msg = f"sent {n} CoT event to {url}"
        except (ValueError, OSError) as e:
            msg = f"not sent: {e}"
        self.md_status.content = msg
        return msg

    def write_file(self) -> Path:
        from geoloc.userfiles import write_bytes

        ev = self._fresh_event()
        n = len(list(pick_folder().glob("pick_*.cot"))) + 1
        path = write_bytes(pick_folder() / f"pick_{n:03d}.cot", ev + b"\n")
        self.md_status.content = f"wrote the CoT event to `{path}`"
        return path

    def close(self) -> None:
        self.closed = True


def attach(session):
    """The send-the-point layer (every scenario with a frame sensor)."""
    return ShareLayer(session)
