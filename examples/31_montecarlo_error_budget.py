"""Which error source dominates? An error budget of the [Q17] Table 1-2 scenario (docs/method.md section 5).

Runs the full Monte Carlo (N = 5000, as in [Q17]), then the first-order
propagation with one error source at a time, and prints each source's share of
the radial error variance (eq. 18 squared). The terrain-height uncertainty
(62.47 m at an incidence of ~50 deg) dominates; among the instrument errors the
POS position (0.0001 deg, about 11 m) leads, then aircraft height, roll and
heading; the Table 2 installation errors are negligible.
Then it shows how the eq. 18 CEP and the empirical 50 % radius differ
(docs/montecarlo.md).

Run:  python examples/31_montecarlo_error_budget.py
"""

from dataclasses import replace

import numpy as np

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ERROR_SOURCES, ErrorModel
from geoloc.assets import asset_path

model = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
res = mc.run(model, 5000, np.random.default_rng(0))
s = res.stats
print(
    f"Monte Carlo N = 5000: std lat {s['std_lat_deg']:.5f} deg, lon {s['std_lon_deg']:.5f} deg, "
    f"h {s['std_h_m']:.1f} m  ([Q17]: 0.00048, 0.00060, 62.3)"
)
print(f"CEP eq. 18 {s['cep_m']:.1f} m, empirical 50 % radius {s['cep50_empirical_m']:.1f} m\n")

total = mc.first_order(model).cep_m ** 2
rows = []
for name, dist in model.errors.items():
    one = replace(model, errors={name: dist})
    rows.append((mc.first_order(one).cep_m, name, dist))
print(f"{'source':30} {'distribution':>22} {'eq. 18 alone m':>15} {'share %':>8}")
for cep, name, dist in sorted(rows, key=lambda r: r[0], reverse=True):
    d = f"{dist.dist} {'sigma' if dist.dist == 'normal' else 'max'} {dist.scale:g}"
    print(f"{name:30} {d:>22} {cep:15.3f} {100 * cep**2 / total:8.3f}   {ERROR_SOURCES[name]}")
print(f"{'all (first order)':30} {'':>22} {np.sqrt(total):15.3f} {100.0:8.3f}")
