"""The bundled TianGong-2-like scenario: 1 137 frames x 48 pixels of a forward limb slit.

Prints, per pixel of the slit, the range of exact tangent heights over the
frames, how many frames see the Earth instead, and the worst [L18] error.

Run:  python examples/44_limb_scenario.py
(command-line equivalent: geoloc limb assets/scenarios/tiangong2_limb.toml --out limb.csv)
"""

import numpy as np

from geoloc.status import Status
from geoloc.workflows.scenario import load_scenario

sc = load_scenario("assets/scenarios/tiangong2_limb.toml")
chain, r = sc.solve()
alpha = np.degrees(sc.alphas())
print(sc.name)
print(f"{'pixel':>5} {'alpha deg':>9} {'hits Earth':>10} {'h min km':>9} {'h max km':>9} {'max|L18-exact| mm':>18}")
for j in range(sc.n_pixels):
    ok = r.status[:, j] == Status.OK
    hits = int(np.sum(r.status[:, j] == Status.HITS_EARTH))
    if ok.any():
        h = r.exact_h[ok, j] / 1e3
        e = 1e3 * np.max(np.abs(r.h_difference[ok, j]))
        print(f"{j:5d} {alpha[j]:9.3f} {hits:10d} {h.min():9.2f} {h.max():9.2f} {e:18.3f}")
    else:
        print(f"{j:5d} {alpha[j]:9.3f} {hits:10d} {'-':>9} {'-':>9} {'-':>18}")
