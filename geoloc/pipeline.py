"""The one location pipeline: sensor -> line-of-sight corrections -> surface, and back.

Every computation of geoloc that turns a pixel into a ground point, or a ground point into
a pixel, goes through a :class:`Pipeline` (``docs/architecture.md``, "The location
pipeline")::

    pipe = Pipeline(sensor, surface, Corrections.for_sensor(sensor, refraction="standard"))
    hit = pipe.locate(row, col, state)              # GroundPoint, with .corrections, .refraction_m
    hit = pipe.intersect(sensor_los)                # the same, from the sensor's lines of sight
    px = pipe.ground_to_pixel(lat, lon, h, state)   # PixelHit: the inverse, the same corrections

The order is Orekit Rugged's ``directLocation``: the sensor's line of sight (the direction
as the moving sensor sees it, in the air at the platform), then aberration of light (the
direction the light really came from, :func:`geoloc.corrections.lighttime.aberration`), then
light-time (the Earth turned while the light travelled,
:func:`geoloc.corrections.lighttime.light_time_line`), then the surface (the raw hit), then
atmospheric refraction near the raw hit to a fixed point
(:meth:`geoloc.corrections.refraction.Refraction.correct`). The inverse runs the same
corrections backwards: :func:`~geoloc.corrections.lighttime.light_time_source`,
:meth:`~geoloc.corrections.refraction.Refraction.aim`,
:func:`~geoloc.corrections.lighttime.apparent_direction`, then the sensor's own
``ground_to_pixel`` of a point along the apparent direction.

The compiled engines are executors of the same pipeline, chosen by batch size
(``engine="auto"``): the sensor's compiled line of sight (``FrameSensor.line_of_sight``),
the fused chain-and-ellipsoid kernel (:mod:`geoloc.sensors._fastlocate`) for the raw hit on
the inflated height surface, the DEM walk's kernel inside ``DemSurface``. Corrections run
after them, the same for every executor; ``tests/test_pipeline_contract.py`` holds them
equal ray for ray.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from geoloc import corrections as _corr
from geoloc.corrections.lighttime import (
    aberration,
    apparent_direction,
    inertial_velocity,
    light_time_line,
    light_time_point,
    light_time_source,
)
from geoloc.geodesy.ellipsoid import ecef_to_geodetic, geodetic_to_ecef
from geoloc.sensors.base import COMPILED_MIN_RAYS, PixelHit, check_outside
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight
from geoloc.surfaces.height import HeightSurface

if TYPE_CHECKING:  # the refraction kernels import numba: loaded when refraction is asked for
    from geoloc.corrections.refraction import Refraction
    from geoloc.sensors.base import Sensor
    from geoloc.surfaces.base import Surface

#: The corrections, in the order the pipeline applies them.
CORRECTIONS = ("aberration", "light_time", "refraction")
#: ``--refraction`` choices: off (as the papers, and Rugged by default) or the U.S. Standard
#: Atmosphere 1976 (:data:`geoloc.corrections.refraction.STANDARD_REFRACTION`).
REFRACTION_MODELS = _corr.REFRACTION_MODELS
#: A ray whose refraction fixed point moves its hit by less than this is settled [m]: a tenth
#: of the DEM solvers' own millimetre agreement is below every figure geoloc reports.
REFRACTION_TOL_M = 1e-3
#: At most this many refraction steps on a surface that is not of constant height (a DEM):
#: each step gains the ratio of the terrain slope's effect to the shift (docs/refraction.md).
REFRACTION_MAX_ITER = 6


@dataclass(frozen=True)
class Corrections:
    """Which line-of-sight corrections a pipeline applies.

    Attributes
    ----------
    refraction : Refraction or None
        Atmospheric refraction (:data:`geoloc.corrections.refraction.STANDARD_REFRACTION`:
        the U.S. Standard Atmosphere 1976), or None: off.
    light_time : bool
        The Earth's rotation during the light's travel (needs only the range).
    aberration : bool
        Aberration of light by the platform's velocity (needs ``LineOfSight.velocity_ecef``).
    """

    refraction: Refraction | None = None
    light_time: bool = False
    aberration: bool = False

    @classmethod
    def for_sensor(
        cls,
        sensor: object,
        refraction: str | Refraction | None = "none",
        light_time: bool | None = None,
        aberration: bool | None = None,
    ) -> Corrections:
        """Rugged's defaults for ``sensor``: refraction off unless asked for; light-time and
        aberration on for a spaceborne sensor (``sensor.spaceborne``), off otherwise; an RPC
        (``sensor.includes_corrections``) takes none.

        Parameters
        ----------
        refraction : {"none", "standard"} or Refraction or None
        light_time, aberration : bool, optional
            None: the sensor's default.

        Raises
        ------
        ValueError
            An unknown refraction model, a correction asked of an RPC, or aberration asked of
            a sensor whose lines of sight carry no velocity, each named.
        """
        if isinstance(refraction, str):
            if refraction not in REFRACTION_MODELS:
                raise ValueError(f"refraction = {refraction!r}: must be one of {list(REFRACTION_MODELS)}")
            refraction = None if refraction == "none" else refraction
        if refraction is not None:  # its module (kernels, atmosphere) is imported only when asked for
            from geoloc.corrections.refraction import STANDARD_REFRACTION, Refraction

            if isinstance(refraction, str):  # "standard", the one model left
                refraction = STANDARD_REFRACTION
            elif not isinstance(refraction, Refraction):
                raise ValueError(f"refraction = {refraction!r}: must be 'none', 'standard' or a Refraction")
        space = bool(getattr(sensor, "spaceborne", False))
        lt = space if light_time is None else bool(light_time)
        ab = space if aberration is None else bool(aberration)
        name = "frame sensor" if sensor is None else type(sensor).__name__
        if getattr(sensor, "includes_corrections", False):
            asked = [
                n for n, on in (("refraction", refraction is not None), ("light_time", lt), ("aberration", ab)) if on
            ]
            if asked:
                raise ValueError(
                    f"{name}: an RPC is fitted to its maker's rigorous model, which already "
                    f"corrects the lines of sight; {asked[0]} cannot be applied on top of it "
                    "(use --refraction none)"
                )
        elif ab and not space:
            raise ValueError(
                f"aberration = True: a {name}'s lines of sight carry no platform velocity "
                "(aberration of light is for spaceborne sensors; at aircraft speeds it is "
                "below 1 microradian)"
            )
        return cls(refraction, lt, ab)

    def overridden(
        self,
        sensor: object,
        refraction: str | Refraction | None = None,
        light_time: bool | None = None,
        aberration: bool | None = None,
    ) -> Corrections:
        """These corrections with the given settings changed (None: kept), checked for ``sensor``
        as :meth:`for_sensor` checks them (a command line's flags over a file's table)."""
        return Corrections.for_sensor(
            sensor,
            self.refraction if refraction is None else refraction,
            self.light_time if light_time is None else light_time,
            self.aberration if aberration is None else aberration,
        )

    def to_table(self) -> dict:
        """The ``[corrections]`` table that :func:`corrections_from_table` reads back to these
        corrections (a refraction through a ``StandardAtmosphere``: its ground measurement too)."""
        from geoloc.corrections.atmosphere import StandardAtmosphere

        table: dict[str, str | bool | float] = {
            "refraction": "none" if self.refraction is None else "standard",
            "light_time": bool(self.light_time),
            "aberration": bool(self.aberration),
        }
        atm = getattr(self.refraction, "atmosphere", None)
        if self.refraction is not None and not isinstance(atm, StandardAtmosphere):
            raise ValueError(f"refraction through {type(atm).__name__}: no [corrections] table names it")
        if isinstance(atm, StandardAtmosphere):
            for key in _corr.GROUND_KEYS:
                v = getattr(atm, key)
                if v is not None and not (key == "ground_h_m" and v == 0.0):
                    table[key] = float(v)
        return table

    @property
    def names(self) -> tuple:
        """The corrections on, in the pipeline's order (a subset of :data:`CORRECTIONS`)."""
        on = {"aberration": self.aberration, "light_time": self.light_time, "refraction": self.refraction is not None}
        return tuple(n for n in CORRECTIONS if on[n])

    @property
    def label(self) -> str:
        """``"aberration+light_time"``, ``"refraction"``, ... or ``"none"``: an output row's ``corrections``."""
        return "+".join(self.names) or "none"

    def __bool__(self) -> bool:
        return bool(self.names)


NO_CORRECTIONS = Corrections()
#: The keys of a sensor or scenario file's ``[corrections]`` table.
TABLE_KEYS = _corr.TABLE_KEYS


def refraction_model(
    name: str | Refraction | None, ground: dict | None = None, source: str = "[corrections]"
) -> str | Refraction | None:
    """The refraction of ``name`` (``"none"``, ``"standard"``, or a Refraction), its standard
    atmosphere fitted to ``ground`` (``ground_h_m``, ``ground_p_pa``, ``ground_t_k``: a measured
    ground pressure and temperature; ``StandardAtmosphere``) when given. Errors name ``source``."""
    ground = {k: float(v) for k, v in (ground or {}).items() if v is not None}
    if not ground or not isinstance(name, str):
        return name
    if name != "standard":
        raise ValueError(
            f"{source}: {', '.join(sorted(ground))} given, but refraction = {name!r}: the ground "
            'measurement fits the standard atmosphere (refraction = "standard")'
        )
    from geoloc.corrections.atmosphere import StandardAtmosphere
    from geoloc.corrections.refraction import Refraction  # imported only when one is made

    try:
        return Refraction(StandardAtmosphere(**ground))
    except ValueError as e:
        raise ValueError(f"{source}: {e}") from None


def corrections_from_table(
    sensor: object, table: dict | None, source: str = "[corrections]", **override: object
) -> Corrections:
    """A file's ``[corrections]`` table (``refraction = "none" | "standard"``, ``light_time`` and
    ``aberration`` true or false), with the command line's ``override`` (None: not given) on top,
    over the sensor's defaults (:meth:`Corrections.for_sensor`). Errors name ``source`` and the key."""
    table = _corr.check_table(table or {}, source)
    for key, value in override.items():
        if value is not None:
            table[key] = value
    refraction = refraction_model(table.get("refraction", "none"), {k: table.get(k) for k in _corr.GROUND_KEYS}, source)
    return Corrections.for_sensor(sensor, refraction, table.get("light_time"), table.get("aberration"))


def _constant_height(surface) -> bool:
    """True for a surface of constant height (a point at the raw hit's height is on it)."""
    return bool(getattr(surface, "constant_height", False))


@dataclass(frozen=True)
class Pipeline:
    """A sensor, its line-of-sight corrections and a surface: pixels to ground and back.

    Parameters
    ----------
    sensor : Sensor or None
        Any :class:`geoloc.sensors.base.Sensor` (frame, pushbroom, RPC); None for a pipeline
        that only meets given lines of sight with its surface (:meth:`intersect`).
    surface : Surface or None
        What the lines of sight meet (:class:`geoloc.surfaces.base.Surface`); None for a
        pipeline that only projects ground points to pixels (:meth:`ground_to_pixel`).
    corrections : Corrections
        Off by default (:meth:`Corrections.for_sensor` gives Rugged's defaults).
    """

    sensor: Sensor | None
    surface: Surface | None
    corrections: Corrections = NO_CORRECTIONS

    @property
    def _sensor(self) -> Sensor:
        if self.sensor is None:
            raise ValueError("Pipeline(sensor=None): it meets given lines of sight only (intersect), no pixels")
        return self.sensor

    @property
    def _surface(self) -> Surface:
        if self.surface is None:
            raise ValueError("Pipeline(surface=None): it projects ground points to pixels only (ground_to_pixel)")
        return self.surface

    # ------------------------------------------------------------ pixel -> ground
    def locate(
        self, row: npt.ArrayLike, col: npt.ArrayLike, state: Any = None, *, outside: str = "flag", engine: str = "auto"
    ) -> GroundPoint:
        """1-based pixels -> ground points, batched (NaN and a Status per ray).

        Parameters
        ----------
        row, col : array_like
        state : optional
            The sensor's state (a frame sensor's ``Pose``).
        outside : {"flag", "extrapolate"}
        engine : {"auto", "numpy", "numba"}
            The executor: ``"numpy"`` the reference; ``"numba"`` the compiled line of sight
            (and, on the inflated height surface, the fused kernel for the raw hit);
            ``"auto"`` the compiled ones for batches of :data:`COMPILED_MIN_RAYS` or more.
        """
        if engine not in ("auto", "numpy", "numba"):
            raise ValueError(f"engine must be 'auto', 'numpy' or 'numba', got {engine!r}")
        check_outside(outside)
        fused = self._fused(row, col, state, engine, outside)
        if fused is not None:
            # the kernel writes the line of sight's own statuses and, without refraction, the
            # result's shift (0 where OK) too: numpy passes over the batch cost 8 ms per 1 M rays
            lat, lon, h, ecef, rng, status, o, d, los_status, shift = fused
            los = LineOfSight(o, d, los_status)
            raw = GroundPoint(lat, lon, h, ecef, rng, status, los)
            if shift is not None:
                return dataclasses.replace(raw, corrections=self.corrections.names, refraction_m=shift)
            return self._refract(los, los, raw)
        # a frame sensor has a compiled line of sight; the others have one executor
        kw = {"engine": engine} if hasattr(self.sensor, "compiled") else {}
        los = self._sensor.line_of_sight(row, col, state, outside=outside, **kw)
        return self.intersect(los)

    def _fused(self, row, col, state, engine, outside):
        """The fused chain-and-ellipsoid kernel's results, when it serves this pipeline and batch, else None."""
        surf = self.surface
        if engine == "numpy" or type(surf) is not HeightSurface or surf.kind != "inflated":
            return None
        if engine == "auto" and (state is None or state.batch_size(row, col, surf.h) < COMPILED_MIN_RAYS):
            # a small batch, or a sensor with no platform state (a pushbroom's is in its own
            # ephemeris), which the kernel does not serve: the kernel module is not even imported
            return None
        from geoloc.sensors import _fastlocate

        if self.corrections.aberration or self.corrections.light_time or not _fastlocate.serves(self.sensor):
            return None
        return _fastlocate.locate_fast(
            state, self.sensor, row, col, surf.h, outside=outside, refraction_m=self.corrections.refraction is None
        )

    def intersect(self, los: LineOfSight) -> GroundPoint:
        """The sensor's lines of sight -> ground points, through every correction of the pipeline.

        ``los`` is what the sensor gives (the apparent direction in the air at the platform);
        the returned :class:`GroundPoint` keeps it as ``los`` and says which corrections
        were applied (``corrections``) and how far refraction moved each point
        (``refraction_m``).
        """
        c = self.corrections
        line = los
        if c.aberration:
            if los.velocity_ecef is None:
                raise ValueError("aberration: the lines of sight carry no velocity (LineOfSight.velocity_ecef)")
            v = inertial_velocity(los.origin_ecef, los.velocity_ecef)
            d = aberration(los.direction_ecef, v)
            line = LineOfSight(los.origin_ecef, d, los.status, los.velocity_ecef)
        raw = self._surface.intersect(line)
        if c.light_time:
            o = np.asarray(line.origin_ecef, float)
            # a ray with no raw hit is not turned (its range taken as 0): it keeps its own status
            hit = np.where(np.isfinite(raw.ecef), raw.ecef, o)
            line = LineOfSight(*light_time_line(o, line.direction_ecef, hit), line.status, los.velocity_ecef)
            if _constant_height(self.surface):  # a surface of revolution: the hit turns with the line
                ecef = light_time_point(o, raw.ecef)
                raw = dataclasses.replace(raw, ecef=ecef, lon=np.arctan2(ecef[..., 1], ecef[..., 0]))
            else:
                raw = self._surface.intersect(line)
        return self._refract(los, line, raw)

    def _refract(self, los: LineOfSight, line: LineOfSight, raw: GroundPoint) -> GroundPoint:
        """Refraction near the raw hit (to a fixed point on a DEM), then the result's bookkeeping."""
        c = self.corrections
        ok_raw = np.asarray(raw.status) == Status.OK
        if c.refraction is None:
            shift = np.where(ok_raw, 0.0, np.nan)
            return dataclasses.replace(raw, los=los, corrections=c.names, refraction_m=shift)
        o = np.asarray(line.origin_ecef, float)
        d = np.asarray(line.direction_ecef, float)
        raw_ecef = np.asarray(raw.ecef, float)
        bent = c.refraction.correct(o, d, raw_ecef, hit_llh=(raw.lat, raw.lon, raw.h))
        if _constant_height(self.surface):
            # the bent point at the raw hit's height is on the surface; where the raw hit is NaN the
            # correction is NaN too (INVALID_INPUT), and the raw hit's status is kept
            status = np.where(ok_raw, bent.status, raw.status).astype(np.uint8)
            ecef = bent.hit_ecef
            shift = bent.shift_m  # from the straight line's point at that height: the raw hit
            rng = bent.range_m  # from the camera: line.origin_ecef is los.origin_ecef (light-time turns both)
            if c.light_time:
                rng = np.linalg.norm(ecef - np.asarray(los.origin_ecef, float), axis=-1)
            return dataclasses.replace(
                raw,
                lat=bent.lat,
                lon=bent.lon,
                h=bent.h,
                ecef=ecef,
                status=status,
                slant_range=rng,
                los=los,
                corrections=c.names,
                refraction_m=shift,
            )
        hit = self._refract_fixed_point(c.refraction, o, d, raw, bent)
        ok = np.asarray(hit.status) == Status.OK
        shift = np.where(ok, np.linalg.norm(np.asarray(hit.ecef) - raw_ecef, axis=-1), np.nan)
        rng = np.where(ok, np.linalg.norm(np.asarray(hit.ecef) - np.asarray(los.origin_ecef, float), axis=-1), np.nan)
        return dataclasses.replace(hit, slant_range=rng, los=los, corrections=c.names, refraction_m=shift)

    def _refract_fixed_point(self, refraction: Refraction, o, d, raw: GroundPoint, bent) -> GroundPoint:
        """Meet the bent ray's tangent line with the surface, at the new hit's height, until it settles."""
        ok_raw = np.asarray(raw.status) == Status.OK
        hit = raw
        moving = ok_raw
        for _ in range(REFRACTION_MAX_ITER):
            st = np.where(ok_raw, bent.status, raw.status).astype(np.uint8)
            new = self._surface.intersect(LineOfSight(bent.origin_ecef, bent.direction_ecef, st))
            step = np.linalg.norm(np.asarray(new.ecef) - np.asarray(hit.ecef), axis=-1)
            hit = new
            moving = (np.asarray(new.status) == Status.OK) & ~(step < REFRACTION_TOL_M)
            if not np.any(moving):
                break
            bent = refraction.correct(o, d, np.asarray(raw.ecef), at_h=np.where(np.isfinite(new.h), new.h, raw.h))
        status = np.where(moving, np.uint8(Status.NO_CONVERGENCE), np.asarray(hit.status)).astype(np.uint8)
        status = np.where(ok_raw, status, np.asarray(raw.status)).astype(np.uint8)
        ok = status == Status.OK
        ecef = np.where(ok[..., None], hit.ecef, np.nan)
        return dataclasses.replace(
            hit,
            ecef=ecef,
            lat=np.where(ok, hit.lat, np.nan),
            lon=np.where(ok, hit.lon, np.nan),
            h=np.where(ok, hit.h, np.nan),
            status=status,
        )

    def lines_near(self, los: LineOfSight, near_ecef: npt.ArrayLike) -> LineOfSight:
        """The sensor's lines of sight, corrected, as straight lines near the points ``near_ecef``.

        For a computation that meets the rays with something other than a surface (triangulation
        meets them with each other): aberration turns each direction, light-time turns each line
        by the Earth's rotation over the range to its point, and refraction replaces it by the
        tangent of the bent ray where it reaches the point's geodetic height (its origin backed
        off along it by the range). Without corrections, ``los`` itself.
        """
        c = self.corrections
        if not c:
            return los
        o = np.asarray(los.origin_ecef, float)
        d = np.asarray(los.direction_ecef, float)
        p = np.asarray(near_ecef, float)
        if c.aberration:
            if los.velocity_ecef is None:
                raise ValueError("aberration: the lines of sight carry no velocity (LineOfSight.velocity_ecef)")
            d = aberration(d, inertial_velocity(o, los.velocity_ecef))
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        if c.light_time:
            o, d = light_time_line(o, d, p)
        if c.refraction is None:
            return LineOfSight(o, d, los.status, los.velocity_ecef)
        t = np.einsum("...i,...i->...", p - o, d)
        foot = o + t[..., None] * d  # the straight line's point nearest the given one
        h = ecef_to_geodetic(p)[2]
        bent = c.refraction.correct(o, d, foot, at_h=h)
        status = np.where(np.asarray(los.status) == Status.OK, bent.status, los.status).astype(np.uint8)
        return LineOfSight(bent.origin_ecef, bent.direction_ecef, status, los.velocity_ecef)

    # ------------------------------------------------------------ ground -> pixel
    def ground_to_pixel(
        self,
        lat: npt.ArrayLike,
        lon: npt.ArrayLike,
        h: npt.ArrayLike,
        state: Any = None,
        *,
        max_iter: int = 4,
        tol_px: float = 1e-7,
    ) -> PixelHit:
        """Geodetic points (radians, metres ellipsoidal) -> 1-based pixels: the inverse of :meth:`locate`.

        With no correction it is the sensor's ``ground_to_pixel``. With corrections, each
        point is turned into the point the sensor would see it at without them: light-time
        (:func:`~geoloc.corrections.lighttime.light_time_source`), refraction
        (:meth:`~geoloc.corrections.refraction.Refraction.aim`) and aberration
        (:func:`~geoloc.corrections.lighttime.apparent_direction`) give the apparent
        direction from the optical centre, and the sensor projects a point along it. A
        sensor whose optical centre moves with the row (a pushbroom) repeats this from the
        new pixel's centre until the pixel moves by less than ``tol_px`` (``max_iter``
        times at most; the corrections change the row by a few lines at most).
        """
        c = self.corrections
        px = self._sensor.ground_to_pixel(lat, lon, h, state)
        if not c:
            return px
        ground = geodetic_to_ecef(lat, lon, h)
        for _ in range(max_iter):
            row = np.asarray(px.row, float)
            col = np.asarray(px.col, float)
            los = self._sensor.line_of_sight(
                np.where(np.isfinite(row), row, 0.0), np.where(np.isfinite(col), col, 0.0), state, outside="extrapolate"
            )
            o = np.asarray(los.origin_ecef, float)
            target = light_time_source(o, ground) if c.light_time else ground
            if c.refraction is not None:
                d, rst = c.refraction.aim(o, target)
            else:
                d = target - o
                rst = np.zeros(np.shape(d)[:-1], np.uint8)
            if c.aberration:
                if los.velocity_ecef is None:
                    raise ValueError("aberration: the lines of sight carry no velocity (LineOfSight.velocity_ecef)")
                d = apparent_direction(d, inertial_velocity(o, los.velocity_ecef))
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
            virtual = o + np.linalg.norm(target - o, axis=-1, keepdims=True) * d
            vlat, vlon, vh = ecef_to_geodetic(virtual)
            new = self._sensor.ground_to_pixel(vlat, vlon, vh, state)
            bad = (np.asarray(rst) != Status.OK) & np.isfinite(np.asarray(new.row, float))
            status = np.where(bad, np.uint8(Status.NO_CONVERGENCE), np.asarray(new.status)).astype(np.uint8)
            new = PixelHit(np.where(bad, np.nan, new.row), np.where(bad, np.nan, new.col), status)
            with np.errstate(invalid="ignore"):
                moved = np.nanmax(
                    np.abs(
                        np.concatenate(
                            [np.ravel(np.asarray(new.row, float) - row), np.ravel(np.asarray(new.col, float) - col)]
                        )
                    ),
                    initial=0.0,
                )
            px = new
            if moved < tol_px:
                break
        return px


def at_height(
    sensor: Sensor,
    row: npt.ArrayLike,
    col: npt.ArrayLike,
    h: npt.ArrayLike,
    state: Any = None,
    *,
    height_kind: str = "geodetic",
    corrections: Corrections = NO_CORRECTIONS,
    outside: str = "flag",
) -> GroundPoint:
    """Pixels of any sensor -> ground points at ellipsoidal height ``h``: the pipeline on a
    :class:`geoloc.surfaces.height.HeightSurface` (the exact surface of constant geodetic height
    by default, as an RPC's heights are)."""

    return Pipeline(sensor, HeightSurface(h, height_kind), corrections).locate(row, col, state, outside=outside)


__all__ = [
    "COMPILED_MIN_RAYS",
    "CORRECTIONS",
    "Corrections",
    "NO_CORRECTIONS",
    "Pipeline",
    "REFRACTION_MODELS",
    "TABLE_KEYS",
    "at_height",
    "corrections_from_table",
    "refraction_model",
]
