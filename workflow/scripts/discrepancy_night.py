"""Rule discrepancy_night: name the physical effect missing from the model, per scan."""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from pathlib import Path  # noqa: E402

from borescan.stages._common import write_stage_outputs  # noqa: E402
from borescan.stages.discrepancy import findings_night_dir, stage_discrepancy  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        night_dir = findings_night_dir(smk.params.results_root, smk.wildcards.night)
        if Path(smk.output.scans).resolve() != night_dir.resolve():
            raise ValueError(f"rule output {smk.output.scans} is not the stage's folder {night_dir}")
        findings, bad = stage_discrepancy(
            smk.params.raw_root,
            smk.wildcards.night,
            smk.params.results_root,
            smk.input.scans,
            list(smk.input.calibrations),
            smk.params.discrepancy,
            log=log,
            workers=smk.threads,
            findings_tables=list(smk.input.findings_before),
        )
        write_stage_outputs(smk.output, bad, findings=findings)
        log(
            f"{findings['scan_id'].n_unique() if findings.height else 0} scans examined, {len(bad)} set aside"
        )


if __name__ == "__main__":  # worker processes import this file; only the job itself runs the stage
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script> night=YYYY-MM-DD
