"""Rod diameters with a rod calibration's budget, and a rod's layer-by-layer gauge verification.

The joint rod solve (:func:`borescan.rod.solve_rod`) of a hold's pose means at the calibration's
layers (:mod:`borescan.rod_calibration`: l0 on certified ring gauges, or the design geometry); the
diameter's GUM budget (:func:`borescan.measure.diameter_uncertainty`) takes the calibration's
budget with sensitivity 2 on the layer's l0.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import numpy as np

from ..config import schema_default
from ..rod import solve_rod
from ..rod_calibration import (
    layer_gauges,
    pose_means_of_scan,
    rod_calibration_from_rows,
    rod_coaxiality_mm,
    rod_layer_draws_from_rows,
)
from ..rod_layer_geometry import hold_radius_shifts, layer_geometry_input
from ..rod_minima import DELTA_CHI2_MAX, minima_radius_cov

__all__ = ["layer_jacobian", "minima_input", "rod_diameters_with_budget", "rod_verifications"]


def layer_jacobian(channels, channel: int) -> np.ndarray:
    """Return d D_channel / d l0 of every layer.

    d D_channel / d l0 of every layer (2 on its own layer, 0 elsewhere): a diameter's sensitivity
    to the calibration's outputs.
    """
    return np.array([2.0 if int(c) == int(channel) else 0.0 for c in channels])


def minima_input(sol, j: int, scan_label: str, channel: int):
    """Return the choice between the solve's minima as layer ``j``'s diameter input (input, dD / d input).

    u = 2 sqrt(sum_k w_k (r_kj - r_0j)^2) (:mod:`borescan.rod_minima`), the minima listed in its source.
    """
    from ..uncertainty import Input

    u = 2.0 * float(np.sqrt(minima_radius_cov(sol.radius_mm, sol.other_minima)[j, j]))
    alts = "; ".join(
        f"dchi2 {mk.delta_chi2:.2f}, weight {mk.weight:.3f}, D - D0 {2e3 * (r[j] - sol.radius_mm[j]):+.2f} um"
        for mk, r in ((mk, mk.radius_mm) for mk in sol.other_minima)
    )
    return (
        Input(
            f"rod_minima:{scan_label}:ch{int(channel)}",
            f"the rod solve's minimum (channel {int(channel)}): other minima within {DELTA_CHI2_MAX:g} chi2, "
            "the chosen one reported",
            f"e_min,{int(channel)}",
            "mm",
            0.0,
            u,
            "normal",
            source=f"rod solve's starts (borescan.rod_minima; root mean square over the weights): {alts}",
        ),
        1.0,
    )


def rod_diameters_with_budget(
    scan, layer_rows: list[dict], unc_cfg: dict, calibration_id: str | None = None, cleaning=None
) -> list[dict]:
    """Hole diameters of a rod scan with their GUM budgets.

    The joint rod solve with the calibration's layers (``layer_rows``: its ``calibrations`` rows,
    a ring-gauge calibration or the design geometry), each mean reading's uncertainty from the
    sensors' data sheet; the budget (:func:`borescan.measure.diameter_uncertainty`) adds the
    calibration's budget with sensitivity 2 on the layer's l0 (none for the design geometry), the
    scan's temperature and the artifact's expansion coefficient, and the layers' phi, d, gamma
    against the calibration hold's (:mod:`borescan.rod_layer_geometry`, when the calibration recorded
    its draws). ``cleaning``: the spike policy
    (:func:`borescan.rod_calibration.pose_means_of_scan`).

    Returns one dict per layer: channel, feature, diameter_mm (at the scan's temperature), du
    (:class:`borescan.measure.DiameterUncertainty`), poses, condition, traceable (a gauge calibration).

    Raises :class:`borescan.artifacts.MissingTemperature`, :class:`borescan.rod.RodSolveError`,
    ValueError (a channel the calibration has no layer for).
    """
    from .. import measure
    from ..artifacts import artifact_cte, scan_temperature
    from .budget import diameter_uncertainty

    channels, means, u_mean, sensors = pose_means_of_scan(scan, cleaning)
    layers, cal_budget, cal_hold = rod_calibration_from_rows(layer_rows)
    by_ch = {int(lay.channel): lay for lay in layers}
    missing = sorted(set(channels) - set(by_ch))
    if missing:
        raise ValueError(f"calibration {calibration_id} has no rod layer for channel(s) {missing}")
    temp, cte = scan_temperature(scan.meta, unc_cfg), artifact_cte(scan.meta, unc_cfg)
    sol = solve_rod(
        means,
        layers=[by_ch[c] for c in channels],
        u_reading_mm=u_mean,
        coaxiality_mm=rod_coaxiality_mm(unc_cfg),
    )
    feat = {int(l["channel"]): l.get("feature") for l in (scan.meta.get("rod") or {}).get("layers", [])}
    cal_chans = sorted(by_ch)
    draws = rod_layer_draws_from_rows(layer_rows) if cal_budget is not None else None
    geo_shift = (
        None
        if draws is None
        else hold_radius_shifts(
            means, [by_ch[c] for c in channels], u_mean, rod_coaxiality_mm(unc_cfg), draws, sol
        ).shift_mm
    )
    here = measure.hold_readings(means)
    degree = int(
        unc_cfg.get("linearity_curve_degree") or schema_default("uncertainty", "linearity_curve_degree")
    )
    out = []
    for j, ch in enumerate(channels):
        f = feat.get(ch) or f"layer{ch}"
        lin = measure.linearity_terms(
            sensors, ch, j, here, cal_budget, cal_hold, cal_chans, f"{scan.scan_id}/{f}", degree
        )
        geo = (
            None
            if geo_shift is None
            else layer_geometry_input(draws, geo_shift, j, cal_chans.index(ch), f"{scan.scan_id}/{f}", ch)
        )
        if geo is not None:
            lin = [*lin, geo]
        if sol.other_minima:  # the solve's choice between minima this hold's readings do not rule out
            lin = [*lin, minima_input(sol, j, f"{scan.scan_id}/{f}", ch)]
        du = diameter_uncertainty(
            float(sol.diameter_mm[j]),
            jac_params=None if cal_budget is None else layer_jacobian(cal_chans, ch),
            calibration_budget=cal_budget,
            u_readings_mm=float(sol.u_diameter_mm[j]),
            dof_readings=float("inf"),
            temperature=temp,
            cte=cte,
            artifact=dict(scan.meta.get("artifact") or {}),
            scan_id=f"{scan.scan_id}/{f}",
            p=float(unc_cfg["coverage_probability"]),
            default_resolution_mm=float(unc_cfg["sensor_resolution_mm"]),
            calibration_id=calibration_id,
            extra_terms=lin,
        )
        out.append(
            {
                "channel": ch,
                "feature": f,
                "diameter_mm": float(sol.diameter_mm[j]),
                "du": du,
                "poses": int(means.shape[0]),
                "condition": float(sol.condition),
                "traceable": cal_budget is not None,
                "solution": sol,
                # where this hold and the calibration's read the sensor's range (the linearity's change)
                "spread_mm": float(np.sqrt(here["var_mm2"][j])),
                "other_minima": [mk.to_dict() for mk in sol.other_minima],
                "cal_spread_mm": None
                if cal_hold is None
                else float(np.sqrt(cal_hold["var_mm2"][cal_chans.index(ch)])),
            }
        )
    return out


def rod_verifications(
    scan, diameters: list[dict], calibration_id: str, unc_cfg: dict, lab_cfg: dict, tolerance_mm: float
) -> list[dict]:
    """Return the ``verifications`` rows of a rod scan in certified gauges.

    ``verifications`` rows of a rod scan in certified gauges: each layer's diameter at 20 degC
    against its gauge (:func:`borescan.rod_calibration.layer_gauges`,
    :func:`borescan.measure.verify_budget`), one row per layer with ``feature``, the budget rows
    (``budget``) and the scan's raw files; the budget's largest input (``dominant_input``, its
    key) and, when U(E) is not below the tolerance, what would reduce it (``dominant_fix``,
    :func:`borescan.plan_rod.dominant_fix`).

    Raises ValueError when a layer has no certified gauge.
    """
    from .. import plan_rod
    from .verify import verification_row, verify_budget

    gauges = {g["channel"]: g for g in layer_gauges(scan.meta, [d["channel"] for d in diameters])}
    rows = []
    for d in diameters:
        g = gauges[d["channel"]]
        v = verify_budget(
            d["du"],
            g,
            tolerance_mm,
            float(unc_cfg["coverage_probability"]),
            lab_cfg["decision_rule"],
            float(lab_cfg["guard_band_factor"]),
        )
        row = verification_row(scan.scan_id, scan.meta["device"]["id"], g["id"], v)
        top = row["dominant_input"]
        if top is not None and not v.U_error_mm < tolerance_mm:
            row["dominant_fix"] = plan_rod.dominant_fix(
                top, d, rod_coaxiality_mm(unc_cfg), tolerance_mm / v.k
            )
        row.update(
            calibration_id=calibration_id,
            temperature_assumed=d["du"].temperature.assumed,
            feature=d["feature"],
            budget=list(v.budget_rows),
            certificate=g.get("certificate"),
            raw_files={f"{scan.scan_id}/{k}": h for k, h in sorted(scan.sha256.items())},
        )
        rows.append(row)
    return rows
