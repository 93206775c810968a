"""Evidence of the output-stage effects: outliers (isolated jumps) and quantization (a lattice).

Both are named by their own tests, not by a fitted term (the registry's ``candidate`` ``"evidence"``):
outliers are jumps beyond a Bonferroni threshold of the running-median residual, quantization is every
reading on one lattice. :func:`output_stage_evidence` runs both on a base fit and sets the model's weights,
mask and dead zone for the rest of the examination.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from borescan.discrepancy.fitting import FitResult

__all__ = [
    "LATTICE_TOL",
    "outlier_threshold_sigma",
    "lattice_lsb",
    "quantization_evidence",
    "output_stage_evidence",
]

LATTICE_TOL = 1e-5  # readings within this many lsb of the lattice count as on it


def outlier_threshold_sigma(n: int, false_rate: float = 1e-3) -> float:
    """Return the outlier threshold in noise levels for ``n`` samples.

    Outlier threshold in noise levels for ``n`` samples of a channel: the two-sided Gaussian
    quantile that ``n`` independent residuals pass with probability ``false_rate`` in all
    (Bonferroni), at least 4. About 5.2 for 6000 samples, 4.9 for 1000 (a fixed 7 missed
    outliers of 5-6 noise levels, which a channel of 1000 readings shows plainly).
    """
    from scipy.special import (
        ndtri,
    )  # the normal quantile (scipy.stats would add ~0.6 s of imports per worker)

    return max(4.0, float(-ndtri(false_rate / (2.0 * max(n, 1)))))


def lattice_lsb(v: np.ndarray) -> float | None:
    """Return the step of a lattice that every reading lies on (quantised sensor), else None."""
    v = v[np.isfinite(v)]
    if v.size < 20:
        return None
    u = np.unique(v)
    if u.size < 3 or u.size > 0.8 * v.size:
        return None
    dif = np.diff(u)
    step = float(dif.min())
    if step <= 0:
        return None
    span = float(u[-1] - u[0])
    step = span / round(span / step)  # refine over the whole span
    q = v / step
    if np.max(np.abs(q - np.round(q))) > LATTICE_TOL:
        return None
    return step


def quantization_evidence(r_mm: np.ndarray, lsb_mm: float, v_mm: np.ndarray) -> tuple[float, float]:
    """Delta BIC of quantised readings (Gaussian noise, then rounding to ``lsb``) vs plain Gaussian.

    The plain model gives a reading on the lattice the probability p(v) lsb (its density over one
    lattice cell, variance fitted); the quantised model the Gaussian mass of the cell around v
    (noise sigma fitted). One extra parameter (lsb).

    Returns
    -------
    delta_bic, fitted noise sigma before quantisation [mm]
    """
    from scipy.optimize import minimize_scalar
    from scipy.special import ndtr

    r = r_mm[np.isfinite(r_mm)]
    n = r.size
    mu = v_mm[np.isfinite(r_mm)] - r  # model prediction
    s_c = float(np.sqrt(np.mean(r**2)))
    ll_c = float(np.sum(-0.5 * (r / s_c) ** 2 - np.log(np.sqrt(2 * np.pi) * s_c) + np.log(lsb_mm)))
    v = mu + r

    def nll(log_s: float) -> float:
        s = math.exp(log_s)
        hi = (v + lsb_mm / 2 - mu) / s
        lo = (v - lsb_mm / 2 - mu) / s
        # mass of the cell, from the tail nearer to it (no cancellation)
        flip = lo > 0
        m = np.where(flip, ndtr(-lo) - ndtr(-hi), ndtr(hi) - ndtr(lo))
        return -float(np.sum(np.log(np.maximum(m, 1e-300))))

    bounds = (math.log(lsb_mm * 1e-3), math.log(max(s_c * 3, lsb_mm)))
    res = minimize_scalar(nll, bounds=bounds, method="bounded")
    ll_d = -float(res.fun)
    return float(2.0 * (ll_d - ll_c) - np.log(n)), float(math.exp(res.x))


@dataclass
class OutputStage:
    """What the output-stage tests leave for the rest of an examination.

    named : findings of ``outliers`` and ``quantization`` (the findings.json entries)
    sigma_mm : noise floor per channel (c,), a quantised channel's including its rounding noise
    base : the base fit after outliers were masked and the channels weighted
    all_valid : (n, c) every finite reading, outliers included (the gap before is taken over it)
    """

    named: list[dict] = field(default_factory=list)
    sigma_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    base: FitResult | None = None
    all_valid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))

    @property
    def sig_ref_mm(self) -> float:
        """The scan's noise floor: the root mean square of the channels' [mm]."""
        return float(np.sqrt(np.mean(self.sigma_mm**2))) or 1e-6


def _lattices(model) -> list[float | None]:
    """Return each channel's lattice step (:func:`lattice_lsb` of its valid readings), else None."""
    data = model.data
    return [lattice_lsb(data.values_mm[model.valid[:, j], j]) for j in range(len(data.channels))]


def _outliers(
    model, r0: np.ndarray, sigma: np.ndarray, false_rate: float, min_spikes: int, lsbs: list[float | None]
) -> list[dict]:
    """Find each channel's isolated jumps, mask them in ``model.mask``; their findings (evidence to come)."""
    data = model.data
    # A quantised channel's readings carry a rounding error of up to lsb / 2 (standard deviation
    # lsb / sqrt 12) that a noise floor from differences of lattice values underrates: the jump test
    # adds it, so the rounding's largest residuals are not taken for outliers (issue 35).
    sig_test = np.array(sigma, dtype=float)
    for j, lsb in enumerate(lsbs):
        if lsb is not None:
            sig_test[j] = math.hypot(sig_test[j], lsb / math.sqrt(12.0))
    spikes = model.spike_mask(
        r0, sig_test, k_sigma=outlier_threshold_sigma(int(model.valid.sum(axis=0).max()), false_rate)
    )
    out = []
    for j, ch in enumerate(data.channels):
        cnt = int(spikes[:, j].sum())
        if cnt < getattr(model, "min_spikes", min_spikes):  # a pose model's own test names one jump
            continue
        nval = int(model.valid[:, j].sum())
        rs = r0[spikes[:, j], j] - np.median(r0[model.valid[:, j], j])
        out.append(
            {
                "effect": "outliers",
                "channel": ch,
                "parameters": {"rate": cnt / nval, "size_mm": float(np.median(np.abs(rs)))},
                "uncertainties": {
                    "u_rate": math.sqrt(cnt) / nval,
                    "u_size_mm": float(np.std(np.abs(rs)) / math.sqrt(cnt)),
                },
                "_mask": spikes[:, j],
                "_j": j,
            }
        )
        model.mask[spikes[:, j], j] = False
    return out


def _quantization(model, r0: np.ndarray, lsbs: list[float | None]) -> list[dict]:
    """Return the findings of channels whose every reading lies on one lattice (``lsbs``: their steps)."""
    data = model.data
    out = []
    for j, (ch, lsb) in enumerate(zip(data.channels, lsbs, strict=True)):
        if lsb is None:
            continue
        ok = model.mask[:, j]
        dbic_ll, s_q = quantization_evidence(r0[ok, j], lsb, data.values_mm[ok, j])
        nq = int(np.isfinite(r0[ok, j]).sum())
        # A continuous reading lands within LATTICE_TOL lsb of the lattice with probability
        # 2 LATTICE_TOL; every one of the nq readings did: conclusive, whatever the lsb. The
        # finding says what the rounding adds to the noise (lsb / sqrt(12)); once the device's
        # model includes the quantisation it is no longer missing.
        dbic = float(2.0 * nq * math.log(1.0 / (2.0 * LATTICE_TOL)) - math.log(nq))
        out.append(
            {
                "effect": "quantization",
                "channel": ch,
                "parameters": {"lsb_mm": lsb},
                "uncertainties": {"u_lsb_mm": lsb * LATTICE_TOL},
                "evidence": {
                    "delta_bic": dbic,
                    "delta_bic_likelihood": dbic_ll,
                    "lattice": True,
                    "noise_before_quantization_mm": s_q,
                    "rounding_noise_mm": lsb / math.sqrt(12.0),
                },
                "_q": (j, lsb),
            }
        )
    return out


def output_stage_evidence(
    model,
    base: FitResult,
    refit: Callable[[dict[str, float]], FitResult | None],
    *,
    threshold: float,
    false_rate: float,
    min_spikes: int,
) -> OutputStage:
    """Name outliers and quantization on the base fit; weight, mask and dead-zone the model for the rest.

    ``refit(start)`` fits the base model again (after outliers are masked and channels weighted). Each
    finding's evidence is a Delta BIC: an outlier costs one parameter per jump; a lattice is conclusive.
    Findings at or below ``threshold`` are dropped. The weights equalise the channels' noise floors.
    """
    data = model.data
    r0 = model.residual_matrix(base.values(), [])
    sigma = model.noise_floor(r0)
    sig_ref = float(np.sqrt(np.mean(sigma**2))) or 1e-6
    all_valid = model.valid.copy()
    lsbs = _lattices(model)  # model.valid is fixed: the lattices hold for the outliers and the quantisation
    named = _outliers(model, r0, sigma, false_rate, min_spikes, lsbs)
    w = sig_ref / np.maximum(sigma, 1e-9 * sig_ref)
    model.weights = w
    base = refit(base.values()) or base
    r0 = model.residual_matrix(base.values(), [])
    n_res = int(model.mask.sum())
    for e in named:  # evidence: each jump is one extra parameter
        rw = r0 * w
        keep = model.mask.copy()
        keep[:, e["_j"]] |= e["_mask"]
        rss_with = float(np.sum(rw[keep] ** 2))
        rss_without = float(np.sum(rw[model.mask] ** 2))
        e["evidence"] = {
            "delta_bic": float(
                n_res * np.log(rss_with / max(rss_without, 1e-300)) - e["_mask"].sum() * np.log(n_res)
            )
        }
    named += _quantization(model, r0, lsbs)
    named = [e for e in named if e["evidence"]["delta_bic"] > threshold]
    half = np.zeros(len(data.channels))
    for e in named:  # a quantised sensor's floor includes the rounding noise lsb^2 / 12
        if "_q" in e:
            j, lsb = e["_q"]
            s_q = e["evidence"]["noise_before_quantization_mm"]
            sigma[j] = math.sqrt(s_q**2 + lsb**2 / 12.0)
            if lsb / math.sqrt(12.0) > s_q:
                # coarse cells: the rounding error follows the reading, not white noise; a model
                # value anywhere inside the cell fits (dead zone), so no effect is invented for it
                half[j] = 0.5 * lsb
    if half.any():
        sig_ref = float(np.sqrt(np.mean(sigma**2))) or 1e-6
        model.dead_zone_mm = half
        model.weights = sig_ref / np.maximum(sigma, 1e-9 * sig_ref)
        base = refit(base.values()) or base
    return OutputStage(
        named=[{k: v for k, v in e.items() if not k.startswith("_")} for e in named],
        sigma_mm=sigma,
        base=base,
        all_valid=all_valid,
    )
