"""Rule build_catalog: results_root/catalog.duckdb extended by the nights whose stage tables are new."""

from borescan.stages.catalog import stage_catalog
from borescan.workflow_log import log_to, rule_job


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        update = stage_catalog(
            smk.params.results_root, smk.output.catalog, raw_root=smk.params.raw_root, log=log
        )
        log(f"{update.mode}: {update.reason}")
        if update.added or update.removed:
            log(
                f"nights read: {', '.join(update.added) or 'none'}; "
                f"nights taken out first: {', '.join(update.removed) or 'none'}"
            )
        for table, n in update.rows.items():
            log(f"{table}: {n} rows")


if __name__ == "__main__":
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script>
