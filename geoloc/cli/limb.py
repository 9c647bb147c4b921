"""``geoloc limb``: tangent height of limb lines of sight ([L18] virtual ellipsoid and exact minimum).

Two modes: a scenario file (orbit + attitude + slit, ``docs/limb.md``) giving
one CSV row per frame and pixel, or one raw line of sight in ECEF. Degrees and
metres at this edge; see :mod:`geoloc.sensors.limb`.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import sys

import numpy as np

from geoloc.cli import VERB_HELP
from geoloc.cli._options import input_path, text_output_path
from geoloc.geodesy.ellipsoid import ecef_to_geodetic
from geoloc.pipeline import Corrections
from geoloc.sensors.limb import limb_tangent
from geoloc.status import Status, describe
from geoloc.userfiles import atomic_path
from geoloc.workflows.scenario import load_scenario

#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = "geoloc limb assets/scenarios/tiangong2_limb.toml --frames 3 --out limb.csv"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "limb",
        help=VERB_HELP["limb"],
        description="Tangent point and limb height of lines of sight that miss the Earth: the [L18] "
        "virtual ellipsoid of equal flattening (eq. 13-26, Newton-Raphson on eq. 17) and, "
        "independently, the minimum geodetic height along the line. Either a scenario TOML "
        "(orbit, attitude, slit; e.g. assets/scenarios/tiangong2_limb.toml) or one raw line "
        "of sight given in ECEF.",
    )
    p.add_argument(
        "scenario", nargs="?", default=None, type=input_path, help="limb scenario TOML file (see docs/limb.md)"
    )
    p.add_argument(
        "--out", default=None, type=text_output_path, help="scenario mode: write one CSV row per frame and pixel here"
    )
    p.add_argument("--frames", type=int, default=None, help="scenario mode: use only the first N frames")
    p.add_argument(
        "--origin-ecef",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=None,
        help="raw mode: sensor position, ECEF [m]",
    )
    p.add_argument(
        "--direction-ecef",
        type=float,
        nargs=3,
        metavar=("DX", "DY", "DZ"),
        default=None,
        help="raw mode: line-of-sight direction, ECEF (any length)",
    )
    p.add_argument("--max-iter", type=int, default=20, help="Newton-Raphson step limit for eq. 17 (default 20)")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.add_argument(
        "--refraction",
        choices=["none", "standard"],
        default=None,
        help="standard: also the refracted tangent point, the ray bent through the U.S. Standard "
        "Atmosphere 1976 (refracted_tangent_h_m; default: the scenario's [corrections], else none)",
    )
    p.add_argument(
        "--velocity-ecef",
        type=float,
        nargs=3,
        metavar=("VX", "VY", "VZ"),
        default=None,
        help="raw mode: the sensor's Earth-fixed velocity [m/s]: the line of sight is then turned by "
        "aberration of light (as for every spaceborne sensor; --no-aberration leaves it)",
    )
    p.add_argument(
        "--no-aberration",
        action="store_true",
        help="leave aberration of light out (on by default in scenario mode and with --velocity-ecef)",
    )
    p.set_defaults(func=run)


def _num(x, nd=None):
    x = float(x)
    if not math.isfinite(x):
        return None
    return round(x, nd) if nd is not None else x


def _label(aberration: bool, refraction: str) -> str:
    """The output's ``corrections``, named as every locating verb names them (``Corrections.label``);
    a tangent ray meets no surface, so light-time has nothing to act on."""
    from geoloc.corrections.refraction import STANDARD_REFRACTION

    return Corrections(
        refraction=STANDARD_REFRACTION if refraction == "standard" else None, aberration=aberration
    ).label


def _refracted(refraction: str, origin, direction) -> dict:
    """The refracted tangent point of limb rays (``--refraction standard``), as output columns;
    {} when refraction is off. ``Refraction.limb``: n(r_t) r_t = n(r_p) c0 (docs/refraction.md)."""
    if refraction in (None, "none"):
        return {}
    from geoloc.corrections.refraction import STANDARD_REFRACTION

    r = STANDARD_REFRACTION.limb(origin, direction)
    lat, lon, _ = ecef_to_geodetic(r.refracted_tangent_ecef)
    return {
        "refracted_tangent_h_m": r.refracted_tangent_h_m,
        "refracted_tangent_lat_deg": np.degrees(lat),
        "refracted_tangent_lon_deg": np.degrees(lon),
        "refraction_m": r.tangent_h_m - r.refracted_tangent_h_m,
        "refraction_bending_rad": r.bending_rad,
    }


def _raw(args) -> int:
    if args.origin_ecef is None or args.direction_ecef is None:
        raise ValueError("raw mode needs both --origin-ecef X Y Z and --direction-ecef DX DY DZ")
    o = np.array(args.origin_ecef, float)
    d = np.array(args.direction_ecef, float)
    if not np.all(np.isfinite(o)):
        raise ValueError(f"--origin-ecef must be finite, got {args.origin_ecef}")
    if not np.all(np.isfinite(d)) or not np.any(d != 0):
        raise ValueError(f"--direction-ecef must be finite and non-zero, got {args.direction_ecef}")
    aberrated = args.velocity_ecef is not None and not args.no_aberration
    if args.velocity_ecef is not None:
        v = np.array(args.velocity_ecef, float)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"--velocity-ecef must be finite, got {args.velocity_ecef}")
        if aberrated:
            from geoloc.corrections.lighttime import aberration, inertial_velocity

            d = aberration(d, inertial_velocity(o, v))
    refraction = args.refraction or "none"
    r = limb_tangent(o, d, max_iter=args.max_iter)
    st = Status(int(r.status))
    out = {
        "status": st.name.lower(),
        "tangent_lat_deg": _num(np.degrees(r.tangent_lat), 9),
        "tangent_lon_deg": _num(np.degrees(r.tangent_lon), 9),
        "tangent_h_m": _num(r.tangent_h, 6),
        "exact_tangent_h_m": _num(r.exact_h, 6),
        "h_difference_m": _num(r.h_difference, 6),
        "exact_tangent_lat_deg": _num(np.degrees(r.exact_lat), 9),
        "exact_tangent_lon_deg": _num(np.degrees(r.exact_lon), 9),
        "delta_a_m": _num(r.delta_a, 6),
        "nr_iterations": int(r.nr_iterations),
        "nr_residual": _num(r.nr_residual_history[int(r.nr_iterations)]),
        "tangent_range_m": _num(r.s, 3),
        "exact_tangent_range_m": _num(r.exact_s, 3),
        "corrections": _label(aberrated, refraction),
    }
    for k, v in _refracted(refraction, o, d).items():
        out[k] = _num(v, 9 if k.endswith("_deg") else 6)
    if st == Status.HITS_EARTH:
        lat, lon, _ = ecef_to_geodetic(r.earth_hit_ecef)
        out["earth_hit_lat_deg"] = _num(np.degrees(lat), 9)
        out["earth_hit_lon_deg"] = _num(np.degrees(lon), 9)
    if args.json:
        print(json.dumps(out))
    elif st == Status.OK:
        print(
            f"virtual ellipsoid [L18]: lat {out['tangent_lat_deg']:.6f} deg  lon {out['tangent_lon_deg']:.6f} deg"
            f"  h {out['tangent_h_m']:.3f} m  (Delta a {out['delta_a_m']:.3f} m,"
            f" {out['nr_iterations']} Newton-Raphson steps)"
        )
        print(
            f"exact (min geodetic h): lat {out['exact_tangent_lat_deg']:.6f} deg"
            f"  lon {out['exact_tangent_lon_deg']:.6f} deg  h {out['exact_tangent_h_m']:.3f} m"
        )
        print(f"difference (L18 - exact): {out['h_difference_m'] * 1e3:.3f} mm")
        if out.get("refracted_tangent_h_m") is not None:
            print(
                f"refracted (standard atmosphere): h {out['refracted_tangent_h_m']:.3f} m, "
                f"{out['refraction_m']:.3f} m below the straight line's; bent "
                f"{out['refraction_bending_rad'] * 1e3:.3f} mrad to the tangent point"
            )
    if st != Status.OK:
        print(f"geoloc limb: {describe(st)}", file=sys.stderr)
        return 1
    return 0


_COLUMNS = [
    "frame",
    "pixel",
    "time_s",
    "alpha_deg",
    "sat_lat_deg",
    "sat_lon_deg",
    "sat_h_m",
    "status",
    "tangent_lat_deg",
    "tangent_lon_deg",
    "tangent_h_m",
    "delta_a_m",
    "nr_iterations",
    "exact_tangent_lat_deg",
    "exact_tangent_lon_deg",
    "exact_tangent_h_m",
    "h_difference_m",
    "tangent_range_m",
]


def _scenario(args) -> int:
    sc = load_scenario(args.scenario, expect="limb")
    if args.frames is not None:
        if args.frames < 1:
            raise ValueError(f"--frames must be >= 1, got {args.frames}")
        sc = sc.with_frames(min(args.frames, sc.n_frames))
    if args.velocity_ecef is not None:
        raise ValueError("--velocity-ecef is for raw mode: a scenario's orbit gives the velocity")
    sc = dataclasses.replace(
        sc, aberration=sc.aberration and not args.no_aberration, refraction=args.refraction or sc.refraction
    )
    chain, r = sc.solve(max_iter=args.max_iter)
    nf, npx = r.shape
    refr = {
        k: np.broadcast_to(v, (nf, npx))
        for k, v in _refracted(sc.refraction, chain.origin_ecef, chain.direction_ecef).items()
    }
    columns = _COLUMNS + [k for k in refr if k != "refraction_bending_rad"]
    t = sc.times()
    alpha = np.degrees(sc.alphas())
    slat, slon, sh = ecef_to_geodetic(chain.origin_ecef[:, 0, :])
    names = np.array([s.name.lower() for s in Status])[r.status]
    if args.out:
        cols = {
            "frame": np.repeat(np.arange(nf), npx),
            "pixel": np.tile(np.arange(npx), nf),
            "time_s": np.repeat(t, npx),
            "alpha_deg": np.tile(alpha, nf),
            "sat_lat_deg": np.repeat(np.degrees(slat), npx),
            "sat_lon_deg": np.repeat(np.degrees(slon), npx),
            "sat_h_m": np.repeat(sh, npx),
            "status": names.ravel(),
            "tangent_lat_deg": r.tangent_lat_deg.ravel(),
            "tangent_lon_deg": r.tangent_lon_deg.ravel(),
            "tangent_h_m": r.tangent_h.ravel(),
            "delta_a_m": r.delta_a.ravel(),
            "nr_iterations": r.nr_iterations.ravel(),
            "exact_tangent_lat_deg": r.exact_lat_deg.ravel(),
            "exact_tangent_lon_deg": r.exact_lon_deg.ravel(),
            "exact_tangent_h_m": r.exact_h.ravel(),
            "h_difference_m": r.h_difference.ravel(),
            "tangent_range_m": r.s.ravel(),
            **{k: v.ravel() for k, v in refr.items()},
        }
        fmt = {
            "time_s": "{:.3f}",
            "alpha_deg": "{:.5f}",
            "sat_h_m": "{:.3f}",
            "tangent_h_m": "{:.4f}",
            "refracted_tangent_h_m": "{:.4f}",
            "refraction_m": "{:.4f}",
            "delta_a_m": "{:.4f}",
            "exact_tangent_h_m": "{:.4f}",
            "h_difference_m": "{:.6f}",
            "tangent_range_m": "{:.3f}",
        }

        def cell(name, v):
            if isinstance(v, (np.floating, float)):
                if not math.isfinite(v):
                    return ""
                return fmt.get(name, "{:.8f}").format(v)
            return str(v)

        with atomic_path(args.out, "--out") as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(columns)
            for i in range(nf * npx):
                w.writerow([cell(c, cols[c][i]) for c in columns])
    ok = r.status == Status.OK
    counts = {s.name.lower(): int(np.sum(r.status == s)) for s in Status if np.any(r.status == s)}
    summary = {
        "scenario": sc.name,
        "frames": nf,
        "pixels": npx,
        "status_counts": counts,
        "exact_tangent_h_m_min": _num(np.min(r.exact_h[ok]), 3) if ok.any() else None,
        "exact_tangent_h_m_max": _num(np.max(r.exact_h[ok]), 3) if ok.any() else None,
        "max_abs_h_difference_m": _num(np.max(np.abs(r.h_difference[ok])), 6) if ok.any() else None,
        "max_nr_iterations": int(r.nr_iterations.max()),
        "out": args.out,
        "corrections": _label(sc.aberration, sc.refraction),
    }
    if refr:
        rh = refr["refracted_tangent_h_m"]
        good = np.isfinite(rh)
        summary["refracted_tangent_h_m_min"] = _num(np.min(rh[good]), 3) if good.any() else None
        summary["refracted_tangent_h_m_max"] = _num(np.max(rh[good]), 3) if good.any() else None
        summary["max_refraction_m"] = _num(np.max(refr["refraction_m"][good]), 3) if good.any() else None
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{sc.name}: {nf} frames x {npx} pixels; status {counts}")
        if ok.any():
            print(
                f"exact tangent heights {summary['exact_tangent_h_m_min'] / 1e3:.2f}"
                f"-{summary['exact_tangent_h_m_max'] / 1e3:.2f} km; max |L18 - exact| "
                f"{summary['max_abs_h_difference_m'] * 1e3:.3f} mm; Newton-Raphson <= "
                f"{summary['max_nr_iterations']} steps"
            )
        if args.out:
            print(f"wrote {nf * npx} rows to {args.out}")
    return 0


def run(args: argparse.Namespace) -> int:
    raw = args.origin_ecef is not None or args.direction_ecef is not None
    if raw and args.scenario:
        raise ValueError("give either a SCENARIO file or --origin-ecef/--direction-ecef, not both")
    if args.max_iter < 0:
        raise ValueError(f"--max-iter must be >= 0, got {args.max_iter}")
    if raw:
        return _raw(args)
    if not args.scenario:
        raise ValueError("give a SCENARIO file, or --origin-ecef X Y Z --direction-ecef DX DY DZ")
    return _scenario(args)
