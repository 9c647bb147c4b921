"""Rational polynomial (RPC00B) sensor model and the RPC as a :class:`~geoloc.sensors.base.Sensor`.

Conventions: ``docs/conventions.md``; user guide ``docs/rpc.md`` [L12 section 4.1].

An RPC maps geodetic (latitude P, longitude L, ellipsoidal height H) to the
image: with normalised values ``Pn = (P - LAT_OFF) / LAT_SCALE`` (and the same
for L, H, line and sample),

    line_n = LINE_NUM(Ln, Pn, Hn) / LINE_DEN(Ln, Pn, Hn)
    samp_n = SAMP_NUM(Ln, Pn, Hn) / SAMP_DEN(Ln, Pn, Hn)

with four cubic polynomials of 20 terms each in the RPC00B order (the order
GDAL uses): 1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P,
P^3, PH^2, L^2H, P^2H, H^3. The two denominators' constant terms are 1, so a
model has 4 x 20 - 2 = 78 free coefficients.

Pixels. The format's image coordinates have (0, 0) at the *centre* of the
upper-left pixel. GDAL's RPC transformer (``alg/gdal_rpc.cpp``,
``RPCTransformPoint``) adds 0.5 to reach its own pixel/line space, where
(0, 0) is the upper-left *corner* and (0.5, 0.5) the centre of the first
pixel (checked against rasterio's ``RPCTransformer`` in ``tests/analysis/test_rpc.py``).
This project's pixels are 1-based centres, so

    row = RPC line + 1 = GDAL line + 0.5,    col = RPC sample + 1 = GDAL pixel + 0.5.

:class:`RPCModel` holds the coefficients; :class:`RPCSensor` is the RPC behind
the common sensor interface (``docs/architecture.md``): ``ground_to_pixel`` is
the RPC itself with a domain check, ``line_of_sight`` comes from the model (the
pixel's ground points at two heights), and ``params`` are the image-space bias
/ affine correction of Grodecki & Dial (PE&RS 69(1), 2003) that
:func:`geoloc.analysis.rpc_adjust.adjust_rpc` fits to ground control points.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.sensors.base import PixelHit, check_outside, check_param_names, flag_outside, in_sensor, replace_params
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight

#: Names of the 20 RPC00B terms, in order (L = longitude, P = latitude, H = height).
TERMS = (
    "1",
    "L",
    "P",
    "H",
    "LP",
    "LH",
    "PH",
    "LL",
    "PP",
    "HH",
    "PLH",
    "LLL",
    "LPP",
    "LHH",
    "LLP",
    "PPP",
    "PHH",
    "LLH",
    "PPH",
    "HHH",
)

#: The image-space correction parameters of :class:`RPCSensor` (Grodecki & Dial 2003).
PARAM_NAMES = ("row_bias", "row_per_row", "row_per_col", "col_bias", "col_per_row", "col_per_col")

#: The GDAL "RPC" metadata keys (RFC 22) that carry one number each.
_SCALAR_KEYS = (
    "LINE_OFF",
    "SAMP_OFF",
    "LAT_OFF",
    "LONG_OFF",
    "HEIGHT_OFF",
    "LINE_SCALE",
    "SAMP_SCALE",
    "LAT_SCALE",
    "LONG_SCALE",
    "HEIGHT_SCALE",
)
_COEFF_KEYS = ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF")


def rpc_terms(L: ArrayLike, P: ArrayLike, H: ArrayLike) -> np.ndarray:
    """The 20 cubic terms of RPC00B for normalised (L, P, H), shape (..., 20)."""
    L, P, H = np.broadcast_arrays(np.asarray(L, float), np.asarray(P, float), np.asarray(H, float))
    one = np.ones_like(L)
    return np.stack(
        [
            one,
            L,
            P,
            H,
            L * P,
            L * H,
            P * H,
            L * L,
            P * P,
            H * H,
            P * L * H,
            L**3,
            L * P * P,
            L * H * H,
            L * L * P,
            P**3,
            P * H * H,
            L * L * H,
            P * P * H,
            H**3,
        ],
        axis=-1,
    )


def _cubic_in_lp(c, H):
    """The ten coefficients (arrays over H) of an RPC00B polynomial seen as a cubic in (L, P) at height H.

    Order: 1, L, P, LP, LL, PP, LLL, LPP, LLP, PPP.
    """
    H = np.asarray(H, float)
    return (
        c[0] + H * (c[3] + H * (c[9] + H * c[19])),
        c[1] + H * (c[5] + H * c[13]),
        c[2] + H * (c[6] + H * c[16]),
        c[4] + H * c[10],
        c[7] + H * c[17],
        c[8] + H * c[18],
        np.full(H.shape, c[11]),
        np.full(H.shape, c[12]),
        np.full(H.shape, c[14]),
        np.full(H.shape, c[15]),
    )


def _eval_cubic(a, L, P):
    """Value and (d/dL, d/dP) of the cubic of :func:`_cubic_in_lp`."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8, a9 = a
    LL, PP, LP = L * L, P * P, L * P
    v = a0 + a1 * L + a2 * P + a3 * LP + a4 * LL + a5 * PP + a6 * LL * L + a7 * L * PP + a8 * LL * P + a9 * PP * P
    dL = a1 + a3 * P + 2 * a4 * L + 3 * a6 * LL + a7 * PP + 2 * a8 * LP
    dP = a2 + a3 * L + 2 * a5 * P + 2 * a7 * LP + a8 * LL + 3 * a9 * PP
    return v, dL, dP


def _parse_number(key, text):
    try:
        return float(str(text).split()[0])  # "+003437.00 pixels" (a _RPC.TXT) -> 3437.0
    except (ValueError, IndexError):
        raise ValueError(f"RPC metadata: {key} = {text!r} is not a number") from None


@dataclass(frozen=True)
class RPCModel:
    """One RPC00B model (the 78 coefficients and 10 normalisation constants).

    Offsets and scales are in the units of the format: degrees (lat, long),
    metres above the WGS-84 ellipsoid (height), pixels with (0, 0) at the
    centre of the upper-left pixel (line, samp). Coefficient arrays have 20
    entries; ``line_den[0]`` and ``samp_den[0]`` are 1.
    """

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num: np.ndarray
    line_den: np.ndarray
    samp_num: np.ndarray
    samp_den: np.ndarray
    err_bias: float = -1.0
    err_rand: float = -1.0

    def normalise(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Normalised (Ln, Pn, Hn) from latitude, longitude [rad] and height [m]."""
        lat_deg, lon_deg = np.rad2deg(lat), np.rad2deg(lon)
        dl = (lon_deg - self.long_off + 180.0) % 360.0 - 180.0  # the antimeridian, as GDAL
        return (
            dl / self.long_scale,
            (lat_deg - self.lat_off) / self.lat_scale,
            (np.asarray(h, float) - self.height_off) / self.height_scale,
        )

    def denormalise(self, Ln: ArrayLike, Pn: ArrayLike, Hn: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse of :meth:`normalise`: (lat, lon [rad], h [m]); longitude wrapped to [-pi, pi)."""
        lon_deg = (np.asarray(Ln, float) * self.long_scale + self.long_off + 180.0) % 360.0 - 180.0
        lat_deg = np.asarray(Pn, float) * self.lat_scale + self.lat_off
        return np.deg2rad(lat_deg), np.deg2rad(lon_deg), np.asarray(Hn, float) * self.height_scale + self.height_off

    def normalised_image(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Normalised (line_n, samp_n) of ground points: the two ratios of the RPC."""
        T = rpc_terms(*self.normalise(lat, lon, h))
        with np.errstate(invalid="ignore", divide="ignore"):
            ln = np.einsum("...i,i->...", T, self.line_num) / np.einsum("...i,i->...", T, self.line_den)
            sn = np.einsum("...i,i->...", T, self.samp_num) / np.einsum("...i,i->...", T, self.samp_den)
        return ln, sn

    def ground_to_pixel(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Ground (lat, lon [rad], ellipsoidal h [m]) -> 1-based (row, col) by the RPC equations.

        No domain check and no status (see :meth:`RPCSensor.ground_to_pixel` for both).

        Returns
        -------
        row, col : ndarray
        """
        ln, sn = self.normalised_image(lat, lon, h)
        return ln * self.line_scale + self.line_off + 1.0, sn * self.samp_scale + self.samp_off + 1.0

    def image_size(self) -> tuple[int, int]:
        """(rows, cols) implied by the offsets and scales: ``floor(OFF + SCALE + 0.5)`` per axis.

        The normalised image coordinate +1 is taken to fall in the last pixel
        (RPC coordinate ``rows - 1``, whose pixel extends to ``rows - 0.5``).
        Exact for RPCs of :func:`geoloc.analysis.rpc_fit.fit_rpc` (OFF = (n - 1) / 2,
        SCALE = n / 2) and for the usual vendor choice OFF = SCALE = n / 2; an
        estimate otherwise: give the image size when it is known.
        """
        return (math.floor(self.line_off + self.line_scale + 0.5), math.floor(self.samp_off + self.samp_scale + 0.5))

    # ------------------------------------------------------------ GDAL I/O
    def to_gdal(self) -> dict:
        """The GDAL "RPC" metadata domain (RFC 22) as a dict of strings."""

        def f(v):
            return f"{float(v):.15g}"

        md = {
            k.upper(): f(getattr(self, k))
            for k in (
                "line_off",
                "samp_off",
                "lat_off",
                "long_off",
                "height_off",
                "line_scale",
                "samp_scale",
                "lat_scale",
                "long_scale",
                "height_scale",
                "err_bias",
                "err_rand",
            )
        }
        for k in ("line_num", "line_den", "samp_num", "samp_den"):
            md[f"{k.upper()}_COEFF"] = " ".join(f(v) for v in getattr(self, k))
        return md

    @classmethod
    def from_gdal(cls, md: Mapping[str, Any]) -> RPCModel:
        """From the GDAL "RPC" metadata domain (a dict of strings, as ``dataset.tags(ns="RPC")``).

        Trailing units (``"3437.00 pixels"``) are ignored; a missing or bad key is
        a ValueError naming it.
        """
        md = {str(k).upper(): v for k, v in dict(md).items()}
        missing = [k for k in _SCALAR_KEYS + _COEFF_KEYS if k not in md]
        if missing:
            raise ValueError(f"RPC metadata: missing key(s) {missing}")
        vals = {k.lower(): _parse_number(k, md[k]) for k in _SCALAR_KEYS}
        coef = {}
        for k in _COEFF_KEYS:
            parts = str(md[k]).replace(",", " ").split()
            if len(parts) != 20:
                raise ValueError(f"RPC metadata: {k} has {len(parts)} values, RPC00B needs 20")
            coef[k] = np.array([_parse_number(k, p) for p in parts])
        errs = [_parse_number(k, md[k]) if k in md else -1.0 for k in ("ERR_BIAS", "ERR_RAND")]
        return cls(
            vals["line_off"],
            vals["samp_off"],
            vals["lat_off"],
            vals["long_off"],
            vals["height_off"],
            vals["line_scale"],
            vals["samp_scale"],
            vals["lat_scale"],
            vals["long_scale"],
            vals["height_scale"],
            coef["LINE_NUM_COEFF"],
            coef["LINE_DEN_COEFF"],
            coef["SAMP_NUM_COEFF"],
            coef["SAMP_DEN_COEFF"],
            errs[0],
            errs[1],
        )

    def to_rasterio(self) -> Any:
        """A :class:`rasterio.rpc.RPC` (for ``dataset.rpcs = ...`` and ``RPCTransformer``)."""
        from rasterio.rpc import RPC

        return RPC.from_gdal(self.to_gdal())

    @classmethod
    def from_rasterio(cls, rpc: Any) -> RPCModel:
        """From a :class:`rasterio.rpc.RPC` (``dataset.rpcs``)."""
        return cls(
            rpc.line_off,
            rpc.samp_off,
            rpc.lat_off,
            rpc.long_off,
            rpc.height_off,
            rpc.line_scale,
            rpc.samp_scale,
            rpc.lat_scale,
            rpc.long_scale,
            rpc.height_scale,
            np.asarray(rpc.line_num_coeff, float),
            np.asarray(rpc.line_den_coeff, float),
            np.asarray(rpc.samp_num_coeff, float),
            np.asarray(rpc.samp_den_coeff, float),
            -1.0 if rpc.err_bias is None else rpc.err_bias,
            -1.0 if rpc.err_rand is None else rpc.err_rand,
        )


def _positive_int(name, v):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise ValueError(f"RPCSensor: {name} = {v!r} must be a positive integer (pixels)")
    return int(v)


def _finite(name, v, lo=None):
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v):
        raise ValueError(f"RPCSensor: {name} = {v!r} must be a finite number")
    if lo is not None and not v > lo:
        raise ValueError(f"RPCSensor: {name} = {v!r} must be > {lo}")
    return float(v)


@dataclass(frozen=True)
class RPCSensor:
    """An RPC behind the :class:`~geoloc.sensors.base.Sensor` interface (``state`` is ignored).

    Attributes
    ----------
    model : RPCModel
    rows, cols : int, optional
        Image size. Default: :meth:`RPCModel.image_size` (from the line / sample
        offsets and scales); give it when it is known (``read_rpc`` takes it
        from the raster).
    row_bias, row_per_row, row_per_col, col_bias, col_per_row, col_per_col : float
        Image-space correction (Grodecki & Dial 2003), 0 by default. With
        (r, c) the RPC's 1-based projection, the image pixel is
        ``row = r + row_bias + row_per_row * r + row_per_col * c`` and
        ``col = c + col_bias + col_per_row * r + col_per_col * c``
        (biases in pixels, the other four in pixels per pixel). These are
        :attr:`params`; :func:`geoloc.analysis.rpc_adjust.adjust_rpc` fits them.
    domain_latlon, domain_height : float
        Validity domain: a ground point whose normalised latitude or longitude
        exceeds ``domain_latlon`` in absolute value (default 1.1: 10 % beyond
        the fitted footprint), or whose normalised height exceeds
        ``domain_height`` (default 1.5, GDAL's own warning level), is refused
        by :meth:`ground_to_pixel` (NaN, ``OUTSIDE_DOMAIN``), never extrapolated.
    los_fraction : float
        :meth:`line_of_sight` inverts the RPC at the heights
        ``HEIGHT_OFF +- los_fraction * HEIGHT_SCALE`` (default 1: the edges of
        the fitted height range); must lie in (0, ``domain_height``].
    tol_px, max_iter :
        Newton iterations of the inverse: stop when both image residuals are
        below ``tol_px`` (default 1e-9 px); ``NO_CONVERGENCE`` after ``max_iter``.
    name : str
    """

    model: RPCModel
    # None: the model's image size (RPCModel.image_size), which __post_init__ puts in its place;
    # an int after construction, as the Sensor interface says
    rows: int = None  # type: ignore[assignment]
    cols: int = None  # type: ignore[assignment]
    row_bias: float = 0.0
    row_per_row: float = 0.0
    row_per_col: float = 0.0
    col_bias: float = 0.0
    col_per_row: float = 0.0
    col_per_col: float = 0.0
    domain_latlon: float = 1.1
    domain_height: float = 1.5
    los_fraction: float = 1.0
    tol_px: float = 1e-9
    max_iter: int = 30
    name: str = ""

    #: An RPC is fitted to its maker's rigorous model, which already bent and moved the lines
    #: of sight (refraction, light-time, aberration): no correction is applied on top of it
    #: (:class:`geoloc.pipeline.Corrections` refuses one by name).
    includes_corrections: ClassVar[bool] = True

    def __post_init__(self):
        if not isinstance(self.model, RPCModel):
            raise ValueError(f"RPCSensor: model must be an RPCModel, got {type(self.model).__name__}")
        r0, c0 = self.model.image_size() if (self.rows is None or self.cols is None) else (None, None)
        object.__setattr__(self, "rows", _positive_int("rows", r0 if self.rows is None else self.rows))
        object.__setattr__(self, "cols", _positive_int("cols", c0 if self.cols is None else self.cols))
        for k in PARAM_NAMES:
            object.__setattr__(self, k, _finite(k, getattr(self, k)))
        object.__setattr__(self, "domain_latlon", _finite("domain_latlon", self.domain_latlon, 0.0))
        object.__setattr__(self, "domain_height", _finite("domain_height", self.domain_height, 0.0))
        f = _finite("los_fraction", self.los_fraction, 0.0)
        if f > self.domain_height:
            raise ValueError(
                f"RPCSensor: los_fraction = {f!r} must not exceed domain_height = "
                f"{self.domain_height!r} (the heights must lie inside the domain)"
            )
        object.__setattr__(self, "los_fraction", f)
        object.__setattr__(self, "tol_px", _finite("tol_px", self.tol_px, 0.0))
        object.__setattr__(self, "max_iter", _positive_int("max_iter", self.max_iter))
        det = (1.0 + self.row_per_row) * (1.0 + self.col_per_col) - self.row_per_col * self.col_per_row
        if not abs(det) > 1e-12:
            raise ValueError(f"RPCSensor: the affine correction is singular (determinant {det!r})")

    # ------------------------------------------------------------ parameters
    @property
    def params(self) -> dict[str, float]:
        """The image-space correction: ``row_bias``, ``row_per_row``, ..., ``col_per_col``."""
        return {k: getattr(self, k) for k in PARAM_NAMES}

    def with_params(self, **changes: float) -> RPCSensor:
        """A copy with some of :attr:`params` changed (unknown names are a ValueError)."""
        check_param_names(changes, self.params, "RPCSensor")
        return replace_params(self, changes)

    def rpc_to_image(self, r: ArrayLike, c: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The correction: RPC projection (1-based) -> image pixel."""
        r, c = np.asarray(r, float), np.asarray(c, float)
        return (
            r + (self.row_bias + self.row_per_row * r + self.row_per_col * c),
            c + (self.col_bias + self.col_per_row * r + self.col_per_col * c),
        )

    def image_to_rpc(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`rpc_to_image` (exact: a 2 x 2 linear system)."""
        row, col = np.asarray(row, float), np.asarray(col, float)
        a, b = 1.0 + self.row_per_row, self.row_per_col
        c, d = self.col_per_row, 1.0 + self.col_per_col
        y, x = row - self.row_bias, col - self.col_bias
        det = a * d - b * c
        return (d * y - b * x) / det, (a * x - c * y) / det

    # ------------------------------------------------------- ground -> image
    def in_domain(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> np.ndarray:
        """True where the ground point lies inside the validity domain (see the class docstring)."""
        Ln, Pn, Hn = self.model.normalise(lat, lon, h)
        with np.errstate(invalid="ignore"):
            return (
                (np.abs(Ln) <= self.domain_latlon)
                & (np.abs(Pn) <= self.domain_latlon)
                & (np.abs(Hn) <= self.domain_height)
            )

    def ground_to_pixel(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike, state: Any = None) -> PixelHit:
        """Geodetic points (rad, rad, ellipsoidal m) -> 1-based image pixels by the RPC (and the correction).

        Returns
        -------
        PixelHit
            ``INVALID_INPUT`` for non-finite input; ``OUTSIDE_DOMAIN`` (NaN)
            outside the validity domain or where a denominator vanishes;
            ``OUTSIDE_SENSOR`` where the pixel is computed but off the image.
        """
        lat, lon, h = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float))
        finite = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
        inside = self.in_domain(lat, lon, h)
        r, c = self.rpc_to_image(*self.model.ground_to_pixel(lat, lon, h))
        status = np.full(lat.shape, Status.OK, np.uint8)
        status[finite & ~(inside & np.isfinite(r) & np.isfinite(c))] = Status.OUTSIDE_DOMAIN
        status[~finite] = Status.INVALID_INPUT
        ok = status == Status.OK
        r, c = np.where(ok, r, np.nan), np.where(ok, c, np.nan)
        return PixelHit(r, c, flag_outside(status, r, c, self.rows, self.cols))

    def in_image(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        """True where the 1-based pixel lies on the image (0.5 .. rows + 0.5, 0.5 .. cols + 0.5)."""
        return in_sensor(row, col, self.rows, self.cols)

    # ------------------------------------------------------- image -> ground
    def ground_at_height(
        self, row: ArrayLike, col: ArrayLike, h: ArrayLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The RPC inverse at fixed ellipsoidal heights: pixels -> (lat, lon, status).

        Newton iterations on the normalised (longitude, latitude) with the
        analytic Jacobian of the two ratios, all points at once, from the
        centre of the footprint; stop when both image residuals are below
        ``tol_px``.

        Parameters
        ----------
        row, col : array_like
            1-based image pixels (the correction is undone first).
        h : array_like
            Ellipsoidal height [m], broadcasting.

        Returns
        -------
        lat, lon : ndarray
            Radians; NaN where the status is not OK / OUTSIDE_SENSOR.
        status : ndarray of uint8
            ``INVALID_INPUT`` (non-finite), ``OUTSIDE_DOMAIN`` (the height, or the
            solution, outside the validity domain: refused), ``NO_CONVERGENCE``,
            ``OUTSIDE_SENSOR`` (pixel off the image; the point is still computed), OK.
        """
        m = self.model
        row, col, h = np.broadcast_arrays(np.asarray(row, float), np.asarray(col, float), np.asarray(h, float))
        finite = np.isfinite(row) & np.isfinite(col) & np.isfinite(h)
        r, c = self.image_to_rpc(np.where(finite, row, 0.0), np.where(finite, col, 0.0))
        ln_t = (r - 1.0 - m.line_off) / m.line_scale
        sn_t = (c - 1.0 - m.samp_off) / m.samp_scale
        Hn = np.where(finite, (h - m.height_off) / m.height_scale, 0.0)
        h_in = np.abs(Hn) <= self.domain_height
        Hn = np.where(h_in, Hn, 0.0)
        L, P, converged = self._newton(Hn.ravel(), ln_t.ravel(), sn_t.ravel())
        L, P, converged = L.reshape(row.shape), P.reshape(row.shape), converged.reshape(row.shape)
        inside = (np.abs(L) <= self.domain_latlon) & (np.abs(P) <= self.domain_latlon)
        status = np.full(row.shape, Status.OK, np.uint8)
        status[~converged] = Status.NO_CONVERGENCE
        status[converged & ~inside] = Status.OUTSIDE_DOMAIN
        status[~h_in] = Status.OUTSIDE_DOMAIN
        status[~finite] = Status.INVALID_INPUT
        status = flag_outside(status, row, col, self.rows, self.cols)
        good = (status == Status.OK) | (status == Status.OUTSIDE_SENSOR)
        lat, lon, _ = m.denormalise(L, P, Hn)
        return np.where(good, lat, np.nan), np.where(good, lon, np.nan), status

    def _newton(self, Hn, ln_t, sn_t):
        """Solve line_n(L, P, Hn) = ln_t, samp_n(L, P, Hn) = sn_t for (L, P), flat arrays.

        At a fixed height each RPC polynomial is a cubic in (L, P) whose ten
        coefficients depend on Hn only; they are formed once, then Newton steps
        with the analytic Jacobian run on the points not yet converged.
        """
        m = self.model
        n = Hn.size
        polys = [_cubic_in_lp(c, Hn) for c in (m.line_num, m.line_den, m.samp_num, m.samp_den)]
        L, P = np.zeros(n), np.zeros(n)
        converged = np.zeros(n, bool)
        cap = 10.0 * max(self.domain_latlon, 1.0)  # a step that leaves this is a divergence
        act = np.arange(n)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for it in range(self.max_iter + 1):
                la, pa = L[act], P[act]
                (ln, ln_l, ln_p), (ld, ld_l, ld_p), (sn, sn_l, sn_p), (sd, sd_l, sd_p) = (
                    _eval_cubic([a[act] for a in q], la, pa) for q in polys
                )
                fl, fs = ln / ld, sn / sd
                el, es = fl - ln_t[act], fs - sn_t[act]
                ok = (np.abs(el) * m.line_scale <= self.tol_px) & (np.abs(es) * m.samp_scale <= self.tol_px)
                converged[act[ok]] = True
                stop = ok | ~(np.isfinite(el) & np.isfinite(es))
                keep = ~stop
                act = act[keep]
                if act.size == 0 or it == self.max_iter:
                    break
                el, es, fl, fs = el[keep], es[keep], fl[keep], fs[keep]
                j11 = (ln_l[keep] - fl * ld_l[keep]) / ld[keep]
                j12 = (ln_p[keep] - fl * ld_p[keep]) / ld[keep]
                j21 = (sn_l[keep] - fs * sd_l[keep]) / sd[keep]
                j22 = (sn_p[keep] - fs * sd_p[keep]) / sd[keep]
                det = j11 * j22 - j12 * j21
                L[act] = np.clip(la[keep] - (j22 * el - j12 * es) / det, -cap, cap)
                P[act] = np.clip(pa[keep] - (j11 * es - j21 * el) / det, -cap, cap)
        return L, P, converged

    def line_of_sight(self, row: ArrayLike, col: ArrayLike, state: Any = None, *, outside: str = "flag") -> LineOfSight:
        """1-based pixels -> straight lines of sight in ECEF, from the RPC itself.

        The pixel is inverted at the two heights ``HEIGHT_OFF +- los_fraction
        * HEIGHT_SCALE`` (:meth:`ground_at_height`); the origin is the upper
        ground point, the direction the unit vector from it to the lower one.
        So :func:`geoloc.surfaces.height.intersect_los_height` and
        :func:`geoloc.surfaces.terrain.intersect_dem` work on an RPC. An RPC's
        "line of sight" is a curve (the RPC only approximates a straight ray);
        the chord's departure from it is measured in ``docs/rpc.md`` (below
        1e-6 px over the fitted height range for both bundled scenarios).
        Heights above the upper point are behind the origin (the height
        surfaces answer ``ORIGIN_BELOW``); below the lower one the chord is
        extended.

        Parameters
        ----------
        row, col : array_like
            1-based image pixels.
        state : ignored
            An RPC has no per-image state.
        outside : {"flag", "extrapolate"}
            A pixel off the image gets ``OUTSIDE_SENSOR`` (default; the geometry
            is still computed) or status OK (``"extrapolate"``, for a caller that
            reports such pixels itself). Either way a pixel whose ground lies
            outside the validity domain is refused.

        Returns
        -------
        LineOfSight
            Status from the two inversions (the worst of both):
            ``INVALID_INPUT``, ``OUTSIDE_DOMAIN``, ``NO_CONVERGENCE`` (NaN), or
            ``OUTSIDE_SENSOR`` for a pixel off the image (geometry computed).
        """
        check_outside(outside)
        row, col = np.broadcast_arrays(np.asarray(row, float), np.asarray(col, float))
        m = self.model
        hs = m.height_off + self.los_fraction * m.height_scale * np.array([1.0, -1.0])
        lat, lon, st = self.ground_at_height(row[None], col[None], hs.reshape((2,) + (1,) * row.ndim))
        p = geodetic_to_ecef(lat, lon, np.broadcast_to(hs.reshape((2,) + (1,) * row.ndim), lat.shape))
        d = p[1] - p[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        # both inversions are of the same pixel: OUTSIDE_SENSOR in both or neither; a failure wins
        hard = (st != Status.OK) & (st != Status.OUTSIDE_SENSOR)
        status = np.where(hard[0], st[0], np.where(hard[1], st[1], st[0]))
        keep = (status == Status.OK) | (status == Status.OUTSIDE_SENSOR)
        if outside == "extrapolate":
            status = np.where(status == Status.OUTSIDE_SENSOR, np.uint8(Status.OK), status)
        return LineOfSight(
            np.where(keep[..., None], p[0], np.nan), np.where(keep[..., None], d, np.nan), status.astype(np.uint8)
        )

    def frames(self, state: Any = None) -> None:
        """None: an RPC has no frame graph.

        It is a ground <-> image mapping with no optical centre, attitude or
        joints; the viewers draw its lines of sight (or the footprint) only.
        """


__all__ = ["PARAM_NAMES", "TERMS", "RPCModel", "RPCSensor", "rpc_terms"]
