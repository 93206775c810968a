"""Rule signal_night: revolutions, sub-sample extrema and per-channel summaries of a night."""

from borescan import pipeline
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    extrema, summary, bad = pipeline.stage_signal(
        snakemake.params.raw_root, snakemake.wildcards.night,
        snakemake.params.results_root, snakemake.input.scans, snakemake.params.signal, log=log,
    )
    pipeline.write_table(extrema, snakemake.output.extrema)
    pipeline.write_table(summary, snakemake.output.summary)
    pipeline.write_table(pipeline.quarantine_frame(bad), snakemake.output.quarantine)
    log(f"{summary['scan_id'].n_unique() if summary.height else 0} scans processed, {len(bad)} quarantined")
