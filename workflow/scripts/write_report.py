"""Rule write_report: results_root/report.html with plots, tables and links."""

from borescan import report
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    path = report.write_report(snakemake.params.results_root)
    log(f"report written to {path}")
