"""A fault battery on copies of the demo's first night (issue 40): what a real gauge room produces.

Input faults (one scan or folder each, beside the untouched demo night, one workflow run
``snakemake --cores 2 catalog``, as the user nobody when run as root): the bad-input battery of the
tests (``tests/bad_inputs.py``: format, tables, clocks, spindle streams in other units, symlinks,
stage faults), a joint calibration spoiled by one scan's encoder stream (the scan blamed alone, its
partner used), the absurd numbers of ``scan.json`` (``tests/fault_roots.py``: range, temperatures,
uncertainties, tolerances, dates, certified diameters), files and a folder written with umask 077 by
another user, an empty night, a night folder that is no date, a rod-only night. Process faults (a rod
night each, small runs): a night added with its old times run from a second checkout, the same on a
copied results root, a config edit, a recomputation asked for, a catalog cut in half, a run killed
with SIGKILL.

Per case one line: processed / quarantined (the reason, which names the key, file or folder) /
skipped (the reason) / crashed, and whether the raw files stayed byte-identical.

    python -m bench faults
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the battery's builders are the tests' (one definition)

RUN_BY_DEFAULT = False  # several workflow runs: minutes


@dataclass(frozen=True)
class Outcome:
    """How the pipeline handled one fault case, and whether the raw files stayed unchanged."""

    case: str
    result: str  # processed | quarantined | skipped | crashed
    detail: str
    raw_unchanged: bool


def _run(checkout: Path, raw: Path, res: Path, home: Path, *extra: str, user=lambda c: c):
    from test_faults import _workflow

    return _workflow(checkout, raw, res, home, *extra, user=user)


def _checksums(root: Path) -> dict[str, str]:
    from conftest import checksums

    return checksums(root)


def input_battery(  # noqa: C901 (one branch per kind of input fault and its expected outcome)
    tmp: Path, demo_raw: Path
) -> list[Outcome]:
    """Every input fault under one raw root, processed by one workflow run."""
    import duckdb

    from bad_inputs import make_bad_scans, make_stage_cases
    from fault_roots import (
        PLAUSIBILITY_CASES,
        as_nobody,
        can_drop_to_nobody,
        checkout_copy,
        copy_scan,
        give_to_nobody,
        make_crash_root,
    )

    raw = tmp / "raw"
    crash = make_crash_root(
        demo_raw, raw
    )  # rod night, refused calibration, empty night, 2026-02-30, umask 077
    night20 = demo_raw / "night=2026-11-20"
    for d in sorted(night20.iterdir()):
        if not (raw / "night=2026-11-20" / d.name).exists():
            copy_scan(d, raw, "2026-11-20", d.name[5:])
    bad_night = "2026-11-23"
    good_tri = night20 / "scan=N20261120-TRI01-CAL-P1-A"
    cases = make_bad_scans(
        raw, bad_night, good_tri, night20 / "scan=N20261120-ROD01-MEAS-CYL2H", "N20261120-TRI01-CAL-P1-A"
    )
    stage_cases, _ = make_stage_cases(raw, tmp / "truth", bad_night)
    expected = {c.scan_id: (c.file, c.problem) for c in cases + stage_cases}
    for i, (_name, src, edit, text) in enumerate(PLAUSIBILITY_CASES):
        d = copy_scan(night20 / src, raw, bad_night, f"PLAUS-{i:02d}")
        meta = json.loads((d / "scan.json").read_text())
        meta["started_at"] = meta["started_at"].replace("2026-11-20", bad_night)
        edit(meta)
        (d / "scan.json").write_text(json.dumps(meta, indent=1))
        expected[f"PLAUS-{i:02d}"] = ("scan.json", text)
    expected.update(_joint_fit_cases(night20, raw, bad_night))
    for p in raw.rglob("*"):
        if "UMASK077" not in str(p):
            p.chmod(0o755 if p.is_dir() else 0o644)
    before = _checksums(raw) if os.geteuid() == 0 else None  # root reads the umask-077 files too
    co, res, home = checkout_copy(ROOT, tmp / "checkout"), tmp / "results", tmp / "home"
    res.mkdir(), home.mkdir()
    user = lambda c: c  # noqa: E731
    if can_drop_to_nobody():
        give_to_nobody(co, res, home)
        user = as_nobody
    t0 = time.perf_counter()
    proc = _run(co, raw, res, home, "catalog", user=user)
    print(
        f"input battery: one workflow run over {len(list(raw.glob('night=*/scan=*')))} scan folders in "
        f"{time.perf_counter() - t0:.0f} s, exit {proc.returncode}"
    )
    raw_same = before is None or _checksums(raw) == before
    if proc.returncode != 0:
        print(proc.stderr[-3000:])
        return [Outcome("input battery", "crashed", f"snakemake exit {proc.returncode}", raw_same)]
    con = duckdb.connect(str(res / "catalog.duckdb"), read_only=True)
    rows = {s: (st, r) for s, st, r in con.execute("SELECT scan_id, status, reason FROM scans").fetchall()}
    out = []
    for sid in sorted(set(expected) | {crash.unreadable_file, crash.unreadable_folder}):
        st, reason = rows.get(sid, ("missing", "not in the catalog"))
        out.append(
            Outcome(
                sid,
                "quarantined" if st == "quarantined" else "processed" if st == "ok" else "crashed",
                reason or "",
                raw_same,
            )
        )
    log = (res / "logs" / "build_catalog.log").read_text()
    for line in log.splitlines():
        if "SKIPPED" in line:
            out.append(
                Outcome(
                    line.split("SKIPPED ")[1].split(":")[0], "skipped", line.split("SKIPPED ")[1], raw_same
                )
            )
    for night in ("2026-11-20", "2026-11-21", crash.empty_night):
        ok = all(
            (res / "stage" / t / f"night={night}.parquet").is_file() for t in ("scans", "pooled_findings")
        )
        n = con.execute("SELECT count(*) FROM scans WHERE night = ?", [night]).fetchone()[0]
        out.append(
            Outcome(
                f"night {night} "
                f"({'rod only, refused calibration' if night == '2026-11-21' else 'empty' if night == crash.empty_night else 'demo + rod + umask 077'})",  # noqa: E501 (one conditional inside the f-string)
                "processed" if ok else "crashed",
                f"{n} scans in the catalog, every stage table written",
                raw_same,
            )
        )
    return out


def _joint_fit_cases(night20: Path, raw: Path, night: str) -> dict[str, tuple[str, str]]:
    """Write a device's two calibration scans, one with an encoder stream that does not fit its readings.

    The angle is 1.5 times what it was (it passes every format check): the joint fit fails, the spoiled
    scan is blamed alone and its partner calibrates the device (issue 40 item 11).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq
    from fault_roots import copy_scan

    out = {}
    for src, sid in (
        ("N20261120-TRI01-CAL-P1-A", "JOINT-FIT-SPOILED"),
        ("N20261120-TRI01-CAL-P1-B", "JOINT-FIT-PARTNER"),
    ):
        d = copy_scan(night20 / f"scan={src}", raw, night, sid)
        meta = json.loads((d / "scan.json").read_text())
        meta["device"]["id"], meta["started_at"] = "TRI-09", meta["started_at"].replace("2026-11-20", night)
        (d / "scan.json").write_text(json.dumps(meta, indent=1))
        out[sid] = ("calibrate stage", "calibration failed on its own") if "SPOILED" in sid else ("", "")
    d = raw / f"night={night}" / "scan=JOINT-FIT-SPOILED"
    t = pq.read_table(d / "spindle.parquet")
    a = t.column("angle_rad").to_numpy()
    i = t.schema.get_field_index("angle_rad")
    pq.write_table(
        t.set_column(i, t.schema.field(i), pa.array(a[0] + 1.5 * (a - a[0]))), d / "spindle.parquet"
    )
    return out


def _rod_night(demo_raw: Path, raw: Path, night: str) -> None:
    from test_faults import _rod_night as rod_night

    rod_night(demo_raw, raw, night)


def process_battery(tmp: Path, demo_raw: Path) -> list[Outcome]:
    """Process faults on rod nights (the cheapest nights that run every stage)."""
    import duckdb

    from fault_roots import checkout_copy

    out = []
    raw, res, home = tmp / "raw", tmp / "results", tmp / "home"
    home.mkdir()
    a, b = checkout_copy(ROOT, tmp / "A"), checkout_copy(ROOT, tmp / "B")
    _rod_night(demo_raw, raw, "2026-11-20")
    _run(a, raw, res, home, "catalog")
    before = _checksums(raw)
    past = {k: v for k, v in _checksums(res / "stage").items() if "2026-11-20" in k}
    _rod_night(demo_raw, raw, "2026-11-21")
    before = _checksums(raw)
    copied = tmp / "copied-results"
    shutil.copytree(res, copied, symlinks=True)
    for name, checkout, results in (
        ("night added with cp -a, run from a second checkout", b, res),
        ("night added with cp -a, on a copied results root", a, copied),
    ):
        proc = _run(checkout, raw, results, home, "catalog")
        con = duckdb.connect(str(results / "catalog.duckdb"), read_only=True)
        n = con.execute("SELECT count(*) FROM scans WHERE night = '2026-11-21'").fetchone()[0]
        con.close()
        out.append(
            Outcome(
                name,
                "processed" if proc.returncode == 0 and n == 2 else "crashed",
                f"{n} scans of the added night in the catalog",
                _checksums(raw) == before,
            )
        )
    cfg = a / "config" / "config.yaml"
    cfg.write_text(cfg.read_text().replace("  tolerance_mm: 0.015\n", "  tolerance_mm: 0.002\n"))
    proc = _run(a, raw, copied, home, "catalog")
    same = {k: v for k, v in _checksums(copied / "stage").items() if "2026-11-20" in k} == past
    out.append(
        Outcome(
            "config edit (verification.tolerance_mm)",
            "processed" if proc.returncode == 0 and same else "crashed",
            "past night's stage tables byte-identical" if same else "PAST NIGHT REWRITTEN",
            _checksums(raw) == before,
        )
    )
    proc = subprocess.run(
        [sys.executable, "-m", "borescan.cli", "recompute", "--from", "2026-11-20", "--results", str(copied)],
        cwd=a,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(a / "src")},
    )
    rerun = _run(a, raw, copied, home, "catalog")
    out.append(
        Outcome(
            "borescan recompute --from 2026-11-20",
            "processed" if rerun.returncode == 0 else "crashed",
            proc.stdout.strip()[:160],
            _checksums(raw) == before,
        )
    )
    final = res / "catalog.duckdb"
    final.write_bytes(final.read_bytes()[: final.stat().st_size // 2])
    proc = _run(b, raw, res, home, "catalog")
    from borescan import catalog

    ok = proc.returncode == 0 and catalog.catalog_damage(final) is None
    out.append(
        Outcome(
            "catalog.duckdb cut in half",
            "processed" if ok else "crashed",
            "set aside and rebuilt by the next run" if ok else proc.stderr[-200:],
            _checksums(raw) == before,
        )
    )
    out.append(_killed_run(a, demo_raw, tmp))
    return out


def _killed_run(checkout: Path, demo_raw: Path, tmp: Path) -> Outcome:
    """SIGKILL to the whole run during its night jobs, then the same command again."""
    from test_faults import _python_for

    raw, res, home = tmp / "kill-raw", tmp / "kill-results", tmp / "home"
    _rod_night(demo_raw, raw, "2026-11-20")
    before = _checksums(raw)
    python, _ = _python_for(lambda c: c)
    cmd = [
        *python,
        "-m",
        "snakemake",
        "--cores",
        "2",
        "catalog",
        "--config",
        f"raw_root={raw}",
        f"results_root={res}",
    ]
    env = {
        "PATH": f"{Path(python[0]).parent}:/usr/bin:/bin",
        "HOME": str(home),
        "PYTHONPATH": str(checkout / "src"),
    }
    p = subprocess.Popen(
        cmd,
        cwd=checkout,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.time() + 300
    while time.time() < deadline and not (res / "stage" / "scans").exists():
        time.sleep(0.2)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    proc = _run(checkout, raw, res, home, "catalog")
    first = next((line for line in (proc.stdout + proc.stderr).splitlines() if "lock" in line.lower()), "")
    return Outcome(
        "snakemake killed with SIGKILL mid-run, then rerun",
        "processed" if proc.returncode == 0 else "crashed",
        "recovered by itself" if proc.returncode == 0 else first[:160],
        _checksums(raw) == before,
    )


def main() -> None:
    """Run the input and processing fault batteries on the demo nights and print one line per case."""
    from borescan.synthetic import demo

    with tempfile.TemporaryDirectory(prefix="bench-faults-") as t:
        tmp = Path(t)
        tmp.chmod(0o755)
        demo.make_demo(tmp / "demo")
        demo_raw = tmp / "demo" / "raw"
        (tmp / "in").mkdir(mode=0o755)
        (tmp / "proc").mkdir(mode=0o755)
        outcomes = input_battery(tmp / "in", demo_raw) + process_battery(tmp / "proc", demo_raw)
    width = max(len(o.case) for o in outcomes)
    for o in outcomes:
        print(
            f"{o.case:<{width}}  {o.result:<11}  raw "
            f"{'unchanged' if o.raw_unchanged else 'CHANGED'}  {o.detail}"
        )
    counts = {
        r: sum(o.result == r for o in outcomes) for r in ("processed", "quarantined", "skipped", "crashed")
    }
    print(
        f"{len(outcomes)} cases: "
        + ", ".join(f"{n} {r}" for r, n in counts.items())
        + f"; raw changed in {sum(not o.raw_unchanged for o in outcomes)}"
    )


if __name__ == "__main__":
    main()
