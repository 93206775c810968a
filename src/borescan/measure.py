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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .circlefit import Circle, fit_circle_ls, harmonic_spectrum, reference_circles
from .geometry import Beams, beam_frame, circumcircle, wall_points_device

__all__ = [
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


def static_diameter_jacobian(readings_mm, beams: Beams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
    n = np.stack([-np.sin(beams.beta_rad), np.cos(beams.beta_rad)], axis=-1)
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
    """Static diameter from one or k sets of readings, with its standard uncertainty.

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


def measure_rotating(readings_mm, phi_rad, spindle_xy_mm, beams: Beams, *, max_upr: int = 50) -> RotatingResult:
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


def _rotating_angle(scan, t_s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Device angle at the readings (:mod:`borescan.kinematics`): the encoder angle, else the
    commanded profile with its speed scale found from the readings (the phase of a closed
    profile does not change a circle's diameter or roundness)."""
    from .kinematics import angle_model_of_scan, estimate_speed_scale

    am = angle_model_of_scan(scan.meta, scan.spindle)
    if not am.fits_speed_and_phase:
        return am.phi_rad(t_s)
    Phi = am.commanded_rad(t_s)
    return estimate_speed_scale(Phi, v) * Phi


def measure_scan(scan, beams: Beams, cov_beams=None) -> dict:
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
    (list of dicts pose, diameter_mm, u_diameter_mm).
    """
    from .rawio import lds_matrix

    m = lds_matrix(scan)
    idx = [m.channels.index(ch) for ch in beams.channels]
    v = m.values_mm[:, idx]
    sp = scan.spindle
    if sp is not None and sp.height > 1:
        t_sp = sp["t_ns"].to_numpy() * 1e-9
        phi = _rotating_angle(scan, m.t_s, v)
        S = np.column_stack([np.interp(m.t_s, t_sp, sp["x_mm"].to_numpy()), np.interp(m.t_s, t_sp, sp["y_mm"].to_numpy())])
        res = measure_rotating(v, phi, S, beams)
        return {
            "diameter_mm": res.diameter_mm,
            "u_diameter_mm": res.u_diameter_mm,
            "method": "rotating LS circle",
            "ront_mm": res.ront_mm,
        }
    sensors = {int(s["channel"]): s for s in scan.meta["sensors"]}
    rep = np.array([float(sensors.get(ch, {}).get("repeatability_mm", 0.0) or 0.0) for ch in beams.channels])
    poses = []
    for p in np.unique(m.pose):
        vv = v[(m.pose == p) & np.all(np.isfinite(v), axis=1)]
        if vv.shape[0] == 0:
            continue
        sd = vv.std(axis=0, ddof=1) if vv.shape[0] > 1 else np.zeros(vv.shape[1])
        res = static_diameter(vv.mean(axis=0), beams, cov_beams, np.maximum(sd, rep) / np.sqrt(vv.shape[0]))
        poses.append({"pose": int(p), "diameter_mm": res.diameter_mm, "u_diameter_mm": res.u_diameter_mm,
                      "u_calibration_mm": res.u_calibration_mm, "u_readings_mm": res.u_readings_mm})
    if not poses:
        raise ValueError(f"{scan.scan_id}: no complete static reading set")
    D = np.array([q["diameter_mm"] for q in poses])
    u_cal = float(np.mean([q["u_calibration_mm"] for q in poses]))
    u_rd = np.array([q["u_readings_mm"] for q in poses])
    k = D.size
    var_mean = max(float(np.var(D, ddof=1)) if k > 1 else 0.0, float(np.mean(u_rd**2))) / k
    return {"diameter_mm": float(D.mean()), "u_diameter_mm": float(np.sqrt(u_cal**2 + var_mean)),
            "method": f"static {'circumcircle' if len(beams.channels) == 3 else 'least-squares circle'}, mean of {k} poses",
            "poses": poses}


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
    """Standard uncertainty of one reading per channel from the sensors' data sheet [mm].

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


# --------------------------------------------------------------------------- verification


@dataclass(frozen=True)
class Verification:
    """Result of :func:`verify` (all lengths in mm)."""

    measured_mm: float
    u_measured_mm: float
    certified_mm: float
    expected_at_t_mm: float
    error_mm: float
    u_error_mm: float
    tolerance_mm: float
    passed: bool
    en: float


def verify(measured_mm, u_measured_mm, certified_diameter_mm, u_cert_mm, cte_per_k, temperature_c, tolerance_mm) -> Verification:
    """Error of a measured diameter against a gauge's certified diameter, pass/fail.

    The certificate gives D20 at 20 degC. At temperature T the gauge has expanded to
    D_T = D20 (1 + cte (T - 20)) and a device reading at T measures D_T, so
    error = measured - D_T (a gauge warmer than 20 degC reads larger; without the correction
    that would show as a positive error). Equivalently, to first order, the measured value
    corrected to 20 degC, measured / (1 + cte (T - 20)), minus D20.

    Parameters
    ----------
    u_cert_mm : standard (k = 1) uncertainty of the certified diameter; a certificate's
        expanded U with k = 2 must be divided by 2 by the caller.

    Returns
    -------
    Verification; passed = |error| <= tolerance; en = error / (2 u_error) (E_n number, k = 2).
    """
    D_T = float(certified_diameter_mm) * (1.0 + float(cte_per_k) * (float(temperature_c) - 20.0))
    err = float(measured_mm) - D_T
    u_err = float(np.hypot(u_measured_mm, u_cert_mm * (1.0 + cte_per_k * (temperature_c - 20.0))))
    return Verification(
        measured_mm=float(measured_mm),
        u_measured_mm=float(u_measured_mm),
        certified_mm=float(certified_diameter_mm),
        expected_at_t_mm=D_T,
        error_mm=err,
        u_error_mm=u_err,
        tolerance_mm=float(tolerance_mm),
        passed=bool(abs(err) <= tolerance_mm),
        en=err / (2.0 * u_err) if u_err > 0 else float("inf") * np.sign(err),
    )


def diameter_row(scan_id, device_id, artifact_id, feature, diameter_mm, u_diameter_mm, calibration_id, method) -> dict:
    """One row of the catalog's ``diameters`` table (outputs.md column names)."""
    return {
        "scan_id": str(scan_id),
        "device_id": str(device_id),
        "artifact_id": None if artifact_id is None else str(artifact_id),
        "feature": None if feature is None else str(feature),
        "diameter_mm": float(diameter_mm),
        "u_diameter_mm": float(u_diameter_mm),
        "calibration_id": None if calibration_id is None else str(calibration_id),
        "method": str(method),
    }


def verification_row(scan_id, device_id, artifact_id, v: Verification) -> dict:
    """One row of the catalog's ``verifications`` table (outputs.md; extra columns allowed)."""
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
    }
