"""Former home of the stage glue, kept so that existing imports keep working.

The stages now live in :mod:`borescan.stages` (one module per stage) and the domain rules they
used in the library modules they belong to; this module only forwards the old names, loading the
module that holds a name on first use. New code imports from the new places (right column).
"""

from __future__ import annotations

import importlib

#: old name -> (module, name there)
MOVED: dict[str, tuple[str, str]] = {
    # raw-file discovery and clock checks: rawio
    "nights": ("borescan.rawio", "nights"),
    "scan_dirs": ("borescan.rawio", "night_scan_dirs"),
    "night_raw_files": ("borescan.rawio", "night_raw_files"),
    "earlier_duplicate_ids": ("borescan.rawio", "earlier_duplicate_ids"),
    "clock_jump": ("borescan.rawio", "clock_jump"),
    # shared stage glue
    "Quarantined": ("borescan.stages._common", "Quarantined"),
    "write_quarantine_record": ("borescan.stages._common", "write_quarantine_record"),
    "quarantine_frame": ("borescan.stages._common", "quarantine_frame"),
    "write_table": ("borescan.stages._common", "write_table"),
    "write_stage_outputs": ("borescan.stages._common", "write_stage_outputs"),
    "ok_scans": ("borescan.stages._common", "ok_scans"),
    "night_scans": ("borescan.stages._common", "night_scans"),
    # stages
    "stage_ingest": ("borescan.stages.ingest", "stage_ingest"),
    "signal_options": ("borescan.stages.signal", "signal_options"),
    "stage_signal": ("borescan.stages.signal", "stage_signal"),
    "_signal_one": ("borescan.stages.signal", "signal_one"),
    "config_hash": ("borescan.stages.calibrate", "config_hash"),
    "stage_calibrate": ("borescan.stages.calibrate", "stage_calibrate"),
    "_spindle_inputs": ("borescan.stages.calibration_fit", "spindle_inputs"),
    "acceptance_rule": ("borescan.stages.calibration_fit", "acceptance_rule"),
    "fit_device_calibration": ("borescan.stages.calibration_fit", "fit_device_calibration"),
    "calibrate_raw_scans": ("borescan.stages.calibration_fit", "calibrate_raw_scans"),
    "measure_rod_scan": ("borescan.stages.measure", "measure_rod_scan"),
    "stage_measure": ("borescan.stages.measure", "stage_measure"),
    "findings_rows": ("borescan.stages.discrepancy", "findings_rows"),
    "stage_discrepancy": ("borescan.stages.discrepancy", "stage_discrepancy"),
    "stage_papers": ("borescan.stages.papers", "stage_papers"),
    "stage_catalog": ("borescan.stages.catalog", "stage_catalog"),
    # domain rules: library modules
    "gauge_radius_mm": ("borescan.artifacts", "gauge_radius_mm"),
    "choose_calibration": ("borescan.calibrations", "choose_calibration"),
    "rod_nominal_calibration_rows": ("borescan.calibrations", "rod_nominal_calibration_rows"),
    "discrepancy_reference": ("borescan.discrepancy.reference", "discrepancy_reference"),
    # the history tables: catalog and tables
    "CATALOG_TABLES": ("borescan.catalog", "STAGE_TABLES"),
    "read_stage_table": ("borescan.catalog", "read_stage_table"),
    "read_quarantine": ("borescan.catalog", "read_quarantine"),
    "assemble_history": ("borescan.catalog", "assemble_history"),
}

_SCHEMAS = {"QUARANTINE_SCHEMA": "quarantine", "SCANS_SCHEMA": "scans", "SCAN_FILES_SCHEMA": "scan_files"}

__all__ = sorted([n for n in MOVED if not n.startswith("_")] + list(_SCHEMAS))


def __getattr__(name: str):
    if name in _SCHEMAS:
        from borescan.tables import polars_schema

        return polars_schema(_SCHEMAS[name])
    if name not in MOVED:
        raise AttributeError(f"module 'borescan.pipeline' has no attribute {name!r}")
    module, attr = MOVED[name]
    return getattr(importlib.import_module(module), attr)


def __dir__() -> list[str]:
    return sorted(set(__all__) | set(MOVED))
