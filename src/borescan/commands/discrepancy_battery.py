"""``borescan discrepancy-battery``: seeded battery of simulated scans with hidden effects."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from borescan.commands._common import (
    Progress,
    UsageError,
    nonnegative_int,
    positive_float,
    positive_int,
    probability,
)

NAME = "discrepancy-battery"
HELP = "Examine a seeded battery of simulated spindle scans with hidden effects; print the confusion table."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument("--n", type=positive_int, default=100, help="number of scans, >= 1 (default 100)")
    parser.add_argument(
        "--seed", type=nonnegative_int, default=1, help="seed of the battery, >= 0 (default 1)"
    )
    parser.add_argument(
        "--threshold", type=positive_float, default=10.0, help="Delta BIC threshold, > 0 (default 10)"
    )
    parser.add_argument(
        "--p-free", type=probability, default=0.15, help="share of effect-free scans, 0..1 (default 0.15)"
    )
    parser.add_argument(
        "--p-pair",
        type=probability,
        default=0.15,
        help="share of scans with two effects, 0..1 (default 0.15); p-free + p-pair <= 1",
    )
    parser.add_argument(
        "--scale",
        type=positive_float,
        default=1.0,
        help="multiply every effect magnitude (tilt angles by its square root), > 0; default 1",
    )
    parser.add_argument("--out", type=Path, default=None, help="write per-scan rows as JSON lines here")
    parser.add_argument("--verbose", action="store_true", help="print every wrongly named scan")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def _pct(x: float, why: str) -> str:
    return f"{x:.1%}" if math.isfinite(x) else f"n/a ({why})"


def run(args: argparse.Namespace) -> int:
    """Run the battery with the options ``args``; return the exit status."""
    from borescan.discrepancy.battery import run_battery

    if args.p_free + args.p_pair > 1.0:
        raise UsageError(
            f"--p-free {args.p_free:g} + --p-pair {args.p_pair:g} exceed 1 (they are shares of the scans)"
        )
    if args.out is not None and args.out.is_dir():
        raise UsageError(f"--out {args.out} is a folder; give a file name for the JSON lines")
    bar = Progress(args.n, "examined", enabled=not args.quiet)
    done = [0]

    def progress(row: dict) -> None:
        done[0] += 1
        if args.verbose and not row["correct"]:
            print(
                f"wrong: {row['scan_id']} hidden {row['truth']} -> {row['verdict']} {row['named']}",
                flush=True,
            )
        bar.update(done[0], row["scan_id"])

    res = run_battery(
        args.n,
        args.seed,
        p_free=args.p_free,
        p_pair=args.p_pair,
        threshold=args.threshold,
        scale=args.scale,
        progress=progress,
    )
    print(res.table())
    n_free = sum(1 for r in res.rows if not r["truth"])
    n_pair = sum(1 for r in res.rows if len(r["truth"]) == 2)
    no_free = "no effect-free scans drawn"
    print(f"scans {len(res.rows)} (effect-free {n_free}, two effects {n_pair})")
    print(
        f"correct naming      {_pct(res.accuracy, 'no scans')} "
        "(ambiguous counts only through the spec's look-alikes)"
    )
    print(
        f"                    {_pct(res.accuracy_lenient, 'no scans')} "
        "(counting also ambiguous verdicts listing the truth)"
    )
    print(
        f"false-alarm rate    {_pct(res.false_alarm_rate, no_free)} "
        "(effect-free scans called anything but no_missing_effect)"
    )
    print(
        f"gap after at the noise floor (<= 1.10x) on {_pct(res.share_at_floor, 'no effect claimed')} of the "
        "scans where an effect is claimed"
    )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("w") as fh:
            for r in res.rows:
                fh.write(json.dumps({k: v for k, v in r.items()}, sort_keys=True, default=float) + "\n")
    return 0
