"""Signal-stage throughput vs plain Parquet reading (target: stage >= 0.5 x plain read).

A 600-revolution x 660-samples x 3-channel scan (Yang-like geometry, 2.5 um noise, a few nulls
and spikes) is written in the long ``lds.parquet`` layout of raw-scan-format.md to a temporary
file. Measured in the same run, best of several repeats:
- plain read: ``polars.read_parquet`` of the five columns;
- stage: the same read, ``rawio.lds_matrix`` (long -> wide) and ``signal.process_arrays`` with
  its defaults (spikes, period from the readings, extrema, n/m, status, spacings).
Throughput is readings (rows of the long table) per second. Also prints where ``process_arrays``
spends its time (its three heavy public steps timed on their own) and the filter table of
``signal.filter_performance`` (scatter reduction, phase lag, amplitude loss per filter).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import polars as pl

from borescan import rawio
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


def _write_scan(path: Path, seed: int = 0) -> int:
    beams = Beams((1, 2, 3), np.array([0.3, 2.4, 4.5]), np.array([5.5484, -2.5295, 1.5262]),
                  np.array([132.6718, 132.8883, 134.1108]))
    n = N_REV * SPR
    k = np.arange(n)
    v = tri_spindle_readings(2 * np.pi * k / SPR * 1.002, np.array([262.955, -275.502]), beams,
                             Bore((262.833, -273.182), 275.029 / 2))
    rng = np.random.default_rng(seed)
    v = v + rng.normal(0, 0.0025, v.shape)
    v[rng.integers(0, n, 200), rng.integers(0, 3, 200)] += 0.2
    v[rng.integers(0, n, 200), rng.integers(0, 3, 200)] = np.nan
    c = v.shape[1]
    df = pl.DataFrame({
        "sample": np.repeat(k, c).astype(np.int64),
        "t_ns": np.repeat(np.round(k * 1e9 / SPR), c).astype(np.int64),
        "sensor": np.tile(np.arange(1, c + 1), n).astype(np.int16),
        "value_mm": pl.Series(v.reshape(-1)).fill_nan(None),
        "pose": pl.Series([None] * (n * c), dtype=pl.Int32),
    })
    df.write_parquet(path)
    return df.height


def _best(fn, repeats: int = 5) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "lds.parquet"
        rows = _write_scan(path)

        def read() -> pl.DataFrame:
            return pl.read_parquet(path, columns=COLUMNS)

        def stage():
            mat = rawio.lds_matrix(SimpleNamespace(lds=read(), channels=(1, 2, 3)))
            return process_arrays(mat.values_mm, sample_rate_hz=float(SPR), rpm_nominal=60.0, t_s=mat.t_s,
                                  channels=mat.channels, scan_id="bench")

        res = stage()  # warm-up (imports, caches) and a sanity check
        df = read()
        mat = rawio.lds_matrix(SimpleNamespace(lds=df, channels=(1, 2, 3)))
        t_read = _best(read)
        t_stage = _best(stage)
        t_matrix = _best(lambda: rawio.lds_matrix(SimpleNamespace(lds=df, channels=(1, 2, 3))))
        t_proc = _best(lambda: process_arrays(mat.values_mm, sample_rate_hz=float(SPR), rpm_nominal=60.0,
                                              t_s=mat.t_s, channels=mat.channels, scan_id="bench"))
        # where process_arrays spends its time (the public steps it calls, each on its own)
        clean, _ = remove_spikes(mat.values_mm)
        u = np.arange(clean.shape[0]) / res.period.samples_per_rev
        steps = {
            "remove_spikes": _best(lambda: remove_spikes(mat.values_mm)),
            "period_from_readings": _best(lambda: period_from_readings(clean, samples_per_rev_guess=float(SPR))),
            "find_extrema": _best(lambda: find_extrema(clean, u, samples_per_rev=res.period.samples_per_rev,
                                                       channels=mat.channels)),
        }
    out = {"rows": rows, "read_s": t_read, "stage_s": t_stage, "matrix_s": t_matrix, "process_s": t_proc,
           "read_rows_per_s": rows / t_read, "stage_rows_per_s": rows / t_stage, "ratio": t_read / t_stage,
           "ratio_process_only": t_read / t_proc,
           "samples_per_rev": res.period.samples_per_rev, "extrema": res.extrema.height,
           **{f"{k}_s": t for k, t in steps.items()}}
    print(f"signal stage: {rows} readings ({N_REV} rev x {SPR} x 3 channels), best of 5")
    print(f"  plain read_parquet          : {t_read * 1e3:8.1f} ms  {rows / t_read / 1e6:7.2f} M readings/s")
    print(f"  read + lds_matrix + process : {t_stage * 1e3:8.1f} ms  "
          f"{rows / t_stage / 1e6:7.2f} M readings/s")
    print(f"    of which rawio.lds_matrix : {t_matrix * 1e3:8.1f} ms")
    print(f"    of which process_arrays   : {t_proc * 1e3:8.1f} ms  {rows / t_proc / 1e6:7.2f} M readings/s")
    for name, t in steps.items():
        print(f"      {name:24s}: {t * 1e3:8.1f} ms")
    print(f"  ratio stage / read          : {out['ratio']:.3f}  (target >= 0.5)")
    print(f"  ratio process_arrays / read : {out['ratio_process_only']:.3f}")
    print(f"  period {res.period.samples_per_rev:.5f} +- {res.period.u_samples_per_rev:.1e} samples/rev "
          f"(truth {SPR / 1.002:.4f}), {res.extrema.height} extrema")
    tab = filter_performance(revolutions=8, samples_per_rev=SPR, noise_mm=0.0025, seed=0)
    print("  filters, simulated 60 rpm / 660 samples/rev, 2.5 um noise (Yang §4: 15 um beat -> 3 um),")
    print("  channel 1 (2.3 mm eccentricity): lag/amplitude of the 1-UPR term, shift of the minimum")
    print(f"  {'filter':28s} {'beat um':>8s} {'rms um':>7s} {'lag rad':>9s} {'lag smp':>8s}"
          f" {'amp loss um':>11s} {'min shift smp':>13s}")
    for r in tab.iter_rows(named=True):
        print(f"  {r['filter']:28s} {r['beat_um']:8.2f} {r['scatter_um']:7.2f} {r['lag_rad']:9.5f}"
              f" {r['lag_samples']:8.3f} {r['amplitude_loss_um']:11.3f} {r['min_shift_samples']:13.3f}")
    out["filters"] = tab
    return out


if __name__ == "__main__":
    main()
