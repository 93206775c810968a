"""A three-sensor diameter with its calibration's budget.

A flagged beam's two-solution mixture and the device model's inputs.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import numpy as np
from .. import device_model
from ..geometry import Beams
from ..uncertainty import Budget, Input, Term
from .budget import DiameterUncertainty, diameter_uncertainty
from .rotating import measure_scan

__all__ = [
    "calibration_budget_of",
    "tri_diameter_with_budget",
]


def calibration_budget_of(cal) -> Budget:
    """Return the GUM budget a calibration carries.

    Return the GUM budget a calibration carries (``diagnostics["budget"]``, written by the calibrate
    stage); for a calibration without one, its covariance as a single term, said so in the source.
    """
    d = (cal.diagnostics or {}).get("budget")
    if d:
        return Budget.from_dict(d)
    names = [f"{n}[{ch}]" for ch in cal.beams.channels for n in ("beta_rad", "rho_mm", "d_b_mm")]
    units = ["rad", "mm", "mm"] * len(cal.beams.channels)
    return Budget(
        tuple(names),
        tuple(units),
        cal.params,
        [
            Term(
                Input(
                    f"calibration:{cal.calibration_id}",
                    f"calibration {cal.calibration_id} (covariance only, no budget recorded)",
                    "p",
                    "-",
                    None,
                    0.0,
                    "normal",
                    source="TriCalibration.cov",
                ),
                cov=cal.cov,
            )
        ],
    )


def tri_diameter_with_budget(scan, cal, unc_cfg: dict, cleaning=None) -> tuple[dict, DiameterUncertainty]:
    """Return the diameter of a three-sensor scan with its GUM budget.

    Diameter of a three-sensor scan (:func:`measure_scan`) with its GUM budget
    (:func:`diameter_uncertainty`): the calibration's budget, the readings, the sensors, the
    scan's temperature (``uncertainty`` policy) and the artifact's expansion coefficient.
    ``cleaning``: the spike policy of :func:`measure_scan`.

    Raises :class:`borescan.artifacts.MissingTemperature` when the scan has no temperature and
    the config refuses such scans.
    """
    from ..artifacts import artifact_cte, scan_temperature

    temp = scan_temperature(scan.meta, unc_cfg)
    cte = artifact_cte(scan.meta, unc_cfg)
    dm = device_model.from_dicts((cal.diagnostics or {}).get("device_model"))
    res = measure_scan(scan, cal.beams, cal.cov, device_model=dm, cleaning=cleaning)
    sensors = {int(s["channel"]): s for s in scan.meta.get("sensors", [])}
    du = diameter_uncertainty(
        res["diameter_mm"],
        jac_params=res["jac_params"],
        calibration_budget=calibration_budget_of(cal),
        jac_readings=res["jac_readings"],
        u_readings_mm=res["u_readings_mm"],
        dof_readings=res["dof_readings"],
        sensors=sensors,
        channels=cal.beams.channels,
        noise_mm=res["noise_mm"],
        temperature=temp,
        cte=cte,
        artifact=dict(scan.meta.get("artifact") or {}),
        scan_id=scan.scan_id,
        p=float(unc_cfg["coverage_probability"]),
        default_resolution_mm=float(unc_cfg["sensor_resolution_mm"]),
        readings_what="measurement",
        calibration_id=cal.calibration_id,
        model=res["model"],
        beams=cal.beams,
        rho_profiles=(cal.diagnostics or {}).get("rho_profiles"),
        extra_terms=_device_model_inputs(scan, cal, dm, cleaning),
    )
    return _with_mirror_mixture(scan.scan_id, cal, res, du)


def _with_mirror_mixture(
    scan_id: str, cal, res: dict, du: DiameterUncertainty
) -> tuple[dict, DiameterUncertainty]:
    """Return the diameter measured with a calibration that has a flagged beam, or refuse it.

    For a calibration with a flagged beam (:mod:`borescan.mirror`): the diameter refused outside the bore
    range where the calibration may be used (ValueError with the reason), else the two-solution mixture by
    Monte Carlo (:func:`borescan.mirror.mixture_diameter`): the estimate, u and interval replace the GUM ones,
    ``res["mirror_mixture"]`` holds the components. A calibration without a flagged beam: unchanged.
    """
    from dataclasses import replace as _replace

    from ..mirror import mirror_checks_of, mixture_components, mixture_diameter, mixture_seed, refusal

    checks = mirror_checks_of(cal.diagnostics)
    if all(m.resolved for m in checks):
        return res, du
    why = refusal(scan_id, cal.calibration_id, float(res["diameter_mm"]), checks)
    if why is not None:
        raise ValueError(why)
    jp = np.asarray(res["jac_params"], dtype=float)
    cov_fit = np.asarray((cal.diagnostics or {}).get("cov_fit", cal.cov), dtype=float)
    var_main = float(jp @ cov_fit @ jp)
    comps = []
    for k, (w, params, cov) in enumerate(mixture_components(cal.params, cov_fit, checks)):
        p3 = np.asarray(params, dtype=float)
        beams = Beams(cal.beams.channels, p3[0::3], p3[1::3], p3[2::3])
        d_k = float(res["diameter_mm"]) if k == 0 else float(res["model"](beams))
        # a solution's covariance maps through D's derivatives at that solution: near-degenerate fits are
        # precise only along their own solution's direction (the kept one's derivatives inflated it 1e2-1e5 x)
        jp_k = jp if k == 0 else _jac_params_at(res["model"], beams)
        comps.append((w, d_k, 0.0 if k == 0 else float(jp_k @ cov @ jp_k) - var_main))
    f = du.diameter_20_mm / du.diameter_mm
    p = du.combined_20.p
    mix = mixture_diameter(
        comps, f, du.combined_20.u, du.combined_t.u, p, mixture_seed(scan_id, cal.calibration_id)
    )
    method = f"Monte Carlo (JCGM 101), {len(comps)}-solution mixture of calibration {cal.calibration_id}"

    def combined(c, est, u, lo, hi):
        U = max(est - lo, hi - est)
        return _replace(c, u=u, U=U, k=U / u if u > 0 else float("nan"), method=method)

    du2 = _replace(
        du,
        diameter_mm=mix.diameter_mm,
        diameter_20_mm=mix.diameter_20_mm,
        combined_t=combined(du.combined_t, mix.diameter_mm, mix.u_mm, *mix.interval_mm),
        combined_20=combined(du.combined_20, mix.diameter_20_mm, mix.u_20_mm, *mix.interval_20_mm),
        thermal_correction_mm=mix.diameter_20_mm - mix.diameter_mm,
    )
    res2 = dict(res, diameter_mm=mix.diameter_mm, u_diameter_mm=mix.u_mm, mirror_mixture=mix)
    return res2, du2


def _jac_params_at(model, beams: Beams) -> np.ndarray:
    """Return dD/d(beta, rho, d_b) (3c,) of the scan's diameter ``model`` at ``beams`` (the exact forms)."""
    from .rotating import _rotating_sensitivities
    from .static import static_diameter_jacobian

    if model.kind == "static":
        return np.mean(static_diameter_jacobian(model.readings_mm, beams)[1], axis=0)
    return _rotating_sensitivities(model, beams)[0]


def _device_model_inputs(scan, cal, dm, cleaning=None) -> list[tuple[Input, float]]:
    """Return the GUM inputs of the carried device-model parameters.

    (input, dD/d parameter) of each carried device-model parameter through this scan's own readings
    (:func:`borescan.device_model.derivatives` of :func:`measure_scan`'s diameter).
    """
    d = device_model.derivatives(
        dm, lambda m: measure_scan(scan, cal.beams, None, m, cleaning)["diameter_mm"]
    )
    return [(device_model.gum_input(cal.device_id, dm[i], name), float(v)) for (i, name), v in d.items()]
