"""What the workflow does around its jobs: putting back a folder a killed run left half-written."""

from pathlib import Path


def test_a_backup_left_by_a_killed_run_is_put_back(tmp_path):
    """Snakemake's copy of an update() folder, left by a run killed inside the job, replaces the
    half-written folder when the next run starts (else that run's own copy fails: FileExistsError).
    """
    from borescan.workflow_log import restore_stale_backups

    folder = tmp_path / "results" / "report"
    (folder / "2026-11").mkdir(parents=True)
    (folder / "2026-11" / "index.html").write_text("half written")
    backup = tmp_path / ".snakemake" / "backups" / str(folder.resolve()).lstrip("/")
    (backup / "2026-11").mkdir(parents=True)
    (backup / "2026-11" / "index.html").write_text("before the job")
    lines = []
    assert restore_stale_backups(tmp_path / ".snakemake", [folder], log=lines.append) == [folder]
    assert (folder / "2026-11" / "index.html").read_text() == "before the job"
    assert not backup.exists() and "restored" in lines[0]
    assert restore_stale_backups(tmp_path / ".snakemake", [folder]) == []  # nothing left: nothing done


def test_the_backup_of_a_relative_results_folder_is_found(tmp_path, monkeypatch):
    """results_root is relative by default ("results"): Snakemake keeps the copy under
    .snakemake/backups/results/report, and that is where it is looked for.
    """
    from borescan.workflow_log import restore_stale_backups

    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "report").mkdir(parents=True)
    (tmp_path / "results" / "report" / "index.html").write_text("half written")
    backup = tmp_path / ".snakemake" / "backups" / "results" / "report"
    backup.mkdir(parents=True)
    (backup / "index.html").write_text("before the job")
    assert restore_stale_backups(".snakemake", ["results/report"], log=lambda _m: None) == [
        Path("results/report")
    ]
    assert (
        tmp_path / "results" / "report" / "index.html"
    ).read_text() == "before the job" and not backup.exists()


def test_idle_timers_are_cancelled_so_the_run_exits_at_once():
    """A waiting threading.Timer (Snakemake's scheduler leaves one armed for 1 s) is cancelled: its
    thread ends without running its action; other threads are left alone.
    """
    import threading

    from borescan.workflow_log import cancel_idle_timers

    fired = []
    timer = threading.Timer(60.0, lambda: fired.append(1))
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, args=(60.0,))
    timer.start()
    other.start()
    try:
        assert cancel_idle_timers() == 1
        timer.join(5.0)
        assert not timer.is_alive() and fired == []
        assert other.is_alive()
    finally:
        stop.set()
        other.join()


def test_locks_of_a_killed_run_are_released_and_a_live_run_keeps_its_own(tmp_path):
    """Issue 40 item 9: a run killed with SIGKILL leaves its lock files; the next run releases them when
    the process that wrote them is gone (same boot), never while it lives.
    """
    import json
    import os
    import subprocess
    import sys

    from borescan.workflow_log import record_lock_owner, release_stale_locks

    locks = tmp_path / ".snakemake" / "locks"
    locks.mkdir(parents=True)
    mine, theirs = locks / "0.input.lock", locks / "1.output.lock"
    mine.write_text("a\n"), theirs.write_text("b\n")
    record_lock_owner(tmp_path / ".snakemake", [mine])  # this (live) process
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    pid = int(dead.stdout)  # finished: no such process any more
    owner = json.loads((locks / f"borescan-owner-{os.getpid()}.json").read_text())
    (locks / f"borescan-owner-{pid}.json").write_text(json.dumps(dict(owner, pid=pid, locks=[str(theirs)])))
    assert release_stale_locks(tmp_path / ".snakemake") == [pid]
    assert mine.is_file() and not theirs.exists()
    assert release_stale_locks(tmp_path / ".snakemake") == []


def test_a_run_log_is_quiet_and_readable(tmp_path):
    """Issue 37 item 8: the default profile prints the rules' messages, not "Shell command: None" (the
    rules run scripts) nor "reason:" lines listing every input of a night job; a mistyped config key
    is one line naming it, not the schema.
    """
    from conftest import run_snakemake

    from borescan.synthetic import simulate

    raw = tmp_path / "raw"
    for i in range(3):
        sim = simulate.simulate_rod(None, n_poses=6, samples_per_pose=2, scan_id=f"R{i}", seed=i)
        simulate.write_simulated(sim, raw, tmp_path / "truth")
    proc = run_snakemake(raw, tmp_path / "results", "--dry-run")
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-2000:]
    assert "Validating and registering the scans of night 2026-11-20" in log
    assert "Shell command" not in log and "reason:" not in log.lower()
    proc = run_snakemake(raw, tmp_path / "results", "calibraton={}", "--dry-run")  # a --config value
    log = proc.stdout + proc.stderr
    assert proc.returncode != 0 and len(log.splitlines()) < 15, log[-3000:]
    assert "calibraton: unknown key (known here: artifacts, calibration," in log


def _burn_cpu(seconds: float) -> float:
    """Spin on this process's CPU clock for ``seconds``; return the process's CPU time at the end."""
    import time

    t0 = time.process_time()
    while time.process_time() - t0 < seconds:
        sum(i * i for i in range(1000))
    return time.process_time()


def test_a_jobs_last_log_line_counts_the_cpu_of_its_workers(tmp_path):
    """log_to's last line is the job's CPU: a worker of the job's pool (parallel.start_job_workers) is
    stopped and waited for first, so the CPU it spent (0.3 s, read on its own clock) is in the line's
    worker seconds; the line's user + sys equals its own process + workers (printed to 1 ms each).
    """
    import time

    from borescan import parallel
    from borescan.workflow_log import job_cpu, log_to, parse_job_cpu

    before = job_cpu()
    pool = parallel._spawn_pool(1)
    parallel._JOB_POOL.update(pool=pool, workers=2)
    log_file = tmp_path / "logs" / "job.log"
    with log_to(log_file) as log:
        worker_cpu_s = pool.submit(_burn_cpu, 0.3).result()
        log("one item")
    assert not parallel._JOB_POOL  # stopped: the worker has exited (its CPU is counted below)
    lines = log_file.read_text().splitlines()
    assert lines[0].endswith("one item") and len(lines) == 2
    cpu = parse_job_cpu(lines[-1])
    assert cpu is not None
    # the worker's whole life (interpreter start, imports, the burn) is at least what its clock read
    assert cpu.workers_s - before.workers_s >= worker_cpu_s - 0.01
    assert abs(cpu.total_s - (cpu.own_s + cpu.workers_s)) <= 0.004
    assert 0.0 <= cpu.before_stage_s <= cpu.own_s <= time.process_time() + 0.01


def test_a_job_that_fails_writes_no_cpu_line(tmp_path):
    """On an error the log ends where the job stopped: no CPU line is added after the traceback's cause."""
    import pytest

    from borescan.workflow_log import log_to

    log_file = tmp_path / "job.log"
    with pytest.raises(ValueError), log_to(log_file) as log:
        log("started")
        raise ValueError("bad scan")
    assert log_file.read_text().splitlines()[-1].endswith("started")
