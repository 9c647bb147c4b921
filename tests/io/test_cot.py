"""Cursor-on-Target export (geoloc.io.cot, ``geoloc export --format cot`` / ``--cot udp://...``).

Read back by an independent parser: takproto (the TAK Protocol library on PyPI)
parses each event's XML into a TAK protobuf message (``xml2message``) and its
round trip through the TAK Protocol v1 wire format (``xml2proto`` then
``parse_proto``). And checked against the CoT Event schema (MITRE, version 2.0):
an XSD written here from the published schema's required elements, attributes
and their types (not a copy of it), validated by lxml.
"""

import csv
import math
import socket
from datetime import UTC, datetime

import numpy as np
import pytest
from scipy.stats import norm, rayleigh

from geoloc.cli import main
from geoloc.io.cot import COT_UNKNOWN, cot_events, parse_udp_url, send_udp, write_cot
from geoloc.io.gis import read_results

pytest.importorskip("takproto")
import takproto.functions as takproto  # noqa: E402  (xml2message, xml2proto, parse_proto)

etree = pytest.importorskip("lxml.etree")

# The CoT 2.0 schema's requirements, written out: <event> holds one <point> and an optional
# <detail>; event has version (decimal >= 2), type (\w+(-\w+)*(;[^;]*)?), uid, time, start,
# stale (xs:dateTime), how (\w(-\w+)*), optional access/qos/opex; point has lat in [-90, 90],
# lon in [-180, 180], hae, ce, le (decimals), all required; detail is open content.
COT_XSD = b"""<?xml version="1.0"?>
<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema" elementFormDefault="qualified">
 <xs:element name="event"><xs:complexType>
  <xs:all><xs:element ref="point"/><xs:element ref="detail" minOccurs="0"/></xs:all>
  <xs:attribute name="version" use="required"><xs:simpleType>
   <xs:restriction base="xs:decimal"><xs:minInclusive value="2"/></xs:restriction></xs:simpleType></xs:attribute>
  <xs:attribute name="type" use="required"><xs:simpleType>
   <xs:restriction base="xs:string"><xs:pattern value="\\w+(-\\w+)*(;[^;]*)?"/></xs:restriction>
  </xs:simpleType></xs:attribute>
  <xs:attribute name="uid" type="xs:string" use="required"/>
  <xs:attribute name="time" type="xs:dateTime" use="required"/>
  <xs:attribute name="start" type="xs:dateTime" use="required"/>
  <xs:attribute name="stale" type="xs:dateTime" use="required"/>
  <xs:attribute name="how" use="required"><xs:simpleType>
   <xs:restriction base="xs:string"><xs:pattern value="\\w(-\\w+)*"/></xs:restriction></xs:simpleType></xs:attribute>
  <xs:attribute name="access" type="xs:string"/>
  <xs:attribute name="qos" type="xs:string"/>
  <xs:attribute name="opex" type="xs:string"/>
 </xs:complexType></xs:element>
 <xs:element name="detail"><xs:complexType>
  <xs:sequence><xs:any processContents="lax" minOccurs="0" maxOccurs="unbounded"/></xs:sequence>
  <xs:anyAttribute processContents="skip"/>
 </xs:complexType></xs:element>
 <xs:element name="remarks" type="xs:string"/>
 <xs:element name="point"><xs:complexType>
  <xs:attribute name="lat" use="required"><xs:simpleType><xs:restriction base="xs:decimal">
   <xs:minInclusive value="-90"/><xs:maxInclusive value="90"/></xs:restriction></xs:simpleType></xs:attribute>
  <xs:attribute name="lon" use="required"><xs:simpleType><xs:restriction base="xs:decimal">
   <xs:minInclusive value="-180"/><xs:maxInclusive value="180"/></xs:restriction></xs:simpleType></xs:attribute>
  <xs:attribute name="hae" type="xs:decimal" use="required"/>
  <xs:attribute name="ce" type="xs:decimal" use="required"/>
  <xs:attribute name="le" type="xs:decimal" use="required"/>
 </xs:complexType></xs:element>
</xs:schema>"""

SCHEMA = etree.XMLSchema(etree.fromstring(COT_XSD))
NOW = datetime(2026, 12, 2, 10, 0, 0, tzinfo=UTC)


def _csv(path, rows, header):
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


@pytest.fixture
def results(tmp_path):
    """A results CSV with three located points (one with an EGM96 height, one with CE90/LE90) and one sky row."""
    header = ["table", "point", "lat_deg", "lon_deg", "h_m", "h_datum", "status", "ce90_m", "le90_m", "time_utc"]
    rows = [
        ["T1", "1", "36.60000001", "-84.25", "412.5", "", "ok", "12.5", "4.25", "2024-05-14T15:00:00Z"],
        ["T1", "2", "-33.9", "18.4", "100.0", "EGM96", "ok", "", "", "2024-05-14T15:00:01Z"],
        ["T1", "3", "", "", "", "", "sky", "", "", "2024-05-14T15:00:02Z"],
        ["T1", "4", "89.9", "179.999", "", "", "ok", "3", "", "2024-05-14T15:00:03Z"],
    ]
    return _csv(tmp_path / "res.csv", rows, header)


def _check_event(xml: bytes):
    """Schema-valid, and parsed by takproto directly and through the TAK v1 protobuf."""
    doc = etree.fromstring(xml)
    SCHEMA.assertValid(doc)
    msg = takproto.xml2message(xml)
    wire = takproto.xml2proto(xml.decode())
    back = takproto.parse_proto(wire)
    assert back.cotEvent == msg.cotEvent
    return doc, msg.cotEvent


def test_file_events_parse_and_carry_the_points(results, tmp_path):
    from geoloc.geodesy.geoid import egm96_undulation

    out = tmp_path / "pts.cot"
    assert main(["export", str(results), "--out", str(out), "--cot-stale-s", "600"]) == 0
    lines = out.read_bytes().splitlines()
    assert len(lines) == 3  # the sky row has no event
    ev = [_check_event(x) for x in lines]
    (d1, e1), (d2, e2), (d3, e3) = ev
    for d, e in ev:
        assert d.get("version") == "2.0" and e.type == "a-u-G" and e.how == "m-i"
        assert e.staleTime - e.startTime == 600_000  # takproto: ms since 1970
        assert e.startTime == e.sendTime
    assert e1.lat == pytest.approx(36.60000001, abs=1e-12) and e1.lon == -84.25 and e1.hae == 412.5
    # CE90 -> one sigma: the 0.9 quantile of the Rayleigh radius; LE90 -> sigma: the normal's 0.95 quantile
    assert e1.ce == pytest.approx(12.5 / rayleigh.ppf(0.9), rel=1e-12)
    assert e1.le == pytest.approx(4.25 / norm.ppf(0.95), rel=1e-12)
    # the EGM96 row's height is made ellipsoidal (h = H + N); no CE90/LE90: unknown
    n = float(egm96_undulation(math.radians(-33.9), math.radians(18.4)))
    assert e2.hae == pytest.approx(100.0 + n, abs=1e-9)
    assert e2.ce == COT_UNKNOWN and e2.le == COT_UNKNOWN
    # unknown height: hae and le unknown, ce still from CE90
    assert e3.hae == COT_UNKNOWN and e3.le == COT_UNKNOWN and e3.ce == pytest.approx(3 / rayleigh.ppf(0.9))
    uids = {e.uid for _, e in ev}
    assert len(uids) == 3 and "geoloc.res.T1_1" in uids
    remarks = d1.find("detail/remarks").text
    assert "frame table T1, point 1 (row 0)" in remarks and "observed 2024-05-14T15:00:00Z" in remarks
    assert "MGRS 16S" in remarks and "CE90 12.50 m" in remarks
    assert takproto.xml2message(lines[0]).cotEvent.detail.xmlDetail.startswith("<remarks>")


def test_klv_replay_to_cot_and_the_type_option(tmp_path):
    from geoloc.assets import asset_path
    from geoloc.workflows.klv_replay import replay_klv, write_klv_csv

    r = replay_klv(asset_path("klv", "example_flight.klv"))
    csv_path = tmp_path / "flight.csv"
    write_klv_csv(csv_path, r)
    ev = cot_events(read_results(csv_path), source="flight", cot_type="b-m-p-s-p-i", now=NOW)
    ok = np.isfinite(r.columns["lat_deg"])
    assert len(ev.events) == int(ok.sum()) and len(ev.skipped) == int((~ok).sum())
    lat = r.columns["lat_deg"][ok]
    h = r.columns["h_m"][ok]
    for j in range(0, len(ev.events), 37):
        _, e = _check_event(ev.events[j])
        assert e.type == "b-m-p-s-p-i"
        assert e.lat == pytest.approx(lat[j], abs=1e-9)  # the CSV's 9 decimals
        assert e.hae == pytest.approx(h[j], abs=1e-3)  # the CSV's 3 decimals
        assert e.startTime == int(NOW.timestamp() * 1000)
        assert f"frame file example_flight.klv, packet {r.columns['packet'][ok][j]} " in e.detail.xmlDetail


def test_udp_datagrams_on_loopback(results):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    port = rx.getsockname()[1]
    try:
        assert main(["export", str(results), "--cot", f"udp://127.0.0.1:{port}"]) == 0
        got = [rx.recv(65535) for _ in range(3)]
    finally:
        rx.close()
    ev = [_check_event(g)[1] for g in got]
    assert [e.uid for e in ev] == ["geoloc.res.T1_1", "geoloc.res.T1_2", "geoloc.res.T1_4"]


def test_send_udp_to_a_multicast_url_is_parsed_but_only_loopback_is_used_here(tmp_path):
    assert parse_udp_url("udp://239.2.3.1:6969") == ("239.2.3.1", 6969)
    for bad in ("tcp://127.0.0.1:1", "udp://127.0.0.1", "239.2.3.1:6969"):
        with pytest.raises(ValueError, match="udp://HOST:PORT"):
            parse_udp_url(bad)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    try:
        table = {"lat_deg": np.array([1.0]), "lon_deg": np.array([2.0]), "h_m": np.array([3.0])}
        ev = cot_events(table, now=NOW)
        assert send_udp(ev, f"udp://127.0.0.1:{rx.getsockname()[1]}") == 1
        assert rx.recv(65535) == ev.events[0]
    finally:
        rx.close()
    write_cot(ev, tmp_path / "one.cot")
    SCHEMA.assertValid(etree.parse(str(tmp_path / "one.cot")))  # one event: the file is an XML document


def test_bad_options_name_the_value(results, tmp_path, capsys):
    table = read_results(results)
    with pytest.raises(ValueError, match="CoT type 'not a type'"):
        cot_events(table, cot_type="not a type")
    with pytest.raises(ValueError, match="stale"):
        cot_events(table, stale_s=0)
    assert main(["export", str(results), "--cot", "udp://nowhere"]) == 2
    assert "udp://HOST:PORT" in capsys.readouterr().err
    assert main(["export", str(results)]) == 2
    assert main(["export", str(results), "--format", "cot", "--out", str(results)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
