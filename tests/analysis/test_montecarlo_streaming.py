"""Monte Carlo in bounded memory: chunked evaluation and streamed statistics.

The streamed statistics (geoloc.analysis.streaming.StreamingStats) against the exact ones of
geoloc.analysis.montecarlo.statistics on the same samples; one chunk gives today's numbers
exactly; the progress line; the refusal to keep too many samples.
"""

import io
import math

import numpy as np
import pytest

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.analysis.streaming import StreamingStats
from geoloc.assets import asset_path
from geoloc.cli import main
from geoloc.status import Status

SCEN = asset_path("scenarios", "qiao2017_table1.toml")
EXACT_KEYS = ("mean_lat_deg", "mean_lon_deg", "mean_h_m", "std_lat_deg", "std_lon_deg", "std_h_m", "cep_m")


@pytest.fixture(scope="module")
def model():
    return ErrorModel.from_toml(SCEN)


def test_one_chunk_gives_the_same_numbers_as_keeping_the_samples(model):
    a = mc.run(model, 5000, np.random.default_rng(0))  # samples kept
    b = mc.run(model, 5000, np.random.default_rng(0), keep_samples=False)  # one chunk
    assert a.lat is not None and b.lat is None and not b.streamed
    assert a.stats == b.stats
    assert b.status_counts[Status.OK] == 5000


def test_streamed_statistics_equal_the_exact_ones_on_the_same_samples(model):
    kw = dict(chunk=20_000)
    ex = mc.run(model, 100_000, np.random.default_rng(5), **kw)  # kept: exact
    st = mc.run(model, 100_000, np.random.default_rng(5), keep_samples=False, **kw)
    assert st.streamed and st.lat is None
    for k in EXACT_KEYS:  # pairwise merging: the same numbers to rounding
        assert st.stats[k] == pytest.approx(ex.stats[k], rel=1e-9, abs=1e-12), k
    # the 50 % radius from the histogram: 1e-4 of it in practice (sampling error 3e-3 here)
    assert st.stats["cep50_empirical_m"] == pytest.approx(ex.stats["cep50_empirical_m"], rel=1e-3)
    assert st.stats["n_ok"] == ex.stats["n_ok"] == 100_000 and st.stats["warnings"] == []
    # the covariance in local metres: its horizontal trace is eq. 18 squared
    cov = np.array(st.stats["cov_neu_m2"])
    assert math.sqrt(cov[0, 0] + cov[1, 1]) == pytest.approx(st.stats["cep_m"], rel=1e-9)
    assert math.sqrt(cov[2, 2]) == pytest.approx(st.stats["std_h_m"], rel=1e-9)


def _cloud(rng, n, corr, lon0=80.85, sigma=1e-5):
    z = rng.standard_normal((n, 2))
    a, b = z[:, 0], corr * z[:, 0] + math.sqrt(1 - corr**2) * z[:, 1]
    lat = np.deg2rad(35.57) + sigma * a
    lon = np.deg2rad(lon0) + 1.3 * sigma * b
    lon = (lon + np.pi) % (2 * np.pi) - np.pi
    return lat, lon, 5000 + 60 * rng.standard_normal(n)


@pytest.mark.parametrize("corr", [0.0, 0.9])
def test_histogram_median_against_the_exact_one(corr):
    rng = np.random.default_rng(11)
    lat, lon, h = _cloud(rng, 1_000_000, corr)
    ex = mc.statistics(lat, lon, h)
    acc = StreamingStats()
    for a in range(0, lat.size, 100_000):
        acc.add(lat[a : a + 100_000], lon[a : a + 100_000], h[a : a + 100_000])
    s = acc.result()
    for k in EXACT_KEYS:
        assert s[k] == pytest.approx(ex[k], rel=1e-12, abs=1e-12), k
    # documented accuracy (geoloc/analysis/streaming.py, docs/montecarlo.md): about 1e-4 of
    # the radius; bound: half a cell diagonal, 0.011 sigma
    rel = abs(s["cep50_empirical_m"] / ex["cep50_empirical_m"] - 1)
    assert rel < 3e-4, rel


def test_longitude_across_the_antimeridian_and_merge():
    rng = np.random.default_rng(2)
    lat, lon, h = _cloud(rng, 200_000, 0.3, lon0=179.9999)
    assert lon.min() < 0 < lon.max()  # the cloud straddles +-180 deg
    ex = mc.statistics(lat, lon, h)
    a, b = StreamingStats(), StreamingStats()
    a.add(lat[:50_000], lon[:50_000], h[:50_000])
    b.ref, b.grid, b.hist = a.ref, a.grid, np.zeros_like(a.hist)  # same reference and grid
    b.add(lat[50_000:], lon[50_000:], h[50_000:])
    a.merge(b)
    s = a.result()
    for k in EXACT_KEYS:
        assert s[k] == pytest.approx(ex[k], rel=1e-9, abs=1e-9), k
    assert s["cep50_empirical_m"] == pytest.approx(ex["cep50_empirical_m"], rel=1e-3)


def test_failed_samples_are_counted_by_status(tmp_path, capsys):
    # every sample sky, streamed over three chunks: exit 1 and the count per status
    text = SCEN.read_text().replace("gimbal_roll_deg = 50.0", "gimbal_roll_deg = 95.0")
    scen = tmp_path / "sky.toml"
    scen.write_text(text)
    assert main(["montecarlo", str(scen), "--samples", "300", "--chunk", "100"]) == 1
    assert "sky: 300" in capsys.readouterr().err


def test_progress_line_has_the_time_left(model, capsys):
    buf = io.StringIO()
    bar = mc.Progress(4, "x", enabled=True, stream=buf)
    bar.update(1)
    bar.update(3)
    bar.close()
    assert "left" in buf.getvalue() and "100.0%" in buf.getvalue()
    # the CLI: stderr only, with --progress (or a terminal)
    assert main(["montecarlo", str(SCEN), "--samples", "3000", "--chunk", "1000", "--progress"]) == 0
    cap = capsys.readouterr()
    assert "left" in cap.err and "left" not in cap.out
    assert main(["montecarlo", str(SCEN), "--samples", "3000", "--chunk", "1000"]) == 0
    assert "left" not in capsys.readouterr().err  # not a terminal, not asked


def test_keeping_too_many_samples_is_refused(model):
    with pytest.raises(ValueError, match="stream them"):
        mc.run(model, mc.KEEP_MAX + 1, np.random.default_rng(0), keep_samples=True)
    with pytest.raises(ValueError, match="samples"):
        mc.run(model, 1, np.random.default_rng(0))


def test_sweep_streams_beyond_one_chunk(model):
    # 1000 samples x 2 sigmas per angle with chunks of 500: streamed, same distribution
    a = mc.sweep_terrain_sigma(model, [30.0, 70.0], [10.0, 100.0], 1000, np.random.default_rng(0))
    b = mc.sweep_terrain_sigma(model, [30.0, 70.0], [10.0, 100.0], 1000, np.random.default_rng(0), chunk=500)
    assert (a.n_ok == 1000).all() and (b.n_ok == 1000).all()
    assert np.allclose(a.cep_m, b.cep_m, rtol=0.1)
