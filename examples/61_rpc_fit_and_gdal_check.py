"""61: fit an RPC to both sensors, write it as GDAL metadata, and let GDAL (RPC_DEM) locate pixels.

Run: python examples/61_rpc_fit_and_gdal_check.py
"""

import tempfile
from pathlib import Path

from geoloc.assets import asset_path
from geoloc.surfaces.dem import DEM
from geoloc.workflows.rpc_scenario import rpc_report
from geoloc.workflows.scenario import load_scenario

with tempfile.TemporaryDirectory() as tmp:
    for name in ("zy3_nadir", "qiao2017_frame"):
        sc = load_scenario(asset_path("scenarios", f"{name}.toml"))
        dem = DEM.open(sc.dem_path, datum=sc.dem_datum)  # the DEM the scenario names
        rep = rpc_report(sc, Path(tmp) / f"{name}.tif", dem)
        print(f"{name}:")
        print(f"  fit_rms_px           {rep['fit_rms_px']:.2e}")
        print(f"  check_rms_px         {rep['check_rms_px']:.2e}   check_max_px {rep['check_max_px']:.2e}")
        print(
            f"  gdal_vs_exact_max_px {rep['gdal_vs_exact_max_px']:.2e}   ({rep['gdal_points']} pixels, "
            f"RPC_PIXEL_ERROR_THRESHOLD 1e-6)"
        )
        print(f"  GDAL default threshold (0.1 px): max {rep['gdal_default_threshold_max_px']:.3f} px")
        print(
            f"  orthometric DEM given to GDAL as-is: max {rep['gdal_orthometric_dem_max_px']:.3g} px "
            f"({rep['gdal_orthometric_dem_max_m']:.1f} m)"
        )
