"""Circle fitting: least squares (NIST-conformant) and the ISO 12181 reference circles.

All functions take point coordinates ``x_mm, y_mm`` (n,) and return a :class:`Circle`.
Coordinates are centred on their mean before any arithmetic so that parts far from the
origin (NIST places them up to 1000 mm out) keep full precision.

- :func:`fit_circle_ls`: geometric least squares min sum (|p_i - c| - R)^2 (LSCI), Gauss-Newton
  from the algebraic Kasa start, Levenberg damping only when a step does not descend.
- :func:`min_circumscribed_circle` (MCCI): exact, Welzl's algorithm (move-to-front, seeded).
- :func:`max_inscribed_circle` (MICI): the global maximum of min_i |p_i - c| over centres c
  inside the closed profile polygon: the best Voronoi vertex of the points (a Delaunay
  circumcentre) inside the polygon, then the exact 3-point polish.
- :func:`min_zone_circle` (MZCI): sequential linear programming (exact gradients, trust region)
  on min_c (max_i |p_i - c| - min_i |p_i - c|), converged to a vertex, then polished by solving
  the active-set equations exactly (Newton).
- MZCI, MICI and MCCI need a closed profile: the largest angular gap between consecutive points
  about the least-squares centre must not exceed ``max_gap_deg`` (default
  :data:`CLOSED_MAX_GAP_DEG` = 150 deg); an open arc raises :class:`CircleFitError`
  "profile is not closed (largest gap X deg)". :func:`largest_gap_deg` gives the gap.
- roundness RONt (peak-to-valley of radial deviations) about each centre: :func:`roundness`.
- :func:`harmonic_spectrum`: amplitude per undulations per revolution (UPR), least-squares
  Fourier fit (valid for non-uniform angles).
"""

from __future__ import annotations

from borescan.circlefit.circumscribed import mcci_of, min_circumscribed_circle
from borescan.circlefit.inscribed import max_inscribed_circle, mici_of
from borescan.circlefit.lsq import (
    CLOSED_MAX_GAP_DEG,
    Circle,
    CircleFitError,
    closed_profile,
    fit_circle_kasa,
    fit_circle_ls,
    harmonic_spectrum,
    largest_gap_deg,
    roundness,
)
from borescan.circlefit.zone import min_zone_circle, mzci_of

__all__ = [
    "Circle",
    "CircleFitError",
    "CLOSED_MAX_GAP_DEG",
    "largest_gap_deg",
    "fit_circle_ls",
    "fit_circle_kasa",
    "min_circumscribed_circle",
    "max_inscribed_circle",
    "min_zone_circle",
    "roundness",
    "reference_circles",
    "harmonic_spectrum",
]


def reference_circles(x_mm, y_mm, *, max_gap_deg: float = CLOSED_MAX_GAP_DEG) -> dict[str, Circle]:
    """All four ISO 12181 reference circles: {"LSCI", "MZCI", "MICI", "MCCI"}.

    Raises CircleFitError "profile is not closed (largest gap X deg)" when the largest angular
    gap about the least-squares centre exceeds ``max_gap_deg`` [deg].
    """
    ls = fit_circle_ls(x_mm, y_mm)
    # one preparation (finite points, shift, closed-profile check and angular order about the LS
    # centre) for all three: the same as each function's own, checked as min_zone_circle would
    prof = closed_profile(x_mm, y_mm, ls.center_xy_mm, max_gap_deg, "MZCI", min_points=4)
    return {"LSCI": ls, "MZCI": mzci_of(prof), "MICI": mici_of(prof), "MCCI": mcci_of(prof)}
