"""The sensor interface: pixels to lines of sight and ground points to pixels.

Every sensor of geoloc (the frame camera on a gimbal, the pushbroom [L12], the
RPC model, the [L18] limb instrument) offers the calls of :class:`Sensor`, so
that locate, replay, Monte Carlo, calibration and both viewers work with any of
them (``docs/architecture.md``). Pixels are 1-based pixel centres ``(row, col)``
(``docs/conventions.md``, "Pixels").

Batch calls never raise for a bad element: they return NaN and a
:class:`geoloc.status.Status` per element. ``OUTSIDE_SENSOR`` marks a pixel off
the sensor; its geometry is still computed, so a caller that wants the
extrapolated ray can read it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from geoloc.status import Status
from geoloc.surfaces.base import LineOfSight

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

#: Batches of this many rays or more take the compiled kernels when the caller lets the code
#: choose (``engine="auto"`` of the pipeline, :func:`geoloc.locate.locate`,
#: ``FrameSensor.line_of_sight`` and the uncertainty): below it numba's call overhead and the
#: argument checks are a larger share.
COMPILED_MIN_RAYS = 10_000

_D = TypeVar("_D", bound="DataclassInstance")


@dataclass(frozen=True)
class PixelHit:
    """Result of a batch ground -> pixel projection.

    Attributes
    ----------
    row, col : ndarray
        1-based pixel centre coordinates; NaN where the status says why not.
    status : ndarray of uint8
        OK, BEHIND_CAMERA, OUTSIDE_SENSOR (the pixel is computed but off the
        sensor), OUTSIDE_DOMAIN (RPC), INVALID_INPUT, NO_CONVERGENCE.
    """

    row: np.ndarray
    col: np.ndarray
    status: np.ndarray

    def __iter__(self):
        # unpacks as (row, col, status), as ground_to_pixel returned before
        return iter((self.row, self.col, self.status))


@runtime_checkable
class Sensor(Protocol):
    """What every sensor offers (``docs/architecture.md``, "The Sensor interface")."""

    @property
    def rows(self) -> int:
        """Image height [pixels]."""

    @property
    def cols(self) -> int:
        """Image width [pixels]."""

    @property
    def params(self) -> Mapping[str, float]:
        """Named parameters in SI units: what Monte Carlo may perturb and calibration fit."""

    def with_params(self, **changes: float) -> "Sensor":
        """A copy with some named parameters changed (unknown names are an error)."""

    def line_of_sight(self, row: ArrayLike, col: ArrayLike, state: Any = None, *, outside: str = "flag") -> LineOfSight:
        """1-based pixels -> lines of sight in ECEF, batched, NaN + Status (``outside``: "flag" or
        "extrapolate", :func:`check_outside`)."""

    def ground_to_pixel(self, lat: ArrayLike, lon: ArrayLike, h: ArrayLike, state: Any = None) -> PixelHit:
        """Geodetic points (radians, metres) -> 1-based pixels, batched, NaN + Status."""

    def in_image(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        """True where the 1-based pixel lies on the sensor."""

    def frames(self, state: Any = None) -> Any:
        """The sensor's frame graph for ``state`` (what the viewers draw)."""


def in_sensor(row: ArrayLike, col: ArrayLike, rows: int, cols: int) -> np.ndarray:
    """True where 0.5 <= row <= rows + 0.5 and 0.5 <= col <= cols + 0.5 (1-based pixel centres)."""
    row, col = np.asarray(row, float), np.asarray(col, float)
    with np.errstate(invalid="ignore"):
        return (row >= 0.5) & (row <= rows + 0.5) & (col >= 0.5) & (col <= cols + 0.5)


def flag_outside(status: ArrayLike, row: ArrayLike, col: ArrayLike, rows: int, cols: int) -> np.ndarray:
    """``status`` with OUTSIDE_SENSOR where an otherwise OK pixel lies off the sensor."""
    status = np.asarray(status, np.uint8)
    off = ~in_sensor(row, col, rows, cols) & np.isfinite(row) & np.isfinite(col)
    return np.where((status == Status.OK) & off, np.uint8(Status.OUTSIDE_SENSOR), status).astype(np.uint8)


#: What a line-of-sight call does with a pixel off the sensor.
OUTSIDE_MODES = ("flag", "extrapolate")


def check_outside(outside: str) -> None:
    if outside not in OUTSIDE_MODES:
        raise ValueError(f"outside = {outside!r}: must be one of {OUTSIDE_MODES}")


def check_angle_names(given: Mapping[str, str], need: Sequence[str], gimbal: str, defaults: Sequence[str] = ()) -> None:
    """Check the joint angles a caller gives against those a gimbal has (an angle the gimbal lacks
    would otherwise be ignored without a word).

    Parameters
    ----------
    given : mapping
        Angle name -> how the caller gave it, for the message (e.g. ``"--angle tilt=-30"``).
    need : sequence of str
        The gimbal's joint angles (``FrameSensor.angle_names``).
    gimbal : str
        The gimbal's name.
    defaults : sequence of str
        Angles that may be left out (taken as 0).

    Raises
    ------
    ValueError
        An angle the gimbal does not have (first: a misspelt name explains a missing one),
        naming it, how it was given and the gimbal's angles; then the angles missing.
    """
    need = list(need)
    unknown = [a for a in given if a not in need]
    if unknown:
        more = f" (also unknown: {unknown[1:]})" if len(unknown) > 1 else ""
        raise ValueError(
            f"{given[unknown[0]]}: the sensor's {gimbal} gimbal has no angle {unknown[0]!r}; "
            f"its angles are {need}{more}"
        )
    missing = [a for a in need if a not in given and a not in defaults]
    if missing:
        raise ValueError(
            f"missing angle(s) {missing}: the sensor's {gimbal} gimbal needs {need}; "
            "give each (--angle NAME=DEG on the command line)"
        )


def replace_params(obj: _D, changes: Mapping[str, float]) -> _D:
    """``dataclasses.replace(obj, **changes)`` for names :func:`check_param_names` has checked
    against ``obj.params`` (float fields). The changes pass as a ``dict[str, Any]``: the checker
    cannot tell from a mapping's value type which fields its names are, and would hold every float
    against every field's type."""
    fields: dict[str, Any] = dict(changes)
    return dataclasses.replace(obj, **fields)


def check_param_names(changes: Mapping[str, float], known: Mapping[str, float], what: str) -> None:
    """Raise ValueError naming any parameter of ``changes`` that ``known`` does not have."""
    unknown = sorted(set(changes) - set(known))
    if unknown:
        raise ValueError(f"{what} has no parameter(s) {unknown}; its parameters are {sorted(known)}")
