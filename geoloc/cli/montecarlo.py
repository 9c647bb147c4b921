"""``geoloc montecarlo``: Monte Carlo error analysis of a scenario [Q17 section 3].

Degrees and metres at this edge; see ``docs/montecarlo.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.analysis import montecarlo as mc
from geoloc.analysis.errormodel import ERROR_SOURCES, DemSpec, Distribution, ErrorModel
from geoloc.cli import VERB_HELP
from geoloc.cli._options import (
    add_correction_options,
    add_dem_options,
    add_progress_options,
    add_sensor_option,
    corrections_from_args,
    input_path,
    one_dem_raster,
    output_dir,
    surface_from_scenario,
    text_output_path,
)
from geoloc.status import Status
from geoloc.userfiles import check_output_dir, write_text

#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc montecarlo assets/scenarios/qiao2017_table1.toml --samples 200 --out stats.json"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "montecarlo",
        help=VERB_HELP["montecarlo"],
        description="Sample every error source of a scenario file (nominal pose, gimbal angles, "
        "camera, target, per-parameter distributions; see docs/montecarlo.md), locate the "
        "target for every sample through the geolocation chain, and report the mean and "
        "standard deviation of lat, lon, h, the CEP of [Q17] eq. 18 and the empirical 50 % "
        "radius. With --sweep, CEP against the outer gimbal angle ([Q17] Fig. 10) as CSV + PNG.",
    )
    p.add_argument(
        "scenario",
        type=input_path,
        help="scenario TOML, e.g. assets/scenarios/qiao2017_table1.toml "
        "(a path starting with assets/ names the bundled file when it is not here)",
    )
    p.add_argument(
        "--samples",
        type=sample_count,
        default=5000,
        help="number of samples N (default 5000; 1e9 is accepted: the samples are "
        "processed in chunks and their statistics streamed, in constant memory)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_sensor_option(
        p,
        help="sensor TOML (docs/sensor_format.md; a lens of any model on the roll-pitch "
        "gimbal) or first-phase camera TOML replacing the scenario's [camera] table",
    )
    p.add_argument(
        "--error",
        action="append",
        default=[],
        metavar="SOURCE=DIST:VALUE",
        help="add or replace one error source of the scenario, in its [errors] unit: "
        "e.g. --error cx_px=normal:0.5 --error k1=normal:0.002 --error "
        "vibration_yaw_deg=uniform:0.01 (normal:SIGMA or uniform:MAX, optional :BIAS); "
        "lens sources: fx_px fy_px focal_length_px cx_px cy_px skew_px k1 k2 p1 p2 k3 k4 k5 k6; "
        "repeatable",
    )
    p.add_argument("--out", default=None, type=text_output_path, help="statistics JSON of a single run")
    p.add_argument(
        "--out-dir",
        default=None,
        type=output_dir,
        help="with --sweep: the folder of the sweep's CSV and PNG files (default montecarlo_sweep)",
    )
    p.add_argument(
        "--sweep",
        choices=["terrain", "dem", "both"],
        default=None,
        help="terrain: CEP vs gimbal roll for several terrain sigmas, ellipsoid model "
        "([Q17] Fig. 10a); dem: the same with the target on the scenario's DEM "
        "(Fig. 10b); both",
    )
    p.add_argument(
        "--angles-deg",
        default=None,
        help="sweep angles START:STOP:STEP in degrees, STOP included "
        "(default: the scenario's [sweep] angles_deg, else 10:82:2)",
    )
    p.add_argument(
        "--terrain-sigmas-m",
        default=None,
        help="comma-separated terrain standard deviations [m] for --sweep terrain "
        "(default: the scenario's [sweep] terrain_sigmas_m, else 10,20,...,100)",
    )
    add_correction_options(p)
    add_dem_options(
        p,
        mosaic=False,
        tolerances=False,
        method_default=None,
        dem_help="DEM raster replacing the target height (overrides the scenario's [dem])",
        method_help="DEM method: steps [Q17], bisect [L23] or exact (default: the scenario's [dem] method, else exact)",
    )
    p.add_argument(
        "--no-dem", action="store_true", help="ignore the scenario's [dem] table (ellipsoid model with target_h_m)"
    )
    p.add_argument(
        "--chunk",
        type=sample_count,
        default=mc.CHUNK,
        help=f"samples per vectorised batch (memory bound; default {mc.CHUNK}; at most "
        f"{mc.CHUNK_MEMORY_SHARE * 100:.0f}%% of the available memory at {mc.BYTES_PER_SAMPLE} bytes a "
        "sample, checked when the run starts)",
    )
    add_progress_options(p)
    p.set_defaults(func=run)


def sample_count(text: str) -> int:
    """``"5000"``, ``"1e9"`` or ``"1_000_000"`` -> an int; argparse reports anything else."""

    t = str(text).strip().replace("_", "")
    try:
        v = int(t)
    except ValueError:
        try:
            f = float(t)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number of samples") from None
        if not math.isfinite(f) or f != int(f):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of samples") from None
        v = int(f)
    return v


def parse_angles(text: str) -> np.ndarray:
    """``"10:82:2"`` -> [10, 12, ..., 82]; a comma list is also accepted."""
    try:
        if ":" in text:
            a, b, s = (float(x) for x in text.split(":"))
            if s <= 0 or b < a:
                raise ValueError
            return np.round(np.arange(a, b + s / 2, s), 9)
        return np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise ValueError(
            f"--angles-deg = {text!r}: expected START:STOP:STEP (STEP > 0, "
            "STOP >= START) or a comma-separated list of degrees"
        ) from None


def parse_error(text: str) -> tuple[str, Distribution]:
    """``"cx_px=normal:0.5"`` / ``"k1=uniform:0.01:0.001"`` -> (source, Distribution), errors naming the text."""

    name, sep, spec = str(text).partition("=")
    name = name.strip()
    if not sep or name not in ERROR_SOURCES:
        raise ValueError(f"--error {text!r}: expected SOURCE=DIST:VALUE with SOURCE one of {sorted(ERROR_SOURCES)}")
    parts = spec.split(":")
    try:
        values = [float(x) for x in parts[1:]]
    except ValueError:
        values = []
    if (
        parts[0] not in ("normal", "uniform")
        or len(values) not in (1, 2)
        or not all(map(math.isfinite, values))
        or values[0] < 0
    ):
        raise ValueError(
            f"--error {text!r}: expected {name}=normal:SIGMA or {name}=uniform:MAX "
            "(>= 0, in the source's unit), optionally :BIAS"
        )
    return name, Distribution(parts[0], values[0], values[1] if len(values) == 2 else 0.0)


def _floats(text: str, name: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise ValueError(f"{name} = {text!r}: expected comma-separated numbers") from None
    if np.any(~np.isfinite(v)) or np.any(v < 0):
        raise ValueError(f"{name} = {text!r}: values must be finite and >= 0")
    return v


def load_model(args: argparse.Namespace) -> ErrorModel:

    scenario = Path(args.scenario)
    if not scenario.is_file():
        raise FileNotFoundError(f"scenario file not found: {args.scenario}")
    from geoloc.workflows.scenario import load_scenario

    model = load_scenario(scenario, expect="montecarlo")
    if getattr(args, "camera", None):
        from geoloc.sensors.sensor_file import load_sensor

        path = Path(args.camera)
        if not path.is_file():
            raise FileNotFoundError(f"--sensor file not found: {args.camera}")
        model = model.with_camera(load_sensor(path))
    for text in getattr(args, "error", []):
        model = model.with_error(*parse_error(text))
    if args.no_dem:
        model = model.without_dem()
    dem = one_dem_raster(args, "montecarlo")
    if dem:
        if not Path(dem).exists():
            raise FileNotFoundError(f"--dem file not found: {dem}")
        model = replace(model, dem=DemSpec(Path(dem), args.dem_datum, model.dem.method if model.dem else None))
    if args.method is not None:
        if model.dem is None:
            raise ValueError(
                f"--method {args.method}: the scenario has no DEM (give --dem FILE or a scenario with a [dem] table)"
            )
        model = replace(model, dem=replace(model.dem, method=args.method))
    # the scenario's [corrections] with --refraction / --light-time / --no-aberration on top
    return replace(model, corrections=corrections_from_args(args, model.camera, base=model.corrections))


def format_stats(stats: dict, nominal: Any = None) -> str:
    lines = []
    if nominal is not None:
        lat, lon, h, _ = nominal
        lines.append(f"nominal target   {math.degrees(lat):.6f} N  {math.degrees(lon):.6f} E  {h:.1f} m")
    lines += [
        f"mean             {stats['mean_lat_deg']:.6f} N  {stats['mean_lon_deg']:.6f} E  {stats['mean_h_m']:.1f} m",
        f"std              lat {stats['std_lat_deg']:.6f} deg  lon {stats['std_lon_deg']:.6f} deg  "
        f"h {stats['std_h_m']:.2f} m",
        f"CEP [Q17 eq. 18] {stats['cep_m']:.2f} m   empirical 50 % radius {stats['cep50_empirical_m']:.2f} m",
        f"samples          {stats['n_ok']} located, {stats['n_failed']} failed",
    ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    mc.check_samples_and_chunk(args.samples, args.chunk, field_n="--samples", field_chunk="--chunk")
    if args.sweep and args.out:
        raise ValueError(
            f"--out {args.out} is the statistics JSON of a single run; a sweep writes its CSV "
            "and PNG files into --out-dir DIR"
        )
    if args.out_dir and not args.sweep:
        raise ValueError(f"--out-dir {args.out_dir} goes with --sweep; a single run writes --out FILE.json")
    model = load_model(args)
    if args.sweep in ("dem", "both") and model.dem is None:
        # refuse before any work (and before writing Fig. 10a for --sweep both)
        raise ValueError(
            f"--sweep {args.sweep}: scenario {args.scenario} has no [dem] table; "
            "give --dem FILE, use a scenario with a DEM (e.g. "
            "assets/scenarios/qiao2017_table1_dem.toml) or --sweep terrain"
        )
    rng = np.random.default_rng(args.seed)
    surface = surface_from_scenario(model)  # a bad DEM fails here, named
    if args.sweep is None:
        res = mc.run(
            model, args.samples, rng, surface=surface, chunk=args.chunk, progress=args.progress, keep_samples=False
        )
        if res.stats["n_ok"] < 2:
            st = res.status_counts
            why = ", ".join(f"{Status(k).name.lower()}: {int(c)}" for k, c in enumerate(st) if c)
            print(f"geoloc montecarlo: fewer than 2 samples located ({why}); no statistics", file=sys.stderr)
            return 1
        print(
            f"scenario {model.name}: N = {args.samples}, seed {args.seed}, "
            f"{'streamed in chunks of ' + str(args.chunk) + ', ' if res.streamed else ''}"
            f"{'DEM ' + str(model.dem.path) if model.dem else 'ellipsoid model'}, "
            f"{res.seconds:.2f} s"
        )
        print(format_stats(res.stats, res.nominal))
        for w in res.stats.get("warnings", []):
            print(f"warning: {w}", file=sys.stderr)
        if model.dem is None:
            try:
                fo = mc.first_order(model)
                print(
                    f"first order      lat {fo.std_lat_deg:.6f} deg  lon {fo.std_lon_deg:.6f} deg  "
                    f"h {fo.std_h_m:.2f} m  eq. 18 {fo.cep_m:.2f} m"
                )
            except ValueError as e:  # the nominal geometry (or a step of it) has no ground point
                print(f"first order      not available: {e}")
        if args.out:
            out = {k: float(res.stats[k]) for k in mc.STATS_KEYS}
            write_text(args.out, json.dumps(out, indent=2) + "\n", "--out")
            print(f"wrote {args.out}")
        return 0

    sw = model.sweep
    angles = (
        parse_angles(args.angles_deg)
        if args.angles_deg
        else (_sweep_angles(sw.get("angles_deg")) if "angles_deg" in sw else parse_angles("10:82:2"))
    )
    sigmas = (
        _floats(args.terrain_sigmas_m, "--terrain-sigmas-m")
        if args.terrain_sigmas_m
        else (np.asarray(sw.get("terrain_sigmas_m", np.arange(10.0, 101.0, 10.0)), float))
    )
    outdir = check_output_dir(args.out_dir or "montecarlo_sweep", "--out-dir")
    outdir.mkdir(parents=True, exist_ok=True)
    kinds = ["terrain", "dem"] if args.sweep == "both" else [args.sweep]
    for kind in kinds:
        if kind == "terrain":
            s = mc.sweep_terrain_sigma(model, angles, sigmas, args.samples, rng, args.progress, chunk=args.chunk)
            stem = "fig10a_terrain_sigma"
        else:
            s = mc.sweep_dem(
                model, angles, args.samples, rng, surface=surface, progress=args.progress, chunk=args.chunk
            )
            stem = "fig10b_dem"
        s.to_csv(outdir / f"{stem}.csv")
        s.to_png(outdir / f"{stem}.png")
        print(f"{s.title}: wrote {outdir / (stem + '.csv')} and .png")
        print(sweep_table(s))
    return 0


def _sweep_angles(v) -> np.ndarray:
    if isinstance(v, list) and len(v) == 3:
        return parse_angles(":".join(str(x) for x in v))
    raise ValueError(f"[sweep] angles_deg = {v!r}: expected [start, stop, step]")


def sweep_table(s: mc.Sweep, every: int = 1) -> str:
    """Plain text: one line per angle, CEP (eq. 18) per curve."""
    head = f"{'angle':>6} " + " ".join(f"{lab:>14}" for lab in s.labels)
    lines = [head + "   (CEP [Q17 eq. 18], m)"]
    for i in range(0, len(s.angles_deg), every):
        lines.append(f"{s.angles_deg[i]:6.1f} " + " ".join(f"{v:14.1f}" for v in s.cep_m[i]))
    return "\n".join(lines)
