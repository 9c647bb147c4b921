"""``geoloc reproduce``: print a paper's published numbers beside the project's."""

from __future__ import annotations

import argparse
import json

from geoloc.cli._options import surface_from_scenario, text_output_path
from geoloc.userfiles import write_text
from geoloc.workflows import reproduce as rp
from geoloc.cli import VERB_HELP

PAPERS = {
    "qiao2017": "[Q17] Table 1 nominal point, Monte Carlo standard deviations (ellipsoid and DEM), "
    "flight-test positions and errors, Fig. 10 trend",
    "li2023": "[L23] DEM evaluations of the bisection on the target elevation against [Q17]'s "
    "descending steps, at equal height tolerances",
}


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
#: Two coarse tolerances: the descending steps take (relief / tolerance) DEM reads a ray, so the
#: 20,10 m fills the same table through the same writer in about a tenth of the default 10,2,1 m's
#: CPU (0.23 s against 2.8 s, warm, measured in one process).
EXAMPLE = "geoloc reproduce li2023 --rays 10 --tolerances-m 20,10 --json numbers.json"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reproduce",
        help=VERB_HELP["reproduce"],
        description="Recompute the published results of a source paper with the project's "
        "code and print both side by side. " + "; ".join(f"{k}: {v}" for k, v in PAPERS.items()),
    )
    p.add_argument("paper", choices=sorted(PAPERS), help="which paper")
    p.add_argument("--samples", type=int, default=5000, help="Monte Carlo N (default 5000, as in [Q17])")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--sweep-samples", type=int, default=2000, help="samples per point of the Fig. 10 trend (default 2000)"
    )
    p.add_argument("--no-dem", action="store_true", help="qiao2017: skip the DEM parts")
    p.add_argument(
        "--rays",
        type=int,
        default=100,
        help="li2023: number of Table 1-2 rays (plus the 20 flight-test records; default 100)",
    )
    p.add_argument(
        "--tolerances-m",
        default="10,2,1",
        help="li2023: comma-separated height tolerances [m], step of the descending "
        "method and bisection threshold (default 10,2,1)",
    )
    p.add_argument("--json", default=None, type=text_output_path, help="also write the key numbers to this JSON file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.samples < 2 or args.sweep_samples < 2:
        raise ValueError(f"--samples = {args.samples}, --sweep-samples = {args.sweep_samples}: must be >= 2")
    if args.paper == "qiao2017":
        with_dem = not args.no_dem and rp.dem_scenario_available()
        surface = surface_from_scenario(rp.load_q17_dem_model()) if with_dem else None
        rep = rp.qiao2017_report(args.samples, args.seed, args.sweep_samples, surface=surface)
    else:
        if args.rays < 1:
            raise ValueError(f"--rays = {args.rays}: must be >= 1")
        try:
            tols = tuple(float(x) for x in args.tolerances_m.split(","))
        except ValueError:
            tols = ()
        if not tols or not all(t > 0 and t == t and t != float("inf") for t in tols):
            raise ValueError(
                f"--tolerances-m = {args.tolerances_m!r}: expected positive numbers of metres, comma-separated"
            )
        rep = rp.li2023_report(
            surface_from_scenario(rp.load_q17_dem_model()), seed=args.seed, n_rays=args.rays, tolerances_m=tols
        )
    print(rep.text())
    if args.json:
        write_text(args.json, json.dumps(rep.numbers, indent=2) + "\n", "--json")
        print(f"wrote {args.json}")
    return 0
