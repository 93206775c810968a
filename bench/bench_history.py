"""A year of nights at the cost of one (issue 21): catalog and report per added night vs history.

A synthetic year is made cheaply from the processed demo nights
(:mod:`borescan.synthetic.history`: their stage tables copied under new nights and ids; every
synthetic night holds both demo nights, 18 scans of 2 devices, the same work each night;
``BENCH_HISTORY_COPIES=2`` doubles the devices).
Then night k is added to a history of k-1 nights, for k = 2, 30, 120, 365, and the two history
steps the workflow runs after a night's stage jobs are timed in this process:
``catalog.update_catalog`` (rule build_catalog) and ``update_report`` (rule
write_report). The history before each of those nights is saved, and the adds are timed in
``BENCH_HISTORY_REPEATS`` rounds, every checkpoint's add once a round from its saved history
(median shown): a change of the machine's load falls on all of them alike, and the target is
judged on the median of the rounds' own ratios (night 365 / night 2, CPU time). Prints the
catalog's size, a full rebuild for comparison and the time of every saved query
(``workflow/queries``) over the year. Targets: adding night 365 costs at most 1.2 times adding
night 2; every saved query under 1 s.

    python -m bench history
    BENCH_HISTORY_NIGHTS=120 python -m bench history          # shorter history
    BENCH_HISTORY_SOURCE=results python -m bench history      # copy nights of an existing run

Without ``BENCH_HISTORY_SOURCE`` the demo's two nights are first processed by
``snakemake --cores 2 catalog`` (a few minutes, not timed). Paper reproductions are not copied,
so the report's constant papers section is left out of both ends of the ratio.
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
START = "2027-01-01"
CHECKPOINTS = (2, 30, 120, 365)
TARGET_RATIO = 1.2
TARGET_QUERY_S = 1.0
CATALOG_FILES = ("catalog.duckdb", "catalog.duckdb.sha256")


def demo_results(tmp: Path) -> Path:
    """Return the demo's two nights processed up to the catalog (stage tables, certificates, findings)."""
    from borescan.synthetic import demo

    demo.make_demo(tmp / "demo")
    results = tmp / "demo-results"
    snakemake = Path(sys.executable).with_name("snakemake")
    cmd = [
        str(snakemake),
        "catalog",
        "--cores",
        "2",
        "--quiet",
        "all",
        "--config",
        f"raw_root={tmp / 'demo' / 'raw'}",
        f"results_root={results}",
    ]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        print(proc.stderr[-3000:])
        raise SystemExit("demo pipeline failed")
    return results


def _move_night(src_root: Path, dst_root: Path, night: str, place=os.replace) -> None:
    """Move a night's stage files from one results root to another (``place=os.link``: link them)."""
    for f in src_root.glob(f"stage/**/night={night}.parquet"):
        target = dst_root / f.relative_to(src_root)
        target.parent.mkdir(parents=True, exist_ok=True)
        place(f, target)


def _own_catalog(src_results: Path, dst_results: Path) -> None:
    """Give a hard-linked copy of a results root its own catalog and seal (written in place)."""
    for name in CATALOG_FILES:
        os.unlink(dst_results / name)
        shutil.copyfile(src_results / name, dst_results / name)


def _save_state(results: Path, pool: Path, night: str, state: Path) -> Path:
    """Save the history before ``night`` (results as hard links, the catalog copied) and the night's files.

    Every file of the results is replaced, never edited, except the catalog and its seal (copied).
    """
    shutil.copytree(results, state / "results", copy_function=os.link)
    _own_catalog(results, state / "results")
    _move_night(pool, state / "pool", night, place=os.link)
    return state


def _fresh_run(state: Path, run: Path) -> Path:
    """Return ``run`` holding a fresh copy of a saved history (:func:`_save_state`), ready for its night."""
    if run.exists():
        shutil.rmtree(run)
    shutil.copytree(state, run, copy_function=os.link)
    _own_catalog(state / "results", run / "results")
    return run


def add_night(results: Path, pool: Path, night: str) -> tuple[float, float, float, float, str]:
    """Move a night's stage files in, update catalog and report.

    Returns (catalog s, report s, catalog CPU s, report CPU s, what was done); CPU time is this
    process's, all threads, so other work on a shared machine does not count.
    """
    from borescan import catalog
    from borescan.report.pages import update_report

    _move_night(pool, results, night)
    t0, c0 = time.perf_counter(), time.process_time()
    cu = catalog.update_catalog(results)
    t1, c1 = time.perf_counter(), time.process_time()
    ru = update_report(results)
    t2, c2 = time.perf_counter(), time.process_time()
    return (
        t1 - t0,
        t2 - t1,
        c1 - c0,
        c2 - c1,
        f"catalog {cu.mode} {len(cu.added)} night(s), pages {','.join(ru.rendered)}, {ru.plots_drawn} plots",
    )


def _save_histories(results: Path, pool: Path, nights: list[str], checkpoints: list[int], tmp: Path) -> dict:
    """Grow the history (not timed) and save it before each checkpoint's night: k -> saved state."""
    from borescan import catalog
    from borescan.report.pages import update_report

    done, states = 0, {}
    for k in checkpoints:
        for night in nights[done : k - 1]:  # the history before night k, caught up at once
            _move_night(pool, results, night)
        catalog.update_catalog(results)
        update_report(results)
        done = k - 1
        states[k] = _save_state(results, pool, nights[k - 1], tmp / f"state-{k}")
    print(f"histories before nights {', '.join(map(str, checkpoints))} saved", flush=True)
    return states


def _time_rounds(states: dict, nights: list[str], repeats: int, run_dir: Path) -> tuple[dict, dict]:
    """Add each checkpoint's night to its saved history, once a round: (k -> runs, k -> (MB, rows)).

    The checkpoints are taken in turn within a round (the order reversed every other round), so
    a change of the machine's load falls on every checkpoint alike.
    """
    from borescan import catalog

    checkpoints = list(states)
    runs: dict[int, list] = {k: [] for k in checkpoints}
    sizes: dict[int, tuple[float, int]] = {}
    for r in range(repeats):
        for k in checkpoints if r % 2 == 0 else checkpoints[::-1]:
            run = _fresh_run(states[k], run_dir)
            runs[k].append(add_night(run / "results", run / "pool", nights[k - 1]))
            if k not in sizes:
                sizes[k] = (
                    (run / "results" / "catalog.duckdb").stat().st_size / 1e6,
                    sum(catalog.update_catalog(run / "results").rows.values()),  # unchanged: counts only
                )
        print(
            f"  round {r + 1}/{repeats}, CPU s: "
            + ", ".join(f"night {k} {runs[k][-1][2] + runs[k][-1][3]:.2f}" for k in checkpoints),
            flush=True,
        )
    for k in checkpoints:
        print(f"  night {k:3d} ({nights[k - 1]}): [{runs[k][-1][4]}]")
    return runs, sizes


def _print_table(runs: dict, sizes: dict, repeats: int) -> None:
    """Print the medians per checkpoint and the ratio of the last checkpoint to the first."""
    checkpoints = list(runs)
    rows = {}
    for k in checkpoints:
        med = [statistics.median(x[i] for x in runs[k]) for i in range(4)]
        rows[k] = (
            med[0],
            med[1],
            statistics.median(x[0] + x[1] for x in runs[k]),
            med[2],
            med[3],
            statistics.median(x[2] + x[3] for x in runs[k]),
            *sizes[k],
        )
    print()
    print(
        "adding night k to a history of k-1 nights (median of "
        f"{repeats}; in-process, Python start-up and imports not included;\n"
        "CPU time: this process's, not disturbed by other work on a shared machine)"
    )
    print(f"{'':28s}" + "".join(f"{'night ' + str(k):>12s}" for k in checkpoints))
    for label, i, fmt in (
        ("catalog update [s]", 0, "{:12.2f}"),
        ("report update [s]", 1, "{:12.2f}"),
        ("catalog + report [s]", 2, "{:12.2f}"),
        ("  CPU: catalog [s]", 3, "{:12.2f}"),
        ("  CPU: report [s]", 4, "{:12.2f}"),
        ("  CPU: catalog + report [s]", 5, "{:12.2f}"),
        ("catalog.duckdb [MB]", 6, "{:12.1f}"),
        ("catalog rows", 7, "{:12,d}"),
    ):
        print(f"{label:28s}" + "".join(fmt.format(rows[k][i]) for k in checkpoints))
    first, last = checkpoints[0], checkpoints[-1]
    for what, i in (("wall time", 2), ("CPU time", 5)):
        ratio = rows[last][i] / rows[first][i]
        print(f"night {last} / night {first}, {what}, of the medians: {ratio:.2f}")
    paired = statistics.median(
        (b[2] + b[3]) / (a[2] + a[3]) for a, b in zip(runs[first], runs[last], strict=True)
    )
    print(
        f"night {last} / night {first}, CPU time, median of the rounds' ratios: {paired:.2f}  "
        f"(target <= {TARGET_RATIO}) {'OK' if paired <= TARGET_RATIO else 'MISSED'}"
    )
    if 30 in rows and last > 30:  # the same month fill at both ends: the history's own growth
        print(
            f"night {last} / night 30, CPU time: {rows[last][5] / rows[30][5]:.2f} (not the target: both "
            "months' pages hold a whole month of nights, night 2's only two)"
        )


def _time_queries(results: Path, n_nights: int) -> None:
    """Time a full catalog rebuild and every saved query over the whole history."""
    from borescan import catalog

    t0 = time.perf_counter()
    full = catalog.rebuild_catalog(results)
    print(
        f"full catalog rebuild over {len(full.added)} nights: {time.perf_counter() - t0:.2f} s "
        f"(borescan rebuild-catalog; the same tables as the nightly path)"
    )

    con = catalog.open_catalog(results)
    try:
        print(f"saved queries over {n_nights} nights (median of 3, all rows fetched):")
        worst = 0.0
        for name in catalog.saved_queries():
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                n = len(con.execute(f"SELECT * FROM {name}").fetchall())
                times.append(time.perf_counter() - t0)
            worst = max(worst, statistics.median(times))
            print(f"  {name:28s} {statistics.median(times):8.3f} s  {n:8,d} rows")
        print(
            f"slowest saved query {worst:.3f} s (target < {TARGET_QUERY_S} s) "
            f"{'OK' if worst < TARGET_QUERY_S else 'MISSED'}"
        )
    finally:
        con.close()


def main() -> None:
    """Time the catalog's queries and the report on a synthetic history of many nights."""
    from borescan.synthetic import history as sh

    n_nights = int(os.environ.get("BENCH_HISTORY_NIGHTS", "365"))
    copies = int(os.environ.get("BENCH_HISTORY_COPIES", "1"))
    repeats = int(os.environ.get("BENCH_HISTORY_REPEATS", "5"))
    checkpoints = [k for k in CHECKPOINTS if k <= n_nights]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        source = (
            Path(os.environ["BENCH_HISTORY_SOURCE"])
            if os.environ.get("BENCH_HISTORY_SOURCE")
            else demo_results(tmp)
        )
        src = sh.read_source(source)
        results, pool = tmp / "results", tmp / "pool"
        nights = sh.copy_nights(src, results, START, range(n_nights), copies=copies, stage_root=pool)
        per_night = sum(t["scans"].height for t in src.tables.values()) * copies
        print(
            f"synthetic history: {n_nights} nights from {START}, {per_night} scans and "
            f"{len(src.devices) * copies} devices a night, made of {len(src.nights)} processed nights "
            f"(made in {time.perf_counter() - t0:.0f} s, not timed)",
            flush=True,
        )

        states = _save_histories(results, pool, nights, checkpoints, tmp)
        runs, sizes = _time_rounds(states, nights, repeats, tmp / "run")
        _print_table(runs, sizes, repeats)
        for night in nights[checkpoints[-1] - 1 :]:  # the whole history, for the rebuild and the queries
            _move_night(pool, results, night)
        _time_queries(results, n_nights)
