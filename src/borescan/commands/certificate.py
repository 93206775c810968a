"""``borescan certificate ID``: reissue a calibration's certificate from the history."""

from __future__ import annotations

import argparse
from pathlib import Path

from borescan.commands._common import CommandFailed, UsageError, night_date

NAME = "certificate"
HELP = (
    "reissue a calibration's certificate (pdf, json, dcc) from the history; "
    "a changed laboratory makes a new one"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``borescan certificate`` options to ``parser``."""
    parser.add_argument("id", nargs="?", help="calibration id or certificate number (omit with --all)")
    parser.add_argument("--all", action="store_true", help="every calibration's certificate")
    parser.add_argument(
        "--format",
        default="all",
        choices=["pdf", "json", "dcc", "all"],
        help="documents to write (pdf: certificate.pdf and residuals.png; default: all)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="folder to write into (default: the certificate's own folder "
        "in the results, its calibration/<device>/<id> link restored)",
    )
    parser.add_argument("--results", default="results", help="results folder (default: results)")
    parser.add_argument(
        "--config",
        default="config/config.yaml",
        help="config whose laboratory section issues the certificate (default: config/config.yaml)",
    )
    parser.add_argument(
        "--issue-date",
        type=night_date,
        default=None,
        help="date of issue of a new document (default: today, UTC)",
    )
    parser.epilog = (
        "With the laboratory section the certificate was issued under, the latest issue is written again and "
        "compared, file by file, with the SHA-256 recorded "
        "when it was first written (and certificate.json with "
        "the catalog's). With a changed one, a new certificate "
        "<calibration id>-R<n> is issued (ISO/IEC 17025 "
        "7.8.8.2): the date of reissue, the new laboratory "
        "data and a reference to the certificate it replaces; "
        "`borescan trace ID` lists every issue."
    )


def run(  # noqa: C901 (one branch per option and per refusal of the command)
    args: argparse.Namespace,
) -> int:
    """Issue the certificates asked for by ``args``; return the exit status."""
    from borescan import certificate_issue
    from borescan.config import load_config
    from borescan.stages._common import link_into_night

    if bool(args.id) == bool(args.all):
        raise UsageError("give a calibration id or certificate number, or --all")
    cfg_path = Path(args.config)
    if not cfg_path.is_file():
        raise UsageError(f"config {cfg_path}: no such file")
    lab = load_config(cfg_path)["laboratory"]
    root = Path(args.results)
    ids = [args.id] if args.id else sorted({i.calibration_id for i in certificate_issue.read_issues(root)})
    if not ids:
        raise CommandFailed(f"no certificate recorded under {root / certificate_issue.ISSUE_TABLE}")
    differ = 0
    for ident in ids:
        out = None if args.out is None else Path(args.out) / (ident if args.all else "")
        try:
            done = certificate_issue.reissue(
                root, ident, lab, fmt=args.format, out_dir=out, issue_date=args.issue_date
            )
        except ValueError as err:
            raise CommandFailed(str(err)) from None
        iss = done.issue
        if out is None and iss.issue == 0:
            link_into_night(root / iss.folder, done.out_dir)
        if done.new_document:
            print(
                f"{iss.document_id}: NEW certificate issued {iss.issue_date}, replaces {iss.replaces} "
                f"(laboratory changed) -> {done.out_dir}"
            )
        else:
            print(
                f"{iss.document_id}: reissued unchanged (issue "
                f"{iss.issue} of {iss.issue_date}) -> {done.out_dir}"
            )
        for name, sha in sorted(done.files.items()):
            state = {
                True: "agrees with the recorded SHA-256",
                False: "DIFFERS from the recorded SHA-256",
                None: "new",
            }[done.agree[name] if not done.new_document else None]
            print(f"  {name} sha256 {sha} {state}")
            differ += done.agree[name] is False and not done.new_document
        if done.catalog_agree is not None:
            print(
                "  certificate.json "
                + ("agrees with" if done.catalog_agree else "DIFFERS from")
                + " calibrations.certificate_sha256 of the catalog"
            )
            differ += not done.catalog_agree
    if differ:
        raise CommandFailed(f"{differ} reissued file(s) differ from the recorded digests")
    return 0
