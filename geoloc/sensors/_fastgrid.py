"""Compiled lines of sight for a whole grid of pixels of one frame (one pose).

:meth:`geoloc.sensors.frame.FrameSensor.line_of_sight` builds a frame's 5.3 M
rays (the 2323 x 2292 [Q17] sensor) through about a dozen temporary arrays of
5.3 M x 3 doubles (3.5 s on this 2-core machine). Here the pose is one state, so
the whole chain from the optical frame to ECEF is one rotation: it is composed
once, with the pieces of the fused kernel of :mod:`geoloc.sensors._fastlocate`
(``_mul_T``, ``_turn_back``, ``_body_to_ned``: the same hops in the same order,
[Q17 eq. 4-7] and the gimbal presets of ``docs/conventions.md``), and each pixel
costs one lens inversion (:func:`geoloc.sensors.lenses.unproject_nb`) and one
3x3 product, in parallel over the rows.

The optical centre (navigation reference plus lever arm) is the numpy path's own
:meth:`FrameSensor.optical_centre_ecef`: one point per frame.

``tests/workflows/test_ortho.py`` holds :func:`grid_line_of_sight` equal to
``sensor.line_of_sight`` ray for ray, for the [Q17] pinhole, the turret's Brown
lens on the azimuth-elevation gimbal (mount, boresight, lever arm) and the drone's
earth-referenced gimbal. Conventions: ``docs/conventions.md`` (1-based pixel
centres, passive rotations).
"""

from __future__ import annotations

import math
import sys

import numpy as np

from geoloc import status as _status_module
from geoloc.geodesy import _nbgeo
from geoloc.geodesy._nbgeo import cached_njit, dependency_key, prange
from geoloc.sensors import _fastlocate
from geoloc.sensors import lenses as _lenses_module
from geoloc.sensors._fastlocate import _AXIS, _body_to_ned, _mul_T, _turn_back
from geoloc.sensors.lenses import unproject_nb
from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight

#: Cache key: constants and the sources of every module whose compiled code the kernels call.
KEY = dependency_key(_nbgeo, _status_module, _lenses_module, _fastlocate, sys.modules[__name__])

_OK = int(Status.OK)
_INVALID = int(Status.INVALID_INPUT)
_OUTSIDE = int(Status.OUTSIDE_SENSOR)


@cached_njit(KEY)
def _chain_matrix(lat, lon, heading, pitch, roll, angles, axes, R_cam_last, has_mount, R_base_body, earth_ref, out_R):
    """``R_ecef_cam`` of one state: the columns are the optical axes carried hop by hop to ECEF.

    The hops of ``_fastlocate.locate_kernel``: optical -> last joint frame (``R_cam_last``^T),
    each joint back to its parent, the mount (unless earth-referenced), body -> NED
    [Q17 eq. 6], NED -> ECEF [Q17 eq. 5].
    """
    nj = axes.shape[0]
    sp, cp = math.sin(lat), math.cos(lat)
    sl, cl = math.sin(lon), math.cos(lon)
    for i in range(3):
        x = 1.0 if i == 0 else 0.0
        y = 1.0 if i == 1 else 0.0
        z = 1.0 if i == 2 else 0.0
        x, y, z = _mul_T(R_cam_last, x, y, z)
        for j in range(nj - 1, -1, -1):
            x, y, z = _turn_back(axes[j], angles[j], x, y, z)
        if not earth_ref:
            if has_mount:
                x, y, z = _mul_T(R_base_body, x, y, z)
            x, y, z = _body_to_ned(heading, pitch, roll, x, y, z)
        out_R[0, i] = -sp * cl * x - sl * y - cp * cl * z
        out_R[1, i] = -sp * sl * x + cl * y - cp * sl * z
        out_R[2, i] = cp * x - sp * z


@cached_njit(KEY, parallel=True)
def grid_kernel(rows, cols, lens_code, lens_p, n_rows, n_cols, R, bad_state, out_d, out_status):
    """Directions (ECEF, unit) and status of every (rows[i], cols[j]) pixel (1-based centres)."""
    nr = rows.shape[0]
    nc = cols.shape[0]
    for i in prange(nr):
        r = rows[i]
        row_in = 0.5 <= r <= n_rows + 0.5
        for j in range(nc):
            c = cols[j]
            # pixel (1-based) -> optical frame (OpenCV's 0-based u, v), as _fastlocate
            x, y, z = unproject_nb(lens_code, lens_p, c - 1.0, r - 1.0)
            dx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
            dy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
            dz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
            k = i * nc + j
            out_d[k, 0], out_d[k, 1], out_d[k, 2] = dx, dy, dz
            if bad_state or not (math.isfinite(r) and math.isfinite(c)):
                out_status[k] = _INVALID
            elif not (row_in and 0.5 <= c <= n_cols + 0.5):
                out_status[k] = _OUTSIDE  # before the lens's NaN: off the sensor is the reason, which says what to fix
            elif not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
                out_status[k] = _INVALID
            else:
                out_status[k] = _OK


def _scalar_state(state, names):
    """The pose's fields as floats; ValueError if the pose holds more than one state."""
    if int(np.prod(state.shape)) != 1:
        raise ValueError(f"pose has batch shape {state.shape}: a whole frame needs one pose (one state)")
    one = lambda v: float(np.ravel(np.asarray(v, float))[0])
    fields = [one(getattr(state, k)) for k in ("lat", "lon", "heading", "pitch", "roll")]
    return fields, np.array([one(state.angle(a)) for a in names], float)


def R_ecef_cam(sensor, state) -> np.ndarray:
    """The rotation optical frame -> ECEF of ``sensor`` (a FrameSensor) at one ``state``, (3, 3)."""
    sensor._check_state(state)
    (lat, lon, heading, pitch, roll), angles = _scalar_state(state, sensor.angle_names)
    axes = np.array([_AXIS[j.axis] for j in sensor.gimbal.joints], dtype=np.int64)
    R = np.empty((3, 3))
    _chain_matrix(
        lat,
        lon,
        heading,
        pitch,
        roll,
        angles,
        axes,
        np.ascontiguousarray(sensor.R_cam_last, float),
        not np.array_equal(sensor.R_base_body, np.eye(3)),
        np.ascontiguousarray(sensor.R_base_body, float),
        bool(sensor.gimbal.earth_referenced),
        R,
    )
    return R


def supports(sensor) -> bool:
    """True if :func:`grid_line_of_sight` serves ``sensor``: a FrameSensor with one (unbatched) lens
    and no per-sample Monte Carlo perturbations."""
    from geoloc.sensors._fastlocate import serves

    return serves(sensor)


def grid_line_of_sight(sensor, state, rows, cols) -> LineOfSight:
    """Lines of sight of the pixel grid ``rows x cols`` of one frame, compiled.

    Parameters
    ----------
    sensor : FrameSensor
        See :func:`supports`.
    state : Pose
        One pose (batch size 1) with the gimbal's joint angles.
    rows, cols : array_like, 1-D
        1-based pixel centres (``docs/conventions.md``, "Pixels").

    Returns
    -------
    LineOfSight
        Shape ``(len(rows), len(cols))``: the origin is one optical centre broadcast
        (a read-only view), the directions unit vectors in ECEF. Status
        INVALID_INPUT for a pose out of range or a NaN pixel (the whole grid for
        a bad pose), OUTSIDE_SENSOR off the rows/columns, as ``sensor.line_of_sight``.
    """
    if not supports(sensor):
        raise ValueError(
            f"sensor = {sensor!r}: the compiled grid serves a FrameSensor with one lens (use sensor.line_of_sight)"
        )
    rows = np.ascontiguousarray(np.asarray(rows, float).reshape(-1))
    cols = np.ascontiguousarray(np.asarray(cols, float).reshape(-1))
    R = R_ecef_cam(sensor, state)
    o = np.asarray(sensor.optical_centre_ecef(state), float).reshape(-1, 3)[0]
    bad = bool(np.any(state.invalid_mask())) or not np.all(np.isfinite(o))
    n = rows.size * cols.size
    d = np.empty((n, 3))
    st = np.empty(n, dtype=np.uint8)
    lens = sensor.lens
    grid_kernel(
        rows,
        cols,
        int(lens.code),
        np.ascontiguousarray(lens.as_array(), float),
        float(sensor.rows),
        float(sensor.cols),
        R,
        bad,
        d,
        st,
    )
    shape = (rows.size, cols.size)
    return LineOfSight(np.broadcast_to(o, shape + (3,)), d.reshape(shape + (3,)), st.reshape(shape))
