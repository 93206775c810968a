"""Calibration drift explained by the named effects of a pooled examination.

What a calibration that ignores a term puts into the beams (:func:`calibration_equivalent`) and
which flagged drift it explains (:func:`drift_explanations`).
"""

from __future__ import annotations

import numpy as np

from borescan.discrepancy.pooled.model import PooledModel
from borescan.discrepancy.pooled.terms import BASE_SCALE
from borescan.discrepancy.terms import Term
from borescan.discrepancy.tri import SCAN_KIND
from borescan.effects import EFFECTS

#: Registry base parameter -> column of the calibrations table.
_CAL_COLUMN = {"beta": "beta_rad", "rho": "rho_mm", "d_b": "d_b_mm"}


def calibration_equivalent(model: PooledModel, p: dict[str, float], terms: list[Term], t: Term) -> dict:
    """Return what a calibration that ignores term ``t`` would put into the beams, scan by scan.

    For each scan the term acts on, the term's signature (readings with every term less readings
    without ``t``) is fitted, linearised and weighted by the scan's noise floor, by changes of the
    beam parameters the registry says absorb the effect (``absorbed_by``: beta, d_b) on the term's
    channel (every channel for a common term) and of the scan's nuisance other than the centre (a
    calibration knows the centre and spindle position). Only those: rho, weakly determined, would
    otherwise trade with beta along a nearly flat valley. Returns, per scan id, those changes
    (``beta_rad``, ``d_b_mm``; one value, or one per channel for a common term) and
    ``absorbed_share``: the part of the signature's chi-square they take up (1 when the registry's
    absorption is exact in that scan, e.g. a delay at constant speed).
    """
    spec = EFFECTS[t.effect]
    pars = [b for b in spec.absorbers(SCAN_KIND) if b in _CAL_COLUMN]
    if not pars:
        return {}
    c = len(model.data.channels)
    js = list(range(c)) if t.channel in (None, 0) else [model.data.channels.index(int(t.channel))]
    others = [x for x in terms if x.key != t.key]
    out = {}
    prefixes = {"beta": "dbeta", "rho": "drho", "d_b": "dd_b"}
    for k in model.members(t):
        sid = model.scan_ids[k]
        m = model.models[k]
        q, own = model._scan_params(k, p, terms)
        q0, own0 = model._scan_params(k, p, others)
        sig = m.predict(q, own) - m.predict(q0, own0)
        w = 1.0 / model.scan_sigma[k]
        ok = model.mask[model._rows(k)] & np.isfinite(sig)
        # the beams of the absorbing parameters, and the scan's nuisance other than the centre
        names = [f"{prefixes[b]}[{j}]" for b in pars for j in js]
        nuis = [n for n in model._nuisance(k) if n not in ("cx", "cy")]
        f0 = m.predict(q0, own0)
        cols = []
        for n in names + nuis:
            key = "speed_error.eps" if n == "eps" else n
            h = BASE_SCALE[n.split("[")[0]] * 1e-2
            qq = dict(q0)
            qq[key] = qq.get(key, 0.0) + h
            cols.append((((m.predict(qq, own0) - f0) / h) * w)[ok])
        J = np.stack(cols, axis=1)
        y = (sig * w)[ok]
        coef = np.linalg.lstsq(J, y, rcond=None)[0]
        chi_sig = float(y @ y)
        res = y - J @ coef
        entry = {"absorbed_share": float(1.0 - (res @ res) / chi_sig) if chi_sig > 0 else 0.0}
        for b in pars:
            vals = [float(coef[names.index(f"{prefixes[b]}[{j}]")]) for j in js]
            entry[_CAL_COLUMN[b]] = vals[0] if len(vals) == 1 else vals
        out[sid] = entry
    return out


def drift_explanations(drift, findings: dict) -> list[dict]:
    """Whether a named effect of a pooled examination explains the flagged calibration drifts of its device.

    Parameters
    ----------
    drift : :func:`borescan.calibrations.calibration_drift` of the calibrations table (polars frame)
    findings : :attr:`PooledExamination.findings` of the device

    Returns
    -------
    list of dicts, one per flagged row of the device: the row's device_id, channel, parameter,
    calibration ids, change and u_combined, ``explained_by`` (the named terms the registry says that
    parameter absorbs on that channel; empty when none), ``equivalent_change`` (term -> scan ->
    the change a calibration ignoring the term would make, :func:`calibration_equivalent`) and
    ``explanation`` in words.
    """
    out = []
    col_par = {v: k for k, v in _CAL_COLUMN.items()}
    for row in drift.iter_rows(named=True):
        if not row["flagged"] or row["device_id"] != findings["device_id"]:
            continue
        par = col_par.get(row["parameter"])
        hits = []
        for n in findings["named"]:
            spec = EFFECTS.get(n["effect"])
            if spec is None or par not in spec.absorbers(SCAN_KIND):
                continue
            if n.get("channel") not in (None, row["channel"]):
                continue
            hits.append(n)
        eq = {
            n.get("term", n["effect"]): {
                sid: e.get(row["parameter"]) for sid, e in (n.get("calibration_equivalent") or {}).items()
            }
            for n in hits
        }
        change = (
            f"{row['parameter']} of channel {row['channel']} moved by {row['change']:+.4g} "
            f"({row['change_over_u']:+.1f} combined u) from {row['calibration_id_before']} "
            f"to {row['calibration_id_after']}"
        )
        if hits:
            words = "; ".join(
                f"{n.get('term', n['effect'])} is absorbed by {spec_text(n['effect'], par)}"
                + (
                    ": a calibration ignoring it moves it by "
                    + ", ".join(
                        f"{v:+.4g} ({sid})"
                        for sid, v in eq[n.get("term", n["effect"])].items()
                        if isinstance(v, float)
                    )
                    if eq[n.get("term", n["effect"])]
                    else ""
                )
                for n in hits
            )
            text = f"{change}; explained by the pooled examination: {words}"
        else:
            text = (
                f"{change}; no effect named by the pooled examination of {', '.join(findings['scan_ids'])} "
                "is absorbed by it"
            )
        out.append(
            {
                "device_id": row["device_id"],
                "channel": row["channel"],
                "parameter": row["parameter"],
                "calibration_id_before": row["calibration_id_before"],
                "calibration_id_after": row["calibration_id_after"],
                "change": row["change"],
                "u_combined": row["u_combined"],
                "explained_by": [n.get("term", n["effect"]) for n in hits],
                "equivalent_change": eq,
                "explanation": text,
            }
        )
    return out


def spec_text(effect: str, par: str) -> str:
    """Return the registry's words for the base parameter ``par`` absorbing ``effect`` in a spindle scan."""
    return EFFECTS[effect].absorbers(SCAN_KIND).get(par, par)
