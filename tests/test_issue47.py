"""Issue 47, item 1: each case of the second bad-input catalogue, pinned by a test that failed before
it was mended (the KLV cases and ``view --export`` have their own tests elsewhere).

Exit codes, ``--out`` rules, interrupts, broken pipes and progress: docs/cli.md.
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from geoloc.assets import asset_path
from geoloc.cli import main

ROOT = Path(__file__).resolve().parents[1]
GEOLOC = [sys.executable, "-m", "geoloc"]
SCEN = asset_path("scenarios", "qiao2017_table1.toml")
SRTM = asset_path("dem", "srtm_jacksboro.tif")
ETOPO = asset_path("dem", "etopo5_flight_area.tif")
TURRET = asset_path("sensors", "eo_turret.toml")
TURRET_CSV = asset_path("records", "eo_turret_flight.csv")


# ------------------------------------------------------------------ rpc of a scenario of another kind
def test_rpc_of_a_montecarlo_scenario_is_one_clear_line(tmp_path, capsys):
    # before: AttributeError: 'ErrorModel' object has no attribute 'dem_path' (a traceback)
    out = tmp_path / "x.tif"
    assert main(["rpc", str(SCEN), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "montecarlo" in err and "'pushbroom' or 'frame'" in err, err
    assert not out.exists()
