"""CPU of writing a calibration's certificate documents (issue 38), one process.

Every certificate recorded in a processed results root (``stage/certificate_issues``: the content and,
for a three-sensor calibration, its residuals) is written again by
:func:`borescan.certificate.write_certificate_files` into a temporary folder, each
``BENCH_CERT_REPEATS`` times (median), on the CPU clock of this process (``time.process_time``):
the PDF alone (its pages built and written in :func:`borescan.certificate.layout._pdf_context`),
and all documents together (JSON, DCC, residual plot, PDF). Compare two checkouts by alternating the
same command with ``PYTHONPATH=<checkout>/src`` (a shared machine stretches CPU times too).

    python -m bench.bench_certificate RESULTS_ROOT [--out DIR] [--profile] [--rod]
    BENCH_CERT_SOURCE=RESULTS_ROOT python -m bench certificate

``--out DIR`` keeps the documents written (one folder per certificate) to compare them with another
checkout's (``cmp``, ``pdftotext``, or render the PDF pages to PNG); ``--profile`` prints the cProfile
of writing the PDFs; ``--rod`` times the rod certificates only. Run on request only (it needs a
processed results root, e.g. the demo's: ``borescan simulate demo`` and ``snakemake`` into a folder
of your own, or ``python -m bench.bench_contract_night --keep K``).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

RUN_BY_DEFAULT = False


@dataclass(frozen=True)
class CertificateTiming:
    """CPU seconds of one certificate's documents (median over the repeats)."""

    name: str
    pages: int
    pdf_cpu_s: float
    all_cpu_s: float


def recorded_certificates(results: Path, rod_only: bool = False) -> list:
    """Return the latest recorded issue of every certificate under ``results``, by calibration id."""
    from borescan.certificate_issue import read_issues

    latest = {i.calibration_id: i for i in read_issues(results)}
    return [
        latest[k]
        for k in sorted(latest)
        if not rod_only or (latest[k].content.get("device") or {}).get("type") == "rod"
    ]


def time_certificate(
    cert: dict, residuals: dict | None, out_dir: Path, repeats: int
) -> tuple[int, float, float]:
    """Return (pages, median PDF CPU s, median CPU s of all documents) of writing ``cert``."""
    from borescan.certificate.content import _residual_arrays

    try:
        from borescan.certificate.layout import _pdf_context
    except ImportError:  # a checkout before the core-font PDF (before 748b6b3): DejaVu Sans

        def _pdf_context(cert):
            from borescan.certificate.layout import _RC

            import matplotlib

            return matplotlib.rc_context(_RC)

    from borescan.certificate.rod import _rod_pages
    from borescan.certificate.write import _pages, _pdf_bytes, write_certificate_files

    rod = (cert.get("device") or {}).get("type") == "rod"
    pdf_s, all_s, pages = [], [], 0
    for _ in range(repeats):
        c0 = time.process_time()
        with _pdf_context(cert):
            figs = _rod_pages(cert) if rod else _pages(cert, *_residual_arrays(residuals))
            _pdf_bytes(figs, "bench")
        c1 = time.process_time()
        write_certificate_files(cert, out_dir, residuals)
        c2 = time.process_time()
        pdf_s.append(c1 - c0)
        all_s.append(c2 - c1)
        pages = len(figs)
    return pages, statistics.median(pdf_s), statistics.median(all_s)


def main(argv: list[str] | None = None) -> None:
    """Time the rod certificates of a results root (arguments: see the module docstring)."""
    import os

    ap = argparse.ArgumentParser(prog="python -m bench.bench_certificate")
    ap.add_argument("results", type=Path, nargs="?", default=os.environ.get("BENCH_CERT_SOURCE"))
    ap.add_argument("--out", type=Path, help="keep the documents written here")
    ap.add_argument("--profile", action="store_true", help="cProfile of writing the PDFs")
    ap.add_argument("--rod", action="store_true", help="the rod certificates only")
    # run by `python -m bench certificate` the command line is the runner's: the root from BENCH_CERT_SOURCE
    args = ap.parse_args(([] if __name__ != "__main__" else sys.argv[1:]) if argv is None else argv)
    if args.results is None:
        raise SystemExit("name a processed results root (or set BENCH_CERT_SOURCE)")
    repeats = int(os.environ.get("BENCH_CERT_REPEATS", "3"))
    issues = recorded_certificates(args.results, rod_only=args.rod)
    if not issues:
        raise SystemExit(f"no certificate recorded under {args.results} (stage/certificate_issues)")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        rows = []
        prof = cProfile.Profile() if args.profile else None
        for issue in issues:
            name = issue.calibration_id
            if prof is not None:
                prof.enable()
            timing = time_certificate(issue.content, issue.residuals, root / name, repeats)
            rows.append(CertificateTiming(name, *timing))
            if prof is not None:
                prof.disable()
    for r in rows:
        print(
            f"  {r.name:52s} {r.pages:3d} pages  PDF {r.pdf_cpu_s:6.3f} s  all documents {r.all_cpu_s:6.3f} s"
        )
    pdf = [r.pdf_cpu_s for r in rows]
    print(
        f"{len(rows)} certificates, {sum(r.pages for r in rows)} pages (median of {repeats}, CPU s of "
        f"this process): PDF {sum(pdf):.2f} s in all, {statistics.median(pdf):.3f} s median, "
        f"{max(pdf):.3f} s max; all documents {sum(r.all_cpu_s for r in rows):.2f} s"
    )
    if prof is not None:
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(40)
        print(s.getvalue())


if __name__ == "__main__":
    main()
