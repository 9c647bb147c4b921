"""Drone photos: EXIF and DJI's XMP (``drone-dji``) from JPEG and TIFF, and the sensor they describe.

Other makers (Skydio, Parrot, Pix4D ``Camera:`` tags of Autel and Sequoia, MicaSense, Teal) are
read through their tables in :mod:`geoloc.io.photo_makers`, their angles turned into DJI's
convention; a photo without calibration takes its lens from the camera database
(:mod:`geoloc.io.camera_db`), with the focal length's 1-sigma (:func:`lens_uncertainty`).

``docs/photos.md`` is the user's page; this docstring is the short version.

What is read (:func:`read_photo` -> :class:`PhotoMeta`):

* **EXIF** through Pillow (``Image.getexif``, ``get_ifd``): Make, Model and
  Orientation (IFD0); PixelXDimension / PixelYDimension, FocalLength and
  FocalLengthIn35mmFilm (Exif IFD); GPSLatitude(Ref), GPSLongitude(Ref),
  GPSAltitude(Ref) (GPS IFD).
* **XMP**: the packet of a JPEG's APP1 segment that starts with
  ``http://ns.adobe.com/xap/1.0/\\0`` (read here segment by segment), or a TIFF's
  tag 700, parsed with ``defusedxml.ElementTree`` (no DTDs, no entities). Every
  ``drone-dji`` property (namespace ``http://www.dji.com/drone-dji/1.0/``) is
  collected, whether DJI wrote it as an attribute of ``rdf:Description`` (what
  the cameras do) or as a child element (what XMP editors often rewrite it to).
  The fields used: GpsLatitude, GpsLongitude (and DJI's older spelling
  GpsLongtitude), AbsoluteAltitude, RelativeAltitude, AltitudeType,
  Gimbal{Yaw,Pitch,Roll}Degree, Flight{Yaw,Pitch,Roll}Degree,
  CalibratedFocalLength, CalibratedOpticalCenterX/Y, DewarpData, DewarpFlag,
  RtkFlag.
* the **raster's own size** (Pillow's ``Image.size``, without decoding pixels).

The sensor (:func:`sensor_from_photo`): a lens from the calibration tags on the
earth-referenced ``yaw-pitch-roll`` gimbal preset (DJI's gimbal angles are in
NED, z-y-x: ``docs/conventions.md``, "Gimbal presets"); the state
(:func:`pose_from_photo`): a :class:`geoloc.frames.chain.Pose` at the photo's GPS
position and height, the flight attitude as heading/pitch/roll and the angles
``gimbal_yaw``, ``gimbal_pitch``, ``gimbal_roll``.

Pixels. DJI's calibration is in pixels of the full-resolution image (EXIF
PixelXDimension x PixelYDimension), with its origin at the top-left **corner** of
the image: the "designed" optical centre DJI writes is exactly (W/2, H/2) (for
example 2736, 1824 for 5472 x 3648), the centre of the picture, and DewarpData's
cx, cy are offsets from that centre ("origin point: photo center"). So an OpenCV
principal point (0-based pixel centres, as the lenses take it) is the DJI
coordinate minus 0.5, and a 1-based project pixel is the DJI coordinate plus 0.5.
A photo resized since it was taken keeps the full-resolution tags: the corner
origin makes the scaling exact (x' = s x), see :func:`scale_lens`.

Heights. DJI's AbsoluteAltitude is taken as EGM96 orthometric by default
(``altitude_datum="egm96"``) and converted with the bundled EGM96 grid
(h = H + N); ``altitude_datum="ellipsoid"`` takes it as WGS-84 ellipsoidal height
(what DJI's RTK aircraft write). ``docs/photos.md`` gives the sources and why.

Conventions: ``docs/conventions.md`` (degrees only at this edge, ``_deg`` names).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import os
import dataclasses
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from geoloc.frames.chain import Pose
from geoloc.io.photo_makers import (
    CONVENTIONS,
    MAKERS,
    MakerTags,
    angles_namespace,
    earth_gimbal_deg,
    pick_maker,
    xmp_properties,
    xmp_values,
)
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens, Lens, PinholeLens
from geoloc.userfiles import note_input

if TYPE_CHECKING:  # the camera database is read only for a photo without a calibration
    from geoloc.io.camera_db import DbLens

__all__ = [
    "ALTITUDE_DATUMS",
    "DJI_NS",
    "GIMBAL_ANGLES",
    "XMP_APP1_HEADER",
    "DewarpData",
    "PhotoMeta",
    "PhotoTagError",
    "camera_height",
    "database_lens",
    "lens_from_photo",
    "lens_source",
    "lens_uncertainty",
    "parse_dewarp_data",
    "parse_xmp",
    "photo_columns",
    "photo_sensor",
    "pose_from_photo",
    "read_photo",
    "read_xmp_packet",
    "scale_lens",
    "sensor_from_photo",
]

#: DJI's XMP namespace.
DJI_NS = "http://www.dji.com/drone-dji/1.0/"
#: The signature that opens an APP1 segment holding the (standard) XMP packet of a JPEG.
XMP_APP1_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_TIFF_NS = "http://ns.adobe.com/tiff/1.0/"
_RDF_LI = "{http://www.w3.org/1999/02/22-rdf-syntax-ns#}li"
#: Values of ``altitude_datum``: the vertical datum AbsoluteAltitude is taken in.
ALTITUDE_DATUMS = ("egm96", "ellipsoid")
#: The gimbal preset of a DJI photo and its angle names (docs/conventions.md, "Gimbal presets").
GIMBAL_PRESET = "yaw-pitch-roll"
GIMBAL_ANGLES = ("gimbal_yaw", "gimbal_pitch", "gimbal_roll")
#: Diagonal of the 36 x 24 mm frame that FocalLengthIn35mmFilm refers to [mm].
_DIAGONAL_35MM = math.hypot(36.0, 24.0)
#: RtkFlag values of an RTK-corrected position (DJI: 32-49 float solution, 50 fixed).
RTK_CORRECTED_MIN = 32

# EXIF tag numbers (EXIF 2.32 / CIPA DC-008)
_MAKE, _MODEL, _ORIENTATION = 0x010F, 0x0110, 0x0112
_EXIF_IFD, _GPS_IFD = 0x8769, 0x8825
_PIXEL_X, _PIXEL_Y, _FOCAL, _FOCAL_35 = 0xA002, 0xA003, 0x920A, 0xA405
#: EXIF FocalPlaneXResolution, FocalPlaneYResolution, FocalPlaneResolutionUnit (EXIF 2.32, 4.6.5)
_FP_X, _FP_Y, _FP_UNIT = 0xA20E, 0xA20F, 0xA210
#: FocalPlaneResolutionUnit -> millimetres per unit (2 inch, 3 centimetre; 4 millimetre, 5 micrometre:
#: values some writers use beyond the standard's two)
_FP_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}
#: Pix4D's camera namespace, whose calibration tags MicaSense and Sequoia write (Pix4D "How to write
#: XMP tags"; MicaSense imageprocessing metadata.py and image.py read them)
_PIX4D_NS = "http://pix4d.com/camera/1.0/"
_GPS_LAT_REF, _GPS_LAT, _GPS_LON_REF, _GPS_LON, _GPS_ALT_REF, _GPS_ALT = 1, 2, 3, 4, 5, 6
_XMP_TIFF_TAG = 700


class PhotoTagError(ValueError):
    """A photo lacks tags it needs; the message names the file and the tags.

    Attributes
    ----------
    path : str
    missing : tuple of str
        The tags (or alternatives, ``"A or B"``) that are missing.
    """

    def __init__(self, path: str | os.PathLike[str], missing: Iterable[str], why: str = "cannot be geolocated"):
        self.path = str(path)
        self.missing = tuple(missing)
        super().__init__(f"{Path(self.path).name}: {why}: missing tag(s) {', '.join(self.missing)} (file {self.path})")


@dataclass(frozen=True)
class DewarpData:
    """DJI's ``DewarpData``: ``"date;fx,fy,cx,cy,k1,k2,p1,p2,k3"`` (``docs/photos.md``).

    Attributes
    ----------
    date : str
        The calibration date (the part before ``;``), "" when absent.
    fx, fy : float
        Calibrated focal lengths [pixels of the full-resolution image].
    cx, cy : float
        **Offsets** of the principal point from the image centre (W/2, H/2)
        [pixels of the full-resolution image]: DJI, "origin point: photo center".
    k1, k2, p1, p2, k3 : float
        Brown-Conrady coefficients in OpenCV's order and meaning.
    k4, k5, k6 : float
        The rational denominator (only in DJI's 12-value ``DewarpDataK6``); 0 otherwise.
    """

    date: str
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0

    @property
    def coefficients(self) -> dict:
        return {k: getattr(self, k) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")}

    @property
    def is_zero(self) -> bool:
        """All values 0 (what some firmware writes when there is no calibration)."""
        return not any((self.fx, self.fy, self.cx, self.cy, *self.coefficients.values()))


def parse_dewarp_data(text: str, source: str = "DewarpData") -> DewarpData:
    """Parse DJI's DewarpData string ``"[date;]fx,fy,cx,cy,k1,k2,p1,p2,k3"`` (or 12 values, to k6).

    Raises
    ------
    ValueError
        Not 9 or 12 numbers after the optional ``date;``; the message names
        ``source`` and the value.
    """
    raw = str(text).strip()
    date, _, values = raw.rpartition(";")
    parts = [p.strip() for p in values.split(",") if p.strip()]
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        raise ValueError(
            f"{source} = {raw!r}: not numbers after the date (expected 'date;fx,fy,cx,cy,k1,k2,p1,p2,k3')"
        ) from None
    if len(nums) not in (9, 12) or not all(math.isfinite(v) for v in nums):
        raise ValueError(
            f"{source} = {raw!r}: {len(nums)} values; expected 9 finite numbers "
            "'fx,fy,cx,cy,k1,k2,p1,p2,k3' (or 12, to k6) after 'date;'"
        )
    return DewarpData(date.strip(), *nums)


@dataclass
class PhotoMeta:
    """What :func:`read_photo` found in a photo (degrees and metres: this is an edge).

    Sizes: ``width`` x ``height`` is the raster as stored; ``exif_width`` x
    ``exif_height`` the EXIF PixelXDimension x PixelYDimension (the size the
    camera wrote, in which DJI's calibration tags are), ``None`` if absent.
    Calibration values are as tagged (full-resolution pixels); ``scale_x``,
    ``scale_y`` take them to the raster.
    """

    path: str
    width: int
    height: int
    exif_width: int | None = None
    exif_height: int | None = None
    make: str | None = None
    model: str | None = None
    orientation: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    position_source: str = ""
    absolute_altitude_m: float | None = None
    relative_altitude_m: float | None = None
    gps_altitude_m: float | None = None
    altitude_source: str = ""
    altitude_type: str | None = None
    gimbal_yaw_deg: float | None = None
    gimbal_pitch_deg: float | None = None
    gimbal_roll_deg: float | None = None
    flight_yaw_deg: float | None = None
    flight_pitch_deg: float | None = None
    flight_roll_deg: float | None = None
    calibrated_focal_px: float | None = None
    calibrated_center_x_px: float | None = None
    calibrated_center_y_px: float | None = None
    dewarp: DewarpData | None = None
    dewarp_flag: int | None = None
    rtk_flag: int | None = None
    calibrated_focal_y_px: float | None = None
    maker: str = ""
    focal_mm: float | None = None
    focal_35mm: float | None = None
    xmp: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    missing: tuple = ()

    @property
    def name(self) -> str:
        return Path(self.path).name

    @property
    def full_width(self) -> int:
        """Width of the image the calibration tags refer to: EXIF PixelXDimension, else the raster's."""
        return self.exif_width or self.width

    @property
    def full_height(self) -> int:
        return self.exif_height or self.height

    @property
    def scale_x(self) -> float:
        """Raster pixels per full-resolution pixel along the columns (1 unless resized)."""
        return self.width / self.full_width

    @property
    def scale_y(self) -> float:
        return self.height / self.full_height

    @property
    def resized(self) -> bool:
        return (self.width, self.height) != (self.full_width, self.full_height)

    @property
    def altitude_m(self) -> float | None:
        """The camera's altitude as tagged: AbsoluteAltitude, else EXIF GPSAltitude."""
        return self.absolute_altitude_m if self.absolute_altitude_m is not None else self.gps_altitude_m

    @property
    def rtk_corrected(self) -> bool:
        """RtkFlag says RTK float or fixed (>= 32): DJI's RTK aircraft write ellipsoidal heights."""
        return self.rtk_flag is not None and self.rtk_flag >= RTK_CORRECTED_MIN


# --------------------------------------------------------------------------- XMP


def _jpeg_xmp(fh, path) -> bytes | None:
    """The standard XMP packet of a JPEG: walk the segments up to the image data (SOS), reading only them."""
    name = Path(path).name
    if fh.read(2) != b"\xff\xd8":
        raise ValueError(f"{name}: not a JPEG file (no SOI marker) (file {path})")
    while True:
        pos = fh.tell()
        b = fh.read(2)
        if len(b) < 2:
            return None
        if b[0] != 0xFF:
            raise ValueError(f"{name}: JPEG segment at byte {pos} does not start with 0xFF (file {path})")
        marker = b[1]
        while marker == 0xFF:  # fill bytes
            nxt = fh.read(1)
            if not nxt:
                return None
            marker = nxt[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # markers without a length
            continue
        if marker in (0xDA, 0xD9):  # start of scan / end of image: no more metadata
            return None
        raw = fh.read(2)
        length = struct.unpack(">H", raw)[0] if len(raw) == 2 else 0
        payload = fh.read(length - 2) if length >= 2 else b""
        if length < 2 or len(payload) != length - 2:
            raise ValueError(
                f"{name}: JPEG segment 0xFF{marker:02X} at byte {pos} has length {length}, "
                f"past the end of the file (file {path})"
            )
        if marker == 0xE1 and payload.startswith(XMP_APP1_HEADER):
            return payload[len(XMP_APP1_HEADER) :]


def read_xmp_packet(path: str | os.PathLike[str], image: Any = None) -> bytes | None:
    """The XMP packet of a JPEG (APP1 ``http://ns.adobe.com/xap/1.0/\\0``) or TIFF (tag 700); None if none.

    ``image`` is an open Pillow image of ``path`` (for TIFF), opened here if not given.
    """
    p = Path(path)
    with p.open("rb") as fh:
        head = fh.read(2)
        if head == b"\xff\xd8":
            fh.seek(0)
            return _jpeg_xmp(fh, path)
    from PIL import Image

    img = image if image is not None else Image.open(p)
    try:
        tags = getattr(img, "tag_v2", None)
        v = tags.get(_XMP_TIFF_TAG) if tags is not None else img.info.get("xmp")
    finally:
        if image is None:
            img.close()
    if v is None:
        return None
    if isinstance(v, str):
        return v.encode("utf-8")
    if isinstance(v, (tuple, list)):  # BYTE arrays as a tuple of ints
        return bytes(v)
    return bytes(v)


def _local(tag: str, ns: str) -> str | None:
    prefix = "{" + ns + "}"
    return tag[len(prefix) :] if tag.startswith(prefix) else None


def xmp_element(packet: bytes) -> bytes:
    """The ``<x:xmpmeta ...>...</x:xmpmeta>`` element of an XMP packet, located by its name.

    What stands around it is not XML for a parser: the ``<?xpacket?>`` wrapper is fine, but
    GDAL writes a TIFF's XMP tag from its ``xml:XMP`` metadata domain as
    ``xml:XMP=<?xpacket ...`` when a program copies that domain as key=value items (as
    rasterio's ``update_tags(ns="xml:XMP", **src.tags(ns="xml:XMP"))`` does), and some
    writers pad with NULs. Readers such as OpenSfM's locate the packet the same way (by its
    element). A packet without the element (``x:xapmeta`` of old writers, a bare
    ``rdf:RDF``) is returned as it is, trailing NULs and blanks stripped (some writers pad the packet).
    """
    start = packet.find(b"<x:xmpmeta")
    end = packet.rfind(b"</x:xmpmeta>")
    # a DTD before it stays, for defusedxml to refuse by name (cut off, its entities would
    # read as merely undefined)
    if start >= 0 and end > start and b"<!" not in packet[:start]:
        return packet[start : end + len(b"</x:xmpmeta>")]
    return packet.rstrip(b"\x00 \t\r\n")


def parse_xmp(packet: bytes, source: str = "XMP") -> tuple[dict, dict]:
    """``drone-dji`` and ``tiff`` properties of an XMP packet: ``(dji, tiff)``, name -> text.

    Both XMP forms are read: a property as an attribute of an element
    (``drone-dji:GimbalYawDegree="+12.30"`` on ``rdf:Description``) and as a
    child element (``<drone-dji:GimbalYawDegree>+12.30</drone-dji:GimbalYawDegree>``,
    or an ``rdf:Alt``/``rdf:Seq`` whose first ``rdf:li`` holds the value).

    Raises
    ------
    ValueError
        The packet is not well-formed XML, or holds a DTD or entity declarations
        (refused by defusedxml); the message names ``source``.
    ImportError
        defusedxml is not installed.
    """
    return _dji_and_tiff(_xmp_root(packet, source))


def _xmp_root(packet: bytes, source: str) -> Any:
    """The root element of an XMP packet (:func:`parse_xmp`'s errors)."""
    try:
        from defusedxml import DefusedXmlException
        from defusedxml import ElementTree as DET
    except ImportError as e:  # pragma: no cover - a declared dependency
        raise ImportError("reading XMP needs defusedxml: pip install defusedxml") from e
    from xml.etree.ElementTree import ParseError

    text = xmp_element(packet)
    try:
        root = DET.fromstring(text)
    except DefusedXmlException as e:
        raise ValueError(
            f"{source}: XMP packet refused ({type(e).__name__}: DTDs and entity declarations are not allowed in XMP)"
        ) from None
    except ParseError as e:
        raise ValueError(f"{source}: XMP packet is not well-formed XML ({e})") from None
    return root


def _dji_and_tiff(root) -> tuple[dict, dict]:
    out: dict[str, dict[str, str]] = {DJI_NS: {}, _TIFF_NS: {}}
    for elem in root.iter():
        for k, v in elem.attrib.items():
            for ns, d in out.items():
                name = _local(k, ns)
                if name is not None:
                    d.setdefault(name, v.strip())
        if not isinstance(elem.tag, str):
            continue
        for ns, d in out.items():
            name = _local(elem.tag, ns)
            if name is None:
                continue
            li = next(elem.iter(_RDF_LI), None)
            value = (li.text if li is not None else elem.text) or ""
            if value.strip() or len(elem) == 0:
                d.setdefault(name, value.strip())
    return out[DJI_NS], out[_TIFF_NS]


# --------------------------------------------------------------------------- EXIF


def _rational(v) -> float:
    if isinstance(v, tuple) and len(v) == 2:  # (numerator, denominator) from some writers
        return float(v[0]) / float(v[1])
    return float(v)


def _text(v) -> str | None:
    if v is None:
        return None
    if isinstance(v, bytes):
        v = v.decode("ascii", "replace")
    return str(v).strip("\x00 ").strip() or None


def _gps_coordinate(value, ref, positive: str, negative: str, limit: float, name: str, path):
    """EXIF GPS degrees-minutes-seconds and N/S (E/W) -> signed degrees (ValueError naming the tag)."""
    try:
        parts = [_rational(x) for x in value] if isinstance(value, (tuple, list)) else [_rational(value)]
    except (TypeError, ValueError, ZeroDivisionError):
        raise ValueError(
            f"{Path(path).name}: EXIF {name} = {value!r}: not degrees, minutes, seconds (file {path})"
        ) from None
    parts = (parts + [0.0, 0.0])[:3]
    deg = parts[0] + parts[1] / 60.0 + parts[2] / 3600.0
    r = (_text(ref) or positive).upper()[:1]
    if r not in (positive, negative):
        raise ValueError(
            f"{Path(path).name}: EXIF {name}Ref = {ref!r}: must be {positive!r} or {negative!r} (file {path})"
        )
    deg = -deg if r == negative else deg
    if not (math.isfinite(deg) and abs(deg) <= limit):
        raise ValueError(f"{Path(path).name}: EXIF {name} = {deg!r} deg: out of range (file {path})")
    return deg


#: TIFF tag where GDAL keeps the metadata items a TIFF has no tag for (GDAL_METADATA, XML).
_GDAL_METADATA_TAG = 42112
#: GDAL's names of the EXIF items read from its metadata, and their EXIF tags.
_GDAL_EXIF_NAMES = {
    "EXIF_PixelXDimension": _PIXEL_X,
    "EXIF_PixelYDimension": _PIXEL_Y,
    "EXIF_FocalLength": _FOCAL,
    "EXIF_FocalLengthIn35mmFilm": _FOCAL_35,
}


def _gdal_exif(img, notes) -> dict:
    """EXIF tag -> value of the ``EXIF_*`` items of a TIFF's GDAL_METADATA tag (42112).

    GDAL reads a photo's EXIF directory as metadata items ``EXIF_PixelXDimension``, ...;
    a TIFF it writes from them (a resized copy of a drone photo, as public test sets are
    shipped) holds them in its GDAL_METADATA XML, not in an EXIF directory (GDAL 3.10),
    so that PixelXDimension/PixelYDimension (the full size the calibration is in) are read
    from there. Values are GDAL's text (``(3.6)`` for a rational)."""
    tags = getattr(img, "tag_v2", None)
    raw = tags.get(_GDAL_METADATA_TAG) if tags is not None else None
    if not raw:
        return {}
    from xml.etree.ElementTree import ParseError

    from defusedxml import DefusedXmlException
    from defusedxml import ElementTree as DET

    try:
        root = DET.fromstring(raw.encode("utf-8") if isinstance(raw, str) else bytes(raw))
    except (ParseError, DefusedXmlException) as e:
        notes.append(f"GDAL_METADATA tag not readable ({type(e).__name__}): its EXIF items ignored")
        return {}
    out: dict[int, int | float | str] = {}
    for item in root.iter("Item"):
        tag = _GDAL_EXIF_NAMES.get(item.get("name", ""))
        if tag is not None and item.get("band") is None and item.text:
            text = item.text.strip().strip("()")
            try:
                out[tag] = int(text) if tag in (_PIXEL_X, _PIXEL_Y) else float(text)
            except ValueError:
                out[tag] = text  # named as not an integer below
    return out


def _read_exif(img, path, notes) -> dict:
    out: dict[str, Any] = {}  # EXIF name -> text, number or pair, each key its own
    try:
        exif = img.getexif()
    except Exception as e:  # noqa: BLE001 - a broken EXIF block must not hide the XMP
        notes.append(f"EXIF not readable ({type(e).__name__}: {e}); using XMP only")
        return out
    out["make"] = _text(exif.get(_MAKE))
    out["model"] = _text(exif.get(_MODEL))
    o = exif.get(_ORIENTATION)
    out["orientation"] = int(o) if isinstance(o, int) else None
    sub = dict(exif.get_ifd(_EXIF_IFD))
    for tag, v in _gdal_exif(img, notes).items():  # a TIFF written by GDAL: its GDAL_METADATA items
        sub.setdefault(tag, v)
    for key, tag in (("exif_width", _PIXEL_X), ("exif_height", _PIXEL_Y)):
        v = sub.get(tag)
        if v is not None:
            try:
                out[key] = int(v)
            except (TypeError, ValueError):
                notes.append(
                    f"EXIF {'PixelXDimension' if tag == _PIXEL_X else 'PixelYDimension'} "
                    f"= {v!r} ignored: not an integer"
                )
    for key, tag in (("focal_mm", _FOCAL), ("focal_35mm", _FOCAL_35)):
        v = sub.get(tag)
        if v is not None:
            try:
                f = _rational(v)
                if math.isfinite(f) and f > 0:
                    out[key] = f
            except (TypeError, ValueError, ZeroDivisionError):
                pass
    if _FP_X in sub and _FP_Y in sub:
        try:
            fx_res, fy_res = _rational(sub[_FP_X]), _rational(sub[_FP_Y])
        except (TypeError, ValueError, ZeroDivisionError):
            fx_res = fy_res = float("nan")
        unit = sub.get(_FP_UNIT)
        if unit is None:  # MicaSense's imageprocessing reads the values as pixels per millimetre
            notes.append("EXIF FocalPlaneResolutionUnit absent: FocalPlaneX/YResolution read as pixels per mm")
        mm = _FP_UNIT_MM.get(int(unit) if isinstance(unit, int) else 4)
        if mm is None:
            notes.append(f"EXIF FocalPlaneResolutionUnit = {unit!r} ignored: not inch, cm, mm or um")
        elif math.isfinite(fx_res) and math.isfinite(fy_res) and fx_res > 0 and fy_res > 0:
            out["focal_plane_px_per_mm"] = (fx_res / mm, fy_res / mm)
        else:
            notes.append(f"EXIF FocalPlaneX/YResolution = {sub[_FP_X]!r}, {sub[_FP_Y]!r} ignored: not > 0")
    gps = exif.get_ifd(_GPS_IFD)
    if _GPS_LAT in gps and _GPS_LON in gps:
        out["gps_lat_deg"] = _gps_coordinate(gps[_GPS_LAT], gps.get(_GPS_LAT_REF), "N", "S", 90.0, "GPSLatitude", path)
        out["gps_lon_deg"] = _gps_coordinate(
            gps[_GPS_LON], gps.get(_GPS_LON_REF), "E", "W", 180.0, "GPSLongitude", path
        )
    if _GPS_ALT in gps:
        try:
            alt = _rational(gps[_GPS_ALT])
        except (TypeError, ValueError, ZeroDivisionError):
            alt = float("nan")
        ref = gps.get(_GPS_ALT_REF, 0)
        ref = ref[0] if isinstance(ref, bytes) and ref else ref
        if math.isfinite(alt):
            out["gps_altitude_m"] = -alt if ref == 1 else alt
    return out


# --------------------------------------------------------------------------- reading


def _number(dji: dict, key: str, notes: list) -> float | None:
    if key not in dji:
        return None
    v = dji[key]
    try:
        x = float(v)
    except ValueError:
        notes.append(f"drone-dji:{key} = {v!r} ignored: not a number")
        return None
    if not math.isfinite(x):
        notes.append(f"drone-dji:{key} = {v!r} ignored: not finite")
        return None
    return x


def _integer(dji: dict, key: str, notes: list) -> int | None:
    x = _number(dji, key, notes)
    if x is None:
        return None
    if x != int(x):
        notes.append(f"drone-dji:{key} = {dji[key]!r} ignored: not an integer")
        return None
    return int(x)


#: The tags a photo must have to be geolocated (alternatives joined by "or").
REQUIRED = {
    "position": "drone-dji:GpsLatitude/GpsLongitude or EXIF GPSLatitude/GPSLongitude",
    "altitude": "drone-dji:AbsoluteAltitude or EXIF GPSAltitude",
    "gimbal_yaw_deg": "drone-dji:GimbalYawDegree",
    "gimbal_pitch_deg": "drone-dji:GimbalPitchDegree",
    "gimbal_roll_deg": "drone-dji:GimbalRollDegree",
}


def read_photo(path: str | os.PathLike[str], *, require: bool = True) -> PhotoMeta:
    """Read a drone photo's EXIF and DJI XMP (JPEG or TIFF).

    Parameters
    ----------
    path : path-like
    require : bool
        Raise :class:`PhotoTagError` when a tag needed for geolocation (position,
        altitude, the three gimbal angles: :data:`REQUIRED`) is missing. With
        ``False`` the photo is returned and :attr:`PhotoMeta.missing` lists them.

    Returns
    -------
    PhotoMeta
        ``notes`` holds what a user should know: a resized photo (its
        calibration will be scaled), tags that could not be parsed, a missing
        flight attitude, position tags that disagree.

    Raises
    ------
    FileNotFoundError
        No such file.
    PhotoTagError
        Required tags missing (``require=True``); names the file and the tags.
    ValueError
        Not an image Pillow reads, a broken JPEG segment, XMP that is not
        well-formed (or holds a DTD/entities), a bad tag value (message names the
        file and the tag).
    """
    note_input(path)
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"photo not found: {path}")
    notes: list = []
    width, height, ex, packet = _open_photo(p, path, notes)
    root = None
    if packet is not None:
        root = _xmp_root(packet, f"{p.name}")
        dji, tiff = _dji_and_tiff(root)
        props = xmp_properties(root)
    else:
        dji, tiff, props = {}, {}, {}
    maker = None if dji else pick_maker(props, ex.get("make") or tiff.get("Make"))
    if packet is None:
        notes.append("no XMP packet (no drone-dji tags)" if maker is None else "no XMP packet")
    elif not dji and maker is None:
        notes.append(f"XMP packet without drone-dji ({DJI_NS}) properties")

    m = PhotoMeta(path=str(path), width=int(width), height=int(height), xmp=dict(dji), notes=notes)
    m.exif_width, m.exif_height = ex.get("exif_width"), ex.get("exif_height")
    m.make = ex.get("make") or tiff.get("Make")
    m.model = ex.get("model") or tiff.get("Model")
    m.orientation = ex.get("orientation")
    m.focal_mm, m.focal_35mm = ex.get("focal_mm"), ex.get("focal_35mm")
    if maker is not None:
        _read_maker(m, maker, props, ex, notes)
        if root is not None:
            _pix4d_calibration(m, root, ex, notes)
        _size_notes(m, notes)
        if m.missing and require:
            raise PhotoTagError(path, m.missing)
        return m
    if not dji and (m.make or "").strip().lower() not in DJI_MAKES and m.make:
        return _unknown_maker(m, m.make, path, require)
    m.maker = "DJI"
    _read_dji(m, dji, ex, notes, p.name, path)
    _size_notes(m, notes)
    _centre_notes(m, notes)
    m.missing = _missing_required(m)
    if m.missing and require:
        raise PhotoTagError(path, m.missing)
    return m


def _unknown_maker(m: PhotoMeta, make: str, path: str | os.PathLike[str], require: bool) -> PhotoMeta:
    """A photo of a camera maker geoloc does not read (``make``, its EXIF Make, and no known
    maker's XMP namespace): its one missing tag says so; refused with ``require``."""
    m.missing = (_unknown_maker_tags(),)
    m.maker = make
    if require:
        raise PhotoTagError(
            path,
            m.missing,
            why=f"camera maker {make!r} (EXIF Make) is not one geoloc "
            "reads, and no known maker's XMP namespace is in the photo",
        )
    return m


def _read_dji(m: PhotoMeta, dji: dict, ex: dict, notes: list, name: str, path: str | os.PathLike[str]) -> None:
    """The drone-dji XMP tags read into ``m``: position, altitude, attitude, calibration, and the
    dewarp and RTK flags."""
    _dji_position(m, dji, ex, notes, name, path)
    _dji_altitude(m, dji, ex, notes)
    _dji_attitude(m, dji, notes)
    _dji_calibration(m, dji, notes, name)
    m.dewarp_flag = _integer(dji, "DewarpFlag", notes)
    m.rtk_flag = _integer(dji, "RtkFlag", notes)


def _open_photo(p: Path, path: str | os.PathLike[str], notes: list) -> tuple[int, int, dict, bytes | None]:
    """The raster's width and height, the EXIF tags read (:func:`_read_exif`; none when Pillow
    cannot parse its directories: said in ``notes``) and the XMP packet (None without one).

    ValueError naming the file when Pillow cannot open it, its header declares too many pixels,
    a JPEG segment is broken or a TIFF's XMP tag cannot be read."""
    from PIL import Image, UnidentifiedImageError

    with p.open("rb") as fh:
        jpeg = fh.read(2) == b"\xff\xd8"
    packet = read_xmp_packet(p) if jpeg else None  # a broken JPEG segment is named here, precisely
    try:
        img = Image.open(p)
    except UnidentifiedImageError:
        raise ValueError(f"{p.name}: not an image file Pillow can read (file {path})") from None
    except Image.DecompressionBombError as e:  # found by fuzzing: a header declaring 179 M pixels
        raise ValueError(
            f"{p.name}: its header declares more pixels than Pillow opens, a damaged file? ({e}) (file {path})"
        ) from None
    except OSError as e:
        raise ValueError(f"{p.name}: Pillow cannot read it ({e}) (file {path})") from None
    with img:
        width, height = img.size
        try:
            ex = _read_exif(img, path, notes)
        except (TypeError, AttributeError, KeyError, IndexError, SyntaxError, struct.error) as e:
            # Pillow's EXIF directory parsing fails on some multispectral TIFFs (a
            # MicaSense TIFF raised a TypeError here): the XMP still holds what is needed
            notes.append(f"EXIF directories not readable by Pillow ({type(e).__name__}: {e}); using the XMP only")
            ex = {}
        if not jpeg:
            try:
                packet = read_xmp_packet(p, img)
            except (TypeError, AttributeError) as e:
                raise ValueError(
                    f"{p.name}: TIFF tag 700 (XMP) not readable ({type(e).__name__}: {e}) (file {path})"
                ) from None
    return int(width), int(height), ex, packet


def _dji_position(
    m: PhotoMeta, dji: dict[str, str], ex: Mapping[str, Any], notes: list, name: str, path: str | os.PathLike[str]
) -> None:
    """The position: DJI's XMP (8 decimals) first, the EXIF GPS IFD otherwise; a note when the two
    differ by more than 1e-5 deg. ValueError naming the file and the tags when DJI's is out of range."""
    lat = _number(dji, "GpsLatitude", notes)
    lon_key = "GpsLongitude" if "GpsLongitude" in dji else "GpsLongtitude"  # DJI's older spelling
    lon = _number(dji, lon_key, notes)
    if lat is not None and lon is not None:
        if not (abs(lat) <= 90 and abs(lon) <= 180):
            raise ValueError(f"{name}: drone-dji:GpsLatitude/{lon_key} = {lat!r}, {lon!r}: out of range (file {path})")
        m.lat_deg, m.lon_deg, m.position_source = lat, lon, f"drone-dji:GpsLatitude/{lon_key}"
        if "gps_lat_deg" in ex:
            d = max(abs(ex["gps_lat_deg"] - lat), abs(ex["gps_lon_deg"] - lon))
            if d > 1e-5:
                notes.append(f"EXIF GPS position differs from drone-dji's by {d:.2e} deg; using drone-dji's")
    elif "gps_lat_deg" in ex:
        m.lat_deg, m.lon_deg, m.position_source = ex["gps_lat_deg"], ex["gps_lon_deg"], "EXIF GPS"


def _dji_altitude(m: PhotoMeta, dji: dict[str, str], ex: Mapping[str, Any], notes: list) -> None:
    """The altitudes: DJI's AbsoluteAltitude, else EXIF GPSAltitude (noted); the relative altitude
    and DJI's AltitudeType as read."""
    m.absolute_altitude_m = _number(dji, "AbsoluteAltitude", notes)
    m.relative_altitude_m = _number(dji, "RelativeAltitude", notes)
    m.gps_altitude_m = ex.get("gps_altitude_m")
    m.altitude_type = dji.get("AltitudeType") or None
    if m.absolute_altitude_m is not None:
        m.altitude_source = "drone-dji:AbsoluteAltitude"
    elif m.gps_altitude_m is not None:
        m.altitude_source = "EXIF GPSAltitude"
        notes.append("no drone-dji:AbsoluteAltitude: using EXIF GPSAltitude (same datum question)")


def _dji_attitude(m: PhotoMeta, dji: dict[str, str], notes: list) -> None:
    """The gimbal's and the aircraft's yaw, pitch and roll; a flight angle missing where another is
    given is taken as 0 (noted), all three missing are left None (noted when there is DJI XMP)."""
    for what in ("Gimbal", "Flight"):
        for axis in ("Yaw", "Pitch", "Roll"):
            setattr(m, f"{what.lower()}_{axis.lower()}_deg", _number(dji, f"{what}{axis}Degree", notes))
    if all(getattr(m, f"flight_{a}_deg") is None for a in ("yaw", "pitch", "roll")):
        if dji:
            notes.append(
                "no drone-dji:Flight{Yaw,Pitch,Roll}Degree: flight attitude taken as 0 "
                "(the earth-referenced gimbal does not depend on it)"
            )
    else:
        for a in ("yaw", "pitch", "roll"):
            if getattr(m, f"flight_{a}_deg") is None:
                setattr(m, f"flight_{a}_deg", 0.0)
                notes.append(f"no drone-dji:Flight{a.capitalize()}Degree: taken as 0")


def _dji_calibration(m: PhotoMeta, dji: dict[str, str], notes: list, name: str) -> None:
    """DJI's calibrated focal length and optical centre (a focal length not > 0 ignored), and the
    first usable DewarpData (the 12-value form first; all zeros, focal lengths not > 0 or a bad
    value ignored, each noted)."""
    m.calibrated_focal_px = _number(dji, "CalibratedFocalLength", notes)
    m.calibrated_center_x_px = _number(dji, "CalibratedOpticalCenterX", notes)
    m.calibrated_center_y_px = _number(dji, "CalibratedOpticalCenterY", notes)
    if m.calibrated_focal_px is not None and m.calibrated_focal_px <= 0:
        notes.append(f"drone-dji:CalibratedFocalLength = {m.calibrated_focal_px!r} ignored: not > 0")
        m.calibrated_focal_px = None
    for key in ("DewarpDataK6", "DewarpData"):  # the 12-value form (k4..k6) first where DJI writes both
        if key in dji and dji[key].strip():
            try:
                d = parse_dewarp_data(dji[key], f"{name}: drone-dji:{key}")
            except ValueError as e:
                notes.append(f"{e}; ignored")
                continue
            if d.is_zero:
                notes.append(f"drone-dji:{key} is all zeros: ignored")
                continue
            if d.fx <= 0 or d.fy <= 0:
                notes.append(f"drone-dji:{key} focal lengths {d.fx!r}, {d.fy!r} not > 0: ignored")
                continue
            m.dewarp = d
            break


def _centre_notes(m: PhotoMeta, notes: list) -> None:
    """Notes on DJI's calibrated optical centre: far from the raster's centre without the EXIF
    full size (a resized photo, not scaled), or off the image centre with DewarpData (whose offsets
    are from the image centre)."""
    if m.calibrated_center_x_px is None or m.calibrated_center_y_px is None:
        return
    cx, cy = 2 * m.calibrated_center_x_px, 2 * m.calibrated_center_y_px
    if m.exif_width is None and (abs(cx - m.width) > 0.05 * m.width or abs(cy - m.height) > 0.05 * m.height):
        notes.append(
            f"drone-dji:CalibratedOpticalCenterX/Y ({m.calibrated_center_x_px:g}, "
            f"{m.calibrated_center_y_px:g}) is far from the centre of the {m.width} x "
            f"{m.height} raster and EXIF PixelXDimension/PixelYDimension are absent: the "
            f"photo may have been resized from about {cx:.0f} x {cy:.0f} (not scaled here)"
        )
    elif m.dewarp is not None and (abs(cx - m.full_width) > 2 or abs(cy - m.full_height) > 2):
        notes.append(
            f"drone-dji:CalibratedOpticalCenterX/Y ({m.calibrated_center_x_px:g}, "
            f"{m.calibrated_center_y_px:g}) is not the image centre ({m.full_width / 2:g}, "
            f"{m.full_height / 2:g}); DewarpData's offsets are taken from the image centre "
            "(DJI: 'origin point: photo center')"
        )


def _missing_required(m: PhotoMeta) -> tuple[str, ...]:
    """The tags of :data:`REQUIRED` a DJI photo lacks (their descriptions)."""
    return tuple(
        REQUIRED[k]
        for k in REQUIRED
        if (
            (k == "position" and m.lat_deg is None)
            or (k == "altitude" and m.altitude_m is None)
            or (k.endswith("_deg") and getattr(m, k) is None)
        )
    )


def _size_notes(m: PhotoMeta, notes: list) -> None:
    """Notes on a resized raster and a rotated view (every maker)."""
    # sizes: a raster smaller (or larger) than the size the camera wrote was resized since
    if m.resized:
        notes.append(
            f"resized photo: the raster is {m.width} x {m.height}, EXIF PixelXDimension x "
            f"PixelYDimension say {m.full_width} x {m.full_height}; the calibration tags (in "
            f"full-resolution pixels) are scaled by {m.scale_x:.6g} x {m.scale_y:.6g}"
        )
        if abs(m.scale_x - m.scale_y) > 0.01 * max(m.scale_x, m.scale_y):
            notes.append(
                "the two scales differ by more than 1 %: the photo may have been cropped, "
                "which scaling cannot undo (check the geolocation)"
            )
    if m.orientation not in (None, 1):
        notes.append(
            f"EXIF Orientation = {m.orientation}: pixels are taken in the stored raster's "
            "orientation (rows and columns of the file, not of a rotated view)"
        )


#: EXIF Make of DJI's cameras (Hasselblad: the L1D/L2D cameras of Mavic 2 Pro and Mavic 3).
DJI_MAKES = ("dji", "hasselblad")


def _unknown_maker_tags() -> str:
    """The orientation tags looked for, every maker's (for the unknown maker's error)."""
    looked = ["drone-dji:GimbalYawDegree/GimbalPitchDegree/GimbalRollDegree"]
    for mk in MAKERS:
        looked.append(f"{mk.name}: " + "/".join(mk.tag_names("yaw") + mk.tag_names("pitch") + mk.tag_names("roll")))
    return "camera angles of a known maker (looked for " + "; ".join(looked) + ")"


def _maker_number(d: dict, names, prefix: str, notes: list) -> tuple:
    """The first of ``names`` in ``d`` as a float (``"a/b"`` rationals too): ``(value, name)``."""
    for key in names:
        if key not in d:
            continue
        text = d[key].strip()
        try:
            if "/" in text:
                num, den = text.split("/", 1)
                x = float(num) / float(den)
            else:
                x = float(text)
        except (ValueError, ZeroDivisionError):
            notes.append(f"{prefix}:{key} = {text!r} ignored: not a number")
            continue
        if not math.isfinite(x):
            notes.append(f"{prefix}:{key} = {text!r} ignored: not finite")
            continue
        return x, key
    return None, None


#: The Pix4D calibration tags read (the text the output's ``lens`` column names).
PIX4D_CALIBRATION = "Camera:PerspectiveFocalLength, PrincipalPoint, PerspectiveDistortion"


def _pix4d_calibration(m: PhotoMeta, root, ex: dict, notes: list) -> None:
    """The lens of Pix4D's camera calibration tags, as MicaSense writes them (RedEdge, Altum; Sequoia
    too), in ``m.dewarp`` (DJI's form: offsets from the image centre, OpenCV's coefficient order).

    MicaSense imageprocessing (``metadata.py``, ``image.py``: ``cv2_camera_matrix``,
    ``cv2_distortion_coeff``): ``Camera:PerspectiveFocalLength`` in mm when
    ``Camera:PerspectiveFocalLengthUnits`` is ``mm`` (else pixels), ``Camera:PrincipalPoint`` "x,y" in
    mm, both times EXIF FocalPlaneX/YResolution [px/mm] give OpenCV's fx, fy, cx, cy (the principal
    point's pixels taken as OpenCV's, first pixel's centre at 0, as MicaSense does);
    ``Camera:PerspectiveDistortion`` is ``k1, k2, k3, p1, p2``, OpenCV's ``(k1, k2, p1, p2, k3)``
    being items ``[0, 1, 3, 4, 2]``. A photo without them, or with one unreadable (a note says
    which), keeps the camera database's lens.
    """
    f_items = xmp_values(root, _PIX4D_NS, "PerspectiveFocalLength")
    if not f_items:
        return
    where = f"{m.name}: Camera:PerspectiveFocalLength"
    res = ex.get("focal_plane_px_per_mm")
    pp = xmp_values(root, _PIX4D_NS, "PrincipalPoint")
    dist = xmp_values(root, _PIX4D_NS, "PerspectiveDistortion")
    units = (xmp_values(root, _PIX4D_NS, "PerspectiveFocalLengthUnits") or ["mm"])[0].lower()
    try:
        f = float(f_items[0])
        ppx, ppy = (float(t) for t in (pp or [])) if pp and len(pp) == 2 else (math.nan, math.nan)
        k = [float(t) for t in dist] if dist else [0.0] * 5
    except ValueError as e:
        notes.append(f"{where} and its calibration tags ignored: {e}")
        return
    missing = [n for n, ok in (("EXIF FocalPlaneX/YResolution", res), ("Camera:PrincipalPoint (x,y)", pp)) if not ok]
    if res is None or missing or len(k) != 5 or not all(map(math.isfinite, [f, ppx, ppy, *k])) or f <= 0:
        why = (
            f"missing {', '.join(missing)}"
            if missing
            else f"PerspectiveDistortion has {len(k)} of 5 values, or a value not finite"
        )
        notes.append(f"{where} ignored ({why}): the lens comes from elsewhere")
        return
    rx, ry = res
    fx, fy = (f * rx, f * ry) if units == "mm" else (f, f * ry / rx)
    cx_cv, cy_cv = ppx * rx, ppy * ry
    W, H = m.full_width, m.full_height
    # DJI's DewarpData offsets are from the image centre in corner-origin pixels (OpenCV's + 0.5)
    m.dewarp = DewarpData("", fx, fy, cx_cv + 0.5 - W / 2.0, cy_cv + 0.5 - H / 2.0, k[0], k[1], k[3], k[4], k[2])
    m.dewarp_flag = 0
    m.xmp["_calibration_tags"] = PIX4D_CALIBRATION
    notes.append(
        f"lens from {PIX4D_CALIBRATION} (Pix4D tags, MicaSense's reading): fx {fx:.2f}, fy {fy:.2f}, "
        f"cx {cx_cv:.2f}, cy {cy_cv:.2f} px (OpenCV)"
    )


_PLATFORM = ("platform_yaw", "platform_pitch", "platform_roll")


def _maker_position(m: PhotoMeta, maker: MakerTags, own: dict, ex: dict, notes: list) -> None:
    """``m``'s position from the maker's tags, else EXIF GPS; its heights and where they came
    from (a note says the maker's datum). ValueError naming the tags for a position out of range."""
    pre = maker.prefix
    lat, klat = _maker_number(own, maker.lat, pre, notes)
    lon, klon = _maker_number(own, maker.lon, pre, notes)
    if lat is not None and lon is not None:
        if not (abs(lat) <= 90 and abs(lon) <= 180):
            raise ValueError(f"{m.name}: {pre}:{klat}/{klon} = {lat!r}, {lon!r}: out of range (file {m.path})")
        m.lat_deg, m.lon_deg, m.position_source = lat, lon, f"{pre}:{klat}/{klon}"
    elif "gps_lat_deg" in ex:
        m.lat_deg, m.lon_deg, m.position_source = ex["gps_lat_deg"], ex["gps_lon_deg"], "EXIF GPS"
    alt, kalt = _maker_number(own, maker.altitude, pre, notes)
    m.absolute_altitude_m = alt
    m.relative_altitude_m, _ = _maker_number(own, maker.relative_altitude, pre, notes)
    m.gps_altitude_m = ex.get("gps_altitude_m")
    m.altitude_source = (
        f"{pre}:{kalt}" if alt is not None else ("EXIF GPSAltitude" if m.gps_altitude_m is not None else "")
    )
    if m.altitude_source:
        notes.append(f"{maker.name}: altitude from {m.altitude_source}; its datum: {maker.altitude_datum}")


def _maker_angle_values(maker: MakerTags, own: dict, ang: dict, notes: list) -> tuple[dict, dict, float]:
    """The camera's angles (yaw, pitch, roll) and the platform's as the tags give them (None where
    absent), and the factor to degrees."""
    pre = maker.prefix
    ang_pre = "Camera" if maker.convention == "pix4d-nadir" else pre
    raw, plat = {}, {}
    for which in ("yaw", "pitch", "roll"):
        raw[which], _ = _maker_number(ang, getattr(maker, which), ang_pre, notes)
    plat_from = ang if maker.convention == "platform-relative" else own
    for which in _PLATFORM:
        plat[which], _ = _maker_number(plat_from, getattr(maker, which), pre, notes)
    return raw, plat, (math.degrees(1.0) if maker.unit == "rad" else 1.0)


def _missing_angle_tags(maker: MakerTags, raw: dict, plat: dict) -> list[str]:
    """The tags (alternatives joined by "or") of each angle the photo lacks."""
    names = {k: maker.tag_names(k) for k in ("yaw", "pitch", "roll")}
    if maker.convention == "pix4d-nadir":
        names = {k: [f"Camera:{t}" for t in getattr(maker, k)] for k in ("yaw", "pitch", "roll")}
    missing = [" or ".join(names[k]) for k in ("yaw", "pitch", "roll") if raw[k] is None]
    if maker.convention == "platform-relative":
        missing += [" or ".join(maker.tag_names(k)) for k in _PLATFORM if plat[k] is None]
    return missing


def _maker_attitude(m: PhotoMeta, maker: MakerTags, own: dict, ang: dict, notes: list) -> list[str]:
    """``m``'s flight attitude and DJI's earth-referenced gimbal angles from the maker's own
    (:func:`geoloc.io.photo_makers.earth_gimbal_deg`); the tags of the angles missing."""
    raw, plat, scale = _maker_angle_values(maker, own, ang, notes)
    if any(v is not None for v in plat.values()):
        m.flight_yaw_deg, m.flight_pitch_deg, m.flight_roll_deg = ((plat[k] or 0.0) * scale for k in _PLATFORM)
    missing = _missing_angle_tags(maker, raw, plat)
    if missing:
        return missing
    y, p_, r = (raw[k] * scale for k in ("yaw", "pitch", "roll"))
    platform = tuple(plat[k] * scale for k in _PLATFORM) if maker.convention == "platform-relative" else None
    m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg = earth_gimbal_deg(maker.convention, y, p_, r, platform)
    if maker.convention != "ned-horizon":
        notes.append(
            f"{maker.name}: camera angles yaw {y:g}, pitch {p_:g}, roll {r:g} deg "
            f"({CONVENTIONS[maker.convention]}) are DJI's earth-referenced gimbal yaw "
            f"{m.gimbal_yaw_deg:.6g}, pitch {m.gimbal_pitch_deg:.6g}, roll {m.gimbal_roll_deg:.6g} deg"
        )
    return []


def _maker_lens(m: PhotoMeta, maker: MakerTags, own: dict, notes: list) -> None:
    """``m``'s calibrated pinhole from the maker's tags, where it gives a positive focal length."""
    pre = maker.prefix
    fx, _ = _maker_number(own, maker.focal_x_px, pre, notes)
    fy, _ = _maker_number(own, maker.focal_y_px, pre, notes)
    if fx is not None and fx > 0:
        m.calibrated_focal_px = fx
        m.calibrated_focal_y_px = fy if fy is not None and fy > 0 else None
        m.calibrated_center_x_px, _ = _maker_number(own, maker.center_x_px, pre, notes)
        m.calibrated_center_y_px, _ = _maker_number(own, maker.center_y_px, pre, notes)
        m.xmp["_calibration_tags"] = f"{pre}:{maker.focal_x_px[0]}"


def _missing_position_tags(m: PhotoMeta, maker: MakerTags) -> list[str]:
    """The tags (the maker's, then EXIF's) of the position and the altitude where ``m`` has none."""
    pre, miss = maker.prefix, []
    if m.lat_deg is None:
        miss.append(
            " or ".join([f"{pre}:{maker.lat[0]}/{maker.lon[0]}"] if maker.lat else [])
            + (" or " if maker.lat else "")
            + "EXIF GPSLatitude/GPSLongitude"
        )
    if m.altitude_m is None:
        miss.append((f"{pre}:{maker.altitude[0]} or " if maker.altitude else "") + "EXIF GPSAltitude")
    return miss


def _read_maker(m: PhotoMeta, maker: MakerTags, props: dict, ex: dict, notes: list) -> None:
    """Fill ``m`` from a non-DJI maker's tags (:mod:`geoloc.io.photo_makers`)."""
    m.maker = maker.name
    own: dict = {}
    for u in maker.namespaces:
        for k, v in props.get(u, {}).items():
            own.setdefault(k, v)
    ang = angles_namespace(maker, props)
    m.xmp = {**own, **ang}
    _maker_position(m, maker, own, ex, notes)
    missing = _maker_attitude(m, maker, own, ang, notes)
    _maker_lens(m, maker, own, notes)
    m.missing = tuple(_missing_position_tags(m, maker) + missing)


# --------------------------------------------------------------------------- lens, sensor, pose


def scale_lens(lens: Lens, width: int, height: int) -> Lens:
    """``lens`` for the same image resampled to ``width`` x ``height`` pixels.

    In coordinates whose origin is the image's top-left corner (OpenCV's u + 0.5)
    a resampling is x' = s x exactly, so fx' = s fx and u0' + 0.5 = s (u0 + 0.5);
    the distortion coefficients act on normalised coordinates and do not change.
    """
    sx, sy = width / lens.width, height / lens.height
    return dataclasses.replace(
        lens,
        fx=lens.fx * sx,
        fy=lens.fy * sy,
        skew=lens.skew * sx,
        cx=(lens.cx + 0.5) * sx - 0.5,
        cy=(lens.cy + 0.5) * sy - 0.5,
        width=int(width),
        height=int(height),
    )


def database_lens(meta: PhotoMeta) -> DbLens | None:
    """The camera database's pinhole for the photo (:mod:`geoloc.io.camera_db`), or None."""
    from geoloc.io.camera_db import db_lens, find_camera

    entry = find_camera(meta.make, meta.model, meta.full_width, meta.full_height)
    return db_lens(entry, meta.full_width, meta.full_height, meta.focal_mm) if entry is not None else None


def lens_source(meta: PhotoMeta) -> str:
    """Which tags the photo's lens comes from (written to every output row)."""
    if meta.dewarp is not None and meta.xmp.get("_calibration_tags") == PIX4D_CALIBRATION:
        return f"brown ({PIX4D_CALIBRATION})"
    if meta.dewarp is not None:
        return (
            "pinhole (DewarpData, DewarpFlag=1: already undistorted)" if meta.dewarp_flag == 1 else "brown (DewarpData)"
        )
    if meta.calibrated_focal_px is not None:
        if meta.maker not in ("", "DJI"):
            return f"pinhole ({meta.xmp.get('_calibration_tags', 'calibrated focal length')}, X/Y)"
        return "pinhole (CalibratedFocalLength, CalibratedOpticalCenterX/Y)"
    db = database_lens(meta)
    if db is not None:
        return f"pinhole ({db.describe()})"
    if meta.focal_35mm is not None:
        return "pinhole (EXIF FocalLengthIn35mmFilm, approximate)"
    return ""


def lens_from_photo(meta: PhotoMeta) -> Lens:
    """The photo's lens, in the raster's pixels (OpenCV convention, as the lenses take it).

    * DewarpData (and DewarpFlag not 1): a :class:`BrownLens` with DewarpData's
      fx, fy, k1, k2, p1, p2, k3 (k4..k6 from DewarpDataK6) and the principal
      point at the image centre plus DewarpData's offsets cx, cy.
    * DewarpFlag = 1 (the camera already removed the distortion, keeping the
      camera matrix): a :class:`PinholeLens` with DewarpData's fx, fy and
      principal point.
    * no DewarpData: a pinhole with fx = fy = CalibratedFocalLength at
      CalibratedOpticalCenterX/Y (the image centre if absent); without those, an
      approximate pinhole from EXIF FocalLengthIn35mmFilm (35 mm equivalent by the
      diagonal: f = f35 * diagonal / 43.27 mm) at the image centre.

    DJI's pixel coordinates have their origin at the image's top-left corner
    (module docstring): the OpenCV principal point is DJI's minus 0.5. The tags are
    in pixels of the full-resolution image; a resized photo's lens is scaled to its
    raster (:func:`scale_lens`).

    Raises
    ------
    PhotoTagError
        None of DewarpData, CalibratedFocalLength, FocalLengthIn35mmFilm.
    """
    W, H = meta.full_width, meta.full_height
    kind: type[PinholeLens] | type[BrownLens] = PinholeLens
    coeffs: dict = {}
    if meta.dewarp is not None:
        d = meta.dewarp
        fx, fy, x0, y0 = d.fx, d.fy, W / 2.0 + d.cx, H / 2.0 + d.cy
        if meta.dewarp_flag != 1:
            kind, coeffs = BrownLens, d.coefficients
    elif meta.calibrated_focal_px is not None:
        fx = fy = meta.calibrated_focal_px
        if meta.calibrated_focal_y_px is not None:
            fy = meta.calibrated_focal_y_px
        x0 = meta.calibrated_center_x_px if meta.calibrated_center_x_px is not None else W / 2.0
        y0 = meta.calibrated_center_y_px if meta.calibrated_center_y_px is not None else H / 2.0
    elif (db := database_lens(meta)) is not None:
        fx, fy, x0, y0 = db.fx, db.fy, W / 2.0, H / 2.0
    elif meta.focal_35mm is not None:
        fx = fy = meta.focal_35mm * math.hypot(W, H) / _DIAGONAL_35MM
        x0, y0 = W / 2.0, H / 2.0
    else:
        raise PhotoTagError(
            meta.path,
            (
                (
                    "drone-dji:DewarpData or drone-dji:CalibratedFocalLength or "
                    "a camera of the camera database (assets/cameras/drone_cameras.csv, "
                    f"EXIF Make/Model {meta.make!r}/{meta.model!r}) or "
                    "EXIF FocalLengthIn35mmFilm"
                ),
            ),
            why="has no lens calibration (give a sensor file instead)",
        )
    full = kind(fx=fx, fy=fy, cx=x0 - 0.5, cy=y0 - 0.5, width=W, height=H, **coeffs)
    return scale_lens(full, meta.width, meta.height) if meta.resized else full


def lens_uncertainty(meta: PhotoMeta) -> dict:
    """The lens's 1-sigma errors as ``[uncertainty]`` keys (``fx_px``, ``fy_px``, raster pixels).

    Only a lens from the camera database has a stated one (:mod:`geoloc.io.camera_db`: the nominal
    focal length against a calibrated one, and its rounding); {} for calibrated lenses (the
    maker states none) and for the approximate 35 mm lens (no stated precision).
    """
    if meta.dewarp is not None or meta.calibrated_focal_px is not None:
        return {}
    db = database_lens(meta)
    if db is None:
        return {}
    return {"fx_px": db.sigma_fx * meta.scale_x, "fy_px": db.sigma_fy * meta.scale_y}


def sensor_from_photo(meta: PhotoMeta) -> FrameSensor:
    """The photo's camera: :func:`lens_from_photo` on the earth-referenced ``yaw-pitch-roll`` preset."""
    name = " ".join(s for s in (meta.make, meta.model) if s) or meta.name
    return FrameSensor(lens=lens_from_photo(meta), gimbal=PRESETS[GIMBAL_PRESET], name=f"{name} ({lens_source(meta)})")


def camera_height(meta: PhotoMeta, altitude_datum: str = "egm96") -> tuple[float, float]:
    """The camera's ellipsoidal height [m] and the EGM96 undulation N [m] at the photo.

    ``altitude_datum="egm96"``: AbsoluteAltitude (else EXIF GPSAltitude) is an
    EGM96 orthometric height H and h = H + N; ``"ellipsoid"``: it is h already.
    N is returned in both cases (it is what a wrong choice would cost).
    """
    if altitude_datum not in ALTITUDE_DATUMS:
        raise ValueError(f"altitude_datum = {altitude_datum!r}: must be one of {ALTITUDE_DATUMS}")
    missing = [REQUIRED["position"]] if meta.lat_deg is None or meta.lon_deg is None else []
    missing += [REQUIRED["altitude"]] if meta.altitude_m is None else []
    if meta.lat_deg is None or meta.lon_deg is None or meta.altitude_m is None:
        raise PhotoTagError(meta.path, missing)
    n = float(egm96_undulation(math.radians(meta.lat_deg), math.radians(meta.lon_deg)))
    h = meta.altitude_m + (n if altitude_datum == "egm96" else 0.0)
    return h, n


def pose_from_photo(meta: PhotoMeta, altitude_datum: str = "egm96") -> Pose:
    """The photo's state: GPS position, ellipsoidal height (:func:`camera_height`), flight attitude, gimbal angles.

    The flight yaw/pitch/roll become heading/pitch/roll (0 where not tagged); the
    gimbal's ``angles_deg`` are ``gimbal_yaw``, ``gimbal_pitch``, ``gimbal_roll``
    (earth-referenced, NED, z-y-x, as DJI writes them).
    """
    if meta.missing:
        raise PhotoTagError(meta.path, meta.missing)
    h, _ = camera_height(meta, altitude_datum)
    gimbal = {name: getattr(meta, f"{name}_deg") for name in GIMBAL_ANGLES}
    absent = [REQUIRED[f"{name}_deg"] for name, v in gimbal.items() if v is None]
    if meta.lat_deg is None or meta.lon_deg is None or absent:  # (meta.missing names them already)
        raise PhotoTagError(meta.path, absent or [REQUIRED["position"]])
    return Pose.from_deg(
        meta.lat_deg,
        meta.lon_deg,
        h,
        meta.flight_yaw_deg or 0.0,
        meta.flight_pitch_deg or 0.0,
        meta.flight_roll_deg or 0.0,
        angles_deg=gimbal,
    )


def photo_sensor(meta: PhotoMeta, sensor: FrameSensor | None = None) -> tuple[FrameSensor, str]:
    """The sensor to locate ``meta``'s pixels with, and where its lens comes from.

    Without ``sensor``: :func:`sensor_from_photo`. With one (a user's calibrated
    sensor): it replaces the photo's lens; it must take the DJI angles
    (:data:`GIMBAL_ANGLES`), and be the size of the raster, or of the
    full-resolution image (then it is scaled to the raster, as the tags would be).

    Raises
    ------
    TypeError
        ``sensor`` is not a FrameSensor.
    ValueError
        The sensor's gimbal angles or size do not fit the photo (names both).
    """
    if sensor is None:
        return sensor_from_photo(meta), lens_source(meta)
    if not isinstance(sensor, FrameSensor):
        raise TypeError(f"sensor = {sensor!r}: must be a FrameSensor (a frame camera)")
    if set(sensor.angle_names) != set(GIMBAL_ANGLES):
        raise ValueError(
            f"sensor {sensor.name or ''} uses the {sensor.gimbal.name} gimbal with angles "
            f"{list(sensor.angle_names)}; a DJI photo gives {list(GIMBAL_ANGLES)} in NED: "
            f'use the {GIMBAL_PRESET!r} preset ([gimbal] preset = "{GIMBAL_PRESET}")'
        )
    label = f"sensor file{' ' + sensor.name if sensor.name else ''}"
    if (sensor.cols, sensor.rows) == (meta.width, meta.height):
        return sensor, label
    if (sensor.cols, sensor.rows) == (meta.full_width, meta.full_height):
        return dataclasses.replace(
            sensor, lens=scale_lens(sensor.lens, meta.width, meta.height)
        ), f"{label}, scaled to the resized raster"
    raise ValueError(
        f"{meta.name}: the sensor is {sensor.cols} x {sensor.rows} pixels, the photo "
        f"{meta.width} x {meta.height} (full resolution {meta.full_width} x {meta.full_height})"
    )


def photo_columns(meta: PhotoMeta) -> dict:
    """The photo's own fields as output columns (degrees, metres)."""
    return {
        "absolute_altitude_m": meta.absolute_altitude_m,
        "relative_altitude_m": meta.relative_altitude_m,
        "heading_deg": meta.flight_yaw_deg,
        "pitch_deg": meta.flight_pitch_deg,
        "roll_deg": meta.flight_roll_deg,
        "gimbal_yaw_deg": meta.gimbal_yaw_deg,
        "gimbal_pitch_deg": meta.gimbal_pitch_deg,
        "gimbal_roll_deg": meta.gimbal_roll_deg,
        "rtk_flag": meta.rtk_flag,
        "make": meta.make,
        "model": meta.model,
        "maker": meta.maker,
        "lens_fx_sigma_px": lens_uncertainty(meta).get("fx_px"),
    }
