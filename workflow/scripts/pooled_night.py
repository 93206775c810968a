"""Rule pooled_night: examine each device's spindle scans of the window together; calibration drift."""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from borescan.stages._common import write_stage_outputs  # noqa: E402
from borescan.stages.pooled import pooled_dir, stage_pooled  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        pooled_dir(smk.params.results_root, smk.wildcards.night).mkdir(parents=True, exist_ok=True)
        findings, drift = stage_pooled(
            smk.params.raw_root,
            smk.wildcards.night,
            smk.params.results_root,
            list(smk.input.scans),
            list(smk.input.calibrations),
            smk.params.discrepancy,
            smk.params.devices,
            log=log,
            workers=smk.threads,
        )
        write_stage_outputs(smk.output, pooled_findings=findings, calibration_drift=drift)
        log(
            f"{findings['device_id'].n_unique() if findings.height else 0} devices examined pooled, "
            f"{int(drift['flagged'].sum()) if drift.height else 0} calibration drifts flagged"
        )


if __name__ == "__main__":  # worker processes import this file; only the job itself runs the stage
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script> night=YYYY-MM-DD
