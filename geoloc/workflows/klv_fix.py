"""MISB ST 0601 KLV written back: a copy of a stream with the recomputed frame centre and corners.

``fix_klv(IN, OUT)`` replays every packet (:func:`geoloc.workflows.klv_replay.replay_klv`,
on a DEM and with a calibrated sensor file when given) and writes a copy of the
input whose frame-centre and corner items hold geoloc's answer:

* 23, 24 (frame centre latitude, longitude) and 78 (its height above the
  ellipsoid) from the recomputed centre; 25 (frame centre elevation, MSL) as
  that height minus the EGM96 undulation at the new centre (h = H + N);
* 82-89 (full corners) from the recomputed corners; 26-33 (offset corners) as
  the corners minus the new centre (an offset beyond the item's +-0.075 deg is
  written as its reserved "error" value, and said);
* with an error budget (the sensor file's ``[uncertainty]`` table), 45 and 46
  (Target Error Estimate CE90 / LE90) from the predicted uncertainty of the
  recomputed centre (:func:`geoloc.analysis.uncertainty.propagate`: CE90 of its
  ellipse, LE90), added before the checksum to a packet that has neither;
* the checksum (tag 1) recomputed.

Only items the packet already has are rewritten, each in place (same length:
every byte of the key, the BER length and the other items stays as it was),
except tags 45 and 46, which a budget adds where the packet has none (the BER
length then grows; every other item stays as it was).
A packet the replay could not locate (a missing tag, a ray to the sky) or a
bad packet (checksum mismatch, truncated) is copied unchanged and reported.
Raw ``.klv`` / ``.bin``: the bytes between packets are copied too. MPEG-TS
(or any container PyAV remuxes): every packet of every other stream (video,
audio, other data) is copied as it is with its time stamps (a remux, no
re-encode); the KLV stream's packets are replaced one for one.

The output is written through :func:`geoloc.userfiles.atomic_path` (a temporary
file in the output's folder, renamed into place); it may not be the input. See ``docs/klv.md``, "Writing corrected
metadata back".
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from geoloc.extras import require
from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.klv import (
    TAG_BY_NAME,
    UAS_LS_KEY,
    KlvError,
    _klv_stream,
    add_items,
    encode_value,
    is_container_file,
    iter_packets,
    local_set_items,
    replace_values,
)
from geoloc.pipeline import NO_CORRECTIONS, Corrections
from geoloc.status import Status, describe
from geoloc.userfiles import atomic_path, note_input
from geoloc.workflows.klv_replay import CONTAINER_SUFFIXES, KlvReplay, _ranges, read_klv, replay_klv

if TYPE_CHECKING:
    from geoloc.sensors.budget import ErrorBudget
    from geoloc.sensors.frame import FrameSensor
    from geoloc.surfaces.base import Surface

#: The items rewritten: tag -> field name.
CENTRE_TAGS = {
    23: "frame_center_latitude_deg",
    24: "frame_center_longitude_deg",
    25: "frame_center_elevation_m",
    78: "frame_center_hae_m",
}
OFFSET_CORNER_TAGS = {
    26 + 2 * j + a: f"offset_corner_{'latitude' if a == 0 else 'longitude'}_{j + 1}_deg"
    for j in range(4)
    for a in (0, 1)
}
FULL_CORNER_TAGS = {
    82 + 2 * j + a: f"corner_{'latitude' if a == 0 else 'longitude'}_{j + 1}_deg" for j in range(4) for a in (0, 1)
}
#: Target Error Estimate CE90 / LE90 (MISB ST 0601 tags 45, 46): the replay's predicted column for each.
ERROR_TAGS = {45: ("target_error_ce90_m", "ce90_m"), 46: ("target_error_le90_m", "le90_m")}


@dataclass
class KlvFix:
    """What :func:`fix_klv` wrote."""

    source: str
    out: str
    packets: int = 0  # good packets read
    rewritten: int = 0  # packets with at least one item rewritten
    unchanged: list = field(default_factory=list)  # (packet number, reason) of good packets left as they were
    bad: list = field(default_factory=list)  # KlvError of bad packets, copied unchanged
    items: dict = field(default_factory=dict)  # tag -> number of items rewritten
    notes: list = field(default_factory=list)  # (packet number, text): items not rewritten in a rewritten packet
    other_packets: int = 0  # container: packets of other streams copied
    correction_m: np.ndarray | None = None  # per good packet: the frame-centre correction (replay error) [m]
    budget_source: str = ""  # the [uncertainty] budget's file when tags 45 / 46 were written
    added: dict = field(default_factory=dict)  # tag -> number of items added (packets without it)

    def __str__(self) -> str:
        lines = [
            f"{self.source}: {self.packets} packets read, {self.rewritten} rewritten, "
            f"{len(self.unchanged)} left unchanged, {len(self.bad)} bad packet(s) copied as they were"
        ]
        if self.items:
            lines.append("  items rewritten: " + ", ".join(f"tag {t}: {n}" for t, n in sorted(self.items.items())))
        if self.budget_source:
            n45, n46 = self.items.get(45, 0), self.items.get(46, 0)
            add = ", ".join(f"tag {t} added to {n}" for t, n in sorted(self.added.items()) if n)
            lines.append(
                f"  target error estimate: tags 45 / 46 hold the predicted CE90 / LE90 of the "
                f"[uncertainty] budget of {self.budget_source} ({n45} / {n46} packets"
                + (f"; {add} packet(s) that had none" if add else "")
                + ")"
            )
        c = self.correction_m
        if c is not None and np.isfinite(c).any():
            f = c[np.isfinite(c)]
            lines.append(f"  frame-centre correction: median {np.median(f):.3f} m, max {f.max():.3f} m")
        # one line per reason, not per packet: a writer that never sends an angle leaves every
        # packet of a long flight unchanged for the same reason
        by_why: dict = {}
        for k, why in self.unchanged:
            by_why.setdefault(why, []).append(k)
        for why, ks in list(by_why.items())[:20]:
            head = f"packet {ks[0]}" if len(ks) == 1 else f"{_ranges(ks)} ({len(ks)})"
            lines.append(f"  {head}: unchanged: {why}")
        if len(by_why) > 20:
            rest = sum(len(ks) for ks in list(by_why.values())[20:])
            lines.append(f"  ... {rest} more unchanged, for {len(by_why) - 20} other reasons")
        for e in self.bad:
            lines.append(f"  bad packet copied unchanged: {e}")
        for k, text in self.notes[:20]:
            lines.append(f"  packet {k}: {text}")
        if self.other_packets:
            lines.append(f"  {self.other_packets} packets of the other streams copied as they were")
        lines.append(f"  wrote {self.out}")
        return "\n".join(lines)


def _wrap(d):
    return (d + 180.0) % 360.0 - 180.0


def _new_values(r: KlvReplay, k: int, tags: set, notes: list, errors: bool = False) -> dict:
    """Tag -> value bytes for row k of the replay, for the tags the packet has (and, with
    ``errors``, tags 45 / 46 whether it has them or not)."""
    c = r.columns
    out = {}

    def put(tag, name, value, what):
        try:
            out[tag] = encode_value(name, value)
        except ValueError as e:
            notes.append(f"tag {tag} ({what}) not rewritten: {e}")

    if int(c["status"][k]) == Status.OK:
        lat, lon, h = float(c["lat_deg"][k]), float(c["lon_deg"][k]), float(c["h_m"][k])
        if 23 in tags:
            put(23, CENTRE_TAGS[23], lat, "frame centre latitude")
        if 24 in tags:
            put(24, CENTRE_TAGS[24], lon, "frame centre longitude")
        if 78 in tags:
            put(78, CENTRE_TAGS[78], h, "frame centre HAE")
        if 25 in tags:
            n = float(egm96_undulation(math.radians(lat), math.radians(lon)))
            put(25, CENTRE_TAGS[25], h - n, "frame centre elevation, MSL")
        if errors:
            for t, (name, col) in ERROR_TAGS.items():
                v = float(c[col][k])
                if not math.isfinite(v):
                    notes.append(f"tag {t}: no predicted {col[:-2].upper()} for this centre: left as it was")
                elif v > TAG_BY_NAME[name].hi:  # 0..4095 m
                    notes.append(
                        f"tag {t}: predicted {col[:-2].upper()} {v:.0f} m is beyond the item's "
                        f"{TAG_BY_NAME[name].hi:g} m: written as {TAG_BY_NAME[name].hi:g} m"
                    )
                    put(t, name, TAG_BY_NAME[name].hi, "target error estimate")
                else:
                    put(t, name, v, "target error estimate")
    if int(c["corner_status"][k]) == Status.OK:
        for j in range(4):
            klat, klon = float(c[f"corner{j + 1}_lat_deg"][k]), float(c[f"corner{j + 1}_lon_deg"][k])
            for a, v in ((0, klat), (1, klon)):
                t = 82 + 2 * j + a
                if t in tags:
                    put(t, FULL_CORNER_TAGS[t], v, f"corner {j + 1} {'latitude' if a == 0 else 'longitude'}")
            if int(c["status"][k]) == Status.OK:
                for a, d in ((0, klat - float(c["lat_deg"][k])), (1, _wrap(klon - float(c["lon_deg"][k])))):
                    t = 26 + 2 * j + a
                    if t not in tags:
                        continue
                    spec = TAG_BY_NAME[OFFSET_CORNER_TAGS[t]]
                    if abs(d) > spec.hi:
                        out[t] = encode_value(spec.name, math.nan)  # the reserved "error" value
                        notes.append(
                            f"tag {t}: offset {d:+.4f} deg is beyond +-{spec.hi:g} deg: written as the "
                            "reserved error value (full corners 82-89 have the range)"
                        )
                    else:
                        put(t, spec.name, d, f"offset corner {j + 1}")
    return out


def _why_unchanged(r: KlvReplay, k: int) -> str:
    c = r.columns
    st = int(c["status"][k])
    note = str(c["note"][k] or "")
    return f"{Status(st).name.lower()}: {note or describe(st)}"


class _Rewriter:
    """Rewrites good packets in file order against the replay's rows."""

    def __init__(self, r: KlvReplay, fix: KlvFix, errors: bool = False):
        self.r, self.fix, self.k, self.errors = r, fix, 0, errors
        self.number = np.asarray(r.columns["packet"])

    def packet(self, blob: bytes) -> bytes:
        k = self.k
        self.k += 1
        if k >= len(self.r):
            raise RuntimeError("more good packets than replay rows: the stream changed while it was read")
        if not blob.startswith(UAS_LS_KEY):  # an EG 0104 universal set (docs/klv.md): no ST 0601 item to rewrite
            self.fix.unchanged.append((int(self.number[k]), "an EG 0104 packet: klv fix rewrites ST 0601 items only"))
            return blob
        tags = {t for t, _, _ in local_set_items(blob)}
        notes: list[str] = []
        values = _new_values(self.r, k, tags, notes, self.errors)
        num = int(self.number[k])
        for text in notes:
            self.fix.notes.append((num, text))
        if not values:
            self.fix.unchanged.append(
                (
                    num,
                    _why_unchanged(self.r, k)
                    if int(self.r.columns["status"][k]) != Status.OK
                    else "no frame-centre or corner item to rewrite",
                )
            )
            return blob
        for t in values:
            self.fix.items[t] = self.fix.items.get(t, 0) + 1
        self.fix.rewritten += 1
        new = {t: v for t, v in values.items() if t not in tags}
        for t in new:
            self.fix.added[t] = self.fix.added.get(t, 0) + 1
        out = replace_values(blob, {t: v for t, v in values.items() if t in tags})
        return add_items(out, new) if new else out


def _fix_bytes(data: bytes, rw: _Rewriter, verify: bool, raw: bool = False) -> bytes:
    """Rewrite the good packets of raw KLV bytes (bad packets and other bytes copied as they are)."""
    parts, pos = [], 0
    for p in iter_packets(data, verify_checksum=verify):
        if isinstance(p, KlvError):
            continue  # copied with the bytes around it
        start = p.offset
        if start is None:  # a scan of bytes gives each packet its offset; a packet from a TS has none
            raise RuntimeError("a KLV packet without its byte offset: it cannot be rewritten in place")
        if raw and rw.k < len(rw.r) and int(rw.r.columns["offset"][rw.k]) != start:
            raise RuntimeError(
                f"packet at byte {start}: the replay's row {rw.k} is at byte {int(rw.r.columns['offset'][rw.k])}"
            )
        b = data[start + 16]
        end = (
            start
            + 17
            + (b if b < 0x80 else (b & 0x7F) + int.from_bytes(data[start + 17 : start + 17 + (b & 0x7F)], "big"))
        )
        parts.append(data[pos:start])
        parts.append(rw.packet(data[start:end]))
        pos = end
    parts.append(data[pos:])
    return b"".join(parts)


def _remux(src: Path, tmp: str, rw: _Rewriter, fix: KlvFix, verify: bool) -> None:
    av = require("av", "writing KLV back into MPEG-TS video")

    with av.open(os.fspath(src)) as inp:
        klv = _klv_stream(inp, None, src)
        fmt = inp.format.name.split(",")[0]
        with av.open(tmp, "w", format=fmt) as out:
            streams = {}
            for s in inp.streams:
                if s.type == "data":
                    o = out.add_data_stream(codec_name=s.codec_context.name if s.codec_context else "klv")
                else:
                    o = out.add_stream_from_template(s)
                try:
                    o.id = s.id  # keep the MPEG-TS PID
                except (AttributeError, ValueError, TypeError):
                    pass
                streams[s.index] = o
            for pkt in inp.demux():
                if pkt.dts is None and pkt.size == 0:
                    continue  # the demuxer's flush packet
                o = streams[pkt.stream.index]
                if pkt.stream.index == klv.index and pkt.size:
                    old = bytes(pkt)
                    new = _fix_bytes(old, rw, verify)
                    q = av.Packet(new)
                    q.pts, q.dts, q.time_base = pkt.pts, pkt.dts, pkt.time_base
                    q.is_keyframe = pkt.is_keyframe
                    q.stream = o
                    out.mux(q)
                else:
                    if pkt.stream.index != klv.index:
                        fix.other_packets += 1
                    pkt.stream = o
                    out.mux(pkt)


def fix_klv(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    surface: Surface | None = None,
    sensor: FrameSensor | None = None,
    budget: ErrorBudget | None = None,
    verify_checksum: bool = True,
    corrections: Corrections = NO_CORRECTIONS,
) -> KlvFix:
    """Write a copy of a KLV stream whose frame-centre and corner items are geoloc's.

    Parameters
    ----------
    source : path
        Raw KLV (``.klv``, ``.bin``: concatenated packets) or a container
        (``.ts``, ``.m2ts``, ``.mpg``, ...) with a KLV data stream.
    out : path
        The copy to write (same kind as ``source``); never the input.
    surface, sensor
        As :func:`geoloc.workflows.klv_replay.replay_klv`: the terrain to intersect
        (default: each packet's own frame-centre height), and a sensor file's
        sensor (a calibration from ``geoloc calibrate --fit ... --write-sensor``:
        mount, boresight, lever arm).
    budget : ErrorBudget, optional
        The sensor file's ``[uncertainty]`` table: tags 45 / 46 (Target Error Estimate CE90 /
        LE90) get each recomputed centre's predicted CE90 / LE90 (the replay's ``ce90_m`` /
        ``le90_m``), added where a packet has none; the report says so.
    verify_checksum : bool
        Bad checksums make bad packets (copied unchanged). Default True.

    Returns
    -------
    KlvFix
    """

    src, dst = Path(source), Path(out)
    if not src.is_file():
        raise FileNotFoundError(f"KLV file {str(source)!r} does not exist")
    note_input(src)
    if dst.exists() and os.path.samefile(dst, src):
        raise ValueError(f"--out {dst} is the input: refusing to overwrite it")
    container = is_container_file(src)  # by its bytes when they say: a suffix can lie
    # the output is written in the input's format (its muxer, not its name); a lying suffix may stay
    same_suffix = dst.suffix.lower() == src.suffix.lower()
    if container != (dst.suffix.lower() in CONTAINER_SUFFIXES or (container and same_suffix)):
        raise ValueError(
            f"--out {dst.name}: write the same kind of file as the input {src.name} "
            "(raw KLV to raw KLV, a container to a container)"
        )
    read = read_klv(src, verify_checksum=verify_checksum)
    r = replay_klv(read, surface=surface, sensor=sensor, budget=budget, corrections=corrections)
    fix = KlvFix(
        str(src),
        str(dst),
        packets=len(r),
        correction_m=np.asarray(r.columns["frame_center_error_m"]),
        bad=[e for e in read.errors if not e.reason.endswith("are not a UAS LS packet")],
        budget_source=(str(budget.source or "the sensor file") if budget is not None else ""),
    )
    rw = _Rewriter(r, fix, errors=budget is not None)
    with atomic_path(dst, "--out") as tmp:
        if container:
            _remux(src, str(tmp), rw, fix, verify_checksum)
        else:
            tmp.write_bytes(_fix_bytes(src.read_bytes(), rw, verify_checksum, raw=True))
        if rw.k != len(r):
            raise RuntimeError(f"{rw.k} good packets rewritten for {len(r)} replayed: the stream changed")
    return fix


__all__ = ["CENTRE_TAGS", "ERROR_TAGS", "FULL_CORNER_TAGS", "KlvFix", "OFFSET_CORNER_TAGS", "fix_klv"]
