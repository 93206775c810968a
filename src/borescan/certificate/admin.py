"""The administrative part shared by three-sensor and rod certificates.

Statements, laboratory, items, measurement results, traceability, decision rule and conformity (DCC
element names).
"""

from __future__ import annotations

from typing import Any

from borescan.certificate.content import _UNITS_DSI, CERTIFICATE_FORMAT, PLACEHOLDER, _laboratory
from borescan.decision import CANNOT_DECIDE, CONFORMS, DOES_NOT_CONFORM, split_verdict


def _statements(lab: dict, dates: dict, conformity: dict, traceability: str) -> list[dict]:
    """Return the DCC statements of every certificate.

    DCC statements of every certificate: reproduction clause (ISO/IEC 17025 7.8.2.1 m), ``traceability``
    text, decision rule, conformity, recalibration due date (ISO date) and how the issue date was derived.
    """
    return [
        {
            "norm": "ISO/IEC 17025:2017",
            "reference": "7.8.2.1 m",
            "declaration": "The results relate only to the item calibrated. This certificate shall not "
            "be reproduced "
            "except in full without the written approval of the issuing laboratory.",
        },
        {"refType": "basic_traceability", "declaration": traceability},
        {"refType": "basic_decisionRule", "declaration": _decision_rule_text(lab)},
        {
            "refType": "basic_conformity",
            "conformity": conformity["conformity"],
            "declaration": conformity["text"],
        },
        {
            "refType": "basic_recalibration",
            "date": dates.get("recalibration_due"),
            "declaration": dates.get("recalibration_rule", ""),
        },
        {"refType": "borescan_issueDate", "declaration": dates.get("issue_rule", "")},
    ]


def _administrative_data(
    cal, lab: dict, dates: dict, conformity: dict, item: dict, traceability: str, software_version: str
) -> dict:
    """Return the DCC ``administrativeData``.

    DCC ``administrativeData``: software, core data (ISO dates of calibration and issue), the ``item``,
    laboratory, signatory, customer, statements and the laboratory settings left at their placeholders.
    """
    return {
        "dccSoftware": {"software": [{"name": "borescan", "release": software_version}]},
        "coreData": {
            "countryCodeISO3166_1": lab.get("country_code"),
            "usedLangCodeISO639_1": ["en"],
            "mandatoryLangCodeISO639_1": ["en"],
            "uniqueIdentifier": cal.calibration_id,
            "beginPerformanceDate": dates.get("begin"),
            "endPerformanceDate": dates.get("end"),
            "issueDate": dates.get("issue"),
            "performanceLocation": lab.get("performance_location"),
        },
        "items": [item],
        "calibrationLaboratory": {
            "contact": {"name": lab.get("name"), "location": {"further": lab.get("address")}},
            "accreditation": lab.get("accreditation"),
        },
        "respPersons": [
            {
                "person": {"name": lab.get("signatory")},
                "role": lab.get("signatory_function"),
                "mainSigner": True,
            }
        ],
        "customer": {"name": lab.get("customer")},
        "statements": _statements(lab, dates, conformity, traceability),
        "placeholders": sorted(k for k, v in lab.items() if isinstance(v, str) and PLACEHOLDER in v),
    }


def _shared_part(
    cal,
    *,
    item_name: str,
    item_id: Any,
    traceability: str,
    device: dict,
    artifact: dict,
    conditions: dict,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
    laboratory: dict | None,
    coverage_probability: float,
    dates: dict | None,
    verifications: list[dict] | None,
) -> dict:
    """Return the top-level keys every certificate has.

    Return the top-level keys every certificate has (three-sensor and rod): identification, coverage
    probability, ``administrativeData`` (the item ``item_name`` identified by ``item_id``, the
    ``traceability`` statement), device, artifact, conditions, verifications with the conformity,
    dates (ISO), laboratory, raw file digests (sha256 hex), software version and config hash.
    Not yet JSON-safe (:func:`_fixed`).
    """
    lab = _laboratory(laboratory)
    dates = dict(dates or {})
    ver = list(verifications or [])
    conformity = _conformity(ver)
    item = {
        "name": item_name,
        "identifications": [{"issuer": "customer", "value": item_id}],
        "sensors": device.get("sensors", []),
    }
    return {
        "format": CERTIFICATE_FORMAT,
        "calibration_id": cal.calibration_id,
        "device_id": cal.device_id,
        "method": cal.method,
        "scan_ids": list(cal.scan_ids),
        "coverage_probability": float(coverage_probability),
        "administrativeData": _administrative_data(
            cal, lab, dates, conformity, item, traceability, software_version
        ),
        "device": device,
        "artifact": artifact,
        "conditions": conditions,
        "verifications": ver,
        "conformity": conformity,
        "dates": dates,
        "laboratory": lab,
        "raw_files": dict(sorted(raw_files.items())),
        "software_version": software_version,
        "config_hash": config_hash,
    }


def _measurement_results(
    name: str,
    method: str,
    description: str,
    uncertainty_norm: str,
    equipment: list[dict],
    conditions: dict,
    results: list[dict],
    budgets: dict,
) -> list[dict]:
    """Return the DCC ``measurementResults``.

    DCC ``measurementResults``: one result set ``name`` with its method (``description``), the
    uncertainty evaluation's norm, the standards used, the influence conditions, results and budgets.
    """
    return [
        {
            "name": name,
            "usedMethods": [
                {"name": method, "description": description},
                {"name": "uncertainty", "norm": uncertainty_norm},
            ],
            "measuringEquipments": equipment,
            "influenceConditions": conditions,
            "results": results,
            "uncertaintyBudget": budgets,
        }
    ]


def _gauge_equipment(artifact: dict) -> dict:
    """Return the reference ring gauge as DCC measuring equipment (certified diameter [mm] with U and k)."""
    return {
        "refType": "basic_normalUsed",
        "name": "ring gauge",
        "id": artifact.get("id"),
        "certificate": artifact.get("certificate"),
        "issuer": artifact.get("certificate_issuer"),
        "validUntil": artifact.get("certificate_valid_until"),
        "certifiedDiameter": {
            "value": artifact.get("certified_diameter_mm"),
            "unit": _UNITS_DSI["mm"],
            "expandedUnc": {
                "uncertainty": artifact.get("u_diameter_mm"),
                "coverageFactor": artifact.get("k"),
                "coverageProbability": None,
                "distribution": "normal",
            },
        },
        "cte_per_k": artifact.get("cte_per_k"),
    }


def _traceability_text(art: dict) -> str:
    issuer = art.get("certificate_issuer")
    valid = art.get("certificate_valid_until")
    who = f"issued by {issuer}" if issuer else "issuer not stated in scan.json (artifact.certificate_issuer)"
    until = (
        f"valid until {valid}"
        if valid
        else "validity not stated in scan.json (artifact.certificate_valid_until)"
    )
    return (
        f"The results are traceable to the SI unit of length (the metre) through the reference ring gauge "
        f"{art.get('id')}, certificate {art.get('certificate')} ({who}; {until}), certified diameter "
        f"{art.get('certified_diameter_mm')} mm at 20 degC with U = {art.get('u_diameter_mm')} mm "
        f"(k = {art.get('k')})."
    )


def _standard_statement(lab: dict) -> str:
    """Return what the certificate says of ISO/IEC 17025.

    "issued in accordance with" only under an accreditation the config states (laboratory.accreditation); else
    its content follows 7.8 and no accreditation is claimed.
    """
    acc = str(lab.get("accreditation") or "")
    if not acc or acc.upper().startswith("PLACEHOLDER") or "no accreditation" in acc.lower():
        return (
            "The content of this certificate follows ISO/IEC 17025:2017 7.8; the laboratory claims no "
            "accreditation for it."
        )
    return f"This certificate is issued in accordance with ISO/IEC 17025:2017 7.8 ({acc})."


def _decision_rule_text(lab: dict) -> str:
    """Return the laboratory's decision rule (:mod:`borescan.decision`) in words.

    E is the error of the diameter at 20 degC, T the tolerance, w the guard band.
    """
    f = lab.get("guard_band_factor")
    tail = (
        "E the error of the diameter at 20 degC, U(E) its "
        "expanded uncertainty, T the tolerance. A result whose "
        "U(E) is not below T is never stated to conform."
    )
    if lab.get("decision_rule") in ("guard_band", "guarded_acceptance"):
        return (
            "Guarded acceptance (ILAC-G8:09/2019 4.2.2, ISO "
            f"14253-1): conforms when |E| <= T - w, w = {f} U(E); "
            f"does not conform when |E| > T; between, cannot decide (not accepted). " + tail
        )
    if lab.get("decision_rule") == "guarded_rejection":
        return (
            "Guarded rejection (ILAC-G8:09/2019 4.2.3, ISO "
            f"14253-1): does not conform when |E| > T + w, w = {f} "
            f"U(E); conforms when |E| <= T; between, cannot decide (not rejected). " + tail
        )
    return (
        "Simple acceptance (ILAC-G8:09/2019 4.2.1): conforms when |E| <= T (guard band w = 0), else does not "
        "conform; at the limit the probability of a false accept reaches 50 %. " + tail
    )


def _conformity(ver: list[dict]) -> dict:
    if not ver:
        return {
            "conformity": "noStatement",
            "text": "No verification scan of this device was taken in "
            "the calibration night: conformity is not stated.",
        }
    verdicts = [
        split_verdict(v.get("conformity"))[0] or (CONFORMS if v.get("passed") else DOES_NOT_CONFORM)
        for v in ver
    ]
    ok = all(bool(v.get("passed")) for v in ver)
    n_pass = sum(bool(v.get("passed")) for v in ver)
    counts = ", ".join(
        f"{verdicts.count(x)} {x}" for x in (CONFORMS, CANNOT_DECIDE, DOES_NOT_CONFORM) if x in verdicts
    )
    guard = sorted(
        {
            f"{_ver_name(v)}: U(E) {1e3 * v['expanded_u_error_mm']:.1f} um against T "
            f"{1e3 * v['tolerance_mm']:.1f} um"
            + (
                f", largest input {v['dominant_input']}, fixed by {v['dominant_fix']}"
                if v.get("dominant_fix")
                else ""
            )
            for v in ver
            if v.get("expanded_u_error_mm") is not None and v["expanded_u_error_mm"] >= v["tolerance_mm"]
        }
    )
    overall = (
        DOES_NOT_CONFORM
        if DOES_NOT_CONFORM in verdicts
        else CANNOT_DECIDE
        if CANNOT_DECIDE in verdicts
        else CONFORMS
    )
    head = (
        "Whether the device conforms to the verification tolerance cannot be decided"
        if overall == CANNOT_DECIDE
        else f"The device {overall.replace('does not', 'does NOT')} to the verification tolerance"
    )
    text = (
        f"{head} under the stated decision rule: of {len(ver)} "
        f"verifications on certified ring gauges {counts} "
        f"({n_pass} accepted by the rule)."
    )
    if guard:
        text += (
            " The expanded uncertainty is not below the tolerance ("
            + "; ".join(guard)
            + "): these verifications cannot show conformity."
        )
    # DCC conformity: a verdict that cannot decide is conditional, passed or not by the rule
    dcc = {CONFORMS: "pass", DOES_NOT_CONFORM: "fail"}.get(
        overall, "conditionalPass" if ok else "conditionalFail"
    )
    return {"conformity": dcc, "text": text}


def _ver_name(v: dict) -> str:
    """Return a verification's name in the certificate: its scan, and the layer's feature for a rod."""
    return f"{v.get('scan_id')}" + (
        f" layer {v['feature']} ({v.get('artifact_id')})" if v.get("feature") else ""
    )
