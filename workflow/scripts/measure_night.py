"""Rule measure_night: verify calibrations on certified gauges, then measure the night's parts."""

from borescan import pipeline
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    diameters, verifications, artifacts, bad = pipeline.stage_measure(
        snakemake.params.raw_root, snakemake.wildcards.night, snakemake.params.results_root,
        snakemake.input.scans, list(snakemake.input.calibrations), list(snakemake.input.verifications_before),
        {k: snakemake.params[k] for k in ("verification", "measurement", "calibration")}, log=log,
    )
    pipeline.write_table(diameters, snakemake.output.diameters)
    pipeline.write_table(verifications, snakemake.output.verifications)
    pipeline.write_table(artifacts, snakemake.output.artifacts)
    pipeline.write_table(pipeline.quarantine_frame(bad), snakemake.output.quarantine)
    log(f"{diameters.height} diameters, {verifications.height} verifications, {len(bad)} quarantined")
