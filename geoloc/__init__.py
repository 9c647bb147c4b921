"""geoloc: direct geolocation of ground targets from airborne and spaceborne cameras.

The compute core. It imports no visualisation library; ``viz/`` depends on it,
never the reverse. Conventions (frames, rotation order, units, angle names):
``docs/conventions.md``.
"""

from geoloc.frames.chain import FrameChain, Pose
from geoloc.geodesy.ellipsoid import (
    ecef_to_geodetic,
    ecef_to_geodetic_q17,
    geodetic_to_ecef,
)
from geoloc.locate import ground_to_pixel, line_of_sight, locate
from geoloc.pipeline import Corrections, Pipeline
from geoloc.sensors.camera import Camera
from geoloc.status import Status
from geoloc.surfaces.base import GroundPoint, LineOfSight
from geoloc.surfaces.height import HeightSurface

__all__ = [
    "Camera",
    "Corrections",
    "FrameChain",
    "GroundPoint",
    "HeightSurface",
    "LineOfSight",
    "Pipeline",
    "Pose",
    "Status",
    "ecef_to_geodetic",
    "ecef_to_geodetic_q17",
    "geodetic_to_ecef",
    "ground_to_pixel",
    "line_of_sight",
    "locate",
]

__version__ = "0.1.0"
