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
name and the others still run. Workers open the sensor and the DEM once per
process, from their paths.

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

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Photo suffixes (as ``geoloc replay``).
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".dng")
#: Records suffixes.
RECORDS_SUFFIXES = (".parquet", ".pq", ".csv")
#: Photos per photo unit.
PHOTOS_PER_UNIT = 16
SCHEDULERS_SERIAL = ("none", "serial")


@dataclass(frozen=True)
class CampaignConfig:
    """What every unit needs (paths, not objects: workers open them once each).

    Attributes
    ----------
    sensor : str or None
        Sensor (or first-phase camera) file; None: the workflow's default.
    dem : str, list of str or None
        ``--dem``: one raster, a folder of tiles, a ``.vrt`` or a list (a mosaic).
    dem_datum : {"egm96", "ellipsoid"}
    method, dem_model : str
        DEM solver (:func:`geoloc.surfaces.terrain.intersect_dem`).
    dem_options : dict
        ``eps_h``, ``threshold``.
    target_h_m : float or None
        Records without a DEM: one ellipsoidal target height [m] for every record...
    height_column : str or None
        ... or a column of them.
    altitude_datum : {"ellipsoid", "egm96"}
        Records: datum of ``ac_h_m`` (egm96 adds the bundled EGM96 N).
    targets : str or None
        Photos: the targets CSV.
    carry_columns : bool
        Records: copy the input columns to the output.
    dem_cache_bytes : int
        Bound of a mosaic's tile cache.
    """

    sensor: str | None = None
    dem: object = None
    dem_datum: str = "egm96"
    method: str = "exact"
    dem_model: str = "bilinear"
    dem_options: dict = field(default_factory=dict)
    target_h_m: float | None = None
    height_column: str | None = None
    altitude_datum: str = "ellipsoid"
    targets: str | None = None
    carry_columns: bool = True
    dem_cache_bytes: int = 64 * 2**20


@dataclass
class UnitResult:
    """What a unit hands back: where its rows went, how many, what went wrong, its CPU time."""

    index: int
    source: str
    part: str | None
    rows: int
    messages: list
    failed: bool
    cpu_s: float


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

    def table(self):
        """All rows as one ``pyarrow.Table``, in unit order (reads the parts)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        parts = [pq.read_table(u.part) for u in self.units if u.part]
        return pa.concat_tables(parts, promote_options="permissive") if parts else pa.table({})

    def summary(self) -> str:
        lines = [f"campaign ({self.kind}): {len(self.units)} unit(s), {self.rows} rows, "
                 f"{len(self.failed)} failed; Parquet parts in {self.out_dir}"]
        if np.isfinite(self.wall_s) and self.wall_s > 0:
            lines.append(f"wall {self.wall_s:.2f} s, unit CPU {self.cpu_s:.2f} s, "
                         f"{self.rows / self.wall_s:,.0f} rows/s")
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


def campaign_units(inputs, photos_per_unit: int = PHOTOS_PER_UNIT, exclude=()):
    """(kind, units, notes): the inputs' files (folders expanded, recursively: a partitioned
    Parquet dataset is a folder of ``.parquet`` files) as units of one kind.

    Files of no known kind are left out with a note; a mix of kinds is an error.
    """
    skip = {Path(x).resolve() for x in exclude if x}
    files = [f for f in _expand(inputs) if f.resolve() not in skip]  # e.g. the targets file beside the photos
    notes, kinds = [], {}
    for f in files:
        k = _kind(f)
        if k is None:
            notes.append(f"{f}: not a KLV, photo or records file (suffix {f.suffix!r}): left out")
            continue
        kinds.setdefault(k, []).append(str(f))
    if not kinds:
        raise ValueError("campaign: no KLV, photo or records file among the inputs")
    if len(kinds) > 1:
        raise ValueError("campaign inputs of different kinds: " + "; ".join(
            f"{k}: {v[0]} (+{len(v) - 1})" for k, v in kinds.items()) + "; run one kind at a time")
    (kind, paths), = kinds.items()
    if kind == "photos":
        units = [paths[i: i + photos_per_unit] for i in range(0, len(paths), photos_per_unit)]
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
    from geoloc.sensors.sensor_file import load_camera_or_sensor

    return _cached(("sensor", cfg.sensor), lambda: load_camera_or_sensor(cfg.sensor))


def _dem(cfg: CampaignConfig, whole: bool = False):
    """The DEM (or mosaic) of the campaign, opened once per process; ``whole``: one in-memory DEM."""
    if cfg.dem is None:
        return None
    from geoloc.surfaces.mosaic import DemMosaic, open_dem_or_mosaic

    key = ("dem", str(cfg.dem), cfg.dem_datum, cfg.method, cfg.dem_model, whole)

    def make():
        d = open_dem_or_mosaic(cfg.dem if isinstance(cfg.dem, (str, Path)) else list(cfg.dem), cfg.dem_datum,
                               cache_bytes=cfg.dem_cache_bytes, method=cfg.method, dem_model=cfg.dem_model,
                               **cfg.dem_options)
        return d.to_dem() if whole and isinstance(d, DemMosaic) else d

    return _cached(key, make)


def run_unit(index: int, unit, kind: str, cfg: CampaignConfig, out_dir: str) -> UnitResult:
    """Replay one unit and write its rows to ``out_dir/part-<index>.parquet``; never raises for a bad unit."""
    import pyarrow.parquet as pq

    c0 = time.thread_time()
    source = unit if isinstance(unit, str) else f"{unit[0]} (+{len(unit) - 1} photos)"
    try:
        table, messages = {"records": _records_unit, "klv": _klv_unit, "photos": _photos_unit}[kind](unit, cfg)
    except Exception as e:  # a bad unit is reported and the campaign goes on
        return UnitResult(index, source, None, 0, [f"{source}: failed: {type(e).__name__}: {e}"], True,
                          time.thread_time() - c0)
    part = None
    if table.num_rows:
        part = str(Path(out_dir) / f"part-{index:05d}.parquet")
        pq.write_table(table, part)
    return UnitResult(index, source, part, table.num_rows, messages, table.num_rows == 0 and kind == "klv",
                      time.thread_time() - c0)


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


def _records_unit(path: str, cfg: CampaignConfig):
    """One records file through the vectorised core: (pyarrow table, messages)."""
    import pyarrow as pa

    from geoloc.frames.chain import Pose
    from geoloc.geodesy.geodesic import horizontal_distance_m
    from geoloc.io.records import Q17_ANGLES, required_columns
    from geoloc.locate import as_sensor, line_of_sight
    from geoloc.status import Status
    from geoloc.surfaces.height import HeightSurface
    from geoloc.surfaces.terrain import DemSurface

    from geoloc.assets import DEFAULT_CAMERA, asset_path
    from geoloc.sensors.sensor_file import load_camera_or_sensor

    sensor = _sensor(cfg) if cfg.sensor else _cached(
        ("sensor", "default"), lambda: load_camera_or_sensor(asset_path(*DEFAULT_CAMERA)))
    s = as_sensor(sensor)
    table = _read_table(path)
    n = table.num_rows
    req = required_columns(s.angle_names)
    cols = {k: _column(table, k, path) for k in req}
    messages = []
    bad = np.zeros(n, bool)
    for k, (lo, hi) in req.items():
        v = cols[k]
        b = ~(np.isfinite(v) & (v >= lo) & (v <= hi))
        if b.any():
            i = int(np.flatnonzero(b)[0])
            messages.append(f"{path}: {int(b.sum())} row(s) with {k} missing or outside [{lo:g}, {hi:g}], "
                            f"first row {i} ({k} = {v[i]!r}): status invalid_input")
            bad |= b
    h_ac = cols["ac_h_m"]
    if cfg.altitude_datum == "egm96":
        from geoloc.geodesy.geoid import egm96_undulation

        h_ac = h_ac + egm96_undulation(np.deg2rad(cols["ac_lat_deg"]), np.deg2rad(cols["ac_lon_deg"]))
    elif cfg.altitude_datum != "ellipsoid":
        raise ValueError(f"altitude_datum = {cfg.altitude_datum!r}: must be 'ellipsoid' or 'egm96'")
    clean = {k: np.where(bad, 0.0, v) for k, v in cols.items()}  # bad rows: a harmless pose, flagged below
    q17 = {a: clean[f"{a}_deg"] for a in Q17_ANGLES if f"{a}_deg" in clean}
    other = {a: clean[f"{a}_deg"] for a in s.angle_names if a not in Q17_ANGLES}
    pose = Pose.from_deg(clean["ac_lat_deg"], clean["ac_lon_deg"], np.where(bad, 0.0, h_ac), clean["heading_deg"],
                         clean["pitch_deg"], clean["roll_deg"], q17.get("gimbal_roll", 0.0),
                         q17.get("gimbal_pitch", 0.0), angles_deg=other)
    los = line_of_sight(pose, sensor, clean["row"], clean["col"], outside="extrapolate")
    dem = _dem(cfg)
    if dem is not None:
        surf = dem if hasattr(dem, "cache") else DemSurface(dem, cfg.method, cfg.dem_model, **cfg.dem_options)
    elif cfg.height_column is not None:
        surf = HeightSurface(_column(table, cfg.height_column, path), "inflated")
    elif cfg.target_h_m is not None:
        surf = HeightSurface(float(cfg.target_h_m), "inflated")
    else:
        raise ValueError("records need a DEM, a height column or a target height")
    hit = surf.intersect(los)
    status = np.asarray(hit.status, np.uint8).copy()
    off = ~s.in_image(clean["row"], clean["col"]) & (status == Status.OK)
    status[off] = Status.OUTSIDE_SENSOR  # located by extending the lens model, flagged (as geoloc replay)
    if off.any():
        messages.append(f"{path}: {int(off.sum())} row(s) with the pixel off the sensor, first row "
                        f"{int(np.flatnonzero(off)[0])}: located by extending the lens model, status outside_sensor")
    status[bad] = Status.INVALID_INPUT
    nan = lambda a: np.where(bad, np.nan, np.asarray(a, float))  # noqa: E731
    lat, lon = nan(hit.lat_deg), nan(hit.lon_deg)
    out = {"source": pa.array(np.full(n, Path(path).name, dtype=object), pa.string()).dictionary_encode(),
           "row_index": np.arange(n, dtype=np.int64), "lat_deg": lat, "lon_deg": lon, "h_m": nan(hit.h),
           "h_datum": pa.array(np.full(n, "ellipsoid (WGS 84)", dtype=object), pa.string()).dictionary_encode(),
           "slant_range_m": nan(hit.slant_range), "status": status}
    if "truth_lat_deg" in table.column_names and "truth_lon_deg" in table.column_names:
        out["error_to_truth_m"] = horizontal_distance_m(lat, lon, _column(table, "truth_lat_deg", path),
                                                        _column(table, "truth_lon_deg", path))
    arrays = {k: pa.array(v) if isinstance(v, np.ndarray) else v for k, v in out.items()}
    if not cfg.carry_columns:
        return pa.table(arrays), messages
    base = table.drop_columns([k for k in arrays if k in table.column_names])
    for k, v in arrays.items():
        base = base.append_column(k, v)
    return base, messages


def _arrow_columns(columns: dict, source: str):
    import pyarrow as pa

    n = len(next(iter(columns.values()))) if columns else 0
    out = {"source": pa.array([source] * n, pa.string())}
    for k, v in columns.items():
        a = np.asarray(v)
        if a.dtype.kind == "O":
            out[k] = pa.array([None if x is None or (isinstance(x, float) and x != x) else str(x) for x in a],
                              pa.string())
        else:
            out[k] = pa.array(a)
    return pa.table(out)


def _klv_unit(path: str, cfg: CampaignConfig):
    from geoloc.workflows.klv_replay import replay_klv

    r = replay_klv(path, dem=_dem(cfg, whole=True), sensor=_sensor(cfg), method=cfg.method,
                   dem_model=cfg.dem_model, dem_options=dict(cfg.dem_options))
    messages = [f"{path}: {e}" for e in r.errors[:20]]
    if len(r.errors) > 20:
        messages.append(f"{path}: ... {len(r.errors) - 20} more bad packets")
    if len(r) == 0:
        messages.append(f"{path}: no good UAS LS packet")
    return _arrow_columns(r.columns, Path(path).name), messages


def _photos_unit(paths, cfg: CampaignConfig):
    import pyarrow as pa

    from geoloc.workflows.photo_replay import replay_photos

    if cfg.targets is None:
        raise ValueError("drone photos need a targets file (targets=, --targets T.csv)")
    rows, messages = replay_photos(list(paths), cfg.targets, sensor=_sensor(cfg), dem=_dem(cfg, whole=True),
                                   method=cfg.method, altitude_datum=cfg.altitude_datum)
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
def run_campaign(inputs, out_dir, config: CampaignConfig | None = None, *, scheduler: str = "local",
                 workers: int = 2, processes: bool = True, threads_per_worker: int = 1,
                 photos_per_unit: int = PHOTOS_PER_UNIT, on_unit=None) -> CampaignResult:
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

    Returns
    -------
    CampaignResult
    """
    cfg = config or CampaignConfig()
    kind, units, notes = campaign_units(inputs, photos_per_unit, exclude=(cfg.targets,))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    old = sorted(out.glob("part-*.parquet"))
    if old:
        raise ValueError(f"--parquet-out {out} already holds {len(old)} part file(s) ({old[0].name}, ...): "
                         "give an empty or new folder")
    if not (isinstance(workers, (int, np.integer)) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if cfg.dem is not None:
        _dem(cfg)  # a bad DEM is one error here, not one per unit
    results = [None] * len(units)
    t0 = time.perf_counter()

    def done(r):
        results[r.index] = r
        if on_unit is not None:
            on_unit(r)

    if scheduler in SCHEDULERS_SERIAL:
        for k, u in enumerate(units):
            done(run_unit(k, u, kind, cfg, str(out)))
    else:
        from dask.distributed import Client, LocalCluster, as_completed

        cluster = None
        if scheduler == "local":
            # every server on 127.0.0.1: worker processes' TCP (host), and the HTTP servers
            # (/health, metrics; dashboards) of the scheduler and of every worker, which
            # distributed opens on all interfaces otherwise, even for in-process workers
            net = {"host": "127.0.0.1"} if processes else {}
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=int(threads_per_worker),
                                   processes=bool(processes), dashboard_address="127.0.0.1:0",
                                   worker_dashboard_address="127.0.0.1:0", **net)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            futs = [client.submit(run_unit, k, u, kind, cfg, str(out.resolve()), pure=False, key=f"unit-{k}")
                    for k, u in enumerate(units)]
            for f in as_completed(futs):
                done(f.result())
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return CampaignResult(kind, str(out), results, time.perf_counter() - t0, notes)
