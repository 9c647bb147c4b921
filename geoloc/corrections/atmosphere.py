"""The U.S. Standard Atmosphere 1976 to 86 km, and the refractivity of its air for visible light.

Sources
-------
[USSA76] U.S. Standard Atmosphere, 1976. NOAA-S/T 76-1562, NOAA / NASA / USAF,
    Washington D.C., October 1976. Part 1: the constants, the layers of the linear
    temperature-height profile below 86 km (Table 4),
    the geopotential height (eq. 18), the hydrostatic pressure in a layer
    (eq. 33a for a lapse rate, 33b for an isothermal layer), the density (eq. 42).
[BD93] K. P. Birch and M. J. Downs, "An updated Edlen equation for the refractive
    index of air", Metrologia 30 (1993) 155-162: the dispersion of standard dry air
    (15 degC, 101 325 Pa) and its dependence on pressure and temperature, as
    corrected in Metrologia 31 (1994) 315.

No package is used for the atmosphere: the well-kept ones (``ambiance``, ``fluids``)
are not dependencies of geoloc, and the part needed here is the seven-layer table
below. The values it gives are checked in ``tests/corrections/test_refraction.py`` against the
published tables of [USSA76] (Table I).

Heights are geometric heights above the ellipsoid [m], treated as heights above
mean sea level (the geoid's +-100 m changes the refractivity by at most 1.2 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

#: [USSA76]'s constants: standard gravity [m/s^2], the gas constant [J/(kmol K)], the mean
#: molecular weight of air below 86 km [kg/kmol], the Earth radius of eq. 18 [m].
G0 = 9.80665
R_STAR = 8.31432e3
M0 = 28.9644
R0_EARTH = 6356766.0
#: Specific gas constant of air R*/M0 [J/(kg K)].
R_AIR = R_STAR / M0

#: [USSA76] Table 4: base geopotential height of each layer [m'] and its temperature
#: gradient [K/m'], from the ground to the top of the linear profile at 84.852 km'.
H_BASE = np.array([0.0, 11000.0, 20000.0, 32000.0, 47000.0, 51000.0, 71000.0, 84852.0])
LAPSE = np.array([-6.5e-3, 0.0, 1.0e-3, 2.8e-3, 0.0, -2.8e-3, -2.0e-3])
#: Sea-level temperature [K] and pressure [Pa] of [USSA76].
T_SEA = 288.15
P_SEA = 101325.0

#: Top of the profile: 84.852 km geopotential = 86 km geometric [USSA76 section 1.3].
TOP_M = 86000.0
#: Visible light: the default wavelength [micrometres].
WAVELENGTH_UM = 0.55


def geopotential_height(h_m: ArrayLike) -> np.ndarray:
    """Geopotential height H = r0 h / (r0 + h) (USSA76 eq. 18), in geopotential metres, from geometric height [m]."""
    h = np.asarray(h_m, float)
    return R0_EARTH * h / (R0_EARTH + h)


def geometric_height(H_m: ArrayLike) -> np.ndarray:
    """Geometric height h = r0 H / (r0 - H) [m], the inverse of :func:`geopotential_height`."""
    H = np.asarray(H_m, float)
    return R0_EARTH * H / (R0_EARTH - H)


#: The layer boundaries as geometric heights [m]: 0, 11.019, 20.063, 32.162, 47.350, 51.413,
#: 71.802, 86.000 km. The density has a kink at each (its temperature gradient jumps), so the
#: refraction quadrature puts its panel boundaries there.
LAYER_TOPS_M = geometric_height(H_BASE)


def _base_values(t0: float, p0: float):
    """Temperature [K] and pressure [Pa] at each layer base for sea-level (t0, p0) [USSA76 eq. 33]."""
    gmr = G0 * M0 / R_STAR  # 0.0341632 K/m'
    tb = np.empty(len(H_BASE))
    pb = np.empty(len(H_BASE))
    tb[0], pb[0] = t0, p0
    for i, L in enumerate(LAPSE):
        dH = H_BASE[i + 1] - H_BASE[i]
        tb[i + 1] = tb[i] + L * dH
        if L == 0.0:
            pb[i + 1] = pb[i] * np.exp(-gmr * dH / tb[i])  # eq. 33b
        else:
            pb[i + 1] = pb[i] * (tb[i] / tb[i + 1]) ** (gmr / L)  # eq. 33a
    return tb, pb


@dataclass(frozen=True)
class StandardAtmosphere:
    """The [USSA76] atmosphere below 86 km, its troposphere optionally fitted to a measured ground.

    Parameters
    ----------
    ground_h_m : float
        Height of the ground measurement [m] (used with the two below).
    ground_p_pa, ground_t_k : float or None
        Pressure [Pa] and temperature [K] measured at ``ground_h_m``; ``None`` keeps the
        standard value. The troposphere (below 11 km') then keeps the standard lapse
        rate, -6.5 K/km', through the measured temperature, and its pressure follows the
        hydrostatic law [USSA76 eq. 33a] from the measured pressure; above the
        tropopause the temperatures are the standard ones and the pressure is the
        standard one scaled to meet the troposphere's at 11 km' (pressure is
        continuous; the density can step there when the ground is not standard).
    wavelength_um : float
        Vacuum wavelength for the refractivity [micrometres], 0.3-1.7 (the range of
        [BD93]'s dispersion formula); 0.55 (green) by default.

    Notes
    -----
    Water vapour is ignored: it lowers n - 1 by 3.7e-10 per pascal of vapour
    pressure [BD93], 0.15 % of the dry refractivity at 1 kPa, a humid day.
    """

    ground_h_m: float = 0.0
    ground_p_pa: float | None = None
    ground_t_k: float | None = None
    wavelength_um: float = WAVELENGTH_UM

    def __post_init__(self):
        for name in ("ground_h_m", "ground_p_pa", "ground_t_k", "wavelength_um"):
            v = getattr(self, name)
            if v is not None and not np.isfinite(v):
                raise ValueError(f"StandardAtmosphere: {name} must be finite, got {v!r}")
        if not -1000.0 <= self.ground_h_m < 11000.0:
            raise ValueError(f"StandardAtmosphere: ground_h_m must be in [-1000, 11000) m, got {self.ground_h_m!r}")
        if self.ground_p_pa is not None and not 1e3 < self.ground_p_pa < 2e5:
            raise ValueError(f"StandardAtmosphere: ground_p_pa must be in (1e3, 2e5) Pa, got {self.ground_p_pa!r}")
        if self.ground_t_k is not None and not 150.0 < self.ground_t_k < 350.0:
            raise ValueError(f"StandardAtmosphere: ground_t_k must be in (150, 350) K, got {self.ground_t_k!r}")
        if not 0.3 <= self.wavelength_um <= 1.7:
            raise ValueError(f"StandardAtmosphere: wavelength_um must be in [0.3, 1.7], got {self.wavelength_um!r}")

    # -- the profile -----------------------------------------------------------------------
    def _tables(self):
        return _tables(self.ground_h_m, self.ground_p_pa, self.ground_t_k)

    def temperature_pressure(self, h_m: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Temperature [K] and pressure [Pa] at geometric height ``h_m`` [m] (NaN above 86 km).

        [USSA76] eq. 23 (linear temperature in geopotential height) and eq. 33a/b
        (pressure), layer by layer from the bases of :func:`_base_values`.
        """
        h = np.asarray(h_m, float)
        H = geopotential_height(h)
        tb, pb, ttrop, ptrop_scale, t0, p0 = self._tables()
        gmr = G0 * M0 / R_STAR
        i = np.clip(np.searchsorted(H_BASE, H, side="right") - 1, 0, len(LAPSE) - 1)
        L = LAPSE[i]
        dH = H - H_BASE[i]
        T = tb[i] + L * dH
        with np.errstate(divide="ignore", invalid="ignore"):
            p_lin = pb[i] * (tb[i] / T) ** (gmr / np.where(L == 0.0, 1.0, L))
            p_iso = pb[i] * np.exp(-gmr * dH / tb[i])
        P = np.where(L == 0.0, p_iso, p_lin) * ptrop_scale
        # the troposphere from the (possibly measured) ground: -6.5 K/km' through (t0, p0) at sea level
        trop = H < H_BASE[1]
        T_tr = t0 + LAPSE[0] * H
        with np.errstate(invalid="ignore"):
            P_tr = p0 * (t0 / T_tr) ** (gmr / LAPSE[0])
        T = np.where(trop, T_tr, T)
        P = np.where(trop, P_tr, P)
        bad = ~np.isfinite(h) | (h > TOP_M + 1e-6) | (h < -5000.0)
        return np.where(bad, np.nan, T), np.where(bad, np.nan, P)

    def temperature(self, h_m: ArrayLike) -> np.ndarray:
        """Temperature [K] at geometric height ``h_m`` [m]."""
        return self.temperature_pressure(h_m)[0]

    def pressure(self, h_m: ArrayLike) -> np.ndarray:
        """Pressure [Pa] at geometric height ``h_m`` [m]."""
        return self.temperature_pressure(h_m)[1]

    def density(self, h_m: ArrayLike) -> np.ndarray:
        """Density rho = P M0 / (R* T) in kg/m^3, USSA76 eq. 42."""
        T, P = self.temperature_pressure(h_m)
        return P / (R_AIR * T)

    # -- the refractivity ------------------------------------------------------------------
    def refractivity(self, h_m: ArrayLike) -> np.ndarray:
        """n - 1 of dry air at height ``h_m`` for this wavelength [BD93] (dimensionless).

        (n - 1)_s 1e8 = 8342.54 + 2406147 / (130 - s^2) + 15998 / (38.9 - s^2), s = 1/lambda
        [1/um], for standard air (15 degC, 101 325 Pa); then
        (n - 1)_tp = (n - 1)_s p [1 + 1e-8 (0.601 - 0.00972 t) p] / (96095.43 (1 + 0.003661 t))
        with p [Pa] and t [degC]. Above 86 km the refractivity (1.6e-9 at 86 km) is
        continued with the density's scale height there and cut at 110 km.
        """
        h = np.asarray(h_m, float)
        T, P = self.temperature_pressure(np.minimum(h, TOP_M))
        nm1 = air_refractivity(P, T, self.wavelength_um)
        scale_h = R_AIR * T / G0  # the scale height RT/g at 86 km, 5.5 km
        above = h > TOP_M
        with np.errstate(over="ignore", invalid="ignore"):
            nm1 = np.where(above, nm1 * np.exp(-(h - TOP_M) / scale_h), nm1)
        return np.where(h >= CUT_M, 0.0, nm1)

    def refractive_index(self, h_m: ArrayLike) -> np.ndarray:
        """n = 1 + :meth:`refractivity` at geometric height ``h_m`` [m]."""
        return 1.0 + self.refractivity(h_m)

    def table(self) -> tuple[float, float, np.ndarray]:
        """(h0 [m], step [m], n - 1 at h0 + k step) for the ray tracer: :data:`TABLE_STEP_M` apart."""
        return _refractivity_table(self)


#: Above this height the refractivity is taken as zero [m] (there it is below 2e-11).
CUT_M = 110000.0
#: The ray tracer's table of n - 1: from -1 km to CUT_M every 20 m (5551 values, 44 kB);
#: linear interpolation between its entries is within 2e-6 of n - 1 (its second
#: derivative, (n - 1)/H^2 with scale heights H >= 5.5 km, times step^2 / 8).
TABLE_H0_M = -1000.0
TABLE_STEP_M = 20.0


@lru_cache(maxsize=32)
def _tables(ground_h_m, ground_p_pa, ground_t_k):
    tb, pb = _base_values(T_SEA, P_SEA)
    gmr = G0 * M0 / R_STAR
    Hg = float(geopotential_height(ground_h_m))
    # the sea-level values of the fitted troposphere: through (T_g, P_g) at the ground
    tg = T_SEA + LAPSE[0] * Hg if ground_t_k is None else ground_t_k
    t0 = tg - LAPSE[0] * Hg
    pg_std = P_SEA * (T_SEA / (T_SEA + LAPSE[0] * Hg)) ** (gmr / LAPSE[0])
    pg = pg_std if ground_p_pa is None else ground_p_pa
    p0 = pg * (t0 / tg) ** (-gmr / LAPSE[0])  # eq. 33a from the ground down to sea level
    t_trop = t0 + LAPSE[0] * H_BASE[1]
    p_trop = p0 * (t0 / t_trop) ** (gmr / LAPSE[0])
    return tb, pb, t_trop, p_trop / pb[1], t0, p0


@lru_cache(maxsize=32)
def _refractivity_table(atm: StandardAtmosphere):
    n = int(round((CUT_M - TABLE_H0_M) / TABLE_STEP_M)) + 1
    h = TABLE_H0_M + TABLE_STEP_M * np.arange(n)
    eps = atm.refractivity(h)
    eps.setflags(write=False)
    return TABLE_H0_M, TABLE_STEP_M, eps


def air_refractivity(p_pa: ArrayLike, t_k: ArrayLike, wavelength_um: float = WAVELENGTH_UM) -> np.ndarray:
    """n - 1 of dry air at pressure ``p_pa`` [Pa] and temperature ``t_k`` [K], after [BD93].

    (n - 1)_tp = (n - 1)_s p [1 + 1e-8 (0.601 - 0.00972 t) p] / (96095.43 (1 + 0.003661 t)),
    t in degC; 2.7180e-4 at 20 degC, 101 325 Pa, 633 nm.
    """
    p = np.asarray(p_pa, float)
    t = np.asarray(t_k, float) - 273.15
    return (
        standard_air_refractivity(wavelength_um)
        * p
        * (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p)
        / (96095.43 * (1.0 + 0.003661 * t))
    )


def standard_air_refractivity(wavelength_um: float = WAVELENGTH_UM) -> float:
    """(n - 1) of standard dry air (15 degC, 101 325 Pa) [BD93]: 2.7784e-4 at 0.55 um."""
    s2 = 1.0 / wavelength_um**2
    return (8342.54 + 2406147.0 / (130.0 - s2) + 15998.0 / (38.9 - s2)) * 1e-8


#: The standard atmosphere with no ground measurement, visible light.
STANDARD = StandardAtmosphere()
