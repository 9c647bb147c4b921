"""Direct geolocation: pixel -> line of sight in ECEF -> ground point on a surface.

[Q17 section 2.2]: T'_E = C^ECEF_NED C^NED_AC C^AC_S T'_S (eq. 9), the target on
the line from the optical centre O_E through T'_E (eq. 10), on the ellipsoid
inflated to the target height (eq. 11), converted to geodetic coordinates
(eq. 12-13; here by the closed form of :func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`).

Every call goes through the location pipeline (:class:`geoloc.pipeline.Pipeline`,
``docs/architecture.md``)::

    locate(pose, sensor, row, col, target_h, corrections=c)
        ==  Pipeline(sensor, HeightSurface(target_h), c).locate(row, col, pose)

``sensor`` is a :class:`geoloc.sensors.frame.FrameSensor` or a first-phase
:class:`geoloc.sensors.camera.Camera` (taken as its sensor: a pinhole on the
[Q17] roll-pitch gimbal). Conventions: ``docs/conventions.md``. Batch functions
never raise for a bad ray: they return NaN and a :class:`geoloc.status.Status`
code per ray.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.frames.chain import Pose
from geoloc.geodesy.ellipsoid import geodetic_to_ecef
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.sensors.base import PixelHit, check_outside
from geoloc.sensors.camera import as_sensor
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight
from geoloc.surfaces.height import HeightSurface

if TYPE_CHECKING:
    from geoloc.sensors.camera import FrameSensorLike
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import TerrainHit


def _default_pixel(sensor, row, col):
    r0, c0 = sensor.center_pixel
    return (r0 if row is None else row), (c0 if col is None else col)


def line_of_sight(
    pose: Pose,
    sensor: FrameSensorLike,
    row: ArrayLike | None = None,
    col: ArrayLike | None = None,
    *,
    outside: str = "flag",
    engine: str = "auto",
) -> LineOfSight:
    """Pixel (i, j) -> line of sight in ECEF [Q17 eq. 8-9, generalised to any gimbal and lens].

    Parameters
    ----------
    pose : Pose
        Platform pose and gimbal angles (radians), any batch shape.
    sensor : FrameSensor or Camera
    row, col : array_like, optional
        1-based pixel; default the image centre ((M+1)/2, (N+1)/2).
    outside : {"flag", "extrapolate"}
        A pixel off the sensor gets status OUTSIDE_SENSOR (default), or its
        ray through the lens model beyond the edge (``"extrapolate"``, for a
        caller that reports such pixels itself).
    engine : {"auto", "numpy", "numba"}
        See :meth:`geoloc.sensors.frame.FrameSensor.line_of_sight` (``"auto"``: the
        compiled kernel for 10 000 rays or more).

    Returns
    -------
    LineOfSight
        Status INVALID_INPUT for a bad pose or pixel, OUTSIDE_SENSOR for a
        pixel off the sensor.
    """
    check_outside(outside)
    s = as_sensor(sensor)
    row, col = _default_pixel(s, row, col)
    return s.line_of_sight(row, col, pose, outside=outside, engine=engine)


def locate(
    pose: Pose,
    sensor: FrameSensorLike,
    row: ArrayLike | None = None,
    col: ArrayLike | None = None,
    target_h: ArrayLike = 0.0,
    *,
    height_kind: str = "inflated",
    engine: str = "auto",
    outside: str = "flag",
    corrections: Corrections = NO_CORRECTIONS,
) -> GroundPoint:
    """Geolocate pixels at a known target height: the whole of [Q17 section 2.2].

    Vectorised: pose fields, pixels and ``target_h`` broadcast together.

    Parameters
    ----------
    pose : Pose
    sensor : FrameSensor or Camera
    row, col : array_like, optional
        1-based pixel; default the image centre.
    target_h : array_like
        Target ellipsoidal height [m].
    height_kind : {"inflated", "geodetic"}
        Kind of constant-height surface (:class:`geoloc.surfaces.height.HeightSurface`).
    engine : {"auto", "numpy", "numba"}
        ``"numpy"`` is the reference path (lens and frame graph in numpy);
        ``"numba"`` runs the fused kernel of :mod:`geoloc.sensors._fastlocate`
        (same mathematics, any gimbal, lens, mount, boresight and lever arm;
        inflated surface). ``"auto"`` picks numba for batches of
        10 000 rays or more on the inflated surface.
    outside : {"flag", "extrapolate"}
        See :func:`line_of_sight`.
    corrections : Corrections
        The line-of-sight corrections (:class:`geoloc.pipeline.Corrections`; none by default,
        as the paper).

    Returns
    -------
    GroundPoint
        NaN and a status where a ray looks at the sky, starts below the
        target height, has invalid input or comes from a pixel off the sensor.

    Examples
    --------
    >>> from geoloc import Camera, Pose, locate
    >>> cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)
    >>> pose = Pose.from_deg(35.48, 80.97, 18000, 45, 3.5, 0, 50, -2.6)
    >>> round(float(locate(pose, cam, target_h=5083.5).lat_deg), 5)
    35.57709
    """
    check_outside(outside)
    s = as_sensor(sensor)
    surface = HeightSurface(target_h, height_kind)
    if engine == "numba":
        from geoloc.sensors import _fastlocate

        if not (height_kind == "inflated" and _fastlocate.serves(s)):
            raise ValueError(
                "engine='numba' needs height_kind='inflated' and a sensor the kernel serves "
                "(one lens, no per-sample perturbation)"
            )
    row, col = _default_pixel(s, row, col)
    return Pipeline(s, surface, corrections).locate(row, col, pose, outside=outside, engine=engine)


def ground_to_pixel(
    pose: Pose,
    sensor: FrameSensorLike,
    lat: ArrayLike,
    lon: ArrayLike,
    h: ArrayLike,
    corrections: Corrections = NO_CORRECTIONS,
) -> PixelHit:
    """Ground point (geodetic, radians and metres) -> 1-based pixel: the inverse of :func:`locate`
    (with the same ``corrections``: :meth:`geoloc.pipeline.Pipeline.ground_to_pixel`).

    Returns
    -------
    PixelHit
        ``row, col, status`` (it unpacks as that triple); NaN where the point
        is behind the camera, OUTSIDE_SENSOR where it projects off the sensor.
    """
    return Pipeline(as_sensor(sensor), None, corrections).ground_to_pixel(lat, lon, h, pose)


#: A ground point is hidden from the camera when the camera's ray towards it meets the surface
#: this much nearer [m]: the exact solver's hits agree to millimetres (docs/terrain.md), the
#: DEM's bilinear surface is continuous, so 1 m separates a true occluder from round-off.
HIDDEN_TOLERANCE_M = 1.0


@dataclass(frozen=True)
class PointView:
    """How a camera sees one ground point (:func:`point_view`)."""

    row: float
    col: float
    pixel_status: int  # Status of ground_to_pixel: OK, OUTSIDE_SENSOR, BEHIND_CAMERA, ...
    visible: bool  # nothing on the surface in front of it (False where no pixel was found)
    occluder_range_m: float  # where the pixel's line of sight meets the surface first [m], NaN if nowhere
    range_m: float  # camera to the point [m]


def point_view(
    pipe: Pipeline,
    state: Any,
    lat: float | NDArray[np.float64],
    lon: float | NDArray[np.float64],
    h: float | NDArray[np.float64],
) -> PointView:
    """The pixel that sees one ground point, and whether the surface hides it from the camera.

    The pixel is ``pipe.ground_to_pixel`` (radians, metres ellipsoidal). Where it is in the
    frame or off its edge (``OUTSIDE_SENSOR``), the line of sight through that pixel
    (extrapolated beyond the edge) is cast through the pipeline: the point is hidden when the
    ray meets the surface more than :data:`HIDDEN_TOLERANCE_M` before it. Used by the
    viewer's terrain pick and by ``geoloc pixel``.
    """

    px = pipe.ground_to_pixel(np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float), state)
    st = int(np.asarray(px.status))
    row, col = float(np.asarray(px.row)), float(np.asarray(px.col))
    nan = float("nan")
    visible, occ, rng = False, nan, nan
    if st in (Status.OK, Status.OUTSIDE_SENSOR):
        back = pipe.locate(row, col, state, outside="extrapolate")
        rng = float(
            np.linalg.norm(geodetic_to_ecef(float(lat), float(lon), float(h)) - np.asarray(back.los.origin_ecef))
        )
        if int(np.asarray(back.status)) == Status.OK:
            occ = float(back.slant_range)
            visible = occ > rng - HIDDEN_TOLERANCE_M
        else:  # the camera's ray meets nothing before it: nothing hides the point
            visible = True
    return PointView(row, col, st, visible, occ, rng)


def locate_dem(
    pose: Pose,
    sensor: FrameSensorLike,
    row: ArrayLike | None = None,
    col: ArrayLike | None = None,
    dem: DEM | None = None,
    method: str = "exact",
    *,
    corrections: Corrections = NO_CORRECTIONS,
    **kwargs: Any,
) -> TerrainHit:
    """Geolocate pixels on a DEM: the pipeline with a :class:`geoloc.surfaces.terrain.DemSurface`.

    Parameters
    ----------
    pose, sensor, row, col
        As for :func:`locate`.
    dem : geoloc.surfaces.dem.DEM
    method : {"steps", "bisect", "exact"}
    corrections : Corrections
    **kwargs
        ``dem_model``, ``eps_h``, ``threshold``, ``trace``, ``max_iter``.
    """
    from geoloc.surfaces.terrain import DemSurface, TerrainHit

    if dem is None:
        raise ValueError("dem is required")
    s = as_sensor(sensor)
    row, col = _default_pixel(s, row, col)
    dem_model = kwargs.pop("dem_model", "bilinear")
    hit = Pipeline(s, DemSurface(dem, method, dem_model, **kwargs), corrections).locate(row, col, pose)
    # DemSurface meets the rays in a TerrainHit and the pipeline's corrections replace its fields
    # (dataclasses.replace), keeping its class: the type the Pipeline's signature cannot say
    assert isinstance(hit, TerrainHit)
    return hit


__all__ = [
    "HIDDEN_TOLERANCE_M",
    "PointView",
    "as_sensor",
    "ground_to_pixel",
    "line_of_sight",
    "locate",
    "locate_dem",
    "point_view",
]
