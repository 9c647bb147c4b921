"""Drone photos: EXIF and DJI XMP read from JPEG/TIFF built here, the sensor and pose they give, the replay.

The photos are made in the test with Pillow: an EXIF block (IFD0 Make/Model, the
Exif IFD's PixelXDimension/PixelYDimension, the GPS IFD) and an XMP packet laid
out as DJI's cameras write it (one ``rdf:Description`` whose ``drone-dji:``
attributes hold the values as signed decimal strings, ``GimbalPitchDegree="-90.00"``),
or with the same properties as child elements. Oracles independent of the chain:
the geometry of a nadir ray, pymap3d's ``lookAtSpheroid``, NGA's published EGM96
test values, the DewarpData string of a public DJI Phantom 4 RTK photo.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin

from geoloc.geodesy.geoid import egm96_undulation
from geoloc.io.gis import ELLIPSOID_DATUM, read_results
from geoloc.io.photos import (
    DJI_NS,
    DewarpData,
    PhotoTagError,
    lens_from_photo,
    parse_dewarp_data,
    parse_xmp,
    pose_from_photo,
    read_photo,
    scale_lens,
    sensor_from_photo,
)
from geoloc.sensors.frame import FrameSensor
from geoloc.sensors.gimbals import PRESETS
from geoloc.sensors.lenses import BrownLens, PinholeLens
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.photo_replay import (
    read_targets,
    replay_photos,
    summarize,
    write_rows,
)

lookAtSpheroid = pytest.importorskip("pymap3d.los").lookAtSpheroid

W, H = 800, 600  # full-resolution size of the test photos (EXIF PixelXDimension x PixelYDimension)
LAT, LON = 36.52, -84.21  # inside the bundled 15' EGM96 crop (egm96_jacksboro.tif)

#: The drone-dji properties of a nadir photo, as DJI writes them (signed decimals, 2 digits for angles).
BASE_TAGS = {
    "GpsLatitude": f"{LAT:.8f}",
    "GpsLongitude": f"{LON:.8f}",
    "AbsoluteAltitude": "+412.60",
    "RelativeAltitude": "+100.20",
    "GimbalRollDegree": "+0.00",
    "GimbalYawDegree": "+37.50",
    "GimbalPitchDegree": "-90.00",
    "FlightRollDegree": "+2.50",
    "FlightYawDegree": "+36.90",
    "FlightPitchDegree": "-4.50",
    "FlightXSpeed": "+0.50",
    "FlightYSpeed": "-2.90",
    "FlightZSpeed": "+0.00",
    "CamReverse": "0",
    "GimbalReverse": "0",
    "SelfData": "Undefined",
    "CalibratedFocalLength": "700.000000",
    "CalibratedOpticalCenterX": "400.000000",
    "CalibratedOpticalCenterY": "300.000000",
    "RtkFlag": "16",
}


def xmp_packet(tags: dict, form: str = "attributes") -> bytes:
    """An XMP packet as DJI's cameras write it (``form="attributes"``), or with child elements."""
    ns = (
        'xmlns:tiff="http://ns.adobe.com/tiff/1.0/" xmlns:exif="http://ns.adobe.com/exif/1.0/" '
        'xmlns:xmp="http://ns.adobe.com/xap/1.0/" xmlns:xmpMM="http://ns.adobe.com/xap/1.0/mm/" '
        'xmlns:dc="http://purl.org/dc/elements/1.1/" xmlns:crs="http://ns.adobe.com/camera-raw-settings/1.0/" '
        f'xmlns:drone-dji="{DJI_NS}"'
    )
    if form == "attributes":
        attrs = "\n    ".join(f'drone-dji:{k}="{v}"' for k, v in tags.items())
        desc = (
            f'  <rdf:Description rdf:about="DJI Meta Data"\n    {ns}\n    tiff:Make="DJI"\n'
            f'    tiff:Model="FC6310R"\n    dc:format="image/jpg"\n    {attrs}\n    crs:Version="7.0"\n'
            '    crs:HasSettings="False">\n   <xmpMM:Version>1</xmpMM:Version>\n  </rdf:Description>\n'
        )
    else:
        elems = "\n".join(f"   <drone-dji:{k}>{v}</drone-dji:{k}>" for k, v in tags.items())
        desc = f'  <rdf:Description rdf:about="" {ns}>\n   <tiff:Make>DJI</tiff:Make>\n{elems}\n  </rdf:Description>\n'
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        f"{desc} </rdf:RDF>\n</x:xmpmeta>\n" + " " * 200 + '\n<?xpacket end="w"?>'
    ).encode("utf-8")


def _dms(deg):
    a = abs(deg)
    d = int(a)
    m = int((a - d) * 60)
    return (float(d), float(m), (a - d - m / 60) * 3600)


def exif_block(lat=LAT, lon=LON, alt=412.6, full=(W, H), make="DJI", model="FC6310R") -> Image.Exif:
    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = make, model
    gps = ex.get_ifd(0x8825)
    if lat is not None:
        gps[1], gps[2] = ("N" if lat >= 0 else "S"), _dms(lat)
        gps[3], gps[4] = ("E" if lon >= 0 else "W"), _dms(lon)
    if alt is not None:
        gps[5], gps[6] = b"\x00", abs(alt)
    if full is not None:
        sub = ex.get_ifd(0x8769)
        sub[0xA002], sub[0xA003] = full
    return ex


def make_jpeg(path, tags=None, drop=(), size=(W, H), form="attributes", exif=None):
    """A JPEG with DJI's XMP (BASE_TAGS updated by ``tags``, without ``drop``) and EXIF."""
    t = {**BASE_TAGS, **(tags or {})}
    for k in drop:
        t.pop(k, None)
    Image.new("RGB", size, (90, 120, 60)).save(
        path, exif=exif if exif is not None else exif_block(), xmp=xmp_packet(t, form), quality=70
    )
    return path


def make_tiff(path, tags=None, size=(W, H)):
    """A TIFF with the XMP in tag 700 and EXIF/GPS sub-IFDs (as DJI's multispectral cameras write)."""
    t = {**BASE_TAGS, **(tags or {})}
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[271], info[272] = "DJI", "FC6360"
    info[700] = xmp_packet(t)
    info[34853] = {1: "N", 2: _dms(LAT), 3: "W", 4: _dms(LON), 5: b"\x00", 6: 412.6}
    info[34665] = {0xA002: W, 0xA003: H}
    Image.new("L", size, 100).save(path, tiffinfo=info)
    return path


def write_targets(path, rows, header="image,row,col"):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


# --------------------------------------------------------------------------- reading


@pytest.mark.parametrize("form", ["attributes", "elements"])
def test_read_jpeg_both_xmp_forms(tmp_path, form):
    m = read_photo(make_jpeg(tmp_path / f"DJI_{form}.JPG", form=form))
    assert (m.width, m.height, m.exif_width, m.exif_height) == (W, H, W, H)
    assert (m.make, m.model) == ("DJI", "FC6310R")
    assert m.lat_deg == pytest.approx(LAT, abs=1e-12) and m.lon_deg == pytest.approx(LON, abs=1e-12)
    assert m.position_source.startswith("drone-dji")
    assert (m.absolute_altitude_m, m.relative_altitude_m) == (412.6, 100.2)
    assert (m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg) == (37.5, -90.0, 0.0)
    assert (m.flight_yaw_deg, m.flight_pitch_deg, m.flight_roll_deg) == (36.9, -4.5, 2.5)
    assert (m.calibrated_focal_px, m.calibrated_center_x_px, m.calibrated_center_y_px) == (700.0, 400.0, 300.0)
    assert m.rtk_flag == 16 and m.dewarp is None and not m.resized and m.missing == ()
    assert m.xmp["SelfData"] == "Undefined"
    assert m.gps_altitude_m == pytest.approx(412.6)


def test_read_tiff_xmp_in_tag_700(tmp_path):
    m = read_photo(make_tiff(tmp_path / "IMG_0001_1.TIF"))
    assert (m.width, m.height, m.exif_width) == (W, H, W)
    assert (m.make, m.model) == ("DJI", "FC6360")
    assert (m.gimbal_pitch_deg, m.gimbal_yaw_deg) == (-90.0, 37.5)
    assert m.lat_deg == pytest.approx(LAT, abs=1e-12)


def test_exif_gps_only_south_west(tmp_path):
    # no drone-dji position: the EXIF GPS IFD's degrees-minutes-seconds and S/W references
    lat, lon = -33.8675, 151.2070 * -1
    p = make_jpeg(tmp_path / "exif_only.jpg", drop=("GpsLatitude", "GpsLongitude"), exif=exif_block(lat=lat, lon=lon))
    m = read_photo(p)
    assert m.position_source == "EXIF GPS"
    assert m.lat_deg == pytest.approx(lat, abs=1e-9) and m.lon_deg == pytest.approx(lon, abs=1e-9)


def test_dji_longtitude_spelling(tmp_path):
    # older DJI firmware (Phantom 4 RTK) writes drone-dji:GpsLongtitude
    p = make_jpeg(tmp_path / "p4rtk.jpg", tags={"GpsLongtitude": "-84.10000000"}, drop=("GpsLongitude",))
    assert read_photo(p).lon_deg == -84.1


def test_missing_gimbal_tags_name_the_file_and_tags(tmp_path):
    p = make_jpeg(tmp_path / "no_gimbal.jpg", drop=("GimbalYawDegree", "GimbalPitchDegree"))
    with pytest.raises(PhotoTagError) as e:
        read_photo(p)
    msg = str(e.value)
    assert "no_gimbal.jpg" in msg and "GimbalYawDegree" in msg and "GimbalPitchDegree" in msg
    assert "GimbalRollDegree" not in msg
    m = read_photo(p, require=False)
    assert m.missing == ("drone-dji:GimbalYawDegree", "drone-dji:GimbalPitchDegree")


def test_photo_without_xmp(tmp_path):
    p = tmp_path / "plain.jpg"
    Image.new("RGB", (40, 30)).save(p, exif=exif_block())
    with pytest.raises(PhotoTagError, match=r"plain\.jpg.*GimbalYawDegree"):
        read_photo(p)
    assert "no XMP packet" in read_photo(p, require=False).notes[0]


def test_xmp_with_entities_is_refused(tmp_path):
    bomb = (
        b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY a "aaaa"><!ENTITY b "&a;&a;&a;">]>'
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/">&b;</x:xmpmeta>'
    )
    with pytest.raises(ValueError, match="refused"):
        parse_xmp(bomb, "bomb.jpg")
    p = tmp_path / "bomb.jpg"
    Image.new("RGB", (40, 30)).save(p, xmp=bomb)
    with pytest.raises(ValueError, match=r"bomb\.jpg"):
        read_photo(p)


def test_broken_jpeg_segment_names_the_file(tmp_path):
    data = bytearray(make_jpeg(tmp_path / "ok.jpg").read_bytes())
    k = data.index(b"http://ns.adobe.com/xap/1.0/") - 4  # the XMP APP1 marker
    assert data[k : k + 2] == b"\xff\xe1"
    data[k + 2 : k + 4] = b"\xff\xff"  # a length past the end of the file
    bad = tmp_path / "broken.jpg"
    bad.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"broken\.jpg: JPEG segment 0xFFE1 at byte \d+ has length 65535"):
        read_photo(bad)


def test_rdf_alt_value_and_attribute_precedence():
    pkt = xmp_packet({"GimbalYawDegree": "+10.00"}, "elements").replace(
        b"<drone-dji:GimbalYawDegree>+10.00</drone-dji:GimbalYawDegree>",
        b"<drone-dji:GimbalYawDegree><rdf:Alt><rdf:li>+11.00</rdf:li></rdf:Alt></drone-dji:GimbalYawDegree>",
    )
    dji, tiff = parse_xmp(pkt)
    assert dji["GimbalYawDegree"] == "+11.00" and tiff["Make"] == "DJI"


# --------------------------------------------------------------------------- DewarpData and lenses

#: DewarpData of a public DJI Phantom 4 RTK photo (FC6310R, 5472 x 3648), as exiftool prints it
#: (Agisoft forum, "Import Calibration data from DJI XMP data", 2020).
P4RTK_DEWARP = (
    " 2018-09-06;3684.480000000000,3677.570000000000,2.240000000000,22.050000000000,"
    "-0.263482000000,0.106788000000,0.000037110700,-0.000327247000,-0.030078300000"
)


def test_parse_dewarp_data_literal():
    d = parse_dewarp_data(P4RTK_DEWARP)
    assert d == DewarpData(
        "2018-09-06", 3684.48, 3677.57, 2.24, 22.05, -0.263482, 0.106788, 0.0000371107, -0.000327247, -0.0300783
    )
    with pytest.raises(ValueError, match="9 finite numbers"):
        parse_dewarp_data("2018-09-06;1,2,3")
    with pytest.raises(ValueError, match="not numbers"):
        parse_dewarp_data("2018-09-06;a,b,c,d,e,f,g,h,i")
    assert parse_dewarp_data("0,0,0,0,0,0,0,0,0").is_zero


def test_dewarp_lens_offset_principal_point(tmp_path):
    # the Phantom 4 RTK's full-resolution calibration, on a photo shared at a quarter of its size
    p = make_jpeg(
        tmp_path / "p4rtk_small.jpg",
        tags={
            "DewarpData": P4RTK_DEWARP,
            "DewarpFlag": "0",
            "CalibratedOpticalCenterX": "2736.000000",
            "CalibratedOpticalCenterY": "1824.000000",
        },
        size=(1368, 912),
        exif=exif_block(full=(5472, 3648)),
    )
    m = read_photo(p)
    assert m.resized and any("resized photo" in n for n in m.notes)
    full = lens_from_photo(
        read_photo(
            make_jpeg(
                tmp_path / "p4rtk_full.jpg",
                size=(5472, 3648),
                tags={"DewarpData": P4RTK_DEWARP},
                exif=exif_block(full=(5472, 3648)),
            )
        )
    )
    assert isinstance(full, BrownLens)
    # principal point: image centre (W/2, H/2, corner origin) + DewarpData's offsets, in OpenCV's
    # 0-based pixel centres: 2736 + 2.24 - 0.5, 1824 + 22.05 - 0.5
    assert (full.fx, full.fy) == (3684.48, 3677.57)
    assert full.cx == pytest.approx(2737.74, abs=1e-9) and full.cy == pytest.approx(1845.55, abs=1e-9)
    assert (full.k1, full.k2, full.p1, full.p2, full.k3) == (
        -0.263482,
        0.106788,
        0.0000371107,
        -0.000327247,
        -0.0300783,
    )
    small = lens_from_photo(m)
    assert (small.width, small.height) == (1368, 912)
    assert small.fx == pytest.approx(3684.48 / 4) and small.fy == pytest.approx(3677.57 / 4)
    # corner-origin scaling: (u + 0.5) scales with the image
    assert small.cx == pytest.approx((2737.74 + 0.5) / 4 - 0.5) and small.cy == pytest.approx((1845.55 + 0.5) / 4 - 0.5)
    assert small.k1 == full.k1 and small.p2 == full.p2
    # the same ray through both: a full-resolution pixel and its resized position
    u, v = 4000.0, 500.0
    d_full = full.unproject(u, v)
    d_small = small.unproject((u + 0.5) / 4 - 0.5, (v + 0.5) / 4 - 0.5)
    np.testing.assert_allclose(d_small, d_full, atol=1e-12)


def test_dewarp_flag_1_gives_a_pinhole(tmp_path):
    m = read_photo(
        make_jpeg(
            tmp_path / "dewarped.jpg",
            tags={"DewarpData": "2020-01-01;702.0,701.0,3.0,-2.0,-0.2,0.1,0.0,0.0,0.0", "DewarpFlag": "1"},
        )
    )
    lens = lens_from_photo(m)
    assert isinstance(lens, PinholeLens)
    assert (lens.fx, lens.fy, lens.cx, lens.cy) == (702.0, 701.0, 400 + 3.0 - 0.5, 300 - 2.0 - 0.5)


def test_calibrated_focal_pinhole_and_conventions(tmp_path):
    s = sensor_from_photo(read_photo(make_jpeg(tmp_path / "a.jpg")))
    assert s.gimbal is PRESETS["yaw-pitch-roll"] and isinstance(s.lens, PinholeLens)
    # DJI's optical centre (400, 300) = W/2, H/2: OpenCV (399.5, 299.5), the 1-based image centre
    assert (s.lens.cx, s.lens.cy) == (399.5, 299.5)
    assert (s.params["cx"], s.params["cy"]) == s.center_pixel[::-1] == (400.5, 300.5)
    assert "DJI FC6310R" in s.name


def test_no_lens_tags(tmp_path):
    m = read_photo(make_jpeg(tmp_path / "nolens.jpg", drop=("CalibratedFocalLength",)))
    with pytest.raises(PhotoTagError, match=r"nolens\.jpg.*CalibratedFocalLength"):
        lens_from_photo(m)


def test_scale_lens_round_trip():
    lens = BrownLens(fx=1000.0, fy=990.0, cx=511.7, cy=380.2, width=1024, height=768, k1=-0.1, p1=1e-4)
    back = scale_lens(scale_lens(lens, 512, 384), 1024, 768)
    for k in ("fx", "fy", "cx", "cy", "k1", "p1"):
        assert getattr(back, k) == pytest.approx(getattr(lens, k), abs=1e-12)


# --------------------------------------------------------------------------- geolocation oracles


def _flat_dem(h=250.0, datum="ellipsoid"):
    return DEM.from_array(
        np.full((41, 41), h) + np.arange(41)[None, :] * 0.5, LAT + 0.02, LON - 0.02, 0.001, 0.001, datum=datum
    )


def test_nadir_principal_point_is_below_the_camera(tmp_path):
    # gimbal pitch -90 (whatever the airframe's attitude): the principal point's ray is the
    # ellipsoid normal, so the ground point has the camera's latitude and longitude and the DEM's height
    tags = {"DewarpData": "2019-05-05;705.5,704.0,6.25,-4.75,-0.12,0.05,0.0001,-0.0002,-0.01", "DewarpFlag": "0"}
    p = make_jpeg(tmp_path / "nadir.jpg", tags=tags)
    # principal point: OpenCV (400 + 6.25 - 0.5, 300 - 4.75 - 0.5), 1-based +1
    col, row = 400 + 6.25 + 0.5, 300 - 4.75 + 0.5
    t = write_targets(tmp_path / "t.csv", [["nadir.jpg", row, col]])
    dem = _flat_dem(datum="egm96")
    rows, _ = replay_photos([p], t, surface=surface_for(dem=dem))
    (r,) = rows
    assert r["status"] == "ok" and r["h_datum"] == ELLIPSOID_DATUM
    assert r["lat_deg"] == pytest.approx(LAT, abs=1e-10) and r["lon_deg"] == pytest.approx(LON, abs=1e-10)
    h_dem = float(dem.height(np.deg2rad(LAT), np.deg2rad(LON)))
    assert r["h_m"] == pytest.approx(h_dem, abs=1e-4)
    assert r["slant_range_m"] == pytest.approx(r["sensor_h_m"] - h_dem, abs=1e-3)
    assert r["lens"] == "brown (DewarpData)"
    from test_mgrs import oracle  # pyproj's UTM and the standard's letters

    assert r["mgrs"] == oracle(r["lat_deg"], r["lon_deg"])


def test_nadir_image_top_points_along_gimbal_yaw(tmp_path):
    # at nadir the image's top is the gimbal yaw's direction: a pixel above the centre lies that way
    p = make_jpeg(tmp_path / "up.jpg", tags={"GimbalYawDegree": "+90.00"})  # image top = east
    t = write_targets(
        tmp_path / "t.csv",
        [["up.jpg", 100.5, 400.5], ["up.jpg", 300.5, 700.5]],
    )
    rows, _ = replay_photos([p], t, surface=surface_for(dem=_flat_dem()))
    assert rows[0]["lon_deg"] > LON and rows[0]["lat_deg"] == pytest.approx(LAT, abs=2e-6)
    assert rows[1]["lat_deg"] < LAT  # image right = south when the top is east


@pytest.mark.parametrize("yaw, pitch", [(120.0, -35.0), (-47.3, -62.0), (200.0, -15.0)])
def test_oblique_matches_pymap3d_look_at_spheroid(tmp_path, yaw, pitch):
    # zero gimbal roll: the principal point looks at azimuth = gimbal yaw, tilt from nadir
    # = 90 + gimbal pitch; pymap3d intersects the ellipsoid (h = 0) on its own. A pixel straight
    # below it on the image's vertical centre line looks atan(dv / fy) lower (pinhole).
    p = make_jpeg(
        tmp_path / "obl.jpg",
        tags={"GimbalYawDegree": f"{yaw:+.2f}", "GimbalPitchDegree": f"{pitch:+.2f}", "AbsoluteAltitude": "+150.00"},
    )
    dv = 120.0
    t = write_targets(
        tmp_path / "t.csv",
        [["obl.jpg", 300.5, 400.5, 0.0], ["obl.jpg", 300.5 + dv, 400.5, 0.0]],
        header="image,row,col,truth_h_m",
    )
    rows, msgs = replay_photos([p], t, altitude_datum="ellipsoid")
    assert msgs == []
    assert all(r["status"] == "ok" for r in rows)
    assert rows[0]["sensor_h_m"] == 150.0 and rows[0]["altitude_datum"].startswith("ellipsoid")
    for r, extra in zip(rows, (0.0, math.degrees(math.atan(dv / 700.0)))):
        lat, lon, rng = lookAtSpheroid(LAT, LON, 150.0, yaw, 90.0 + pitch - extra)
        # Same ellipsoid, same ray: only rounding separates the two intersections (ECEF
        # coordinates of 6.4e6 m in float64, the lens's Newton inversion to 1e-14; measured
        # differences are ~1e-8 m). 1e-9 deg is 0.1 mm on the ground; a wrong sign, pixel
        # convention or focal scaling moves the point by metres.
        assert r["lat_deg"] == pytest.approx(float(lat), abs=1e-9)
        assert r["lon_deg"] == pytest.approx(float(lon), abs=1e-9)
        assert r["slant_range_m"] == pytest.approx(float(rng), abs=1e-5)
        assert r["h_m"] == pytest.approx(0.0, abs=1e-6)


def test_resized_photo_locates_like_the_full_one(tmp_path):
    # the same capture at full size and at half size (raster 400 x 300, EXIF still 800 x 600)
    tags = {"GimbalPitchDegree": "-50.00", "DewarpData": "2021-03-03;705.0,703.0,5.0,-3.0,-0.15,0.04,0.0,0.0,0.0"}
    full = make_jpeg(tmp_path / "full.jpg", tags=tags)
    half = make_jpeg(tmp_path / "half.jpg", tags=tags, size=(W // 2, H // 2))
    m = read_photo(half)
    lens = lens_from_photo(m)
    assert (lens.width, lens.height) == (400, 300)
    assert lens.fx == 352.5 and lens.fy == 351.5
    assert lens.cx == pytest.approx((400 + 5.0) / 2 - 0.5) and lens.cy == pytest.approx((300 - 3.0) / 2 - 0.5)
    # full-resolution 1-based (row, col) -> half-size: (x - 0.5) / 2 + 0.5
    px = [(150.5, 600.5), (500.0, 80.0)]
    t = write_targets(
        tmp_path / "t.csv",
        [["full.jpg", r, c] for r, c in px] + [["half.jpg", (r - 0.5) / 2 + 0.5, (c - 0.5) / 2 + 0.5] for r, c in px],
    )
    rows, msgs = replay_photos([full, half], t, surface=surface_for(dem=_flat_dem()))
    assert any("half.jpg: resized photo" in s and "400 x 300" in s for s in msgs)
    for a, b in zip(rows[:2], rows[2:]):
        assert b["lat_deg"] == pytest.approx(a["lat_deg"], abs=1e-10)
        assert b["lon_deg"] == pytest.approx(a["lon_deg"], abs=1e-10)


def test_user_sensor_overrides_the_lens(tmp_path):
    p = make_jpeg(tmp_path / "s.jpg", size=(W // 2, H // 2))
    own = FrameSensor(
        BrownLens(fx=650.0, fy=650.0, cx=399.5, cy=299.5, width=W, height=H, k1=-0.1),
        gimbal=PRESETS["yaw-pitch-roll"],
        name="calibrated",
    )
    t = write_targets(tmp_path / "t.csv", [["s.jpg", 150.5, 200.5]])
    rows, msgs = replay_photos([p], t, sensor=own, surface=surface_for(dem=_flat_dem()))
    assert rows[0]["lens"] == "sensor file calibrated, scaled to the resized raster"
    wrong = FrameSensor(own.lens, name="q17")  # the roll-pitch gimbal: not DJI's angles
    rows, msgs = replay_photos([p], t, sensor=wrong, surface=surface_for(dem=_flat_dem()))
    assert rows == [] and any("s.jpg" in s and "yaw-pitch-roll" in s for s in msgs)


# --------------------------------------------------------------------------- datums


def test_altitude_datum_egm96_against_nga_test_value(tmp_path):
    # NGA's EGM96 test point (F477 program, OUTINTPT.DAT): N(38.6281550 N, 269.7791550 E) = -31.628 m.
    # It lies outside the bundled 15' crops: the global 30' copy holds it (its documented error:
    # RMS 0.15 m, 99 % within 0.61 m; here 0.04 m), hence the 0.1 m tolerance.
    lat, lon = 38.6281550, 269.7791550 - 360.0
    p = make_jpeg(
        tmp_path / "stl.jpg",
        tags={
            "GpsLatitude": f"{lat:.8f}",
            "GpsLongitude": f"{lon:.8f}",
            "AbsoluteAltitude": "+300.00",
            "GimbalPitchDegree": "-45.00",
        },
    )
    t = write_targets(tmp_path / "t.csv", [["stl.jpg", 300.5, 400.5, 140.0]], header="image,row,col,truth_h_m")
    (r,), _ = replay_photos([p], t)
    assert r["geoid_undulation_m"] == pytest.approx(-31.628, abs=0.1)
    assert r["sensor_h_m"] == pytest.approx(300.0 + r["geoid_undulation_m"], abs=1e-9)
    assert "EGM96" in r["altitude_datum"] and r["h_datum"] == ELLIPSOID_DATUM
    (r2,), _ = replay_photos([p], t, altitude_datum="ellipsoid")
    assert r2["sensor_h_m"] == 300.0 and r2["altitude_datum"].startswith("ellipsoid")
    # inside the bundled 15' crop the conversion uses that grid
    m = read_photo(make_jpeg(tmp_path / "j.jpg"))
    assert pose_from_photo(m).h == pytest.approx(412.6 + float(egm96_undulation(np.deg2rad(LAT), np.deg2rad(LON))))


def test_rtk_photo_warns_about_the_datum(tmp_path):
    p = make_jpeg(tmp_path / "rtk.jpg", tags={"RtkFlag": "50"})
    t = write_targets(tmp_path / "t.csv", [["rtk.jpg", 300.5, 400.5]])
    _, msgs = replay_photos([p], t, surface=surface_for(dem=_flat_dem()))
    assert any("rtk.jpg: RtkFlag = 50" in s and "altitude_datum='ellipsoid'" in s for s in msgs)
    _, msgs = replay_photos([p], t, surface=surface_for(dem=_flat_dem()), altitude_datum="ellipsoid")
    assert not any("RtkFlag" in s for s in msgs)


def test_altitude_check_against_relative_altitude(tmp_path):
    # camera 412.6 + N ~ 382 m, the DEM at ~260 m: ~122 m above it, RelativeAltitude 100.2 is within 30 m;
    # a DEM at 0 m puts the camera ~382 m above it: the check speaks
    p = make_jpeg(tmp_path / "chk.jpg")
    t = write_targets(tmp_path / "t.csv", [["chk.jpg", 300.5, 400.5]])
    _, msgs = replay_photos([p], t, surface=surface_for(dem=_flat_dem()))
    assert not any("altitude check" in s for s in msgs)
    _, msgs = replay_photos([p], t, surface=surface_for(dem=_flat_dem(h=0.0)))
    assert any("chk.jpg: altitude check" in s and "RelativeAltitude" in s for s in msgs)


# --------------------------------------------------------------------------- the replay's messages and file


def test_bad_photo_is_reported_and_skipped_others_run(tmp_path):
    good = make_jpeg(tmp_path / "good.jpg")
    bad = make_jpeg(tmp_path / "bad.jpg", drop=("GimbalYawDegree", "GimbalPitchDegree", "GimbalRollDegree"))
    t = write_targets(
        tmp_path / "t.csv",
        [
            ["good.jpg", 300.5, 400.5, LAT, LON],
            ["bad.jpg", 10, 10, LAT, LON],
            ["good", 5000, 10, LAT, LON],  # the stem names the photo too
            ["missing.jpg", 10, 10, LAT, LON],
            ["good.jpg", "x", 10, LAT, LON],
        ],
        header="image,row,col,truth_lat_deg,truth_lon_deg",
    )
    junk = tmp_path / "junk.jpg"
    junk.write_text("not an image")
    rows, msgs = replay_photos([good, bad, junk], t, surface=surface_for(dem=_flat_dem()))
    assert [r["image"] for r in rows] == ["good.jpg", "good"]
    assert any(s.startswith("junk.jpg: skipped:") for s in msgs)
    assert rows[0]["status"] == "ok" and rows[0]["error_to_truth_m"] == pytest.approx(0.0, abs=1e-4)
    assert rows[1]["status"] == "outside_sensor" and rows[1]["lat_deg"] is None
    text = "\n".join(msgs)
    assert "bad.jpg: cannot be geolocated: missing tag(s) drone-dji:GimbalYawDegree" in text
    assert "bad.jpg: 1 target(s) skipped" in text
    assert "image 'missing.jpg' is not among the photos given" in text
    assert "line 6: row = 'x' is not a finite number" in text
    assert "line 4 (good.jpg): pixel row 5000" in text


def test_no_dem_needs_truth_heights(tmp_path):
    p = make_jpeg(tmp_path / "a.jpg")
    t = write_targets(tmp_path / "t.csv", [["a.jpg", 300.5, 400.5]])
    with pytest.raises(ValueError, match="no DEM.*truth_h_m"):
        replay_photos([p], t)
    t2 = write_targets(
        tmp_path / "t2.csv",
        [["a.jpg", 300.5, 400.5, ""], ["a.jpg", 300.5, 400.5, 250.0]],
        header="image,row,col,truth_h_m",
    )
    rows, msgs = replay_photos([p], t2)
    assert len(rows) == 1 and rows[0]["h_m"] == pytest.approx(250.0, abs=1e-6)
    assert any("line 2" in s and "no truth_h_m" in s for s in msgs)


def test_targets_file_errors(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("image,row\na.jpg,1\n")
    with pytest.raises(ValueError, match=r"\['col'\] missing"):
        read_targets(bad)
    bom = tmp_path / "bom.csv"
    bom.write_text("\ufeffimage,row,col,point\na.jpg,1,2,P1\n", encoding="utf-8")
    targets, header, _ = read_targets(bom)
    assert header[0] == "image" and targets[0]["point"] == "P1"


def test_write_rows_reads_back_in_the_gis_reader(tmp_path):
    p = make_jpeg(tmp_path / "w.jpg", tags={"GimbalPitchDegree": "-60.00"})
    t = write_targets(
        tmp_path / "t.csv",
        [["w.jpg", 200.5, 300.5, "P7", 36.5201, -84.2101, 255.0]],
        header="image,row,col,point,truth_lat_deg,truth_lon_deg,truth_h_m",
    )
    rows, msgs = replay_photos([p], t, surface=surface_for(dem=_flat_dem()))
    out = tmp_path / "out.csv"
    write_rows(out, rows)
    table = read_results(out)
    assert table["image"] == ["w.jpg"] and table["point"] == ["P7"] and table["status"] == ["ok"]
    assert table["lat_deg"][0] == rows[0]["lat_deg"]  # full precision
    assert table["h_datum"] == [ELLIPSOID_DATUM]
    assert np.isfinite(table["error_to_truth_m"][0]) and np.isfinite(table["vertical_error_m"][0])
    assert table["sensor_h_m"][0] == pytest.approx(rows[0]["sensor_h_m"])
    assert "w.jpg: 1/1 targets located" in summarize(rows, msgs)


# --------------------------------------------------------------------------- one target in several photos


def _photos_around(tmp_path, g_h, n=3, dist=150.0):
    """``n`` nadir-free photos from around a ground point G = (LAT, LON, g_h), each looking near
    it; the pixel that sees G in each, from the photo's own sensor and pose as read back."""
    import pyproj

    from geoloc.io.photos import pose_from_photo, read_photo, sensor_from_photo
    from geoloc.status import Status

    geod = pyproj.Geod(ellps="WGS84")
    paths, pixels = [], []
    for i in range(n):
        az = 30.0 + 360.0 * i / n
        lon, lat, back = geod.fwd(LON, LAT, az, dist)
        h_cam = 412.6 + float(egm96_undulation(math.radians(lat), math.radians(lon)))  # AbsoluteAltitude, EGM96
        pitch = -math.degrees(math.atan2(h_cam - g_h, dist))
        tags = {
            "GpsLatitude": f"{lat:.8f}",
            "GpsLongitude": f"{lon:.8f}",
            "GimbalYawDegree": f"{(back + 180) % 360 - 180:+.2f}",
            "GimbalPitchDegree": f"{pitch:+.2f}",
        }
        p = make_jpeg(tmp_path / f"p{i}.jpg", tags=tags, exif=exif_block(lat=lat, lon=lon))
        meta = read_photo(p)
        px = sensor_from_photo(meta).ground_to_pixel(math.radians(LAT), math.radians(LON), g_h, pose_from_photo(meta))
        assert int(np.asarray(px.status)) == Status.OK
        paths.append(p)
        pixels.append((float(np.asarray(px.row)), float(np.asarray(px.col))))
    return paths, pixels


def test_a_target_id_in_the_targets_file_is_triangulated_from_its_photos(tmp_path, capsys):
    """Triangulation from drone photos: the pixel that sees G in each of three photos, one
    ``target_id``: the rays' intersection is G (pyproj's ECEF, not the code under test) to a
    millimetre; a DEM 30 m above G is reported as a likely DEM or datum error (+30 m, the DEM's own
    offset), a DEM through G is not."""
    import pyproj

    from geoloc.cli import main
    from geoloc.status import Status

    g_h = 250.0
    paths, pixels = _photos_around(tmp_path, g_h)
    rows = [[p.name, r, c, "G", g_h] for p, (r, c) in zip(paths, pixels)]
    rows.append([paths[0].name, 300.5, 400.5, "alone", g_h])  # named once: not triangulated
    t = write_targets(tmp_path / "t.csv", rows, header="image,row,col,target_id,truth_h_m")
    G = np.array(pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(LON, LAT, g_h))
    for offset, warned in ((30.0, True), (0.0, False)):
        dem = DEM.from_array(np.full((41, 41), g_h + offset), LAT + 0.02, LON - 0.02, 0.001, 0.001)
        found = []
        out, _ = replay_photos(paths, t, surface=surface_for(dem=dem), targets_out=found)
        assert len(out) == 4 and [r.target_id for r in found] == ["G"]
        tri = found[0].tri
        assert tri.status == Status.OK and tri.n_rays == 3
        # each ray passes through G (ground_to_pixel's inversion: 1e-9 px over 200 m): they meet there
        assert np.linalg.norm(np.asarray(tri.ecef) - G) < 1e-3
        assert np.nanmax(tri.residual_m) < 1e-3
        s = found[0].surface
        # a level DEM: every photo's hit is at its height, the offset above G (the solver's 1e-3 m)
        assert s["mean_m"] == pytest.approx(offset, abs=1e-2)
        assert bool(s["warning"]) == warned and (not warned or "likely DEM or datum error" in s["warning"])
    # the command line prints the target (located at truth_h_m: no DEM)
    assert main(["replay", *map(str, paths), "--targets", str(t)]) == 0
    text = capsys.readouterr().out
    assert f"target G: {LAT:.7f} {LON:.7f} h {g_h:.1f} m" in text and "from 3 rays" in text
    assert "target alone" not in text
