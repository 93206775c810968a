"""Static three-sensor diameter: the circumcircle of three wall points, its Jacobian and GUM budget inputs.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
from ..circlefit import fit_circle_ls
from ..geometry import Beams, beam_frame, circumcircle, wall_points_device

__all__ = [
    "StaticDiameter",
    "static_diameter_jacobian",
    "static_diameter",
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
