"""`geoloc pixel`: the pixel that sees a ground point, given by latitude/longitude or MGRS.

Oracles: `geoloc locate` (the forward verb: a pixel's ray met on the DEM must come back to
that pixel), the `mgrs` package's own decoding and pyproj's geodesic (the MGRS input),
and a hand-made ridge DEM written with rasterio (a point behind it is hidden).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess

import numpy as np
import pytest

POSE = [
    "--sensor",
    "assets/sensors/eo_turret.toml",
    "--lat-deg",
    "36.6",
    "--lon-deg",
    "-84.25",
    "--h-m",
    "2500",
    "--heading-deg",
    "45",
    "--pitch-deg",
    "2",
    "--roll-deg",
    "1",
    "--angle",
    "azimuth=90",
    "--angle",
    "elevation=-30",
]
DEM = ["--dem", "assets/dem/srtm_jacksboro.tif"]


def geoloc(*args, cwd=None) -> subprocess.CompletedProcess:
    """``geoloc ARGS`` run in this process (``geoloc.cli.main``, the function ``python -m geoloc``
    calls), in ``cwd``, with its standard output and error captured: what a subprocess returns,
    without a Python start-up and geoloc's imports each (about 4 s a call under CI's load)."""
    from geoloc.cli import main

    out, err = (io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True) for _ in range(2))
    old = os.getcwd()
    try:
        os.chdir(cwd or old)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(list(args))
            except SystemExit as e:  # argparse's usage errors
                rc = e.code
    finally:
        os.chdir(old)
    text = [s.buffer.getvalue().decode("utf-8") for s in (out, err)]  # type: ignore[attr-defined]
    return subprocess.CompletedProcess(["geoloc", *args], rc, *text)


def test_locate_then_pixel_comes_back_to_the_pixel(tmp_path):
    for row, col in ((300.0, 700.0), (541.0, 961.0), (1000.5, 1800.25)):
        r = geoloc("locate", *POSE, *DEM, "--row", str(row), "--col", str(col), "--json", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        g = json.loads(r.stdout)
        p = geoloc(
            "pixel",
            *POSE,
            *DEM,
            "--point-lat-deg",
            repr(g["lat_deg"]),
            "--point-lon-deg",
            repr(g["lon_deg"]),
            "--point-h-m",
            repr(g["h_m"]),
            "--json",
            cwd=tmp_path,
        )
        assert p.returncode == 0, p.stderr
        out = json.loads(p.stdout)
        # the exact walk stops within millimetres of the DEM at ~5 km: 1e-6 rad, under 0.01 px
        assert out["row"] == pytest.approx(row, abs=0.01) and out["col"] == pytest.approx(col, abs=0.01)
        assert out["verdict"] == "in the frame" and out["visible"] is True
        # without --point-h-m the height is the DEM's there: the same point, so the same pixel
        q = json.loads(
            geoloc(
                "pixel",
                *POSE,
                *DEM,
                "--point-lat-deg",
                repr(g["lat_deg"]),
                "--point-lon-deg",
                repr(g["lon_deg"]),
                "--json",
                cwd=tmp_path,
            ).stdout
        )
        assert q["h_from"] == "the DEM" and q["h_m"] == pytest.approx(g["h_m"], abs=0.05)
        assert q["row"] == pytest.approx(row, abs=0.05) and q["col"] == pytest.approx(col, abs=0.05)


@pytest.mark.parametrize("ref,east,north", [("16SGF4866651490", 48666.5, 51490.5), ("16SGF4851", 48500.0, 51500.0)])
def test_an_mgrs_reference_is_the_centre_of_its_square(ref, east, north, tmp_path):
    import mgrs
    from pyproj import Transformer

    p = geoloc("pixel", *POSE, "--mgrs", ref, "--point-h-m", "300", "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # pyproj's UTM zone 16N puts the point at the centre of the named square (1 m, 1 km), and the
    # mgrs package decodes the reference to the same place (1e-9 deg: ~0.1 mm)
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32616", always_xy=True).transform(out["lon_deg"], out["lat_deg"])
    assert e % 1e5 == pytest.approx(east, abs=0.01) and n % 1e5 == pytest.approx(north, abs=0.01)
    lat, lon = mgrs.MGRS().toLatLon(ref)
    assert out["lat_deg"] == pytest.approx(lat, abs=1e-9) and out["lon_deg"] == pytest.approx(lon, abs=1e-9)
    ll = json.loads(
        geoloc(
            "pixel",
            *POSE,
            "--point-lat-deg",
            repr(out["lat_deg"]),
            "--point-lon-deg",
            repr(out["lon_deg"]),
            "--point-h-m",
            "300",
            "--json",
            cwd=tmp_path,
        ).stdout
    )
    assert (ll["row"], ll["col"]) == (out["row"], out["col"])
    assert out["given"] == f"MGRS {ref}" and "no DEM" in out["verdict"]


def test_outside_the_frame_and_behind_the_camera(tmp_path):
    # the turret looks 90 deg right of a 45 deg heading (south-east), 30 deg down: a point north-west
    # of the aircraft is behind the camera, one 10 km south-west far outside the frame
    behind = geoloc(
        "pixel",
        *POSE,
        "--point-lat-deg",
        "36.62",
        "--point-lon-deg",
        "-84.27",
        "--point-h-m",
        "300",
        "--json",
        cwd=tmp_path,
    )
    assert behind.returncode == 1 and json.loads(behind.stdout)["verdict"] == "behind the camera"
    off = geoloc(
        "pixel",
        *POSE,
        "--point-lat-deg",
        "36.52",
        "--point-lon-deg",
        "-84.33",
        "--point-h-m",
        "300",
        "--json",
        cwd=tmp_path,
    )
    assert off.returncode == 1, off.stdout + off.stderr
    assert json.loads(off.stdout)["verdict"] in ("outside the frame", "behind the camera")


def test_a_point_behind_a_ridge_is_hidden(tmp_path):
    # a plain at 100 m with a 600 m ridge ~4 km north of the camera, 400 m above the plain, looking
    # north 3 deg down: a point ~5.5 km north is in the frame but hidden; one at 3.3 km is seen
    import rasterio
    from rasterio.transform import from_origin

    lat0, lon0, step, n = 36.5, -84.2, 0.0005, 401
    H = np.full((n, n), 100.0, np.float32)
    lats = lat0 + 0.1 - step * (np.arange(n) + 0.5)
    H[np.abs(lats - (lat0 + 0.036)) < 0.002, :] = 600.0
    path = tmp_path / "ridge.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=from_origin(lon0 - 0.1, lat0 + 0.1, step, step),
    ) as ds:
        ds.write(H, 1)
    pose = [
        "--sensor",
        "assets/sensors/eo_turret.toml",
        "--lat-deg",
        str(lat0),
        "--lon-deg",
        str(lon0),
        "--h-m",
        "500",
        "--angle",
        "azimuth=0",
        "--angle",
        "elevation=-3",
    ]
    dem = ["--dem", str(path), "--dem-datum", "ellipsoid"]
    hid = geoloc(
        "pixel",
        *pose,
        *dem,
        "--point-lat-deg",
        str(lat0 + 0.0495),
        "--point-lon-deg",
        str(lon0),
        "--json",
        cwd=tmp_path,
    )
    out = json.loads(hid.stdout)
    assert hid.returncode == 1 and out["status"] == "ok", hid.stdout + hid.stderr
    assert out["verdict"] == "hidden behind terrain from this camera" and out["visible"] is False
    assert 3.5e3 < out["occluder_range_m"] < 4.5e3
    seen = geoloc(
        "pixel", *pose, *dem, "--point-lat-deg", str(lat0 + 0.030), "--point-lon-deg", str(lon0), "--json", cwd=tmp_path
    )
    assert seen.returncode == 0 and json.loads(seen.stdout)["verdict"] == "in the frame", seen.stdout + seen.stderr


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--mgrs", "16SXX99"], "--mgrs '16SXX99'"),
        (["--mgrs", "16SGF4866651490", "--point-lat-deg", "36.5", "--point-h-m", "0"], "not both"),
        (["--point-lat-deg", "36.5", "--point-h-m", "0"], "--point-lon-deg"),
        (["--point-lat-deg", "95", "--point-lon-deg", "0", "--point-h-m", "0"], "--point-lat-deg 95"),
        (["--point-lat-deg", "36.5", "--point-lon-deg", "-84.2"], "--point-h-m"),
    ],
)
def test_bad_ground_points_are_one_line(args, needle, tmp_path):
    r = geoloc("pixel", *POSE, *args, cwd=tmp_path)
    assert r.returncode == 2 and needle in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
