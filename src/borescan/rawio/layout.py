"""Finding raw data: scan folders, nights, a night's files and manifest, duplicate ids, clock jumps."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from borescan.rawio.format import ScanError, _NO_SCAN
from borescan.rawio.meta import _valid_night
from borescan.rawio.reader import _inspect


def _listing(folder: Path) -> list[Path]:
    """Return the entries of ``folder``; [] when it cannot be listed.

    Unlistable means unreadable, e.g. written with umask 077 by another user: the scan's own check
    (:func:`_check_folder`) or :func:`tree_problems` names it.
    """
    try:
        return list(Path(folder).iterdir())
    except OSError:
        return []


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:
        return False


def _sort_key(scan_dir: Path) -> tuple[str, str]:
    return (scan_dir.parent.name[6:], scan_dir.name[5:])


def discover_scans(raw_root: Path) -> list[Path]:
    """Scan folders ``<raw_root>/night=*/scan=*``, sorted by (night, scan_id).

    Hidden entries (names starting with ``.``, e.g. unfinished temporary folders) are skipped.
    Folders are listed, not validated.
    """
    raw_root = Path(raw_root)
    out = []
    if not raw_root.is_dir():
        return out
    for night_dir in _listing(raw_root):
        if not night_dir.name.startswith("night=") or not _is_dir(night_dir):
            continue
        for scan_dir in _listing(night_dir):
            if scan_dir.name.startswith("scan=") and _is_dir(scan_dir):
                out.append(scan_dir)
    return sorted(out, key=_sort_key)


def nights(raw_root: str | Path) -> list[str]:
    """Return the nights with a ``night=<date>`` folder under ``raw_root``.

    Nights (``YYYY-MM-DD``) with a ``night=<date>`` folder under ``raw_root``, sorted; [] when it does not
    exist.

    The unit of work of the pipeline: each stage runs once per night. Folders whose name is not
    ``night=`` + a calendar date (``night=2026-02-30`` is not one) are never processed
    (:func:`tree_problems` names them, and the catalog step reports them as skipped).
    """
    root = Path(raw_root)
    if not root.is_dir():
        return []
    return sorted(
        p.name[6:]
        for p in _listing(root)
        if p.name.startswith("night=") and _valid_night(p.name[6:]) and _is_dir(p)
    )


def night_scan_dirs(raw_root: str | Path, night: str) -> list[Path]:
    """Return the scan folders of one night, sorted.

    Scan folders ``scan=<scan_id>`` (non-empty id) of one night, sorted by folder name; listed, not
    validated.
    """
    night_dir = Path(raw_root) / f"night={night}"
    return sorted(
        p for p in _listing(night_dir) if p.name.startswith("scan=") and len(p.name) > 5 and _is_dir(p)
    )


def night_raw_files(raw_root: str | Path, night: str) -> list[str]:
    """Every regular file of a night's scan folders (the inputs whose change must rerun that night).

    Files this user cannot read are left out, and a scan folder that cannot be listed contributes
    none (Snakemake hashes a job's inputs; ingest quarantines the scan, naming the file or folder).
    """
    return [
        str(f)
        for d in night_scan_dirs(raw_root, night)
        for f in sorted(_listing(d))
        if _is_file(f) and os.access(f, os.R_OK)
    ]


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except OSError:
        return False


def night_manifest(raw_root: str | Path, night: str) -> str:
    """Return what a night of the raw root holds, as text.

    One line per scan folder and per file in it (``scan=<id>/<file> <bytes> <mtime_ns>``; a folder that cannot
    be listed: ``scan=<id>/ unlistable``).

    Equal text means the night's scans are the ones last processed, whatever the files' times
    say about their order: a scan added with old times (``cp -a``, ``rsync -a``), removed, or a
    file replaced changes the text (the workflow's ``raw_index``, an input of every night job).
    """
    lines = []
    for d in night_scan_dirs(raw_root, night):
        try:
            entries = sorted(d.iterdir())
        except OSError:
            lines.append(f"{d.name}/ unlistable")
            continue
        for f in entries:
            try:
                st = f.stat()
            except OSError:
                lines.append(f"{d.name}/{f.name} unreadable")
                continue
            if f.is_file():
                lines.append(f"{d.name}/{f.name} {st.st_size} {st.st_mtime_ns}")
    return "".join(line + "\n" for line in lines)


def earlier_duplicate_ids(raw_root: str | Path, night: str) -> list[str]:
    """Scan ids of ``night`` that already occur in an earlier night (the earlier scan keeps the id).

    Scan ids are unique across nights. Depends only on this and earlier nights, so adding a
    later night changes nothing here.
    """
    ids_here = {d.name[5:] for d in night_scan_dirs(raw_root, night)}
    seen: set[str] = set()
    for n in nights(raw_root):
        if n >= night:
            break
        seen.update(d.name[5:] for d in night_scan_dirs(raw_root, n))
    return sorted(ids_here & seen)


def clock_jump(sample: np.ndarray, t_s: np.ndarray, sample_rate_hz: float) -> str | None:
    """Describe the first tick whose time step disagrees with the sample step by more than half a period.

    On a spindle scan one clock drives every channel, so ``t`` must advance by
    ``(sample step) / sample_rate_hz``; a larger error means the logger's clock or counter
    slipped. Returns None when every step agrees (or there are fewer than two samples).

    Parameters
    ----------
    sample : (n,) sample numbers, increasing.
    t_s : (n,) times of the samples [s].
    sample_rate_hz : the scan's nominal sample rate [Hz].
    """
    sample = np.asarray(sample)
    t_s = np.asarray(t_s, dtype=float)
    if sample.size < 2:
        return None
    expected = np.diff(sample) / sample_rate_hz
    step = np.diff(t_s)
    bad = np.flatnonzero(np.abs(step - expected) > 0.5 / sample_rate_hz)
    if bad.size == 0:
        return None
    i = int(bad[0])
    return (
        f"clock jump: t_ns advances {step[i]:.6g} s between samples {int(sample[i])} and "
        f"{int(sample[i + 1])}, expected {expected[i]:.6g} s at {sample_rate_hz:g} Hz"
    )


def validate_root(raw_root: Path, *, warnings: list[str] | None = None) -> list[ScanError]:
    """Every problem of every scan under ``raw_root``, plus stray folders and duplicate ids.

    Parameters
    ----------
    raw_root : Path
    warnings : list, optional
        If given, non-fatal warnings of valid scans are appended as ``"scan_id: file: text"``.

    Returns
    -------
    list of ScanError
        Empty when every scan is valid. Entries that are not ``night=<date>/scan=<id>``
        folders are reported with scan_id ``"-"``.
    """
    raw_root = Path(raw_root)
    if not raw_root.is_dir():
        return [ScanError(_NO_SCAN, str(raw_root), "raw root does not exist or is not a folder")]
    errors = tree_problems(raw_root)
    seen: dict[str, str] = {}
    for scan_dir in discover_scans(raw_root):
        if not _valid_night(scan_dir.parent.name[6:]):
            continue  # reported by tree_problems
        scan, errs = _inspect(scan_dir, raw_root)
        errors.extend(errs)
        sid = scan_dir.name[5:]
        if sid in seen:
            errors.append(
                ScanError(
                    sid,
                    f"{scan_dir.parent.name}/{scan_dir.name}",
                    f"scan_id also used in {seen[sid]} (scan ids are unique across nights)",
                )
            )
        else:
            seen[sid] = scan_dir.parent.name
        if scan is not None and warnings is not None:
            warnings.extend(f"{scan.scan_id}: {w}" for w in scan.warnings)
    return errors


def tree_problems(raw_root: Path) -> list[ScanError]:
    """Entries of an existing raw root that are not ``night=<date>/scan=<id>`` folders (scan_id ``"-"``).

    Hidden entries are skipped. A night folder whose name is not a date is reported here, and
    its scans are not checked further.
    """
    errors: list[ScanError] = []
    for entry in sorted(_listing(raw_root)):
        if entry.name.startswith("."):
            continue
        if not (entry.name.startswith("night=") and _is_dir(entry)):
            errors.append(ScanError(_NO_SCAN, entry.name, "not a night=<YYYY-MM-DD> folder"))
            continue
        if not _valid_night(entry.name[6:]):
            errors.append(
                ScanError(
                    _NO_SCAN, entry.name, "folder night is not a date YYYY-MM-DD; its scans are not processed"
                )
            )
        try:
            subs = sorted(entry.iterdir())
        except OSError as e:
            errors.append(ScanError(_NO_SCAN, entry.name, f"cannot list the night folder: {e.strerror or e}"))
            continue
        for sub in subs:
            if sub.name.startswith("."):
                continue
            if not (sub.name.startswith("scan=") and _is_dir(sub)):
                errors.append(ScanError(_NO_SCAN, f"{entry.name}/{sub.name}", "not a scan=<scan_id> folder"))
    return errors
