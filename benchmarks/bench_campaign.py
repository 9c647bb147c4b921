"""Campaign speed: replay 10 M flight records from a partitioned Parquet, one process vs a local dask cluster.

Makes ``--records`` synthetic records (default 10 000 000; seeded) from the 24 records
of ``assets/records/eo_turret_flight.csv`` (sensor ``assets/sensors/eo_turret.toml``):
each a random one of the 24 with its aircraft position jittered by up to 0.001 deg and
20 m, its attitude and turret angles by up to 0.2 deg and its pixel by up to 5 px. They
are written in chunks of ``--partition`` rows (default 250 000), one Parquet file each
(hive layout ``part=K/data.parquet``) in a temporary folder, so memory stays bounded
(one chunk) however many records are asked for.

Then times ``geoloc.workflows.campaign.run_campaign`` on that dataset, each partition
located on the Jacksboro SRTM crop (exact solver) and written to Parquet:

- one process: ``scheduler="none"`` (the units one after the other in this process);
- the local cluster: ``scheduler="local"``, ``--workers`` worker processes (default 2),
  one thread each.

Before the timed runs every process replays one small partition (untimed): numba
compiles or loads its kernels once per process, and on a tree whose kernels were just
edited that compile (tens of seconds on a loaded machine) is not the campaign's speed.

Figures: wall time (time.perf_counter) and CPU time: for one process its
time.process_time; for the cluster the sum of the units' CPU (time.thread_time in the
workers) plus the driver's process time. ``--repeat`` runs each (default 1: a run is
long), medians printed. Prints records per second for both and ``speed-up: X`` =
cluster records/s over one process records/s (the peer, measured in the same run).

Run: python benchmarks/bench_campaign.py [--records N] [--partition P] [--workers W] [--repeat R]
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from geoloc.assets import asset_path
from geoloc.workflows.campaign import CampaignConfig, run_campaign

JITTER = {"ac_lat_deg": 1e-3, "ac_lon_deg": 1e-3, "ac_h_m": 20.0, "heading_deg": 0.2, "pitch_deg": 0.2,
          "roll_deg": 0.2, "azimuth_deg": 0.2, "elevation_deg": 0.2, "row": 5.0, "col": 5.0}


def make_dataset(folder: Path, n: int, partition: int, seed: int = 2026) -> int:
    """Write n synthetic records as Parquet partitions of ``partition`` rows; returns the partition count."""
    base = pcsv.read_csv(asset_path("records", "eo_turret_flight.csv"))
    num = {c: base.column(c).to_numpy() for c in base.column_names
           if pa.types.is_floating(base.column(c).type) or pa.types.is_integer(base.column(c).type)}
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


def run(data: Path, out_root: Path, cfg, scheduler, workers, tag):
    out = out_root / tag
    c, w = time.process_time(), time.perf_counter()
    res = run_campaign([data], out, cfg, scheduler=scheduler, workers=workers, processes=True)
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    if scheduler != "none":
        cpu += res.cpu_s  # the workers' CPU
    if res.failed:
        raise RuntimeError(f"{len(res.failed)} failed units: {res.failed[0].messages}")
    import shutil

    shutil.rmtree(out)
    return wall, cpu, res.rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--records", type=int, default=10_000_000)
    ap.add_argument("--partition", type=int, default=250_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    cfg = CampaignConfig(sensor=str(asset_path("sensors", "eo_turret.toml")),
                         dem=str(asset_path("dem", "srtm_jacksboro.tif")), carry_columns=False)
    with tempfile.TemporaryDirectory(prefix="geoloc_bench_campaign_") as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        parts = make_dataset(tmp / "records.parquet", a.records, a.partition)
        make_dataset(tmp / "warm.parquet", 2000, 1000)
        print(f"{a.records:,} records in {parts} Parquet partitions written in {time.perf_counter() - t:.1f} s")
        # warm-up (untimed): this process, then every worker of a cluster of the same size
        run(tmp / "warm.parquet", tmp, cfg, "none", 1, "warm0")
        figures = {}
        for tag, sched in (("one process", "none"), (f"local cluster ({a.workers} workers)", "local")):
            walls, cpus = [], []
            for r in range(a.repeat):
                if sched == "local":
                    # a fresh cluster per run: warm its workers on the small dataset first (untimed)
                    from dask.distributed import Client, LocalCluster

                    from geoloc.workflows.campaign import run_unit

                    with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True,
                                      host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                      worker_dashboard_address="127.0.0.1:0") as cl, Client(cl) as client:
                        (tmp / f"w{r}").mkdir()
                        warm = sorted((tmp / "warm.parquet").rglob("*.parquet"))
                        for wk, addr in enumerate(client.scheduler_info()["workers"]):
                            client.submit(run_unit, 100 + wk, str(warm[wk % len(warm)]), "records", cfg,
                                          str(tmp / f"w{r}"), workers=[addr], pure=False).result()
                        wall, cpu, rows = run(tmp / "records.parquet", tmp, cfg, cl.scheduler_address,
                                              a.workers, f"run{r}")
                else:
                    wall, cpu, rows = run(tmp / "records.parquet", tmp, cfg, sched, 1, f"run{r}")
                walls.append(wall)
                cpus.append(cpu)
            wall, cpu = statistics.median(walls), statistics.median(cpus)
            figures[tag] = rows / wall
            print(f"{tag:<28} wall {wall:8.2f} s  CPU {cpu:8.2f} s  {rows / wall:12,.0f} records/s  "
                  f"({rows / cpu:,.0f} per CPU second)")
        one, many = figures.values()
        print(f"speed-up: {many / one:.2f} (local cluster over one process, records/s, same run)")


if __name__ == "__main__":
    main()
