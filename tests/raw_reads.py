"""Count the raw parses of one night's stages run in one process (issue 34: raw read once per night).

:func:`count_night_reads` patches the two parsers of :mod:`borescan.rawio.reader` (``_read_parquet``
for ``lds.parquet`` / ``spindle.parquet``, ``_read_meta_file`` for ``scan.json``), runs ingest, signal,
calibrate, measure, discrepancy and pooled on one night the way the workflow's scripts call them (one
worker, so every read happens in this process; the raw cache emptied before each stage, as in its own
job) and returns the parses per stage, file kind and scan folder. Ingest validates each raw file and
writes the night's readings store (:mod:`borescan.rawio.store`); the later stages read that store.

By hand: ``PYTHONPATH=src python tests/raw_reads.py /tmp/demo_raw/raw 2026-11-20 [--no-cache] [--read-cpu]``
(``--read-cpu``: also :func:`read_cpu_s`, the CPU time of a stage's read of the night's scans, from raw
and from ingest's store).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from borescan import night_config
from borescan import rawio
from borescan.config import load_config
from borescan.rawio import reader
from borescan.stages._common import write_table
from borescan.stages.calibrate import stage_calibrate
from borescan.stages.discrepancy import stage_discrepancy
from borescan.stages.ingest import stage_ingest
from borescan.stages.measure import stage_measure
from borescan.stages.pooled import pooled_dir, stage_pooled
from borescan.stages.signal import stage_signal

STAGES = ("ingest", "signal", "calibrate", "measure", "discrepancy", "pooled")


@dataclass(frozen=True)
class NightReads:
    """Raw parses of one night: ``(stage, file name, scan folder name) -> parses``, and the stages' tables."""

    parses: dict[tuple[str, str, str], int]
    tables: dict[str, pl.DataFrame]

    def per_kind(self, stage: str | None = None) -> dict[str, int]:
        """File name -> parses (of one stage, or of all)."""
        out: Counter = Counter()
        for (st, name, _), n in self.parses.items():
            if stage is None or st == stage:
                out[name] += n
        return dict(sorted(out.items()))


def _begin(stage: list[str], name: str) -> None:
    """Start a stage: in the workflow each runs in its own process, so nothing read before is kept."""
    stage[0] = name
    reader._SCAN_CACHE.clear()


def _run_stages(raw: Path, night: str, out: Path, stage: list[str]) -> dict[str, pl.DataFrame]:
    cfg, res = load_config(), out / "res"
    quiet = lambda _: None  # noqa: E731
    night_config.settle(res, [night], cfg)
    _begin(stage, "ingest")
    scans, _, _ = stage_ingest(raw, night, res)
    write_table(scans, out / "scans.parquet")
    _begin(stage, "signal")
    _, summary, _ = stage_signal(raw, night, res, out / "scans.parquet", cfg["signal"], log=quiet)
    write_table(summary, out / "summary.parquet")
    _begin(stage, "calibrate")
    cals, _, _ = stage_calibrate(
        raw,
        night,
        res,
        out / "scans.parquet",
        out / "summary.parquet",
        cfg["calibration"],
        log=quiet,
        uncertainty=cfg["uncertainty"],
        laboratory=cfg["laboratory"],
        verification=cfg["verification"],
        devices=cfg["devices"],
        signal=cfg["signal"],
    )
    write_table(cals, out / "calibrations.parquet")
    _begin(stage, "measure")
    mcfg = {
        k: cfg[k]
        for k in ("verification", "measurement", "calibration", "uncertainty", "laboratory", "signal")
    }
    diameters, verifications, _, _ = stage_measure(
        raw, night, res, out / "scans.parquet", [out / "calibrations.parquet"], [], mcfg, log=quiet
    )
    _begin(stage, "discrepancy")
    findings, _ = stage_discrepancy(
        raw, night, res, out / "scans.parquet", [out / "calibrations.parquet"], cfg["discrepancy"], log=quiet
    )
    _begin(stage, "pooled")
    pooled_dir(res, night).mkdir(parents=True, exist_ok=True)
    pooled, drift = stage_pooled(
        raw,
        night,
        res,
        [out / "scans.parquet"],
        [out / "calibrations.parquet"],
        cfg["discrepancy"],
        cfg["devices"],
        log=quiet,
    )
    return {
        "scans": scans,
        "summary": summary,
        "calibrations": cals,
        "diameters": diameters,
        "verifications": verifications,
        "findings": findings,
        "pooled_findings": pooled,
        "calibration_drift": drift,
    }


def count_night_reads(raw: Path, night: str, out: Path, monkeypatch) -> NightReads:
    """Run the night's stages in this process, counting every raw parse (``monkeypatch``: pytest's)."""
    parses: Counter = Counter()
    stage = ["-"]
    read_parquet, read_meta = reader._read_parquet, reader._read_meta_file

    def counted_parquet(path, fname, schema, p):
        parses[(stage[0], fname, Path(path).parent.name)] += 1
        return read_parquet(path, fname, schema, p)

    def counted_meta(path, p):
        parses[(stage[0], reader.SCAN_JSON, Path(path).parent.name)] += 1
        return read_meta(path, p)

    monkeypatch.setattr(reader, "_read_parquet", counted_parquet)
    monkeypatch.setattr(reader, "_read_meta_file", counted_meta)
    tables = _run_stages(Path(raw), night, Path(out), stage)
    return NightReads(dict(parses), tables)


def read_cpu_s(raw: Path, night: str, results_root: Path, repeats: int = 5) -> tuple[float, float]:
    """CPU seconds of one process to read the night's stored scans and their wide matrices.

    Returns (from raw: ``rawio.read_scan`` with the reader's cache off, what each stage job did
    before; from ingest's store: ``rawio.load_stored_scan``), each the sum over the scans of the best
    of ``repeats`` reads, the two reads of a scan alternated.
    """
    enabled = reader._SCAN_CACHE.enabled
    reader._SCAN_CACHE.enabled = False
    from_raw = from_store = 0.0
    try:
        for folder in sorted(rawio.readings_dir(results_root, night).iterdir()):
            raw_dir = Path(raw) / f"night={night}" / folder.name
            best = [float("inf"), float("inf")]
            for _ in range(repeats):
                for i in (0, 1):
                    t0 = time.process_time()
                    scan = rawio.load_stored_scan(folder) if i else rawio.read_scan(raw_dir, raw_root=raw)
                    rawio.lds_matrix(scan)
                    best[i] = min(best[i], time.process_time() - t0)
            from_raw += best[0]
            from_store += best[1]
    finally:
        reader._SCAN_CACHE.enabled = enabled
    return from_raw, from_store


if __name__ == "__main__":
    import pytest

    with pytest.MonkeyPatch.context() as mp, tempfile.TemporaryDirectory() as tmp:
        mp.setattr(reader._SCAN_CACHE, "enabled", "--no-cache" not in sys.argv[3:])
        reads = count_night_reads(Path(sys.argv[1]), sys.argv[2], Path(tmp), mp)
        timed = "--read-cpu" in sys.argv[3:]
        cpu = read_cpu_s(Path(sys.argv[1]), sys.argv[2], Path(tmp) / "res") if timed else None
    per_scan = Counter()
    for (_, name, scan), n in reads.parses.items():
        per_scan[(name, scan)] += n
    print(f"{'stage':<12} " + " ".join(f"{k:>16}" for k in ("scan.json", "lds.parquet", "spindle.parquet")))
    for st in STAGES:
        kinds = reads.per_kind(st)
        print(
            f"{st:<12} "
            + " ".join(f"{kinds.get(k, 0):>16}" for k in ("scan.json", "lds.parquet", "spindle.parquet"))
        )
    total = reads.per_kind()
    print(
        f"{'total':<12} "
        + " ".join(f"{total.get(k, 0):>16}" for k in ("scan.json", "lds.parquet", "spindle.parquet"))
    )
    print("most parses of one file:", max(per_scan.values()) if per_scan else 0)
    if cpu is not None:
        print(f"CPU s to read the night's stored scans: from raw {cpu[0]:.3f}, from the store {cpu[1]:.3f}")
