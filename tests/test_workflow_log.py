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
    assert restore_stale_backups(".snakemake", ["results/report"], log=lambda _m: None) == [Path("results/report")]
    assert (tmp_path / "results" / "report" / "index.html").read_text() == "before the job" and not backup.exists()


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
