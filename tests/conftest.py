"""Shared fixtures: one real Snakemake run over the demo nights plus the bad-input battery."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from bad_inputs import make_bad_scans, make_stage_cases  # noqa: E402

from borescan import rawio
from borescan.synthetic import demo  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = Path(sys.executable).with_name("snakemake")
BAD_NIGHT = "2026-11-22"


def workflow_env(home: Path) -> dict[str, str]:
    """Environment of a workflow run by the tests: this venv's tools, and the package of this
    checkout (the one the tests import) for every job.
    """
    return {
        "PATH": f"{SNAKEMAKE.parent}:/usr/bin:/bin",
        "HOME": str(home),
        "MPLBACKEND": "Agg",
        "PYTHONPATH": str(ROOT / "src"),
    }


def run_snakemake(
    raw_root: Path, results_root: Path, *extra: str, timeout: float = 900
) -> subprocess.CompletedProcess:
    """Run the project's Snakefile like a user would (``snakemake --cores 2``)."""
    cmd = [
        str(SNAKEMAKE),
        "--cores",
        "2",
        "--config",
        f"raw_root={raw_root}",
        f"results_root={results_root}",
        *extra,
    ]
    env = workflow_env(results_root.parent)
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=timeout)


def checksums(root: Path) -> dict[str, str]:
    """SHA-256 of every file below ``root`` (following the layout, not symlinks out of it)."""
    return {str(p.relative_to(root)): rawio.sha256_file(p) for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session")
def pipeline_run(tmp_path_factory):
    """Return the demo nights + the bad-input battery (a third night), processed by Snakemake once."""
    base = tmp_path_factory.mktemp("pipeline")
    demo.make_demo(base / "demo")
    raw = base / "demo" / "raw"
    first_night = sorted(raw.iterdir())[0]
    good_tri = next(p for p in sorted(first_night.iterdir()) if "CAL-P1-A" in p.name)
    good_rod = next(p for p in sorted(first_night.iterdir()) if "ROD01-MEAS" in p.name)
    good_ids = sorted(p.name.removeprefix("scan=") for p in raw.glob("night=*/scan=*"))
    cases = make_bad_scans(raw, BAD_NIGHT, good_tri, good_rod, good_tri.name.removeprefix("scan="))
    stage_cases, special = make_stage_cases(raw, base / "demo" / "truth", BAD_NIGHT)
    cases += stage_cases
    before = checksums(raw)
    results = base / "results"
    proc = run_snakemake(raw, results)
    return {
        "raw": raw,
        "results": results,
        "proc": proc,
        "before": before,
        "cases": cases,
        "good_ids": good_ids,
        "special": special,
        "truth": base / "demo" / "truth",
    }
