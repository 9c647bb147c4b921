"""Cursor-on-Target fields, each against the CoT 2.0 schema's rules written in the test.

The schema (MITRE CoT Event 2.0): ``ce``, ``le`` and ``hae`` are 9999999 when unknown; ``ce`` and
``le`` are one sigma; times are xs:dateTime. The expected values are the inputs of the test table
divided by the normal distribution's quantiles computed here with scipy, or the schema's literals;
the XML is read with lxml. The sender's multicast rule is the IPv4 multicast block, 224.0.0.0/4
(RFC 5771), checked with Python's ``ipaddress``.
"""

import ipaddress
import math
import socket
from datetime import UTC, datetime

import numpy as np
import pytest
from scipy.stats import norm, rayleigh

from geoloc.io import cot as cot_mod
from geoloc.io.cot import cot_events, send_udp

etree = pytest.importorskip("lxml.etree")

NOW = datetime(2026, 12, 6, 12, 0, 0, 500_000, tzinfo=UTC)


def _points(events):
    return [etree.fromstring(e) for e in events.events]


def test_ce_le_and_hae_known_or_the_schemas_unknown_and_the_remarks_say_which():
    table = {
        "lat_deg": np.array([36.0, 36.1, 36.2, 36.3, 36.4]),
        "lon_deg": np.array([-84.0, -84.1, -84.2, -84.3, -84.4]),
        "h_m": np.array([300.0, 310.0, np.nan, 330.0, 340.0]),
        "ce90_m": np.array([5.0, np.nan, np.nan, np.nan, -1.0]),
        "le90_m": np.array([np.nan, 7.0, 7.0, np.nan, -1.0]),
    }
    ev = _points(cot_events(table, now=NOW))
    pt = [e.find("point") for e in ev]
    rem = [e.find("detail/remarks").text for e in ev]
    # one sigma: CE90 / Rayleigh's 90 % quantile, LE90 / the normal's two-sided 90 % quantile
    assert float(pt[0].get("ce")) == pytest.approx(5.0 / rayleigh.ppf(0.9), rel=1e-12)
    assert pt[0].get("le") == "9999999.0" and "predicted CE90 5.00 m, LE90 unknown" in rem[0]
    assert float(pt[1].get("le")) == pytest.approx(7.0 / norm.ppf(0.95), rel=1e-12)
    assert pt[1].get("ce") == "9999999.0" and "predicted CE90 unknown, LE90 7.00 m" in rem[1]
    # no height: hae and le are unknown, whatever LE90 says
    assert (pt[2].get("hae"), pt[2].get("le")) == ("9999999.0", "9999999.0") and "hae unknown" in rem[2]
    assert "no predicted uncertainty: ce/le unknown (9999999)" in rem[3]
    # a negative spread is no spread
    assert (pt[4].get("ce"), pt[4].get("le")) == ("9999999.0", "9999999.0")


def test_times_keep_their_milliseconds_and_a_pole_beyond_90_is_skipped():
    table = {"lat_deg": np.array([90.5, 36.0]), "lon_deg": np.array([1.0, 2.0]), "h_m": np.array([3.0, 4.0])}
    out = cot_events(table, now=NOW, stale_s=90.25)
    assert [k for k, _ in out.skipped] == [0] and "latitude 90.5" in out.skipped[0][1]
    (e,) = _points(out)
    assert e.get("time") == e.get("start") == "2026-12-06T12:00:00.500Z"
    assert e.get("stale") == "2026-12-06T12:01:30.750Z"
    assert out.rows == [1]


class _FakeSocket:
    calls: list = []

    def __init__(self, family, kind):
        self.family = family

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False

    def setsockopt(self, level, name, value):
        _FakeSocket.calls.append(("ttl", value))

    def sendto(self, data, addr):
        _FakeSocket.calls.append(("to", addr))


@pytest.mark.parametrize("host", ["223.255.255.1", "224.0.0.1", "239.2.3.1", "239.255.255.255", "240.0.0.1"])
def test_the_multicast_ttl_is_set_inside_224_0_0_0_4_only(host, monkeypatch):
    monkeypatch.setattr(cot_mod.socket, "socket", _FakeSocket)
    _FakeSocket.calls = []
    ev = cot_events({"lat_deg": [36.0], "lon_deg": [-84.0], "h_m": [300.0]}, now=NOW)
    assert send_udp(ev, f"udp://{host}:6969", ttl=3) == 1
    multicast = ipaddress.ip_address(host) in ipaddress.ip_network("224.0.0.0/4")
    assert (("ttl", 3) in _FakeSocket.calls) == multicast
    assert ("to", (host, 6969)) in _FakeSocket.calls


def test_the_first_address_the_resolver_gives_is_used(monkeypatch):
    monkeypatch.setattr(cot_mod.socket, "socket", _FakeSocket)
    _FakeSocket.calls = []
    first, second = ("127.0.0.1", 7001), ("127.0.0.2", 7002)
    monkeypatch.setattr(
        cot_mod.socket,
        "getaddrinfo",
        lambda *a, **k: [
            (socket.AF_INET, socket.SOCK_DGRAM, 17, "", first),
            (socket.AF_INET, socket.SOCK_DGRAM, 17, "", second),
        ],
    )
    ev = cot_events({"lat_deg": [36.0], "lon_deg": [-84.0], "h_m": [300.0]}, now=NOW)
    send_udp(ev, "udp://example.invalid:7001")
    assert _FakeSocket.calls == [("to", first)]
    assert math.isfinite(float(_points(ev)[0].find("point").get("hae")))
