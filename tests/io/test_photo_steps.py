"""The named steps of a DJI photo's reading (geoloc.io.photos.read_photo), each alone."""

from __future__ import annotations

from geoloc.io.photos import PhotoMeta, _dji_attitude, _missing_required, _dji_position


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
