"""A night of many devices (issue 21): its jobs on --cores 1 and --cores 2, and the SLURM plan.

The demo's first night copied for ``BENCH_DEVICES`` devices (default 20: ten three-sensor
devices, each with its two calibration scans in RG-275, a ring-gauge verification and a part,
and ten measuring rods with a two-hole part each; 50 scans). ``scan.json`` is rewritten with the
new device and scan ids; the readings are hard-linked. ``snakemake catalog`` processes the night
from scratch with ``--cores 1`` and with ``--cores 2`` (papers and report are left out: they do
not depend on the night); printed: wall time, the time each rule's jobs took, and the speed-up.
Then ``snakemake --profile profiles/slurm --dry-run`` shows the SLURM jobs the night becomes.

    python -m bench devices
    BENCH_DEVICES=6 python -m bench devices      # smaller night
    BENCH_DEVICES_CORES=2 python -m bench devices  # only one run

A night job spreads its scans over its rule's threads (2), so ingest, signal, measure
and discrepancy use both cores, and calibrate_night its devices (one three-sensor device or one
rod calibration scan per process at a time).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: about 15 minutes on 2 cores (two full runs of a 50-scan night): ``make bench`` leaves it out
RUN_BY_DEFAULT = False
KEEP = ("-CAL-P1-A", "-CAL-P1-B", "-VER-RG275", "-MEAS-HSG1101", "-ROD01-MEAS-")


def make_night(src_night: Path, raw: Path, n_devices: int) -> int:
    """Copy the demo night for ``n_devices`` devices (half three-sensor, half rods); return scans written."""
    night = src_night.name
    n = 0
    for k in range(1, n_devices // 2 + 1):
        tri, rod = f"TRI{k:02d}", f"ROD{k:02d}"
        for d in sorted(src_night.iterdir()):
            if not any(tag in d.name for tag in KEEP):
                continue
            new_id = d.name.removeprefix("scan=").replace("TRI01", tri).replace("ROD01", rod)
            out = raw / night / f"scan={new_id}"
            out.mkdir(parents=True)
            meta = json.loads((d / "scan.json").read_text())
            meta["scan_id"] = new_id
            old_dev = meta["device"]["id"]
            new_dev = re.sub(r"-01$", f"-{k:02d}", old_dev)
            meta["device"]["id"] = new_dev
            for s in meta.get("sensors", []):
                if s.get("serial"):
                    s["serial"] = s["serial"].replace(old_dev, new_dev)
            (out / "scan.json").write_text(json.dumps(meta, indent=1) + "\n")
            for f in d.iterdir():
                if f.name != "scan.json":
                    os.link(f, out / f.name)
            n += 1
    return n


def run(raw: Path, results: Path, *args: str) -> subprocess.CompletedProcess:
    """Run Snakemake with ``args`` on the raw and results folders; return the finished process."""
    snakemake = Path(sys.executable).with_name("snakemake")
    cmd = [str(snakemake), *args, "--config", f"raw_root={raw}", f"results_root={results}"]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)


def main() -> None:
    """Time a night of many devices through the workflow on each number of cores."""
    from bench.bench_pipeline import job_times, union_seconds
    from borescan.synthetic import demo

    n_devices = int(os.environ.get("BENCH_DEVICES", "20"))
    cores_list = [int(c) for c in os.environ.get("BENCH_DEVICES_CORES", "1,2").split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        demo.make_demo(tmp / "demo")
        src_night = sorted((tmp / "demo" / "raw").iterdir())[0]
        raw = tmp / "raw"
        n_scans = make_night(src_night, raw, n_devices)
        print(
            f"one night: {n_devices} devices ({n_devices // 2} three-sensor, {n_devices // 2} rods), "
            f"{n_scans} scans",
            flush=True,
        )
        walls, per_rule = {}, {}
        for cores in cores_list:
            results = tmp / f"results-{cores}"
            t0 = time.perf_counter()
            proc = run(raw, results, "catalog", "--cores", str(cores), "--quiet", "all")
            walls[cores] = time.perf_counter() - t0
            if proc.returncode != 0:
                print(proc.stderr[-3000:])
                raise SystemExit(f"pipeline failed with --cores {cores}")
            jobs = job_times(results)
            per_rule[cores] = {rule: sum(b - a for a, b in iv) for rule, iv in jobs.items()}
            busy = union_seconds([x for iv in jobs.values() for x in iv])
            print(f"  --cores {cores}: wall {walls[cores]:.1f} s (some job running {busy:.1f} s)", flush=True)
        print()
        print(
            f"{'rule (time in its jobs) [s]':32s}"
            + "".join(f"{'--cores ' + str(c):>12s}" for c in cores_list)
        )
        for rule in sorted(per_rule[cores_list[0]], key=lambda r: -per_rule[cores_list[0]][r]):
            print(f"{rule:32s}" + "".join(f"{per_rule[c].get(rule, float('nan')):12.1f}" for c in cores_list))
        print(f"{'wall time [s]':32s}" + "".join(f"{walls[c]:12.1f}" for c in cores_list))
        if len(cores_list) > 1:
            a, b = cores_list[0], cores_list[-1]
            print(f"speed-up --cores {a} -> --cores {b}: {walls[a] / walls[b]:.2f}")

        proc = run(raw, tmp / "results-slurm", "catalog", "--profile", "profiles/slurm", "--dry-run")
        out = proc.stdout + proc.stderr
        if proc.returncode != 0:
            print(out[-3000:])
            raise SystemExit("SLURM profile dry run failed")
        stats = out[out.index("Job stats:") :].split("\n\n")[0]
        groups = re.findall(r"Group job (\w+)", out)
        print()
        print("snakemake --profile profiles/slurm --dry-run catalog (the SLURM jobs of this night):")
        print(stats)
        print(f"group jobs (several rules or nights in one SLURM job): {', '.join(groups) or 'none'}")
        print(f"SLURM submissions: {_submissions(out)}")


def _submissions(out: str) -> int:
    """Jobs the dry run plans, a group counting once, local rules not at all."""
    stats = out[out.index("Job stats:") :].split("\n\n")[0]
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", stats, re.M))
    total = int(counts.pop("total", 0))
    total -= int(counts.get("catalog", 0)) + int(counts.get("all", 0))
    members, in_group = [], False
    for line in out.splitlines():
        if re.search(r"Group job \w+ \(jobs in lexicogr\. order\):", line):
            members.append(0)
            in_group = True
        elif in_group and re.match(r"    Job \d+:", line):
            members[-1] += 1
        elif in_group and line.startswith(("[", "Job", "rule", "localrule")):  # the next job, not indented
            in_group = False
    return total - sum(n - 1 for n in members if n)
