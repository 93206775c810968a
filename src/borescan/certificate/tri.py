"""``certificate.json`` of a three-sensor calibration: beam results, fit, device model, sign of rho."""

from __future__ import annotations

import numpy as np

from borescan.calibrate.result import TriCalibration
from borescan.certificate.admin import (
    _gauge_equipment,
    _measurement_results,
    _shared_part,
    _traceability_text,
)
from borescan.certificate.content import (
    _METHOD_TEXT,
    _budget_entry,
    _budget_of,
    _combined,
    _expanded,
    _fixed,
    _held,
    _parameter_rows,
    _residual_arrays,
    _result,
)
from borescan.config import schema_default
from borescan.physics.tri_params import straighten
from borescan.uncertainty import Budget


def _beam_results(cal: TriCalibration, budget: Budget | None, p: float) -> tuple[list[dict], dict]:
    """Return the DCC results of the beams and their budgets.

    DCC results (beta [rad], rho and d_b [mm] per channel, U for coverage probability ``p``) and,
    with a budget, each one's uncertainty budget.
    """
    names = [f"{n}[{ch}]" for ch in cal.beams.channels for n in ("beta_rad", "rho_mm", "d_b_mm")]
    units = ["rad", "mm", "mm"] * len(cal.beams.channels)
    results, budgets = [], {}
    for i, (name, unit) in enumerate(zip(names, units)):
        comb = _combined(cal, budget, i, p)
        results.append(_result(name, "borescan_beamParameter", _held(cal, i), cal.params[i], unit, comb))
        if budget is not None:
            budgets[name] = _budget_entry(unit, budget.rows(i), comb)
    return results, budgets


def _effective_base_lengths(
    cal: TriCalibration, budget: Budget | None, conditions: dict, p: float
) -> list[dict]:
    """Return the effective base lengths g per channel with U.

    Per channel g = d_b + rho^2/(2R) [mm] (R the gauge radius at its temperature [mm]) with U for
    coverage probability ``p``; empty without a budget or a radius.
    """
    R = conditions.get("gauge_radius_at_temperature_mm") if isinstance(conditions, dict) else None
    if budget is None or not R:
        return []
    rows = []
    for j, ch in enumerate(cal.beams.channels):
        vec = np.zeros(3 * len(cal.beams.channels))
        rho = float(cal.beams.rho_mm[j])
        vec[3 * j + 1], vec[3 * j + 2] = rho / float(R), 1.0
        rows.append(
            {
                "channel": int(ch),
                "value_mm": float(straighten(cal.beams.beta_rad[j], rho, cal.beams.d_b_mm[j], float(R))[1]),
                "expandedUnc": _expanded(budget.combined(vec, p)),
            }
        )
    return rows


def _fit_part(cal: TriCalibration) -> dict:
    """Return the fit's summary and the diagnostics a certificate reports.

    Return the fit's summary (residual rms [mm], dof, rank, condition, convergence, nuisance) and the
    diagnostics a certificate reports.
    """
    keys = (
        "gauge",
        "beta_reference",
        "acceptance",
        "n_obs",
        "n_params",
        "n_params_all_free",
        "rank_all_free",
        "weak_rho_channels",
        "g_mm",
        "u_g_mm",
        "n_minima",
        "ambiguous_minima",
    )
    diag = {k: cal.diagnostics[k] for k in keys if k in cal.diagnostics}
    if cal.diagnostics.get("rho_profiles"):  # where the cost along a rho is not the linear one
        diag["rho_profiled_channels"] = [
            int(p["channel"]) for p in cal.diagnostics["rho_profiles"] if not p.get("linear", True)
        ]
    if cal.diagnostics.get("device_model"):  # the effects of the device's model the calibration carried
        diag["device_model"] = [
            {k: m.get(k) for k in ("key", "estimated", "values", "u", "night", "evidence_scans", "source")}
            for m in cal.diagnostics["device_model"]
        ]
    return {
        "residual_rms_mm": cal.residual_rms_mm,
        "dof": cal.dof,
        "rank": cal.rank,
        "condition": cal.condition,
        "converged": cal.converged,
        "nuisance": cal.nuisance,
        **diag,
    }


def device_model_text(entries: list[dict]) -> str:
    """Return the device model a calibration carried, in words (certificate section 2)."""
    carried, listed = [], []
    for m in entries:
        if not m.get("estimated"):
            listed.append(m["key"])
            continue
        vals = ", ".join(f"{k} = {v:.6g} (u {m['u'].get(k, 0.0):.2g})" for k, v in m["values"].items())
        how = " (entered automatically: named night after night)" if m.get("source") == "automatic" else ""
        carried.append(
            f"{m['key']}: {vals}, from the pooled examination of {m['night']} "
            f"({', '.join(m.get('evidence_scans') or []) or 'its scans'}){how}"
        )
    out = []
    if carried:
        out.append(
            "Device model carried (the readings corrected for it, a channel delay taken in the channel's "
            "angle; each value's uncertainty is an input of the budget): " + "; ".join(carried) + "."
        )
    if listed:
        out.append(
            "Listed in the device model but not estimated by any earlier pooled examination, so not "
            "corrected: " + ", ".join(listed) + "."
        )
    return " ".join(out)


def certificate_dict(
    cal: TriCalibration,
    *,
    device: dict,
    artifact: dict,
    conditions: dict,
    residuals: dict,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
    budget: Budget | None = None,
    laboratory: dict | None = None,
    coverage_probability: float | None = None,
    dates: dict | None = None,
    verifications: list[dict] | None = None,
) -> dict:
    """Return the content of ``certificate.json`` (JSON-safe, floats rounded to 12 significant digits).

    See :func:`write_certificate` for the arguments.
    """
    t, res = _residual_arrays(residuals)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(res**2, axis=0)) if res.size else np.array([])
    budget = _budget_of(cal, budget)
    p = float(
        schema_default("uncertainty", "coverage_probability")
        if coverage_probability is None
        else coverage_probability
    )
    results, budgets = _beam_results(cal, budget, p)
    shared = _shared_part(
        cal,
        item_name=f"three-sensor bore measuring device ({device.get('type', 'tri_lds')})",
        item_id=device.get("id", cal.device_id),
        traceability=_traceability_text(artifact),
        device=device,
        artifact=artifact,
        conditions=conditions,
        raw_files=raw_files,
        software_version=software_version,
        config_hash=config_hash,
        laboratory=laboratory,
        coverage_probability=p,
        dates=dates,
        verifications=verifications,
    )
    return _fixed(
        {
            **shared,
            "measurementResults": _measurement_results(
                "calibrated beam geometry",
                cal.method,
                _METHOD_TEXT.get(cal.method, cal.method),
                "JCGM 100:2008 (GUM); JCGM 101:2008 (GUM S1)",
                [_gauge_equipment(artifact)],
                conditions,
                results,
                budgets,
            ),
            "parameters": _parameter_rows(cal, budget, p),
            "effective_base_length": _effective_base_lengths(cal, budget, conditions, p),
            "covariance": cal.cov,
            "covariance_fit": cal.diagnostics.get("cov_fit", cal.cov),
            "correlation": cal.correlation,
            "fit": _fit_part(cal),
            "rho_sign": rho_sign_part(cal),
            "residuals": {"n_samples": int(t.size), "rms_mm_per_channel": rms},
            "raw_sha256": dict(sorted(cal.raw_sha256.items())),
        }
    )


def rho_sign_part(cal: TriCalibration) -> dict:
    """Return certificate.json's ``rho_sign``: per beam the mirror check with its statement.

    Per beam the mirror check (:class:`borescan.mirror.BeamMirror`) with its statement; a flagged beam's two
    solutions (parameters of its own channel, the full (3c,) vectors and covariances).
    """
    from borescan.mirror import RESOLVED_DCHI2, mirror_checks_of

    beams = []
    for m in mirror_checks_of(cal.diagnostics):
        j = list(cal.beams.channels).index(m.channel)
        e = {**m.to_dict(), "statement": m.statement()}
        e.pop("alternative", None)
        if m.alternative is not None:
            pa = m.alternative.params_array
            e["u_main"] = {
                "beta_rad": float(cal.beams.beta_rad[j]),
                "rho_mm": float(cal.beams.rho_mm[j]),
                "d_b_mm": float(cal.beams.d_b_mm[j]),
            }
            e["alternative"] = {
                "beta_rad": float(pa[3 * j]),
                "rho_mm": float(pa[3 * j + 1]),
                "d_b_mm": float(pa[3 * j + 2]),
                "delta_chi2": m.alternative.delta_chi2,
                "weight": m.alternative.weight,
                "params": list(m.alternative.params),
                "covariance": m.alternative.cov,
            }
            e["main"] = {"params": cal.params.tolist(), "covariance": cal.cov.tolist()}
        beams.append(e)
    return {
        "resolved_delta_chi2": RESOLVED_DCHI2,
        "beams": beams,
        "note": (cal.diagnostics or {}).get("mirror_note", ""),
    }
