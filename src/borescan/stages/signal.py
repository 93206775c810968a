"""Stage ``signal_night``: revolutions, extrema and summaries of a night.

Stage ``signal_night``: revolutions, sub-sample extrema and per-channel summaries of a night's spindle
scans.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from borescan import rawio, readings, signal
from borescan.parallel import map_timed, workers_for
from borescan.preconditions import summary_revolutions
from borescan.stages._common import Quarantined, frames_or_empty, night_scans, quarantine
from borescan.workflow_log import compute_line

__all__ = ["signal_options", "stage_signal", "signal_one", "scan_summary"]


def signal_options(cfg: dict) -> dict:
    """Return the config's ``signal`` section as processing keywords.

    Return the config's ``signal`` section (schema defaults filled) as :func:`borescan.signal.process_scan`
    keywords.
    """
    method = cfg["filter"]
    params: dict = {}
    if method in ("median", "moving_average"):
        params["window_samples"] = int(cfg["window_samples"])
    elif method == "gaussian":
        params["cutoff_upr"] = float(cfg["gaussian_cutoff_upr"])
    spikes = readings.cleaning_policy(cfg)  # the one spike policy of every stage that fits readings
    return {
        "filter": method,
        "filter_params": params,
        "spike_threshold": spikes.spike_threshold_mad,
        "spike_window_samples": spikes.spike_window_samples,
        "extrema_on": cfg["extrema_on"],
    }


def stage_signal(
    raw_root, night: str, results_root, scans_table, cfg: dict, log=print, workers: int = 1
) -> tuple[pl.DataFrame, pl.DataFrame, list[Quarantined]]:
    """Revolutions, sub-sample extrema and per-channel summaries of every spindle scan of a night.

    Returns (extrema, summary, quarantined). The summary has one row per scan and channel with
    mean d_min/d_max and their uncertainties, n/m counts, advanced/backward status and the
    rotation period (``period_*`` columns, including whether it disagrees with the nominal).
    A scan whose clock jumps (:func:`borescan.rawio.clock_jump`) is quarantined. Scans are
    spread over ``workers`` processes.
    """
    opts = signal_options(cfg)
    jobs = [
        (raw_root, night, results_root, d, opts)
        for _, d in night_scans(results_root, night, scans_table, device_type="tri_lds")
    ]
    log(f"{len(jobs)} three-sensor scans on {workers_for(len(jobs), workers)} process(es)")
    extrema, summaries, bad = [], [], []
    for ((ext, summ, q, msg), cpu_s), job in zip(map_timed(signal_one, jobs, workers), jobs):
        log(compute_line(Path(job[3]).name.removeprefix("scan="), cpu_s))
        bad += q
        if ext is not None:
            extrema.append(ext)
            summaries.append(summ)
        if msg:
            log(msg)
    return frames_or_empty(extrema), frames_or_empty(summaries), bad


def signal_one(job) -> tuple[pl.DataFrame | None, pl.DataFrame | None, list[Quarantined], str | None]:
    """Run the signal stage of one scan.

    Signal stage of one scan ``(raw_root, night, results_root, stored scan folder, options)``:
    (extrema, summary, quarantined, log line); None frames when skipped (static scans).
    """
    raw_root, night, results_root, d, opts = job
    bad: list[Quarantined] = []
    scan = rawio.load_stored_scan(d)
    if scan.spindle is None:
        return None, None, bad, None  # static readings: no revolutions
    mat = rawio.lds_matrix(scan)
    jump = rawio.clock_jump(np.asarray(mat.sample), np.asarray(mat.t_s), scan.scan_meta.sample_rate_hz)
    if jump:
        quarantine(results_root, bad, scan.scan_id, night, "signal", "lds.parquet", jump)
        return None, None, bad, None
    try:
        extrema, summary, res = scan_summary(scan, mat, opts)
    except (ValueError, np.linalg.LinAlgError, IndexError) as err:
        quarantine(
            results_root, bad, scan.scan_id, night, "signal", "lds.parquet", f"signal stage failed: {err}"
        )
        return None, None, bad, None
    recorded, with_extrema = summary_revolutions(summary)
    msg = (
        f"{scan.scan_id}: {recorded} whole revolutions recorded, {with_extrema} with every channel's "
        f"extremum, {res.period.samples_per_rev:.3f} samples/rev ({res.period.source})"
    )
    return extrema, summary, bad, msg


def scan_summary(
    scan: rawio.RawScan, mat, opts: dict
) -> tuple[pl.DataFrame, pl.DataFrame, signal.SignalResult]:
    """Run the signal stage on one spindle scan (extrema, summary rows per channel, the result).

    ``mat`` is its :func:`borescan.rawio.lds_matrix`, ``opts`` :func:`signal_options`. Return (extrema,
    summary rows per channel, the result); the summary also has ``n_samples_recorded`` and the ``period_*``
    columns. Raises ValueError, LinAlgError or IndexError when the readings give no period or extrema.
    """
    res = signal.process_scan(scan, mat, **opts)
    frames = res.to_frames()
    period = {(k if k.startswith("period_") else f"period_{k}"): v for k, v in res.period.to_dict().items()}
    feats = signal.feature_points(frames["extrema"], res.period.samples_per_rev).select(
        "channel", "feature_sample", "u_feature_sample"
    )
    summary = (
        frames["summary"]
        .join(feats, on="channel", how="left")
        .with_columns(
            n_samples_recorded=pl.lit(mat.values_mm.shape[0]), **{k: pl.lit(v) for k, v in period.items()}
        )
    )
    return frames["extrema"], summary, res
