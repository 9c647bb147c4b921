"""Cursor-on-Target (CoT) events of located points, to a file or to TAK over UDP (``docs/gis.md``).

A CoT event (MITRE's CoT Event schema, version 2.0) is one XML element::

    <event version="2.0" type="a-u-G" uid="..." how="m-i"
           time="2024-05-14T15:00:00.000Z" start="..." stale="...">
      <point lat="36.6" lon="-84.25" hae="412.3" ce="5.6" le="2.7"/>
      <detail><remarks>...</remarks></detail>
    </event>

The schema requires, on ``event``: ``version`` (>= 2), ``type`` (dash-separated
hierarchy, e.g. ``a-u-G``: atom, unknown affiliation, ground), ``uid``,
``time``, ``start``, ``stale`` (ISO 8601 UTC) and ``how`` (``m-i``: machine,
mensurated from imagery); on ``point``: ``lat``, ``lon`` (WGS 84 degrees),
``hae`` (metres above the WGS 84 ellipsoid), ``ce`` and ``le`` (metres). The
schema defines ``ce`` and ``le``, when they describe an error, as **one sigma**
of a zero-mean normal distribution (the ``point`` element's documentation in
MITRE's Event.xsd: "If it is appropriate for the ce field to represent an error
value ... the value will represent the one sigma point for a zero mean normal
(Gaussian) distribution", and the same for ``le``); unknown is ``9999999`` (the
CoT convention). We found no published source for reading them as CE90 / LE90,
so we keep the schema's meaning. From a results table with predicted ``ce90_m`` /
``le90_m`` columns (``geoloc replay`` with a sensor file's ``[uncertainty]``:
the exact CE90 of each point's ellipse, :mod:`geoloc.analysis.uncertainty`)
they are ``CE90 / 2.1460`` (the sigma of the circular normal error whose 90 %
circle is that CE90: CE90 = sqrt(2 ln 10) sigma) and ``LE90 / 1.6449`` (normal:
LE90 = 1.6449 sigma); the CE90 / LE90 themselves are in the remarks.

``time`` and ``start`` are when the events are made (TAK clients drop events
whose ``stale`` has passed, so a replay of an old flight would never show);
``stale`` is ``start`` plus ``stale_s``. The observation time of the row
(``time_utc`` or ``time_s``), the frame (table/point/record/image/packet), the
MGRS reference and the datum are in ``detail/remarks``.

Files hold one event per line (no XML declaration), as TAK's stream format
sends them; a file of one event is an XML document. :func:`send_udp` sends
one event per datagram, as TAK's situational-awareness multicast does
(``udp://239.2.3.1:6969`` is its default group; the tests send only to
loopback).
"""

from __future__ import annotations

import math
import os
import re
import socket
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from urllib.parse import urlsplit
from xml.sax.saxutils import escape, quoteattr

import numpy as np

#: CoT's "unknown" for ce, le and hae.
COT_UNKNOWN = 9999999.0
#: Default event type: atom, unknown affiliation, ground.
DEFAULT_TYPE = "a-u-G"
#: Default how: machine generated, mensurated from imagery.
DEFAULT_HOW = "m-i"
#: Default validity after the event is made [s].
DEFAULT_STALE_S = 3600.0
#: TAK's situational-awareness multicast group (ATAK/WinTAK listen there by default).
TAK_SA_MULTICAST = "udp://239.2.3.1:6969"
#: CE90 = sqrt(2 ln 10) sigma for a circular normal distribution (Rayleigh radius quantile).
CE90_PER_SIGMA = math.sqrt(2.0 * math.log(10.0))
#: LE90 = 1.6449 sigma for a normal distribution (two-sided 90 %).
LE90_PER_SIGMA = 1.6448536269514722

_TYPE_RE = re.compile(r"^\w+(-\w+)*(;[^;]*)?$")  # the schema's pattern for type
_HOW_RE = re.compile(r"^\w(-\w+)*$")  # and for how


@dataclass
class CotEvents:
    """Events made from a table: the XML of each, its data row, and the rows left out with why."""

    events: list = field(default_factory=list)  # bytes, one event each
    rows: list = field(default_factory=list)  # data row (0-based) of each event
    skipped: list = field(default_factory=list)  # (row, reason)


def _iso(t: datetime) -> str:
    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _num(x: float) -> str:
    return repr(float(x))


def _uid_part(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.:-]+", "_", text).strip("_") or "x"


def cot_events(
    table: dict,
    *,
    source: str = "geoloc",
    cot_type: str = DEFAULT_TYPE,
    how: str = DEFAULT_HOW,
    stale_s: float = DEFAULT_STALE_S,
    now: datetime | None = None,
    epoch: str | None = None,
) -> CotEvents:
    """One CoT event per located point of a results table.

    Parameters
    ----------
    table : dict
        As :func:`geoloc.io.gis.read_results` returns (``lat_deg``, ``lon_deg``,
        ``h_m`` with ``h_datum``, optional ``ce90_m`` / ``le90_m``, ids, times).
    source : str
        Names the input in the uid (``geoloc.<source>.<frame>``) and the remarks.
    cot_type, how : str
        CoT type and how, checked against the schema's patterns.
    stale_s : float
        Validity after ``now`` [s], > 0.
    now : datetime, optional
        When the events are made (default: the current UTC time).
    epoch : str, optional
        What ``time_s`` counts from (:data:`geoloc.io.gis.DEFAULT_EPOCH`).

    Returns
    -------
    CotEvents
        Rows without a position are skipped with the reason, never raised.
    """
    from geoloc.io.gis import DEFAULT_EPOCH, ELLIPSOID_DATUM, ID_COLUMNS, build_layers

    if not _TYPE_RE.match(str(cot_type)):
        raise ValueError(f"CoT type {cot_type!r}: not a dash-separated type such as a-u-G or b-m-p-s-p-i")
    if not _HOW_RE.match(str(how)):
        raise ValueError(f"CoT how {how!r}: not a how such as m-i (machine, from imagery) or h-e")
    if not (math.isfinite(stale_s) and stale_s > 0):
        raise ValueError(f"CoT stale time {stale_s!r} s: must be a number of seconds > 0")
    now = now or datetime.now(UTC)
    t0 = _iso(now)
    t_stale = _iso(now + timedelta(seconds=float(stale_s)))
    layers, ctx = build_layers(table, epoch=epoch or DEFAULT_EPOCH)
    n = ctx.n

    def col(name):
        v = table.get(name)
        if v is None:
            return np.full(n, np.nan)
        try:
            return np.asarray(v, float)
        except (TypeError, ValueError):
            return np.full(n, np.nan)

    ce90, le90 = col("ce90_m"), col("le90_m")
    out = CotEvents()
    seen = {}
    for f in layers["points"].features:
        k = f.row
        if not f.coords:
            st = ctx.status[k] if ctx.status is not None and ctx.status[k] else "no position"
            out.skipped.append((k, f"row {k} ({ctx.labels[k]}): {st}"))
            continue
        lon, lat, h = f.coords[0]
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0):
            out.skipped.append((k, f"row {k} ({ctx.labels[k]}): latitude {lat!r} / longitude {lon!r}"))
            continue
        lon = (lon + 180.0) % 360.0 - 180.0
        ce = ce90[k] / CE90_PER_SIGMA if np.isfinite(ce90[k]) and ce90[k] >= 0 else COT_UNKNOWN
        le = le90[k] / LE90_PER_SIGMA if np.isfinite(le90[k]) and le90[k] >= 0 and math.isfinite(h) else COT_UNKNOWN
        hae = h if math.isfinite(h) else COT_UNKNOWN
        label = ctx.labels[k]
        uid = f"geoloc.{_uid_part(source)}.{_uid_part(label)}"
        if uid in seen:  # labels repeat (e.g. no id column): the row index makes it unique
            uid = f"{uid}.row{k}"
        seen[uid] = k
        frame = ", ".join(f"{c} {f.attrs[c]}" for c in ID_COLUMNS if f.attrs.get(c) not in (None, ""))
        files = table.get("file")
        if isinstance(files, list) and files[k]:
            frame = f"file {files[k]}, " + frame if frame else f"file {files[k]}"
        remarks = [f"geoloc: {source}, frame {frame or label} (row {k})"]
        if ctx.real_time and f.time is not None:
            remarks.append(f"observed {ctx.iso(f.time)}")
        mg = f.attrs.get("mgrs")
        if mg:
            remarks.append(f"MGRS {mg}")
        remarks.append(f"hae {'unknown' if not math.isfinite(h) else 'above the ' + ELLIPSOID_DATUM}")
        if np.isfinite(ce90[k]) or np.isfinite(le90[k]):
            remarks.append(
                "predicted CE90 "
                + (f"{ce90[k]:.2f} m" if np.isfinite(ce90[k]) else "unknown")
                + ", LE90 "
                + (f"{le90[k]:.2f} m" if np.isfinite(le90[k]) else "unknown")
                + "; ce/le are one sigma (CoT schema)"
            )
        else:
            remarks.append("no predicted uncertainty: ce/le unknown (9999999)")
        xml = (
            f'<event version="2.0" type={quoteattr(cot_type)} uid={quoteattr(uid)} how={quoteattr(how)} '
            f'time="{t0}" start="{t0}" stale="{t_stale}">'
            f'<point lat="{_num(lat)}" lon="{_num(lon)}" hae="{_num(hae)}" ce="{_num(ce)}" '
            f'le="{_num(le)}"/>'
            f"<detail><remarks>{escape('; '.join(remarks))}</remarks></detail></event>"
        )
        out.events.append(xml.encode("utf-8"))
        out.rows.append(k)
    return out


def write_cot(events: CotEvents, path: str | os.PathLike[str], option: str = "--out") -> Path:
    """Write the events, one a line (UTF-8), through :func:`geoloc.userfiles.write_bytes` (atomic)."""
    from geoloc.userfiles import write_bytes

    return write_bytes(path, b"".join(e + b"\n" for e in events.events), option)


def parse_udp_url(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port); ``ValueError`` naming the value."""
    u = urlsplit(str(url))
    if u.scheme != "udp" or not u.hostname or u.port is None:
        raise ValueError(f"--cot {url!r}: give udp://HOST:PORT (TAK's multicast default is {TAK_SA_MULTICAST})")
    return u.hostname, int(u.port)


def send_udp(events: CotEvents, url: str, ttl: int = 1) -> int:
    """Send each event as one UDP datagram to ``udp://HOST:PORT``; returns the number sent.

    A multicast group (224.0.0.0/4, e.g. TAK's 239.2.3.1:6969) is sent with
    ``ttl`` hops (default 1: the local network only).
    """
    host, port = parse_udp_url(url)
    info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    family, _, _, _, addr = info[0]
    with socket.socket(family, socket.SOCK_DGRAM) as s:
        if family == socket.AF_INET and 224 <= int(str(addr[0]).split(".")[0]) <= 239:
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, int(ttl))
        for e in events.events:
            s.sendto(e, addr)
    return len(events.events)


__all__ = [
    "COT_UNKNOWN",
    "CotEvents",
    "DEFAULT_HOW",
    "DEFAULT_STALE_S",
    "DEFAULT_TYPE",
    "TAK_SA_MULTICAST",
    "cot_events",
    "parse_udp_url",
    "send_udp",
    "write_cot",
]
