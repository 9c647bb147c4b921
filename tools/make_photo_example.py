"""Make the bundled drone-photo example: one synthetic DJI JPEG and its targets (seeded).

``python tools/make_photo_example.py`` writes ``assets/photos/DJI_0001.JPG`` (an
800 x 600 picture carrying EXIF and DJI's XMP as a Phantom 4 RTK-like camera
writes them) and ``assets/photos/targets.csv`` (five pixels with their surveyed
truth). How: the truth is each pixel located on the bundled SRTM crop from the
photo's *true* tags; the photo then carries tags with errors of the size real
ones have (gimbal yaw +0.4 deg, pitch -0.2 deg, altitude +3 m), so the replay's
errors to truth are what those errors cost. Example data, not a test oracle.

The picture is rendered by geoloc from the *true* tags
(:func:`geoloc.workflows.render.render_frame`: every pixel's exact hit on the DEM,
coloured from the hillshade of the SRTM crop with a 0.0001 deg graticule and the five
surveyed targets painted as red crosses, ``CROSS_ARM_M`` and ``CROSS_WIDTH_M``), so
each cross sits on its target's pixel and the tags' errors show as the distance
between a cross and the reprojection of its survey. The EXIF and XMP segments are
those of the tags alone (the pixels do not enter them): the replay's figures do not
depend on the picture.
"""

from __future__ import annotations

import math
from pathlib import Path

from PIL import Image

from geoloc.geodesy.geoid import egm96_undulation
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.photo_replay import replay_photos

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "assets" / "photos"
DJI_NS = "http://www.dji.com/drone-dji/1.0/"
W, H = 800, 600
LAT, LON = 36.60, -84.23
#: The painted targets: half-length and width of each bar [m] (about 12 x 3 px at the 0.25 m
#: ground sample of the image centre).
CROSS_ARM_M, CROSS_WIDTH_M = 3.0, 0.8
#: Graticule spacing [deg] (about 11 m north-south): the SRTM relief is smooth at this scale.
GRATICULE_DEG = 1e-4
#: JPEG quality of the rendered picture.
QUALITY = 85


def xmp_packet(tags: dict) -> bytes:
    """An XMP packet with the drone-dji properties as attributes of rdf:Description, as DJI writes it."""
    attrs = "\n    ".join(f'drone-dji:{k}="{v}"' for k, v in tags.items())
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        f'  <rdf:Description rdf:about="DJI Meta Data" xmlns:tiff="http://ns.adobe.com/tiff/1.0/"\n'
        f'    xmlns:drone-dji="{DJI_NS}" tiff:Make="DJI" tiff:Model="FC6310R"\n    {attrs}/>\n'
        ' </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end="w"?>'
    ).encode("utf-8")


def exif_block(alt: float) -> Image.Exif:
    def dms(deg):
        a = abs(deg)
        d, m = int(a), int((abs(deg) - int(a)) * 60)
        return (float(d), float(m), (a - d - m / 60) * 3600)

    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = "DJI", "FC6310R"
    gps = ex.get_ifd(0x8825)
    gps[1], gps[2], gps[3], gps[4] = "N", dms(LAT), "W", dms(LON)
    gps[5], gps[6] = b"\x00", abs(alt)
    sub = ex.get_ifd(0x8769)
    sub[0xA002], sub[0xA003] = W, H
    return ex


def tags(alt, yaw, pitch):
    return {
        "GpsLatitude": f"{LAT:.8f}",
        "GpsLongitude": f"{LON:.8f}",
        "AbsoluteAltitude": f"{alt:+.2f}",
        "RelativeAltitude": "+150.00",
        "GimbalRollDegree": "+0.00",
        "GimbalYawDegree": f"{yaw:+.2f}",
        "GimbalPitchDegree": f"{pitch:+.2f}",
        "FlightRollDegree": "+1.80",
        "FlightYawDegree": f"{yaw - 1.2:+.2f}",
        "FlightPitchDegree": "-3.10",
        "CalibratedFocalLength": "690.000000",
        "CalibratedOpticalCenterX": "400.000000",
        "CalibratedOpticalCenterY": "300.000000",
        "DewarpData": "2024-05-14;690.10,690.10,1.25,-0.80,-0.2680,0.1110,0.00090,-0.00060,-0.0240",
        "DewarpFlag": "0",
        "RtkFlag": "0",
    }


def write(path, alt, yaw, pitch, image=None, quality=60):
    """The JPEG with its EXIF and XMP; ``image`` (H, W, 3) uint8, default a flat grey-green."""
    pic = Image.new("RGB", (W, H), (96, 120, 70)) if image is None else Image.fromarray(image)
    pic.save(path, exif=exif_block(alt), xmp=xmp_packet(tags(alt, yaw, pitch)), quality=quality)


def render(photo, dem, truths):
    """The picture seen from ``photo``'s tags (the true ones), the ``truths`` painted as crosses."""
    from geoloc.io.photos import photo_sensor, pose_from_photo, read_photo
    from geoloc.workflows.render import Cross, ground_texture, render_frame

    meta = read_photo(photo)
    s, _ = photo_sensor(meta)
    tex = ground_texture(
        dem,
        [Cross(la, lo, CROSS_ARM_M, CROSS_WIDTH_M, f"T{k + 1}") for k, (la, lo) in enumerate(truths)],
        graticule_deg=GRATICULE_DEG,
        graticule_width_m=0.15,
    )
    return render_frame(s, pose_from_photo(meta), dem, tex).image


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    dem = DEM.open(ROOT / "assets" / "dem" / "srtm_jacksboro.tif", datum="egm96")
    lat, lon = math.radians(LAT), math.radians(LON)
    ground_msl = float(dem.height(lat, lon)) - float(egm96_undulation(lat, lon))  # the DEM is EGM96 + N
    alt = round(ground_msl + 150.0, 2)  # AbsoluteAltitude: MSL-like, as consumer DJI aircraft write it
    photo = OUT / "DJI_0001.JPG"
    pixels = [(300.5, 400.5), (120.0, 150.0), (120.0, 650.0), (480.0, 150.0), (480.0, 650.0)]
    write(photo, alt, 40.0, -60.0)  # the true tags: locate the truth
    tgt = OUT / "targets.csv"
    tgt.write_text("image,row,col\n" + "".join(f"DJI_0001.JPG,{r},{c}\n" for r, c in pixels))
    rows, msgs = replay_photos([photo], tgt, surface=surface_for(dem=dem))
    assert all(r["status"] == "ok" for r in rows), (rows, msgs)
    tgt.write_text(
        "image,row,col,truth_lat_deg,truth_lon_deg,truth_h_m\n"
        + "".join(
            f"DJI_0001.JPG,{r['row']},{r['col']},{r['lat_deg']:.8f},{r['lon_deg']:.8f},{r['h_m']:.2f}\n" for r in rows
        )
    )
    image = render(photo, dem, [(r["lat_deg"], r["lon_deg"]) for r in rows])  # seen from the true tags
    write(photo, alt + 3.0, 40.4, -60.2, image, QUALITY)  # what the photo says: tenths of a degree, metres off
    print(
        f"wrote {photo.relative_to(ROOT)} ({photo.stat().st_size} bytes) and {tgt.relative_to(ROOT)} "
        f"({len(rows)} targets)"
    )


if __name__ == "__main__":
    main()
