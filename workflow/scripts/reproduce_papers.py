"""Rule reproduce_papers: the papers' tables and figures reproduced beside the printed values."""

from borescan.stages.papers import stage_papers
from borescan.workflow_log import log_to

with log_to(snakemake.log[0]) as log:
    from pathlib import Path

    index = stage_papers(Path(snakemake.output.index).parent, log=log)
    log(f"{index.height} files written")
