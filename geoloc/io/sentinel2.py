"""Sentinel-2 L1B geometry: the datastrip and granule metadata, the GIPP files, the IERS file.

User guide: ``docs/sentinel2.md``. Conventions: ``docs/conventions.md``.

An L1B product (ESA's Sentinel-2 Products Specification Document, PSD 15) holds, per
datastrip, the GPS orbit (``GPS_Points_List``: ITRF position and velocity in mm and mm/s, GPS
time), the attitude (``Corrected_Attitudes``: quaternions EME2000 -> piloting frame, vector
part first, GPS time), the line dating (``Time_Stamp``: the 10 m line period and, per band and
detector, the GPS time of the first line) and optionally the refining corrections that the
ground segment fitted (``Refined_Corrections``: polynomials in time of a rotation of the MSI
frame). The GIPP files add each detector pixel's viewing direction (``GIP_VIEDIR``: tan psi_x,
tan psi_y per pixel) and the instrument's mounting (``GIP_SPAMOD``: piloting frame -> MSI ->
focal plane -> detector, small rotations in mrad). :func:`read_product` reads them into a
:class:`Sentinel2Product`; :meth:`Sentinel2Product.sensor` builds the pushbroom sensor of one
band and detector (:class:`geoloc.sensors.pushbroom_inertial.InertialPushbroomSensor`).

The geometry follows ESA's Sen2VM (Apache-2.0, github.com/sen2vm/sen2vm-core), whose ideas,
not code, are taken: the first line's date is its GPS time plus half a line period (the middle
of the integration), the line period of a band is the 10 m one times its pixel size / 10 m,
refining polynomials count seconds from the datastrip's middle (UTC start and stop).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from defusedxml import ElementTree as ET

from geoloc.userfiles import note_input

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from geoloc.frames.earth import EarthOrientation
    from geoloc.sensors.pushbroom_inertial import InertialPushbroomSensor

#: band name -> (band index in the metadata, pixel size [m], focal plane)
BANDS = {
    "B01": (0, 60, "VNIR"),
    "B02": (1, 10, "VNIR"),
    "B03": (2, 10, "VNIR"),
    "B04": (3, 10, "VNIR"),
    "B05": (4, 20, "VNIR"),
    "B06": (5, 20, "VNIR"),
    "B07": (6, 20, "VNIR"),
    "B08": (7, 10, "VNIR"),
    "B8A": (8, 20, "VNIR"),
    "B09": (9, 60, "VNIR"),
    "B10": (10, 60, "SWIR"),
    "B11": (11, 20, "SWIR"),
    "B12": (12, 20, "SWIR"),
}
#: the bands whose viewing directions depend on the TDI configuration (a list per setting)
TDI_BANDS = ("B03", "B04", "B11", "B12")
#: mrad -> rad
MRAD = 1e-3


def _bad(where, field_name, value, why):
    raise ValueError(f"{where}: {field_name} = {value!r}: {why}")


def band_info(band: str) -> tuple[str, int, int, str]:
    """(index, pixel size [m], focal plane) of ``band`` ("B02", "B8A", ...), or ValueError naming it."""
    b = str(band).upper()
    if re.fullmatch(r"B\d", b):
        b = "B0" + b[1]
    if b not in BANDS:
        raise ValueError(f"band = {band!r}: not a Sentinel-2 band ({', '.join(BANDS)})")
    return (b, *BANDS[b])


def detector_id(detector: int | str) -> str:
    """'01'..'12' from 1..12 or '1'..'12' or 'D04', or ValueError naming it."""
    s = str(detector).upper().lstrip("D")
    if not s.isdigit() or not 1 <= int(s) <= 12:
        raise ValueError(f"detector = {detector!r}: must be 1..12")
    return f"{int(s):02d}"


def gps_time(text: str, where: str = "") -> np.datetime64:
    """An ISO date of the metadata (GPS or UTC, 'Z' ignored) -> datetime64[ns]."""
    s = str(text).strip().rstrip("Z")
    try:
        return np.datetime64(s, "ns")
    except ValueError:
        raise ValueError(f"{where}: {s!r} is not an ISO date") from None


def _floats(text, n=None, where=""):
    try:
        v = np.array([float(x) for x in str(text).split()])
    except ValueError:
        raise ValueError(f"{where}: {str(text)[:60]!r} is not a list of numbers") from None
    if n is not None and v.size != n:
        raise ValueError(f"{where}: expected {n} numbers, got {v.size}")
    return v


def _find(root, path, where):
    el = root.find(path)
    if el is None:
        raise ValueError(f"{where}: missing element {path}")
    return el


def _strip_ns(root):
    for el in root.iter():
        if isinstance(el.tag, str) and "}" in el.tag:
            el.tag = el.tag.split("}", 1)[1]
    return root


def _parse(path: Path, what: str):
    note_input(path)
    try:
        return _strip_ns(ET.parse(str(path)).getroot())
    except ET.ParseError as e:
        raise ValueError(f"{path}: not a readable {what} XML file ({e})") from None


# ------------------------------------------------------------------ the datastrip
@dataclass(frozen=True)
class Refining:
    """Refining corrections of the datastrip (``Refined_Corrections``), polynomials in seconds
    from ``t_centre`` (the datastrip's middle).

    ``msi_rotation`` holds the coefficients (lowest degree first) of the rotation angles about
    X, Y, Z [rad] added to the piloting -> MSI rotation (``MSI_State``); ``msi_homothety_z`` the
    relative scale of the MSI frame's Z (focal length); ``focal_plane`` the same two terms of
    the MSI -> focal plane rotation, per focal plane (``Focal_Plane_State``, ``focalPlaneId``
    VNIR or SWIR: ``{"VNIR": (rotation, homothety_z)}``, empty where the product gives none);
    ``position`` the ``Spacecraft_Position`` polynomials X, Y, Z [m] "in the local spacecraft
    reference frame" (the product format names no axes for it: the sensor refuses a product
    that carries them, rather than guess; None where the product gives none).
    """

    t_centre: np.datetime64  # GPS
    msi_rotation: tuple = ((0.0,), (0.0,), (0.0,))
    msi_homothety_z: tuple = (0.0,)
    position: tuple | None = None
    focal_plane: dict = field(default_factory=dict)

    def angles(self, t_s_from_centre: ArrayLike) -> np.ndarray:
        """Rotation angles about X, Y, Z [rad] at seconds from the centre (..., 3)."""
        t = np.asarray(t_s_from_centre, float)
        return np.stack([np.polynomial.polynomial.polyval(t, c) for c in self.msi_rotation], axis=-1)

    def homothety(self, t_s_from_centre: ArrayLike) -> np.ndarray:
        return np.polynomial.polynomial.polyval(np.asarray(t_s_from_centre, float), self.msi_homothety_z)


@dataclass(frozen=True)
class Datastrip:
    """What the L1B datastrip metadata says about the geometry (times as datetime64[ns], GPS scale).

    Attributes
    ----------
    path : Path
    orbit_t : ndarray (K,) datetime64
    orbit_position_itrf, orbit_velocity_itrf : ndarray (K, 3)
        GPS points in ITRF [m], [m/s].
    attitude_t : ndarray (M,) datetime64
    q_eme2000_to_piloting : ndarray (M, 4)
        Corrected attitude quaternions, scalar FIRST here (the file puts it last).
    line_period_10m_s : float
    first_line : dict
        (band index, detector id) -> (reference line, GPS time of that line's start).
    granules : dict
        detector id -> list of (granule id, position in 10 m lines, 1-based).
    sensing_start_utc, sensing_stop_utc : datetime64
    refining : Refining or None
    iers : tuple
        The datastrip's own IERS bulletin values: (UT1-UTC [s], pole x [arcsec], pole y [arcsec]).
    aocs_t, aocs_position, aocs_velocity : ndarray
        The on-board (AOCS) ephemeris, inertial: a check of the frames, not used to locate.
    """

    path: Path
    orbit_t: np.ndarray
    orbit_position_itrf: np.ndarray
    orbit_velocity_itrf: np.ndarray
    attitude_t: np.ndarray
    q_eme2000_to_piloting: np.ndarray
    line_period_10m_s: float
    first_line: dict
    granules: dict
    sensing_start_utc: np.datetime64
    sensing_stop_utc: np.datetime64
    refining: Refining | None
    iers: tuple
    aocs_t: np.ndarray = field(default_factory=lambda: np.zeros(0, "datetime64[ns]"))
    aocs_position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    aocs_velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def line_period_s(self, band: str) -> float:
        """A band's line period: the 10 m period times pixel size / 10 m."""
        _, _, size, _ = band_info(band)
        return self.line_period_10m_s * size / 10.0

    def first_line_time(self, band: str, detector: int | str) -> np.datetime64:
        """The date of line 1's centre (its GPS time stamp plus half a line period) of a band/detector."""
        b, idx, size, _ = band_info(band)
        det = detector_id(detector)
        key = (idx, det)
        if key not in self.first_line:
            raise ValueError(f"{self.path}: no Time_Stamp for band {b} detector {det}")
        ref_line, t = self.first_line[key]
        period = self.line_period_s(b)
        # a reference line other than 1 is in 10 m lines: move to line 1 of this band
        lines_back = (ref_line - 1) * 10.0 / size
        return t + np.timedelta64(int(round((0.5 - lines_back) * period * 1e9)), "ns")


def _poly(el, where):
    if el is None:
        return None
    c = el.find("COEFFICIENTS")
    if c is None:
        raise ValueError(f"{where}: polynomial without COEFFICIENTS")
    return tuple(_floats(c.text, where=where).tolist())


def read_datastrip(path: str | Path) -> Datastrip:
    """Read an L1B datastrip metadata file (``S2?_OPER_MTD_L1B_DS_*.xml``).

    Raises ValueError naming the file and the element for a missing or malformed one.
    """
    path = Path(path)
    w = str(path)
    root = _parse(path, "Sentinel-2 L1B datastrip metadata")
    ti = _find(root, "General_Info/Datastrip_Time_Info", w)
    start = gps_time(_find(ti, "DATASTRIP_SENSING_START", w).text, w)
    stop = gps_time(_find(ti, "DATASTRIP_SENSING_STOP", w).text, w)
    t, p, v = _ds_orbit(root, w)
    ta, qa = _ds_attitudes(root, w)
    period, first = _ds_line_timing(root, w)
    at_, ap, av = _ds_aocs(root, w)
    return Datastrip(
        path=path,
        orbit_t=t,
        orbit_position_itrf=p,
        orbit_velocity_itrf=v,
        attitude_t=ta,
        q_eme2000_to_piloting=qa,
        line_period_10m_s=period,
        first_line=first,
        granules=_ds_granules(root, w),
        sensing_start_utc=start,
        sensing_stop_utc=stop,
        refining=_ds_refining(root, w, start, stop),
        iers=_ds_iers(root),
        aocs_t=at_,
        aocs_position=ap,
        aocs_velocity=av,
    )


def _first_of_each_time(t: np.ndarray) -> np.ndarray:
    """True at each sorted date's first entry (a repeated date's later entries dropped)."""
    return np.concatenate([[True], np.diff(t) > np.timedelta64(0, "ns")])


def _ds_orbit(root, w: str):
    """The dated GPS points of the ephemeris (dates, ITRF position and velocity [km, km/s]) in
    time order, a repeated date's first kept; an undated point skipped; at least 4."""
    eph = _find(root, "Satellite_Ancillary_Data_Info/Ephemeris", w)
    t: Any = []  # the GPS dates, then their array
    p: Any = []
    v: Any = []
    for i, pt in enumerate(eph.iter("GPS_Point")):
        wi = f"{w}: GPS_Point {i + 1}"
        gt = pt.find("GPS_TIME")
        if gt is None or not (gt.text or "").strip():
            continue  # Sen2VM skips an undated point too
        t.append(gps_time(gt.text, wi))
        p.append(_floats(_find(pt, "POSITION_VALUES", wi).text, 3, wi) / 1000.0)
        v.append(_floats(_find(pt, "VELOCITY_VALUES", wi).text, 3, wi) / 1000.0)
    if len(t) < 4:
        _bad(w, "GPS_Points_List", len(t), "needs at least 4 dated GPS points")
    t = np.array(t)
    order = np.argsort(t, kind="stable")
    t, p, v = t[order], np.array(p)[order], np.array(v)[order]
    keep = _first_of_each_time(t)  # duplicates: the first kept
    return t[keep], p[keep], v[keep]


def _ds_attitudes(root, w: str):
    """The corrected attitudes: dates and unit quaternions EME2000 -> piloting (scalar first) in
    time order, a repeated date's first kept; a norm off 1 by 1e-3 refused; at least 4."""
    att = _find(root, "Satellite_Ancillary_Data_Info/Attitudes/Corrected_Attitudes", w)
    ta: Any = []  # the quaternions' dates, then their array
    qa: Any = []
    for i, val in enumerate(att.iter("Values")):
        wi = f"{w}: Corrected_Attitudes Values {i + 1}"
        ta.append(gps_time(_find(val, "GPS_TIME", wi).text, wi))
        q = _floats(_find(val, "QUATERNION_VALUES", wi).text, 4, wi)
        n = np.linalg.norm(q)
        if not abs(n - 1.0) < 1e-3:
            _bad(wi, "QUATERNION_VALUES", q.tolist(), f"norm {n:.6f} is not 1")
        qa.append(np.r_[q[3], q[:3]] / n)
    if len(ta) < 4:
        _bad(w, "Corrected_Attitudes", len(ta), "needs at least 4 quaternions")
    ta = np.array(ta)
    oa = np.argsort(ta, kind="stable")
    ta, qa = ta[oa], np.array(qa)[oa]
    keep_a = _first_of_each_time(ta)
    return ta[keep_a], qa[keep_a]


def _ds_line_timing(root, w: str):
    """The 10 m line period [s] (about 1.5 ms) and each (band, detector)'s reference line and its date."""
    ts = _find(root, "Image_Data_Info/Sensor_Configuration/Time_Stamp", w)
    lp = _find(ts, "LINE_PERIOD", w)
    period = float(lp.text) * (1e-3 if lp.get("unit", "ms") == "ms" else 1.0)
    if not 1e-4 < period < 1e-1:
        _bad(w, "LINE_PERIOD", lp.text, "must be a line period of about 1.5 ms")
    first = {}
    for bts in ts.iter("Band_Time_Stamp"):
        b = int(bts.get("bandId"))
        for det in bts.iter("Detector"):
            d = detector_id(det.get("detectorId"))
            wi = f"{w}: Band_Time_Stamp {b} Detector {d}"
            first[(b, d)] = (int(_find(det, "REFERENCE_LINE", wi).text), gps_time(_find(det, "GPS_TIME", wi).text, wi))
    return period, first


def _ds_granules(root, w: str) -> dict:
    """Each detector's granules, (granule id, first line) in line order."""
    granules = {}
    for det in root.iterfind("Image_Data_Info/Granules_Information/Detector_List/Detector"):
        d = detector_id(det.get("detectorId"))
        granules[d] = sorted(
            ((g.get("granuleId"), int(_find(g, "POSITION", w).text)) for g in det.iter("Granule")), key=lambda x: x[1]
        )
    return granules


def _ds_refining(root, w: str, start, stop) -> Refining | None:
    """The refined corrections' polynomials (MSI rotation and homothety, spacecraft position, each
    focal plane's), counting seconds from the datastrip's middle; None unless flagged REFINED."""
    ir = root.find("Image_Data_Info/Geometric_Info/Image_Refining")
    if ir is None or (ir.get("flag") or "").upper() != "REFINED":
        return None
    rc = root.find("Image_Data_Info/Geometric_Info/Refined_Corrections_List/Refined_Corrections")
    from geoloc.frames.earth import utc_to_gps

    # the polynomials count seconds from the datastrip's middle, its start and stop being UTC
    centre = utc_to_gps(start + (stop - start) / 2)
    rot = [(0.0,), (0.0,), (0.0,)]
    hom = (0.0,)
    pos = None
    focal: dict = {}
    if rc is not None:
        msi = rc.find("MSI_State")
        if msi is not None:
            r = msi.find("Rotation")
            if r is not None:
                rot = [_poly(r.find(a), f"{w}: MSI_State Rotation {a}") or (0.0,) for a in "XYZ"]
            h = msi.find("Homothety/Z")
            hom = _poly(h, f"{w}: MSI_State Homothety Z") or (0.0,)
        sp = rc.find("Spacecraft_Position")
        if sp is not None and len(sp):
            pos = tuple(_poly(sp.find(a), f"{w}: Spacecraft_Position {a}") or (0.0,) for a in "XYZ")
        focal = _ds_focal_planes(rc, w)
    return Refining(cast(np.datetime64, centre), tuple(rot), hom, pos, focal)


def _ds_focal_planes(rc, w: str) -> dict:
    """Each focal plane's refined rotation and homothety polynomials, by name (VNIR, SWIR)."""
    focal = {}
    for fp in rc.iter("Focal_Plane_State"):
        if not len(fp):
            continue
        name = (fp.get("focalPlaneId") or "").upper()
        wf = f"{w}: Focal_Plane_State {name}"
        if name not in ("VNIR", "SWIR"):
            raise ValueError(f"{wf}: focalPlaneId = {fp.get('focalPlaneId')!r}: must be VNIR or SWIR")
        r = fp.find("Rotation")
        frot = (
            tuple(_poly(r.find(a), f"{wf} Rotation {a}") or (0.0,) for a in "XYZ")
            if r is not None
            else ((0.0,), (0.0,), (0.0,))
        )
        fh = _poly(fp.find("Homothety/Z"), f"{wf} Homothety Z") or (0.0,)
        focal[name] = (frot, fh)
    return focal


def _ds_iers(root) -> tuple:
    """The IERS bulletin's UT1 - UTC and pole angles, NaN without a bulletin."""
    ib = root.find("Auxiliary_Data_Info/IERS_Bulletin")
    if ib is None:
        return (np.nan, np.nan, np.nan)
    return (float(ib.find("UT1_UTC").text), float(ib.find("POLE_U_ANGLE").text), float(ib.find("POLE_V_ANGLE").text))


def _ds_aocs(root, w: str):
    """The on-board (AOCS) ephemeris, dates, positions, velocities; an unreadable entry skipped
    (it is only a check)."""
    at_, ap, av = [], [], []
    for e in root.iterfind("Satellite_Ancillary_Data_Info/Ephemeris/AOCS_Ephemeris_List/AOCS_Ephemeris"):
        try:
            at_.append(gps_time(e.find("GPS_TIME").text, w))
            ap.append(_floats(e.find("POSITION_VALUES").text, 3, w))
            av.append(_floats(e.find("VELOCITY_VALUES").text, 3, w))
        except (AttributeError, ValueError):
            continue  # the on-board ephemeris is only a check
    return np.array(at_, "datetime64[ns]"), np.array(ap).reshape(-1, 3), np.array(av).reshape(-1, 3)


# ------------------------------------------------------------------ granules
@dataclass(frozen=True)
class Granule:
    """One L1B granule: a detector's block of lines (``S2?_OPER_MTD_L1B_GR_*.xml``)."""

    granule_id: str
    detector: str
    position: int  # first line, in 10 m lines, 1-based
    size: dict  # pixel size [m] -> (rows, cols)
    path: Path | None = None

    def first_row(self, band: str) -> int:
        """The granule's first row in the band's lines of its detector (1-based)."""
        _, _, size, _ = band_info(band)
        return (self.position - 1) * 10 // size + 1

    def shape(self, band: str) -> tuple:
        _, _, size, _ = band_info(band)
        if size not in self.size:
            raise ValueError(f"{self.path}: no Granule_Dimensions for {size} m")
        return self.size[size]


def read_granule(path: str | Path) -> Granule:
    path = Path(path)
    w = str(path)
    root = _parse(path, "Sentinel-2 L1B granule metadata")
    gid = _find(root, "General_Info/GRANULE_ID", w).text.strip()
    det = detector_id(_find(root, "General_Info/DETECTOR_ID", w).text)
    pos = int(_find(root, "Geometric_Info/Granule_Position/POSITION", w).text)
    size = {}
    for s in root.iterfind("Geometric_Info/Granule_Dimensions/Size"):
        size[int(s.get("resolution"))] = (int(_find(s, "NROWS", w).text), int(_find(s, "NCOLS", w).text))
    return Granule(gid, det, pos, size, path)


# ------------------------------------------------------------------ GIPP
def read_viewing_directions(path: str | Path, tdi: str | None = None) -> dict:
    """A ``GIP_VIEDIR`` file -> {detector id: (N, 2) array of (tan psi_x, tan psi_y)}, and the band index.

    ``tdi``: the TDI configuration to pick where the file has one list per setting (bands 3, 4,
    11, 12); the first list otherwise.
    """
    path = Path(path)
    w = str(path)
    root = _parse(path, "Sentinel-2 GIPP viewing directions")
    band = int(_find(root, "DATA/BAND_ID", w).text)
    lists = root.findall("DATA/VIEWING_DIRECTIONS_LIST")
    if not lists:
        raise ValueError(f"{w}: missing element DATA/VIEWING_DIRECTIONS_LIST")
    chosen = lists[0]
    if tdi is not None:
        match = [x for x in lists if x.get("tdi_config") == tdi]
        if not match:
            _bad(w, "tdi_config", tdi, f"no list for it (the file has {[x.get('tdi_config') for x in lists]})")
        chosen = match[0]
    out = {}
    for vd in chosen.iter("VIEWING_DIRECTIONS"):
        d = detector_id(vd.get("detector_id"))
        wi = f"{w}: detector {d}"
        n = int(_find(vd, "NB_OF_PIXELS", wi).text)
        tx = _floats(_find(vd, "TAN_PSI_X_LIST", wi).text, n, wi + " TAN_PSI_X_LIST")
        ty = _floats(_find(vd, "TAN_PSI_Y_LIST", wi).text, n, wi + " TAN_PSI_Y_LIST")
        out[d] = np.stack([tx, ty], axis=-1)
    return {"band": band, "detectors": out}


def _rotation_el(el, where):
    """(angles about the axes [rad], axes) of an R1/R2/R3 element triple."""
    angles, axes = [], []
    for r in ("R1", "R2", "R3"):
        e = _find(el, r, where)
        unit = e.get("unit", "mrad")
        scale = {"mrad": MRAD, "rad": 1.0, "deg": np.pi / 180, "microrad": 1e-6, "urad": 1e-6}.get(unit)
        if scale is None:
            _bad(where, f"{r} unit", unit, "must be rad, mrad, urad or deg")
        angles.append(float(e.text) * scale)
        axes.append(e.get("axis", "XYZ"[len(axes)]).upper())
    return tuple(angles), tuple(axes)


def read_spacecraft_model(path: str | Path) -> dict:
    """A ``GIP_SPAMOD`` file -> {"piloting_to_msi": (angles, axes, scale), "msi_to_focal_plane":
    {"VNIR": ..., "SWIR": ...}, "focal_plane_to_detector": {("VNIR", "01"): (angles, axes), ...}}."""
    path = Path(path)
    w = str(path)
    root = _parse(path, "Sentinel-2 GIPP spacecraft model")
    data = _find(root, "DATA", w)
    p2m = _find(data, "PILOTING_TO_MSI_FRAME", w)
    out: dict[str, Any] = {
        "piloting_to_msi": (*_rotation_el(p2m, w + " PILOTING_TO_MSI_FRAME"), float(p2m.findtext("SCALE_FACTOR", "1")))
    }
    fp = {}
    for name in ("VNIR", "SWIR"):
        el = data.find(f"MSI_TO_FOCAL_PLANE/MSI_TO_{name}")
        if el is not None:
            fp[name] = (*_rotation_el(el, f"{w} MSI_TO_{name}"), float(el.findtext("SCALE_FACTOR", "1")))
    out["msi_to_focal_plane"] = fp
    det = {}
    for name in ("VNIR", "SWIR"):
        for el in data.iterfind(f"FOCAL_PLANE_TO_DETECTOR/FOCAL_PLANE_TO_DETECTOR_{name}"):
            det[(name, detector_id(el.get("detector_id")))] = _rotation_el(el, f"{w} detector {el.get('detector_id')}")
    out["focal_plane_to_detector"] = det
    return out


# ------------------------------------------------------------------ IERS
def read_ut1utc(path: str | Path) -> EarthOrientation:
    """An IERS Bulletin A text file (Sentinel-2's ``AUX_UT1UTC``) -> EarthOrientation.

    Reads the rows of the "COMBINED EARTH ORIENTATION PARAMETERS" table
    (``YY MM DD MJD x err y err UT1-UTC err``) and of the predictions table
    (``YYYY MM DD MJD x y UT1-UTC``); a day in both keeps the first (the measured value).
    """
    from geoloc.frames.earth import EarthOrientation

    path = Path(path)
    note_input(path)
    try:
        text = path.read_text(encoding="latin-1")
    except OSError as e:
        raise ValueError(f"{path}: cannot read the IERS file ({e.strerror})") from None
    rows: dict[int, tuple[float, float, float]] = {}
    combined = re.compile(
        r"^\s*(\d{2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{5})\s+([-\d.]+)\s+[\d.]+\s+([-\d.]+)\s+[\d.]+\s+([-\d.]+)\s+[\d.]+\s*$"
    )
    predicted = re.compile(r"^\s*(\d{4})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{5})\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s*$")
    for line in text.splitlines():
        m = combined.match(line) or predicted.match(line)
        if m:
            rows.setdefault(int(m.group(4)), (float(m.group(5)), float(m.group(6)), float(m.group(7))))
    if not rows:
        raise ValueError(f"{path}: no Bulletin A rows (YY MM DD MJD x y UT1-UTC) found")
    days = sorted(rows)
    vals = np.array([rows[k] for k in days])
    return EarthOrientation(np.array(days, float), vals[:, 2], vals[:, 0], vals[:, 1], source=str(path))


# ------------------------------------------------------------------ the product
def _one(paths, what, where):
    paths = sorted(paths)
    if not paths:
        raise ValueError(f"{where}: no {what} found")
    return paths[0]


@dataclass(frozen=True)
class Sentinel2Product:
    """An L1B product's geometry: datastrip, granules, GIPP viewing directions and spacecraft
    model, Earth orientation (:func:`read_product`)."""

    path: Path
    datastrip: Datastrip
    granules: dict  # granule id -> Granule
    gipp_dir: Path
    spacecraft_model: dict
    eop: EarthOrientation
    eop_source: str
    _viedir: dict = field(default_factory=dict, repr=False, compare=False)

    def granule(self, detector: int | str, which: int | str | None = None) -> Granule:
        """A detector's granule: ``which`` an id, a 1-based index along the datastrip, or None (the first)."""
        det = detector_id(detector)
        mine = sorted((g for g in self.granules.values() if g.detector == det), key=lambda g: g.position)
        if not mine:
            raise ValueError(f"{self.path}: no granule metadata for detector {det}")
        if which is None:
            return mine[0]
        if isinstance(which, int):
            if not 1 <= which <= len(mine):
                raise ValueError(f"granule = {which}: detector {det} has granules 1..{len(mine)}")
            return mine[which - 1]
        for g in mine:
            if g.granule_id == which:
                return g
        raise ValueError(f"granule = {which!r}: not a granule of detector {det} in {self.path}")

    def viewing_directions(self, band: str, detector: int | str) -> np.ndarray:
        """(N, 2) tan psi_x, tan psi_y of a band and detector, from the band's GIP_VIEDIR file."""
        b, idx, _, _ = band_info(band)
        det = detector_id(detector)
        if b not in self._viedir:
            files = [p for p in self.gipp_dir.glob("*GIP_VIEDIR*") if p.suffix.lower() in (".xml", ".dbl")]
            files = [p for p in files if re.search(rf"_B{b[1:]}\.", p.name)]
            f = _one(files, f"GIP_VIEDIR file for {b}", str(self.gipp_dir))
            tdi = None
            if b in TDI_BANDS:
                tdi = self.datastrip_tdi.get(idx)
            self._viedir[b] = read_viewing_directions(f, tdi)
        vd = self._viedir[b]
        if det not in vd["detectors"]:
            raise ValueError(f"{self.gipp_dir}: the {b} viewing directions have no detector {det}")
        return vd["detectors"][det]

    @property
    def datastrip_tdi(self) -> dict:
        root = _parse(self.datastrip.path, "Sentinel-2 L1B datastrip metadata")
        out = {}
        for el in root.iterfind(
            "Image_Data_Info/Sensor_Configuration/Acquisition_Configuration/TDI_Configuration_List/TDI_CONFIGURATION"
        ):
            out[int(el.get("bandId"))] = el.text.strip()
        return out

    def sensor(self, band: str, detector: int | str, *, refining: bool = True) -> InertialPushbroomSensor:
        """The pushbroom sensor of a band and detector over the whole datastrip (rows: all its lines).

        Row 1 is the detector's first line in the datastrip; a granule's rows start at
        :meth:`Granule.first_row`. ``refining=False`` ignores the product's refining corrections.
        """
        from geoloc.frames.earth import EarthRotationTable
        from geoloc.sensors.pushbroom import LookAngles, Orbit
        from geoloc.sensors.pushbroom_inertial import InertialPushbroomSensor, R_small

        b, idx, size, plane = band_info(band)
        det = detector_id(detector)
        ds = self.datastrip
        epoch = ds.orbit_t[0]

        def secs(t):
            return (np.asarray(t, "datetime64[ns]") - epoch).astype(np.int64) * 1e-9

        orbit = Orbit(secs(ds.orbit_t), ds.orbit_position_itrf, ds.orbit_velocity_itrf)
        ta = secs(ds.attitude_t)
        period = ds.line_period_s(b)
        t0 = float(secs(ds.first_line_time(b, det)))
        mine = [g for g in self.granules.values() if g.detector == det]
        if mine:
            last = max(mine, key=lambda g: g.position)
            rows = last.first_row(b) - 1 + last.shape(b)[0]
        else:
            rows = int((min(orbit.span[1], ta[-1]) - t0) / period)
        look = self.viewing_directions(b, det)
        sm = self.spacecraft_model
        ang, axes, _ = sm["piloting_to_msi"]
        R_msi_pil = R_small(ang, axes)
        R_fp_msi = np.eye(3)
        if plane in sm["msi_to_focal_plane"]:
            a2, ax2, _ = sm["msi_to_focal_plane"][plane]
            R_fp_msi = R_small(a2, ax2)
        R_det_fp = np.eye(3)
        if (plane, det) in sm["focal_plane_to_detector"]:
            a3, ax3 = sm["focal_plane_to_detector"][(plane, det)]
            R_det_fp = R_small(a3, ax3)
        # the detector chain: piloting <- MSI (then MSI_State), MSI <- focal plane (then
        # Focal_Plane_State), focal plane <- detector
        kw: dict = {"R_body_msi": R_msi_pil, "R_msi_fp": R_fp_msi.T, "R_fp_det": R_det_fp.T}
        if refining and ds.refining is not None:
            if ds.refining.position is not None:
                raise ValueError(
                    f"{ds.path}: Refined_Corrections/Spacecraft_Position = {ds.refining.position!r}: the format "
                    "gives these orbit offsets 'in the local spacecraft reference frame' without naming its axes; "
                    "geoloc does not guess them (refining=False, or --no-refining, ignores all the refining)"
                )
            kw.update(
                refining_t0_s=float(secs(ds.refining.t_centre)),
                refining_rotation=ds.refining.msi_rotation,
                refining_homothety=ds.refining.msi_homothety_z,
            )
            if plane in ds.refining.focal_plane:
                kw["focal_rotation"], kw["focal_homothety"] = ds.refining.focal_plane[plane]
        span = (min(orbit.span[0], ta[0]), max(orbit.span[1], ta[-1]))
        earth = EarthRotationTable.build(epoch, span[0] - 1.0, span[1] + 1.0, self.eop)
        return InertialPushbroomSensor(
            orbit=orbit,
            attitude_t=ta,
            q_in_body=ds.q_eme2000_to_piloting,
            earth=earth,
            look=LookAngles(look[:, 0], look[:, 1]),
            rows=int(rows),
            line_period_s=period,
            t0_s=t0,
            name=f"Sentinel-2 {b} D{det}",
            epoch=epoch,
            **kw,
        )


def read_product(path: str | Path, gipp: str | Path | None = None, iers: str | Path | None = None) -> Sentinel2Product:
    """Open an L1B product folder (``DATASTRIP/*/MTD_L1B_DS*.xml``, ``GRANULE/*/MTD_L1B_GR*.xml``).

    Parameters
    ----------
    path : path
        The product folder (the one holding DATASTRIP and GRANULE).
    gipp : path, optional
        The folder of the GIPP files (``GIP_VIEDIR`` per band, ``GIP_SPAMOD``); default
        ``path/GIPP``.
    iers : path, optional
        An IERS Bulletin A file (``AUX_UT1UTC``); default the one in ``path/IERS`` if any, else the
        datastrip's own IERS bulletin values (one day).
    """
    from geoloc.frames.earth import EarthOrientation

    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"{path}: not a folder (an L1B product folder holds DATASTRIP and GRANULE)")
    ds_file = _one(path.glob("DATASTRIP/*/*MTD_L1B_DS*.xml"), "DATASTRIP/*/*MTD_L1B_DS*.xml", str(path))
    ds = read_datastrip(ds_file)
    granules = {}
    for f in sorted(path.glob("GRANULE/*/*MTD_L1B_GR*.xml")):
        g = read_granule(f)
        granules[g.granule_id] = g
    gipp_dir = Path(gipp) if gipp is not None else path / "GIPP"
    if not gipp_dir.is_dir():
        raise ValueError(f"gipp = {str(gipp_dir)!r}: not a folder of GIPP files")
    spamod = _one(
        [p for p in gipp_dir.glob("*GIP_SPAMOD*") if p.suffix.lower() in (".xml", ".dbl")],
        "GIP_SPAMOD file (.xml or .DBL)",
        str(gipp_dir),
    )
    sm = read_spacecraft_model(spamod)
    if iers is None:
        found = sorted((path / "IERS").glob("*UT1UTC*")) if (path / "IERS").is_dir() else []
        iers = found[0] if found else None
    if iers is not None:
        eop = read_ut1utc(iers)
        source = str(iers)
    else:
        if not np.all(np.isfinite(ds.iers)):
            raise ValueError(f"{ds_file}: no IERS_Bulletin and no IERS file given (--iers)")
        mjd = (ds.sensing_start_utc.astype("datetime64[D]") - np.datetime64("1858-11-17", "D")).astype(float)
        eop = EarthOrientation(
            np.array([mjd]),
            np.array([ds.iers[0]]),
            np.array([ds.iers[1]]),
            np.array([ds.iers[2]]),
            source=f"{ds_file} IERS_Bulletin",
        )
        source = f"{ds_file} IERS_Bulletin"
    return Sentinel2Product(path, ds, granules, gipp_dir, sm, eop, source)
