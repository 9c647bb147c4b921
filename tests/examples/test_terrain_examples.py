"""The terrain examples (examples/2*.py) run and show what they promise."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples").glob("2[0-9]_*.py"))


def run(path):
    # check=False: a failing example is reported with its stderr by the assert below
    r = subprocess.run([sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path):
    out = run(path)
    assert out.strip()
    if path.name.startswith("26_"):
        assert "frame grid 291 x 287 (step 8): {'ok': 83517}" in out  # every pixel meets the ETOPO5 DEM
        assert "ellipsoid (WGS 84)" in out and "orthophoto" in out and "seen" in out
    if path.name.startswith("27_"):
        # the mosaic of tiles gives the merged raster's hits (the roots are polished to 1e-7 m)
        assert "same status on every ray: True" in out
        assert float(re.search(r"merged raster: ([0-9.e+-]+) m", out).group(1)) < 1e-6
    if path.name.startswith("28_"):
        # docs/terrain.md, "Where embree and the walk differ": on every ray whose hits land
        # apart, the referee finds the walk's (2 such rays here with embreex 2.17)
        n = int(re.search(r"(\d+) hits more than 1 mm apart", out).group(1))
        rays = [ln for ln in out.splitlines() if ln.startswith("ray ")]
        assert n >= 1 and len(rays) == n
        assert all("referee finds the walk's hit" in ln for ln in rays)
    if path.name.startswith("20_"):
        assert "N =  -26.79 m" in out and "N =   17.16 m" in out  # published EGM96 values
    if path.name.startswith("24_"):
        lines = {ln.split()[0]: ln for ln in out.splitlines()}
        assert "hidden = True" in lines["bisect"] and "hidden = False" in lines["exact"]
        # docs/terrain.md: "the ridge at 213 m is hit first, bisection returns the valley
        # floor at 0.6 m, 1.8 km further"
        h_ex, s_ex = _nums(lines["exact"])[:2]
        h_bi, s_bi = _nums(lines["bisect"])[:2]
        h_st = _nums(lines["steps"])[0]
        assert round(h_ex) == 213 and round(h_bi, 1) == 0.6 and round((s_bi - s_ex) / 1e3, 1) == 1.8
        assert h_ex - 1.0 <= h_st <= h_ex + 0.01  # [Q17]'s steps (eps_h 1 m) stop within one step
    if path.name.startswith("21_"):
        assert "40.0000 N -84.2500 E  h =      nan m  left_dem" in out
        lo, hi = _nums(next(ln for ln in out.splitlines() if ln.startswith("heights")))[:2]
        # the SRTM crop's orthometric range (read here with rasterio) plus EGM96 N there
        # (-30.6 m, examples/20): 1 m for N's variation over the tile
        import rasterio

        with rasterio.open(ROOT / "assets" / "dem" / "srtm_jacksboro.tif") as f:
            z = f.read(1).astype(float)
        assert lo == pytest.approx(z.min() - 30.6, abs=1.0) and hi == pytest.approx(z.max() - 30.6, abs=1.0)
    if path.name.startswith("22_"):
        rows = {ln.split()[0]: ln for ln in out.splitlines()}
        h = {k: np.array(_nums(rows[k].split("h = [")[1].split("]")[0])) for k in ("steps", "bisect", "exact")}
        hidden = np.array(["True" in v for v in rows["bisect"].split("hidden = [")[1].split("]")[0].split()])
        # steps (eps_h 5 m) stop within one step below the exact hit (printed to 0.1 m); the
        # bisection (threshold 5 m) is within its threshold of the terrain where not hidden:
        # there within a few metres of the exact hit on these slopes, and flagged elsewhere
        assert np.all((h["steps"] <= h["exact"] + 0.1) & (h["steps"] >= h["exact"] - 5.1))
        assert hidden.sum() == 1 and np.all(np.abs(h["bisect"] - h["exact"])[~hidden] < 40.0)
        assert np.abs(h["bisect"] - h["exact"])[hidden][0] > 100.0
    if path.name.startswith("23_"):
        lines = out.splitlines()
        H = [_nums(ln.split("=")[1])[0] for ln in lines if ln.strip().startswith("H_") and "bracket" not in ln]
        dem = [_nums(ln.split("=")[-1])[0] for ln in lines if ln.strip().startswith("H_") and "bracket" not in ln]
        assert len(H) == 14 and "steps: 14 DEM evaluations" in out
        assert np.allclose(np.diff(H), -100.0, atol=0.11)  # eps_h = 100 m, printed to 0.1 m
        assert all(a > b for a, b in zip(H[:-1], dem[:-1])) and H[-1] <= dem[-1]  # [Q17]'s stop rule
        br = [_nums(ln.split("bracket [")[1]) for ln in lines if "bracket [" in ln]
        widths = [b - a for a, b in br]
        assert np.allclose(np.array(widths[1:]) / np.array(widths[:-1]), 0.5, atol=2e-3)  # halving
    if path.name.startswith("25_"):
        d = float(out.split("max difference ")[1].split()[0])
        assert d < 7e-8  # docs/tour_terrain.md: triangle mode vs trimesh/embree "to 7e-8 m"


def _nums(text):
    return [float(v) for v in re.findall(r"[-+]?[0-9]*\.?[0-9]+(?:e[-+]?[0-9]+)?", text)]


def test_there_are_terrain_examples():
    assert len(EXAMPLES) >= 6
