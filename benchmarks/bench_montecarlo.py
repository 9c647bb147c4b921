"""Benchmark of the vectorised Monte Carlo (geoloc.analysis.montecarlo) on the [Q17] Table 1-2 scenario.

Goals (medians on the 2-core machine):
* N = 5000 with a DEM (target on the bundled ETOPO5 crop) <= 0.5 s;
* 1 M samples on the ellipsoid <= 30 s.

Peer, measured in the same run: the same Monte Carlo done by a per-sample
Python loop (one :func:`geoloc.analysis.montecarlo.evaluate` call per sample, i.e. one
scalar trip through the core chain per sample) over a subset of samples,
scaled linearly to the full N. The final ``ratio:`` line is
(peer time scaled to 1 M samples) / (vectorised time for 1 M samples), i.e. the
speed-up of vectorisation; > 1 means the vectorised path is faster.

Run: ``python benchmarks/bench_montecarlo.py [--quick]``.
"""

from __future__ import annotations

import statistics as st
import sys
import time

import numpy as np

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import asset_path


def median_time(fn, repeat):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return st.median(ts), ts


def per_sample_loop(model, n, rng, surface=None):
    """The peer: one core call per sample (what a non-vectorised tool does)."""
    errs = model.sample(n, rng)
    out = np.empty((n, 3))
    for i in range(n):
        one = {k: v[i : i + 1] for k, v in errs.items()}
        lat, lon, h, _ = mc.evaluate(model, one, surface)
        out[i] = lat[0], lon[0], h[0]
    return out


def main(argv=None):
    quick = "--quick" in (argv if argv is not None else sys.argv[1:])
    model = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1.toml"))
    n_big = 200_000 if quick else 1_000_000
    rep = 1 if quick else 3

    t5k, _ = median_time(lambda: mc.run(model, 5000, np.random.default_rng(0)), 5)
    print(f"ellipsoid N = 5000: median {t5k:.3f} s over 5 runs")

    tbig, ts = median_time(lambda: mc.run(model, n_big, np.random.default_rng(0), progress=None), rep)
    print(
        f"ellipsoid N = {n_big}: median {tbig:.2f} s over {rep} runs "
        f"({', '.join(f'{t:.2f}' for t in ts)}); goal <= 30 s for 1 M"
    )

    from geoloc.cli._options import surface_from_scenario

    try:
        dmodel = ErrorModel.from_toml(asset_path("scenarios", "qiao2017_table1_dem.toml"))
        dem = surface_from_scenario(dmodel)  # the scenario's [dem] table as a Surface, as the verb does
    except (ImportError, FileNotFoundError) as e:
        dmodel = dem = None
        print(f"DEM: not benchmarked ({e})")
    if dem is not None:
        t = time.perf_counter()
        mc.run(dmodel, 10, np.random.default_rng(0), surface=dem)
        print(
            f"DEM warm-up (numba kernels of geoloc.surfaces.terrain: compiled or loaded from cache): "
            f"{time.perf_counter() - t:.2f} s, not counted"
        )
        tdem, ts = median_time(lambda: mc.run(dmodel, 5000, np.random.default_rng(0), surface=dem), 5)
        print(f"DEM N = 5000: median {tdem:.3f} s over 5 runs ({', '.join(f'{t:.3f}' for t in ts)}); goal <= 0.5 s")
        n_peer = 100
        tp, _ = median_time(lambda: per_sample_loop(dmodel, n_peer, np.random.default_rng(1), dem), 1)
        print(
            f"DEM peer (per-sample loop): {tp / n_peer * 1e3:.2f} ms per sample -> "
            f"{tp / n_peer * 5000:.1f} s for N = 5000 (speed-up {tp / n_peer * 5000 / tdem:.0f}x)"
        )

    n_peer = 500 if quick else 2000
    tp, _ = median_time(lambda: per_sample_loop(model, n_peer, np.random.default_rng(1)), 1)
    per = tp / n_peer
    peer_big = per * n_big
    print(
        f"ellipsoid peer (per-sample Python loop over {n_peer} samples): {per * 1e6:.0f} us per "
        f"sample -> {peer_big:.1f} s scaled to N = {n_big}"
    )
    print(f"ratio: {peer_big / tbig:.1f}")


if __name__ == "__main__":
    main()
