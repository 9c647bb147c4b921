"""The sensor's error budget: the ``[uncertainty]`` table of a sensor file.

Every value is the **standard deviation (1 sigma) of a zero-mean normal error**, in the
unit its key names (``docs/sensor_format.md``, "The error budget"; the propagation that
uses it: :mod:`geoloc.analysis.uncertainty`, ``docs/uncertainty.md``)::

    [uncertainty]
    north_m = 2.0            # platform position (navigation reference), local north [m]
    east_m = 2.0
    up_m = 3.0
    heading_deg = 0.05       # attitude [deg]
    pitch_deg = 0.02
    roll_deg = 0.02
    azimuth_deg = 0.01       # each gimbal joint by its angle name + _deg
    elevation_deg = 0.01
    mount_x_deg = 0.01       # mount, boresight [deg]; lever arm [m]
    boresight_z_deg = 0.01
    lever_arm_x_m = 0.05
    time_s = 0.005           # time tag: the platform moves v * dt (needs its velocity)
    fx_px = 2.0              # lens: focal lengths, principal point, skew [px]; k1.. dimensionless
    cx_px = 0.5
    height_m = 10.0          # a constant target height's vertical error [m]
    dem_m = 9.73             # a DEM's vertical error [m] (or dem_product = "srtm")
    refraction = 0.05        # atmospheric refraction: a fraction of the standard atmosphere's shift

This module is data and checking only (layer 4, beside the sensor file); the numbers'
meaning in the geometry is :mod:`geoloc.analysis.uncertainty`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from geoloc.sensors.frame import FrameSensor

#: LE90 / sigma of a normal error: the 0.95 quantile of N(0, 1) (a two-sided 90 % interval).
LE90_PER_SIGMA = 1.6448536269514722

#: Published vertical accuracy of DEM products, as LE90 (90 % linear error) [m], and where it comes from.
#: ``dem_product = NAME`` in a budget takes sigma = LE90 / 1.6449.
DEM_PRODUCTS = {
    "srtm": (
        16.0,
        "SRTM's mission specification of absolute vertical accuracy, 16 m at 90 % (LE90; "
        "sigma 9.73 m): Farr et al. 2007, 'The Shuttle Radar Topography Mission', Rev. Geophys. "
        "45, RG2004, doi:10.1029/2005RG000183; the same 16 m / RMSE 9.73 m is quoted as the "
        "consensus figure by Mukul et al. 2017, Sci. Rep. 7, 41672. The errors measured against "
        "ground truth, as 90 % errors per continent, are Rodriguez et al. 2006, 'A global "
        "assessment of the SRTM performance', PE&RS 72(3), 249-260, doi:10.14358/PERS.72.3.249; "
        "the specification is kept as the conservative default",
    ),
    "copernicus-glo30": (
        4.0,
        "Copernicus DEM GLO-30 product handbook: absolute vertical accuracy < 4 m at 90 % (LE90)",
    ),
}

#: The bundled DEMs (``assets/dem``) and the product each one is a crop of (None: no published
#: figure; a budget used with it must give ``dem_m``).
BUNDLED_DEMS = {
    "srtm_jacksboro.tif": "srtm",
    # ETOPO5 (NOAA NGDC, 1988) publishes no single vertical accuracy: its land heights come from
    # several older grids, and on 5' (9 km) cells the error is mostly the terrain between the nodes.
    "etopo5_flight_area.tif": None,
}

#: Keys of the platform and the surface (fixed names), with their unit and meaning.
FIXED_KEYS = {
    "north_m": "platform position, local north [m]",
    "east_m": "platform position, local east [m]",
    "up_m": "platform position, up (ellipsoidal height) [m]",
    "heading_deg": "attitude heading [deg]",
    "pitch_deg": "attitude pitch [deg]",
    "roll_deg": "attitude roll [deg]",
    "time_s": "time tag [s] (the platform moves by its velocity times the error)",
    "height_m": "vertical error of a constant target height [m]",
    "dem_m": "vertical error of the DEM [m]",
    "refraction": "atmospheric refraction, as a fraction of the standard atmosphere's shift (dimensionless; "
    "0.05 for a day's weather against the yearly mean, 1.0 for refraction left out)",
}
#: The sensor's own parameters (``FrameSensor.params``), degrees and metres at this edge.
SENSOR_KEYS = {
    **{f"mount_{a}_deg": f"mount angle {a} [deg]" for a in "xyz"},
    **{f"boresight_{a}_deg": f"boresight angle {a} [deg]" for a in "xyz"},
    **{f"lever_arm_{a}_m": f"lever arm {a} (body axes) [m]" for a in "xyz"},
}
#: The lens's parameters (``Lens.params``): key -> parameter name. Pixels, or dimensionless.
LENS_KEYS = {
    "fx_px": "fx",
    "fy_px": "fy",
    "cx_px": "cx",
    "cy_px": "cy",
    "skew_px": "skew",
    **{k: k for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")},
}


@dataclass(frozen=True)
class ErrorBudget:
    """A sensor's error budget: 1-sigma normal errors in edge units (degrees, metres, pixels, seconds).

    Attributes
    ----------
    sigmas : dict
        Key (``north_m``, ``heading_deg``, ``<angle>_deg``, ``mount_x_deg``, ``fx_px``, ``k1``,
        ``time_s``, ``height_m``, ``dem_m``, ...) -> standard deviation (>= 0) in the key's unit.
    dem_product : str or None
        A DEM product of :data:`DEM_PRODUCTS` whose published LE90 gives the DEM's sigma.
    source : str
        Where the budget came from (for error messages).
    """

    sigmas: dict = field(default_factory=dict)
    dem_product: str | None = None
    source: str = "budget"

    def sigma(self, key: str) -> float:
        """The key's sigma in its edge unit (0 when the budget does not give it)."""
        return float(self.sigmas.get(key, 0.0))

    def scaled(self, factor: float) -> "ErrorBudget":
        """Every sigma times ``factor`` (the DEM product's too: it becomes an explicit ``dem_m``)."""
        s = {k: v * factor for k, v in self.sigmas.items()}
        if self.dem_product is not None and "dem_m" not in s:
            s["dem_m"] = DEM_PRODUCTS[self.dem_product][0] / LE90_PER_SIGMA * factor
        return ErrorBudget(s, None, self.source)

    def dem_sigma_m(self, dem: object = None) -> float:
        """The DEM's vertical sigma [m]: ``dem_m``, else ``dem_product``'s LE90 / 1.6449, else the
        bundled DEM's product (by its file name); ValueError naming what is missing."""
        if "dem_m" in self.sigmas:
            return float(self.sigmas["dem_m"])
        product = self.dem_product
        name = None
        path = getattr(dem, "path", None)  # a DEM raster read from a file (a mosaic has paths)
        if product is None and path is not None:
            from pathlib import Path

            name = Path(str(path)).name
            product = BUNDLED_DEMS.get(name)
        if product is None:
            what = f" (the bundled {name} has no published vertical accuracy)" if name in BUNDLED_DEMS else ""
            raise ValueError(
                f"{self.source}: [uncertainty] gives no DEM vertical error{what}: set dem_m "
                f"(sigma, metres) or dem_product (one of {sorted(DEM_PRODUCTS)})"
            )
        return DEM_PRODUCTS[product][0] / LE90_PER_SIGMA


def budget_from_dict(table: object, sensor: FrameSensor, source: str = "sensor") -> ErrorBudget:
    """Check the ``[uncertainty]`` table against ``sensor`` (its gimbal's angle names, its lens).

    Every key must be known (:data:`FIXED_KEYS`, the gimbal's ``<angle>_deg``, :data:`SENSOR_KEYS`
    but no mount on an earth-referenced gimbal, the lens's :data:`LENS_KEYS`) and every value a
    finite number >= 0; ValueError names the key, the value and the file.
    """
    where = f"{source}: [uncertainty]"
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table of standard deviations, got {table!r}")
    allowed = dict(FIXED_KEYS)
    allowed.update({f"{a}_deg": f"gimbal joint {a} [deg]" for a in sensor.angle_names})
    allowed.update(
        {k: v for k, v in SENSOR_KEYS.items() if not (sensor.gimbal.earth_referenced and k.startswith("mount_"))}
    )
    lens_params = sensor.lens.params
    allowed.update({k: f"lens {p}" for k, p in LENS_KEYS.items() if p in lens_params})
    sigmas, product = {}, None
    for k, v in table.items():
        if k == "dem_product":
            if v not in DEM_PRODUCTS:
                raise ValueError(f"{where} dem_product = {v!r}: must be one of {sorted(DEM_PRODUCTS)}")
            product = v
            continue
        if k not in allowed:
            hint = ""
            if k in LENS_KEYS:
                hint = f" (the {sensor.lens.model} lens has no parameter {LENS_KEYS[k]!r})"
            elif k.startswith("mount_") and sensor.gimbal.earth_referenced:
                hint = f" (the earth-referenced {sensor.gimbal.name} gimbal has no mount)"
            elif k.endswith("_deg"):
                hint = f" (the {sensor.gimbal.name} gimbal's angles are {list(sensor.angle_names)})"
            raise ValueError(f"{where}: unknown key {k!r}{hint}; allowed: {sorted(allowed) + ['dem_product']}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ValueError(f"{where} {k} = {v!r}: must be a standard deviation >= 0 ({allowed[k]})")
        sigmas[k] = float(v)
    if product is not None and "dem_m" in sigmas:
        raise ValueError(f"{where}: give dem_m or dem_product, not both")
    return ErrorBudget(sigmas, product, source)


def budget_to_dict(budget: ErrorBudget) -> dict:
    """The ``[uncertainty]`` table that :func:`budget_from_dict` reads back to ``budget``."""
    out = dict(budget.sigmas)
    if budget.dem_product is not None:
        out["dem_product"] = budget.dem_product
    return out
