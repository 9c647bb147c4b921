"""Newton-Raphson on the tangency condition [L18 eq. 17]: Delta a and the residual per iteration.

Starting from Delta a = 0 (the WGS-84 ellipsoid) the iteration converges
quadratically; with max_iter too small the line gets status NO_CONVERGENCE.

Run:  python examples/42_limb_newton_raphson.py
"""

from geoloc.sensors.limb import limb_tangent
from geoloc.status import describe
from geoloc.workflows.scenario import load_scenario

sc = load_scenario("assets/scenarios/tiangong2_limb.toml").with_frames(1)
chain = sc.lines_of_sight()
o, d = chain.origin_ecef[0, 30], chain.direction_ecef[0, 30]  # one pixel of the first frame

r = limb_tangent(o, d)
print("iter   Delta a [m]        residual (eq. 17 / |v'|^2)")
for k in range(int(r.nr_iterations) + 1):
    print(f"{k:4d}  {r.nr_delta_a_history[k]:14.6f}   {r.nr_residual_history[k]: .3e}")
print(f"status: {describe(r.status)}; limb height {float(r.tangent_h):.3f} m, exact {float(r.exact_h):.3f} m")

r2 = limb_tangent(o, d, max_iter=2)
print(
    f"with max_iter=2: status {describe(r2.status)} (nr: {describe(r2.nr_status)}, "
    f"exact: {describe(r2.exact_status)}), limb height {float(r2.tangent_h)}"
)
