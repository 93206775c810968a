"""A full-data calibration on its own scans again: residuals, and sensitivities for its GUM budget.

:func:`full_residuals` gives model - reading of a ``full_lsq`` calibration on one of its scans;
:func:`full_lsq_sensitivities` the linear sensitivities of its parameters to what the fit takes as
known (implicit differentiation of the least-squares optimum), which the budget
(:mod:`borescan.calibrate.budget`) multiplies by the inputs' uncertainties.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from borescan.calibrate.censoring import censoring_keep, guard_sigma
from borescan.calibrate.problem import (
    NuisanceColumns,
    channel_offsets,
    nuisance_columns,
    per_scan_xy,
    public_index,
)
from borescan.calibrate.result import AcceptanceRule, TriCalibration
from borescan.geometry import Bore
from borescan.kinematics import AngleModel
from borescan.noise import noise_floor_mm
from borescan.physics.tri import commanded_device_angle, tri_readings_at, tri_spindle_jacobian

__all__ = ["full_residuals", "full_lsq_sensitivities"]


def full_residuals(
    cal: TriCalibration,
    t_s,
    readings_mm,
    R_mm: float,
    scan_id: str | None = None,
    angle_model: AngleModel | None = None,
) -> np.ndarray:
    """Residuals (model - reading) (n, c) [mm] of a ``full_lsq`` calibration on one of its scans.

    Uses the scan's fitted offset, phase and speed scale from ``cal.nuisance`` with the scan's
    ``angle_model`` (default: constant speed ``omega_rad_s``); NaN readings give NaN residuals.
    """
    if cal.method != "full_lsq":
        raise ValueError(f"full_residuals needs a full_lsq calibration, got {cal.method!r}")
    scan_id = scan_id if scan_id is not None else cal.scan_ids[0]
    nu = cal.nuisance[scan_id]
    t = np.asarray(t_s, dtype=float)
    tau_c = channel_offsets(cal.diagnostics.get("channel_time_offsets_s"), len(cal.beams.channels))
    t = t if tau_c is None else t[:, None] - tau_c[None, :]
    if angle_model is None:
        phi = nu["phase0_rad"] + nu["omega_rad_s"] * t
    else:
        phi = angle_model.phi_rad(t, nu["phase0_rad"], nu.get("speed_scale", 1.0))
    off = np.array([nu["offset_x_mm"], nu["offset_y_mm"]])
    model = tri_readings_at(phi, off, cal.beams, Bore((0.0, 0.0), R_mm))
    return model - np.asarray(readings_mm, dtype=float)


@dataclass(frozen=True)
class _Linearised:
    """The readings' Jacobian at a calibration's solution, stacked over its scans' used readings.

    J (rows, p) in the public free parameters; dv_dR (rows,); chan (rows,) each row's channel index;
    masks per scan (n, c) the used readings; dtau per scan (n, c) d model / d tau of each reading;
    Jp (2 per prior, p) the prior rows; prior_rows {scan_id: index of its pair}; w the prior weight.
    """

    J: np.ndarray
    dv_dR: np.ndarray
    chan: np.ndarray
    masks: list[np.ndarray]
    dtau: list[np.ndarray]
    Jp: np.ndarray
    prior_rows: dict[str, int]
    w: float
    prior_sigma: float


def _columns(cal: TriCalibration, angle_models: Sequence[AngleModel], ch0_free: int):
    """Return each scan's nuisance columns and the vector's length, as the fit laid them out."""
    c = len(cal.beams.channels)
    free_phase = [bool(cal.nuisance[sid].get("phase_free")) for sid in cal.scan_ids]
    commanded = [am.fits_speed_and_phase for am in angle_models]
    return nuisance_columns(3 * c - 1 + ch0_free, free_phase, commanded)


def _scan_jacobian(
    cal, k: int, t: np.ndarray, y, am: AngleModel, cl: NuisanceColumns, p: int, ch0_free, R_mm
):
    """Return scan ``k``'s readings (n, c), Jacobian (n, c, p), jac dict (n, c) and d/dtau (n, c)."""
    beams, c = cal.beams, len(cal.beams.channels)
    nu = cal.nuisance[cal.scan_ids[k]]
    tau_c = channel_offsets(cal.diagnostics.get("channel_time_offsets_s"), c)

    def phi_at(tt):
        P = am.commanded_rad(tt)
        if not am.fits_speed_and_phase:
            return P
        return commanded_device_angle(P, float(nu["phase0_rad"]), float(nu.get("speed_scale", 1.0)))

    tc = np.repeat(t[:, None], c, axis=1) - (0.0 if tau_c is None else tau_c[None, :])
    Phi = am.commanded_rad(tc)
    phi = phi_at(tc)
    off = np.array([nu["offset_x_mm"], nu["offset_y_mm"]], dtype=float)
    v_k, jac = tri_spindle_jacobian(phi, beams, off, R_mm)
    jac = {name: a.T for name, a in jac.items()}  # (n, c) views
    # the model's readings per unit of a channel's time offset: phi of channel c at t - tau_c
    h = 1e-6
    dtau = jac["phi"] * (phi_at(tc - h) - phi_at(tc + h)) / (2.0 * h)
    Jk = np.zeros((t.size, c, p))
    for j in range(c):
        if j > 0 or ch0_free:
            Jk[:, j, j - 1 + ch0_free] = jac["beta"][:, j]
        Jk[:, j, c - 1 + ch0_free + j] = jac["rho"][:, j]
        Jk[:, j, 2 * c - 1 + ch0_free + j] = -1.0
    Jk[:, :, cl.ox] = jac["ox"]
    Jk[:, :, cl.oy] = jac["oy"]
    if cl.phase is not None:
        Jk[:, :, cl.phase] = jac["phi"]
    if cl.scale is not None:
        Jk[:, :, cl.scale] = jac["phi"] * Phi
    return v_k, Jk, jac, dtau


def _linearise(cal, ts, ys, R_mm, angle_models, priors, ch0_free) -> _Linearised:
    """Return the Jacobian of the fit's rows at the calibration (:class:`_Linearised`)."""
    c = len(cal.beams.channels)
    cols, p = _columns(cal, angle_models, ch0_free)
    floors = np.array([noise_floor_mm(y, order=4) for y in ys])
    sigma = float(np.sqrt(np.mean(floors**2))) if np.all(np.isfinite(floors)) else 0.0
    a = float(
        cal.diagnostics.get("acceptance", {}).get(
            "position_accuracy_mm", AcceptanceRule.defaults().position_accuracy_mm
        )
    )
    prior_sigma = a * np.sqrt(2.0 / 3.0)
    w = (sigma if sigma > 0 else 1e-3) / prior_sigma
    guard = cal.diagnostics.get("censoring_guard")
    guard_range = np.asarray(guard["range_mm"], dtype=float) if guard else None
    J_parts, dR_parts, chan_parts, masks, dtaus = [], [], [], [], []
    for k, (t, y, am) in enumerate(zip(ts, ys, angle_models)):
        v_k, Jk, jac, dtau = _scan_jacobian(cal, k, t, y, am, cols[k], p, ch0_free, R_mm)
        m = np.isfinite(y)
        if guard is not None:  # the readings the fit set aside near the sensor range limits
            m &= censoring_keep(v_k, y, guard_range, guard_sigma(floors[k], sigma))[0]
        J_parts.append(Jk[m])
        masks.append(m)
        dtaus.append(dtau)
        dR_parts.append(np.hypot(jac["ox"], jac["oy"])[m])
        chan_parts.append(np.broadcast_to(np.arange(c), (t.size, c))[m])
    Jp_rows, prior_rows = [], {}
    for k, sid in enumerate(cal.scan_ids):
        if priors[k] is None:
            continue
        row = np.zeros((2, p))
        row[0, cols[k].ox] = w
        row[1, cols[k].oy] = w
        prior_rows[sid] = len(Jp_rows)
        Jp_rows.append(row)
    return _Linearised(
        J=np.vstack(J_parts),
        dv_dR=np.concatenate(dR_parts),
        chan=np.concatenate(chan_parts),
        masks=masks,
        dtau=dtaus,
        Jp=np.vstack(Jp_rows) if Jp_rows else np.zeros((0, p)),
        prior_rows=prior_rows,
        w=float(w),
        prior_sigma=float(prior_sigma),
    )


def full_lsq_sensitivities(
    cal: TriCalibration,
    t_s,
    readings_mm,
    R_mm: float,
    angle_models: Sequence[AngleModel],
    *,
    spindle_xy_mm=None,
    center_xy_mm=None,
    reading_perturbations: Mapping[str, Sequence[np.ndarray]] | None = None,
) -> dict[str, Any]:
    """Return a ``full_lsq`` calibration's sensitivities and covariance split.

    Linear sensitivities of a ``full_lsq`` calibration to what it takes as known, and the split
    of its covariance into the readings' part and the position priors' part.

    At the solution, J is the Jacobian of the readings' residuals with respect to the free public
    parameters p (beta where free, rho, d_b, per scan the offset o = S - C, the phase where free
    and the speed scale without an encoder), Jp that of the prior rows w (o - o_reported) with
    w = sigma / (a sqrt(2/3)) (sigma the readings' noise floor, a the stated position accuracy,
    as in the fit), H = J^T J + Jp^T Jp and s^2 = SSR / dof. The estimate stays the minimum when
    an input moves, so to first order (implicit differentiation of the normal equations):

    - gauge radius: dp/dR = -H^-1 J^T dv/dR, with dv/dR = R / (P . Rot(phi) u) from |P| = R,
      P the wall point relative to the gauge centre (dv/dR equals |(dv/do_x, dv/do_y)|);
    - a constant error e_c of every reading of channel c: dp/de_c = H^-1 J^T 1_c;
    - the reported offset of scan k (prior mean): dp/do_k = H^-1 Jp_k^T w;
    - covariance of the fit: s^2 H^-1 = s^2 H^-1 J^T J H^-1 (readings) + s^2 H^-1 Jp^T Jp H^-1
      (priors). The calibration's ``cov`` adds to s^2 H^-1 the second-order term of d_b in rho,
      the spread along a non-linear rho profile and any unresolved minimum; ``cov_extra`` is that
      difference.

    Parameters
    ----------
    cal : the ``full_lsq`` TriCalibration (its nuisance, diagnostics cost and acceptance)
    t_s, readings_mm : per scan (lists), exactly what the fit saw (despiked readings, NaN missing)
    R_mm : the gauge radius the fit used [mm]
    angle_models : per scan AngleModel, as given to the fit
    spindle_xy_mm, center_xy_mm : per scan reported positions (None where unknown), as given to the fit
    reading_perturbations : name -> per scan dy (n, c): readings that move by dy per unit of a
        quantity (e.g. a carried device-model parameter); dp = H^-1 J^T dy for each

    Returns
    -------
    dict with, in the calibration's (3c,) parameter order (gauge-fixed beta: 0):
    ``dR`` (3c,) [per mm], ``reading_offset`` (3c, c) [-], ``offset_prior`` {scan_id: (3c, 2)} [-],
    ``cov_readings``, ``cov_priors``, ``cov_linear`` (= their sum), ``cov_extra`` (3c, 3c),
    ``s2`` [mm^2], ``prior_sigma_mm`` (u of each reported offset coordinate) and
    ``second_order_d_b_mm2`` (c,) (the d_b variance term 3 u(rho)^4 / (4 R^2)),
    ``reading_perturbation`` {name: (3c,)} (per ``reading_perturbations``) and
    ``channel_time_offset`` (3c, c) [per s] (dp / d tau_c: the time at which channel c's readings are
    taken, as a carried ``channel_delay``).
    """
    if cal.method != "full_lsq":
        raise ValueError(f"full_lsq_sensitivities needs a full_lsq calibration, got {cal.method!r}")
    ts = [np.asarray(x, dtype=float) for x in t_s]
    ys = [np.asarray(x, dtype=float) for x in readings_mm]
    K = len(ts)
    if len(ys) != K or len(angle_models) != K or len(cal.scan_ids) != K:
        raise ValueError("t_s, readings_mm, angle_models and the calibration's scans must correspond")
    c = len(cal.beams.channels)
    Ss, Cs = per_scan_xy(spindle_xy_mm, K), per_scan_xy(center_xy_mm, K)
    priors = [None if (Ss[k] is None or Cs[k] is None) else Ss[k] - Cs[k] for k in range(K)]
    ch0_free = 1 if cal.diagnostics.get("beta_reference") == "absolute" else 0
    lin = _linearise(cal, ts, ys, R_mm, angle_models, priors, ch0_free)
    J, Jp = lin.J, lin.Jp
    colnorm = np.sqrt(np.sum(J**2, axis=0) + np.sum(Jp**2, axis=0))
    colnorm[colnorm == 0] = 1.0
    Hs = (J / colnorm).T @ (J / colnorm) + (Jp / colnorm).T @ (Jp / colnorm)
    Hinv = np.linalg.pinv(Hs, rcond=1e-15, hermitian=True) / np.outer(colnorm, colnorm)
    s2 = 2.0 * float(cal.diagnostics["cost"]) / float(cal.dof)
    idx = public_index(c, ch0_free)  # public free parameters -> the calibration's (3c,) order
    ok = idx >= 0

    def vec(x: np.ndarray) -> np.ndarray:
        out = np.zeros((3 * c,) + x.shape[1:])
        out[ok] = x[idx[ok]]
        return out

    def mat(C: np.ndarray) -> np.ndarray:
        out = np.zeros((3 * c, 3 * c))
        out[np.ix_(ok, ok)] = C[np.ix_(idx[ok], idx[ok])]
        return out

    def response(dys) -> np.ndarray:  # dp = H^-1 J^T dy: readings that move by dy (per scan (n, c))
        return vec(Hinv @ (J.T @ np.concatenate([np.asarray(d, float)[m] for d, m in zip(dys, lin.masks)])))

    # a channel's time offset moves the model's readings by df; the fit answers as to readings moved by -df
    time_offset = np.column_stack(
        [response([-np.where(np.arange(c)[None, :] == j, d, 0.0) for d in lin.dtau]) for j in range(c)]
    )
    A, B = Hinv @ J.T, Hinv @ Jp.T
    cov_linear = mat(s2 * Hinv)
    return {
        "dR": vec(-Hinv @ (J.T @ lin.dv_dR)),
        "reading_offset": np.column_stack([vec(Hinv @ J[lin.chan == j].sum(axis=0)) for j in range(c)]),
        "offset_prior": {
            sid: vec(Hinv @ Jp[2 * r0 : 2 * r0 + 2].T * lin.w) for sid, r0 in lin.prior_rows.items()
        },
        "cov_readings": mat(s2 * (A @ A.T)),
        "cov_priors": mat(s2 * (B @ B.T)),
        "cov_linear": cov_linear,
        "cov_extra": cal.cov - cov_linear,
        "s2": s2,
        "prior_sigma_mm": lin.prior_sigma,
        "second_order_d_b_mm2": 3.0 * np.diag(cov_linear)[1::3] ** 2 / (4.0 * R_mm**2),
        "reading_perturbation": {name: response(dys) for name, dys in (reading_perturbations or {}).items()},
        "channel_time_offset": time_offset,
    }
