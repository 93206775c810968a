"""Rule write_report: the report, its month pages and the papers' page.

Rule write_report: results_root/report.html, the month pages (redrawn where rows changed),
report/papers.html.
"""

from borescan.parallel import start_job_workers

start_job_workers(globals())  # first, before numpy loads: the job's workers import while this process does

from borescan.report.pages import PAPERS_PAGE, REPORT_DIR, update_report  # noqa: E402
from borescan.workflow_log import log_to, rule_job  # noqa: E402


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        update = update_report(smk.params.results_root, workers=smk.threads)
        log(
            f"{len(update.months)} month(s); pages written: {', '.join(update.rendered) or 'none'}; "
            f"{update.plots_drawn} plot(s) drawn"
        )
        log(f"report written to {update.path} (papers: {update.path.parent / REPORT_DIR / PAPERS_PAGE})")


if __name__ == "__main__":  # worker processes import this file; only the job itself writes the report
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script>
