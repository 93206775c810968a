"""Rotating-scan diameter and roundness; ``measure_scan``: one scan, static or rotating.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np
from ..circlefit import Circle, fit_circle_ls, harmonic_spectrum, reference_circles
from ..geometry import Beams, beam_frame, wall_points_device
from .sensors import sensor_ranges_mm
from .static import static_diameter, static_diameter_jacobian

__all__ = [
    "RotatingResult",
    "wall_points_machine",
    "measure_rotating",
    "DiameterModel",
    "measure_scan",
]


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
    from ..kinematics import angle_model_of_scan, estimate_speed_scale

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
    from ..device_model import channel_time_offsets, correct
    from ..noise import noise_floor_mm
    from ..readings import prepared_matrix

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
