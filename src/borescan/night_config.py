"""The config each night was processed with.

Results already in the history keep the rules they were made under.

A night's jobs take their settings (every section of the config but the roots) from the night's
record, ``<results_root>/stage/night_config/night=<night>.parquet``,
written the first time the workflow sees the night. An edit of ``config/config.yaml`` therefore
applies to nights not yet in the history, from the first of them on (as a device model's ``from:``
does); past nights are neither rerun nor rewritten by it. The catalog has the records as the table
``night_config`` (night, config hash, the settings as JSON, who recorded them).

Applying a new config to past nights is a deliberate act: :func:`recompute` (``borescan recompute
--from NIGHT``) keeps the current results of those nights under ``<results_root>/versions/<change>/``,
records the new settings for each night from ``NIGHT`` on and a change record
(``stage/config_changes/``, catalog table ``config_changes``: the nights, the old and new hashes and
the keys that differ), and marks the nights' raw manifests so that the next run recomputes them
(whatever checkout runs it).

A record also keeps ``first_processed``, the UTC date the workflow first saw the night: the date of
issue of the night's certificates (:func:`first_processed`), so that a certificate regenerated later
carries the same date and the same bytes. A recomputation keeps it.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from borescan import tables
from borescan.atomic import atomic_write_bytes
from borescan.raw_index import raw_index_path

__all__ = [
    "RUN_KEYS",
    "NightConfig",
    "ConfigChange",
    "night_settings",
    "settings_hash",
    "changed_keys",
    "record_path",
    "read_record",
    "first_processed",
    "settle",
    "recompute",
]

#: config keys that say where and how fast to run, not how to compute: never part of a night's record
RUN_KEYS = ("raw_root", "results_root")


@dataclass(frozen=True)
class NightConfig:
    """The settings one night was (or will be) processed with."""

    night: str
    config_hash: str
    settings: dict
    recorded_by: str
    #: UTC date (ISO) the workflow first saw the night; None in a record written before it was kept
    first_processed: str | None = None


@dataclass(frozen=True)
class ConfigChange:
    """A recomputation asked for: which nights, from which settings to which, where the old results went."""

    change_id: str
    from_night: str
    nights: tuple[str, ...]
    old_hashes: tuple[str, ...]
    new_hash: str
    keys: tuple[str, ...]
    archive: str


def night_settings(config: dict) -> dict:
    """Return the settings of ``config`` that a night's results depend on (JSON-normalised)."""
    return json.loads(
        json.dumps({k: v for k, v in config.items() if k not in RUN_KEYS}, sort_keys=True, default=str)
    )


def settings_hash(settings: dict) -> str:
    """16 hex digits of SHA-256 over the settings' canonical JSON (as ``stages._common.config_hash``)."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _write_parquet(df: pl.DataFrame, path: Path) -> None:
    buf = io.BytesIO()
    df.write_parquet(buf, statistics=False)
    atomic_write_bytes(path, buf.getvalue())


def changed_keys(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two settings dicts (added or removed keys included)."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += changed_keys(a, b, f"{prefix}{k}.")
        elif a != b or (k in old) != (k in new):
            out.append(f"{prefix}{k}")
    return out


def record_path(results_root, night: str) -> Path:
    """Return the path of ``night``'s config record under ``results_root``."""
    return Path(results_root) / "stage" / "night_config" / f"night={night}.parquet"


def read_record(results_root, night: str) -> NightConfig | None:
    """Return the night's record, or None when the workflow has not seen the night yet."""
    path = record_path(results_root, night)
    if not path.is_file():
        return None
    row = pl.read_parquet(path).row(0, named=True)
    first = row.get("first_processed")
    return NightConfig(
        night,
        row["config_hash"],
        json.loads(row["config_json"]),
        row["recorded_by"],
        str(first) if first is not None else None,
    )


def first_processed(results_root, night: str) -> str:
    """Return the UTC date (ISO) the workflow first processed ``night``: its certificates' date of issue.

    Raises ValueError naming the record when the night has none (the workflow writes it when it first
    sees the night, before any job) or the record has no date.
    """
    rec = read_record(results_root, night)
    if rec is None or rec.first_processed is None:
        raise ValueError(
            f"night {night}: {record_path(results_root, night)} "
            + ("does not exist" if rec is None else "has no first_processed date")
            + " (the workflow records it when it first sees the night)"
        )
    return rec.first_processed


def _today() -> str:
    return _dt.datetime.now(_dt.UTC).date().isoformat()


def _record_date(path: Path) -> str:
    """UTC date of a record file's last write: when a record from before ``first_processed`` was made."""
    return _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.UTC).date().isoformat()


def _write_record(results_root, rec: NightConfig) -> None:
    _write_parquet(
        tables.frame(
            "night_config",
            [
                {
                    "night": rec.night,
                    "config_hash": rec.config_hash,
                    "config_json": json.dumps(rec.settings, sort_keys=True),
                    "recorded_by": rec.recorded_by,
                    "first_processed": rec.first_processed,
                }
            ],
        ),
        record_path(results_root, rec.night),
    )


def settle(
    results_root, nights: list[str], config: dict, *, record: bool = True
) -> tuple[dict[str, dict], list[str]]:
    """Each night's settings: its record, else the current config (recorded now for it).

    Returns (night -> settings, the recorded nights whose settings differ from the current config).
    A results root that cannot be written gets no record (the run stops at its first output); nor does a
    dry run (``record=False``: the settings a run would record, nothing written).
    A record written before ``first_processed`` was kept gets the date its file was written, once.
    """
    current = night_settings(config)
    h = settings_hash(current)
    out, differ = {}, []
    for night in nights:
        rec = read_record(results_root, night)
        if rec is None:
            rec = NightConfig(night, h, current, "first run", _today())
            try:
                if record:
                    _write_record(results_root, rec)
            except OSError:
                pass
        elif rec.first_processed is None:
            dated = NightConfig(
                night,
                rec.config_hash,
                rec.settings,
                rec.recorded_by,
                _record_date(record_path(results_root, night)),
            )
            try:
                _write_record(results_root, dated)
            except OSError:
                pass
        if rec.config_hash != h:
            differ.append(night)
        out[night] = rec.settings
    return out, differ


def _archive_night(results_root: Path, night: str, dest: Path) -> None:
    """Copy the night's stage tables and per-night folders into ``dest`` (same relative paths)."""
    stage = results_root / "stage"
    for f in sorted(stage.rglob(f"night={night}.parquet")):
        target = dest / f.relative_to(results_root)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(f, target)
    for area in ("calibration", "discrepancy", "discrepancy/pooled"):
        folder = results_root / area / f"night={night}"
        if folder.is_dir():
            shutil.copytree(folder, dest / area / f"night={night}", symlinks=True)


def recompute(results_root, from_night: str, config: dict) -> ConfigChange | None:
    """Apply ``config`` to every recorded night from ``from_night`` on; None when none differs.

    The nights' current results are copied to ``<results_root>/versions/<change_id>/`` first (the
    stage tables and the certificates' and findings' night folders), then each gets a new record
    (``recorded_by = "recompute <change_id>"``), the change record is appended to
    ``stage/config_changes/night=<from_night>.parquet``, and each night's raw manifest
    (``raw_index/night=<night>.txt``, an input of its jobs) is given the current time, so that the
    next workflow run recomputes these nights and what depends on them.
    """
    root = Path(results_root)
    current = night_settings(config)
    h = settings_hash(current)
    recs = [
        read_record(root, p.name[6:-8])
        for p in sorted((root / "stage" / "night_config").glob("night=*.parquet"))
    ]
    todo = [r for r in recs if r is not None and r.night >= from_night and r.config_hash != h]
    if not todo:
        return None
    changes_file = root / "stage" / "config_changes" / f"night={from_night}.parquet"
    done = sorted((root / "versions").glob("change-*")) if (root / "versions").is_dir() else []
    change_id = f"change-{len(done) + 1:04d}"
    archive = root / "versions" / change_id
    for r in todo:
        _archive_night(root, r.night, archive)
    keys = sorted({k for r in todo for k in changed_keys(r.settings, current)})
    change = ConfigChange(
        change_id,
        from_night,
        tuple(r.night for r in todo),
        tuple(r.config_hash for r in todo),
        h,
        tuple(keys),
        str(archive.relative_to(root)),
    )
    row = {
        "night": from_night,
        "change_id": change_id,
        "nights": ",".join(change.nights),
        "old_hashes": ",".join(change.old_hashes),
        "new_hash": h,
        "changed_keys": ",".join(keys),
        "archive": change.archive,
    }
    before = pl.read_parquet(changes_file) if changes_file.is_file() else tables.frame("config_changes", [])
    _write_parquet(
        pl.concat([before, tables.frame("config_changes", [row])], how="diagonal_relaxed"), changes_file
    )
    for r in todo:
        _write_record(
            root, NightConfig(r.night, h, current, f"recompute {change_id}", r.first_processed or _today())
        )
        index = raw_index_path(root, r.night)
        if index.is_file():
            os.utime(index)  # now: the night's jobs are older than an input, whichever checkout runs
    return change
