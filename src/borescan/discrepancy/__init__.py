"""Model-discrepancy workflow: where simulation and measurement disagree, and which named effect is missing.

For each scan: fit the base model (ideal device of the spec, nominal beams, nuisance
parameters free), locate the disagreement (channel, part of the revolution, undulations per
revolution, trends), refit with every named effect of ``geometry-and-effects.md`` as a
parametric term (and pairs), select by BIC with a stated threshold, and report the gap before
and after against a noise floor taken from second differences.

Entry points: :func:`examine_scan` (findings dict, ``outputs.md`` format), :func:`analyse_scan`
(findings plus arrays), :func:`write_findings`, :func:`plot_gap`, :func:`examine_to_dir`
(both files of ``results/discrepancy/<scan_id>/``), :func:`examine_table2`.
"""

from borescan.discrepancy.examine import Examination, analyse_scan, examine_scan, examine_tri, write_findings
from borescan.discrepancy.plot import plot_gap
from borescan.discrepancy.table2 import examine_table2


def examine_to_dir(scan, out_dir, **cfg) -> dict:
    """Examine ``scan``, write ``<out_dir>/findings.json`` and ``<out_dir>/gap.png``; return the findings."""
    from pathlib import Path

    ex = analyse_scan(scan, **cfg)
    write_findings(ex.findings, out_dir)
    plot_gap(ex, Path(out_dir) / "gap.png")
    return ex.findings


__all__ = [
    "Examination",
    "analyse_scan",
    "examine_scan",
    "examine_tri",
    "write_findings",
    "plot_gap",
    "examine_table2",
    "examine_to_dir",
]
