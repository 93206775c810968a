"""Rule calibrate_night: calibrate each device from the night's ring-gauge scans; certificates."""

from borescan.stages._common import write_stage_outputs
from borescan.stages.calibrate import stage_calibrate
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    cals, links, bad = stage_calibrate(
        snakemake.params.raw_root, snakemake.wildcards.night, snakemake.params.results_root,
        snakemake.input.scans, snakemake.input.summary, snakemake.params.calibration, log=log,
    )
    write_stage_outputs(snakemake.output, bad, calibrations=cals, calibration_scans=links)
    log(f"{cals['calibration_id'].n_unique() if cals.height else 0} calibrations, {len(bad)} scans quarantined")
