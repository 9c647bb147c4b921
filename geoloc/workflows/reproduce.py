"""Reproduction reports: the papers' published numbers beside the project's.

* :func:`qiao2017_report`: [Q17] Table 1 nominal point, Monte Carlo standard
  deviations (ellipsoid and DEM), flight-test positions and errors (Tables 3-4),
  Fig. 10 trend.
* :func:`li2023_report`: [L23] iteration saving of bisection on the target
  elevation against [Q17]'s descending steps.

Every paper number printed here is quoted from the paper (docs/method.md section 8);
every project number is computed at run time. Conventions: ``docs/conventions.md``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import DEFAULT_CAMERA, DEFAULT_RECORDS, asset_path
from geoloc.pipeline import Pipeline
from geoloc.sensors.camera import camera_from_sensor
from geoloc.sensors.sensor_file import load_sensor
from geoloc.surfaces.base import LineOfSight, terrain_of
from geoloc.workflows.scenario import load_scenario

if TYPE_CHECKING:
    from geoloc.surfaces.base import Surface

#: Bundled scenario of [Q17] Tables 1-2 (ellipsoid model).
Q17_SCENARIO = ("scenarios", "qiao2017_table1.toml")
#: The same with the target on the bundled ETOPO5 crop of the flight-test area.
Q17_DEM_SCENARIO = ("scenarios", "qiao2017_table1_dem.toml")

#: [Q17] section 3.2 (quoted).
Q17_NOMINAL_DEG = (35.57709, 80.84918)
Q17_STD_ELLIPSOID = (0.00048, 0.00060, 62.3)  # lat deg, lon deg, h m
Q17_STD_DEM = (0.00015, 0.00013, 3.58)  # with ASTER GDEM
Q17_DEM_TARGET_DEG = (35.57704, 80.84923, 5087.9)
#: [Q17] section 4: mean error per flight (Tables 3, 4, 5) [m].
Q17_MEAN_ERROR = {"T3": 50.246, "T4": 50.485, "T5": 59.972}
#: [Q17] Fig. 10b text: CEP < 50 m for frame roll < 70 deg, < 180 m at 80 deg.
Q17_FIG10B = ((70.0, 50.0), (80.0, 180.0))


@dataclass
class Report:
    """Lines of text plus the key numbers (for tests and JSON)."""

    lines: list = field(default_factory=list)
    numbers: dict = field(default_factory=dict)

    def add(self, *lines: str) -> None:
        self.lines.extend(lines)

    def text(self) -> str:
        return "\n".join(self.lines)


def _pct(ours, paper):
    return f"{100.0 * (ours - paper) / paper:+6.1f} %"


def load_q17_model() -> ErrorModel:
    return load_scenario(asset_path(*Q17_SCENARIO), expect="montecarlo")


def load_q17_dem_model() -> ErrorModel:
    """The [Q17] Table 1-2 scenario with the target on the bundled ETOPO5 crop: its ``[dem]``
    table names the DEM, which the caller opens once (``geoloc.cli._options.surface_from_scenario``)."""
    return load_scenario(asset_path(*Q17_DEM_SCENARIO), expect="montecarlo")


def dem_scenario_available() -> bool:
    """True when the bundled DEM scenario is there (a trimmed install may leave it out)."""
    try:
        return asset_path(*Q17_DEM_SCENARIO).exists()
    except FileNotFoundError:
        return False


def qiao2017_report(
    samples: int = 5000,
    seed: int = 0,
    sweep_samples: int = 2000,
    surface: Surface | None = None,
    progress: bool | None = False,
) -> Report:
    """[Q17] side by side with the project.

    Parameters
    ----------
    samples : int
        Monte Carlo N (the paper's 5000).
    seed : int
    sweep_samples : int
        Samples per point of the Fig. 10 trend.
    surface : Surface, optional
        The DEM of :func:`load_q17_dem_model`'s ``[dem]`` table, built once by the caller
        (``geoloc.cli._options.surface_from_scenario(load_q17_dem_model())``, as
        ``geoloc reproduce qiao2017`` does): the DEM parts run on it; None skips them.
    """
    rep = Report()
    model = load_q17_model()
    rng = np.random.default_rng(seed)
    dmodel = load_q17_dem_model() if surface is not None else None
    _q17_nominal(rep, model)
    _q17_monte_carlo(rep, model, samples, seed, rng, progress)
    _q17_monte_carlo_dem(rep, dmodel, samples, seed, surface, progress)
    _q17_flight_test(rep)
    _q17_fig10(rep, model, dmodel, sweep_samples, rng, surface, progress)
    return rep


def _q17_nominal(rep: Report, model) -> None:
    """Section 1: the Table 1 nominal target (CCD centre, ellipsoid inflated to h_T)."""
    lat, lon, h, _ = mc.nominal_point(model)
    la, lo = math.degrees(lat), math.degrees(lon)
    rep.numbers.update(nominal_lat_deg=la, nominal_lon_deg=lo, nominal_h_m=h)
    rep.add(
        "[Q17] Qiao et al. 2017 -- paper vs geoloc",
        "",
        "1. Table 1 nominal target (CCD centre, ellipsoid inflated to h_T = 5083.5 m)",
        f"   paper   {Q17_NOMINAL_DEG[0]:.5f} N  {Q17_NOMINAL_DEG[1]:.5f} E",
        f"   geoloc  {la:.5f} N  {lo:.5f} E   ({la:.7f}, {lo:.7f}; h {h:.3f} m)",
        "",
    )


def _q17_monte_carlo(rep: Report, model, samples: int, seed: int, rng, progress) -> None:
    """Section 2: the Tables 1-2 Monte Carlo on the ellipsoid model, beside the first order."""
    res = mc.run(model, samples, rng, progress=progress)
    s = res.stats
    fo = mc.first_order(model)
    rep.numbers.update({f"mc_{k}": v for k, v in s.items()})
    rep.add(
        f"2. Monte Carlo, Tables 1-2, ellipsoid model, terrain sigma 62.47 m, N = {samples}, seed {seed}",
        f"   {'':8} {'std lat deg':>12} {'std lon deg':>12} {'std h m':>9}",
        f"   {'paper':8} {Q17_STD_ELLIPSOID[0]:12.5f} {Q17_STD_ELLIPSOID[1]:12.5f} {Q17_STD_ELLIPSOID[2]:9.1f}",
        f"   {'geoloc':8} {s['std_lat_deg']:12.5f} {s['std_lon_deg']:12.5f} {s['std_h_m']:9.1f}"
        f"   ({_pct(s['std_lat_deg'], Q17_STD_ELLIPSOID[0])}, {_pct(s['std_lon_deg'], Q17_STD_ELLIPSOID[1])}, "
        f"{_pct(s['std_h_m'], Q17_STD_ELLIPSOID[2])})",
        f"   {'1st ord.':8} {fo.std_lat_deg:12.5f} {fo.std_lon_deg:12.5f} {fo.std_h_m:9.1f}"
        "   (linear propagation, Jacobian of the chain)",
        f"   CEP [Q17 eq. 18] {s['cep_m']:.1f} m, empirical 50 % radius {s['cep50_empirical_m']:.1f} m "
        "(eq. 18 is a radial RMS; see docs/montecarlo.md)",
        "",
    )


def _q17_monte_carlo_dem(rep: Report, dmodel, samples: int, seed: int, surface, progress) -> None:
    """Section 3: the Monte Carlo on the DEM scenario (its own generator, seeded alike); skipped
    without a DEM surface."""
    if dmodel is None:
        rep.add(
            "3. Monte Carlo with a DEM: skipped (no DEM surface given: --no-dem, or the bundled DEM "
            "scenario is not installed)",
            "",
        )
        return
    dres = mc.run(dmodel, samples, np.random.default_rng(seed), surface=surface, progress=progress)
    ds = dres.stats
    dlat, dlon, dh, _ = dres.nominal
    rep.numbers.update({f"mcdem_{k}": v for k, v in ds.items()})
    rep.add(
        f"3. Monte Carlo with a DEM, N = {samples} (paper: ASTER GDEM 30 m; geoloc: bundled "
        "ETOPO5 5' crop, so the terrain and its slopes differ)",
        f"   {'':8} {'target':>24} {'h m':>8} {'std lat deg':>12} {'std lon deg':>12} {'std h m':>8}",
        f"   {'paper':8} {Q17_DEM_TARGET_DEG[0]:10.5f} N {Q17_DEM_TARGET_DEG[1]:10.5f} E "
        f"{Q17_DEM_TARGET_DEG[2]:8.1f} {Q17_STD_DEM[0]:12.5f} {Q17_STD_DEM[1]:12.5f} {Q17_STD_DEM[2]:8.2f}",
        f"   {'geoloc':8} {math.degrees(dlat):10.5f} N {math.degrees(dlon):10.5f} E "
        f"{dh:8.1f} {ds['std_lat_deg']:12.5f} {ds['std_lon_deg']:12.5f} {ds['std_h_m']:8.2f}",
        f"   CEP [Q17 eq. 18] {ds['cep_m']:.1f} m, empirical 50 % radius "
        f"{ds['cep50_empirical_m']:.1f} m; {ds['n_failed']} samples without a terrain hit",
        "",
    )


def _q17_flight_test(rep: Report) -> None:
    """Section 4: the Tables 3-4 flight tests replayed at each point's published height, per flight."""
    from geoloc.io.records import load_records
    from geoloc.workflows.replay import replay_at_height

    records = load_records(asset_path(*DEFAULT_RECORDS))
    camera = load_sensor(asset_path(*DEFAULT_CAMERA))
    rr = replay_at_height(records, camera, "paper_height_m")
    tables = records.text("table")
    rep.add(
        "4. Flight test (Tables 3-4; fitted camera assets/cameras/qiao2017.toml, target at "
        "each point's published height)",
        f"   {'flight':6} {'n':>3} {'mean error to truth m':>22} {'published mean m':>17} "
        f"{'RMS to published position m':>28}",
    )
    for t in sorted(set(tables)):
        m = np.array([x == t for x in tables])
        mean_err = float(np.nanmean(rr.error_to_truth_m[m]))
        rms_pub = float(np.sqrt(np.nanmean(rr.error_to_paper_m[m] ** 2)))
        rep.numbers[f"flight_{t}_mean_error_m"] = mean_err
        rep.numbers[f"flight_{t}_rms_to_paper_m"] = rms_pub
        rep.add(f"   {t:6} {int(m.sum()):3d} {mean_err:22.2f} {Q17_MEAN_ERROR.get(t, math.nan):17.3f} {rms_pub:28.2f}")
    rms_all = float(np.sqrt(np.nanmean(rr.error_to_paper_m**2)))
    rep.numbers["flight_rms_to_paper_m"] = rms_all
    rep.add(
        f"   all: RMS distance to the published positions {rms_all:.2f} m (published coordinates "
        "are rounded to 1e-5 deg, about 1 m)",
        "   [Q17] Table 5, a third flight at roll gimbal angles of 57-63 deg, is not in the "
        "bundled records (the copy of the paper they come from lacks that table); the paper's "
        f"text gives its mean error to truth, {Q17_MEAN_ERROR['T5']} m",
        "",
    )


def _q17_fig10(rep: Report, model, dmodel, sweep_samples: int, rng, surface, progress) -> None:
    """Section 5: the Fig. 10 trend, CEP against the outer frame angle: (a) on the ellipsoid model
    for three terrain sigmas, (b) on the DEM when there is one; whether it grows as the paper's."""
    angles = np.array([10.0, 30.0, 50.0, 63.0, 70.0, 80.0, 82.0])
    sigmas = np.array([10.0, 62.47, 100.0])
    sw = mc.sweep_terrain_sigma(model, angles, sigmas, sweep_samples, rng, progress)
    rep.numbers["fig10a_cep_m"] = sw.cep_m.tolist()
    head = "   " + f"{'angle':>6}" + "".join(f"{'sigma ' + format(x, 'g') + ' m':>16}" for x in sigmas)
    rep.add(
        f"5. Fig. 10 trend: CEP [Q17 eq. 18] against the outer frame angle, N = {sweep_samples} per point",
        "   (a) ellipsoid model; paper: CEP grows with the angle and with the terrain sigma",
    )
    dsw = None
    if dmodel is not None:
        dsw = mc.sweep_dem(dmodel, angles, sweep_samples, rng, surface=surface, progress=progress)
        rep.numbers["fig10b_cep_m"] = dsw.cep_m[:, 0].tolist()
        head += f"{'DEM (b)':>12}"
    rep.add(head)
    for i, a in enumerate(angles):
        line = f"   {a:6.1f}" + "".join(f"{v:16.1f}" for v in sw.cep_m[i])
        if dsw is not None:
            line += f"{dsw.cep_m[i, 0]:12.1f}"
        rep.add(line)
    mono_a = bool(np.all(np.diff(sw.cep_m, axis=0) > 0))
    mono_s = bool(np.all(np.diff(sw.cep_m, axis=1) > 0))
    rep.numbers.update(fig10a_increasing_with_angle=mono_a, fig10a_increasing_with_sigma=mono_s)
    rep.add(f"   geoloc: CEP increases with the angle: {mono_a}; with the terrain sigma: {mono_s}")
    if dsw is not None:
        c70 = float(np.interp(70.0, angles, dsw.cep_m[:, 0]))
        c80 = float(np.interp(80.0, angles, dsw.cep_m[:, 0]))
        rep.add(
            f"   (b) paper with ASTER GDEM: CEP < 50 m below 70 deg, < 180 m at 80 deg; "
            f"geoloc on ETOPO5: {c70:.1f} m at 70 deg, {c80:.1f} m at 80 deg"
        )


#: [L23] abstract: bisection is 45.5 % more iteration-efficient than stepping.
L23_SAVING_PCT = 45.5


def li2023_report(
    surface: Surface, seed: int = 0, n_rays: int = 100, tolerances_m: Iterable[float] = (10.0, 2.0, 1.0)
) -> Report:
    """[L23] bisection on the target elevation against [Q17]'s descending steps.

    ``surface`` is the DEM of :func:`load_q17_dem_model`'s ``[dem]`` table, built once by the
    caller (``geoloc.cli._options.surface_from_scenario``); its raster is what every solver reads.

    Rays: the [Q17] Table 1-2 geometry with the outer gimbal angle spread
    uniformly over 10-80 deg (Table 1-2 errors sampled on top), plus the 20
    flight-test records, all on the bundled ETOPO5 crop of the flight area.
    For each tolerance t the descending steps use eps_h = t and the bisection
    stops at |H - h_DEM| < t (the same height accuracy); both are compared with
    the exact first hit of :mod:`geoloc.surfaces.terrain`.
    """

    from geoloc.surfaces.dem import DEM
    from geoloc.surfaces.terrain import DemSurface

    dem = terrain_of(surface)
    if not isinstance(dem, DEM):  # the report reads the raster's nodes and file name: no mosaic
        raise ValueError(
            f"li2023_report: surface = {surface!r} has no DEM raster (none, or a mosaic); give the DEM "
            "scenario's surface (geoloc.cli._options.surface_from_scenario(load_q17_dem_model()))"
        )
    rep = Report()
    los, n_records = _l23_rays(seed, n_rays)
    n = len(los.status)
    # the paper's experiment is on the DEM solvers themselves: the same rays through the pipeline
    # with each solver as its surface, no corrections (as [Q17] and [L23])
    exact = Pipeline(None, DemSurface(dem, "exact")).intersect(los)
    rep.add(
        "[L23] Li et al. 2023 -- bisection on the target elevation vs [Q17] descending steps",
        "",
        f"DEM: {dem.path} ({dem.shape[0]}x{dem.shape[1]} nodes, heights {dem.min_height():.0f}-"
        f"{dem.max_height():.0f} m); {n} rays: {n_rays} Table 1-2 rays with the outer gimbal "
        f"angle in 10-80 deg (seed {seed}) + {n_records} flight-test records",
        f"paper: bisection with the threshold at 1/10 of the DEM accuracy is {L23_SAVING_PCT} % "
        "more iteration-efficient than the stepping method",
        "",
        f"{'tol m':>6} {'steps evals':>12} {'bisect evals':>13} {'saving %':>9} {'steps s':>8} "
        f"{'bisect s':>9} {'max dist to exact m (steps/bisect)':>36} {'hidden':>7}",
    )
    for tol in tolerances_m:
        _l23_tolerance(rep, dem, los, exact, tol)
    rep.add(
        "",
        "evals: DEM heights read per ray (mean over rays where all three methods hit); "
        "saving = 1 - bisect/steps evaluations; hidden: bisection answers behind a ridge.",
        "The steps start at the DEM's highest node, so their count grows with (H_max - h)/tol; "
        "bisection grows with log2((H_max - H_min)/tol): the saving depends on the relief and "
        "the tolerance, not on one number.",
    )
    return rep


def _l23_rays(seed: int, n_rays: int) -> tuple[LineOfSight, int]:
    """The [L23] comparison's rays: ``n_rays`` of the [Q17] Table 1-2 geometry with the outer gimbal
    angle uniform over 10-80 deg (the Table 1-2 errors sampled on top), then the flight-test
    records' rays; and the number of records."""
    from geoloc.io.records import load_records
    from geoloc.workflows.replay import records_line_of_sight

    dmodel = load_q17_dem_model()
    rng = np.random.default_rng(seed)
    errs = dmodel.sample(n_rays, rng)
    angles = rng.uniform(10.0, 80.0, n_rays)
    errs["gimbal_roll_deg"] = errs.get("gimbal_roll_deg", 0.0) + np.radians(angles - dmodel.nominal["gimbal_roll_deg"])
    pose, chain, row, col = mc.perturbed_geometry(dmodel, errs)
    # the [Q17] chain, as the paper: the scenario camera's file form (exact: camera_from_sensor
    # inverts to_sensor) on the batched FrameChain
    los_a = camera_from_sensor(dmodel.camera).chain_line_of_sight(pose, row, col, chain=chain)
    records = load_records(asset_path(*DEFAULT_RECORDS))
    los_b = records_line_of_sight(records, load_sensor(asset_path(*DEFAULT_CAMERA)))
    los = LineOfSight(
        np.concatenate([los_a.origin_ecef, los_b.origin_ecef]),
        np.concatenate([los_a.direction_ecef, los_b.direction_ecef]),
        np.concatenate([los_a.status, los_b.status]),
    )
    return los, len(records)


def _solver_hit(surface, los: LineOfSight):
    """The rays through the pipeline on a DEM solver's surface, as the solver's TerrainHit (with
    its evaluation counts and hidden flags)."""
    from geoloc.surfaces.terrain import TerrainHit

    # DemSurface meets the rays in a TerrainHit, which the pipeline passes on as it is without
    # corrections: the type its signature cannot say
    hit = Pipeline(None, surface).intersect(los)
    assert isinstance(hit, TerrainHit)
    return hit


def _l23_tolerance(rep: Report, dem, los: LineOfSight, exact, tol: float) -> None:
    """One tolerance's row: the descending steps (eps_h = tol) and the bisection (threshold tol)
    on the same rays, their DEM reads, times and distances to the exact first hit."""
    from geoloc.geodesy.geodesic import horizontal_distance_m
    from geoloc.surfaces.terrain import DemSurface

    t0 = time.perf_counter()
    st = _solver_hit(DemSurface(dem, "steps", eps_h=tol), los)
    t1 = time.perf_counter()
    bi = _solver_hit(DemSurface(dem, "bisect", threshold=tol), los)
    t2 = time.perf_counter()
    ok = (st.status == 0) & (bi.status == 0) & (exact.status == 0)
    es, eb = st.dem_evaluations[ok].astype(float), bi.dem_evaluations[ok].astype(float)
    saving = 100.0 * (1.0 - eb.sum() / es.sum())
    ds = horizontal_distance_m(st.lat_deg[ok], st.lon_deg[ok], exact.lat_deg[ok], exact.lon_deg[ok])
    db = horizontal_distance_m(bi.lat_deg[ok], bi.lon_deg[ok], exact.lat_deg[ok], exact.lon_deg[ok])
    rep.numbers[f"tol_{tol:g}"] = dict(
        steps_mean_evals=float(es.mean()),
        bisect_mean_evals=float(eb.mean()),
        saving_pct=saving,
        n_ok=int(ok.sum()),
        hidden=int(bi.hidden[ok].sum()),
    )
    rep.add(
        f"{tol:6g} {es.mean():12.1f} {eb.mean():13.1f} {saving:9.1f} {t1 - t0:8.2f} {t2 - t1:9.2f} "
        f"{np.max(ds):17.1f} / {np.max(db):<16.1f} {int(bi.hidden[ok].sum()):7d}"
    )
