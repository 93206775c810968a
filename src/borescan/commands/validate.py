"""``borescan validate RAW_ROOT``: check a raw root without processing it.

The checks ingest runs, over every scan the pipeline would ingest, then what the later stages will do with
each accepted scan.

One validator (:func:`borescan.validation.validate_tree`, the function the ingest stage calls
per scan): a scan this command calls valid is never quarantined at ingest, and the reverse. Then
the stages' preconditions (:func:`borescan.preconditions.expected_outcomes`, the functions the
stages call): the signal stage's processing of each three-sensor spindle scan (its revolutions),
a calibration scan's design geometry and revolutions, an examination without ``device.nominal``.
A scan a later stage will set aside is a problem line ``scan_id: file: will be quarantined at
<stage>: <reason>``; what a scan will only lack is a ``note:`` line.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from borescan.commands._common import Progress, UsageError, command_config

NAME = "validate"
HELP = (
    "check scans under RAW_ROOT exactly as the pipeline's ingest does: format, sensor range, "
    "sample clock, unique ids (one line per problem, exit 1 if any)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``RAW_ROOT``."""
    parser.add_argument(
        "raw_root",
        metavar="RAW_ROOT",
        type=Path,
        help="root of night=*/scan=* folders (relative or absolute)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="pipeline config whose signal and calibration settings the stages use (default: "
        "config/config.yaml when present, else the schema's defaults)",
    )
    # Before the checks were one, readings outside the sensor range were warnings shown by this
    # flag; they are problems now (ingest quarantines them). Accepted so old scripts keep working.
    parser.add_argument("--warnings", action="store_true", help=argparse.SUPPRESS)
    parser.epilog = (
        "Problems go to stdout as 'scan_id: file: problem' ('-' for folders that are not "
        "scans), the summary to stderr. Exit 0: all valid; 1: problems, or no scans under RAW_ROOT; "
        "2: RAW_ROOT missing."
    )


def _plausibility():
    """Return the plausibility bounds of the project's config/config.yaml, else the schema's.

    The project's config is read when the command runs from the project folder.
    """
    from borescan import validation
    from borescan.config import load_configs

    cfg = Path("config/config.yaml")
    return validation.Plausibility.from_config(load_configs([cfg])["plausibility"] if cfg.is_file() else None)


def run(args: argparse.Namespace) -> int:
    """Print ``scan_id: file: problem`` lines; exit 1 if any, else a summary and exit 0."""
    from borescan import rawio, validation

    progress = None
    if sys.stderr.isatty():  # a person waiting; cron logs get only the result
        bar: list[Progress] = []

        def progress(i: int, n: int) -> None:
            if not bar:
                bar.append(Progress(n, "validated", min_interval_s=2.0))
            bar[0].update(i)

    cfg, _ = command_config(args.config)
    try:
        report = validation.validate_tree(args.raw_root, progress=progress, limits=_plausibility())
    except validation.RawRootError as err:
        raise UsageError(str(err)) from None
    for e in report.problems:
        print(e)
    if report.n_scans == 0:  # nothing to validate is not "all valid": a wrong path or an empty share
        nights = rawio.nights(args.raw_root)
        where = f"{len(nights)} night folder(s), none with a scan" if nights else "no night=YYYY-MM-DD folder"
        print(f"no scans under RAW_ROOT {args.raw_root} ({where})", file=sys.stderr)
        return 1
    outcomes = stage_outcomes(args.raw_root, report.bad_scan_ids, cfg)
    later = sorted({o.scan_id for o in outcomes if o.quarantined})
    for o in outcomes:
        print(
            f"{o.scan_id}: {o.file}: will be quarantined at {o.stage}: {o.reason}"
            if o.quarantined
            else f"{o.scan_id}: {o.file}: note: {o.stage}: {o.reason}"
        )
    if report.problems or later:
        print(
            f"{len(report.problems) + len(later)} problems; of "
            f"{report.n_scans} scans {len(report.bad_scan_ids)} "
            f"invalid (set aside at ingest), {len(later)} to be set aside by a later stage",
            file=sys.stderr,
        )
        return 1
    print(f"{report.n_scans} scans, all valid" + (" (see the notes)" if outcomes else ""))
    return 0


def stage_outcomes(raw_root: Path, bad_scan_ids: set[str], cfg: dict) -> list:
    """Return the :class:`borescan.preconditions.StageOutcome` of every scan ingest accepts.

    In night and scan order: the signal stage's processing of a three-sensor spindle scan (as
    ``stages.signal`` runs it, with the config's settings), then
    :func:`borescan.preconditions.expected_outcomes`.
    """
    import numpy as np

    from borescan import preconditions, rawio
    from borescan.stages.signal import scan_summary, signal_options

    opts, min_rev = signal_options(cfg["signal"]), int(cfg["calibration"]["min_revolutions"])
    out = []
    for night in rawio.nights(raw_root):
        for d in rawio.night_scan_dirs(raw_root, night):
            if d.name[5:] in bad_scan_ids:
                continue
            scan = rawio.read_scan(d, raw_root=Path(raw_root))
            revolutions = source = None
            if scan.spindle is not None and scan.meta["device"]["type"] == "tri_lds":
                try:
                    summary = scan_summary(scan, rawio.lds_matrix(scan), opts)[1]
                    revolutions = preconditions.summary_revolutions(summary, cfg["calibration"]["method"])
                    source = preconditions.summary_period_source(summary)
                except (ValueError, np.linalg.LinAlgError, IndexError) as err:
                    out.append(
                        preconditions.StageOutcome(
                            scan.scan_id, "signal", rawio.LDS_FILE, f"signal stage failed: {err}", True
                        )
                    )
                    continue
            out += preconditions.expected_outcomes(
                scan.meta,
                has_spindle=scan.spindle is not None,
                revolutions=revolutions,
                min_rev=min_rev,
                period_source=source,
            )
    return out
