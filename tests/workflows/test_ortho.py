"""Whole frames (``geoloc.workflows.ortho``, ``geoloc ortho``): the compiled pixel grid, the image-grid
GeoTIFF against ``geoloc locate``, trimesh/embree and pymap3d, the orthophoto against surveyed targets
and against GDAL's own geolocation-array warp, bad inputs.
"""

import json
import platform
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from geoloc.cli import main
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
from geoloc.io.records import load_records
from geoloc.locate import as_sensor
from geoloc.sensors._fastgrid import grid_line_of_sight
from geoloc.sensors.sensor_file import load_sensor
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.height import HeightSurface
from geoloc.surfaces.terrain import surface_for
from geoloc.workflows.ortho import (
    frame_pixels,
    locate_frame,
    orthorectify,
    read_frame_geotiff,
)

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"
Q17_CAMERA = ASSETS / "cameras" / "qiao2017.toml"
Q17_RECORDS = ASSETS / "records" / "qiao2017_flight_tests.csv"
ETOPO = ASSETS / "dem" / "etopo5_flight_area.tif"
SRTM = ASSETS / "dem" / "srtm_jacksboro.tif"
PHOTO = ASSETS / "photos" / "DJI_0001.JPG"
TARGETS = ASSETS / "photos" / "targets.csv"


def _record(sensor_path, records_path, k=0):
    s = as_sensor(load_sensor(sensor_path))
    rec = load_records(records_path, angles=s.angle_names)
    return s, rec, rec.subset([k]).pose()


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            return src.read(), src.tags(), src.descriptions, [src.tags(b) for b in (1, 2, 3, 4)]


# --------------------------------------------------------------------------- the compiled grid
@pytest.mark.parametrize(
    "sensor_file, records",
    [
        (Q17_CAMERA, Q17_RECORDS),  # [Q17] pinhole, roll-pitch
        (ASSETS / "sensors" / "eo_turret.toml", ASSETS / "records" / "eo_turret_flight.csv"),  # Brown, mount, lever arm
        (ASSETS / "sensors" / "drone_camera.toml", ASSETS / "records" / "drone_targets.csv"),  # earth-referenced
    ],
)
def test_grid_line_of_sight_equals_the_sensors_ray_for_ray(sensor_file, records):
    s, _, pose = _record(sensor_file, records)
    rows, cols = frame_pixels(s, 37)
    # a row and a column off the sensor, and a NaN pixel: the statuses must match too
    rows = np.concatenate([[0.2, np.nan], rows, [s.rows + 0.7]])
    cols = np.concatenate([[-3.0], cols, [s.cols + 0.5]])
    fast = grid_line_of_sight(s, pose, rows, cols)
    R, C = np.meshgrid(rows, cols, indexing="ij")
    ref = s.line_of_sight(R, C, pose)
    assert np.array_equal(fast.status, ref.status)
    assert {Status.OK, Status.OUTSIDE_SENSOR, Status.INVALID_INPUT} <= set(np.unique(fast.status).tolist())
    ok = ref.status != Status.INVALID_INPUT
    # the same optical centre: the numpy path's own function, so equal to rounding of one broadcast
    assert np.array_equal(fast.origin_ecef[ok], ref.origin_ecef[ok])
    # unit directions: the compiled path composes the chain once (one 3x3) where numpy goes hop by
    # hop; both are ~10 rounded products of unit-norm factors, a few 1e-16 each. 2e-15 rad is 5e-11 m
    # at 25 km range.
    assert np.abs(fast.direction_ecef[ok] - ref.direction_ecef[ok]).max() < 2e-15
    assert np.isnan(fast.direction_ecef[~ok]).all() == np.isnan(ref.direction_ecef[~ok]).all()


def test_bad_pose_gives_invalid_input_per_pixel_not_an_exception():
    s, _, pose = _record(Q17_CAMERA, Q17_RECORDS)
    import dataclasses

    bad = dataclasses.replace(pose, pitch=np.array([np.deg2rad(120.0)]))  # out of [-90, 90] deg
    grid = locate_frame(s, bad, HeightSurface(0.0), step=400)
    assert (grid.status == Status.INVALID_INPUT).all()
    assert np.isnan(grid.lat).all() and np.isnan(grid.h).all()


# --------------------------------------------------------------------------- the GeoTIFF vs geoloc locate
def _locate_cli_args(rec, k=0):
    c = rec.column
    return [
        "--lat-deg",
        repr(float(c("ac_lat_deg")[k])),
        "--lon-deg",
        repr(float(c("ac_lon_deg")[k])),
        "--h-m",
        repr(float(c("ac_h_m")[k])),
        "--heading-deg",
        repr(float(c("heading_deg")[k])),
        "--pitch-deg",
        repr(float(c("pitch_deg")[k])),
        "--roll-deg",
        repr(float(c("roll_deg")[k])),
        "--gimbal-roll-deg",
        repr(float(c("gimbal_roll_deg")[k])),
        "--gimbal-pitch-deg",
        repr(float(c("gimbal_pitch_deg")[k])),
    ]


def test_geotiff_pixels_equal_geoloc_locate(tmp_path, capsys):
    out = tmp_path / "q17.tif"
    step = 97
    assert (
        main(
            [
                "ortho",
                "--record",
                "T3-1",
                "--dem",
                str(ETOPO),
                "--step",
                str(step),
                "--out",
                str(out),
                "--json",
                "--serial",
            ]
        )
        == 0
    )
    info = json.loads(capsys.readouterr().out)
    bands, tags, desc, btags = _read(out)
    s, rec, _ = _record(Q17_CAMERA, Q17_RECORDS)
    n_r, n_c = len(range(1, s.rows + 1, step)), len(range(1, s.cols + 1, step))
    assert bands.shape == (4, n_r, n_c) and bands.dtype == np.float64
    assert info["shape"] == [n_r, n_c] and info["counts"] == {"ok": n_r * n_c}
    # every height says its datum: file tags, band tags and descriptions
    assert tags["h_datum"] == btags[2]["datum"] == "ellipsoid (WGS 84)"
    assert "ellipsoid (WGS 84)" in desc[2] and desc[0].startswith("lat_deg") and desc[3].startswith("status")
    assert [t["name"] for t in btags] == ["lat_deg", "lon_deg", "h_m", "status"] and tags["step"] == str(step)
    assert (bands[3] == 0).all()
    for i, j in [(0, 0), (n_r - 1, n_c - 1), (n_r // 2, 3), (7, n_c // 2)]:
        row, col = 1 + i * step, 1 + j * step
        assert (
            main(
                ["locate", *_locate_cli_args(rec), "--row", str(row), "--col", str(col), "--dem", str(ETOPO), "--json"]
            )
            == 0
        )
        ref = json.loads(capsys.readouterr().out)
        # the same rays to ~1e-16 rad (the test above) meet the same bilinear cell; the walk polishes its
        # root to 1e-7 m along the ray: 1e-9 deg is 0.1 mm, 1e-5 m a hundred times the polish
        assert abs(bands[0, i, j] - ref["lat_deg"]) < 1e-9
        assert abs(bands[1, i, j] - ref["lon_deg"]) < 1e-9
        assert abs(bands[2, i, j] - ref["h_m"]) < 1e-5
        assert ref["h_datum"] == tags["h_datum"]


def test_corner_pixels_agree_with_trimesh_embree_on_the_dem_mesh(tmp_path):
    if platform.machine() != "x86_64":
        pytest.importorskip("embreex")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    out = tmp_path / "tri.tif"
    step = 191
    assert (
        main(
            [
                "ortho",
                "--record",
                "T3-7",
                "--dem",
                str(ETOPO),
                "--dem-model",
                "triangles",
                "--step",
                str(step),
                "--out",
                str(out),
                "--serial",
            ]
        )
        == 0
    )
    grid = read_frame_geotiff(out)
    s, rec, _ = _record(Q17_CAMERA, Q17_RECORDS)
    pose = rec.subset([rec.labels().index("T3-7")]).pose()
    corners = [(0, 0), (0, -1), (-1, 0), (-1, -1)]
    rows = np.array([grid.rows[i] for i, _ in corners])
    cols = np.array([grid.cols[j] for _, j in corners])
    los = s.line_of_sight(rows, cols, pose)  # the numpy reference rays, not the compiled grid
    dem = DEM.open(ETOPO)
    m = dem.to_trimesh()
    fr = m.metadata["enu_frame"]
    loc, idx, _ = RayMeshIntersector(m).intersects_location(
        fr.from_ecef(los.origin_ecef), fr.vector_from_ecef(los.direction_ecef), multiple_hits=False
    )
    assert sorted(idx.tolist()) == [0, 1, 2, 3]
    ours = np.array([geodetic_to_ecef(grid.lat[i, j], grid.lon[i, j], grid.h[i, j]) for i, j in corners])
    err = np.linalg.norm(fr.from_ecef(ours[idx]) - loc, axis=-1)
    # tests/surfaces/test_terrain_trimesh.py: the triangle walk and trimesh agree to 7e-8 m on rays 2 km long;
    # these are 25 km long and written as degrees (float64 degrees: 1e-14 deg = 1 nm): 1e-6 m
    assert err.max() < 1e-6, err


def test_flat_surface_corners_agree_with_pymap3d_look_at_spheroid(tmp_path):
    from pymap3d import ecef2aer
    from pymap3d.los import lookAtSpheroid

    out = tmp_path / "flat.tif"
    step = 229
    assert (
        main(
            [
                "ortho",
                "--sensor",
                str(ASSETS / "sensors" / "drone_camera.toml"),
                "--record",
                "survey1-1",
                "--records",
                str(ASSETS / "records" / "drone_targets.csv"),
                "--target-h-m",
                "0",
                "--height-kind",
                "geodetic",
                "--step",
                str(step),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    grid = read_frame_geotiff(out)
    s, rec, pose = _record(ASSETS / "sensors" / "drone_camera.toml", ASSETS / "records" / "drone_targets.csv")
    assert (grid.status == Status.OK).all()  # 70 deg below the horizon: every pixel meets the ellipsoid
    for i, j in [(0, 0), (0, -1), (-1, 0), (-1, -1)]:
        los = s.line_of_sight(grid.rows[i], grid.cols[j], pose)  # the numpy reference ray
        o, d = los.origin_ecef.reshape(3), los.direction_ecef.reshape(3)
        lat0, lon0, h0 = (float(v) for v in ecef_to_geodetic(o))
        lat0, lon0 = np.rad2deg(lat0), np.rad2deg(lon0)
        p = o + 1000.0 * d
        az, el, _ = ecef2aer(*p, lat0, lon0, h0)  # pymap3d's own local frame
        lat, lon, _ = lookAtSpheroid(lat0, lon0, h0, az, 90.0 + el)  # tilt from nadir, h = 0
        # pymap3d's closed form vs ours: both exact; 1e-8 deg is 1 mm at this latitude
        assert abs(grid.lat_deg[i, j] - lat) < 1e-8 and abs(grid.lon_deg[i, j] - lon) < 1e-8
        assert abs(grid.h[i, j]) < 1e-3  # the geodetic surface h = 0 [m]


def test_chunks_change_nothing_and_bound_memory():
    s, _, pose = _record(Q17_CAMERA, Q17_RECORDS)
    dem = DEM.open(ETOPO)
    big = locate_frame(s, pose, dem, step=9, chunk=1 << 20, parallel=False)
    tracemalloc.start()
    small = locate_frame(s, pose, dem, step=9, chunk=4096, parallel=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    for a, b in zip((big.lat, big.lon, big.h, big.status), (small.lat, small.lon, small.h, small.status)):
        assert np.array_equal(a, b, equal_nan=True)
    result = sum(a.nbytes for a in (small.lat, small.lon, small.h, small.status))
    # 4096 rays of ~200 bytes of temporaries each, plus one image row (255 pixels): well under 4 MB
    # beyond the answer itself (66 000 pixels, 1.8 MB)
    assert peak - result < 4e6, (peak, result)


def test_parallel_solver_gives_the_serial_hits():
    # the default (numba threads) against one thread: the same kernel per ray, so the same numbers
    s, _, pose = _record(Q17_CAMERA, Q17_RECORDS)
    dem = DEM.open(ETOPO)
    par = locate_frame(s, pose, dem, step=23)
    ser = locate_frame(s, pose, dem, step=23, parallel=False)
    for a, b in zip((par.lat, par.lon, par.h, par.status), (ser.lat, ser.lon, ser.h, ser.status)):
        assert np.array_equal(a, b, equal_nan=True)


# --------------------------------------------------------------------------- the orthophoto
@pytest.fixture(scope="module")
def photo():
    from geoloc.io.photos import photo_sensor, pose_from_photo, read_photo
    from geoloc.workflows.ortho import read_photo_pixels

    meta = read_photo(PHOTO)
    s, _ = photo_sensor(meta)
    return s, pose_from_photo(meta), DEM.open(SRTM), read_photo_pixels(PHOTO)


def _centroid(band, tr):
    """Weighted centroid (x, y) of a raster's non-zero cells, in its CRS (cell centres)."""
    ii, jj = np.nonzero(band > 0)
    w = band[ii, jj].astype(float)
    j, i = np.sum(w * (jj + 0.5)) / w.sum(), np.sum(w * (ii + 0.5)) / w.sum()
    return tr.a * j + tr.b * i + tr.c, tr.d * j + tr.e * i + tr.f


def test_photo_target_lands_at_its_surveyed_position_in_the_orthophoto(tmp_path, photo):
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    from geoloc.geodesy.geodesic import horizontal_distance_m
    from geoloc.workflows.photo_replay import replay_photos

    s, pose, dem, img = photo
    gsd = 0.25
    frame = locate_frame(s, pose, dem, parallel=False)
    # `geoloc replay`'s answer for each surveyed target (the forward model: pixel -> ray -> DEM)
    rows, _ = replay_photos([PHOTO], TARGETS, surface=surface_for(dem=dem))
    assert len(rows) == 5
    for t in rows[:3]:
        # a marker photo: a disc of radius 2.5 px around the target pixel, orthorectified (inverse map)
        vv, uu = np.mgrid[1 : s.rows + 1, 1 : s.cols + 1]
        marker = (((vv - t["row"]) ** 2 + (uu - t["col"]) ** 2) <= 2.5**2).astype(np.uint8)[None] * 200
        out = tmp_path / f"ortho_{t['row']}_{t['col']}.tif"
        info = orthorectify(marker, s, pose, dem, out, gsd_m=gsd, frame=frame, parallel=False)
        with rasterio.open(out) as src:  # the orthophoto's own georeferencing, read by rasterio
            band, alpha, tr, crs = src.read(1), src.read(2), src.transform, src.crs
        assert crs.to_epsg() == 4326 and info["cells_seen"] == int((alpha > 0).sum()) > 0
        x, y = _centroid(band, tr)
        # against the forward model: half a cell of sampling (0.125 m); the disc (about 2 m on the
        # ground) seen in perspective moves its centroid off its centre's image by ~r^2/range, 1 cm: 0.15 m
        to_model = float(horizontal_distance_m(y, x, t["lat_deg"], t["lon_deg"]))
        assert to_model < 0.15, (t["row"], t["col"], to_model)
        # against the survey: the model's own error there (the replay's error_to_truth_m, 1.2-2.5 m:
        # pose, lens and DEM) plus the same 0.15 m; the orthophoto adds no error of its own
        to_truth = float(horizontal_distance_m(y, x, t["truth_lat_deg"], t["truth_lon_deg"]))
        assert to_truth < t["error_to_truth_m"] + 0.15, (t["row"], t["col"], to_truth)
        # GDAL's own warp of the same marker with the frame's per-pixel lat/lon as geolocation arrays
        # (an independent resampler; its backmap is approximate): its centroid within 2 cells of ours
        dst = np.zeros(band.shape, np.float32)
        reproject(
            marker[0].astype(np.float32),
            dst,
            src_geoloc_array=np.stack([frame.lon_deg, frame.lat_deg]),
            src_crs=crs,
            dst_transform=tr,
            dst_crs=crs,
            resampling=Resampling.bilinear,
        )
        gx, gy = _centroid(dst, tr)
        assert float(horizontal_distance_m(gy, gx, y, x)) < 2 * gsd


def test_ortho_cli_writes_a_georeferenced_photo(tmp_path, capsys):
    out, ortho = tmp_path / "grid.tif", tmp_path / "ortho.tif"
    assert (
        main(
            [
                "ortho",
                "--photo",
                str(PHOTO),
                "--dem",
                str(SRTM),
                "--out",
                str(out),
                "--ortho-out",
                str(ortho),
                "--gsd-m",
                "0.5",
                "--ortho-crs",
                "utm",
                "--json",
                "--serial",
            ]
        )
        == 0
    )
    info = json.loads(capsys.readouterr().out)
    assert info["shape"] == [600, 800] and info["counts"] == {"ok": 480000}
    with rasterio.open(ortho) as src:
        assert src.crs.to_epsg() == 32616 and src.count == 4 and src.dtypes[0] == "uint8"  # UTM 16N at -84.2
        assert src.res == (0.5, 0.5)
        alpha = src.read(4)
        rgb = src.read((1, 2, 3))
    assert info["ortho"]["cells_seen"] == int((alpha == 255).sum()) > 0
    assert rgb[:, alpha == 255].mean() > 10  # the photo's colours, not black


# --------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize(
    "argv, words",
    [
        (["--record", "T3-1", "--step", "0"], "--step 0"),
        (["--record", "T3-1", "--chunk", "0"], "--chunk 0"),
        (["--record", "T9-9"], "--record 'T9-9'"),
        (["--lat-deg", "36.4"], "--lon-deg"),
        (["--record", "T3-1", "--ortho-out", "o.tif", "--gsd-m", "1"], "--ortho-out needs --photo"),
        (["--photo", str(PHOTO), "--ortho-out", "o.tif"], "--gsd-m"),
        (["--photo", str(PHOTO), "--ortho-out", "o.tif", "--gsd-m", "-2"], "--gsd-m -2"),
        (["--record", "T3-1", "--lat-deg", "1", "--lon-deg", "2", "--h-m", "3"], "the pose is given twice"),
        (["--lat-deg", "120", "--lon-deg", "2", "--h-m", "3000"], "lat = 120"),
        (["--record", "T3-1", "--dem", str(ETOPO), "--target-h-m", "0"], "--dem and --target-h-m"),
    ],
)
def test_bad_inputs_name_the_field(tmp_path, capsys, argv, words):
    assert main(["ortho", *argv, "--out", str(tmp_path / "x.tif")]) == 2
    err = capsys.readouterr().err
    assert words in err, err


def test_bad_arguments_of_locate_frame_name_the_field():
    s, _, pose = _record(Q17_CAMERA, Q17_RECORDS)
    for kw, name in ((dict(step=0), "step = 0"), (dict(step=1.5), "step = 1.5"), (dict(chunk=-1), "chunk = -1")):
        with pytest.raises(ValueError, match=name):
            locate_frame(s, pose, HeightSurface(0.0), **kw)
    with pytest.raises(ValueError, match="surface = "):
        locate_frame(s, pose, "assets/dem/srtm_jacksboro.tif")
    two = load_records(Q17_RECORDS).subset([0, 1]).pose()
    with pytest.raises(ValueError, match="one pose"):
        locate_frame(s, two, HeightSurface(0.0), step=500)
