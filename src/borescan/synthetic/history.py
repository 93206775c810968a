"""A long history made cheaply: processed nights' stage outputs copied under new nights and ids.

Running the pipeline for a year of nights takes hours; the catalog and the report only read the
stage tables (``<results_root>/stage/<table>/night=<night>.parquet``) and the files their rows
point to (certificates, gap plots, quarantine records). :func:`copy_nights` writes synthetic
nights from the nights of an already processed results folder (for example the demo's two
nights): every synthetic night holds all source nights at once, their dates replaced by its own
and their scan ids tagged ``-S1``, ``-S2``, ... (a verification of the demo's second night still
names the calibration of the first, now of the same night), so every synthetic night carries
the same work. ``copies`` > 1 replicates it for more devices (``TRI-01`` -> ``TRI-01-K1`` ...;
scan ids get ``-K1`` ...). Parts (artifacts of type ``part``) get the night in their id, so each
synthetic night measures new parts; ring gauges keep theirs. Files are hard-linked where the
filesystem allows (copied otherwise), so a year costs seconds.

Only the tables the catalog reads are written (:data:`borescan.catalog.STAGE_TABLES` and the
quarantine rows of every stage). Nothing here is a measurement: the numbers are the source's.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import polars as pl

__all__ = ["SourceNights", "read_source", "copy_nights", "synthetic_night"]

_COPIED_TABLES = (
    "scans",
    "scan_files",
    "calibrations",
    "calibration_scans",
    "diameters",
    "verifications",
    "findings",
    "artifacts",
)


@dataclass
class SourceNights:
    """The stage tables of a processed results folder, night by night (read once)."""

    root: Path
    nights: list[str]
    tables: dict[str, dict[str, pl.DataFrame]]  # night -> table (incl. "quarantine/stage=<s>") -> frame
    devices: list[str]
    parts: set[str]


def read_source(results_root: str | os.PathLike) -> SourceNights:
    """Read every night's stage tables of ``results_root`` (raises ``ValueError`` when there are none)."""
    root = Path(results_root)
    nights = sorted(p.stem.removeprefix("night=") for p in (root / "stage" / "scans").glob("night=*.parquet"))
    if not nights:
        raise ValueError(f"{root}: no stage/scans/night=*.parquet to copy nights from")
    tables: dict[str, dict[str, pl.DataFrame]] = {}
    devices, parts = set(), set()
    for night in nights:
        per: dict[str, pl.DataFrame] = {}
        for name in _COPIED_TABLES:
            f = root / "stage" / name / f"night={night}.parquet"
            if f.is_file():
                per[name] = pl.read_parquet(f)
        for f in sorted((root / "stage" / "quarantine").glob(f"stage=*/night={night}.parquet")):
            per[f"quarantine/{f.parent.name}"] = pl.read_parquet(f)
        tables[night] = per
        if "device_id" in per.get("scans", pl.DataFrame()).columns:
            devices |= set(per["scans"]["device_id"].drop_nulls().to_list())
        art = per.get("artifacts")
        if art is not None and {"artifact_id", "type"} <= set(art.columns):
            parts |= set(art.filter(pl.col("type") == "part")["artifact_id"].to_list())
    # longest first, so that a device id that contains another is replaced as a whole
    return SourceNights(root, nights, tables, sorted(devices, key=lambda d: (-len(d), d)), parts)


def synthetic_night(start: str, index: int) -> str:
    """Return the ISO date of synthetic night ``index`` (0-based) counted from ``start``."""
    return (_dt.date.fromisoformat(start) + _dt.timedelta(days=index)).isoformat()


def _compact(iso: str) -> str:
    return iso.replace("-", "")


class _Renamer:
    """The id map of one (source night, copy) in a synthetic night.

    The id map of one (source night, copy) in a synthetic night: source dates -> its date,
    devices, scans and parts suffixed.
    """

    def __init__(self, src: SourceNights, block_dates: dict[str, str], copy: int, night: str, tag: str = ""):
        self.suffix = f"-K{copy}" if copy else ""
        self.tag = tag
        self.dates = dict(block_dates)
        self.dates.update({_compact(a): _compact(b) for a, b in block_dates.items()})
        self.devices = {d: d + self.suffix for d in src.devices} if copy else {}
        self.night = night
        self.parts = src.parts
        self.ids = {**self.dates, **self.devices}
        self._rx_ids = _alternation(self.ids)
        self._rx_dates = _alternation(self.dates)

    def text(self, s: str | None, *, devices: bool = True) -> str | None:
        """Dates (and device ids) replaced inside an id or path, in one pass (longest match first)."""
        if s is None:
            return None
        rx, table = (self._rx_ids, self.ids) if devices else (self._rx_dates, self.dates)
        return rx.sub(lambda m: table[m.group(0)], s) if table else s

    def scan(self, s: str | None) -> str | None:
        if s is None:
            return None
        new = self.text(s, devices=False)
        if new == s:  # an id without its night's date: made unique per night
            new = f"{s}-{_compact(self.night)}"
        return new + self.tag + self.suffix

    def raw_path(self, s: str | None) -> str | None:
        """``.../night=<night>/scan=<scan_id>`` with the new night and scan id."""
        if s is None or "scan=" not in s:
            return s
        head, _, sid = s.rpartition("scan=")
        return self.text(head, devices=False) + "scan=" + self.scan(sid)

    def device(self, s: str | None) -> str | None:
        return None if s is None else s + self.suffix

    def artifact(self, s: str | None) -> str | None:
        if s is None or s not in self.parts:
            return s
        return f"{s}-{_compact(self.night)}{self.suffix}"

    def frame(self, df: pl.DataFrame, shift_days: int) -> pl.DataFrame:
        out = []
        for c in df.columns:
            col = pl.col(c)
            if df.schema[c] != pl.Utf8:
                out.append(col)
            elif c == "scan_id":
                out.append(col.map_elements(self.scan, return_dtype=pl.Utf8))
            elif c == "raw_path":
                out.append(col.map_elements(self.raw_path, return_dtype=pl.Utf8))
            elif c == "device_id":
                out.append(col.map_elements(self.device, return_dtype=pl.Utf8))
            elif c == "artifact_id":
                out.append(col.map_elements(self.artifact, return_dtype=pl.Utf8))
            elif c in ("calibration_id", "certificate_path"):
                out.append(col.map_elements(self.text, return_dtype=pl.Utf8))
            elif c in ("night", "valid_from"):
                out.append(col.map_elements(lambda s: self.dates.get(s, s), return_dtype=pl.Utf8))
            elif c in ("started_at", "recalibration_due"):  # a calibration falls due as long after it
                out.append(col.map_elements(lambda s: _shift_time(s, shift_days), return_dtype=pl.Utf8))
            else:
                out.append(col)
        return df.select(out) if df.height else df


def _alternation(keys: Iterable[str]) -> re.Pattern:
    return re.compile("|".join(re.escape(k) for k in sorted(keys, key=len, reverse=True)) or "(?!)")


def _shift_time(s: str | None, days: int) -> str | None:
    """Return an ISO 8601 time stamp moved by whole days (its text after the date kept as written)."""
    if s is None or len(s) < 10:
        return s
    try:
        d = _dt.date.fromisoformat(s[:10])
    except ValueError:
        return s
    return (d + _dt.timedelta(days=days)).isoformat() + s[10:]


def _link_tree(src: Path, dst: Path) -> None:
    """Hard-link every file of ``src`` under ``dst`` (copy where links are not possible)."""
    for f in src.rglob("*"):
        if f.is_file():
            target = dst / f.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            if target.exists():
                continue
            try:
                os.link(f, target)
            except OSError:
                shutil.copy2(f, target)


def _write(df: pl.DataFrame, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    df.write_parquet(tmp, statistics=False)
    tmp.replace(path)


def copy_nights(
    src: SourceNights,
    dest_root: str | os.PathLike,
    start: str,
    indices: Iterable[int],
    copies: int = 1,
    stage_root: str | os.PathLike | None = None,
) -> list[str]:
    """Write synthetic nights ``indices`` (0-based from ``start``) into ``dest_root``; return their dates.

    ``stage_root`` (default ``dest_root``) is where the ``stage/`` tables go, so the nights can be
    prepared beside a results folder and moved in later; the files they point to (certificates,
    gap plots, quarantine records) always go under ``dest_root``.
    """
    dest = Path(dest_root)
    stage = Path(stage_root) if stage_root is not None else dest
    written = []
    for i in indices:
        night = synthetic_night(start, i)
        dates = {s: night for s in src.nights}
        per: dict[str, list[pl.DataFrame]] = {}
        for k in range(copies):
            for j, src_night in enumerate(src.nights):
                ren = _Renamer(src, dates, k, night, tag=f"-S{j + 1}" if len(src.nights) > 1 else "")
                shift = (_dt.date.fromisoformat(night) - _dt.date.fromisoformat(src_night)).days
                for name, df in src.tables[src_night].items():
                    per.setdefault(name, []).append(ren.frame(df, shift))
                _copy_files(src, dest, src_night, ren)
        for name, frames in per.items():
            _write(
                pl.concat(frames, how="diagonal_relaxed"), stage / "stage" / name / f"night={night}.parquet"
            )
        written.append(night)
    return written


def _copy_files(src: SourceNights, dest: Path, src_night: str, ren: _Renamer) -> None:
    """Certificates, gap plots and quarantine records of a source night under their new ids."""
    t = src.tables[src_night]
    cal = t.get("calibrations")
    if cal is not None and "certificate_path" in cal.columns:
        for path in sorted(set(cal["certificate_path"].drop_nulls().to_list())):
            folder = Path(path).parent
            if (src.root / folder).is_dir():
                _link_tree(src.root / folder, dest / ren.text(folder.as_posix()))
    for sid in t.get("scans", pl.DataFrame({"scan_id": []}))["scan_id"].to_list():
        d = src.root / "discrepancy" / sid
        if d.is_dir():
            _link_tree(d, dest / "discrepancy" / ren.scan(sid))
        q = src.root / "quarantine" / f"{sid}.json"
        if q.is_file():
            target = dest / "quarantine" / f"{ren.scan(sid)}.json"
            target.parent.mkdir(parents=True, exist_ok=True)
            if not target.exists():
                try:
                    os.link(q, target)
                except OSError:
                    shutil.copy2(q, target)
