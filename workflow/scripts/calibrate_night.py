"""Rule calibrate_night: calibrate each device from the night's ring-gauge scans; certificates."""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from borescan.certificate_issue import issue_frame  # noqa: E402
from borescan.stages._common import quarantined_text, write_stage_outputs  # noqa: E402
from borescan.stages.calibrate import stage_calibrate  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        issued = []
        cals, links, bad = stage_calibrate(
            smk.params.raw_root,
            smk.wildcards.night,
            smk.params.results_root,
            smk.input.scans,
            smk.input.summary,
            smk.params.calibration,
            log=log,
            uncertainty=smk.params.uncertainty,
            laboratory=smk.params.laboratory,
            verification=smk.params.verification,
            devices=smk.params.devices,
            pooled_tables=list(smk.input.pooled),
            auto_nights=smk.params.device_model_auto_nights,
            signal=smk.params.signal,
            workers=smk.threads,
            certificates=issued,
        )
        write_stage_outputs(
            smk.output,
            bad,
            calibrations=cals,
            calibration_scans=links,
            certificate_issues=issue_frame(issued),
        )
        log(
            f"{cals['calibration_id'].n_unique() if cals.height else 0} calibrations, {quarantined_text(bad)}"
        )


if __name__ == "__main__":  # worker processes import this file; only the job itself runs the stage
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script> night=YYYY-MM-DD
