"""``borescan discrepancy-battery``: seeded battery of simulated scans with hidden effects."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "discrepancy-battery"
HELP = "Examine a seeded battery of simulated spindle scans with hidden effects; print the confusion table."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", type=int, default=100, help="number of scans (default 100)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the battery (default 1)")
    parser.add_argument("--threshold", type=float, default=10.0, help="Delta BIC threshold (default 10)")
    parser.add_argument("--p-free", type=float, default=0.15, help="share of effect-free scans (0.15)")
    parser.add_argument("--p-pair", type=float, default=0.15, help="share of scans with two effects (0.15)")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="multiply every effect magnitude (tilt angles by its square root); default 1")
    parser.add_argument("--out", type=Path, default=None, help="write per-scan rows as JSON lines here")
    parser.add_argument("--verbose", action="store_true", help="print every wrongly named scan")


def run(args: argparse.Namespace) -> int:
    from borescan.discrepancy.battery import run_battery

    def progress(row: dict) -> None:
        if args.verbose and not row["correct"]:
            print(f"wrong: {row['scan_id']} hidden {row['truth']} -> {row['verdict']} {row['named']}",
                  flush=True)

    res = run_battery(args.n, args.seed, p_free=args.p_free, p_pair=args.p_pair, threshold=args.threshold,
                      scale=getattr(args, "scale", 1.0), progress=progress)
    print(res.table())
    n_free = sum(1 for r in res.rows if not r["truth"])
    n_pair = sum(1 for r in res.rows if len(r["truth"]) == 2)
    print(f"scans {len(res.rows)} (effect-free {n_free}, two effects {n_pair})")
    print(f"correct naming      {res.accuracy:.1%} (ambiguous counts only through the spec's look-alikes)")
    print(f"                    {res.accuracy_lenient:.1%} (counting also ambiguous verdicts listing the truth)")
    print(f"false-alarm rate    {res.false_alarm_rate:.1%} "
          "(effect-free scans called anything but no_missing_effect)")
    print(f"median gap shrink   {res.median_shrink:.2f}x (gap_before / gap_after, scans with effects)")
    print(f"median gap_before / noise floor {res.median_shrink_ceiling:.2f}x (the ceiling of the shrink)")
    print(f"gap_after <= 1.5 noise floor on {res.share_at_floor:.1%} of the scans with effects")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("w") as fh:
            for r in res.rows:
                fh.write(json.dumps({k: v for k, v in r.items()}, sort_keys=True, default=float) + "\n")
    return 0
