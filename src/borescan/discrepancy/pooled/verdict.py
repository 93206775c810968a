"""The pooled verdict of the spindle scans of one device.

:func:`examine_pooled` runs the single-scan search on the pooled model, checks a pair verdict,
refits the verdict's terms and reports the carriers, the beams and the device model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from borescan.discrepancy.examine import Examination, _clean, _named_entry, examine_model
from borescan.discrepancy.fitting import FitResult, fit_least_squares
from borescan.discrepancy.pooled.drift import calibration_equivalent
from borescan.discrepancy.pooled.model import PooledModel
from borescan.discrepancy.pooled.terms import PooledScan, parse_device_effect
from borescan.discrepancy.terms import Term, term_parameters, term_values
from borescan.discrepancy.tri import SCAN_KIND
from borescan.effects import EFFECTS, SCOPES, Effect
from borescan.geometry import Beams

#: Share of the total chi-square decrease that the scans named as carrying the evidence hold.
CARRIER_SHARE = 0.9


@dataclass
class PooledExamination:
    """The pooled findings and the examination behind them.

    The pooled findings and the examination behind them (arrays stacked over the scans); ``fit``
    is the verdict's fit (base and ``terms``; the base alone when nothing is named).
    """

    findings: dict
    examination: Examination
    model: PooledModel
    fit: FitResult | None = None
    terms: list[Term] = field(default_factory=list)


def _chi2_by_scan(model: PooledModel, r_mm: np.ndarray) -> np.ndarray:
    """Sum over each scan of (residual / the scan's noise floor)^2 over finite entries (K,)."""
    out = np.zeros(len(model.scans))
    for k in range(len(model.scans)):
        rk = r_mm[model._rows(k)] / model.scan_sigma[k]
        out[k] = float(np.nansum(rk**2))
    return out


def _carriers(model: PooledModel, gain: np.ndarray, ks: Sequence[int] | None = None) -> list[str]:
    """Return the fewest scans holding most of the chi-square decrease.

    Return the fewest scans (largest chi-square decrease first) holding :data:`CARRIER_SHARE` of the
    decrease.
    """
    ks = list(range(len(model.scans))) if ks is None else list(ks)
    pos = [(float(gain[k]), k) for k in ks if gain[k] > 0]
    pos.sort(reverse=True)
    total = sum(g for g, _ in pos)
    out, acc = [], 0.0
    for g, k in pos:
        if total <= 0 or acc >= CARRIER_SHARE * total:
            break
        out.append(model.scan_ids[k])
        acc += g
    return out


def _absorbed_summary(model: PooledModel) -> list[dict]:
    """Return the absorbed terms grouped by effect and absorbing parameter.

    Return the absorbed terms grouped by effect and absorbing parameter (one line each; for an
    effect of several groups, its part common to every group).
    """
    out: dict[tuple, dict] = {}
    for a in model.absorbed:
        key = (a["effect"], a["parameter"])
        e = out.setdefault(key, {k: v for k, v in a.items() if k != "term"} | {"terms": []})
        e["terms"].append(a["term"])
    for e in out.values():
        e["advice"] = f"{e['effect']} cannot be told from {e['absorbed_by']} by these scans" + (
            f" ({e['design']}); {e['separated_by']} separates them"
            if e.get("separated_by")
            else "; no scan separates them: a calibration includes it"
        )
    return sorted(out.values(), key=lambda e: (e["effect"], e["parameter"]))


#: What a scan must change to vary an effect of each registry scope (the other scopes' stay).
_SCOPE_CHANGE = {
    "scan": "another scan",
    "night": "a scan on another night",
    "artifact": "a scan of another artifact",
    "device": "a scan with another device",
}


def separation(a: Term, b: Term) -> str | None:
    """Return the measurement that separates two tied terms, from the registry.

    Return the measurement that separates two tied terms, from the registry: effects of different
    ``scope`` part when the narrower one's unit changes (another run, night or artifact) and the
    other's does not; None when the registry knows none (the same scope: a spec look-alike).
    """
    sa, sb = EFFECTS[a.effect].scope, EFFECTS[b.effect].scope
    if sa == sb:
        return None
    narrow, wide = (a, b) if SCOPES.index(sa) > SCOPES.index(sb) else (b, a)
    return (
        f"{_SCOPE_CHANGE[EFFECTS[narrow.effect].scope]} of the same device: {narrow.effect} belongs to the "
        f"{EFFECTS[narrow.effect].scope}, {wide.effect} to the {EFFECTS[wide.effect].scope}"
    )


#: Most function evaluations of the fits that check a pair verdict (the search's own fits stop at 60).
POLISH_NFEV = 200


def _entry_start(model: PooledModel, t: Term, n: dict) -> dict[str, float]:
    """Return the fitted values of term ``t`` from its named entry ``n`` (spec parameters, turns)."""
    spec = EFFECTS[t.effect]
    par = {k: v for k, v in n["parameters"].items() if k in spec.params}
    if spec.per_channel:
        par["channel"] = int(t.channel) if t.channel not in (None, 0) else int(model.data.channels[0])
    out = term_values(t, Effect(t.effect, par))
    for sid, a in (n["parameters"].get("turned_rad") or {}).items():
        out[f"{t.key}.turn@{sid}"] = a
    return out


def _fit_terms(
    model: PooledModel, terms: list[Term], start: dict[str, float], max_nfev: int = 60
) -> FitResult | None:
    names = model.base_names() + [nm for t in terms for nm in t.names()]
    scales = model.base_scales() + [s for t in terms for s in t.scales()]
    try:
        fr = fit_least_squares(
            lambda p: model.residual(p, terms),
            names,
            [start.get(nm, 0.0) for nm in names],
            scales,
            max_nfev=max_nfev,
        )
    except ValueError:
        return None
    return fr if np.isfinite(fr.rss) else None


def _check_pair(model: PooledModel, f: dict, terms: list[Term], entries: list[dict]) -> dict | None:
    """Return a pair verdict checked with fits run to convergence (:data:`POLISH_NFEV` evaluations).

    The search prefers a pair to the best single only when it beats it by more than the
    threshold; but the pair's fit starts where the single's stopped, so a single that its
    evaluation limit stopped early can lose to a pair whose second term is nothing. Here the pair
    and each of its terms alone are refitted from the pair's values; when a single comes within the
    threshold of the pair (and beats the base by more), the examination's own rule names that
    single. Returns the replacing single (term, fit, pair fit) or None.
    """
    T = float(f["threshold_delta_bic"])
    start = dict(model.base_values)
    for t, n in zip(terms, entries):
        start.update(_entry_start(model, t, n))
    pair = _fit_terms(model, terms, start, POLISH_NFEV)
    if pair is None:
        return None
    singles = []
    for t in terms:
        st = {
            k: v
            for k, v in pair.values().items()
            if not any(k.startswith(o.key + ".") for o in terms if o is not t)
        }
        fr = _fit_terms(model, [t], st, POLISH_NFEV)
        if fr is not None:
            singles.append((fr.bic, t.key, t, fr))
    if not singles:
        return None
    singles.sort(key=lambda z: z[:2])
    bic1, _, t1, fr1 = singles[0]
    if bic1 - pair.bic > T or f["base_model"]["bic"] - bic1 <= T:
        return None
    return {"term": t1, "fit": fr1, "pair": pair}


def _name_terms(model: PooledModel, f: dict) -> tuple[list[Term], list[dict]]:
    """Return the named terms and their entries in ``f["named"]``, each entry marked with its term.

    The terms are in the order of the named entries (term_parameters is asked once per entry); an
    entry of a group term whose effect a free shared beam parameter absorbs notes that its value is
    relative to the other pooled scans.
    """
    named_terms = [t for t in model.reported if t is not None]
    effect_entries = [n for n in f["named"] if n["effect"] not in ("outliers", "quantization")]
    if len(named_terms) != len(effect_entries) or any(
        t.effect != n["effect"] for t, n in zip(named_terms, effect_entries)
    ):
        raise RuntimeError(f"{model.label}: the named effects and the reported terms disagree")
    for t, n in zip(named_terms, effect_entries):
        n["term"] = t.key
        n["group"] = getattr(t, "group", None)
        shared = [v for b, v in EFFECTS[t.effect].absorbers(SCAN_KIND).items() if b in model.free_beams]
        if n["group"] is not None and shared:
            n["note"] = "relative to the other pooled scans: a part common to every scan is " + "; ".join(
                shared
            )
    return named_terms, effect_entries


def _settle_pair(
    model: PooledModel, ex: Examination, named_terms: list[Term], effect_entries: list[dict]
) -> tuple[list[Term], list[dict]]:
    """Return the named terms and entries after checking a pair verdict (:func:`_check_pair`).

    When the pair's second term is not needed once the single is fitted to convergence, the single
    replaces the pair in ``ex.findings["named"]`` and the examination's residual after is the single's.
    """
    f = ex.findings
    if not (f["verdict"] == "missing_effect" and len(named_terms) == 2):
        return named_terms, effect_entries
    single = _check_pair(model, f, named_terms, effect_entries)
    if single is None:
        return named_terms, effect_entries
    t1 = single["term"]
    entry = _named_entry(t1, single["fit"], SimpleNamespace(bic=f["base_model"]["bic"]), None, model)
    entry.update(
        {
            "term": t1.key,
            "group": getattr(t1, "group", None),
            "pair_checked": {
                "terms": [t.key for t in named_terms],
                "delta_bic_pair_over_single": float(single["fit"].bic - single["pair"].bic),
                "note": "the pair's second term is not needed once the single is fitted "
                f"to convergence ({POLISH_NFEV} evaluations)",
            },
        }
    )
    f["named"] = [n for n in f["named"] if n["effect"] in ("outliers", "quantization")] + [entry]
    r_after = model.residual_matrix(single["fit"].values(), [t1])
    ex.residual_after_mm = np.where(model.mask, r_after, np.nan)
    f["gap_after"] = {"rms_mm": float(np.sqrt(np.nanmean(ex.residual_after_mm**2)))}
    return [t1], [entry]


def _beams_entry(
    model: PooledModel, final_values: dict[str, float], fit: FitResult | None, chosen: list[Term]
) -> dict:
    """Return the shared beams of the verdict's fit with their standard uncertainties (``beams``)."""
    b = model.beams_at(final_values)
    if fit is not None:
        ub = np.sqrt(
            np.clip(np.diag(model.beam_covariance(final_values, fit.names, fit.cov)), 0, None)
        ).reshape(-1, 3)
    else:
        ub = np.full((len(b.channels), 3), math.nan)
    return {
        "channels": list(b.channels),
        "beta_rad": [float(x) for x in b.beta_rad],
        "rho_mm": [float(x) for x in b.rho_mm],
        "d_b_mm": [float(x) for x in b.d_b_mm],
        "u_beta_rad": [float(x) for x in ub[:, 0]],
        "u_rho_mm": [float(x) for x in ub[:, 1]],
        "u_d_b_mm": [float(x) for x in ub[:, 2]],
        "with_terms": [t.key for t in chosen] if fit is not None else None,
        "note": f"psi = beta + asin(rho / R) of channel {model.data.channels[0]} held at the start (a common "
        "turn is each scan's centre): its beta moves only with its rho",
    }


def _device_model_entries(
    model: PooledModel, final_values: dict[str, float], fit: FitResult | None
) -> list[dict]:
    """Return the device model's terms: fitted with the base model, or absorbed and not fitted."""
    in_model = []
    for t in model.device_terms:
        par, unc = term_parameters(t, final_values, fit.uncertainties() if fit is not None else {})
        in_model.append(
            {
                "effect": t.effect,
                "channel": t.channel,
                "term": t.key,
                "parameters": par,
                "uncertainties": {f"u_{k}": v for k, v in unc.items()},
                "note": "in the device model (fitted with the base model, not a candidate)",
            }
        )
    for a in model.device_absorbed:
        in_model.append(
            {
                "effect": a["effect"],
                "channel": parse_device_effect(a["term"]).channel,
                "term": a["term"],
                "parameters": None,
                "uncertainties": None,
                "note": f"in the device model; not fitted: these scans cannot tell it from {a['absorbed_by']}"
                + (
                    f" ({a['design']}; {a['separated_by']} would)"
                    if a.get("separated_by")
                    else ", which a calibration fits with it"
                ),
            }
        )
    return in_model


def examine_pooled(
    scans: Sequence[PooledScan],
    beams: Beams | None = None,
    *,
    free_beams: tuple[str, ...] = ("beta", "rho", "d_b"),
    label: str | None = None,
    device_effects: Sequence[str] = (),
    **cfg,
) -> PooledExamination:
    """Examine the spindle scans of one device together (module doc).

    Parameters
    ----------
    scans : :class:`PooledScan` of one device (:func:`pooled_scan` of each raw scan)
    beams : start of the shared beams, the device's latest calibration (default ``device.nominal``
        of the first scan)
    free_beams : shared beam parameters that are free
    label : name of the set (default the device id)
    device_effects : the device model (registry keys, :func:`borescan.effects.device_model_effects`): fitted
        as part
        of the base model, never candidates; reported under ``device_model``
    **cfg : the settings of :func:`~borescan.discrepancy.examine.examine_model`
        (:func:`~borescan.discrepancy.examine.discrepancy_settings` of the config's section)

    Returns
    -------
    PooledExamination; ``findings`` holds ``verdict`` (``missing_effect``, ``ambiguous``,
    ``no_missing_effect``), ``named`` (effect, channel, group, parameters, uncertainties,
    evidence, ``scans``: the scans carrying the evidence), ``evidence_by_scan`` (chi-square
    decrease per scan), ``absorbed`` (effects these scans cannot separate from a calibration
    parameter, and the measurement that would), ``beams`` (the pooled fit's shared beams with
    standard uncertainties), ``design``, the gaps and noise floors, candidates and base model.
    """
    model = PooledModel(scans, beams, free_beams=free_beams, label=label, device_effects=device_effects)
    cfg = {k: v for k, v in cfg.items() if k not in ("beams", "layers", "free_beams")}
    ex = examine_model(model, **cfg)
    f = ex.findings
    named_terms, effect_entries = _settle_pair(model, ex, *_name_terms(model, f))
    # the verdict's fit once more (the examination keeps only its findings; the base fit when nothing
    # is named): the beams with their u
    chosen = list(named_terms) if f["verdict"] == "missing_effect" else named_terms[:1]
    start = dict(model.base_values)
    for t, n in zip(named_terms, effect_entries):
        if t in chosen:
            start.update(_entry_start(model, t, n))
    fit = _fit_terms(model, chosen, start)
    # evidence by scan: the chi-square decrease from the base fit to the verdict's fit
    r_before = np.where(model.mask, ex.residual_before_mm, np.nan)
    gain = _chi2_by_scan(model, r_before) - _chi2_by_scan(model, ex.residual_after_mm)
    for n in f["named"]:
        t = next((x for x in named_terms if x.key == n.get("term")), None)
        n["scans"] = _carriers(model, gain, model.members(t) if t is not None else None)
    final_values = fit.values() if fit is not None else dict(model.base_values)
    if fit is not None and chosen:
        for t, n in zip(named_terms, effect_entries):
            if t in chosen:
                eq = calibration_equivalent(model, final_values, chosen, t)
                if eq:
                    n["calibration_equivalent"] = eq
    beams = _beams_entry(model, final_values, fit, chosen)
    in_model = _device_model_entries(model, final_values, fit)
    out = {
        "device_id": model.label,
        "device_model": [t["term"] for t in in_model],
        "in_device_model": in_model,
        "scan_ids": list(model.scan_ids),
        "nights": sorted({s.night for s in model.scans}),
        "verdict": f["verdict"],
        "named": f["named"],
        "evidence_by_scan": {sid: float(g) for sid, g in zip(model.scan_ids, gain)},
        "absorbed": _absorbed_summary(model),
        "separation": [
            {
                "terms": [named_terms[0].key, t.key],
                "separated_by": separation(named_terms[0], t) or "no measurement the registry knows of",
            }
            for t in named_terms[1:]
        ]
        if f["verdict"] == "ambiguous"
        else [],
        "beams": beams,
        "design": model.design(model.base_values),
        "gap_before": f["gap_before"],
        "gap_after": f["gap_after"],
        "noise_floor_mm": f["noise_floor_mm"],
        "noise_floor_by_channel_mm": f["noise_floor_by_channel_mm"],
        "noise_floor_by_scan_mm": {
            sid: [float(x) for x in model.scan_sigma[k]] for k, sid in enumerate(model.scan_ids)
        },
        "threshold_delta_bic": f["threshold_delta_bic"],
        "candidates": f["candidates"],
        "screen": f["screen"],
        "base_model": f["base_model"],
        "localisation": f["localisation"],
        "config": f["config"],
        "samples_used": f["samples_used"],
        "samples_total": f["samples_total"],
    }
    return PooledExamination(findings=_clean(out), examination=ex, model=model, fit=fit, terms=chosen)
