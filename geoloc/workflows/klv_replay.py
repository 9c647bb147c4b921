"""Replay of MISB ST 0601 KLV metadata: recompute each packet's frame centre and corners, compare.

Every UAS Datalink LS packet (``geoloc.io.klv``) carries the platform's pose, the
sensor's pointing and field of view, and what the platform itself computed from
them: the frame centre (tags 23-25, 78) and the image corners (82-89, or the
offsets 26-33). This module recomputes the frame centre and the four corners of
every packet from the packet's own pose, through the sensor interface, and
measures how far the platform's answer is from it (``docs/klv.md``, "Replay").

The sensor (:func:`klv_sensor`): a :class:`geoloc.sensors.frame.FrameSensor` on
the ``azimuth-elevation-roll`` gimbal preset (tags 18, 19, 20 are its angles
``azimuth``, ``elevation``, ``sensor_roll``; ``docs/conventions.md``, "Gimbal
presets") with a lens from the fields of view (tags 16, 17:
:func:`geoloc.sensors.lenses.lens_from_fov`), principal point at the image
centre. The image size comes from an optional sensor file (with its mount,
boresight and lever arm), else a nominal 1920 x 1080: the corners depend only
on the fields of view. The frame centre is the line of sight of the image
centre ((M+1)/2, (N+1)/2), the corners are the image corners (rows 0.5 and
M + 0.5, columns 0.5 and N + 0.5: the outer edges of the corner pixels, as
1-based pixel centres count them; ``docs/conventions.md``, "Pixels").

Per packet, the pose is

* position: tags 13, 14 and the sensor height, tag 75 (HAE) when present, else
  tag 15 (MSL) + N (the bundled EGM96 grid, :func:`geoloc.geodesy.geoid.egm96_undulation`);
* attitude: tag 5 (heading), tag 90 (pitch, full range) else 6, tag 91 (roll,
  full range) else 7, z-y-x from NED;
* gimbal: tags 18, 19, 20; lens: tags 16, 17.

Without a DEM every ray is intersected with the surface of constant geodetic
height at the packet's own frame-centre height (tag 78, else tag 25 + N), so
the comparison isolates the angles; with a DEM (:class:`geoloc.surfaces.terrain.DemSurface`),
with the terrain. All packets are one batch: one :class:`geoloc.frames.chain.Pose`
of angle arrays, one call for the frame centres and one for the four corners.

Varying fields of view in one batch: one sensor serves every packet. Its lens is
``lens_from_fov`` of the file's median fields of view, and packet i's corners are
the pixels whose rays are those of ``lens_from_fov(hfov_i, vfov_i)``'s corners:
for a pinhole, column c of the packet's lens and column
c0 + (c - c0) tan(hfov_i / 2) / tan(hfov_ref / 2) of the reference lens have the
same ray (exactly; the tests hold it to one sensor per packet). Those pixels may
lie beyond the reference sensor's edge; they are located with
``outside="extrapolate"``, which for a pinhole is exact.

Outliers: a packet's frame-centre error e is flagged when
``|e - median| > max(3.5 * 1.4826 * MAD, 1 m)`` over the file's compared packets
(MAD the median absolute deviation from the median; 1.4826 MAD estimates the
standard deviation of normal errors, so 3.5 of them is the usual modified
z-score cut of Iglewicz and Hoaglin; the 1 m floor keeps a stream whose errors
are all at the quantisation level, millimetres, from flagging noise).

Distances are horizontal geodesic distances on WGS-84 (:mod:`geoloc.geodesy.geodesic`).
Every height written is ellipsoidal (WGS-84) except the decoded MSL items,
whose column names say ``_msl_``; the ``h_datum`` column states it per row.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.analysis.accuracy import MAD_SCALE, MIN_EXCESS_M, OUTLIER_K, outlier_rule
from geoloc.frames.chain import Pose
from geoloc.geodesy.geodesic import horizontal_distance_m
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.sensors.platform import DRONE_CEILING_M, DRONE_MAX_HEIGHT_M
from geoloc.io.klv import (
    TAG_BY_NAME,
    KlvError,
    Packet,
    QuirkTally,
    is_container_file,
    iter_packets,
    packets_to_columns,
    read_ts_klv,
    sniff_klv_file,
)
from geoloc.io.mgrs_grid import mgrs_column
from geoloc.locate import line_of_sight, locate
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import lens_from_fov
from geoloc.status import Status, names
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.height import HeightSurface
from geoloc.userfiles import atomic_path

if TYPE_CHECKING:
    from geoloc.sensors.budget import ErrorBudget
    from geoloc.surfaces.base import Surface

#: What :func:`read_klv` reads: a file's path, its bytes, or the results of a :mod:`geoloc.io.klv` read.
KlvSource = str | os.PathLike[str] | bytes | bytearray | memoryview | Iterable[Packet | KlvError]

__all__ = [
    "CONTAINER_SUFFIXES",
    "GIMBAL",
    "H_DATUM",
    "KLV_SUFFIXES",
    "MIN_EXCESS_M",
    "NOMINAL_SIZE",
    "OUTLIER_K",
    "RAW_SUFFIXES",
    "KlvRead",
    "KlvReplay",
    "KlvSummary",
    "is_klv_path",
    "klv_pose",
    "klv_pose_deg",
    "klv_sensor",
    "outlier_mask",
    "read_klv",
    "replay_klv",
    "write_klv_csv",
]

#: Raw KLV files (concatenated packets).
RAW_SUFFIXES = (".klv", ".bin")
#: Containers read through PyAV (``geoloc.io.klv.read_ts_klv``).
CONTAINER_SUFFIXES = (".ts", ".m2ts", ".mts", ".mpg", ".mpeg", ".mp4", ".mov", ".mkv", ".trp")
#: Every suffix the KLV replay takes.
KLV_SUFFIXES = RAW_SUFFIXES + CONTAINER_SUFFIXES
#: The gimbal preset whose angles are tags 18, 19, 20.
GIMBAL = "azimuth-elevation-roll"
#: Image size (width, height) [pixels] when no sensor file gives one.
NOMINAL_SIZE = (1920, 1080)
# The outlier rule's constants (OUTLIER_K = 3.5 robust sigmas, MAD_SCALE = 1.4826, MIN_EXCESS_M = 1 m)
# live with the rule in geoloc.analysis.accuracy and are re-exported here.
#: Tag 75 - tag 15 (or 78 - 25) may differ from N by this much before a datum warning [m]
#: (two 0.3 m quantisation steps and the geoid grid's own error fit well inside).
DATUM_CHECK_M = 3.0
#: The datum of every height column without ``_msl_`` in its name.
H_DATUM = "ellipsoid (WGS 84)"

_TAG_TEXT = {name: f"tag {s.tag} ({s.title})" for name, s in TAG_BY_NAME.items()}
#: A needed item the packet holds with the standard's reserved value (0x80..., ST 0601's
#: "error" / "out of range"): the writer had no value for it.
_RESERVED_NOTE = "holds the standard's reserved value (error / out of range): no value"


def is_klv_path(path: str | os.PathLike[str]) -> bool:
    """True for a file the KLV replay reads: by its suffix (``.klv``, ``.bin``, ``.ts``, ``.mpg``,
    ``.mp4``, ...), or, whatever its name, by its first bytes (an MPEG-TS's sync bytes, a raw
    KLV's universal key: :func:`geoloc.io.klv.sniff_klv_file`: a suffix can lie)."""
    p = Path(str(path))
    if p.suffix.lower() in KLV_SUFFIXES:
        return True
    try:
        return p.is_file() and sniff_klv_file(p) in ("mpegts", "klv")  # not ftyp: a HEIC photo has one
    except OSError:
        return False


# --------------------------------------------------------------------------- reading


@dataclass
class KlvRead:
    """The good packets of one file as columns, and the bad ones.

    Attributes
    ----------
    source : str
        File name (or a label).
    columns : dict
        :func:`geoloc.io.klv.packets_to_columns` of the good packets.
    errors : list of KlvError
        The bad packets, in file order, with their byte offsets.
    quirks : list of str
        The writer's quirks that left the values unambiguous, one line per kind with its
        count and first offset (:class:`geoloc.io.klv.QuirkTally`, docs/klv.md).
    pts_s : ndarray
        Container presentation time of each good packet [s] (NaN for raw KLV).
    packet : ndarray of int
        Each good packet's number in the file (0-based), bad packets counted: every
        packet the scanner found a key for is one, stray bytes are none.
    time_back : list of str
        The packets whose Precision Time Stamp (tag 2) goes back from the packet with a time
        stamp before them: one line (their count and the first one's :attr:`Packet.time_back`),
        or none.
    """

    source: str
    columns: dict
    errors: list
    pts_s: np.ndarray
    packet: np.ndarray
    quirks: list = field(default_factory=list)
    time_back: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.columns["offset"])


def _tiles(data: bytes, offsets) -> bool:
    """True when the packets at ``offsets`` (key offsets, file order) cover ``data``
    end to end: then no byte was skipped and the scanner has nothing to report."""
    ks = np.asarray(offsets, np.int64)
    if len(ks) == 0:
        return len(data) == 0
    arr = np.frombuffer(data, np.uint8)
    b = arr[ks + 16].astype(np.int64)
    long = b >= 0x80
    length = np.where(long, 0, b)
    head = np.full(len(ks), 17, np.int64)
    if long.any():
        m = b[long] & 0x7F
        kl = ks[long]
        val = np.zeros(len(kl), np.int64)
        for j in range(int(m.max())):
            more = j < m
            byte = arr[np.where(more, kl + 17 + j, 0)].astype(np.int64)
            val = np.where(more, val * 256 + byte, val)
        length[long] = val
        head[long] = 17 + m
    ends = ks + head + length
    return bool(ks[0] == 0 and ends[-1] == len(data) and np.all(ks[1:] == ends[:-1]))


def _is_stray(e: KlvError) -> bool:
    """Bytes that are no packet (geoloc.io.klv reports them '... are not a UAS LS packet')."""
    return e.reason.endswith("are not a UAS LS packet")


def _time_back_line(count: int, first: str | None) -> list[str]:
    """One line for every packet whose time stamp goes back: the count and the first one's note
    (as a quirk is reported: once per kind, never once per packet)."""
    if not count:
        return []
    return [f"{count} packet{'s' if count != 1 else ''}, the first: {first}"]


def _time_back_columns(cols: dict) -> list[str]:
    """:func:`_time_back_line` of columns decoded from raw bytes that tile the file (every packet
    good, so packet k of the file is row k - 1): the same note as
    :func:`geoloc.io.klv._note_time_back` gives each packet, from one vectorised difference of the
    time stamps (each against the packet with a time stamp before it)."""
    t = cols.get("precision_time_stamp_us")
    if t is None or len(t) < 2:
        return []
    has = np.flatnonzero(~np.isnan(t))
    if len(has) < 2:
        return []
    ts = t[has]
    back = np.flatnonzero(ts[1:] < ts[:-1])  # float64 holds the microseconds exactly (packets_to_columns)
    if len(back) == 0:
        return []
    i, j = int(has[back[0] + 1]), int(has[back[0]])
    off = cols["offset"]
    first = (
        f"packet {i + 1} (byte {int(off[i])}): Precision Time Stamp goes back "
        f"{(int(t[j]) - int(t[i])) / 1e6:.6f} s from packet {j + 1} (byte {int(off[j])})"
    )
    return _time_back_line(len(back), first)


def _from_results(results, source: str) -> KlvRead:
    packets, errors, number = [], [], []
    seq = 0
    tally = QuirkTally()
    n_back, first_back = 0, None
    for r in results:
        if isinstance(r, Packet):
            tally.add(r)
            if r.time_back:
                n_back += 1
                first_back = first_back or r.time_back
            packets.append(r)
            number.append(seq)
            seq += 1
        elif isinstance(r, KlvError):
            errors.append(r)
            seq += 0 if _is_stray(r) else 1
    cols = packets_to_columns(packets)
    pts_s = np.array([np.nan if p.time_s is None else p.time_s for p in packets], float)
    number_ = np.array(number, np.int64)
    return KlvRead(source, cols, errors, pts_s, number_, tally.lines(), _time_back_line(n_back, first_back))


def read_klv(
    source: KlvSource, *, verify_checksum: bool = True, fast: bool = True, label: str | None = None
) -> KlvRead:
    """Read the packets of a KLV file, an MPEG-TS (or other container), raw bytes or read results.

    Parameters
    ----------
    source : path, bytes, or iterable of Packet / KlvError
        A ``.klv`` / ``.bin`` file (concatenated packets), a container (``.ts``,
        ``.mpg``, ``.mp4``, ...: its KLV data stream through PyAV), raw bytes, or
        the results of a :mod:`geoloc.io.klv` read.
    verify_checksum : bool
        Check each packet's checksum (tag 1). Default True.
    fast : bool
        Raw bytes: decode with :func:`geoloc.io.klv.packets_to_columns` (numpy) and,
        when the good packets do not cover the file end to end (a bad packet or
        stray bytes), read again packet by packet to report the bad ones. False:
        always packet by packet. Same results either way.
    label : str, optional
        Name used in messages (default: the file name).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A container PyAV cannot open, or one without a data stream.
    """
    if isinstance(source, (bytes, bytearray, memoryview)):
        return _read_bytes(bytes(source), label or "<bytes>", verify_checksum, fast)
    if isinstance(source, (str, os.PathLike)):  # a path (os.PathLike: any object with __fspath__)
        p = Path(source)
        if not p.exists():
            raise FileNotFoundError(f"KLV file {str(source)!r} does not exist")
        if not p.is_file():
            raise FileNotFoundError(f"KLV path {str(source)!r} is not a file")
        name = label or str(p)
        if is_container_file(p):  # by its bytes: a .ts renamed .klv is still an MPEG-TS
            return _from_results(read_ts_klv(p, verify_checksum=verify_checksum), name)
        return _read_bytes(p.read_bytes(), name, verify_checksum, fast)
    return _from_results(list(source), label or "<packets>")


def _read_bytes(data: bytes, source: str, verify: bool, fast: bool) -> KlvRead:
    if fast:
        tally = QuirkTally()
        cols = packets_to_columns(data, verify_checksum=verify, quirks=tally)
        if _tiles(data, cols["offset"]):
            m = len(cols["offset"])
            pts_s, number = np.full(m, np.nan), np.arange(m, dtype=np.int64)
            return KlvRead(source, cols, [], pts_s, number, tally.lines(), _time_back_columns(cols))
    return _from_results(iter_packets(data, verify_checksum=verify), source)


# --------------------------------------------------------------------------- the sensor


def klv_sensor(hfov: float, vfov: float, base: FrameSensor | None = None) -> FrameSensor:
    """The replay's sensor: ``lens_from_fov(hfov, vfov, width, height)`` on the
    ``azimuth-elevation-roll`` preset, principal point at the image centre.

    Parameters
    ----------
    hfov, vfov : float
        Fields of view [rad], in (0, pi).
    base : FrameSensor, optional
        A sensor file's sensor: its image size, mount, boresight and lever arm are
        kept, its lens is replaced (ST 0601 gives fields of view, no distortion), its
        gimbal must be ``azimuth-elevation-roll`` or ``azimuth-elevation`` (the same
        joints without the roll, which tag 20 then supplies). Default: a nominal
        1920 x 1080 image and no mount, boresight or lever arm.

    Raises
    ------
    ValueError
        A base sensor on another gimbal (the message names it).
    """
    if base is None:
        w, h = NOMINAL_SIZE
        return FrameSensor(lens_from_fov(hfov, vfov, w, h), PRESETS[GIMBAL], name="MISB ST 0601 sensor")
    if not isinstance(base, FrameSensor):
        raise ValueError(
            f"sensor {base!r}: the KLV replay needs a sensor file ([lens], [gimbal] preset = "
            f"{GIMBAL!r}); a first-phase camera file has the [Q17] roll-pitch gimbal"
        )
    if base.gimbal.name not in (GIMBAL, "azimuth-elevation"):
        raise ValueError(
            f"sensor {base.name or 'file'}: gimbal {base.gimbal.name!r}: MISB ST 0601's "
            f"sensor-relative angles (tags 18-20) are the {GIMBAL!r} preset; give a sensor "
            f"file with [gimbal] preset = {GIMBAL!r} (or 'azimuth-elevation')"
        )
    lens = lens_from_fov(hfov, vfov, base.cols, base.rows)
    return dataclasses.replace(base, lens=lens, gimbal=PRESETS[GIMBAL])


# --------------------------------------------------------------------------- poses


def klv_pose_deg(columns: dict, k: int | None = None) -> dict:
    """The pose of each replayed packet from :attr:`KlvReplay.columns`, as keyword arguments in degrees.

    Keys ``lat_deg, lon_deg, h_m`` (the sensor: tags 13, 14 and the ellipsoidal
    height of tag 75, else tag 15 + N), ``heading_deg, pitch_deg, roll_deg``
    (tag 5; 90 else 6; 91 else 7) and ``angles_deg`` (``azimuth``, ``elevation``,
    ``sensor_roll``: tags 18, 19, 20; a missing sensor roll is 0, as only the
    corners need it): the names of :meth:`geoloc.frames.chain.Pose.from_deg`
    and of the viewer's ``Inputs``. With ``k``, packet ``k``'s values as floats.
    """

    def get(name):
        v = np.asarray(columns[name], float)
        return float(v[k]) if k is not None else v

    roll = get("sensor_relative_roll_deg")
    roll = (roll if math.isfinite(roll) else 0.0) if k is not None else np.nan_to_num(roll)
    return {
        "lat_deg": get("sensor_lat_deg"),
        "lon_deg": get("sensor_lon_deg"),
        "h_m": get("sensor_h_m"),
        "heading_deg": get("platform_heading_deg"),
        "pitch_deg": get("platform_pitch_deg"),
        "roll_deg": get("platform_roll_deg"),
        "angles_deg": {
            "azimuth": get("sensor_relative_azimuth_deg"),
            "elevation": get("sensor_relative_elevation_deg"),
            "sensor_roll": roll,
        },
    }


def klv_pose(columns: dict) -> Pose:
    """Every replayed packet's pose as one batched :class:`geoloc.frames.chain.Pose` (:func:`klv_pose_deg`)."""
    return Pose.from_deg(**klv_pose_deg(columns))


# --------------------------------------------------------------------------- outliers


def outlier_mask(
    err: ArrayLike, k: float = OUTLIER_K, min_excess_m: float = MIN_EXCESS_M
) -> tuple[np.ndarray, float, float, float]:
    """Robust outlier flags: ``|e - median| > max(k * 1.4826 * MAD, min_excess_m)``.

    The one rule of :func:`geoloc.analysis.accuracy.outlier_rule` (which the
    accuracy report also uses); kept under this name for the KLV replay.

    Returns
    -------
    (mask, median, mad, threshold)
        ``mask`` (bool, the shape of ``err``); the median, the MAD and the cut on
        ``|e - median|`` [m] (NaN when no error is finite).
    """
    return outlier_rule(err, k, min_excess_m)


# --------------------------------------------------------------------------- the replay


@dataclass
class KlvSummary:
    """What one file's replay found (``str()`` prints it).

    Counts are of good packets; ``outliers`` are file packet numbers (bad packets
    counted, as the ``packet`` column); distances in metres (NaN when nothing was
    compared); ``*_h_sources`` count the packets whose height came from each tag;
    ``datum_warnings`` has one line per packet whose HAE and MSL items disagree with N.
    """

    source: str
    packets: int
    errors: list
    status_counts: dict
    invalid_reasons: dict
    compared: int
    median_m: float
    p90_m: float
    max_m: float
    corner_compared: int
    corner_median_m: float
    corner_p90_m: float
    outliers: list
    outlier_median_m: float
    outlier_threshold_m: float
    sensor_h_sources: dict
    reported_h_sources: dict
    surface: str
    datum_warnings: list
    notes: list = field(default_factory=list)
    #: One line per drone packet (Platform Designation, or the sensor file's ``platform``) whose
    #: sensor is too high for a drone (:func:`_drone_height_warnings`, docs/records.md).
    plausibility_warnings: list = field(default_factory=list)
    #: The writer's quirks that left the values unambiguous: one line per kind (count, first offset).
    quirks: list = field(default_factory=list)
    #: The packets whose Precision Time Stamp goes back: one line (count, the first one's note) or none.
    time_back: list = field(default_factory=list)

    def __str__(self) -> str:
        L = [f"{self.source}: {self.packets} packets read, {len(self.errors)} bad packet(s) skipped"]
        for e in self.errors[:20]:
            L.append(f"  bad packet at {_where(e)}: {e.reason}")
        if len(self.errors) > 20:
            L.append(f"  ... and {len(self.errors) - 20} more bad packets")
        for q in self.quirks:
            L.append(f"  quirk: {q}")
        for q in self.time_back:  # kept and located in file order; the user is told where the clock went back
            L.append(f"  time goes back: {q}")
        L.append(f"  surface: {self.surface}")
        L.append("  sensor height: " + _counts(self.sensor_h_sources))
        L.append("  reported frame-centre height: " + _counts(self.reported_h_sources))
        L.append("  status: " + (", ".join(f"{k} {v}" for k, v in self.status_counts.items()) or "no packet"))
        for reason, count in self.invalid_reasons.items():
            L.append(f"    invalid_input, {count} packet(s): {reason}")
        if self.compared:
            L.append(
                f"  frame-centre error (recomputed vs reported, horizontal): median {self.median_m:.3f} m, "
                f"90th percentile {self.p90_m:.3f} m, max {self.max_m:.3f} m over {self.compared} packets"
            )
        else:
            L.append("  frame-centre error: no packet with both a reported and a recomputed frame centre")
        if self.corner_compared:
            L.append(
                f"  corner error (mean of the corners): median {self.corner_median_m:.3f} m, "
                f"90th percentile {self.corner_p90_m:.3f} m over {self.corner_compared} packets"
            )
        if self.compared:
            L.append(
                f"  outliers (|error - median| > max({OUTLIER_K:g} x {MAD_SCALE} x MAD, {MIN_EXCESS_M:g} m) "
                f"= {self.outlier_threshold_m:.3f} m from the median {self.outlier_median_m:.3f} m): "
                f"{len(self.outliers)} packet(s)" + (f": {_ranges(self.outliers)}" if self.outliers else "")
            )
        if self.datum_warnings:
            L.append(
                f"  datum check: {len(self.datum_warnings)} packet(s) whose HAE and MSL heights do not differ "
                f"by the EGM96 N (within {DATUM_CHECK_M:g} m): one of the two is in the wrong datum"
            )
            for w in self.datum_warnings[:5]:
                L.append(f"    {w}")
            if len(self.datum_warnings) > 5:
                L.append(f"    ... and {len(self.datum_warnings) - 5} more (column datum_warning)")
        if self.plausibility_warnings:
            L.append(
                f"  warning: {len(self.plausibility_warnings)} packet(s) too high for a drone "
                f"(over {DRONE_MAX_HEIGHT_M:g} m above the terrain or frame centre, or {DRONE_CEILING_M:g} m): "
                "used as read"
            )
            for w in self.plausibility_warnings[:5]:
                L.append(f"    {w}")
            if len(self.plausibility_warnings) > 5:
                L.append(f"    ... and {len(self.plausibility_warnings) - 5} more")
        L += [f"  note: {n}" for n in self.notes]
        L.append(
            f"  heights written: ellipsoidal, {H_DATUM} (column h_datum), except the decoded "
            "*_msl_m items (mean sea level)"
        )
        return "\n".join(L)


def _where(e: KlvError) -> str:
    where = f"byte {e.offset}" if e.offset is not None else "unknown position"
    return f"pts {e.pts} ({where})" if e.pts is not None else where


def _counts(d: dict) -> str:
    return ", ".join(f"{k}: {v} packet(s)" for k, v in d.items() if v) or "none"


def _ranges(idx) -> str:
    """[1, 2, 3, 7] -> 'packets 1-3, 7'."""
    idx = sorted(int(i) for i in idx)
    parts: list[str] = []
    start: int | None = None
    prev = -2  # no packet yet: the first one starts a range
    for i in idx:
        if start is None:
            start = prev = i
        elif i == prev + 1:
            prev = i
        else:
            parts.append(f"{start}-{prev}" if prev > start else f"{start}")
            start = prev = i
    if start is not None:
        parts.append(f"{start}-{prev}" if prev > start else f"{start}")
    return "packets " + ", ".join(parts)


@dataclass
class KlvReplay:
    """The replay of one file: a column per output field, the bad packets, the summary.

    Attributes
    ----------
    columns : dict
        Output column name -> array (one entry per good packet, file order); the
        columns are listed in docs/klv.md ("Replay", "Output columns").
    errors : list of KlvError
    summary : KlvSummary
    sensor : FrameSensor
        The sensor used (reference fields of view).
    """

    columns: dict
    errors: list
    summary: KlvSummary
    sensor: FrameSensor

    def __len__(self) -> int:
        return len(self.columns["packet"])

    def rows(self) -> list:
        """One dict per packet (NaN as None, status as its name)."""
        keys = list(self.columns)
        vals = [_pyvalues(k, self.columns[k]) for k in keys]
        return [dict(zip(keys, r)) for r in zip(*vals)]

    def write_csv(self, path: str | os.PathLike[str]) -> None:
        """Write the rows to a CSV (``geoloc.io.gis.read_results`` reads it back)."""
        write_klv_csv(path, [self])


def _pyvalues(name, arr):
    if name == "status" or name == "corner_status":
        return list(names(arr))
    a = np.asarray(arr)
    if a.dtype.kind == "f":
        return [None if v != v else v for v in a.tolist()]
    return a.tolist()


def _f(cols, name, n):
    v = cols.get(name)
    return np.full(n, np.nan) if v is None else np.asarray(v, float)


def _undulation(lat_deg, lon_deg):
    """EGM96 N [m] where lat/lon are finite, NaN elsewhere."""
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    out = np.full(lat.shape, np.nan)
    ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90)
    if ok.any():
        out[ok] = egm96_undulation(np.deg2rad(lat[ok]), np.deg2rad(lon[ok]))
    return out


def _iso(time_us):
    """Microseconds since 1970 UTC -> ISO 8601 strings ('' where NaN)."""
    t = np.asarray(time_us, float)
    out = np.full(t.shape, "", dtype=object)
    ok = np.isfinite(t)
    if ok.any():
        s = np.datetime_as_string(t[ok].astype(np.int64).astype("datetime64[us]"), unit="us")
        out[ok] = [x + "Z" for x in s.tolist()]
    return out


def _text(mask, yes, no=""):
    out = np.full(mask.shape, no, dtype=object)
    out[mask] = yes
    return out


def _append(notes, mask, text):
    if mask.any():
        notes[mask] = notes[mask] + text


def replay_klv(
    source: KlvSource | KlvRead,
    *,
    surface: Surface | None = None,
    sensor: FrameSensor | None = None,
    verify_checksum: bool = True,
    fast: bool = True,
    label: str | None = None,
    budget: ErrorBudget | None = None,
    corrections: Corrections = NO_CORRECTIONS,
) -> KlvReplay:
    """Recompute every packet's frame centre and corners and compare with the packet's own.

    Parameters
    ----------
    source : path, bytes, iterable of Packet / KlvError, or KlvRead
        What :func:`read_klv` reads (a ``.klv`` / ``.bin`` file, an MPEG-TS, ...).
    surface : Surface, optional
        Where the lines of sight end: a DEM (:class:`geoloc.surfaces.terrain.DemSurface`,
        a mosaic; :func:`geoloc.surfaces.terrain.surface_for`) or any surface; default:
        the surface of constant geodetic height at each packet's own frame-centre
        height (tag 78, else tag 25 + EGM96 N).
    sensor : FrameSensor, optional
        A sensor file's sensor (image size, mount, boresight, lever arm; see
        :func:`klv_sensor`).
    verify_checksum, fast, label
        See :func:`read_klv`.
    budget : ErrorBudget, optional
        The sensor file's ``[uncertainty]``: each frame centre's predicted uncertainty
        (:func:`geoloc.analysis.uncertainty.propagate`) as ``ce90_m le90_m ellipse_*`` beside
        the packet's own target error estimates, ``reported_ce90_m`` / ``reported_le90_m``
        (MISB ST 0601 tags 45 and 46, Target Error Estimate CE90 / LE90).
    corrections : Corrections
        The line-of-sight corrections of the location pipeline (:class:`geoloc.pipeline.Corrections`;
        none by default): the rows say which (``corrections``) and ``refraction_m``.

    Returns
    -------
    KlvReplay
        One row per good packet; a packet lacking a needed tag has status
        ``invalid_input`` and a ``note`` naming the tag, the others are located.
    """
    read = (
        source
        if isinstance(source, KlvRead)
        else read_klv(source, verify_checksum=verify_checksum, fast=fast, label=label)
    )
    return _replay(read, surface, sensor, budget, corrections)


#: The largest gap between two packets [s] across which a velocity is differenced: beyond it the
#: platform may have turned, and a chord is no velocity.
VELOCITY_MAX_GAP_S = 5.0


def platform_velocity_ned(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    h_m: ArrayLike,
    time_s: ArrayLike,
    north_m_s: ArrayLike | None = None,
    east_m_s: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.object_]]:
    """Each packet's platform velocity (north, east, down) [m/s], and where it comes from.

    MISB ST 0601 carries the horizontal velocity (tag 79 Sensor North Velocity, tag 80 Sensor
    East Velocity, +/-327 m/s) and no vertical one. Where a packet has both tags they give north
    and east; every other component is the central difference of the neighbouring packets'
    positions (ECEF, WGS 84) over their time stamps (tag 2), rotated into the packet's NED frame
    (one-sided at the ends and beside a gap). Two packets more than
    :data:`VELOCITY_MAX_GAP_S` apart, or with a time stamp that does not increase, are not
    differenced.

    Tag 13/14's quantisation (4.2e-8 deg, 5 mm) over a 1/30 s step is a 0.14 m/s velocity
    noise: times a time-tag error of milliseconds, sub-millimetre.

    Parameters
    ----------
    lat_deg, lon_deg, h_m, time_s : array_like (n,)
        The sensor's position (h ellipsoidal) and time stamp; NaN where a packet lacks one.
    north_m_s, east_m_s : array_like (n,), optional
        Tags 79 and 80 (NaN where absent).

    Returns
    -------
    (ndarray (n, 3), ndarray (n,) of str)
        The velocity (NaN rows where it cannot be known) and ``"tags 79, 80"``,
        ``"differenced"`` or ``""`` per packet.
    """
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef
    from geoloc.geodesy.local import R_ecef_ned

    lat = np.deg2rad(np.asarray(lat_deg, float))
    lon = np.deg2rad(np.asarray(lon_deg, float))
    h = np.asarray(h_m, float)
    t = np.asarray(time_s, float)
    n = lat.shape[0]
    X = np.asarray(geodetic_to_ecef(lat, lon, h), float).reshape(n, 3)
    good = np.isfinite(X).all(axis=1) & np.isfinite(t)
    idx = np.flatnonzero(good)
    v_ecef = np.full((n, 3), np.nan)
    if idx.size >= 2:
        dt = np.diff(t[idx])
        link = (dt > 0) & (dt <= VELOCITY_MAX_GAP_S)  # between idx[j] and idx[j + 1]
        prev_ok = np.r_[False, link]
        next_ok = np.r_[link, False]
        lo = np.where(prev_ok, np.r_[0, np.arange(idx.size - 1)], np.arange(idx.size))
        hi = np.where(next_ok, np.r_[np.arange(1, idx.size), idx.size - 1], np.arange(idx.size))
        a, b = idx[lo], idx[hi]
        span = t[b] - t[a]
        with np.errstate(invalid="ignore", divide="ignore"):
            v = (X[b] - X[a]) / span[:, None]
        v[span <= 0] = np.nan
        v_ecef[idx] = v
    R = np.asarray(R_ecef_ned(np.where(np.isfinite(lat), lat, 0.0), np.where(np.isfinite(lon), lon, 0.0)))
    v_ned = np.einsum("nji,nj->ni", R, v_ecef)  # R_ecef_ned maps NED to ECEF: its transpose back
    from_tags = np.zeros(n, bool)
    if north_m_s is not None and east_m_s is not None:
        vn, ve = np.asarray(north_m_s, float), np.asarray(east_m_s, float)
        from_tags = np.isfinite(vn) & np.isfinite(ve)
        v_ned[from_tags, 0] = vn[from_tags]
        v_ned[from_tags, 1] = ve[from_tags]
    known = np.isfinite(v_ned).all(axis=1)
    src = np.where(from_tags & known, "tags 79, 80", np.where(known, "differenced", ""))
    return v_ned, src.astype(object)


def _klv_uncertainty(sens, pose, surface, budget, ok, velocity_ned_m_s=None):
    """The frame centres' predicted uncertainty columns (NaN where a packet has no centre), and
    the messages to show.

    The packets' lens is made from their fields of view (a pinhole), so a budget's distortion keys
    (k1, ...) do not apply and are left out. A ``time_s`` term moves the platform by its velocity
    (:func:`platform_velocity_ned`); a packet whose velocity cannot be known gets no time term,
    and the messages count them."""
    from geoloc.analysis.uncertainty import propagate
    from geoloc.sensors.budget import LENS_KEYS, ErrorBudget

    messages = []
    keep = {k: v for k, v in budget.sigmas.items() if not (k in LENS_KEYS and LENS_KEYS[k] not in sens.lens.params)}
    vel = None
    if budget.sigma("time_s") > 0:
        known = np.isfinite(velocity_ned_m_s).all(axis=1) if velocity_ned_m_s is not None else np.zeros(len(ok), bool)
        if not known.any():
            keep.pop("time_s", None)
            messages.append(
                f"{budget.source}: [uncertainty] time_s = {budget.sigma('time_s'):g} s left out of the "
                "predicted uncertainty: no packet has a velocity (tags 79, 80, or a neighbour to "
                "difference)"
            )
        else:
            vel = np.where(known[:, None], velocity_ned_m_s, 0.0)
            if (~known & ok).any():
                messages.append(
                    f"{budget.source}: [uncertainty] time_s left out for {int(np.sum(~known & ok))} "
                    "packet(s) whose velocity cannot be known"
                )
    pu = propagate(
        sens,
        pose,
        None,
        None,
        ErrorBudget(keep, budget.dem_product, budget.source),
        surface=surface,
        velocity_ned_m_s=vel,
    )
    good = ok & (np.asarray(pu.status) == Status.OK)
    return {k: np.where(good, np.asarray(v, float), np.nan) for k, v in pu.columns().items()}, messages


@dataclass(frozen=True)
class _Heights:
    """Each packet's sensor and reported frame-centre positions [deg] and heights [m], every
    height ellipsoidal (WGS-84) and the tag it came from, NaN where the packet cannot say."""

    lat_s: np.ndarray
    lon_s: np.ndarray
    h75: np.ndarray  # tag 75, sensor height above the ellipsoid
    h15: np.ndarray  # tag 15, sensor height above mean sea level (EGM96)
    n_s: np.ndarray  # EGM96 N at the sensor
    from75: np.ndarray
    from15: np.ndarray
    h_s: np.ndarray  # sensor ellipsoidal height
    sensor_h_from: np.ndarray
    fc_lat: np.ndarray
    fc_lon: np.ndarray
    h78: np.ndarray  # tag 78, frame centre height above the ellipsoid
    h25: np.ndarray  # tag 25, frame centre elevation above mean sea level (EGM96)
    has_fc: np.ndarray
    n_fc: np.ndarray  # EGM96 N at the frame centre (at the sensor where the packet has no centre)
    from78: np.ndarray
    from25: np.ndarray
    rep_h: np.ndarray  # reported frame-centre ellipsoidal height
    rep_h_from: np.ndarray


def _packet_heights(g) -> _Heights:
    """The sensor's and the reported frame centre's heights, each made ellipsoidal: the HAE tag
    (75, 78) where present, else the MSL tag (15, 25) + EGM96 N."""
    lat_s, lon_s = g("sensor_latitude_deg"), g("sensor_longitude_deg")
    h75, h15 = g("sensor_ellipsoid_height_m"), g("sensor_true_altitude_m")
    n_s = _undulation(lat_s, lon_s)
    from75 = np.isfinite(h75)
    from15 = ~from75 & np.isfinite(h15) & np.isfinite(n_s)
    fc_lat, fc_lon = g("frame_center_latitude_deg"), g("frame_center_longitude_deg")
    h78, h25 = g("frame_center_hae_m"), g("frame_center_elevation_m")
    has_fc = np.isfinite(fc_lat) & np.isfinite(fc_lon)
    n_fc = _undulation(np.where(has_fc, fc_lat, lat_s), np.where(has_fc, fc_lon, lon_s))
    from78 = np.isfinite(h78)
    from25 = ~from78 & np.isfinite(h25) & np.isfinite(n_fc)
    return _Heights(
        lat_s=lat_s,
        lon_s=lon_s,
        h75=h75,
        h15=h15,
        n_s=n_s,
        from75=from75,
        from15=from15,
        h_s=np.where(from75, h75, np.where(from15, h15 + n_s, np.nan)),
        sensor_h_from=np.where(from75, "tag 75 (HAE)", np.where(from15, "tag 15 (MSL) + EGM96 N", "")),
        fc_lat=fc_lat,
        fc_lon=fc_lon,
        h78=h78,
        h25=h25,
        has_fc=has_fc,
        n_fc=n_fc,
        from78=from78,
        from25=from25,
        rep_h=np.where(from78, h78, np.where(from25, h25 + n_fc, np.nan)),
        rep_h_from=np.where(from78, "tag 78 (HAE)", np.where(from25, "tag 25 (MSL) + EGM96 N", "")),
    )


@dataclass(frozen=True)
class _Angles:
    """Each packet's attitude, turret angles and fields of view [deg], NaN where absent."""

    heading: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    az: np.ndarray
    el: np.ndarray
    sroll: np.ndarray
    hfov: np.ndarray
    vfov: np.ndarray
    hfov_ok: np.ndarray  # a field of view a lens can have: finite, in (0, 180)
    vfov_ok: np.ndarray


def _packet_angles(g) -> _Angles:
    """Attitude (the full-range pitch and roll, tags 90 and 91, where present, else tags 6 and 7),
    the turret's angles (tags 18-20) and the fields of view (tags 16, 17)."""
    p90, r91 = g("platform_pitch_full_deg"), g("platform_roll_full_deg")
    hfov, vfov = g("sensor_horizontal_fov_deg"), g("sensor_vertical_fov_deg")
    with np.errstate(invalid="ignore"):
        hfov_ok = np.isfinite(hfov) & (hfov > 0) & (hfov < 180)
        vfov_ok = np.isfinite(vfov) & (vfov > 0) & (vfov < 180)
    return _Angles(
        heading=g("platform_heading_deg"),
        pitch=np.where(np.isfinite(p90), p90, g("platform_pitch_deg")),
        roll=np.where(np.isfinite(r91), r91, g("platform_roll_deg")),
        az=g("sensor_relative_azimuth_deg"),
        el=g("sensor_relative_elevation_deg"),
        sroll=g("sensor_relative_roll_deg"),
        hfov=hfov,
        vfov=vfov,
        hfov_ok=hfov_ok,
        vfov_ok=vfov_ok,
    )


def _centre_needs(hts: _Heights, ang: _Angles, surface, centre_needs_roll: bool) -> list[tuple]:
    """What a packet needs to be located: per need, (where it lacks it, the tags in words, the
    items that may hold the reserved value instead of being absent)."""
    needs = [
        (~np.isfinite(hts.lat_s), _TAG_TEXT["sensor_latitude_deg"], ("sensor_latitude_deg",)),
        (~np.isfinite(hts.lon_s), _TAG_TEXT["sensor_longitude_deg"], ("sensor_longitude_deg",)),
        (~np.isfinite(hts.h_s), "tag 75 (Sensor Ellipsoid Height) or tag 15 (Sensor True Altitude)", ()),
        (~np.isfinite(ang.heading), _TAG_TEXT["platform_heading_deg"], ()),
        (
            ~np.isfinite(ang.pitch),
            "tag 90 or tag 6 (Platform Pitch Angle)",
            ("platform_pitch_full_deg", "platform_pitch_deg"),
        ),
        (
            ~np.isfinite(ang.roll),
            "tag 91 or tag 7 (Platform Roll Angle)",
            ("platform_roll_full_deg", "platform_roll_deg"),
        ),
        (~np.isfinite(ang.az), _TAG_TEXT["sensor_relative_azimuth_deg"], ()),
        (~np.isfinite(ang.el), _TAG_TEXT["sensor_relative_elevation_deg"], ("sensor_relative_elevation_deg",)),
    ]
    if surface is None:
        needs.append(
            (
                ~np.isfinite(hts.rep_h),
                "tag 78 (Frame Center Height Above Ellipsoid) or tag 25 "
                "(Frame Center Elevation), the height to intersect at (or give a DEM)",
                (),
            )
        )
    if centre_needs_roll:
        needs.append((~np.isfinite(ang.sroll), _TAG_TEXT["sensor_relative_roll_deg"], ()))
    return needs


def _corner_needs(ang: _Angles, centre_needs_roll: bool) -> list[tuple]:
    """What a located packet needs beyond that to have its corners: (where it lacks it, the tags)."""
    needs = [
        (~ang.hfov_ok, "tag 16 (Sensor Horizontal Field of View; absent, 0 or 180)"),
        (~ang.vfov_ok, "tag 17 (Sensor Vertical Field of View; absent, 0 or 180)"),
    ]
    if not centre_needs_roll:
        needs.append((~np.isfinite(ang.sroll), _TAG_TEXT["sensor_relative_roll_deg"]))
    return needs


def _holds_reserved(reserved, names: tuple) -> np.ndarray:
    """Per packet, whether it holds any of the items ``names`` at the reserved value."""
    return np.fromiter((any(x in t for x in names) for t in reserved), bool, len(reserved))


def _lacks_text(absent: str, reserved: str) -> str:
    """'missing tag ..., tag ...; tag ... holds a reserved value (no value)' from the two lists
    (each "tag ..., tag ..., ", ending in a comma and a space; either may be empty)."""
    parts = (("missing " + absent[:-2]) if absent else "", (reserved[:-2] + " " + _RESERVED_NOTE) if reserved else "")
    return "; ".join(t for t in parts if t)


def _missing_tags(
    hts: _Heights, ang: _Angles, surface, base_sensor, reserved=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """What each packet lacks to be located (``bad_c``) and, beyond that, to have its corners
    (``bad_k``); the note naming the tags per packet, and the count of each reason.

    Without a surface the packet's own frame-centre height is where its rays end, so it is
    needed; with a boresight the centre's ray turns with the sensor roll, so the roll is needed
    for the centre, else only for the corners. ``reserved`` (per packet, the names of the items
    it holds at the standard's reserved value, 0x80000000, "error"): a writer that has no value
    may still send the item, and such an item is named as that, not as missing."""
    n = len(hts.lat_s)
    if reserved is None:
        reserved = np.empty(n, object)
        reserved[:] = [()] * n
    centre_needs_roll = base_sensor is not None and any(getattr(base_sensor, "boresight", ()))
    notes = np.full(n, "", dtype=object)
    bad_c = np.zeros(n, bool)
    rnotes = np.full(n, "", dtype=object)
    for mask, text, items in _centre_needs(hts, ang, surface, centre_needs_roll):
        bad_c |= mask
        r = mask & _holds_reserved(reserved, items) if items else np.zeros(n, bool)
        _append(notes, mask & ~r, f"{text}, ")
        _append(rnotes, r, f"{text}, ")
    centre_notes = [_lacks_text(a, r) for a, r in zip(notes.tolist(), rnotes.tolist())]
    invalid_reasons = dict(Counter(centre_notes[i] for i in np.flatnonzero(bad_c)).most_common())
    knotes = np.full(n, "", dtype=object)
    bad_k = bad_c.copy()
    for mask, text in _corner_needs(ang, centre_needs_roll):
        bad_k |= mask
        _append(knotes, mask & ~bad_c, f"{text}, ")
    notes = np.array(
        [
            a + ("; " if a and b else "") + ("corners not computed: missing " + b[:-2] if b else "")
            for a, b in zip(centre_notes, knotes.tolist())
        ]
        + [None],
        dtype=object,
    )[:-1]
    return bad_c, bad_k, notes, invalid_reasons


def _clean(v, bad, fill=0.0):
    """``v`` with ``fill`` where a packet is bad or the value is not finite (such a packet's row is
    marked invalid; the fill only keeps the batch's arithmetic finite)."""
    return np.where(bad | ~np.isfinite(v), fill, v)


@dataclass(frozen=True)
class _Geometry:
    """The batch's one sensor, the poses of the centres and of the corners, and each packet's
    four corner pixels (upper left, upper right, lower right, lower left; shape (4, n))."""

    sensor: FrameSensor
    pose_c: Pose
    pose_k: Pose
    k_rows: np.ndarray
    k_cols: np.ndarray


def _replay_geometry(hts: _Heights, ang: _Angles, bad_c, bad_k, base_sensor) -> _Geometry:
    """One sensor for every packet, its lens from the median fields of view; packet i's corners
    are the pixels of that lens whose rays are those of packet i's own lens's corners (for a
    pinhole: offsets from the centre scaled by tan(fov_i / 2) / tan(fov_ref / 2), exact)."""
    hv = ang.hfov_ok & ang.vfov_ok
    href = float(np.median(ang.hfov[hv])) if hv.any() else 10.0
    vref = float(np.median(ang.vfov[hv])) if hv.any() else 10.0
    sens = klv_sensor(math.radians(href), math.radians(vref), base_sensor)
    pose_c = Pose.from_deg(
        _clean(hts.lat_s, bad_c),
        _clean(hts.lon_s, bad_c),
        _clean(hts.h_s, bad_c, 1000.0),
        _clean(ang.heading, bad_c),
        _clean(ang.pitch, bad_c),
        _clean(ang.roll, bad_c),
        angles_deg={
            "azimuth": _clean(ang.az, bad_c),
            "elevation": _clean(ang.el, bad_c, -45.0),
            "sensor_roll": _clean(ang.sroll, bad_c),
        },
    )
    r0, c0 = sens.center_pixel
    with np.errstate(invalid="ignore"):
        sx = np.tan(np.deg2rad(_clean(ang.hfov, bad_k, href)) / 2) / math.tan(math.radians(href) / 2) * sens.cols / 2
        sy = np.tan(np.deg2rad(_clean(ang.vfov, bad_k, vref)) / 2) / math.tan(math.radians(vref) / 2) * sens.rows / 2
    return _Geometry(
        sensor=sens,
        pose_c=pose_c,
        pose_k=pose_c.with_angles(sensor_roll=np.deg2rad(_clean(ang.sroll, bad_k))),
        k_rows=np.stack([r0 - sy, r0 - sy, r0 + sy, r0 + sy]),
        k_cols=np.stack([c0 - sx, c0 + sx, c0 + sx, c0 - sx]),
    )


def _surface_text(surface, terrain) -> str:
    """What the rays were intersected with, in words, for the summary."""
    if surface is None:
        return (
            "each packet's own frame-centre height, ellipsoidal (tag 78 HAE; tag 25 MSL + EGM96 N "
            "where 78 is absent): the comparison isolates the angles"
        )
    if terrain is not None:
        src = getattr(terrain, "path", None) or "DEM"
        return (
            f"DEM {src} (heights {terrain.datum}"
            + (" -> ellipsoidal with EGM96 N" if terrain.datum == "egm96" else "")
            + f"), method {surface.method}"
        )
    return repr(surface)


def _intersect_packets(geo: _Geometry, surface, h_int, corrections: Corrections):
    """The frame centres' and the corners' ground points: one batch call each. Without a surface
    each packet's rays end at its own ellipsoidal height ``h_int``. Corner pixels may lie beyond
    the reference sensor's edge: extrapolated, which for a pinhole is exact."""
    if surface is None:
        gc = locate(geo.pose_c, geo.sensor, target_h=h_int, height_kind="geodetic", corrections=corrections)
        gk = locate(
            geo.pose_k,
            geo.sensor,
            geo.k_rows,
            geo.k_cols,
            target_h=h_int[None, :],
            height_kind="geodetic",
            outside="extrapolate",
            corrections=corrections,
        )
        return gc, gk
    pipe = Pipeline(geo.sensor, surface, corrections)
    gc = pipe.intersect(line_of_sight(geo.pose_c, geo.sensor))
    gk = pipe.intersect(line_of_sight(geo.pose_k, geo.sensor, geo.k_rows, geo.k_cols, outside="extrapolate"))
    return gc, gk


def _corner_status(kst) -> np.ndarray:
    """One status per packet from its four corners' (shape (4, n)): the first failed corner's."""
    out = np.zeros(kst.shape[1], np.uint8)
    for j in (3, 2, 1, 0):
        out = np.where(kst[j] != Status.OK, kst[j], out)
    return out


def _reported_corners(g, hts: _Heights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The packets' own corners [deg] (shape (4, n)): the full corners (tags 82-89) where both
    items are there, else the offsets (tags 26-33) added to the frame centre; and where they came
    from per packet."""
    n = len(hts.lat_s)
    rk_lat, rk_lon = np.full((4, n), np.nan), np.full((4, n), np.nan)
    n_full = np.zeros(n, int)
    n_off = np.zeros(n, int)
    for j in range(4):
        fl, fo = g(f"corner_latitude_{j + 1}_deg"), g(f"corner_longitude_{j + 1}_deg")
        ol, oo = g(f"offset_corner_latitude_{j + 1}_deg"), g(f"offset_corner_longitude_{j + 1}_deg")
        full = np.isfinite(fl) & np.isfinite(fo)
        off = ~full & np.isfinite(ol) & np.isfinite(oo) & hts.has_fc
        rk_lat[j] = np.where(full, fl, np.where(off, hts.fc_lat + ol, np.nan))
        rk_lon[j] = np.where(full, fo, np.where(off, hts.fc_lon + oo, np.nan))
        n_full += full
        n_off += off
    rep_corners = np.full(n, "", dtype=object)
    rep_corners[n_full == 4] = "tags 82-89 (full)"
    rep_corners[n_off == 4] = "tags 26-33 (offsets from the frame centre)"
    rep_corners[(n_full + n_off > 0) & (n_full != 4) & (n_off != 4)] = "partial"
    return rk_lat, rk_lon, rep_corners


def _datum_warnings(read: KlvRead, hts: _Heights) -> tuple[np.ndarray, list[str]]:
    """Where a packet carries both heights, HAE - MSL must be EGM96 N (within ``DATUM_CHECK_M``):
    the per-packet warning column, and the summary's lines (packet and byte offset)."""
    datum_warn = np.full(len(hts.lat_s), "", dtype=object)
    warnings = []
    with np.errstate(invalid="ignore"):
        dev_s = np.abs((hts.h75 - hts.h15) - hts.n_s) > DATUM_CHECK_M
        dev_f = np.abs((hts.h78 - hts.h25) - hts.n_fc) > DATUM_CHECK_M
    for k in np.flatnonzero(dev_s | dev_f):
        parts = []
        if dev_s[k]:
            parts.append(
                f"tag 75 - tag 15 = {hts.h75[k] - hts.h15[k]:+.1f} m but EGM96 N = {hts.n_s[k]:+.1f} m at the sensor"
            )
        if dev_f[k]:
            parts.append(
                f"tag 78 - tag 25 = {hts.h78[k] - hts.h25[k]:+.1f} m but EGM96 N = {hts.n_fc[k]:+.1f} m "
                "at the frame centre"
            )
        datum_warn[k] = "; ".join(parts)
        warnings.append(f"packet {int(read.packet[k])} (byte {int(read.columns['offset'][k])}): {datum_warn[k]}")
    return datum_warn, warnings


def _uncertainty_columns(g, budget, geo: _Geometry, unc_surface, ok, hts: _Heights, time_s) -> tuple[dict, list[str]]:
    """The predicted uncertainty columns beside the packet's own target error estimates (tags 45,
    46), the platform's velocity where a ``time_s`` term needs it, and the messages to show."""
    cols = {"reported_ce90_m": g("target_error_ce90_m"), "reported_le90_m": g("target_error_le90_m")}
    vel = None
    if budget.sigma("time_s") > 0:
        vel, vel_from = platform_velocity_ned(
            hts.lat_s, hts.lon_s, hts.h_s, time_s, g("sensor_north_velocity_m_s"), g("sensor_east_velocity_m_s")
        )
    ucols, messages = _klv_uncertainty(geo.sensor, geo.pose_c, unc_surface, budget, ok, vel)
    cols.update(ucols)
    if vel is not None:
        for j, axis in enumerate(("north", "east", "down")):
            cols[f"velocity_{axis}_m_s"] = vel[:, j]
        cols["velocity_from"] = vel_from
        used = ok & (vel_from != "")
        messages.append(
            f"time_s = {budget.sigma('time_s'):g} s propagated with the platform's velocity: "
            f"tags 79, 80 for {int(np.sum(used & (vel_from == 'tags 79, 80')))} packet(s), "
            f"differenced positions for {int(np.sum(used & (vel_from == 'differenced')))} "
            "(column velocity_from)"
        )
    return cols, messages


def _dem_height_note(hts: _Heights, h) -> str | None:
    """The reported frame-centre heights against the DEM's: the median difference, and a hint
    when it is about -N (reported heights orthometric where they should be ellipsoidal)."""
    dh = hts.rep_h - h
    okh = np.isfinite(dh)
    if not okh.any():
        return None
    mdh = float(np.median(dh[okh]))
    mn = float(np.nanmedian(hts.n_fc[okh])) if np.isfinite(hts.n_fc[okh]).any() else math.nan
    text = f"reported frame-centre height minus the DEM's: median {mdh:+.2f} m"
    if abs(mdh) > 5 and math.isfinite(mn) and abs(mdh + mn) < DATUM_CHECK_M:
        text += (
            f", about -N ({-mn:+.1f} m): the reported heights look orthometric (MSL) where "
            "they should be ellipsoidal, or the DEM's datum is wrong (--dem-datum)"
        )
    return text


@dataclass(frozen=True)
class _GroundPoints:
    """The batch's ground points in degrees and metres, NaN where a packet has none: the frame
    centres' (shape (n,)) and the corners' (shape (4, n)), each with its status (a packet missing
    a tag is ``INVALID_INPUT`` whatever the intersection said)."""

    status: np.ndarray
    ok: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    range_m: np.ndarray
    refraction_m: np.ndarray
    k_status: np.ndarray
    k_lat: np.ndarray
    k_lon: np.ndarray
    k_h: np.ndarray


def _ground_points(gc, gk, bad_c, bad_k) -> _GroundPoints:
    """The intersections ``gc`` (centres) and ``gk`` (corners) as :class:`_GroundPoints`: radians
    to degrees, NaN where the status is not OK, ``INVALID_INPUT`` where ``bad_c`` / ``bad_k``."""
    status = np.where(bad_c, np.uint8(Status.INVALID_INPUT), np.asarray(gc.status, np.uint8)).astype(np.uint8)
    ok = status == Status.OK
    kst = np.where(bad_k[None, :], np.uint8(Status.INVALID_INPUT), np.asarray(gk.status, np.uint8))
    kok = kst == Status.OK
    return _GroundPoints(
        status=status,
        ok=ok,
        lat=np.where(ok, np.rad2deg(gc.lat), np.nan),
        lon=np.where(ok, np.rad2deg(gc.lon), np.nan),
        h=np.where(ok, gc.h, np.nan),
        range_m=np.where(ok, gc.slant_range, np.nan),
        refraction_m=np.where(ok, np.asarray(gc.refraction_m, float), np.nan),
        k_status=kst,
        k_lat=np.where(kok, np.rad2deg(gk.lat), np.nan),
        k_lon=np.where(kok, np.rad2deg(gk.lon), np.nan),
        k_h=np.where(kok, gk.h, np.nan),
    )


def _mean_corner_error(pts: _GroundPoints, rk_lat, rk_lon) -> np.ndarray:
    """Per packet, the mean horizontal distance [m] from its computed corners to its reported
    ones (``rk_lat``, ``rk_lon`` [deg], shape (4, n)) over the corners both have; NaN where none."""
    k_err = horizontal_distance_m(pts.k_lat, pts.k_lon, rk_lat, rk_lon)
    k_cnt = np.isfinite(k_err).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(k_cnt > 0, np.nansum(k_err, axis=0) / np.maximum(k_cnt, 1), np.nan)


def _point_columns(pts: _GroundPoints, fc_err, corrections: Corrections) -> dict:
    """The recomputed frame centre's columns and the four corners', in the CSV's order."""
    cols = {
        "lat_deg": pts.lat,
        "lon_deg": pts.lon,
        "mgrs": np.array(mgrs_column(pts.lat, pts.lon), dtype=object),  # '' where no point (io.mgrs_grid)
        "h_m": pts.h,
        "status": pts.status,
        "range_m": pts.range_m,
        "frame_center_error_m": fc_err,
        "corrections": np.full(len(pts.lat), corrections.label, dtype=object),
        "refraction_m": pts.refraction_m,
    }
    for j in range(4):
        cols[f"corner{j + 1}_lat_deg"] = pts.k_lat[j]
        cols[f"corner{j + 1}_lon_deg"] = pts.k_lon[j]
        cols[f"corner{j + 1}_h_m"] = pts.k_h[j]
    return cols


def _summary_notes(base_sensor, sens: FrameSensor, terrain, hts: _Heights, h, fc_err) -> list[str]:
    """The summary's notes on the sensor file used and, with a DEM, the reported heights against it."""
    out = []
    if base_sensor is not None:
        out.append(
            f"sensor file: image {sens.cols} x {sens.rows}, mount, boresight and lever arm "
            "used; its lens is replaced by each packet's fields of view (tags 16, 17)"
        )
    if terrain is not None and np.isfinite(fc_err).any():
        note = _dem_height_note(hts, h)
        if note is not None:
            out.append(note)
    return out


def _replay(read: KlvRead, surface, base_sensor, budget=None, corrections: Corrections = NO_CORRECTIONS) -> KlvReplay:
    """Every packet of ``read`` located on ``surface`` (None: its own frame-centre height) and
    compared with its reported frame centre and corners; the steps are the functions above."""
    terrain = terrain_of(surface)
    n = len(read)
    g = lambda name: _f(read.columns, name, n)  # noqa: E731

    hts = _packet_heights(g)
    ang = _packet_angles(g)
    bad_c, bad_k, notes, invalid_reasons = _missing_tags(hts, ang, surface, base_sensor, read.columns.get("reserved"))
    geo = _replay_geometry(hts, ang, bad_c, bad_k, base_sensor)
    h_int = _clean(hts.rep_h, bad_c)
    gc, gk = _intersect_packets(geo, surface, h_int, corrections)
    pts = _ground_points(gc, gk, bad_c, bad_k)
    rk_lat, rk_lon, rep_corners = _reported_corners(g, hts)

    fc_err = horizontal_distance_m(pts.lat, pts.lon, hts.fc_lat, hts.fc_lon)
    corner_err = _mean_corner_error(pts, rk_lat, rk_lon)
    outlier, med, _mad, thr = outlier_mask(fc_err)
    datum_warn, warnings = _datum_warnings(read, hts)
    plaus = _drone_height_warnings(read, base_sensor, terrain, hts, pts.h)

    ts = g("precision_time_stamp_us")
    cols = _packet_columns(read, g, hts, ang, ts, rk_lat, rk_lon, rep_corners)
    cols.update(_point_columns(pts, fc_err, corrections))
    unc_messages: list[str] = []
    if budget is not None:
        unc_surface = HeightSurface(h_int, "geodetic") if surface is None else surface
        ucols, unc_messages = _uncertainty_columns(g, budget, geo, unc_surface, pts.ok, hts, ts / 1e6)
        cols.update(ucols)
    cols.update(
        {
            "corner_status": _corner_status(pts.k_status),
            "corner_error_m": corner_err,
            "h_datum": np.full(n, H_DATUM, dtype=object),
            "outlier": outlier.astype(np.int64),
            "datum_warning": datum_warn,
            "note": notes,
        }
    )
    summary = _summary(
        read,
        hts,
        pts.status,
        fc_err,
        corner_err,
        outlier,
        med,
        thr,
        invalid_reasons,
        _surface_text(surface, terrain),
        warnings,
        unc_messages + _summary_notes(base_sensor, geo.sensor, terrain, hts, pts.h, fc_err),
        plaus,
    )
    return KlvReplay(cols, list(read.errors), summary, geo.sensor)


def _packet_columns(
    read: KlvRead,
    g: Callable[[str], np.ndarray],
    hts: _Heights,
    ang: _Angles,
    ts: np.ndarray,
    rk_lat: np.ndarray,
    rk_lon: np.ndarray,
    rep_corners: np.ndarray,
) -> dict[str, Any]:
    """The replay's columns that echo each packet as read: where it is in the file, its time, the
    platform's position, heights and attitude, the turret's angles and fields of view, the reported
    frame centre and corners (``g(name)``: a decoded column as floats, NaN where absent)."""
    c = read.columns
    n = len(read)
    cols = {
        "file": np.full(n, Path(read.source).name, dtype=object),
        "packet": np.asarray(read.packet, np.int64),
        "offset": np.asarray(c["offset"], np.int64),
        "pts_s": np.asarray(read.pts_s, float),
        "time_utc": _iso(ts),
        "time_s": ts / 1e6,
        "sensor_lat_deg": hts.lat_s,
        "sensor_lon_deg": hts.lon_s,
        "sensor_h_m": hts.h_s,
        "sensor_h_from": hts.sensor_h_from.astype(object),
        "sensor_ellipsoid_height_m": hts.h75,
        "sensor_true_altitude_msl_m": hts.h15,
        "sensor_geoid_n_m": hts.n_s,
        "platform_heading_deg": ang.heading,
        "platform_pitch_deg": ang.pitch,
        "platform_roll_deg": ang.roll,
        "sensor_relative_azimuth_deg": ang.az,
        "sensor_relative_elevation_deg": ang.el,
        "sensor_relative_roll_deg": ang.sroll,
        "sensor_horizontal_fov_deg": ang.hfov,
        "sensor_vertical_fov_deg": ang.vfov,
        "slant_range_m": g("slant_range_m"),
        "frame_center_hae_m": hts.h78,
        "frame_center_elevation_msl_m": hts.h25,
        "reported_lat_deg": hts.fc_lat,
        "reported_lon_deg": hts.fc_lon,
        "reported_h_m": hts.rep_h,
        "reported_h_from": hts.rep_h_from.astype(object),
    }
    for j in range(4):
        cols[f"reported_corner{j + 1}_lat_deg"] = rk_lat[j]
        cols[f"reported_corner{j + 1}_lon_deg"] = rk_lon[j]
    cols["reported_corners_from"] = rep_corners
    return cols


def _summary(
    read: KlvRead,
    hts: _Heights,
    status: np.ndarray,
    fc_err: np.ndarray,
    corner_err: np.ndarray,
    outlier: np.ndarray,
    outlier_median_m: float,
    outlier_threshold_m: float,
    invalid_reasons: dict,
    surface_text: str,
    datum_warnings: list,
    notes: list[str],
    plausibility_warnings: list,
) -> KlvSummary:
    """The replay's summary: packets per status, the frame-centre and corner errors' figures over
    the packets compared (NaN where none), the outliers, where the heights came from."""
    fin = np.isfinite(fc_err)
    kfin = np.isfinite(corner_err)
    return KlvSummary(
        source=read.source,
        packets=len(read),
        errors=list(read.errors),
        status_counts={s.name.lower(): int(np.sum(status == s)) for s in Status if np.any(status == s)},
        invalid_reasons=invalid_reasons,
        compared=int(fin.sum()),
        median_m=float(np.median(fc_err[fin])) if fin.any() else math.nan,
        p90_m=float(np.percentile(fc_err[fin], 90)) if fin.any() else math.nan,
        max_m=float(np.max(fc_err[fin])) if fin.any() else math.nan,
        corner_compared=int(kfin.sum()),
        corner_median_m=float(np.median(corner_err[kfin])) if kfin.any() else math.nan,
        corner_p90_m=float(np.percentile(corner_err[kfin], 90)) if kfin.any() else math.nan,
        outliers=read.packet[outlier].tolist(),
        outlier_median_m=outlier_median_m,
        outlier_threshold_m=outlier_threshold_m,
        sensor_h_sources={"tag 75 (HAE)": int(hts.from75.sum()), "tag 15 (MSL) + EGM96 N": int(hts.from15.sum())},
        reported_h_sources={"tag 78 (HAE)": int(hts.from78.sum()), "tag 25 (MSL) + EGM96 N": int(hts.from25.sum())},
        surface=surface_text,
        datum_warnings=datum_warnings,
        notes=notes,
        plausibility_warnings=plausibility_warnings,
        quirks=list(read.quirks),
        time_back=list(read.time_back),
    )


def _drone_height_warnings(read: KlvRead, base_sensor, terrain, hts: _Heights, h) -> list:
    """One line per packet of a drone whose sensor is too high for a drone (a feet or datum mix-up
    is still located as ok); ``h`` the located points' heights.

    A packet is a drone's when its Platform Designation (tag 10) names one, or, without a
    designation, when the sensor file's ``platform`` does (:func:`geoloc.sensors.platform.is_drone`).
    Too high: more than DRONE_MAX_HEIGHT_M above the terrain under the sensor (a DEM), else
    above the reported frame centre (tags 78 / 25), else above the located point; or above
    DRONE_CEILING_M. The rule and its numbers: docs/records.md, "Plausibility checks"."""
    from geoloc.sensors.platform import drone_height_hint, drone_height_where, drone_too_high, is_drone

    c, n = read.columns, len(read)
    h_s, h75, h15, rep_h = hts.h_s, hts.h75, hts.h15, hts.rep_h
    desig = c.get("platform_designation")
    desig = [None] * n if desig is None else list(desig)
    default = is_drone(getattr(base_sensor, "platform", ""))
    drone = np.array([is_drone(d) if d else default for d in desig], dtype=bool)
    if not drone.any():
        return []
    ref = np.where(np.isfinite(rep_h), rep_h, h)
    what = np.where(
        np.isfinite(rep_h),
        np.where(hts.from78, "the frame centre (tag 78)", "the frame centre (tag 25)"),
        "the located point",
    ).astype(object)
    if terrain is not None:
        ground, _ = terrain.sample(np.deg2rad(hts.lat_s), np.deg2rad(hts.lon_s))
    else:
        ground = None
    high, ref, what = drone_too_high(h_s, ref, ground, what, "the terrain under it (the DEM)")
    high &= drone
    out = []
    for k in np.flatnonzero(high):
        tag, value = (
            ("tag 75 (Sensor Ellipsoid Height)", h75[k])
            if hts.from75[k]
            else ("tag 15 (Sensor True Altitude, MSL)", h15[k])
        )
        known = np.isfinite(ref[k])
        where = drone_height_where(h_s[k], ref[k], what[k])
        said = f"Platform Designation {desig[k]!r}" if desig[k] else "the sensor file's platform"
        hint = drone_height_hint(value, ref[k] - (h_s[k] - value) if known else None)
        out.append(
            f"packet {int(read.packet[k])} (byte {int(c['offset'][k])}): {tag} = {value:.1f} m: a drone's "
            f"camera ({said}) {where}: {hint}"
        )
    return out


# --------------------------------------------------------------------------- writing


def _fmt_of(name: str) -> str:
    if name.endswith(("lat_deg", "lon_deg")):
        return "%.9f"
    if name.endswith("_error_m"):
        return "%.4f"
    if name.endswith("_deg"):
        return "%.7f"
    if name in ("time_s", "pts_s", "frame_pts_s"):
        return "%.6f"
    return "%.3f"


def _column_text(name, arr) -> list:
    if name in ("status", "corner_status"):
        return list(names(arr))
    a = np.asarray(arr)
    if a.dtype == object:
        return ["" if v is None else str(v) for v in a.tolist()]
    if a.dtype.kind in "iub":
        return [str(v) for v in a.tolist()]
    fmt = _fmt_of(name)
    out = [fmt % v for v in a.tolist()]
    for k in np.flatnonzero(~np.isfinite(a)).tolist():
        out[k] = ""
    return out


def write_klv_csv(path: str | os.PathLike[str], replays: KlvReplay | Iterable[KlvReplay]) -> int:
    """Write the rows of one or more replays (the same columns) to one CSV; returns the row count."""
    replays = [replays] if isinstance(replays, KlvReplay) else list(replays)
    if not replays:
        raise ValueError("no replay to write")
    header = list(replays[0].columns)
    n = 0
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for r in replays:
            texts = [_column_text(k, r.columns[k]) for k in header]
            w.writerows(zip(*texts))
            n += len(r)
    return n
