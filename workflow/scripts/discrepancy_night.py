"""Rule discrepancy_night: name the physical effect missing from the model, per scan."""

from borescan import pipeline
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    findings, bad = pipeline.stage_discrepancy(
        snakemake.params.raw_root, snakemake.wildcards.night, snakemake.params.results_root,
        snakemake.input.scans, list(snakemake.input.calibrations), snakemake.params.discrepancy, log=log,
    )
    pipeline.write_table(findings, snakemake.output.findings)
    pipeline.write_table(pipeline.quarantine_frame(bad), snakemake.output.quarantine)
    log(f"{findings['scan_id'].n_unique() if findings.height else 0} scans examined, {len(bad)} set aside")
