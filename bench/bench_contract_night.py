"""A night drawn over the whole contract, raw to report with ``snakemake --cores 2`` (issue 38).

The night is written by ``borescan simulate contract`` (:func:`borescan.synthetic.battery.write_battery`):
N scans of each kind (default N = 24, 120 scans) on one night: three-sensor ring-gauge
calibrations (one device each; one or two speeds, encoder or not, a channel leaving its range,
nulls), rotating measurements of parts on those devices, static three-sensor sets (ring gauges
and parts), rod scans (ring-gauge sets and parts) and rod calibrations. About half the scans
carry one named effect of the registry, its size times a factor log-uniform in 0.3-3 of the
battery's realistic size (just visible to large), so that some calibrations are refused and
their devices are examined against the design geometry with the beams free.

The reproduction of the papers runs first into the same results folder, untimed (not part of a
night). Then the night is timed: wall time, the load average meanwhile, the CPU time of the whole
run, of Snakemake itself and of each rule's jobs (workers and imports included: each job log's last
line, ``borescan.workflow_log.job_cpu_line``), each rule's job time (Snakemake's benchmark files),
and per stage the percentiles (50, 95, max) of the CPU seconds of each scan's (calibration:
each device's; pooled: each device's) work, read from the ``compute <item> <s> s`` lines the
stages write to their logs (:func:`borescan.workflow_log.compute_line`; never into a table).

    python -m bench contract_night                      # N = 24 per kind, --cores 2
    python -m bench.bench_contract_night --cores 1 2    # the same night on 1 and 2 cores, side by side
    BENCH_CONTRACT_N=8 python -m bench contract_night   # scaled down
    python -m bench.bench_contract_night --keep K       # keep the night and its results in K
    OPENBLAS_NUM_THREADS=1 python -m bench.bench_contract_night --devices K/results_cores2 --repeat 2

``--devices RESULTS`` times the three-sensor calibrations alone: the calibrate stage's job of every
tri_lds device of the night (:func:`borescan.stages.calibrate.calibrate_device`: fit, budget,
certificate) run again in this process on a copy of a kept results root, each on the CPU clock
(``time.process_time``); run it with two checkouts' ``PYTHONPATH`` in turn to compare them.

Targets (issue 38, benchmark not test): <= 60 s wall on 2 cores, no scan's stage work over 10 s,
95th percentile under 2 s.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.bench_pipeline import job_cpu, job_times, run_timed, union_seconds

ROOT = Path(__file__).resolve().parents[1]
KINDS = "calibration,measurement,static,rod,rod_calibration"
NIGHT = "2027-01-01"
STAGES = ("signal_night", "calibrate_night", "measure_night", "discrepancy_night", "pooled_night")


def write_night(out: Path, n: int, seed: int) -> None:
    """``borescan simulate contract``: N scans of each kind on one night, half with an effect."""
    borescan = Path(sys.executable).with_name("borescan")
    cmd = [
        str(borescan),
        "simulate",
        "contract",
        "--n",
        str(n),
        "--seed",
        str(seed),
        "--out",
        str(out),
        "--kinds",
        KINDS,
        "--effect-share",
        "0.5",
        "--effect-scale",
        "0.3",
        "3",
        "--per-night",
        str(10 * n),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"simulate contract failed: {proc.stderr[-2000:]}")


def compute_seconds(results: Path) -> dict[str, list[tuple[str, float]]]:
    """Per rule, (item, CPU seconds) of every ``compute`` line of its logs."""
    from borescan.workflow_log import COMPUTE_RE

    out: dict[str, list[tuple[str, float]]] = {}
    for log in sorted((results / "logs").rglob("*.log")):
        for line in log.read_text().splitlines():
            m = COMPUTE_RE.search(line)
            if m:
                out.setdefault(log.parent.name, []).append((m["item"], float(m["seconds"])))
    return out


def run_night(raw: Path, results: Path, cores: int) -> dict:
    """One timed run of the night into ``results`` (which already holds the papers)."""
    snakemake = Path(sys.executable).with_name("snakemake")
    for f in (results / "benchmarks").rglob("*.tsv"):
        f.unlink()  # the night's job times only
    cmd = [
        str(snakemake),
        "--cores",
        str(cores),
        "--quiet",
        "all",
        "--config",
        f"raw_root={raw}",
        f"results_root={results}",
    ]
    run = run_timed(cmd, ROOT)
    if run.returncode != 0:
        print(run.stderr[-3000:])
        raise SystemExit("pipeline failed")
    jobs = job_times(results)
    busy = union_seconds([x for iv in jobs.values() for x in iv])
    cpu = {r: sum(v) for r, v in job_cpu(results, run.started_at).items()}
    return {
        "wall": run.wall_s,
        "cpu": run.cpu_s,
        "snakemake_cpu": run.cpu_s - sum(cpu.values()),
        "load": (run.load_min, run.load_median, run.load_max),
        "jobs": {r: sum(b - a for a, b in iv) for r, iv in jobs.items()},
        "jobs_cpu": cpu,
        "busy": busy,
        "compute": compute_seconds(results),
    }


def device_cpu(results: Path, repeat: int) -> dict[str, list[float]]:
    """CPU seconds of each three-sensor device's calibrate job of a kept night, ``repeat`` times each.

    The jobs are those :func:`borescan.stages.calibrate.stage_calibrate` builds (the config's schema
    defaults), run in this process on a copy of ``results`` (a job writes its certificates there).
    """
    from borescan.config import schema_defaults
    from borescan.stages._common import night_scans
    from borescan.stages.calibrate import calibrate_device
    from borescan.stages.calibrate_jobs import CalibrationJob, CalibrationSettings

    import polars as pl

    dflt = schema_defaults()
    stage = results / "stage"
    scans_table = stage / "scans" / f"night={NIGHT}.parquet"
    summary = pl.read_parquet(stage / "signal_summary" / f"night={NIGHT}.parquet")
    out: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "results"
        shutil.copytree(results, copy, symlinks=True)
        settings = CalibrationSettings(
            uncertainty=dflt["uncertainty"],
            laboratory=dflt["laboratory"],
            verification=dflt["verification"],
            signal=dflt["signal"],
            raw_root=copy,
            scans_table=scans_table,
            devices=None,
            night=NIGHT,
            pooled_rows=(),
            auto_nights=0,
        )
        by_device: dict[str, list] = {}
        for row, d in night_scans(copy, NIGHT, scans_table, kind="calibration", device_type="tri_lds"):
            by_device.setdefault(row["device_id"], []).append((row, d))
        for device, items in sorted(by_device.items()):
            job = CalibrationJob("tri", tuple(items), copy, summary, dflt["calibration"], settings)
            for _ in range(repeat):
                t0 = time.process_time()
                calibrate_device(job)
                out.setdefault(device, []).append(time.process_time() - t0)
    return out


def percentiles(items: list[tuple[str, float]]) -> tuple[float, float, float, str]:
    """Return the median, 95th percentile and maximum of the timings, and the slowest item's name."""
    s = np.array([x for _, x in items])
    worst = max(items, key=lambda z: z[1])
    return float(np.percentile(s, 50)), float(np.percentile(s, 95)), float(s.max()), worst[0]


def report(runs: dict[int, dict], n_scans: int) -> None:
    """Print the timings of each ``--cores`` run side by side, one row per figure."""
    cores = sorted(runs)
    head = "".join(f"{f'--cores {c}':>14}" for c in cores)
    print(f"{'':34}{head}")
    print(
        f"{'wall time [s]':34}"
        + "".join(f"{runs[c]['wall']:14.1f}" for c in cores)
        + "   (target <= 60 s on 2 cores)"
    )

    def row(label: str, cell) -> None:
        print(f"{label:34}" + "".join(f"{cell(runs[c]):>14}" for c in cores))

    row("load average (min-max)", lambda r: f"{r['load'][0]:.1f}-{r['load'][2]:.1f}")
    print(f"{'':34}(on 2 cores a load above 2 means the run waited for a core: read the CPU seconds)")
    row("CPU, Snakemake and all jobs [s]", lambda r: f"{r['cpu']:.1f}")
    row("CPU, Snakemake itself [s]", lambda r: f"{r['snakemake_cpu']:.1f}")
    row("some job running [s]", lambda r: f"{r['busy']:.1f}")
    rules = sorted(
        {r for c in cores for r in runs[c]["jobs"]}, key=lambda r: -runs[cores[-1]]["jobs_cpu"].get(r, 0.0)
    )
    print("per rule: job time / CPU [s] (CPU: user + sys of the job and its workers, imports included)")
    nan = float("nan")
    for rule in rules:
        row(f"  {rule}", lambda r, k=rule: f"{r['jobs'].get(k, nan):.1f} / {r['jobs_cpu'].get(k, nan):.1f}")
    print("per-item compute [CPU s]: items  p50  p95  max (slowest item)   (targets: p95 < 2 s, max <= 10 s)")
    for stage in STAGES:
        for c in cores:
            items = runs[c]["compute"].get(stage)
            if not items:
                continue
            p50, p95, mx, worst = percentiles(items)
            print(f"  {stage:22} cores {c}  {len(items):4d} {p50:6.2f} {p95:6.2f} {mx:7.2f}  ({worst})")
    print(f"{n_scans} scans")


def main(argv: list[str] | None = None) -> None:
    """Write a contract night, run the workflow on it once per ``--cores`` value and print the timings."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--n", type=int, default=int(os.environ.get("BENCH_CONTRACT_N", "24")), help="scans of each kind"
    )
    ap.add_argument("--seed", type=int, default=38)
    ap.add_argument(
        "--cores", type=int, nargs="+", default=[2], help="run the night once per value, side by side"
    )
    ap.add_argument("--keep", type=Path, default=None, help="keep the night and its results in this folder")
    ap.add_argument(
        "--devices", type=Path, default=None, help="time the three-sensor calibrations of a kept run"
    )
    ap.add_argument("--repeat", type=int, default=1, help="with --devices: runs of each device's job")
    a, _ = ap.parse_known_args(argv if argv is not None else sys.argv[1:])
    if a.devices is not None:
        for device, cpu in device_cpu(a.devices, a.repeat).items():
            print(f"{device:20} " + " ".join(f"{x:7.3f}" for x in cpu) + "  CPU s")
        return
    with tempfile.TemporaryDirectory() as tmp:
        work = a.keep or Path(tmp)
        night = work / "night"
        t0 = time.perf_counter()
        write_night(night, a.n, a.seed)
        n_scans = len(list((night / "raw").glob("night=*/scan=*")))
        print(
            f"contract night: {n_scans} scans ({a.n} of each of {KINDS}), seed {a.seed}, half with an effect "
            f"(written in {time.perf_counter() - t0:.0f} s, not timed)",
            flush=True,
        )
        snakemake = Path(sys.executable).with_name("snakemake")
        papers = work / "papers_only"
        t0 = time.perf_counter()
        proc = subprocess.run(
            [
                str(snakemake),
                "papers",
                "--cores",
                "2",
                "--quiet",
                "all",
                "--config",
                f"raw_root={night / 'raw'}",
                f"results_root={papers}",
            ],
            cwd=ROOT,
            capture_output=True,
            check=False,
            text=True,
        )
        if proc.returncode != 0:
            print(proc.stderr[-3000:])
            raise SystemExit("papers failed")
        print(
            f"papers reproduced first in {time.perf_counter() - t0:.0f} s (not part of a night, not timed)",
            flush=True,
        )
        runs = {}
        for c in a.cores:
            results = work / f"results_cores{c}"
            shutil.rmtree(results, ignore_errors=True)
            shutil.copytree(papers, results, symlinks=True)
            runs[c] = run_night(night / "raw", results, c)
            print(f"  --cores {c}: {runs[c]['wall']:.1f} s wall", flush=True)
        report(runs, n_scans)


if __name__ == "__main__":
    main()
