"""Reference night from raw to catalog and report with ``snakemake --cores 2`` (issue 6).

A night of N three-sensor spindle scans (60 revolutions x 660 samples x 3 channels; 4 of them
calibration scans in the 275.029 mm ring gauge, the rest rotating measurements of bores) plus
M rod scans. Prints wall time, readings per second and the share of wall time that is workflow
overhead (wall time during which no job was running; Snakemake records every job's run time
in ``results/benchmarks``). Target (issue 21): <= 30 s and <= 20 % overhead for N = 100, M = 20.

The reproduction of the papers is not part of a night once it has run: the ``papers`` target
runs first into the same results folder, untimed, then the night is timed. The device is
``TRI-REF`` (not the demo's TRI-01, whose device model config/devices.yaml dates from 2026-11-24).

    python -m bench pipeline            # the reference night (N = 100, M = 20)
    BENCH_PIPELINE_SCANS=20 python -m bench pipeline   # scaled down
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NIGHT = "2026-11-30"


def make_night(raw: Path, truth: Path, n_tri: int, n_rod: int) -> int:
    """Write the reference night; returns the number of readings."""
    import numpy as np

    from borescan.synthetic import demo, scenes, simulate

    base = scenes.default_tri_scene()
    readings = 0
    for i in range(n_tri):
        cal = i < 4
        if cal:
            scene = replace(base, spindle_xy_mm=scenes.YANG_P1_XY_MM, phase_rad=0.3 * i)
            kw = dict(
                artifact=demo.RG275,
                spindle_label="P1",
                center_xy_mm=scenes.YANG_P0_XY_MM,
                kind="calibration",
            )
        else:
            d = 276.0 + 4.0 * (i % 10) / 10
            scene = replace(
                base,
                bore_center_xy_mm=(0.0, 0.0),
                bore_radius_20_mm=d / 2,
                spindle_xy_mm=(1.5 * np.cos(i), 1.5 * np.sin(i)),
                phase_rad=0.1 * i,
            )
            kw = dict(
                artifact={
                    "id": f"HSG-{2000 + i}",
                    "type": "part",
                    "nominal_diameter_mm": round(d, 1),
                    "cte_per_k": 11.5e-6,
                },
                spindle_label="BORE",
                kind="measurement",
            )
        sim = simulate.simulate_tri_spindle(
            scene,
            n_rev=60,
            nominal_beams=demo.NOMINAL_BEAMS,
            scan_id=f"REF-TRI-{i:03d}",
            night=NIGHT,
            seed=1000 + i,
            started_at=simulate.started_at_plus(NIGHT, 20, 0),
            device_id="TRI-REF",
            **kw,
        )
        simulate.write_simulated(sim, raw, truth)
        readings += sim.lds.height
    for j in range(n_rod):
        sim = simulate.simulate_rod(
            scenes.default_rod_scene(),
            n_poses=24,
            samples_per_pose=5,
            artifact={"id": f"CYL-{j}", "type": "part", "nominal_diameter_mm": 150.0, "cte_per_k": 11.5e-6},
            features=("H1", "H2"),
            device_id="ROD-01",
            scan_id=f"REF-ROD-{j:03d}",
            night=NIGHT,
            kind="measurement",
            seed=5000 + j,
            started_at=simulate.started_at_plus(NIGHT, 21, 0),
        )
        simulate.write_simulated(sim, raw, truth)
        readings += sim.lds.height
    return readings


def job_times(results: Path) -> dict[str, list[tuple[float, float]]]:
    """(start, end) epoch seconds of every job, per rule, from Snakemake's benchmark files.

    A benchmark file is written when its job ends, so its mtime is the end and mtime - s the start.
    """
    out: dict[str, list[tuple[float, float]]] = {}
    for tsv in sorted((results / "benchmarks").rglob("*.tsv")):
        rule = tsv.parent.name if tsv.parent != results / "benchmarks" else tsv.stem
        with tsv.open() as fh:
            row = next(csv.DictReader(fh, delimiter="\t"))
        end = tsv.stat().st_mtime
        out.setdefault(rule, []).append((end - float(row["s"]), end))
    return out


def union_seconds(intervals: list[tuple[float, float]]) -> float:
    """Length of the union of time intervals [s]: the time at least one job was running."""
    total, cur_start, cur_end = 0.0, None, None
    for a, b in sorted(intervals):
        if cur_end is None or a > cur_end:
            if cur_end is not None:
                total += cur_end - cur_start
            cur_start, cur_end = a, b
        else:
            cur_end = max(cur_end, b)
    return total + (cur_end - cur_start if cur_end is not None else 0.0)


def main() -> None:
    """Time the workflow on a generated reference night."""
    n_tri = int(os.environ.get("BENCH_PIPELINE_SCANS", "100"))
    n_rod = max(1, n_tri // 5)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        readings = make_night(tmp / "raw", tmp / "truth", n_tri, n_rod)
        print(
            f"reference night: {n_tri} tri scans (60 rev x 660 x 3) + {n_rod} rod scans, {readings:,} "
            "readings "
            f"(generated in {time.perf_counter() - t0:.1f} s, not timed)",
            flush=True,
        )
        snakemake = Path(sys.executable).with_name("snakemake")
        config = ["--config", f"raw_root={tmp / 'raw'}", f"results_root={tmp / 'results'}"]
        t0 = time.perf_counter()
        papers = subprocess.run(
            [str(snakemake), "papers", "--cores", "2", "--quiet", "all", *config],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        if papers.returncode != 0:
            print(papers.stderr[-3000:])
            raise SystemExit("papers failed")
        print(
            f"papers reproduced first in {time.perf_counter() - t0:.1f} s (not part of a night, not timed)",
            flush=True,
        )
        for f in (tmp / "results" / "benchmarks").rglob("*.tsv"):
            f.unlink()  # the night's job times only
        cmd = [str(snakemake), "--cores", "2", "--quiet", "all", *config]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            print(proc.stderr[-3000:])
            raise SystemExit("pipeline failed")
        jobs = job_times(tmp / "results")
        print(f"wall time            {wall:8.1f} s   (target <= 30 s for 100 + 20 scans)")
        print(f"throughput           {readings / wall:12,.0f} readings/s")
        for rule, iv in sorted(jobs.items(), key=lambda kv: -sum(b - a for a, b in kv[1])):
            print(f"  {rule:22s} {sum(b - a for a, b in iv):8.1f} s in its jobs")
        # Overhead: wall time during which no job was running (Snakemake start-up, DAG, job
        # launches, scheduling gaps). Jobs that overlap (2 cores) count once.
        busy = union_seconds([x for iv in jobs.values() for x in iv])
        overhead = max(0.0, wall - busy)
        print(f"some job running     {busy:8.1f} s")
        print(
            f"workflow overhead    {overhead:8.1f} s = {100 * overhead / wall:.0f} % of wall (target <= 20 %)"
        )
