"""The KLV replay's steps, each alone (geoloc.workflows.klv_replay: ``_packet_heights``,
``_packet_angles``, ``_missing_tags`` and its ``_centre_needs``, ``_corner_needs``,
``_holds_reserved``, ``_lacks_text``, ``_replay_geometry``, ``_reported_corners``, ``_ground_points``,
``_mean_corner_error``, ``_point_columns``, ``_corner_status``, ``_datum_warnings``,
``_drone_height_warnings``, ``_summary_notes``), on columns written here by hand.

Oracles: PROJ's own vgridshift on the bundled EGM96 grid for N (tests/workflows/test_klv_replay.py's
``proj_undulation``), MISB ST 0601's tag rules (75 before 15, 78 before 25, 90/91 before 6/7,
82-89 before 26-33 + the frame centre), and the pinhole's closed form for the corners: a pixel
at column offset x from the centre of a lens whose focal length is f pixels looks atan(x / f)
off the axis; pyproj's geodesic (Karney's, on WGS-84) for the corners' distances.
"""

import math

from types import SimpleNamespace

import numpy as np
import pytest
from pyproj import Geod

from geoloc.status import Status
from geoloc.workflows import klv_replay as kr
from test_klv_replay import proj_undulation

LAT, LON = 36.60, -84.25  # on the bundled EGM96 crop (Jacksboro)


def getter(**cols):
    n = max(len(np.atleast_1d(v)) for v in cols.values())
    arrays = {k: np.broadcast_to(np.asarray(v, float), (n,)).copy() for k, v in cols.items()}
    return lambda name: kr._f(arrays, name, n)


def full_packet(n=1, **over):
    cols = dict(
        sensor_latitude_deg=LAT,
        sensor_longitude_deg=LON,
        sensor_ellipsoid_height_m=2500.0,
        platform_heading_deg=30.0,
        platform_pitch_deg=0.0,
        platform_roll_deg=0.0,
        sensor_relative_azimuth_deg=90.0,
        sensor_relative_elevation_deg=-30.0,
        sensor_relative_roll_deg=0.0,
        sensor_horizontal_fov_deg=8.0,
        sensor_vertical_fov_deg=4.5,
        frame_center_latitude_deg=LAT + 0.01,
        frame_center_longitude_deg=LON + 0.02,
        frame_center_hae_m=300.0,
    )
    cols.update(over)
    cols = {k: v for k, v in cols.items() if v is not None}
    cols["_n"] = np.zeros(n)
    return getter(**cols)


def test_heights_take_the_ellipsoidal_tag_first_else_msl_plus_proj_n():
    n_s = proj_undulation(LAT, LON)
    # packet 0 carries both sensor heights (75 wins), packet 1 only tag 15, packet 2 neither
    g = full_packet(
        3,
        sensor_ellipsoid_height_m=[2500.0, np.nan, np.nan],
        sensor_true_altitude_m=[9999.0, 2400.0, np.nan],
        frame_center_hae_m=[300.0, np.nan, np.nan],
        frame_center_elevation_m=[np.nan, 250.0, np.nan],
        frame_center_latitude_deg=LAT,
        frame_center_longitude_deg=LON,
    )
    hts = kr._packet_heights(g)
    # 1 mm: the bundled grid read bilinearly by two codes (the project's and PROJ's)
    assert hts.h_s[0] == 2500.0
    assert hts.h_s[1] == pytest.approx(2400.0 + n_s, abs=1e-3)
    assert np.isnan(hts.h_s[2])
    assert hts.sensor_h_from.tolist() == ["tag 75 (HAE)", "tag 15 (MSL) + EGM96 N", ""]
    assert hts.rep_h[0] == 300.0
    assert hts.rep_h[1] == pytest.approx(250.0 + n_s, abs=1e-3)
    assert hts.rep_h_from.tolist() == ["tag 78 (HAE)", "tag 25 (MSL) + EGM96 N", ""]


def test_angles_take_the_full_range_pitch_and_roll_first_and_refuse_impossible_fields_of_view():
    g = full_packet(
        3,
        platform_pitch_deg=[5.0, 5.0, 5.0],
        platform_pitch_full_deg=[-120.0, np.nan, np.nan],
        platform_roll_full_deg=[np.nan, 100.0, np.nan],
        platform_roll_deg=[1.0, 1.0, 1.0],
        sensor_horizontal_fov_deg=[8.0, 0.0, 180.0],
    )
    ang = kr._packet_angles(g)
    assert ang.pitch.tolist() == [-120.0, 5.0, 5.0]
    assert ang.roll.tolist() == [1.0, 100.0, 1.0]
    assert ang.hfov_ok.tolist() == [True, False, False]  # MISB: 0 and 180 are no field of view


def test_missing_tags_name_the_tag_and_keep_the_corners_apart():
    g = full_packet(
        3,
        sensor_latitude_deg=[LAT, np.nan, LAT],
        sensor_vertical_fov_deg=[4.5, 4.5, np.nan],
    )
    hts, ang = kr._packet_heights(g), kr._packet_angles(g)
    bad_c, bad_k, notes, reasons = kr._missing_tags(hts, ang, None, None)
    assert bad_c.tolist() == [False, True, False]
    assert bad_k.tolist() == [False, True, True]  # a packet that cannot be located has no corners either
    assert notes[0] == ""
    assert notes[1] == "missing tag 13 (Sensor Latitude)"
    assert notes[2].startswith("corners not computed: missing tag 17")
    assert reasons == {"missing tag 13 (Sensor Latitude)": 1}


def test_without_a_surface_the_reported_height_is_needed_and_with_one_it_is_not():
    g = full_packet(1, frame_center_hae_m=None)
    hts, ang = kr._packet_heights(g), kr._packet_angles(g)
    assert kr._missing_tags(hts, ang, None, None)[0].tolist() == [True]
    assert kr._missing_tags(hts, ang, object(), None)[0].tolist() == [False]


def test_each_packets_corners_look_half_its_own_field_of_view_off_the_axis():
    # three fields of view in one batch: the sensor's lens is the median's (8 x 4.5 deg)
    hfov, vfov = np.array([4.0, 8.0, 20.0]), np.array([2.25, 4.5, 11.0])
    g = full_packet(3, sensor_horizontal_fov_deg=hfov, sensor_vertical_fov_deg=vfov)
    hts, ang = kr._packet_heights(g), kr._packet_angles(g)
    bad_c, bad_k, _, _ = kr._missing_tags(hts, ang, None, None)
    geo = kr._replay_geometry(hts, ang, bad_c, bad_k, None)
    s = geo.sensor
    r0, c0 = s.center_pixel
    f_cols = (s.cols / 2) / math.tan(math.radians(8.0) / 2)  # the median lens's focal length [px]
    f_rows = (s.rows / 2) / math.tan(math.radians(4.5) / 2)
    # upper right corner: half the horizontal and vertical fields of view off the axis (1e-9 deg:
    # rounding of the tangents)
    assert np.degrees(np.arctan((geo.k_cols[1] - c0) / f_cols)) == pytest.approx(hfov / 2, abs=1e-9)
    assert np.degrees(np.arctan((r0 - geo.k_rows[1]) / f_rows)) == pytest.approx(vfov / 2, abs=1e-9)
    # the median packet's corners are the image's outer edges (1-based pixel centres: 0.5 and N + 0.5)
    assert geo.k_cols[:, 1].tolist() == pytest.approx([0.5, s.cols + 0.5, s.cols + 0.5, 0.5])
    assert geo.k_rows[:, 1].tolist() == pytest.approx([0.5, 0.5, s.rows + 0.5, s.rows + 0.5])


def test_reported_corners_are_the_full_tags_else_the_offsets_from_the_centre():
    full = {f"corner_latitude_{j}_deg": [LAT + j, np.nan] for j in range(1, 5)}
    full |= {f"corner_longitude_{j}_deg": [LON + j, np.nan] for j in range(1, 5)}
    off = {f"offset_corner_latitude_{j}_deg": [0.5, 0.01 * j] for j in range(1, 5)}
    off |= {f"offset_corner_longitude_{j}_deg": [0.5, -0.01 * j] for j in range(1, 5)}
    g = full_packet(2, **full, **off)
    rk_lat, rk_lon, src = kr._reported_corners(g, kr._packet_heights(g))
    assert rk_lat[:, 0].tolist() == [LAT + j for j in range(1, 5)]  # full corners win over offsets
    assert rk_lat[:, 1] == pytest.approx([LAT + 0.01 + 0.01 * j for j in range(1, 5)], abs=1e-12)
    assert rk_lon[:, 1] == pytest.approx([LON + 0.02 - 0.01 * j for j in range(1, 5)], abs=1e-12)
    assert src.tolist() == ["tags 82-89 (full)", "tags 26-33 (offsets from the frame centre)"]


def test_corner_status_is_the_first_failed_corners():
    OK, MISS, INV = int(Status.OK), int(Status.SKY), int(Status.INVALID_INPUT)
    kst = np.array([[OK, OK, OK], [OK, MISS, INV], [OK, INV, OK], [OK, OK, MISS]], np.uint8)
    # per packet (columns): all OK; corner 1 then 2 failed; corner 1 then 3 failed
    assert kr._corner_status(kst).tolist() == [OK, MISS, INV]


def test_datum_warning_when_hae_minus_msl_is_not_n():
    n_s = proj_undulation(LAT, LON)
    # packet 0: HAE - MSL = N (no warning); packet 1: the MSL item carries the HAE (off by -N)
    g = full_packet(
        2,
        sensor_ellipsoid_height_m=[2500.0, 2500.0],
        sensor_true_altitude_m=[2500.0 - n_s, 2500.0],
        frame_center_latitude_deg=LAT,
        frame_center_longitude_deg=LON,
    )
    read = type("R", (), {"packet": np.array([7, 8]), "columns": {"offset": np.array([0, 190])}})()
    warn, lines = kr._datum_warnings(read, kr._packet_heights(g))
    assert warn[0] == ""
    assert "tag 75 - tag 15 = +0.0 m" in warn[1] and "at the sensor" in warn[1]
    assert lines == [f"packet 8 (byte 190): {warn[1]}"]


def test_missing_tags_name_a_reserved_item_as_reserved_not_as_missing():
    # packet 0 sends tag 13 at the reserved value, packet 1 does not send it, packet 2 has both
    g = full_packet(3, sensor_latitude_deg=[np.nan, np.nan, LAT])
    reserved = np.empty(3, object)
    reserved[:] = [("sensor_latitude_deg",), (), ()]
    assert kr._holds_reserved(reserved, ("sensor_latitude_deg", "x")).tolist() == [True, False, False]
    hts, ang = kr._packet_heights(g), kr._packet_angles(g)
    bad_c, _, notes, reasons = kr._missing_tags(hts, ang, None, None, reserved)
    assert bad_c.tolist() == [True, True, False]
    assert notes[0] == f"tag 13 (Sensor Latitude) {kr._RESERVED_NOTE}"
    assert notes[1] == "missing tag 13 (Sensor Latitude)"
    assert reasons == {notes[0]: 1, notes[1]: 1}


def test_lacks_text_joins_the_missing_and_the_reserved_lists():
    assert kr._lacks_text("", "") == ""
    assert kr._lacks_text("tag 5 (A), tag 6 (B), ", "") == "missing tag 5 (A), tag 6 (B)"
    assert kr._lacks_text("", "tag 13 (C), ") == f"tag 13 (C) {kr._RESERVED_NOTE}"
    assert kr._lacks_text("tag 5 (A), ", "tag 13 (C), ") == f"missing tag 5 (A); tag 13 (C) {kr._RESERVED_NOTE}"


def test_the_sensor_roll_is_a_centre_need_with_a_boresight_else_a_corner_need():
    g = full_packet(1, sensor_relative_roll_deg=np.nan)
    hts, ang = kr._packet_heights(g), kr._packet_angles(g)
    roll = kr._TAG_TEXT["sensor_relative_roll_deg"]
    for centre in (True, False):
        c_texts = [t for mask, t, _ in kr._centre_needs(hts, ang, object(), centre) if mask.any()]
        k_texts = [t for mask, t in kr._corner_needs(ang, centre) if mask.any()]
        assert (c_texts, k_texts) == (([roll], []) if centre else ([], [roll]))
    # a surface given: the frame-centre height is no need; none given: it is one, and the only one lacking
    g = full_packet(1, frame_center_hae_m=None)
    hts = kr._packet_heights(g)
    lacking = [t for mask, t, _ in kr._centre_needs(hts, kr._packet_angles(g), None, False) if mask.any()]
    assert len(lacking) == 1 and lacking[0].startswith("tag 78")
    assert not any(m.any() for m, _, _ in kr._centre_needs(hts, kr._packet_angles(g), object(), False))


def test_ground_points_are_degrees_where_ok_and_invalid_where_a_tag_is_missing():
    OK, SKY, INV = int(Status.OK), int(Status.SKY), int(Status.INVALID_INPUT)
    lat, lon = np.radians([36.5, 36.6, 36.7]), np.radians([-84.1, -84.2, -84.3])
    gc = SimpleNamespace(
        lat=lat,
        lon=lon,
        h=np.array([300.0, 310.0, 320.0]),
        status=np.array([OK, SKY, OK], np.uint8),
        slant_range=np.array([1000.0, 2000.0, 3000.0]),
        refraction_m=np.array([0.1, 0.2, 0.3]),
    )
    gk = SimpleNamespace(
        lat=np.tile(lat, (4, 1)), lon=np.tile(lon, (4, 1)), h=np.full((4, 3), 5.0), status=np.zeros((4, 3), np.uint8)
    )
    pts = kr._ground_points(gc, gk, np.array([False, False, True]), np.array([False, True, True]))
    assert pts.status.tolist() == [OK, SKY, INV]
    assert pts.lat[0] == pytest.approx(36.5, abs=1e-12) and pts.lon[0] == pytest.approx(-84.1, abs=1e-12)
    assert np.isnan(pts.lat[1:]).all() and np.isnan(pts.h[1:]).all() and np.isnan(pts.range_m[1:]).all()
    assert pts.refraction_m[0] == 0.1 and np.isnan(pts.refraction_m[2])
    assert (pts.k_status[:, 1:] == INV).all() and (pts.k_status[:, 0] == OK).all()
    assert pts.k_lat[:, 0] == pytest.approx([36.5] * 4, abs=1e-12) and np.isnan(pts.k_h[:, 1:]).all()
    cols = kr._point_columns(pts, np.array([1.0, np.nan, np.nan]), kr.NO_CORRECTIONS)
    assert list(cols)[:3] == ["lat_deg", "lon_deg", "mgrs"] and list(cols)[-3:] == [
        "corner4_lat_deg",
        "corner4_lon_deg",
        "corner4_h_m",
    ]
    assert cols["mgrs"][1] == "" and cols["corner2_h_m"].tolist()[0] == 5.0


def test_mean_corner_error_is_pyprojs_geodesic_over_the_corners_both_have():
    # packet 0: four corners computed and reported; packet 1: two reported; packet 2: none
    k_lat = np.full((4, 3), LAT)
    k_lon = np.full((4, 3), LON)
    rk_lat = np.array([[LAT + 0.001, LAT, np.nan]] * 4)
    rk_lon = np.array(
        [[LON, LON + 0.002, np.nan], [LON + 0.001, LON + 0.004, np.nan], [LON, np.nan, np.nan], [LON, np.nan, np.nan]]
    )
    pts = SimpleNamespace(k_lat=k_lat, k_lon=k_lon)
    got = kr._mean_corner_error(pts, rk_lat, rk_lon)
    geod = Geod(ellps="WGS84")
    d = np.array([[geod.inv(LON, LAT, rk_lon[j, i], rk_lat[j, i])[2] for i in range(2)] for j in range(4)])
    # 1 mm: two geodesic codes on a few hundred metres
    assert got[0] == pytest.approx(d[:, 0].mean(), abs=1e-3)
    assert got[1] == pytest.approx(d[:2, 1].mean(), abs=1e-3)
    assert np.isnan(got[2])


def test_summary_notes_name_the_sensor_file_and_a_dem_height_of_about_minus_n():
    n_fc = proj_undulation(LAT, LON)
    sens = SimpleNamespace(cols=640, rows=512)
    # the reported frame-centre heights are orthometric (H) where the DEM's are ellipsoidal (H + N):
    # reported minus the DEM's is -N
    hts = SimpleNamespace(rep_h=np.array([300.0, 301.0]), n_fc=np.array([n_fc, n_fc]))
    h_dem = hts.rep_h + n_fc
    fc_err = np.array([1.0, 2.0])
    notes = kr._summary_notes(object(), sens, object(), hts, h_dem, fc_err)
    assert notes[0].startswith("sensor file: image 640 x 512")
    assert f"median {-n_fc:+.2f} m" in notes[1] and "orthometric" in notes[1]
    assert kr._summary_notes(None, sens, None, hts, h_dem, fc_err) == []


def test_drone_height_warning_names_the_tag_and_the_height_above_the_frame_centre():
    # a drone 2000 m above its frame centre (a feet / metres mix-up), the other packet 100 m
    g = full_packet(2, sensor_ellipsoid_height_m=[2300.0, 400.0], frame_center_hae_m=300.0)
    hts = kr._packet_heights(g)
    cols = {"offset": np.array([0, 190]), "platform_designation": np.array(["DJI Mavic 3", "DJI Mavic 3"])}
    read = type("R", (), {"packet": np.array([1, 2]), "columns": cols, "__len__": lambda self: 2})()
    lines = kr._drone_height_warnings(read, None, None, hts, np.array([300.0, 300.0]))
    assert len(lines) == 1
    assert lines[0].startswith("packet 1 (byte 0): tag 75 (Sensor Ellipsoid Height) = 2300.0 m: a drone's camera")
