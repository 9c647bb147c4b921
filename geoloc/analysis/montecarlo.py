"""Monte Carlo error analysis of direct geolocation [Q17 section 3, eq. 14-18].

Each sample perturbs every measured quantity of an :class:`~geoloc.analysis.errormodel.ErrorModel`
(Delta x_k = R_i sigma_k, [Q17 eq. 15]) and locates the target through the core
chain, all samples in one vectorised call (no Python loop per sample):

* aircraft position / attitude and gimbal encoders -> the fields of a batched
  :class:`geoloc.frames.chain.Pose`;
* shock-absorber vibration (yaw, pitch, roll) -> ``R_base_body = Rx(roll) Ry(pitch) Rz(yaw)``
  between the aircraft body and the gimbal base (same z-y-x order as [Q17 eq. 6]);
* gimbal non-orthogonality delta: the inner (pitch) axis tilted by delta about the
  outer gimbal's Z, so the inner gimbal is ``Ry(theta_pitch) Rz(delta)`` instead of
  ``Ry(theta_pitch)``; written after the gimbals as
  ``Ry(theta_pitch) Rz(delta) Ry(theta_pitch)^T``;
* collimation epsilon: the line of sight turned by ``Rx(epsilon)`` in the camera
  frame (it leaves the plane normal to the inner axis);
  both make ``R_cam_inner`` of :class:`geoloc.frames.chain.FrameChain`;
* image-centre error: a pixel offset (micrometres / pixel pitch) on row and column;
* the sensor's named parameters: mount, boresight and lever arm (per-sample rotations and
  offsets of :class:`geoloc.sensors.frame.FrameSensor`), and the lens's (``fx_px``,
  ``cx_px``, ``k1``, ...: a lens whose parameters are per-sample arrays,
  :meth:`geoloc.sensors.lenses.Lens.with_params`, broadcasting over the chunk);
* target height: the nominal height plus the terrain error, or a DEM.

Statistics: mean and standard deviation of latitude, longitude and height, the
paper's CEP [Q17 eq. 18] and the empirical 50 % radius (see :func:`statistics`
and ``docs/montecarlo.md`` for why they differ), and a first-order propagation
(the Jacobian of the chain) to check them. Samples are drawn and located one
chunk at a time around :func:`evaluate`; beyond one chunk the statistics are
streamed (:mod:`geoloc.analysis.streaming`), so any N runs in constant memory.

Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geoloc.analysis.errormodel import LENS_SOURCES, POSE_KEYS, ErrorModel
from geoloc.analysis.streaming import STATS_KEYS, StreamingStats, cep_eq18, summary
from geoloc.frames import rotations as rot
from geoloc.frames.chain import FrameChain, Pose
from geoloc.geodesy.ellipsoid import (
    meridian_radius,
    prime_vertical_radius,
)
from geoloc.pipeline import Pipeline
from geoloc.progress import Progress
from geoloc.sensors.frame import small_rotation
from geoloc.sensors.lenses import Lens
from geoloc.status import Status
from geoloc.surfaces.base import Surface
from geoloc.userfiles import atomic_path

# STATS_KEYS (imported above, defined beside the streamed statistics): the keys of
# ``geoloc montecarlo --out stats.json`` (an interface other tools read).

_POSE_ERR = {k: k for k in POSE_KEYS}  # error source -> nominal key (same names)

#: Default chunk of samples evaluated at once (memory: ~1.5 kB per sample in flight);
#: runs and sweeps larger than a chunk stream their statistics (constant memory).
CHUNK = 100_000
#: Bytes one sample in flight may take, the bound the chunk cap divides by. Measured:
#: 744 B/sample peak traced by ``tracemalloc`` on the [Q17] Table 1 scenario and 720 B on its DEM
#: variant (chunks of 5e4 and 2e5), and 727 B/sample of peak RSS between ``--chunk 1e4`` and
#: ``--chunk 1e6`` on the DEM scenario (310 MB -> 1013 MB); 2 kB leaves room for lens and
#: sensor parameters perturbed per sample (a few more (n,) float64 arrays each).
BYTES_PER_SAMPLE = 2000
#: Share of the available memory one chunk may take (the rest: the interpreter, the DEM, the
#: other processes of a shared machine).
CHUNK_MEMORY_SHARE = 0.5
#: Largest number of samples a run takes: at the ~1e5 samples/s measured on one core here,
#: 1e12 samples run for about four months; beyond that no run ends (and ``--samples 1e20`` is a typo).
MAX_SAMPLES = 10**12


def available_memory_bytes() -> int:
    """The memory a new allocation can take without swapping: Linux's ``MemAvailable``
    (``/proc/meminfo``), else the free physical pages (``os.sysconf``), else 4 GiB."""
    import os

    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return 4 << 30


def max_chunk(available_bytes: int | None = None) -> int:
    """The largest chunk this machine holds: ``CHUNK_MEMORY_SHARE`` of the available memory
    (:func:`available_memory_bytes`) over ``BYTES_PER_SAMPLE``, and never below ``CHUNK``'s
    tenth (so a busy machine still runs the default's order of chunk)."""
    avail = available_memory_bytes() if available_bytes is None else int(available_bytes)
    return max(int(CHUNK_MEMORY_SHARE * avail // BYTES_PER_SAMPLE), CHUNK // 10)


def check_samples_and_chunk(
    n: int, chunk: int, *, field_n: str = "samples", field_chunk: str = "chunk"
) -> tuple[int, int]:
    """``(n, chunk)`` as ints, or ValueError naming the field and the value: ``n`` in
    2..``MAX_SAMPLES``, ``chunk`` in 1..:func:`max_chunk` (the memory bound:
    ``--chunk 1e8`` once grew to 7.2 GB and died)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"{field_n} = {n!r}: must be an integer >= 2")
    if n > MAX_SAMPLES:
        raise ValueError(
            f"{field_n} = {n:.3g}: more than {MAX_SAMPLES:.0e} samples is refused (at about "
            f"1e5 samples a second that run would take {n / 1e5 / 86400 / 365.25:.3g} years)"
        )
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"{field_chunk} = {chunk!r}: must be an integer >= 1")
    cap = max_chunk()
    if chunk > cap:
        raise ValueError(
            f"{field_chunk} = {chunk}: a chunk that size needs about "
            f"{chunk * BYTES_PER_SAMPLE / 1e9:.3g} GB ({BYTES_PER_SAMPLE} bytes a sample), "
            f"more than {CHUNK_MEMORY_SHARE:.0%} of the {available_memory_bytes() / 1e9:.3g} GB "
            f"available; at most {cap} here (the samples stream through the chunks, so a smaller "
            f"chunk streams the same samples' statistics in constant memory)"
        )
    return int(n), int(chunk)


# --------------------------------------------------------------------- evaluation
def perturbed_geometry(
    model: ErrorModel, errors: dict, build_chain: bool = True, with_camera: bool = True
) -> tuple[Pose, Any, np.ndarray, np.ndarray]:
    """Pose, chain and pixel of a batch of perturbed samples.

    Parameters
    ----------
    model : ErrorModel
    errors : dict
        Source name -> ndarray (n,) in SI units (as :meth:`ErrorModel.sample`);
        missing sources are zero.

    Returns
    -------
    pose : Pose
    chain : FrameChain
        (with ``build_chain=False``: the pair ``(R_cam_inner, R_base_body)``,
        either may be None; ``with_camera=False`` leaves out the camera file's own
        boresight and mount, which the sensor applies itself)
    row, col : ndarray
        Target pixel including the image-centre error.
    """
    n = _batch_len(errors)
    nom = model.nominal_pose()
    # Pose's array fields by name; Any, as the checker would hold each against every field of Pose
    # (its joint angles are a dict, not drawn here)
    vals: dict[str, Any] = {}
    for k in POSE_KEYS:
        base = getattr(nom, _field(k))
        e = errors.get(k)
        vals[_field(k)] = base + e if e is not None else np.broadcast_to(base, (n,))
    pose = Pose(**vals)

    R_base_body = None
    vy, vp, vr = (errors.get(f"vibration_{a}_deg") for a in ("yaw", "pitch", "roll"))
    if vy is not None or vp is not None or vr is not None:
        z = np.zeros(n)
        R_base_body = rot.rx(_or(vr, z)) @ rot.ry(_or(vp, z)) @ rot.rz(_or(vy, z))

    R_cam_inner = None
    delta = errors.get("gimbal_nonorthogonality_deg")
    eps = errors.get("collimation_deg")
    if delta is not None:
        Ry = rot.ry(pose.gimbal_pitch)
        R_cam_inner = Ry @ rot.rz(delta) @ np.swapaxes(Ry, -1, -2)
    if eps is not None:
        R_eps = rot.rx(eps)
        R_cam_inner = R_eps if R_cam_inner is None else R_eps @ R_cam_inner

    # the sensor's named mount / boresight parameters: the sample's angles are the file's plus
    # the draw (exact: the drawn rotation replaces the file's)
    sensor = model.camera
    drawn = {}
    for which in ("mount", "boresight"):
        draws = [errors.get(f"{which}_{a}_deg") for a in "xyz"]
        if any(d is not None for d in draws):
            base = getattr(sensor, which)
            drawn[which] = small_rotation(tuple(b + _or(d, np.zeros(n)) for b, d in zip(base, draws)))
    R_m_file, R_b_file = small_rotation(sensor.mount), small_rotation(sensor.boresight)
    if with_camera:
        # v_cam = R_err_inner @ R_boresight @ v_inner, v_base = R_mount @ R_vib @ v_body
        Rb = drawn.get("boresight", R_b_file)
        Rm = drawn.get("mount", R_m_file)
        R_cam_inner = Rb if R_cam_inner is None else R_cam_inner @ Rb
        R_base_body = Rm if R_base_body is None else Rm @ R_base_body
    else:
        # the sensor applies its file's rotations itself: hand it what makes the same product
        if "boresight" in drawn:
            R_e = drawn["boresight"] @ R_b_file.T
            R_cam_inner = R_e if R_cam_inner is None else R_cam_inner @ R_e
        if "mount" in drawn:
            R_e = R_m_file.T @ drawn["mount"]
            R_base_body = R_e if R_base_body is None else R_e @ R_base_body
    row = model.row + _or(errors.get("image_centre_x_px"), 0.0)
    col = model.col + _or(errors.get("image_centre_y_px"), 0.0)
    row, col = np.broadcast_to(row, (n,)), np.broadcast_to(col, (n,))
    if not build_chain:
        return pose, (R_cam_inner, R_base_body), row, col
    chain = FrameChain(pose, R_cam_inner=R_cam_inner, R_base_body=R_base_body)
    return pose, chain, row, col


def perturbed_lens(lens: Lens, errors: dict) -> Lens:
    """The lens with the samples' lens errors added: per-sample parameter arrays (or ``lens`` itself).

    Parameters
    ----------
    lens : geoloc.sensors.lenses.Lens
    errors : dict
        Source -> ndarray (n,); the lens sources (:data:`geoloc.analysis.errormodel.LENS_SOURCES`,
        pixels or dimensionless) add their draw to the lens's value; ``focal_length_px`` adds
        the same draw to fx and fy.

    Returns
    -------
    Lens
        Its perturbed parameters are arrays (n,), broadcasting with the chunk's pixels and
        poses (``Lens.unproject``); a sample whose draw makes no lens (fx <= 0) gets NaN and
        ``INVALID_INPUT`` downstream.
    """
    changes: dict[str, np.ndarray] = {}
    for source, names in LENS_SOURCES.items():
        d = errors.get(source)
        if d is None:
            continue
        for name in names:
            changes[name] = changes.get(name, getattr(lens, name)) + np.asarray(d, float)
    return lens.with_params(**changes) if changes else lens


def evaluate(
    model: ErrorModel, errors: dict, surface: Surface | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Locate the target for a batch of perturbed samples [Q17 eq. 14].

    Parameters
    ----------
    model : ErrorModel
    errors : dict
        Source -> ndarray (n,) in SI units; missing sources are zero.
    surface : Surface, optional
        The terrain its caller built once (:func:`geoloc.surfaces.terrain.surface_for`; for
        the scenario's ``[dem]`` table, ``geoloc.cli._options.surface_from_scenario``): the
        target is the line of sight's hit on it (``target_h_m`` errors are then ignored).
        Without it, the target height is ``model.target_h_m + errors["target_h_m"]`` (the
        model's ``kind`` of height surface).

    Notes
    -----
    The one engine: the camera's sensor (:class:`geoloc.sensors.frame.FrameSensor`) with
    per-sample mount, boresight, lever-arm and lens perturbations, rotating the vector
    hop by hop. The paper's batched :class:`geoloc.frames.chain.FrameChain` is the
    reference the tests hold it to (:func:`perturbed_geometry` and
    :meth:`geoloc.sensors.camera.Camera.chain_line_of_sight`).

    Returns
    -------
    lat, lon, h : ndarray (n,)
        Radians and metres; NaN where the status is not OK.
    status : ndarray (n,) of uint8
    """
    pose, (Ri, Rb), row, col = perturbed_geometry(model, errors, build_chain=False, with_camera=False)
    lever = [errors.get(f"lever_arm_{a}_m") for a in "xyz"]
    extra = None if all(v is None for v in lever) else np.stack([_or(v, np.zeros(len(row))) for v in lever], -1)
    s = model.camera
    s = dataclasses.replace(
        s, lens=perturbed_lens(s.lens, errors), R_base_extra=Rb, R_bore_extra=Ri, lever_extra_m=extra
    )
    los = s.line_of_sight(row, col, pose, outside="extrapolate")
    _needs_surface(model, surface)
    if surface is None:  # the one "height or DEM" choice (geoloc.surfaces.terrain.surface_for)
        from geoloc.surfaces.terrain import surface_for

        surface = surface_for(model.target_h_m + _or(errors.get("target_h_m"), 0.0), kind=model.height_kind)
    g = Pipeline(s, surface, model.corrections).intersect(los)
    return g.lat, g.lon, g.h, np.asarray(g.status, np.uint8)


def nominal_point(model: ErrorModel, surface: Surface | None = None) -> tuple[float, float, float, int]:
    """The error-free target (lat, lon, h) [rad, rad, m] and its status: y = f(x_1, ..., x_n),
    on ``surface`` (as :func:`evaluate`)."""
    lat, lon, h, st = evaluate(model, {}, surface)
    return float(lat[0]), float(lon[0]), float(h[0]), int(st[0])


# --------------------------------------------------------------------- statistics
def statistics(lat: ArrayLike, lon: ArrayLike, h: ArrayLike, status: ArrayLike | None = None) -> dict[str, float]:
    """Mean and standard deviation of the located points, CEP [Q17 eq. 18] and the empirical CEP50.

    * ``cep_m`` is [Q17 eq. 18]:
      sigma_r = sqrt( (sigma_lambda (R_N + h_T) cos phi_T)^2 + (sigma_phi (R_M + h_T))^2 ),
      with R_N, R_M at the mean latitude [Q17 eq. 16-17] and h_T the mean height.
      It is the radial RMS distance to the mean point (also called DRMS), not a
      50 % radius: about 63-68 % of the points fall inside it for a circular
      normal cloud and 68 % for a cloud stretched along one line.
    * ``cep50_empirical_m`` is the median horizontal distance of the samples to
      their mean point, distances in the same local tangent-plane metric.

    Parameters
    ----------
    lat, lon : array_like
        Latitude and longitude [rad].
    h : array_like
        Height [m].
    status : array_like of uint8, optional
        Only OK samples are used (all finite samples if omitted).

    Returns
    -------
    dict
        The :data:`STATS_KEYS` (degrees and metres) plus ``n_ok``, ``n_failed``.
    """
    lat_a, lon_a, h_a = (np.asarray(v, float).ravel() for v in (lat, lon, h))
    ok = np.isfinite(lat_a) & np.isfinite(lon_a) & np.isfinite(h_a)
    if status is not None:
        ok &= np.asarray(status).ravel() == Status.OK
    lat_k, lon_k, h_k = lat_a[ok], lon_a[ok], h_a[ok]
    n = lat_k.size
    if n < 2:
        out = {k: math.nan for k in STATS_KEYS}
        out.update(n_ok=int(n), n_failed=int((~ok).sum()))
        return out
    # longitude: average the offsets from the first sample (no wrap at +-180 deg)
    dlon = (lon_k - lon_k[0] + np.pi) % (2 * np.pi) - np.pi
    m_lat, m_h = lat_k.mean(), h_k.mean()
    m_lon = lon_k[0] + dlon.mean()
    s_lat, s_lon, s_h = lat_k.std(ddof=1), dlon.std(ddof=1), h_k.std(ddof=1)
    rn, rm = prime_vertical_radius(m_lat), meridian_radius(m_lat)
    east = (dlon - dlon.mean()) * (rn + m_h) * math.cos(m_lat)
    north = (lat_k - m_lat) * (rm + m_h)
    out = summary(m_lat, m_lon, m_h, s_lat, s_lon, s_h, float(np.median(np.hypot(east, north))))
    out.update(n_ok=int(n), n_failed=int((~ok).sum()))
    return out


# --------------------------------------------------------------------- Monte Carlo
@dataclass
class MonteCarloResult:
    """Samples and statistics of one Monte Carlo run.

    Attributes
    ----------
    lat, lon, h : ndarray (n,) or None
        Located targets [rad, rad, m] (NaN where status is not OK); None when
        the run streamed its samples (``keep_samples=False``).
    status : ndarray (n,) of uint8, or None
    stats : dict
        :func:`statistics` of the samples (or the streamed equivalent,
        :class:`geoloc.analysis.streaming.StreamingStats`).
    nominal : tuple
        Error-free target (lat, lon, h, status) [rad, rad, m].
    seconds : float
        Wall time of the sampling and location.
    status_counts : ndarray of int
        Samples per :class:`geoloc.status.Status` code.
    streamed : bool
        True when the statistics were streamed (more than one chunk, samples not kept).
    """

    lat: np.ndarray | None
    lon: np.ndarray | None
    h: np.ndarray | None
    status: np.ndarray | None
    stats: dict
    nominal: tuple
    seconds: float
    status_counts: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(len(Status), np.int64))
    streamed: bool = False


#: Largest N whose samples :func:`run` keeps by default (25 bytes each: 50 MB).
KEEP_MAX = 2_000_000


def run(
    model: ErrorModel,
    n: int,
    rng: np.random.Generator,
    *,
    surface: Surface | None = None,
    chunk: int = CHUNK,
    progress: bool | None = False,
    keep_samples: bool | None = None,
) -> MonteCarloResult:
    """Monte Carlo of ``n`` samples [Q17 eq. 14-15], vectorised in chunks of ``chunk``.

    Memory is bounded by the chunk: each chunk is drawn, located by :func:`evaluate`
    and folded into the statistics. With ``n <= chunk`` (one chunk) or kept
    samples the statistics are :func:`statistics` of all samples, exactly; beyond
    that without kept samples they are streamed
    (:class:`geoloc.analysis.streaming.StreamingStats`: the same mean, standard
    deviations and eq. 18 up to rounding, the empirical 50 % radius from a
    histogram, about 1e-4 of it). The samples drawn are the same either way: a
    seed gives the same sample sequence for a given chunk size.

    Parameters
    ----------
    model : ErrorModel
    n : int
        Number of samples N (>= 2); any size when the samples are not kept.
    rng : numpy.random.Generator
        Seeded generator; the samples depend on the seed and the chunk size.
    surface : Surface, optional
        The terrain for the target (overrides the target-height error), built once by the
        caller (as :func:`evaluate`). Required when the model names a DEM (``[dem]``):
        ``geoloc.cli._options.surface_from_scenario(model)`` builds it.
    chunk : int
        Samples per vectorised call (the memory bound: about 1.5 kB per sample).
    progress : bool or None
        Progress line with the time left on stderr (None: when stderr is a terminal).
    keep_samples : bool or None
        Keep every located sample in the result (``lat``, ``lon``, ...). None
        (default): keep them when ``n <= KEEP_MAX``. True with a larger ``n`` is
        refused (memory).

    Returns
    -------
    MonteCarloResult
    """
    n, chunk = check_samples_and_chunk(n, chunk)
    keep = n <= KEEP_MAX if keep_samples is None else bool(keep_samples)
    if keep and n > KEEP_MAX:
        raise ValueError(
            f"samples = {n}: keeping more than {KEEP_MAX} samples is refused "
            f"({25 * n / 1e9:.1f} GB); stream them (keep_samples=False)"
        )
    t0 = time.perf_counter()
    # lat, lon, h, status of every sample when they are kept
    kept: tuple[np.ndarray, ...] | None = (
        (np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.uint8)) if keep else None
    )
    acc = None if keep or n <= chunk else StreamingStats()
    counts = np.zeros(len(Status), np.int64)
    one = None  # the single chunk's results, when there is one chunk and nothing is kept
    bar = Progress(n, f"montecarlo {model.name}", progress)
    for a in range(0, n, chunk):
        b = min(a + chunk, n)
        out = evaluate(model, model.sample(b - a, rng), surface)
        counts += np.bincount(out[3], minlength=len(Status))[: len(Status)]
        if kept is not None:
            for whole, part in zip(kept, out):
                whole[a:b] = part
        elif acc is None:
            one = out
        else:
            acc.add(*out)
        bar.update(b - a)
    bar.close()
    if kept is not None:
        stats = statistics(*kept)
    elif acc is None:
        assert one is not None  # n <= chunk: the loop ran once
        stats = statistics(*one)
    else:
        stats = acc.result()
    secs = time.perf_counter() - t0
    lat, lon, h, st = kept if kept is not None else (None, None, None, None)
    return MonteCarloResult(
        lat, lon, h, st, stats, nominal_point(model, surface), secs, status_counts=counts, streamed=acc is not None
    )


def _needs_surface(model: ErrorModel, surface) -> None:
    """A model that names a DEM is run on the surface its caller built from it, never without."""
    if surface is None and model.dem is not None:
        raise ValueError(
            f"{model.source}: [dem] path = {model.dem.path}: Monte Carlo takes the surface "
            "built from it (surface=geoloc.cli._options.surface_from_scenario(model), or "
            "geoloc.surfaces.terrain.surface_for(dem=...)); model.without_dem() for the height"
        )


# --------------------------------------------------------------------- first order
@dataclass
class FirstOrder:
    """First-order (linear) propagation of the error model through the chain.

    Attributes
    ----------
    sources : list of str
    jacobian : ndarray (3, k)
        d(lat [rad], lon [rad], h [m]) / d(source [SI]).
    cov : ndarray (3, 3)
        J diag(std^2) J^T.
    std_lat_deg, std_lon_deg, std_h_m, cep_m : float
        Standard deviations and [Q17 eq. 18] from ``cov``.
    """

    sources: list
    jacobian: np.ndarray
    cov: np.ndarray
    std_lat_deg: float
    std_lon_deg: float
    std_h_m: float
    cep_m: float


def first_order(model: ErrorModel, rel_step: float = 0.1) -> FirstOrder:
    """Linear error propagation: cov = J Sigma J^T with J by central differences of the chain.

    All 2k perturbed evaluations go through :func:`evaluate` in one batch.
    Biases are ignored (they shift the mean, not the spread). Ellipsoid model
    only (a DEM makes the map piecewise).

    Parameters
    ----------
    model : ErrorModel
    rel_step : float
        Difference step as a fraction of each source's standard deviation.
    """
    std = model.std_si()
    sources = [k for k, s in std.items() if s > 0]
    k = len(sources)
    keys = [s.replace("_um", "_px") for s in sources]
    errs = {key: np.zeros(2 * k) for key in keys}
    steps = np.array([rel_step * std[s] for s in sources])
    for i, key in enumerate(keys):
        errs[key][2 * i] = steps[i]
        errs[key][2 * i + 1] = -steps[i]
    lat, lon, h, st = evaluate(model.without_dem(), errs)
    if np.any(st != Status.OK):
        raise ValueError(
            f"{model.source}: the nominal geometry gives no ground point (status {sorted(set(int(x) for x in st))})"
        )
    y = np.stack([lat, lon, h])  # (3, 2k)
    J = (y[:, 0::2] - y[:, 1::2]) / (2 * steps)
    sig = np.array([std[s] for s in sources])
    cov = (J * sig**2) @ J.T
    s_lat, s_lon, s_h = np.sqrt(np.diag(cov))
    lat0 = float(np.mean(lat))
    h0 = float(np.mean(h))
    return FirstOrder(
        sources, J, cov, math.degrees(s_lat), math.degrees(s_lon), float(s_h), cep_eq18(s_lat, s_lon, lat0, h0)
    )


# --------------------------------------------------------------------- sweeps
@dataclass
class Sweep:
    """CEP against the outer gimbal angle [Q17 Fig. 10].

    Attributes
    ----------
    angles_deg : ndarray (a,)
    labels : list of str
        One per curve (e.g. ``sigma_h=10m`` or ``dem``).
    cep_m, cep50_m : ndarray (a, c)
        [Q17 eq. 18] and the empirical 50 % radius, NaN where too few samples hit.
    n_ok : ndarray (a, c) of int
    """

    angles_deg: np.ndarray
    labels: list
    cep_m: np.ndarray
    cep50_m: np.ndarray
    n_ok: np.ndarray
    title: str = ""
    #: Published bounds drawn on the PNG: (angle_deg, cep_m, label) upper limits.
    reference: tuple = ()

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """One row per angle and curve: angle, curve, cep_m, cep50_empirical_m, n_ok."""
        with atomic_path(path) as tmp, open(tmp, "w") as fh:
            fh.write("gimbal_roll_deg,curve,cep_m,cep50_empirical_m,n_ok\n")
            for i, a in enumerate(self.angles_deg):
                for j, lab in enumerate(self.labels):
                    fh.write(f"{a:g},{lab},{self.cep_m[i, j]:.3f},{self.cep50_m[i, j]:.3f},{int(self.n_ok[i, j])}\n")

    def to_png(self, path: str | os.PathLike[str]) -> None:
        """Matplotlib figure like [Q17 Fig. 10]: solid eq. 18, dashed empirical CEP50."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
        colors = plt.cm.viridis(np.linspace(0, 0.9, len(self.labels)))
        for j, lab in enumerate(self.labels):
            ax.plot(self.angles_deg, self.cep_m[:, j], "-", color=colors[j], label=f"{lab} eq. 18")
            ax.plot(self.angles_deg, self.cep50_m[:, j], ":", color=colors[j], lw=1)
        for k, (a, c, lab) in enumerate(self.reference):
            ax.plot([a], [c], "rv", ms=8, label=lab if k == 0 else None)
        ax.set_xlabel("outer gimbal (frame roll) angle [deg]")
        ax.set_ylabel("CEP [m]  (solid: [Q17] eq. 18, dotted: empirical 50 %)")
        ax.set_title(self.title or "CEP against the outer frame angle")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
        plt.close(fig)


def _sweep_point(ma: ErrorModel, n: int, c: int, draw, bar, surface=None, chunk: int = CHUNK) -> list:
    """Statistics of ``c`` blocks of ``n`` samples at one sweep angle.

    ``draw(k)`` returns the errors of ``k * c`` samples, block j holding samples
    ``j*k .. (j+1)*k``. With ``n * c <= chunk`` one batch (the samples and numbers
    of a single call); else ``chunk // c`` samples per block at a time, streamed
    (:class:`geoloc.analysis.streaming.StreamingStats`), in constant memory.
    """
    if n * c <= chunk:
        lat, lon, h, st = evaluate(ma, draw(n), surface)
        bar.update(n * c)
        return [
            statistics(
                lat[j * n : (j + 1) * n], lon[j * n : (j + 1) * n], h[j * n : (j + 1) * n], st[j * n : (j + 1) * n]
            )
            for j in range(c)
        ]
    accs = [StreamingStats() for _ in range(c)]
    per = max(chunk // c, 1)
    for a in range(0, n, per):
        k = min(per, n - a)
        lat, lon, h, st = evaluate(ma, draw(k), surface)
        for j in range(c):
            s = slice(j * k, (j + 1) * k)
            accs[j].add(lat[s], lon[s], h[s], st[s])
        bar.update(k * c)
    return [acc.result() for acc in accs]


def sweep_terrain_sigma(
    model: ErrorModel,
    angles_deg: ArrayLike,
    sigmas_m: ArrayLike,
    n: int,
    rng: np.random.Generator,
    progress: bool | None = False,
    chunk: int = CHUNK,
) -> Sweep:
    """[Q17 Fig. 10a]: CEP against the outer gimbal angle for several terrain sigmas (ellipsoid).

    For each angle the nominal ``gimbal_roll_deg`` is replaced, and one
    vectorised batch of ``n * len(sigmas_m)`` samples is located, block j
    with the target height error ``sigmas_m[j] * N(0, 1)`` (the model's own
    ``target_h_m`` error is replaced). A batch larger than ``chunk`` is split
    and its statistics streamed (constant memory).
    """
    angles = np.asarray(angles_deg, float).ravel()
    sig = np.asarray(sigmas_m, float).ravel()
    m = model.without_dem().with_error("target_h_m", None)
    c = sig.size
    cep = np.full((angles.size, c), np.nan)
    cep50 = np.full_like(cep, np.nan)
    nok = np.zeros(cep.shape, int)
    bar = Progress(angles.size * c * n, "sweep fig10a", progress)
    for i, a in enumerate(angles):
        ma = m.with_nominal(gimbal_roll_deg=a)

        def draw(k, ma=ma):
            errs = ma.sample(k * c, rng)
            errs["target_h_m"] = rng.standard_normal(k * c) * np.repeat(sig, k)
            return errs

        for j, stt in enumerate(_sweep_point(ma, n, c, draw, bar, chunk=chunk)):
            cep[i, j], cep50[i, j], nok[i, j] = stt["cep_m"], stt["cep50_empirical_m"], stt["n_ok"]
    bar.close()
    return Sweep(
        angles,
        [f"sigma_h={s:g}m" for s in sig],
        cep,
        cep50,
        nok,
        "[Q17] Fig. 10a: ellipsoid model, terrain standard deviation",
    )


def sweep_dem(
    model: ErrorModel,
    angles_deg: ArrayLike,
    n: int,
    rng: np.random.Generator,
    surface: Surface | None = None,
    progress: bool | None = False,
    chunk: int = CHUNK,
) -> Sweep:
    """[Q17 Fig. 10b]: CEP against the outer gimbal angle with the target on a DEM: ``surface``,
    built once by the caller (``geoloc.cli._options.surface_from_scenario(model)`` for the
    scenario's ``[dem]`` table)."""
    if surface is None:
        raise ValueError(
            f"{model.source}: the DEM sweep needs the DEM's surface (surface=; "
            "geoloc.cli._options.surface_from_scenario(model) for a [dem] table)"
        )
    angles = np.asarray(angles_deg, float).ravel()
    cep = np.full((angles.size, 1), np.nan)
    cep50 = np.full_like(cep, np.nan)
    nok = np.zeros(cep.shape, int)
    bar = Progress(angles.size * n, "sweep fig10b", progress)
    for i, a in enumerate(angles):
        ma = model.with_nominal(gimbal_roll_deg=a)
        (stt,) = _sweep_point(ma, n, 1, lambda k, ma=ma: ma.sample(k, rng), bar, surface, chunk)
        cep[i, 0], cep50[i, 0], nok[i, 0] = stt["cep_m"], stt["cep50_empirical_m"], stt["n_ok"]
    bar.close()
    return Sweep(
        angles,
        ["dem"],
        cep,
        cep50,
        nok,
        "[Q17] Fig. 10b: target on the DEM",
        reference=((70.0, 50.0, "[Q17] upper bounds: < 50 m below 70 deg, < 180 m at 80 deg"), (80.0, 180.0, "")),
    )


# --------------------------------------------------------------------- helpers
def _field(key: str) -> str:
    return key[:-4] if key.endswith("_deg") else key[:-2]  # lat_deg -> lat, h_m -> h


def _or(x, default):
    return default if x is None else x


def _batch_len(errors: dict) -> int:
    for v in errors.values():
        return int(np.shape(v)[0])
    return 1
