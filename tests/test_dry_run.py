"""A dry run (``snakemake -n``) writes nothing under the results root (issue 40's leftovers).

The workflow reads the raw root when it parses the Snakefile: each night's manifest
(:mod:`borescan.raw_index`) and the settings each night is processed with (:mod:`borescan.night_config`)
were written then, by dry runs too. A dry run now writes the manifests it needs to a temporary folder and
records no settings; a run writes both as before.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from conftest import ROOT, SNAKEMAKE, checksums, workflow_env

from borescan import night_config, raw_index
from borescan.config import load_config
from borescan.workflow_log import is_dry_run

OLD_NS = 1_700_000_000 * 10**9


def _raw(root: Path, night: str, *scans: str) -> Path:
    """Scan folders with files of a few bytes (the manifest lists files; parsing reads no scan)."""
    for sid in scans:
        d = root / f"night={night}" / f"scan={sid}"
        d.mkdir(parents=True)
        for name in ("scan.json", "lds.parquet"):
            (d / name).write_text(f"{sid} {name}\n")
            os.utime(d / name, ns=(OLD_NS, OLD_NS))
    return root


@pytest.mark.parametrize(
    ("argv", "dry"),
    [
        (["-n", "--cores", "2"], True),
        (["--cores", "2", "-np", "catalog"], True),
        (["--dry-run"], True),
        (["--dryrun", "--config", "raw_root=x"], True),
        (["--cores", "2", "catalog", "--config", "raw_root=n"], False),
        ([], False),
    ],
)
def test_a_dry_run_is_told_from_the_command_line(argv, dry):
    assert is_dry_run(None, argv) is dry


def test_a_dry_run_leaves_the_manifests_alone_and_reads_the_ones_a_run_would_write(tmp_path):
    raw, res = _raw(tmp_path / "raw", "2026-11-20", "S1"), tmp_path / "res"
    _raw(raw, "2026-11-21", "T1")
    nights = ["2026-11-20", "2026-11-21"]
    raw_index.refresh_raw_index(raw, res, nights[:1])  # a run saw night 20 only
    before = checksums(res)
    mtime = raw_index.raw_index_path(res, nights[0]).stat().st_mtime_ns
    _raw(raw, "2026-11-20", "S2")  # a scan added with its old times (cp -a)
    paths = raw_index.night_index_paths(raw, res, nights, dry_run=True)
    assert checksums(res) == before and raw_index.raw_index_path(res, nights[0]).stat().st_mtime_ns == mtime
    for night in nights:  # a changed night and a new one: the manifests a run would write, elsewhere
        assert not paths[night].is_relative_to(res)
        assert paths[night].read_text() == raw_index.rawio.night_manifest(raw, night)
    assert paths[nights[0]].stat().st_mtime_ns > OLD_NS  # changed: now-dated, so its jobs rerun
    assert paths[nights[1]].stat().st_mtime_ns == OLD_NS  # first manifest: the raw files' time
    run = raw_index.night_index_paths(raw, res, nights, dry_run=False)
    assert run == {n: raw_index.raw_index_path(res, n) for n in nights}
    assert [run[n].read_text() for n in nights] == [paths[n].read_text() for n in nights]
    assert raw_index.night_index_paths(raw, res, nights, dry_run=True) == run  # nothing changed since


def test_settle_records_nothing_in_a_dry_run(tmp_path):
    settings, differ = night_config.settle(tmp_path, ["2026-11-20"], load_config(), record=False)
    assert differ == [] and settings["2026-11-20"] == night_config.night_settings(load_config())
    assert not tmp_path.exists() or not any(tmp_path.iterdir())


@pytest.mark.slow  # Snakemake parses the whole workflow (about 5 s idle, 20 s on a loaded machine)
def test_snakemake_dry_run_writes_nothing_under_the_results_root(tmp_path):
    raw, res = _raw(tmp_path / "raw", "2026-11-20", "S1", "S2"), tmp_path / "res"
    cmd = [
        str(SNAKEMAKE),
        "-n",
        "--cores",
        "1",
        "catalog",
        "--config",
        f"raw_root={raw}",
        f"results_root={res}",
    ]
    proc = subprocess.run(
        cmd, cwd=ROOT, capture_output=True, text=True, env=workflow_env(tmp_path), timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ingest_night" in proc.stdout and "This was a dry-run" in proc.stdout
    assert not res.exists() or sorted(str(p.relative_to(res)) for p in res.rglob("*")) == []
