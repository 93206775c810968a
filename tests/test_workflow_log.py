"""What the workflow does around its jobs: putting back a folder a killed run left half-written."""


def test_a_backup_left_by_a_killed_run_is_put_back(tmp_path):
    """Snakemake's copy of an update() folder, left by a run killed inside the job, replaces the
    half-written folder when the next run starts (else that run's own copy fails: FileExistsError)."""
    from borescan.workflow_log import restore_stale_backups

    folder = tmp_path / "results" / "report"
    (folder / "2026-11").mkdir(parents=True)
    (folder / "2026-11" / "index.html").write_text("half written")
    backup = tmp_path / ".snakemake" / "backups" / str(folder.resolve()).lstrip("/")
    (backup / "2026-11").mkdir(parents=True)
    (backup / "2026-11" / "index.html").write_text("before the job")
    lines = []
    assert restore_stale_backups(tmp_path / ".snakemake", [folder], log=lines.append) == [folder.resolve()]
    assert (folder / "2026-11" / "index.html").read_text() == "before the job"
    assert not backup.exists() and "restored" in lines[0]
    assert restore_stale_backups(tmp_path / ".snakemake", [folder]) == []  # nothing left: nothing done
