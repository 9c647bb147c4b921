"""Error models for Monte Carlo geolocation analysis [Q17 section 3, Tables 1-2].

An error model is a TOML file with a nominal geometry (aircraft pose, gimbal
angles, camera, target pixel and height, optionally a DEM) and one
distribution per error source. Degrees, micrometres and metres at this edge
(``_deg``, ``_um``, ``_m`` suffixes); :meth:`ErrorModel.sample` returns radians
and metres. Conventions: ``docs/conventions.md``; user guide:
``docs/montecarlo.md``.

File format (``assets/scenarios/qiao2017_table1.toml`` is a complete example)::

    name = "..."
    [camera]            # the keys of a camera file (docs/camera_format.md; pixel_pitch_m needed
                        # for the image-centre error in micrometres), or the tables of a
                        # sensor file ([camera.lens], [camera.gimbal] = roll-pitch,
                        # [camera.mount], ...: docs/sensor_format.md), e.g. a Brown lens
    [nominal]           # lat_deg lon_deg h_m heading_deg pitch_deg roll_deg
                        # gimbal_roll_deg gimbal_pitch_deg
    [target]            # h_m (ellipsoidal), optional row/col (default CCD centre),
                        # height_kind = "inflated" | "geodetic"
    [errors]            # source = { dist = "normal", sigma = s } or
                        #          { dist = "uniform", max = m }, optional bias = b
    [dem]               # optional: path (relative to the file or assets/), datum,
                        # method; replaces the target height by the terrain

Error sources (all optional, missing means exactly zero):

=============================  =====================================================
``lat_deg lon_deg h_m``        aircraft position (POS) [Q17 Table 1]
``heading_deg pitch_deg
roll_deg``                     aircraft attitude (POS) [Q17 Table 1]
``gimbal_roll_deg
gimbal_pitch_deg``             gimbal encoders [Q17 Table 1]
``image_centre_x_um
image_centre_y_um``            image-centre position error on the CCD [Q17 Table 2];
                               x along rows (i), y along columns (j) as in [Q17 eq. 8]
``gimbal_nonorthogonality_deg`` inner (pitch) axis tilted towards the outer (roll) axis
``collimation_deg``            line of sight not perpendicular to the inner axis
``vibration_yaw_deg
vibration_pitch_deg
vibration_roll_deg``           shock-absorber angular vibration between body and
                               gimbal base [Q17 Table 2]
``target_h_m``                 target height uncertainty (terrain standard deviation)
``mount_{x,y,z}_deg
boresight_{x,y,z}_deg
lever_arm_{x,y,z}_m``          the sensor's named mount / boresight / lever-arm
                               parameters (``FrameSensor.params``), perturbed
                               exactly: the sample's value is the file's plus the draw
``fx_px fy_px``                the lens's focal lengths [px] (``FrameSensor.params``)
``focal_length_px``            both focal lengths by the same draw (square pixels)
``cx_px cy_px``                the lens's principal point (column, row) [px]
``skew_px``                    the lens's skew ``K[0, 1]`` [px]
``k1 k2 p1 p2 k3 k4 k5 k6``    the lens's distortion coefficients (Brown; a fisheye
                               lens has k1..k4); each the lens's value plus the draw,
                               per sample (``Lens.with_params`` with arrays)
=============================  =====================================================
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.frames.chain import Pose
from geoloc.pipeline import NO_CORRECTIONS, Corrections, corrections_from_table
from geoloc.sensors.camera import as_sensor
from geoloc.sensors.frame import FrameSensor
from geoloc.tomlio import read_toml

#: Pose fields of the [nominal] table, in Pose order, with their unit suffix.
POSE_KEYS = ("lat_deg", "lon_deg", "h_m", "heading_deg", "pitch_deg", "roll_deg", "gimbal_roll_deg", "gimbal_pitch_deg")


def _pose_deg(nominal: Mapping[str, float]) -> Pose:
    """The :class:`Pose` of a ``[nominal]`` table's :data:`POSE_KEYS` (degrees and metres)."""
    n = nominal
    return Pose.from_deg(
        n["lat_deg"],
        n["lon_deg"],
        n["h_m"],
        n["heading_deg"],
        n["pitch_deg"],
        n["roll_deg"],
        n["gimbal_roll_deg"],
        n["gimbal_pitch_deg"],
    )


#: Every error source the model knows, with a one-line meaning (docs and errors).
ERROR_SOURCES = {
    "lat_deg": "aircraft latitude (POS)",
    "lon_deg": "aircraft longitude (POS)",
    "h_m": "aircraft ellipsoidal height (POS)",
    "heading_deg": "aircraft heading (POS)",
    "pitch_deg": "aircraft pitch (POS)",
    "roll_deg": "aircraft roll (POS)",
    "gimbal_roll_deg": "outer gimbal encoder",
    "gimbal_pitch_deg": "inner gimbal encoder",
    "image_centre_x_um": "image-centre position error, x (rows)",
    "image_centre_y_um": "image-centre position error, y (columns)",
    "gimbal_nonorthogonality_deg": "inner/outer gimbal axes not orthogonal",
    "collimation_deg": "line of sight not perpendicular to the inner gimbal axis",
    "vibration_yaw_deg": "shock-absorber vibration, yaw",
    "vibration_pitch_deg": "shock-absorber vibration, pitch",
    "vibration_roll_deg": "shock-absorber vibration, roll",
    "target_h_m": "target height (terrain standard deviation)",
    # the sensor's named parameters (geoloc.sensors.frame.FrameSensor.params), by their angle in degrees
    "mount_x_deg": "sensor mount angle x (gimbal base in the body)",
    "mount_y_deg": "sensor mount angle y",
    "mount_z_deg": "sensor mount angle z",
    "boresight_x_deg": "sensor boresight angle x (camera in the last gimbal frame)",
    "boresight_y_deg": "sensor boresight angle y",
    "boresight_z_deg": "sensor boresight angle z",
    "lever_arm_x_m": "sensor lever arm x (forward, body axes)",
    "lever_arm_y_m": "sensor lever arm y (right)",
    "lever_arm_z_m": "sensor lever arm z (down)",
    # the lens's named parameters (geoloc.sensors.lenses.Lens.params), pixels or dimensionless
    "fx_px": "lens focal length along the columns fx [px]",
    "fy_px": "lens focal length along the rows fy [px]",
    "focal_length_px": "lens focal length, fx and fy together [px]",
    "cx_px": "lens principal point, column [px]",
    "cy_px": "lens principal point, row [px]",
    "skew_px": "lens skew K[0, 1] [px]",
    "k1": "lens radial distortion k1",
    "k2": "lens radial distortion k2",
    "p1": "lens tangential distortion p1",
    "p2": "lens tangential distortion p2",
    "k3": "lens radial distortion k3",
    "k4": "lens radial distortion k4 (Brown: rational denominator)",
    "k5": "lens radial distortion k5 (rational denominator)",
    "k6": "lens radial distortion k6 (rational denominator)",
}

#: Error source -> the lens parameters it moves (``Lens.params`` names; the draw adds to each).
LENS_SOURCES = {
    "fx_px": ("fx",),
    "fy_px": ("fy",),
    "focal_length_px": ("fx", "fy"),
    "cx_px": ("cx",),
    "cy_px": ("cy",),
    "skew_px": ("skew",),
    **{k: (k,) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")},
}

DISTRIBUTIONS = ("normal", "uniform")


@dataclass(frozen=True)
class Distribution:
    """One error source: ``bias + sigma * N(0, 1)`` or ``bias + U(-max, max)`` [Q17 eq. 15].

    Attributes
    ----------
    dist : {"normal", "uniform"}
    scale : float
        sigma (normal) or the half-width ``max`` (uniform), in the source's edge unit.
    bias : float
        Constant offset added to every sample (edge unit); 0 by default.
    """

    dist: str
    scale: float
    bias: float = 0.0

    @property
    def std(self) -> float:
        """Standard deviation: sigma, or max / sqrt(3) for the uniform distribution."""
        return self.scale if self.dist == "normal" else self.scale / math.sqrt(3.0)

    def draw(self, rng: np.random.Generator, shape: int | tuple[int, ...]) -> np.ndarray:
        """Samples of this error (edge unit), shape ``shape``."""
        if self.dist == "normal":
            x = rng.standard_normal(shape) * self.scale
        else:
            x = rng.uniform(-self.scale, self.scale, shape)
        return x + self.bias if self.bias else x


@dataclass(frozen=True)
class DemSpec:
    """Optional terrain of the scenario: a DEM file replacing the target height."""

    path: Path
    datum: str = "egm96"
    method: str | None = None


@dataclass(frozen=True)
class ErrorModel:
    """Nominal geometry and error distributions of a Monte Carlo scenario.

    Attributes
    ----------
    name : str
    camera : FrameSensor
        The [camera] table's sensor: a first-phase camera's keys (a pinhole, with its
        ``pixel_pitch_m``) or a sensor file's tables (a lens of any model), on the
        ``roll-pitch`` gimbal, whose two angles the [nominal] table gives.
    nominal : dict
        The [nominal] table: ``POSE_KEYS`` -> value (degrees, metres).
    target_h_m : float
        Nominal target ellipsoidal height [m].
    row, col : float
        Target pixel (1-based); the CCD centre by default.
    height_kind : str
        "inflated" [Q17 eq. 11] or "geodetic": the kind of constant-height surface the target
        is on (the file's ``[target] height_kind``; a file written before it was named so says
        ``surface``, read the same).
    errors : dict
        Source name -> :class:`Distribution`.
    dem : DemSpec or None
    sweep : dict
        The optional [sweep] table (defaults of ``geoloc montecarlo --sweep``).
    source : str
        Where the model came from (for error messages).
    corrections : Corrections
        The line-of-sight corrections every sample is located with (the file's
        ``[corrections]`` table; none by default, as [Q17]).
    """

    name: str
    camera: FrameSensor
    nominal: dict
    target_h_m: float
    row: float
    col: float
    height_kind: str = "inflated"
    errors: dict = field(default_factory=dict)
    dem: DemSpec | None = None
    sweep: dict = field(default_factory=dict)
    source: str = "error model"
    corrections: Corrections = NO_CORRECTIONS

    def __post_init__(self):
        # the one entrance for a Monte Carlo sensor: a first-phase Camera built in Python becomes
        # its FrameSensor here (frozen: object.__setattr__), so the engine holds a Sensor only
        object.__setattr__(self, "camera", _sensor(self.camera, self.source))

    # ------------------------------------------------------------ loading
    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> "ErrorModel":
        """Load a scenario file; every bad key or value raises ``ValueError`` naming it."""
        path = Path(path)
        data = read_toml(path, "scenario file")
        return cls.from_dict(data, source=str(path), base_dir=path.parent)

    @classmethod
    def from_dict(
        cls, data: dict, source: str = "error model", base_dir: str | os.PathLike[str] | None = None
    ) -> "ErrorModel":
        """Build from the parsed TOML tables (see the module docstring)."""
        allowed = {
            "name",
            "description",
            "reference",
            "camera",
            "nominal",
            "target",
            "errors",
            "dem",
            "sweep",
            "kind",
            "corrections",
        }
        _no_unknown(data, allowed, source)
        if data.get("kind", "montecarlo") != "montecarlo":  # geoloc.workflows.scenario's dispatch key
            raise ValueError(f"{source}: kind = {data['kind']!r}: this loader reads 'montecarlo' scenarios")
        for k in ("camera", "nominal", "target"):
            if k not in data:
                raise ValueError(f"{source}: missing table [{k}]")
        camera = camera_from_table(data["camera"], f"{source} [camera]")

        nom = data["nominal"]
        _no_unknown(nom, set(POSE_KEYS), f"{source} [nominal]")
        missing = [k for k in ("lat_deg", "lon_deg", "h_m") if k not in nom]
        if missing:
            raise ValueError(f"{source} [nominal]: missing key(s) {missing}")
        nominal = {k: _number(nom.get(k, 0.0), f"{source} [nominal] {k}") for k in POSE_KEYS}
        _pose_deg(nominal).validate()

        tgt = data["target"]
        _no_unknown(tgt, {"h_m", "row", "col", "height_kind", "surface"}, f"{source} [target]")
        if "h_m" not in tgt:
            raise ValueError(f"{source} [target]: missing key 'h_m' (target ellipsoidal height)")
        r0, c0 = camera.center_pixel
        row = _number(tgt.get("row", r0), f"{source} [target] row")
        col = _number(tgt.get("col", c0), f"{source} [target] col")
        if "height_kind" in tgt and "surface" in tgt:
            raise ValueError(f"{source} [target]: give height_kind, not both height_kind and surface (its older name)")
        key = "surface" if "surface" in tgt else "height_kind"  # a file of before the rename says surface
        height_kind = tgt.get(key, "inflated")
        if height_kind not in ("inflated", "geodetic"):
            raise ValueError(f"{source} [target] {key} = {height_kind!r}: must be 'inflated' or 'geodetic'")

        errors = {}
        for name, spec in data.get("errors", {}).items():
            where = f"{source} [errors] {name}"
            if name not in ERROR_SOURCES:
                raise ValueError(f"{where}: unknown error source; known: {sorted(ERROR_SOURCES)}")
            errors[name] = _distribution(spec, where)
        check_lens_sources(errors, camera, source)
        check_pixel_pitch(errors, camera, f"{source} [camera]")

        dem = None
        if "dem" in data:
            d = data["dem"]
            _no_unknown(d, {"path", "datum", "method"}, f"{source} [dem]")
            if "path" not in d:
                raise ValueError(f"{source} [dem]: missing key 'path'")
            dem = DemSpec(_resolve(d["path"], base_dir), str(d.get("datum", "egm96")), d.get("method"))
        table = data.get("corrections", {})
        if not isinstance(table, dict):
            raise ValueError(f"{source}: corrections must be a table [corrections], got {table!r}")
        corrections = corrections_from_table(camera, table, f"{source} [corrections]")
        return cls(
            str(data.get("name", Path(source).stem)),
            camera,
            nominal,
            _number(tgt["h_m"], f"{source} [target] h_m"),
            row,
            col,
            height_kind,
            errors,
            dem,
            dict(data.get("sweep", {})),
            source,
            corrections,
        )

    # ------------------------------------------------------------ use
    def with_nominal(self, **changes: float) -> "ErrorModel":
        """A copy with some nominal values changed (degrees / metres), e.g. ``gimbal_roll_deg=70``."""
        _no_unknown(changes, set(POSE_KEYS), "with_nominal")
        nominal = dict(self.nominal)
        nominal.update({k: float(v) for k, v in changes.items()})
        return _replace(self, nominal=nominal)

    def with_error(self, name: str, dist: Distribution | None) -> "ErrorModel":
        """A copy with one error source replaced (``None`` removes it)."""
        if name not in ERROR_SOURCES:
            raise ValueError(f"unknown error source {name!r}; known: {sorted(ERROR_SOURCES)}")
        errors = dict(self.errors)
        if dist is None:
            errors.pop(name, None)
        else:
            errors[name] = dist
        check_lens_sources(errors, self.camera, self.source)
        check_pixel_pitch(errors, self.camera, f"{self.source} [camera]")
        return _replace(self, errors=errors)

    def with_camera(self, camera: Any) -> "ErrorModel":
        """A copy with another camera or sensor (``geoloc montecarlo --sensor FILE``).

        The sensor must use the ``roll-pitch`` gimbal (the [nominal] table's two angles) and
        have every lens parameter the error sources name.
        """
        camera = _sensor(camera, self.source)
        check_camera(camera, self.source)
        check_lens_sources(self.errors, camera, self.source)
        check_pixel_pitch(self.errors, camera, f"{self.source}: camera {getattr(camera, 'name', '') or camera!r}")
        return _replace(self, camera=camera)

    def without_dem(self) -> "ErrorModel":
        return _replace(self, dem=None)

    def nominal_pose(self) -> Pose:
        """The nominal pose (radians)."""
        return _pose_deg(self.nominal)

    def std_si(self) -> dict:
        """Standard deviation of every error source in SI units (radians, metres)."""
        return {k: d.std * _to_si(k, self.camera) for k, d in self.errors.items()}

    def sample(self, n: int, rng: np.random.Generator) -> dict:
        """Draw ``n`` samples of every error source [Q17 eq. 15], in SI units.

        Returns
        -------
        dict
            Source name -> ndarray (n,) of errors in radians or metres (the
            image-centre errors in pixels, keys ``image_centre_x_px`` /
            ``image_centre_y_px``). Sources are drawn in a fixed order so a
            seed gives the same samples whatever the file's key order.
        """
        out = {}
        for name in ERROR_SOURCES:  # fixed order: reproducible for a seed
            d = self.errors.get(name)
            if d is None:
                continue
            key = name.replace("_um", "_px") if name.endswith("_um") else name
            out[key] = d.draw(rng, (n,)) * _to_si(name, self.camera)
        return out


def _to_si(name: str, camera) -> float:
    """Factor from a source's edge unit to SI (rad, m) or pixels (image centre, lens)."""
    if name.endswith("_deg"):
        return math.pi / 180.0
    if name.endswith("_um"):
        return 1e-6 / camera.pixel_pitch_m  # micrometres on the CCD -> pixels
    return 1.0


def check_pixel_pitch(errors: dict, camera: Any, where: str) -> None:
    """The image-centre errors in micrometres need the camera's ``pixel_pitch_m`` (a camera file's key)."""
    needs_pitch = any(errors.get(k) is not None for k in ("image_centre_x_um", "image_centre_y_um"))
    if needs_pitch and getattr(camera, "pixel_pitch_m", None) is None:
        raise ValueError(f"{where}: pixel_pitch_m is required for the image-centre error in micrometres")


def camera_from_table(table: Mapping[str, Any], where: str) -> FrameSensor:
    """The [camera] table's :class:`FrameSensor`: a camera file's keys or a sensor file's tables
    (:func:`geoloc.sensors.sensor_file.sensor_from_dict`, the one reader of both)."""
    if not isinstance(table, dict):
        raise ValueError(f"{where} = {table!r}: must be a table")
    from geoloc.sensors.sensor_file import _naming_source, sensor_from_dict

    sensor = _naming_source(where, lambda: sensor_from_dict(dict(table), source=where))
    check_camera(sensor, where)
    return sensor


def _sensor(camera, where: str) -> FrameSensor:
    """A Python caller's camera as its :class:`FrameSensor` (a first-phase
    :class:`geoloc.sensors.camera.Camera` through ``as_sensor``); ValueError naming it otherwise."""
    try:
        return as_sensor(camera)
    except ValueError:
        raise ValueError(f"{where}: camera {camera!r}: must be a Camera or a FrameSensor") from None


def check_camera(camera: Any, where: str) -> None:
    """A Monte Carlo camera: a :class:`FrameSensor` on the roll-pitch gimbal."""
    sensor = _sensor(camera, where)
    if tuple(sensor.angle_names) != ("gimbal_roll", "gimbal_pitch"):
        raise ValueError(
            f"{where}: gimbal = {sensor.gimbal.name!r}: Monte Carlo's [nominal] table gives "
            "gimbal_roll_deg and gimbal_pitch_deg, so the sensor must use the roll-pitch gimbal"
        )


def lens_params(camera: Any) -> dict:
    """The lens's named parameters (``Lens.params``, OpenCV's 0-based cx, cy) of a sensor."""
    return dict(camera.lens.params)


def check_lens_sources(errors: dict, camera: Any, where: str) -> None:
    """Every lens source must name a parameter of the camera's lens (k1 needs a distorted lens)."""
    have = lens_params(camera)
    for name in errors:
        for p in LENS_SOURCES.get(name, ()):
            if p not in have:
                model = camera.lens.model
                raise ValueError(
                    f"{where} [errors] {name}: the camera's {model} lens has no parameter {p!r} "
                    f"(its parameters: {sorted(have)}); give a [camera.lens] table with a "
                    'lens model that has it, e.g. model = "brown"'
                )


def _replace(model: ErrorModel, **kw) -> ErrorModel:
    from dataclasses import replace

    return replace(model, **kw)


def _no_unknown(table: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _number(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{where} = {v!r}: must be a finite number")
    return float(v)


def _distribution(spec, where: str) -> Distribution:
    if not isinstance(spec, dict):
        raise ValueError(f'{where} = {spec!r}: must be a table like {{{{ dist = "normal", sigma = 0.01 }}}}')
    dist = spec.get("dist")
    if dist not in DISTRIBUTIONS:
        raise ValueError(f"{where} dist = {dist!r}: must be one of {list(DISTRIBUTIONS)}")
    key = "sigma" if dist == "normal" else "max"
    _no_unknown(spec, {"dist", key, "bias"}, where)
    if key not in spec:
        raise ValueError(f"{where}: a {dist} error needs '{key}'")
    scale = _number(spec[key], f"{where} {key}")
    if scale < 0:
        raise ValueError(f"{where} {key} = {scale!r}: must be >= 0")
    return Distribution(dist, scale, _number(spec.get("bias", 0.0), f"{where} bias"))


def _resolve(p, base_dir) -> Path:
    """A DEM path: absolute, relative to the scenario file, or relative to assets/."""
    from geoloc.assets import ASSETS

    p = Path(str(p))
    if p.is_absolute():
        return p
    for base in ([Path(base_dir)] if base_dir is not None else []) + [ASSETS]:
        if (base / p).exists():
            return base / p
    return (Path(base_dir) / p) if base_dir is not None else p
