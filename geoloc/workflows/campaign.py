"""Campaigns: many replay inputs on ``dask.distributed``, each unit through the vectorised core, to Parquet.

A campaign is a list of *units* (``docs/scale.md``):

* a KLV unit is one MISB ST 0601 file (``.klv``, ``.bin``, ``.ts``, ...), replayed by
  :func:`geoloc.workflows.klv_replay.replay_klv`;
* a photo unit is a chunk of drone photos with the campaign's targets file,
  replayed by :func:`geoloc.workflows.photo_replay.replay_photos`;
* a records unit is one Parquet file (a partition of a partitioned dataset) or
  one CSV of flight records with the canonical columns of ``docs/records.md``
  (``row, col, ac_lat_deg, ac_lon_deg, ac_h_m, heading_deg, pitch_deg, roll_deg``
  and one ``<angle>_deg`` per joint of the sensor's gimbal), located as whole
  columns: one batched :class:`~geoloc.frames.chain.Pose`, one
  :func:`geoloc.locate.line_of_sight` call, one surface ``intersect`` (the DEM,
  or the ellipsoid inflated to a height [Q17 eq. 11]).

Every unit runs the same function (:func:`run_unit`) in the driver
(``scheduler="none"``), on a local cluster (``"local"``, the default:
``dask.distributed.LocalCluster`` bound to 127.0.0.1) or on any scheduler
(its address). Each writes its rows to ``out_dir/part-NNNNN.parquet`` (NNNNN the
unit's place in the campaign) and hands back only a small :class:`UnitResult`;
a unit that fails (a corrupt file, a missing column) is reported with its file
name and the others still run. Workers load the sensor once per process, from its
path, and build the surface once per process from the config's
:class:`geoloc.surfaces.spec.SurfaceSpec` (the one way every verb builds its surface).

Output columns, records units: the input columns (``carry_columns``), then
``source`` (the unit's file), ``row_index`` (0-based row of the unit),
``lat_deg``, ``lon_deg``, ``h_m`` (ellipsoidal, WGS 84: ``h_datum``),
``slant_range_m``, ``status`` (:class:`geoloc.status.Status` code) and
``error_to_truth_m`` (horizontal geodesic distance, when the unit has truth
columns). KLV and photo units: the columns of their workflows (docs/klv.md,
docs/photos.md) plus ``source``.

Conventions: ``docs/conventions.md`` (degrees and metres at this edge).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from geoloc.extras import require
from geoloc.frames.chain import Pose
from geoloc.locate import line_of_sight
from geoloc.pipeline import NO_CORRECTIONS, Corrections, Pipeline
from geoloc.status import Status
from geoloc.surfaces.base import terrain_of
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.userfiles import atomic_path

if TYPE_CHECKING:  # dask and pyarrow are optional dependencies (geoloc[campaign])
    import pyarrow as pa
    from dask.distributed import LocalCluster

#: Photo suffixes (as ``geoloc replay``).
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".dng")
#: Records suffixes.
RECORDS_SUFFIXES = (".parquet", ".pq", ".csv")
#: Photos per photo unit.
PHOTOS_PER_UNIT = 16
SCHEDULERS_SERIAL = ("none", "serial")


@dataclass(frozen=True)
class CampaignConfig:
    """What every unit needs (paths and values, not objects: workers open them once each).

    Attributes
    ----------
    sensor : str or None
        Sensor (or first-phase camera) file; None: the workflow's default.
    surface : SurfaceSpec
        The ground (``geoloc.cli._options.surface_spec_from_args`` on the command line):
        ``SurfaceSpec(dem=...)`` (one raster, a folder of tiles, a ``.vrt`` or a tuple: a
        mosaic, with its datum, method and tolerances), or, for records without a DEM,
        ``SurfaceSpec(target_h_m=...)`` or ``SurfaceSpec(height_column=...)``. The default
        names none: KLV units then use each packet's frame-centre height, photo units each
        target's truth height.
    altitude_datum : {"ellipsoid", "egm96"}
        Records: datum of ``ac_h_m`` (egm96 adds the bundled EGM96 N).
    targets : str or None
        Photos: the targets CSV.
    carry_columns : bool
        Records: copy the input columns to the output.
    corrections : Corrections
        The location pipeline's line-of-sight corrections for every unit (plain values: it
        pickles with the rest).
    """

    sensor: str | None = None
    surface: SurfaceSpec = field(default_factory=SurfaceSpec)
    altitude_datum: str = "ellipsoid"
    targets: str | None = None
    carry_columns: bool = True
    corrections: Corrections = NO_CORRECTIONS

    def __post_init__(self):
        if not isinstance(self.surface, SurfaceSpec):
            raise TypeError(
                f"CampaignConfig.surface must be a geoloc.surfaces.spec.SurfaceSpec, got {type(self.surface).__name__}"
            )


@dataclass
class UnitResult:
    """What a unit hands back: where its rows went, how many, what went wrong, its CPU time (this
    thread's), the numba threads it ran with."""

    index: int
    source: str
    part: str | None
    rows: int
    messages: list
    failed: bool
    cpu_s: float
    numba_threads: int = 0  # numba threads the unit's parallel kernels could use (0: numba not loaded)


@dataclass
class CampaignResult:
    """The campaign's units (in order) and where their Parquet parts are."""

    kind: str
    out_dir: str
    units: list
    wall_s: float = float("nan")
    notes: list = field(default_factory=list)  # inputs left out (not a KLV, photo or records file)

    @property
    def rows(self) -> int:
        return sum(u.rows for u in self.units)

    @property
    def failed(self) -> list:
        return [u for u in self.units if u.failed]

    @property
    def messages(self) -> list:
        return list(self.notes) + [m for u in self.units for m in u.messages]

    @property
    def cpu_s(self) -> float:
        """CPU seconds the units took (summed over workers)."""
        return float(sum(u.cpu_s for u in self.units))

    def table(self) -> pa.Table:
        """All rows as one ``pyarrow.Table``, in unit order (reads the parts)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        parts = [pq.read_table(u.part) for u in self.units if u.part]
        return pa.concat_tables(parts, promote_options="permissive") if parts else pa.table({})

    def summary(self) -> str:
        lines = [
            f"campaign ({self.kind}): {len(self.units)} unit(s), {self.rows} rows, "
            f"{len(self.failed)} failed; Parquet parts in {self.out_dir}"
        ]
        if np.isfinite(self.wall_s) and self.wall_s > 0:
            lines.append(
                f"wall {self.wall_s:.2f} s, unit CPU {self.cpu_s:.2f} s, {self.rows / self.wall_s:,.0f} rows/s"
            )
        return "\n".join(lines)


# --------------------------------------------------------------------------- units
def _expand(inputs) -> list:
    out = []
    for x in inputs:
        p = Path(x)
        if p.is_dir():
            files = sorted(q for q in p.rglob("*") if q.is_file() and not q.name.startswith((".", "_")))
            if not files:
                raise ValueError(f"campaign input folder {p} is empty")
            out += files
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"campaign input not found: {p}")
    return out


def _kind(path: Path) -> str | None:
    from geoloc.workflows.klv_replay import is_klv_path

    s = path.suffix.lower()
    if s in RECORDS_SUFFIXES:
        return "records"
    if is_klv_path(path):
        return "klv"
    if s in PHOTO_SUFFIXES:
        return "photos"
    return None


def campaign_units(
    inputs: Iterable[str | os.PathLike],
    photos_per_unit: int = PHOTOS_PER_UNIT,
    exclude: Iterable[str | os.PathLike | None] = (),
) -> tuple[str, list[list[str]] | list[str], list[str]]:
    """(kind, units, notes): the inputs' files (folders expanded, recursively: a partitioned
    Parquet dataset is a folder of ``.parquet`` files) as units of one kind.

    Files of no known kind are left out with a note; a mix of kinds is an error.
    """
    skip = {Path(x).resolve() for x in exclude if x}
    files = [f for f in _expand(inputs) if f.resolve() not in skip]  # e.g. the targets file beside the photos
    notes: list[str] = []
    kinds: dict[str, list[str]] = {}
    for f in files:
        k = _kind(f)
        if k is None:
            notes.append(f"{f}: not a KLV, photo or records file (suffix {f.suffix!r}): left out")
            continue
        kinds.setdefault(k, []).append(str(f))
    if not kinds:
        raise ValueError("campaign: no KLV, photo or records file among the inputs")
    if len(kinds) > 1:
        raise ValueError(
            "campaign inputs of different kinds: "
            + "; ".join(f"{k}: {v[0]} (+{len(v) - 1})" for k, v in kinds.items())
            + "; run one kind at a time"
        )
    ((kind, paths),) = kinds.items()
    units: list[list[str]] | list[str]  # photos go in batches; a flight file is a unit of its own
    if kind == "photos":
        units = [paths[i : i + photos_per_unit] for i in range(0, len(paths), photos_per_unit)]
    else:
        units = paths
    return kind, units, notes


_OPENED: dict = {}  # per process: opened sensors and DEMs, by path


def _cached(key, make):
    if key not in _OPENED:
        _OPENED[key] = make()
    return _OPENED[key]


def _sensor(cfg: CampaignConfig, default=None):
    if cfg.sensor is None:
        return default
    from geoloc.sensors.sensor_file import load_sensor

    return _cached(("sensor", cfg.sensor), lambda: load_sensor(cfg.sensor))


def _dem_surface(cfg: CampaignConfig, whole: bool = False):
    """The campaign's DEM surface, built once per process from its spec (None without a DEM);
    ``whole``: a mosaic read as one in-memory DEM (KLV and photo units, whose rays spread over the area)."""
    if cfg.surface.dem is None:
        return None
    return _cached(("surface", cfg.surface, whole), lambda: cfg.surface.build(whole=whole))


#: glibc ``mallopt`` parameters (malloc.h) and the values a worker process gets (see :func:`tune_worker_malloc`).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
WORKER_MMAP_THRESHOLD = 32 * 2**20  # glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit: the dynamic threshold's ceiling
WORKER_TRIM_THRESHOLD = 64 * 2**20  # twice that, as glibc's dynamic rule sets it (free heap kept at most 64 MiB)
_MALLOC: dict[str, bool | None] = {
    "tuned": None
}  # per process: None (not looked at), True (mallopt done), False (left alone)


def set_malloc_thresholds(
    mmap_threshold: int = WORKER_MMAP_THRESHOLD, trim_threshold: int = WORKER_TRIM_THRESHOLD
) -> bool:
    """Set this process's glibc malloc mmap and trim thresholds (``mallopt(3)``).

    Parameters
    ----------
    mmap_threshold : int
        Bytes: larger requests get their own ``mmap`` (M_MMAP_THRESHOLD; glibc caps it at 32 MiB).
    trim_threshold : int
        Bytes of free memory at the top of the heap before it is handed back (M_TRIM_THRESHOLD).

    Returns
    -------
    bool
        True if both were set; False where there is no glibc ``mallopt`` (not Linux, musl).
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, int(mmap_threshold))) and bool(mallopt(M_TRIM_THRESHOLD, int(trim_threshold)))


def tune_worker_malloc() -> bool:
    """Undo, in a dask worker *process*, what ``MALLOC_TRIM_THRESHOLD_`` does to numpy (once per process).

    ``distributed`` starts worker processes with ``MALLOC_TRIM_THRESHOLD_=65536``
    (its config ``distributed.nanny.pre-spawn-environ``, to hand freed memory back to
    the OS). Setting any malloc threshold switches off glibc's dynamic mmap threshold
    (``mallopt(3)``, M_MMAP_THRESHOLD: "dynamic adjustment ... is disabled if any of
    M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD, or M_MMAP_MAX is set"), so every
    array of 128 KiB or more is a fresh ``mmap``, its pages faulted in and zeroed by
    the kernel on first touch and unmapped on free. A records unit allocates
    hundreds of such arrays: in a worker it took about 5x the page faults, 3x the
    system time and 1.4-1.55x the CPU of the same unit in a plain process with the
    numpy line of sight, 1.10-1.20x with the compiled one (fewer temporaries;
    ``benchmarks/bench_campaign.py --ab-malloc``). Here the thresholds are set to
    where glibc's own dynamic rule would take them (mmap 32 MiB, its ceiling; trim
    twice that), so a worker keeps at most 64 MiB of freed heap.

    Only in a process that a dask worker runs in, that was spawned (not the caller's
    own process: in-process thread workers are left alone) and that has
    ``MALLOC_TRIM_THRESHOLD_`` in its environment; set ``GEOLOC_DASK_MALLOC=keep`` to
    leave distributed's setting as it is.

    Returns
    -------
    bool
        Whether this process's thresholds were set (now or at an earlier call).
    """
    tuned = _MALLOC["tuned"]
    if tuned is not None:
        return tuned
    _MALLOC["tuned"] = False
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or os.environ.get("GEOLOC_DASK_MALLOC") == "keep":
        return False
    import multiprocessing

    if multiprocessing.parent_process() is None:
        return False  # not a spawned worker process
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return False
    tuned = _MALLOC["tuned"] = set_malloc_thresholds()
    return tuned


def _dictionary_columns(table) -> list:
    """Columns worth Parquet dictionary pages: strings, dictionaries, small integers (source, h_datum,
    status), not floats (pyarrow would try, then fall back: 3x the write time of a records part)."""
    import pyarrow as pa

    return [
        f.name
        for f in table.schema
        if pa.types.is_dictionary(f.type)
        or pa.types.is_string(f.type)
        or pa.types.is_large_string(f.type)
        or pa.types.is_boolean(f.type)
        or (pa.types.is_integer(f.type) and f.type.bit_width <= 16)
    ]


def run_unit(
    index: int,
    unit: str | Sequence[str],
    kind: str,
    cfg: CampaignConfig,
    out_dir: str,
    numba_threads: int | None = None,
) -> UnitResult:
    """Replay one unit and write its rows to ``out_dir/part-<index>.parquet``; never raises for a bad unit.

    ``numba_threads``: the threads this unit's parallel kernels may use (numba's setting
    is per thread: this thread's, restored afterwards); None leaves numba's as it is.
    """
    tune_worker_malloc()
    if not numba_threads:
        return _run_unit(index, unit, kind, cfg, out_dir)
    import numba

    before = numba.get_num_threads()
    # numba.config sets NUMBA_NUM_THREADS from the environment when it is imported, so the module
    # declares no such name the checker could see
    most = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    numba.set_num_threads(max(1, min(int(numba_threads), most)))
    try:
        return _run_unit(index, unit, kind, cfg, out_dir)
    finally:
        numba.set_num_threads(before)


def _run_unit(index, unit, kind, cfg, out_dir) -> UnitResult:
    import pyarrow.parquet as pq

    c0 = time.thread_time()
    source = unit if isinstance(unit, str) else f"{unit[0]} (+{len(unit) - 1} photos)"
    try:
        table, messages = {"records": _records_unit, "klv": _klv_unit, "photos": _photos_unit}[kind](unit, cfg)
    except Exception as e:  # a bad unit is reported and the campaign goes on
        return UnitResult(
            index,
            source,
            None,
            0,
            [f"{source}: failed: {type(e).__name__}: {e}"],
            True,
            time.thread_time() - c0,
            _threads_now(),
        )
    part = None
    if table.num_rows:
        part = str(Path(out_dir) / f"part-{index:05d}.parquet")
        with atomic_path(part) as tmp:  # a part is whole or absent: an interrupted campaign resumes cleanly
            pq.write_table(table, tmp, use_dictionary=_dictionary_columns(table))
    return UnitResult(
        index,
        source,
        part,
        table.num_rows,
        messages,
        table.num_rows == 0 and kind == "klv",
        time.thread_time() - c0,
        _threads_now(),
    )


def _threads_now() -> int:
    """This thread's numba threads (0 if numba is not loaded)."""
    return int(sys.modules["numba"].get_num_threads()) if "numba" in sys.modules else 0


def _read_table(path: str):
    if path.lower().endswith(".csv"):
        import pyarrow.csv as pcsv

        return pcsv.read_csv(path)
    import pyarrow.parquet as pq

    return pq.read_table(path)


def _column(table, name, source):
    import pyarrow as pa
    import pyarrow.compute as pc

    if name not in table.column_names:
        raise ValueError(f"no column {name!r} (columns: {', '.join(table.column_names)})")
    col = table.column(name)
    if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type)):
        raise ValueError(f"column {name!r} is {col.type}, not numbers")
    return pc.cast(col, pa.float64()).to_numpy(zero_copy_only=False)  # nulls -> NaN


def _constant_column(text: str, n: int):
    """n copies of one string as a dictionary column (indices into a one-word dictionary)."""
    import pyarrow as pa

    return pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, np.int32)), pa.array([text], pa.string()))


def _records_unit(path: str, cfg: CampaignConfig):
    """One records file through the vectorised core: (pyarrow table, messages)."""
    import pyarrow as pa

    from geoloc.assets import DEFAULT_CAMERA, asset_path
    from geoloc.geodesy.geodesic import horizontal_distance_m
    from geoloc.io.records import Q17_ANGLES, required_columns
    from geoloc.sensors.sensor_file import load_sensor

    sensor = (
        _sensor(cfg) if cfg.sensor else _cached(("sensor", "default"), lambda: load_sensor(asset_path(*DEFAULT_CAMERA)))
    )
    table = _read_table(path)
    n = table.num_rows
    req = required_columns(sensor.angle_names)
    cols = {k: _column(table, k, path) for k in req}
    messages = []
    bad = np.zeros(n, bool)
    for k, (lo, hi) in req.items():
        v = cols[k]
        b = ~(np.isfinite(v) & (v >= lo) & (v <= hi))
        if b.any():
            i = int(np.flatnonzero(b)[0])
            messages.append(
                f"{path}: {int(b.sum())} row(s) with {k} missing or outside [{lo:g}, {hi:g}], "
                f"first row {i} ({k} = {v[i]!r}): status invalid_input"
            )
            bad |= b
    h_ac = cols["ac_h_m"]
    if cfg.altitude_datum == "egm96":
        from geoloc.geodesy.geoid import egm96_undulation

        h_ac = h_ac + egm96_undulation(np.deg2rad(cols["ac_lat_deg"]), np.deg2rad(cols["ac_lon_deg"]))
    elif cfg.altitude_datum != "ellipsoid":
        raise ValueError(f"altitude_datum = {cfg.altitude_datum!r}: must be 'ellipsoid' or 'egm96'")
    clean = {k: np.where(bad, 0.0, v) for k, v in cols.items()}  # bad rows: a harmless pose, flagged below
    q17 = {a: clean[f"{a}_deg"] for a in Q17_ANGLES if f"{a}_deg" in clean}
    other = {a: clean[f"{a}_deg"] for a in sensor.angle_names if a not in Q17_ANGLES}
    pose = Pose.from_deg(
        clean["ac_lat_deg"],
        clean["ac_lon_deg"],
        np.where(bad, 0.0, h_ac),
        clean["heading_deg"],
        clean["pitch_deg"],
        clean["roll_deg"],
        q17.get("gimbal_roll", 0.0),
        q17.get("gimbal_pitch", 0.0),
        angles_deg=other,
    )
    los = line_of_sight(pose, sensor, clean["row"], clean["col"], outside="extrapolate")
    spec = cfg.surface
    if spec.dem is None and spec.height_column is None and spec.target_h_m is None:
        raise ValueError("records need a DEM, a height column or a target height")
    surf = (
        _dem_surface(cfg)
        if spec.dem is not None
        else spec.build(_column(table, spec.height_column, path))
        if spec.height_column is not None
        else _cached(("surface", spec), spec.build)
    )
    dem = terrain_of(surf)
    hit = Pipeline(sensor, surf, cfg.corrections).intersect(los)
    status = np.asarray(hit.status, np.uint8).copy()
    off = ~sensor.in_image(clean["row"], clean["col"]) & (status == Status.OK)
    status[off] = Status.OUTSIDE_SENSOR  # located by extending the lens model, flagged (as geoloc replay)
    if off.any():
        messages.append(
            f"{path}: {int(off.sum())} row(s) with the pixel off the sensor, first row "
            f"{int(np.flatnonzero(off)[0])}: located by extending the lens model, status outside_sensor"
        )
    status[bad] = Status.INVALID_INPUT
    messages += _drone_height_messages(path, table, sensor, dem, cols, h_ac, np.asarray(hit.h, float), bad)
    nan = lambda a: np.where(bad, np.nan, np.asarray(a, float))  # noqa: E731
    lat, lon = nan(hit.lat_deg), nan(hit.lon_deg)
    out = {
        "source": _constant_column(Path(path).name, n),
        "row_index": np.arange(n, dtype=np.int64),
        "lat_deg": lat,
        "lon_deg": lon,
        "h_m": nan(hit.h),
        "h_datum": _constant_column("ellipsoid (WGS 84)", n),
        "slant_range_m": nan(hit.slant_range),
        "status": status,
        "corrections": _constant_column(cfg.corrections.label, n),
        "refraction_m": nan(hit.refraction_m),
    }
    if "truth_lat_deg" in table.column_names and "truth_lon_deg" in table.column_names:
        out["error_to_truth_m"] = horizontal_distance_m(
            lat, lon, _column(table, "truth_lat_deg", path), _column(table, "truth_lon_deg", path)
        )
    arrays = {k: pa.array(v) if isinstance(v, np.ndarray) else v for k, v in out.items()}
    if not cfg.carry_columns:
        return pa.table(arrays), messages
    base = table.drop_columns([k for k in arrays if k in table.column_names])
    for k, v in arrays.items():
        base = base.append_column(k, v)
    return base, messages


def _drone_height_messages(path, table, sensor, dem, cols, h_ac, hit_h, bad) -> list:
    """The records' drone check (``geoloc replay``'s, docs/records.md "Plausibility checks") for
    one unit: a count and the first row, as the unit's other messages; the rows run as read."""
    from geoloc.sensors.platform import (
        DRONE_CEILING_M,
        DRONE_MAX_HEIGHT_M,
        drone_height_hint,
        drone_height_where,
        drone_too_high,
        is_drone,
    )

    default = is_drone(getattr(sensor, "platform", ""))
    if "platform" in table.column_names:
        cells = table.column("platform").to_pylist()
        drone = np.array([is_drone(t) if t not in (None, "") and str(t).strip() else default for t in cells], bool)
    else:
        drone = np.full(len(h_ac), default)
    drone &= ~bad
    if not drone.any():
        return []
    ground = None if dem is None else dem.sample(np.deg2rad(cols["ac_lat_deg"]), np.deg2rad(cols["ac_lon_deg"]))[0]
    high, ref, what = drone_too_high(h_ac, hit_h, ground)
    high &= drone
    if not high.any():
        return []
    i = int(np.flatnonzero(high)[0])
    v, known = float(cols["ac_h_m"][i]), bool(np.isfinite(ref[i]))
    where = drone_height_where(h_ac[i], ref[i], what[i])
    hint = drone_height_hint(v, ref[i] - (h_ac[i] - v) if known else None)
    return [
        f"{path}: warning: {int(high.sum())} row(s) of a drone more than {DRONE_MAX_HEIGHT_M:.0f} m above the "
        f"terrain or target (or {DRONE_CEILING_M:.0f} m), first row {i} (ac_h_m = {v:g}: {where}): {hint}; "
        "used as read"
    ]


def _arrow_columns(columns: dict, source: str):
    import pyarrow as pa

    n = len(next(iter(columns.values()))) if columns else 0
    out = {"source": pa.array([source] * n, pa.string())}
    for k, v in columns.items():
        a = np.asarray(v)
        if a.dtype.kind == "O":
            out[k] = pa.array(
                [None if x is None or (isinstance(x, float) and x != x) else str(x) for x in a], pa.string()
            )
        else:
            out[k] = pa.array(a)
    return pa.table(out)


def _klv_unit(path: str, cfg: CampaignConfig):
    from geoloc.workflows.klv_replay import replay_klv

    r = replay_klv(path, surface=_dem_surface(cfg, whole=True), sensor=_sensor(cfg), corrections=cfg.corrections)
    messages = [f"{path}: {e}" for e in r.errors[:20]]
    if len(r.errors) > 20:
        messages.append(f"{path}: ... {len(r.errors) - 20} more bad packets")
    if len(r) == 0:
        messages.append(f"{path}: no good UAS LS packet")
    high = r.summary.plausibility_warnings
    if high:
        messages.append(f"{path}: warning: {len(high)} packet(s) too high for a drone, first {high[0]}")
    return _arrow_columns(r.columns, Path(path).name), messages


def _photos_unit(paths, cfg: CampaignConfig):
    import pyarrow as pa

    from geoloc.workflows.photo_replay import replay_photos

    if cfg.targets is None:
        raise ValueError("drone photos need a targets file (targets=, --targets T.csv)")
    rows, messages = replay_photos(
        list(paths),
        cfg.targets,
        sensor=_sensor(cfg),
        surface=_dem_surface(cfg, whole=True),
        altitude_datum=cfg.altitude_datum,
        corrections=cfg.corrections,
    )
    # targets of the campaign's other photo units are not this unit's business
    messages = [m for m in messages if "is not among the photos given" not in m]
    if not rows:
        return pa.table({}), messages
    keys = list(rows[0])
    cols = {k: np.array([r.get(k) for r in rows], dtype=object) for k in keys}
    for k, v in cols.items():
        if all(isinstance(x, (int, float, np.number)) or x is None for x in v):
            cols[k] = np.array([np.nan if x is None else x for x in v], dtype=float)
    return _arrow_columns(cols, Path(paths[0]).parent.name), messages


# --------------------------------------------------------------------------- running
def local_cluster(workers: int = 2, threads_per_worker: int = 1, processes: bool = True) -> LocalCluster:
    """The ``dask.distributed.LocalCluster`` of ``scheduler="local"``: every server on 127.0.0.1.

    ``workers`` worker processes (or, ``processes=False``, threads of this process) of
    ``threads_per_worker`` threads each. Bound to 127.0.0.1: the worker processes' TCP
    (``host``) and the HTTP servers (/health, metrics; dashboards, on a free port) of
    the scheduler and of every worker, which distributed opens on all interfaces
    otherwise, even for in-process workers. The workers' statistical profiler is off:
    it samples the running thread's stack every 10 ms for a dashboard nobody is shown
    (about 5 % of a worker's CPU on records units).

    Parameters
    ----------
    workers : int
        Workers (>= 1).
    threads_per_worker : int
        Threads of each worker (>= 1).
    processes : bool
        Worker processes (True) or threads of this process.

    Returns
    -------
    dask.distributed.LocalCluster
        Close it when done (it is a context manager).
    """
    dask = require("dask", "a campaign's local Dask cluster")
    from dask.distributed import LocalCluster

    if not (isinstance(workers, (int, np.integer)) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if not (isinstance(threads_per_worker, (int, np.integer)) and threads_per_worker >= 1):
        raise ValueError(f"threads_per_worker must be a positive integer, got {threads_per_worker!r}")
    net = {"host": "127.0.0.1"} if processes else {}
    with dask.config.set({"distributed.worker.profile.enabled": False}):  # the workers take this config along
        return LocalCluster(
            n_workers=int(workers),
            threads_per_worker=int(threads_per_worker),
            processes=bool(processes),
            dashboard_address="127.0.0.1:0",
            worker_dashboard_address="127.0.0.1:0",
            **net,
        )


def worker_numba_threads(workers: int, threads_per_worker: int = 1) -> int:
    """Numba threads for each unit on a local cluster: this process's cores // (workers x threads), >= 1.

    The compiled kernels are parallel (the line of sight of ``FrameSensor.line_of_sight``
    for 10 000 rays or more); left alone, numba gives every worker thread one thread per
    core: 2 workers x 2 threads on 2 cores.
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, cores // (int(workers) * int(threads_per_worker)))


def run_campaign(
    inputs: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    config: CampaignConfig | None = None,
    *,
    scheduler: str = "local",
    workers: int = 2,
    processes: bool = True,
    threads_per_worker: int = 1,
    photos_per_unit: int = PHOTOS_PER_UNIT,
    on_unit: Callable[[UnitResult], object] | None = None,
    numba_threads: int | str | None = "auto",
    progress: bool | None = False,
) -> CampaignResult:
    """Replay every unit of ``inputs`` (files or folders) and write Parquet parts to ``out_dir``.

    Parameters
    ----------
    inputs : list of path
        KLV / video files, photos, Parquet / CSV records, or folders of them (one kind).
    out_dir : path
        Created if missing; must not hold ``part-*.parquet`` files already (ValueError).
    config : CampaignConfig
    scheduler : str
        "local" (a ``LocalCluster`` of ``workers`` workers on 127.0.0.1, closed at the
        end), "none" (serial, in this process), or a scheduler address
        (``tcp://host:8786``).
    workers, processes, threads_per_worker
        The local cluster: worker processes (True) or threads of this process.
    on_unit : callable, optional
        Called with each :class:`UnitResult` as it completes (the CLI prints messages).
    numba_threads : "auto", int or None
        Threads for each unit's parallel kernels (the compiled line of sight).
        "auto": on the local cluster this machine's cores shared out
        (:func:`worker_numba_threads`: 1 for 2 workers on 2 cores), elsewhere
        numba's own setting (a worker's ``NUMBA_NUM_THREADS``, or the caller's in
        serial). An int: that many, at most ``NUMBA_NUM_THREADS``. None: numba's own.
    progress : bool or None
        :class:`geoloc.progress.Progress` on stderr, one step per unit done (None: the bar on a
        terminal, a line every 10 s in a log; False, the default: nothing).

    Returns
    -------
    CampaignResult
    """
    require("pyarrow", "a campaign (Parquet parts)")
    cfg = config or CampaignConfig()
    kind, units, notes = campaign_units(inputs, photos_per_unit, exclude=(cfg.targets,))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    old = sorted(out.glob("part-*.parquet"))
    if old:
        raise ValueError(
            f"--parquet-out {out} already holds {len(old)} part file(s) ({old[0].name}, ...): "
            "give an empty or new folder"
        )
    if not (isinstance(workers, (int, np.integer)) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if isinstance(numba_threads, str) and numba_threads == "auto":
        numba_threads = worker_numba_threads(workers, threads_per_worker) if scheduler == "local" else None
    elif not (numba_threads is None or (isinstance(numba_threads, (int, np.integer)) and numba_threads >= 1)):
        raise ValueError(f"numba_threads must be 'auto', a positive integer or None, got {numba_threads!r}")
    if cfg.surface.dem is not None:
        _dem_surface(cfg)  # a bad DEM is one error here, not one per unit
    results = [None] * len(units)
    t0 = time.perf_counter()
    from geoloc.progress import Progress

    bar = Progress(len(units), f"replay campaign of {len(units)} {kind} unit(s)", progress)

    def done(r):
        results[r.index] = r
        bar.update(1)
        if on_unit is not None:
            on_unit(r)

    if scheduler in SCHEDULERS_SERIAL:
        for k, u in enumerate(units):
            done(run_unit(k, u, kind, cfg, str(out), numba_threads))
    else:
        require("distributed", "a campaign on Dask")
        from dask.distributed import Client, as_completed

        cluster = None
        if scheduler == "local":
            cluster = local_cluster(workers, threads_per_worker, processes)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            futs = [
                client.submit(run_unit, k, u, kind, cfg, str(out.resolve()), numba_threads, pure=False, key=f"unit-{k}")
                for k, u in enumerate(units)
            ]
            for f in as_completed(futs):
                done(f.result())
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    bar.close()
    return CampaignResult(kind, str(out), results, time.perf_counter() - t0, notes)
