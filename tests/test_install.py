"""borescan installed from a wheel (not editable) works without the checkout's ``src/``: the package finds
its shipped files (config schema, saved queries, the papers' tables) through :mod:`importlib.resources`,
and Snakemake runs the workflow with that install on a tiny night.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import duckdb
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert proc.returncode == 0, (proc.stdout[-3000:], proc.stderr[-3000:])
    return proc


@pytest.mark.slow
def test_a_wheel_install_runs_the_workflow(tmp_path):
    # a fresh venv on top of this one's dependencies (no download), borescan built as a wheel from a copy of
    # the source (an in-tree build leaves build/ and *.egg-info behind) and installed into it
    def egg_info_dirs():  # the checkout's own editable install (make test) may have one already
        return {p.name for p in ROOT.joinpath("src").iterdir() if p.name.endswith(".egg-info")}

    egg_info_before = egg_info_dirs()
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", venv])
    py = venv / "bin" / "python"
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    source = tmp_path / "source"
    source.mkdir()
    shutil.copy2(ROOT / "pyproject.toml", source)
    shutil.copytree(ROOT / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    _run([py, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "--quiet", source])
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    where = _run(
        [
            py,
            "-c",
            "import borescan, borescan.config as c, borescan.catalog as k; "
            "print(borescan.__file__); print(c.SCHEMA_PATH); print(k.DEFAULT_QUERIES_DIR)",
        ],
        env=env,
        cwd=tmp_path,
    ).stdout.split()
    assert all(p.startswith(str(site)) for p in where), where

    # the workflow without src/ (its workflow/schemas and data/papers links dangle): the install serves it
    wf = tmp_path / "workflow"
    wf.mkdir()
    shutil.copy2(ROOT / "Snakefile", wf)
    for d in ("rules", "workflow", "config"):
        shutil.copytree(ROOT / d, wf / d, symlinks=True)
    assert not (wf / "workflow" / "schemas" / "config.schema.yaml").exists()
    raw, truth, results = tmp_path / "raw", tmp_path / "truth", tmp_path / "results"
    _run(
        [
            venv / "bin" / "borescan",
            "simulate",
            "tri",
            "--raw-root",
            raw,
            "--truth-root",
            truth,
            "--n-rev",
            "8",
            "--scan-id",
            "TINY-TRI-CAL",
        ],
        env=env,
        cwd=tmp_path,
    )
    _run(
        [py, "-m", "snakemake", "--cores", "2", "--config", f"raw_root={raw}", f"results_root={results}"],
        env={**env, "PYTHONDONTWRITEBYTECODE": "1"},
        cwd=wf,
        timeout=1800,
    )
    con = duckdb.connect(str(results / "catalog.duckdb"), read_only=True)
    assert con.execute("SELECT scan_id, status FROM scans").fetchall() == [("TINY-TRI-CAL", "ok")]
    assert con.execute("SELECT count(*) FROM calibrations WHERE method = 'full_lsq'").fetchone()[0] == 3
    shipped = {q.stem for q in (site / "borescan" / "shipped" / "queries").glob("*.sql")}
    views = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
    assert shipped and shipped <= views  # the saved queries the install ships, one view each
    assert (results / "report.html").is_file() and (results / "papers" / "index.csv").is_file()
    assert egg_info_dirs() == egg_info_before  # the build left nothing behind in the checkout
