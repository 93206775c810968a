"""The pipeline's stages: one module per Snakemake rule family, each a ``stage_*`` function.

Every stage works on one night at a time (batching keeps Snakemake's per-job overhead small),
reads raw scans only through :mod:`borescan.rawio`, returns its tables as polars frames that the
rule's script writes as ``<results_root>/stage/<table>/night=<night>.parquet`` (hive layout, so
DuckDB and polars read all nights at once), and never stops for one bad scan: the scan is
quarantined with its reason (``<results_root>/quarantine/<scan_id>.json`` and a row in the
stage's quarantine table) and the stage goes on with the others.

=================  ==============================================================
module             stage
=================  ==============================================================
``ingest``         validate and register a night's scans (``scans``, ``scan_files``)
``signal``         revolutions, extrema, per-channel summaries (``extrema``, ``signal_summary``)
``calibrate``      device calibrations and certificates (``calibrations``, ``calibration_scans``)
``measure``        verifications, then diameters (``verifications``, ``diameters``, ``artifacts``)
``discrepancy``    the named missing effect per scan (``findings``, ``discrepancy/<scan_id>/``)
``papers``         the papers' tables reproduced (``papers/``)
``catalog``        ``catalog.duckdb`` from every stage table
``_common``        what every stage shares: quarantine records, the night's scans, writing tables
=================  ==============================================================

The package imports nothing itself, so ``rules/common.smk`` and a night job load only the
stage they need.
"""
