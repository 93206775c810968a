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
from borescan.discrepancy.classes import (
    class_statement,
    other_readings,
    rod_classes,
    spindle_classes,
    static_classes,
    zero_weights,
)
from borescan.discrepancy.evidence import output_stage_evidence
from borescan.discrepancy.fitting import FitResult
from borescan.discrepancy.judge import Rejection, explanation, judge, plausible_ranges
from borescan.discrepancy.poses import RodModel, StaticModel, pose_data_from_arrays
from borescan.discrepancy.tri_starts import mirrored_rho_starts
from borescan.discrepancy.search import (
    Candidate,
    Fitter,
    Search,
    jacobian_columns,
    rms,
    search_candidates,
    tie_sorted,
)
from borescan.discrepancy.terms import Term
from borescan.discrepancy.tri import TriData, TriModel, tri_data_from_arrays
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
    "model_of",
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
    "floor_ratio": "floor_ratio",
    "plausible_ranges": "plausible",
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


def model_of(scan, **cfg):
    """Return the model an examination of ``scan`` fits: a spindle, rod or static model.

    ``cfg`` as :func:`examine_scan` takes it (the reference ``beams`` / ``layers``, ``free_beams``,
    ``device_effects``, ``max_samples``).
    """
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
        return TriModel(
            data,
            free_beams=tuple(cfg.get("free_beams", ())),
            device_effects=tuple(cfg.get("device_effects", ())),
        )
    if pose is None:
        raise ValueError(f"{meta['scan_id']}: lds.parquet: a {dtype} scan needs the pose column")
    pdata = pose_data_from_arrays(meta["scan_id"], meta, t_s, vals, channels, pose)
    if dtype == "rod":
        return RodModel(pdata)
    if dtype == "tri_lds":
        return StaticModel(pdata)
    raise ValueError(f"{meta['scan_id']}: scan.json: unknown device type {dtype!r}")


def analyse_scan(scan, **cfg) -> Examination:
    """Examine a ``RawScan`` (any ``borescan-raw/1`` scan): see :func:`examine_scan`."""
    return examine_model(model_of(scan, **cfg), **cfg)


def examine_scan(scan, **cfg) -> dict:
    """Find where model and data disagree, name the missing effect and show the gap it leaves.

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


# ---------------------------------------------------------------------------- the examination


def examine_model(model, **cfg) -> Examination:
    """Run the examination workflow on any model object (:class:`TriModel`, rod and static models).

    The model provides the data, the base parameters and their start, the forward model with
    terms, the candidate terms, the noise floor and the localisation (see ``TriModel``). Steps: base fit,
    outliers and quantization (:mod:`~borescan.discrepancy.evidence`), localisation, the candidate search
    (:mod:`~borescan.discrepancy.search`), the rules a named candidate must meet
    (:mod:`~borescan.discrepancy.judge`), the decision and the findings.
    """
    c = {**DEFAULTS, **cfg}
    data = model.data
    fitter = Fitter(model)
    start0 = model.base_start()
    base = fitter([], {n: start0.get(n, 0.0) for n in fitter.base_names})
    if base is None:
        raise ValueError(f"{data.scan_id}: the base model does not reach the data (beams miss the bore)")
    fitter.fallback.update(base.values())

    def refit(start: dict) -> FitResult | None:
        fr = fitter([], start)
        if fr is not None:
            fitter.fallback.update(fr.values())
        return fr

    out = output_stage_evidence(
        model,
        base,
        refit,
        threshold=float(c["threshold"]),
        false_rate=float(c["spike_false_rate"]),
        min_spikes=int(c["min_spikes"]),
    )
    base = _mirror_checked(model, fitter, out.base, out.sig_ref_mm, float(c["floor_ratio"]))
    r0 = model.residual_matrix(base.values(), [])
    loc = model.localise(r0, out.sigma_mm)
    f_vib = model.vibration_f(np.where(model.mask, r0, np.nan))
    terms = model.candidate_terms(k_max=int(c["k_max"]), vibration_f_hz=f_vib)
    vib_start = {"vibration.f_hz": f_vib} if f_vib is not None else {}
    found = search_candidates(fitter, base, terms, c, out.sig_ref_mm, vib_start)
    decision = decide(model, base, found, out.sigma_mm, c)
    r_after = model.residual_matrix(decision.after.values(), list(decision.after_terms))
    findings = _findings(model, c, base, out, loc, found, decision, r_after)
    other_readings(model, findings, r0, r_after, out.sigma_mm)
    return Examination(
        findings=_clean(findings),
        t_s=data.t_s,
        angle_rad=model.plot_angle(),
        channels=data.channels,
        residual_before_mm=np.where(out.all_valid, r0, np.nan),
        residual_after_mm=np.where(model.mask, r_after, np.nan),
        rev_hz=model.rev_hz,
        angle_label=model.angle_label,
    )


def _mirror_checked(model, fitter: Fitter, base: FitResult, sig_ref: float, floor_ratio: float) -> FitResult:
    """Return the base fit, or the fit from a mirrored beam offset where that fits lower (:mod:`.tri_starts`).

    Tried only where the base already leaves the gap within ``floor_ratio`` of the noise floor: there a
    lower mirror is the geometry's own minimum; above it a large effect is missing and a mirror would only
    absorb part of it.
    """
    if rms(model.residual_matrix(base.values(), []), model.mask) > floor_ratio * sig_ref:
        return base
    for st in mirrored_rho_starts(model, base.values()):
        fr = fitter([], st)
        if fr is not None and fr.rss < base.rss:
            base = fr
    return base


@dataclass
class Decision:
    """The choice among the candidates: the named ones, the fit after, and the rejected ones."""

    verdict: str
    named: list[dict]
    after: FitResult
    after_terms: tuple[Term, ...] = ()
    named_fits: list[Candidate] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)


def decide(model, base: FitResult, found: Search, sigma_mm: np.ndarray, c: dict) -> Decision:
    """Choose the named candidates (module doc), among those the rules of :mod:`.judge` let through.

    A level (singles, or pairs when a pair beats the best single by the threshold) passes when it lowers the
    BIC by more than the threshold; every candidate of it within the threshold of its best is named.
    """
    T = float(c["threshold"])
    ranges = plausible_ranges(c.get("plausible"))
    sig_ref = float(np.sqrt(np.mean(sigma_mm**2))) or 1e-6
    cache: list[np.ndarray] = []

    def absorbable() -> np.ndarray:  # the base Jacobian, computed once and only when a rule needs it
        if not cache:
            cache.append(jacobian_columns(model, base.values(), [], list(base.names), model.base_scales()))
        return cache[0]

    singles, rej1 = judge(model, found.singles, absorbable, sig_ref, ranges, base.bic)
    pairs, rej2 = judge(model, found.pairs, absorbable, sig_ref, ranges, base.bic)
    rejected = tie_sorted(rej1 + rej2, lambda z: -z.delta_bic, lambda z: z.terms)
    level: list[Candidate] = []
    if singles and base.bic - singles[0].fit.bic > T:
        level = pairs if pairs and singles[0].fit.bic - pairs[0].fit.bic > T else singles
    elif pairs and base.bic - pairs[0].fit.bic > T:
        level = pairs
    if not level:
        passing = [z for z in rejected if z.delta_bic > T]
        return Decision("missing_effect" if passing else "no_missing_effect", [], base, rejected=rejected)
    top = level[0].fit.bic
    tied = [z for z in level if z.fit.bic - top < T]
    skipped = [b for b in found.skipped_bic if b - top >= T] if level is singles else []
    runner = min([z.fit.bic for z in level if z.fit.bic - top >= T] + skipped, default=None)
    named, seen = [], set()
    for z in tied:
        for t in z.terms:
            if t.key not in seen:
                seen.add(t.key)
                named.append(_named_entry(t, z.fit, base, runner, model))
    return Decision(
        "ambiguous" if len(tied) > 1 else "missing_effect",
        named,
        tied[0].fit,
        tied[0].terms,
        named_fits=tied,
        rejected=rejected,
    )


def not_testable(model) -> list[str]:
    """Return the artifact's effects (registry scope ``artifact``) a scan of the model's kind cannot show.

    E.g. a static three-sensor set cannot show the bore's form (``bore_lobing``, ``axis_tilt``): a gap such
    an effect leaves is named as its look-alikes, so the finding says which were not tried.
    """
    return [
        name
        for name, spec in EFFECTS.items()
        if spec.scope == "artifact"
        and model.device_type in spec.device_types
        and model.scan_kind not in spec.candidate
    ]


def _statement(
    verdict: str, named: list[dict], explained: str, remaining: dict | None, rejected, untried: list[str]
) -> str:
    """Return the finding in one sentence a person can act on."""
    if verdict != "no_missing_effect" and untried:
        note = f"; a scan of this kind cannot fit the artifact's {', '.join(untried)}, which were not tried"
    else:
        note = ""
    return _sentence(verdict, named, explained, remaining, rejected) + note


def _sentence(verdict: str, named: list[dict], explained: str, remaining: dict | None, rejected) -> str:
    """Return what the verdict says, without the note on untried effects."""
    labels = [n["effect"] + (f" on channel {n['channel']}" if n.get("channel") else "") for n in named]
    if verdict == "no_missing_effect":
        return "the residual is at the noise floor: no effect is missing"
    if not named:
        why = "; ".join(z.sentence for z in rejected[:3])
        return f"a gap no plausible candidate explains: {why}"
    if len(labels) == 1:
        what = labels[0]
    elif verdict == "missing_effect":  # one candidate (a pair, or the evidence effects): together, not alike
        what = " together with ".join(labels)
    else:
        what = "one of " + ", ".join(labels) + " (they look alike in this scan)"
    if explained == "fully":
        return f"explained by {what}: the gap after is at the noise floor"
    rem = remaining or {}
    chans = ", ".join(f"channel {k} {v:.2g}x" for k, v in rem.get("channels_above_floor", {}).items())
    conv = "" if rem.get("fit_converged", True) else "; the fit did not converge"
    return (
        f"partly explained by {what}: the gap after is {rem.get('gap_after_over_floor', math.nan):.3g}x the "
        f"noise floor" + (f" ({chans})" if chans else "") + conv + "; something else is missing"
    )


def _findings(model, c: dict, base, out, loc: dict, found: Search, dec: Decision, r_after) -> dict:
    """Return the findings.json content of one examination (``outputs.md`` plus the workflow's details)."""
    data = model.data
    dec_named, classes = dec.named, []
    if model.device_type == "rod":
        dec_named, classes = rod_classes(dec.named)
    elif model.scan_kind == "tri_static":
        weights = zero_weights(model.data.channels, model.beams.beta_rad)
        v = np.where(model.valid, data.values_mm, np.nan)
        readings = {
            ch: (v[:, i][np.isfinite(v[:, i])], float(data.range_mm[i])) for i, ch in enumerate(data.channels)
        }
        dec_named, classes = static_classes(dec.named, weights, [z.keys for z in dec.named_fits], readings)
    elif model.scan_kind == "tri_spindle" and "d_b" not in getattr(model, "free_beams", ("d_b",)):
        dec_named, classes = spindle_classes(dec.named)  # the beams held: a channel's offset is a candidate
    named = list(out.named) + dec_named
    verdict = dec.verdict
    if out.named and verdict == "no_missing_effect":
        verdict = "missing_effect"
    explained, remaining = "fully", None
    if dec.named:
        explained, remaining = explanation(
            model, dec.named_fits, r_after, out.sigma_mm, float(c["floor_ratio"])
        )
    elif dec.rejected and verdict == "missing_effect" and not out.named:
        explained = "none"
    gap_before = rms(model.residual_matrix(base.values(), []), out.all_valid)
    gap_after = rms(r_after, model.mask)
    base_names = model.base_names()
    cand_report = [
        {"terms": list(z.keys), "delta_bic": float(base.bic - z.fit.bic)} for z in found.singles + found.pairs
    ]
    cand_report = tie_sorted(cand_report, lambda z: -z["delta_bic"], lambda z: z["terms"])
    return {
        "scan_id": data.scan_id,
        "verdict": verdict,
        "explained": explained,
        "statement": _statement(  # outliers or quantization alone: what explains the scan
            verdict, dec_named or list(out.named), explained, remaining, dec.rejected, not_testable(model)
        )
        if not classes
        else class_statement(
            classes,
            dec_named,
            explained,
            remaining,
            frozenset.intersection(*(frozenset(z.keys) for z in dec.named_fits or [Candidate(base, ())])),
        ),
        "classes": [k.to_dict() for k in classes],
        "not_tried": not_testable(model),
        "remaining": remaining,
        "named": named,
        "rejected": [z.to_dict() for z in dec.rejected[:8]],
        "gap_before": {"rms_mm": gap_before},
        "gap_after": {"rms_mm": gap_after},
        "gap_after_over_floor": gap_after / out.sig_ref_mm,
        "noise_floor_mm": out.sig_ref_mm,
        "noise_floor_by_channel_mm": {str(ch): float(s) for ch, s in zip(data.channels, out.sigma_mm)},
        "threshold_delta_bic": float(c["threshold"]),
        "config": {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in c.items()
            if k not in ("beams", "layers", "device_effects", "plausible")
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
            "fixed": base_fixed(model, c),
            **model.base_summary(base.values()),
            "bic": base.bic,
        },
        "localisation": loc,
        "candidates": cand_report[:12],
        "screen": {
            "exact_refits": not found.gated,
            "pairs_refitted": found.pairs_refitted,
            "singles_not_refitted": found.singles_skipped,
            "max_linearised_delta_bic": float(max(found.screen_dbic)) if found.screen_dbic else None,
            "best_linearised": [
                {"terms": [z.term.key], "delta_bic": float(d)}
                for d, z in list(zip(found.screen_dbic, found.screen))[:3]
            ],
        },
    }


def base_fixed(model, c: dict) -> str:
    """Return what the base model held fixed (findings.json's ``base_model.fixed``).

    The model's own description names the design (``device.nominal``); a scan examined against a
    calibration (``beams`` or ``layers`` given) held that calibration's geometry instead, and beams freed in
    the base (``free_beams``) only started from it.
    """
    text = model.base_description
    if "device.nominal" not in text:  # a pooled model says itself what it shares and frees
        return text
    if c.get("beams") is not None or c.get("layers") is not None:
        text = text.replace("device.nominal", "the given calibration's", 1)
    free = tuple(getattr(model, "free_beams", ()))
    if free:
        held = " (the first beam's direction held)" if "beta" in free else ""
        text = text.replace(" beams", f" beams as the start of their free {', '.join(free)}{held}", 1)
    return text


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
