"""Campaigns on dask.distributed (geoloc.workflows.campaign, ``geoloc replay --parquet-out``): a local
cluster of two workers gives the same Parquet rows as the serial run, a corrupt file is reported by name
and the others still run, and the records path agrees with the one-file replay (geoloc.workflows.replay,
which reads the CSV row by row through geoloc.io.records) and with the surveyed truth."""

import csv
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq
import pytest

from geoloc.cli import main
from geoloc.status import Status
from geoloc.surfaces.spec import SurfaceSpec
from geoloc.workflows.campaign import CampaignConfig, campaign_units, run_campaign

ROOT = Path(__file__).resolve().parents[2]
KLV = ROOT / "assets" / "klv" / "example_flight.klv"
TURRET = ROOT / "assets" / "records" / "eo_turret_flight.csv"
SENSOR = ROOT / "assets" / "sensors" / "eo_turret.toml"
SRTM = ROOT / "assets" / "dem" / "srtm_jacksboro.tif"


def assert_same_tables(a: pa.Table, b: pa.Table):
    """Column by column, NaN-aware (NaN == NaN; Table.equals says NaN != NaN)."""
    assert a.schema.names == b.schema.names and a.num_rows == b.num_rows
    for name in a.schema.names:
        x, y = a.column(name).to_numpy(zero_copy_only=False), b.column(name).to_numpy(zero_copy_only=False)
        if x.dtype.kind == "f":
            assert np.array_equal(x, y, equal_nan=True), name
        else:
            assert list(x) == list(y), name


@pytest.fixture(scope="module")
def klv_folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("klv")
    for k in range(3):
        shutil.copy(KLV, d / f"flight_{k}.klv")
    (d / "corrupt.klv").write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    (d / "README.txt").write_text("not a flight")  # left out with a note
    return d


def test_klv_folder_local_cluster_equals_serial(klv_folder, tmp_path):
    serial = run_campaign([klv_folder], tmp_path / "serial", scheduler="none")
    import psutil

    listening = []  # every socket this process listens on while the local cluster runs

    def spy(unit):
        listening.extend(c.laddr.ip for c in psutil.Process().net_connections("inet") if c.status == "LISTEN")

    dist = run_campaign([klv_folder], tmp_path / "dask", scheduler="local", workers=2, processes=False, on_unit=spy)
    assert listening and set(listening) == {"127.0.0.1"}  # house rule: servers bind 127.0.0.1
    for r in (serial, dist):
        assert r.kind == "klv" and r.rows == 3 * 299  # 299 good packets per copy (docs/klv.md)
        assert [Path(u.source).name for u in r.failed] == ["corrupt.klv"]
        assert any("corrupt.klv" in m and "no good UAS LS packet" in m for m in r.messages)
        assert any("README.txt" in m and "left out" in m for m in r.messages)
    assert_same_tables(serial.table(), dist.table())
    t = serial.table()
    assert sorted(set(t.column("source").to_pylist())) == ["flight_0.klv", "flight_1.klv", "flight_2.klv"]
    # each file's rows are the one-file replay's (geoloc.workflows.klv_replay), order and values
    from geoloc.workflows.klv_replay import replay_klv

    one = replay_klv(klv_folder / "flight_1.klv").columns
    rows = t.filter(pa.compute.equal(t.column("source"), "flight_1.klv"))
    assert np.array_equal(rows.column("lat_deg").to_numpy(), one["lat_deg"], equal_nan=True)
    assert rows.column("status").to_pylist() == one["status"].tolist()


@pytest.fixture(scope="module")
def turret_parquet(tmp_path_factory):
    """The turret flight as a partitioned Parquet (hive layout, 3 partitions), one row made bad."""
    d = tmp_path_factory.mktemp("records") / "flight.parquet"
    t = pcsv.read_csv(TURRET)
    lat = t.column("ac_lat_deg").to_numpy().copy()
    lat[5] = np.nan  # row 5 (point 6): no aircraft latitude
    t = t.set_column(t.schema.get_field_index("ac_lat_deg"), "ac_lat_deg", pa.array(lat))
    for k in range(3):
        (d / f"part={k}").mkdir(parents=True)
        pq.write_table(t.slice(8 * k, 8), d / f"part={k}" / "data.parquet")
    return d


def test_parquet_records_local_cluster_equals_serial(turret_parquet, tmp_path):
    cfg = CampaignConfig(sensor=str(SENSOR), surface=SurfaceSpec(dem=str(SRTM)))
    kind, units, _ = campaign_units([turret_parquet])
    assert kind == "records" and len(units) == 3
    serial = run_campaign([turret_parquet], tmp_path / "serial", cfg, scheduler="none")
    # worker threads (processes=False): fast to start; the units still go through the scheduler
    # (benchmarks/bench_campaign.py runs worker processes)
    dist = run_campaign([turret_parquet], tmp_path / "dask", cfg, scheduler="local", workers=2, processes=False)
    a, b = serial.table(), dist.table()
    assert_same_tables(a, b)
    assert a.num_rows == 24 and not serial.failed
    st = a.column("status").to_numpy()
    assert st[5] == Status.INVALID_INPUT and np.isnan(a.column("lat_deg").to_numpy()[5])
    assert any("part=0" in m and "ac_lat_deg" in m and "first row 5" in m for m in serial.messages)
    assert set(st[np.arange(24) != 5].tolist()) == {Status.OK}
    assert set(a.column("h_datum").to_pylist()) == {"ellipsoid (WGS 84)"}


def test_records_agree_with_one_file_replay_and_truth(turret_parquet, tmp_path):
    # the oracle path: geoloc replay on the CSV (rows through geoloc.io.records, the terrain hook)
    out = tmp_path / "one.csv"
    assert main(["replay", str(TURRET), "--sensor", str(SENSOR), "--dem", str(SRTM), "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    res = run_campaign(
        [turret_parquet],
        tmp_path / "c",
        CampaignConfig(sensor=str(SENSOR), surface=SurfaceSpec(dem=str(SRTM))),
        scheduler="none",
    )
    t = res.table()
    good = np.arange(24) != 5
    lat = np.array([float(r["lat_deg"]) for r in rows])
    lon = np.array([float(r["lon_deg"]) for r in rows])
    h = np.array([float(r["h_m"]) for r in rows])
    # 1e-8 deg and 1 mm: the CSV's printed precision (".8f", ".3f")
    assert np.max(np.abs(t.column("lat_deg").to_numpy()[good] - lat[good])) < 1e-8
    assert np.max(np.abs(t.column("lon_deg").to_numpy()[good] - lon[good])) < 1e-8
    assert np.max(np.abs(t.column("h_m").to_numpy()[good] - h[good])) < 1e-3
    # docs/sensors.md: mean error to the surveyed truth 22.87 m over the 24 records (pyproj geodesic)
    from pyproj import Geod

    d = Geod(ellps="WGS84").inv(
        t.column("lon_deg").to_numpy()[good],
        t.column("lat_deg").to_numpy()[good],
        t.column("truth_lon_deg").to_numpy()[good],
        t.column("truth_lat_deg").to_numpy()[good],
    )[2]
    assert np.allclose(d, t.column("error_to_truth_m").to_numpy()[good], atol=1e-6)
    e_all = np.array([float(r["error_to_truth_m"]) for r in rows])
    assert abs(d.mean() - e_all[good].mean()) < 1e-3 and round(e_all.mean(), 2) == 22.87  # CSV: 1 mm


def test_cli_campaign(klv_folder, turret_parquet, tmp_path, capsys):
    out = tmp_path / "parts"
    assert main(["replay", str(klv_folder), "--parquet-out", str(out), "--scheduler", "none"]) == 0
    cap = capsys.readouterr()
    assert "campaign (klv): 4 unit(s), 897 rows, 1 failed" in cap.out and "corrupt.klv" in cap.err
    assert len(list(out.glob("part-*.parquet"))) == 3
    # the same folder again: refused, the parts are not mixed
    assert main(["replay", str(klv_folder), "--parquet-out", str(out), "--scheduler", "none"]) == 2
    assert "already holds 3 part file(s)" in capsys.readouterr().err
    # a folder without --parquet-out: told what to do
    assert main(["replay", str(klv_folder)]) == 2
    assert "--parquet-out" in capsys.readouterr().err
    # records with a target height instead of a DEM, and a local cluster from the command line
    out2 = tmp_path / "rec"
    assert (
        main(
            [
                "replay",
                str(turret_parquet),
                "--sensor",
                str(SENSOR),
                "--target-h-m",
                "600",
                "--parquet-out",
                str(out2),
                "--workers",
                "2",
            ]
        )
        == 0
    )
    t = pa.concat_tables([pq.read_table(p) for p in sorted(out2.glob("*.parquet"))])
    assert t.num_rows == 24 and np.allclose(
        t.column("h_m").to_numpy()[np.arange(24) != 5], 600, atol=0.02
    )  # inflated [Q17 eq. 11]: mm


def test_the_campaign_surface_is_the_verbs_spec_and_crosses_to_workers(tmp_path):
    """``replay --parquet-out``'s surface is ``surface_spec_from_args`` of its options (as every verb's);
    it pickles, and a worker's build hits the rays where the one-file verb's surface does."""
    import pickle

    from geoloc.cli import build_parser
    from geoloc.cli._options import surface_from_args, surface_spec_from_args
    from geoloc.surfaces.base import LineOfSight

    args = build_parser().parse_args(
        [
            "replay",
            str(TURRET),
            "--dem",
            str(SRTM),
            "--dem",
            str(SRTM),
            "--method",
            "bisect",
            "--threshold",
            "0.5",
            "--parquet-out",
            str(tmp_path),
        ]
    )
    spec = surface_spec_from_args(args)
    assert spec == SurfaceSpec(
        dem=(str(SRTM), str(SRTM)), method="bisect", eps_h=1.0, threshold=0.5, cache_bytes=64 * 2**20
    )
    back = pickle.loads(pickle.dumps(CampaignConfig(surface=spec)))
    assert back.surface == spec and hash(back.surface) == hash(spec)
    # a ray down from 3 km over the DEM: the worker's build and the verb's own surface agree exactly
    from geoloc.geodesy.ellipsoid import geodetic_to_ecef

    lat, lon = np.deg2rad(36.59), np.deg2rad(-84.25)
    o = np.asarray(geodetic_to_ecef(lat, lon, 3000.0), float)
    los = LineOfSight(o[None], (-o / np.linalg.norm(o))[None], np.zeros(1, np.uint8))
    a, b = back.surface.build().intersect(los), surface_from_args(args).intersect(los)
    assert np.isfinite(a.h).all() and np.array_equal(a.h, b.h) and np.array_equal(a.lat, b.lat)
    with pytest.raises(TypeError, match="SurfaceSpec"):
        CampaignConfig(surface=back.surface.build())


# --------------------------------------------------------------------------- worker processes, malloc
_FAULTS = r"""
import resource, sys
import numpy as np
if sys.argv[1] == "tune":
    from geoloc.workflows.campaign import set_malloc_thresholds
    assert set_malloc_thresholds()
def faults(n, nbytes=2**20):  # 1 MiB: above glibc's first mmap threshold (128 KiB), below numpy's hugepage size
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        a = np.ones(nbytes // 8)  # every page touched
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
faults(5)
print(faults(50))
"""


def _minor_faults(mode: str, env: dict) -> int:
    import os
    import subprocess
    import sys

    e = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"} | env
    out = subprocess.run([sys.executable, "-c", _FAULTS, mode], env=e, capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="glibc malloc")
def test_dask_malloc_environment_faults_every_array_and_the_tuning_undoes_it():
    # Oracle: the kernel's minor page-fault counter (getrusage). 50 arrays of 1 MiB = 256 pages each.
    pages = 2**20 // 4096
    # as distributed starts its workers: each array a fresh mmap, all its pages faulted (the control:
    # it shows the counter sees the effect; >= 40 of the 50 arrays, not all, for page-size noise)
    assert _minor_faults("plain", {"MALLOC_TRIM_THRESHOLD_": "65536"}) >= 40 * pages
    # the same environment after set_malloc_thresholds: the heap's pages are reused; at most 5 arrays'
    # worth of faults (glibc's first extension of the heap and its own bookkeeping)
    assert _minor_faults("tune", {"MALLOC_TRIM_THRESHOLD_": "65536"}) <= 5 * pages
    assert _minor_faults("plain", {}) <= 5 * pages  # a plain process: glibc's dynamic threshold does the same


def test_records_on_worker_processes_equal_serial(turret_parquet, tmp_path):
    """The benchmark's configuration (worker processes, run_campaign's local cluster): the serial rows, and
    in every worker the malloc thresholds set, no profiler, servers on 127.0.0.1."""
    from dask.distributed import Client

    from geoloc.workflows.campaign import local_cluster

    cfg = CampaignConfig(sensor=str(SENSOR), surface=SurfaceSpec(dem=str(SRTM)))
    serial = run_campaign([turret_parquet], tmp_path / "serial", cfg, scheduler="none")
    with local_cluster(2, 1, processes=True) as cl, Client(cl) as client:
        dist = run_campaign([turret_parquet], tmp_path / "dask", cfg, scheduler=cl.scheduler_address)
        assert_same_tables(serial.table(), dist.table())
        assert not dist.failed and dist.rows == 24

        def state(dask_worker):
            import os
            import resource

            import numpy as np

            from geoloc.workflows import campaign

            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            for _ in range(50):
                a = np.ones(2**17)  # 1 MiB, every page touched
                del a
            return (
                campaign._MALLOC["tuned"],
                "MALLOC_TRIM_THRESHOLD_" in os.environ,
                resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0,
                "profile" in dask_worker.periodic_callbacks,
            )

        states = client.run(state)
        assert len(states) == 2 and all(a.startswith("tcp://127.0.0.1:") for a in states)
        for tuned, env_set, faults, profiler in states.values():
            assert tuned == env_set  # tuned wherever distributed set MALLOC_TRIM_THRESHOLD_ (its default)
            assert faults <= 5 * 256  # kernel counter: 50 x 256 pages without the tuning (test above)
            assert not profiler
        # another scheduler's workers keep their numba setting (NUMBA_NUM_THREADS, default: every core)
        import numba

        assert {u.numba_threads for u in dist.units} == {numba.config.NUMBA_NUM_THREADS}
    # run_campaign's own local cluster (worker processes): the same rows, and the cores shared out to the
    # units' parallel kernels, 2 workers x 1 thread: cores // 2 numba threads each (not one per core each)
    import os

    local = run_campaign([turret_parquet], tmp_path / "local", cfg, scheduler="local", workers=2, processes=True)
    assert_same_tables(serial.table(), local.table())
    want = min(max(1, len(os.sched_getaffinity(0)) // 2), numba.config.NUMBA_NUM_THREADS)
    assert [u.numba_threads for u in local.units] == [want] * 3


def test_local_cluster_refuses_bad_sizes():
    from geoloc.workflows.campaign import local_cluster

    with pytest.raises(ValueError, match="workers must be a positive integer, got 0"):
        local_cluster(0)
    with pytest.raises(ValueError, match="threads_per_worker must be a positive integer, got 1.5"):
        local_cluster(2, 1.5)


def test_numba_threads_serial_is_the_units_and_restored(turret_parquet, tmp_path):
    import numba

    before = numba.get_num_threads()
    cfg = CampaignConfig(sensor=str(SENSOR), surface=SurfaceSpec(dem=str(SRTM)))
    res = run_campaign([turret_parquet], tmp_path / "one", cfg, scheduler="none", numba_threads=1)
    assert [u.numba_threads for u in res.units] == [1, 1, 1] and numba.get_num_threads() == before
    auto = run_campaign([turret_parquet], tmp_path / "auto", cfg, scheduler="none")  # serial "auto": the caller's
    assert {u.numba_threads for u in auto.units} == {before}
    assert_same_tables(res.table(), auto.table())
    with pytest.raises(ValueError, match="numba_threads must be 'auto', a positive integer or None, got 0"):
        run_campaign([turret_parquet], tmp_path / "bad", cfg, scheduler="none", numba_threads=0)
