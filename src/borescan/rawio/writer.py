"""Writing a scan folder atomically (a temporary folder, then a rename); never over other content."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from borescan.rawio.format import LDS_FILE, SCAN_JSON, SPINDLE_FILE, SPINDLE_SCHEMA, sha256_file
from borescan.rawio.lds import _frame_to_arrow, _lds_to_arrow, check_scan_data
from borescan.rawio.meta import _Problems

# ---------------------------------------------------------------------------------------------
# writing


def _json_bytes(meta: dict) -> bytes:
    return (json.dumps(meta, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode("utf-8")


def _write_parquet(table: pa.Table, path: Path) -> None:
    pq.write_table(table, path, compression="zstd", use_dictionary=False, write_statistics=True)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _same_content(a: Path, b: Path) -> bool:
    fa = sorted(x.name for x in a.iterdir())
    fb = sorted(x.name for x in b.iterdir())
    return fa == fb and all(sha256_file(a / n) == sha256_file(b / n) for n in fa)


def write_scan(  # noqa: C901 (checks, staging and atomic rename of a scan's raw files)
    raw_root: Path, meta: dict, lds: pl.DataFrame, spindle: pl.DataFrame | None = None
) -> Path:
    """Write one scan as ``<raw_root>/night=<night>/scan=<scan_id>/`` (atomic, write-once).

    Columns are cast losslessly to the format dtypes (e.g. int64 -> int16 for ``sensor``);
    extra columns are dropped. The data are validated before anything is written. The files go
    to a temporary folder beside the target, which is then renamed into place. Writing the
    same content again is a no-op.

    Parameters
    ----------
    raw_root : Path
    meta : dict
        ``scan.json`` content.
    lds : pl.DataFrame
        Long table: sample, t_ns, sensor, value_mm, pose.
    spindle : pl.DataFrame, optional
        t_ns, angle_rad, x_mm, y_mm, rpm.

    Returns
    -------
    Path
        The scan folder.

    Raises
    ------
    ScanError
        The data would not make a valid scan (first problem; all are in ``problems``).
    FileExistsError
        The folder exists with different content, or the scan_id exists under another night.
    """
    raw_root = Path(raw_root)
    errors = check_scan_data(meta, lds, spindle)
    if errors:
        err = errors[0]
        err.problems = errors  # type: ignore[attr-defined]
        raise err
    p = _Problems(meta["scan_id"])
    lds_t = _lds_to_arrow(lds, p, LDS_FILE)
    sp_t = _frame_to_arrow(spindle, SPINDLE_SCHEMA, p, SPINDLE_FILE) if spindle is not None else None
    sid, night = meta["scan_id"], meta["night"]
    night_dir = raw_root / f"night={night}"
    final = night_dir / f"scan={sid}"
    if raw_root.is_dir():
        for other in raw_root.glob(f"night=*/scan={sid}"):
            if other.parent.name != night_dir.name:
                raise FileExistsError(
                    f"{sid}: {other.parent.name}/{other.name}: scan_id already used under another night"
                )
    night_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".scan={sid}.tmp-", dir=night_dir))
    try:
        (tmp / SCAN_JSON).write_bytes(_json_bytes(meta))
        _write_parquet(lds_t, tmp / LDS_FILE)
        if sp_t is not None:
            _write_parquet(sp_t, tmp / SPINDLE_FILE)
        for f in tmp.iterdir():
            _fsync(f)
        os.chmod(tmp, 0o755)
        if final.exists() or final.is_symlink():
            if final.is_dir() and not final.is_symlink() and _same_content(tmp, final):
                return final
            raise FileExistsError(
                f"{sid}: {night_dir.name}/{final.name}: exists with different content "
                "(raw folders are write-once)"
            )
        try:
            os.rename(tmp, final)
        except OSError:
            if final.is_dir() and _same_content(tmp, final):
                return final
            raise FileExistsError(
                f"{sid}: {night_dir.name}/{final.name}: appeared while writing with different content"
            ) from None
        _fsync(night_dir)
        return final
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
