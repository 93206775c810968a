"""GUM budget of a three-sensor calibration.

GUM budget of a three-sensor calibration (:mod:`borescan.uncertainty` applied to a
:class:`TriCalibration`).

The fit's own covariance is split into its Type A part (the readings' scatter) and the position
priors, and what the fit takes as known is added: the gauge's certified diameter (U, k of its
certificate), the scan's temperature and the gauge's expansion coefficient (through the gauge
radius R = D20 / 2 (1 + alpha (T - 20))), each sensor's linearity and resolution, and each
parameter of a device-model effect the readings were corrected for (:mod:`borescan.device_model`).
Sensitivities: :func:`borescan.calibrate.sensitivities.full_lsq_sensitivities` (implicit differentiation of
the least-squares optimum); a Yang 2017 calibration passes its own (central differences of its
closed forms, :func:`borescan.stages.calibration_fit.yang_sensitivities`).
:func:`with_budget` puts the combined covariance into the calibration (so the catalog's u_*
columns and every diameter carry it) and keeps the fit's own as ``diagnostics["cov_fit"]``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from borescan import device_model
from borescan.calibrate.sensitivities import full_lsq_sensitivities
from borescan.artifacts import artifact_key
from borescan.effects import REFERENCE_TEMPERATURE_C, thermal_expansion_factor
from borescan.measure import sensor_terms
from borescan.noise import noise_floor_mm
from borescan.uncertainty import Budget, Input, Term

__all__ = ["calibration_budget", "with_budget", "parameter_labels"]


def parameter_labels(cal) -> tuple[list[str], list[str]]:
    """Names (``beta_rad[1]``, ...) and units of a calibration's parameters, in its order."""
    names, units = [], []
    for ch in cal.beams.channels:
        names += [f"beta_rad[{ch}]", f"rho_mm[{ch}]", f"d_b_mm[{ch}]"]
        units += ["rad", "mm", "mm"]
    return names, units


def _rank_one_parts(C: np.ndarray, scale: np.ndarray, rel: float = 1e-6) -> list[np.ndarray]:
    """Directions d with C = sum d d^T (up to rounding) of a symmetric, nearly PSD matrix.

    Decomposed in units of ``scale`` (the parameters' standard uncertainties), so that beta [rad]
    and rho [mm] weigh alike; parts below ``rel`` of a parameter's variance are rounding and dropped.
    """
    sc = np.where(scale > 0, scale, 1.0)
    w, V = np.linalg.eigh(0.5 * (C + C.T) / np.outer(sc, sc))
    return [sc * V[:, i] * math.sqrt(w[i]) for i in range(w.size) if w[i] > rel]


def _device_model_derivatives(model, inputs: list, channels) -> tuple[dict, dict]:
    """Return the derivatives of the corrected readings and time offsets per carried parameter.

    Per carried parameter (``"<entry index>:<name>"``): d(corrected readings)/d(parameter) per scan
    (beam and reading effects) and d(channel time offsets)/d(parameter) (c,) (a channel delay);
    each is zero for the other kind (:func:`borescan.device_model.derivatives`).
    """
    dys: dict[str, list[np.ndarray]] = {}
    for x in inputs:
        y = x.readings_mm if x.readings_recorded_mm is None else x.readings_recorded_mm
        for (i, name), dy in device_model.derivatives(
            model, lambda m, x=x, y=y: device_model.correct(x.t_s, y, x.channels, m, x.range_mm)
        ).items():
            dys.setdefault(f"{i}:{name}", []).append(np.nan_to_num(dy))
    dtau = {
        f"{i}:{name}": d
        for (i, name), d in device_model.derivatives(
            model, lambda m: device_model.channel_time_offsets(m, channels, zeros=True)
        ).items()
    }
    return dys, dtau


def calibration_budget(
    cal,
    inputs: list,
    uncertainty: dict,
    *,
    scan_ids,
    sensitivities: dict | None = None,
    extrema_dof: float | None = None,
    position_accuracy_mm: float | None = None,
) -> Budget:
    """GUM budget of a calibration's parameters (per channel beta, rho, d_b; the calibration's order).

    Terms: the fit's Type A covariance (readings); for ``full_lsq`` the second-order term of d_b in
    rho (where its profile was linear), the spread along each non-linear rho profile beyond the linear
    covariance (``profile<channel>``; a diameter maps it by its own secants along the profile's points,
    :func:`borescan.measure.diameter_uncertainty`) and any unresolved mirror solution (eigen-directions
    of the rest of the fit's covariance, each a rectangular between the two solutions); the reported offset
    S - C of each scan with
    positions (triangular: centre and spindle each within +-a per coordinate,
    ``calibration.position_accuracy_mm``; the same reported positions in several scans are one
    input); the gauge's certified diameter (normal, U / k); the first scan's temperature and the
    gauge's expansion coefficient (rectangular, :func:`borescan.artifacts.scan_temperature`,
    :func:`~borescan.artifacts.artifact_cte`); each sensor's linearity and resolution at the
    calibration (:func:`borescan.measure.sensor_terms`).

    Parameters
    ----------
    cal : the fitted TriCalibration (its ``cov`` the fit's own)
    inputs : per scan :class:`borescan.stages.calibration_fit.SpindleInputs`
    uncertainty : the config's ``uncertainty`` section
    scan_ids : the scans, in the order of ``inputs``
    sensitivities : for a ``yang2017`` calibration: ``dR`` (3c,), ``offset_prior`` {scan_id: (3c, 2)},
        ``reading_offset`` (3c, c); its covariance is then the Type A term with ``extrema_dof``
    position_accuracy_mm : the machine's stated accuracy (``yang2017``; full_lsq states its own)
    """
    names, units = parameter_labels(cal)
    b = Budget(tuple(names), tuple(units), cal.params)
    if cal.method == "full_lsq":
        sens, terms = _full_lsq_terms(cal, inputs)
        prior_u = sens["prior_sigma_mm"]
    else:
        if sensitivities is None or position_accuracy_mm is None:
            raise ValueError("a yang2017 budget needs its sensitivities and position_accuracy_mm")
        sens = sensitivities
        terms = [_yang_term(cal, scan_ids, extrema_dof)]
        prior_u = float(position_accuracy_mm) * math.sqrt(2.0 / 3.0)
    terms += _position_terms(scan_ids, inputs, sens, prior_u)
    terms += _gauge_terms(inputs[0], scan_ids, sens["dR"])
    ys = [np.asarray(x.readings_mm, float) for x in inputs]
    noise = np.sqrt(np.mean([noise_floor_mm(y, order=4) ** 2 for y in ys], axis=0))
    terms += sensor_terms(
        inputs[0].sensors,
        cal.beams.channels,
        sens["reading_offset"],
        cal.calibration_id,
        noise,
        float(uncertainty["sensor_resolution_mm"]),
        "calibration",
    )
    for t in terms:
        b.add(t)
    return b.merged()


def _full_lsq_terms(cal, inputs: list) -> tuple[dict, list[Term]]:
    """Return a ``full_lsq`` calibration's sensitivities and its fit's terms.

    Terms: each carried device-model parameter, the readings' Type A part, the second-order term of
    d_b in rho, each non-linear profile's spread and each unresolved mirror's direction.
    """
    x0 = inputs[0]
    model = device_model.from_dicts(cal.diagnostics.get("device_model"))
    dys, dtau = _device_model_derivatives(model, inputs, cal.beams.channels)
    sens = full_lsq_sensitivities(
        cal,
        [x.t_s for x in inputs],
        [x.readings_mm for x in inputs],
        x0.radius_mm,
        [x.angle_model for x in inputs],
        spindle_xy_mm=[x.spindle_xy_mm for x in inputs],
        center_xy_mm=[x.center_xy_mm for x in inputs],
        reading_perturbations=dys,
    )
    terms = []
    for key, d in dtau.items():  # each carried parameter: through the readings and the channels' times
        i, name = key.split(":", 1)
        terms.append(
            Term(
                device_model.gum_input(cal.device_id, model[int(i)], name),
                sens["reading_perturbation"][key] + sens["channel_time_offset"] @ d,
            )
        )
    n_obs = int(cal.diagnostics.get("n_obs", 0))
    terms.append(
        Term(
            Input(
                f"fit:{cal.calibration_id}:readings",
                "least-squares fit to the readings (their scatter)",
                "v",
                "mm",
                None,
                math.sqrt(sens["s2"]),
                "normal",
                float(cal.dof),
                "A",
                f"{n_obs} readings of {', '.join(cal.scan_ids)}; u is the residual standard deviation "
                "s = sqrt(SSR / dof)",
            ),
            cov=sens["cov_readings"],
        )
    )
    return sens, terms + _fit_extra_terms(cal, sens)


def _fit_extra_terms(cal, sens: dict) -> list[Term]:
    """Return the terms of the fit's covariance beyond the linear one (second order, profiles, mirrors)."""
    c = len(cal.beams.channels)
    profiles = list(cal.diagnostics.get("rho_profiles") or [])
    linear = np.ones(c, dtype=bool)  # where a rho's profile was linear, its second-order term of d_b
    for prof in profiles:
        linear[list(cal.beams.channels).index(int(prof["channel"]))] = bool(prof.get("linear", True))
    second = np.zeros((3 * c, 3 * c))
    second[2::3, 2::3] = np.diag(np.where(linear, sens["second_order_d_b_mm2"], 0.0))
    terms = []
    if np.any(second > 0):
        terms.append(
            Term(
                Input(
                    f"fit:{cal.calibration_id}:second_order",
                    "second-order term of d_b = g - rho^2 / (2R) in rho",
                    "rho^2",
                    "mm^2",
                    None,
                    0.0,
                    "normal",
                    source="3 u(rho)^4 / (4 R^2), fit_full_calibration",
                ),
                cov=second,
            )
        )
    rest = sens["cov_extra"] - second
    for prof in profiles:
        if "extra_cov_params" not in prof:
            continue
        E = np.asarray(prof["extra_cov_params"], dtype=float)
        rest = rest - E
        terms.append(
            Term(
                Input(
                    f"fit:{cal.calibration_id}:profile{prof['channel']}",
                    f"spread along the non-linear profile of rho of channel {prof['channel']} beyond the "
                    "linear covariance",
                    "rho",
                    "mm",
                    None,
                    0.0,
                    "normal",
                    source="fit_full_calibration: likelihood-weighted second moment along the profile "
                    f"(rho {prof['rho_range_mm'][0]:.4f} .. {prof['rho_range_mm'][1]:.4f} mm)",
                ),
                cov=E,
            )
        )
    scale = np.sqrt(np.clip(np.diag(cal.cov), 0.0, None))
    for i, part in enumerate(_rank_one_parts(rest, scale)):
        terms.append(
            Term(
                Input(
                    f"fit:{cal.calibration_id}:mirror{i + 1}",
                    "unresolved mirror solution (the data do not "
                    "reject it): position between the two solutions",
                    "lambda",
                    "-",
                    0.0,
                    1.0 / math.sqrt(3.0),
                    "rectangular",
                    source="fit_full_calibration: mirror solution within 4 s^2 of the kept one",
                ),
                part * math.sqrt(3.0),
            )
        )
    return terms


def _yang_term(cal, scan_ids, extrema_dof: float | None) -> Term:
    """Return a Yang 2017 calibration's Type A term (its covariance from the extrema's scatter)."""
    return Term(
        Input(
            f"fit:{cal.calibration_id}:extrema",
            "mean extreme readings and feature points (their scatter)",
            "d",
            "mm",
            None,
            0.0,
            "normal",
            float(extrema_dof or float("inf")),
            "A",
            f"Yang 2017 Eq. 8-15 from {scan_ids[0]}",
        ),
        cov=cal.cov,
    )


def _position_terms(scan_ids, inputs: list, sens: dict, prior_u: float) -> list[Term]:
    """Return the terms of each scan's reported offset S - C (triangular, per coordinate)."""
    terms = []
    for sid, x in zip(scan_ids, inputs):
        if sid not in sens["offset_prior"] or x.center_xy_mm is None:
            continue
        o = np.subtract(x.spindle_xy_mm, x.center_xy_mm)
        # the same reported spindle position and centre in several scans are one quantity (one error)
        where = "S ({:.4f}, {:.4f}) C ({:.4f}, {:.4f})".format(*x.spindle_xy_mm, *x.center_xy_mm)
        for axis, name in enumerate("xy"):
            terms.append(
                Term(
                    Input(
                        f"position:{where}:{name}",
                        f"reported spindle-to-centre offset {name} (S - C), {where} mm",
                        f"o_{name}",
                        "mm",
                        float(o[axis]),
                        prior_u,
                        "triangular",
                        source="scan.json spindle.position and center, each within +- the machine's stated "
                        "accuracy (calibration.position_accuracy_mm)",
                    ),
                    sens["offset_prior"][sid][:, axis],
                )
            )
    return terms


def _gauge_terms(x0, scan_ids, dR: np.ndarray) -> list[Term]:
    """Return the gauge radius's terms: certified diameter, temperature, expansion coefficient."""
    art, temp, cte = x0.artifact, x0.temperature, x0.cte
    d20 = float(art.get("certified_diameter_mm", art.get("nominal_diameter_mm")))
    dT = temp.temperature_c - REFERENCE_TEMPERATURE_C
    gkey = f"gauge:{artifact_key(art)}"
    k_cert = float(art.get("k") or 2.0)
    u_d20 = float(art.get("u_diameter_mm") or 0.0) / k_cert
    f = thermal_expansion_factor(cte.cte_per_k, temp.temperature_c)
    return [
        Term(
            Input(
                f"{gkey}:D20",
                f"certified diameter of ring gauge {art.get('id')} at 20 degC",
                "D_g",
                "mm",
                d20,
                u_d20,
                "normal",
                source=f"certificate {art.get('certificate')}: U = {art.get('u_diameter_mm')} mm "
                f"(k = {k_cert:g})",
            ),
            dR * 0.5 * f,
        ),
        Term(
            temp.budget_input(f"temperature:{scan_ids[0]}", f"temperature of the gauge during {scan_ids[0]}"),
            dR * 0.5 * d20 * cte.cte_per_k,
        ),
        Term(
            cte.budget_input(
                f"cte:{artifact_key(art)}", f"expansion coefficient of ring gauge {art.get('id')}"
            ),
            dR * 0.5 * d20 * dT,
        ),
    ]


def with_budget(cal, budget: Budget):
    """Return the calibration with the budget's combined covariance as ``cov``.

    Return the calibration with the budget's combined covariance as ``cov``; the fit's own covariance
    is kept as ``diagnostics["cov_fit"]`` and the budget as ``diagnostics["budget"]``.
    """
    diag = dict(cal.diagnostics)
    diag["cov_fit"] = np.asarray(cal.cov).tolist()
    diag["budget"] = budget.to_dict()
    return replace(cal, cov=budget.covariance(), diagnostics=diag)
