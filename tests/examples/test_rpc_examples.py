"""The pushbroom / RPC examples (examples/6*.py) run and print what they promise."""

import re
import runpy
from pathlib import Path

EX = Path(__file__).resolve().parents[2] / "examples"


def test_example_60_pushbroom_scene(capsys):
    runpy.run_path(str(EX / "60_pushbroom_scene.py"), run_name="__main__")
    out = capsys.readouterr().out
    across = float(re.search(r"across ([0-9.]+) m", out).group(1))
    assert abs(across - 2.1) < 0.05  # [L12] Table 2: 2.1 m
    err = float(re.search(r"max error \[px\]: ([0-9.e+-]+)", out).group(1))
    assert err < 1e-5


def test_example_61_rpc_fit_and_gdal_check(capsys):
    runpy.run_path(str(EX / "61_rpc_fit_and_gdal_check.py"), run_name="__main__")
    out = capsys.readouterr().out
    vals = [float(v) for v in re.findall(r"(?:check_max_px|gdal_vs_exact_max_px) +([0-9.e+-]+)", out)]
    assert len(vals) == 4 and max(vals) <= 0.01  # within both budgets: the fit's 0.01 px and GDAL's 0.1 px


def test_example_62_rpc_sensor_on_dem(capsys):
    runpy.run_path(str(EX / "62_rpc_sensor_on_dem.py"), run_name="__main__")
    out = capsys.readouterr().out
    n_ok = int(re.search(r"(\d+) of \d+ pixels meet the DEM", out).group(1))
    assert n_ok >= 80
    chord = float(re.search(r"line of sight vs RPC at the terrain, max \[px\]: ([0-9.e+-]+)", out).group(1))
    assert chord < 5e-6  # tests/sensors/test_rpc_sensor.py: CHORD_TOL
    px, m = (
        float(v) for v in re.search(r"GDAL RPC_DEM vs RPC sensor: max ([0-9.e+-]+) px, ([0-9.e+-]+) m", out).groups()
    )
    assert px < 5e-6 and m < 2e-5
    assert "OUTSIDE_DOMAIN" in out


def test_example_63_sentinel2_pixel_to_ground(capsys):
    """Sen2VM's point within 0.5 m with its settings (measured 0.020 m), 18-22 m away with Rugged's
    light-time and aberration (tests/sensors/test_sentinel2.py has the closed forms), and back to the pixel."""
    runpy.run_path(str(EX / "63_sentinel2_pixel_to_ground.py"), run_name="__main__")
    out = capsys.readouterr().out
    d = [float(v) for v in re.findall(r"E, ([0-9.]+) m from Sen2VM", out)]
    assert len(d) == 2 and d[0] < 0.5 and 18 < d[1] < 22
    backs = re.findall(r"and back: row ([0-9.]+), col ([0-9.]+)", out)
    assert len(backs) == 2 and all(abs(float(r) - 1201) < 1e-3 and abs(float(c) - 1201) < 1e-3 for r, c in backs)
