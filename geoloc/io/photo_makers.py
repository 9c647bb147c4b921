"""Drone photo metadata by maker: one small table per maker (XMP namespace, tag names, angle conventions).

:func:`geoloc.io.photos.read_photo` reads DJI's ``drone-dji`` tags itself; for every other maker
it picks a :class:`MakerTags` of :data:`MAKERS` by the XMP namespaces the photo holds (then by its
EXIF Make) and reads the tags named there. Every maker's camera angles are turned into DJI's
convention, the one the ``yaw-pitch-roll`` gimbal preset takes (earth-referenced, NED, z-y-x:
yaw clockwise from north, pitch up from the horizon, roll about the line of sight;
``docs/conventions.md``, "Gimbal presets"), so a photo of any maker becomes the same sensor and
pose. ``docs/photos.md``, "Other makers", is the user's page.

Where each table comes from (no maker's document could be re-read while this was written, offline;
each entry names what it follows, and its test builds metadata from that list, not from a photo):

* **Skydio** (namespace ``http://www.skydio.com/drone-skydio/1.0/``; OpenAthena spells it
  ``https://``, both are read): Skydio's "Skydio camera and metadata overview" (Skydio support
  article 4417425974683), as read by OpenAthena (``MetadataExtractor.handleSKYDIO``, AGPL-3.0,
  read, not copied): ``Latitude``, ``Longitude``, ``AbsoluteAltitude``, ``RelativeAltitude``, the
  struct ``CameraOrientationNED`` with ``Yaw``, ``Pitch``, ``Roll`` in degrees (NED, pitch up from
  the horizon: OpenAthena negates it to get its "down is positive" angle, exactly as for DJI's
  GimbalPitchDegree), and the structs ``CalibratedFocalLength`` and ``CalibratedOpticalCenter``
  (``X``, ``Y``, pixels). Newer firmware writes the structs as child elements
  (``rdf:parseType="Resource"``), older as attributes of the struct's element: both are read.
* **Parrot ANAFI** (``http://www.parrot.com/drone-parrot/1.0/``): Parrot's "Photo metadata"
  page of the GroundSDK tools (developer.parrot.com/docs/groundsdk-tools/photo-metadata.html), as
  read by OpenAthena (``handlePARROT``): ``CameraYawDegree``, ``CameraPitchDegree``,
  ``CameraRollDegree`` (degrees, pitch up from the horizon, the camera's own earth-referenced
  attitude), ``DroneYawDegree`` ... for the airframe; the position is EXIF GPS only. Heights: EXIF
  GPSAltitude is EGM96 on ANAFI 4K/Thermal/USA and WGS-84 ellipsoidal on ANAFI Ai (Parrot's page,
  quoted by OpenAthena).
* **Pix4D camera tags** (``Camera:``, ``http://pix4d.com/camera/1.0/``), written by Autel's older
  firmware, MicaSense, Parrot Sequoia and Sentera: Pix4D's articles "Yaw, Pitch, Roll and Omega,
  Phi, Kappa angles" (support.pix4d.com 202558969) and "How to write XMP tags" (as read by
  OpenAthena ``handleAUTEL`` and by OpenDroneMap ``opendm/photo.py``, ``compute_opk``, AGPL-3.0):
  ``Camera:Yaw``, ``Camera:Pitch``, ``Camera:Roll`` in degrees; at (0, 0, 0) the camera looks
  **straight down** with the top of the image towards north; the camera's attitude is
  R = Rz(yaw) Ry(pitch) Rx(roll) in NED with the camera axes x = image top, y = image right,
  z = line of sight, so pitch 0 is nadir and 90 looks at the horizon (OpenAthena: "pitch 0 is
  down, 90 is forwards towards horizon").
* **MicaSense** (RedEdge, Altum): the Pix4D ``Camera:`` tags above (degrees), plus
  ``DLS:Yaw``, ``DLS:Pitch``, ``DLS:Roll`` (``http://micasense.com/DLS/1.0/``) in **radians**:
  the attitude of the downwelling light sensor on the airframe, not of the camera (MicaSense's
  ``imageprocessing`` library, ``metadata.py``, ``dls_pose``: "yaw, pitch, roll in radians").
  They are kept in ``PhotoMeta.xmp`` and not used for the camera. The photos are 16-bit TIFFs,
  one per band.
* **Teal** (Teal 2; EXIF Make "Teledyne FLIR", Hadron 640R / Boson 640 cameras): no tag list
  published by Teal is known to us. OpenAthena (``handleTeal``) reads the Adobe ``exif:``
  namespace's ``PlatformYaw``, ``PlatformPitch``, ``PlatformRoll``, ``CameraYaw``,
  ``CameraPitch``, ``CameraRoll`` (rationals such as ``"12345/100"``, degrees), the camera's
  angles relative to the platform, and adds them. Here the two rotations are composed
  (R = R_platform R_camera, both z-y-x), which equals OpenAthena's sums when the platform is
  level and is exact for a camera whose angles are relative to the airframe; say so before
  trusting a Teal photo flown with the airframe banked.
"""

from __future__ import annotations

from typing import Any

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "MAKERS",
    "MakerTags",
    "earth_gimbal_deg",
    "maker_by_name",
    "pick_maker",
    "rotation_zyx",
    "xmp_properties",
    "xmp_values",
    "zyx_from_rotation",
]

_RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_SKIP_NS = (_RDF, "adobe:ns:meta/")

#: The conventions a maker's camera angles come in.
CONVENTIONS = {
    "ned-horizon": "earth-referenced NED z-y-x: yaw from north, pitch up from the horizon, roll about "
    "the line of sight (DJI's gimbal; the yaw-pitch-roll preset)",
    "pix4d-nadir": "Pix4D: R = Rz(yaw) Ry(pitch) Rx(roll), camera x = image top, z = line of sight; "
    "(0, 0, 0) looks straight down, top of the image north; pitch 0 = nadir",
    "platform-relative": "camera angles relative to the platform (both z-y-x, pitch up from the "
    "horizon), composed with the platform's attitude",
}


@dataclass(frozen=True)
class MakerTags:
    """One maker's tags: where the position, heights and camera angles are, and their conventions.

    Tag names are paths inside one XMP namespace: ``"Latitude"``, or ``"Struct/Field"`` for a field
    of an XMP struct. Each field lists alternatives, tried in order.

    Attributes
    ----------
    name : str
        The maker (``"Skydio"``), as messages and the ``maker`` column say it.
    namespaces : tuple of str
        The XMP namespace URIs (spellings) that identify the maker; its tags are read in them.
    prefix : str
        The namespace's usual prefix, for messages (``drone-skydio``).
    makes : tuple of str
        Lower-case words of EXIF Make that identify the maker when its namespace is absent.
    lat, lon, altitude, relative_altitude : tuple of str
        Position [deg] and heights [m]; empty: the EXIF GPS IFD.
    yaw, pitch, roll : tuple of str
        The camera's angles, in ``unit`` and ``convention``.
    platform_yaw, platform_pitch, platform_roll : tuple of str
        The airframe's attitude (degrees; with ``convention="platform-relative"`` the camera's
        angles are relative to it).
    focal_x_px, focal_y_px, center_x_px, center_y_px : tuple of str
        A calibrated pinhole in the photo (pixels of the full-resolution image, corner origin).
    unit : {"deg", "rad"}
    convention : str
        A key of :data:`CONVENTIONS`.
    altitude_datum : str
        What the maker's documents say of the altitude's datum (messages only; the replay's
        ``altitude_datum`` decides).
    source : str
        Where the tag list and the conventions come from.
    """

    name: str
    namespaces: tuple
    prefix: str
    makes: tuple = ()
    lat: tuple = ()
    lon: tuple = ()
    altitude: tuple = ()
    relative_altitude: tuple = ()
    yaw: tuple = ()
    pitch: tuple = ()
    roll: tuple = ()
    platform_yaw: tuple = ()
    platform_pitch: tuple = ()
    platform_roll: tuple = ()
    focal_x_px: tuple = ()
    focal_y_px: tuple = ()
    center_x_px: tuple = ()
    center_y_px: tuple = ()
    unit: str = "deg"
    convention: str = "ned-horizon"
    altitude_datum: str = "not stated"
    source: str = ""
    extra: dict = field(default_factory=dict)

    def tag_names(self, which: str) -> list:
        """``prefix:Tag`` names of a field (for messages)."""
        return [f"{self.prefix}:{t}" for t in getattr(self, which)]

    def required_names(self) -> dict:
        """PhotoMeta field -> the tags that give it (alternatives joined by "or")."""

        def alt(which):
            names = self.tag_names(which)
            if which in ("platform_yaw", "platform_pitch", "platform_roll") and not names:
                return ""
            return " or ".join(names)

        out = {"gimbal_yaw_deg": alt("yaw"), "gimbal_pitch_deg": alt("pitch"), "gimbal_roll_deg": alt("roll")}
        if self.convention == "platform-relative":
            out.update(
                flight_yaw_deg=alt("platform_yaw"),
                flight_pitch_deg=alt("platform_pitch"),
                flight_roll_deg=alt("platform_roll"),
            )
        return out


_SKYDIO_SRC = (
    "Skydio support article 4417425974683, 'Skydio camera and metadata overview', as read by "
    "OpenAthena MetadataExtractor.handleSKYDIO (AGPL-3.0; read, not copied)"
)
_PIX4D_SRC = (
    "Pix4D support articles 202558969 'Yaw, Pitch, Roll and Omega, Phi, Kappa angles' and 'How "
    "to write XMP tags'; as read by OpenAthena handleAUTEL and OpenDroneMap opendm/photo.py"
)

#: The makers read besides DJI (DJI's own reader is :func:`geoloc.io.photos.read_photo`'s).
MAKERS = (
    MakerTags(
        name="Skydio",
        prefix="drone-skydio",
        namespaces=("http://www.skydio.com/drone-skydio/1.0/", "https://www.skydio.com/drone-skydio/1.0/"),
        makes=("skydio",),
        lat=("Latitude",),
        lon=("Longitude",),
        altitude=("AbsoluteAltitude",),
        relative_altitude=("RelativeAltitude",),
        yaw=("CameraOrientationNED/Yaw",),
        pitch=("CameraOrientationNED/Pitch",),
        roll=("CameraOrientationNED/Roll",),
        focal_x_px=("CalibratedFocalLength/X",),
        focal_y_px=("CalibratedFocalLength/Y",),
        center_x_px=("CalibratedOpticalCenter/X",),
        center_y_px=("CalibratedOpticalCenter/Y",),
        convention="ned-horizon",
        altitude_datum="EGM96 per OpenAthena (Skydio 2); users report WGS-84 ellipsoidal heights on the X10",
        source=_SKYDIO_SRC,
    ),
    MakerTags(
        name="Parrot",
        prefix="drone-parrot",
        namespaces=("http://www.parrot.com/drone-parrot/1.0/",),
        makes=("parrot",),
        yaw=("CameraYawDegree",),
        pitch=("CameraPitchDegree",),
        roll=("CameraRollDegree",),
        platform_yaw=("DroneYawDegree",),
        platform_pitch=("DronePitchDegree",),
        platform_roll=("DroneRollDegree",),
        convention="ned-horizon",
        altitude_datum="EXIF GPSAltitude: EGM96 on ANAFI 4K/Thermal/USA, WGS-84 ellipsoid on ANAFI Ai (Parrot)",
        source="Parrot GroundSDK tools, 'Photo metadata' (developer.parrot.com/docs/groundsdk-tools/"
        "photo-metadata.html), as read by OpenAthena handlePARROT",
    ),
    MakerTags(
        name="MicaSense",
        prefix="Camera",
        namespaces=("http://micasense.com/MicaSense/1.0/", "http://micasense.com/DLS/1.0/"),
        makes=("micasense",),
        yaw=("Yaw",),
        pitch=("Pitch",),
        roll=("Roll",),
        convention="pix4d-nadir",
        altitude_datum="EXIF GPSAltitude, datum not stated",
        source=_PIX4D_SRC + "; DLS:Yaw/Pitch/Roll in radians per MicaSense imageprocessing metadata.py "
        "(dls_pose), the light sensor's attitude, not used",
        extra={"angles_namespace": "http://pix4d.com/camera/1.0/"},
    ),
    MakerTags(
        name="Teal",
        prefix="exif",
        namespaces=(),
        makes=("teledyne flir", "teal"),
        yaw=("CameraYaw",),
        pitch=("CameraPitch",),
        roll=("CameraRoll",),
        platform_yaw=("PlatformYaw",),
        platform_pitch=("PlatformPitch",),
        platform_roll=("PlatformRoll",),
        convention="platform-relative",
        altitude_datum="EXIF GPSAltitude, EGM96 per OpenAthena",
        source="no tag list published by Teal is known to us; OpenAthena handleTeal reads these Adobe "
        "exif: properties (rationals, degrees) and adds camera to platform",
        extra={"angles_namespace": "http://ns.adobe.com/exif/1.0/"},
    ),
    MakerTags(
        name="Pix4D Camera tags (Autel, Sequoia, Sentera)",
        prefix="Camera",
        namespaces=("http://pix4d.com/camera/1.0/", "http://pix4d.com/camera/1.0"),
        makes=("autel", "autel robotics", "sentera"),
        yaw=("Yaw",),
        pitch=("Pitch",),
        roll=("Roll",),
        convention="pix4d-nadir",
        altitude_datum="EXIF GPSAltitude; OpenAthena: old Autel firmware writes MSL while its tags say ellipsoidal",
        source=_PIX4D_SRC,
    ),
)


def maker_by_name(name: str) -> MakerTags:
    for m in MAKERS:
        if m.name == name:
            return m
    raise KeyError(f"no maker {name!r}; makers: {[m.name for m in MAKERS]}")


def angles_namespace(maker: MakerTags, props: dict) -> dict:
    """The properties the maker's angles are read from (its own namespace, or the one it names)."""
    ns = maker.extra.get("angles_namespace")
    if ns is not None:
        out = dict(props.get(ns, {}))
        out.update(props.get(ns.rstrip("/"), {}))
        return out
    out = {}
    for u in maker.namespaces:
        for k, v in props.get(u, {}).items():
            out.setdefault(k, v)
    return out


def pick_maker(props: dict, make: str | None) -> MakerTags | None:
    """The maker of a photo: by the XMP namespaces present (with a property), then by EXIF Make."""
    present = {ns for ns, d in props.items() if d}
    for m in MAKERS:
        if any(ns in present for ns in m.namespaces):
            return m
    words = (make or "").strip().lower()
    if words:
        for m in MAKERS:
            if any(words.startswith(w) for w in m.makes):
                return m
    return None


# --------------------------------------------------------------------------- XMP, every namespace


def xmp_properties(root: Any) -> dict:
    """Every property of a parsed XMP tree: ``{namespace: {path: text}}``.

    ``path`` is the property's local name, or ``Struct/Field`` for a field of a struct (written
    as child elements, with or without ``rdf:parseType="Resource"`` or a nested
    ``rdf:Description``, or as attributes of the struct's element). A value inside
    ``rdf:Alt``/``rdf:Seq``/``rdf:Bag`` is the first ``rdf:li``. The first occurrence wins.
    """
    out: dict = {}

    def split(tag):
        if not isinstance(tag, str) or not tag.startswith("{"):
            return None, None
        ns, _, local = tag[1:].partition("}")
        return ns, local

    def put(ns, path, value):
        out.setdefault(ns, {}).setdefault(path, (value or "").strip())

    def walk(elem, prefix):
        ns, local = split(elem.tag)
        is_prop = ns is not None and ns not in _SKIP_NS
        here = f"{prefix}/{local}" if (is_prop and prefix) else (local if is_prop else prefix)
        for k, v in elem.attrib.items():
            ans, alocal = split(k)
            if ans is None or ans in _SKIP_NS or ans == "http://www.w3.org/XML/1998/namespace":
                continue
            put(ans, f"{here}/{alocal}" if here else alocal, v)
        children = [c for c in elem if isinstance(c.tag, str)]
        if is_prop:
            li = next(elem.iter(f"{{{_RDF}}}li"), None)
            props_below = [c for c in elem.iter() if c is not elem and split(c.tag)[0] not in (None, *_SKIP_NS)]
            if li is not None and not props_below:
                put(ns, here, li.text)
                return
            if not children:
                put(ns, here, elem.text)
                return
        for c in children:
            walk(c, here)

    walk(root, "")
    return out


# --------------------------------------------------------------------------- rotations


def rotation_zyx(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) [rad]: body (or camera) axes to NED."""
    cy, sy, cp, sp, cr, sr = (
        math.cos(yaw),
        math.sin(yaw),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(roll),
        math.sin(roll),
    )
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def zyx_from_rotation(r: ArrayLike) -> tuple:
    """(yaw, pitch, roll) [rad] of R = Rz Ry Rx; at pitch = +-90 deg (gimbal lock, e.g. a nadir
    camera) roll is set to 0 and yaw carries the whole rotation about the vertical."""
    r = np.asarray(r, float)
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if math.hypot(r[0, 0], r[1, 0]) < 1e-12:
        # R = Rz(yaw +- roll) Ry(+-90): row 1 of R is (0, cos, -+sin) of yaw +- roll
        return math.atan2(-r[0, 1], r[1, 1]), pitch, 0.0
    return math.atan2(r[1, 0], r[0, 0]), pitch, math.atan2(r[2, 1], r[2, 2])


#: Pix4D's camera axes (x = image top, y = right, z = line of sight) -> DJI's (x = line of sight,
#: y = right, z = image down): DJI's x is Pix4D's z, DJI's z is minus Pix4D's x, i.e. Ry(-90 deg).
_PIX4D_TO_DJI = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


def earth_gimbal_deg(
    convention: str, yaw_deg: float, pitch_deg: float, roll_deg: float, platform_deg: tuple | None = None
) -> tuple:
    """A maker's camera angles [deg] -> DJI's earth-referenced (yaw, pitch, roll) [deg].

    ``"ned-horizon"``: unchanged. ``"pix4d-nadir"``: R_dji = Rz Ry Rx (Pix4D) Ry(-90 deg), then
    z-y-x angles. ``"platform-relative"``: R = R_zyx(platform) R_zyx(camera), then z-y-x angles.
    """
    if convention == "ned-horizon":
        return float(yaw_deg), float(pitch_deg), float(roll_deg)
    rad = [math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg)]
    if convention == "pix4d-nadir":
        r = rotation_zyx(*rad) @ _PIX4D_TO_DJI
    elif convention == "platform-relative":
        if platform_deg is None:
            raise ValueError("platform-relative camera angles need the platform's attitude")
        r = rotation_zyx(*[math.radians(v) for v in platform_deg]) @ rotation_zyx(*rad)
    else:
        raise ValueError(f"convention = {convention!r}: one of {sorted(CONVENTIONS)}")
    y, p, rr = zyx_from_rotation(r)
    return math.degrees(y), math.degrees(p), math.degrees(rr)


def xmp_values(root: Any, namespace: str, name: str) -> list[str] | None:
    """Every value of the first property ``namespace:name`` of a parsed XMP tree, in order: the
    ``rdf:li`` items of an ``rdf:Seq``/``rdf:Bag``/``rdf:Alt``, else its text (or attribute) split at
    commas (``"0.1,0.2"``); None when the property is absent. :func:`xmp_properties` keeps only the
    first item of a list (a value); a calibration's coefficients need them all."""
    tag = f"{{{namespace}}}{name}"
    for elem in root.iter():
        if elem.tag == tag:
            items = [(li.text or "").strip() for li in elem.iter(f"{{{_RDF}}}li")]
            if items:
                return items
            return [t.strip() for t in (elem.text or "").split(",") if t.strip()]
        if tag in elem.attrib:
            return [t.strip() for t in elem.attrib[tag].split(",") if t.strip()]
    return None
