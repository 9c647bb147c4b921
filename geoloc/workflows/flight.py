"""Simulated flight: an aircraft track with a whisk-broom gimbal scan (a scenario file).

The scan of [Q17] section 3 (Fig. 10): the outer gimbal ("frame") angle sweeps
back and forth between two limits (10-82 deg in the paper's CEP study) while
the aircraft flies a straight line at constant ellipsoidal height. Every time
step gives one :class:`geoloc.frames.chain.Pose`; the whole flight is one batched
Pose, so the core geolocates all steps in one call.

Scenario file (TOML, degrees and metres at this edge; e.g.
``assets/scenarios/flight_scan.toml``)::

    name = "..."
    camera = "../cameras/qiao2017.toml"      # relative to the scenario file
    [aircraft]
    start_lat_deg = 35.48                   # geodetic, start of the track
    start_lon_deg = 80.97
    h_m = 18000.0                           # constant ellipsoidal height
    heading_deg = 45.0                      # initial azimuth of the geodesic track
    speed_m_s = 200.0                       # ground speed along the geodesic
    pitch_deg = 3.5
    roll_deg = 0.0
    roll_amplitude_deg = 0.0                # optional sinusoidal roll (turbulence)
    roll_period_s = 10.0
    [time]
    duration_s = 60.0
    rate_hz = 4.0                           # steps at t_k = k / rate_hz, k = 0 .. floor(duration * rate)
    [scan]
    outer_min_deg = 10.0                    # outer gimbal (frame) angle limits, magnitude
    outer_max_deg = 82.0
    period_s = 20.0                         # one sweep out and back
    side = "left"                           # "left": gimbal_roll > 0; "right": < 0 (conventions)
    inner_deg = -2.6                        # inner gimbal (pitch), constant
    [terrain]
    target_h_m = 5083.0                     # ellipsoid inflated to this height [Q17 eq. 11]
    dem = "../dem/....tif"                  # optional DEM (see geoloc.surfaces.terrain)
    dem_datum = "egm96"                     # or "ellipsoid"
    method = "steps"                        # DEM method for the located point
    eps_h_m = 10.0                          # step of the descending method
    threshold_m = 10.0                      # threshold of the bisection
    [montecarlo]                            # optional: CEP of every step [Q17 eq. 14-18]
    error_model = "qiao2017_table1.toml"    # error sources of geoloc.analysis.errormodel (its nominal is replaced)
    samples = 200
    seed = 7

The track is a geodesic on WGS-84 (pyproj's Karney solver, as in
:mod:`geoloc.workflows.replay`); the heading at each step is the geodesic's forward
azimuth there, so the nose follows the track. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import Geod

from geoloc.frames.chain import Pose
from geoloc.tomlio import read_toml

if TYPE_CHECKING:
    from geoloc.analysis.errormodel import ErrorModel

_GEOD = Geod(ellps="WGS84")

#: Terrain methods accepted in a scenario file (``ellipsoid`` = constant target height).
METHODS = ("ellipsoid", "steps", "bisect", "exact")


@dataclass(frozen=True)
class FlightScenario:
    """A simulated flight with a whisk-broom scan (fields in the units of the scenario file).

    Attributes
    ----------
    name : str
    camera_path : Path or None
        Camera TOML (None: the bundled [Q17] camera).
    start_lat_deg, start_lon_deg, h_m, heading_deg, speed_m_s : float
        Start of the geodesic track, its constant ellipsoidal height, initial azimuth, ground speed.
    pitch_deg, roll_deg, roll_amplitude_deg, roll_period_s : float
        Attitude: constant pitch; roll = roll_deg + roll_amplitude_deg sin(2 pi t / roll_period_s).
    duration_s, rate_hz : float
        Time steps t_k = k / rate_hz for k = 0 .. floor(duration_s rate_hz).
    outer_min_deg, outer_max_deg, scan_period_s : float
        Whisk-broom sweep of the outer gimbal between the two magnitudes (see :func:`whisk_broom`).
    side : str
        "left" (gimbal roll > 0, line of sight left of track) or "right".
    inner_deg : float
        Inner gimbal (pitch) angle, constant.
    target_h_m : float or None
        Target height of the ellipsoid model [Q17 eq. 11].
    dem_path : Path or None
    dem_datum : str
    method : str
        One of :data:`METHODS`.
    eps_h_m, threshold_m : float
        Step of the descending method and threshold of the bisection [m].
    row, col : float or None
        Pixel (1-based) of the line of sight; None = the CCD centre.
    """

    name: str
    camera_path: Path | None
    start_lat_deg: float
    start_lon_deg: float
    h_m: float
    heading_deg: float
    speed_m_s: float
    pitch_deg: float
    roll_deg: float
    roll_amplitude_deg: float
    roll_period_s: float
    duration_s: float
    rate_hz: float
    outer_min_deg: float
    outer_max_deg: float
    scan_period_s: float
    side: str
    inner_deg: float
    target_h_m: float | None
    dem_path: Path | None
    dem_datum: str
    method: str
    eps_h_m: float
    threshold_m: float
    row: float | None = None
    col: float | None = None
    mc_model_path: Path | None = None
    mc_samples: int = 0
    mc_seed: int = 0

    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> "FlightScenario":
        """Load and validate a scenario file; errors name the key and the value."""
        path = Path(path)
        data = read_toml(path, "scenario file")
        return cls.from_dict(data, base=path.parent, source=str(path))

    @classmethod
    def from_dict(
        cls, data: dict[str, Any], base: str | os.PathLike[str] = Path("."), source: str = "scenario"
    ) -> "FlightScenario":
        base = Path(base)
        top = {"name", "camera", "aircraft", "time", "scan", "terrain", "pixel", "kind", "montecarlo"}
        _no_unknown(data, top, source)
        kind = data.get("kind", "flight_scan")
        if kind != "flight_scan":
            raise ValueError(f"{source}: kind = {kind!r}: this loader reads 'flight_scan' scenarios")
        ac = _table(data, "aircraft", source)
        tm = _table(data, "time", source)
        sc = _table(data, "scan", source)
        te = data.get("terrain", {})
        px = data.get("pixel", {})
        mc = data.get("montecarlo", {})
        _no_unknown(mc, {"error_model", "samples", "seed"}, f"{source} [montecarlo]")
        if mc and "error_model" not in mc:
            raise ValueError(f"{source} [montecarlo] error_model: missing")
        for key, lo, hi in (("samples", 2, 1_000_000), ("seed", 0, 2**63 - 1)):
            v = mc.get(key, 200 if key == "samples" else 0)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"{source} [montecarlo] {key} = {v!r}: must be an integer in [{lo}, {hi}]")
        _no_unknown(
            ac,
            {
                "start_lat_deg",
                "start_lon_deg",
                "h_m",
                "heading_deg",
                "speed_m_s",
                "pitch_deg",
                "roll_deg",
                "roll_amplitude_deg",
                "roll_period_s",
            },
            f"{source} [aircraft]",
        )
        _no_unknown(tm, {"duration_s", "rate_hz"}, f"{source} [time]")
        _no_unknown(sc, {"outer_min_deg", "outer_max_deg", "period_s", "side", "inner_deg"}, f"{source} [scan]")
        _no_unknown(te, {"target_h_m", "dem", "dem_datum", "method", "eps_h_m", "threshold_m"}, f"{source} [terrain]")
        _no_unknown(px, {"row", "col"}, f"{source} [pixel]")

        def num(tab, key, lo, hi, default=None, section=""):
            where = f"{source} [{section}] {key}"
            if key not in tab:
                if default is None:
                    raise ValueError(f"{where}: missing")
                return float(default)
            v = tab[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{where} = {v!r}: must be a finite number")
            if not lo <= v <= hi:
                raise ValueError(f"{where} = {v!r}: out of range [{lo:g}, {hi:g}]")
            return float(v)

        side = sc.get("side", "left")
        if side not in ("left", "right"):
            raise ValueError(f"{source} [scan] side = {side!r}: must be 'left' or 'right'")
        method = te.get("method", "ellipsoid" if "dem" not in te else "steps")
        if method not in METHODS:
            raise ValueError(f"{source} [terrain] method = {method!r}: must be one of {METHODS}")
        datum = te.get("dem_datum", "egm96")
        if datum not in ("egm96", "ellipsoid"):
            raise ValueError(f"{source} [terrain] dem_datum = {datum!r}: must be 'egm96' or 'ellipsoid'")
        target_h = num(te, "target_h_m", -1.2e4, 1e5, None, "terrain") if "target_h_m" in te else None
        # paths must be text (fuzzing found camera = nan raised "unsupported operand type(s) for /")
        for key, v in (("camera", data.get("camera")), ("[terrain] dem", te.get("dem"))):
            if v is not None and not isinstance(v, str):
                raise ValueError(f"{source} {key} = {v!r}: must be the path of a file (a string)")
        dem = (base / te["dem"]) if "dem" in te else None
        if dem is None and target_h is None:
            raise ValueError(f"{source} [terrain]: give target_h_m (ellipsoid model) or dem")
        if method != "ellipsoid" and dem is None:
            raise ValueError(f"{source} [terrain] method = {method!r} needs a dem")
        if method == "ellipsoid" and target_h is None:  # a dem alone is the truth, not the located surface
            raise ValueError(f"{source} [terrain] method = 'ellipsoid' needs target_h_m")
        cam = data.get("camera")
        scn = cls(
            name=str(data.get("name", Path(source).stem)),
            camera_path=(base / cam) if cam else None,
            start_lat_deg=num(ac, "start_lat_deg", -89.0, 89.0, section="aircraft"),
            start_lon_deg=num(ac, "start_lon_deg", -180.0, 360.0, section="aircraft"),
            h_m=num(ac, "h_m", -1.2e4, 1e6, section="aircraft"),
            heading_deg=num(ac, "heading_deg", -360.0, 360.0, section="aircraft"),
            speed_m_s=num(ac, "speed_m_s", 0.0, 1e4, section="aircraft"),
            pitch_deg=num(ac, "pitch_deg", -89.0, 89.0, 0.0, "aircraft"),
            roll_deg=num(ac, "roll_deg", -89.0, 89.0, 0.0, "aircraft"),
            roll_amplitude_deg=num(ac, "roll_amplitude_deg", 0.0, 45.0, 0.0, "aircraft"),
            roll_period_s=num(ac, "roll_period_s", 1e-3, 1e6, 10.0, "aircraft"),
            duration_s=num(tm, "duration_s", 0.0, 1e6, section="time"),
            rate_hz=num(tm, "rate_hz", 1e-6, 1e4, section="time"),
            outer_min_deg=num(sc, "outer_min_deg", 0.0, 179.0, section="scan"),
            outer_max_deg=num(sc, "outer_max_deg", 0.0, 179.0, section="scan"),
            scan_period_s=num(sc, "period_s", 1e-3, 1e6, section="scan"),
            side=side,
            inner_deg=num(sc, "inner_deg", -90.0, 90.0, 0.0, "scan"),
            target_h_m=target_h,
            dem_path=dem,
            dem_datum=datum,
            method=method,
            eps_h_m=num(te, "eps_h_m", 1e-3, 1e4, 10.0, "terrain"),
            threshold_m=num(te, "threshold_m", 1e-4, 1e4, 10.0, "terrain"),
            row=num(px, "row", -1e7, 1e7, section="pixel") if "row" in px else None,
            col=num(px, "col", -1e7, 1e7, section="pixel") if "col" in px else None,
            mc_model_path=(base / mc["error_model"]) if mc else None,
            mc_samples=int(mc.get("samples", 200)) if mc else 0,
            mc_seed=int(mc.get("seed", 0)) if mc else 0,
        )
        if scn.outer_max_deg < scn.outer_min_deg:
            raise ValueError(
                f"{source} [scan] outer_max_deg = {scn.outer_max_deg!r}: below outer_min_deg = {scn.outer_min_deg!r}"
            )
        n = scn.n_steps
        if n > 1_000_000:
            raise ValueError(f"{source} [time]: duration_s x rate_hz gives {n} steps (limit 1 000 000)")
        return scn

    @property
    def n_steps(self) -> int:
        """Number of time steps: floor(duration_s rate_hz) + 1."""
        return int(math.floor(self.duration_s * self.rate_hz + 1e-9)) + 1


def _table(data, key, source):
    tab = data.get(key)
    if not isinstance(tab, dict):
        raise ValueError(f"{source}: missing table [{key}]")
    return tab


def _no_unknown(tab, allowed, source):
    unknown = sorted(set(tab) - set(allowed))
    if unknown:
        raise ValueError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def whisk_broom(t: ArrayLike, lo: float, hi: float, period: float) -> NDArray[np.float64]:
    """Outer gimbal magnitude of a whisk-broom scan: a triangle wave between ``lo`` and ``hi``.

    a(t) = lo + (hi - lo) (1 - |2 frac(t / period) - 1|): ``lo`` at t = 0, ``hi`` at
    half a period, back to ``lo`` after a full period (constant angular rate
    2 (hi - lo) / period). Units of ``lo`` and ``hi`` are kept (radians inside).

    Parameters
    ----------
    t : array_like
        Time [s].
    lo, hi : float
        Angle limits (magnitudes).
    period : float
        One sweep out and back [s].
    """
    t = np.asarray(t, float)
    phase = np.mod(t / period, 1.0)
    return lo + (hi - lo) * (1.0 - np.abs(2.0 * phase - 1.0))


@dataclass(frozen=True)
class FlightTrack:
    """The simulated flight: time of each step and the batched pose.

    Attributes
    ----------
    t : ndarray (n,)
        Time of each step [s], t_k = k / rate_hz.
    pose : Pose
        Batched pose (radians, metres), one entry per step.
    """

    t: np.ndarray
    pose: Pose

    def __len__(self) -> int:
        return len(self.t)


def simulate(scn: FlightScenario) -> FlightTrack:
    """Positions, attitude and gimbal angles of every time step of a scenario.

    Position: the geodesic from the start point with the initial azimuth
    ``heading_deg``, at distance ``speed_m_s t`` (pyproj ``Geod.fwd`` on
    WGS-84), at constant ellipsoidal height ``h_m``. Heading: the geodesic's
    forward azimuth at that point. Gimbal roll: :func:`whisk_broom`, positive
    for ``side = "left"`` (docs/conventions.md: positive gimbal roll looks left).

    Returns
    -------
    FlightTrack
    """
    n = scn.n_steps
    t = np.arange(n, dtype=float) / scn.rate_hz
    lon, lat, back_az = _GEOD.fwd(
        np.full(n, scn.start_lon_deg), np.full(n, scn.start_lat_deg), np.full(n, scn.heading_deg), scn.speed_m_s * t
    )
    lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    heading = np.mod(np.asarray(back_az, float) + 180.0 + 180.0, 360.0) - 180.0  # (-180, 180]
    roll = scn.roll_deg + scn.roll_amplitude_deg * np.sin(2 * np.pi * t / scn.roll_period_s)
    sign = 1.0 if scn.side == "left" else -1.0
    outer = sign * whisk_broom(t, scn.outer_min_deg, scn.outer_max_deg, scn.scan_period_s)
    pose = Pose.from_deg(
        lat, lon, np.full(n, scn.h_m), heading, np.full(n, scn.pitch_deg), roll, outer, np.full(n, scn.inner_deg)
    )
    return FlightTrack(t, pose)


def step_cep(
    track: FlightTrack, model: ErrorModel, target_h_m: float, n: int, rng: np.random.Generator
) -> dict[str, NDArray[np.float64]]:
    """Monte Carlo CEP of every step: [Q17 eq. 14-18] with the step's pose as the nominal.

    For each step the error model's nominal pose is replaced by the step's
    (degrees at the model's edge), its target height by ``target_h_m`` (ellipsoid
    model, with the model's own target-height error), its DEM removed, and
    ``n`` samples are located by :func:`geoloc.analysis.montecarlo.run` (one vectorised
    batch per step).

    Parameters
    ----------
    track : FlightTrack
    model : geoloc.analysis.errormodel.ErrorModel
        Error sources (e.g. ``assets/scenarios/qiao2017_table1.toml``).
    target_h_m : float
    n : int
        Samples per step.
    rng : numpy.random.Generator

    Returns
    -------
    dict
        ``cep_m`` ([Q17 eq. 18]) and ``cep50_empirical_m``, arrays (n_steps,).
    """
    from dataclasses import replace

    from geoloc.analysis.montecarlo import run

    p = track.pose
    d = np.rad2deg
    fields_deg = {
        "lat_deg": d(p.lat),
        "lon_deg": d(p.lon),
        "h_m": p.h,
        "heading_deg": d(p.heading),
        "pitch_deg": d(p.pitch),
        "roll_deg": d(p.roll),
        "gimbal_roll_deg": d(p.gimbal_roll),
        "gimbal_pitch_deg": d(p.gimbal_pitch),
    }
    m = len(track)
    arrays = {k: np.broadcast_to(np.asarray(v, float), (m,)) for k, v in fields_deg.items()}
    base = replace(model.without_dem(), target_h_m=float(target_h_m))
    cep = np.full(m, np.nan)
    cep50 = np.full(m, np.nan)
    for k in range(m):
        mk = base.with_nominal(**{name: a[k] for name, a in arrays.items()})
        st = run(mk, n, rng).stats
        cep[k], cep50[k] = st["cep_m"], st["cep50_empirical_m"]
    return {"cep_m": cep, "cep50_empirical_m": cep50}
