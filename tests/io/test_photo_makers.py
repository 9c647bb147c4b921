"""Photos of other makers than DJI: Skydio, Parrot, Pix4D ``Camera:`` tags (Autel), MicaSense, Teal.

No real photo of these makers is in the repository: every photo here is built in the test, its
XMP written to the maker's published tag list as :mod:`geoloc.io.photo_makers` cites it (Skydio's
"camera and metadata overview", Parrot's GroundSDK "Photo metadata" page, Pix4D's "Yaw, Pitch,
Roll and Omega, Phi, Kappa angles", MicaSense's ``imageprocessing`` metadata reader, OpenAthena's
Teal reader). The oracle is independent of geoloc's chain: the line of sight is written out here
from each maker's stated convention (rotation matrices in numpy) and intersected with the WGS-84
ellipsoid by pymap3d's ``lookAtSpheroid``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin

from geoloc.io.photo_makers import earth_gimbal_deg
from geoloc.io.photos import (
    PhotoTagError,
    lens_from_photo,
    lens_source,
    lens_uncertainty,
    read_photo,
    sensor_from_photo,
)
from geoloc.sensors.budget import budget_from_dict
from geoloc.workflows.photo_replay import replay_photos

lookAtSpheroid = pytest.importorskip("pymap3d.los").lookAtSpheroid

W, H = 800, 600
LAT, LON = 36.52, -84.21  # 36 31' 12" N, 84 12' 36" W: exact in EXIF degrees-minutes-seconds
CAM_H = 150.0  # camera height [m], taken as ellipsoidal (altitude_datum="ellipsoid")
F_PX = 700.0


def _packet(ns_decls: str, body: str, attrs: str = "") -> bytes:
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        f'  <rdf:Description rdf:about="" {ns_decls} {attrs}>\n{body}\n  </rdf:Description>\n'
        ' </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end="w"?>'
    ).encode("utf-8")


def _dms(deg):
    a = abs(deg)
    d = int(a)
    m = int(round((a - d) * 60, 9))
    return (float(d), float(m), round((a - d - m / 60) * 3600, 9))


def _exif(make, model, focal_mm=None, alt=CAM_H):
    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = make, model
    gps = ex.get_ifd(0x8825)
    gps[1], gps[2], gps[3], gps[4] = "N", _dms(LAT), "W", _dms(LON)
    gps[5], gps[6] = b"\x00", alt
    sub = ex.get_ifd(0x8769)
    sub[0xA002], sub[0xA003] = W, H
    if focal_mm is not None:
        sub[0x920A] = focal_mm
    return ex


def _jpeg(path, xmp, make, model, **kw):
    Image.new("RGB", (W, H), (90, 120, 60)).save(path, exif=_exif(make, model, **kw), xmp=xmp, quality=70)
    return path


def _targets(tmp_path, name, pixels):
    t = tmp_path / "t.csv"
    t.write_text("image,row,col,truth_h_m\n" + "".join(f"{name},{r},{c},0.0\n" for r, c in pixels))
    return t


def _rzyx(y, p, r):
    """Rz(y) Ry(p) Rx(r), written out (radians)."""
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return (
        np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    )


def _oracle(los_ned):
    """Ground point of a NED line of sight from the camera, on the ellipsoid, by pymap3d."""
    n, e, d = los_ned / np.linalg.norm(los_ned)
    az, tilt = math.degrees(math.atan2(e, n)), math.degrees(math.acos(d))
    lat, lon, _ = lookAtSpheroid(LAT, LON, CAM_H, az, tilt)
    return float(lat), float(lon)


def _check(rows, oracles):
    for r, (lat, lon) in zip(rows, oracles):
        assert r["status"] == "ok"
        # Same ellipsoid and ray: the DJI test's 1e-9 deg (0.1 mm) holds here too; a wrong angle
        # convention or sign moves the point by metres. EXIF GPS degrees-minutes-seconds read back
        # to ~1e-12 deg (rationals), far below.
        assert r["lat_deg"] == pytest.approx(lat, abs=1e-9)
        assert r["lon_deg"] == pytest.approx(lon, abs=1e-9)


#: Pixels: the principal point and one right of and below it (1-based pixel centres).
PIXELS = [(300.5, 400.5), (300.5 + 90.0, 400.5 + 60.0)]


def _camera_rays(top, right, los, f=F_PX):
    """Rays of PIXELS from the camera's image axes (NED): top, right, line of sight."""
    out = []
    for r, c in PIXELS:
        x, y = (c - 400.5) / f, (r - 300.5) / f  # right, down in normalised image coordinates
        out.append(los + x * right - y * top)
    return out


# --------------------------------------------------------------------------- Skydio

SKYDIO_NS = "http://www.skydio.com/drone-skydio/1.0/"


@pytest.mark.parametrize("form", ["elements", "attributes"])
def test_skydio_photo_locates_like_the_ned_convention(tmp_path, form):
    # Skydio's tag list (support article 4417425974683, via OpenAthena): CameraOrientationNED
    # {Yaw, Pitch, Roll} in degrees, pitch up from the horizon; newer firmware writes the struct
    # as child elements, older as attributes of the struct element
    yaw, pitch, roll = 120.0, -35.0, 4.0
    if form == "elements":
        body = (
            "<drone-skydio:Latitude>36.52</drone-skydio:Latitude>"
            "<drone-skydio:Longitude>-84.21</drone-skydio:Longitude>"
            "<drone-skydio:AbsoluteAltitude>150.0</drone-skydio:AbsoluteAltitude>"
            '<drone-skydio:CameraOrientationNED rdf:parseType="Resource">'
            f"<drone-skydio:Yaw>{yaw}</drone-skydio:Yaw><drone-skydio:Pitch>{pitch}</drone-skydio:Pitch>"
            f"<drone-skydio:Roll>{roll}</drone-skydio:Roll></drone-skydio:CameraOrientationNED>"
            '<drone-skydio:CalibratedFocalLength rdf:parseType="Resource"><drone-skydio:X>700</drone-skydio:X>'
            "<drone-skydio:Y>700</drone-skydio:Y></drone-skydio:CalibratedFocalLength>"
            '<drone-skydio:CalibratedOpticalCenter rdf:parseType="Resource"><drone-skydio:X>400</drone-skydio:X>'
            "<drone-skydio:Y>300</drone-skydio:Y></drone-skydio:CalibratedOpticalCenter>"
        )
        xmp = _packet(f'xmlns:drone-skydio="{SKYDIO_NS}"', body)
    else:
        body = (
            f'<drone-skydio:CameraOrientationNED drone-skydio:Roll="{roll}" drone-skydio:Pitch="{pitch}" '
            f'drone-skydio:Yaw="{yaw}"/>'
            '<drone-skydio:CalibratedFocalLength drone-skydio:X="700" drone-skydio:Y="700"/>'
        )
        xmp = _packet(
            f'xmlns:drone-skydio="{SKYDIO_NS.replace("http:", "https:")}"',
            body,
            'drone-skydio:Latitude="36.52" drone-skydio:Longitude="-84.21" drone-skydio:AbsoluteAltitude="150.0"',
        )
    p = _jpeg(tmp_path / "S1.JPG", xmp, "Skydio", "X2")
    m = read_photo(p)
    assert m.maker == "Skydio" and m.position_source.startswith("drone-skydio:Latitude")
    assert (m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg) == (yaw, pitch, roll)
    rows, _ = replay_photos([p], _targets(tmp_path, "S1.JPG", PIXELS), altitude_datum="ellipsoid")
    # NED z-y-x with camera x = line of sight, y = image right, z = image down (as DJI's gimbal)
    R = _rzyx(*np.radians([yaw, pitch, roll]))
    rays = _camera_rays(top=-R[:, 2], right=R[:, 1], los=R[:, 0])
    _check(rows, [_oracle(d) for d in rays])
    assert rows[0]["lens"].startswith("pinhole (drone-skydio:CalibratedFocalLength")
    assert rows[0]["maker"] == "Skydio"


def test_a_skydio_2_photo_without_calibration_gets_the_database_lens_and_its_sigma(tmp_path):
    # Skydio 2 writes EXIF Model "2" (OpenAthena's makeModel "skydio2" = Make lower-cased + Model);
    # without CalibratedFocalLength the camera database gives the lens: 3.7 mm (EXIF FocalLength) on
    # the maker's 6.2868 x 4.712 mm sensor, this photo 800 x 600 px; 1-sigma 2.5 % (the row's: it
    # covers OpenAthena's 2.3 % / 4.6 % finer pixel pitch within 2 sigma)
    body = (
        "<drone-skydio:Latitude>36.52</drone-skydio:Latitude>"
        "<drone-skydio:Longitude>-84.21</drone-skydio:Longitude>"
        "<drone-skydio:AbsoluteAltitude>150.0</drone-skydio:AbsoluteAltitude>"
        '<drone-skydio:CameraOrientationNED rdf:parseType="Resource">'
        "<drone-skydio:Yaw>10</drone-skydio:Yaw><drone-skydio:Pitch>-60</drone-skydio:Pitch>"
        "<drone-skydio:Roll>0</drone-skydio:Roll></drone-skydio:CameraOrientationNED>"
    )
    p = _jpeg(tmp_path / "S2.JPG", _packet(f'xmlns:drone-skydio="{SKYDIO_NS}"', body), "Skydio", "2", focal_mm=3.7)
    m = read_photo(p)
    lens = lens_from_photo(m)
    fx, fy = 3.7 / 6.2868 * W, 3.7 / 4.712 * H
    assert (lens.fx, lens.fy) == pytest.approx((fx, fy), rel=1e-12)
    assert lens_uncertainty(m) == pytest.approx({"fx_px": 0.025 * fx, "fy_px": 0.025 * fy}, rel=1e-12)


# --------------------------------------------------------------------------- Parrot


def test_parrot_photo_position_from_exif_angles_from_drone_parrot(tmp_path):
    # Parrot GroundSDK "Photo metadata" (via OpenAthena): drone-parrot:Camera{Yaw,Pitch,Roll}Degree,
    # degrees, pitch up from the horizon; position and altitude in EXIF GPS only
    yaw, pitch, roll = -47.3, -62.0, 0.0
    body = (
        f"<drone-parrot:CameraYawDegree>{yaw}</drone-parrot:CameraYawDegree>"
        f"<drone-parrot:CameraPitchDegree>{pitch}</drone-parrot:CameraPitchDegree>"
        f"<drone-parrot:CameraRollDegree>{roll}</drone-parrot:CameraRollDegree>"
        "<drone-parrot:DroneYawDegree>-50.1</drone-parrot:DroneYawDegree>"
    )
    xmp = _packet('xmlns:drone-parrot="http://www.parrot.com/drone-parrot/1.0/"', body)
    # ANAFI: no calibration in the photo; the camera database knows its sensor, EXIF its focal length
    p = _jpeg(tmp_path / "P1.JPG", xmp, "Parrot", "ANAFI", focal_mm=4.0)
    m = read_photo(p)
    assert m.maker == "Parrot" and m.position_source == "EXIF GPS" and m.altitude_source == "EXIF GPSAltitude"
    assert m.flight_yaw_deg == -50.1
    # the ANAFI's 5344 x 4016 sensor of 1.12 um pixels (5.98528 mm wide) behind a 4.0 mm lens, for
    # an 800 x 600 image (same 4:3 aspect within 0.3 %): fx = 4.0 / 5.98528 * 800
    fx = 4.0 / (5344 * 1.12e-3) * W
    lens = lens_from_photo(m)
    assert lens.fx == pytest.approx(fx, rel=1e-12)
    rows, _ = replay_photos([p], _targets(tmp_path, "P1.JPG", PIXELS), altitude_datum="ellipsoid")
    R = _rzyx(*np.radians([yaw, pitch, roll]))
    rays = _camera_rays(top=-R[:, 2], right=R[:, 1], los=R[:, 0], f=fx)
    # fy differs from fx by the aspect mismatch (4016/5344 against 600/800): the off-axis pixel's
    # row offset uses fy; the oracle uses fx, so only the principal point is compared exactly
    _check(rows[:1], [_oracle(rays[0])])
    assert "camera database: Parrot ANAFI" in rows[0]["lens"]


# --------------------------------------------------------------------------- Pix4D Camera: (Autel)


def test_pix4d_camera_tags_pitch_from_nadir(tmp_path):
    # Pix4D "Yaw, Pitch, Roll and Omega, Phi, Kappa angles": (0, 0, 0) looks down with the image
    # top north; R = Rz(yaw) Ry(pitch) Rx(roll), camera x = image top, y = right, z = line of sight
    yaw, pitch, roll = 120.0, 55.0, 7.0
    body = f"<Camera:Yaw>{yaw}</Camera:Yaw><Camera:Pitch>{pitch}</Camera:Pitch><Camera:Roll>{roll}</Camera:Roll>"
    xmp = _packet('xmlns:Camera="http://pix4d.com/camera/1.0/"', body)
    p = _jpeg(tmp_path / "A1.JPG", xmp, "Autel Robotics", "XT701", focal_mm=4.0)
    m = read_photo(p)
    assert m.maker.startswith("Pix4D")
    # no database entry for this model: the lens is the approximate one, or a clear error
    with pytest.raises(PhotoTagError, match=r"A1\.JPG.*camera database"):
        lens_from_photo(m)
    p2 = tmp_path / "A2.JPG"
    ex = _exif("Autel Robotics", "XT701", focal_mm=4.0)
    ex.get_ifd(0x8769)[0xA405] = 24  # FocalLengthIn35mmFilm
    Image.new("RGB", (W, H)).save(p2, exif=ex, xmp=xmp)
    assert read_photo(p2).maker.startswith("Pix4D")
    f35 = 24 * math.hypot(W, H) / math.hypot(36, 24)
    rows, _ = replay_photos([p2], _targets(tmp_path, "A2.JPG", PIXELS), altitude_datum="ellipsoid")
    R = _rzyx(*np.radians([yaw, pitch, roll]))
    rays = _camera_rays(top=R[:, 0], right=R[:, 1], los=R[:, 2], f=f35)
    _check(rows, [_oracle(d) for d in rays])


def test_pix4d_to_dji_angles_closed_form():
    # without roll, Pix4D's (yaw, pitch from nadir) is DJI's (yaw, pitch - 90, 0): the camera
    # tilts up from nadir towards the image top, which is the heading
    for y, p in ((30.0, 20.0), (-120.0, 80.0), (200.0, 45.0)):
        gy, gp, gr = earth_gimbal_deg("pix4d-nadir", y, p, 0.0)
        assert (math.remainder(gy - y, 360.0), gp, gr) == pytest.approx((0.0, p - 90.0, 0.0), abs=1e-9)
    # nadir (gimbal lock): the rotation about the vertical is all in the yaw
    gy, gp, gr = earth_gimbal_deg("pix4d-nadir", 75.0, 0.0, 0.0)
    assert (gy, gp, gr) == pytest.approx((75.0, -90.0, 0.0), abs=1e-9)


# --------------------------------------------------------------------------- MicaSense


def _micasense_tiff(path, camera_angles=(0.0, 0.0, 0.0), exif_type_error=False, calibration="", exif_extra=None):
    y, p, r = camera_angles
    xmp = _packet(
        'xmlns:Camera="http://pix4d.com/camera/1.0/" xmlns:DLS="http://micasense.com/DLS/1.0/" '
        'xmlns:MicaSense="http://micasense.com/MicaSense/1.0/"',
        "<Camera:BandName><rdf:Seq><rdf:li>Blue</rdf:li></rdf:Seq></Camera:BandName>"
        f"<Camera:Yaw>{y}</Camera:Yaw><Camera:Pitch>{p}</Camera:Pitch><Camera:Roll>{r}</Camera:Roll>"
        "<DLS:Yaw>0.73310724098153246</DLS:Yaw><DLS:Pitch>0.0413</DLS:Pitch><DLS:Roll>0.1538</DLS:Roll>"
        "<MicaSense:CaptureId>abc</MicaSense:CaptureId>" + calibration,
    )
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[271], info[272] = "MicaSense", "RedEdge-M"
    info[700] = xmp
    info[34853] = {1: "N", 2: _dms(LAT), 3: "W", 4: _dms(LON), 5: b"\x00", 6: CAM_H}
    info[34665] = {0x920A: 5.4, **(exif_extra or {})}
    Image.fromarray(np.full((960, 1280), 1000, np.uint16)).save(path, tiffinfo=info)
    return path


def test_micasense_16bit_tiff_reads_and_gets_a_database_lens(tmp_path):
    # MicaSense writes Pix4D's Camera: tags (degrees) and DLS: angles in radians (the light sensor's
    # attitude, MicaSense imageprocessing metadata.py): the camera angles come from Camera:
    p = _micasense_tiff(tmp_path / "IMG_0001_1.tif", (0.0, 0.0, 0.0))
    m = read_photo(p)
    assert m.maker == "MicaSense" and (m.width, m.height) == (1280, 960)
    assert m.xmp["Yaw"] == "0.0" and m.xmp["BandName"] == "Blue"
    assert (m.gimbal_pitch_deg, m.gimbal_roll_deg) == pytest.approx((-90.0, 0.0))
    # RedEdge-M spec: 5.4 mm focal length, 3.75 um pixels -> 1440 px; 1-sigma: 1 % (nominal against
    # calibrated) and the rounding of "5.4" (step 0.1 mm, uniform: 0.1 / sqrt(12)), in quadrature
    lens = lens_from_photo(m)
    assert (lens.fx, lens.fy) == pytest.approx((5.4 / 3.75e-3, 5.4 / 3.75e-3), rel=1e-12)
    sigma = 1440.0 * math.hypot(0.01, 0.1 / math.sqrt(12) / 5.4)
    assert lens_uncertainty(m) == pytest.approx({"fx_px": sigma, "fy_px": sigma}, rel=1e-12)
    # the sigmas are keys a sensor's [uncertainty] budget takes
    b = budget_from_dict(lens_uncertainty(m), sensor_from_photo(m), "photo")
    assert b.sigma("fx_px") == pytest.approx(sigma)
    # nadir: the principal point is below the camera
    t = tmp_path / "t.csv"
    t.write_text("image,row,col,truth_h_m\nIMG_0001_1.tif,480.5,640.5,0.0\n")
    rows, _ = replay_photos([p], t, altitude_datum="ellipsoid")
    assert rows[0]["lat_deg"] == pytest.approx(LAT, abs=1e-9) and rows[0]["lon_deg"] == pytest.approx(LON, abs=1e-9)
    assert rows[0]["lens_fx_sigma_px"] == pytest.approx(sigma)
    assert "camera database: MicaSense RedEdge-M" in rows[0]["lens"]


#: A RedEdge-M band's calibration as MicaSense writes it (Pix4D's Camera: tags; values of the size a
#: RedEdge-M calibration has): focal length [mm], principal point [mm], k1, k2, k3, p1, p2
MICASENSE_CAL = (
    "<Camera:PerspectiveFocalLength>5.4323</Camera:PerspectiveFocalLength>"
    "<Camera:PerspectiveFocalLengthUnits>mm</Camera:PerspectiveFocalLengthUnits>"
    "<Camera:PrincipalPoint>2.4312,1.7731</Camera:PrincipalPoint>"
    "<Camera:PerspectiveDistortion><rdf:Seq><rdf:li>-0.1053</rdf:li><rdf:li>0.1862</rdf:li>"
    "<rdf:li>-0.0975</rdf:li><rdf:li>0.00041</rdf:li><rdf:li>-0.00037</rdf:li></rdf:Seq>"
    "</Camera:PerspectiveDistortion>"
)
#: EXIF FocalPlaneX/YResolution of 3.75 um pixels [px/mm], unit 4 (mm)
MICASENSE_FP = {0xA20E: 1 / 0.00375, 0xA20F: 1 / 0.00375, 0xA210: 4}


def test_micasense_calibration_tags_give_the_lens_opencv_projects_with_micasenses_reading(tmp_path):
    """MicaSense's calibration tags (Pix4D's Camera: namespace) give the lens, not the database: its
    projection equals cv2.projectPoints with the camera matrix and coefficients built as MicaSense's
    imageprocessing builds them (image.py cv2_camera_matrix: f [mm] and the principal point [mm] times
    FocalPlaneX/YResolution; cv2_distortion_coeff: PerspectiveDistortion items [0, 1, 3, 4, 2])."""
    import cv2

    p = _micasense_tiff(tmp_path / "IMG_0003_1.tif", calibration=MICASENSE_CAL, exif_extra=MICASENSE_FP)
    m = read_photo(p)
    lens = lens_from_photo(m)
    assert lens_source(m) == "brown (Camera:PerspectiveFocalLength, PrincipalPoint, PerspectiveDistortion)"
    assert lens_uncertainty(m) == {}  # a calibration: no database sigma
    res = 1 / 0.00375
    K = np.array([[5.4323 * res, 0, 2.4312 * res], [0, 5.4323 * res, 1.7731 * res], [0, 0, 1.0]])
    dist = np.array([-0.1053, 0.1862, -0.0975, 0.00041, -0.00037])[[0, 1, 3, 4, 2]]
    rng = np.random.default_rng(45)
    dirs = np.column_stack([rng.uniform(-0.35, 0.35, 20), rng.uniform(-0.27, 0.27, 20), np.ones(20)])
    uv, _ = cv2.projectPoints(dirs.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    u, v, st = lens.project(dirs)
    # float64 round-off of the same polynomial: 1e-9 px
    assert np.all(st == 0)
    assert np.max(np.abs(u - uv[:, 0, 0])) < 1e-9 and np.max(np.abs(v - uv[:, 0, 1])) < 1e-9
    # the replay names where its lens came from
    t = tmp_path / "t.csv"
    t.write_text("image,row,col,truth_h_m\nIMG_0003_1.tif,480.5,640.5,0.0\n")
    rows, _ = replay_photos([p], t, altitude_datum="ellipsoid")
    assert rows[0]["lens"].startswith("brown (Camera:PerspectiveFocalLength")


def test_micasense_calibration_without_the_focal_plane_resolution_is_named_and_the_database_used(tmp_path):
    p = _micasense_tiff(tmp_path / "IMG_0004_1.tif", calibration=MICASENSE_CAL)
    m = read_photo(p)
    assert any("Camera:PerspectiveFocalLength ignored (missing EXIF FocalPlaneX/YResolution)" in n for n in m.notes)
    assert "camera database: MicaSense RedEdge-M" in lens_source(m)
    assert lens_from_photo(m).fx == pytest.approx(5.4 / 3.75e-3, rel=1e-12)


def test_pillow_exif_type_error_is_a_note_not_a_crash(tmp_path, monkeypatch):
    # A user's MicaSense TIFF raised a TypeError inside Pillow's EXIF directory reading (the
    # file is not available here): simulate Pillow failing there; the XMP must still be read
    p = _micasense_tiff(tmp_path / "IMG_0002_1.tif", (10.0, 5.0, 0.0))

    def broken(self, tag):
        raise TypeError("unsupported operand type(s)")

    monkeypatch.setattr(Image.Exif, "get_ifd", broken)
    m = read_photo(p, require=False)
    assert any("EXIF directories not readable by Pillow (TypeError" in n for n in m.notes)
    assert m.maker == "MicaSense" and m.gimbal_yaw_deg is not None
    assert m.missing and "EXIF GPS" in " ".join(m.missing)  # the position was in the EXIF GPS IFD
    with pytest.raises(PhotoTagError, match=r"IMG_0002_1\.tif.*EXIF GPSLatitude"):
        read_photo(p)


# --------------------------------------------------------------------------- Teal


def test_teal_angles_relative_to_the_platform(tmp_path):
    # OpenAthena's Teal reader: exif:Platform{Yaw,Pitch,Roll} + exif:Camera{Yaw,Pitch,Roll},
    # rationals in degrees, summed. With a level platform composing the rotations is the sum.
    body = (
        "<exif:PlatformYaw>9000/100</exif:PlatformYaw><exif:PlatformPitch>0/1</exif:PlatformPitch>"
        "<exif:PlatformRoll>0/1</exif:PlatformRoll><exif:CameraYaw>2500/100</exif:CameraYaw>"
        "<exif:CameraPitch>-4000/100</exif:CameraPitch><exif:CameraRoll>0/1</exif:CameraRoll>"
    )
    xmp = _packet('xmlns:exif="http://ns.adobe.com/exif/1.0/"', body)
    p = _jpeg(tmp_path / "T1.JPG", xmp, "Teledyne FLIR", "Hadron 640R", focal_mm=9.0)
    m = read_photo(p)
    assert m.maker == "Teal"
    assert (m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg) == pytest.approx((115.0, -40.0, 0.0), abs=1e-9)
    # Boson 640: 640 x 512 px of 12 um = 7.68 mm wide; 800 x 600 is not its 5:4 aspect: no lens
    with pytest.raises(PhotoTagError, match="camera database"):
        lens_from_photo(m)


# --------------------------------------------------------------------------- bad inputs


def test_unknown_maker_names_the_file_and_every_tag_looked_for(tmp_path):
    xmp = _packet('xmlns:acme="http://acme.example/1.0/"', "<acme:Heading>12</acme:Heading>")
    p = _jpeg(tmp_path / "X1.JPG", xmp, "Acme", "Hawk")
    with pytest.raises(PhotoTagError) as e:
        read_photo(p)
    msg = str(e.value)
    for tag in (
        "X1.JPG",
        "'Acme'",
        "drone-dji:GimbalYawDegree",
        "drone-skydio:CameraOrientationNED/Yaw",
        "drone-parrot:CameraPitchDegree",
        "Camera:Yaw",
        "exif:CameraYaw",
    ):
        assert tag in msg


def test_missing_maker_angle_names_the_maker_tag(tmp_path):
    xmp = _packet(
        'xmlns:drone-parrot="http://www.parrot.com/drone-parrot/1.0/"',
        "<drone-parrot:CameraYawDegree>10</drone-parrot:CameraYawDegree>"
        "<drone-parrot:CameraPitchDegree>abc</drone-parrot:CameraPitchDegree>",
    )
    p = _jpeg(tmp_path / "P2.JPG", xmp, "Parrot", "ANAFI")
    with pytest.raises(PhotoTagError, match=r"P2\.JPG.*drone-parrot:CameraPitchDegree, drone-parrot:CameraRollDegree"):
        read_photo(p)
    assert any("CameraPitchDegree = 'abc' ignored" in n for n in read_photo(p, require=False).notes)
