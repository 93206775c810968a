"""Rule reproduce_papers: the papers' tables and figures reproduced beside the printed values."""

from pathlib import Path

from borescan.stages.papers import stage_papers
from borescan.workflow_log import log_to, rule_job


def main(smk) -> None:
    """Run the rule's stage with Snakemake's ``smk`` (inputs, outputs, params, log)."""
    with log_to(smk.log[0]) as log:
        index = stage_papers(Path(smk.output.index).parent, log=log)
        log(f"{index.height} files written")


if __name__ == "__main__":
    main(rule_job(globals(), __file__))  # Snakemake's job, or by hand: python <this script>
