"""Rule measure_night: verify calibrations on certified gauges, then measure the night's parts."""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from borescan.stages._common import quarantined_text, write_stage_outputs  # noqa: E402
from borescan.stages.measure import stage_measure  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        diameters, verifications, artifacts, bad = stage_measure(
            smk.params.raw_root,
            smk.wildcards.night,
            smk.params.results_root,
            smk.input.scans,
            list(smk.input.calibrations),
            list(smk.input.verifications_before),
            {
                k: smk.params[k]
                for k in ("verification", "measurement", "calibration", "uncertainty", "laboratory", "signal")
            },
            log=log,
            workers=smk.threads,
        )
        write_stage_outputs(
            smk.output, bad, diameters=diameters, verifications=verifications, artifacts=artifacts
        )
        log(f"{diameters.height} diameters, {verifications.height} verifications, {quarantined_text(bad)}")


if __name__ == "__main__":  # worker processes import this file; only the job itself runs the stage
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script> night=YYYY-MM-DD
