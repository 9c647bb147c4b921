"""Direct geolocation: pixel -> line of sight in ECEF -> ground point at a target height.

[Q17 section 2.2]: T'_E = C^ECEF_NED C^NED_AC C^AC_S T'_S (eq. 9), the target on
the line from the optical centre O_E through T'_E (eq. 10), on the ellipsoid
inflated to the target height (eq. 11), converted to geodetic coordinates
(eq. 12-13; here by the closed form of :func:`geoloc.geodesy.ellipsoid.ecef_to_geodetic`).

Conventions: ``docs/conventions.md``. Batch functions never raise for a bad ray:
they return NaN and a :class:`geoloc.status.Status` code per ray.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from geoloc.frames.chain import FrameChain, Pose
from geoloc.sensors.camera import Camera
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight
from geoloc.surfaces.height import intersect_los_height

if TYPE_CHECKING:
    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import TerrainHit


def camera_chain(pose: Pose, camera: Camera) -> FrameChain:
    """The frame chain of ``pose`` with the camera's optional boresight and mounting rotations.

    ``FrameChain(pose, R_cam_inner=camera.R_cam_inner, R_base_body=camera.R_base_body)``;
    for a camera without them it is ``FrameChain(pose)``.
    """
    return FrameChain(pose, R_cam_inner=camera.R_cam_inner, R_base_body=camera.R_base_body)


def line_of_sight(pose: Pose, camera: Camera, row=None, col=None, *, chain: FrameChain | None = None,
                  ) -> LineOfSight:
    """Pixel (i, j) -> line of sight in ECEF [Q17 eq. 8-9].

    Parameters
    ----------
    pose : Pose
        Aircraft pose and gimbal angles (radians), any batch shape.
    camera : Camera
        The camera.
    row, col : array_like, optional
        1-based pixel; default the CCD centre ((M+1)/2, (N+1)/2).
    chain : FrameChain, optional
        A prebuilt chain for ``pose`` (to add boresight / mounting rotations);
        default :func:`camera_chain` (which applies the camera's own
        ``boresight`` / ``mount`` if it has them; a given chain replaces them).

    Returns
    -------
    LineOfSight
    """
    if row is None or col is None:
        r0, c0 = camera.center_pixel
        row = r0 if row is None else row
        col = c0 if col is None else col
    chain = chain if chain is not None else camera_chain(pose, camera)
    d_cam = camera.pixel_to_los(row, col)
    d_ecef = chain.cam_to_ecef(d_cam)
    o = chain.origin_ecef
    shape = np.broadcast_shapes(o.shape, d_ecef.shape)[:-1]
    o = np.broadcast_to(o, shape + (3,))
    d_ecef = np.broadcast_to(d_ecef, shape + (3,))
    bad = np.broadcast_to(pose.invalid_mask(), shape)
    bad = bad | ~np.all(np.isfinite(d_ecef), axis=-1)
    status = np.where(bad, Status.INVALID_INPUT, Status.OK).astype(np.uint8)
    return LineOfSight(o, d_ecef, status)


def locate(pose: Pose, camera: Camera, row=None, col=None, target_h=0.0, *,
           surface: str = "inflated", chain: FrameChain | None = None,
           engine: str = "auto") -> GroundPoint:
    """Geolocate pixels at a known target height: the whole of [Q17 section 2.2].

    Vectorised: pose fields, pixels and ``target_h`` broadcast together.

    Parameters
    ----------
    pose : Pose
    camera : Camera
    row, col : array_like, optional
        1-based pixel; default the CCD centre.
    target_h : array_like
        Target ellipsoidal height [m].
    surface : {"inflated", "geodetic"}
        See :func:`intersect_los_height`.
    chain : FrameChain, optional
        Prebuilt chain (boresight / mounting rotations).
    engine : {"auto", "numpy", "numba"}
        ``"numpy"`` composes the :class:`FrameChain` matrices (the reference);
        ``"numba"`` runs the fused kernel of :mod:`geoloc.sensors._fastlocate` (same
        mathematics, ~10x faster on large batches; inflated surface, no extra
        chain rotations, no camera boresight / mount, no lens distortion). ``"auto"`` picks numba for
        batches of 10 000 rays or more when it applies.

    Returns
    -------
    GroundPoint
        NaN and a status where a ray looks at the sky, starts below the
        target height or has invalid input.

    Examples
    --------
    >>> from geoloc import Camera, Pose, locate
    >>> cam = Camera(166841.0, 1162.12, 1146.42, 2323, 2292)
    >>> pose = Pose.from_deg(35.48, 80.97, 18000, 45, 3.5, 0, 50, -2.6)
    >>> round(float(locate(pose, cam, target_h=5083.5).lat_deg), 5)
    35.57709
    """
    if engine not in ("auto", "numpy", "numba"):
        raise ValueError(f"engine must be 'auto', 'numpy' or 'numba', got {engine!r}")
    fast_ok = (chain is None and surface == "inflated" and type(camera) is Camera
               and camera.boresight is None and camera.mount is None)
    if engine == "numba" and not fast_ok:
        raise ValueError("engine='numba' needs surface='inflated', no chain and a plain Camera")
    if row is None or col is None:
        r0, c0 = camera.center_pixel
        row = r0 if row is None else row
        col = c0 if col is None else col
    if engine == "numba" or (engine == "auto" and fast_ok and _batch_size(pose, row, col, target_h) >= 10_000):
        from geoloc.sensors._fastlocate import locate_fast

        lat, lon, h, ecef, s, status, o, d = locate_fast(pose, camera, row, col, target_h)
        los = LineOfSight(o, d, np.where(status == Status.INVALID_INPUT, status, Status.OK).astype(np.uint8))
        return GroundPoint(lat, lon, h, ecef, s, status, los)
    los = line_of_sight(pose, camera, row, col, chain=chain)
    return intersect_los_height(los, target_h, surface)


def _batch_size(pose: Pose, *arrays) -> int:
    shape = np.broadcast_shapes(pose.shape, *(np.shape(a) for a in arrays))
    return int(np.prod(shape))


def ground_to_pixel(pose: Pose, camera: Camera, lat, lon, h, *, chain: FrameChain | None = None):
    """Ground point (geodetic) -> pixel: the inverse of :func:`locate`.

    d_S = R_cam_ecef (P_E - O_E), then the pinhole projection of
    :meth:`Camera.los_to_pixel`.

    Returns
    -------
    row, col : ndarray
        1-based pixel coordinates; NaN where the point is behind the camera.
    status : ndarray of uint8
    """
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    chain = chain if chain is not None else camera_chain(pose, camera)
    p = geodetic_to_ecef(lat, lon, h)
    d_cam = chain.ecef_to_cam(p - chain.origin_ecef)
    return camera.los_to_pixel(d_cam)


def locate_dem(pose, camera, row=None, col=None, dem: DEM | None = None, method: str = "exact", *,
               chain=None, **kwargs) -> TerrainHit:
    """Geolocate pixels on a DEM: :func:`line_of_sight` then :func:`geoloc.surfaces.terrain.intersect_dem`.

    Parameters
    ----------
    pose, camera, row, col, chain
        As for :func:`geoloc.locate.locate`.
    dem : geoloc.surfaces.dem.DEM
    method : {"steps", "bisect", "exact"}
    **kwargs
        ``eps_h``, ``threshold``, ``surface``, ``trace``, ``max_iter``.
    """
    if dem is None:
        raise ValueError("dem is required")
    from geoloc.surfaces.terrain import intersect_dem

    los = line_of_sight(pose, camera, row, col, chain=chain)
    return intersect_dem(los, dem, method, **kwargs)
