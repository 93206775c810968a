"""Examine one scan: base fit, localisation, candidate effects, BIC selection, findings.

Selection rule (stated, not tuned): a candidate (one named effect, or a pair when no single
one is enough) is accepted when its BIC is lower than the base model's by more than
``threshold`` (default 10, "very strong" on the Kass-Raftery scale). Every candidate of the
same size within ``threshold`` of the best is listed: one -> "missing_effect", several ->
"ambiguous". A pair is preferred to the best single only when it beats it by more than
``threshold``. Nothing passing -> "no_missing_effect".
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from borescan.atomic import atomic_write_text
from borescan.config import schema_defaults
from borescan.discrepancy.fitting import FitResult, fit_least_squares, residual_sparsity
from borescan.discrepancy.poses import RodModel, StaticModel, pose_data_from_arrays
from borescan.discrepancy.tri import Term, TriData, TriModel, tri_data_from_arrays
from borescan.effects import EFFECTS

__all__ = [
    "Examination",
    "discrepancy_settings",
    "examine_scan",
    "examine_tri",
    "analyse_scan",
    "against_reference",
    "write_findings",
    "scan_arrays",
]

#: config key (``discrepancy:`` section of the schema) -> keyword of :func:`examine_model`
SETTINGS = {
    "delta_bic_threshold": "threshold",
    "max_harmonic": "k_max",
    "exact_refits": "n_exact",
    "pair_seeds": "n_pair_seeds",
    "pair_extensions": "n_pair_ext",
    "screen_gate": "screen_gate",
    "outlier_false_rate": "spike_false_rate",
    "min_outliers": "min_spikes",
    "max_samples": "max_samples",
}


def discrepancy_settings(section: dict | None = None) -> dict[str, Any]:
    """Return the keywords of :func:`examine_scan` from the config.

    Keywords of :func:`examine_scan` from the config's ``discrepancy`` section; the defaults
    (and any key the section leaves out) come from the schema, the one place defaults live.
    """
    merged = {**schema_defaults()["discrepancy"], **(section or {})}
    return {kw: merged[key] for key, kw in SETTINGS.items()}


DEFAULTS: dict[str, Any] = {
    **discrepancy_settings(),
    "free_beams": (),  # spindle scans: free "d_b" and/or "beta" (then offsets / delays are absorbed)
    "beams": None,  # Beams (or nominal-format list) replacing device.nominal beams, e.g. a calibration
    "layers": None,  # rod: nominal-format layer list replacing device.nominal layers
}


@dataclass
class Examination:
    """Everything one examination produced: the findings dict and arrays for plots."""

    findings: dict
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    channels: tuple[int, ...] = ()
    residual_before_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    residual_after_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    rev_hz: float = 1.0
    angle_label: str = "device angle [deg]"


# ---------------------------------------------------------------------------- raw scan access


def scan_arrays(scan) -> tuple[np.ndarray, tuple[int, ...], np.ndarray, np.ndarray | None, dict | None]:
    """Return reading matrix of a ``RawScan``-like object (``.meta``, ``.lds`` polars, ``.spindle``).

    Returns
    -------
    t_s (n,), channels, values_mm (n, c) with NaN for null, pose (n,) or None, spindle dict or None
    """
    import polars as pl

    lds = scan.lds
    channels = tuple(sorted(int(c) for c in lds["sensor"].unique().to_list()))
    samples = lds.select(pl.col("sample"), pl.col("t_ns")).unique(subset="sample").sort("sample")
    sample = samples["sample"].to_numpy()
    t_s = samples["t_ns"].to_numpy().astype(float) * 1e-9
    pos = np.searchsorted(sample, lds["sample"].to_numpy())
    col = np.searchsorted(np.array(channels), lds["sensor"].to_numpy().astype(int))
    vals = np.full((sample.size, len(channels)), np.nan)
    v = lds["value_mm"].cast(pl.Float64).fill_null(np.nan).to_numpy()
    vals[pos, col] = v
    pose = None
    if "pose" in lds.columns and lds["pose"].null_count() < lds.height:
        pose = np.full(sample.size, -1, dtype=np.int64)
        pose[pos] = lds["pose"].fill_null(-1).to_numpy()
    spindle = None
    sp = getattr(scan, "spindle", None)
    if sp is not None and sp.height:
        spindle = {
            "t_s": sp["t_ns"].to_numpy().astype(float) * 1e-9,
            "x_mm": sp["x_mm"].to_numpy().astype(float),
            "y_mm": sp["y_mm"].to_numpy().astype(float),
            "angle_rad": sp["angle_rad"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            if "angle_rad" in sp.columns
            else None,
            "rpm": sp["rpm"].cast(pl.Float64).fill_null(np.nan).to_numpy() if "rpm" in sp.columns else None,
        }
    return t_s, channels, vals, pose, spindle


def against_reference(meta: dict, beams=None, layers=None) -> dict:
    """Return ``scan.json`` with its ``device.nominal`` replaced by a calibrated device's geometry.

    The calibrated device's ``beams`` (a :class:`~borescan.geometry.Beams` or the nominal-format list) or rod
    ``layers``: the geometry an examination starts from (``meta`` itself when neither is given).
    """
    if beams is None and layers is None:
        return meta
    meta = copy.deepcopy(meta)
    nominal = meta["device"].get("nominal") or {}
    meta["device"]["nominal"] = nominal
    if beams is not None:
        nominal["beams"] = beams.to_nominal() if hasattr(beams, "to_nominal") else [dict(x) for x in beams]
    if layers is not None:
        nominal["layers"] = [dict(x) for x in layers]
    return meta


def analyse_scan(scan, **cfg) -> Examination:
    """Examine a ``RawScan`` (any ``borescan-raw/1`` scan): see :func:`examine_scan`."""
    meta = against_reference(scan.meta, cfg.get("beams"), cfg.get("layers"))  # a calibrated device, if given
    dtype = meta["device"]["type"]
    t_s, channels, vals, pose, spindle = scan_arrays(scan)
    if dtype == "tri_lds" and pose is None:
        data = tri_data_from_arrays(
            meta["scan_id"],
            meta,
            t_s,
            vals,
            channels,
            spindle,
            max_samples=int(cfg.get("max_samples", DEFAULTS["max_samples"])),
        )
        return examine_tri(data, **cfg)
    if pose is None:
        raise ValueError(f"{meta['scan_id']}: lds.parquet: a {dtype} scan needs the pose column")
    pdata = pose_data_from_arrays(meta["scan_id"], meta, t_s, vals, channels, pose)
    if dtype == "rod":
        return examine_model(RodModel(pdata), **cfg)
    if dtype == "tri_lds":
        return examine_model(StaticModel(pdata), **cfg)
    raise ValueError(f"{meta['scan_id']}: scan.json: unknown device type {dtype!r}")


def examine_scan(scan, **cfg) -> dict:
    """Find where model and data disagree, name the missing effect and show the gap shrink.

    Parameters
    ----------
    scan : rawio.RawScan (or any object with ``.meta``, ``.lds``, ``.spindle``)
    **cfg : overrides of :data:`DEFAULTS` (``threshold`` in BIC units, ``free_beams``,
        ``max_samples``, ...), and ``beams`` (a :class:`~borescan.geometry.Beams` or the
        ``device.nominal.beams`` list) / ``layers`` (rod) to examine the scan against a
        calibrated device instead of ``device.nominal``; ``device_effects`` (spindle scans):
        the effects of the device model its calibration carried, fitted with the base from their
        carried values and never named as missing.

    Returns
    -------
    dict in the ``findings.json`` format of ``outputs.md`` (plus ``localisation``,
    ``candidates`` and uncertainties).
    """
    return analyse_scan(scan, **cfg).findings


# ---------------------------------------------------------------------------- tri spindle


def _jacobian_columns(
    model, p: dict, terms: list[Term], names: list[str], scales: list[float], f0: np.ndarray | None = None
) -> np.ndarray:
    """Forward-difference columns of the weighted model over the unmasked samples, per unit scale.

    ``f0``: the residual at ``p`` when the caller has it (a candidate term at zero adds nothing:
    its residual is the one without it, bit for bit), else it is evaluated here.
    """
    if f0 is None:
        f0 = model.residual(p, terms)
    cols = []
    for n, s in zip(names, scales):
        q = dict(p)
        q[n] = q[n] + s
        cols.append(f0 - model.residual(q, terms))  # d(model)/d(param) * scale
    return np.stack(cols, axis=1) if cols else np.zeros((f0.size, 0))


def _lstsq(J: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """Return the linearised least-squares step of the screen, or None.

    Linearised least squares of the screen; None when the Jacobian or the residual is not
    finite (a finite-difference step left the model undefined) or the solver fails.
    """
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return None
    try:
        return np.linalg.lstsq(J, r, rcond=None)[0]
    except np.linalg.LinAlgError:
        return None


def _rms(r: np.ndarray, mask: np.ndarray) -> float:
    x = r[mask & np.isfinite(r)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


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


def _lattice_lsb(v: np.ndarray) -> float | None:
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


def _quantization_evidence(r_mm: np.ndarray, lsb_mm: float, v_mm: np.ndarray) -> tuple[float, float]:
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


def examine_tri(data: TriData, **cfg) -> Examination:
    """Examine a three-sensor spindle scan given as :class:`TriData` (see :func:`examine_scan`)."""
    return examine_model(
        TriModel(
            data,
            free_beams=tuple(cfg.get("free_beams", ())),
            device_effects=tuple(cfg.get("device_effects", ())),
        ),
        **cfg,
    )


def examine_model(  # noqa: C901 (the screen/refit/criterion engine, to be split into small functions)
    model, **cfg
) -> Examination:
    """Run the examination workflow on any model object (:class:`TriModel`, rod and static models).

    The model provides the data, the base parameters and their start, the forward model with
    terms, the candidate terms, the noise floor and the localisation (see ``TriModel``).
    """
    c = {**DEFAULTS, **cfg}
    T = float(c["threshold"])
    data = model.data
    base_names = model.base_names()
    base_scales = model.base_scales()
    start0 = model.base_start()
    x0 = [start0.get(n, 0.0) for n in base_names]

    fallback: dict[str, float] = {}

    def fit(terms: list[Term], start: dict[str, float]) -> FitResult | None:
        """Fit base + terms from ``start``; None when the model cannot be fitted.

        Fit base + terms from ``start``; if the model is undefined there (a ray missing the
        bore), from the base fit with zero effects; None when that fails too.
        """
        names = base_names + [n for t in terms for n in t.names()]
        scales = base_scales + [s for t in terms for s in t.scales()]
        for st in (start, {**fallback, **{k: v for k, v in start.items() if k.endswith("f_hz")}}):
            xs = [st.get(n, 0.0) for n in names]
            try:
                fr = fit_least_squares(
                    lambda p: model.residual(p, terms),
                    names,
                    xs,
                    scales,
                    sparsity=residual_sparsity(
                        names, model.mask, data.channels, getattr(data, "pose_index", None)
                    ),
                )
            except ValueError:
                continue
            if np.isfinite(fr.rss):
                return fr
        return None

    base = fit([], dict(zip(base_names, x0)))
    if base is None:
        raise ValueError(f"{data.scan_id}: the base model does not reach the data (beams miss the bore)")
    fallback.update(base.values())
    r0 = model.residual_matrix(base.values(), [])
    sigma = model.noise_floor(r0)
    sig_ref = float(np.sqrt(np.mean(sigma**2))) or 1e-6
    named_extra: list[dict] = []
    # --- outliers: isolated jumps (running-median residual), per channel
    spikes = model.spike_mask(
        r0,
        sigma,
        k_sigma=outlier_threshold_sigma(int(model.valid.sum(axis=0).max()), float(c["spike_false_rate"])),
    )
    all_valid = model.valid.copy()
    for j, ch in enumerate(data.channels):
        cnt = int(spikes[:, j].sum())
        if cnt >= c["min_spikes"]:
            nval = int(all_valid[:, j].sum())
            rs = r0[spikes[:, j], j] - np.median(r0[all_valid[:, j], j])
            named_extra.append(
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
    # weights: equalise channel noise levels
    w = sig_ref / np.maximum(sigma, 1e-9 * sig_ref)
    model.weights = w
    base = fit([], base.values()) or base
    fallback.update(base.values())
    r0 = model.residual_matrix(base.values(), [])
    n_res = int(model.mask.sum())
    for e in named_extra:  # evidence: each jump is one extra parameter
        j = e["_j"]
        rw = r0 * w
        keep = model.mask.copy()
        keep[:, j] |= e["_mask"]
        rss_with = float(np.sum(rw[keep] ** 2))
        rss_without = float(np.sum(rw[model.mask] ** 2))
        e["evidence"] = {
            "delta_bic": float(
                n_res * np.log(rss_with / max(rss_without, 1e-300)) - e["_mask"].sum() * np.log(n_res)
            )
        }
    # --- quantisation: readings on a lattice
    for j, ch in enumerate(data.channels):
        lsb = _lattice_lsb(data.values_mm[model.valid[:, j], j])
        if lsb is None:
            continue
        ok = model.mask[:, j]
        dbic_ll, s_q = _quantization_evidence(r0[ok, j], lsb, data.values_mm[ok, j])
        nq = int(np.isfinite(r0[ok, j]).sum())
        # A continuous reading lands within LATTICE_TOL lsb of the lattice with probability
        # 2 LATTICE_TOL; every one of the nq readings did: conclusive, whatever the lsb. The
        # finding says what the rounding adds to the noise (lsb / sqrt(12)); once the device's
        # model includes the quantisation it is no longer missing.
        dbic = float(2.0 * nq * math.log(1.0 / (2.0 * LATTICE_TOL)) - math.log(nq))
        named_extra.append(
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
    named_extra = [e for e in named_extra if e["evidence"]["delta_bic"] > T]
    half = np.zeros(len(data.channels))
    for e in named_extra:  # a quantised sensor's floor includes the rounding noise lsb^2 / 12
        if "_q" in e:
            j, lsb = e["_q"]
            s_q = e["evidence"]["noise_before_quantization_mm"]
            sigma[j] = math.sqrt(s_q**2 + lsb**2 / 12.0)
            if lsb / math.sqrt(12.0) > s_q:
                # coarse cells: the rounding error follows the reading, not white noise; a model
                # value anywhere inside the cell fits (dead zone), so no effect is invented for it
                half[j] = 0.5 * lsb
    sig_ref = float(np.sqrt(np.mean(sigma**2))) or 1e-6
    if half.any():
        model.dead_zone_mm = half
        model.weights = sig_ref / np.maximum(sigma, 1e-9 * sig_ref)
        base = fit([], base.values()) or base
        fallback.update(base.values())
        r0 = model.residual_matrix(base.values(), [])

    # --- localisation of the gap
    loc = model.localise(r0, sigma)
    f_vib = model.vibration_f(np.where(model.mask, r0, np.nan))
    terms = model.candidate_terms(k_max=int(c["k_max"]), vibration_f_hz=f_vib)

    # --- linear screen of every candidate
    p0 = base.values()
    vib_start = {"vibration.f_hz": f_vib} if f_vib is not None else {}
    rvec = model.residual(p0, [])
    Jb = _jacobian_columns(model, p0, [], base_names, base_scales, f0=rvec)
    screen = []
    for t in terms:
        if t.channel == 0 and len(model.data.channels) == 1:  # a common term is the channel's own
            continue
        pt = {**p0, **{n: 0.0 for n in t.names()}, **vib_start}
        tn = [n for n in t.names() if not n.endswith("f_hz")]
        ts = [s for n, s in zip(t.names(), t.scales()) if not n.endswith("f_hz")]
        Jt = _jacobian_columns(model, pt, [t], tn, ts, f0=rvec)
        J = np.hstack([Jb, Jt])
        coef = _lstsq(J, rvec)
        if coef is None:  # the term's start leaves the model undefined (a ray missing the bore)
            continue
        rss = float(np.sum((rvec - J @ coef) ** 2))
        start = dict(pt)
        for n, s, a in zip(base_names + tn, base_scales + ts, coef):
            start[n] = start[n] + a * s
        screen.append((rss, t, start))
    screen.sort(key=lambda z: z[0])
    # --- gate: a scan whose base residual is at the noise floor and whose best linearised
    # candidate is far below the threshold skips the exact refits (they cannot pass: for the small
    # effects such a screen allows, the linearisation is accurate, and a pair gains about the sum
    # of its singles). The nonlinear starts (axis tilt, large speed error) show as a gap above the floor.
    rss_base = float(np.sum(rvec**2))
    n_scr = max(int(rvec.size), 2)

    def lin_dbic(rss: float, t: Term) -> float:
        k = len([n for n in t.names() if not n.endswith("f_hz")])
        return float(n_scr * math.log(rss_base / max(rss, 1e-300)) - k * math.log(n_scr))

    screen_dbic = [lin_dbic(rss, t) for rss, t, _ in screen]
    gap0 = _rms(r0, model.mask)
    gated = bool(
        screen
        and max(screen_dbic) < float(c["screen_gate"]) * T
        and gap0 <= 1.5 * float(np.sqrt(np.mean(sigma**2)))
    )
    exact: list[tuple[FitResult, list[Term]]] = []
    chosen = [] if gated else screen[: int(c["n_exact"])]
    keys = {t.key for _, t, _ in chosen}
    chosen = chosen + ([] if gated else model.extra_starts(screen, keys, None))
    # exact refits only where the screen cannot decide: a candidate whose linearised gain falls more
    # than twice the threshold short of the best exact single so far can be neither named (within
    # the threshold of the best) nor the seed of a pair that counts; one threshold is left for the
    # linearisation, and for large effects (whose linearisation errs in proportion) half the best
    # gain. The nonlinear starts (extra_starts, rss 0) are always refitted.
    best_gain = -math.inf
    singles_skipped = 0
    skipped_bic: list[float] = []  # their BIC as the screen estimates it (a runner-up of the singles)
    for rss, t, start in chosen:
        if rss > 0.0 and lin_dbic(rss, t) < min(best_gain - 2.0 * T, 0.5 * best_gain):
            singles_skipped += 1
            skipped_bic.append(base.bic - lin_dbic(rss, t))
            continue
        fr = fit([t], start)
        if fr is not None:
            exact.append((fr, [t]))
            best_gain = max(best_gain, base.bic - fr.bic)
    exact.sort(key=lambda z: z[0].bic)
    exact = [z for i, z in enumerate(exact) if z[1][0].key not in {y[1][0].key for y in exact[:i]}]
    # --- pairs: extend the best singles by a second term (screened linearly at the single's fit)
    pairs: list[tuple[FitResult, list[Term]]] = []
    seen = set()
    pairs_refitted = 0
    for fr, (t1,) in exact[: int(c["n_pair_seeds"])]:
        p1 = fr.values()
        r1 = model.residual(p1, [t1])
        Jb1 = _jacobian_columns(model, p1, [t1], base_names + t1.names(), base_scales + t1.scales(), f0=r1)
        ext = []
        for t2 in terms:
            if t2.key == t1.key or t2.effect == t1.effect and t2.channel == t1.channel:
                continue
            pt = {**p1, **{n: 0.0 for n in t2.names()}, **(vib_start if t2.effect == "vibration" else {})}
            tn = [n for n in t2.names() if not n.endswith("f_hz")]
            ts = [s for n, s in zip(t2.names(), t2.scales()) if not n.endswith("f_hz")]
            Jt = _jacobian_columns(model, pt, [t1, t2], tn, ts, f0=r1)
            J = np.hstack([Jb1, Jt])
            coef = _lstsq(J, r1)
            if coef is None:
                continue
            start = dict(pt)
            for n, s, a in zip(base_names + t1.names() + tn, base_scales + t1.scales() + ts, coef):
                start[n] = start[n] + a * s
            ext.append((float(np.sum((r1 - J @ coef) ** 2)), t2, start))
        ext.sort(key=lambda z: z[0])
        # the single's gate: where the single leaves the gap at the noise floor and no second term
        # gains half the threshold at its fit (linearised), no pair can beat the single by the
        # threshold: its exact refits are skipped (as a scan's singles are, above)
        rss1 = float(np.sum(r1**2))
        gain = max(
            (
                n_scr * math.log(rss1 / max(rss, 1e-300))
                - len([n for n in t2.names() if not n.endswith("f_hz")]) * math.log(n_scr)
                for rss, t2, _ in ext
            ),
            default=-math.inf,
        )
        if gain < float(c["screen_gate"]) * T and _rms(
            model.residual_matrix(p1, [t1]), model.mask
        ) <= 1.5 * float(np.sqrt(np.mean(sigma**2))):
            continue
        # a pair counts only if it beats the best single by the threshold (or, with no single
        # passing, the base by it): a seed whose own gain plus its best second term's (linearised)
        # falls short of the best single's gain cannot get there, with a threshold to spare for
        # the linearisation
        if (base.bic - fr.bic) + max(gain, 0.0) < max(base.bic - exact[0][0].bic, 0.0):
            continue
        more = model.extra_starts(ext, {z[1].key for z in ext[: int(c["n_pair_ext"])]} | {"*"}, t1)
        ext = ext[: int(c["n_pair_ext"])] + more
        for _, t2, start in ext:
            key = tuple(sorted((t1.key, t2.key)))
            if key in seen:
                continue
            seen.add(key)
            fr = fit([t1, t2], start)
            pairs_refitted += 1
            if fr is not None:
                pairs.append((fr, [t1, t2]))
    pairs.sort(key=lambda z: z[0].bic)

    # --- decision
    best1 = exact[0] if exact else None
    best2 = pairs[0] if pairs else None
    level: list[tuple[FitResult, list[Term]]] = []
    if best1 is not None and base.bic - best1[0].bic > T:
        level = exact
        if best2 is not None and best1[0].bic - best2[0].bic > T:
            level = pairs
    elif best2 is not None and base.bic - best2[0].bic > T:
        level = pairs
    named: list[dict] = []
    after = base
    after_terms: list[Term] = []
    cand_report = [
        {"terms": [t.key for t in ts], "delta_bic": float(base.bic - fr.bic)} for fr, ts in (exact + pairs)
    ]
    cand_report.sort(key=lambda z: -z["delta_bic"])
    verdict = "no_missing_effect"
    if level:
        top = level[0][0].bic
        tied = [z for z in level if z[0].bic - top < T and _physical(z)]
        if not tied:
            tied = [level[0]]
        after, after_terms = tied[0]
        runner = min(
            [z[0].bic for z in level if z[0].bic - top >= T]
            + ([b for b in skipped_bic if b - top >= T] if level is exact else []),
            default=None,
        )
        seen_terms = set()
        for fr, ts in tied:
            for t in ts:
                if t.key in seen_terms:
                    continue
                seen_terms.add(t.key)
                named.append(_named_entry(t, fr, base, runner, model))
        verdict = "ambiguous" if len(tied) > 1 else "missing_effect"
    r_after = model.residual_matrix(after.values(), after_terms)
    extra_named = []
    for e in named_extra:
        extra_named.append({k: v for k, v in e.items() if not k.startswith("_")})
    if extra_named:
        named = extra_named + named
        if verdict == "no_missing_effect":
            verdict = "missing_effect"
    eval_mask = model.mask  # outlier samples are explained by the outliers term
    gap_before = _rms(model.residual_matrix(base.values(), []), all_valid)
    gap_after = _rms(r_after, eval_mask)
    findings = {
        "scan_id": data.scan_id,
        "verdict": verdict,
        "named": named,
        "gap_before": {"rms_mm": gap_before},
        "gap_after": {"rms_mm": gap_after},
        "noise_floor_mm": sig_ref,
        "noise_floor_by_channel_mm": {str(ch): float(s) for ch, s in zip(data.channels, sigma)},
        "threshold_delta_bic": T,
        "config": {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in c.items()
            if k not in ("beams", "layers", "device_effects")
        },
        # the device model the reference calibration carried, fitted with the base (Effect.to_dict)
        "device_effects": [e.to_dict() for e in c.get("device_effects", ())],
        "examined_against": "calibration given to the workflow"
        if c.get("beams") is not None or c.get("layers") is not None
        else "device.nominal",
        "samples_used": int(data.t_s.size),
        "samples_total": int(getattr(data, "n_total", None) or data.t_s.size),
        "device_type": model.device_type,
        "base_model": {
            "free": base_names if len(base_names) <= 8 else [*base_names[:8], f"({len(base_names)} in all)"],
            "fixed": model.base_description,
            **model.base_summary(base.values()),
            "bic": base.bic,
        },
        "localisation": loc,
        "candidates": cand_report[:12],
        "screen": {
            "exact_refits": not gated,
            "pairs_refitted": pairs_refitted,
            "singles_not_refitted": singles_skipped,
            "max_linearised_delta_bic": float(max(screen_dbic)) if screen_dbic else None,
            "best_linearised": [
                {"terms": [t.key], "delta_bic": float(d)}
                for d, (_, t, _) in list(zip(screen_dbic, screen))[:3]
            ],
        },
    }
    return Examination(
        findings=_clean(findings),
        t_s=data.t_s,
        angle_rad=model.plot_angle(),
        channels=data.channels,
        residual_before_mm=np.where(all_valid, model.residual_matrix(base.values(), []), np.nan),
        residual_after_mm=np.where(eval_mask, r_after, np.nan),
        rev_hz=model.rev_hz,
        angle_label=model.angle_label,
    )


def _physical(z: tuple[FitResult, list[Term]]) -> bool:
    """Return False for fits that need a physically impossible value.

    Return False for fits that need a physically impossible value: a fitted parameter more than two
    standard uncertainties outside its registry bounds (e.g. ``beam_tilt`` shortening the reading).
    """
    fr, ts = z
    v, u = fr.values(), fr.uncertainties()
    for t in ts:
        for q in EFFECTS[t.effect].fit:
            n = f"{t.key}.{q.name}"
            if v[n] < q.lower - 2.0 * u[n] or v[n] > q.upper + 2.0 * u[n]:
                return False
    return True


def _named_entry(t: Term, fr: FitResult, base: FitResult, runner_bic: float | None, model) -> dict:
    data = model.data
    par, unc = model.term_parameters(t, fr.values(), fr.uncertainties())
    entry = {
        "effect": t.effect,
        "channel": None if t.channel in (None, 0) else int(t.channel),
        "parameters": par,
        "uncertainties": {f"u_{k}": v for k, v in unc.items()},
        "evidence": {
            "delta_bic": float(base.bic - fr.bic),
            "delta_bic_runner_up": None if runner_bic is None else float(runner_bic - fr.bic),
        },
    }
    if t.channel == 0:
        entry["channels"] = [int(ch) for ch in data.channels]
        entry["note"] = "same value on every channel"
    if t.effect in model.absorbed_by:
        entry["absorbed_by_calibration"] = model.absorbed_by[t.effect]
    return entry


def _clean(obj):
    """JSON-ready: numpy scalars to float, non-finite to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj


def write_findings(findings: dict, out_dir: str | Path) -> Path:
    """Write ``<out_dir>/findings.json`` (sorted keys, deterministic); returns the path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "findings.json"
    atomic_write_text(path, json.dumps(_clean(findings), sort_keys=True, indent=2) + "\n")
    return path
