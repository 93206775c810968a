"""What the night benchmarks read: a run's CPU and load, each job's CPU from its log, two roots compared."""

import os
import sys
import time


def test_run_timed_counts_the_cpu_of_the_command_and_its_children(tmp_path):
    """A command that spends 0.3 s of CPU in a grandchild process: the run's CPU seconds include it
    (getrusage of every process waited for below the bench), and at least one load sample is taken.
    """
    from bench.bench_pipeline import run_timed

    burn = (
        "import time; t = time.process_time()\n"
        "while time.process_time() - t < 0.3: sum(i * i for i in range(1000))\n"
        "print(time.process_time())"
    )
    child = (
        "import subprocess, sys\n"
        f"p = subprocess.run([sys.executable, '-c', {burn!r}], capture_output=True, text=True)\n"
        "sys.stderr.write(p.stdout)"
    )
    run = run_timed([sys.executable, "-c", child], cwd=tmp_path)
    assert run.returncode == 0
    grandchild_cpu_s = float(run.stderr)  # its own clock, read just before it exited
    assert grandchild_cpu_s >= 0.3
    assert run.cpu_s >= grandchild_cpu_s and run.wall_s > 0.0
    assert 0.0 <= run.load_min <= run.load_median <= run.load_max


def test_job_cpu_reads_each_jobs_last_log_line_written_after_the_start(tmp_path):
    """Per rule, the CPU of the jobs whose logs were written during the run: a log older than the run
    (the papers' job before the night) and a log that ends without the line (a failed job) are left out.
    """
    from bench.bench_pipeline import job_cpu
    from borescan.workflow_log import JobCpu, job_cpu_line

    logs = tmp_path / "logs"
    (logs / "measure_night").mkdir(parents=True)
    old = logs / "reproduce_papers.log"
    old.write_text("[  0.00 s] " + job_cpu_line(JobCpu(5.0, 0.5, 1.0, 0.5, 4.5)) + "\n")
    os.utime(old, (time.time() - 100, time.time() - 100))
    since = time.time() - 10
    for night, (user, sys_) in {"2027-01-01": (2.0, 0.25), "2027-01-02": (1.5, 0.125)}.items():
        cpu = JobCpu(user_s=user, sys_s=sys_, own_s=1.0, before_stage_s=0.75, workers_s=user + sys_ - 1.0)
        (logs / "measure_night" / f"{night}.log").write_text(
            f"[  0.10 s] compute S1 0.500 s\n[  3.00 s] {job_cpu_line(cpu)}\n"
        )
    (logs / "build_catalog.log").write_text("[  0.10 s] started\n")
    got = job_cpu(tmp_path, since)
    assert got == {"measure_night": [2.25, 1.625]}


def _results_root(root, diameter_mm: float, pdf: bytes):
    """Write a results root: a catalog with a two-row table 'scans' and one certificate's files."""
    import duckdb

    root.mkdir()
    con = duckdb.connect(str(root / "catalog.duckdb"))
    con.execute("CREATE TABLE scans (scan_id VARCHAR, night DATE, artifact_certified_diameter_mm DOUBLE)")
    con.execute(
        "INSERT INTO scans VALUES ('S1', DATE '2027-01-01', 275.0), ('S2', DATE '2027-01-01', ?)",
        [diameter_mm],
    )
    con.close()
    cert = root / "calibration" / "night=2027-01-01" / "TRI-1" / "TRI-1-20270101-full_lsq-0"
    cert.mkdir(parents=True)
    (cert / "certificate.json").write_text('{"device_id": "TRI-1"}')
    (cert / "certificate.pdf").write_bytes(pdf)
    (cert.parents[1] / ".snakemake_timestamp").write_text(
        str(time.time_ns())
    )  # Snakemake's marker, not a result
    return root


def test_compare_results_names_the_table_column_and_certificate_file_that_differ(tmp_path, capsys):
    """Two roots the same but for one diameter (1e-9 mm apart) and one certificate's pdf bytes: the
    comparison names the table, the column with its largest difference, and the file; identical roots pass.
    """
    from bench.compare_results import compare_catalogs, compare_certificates, main

    old = _results_root(tmp_path / "old", 276.000000001, b"%PDF-1.4 a")
    same = _results_root(tmp_path / "same", 276.000000001, b"%PDF-1.4 a")
    new = _results_root(tmp_path / "new", 276.000000002, b"%PDF-1.4 b")
    assert compare_catalogs(old, same) == [] and compare_certificates(old, same) == (2, [])
    assert main([str(old), str(same)]) == 0
    (d,) = compare_catalogs(old, new)
    assert d.table == "scans" and d.reason == "1 of 2 rows differ"
    (c,) = d.columns
    assert c.column == "artifact_certified_diameter_mm" and c.rows == 1
    assert abs(c.max_abs - 1e-9) < 1e-12 and abs(c.max_rel - 1e-9 / 276.000000002) < 1e-14
    n, files = compare_certificates(old, new)
    assert n == 2 and files == [
        "TRI-1/TRI-1-20270101-full_lsq-0/certificate.pdf".join(["night=2027-01-01/", ""])
    ]
    assert compare_catalogs(old, new, {"scans.artifact_certified_diameter_mm"}) == []
    capsys.readouterr()
    assert main([str(old), str(new)]) == 1
    out = capsys.readouterr().out
    assert "scans: 1 of 2 rows differ" in out and "certificate.pdf" in out
