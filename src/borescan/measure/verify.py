"""Verification against certified gauges and part conformity with the decision rule; the stage rows.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
import numpy as np
from ..artifacts import artifact_key, number_or_none
from ..atomic import json_ready
from ..effects import thermal_expansion_factor
from ..decision import DECISION_RULES as _DECISION_RULES
from ..decision import decision
from ..uncertainty import Input, Term
from .budget import DiameterUncertainty
from .tri import tri_diameter_with_budget

__all__ = [
    "DECISION_RULES",
    "decide",
    "Verification",
    "verify",
    "part_feature",
    "part_conformity",
    "verify_budget",
    "diameter_row",
    "verification_row",
    "verification_for_certificate",
]


# --------------------------------------------------------------------------- verification

#: decision rules of a verification or a part (ILAC-G8:09/2019 §4.2; :mod:`borescan.decision`)
DECISION_RULES = tuple(_DECISION_RULES)


def decide(
    error_mm: float,
    U_mm: float,
    tolerance_mm: float,
    rule: str = "simple_acceptance",
    guard_band_factor: float = 1.0,
) -> tuple[bool, float, str]:
    """Return the verdict on |error| against the tolerance by a decision rule.

    ISO/IEC 17025 7.8.6, ILAC-G8:09/2019: :func:`borescan.decision.decision`, the one place of the rules.

    Returns
    -------
    (passed, acceptance limit [mm], statement)
        passed: the rule's binary decision; statement: verdict, numbers, rule and guard band.
    """
    d = decision(error_mm, U_mm, tolerance_mm, rule, guard_band_factor)
    return d.passed, d.acceptance_limit_mm, d.statement


@dataclass(frozen=True)
class Verification:
    """Result of :func:`verify` / :func:`verify_budget` (all lengths in mm).

    measured_mm : the measured diameter brought to 20 degC (ISO 1), comparable with the
    certificate; measured_at_t_mm : as measured at the scan's temperature; expected_at_t_mm :
    the gauge's size at that temperature; error_mm = measured_mm - certified_mm.
    """

    measured_mm: float
    u_measured_mm: float
    certified_mm: float
    expected_at_t_mm: float
    error_mm: float
    u_error_mm: float
    tolerance_mm: float
    passed: bool
    en: float
    measured_at_t_mm: float = float("nan")
    temperature_c: float = float("nan")
    U_error_mm: float = float("nan")
    k: float = float("nan")
    acceptance_limit_mm: float = float("nan")
    decision_rule: str = "simple_acceptance"
    conformity: str = ""
    budget_rows: tuple = ()


def verify(
    measured_mm,
    u_measured_mm,
    certified_diameter_mm,
    u_cert_mm,
    cte_per_k,
    temperature_c,
    tolerance_mm,
    decision_rule: str = "simple_acceptance",
    guard_band_factor: float = 1.0,
    k: float = 2.0,
) -> Verification:
    """Error of a measured diameter against a gauge's certified diameter, pass/fail.

    The certificate gives D20 at 20 degC. At temperature T the gauge has expanded to
    D_T = D20 (1 + cte (T - 20)) and a device reading at T measures D_T. The measured value is
    brought to 20 degC, measured_20 = measured / (1 + cte (T - 20)) (ISO 1), and
    error = measured_20 - D20, equal to (measured - D_T) / (1 + cte (T - 20)) (a gauge warmer than
    20 degC reads larger; without the correction that would show as a positive error).

    Parameters
    ----------
    u_cert_mm : standard (k = 1) uncertainty of the certified diameter; a certificate's
        expanded U with k = 2 must be divided by 2 by the caller.
    decision_rule, guard_band_factor : :func:`decide`, with U = k u_error.

    Returns
    -------
    Verification; en = error / (2 u_error) (E_n number, k = 2).
    """
    f = thermal_expansion_factor(float(cte_per_k), float(temperature_c))
    D_T = float(certified_diameter_mm) * f
    m20 = float(measured_mm) / f
    err = m20 - float(certified_diameter_mm)
    u_m20 = float(u_measured_mm) / f
    u_err = float(np.hypot(u_m20, u_cert_mm))
    passed, A, text = decide(err, k * u_err, tolerance_mm, decision_rule, guard_band_factor)
    return Verification(
        measured_mm=m20,
        u_measured_mm=u_m20,
        certified_mm=float(certified_diameter_mm),
        expected_at_t_mm=D_T,
        error_mm=err,
        u_error_mm=u_err,
        tolerance_mm=float(tolerance_mm),
        passed=passed,
        en=err / (2.0 * u_err) if u_err > 0 else float("inf") * np.sign(err),
        measured_at_t_mm=float(measured_mm),
        temperature_c=float(temperature_c),
        U_error_mm=k * u_err,
        k=k,
        acceptance_limit_mm=A,
        decision_rule=decision_rule,
        conformity=text,
    )


def only_feature_id(artifact: dict) -> str | None:
    """Return the id of the artifact's only feature (the bore a three-sensor scan measures), else None.

    None when scan.json lists no feature (a ring gauge) or several (the scan does not say which).
    """
    feats = [f for f in (artifact.get("features") or []) if isinstance(f, dict) and f.get("id") is not None]
    return str(feats[0]["id"]) if len(feats) == 1 else None


def part_feature(artifact: dict, feature: str | None) -> dict:
    """Return the scan.json feature a diameter belongs to.

    Return the scan.json feature a diameter belongs to: ``{"nominal_diameter_mm", "tolerance_mm"}`` (None
    where
    unknown).

    ``feature`` names one of ``artifact.features[].id``; a diameter without a feature (a three-sensor
    scan of one bore) belongs to the artifact's only feature, else to the artifact itself
    (``artifact.nominal_diameter_mm``). ``tolerance_mm`` is an optional field of a feature (or of the
    artifact) that this project reads beside the spec's: +- that many mm about the nominal.
    """
    feats = [f for f in (artifact.get("features") or []) if isinstance(f, dict)]
    if feature is not None:
        match = [f for f in feats if str(f.get("id")) == str(feature)]
    else:
        match = feats if len(feats) == 1 else []
    src = match[0] if match else (artifact if feature is None or not feats else {})

    nominal = number_or_none(src.get("nominal_diameter_mm"))
    if nominal is None and feature is None:
        nominal = number_or_none(artifact.get("nominal_diameter_mm"))
    return {
        "nominal_diameter_mm": nominal,
        "tolerance_mm": number_or_none(src.get("tolerance_mm"))
        or number_or_none(artifact.get("tolerance_mm")),
    }


def part_conformity(
    diameter_20_mm: float,
    U_mm: float,
    nominal_mm: float | None,
    tolerance_mm: float | None,
    rule: str = "simple_acceptance",
    guard_band_factor: float = 1.0,
) -> dict:
    """Return a part's diameter against its nominal and tolerance: deviation at 20 degC and the verdict.

    deviation = D20 - nominal; the verdict is :func:`borescan.decision.decision` on (deviation, U,
    tolerance) by the laboratory's decision rule: its short text, which starts with "conforms",
    "does not conform" or "cannot decide" and names U, T, the rule and its guard band; None without
    a nominal or a tolerance.

    Returns ``{"nominal_diameter_mm", "tolerance_mm", "deviation_mm", "conformity"}``.
    """
    dev = None if nominal_mm is None else float(diameter_20_mm) - float(nominal_mm)
    verdict = None
    if dev is not None and tolerance_mm is not None:
        verdict = decision(dev, float(U_mm), float(tolerance_mm), rule, guard_band_factor).short
    return {
        "nominal_diameter_mm": nominal_mm,
        "tolerance_mm": tolerance_mm,
        "deviation_mm": dev,
        "conformity": verdict,
    }


def verify_budget(
    d: DiameterUncertainty,
    artifact: dict,
    tolerance_mm: float,
    p: float,
    decision_rule: str = "simple_acceptance",
    guard_band_factor: float = 1.0,
) -> Verification:
    """Verification of a budgeted diameter against a ring gauge: E = D20 - D20_certified.

    The budget of E is that of D20 plus the gauge's certified diameter (sensitivity -1, normal,
    u = U / k of its certificate). Where the gauge is the one the calibration used (same id and
    certificate), its certified diameter and expansion coefficient are the same inputs and their
    sensitivities add (:meth:`Budget.merged`): the calibration transfers the gauge's size to the
    device, so the gauge's own uncertainty largely cancels in E. Verdict by :func:`decide` with
    U(E) = k u(E).
    """
    cert = float(artifact["certified_diameter_mm"])
    k_cert = float(artifact.get("k") or 2.0)
    u_cert = float(artifact.get("u_diameter_mm") or 0.0) / k_cert
    b = d.budget.mapped(np.array([[0.0, 1.0]]), ("E",), ("mm",), [d.diameter_20_mm - cert])
    b.add(
        Term(
            Input(
                f"gauge:{artifact_key(artifact)}:D20",
                f"certified diameter of ring gauge {artifact.get('id')} at 20 degC",
                "D_g",
                "mm",
                cert,
                u_cert,
                "normal",
                source=f"certificate {artifact.get('certificate')}: U = {artifact.get('u_diameter_mm')} "
                f"mm (k = {k_cert:g})",
            ),
            np.array([-1.0]),
        )
    )
    b = b.merged()
    comb = b.combined(0, p)
    err = d.diameter_20_mm - cert
    passed, A, text = decide(err, comb.U, tolerance_mm, decision_rule, guard_band_factor)
    f = thermal_expansion_factor(d.cte.cte_per_k, d.temperature.temperature_c)
    return Verification(
        measured_mm=d.diameter_20_mm,
        u_measured_mm=d.combined_20.u,
        certified_mm=cert,
        expected_at_t_mm=cert * f,
        error_mm=err,
        u_error_mm=comb.u,
        tolerance_mm=float(tolerance_mm),
        passed=passed,
        en=err / comb.U if comb.U > 0 else float("inf") * np.sign(err),
        measured_at_t_mm=d.diameter_mm,
        temperature_c=d.temperature.temperature_c,
        U_error_mm=comb.U,
        k=comb.k,
        acceptance_limit_mm=A,
        decision_rule=decision_rule,
        conformity=text,
        budget_rows=tuple(json_ready(b.rows(0))),
    )


def diameter_row(
    scan_id,
    device_id,
    artifact_id,
    feature,
    diameter_mm,
    u_diameter_mm,
    calibration_id,
    method,
    uncertainty: DiameterUncertainty | None = None,
) -> dict:
    """One row of the catalog's ``diameters`` table (outputs.md column names).

    ``diameter_mm`` is at the scan's temperature (``temperature_c``); with ``uncertainty`` the row
    also has the diameter at 20 degC, the correction, U, k and the budget (tables.py).
    """
    row = {
        "scan_id": str(scan_id),
        "device_id": str(device_id),
        "artifact_id": None if artifact_id is None else str(artifact_id),
        "feature": None if feature is None else str(feature),
        "diameter_mm": float(diameter_mm),
        "u_diameter_mm": float(u_diameter_mm),
        "calibration_id": None if calibration_id is None else str(calibration_id),
        "method": str(method),
    }
    if uncertainty is not None:
        row["u_diameter_mm"] = float(uncertainty.combined_t.u)
        row.update(uncertainty.columns())
    return row


def verification_row(scan_id, device_id, artifact_id, v: Verification) -> dict:
    """One row of the catalog's ``verifications`` table (outputs.md; extra columns allowed).

    ``measured_mm`` is the measured diameter at 20 degC, so measured_mm - certified_mm = error_mm;
    ``measured_at_t_mm`` is as measured at ``temperature_c``, where the gauge measured
    ``expected_at_t_mm``. ``dominant_input``: the key of the budget's largest contribution to u(E)
    (None without a budget); ``dominant_fix`` (what would reduce it) is the caller's to say, None here.
    """
    top = max(v.budget_rows or (), key=lambda b: abs(b.get("contribution") or 0.0), default=None)
    return {
        "scan_id": str(scan_id),
        "device_id": str(device_id),
        "artifact_id": str(artifact_id),
        "measured_mm": v.measured_mm,
        "certified_mm": v.certified_mm,
        "error_mm": v.error_mm,
        "tolerance_mm": v.tolerance_mm,
        "passed": v.passed,
        "u_measured_mm": v.u_measured_mm,
        "expected_at_t_mm": v.expected_at_t_mm,
        "u_error_mm": v.u_error_mm,
        "measured_at_t_mm": v.measured_at_t_mm,
        "temperature_c": v.temperature_c,
        "expanded_u_error_mm": v.U_error_mm,
        "k": v.k,
        "acceptance_limit_mm": v.acceptance_limit_mm,
        "decision_rule": v.decision_rule,
        "conformity": v.conformity,
        "budget_json": json.dumps(list(v.budget_rows), sort_keys=True) if v.budget_rows else None,
        "dominant_input": None if top is None else str(top["key"]),
        "dominant_fix": None,
    }


def verification_for_certificate(
    scan, cal, unc_cfg: dict, lab_cfg: dict, tolerance_mm: float, cleaning=None
) -> dict | None:
    """Return a verification scan measured with ``cal`` as a certificate row.

    Return a ring-gauge verification scan measured with ``cal`` and verified (:func:`verify_budget`),
    as a row for the calibration's certificate: the ``verifications`` columns plus the budget rows
    (``budget``), the gauge's ``certificate`` and the scan's ``raw_files`` (name -> SHA-256).
    None when the scan's artifact is not a certified ring gauge. ``cleaning``: the spike policy.
    """
    art = scan.meta.get("artifact") or {}
    if art.get("type") != "ring_gauge" or art.get("certified_diameter_mm") is None:
        return None
    _, du = tri_diameter_with_budget(scan, cal, unc_cfg, cleaning)
    v = verify_budget(
        du,
        art,
        tolerance_mm,
        float(unc_cfg["coverage_probability"]),
        lab_cfg["decision_rule"],
        float(lab_cfg["guard_band_factor"]),
    )
    row = verification_row(scan.scan_id, cal.device_id, art.get("id"), v)
    row.pop("budget_json", None)
    row.update(
        temperature_assumed=du.temperature.assumed,
        budget=list(v.budget_rows),
        certificate=art.get("certificate"),
        raw_files={f"{scan.scan_id}/{k}": h for k, h in sorted(scan.sha256.items())},
    )
    return row
