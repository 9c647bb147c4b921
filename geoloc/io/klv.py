"""MISB ST 0601 (UAS Datalink Local Set) KLV metadata: decoder and encoder.

Full-motion video from airborne cameras carries its pose and pointing metadata as
SMPTE ST 336 KLV packets of the UAS Datalink Local Set, MISB ST 0601: a 16-byte
universal key, a BER length and a local set of (tag, length, value) items, the
last of which is a 16-bit checksum. This module reads those packets from raw
``.klv`` / ``.bin`` files (concatenated packets), from MPEG-TS and other
containers through PyAV, and writes them (:func:`encode_packet`, :func:`write_ts`).

What is decoded: every item that matters for geolocation (platform attitude,
sensor position, field of view, sensor-relative pointing, slant range, frame
centre, image corners, target location and its error estimate), each with the
standard's linear mapping and its reserved error / out-of-range value; see
:data:`TAGS` and docs/klv.md. Decoded field names carry their unit, degrees and
metres as in the standard (``platform_heading_deg``, ``sensor_true_altitude_m``):
this is an edge of the package (docs/conventions.md: degrees only at the edges).
Heights keep the datum the standard gives them: ``sensor_true_altitude_m``,
``frame_center_elevation_m`` and ``target_location_elevation_m`` are above mean
sea level (orthometric), ``sensor_ellipsoid_height_m`` (tag 75) and
``frame_center_hae_m`` (tag 78) above the WGS-84 ellipsoid. Items of other tags
are kept raw (tag number -> bytes) in :attr:`Packet.unknown`.

Bad packets do not stop a read: a checksum mismatch, a truncated packet, a length
running past the end, an integer item longer than 8 bytes, or bytes that are no
packet at all are reported as a :class:`KlvError` (byte offset of the packet's key
in the file, and the reason) in the stream of results, and the scan resumes at the
next key. A packet whose Precision Time Stamp (Tag 2) goes back from the one before it
is kept in file order and carries the report in :attr:`Packet.time_back`.

What writers in the wild do is read (docs/klv.md, "Encoders in the wild"): an
integer item at another length than the standard's is decoded at its length with
the standard's step, an empty numeric item is absent, the nested ST 0102 security
(tag 48) and ST 0903 VMTI (tag 74) sets are decoded into fields
(:mod:`geoloc.io.klv_sets`), and packets of the older EG 0104 universal set are found
by their key and read into the same field names. Each such quirk is listed in
:attr:`Packet.quirks` and tallied once per kind by :class:`QuirkTally`.

Speed: packets of a stream mostly share one layout (the same items with the same
lengths in the same order). The decoder walks the items of the first packet of
each layout once and compiles the layout: two :class:`struct.Struct` (one to
recognise the layout from its tag and length bytes, one to unpack every value)
and a generated function that scales every value with its item's constants into
one dict. A run of many complete packets is decoded as a batch with numpy (the
packets gathered into one array, checksums summed and layouts matched for all at
once, each item's column scaled at once); the results are the same Packets as one
packet at a time, and a bad packet in the run goes to the per-packet path, which
reports it. :func:`packets_to_columns` on raw bytes skips the Packets altogether.
See docs/klv.md for figures.

References: MISB ST 0601 (UAS Datalink Local Set; tag numbers, mappings and the
example values of its item tables, Section 8 of ST 0601.11 and later), SMPTE ST
336 (KLV coding: universal keys, BER lengths, BER-OID tags).
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any, BinaryIO, Iterable, Iterator

import numpy as np

from geoloc.io.klv_sets import UAS_LS_KEY as _UAS_LS_KEY
from geoloc.io.klv_sets import EG0104_KEY, SetError, ber_length, ber_oid, decode_eg0104, decode_security, decode_vmti
from geoloc.userfiles import note_input
from geoloc.extras import require

__all__ = [
    "UAS_LS_KEY",
    "TAGS",
    "TAG_BY_NUMBER",
    "TAG_BY_NAME",
    "TagSpec",
    "Packet",
    "KlvError",
    "checksum",
    "ber_length",
    "ber_oid",
    "iter_packets",
    "read_klv_file",
    "read_ts_klv",
    "read_packets",
    "decode_packet",
    "decode_local_set",
    "encode_packet",
    "encode_value",
    "local_set_items",
    "add_items",
    "replace_values",
    "write_ts",
    "packets_to_columns",
    "QuirkTally",
    "EG0104_KEY",
    "DERIVED_FIELDS",
]

#: The 16-byte universal key of the UAS Datalink Local Set (MISB ST 0601, "UAS
#: Datalink LS" key 06.0E.2B.34.02.0B.01.01.0E.01.03.01.01.00.00.00).
UAS_LS_KEY = _UAS_LS_KEY

#: Largest packet (value length) the scanner accepts; a longer BER length is taken
#: as a corrupt length and reported, so a streaming read never buffers more.
MAX_PACKET_LENGTH = 1 << 24

OUT_OF_RANGE = "out of range"
ERROR = "error"

_CHECKSUM_TAG = 1


@dataclass(frozen=True)
class TagSpec:
    """One item of the UAS Datalink Local Set (MISB ST 0601, the item's tag table).

    Attributes
    ----------
    tag : int
        Tag number (BER-OID coded in the packet; tags above 127 take two bytes).
    name : str
        Field name of the decoded value, with its unit (``_deg``, ``_m``, ``_us``).
    title : str
        The item's name in the standard.
    kind : str
        ``"uint"``: unsigned integer of ``size`` bytes mapped linearly onto
        [lo, hi], value = lo + raw (hi - lo) / (2^(8 size) - 1).
        ``"int"``: signed integer mapped onto the symmetric [lo, hi] = [-hi, hi],
        value = raw (hi - lo) / (2^(8 size) - 2).
        ``"u64"``, ``"u8"``: unsigned integers kept as int; ``"str"``: text (UTF-8).
    size : int
        Length of the value in bytes (0: variable, for text).
    lo, hi : float
        The mapped range (for ``uint`` and ``int``).
    reserved : str
        Meaning of the reserved most negative raw value of an ``int`` item
        (-(2^(8 size - 1)): 0x8000, 0x80000000): ``"out of range"`` or ``"error"``;
        empty where the standard reserves none. Decoded as NaN with this flag.
    datum : str
        Vertical datum of a height: ``"MSL"`` or ``"HAE"`` (WGS-84 ellipsoid).
    """

    tag: int
    name: str
    title: str
    kind: str
    size: int = 0
    lo: float = 0.0
    hi: float = 0.0
    reserved: str = ""
    datum: str = ""

    @property
    def step(self) -> float:
        """Quantisation step (value of one raw count) of a mapped item."""
        if self.kind == "uint":
            return (self.hi - self.lo) / (2.0 ** (8 * self.size) - 1.0)
        if self.kind == "int":
            return (self.hi - self.lo) / (2.0 ** (8 * self.size) - 2.0)
        return 1.0

    @property
    def sentinel(self) -> int | None:
        """The reserved raw value, or None."""
        return -(1 << (8 * self.size - 1)) if self.reserved else None

    @property
    def fmt(self) -> str:
        """The :mod:`struct` code of the value (big-endian)."""
        if self.kind == "str":
            return "s"
        code = {1: "b", 2: "h", 4: "i", 8: "q"}[self.size]
        return code if self.kind == "int" else code.upper()


def _u(tag, name, title, size, lo, hi, datum=""):
    return TagSpec(tag, name, title, "uint", size, float(lo), float(hi), "", datum)


def _s(tag, name, title, size, hi, reserved, datum=""):
    return TagSpec(tag, name, title, "int", size, -float(hi), float(hi), reserved, datum)


def _t(tag, name, title):
    return TagSpec(tag, name, title, "str")


_CORNERS = []
for _i in range(4):
    _CORNERS.append(
        _s(
            26 + 2 * _i,
            f"offset_corner_latitude_{_i + 1}_deg",
            f"Offset Corner Latitude Point {_i + 1}",
            2,
            0.075,
            ERROR,
        )
    )
    _CORNERS.append(
        _s(
            27 + 2 * _i,
            f"offset_corner_longitude_{_i + 1}_deg",
            f"Offset Corner Longitude Point {_i + 1}",
            2,
            0.075,
            ERROR,
        )
    )
_FULL_CORNERS = []
for _i in range(4):
    _FULL_CORNERS.append(
        _s(82 + 2 * _i, f"corner_latitude_{_i + 1}_deg", f"Corner Latitude Point {_i + 1} (Full)", 4, 90, ERROR)
    )
    _FULL_CORNERS.append(
        _s(83 + 2 * _i, f"corner_longitude_{_i + 1}_deg", f"Corner Longitude Point {_i + 1} (Full)", 4, 180, ERROR)
    )

#: The decoded items, in tag order (MISB ST 0601 tag tables). Offset corners
#: (26-33) are offsets from the frame centre (23, 24); 82-89 are the full corners.
#: Corner points 1-4 are upper left, upper right, lower right, lower left.
TAGS: tuple[TagSpec, ...] = (
    TagSpec(2, "precision_time_stamp_us", "Precision Time Stamp", "u64", 8),  # us since 1970 UTC
    _t(3, "mission_id", "Mission ID"),
    _t(4, "platform_tail_number", "Platform Tail Number"),
    _u(5, "platform_heading_deg", "Platform Heading Angle", 2, 0, 360),
    _s(6, "platform_pitch_deg", "Platform Pitch Angle", 2, 20, OUT_OF_RANGE),
    _s(7, "platform_roll_deg", "Platform Roll Angle", 2, 50, OUT_OF_RANGE),
    _t(10, "platform_designation", "Platform Designation"),
    _t(11, "image_source_sensor", "Image Source Sensor"),
    _t(12, "image_coordinate_system", "Image Coordinate System"),
    _s(13, "sensor_latitude_deg", "Sensor Latitude", 4, 90, ERROR),
    _s(14, "sensor_longitude_deg", "Sensor Longitude", 4, 180, ERROR),
    _u(15, "sensor_true_altitude_m", "Sensor True Altitude", 2, -900, 19000, "MSL"),
    _u(16, "sensor_horizontal_fov_deg", "Sensor Horizontal Field of View", 2, 0, 180),
    _u(17, "sensor_vertical_fov_deg", "Sensor Vertical Field of View", 2, 0, 180),
    _u(18, "sensor_relative_azimuth_deg", "Sensor Relative Azimuth Angle", 4, 0, 360),
    _s(19, "sensor_relative_elevation_deg", "Sensor Relative Elevation Angle", 4, 180, ERROR),
    _u(20, "sensor_relative_roll_deg", "Sensor Relative Roll Angle", 4, 0, 360),
    _u(21, "slant_range_m", "Slant Range", 4, 0, 5e6),
    _u(22, "target_width_m", "Target Width", 2, 0, 1e4),
    _s(23, "frame_center_latitude_deg", "Frame Center Latitude", 4, 90, ERROR),
    _s(24, "frame_center_longitude_deg", "Frame Center Longitude", 4, 180, ERROR),
    _u(25, "frame_center_elevation_m", "Frame Center Elevation", 2, -900, 19000, "MSL"),
    *_CORNERS,
    _s(40, "target_location_latitude_deg", "Target Location Latitude", 4, 90, ERROR),
    _s(41, "target_location_longitude_deg", "Target Location Longitude", 4, 180, ERROR),
    _u(42, "target_location_elevation_m", "Target Location Elevation", 2, -900, 19000, "MSL"),
    _u(45, "target_error_ce90_m", "Target Error Estimate - CE90", 2, 0, 4095),
    _u(46, "target_error_le90_m", "Target Error Estimate - LE90", 2, 0, 4095),
    TagSpec(65, "uas_ls_version", "UAS Datalink LS Version Number", "u8", 1),
    _u(75, "sensor_ellipsoid_height_m", "Sensor Ellipsoid Height", 2, -900, 19000, "HAE"),
    _u(78, "frame_center_hae_m", "Frame Center Height Above Ellipsoid", 2, -900, 19000, "HAE"),
    _s(79, "sensor_north_velocity_m_s", "Sensor North Velocity", 2, 327, OUT_OF_RANGE),
    _s(80, "sensor_east_velocity_m_s", "Sensor East Velocity", 2, 327, OUT_OF_RANGE),
    *_FULL_CORNERS,
    _s(90, "platform_pitch_full_deg", "Platform Pitch Angle (Full)", 4, 90, OUT_OF_RANGE),
    _s(91, "platform_roll_full_deg", "Platform Roll Angle (Full)", 4, 90, OUT_OF_RANGE),
)
del _i

#: Tag number -> :class:`TagSpec`.
TAG_BY_NUMBER: dict[int, TagSpec] = {s.tag: s for s in TAGS}
#: Field name -> :class:`TagSpec`.
TAG_BY_NAME: dict[str, TagSpec] = {s.name: s for s in TAGS}

#: Fields decoded from the nested sets (ST 0102 security, tag 48; ST 0903 VMTI, tag 74) and
#: the EG 0104 items with no ST 0601 tag: read-only (the encoder writes the nested sets back
#: from their raw bytes in :attr:`Packet.unknown` and skips these names).
DERIVED_FIELDS = (
    "security_classification",
    "security_classifying_country",
    "security_sci_shi",
    "security_caveats",
    "security_releasing_instructions",
    "security_version",
    "vmti_system_name",
    "vmti_version",
    "vmti_targets_detected",
    "vmti_targets_reported",
    "vmti_frame_width_px",
    "vmti_frame_height_px",
    "vmti_detections",
    "eg0104_angle_to_north_deg",
    "eg0104_obliquity_angle_deg",
    "eg0104_sensor_roll_deg",
)
_FIELD_RANK = {s.name: i for i, s in enumerate(TAGS)}
_FIELD_RANK.update({n: len(TAGS) + i for i, n in enumerate(DERIVED_FIELDS)})
_RANK_LAST = len(_FIELD_RANK)


def _rank(name):
    return _FIELD_RANK.get(name, _RANK_LAST)


_NUMERIC_SPECS = [s for s in TAGS if s.kind != "str"]
_TEXT_SPECS = [s for s in TAGS if s.kind == "str"]
_NUMERIC_NAMES = frozenset(s.name for s in _NUMERIC_SPECS)


# --------------------------------------------------------------------------- results


class KlvError(ValueError):
    """A bad packet or unreadable bytes, reported in the stream of results (and raised
    by :func:`decode_packet`).

    Attributes
    ----------
    offset : int or None
        Byte offset of the packet's key in the file (of the first skipped byte for
        bytes that are no packet). In a container read through PyAV: the demuxer's
        byte position of the data packet that carried it (None if unknown).
    reason : str
        What is wrong.
    pts : int or None
        Presentation time stamp of the container packet (container reads only).
    """

    def __init__(self, offset: int | None, reason: str, pts: int | None = None):
        super().__init__(offset, reason)
        self.offset = offset
        self.reason = reason
        self.pts = pts

    def __str__(self) -> str:
        where = f"byte {self.offset}" if self.offset is not None else "unknown position"
        if self.pts is not None:
            where = f"pts {self.pts} ({where})"
        return f"{where}: {self.reason}"

    def __repr__(self) -> str:
        return f"KlvError(offset={self.offset!r}, reason={self.reason!r}, pts={self.pts!r})"

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, KlvError)
            and self.offset == other.offset
            and self.reason == other.reason
            and self.pts == other.pts
        )

    # unhashable, as equal errors must hash alike and these hold their own fields: Python sets
    # __hash__ to None itself in a class that defines __eq__ and not __hash__


@dataclass(eq=True, slots=True)
class Packet:
    """One decoded UAS Datalink Local Set packet.

    Attributes
    ----------
    fields : dict
        Decoded items by field name (see :data:`TAGS`): floats in the unit of the
        name, ``precision_time_stamp_us`` and ``uas_ls_version`` as int, text as
        str. A reserved (error / out-of-range) value is NaN, with its flag in
        ``flags``. Absent items are absent.
    offset : int or None
        Byte offset of the packet's key in the file (container reads: the
        demuxer's byte position of the data packet that carried it).
    flags : dict
        Field name -> ``"error"`` or ``"out of range"`` for reserved values.
    unknown : dict
        Tag number -> raw value bytes of the items not in :data:`TAGS`.
    checksum : int or None
        The packet's checksum item (tag 1), verified unless the read was asked not to.
    pts : int or None
        Presentation time stamp of the container packet (container reads only).
    time_base : Fraction or None
        Time base of ``pts`` [s].
    quirks : tuple of str
        The ways this packet departs from the standard while its values stay
        unambiguous (an item at another length than the standard's, an empty item,
        an undecodable nested set, ...), one text per kind; a read tallies them with
        :class:`QuirkTally` (docs/klv.md, "Encoders in the wild").
    time_back : str or None
        Set by the file readers (:func:`iter_packets`, :func:`read_klv_file`,
        :func:`read_ts_klv`) when this packet's Precision Time Stamp (MISB ST 0601
        Tag 2) is earlier than the packet's before it: one line naming this
        packet's index among the packets decoded (1-based) and byte offset, how far
        back, and the packet it goes back from. The packet is kept, in file order.
        Not part of a packet's equality (it is a note on the read, not the packet).
    """

    fields: dict
    offset: int | None = None
    flags: dict | None = None
    unknown: dict | None = None
    checksum: int | None = None
    pts: int | None = None
    time_base: Fraction | None = None
    quirks: tuple = ()
    time_back: str | None = field(default=None, compare=False)

    def __getitem__(self, name: str):
        return self.fields[name]

    def get(self, name: str, default: Any = None) -> Any:
        """``fields.get(name, default)``."""
        return self.fields.get(name, default)

    @property
    def time_s(self) -> float | None:
        """Presentation time [s] (container reads), else None."""
        if self.pts is None or self.time_base is None:
            return None
        return float(self.pts * self.time_base)

    def to_json(self) -> dict:
        """A JSON-ready dict: offset (and pts, time_s), the fields (NaN as None),
        then ``flags``, ``unknown`` (tag -> hex) and ``checksum`` where present."""
        d: dict = {}
        if self.offset is not None:
            d["offset"] = self.offset
        if self.pts is not None:
            d["pts"] = self.pts
            if self.time_base is not None:
                d["time_s"] = self.time_s
        f = self.fields
        for k in sorted(f, key=_rank):
            v = f[k]
            d[k] = None if isinstance(v, float) and v != v else v
        if self.flags:
            d["flags"] = dict(self.flags)
        if self.unknown:
            d["unknown"] = {str(t): v.hex() for t, v in self.unknown.items()}
        if self.checksum is not None:
            d["checksum"] = f"0x{self.checksum:04X}"
        return d


class _Bad(Exception):
    """A structural error inside one packet (its reason; the scanner adds the offset)."""


# --------------------------------------------------------------------------- coding pieces


def checksum(packet: bytes) -> int:
    """The ST 0601 checksum (tag 1) of a packet.

    A 16-bit running sum over every byte from the first byte of the key up to and
    including the checksum item's tag and length bytes, each byte at an even index
    (0, 2, ...) from the key's first byte added shifted left by 8 (MISB ST 0601,
    Tag 1, reference algorithm ``bcc_16``: ``bcc += buf[i] << (8 * ((i + 1) % 2))``);
    that is the sum of the big-endian 16-bit words, a trailing odd byte as the high
    byte of a last word.

    Parameters
    ----------
    packet : bytes
        The whole packet: key, length, local set, ending with the 2 checksum bytes
        (which are excluded from the sum).

    Returns
    -------
    int
        The checksum, 0..0xFFFF.
    """
    packet = bytes(packet)
    end = len(packet) - 2
    return ((_bytesum(packet[0:end:2]) << 8) + _bytesum(packet[1:end:2])) & 0xFFFF


def _bytesum(b: bytes) -> int:
    """Exact sum of the bytes of b.

    zlib.adler32's low half is 1 + (sum of the bytes mod 65521): exact for up to 256
    bytes (at most 65280), several times faster than ``sum(b)``.
    """
    if len(b) <= 256:
        return (zlib.adler32(b) & 0xFFFF) - 1
    return sum((zlib.adler32(b[i : i + 256]) & 0xFFFF) - 1 for i in range(0, len(b), 256))


# --------------------------------------------------------------------------- layouts


_INT_CODES = {1: "b", 2: "h", 4: "i", 8: "q"}


def _raw_code(spec: TagSpec, ln: int) -> str:
    """The :mod:`struct` code of a numeric item given in ``ln`` bytes (``{ln}s`` for 3, 5, 6, 7:
    converted by :func:`_ib`)."""
    code = _INT_CODES.get(ln)
    if code is None:
        return f"{ln}s"
    return code if spec.kind == "int" else code.upper()


def _ib(b: bytes, signed: bool) -> int:
    """A big-endian integer of any length (the items given in 3, 5, 6 or 7 bytes)."""
    return int.from_bytes(b, "big", signed=signed)


def _raw_bounds(spec: TagSpec) -> tuple[int, int]:
    """The raw values the standard's length of a mapped item can hold (the sentinel excluded):
    an item given in more bytes is in range only inside them (same step: docs/klv.md)."""
    if spec.kind == "uint":
        return 0, (1 << (8 * spec.size)) - 1
    lim = (1 << (8 * spec.size - 1)) - 1
    return -lim, lim


def _length_quirk(spec: TagSpec, ln: int) -> str | None:
    """The quirk text of a numeric item given in ``ln`` bytes (None at the standard's length)."""
    if spec.kind == "str" or ln == spec.size:
        return None
    if ln == 0:
        return f"tag {spec.tag} ({spec.title}) is empty (0 bytes): taken as absent"
    return (
        f"tag {spec.tag} ({spec.title}) in {ln} bytes, the standard's {spec.size}: "
        f"decoded at its length with the standard's step"
    )


class _Layout:
    """A compiled local-set layout: the items (tag, lengths) of a packet in order.

    ``hdr`` unpacks the tag and length bytes (the layout's signature, compared with
    ``hdr_vals``); ``vals`` unpacks every value (tag and length bytes skipped).
    ``quirks`` are the layout's departures from the standard (items at other lengths).
    """

    def __init__(self, items, data, vs):
        # items: list of (tag, item_start, value_start, length) with absolute positions.
        hdr_fmt, val_fmt = [">"], [">"]
        self.hdr_pos = []  # positions of tag/length bytes relative to the value start vs
        self.vitems = []  # (spec or None, tag, value offset relative to vs, length)
        p = vs
        kinds = []
        quirks = []
        for tag, t0, v0, ln in items:
            h = v0 - t0
            hdr_fmt.append(f"{h}B{ln}x")
            spec = TAG_BY_NUMBER.get(tag)
            if tag == _CHECKSUM_TAG:
                code = "H"
            elif spec is None or spec.kind == "str":
                code = f"{ln}s"
            else:
                code = _raw_code(spec, ln) if ln else "0s"
                q = _length_quirk(spec, ln)
                if q is not None and q not in quirks:
                    quirks.append(q)
            val_fmt.append(f"{h}x{code}")
            self.hdr_pos.extend(range(t0 - vs, v0 - vs))
            self.vitems.append((spec, tag, v0 - vs, ln))
            kinds.append((spec, tag, ln))
            p = v0 + ln
        self.length = p - vs
        self.quirks = tuple(quirks)
        self.hdr = struct.Struct("".join(hdr_fmt))
        self.hdr_vals = self.hdr.unpack_from(data, vs)
        self.vals = struct.Struct("".join(val_fmt))
        self.hdr_pos = np.array(self.hdr_pos, dtype=np.intp)
        self.hdr_arr = (
            np.frombuffer(bytes(data[vs + int(i)] for i in self.hdr_pos), np.uint8)
            if len(self.hdr_pos)
            else np.zeros(0, np.uint8)
        )

        self.ck_idx = next((i for i, (_, tag, _) in enumerate(kinds) if tag == _CHECKSUM_TAG), None)
        self.nested = any(tag in _NESTED for _, tag, _ in kinds)
        make = _compile_make(kinds, self.quirks)
        if self.nested:

            def make_nested(raws, offset, _make=make):
                return _decode_nested(_make(raws, offset))

            self.make = make_nested
        else:
            self.make = make


def _compile_make(kinds, quirks=()):
    """Compile ``make(raws, offset) -> Packet`` for one layout.

    The function is generated (as :func:`collections.namedtuple` does) so that each
    value is converted by inline arithmetic with its item's constants and the fields
    dict is built by one dict display: several times faster than a loop over items.
    Only field names from :data:`TAGS`, float constants (``repr`` round-trips them
    exactly) and integer tag numbers enter the source.

    An item given at another length than the standard's is decoded at its length with
    the standard's step (its leading bytes added or left out, as later ST 0601 versions
    and the writers in the wild do: docs/klv.md); a value beyond what the standard's
    length can hold is NaN, flagged ``"out of range"``. An empty numeric item is absent.
    """
    names = [f"r{i}" for i in range(len(kinds))]
    # A repeated item: the last one wins, as in a dict.
    entries, unknown, reserved, ranged = {}, {}, {}, {}
    ck = "None"
    for r, (spec, tag, ln) in zip(names, kinds):
        if tag == _CHECKSUM_TAG:
            ck = r
        elif spec is None:
            unknown[tag] = f"{tag!r}: {r}"
        else:
            reserved.pop(spec.name, None)
            ranged.pop(spec.name, None)
            if spec.kind == "str":
                entries[spec.name] = f"{spec.name!r}: str({r}, 'utf-8', 'replace')"
                continue
            if ln == 0:
                entries.pop(spec.name, None)
                continue
            raw = r if ln in _INT_CODES else f"_ib({r}, {spec.kind == 'int'})"
            if spec.kind == "uint":
                entries[spec.name] = f"{spec.name!r}: {raw} * {spec.step!r}" + (f" + {spec.lo!r}" if spec.lo else "")
            elif spec.kind == "int":
                entries[spec.name] = f"{spec.name!r}: {raw} * {spec.step!r}"
                if spec.reserved and ln >= spec.size:  # the standard's sentinel, sign-extended
                    reserved[spec.name] = (raw, spec, -(1 << (8 * spec.size - 1)))
            else:
                entries[spec.name] = f"{spec.name!r}: {raw}"
            if ln != spec.size and spec.kind in ("uint", "int"):
                ranged[spec.name] = (raw, _raw_bounds(spec))
    entries, unknown = list(entries.values()), list(unknown.values())
    lines = ["def make(raws, offset):"]
    if names:
        lines.append(f"    {', '.join(names)}, = raws")
    lines.append(f"    fields = {{{', '.join(entries)}}}")
    lines.append("    flags = {}")
    by_sentinel: dict[int, list] = {}
    for raw, spec, sentinel in reserved.values():
        by_sentinel.setdefault(sentinel, []).append((raw, spec))
    for sentinel, lst in by_sentinel.items():
        lines.append(f"    if {sentinel} in ({', '.join(r for r, _ in lst)},):")
        for r, spec in lst:
            lines.append(f"        if {r} == {sentinel}:")
            lines.append(f"            fields[{spec.name!r}] = nan")
            lines.append(f"            flags[{spec.name!r}] = {spec.reserved!r}")
    for name, (raw, (a, b)) in ranged.items():
        lines.append(f"    if {name!r} not in flags and not {a} <= {raw} <= {b}:")
        lines.append(f"        fields[{name!r}] = nan")
        lines.append(f"        flags[{name!r}] = {OUT_OF_RANGE!r}")
    lines.append(f"    return Packet(fields, offset, flags, {{{', '.join(unknown)}}}, {ck}, quirks=QUIRKS)")
    ns = {"Packet": Packet, "nan": math.nan, "_ib": _ib, "QUIRKS": tuple(quirks)}
    exec("\n".join(lines), ns)
    return ns["make"]


def _walk(data, vs, ve):
    """The items of the local set data[vs:ve]: list of (tag, item_start, value_start, length).

    Raises _Bad for a tag or length running past the end or an invalid BER length.
    """
    items = []
    p = vs
    while p < ve:
        t0 = p
        tag = 0
        while True:
            if p >= ve:
                raise _Bad(f"item at local-set byte {t0 - vs}: its tag runs past the end of the local set")
            b = data[p]
            p += 1
            tag = (tag << 7) | (b & 0x7F)
            if b < 0x80:
                break
            if p - t0 >= 4:
                raise _Bad(f"item at local-set byte {t0 - vs}: tag longer than 4 bytes")
        if p >= ve:
            raise _Bad(f"tag {tag}: no length byte before the end of the local set")
        b = data[p]
        p += 1
        if b < 0x80:
            ln = b
        else:
            m = b & 0x7F
            if m == 0 or m > 8:
                raise _Bad(f"tag {tag}: invalid BER length byte 0x{b:02X}")
            if p + m > ve:
                raise _Bad(f"tag {tag}: its BER length runs past the end of the local set")
            ln = int.from_bytes(data[p : p + m], "big")
            p += m
        if p + ln > ve:
            raise _Bad(f"tag {tag}: length {ln} runs past the end of the local set ({ve - p} bytes left)")
        items.append((tag, t0, p, ln))
        p += ln
    return items


#: Nested local sets decoded into fields: ST 0601 tag -> (title, decoder).
_NESTED = {48: ("Security Local Set, ST 0102", decode_security), 74: ("VMTI Local Set, ST 0903", decode_vmti)}


def _decode_nested(p: Packet) -> Packet:
    """Add the fields of the packet's nested sets (tags 48, 74; their raw bytes stay in
    ``unknown``); a set that cannot be read is a quirk of the packet, which is kept."""
    unknown = p.unknown
    if not unknown:
        return p
    for tag, (title, dec) in _NESTED.items():
        v = unknown.get(tag)
        if not v:  # absent or empty (the standard's example packet has both sets empty)
            continue
        try:
            p.fields.update(dec(v))
        except SetError as e:
            p.quirks = p.quirks + (f"tag {tag} ({title}) cannot be read ({e}): kept raw, its fields left out",)
    return p


class QuirkTally:
    """The quirks of a read, one entry per kind: how many packets, and the first one's offset.

    Feed it every result of a read (:meth:`add`); :meth:`lines` gives one line per kind
    (``docs/klv.md``, "Encoders in the wild"), never one per packet.
    """

    def __init__(self):
        self.kinds: dict[str, list] = {}

    def add(self, result: Packet | KlvError) -> None:
        q = getattr(result, "quirks", None)
        if not q:
            return
        for kind in q:
            e = self.kinds.get(kind)
            if e is None:
                self.kinds[kind] = [1, result.offset]
            else:
                e[0] += 1

    def add_kind(self, kind: str, count: int, offset: int | None) -> None:
        """``count`` packets of one kind, the first of them at ``offset`` (batch decoding)."""
        e = self.kinds.get(kind)
        if e is None:
            self.kinds[kind] = [int(count), offset]
        else:
            e[0] += int(count)
            if offset is not None and (e[1] is None or offset < e[1]):
                e[1] = offset

    def __len__(self) -> int:
        return len(self.kinds)

    def lines(self) -> list[str]:
        """``"<kind> (N packets, the first at byte X)"`` for each kind, in the order first seen."""
        out = []
        for kind, (n, off) in self.kinds.items():
            where = f", the first at byte {off}" if off is not None else ""
            out.append(f"{kind} ({n} packet{'s' if n != 1 else ''}{where})")
        return out


class _Decoder:
    """Layout cache shared by every read (layouts depend on structure only)."""

    MAX_PER_LENGTH = 8
    MAX_LENGTHS = 512

    def __init__(self):
        self.layouts: dict[int, list[_Layout]] = {}

    def layout(self, data, vs, ve, need_checksum) -> _Layout:
        """The compiled layout of data[vs:ve] (cached), validating a new one."""
        L = ve - vs
        for lay in self.layouts.get(L, ()):
            if lay.hdr.unpack_from(data, vs) == lay.hdr_vals:
                if need_checksum and lay.ck_idx is None:
                    break
                return lay
        items = _walk(data, vs, ve)
        for n, (tag, t0, v0, ln) in enumerate(items):
            spec = TAG_BY_NUMBER.get(tag)
            if tag == _CHECKSUM_TAG:
                if ln != 2:
                    raise _Bad(f"tag 1 (Checksum) has length {ln}, expected 2")
                if n != len(items) - 1:
                    raise _Bad("tag 1 (Checksum) is not the last item of the local set")
            elif spec is not None and spec.kind != "str" and ln > 8:
                raise _Bad(
                    f"tag {tag} ({spec.title}) has length {ln}, expected {spec.size}: an integer "
                    "of more than 8 bytes cannot be decoded at its length"
                )
        if need_checksum and (not items or items[-1][0] != _CHECKSUM_TAG):
            raise _Bad("no checksum item (tag 1) at the end of the local set")
        lay = _Layout(items, data, vs)
        if len(self.layouts) >= self.MAX_LENGTHS:
            self.layouts.clear()
        lst = self.layouts.setdefault(L, [])
        if len(lst) >= self.MAX_PER_LENGTH:
            lst.pop(0)
        lst.append(lay)
        return lay

    def decode(self, data, k, vs, ve, offset, verify) -> Packet:
        """Decode the packet with key at data[k], local set data[vs:ve]; raises _Bad."""
        if verify:
            if ve - vs < 4 or data[ve - 4] != 1 or data[ve - 3] != 2:
                raise _Bad("no checksum item (tag 1, length 2) at the end of the local set")
            if ve - k <= 514:
                calc = (
                    ((zlib.adler32(data[k : ve - 2 : 2]) & 0xFFFF) << 8)
                    + (zlib.adler32(data[k + 1 : ve - 2 : 2]) & 0xFFFF)
                    - 257
                ) & 0xFFFF
            else:
                calc = ((_bytesum(data[k : ve - 2 : 2]) << 8) + _bytesum(data[k + 1 : ve - 2 : 2])) & 0xFFFF
            stored = (data[ve - 2] << 8) | data[ve - 1]
            if calc != stored:
                raise _Bad(f"checksum mismatch: the packet says 0x{stored:04X}, its bytes sum to 0x{calc:04X}")
        for lay in self.layouts.get(ve - vs, ()):
            if lay.hdr.unpack_from(data, vs) == lay.hdr_vals and (lay.ck_idx is not None or not verify):
                break
        else:
            lay = self.layout(data, vs, ve, verify)
        return lay.make(lay.vals.unpack_from(data, vs), offset)


_DECODER = _Decoder()


# --------------------------------------------------------------------------- scanning


class _ScanState:
    __slots__ = ("garbage_from",)

    def __init__(self, garbage_from):
        # Absolute offset where bytes that are no packet started to be skipped
        # (after a good packet or at the start), None right after a bad packet.
        self.garbage_from = garbage_from


def _scan(data, base, final, state, verify, start=0, max_length=MAX_PACKET_LENGTH, limit=None):
    """Scan data[start:] for packets.

    Returns (results, used): ``used`` is where the next scan must start (bytes before
    it are done with). When not ``final``, the scan stops before a packet that may
    continue in data not yet read; with a ``limit``, once it has that many results.
    """
    out = []
    append = out.append
    key = UAS_LS_KEY
    find = data.find
    n = len(data)
    pos = start
    dec = _DECODER
    no_batch_before = start  # no batch decoding before this offset (a short run, a bad packet)
    if limit is None:
        limit = 1 << 62
    k104 = -1  # the next EG 0104 key at or after pos (n: none), looked for when pos passes it
    while True:
        if len(out) >= limit:
            return out, pos
        if data.startswith(key, pos):
            k = pos
        else:
            k = find(key, pos)
            if k104 < pos:  # an EG 0104 key before the next UAS LS key? (the search stops there)
                stop = k if k >= 0 else n
                k104 = find(EG0104_KEY, pos, stop)
                if k104 < 0:
                    k104 = stop if k >= 0 else n
            if k104 < n and (k < 0 or k104 < k):
                r = _scan_eg0104(data, k104, n, base, final, state, max_length)
                if r is None:  # may continue in data not yet read
                    return out, k104
                res, pos = r
                append(res)
                continue
            if k < 0:
                if final:
                    g = state.garbage_from
                    if g is not None and g < base + n:
                        append(KlvError(g, f"{base + n - g} bytes at the end are not a UAS LS packet"))
                    return out, n
                return out, max(pos, n - (len(key) - 1))  # a key may straddle the next read
        g = state.garbage_from
        if g is not None and base + k > g:
            append(KlvError(g, f"{base + k - g} bytes before the next UAS LS key are not a UAS LS packet"))
            state.garbage_from = None
        if k >= no_batch_before:
            # Many complete packets in a row: decode them at once with numpy (the same
            # results as one by one); the first bad one goes to the per-packet path.
            ks, vss, Ls = _locate_run(data, k, n, _BATCH_MAX, max_length)
            if len(ks) < _BATCH_MIN:
                no_batch_before = vss[-1] + Ls[-1] if ks else k + 1
            else:
                res = _decode_batch(data, ks, vss, Ls, base, verify)
                j = 0
                for r in res:
                    if r is None:
                        break
                    append(r)
                    j += 1
                if j:
                    pos = vss[j - 1] + Ls[j - 1]
                    state.garbage_from = base + pos
                if j < len(res):
                    no_batch_before = ks[j] + 1
                continue
        p = k + 16
        if p >= n:
            if not final:
                return out, k
            append(KlvError(base + k, "truncated: the data ends after the key, before the length"))
            state.garbage_from = None
            pos = k + 1
            continue
        b = data[p]
        if b < 0x80:
            L = b
            vs = p + 1
        else:
            m = b & 0x7F
            if m == 0 or m > 8:
                append(KlvError(base + k, f"invalid BER length byte 0x{b:02X} after the key"))
                state.garbage_from = None
                pos = k + 1
                continue
            if p + 1 + m > n:
                if not final:
                    return out, k
                append(KlvError(base + k, "truncated: the data ends inside the BER length"))
                state.garbage_from = None
                pos = k + 1
                continue
            L = int.from_bytes(data[p + 1 : p + 1 + m], "big")
            vs = p + 1 + m
        if L > max_length:
            append(KlvError(base + k, f"implausible length {L} (more than {max_length} bytes)"))
            state.garbage_from = None
            pos = k + 1
            continue
        ve = vs + L
        if ve > n:
            if not final:
                return out, k
            append(KlvError(base + k, f"truncated: the length says {L} bytes, only {n - vs} are left"))
            state.garbage_from = None
            pos = k + 1
            continue
        try:
            pkt = dec.decode(data, k, vs, ve, base + k, verify)
        except _Bad as e:
            append(KlvError(base + k, str(e)))
            state.garbage_from = None
            pos = k + 1
            continue
        append(pkt)
        pos = ve
        state.garbage_from = base + ve


_EG0104_QUIRK = (
    "EG 0104 Predator UAV Basic Universal Set (16-byte item keys, no checksum): read into the ST 0601 fields"
)


def _scan_eg0104(data, k, n, base, final, state, max_length):
    """The EG 0104 packet whose key is at data[k]: (Packet or KlvError, next position), or None
    when it may continue past the data read so far (not ``final``)."""
    g = state.garbage_from
    pre = None
    if g is not None and base + k > g:
        pre = KlvError(g, f"{base + k - g} bytes before the next UAS LS key are not a UAS LS packet")
    p = k + 16
    if p >= n or (data[p] >= 0x80 and p + 1 + (data[p] & 0x7F) > n):
        if not final:
            return None
        res = KlvError(base + k, "truncated: the EG 0104 packet ends before its length")
        state.garbage_from = None
        return (pre or res), (k if pre else k + 1)
    b = data[p]
    if b < 0x80:
        L, vs = b, p + 1
    else:
        m = b & 0x7F
        L, vs = (int.from_bytes(data[p + 1 : p + 1 + m], "big") if 0 < m <= 8 else -1), p + 1 + m
    if pre is not None:  # report the stray bytes first; the packet on the next call
        state.garbage_from = None
        return pre, k
    if L < 0 or L > max_length:
        state.garbage_from = None
        return KlvError(base + k, f"EG 0104 packet: invalid BER length byte 0x{b:02X}"), k + 1
    ve = vs + L
    if ve > n:
        if not final:
            return None
        state.garbage_from = None
        return KlvError(base + k, f"truncated: the EG 0104 length says {L} bytes, only {n - vs} are left"), k + 1
    if not final and ve + 15 > n:
        return None  # a key overlapping its end may be in the data not yet read
    body = data[vs:ve]
    # no checksum: a length running over (into) the next packet's key is the tell
    if any(0 <= data.find(key, vs, ve + 15) < ve for key in (UAS_LS_KEY, EG0104_KEY)):
        state.garbage_from = None
        return KlvError(base + k, "EG 0104 packet: its length runs over the next packet's key"), k + 1
    try:
        fields, _, quirks = decode_eg0104(body)
    except SetError as e:
        state.garbage_from = None
        return KlvError(base + k, f"EG 0104 packet: {e}"), k + 1
    state.garbage_from = base + ve
    pkt = Packet(fields, base + k, {}, None, None, quirks=(_EG0104_QUIRK, *quirks))
    return pkt, ve


def _iter_stream(f: BinaryIO, verify: bool, chunk_size: int, max_length: int) -> Iterator[Packet | KlvError]:
    """Streaming scan of a binary file object: memory is bounded by a chunk plus one packet."""
    buf = b""
    base = 0
    state = _ScanState(0)
    eof = False
    while True:
        if not eof:
            chunk = f.read(chunk_size)
            if not chunk:
                eof = True
            else:
                buf = buf + bytes(chunk) if buf else bytes(chunk)
        out, used = _scan(buf, base, eof, state, verify, 0, max_length)
        yield from out
        if eof:
            return
        if used:
            buf = buf[used:]
            base += used


def _note_time_back(results: Iterable[Packet | KlvError]) -> Iterator[Packet | KlvError]:
    """Pass ``results`` through, noting on each good packet whose Precision Time Stamp
    (MISB ST 0601 Tag 2, microseconds since 1970 UTC) is earlier than that of the packet
    with a time stamp before it: :attr:`Packet.time_back`. Nothing is dropped or reordered (a sender's re-stamped
    or reordered packets are still the flight's; the user decides), as the SRT reader keeps a
    time code going back and names its line."""
    last_us: int | None = None
    last_k, last_at = 0, None
    k = 0
    for r in results:
        if isinstance(r, Packet):
            k += 1
            t = r.fields.get("precision_time_stamp_us")
            if isinstance(t, int):
                if last_us is not None and t < last_us:
                    where = f"byte {r.offset}" if r.offset is not None else "unknown position"
                    was = f"byte {last_at}" if last_at is not None else "unknown position"
                    r.time_back = (
                        f"packet {k} ({where}): Precision Time Stamp goes back {(last_us - t) / 1e6:.6f} s "
                        f"from packet {last_k} ({was})"
                    )
                # each packet against the one before it (as the SRT reader's blocks): a clock that
                # restarts is reported once, not at every packet after it
                last_us, last_k, last_at = t, k, r.offset
        yield r


def iter_packets(
    data: bytes | bytearray | memoryview | BinaryIO,
    *,
    verify_checksum: bool = True,
    chunk_size: int = 1 << 20,
    max_length: int = MAX_PACKET_LENGTH,
) -> Iterator[Packet | KlvError]:
    """Scan bytes or a binary file for UAS Datalink LS packets.

    Each packet is found by its 16-byte key (:data:`UAS_LS_KEY`), its BER length read,
    its checksum verified (MISB ST 0601 Tag 1) and its items decoded. A bad packet
    (checksum mismatch, truncated, a length running past the end, an item whose
    length is wrong for its type, no checksum item at the end) yields a
    :class:`KlvError` with the byte offset of its key; the scan resumes at the next
    key after that offset, so good packets are still returned. Bytes between packets
    that are no packet yield one :class:`KlvError` at their first byte.

    Parameters
    ----------
    data : bytes, bytearray, memoryview or binary file object
        Concatenated packets. A file object (anything with ``read``) is read in
        chunks of ``chunk_size`` bytes: memory stays bounded by a chunk and one packet.
    verify_checksum : bool
        Check each packet's checksum (and require the checksum item). Default True.
    chunk_size : int
        Read size for file objects [bytes].
    max_length : int
        A longer BER length is reported as corrupt.

    Yields
    ------
    Packet or KlvError
        In file order; a packet whose Precision Time Stamp goes back carries
        :attr:`Packet.time_back`.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)) and hasattr(data, "read"):
        yield from _note_time_back(_iter_stream(data, verify_checksum, chunk_size, max_length))
        return
    yield from _note_time_back(_iter_bytes(data, verify_checksum, max_length))


def _iter_bytes(data, verify_checksum: bool, max_length: int) -> Iterator[Packet | KlvError]:
    if not isinstance(data, (bytes, bytearray)):
        data = bytes(data)
    state = _ScanState(0)
    pos, n = 0, len(data)
    while True:  # a few thousand results at a time: the caller may stop early
        out, pos = _scan(data, 0, True, state, verify_checksum, pos, max_length, _BATCH_MAX)
        yield from out
        if pos >= n:
            return


def read_klv_file(
    path: str | os.PathLike[str], *, verify_checksum: bool = True, chunk_size: int = 1 << 20
) -> Iterator[Packet | KlvError]:
    """Stream the packets of a raw KLV file (``.klv``, ``.bin``: concatenated packets).

    Memory-bounded: the file is read in chunks (see :func:`iter_packets`).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    verify_checksum : bool
        Check each packet's checksum. Default True.
    chunk_size : int
        Read size [bytes].

    Yields
    ------
    Packet or KlvError
        In file order; offsets are byte offsets in the file. A packet whose Precision
        Time Stamp goes back carries :attr:`Packet.time_back`.
    """
    with open(path, "rb") as f:
        yield from _note_time_back(_iter_stream(f, verify_checksum, chunk_size, MAX_PACKET_LENGTH))


def _klv_stream(container, index, path=None):
    where = f"{path}: " if path is not None else ""
    data = [s for s in container.streams if s.type == "data"]
    if index is not None:
        for s in data:
            if s.index == index:
                return s
        raise ValueError(
            f"{where}stream {index} is not a data stream of the container (data streams: {[s.index for s in data]})"
        )
    if not data:
        kinds = (
            ", ".join(f"{s.type} ({s.codec_context.name if s.codec_context else '?'})" for s in container.streams)
            or "none"
        )
        raise ValueError(
            f"{where}the container has no data (KLV) stream (its streams: {kinds}), "
            "so it carries no MISB ST 0601 metadata to read"
        )
    klv = [s for s in data if getattr(s, "name", None) in ("klv", "smpte_klv")]
    return (klv or data)[0]


def read_ts_klv(
    path: str | os.PathLike[str], *, verify_checksum: bool = True, stream: int | None = None
) -> Iterator[Packet | KlvError]:
    """Stream the UAS LS packets of the KLV data stream of an MPEG-TS (or any container
    FFmpeg demuxes), through PyAV.

    Every data packet of the stream (``container.demux(stream)``; ``bytes(pkt)``) is
    scanned like a raw file (one or more KLV packets each); empty ones are skipped.
    Results carry the container packet's ``pts`` (and ``time_base``); their
    ``offset`` is the demuxer's byte position of that packet (``pkt.pos``).

    Parameters
    ----------
    path : str or os.PathLike
        The file (``.ts``, ``.mpg``, ``.m2ts``, ``.mp4``, ...).
    verify_checksum : bool
        Check each packet's checksum. Default True.
    stream : int or None
        Index of the data stream; default: the first stream of codec ``klv``, else
        the first data stream.

    Yields
    ------
    Packet or KlvError
        In the stream's order; a packet whose Precision Time Stamp goes back carries
        :attr:`Packet.time_back`.
    """
    yield from _note_time_back(_read_ts_klv(path, verify_checksum, stream))


def _read_ts_klv(path, verify_checksum: bool, stream: int | None) -> Iterator[Packet | KlvError]:
    av = require("av", "reading KLV from MPEG-TS video")

    try:
        container = av.open(os.fspath(path))
    except FileNotFoundError:
        raise
    except av.error.FFmpegError as e:
        if sniff_klv_file(path) == "mpegts":
            yield from _read_ts_native(path, verify_checksum, str(e))
            return
        raise ValueError(f"{path}: PyAV cannot open it: {e}") from e
    with container:
        try:
            ds = _klv_stream(container, stream, path)
        except ValueError as e:
            # FFmpeg found no data stream: a transport stream without PAT / PMT (or whose PMT does
            # not declare its KLV) still has it, in PES found by their UAS LS / EG 0104 keys
            if stream is not None or sniff_klv_file(path) != "mpegts":
                raise
            yield from _read_ts_native(path, verify_checksum, str(e))
            return
        tb = ds.time_base
        tb = Fraction(tb.numerator, tb.denominator) if tb is not None else None
        packets = container.demux(ds)
        pos = None
        while True:
            try:
                pkt = next(packets)
            except StopIteration:
                break
            except (IndexError, KeyError, ValueError, OSError, RuntimeError) as e:
                # found by fuzzing: on a damaged stream PyAV's demuxer raised IndexError ("list index
                # out of range", a stream it had not announced); the packets read so far are kept
                yield KlvError(
                    pos,
                    f"the container's demultiplexer stopped here ({type(e).__name__}: {e}); "
                    "the rest of the file is not read",
                )
                return
            b = bytes(pkt)
            if not b:
                continue
            pos = pkt.pos if pkt.pos is not None and pkt.pos >= 0 else None
            out, _ = _scan(b, 0, True, _ScanState(0), verify_checksum)
            for r in out:
                if isinstance(r, Packet):
                    r.offset, r.pts, r.time_base = pos, pkt.pts, tb
                else:
                    r = KlvError(pos, r.reason, pkt.pts)
                yield r


def _read_ts_native(path, verify_checksum: bool, why: str) -> Iterator[Packet | KlvError]:
    """The KLV of an MPEG-TS through geoloc's own demultiplexer (:class:`geoloc.io.ts_demux.TsDemuxer`),
    read in chunks: the PES of the PMT's KLV streams, or with no PAT / PMT those whose data starts
    with a UAS LS or EG 0104 key. Results carry the offset of the TS packet that started their PES,
    its pts and the 90 kHz time base (as the live receiver gives them). Raises ValueError(``why``)
    when it finds none either."""
    from geoloc.io.ts_demux import TsDemuxer

    dm = TsDemuxer(keep_video=False, reorder=False, video_window=1)
    tb = Fraction(1, 90000)
    n = 0
    with open(path, "rb") as f:
        while True:
            chunk = f.read(1 << 20)
            units = dm.feed(chunk) if chunk else dm.flush()
            for u in units:
                if u.kind != "klv" or not u.data:
                    continue
                out, _ = _scan(u.data, 0, True, _ScanState(0), verify_checksum)
                for r in out:
                    if isinstance(r, Packet):
                        r.offset, r.pts, r.time_base = u.offset, u.pts, tb
                    else:
                        r = KlvError(u.offset, r.reason, u.pts)
                    n += 1
                    yield r
            if not chunk:
                break
    if n == 0:
        raise ValueError(why)


_CONTAINER_SUFFIXES = {".ts", ".m2ts", ".mts", ".mpg", ".mpeg", ".mp4", ".mov", ".mkv", ".trp"}

#: Transport-stream packets checked by :func:`sniff_klv_file` (ISO/IEC 13818-1 2.4.3.2: every
#: 188-byte packet starts with the sync byte 0x47; Blu-ray's M2TS puts a 4-byte time code first).
_SNIFF_TS_PACKETS = 5


def sniff_klv_file(path: str | os.PathLike[str]) -> str | None:
    """What a file's first bytes say it is, whatever its name: ``"mpegts"`` (the sync byte
    0x47 at every 188th byte, ISO/IEC 13818-1 2.4.3.2; or every 192nd after a 4-byte time
    code, M2TS), ``"mp4"`` (an ISO BMFF ``ftyp`` box, ISO/IEC 14496-12 4.3), ``"matroska"``
    (the EBML magic 1A 45 DF A3), ``"mpegps"`` (a pack start code 00 00 01 BA),
    ``"klv"`` (a SMPTE 336M universal key, 06 0E 2B 34) or None (unknown: the suffix decides).

    A ``.ts`` renamed ``.klv`` is thus read as the MPEG-TS it is: a suffix can lie."""
    with open(path, "rb") as f:
        head = f.read(192 * _SNIFF_TS_PACKETS)
    for size, skip in ((188, 0), (192, 4)):
        k = min(_SNIFF_TS_PACKETS, max(len(head) - skip, 0) // size)
        if k >= 1 and all(head[skip + i * size] == 0x47 for i in range(k)) and (k >= 2 or len(head) == size):
            return "mpegts"
    if head[4:8] == b"ftyp":
        return "mp4"
    if head[:4] == b"\x1a\x45\xdf\xa3":
        return "matroska"
    if head[:4] == b"\x00\x00\x01\xba":
        return "mpegps"
    if head[:4] == b"\x06\x0e\x2b\x34":
        return "klv"
    return None


def is_container_file(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is read through PyAV (a container): by its bytes
    (:func:`sniff_klv_file`) when they say, else by its suffix (``.ts``, ``.mpg``, ``.mp4``, ...)."""
    kind = sniff_klv_file(path)
    if kind is not None:
        return kind != "klv"
    return os.path.splitext(os.fspath(path))[1].lower() in _CONTAINER_SUFFIXES


def read_packets(path: str | os.PathLike[str], *, verify_checksum: bool = True) -> Iterator[Packet | KlvError]:
    """Raw KLV files through :func:`read_klv_file`, containers (MPEG-TS, MP4, Matroska,
    MPEG-PS) through :func:`read_ts_klv` (an MPEG-TS in which FFmpeg finds no data stream
    through geoloc's own demultiplexer); which is which is sniffed from the bytes
    (:func:`is_container_file`), the suffix deciding only when the bytes do not say."""
    note_input(path)
    if is_container_file(path):
        return read_ts_klv(path, verify_checksum=verify_checksum)
    return read_klv_file(path, verify_checksum=verify_checksum)


def decode_packet(packet: bytes, *, verify_checksum: bool = True) -> Packet:
    """Decode one complete packet (key, BER length, local set), as ``bytes(av_packet)``.

    Parameters
    ----------
    packet : bytes
        Exactly one UAS LS packet.
    verify_checksum : bool
        Check the checksum (MISB ST 0601 Tag 1). Default True.

    Returns
    -------
    Packet
        With ``offset`` 0.

    Raises
    ------
    KlvError
        For a bad packet (offset 0), or bytes after the packet.
    """
    data = bytes(packet)
    if not data.startswith(UAS_LS_KEY):
        raise KlvError(0, "does not start with the UAS Datalink LS key")
    out, _ = _scan(data, 0, True, _ScanState(None), verify_checksum)
    if not out:
        raise KlvError(0, "no packet")
    first = out[0]
    if isinstance(first, KlvError):
        raise first
    if len(out) > 1 or first.offset != 0:
        raise KlvError(0, f"{len(data) - _packet_end(data)} bytes after the packet")
    return first


def _packet_end(data: bytes) -> int:
    b = data[16]
    if b < 0x80:
        return 17 + b
    m = b & 0x7F
    return 17 + m + int.from_bytes(data[17 : 17 + m], "big")


def decode_local_set(value: bytes) -> Packet:
    """Decode the items of a bare local set (the value of a packet, without key and
    length). The checksum cannot be verified without the key and length bytes it
    covers; a checksum item, if present, is returned as read.

    Raises
    ------
    KlvError
        For an item running past the end or of a length wrong for its type (offset:
        the byte of the local set where the problem was found is in the reason).
    """
    data = bytes(value)
    try:
        lay = _DECODER.layout(data, 0, len(data), False)
        return lay.make(lay.vals.unpack_from(data, 0), None)
    except _Bad as e:
        raise KlvError(None, str(e)) from None


# --------------------------------------------------------------------------- encoding


def _item_encoder(spec: TagSpec):
    """``encode(value) -> bytes`` (tag, length, value) of one item, constants precomputed."""
    tag = ber_oid(spec.tag)
    where = f"(ST 0601 Tag {spec.tag})"
    name = spec.name
    if spec.kind == "str":

        def enc(value):
            b = value.encode("utf-8") if isinstance(value, str) else bytes(value)
            if len(b) > 127:
                raise ValueError(f"{name}: {len(b)} bytes of text, the standard allows at most 127 {where}")
            return tag + bytes((len(b),)) + b

        return enc
    prefix = tag + bytes((spec.size,))
    pack = struct.Struct(">" + spec.fmt).pack
    if spec.kind in ("u64", "u8"):
        top = (1 << (8 * spec.size)) - 1

        def enc(value):
            if isinstance(value, float):
                if not value.is_integer():
                    raise ValueError(f"{name} = {value!r} is not an integer {where}")
                value = int(value)
            v = int(value)
            if not 0 <= v <= top:
                raise ValueError(f"{name} = {v} does not fit {spec.size} unsigned bytes {where}")
            return prefix + pack(v)

        return enc
    step, lo = spec.step, spec.lo
    span = f"[{spec.lo:g}, {spec.hi:g}]"
    if spec.kind == "uint":
        top = (1 << (8 * spec.size)) - 1

        def enc(value):
            v = float(value)
            if not math.isfinite(v):
                raise ValueError(f"{name} = {v!r}: {where} reserves no error value, give a number in {span}")
            raw = round((v - lo) / step)
            if not 0 <= raw <= top:
                raise ValueError(f"{name} = {v!r} is outside {span} {where}")
            return prefix + pack(raw)

        return enc
    lim = (1 << (8 * spec.size - 1)) - 1
    sentinel = prefix + pack(-lim - 1)
    reserved = spec.reserved

    def enc_signed(value):
        v = float(value)
        if v != v:
            if not reserved:
                raise ValueError(f"{name} is NaN and {where} reserves no error value")
            return sentinel
        raw = round(v / step) if v - v == 0 else (lim + 1 if v > 0 else -lim - 1)
        if not -lim <= raw <= lim:
            if reserved == OUT_OF_RANGE:
                return sentinel
            raise ValueError(f"{name} = {v!r} is outside {span} {where}")
        return prefix + pack(raw)

    return enc_signed


def _first(t):
    return t[0]


_DERIVED = frozenset(DERIVED_FIELDS)

#: Field name -> (tag, item encoder).
_ENCODERS = {s.name: (s.tag, _item_encoder(s)) for s in TAGS}


def encode_packet(fields: dict, *, unknown: dict | None = None, with_checksum: bool = True) -> bytes:
    """Encode one UAS Datalink LS packet: the inverse of :func:`decode_packet`.

    Values are quantised with the standard's mappings (see :data:`TAGS`): the result
    decodes to within half a step (:attr:`TagSpec.step`) of each value. Items, raw
    ones included, are written in tag order (so Precision Time Stamp, tag 2, first, as
    the standard wants it), the checksum (tag 1) last.

    Parameters
    ----------
    fields : dict
        Field name (see :data:`TAGS`) -> value; None values are left out. NaN writes
        the reserved value of a signed item (decoded as NaN with its flag); a value
        beyond the range of an item whose reserved value means "out of range"
        (platform pitch and roll, 6, 7, 90, 91) writes that value. Integer keys are
        taken as raw items (tag -> bytes).
    unknown : dict, optional
        More raw items: tag number -> value bytes (e.g. :attr:`Packet.unknown`).
    with_checksum : bool
        Append the checksum item. Default True.

    Returns
    -------
    bytes
        The packet: key, BER length, local set.

    Raises
    ------
    ValueError
        For an unknown field name, or a value outside its item's range or type.
    """
    known = []
    raw_items = dict(unknown) if unknown else {}
    encoders = _ENCODERS
    for name, value in fields.items():
        if value is None:
            continue
        e = encoders.get(name)
        if e is None:
            if name in _DERIVED:
                continue  # read from a nested set: written back from its raw bytes (unknown)
            if isinstance(name, int):
                raw_items[name] = bytes(value)
                continue
            raise ValueError(f"unknown UAS LS field {name!r} (known: see geoloc.io.klv.TAGS)")
        known.append((e[0], e[1](value)))
    for t, v in raw_items.items():
        if t != _CHECKSUM_TAG:
            v = bytes(v)
            known.append((t, ber_oid(t) + ber_length(len(v)) + v))
    known.sort(key=_first)
    body = b"".join([b for _, b in known])
    if not with_checksum:
        return UAS_LS_KEY + ber_length(len(body)) + body
    head = UAS_LS_KEY + ber_length(len(body) + 4) + body + b"\x01\x02"
    return head + checksum(head + b"\0\0").to_bytes(2, "big")


def encode_value(name: str, value: Any) -> bytes:
    """The value bytes of one item (no tag, no length), as :func:`encode_packet` writes them.

    NaN gives the reserved value of an item that has one; ``ValueError`` (naming the
    field, the value and the tag) for a value outside the item's range.
    """
    e = _ENCODERS.get(name)
    if e is None:
        raise ValueError(f"unknown UAS LS field {name!r} (known: see geoloc.io.klv.TAGS)")
    b = e[1](value)
    spec = TAG_BY_NAME[name]
    return b[len(ber_oid(spec.tag)) + 1 :]


def local_set_items(packet: bytes | bytearray | memoryview) -> list[tuple[int, int, int]]:
    """The items of one packet as ``(tag, start, end)``: the value of each is ``packet[start:end]``.

    Parameters
    ----------
    packet : bytes-like
        One complete packet (key, BER length, local set).

    Raises
    ------
    KlvError
        Offset 0: no UAS LS key, a length running past the end, or bytes after the packet.
    """
    data = bytes(packet)
    if not data.startswith(UAS_LS_KEY) or len(data) < 17:
        raise KlvError(0, "does not start with the UAS Datalink LS key")
    end = _packet_end(data)
    if end != len(data):
        raise KlvError(0, f"the BER length says {end} bytes, the packet has {len(data)}")
    b = data[16]
    i = 17 if b < 0x80 else 17 + (b & 0x7F)
    items = []
    while i < end:
        tag = 0
        while True:  # BER-OID tag
            if i >= end:
                raise KlvError(0, f"item tag runs past the end at byte {i}")
            t = data[i]
            i += 1
            tag = (tag << 7) | (t & 0x7F)
            if t < 0x80:
                break
        if i >= end:
            raise KlvError(0, f"tag {tag}: length runs past the end at byte {i}")
        n = data[i]
        i += 1
        if n >= 0x80:
            m = n & 0x7F
            n = int.from_bytes(data[i : i + m], "big")
            i += m
        if i + n > end:
            raise KlvError(0, f"tag {tag}: {n} bytes run past the end of the packet")
        items.append((tag, i, i + n))
        i += n
    return items


def add_items(packet: bytes, values: dict) -> bytes:
    """A copy of one packet with new items inserted before its checksum (BER length and checksum redone).

    The items the packet has, and their order, are kept byte for byte; the new ones (tag number
    -> value bytes, e.g. :func:`encode_value`) go in tag order just before the checksum, which
    stays the last item (MISB ST 0601 Tag 1: the checksum is the final item of the local set).
    The packet's BER length is rewritten for the new length (its size may grow).

    Raises
    ------
    KlvError
        The packet cannot be walked (see :func:`local_set_items`), or ends without a checksum.
    ValueError
        A tag the packet already has (use :func:`replace_values`).
    """
    data = bytes(packet)
    items = local_set_items(data)
    if not items or items[-1][0] != _CHECKSUM_TAG or items[-1][2] - items[-1][1] != 2:
        raise KlvError(0, "the packet does not end with a checksum item (tag 1, 2 bytes)")
    have = {t for t, _, _ in items}
    for tag in values:
        if tag in have:
            raise ValueError(f"tag {tag} is in the packet already: replace_values rewrites it")
    b = data[16]
    body0 = 17 if b < 0x80 else 17 + (b & 0x7F)
    ck = items[-1][1] - 2  # the checksum item's tag and length bytes (01 02)
    new = b"".join(ber_oid(t) + ber_length(len(v)) + bytes(v) for t, v in sorted(values.items()))
    body = data[body0:ck] + new + b"\x01\x02"
    head = UAS_LS_KEY + ber_length(len(body) + 2) + body
    return head + checksum(head + b"\0\0").to_bytes(2, "big")


def replace_values(packet: bytes, values: dict) -> bytes:
    """A copy of one packet with the values of some items replaced and the checksum recomputed.

    Every other byte is kept: the key, the BER length, every other item (tag,
    length and value), the order of the items. A new value must have its
    item's length (the packet's length bytes are not rewritten), or, for an item a
    writer gave at another length than the standard's, the standard's length: then
    the item is rewritten at it and the packet's BER length redone (docs/klv.md,
    "Encoders in the wild"). The last item must be the checksum (tag 1), which is
    recomputed (MISB ST 0601 Tag 1).

    Parameters
    ----------
    packet : bytes
        One complete packet.
    values : dict
        Tag number -> new value bytes (e.g. :func:`encode_value`). A tag the
        packet does not have is an error: this adds no item.

    Raises
    ------
    KlvError
        The packet cannot be walked (see :func:`local_set_items`), or ends without a checksum.
    ValueError
        A tag is absent, or a value's length differs from the item's.
    """
    data = bytearray(packet)
    items = local_set_items(data)
    if not items or items[-1][0] != _CHECKSUM_TAG or items[-1][2] - items[-1][1] != 2:
        raise KlvError(0, "the packet does not end with a checksum item (tag 1, 2 bytes)")
    where = {t: (a, b) for t, a, b in items}
    resized = False
    for tag, v in values.items():
        if tag not in where:
            raise ValueError(f"tag {tag} is not in the packet: replace_values adds no item")
        a, b = where[tag]
        v = bytes(v)
        if len(v) != b - a:
            spec = TAG_BY_NUMBER.get(tag)
            if spec is None or spec.kind in ("str",) or len(v) != spec.size:
                raise ValueError(f"tag {tag}: {len(v)} new bytes for an item of {b - a}")
            resized = True  # a writer's item at another length: rewritten at the standard's
            continue
        data[a:b] = v
    if resized:
        body = b"".join(
            ber_oid(t) + ber_length(len(v)) + v
            for t, v in ((t, bytes(values[t]) if t in values else bytes(data[a:b])) for t, a, b in items[:-1])
        )
        head = UAS_LS_KEY + ber_length(len(body) + 4) + body + b"\x01\x02"
        return head + checksum(head + b"\0\0").to_bytes(2, "big")
    data[-2:] = checksum(bytes(data)).to_bytes(2, "big")
    return bytes(data)


def write_ts(
    path: str | os.PathLike[str],
    packets: Iterable,
    *,
    rate: float = 30.0,
    pts: Iterable[int] | None = None,
    time_base: Fraction = Fraction(1, 90000),
    video: bool = False,
    video_size: tuple[int, int] = (64, 48),
    frames: Iterable | None = None,
    codec: str = "libx264",
    codec_options: dict | None = None,
    gop: int = 10,
) -> int:
    """Write an MPEG-TS with a KLV data stream (and optionally a video stream), via PyAV.

    With ``frames`` the file has the STANAG 4609 layout: a video stream (H.264 by
    default) and the KLV data stream (SMPTE 336M KLV, FFmpeg's ``klv`` codec: a
    private PES stream with the ``KLVA`` registration descriptor), frame i carrying
    packet i's time stamp, so both are on one clock (the container PTS).

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    packets : iterable
        Encoded packets (bytes), field dicts (encoded with :func:`encode_packet`) or
        :class:`Packet` (re-encoded with their unknown items).
    rate : float
        Packets per second when ``pts`` is not given (packet i at i / rate s), and the
        video frame rate.
    pts : iterable of int, optional
        Presentation time stamps in ``time_base``.
    time_base : Fraction
        Time base of the KLV stream's time stamps. Default 1/90000 s (MPEG-TS clock).
    video : bool
        Also write a grey MPEG-2 video stream, one frame per packet, for players that
        want one. The muxer may then shift every time stamp by the video's start delay.
    video_size : (int, int)
        Width and height of the video [pixels].
    frames : iterable of ndarray (rows, cols, 3) uint8, optional
        One RGB picture per packet (array row 0 the top row), encoded with ``codec``
        at the packet's time stamp (the video stream's time base is ``time_base``).
        An iterable is consumed lazily, so a long video is never held in memory.
    codec : str
        FFmpeg encoder of ``frames``: ``libx264`` (default), ``mpeg2video``, ``mpeg4``, ...
    codec_options : dict, optional
        Encoder options (libx264 default: ``preset=medium``, ``crf=26``, no B-frames,
        so that time stamps need no decoding delay).
    gop : int
        Key-frame interval of ``frames`` [frames].

    Returns
    -------
    int
        Number of KLV packets written.
    """
    av = require("av", "writing KLV into MPEG-TS video")

    blobs = []
    for p in packets:
        if isinstance(p, (bytes, bytearray, memoryview)):
            blobs.append(bytes(p))
        elif isinstance(p, Packet):
            blobs.append(encode_packet(p.fields, unknown=p.unknown))
        else:
            blobs.append(encode_packet(p))
    if pts is None:
        ts = [round(i / (rate * time_base)) for i in range(len(blobs))]
    else:
        ts = [int(t) for t in pts]
        if len(ts) != len(blobs):
            raise ValueError(f"{len(ts)} pts for {len(blobs)} packets")
    with av.open(os.fspath(path), "w", format="mpegts") as out:
        vs = None
        pictures = None
        if frames is not None:
            pictures = iter(frames)
            first = next(pictures, None)
            if first is None:
                raise ValueError("frames: no picture given")
            first = np.asarray(first)
            if first.ndim != 3 or first.shape[2] != 3 or first.dtype != np.uint8:
                raise ValueError(
                    f"frames: each picture must be (rows, cols, 3) uint8 RGB, got {first.shape} {first.dtype}"
                )
            vs = out.add_stream(codec, rate=Fraction(rate).limit_denominator(1001))
            vs.height, vs.width = first.shape[:2]
            vs.pix_fmt = "yuv420p"
            vs.time_base = time_base
            vs.codec_context.time_base = time_base
            vs.gop_size = int(gop)
            opts = {"preset": "medium", "crf": "26", "bf": "0"} if codec == "libx264" else {}
            opts.update(codec_options or {})
            vs.options = {k: str(v) for k, v in opts.items()}
            pictures = _chain_first(first, pictures)
        elif video:
            vs = out.add_stream("mpeg2video", rate=Fraction(rate).limit_denominator(1001))
            vs.width, vs.height = video_size
            vs.pix_fmt = "yuv420p"
            grey = np.full((video_size[1], video_size[0], 3), 128, np.uint8)
        ds = out.add_data_stream(codec_name="klv")
        for i, (b, t) in enumerate(zip(blobs, ts)):
            if pictures is not None:
                assert vs is not None  # made with the pictures' first frame above
                pic = next(pictures, None)
                if pic is None:
                    raise ValueError(f"frames: {i} pictures for {len(blobs)} packets")
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(pic), format="rgb24")
                frame.pts, frame.time_base = t, time_base
                for vp in vs.encode(frame):
                    out.mux(vp)
            elif vs is not None:
                frame = av.VideoFrame.from_ndarray(grey, format="rgb24")
                frame.pts = i
                for vp in vs.encode(frame):
                    out.mux(vp)
            pk = av.Packet(b)
            pk.stream = ds
            pk.time_base = time_base
            pk.pts = pk.dts = t
            out.mux(pk)
        if vs is not None:
            for vp in vs.encode():
                out.mux(vp)
    return len(blobs)


def _chain_first(first, rest):
    yield first
    yield from rest


# --------------------------------------------------------------------------- columns


def _empty_columns(n: int) -> dict[str, np.ndarray]:
    cols = {"offset": np.full(n, -1, np.int64), "pts": np.full(n, np.nan)}
    for s in _NUMERIC_SPECS:
        cols[s.name] = np.full(n, np.nan)
    for s in _TEXT_SPECS:
        cols[s.name] = np.full(n, None, dtype=object)
    cols["reserved"] = _no_reserved(n)
    return cols


def _reserved_names(names) -> tuple:
    """Field names in tag order, each once (both decoders give the same tuple)."""
    return tuple(sorted(set(names), key=_FIELD_RANK.__getitem__))


def _no_reserved(n: int) -> np.ndarray:
    """The ``reserved`` column of n packets that have none: an empty tuple each."""
    col = np.empty(n, dtype=object)
    col[:] = [()] * n
    return col


def _columns_from_packets(packets) -> dict[str, np.ndarray]:
    rows = [p for p in packets if isinstance(p, Packet)]
    n = len(rows)
    cols = _empty_columns(n)
    cols["offset"][:] = [-1 if p.offset is None else p.offset for p in rows]
    cols["pts"][:] = [np.nan if p.pts is None else p.pts for p in rows]
    nan = math.nan
    for s in _NUMERIC_SPECS:
        name = s.name
        cols[name][:] = [p.fields.get(name, nan) for p in rows]
    for s in _TEXT_SPECS:
        name = s.name
        cols[name][:] = [p.fields.get(name) for p in rows]
    cols["reserved"][:] = [_reserved_names(n for n in (p.flags or ()) if n in _NUMERIC_NAMES) for p in rows]
    return cols


def packets_to_columns(
    packets: Iterable[Packet | KlvError] | bytes | bytearray,
    *,
    verify_checksum: bool = True,
    quirks: QuirkTally | None = None,
) -> dict[str, np.ndarray]:
    """Decoded packets as columns, for vectorised use.

    Parameters
    ----------
    packets : iterable of Packet / KlvError, or bytes
        Results of a read (errors are skipped), or raw concatenated packets: those
        are decoded in groups of one layout with numpy at once (same results as
        ``packets_to_columns(iter_packets(data))``, many times faster).
    verify_checksum : bool
        For raw bytes: check each packet's checksum. Default True.
    quirks : QuirkTally, optional
        Where to count the quirks of the packets (:attr:`Packet.quirks`).

    Returns
    -------
    dict of str -> numpy.ndarray
        One entry per good packet in each column: ``offset`` (int64, -1 if unknown),
        ``pts`` (float, NaN if none), every numeric field of :data:`TAGS` (float64;
        NaN where the item is absent or reserved; the time stamp in microseconds is
        exact in float64 until the year 2255), the text fields (object; None where
        absent) and ``reserved`` (object: a tuple per packet of the numeric fields that
        are NaN because the packet holds the item with a reserved value or one beyond
        what the standard's length holds, :attr:`Packet.flags`; ``()`` for none), which
        tells such an item from an absent one.
    """
    if isinstance(packets, (bytes, bytearray, memoryview)):
        return _columns_from_bytes(bytes(packets), verify_checksum, quirks)
    if quirks is not None:
        packets = list(packets)
        for p in packets:
            quirks.add(p)
    return _columns_from_packets(packets)


_KEY_EVEN = sum(UAS_LS_KEY[0::2])
_KEY_ODD = sum(UAS_LS_KEY[1::2])
_BLOCK = 1 << 15


def _be_ints(M, off, size, signed):
    """Big-endian integers of ``size`` bytes (1 to 8) at column ``off`` of the rows M."""
    if size in _INT_CODES:
        sub = np.ascontiguousarray(M[:, off : off + size])
        return sub.view(f">{'i' if signed else 'u'}{size}")[:, 0]
    v = np.zeros(M.shape[0], np.int64)
    for j in range(size):
        v = v * 256 + M[:, off + j]
    if signed:
        v = np.where(v >= 1 << (8 * size - 1), v - (1 << (8 * size)), v)
    return v


def _texts(M, off, ln):
    if ln == 0:
        return np.full(M.shape[0], "", dtype=object)
    sub = np.ascontiguousarray(M[:, off : off + ln]).view(f"V{ln}")[:, 0]
    uniq, inv = np.unique(sub, return_inverse=True)
    dec = np.array([bytes(u).decode("utf-8", "replace") for u in uniq] + [None], dtype=object)[:-1]
    return dec[inv.ravel()]


def _raw_bytes(M, off, ln):
    n = M.shape[0]
    if ln == 0:
        return [b""] * n
    b = np.ascontiguousarray(M[:, off : off + ln]).tobytes()
    return [b[i : i + ln] for i in range(0, n * ln, ln)]


def _gather(arr, vs_rows, L):
    """The local sets of packets starting at vs_rows, all of length L: an (n, L) uint8 array."""
    return arr[vs_rows[:, None] + np.arange(L)]


def _match_group(data, M, vs_rows, k0, L, verify):
    """Checksums and layouts of the packets of one group (same local-set length L and
    length-field size; the first has its key at k0).

    Returns (ok, matches): ``ok`` marks the good packets; ``matches`` lists
    (layout, row indices) covering them.
    """
    n = len(M)
    ok = np.ones(n, bool)
    if verify:
        if L < 4:
            return np.zeros(n, bool), []
        vs0 = int(vs_rows[0])
        lb = data[k0 + 16 : vs0]
        even = _KEY_EVEN + sum(lb[0::2])
        odd = _KEY_ODD + sum(lb[1::2])
        s = (vs0 - k0) % 2  # local-set byte 0 at an even index from the key: s = 0
        se = M[:, s : L - 2 : 2].sum(axis=1, dtype=np.int64)
        so = M[:, 1 - s : L - 2 : 2].sum(axis=1, dtype=np.int64)
        calc = ((even + se) * 256 + odd + so) & 0xFFFF
        stored = M[:, L - 2].astype(np.int64) * 256 + M[:, L - 1]
        ok &= (calc == stored) & (M[:, L - 4] == 1) & (M[:, L - 3] == 2)
    todo = ok.copy()
    matches = []
    while todo.any():
        r = int(np.flatnonzero(todo)[0])
        vs = int(vs_rows[r])
        try:
            lay = _DECODER.layout(data, vs, vs + L, verify)
        except _Bad:
            todo[r] = ok[r] = False
            continue
        if len(lay.hdr_pos):
            match = todo & (M[:, lay.hdr_pos] == lay.hdr_arr).all(axis=1)
        else:
            match = todo.copy()
        match[r] = True
        todo &= ~match
        matches.append((lay, np.flatnonzero(match)))
    return ok, matches


def _item_values(spec, Ms, off, ln):
    """Decoded values of one item over rows Ms (numpy), and its flags: a list of
    (mask, meaning) for the reserved values and, at a length other than the standard's,
    the values beyond what the standard's length holds (``"out of range"``)."""
    if spec.kind == "str":
        return _texts(Ms, off, ln), []
    raw = _be_ints(Ms, off, ln, spec.kind == "int")
    flags = []
    if spec.kind == "uint":
        val = raw * spec.step + spec.lo if spec.lo else raw * spec.step
    elif spec.kind == "int":
        val = raw * spec.step
        if spec.reserved and ln >= spec.size:  # the standard's sentinel, sign-extended
            mask = raw == -(1 << (8 * spec.size - 1))
            if mask.any():
                val[mask] = np.nan
                flags.append((mask, spec.reserved))
    else:
        return raw, []  # plain integers
    if ln != spec.size:
        a, b = _raw_bounds(spec)
        mask = (raw < a) | (raw > b)
        for m, _ in flags:
            mask &= ~m
        if mask.any():
            val = np.array(val, float)
            val[mask] = np.nan
            flags.append((mask, OUT_OF_RANGE))
    return val, flags


def _group_packets(lay, Ms, offsets):
    """Packets (as the per-packet decoder makes them) of rows Ms of one layout."""
    n = len(Ms)
    names, cols, flagged, unknown = [], [], {}, {}
    ck = None
    for spec, tag, off, ln in lay.vitems:
        if tag == _CHECKSUM_TAG:
            ck = _be_ints(Ms, off, 2, False).tolist()
        elif spec is None:
            unknown[tag] = _raw_bytes(Ms, off, ln)
        elif ln == 0 and spec.kind != "str":
            if spec.name in names:  # an empty numeric item: absent (a repeated one is dropped too)
                i = names.index(spec.name)
                del names[i], cols[i]
            flagged.pop(spec.name, None)
        else:
            val, fl = _item_values(spec, Ms, off, ln)
            flagged.pop(spec.name, None)
            if fl:
                flagged[spec.name] = fl
            if spec.name in names:  # a repeated item: the last one wins, in the first's place
                cols[names.index(spec.name)] = val.tolist()
            else:
                names.append(spec.name)
                cols.append(val.tolist())
    rows = zip(*cols) if cols else [()] * n
    cks = ck if ck is not None else [None] * n
    mk = _row_maker(tuple(names))
    q = lay.quirks
    out = [Packet(mk(vals), o, {}, {}, c, quirks=q) for vals, o, c in zip(rows, offsets, cks)]
    if unknown:
        tags = list(unknown)
        for p, vals in zip(out, zip(*unknown.values())):
            p.unknown = dict(zip(tags, vals))
    for name, fl in flagged.items():
        for mask, meaning in fl:
            for j in np.flatnonzero(mask):
                out[j].flags[name] = meaning
    if lay.nested:
        out = [_decode_nested(p) for p in out]
    return out


_ROW_MAKERS: dict[tuple, object] = {}


def _row_maker(names: tuple):
    """``make(values) -> dict`` for these field names: one dict display, compiled once
    (a dict built at its final size, faster than ``dict(zip(names, values))``)."""
    mk = _ROW_MAKERS.get(names)
    if mk is None:
        if len(_ROW_MAKERS) > 4096:
            _ROW_MAKERS.clear()
        assert all(n in _FIELD_RANK for n in names)  # only names of TAGS enter the source
        args = [f"v{i}" for i in range(len(names))]
        src = ["def make(values):"]
        if names:
            src.append(f"    {', '.join(args)}, = values")
        src.append("    return {" + ", ".join(f"{n!r}: {a}" for n, a in zip(names, args)) + "}")
        ns: dict = {}
        exec("\n".join(src), ns)
        mk = _ROW_MAKERS[names] = ns["make"]
    return mk


#: Fewest complete packets in a row that the scanner decodes as one batch.
_BATCH_MIN = 16
#: Most packets in a batch.
_BATCH_MAX = 4096


def _locate_run(data, pos, n, limit, max_length):
    """Complete packets following one another from ``pos`` (key, then the next key right
    after): lists of key offsets, local-set starts and lengths."""
    ks, vss, Ls = [], [], []
    key = UAS_LS_KEY
    startswith = data.startswith
    while len(ks) < limit and startswith(key, pos):
        p = pos + 16
        if p >= n:
            break
        b = data[p]
        if b < 0x80:
            L, vs = b, p + 1
        else:
            m = b & 0x7F
            if m == 0 or m > 8 or p + 1 + m > n:
                break
            L, vs = int.from_bytes(data[p + 1 : p + 1 + m], "big"), p + 1 + m
        if L > max_length or vs + L > n:
            break
        ks.append(pos)
        vss.append(vs)
        Ls.append(L)
        pos = vs + L
    return ks, vss, Ls


def _decode_batch(data, ks, vss, Ls, base, verify):
    """Decode a run of packets with numpy, group by group. Returns the list of packets
    (None for a bad one: the per-packet decoder then reports it)."""
    ks = np.asarray(ks, np.int64)
    vss = np.asarray(vss, np.int64)
    Ls = np.asarray(Ls, np.int64)
    arr = np.frombuffer(data, np.uint8)
    res = [None] * len(ks)
    gid = Ls * 32 + (vss - ks)
    order = np.argsort(gid, kind="stable")
    for rows in np.split(order, np.flatnonzero(np.diff(gid[order])) + 1):
        L = int(Ls[rows[0]])
        M = _gather(arr, vss[rows], L)
        ok, matches = _match_group(data, M, vss[rows], int(ks[rows[0]]), L, verify)
        for lay, sel in matches:
            dst = rows[sel]
            for j, p in zip(dst.tolist(), _group_packets(lay, M[sel], (ks[dst] + base).tolist())):
                res[j] = p
    return res


def _columns_from_bytes(data: bytes, verify: bool, quirks: QuirkTally | None = None) -> dict[str, np.ndarray]:
    n = len(data)
    key = UAS_LS_KEY
    ks_run: list[int] = []
    vss_run: list[int] = []
    Ls_run: list[int] = []
    pos = 0
    stop = None  # offset from which the exact scanner takes over
    while True:
        if not data.startswith(key, pos):
            # Bytes that are no packet: skipped (the scanner reports them; columns keep
            # good packets only), the scan goes on at the next key as the scanner's does.
            pos = data.find(key, pos)
            if pos < 0:
                break
        run = _locate_run(data, pos, n, 1 << 62, MAX_PACKET_LENGTH)
        if not run[0]:
            stop = pos  # an incomplete or odd packet here: the scanner decides
            break
        ks_run += run[0]
        vss_run += run[1]
        Ls_run += run[2]
        pos = run[1][-1] + run[2][-1]
    ks = np.array(ks_run, np.int64)
    vss = np.array(vss_run, np.int64)
    Ls = np.array(Ls_run, np.int64)
    N = len(ks)
    arr = np.frombuffer(data, np.uint8)
    cols = _empty_columns(N)
    cols["offset"][:] = ks
    good = np.zeros(N, bool)
    qrows = []  # (quirks, packet rows) of the layouts that have quirks
    if N:
        gid = Ls * 32 + (vss - ks)
        order = np.argsort(gid, kind="stable")
        for idx in np.split(order, np.flatnonzero(np.diff(gid[order])) + 1):
            L = int(Ls[idx[0]])
            for b0 in range(0, len(idx), _BLOCK):
                rows = idx[b0 : b0 + _BLOCK]
                M = _gather(arr, vss[rows], L)
                ok, matches = _match_group(data, M, vss[rows], int(ks[rows[0]]), L, verify)
                good[rows] = ok
                for lay, sel in matches:
                    Ms, dst = M[sel], rows[sel]
                    if quirks is not None and lay.quirks:
                        qrows.append((lay.quirks, dst))
                    for spec, tag, off, ln in lay.vitems:
                        if spec is not None and tag != _CHECKSUM_TAG:
                            if ln == 0 and spec.kind != "str":
                                cols[spec.name][dst] = None if spec.kind == "str" else np.nan
                            else:
                                val, flags = _item_values(spec, Ms, off, ln)
                                cols[spec.name][dst] = val
                                for mask, _ in flags:
                                    res = cols["reserved"]
                                    for j in dst[mask]:
                                        res[j] = _reserved_names(res[j] + (spec.name,))
    bad = np.flatnonzero(~good)
    cut = int(bad[0]) if len(bad) else N
    if cut < N:
        stop = int(ks[cut])
    out = {name: c[:cut] for name, c in cols.items()}
    if quirks is not None:  # qrows is filled only then
        for kinds, dst in qrows:  # the packets before the cut (the scanner counts the rest's)
            dst = dst[dst < cut]
            if len(dst):
                for kind in kinds:
                    quirks.add_kind(kind, len(dst), int(ks[dst].min()))
    if stop is not None:
        rest, _ = _scan(data, 0, True, _ScanState(None), verify, stop)
        if quirks is not None:
            for r in rest:
                quirks.add(r)
        tail = _columns_from_packets(rest)
        out = {name: np.concatenate([out[name], tail[name]]) for name in out}
    return out
