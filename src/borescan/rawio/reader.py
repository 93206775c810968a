"""Reading one scan folder: folder and containment checks, the files opened read-only, the scan validated."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from borescan.rawio.format import (
    LDS_FILE,
    LDS_SCHEMA,
    RawScan,
    SCAN_JSON,
    SPINDLE_FILE,
    SPINDLE_SCHEMA,
    ScanError,
    _NO_SCAN,
)
from borescan.rawio.lds import _check_lds, _check_schema, _check_spindle
from borescan.rawio.meta import _Problems, _check_meta, _parse_json_bytes, _valid_night, _valid_scan_id

# ---------------------------------------------------------------------------------------------
# reading


def _scan_id_from_dir(scan_dir: Path) -> str:
    name = scan_dir.name
    sid = name[5:] if name.startswith("scan=") else name
    return sid if _valid_scan_id(sid) else (sid[:64] or _NO_SCAN)


def _check_folder(scan_dir: Path, raw_root: Path | None, p: _Problems) -> tuple[str | None, str | None]:
    """Folder-name and containment checks; return (scan_id, night) from the names."""
    name, parent = scan_dir.name, scan_dir.parent.name
    sid = name[5:] if name.startswith("scan=") else None
    night = parent[6:] if parent.startswith("night=") else None
    rel = f"{parent}/{name}"
    if sid is None or night is None:
        p.add(rel, "folder is not <raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>")
    if sid is not None and not _valid_scan_id(sid):
        p.add(rel, f"folder scan_id {sid!r:.80} does not match [A-Za-z0-9_-]{{1,64}}")
        sid = None
    if night is not None and not _valid_night(night):
        p.add(rel, f"folder night {night!r:.40} is not a date YYYY-MM-DD")
        night = None
    root = Path(raw_root) if raw_root is not None else scan_dir.parent.parent
    try:
        real_root = root.resolve(strict=True)
        real = scan_dir.resolve(strict=True)
    except (OSError, RuntimeError) as e:
        p.add(rel, f"cannot resolve folder: {e}")
        return sid, night
    if not real.is_relative_to(real_root) or real == real_root:
        p.add(rel, f"folder resolves to {real}, outside the raw root {real_root}")
    elif not real.is_dir():
        p.add(rel, "not a directory")
    else:
        try:
            os.listdir(real)
        except OSError as e:  # e.g. written with umask 077 by another user
            p.add(rel, f"cannot list the scan folder: {e.strerror or e}")
    return sid, night


def _open_file(
    scan_dir: Path, fname: str, real_root: Path | None, p: _Problems, required: bool
) -> Path | None:
    path = scan_dir / fname
    try:
        if not os.path.lexists(path):
            if required:
                p.add(fname, "missing (required)")
            return None
        real = path.resolve(strict=True)
    except (OSError, RuntimeError) as e:
        p.add(fname, f"cannot resolve: {e}")
        return None
    if real_root is not None and not real.is_relative_to(real_root):
        p.add(fname, f"resolves to {real}, outside the raw root")
        return None
    if not real.is_file():
        p.add(fname, "not a regular file")
        return None
    return path


def _read_meta_file(path: Path, p: _Problems) -> tuple[Any, str | None]:
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        p.add(SCAN_JSON, f"unreadable: {e.strerror or e}")
        return None, None
    digest = hashlib.sha256(data).hexdigest()
    try:
        return _parse_json_bytes(data), digest
    except UnicodeDecodeError as e:
        p.add(SCAN_JSON, f"not UTF-8 text: {e.reason} at byte {e.start}")
    except (ValueError, RecursionError) as e:
        p.add(SCAN_JSON, f"invalid JSON: {e}")
    return None, digest


def _read_parquet(path: Path, fname: str, schema: pa.Schema, p: _Problems) -> pa.Table | None:
    """Read only the schema's columns of a Parquet file; None after a problem."""
    # An Arrow-native file, never a Python file object: column decoding runs on Arrow's thread
    # pool, and its tasks drop their page readers after the read has returned. Over a Python file
    # object those hold Python-owned buffers whose release needs the GIL; a worker that asks for it
    # while the interpreter is shutting down is terminated inside a C++ destructor, and the process
    # aborts after its output ("terminate called without an active exception", exit 134).
    try:
        with pa.OSFile(str(path)) as f:
            pf = pq.ParquetFile(f)
            if not _check_schema(pf.schema_arrow, schema, p, fname):
                return None
            table = pf.read(columns=schema.names)  # Arrow's pool: OMP_NUM_THREADS threads
    except OSError as e:
        if e.errno is not None:
            p.add(fname, f"unreadable: {os.strerror(e.errno)}")
        else:
            p.add(fname, f"not a readable Parquet file (truncated or corrupt): {e}")
        return None
    except Exception as e:  # noqa: BLE001 - any decoder failure means a corrupt file
        p.add(fname, f"not a readable Parquet file (truncated or corrupt): {type(e).__name__}: {e}")
        return None
    return table.select(schema.names)


def _meta_folder_checks(meta: dict, sid: str | None, night: str | None, p: _Problems) -> None:
    msid = meta.get("scan_id")
    if sid is not None and isinstance(msid, str) and msid != sid:
        p.add(SCAN_JSON, f"scan_id {msid!r:.80} differs from the folder name scan={sid}")
    mnight = meta.get("night")
    if night is not None and isinstance(mnight, str) and mnight != night:
        p.add(SCAN_JSON, f"night {mnight!r:.40} differs from the folder name night={night}")


# ---------------------------------------------------------------------------------------------
# the night's valid scans, parsed once per process

# Bound of the cache: the raw data of one demo night is about 30 MB in memory; a night of large
# scans keeps its most recently read ones within this (least recently used first out).
_CACHE_MAX_BYTES = 1 << 30


@dataclass(frozen=True)
class _MetaRead:
    """A valid ``scan.json`` read alone (:func:`read_scan_meta`) and the SHA-256 of its bytes."""

    meta: dict
    sha256: str | None


def _stamp(scan_dir: Path) -> tuple | None:
    """Return what identifies the folder's files on disk now; None when one cannot be examined.

    For the folder and each raw file: the entry itself (``lstat``: a replaced symlink) and what it
    resolves to (device, inode, size, mtime_ns, ctime_ns: a rewritten, replaced or chmod-ed file).
    """
    out: list[tuple | None] = []
    for path in (scan_dir, scan_dir / SCAN_JSON, scan_dir / LDS_FILE, scan_dir / SPINDLE_FILE):
        try:
            entry = os.lstat(path)
        except FileNotFoundError:
            out.append(None)
            continue
        except OSError:
            return None
        try:
            st = os.stat(path)
        except OSError:
            return None
        out.append(
            (entry.st_ino, entry.st_mtime_ns, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
            + (st.st_ctime_ns,)
        )
    return tuple(out)


def _nbytes(scan: RawScan) -> int:
    n = scan.lds.estimated_size() + (scan.spindle.estimated_size() if scan.spindle is not None else 0)
    if scan._matrix is not None:
        m = scan._matrix[1]
        n += sum(a.nbytes for a in (m.sample, m.t_s, m.values_mm, m.pose))
    return n


class _ScanCache:
    """The valid scans of one night folder read by this process, each served while its files are unchanged.

    A scan of another night folder empties it first (memory bounded to one night, and to
    ``_CACHE_MAX_BYTES``). Only valid reads are kept: a bad scan is read again, with its problems.
    """

    def __init__(self, max_bytes: int) -> None:
        self.enabled = True
        self.max_bytes = max_bytes
        self._night: str | None = None
        self._items: OrderedDict[tuple, tuple[tuple, RawScan | _MetaRead, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()  # readers on threads of one process

    @staticmethod
    def key(scan_dir: Path, raw_root: Path | None) -> tuple[str, str, str]:
        """Return the folder as given, where it resolves and the raw root it must stay in."""
        root = raw_root if raw_root is not None else scan_dir.parent.parent
        return os.path.abspath(scan_dir), os.path.realpath(scan_dir), os.path.realpath(root)

    def clear(self) -> None:
        """Forget every scan."""
        with self._lock:
            self._items.clear()
            self._bytes, self._night = 0, None

    def get(self, key: tuple, stamp: tuple | None) -> RawScan | _MetaRead | None:
        """Return the kept read of ``key`` if its files still carry ``stamp``."""
        with self._lock:
            item = self._items.get(key)
            if item is None or stamp is None or item[0] != stamp:
                return None
            self._items.move_to_end(key)
            return item[1]

    def put(self, key: tuple, stamp: tuple, found: RawScan | _MetaRead) -> None:
        """Keep a valid read of ``key`` (its files' ``stamp`` unchanged over the read)."""
        n = _nbytes(found) if isinstance(found, RawScan) else 0
        night = os.path.dirname(key[0])
        with self._lock:
            if night != self._night:
                self._items.clear()
                self._bytes, self._night = 0, night
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old[2]
            self._items[key] = (stamp, found, n)
            self._bytes += n
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, (_, _, gone) = self._items.popitem(last=False)
                self._bytes -= gone


_SCAN_CACHE = _ScanCache(_CACHE_MAX_BYTES)


def _handout(scan: RawScan) -> RawScan:
    """Return a caller's own copy of a kept scan.

    Its dicts and lists copied, frames cloned (the data shared, immutable in polars), the wide
    matrix's arrays read-only: a caller cannot change what the next one gets.
    """
    lds = scan.lds.clone()
    return dataclasses.replace(
        scan,
        meta=copy.deepcopy(scan.meta),
        lds=lds,
        spindle=scan.spindle.clone() if scan.spindle is not None else None,
        files=dict(scan.files),
        warnings=list(scan.warnings),
        _digests=dict(scan._digests),
        _matrix=(lds, scan._matrix[1]) if scan._matrix is not None else None,
    )


def _unwrap(found: RawScan | _MetaRead | None, errors: list[ScanError]):
    return (found.meta if isinstance(found, _MetaRead) else found), errors


def _inspect(
    scan_dir: Path, raw_root: Path | None = None, meta_only: bool = False
) -> tuple[RawScan | dict | None, list[ScanError]]:
    """Read and validate a scan folder, through this process's cache of the night's valid scans."""
    scan_dir = Path(scan_dir)
    cache = _SCAN_CACHE
    if not cache.enabled:
        return _unwrap(*_inspect_files(scan_dir, raw_root, meta_only))
    key = cache.key(scan_dir, raw_root)
    stamp = _stamp(scan_dir)
    hit = cache.get(key, stamp)
    if isinstance(hit, RawScan):
        return (copy.deepcopy(hit.meta) if meta_only else _handout(hit)), []
    known = hit if isinstance(hit, _MetaRead) else None
    if meta_only and known is not None:
        return copy.deepcopy(known.meta), []
    found, errors = _inspect_files(scan_dir, raw_root, meta_only, known)
    if errors or stamp is None or _stamp(scan_dir) != stamp:
        return _unwrap(found, errors)  # only valid scans of unchanged folders are kept
    if meta_only:
        cache.put(key, stamp, found)
        return copy.deepcopy(found.meta), errors
    cache.put(key, stamp, found)
    return _handout(found), errors


def _inspect_files(  # noqa: C901 (one branch per raw file and problem of a scan folder)
    scan_dir: Path, raw_root: Path | None = None, meta_only: bool = False, known: _MetaRead | None = None
) -> tuple[RawScan | dict | None, list[ScanError]]:
    """Read and validate a scan folder from its files (``known``: its ``scan.json`` already parsed).

    Returns ``(RawScan, [])``, ``(_MetaRead, [])`` with ``meta_only`` or ``(None, problems)``.
    """
    p = _Problems(_scan_id_from_dir(scan_dir))
    sid, night = _check_folder(scan_dir, raw_root, p)
    if p:
        return None, p.errors
    root = Path(raw_root) if raw_root is not None else scan_dir.parent.parent
    real_root = root.resolve()
    meta_path = _open_file(scan_dir, SCAN_JSON, real_root, p, required=True)
    lds_path = _open_file(scan_dir, LDS_FILE, real_root, p, required=True) if not meta_only else None
    sp_path = _open_file(scan_dir, SPINDLE_FILE, real_root, p, required=False) if not meta_only else None
    meta, meta_digest = (None, None)
    if meta_path is not None and known is not None:
        meta, meta_digest = copy.deepcopy(known.meta), known.sha256
    elif meta_path is not None:
        meta, meta_digest = _read_meta_file(meta_path, p)
    meta_ok = False
    if meta is not None:
        n0 = len(p.errors)
        _check_meta(meta, p, SCAN_JSON)
        if isinstance(meta, dict):
            _meta_folder_checks(meta, sid, night, p)
        meta_ok = len(p.errors) == n0
    if meta_only:
        return (_MetaRead(meta, meta_digest) if not p else None), p.errors
    has_spindle_file = os.path.lexists(scan_dir / SPINDLE_FILE)
    lds_tab = _read_parquet(lds_path, LDS_FILE, LDS_SCHEMA, p) if lds_path is not None else None
    sp_tab = _read_parquet(sp_path, SPINDLE_FILE, SPINDLE_SCHEMA, p) if sp_path is not None else None
    warnings: list[str] = []
    matrix = None
    if lds_tab is not None:
        warnings, matrix = _check_lds(lds_tab, meta if meta_ok else None, has_spindle_file, p, LDS_FILE)
    if sp_tab is not None:
        _check_spindle(sp_tab, p, SPINDLE_FILE)
    if p:
        return None, p.errors
    files = {SCAN_JSON: meta_path, LDS_FILE: lds_path}
    if sp_tab is not None:
        files[SPINDLE_FILE] = sp_path
    lds = pl.from_arrow(lds_tab)
    if matrix is not None:
        for a in (matrix.sample, matrix.t_s, matrix.values_mm, matrix.pose):
            a.flags.writeable = False  # shared by every lds_matrix(scan) call
    scan = RawScan(
        scan_id=sid,
        night=night,
        path=scan_dir,
        meta=meta,
        lds=lds,
        spindle=pl.from_arrow(sp_tab) if sp_tab is not None else None,
        files=files,
        warnings=warnings,
        _digests={SCAN_JSON: meta_digest},
        _matrix=(lds, matrix) if matrix is not None else None,
    )
    return scan, []


def read_scan(scan_dir: Path, raw_root: Path | None = None) -> RawScan:
    """Read and fully validate one scan folder.

    Parameters
    ----------
    scan_dir : Path
        ``<raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>``.
    raw_root : Path, optional
        The raw root; defaults to ``scan_dir.parent.parent``. The folder and its files must
        resolve inside it (symlinks that leave it are rejected).

    Returns
    -------
    RawScan

    Raises
    ------
    ScanError
        The first problem found (:func:`validate_root` lists them all).
    """
    scan, errors = _inspect(scan_dir, raw_root)
    if errors:
        raise errors[0]
    return scan


def inspect_scan(scan_dir: Path, raw_root: Path | None = None) -> tuple[RawScan | None, list[ScanError]]:
    """Read and validate one scan folder, returning every problem.

    Read and validate one scan folder like :func:`read_scan`, returning every problem instead of
    raising the first: ``(scan, [])`` when valid, ``(None, problems)`` otherwise.
    """
    return _inspect(scan_dir, raw_root)


def read_scan_meta(scan_dir: Path, raw_root: Path | None = None) -> dict:
    """Read and check only ``scan.json`` of a scan folder (fast path for listings).

    Raises
    ------
    ScanError
        First problem of the folder names or of ``scan.json``.
    """
    meta, errors = _inspect(scan_dir, raw_root, meta_only=True)
    if errors:
        raise errors[0]
    return meta
