"""Signal-stage throughput vs plain Parquet reading (target: stage >= 0.5 x plain read).

A 600-revolution x 660-samples x 3-channel scan (Yang-like geometry, 2.5 um noise, a few nulls
and spikes) is written as a scan folder of raw-scan-format.md (scan.json, lds.parquet, a
spindle.parquet without encoder angle, so the period comes from the readings). Measured in the
same run, best of several repeats, throughput in readings (rows of the long table) per second:

- plain read: the five ``lds.parquet`` columns by the faster of ``polars.read_parquet`` and
  ``pyarrow.parquet.read_table`` (both multi-threaded);
- whole stage: what the night's signal job does for one scan (``borescan.stages.signal.signal_one``): read
  the scan as ingest stored it (``rawio.load_stored_scan``: the raw folder is read and validated once, by
  ingest, ``rawio.read_scan``, timed below), the wide matrix, the clock check, spikes, period,
  extrema, n/m, status, spacings, feature points, the summary row. Not included: writing the
  night's tables (once per night, for all scans);
- processing only: ``rawio.lds_matrix`` + ``signal.process_arrays`` on the table in memory (the
  figure this benchmark printed before it measured the whole stage).

Also prints where the time goes (each step on its own; ``lds_matrix`` is timed on a scan without the
matrix ``read_scan``'s check builds, as the stage's stored scan is), the stage's time besides its
read next to the read's own (the budget 0.5x leaves) and the pyarrow read on one thread (the
threaded read keeps both cores busy, so there is no idle core to overlap with), and the filter
table of ``signal.filter_performance`` (scatter reduction, phase lag, amplitude loss per filter).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import polars as pl
import pyarrow.parquet as pq

from borescan import rawio
from borescan.config import load_config
from borescan.stages.signal import signal_one, signal_options
from borescan.geometry import Beams, Bore, tri_spindle_readings
from borescan.signal import (
    filter_performance,
    find_extrema,
    period_from_readings,
    process_arrays,
    remove_spikes,
)

N_REV = 600
SPR = 660
COLUMNS = ["sample", "t_ns", "sensor", "value_mm", "pose"]
NIGHT = "2026-11-30"


def _write_scan(raw: Path, seed: int = 0) -> tuple[Path, int]:
    """Return the reference scan folder under ``raw``; returns (folder, readings)."""
    beams = Beams(
        (1, 2, 3),
        np.array([0.3, 2.4, 4.5]),
        np.array([5.5484, -2.5295, 1.5262]),
        np.array([132.6718, 132.8883, 134.1108]),
    )
    n = N_REV * SPR
    k = np.arange(n)
    v = tri_spindle_readings(
        2 * np.pi * k / SPR * 1.002,
        np.array([262.955, -275.502]),
        beams,
        Bore((262.833, -273.182), 275.029 / 2),
    )  # 1.1-7.3 mm: inside the 10 mm range
    rng = np.random.default_rng(seed)
    v = v + rng.normal(0, 0.0025, v.shape)
    v[rng.integers(0, n, 200), rng.integers(0, 3, 200)] += 0.2
    v[rng.integers(0, n, 200), rng.integers(0, 3, 200)] = np.nan
    c = v.shape[1]
    lds = pl.DataFrame(
        {
            "sample": np.repeat(k, c).astype(np.int64),
            "t_ns": np.repeat(np.round(k * 1e9 / SPR), c).astype(np.int64),
            "sensor": np.tile(np.arange(1, c + 1), n).astype(np.int16),
            "value_mm": pl.Series(v.reshape(-1)).fill_nan(None),
            "pose": pl.Series([None] * (n * c), dtype=pl.Int32),
        }
    )
    t_sp = np.arange(0, n, 66) / SPR  # spindle stream at 10 Hz, no encoder angle
    spindle = pl.DataFrame(
        {
            "t_ns": np.round(t_sp * 1e9).astype(np.int64),
            "angle_rad": pl.Series([None] * t_sp.size, dtype=pl.Float64),
            "x_mm": np.full(t_sp.size, 262.955),
            "y_mm": np.full(t_sp.size, -275.502),
            "rpm": np.full(t_sp.size, 60.0),
        }
    )
    meta = {
        "format": "borescan-raw/1",
        "scan_id": "BENCH-SIGNAL",
        "night": NIGHT,
        "started_at": f"{NIGHT}T20:00:00Z",
        "kind": "calibration",
        "device": {"id": "TRI-01", "type": "tri_lds"},
        "sample_rate_hz": float(SPR),
        "sensors": [{"channel": ch, "model": "HG-C1030", "range_mm": 10.0} for ch in range(1, c + 1)],
        "spindle": {"rpm_nominal": 60.0, "direction": "ccw"},
        "artifact": {"id": "RG-275", "type": "ring_gauge"},
        "acquisition": {"software": "bench", "simulated": True},
    }
    return rawio.write_scan(raw, meta, lds, spindle), lds.height


def _best(fn, repeats: int = 5) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> dict:
    """Time the signal stage on one written scan; return the timings."""
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw"
        folder, rows = _write_scan(raw)
        lds_path = folder / rawio.LDS_FILE
        opts = signal_options(load_config()["signal"])
        # the stage reads the scan as ingest stored it (borescan.rawio.store), not the raw folder
        scan0 = rawio.read_scan(folder, raw_root=raw)
        stored = rawio.stored_scan_dir(Path(tmp) / "results", NIGHT, scan0.scan_id)
        rawio.write_stored_scan(stored, scan0, scan0.sha256)
        job = (raw, NIGHT, Path(tmp) / "results", stored, opts)

        def read_polars() -> pl.DataFrame:
            return pl.read_parquet(lds_path, columns=COLUMNS)

        def read_arrow():
            return pq.read_table(lds_path, columns=COLUMNS)

        def read_arrow_one_thread():
            return pq.read_table(lds_path, columns=COLUMNS, use_threads=False)

        def whole_stage():
            ext, summary, bad, _ = signal_one(job)
            assert not bad and ext is not None
            return ext, summary

        def processing(df):
            mat = rawio.lds_matrix(SimpleNamespace(lds=df, channels=(1, 2, 3)))
            return process_arrays(
                mat.values_mm,
                sample_rate_hz=float(SPR),
                rpm_nominal=60.0,
                t_s=mat.t_s,
                channels=mat.channels,
                scan_id="bench",
            )

        ext, _ = whole_stage()  # warm-up (imports, caches) and a sanity check
        df = read_polars()
        res = processing(df)
        mat = rawio.lds_matrix(SimpleNamespace(lds=df, channels=(1, 2, 3)))
        times = {}
        for _ in range(2):  # interleaved, best of both rounds
            for name, fn in (
                ("read_polars", read_polars),
                ("read_arrow", read_arrow),
                ("stage", whole_stage),
                ("processing", lambda: (read_polars(), processing(df))),
            ):
                times[name] = min(times.get(name, np.inf), _best(fn, 3))
        t_read = min(times["read_polars"], times["read_arrow"])
        t_stage = times["stage"]
        t_proc = times["processing"] - times["read_polars"]  # lds_matrix + process_arrays after a read
        scan = rawio.read_scan(folder, raw_root=raw)
        clean, _ = remove_spikes(mat.values_mm)
        u = np.arange(clean.shape[0]) / res.period.samples_per_rev
        t_read_one = _best(read_arrow_one_thread)
        steps = {
            "rawio.read_scan": _best(lambda: rawio.read_scan(folder, raw_root=raw)),
            "rawio.lds_matrix, uncached": _best(
                lambda: rawio.lds_matrix(SimpleNamespace(lds=scan.lds, channels=(1, 2, 3)))
            ),
            "process_arrays": _best(
                lambda: process_arrays(
                    mat.values_mm,
                    sample_rate_hz=float(SPR),
                    rpm_nominal=60.0,
                    t_s=mat.t_s,
                    channels=mat.channels,
                )
            ),
            "  remove_spikes": _best(lambda: remove_spikes(mat.values_mm)),
            "  period_from_readings": _best(
                lambda: period_from_readings(clean, samples_per_rev_guess=float(SPR))
            ),
            "  find_extrema": _best(
                lambda: find_extrema(
                    clean, u, samples_per_rev=res.period.samples_per_rev, channels=mat.channels
                )
            ),
        }
    out = {
        "rows": rows,
        "read_s": t_read,
        "read_one_thread_s": t_read_one,
        "read_polars_s": times["read_polars"],
        "read_arrow_s": times["read_arrow"],
        "stage_s": t_stage,
        "processing_s": t_proc,
        "read_rows_per_s": rows / t_read,
        "stage_rows_per_s": rows / t_stage,
        "ratio": t_read / t_stage,
        "ratio_processing": t_read / (t_read + t_proc),
        "samples_per_rev": res.period.samples_per_rev,
        "extrema": ext.height,
        **{f"{k.strip()}_s": t for k, t in steps.items()},
    }
    print(f"signal stage: {rows} readings ({N_REV} rev x {SPR} x 3 channels), best of 6, interleaved")
    print(
        f"  plain read (polars / pyarrow)  : {times['read_polars'] * 1e3:6.1f} / "
        f"{times['read_arrow'] * 1e3:6.1f} ms"
        f"  -> {rows / t_read / 1e6:6.2f} M readings/s (the faster)"
    )
    print(
        f"  whole stage (read_scan ... summary): {t_stage * 1e3:6.1f} ms  {rows / t_stage / 1e6:6.2f} M "
        "readings/s"
    )
    print(f"  processing only (lds_matrix + process_arrays): {t_proc * 1e3:6.1f} ms")
    for name, t in steps.items():
        print(f"    {name:26s}: {t * 1e3:7.1f} ms")
    print(
        f"  stage less the plain read       : {(t_stage - t_read) * 1e3:6.1f} ms (one thread); at 0.5x "
        "it may take"
        f" {t_read * 1e3:.1f} ms, the read's own time"
    )
    print(
        f"  pyarrow read on one thread      : {t_read_one * 1e3:6.1f} ms (the threaded read keeps both "
        "cores busy)"
    )
    print(f"  ratio whole stage / read        : {out['ratio']:.3f}  (target >= 0.5)")
    print(f"  ratio read + processing / read  : {out['ratio_processing']:.3f}  (no validation)")
    print(
        f"  period {res.period.samples_per_rev:.5f} +- {res.period.u_samples_per_rev:.1e} samples/rev "
        f"(truth {SPR / 1.002:.4f}), {ext.height} extrema"
    )
    tab = filter_performance(revolutions=8, samples_per_rev=SPR, noise_mm=0.0025, seed=0)
    print("  filters, simulated 60 rpm / 660 samples/rev, 2.5 um noise (Yang §4: 15 um beat -> 3 um),")
    print("  channel 1 (2.3 mm eccentricity): lag/amplitude of the 1-UPR term, shift of the minimum")
    print(
        f"  {'filter':28s} {'beat um':>8s} {'rms um':>7s} {'lag rad':>9s} {'lag smp':>8s}"
        f" {'amp loss um':>11s} {'min shift smp':>13s}"
    )
    for r in tab.iter_rows(named=True):
        print(
            f"  {r['filter']:28s} {r['beat_um']:8.2f} {r['scatter_um']:7.2f} {r['lag_rad']:9.5f}"
            f" {r['lag_samples']:8.3f} {r['amplitude_loss_um']:11.3f} {r['min_shift_samples']:13.3f}"
        )
    out["filters"] = tab
    return out


if __name__ == "__main__":
    main()
