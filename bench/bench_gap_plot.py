"""CPU of drawing a night's gap plots (issue 38), one process.

Every scan of a processed night is examined again as the discrepancy stage does (not timed), then
:func:`borescan.discrepancy.plot_gap` draws all their ``gap.png`` in this process, ``BENCH_GAP_REPEATS``
passes (default 2), each from empty caches (a new process's first night), on the CPU clock of this
process (``time.process_time``). Compare two checkouts by alternating the same command with
``PYTHONPATH=<checkout>/src`` (a shared machine stretches CPU times too).

    python -m bench.bench_gap_plot RESULTS_ROOT [--night YYYY-MM-DD] [--out DIR]
    BENCH_GAP_SOURCE=RESULTS_ROOT python -m bench gap_plot

``--out DIR`` keeps the plots (``<scan_id>.png``) to compare them with another checkout's. Run on request
only: it needs a processed results root, e.g. the contract night's
(``python -m bench.bench_contract_night --keep K``, then ``K/results_cores2``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

RUN_BY_DEFAULT = False


def _night_of(results: Path, night: str | None) -> str:
    scans = (results / "stage" / "scans").glob("night=*.parquet")
    nights = sorted(p.stem.removeprefix("night=") for p in scans)
    if night is not None:
        if night not in nights:
            have = ", ".join(nights) or "none"
            raise SystemExit(f"no night {night} under {results} (stage/scans has {have})")
        return night
    if len(nights) != 1:
        raise SystemExit(f"{results} holds nights {', '.join(nights) or 'none'}: name one with --night")
    return nights[0]


def examinations(results: Path, night: str) -> list:
    """Return the examinations of every scan of ``night`` under ``results``, as the discrepancy stage's.

    With the config schema's ``discrepancy`` defaults, against the calibrations of that night and before;
    a scan the stage would set aside is left out.
    """
    import polars as pl

    from borescan import discrepancy, rawio
    from borescan.config import schema_defaults
    from borescan.discrepancy.examine import discrepancy_settings
    from borescan.discrepancy.reference import discrepancy_reference
    from borescan.stages._common import night_scans, read_tables

    settings = discrepancy_settings(schema_defaults()["discrepancy"])
    tables = sorted(
        p
        for p in (results / "stage" / "calibrations").glob("night=*.parquet")
        if p.stem.removeprefix("night=") <= night
    )
    cals = read_tables(tables, "calibrations") if tables else pl.DataFrame()
    out = []
    for row, d in night_scans(results, night, results / "stage" / "scans" / f"night={night}.parquet"):
        ref_kw, _ = discrepancy_reference(cals, row["device_id"], row["device_type"], night)
        try:
            out.append(discrepancy.analyse_scan(rawio.load_stored_scan(d), **settings, **ref_kw))
        except (ValueError, KeyError, ArithmeticError):
            continue
    return out


def time_plots(exs: list, out: Path) -> float:
    """Return the CPU seconds of drawing every examination's gap plot into ``out``, from empty caches."""
    from borescan.discrepancy import plot

    plot._FIGURES.clear()
    for cache in ("_STRIPS", "_BACKGROUNDS"):  # this checkout's caches, or an older one's
        getattr(plot, cache, {}).clear()
    t0 = time.process_time()
    for ex in exs:
        plot.plot_gap(ex, out / f"{ex.findings['scan_id']}.png")
    return time.process_time() - t0


def main(argv: list[str] | None = None) -> None:
    """Examine a processed night's scans and time their gap plots (arguments: see the module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m bench.bench_gap_plot")
    ap.add_argument("results", type=Path, nargs="?", default=os.environ.get("BENCH_GAP_SOURCE"))
    ap.add_argument("--night", help="the night to plot (default: the only one)")
    ap.add_argument("--out", type=Path, help="keep the plots here")
    # run by `python -m bench gap_plot` the command line is the runner's: the root from BENCH_GAP_SOURCE
    args = ap.parse_args(([] if __name__ != "__main__" else sys.argv[1:]) if argv is None else argv)
    if args.results is None:
        raise SystemExit("name a processed results root (or set BENCH_GAP_SOURCE)")
    night = _night_of(args.results, args.night)
    t0 = time.process_time()
    exs = examinations(args.results, night)
    print(f"{len(exs)} scans of night {night} examined in {time.process_time() - t0:.1f} CPU s (not timed)")
    repeats = int(os.environ.get("BENCH_GAP_REPEATS", "2"))
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        cpu = [time_plots(exs, out) for _ in range(repeats)]
    med = statistics.median(cpu)
    print(
        f"gap plots: {len(exs)} in {med:.2f} CPU s (median of {repeats}: "
        f"{', '.join(f'{c:.2f}' for c in cpu)}), {med / max(len(exs), 1) * 1e3:.0f} ms a plot"
    )


if __name__ == "__main__":
    main()
