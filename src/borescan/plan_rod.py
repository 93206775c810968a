"""What a rod hold will fix (``borescan plan --rod-scan``): poses and spread that reach a target u(D).

A hold of the measuring rod (one scan: the rod turned by hand through n poses inside coaxial holes)
determines each hole's radius to its Cramer-Rao bound (:func:`borescan.rod.rod_crb`, with the
holes' coaxiality as the solve takes it, ``uncertainty.rod_hole_coaxiality_mm``), which depends on
the number of poses, their angular spread and how the rod sits: its eccentricity (the layers'
offsets from the axis) and its deflection across that eccentricity (which makes the offsets of the
layers non-collinear with the axis, Wang 2017's condition). :func:`hold_of_solution` takes these
from a solve of the hold, :func:`predict_rod` gives the bound of a proposed hold and
:func:`recommend_rod` the fewest poses, per angular spread, that bring u(D) = 2 u(r) of every hole
to a target. Poses are taken equally spaced over the spread (a hand-turned rod's poses spread as
well as the operator manages: the bound of equal spacing is a lower limit).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from borescan.geometry import Hole, RodAxis, RodLayer
from borescan.rod import RodSolution, rod_crb

__all__ = ["RodHold", "RodPlanPrediction", "dominant_fix", "hold_of_solution", "predict_rod", "recommend_rod"]


@dataclass(frozen=True)
class RodHold:
    """A rod hold as the plan sees it.

    layers : the rod's layers; holes : the holes (centres and radii, in the frame of ``axis``)
    axis : the rod axis (through (dx, dy) at z = 0, deflection omega towards omega_az)
    sigma_mm : standard uncertainty of one pose mean [mm]; n_poses; spread_rad : arc the poses cover
    coaxiality_mm : the holes' coaxiality the solve takes (None: the deflection bound only)
    alpha_rad : the hold's own pose angles (a solved hold; None: poses equally spaced over the spread)
    """

    layers: tuple[RodLayer, ...]
    holes: tuple[Hole, ...]
    axis: RodAxis
    sigma_mm: float
    n_poses: int
    spread_rad: float
    coaxiality_mm: float | None
    alpha_rad: tuple[float, ...] | None = None


@dataclass(frozen=True)
class RodPlanPrediction:
    """Cramer-Rao standard uncertainty of each hole's diameter for one hold, u_diameter_mm (m,) [mm]."""

    hold: RodHold
    u_diameter_mm: tuple[float, ...]


def _pose_spread_rad(alpha_rad: np.ndarray) -> float:
    """Arc covered by the pose angles: 2 pi minus the largest gap between neighbours [rad]."""
    a = np.sort(np.mod(alpha_rad[np.isfinite(alpha_rad)], 2 * np.pi))
    if a.size < 2:
        return 0.0
    gaps = np.diff(np.concatenate([a, [a[0] + 2 * np.pi]]))
    return float(2 * np.pi - gaps.max())


def hold_of_solution(sol: RodSolution, coaxiality_mm: float | None) -> RodHold:
    """Return the hold a rod solve describes, in the solve's own frame.

    The axis through the origin at z = 0 with the reported deflection vector, each hole's centre
    its solved centre c_m (relative to the axis at the spot) plus the axis' offset at the spot
    height z_m = h_m + r_m tan(gamma_m); the pose-mean noise, the number of poses and their spread.
    """
    w = np.asarray(sol.deflection_posterior_xy_rad, dtype=float)
    omega = float(np.hypot(*w))
    u_az = w / omega if omega > 0 else np.zeros(2)
    r = np.asarray(sol.radius_mm, dtype=float)
    z = np.array([lay.h_mm for lay in sol.layers]) + r * np.tan([lay.gamma_rad for lay in sol.layers])
    c = np.asarray(sol.center_xy_mm, dtype=float) + (z * math.sin(omega))[:, None] * u_az[None, :]
    alpha = np.asarray(sol.alpha_rad, dtype=float)
    return RodHold(
        layers=tuple(sol.layers),
        holes=tuple(Hole((float(x), float(y)), float(rr)) for (x, y), rr in zip(c, r)),
        axis=RodAxis(0.0, 0.0, omega, float(np.arctan2(w[1], w[0]))),
        sigma_mm=float(sol.sigma_mm),
        n_poses=int(np.isfinite(alpha).sum()),
        spread_rad=_pose_spread_rad(alpha),
        coaxiality_mm=coaxiality_mm,
        alpha_rad=tuple(float(a) for a in alpha[np.isfinite(alpha)]),
    )


def predict_rod(hold: RodHold) -> RodPlanPrediction:
    """Return the Cramer-Rao u(D) of every hole for ``hold``'s poses.

    Its own pose angles when it has them (a solved hold: what this hold fixed), else ``n_poses``
    equally spaced over its spread (a proposed hold).
    """
    full = hold.spread_rad >= 2 * np.pi - 1e-9
    if hold.alpha_rad is not None and len(hold.alpha_rad) == hold.n_poses:
        alpha = np.asarray(hold.alpha_rad, dtype=float)
    else:
        alpha = np.linspace(0.0, hold.spread_rad, hold.n_poses, endpoint=not full)
    u_r = rod_crb(
        alpha,
        layers=hold.layers,
        holes=hold.holes,
        axis=hold.axis,
        sigma_mm=hold.sigma_mm,
        coaxiality_mm=hold.coaxiality_mm,
    )
    return RodPlanPrediction(hold, tuple(float(2 * u) for u in u_r))


def _poses_nested(n_small: int, n_large: int, full_circle: bool) -> bool:
    """Whether ``n_small`` poses equally spaced over a spread are a subset of ``n_large`` over it.

    Over the full circle (no end pose) the poses are 2 pi k / n: nested when n_small divides
    n_large; over an arc (both ends) they are spread k / (n - 1): nested when n_small - 1 divides
    n_large - 1.
    """
    if full_circle:
        return n_large % n_small == 0
    return n_small >= 2 and (n_large - 1) % (n_small - 1) == 0


def recommend_rod(
    hold: RodHold,
    target_u_diameter_mm: float,
    poses: Sequence[int] = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256),
    spreads_rad: Sequence[float] = (math.pi / 2, math.pi, 1.5 * math.pi, 2 * math.pi),
) -> list[tuple[float, RodPlanPrediction | None]]:
    """Return, per angular spread, the hold with the fewest ``poses`` reaching the target (None: none does).

    The target: every hole's u(D) <= ``target_u_diameter_mm``; the rod held as in ``hold`` (same
    eccentricity and deflection, same noise of a pose mean).

    The answer is that of trying every count in increasing order, with fewer bounds: u(D) does
    not rise when poses are added to a hold (the new poses' readings add Fisher information, their
    angles are new unknowns of their own), so a count whose poses are a subset of a count that
    misses the target misses it too (:func:`_poses_nested`) and is not tried. The counts are
    tried from the largest down until one reaches the target or every count is known to miss
    (over the full circle 256 and 192 poses settle the whole default grid), then upwards from the
    smallest not known to miss. Counts that are not nested are always tried: u(D) of equally
    spaced poses is not monotone in their number in general (8 -> 12 poses over the full circle
    can raise it by half; ``tests/test_plan_rod.py``).
    """
    counts = sorted({int(n) for n in poses})
    return [(float(sp), _fewest_poses(hold, target_u_diameter_mm, counts, float(sp))) for sp in spreads_rad]


def _fewest_poses(
    hold: RodHold, target_u_diameter_mm: float, counts: list[int], spread_rad: float
) -> RodPlanPrediction | None:
    """Return the prediction of the fewest of the sorted ``counts`` reaching the target over one spread.

    Down from the largest count, each miss marking the counts nested in it, then up from the
    smallest count not known to miss (:func:`recommend_rod`).
    """
    full = spread_rad >= 2 * np.pi - 1e-9
    tried: dict[int, RodPlanPrediction] = {}
    missed: set[int] = set()

    def reaches(n: int) -> bool:
        if n not in tried:
            tried[n] = predict_rod(replace(hold, n_poses=n, spread_rad=spread_rad, alpha_rad=None))
        return max(tried[n].u_diameter_mm) <= target_u_diameter_mm

    for n in reversed(counts):
        if n in missed:
            continue
        if reaches(n):
            break
        missed.update(k for k in counts if _poses_nested(k, n, full))
    for n in counts:
        if n not in missed and reaches(n):
            return tried[n]
    return None


def dominant_fix(key: str, diameter: dict, coaxiality_mm: float | None, u_allowed_mm: float) -> str:
    """Say what would reduce a rod verification's largest input ``key`` (a budget key).

    ``diameter``: a row of :func:`borescan.measure.rod_diameters_with_budget`;
    ``coaxiality_mm``: the holes' coaxiality the solve took; ``u_allowed_mm``: the u(E) at which U(E)
    equals the tolerance. This hold's readings: the fewest poses, per angular spread, that bring its
    u(D) to half of it with the rod held as in this scan (:func:`recommend_rod`); the calibration
    hold's readings: a new calibration with more poses; the layer geometry: a hold as the
    calibration's; a data-sheet input (linearity, resolution): no hold reduces it.
    """
    target_mm = 0.5 * u_allowed_mm
    if key.startswith("readings:"):
        hold = hold_of_solution(diameter["solution"], coaxiality_mm)
        for spread, best in recommend_rod(hold, target_mm, spreads_rad=(2 * np.pi, 1.5 * np.pi, np.pi)):
            if best is not None:
                j = [lay.channel for lay in hold.layers].index(diameter["channel"])
                return (
                    f"this hold's readings: {best.hold.n_poses} poses over {np.degrees(spread):.0f} deg, "
                    "the rod held as in this scan, would bring its u(D) to "
                    f"{best.u_diameter_mm[j] * 1e3:.1f} um (now "
                    f"{diameter['solution'].u_diameter_mm[j] * 1e3:.1f} um; borescan plan --rod-scan)"
                )
        return (
            f"this hold's readings: no hold of up to 256 poses with the rod held as in this scan brings "
            f"u(D) to {target_mm * 1e3:.1f} um: hold the rod more skew to the holes or average more "
            "readings per pose (borescan plan --rod-scan)"
        )
    if key.startswith("fit:"):
        return (
            f"the calibration hold {key.split(':')[1]}'s readings: a calibration with more poses (borescan "
            f"plan --rod-scan on that scan gives how many for u(D) <= {target_mm * 1e3:.1f} um)"
        )
    if key.startswith("linearity:") and diameter.get("cal_spread_mm") is not None:
        return (
            "the change of the sensor's linearity curve between the calibration hold's readings and this "
            f"hold's (their spread over the poses {diameter['cal_spread_mm'] * 1e3:.0f} um and "
            f"{diameter['spread_mm'] * 1e3:.0f} um): hold the rod with the eccentricity of the calibration, "
            "or calibrate with it held as it will be measured (the same spread), or sensors of better "
            "linearity (borescan.measure.linearity_change_mm)"
        )
    if key.startswith("layer_geometry:"):
        return (
            "the rod layers' phi, d, gamma, taken as the design's: the calibration's l0 absorbed them at the "
            "calibration hold's eccentricity and deflection only; hold the rod as it was held in the "
            "calibration, or calibrate in a hold that sits as this one (borescan.rod_layer_geometry)"
        )
    if key.startswith("linearity:"):
        return (
            "the sensors' data-sheet linearity: no hold of the rod reduces it; a linearity calibration of "
            "the sensors over their range (or sensors of better linearity) would"
        )
    return f"{key} is a stated (certificate or data-sheet) input: no hold of the rod reduces it"
