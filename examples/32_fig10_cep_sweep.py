"""[Q17] Fig. 10a: CEP against the outer frame angle for terrain sigmas of 10-100 m (docs/method.md section 5).

Writes fig10a.csv and fig10a.png in the current folder (or the folder given as
the first argument) and prints a few rows. Solid lines: [Q17] eq. 18; dotted:
the empirical 50 % radius. With a DEM (Fig. 10b) use
``geoloc montecarlo assets/scenarios/qiao2017_table1_dem.toml --sweep dem``.

Run:  python examples/32_fig10_cep_sweep.py [OUTDIR]
"""

import sys
from pathlib import Path

import numpy as np

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import asset_path

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
out.mkdir(parents=True, exist_ok=True)
model = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
angles = np.arange(10.0, 82.1, 4.0)
sigmas = np.array([10.0, 25.0, 50.0, 62.47, 75.0, 100.0])
sw = mc.sweep_terrain_sigma(model, angles, sigmas, 2000, np.random.default_rng(0), progress=None)
sw.to_csv(out / "fig10a.csv")
sw.to_png(out / "fig10a.png")
print("angle " + " ".join(f"{lab:>16}" for lab in sw.labels))
for i in range(0, len(angles), 3):
    print(f"{angles[i]:5.0f} " + " ".join(f"{v:16.1f}" for v in sw.cep_m[i]))
print(f"wrote {out / 'fig10a.csv'} and {out / 'fig10a.png'}")
