"""A year of nights at the cost of one (issue 21): catalog and report per added night vs history.

A synthetic year is made cheaply from the processed demo nights
(:mod:`borescan.synthetic.history`: their stage tables copied under new nights and ids; every
synthetic night holds both demo nights, 18 scans of 2 devices, the same work each night;
``BENCH_HISTORY_COPIES=2`` doubles the devices).
Then night k is added to a history of k-1 nights, for k = 2, 30, 120, 365, and the two history
steps the workflow runs after a night's stage jobs are timed in this process:
``catalog.update_catalog`` (rule build_catalog) and ``update_report`` (rule
write_report). Each add is timed ``BENCH_HISTORY_REPEATS`` times from the same saved state
(median shown). Prints the catalog's size, a full rebuild for comparison and the time of every
saved query (``workflow/queries``) over the year. Targets: adding night 365 costs at most 1.2
times adding night 2; every saved query under 1 s.

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


def _move_night(src_root: Path, dst_root: Path, night: str) -> None:
    for f in src_root.glob(f"stage/**/night={night}.parquet"):
        target = dst_root / f.relative_to(src_root)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(f, target)


def _snapshot(results: Path, snap: Path) -> None:
    if snap.exists():
        shutil.rmtree(snap)
    snap.mkdir()
    for name in CATALOG_FILES:  # the catalog and its seal: a catalog restored without it reads as damaged
        shutil.copyfile(results / name, snap / name)
    shutil.copytree(
        results / "report", snap / "report", copy_function=os.link
    )  # files are replaced, never edited
    shutil.copyfile(results / "report.html", snap / "report.html")


def _restore(results: Path, snap: Path) -> None:
    for name in CATALOG_FILES:
        shutil.copyfile(snap / name, results / name)
    shutil.rmtree(results / "report")
    shutil.copytree(snap / "report", results / "report", copy_function=os.link)
    shutil.copyfile(snap / "report.html", results / "report.html")


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


def main() -> None:
    """Time the catalog's queries and the report on a synthetic history of many nights."""
    from borescan import catalog
    from borescan.report.pages import update_report
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

        done, rows = 0, {}
        for k in checkpoints:
            for night in nights[done : k - 1]:  # the history before night k, caught up at once (not timed)
                _move_night(pool, results, night)
            catalog.update_catalog(results)
            update_report(results)
            done = k - 1
            snap = tmp / "snapshot"
            _snapshot(results, snap)
            runs = []
            for r in range(repeats):
                if r:
                    _move_night(results, pool, nights[k - 1])
                    _restore(results, snap)
                runs.append(add_night(results, pool, nights[k - 1]))
            done = k
            size_mb = (results / "catalog.duckdb").stat().st_size / 1e6
            n_rows = sum(catalog.update_catalog(results).rows.values())  # unchanged: counts only
            med = [statistics.median(r[i] for r in runs) for i in range(4)]
            rows[k] = (
                med[0],
                med[1],
                statistics.median(r[0] + r[1] for r in runs),
                med[2],
                med[3],
                statistics.median(r[2] + r[3] for r in runs),
                size_mb,
                n_rows,
            )
            print(
                f"  night {k:3d} ({nights[k - 1]}): catalog {med[0]:.2f} s, report {med[1]:.2f} s "
                f"[{runs[-1][4]}]",
                flush=True,
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
            print(
                f"night {last} / night {first}, {what}: {ratio:.2f}  (target <= {TARGET_RATIO}) "
                f"{'OK' if ratio <= TARGET_RATIO else 'MISSED'}"
            )
        if 30 in rows and last > 30:  # the same month fill at both ends: the history's own growth
            print(
                f"night {last} / night 30, CPU time: {rows[last][5] / rows[30][5]:.2f} (not the target: both "
                "months' pages hold a whole month of nights, night 2's only two)"
            )

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
