"""Stage ``build_catalog``: extend ``catalog.duckdb`` and check it against the raw root.

``catalog.duckdb`` extended by the nights whose stage tables are new, then checked against the raw root: every
night and scan of it is in the history (ok or quarantined).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import duckdb

from borescan import catalog, rawio
from borescan.stages._common import Quarantined, sync_quarantine_records

__all__ = ["HistoryGapError", "Coverage", "raw_coverage", "catalog_quarantine", "stage_catalog"]

#: scans named in full in a gap message; the rest are counted
_NAMED = 12


class HistoryGapError(RuntimeError):
    """Scans of the raw root that the history lacks (the run must fail, naming them)."""


@dataclass(frozen=True)
class Coverage:
    """The raw root against the history.

    Attributes
    ----------
    missing : ``night=<night>/scan=<scan_id>`` of every scan folder the pipeline ingests
        (:func:`borescan.rawio.nights`, :func:`borescan.rawio.night_scan_dirs`) with no row in the
        catalog's ``scans`` (neither ok nor quarantined).
    skipped : ``"<folder>: <reason>"`` of the entries the pipeline never processes
        (:func:`borescan.rawio.tree_problems`: a folder ``night=2026-02-30``, a stray file, a night
        folder it cannot list), said in the log, as ``borescan validate`` says them.
    n_scans : scan folders of the raw root checked.
    """

    missing: tuple[str, ...]
    skipped: tuple[str, ...]
    n_scans: int

    def message(self) -> str:
        """One paragraph naming what the history lacks and what to run."""
        nights = sorted({m.split("/")[0] for m in self.missing})
        named = ", ".join(self.missing[:_NAMED]) + (
            f" and {len(self.missing) - _NAMED} more" if len(self.missing) > _NAMED else ""
        )
        return (
            f"the history lacks {len(self.missing)} of the {self.n_scans} scans of the raw root "
            f"({', '.join(nights)}): {named}. Run `snakemake --cores N --forcerun ingest_night` to process "
            "every night of the raw root again (results already present are rewritten identically), "
            "or `borescan validate RAW_ROOT` to see why a folder is not read"
        )


def raw_coverage(raw_root: str | Path, catalog_file: str | Path) -> Coverage:
    """Compare the scan folders of ``raw_root`` with the ``scans`` rows of the catalog."""
    expected = [(n, d.name[5:]) for n in rawio.nights(raw_root) for d in rawio.night_scan_dirs(raw_root, n)]
    con = duckdb.connect(str(catalog_file), read_only=True)
    try:
        have = {(str(n), s) for n, s in con.execute("SELECT night, scan_id FROM scans").fetchall()}
    finally:
        con.close()
    missing = tuple(f"night={n}/scan={s}" for n, s in expected if (n, s) not in have)
    skipped = tuple(f"{e.file}: {e.problem}" for e in rawio.tree_problems(Path(raw_root)))
    return Coverage(missing, skipped, len(expected))


def catalog_quarantine(catalog_file: str | Path) -> list[Quarantined]:
    """One record per quarantined scan of the catalog: its earliest stage's (the ``scans`` reason)."""
    order = " ".join(f"WHEN '{s}' THEN {i}" for i, s in enumerate(catalog.STAGE_ORDER))
    con = duckdb.connect(str(catalog_file), read_only=True)
    try:
        rows = con.execute(
            "SELECT scan_id, strftime(night, '%Y-%m-%d'), stage, file, reason FROM quarantine "
            "QUALIFY row_number() OVER (PARTITION BY scan_id, night "
            f"ORDER BY CASE stage {order} ELSE 9 END, file) = 1 "
            "ORDER BY night, scan_id"
        ).fetchall()
    finally:
        con.close()
    return [Quarantined(*r) for r in rows]


def stage_catalog(
    results_root: str | Path,
    catalog_file: str | Path | None = None,
    full: bool = False,
    raw_root: str | Path | None = None,
    log=print,
) -> catalog.CatalogUpdate:
    """Bring ``<results_root>/catalog.duckdb`` up to date (:func:`borescan.catalog.update_catalog`).

    Only new nights' stage files are read; ``full=True`` rebuilds from every night. ``catalog_file``,
    when given, must be where the catalog is written (the rule's output). With ``raw_root``, the
    history is then checked against it (:func:`raw_coverage`): folders never processed are logged
    with their reason, and a scan of the raw root missing from the history raises
    :class:`HistoryGapError` naming it (the run fails; nothing is left out silently).
    """
    update = catalog.update_catalog(results_root, full=full)
    if catalog_file is not None and Path(catalog_file).resolve() != Path(update.path).resolve():
        raise RuntimeError(f"catalog written to {update.path}, rule expected {catalog_file}")
    written, removed = sync_quarantine_records(results_root, catalog_quarantine(update.path))
    if written or removed:
        log(f"quarantine records: {written} written, {removed} removed (they follow the catalog)")
    if raw_root is not None:
        cov = raw_coverage(raw_root, update.path)
        for s in cov.skipped:
            log(f"SKIPPED {s}")
        if cov.missing:
            raise HistoryGapError(cov.message())
        log(f"every one of the {cov.n_scans} scans of the raw root is in the history")
    return update
