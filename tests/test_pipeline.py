"""The whole pipeline, run by Snakemake on the embedded demo nights (issue 6 tests).

One session-scoped run on a copy of the demo nights plus one deliberately corrupt scan;
the tests then read the catalog and the result files.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import duckdb
import pytest

from borescan import demo, rawio

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = Path(sys.executable).with_name("snakemake")


def run_snakemake(raw_root: Path, results_root: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [str(SNAKEMAKE), "--cores", "2", "--config", f"raw_root={raw_root}", f"results_root={results_root}", *extra]
    env = {"PATH": f"{SNAKEMAKE.parent}:/usr/bin:/bin", "HOME": str(results_root.parent), "MPLBACKEND": "Agg"}
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=900)


def checksums(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): rawio.sha256_file(p) for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session")
def pipeline_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("pipeline")
    demo.make_demo(base / "demo")
    raw = base / "demo" / "raw"
    # A truncated lds.parquet in a copy of a good scan: must be quarantined, never stop the night.
    night = sorted(raw.iterdir())[0]
    good = sorted(night.iterdir())[0]
    bad = night / "scan=BROKEN-TRUNCATED"
    shutil.copytree(good, bad)
    meta = json.loads((bad / "scan.json").read_text())
    meta["scan_id"] = "BROKEN-TRUNCATED"
    (bad / "scan.json").write_text(json.dumps(meta))
    data = (bad / "lds.parquet").read_bytes()
    (bad / "lds.parquet").write_bytes(data[: len(data) // 2])
    before = checksums(raw)
    results = base / "results"
    proc = run_snakemake(raw, results)
    return {"raw": raw, "results": results, "proc": proc, "before": before}


def test_pipeline_completes(pipeline_run):
    proc = pipeline_run["proc"]
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (pipeline_run["results"] / "catalog.duckdb").is_file()
    assert (pipeline_run["results"] / "report.html").is_file()


def test_catalog_has_every_scan_with_checksums(pipeline_run):
    con = duckdb.connect(str(pipeline_run["results"] / "catalog.duckdb"), read_only=True)
    rows = con.execute("SELECT scan_id, status, reason, raw_sha256 FROM scans ORDER BY scan_id").fetchall()
    n_raw = sum(1 for _ in pipeline_run["raw"].glob("night=*/scan=*"))
    assert len(rows) == n_raw == 19
    by_id = {r[0]: r for r in rows}
    assert by_id["BROKEN-TRUNCATED"][1] == "quarantined"
    assert "lds.parquet" in by_id["BROKEN-TRUNCATED"][2]
    assert all(r[1] == "ok" for sid, r in by_id.items() if sid != "BROKEN-TRUNCATED")
    assert all(len(r[3]) == 64 for r in rows)
    # per-file SHA-256 equals the raw bytes' digest
    for scan_id, file, sha in con.execute("SELECT scan_id, file, sha256 FROM scan_files").fetchall():
        night = con.execute("SELECT night FROM scans WHERE scan_id = ?", [scan_id]).fetchone()[0]
        path = pipeline_run["raw"] / f"night={night}" / f"scan={scan_id}" / file
        assert rawio.sha256_file(path) == sha


def test_quarantine_record_names_scan_file_and_problem(pipeline_run):
    rec = json.loads((pipeline_run["results"] / "quarantine" / "BROKEN-TRUNCATED.json").read_text())
    assert rec["scan_id"] == "BROKEN-TRUNCATED" and rec["file"] == "lds.parquet" and rec["reason"]
    assert rec["message"].startswith("BROKEN-TRUNCATED: lds.parquet: ")


def test_raw_files_untouched(pipeline_run):
    assert checksums(pipeline_run["raw"]) == pipeline_run["before"]


def test_rerun_does_nothing(pipeline_run):
    proc = run_snakemake(pipeline_run["raw"], pipeline_run["results"], "--dry-run")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr
