"""Triangulation (geoloc.analysis.triangulate) against a weighted least squares written here.

Why: every test of ``tests/analysis/test_triangulate.py`` has rays of the same quality from one
constant-range orbit, so weighting each ray by its covariance instead of its inverse moved the
point by 1e-9 m and no test saw it. Here the rays are of **unequal** quality - ranges from 1.5 to
25 km, directions 20 to 130 deg apart, position and angle errors of different sizes per ray - and
they miss each other by metres (as measured rays do), so the weighting decides where the point is.

The referee is the textbook weighted least squares of the point closest to lines (e.g. Hartley and
Zisserman, *Multiple View Geometry*, 2nd ed., 12.2; Mikhail, *Observations and Least Squares*,
ch. 4), written here without the module's across-ray basis: ray ``i`` through ``O_i`` with unit
direction ``d_i``; its miss at ``X`` is ``P_i (X - O_i)`` with the projector ``P_i = I - d_i d_i^T``;
its covariance there ``Sigma_i = P_i F_i F_i^T P_i`` (``F_i``: the ray's move at the target per
1-sigma source, ``dO + t dD`` at the range ``t``); the weight is its pseudo-inverse
``M_i = pinv(Sigma_i)`` (numpy's SVD) and the normal equations ``(sum M_i) X = sum M_i O_i``. The
first-order covariance is ``J J^T`` with ``J``'s column ``(sum M)^-1 M_i f`` per source and ray (noise)
or summed over the rays (a bias shared by every frame); with noise sources only it is Gauss-Markov's
``(sum M_i)^-1`` (a second, closed-form path). ENU axes at the point from pyproj's latitude and
longitude; LE90 and CE90 from scipy's normal distribution and quadrature.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pyproj import Transformer
from scipy import integrate, optimize, stats

from geoloc.analysis import triangulate as T
from geoloc.status import Status

_TO_LLH = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
_TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)

#: The target: 36.5 N, 84.25 W, 400 m (ECEF by pyproj).
X_TRUE = np.array(_TO_ECEF.transform(-84.25, 36.5, 400.0))
#: Ranges [m] and (azimuth, elevation) [deg] from the target to each camera: unequal on purpose.
RANGES = np.array([1500.0, 4000.0, 9000.0, 25000.0, 6000.0])
AZ_EL = np.array([[10.0, 35.0], [95.0, 60.0], [200.0, 15.0], [290.0, 8.0], [150.0, 80.0]])
#: Each ray's position error [m] and angle error [rad] (1 sigma): a factor 40 between the best and worst.
POS_SIGMA = np.array([0.5, 4.0, 1.0, 20.0, 2.0])
ANG_SIGMA = np.array([2e-4, 1e-4, 8e-4, 5e-5, 1.5e-3])
#: The sources: two independent per frame (noise), one shared by every frame (a bias).
NAMES = ("north_m", "heading_deg", "mount_z_deg")


def _enu_axes(lat, lon):
    """Rows: east, north, up unit vectors in ECEF (the standard local-tangent-plane definition)."""
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def _geometry(seed=5):
    """Origins, unit directions, derivatives dO, dD (n, 3, 3): rays of unequal quality that miss."""
    rng = np.random.default_rng(seed)
    lon, lat, _ = _TO_LLH.transform(*X_TRUE)
    E = _enu_axes(math.radians(lat), math.radians(lon))
    az, el = np.radians(AZ_EL[:, 0]), np.radians(AZ_EL[:, 1])
    up_dir = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1) @ E  # target -> camera
    O = X_TRUE + RANGES[:, None] * up_dir
    n = len(O)
    # each ray aimed a few metres off the target (measured rays never meet): misses of 1-8 m across
    aim = X_TRUE + rng.normal(0.0, 4.0, (n, 3))
    D = aim - O
    D /= np.linalg.norm(D, axis=-1, keepdims=True)
    dO = np.zeros((n, 3, 3))
    dD = np.zeros((n, 3, 3))
    for i in range(n):
        u = rng.normal(size=3)
        dO[i, :, 0] = POS_SIGMA[i] * u / np.linalg.norm(u)  # a position error, any direction
        w = np.cross(D[i], rng.normal(size=3))
        dD[i, :, 1] = ANG_SIGMA[i] * w / np.linalg.norm(w)  # an attitude error: the ray turns
        dO[i, :, 1] = 0.3 * POS_SIGMA[i] * np.cross(w, u) / np.linalg.norm(np.cross(w, u))  # and its lever arm moves
        w2 = np.cross(D[i], E[2])
        dD[i, :, 2] = 3e-4 * w2 / np.linalg.norm(w2)  # a mount bias: the same turn everywhere
    return O, D, dO, dD


def _wls(O, D, Sig=None):
    """The textbook weighted least-squares point: (X, weights M_i); Sig None: the plain projectors."""
    n = len(O)
    P = np.eye(3)[None] - D[:, :, None] * D[:, None, :]
    M = P if Sig is None else np.stack([np.linalg.pinv(Sig[i], rcond=1e-10) for i in range(n)])
    A = M.sum(0)
    X = np.linalg.solve(A, np.einsum("nij,nj->i", M, O))
    return X, M, A


def _reference(O, D, dO, dD, shared=("mount_z_deg",), names=NAMES):
    """The point, its ECEF covariance, the per-ray moves F and the normal matrix A, by the textbook."""
    X0, _, _ = _wls(O, D)  # unweighted: the range to the target
    t = np.einsum("ni,ni->n", X0 - O, D)
    F = dO + t[:, None, None] * dD  # (n, 3, k): each ray's move at the target
    P = np.eye(3)[None] - D[:, :, None] * D[:, None, :]
    Sig = P @ F @ np.swapaxes(F, -1, -2) @ P  # rank 2: the miss across the ray
    X, M, A = _wls(O, D, Sig)
    Ainv = np.linalg.inv(A)
    cols = []
    for k, name in enumerate(names):
        per_ray = [Ainv @ M[i] @ F[i, :, k] for i in range(len(O))]
        cols += [np.sum(per_ray, 0)] if name in shared else per_ray
    J = np.stack(cols, -1)
    return X, J @ J.T, F, A, Sig


def test_unequal_rays_point_is_the_inverse_covariance_weighted_least_squares():
    O, D, dO, dD = _geometry()
    X_ref, _, _, _, Sig = _reference(O, D, dO, dD)
    tri = T.triangulate_rays(O, D, None, NAMES, dO, dD)
    assert tri.status == Status.OK and tri.n_rays == len(O)
    # the same normal equations solved two ways (an SVD pseudo-inverse here, a 2x2 inverse in the
    # module, which also adds 1e-12 m^2 to each covariance: 1e-12 / 0.25 m^2 relative at most):
    # equal to 1 mm
    assert np.linalg.norm(tri.ecef - X_ref) < 1e-3, tri.ecef - X_ref
    # the test has power: the unweighted point and the point weighted by the covariance itself
    # (instead of its inverse) are metres away from the right one
    X_plain, _, _ = _wls(O, D)
    X_wrong, _, _ = _wls(O, D, np.stack([np.linalg.pinv(s, rcond=1e-10) for s in Sig]))
    assert np.linalg.norm(X_plain - X_ref) > 1.0 and np.linalg.norm(X_wrong - X_ref) > 1.0
    # each ray's residual: its perpendicular distance from the point, written out
    r = X_ref - O
    miss = np.linalg.norm(r - np.einsum("ni,ni->n", r, D)[:, None] * D, axis=-1)
    np.testing.assert_allclose(tri.residual_m, miss, atol=2e-3)  # 1 mm in X moves each by 1 mm at most
    # latitude, longitude, height of the point: pyproj's
    lon, lat, h = _TO_LLH.transform(*tri.ecef)
    assert tri.lat_deg == pytest.approx(lat, abs=1e-11) and tri.lon_deg == pytest.approx(lon, abs=1e-11)
    assert tri.h == pytest.approx(h, abs=1e-6)


def test_unequal_rays_covariance_is_first_order_least_squares():
    O, D, dO, dD = _geometry()
    X_ref, cov_ecef, _, _, _ = _reference(O, D, dO, dD)
    tri = T.triangulate_rays(O, D, None, NAMES, dO, dD)
    lon, lat, _ = _TO_LLH.transform(*X_ref)
    E = _enu_axes(math.radians(lat), math.radians(lon))
    cov = E @ cov_ecef @ E.T
    # relative 1e-6 of the largest entry: the module's 1e-12 m^2 regularisation and the two
    # inversions' rounding (the covariances span 5e-3 to 500 m^2)
    np.testing.assert_allclose(tri.cov_enu, cov, rtol=0, atol=1e-6 * np.abs(cov).max())
    # LE90: the two-sided 90 % of the normal law on the up axis (scipy)
    assert tri.le90_m == pytest.approx(stats.norm.ppf(0.95) * math.sqrt(cov[2, 2]), rel=1e-9)
    # the 1-sigma ellipse: the square roots of the horizontal block's eigenvalues
    ev = np.linalg.eigvalsh(cov[:2, :2])
    assert tri.ellipse_major_m == pytest.approx(math.sqrt(ev[1]), rel=1e-6)
    assert tri.ellipse_minor_m == pytest.approx(math.sqrt(ev[0]), rel=1e-6)
    # its azimuth (clockwise from north) from the major eigenvector
    w, V = np.linalg.eigh(cov[:2, :2])
    az = math.degrees(math.atan2(V[0, 1], V[1, 1])) % 180.0
    assert abs((tri.ellipse_azimuth_deg - az + 90.0) % 180.0 - 90.0) < 1e-4
    # CE90: P(|e| <= R) = 0.9 for e ~ N(0, diag(major^2, minor^2)), by quadrature and a root
    a, b = math.sqrt(ev[1]), math.sqrt(ev[0])

    def p_inside(R):
        f = lambda x: stats.norm.pdf(x, scale=a) * (2 * stats.norm.cdf(math.sqrt(max(R * R - x * x, 0)), scale=b) - 1)
        return integrate.quad(f, -R, R, epsabs=1e-12, epsrel=1e-10)[0]

    R90 = optimize.brentq(lambda R: p_inside(R) - 0.9, 1e-3 * a, 5 * a, xtol=1e-12)
    assert tri.ce90_m == pytest.approx(R90, rel=1e-6)  # the module's table: < 1e-7 of R


def test_noise_only_covariance_is_gauss_markov():
    """With independent sources only, first-order propagation through the weighted least squares
    is (sum M_i)^-1 (the weights are the inverse covariances): a closed form, no Jacobian."""
    O, D, dO, dD = _geometry()
    _, _, _, A, _ = _reference(O, D, dO[..., :2], dD[..., :2], shared=(), names=NAMES[:2])
    tri = T.triangulate_rays(O, D, None, NAMES[:2], dO[..., :2], dD[..., :2], shared=frozenset())
    lon, lat, _ = _TO_LLH.transform(*tri.ecef)
    E = _enu_axes(math.radians(lat), math.radians(lon))
    cov = E @ np.linalg.inv(A) @ E.T
    np.testing.assert_allclose(tri.cov_enu, cov, rtol=0, atol=1e-6 * np.abs(cov).max())


def test_a_bias_shared_by_every_frame_is_summed_before_squaring():
    """The shared mount source is one column (the rays' moves summed), so its variance is the
    square of the sum, not the sum of the squares (what treating it as noise would give): the
    module's covariance is the first reading, and the second differs from it by more than 10 %."""
    O, D, dO, dD = _geometry()
    tri = T.triangulate_rays(O, D, None, NAMES, dO, dD)
    lon, lat, _ = _TO_LLH.transform(*tri.ecef)
    E = _enu_axes(math.radians(lat), math.radians(lon))
    _, shared_cov, _, _, _ = _reference(O, D, dO, dD)
    _, noise_cov, _, _, _ = _reference(O, D, dO, dD, shared=())
    cov, noise = E @ shared_cov @ E.T, E @ noise_cov @ E.T
    np.testing.assert_allclose(tri.cov_enu, cov, rtol=0, atol=1e-6 * np.abs(cov).max())
    assert np.abs(noise - cov).max() > 0.1 * np.abs(cov).max()
    # and a source named as shared by the caller is summed too
    tri2 = T.triangulate_rays(O, D, None, NAMES, dO, dD, shared=frozenset({"heading_deg", "mount_z_deg"}))
    _, both, _, _, _ = _reference(O, D, dO, dD, shared=("heading_deg", "mount_z_deg"))
    np.testing.assert_allclose(tri2.cov_enu, E @ both @ E.T, rtol=0, atol=1e-6 * np.abs(cov).max())


def test_a_ray_left_out_is_not_weighted_and_has_no_residual():
    O, D, dO, dD = _geometry()
    ok = np.array([True, True, False, True, True])
    keep = np.flatnonzero(ok)
    X_ref, _, _, _, _ = _reference(O[keep], D[keep], dO[keep], dD[keep])
    tri = T.triangulate_rays(O, D, ok, NAMES, dO, dD)
    assert tri.n_rays == 4 and np.isnan(tri.residual_m[2]) and np.all(np.isfinite(tri.residual_m[keep]))
    assert np.linalg.norm(tri.ecef - X_ref) < 1e-3


# ------------------------------------------------------------------ the DEM offset's standard error


def _tri_with_cov(cov_enu):
    X = X_TRUE
    lon, lat, h = _TO_LLH.transform(*X)
    return T.Triangulation(
        X,
        math.radians(lat),
        math.radians(lon),
        h,
        4,
        np.zeros(4),
        None if cov_enu is None else np.asarray(cov_enu, float),
    )


def test_dem_offset_standard_error_with_the_triangulations_own_term():
    """se = sqrt(s^2 / n + sigma_up^2): the frames' scatter (sample standard deviation, n - 1)
    over sqrt(n), and the triangulated height's own 1-sigma (the up-up entry of its ENU
    covariance) - here 20 m, larger than the scatter, so it decides the verdict."""
    cov = np.array([[4.0, 1.0, 0.5], [1.0, 9.0, 0.7], [0.5, 0.7, 400.0]])  # up sigma 20 m; E, N smaller
    tri = _tri_with_cov(cov)
    d = np.array([48.0, 50.5, 51.0, 52.5])  # DEM minus triangulated: mean 50.5 m
    c = T.compare_with_surface(tri, tri.h + d)
    n = d.size
    s2 = np.sum((d - d.mean()) ** 2) / (n - 1)
    se = math.sqrt(s2 / n + 400.0)
    assert c["mean_m"] == pytest.approx(50.5, abs=1e-9)
    assert c["se_m"] == pytest.approx(se, rel=1e-12)
    assert c["warning"] == ""  # 50.5 m < 3 x 20.1 m: the triangulation itself is that uncertain
    # the same offsets with a 5 m up sigma: now 50.5 m is 3 standard errors and more away
    tight = cov.copy()
    tight[2, 2] = 25.0
    c2 = T.compare_with_surface(_tri_with_cov(tight), tri.h + d)
    assert c2["se_m"] == pytest.approx(math.sqrt(s2 / n + 25.0), rel=1e-12)
    assert "likely DEM or datum error" in c2["warning"] and "+50.5 m" in c2["warning"] and "4 frames" in c2["warning"]


def test_dem_offset_scatter_term_and_the_frames_left_out():
    """Without a covariance only the scatter counts: s / sqrt(n) with the n - 1 sample deviation
    (n = 3 here, so n against n - 1 is a factor 1.22); NaN heights and frames flagged not OK are
    left out; a mean under 5 m is never reported, a single frame has no scatter."""
    tri = _tri_with_cov(None)
    d = np.array([10.0, 14.0, np.nan, 12.0, 400.0])
    ok = np.array([True, True, True, True, False])
    c = T.compare_with_surface(tri, tri.h + d, ok)
    v = np.array([10.0, 14.0, 12.0])
    se = math.sqrt(np.sum((v - 12.0) ** 2) / 2) / math.sqrt(3)
    assert c["mean_m"] == pytest.approx(12.0, abs=1e-9) and c["se_m"] == pytest.approx(se, rel=1e-12)
    assert "likely DEM" in c["warning"] and "3 frames" in c["warning"]  # 12 > 3 x 1.15 and > 5 m
    np.testing.assert_allclose(c["differences_m"], d, atol=1e-9)
    small = T.compare_with_surface(tri, tri.h + np.array([4.9, 4.9, 4.9]))  # se 0: only the 5 m floor holds
    assert small["se_m"] == 0.0 and small["warning"] == ""
    one = T.compare_with_surface(_tri_with_cov(np.diag([1.0, 1.0, 4.0])), np.array([tri.h + 30.0]))
    assert one["se_m"] == pytest.approx(2.0, rel=1e-12) and "1 frames" in one["warning"]
    none = T.compare_with_surface(tri, np.array([np.nan, np.nan]))
    assert math.isnan(none["mean_m"]) and math.isnan(none["se_m"]) and none["warning"] == ""


@pytest.mark.parametrize(
    "mean_m,sigma_up_m,warned",
    [
        (35.0, 10.0, True),  # 3.5 standard errors: over 3 (a threshold of 4 would keep quiet)
        (25.0, 10.0, False),  # 2.5 standard errors: under 3 (a threshold of 2 would warn)
        (5.5, 0.1, True),  # 55 standard errors and over the 5 m floor (a 6 m floor would keep quiet)
        (4.5, 0.1, False),  # under the 5 m floor (a 4 m floor would warn)
        (-35.0, 10.0, True),  # below the triangulated point as well
    ],
)
def test_dem_offset_verdict_on_both_sides_of_each_threshold(mean_m, sigma_up_m, warned):
    """Every frame the same difference (no scatter): the standard error is the up sigma alone,
    and the verdict is |mean| > 3 se and |mean| > 5 m, as the docstring states."""
    tri = _tri_with_cov(np.diag([1.0, 1.0, sigma_up_m**2]))
    c = T.compare_with_surface(tri, tri.h + np.full(6, mean_m))
    assert c["se_m"] == pytest.approx(sigma_up_m, rel=1e-12)
    assert bool(c["warning"]) == warned, c


#: Nadir directions along simple ECEF axes (exact): where a ray straight down points along z,
#: x, (+-1, 0, 1) or (0, +-1, 1) - the directions a basis across the ray could be built from.
NADIR_AXES = {
    (90.0, 0.0): (0.0, 0.0, 1.0),
    (-90.0, 0.0): (0.0, 0.0, -1.0),
    (0.0, 0.0): (1.0, 0.0, 0.0),
    (45.0, 0.0): (1.0, 0.0, 1.0),
    (45.0, 180.0): (-1.0, 0.0, 1.0),
    (45.0, 90.0): (0.0, 1.0, 1.0),
    (45.0, -90.0): (0.0, -1.0, 1.0),
}


@pytest.mark.parametrize("lat_deg,lon_deg", list(NADIR_AXES))
def test_a_nadir_ray_along_any_axis_is_weighted_like_the_others(lat_deg, lon_deg):
    """A ray straight down at a pole runs along the ECEF z axis, at 0 N 0 E along x, at 45 N along
    (+-1, 0, 1) or (0, +-1, 1): directions that a basis across the ray must not be built from.
    With the other rays of unequal quality, the point is still the textbook weighted least squares."""
    X = np.array(_TO_ECEF.transform(lon_deg, lat_deg, 100.0))
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    E = _enu_axes(lat, lon)
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    rng = np.random.default_rng(9)
    O = np.stack([X + 3000.0 * up, X + 5000.0 * (0.6 * E[0] + 0.8 * E[2]), X + 8000.0 * (-0.5 * E[1] + 0.866 * E[2])])
    D = np.stack([-up, X - O[1] + rng.normal(0, 3, 3), X - O[2] + rng.normal(0, 3, 3)])
    D /= np.linalg.norm(D, axis=-1, keepdims=True)
    # the nadir exactly along the axis (cos(pi/2) = 6e-17 in floating point would leave it 1e-16 off)
    axis = np.array(NADIR_AXES[(lat_deg, lon_deg)])
    axis /= np.linalg.norm(axis)
    D[0] = -axis
    assert np.all(np.cross(D[0], axis) == 0.0) and np.allclose(D[0], -up, atol=1e-15)
    dO = np.zeros((3, 3, 3))
    dD = np.zeros((3, 3, 3))
    for i, (sp, sa) in enumerate([(0.5, 1e-3), (6.0, 2e-4), (2.0, 5e-4)]):
        dO[i, :, 0] = sp * E[0] + 0.3 * sp * E[1]
        w = np.cross(D[i], rng.normal(size=3))
        dD[i, :, 1] = sa * w / np.linalg.norm(w)
        w2 = np.cross(D[i], E[0])
        dD[i, :, 2] = 2e-4 * w2 / np.linalg.norm(w2)
    X_ref, cov_ecef, _, _, _ = _reference(O, D, dO, dD)
    tri = T.triangulate_rays(O, D, None, NAMES, dO, dD)
    assert tri.status == Status.OK and np.all(np.isfinite(tri.cov_enu))
    assert np.linalg.norm(tri.ecef - X_ref) < 1e-3
    # ENU at the point found (at a pole its longitude is that of the point, not of the pole)
    plon, plat, _ = _TO_LLH.transform(*X_ref)
    Ep = _enu_axes(math.radians(plat), math.radians(plon))
    np.testing.assert_allclose(tri.cov_enu, Ep @ cov_ecef @ Ep.T, rtol=0, atol=1e-6 * np.abs(cov_ecef).max())
    plain = T.triangulate_rays(O, D)
    assert np.linalg.norm(plain.ecef - _wls(O, D)[0]) < 1e-3


def test_two_rays_suffice_and_rays_within_the_minimum_angle_are_refused():
    """Two rays whose directions are 1.5 deg apart: a point (the textbook one); 0.5 deg apart, or
    with the minimum raised to 2 deg: INVALID_INPUT and NaN; no usable ray, or one: refused."""
    O, D, dO, dD = _geometry()
    lon, lat, _ = _TO_LLH.transform(*X_TRUE)
    E = _enu_axes(math.radians(lat), math.radians(lon))
    O2 = np.stack(
        [
            X_TRUE + 5000.0 * E[2],
            X_TRUE + 5000.0 * (math.cos(math.radians(1.5)) * E[2] + math.sin(math.radians(1.5)) * E[0]),
        ]
    )
    D2 = X_TRUE + np.array([[0.0, 0.0, 0.0], [3.0, -2.0, 1.0]]) - O2
    D2 /= np.linalg.norm(D2, axis=-1, keepdims=True)
    ang = math.degrees(math.acos(float(D2[0] @ D2[1])))
    assert 1.0 < ang < 2.0
    two = T.triangulate_rays(O2, D2)
    assert two.status == Status.OK and two.n_rays == 2
    assert np.linalg.norm(two.ecef - _wls(O2, D2)[0]) < 1e-3
    assert T.triangulate_rays(O2, D2, min_angle_deg=2.0).status == Status.INVALID_INPUT
    O3 = np.stack([O2[0], X_TRUE + 5000.0 * (math.cos(math.radians(0.5)) * E[2] + math.sin(math.radians(0.5)) * E[0])])
    D3 = X_TRUE - O3
    narrow = T.triangulate_rays(O3, D3)
    assert narrow.status == Status.INVALID_INPUT and np.all(np.isnan(narrow.ecef)) and math.isnan(narrow.h)
    none = T.triangulate_rays(O, D, np.zeros(len(O), bool), NAMES, dO, dD)
    assert none.status == Status.INVALID_INPUT and none.n_rays == 0 and np.all(np.isnan(none.residual_m))
    one = T.triangulate_rays(O, D, np.eye(len(O), dtype=bool)[0], NAMES, dO, dD)
    assert one.status == Status.INVALID_INPUT and one.n_rays == 1


def test_dem_offset_at_exactly_three_standard_errors_or_five_metres_is_not_reported():
    """The verdict is strict (|mean| > 3 SE and |mean| > 5 m): at exactly 3 SE (30 m, an up sigma
    of 10 m, no scatter) or exactly 5 m, nothing; a metre more, the warning. Heights chosen so that
    every difference is exact in floating point."""

    def tri(sig2):
        return T.Triangulation(X_TRUE, 0.6, -1.4, 400.0, 4, np.zeros(4), np.diag([1.0, 1.0, sig2]))

    at = T.compare_with_surface(tri(100.0), np.full(5, 430.0))
    assert at["mean_m"] == 30.0 and at["se_m"] == 10.0 and at["warning"] == ""
    assert T.compare_with_surface(tri(100.0), np.full(5, 431.0))["warning"]
    five = T.compare_with_surface(tri(0.25), np.full(5, 405.0))
    assert five["mean_m"] == 5.0 and five["se_m"] == 0.5 and five["warning"] == ""
    assert T.compare_with_surface(tri(0.25), np.full(5, 406.0))["warning"]
