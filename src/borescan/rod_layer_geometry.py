"""A rod's layer geometry (phi, d, gamma of each layer) in the budget of a diameter measured with it.

The pipeline takes each layer's in-plane angle phi, beam offset d and tilt gamma as the design's
(0 on every device so far) and calibrates only the base lengths l0 (:mod:`borescan.rod_calibration`).
A real rod's layers are off the design by up to the contract's tolerances (``uncertainty.
rod_layer_phi_bound_rad``, ``rod_layer_d_bound_mm``, ``rod_layer_gamma_bound_rad``; rectangular).
The calibration hold's l0 absorbs what that does to the radii at the calibration hold's own
eccentricity and deflection; a later hold that sits otherwise is off by the difference:

    e_D = -2 [(R_H(g) - R_H(0)) - (R_C(g) - R_C(0))],

R_H(g) the radii the rod solve gives from hold H's pose means with the layers' geometry g (C the
calibration hold, l0 the calibrated ones throughout; exact to O(dR/dl0 - 1) = O(e^2 / r^2)).

The response is far from linear: on the coverage bench's chain 3 it is even in g (g and -g give the
same error, so a derivative at g = 0 is zero) and of degree one (half of g gives half the error): a
first-order GUM sensitivity would state nothing. The input is therefore propagated by Monte Carlo
(JCGM 101): ``uncertainty.rod_layer_geometry_draws`` geometries drawn once per calibration from the
rectangular tolerances (a fixed seed, so reruns are identical), the calibration hold solved at
each (:func:`calibration_draws`, recorded with the calibration), every later hold solved at the
same draws, and the diameter's input is the root mean square of e_D over the draws
(:func:`layer_geometry_input`: a bias with the draws' mean is folded into the u, not corrected,
since its sign follows the unknown geometry's). Each draw's solve is one local refinement of the
hold's nominal solve (:func:`_shifts`; a full solve where it leaves the nominal's basin).

Why not calibrate phi, d, gamma instead: see docs/ENGINEERING.md "Rod layer geometry" (the
calibration hold's Fisher information on them against the tolerances).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .config import schema_default
from .geometry import RodLayer
from .uncertainty import Input

__all__ = [
    "LayerGeometryPrior",
    "LayerGeometryDraws",
    "layer_geometry_prior",
    "calibration_draws",
    "HoldShifts",
    "hold_radius_shifts",
    "layer_geometry_input",
    "layer_geometry_information",
]

#: seed of the geometry draws (one fixed set: reruns and every hold of a calibration share it)
DRAW_SEED = 20261128


@dataclass(frozen=True)
class LayerGeometryPrior:
    """The tolerances of a layer's geometry about the design (rectangular half-widths) and the draws."""

    phi_bound_rad: float
    d_bound_mm: float
    gamma_bound_rad: float
    draws: int

    @property
    def bounds(self) -> np.ndarray:
        """Half-widths (phi [rad], d [mm], gamma [rad])."""
        return np.array([self.phi_bound_rad, self.d_bound_mm, self.gamma_bound_rad])


@dataclass(frozen=True)
class LayerGeometryDraws:
    """Geometry draws about the design and the calibration hold's radius shift at each.

    offsets : (k, m, 3) the draws' (phi [rad], d [mm], gamma [rad]) offsets of each layer
    cal_shift_mm : (k, m) R_C(design + offset) - R_C(design) of the calibration hold [mm] (NaN where
        the solve refused that draw; null in the record)
    bounds : the half-widths drawn within (phi [rad], d [mm], gamma [rad])
    cal_full_solves : draws of the calibration hold solved afresh (:func:`_shifts`)
    """

    offsets: np.ndarray
    cal_shift_mm: np.ndarray
    bounds: tuple[float, float, float]
    cal_full_solves: int = 0

    def to_dict(self) -> dict:
        """JSON-ready (the calibration's record)."""
        return {
            "offsets": self.offsets.tolist(),
            "cal_shift_mm": [[None if np.isnan(x) else float(x) for x in row] for row in self.cal_shift_mm],
            "bounds": list(self.bounds),
            "cal_full_solves": int(self.cal_full_solves),
        }

    @classmethod
    def from_dict(cls, d: dict | None) -> LayerGeometryDraws | None:
        """Read :meth:`to_dict`'s output back (None: a calibration recorded without draws)."""
        if not d:
            return None
        return cls(
            np.asarray(d["offsets"], dtype=float),
            np.array([[np.nan if x is None else x for x in row] for row in d["cal_shift_mm"]], dtype=float),
            tuple(float(b) for b in d["bounds"]),
            int(d.get("cal_full_solves", 0)),
        )


def layer_geometry_prior(unc_cfg: dict) -> LayerGeometryPrior:
    """Return the layers' stated tolerances and the number of draws (``uncertainty.rod_layer_*``)."""

    def get(key):
        return unc_cfg[key] if key in unc_cfg else schema_default("uncertainty", key)

    return LayerGeometryPrior(
        float(get("rod_layer_phi_bound_rad")),
        float(get("rod_layer_d_bound_mm")),
        float(get("rod_layer_gamma_bound_rad")),
        int(get("rod_layer_geometry_draws")),
    )


def _offsets(prior: LayerGeometryPrior, m: int) -> np.ndarray:
    """Return the fixed draws (k, m, 3), uniform within the bounds."""
    rng = np.random.default_rng(DRAW_SEED)
    return rng.uniform(-1.0, 1.0, (prior.draws, m, 3)) * prior.bounds


def _shifted(layers, offset) -> list[RodLayer]:
    return [
        replace(
            lay,
            phi_rad=lay.phi_rad + float(o[0]),
            d_mm=lay.d_mm + float(o[1]),
            gamma_rad=lay.gamma_rad + float(o[2]),
        )
        for lay, o in zip(layers, offset)
    ]


@dataclass(frozen=True)
class HoldShifts:
    """A hold's radius shifts at the draws and how many draws needed a full solve.

    shift_mm : (k, m) R(layers + offset) - R(layers) [mm] (NaN where the solve refused the draw)
    full_solves : draws whose refinement left the nominal solve's basin (solved afresh instead)
    """

    shift_mm: np.ndarray
    full_solves: int


def _shifts(means_mm, layers, u_reading_mm, coaxiality_mm, offsets, nominal=None) -> HoldShifts:
    """R(layers + offset) - R(layers) for every draw: the nominal solve refined to each draw.

    Each draw moves the nominal (``layers``) solve's minimum by micrometres: one local refinement
    from it (:func:`borescan.rod_refine.refine_rod`) gives what a full solve gives, at a quarter of
    its cost; where the refinement leaves the nominal's basin (its chi^2 more than 9 above the
    nominal's, a pose or the deflection moved: :class:`borescan.rod_refine.RodBasin`) or is
    refused, the draw is solved afresh (:func:`borescan.rod.solve_rod`) and counted.
    ``nominal``: the solve at ``layers`` when the caller has it (else solved here).
    """
    from .rod import solve_rod
    from .rod_refine import refine_rod

    kw = dict(u_reading_mm=u_reading_mm, coaxiality_mm=coaxiality_mm)
    if nominal is None:
        nominal = solve_rod(means_mm, layers=list(layers), **kw)
    out = np.full(offsets.shape[:2], np.nan)
    n_full = 0
    for i, off in enumerate(offsets):
        lays = _shifted(layers, off)
        try:
            sol = refine_rod(means_mm, nominal, layers=lays, **kw)
        except ValueError:  # RodBasinError or a refusal: the full solve decides
            n_full += 1
            try:
                sol = solve_rod(means_mm, layers=lays, **kw)
            except ValueError:  # RodSolveError: this geometry does not fit the poses; the draw is left out
                continue
        out[i] = sol.radius_mm - nominal.radius_mm
    return HoldShifts(out, n_full)


def calibration_draws(
    means_mm, layers, u_reading_mm, coaxiality_mm, prior: LayerGeometryPrior, nominal=None
) -> LayerGeometryDraws:
    """Return the draws and the calibration hold's radius shift at each (``layers``: the calibrated ones).

    ``nominal``: the solve at ``layers`` (:func:`borescan.rod_calibration.calibrate_l0`'s) if at hand.
    """
    off = _offsets(prior, len(layers))
    shifts = _shifts(means_mm, layers, u_reading_mm, coaxiality_mm, off, nominal)
    return LayerGeometryDraws(off, shifts.shift_mm, tuple(float(b) for b in prior.bounds), shifts.full_solves)


def hold_radius_shifts(
    means_mm, layers, u_reading_mm, coaxiality_mm, draws: LayerGeometryDraws, nominal=None
) -> HoldShifts:
    """Return R_H(layers + offset) - R_H(layers) of a later hold at the calibration's draws (k, m) [mm].

    ``nominal``: the hold's solve at ``layers`` if at hand.
    """
    return _shifts(means_mm, layers, u_reading_mm, coaxiality_mm, draws.offsets, nominal)


def layer_geometry_input(
    draws: LayerGeometryDraws, hold_shift_mm: np.ndarray, j: int, j_cal: int, scan_label: str, channel: int
) -> tuple[Input, float] | None:
    """Return the layer geometry's input of one diameter, as (input, dD / d input) for ``extra_terms``.

    ``j``: the layer's column in this hold, ``j_cal`` in the calibration. The input is the
    diameter's error e_D (module doc) over the draws where both holds solved: u its root mean
    square (its mean included), rectangular-sourced but Monte Carlo-propagated, so entered as
    ``normal`` with dof k - 1. None when fewer than half of the draws solved in both holds.
    """
    e = -2.0 * (hold_shift_mm[:, j] - draws.cal_shift_mm[:, j_cal])
    e = e[np.isfinite(e)]
    k = draws.offsets.shape[0]
    if e.size < max(2, k // 2):
        return None
    u = float(np.sqrt(np.mean(e**2)))
    bounds = draws.bounds
    return (
        Input(
            f"layer_geometry:{scan_label}:ch{int(channel)}",
            f"rod layers' phi, d, gamma off the design (channel {int(channel)}; l0 absorbed them at the "
            "calibration hold only)",
            f"e_geo,{int(channel)}",
            "mm",
            0.0,
            u,
            "normal",
            dof=float(e.size - 1),
            source=(
                f"Monte Carlo over {e.size} geometries uniform within phi +-{bounds[0]:.3g} rad, d "
                f"+-{bounds[1]:.3g} mm, gamma +-{bounds[2]:.3g} rad (uncertainty.rod_layer_*; mean error "
                f"{np.mean(e) * 1e3:+.1f} um folded into u); borescan.rod_layer_geometry"
            ),
        ),
        1.0,
    )


def layer_geometry_information(
    means_mm, layers, u_reading_mm, coaxiality_mm, prior: LayerGeometryPrior
) -> np.ndarray:
    """Return what a hold's readings fix of the layers' geometry: posterior over prior SD per direction.

    The hold's Fisher matrix in the solve's unknowns [rho, c, alpha, beta] (rho standing in for l0,
    which a calibration hold leaves free), the coaxial prior's rows, and the 3m geometry unknowns
    (phi, d, gamma per layer; central differences of the exact readings at the solve's minimum),
    with the stated tolerances as a prior (rectangular SDs); the geometry's block of the posterior
    covariance, in prior-SD units, eigen-decomposed. Returns its eigenvalues' square roots,
    ascending (3m,): 1 is a direction the readings do not inform, 0.1 one they fix to a tenth of
    its tolerance.
    """
    from .rod_deflection import _coaxial_rows
    from .rod_eq16 import _prepare, rod_start
    from .rod_model import _RodProblem, _solve_core

    lays = tuple(layers)
    l0 = np.array([lay.l0_mm for lay in lays])
    L, mask, _keep = _prepare(np.asarray(means_mm, dtype=float), l0, 2)
    n, m = L.shape
    p0, _S = rod_start(L, mask, 0)
    a0 = np.insert(p0[3 * m :], 0, 0.0)
    prob = _RodProblem(L - l0, mask, lays, 0, True)
    p, _cost, _nfev = _solve_core(prob, L, mask, [a0, -a0], True)
    sigma = float(u_reading_mm)
    Jp = -prob.jac(p, beta_step=1e-4) / sigma  # d(model)/dp, whitened
    u_g = np.tile(prior.bounds / np.sqrt(3.0), m)
    Jg = np.zeros((Jp.shape[0], 3 * m))
    for k in range(m):
        for q in range(3):
            h = 1e-3 * u_g[3 * k + q]
            rows = []
            for sg in (1.0, -1.0):
                off = np.zeros((m, 3))
                off[k, q] = sg * h
                pr = _RodProblem(prob.V, mask, _shifted(lays, off), 0, True)
                rows.append(pr.readings(*pr.unpack(p))[mask])
            Jg[:, 3 * k + q] = (rows[0] - rows[1]) / (2 * h) / sigma * u_g[3 * k + q]  # per prior SD
    rho, c, _alpha, w = prob.unpack(p)
    if coaxiality_mm is not None:
        C = _coaxial_rows(lays, rho, c, w, float(coaxiality_mm), prob.n_par)
        Jp = np.vstack([Jp, C])
        Jg = np.vstack([Jg, np.zeros((C.shape[0], 3 * m))])
    A = np.block([[Jp.T @ Jp, Jp.T @ Jg], [Jg.T @ Jp, Jg.T @ Jg + np.eye(3 * m)]])
    cov_g = np.linalg.pinv(A)[-3 * m :, -3 * m :]
    return np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (cov_g + cov_g.T)), 0.0, None))
