"""Campaign speed: replay 10 M flight records from a partitioned Parquet, one process vs a local dask cluster.

Makes ``--records`` synthetic records (default 10 000 000; seeded) from the 24 records
of ``assets/records/eo_turret_flight.csv`` (sensor ``assets/sensors/eo_turret.toml``):
each a random one of the 24 with its aircraft position jittered by up to 0.001 deg and
20 m, its attitude and turret angles by up to 0.2 deg and its pixel by up to 5 px. They
are written in chunks of ``--partition`` rows (default 250 000), one Parquet file each
(hive layout ``part=K/data.parquet``) in a temporary folder, so memory stays bounded
(one chunk) however many records are asked for. The truth columns are carried along,
so every unit also computes ``error_to_truth_m`` (pyproj geodesics).

Then times ``geoloc.workflows.campaign.run_campaign`` on that dataset, each partition
located on the Jacksboro SRTM crop (exact solver, serial kernel; the line of sight by
the compiled kernel, parallel over ``numba_threads``) and written to Parquet. Sides:

- **one process, 1 thread** (the peer of ``ratio:``): ``scheduler="none"``, the units
  one after the other in this process, ``numba_threads=1``;
- **one process, numba x N** (N = ``NUMBA_NUM_THREADS``, every core): the same with the
  line-of-sight kernel on N threads (what ``--scheduler none`` gets by default), for
  the comparison at equal threads;
- **cluster**: ``--workers`` worker processes (default 2) of one thread each, made by
  ``campaign.local_cluster`` (run_campaign's), each unit's kernels on
  ``worker_numba_threads`` threads (cores // workers: 1 on 2 cores), the scheduler and
  the nannies in this process.

``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` are set to 1 (unless
given) before numpy is imported; workers inherit them. Each side prints the numba
threads its units ran with and its CPU/wall ratio (1.00 = one core busy).

Before the timed runs every process replays one small partition (untimed): numba
compiles or loads its kernels once per process, and on a tree whose kernels were just
edited that compile (tens of seconds on a loaded machine) is not the campaign's speed.

Figures: wall time (time.perf_counter) and CPU time. One process: its
``time.process_time``. Cluster: the workers' whole process CPU (``time.process_time``
in every worker before and after, through ``Client.run``: the units and dask's own
threads) plus this process's (scheduler, nannies, client). Also printed: the units'
own CPU (``time.thread_time`` around each unit), system CPU and minor page faults per
record (``resource.getrusage``), and the mean number of cores the machine's *other*
processes kept busy meanwhile (``/proc/stat`` minus the campaign's CPU): on 2 shared
cores, anything above 0 comes out of the cluster's second core. ``--repeat`` runs each
side (default 1: a run is long), interleaved, medians printed. ``--ab-malloc`` adds a
cluster run with distributed's malloc setting left as it is (``GEOLOC_DASK_MALLOC=keep``,
see ``geoloc.workflows.campaign.tune_worker_malloc``). The last line is ``ratio: X`` =
cluster records/s over one process (1 thread) records/s: the speed-up, the peer
measured in the same run.

Run: python benchmarks/bench_campaign.py [--records N] [--partition P] [--workers W] [--repeat R] [--ab-malloc]
"""

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # before numpy is imported; worker processes inherit them

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from geoloc.assets import asset_path
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.workflows.campaign import (
    CampaignConfig,
    local_cluster,
    run_campaign,
    run_unit,
    worker_numba_threads,
)

JITTER = {
    "ac_lat_deg": 1e-3,
    "ac_lon_deg": 1e-3,
    "ac_h_m": 20.0,
    "heading_deg": 0.2,
    "pitch_deg": 0.2,
    "roll_deg": 0.2,
    "azimuth_deg": 0.2,
    "elevation_deg": 0.2,
    "row": 5.0,
    "col": 5.0,
}


def make_dataset(folder: Path, n: int, partition: int, seed: int = 2026) -> int:
    """Write n synthetic records as Parquet partitions of ``partition`` rows; returns the partition count."""
    base = pcsv.read_csv(asset_path("records", "eo_turret_flight.csv"))
    num = {
        c: base.column(c).to_numpy()
        for c in base.column_names
        if pa.types.is_floating(base.column(c).type) or pa.types.is_integer(base.column(c).type)
    }
    rng = np.random.default_rng(seed)
    k = 0
    for start in range(0, n, partition):
        m = min(partition, n - start)
        pick = rng.integers(0, base.num_rows, m)
        cols = {}
        for c, v in num.items():
            x = v[pick].astype(float)
            if c in JITTER:
                x = x + rng.uniform(-JITTER[c], JITTER[c], m)
            cols[c] = x
        cols["point"] = (start + np.arange(m)).astype(np.int64)
        d = folder / f"part={k:04d}"
        d.mkdir(parents=True)
        pq.write_table(pa.table(cols), d / "data.parquet")
        k += 1
    return k


def _usage():
    """(CPU s, system CPU s, minor page faults) of the calling process (in a worker, through Client.run)."""
    import resource as res
    import time as tm

    r = res.getrusage(res.RUSAGE_SELF)
    return tm.process_time(), r.ru_stime, r.ru_minflt


def _busy_s() -> float:
    """CPU seconds all processes of the machine have used (/proc/stat: user+nice+system+irq+softirq+steal)."""
    try:
        with open("/proc/stat") as f:
            cpu = [int(x) for x in f.readline().split()[1:9]]
    except OSError:
        return float("nan")
    user, nice, system, _idle, _iowait, irq, softirq, steal = cpu
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def _add(*usages):
    return tuple(sum(u[i] for u in usages) for i in range(3))


def _sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def run(data: Path, out_root: Path, cfg, scheduler, tag, numba_threads, client=None):
    """One timed campaign: (wall, (CPU, system CPU, minor faults), units' CPU, rows, others' cores,
    the units' numba threads)."""
    out = out_root / tag
    workers0 = client.run(_usage) if client is not None else {}
    u0, b0, w = _usage(), _busy_s(), time.perf_counter()
    res = run_campaign([data], out, cfg, scheduler=scheduler, processes=True, numba_threads=numba_threads)
    wall, use, busy = time.perf_counter() - w, _sub(_usage(), u0), _busy_s() - b0
    if client is not None:
        workers1 = client.run(_usage)
        use = _add(use, *(_sub(workers1[k], workers0[k]) for k in workers1))
    if res.failed:
        raise RuntimeError(f"{len(res.failed)} failed units: {res.failed[0].messages}")
    shutil.rmtree(out)
    others = max(busy - use[0], 0.0) / wall  # the other processes' mean cores
    return wall, use, res.cpu_s, res.rows, others, sorted({u.numba_threads for u in res.units})


def cluster_run(tmp: Path, cfg, workers: int, r: int, tag: str):
    """A fresh local cluster (run_campaign's): its workers warmed on the small dataset (untimed), then
    one timed run with run_campaign's own share of the cores for each unit's numba kernels."""
    from dask.distributed import Client

    nt = worker_numba_threads(workers, 1)  # what run_campaign(scheduler="local") gives its units
    with local_cluster(workers, 1, processes=True) as cl, Client(cl) as client:
        warm_out = tmp / f"warm-{tag}-{r}"
        warm_out.mkdir()
        warm = sorted((tmp / "warm.parquet").rglob("*.parquet"))
        addrs = list(client.scheduler_info()["workers"])
        assert len(addrs) == workers, addrs
        for wk, addr in enumerate(addrs):
            client.submit(
                run_unit,
                100 + wk,
                str(warm[wk % len(warm)]),
                "records",
                cfg,
                str(warm_out),
                nt,
                workers=[addr],
                pure=False,
            ).result()
        return run(tmp / "records.parquet", tmp, cfg, cl.scheduler_address, f"{tag}-{r}", nt, client)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--records", type=int, default=10_000_000)
    ap.add_argument("--partition", type=int, default=250_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument(
        "--ab-malloc",
        action="store_true",
        help="also a cluster run with distributed's MALLOC_TRIM_THRESHOLD_ left in effect",
    )
    a = ap.parse_args()
    cfg = CampaignConfig(
        sensor=str(asset_path("sensors", "eo_turret.toml")),
        surface=SurfaceSpec(dem=str(asset_path("dem", "srtm_jacksboro.tif"))),
        carry_columns=False,
    )
    import numba

    cores = numba.config.NUMBA_NUM_THREADS
    print(
        f"load average {os.getloadavg()[0]:.2f} at the start; {os.cpu_count()} CPUs; numba threads "
        f"{cores}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}"
    )
    # (tag, scheduler, numba threads of each unit, malloc); the first is the peer of the ratio
    sides = [
        ("one process, 1 thread", "none", 1, None),
        (f"one process, numba x{cores}", "none", cores, None),
        (f"cluster {a.workers} proc x 1 thr", "local", None, None),
    ]
    if a.ab_malloc:
        sides.append(("  same, dask malloc", "local", None, "keep"))
    with tempfile.TemporaryDirectory(prefix="geoloc_bench_campaign_") as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        parts = make_dataset(tmp / "records.parquet", a.records, a.partition)
        make_dataset(tmp / "warm.parquet", 2000, 1000)
        print(
            f"{a.records:,} records in {parts} Parquet partitions of {a.partition:,} written in "
            f"{time.perf_counter() - t:.1f} s"
        )
        for nt in (1, cores):  # this process's warm-up (untimed), each thread count
            run(tmp / "warm.parquet", tmp, cfg, "none", f"warm{nt}", nt)
        runs = {tag: [] for tag, *_ in sides}
        for r in range(a.repeat):  # the sides interleaved: a change of the machine's load hits all
            for k, (tag, sched, nt, malloc) in enumerate(sides):
                if sched == "none":
                    runs[tag].append(run(tmp / "records.parquet", tmp, cfg, "none", f"one{k}-{r}", nt))
                    continue
                if malloc:
                    os.environ["GEOLOC_DASK_MALLOC"] = malloc  # spawned workers inherit it
                try:
                    runs[tag].append(cluster_run(tmp, cfg, a.workers, r, f"cl{k}"))
                finally:
                    os.environ.pop("GEOLOC_DASK_MALLOC", None)
        figures = {}
        for tag, rs in runs.items():
            wall = statistics.median(x[0] for x in rs)
            cpu = statistics.median(x[1][0] for x in rs)
            sys_ = statistics.median(x[1][1] for x in rs)
            flt = statistics.median(x[1][2] for x in rs)
            unit = statistics.median(x[2] for x in rs)
            others = statistics.median(x[4] for x in rs)
            rows, nts = rs[0][3], sorted({t for x in rs for t in x[5]})
            figures[tag] = (rows / wall, cpu / rows)
            print(
                f"{tag:<24} numba {'/'.join(map(str, nts))}  wall {wall:7.2f} s  CPU {cpu:7.2f} s (CPU/wall "
                f"{cpu / wall:4.2f}; units {unit:6.2f} s; system {sys_:5.2f} s)  {rows / wall:9,.0f} records/s  "
                f"{cpu / rows * 1e6:5.2f} us CPU/record  {flt / rows:5.2f} page faults/record  "
                f"other processes {others:4.2f} cores"
            )
        (one, cpu1), (two, _), (many, cpun) = list(figures.values())[:3]
        print(
            f"CPU per record, cluster / one process (1 thread): {cpun / cpu1:.2f}; cluster over one process "
            f"with numba x{cores}: {many / two:.2f}; load average {os.getloadavg()[0]:.2f} at the end"
        )
        print(f"ratio: {many / one:.2f} (speed-up: cluster records/s over one process, 1 thread, records/s, same run)")


if __name__ == "__main__":
    main()
