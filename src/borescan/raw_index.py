"""What a night of the raw root holds, kept beside the results.

It, not file times, decides what reruns.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

from borescan import rawio
from borescan.atomic import atomic_write_text

__all__ = ["raw_index_path", "refresh_raw_index", "night_index_paths"]


def raw_index_path(results_root, night: str) -> Path:
    """``<results_root>/raw_index/night=<night>.txt``: the night's :func:`borescan.rawio.night_manifest`."""
    return Path(results_root) / "raw_index" / f"night={night}.txt"


def refresh_raw_index(raw_root, results_root, nights: list[str]) -> list[str]:
    """Write each night's manifest where it differs from the one written before; return those nights.

    The workflow calls this when it reads the raw root (every run, dry runs too) and makes the
    file an input of the night's jobs. Snakemake decides what is out of date from file times, and
    from its own records of inputs and parameters only when the checkout that runs has them (a
    second checkout, a fresh ``.snakemake/``, has none); a scan added with its old times
    (``cp -a``, ``rsync -a``) would look older than the night's results. The manifest is rewritten
    only when the night's scans changed, so its new time makes the night's jobs rerun, whatever
    the raw files' times and whichever checkout runs. A manifest written for the first time takes
    the time of the night's newest raw file, so it reruns nothing the raw files' times would not
    (results made before the manifest existed stay as they are). A results root that cannot be
    written is left alone (the run then stops at its first output, naming it).
    """
    return [night for night, _, first in _refresh(raw_root, results_root, nights, results_root) if not first]


def _refresh(raw_root, results_root, nights: list[str], into) -> list[tuple[str, Path, bool]]:
    """Write the manifests that differ from those under ``results_root`` into ``into``.

    As :func:`refresh_raw_index` writes them; return (night, path written, written for the first time).
    """
    written = []
    for night in nights:
        path, old = raw_index_path(into, night), raw_index_path(results_root, night)
        text = rawio.night_manifest(raw_root, night)
        try:
            existed = old.is_file()
            if existed and old.read_text() == text:
                continue
            atomic_write_text(path, text)
            if not existed:
                times = [int(t) for line in text.splitlines() for t in line.split()[2:3]]
                if times:
                    os.utime(path, ns=(max(times), max(times)))
        except OSError:
            continue
        written.append((night, path, not existed))
    return written


def night_index_paths(raw_root, results_root, nights: list[str], dry_run: bool) -> dict[str, Path]:
    """Return the manifest each night's ingest reads (night -> path), refreshed first.

    A run refreshes the manifests under the results root (:func:`refresh_raw_index`). A dry run
    (``snakemake -n``) writes nothing there: the manifests that are new or changed are written to a
    temporary folder (removed when the process exits), with the times a run would give them, so the
    dry run lists the jobs the run will make.
    """
    paths = {n: raw_index_path(results_root, n) for n in nights}
    into = results_root
    if dry_run:
        into = Path(tempfile.mkdtemp(prefix="borescan-dry-run-index-"))
        atexit.register(shutil.rmtree, into, ignore_errors=True)
    paths.update({n: path for n, path, _ in _refresh(raw_root, results_root, nights, into)})
    return paths
