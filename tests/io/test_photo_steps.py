"""The named steps of a photo's reading (geoloc.io.photos.read_photo: DJI's, and another maker's
``_read_maker``), each alone.

Oracles: the makers' tag lists as geoloc.io.photo_makers cites them (tag names, the order tried),
and scipy's rotations for the angles of a camera turned on its platform (Teal's convention: the
camera's z-y-x angles after the platform's, ``Rotation.from_euler("ZYX", ...)``).
"""

from __future__ import annotations


import pytest
from scipy.spatial.transform import Rotation

from geoloc.io.photo_makers import maker_by_name
from geoloc.io.photos import (
    PhotoMeta,
    _dji_attitude,
    _dji_position,
    _maker_attitude,
    _maker_lens,
    _maker_position,
    _missing_angle_tags,
    _missing_position_tags,
    _missing_required,
)


def _meta():
    return PhotoMeta(path="x.jpg", width=4000, height=3000, xmp={}, notes=[])


def test_a_flight_angle_missing_beside_the_others_is_zero_and_said():
    m, notes = _meta(), []
    dji = {"GimbalYawDegree": "10.5", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0", "FlightYawDegree": "7"}
    _dji_attitude(m, dji, notes)
    assert (m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg) == (10.5, -90.0, 0.0)
    assert (m.flight_yaw_deg, m.flight_pitch_deg, m.flight_roll_deg) == (7.0, 0.0, 0.0)
    assert notes == [
        "no drone-dji:FlightPitchDegree: taken as 0",
        "no drone-dji:FlightRollDegree: taken as 0",
    ]
    # none of the three: left None, one note
    m, notes = _meta(), []
    _dji_attitude(m, {"GimbalYawDegree": "1"}, notes)
    assert m.flight_yaw_deg is None and len(notes) == 1 and "flight attitude taken as 0" in notes[0]


def test_the_position_prefers_dji_and_names_a_disagreement():
    m, notes = _meta(), []
    ex = {"gps_lat_deg": 36.6001, "gps_lon_deg": -84.25}
    _dji_position(m, {"GpsLatitude": "36.6", "GpsLongtitude": "-84.25"}, ex, notes, "x.jpg", "x.jpg")
    assert (m.lat_deg, m.lon_deg, m.position_source) == (36.6, -84.25, "drone-dji:GpsLatitude/GpsLongtitude")
    assert notes and "differs from drone-dji's by 1.00e-04 deg" in notes[0]
    m = _meta()
    _dji_position(m, {}, ex, [], "x.jpg", "x.jpg")
    assert (m.lat_deg, m.position_source) == (36.6001, "EXIF GPS")


def test_missing_required_names_each_tag_not_found():
    m = _meta()
    assert len(_missing_required(m)) == 5
    m.lat_deg, m.lon_deg = 36.6, -84.25
    m.gimbal_yaw_deg = m.gimbal_pitch_deg = m.gimbal_roll_deg = 0.0
    assert _missing_required(m) == ("drone-dji:AbsoluteAltitude or EXIF GPSAltitude",)


SKYDIO = maker_by_name("Skydio")
TEAL = maker_by_name("Teal")
MICASENSE = maker_by_name("MicaSense")


def test_maker_position_takes_its_own_tags_else_exif_and_names_the_altitudes_datum():
    m, notes = _meta(), []
    own = {"Latitude": "36.5", "Longitude": "-84.2", "AbsoluteAltitude": "412.5", "RelativeAltitude": "120"}
    _maker_position(m, SKYDIO, own, {"gps_lat_deg": 1.0, "gps_lon_deg": 2.0, "gps_altitude_m": 3.0}, notes)
    assert (m.lat_deg, m.lon_deg, m.position_source) == (36.5, -84.2, "drone-skydio:Latitude/Longitude")
    assert (m.absolute_altitude_m, m.relative_altitude_m, m.altitude_source) == (
        412.5,
        120.0,
        "drone-skydio:AbsoluteAltitude",
    )
    assert notes == [f"Skydio: altitude from drone-skydio:AbsoluteAltitude; its datum: {SKYDIO.altitude_datum}"]
    m, notes = _meta(), []
    _maker_position(m, SKYDIO, {"Latitude": "abc"}, {"gps_lat_deg": 1.0, "gps_lon_deg": 2.0}, notes)
    assert (m.lat_deg, m.lon_deg, m.position_source, m.altitude_source) == (1.0, 2.0, "EXIF GPS", "")
    assert notes == ["drone-skydio:Latitude = 'abc' ignored: not a number"]
    with pytest.raises(ValueError, match=r"drone-skydio:Latitude/Longitude = 96.0, 10.0: out of range"):
        _maker_position(_meta(), SKYDIO, {"Latitude": "96", "Longitude": "10"}, {}, [])


def test_missing_position_tags_name_the_makers_then_exifs():
    m = _meta()
    assert _missing_position_tags(m, SKYDIO) == [
        "drone-skydio:Latitude/Longitude or EXIF GPSLatitude/GPSLongitude",
        "drone-skydio:AbsoluteAltitude or EXIF GPSAltitude",
    ]
    assert _missing_position_tags(m, TEAL) == ["EXIF GPSLatitude/GPSLongitude", "EXIF GPSAltitude"]


def test_missing_angle_tags_follow_the_convention():
    none3 = dict.fromkeys(("yaw", "pitch", "roll"))
    plat = dict.fromkeys(("platform_yaw", "platform_pitch", "platform_roll"))
    assert _missing_angle_tags(MICASENSE, none3, plat) == ["Camera:Yaw", "Camera:Pitch", "Camera:Roll"]
    assert _missing_angle_tags(TEAL, {"yaw": 1.0, "pitch": 1.0, "roll": None}, plat) == [
        "exif:CameraRoll",
        "exif:PlatformYaw",
        "exif:PlatformPitch",
        "exif:PlatformRoll",
    ]
    assert _missing_angle_tags(SKYDIO, {"yaw": 1.0, "pitch": None, "roll": 1.0}, plat) == [
        "drone-skydio:CameraOrientationNED/Pitch"
    ]


def test_a_camera_turned_on_a_banked_platform_composes_as_scipys_rotations():
    m, notes = _meta(), []
    ang = {"PlatformYaw": "30", "PlatformPitch": "5", "PlatformRoll": "-20", "CameraYaw": "25", "CameraPitch": "-40"}
    ang["CameraRoll"] = "3"
    assert _maker_attitude(m, TEAL, {}, ang, notes) == []
    want = (
        Rotation.from_euler("ZYX", [30, 5, -20], degrees=True) * Rotation.from_euler("ZYX", [25, -40, 3], degrees=True)
    ).as_euler("ZYX", degrees=True)
    # 1e-9 deg: two codes' rounding of the same three rotations
    assert (m.gimbal_yaw_deg, m.gimbal_pitch_deg, m.gimbal_roll_deg) == pytest.approx(tuple(want), abs=1e-9)
    assert (m.flight_yaw_deg, m.flight_pitch_deg, m.flight_roll_deg) == (30.0, 5.0, -20.0)
    assert len(notes) == 1 and notes[0].startswith("Teal: camera angles yaw 25, pitch -40, roll 3 deg")
    # a camera angle missing: no gimbal angles, its tag named
    m = _meta()
    assert _maker_attitude(m, TEAL, {}, {**ang, "CameraRoll": "x"}, []) == ["exif:CameraRoll"]
    assert m.gimbal_yaw_deg is None


def test_maker_lens_needs_a_positive_focal_length():
    m = _meta()
    m.xmp = {}
    own = {"CalibratedFocalLength/X": "2000.5", "CalibratedFocalLength/Y": "-1", "CalibratedOpticalCenter/X": "2010"}
    _maker_lens(m, SKYDIO, own, [])
    assert (m.calibrated_focal_px, m.calibrated_focal_y_px, m.calibrated_center_x_px) == (2000.5, None, 2010.0)
    assert m.calibrated_center_y_px is None
    assert m.xmp["_calibration_tags"] == "drone-skydio:CalibratedFocalLength/X"
    m = _meta()
    _maker_lens(m, SKYDIO, {"CalibratedFocalLength/X": "0"}, [])
    assert m.calibrated_focal_px is None
