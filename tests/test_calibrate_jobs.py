"""The calibrate stage's typed jobs: what crosses to a worker process and back, and how outcomes add up."""

from __future__ import annotations

import pickle
from pathlib import Path

import polars as pl

from borescan.config import schema_defaults
from borescan.stages.calibrate_jobs import (
    CalibrationJob,
    CalibrationJobResult,
    CalibrationOutcome,
    CalibrationSettings,
)
from borescan.stages.quarantine import Quarantined


def _settings(tmp_path: Path) -> CalibrationSettings:
    d = schema_defaults()
    return CalibrationSettings(
        uncertainty=d["uncertainty"],
        laboratory=d["laboratory"],
        verification=d["verification"],
        signal=d["signal"],
        raw_root=tmp_path / "raw",
        scans_table=tmp_path / "scans.parquet",
        devices={"TRI-01": {"effects": ["channel_delay@2"]}},
        night="2026-11-20",
        pooled_rows=({"device_id": "TRI-01", "night": "2026-11-19", "effect": "channel_delay"},),
        auto_nights=2,
    )


def test_a_job_and_its_result_cross_to_a_worker_process_unchanged(tmp_path):
    """Jobs run on spawned workers (:func:`borescan.parallel.map_timed`): both ways pickle losslessly."""
    summary = pl.DataFrame({"scan_id": ["S1", "S1"], "channel": [1, 2], "d_max_mm": [5.25, 5.5]})
    job = CalibrationJob(
        "tri",
        (({"device_id": "TRI-01", "scan_id": "S1"}, tmp_path / "raw" / "scan=S1"),),
        tmp_path / "results",
        summary,
        schema_defaults()["calibration"],
        _settings(tmp_path),
    )
    back = pickle.loads(pickle.dumps(job))
    assert (back.kind, back.items, back.results_root, back.cfg) == (
        job.kind,
        job.items,
        job.results_root,
        job.cfg,
    )
    assert back.summary.equals(summary) and back.settings == job.settings
    assert back.name == "TRI-01"
    q = Quarantined("S1", "2026-11-20", "calibrate", "lds.parquet", "too few revolutions")
    res = CalibrationJobResult(
        "tri", CalibrationOutcome(({"calibration_id": "C1"},), quarantined=(q,)), ("a line",)
    )
    assert pickle.loads(pickle.dumps(res)) == res
    ctx = back.settings.context()  # built in the worker: the device model lookup is a closure, never pickled
    assert ctx.raw_root == tmp_path / "raw" and ctx.uncertainty == job.settings.uncertainty


def test_outcomes_add_up_in_order():
    """Rows of several calibrations of a device come back in the order they were made."""
    q1 = Quarantined("S1", "n", "calibrate", "f", "r1")
    q2 = Quarantined("S2", "n", "calibrate", "f", "r2")
    a = CalibrationOutcome(({"id": 1},), ({"scan": "S0"},), (q1,), ({"cert": 1},))
    b = CalibrationOutcome(({"id": 2},), ({"scan": "S3"},), (q2,), ())
    s = CalibrationOutcome() + a + b
    assert s.calibration_rows == ({"id": 1}, {"id": 2})
    assert s.calibration_scan_rows == ({"scan": "S0"}, {"scan": "S3"})
    assert s.quarantined == (q1, q2) and s.certificate_rows == ({"cert": 1},)
