"""What sensors hand to surfaces and surfaces hand back, and what a surface is.

A sensor turns pixels into a :class:`LineOfSight` batch (ECEF origin, unit
direction, a :class:`geoloc.status.Status` per ray); a :class:`Surface` turns it
into a :class:`GroundPoint` batch. A :class:`DemSource` is a DEM raster
(:class:`geoloc.surfaces.dem.DEM`) or a mosaic of them
(:class:`geoloc.surfaces.mosaic.DemMosaic`, which is a surface too:
:func:`is_mosaic`). ``docs/architecture.md`` describes the interfaces;
``docs/conventions.md`` the frames and units.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeGuard, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # a raster module that imports no surface: no cycle
    from geoloc.surfaces.dem import DEM


@dataclass(frozen=True)
class LineOfSight:
    """A batch of lines of sight in ECEF.

    Attributes
    ----------
    origin_ecef : ndarray (..., 3)
        Optical centre O_E [m].
    direction_ecef : ndarray (..., 3)
        Unit direction d_E.
    status : ndarray (...) of uint8
        INVALID_INPUT where the pose or pixel is not finite / out of range.
    velocity_ecef : ndarray (..., 3) or None
        The optical centre's Earth-fixed velocity [m/s] where the sensor knows it (a
        pushbroom's orbit, the limb chain's): what aberration of light needs
        (:class:`geoloc.pipeline.Corrections`). None for a frame sensor's pose.
    """

    origin_ecef: np.ndarray
    direction_ecef: np.ndarray
    status: np.ndarray
    velocity_ecef: np.ndarray | None = None


class LatLonDeg:
    """``lat_deg`` / ``lon_deg`` of a result whose ``lat``, ``lon`` are in radians."""

    lat: np.ndarray  # (the result's own fields: this class is no dataclass, so they add none)
    lon: np.ndarray

    @property
    def lat_deg(self) -> np.ndarray:
        return np.rad2deg(self.lat)

    @property
    def lon_deg(self) -> np.ndarray:
        return np.rad2deg(self.lon)


@dataclass(frozen=True)
class GroundPoint(LatLonDeg):
    """Result of a batch geolocation.

    Attributes
    ----------
    lat, lon : ndarray
        Geodetic latitude and longitude of the target [rad]; NaN where no hit.
    h : ndarray
        Ellipsoidal height of the target [m].
    ecef : ndarray (..., 3)
        Target in ECEF [m].
    slant_range : ndarray
        Distance from the optical centre [m].
    status : ndarray of uint8
        :class:`geoloc.status.Status` per ray.
    los : LineOfSight
        The line of sight used (the sensor's, as it gave it, when the point came through
        :class:`geoloc.pipeline.Pipeline`).
    corrections : tuple of str
        The line-of-sight corrections applied (``geoloc.pipeline.CORRECTIONS``: ``"aberration"``,
        ``"light_time"``, ``"refraction"``); empty for a surface met directly.
    refraction_m : ndarray or None
        How far atmospheric refraction moved each point [m] (0 where it is off, NaN where
        there is no point); None for a surface met directly.
    """

    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    ecef: np.ndarray
    slant_range: np.ndarray
    status: np.ndarray
    los: LineOfSight
    corrections: tuple = field(default=(), kw_only=True)
    refraction_m: np.ndarray | None = field(default=None, kw_only=True)


@runtime_checkable
class Surface(Protocol):
    """What a line of sight meets (docs/architecture.md, "The `Surface` interface").

    ``intersect`` returns one :class:`GroundPoint` per ray, NaN and a
    :class:`geoloc.status.Status` where there is no hit; it never raises for a bad ray.
    Implementations: :class:`geoloc.surfaces.height.HeightSurface`,
    :class:`geoloc.surfaces.height.PerRecordHeightSurface`,
    :class:`geoloc.surfaces.terrain.DemSurface`, :class:`geoloc.surfaces.mosaic.DemMosaic`,
    :class:`geoloc.surfaces.terrain.DemElseHeight`.
    """

    def intersect(self, los: LineOfSight) -> GroundPoint: ...


@runtime_checkable
class DemSource(Protocol):
    """A DEM: one raster (:class:`geoloc.surfaces.dem.DEM`) or a mosaic of tiles
    (:class:`geoloc.surfaces.mosaic.DemMosaic`).

    Heights are ellipsoidal (WGS 84) once read: ``datum`` says what the file held
    (``"egm96"``: orthometric, made ellipsoidal with h = H + N; ``"ellipsoid"``).
    """

    datum: str

    @property
    def bounds_deg(self) -> tuple: ...  # (west, south, east, north) [deg]

    @property
    def extent_deg(self) -> tuple: ...  # (west, south, east, north) [deg] where sample gives heights

    def height(
        self, lat: ArrayLike, lon: ArrayLike
    ) -> np.ndarray: ...  # ellipsoidal height [m] at (lat, lon) [rad]; NaN off the data

    def sample(self, lat: ArrayLike, lon: ArrayLike) -> tuple[np.ndarray, np.ndarray]: ...  # height [m], Status


class MosaicSource(DemSource, Protocol):
    """A :class:`DemSource` that is a :class:`Surface` too and solves region by region
    (:class:`geoloc.surfaces.mosaic.DemMosaic`): what :func:`is_mosaic` tells apart. Described here so
    that the terrain module can name it without importing the mosaic module, which imports it."""

    def with_solver(
        self, method: str | None = None, dem_model: str | None = None, **options: Any
    ) -> "MosaicSource": ...

    def intersect(self, los: LineOfSight) -> GroundPoint: ...  # a TerrainHit

    def max_height(self) -> float: ...  # the highest node [m], ellipsoidal

    def to_dem(self) -> DEM: ...  # the whole mosaic as one raster


def is_mosaic(dem: object) -> TypeGuard[MosaicSource]:
    """True for a DEM mosaic: a :class:`DemSource` that is a :class:`Surface` itself and solves
    region by region within its memory bound (:class:`geoloc.surfaces.mosaic.DemMosaic`).

    The one test for it; nothing else asks ``hasattr(dem, "with_solver")`` or ``"cache"``.
    A DEM raster is a source and no surface; ``DemSurface`` a surface and no source.
    """
    return isinstance(dem, DemSource) and isinstance(dem, Surface)


def terrain_of(surface: object) -> DEM | MosaicSource | None:
    """The :class:`DemSource` a surface reads (a DEM or a mosaic), or None for a height surface."""
    if is_mosaic(surface):
        return surface
    return getattr(surface, "dem", None)
