"""Rule build_catalog: (re)build results_root/catalog.duckdb from every stage table."""

from borescan.stages.catalog import stage_catalog
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    counts = stage_catalog(snakemake.params.results_root, snakemake.output.catalog)
    for table, n in counts.items():
        log(f"{table}: {n} rows")
