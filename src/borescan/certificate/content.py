"""What every certificate's content starts from: folders, dates, conditions, JSON numbers, budget results."""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path
from typing import Any

import numpy as np

from borescan.calibrate.result import TriCalibration
from borescan.uncertainty import Budget, Combined, combine

CERTIFICATE_FORMAT = "borescan-certificate/2"

#: text that marks a laboratory setting left at its default
PLACEHOLDER = "PLACEHOLDER"

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


def certificate_dates(scan_metas: list[dict], night: str, validity_days: int, issue_date: str) -> dict:
    """Dates of a certificate from its scans and its night's record, never the clock at writing.

    ``begin``/``end``: the UTC dates of the calibration scans' ``started_at`` (ISO 8601; a scan
    without a readable one counts as the night); ``issue``: ``issue_date``, the date the workflow first
    processed the night (:func:`borescan.night_config.first_processed`), so that a
    certificate regenerated later keeps its date and bytes; ``recalibration_due``: the night +
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
    due = (_dt.date.fromisoformat(night) + _dt.timedelta(days=int(validity_days))).isoformat()
    return {
        "begin": cal_days[0],
        "end": cal_days[-1],
        "issue": _dt.date.fromisoformat(issue_date).isoformat(),
        "night": night,
        "issue_rule": "the UTC date the night was first processed (recorded in stage/night_config), so that "
        "regenerating the certificate gives the same bytes",
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
