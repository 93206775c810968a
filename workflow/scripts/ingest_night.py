"""Rule ingest_night: validate every scan of a night, record checksums, quarantine bad ones."""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from borescan.stages._common import write_stage_outputs  # noqa: E402
from borescan.stages.ingest import stage_ingest  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        night = smk.wildcards.night
        scans, files, bad = stage_ingest(
            smk.params.raw_root,
            night,
            smk.params.results_root,
            smk.params.duplicates,
            workers=smk.threads,
            earlier_scans=list(smk.input.earlier_scans),
            on_conflict=smk.params.on_conflict,
            log=log,
            plausibility=smk.params.plausibility,
        )
        write_stage_outputs(smk.output, bad, scans=scans, files=files)
        log(f"night {night}: {scans.height} scans, {len(bad)} quarantined")
        for q in bad:
            log(f"QUARANTINED {q.scan_id}: {q.file}: {q.reason}")


if __name__ == "__main__":  # worker processes import this file; only the job itself runs the stage
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script> night=YYYY-MM-DD
