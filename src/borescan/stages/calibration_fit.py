"""How a three-sensor device is calibrated from a night's scans.

How a three-sensor device is calibrated from a night's scans: the full-data fit from raw
spindle scans, and Yang 2017 (Eq. 8-15) from the signal stage's per-channel extrema summary.

Used by the calibrate stage (:mod:`borescan.stages.calibrate`) and by benchmarks that calibrate
raw scans the way a night does (:func:`calibrate_raw_scans`). :func:`budget_of` gives a
calibration its GUM budget (:mod:`borescan.calibrate.budget`); for Yang 2017 with the
sensitivities of :func:`yang_sensitivities`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl

from borescan import device_model, kinematics, rawio, readings
from borescan.artifacts import artifact_cte, gauge_radius_mm, scan_temperature
from borescan.calibrate.budget import calibration_budget, with_budget
from borescan.calibrate.full_fit import fit_full_calibration
from borescan.calibrate.result import AcceptanceRule
from borescan.calibrate.yang import yang_calibration, yang_oe
from borescan.config import schema_defaults
from borescan.geometry import Beams
from borescan.measure import sensor_ranges_mm
from borescan.preconditions import CALIBRATION_NEEDS_BEAMS, design_beams
from borescan.stages.calibrate_jobs import SpindleInputs
from borescan.uncertainty import Budget

__all__ = [
    "spindle_inputs",
    "scan_conditions",
    "acceptance_rule",
    "fit_device_calibration",
    "calibrate_raw_scans",
    "yang_from_summary",
    "yang_sensitivities",
    "budget_of",
]


def spindle_inputs(
    scan: rawio.RawScan, uncertainty: dict | None = None, cleaning: readings.CleaningPolicy | None = None
) -> SpindleInputs:
    """Return the fit inputs of a spindle scan.

    Return times, despiked readings, rotation angle model, positions, temperature and gauge of a spindle
    scan.

    ``uncertainty`` is the config's ``uncertainty`` section (schema defaults when None): the
    scan's temperature follows its ``missing_temperature`` policy
    (:func:`borescan.artifacts.scan_temperature`), never a silent 20 degC. ``cleaning``: the
    config's spike policy (:func:`borescan.readings.cleaning_policy`; schema defaults when None).

    Raises ``ValueError`` naming ``spindle.parquet`` when its angle/rpm columns give no angle, and
    :class:`borescan.artifacts.MissingTemperature` (a ValueError naming scan.json) when the scan
    has no temperature and the policy refuses it.
    """
    mat = readings.prepared_matrix(scan, cleaning)
    clean = np.asarray(mat.values_mm, dtype=float)
    meta, sp = scan.meta, scan.spindle
    sp_meta = meta.get("spindle") or {}
    pos = sp_meta.get("position") or {}
    if pos.get("x_mm") is not None and pos.get("y_mm") is not None:
        spindle_xy = (float(pos["x_mm"]), float(pos["y_mm"]))
    else:
        spindle_xy = (float(sp["x_mm"].mean()), float(sp["y_mm"].mean()))
    center = meta.get("center")
    try:
        angle_model = kinematics.angle_model_of_scan(meta, sp)
    except ValueError as err:
        raise ValueError(f"{scan.scan_id}: spindle.parquet: {err}") from None
    sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
    unc = uncertainty or schema_defaults()["uncertainty"]
    temp = scan_temperature(meta, unc)
    cte = artifact_cte(meta, unc)
    return SpindleInputs(
        t_s=np.asarray(mat.t_s, dtype=float),
        readings_mm=clean,
        channels=tuple(mat.channels),
        spindle_xy_mm=spindle_xy,
        center_xy_mm=None if not center else (float(center["x_mm"]), float(center["y_mm"])),
        rpm=float(abs(angle_model.mean_omega_rad_s()) * 60.0 / (2.0 * np.pi)),
        direction=sp_meta.get("direction", "ccw"),
        angle_model=angle_model,
        range_mm=sensor_ranges_mm(sensors, mat.channels),
        radius_mm=gauge_radius_mm(meta, temp.temperature_c, cte.cte_per_k),
        temperature=temp,
        cte=cte,
        artifact=dict(meta.get("artifact") or {}),
        sensors=sensors,
    )


def scan_conditions(scan: rawio.RawScan, x: SpindleInputs, summary: pl.DataFrame) -> dict:
    """Per-scan conditions of the certificate: positions, speed, revolutions (recorded and with extrema)."""
    s = summary.filter(pl.col("scan_id") == scan.scan_id) if summary.height else summary
    spr = float(s["period_samples_per_rev"][0]) if s.height else 0.0
    recorded = (
        float(s["n_samples_recorded"][0]) / spr if spr > 0 and "n_samples_recorded" in s.columns else None
    )
    return {
        "scan_id": scan.scan_id,
        "started_at": scan.meta.get("started_at"),
        "spindle_position": (scan.meta.get("spindle") or {}).get("position"),
        "center": scan.meta.get("center"),
        "rpm": x.rpm,
        "angle_source": x.angle_model.source,
        "revolutions_recorded": recorded,
        "revolutions_with_extrema": int(s["n_revolutions_min"].min()) if s.height else None,
    }


def acceptance_rule(cal_cfg: dict) -> AcceptanceRule:
    """Return the calibration section's acceptance settings as an :class:`AcceptanceRule`."""
    return AcceptanceRule.from_config(cal_cfg)


def fit_device_calibration(scans, inputs, nominal: Beams, cal_cfg: dict, night: str | None = None, model=()):
    """Calibrate one device from its spindle scans with the full-data fit.

    Full-data calibration of one device from its spindle scans (:func:`spindle_inputs` of each,
    corrected by :func:`borescan.device_model.correct_inputs` for the device ``model``, recorded in the
    calibration's
    ``diagnostics["device_model"]``).

    Raises ``CalibrationError`` (naming the scans and the reason) when the fit fails or is
    refused.
    """
    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    cal = _fit(
        scans,
        inputs,
        nominal,
        cal_cfg,
        night,
        raw_files,
        device_model.channel_time_offsets(model, inputs[0].channels),
    )
    if model:
        cal = replace(cal, diagnostics={**cal.diagnostics, "device_model": [m.to_dict() for m in model]})
    return cal


def _fit(scans, inputs, nominal: Beams, cal_cfg: dict, night, raw_files, tau_s):
    return fit_full_calibration(
        [x.t_s for x in inputs],
        [x.readings_mm for x in inputs],
        inputs[0].channels,
        nominal,
        inputs[0].radius_mm,
        [x.spindle_xy_mm for x in inputs],
        center_xy_mm=[x.center_xy_mm for x in inputs],
        angle_models=[x.angle_model for x in inputs],
        range_mm=inputs[0].range_mm,
        rule=acceptance_rule(cal_cfg),
        scan_ids=[s.scan_id for s in scans],
        device_id=scans[0].meta["device"]["id"],
        raw_sha256=raw_files,
        night=night,
        channel_time_offsets_s=tau_s,
    )


def calibrate_raw_scans(
    scans, cal_cfg: dict, night: str | None = None, uncertainty: dict | None = None, model=()
):
    """Full-data calibration of the calibration scans ``scans`` (``rawio.RawScan``, one device).

    The same path as the night's calibrate stage; ``cal_cfg`` is the config's ``calibration``
    section with its schema defaults. Without ``uncertainty`` the fit's own result (covariance of
    the fit alone); with the config's ``uncertainty`` section, the calibration with its GUM budget
    (:func:`with_budget`), as the stage certifies it; ``model``: the device model carried
    (:func:`borescan.device_model.device_model_at`). Raises ``CalibrationError``.
    """
    inputs = device_model.correct_inputs([spindle_inputs(s, uncertainty) for s in scans], model)
    nominal = design_beams(scans[0].meta, CALIBRATION_NEEDS_BEAMS)
    cal = fit_device_calibration(scans, inputs, nominal, cal_cfg, night=night or scans[0].night, model=model)
    if uncertainty is None:
        return cal
    return with_budget(cal, budget_of(cal, scans, inputs, uncertainty))


def yang_from_summary(
    scan: rawio.RawScan, inputs: SpindleInputs, summary: pl.DataFrame, nominal: Beams, night: str, log=print
):
    """Yang 2017 (Eq. 8-15) from the signal stage's per-channel means of one scan.

    Where a channel's status (advanced/backward) is not significant (|n - m| within its
    uncertainty), the beam's side is taken from ``nominal`` and logged. Raises ``ValueError``
    when the scan has no gauge centre (``scan.json`` ``center``, needed for oe, Eq. 9).
    """
    s = summary.filter(pl.col("scan_id") == scan.scan_id).sort("channel")
    statuses = list(s["status"])
    if "status_significant" in s.columns:
        sgn = 1.0 if inputs.direction == "ccw" else -1.0
        for i, (ch, ok) in enumerate(zip(s["channel"], s["status_significant"])):
            if not ok:
                statuses[i] = "advanced" if sgn * nominal.rho_mm[i] > 0 else "backward"
                log(
                    f"{scan.scan_id}: channel {ch}: status not significant (|n - m| within its uncertainty); "
                    f"side of the beam taken from device.nominal (rho {nominal.rho_mm[i]:+.3f} mm): "
                    f"{statuses[i]}"
                )
    if inputs.center_xy_mm is None:
        raise ValueError(
            "yang2017 needs scan.json center (the gauge centre from a centring scan) for oe (Eq. 9)"
        )
    oe = yang_oe(inputs.spindle_xy_mm, inputs.center_xy_mm)
    spr = float(s["period_samples_per_rev"][0])
    return yang_calibration(
        s["d_max_mm"].to_numpy(),
        s["d_min_mm"].to_numpy(),
        statuses,
        s["feature_sample"].to_numpy(),
        spr,
        inputs.radius_mm,
        oe,
        channels=tuple(int(c) for c in s["channel"]),
        device_id=scan.meta["device"]["id"],
        scan_ids=[scan.scan_id],
        raw_sha256=dict(scan.sha256),
        beta_ref_rad=float(nominal.beta_rad[0]),
        beta_nominal_rad=nominal.beta_rad,
        direction=inputs.direction,
        u_d_max_mm=s["u_d_max_mm"].to_numpy(),
        u_d_min_mm=s["u_d_min_mm"].to_numpy(),
        u_feature_sample=s["u_feature_sample"].to_numpy(),
        night=night,
    )


# --------------------------------------------------------------------------- GUM budget


def yang_sensitivities(scan, x: SpindleInputs, summary: pl.DataFrame, nominal: Beams, night: str) -> dict:
    """Return the sensitivities of Yang 2017's closed forms.

    Central-difference sensitivities (3c,) of Yang 2017's closed forms (:func:`yang_from_summary`):
    to R (h = 1e-4 mm), to each coordinate of the reported offset S - C (through oe = |S - C|) and to
    a constant error of every reading of a channel (its d_max and d_min move together).
    """

    def params(R=None, dS=(0.0, 0.0), shift=None) -> np.ndarray:
        xi = replace(
            x,
            radius_mm=x.radius_mm if R is None else R,
            spindle_xy_mm=(x.spindle_xy_mm[0] + dS[0], x.spindle_xy_mm[1] + dS[1]),
        )
        su = summary
        if shift is not None:
            add = pl.Series("add", np.asarray(shift, float))
            su = (
                summary.filter(pl.col("scan_id") == scan.scan_id)
                .sort("channel")
                .with_columns(
                    (pl.col("d_max_mm") + add).alias("d_max_mm"), (pl.col("d_min_mm") + add).alias("d_min_mm")
                )
            )
        return yang_from_summary(scan, xi, su, nominal, night, log=lambda *a: None).params

    h, c = 1e-4, len(nominal.channels)
    return {
        "dR": (params(R=x.radius_mm + h) - params(R=x.radius_mm - h)) / (2 * h),
        "offset_prior": {
            scan.scan_id: np.column_stack(
                [(params(dS=e * h) - params(dS=-e * h)) / (2 * h) for e in np.eye(2)]
            )
        },
        "reading_offset": np.column_stack(
            [(params(shift=e * h) - params(shift=-e * h)) / (2 * h) for e in np.eye(c)]
        ),
    }


def budget_of(
    cal,
    scans,
    inputs: list[SpindleInputs],
    uncertainty: dict,
    *,
    summary: pl.DataFrame | None = None,
    nominal: Beams | None = None,
    night: str | None = None,
    position_accuracy_mm: float | None = None,
) -> Budget:
    """Return the GUM budget of a calibration from its scans.

    Return the GUM budget of a calibration from its scans
    (:func:`borescan.calibrate.budget.calibration_budget`);
    a ``yang2017`` one also needs the signal ``summary``, ``nominal``, ``night`` and
    ``position_accuracy_mm``.
    """
    ids = [s.scan_id for s in scans]
    if cal.method == "full_lsq":
        return calibration_budget(cal, inputs, uncertainty, scan_ids=ids)
    first = summary.filter(pl.col("scan_id") == ids[0])
    n_rev = int(first["n_revolutions_min"].min()) if first.height else 2
    sens = yang_sensitivities(scans[0], inputs[0], summary, nominal, night or scans[0].night)
    return calibration_budget(
        cal,
        inputs,
        uncertainty,
        scan_ids=ids,
        extrema_dof=float(max(n_rev - 1, 1)),
        sensitivities=sens,
        position_accuracy_mm=position_accuracy_mm,
    )
