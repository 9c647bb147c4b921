"""How far is the [L18] virtual ellipsoid from the exact tangent height? (docs/method.md section 6)

Lines are built tangent to the surface of constant geodetic height h at a known
point (lat, lon, h), in a horizontal direction of azimuth az there: their exact
tangent height is h by construction (the point and the normal come from pyproj
and the closed-form normal, not from geoloc). For each line the script prints

* exact - h           : minimum geodetic height found by geoloc.sensors.limb, minus h (should be ~0)
* Da - h              : the virtual ellipsoid's Delta a taken as the height (the "usual" shortcut)
* h_L18 - h           : the paper's limb height, eq. 21-26
* h_geod(VE) - h      : exact geodetic height of the virtual-ellipsoid tangent point
* lat19 err           : eq. 19 latitude minus the true geodetic latitude of that point, in metres on the ground
* |VE - exact|        : distance between the virtual-ellipsoid and exact tangent points

Run:  python examples/43_limb_virtual_ellipsoid_error.py
"""

import numpy as np
from pyproj import Transformer

from geoloc.geodesy.ellipsoid import meridian_radius
from geoloc.sensors.limb import limb_tangent

to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)

lats = np.array([0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 89.0])
heights = np.array([10e3, 30e3, 60e3, 100e3, 300e3, 1000e3])
azims = np.array([0.0, 45.0, 90.0])  # north, north-east, east
LA, H, AZ = np.meshgrid(lats, heights, azims, indexing="ij")
lon = np.full(LA.shape, 20.0)
x, y, z = to_ecef.transform(lon.ravel(), LA.ravel(), H.ravel())
p0 = np.stack([x, y, z], -1).reshape(LA.shape + (3,))
phi, lam, az = np.radians(LA), np.radians(lon), np.radians(AZ)
north = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], -1)
east = np.stack([-np.sin(lam), np.cos(lam), np.zeros_like(lam)], -1)
d = np.cos(az)[..., None] * north + np.sin(az)[..., None] * east
origin = p0 - 2.5e6 * d  # the sensor 2 500 km before the tangent point

r = limb_tangent(origin, d)
assert np.all(r.status == 0), r.status
lat19_err_m = (r.tangent_lat - r.tangent_lat_geodetic) * meridian_radius(r.tangent_lat_geodetic)
pos_err = np.linalg.norm(r.tangent_ecef - r.exact_ecef, axis=-1)

print(
    f"{'lat':>5} {'h km':>6} {'az':>4} | {'exact-h m':>10} {'Da-h m':>9} {'hL18-h mm':>10} "
    f"{'hgeod(VE)-h mm':>14} {'lat19 err m':>11} {'|VE-exact| m':>12}"
)
for i, la in enumerate(lats):
    for j, hh in enumerate(heights):
        for k, a in enumerate(azims):
            print(
                f"{la:5.0f} {hh / 1e3:6.0f} {a:4.0f} | {r.exact_h[i, j, k] - hh:10.1e} "
                f"{r.delta_a[i, j, k] - hh:9.2f} {1e3 * (r.tangent_h[i, j, k] - hh):10.3f} "
                f"{1e3 * (r.tangent_h_geodetic[i, j, k] - hh):14.3f} {lat19_err_m[i, j, k]:11.1f} "
                f"{pos_err[i, j, k]:12.1f}"
            )

print("\nworst case over latitude and azimuth, per tangent height:")
print(
    f"{'h km':>6} | {'max|Da-h| m':>11} {'max|hL18-h| mm':>14} {'max|hgeod-h| mm':>15} "
    f"{'max|lat19| m':>12} {'max|VE-exact| m':>15} {'max|exact-h| m':>14}"
)
for j, hh in enumerate(heights):
    print(
        f"{hh / 1e3:6.0f} | {np.max(np.abs(r.delta_a[:, j] - hh)):11.2f} "
        f"{1e3 * np.max(np.abs(r.tangent_h[:, j] - hh)):14.3f} "
        f"{1e3 * np.max(np.abs(r.tangent_h_geodetic[:, j] - hh)):15.3f} "
        f"{np.max(np.abs(lat19_err_m[:, j])):12.1f} {np.max(pos_err[:, j]):15.1f} "
        f"{np.max(np.abs(r.exact_h[:, j] - hh)):14.1e}"
    )
