"""Limb-sounding scenarios: a circular orbit, an attitude and a slit of view angles [L18].

Conventions: ``docs/conventions.md``; the file format is documented in
``docs/limb.md`` and exemplified by ``assets/scenarios/tiangong2_limb.toml``.

The orbit is a circular Keplerian orbit (no J2, no drag): the scenario is a
geometry generator for the [L18] chain, not an ephemeris. Inertial -> ECEF is
a rotation about Z by the Greenwich angle theta_g = theta_g0 + omega_E t
(no precession, nutation or polar motion), so ``r_ecef = rz(theta_g) r_eci``
(passive rz, ``geoloc.frames.rotations``) and ``v_ecef = rz(theta_g) (v_eci - omega x r_eci)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geoloc.corrections import check_table
from geoloc.corrections.lighttime import aberration, inertial_velocity
from geoloc.frames.rotations import rotate, rz
from geoloc.geodesy.ellipsoid import A
from geoloc.sensors.limb import L18Chain, LimbTangent, limb_tangent, line_of_sight_l18
from geoloc.tomlio import read_toml

#: Earth's gravitational parameter GM [m^3/s^2] (WGS-84).
GM = 3.986004418e14
#: Earth's rotation rate omega_E [rad/s] (WGS-84).
OMEGA_E = 7.292115e-5


@dataclass(frozen=True)
class LimbScenario:
    """A limb-sounding geometry: orbit, attitude, sensor mounting and slit.

    Angles are radians, lengths metres, times seconds (the TOML file uses
    ``_deg`` fields). See ``docs/limb.md`` for the file format.

    Attributes
    ----------
    name : str
    altitude : float
        Orbit radius minus the WGS-84 semi-major axis a [m].
    inclination, raan, arg_latitude0, greenwich0 : float
        Inclination, right ascension of the ascending node, argument of
        latitude at t = 0 and Greenwich angle at t = 0 [rad].
    n_frames : int
    interval : float
        Time between frames [s].
    yaw, roll, pitch : float
        Platform attitude in the [L18] orbital frame [rad] (eq. 3-6).
    theta_mount : float
        Sensor mounting angle about body X [rad] (eq. 2).
    fov : float
        Slit field of view [rad]; the pixels' alpha are evenly spread over
        [-fov/2, +fov/2] at pixel centres (eq. 1).
    n_pixels : int
    source : str
        Where the scenario was read from (for messages).
    aberration : bool
        Aberration of light by the orbit's velocity applied to the lines of sight (on by
        default, as for every spaceborne sensor; the file's ``[corrections]`` table: the
        bundled [L18] scenario turns it off, as the paper neglects it).
    refraction : str
        ``"none"`` or ``"standard"``: the refracted tangent points too (``geoloc limb``).
    """

    name: str
    altitude: float
    inclination: float
    raan: float
    arg_latitude0: float
    greenwich0: float
    n_frames: int
    interval: float
    yaw: float
    roll: float
    pitch: float
    theta_mount: float
    fov: float
    n_pixels: int
    source: str = "scenario"
    aberration: bool = True
    refraction: str = "none"

    def __post_init__(self):
        def bad(field, value, why):
            key = _KEY.get(field, field)
            if key.endswith("_deg") and field in _KEY and isinstance(value, float):
                value = math.degrees(value)
            raise ValueError(f"{self.source}: {key} = {value!r} {why}")

        for field in (
            "altitude",
            "inclination",
            "raan",
            "arg_latitude0",
            "greenwich0",
            "interval",
            "yaw",
            "roll",
            "pitch",
            "theta_mount",
            "fov",
        ):
            v = getattr(self, field)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                bad(field, v, "must be a finite number")
        if self.altitude <= 0:
            bad("altitude", self.altitude, "must be > 0")
        if not (0 <= self.inclination <= math.pi):
            bad("inclination", self.inclination, "must be within [0, 180]")
        if not (0 < self.fov < math.pi):
            bad("fov", self.fov, "must be within (0, 180)")
        for field in ("n_frames", "n_pixels"):
            v = getattr(self, field)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                bad(field, v, "must be an integer >= 1")
        if self.interval < 0:
            bad("interval", self.interval, "must be >= 0")

    # ---- derived geometry -------------------------------------------------
    @property
    def radius(self) -> float:
        """Orbit radius a + altitude [m]."""
        return A + self.altitude

    @property
    def mean_motion(self) -> float:
        """n = sqrt(GM / r^3) [rad/s]."""
        return math.sqrt(GM / self.radius**3)

    def times(self) -> np.ndarray:
        """Frame times [s], shape (n_frames,)."""
        return np.arange(self.n_frames) * self.interval

    def alphas(self) -> np.ndarray:
        """Pixel view angles alpha [rad] (eq. 1), shape (n_pixels,), increasing (upwards)."""
        k = (np.arange(self.n_pixels) + 0.5) / self.n_pixels - 0.5
        return k * self.fov

    def state_ecef(self, t: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position [m] and velocity [m/s] in ECEF at times t (default: the frames).

        Returns
        -------
        position, velocity : ndarray (..., 3)
        """
        t = self.times() if t is None else np.asarray(t, float)
        r, n = self.radius, self.mean_motion
        u = self.arg_latitude0 + n * t
        ci, si = math.cos(self.inclination), math.sin(self.inclination)
        cO, sO = math.cos(self.raan), math.sin(self.raan)
        cu, su = np.cos(u), np.sin(u)
        r_eci = r * np.stack([cO * cu - sO * su * ci, sO * cu + cO * su * ci, su * si], axis=-1)
        v_eci = r * n * np.stack([-cO * su - sO * cu * ci, -sO * su + cO * cu * ci, cu * si], axis=-1)
        omega = np.array([0.0, 0.0, OMEGA_E])
        R = rz(self.greenwich0 + OMEGA_E * t)
        return rotate(R, r_eci), rotate(R, v_eci - np.cross(omega, r_eci))

    def lines_of_sight(self) -> L18Chain:
        """The [L18] chain for every frame and pixel, shape (n_frames, n_pixels); with
        :attr:`aberration`, its directions are the light's (the apparent line of sight of the
        chain turned back by the orbit's inertial velocity: :func:`geoloc.corrections.lighttime.aberration`)."""
        p, v = self.state_ecef()
        chain = line_of_sight_l18(
            p[:, None, :], v[:, None, :], self.yaw, self.roll, self.pitch, self.theta_mount, self.alphas()[None, :]
        )
        if not self.aberration:
            return chain

        d = aberration(chain.direction_ecef, inertial_velocity(p[:, None, :], v[:, None, :]))
        return replace(chain, direction_ecef=np.where(np.isfinite(chain.direction_ecef), d, np.nan))

    def solve(self, **kwargs: Any) -> tuple[L18Chain, LimbTangent]:
        """Lines of sight and their tangents (keyword arguments go to :func:`geoloc.sensors.limb.limb_tangent`)."""
        chain = self.lines_of_sight()
        return chain, limb_tangent(chain.origin_ecef, chain.direction_ecef, **kwargs)

    def with_frames(self, n_frames: int, interval: float | None = None) -> "LimbScenario":
        """A copy with another number of frames (and optionally interval)."""

        return replace(self, n_frames=n_frames, interval=self.interval if interval is None else interval)


_FIELDS = {
    # toml section, key, attribute, degrees?, required?
    ("orbit", "altitude_m"): ("altitude", False, True),
    ("orbit", "inclination_deg"): ("inclination", True, True),
    ("orbit", "raan_deg"): ("raan", True, False),
    ("orbit", "arg_latitude0_deg"): ("arg_latitude0", True, False),
    ("orbit", "greenwich0_deg"): ("greenwich0", True, False),
    ("frames", "n"): ("n_frames", False, True),
    ("frames", "interval_s"): ("interval", False, True),
    ("attitude", "yaw_deg"): ("yaw", True, False),
    ("attitude", "roll_deg"): ("roll", True, False),
    ("attitude", "pitch_deg"): ("pitch", True, False),
    ("sensor", "theta_mount_deg"): ("theta_mount", True, True),
    ("sensor", "fov_deg"): ("fov", True, True),
    ("sensor", "n_pixels"): ("n_pixels", False, True),
}


#: attribute -> "section.key" of the TOML file, for error messages.
_KEY = {attr: f"{sec}.{key}" for (sec, key), (attr, _, _) in _FIELDS.items()}


def scenario_from_dict(data: dict, source: str = "scenario") -> LimbScenario:
    """Build a :class:`LimbScenario` from the parsed TOML (errors name the field and value)."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a table, got {data!r}")
    known_sections = {s for s, _ in _FIELDS}
    for key, val in data.items():
        if key in ("name", "description", "corrections"):
            continue
        if key == "kind":  # geoloc.workflows.scenario.load_scenario's dispatch key
            if val != "limb":
                raise ValueError(f"{source}: kind = {val!r}: this loader reads 'limb' scenarios")
            continue
        if key not in known_sections:
            raise ValueError(f"{source}: unknown section or key {key!r}")
        for sub in val:
            if (key, sub) not in _FIELDS:
                raise ValueError(f"{source}: unknown key {key}.{sub}")
    kw = {}
    table = check_table(data.get("corrections", {}), f"{source} [corrections]")
    if "light_time" in table:
        raise ValueError(
            f"{source} [corrections]: light_time does not apply to a limb scenario (no ground "
            "point: the tangent point's height does not change)"
        )
    kw["aberration"] = table.get("aberration", True)
    kw["refraction"] = table.get("refraction", "none")
    for (section, key), (attr, deg, required) in _FIELDS.items():
        sec = data.get(section, {})
        if key not in sec:
            if required:
                raise ValueError(f"{source}: missing {section}.{key}")
            kw[attr] = 0.0
            continue
        v = sec[key]
        if attr in ("n_frames", "n_pixels"):
            kw[attr] = v
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{source}: {section}.{key} = {v!r} must be a number")
        kw[attr] = math.radians(v) if deg else float(v)
    return LimbScenario(name=str(data.get("name", source)), source=source, **kw)


def load_limb_scenario(path: str | os.PathLike[str]) -> LimbScenario:
    """Read a limb scenario TOML file (e.g. ``assets/scenarios/tiangong2_limb.toml``).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Naming the field and value when the content is invalid.
    """
    path = Path(path)
    data = read_toml(path, "scenario file")
    return scenario_from_dict(data, source=str(path))
