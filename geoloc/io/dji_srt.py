"""DJI flight-log subtitles: the ``.SRT`` file beside a DJI video, read as a flight.

DJI's aircraft write one SubRip block per video frame (or per second on older models)::

    12
    00:00:00,367 --> 00:00:00,400
    <font size="28">FrameCnt: 12, DiffTime: 33ms
    2023-06-01 10:11:12.345
    [iso: 100] [shutter: 1/640.0] [fnum: 2.8] [ev: 0] [focal_len: 24.00] [latitude: 36.520000]
    [longitude: -84.210000] [rel_alt: 100.200 abs_alt: 412.600] [ct: 5500] </font>

and, on older models (Phantom 4, Inspire 2)::

    1
    00:00:00,000 --> 00:00:01,000
    HOME(-84.2100,36.5200) 2017.08.05 14:11:51
    GPS(-84.2100,36.5200,412.6) BAROMETER:100.2

The fields read (units as DJI writes them: degrees, metres): ``latitude``, ``longitude`` (also
DJI's misspelling ``longtitude``), ``rel_alt`` (height above the take-off point), ``abs_alt``
(altitude above mean sea level, taken as EGM96 orthometric: DJI's "absolute altitude"; the
same datum question as the photos' AbsoluteAltitude, ``docs/photos.md``), ``altitude`` (older
bracketed files: above sea level), ``GPS(lon, lat, alt)`` and ``BAROMETER`` (height above
take-off) of the older form, ``gb_yaw``, ``gb_pitch``, ``gb_roll`` (gimbal, degrees, DJI's
earth-referenced NED z-y-x when present), ``focal_len``, ``dzoom_ratio``, ``FrameCnt``, the
block's time code and date-time. Every other ``[key: value]`` is kept as text.

A block that cannot be read (bad time code, a position that is not a number or out of range,
no position) is reported with its line number and skipped; the good blocks are kept.
``docs/photos.md``, "DJI flight-log subtitles (.SRT)", is the user's page.
"""

from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from geoloc.userfiles import atomic_path, note_input

__all__ = ["SRT_COLUMNS", "SrtFlight", "SrtRecord", "read_srt", "write_srt_records"]

_TIME = re.compile(r"^\s*(\d+):(\d{2}):(\d{2})[,.](\d{1,3})\s*-->\s*(\d+):(\d{2}):(\d{2})[,.](\d{1,3})\s*$")
_PAIR = re.compile(r"([A-Za-z_]+)\s*:\s*([-+]?[0-9.]+(?:/[0-9.]+)?(?=[\s\],]|$)|[^\]\s,]+)")
_GPS = re.compile(r"GPS\s*\(\s*([^,()]+),\s*([^,()]+)(?:,\s*([^,()]+))?\)")
_BARO = re.compile(r"BAROMETER\s*:\s*([-+]?[0-9.]+)")
_DATETIME = re.compile(r"(\d{4}[-.]\d{2}[-.]\d{2}[ T]\d{2}:\d{2}:\d{2}(?:[.,]\d+)*)")
_TAGS = re.compile(r"<[^>]*>")

#: Columns of :func:`write_srt_records` (heights ellipsoidal in ac_h_m, datums stated).
SRT_COLUMNS = [
    "index",
    "line",
    "frame",
    "start_s",
    "end_s",
    "datetime",
    "ac_lat_deg",
    "ac_lon_deg",
    "ac_h_m",
    "h_datum",
    "abs_alt_m",
    "abs_alt_datum",
    "rel_alt_m",
    "rel_alt_datum",
    "heading_deg",
    "pitch_deg",
    "roll_deg",
    "gimbal_yaw_deg",
    "gimbal_pitch_deg",
    "gimbal_roll_deg",
    "focal_len_mm",
]


@dataclass
class SrtRecord:
    """One subtitle block: the aircraft's position and heights at a time of the video."""

    index: int
    line: int
    start_s: float
    end_s: float
    lat_deg: float
    lon_deg: float
    abs_alt_m: float | None = None
    rel_alt_m: float | None = None
    frame: int | None = None
    datetime: str = ""
    gimbal_yaw_deg: float | None = None
    gimbal_pitch_deg: float | None = None
    gimbal_roll_deg: float | None = None
    focal_len_mm: float | None = None
    fields: dict = field(default_factory=dict)


@dataclass
class SrtFlight:
    """The good blocks of an SRT file and the bad ones (``(line, message)``).

    ``warnings`` (``(line, message)``): good blocks kept with a note, a time code that goes back
    from the block before it (a cut or spliced file); the blocks stay in file order.
    """

    path: str
    records: list
    errors: list
    form: str = ""
    warnings: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.records)

    def summary(self) -> str:
        n = len(self.records)
        text = f"{Path(self.path).name}: {n} SRT record(s) ({self.form or 'no'} form)"
        if n:
            t0, t1 = self.records[0].start_s, self.records[-1].end_s
            text += f", {t0:.3f}-{t1:.3f} s of video"
        if self.errors:
            text += f"; {len(self.errors)} bad block(s) skipped"
        if self.warnings:
            text += f"; {len(self.warnings)} time code(s) going back"
        return text


def _num(text: str) -> float:
    text = text.strip()
    if "/" in text:
        a, b = text.split("/", 1)
        return float(a) / float(b)
    return float(text)


def _blocks(lines):
    """(first line number, lines) of each blank-line-separated block."""
    block, start = [], 0
    for k, s in enumerate(lines, start=1):
        if s.strip():
            if not block:
                start = k
            block.append(s)
        elif block:
            yield start, block
            block = []
    if block:
        yield start, block


def read_srt(path: str | os.PathLike[str]) -> SrtFlight:
    """Read a DJI ``.SRT`` flight log (module docstring); bad blocks are reported, good ones kept.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not text (UTF-8), or no block at all is readable (the message gives the first errors).
    """
    note_input(path)
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"SRT file not found: {path}")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(
            f"{p.name}: not a text SRT file (UTF-8): byte 0x{e.object[e.start]:02x} at offset {e.start} (file {path})"
        ) from None
    records, errors, forms = [], [], set()
    for start, block in _blocks(text.splitlines()):
        rec, err, form = _parse_block(start, block)
        if err is not None:
            errors.append(err)
            continue
        records.append(rec)
        forms.add(form)
    if not records:
        first = "; ".join(f"line {ln}: {msg}" for ln, msg in errors[:3]) or "the file is empty"
        raise ValueError(f"{p.name}: no readable DJI SRT block ({first}) (file {path})")
    # a time code before the block before it is kept (the file's order is the video's) and reported
    warnings = [
        (b.line, f"time code {b.start_s:.3f} s goes back from {a.start_s:.3f} s (the block at line {a.line})")
        for a, b in zip(records, records[1:])
        if b.start_s < a.start_s
    ]
    return SrtFlight(str(path), records, errors, "+".join(sorted(forms)), warnings)


def _parse_block(start: int, block: list):
    # the index line, then the time code (some writers omit the index)
    k = 0
    if block[0].strip().isdigit():
        index, k = int(block[0].strip()), 1
    else:
        index = -1
    if k >= len(block):
        return None, (start, "a subtitle index without a time code"), ""
    m = _TIME.match(block[k])
    if m is None:
        return None, (start + k, f"time code {block[k].strip()!r} is not 'HH:MM:SS,mmm --> HH:MM:SS,mmm'"), ""
    g = [int(x) for x in m.groups()]
    t0 = g[0] * 3600 + g[1] * 60 + g[2] + int(m.group(4).ljust(3, "0")) / 1000.0
    t1 = g[4] * 3600 + g[5] * 60 + g[6] + int(m.group(8).ljust(3, "0")) / 1000.0
    body_lines = block[k + 1 :]
    body = _TAGS.sub(" ", " ".join(body_lines))
    fields: dict[str, str] = {}
    for key, value in _PAIR.findall(body):
        fields.setdefault(key.lower(), value)
    rec = SrtRecord(index, start, t0, t1, math.nan, math.nan)
    dt = _DATETIME.search(body)
    rec.datetime = dt.group(1) if dt else ""

    def number(key, text, line_hint):
        try:
            v = _num(text)
        except (ValueError, ZeroDivisionError):
            raise _BadField(f"{key} = {text!r} is not a number", line_hint) from None
        if not math.isfinite(v):
            raise _BadField(f"{key} = {text!r} is not finite", line_hint)
        return v

    def line_of(key):
        for j, s in enumerate(body_lines):
            if key.lower() in s.lower():
                return start + k + 1 + j
        return start

    try:
        gps = _GPS.search(body)
        if "latitude" in fields or "longitude" in fields or "longtitude" in fields:
            form = "bracketed"
            lon_key = "longitude" if "longitude" in fields else "longtitude"
            if "latitude" not in fields or lon_key not in fields:
                raise _BadField("latitude and longitude must both be given", line_of("lat"))
            rec.lat_deg = number("latitude", fields["latitude"], line_of("latitude"))
            rec.lon_deg = number(lon_key, fields[lon_key], line_of(lon_key))
            if "abs_alt" in fields:
                rec.abs_alt_m = number("abs_alt", fields["abs_alt"], line_of("abs_alt"))
            elif "altitude" in fields:
                rec.abs_alt_m = number("altitude", fields["altitude"], line_of("altitude"))
            if "rel_alt" in fields:
                rec.rel_alt_m = number("rel_alt", fields["rel_alt"], line_of("rel_alt"))
        elif gps is not None:
            form = "GPS(lon,lat,alt)"
            rec.lon_deg = number("GPS longitude", gps.group(1), line_of("GPS"))
            rec.lat_deg = number("GPS latitude", gps.group(2), line_of("GPS"))
            if gps.group(3) is not None:
                rec.abs_alt_m = number("GPS altitude", gps.group(3), line_of("GPS"))
            baro = _BARO.search(body)
            if baro:
                rec.rel_alt_m = number("BAROMETER", baro.group(1), line_of("BAROMETER"))
        else:
            raise _BadField("no position: neither [latitude: ..] [longitude: ..] nor GPS(lon,lat,alt)", start)
        if not (abs(rec.lat_deg) <= 90.0 and abs(rec.lon_deg) <= 180.0):
            raise _BadField(
                f"latitude, longitude = {rec.lat_deg!r}, {rec.lon_deg!r}: out of range",
                line_of("lat") if form == "bracketed" else line_of("GPS"),
            )
        if rec.lat_deg == 0.0 and rec.lon_deg == 0.0:
            raise _BadField(
                "latitude, longitude = 0, 0: no GPS fix", line_of("lat") if form == "bracketed" else line_of("GPS")
            )
        for key, attr in (
            ("gb_yaw", "gimbal_yaw_deg"),
            ("gb_pitch", "gimbal_pitch_deg"),
            ("gb_roll", "gimbal_roll_deg"),
            ("focal_len", "focal_len_mm"),
        ):
            if key in fields:
                setattr(rec, attr, number(key, fields[key], line_of(key)))
        fc = fields.get("framecnt")
        if fc is not None:
            rec.frame = int(number("FrameCnt", fc, line_of("FrameCnt")))
    except _BadField as e:
        return None, (e.line, str(e)), ""
    rec.fields = fields
    return rec, None, form


class _BadField(ValueError):
    def __init__(self, message, line):
        super().__init__(message)
        self.line = line


def write_srt_records(path: str | os.PathLike[str], flight: SrtFlight) -> int:
    """Write the flight's records as a CSV (:data:`SRT_COLUMNS`); returns the rows written.

    Heights: ``ac_h_m`` is ellipsoidal (WGS 84): ``abs_alt`` taken as EGM96 orthometric plus the
    bundled EGM96 undulation N (h = H + N); ``abs_alt_m`` is DJI's value as written
    (``abs_alt_datum``) and ``rel_alt_m`` the height above the take-off point (``rel_alt_datum``).
    Without a gimbal in the file (most models) the angle columns are empty. Written through
    :func:`geoloc.userfiles.atomic_path`.
    """
    from geoloc.geodesy.geoid import egm96_undulation
    from geoloc.io.gis import ELLIPSOID_DATUM

    def cell(v):
        if v is None:
            return ""
        if isinstance(v, float):
            return "" if not math.isfinite(v) else repr(v)
        return str(v)

    with atomic_path(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(SRT_COLUMNS)
        for r in flight.records:
            h = None
            if r.abs_alt_m is not None:
                h = r.abs_alt_m + float(egm96_undulation(math.radians(r.lat_deg), math.radians(r.lon_deg)))
            earth = r.gimbal_yaw_deg is not None
            w.writerow(
                [
                    cell(v)
                    for v in (
                        r.index,
                        r.line,
                        r.frame,
                        r.start_s,
                        r.end_s,
                        r.datetime,
                        r.lat_deg,
                        r.lon_deg,
                        h,
                        ELLIPSOID_DATUM if h is not None else "",
                        r.abs_alt_m,
                        "EGM96 (DJI abs_alt, above mean sea level)" if r.abs_alt_m is not None else "",
                        r.rel_alt_m,
                        "above the take-off point" if r.rel_alt_m is not None else "",
                        0.0 if earth else None,
                        0.0 if earth else None,
                        0.0 if earth else None,
                        r.gimbal_yaw_deg,
                        r.gimbal_pitch_deg,
                        r.gimbal_roll_deg,
                        r.focal_len_mm,
                    )
                ]
            )
    return len(flight.records)
