"""Calibration certificates.

The documents are ``certificate.json``, ``certificate.pdf``, ``certificate.dcc.xml`` and ``residuals.png``.

Written into ``results_root/calibration/<device_id>/<calibration_id>/`` (``outputs.md``).

Content (ISO/IEC 17025:2017 7.8.2.1 and 7.8.4.1): title; issuing laboratory, its address and
accreditation statement; place of calibration; unique identification (the calibration id) and
"page x of y" on every page; customer; method; the item (device with its sensors as a table);
dates of calibration and of issue; conditions with their uncertainties; results with the
expanded uncertainty U, coverage factor k and coverage probability; the GUM uncertainty budget
(every input: estimate, standard uncertainty, distribution, degrees of freedom, sensitivity,
contribution); traceability (the reference gauge, its certificate, issuer and validity); the
night's verifications with the decision rule and the conformity statement; the recalibration
due date; the signatory. The laboratory's name, address, accreditation, customer and signatory
come from the config's ``laboratory`` section; its defaults are placeholders that say so.

``certificate.json`` carries the same content; its administrative and result parts use the
element names of the PTB Digital Calibration Certificate (DCC 3.x: ``administrativeData``,
``coreData``, ``uniqueIdentifier``, ``beginPerformanceDate``, ``calibrationLaboratory``,
``respPersons``, ``customer``, ``statements``, ``measurementResults``, ``usedMethods``,
``measuringEquipments``, ``influenceConditions``, ``results``; D-SI ``expandedUnc`` with
``uncertainty``, ``coverageFactor``, ``coverageProbability``, ``distribution``) where they exist.

Regenerating from the same inputs gives byte-identical files: JSON with sorted keys and floats
rounded to 12 significant digits; PDF without CreationDate/ModDate/Producer/Creator; PNG without
the Software key; figures built on fresh ``matplotlib.figure.Figure`` objects (no pyplot state).
The issue date is therefore not the wall clock: it is derived from the data (the last date on
which a scan of the calibration or of its verifications was taken), and the certificate says so.
"""

from __future__ import annotations

import datetime as _dt
import io
import json
import math
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from borescan.atomic import atomic_write_bytes, atomic_write_text
from borescan.calibrate.result import TriCalibration
from borescan.config import schema_default
from borescan.decision import CANNOT_DECIDE, CONFORMS, DOES_NOT_CONFORM, split_verdict
from borescan.certificate_dcc import write_dcc
from borescan.uncertainty import Budget, Combined, combine, round_uncertainty

__all__ = [
    "CERTIFICATE_FORMAT",
    "certificate_dir",
    "certificate_night_dir",
    "certificate_dict",
    "write_certificate",
    "PLACEHOLDER",
    "certificate_dates",
    "calibration_conditions",
    "write_rod_certificate",
    "write_certificate_files",
]

CERTIFICATE_FORMAT = "borescan-certificate/2"
#: text that marks a laboratory setting left at its default
PLACEHOLDER = "PLACEHOLDER"
_PDF_METADATA = {"Creator": None, "Producer": None, "CreationDate": None, "ModDate": None}
_RC = {"font.family": "DejaVu Sans", "font.size": 8, "svg.hashsalt": "borescan", "pdf.compression": 6}
_A4 = (8.27, 11.69)
_UNITS_DSI = {
    "mm": "\\milli\\metre",
    "rad": "\\radian",
    "degC": "\\degreecelsius",
    "K": "\\kelvin",
    "1/K": "\\kelvin\\tothe{-1}",
    "-": "\\one",
    "um": "\\micro\\metre",
}
_METHOD_TEXT = {
    "full_lsq": (
        "Full-data least-squares calibration (borescan fit_full_calibration): every reading of the "
        "ring-gauge "
        "spindle scans is fitted to the exact three-sensor forward model (Yang 2017 geometry; rotation "
        "angle from "
        "the spindle stream); free per beam: direction beta, offset rho and base length d_b; per scan "
        "the spindle "
        "offset, phase and speed; the reported centre and spindle position enter as priors within the "
        "machine's "
        "stated accuracy. Uncertainty evaluated by the GUM (JCGM 100:2008) law of propagation with "
        "sensitivities "
        "of the least-squares optimum; coverage factor from Welch-Satterthwaite where JCGM 101:2008 (GUM S1) "
        "validates it, else from the propagated distribution."
    ),
    "yang2017": (
        "Yang 2017 extrema method (Eq. 8-15): base length and offset of each beam from the mean "
        "extreme readings, "
        "beam angles from the feature points' timing. Uncertainty evaluated by the GUM (JCGM 100:2008) with "
        "sensitivities by central differences of the closed forms."
    ),
    "rod_gauge": (
        "Rod calibration on certified ring gauges (borescan.rod_calibration): the rod is turned by "
        "hand in ring "
        "gauges of certified diameter, one per layer; the joint rod solve (Wang 2017 Eq. 16 "
        "generalised: exact "
        "ray-cylinder readings, pose angles, hole centres and the rod axis deflection free) is "
        "repeated with each "
        "layer's base length l0 corrected by the gauge radius at its temperature minus the solved "
        "radius until "
        "they agree to 1e-7 mm or a thousandth of the radius uncertainty. Beam angle, offset and tilt "
        "of each layer stay at their design values (to first "
        "order a constant reading offset, which l0 absorbs). Uncertainty by the GUM (JCGM 100:2008) law of "
        "propagation: the solve's covariance, the gauges' certificates, temperature, expansion "
        "coefficient and "
        "the sensors' linearity and resolution."
    ),
}


def certificate_dir(results_root: Path | str, cal) -> Path:
    """Return the folder a certificate is read from.

    ``results_root/calibration/<device_id>/<calibration_id>`` (``outputs.md``): where a certificate
    is read (a link into the folder of the calibration's night, :func:`certificate_night_dir`).
    """
    return Path(results_root) / "calibration" / cal.device_id / cal.calibration_id


def certificate_night_dir(results_root: Path | str, cal, night: str) -> Path:
    """Return the folder the calibrate stage writes a certificate into.

    ``results_root/calibration/night=<night>/<device_id>/<calibration_id>``: where the calibrate
    stage writes a certificate (the night's folder is the rule's declared output).
    """
    return Path(results_root) / "calibration" / f"night={night}" / cal.device_id / cal.calibration_id


def certificate_dates(
    scan_metas: list[dict], verification_metas: list[dict], night: str, validity_days: int
) -> dict:
    """Dates of a certificate from its scans, never the clock (regeneration stays byte-identical).

    ``begin``/``end``: the UTC dates of the calibration scans' ``started_at`` (ISO 8601; a scan
    without a readable one counts as the night); ``issue``: the last date of any scan the
    certificate reports (calibration and verification scans); ``recalibration_due``: the night +
    ``calibration.validity_days``, the last night on which a measurement may use the calibration
    (:func:`borescan.calibrations.choose_calibration`). ``issue_rule`` and ``recalibration_rule``
    say so in words, for the certificate.
    """

    def day(meta: dict) -> str:
        try:
            t = _dt.datetime.fromisoformat(str(meta.get("started_at")).replace("Z", "+00:00"))
        except ValueError:
            return night
        return (t.astimezone(_dt.timezone.utc) if t.tzinfo is not None else t).date().isoformat()

    cal_days = sorted(day(m) for m in scan_metas) or [night]
    all_days = sorted(cal_days + [day(m) for m in verification_metas])
    due = (_dt.date.fromisoformat(night) + _dt.timedelta(days=int(validity_days))).isoformat()
    return {
        "begin": cal_days[0],
        "end": cal_days[-1],
        "issue": all_days[-1],
        "night": night,
        "issue_rule": "derived from the data, not the clock: the last UTC date on which a scan "
        "reported here was "
        "taken (scan.json started_at), so that regenerating the certificate gives the same bytes",
        "recalibration_due": due,
        "recalibration_rule": f"night {night} + calibration.validity_days = {int(validity_days)} days; "
        "after it the "
        "pipeline refuses the calibration for measurements",
    }


def calibration_conditions(
    temperature, cte, radius_mm: float, position_accuracy_mm: float, p: float, scans: list[dict]
) -> dict:
    """Return the influence conditions of a certificate.

    Return the influence conditions of a certificate: the gauge's temperature with its uncertainty (U
    for the coverage probability ``p``) and source, its expansion coefficient, its radius at that
    temperature, the machine's stated position accuracy and per scan ``scans`` (positions, speed,
    revolutions). ``temperature``/``cte``: :class:`borescan.artifacts.ScanTemperature` / ``ArtifactCte``.
    """
    t_comb = combine([(temperature.u_c, float("inf"), "rectangular")], p)
    return {
        "temperature": {
            "value_c": temperature.temperature_c,
            "u_c": temperature.u_c,
            "U_c": t_comb.U,
            "k": t_comb.k,
            "halfwidth_c": temperature.halfwidth_c,
            "distribution": "rectangular",
            "assumed": temperature.assumed,
            "source": temperature.source,
            "refType": "basic_temperature",
        },
        "gauge_cte": {
            "value_per_k": cte.cte_per_k,
            "u_per_k": cte.u_per_k,
            "halfwidth_per_k": cte.halfwidth_per_k,
            "assumed": cte.assumed,
            "source": cte.source,
        },
        "gauge_radius_at_temperature_mm": radius_mm,
        "position_accuracy_mm": position_accuracy_mm,
        "scans": scans,
    }


def _fixed(x: Any) -> Any:
    """JSON-safe copy with floats rounded to 12 significant digits (NaN/inf -> None)."""
    if isinstance(x, dict):
        return {str(k): _fixed(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_fixed(v) for v in x]
    if isinstance(x, np.ndarray):
        return _fixed(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return float(f"{x:.12g}") if np.isfinite(x) else None
    return x


def _residual_arrays(residuals: dict) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(residuals["t_s"], dtype=float)
    res = np.asarray(residuals["residual_mm"], dtype=float)
    if res.ndim == 1:
        res = res[:, None]
    if res.shape[0] != t.size:
        raise ValueError(f"residuals: t_s has {t.size} samples, residual_mm {res.shape[0]}")
    return t, res


def _laboratory(laboratory: dict | None) -> dict:
    if laboratory is not None:
        return dict(laboratory)
    from borescan.config import schema_defaults

    return schema_defaults()["laboratory"]


def _budget_of(cal: TriCalibration, budget: Budget | None) -> Budget | None:
    if budget is not None:
        return budget
    d = (cal.diagnostics or {}).get("budget")
    return Budget.from_dict(d) if d else None


def _held(cal: TriCalibration, i: int) -> bool:
    """Parameter i is held at its design value (the gauge freedom): no variance at all."""
    return bool(cal.cov[i, i] == 0.0)


def _combined(cal: TriCalibration, budget: Budget | None, i: int, p: float) -> Combined:
    if budget is not None:
        return budget.combined(i, p)
    return combine([(math.sqrt(max(cal.cov[i, i], 0.0)), float("inf"), "normal")], p)


def _parameter_rows(cal: TriCalibration, budget: Budget | None, p: float) -> list[dict]:
    b = cal.beams
    rows = []
    for j, ch in enumerate(b.channels):
        row: dict[str, Any] = {"channel": int(ch)}
        for k, name in enumerate(("beta_rad", "rho_mm", "d_b_mm")):
            i = 3 * j + k
            comb = _combined(cal, budget, i, p)
            short = name.rsplit("_", 1)[0]
            row[name] = cal.params[i]
            row[f"u_{name}"] = comb.u
            row[f"U_{name}"] = comb.U
            row[f"k_{short}"] = comb.k
            row[f"nu_eff_{short}"] = comb.nu_eff
            row[f"held_{short}"] = _held(cal, i)
        rows.append(row)
    return rows


def _expanded(comb: Combined, distribution: str = "normal") -> dict:
    return {
        "uncertainty": comb.U,
        "coverageFactor": comb.k,
        "coverageProbability": comb.p,
        "distribution": distribution,
        "standardUncertainty": comb.u,
        "effectiveDegreesOfFreedom": comb.nu_eff,
        "coverageMethod": comb.method,
    }


def _result(name: str, ref_type: str, held: bool, value: float, unit: str, comb: Combined) -> dict:
    """Return one DCC result with its expanded uncertainty.

    One DCC result: ``value`` in ``unit`` (a key of ``_UNITS_DSI``: mm, rad, ...) with its D-SI
    expandedUnc.
    """
    return {
        "name": name,
        "refType": ref_type,
        "held_at_design_value": held,
        "real": {"value": value, "unit": _UNITS_DSI[unit], "expandedUnc": _expanded(comb)},
    }


def _budget_entry(unit: str, rows: list[dict], comb: Combined) -> dict:
    """Return one result's uncertainty budget.

    One result's uncertainty budget: its ``unit``, the budget rows (contributions in that unit)
    and their combination (u_c, k, U).
    """
    return {"unit": unit, "rows": rows, "combined": comb.to_dict()}


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
                "value_mm": float(cal.beams.d_b_mm[j]) + rho**2 / (2.0 * float(R)),
                "expandedUnc": _expanded(budget.combined(vec, p)),
            }
        )
    return rows


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


# --------------------------------------------------------------------------- PDF layout


def _wrap(text: str, width: int) -> list[str]:
    out = []
    for para in str(text).split("\n"):
        out.extend(textwrap.wrap(para, width) or [""])
    return out


class _Doc:
    """A4 pages with a running header/footer stamped at the end (page x of y)."""

    TOP, BOTTOM, LEFT, RIGHT = 0.885, 0.075, 0.06, 0.94

    def __init__(self, cert: dict):
        self.cert = cert
        self.pages: list[Figure] = []
        self.new_page()

    def new_page(self) -> None:
        self.fig = Figure(figsize=_A4)
        self.pages.append(self.fig)
        self.y = self.TOP

    def room(self, h: float) -> None:
        if self.y - h < self.BOTTOM:
            self.new_page()

    def heading(self, text: str, size: float = 10.5) -> None:
        self.room(0.05)
        self.y -= 0.008
        self.fig.text(self.LEFT, self.y, text, fontsize=size, weight="bold")
        self.y -= 0.02

    def para(
        self,
        text: str,
        size: float = 7.5,
        width: int = 120,
        indent: float = 0.0,
        style: str = "normal",
        color: str = "black",
    ) -> None:
        for line in _wrap(text, width):
            self.room(0.014)
            self.fig.text(self.LEFT + indent, self.y, line, fontsize=size, style=style, color=color)
            self.y -= 0.0125 * size / 7.5
        self.y -= 0.004

    def kv(
        self, rows: list[tuple[str, str]], key_w: float = 0.23, width: int = 92, size: float = 7.5
    ) -> None:
        for key, val in rows:
            lines = _wrap(val, width)
            self.room(0.0135 * len(lines))
            self.fig.text(self.LEFT, self.y, key, fontsize=size, weight="bold")
            for line in lines:
                self.fig.text(self.LEFT + key_w, self.y, line, fontsize=size)
                self.y -= 0.0135
            self.y -= 0.002

    def table(
        self,
        cols: list[str],
        cells: list[list[str]],
        widths: list[float] | None = None,
        size: float = 6.5,
        row_h: float = 0.0145,
        bold_last: bool = False,
    ) -> None:
        n = len(cells) + 1
        h = row_h * n
        self.room(h + 0.01)
        ax = self.fig.add_axes([self.LEFT, self.y - h, self.RIGHT - self.LEFT, h])
        ax.axis("off")
        tab = ax.table(cellText=cells, colLabels=cols, colWidths=widths, bbox=[0, 0, 1, 1], cellLoc="center")
        tab.auto_set_font_size(False)
        tab.set_fontsize(size)
        for (r, _c), cell in tab.get_celld().items():
            cell.set_linewidth(0.4)
            if r == 0:
                cell.set_facecolor("#e8e8e8")
                cell.get_text().set_weight("bold")
            if bold_last and r == n - 1:
                cell.get_text().set_weight("bold")
        self.y -= h + 0.012

    def finish(self) -> list[Figure]:
        c = self.cert
        lab = c["laboratory"]
        n = len(self.pages)
        for i, fig in enumerate(self.pages):
            fig.text(self.LEFT, 0.962, str(lab.get("name")), fontsize=10, weight="bold")
            fig.text(self.LEFT, 0.948, str(lab.get("address")), fontsize=7)
            fig.text(self.LEFT, 0.936, str(lab.get("accreditation")), fontsize=6.5, style="italic")
            fig.text(self.RIGHT, 0.962, "Calibration certificate", fontsize=10, weight="bold", ha="right")
            fig.text(
                self.RIGHT,
                0.948,
                f"No. {c['administrativeData']['coreData']['uniqueIdentifier']}",
                fontsize=7.5,
                ha="right",
            )
            fig.text(self.RIGHT, 0.936, f"Page {i + 1} of {n}", fontsize=7.5, ha="right", weight="bold")
            fig.add_artist(_hline(fig, 0.928))
            fig.add_artist(_hline(fig, 0.058))
            fig.text(
                self.LEFT,
                0.046,
                "The results relate only to the item calibrated. This certificate shall not be "
                "reproduced except in full without the written approval of the issuing laboratory.",
                fontsize=6,
            )
            fig.text(
                self.LEFT,
                0.034,
                f"Issued {c['dates'].get('issue') or 'n/a'} by borescan {c['software_version']} "
                f"(config {c['config_hash']}); machine-readable copy: certificate.json",
                fontsize=6,
            )
            fig.text(self.RIGHT, 0.034, f"Page {i + 1} of {n}", fontsize=6, ha="right")
        return self.pages


def _hline(fig: Figure, y: float):
    from matplotlib.lines import Line2D

    return Line2D([_Doc.LEFT, _Doc.RIGHT], [y, y], transform=fig.transFigure, color="0.3", lw=0.6)


def _num(x: Any, spec: str, none: str = "n/a") -> str:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return none if x is None else str(x)
    return format(x, spec) if np.isfinite(x) else none


def _scaled(x: Any, scale: float) -> float | None:
    return None if x is None else float(x) * scale


def _ppm(x: Any) -> str:
    try:
        return f"{float(x) * 1e6:.3g} x 10^-6 /K"
    except (TypeError, ValueError):
        return "n/a"


def _vu(value: float, U: float, scale: float = 1.0) -> tuple[str, str]:
    """Value and U (2 significant digits, rounded up) with the same decimals, both times ``scale``."""
    Ur, dec = round_uncertainty(U * scale)
    d = max(dec, 0)
    return f"{value * scale:.{d}f}", f"{Ur:.{d}f}"


def _u_text(u: Any, unit: str) -> str:
    if u is None:
        return "(vector)"
    u = float(u)
    if unit == "degC":
        return f"{u:.3g} K"
    if unit == "mm":
        return f"{u * 1e3:.3g} um"
    if unit == "rad":
        return f"{u * 1e3:.3g} mrad"
    if unit == "1/K":
        return f"{u * 1e6:.2g}e-6 /K"
    return f"{u:.3g} {unit}"


def _est_text(x: Any, unit: str) -> str:
    if x is None:
        return "-"
    x = float(x)
    if unit == "1/K":
        return f"{x * 1e6:.3g}e-6 /K"
    if unit == "degC":
        return f"{x:.2f} degC"
    if unit == "mm":
        return f"{x:.4f} mm" if abs(x) >= 1 else f"{x * 1e3:.2f} um"
    return f"{x:.4g} {unit}"


_DIST = {
    "normal": "normal",
    "rectangular": "rect.",
    "triangular": "triang.",
    "arcsine": "U-shaped",
    "multivariate normal": "normal (vec.)",
}


def _dof_text(nu: Any) -> str:
    if nu is None:
        return "inf"
    nu = float(nu)
    return "inf" if not np.isfinite(nu) or nu > 1e5 else f"{nu:.0f}"


def _short_quantity(row: dict) -> str:
    q = row["quantity"]
    return q if len(q) <= 52 else q[:50] + ".."


def _page_admin(d: _Doc) -> None:
    c = d.cert
    lab, dates, dev = c["laboratory"], c["dates"], c["device"]
    d.fig.text(d.LEFT, d.y - 0.01, "Calibration certificate", fontsize=18, weight="bold")
    d.y -= 0.035
    d.fig.text(
        d.LEFT,
        d.y,
        f"Certificate number {c['administrativeData']['coreData']['uniqueIdentifier']}",
        fontsize=10,
    )
    d.y -= 0.03
    if c["administrativeData"]["placeholders"]:
        d.para(
            "NOTE: the laboratory settings "
            + ", ".join(c["administrativeData"]["placeholders"])
            + " are the "
            "defaults of workflow/schemas/config.schema.yaml, placeholders that name no real "
            "laboratory. Set the "
            "laboratory section of config/config.yaml before issuing this certificate to anyone.",
            color="firebrick",
            size=7.5,
        )
    sensors = dev.get("sensors") or []
    flags = []
    cond = c["conditions"]
    if (cond.get("temperature") or {}).get("assumed"):
        flags.append(
            "the gauge temperature was not recorded; 20 degC was ASSUMED with a wider uncertainty "
            "(uncertainty.missing_temperature)"
        )
    if (cond.get("gauge_cte") or {}).get("assumed"):
        flags.append(
            "the gauge's expansion coefficient was not stated; an assumed value with a wide bound was used"
        )
    d.kv(
        [
            ("Issuing laboratory", f"{lab.get('name')}, {lab.get('address')}"),
            ("Accreditation", str(lab.get("accreditation"))),
            ("Customer", str(lab.get("customer"))),
            (
                "Item calibrated",
                f"{c.get('item', 'three-sensor bore measuring device')} {dev.get('id', c['device_id'])} "
                f"(type {dev.get('type', 'tri_lds')}) with {len(sensors)} laser displacement sensors "
                "(table on page 2)",
            ),
            ("Place of calibration", str(lab.get("performance_location"))),
            ("Date(s) of calibration", _date_range(dates)),
            ("Date of issue", f"{dates.get('issue') or 'n/a'} ({dates.get('issue_rule', 'not stated')})"),
            *(
                [("Replaces", c["reissue"]["declaration"])]
                if (c.get("reissue") or {}).get("replaces")
                else []
            ),
            (
                "Recalibration due",
                f"{dates.get('recalibration_due') or 'n/a'} ({dates.get('recalibration_rule', '')})",
            ),
            ("Method", _METHOD_TEXT.get(c["method"], c["method"])),
            ("Calibration scans", ", ".join(c["scan_ids"])),
            ("Deviations from the method", "; ".join(flags) if flags else "none"),
            (
                "Traceability",
                c.get("traceability_summary")
                or f"reference ring gauge {c['artifact'].get('id')}, certificate "
                f"{c['artifact'].get('certificate')} (section 4)",
            ),
            ("Decision rule", _decision_rule_text(lab) + " (section 7)"),
            ("Conformity", c["conformity"]["text"]),
            (
                "Measurement uncertainty",
                f"Expanded uncertainties U = k u_c with a coverage probability of "
                f"{100 * c['coverage_probability']:.2f} % (about 95 %); k per result (page 3). "
                "Evaluated according to JCGM 100:2008 (GUM) and JCGM 101:2008 (GUM S1); the "
                "budget is on the following pages and in certificate.json.",
            ),
        ]
    )
    d.y -= 0.01
    d.para(
        _standard_statement(lab)
        + " The results relate only to the item calibrated, at the time of calibration. "
        "The user is responsible for arranging recalibration in due time."
    )
    d.y -= 0.03
    d.room(0.09)
    d.fig.text(d.LEFT, d.y, "Authorised signatory", fontsize=8, weight="bold")
    d.fig.text(0.55, d.y, "Date of issue", fontsize=8, weight="bold")
    d.y -= 0.045
    d.fig.add_artist(_line(d.fig, d.LEFT, 0.45, d.y))
    d.fig.add_artist(_line(d.fig, 0.55, 0.80, d.y))
    d.y -= 0.015
    d.fig.text(0.55, d.y, str(dates.get("issue") or "n/a"), fontsize=7.5)
    for line in _wrap(str(lab.get("signatory")), 60) + _wrap(str(lab.get("signatory_function")), 60):
        d.fig.text(d.LEFT, d.y, line, fontsize=7.5)
        d.y -= 0.013
    d.y -= 0.01


def _line(fig: Figure, x0: float, x1: float, y: float):
    from matplotlib.lines import Line2D

    return Line2D([x0, x1], [y, y], transform=fig.transFigure, color="black", lw=0.6)


def _date_range(dates: dict) -> str:
    b, e = dates.get("begin"), dates.get("end")
    if not b:
        return "n/a"
    return b if b == e or not e else f"{b} to {e}"


def _page_item_conditions(d: _Doc) -> None:
    c = d.cert
    dev = c["device"]
    d.new_page()
    d.heading("1  Item calibrated")
    _sensor_table(d, dev, c["device_id"])
    _page_conditions_traceability(d)


def _sensor_table(d: _Doc, dev: dict, device_id: str) -> None:
    """Write the device's sensors as recorded in scan.json, as a table."""
    d.para(
        f"Device {dev.get('id', device_id)}, type {dev.get('type', 'tri_lds')}; sensors as recorded in "
        "scan.json:"
    )
    cols = [
        "channel",
        "model",
        "serial",
        "range [mm]",
        "linearity [% FS]",
        "linearity +- [um]",
        "repeatab. [um]",
        "resolution [um]",
    ]
    cells = []
    for s in dev.get("sensors") or []:
        lin = s.get("linearity_fs")
        rng = s.get("range_mm")
        lin_um = lin * rng * 1e3 if lin is not None and rng is not None else None
        cells.append(
            [
                str(s.get("channel")),
                str(s.get("model", "")),
                str(s.get("serial", "")),
                _num(rng, "g"),
                _num(None if lin is None else 100 * lin, "g"),
                _num(lin_um, ".1f"),
                _num(None if s.get("repeatability_mm") is None else 1e3 * s["repeatability_mm"], "g"),
                _num(
                    None if s.get("resolution_mm") is None else 1e3 * s["resolution_mm"],
                    "g",
                    none="not stated",
                ),
            ]
        )
    if cells:
        d.table(cols, cells, widths=[0.08, 0.13, 0.15, 0.1, 0.13, 0.14, 0.12, 0.15], size=6.8)


def _page_conditions_traceability(d: _Doc) -> None:
    c = d.cert
    art, cond = c["artifact"], c["conditions"]
    d.heading("2  Method")
    d.para(_METHOD_TEXT.get(c["method"], c["method"]))
    fit = c["fit"]
    if fit.get("gauge"):
        d.para("Reference direction: " + fit["gauge"] + ".")
    if fit.get("device_model"):
        d.para(device_model_text(fit["device_model"]))
    d.heading("3  Conditions of calibration")
    temp = cond.get("temperature") or {}
    cte = cond.get("gauge_cte") or {}
    rows = [
        (
            "Gauge temperature",
            (
                f"{_num(temp.get('value_c'), '.2f')} degC, standard uncertainty "
                f"{_num(temp.get('u_c'), '.3f')} K, U = {_num(temp.get('U_c'), '.3f')} K "
                f"(k = {_num(temp.get('k'), '.2f')}, p = {100 * c['coverage_probability']:.2f} %); "
                f"{temp.get('source', 'not stated')}"
            )
            if temp
            else "not recorded",
        )
    ]
    if cte:
        rows.append(
            (
                "Gauge expansion coeff.",
                f"{_ppm(cte.get('value_per_k'))} +- {_ppm(cte.get('halfwidth_per_k'))} "
                f"(rectangular); {cte.get('source', '')}",
            )
        )
    if cond.get("gauge_radius_at_temperature_mm") is not None:
        rows.append(
            (
                "Gauge radius at T",
                f"{_num(cond['gauge_radius_at_temperature_mm'], '.5f')} mm "
                "(R = D20/2 (1 + alpha (T - 20 degC)))",
            )
        )
    for sc in cond.get("scans") or []:
        pos = sc.get("spindle_position") or {}
        cen = sc.get("center") or {}
        acc = cond.get("position_accuracy_mm")
        acc_t = f" (each coordinate +-{_num(1e3 * acc, 'g')} um, machine's stated accuracy)" if acc else ""
        rows.append(
            (
                "Calibration scan",
                f"{sc.get('scan_id')}: spindle at ({_num(pos.get('x_mm'), '.3f')}, "
                f"{_num(pos.get('y_mm'), '.3f')}) mm, gauge centre "
                f"({_num(cen.get('x_mm'), '.3f')}, {_num(cen.get('y_mm'), '.3f')}) mm{acc_t}; "
                f"{_num(sc.get('rpm'), '.1f')} rpm ({sc.get('angle_source', '')}); "
                f"{_num(sc.get('revolutions_recorded'), '.1f')} revolutions recorded, "
                f"{sc.get('revolutions_with_extrema', 'n/a')} complete with both extrema per channel",
            )
        )
    rows.append(
        (
            "Other conditions",
            "humidity, pressure and vibration are not recorded in scan.json; they enter no result",
        )
    )
    d.kv(rows, key_w=0.21, width=96)
    d.heading("4  Traceability")
    d.para(_traceability_text(art))
    issuer = art.get("certificate_issuer")
    valid = art.get("certificate_valid_until")
    chain = [
        ("Reference standard", f"ring gauge {art.get('id')}"),
        (
            "Its certificate",
            f"{art.get('certificate')}, "
            + (
                f"issued by {issuer}"
                if issuer
                else "issuer NOT STATED (scan.json artifact.certificate_issuer)"
            ),
        ),
        ("Valid until", str(valid or "NOT STATED (scan.json artifact.certificate_valid_until)")),
        (
            "Certified diameter",
            f"{_num(art.get('certified_diameter_mm'), '.4f')} mm at 20 degC, U = "
            f"{_num(_scaled(art.get('u_diameter_mm'), 1e3), 'g')} um "
            f"(k = {art.get('k')})",
        ),
    ]
    if valid and c["dates"].get("end") and str(valid) < str(c["dates"]["end"]):
        chain.append(
            (
                "WARNING",
                f"the gauge certificate expired on {valid}, before this calibration: traceability is "
                "not established",
            )
        )
    d.kv(chain, key_w=0.21, width=96)


def _page_results(d: _Doc) -> None:
    c = d.cert
    p = c["coverage_probability"]
    d.new_page()
    d.heading("5  Results")
    d.para(
        "Calibrated beam geometry per channel: direction beta of the beam, its offset rho from the "
        "rotation axis "
        "and its base length d_b (the distance from the foot point to the sensor's measuring start). "
        "Expanded "
        f"uncertainty U = k u_c for a coverage probability of {100 * p:.2f} %; k from the effective "
        "degrees of "
        "freedom (Welch-Satterthwaite) where the GUM S1 check validates it, else from the propagated "
        "distribution."
    )
    cols = ["channel", "quantity", "value", "U", "unit", "k", "nu_eff", "dominant input"]
    cells = []
    results = {r["name"]: r for r in c["measurementResults"][0]["results"]}
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    for prow in c["parameters"]:
        ch = prow["channel"]
        for name, unit, label in (
            ("beta_rad", "rad", "beta"),
            ("rho_mm", "mm", "rho"),
            ("d_b_mm", "mm", "d_b"),
        ):
            key = f"{name}[{ch}]"
            r = results[key]
            eu = r["real"]["expandedUnc"]
            if r["held_at_design_value"]:
                cells.append(
                    [
                        str(ch),
                        label,
                        _num(r["real"]["value"], ".6f"),
                        "held",
                        unit,
                        "-",
                        "-",
                        "reference direction (held at design value)",
                    ]
                )
                continue
            v, U = _vu(r["real"]["value"], eu["uncertainty"])
            dom = (budgets.get(key, {}).get("combined") or {}).get("dominant_input", "")
            cells.append(
                [
                    str(ch),
                    label,
                    v,
                    U,
                    unit,
                    _num(eu["coverageFactor"], ".2f"),
                    _dof_text(eu["effectiveDegreesOfFreedom"]),
                    _dominant_label(dom),
                ]
            )
    d.table(cols, cells, widths=[0.07, 0.08, 0.14, 0.1, 0.05, 0.06, 0.08, 0.42], size=7)
    fit = c["fit"]
    if c.get("effective_base_length"):
        g = "; ".join(
            f"channel {r['channel']}: "
            + " +- ".join(_vu(r["value_mm"], r["expandedUnc"]["uncertainty"]))
            + " mm"
            f" (k = {r['expandedUnc']['coverageFactor']:.2f})"
            for r in c["effective_base_length"]
        )
        d.para(
            "Effective base length g = d_b + rho^2/(2R) (R the gauge radius at its temperature), the "
            "combination the "
            f"data fix best, with U: {g}. rho and d_b of a channel are correlated; certificate.json "
            "gives the full "
            "covariance (combined and of the fit alone) and the correlation matrix."
        )
    acc = fit.get("acceptance")
    d.para(
        f"Fit: residual rms {_num(_scaled(fit.get('residual_rms_mm'), 1e3), '.2f')} um, "
        f"{_num(fit.get('n_obs'), 'g')} readings, {fit.get('dof')} degrees of freedom, Jacobian rank "
        f"{fit.get('rank')}, "
        f"condition {_num(fit.get('condition'), '.3g')}; the optimiser "
        f"{'converged' if fit.get('converged') else 'did NOT converge'}."
    )
    if acc:
        d.para(
            f"Acceptance: largest ratio of a channel's residual rms to its readings' own noise floor "
            f"{_num(acc.get('residual_to_noise_max'), '.3f')} (limit "
            f"{_num(acc.get('max_residual_to_noise'), 'g')}); "
            f"|rho| within the head radius {_num(acc.get('head_radius_mm'), 'g')} mm."
        )
    if fit.get("weak_rho_channels"):
        d.para(
            f"Channels {fit['weak_rho_channels']}: |rho| < 2 u(rho), rho is not distinguished from 0; "
            "U(d_b) of "
            "these channels includes the second-order term of d_b = g - rho^2/(2R)."
        )
    if fit.get("rho_profiled_channels"):
        d.para(
            f"Channels {fit['rho_profiled_channels']}: the cost along rho is not the linear one (rho "
            "enters the "
            "readings mostly through rho^2); their uncertainties come from the profile of the cost "
            "along rho, "
            "every other parameter refitted, not from the linearisation alone."
        )
    _rho_sign_paragraphs(d, c)


def _rho_sign_paragraphs(d: _Doc, c: dict) -> None:
    """Return section 5 of the certificate: each beam's mirror check (certificate.json ``rho_sign``).

    The flagged beams' statement, both solutions, the bore range and the fix; one line for the resolved ones.
    """
    rs = c.get("rho_sign") or {}
    checks = rs.get("beams") or []
    if not checks:
        return
    flagged = [m for m in checks if not m["resolved"]]
    resolved = [str(m["channel"]) for m in checks if m["resolved"]]
    if resolved:
        d.para(
            f"Sign of rho resolved for channel(s) {', '.join(resolved)} (no mirror solution, or one at least "
            f"{rs['resolved_delta_chi2']:g} in chi^2 above the "
            "solution): their uncertainties are the fit's own."
        )
    for m in flagged:
        d.para(m["statement"].replace("the sign", "The sign", 1) + ".")
        alt = m["alternative"]
        u_main = m["u_main"]
        d.para(
            f"Channel {m['channel']}, solution 1 (weight "
            f"{m['weight_main']:.4f}): beta {u_main['beta_rad']:.6f} rad, "
            f"rho {u_main['rho_mm']:+.4f} mm, d_b {u_main['d_b_mm']:.4f} "
            f"mm; solution 2 (weight {alt['weight']:.4f}, "
            f"delta chi^2 {alt['delta_chi2']:.2f}): beta "
            f"{alt['beta_rad']:.6f} rad, rho {alt['rho_mm']:+.4f} mm, "
            f"d_b {alt['d_b_mm']:.4f} mm. Both solutions' covariances are in certificate.json (rho_sign). "
            "A diameter measured with this calibration carries both (Monte Carlo, JCGM 101) and is refused "
            "outside the bore range above."
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


def _dominant_label(key: str) -> str:
    if not key:
        return ""
    kind = key.split(":", 1)[0]
    labels = {
        "fit": "fit to the readings (Type A)",
        "linearity": "sensor linearity",
        "resolution": "sensor resolution",
        "gauge": "reference gauge",
        "temperature": "temperature",
        "cte": "expansion coefficient",
        "position": "reported positions",
        "readings": "readings",
    }
    tail = key.rsplit(":", 1)[-1]
    return labels.get(kind, kind) + (f" ({tail})" if kind in ("linearity", "resolution") else "")


def _short_id(x: str, n: int = 16) -> str:
    return x if len(x) <= n else ".." + x[-(n - 2) :]


def _label(row: dict) -> str:
    """Short name of a budget row for the PDF tables (the full one is in certificate.json)."""
    key = str(row.get("key", ""))
    kind, _, rest = key.partition(":")
    tail = key.rsplit(":", 1)[-1]
    if kind == "fit":
        names = {
            "readings": "fit to the readings (scatter)",
            "second_order": "2nd-order term of d_b in rho",
            "extrema": "extreme readings (scatter)",
        }
        if tail.startswith("profile"):
            return f"rho profile, ch {tail.removeprefix('profile')} (non-linear)"
        return names.get(tail, "unresolved mirror solution " + tail.removeprefix("mirror"))
    if kind == "device_model":  # device_model:<device>:<effect key>:<parameter>@<night>
        parts = rest.split(":")
        return (
            f"device model {parts[1]} {parts[2].split('@')[0]}" if len(parts) >= 3 else _short_quantity(row)
        )
    if kind == "position":
        return f"offset S-C, {tail} (reported positions)"
    if kind == "gauge":
        return f"gauge {rest.split('@')[0]}: certified D20"
    if kind == "temperature":
        return f"temperature, {_short_id(rest)}"
    if kind == "cte":
        return f"expansion coeff., {rest.split('@')[0]}"
    if kind in ("linearity", "resolution"):
        what = "calib." if "(calibration)" in row.get("quantity", "") else "meas."
        return f"{kind}, ch {tail.removeprefix('ch')} ({what})"
    if kind == "readings":
        return "readings (scatter)"
    return _short_quantity(row)


def _tiny(r: dict, uc: float) -> bool:
    c = r.get("contribution") or 0.0
    return uc > 0 and c < 1e-5 * uc


def _budget_tables(  # noqa: C901 (one cell per budget row, parameter kind and held or tiny term)
    d: _Doc,
) -> None:
    c = d.cert
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    if not budgets:
        return
    d.new_page()
    d.heading("6  Uncertainty budget")
    d.para(
        "Per channel, every input x_i of the calibration with its estimate, standard uncertainty u(x_i), "
        "distribution and degrees of freedom nu_i, and for each result its sensitivity coefficient c_i and "
        "contribution u_i = |c_i| u(x_i) (GUM 5.1.3). The fit to the readings is a vector input (u(x_i): the "
        "residual standard deviation per reading); its contribution comes from its covariance. c: for "
        "beta in rad, "
        "for rho and d_b in mm, per unit of the input; contributions in urad (beta) and um (rho, d_b); "
        "0: below "
        "1e-5 u_c; 'in Type A': a resolution dithered by the readings' noise (GUM F.2.2.1)."
    )
    fams = ("beta", "rho", "d_b")
    for prow in c["parameters"]:
        ch = prow["channel"]
        keys = [f"beta_rad[{ch}]", f"rho_mm[{ch}]", f"d_b_mm[{ch}]"]
        rows_by = [budgets[k]["rows"] for k in keys]
        comb = [budgets[k]["combined"] for k in keys]
        cols = [
            "input x_i",
            "estimate",
            "u(x_i)",
            "dist.",
            "nu_i",
            "c(beta)",
            "u_i(beta)",
            "c(rho)",
            "u_i(rho)",
            "c(d_b)",
            "u_i(d_b)",
        ]
        cells = []
        for i, row in enumerate(rows_by[0]):
            u_x = row["standard_uncertainty"]
            cell = [
                _label(row),
                _est_text(row["estimate"], row["unit"]),
                "-" if not u_x else _u_text(u_x, row["unit"]),
                _DIST.get(row["distribution"], row["distribution"]),
                _dof_text(row["degrees_of_freedom"]),
            ]
            for k, rows in enumerate(rows_by):
                r = rows[i]
                if prow[f"held_{fams[k]}"]:
                    cell += ["held", "-"]
                    continue
                if r.get("note") and not r["contribution"]:
                    cell += ["-", "in Type A"]
                    continue
                if _tiny(r, comb[k]["standard_uncertainty"]):
                    cell += ["0", "0"]
                    continue
                cc = r["sensitivity_coefficient"]
                cell.append("-" if cc is None else f"{cc:.3g}")
                cell.append(f"{r['contribution'] * (1e6 if k == 0 else 1e3):.3g}")
            cells.append(cell)
        for label, field, scale_fn in (
            ("combined standard uncertainty u_c", "standard_uncertainty", True),
            ("effective degrees of freedom nu_eff", "effective_degrees_of_freedom", None),
            ("coverage factor k", "coverage_factor", False),
            ("expanded uncertainty U = k u_c", "expanded_uncertainty", True),
        ):
            last = [label, "", "", "", ""]
            for k, cb in enumerate(comb):
                if prow[f"held_{fams[k]}"]:
                    last += ["", "held"]
                    continue
                v = cb.get(field)
                if scale_fn is None:
                    txt = _dof_text(v)
                elif scale_fn:
                    txt = f"{v * (1e6 if k == 0 else 1e3):.3g} {'urad' if k == 0 else 'um'}"
                else:
                    txt = f"{v:.2f}" + ("" if cb.get("coverage_method") == "GUF" else " (S1)")
                last += ["", txt]
            cells.append(last)
        d.room(0.0128 * (len(cells) + 1) + 0.035)
        d.para(f"Channel {ch}", size=8.5)
        d.table(
            cols,
            cells,
            widths=[0.22, 0.09, 0.07, 0.06, 0.05, 0.065, 0.08, 0.065, 0.08, 0.065, 0.08],
            size=5.8,
            row_h=0.0128,
        )
    d.para(
        "k marked (S1): the t-based factor was not validated by GUM S1 (one rectangular input "
        "dominates); k is that "
        "of the propagated distribution. The gauge's expansion coefficient has no first-order effect "
        "at 20 degC. "
        "Sensor linearity is an error of every reading of a channel within the data sheet's bound, "
        "independent "
        "between the calibration and each later measurement. Reported positions that are the same for "
        "several "
        "scans are one input.",
        size=6.8,
    )


def _verification_pages(d: _Doc) -> None:
    c = d.cert
    ver = c["verifications"]
    d.new_page()
    d.heading("7  Verification, decision rule and conformity")
    d.para(_decision_rule_text(c["laboratory"]))
    if not ver:
        d.para(c["conformity"]["text"])
    else:
        d.para(
            "Each verification measures a certified ring gauge with this calibration in the same "
            "night. The measured "
            "diameter is brought to 20 degC (ISO 1) with the gauge's expansion coefficient and the recorded "
            "temperature; E = D20 (measured) - D20 (certified). Where the gauge is the calibration's "
            "own, its "
            "certified diameter enters both and largely cancels in U(E)."
        )
        cols = [
            "scan",
            "gauge",
            "T [degC]",
            "D(T) [mm]",
            "D20 [mm]",
            "cert. [mm]",
            "E [um]",
            "U(E) [um]",
            "k",
            "T_ol [um]",
            "A [um]",
            "verdict",
        ]
        cells = []
        for v in ver:
            tflag = " (assumed)" if v.get("temperature_assumed") else ""
            cells.append(
                [
                    str(v.get("scan_id")),
                    str(v.get("artifact_id")),
                    _num(v.get("temperature_c"), ".2f") + tflag,
                    _num(v.get("measured_at_t_mm"), ".5f"),
                    _num(v.get("measured_mm"), ".5f"),
                    _num(v.get("certified_mm"), ".4f"),
                    _num(1e3 * v["error_mm"], "+.2f"),
                    _num(_scaled(v.get("expanded_u_error_mm"), 1e3), ".2f"),
                    _num(v.get("k"), ".2f"),
                    _num(1e3 * v["tolerance_mm"], ".1f"),
                    _num(
                        1e3 * v["acceptance_limit_mm"] if v.get("acceptance_limit_mm") is not None else None,
                        ".2f",
                    ),
                    (
                        split_verdict(v.get("conformity"))[0]
                        or ("conforms" if v.get("passed") else "does not conform")
                    ),
                ]
            )
        d.table(
            cols,
            cells,
            widths=[0.2, 0.07, 0.08, 0.09, 0.1, 0.08, 0.06, 0.065, 0.04, 0.065, 0.06, 0.05],
            size=6,
        )
        d.para(
            "T: recorded temperature; D(T): as measured at T; D20: brought to 20 degC; cert.: certified D20; "
            "E = D20 - cert.; T_ol: tolerance; A: acceptance limit (T_ol minus the guard band).",
            size=6.8,
        )
        for v in ver:
            d.para(f"{_ver_name(v)}: {v.get('conformity', '')}", size=7)
        d.para("Conformity statement: " + c["conformity"]["text"], size=8)
        for v in ver:
            _verification_budget(d, v)


#: columns of a one-result budget table (a rod layer's l0, a verification's E); contributions in um
_CONTRIBUTION_COLS = ["input x_i", "estimate", "u(x_i)", "dist.", "nu_i", "c_i", "u_i [um]"]
#: layout of those tables: (column widths as fractions of the text width, font size [pt])
_ROD_LAYER_LAYOUT = ([0.4, 0.13, 0.1, 0.1, 0.07, 0.09, 0.11], 6.2)
_VERIFICATION_LAYOUT = ([0.42, 0.12, 0.1, 0.1, 0.06, 0.1, 0.1], 6)


def _input_cells(r: dict, dash_zero_u: bool) -> list[str]:
    """Return one budget row as table cells.

    One budget row as table cells: label, estimate, u(x_i), distribution, nu_i, c_i, u_i [um]
    (``contribution`` [mm] times 1e3). ``dash_zero_u``: a zero or missing u(x_i) shows as "-".
    """
    u_x = r["standard_uncertainty"]
    return [
        _label(r),
        _est_text(r["estimate"], r["unit"]),
        "-" if dash_zero_u and not u_x else _u_text(u_x, r["unit"]),
        _DIST.get(r["distribution"], r["distribution"]),
        _dof_text(r["degrees_of_freedom"]),
        "-" if r["sensitivity_coefficient"] is None else f"{r['sensitivity_coefficient']:.3g}",
        f"{1e3 * r['contribution']:.3g}",
    ]


def _sum_row(label: str, value_mm: float, dof: str = "") -> list[str]:
    """Return a summary line of a budget table.

    Return a summary line of a budget table: ``label``, ``dof`` in the nu_i column, ``value_mm`` [mm] in
    um.
    """
    return [label, "", "", "", dof, "", f"{1e3 * value_mm:.3g}"]


def _contribution_table(
    d: _Doc,
    title: str,
    rows: list[dict],
    sums: list[list[str]],
    layout: tuple[list[float], float],
    dash_zero_u: bool,
) -> None:
    """Write the budget table of one result.

    Write the budget of one result: ``title``, one line per input row (:func:`_input_cells`), then the
    ``sums`` lines (:func:`_sum_row`, the last one bold); ``layout``: (column widths, font size).
    """
    cells = [_input_cells(r, dash_zero_u) for r in rows] + sums
    widths, size = layout
    d.room(0.013 * (len(cells) + 1) + 0.03)
    d.para(title, size=7.5)
    d.table(_CONTRIBUTION_COLS, cells, widths=widths, size=size, row_h=0.013, bold_last=True)


def _verification_budget(d: _Doc, v: dict) -> None:
    """Write the budget of a verification's error E.

    Write the budget of a verification's error E: inputs of at least 5 % of u_c(E) one by one, the
    others folded into one line (root sum of squares), then u_c(E) (contributions in um).
    """
    rows = v.get("budget") or []
    if not rows:
        return
    uc = math.sqrt(sum((r.get("contribution") or 0.0) ** 2 for r in rows))
    big = [r for r in rows if (r.get("contribution") or 0.0) >= 0.05 * uc]
    rest = math.sqrt(max(sum((r.get("contribution") or 0.0) ** 2 for r in rows if r not in big), 0.0))
    sums = [
        _sum_row(f"{len(rows) - len(big)} further inputs (each < 5 % of u_c), combined", rest),
        _sum_row("combined standard uncertainty u_c(E)", uc),
    ]
    _contribution_table(
        d,
        f"Budget of E, {_ver_name(v)} (contributions in um):",
        big,
        sums,
        _VERIFICATION_LAYOUT,
        dash_zero_u=False,
    )


def _rod_layer_budget(d: _Doc, channel: int, budget: dict) -> None:
    """Write the budget of one layer's l0.

    Write the budget of one layer's l0 (``budget``: rows and combined of certificate.json): inputs
    below 1e-5 u_c left out, then u_c with nu_eff and U with k (contributions in um).
    """
    comb = budget["combined"]
    rows = [r for r in budget["rows"] if not _tiny(r, comb["standard_uncertainty"])]
    sums = [
        _sum_row(
            "combined standard uncertainty u_c",
            comb["standard_uncertainty"],
            _dof_text(comb.get("effective_degrees_of_freedom")),
        ),
        _sum_row(f"expanded uncertainty U (k = {comb['coverage_factor']:.2f})", comb["expanded_uncertainty"]),
    ]
    _contribution_table(
        d,
        f"Layer {channel} (contributions in um; inputs below 1e-5 u_c left out):",
        rows,
        sums,
        _ROD_LAYER_LAYOUT,
        dash_zero_u=True,
    )


def _ver_name(v: dict) -> str:
    """Return a verification's name in the certificate: its scan, and the layer's feature for a rod."""
    return f"{v.get('scan_id')}" + (
        f" layer {v['feature']} ({v.get('artifact_id')})" if v.get("feature") else ""
    )


def _page_records(d: _Doc) -> None:
    c = d.cert
    d.new_page()
    d.heading("8  Records")
    d.kv(
        [
            ("Software", f"borescan {c['software_version']}, configuration hash {c['config_hash']}"),
            ("Date of issue", f"{c['dates'].get('issue') or 'n/a'}: {c['dates'].get('issue_rule', '')}"),
            ("Raw data", "SHA-256 of every raw file the calibration used:"),
        ]
    )
    for name, digest in c["raw_files"].items():
        d.room(0.013)
        d.fig.text(d.LEFT, d.y, name, family="monospace", fontsize=6.5)
        d.fig.text(0.42, d.y, digest, family="monospace", fontsize=6.5)
        d.y -= 0.012
    ver_files = {k: h for v in c["verifications"] for k, h in sorted((v.get("raw_files") or {}).items())}
    if ver_files:
        d.y -= 0.006
        d.para("SHA-256 of the raw files of the verifications reported in section 7:")
        for name, digest in ver_files.items():
            d.room(0.013)
            d.fig.text(d.LEFT, d.y, name, family="monospace", fontsize=6.5)
            d.fig.text(0.42, d.y, digest, family="monospace", fontsize=6.5)
            d.y -= 0.012
    d.y -= 0.01
    d.para("Residuals of the fit: residuals.png beside this certificate, and the last page.")


def _residual_figure(
    cert: dict, t: np.ndarray, res: np.ndarray, size=(8.27, 5.0), page: bool = False
) -> Figure:
    fig = Figure(figsize=size)
    n_ch = res.shape[1]
    axes = fig.subplots(n_ch, 1, sharex=True, squeeze=False)[:, 0]
    channels = [int(r["channel"]) for r in cert["parameters"]]
    chans = channels if len(channels) == n_ch else list(range(1, n_ch + 1))
    for ax, j, ch in zip(axes, range(n_ch), chans):
        ax.plot(t, res[:, j] * 1e3, lw=0.5, color=f"C{j}")
        ax.axhline(0.0, color="k", lw=0.5)
        with np.errstate(invalid="ignore"):
            rms = float(np.sqrt(np.nanmean(res[:, j] ** 2))) * 1e3 if res.size else float("nan")
        ax.set_ylabel(f"ch {ch} [um]")
        ax.set_title(f"channel {ch}: rms {rms:.2f} um", fontsize=8, loc="left")
    axes[-1].set_xlabel("t [s]")
    if page:
        fig.text(
            _Doc.LEFT,
            0.885,
            "9  Residuals of the fit (model - reading), first calibration scan",
            fontsize=10.5,
            weight="bold",
        )
        fig.subplots_adjust(left=0.12, right=0.94, top=0.84, bottom=0.1, hspace=0.35)
    else:
        fig.suptitle(f"Residuals (model - reading), {cert['calibration_id']}", fontsize=9)
        fig.tight_layout()
    return fig


def _pages(cert: dict, t: np.ndarray, res: np.ndarray) -> list[Figure]:
    d = _Doc(cert)
    _page_admin(d)
    _page_item_conditions(d)
    _page_results(d)
    _budget_tables(d)
    _verification_pages(d)
    _page_records(d)
    d.pages.append(_residual_figure(cert, t, res, size=_A4, page=True))
    return d.finish()


def write_certificate(
    cal: TriCalibration,
    out_dir: Path | str,
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
) -> dict[str, Path]:
    """Write ``certificate.json``, ``certificate.pdf`` and ``residuals.png`` into ``out_dir``.

    Parameters
    ----------
    cal : TriCalibration (``cov`` the combined covariance of its budget)
    out_dir : results_root/calibration/<device_id>/<calibration_id>/ (see :func:`certificate_dir`)
    device : dict, e.g. {"id", "type", "sensors" (scan.json sensor entries)}
    artifact : scan.json artifact of the gauge (id, certificate, certified_diameter_mm, u_diameter_mm,
        k, cte_per_k; certificate_issuer and certificate_valid_until when known)
    conditions : influence conditions: ``temperature`` {value_c, u_c, U_c, k, source, assumed},
        ``gauge_cte``, ``gauge_radius_at_temperature_mm``, ``position_accuracy_mm``, ``scans`` (per
        scan: scan_id, spindle_position, center, rpm, angle_source, revolutions_recorded,
        revolutions_with_extrema)
    residuals : dict with t_s (n,) [s] and residual_mm (n, c) [mm] (model - reading)
    raw_files : file name -> sha256 hex digest
    software_version, config_hash : str
    budget : the calibration's GUM budget (default: ``cal.diagnostics["budget"]``)
    laboratory : the config's ``laboratory`` section (default: its schema defaults, placeholders)
    coverage_probability : of every U (None: the schema's uncertainty.coverage_probability)
    dates : ``begin``, ``end`` (dates of calibration), ``issue``, ``issue_rule``,
        ``recalibration_due``, ``recalibration_rule`` (ISO dates and the text saying how each was derived)
    verifications : rows of the night's verifications with this calibration
        (:func:`borescan.measure.verification_row` plus ``budget``: its budget rows)

    Returns
    -------
    dict with keys json, dcc, pdf, png -> paths. Same inputs give byte-identical files.
    """
    cert = certificate_dict(
        cal,
        device=device,
        artifact=artifact,
        conditions=conditions,
        residuals=residuals,
        raw_files=raw_files,
        software_version=software_version,
        config_hash=config_hash,
        budget=budget,
        laboratory=laboratory,
        coverage_probability=coverage_probability,
        dates=dates,
        verifications=verifications,
    )
    return write_certificate_files(cert, out_dir, residuals)


def write_certificate_files(
    cert: dict, out_dir: Path | str, residuals: dict | None = None
) -> dict[str, Path]:
    """Write the documents of the certificate whose content is ``cert`` into ``out_dir``.

    ``certificate.json``, ``certificate.dcc.xml`` (:mod:`borescan.certificate_dcc`), ``certificate.pdf`` and,
    for a three-sensor certificate, ``residuals.png`` (``residuals``: t_s [s], residual_mm [mm]). Returns the
    paths by key (json, dcc, pdf, png); the same content gives the same bytes.
    """
    import matplotlib

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = f"Calibration certificate {cert['administrativeData']['coreData']['uniqueIdentifier']}"
    paths = {"json": out_dir / "certificate.json", "pdf": out_dir / "certificate.pdf"}
    # unique temporary names (atomic.py): two runs writing the same certificate never meet
    atomic_write_text(paths["json"], json.dumps(cert, sort_keys=True, indent=2, allow_nan=False) + "\n")
    paths["dcc"] = write_dcc(cert, out_dir)
    with matplotlib.rc_context(_RC):
        if (cert.get("device") or {}).get("type") == "rod":
            atomic_write_bytes(paths["pdf"], _pdf_bytes(_rod_pages(cert), title))
            return paths
        t, res = _residual_arrays(residuals)
        paths["png"] = out_dir / "residuals.png"
        fig = _residual_figure(cert, t, res)
        FigureCanvasAgg(fig)
        buf = io.BytesIO()
        fig.savefig(buf, dpi=110, format="png", metadata={"Software": None})
        atomic_write_bytes(paths["png"], buf.getvalue())
        atomic_write_bytes(paths["pdf"], _pdf_bytes(_pages(cert, t, res), title))
    return paths


def _pdf_bytes(pages: list[Figure], title: str) -> bytes:
    buf = io.BytesIO()
    with PdfPages(buf, metadata=dict(_PDF_METADATA, Title=title)) as pdf:
        for page in pages:
            pdf.savefig(page)
    return buf.getvalue()


# --------------------------------------------------------------------------- rod certificates


def _rod_results(cal, p: float) -> tuple[list[dict], dict]:
    """DCC results (l0 [mm] per layer, U for coverage probability ``p``) and each one's budget."""
    results, budgets = [], {}
    for j, lay in enumerate(cal.layers):
        name = f"l0_mm[{int(lay.channel)}]"
        comb = cal.budget.combined(j, p)
        results.append(_result(name, "borescan_rodBaseLength", False, float(lay.l0_mm), "mm", comb))
        budgets[name] = _budget_entry("mm", cal.budget.rows(j), comb)
    return results, budgets


def _rod_parameters(cal) -> list[dict]:
    """Return the calibrated and design parameters of each layer.

    Per layer: l0 (calibrated and design) and u(l0) [mm], the layer's fixed geometry (h, d [mm],
    phi, gamma [rad]) and its ring gauge (certified D20, radius at temperature [mm]).
    """
    params = []
    for j, lay in enumerate(cal.layers):
        g = cal.gauges[j]
        params.append(
            {
                "channel": int(lay.channel),
                "feature": g.get("feature"),
                "l0_mm": float(lay.l0_mm),
                "l0_nominal_mm": float(cal.l0_nominal_mm[j]),
                "u_l0_mm": float(cal.u_l0_mm[j]),
                "h_mm": float(lay.h_mm),
                "phi_rad": float(lay.phi_rad),
                "d_mm": float(lay.d_mm),
                "gamma_rad": float(lay.gamma_rad),
                "gauge_id": g.get("id"),
                "gauge_certificate": g.get("certificate"),
                "gauge_certified_diameter_mm": g.get("certified_diameter_mm"),
                "gauge_radius_at_temperature_mm": g.get("radius_at_t_mm"),
            }
        )
    return params


def _rod_fit(cal) -> dict:
    """Return the summary of the rod solve at the calibrated l0.

    Return the rod solve at the calibrated l0: residual rms [mm], solves to settle l0, method, rank,
    condition, number of poses, axis deflection [rad] and eccentricity [mm] (None without a solve).
    """
    sol = cal.solution
    return {
        "residual_rms_mm": cal.residual_rms_mm,
        "iterations": cal.iterations,
        "solve_method": None if sol is None else sol.method,
        "rank": None if sol is None else sol.rank,
        "condition": None if sol is None else sol.condition,
        "n_poses": None if sol is None else int(np.size(sol.alpha_rad)),
        "deflection_rad": None if sol is None else sol.deflection_rad,
        "eccentricity_mm": None if sol is None or sol.eccentricity_mm is None else sol.eccentricity_mm,
    }


def rod_certificate_dict(
    cal,
    *,
    device: dict,
    artifact: dict,
    temperature,
    cte,
    raw_files: dict[str, str],
    software_version: str,
    config_hash: str,
    laboratory: dict | None = None,
    coverage_probability: float | None = None,
    dates: dict | None = None,
    verifications: list[dict] | None = None,
) -> dict:
    """Return the ``certificate.json`` of a rod calibration.

    ``certificate.json`` of a rod calibration (:class:`borescan.rod_calibration.RodCalibration`):
    the same administrative part as a three-sensor certificate, results l0 per layer with U and k,
    the budget per layer, each layer's gauge and the solve's diagnostics.
    """
    p = float(
        schema_default("uncertainty", "coverage_probability")
        if coverage_probability is None
        else coverage_probability
    )
    results, budgets = _rod_results(cal, p)
    conditions = calibration_conditions(temperature, cte, None, None, p, [])
    gauges_text = "; ".join(
        f"layer {g['channel']}: ring gauge {g['id']}, certificate {g.get('certificate')}" for g in cal.gauges
    )
    shared = _shared_part(
        cal,
        item_name="measuring rod (rod)",
        item_id=device.get("id"),
        traceability=" ".join(_traceability_text(g) for g in _unique_gauges(cal)),
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
            "item": "measuring rod",
            "traceability_summary": gauges_text + " (section 4)",
            "measurementResults": _measurement_results(
                "calibrated rod base lengths",
                cal.method,
                _METHOD_TEXT[cal.method],
                "JCGM 100:2008 (GUM)",
                [dict(g, refType="basic_normalUsed", name="ring gauge") for g in cal.gauges],
                conditions,
                results,
                budgets,
            ),
            "parameters": _rod_parameters(cal),
            "covariance": cal.budget.covariance(),
            "fit": _rod_fit(cal),
            "gauges": list(cal.gauges),
        }
    )


def _unique_gauges(cal) -> list[dict]:
    seen, out = set(), []
    for g in cal.gauges:
        key = (g.get("id"), g.get("certificate"))
        if key not in seen:
            seen.add(key)
            out.append(g)
    return out


def _rod_page_item_conditions(d: _Doc) -> None:
    """Write sections 1-4 of a rod certificate.

    Sections 1-4 of a rod certificate: item, method, conditions (temperature [degC], expansion
    coefficient [1/K]) and traceability (each layer's ring gauge).
    """
    c = d.cert
    d.new_page()
    d.heading("1  Item calibrated")
    _sensor_table(d, c["device"], c["device_id"])
    d.heading("2  Method")
    d.para(_METHOD_TEXT.get(c["method"], c["method"]))
    d.heading("3  Conditions of calibration")
    temp = c["conditions"].get("temperature") or {}
    cte = c["conditions"].get("gauge_cte") or {}
    d.kv(
        [
            (
                "Gauge temperature",
                f"{_num(temp.get('value_c'), '.2f')} degC, standard uncertainty "
                f"{_num(temp.get('u_c'), '.3f')} K (rectangular); {temp.get('source', 'not stated')}",
            ),
            (
                "Gauge expansion coeff.",
                f"{_ppm(cte.get('value_per_k'))} +- {_ppm(cte.get('halfwidth_per_k'))} "
                f"(rectangular); {cte.get('source', '')}",
            ),
            ("Calibration scans", ", ".join(c["scan_ids"])),
            (
                "Other conditions",
                "humidity, pressure and vibration are not recorded in scan.json; they enter no result",
            ),
        ],
        key_w=0.21,
        width=96,
    )
    d.heading("4  Traceability")
    cells = [
        [
            str(g["channel"]),
            str(g.get("feature")),
            str(g.get("id")),
            str(g.get("certificate")),
            _num(g.get("certified_diameter_mm"), ".4f"),
            _num(_scaled(g.get("u_diameter_mm"), 1e3), "g"),
            str(g.get("k")),
            _num(g.get("radius_at_t_mm"), ".5f"),
        ]
        for g in c["gauges"]
    ]
    d.table(
        ["layer", "feature", "ring gauge", "certificate", "D20 [mm]", "U [um]", "k", "R at T [mm]"],
        cells,
        widths=[0.07, 0.09, 0.17, 0.2, 0.12, 0.08, 0.06, 0.13],
        size=6.8,
    )
    for st in c["administrativeData"]["statements"]:
        if st.get("refType") == "basic_traceability":
            d.para(st["declaration"])


def _rod_page_results(d: _Doc) -> None:
    """Write section 5 of a rod certificate.

    Section 5 of a rod certificate: l0 per layer [mm] with U and k, its change from the design
    value [um], and the rod solve's summary.
    """
    c = d.cert
    d.new_page()
    d.heading("5  Results")
    p = c["coverage_probability"]
    d.para(
        "Calibrated base length l0 of each layer (axis foot to the sensor's measuring start), at which "
        "the rod solve "
        "returns the gauge's radius at its temperature. Expanded uncertainty U = k u_c for a coverage "
        "probability of "
        f"{100 * p:.2f} %. A rod diameter measured with this calibration moves by 2 (l0 - l0 true): its "
        "budget takes "
        "this one with sensitivity 2."
    )
    res = {r["name"]: r for r in c["measurementResults"][0]["results"]}
    budgets = c["measurementResults"][0]["uncertaintyBudget"]
    cells = []
    for prow in c["parameters"]:
        key = f"l0_mm[{prow['channel']}]"
        eu = res[key]["real"]["expandedUnc"]
        v, U = _vu(prow["l0_mm"], eu["uncertainty"])
        dom = (budgets.get(key, {}).get("combined") or {}).get("dominant_input", "")
        cells.append(
            [
                str(prow["channel"]),
                _num(prow["l0_nominal_mm"], ".4f"),
                v,
                U,
                _num(1e3 * (prow["l0_mm"] - prow["l0_nominal_mm"]), "+.2f"),
                _num(eu["coverageFactor"], ".2f"),
                _dominant_label(dom),
            ]
        )
    d.table(
        ["layer", "design l0 [mm]", "l0 [mm]", "U [mm]", "l0 - design [um]", "k", "dominant input"],
        cells,
        widths=[0.07, 0.13, 0.14, 0.1, 0.13, 0.06, 0.37],
        size=7,
    )
    fit = c["fit"]
    d.para(
        f"Rod solve at the calibrated l0 ({fit.get('solve_method')}): residual rms "
        f"{_num(_scaled(fit.get('residual_rms_mm'), 1e3), '.2f')} um over {fit.get('n_poses')} poses, "
        "Jacobian rank "
        f"{fit.get('rank')}, condition {_num(fit.get('condition'), '.3g')}; rod axis deflection "
        f"{_num(_scaled(fit.get('deflection_rad'), 180 / math.pi), '.3f')} deg; {fit.get('iterations')} "
        "solves to "
        "settle l0."
    )


def _rod_pages(cert: dict) -> list[Figure]:
    """Return the pages of a rod certificate's PDF (content: ``cert``, see :func:`rod_certificate_dict`)."""
    d = _Doc(cert)
    _page_admin(d)
    _rod_page_item_conditions(d)
    _rod_page_results(d)
    d.heading("6  Uncertainty budget")
    budgets = cert["measurementResults"][0]["uncertaintyBudget"]
    for prow in cert["parameters"]:
        _rod_layer_budget(d, prow["channel"], budgets[f"l0_mm[{prow['channel']}]"])
    _verification_pages(d)
    _page_records(d)
    return d.finish()


def write_rod_certificate(cal, out_dir: Path | str, **kw) -> dict[str, Path]:
    """Write ``certificate.json``, ``certificate.dcc.xml`` and ``certificate.pdf`` of a rod calibration.

    Into ``out_dir``, from the arguments of :func:`rod_certificate_dict`. Same inputs give byte-identical
    files.
    """
    return write_certificate_files(rod_certificate_dict(cal, **kw), out_dir)
