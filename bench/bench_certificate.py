"""CPU of writing a rod calibration's certificate documents (issue 38), one process.

The rod calibrations of a processed results root (``certificate.json`` of a rod device under
``calibration/night=*/``) are written again from their JSON content by
:func:`borescan.certificate.write_certificate_files` into a temporary folder, each
``BENCH_CERT_REPEATS`` times (median), on the CPU clock of this process (``time.process_time``):
the PDF, and the JSON, DCC and residual plot together. Compare two checkouts by alternating the
same command with ``PYTHONPATH=<checkout>/src`` (a shared machine stretches CPU times too).

    python -m bench.bench_certificate RESULTS_ROOT [--out DIR] [--profile]
    BENCH_CERT_SOURCE=RESULTS_ROOT python -m bench certificate

``--out DIR`` keeps the documents written (one folder per certificate) to compare them with another
checkout's (``cmp``, or render the PDF pages to PNG); ``--profile`` prints the cProfile of writing
the PDFs. Run on request only (it needs a results root with rod calibrations, e.g. the contract
night's: ``python -m bench contract_night`` keeps none, run ``borescan simulate contract`` and
``snakemake`` into a folder of your own).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
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


def rod_certificates(results: Path) -> list[Path]:
    """Return the ``certificate.json`` of every rod calibration under ``results``, sorted."""
    out = []
    for f in sorted(results.glob("calibration/night=*/*/*/certificate.json")):
        if (json.loads(f.read_text()).get("device") or {}).get("type") == "rod":
            out.append(f)
    return out


def time_certificate(cert: dict, out_dir: Path, repeats: int) -> tuple[int, float, float]:
    """Return (pages, median PDF CPU s, median CPU s of all documents) of writing ``cert``."""
    import matplotlib

    from borescan.certificate.layout import _RC
    from borescan.certificate.rod import _rod_pages
    from borescan.certificate.write import _pdf_bytes, write_certificate_files

    pdf_s, all_s, pages = [], [], 0
    for _ in range(repeats):
        c0 = time.process_time()
        with matplotlib.rc_context(_RC):
            figs = _rod_pages(cert)
            _pdf_bytes(figs, "bench")
        c1 = time.process_time()
        write_certificate_files(cert, out_dir)
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
    # run by `python -m bench certificate` the command line is the runner's: the root from BENCH_CERT_SOURCE
    args = ap.parse_args(([] if __name__ != "__main__" else sys.argv[1:]) if argv is None else argv)
    if args.results is None:
        raise SystemExit("name a results root with rod calibrations (or set BENCH_CERT_SOURCE)")
    repeats = int(os.environ.get("BENCH_CERT_REPEATS", "3"))
    files = rod_certificates(args.results)
    if not files:
        raise SystemExit(f"no rod calibration certificate.json under {args.results}/calibration")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        rows = []
        prof = cProfile.Profile() if args.profile else None
        for f in files:
            cert = json.loads(f.read_text())
            name = f.parent.name
            if prof is not None:
                prof.enable()
            rows.append(CertificateTiming(name, *time_certificate(cert, root / name, repeats)))
            if prof is not None:
                prof.disable()
    for r in rows:
        print(
            f"  {r.name:52s} {r.pages:3d} pages  PDF {r.pdf_cpu_s:6.3f} s  all documents {r.all_cpu_s:6.3f} s"
        )
    pdf = [r.pdf_cpu_s for r in rows]
    print(
        f"{len(rows)} rod certificates, {sum(r.pages for r in rows)} pages (median of {repeats}, CPU s of "
        f"this process): PDF {sum(pdf):.2f} s in all, {statistics.median(pdf):.3f} s median, "
        f"{max(pdf):.3f} s max; all documents {sum(r.all_cpu_s for r in rows):.2f} s"
    )
    if prof is not None:
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(40)
        print(s.getvalue())


if __name__ == "__main__":
    main()
