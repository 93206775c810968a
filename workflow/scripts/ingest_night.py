"""Rule ingest_night: validate every scan of a night, record checksums, quarantine bad ones."""

from borescan import pipeline
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    night = snakemake.wildcards.night
    scans, files, bad = pipeline.stage_ingest(
        snakemake.params.raw_root, night, snakemake.params.results_root, snakemake.params.duplicates
    )
    pipeline.write_table(scans, snakemake.output.scans)
    pipeline.write_table(files, snakemake.output.files)
    pipeline.write_table(pipeline.quarantine_frame(bad), snakemake.output.quarantine)
    log(f"night {night}: {scans.height} scans, {len(bad)} quarantined")
    for q in bad:
        log(f"QUARANTINED {q.scan_id}: {q.file}: {q.reason}")
