"""The sets beside and inside MISB ST 0601: ST 0102 security, ST 0903 VMTI, EG 0104.

* **ST 0102 Security Metadata Local Set**, nested in ST 0601 as tag 48: the
  classification and its country and caveats (:func:`decode_security`).
* **ST 0903 Video Moving Target Indicator Local Set**, nested as tag 74: the frame
  size and each detection's pixel centroid and bounding box (:func:`decode_vmti`),
  so a detection can be located on the ground like any pixel.
* **EG 0104 Predator UAV Basic Universal Set**, the older form of the same
  metadata with a 16-byte universal key per item (SMPTE ST 336 universal set):
  read into the ST 0601 field names (:func:`decode_eg0104`).

Every function takes bytes and returns plain values (no exception for bad bytes:
:class:`SetError` is raised with the reason, for the caller to turn into a quirk of
the packet that carried the set; the packet itself keeps its ST 0601 values).

References: MISB ST 0102 (Security Metadata Universal and Local Sets: its tag 1
classification enumeration 1..5, tags 3-6 text, tag 22 version), MISB ST 0903
(VMTI Local Set tags 1-13, 101; VTarget Pack tags 1-3, 5, 19, 20; the pixel number
Column + (Row - 1) x Frame Width with (1, 1) the top-left pixel), MISB EG 0104.5
(Predator UAV Basic Universal Metadata Set: the universal keys of its items, the same
keys as the "US key" column of MISB ST 0601's item table), SMPTE ST 336 (universal
keys, BER lengths, BER-OID tags).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from datetime import datetime, timezone

__all__ = [
    "SetError",
    "EG0104_KEY",
    "UAS_LS_KEY",
    "EG0104_ITEMS",
    "SECURITY_CLASSIFICATION",
    "decode_security",
    "decode_vmti",
    "decode_eg0104",
    "encode_eg0104",
    "encode_local_set",
    "encode_vmti",
]


class SetError(ValueError):
    """Bytes of a nested or universal set that cannot be read (the reason)."""


#: The 16-byte key of the EG 0104 Predator UAV Basic Universal Set (MISB EG 0104.5).
EG0104_KEY = bytes.fromhex("060E2B34020101010E01010201010000")
#: The 16-byte key of the UAS Datalink Local Set (MISB ST 0601; :data:`geoloc.io.klv.UAS_LS_KEY`).
UAS_LS_KEY = bytes.fromhex("060E2B34020B01010E01030101000000")

#: ST 0102 tag 1: the classification enumeration (MISB ST 0102, Security Classification).
SECURITY_CLASSIFICATION = {1: "UNCLASSIFIED", 2: "RESTRICTED", 3: "CONFIDENTIAL", 4: "SECRET", 5: "TOP SECRET"}


def _k(hexkey: str) -> bytes:
    return bytes.fromhex(hexkey.replace(" ", ""))


#: EG 0104 items read: universal key -> (ST 0601 field name, value type). ``"f"``: IEEE 754
#: big-endian float of 4 or 8 bytes (as its length says); ``"t"``: text; ``"u"``: unsigned
#: integer (microseconds since 1970 UTC, ST 0603); ``"dt"``: UTC date-time text
#: ``YYYYMMDDhhmmss``. Keys are compared without byte 8 (index 7, the registry version, which
#: writers and the standard's own table vary: 01, 02, 03, 07, 0A). The platform angles go to
#: the full-range fields (tags 90, 91 for pitch and roll): a float holds any angle.
EG0104_ITEMS: dict[bytes, tuple[str, str]] = {
    _k("06 0E 2B 34 01 01 01 07 07 01 10 01 06 00 00 00"): ("platform_heading_deg", "f"),
    _k("06 0E 2B 34 01 01 01 07 07 01 10 01 05 00 00 00"): ("platform_pitch_full_deg", "f"),
    _k("06 0E 2B 34 01 01 01 07 07 01 10 01 04 00 00 00"): ("platform_roll_full_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 02 04 02 00"): ("sensor_latitude_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 02 06 02 00"): ("sensor_longitude_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 02 01 02 02 00 00"): ("sensor_true_altitude_m", "f"),
    _k("06 0E 2B 34 01 01 01 02 04 20 02 01 01 08 00 00"): ("sensor_horizontal_fov_deg", "f"),
    _k("06 0E 2B 34 01 01 01 07 04 20 02 01 01 0A 01 00"): ("sensor_vertical_fov_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 08 01 01 00 00 00"): ("slant_range_m", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 09 02 01 00 00 00"): ("target_width_m", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 02 01 03 02 00 00"): ("frame_center_latitude_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 02 01 03 04 00 00"): ("frame_center_longitude_deg", "f"),
    _k("06 0E 2B 34 01 01 01 0A 07 01 02 01 03 16 00 00"): ("frame_center_elevation_m", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 07 01 00"): ("corner_latitude_1_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 08 01 00"): ("corner_latitude_2_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 09 01 00"): ("corner_latitude_3_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 0A 01 00"): ("corner_latitude_4_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 0B 01 00"): ("corner_longitude_1_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 0C 01 00"): ("corner_longitude_2_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 0D 01 00"): ("corner_longitude_3_deg", "f"),
    _k("06 0E 2B 34 01 01 01 03 07 01 02 01 03 0E 01 00"): ("corner_longitude_4_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 01 05 05 00 00 00 00 00"): ("mission_id", "t"),  # Episode Number
    _k("06 0E 2B 34 01 01 01 01 01 01 20 01 00 00 00 00"): ("platform_designation", "t"),  # Device Designation
    _k("06 0E 2B 34 01 01 01 01 04 20 01 02 01 01 00 00"): ("image_source_sensor", "t"),  # Image Source Device
    _k("06 0E 2B 34 01 01 01 01 07 01 01 01 00 00 00 00"): ("image_coordinate_system", "t"),
    _k("06 0E 2B 34 01 01 01 03 07 02 01 01 01 05 00 00"): ("precision_time_stamp_us", "u"),  # User Defined Time Stamp
    _k("06 0E 2B 34 01 01 01 01 07 02 01 02 01 01 00 00"): ("eg0104_start_time_us", "dt"),  # Start Date Time - UTC
    # No ST 0601 item has these: kept under their own names (their definitions differ from
    # tags 18-20, the sensor-relative angles, which EG 0104 does not carry)
    _k("06 0E 2B 34 01 01 01 01 07 01 10 01 02 00 00 00"): ("eg0104_angle_to_north_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 10 01 03 00 00 00"): ("eg0104_obliquity_angle_deg", "f"),
    _k("06 0E 2B 34 01 01 01 01 07 01 10 01 01 00 00 00"): ("eg0104_sensor_roll_deg", "f"),
}


def _mask(key: bytes) -> bytes:
    return key[:7] + key[8:]


_EG0104_BY_MASKED = {_mask(k): v for k, v in EG0104_ITEMS.items()}


# --------------------------------------------------------------------------- BER pieces


def ber_length(n: int) -> bytes:
    """BER length (SMPTE ST 336): short form below 128, else 0x80 + count, then the
    count of big-endian bytes."""
    if n < 0:
        raise ValueError(f"length {n} is negative")
    if n < 128:
        return bytes((n,))
    m = (n.bit_length() + 7) // 8
    return bytes((0x80 | m,)) + n.to_bytes(m, "big")


def ber_oid(tag: int) -> bytes:
    """BER-OID tag (SMPTE ST 336): 7 bits a byte, high bit set on every byte but the
    last (tags above 127 take two bytes: 128 -> 0x81 0x00)."""
    if tag < 1:
        raise ValueError(f"tag {tag} is not a positive integer")
    out = [tag & 0x7F]
    tag >>= 7
    while tag:
        out.append(0x80 | (tag & 0x7F))
        tag >>= 7
    return bytes(reversed(out))


def _ber_length(data, p: int, end: int) -> tuple[int, int]:
    """(length, next position) of the BER length at data[p] (SMPTE ST 336)."""
    if p >= end:
        raise SetError("a length runs past the end")
    b = data[p]
    if b < 0x80:
        return b, p + 1
    m = b & 0x7F
    if m == 0 or m > 8 or p + 1 + m > end:
        raise SetError(f"invalid BER length byte 0x{b:02X}")
    return int.from_bytes(data[p + 1 : p + 1 + m], "big"), p + 1 + m


def _ber_oid(data, p: int, end: int) -> tuple[int, int]:
    v = 0
    start = p
    while True:
        if p >= end or p - start >= 4:
            raise SetError("a tag runs past the end")
        b = data[p]
        p += 1
        v = (v << 7) | (b & 0x7F)
        if b < 0x80:
            return v, p


def local_set(data: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
    """The (tag, value) items of a local set (BER-OID tags, BER lengths)."""
    out = []
    p, end = 0, len(data)
    while p < end:
        tag, p = _ber_oid(data, p, end)
        ln, p = _ber_length(data, p, end)
        if p + ln > end:
            raise SetError(f"tag {tag}: length {ln} runs past the end of the set")
        out.append((tag, bytes(data[p : p + ln])))
        p += ln
    return out


def _uint(v: bytes) -> int:
    return int.from_bytes(v, "big")


def _text(v: bytes) -> str:
    return v.decode("utf-8", "replace")


# --------------------------------------------------------------------------- ST 0102


def decode_security(value: bytes) -> dict:
    """The ST 0102 Security Local Set (ST 0601 tag 48) as fields.

    Returns ``security_classification`` (its name, or ``"unknown (N)"``),
    ``security_classifying_country``, ``security_sci_shi``, ``security_caveats``,
    ``security_releasing_instructions`` (text) and ``security_version`` (int), those
    present. Raises :class:`SetError` for a set that cannot be walked.
    """
    f: dict = {}
    for tag, v in local_set(value):
        if tag == 1 and len(v) == 1:
            f["security_classification"] = SECURITY_CLASSIFICATION.get(v[0], f"unknown ({v[0]})")
        elif tag == 3:
            f["security_classifying_country"] = _text(v)
        elif tag == 4:
            f["security_sci_shi"] = _text(v)
        elif tag == 5:
            f["security_caveats"] = _text(v)
        elif tag == 6:
            f["security_releasing_instructions"] = _text(v)
        elif tag == 22 and 1 <= len(v) <= 8:
            f["security_version"] = _uint(v)
    return f


# --------------------------------------------------------------------------- ST 0903


def _pixel(n: int, width: int | None) -> tuple[int, int] | None:
    """(row, column), 1-based, of ST 0903 pixel number n = column + (row - 1) width."""
    if width is None or width <= 0 or n < 1:
        return None
    return (n - 1) // width + 1, (n - 1) % width + 1


def decode_vmti(value: bytes) -> dict:
    """The ST 0903 VMTI Local Set (ST 0601 tag 74) as fields.

    Returns ``vmti_frame_width_px``, ``vmti_frame_height_px``, ``vmti_targets_detected``,
    ``vmti_targets_reported``, ``vmti_system_name``, ``vmti_version`` (those present) and
    ``vmti_detections``: a list of one dict per VTarget Pack of the VTarget Series (tag 101)
    with ``id`` and, where given, ``centroid_row``, ``centroid_col`` (from tag 1 through the
    frame width, or tags 19 and 20), ``box_top_left_row``, ``box_top_left_col``,
    ``box_bottom_right_row``, ``box_bottom_right_col`` (tags 2, 3) and ``confidence_pct``
    (tag 5). Pixel rows and columns are 1-based with (1, 1) the top-left pixel, as in
    ST 0903 and geoloc's pixel convention (docs/conventions.md). Without a frame width
    (tag 8) the pixel numbers are kept as ``*_pixel_number``.

    Raises :class:`SetError` for a set or a pack that cannot be walked.
    """
    items = local_set(value)
    f: dict = {}
    width = None
    series = None
    for tag, v in items:
        if tag == 3:
            f["vmti_system_name"] = _text(v)
        elif tag == 4 and 1 <= len(v) <= 8:
            f["vmti_version"] = _uint(v)
        elif tag == 5 and 1 <= len(v) <= 8:
            f["vmti_targets_detected"] = _uint(v)
        elif tag == 6 and 1 <= len(v) <= 8:
            f["vmti_targets_reported"] = _uint(v)
        elif tag == 8 and 1 <= len(v) <= 8:
            width = f["vmti_frame_width_px"] = _uint(v)
        elif tag == 9 and 1 <= len(v) <= 8:
            f["vmti_frame_height_px"] = _uint(v)
        elif tag == 101:
            series = v
    dets = []
    if series is not None:
        p, end = 0, len(series)
        while p < end:
            ln, p = _ber_length(series, p, end)
            if p + ln > end:
                raise SetError(f"VTarget Pack of {ln} bytes runs past the end of the VTarget Series")
            pack = series[p : p + ln]
            p += ln
            tid, q = _ber_oid(pack, 0, len(pack))
            d: dict = {"id": tid}
            for tag, v in local_set(pack[q:]):
                if tag in (1, 2, 3) and 1 <= len(v) <= 8:
                    name = {1: "centroid", 2: "box_top_left", 3: "box_bottom_right"}[tag]
                    n = _uint(v)
                    rc = _pixel(n, width)
                    if rc is None:
                        d[f"{name}_pixel_number"] = n
                    else:
                        d[f"{name}_row"], d[f"{name}_col"] = rc
                elif tag == 5 and len(v) == 1:
                    d["confidence_pct"] = v[0]
                elif tag == 19 and 1 <= len(v) <= 8:
                    d["centroid_row"] = _uint(v)
                elif tag == 20 and 1 <= len(v) <= 8:
                    d["centroid_col"] = _uint(v)
            dets.append(d)
    f["vmti_detections"] = dets
    return f


def encode_local_set(items: Iterable[tuple[int, bytes]]) -> bytes:
    """A local set from (tag, value bytes) items (BER-OID tags, BER lengths): for tests and writers."""
    return b"".join(ber_oid(t) + ber_length(len(v)) + bytes(v) for t, v in items)


def encode_vmti(width: int, height: int, targets: Iterable[tuple], *, system: str = "", version: int = 5) -> bytes:
    """The value of an ST 0903 VMTI Local Set with a VTarget Series (tests, writers).

    ``targets``: (id, (row, col) centroid, (row, col) top left, (row, col) bottom right,
    confidence %) each, 1-based pixels; the pixel numbers are column + (row - 1) width.
    """

    def num(rc):
        n = rc[1] + (rc[0] - 1) * width
        return n.to_bytes(max(1, (n.bit_length() + 7) // 8), "big")

    packs = []
    for tid, c, tl, br, conf in targets:
        body = ber_oid(tid) + encode_local_set([(1, num(c)), (2, num(tl)), (3, num(br)), (5, bytes((conf,)))])
        packs.append(ber_length(len(body)) + body)
    items = [(4, bytes((version,)))]
    if system:
        items.append((3, system.encode()))
    items += [
        (5, bytes((len(packs),))),
        (6, bytes((len(packs),))),
        (8, width.to_bytes(2, "big")),
        (9, height.to_bytes(2, "big")),
        (101, b"".join(packs)),
    ]
    return encode_local_set(items)


# --------------------------------------------------------------------------- EG 0104


def _dt_us(text: str) -> int:
    t = datetime.strptime(text.strip()[:14], "%Y%m%d%H%M%S").replace(tzinfo=timezone.utc)
    return int(t.timestamp()) * 1_000_000


def decode_eg0104(value: bytes) -> tuple[dict, dict, list]:
    """The items of an EG 0104 universal set (the value after the set's key and length).

    Returns
    -------
    fields : dict
        ST 0601 field names (:data:`EG0104_ITEMS`) -> values: floats in the field's unit
        (EG 0104 gives degrees and metres as IEEE floats), text, integer microseconds.
        ``precision_time_stamp_us`` falls back on the Start Date Time when the set has no
        User Defined Time Stamp.
    unknown : dict
        The other items: universal key (hex) -> value bytes.
    quirks : list of str
        Items of an unexpected length (skipped).

    Raises
    ------
    SetError
        A key or a length running past the end.
    """
    fields: dict = {}
    unknown: dict = {}
    quirks: list = []
    p, end = 0, len(value)
    while p < end:
        if p + 16 > end:
            raise SetError(f"an item key at set byte {p} runs past the end")
        key = bytes(value[p : p + 16])
        ln, p = _ber_length(value, p + 16, end)
        if p + ln > end:
            raise SetError(f"item {key.hex()}: length {ln} runs past the end")
        v = bytes(value[p : p + ln])
        p += ln
        spec = _EG0104_BY_MASKED.get(_mask(key))
        if spec is None:
            unknown[key.hex()] = v
            continue
        name, kind = spec
        if kind == "f":
            if ln not in (4, 8):
                quirks.append(f"EG 0104 {name} in {ln} bytes (a float has 4 or 8): skipped")
                continue
            x = struct.unpack(">f" if ln == 4 else ">d", v)[0]
            if math.isfinite(x):
                fields[name] = x
            else:
                quirks.append(f"EG 0104 {name} is not a finite number: skipped")
        elif kind == "t":
            fields[name] = _text(v)
        elif kind == "u":
            if 1 <= ln <= 8:
                fields[name] = _uint(v)
            else:
                quirks.append(f"EG 0104 {name} in {ln} bytes: skipped")
        else:
            try:
                fields[name] = _dt_us(_text(v))
            except ValueError:
                quirks.append(f"EG 0104 {name} {_text(v)!r} is no YYYYMMDDhhmmss date: skipped")
    start = fields.pop("eg0104_start_time_us", None)
    if "precision_time_stamp_us" not in fields and start is not None:
        fields["precision_time_stamp_us"] = start
    return fields, unknown, quirks


def encode_eg0104(items: Iterable[tuple[bytes, bytes]]) -> bytes:
    """An EG 0104 packet from (universal key bytes, value bytes) items: key, BER length, items."""
    body = b"".join(bytes(k) + ber_length(len(v)) + bytes(v) for k, v in items)
    return EG0104_KEY + ber_length(len(body)) + body
