"""Diameters: static three-sensor readings, rotating scans, and verification against gauges.

Static (Yang 2017, Eqs. 1-7 in coordinate form): each reading v_i puts a wall point at
W_i = rho_i n_i + (d_b,i + v_i) u_i in the device frame (``geometry.wall_points_device``); the
bore is the circumcircle of the three points (least-squares circle with more channels) and
D = 2R. The uncertainty is first-order propagation with the exact Jacobian

    dR = sum_i g_i  nhat_i . dW_i,   g = last row of (A^T A)^-1 A^T,  A_i = [nhat_i^T, 1],

nhat_i the unit vector from the centre to W_i (A is square for three channels: the
circumcircle), with dW/dbeta = -rho u + s n, dW/drho = n, dW/dd_b = dW/dv = u, s = d_b + v.

Rotating (device on a spindle): wall points in machine coordinates p = S + Rot(phi) W; the
least-squares circle gives the diameter, the ISO 12181 reference circles the roundness, and
``circlefit.harmonic_spectrum`` the undulations per revolution.

GUM budget of a diameter (:func:`diameter_uncertainty`): the calibration's own budget (its
fit, gauge, temperature, expansion coefficient, positions, sensor linearity; carried in the
calibration's ``diagnostics["budget"]``) mapped through dD/d(beta, rho, d_b); the readings'
scatter (Type A); each sensor's linearity and resolution at this measurement (independent of
those at the calibration: the data sheet bounds the deviation anywhere in the range, not its
shape); and the temperature correction to 20 degC (ISO 1), D20 = D_T / (1 + alpha (T - 20)),
with the part's temperature and expansion coefficient. Every diameter is given at the measured
temperature and at 20 degC. A verification compares D20 with the gauge's certified D20; where
the gauge is the calibration's own, its certified diameter enters both and its sensitivity is
the difference (:meth:`borescan.uncertainty.Budget.merged`). The verdict follows the configured
decision rule (:func:`decide`, ILAC-G8:09/2019).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from . import device_model
from .artifacts import ArtifactCte, ScanTemperature, artifact_key, diameter_at_20, number_or_none
from .atomic import json_ready
from .effects import thermal_expansion_factor
from .circlefit import Circle, fit_circle_ls, harmonic_spectrum, reference_circles
from .decision import DECISION_RULES as _DECISION_RULES
from .decision import decision
from .geometry import Beams, beam_frame, circumcircle, wall_points_device
from .uncertainty import Budget, Combined, Input, Term

__all__ = [
    "part_feature",
    "part_conformity",
    "StaticDiameter",
    "RotatingResult",
    "Verification",
    "static_diameter",
    "static_diameter_jacobian",
    "wall_points_machine",
    "measure_rotating",
    "measure_scan",
    "verify",
    "pose_means",
    "reading_u_mm",
    "mean_reading_u_mm",
    "diameter_row",
    "verification_row",
    "sensor_terms",
    "DiameterUncertainty",
    "diameter_uncertainty",
    "DECISION_RULES",
    "decide",
    "verify_budget",
    "DiameterModel",
    "calibration_budget_of",
    "tri_diameter_with_budget",
    "verification_for_certificate",
]


@dataclass(frozen=True)
class StaticDiameter:
    """Result of :func:`static_diameter` (arrays of shape (k,) or scalars for one reading set).

    diameter_mm, u_diameter_mm (k = 1, combined), u_calibration_mm (from ``cov_beams``),
    u_readings_mm (from ``u_reading_mm``), center_xy_mm (device frame, (k, 2) or (2,)).
    """

    diameter_mm: np.ndarray | float
    u_diameter_mm: np.ndarray | float
    u_calibration_mm: np.ndarray | float
    u_readings_mm: np.ndarray | float
    center_xy_mm: np.ndarray
    method: str = "circumcircle"


def static_diameter_jacobian(
    readings_mm, beams: Beams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Diameter and its exact first derivatives for static readings.

    Parameters
    ----------
    readings_mm : ndarray (k, c) readings [mm], channels in ``beams`` order, all finite
    beams : Beams

    Returns
    -------
    D_mm : (k,); dD_dparams : (k, 3c) per channel (beta [mm/rad], rho [-], d_b [-]);
    dD_dv : (k, c) [-]; center : (k, 2) [mm]
    """
    v = np.atleast_2d(np.asarray(readings_mm, dtype=float))
    k, c = v.shape
    W = wall_points_device(v, beams)  # (k, c, 2)
    if c == 3:
        center, R = circumcircle(W)
    else:
        center = np.empty((k, 2))
        R = np.empty(k)
        for i in range(k):
            fit = fit_circle_ls(W[i, :, 0], W[i, :, 1])
            center[i], R[i] = fit.center_xy_mm, fit.radius_mm
    dW = W - center[:, None, :]
    nhat = dW / np.linalg.norm(dW, axis=-1, keepdims=True)  # (k, c, 2)
    A = np.concatenate([nhat, np.ones((k, c, 1))], axis=-1)  # (k, c, 3)
    G = np.linalg.solve(np.einsum("kci,kcj->kij", A, A), np.swapaxes(A, 1, 2))  # (k, 3, c)
    g = G[:, 2, :]  # dR / d(nhat_i . dW_i)
    _, u = beam_frame(beams.beta_rad, beams.rho_mm)
    n = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    s = beams.d_b_mm + v  # (k, c)
    dW_dbeta = -beams.rho_mm[None, :, None] * u[None] + s[..., None] * n[None]  # (k, c, 2)
    nu = np.einsum("kci,ci->kc", nhat, u)
    nn = np.einsum("kci,ci->kc", nhat, n)
    nb = np.einsum("kci,kci->kc", nhat, dW_dbeta)
    dD_dparams = np.empty((k, 3 * c))
    dD_dparams[:, 0::3] = 2 * g * nb
    dD_dparams[:, 1::3] = 2 * g * nn
    dD_dparams[:, 2::3] = 2 * g * nu
    dD_dv = 2 * g * nu
    return 2.0 * R, dD_dparams, dD_dv, center


def static_diameter(readings_mm, beams: Beams, cov_beams=None, u_reading_mm=0.0) -> StaticDiameter:
    """Return static diameter from one or k sets of readings, with its standard uncertainty.

    D = 2 R, R the circumradius of the wall points (Yang 2017, Eq. 3 with Eqs. 4-7 in
    coordinate form; the least-squares circle for c > 3 channels). Uncertainty:
    u^2 = j_p^T cov_beams j_p + sum_i (dD/dv_i)^2 u_v^2 (GUM first order, exact Jacobian).

    Parameters
    ----------
    readings_mm : ndarray (c,) or (k, c) [mm]; rows with a NaN give NaN
    beams : Beams (calibrated)
    cov_beams : ndarray (3c, 3c) or None; order per channel (beta_rad, rho_mm, d_b_mm)
    u_reading_mm : float or (c,) standard uncertainty of one reading [mm]

    Returns
    -------
    StaticDiameter (scalars for a (c,) input)
    """
    v = np.asarray(readings_mm, dtype=float)
    single = v.ndim == 1
    v2 = np.atleast_2d(v)
    k, c = v2.shape
    if c != len(beams.channels):
        raise ValueError(f"readings have {c} channels, beams have {len(beams.channels)}")
    if c < 3:
        raise ValueError("a static diameter needs at least three channels")
    ok = np.all(np.isfinite(v2), axis=1)
    D = np.full(k, np.nan)
    center = np.full((k, 2), np.nan)
    u_cal = np.zeros(k)
    u_rd = np.zeros(k)
    if ok.any():
        Dk, jp, jv, ck = static_diameter_jacobian(v2[ok], beams)
        D[ok], center[ok] = Dk, ck
        if cov_beams is not None:
            cov = np.asarray(cov_beams, dtype=float)
            if cov.shape != (3 * c, 3 * c):
                raise ValueError(f"cov_beams must be ({3 * c}, {3 * c}), got {cov.shape}")
            u_cal[ok] = np.sqrt(np.einsum("ki,ij,kj->k", jp, cov, jp))
        uv = np.broadcast_to(np.asarray(u_reading_mm, dtype=float), (c,))
        u_rd[ok] = np.sqrt(np.sum((jv * uv) ** 2, axis=1))
    u_cal[~ok] = np.nan
    u_rd[~ok] = np.nan
    u = np.hypot(u_cal, u_rd)
    method = "circumcircle" if c == 3 else "least-squares circle"
    if single:
        return StaticDiameter(float(D[0]), float(u[0]), float(u_cal[0]), float(u_rd[0]), center[0], method)
    return StaticDiameter(D, u, u_cal, u_rd, center, method)


# --------------------------------------------------------------------------- rotating scans


@dataclass(frozen=True)
class RotatingResult:
    """Diameter and form of a rotating scan (machine coordinates).

    diameter_mm, u_diameter_mm : least-squares circle (u from the residual scatter, k=1)
    circles : {"LSCI", "MZCI", "MICI", "MCCI"} -> Circle; ront_mm : {name: RONt [mm]}
    upr, amplitude_mm : harmonic spectrum of the radial deviation about the LS centre
    x_mm, y_mm : wall points used
    """

    diameter_mm: float
    u_diameter_mm: float
    circles: dict[str, Circle]
    ront_mm: dict[str, float]
    upr: np.ndarray
    amplitude_mm: np.ndarray
    x_mm: np.ndarray = field(repr=False)
    y_mm: np.ndarray = field(repr=False)


def wall_points_machine(readings_mm, phi_rad, spindle_xy_mm, beams: Beams) -> np.ndarray:
    """Wall points p = S + Rot(phi) W(v) in machine coordinates (spec "Spindle scan").

    readings_mm (n, c); phi_rad (n,) or (n, c); spindle_xy_mm (2,) or (n, 2). Returns (n, c, 2).
    """
    W = wall_points_device(readings_mm, beams)
    phi = np.asarray(phi_rad, dtype=float)
    if phi.ndim == 1:
        phi = phi[:, None]
    cph, sph = np.cos(phi), np.sin(phi)
    S = np.asarray(spindle_xy_mm, dtype=float)
    if S.ndim == 2:
        S = S[:, None, :]
    return S + np.stack([cph * W[..., 0] - sph * W[..., 1], sph * W[..., 0] + cph * W[..., 1]], axis=-1)


def measure_rotating(
    readings_mm, phi_rad, spindle_xy_mm, beams: Beams, *, max_upr: int = 50
) -> RotatingResult:
    """Diameter, ISO 12181 roundness and harmonic spectrum of a rotating scan.

    All channels' wall points (NaN readings dropped) are pooled; the LS circle gives the
    diameter; MZCI/MICI/MCCI and their RONt give the form; the spectrum is taken of
    r(theta) about the LS centre.
    """
    P = wall_points_machine(readings_mm, phi_rad, spindle_xy_mm, beams).reshape(-1, 2)
    P = P[np.all(np.isfinite(P), axis=1)]
    x, y = P[:, 0], P[:, 1]
    circles = reference_circles(x, y)
    ls = circles["LSCI"]
    th = np.arctan2(y - ls.center_xy_mm[1], x - ls.center_xy_mm[0])
    r = np.hypot(x - ls.center_xy_mm[0], y - ls.center_xy_mm[1])
    upr, amp, _ = harmonic_spectrum(th, r, max_upr=min(max_upr, (x.size - 1) // 2))
    return RotatingResult(
        diameter_mm=ls.diameter_mm,
        u_diameter_mm=ls.u_diameter_mm,
        circles=circles,
        ront_mm={k: c.ront_mm for k, c in circles.items()},
        upr=upr,
        amplitude_mm=amp,
        x_mm=x,
        y_mm=y,
    )


def _rotating_angle(scan, t_s: np.ndarray, v: np.ndarray, tau_s: np.ndarray | None = None) -> np.ndarray:
    """Return the device angle at the readings.

    Device angle at the readings (:mod:`borescan.kinematics`): the encoder angle, else the
    commanded profile with its speed scale found from the readings (the phase of a closed
    profile does not change a circle's diameter or roundness). With per channel time offsets
    ``tau_s`` (c,) (a carried ``channel_delay``) the angle of channel c at t - tau_c, (n, c).
    """
    from .kinematics import angle_model_of_scan, estimate_speed_scale

    am = angle_model_of_scan(scan.meta, scan.spindle)
    tc = t_s if tau_s is None else t_s[:, None] - np.asarray(tau_s, float)[None, :]
    if not am.fits_speed_and_phase:
        return am.phi_rad(tc)
    return estimate_speed_scale(am.commanded_rad(t_s), v) * am.commanded_rad(tc)


@dataclass(frozen=True)
class DiameterModel:
    """The diameter of one scan as a function of the beams, with the scan's readings fixed.

    ``kind`` ``"static"``: ``readings_mm`` (k, c) the poses' mean readings, D = mean over the poses
    of :func:`static_diameter`; ``"rotating"``: ``readings_mm`` (n, c), ``phi_rad`` (n,),
    ``spindle_xy_mm`` (n, 2), D = the least-squares circle of :func:`wall_points_machine`.
    ``offsets_mm`` (c,) adds a constant to every reading of a channel.
    """

    kind: str
    readings_mm: np.ndarray = field(repr=False)
    phi_rad: np.ndarray | None = field(default=None, repr=False)
    spindle_xy_mm: np.ndarray | None = field(default=None, repr=False)
    #: least-squares circles of the wall points already fitted, by beams (:meth:`ls_circle`)
    _circles: dict = field(default_factory=dict, repr=False, compare=False)

    def __call__(self, beams: Beams, offsets_mm=None) -> float:
        """Return the diameter [mm] with ``beams`` and readings moved by ``offsets_mm``."""
        v = self.readings_mm if offsets_mm is None else self.readings_mm + np.asarray(offsets_mm, float)
        if self.kind == "static":
            return float(np.mean(static_diameter(v, beams).diameter_mm))
        if offsets_mm is None:
            return self.ls_circle(beams).diameter_mm
        P = wall_points_machine(v, self.phi_rad, self.spindle_xy_mm, beams).reshape(-1, 2)
        P = P[np.all(np.isfinite(P), axis=1)]
        return fit_circle_ls(P[:, 0], P[:, 1]).diameter_mm

    def ls_circle(
        self, beams: Beams, points_mm: np.ndarray | None = None, circle: Circle | None = None
    ) -> Circle:
        """Return the least-squares circle of a rotating scan's wall points.

        Return the least-squares circle of a rotating scan's finite wall points with ``beams``, fitted once
        per beams: ``points_mm`` (m, 2) those points when the caller has them; ``circle`` one the
        caller has fitted to them (:func:`measure_rotating`'s LSCI), remembered as it is.
        """
        key = (beams.channels, beams.beta_rad.tobytes(), beams.rho_mm.tobytes(), beams.d_b_mm.tobytes())
        if circle is not None:
            self._circles[key] = circle
        if key not in self._circles:
            if points_mm is None:
                P = wall_points_machine(self.readings_mm, self.phi_rad, self.spindle_xy_mm, beams).reshape(
                    -1, 2
                )
                points_mm = P[np.all(np.isfinite(P), axis=1)]
            self._circles[key] = fit_circle_ls(points_mm[:, 0], points_mm[:, 1])
        return self._circles[key]


def _with_params(beams: Beams, delta: np.ndarray) -> Beams:
    """Beams moved by ``delta`` (3c,), per channel (beta, rho, d_b)."""
    d = np.asarray(delta, dtype=float)
    return Beams(beams.channels, beams.beta_rad + d[0::3], beams.rho_mm + d[1::3], beams.d_b_mm + d[2::3])


def _rotating_sensitivities(model: DiameterModel, beams: Beams) -> tuple[np.ndarray, np.ndarray]:
    """Return the LS circle's diameter sensitivities of a rotating scan.

    dD/d(beta, rho, d_b) (3c,) and dD/d(constant reading error of channel c) (c,) of the LS
    circle of a rotating scan.

    The circle (a, b, r) minimises sum_i (|P_i - c| - r)^2; moving the wall points by dP moves it
    by -(J^T J)^-1 J^T (e_i . dP_i) (J the residuals' Jacobian [-e_x, -e_y, -1], e_i the unit
    vector from the centre to P_i; Gauss-Newton, exact up to the residuals over R, about 1e-8
    here), so one circle fit and the points' derivatives give every sensitivity; D = 2 r.

    The points' derivatives are exact: P = S + Rot(phi) W, W = F + s u, s = d_b + v, with
    (:func:`borescan.geometry.beam_frame`) u = (cos beta, sin beta), n = (-sin beta, cos beta),
    F = rho n, so dF/dbeta = -rho u, dF/drho = n, du/dbeta = n and

        dP/dbeta = Rot(phi) (s n - rho u),  dP/drho = Rot(phi) n,  dP/dd_b = dP/dv = Rot(phi) u,

    for the points of the beam's own channel only. With g_i = dr / d(e_i . dP_i) and
    w_i = Rot(-phi_i) e_i (e_i in the device frame), per channel A = sum_i g_i w_i [-] and
    B = sum_i g_i s_i w_i [mm] over its finite points:

        dD/dbeta = 2 (B . n - rho A . u) [mm/rad],  dD/drho = 2 A . n,  dD/dd_b = dD/dv = 2 A . u [-].
    """
    v = np.asarray(model.readings_mm, dtype=float)
    P = wall_points_machine(v, model.phi_rad, model.spindle_xy_mm, beams)  # (n, c, 2)
    ok = np.all(np.isfinite(P), axis=-1)  # (n, c)
    Pk = P[ok]  # the points in the order of P.reshape(-1, 2)
    circ = model.ls_circle(beams, Pk)
    d = Pk - np.asarray(circ.center_xy_mm)
    e = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    J = np.column_stack([-e, -np.ones(e.shape[0])])
    g = np.zeros(ok.shape)
    g[ok] = -np.linalg.solve(J.T @ J, J.T)[2]  # d r / d (e . dP), per point; 0 where no point
    ex, ey = np.zeros(ok.shape), np.zeros(ok.shape)
    ex[ok], ey[ok] = e[:, 0], e[:, 1]
    phi = np.broadcast_to(np.asarray(model.phi_rad, dtype=float).reshape(v.shape[0], -1), v.shape)
    cph, sph = np.cos(phi), np.sin(phi)
    w = np.stack([cph * ex + sph * ey, cph * ey - sph * ex], axis=-1)  # Rot(-phi) e, (n, c, 2)
    s = np.where(ok, beams.d_b_mm + v, 0.0)
    A = np.einsum("kc,kci->ci", g, w)
    B = np.einsum("kc,kci->ci", g * s, w)
    _, u = beam_frame(beams.beta_rad, beams.rho_mm)
    n = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    Au, An, Bn = np.sum(A * u, axis=1), np.sum(A * n, axis=1), np.sum(B * n, axis=1)
    jp = np.empty(3 * len(beams.channels))
    jp[0::3] = 2.0 * (Bn - beams.rho_mm * Au)
    jp[1::3] = 2.0 * An
    jp[2::3] = 2.0 * Au
    return jp, 2.0 * Au


def measure_scan(scan, beams: Beams, cov_beams=None, device_model=(), cleaning=None) -> dict:
    """Diameter of one ``tri_lds`` raw scan (``rawio.RawScan``) with calibrated ``beams``.

    With a spindle stream: rotating scan (angle from :mod:`borescan.kinematics`: the encoder
    angle, else the rpm profile with its speed scale from the readings; spindle position
    interpolated to the LDS times),
    :func:`measure_rotating`. Without: static poses (the ``pose`` column; all samples one pose
    if it is null). Per pose the mean reading per channel, u of the mean = max(scatter,
    repeatability) / sqrt(samples), gives :func:`static_diameter`; the scan's diameter is the
    mean over poses with u^2 = u_cal^2 (common to all poses) + var(pose diameters) / k.

    Returns
    -------
    dict with diameter_mm, u_diameter_mm, method; rotating: ront_mm per circle; static: poses
    (list of dicts pose, diameter_mm, u_diameter_mm). For the GUM budget
    (:func:`diameter_uncertainty`): ``jac_params`` (3c,) dD/d(beta, rho, d_b) and
    ``jac_readings`` (c,) dD/d(a constant error of every reading of a channel) (means over the
    poses; rotating: the LS circle moved by the points' exact derivatives,
    :func:`_rotating_sensitivities`), ``u_readings_mm`` and ``dof_readings`` (the readings' part
    of u: Type A, or the sensors' repeatability where that is larger than the scatter, nu = inf),
    ``noise_mm`` (c,) the readings' scatter per channel and
    ``model`` (:class:`DiameterModel`, D as a function of the beams with these readings).
    ``device_model``: the calibration's carried device-model effects
    (:class:`borescan.device_model.DeviceEffect`); the readings are corrected for them first.
    ``cleaning``: the spike policy (:func:`borescan.readings.cleaning_policy`; schema defaults
    when None); the readings are :func:`borescan.readings.prepared_matrix`.
    """
    from .device_model import channel_time_offsets, correct
    from .noise import noise_floor_mm
    from .readings import prepared_matrix

    m = prepared_matrix(scan, cleaning)
    idx = [m.channels.index(ch) for ch in beams.channels]
    v = m.values_mm[:, idx]
    sp = scan.spindle
    if device_model:
        sensors = {int(s["channel"]): s for s in scan.meta.get("sensors", [])}
        v = correct(m.t_s, v, beams.channels, device_model, sensor_ranges_mm(sensors, beams.channels))
    if sp is not None and sp.height > 1:
        t_sp = sp["t_ns"].to_numpy() * 1e-9
        phi = _rotating_angle(scan, m.t_s, v, channel_time_offsets(device_model, beams.channels))
        S = np.column_stack(
            [np.interp(m.t_s, t_sp, sp["x_mm"].to_numpy()), np.interp(m.t_s, t_sp, sp["y_mm"].to_numpy())]
        )
        res = measure_rotating(v, phi, S, beams)
        model = DiameterModel("rotating", v, phi, S)
        model.ls_circle(beams, circle=res.circles["LSCI"])  # the same points: fitted once for the budget too
        jp, jv = _rotating_sensitivities(model, beams)
        u_cal = (
            float(np.sqrt(max(jp @ np.asarray(cov_beams, float) @ jp, 0.0))) if cov_beams is not None else 0.0
        )
        return {
            "diameter_mm": res.diameter_mm,
            "u_diameter_mm": float(np.hypot(res.u_diameter_mm, u_cal)),
            "method": "rotating LS circle",
            "ront_mm": res.ront_mm,
            "jac_params": jp,
            "jac_readings": jv,
            "u_readings_mm": res.u_diameter_mm,
            "dof_readings": float(max(res.x_mm.size - 3, 1)),
            "noise_mm": noise_floor_mm(v, order=4),
            "model": model,
        }
    sensors = {int(s["channel"]): s for s in scan.meta["sensors"]}
    rep = np.array([float(sensors.get(ch, {}).get("repeatability_mm", 0.0) or 0.0) for ch in beams.channels])
    poses, jps, jvs, sds, ns, means = [], [], [], [], [], []
    for p in np.unique(m.pose):
        vv = v[(m.pose == p) & np.all(np.isfinite(v), axis=1)]
        if vv.shape[0] == 0:
            continue
        sd = vv.std(axis=0, ddof=1) if vv.shape[0] > 1 else np.zeros(vv.shape[1])
        res = static_diameter(vv.mean(axis=0), beams, cov_beams, np.maximum(sd, rep) / np.sqrt(vv.shape[0]))
        _, jp, jv, _ = static_diameter_jacobian(vv.mean(axis=0)[None, :], beams)
        jps.append(jp[0])
        jvs.append(jv[0])
        means.append(vv.mean(axis=0))
        sds.append(sd)
        ns.append(vv.shape[0])
        poses.append(
            {
                "pose": int(p),
                "diameter_mm": res.diameter_mm,
                "u_diameter_mm": res.u_diameter_mm,
                "u_calibration_mm": res.u_calibration_mm,
                "u_readings_mm": res.u_readings_mm,
            }
        )
    if not poses:
        raise ValueError(f"{scan.scan_id}: no complete static reading set")
    D = np.array([q["diameter_mm"] for q in poses])
    u_cal = float(np.mean([q["u_calibration_mm"] for q in poses]))
    u_rd = np.array([q["u_readings_mm"] for q in poses])
    k = D.size
    between = float(np.var(D, ddof=1)) / k if k > 1 else 0.0
    within = float(np.mean(u_rd**2)) / k
    var_mean = max(between, within)
    sd_all = np.array(sds)
    n_all = np.array(ns)
    if between >= within:
        dof = float(k - 1)
    elif np.all(sd_all >= rep[None, :]):
        dof = float(np.sum(n_all - 1))
    else:
        dof = float("inf")  # the data sheet's repeatability, larger than the scatter (Type B)
    pooled = np.sqrt(np.sum((n_all[:, None] - 1) * sd_all**2, axis=0) / max(int(np.sum(n_all - 1)), 1))
    return {
        "diameter_mm": float(D.mean()),
        "u_diameter_mm": float(np.sqrt(u_cal**2 + var_mean)),
        "method": f"static {'circumcircle' if len(beams.channels) == 3 else 'least-squares circle'}, "
        f"mean of {k} poses",
        "poses": poses,
        "jac_params": np.mean(jps, axis=0),
        "jac_readings": np.mean(jvs, axis=0),
        "u_readings_mm": float(np.sqrt(var_mean)),
        "dof_readings": dof,
        "noise_mm": pooled,
        "model": DiameterModel("static", np.array(means)),
    }


# --------------------------------------------------------------------------- readings per pose (rod)


def pose_means(values_mm, pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean reading per pose and channel, and how many readings each mean has.

    Parameters
    ----------
    values_mm : (n, c) readings, NaN where null [mm].
    pose : (n,) pose number of each sample (-1 or below: no pose, left out).

    Returns
    -------
    poses (k,), means (k, c) [mm] (NaN where a pose has no reading of a channel), counts (k, c).
    """
    v = np.asarray(values_mm, dtype=float)
    pose = np.asarray(pose)
    poses = np.unique(pose[pose >= 0])
    means = np.vstack([np.nanmean(v[pose == p], axis=0) for p in poses])
    counts = np.vstack([np.sum(np.isfinite(v[pose == p]), axis=0) for p in poses])
    return poses, means, counts


def reading_u_mm(sensors: dict, channels) -> np.ndarray:
    """Return standard uncertainty of one reading per channel from the sensors' data sheet [mm].

    u = hypot(linearity_fs * range_mm / sqrt(3), repeatability_mm): the stated linearity is a
    rectangular +-a (GUM 4.3.7), the repeatability a standard deviation. Missing values count 0.
    ``sensors`` maps channel -> the ``scan.json`` sensor entry.
    """

    def one(ch: int) -> float:
        s = sensors.get(ch, {})
        lin = (s.get("linearity_fs") or 0.0) * (s.get("range_mm") or 0.0)
        return float(np.hypot(lin / np.sqrt(3), s.get("repeatability_mm") or 0.0))

    return np.array([one(int(ch)) for ch in channels])


def mean_reading_u_mm(u_one_mm, counts) -> float | None:
    """One standard uncertainty for every mean of :func:`pose_means`: the largest u / sqrt(n) [mm].

    ``u_one_mm`` (c,) from :func:`reading_u_mm`; ``counts`` (k, c). n is each channel's fewest
    readings in a pose (at least 1). None when no sensor states an uncertainty.
    """
    u = np.asarray(u_one_mm, dtype=float)
    if not np.any(u > 0):
        return None
    return float(np.max(u / np.sqrt(np.maximum(np.asarray(counts).min(axis=0), 1))))


# --------------------------------------------------------------------------- GUM budget of a diameter


def sensor_ranges_mm(sensors: dict, channels) -> list[float]:
    """Return each channel's measuring range [mm] from scan.json.

    Each channel's measuring range [mm] from scan.json ``sensors`` (channel -> entry); 10 mm where
    a sensor does not state one.
    """
    return [float((sensors.get(int(ch)) or {}).get("range_mm") or 10.0) for ch in channels]


def sensor_terms(
    sensors: dict,
    channels,
    sensitivity: np.ndarray,
    key: str,
    noise_mm,
    default_resolution_mm: float,
    what: str,
) -> list[Term]:
    """Linearity and resolution terms of the sensors of one set of readings (Type B, rectangular).

    Parameters
    ----------
    sensors : channel -> scan.json sensor entry (``linearity_fs``, ``range_mm``, optional ``resolution_mm``)
    channels : channel numbers, in the order of ``sensitivity``'s columns
    sensitivity : (m, c) d outputs / d (a constant error of every reading of channel c)
    key : identity of this set of readings (a scan or calibration id): an error here is
        independent of the same sensor's error elsewhere in its range
    noise_mm : (c,) the readings' own scatter (dithering check), or None
    default_resolution_mm : ``uncertainty.sensor_resolution_mm``
    what : text naming the readings (``"calibration"``, ``"measurement"``)

    Notes
    -----
    Linearity: the data sheet's +-linearity_fs x range_mm, u = a / sqrt 3 (GUM 4.3.7). Resolution
    delta: u = delta / sqrt 12, counted only where the readings' noise is below delta / 2; with more
    noise the quantisation error is dithered, varies from reading to reading and is part of the
    Type A scatter (GUM F.2.2.1), so its term has sensitivity 0 and says so.
    """
    sens = np.atleast_2d(np.asarray(sensitivity, dtype=float))
    noise = None if noise_mm is None else np.broadcast_to(np.asarray(noise_mm, float), (len(channels),))
    terms = []
    for j, ch in enumerate(channels):
        s = sensors.get(int(ch), {}) or {}
        rng_mm = float(s.get("range_mm") or 0.0)
        lin = float(s.get("linearity_fs") or 0.0) * rng_mm
        label = f"{s.get('model', 'sensor')} {s.get('serial', '')}".strip()
        terms.append(
            Term(
                Input(
                    f"linearity:{key}:ch{int(ch)}",
                    f"linearity deviation, channel {int(ch)} ({what})",
                    f"e_lin,{int(ch)}",
                    "mm",
                    0.0,
                    lin / math.sqrt(3.0),
                    "rectangular",
                    source=f"data sheet of {label}: +-{s.get('linearity_fs')} x "
                    f"{rng_mm:g} mm full scale (scan.json sensors)",
                ),
                sens[:, j],
            )
        )
        res = s.get("resolution_mm")
        src = "scan.json sensors resolution_mm" if res is not None else "uncertainty.sensor_resolution_mm"
        delta = float(res if res is not None else default_resolution_mm)
        dithered = noise is not None and np.isfinite(noise[j]) and noise[j] >= 0.5 * delta
        terms.append(
            Term(
                Input(
                    f"resolution:{key}:ch{int(ch)}",
                    f"resolution, channel {int(ch)} ({what})",
                    f"e_res,{int(ch)}",
                    "mm",
                    0.0,
                    delta / math.sqrt(12.0),
                    "rectangular",
                    source=f"{delta:g} mm ({src})",
                ),
                np.zeros(sens.shape[0]) if dithered else sens[:, j],
                note=(
                    f"dithered by the readings' noise ({noise[j] * 1e3:.2f} um >= half the resolution): "
                    "part of the Type A scatter (GUM F.2.2.1)"
                )
                if dithered
                else "",
            )
        )
    return terms


@dataclass(frozen=True)
class DiameterUncertainty:
    """A diameter at the measured temperature and at 20 degC with its GUM budget.

    diameter_mm, combined_t : D at the scan's temperature and its Combined (u, nu_eff, k, U);
    diameter_20_mm, combined_20 : D20 = D_T / (1 + alpha (T - 20)) (ISO 1) and its Combined;
    temperature : ScanTemperature; cte : ArtifactCte; thermal_correction_mm = D20 - D_T and
    u_thermal_correction_mm (from the temperature and expansion coefficient);
    budget : outputs (D_T, D20); rows_20 / rows_t : budget tables.
    """

    diameter_mm: float
    combined_t: Combined
    diameter_20_mm: float
    combined_20: Combined
    temperature: ScanTemperature
    cte: ArtifactCte
    thermal_correction_mm: float
    u_thermal_correction_mm: float
    budget: Budget

    @property
    def rows_20(self) -> list[dict]:
        """Budget rows of the diameter at 20 degC."""
        return self.budget.rows(1)

    @property
    def rows_t(self) -> list[dict]:
        """Budget rows of the diameter at the measuring temperature."""
        return self.budget.rows(0)

    def columns(self) -> dict:
        """Return the extra ``diameters`` columns (tables.py) of this result."""
        c20, ct = self.combined_20, self.combined_t
        return {
            "temperature_c": self.temperature.temperature_c,
            "u_temperature_c": self.temperature.u_c,
            "temperature_assumed": self.temperature.assumed,
            "cte_per_k": self.cte.cte_per_k,
            "cte_assumed": self.cte.assumed,
            "diameter_20_mm": self.diameter_20_mm,
            "u_diameter_20_mm": c20.u,
            "expanded_u_diameter_20_mm": c20.U,
            "expanded_u_diameter_mm": ct.U,
            "k": c20.k,
            "k_at_t": ct.k,
            "coverage_probability": c20.p,
            "nu_eff": c20.nu_eff if np.isfinite(c20.nu_eff) else None,
            "coverage_method": c20.method,
            "thermal_correction_mm": self.thermal_correction_mm,
            "u_thermal_correction_mm": self.u_thermal_correction_mm,
            "budget_json": json.dumps(json_ready(self.rows_20), sort_keys=True),
        }


def _unit_polar(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return distances and unit vectors of points ``d`` from the origin.

    Distances and unit vectors (rr, n_x, n_y) of points ``d`` (2, m) from the origin: the first
    step of :func:`_ls_radius_change` (the start circle's centre), kept per block of points.
    """
    rr = np.hypot(d[0], d[1])
    return rr, d[0] / rr, d[1] / rr


def _ls_radius_change(
    d: np.ndarray,
    r0: float,
    max_iter: int = 50,
    first: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> float | None:
    """Radius change dr [mm] of the least-squares circle of points given relative to a nearby circle.

    ``d`` (2, m): the points' x and y minus the start circle's centre [mm]; ``r0`` its radius [mm].
    Gauss-Newton on (dc, dr), residuals e_i = |d_i - dc| - (r0 + dr), step -(J^T J)^-1 J^T e with
    J = [-n_x, -n_y, -1] (n_i the unit vector from the centre to the point), until a step is below
    tol = 1e-13 r0 as in :func:`borescan.circlefit.fit_circle_ls`: the same minimum. Near it each
    step is the previous one times a rate (about that step and the residuals over r0), which the
    ratio of the last two steps bounds: it also stops when the last step times that ratio is below
    tol, from a circle a small move away after two steps. The increments are kept apart from r0 so
    that differences of such changes carry no rounding of the radius itself. None when the sum of
    squares grows by more than its rounding (1e-9 relative) or no step converges. ``first``: the
    points' :func:`_unit_polar` when the caller has it (the same numbers as the first step's own).
    """
    tol = 1e-13 * max(1.0, r0)
    dc = np.zeros(2)
    dr = 0.0
    f_prev, last = np.inf, 0.0  # last: the previous step's size (none yet)
    for it in range(max_iter):
        rr, nx, ny = first if it == 0 and first is not None else _unit_polar(d - dc[:, None])
        e = (rr - r0) - dr
        f = float(e @ e)
        if not np.isfinite(f) or f > f_prev * (1.0 + 1e-9):
            return None
        f_prev = f
        sx, sy = float(nx.sum()), float(ny.sum())
        JTJ = np.array([[nx @ nx, nx @ ny, sx], [nx @ ny, ny @ ny, sy], [sx, sy, float(e.size)]])
        step = np.linalg.solve(JTJ, np.array([nx @ e, ny @ e, e.sum()]))
        dc += step[:2]
        dr += step[2]
        size = float(np.max(np.abs(step)))
        if size <= tol or size * size <= tol * last:
            return dr
        last = size
    return None


def _rotating_diameter_changes(model: DiameterModel, beams: Beams, moves) -> list[float]:
    """Return the diameter changes of a rotating scan for moved beams.

    D(beams moved by dl) - D(beams) [mm] of a rotating scan, for moves ``(j, dl)`` of channel j's
    parameters (``dl`` (3c,) per channel (beta, rho, d_b), zero but for channel j).

    The scan's least-squares circle (c0, r0) is fitted once; for each move only channel j's wall
    points are recomputed (:func:`wall_points_machine`), and the moved points' circle is found by
    Gauss-Newton from (c0, r0) (:func:`_ls_radius_change`): D' - D = 2 (dr' - dr_0), dr_0 the same
    iteration on the unmoved points (the base circle's own last digits). A fresh fit
    (:class:`DiameterModel`) where the iteration does not converge.
    """
    v = np.asarray(model.readings_mm, dtype=float)
    n, c = v.shape
    P = wall_points_machine(v, model.phi_rad, model.spindle_xy_mm, beams)  # (n, c, 2)
    ok = np.all(np.isfinite(P), axis=-1)
    Pk = P[ok]
    circ = model.ls_circle(beams, Pk)
    c0, r0 = np.asarray(circ.center_xy_mm), circ.radius_mm
    blocks = [(P[ok[:, j], j] - c0).T for j in range(c)]  # per channel (2, m_j), relative to c0
    polar = [_unit_polar(b) for b in blocks]  # a move changes one channel's: the others' are kept

    def first_step(parts):
        return tuple(np.concatenate(x) for x in zip(*parts))

    dr0 = _ls_radius_change(np.concatenate(blocks, axis=1), r0, first=first_step(polar))
    phi = np.broadcast_to(np.asarray(model.phi_rad, dtype=float).reshape(n, -1), (n, c))
    S = np.broadcast_to(np.asarray(model.spindle_xy_mm, dtype=float), (n, 2))
    out = []
    for j, dl in moves:
        b = _with_params(beams, dl)
        one = Beams((b.channels[j],), b.beta_rad[j : j + 1], b.rho_mm[j : j + 1], b.d_b_mm[j : j + 1])
        k = ok[:, j]
        moved = list(blocks)
        moved[j] = (wall_points_machine(v[k, j : j + 1], phi[k, j], S[k], one)[:, 0] - c0).T
        moved_polar = list(polar)
        moved_polar[j] = _unit_polar(moved[j])
        dr = (
            None
            if dr0 is None
            else _ls_radius_change(np.concatenate(moved, axis=1), r0, first=first_step(moved_polar))
        )
        out.append(2.0 * (dr - dr0) if dr is not None else model(b) - circ.diameter_mm)
    return out


def _second_order_variance(model: DiameterModel, beams: Beams, cov_second: np.ndarray, R_mm: float) -> float:
    """Variance of D from the calibration's second-order term (:func:`diameter_uncertainty`).

    The fit estimates psi = beta + asin(rho/R) and g = d_b + rho^2/(2R) linearly and rho with
    error delta; the calibration's second-order term of d_b is 3 u(rho)^4 / (4 R^2) (the fit's).
    Along that path (psi, g fixed) D moves by q delta^2 at second order; its contribution is
    q^2 3 u^4 (variance and squared bias of q delta^2, as the fit counts them), q from a central
    second difference over +-u(rho). For a rotating scan the differences D(+-u) - D come from
    Gauss-Newton steps from the scan's own circle (:func:`_rotating_diameter_changes`), the same
    minima as fresh fits.
    """
    c = len(beams.channels)
    moves, us = [], []
    for j in range(c):
        s2 = float(cov_second[3 * j + 2, 3 * j + 2])
        if s2 <= 0.0:
            continue
        u = (s2 * 4.0 * R_mm**2 / 3.0) ** 0.25
        rho = float(beams.rho_mm[j])
        for h in (u, -u):
            dl = np.zeros(3 * c)
            dl[3 * j] = -(np.arcsin(np.clip((rho + h) / R_mm, -1, 1)) - np.arcsin(np.clip(rho / R_mm, -1, 1)))
            dl[3 * j + 1] = h
            dl[3 * j + 2] = -(2.0 * rho * h + h * h) / (2.0 * R_mm)
            moves.append((j, dl))
        us.append(u)
    if not moves:
        return 0.0
    if model.kind == "rotating":
        dd = _rotating_diameter_changes(model, beams, moves)
        second = [dd[2 * k] + dd[2 * k + 1] for k in range(len(us))]
    else:
        d0 = model(beams)
        vals = [model(_with_params(beams, dl)) for _, dl in moves]
        second = [vals[2 * k] - 2.0 * d0 + vals[2 * k + 1] for k in range(len(us))]
    var = 0.0
    for u, s in zip(us, second):
        q = s / (2.0 * u * u)
        var += 3.0 * q * q * u**4
    return var


def _profile_variance(model: DiameterModel, beams: Beams, prof: dict, jac_params) -> float:
    """Variance of D from a non-linear rho profile of the calibration, beyond its linear part.

    The calibration walks the cost along one rho, every other parameter refitted, and weighs each
    point by its likelihood ratio (:func:`borescan.calibrate.full_fit.fit_full_calibration`); the parameters'
    second moment there replaces their linear covariance along that rho where it is larger. D is
    evaluated at each point, M_D = sum w (D(p_k) - D(p))^2; the linear covariance already gives D
    (J . c)^2 / u_lin^2 along that rho (c the linear covariance's column of rho, J = dD/dp); the
    term is the excess max(M_D - (J . c)^2 / u_lin^2, 0). Along a profile the beams' rho^2 terms
    move together (beta and d_b follow rho), so D can move far less than its linear sensitivities
    to each parameter say.
    """
    pts = np.asarray(prof["points"]["delta_params"], dtype=float)
    w = np.asarray(prof["points"]["weight"], dtype=float)
    d0 = model(beams)
    dD = np.array([model(_with_params(beams, d)) - d0 for d in pts])
    m_d = float(np.sum(w * dD**2) / np.sum(w))
    col = np.asarray(prof["linear_cov_column"], dtype=float)
    u_lin = float(prof["u_rho_linear_mm"])
    lin = float(np.asarray(jac_params, dtype=float) @ col) ** 2 / u_lin**2 if u_lin > 0 else 0.0
    return max(m_d - lin, 0.0)


def _gauge_radius_of(calibration_budget: Budget) -> float | None:
    for t in calibration_budget.terms:
        if t.input.key.startswith("gauge:") and t.input.key.endswith(":D20") and t.input.estimate:
            return 0.5 * float(t.input.estimate)
    return None


def diameter_uncertainty(
    diameter_mm: float,
    *,
    jac_params=None,
    calibration_budget: Budget | None = None,
    jac_readings=None,
    u_readings_mm: float,
    dof_readings: float,
    sensors: dict | None = None,
    channels=(),
    noise_mm=None,
    temperature: ScanTemperature,
    cte: ArtifactCte,
    artifact: dict,
    scan_id: str,
    p: float,
    default_resolution_mm: float,
    readings_what: str = "readings",
    calibration_id: str | None = None,
    model: DiameterModel | None = None,
    beams: Beams | None = None,
    rho_profiles: list[dict] | None = None,
    extra_terms: Sequence[tuple[Input, float]] = (),
) -> DiameterUncertainty:
    """GUM budget of a measured diameter, at the scan's temperature and at 20 degC.

    D_T = f(readings, beams); D20 = D_T / (1 + alpha (T - 20)). Terms:

    - every term of ``calibration_budget`` (outputs: the calibration's (beta, rho, d_b) per channel)
      mapped by ``jac_params`` (3c,) = dD/d(beta, rho, d_b); with the scan's ``model`` and the
      calibrated ``beams``, the fit's two non-linear terms are mapped by D itself: an unresolved
      mirror solution by the secant D(p + d) - D(p), and the second-order term of d_b by D's own
      curvature along the fit's path (:func:`_second_order_variance`): for a bore of about the
      gauge's size the rho^2 terms of d_b and of the wall points cancel, and D carries little of it;
      the spread along a non-linear rho profile (``rho_profiles``, the calibration's
      ``diagnostics["rho_profiles"]``) by D at the profile's points (:func:`_profile_variance`), for
      the same reason;
    - ``extra_terms``: (input, dD_T / d input) of inputs the readings depend on directly (a carried
      device-model parameter: the same key as in the calibration's budget, so the two add);
    - the readings: u = ``u_readings_mm`` with ``dof_readings`` (Type A; nu = inf: the data sheet's
      repeatability, Type B);
    - each sensor's linearity and resolution at this measurement (:func:`sensor_terms`, sensitivity
      ``jac_readings`` (c,));
    - the scan's temperature T and the artifact's alpha, which only D20 depends on:
      dD20/dT = -D_T alpha / f^2, dD20/dalpha = -D_T (T - 20) / f^2, f = 1 + alpha (T - 20);
      every other sensitivity of D20 is that of D_T times 1 / f.

    Parameters
    ----------
    diameter_mm : D_T [mm]
    p : coverage probability; default_resolution_mm : ``uncertainty.sensor_resolution_mm``
    artifact : scan.json ``artifact`` (its key names the expansion coefficient: the same gauge's
        alpha in a calibration and a verification is one input)

    Returns
    -------
    DiameterUncertainty
    """
    d20, f, dT_sens, da_sens = diameter_at_20(diameter_mm, cte.cte_per_k, temperature.temperature_c)
    to_both = np.array([[1.0], [f]])
    b = Budget(("D_T", "D_20"), ("mm", "mm"), np.array([diameter_mm, d20]))
    if calibration_budget is not None and jac_params is not None:
        jp = np.asarray(jac_params, dtype=float)
        R_g = _gauge_radius_of(calibration_budget)
        both = np.array([1.0, f])
        profile_of = {f":profile{p['channel']}": p for p in (rho_profiles or ()) if "points" in p}
        for t in calibration_budget.terms:
            key = t.input.key
            if model is not None and beams is not None:
                if key.endswith(":second_order") and t.cov is not None and R_g:
                    var = _second_order_variance(model, beams, t.cov, R_g)
                    b.add(
                        Term(
                            t.input,
                            cov=np.outer(both, both) * var,
                            note="D's own curvature along the fit's path (psi, g fixed), not d_b's",
                        )
                    )
                    continue
                prof = profile_of.get(key[key.rfind(":") :]) if key.startswith("fit:") else None
                if prof is not None and t.cov is not None:
                    var = _profile_variance(model, beams, prof, jp)
                    b.add(
                        Term(
                            t.input,
                            cov=np.outer(both, both) * var,
                            note="D's own spread along the rho profile's points beyond its linear "
                            "part, not the "
                            "parameters' spread mapped linearly",
                        )
                    )
                    continue
                if ":mirror" in key and t.sensitivity is not None:
                    dD = model(_with_params(beams, t.sensitivity)) - model(beams)
                    b.add(Term(t.input, both * dD, note="secant: D with the mirror solution's beams minus D"))
                    continue
            b.add(t.mapped(to_both @ jp[None, :]))
    for inp, dD in extra_terms:
        b.add(Term(inp, np.array([1.0, f]) * float(dD)))
    dof = float(dof_readings)
    b.add(
        Term(
            Input(
                f"readings:{scan_id}",
                f"scatter of the readings of {scan_id}",
                "D_rd",
                "mm",
                None,
                float(u_readings_mm),
                "normal",
                dof,
                "A" if np.isfinite(dof) else "B",
                "between/within the poses' diameters"
                if np.isfinite(dof)
                else "sensors' repeatability (data sheet), larger than the scatter",
            ),
            np.array([1.0, f]),
        )
    )
    if jac_readings is not None and sensors is not None:
        jv = np.asarray(jac_readings, dtype=float)
        for t in sensor_terms(
            sensors, channels, to_both @ jv[None, :], scan_id, noise_mm, default_resolution_mm, readings_what
        ):
            b.add(t)
    b.add(
        Term(
            Input(
                f"temperature:{scan_id}",
                f"temperature of {artifact.get('id') or 'the artifact'} during {scan_id}",
                "T",
                "degC",
                temperature.temperature_c,
                temperature.u_c,
                "rectangular",
                source=temperature.source,
            ),
            np.array([0.0, dT_sens]),
        )
    )
    b.add(
        Term(
            Input(
                f"cte:{artifact_key(artifact)}",
                f"expansion coefficient of {artifact.get('id') or 'the artifact'}",
                "alpha",
                "1/K",
                cte.cte_per_k,
                cte.u_per_k,
                "rectangular",
                source=cte.source,
            ),
            np.array([0.0, da_sens]),
        )
    )
    b = b.merged()
    ct, c20 = b.combined(0, p), b.combined(1, p)
    corr = b.combined(np.array([-1.0, 1.0]), p)
    return DiameterUncertainty(
        float(diameter_mm), ct, d20, c20, temperature, cte, d20 - float(diameter_mm), corr.u, b
    )


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
    from .artifacts import artifact_cte, scan_temperature

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

    from .mirror import mirror_checks_of, mixture_components, mixture_diameter, mixture_seed, refusal

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
        comps.append((w, d_k, 0.0 if k == 0 else float(jp @ cov @ jp) - var_main))
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


def _device_model_inputs(scan, cal, dm, cleaning=None) -> list[tuple[Input, float]]:
    """Return the GUM inputs of the carried device-model parameters.

    (input, dD/d parameter) of each carried device-model parameter through this scan's own readings
    (:func:`borescan.device_model.derivatives` of :func:`measure_scan`'s diameter).
    """
    d = device_model.derivatives(
        dm, lambda m: measure_scan(scan, cal.beams, None, m, cleaning)["diameter_mm"]
    )
    return [(device_model.gum_input(cal.device_id, dm[i], name), float(v)) for (i, name), v in d.items()]


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
    ``expected_at_t_mm``.
    """
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
