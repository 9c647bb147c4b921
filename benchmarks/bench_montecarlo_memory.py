"""Peak memory of the Monte Carlo against the sample count: flat when the statistics stream.

Each N runs in a fresh subprocess (so one run's peak cannot hide another's):
``geoloc.analysis.montecarlo.run`` on the [Q17] Table 1-2 scenario (ellipsoid model)
with the default chunk, samples not kept (the command line's mode). The child
reports

* ``peak_py``: the peak of the memory Python and numpy allocated during the run
  (``tracemalloc``; numpy reports its buffers to it);
* ``maxrss``: the process's peak resident set (``resource.getrusage``), which
  includes the interpreter, numpy, numba and the other libraries (about 200 MB
  before any sample is drawn);
* CPU and wall time of the run.

With ``--keep`` the same runs keep every sample (the behaviour before
streaming, 25 bytes a sample) for contrast.

Run: ``python benchmarks/bench_montecarlo_memory.py [--quick] [--keep] [--max 1e7]``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

CHILD = r"""
import json, resource, sys, time, tracemalloc
import numpy as np
from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import asset_path

n, keep = int(sys.argv[1]), sys.argv[2] == "1"
model = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
mc.run(model, 1000, np.random.default_rng(1))  # warm-up: imports, first calls
base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
tracemalloc.start()
c0, w0 = time.process_time(), time.perf_counter()
res = mc.run(model, n, np.random.default_rng(0), keep_samples=keep)
cpu, wall = time.process_time() - c0, time.perf_counter() - w0
_, peak = tracemalloc.get_traced_memory()
tracemalloc.stop()
print(json.dumps(dict(n=n, peak_py=peak, maxrss_kb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                      base_rss_kb=base_rss, cpu=cpu, wall=wall, streamed=res.streamed,
                      cep50=res.stats["cep50_empirical_m"], cep=res.stats["cep_m"])))
"""


def measure(n: int, keep: bool) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(n), "1" if keep else "0"], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    quick = "--quick" in argv
    keep = "--keep" in argv
    top = 1e6 if quick else 1e7
    if "--max" in argv:
        top = float(argv[argv.index("--max") + 1])
    ns = [n for n in (10_000, 100_000, 1_000_000, 10_000_000, 100_000_000) if n <= top]
    t0 = time.perf_counter()
    rows = []
    print(
        f"{'N':>11} {'mode':>8} {'peak_py MB':>11} {'maxrss MB':>10} {'rss before MB':>14} "
        f"{'cpu s':>8} {'wall s':>8} {'us/sample':>10}"
    )
    for mode in ["streamed", "kept"] if keep else ["streamed"]:
        for n in ns:
            if mode == "kept" and n > 2_000_000:  # montecarlo.KEEP_MAX: more is refused
                continue
            r = measure(n, mode == "kept")
            rows.append((mode, r))
            print(
                f"{n:>11} {mode:>8} {r['peak_py'] / 1e6:11.1f} {r['maxrss_kb'] / 1e3:10.1f} "
                f"{r['base_rss_kb'] / 1e3:14.1f} {r['cpu']:8.2f} {r['wall']:8.2f} "
                f"{r['wall'] / n * 1e6:10.2f}",
                flush=True,
            )
    st = [r for m, r in rows if m == "streamed"]
    big = [r for r in st if r["n"] >= 100_000]
    if len(big) >= 2:
        ratio = max(r["peak_py"] for r in big) / min(r["peak_py"] for r in big)
        print(
            f"streamed peak_py, largest / smallest over N = {big[0]['n']}..{big[-1]['n']}: "
            f"ratio: {ratio:.2f}  (flat = 1; the samples alone would grow "
            f"{big[-1]['n'] / big[0]['n']:.0f}x)"
        )
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
