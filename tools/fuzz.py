"""The long fuzz run of every parser: ``python tools/fuzz.py --minutes 10 --seed 0``.

Round after round, every target of ``tests/fuzz_targets.py`` (KLV, MPEG-TS, records CSV with
a column map, column-map TOML, sensor TOML, the five kinds of scenario TOML, photo EXIF/XMP,
XMP alone, RPC00B text) gets a batch of hypothesis examples, with a seed fixed by ``--seed``
and the round, so that a run is repeatable. Prints per target the examples run, the
exceptions that broke the promise (a bare library error; a good row dropped), the distinct
clear errors seen, and the peak memory (RSS) after the first round and at the end.

Found inputs are kept as regression cases (``--keep``, default on): each failing input
(hypothesis' shrunk one), and one input per distinct clear error, at most ``--per-target``,
under ``tests/data/fuzz/TARGET/`` (``tests/io/test_fuzz.py`` replays them all). Exit status 0
when no exception broke the promise, 1 otherwise.
"""

from __future__ import annotations

import argparse
import re
import resource
import sys
import time
import warnings
from typing import Any
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

import fuzz_targets as F  # noqa: E402
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import seed as hseed  # noqa: E402


def _signature(e: BaseException) -> str:
    """An error's kind without its numbers and names: which clear errors a target reached."""
    msg = re.sub(r"0x[0-9a-fA-F]+|\d+(\.\d+)?(e[-+]?\d+)?", "N", str(e))
    msg = re.sub(r"'[^']*'|\"[^\"]*\"", "Q", msg)
    msg = re.sub(r"/[^\s:]+", "P", msg)
    return f"{type(e).__name__}: {msg[:80]}"


def _observer(target, st_, last, args):
    """Count each distinct clear error; keep the first input that reached it."""

    def observe(e):
        sig = _signature(e)
        if sig not in st_["errors"]:
            st_["errors"][sig] = 0
            if args.keep and st_["kept"] < args.per_target and "data" in last and len(last["data"]) <= args.max_bytes:
                F.keep(target, last["data"])
                st_["kept"] += 1
        st_["errors"][sig] += 1

    return observe


def _batch(target, st_, last, args, seed):
    """One round of ``args.batch`` hypothesis examples of ``target``, with a fixed seed."""

    @hseed(seed)
    @settings(
        max_examples=args.batch,
        deadline=None,
        database=None,
        derandomize=False,
        phases=[Phase.generate, Phase.shrink],
        print_blob=False,
        report_multiple_bugs=False,
        suppress_health_check=list(HealthCheck),
    )
    @given(target.strategy())
    def one(data):
        last["data"] = data
        st_["examples"] += 1
        target.run(data)

    return one


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="length of the run (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="hypothesis seed of the first round (default 0)")
    ap.add_argument("--targets", default=",".join(F.TARGETS), help="comma-separated targets (default: all)")
    ap.add_argument("--batch", type=int, default=50, help="examples per target per round (default 50)")
    ap.add_argument("--per-target", type=int, default=12, help="inputs kept per target at most (default 12)")
    ap.add_argument(
        "--max-bytes",
        type=int,
        default=16384,
        help="keep an input of a distinct clear error only up to this size (default 16384; "
        "a finding is kept whatever its size)",
    )
    ap.add_argument("--no-keep", dest="keep", action="store_false", help="keep no input in tests/data/fuzz")
    args = ap.parse_args(argv)
    names = [n.strip() for n in args.targets.split(",") if n.strip()]
    unknown = sorted(set(names) - set(F.TARGETS))
    if unknown:
        ap.error(f"--targets: unknown {unknown}; the targets are {sorted(F.TARGETS)}")
    warnings.simplefilter("ignore")  # the parsers' warnings are their business; exceptions are ours
    stats: dict[str, dict[str, Any]] = {n: {"examples": 0, "findings": 0, "errors": {}, "kept": 0} for n in names}
    failures, seen = [], set()
    t_end = time.monotonic() + 60.0 * args.minutes
    rss_first = None
    rnd = 0
    while time.monotonic() < t_end:
        for name in names:
            if time.monotonic() >= t_end:
                break
            target, st_ = F.TARGETS[name], stats[name]
            last: dict[str, Any] = {}
            one = _batch(target, st_, last, args, args.seed * 1_000_003 + rnd)
            F.OBSERVER = _observer(target, st_, last, args)
            try:
                one()
            except Exception as e:  # noqa: BLE001 - hypothesis re-raises the shrunk failure last
                st_["findings"] += 1
                what = f"{type(e).__name__}: {(str(e).splitlines() or [''])[0][:200]}"
                if (name, _signature(e)) in seen:
                    continue  # the same finding again, another round
                seen.add((name, _signature(e)))
                data = last.get("data", b"")
                kept = F.keep(target, data) if args.keep else None
                failures.append((name, what, kept))
                print(
                    f"FINDING {name}: {failures[-1][1]} (input {len(data)} bytes"
                    f"{', kept as ' + str(kept.relative_to(ROOT)) if kept else ''})",
                    flush=True,
                )
            finally:
                F.OBSERVER = None
        rnd += 1
        if rss_first is None:
            rss_first = rss_mb()
        print(
            f"round {rnd}: {sum(s['examples'] for s in stats.values())} examples, "
            f"{len(failures)} findings, peak RSS {rss_mb():.0f} MB",
            flush=True,
        )
    total = sum(s["examples"] for s in stats.values())
    print(
        f"\nfuzz: {args.minutes:g} min, seed {args.seed}, {rnd} rounds, {total} examples, "
        f"{sum(s['findings'] for s in stats.values())} exceptions that broke the promise "
        f"({len(failures)} distinct)"
    )
    print(f"{'target':28s} {'examples':>9s} {'findings':>9s} {'clear errors (distinct)':>24s} {'kept':>5s}")
    for n in names:
        s = stats[n]
        print(f"{n:28s} {s['examples']:9d} {s['findings']:9d} {len(s['errors']):24d} {s['kept']:5d}")
    print(f"peak RSS: {rss_first or rss_mb():.0f} MB after the first round, {rss_mb():.0f} MB at the end")
    for name, what, kept in failures:
        print(f"  {name}: {what}" + (f" [{kept.relative_to(ROOT)}]" if kept else ""))
    return 1 if failures else 0  # one status for the whole run


if __name__ == "__main__":
    sys.exit(main())
