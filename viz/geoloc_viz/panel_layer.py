"""Room for the picture and the data: a movable panel with the picture large, a map and plots.

One button in the sidebar's head ("open the large panel") opens a viser panel (a window the user
can dock, float, resize and minimise, ``gui.add_panel``) docked on the left, with three tabs:

- **Picture**: the current frame at its own resolution (every image pixel sent, the marks of the
  sidebar's picture drawn on it). A click in it locates that pixel the way a click in the small
  picture does (:meth:`geoloc_viz.image_layer.ImageLayer.pick_pixel`): the same ray, hit, panel
  text and "Send the point on" blocks.
- **Map**: a 2D map of the flight in its own East-North-Up frame (the flight model's
  :class:`geoloc.frames.enu.EnuFrame`, a local tangent plane: metres east and north, north up):
  the hillshade of the scenario's DEM (heights read through the DEM's own bilinear surface on the
  map's pixel grid, shaded by a fixed sun; no tiles, nothing downloaded), the track, every
  footprint thin, and over them, drawn as SVG so a step sends only a few hundred bytes, the
  current frame: its footprint bold, the aircraft, the recomputed and reported points, the truth,
  and the last picks. The map's transform is on the page (``data-*`` attributes) so a point's
  pixel can be computed from its coordinates.
- **Plots**: the error, the heights and the angles against time (matplotlib, drawn once per
  flight, gaps where a value is unknown), with a cursor (a vertical SVG line, in the current
  frame's magenta) on the current frame: a step moves only the line; the pointer over the plots
  shows the nearest frame's name and values (the page holds the plotted series, 0.1 of a unit).

The panel updates only while it is open (a closed panel costs a step nothing). The layer follows
the session's flight layer and picture layer as they are now (a live view attaches them late and
replaces the flight model as the window grows).

Conventions: ``docs/conventions.md``; guide: ``docs/viz.md`` ("Room for the picture and the data").
"""

from __future__ import annotations

import base64
import html
import io
import threading

import numpy as np

from geoloc_viz import flight_layer as fl_mod
from geoloc_viz import image_layer as il_mod
from geoloc_viz.layer_safety import call_safely, own_update

#: Width [px] of the map's image and of the docked panel.
MAP_PX = 520
PANEL_WIDTH_PX = 560
#: Margin around the drawn data on the map, as a fraction of its extent.
MAP_MARGIN = 0.06
#: The map's hillshade sun: azimuth clockwise from north, elevation [deg] (the cartographic
#: north-west light, as the scene's terrain and the rendered video use).
SUN_AZ_EL_DEG = (315.0, 45.0)
#: Colours (RGB): the flight layer's, so a meaning has one colour in the scene, the map and the plots.
COLORS = dict(fl_mod.COLORS)
COLORS["pick"] = il_mod.COLORS["pick"]
COLORS["ground"] = il_mod.COLORS["ground"]
#: Footprints of the whole flight drawn on the map: at most this many (every k-th frame, outliers
#: always), so 300 overlapping outlines thin to a readable trail; the current one is drawn bold.
MAP_TRAIL_MAX = 60
#: The large picture's sizes: fit the panel, or screen pixels per image pixel (the panel scrolls).
PICTURE_SIZES = ("fit the panel", "1:1", "2:1")
#: A growing flight (live mode) redraws the map's background and the plots at most this often [s]
#: (about 0.2 s and 0.2 s of CPU each on the bundled flight); in between the map's overlay, in the
#: same ENU frame, stays exact and the plots' cursor finds the frame by its label.
REBUILD_S = 5.0
OPEN_LABEL = "open the large panel: picture, map, plots"
CLOSE_LABEL = "close the large panel"


def _hex(rgb) -> str:
    return "#%02x%02x%02x" % tuple(int(v) for v in rgb)


def _b64(img: np.ndarray, fmt: str = "JPEG", quality: int = 90) -> str:
    import PIL.Image

    buf = io.BytesIO()
    im = PIL.Image.fromarray(np.ascontiguousarray(img[..., :3]))
    im.save(buf, fmt, **({"quality": quality} if fmt == "JPEG" else {}))
    return base64.b64encode(buf.getvalue()).decode("ascii")


# ---------------------------------------------------------------------------- the map
class MapView:
    """The map's grid: pixel (x, y) (0 at the top-left corner of the image, x east, y south) of a
    point at east, north ``(e, n)`` metres of ``enu`` is ``((e - e0) / m_per_px, (n0 - n) / m_per_px)``.

    Attributes
    ----------
    enu : EnuFrame
        The frame the map is drawn in (the flight model's).
    e0, n0 : float
        East and north [m] of the image's top-left corner.
    m_per_px : float
        Metres per map pixel (the same east and north).
    width, height : int
        Image size [px].
    background : ndarray (height, width, 3) uint8
        The hillshade with the track and the thinned footprints.
    """

    def __init__(self, enu, e0, n0, m_per_px, width, height):
        self.enu, self.e0, self.n0, self.m_per_px = enu, float(e0), float(n0), float(m_per_px)
        self.width, self.height = int(width), int(height)
        self.background = np.zeros((self.height, self.width, 3), np.uint8)
        self.background_b64 = ""
        self.dem_note = ""
        self.extent = MAP_EXTENTS[0]

    def to_px(self, p_enu) -> np.ndarray:
        """(..., 2) map pixels (x, y) of ENU points (..., >= 2) [m] of :attr:`enu`."""
        p = np.asarray(p_enu, float)
        return np.stack([(p[..., 0] - self.e0) / self.m_per_px, (self.n0 - p[..., 1]) / self.m_per_px], -1)

    def cell_centres_enu(self) -> tuple[np.ndarray, np.ndarray]:
        """East and north [m] of every map pixel's centre, (height, width) each."""
        e = self.e0 + (np.arange(self.width) + 0.5) * self.m_per_px
        n = self.n0 - (np.arange(self.height) + 0.5) * self.m_per_px
        return np.meshgrid(e, n)


#: What the map frames: the whole flight (track, footprints, points) or the ground only (footprints
#: and points; the track runs off the edges).
MAP_EXTENTS = ("the whole flight", "the footprints")


def map_extent(model, what: str = MAP_EXTENTS[0]) -> np.ndarray:
    """(e_min, n_min, e_max, n_max) [m] of what the map shows (:data:`MAP_EXTENTS`)."""
    if what not in MAP_EXTENTS:
        raise ValueError(f"map extent {what!r}: one of {MAP_EXTENTS}")
    pts = [model.footprint_enu.reshape(-1, 3), model.recomputed_enu, model.truth_enu, model.reported_enu]
    if what == MAP_EXTENTS[0]:
        pts.append(model.track_enu)
    p = np.concatenate([np.asarray(a, float).reshape(-1, 3) for a in pts])
    p = p[np.all(np.isfinite(p[:, :2]), axis=1)]
    if not len(p):
        return np.array([-1e3, -1e3, 1e3, 1e3])
    lo, hi = p[:, :2].min(0), p[:, :2].max(0)
    pad = MAP_MARGIN * max(float(np.max(hi - lo)), 100.0)
    return np.r_[lo - pad, hi + pad]


def hillshade_grid(H: np.ndarray, m_per_px: float, sun_az_el_deg=SUN_AZ_EL_DEG) -> np.ndarray:
    """Lambert shading in [0, 1] of heights ``H`` (rows north to south) on a square grid of
    ``m_per_px`` metres: the normal from central differences, the sun at azimuth / elevation."""
    Hf = np.where(np.isfinite(H), H, np.nanmedian(H) if np.isfinite(H).any() else 0.0)
    dz_drow, dz_dcol = np.gradient(Hf, m_per_px, m_per_px)
    dz_dn, dz_de = -dz_drow, dz_dcol  # rows run south
    nrm = np.stack([-dz_de, -dz_dn, np.ones_like(Hf)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    az, el = np.radians(sun_az_el_deg)
    light = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    return np.clip(nrm @ light, 0.0, 1.0)


def trail_frames(model, max_n: int = MAP_TRAIL_MAX) -> np.ndarray:
    """Frame indices whose footprints the map draws: every k-th (at most ``max_n``), and every outlier
    (:meth:`geoloc_viz.flight_model.FlightModel.trail_frames`, as the scene's trail)."""
    return model.trail_frames(max_n)


def build_map(model, dem=None, width_px: int = MAP_PX, extent: str = MAP_EXTENTS[0]) -> MapView:
    """The map of a flight model: its grid (:func:`map_extent`, square pixels), the DEM's
    hillshade (heights of the DEM's bilinear surface at each pixel centre's ground point, on the
    ellipsoid's normal through it), the track and the thinned footprints drawn on it."""
    import PIL.Image
    import PIL.ImageDraw

    e_min, n_min, e_max, n_max = map_extent(model, extent)
    mpp = (e_max - e_min) / width_px
    h_px = int(np.clip(np.ceil((n_max - n_min) / mpp), 60, 2 * width_px))
    # centre the data vertically when the height was clipped or rounded
    n0 = 0.5 * (n_min + n_max) + 0.5 * h_px * mpp
    view = MapView(model.enu, e_min, n0, mpp, width_px, h_px)
    view.extent = extent
    shade = np.full((h_px, width_px), 0.75)
    tint = np.ones((h_px, width_px, 3)) * np.array([0.78, 0.80, 0.78])
    if dem is not None:
        E, N = view.cell_centres_enu()
        lat, lon, _h = model.enu.to_geodetic(np.stack([E, N, np.zeros_like(E)], -1))
        H = np.asarray(dem.height(lat, lon), float)
        ok = np.isfinite(H)
        if ok.any():
            shade = hillshade_grid(H, mpp)
            lo, hi = np.nanpercentile(H, [1, 99])
            t = np.clip((np.where(ok, H, lo) - lo) / max(hi - lo, 1.0), 0, 1)[..., None]
            # low green-grey to high sand: a quiet hypsometric tint under the lines
            tint = (1 - t) * np.array([0.62, 0.72, 0.60]) + t * np.array([0.86, 0.80, 0.66])
            tint[~ok] = (0.55, 0.62, 0.75)
            view.dem_note = f"hillshade of the DEM, heights {lo:.0f}-{hi:.0f} m"
    else:
        view.dem_note = "no DEM: plain background"
    rgb = np.clip(tint * (0.35 + 0.65 * shade[..., None]) * 255, 0, 255).astype(np.uint8)
    im = PIL.Image.fromarray(rgb)
    d = PIL.ImageDraw.Draw(im)
    for i in trail_frames(model):
        ring = view.to_px(model.footprint_enu[i])
        if np.all(np.isfinite(ring)):
            col = COLORS["footprint_outlier"] if model.outlier[i] else COLORS["footprint"]
            d.line([tuple(p) for p in ring] + [tuple(ring[0])], fill=col, width=1)
    tr = view.to_px(model.track_enu)
    tr = tr[np.all(np.isfinite(tr), axis=1)]
    if len(tr) > 1:
        d.line([tuple(p) for p in tr], fill=COLORS["track"], width=2)
    _scale_bar(d, view)
    view.background = np.asarray(im)
    view.background_b64 = _b64(view.background, "JPEG", 88)
    return view


def _scale_bar(d, view: MapView) -> None:
    """A scale bar (1-2-5 steps, about a fifth of the width) and N, bottom-left."""
    target = view.width * view.m_per_px / 5
    step = 10 ** np.floor(np.log10(target))
    length = max(s * step for s in (1, 2, 5) if s * step <= target)
    px = length / view.m_per_px
    x0, y0 = 10, view.height - 12
    d.line([(x0, y0), (x0 + px, y0)], fill=(0, 0, 0), width=3)
    d.text((x0, y0 - 14), f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m", fill=(0, 0, 0))
    d.text((view.width - 16, 6), "N", fill=(0, 0, 0))
    d.line([(view.width - 12, 30), (view.width - 12, 20)], fill=(0, 0, 0), width=2)


def map_svg(view: MapView, model, idx: int, picks=()) -> str:
    """The map's current-frame overlay: SVG in the map image's pixels (viewBox = its size).

    ``picks``: ``(kind, (e, n))`` each, kind ``"pick"`` (a clicked pixel's ground point) or
    ``"ground"`` (a terrain click), in the map's ENU frame [m]."""
    out = []

    def pt(p):
        return view.to_px(p)

    ring = pt(model.footprint_enu[idx])
    if np.all(np.isfinite(ring)):
        pts = " ".join(f"{x:.2f},{y:.2f}" for x, y in ring)
        out.append(
            f'<polygon id="geoloc-map-current" points="{pts}" fill="none" '
            f'stroke="{_hex(COLORS["current"])}" stroke-width="3.5" stroke-linejoin="round"/>'
        )
    marks = (
        ("aircraft", model.track_enu[idx], COLORS["track"], 5.0),
        ("recomputed", model.recomputed_enu[idx], COLORS["recomputed"], 4.0),
        ("reported", model.reported_enu[idx], COLORS["reported"], 4.0),
        ("truth", model.truth_enu[idx], COLORS["truth"], 4.0),
    )
    for name, p, col, r in marks:
        if np.all(np.isfinite(p[:2])):
            x, y = pt(p)
            out.append(
                f'<circle id="geoloc-map-{name}" cx="{x:.2f}" cy="{y:.2f}" r="{r}" fill="{_hex(col)}" '
                f'stroke="#000" stroke-width="1"/>'
            )
    for k, (kind, p) in enumerate(picks):
        x, y = pt(p)
        if np.isfinite(x) and np.isfinite(y):
            stroke = _hex(COLORS["pick" if kind == "pick" else "ground"])
            out.append(
                f'<g id="geoloc-map-{kind}" data-x="{x:.2f}" data-y="{y:.2f}" stroke="{stroke}" stroke-width="2.5">'
                f'<line x1="{x - 8:.2f}" y1="{y:.2f}" x2="{x + 8:.2f}" y2="{y:.2f}"/>'
                f'<line x1="{x:.2f}" y1="{y - 8:.2f}" x2="{x:.2f}" y2="{y + 8:.2f}"/></g>'
            )
    return "".join(out)


def map_html(view: MapView, model, idx: int, picks=(), name: str | None = None) -> str:
    """The map tab: the background image and the SVG overlay, its transform in ``data-*``."""
    o = view.enu.to_geodetic(np.zeros(3))
    lat0, lon0, h0 = float(np.degrees(o[0])), float(np.degrees(o[1])), float(o[2])
    legend = (
        f'<span style="color:{_hex(COLORS["current"])}">&#9632;</span> current footprint '
        f'<span style="color:{_hex(COLORS["footprint"])}">&#9632;</span> footprints (thinned) '
        f'<span style="color:{_hex(COLORS["footprint_outlier"])}">&#9632;</span> outliers '
        f'<span style="color:{_hex(COLORS["track"])}">&#9632;</span> track, aircraft '
        f'<span style="color:{_hex(COLORS["recomputed"])}">&#9679;</span> recomputed '
        f'<span style="color:{_hex(COLORS["reported"])}">&#9679;</span> reported '
        f"&#9675; truth "
        f'<span style="color:{_hex(COLORS["pick"])}">+</span> picked pixel '
        f'<span style="color:{_hex(COLORS["ground"])}">+</span> terrain click'
    )
    return (
        f'<div style="padding:0 0.5em"><div id="geoloc-map" style="position:relative;width:100%" '
        f'data-e0="{view.e0!r}" data-n0="{view.n0!r}" data-m-per-px="{view.m_per_px!r}" '
        f'data-width="{view.width}" data-height="{view.height}" data-frame="{idx}" '
        f'data-origin-lat-deg="{lat0!r}" data-origin-lon-deg="{lon0!r}" data-origin-h-m="{h0!r}">'
        f'<img alt="map" src="data:image/jpeg;base64,{view.background_b64}" style="width:100%;display:block">'
        f'<svg viewBox="0 0 {view.width} {view.height}" preserveAspectRatio="none" '
        f'style="position:absolute;left:0;top:0;width:100%;height:100%">{map_svg(view, model, idx, picks)}</svg>'
        f"</div>"
        f'<div style="font-size:0.75em;opacity:0.85">{html.escape(name or model.labels[idx])}: map East-North of '
        f"{lat0:.5f} N, {lon0:.5f} E, north up, {view.m_per_px:.1f} m per pixel; {html.escape(view.dem_note)}"
        f"<br>{legend}</div></div>"
    )


# ---------------------------------------------------------------------------- the plots
def plot_series(scn, model) -> dict:
    """The plotted series, frame by frame: ``t`` (seconds from the first frame: the records' time
    stamps when every one is known and they increase, else the frame index, ``t_unit`` says
    which), and ``error`` [m], ``heights`` [m, ellipsoidal WGS 84], ``angles`` [deg] as
    ``{name: array}``."""
    n = len(model)
    t = np.asarray(getattr(scn, "record_times_s", None) if getattr(scn, "record_times_s", None) is not None else [])
    if len(t) == n and np.all(np.isfinite(t)) and (n < 2 or np.all(np.diff(t) > 0)):
        t, unit = t - t[0], "s"
    else:
        t, unit = np.arange(n, dtype=float), "frame"
    recs = [inp for _info, inp in scn.records[:n]]
    angles = {
        "heading": np.array([r.heading_deg for r in recs]),
        "pitch": np.array([r.pitch_deg for r in recs]),
        "roll": np.array([r.roll_deg for r in recs]),
    }
    names = list(dict.fromkeys(k for r in recs for k in r.angles_deg))
    for k in names:
        angles[k.replace("_", " ")] = np.array([r.angles_deg.get(k, np.nan) for r in recs], float)
    for k, v in list(angles.items()):
        # from (-180, 180], then unwrapped: a heading through north is a step of 360 otherwise
        v = (np.asarray(v, float) + 180.0) % 360.0 - 180.0
        ok = np.isfinite(v)
        if ok.sum() > 1:
            v[ok] = np.degrees(np.unwrap(np.radians(v[ok])))
        angles[k] = v
    err = {f"error to {model.reference} (horizontal)": np.asarray(model.residual_m, float)}
    heights = {
        "aircraft": np.array([r.h_m for r in recs], float),
        "recomputed point": np.asarray(model.recomputed_h_m, float),
    }
    if np.isfinite(model.truth_h_m).any():
        heights["truth"] = np.asarray(model.truth_h_m, float)
    return {"t": t, "t_unit": unit, "error": err, "heights": heights, "angles": angles}


class PlotView:
    """The plots' image and its time axis: the pixel column (0 at the image's left edge) of time
    ``t`` is ``x0_px + (t - t0) * px_per_t``; the axes span rows ``top_px`` .. ``bottom_px``."""

    def __init__(self, image, t0, x0_px, px_per_t, top_px, bottom_px, unit):
        self.image = image
        self.t0, self.x0_px, self.px_per_t = float(t0), float(x0_px), float(px_per_t)
        self.top_px, self.bottom_px, self.unit = float(top_px), float(bottom_px), unit
        self.b64 = _b64(image, "PNG")

    def t_to_px(self, t) -> float:
        return self.x0_px + (float(t) - self.t0) * self.px_per_t


#: Line colours of the plotted series (none of them the current frame's magenta).
SERIES_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#17becf", "#bcbd22")
#: The plots' figure size [px] and resolution.
PLOT_PX = (520, 620)
PLOT_DPI = 100


def build_plots(S: dict) -> PlotView:
    """Error, heights and angles against time, one axes each, sharing the time axis (matplotlib,
    drawn once per flight); gaps where a value is unknown (NaN)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    w, h = PLOT_PX
    fig = Figure(figsize=(w / PLOT_DPI, h / PLOT_DPI), dpi=PLOT_DPI)
    canvas = FigureCanvasAgg(fig)
    axs = fig.subplots(3, 1, sharex=True)
    t = S["t"]
    for ax, (group, title) in zip(
        axs,
        (("error", "error (m)"), ("heights", "heights (m, ellipsoidal WGS 84)"), ("angles", "angles (deg)")),
    ):
        for i, (name, y) in enumerate(S[group].items()):
            ax.plot(t, y, lw=1.0, color=SERIES_COLORS[i % len(SERIES_COLORS)], label=name)
        ax.set_title(title, fontsize=8, loc="left")
        ax.tick_params(labelsize=7)
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.legend(fontsize=6, loc="upper right", ncol=3, framealpha=0.7)
    axs[-1].set_xlabel("time from the first frame (s)" if S["t_unit"] == "s" else "frame index", fontsize=7)
    if len(t) > 1:
        axs[-1].set_xlim(float(t[0]), float(t[-1]))
    fig.subplots_adjust(left=0.11, right=0.98, top=0.96, bottom=0.07, hspace=0.3)
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    H = img.shape[0]
    # display coordinates: origin bottom-left; the image's rows run down
    xa, _ = axs[0].transData.transform((float(t[0]), 0.0))
    xb, _ = axs[0].transData.transform((float(t[-1]) if len(t) > 1 else float(t[0]) + 1.0, 0.0))
    span = (float(t[-1]) - float(t[0])) if len(t) > 1 else 1.0
    top = H - axs[0].get_window_extent().y1
    bottom = H - axs[-1].get_window_extent().y0
    return PlotView(img, t[0], xa, (xb - xa) / span, top, bottom, S["t_unit"])


def readout_json(S: dict) -> str:
    """The plotted values as compact JSON for the hover readout: ``t``, the frames' names and each
    series (rounded to 0.1 of its unit, ``null`` where unknown), ``[[group, name, unit, values], ...]``."""
    import json

    def r(v):
        return [None if not np.isfinite(x) else round(float(x), 1) for x in np.asarray(v, float)]

    units = {"error": "m", "heights": "m", "angles": "deg"}
    series = [[g, name, units[g], r(v)] for g in ("error", "heights", "angles") for name, v in S[g].items()]
    names = S.get("names") or [str(k) for k in range(len(S["t"]))]
    t = [round(float(x), 3) for x in np.asarray(S["t"], float)]  # the time axis, to the millisecond
    return json.dumps({"t": t, "names": names, "s": series}, separators=(",", ":"))


#: The hover readout (the plots' image is a picture: the values under the pointer come from the
#: page's own copy of the plotted series): the frame nearest the pointer's time, its name and values.
_READOUT_JS = (
    "var D=this._d||(this._d=JSON.parse(this.dataset.series));var b=this.getBoundingClientRect();"
    "var W=+this.dataset.width,x=(event.clientX-b.left)/b.width*W;"
    "var t=(x-this.dataset.x0Px)/this.dataset.pxPerT+(+this.dataset.t0);"
    "var k=0,best=1e300;for(var i=0;i<D.t.length;i++){var e=Math.abs(D.t[i]-t);if(e<best){best=e;k=i;}}"
    "var L=[D.names[k]];for(var j=0;j<D.s.length;j++){var v=D.s[j][3][k];"
    "if(v!==null)L.push(D.s[j][1]+': '+v.toFixed(1)+' '+D.s[j][2]);}"
    "var r=this.querySelector('.geoloc-plots-readout');r.textContent=L.join('\\n');r.dataset.frame=k;"
    "r.style.display='block';r.style.left=Math.min(event.clientX-b.left+12,b.width*0.45)+'px';"
    "r.style.top=(event.clientY-b.top+12)+'px';"
)


def plots_html(view: PlotView, t_current: float, idx: int, series_json: str = "") -> str:
    """The plots tab: the image, the cursor (an SVG line at the current frame's time) and, with
    ``series_json`` (:func:`readout_json`), a readout of the values at the pointer."""
    H, W = view.image.shape[:2]
    x = view.t_to_px(t_current)
    col = _hex(COLORS["current"])
    hover = (
        f'data-series="{html.escape(series_json, quote=True)}" '
        f'onmousemove="{html.escape(_READOUT_JS, quote=True)}" '
        "onmouseleave=\"this.querySelector('.geoloc-plots-readout').style.display='none'\" "
        if series_json
        else ""
    )
    return (
        f'<div style="padding:0 0.5em"><div id="geoloc-plots" style="position:relative;width:100%" '
        f'data-t0="{view.t0!r}" data-x0-px="{view.x0_px!r}" data-px-per-t="{view.px_per_t!r}" '
        f'data-width="{W}" data-height="{H}" data-frame="{idx}" data-t="{t_current!r}" {hover}>'
        f'<img alt="plots" src="data:image/png;base64,{view.b64}" style="width:100%;display:block">'
        '<div class="geoloc-plots-readout" style="display:none;position:absolute;pointer-events:none;'
        "white-space:pre;font-size:0.75em;background:rgba(20,20,20,0.85);color:#fff;padding:3px 6px;"
        'border-radius:3px;z-index:2"></div>'
        f'<svg viewBox="0 0 {W} {H}" preserveAspectRatio="none" '
        f'style="position:absolute;left:0;top:0;width:100%;height:100%">'
        f'<line id="geoloc-plots-cursor" x1="{x:.2f}" y1="{view.top_px:.1f}" x2="{x:.2f}" y2="{view.bottom_px:.1f}" '
        f'stroke="{col}" stroke-width="2"/></svg></div></div>'
    )


# ---------------------------------------------------------------------------- the layer
class PanelLayer:
    """The large panel of one session: picture, map and plots (module docstring)."""

    def __init__(self, session):
        self.session = session
        self.gui = session.gui
        self.closed = False
        self.panel = None
        self._lock = threading.RLock()
        self._mute = False
        self.view: MapView | None = None
        self._map_key = None
        self.plot_view: PlotView | None = None
        self._built: dict = {}  # what -> (monotonic time, frames) of its last drawing
        self._series = None
        self._series_key = None
        self.picture_key = None
        head = getattr(session, "md_summary", None)
        base = getattr(head, "order", None)
        order = None if base is None else float(base) + 0.004
        self.bt_open = self.gui.add_button(
            OPEN_LABEL,
            order=order,
            hint="A window beside the scene (drag it, float it, resize it): the frame at full resolution "
            "(click it to locate a pixel), a map of the flight on the DEM's hillshade, and plots against time",
        )
        self.bt_open.on_click(lambda _e: self._safe(self.toggle))
        session.on_refresh(lambda _g: self._safe(self.update), deferred=True)  # after the picture layer

    # -------------------------------------------------------------- plumbing
    def _safe(self, fn, *a):
        return None if self.closed else call_safely(fn, *a, what="the large panel", lock=self._lock)

    def _layer(self, cls):
        for obj in self.session.layers:
            if isinstance(obj, cls):
                return obj
        return None

    @property
    def flight(self):
        return self._layer(fl_mod.FlightLayer)

    @property
    def images(self):
        return self._layer(il_mod.ImageLayer)

    @property
    def is_open(self) -> bool:
        return self.panel is not None

    def toggle(self) -> None:
        self.close_panel() if self.is_open else self.open_panel()

    def open_panel(self) -> None:
        """Build the panel (docked on the left) and fill it for the current frame."""
        if self.is_open:
            return
        g = self.gui
        self.panel = g.add_panel()
        with self.panel.add_tab("Picture"):
            self.md_picture = g.add_markdown(
                "The frame at its own resolution: click a pixel to locate it (as in the sidebar's Picture)."
            )
            self.dd_size = g.add_dropdown(
                "picture size",
                PICTURE_SIZES,
                initial_value=PICTURE_SIZES[0],
                hint="Fit the panel's width, or one or two screen pixels per image pixel (the panel scrolls): "
                "at 1:1 a click can reach every pixel of a frame wider than the panel",
            )
            self.dd_size.on_update(lambda _e: self._safe(self._resize_picture))
            self.html_picture = g.add_html("<p>no picture for this scenario</p>")
            self.tx_pixel = g.add_text(
                "pixel clicked (row, col)",
                "",
                hint="row, col (1-based pixel centres): a click on the large picture writes it; type one to locate it",
            )
            self.tx_pixel.on_update(self._on_pixel_text)
        with self.panel.add_tab("Map"):
            self.dd_extent = g.add_dropdown(
                "map shows", MAP_EXTENTS, initial_value=MAP_EXTENTS[0], hint="Frame the whole flight or the ground seen"
            )
            self.dd_extent.on_update(lambda _e: self._safe(self._on_extent))
            self.html_map = g.add_html("<p>no flight to map</p>")
        with self.panel.add_tab("Plots"):
            self.md_plots = g.add_markdown("")
            self.html_plots = g.add_html("")
        self.panel.dock_left()
        self.panel.set_width(PANEL_WIDTH_PX)
        self.bt_open.label = CLOSE_LABEL
        self._map_key = self._series_key = self.picture_key = None
        self._built = {}
        self.update()

    def close_panel(self) -> None:
        if self.panel is not None:
            try:
                self.panel.remove()
            except Exception:  # the tab left
                pass
        self.panel = None
        self.bt_open.label = OPEN_LABEL

    def close(self) -> None:
        self.closed = True

    # -------------------------------------------------------------- updates
    def update(self) -> None:
        """Fill the open panel for the session's current frame."""
        if not self.is_open:
            return
        self.update_picture()
        self.update_map()
        self.update_plots()

    def _current(self):
        # the session's record is the frame (the flight layer's highlight moves after the refresh)
        fl = self.flight
        if fl is None:
            return None, None
        idx = self.session.scn.record_index
        if idx is None or not 0 <= idx < len(fl.model):
            idx = fl.current
        return (None, None) if idx is None else (fl.model, int(idx))

    # picture
    def update_picture(self) -> None:
        im = self.images
        if im is None or im.image is None:
            self.html_picture.content = "<p>no picture for this frame</p>"
            return
        marks = im._mark_list()
        key = (im.k, id(im.image), repr([(k, np.round(np.atleast_1d(r), 3).tolist()) for k, r, _c, _l in marks]))
        if key == self.picture_key:
            return
        self.picture_key = key
        M, N = im.image.shape[:2]
        size = 7.0 * max(1.0, N / 640.0)
        img = il_mod.draw_marks(im.image[..., :3], marks, lambda r, c: (c - 0.5, r - 0.5), size)
        uuid = self.tx_pixel._impl.uuid
        # a click: its position as a fraction of the shown image -> the pixel (1-based: pixel k spans
        # k - 1 .. k from the image's edge, its centre at k - 0.5), typed into this tab's pixel box as a person types
        # (React reads the native value setter's 'input' event); the server then locates it
        js = (
            "var b=this.getBoundingClientRect();"
            "var x=(event.clientX-b.left)/b.width,y=(event.clientY-b.top)/b.height;"
            f"var r=Math.floor(y*{M})+1,c=Math.floor(x*{N})+1;"
            "r=Math.min(Math.max(r,1),%d);c=Math.min(Math.max(c,1),%d);"
            f"var l=document.querySelector('label[for=\"{uuid}\"]');if(!l)return;"
            "var p=l.parentElement;while(p&&!p.querySelector('input'))p=p.parentElement;if(!p)return;"
            "var i=p.querySelector('input');"
            "Object.getOwnPropertyDescriptor(HTMLInputElement.prototype,'value').set.call(i,r+', '+c);"
            "i.dispatchEvent(new Event('input',{bubbles:true}));"
        ) % (M, N)
        # the sidebar picture's caption: the frame's one name (the timeline's index), not the video's count
        cap = f"{im.caption()}, every pixel shown"
        self._picture_parts = (M, N, _b64(img, "JPEG", 92), js, cap)
        self._resize_picture()

    def _resize_picture(self) -> None:
        """The large picture's HTML at the chosen size (no new JPEG: the size is CSS)."""
        parts = getattr(self, "_picture_parts", None)
        if parts is None or not self.is_open:
            return
        M, N, b64, js, cap = parts
        size = str(self.dd_size.value)
        k = {"1:1": 1, "2:1": 2}.get(size)
        width = "100%" if k is None else f"{N * k}px;max-width:none"
        self.html_picture.content = (
            f'<div style="padding:0 0.5em"><div style="overflow:auto;max-height:80vh">'
            f'<img id="geoloc-picture-large" alt="frame image, full resolution" '
            f'data-rows="{M}" data-cols="{N}" src="data:image/jpeg;base64,{b64}" '
            f'style="width:{width};display:block;cursor:crosshair;image-rendering:pixelated" '
            f'onclick="{html.escape(js, quote=True)}"></div>'
            f'<div style="font-size:0.75em;opacity:0.8">{html.escape(cap)}; shown {html.escape(size)}</div></div>'
        )

    def _on_pixel_text(self, event=None) -> None:
        if self.closed or own_update(self, event):
            return
        rc = il_mod.parse_pixel(str(self.tx_pixel.value))
        im = self.images
        if rc is not None and im is not None:
            # the sidebar picture's own path: the same ray, hit, text and pick listeners
            im._safe(im.pick_pixel, *rc)
            self._safe(self.update)

    def _due(self, what: str, model) -> bool:
        """Whether the map's or the plots' drawing may be redone now: at once for another flight
        (another number of frames aside), at most every :data:`REBUILD_S` seconds for a flight whose
        number of frames changed (a live window growing or sliding)."""
        import time

        now = time.monotonic()
        last = self._built.get(what)  # (monotonic time, frames) of the last drawing
        if what == "map" and self.view is not None:
            moved = not np.allclose(self.view.enu.origin_ecef, model.enu.origin_ecef)
        else:
            moved = False
        if last is not None and last[1] != len(model) and not moved and now - last[0] < REBUILD_S:
            return False
        self._built[what] = (now, len(model))
        return True

    def _on_extent(self) -> None:
        if self.is_open:
            self.update_map()

    # map
    def _picks_enu(self, model):
        im = self.images
        out = []
        if im is None:
            return out
        if im.pick is not None and im.pick.ok:
            h = im.pick.hit
            out.append(("pick", model.enu.from_geodetic(float(h.lat), float(h.lon), float(h.h))))
        g = im.ground
        if g is not None and g.ok:
            out.append(("ground", model.enu.from_geodetic(float(g.hit.lat), float(g.hit.lon), float(g.hit.h))))
        return out

    def update_map(self) -> None:
        model, idx = self._current()
        if model is None:
            self.html_map.content = "<p>one record: no flight to map</p>"
            return
        extent = str(self.dd_extent.value)
        key = (id(model), len(model), extent)
        if key != self._map_key and (self.view is None or self.view.extent != extent or self._due("map", model)):
            dem = self.session.scn.dem if self.session.scn.use_dem else None
            self.view = build_map(model, dem, extent=extent)
            self._map_key = key
        assert self.view is not None  # the key is set only once a map is drawn
        from geoloc_viz.model import frame_name

        name = frame_name(self.session.scn, idx, of=False)  # the one name, as the timeline gives it
        self.html_map.content = map_html(self.view, model, idx, self._picks_enu(model), name=name)

    # plots
    def update_plots(self) -> None:
        model, idx = self._current()
        if model is None:
            self.md_plots.content = "one record: nothing to plot against time"
            self.html_plots.content = ""
            return
        key = (id(model), len(model))
        # drawn at once when there are none yet (a first drawing that failed leaves none)
        if key != self._series_key and (self.plot_view is None or self._due("plots", model)):
            self._series = plot_series(self.session.scn, model)
            self._series["labels"] = list(model.labels)
            from geoloc_viz.model import frame_name

            scn = self.session.scn
            self._series["names"] = [frame_name(scn, k, of=False) for k in range(len(self._series["t"]))]
            self.plot_view = build_plots(self._series)
            self._readout = readout_json(self._series)
            self._series_key = key
        assert self.plot_view is not None  # the key is set only once the plots are drawn
        S = self._series
        label = model.labels[idx]
        # the plotted frame of this label (a live window may have moved on since the plots were drawn;
        # a frame newer than the plots sits at their right edge until the next redraw)
        plotted = label in S["labels"]
        k = S["labels"].index(label) if plotted else len(S["t"]) - 1
        tc = float(S["t"][k])
        from geoloc_viz.model import frame_name

        when = (
            "the magenta line is the current frame; point at the plots to read a frame's values"
            if plotted
            else f"newer than the plots (redrawn every {REBUILD_S:g} s), cursor at their end"
        )
        self.md_plots.content = f"**{frame_name(self.session.scn, idx)}**: {when}"
        self.html_plots.content = plots_html(self.plot_view, tc, idx, getattr(self, "_readout", ""))


def attach(session) -> PanelLayer:
    """The large panel's button in every session (the panel opens on demand)."""
    return PanelLayer(session)
