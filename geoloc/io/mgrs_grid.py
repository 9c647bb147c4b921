"""MGRS and USNG grid references beside latitude and longitude.

The Military Grid Reference System (NGA.STND.0037, "Universal Grids and Grid
Reference Systems"; the US National Grid, FGDC-STD-011-2001, is the same
references on WGS 84 written with spaces) names a square of the UTM grid
(80 S to 84 N, with the Norway 32V and Svalbard 31X-37X zone exceptions) or of
the UPS grid (the polar caps): grid zone designator, 100 km square letters,
then easting and northing digits, truncated (never rounded) to the precision.

The conversions are the maintained ``mgrs`` package (a binding of NGA's
GEOTRANS MGRS code); this module is the project's edge around it: arrays in,
arrays out, an empty string (or NaN) with a :class:`~geoloc.status.Status` and a
reason for a point that has no reference, never an exception in a batch. The
scalar front end :func:`parse_mgrs` raises ``ValueError`` naming the value.

Reading a reference back gives the **centre** of the square it names (as
GEOTRANS 3 does): the point known to that precision with the smallest worst
error, half a square's side in each axis (0.5 m for a 1 m reference).

Checked in ``tests/io/test_mgrs.py`` against pyproj's UTM and UPS projections and
the standard's letter and zone rules, written out in the test.
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from geoloc.status import Status

#: Digits per axis -> the square's side in metres (1 m, 10 m, ... 100 km).
PRECISION_M = {5: 1.0, 4: 10.0, 3: 100.0, 2: 1000.0, 1: 10000.0, 0: 100000.0}

_MGRS_RE = re.compile(r"^(\d{1,2}[C-HJ-NP-X]|[ABYZ])([A-HJ-NP-Z]{2})(\d*)$")


class MgrsResult(NamedTuple):
    """Per point: the reference text ('' when none), a Status code and the reason ('' when OK)."""

    text: np.ndarray  # object array of str
    status: np.ndarray  # uint8
    reason: np.ndarray  # object array of str


class LatLonResult(NamedTuple):
    """Per reference: the square's centre in degrees (NaN when unreadable), Status, reason."""

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    status: np.ndarray
    reason: np.ndarray


def _converter():
    try:
        import mgrs
    except ImportError as e:  # a dependency in pyproject; say how to get it
        raise ImportError("MGRS needs the 'mgrs' package: pip install mgrs") from e
    return mgrs.MGRS()


def latlon_to_mgrs(lat_deg: ArrayLike, lon_deg: ArrayLike, precision: int = 5) -> MgrsResult:
    """MGRS references of geodetic points (WGS 84), element by element.

    Parameters
    ----------
    lat_deg, lon_deg : array_like
        Geodetic latitude and longitude in degrees; broadcast together.
    precision : int
        Digits per axis, 0-5 (5: 1 m squares, the default).

    Returns
    -------
    MgrsResult
        ``text`` (e.g. ``'18SUJ2348606483'``; '' where there is none),
        ``status`` (``INVALID_INPUT`` for NaN, infinite or out-of-range
        coordinates) and ``reason``.
    """
    if int(precision) not in PRECISION_M:
        raise ValueError(f"precision = {precision!r}: MGRS precision is 0-5 digits per axis")
    lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
    text = np.full(lat.shape, "", dtype=object)
    status = np.full(lat.shape, Status.OK, dtype=np.uint8)
    reason = np.full(lat.shape, "", dtype=object)
    conv = _converter()
    for idx in np.ndindex(lat.shape):
        a, o = float(lat[idx]), float(lon[idx])
        why = ""
        if not (np.isfinite(a) and np.isfinite(o)):
            why = f"latitude {a!r} / longitude {o!r} is not a finite number"
        elif abs(a) > 90.0:
            why = f"latitude {a!r} deg is outside [-90, 90]"
        elif abs(o) > 360.0:
            why = f"longitude {o!r} deg is outside [-360, 360]"
        if not why:
            o = (o + 180.0) % 360.0 - 180.0
            try:
                text[idx] = conv.toMGRS(a, o, MGRSPrecision=int(precision))
                continue
            except Exception as e:  # the library's MGRSError: report, never raise in a batch
                why = f"({a!r}, {o!r}): {e}"
        status[idx] = Status.INVALID_INPUT
        reason[idx] = why
    return MgrsResult(text, status, reason)


def normalize_mgrs(text: str) -> str:
    """Upper case, spaces removed, leading zero of a one-digit zone added: ``'4q fj 1 2'`` -> ``'04QFJ12'``."""
    s = re.sub(r"\s+", "", str(text)).upper()
    if re.match(r"^\d[C-X]", s):
        s = "0" + s
    return s


def mgrs_to_latlon(texts: str | ArrayLike) -> LatLonResult:
    """The centres of the squares that MGRS / USNG references name, element by element.

    Parameters
    ----------
    texts : str or array_like of str
        References with or without spaces (``'18S UJ 23486 06483'``,
        ``'18SUJ2348606483'``), upper or lower case.

    Returns
    -------
    LatLonResult
        Degrees, NaN and ``INVALID_INPUT`` with a reason for a reference that
        cannot be read (wrong pattern, odd number of digits, a square that does
        not exist in its zone).
    """
    arr = np.asarray(texts, dtype=object)
    lat = np.full(arr.shape, np.nan)
    lon = np.full(arr.shape, np.nan)
    status = np.full(arr.shape, Status.OK, dtype=np.uint8)
    reason = np.full(arr.shape, "", dtype=object)
    conv = _converter()
    for idx in np.ndindex(arr.shape):
        raw = arr[idx]
        s = normalize_mgrs(raw) if isinstance(raw, str) else ""
        m = _MGRS_RE.match(s)
        why = ""
        if m is None:
            why = f"{raw!r} is not an MGRS reference (zone, band, two square letters, digits)"
        elif len(m.group(3)) % 2 or len(m.group(3)) > 10:
            why = f"{raw!r}: {len(m.group(3))} digits; an MGRS reference has an even number, at most 10"
        else:
            try:
                a, o = conv.toLatLon(s)
                if np.isfinite(a) and np.isfinite(o):
                    lat[idx], lon[idx] = a, o
                    continue
                why = f"{raw!r}: no position"
            except Exception as e:
                why = f"{raw!r}: {e}"
        status[idx] = Status.INVALID_INPUT
        reason[idx] = why
    return LatLonResult(lat, lon, status, reason)


def format_usng(mgrs_text: str) -> str:
    """An MGRS reference written the USNG way: ``'18SUJ2348606483'`` -> ``'18S UJ 23486 06483'``.

    On WGS 84 (every reference here) USNG and MGRS are the same grid; USNG writes
    the zone, the square and the two coordinates as separate groups.
    """
    s = normalize_mgrs(mgrs_text)
    m = _MGRS_RE.match(s)
    if m is None:
        return ""
    gzd, sq, digits = m.groups()
    if gzd[0] == "0":
        gzd = gzd[1:]
    half = len(digits) // 2
    parts = [gzd, sq] + ([digits[:half], digits[half:]] if digits else [])
    return " ".join(parts)


def parse_mgrs(text: str, what: str = "--mgrs") -> tuple[float, float]:
    """One reference -> (lat_deg, lon_deg) of its square's centre; ``ValueError`` naming ``what`` and the value."""
    r = mgrs_to_latlon([text])
    if int(r.status[0]) != Status.OK:
        raise ValueError(f"{what} {text!r}: {r.reason[0]}")
    return float(r.lat_deg[0]), float(r.lon_deg[0])


def mgrs_column(lat_deg: ArrayLike, lon_deg: ArrayLike, precision: int = 5) -> list:
    """The ``mgrs`` column of a results table: one string a row, '' where there is no position."""
    return [str(t) for t in latlon_to_mgrs(lat_deg, lon_deg, precision).text.ravel()]


def mgrs_text(lat_deg: ArrayLike, lon_deg: ArrayLike, precision: int = 5) -> str:
    """One point's references for a panel or a printed line: ``'MGRS 16SGF4866651490 (USNG 16S GF
    48666 51490)'``, or ``'MGRS: none (<reason>)'`` where the point has none."""
    r = latlon_to_mgrs(np.asarray([lat_deg], float), np.asarray([lon_deg], float), precision)
    text = str(r.text.ravel()[0])
    if not text:
        return f"MGRS: none ({r.reason.ravel()[0]})"
    return f"MGRS {text} (USNG {format_usng(text)})"


__all__ = [
    "LatLonResult",
    "MgrsResult",
    "PRECISION_M",
    "format_usng",
    "latlon_to_mgrs",
    "mgrs_column",
    "mgrs_text",
    "mgrs_to_latlon",
    "normalize_mgrs",
    "parse_mgrs",
]
