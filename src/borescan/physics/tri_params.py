"""The three-sensor device's beams in the parameters a ring gauge fixes best: psi and g.

On a ring gauge of radius R a beam's readings depend on its direction and offset mostly through

    psi = beta + asin(rho / R)      (the direction of the wall point it reads, device frame)
    g   = d_b + rho^2 / (2 R)       (its mean level, to second order in rho / R)

and on rho itself only weakly (mostly through rho^2). Fits whose cost valleys run along rho at
fixed psi and g (the full-data calibration, :mod:`borescan.calibrate.full_fit`; the pooled
discrepancy fit, :mod:`borescan.discrepancy.pooled`; one scan's examination with its beams free,
:meth:`borescan.discrepancy.tri.TriModel.beams_at`) take (psi, rho, g) as their parameters; this
module is the one place of the map and its derivatives. The mirror of a beam (rho -> -rho at the
same psi and g) keeps the first harmonic and the mean level.
"""

from __future__ import annotations

import numpy as np

from borescan.geometry import Beams

__all__ = ["rho_arc_rad", "straighten", "unstraighten", "moved_beams", "dbeta_drho_at_psi", "dd_b_drho_at_g"]


def rho_arc_rad(rho_mm: np.ndarray, R_mm: float) -> np.ndarray:
    """Return asin(rho / R) [rad], rho / R clipped to [-1, 1]: psi - beta."""
    return np.arcsin(np.clip(rho_mm / R_mm, -1.0, 1.0))


def straighten(
    beta_rad: np.ndarray, rho_mm: np.ndarray, d_b_mm: np.ndarray, R_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Return (psi [rad], g [mm]) of beams (beta, rho, d_b) on a gauge of radius ``R_mm``."""
    return beta_rad + rho_arc_rad(rho_mm, R_mm), d_b_mm + rho_mm**2 / (2.0 * R_mm)


def unstraighten(
    psi_rad: np.ndarray, rho_mm: np.ndarray, g_mm: np.ndarray, R_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Return (beta [rad], d_b [mm]) of beams (psi, rho, g): the inverse of :func:`straighten`."""
    return psi_rad - rho_arc_rad(rho_mm, R_mm), g_mm - rho_mm**2 / (2.0 * R_mm)


def moved_beams(
    beams: Beams,
    R_mm: float,
    dpsi_rad: np.ndarray,
    drho_mm: np.ndarray,
    dg_mm: np.ndarray,
    free=("beta", "d_b"),
) -> Beams:
    """Return ``beams`` moved by (dpsi, drho, dg) on radius ``R_mm``; beta, d_b not in ``free`` kept."""
    psi, g = straighten(beams.beta_rad, beams.rho_mm, beams.d_b_mm, R_mm)
    beta, d_b = unstraighten(psi + dpsi_rad, beams.rho_mm + drho_mm, g + dg_mm, R_mm)
    return Beams(
        beams.channels,
        beta if "beta" in free else beams.beta_rad.copy(),
        beams.rho_mm + drho_mm,
        d_b if "d_b" in free else beams.d_b_mm.copy(),
    )


def dbeta_drho_at_psi(rho_mm: np.ndarray, R_mm: float) -> np.ndarray:
    """Return d beta / d rho at fixed psi, -1 / sqrt(R^2 - rho^2) [rad/mm]."""
    return -1.0 / np.sqrt(np.maximum(R_mm**2 - rho_mm**2, 1e-300))


def dd_b_drho_at_g(rho_mm: np.ndarray, R_mm: float) -> np.ndarray:
    """Return d d_b / d rho at fixed g, -rho / R [-]."""
    return -rho_mm / R_mm
