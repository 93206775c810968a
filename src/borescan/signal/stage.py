"""The signal stage of one scan.

The signal stage of one scan: despike, period, revolutions, extrema, statuses and spacings
(:func:`process_arrays` on arrays, :func:`process_scan` on a raw scan).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import polars as pl

from borescan.signal._common import _as_2d
from borescan.signal.extrema import find_extrema
from borescan.signal.features import beam_status, feature_spacings, n_m_counts
from borescan.signal.filters import FILTERS, filter_readings
from borescan.signal.period import (
    PeriodEstimate,
    _nominal,
    find_revolutions,
    period_from_encoder,
    period_from_readings,
    revolution_coordinate,
)
from borescan.signal.spikes import (
    _SPIKE_CANDIDATE_THRESHOLD,
    _check_spike_window,
    _despike_rows,
    _padded_rows,
)


@dataclass
class SignalResult:
    """Everything the signal stage produces for one scan (see :func:`process_arrays`)."""

    scan_id: str
    channels: tuple[int, ...]
    sample: np.ndarray
    despiked_mm: np.ndarray
    period: PeriodEstimate
    revolutions: pl.DataFrame
    extrema: pl.DataFrame
    summary: pl.DataFrame
    spacings: pl.DataFrame
    set_aside: pl.DataFrame
    config: dict = field(default_factory=dict)

    @functools.cached_property
    def filtered_mm(self) -> np.ndarray:
        """The despiked readings through the configured filter (``config["filter"]``, zero-phase) [mm].

        Computed on first use: with ``extrema_on="despiked"`` (the default) nothing else needs it.
        """
        if self.config.get("filter", "none") == "none":
            return self.despiked_mm
        return filter_readings(
            self.despiked_mm,
            method=self.config["filter"],
            samples_per_rev=self.period.samples_per_rev,
            **self.config.get("filter_params", {}),
        )

    def to_frames(self) -> dict[str, pl.DataFrame]:
        """Tables for Parquet: revolutions, extrema, summary, spacings, period, set_aside (with scan_id)."""
        sid = pl.lit(self.scan_id).alias("scan_id")
        per = pl.DataFrame([self.period.to_dict()])
        out = {
            "revolutions": self.revolutions,
            "extrema": self.extrema,
            "summary": self.summary,
            "spacings": self.spacings,
            "period": per,
            "set_aside": self.set_aside,
        }
        return {k: (f if "scan_id" in f.columns else f.select(sid, pl.all())) for k, f in out.items()}


def _mean_u(a: np.ndarray) -> tuple[float, float]:
    """Mean and its standard uncertainty s / sqrt(k) (NaN where undefined)."""
    if a.size == 0:
        return float("nan"), float("nan")
    return float(a.mean()), (float(a.std(ddof=1) / math.sqrt(a.size)) if a.size > 1 else float("nan"))


def process_arrays(
    values_mm: np.ndarray,
    *,
    sample_rate_hz: float,
    rpm_nominal: float | None = None,
    direction: str = "ccw",
    scan_id: str = "",
    channels: tuple[int, ...] | None = None,
    sample0: int = 0,
    t_s: np.ndarray | None = None,
    encoder_t_s: np.ndarray | None = None,
    encoder_angle_rad: np.ndarray | None = None,
    commanded_rad: np.ndarray | None = None,
    filter: str = "none",
    filter_params: dict | None = None,
    spike_window_samples: int = 7,
    spike_threshold: float = 6.0,
    half_window_samples: int | None = None,
    extrema_on: str = "despiked",
    n_harmonics: int = 3,
) -> SignalResult:
    """Return the whole signal stage on plain arrays.

    nulls counted -> spikes set aside (:func:`remove_spikes`) -> period (encoder when given,
    else :func:`period_from_readings`) and revolution coordinate -> extrema
    (:func:`find_extrema`, on the despiked readings by default because filtering correlates the
    noise that the fit uncertainty assumes white; ``extrema_on="filtered"`` fits them on the
    readings through ``filter`` with ``filter_params``, zero-phase) -> n, m, status, spacings.
    With the default the filter is computed only when ``SignalResult.filtered_mm`` is read.

    Without an encoder angle, ``commanded_rad`` (the rpm profile's angle Phi at each sample,
    :mod:`borescan.kinematics`) gives the revolutions when the speed changes during the scan:
    u = (1 + eps) |Phi - Phi_0| / 2 pi with the speed scale found from the readings; the
    period is then the scan's mean samples per revolution (source ``"profile"``).

    The summary keeps the paper's rule for ``status`` (n < m -> backward) and adds
    ``n_minus_m_samples`` with its standard uncertainty and ``status_significant`` (|n - m| >= 3u):
    the geometric asymmetry is small (0.29 samples at 660 samples/rev for r = 5.5 mm).
    """
    v, _ = _as_2d(values_mm)
    n, c = v.shape
    chans = tuple(channels) if channels is not None else tuple(range(1, c + 1))
    h = _check_spike_window(spike_window_samples)
    if extrema_on not in ("despiked", "filtered"):
        raise ValueError(f"extrema_on must be 'despiked' or 'filtered', got {extrema_on!r}")
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; valid: {', '.join(FILTERS)}")
    vp = _padded_rows(v, h)  # own copy, one contiguous row per channel
    spike_idx, nulls = _despike_rows(vp, h, spike_threshold, _SPIKE_CANDIDATE_THRESHOLD)
    clean = vp[:, h : h + n].T
    if t_s is None:
        t_s = np.arange(n) / float(sample_rate_hz)
    period, u = _period_and_revolutions(
        clean,
        t_s,
        sample_rate_hz,
        rpm_nominal,
        direction,
        encoder_t_s,
        encoder_angle_rad,
        commanded_rad,
        n_harmonics,
    )
    spr = period.samples_per_rev
    filtered = None
    if extrema_on == "filtered":  # otherwise the filter runs only if SignalResult.filtered_mm is read
        filtered = (
            clean
            if filter == "none"
            else filter_readings(clean, method=filter, samples_per_rev=spr, **(filter_params or {}))
        )
    src = clean if filtered is None else filtered
    ext, info = find_extrema(
        src,
        u,
        half_window_samples=half_window_samples,
        samples_per_rev=spr,
        channels=chans,
        sample0=sample0,
        n_harmonics=n_harmonics,
    )
    summary, min_pos = _channel_summary(ext, info, chans, period, scan_id)
    ext = ext.select(pl.lit(scan_id).alias("scan_id"), pl.all())
    spac = feature_spacings(min_pos, spr, period.u_samples_per_rev)
    revs = find_revolutions(u, sample0)
    set_aside = pl.DataFrame(
        {
            "channel": list(chans),
            "nulls": nulls.astype(np.int64),
            "spikes": np.array([i.size for i in spike_idx], dtype=np.int64),
        }
    )
    cfg = {
        "filter": filter,
        "filter_params": filter_params or {},
        "spike_window_samples": spike_window_samples,
        "spike_threshold": spike_threshold,
        "half_window_samples": info["half_window_samples"],
        "extrema_on": extrema_on,
        "n_harmonics": n_harmonics,
    }
    res = SignalResult(
        scan_id,
        chans,
        np.arange(n, dtype=np.int64) + sample0,
        clean,
        period,
        revs,
        ext,
        summary,
        spac,
        set_aside,
        cfg,
    )
    if filtered is not None:
        res.__dict__["filtered_mm"] = filtered  # computed already (the cached property's slot)
    return res


def _period_and_revolutions(
    clean,
    t_s,
    sample_rate_hz,
    rpm_nominal,
    direction,
    encoder_t_s,
    encoder_angle_rad,
    commanded_rad,
    n_harmonics,
):
    """Return the rotation period and each sample's revolution coordinate (see :func:`process_arrays`).

    From the encoder when it has an angle, else from the rpm profile's commanded angle when the speed
    changes during the scan, else from the readings.
    """
    n = clean.shape[0]
    nom = _nominal(sample_rate_hz, rpm_nominal)
    enc = None if encoder_angle_rad is None else np.asarray(encoder_angle_rad, dtype=float)
    if enc is not None and np.any(~np.isnan(enc)):
        period = period_from_encoder(
            encoder_t_s, enc, t_s, rpm_nominal=rpm_nominal, sample_rate_hz=sample_rate_hz
        )
        return period, revolution_coordinate(
            n, period, sample_times_s=t_s, encoder_t_s=encoder_t_s, encoder_angle_rad=enc
        )
    if commanded_rad is not None and _speed_changes(commanded_rad):
        return _profile_revolutions(np.asarray(commanded_rad, dtype=float), clean, nom, direction)
    period = period_from_readings(
        clean,
        samples_per_rev_guess=nom,
        rpm_nominal=rpm_nominal,
        sample_rate_hz=sample_rate_hz,
        direction=direction,
        n_harmonics=n_harmonics,
    )
    return period, revolution_coordinate(n, period)


def _channel_summary(ext: pl.DataFrame, info: dict, chans, period, scan_id: str) -> tuple[pl.DataFrame, dict]:
    """Return the per-channel summary rows of the extrema and each channel's minima positions.

    Mean d_min/d_max with their uncertainties, n/m counts, status and its significance (see
    :func:`process_arrays`).
    """
    e_ch = ext["channel"].to_numpy()
    e_min = (ext["kind"] == "min").to_numpy()
    e_pos = ext["sample_pos"].to_numpy()
    e_val = ext["value_mm"].to_numpy()
    srows = []
    min_pos = {}
    for ch in chans:
        in_ch = e_ch == ch
        mn, mx = in_ch & e_min, in_ch & ~e_min
        min_pos[ch] = e_pos[mn]
        nn, mm = n_m_counts(e_pos[mn], e_pos[mx])
        dmin, u_dmin = _mean_u(e_val[mn])
        dmax, u_dmax = _mean_u(e_val[mx])
        n_mean, u_n = _mean_u(nn)
        m_mean, u_m = _mean_u(mm)
        if nn.size and mm.size:
            st = beam_status(n_mean, m_mean, period.direction)
        else:
            st = {"status": "undetermined", "rho_sign": 0}
        # n_i - m_i = 2 max_i - min_i - min_{i+1}: neighbours share a minimum (lag-1 correlation 1/6),
        # so the uncertainty of the mean is sqrt(8/6) x s / sqrt(k)
        k = min(nn.size, mm.size)
        nm, u_nm = _mean_u(nn[:k] - mm[:k])
        u_nm *= math.sqrt(8.0 / 6.0)
        srows.append(
            {
                "channel": ch,
                "d_min_mm": dmin,
                "u_d_min_mm": u_dmin,
                "d_max_mm": dmax,
                "u_d_max_mm": u_dmax,
                "n_revolutions_min": int(mn.sum()),
                "n_revolutions_max": int(mx.sum()),
                "n_samples": n_mean,
                "u_n_samples": u_n,
                "m_samples": m_mean,
                "u_m_samples": u_m,
                "n_minus_m_samples": nm,
                "u_n_minus_m_samples": u_nm,
                "status": st["status"],
                "status_significant": bool(abs(nm) >= 3 * u_nm) if k > 1 else False,
                "rho_sign": st["rho_sign"],
                "sigma_fit_mm": info["sigma_mm"].get(ch),
                "extrema_dropped": info["dropped"].get(ch, 0),
            }
        )
    columns = {k: [r[k] for r in srows] for k in (srows[0] if srows else {})}  # by column: faster than rows
    summary = pl.DataFrame({"scan_id": [scan_id] * len(srows)} | columns)
    return summary, min_pos


def _speed_changes(commanded_rad: np.ndarray) -> bool:
    """Return True when the commanded angle is not a straight line in the sample index (a speed change)."""
    x = np.asarray(commanded_rad, dtype=float)
    if x.size < 3:
        return False
    line = x[0] + (x[-1] - x[0]) * np.arange(x.size) / (x.size - 1)
    return bool(np.max(np.abs(x - line)) > 1e-3 * max(abs(x[-1] - x[0]), 1e-12))


def _profile_revolutions(Phi: np.ndarray, clean: np.ndarray, nominal: float | None, direction: str):
    """Revolution coordinate from the rpm profile's angle with the speed scale from the readings."""
    from borescan.kinematics import estimate_speed_scale

    scale = estimate_speed_scale(Phi, clean)
    turned = np.abs(scale * (Phi - Phi[0])) / (2.0 * math.pi)
    n = Phi.size
    spr = (n - 1) / turned[-1] if turned[-1] > 0 else float("nan")
    # the refined scale leaves < ~0.05 rad at the end of the scan: relative u(P) ~ 0.05 / span
    u_spr = spr * 0.05 / max(2.0 * math.pi * turned[-1], 1e-12)
    period = PeriodEstimate(spr, u_spr, "profile", nominal, False, direction)
    return period, turned


def process_scan(scan: Any, matrix: Any = None, **cfg: Any) -> SignalResult:
    """Signal stage of one ``borescan.rawio.RawScan`` (keyword ``cfg`` as :func:`process_arrays`).

    Uses ``rawio.lds_matrix(scan)`` (or ``matrix``, when the caller has built it already);
    missing ticks in ``sample`` become NaN rows (counted as nulls). The encoder angle is used
    when the spindle stream has a non-null ``angle_rad``; otherwise the period comes from the
    readings. ``scan.json`` gives ``sample_rate_hz`` and ``spindle.rpm_nominal``/``direction``.
    """
    from borescan import rawio

    mat = rawio.lds_matrix(scan) if matrix is None else matrix
    sample = np.asarray(mat.sample, dtype=np.int64)
    vals = np.asarray(mat.values_mm, dtype=float)
    t_s = np.asarray(mat.t_s, dtype=float)
    full = np.arange(sample[0], sample[-1] + 1)
    if full.size != sample.size:
        v2 = np.full((full.size, vals.shape[1]), np.nan)
        v2[sample - sample[0]] = vals
        vals = v2
        t_s = np.interp(full, sample, t_s)
    sm = scan.scan_meta  # typed scan.json fields (rawio.ScanMeta)
    enc_t = enc_a = commanded = None
    if scan.spindle is not None and "angle_rad" in scan.spindle.columns:
        a = scan.spindle["angle_rad"].cast(pl.Float64).to_numpy()
        if np.any(~np.isnan(a)):
            enc_t = scan.spindle["t_ns"].to_numpy().astype(float) * 1e-9
            enc_a = a
    if enc_a is None and scan.spindle is not None and scan.spindle.height > 1:
        from borescan.kinematics import angle_model_of_scan

        am = angle_model_of_scan(scan.meta, scan.spindle)
        commanded = am.commanded_rad(t_s)
    kw = dict(
        sample_rate_hz=sm.sample_rate_hz,
        rpm_nominal=sm.rpm_nominal,
        direction=sm.direction or "ccw",
        scan_id=scan.scan_id,
        channels=tuple(mat.channels),
        sample0=int(full[0]),
        t_s=t_s,
        encoder_t_s=enc_t,
        encoder_angle_rad=enc_a,
        commanded_rad=commanded,
    )
    kw.update(cfg)
    return process_arrays(vals, **kw)
