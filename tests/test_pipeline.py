"""The whole pipeline, run by Snakemake on the embedded demo nights (issue 6 tests)."""

from __future__ import annotations

import duckdb

from conftest import checksums, run_snakemake

from borescan import rawio


def _con(run):
    return duckdb.connect(str(run["results"] / "catalog.duckdb"), read_only=True)


def test_pipeline_completes(pipeline_run):
    proc = pipeline_run["proc"]
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (pipeline_run["results"] / "catalog.duckdb").is_file()
    assert (pipeline_run["results"] / "report.html").is_file()


def test_catalog_has_every_scan_with_checksums(pipeline_run):
    con = _con(pipeline_run)
    rows = con.execute("SELECT scan_id, night, status, raw_sha256 FROM scans").fetchall()
    n_raw = sum(1 for _ in pipeline_run["raw"].glob("night=*/scan=*"))
    assert len(rows) == n_raw
    ok = {r[0] for r in rows if r[2] == "ok"}
    assert ok == set(pipeline_run["good_ids"]) | {pipeline_run["special"]["failed_verification"]}
    assert all(len(r[3]) == 64 for r in rows)
    for scan_id, night, file, sha in con.execute(
        "SELECT f.scan_id, s.night, f.file, f.sha256 FROM scan_files f JOIN scans s USING (scan_id, night) WHERE s.status = 'ok'"
    ).fetchall():
        assert rawio.sha256_file(pipeline_run["raw"] / f"night={night}" / f"scan={scan_id}" / file) == sha


def test_raw_files_untouched(pipeline_run):
    assert checksums(pipeline_run["raw"]) == pipeline_run["before"]


def test_rerun_does_nothing(pipeline_run):
    proc = run_snakemake(pipeline_run["raw"], pipeline_run["results"], "--dry-run")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_slurm_profile_dry_run(tmp_path):
    """The SLURM profile (snakemake-executor-plugin-slurm) plans the whole workflow."""
    from borescan import demo

    demo.make_demo(tmp_path / "demo")
    proc = run_snakemake(tmp_path / "demo" / "raw", tmp_path / "results", "--profile", "profiles/slurm", "--dry-run")
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout + proc.stderr
    assert "slurm_partition=compute" in out
    for rule in ("ingest_night", "signal_night", "calibrate_night", "measure_night", "build_catalog", "write_report"):
        assert rule in out
