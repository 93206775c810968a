"""The stage modules: small, importable without cycles; the former ``borescan.pipeline`` is gone."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

import borescan
from borescan.stages._common import Quarantined, quarantine_frame, write_quarantine_record

STAGES = Path(borescan.__file__).parent / "stages"


def test_stage_modules_are_small_and_import_at_the_top():
    for f in sorted(STAGES.glob("*.py")):
        text = f.read_text()
        # thin: 200 lines before the code was formatted with ruff format, which puts one argument a line
        # where a call does not fit 110 characters (about 1.5 times the lines)
        assert len(text.splitlines()) < 320, f.name
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                inner = [n for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom))]
                assert not inner, f"{f.name}: {node.name} imports inside the function"


@pytest.mark.parametrize(
    "module, never",
    [
        ("borescan.catalog", ("borescan.stages", "borescan.pipeline")),
        ("borescan.rawio", ("borescan.stages", "borescan.pipeline", "borescan.catalog")),
        (
            "borescan.stages",
            ("borescan.stages.", "numpy"),
        ),  # the package itself imports nothing: common.smk stays light
    ],
)
def test_library_modules_do_not_import_the_stages(module, never):
    code = f"import sys, {module}; print(sorted(m for m in sys.modules if m.startswith({never!r})))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", f"{module} imports {out}"


def test_the_former_glue_module_is_gone():
    """Every stage lives in borescan.stages; the forwarding module borescan.pipeline was removed
    (README migration note), so nothing can grow a second glue library there again.
    """
    with pytest.raises(ModuleNotFoundError):
        __import__("borescan.pipeline")


def test_quarantine_record_file_and_row(tmp_path):
    q = Quarantined("S1", "2026-11-20", "signal", "lds.parquet", "clock jump")
    path = write_quarantine_record(tmp_path, q)
    assert path == tmp_path / "quarantine" / "S1.json"
    assert json.loads(path.read_text()) == {
        "scan_id": "S1",
        "night": "2026-11-20",
        "stage": "signal",
        "file": "lds.parquet",
        "reason": "clock jump",
        "message": "S1: lds.parquet: clock jump",
    }
    assert quarantine_frame([q]).row(0) == ("S1", "2026-11-20", "signal", "lds.parquet", "clock jump")
    assert quarantine_frame([]).columns == ["scan_id", "night", "stage", "file", "reason"]


def test_a_worker_reading_and_measuring_scans_does_not_load_pandas_scipy_stats_or_signal(tmp_path):
    """Each stage job and each worker process is a new interpreter: what it imports it pays on every
    night (pandas ~0.35 s, loaded by pyarrow's own numpy conversions; scipy.stats and scipy.signal
    ~1.3 s). None is used: the stage modules, reading the demo's first scans (three-sensor and rod) and a
    contract scan with null readings, with every check, and their readings' matrix, the examination's outlier
    threshold and the
    coverage factors load none of them.
    """
    code = f"""
import sys
from pathlib import Path
from borescan import rawio
from borescan.synthetic import battery, demo, simulate
from borescan.stages import calibrate, discrepancy, measure, signal  # noqa: F401 (their imports)
from borescan.discrepancy.evidence import outlier_threshold_sigma
from borescan.uncertainty import coverage_factor, linear_coverage_interval
raw, truth = Path({str(tmp_path)!r}) / "raw", Path({str(tmp_path)!r}) / "truth"
for s in demo.demo_scans()[:11]:
    simulate.write_simulated(s, raw, truth)
battery_dir = Path({str(tmp_path)!r}) / "battery"
battery.write_battery(battery_dir, 2, 20270611, only=[1])  # channels out of range: null readings
for d in rawio.discover_scans(raw) + rawio.discover_scans(battery_dir / "raw"):
    scan = rawio.read_scan(d)
    rawio.lds_matrix(scan)
outlier_threshold_sigma(6000)
coverage_factor(0.9545, 7.0)
linear_coverage_interval([("normal", 1.0, 5.0), ("rectangular", 2.0, float("inf"))], 0.95)
print(sorted(m for m in sys.modules if m.split(".")[0] == "pandas" or m in ("scipy.stats", "scipy.signal")))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-500:]
