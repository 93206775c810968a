"""``borescan recompute --from NIGHT``: apply the current config to nights already in the history.

The workflow processes each night with the settings recorded for it (:mod:`borescan.night_config`),
so editing the config never rewrites the past. This command is the deliberate way to do it: the
nights from NIGHT on whose settings differ get the current ones, their present results are kept
under ``<results>/versions/<change>/``, a change record names the nights, the old and new config
hashes and the keys that differ (catalog table ``config_changes``), and the next ``snakemake`` run
recomputes them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from borescan.commands._common import UsageError, night_date

NAME = "recompute"
HELP = (
    "apply the current config to the nights from --from NIGHT on (new versions beside the old ones, "
    "a change record); the next snakemake run recomputes them"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``borescan recompute`` options to ``parser``."""
    parser.add_argument(
        "--from",
        dest="from_night",
        required=True,
        type=night_date,
        metavar="NIGHT",
        help="first night (YYYY-MM-DD) to recompute with the current config",
    )
    parser.add_argument(
        "--results", default="results", type=Path, help="results folder of the history (default: results)"
    )
    parser.add_argument(
        "--configfile",
        action="append",
        type=Path,
        metavar="FILE",
        help="config file(s) as given to snakemake (default: config/config.yaml and "
        "config/devices.yaml, as the Snakefile reads them)",
    )


def run(args: argparse.Namespace) -> int:
    """Recompute the nights from ``--from`` on with the current config; return the exit status."""
    from borescan import night_config
    from borescan.config import load_configs

    files = args.configfile or [Path("config/config.yaml"), Path("config/devices.yaml")]
    for f in files:
        if not f.is_file():
            raise UsageError(f"config file {f} not found (run from the project folder or pass --configfile)")
    if not (args.results / "stage" / "night_config").is_dir():
        raise UsageError(f"no night records under {args.results}/stage/night_config (run the pipeline first)")
    cfg = load_configs(files)
    change = night_config.recompute(args.results, str(args.from_night), cfg)
    if change is None:
        print(f"every night from {args.from_night} on already has the current config: nothing to recompute")
        return 0
    print(
        f"{change.change_id}: {len(change.nights)} night(s) "
        f"({change.nights[0]}..{change.nights[-1]}) will be "
        f"recomputed with config {change.new_hash} (changed: {', '.join(change.keys) or 'none'}); their "
        f"present results are kept in {args.results / change.archive}. Run snakemake to recompute them."
    )
    return 0
